//! PNG plots of identification and closed-loop results.
//!
//! Two kinds of figure are supported:
//!
//! * [`write_bode_png`]: a 1400x1000 px Bode figure with three stacked panels
//!   sharing a logarithmic frequency axis: magnitude in dB re 1 m/A, phase in
//!   degrees and coherence, with an optional model overlay and vertical
//!   markers at identified resonances.
//! * [`write_time_png`]: one or more stacked time-series panels sharing a
//!   time axis, e.g. for closed-loop step responses.
//!
//! Rendering uses the plotters bitmap backend with an embedded DejaVu Sans
//! font, so no system font libraries are needed. Non-finite samples (and
//! non-positive magnitudes or frequencies, which have no logarithm) are
//! skipped and break the line instead of failing. The image is drawn in
//! memory, encoded to a hidden temporary file next to the target and renamed
//! to it when complete, by the rules of [`crate::outputs`]: a reader never
//! sees a half-written PNG, and an existing file is replaced only with
//! [`Existing::Replace`] (`--overwrite`), never when it is not a regular file.

use std::error::Error as StdError;
use std::io;
use std::io::Write;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use image::codecs::png::PngEncoder;
use image::{ColorType, ImageEncoder};

use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, ValueFormatter};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::outputs::{self, Existing};

/// One frequency-response curve.
#[derive(Debug, Clone, Copy)]
pub struct BodeSeries<'a> {
    /// Legend label of the curve.
    pub label: &'a str,
    /// Frequency grid in Hz (points with non-positive or non-finite frequency
    /// are skipped).
    pub frequency_hz: &'a [f64],
    /// Linear magnitude in m/A, same length as `frequency_hz`; plotted as
    /// 20·log10 (dB re 1 m/A). Zero, negative or non-finite values are skipped.
    pub magnitude: &'a [f64],
    /// Unwrapped phase in degrees, same length as `frequency_hz`.
    pub phase_deg: &'a [f64],
}

/// Everything shown in one Bode figure (see [`write_bode_png`]).
#[derive(Debug, Clone, Copy)]
pub struct BodePlot<'a> {
    /// Figure title, drawn above the panels (omitted when empty).
    pub title: &'a str,
    /// Measured frequency response, drawn as solid lines.
    pub measured: BodeSeries<'a>,
    /// Magnitude-squared coherence on the grid of `measured`, 0..1; must have
    /// the same length as `measured.frequency_hz`.
    pub coherence: &'a [f64],
    /// Optional model response, drawn dashed in another colour; may use a
    /// different frequency grid than `measured` and is clipped to the
    /// measured frequency band.
    pub model: Option<BodeSeries<'a>>,
    /// Resonance frequencies in Hz, drawn as labelled vertical dashed lines on
    /// all panels. Markers outside the plotted frequency range are skipped.
    pub markers_hz: &'a [f64],
}

/// One panel of a time-series figure (see [`write_time_png`]).
#[derive(Debug, Clone, Default)]
pub struct TimePanel<'a> {
    /// Y-axis description including the unit, e.g. `"Position [µm]"`.
    pub y_label: &'a str,
    /// Curves as `(label, t_s, values)`; `t_s` and `values` must have equal
    /// length. Curves with an empty label get no legend entry.
    pub series: Vec<(&'a str, &'a [f64], &'a [f64])>,
}

/// Error writing a plot; every variant except [`PlotError::Font`] names the
/// output path.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The output directory is missing or the file could not be written or
    /// moved into place.
    #[error("cannot write plot {}: {source}", path.display())]
    Io {
        /// Requested output path.
        path: PathBuf,
        /// Underlying I/O error.
        #[source]
        source: io::Error,
    },
    /// The input data is inconsistent (e.g. mismatched slice lengths).
    #[error("invalid data for plot {}: {reason}", path.display())]
    InvalidData {
        /// Requested output path.
        path: PathBuf,
        /// What is wrong with the data.
        reason: String,
    },
    /// plotters failed while drawing or encoding the image.
    #[error("drawing plot {} failed: {message}", path.display())]
    Draw {
        /// Requested output path.
        path: PathBuf,
        /// Error message reported by plotters.
        message: String,
    },
    /// The embedded font could not be registered with plotters.
    #[error("the embedded plot font (DejaVu Sans) could not be loaded")]
    Font,
}

/// Width and height of the Bode figure in pixels.
const BODE_SIZE: (u32, u32) = (1400, 1000);
pub(crate) const FONT: &str = "sans-serif";
static FONT_BYTES: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

const TITLE_SIZE: f64 = 28.0;
const DESC_SIZE: f64 = 20.0;
const TICK_SIZE: f64 = 17.0;
const LEGEND_SIZE: f64 = 17.0;
const MARKER_LABEL_SIZE: f64 = 15.0;
const Y_LABEL_AREA: u32 = 100;
const X_LABEL_AREA: u32 = 60;
const LINE_WIDTH: u32 = 2;
const MARGIN_LEFT: u32 = 10;
const MARGIN_RIGHT: u32 = 30;
const MARGIN_TOP: u32 = 12;

const MEASURED_COLOR: RGBColor = RGBColor(31, 119, 180);
const MODEL_COLOR: RGBColor = RGBColor(214, 39, 40);
const MARKER_COLOR: RGBColor = RGBColor(90, 90, 90);
const GRID_BOLD: RGBColor = RGBColor(200, 200, 200);
const GRID_LIGHT: RGBColor = RGBColor(232, 232, 232);
const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

pub(crate) type BoxError = Box<dyn StdError>;
pub(crate) type Area<'b> = DrawingArea<BitMapBackend<'b>, Shift>;
type Chart<'a, 'b, X> = ChartContext<'a, BitMapBackend<'b>, Cartesian2d<X, Ticked<RangedCoordf64>>>;

