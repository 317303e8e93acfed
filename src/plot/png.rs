//! The PNG file: a figure is drawn into an RGB buffer in memory, encoded
//! to a hidden temporary file next to the target and renamed to it when
//! complete, by the rules of [`crate::outputs`].

use std::io;
use std::io::Write;
use std::path::Path;

use image::codecs::png::PngEncoder;
use image::{ColorType, ImageEncoder};
use plotters::prelude::*;

use super::style::ensure_font;
use super::{Area, BoxError, PlotError};
use crate::outputs::{self, Existing};

/// [`PlotError::InvalidData`] for `path`.
pub(super) fn invalid(path: &Path, reason: String) -> PlotError {
    PlotError::InvalidData {
        path: path.to_path_buf(),
        reason,
    }
}

/// Draws with `draw` into an RGB buffer of `size` px, then writes it as a
/// PNG to `path` through a temporary file renamed when complete
/// ([`outputs::write_atomically`]): a failed write leaves nothing under
/// `path`.
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
    let mut rgb = vec![0u8; size.0 as usize * size.1 as usize * 3];
    (|| -> Result<(), BoxError> {
        let root = BitMapBackend::with_buffer(&mut rgb, size).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present()?;
        Ok(())
    })()
    .map_err(|e| PlotError::Draw {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    outputs::write_atomically(path, existing, |file| {
        let mut w = io::BufWriter::new(file);
        PngEncoder::new(&mut w)
            .write_image(&rgb, size.0, size.1, ColorType::Rgb8)
            .map_err(|e| match e {
                image::ImageError::IoError(e) => e,
                e => io::Error::other(e.to_string()),
            })?;
        w.flush()
    })
    .map_err(io_err)
}
