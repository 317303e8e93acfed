//! The figure's file: drawn in memory (an RGB buffer for a PNG, an SVG
//! document for `.svg` and `.pdf`), encoded, written to a hidden temporary
//! file next to the target and renamed to it when complete, by the rules
//! of [`crate::outputs`].

use std::io;
use std::io::Write;
use std::path::Path;

use image::codecs::png::PngEncoder;
use image::{ColorType, ImageEncoder};
use plotters::prelude::*;

use super::canvas::{Canvas, Format};
use super::style::{ensure_font, FONT_BYTES};
use super::{Area, BoxError, PlotError};
use crate::outputs::{self, Existing};

/// [`PlotError::InvalidData`] for `path`.
pub(super) fn invalid(path: &Path, reason: String) -> PlotError {
    PlotError::InvalidData {
        path: path.to_path_buf(),
        reason,
    }
}

/// Draws with `draw` into a canvas of `size` px and writes it to `path`
/// in the format of its extension ([`Format::of`]): a PNG of the RGB
/// buffer, an SVG document, or a one-page PDF converted from the SVG
/// (points = px × 0.75, as at 96 dpi). Through a temporary file renamed
/// when complete ([`outputs::write_atomically`]): a failed write leaves
/// nothing under `path`.
pub(super) fn write_png_atomically(
    path: &Path,
    existing: Existing,
    size: (u32, u32),
    draw: impl FnOnce(&Area<'_>) -> Result<(), BoxError>,
) -> Result<(), PlotError> {
    ensure_font()?;
    let io_err = |source: io::Error| PlotError::Io {
        path: path.to_path_buf(),
        source,
    };
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        return Err(io_err(io::Error::new(
            io::ErrorKind::NotFound,
            format!("directory {} does not exist", dir.display()),
        )));
    }
    if path.file_name().is_none() {
        return Err(io_err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "path has no file name",
        )));
    }
    let draw_err = |e: BoxError| PlotError::Draw {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let render = |canvas: Canvas<'_>| -> Result<(), BoxError> {
        let root = canvas.into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present()?;
        Ok(())
    };
    let format = Format::of(path);
    let bytes: Vec<u8> = match format {
        Format::Png => {
            let mut rgb = vec![0u8; size.0 as usize * size.1 as usize * 3];
            render(Canvas::Bitmap(BitMapBackend::with_buffer(&mut rgb, size))).map_err(draw_err)?;
            let mut png = Vec::new();
            PngEncoder::new(&mut png)
                .write_image(&rgb, size.0, size.1, ColorType::Rgb8)
                .map_err(|e| draw_err(e.to_string().into()))?;
            png
        }
        Format::Svg | Format::Pdf => {
            let mut svg = String::new();
            render(Canvas::Svg(SVGBackend::with_string(&mut svg, size))).map_err(draw_err)?;
            if format == Format::Svg {
                svg.into_bytes()
            } else {
                svg_to_pdf(&svg).map_err(|e| draw_err(e.into()))?
            }
        }
    };
    outputs::write_atomically(path, existing, |file| {
        let mut w = io::BufWriter::new(file);
        w.write_all(&bytes)?;
        w.flush()
    })
    .map_err(io_err)
}

/// A one-page PDF of the SVG document `svg` (svg2pdf), its text set in
/// the embedded DejaVu Sans (the font the figures are measured in), so it
/// looks the same on every machine.
fn svg_to_pdf(svg: &str) -> Result<Vec<u8>, String> {
    use svg2pdf::usvg;
    let mut fontdb = usvg::fontdb::Database::new();
    fontdb.load_font_data(FONT_BYTES.to_vec());
    fontdb.set_sans_serif_family("DejaVu Sans");
    let options = usvg::Options {
        fontdb: std::sync::Arc::new(fontdb),
        font_family: "DejaVu Sans".to_string(),
        ..usvg::Options::default()
    };
    let tree = usvg::Tree::from_str(svg, &options).map_err(|e| format!("the SVG: {e}"))?;
    svg2pdf::to_pdf(
        &tree,
        svg2pdf::ConversionOptions::default(),
        svg2pdf::PageOptions { dpi: 96.0 },
    )
    .map_err(|e| format!("the PDF conversion: {e}"))
}