/// Writes a Bode figure of `plot` as a 1400x1000 px PNG to `path`.
///
/// Panels from top to bottom: magnitude in dB re 1 m/A (20·log10 of the
/// linear m/A magnitude), unwrapped phase in degrees and coherence (0..1.05),
/// all sharing a logarithmic frequency axis. The axis spans the measured
/// frequencies (the model is clipped to that band); only if the measured
/// series has no usable band do the model frequencies widen it. Invalid points
/// are skipped and break the line. The file is written to a temporary file in
/// the same directory and renamed into place (see [`crate::outputs`]).
///
/// # Errors
///
/// [`PlotError::Io`] if the directory of `path` does not exist or the file
/// cannot be written, [`PlotError::InvalidData`] if slice lengths disagree,
/// [`PlotError::Draw`] if plotters fails, [`PlotError::Font`] if the embedded
/// font cannot be loaded.
pub fn write_bode_png(
    path: &Path,
    existing: Existing,
    plot: &BodePlot<'_>,
) -> Result<(), PlotError> {
    check_series(path, "measured", &plot.measured)?;
    if let Some(model) = &plot.model {
        check_series(path, "model", model)?;
    }
    if plot.coherence.len() != plot.measured.frequency_hz.len() {
        return Err(invalid(
            path,
            format!(
                "coherence has {} points but the measured series has {}",
                plot.coherence.len(),
                plot.measured.frequency_hz.len()
            ),
        ));
    }
    write_png_atomically(path, existing, BODE_SIZE, |root| draw_bode(root, plot))
}

/// Writes stacked time-series `panels` sharing one time axis (s) as a PNG to
/// `path`, with `title` above them (omitted when empty).
///
/// The image is 1400 px wide and 1000 px high for up to three panels, growing
/// by 300 px per additional panel (capped at 8000 px). Each panel gets its own y range (from its
/// data, with a margin) and a legend of its labelled series. Non-finite
/// samples are skipped and break the line.
///
/// # Errors
///
/// [`PlotError::InvalidData`] if `panels` is empty or a series has
/// `t_s.len() != values.len()`; otherwise as for [`write_bode_png`].
pub fn write_time_png(
    path: &Path,
    existing: Existing,
    title: &str,
    panels: &[TimePanel<'_>],
) -> Result<(), PlotError> {
    if panels.is_empty() {
        return Err(invalid(path, "no panels to plot".to_string()));
    }
    for (i, panel) in panels.iter().enumerate() {
        for (label, t, v) in &panel.series {
            if t.len() != v.len() {
                return Err(invalid(
                    path,
                    format!(
                        "panel {i} ({:?}), series {label:?}: {} time stamps but {} values",
                        panel.y_label,
                        t.len(),
                        v.len()
                    ),
                ));
            }
        }
    }
    let extra = u32::try_from(panels.len().saturating_sub(3)).unwrap_or(u32::MAX);
    let height = 1000u32.saturating_add(extra.saturating_mul(300)).min(8000);
    write_png_atomically(path, existing, (1400, height), |root| {
        draw_time(root, title, panels)
    })
}

fn invalid(path: &Path, reason: String) -> PlotError {
    PlotError::InvalidData {
        path: path.to_path_buf(),
        reason,
    }
}

fn check_series(path: &Path, which: &str, s: &BodeSeries<'_>) -> Result<(), PlotError> {
    let n = s.frequency_hz.len();
    if s.magnitude.len() != n || s.phase_deg.len() != n {
        return Err(invalid(
            path,
            format!(
                "{which} series {:?}: {n} frequencies, {} magnitudes, {} phases",
                s.label,
                s.magnitude.len(),
                s.phase_deg.len()
            ),
        ));
    }
    Ok(())
}

fn ensure_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, FONT_BYTES).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(PlotError::Font)
    }
}

/// Draws with `draw` into an RGB buffer, then writes it as a PNG to `path`
/// through a temporary file renamed when complete
/// ([`outputs::write_atomically`](crate::outputs::write_atomically)): a
/// failed write leaves nothing under `path`.
pub(crate) fn write_png_atomically(
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

// ---------------------------------------------------------------------------
// Bode figure

fn to_db(m: f64) -> f64 {
    if m > 0.0 && m.is_finite() {
        20.0 * m.log10()
    } else {
        f64::NAN
    }
}

fn draw_bode(root: &Area<'_>, plot: &BodePlot<'_>) -> Result<(), BoxError> {
    let outer = root.margin(8, 0, 0, 0);
    let body = if plot.title.is_empty() {
        outer
    } else {
        outer.titled(plot.title, (FONT, TITLE_SIZE))?
    };

    let meas = &plot.measured;
    let model = plot.model.as_ref();
    // The measured band sets the frequency axis; the model is clipped to it.
    // Only without a usable measured band does the model widen the axis.
    let x_range = match positive_extent(meas.frequency_hz.iter().copied()) {
        Some((lo, hi)) if hi / lo >= 1.01 => lo..hi,
        _ => log_range(
            meas.frequency_hz
                .iter()
                .chain(model.map_or(&[][..], |m| m.frequency_hz))
                .copied(),
        ),
    };
    let (x_bold, x_light) = log_ticks(&x_range);

    let db = |f: &[f64], m: &[f64]| -> Vec<(f64, f64)> {
        f.iter().zip(m).map(|(&f, &m)| (f, to_db(m))).collect()
    };
    let meas_db = runs(&db(meas.frequency_hz, meas.magnitude), &x_range, true);
    let meas_phase = runs(&pairs(meas.frequency_hz, meas.phase_deg), &x_range, true);
    let coh = runs(&pairs(meas.frequency_hz, plot.coherence), &x_range, true);
    let (model_db, model_phase) = match model {
        Some(m) => (
            runs(&db(m.frequency_hz, m.magnitude), &x_range, true),
            runs(&pairs(m.frequency_hz, m.phase_deg), &x_range, true),
        ),
        None => (Vec::new(), Vec::new()),
    };
    let ys = |a: &[Vec<(f64, f64)>], b: &[Vec<(f64, f64)>]| -> Vec<f64> {
        a.iter().chain(b).flatten().map(|p| p.1).collect()
    };
    let db_range = padded_range(&ys(&meas_db, &model_db), 0.06, 10.0, -100.0..0.0);
    let phase_range = padded_range(&ys(&meas_phase, &model_phase), 0.06, 45.0, -180.0..0.0);
    let coh_range = ys(&coh, &[])
        .iter()
        .fold(0.0f64..1.05f64, |r, &c| r.start.min(c)..r.end.max(c));

    let markers: Vec<f64> = plot
        .markers_hz
        .iter()
        .copied()
        .filter(|&f| f.is_finite() && f >= x_range.start && f <= x_range.end)
        .collect();
    // Marker labels go above the magnitude frame; reserve rows for them.
    let (body_x0, _) = body.get_base_pixel();
    let (body_w, body_h) = body.dim_in_pixel();
    let plot_x0 = f64::from(body_x0) + f64::from(MARGIN_LEFT + Y_LABEL_AREA);
    let plot_w = f64::from(body_w) - f64::from(MARGIN_LEFT + Y_LABEL_AREA + MARGIN_RIGHT);
    let log_span = (x_range.end / x_range.start).ln();
    let (labels, rows) = layout_marker_labels(&body, &markers, |f| {
        (plot_x0 + plot_w * (f / x_range.start).ln() / log_span) as i32
    })?;
    let mag_top = MARGIN_TOP + u32::try_from(rows)? * u32::try_from(marker_row_height())?;

    // Split the body into three panels; the bottom one also holds the x labels.
    let plot_h = f64::from(body_h.saturating_sub(X_LABEL_AREA + mag_top));
    let h_mag = (plot_h * 0.42) as u32 + mag_top;
    let h_phase = (plot_h * 0.31) as u32;
    let (mag_area, rest) = body.split_vertically(h_mag);
    let (phase_area, coh_area) = rest.split_vertically(h_phase);
    let x_fmt = |v: &f64| fmt_tick(*v);
    let no_fmt = |_: &f64| String::new();

    // Magnitude.
    {
        let y_ticks = linear_ticks(&db_range, 8);
        let y_fmt = tick_formatter(&y_ticks);
        let x = freq_axis(&x_range, &x_bold, &x_light);
        let mut chart = panel_chart(&mag_area, x, &db_range, y_ticks, mag_top, false)?;
        mesh(&mut chart, None, "Magnitude [dB re 1 m/A]", &no_fmt, &y_fmt)?;
        draw_markers(&mut chart, &markers, &db_range)?;
        draw_curve(
            &mut chart,
            &meas_db,
            MEASURED_COLOR,
            false,
            Some(meas.label),
        )?;
        if let Some(m) = model {
            draw_curve(&mut chart, &model_db, MODEL_COLOR, true, Some(m.label))?;
        }
        frame(&chart)?;
        legend(&mut chart)?;
        draw_marker_labels(root, &chart, &labels, db_range.end)?;
    }
    // Phase.
    {
        let y_ticks = phase_ticks(&phase_range);
        let y_fmt = tick_formatter(&y_ticks);
        let x = freq_axis(&x_range, &x_bold, &x_light);
        let mut chart = panel_chart(&phase_area, x, &phase_range, y_ticks, MARGIN_TOP, false)?;
        mesh(&mut chart, None, "Phase [°]", &no_fmt, &y_fmt)?;
        draw_markers(&mut chart, &markers, &phase_range)?;
        draw_curve(&mut chart, &meas_phase, MEASURED_COLOR, false, None)?;
        draw_curve(&mut chart, &model_phase, MODEL_COLOR, true, None)?;
        frame(&chart)?;
    }
    // Coherence.
    {
        let y_ticks: Vec<f64> = (0..=5).map(|i| f64::from(i) * 0.2).collect();
        let y_fmt = tick_formatter(&y_ticks);
        let x = freq_axis(&x_range, &x_bold, &x_light);
        let mut chart = panel_chart(&coh_area, x, &coh_range, y_ticks, MARGIN_TOP, true)?;
        let x_desc = Some("Frequency [Hz]");
        mesh(&mut chart, x_desc, "Coherence [-]", &x_fmt, &y_fmt)?;
        draw_markers(&mut chart, &markers, &coh_range)?;
        draw_curve(&mut chart, &coh, MEASURED_COLOR, false, None)?;
        frame(&chart)?;
    }
    Ok(())
}

fn pairs(x: &[f64], y: &[f64]) -> Vec<(f64, f64)> {
    x.iter().copied().zip(y.iter().copied()).collect()
}

fn freq_axis(range: &Range<f64>, bold: &[f64], light: &[f64]) -> Ticked<LogCoord<f64>> {
    Ticked {
        inner: range.clone().log_scale().into(),
        bold: bold.to_vec(),
        light: light.to_vec(),
    }
}

fn linear_axis(range: &Range<f64>, bold: Vec<f64>) -> Ticked<RangedCoordf64> {
    Ticked {
        inner: range.clone().into(),
        bold,
        light: Vec::new(),
    }
}

/// A coordinate axis with explicitly chosen labelled (bold) and grid-only
/// (light) tick positions. plotters' own `WithKeyPoints` cannot be used on
/// `f64` ranges because it loses their value formatter.
struct Ticked<R> {
    inner: R,
    bold: Vec<f64>,
    light: Vec<f64>,
}

impl<R: Ranged<ValueType = f64>> Ranged for Ticked<R> {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        self.inner.map(value, limit)
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        if hint.weight().allow_light_points() {
            self.light.clone()
        } else {
            self.bold.clone()
        }
    }

    fn range(&self) -> Range<f64> {
        self.inner.range()
    }

    fn axis_pixel_range(&self, limit: (i32, i32)) -> Range<i32> {
        self.inner.axis_pixel_range(limit)
    }
}

/// Builds one panel. `bottom` panels get an x label area; the others share
/// the x axis of the bottom panel and show only its grid.
fn panel_chart<'a, 'b: 'a, X: Ranged<ValueType = f64>>(
    area: &'a Area<'b>,
    x: X,
    y_range: &Range<f64>,
    y_ticks: Vec<f64>,
    margin_top: u32,
    bottom: bool,
) -> Result<Chart<'a, 'b, X>, BoxError> {
    let mut builder = ChartBuilder::on(area);
    builder
        .margin_left(MARGIN_LEFT)
        .margin_right(MARGIN_RIGHT)
        .margin_top(margin_top)
        .margin_bottom(if bottom { 10 } else { 0 })
        .y_label_area_size(Y_LABEL_AREA);
    if bottom {
        builder.x_label_area_size(X_LABEL_AREA);
    }
    let chart = builder.build_cartesian_2d(x, linear_axis(y_range, y_ticks))?;
    Ok(chart)
}

fn mesh<'a, 'b: 'a, X>(
    chart: &mut Chart<'a, 'b, X>,
    x_desc: Option<&str>,
    y_desc: &str,
    x_fmt: &dyn Fn(&f64) -> String,
    y_fmt: &dyn Fn(&f64) -> String,
) -> Result<(), BoxError>
where
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let mut m = chart.configure_mesh();
    m.bold_line_style(GRID_BOLD.stroke_width(1))
        .light_line_style(GRID_LIGHT.stroke_width(1))
        .label_style((FONT, TICK_SIZE))
        .axis_desc_style((FONT, DESC_SIZE))
        .x_label_formatter(x_fmt)
        .y_label_formatter(y_fmt)
        .y_desc(y_desc);
    if let Some(d) = x_desc {
        m.x_desc(d);
    }
    m.draw()?;
    Ok(())
}

/// Draws a black frame around the plotting area.
fn frame<X: Ranged<ValueType = f64>>(chart: &Chart<'_, '_, X>) -> Result<(), BoxError> {
    let area = chart.plotting_area().strip_coord_spec();
    let (w, h) = area.dim_in_pixel();
    let (w, h) = (i32::try_from(w)?, i32::try_from(h)?);
    area.draw(&Rectangle::new(
        [(0, 0), (w - 1, h - 1)],
        BLACK.stroke_width(1),
    ))?;
    Ok(())
}

/// Splits `points` at invalid samples (non-finite, or non-positive x for a
/// log axis) and clips the runs to `x_range` (interpolating at the edges,
/// linearly in log x for a log axis). Returns the drawable runs.
fn runs(points: &[(f64, f64)], x_range: &Range<f64>, log_x: bool) -> Vec<Vec<(f64, f64)>> {
    let mut out = Vec::new();
    let mut cur = Vec::new();
    for &(x, y) in points {
        if x.is_finite() && y.is_finite() && (!log_x || x > 0.0) {
            cur.push((x, y));
        } else if !cur.is_empty() {
            out.extend(clip_x(&std::mem::take(&mut cur), x_range, log_x));
        }
    }
    if !cur.is_empty() {
        out.extend(clip_x(&cur, x_range, log_x));
    }
    out
}

/// Clips a polyline of finite points to `x_range`.
fn clip_x(seg: &[(f64, f64)], x_range: &Range<f64>, log_x: bool) -> Vec<Vec<(f64, f64)>> {
    let tx = |x: f64| if log_x { x.ln() } else { x };
    let untx = |x: f64| if log_x { x.exp() } else { x };
    let (lo, hi) = (tx(x_range.start), tx(x_range.end));
    if seg.len() == 1 {
        let x = tx(seg[0].0);
        return if x >= lo && x <= hi {
            vec![seg.to_vec()]
        } else {
            Vec::new()
        };
    }
    let mut out = Vec::new();
    let mut cur: Vec<(f64, f64)> = Vec::new();
    for w in seg.windows(2) {
        let (a, b) = (w[0], w[1]);
        let (xa, xb) = (tx(a.0), tx(b.0));
        let dx = xb - xa;
        let (mut t0, mut t1) = (0.0f64, 1.0f64);
        if dx == 0.0 {
            if xa < lo || xa > hi {
                t0 = 1.0;
                t1 = 0.0;
            }
        } else {
            let (ta, tb) = ((lo - xa) / dx, (hi - xa) / dx);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
        if t0 > t1 {
            if !cur.is_empty() {
                out.push(std::mem::take(&mut cur));
            }
            continue;
        }
        let at = |t: f64| {
            if t <= 0.0 {
                a
            } else if t >= 1.0 {
                b
            } else {
                (untx(xa + t * dx), a.1 + t * (b.1 - a.1))
            }
        };
        let (p0, p1) = (at(t0), at(t1));
        if cur.last() != Some(&p0) {
            if !cur.is_empty() {
                out.push(std::mem::take(&mut cur));
            }
            cur.push(p0);
        }
        cur.push(p1);
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    out
}

/// Draws the runs of one curve (single-point runs as dots) and, if
/// `legend_label` is non-empty, registers a legend entry.
fn draw_curve<'a, 'b: 'a, X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'a, 'b, X>,
    runs: &[Vec<(f64, f64)>],
    color: RGBColor,
    dashed: bool,
    legend_label: Option<&str>,
) -> Result<(), BoxError> {
    let style = color.stroke_width(LINE_WIDTH);
    for run in runs {
        if run.len() == 1 {
            chart.draw_series(std::iter::once(Circle::new(run[0], 3, color.filled())))?;
        } else if dashed {
            chart.draw_series(DashedLineSeries::new(run.iter().copied(), 10, 6, style))?;
        } else {
            chart.draw_series(LineSeries::new(run.iter().copied(), style))?;
        }
    }
    if let Some(label) = legend_label.filter(|l| !l.is_empty()) {
        // An empty series carries the legend entry, so the legend appears even
        // when the curve has no drawable points.
        chart
            .draw_series(std::iter::empty::<PathElement<(f64, f64)>>())?
            .label(label)
            .legend(move |(x, y)| {
                if dashed {
                    DashedPathElement::new(vec![(x, y), (x + 30, y)], 10, 6, style).into_dyn()
                } else {
                    PathElement::new(vec![(x, y), (x + 30, y)], style).into_dyn()
                }
            });
    }
    Ok(())
}

fn legend<'a, 'b: 'a, X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'a, 'b, X>,
) -> Result<(), BoxError> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .margin(12)
        .legend_area_size(40)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK.stroke_width(1))
        .label_font((FONT, LEGEND_SIZE))
        .draw()?;
    Ok(())
}

fn draw_markers<'a, 'b: 'a, X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'a, 'b, X>,
    markers: &[f64],
    y_range: &Range<f64>,
) -> Result<(), BoxError> {
    let style = MARKER_COLOR.stroke_width(1);
    for &f in markers {
        chart.draw_series(DashedLineSeries::new(
            [(f, y_range.start), (f, y_range.end)],
            8,
            5,
            style,
        ))?;
    }
    Ok(())
}

/// A marker label placed above the magnitude panel.
struct MarkerLabel {
    freq: f64,
    text: String,
    row: usize,
}

fn marker_style() -> TextStyle<'static> {
    TextStyle::from((FONT, MARKER_LABEL_SIZE).into_font())
        .color(&MARKER_COLOR)
        .pos(Pos::new(HPos::Center, VPos::Bottom))
}

/// Assigns marker labels to rows so that labels in a row do not overlap;
/// `x_px` maps a frequency to an (approximate) pixel column.
fn layout_marker_labels(
    area: &Area<'_>,
    markers: &[f64],
    x_px: impl Fn(f64) -> i32,
) -> Result<(Vec<MarkerLabel>, usize), BoxError> {
    let style = marker_style();
    let mut sorted = markers.to_vec();
    sorted.sort_by(f64::total_cmp);
    let mut row_right_edges: Vec<i32> = Vec::new();
    let mut labels = Vec::new();
    for freq in sorted {
        let text = format!("{} Hz", fmt_sig(freq, 4));
        let (tw, _) = area.estimate_text_size(&text, &style)?;
        let tw = i32::try_from(tw)?;
        let left = x_px(freq) - tw / 2;
        let row = match row_right_edges.iter().position(|&r| left > r + 8) {
            Some(r) => r,
            None => {
                row_right_edges.push(i32::MIN);
                row_right_edges.len() - 1
            }
        };
        row_right_edges[row] = left + tw;
        labels.push(MarkerLabel { freq, text, row });
    }
    Ok((labels, row_right_edges.len()))
}

/// Height of one row of marker labels in pixels.
fn marker_row_height() -> i32 {
    MARKER_LABEL_SIZE as i32 + 4
}

/// Draws the marker labels above the frame of `chart`, centred on the lines.
fn draw_marker_labels<X: Ranged<ValueType = f64>>(
    root: &Area<'_>,
    chart: &Chart<'_, '_, X>,
    labels: &[MarkerLabel],
    y_top: f64,
) -> Result<(), BoxError> {
    let style = marker_style();
    let (root_w, _) = root.dim_in_pixel();
    let root_w = i32::try_from(root_w)?;
    for l in labels {
        let (px, py) = chart.backend_coord(&(l.freq, y_top));
        let (tw, _) = root.estimate_text_size(&l.text, &style)?;
        let half = i32::try_from(tw)? / 2 + 2;
        let x = px.clamp(half, (root_w - half).max(half));
        let y = py - 4 - i32::try_from(l.row)? * marker_row_height();
        root.draw(&Text::new(l.text.clone(), (x, y), style.clone()))?;
    }
    Ok(())
}

// ---------------------------------------------------------------------------
// Time-series figure

fn draw_time(root: &Area<'_>, title: &str, panels: &[TimePanel<'_>]) -> Result<(), BoxError> {
    let outer = root.margin(8, 0, 0, 0);
    let body = if title.is_empty() {
        outer
    } else {
        outer.titled(title, (FONT, TITLE_SIZE))?
    };
    let t_all: Vec<f64> = panels
        .iter()
        .flat_map(|p| p.series.iter())
        .flat_map(|(_, t, v)| t.iter().zip(v.iter()))
        .filter(|(t, v)| t.is_finite() && v.is_finite())
        .map(|(t, _)| *t)
        .collect();
    let t_range = padded_range(&t_all, 0.0, 0.0, 0.0..1.0);
    let t_ticks = linear_ticks(&t_range, 12);
    let t_fmt = tick_formatter(&t_ticks);
    let no_fmt = |_: &f64| String::new();

    let (_, h) = body.dim_in_pixel();
    let n = u32::try_from(panels.len())?;
    let panel_h = h.saturating_sub(X_LABEL_AREA) / n;
    let mut rest = body;
    for (i, panel) in panels.iter().enumerate() {
        let bottom = i + 1 == panels.len();
        let area = if bottom {
            rest.clone()
        } else {
            let (top, below) = rest.split_vertically(panel_h);
            rest = below;
            top
        };
        let values: Vec<f64> = panel
            .series
            .iter()
            .flat_map(|(_, t, v)| t.iter().zip(v.iter()))
            .filter(|(t, v)| t.is_finite() && v.is_finite())
            .map(|(_, v)| *v)
            .collect();
        let y_range = padded_range(&values, 0.06, 0.0, -1.0..1.0);
        let y_ticks = linear_ticks(&y_range, 8);
        let y_fmt = tick_formatter(&y_ticks);
        let x_axis = linear_axis(&t_range, t_ticks.clone());
        let mut chart = panel_chart(&area, x_axis, &y_range, y_ticks, MARGIN_TOP, bottom)?;
        let x_fmt: &dyn Fn(&f64) -> String = if bottom { &t_fmt } else { &no_fmt };
        let x_desc = bottom.then_some("Time [s]");
        mesh(&mut chart, x_desc, panel.y_label, x_fmt, &y_fmt)?;
        let mut any_label = false;
        for (k, (label, t, v)) in panel.series.iter().enumerate() {
            let color = PALETTE[k % PALETTE.len()];
            any_label |= !label.is_empty();
            let pts = runs(&pairs(t, v), &t_range, false);
            draw_curve(&mut chart, &pts, color, false, Some(label))?;
        }
        frame(&chart)?;
        if any_label {
            legend(&mut chart)?;
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------
// Ranges, ticks and number formatting

/// Range of the finite `values`, widened to at least `min_span` (centred) and
/// then padded by `pad_frac` of the span on both sides. All-equal data gets a
/// span relative to its magnitude (or 2 around zero). `fallback` is used when
/// there is no finite value.
fn padded_range(values: &[f64], pad_frac: f64, min_span: f64, fallback: Range<f64>) -> Range<f64> {
    let (lo, hi) = values
        .iter()
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    if lo > hi {
        return fallback;
    }
    let mid = 0.5 * lo + 0.5 * hi;
    let mut span = hi - lo;
    let degenerate = mid.abs() * 1e-9;
    let min_span = if span <= degenerate && min_span <= degenerate {
        // Constant data without a configured minimum span.
        if mid == 0.0 {
            2.0
        } else {
            mid.abs() * 0.2
        }
    } else {
        min_span.max(degenerate)
    };
    let (mut lo, mut hi) = (lo, hi);
    if span < min_span {
        lo = mid - 0.5 * min_span;
        hi = mid + 0.5 * min_span;
        span = min_span;
    }
    let pad = span * pad_frac;
    let r = (lo - pad)..(hi + pad);
    if r.start.is_finite() && r.end.is_finite() && r.start < r.end {
        r
    } else {
        fallback
    }
}

/// Smallest and largest positive finite value, if any.
fn positive_extent(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && *v > 0.0)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    (lo <= hi).then_some((lo, hi))
}

/// Log-axis range spanning the positive finite `freqs`. A single frequency
/// (or a span under 1 %) gets a factor of two either side.
fn log_range(freqs: impl Iterator<Item = f64>) -> Range<f64> {
    let Some((lo, hi)) = positive_extent(freqs) else {
        return 1.0..1000.0;
    };
    if hi / lo < 1.01 {
        let r = (lo / 2.0)..(hi * 2.0);
        if r.start > 0.0 && r.end.is_finite() {
            return r;
        }
        return 1.0..1000.0;
    }
    lo..hi
}

/// Labelled (bold) and grid-only (light) tick positions for a log axis:
/// decades when the range spans at least two, otherwise 1-2-5 or 1..9 per
/// decade, and a linear fallback for very narrow ranges.
fn log_ticks(r: &Range<f64>) -> (Vec<f64>, Vec<f64>) {
    let (lo, hi) = (r.start, r.end);
    let d0 = lo.log10().floor() as i32;
    let d1 = hi.log10().ceil() as i32;
    let gen = |mantissas: &[f64]| -> Vec<f64> {
        let mut v = Vec::new();
        for d in d0..=d1 {
            let p = 10f64.powi(d);
            for &m in mantissas {
                let x = m * p;
                if x >= lo * (1.0 - 1e-9) && x <= hi * (1.0 + 1e-9) {
                    v.push(x);
                }
            }
        }
        v
    };
    let all: Vec<f64> = (1..=9).map(f64::from).collect();
    let mut bold = gen(&[1.0]);
    if bold.len() > 12 {
        let step = bold.len().div_ceil(10);
        bold = bold.into_iter().step_by(step).collect();
    }
    if bold.len() < 3 {
        bold = gen(&[1.0, 2.0, 5.0]);
    }
    if bold.len() < 3 {
        bold = gen(&all);
    }
    if bold.len() < 2 {
        bold = linear_ticks(r, 6);
    }
    let light = if hi / lo > 3.0 && d1 - d0 <= 30 {
        gen(&all)
    } else {
        Vec::new()
    };
    (bold, light)
}

/// "Nice" 1-2-5 step ticks inside `r`, at most about `max_n` of them.
fn linear_ticks(r: &Range<f64>, max_n: usize) -> Vec<f64> {
    let span = r.end - r.start;
    if !(span > 0.0 && span.is_finite()) || max_n == 0 {
        return vec![r.start];
    }
    let raw = span / max_n as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let first = (r.start / step).ceil();
    let last = (r.end / step).floor();
    if !(first.is_finite() && last.is_finite()) || last - first > 1000.0 {
        return vec![r.start, r.end];
    }
    let (first, last) = (first as i64, last as i64);
    (first..=last).map(|k| k as f64 * step).collect()
}

/// Phase ticks at multiples of 15, 45, 90, 180, 360, ... degrees.
fn phase_ticks(r: &Range<f64>) -> Vec<f64> {
    let span = r.end - r.start;
    let mut step = 15.0;
    for s in [15.0, 45.0, 90.0, 180.0] {
        step = s;
        if span / s <= 8.0 {
            break;
        }
    }
    while span / step > 8.0 {
        step *= 2.0;
    }
    let first = (r.start / step).ceil() as i64;
    let last = (r.end / step).floor() as i64;
    let ticks: Vec<f64> = (first..=last).map(|k| k as f64 * step).collect();
    if ticks.len() < 2 {
        linear_ticks(r, 6)
    } else {
        ticks
    }
}

/// Formatter for the given ticks: fixed-point with as many decimals as the
/// tick spacing needs, or, for very large/small values, scientific notation
/// with one exponent shared by all ticks (e.g. `0.8e-5`, `1.0e-5`).
fn tick_formatter(ticks: &[f64]) -> impl Fn(&f64) -> String {
    let step = ticks
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .fold(f64::INFINITY, f64::min);
    let step = if step.is_finite() && step > 0.0 {
        step
    } else {
        ticks.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1.0)
    };
    let max_abs = ticks.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let scientific = max_abs >= 1e6 || step < 1e-3;
    let step_exp = step.log10().floor();
    let decimals = (-step_exp).clamp(0.0, 12.0) as usize;
    let exp = if max_abs > 0.0 {
        max_abs.log10().floor()
    } else {
        0.0
    };
    let sci_decimals = (exp - step_exp).clamp(0.0, 12.0) as usize;
    move |v: &f64| {
        let v = *v;
        let is_zero = v.abs() < step * 1e-6;
        match (scientific, is_zero) {
            (true, true) => "0".to_string(),
            (true, false) => format!("{:.sci_decimals$}e{exp}", v / 10f64.powf(exp)),
            (false, true) => format!("{:.decimals$}", 0.0),
            (false, false) => format!("{v:.decimals$}"),
        }
    }
}

/// Formats an axis tick value with up to six significant digits, trimming
/// trailing zeros (e.g. `0.2`, `50`, `1000`).
fn fmt_tick(v: f64) -> String {
    fmt_sig(v, 6)
}

/// Formats `v` with `sig` significant digits, trimming trailing zeros.
fn fmt_sig(v: f64, sig: i32) -> String {
    if v == 0.0 || !v.is_finite() {
        return if v.is_finite() {
            "0".to_string()
        } else {
            v.to_string()
        };
    }
    let decimals = (sig - 1 - v.abs().log10().floor() as i32).clamp(0, 15) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;
    use std::fs;

    /// Two-mode compliance `x/i` of a flexure stage in m/A: a main mode near
    /// 71 Hz and a weaker one near 420 Hz, with an optional dead time.
    fn stage_response(f: f64, delay_s: f64) -> (f64, f64) {
        let w = 2.0 * PI * f;
        let mode = |k: f64, m: f64, zeta: f64, gain: f64| {
            let c = 2.0 * zeta * (k * m).sqrt();
            let (re, im) = (k - m * w * w, c * w);
            let d = re * re + im * im;
            (gain * re / d, -gain * im / d)
        };
        let a = mode(2.0e4, 0.1, 0.02, 5.0);
        let b = mode(3.0e5, 0.043, 0.01, 0.6);
        let (re, im) = (a.0 + b.0, a.1 + b.1);
        let mag = re.hypot(im);
        let phase = im.atan2(re) - w * delay_s;
        (mag, phase.to_degrees())
    }

    fn unwrap_deg(p: &mut [f64]) {
        for i in 1..p.len() {
            while p[i] - p[i - 1] > 180.0 {
                p[i] -= 360.0;
            }
            while p[i] - p[i - 1] < -180.0 {
                p[i] += 360.0;
            }
        }
    }

    fn log_grid(n: usize, f0: f64, f1: f64) -> Vec<f64> {
        (0..n)
            .map(|i| f0 * (f1 / f0).powf(i as f64 / (n - 1) as f64))
            .collect()
    }

    struct Example {
        f: Vec<f64>,
        mag: Vec<f64>,
        phase: Vec<f64>,
        coh: Vec<f64>,
        fm: Vec<f64>,
        mag_m: Vec<f64>,
        phase_m: Vec<f64>,
    }

    fn example() -> Example {
        let f = log_grid(200, 1.0, 1000.0);
        let mut mag = Vec::new();
        let mut phase = Vec::new();
        let mut coh = Vec::new();
        for (i, &fi) in f.iter().enumerate() {
            let (m, p) = stage_response(fi, 2e-4);
            // Deterministic "measurement noise" growing with frequency.
            let noise = 0.08 * (fi / 1000.0).sqrt() * (i as f64 * 2.3).sin();
            mag.push(m * (1.0 + noise));
            phase.push(p + 10.0 * noise);
            let dip = (-((fi.ln() - 130f64.ln()) / 0.08).powi(2)).exp();
            coh.push((0.98 - 0.5 * (fi / 1000.0).powi(2) - 0.6 * dip).clamp(0.0, 1.0));
        }
        unwrap_deg(&mut phase);
        let fm = log_grid(600, 0.8, 1200.0);
        let (mut mag_m, mut phase_m): (Vec<f64>, Vec<f64>) =
            fm.iter().map(|&fi| stage_response(fi, 2e-4)).unzip();
        unwrap_deg(&mut phase_m);
        mag_m.iter_mut().for_each(|m| *m *= 1.05);
        Example {
            f,
            mag,
            phase,
            coh,
            fm,
            mag_m,
            phase_m,
        }
    }

    fn bode<'a>(e: &'a Example, markers: &'a [f64]) -> BodePlot<'a> {
        BodePlot {
            title: "X axis compliance, chirp 1–1000 Hz",
            measured: BodeSeries {
                label: "measured",
                frequency_hz: &e.f,
                magnitude: &e.mag,
                phase_deg: &e.phase,
            },
            coherence: &e.coh,
            model: Some(BodeSeries {
                label: "lumped model",
                frequency_hz: &e.fm,
                magnitude: &e.mag_m,
                phase_deg: &e.phase_m,
            }),
            markers_hz: markers,
        }
    }

    /// Reads width and height from the PNG signature + IHDR chunk.
    fn png_size(path: &Path) -> (u32, u32) {
        let bytes = fs::read(path).unwrap();
        assert!(bytes.len() > 24, "PNG too short");
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "not a PNG signature");
        assert_eq!(&bytes[12..16], b"IHDR");
        let w = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
        let h = u32::from_be_bytes(bytes[20..24].try_into().unwrap());
        (w, h)
    }

    fn dir_entries(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn plot_bode_writes_1400x1000_png() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bode.png");
        let e = example();
        write_bode_png(&path, Existing::Refuse, &bode(&e, &[70.9, 420.0])).unwrap();
        assert_eq!(png_size(&path), (1400, 1000));
        // Nothing but the final file is left behind.
        assert_eq!(dir_entries(dir.path()), vec!["bode.png".to_string()]);
    }

    #[test]
    fn plot_bode_replaces_an_existing_file_only_with_overwrite() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bode.png");
        fs::write(&path, b"old").unwrap();
        let e = example();
        let err = write_bode_png(&path, Existing::Refuse, &bode(&e, &[])).unwrap_err();
        assert!(matches!(err, PlotError::Io { .. }), "{err:?}");
        assert_eq!(fs::read(&path).unwrap(), b"old");
        write_bode_png(&path, Existing::Replace, &bode(&e, &[])).unwrap();
        assert_eq!(png_size(&path), (1400, 1000));
        assert_eq!(dir_entries(dir.path()), vec!["bode.png".to_string()]);
    }

    #[test]
    fn plot_bode_survives_nan_zero_and_negative_points() {
        let dir = tempfile::tempdir().unwrap();
        let e = example();
        let mut mag = e.mag.clone();
        let mut phase = e.phase.clone();
        let mut coh = e.coh.clone();
        let mut f = e.f.clone();
        mag[10] = 0.0;
        mag[11] = -1.0;
        mag[50] = f64::NAN;
        mag[120] = f64::INFINITY;
        phase[60] = f64::NAN;
        phase[61] = f64::NEG_INFINITY;
        coh[70] = f64::NAN;
        f[0] = 0.0; // DC bin: no place on a log axis
        f[199] = f64::NAN;
        let plot = BodePlot {
            title: "NaN and zero points",
            measured: BodeSeries {
                label: "measured",
                frequency_hz: &f,
                magnitude: &mag,
                phase_deg: &phase,
            },
            coherence: &coh,
            model: None,
            markers_hz: &[f64::NAN, -5.0, 1e9, 70.9],
        };
        let path = dir.path().join("nan.png");
        write_bode_png(&path, Existing::Refuse, &plot).unwrap();
        assert_eq!(png_size(&path), (1400, 1000));
    }

    #[test]
    fn plot_bode_degenerate_inputs_do_not_panic() {
        let dir = tempfile::tempdir().unwrap();
        let one = [100.0];
        // (frequency, magnitude, phase, coherence)
        type Case = (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>);
        let cases: Vec<Case> = vec![
            // Single point.
            (vec![100.0], vec![1e-4], vec![-90.0], vec![0.9]),
            // All-equal values on a real grid.
            (
                log_grid(20, 1.0, 100.0),
                vec![1e-4; 20],
                vec![-90.0; 20],
                vec![1.0; 20],
            ),
            // All-equal frequencies.
            (vec![50.0; 5], vec![1e-3; 5], vec![0.0; 5], vec![0.5; 5]),
            // Nothing valid at all.
            (
                vec![f64::NAN; 3],
                vec![0.0; 3],
                vec![f64::NAN; 3],
                vec![f64::NAN; 3],
            ),
            // Empty.
            (vec![], vec![], vec![], vec![]),
            // Narrow range without a decade or 1-2-5 tick inside.
            (
                vec![101.0, 103.0, 107.0],
                vec![1e-4, 2e-4, 3e-4],
                vec![1.0, 2.0, 3.0],
                vec![1.0; 3],
            ),
        ];
        for (i, (f, m, p, c)) in cases.iter().enumerate() {
            let plot = BodePlot {
                title: "",
                measured: BodeSeries {
                    label: "measured",
                    frequency_hz: f,
                    magnitude: m,
                    phase_deg: p,
                },
                coherence: c,
                model: Some(BodeSeries {
                    label: "model",
                    frequency_hz: &one,
                    magnitude: &[2e-4],
                    phase_deg: &[-45.0],
                }),
                markers_hz: &one,
            };
            let path = dir.path().join(format!("case{i}.png"));
            write_bode_png(&path, Existing::Refuse, &plot)
                .unwrap_or_else(|e| panic!("case {i}: {e}"));
            assert_eq!(png_size(&path), (1400, 1000), "case {i}");
        }
    }

    #[test]
    fn plot_missing_directory_is_an_error_naming_the_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("no-such-dir").join("bode.png");
        let e = example();
        let err = write_bode_png(&path, Existing::Refuse, &bode(&e, &[])).unwrap_err();
        assert!(matches!(err, PlotError::Io { .. }), "{err:?}");
        let msg = err.to_string();
        assert!(msg.contains(&path.display().to_string()), "{msg}");
        assert!(msg.contains("does not exist"), "{msg}");
        assert!(!path.exists());

        let err =
            write_time_png(&path, Existing::Refuse, "t", &[TimePanel::default()]).unwrap_err();
        assert!(err.to_string().contains(&path.display().to_string()));
    }

    #[test]
    fn plot_mismatched_lengths_are_rejected() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.png");
        let e = example();
        let mut plot = bode(&e, &[]);
        plot.coherence = &e.coh[1..];
        let err = write_bode_png(&path, Existing::Refuse, &plot).unwrap_err();
        assert!(matches!(err, PlotError::InvalidData { .. }), "{err:?}");
        assert!(err.to_string().contains("coherence"));

        let mut plot = bode(&e, &[]);
        plot.model.as_mut().unwrap().phase_deg = &e.phase_m[..3];
        let err = write_bode_png(&path, Existing::Refuse, &plot).unwrap_err();
        assert!(err.to_string().contains("lumped model"), "{err}");

        let t = [0.0, 1.0];
        let panel = TimePanel {
            y_label: "y",
            series: vec![("s", &t[..], &t[..1])],
        };
        let err = write_time_png(&path, Existing::Refuse, "", &[panel]).unwrap_err();
        assert!(matches!(err, PlotError::InvalidData { .. }), "{err:?}");
        assert!(write_time_png(&path, Existing::Refuse, "", &[]).is_err());
        assert!(!path.exists());
    }

    fn step_example() -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
        let t: Vec<f64> = (0..2000).map(|i| i as f64 * 1e-4).collect();
        let r: Vec<f64> = t
            .iter()
            .map(|&t| if t >= 0.02 { 10.0 } else { 0.0 })
            .collect();
        let y: Vec<f64> = t
            .iter()
            .map(|&t| {
                if t < 0.02 {
                    0.0
                } else {
                    let s = t - 0.02;
                    10.0 * (1.0 - (-s / 0.004).exp() * (2.0 * PI * 120.0 * s).cos())
                }
            })
            .collect();
        let u: Vec<f64> = y
            .iter()
            .zip(&r)
            .map(|(y, r)| 0.05 * (r - y) + 0.002 * r)
            .collect();
        (t, r, y, u)
    }

    #[test]
    fn plot_time_writes_png() {
        let dir = tempfile::tempdir().unwrap();
        let (t, r, y, mut u) = step_example();
        u[500] = f64::NAN;
        let panels = [
            TimePanel {
                y_label: "Position [µm]",
                series: vec![("reference", &t[..], &r[..]), ("measured", &t[..], &y[..])],
            },
            TimePanel {
                y_label: "Current [A]",
                series: vec![("", &t[..], &u[..])],
            },
        ];
        let path = dir.path().join("step.png");
        write_time_png(&path, Existing::Refuse, "Closed-loop step", &panels).unwrap();
        assert_eq!(png_size(&path), (1400, 1000));

        // Many panels grow the figure; empty and constant panels are fine.
        let c = vec![3.0; t.len()];
        let mut many = vec![TimePanel::default(); 4];
        many.push(TimePanel {
            y_label: "const",
            series: vec![("c", &t[..], &c[..])],
        });
        write_time_png(&path, Existing::Replace, "", &many).unwrap();
        assert_eq!(png_size(&path), (1400, 1600));
    }

    #[test]
    fn plot_tick_helpers() {
        assert_eq!(log_ticks(&(1.0..1000.0)).0, vec![1.0, 10.0, 100.0, 1000.0]);
        let (bold, _) = log_ticks(&(20.0..80.0));
        assert_eq!(bold.len(), 7, "{bold:?}");
        let (bold, _) = log_ticks(&(5.0..300.0));
        assert_eq!(bold, vec![5.0, 10.0, 20.0, 50.0, 100.0, 200.0]);
        assert!(!log_ticks(&(101.0..107.0)).0.is_empty());
        assert_eq!(
            phase_ticks(&(-200.0..10.0)),
            vec![-180.0, -135.0, -90.0, -45.0, 0.0]
        );
        assert_eq!(fmt_tick(0.30000000000000004), "0.3");
        assert_eq!(fmt_tick(1000.0), "1000");
        assert_eq!(fmt_sig(70.9, 4), "70.9");
        assert_eq!(fmt_sig(1234.56, 4), "1235");
        let r = padded_range(&[5.0, 5.0], 0.0, 0.0, 0.0..1.0);
        assert!(r.start < 5.0 && r.end > 5.0);
        let r = padded_range(&[0.0], 0.05, 0.0, 0.0..1.0);
        assert!(r.start < 0.0 && r.end > 0.0);
        let f = tick_formatter(&[0.0, 0.2, 0.4]);
        assert_eq!(f(&0.4), "0.4");
        let f = tick_formatter(&[0.0, 5e-6, 1e-5]);
        assert_eq!(f(&5e-6), "0.5e-5");
        assert_eq!(f(&1e-5), "1.0e-5");
        assert_eq!(f(&0.0), "0");
    }

    /// Writes `/tmp/bode-example.png` and `/tmp/time-example.png` for visual
    /// inspection: `cargo test --lib plot -- --ignored`.
    #[test]
    #[ignore]
    fn plot_write_examples_to_tmp() {
        let e = example();
        write_bode_png(
            Path::new("/tmp/bode-example.png"),
            Existing::Replace,
            &bode(&e, &[70.9, 420.0]),
        )
        .unwrap();
        let (t, r, y, u) = step_example();
        let panels = [
            TimePanel {
                y_label: "Position [µm]",
                series: vec![("reference", &t[..], &r[..]), ("measured", &t[..], &y[..])],
            },
            TimePanel {
                y_label: "Current [A]",
                series: vec![("coil current", &t[..], &u[..])],
            },
        ];
        write_time_png(
            Path::new("/tmp/time-example.png"),
            Existing::Replace,
            "Closed-loop step, X axis",
            &panels,
        )
        .unwrap();
    }
}
