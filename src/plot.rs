//! PNG plots of identification and closed-loop results.
//!
//! Three kinds of figure are supported:
//!
//! * [`write_bode_png`]: a Bode figure, 1400 px wide. Its top 1000 px hold
//!   three stacked panels sharing a logarithmic frequency axis: magnitude
//!   in dB re 1 m/A, phase in degrees and coherence, with an optional model
//!   overlay and vertical markers at identified resonances. Points whose
//!   coherence is below [`MIN_COHERENCE`] are drawn faint (and left out of
//!   the axis ranges). With a [`PairZoom`] a further 650 px hold two panels
//!   zoomed on the closely spaced pair, with the net phase and the
//!   CMP-CNMP verdict written above them, or the reason no pair was
//!   resolved.
//! * [`write_step_png`]: a closed-loop step response, the whole record
//!   (position, command, error) above and the transient zoomed below, with
//!   the settling band and the rise, settling and overshoot marked.
//! * [`write_time_png`]: one or more stacked time-series panels sharing a
//!   time axis.
//!
//! Legends sit in strips above the panels, outside the plotted area, so
//! they never hide a trace. Rendering uses the plotters bitmap backend with
//! an embedded DejaVu Sans font, so no system font libraries are needed.
//! Non-finite samples (and non-positive magnitudes or frequencies, which
//! have no logarithm) are skipped and break the line instead of failing.
//! Lines are drawn segment by segment, and time series are first reduced to
//! the first, lowest, highest and last sample of each pixel column (the
//! same picture): plotters fills a wide polyline as one polygon, which
//! leaves holes where a dense trace turns back on itself. The image is
//! drawn in memory, encoded to a hidden temporary file next to the target
//! and renamed to it when complete, by the rules of [`crate::outputs`]: a
//! reader never sees a half-written PNG, and an existing file is replaced
//! only with [`Existing::Replace`] (`--overwrite`), never when it is not a
//! regular file.

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

use crate::control::step_metrics::{StepEvents, StepMetrics, SETTLING_BAND, SMOOTHING_S};
use crate::ident::frf::PairVerdict;
pub use crate::ident::frf::MIN_COHERENCE;
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

impl<'a> BodeSeries<'a> {
    /// The H1 estimate `frf` as a figure's measured curve, labelled
    /// "measured (H1)".
    pub fn measured_h1(frf: &'a crate::ident::frf::Frf) -> Self {
        Self {
            label: "measured (H1)",
            frequency_hz: &frf.frequency_hz,
            magnitude: &frf.magnitude_m_per_a,
            phase_deg: &frf.phase_deg,
        }
    }
}

/// The zoom on the closely spaced pair of a Bode figure.
#[derive(Debug, Clone, Copy)]
pub enum PairZoom<'a> {
    /// The pair the FRF analysis found
    /// ([`phase_test`](crate::ident::verdict::phase_test)).
    Resolved {
        /// Its modes, band, net phase and verdict.
        pair: PairVerdict,
        /// The measured phase at the two edges of `pair.band_hz`, degrees:
        /// the values whose difference is `pair.net_phase_deg`
        /// ([`Frf::phase_at_deg`](crate::ident::frf::Frf::phase_at_deg)).
        band_phase_deg: (f64, f64),
    },
    /// No pair was resolved; the panel shows why.
    Unresolved {
        /// The reason, e.g. from
        /// the phase test's reason ([`crate::ident::verdict::PhaseTest`]).
        reason: &'a str,
    },
}

impl<'a> PairZoom<'a> {
    /// The zoom for `test`'s pair on the measured `frf`, or, when it found
    /// none, the panel with `reason` (e.g. [`PairZoom::reason_of`]).
    pub fn of(
        test: &crate::ident::verdict::PhaseTest,
        frf: &crate::ident::frf::Frf,
        reason: &'a str,
    ) -> Self {
        match &test.pair {
            Some(p) => PairZoom::Resolved {
                pair: *p,
                band_phase_deg: (frf.phase_at_deg(p.band_hz.0), frf.phase_at_deg(p.band_hz.1)),
            },
            None => PairZoom::Unresolved { reason },
        }
    }

    /// Why `test` resolved no pair, for the panel.
    pub fn reason_of(test: &crate::ident::verdict::PhaseTest) -> String {
        test.reason
            .clone()
            .unwrap_or_else(|| "no closely spaced pair was fitted".to_string())
    }
}

/// Magnitude (of `h`'s unit) and unwrapped phase (degrees) of the curve
/// `h`, the phase shifted by whole turns onto the branch of `reference_deg`
/// (the measured phase at the first grid point: both start near 0° or
/// −180°), so a model curve lies on the measurement in a Bode plot.
pub fn bode_curve(
    h: &[crate::ident::frf::C64],
    reference_deg: Option<f64>,
) -> (Vec<f64>, Vec<f64>) {
    let magnitude = h.iter().map(|h| h.norm()).collect();
    let mut phase: Vec<f64> = h.iter().map(|h| h.arg().to_degrees()).collect();
    crate::ident::frf::unwrap_deg(&mut phase);
    if let (Some(m0), Some(p0)) = (phase.first().copied(), reference_deg) {
        let shift = ((p0 - m0) / 360.0).round() * 360.0;
        phase.iter_mut().for_each(|p| *p += shift);
    }
    (magnitude, phase)
}

/// Everything shown in one Bode figure (see [`write_bode_png`]).
#[derive(Debug, Clone, Copy)]
pub struct BodePlot<'a> {
    /// Figure title, drawn above the panels (omitted when empty).
    pub title: &'a str,
    /// Measured frequency response, drawn as solid lines (faint where the
    /// coherence is below [`MIN_COHERENCE`]).
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
    /// The zoom on the closely spaced pair (`None`: no zoom section, and the
    /// figure is 1000 px high instead of 1650 px).
    pub pair: Option<PairZoom<'a>>,
}

/// A closed-loop step response with its metrics (see [`write_step_png`]).
/// All slices have one value per recorded sample.
#[derive(Debug, Clone, Copy)]
pub struct StepPlot<'a> {
    /// Figure title (omitted when empty).
    pub title: &'a str,
    /// Time of each sample, s.
    pub t_s: &'a [f64],
    /// Setpoint relative to the start position, µm.
    pub setpoint_um: &'a [f64],
    /// Probe reading relative to the start position, µm.
    pub position_um: &'a [f64],
    /// The reading the metrics are computed on (centred moving average over
    /// [`SMOOTHING_S`]), relative to the start position, µm.
    pub smoothed_um: &'a [f64],
    /// Coil current command, A.
    pub command_a: &'a [f64],
    /// The figures written on the plot
    /// ([`analyze_step`](crate::control::step_metrics::analyze_step)).
    pub metrics: &'a StepMetrics,
    /// Where they happen (sample indices), from the same analysis.
    pub events: &'a StepEvents,
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

/// Width of every figure, and height of the Bode figure's main panels, px.
const BODE_SIZE: (u32, u32) = (1400, 1000);
/// Height added to the Bode figure by the pair zoom, px.
const BODE_ZOOM_H: u32 = 650;
/// Size of the step figure, px.
const STEP_SIZE: (u32, u32) = (1400, 1700);
pub(crate) const FONT: &str = "sans-serif";
static FONT_BYTES: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

const TITLE_SIZE: f64 = 28.0;
const HEADER_SIZE: f64 = 20.0;
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
/// Height of one row of a legend strip, px.
const LEGEND_ROW_H: u32 = 24;

/// Colour of the measured FRF (coherence at or above [`MIN_COHERENCE`]).
pub const MEASURED_COLOR: RGBColor = RGBColor(31, 119, 180);
/// Colour of measured FRF points below [`MIN_COHERENCE`] (the measured
/// colour at 30 % on white).
pub const FAINT_COLOR: RGBColor = RGBColor(188, 214, 233);
const MODEL_COLOR: RGBColor = RGBColor(214, 39, 40);
/// Colour of the resonance markers and of the step instant.
pub const MARKER_COLOR: RGBColor = RGBColor(90, 90, 90);
const GRID_BOLD: RGBColor = RGBColor(200, 200, 200);
const GRID_LIGHT: RGBColor = RGBColor(232, 232, 232);
/// Shading of a zoomed window on the overview panels.
const ZOOM_SHADE: RGBColor = RGBColor(120, 120, 120);
const ZOOM_SHADE_ALPHA: f64 = 0.12;
const SETPOINT_COLOR: RGBColor = RGBColor(31, 119, 180);
const POSITION_COLOR: RGBColor = RGBColor(214, 39, 40);
/// The raw probe reading under its moving average in the zoom.
const POSITION_RAW_COLOR: RGBColor = RGBColor(240, 160, 160);
const SMOOTHED_COLOR: RGBColor = RGBColor(120, 20, 20);
/// Colour of the current command of the step figure.
pub const COMMAND_COLOR: RGBColor = RGBColor(44, 160, 44);
const ERROR_COLOR: RGBColor = RGBColor(31, 119, 180);
const BAND_COLOR: RGBColor = RGBColor(44, 160, 44);
const BAND_ALPHA: f64 = 0.18;
/// Colour of the rise-time markers (10 % and 90 % crossings).
pub const RISE_COLOR: RGBColor = RGBColor(148, 103, 189);
/// Colour of the settling-time marker (and of the coherence threshold).
pub const SETTLE_COLOR: RGBColor = RGBColor(255, 127, 14);
/// Colour of the overshoot marker.
pub const OVERSHOOT_COLOR: RGBColor = RGBColor(140, 86, 75);
const STEADY_COLOR: RGBColor = RGBColor(23, 190, 207);
const BAND_START_COLOR: RGBColor = RGBColor(44, 160, 44);
const BAND_END_COLOR: RGBColor = RGBColor(148, 103, 189);
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

/// Writes a Bode figure of `plot` as a PNG to `path`: 1400x1000 px, or
/// 1400x1650 px with a pair zoom.
///
/// Main panels from top to bottom: magnitude in dB re 1 m/A (20·log10 of
/// the linear m/A magnitude), unwrapped phase in degrees and coherence
/// (0..1.05, with the [`MIN_COHERENCE`] threshold dashed), all sharing a
/// logarithmic frequency axis. The axis spans the measured frequencies (the
/// model is clipped to that band); only if the measured series has no usable
/// band do the model frequencies widen it. Measured points with coherence
/// below [`MIN_COHERENCE`] (or not finite) are drawn in a faint colour and
/// do not set the axis ranges. Invalid points are skipped and break the
/// line.
///
/// The pair zoom ([`PairZoom::Resolved`]) shows magnitude and phase on a
/// linear frequency axis from `lower − d` to `upper + d`, `d = max(upper −
/// lower, 1 % of lower)`, with the grid points dotted, the two modes
/// marked, the phase at the band edges dashed, and above it the pair, its
/// band, the net phase and the verdict; the window is shaded on the main
/// panels. [`PairZoom::Unresolved`] draws the section with its reason.
///
/// The file is written to a temporary file in the same directory and renamed
/// into place (see [`crate::outputs`]).
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
    let size = if plot.pair.is_some() {
        (BODE_SIZE.0, BODE_SIZE.1 + BODE_ZOOM_H)
    } else {
        BODE_SIZE
    };
    write_png_atomically(path, existing, size, |root| draw_bode(root, plot))
}

/// Writes a closed-loop step response as a 1400x1700 px PNG to `path`.
///
/// The upper half shows the whole record on one time axis (s): setpoint and
/// probe reading (µm from the start position), the coil current command
/// (A) and the error `setpoint − position` (µm) with the steady-state window
/// shaded and its mean and σ written in the legend; the zoomed window is
/// shaded on the first two.
///
/// The lower half zooms on the transient, in ms since the step: from `pre`
/// before the step to `post` after it, `post = max(2 × settling time, 4 ×
/// rise time, 20 sample periods)` (to the end of the record when the
/// response never settled), `pre = post / 10` (at least two sample periods),
/// both bounded by the record. Its upper panel shows the setpoint, the raw
/// reading (light), the moving average the metrics are computed on (dark),
/// the ±[`SETTLING_BAND`] band around the final value, and labelled markers:
/// the 10 % and 90 % crossings (rise time), the settling instant and the
/// overshoot peak, with the values of `plot.metrics`. Its lower panel shows
/// the current command. Sampled signals (setpoint, command) are drawn as
/// held between samples (a staircase).
///
/// # Errors
///
/// [`PlotError::InvalidData`] if the slices differ in length or an event
/// index lies outside them; otherwise as for [`write_bode_png`].
pub fn write_step_png(
    path: &Path,
    existing: Existing,
    plot: &StepPlot<'_>,
) -> Result<(), PlotError> {
    let n = plot.t_s.len();
    for (name, v) in [
        ("setpoint_um", plot.setpoint_um),
        ("position_um", plot.position_um),
        ("smoothed_um", plot.smoothed_um),
        ("command_a", plot.command_a),
    ] {
        if v.len() != n {
            return Err(invalid(
                path,
                format!("{name} has {} samples but t_s has {n}", v.len()),
            ));
        }
    }
    let e = plot.events;
    let indices = [
        Some(e.step),
        e.rise_from,
        e.rise_to,
        e.settled,
        e.peak,
        Some(e.steady_state_from),
    ];
    if let Some(k) = indices.into_iter().flatten().find(|&k| k > n) {
        return Err(invalid(
            path,
            format!("step event at sample {k} but the record has {n} samples"),
        ));
    }
    write_png_atomically(path, existing, STEP_SIZE, |root| draw_step(root, plot))
}

/// Writes stacked time-series `panels` sharing one time axis (s) as a PNG to
/// `path`, with `title` above them (omitted when empty).
///
/// The image is 1400 px wide and 1000 px high for up to three panels, growing
/// by 300 px per additional panel (capped at 8000 px). Each panel gets its own y range (from its
/// data, with a margin) and a legend strip of its labelled series above it.
/// Non-finite samples are skipped and break the line.
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
// Shared pieces: axes, panels, curves, legends, labels

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
/// the x axis of the bottom panel and show only its grid. `margin_top` is
/// the space above the frame (for legends and labels).
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

/// The pixel columns (absolute) of the plotting area that [`panel_chart`]
/// builds on `area`, before it is built (for laying out labels).
fn plot_columns(area: &Area<'_>) -> (i32, i32) {
    let (x0, _) = area.get_base_pixel();
    let (w, _) = area.dim_in_pixel();
    let w = i32::try_from(w).unwrap_or(i32::MAX);
    let left = x0 + (MARGIN_LEFT + Y_LABEL_AREA) as i32;
    let right = (x0 + w - MARGIN_RIGHT as i32).max(left + 1);
    (left, right)
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

/// Samples as held from each sample time to the next (zero-order hold):
/// `(t_k, v_k), (t_{k+1}, v_k), (t_{k+1}, v_{k+1}), …`. A non-finite value
/// breaks the line for its period.
fn staircase(t: &[f64], v: &[f64]) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(2 * t.len());
    for k in 0..t.len().min(v.len()) {
        out.push((t[k], v[k]));
        if let Some(&next) = t.get(k + 1) {
            out.push((next, v[k]));
        }
    }
    out
}

/// Reduces a polyline whose x does not decrease to the first, lowest,
/// highest and last point of each of `columns` equal slices of `x_range`
/// (one per pixel column): the same picture with at most four points per
/// column.
fn decimate(pts: &[(f64, f64)], x_range: &Range<f64>, columns: usize) -> Vec<(f64, f64)> {
    let span = x_range.end - x_range.start;
    if pts.len() <= 4 * columns.max(1) || span.is_nan() || span <= 0.0 {
        return pts.to_vec();
    }
    let col = |x: f64| ((x - x_range.start) / span * columns as f64).floor() as i64;
    let mut out = Vec::with_capacity(4 * columns + 4);
    let mut i = 0;
    while i < pts.len() {
        let c = col(pts[i].0);
        let (mut lo, mut hi, mut j) = (i, i, i);
        while j < pts.len() && col(pts[j].0) == c {
            if pts[j].1 < pts[lo].1 {
                lo = j;
            }
            if pts[j].1 > pts[hi].1 {
                hi = j;
            }
            j += 1;
        }
        let mut keep = [i, lo, hi, j - 1];
        keep.sort_unstable();
        let mut last = usize::MAX;
        for k in keep {
            if k != last {
                out.push(pts[k]);
                last = k;
            }
        }
        i = j;
    }
    out
}

/// Draws a polyline segment by segment (a single point as a dot). A wide
/// polyline drawn in one piece is filled by plotters as one polygon, which
/// leaves holes where the trace turns back on itself.
fn draw_polyline<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    pts: &[(f64, f64)],
    color: RGBColor,
    width: u32,
) -> Result<(), BoxError> {
    match pts.len() {
        0 => {}
        1 => {
            chart.draw_series(std::iter::once(Circle::new(pts[0], 3, color.filled())))?;
        }
        _ => {
            let style = color.stroke_width(width);
            chart.draw_series(
                pts.windows(2)
                    .map(|w| PathElement::new(vec![w[0], w[1]], style)),
            )?;
        }
    }
    Ok(())
}

/// Draws `pts` (linear x) split at invalid points, clipped to `x_range` and
/// decimated to the panel's pixel columns.
fn draw_trace<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    pts: &[(f64, f64)],
    x_range: &Range<f64>,
    color: RGBColor,
    width: u32,
) -> Result<(), BoxError> {
    let (xs, _) = chart.plotting_area().get_pixel_range();
    let columns = usize::try_from(xs.end - xs.start).unwrap_or(1).max(1);
    for run in runs(pts, x_range, false) {
        draw_polyline(chart, &decimate(&run, x_range, columns), color, width)?;
    }
    Ok(())
}

/// Draws the runs of a curve, dashed or solid.
fn draw_runs<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    runs: &[Vec<(f64, f64)>],
    color: RGBColor,
    dashed: bool,
) -> Result<(), BoxError> {
    for run in runs {
        if dashed && run.len() > 1 {
            let style = color.stroke_width(LINE_WIDTH);
            chart.draw_series(DashedLineSeries::new(run.iter().copied(), 10, 6, style))?;
        } else {
            draw_polyline(chart, run, color, LINE_WIDTH)?;
        }
    }
    Ok(())
}

/// A vertical dashed line across `y_range` at `x`.
fn vline<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    x: f64,
    y_range: &Range<f64>,
    color: RGBColor,
    width: u32,
) -> Result<(), BoxError> {
    chart.draw_series(DashedLineSeries::new(
        [(x, y_range.start), (x, y_range.end)],
        8,
        5,
        color.stroke_width(width),
    ))?;
    Ok(())
}

/// A horizontal dashed line across `x_range` at `y`.
fn hline<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    y: f64,
    x_range: &Range<f64>,
    color: RGBColor,
) -> Result<(), BoxError> {
    chart.draw_series(DashedLineSeries::new(
        [(x_range.start, y), (x_range.end, y)],
        8,
        5,
        color.stroke_width(LINE_WIDTH),
    ))?;
    Ok(())
}

/// A translucent band from `x` to `x` and `y` to `y` (any order).
fn shade<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    x: (f64, f64),
    y: (f64, f64),
    color: RGBColor,
    alpha: f64,
) -> Result<(), BoxError> {
    let (x0, x1) = (x.0.min(x.1), x.0.max(x.1));
    let (y0, y1) = (y.0.min(y.1), y.0.max(y.1));
    chart.draw_series(std::iter::once(Rectangle::new(
        [(x0, y1), (x1, y0)],
        color.mix(alpha).filled(),
    )))?;
    Ok(())
}

/// How a legend entry is drawn before its text.
#[derive(Debug, Clone, Copy)]
enum Swatch {
    /// A solid line of this width.
    Line(RGBColor, u32),
    /// A dashed line.
    Dashed(RGBColor),
    /// A translucent patch.
    Fill(RGBColor, f64),
    /// Text only.
    Text,
}

struct Entry {
    text: String,
    swatch: Swatch,
}

fn entry(text: impl Into<String>, swatch: Swatch) -> Entry {
    Entry {
        text: text.into(),
        swatch,
    }
}

const SWATCH_W: i32 = 30;

fn legend_style() -> TextStyle<'static> {
    TextStyle::from((FONT, LEGEND_SIZE).into_font()).pos(Pos::new(HPos::Left, VPos::Center))
}

/// Lays `entries` out left to right in rows `width` px wide: the x offset
/// and row of each, and the number of rows.
fn legend_layout(
    area: &Area<'_>,
    entries: &[Entry],
    width: i32,
) -> Result<(Vec<(i32, usize)>, usize), BoxError> {
    let style = legend_style();
    let mut out = Vec::with_capacity(entries.len());
    let (mut x, mut row) = (0, 0);
    for e in entries {
        let (tw, _) = area.estimate_text_size(&e.text, &style)?;
        let sw = if matches!(e.swatch, Swatch::Text) {
            0
        } else {
            SWATCH_W + 6
        };
        let w = sw + i32::try_from(tw)?;
        if x > 0 && x + w > width {
            x = 0;
            row += 1;
        }
        out.push((x, row));
        x += w + 24;
    }
    let rows = if entries.is_empty() { 0 } else { row + 1 };
    Ok((out, rows))
}

/// Height of the legend strip of `entries` above a panel built on `area`.
fn legend_height(area: &Area<'_>, entries: &[Entry]) -> Result<u32, BoxError> {
    let (l, r) = plot_columns(area);
    let (_, rows) = legend_layout(area, entries, r - l)?;
    Ok(u32::try_from(rows)? * LEGEND_ROW_H)
}

/// Draws the legend strip of `entries` with its top-left corner at
/// (`x0`, `y_top`) (absolute pixels), wrapping at `width`.
fn draw_legend(
    root: &Area<'_>,
    entries: &[Entry],
    x0: i32,
    width: i32,
    y_top: i32,
) -> Result<(), BoxError> {
    let (pos, _) = legend_layout(root, entries, width)?;
    let row_h = i32::try_from(LEGEND_ROW_H)?;
    for (e, (dx, row)) in entries.iter().zip(pos) {
        let x = x0 + dx;
        let y = y_top + i32::try_from(row)? * row_h + row_h / 2;
        let seg = vec![(x, y), (x + SWATCH_W, y)];
        match e.swatch {
            Swatch::Line(c, w) => root.draw(&PathElement::new(seg, c.stroke_width(w)))?,
            Swatch::Dashed(c) => {
                root.draw(&DashedPathElement::new(seg, 8, 5, c.stroke_width(2)))?;
            }
            Swatch::Fill(c, a) => root.draw(&Rectangle::new(
                [(x, y - 7), (x + SWATCH_W, y + 7)],
                c.mix(a).filled(),
            ))?,
            Swatch::Text => {}
        }
        let tx = if matches!(e.swatch, Swatch::Text) {
            x
        } else {
            x + SWATCH_W + 6
        };
        root.draw(&Text::new(e.text.clone(), (tx, y), legend_style()))?;
    }
    Ok(())
}

/// Draws the legend strip of `entries` at the top of the space reserved
/// above the frame of `chart` (built on `area`).
fn panel_legend<X: Ranged<ValueType = f64>>(
    root: &Area<'_>,
    area: &Area<'_>,
    chart: &Chart<'_, '_, X>,
    entries: &[Entry],
) -> Result<(), BoxError> {
    let (xs, _) = chart.plotting_area().get_pixel_range();
    let (_, top) = area.get_base_pixel();
    draw_legend(root, entries, xs.start, xs.end - xs.start, top + 2)
}

/// A label placed above the frame of a panel, at the x of its marker.
struct MarkerLabel {
    x: f64,
    text: String,
    color: RGBColor,
    row: usize,
}

fn marker_style(color: RGBColor) -> TextStyle<'static> {
    let mut style = TextStyle::from((FONT, MARKER_LABEL_SIZE).into_font())
        .pos(Pos::new(HPos::Center, VPos::Bottom));
    style.color = color.to_backend_color();
    style
}

/// Assigns marker labels `(x, text, colour)` to rows so that labels in a
/// row do not overlap; `x_px` maps x to an (approximate) pixel column.
/// Returns the labels and the number of rows.
fn layout_marker_labels(
    area: &Area<'_>,
    items: Vec<(f64, String, RGBColor)>,
    x_px: impl Fn(f64) -> i32,
) -> Result<(Vec<MarkerLabel>, usize), BoxError> {
    let mut sorted = items;
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut row_right_edges: Vec<i32> = Vec::new();
    let mut labels = Vec::new();
    for (x, text, color) in sorted {
        let (tw, _) = area.estimate_text_size(&text, &marker_style(color))?;
        let tw = i32::try_from(tw)?;
        let left = x_px(x) - tw / 2;
        let row = match row_right_edges.iter().position(|&r| left > r + 8) {
            Some(r) => r,
            None => {
                row_right_edges.push(i32::MIN);
                row_right_edges.len() - 1
            }
        };
        row_right_edges[row] = left + tw;
        labels.push(MarkerLabel {
            x,
            text,
            color,
            row,
        });
    }
    Ok((labels, row_right_edges.len()))
}

/// Height of one row of marker labels in pixels.
fn marker_row_height() -> i32 {
    MARKER_LABEL_SIZE as i32 + 4
}

/// Draws the marker labels above the frame of `chart`, centred on the lines
/// (kept inside the plotting columns).
fn draw_marker_labels<X: Ranged<ValueType = f64>>(
    root: &Area<'_>,
    chart: &Chart<'_, '_, X>,
    labels: &[MarkerLabel],
    y_top: f64,
) -> Result<(), BoxError> {
    let (xs, _) = chart.plotting_area().get_pixel_range();
    for l in labels {
        let style = marker_style(l.color);
        let (px, py) = chart.backend_coord(&(l.x, y_top));
        let (tw, _) = root.estimate_text_size(&l.text, &style)?;
        let half = i32::try_from(tw)? / 2 + 2;
        let x = px.clamp(xs.start + half, (xs.end - half).max(xs.start + half));
        let y = py - 4 - i32::try_from(l.row)? * marker_row_height();
        root.draw(&Text::new(l.text.clone(), (x, y), style))?;
    }
    Ok(())
}

/// Draws lines of text left-aligned at the plot columns of `area`, from its
/// top.
fn header_lines(root: &Area<'_>, area: &Area<'_>, lines: &[String]) -> Result<(), BoxError> {
    let (left, _) = plot_columns(area);
    let (_, top) = area.get_base_pixel();
    let style =
        TextStyle::from((FONT, HEADER_SIZE).into_font()).pos(Pos::new(HPos::Left, VPos::Top));
    for (i, line) in lines.iter().enumerate() {
        let y = top + i32::try_from(i)? * (HEADER_SIZE as i32 + 8);
        root.draw(&Text::new(line.clone(), (left, y), style.clone()))?;
    }
    Ok(())
}

/// Height of `n` header lines, px.
fn header_height(n: usize) -> u32 {
    u32::try_from(n).unwrap_or(0) * (HEADER_SIZE as u32 + 8) + 6
}

/// The values of `pts` whose x lies in `x_range`.
fn values_in<'p>(pts: &'p [(f64, f64)], x_range: &Range<f64>) -> impl Iterator<Item = f64> + 'p {
    let r = x_range.clone();
    pts.iter()
        .filter(move |p| p.0 >= r.start && p.0 <= r.end && p.1.is_finite())
        .map(|p| p.1)
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

/// The curves of a Bode figure in plot units.
struct BodeCurves {
    meas_db: Vec<(f64, f64)>,
    meas_phase: Vec<(f64, f64)>,
    coh: Vec<(f64, f64)>,
    /// Coherence at or above [`MIN_COHERENCE`] (NaN is not).
    good: Vec<bool>,
    model_db: Vec<(f64, f64)>,
    model_phase: Vec<(f64, f64)>,
}

impl BodeCurves {
    fn new(plot: &BodePlot<'_>) -> Self {
        let db = |f: &[f64], m: &[f64]| -> Vec<(f64, f64)> {
            f.iter().zip(m).map(|(&f, &m)| (f, to_db(m))).collect()
        };
        let meas = &plot.measured;
        let (model_db, model_phase) = match &plot.model {
            Some(m) => (
                db(m.frequency_hz, m.magnitude),
                pairs(m.frequency_hz, m.phase_deg),
            ),
            None => (Vec::new(), Vec::new()),
        };
        Self {
            meas_db: db(meas.frequency_hz, meas.magnitude),
            meas_phase: pairs(meas.frequency_hz, meas.phase_deg),
            coh: pairs(meas.frequency_hz, plot.coherence),
            good: plot.coherence.iter().map(|&c| c >= MIN_COHERENCE).collect(),
            model_db,
            model_phase,
        }
    }

    /// The y values inside `x_range` that set an axis: the measured points
    /// of good coherence (all of them if none is good) and the model's.
    fn y_values(
        meas: &[(f64, f64)],
        good: &[bool],
        model: &[(f64, f64)],
        x: &Range<f64>,
    ) -> Vec<f64> {
        let inside = |p: &(f64, f64)| p.0 >= x.start && p.0 <= x.end && p.1.is_finite();
        let mut v: Vec<f64> = meas
            .iter()
            .zip(good)
            .filter(|(p, g)| **g && inside(p))
            .map(|(p, _)| p.1)
            .collect();
        if v.is_empty() {
            v = meas.iter().filter(|p| inside(p)).map(|p| p.1).collect();
        }
        v.extend(model.iter().filter(|p| inside(p)).map(|p| p.1));
        v
    }
}

/// Draws a measured curve: all valid points faint, then the runs of good
/// coherence on top in the measured colour; `dots` marks each grid point.
fn draw_measured<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    pts: &[(f64, f64)],
    good: &[bool],
    x_range: &Range<f64>,
    log_x: bool,
    dots: bool,
) -> Result<(), BoxError> {
    for run in runs(pts, x_range, log_x) {
        draw_polyline(chart, &run, FAINT_COLOR, LINE_WIDTH)?;
    }
    let solid: Vec<(f64, f64)> = pts
        .iter()
        .zip(good)
        .map(|(p, g)| if *g { *p } else { (p.0, f64::NAN) })
        .collect();
    for run in runs(&solid, x_range, log_x) {
        draw_polyline(chart, &run, MEASURED_COLOR, LINE_WIDTH)?;
    }
    if dots {
        let inside = |p: &(f64, f64)| p.0 >= x_range.start && p.0 <= x_range.end && p.1.is_finite();
        chart.draw_series(
            pts.iter()
                .zip(good)
                .filter(|(p, _)| inside(p))
                .map(|(p, g)| {
                    Circle::new(
                        *p,
                        3,
                        if *g { MEASURED_COLOR } else { FAINT_COLOR }.filled(),
                    )
                }),
        )?;
    }
    Ok(())
}

/// The linear frequency window of the pair zoom (see [`write_bode_png`]),
/// kept inside `x_range` when the pair is.
fn pair_window(pair: &PairVerdict, x_range: &Range<f64>) -> Range<f64> {
    let (lo, hi) = (
        pair.lower_hz.min(pair.upper_hz),
        pair.lower_hz.max(pair.upper_hz),
    );
    let d = (hi - lo).max(0.01 * lo.abs());
    let w = (lo - d)..(hi + d);
    let clipped = w.start.max(x_range.start)..w.end.min(x_range.end);
    if clipped.start < lo && clipped.end > hi {
        clipped
    } else if w.start < w.end && w.start.is_finite() && w.end.is_finite() {
        w
    } else {
        x_range.clone()
    }
}

fn draw_bode(root: &Area<'_>, plot: &BodePlot<'_>) -> Result<(), BoxError> {
    let (main, zoom) = if plot.pair.is_some() {
        let (a, b) = root.split_vertically(BODE_SIZE.1);
        (a, Some(b))
    } else {
        (root.clone(), None)
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
    let curves = BodeCurves::new(plot);
    let window = match plot.pair {
        Some(PairZoom::Resolved { pair, .. }) => Some(pair_window(&pair, &x_range)),
        _ => None,
    };
    draw_bode_main(root, &main, plot, &curves, &x_range, window.as_ref())?;
    if let (Some(area), Some(pz)) = (zoom, plot.pair) {
        match (pz, window) {
            (
                PairZoom::Resolved {
                    pair,
                    band_phase_deg,
                },
                Some(w),
            ) => {
                draw_pair_zoom(root, &area, plot, &curves, &pair, band_phase_deg, &w)?;
            }
            (PairZoom::Unresolved { reason }, _) => draw_no_pair(root, &area, reason)?,
            _ => {}
        }
    }
    Ok(())
}

fn draw_bode_main(
    root: &Area<'_>,
    area: &Area<'_>,
    plot: &BodePlot<'_>,
    c: &BodeCurves,
    x_range: &Range<f64>,
    window: Option<&Range<f64>>,
) -> Result<(), BoxError> {
    let outer = area.margin(8, 0, 0, 0);
    let body = if plot.title.is_empty() {
        outer
    } else {
        outer.titled(plot.title, (FONT, TITLE_SIZE))?
    };
    let meas = &plot.measured;
    let model = plot.model.as_ref();
    let (x_bold, x_light) = log_ticks(x_range);

    let clip = |pts: &[(f64, f64)]| runs(pts, x_range, true);
    let (model_db, model_phase) = (clip(&c.model_db), clip(&c.model_phase));
    let db_vals = BodeCurves::y_values(&c.meas_db, &c.good, &c.model_db, x_range);
    let phase_vals = BodeCurves::y_values(&c.meas_phase, &c.good, &c.model_phase, x_range);
    let db_range = padded_range(&db_vals, 0.06, 10.0, -100.0..0.0);
    let phase_range = padded_range(&phase_vals, 0.06, 45.0, -180.0..0.0);
    let coh_range =
        values_in(&c.coh, x_range).fold(0.0f64..1.05f64, |r, v| r.start.min(v)..r.end.max(v));

    let markers: Vec<f64> = plot
        .markers_hz
        .iter()
        .copied()
        .filter(|&f| f.is_finite() && f >= x_range.start && f <= x_range.end)
        .collect();
    let mut entries = vec![
        entry(meas.label, Swatch::Line(MEASURED_COLOR, LINE_WIDTH)),
        entry(
            format!("{}, coherence < {}", meas.label, fmt_sig(MIN_COHERENCE, 3)),
            Swatch::Line(FAINT_COLOR, LINE_WIDTH),
        ),
    ];
    if let Some(m) = model {
        entries.push(entry(m.label, Swatch::Dashed(MODEL_COLOR)));
    }
    if !markers.is_empty() {
        entries.push(entry("resonance found", Swatch::Dashed(MARKER_COLOR)));
    }
    if window.is_some() {
        entries.push(entry(
            "zoomed below",
            Swatch::Fill(ZOOM_SHADE, ZOOM_SHADE_ALPHA * 2.0),
        ));
    }
    let legend_h = legend_height(&body, &entries)?;
    // Marker labels go above the magnitude frame; reserve rows for them.
    let (px0, px1) = plot_columns(&body);
    let log_span = (x_range.end / x_range.start).ln();
    let items = markers
        .iter()
        .map(|&f| (f, format!("{} Hz", fmt_sig(f, 4)), MARKER_COLOR))
        .collect();
    let (labels, rows) = layout_marker_labels(&body, items, |f| {
        px0 + (f64::from(px1 - px0) * (f / x_range.start).ln() / log_span) as i32
    })?;
    let label_h = u32::try_from(rows)? * u32::try_from(marker_row_height())?;
    let mag_top = MARGIN_TOP + legend_h + 4 + label_h;
    let coh_entries = [
        entry("coherence γ²", Swatch::Line(MEASURED_COLOR, LINE_WIDTH)),
        entry(
            format!(
                "γ² = {}: points below are drawn faint",
                fmt_sig(MIN_COHERENCE, 3)
            ),
            Swatch::Dashed(SETTLE_COLOR),
        ),
    ];
    let coh_top = legend_height(&body, &coh_entries)? + 6;

    // Split the body into three panels; the bottom one also holds the x labels.
    let (_, body_h) = body.dim_in_pixel();
    let plot_h = f64::from(body_h.saturating_sub(X_LABEL_AREA + mag_top + coh_top + MARGIN_TOP));
    let h_mag = (plot_h * 0.42) as u32 + mag_top;
    let h_phase = (plot_h * 0.31) as u32 + MARGIN_TOP;
    let (mag_area, rest) = body.split_vertically(h_mag);
    let (phase_area, coh_area) = rest.split_vertically(h_phase);
    let x_fmt = |v: &f64| fmt_tick(*v);
    let no_fmt = |_: &f64| String::new();
    let shade_window =
        |chart: &mut Chart<'_, '_, Ticked<LogCoord<f64>>>, y: &Range<f64>| match window {
            Some(w) => shade(
                chart,
                (w.start, w.end),
                (y.start, y.end),
                ZOOM_SHADE,
                ZOOM_SHADE_ALPHA,
            ),
            None => Ok(()),
        };

    // Magnitude.
    {
        let y_ticks = linear_ticks(&db_range, 8);
        let y_fmt = tick_formatter(&y_ticks);
        let x = freq_axis(x_range, &x_bold, &x_light);
        let mut chart = panel_chart(&mag_area, x, &db_range, y_ticks, mag_top, false)?;
        mesh(&mut chart, None, "Magnitude [dB re 1 m/A]", &no_fmt, &y_fmt)?;
        shade_window(&mut chart, &db_range)?;
        for &f in &markers {
            vline(&mut chart, f, &db_range, MARKER_COLOR, 1)?;
        }
        draw_measured(&mut chart, &c.meas_db, &c.good, x_range, true, false)?;
        draw_runs(&mut chart, &model_db, MODEL_COLOR, true)?;
        frame(&chart)?;
        panel_legend(root, &mag_area, &chart, &entries)?;
        draw_marker_labels(root, &chart, &labels, db_range.end)?;
    }
    // Phase.
    {
        let y_ticks = phase_ticks(&phase_range);
        let y_fmt = tick_formatter(&y_ticks);
        let x = freq_axis(x_range, &x_bold, &x_light);
        let mut chart = panel_chart(&phase_area, x, &phase_range, y_ticks, MARGIN_TOP, false)?;
        mesh(&mut chart, None, "Phase [°]", &no_fmt, &y_fmt)?;
        shade_window(&mut chart, &phase_range)?;
        for &f in &markers {
            vline(&mut chart, f, &phase_range, MARKER_COLOR, 1)?;
        }
        draw_measured(&mut chart, &c.meas_phase, &c.good, x_range, true, false)?;
        draw_runs(&mut chart, &model_phase, MODEL_COLOR, true)?;
        frame(&chart)?;
    }
    // Coherence.
    {
        let y_ticks: Vec<f64> = (0..=5).map(|i| f64::from(i) * 0.2).collect();
        let y_fmt = tick_formatter(&y_ticks);
        let x = freq_axis(x_range, &x_bold, &x_light);
        let mut chart = panel_chart(&coh_area, x, &coh_range, y_ticks, coh_top, true)?;
        let x_desc = Some("Frequency [Hz]");
        mesh(&mut chart, x_desc, "Coherence [-]", &x_fmt, &y_fmt)?;
        shade_window(&mut chart, &coh_range)?;
        for &f in &markers {
            vline(&mut chart, f, &coh_range, MARKER_COLOR, 1)?;
        }
        hline(&mut chart, MIN_COHERENCE, x_range, SETTLE_COLOR)?;
        draw_runs(
            &mut chart,
            &runs(&c.coh, x_range, true),
            MEASURED_COLOR,
            false,
        )?;
        frame(&chart)?;
        panel_legend(root, &coh_area, &chart, &coh_entries)?;
    }
    Ok(())
}

/// Text of the CMP-CNMP verdict, as the summary prints it.
fn verdict_text(pair: &PairVerdict) -> &'static str {
    if pair.cmp_cnmp {
        "CMP-CNMP zeros: the pair shows the net −360° phase drop"
    } else {
        "no CMP-CNMP zeros: the zeros between the modes give back phase"
    }
}

fn draw_pair_zoom(
    root: &Area<'_>,
    area: &Area<'_>,
    plot: &BodePlot<'_>,
    c: &BodeCurves,
    pair: &PairVerdict,
    band_phase_deg: (f64, f64),
    window: &Range<f64>,
) -> Result<(), BoxError> {
    let area = area.margin(14, 0, 0, 0);
    let lines = [
        format!(
            "Closely spaced pair: {:.2} Hz and {:.2} Hz (zoom {}–{} Hz, shaded above)",
            pair.lower_hz,
            pair.upper_hz,
            fmt_sig(window.start, 4),
            fmt_sig(window.end, 4)
        ),
        format!(
            "Net phase over {:.1}–{:.1} Hz: {:.0}° (≈ {:.0}°) → {}",
            pair.band_hz.0,
            pair.band_hz.1,
            pair.net_phase_deg,
            pair.net_phase_multiple_deg,
            verdict_text(pair)
        ),
    ];
    let (head, panels) = area.split_vertically(header_height(lines.len()));
    header_lines(root, &head, &lines)?;

    let x_ticks = linear_ticks(window, 10);
    let x_fmt = tick_formatter(&x_ticks);
    let no_fmt = |_: &f64| String::new();
    let db_vals = BodeCurves::y_values(&c.meas_db, &c.good, &c.model_db, window);
    let mut phase_vals = BodeCurves::y_values(&c.meas_phase, &c.good, &c.model_phase, window);
    phase_vals.extend([band_phase_deg.0, band_phase_deg.1]);
    let db_range = padded_range(&db_vals, 0.08, 10.0, -100.0..0.0);
    let phase_range = padded_range(&phase_vals, 0.08, 45.0, -180.0..0.0);
    let modes = [pair.lower_hz, pair.upper_hz];

    let (px0, px1) = plot_columns(&panels);
    let span = window.end - window.start;
    let items = modes
        .iter()
        .map(|&f| (f, format!("{} Hz", fmt_sig(f, 4)), MARKER_COLOR))
        .collect();
    let (labels, rows) = layout_marker_labels(&panels, items, |f| {
        px0 + (f64::from(px1 - px0) * (f - window.start) / span) as i32
    })?;
    let mut mag_entries = vec![entry(
        format!("{}, a dot per grid point", plot.measured.label),
        Swatch::Line(MEASURED_COLOR, LINE_WIDTH),
    )];
    if let Some(m) = &plot.model {
        mag_entries.push(entry(m.label, Swatch::Dashed(MODEL_COLOR)));
    }
    mag_entries.push(entry("modes of the pair", Swatch::Dashed(MARKER_COLOR)));
    let mag_top = legend_height(&panels, &mag_entries)?
        + 6
        + u32::try_from(rows)? * u32::try_from(marker_row_height())?;
    let phase_entries = [
        entry(
            format!(
                "φ({:.1} Hz) = {:.0}° (band start)",
                pair.band_hz.0, band_phase_deg.0
            ),
            Swatch::Dashed(BAND_START_COLOR),
        ),
        entry(
            format!(
                "φ({:.1} Hz) = {:.0}° (band end)",
                pair.band_hz.1, band_phase_deg.1
            ),
            Swatch::Dashed(BAND_END_COLOR),
        ),
        entry(
            format!("difference {:.0}°", band_phase_deg.1 - band_phase_deg.0),
            Swatch::Text,
        ),
    ];
    let phase_top = legend_height(&panels, &phase_entries)? + 6;
    let (_, h) = panels.dim_in_pixel();
    let plot_h = f64::from(h.saturating_sub(X_LABEL_AREA + mag_top + phase_top + 10));
    let (mag_area, phase_area) = panels.split_vertically((plot_h * 0.5) as u32 + mag_top);

    {
        let y_ticks = linear_ticks(&db_range, 6);
        let y_fmt = tick_formatter(&y_ticks);
        let x = linear_axis(window, x_ticks.clone());
        let mut chart = panel_chart(&mag_area, x, &db_range, y_ticks, mag_top, false)?;
        mesh(&mut chart, None, "Magnitude [dB re 1 m/A]", &no_fmt, &y_fmt)?;
        for &f in &modes {
            vline(&mut chart, f, &db_range, MARKER_COLOR, 1)?;
        }
        draw_measured(&mut chart, &c.meas_db, &c.good, window, false, true)?;
        if plot.model.is_some() {
            draw_runs(
                &mut chart,
                &runs(&c.model_db, window, false),
                MODEL_COLOR,
                true,
            )?;
        }
        frame(&chart)?;
        panel_legend(root, &mag_area, &chart, &mag_entries)?;
        draw_marker_labels(root, &chart, &labels, db_range.end)?;
    }
    {
        let y_ticks = phase_ticks(&phase_range);
        let y_fmt = tick_formatter(&y_ticks);
        let x = linear_axis(window, x_ticks.clone());
        let mut chart = panel_chart(&phase_area, x, &phase_range, y_ticks, phase_top, true)?;
        mesh(
            &mut chart,
            Some("Frequency [Hz]"),
            "Phase [°]",
            &x_fmt,
            &y_fmt,
        )?;
        for &f in &modes {
            vline(&mut chart, f, &phase_range, MARKER_COLOR, 1)?;
        }
        hline(&mut chart, band_phase_deg.0, window, BAND_START_COLOR)?;
        hline(&mut chart, band_phase_deg.1, window, BAND_END_COLOR)?;
        draw_measured(&mut chart, &c.meas_phase, &c.good, window, false, true)?;
        if plot.model.is_some() {
            draw_runs(
                &mut chart,
                &runs(&c.model_phase, window, false),
                MODEL_COLOR,
                true,
            )?;
        }
        frame(&chart)?;
        panel_legend(root, &phase_area, &chart, &phase_entries)?;
    }
    Ok(())
}

/// The pair zoom when no pair was resolved: a framed panel saying why.
fn draw_no_pair(root: &Area<'_>, area: &Area<'_>, reason: &str) -> Result<(), BoxError> {
    let area = area.margin(14, 0, 0, 0);
    let lines = ["Closely spaced pair: not resolved; CMP-CNMP verdict undetermined".to_string()];
    let (head, rest) = area.split_vertically(header_height(lines.len()));
    header_lines(root, &head, &lines)?;
    let (left, right) = plot_columns(&rest);
    let (_, top) = rest.get_base_pixel();
    let (_, h) = rest.dim_in_pixel();
    let bottom = top + i32::try_from(h.saturating_sub(X_LABEL_AREA + 10))?;
    root.draw(&Rectangle::new(
        [(left, top), (right, bottom)],
        BLACK.stroke_width(1),
    ))?;
    let style =
        TextStyle::from((FONT, HEADER_SIZE).into_font()).pos(Pos::new(HPos::Center, VPos::Center));
    let mid = (left + right) / 2;
    let y = (top + bottom) / 2;
    root.draw(&Text::new(
        "No closely spaced pair was resolved:".to_string(),
        (mid, y - 16),
        style.clone(),
    ))?;
    root.draw(&Text::new(reason.to_string(), (mid, y + 16), style))?;
    Ok(())
}

// ---------------------------------------------------------------------------
// Time-series figures

/// A linear time panel with its mesh drawn; `bottom` panels label the x
/// axis with `x_desc`.
fn time_chart<'a, 'b: 'a>(
    area: &'a Area<'b>,
    x_range: &Range<f64>,
    y_range: &Range<f64>,
    top: u32,
    bottom: bool,
    x_desc: &str,
    y_desc: &str,
) -> Result<Chart<'a, 'b, Ticked<RangedCoordf64>>, BoxError> {
    let x_ticks = linear_ticks(x_range, 12);
    let x_fmt = tick_formatter(&x_ticks);
    let y_ticks = linear_ticks(y_range, 8);
    let y_fmt = tick_formatter(&y_ticks);
    let no_fmt = |_: &f64| String::new();
    let mut chart = panel_chart(
        area,
        linear_axis(x_range, x_ticks),
        y_range,
        y_ticks,
        top,
        bottom,
    )?;
    let x_fmt: &dyn Fn(&f64) -> String = if bottom { &x_fmt } else { &no_fmt };
    mesh(&mut chart, bottom.then_some(x_desc), y_desc, x_fmt, &y_fmt)?;
    Ok(chart)
}

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
        let curves: Vec<(RGBColor, Vec<(f64, f64)>)> = panel
            .series
            .iter()
            .enumerate()
            .map(|(k, (_, t, v))| (PALETTE[k % PALETTE.len()], pairs(t, v)))
            .collect();
        let values: Vec<f64> = curves
            .iter()
            .flat_map(|(_, p)| values_in(p, &t_range))
            .collect();
        let entries: Vec<Entry> = panel
            .series
            .iter()
            .zip(&curves)
            .filter(|((label, _, _), _)| !label.is_empty())
            .map(|((label, _, _), (color, _))| entry(*label, Swatch::Line(*color, LINE_WIDTH)))
            .collect();
        let top = MARGIN_TOP.max(legend_height(&area, &entries)? + 6);
        let y_range = padded_range(&values, 0.06, 0.0, -1.0..1.0);
        let mut chart = time_chart(
            &area,
            &t_range,
            &y_range,
            top,
            bottom,
            "Time [s]",
            panel.y_label,
        )?;
        for (color, pts) in &curves {
            draw_trace(&mut chart, pts, &t_range, *color, LINE_WIDTH)?;
        }
        frame(&chart)?;
        panel_legend(root, &area, &chart, &entries)?;
    }
    Ok(())
}

/// The zoom window of a step figure on the `t_s` axis (see
/// [`write_step_png`]).
fn step_zoom(t_range: &Range<f64>, t_step: f64, period_s: f64, m: &StepMetrics) -> Range<f64> {
    let rest = (t_range.end - t_step).max(0.0);
    let post = match m.settling_time_s {
        Some(ts) => (2.0 * ts)
            .max(4.0 * m.rise_time_s.unwrap_or(0.0))
            .max(20.0 * period_s),
        None => rest,
    }
    .min(rest);
    let pre = (post / 10.0)
        .max(2.0 * period_s)
        .min(t_step - t_range.start)
        .max(0.0);
    let r = (t_step - pre)..(t_step + post);
    if r.end > r.start && r.start.is_finite() && r.end.is_finite() {
        r
    } else {
        t_range.clone()
    }
}

/// Formats a duration in s as ms with three significant digits.
fn fmt_ms(s: f64) -> String {
    format!("{} ms", fmt_sig(s * 1e3, 3))
}

fn draw_step(root: &Area<'_>, p: &StepPlot<'_>) -> Result<(), BoxError> {
    let outer = root.margin(8, 0, 0, 0);
    let body = if p.title.is_empty() {
        outer
    } else {
        outer.titled(p.title, (FONT, TITLE_SIZE))?
    };
    let (m, e) = (p.metrics, p.events);
    let t = p.t_s;
    let t_at = |k: usize| t.get(k).copied().filter(|v| v.is_finite());
    let t_all: Vec<f64> = t.iter().copied().filter(|v| v.is_finite()).collect();
    let t_range = padded_range(&t_all, 0.0, 0.0, 0.0..1.0);
    let period_s = match (t_all.first(), t_all.last()) {
        (Some(a), Some(b)) if t_all.len() > 1 => (b - a) / (t_all.len() - 1) as f64,
        _ => 0.0,
    };
    let t_step = t_at(e.step)
        .or(t_all.last().copied())
        .unwrap_or(t_range.start);
    let zoom = step_zoom(&t_range, t_step, period_s, m);
    let step_um = m.step_m * 1e6;
    let error_um: Vec<f64> = p
        .setpoint_um
        .iter()
        .zip(p.position_um)
        .map(|(s, y)| s - y)
        .collect();

    // Heights: the whole record above, the zoom below.
    let (_, body_h) = body.dim_in_pixel();
    let h = |frac: f64| (f64::from(body_h) * frac) as u32;
    let (ov_pos, rest) = body.split_vertically(h(0.18));
    let (ov_cmd, rest) = rest.split_vertically(h(0.13));
    let (ov_err, rest) = rest.split_vertically(h(0.13) + X_LABEL_AREA + 10);
    let (_, rest) = rest.split_vertically(24);
    let (zoom_pos, zoom_cmd) = rest.split_vertically(h(0.30));

    let sp_stairs = staircase(t, p.setpoint_um);
    let cmd_stairs = staircase(t, p.command_a);
    let pos = pairs(t, p.position_um);

    // Whole record: position.
    {
        let entries = [
            entry("setpoint", Swatch::Line(SETPOINT_COLOR, LINE_WIDTH)),
            entry("position (probe)", Swatch::Line(POSITION_COLOR, LINE_WIDTH)),
            entry(
                format!(
                    "zoomed below ({} to {} s)",
                    fmt_sig(zoom.start, 4),
                    fmt_sig(zoom.end, 4)
                ),
                Swatch::Fill(ZOOM_SHADE, ZOOM_SHADE_ALPHA * 2.0),
            ),
        ];
        let top = legend_height(&ov_pos, &entries)? + 6;
        let vals: Vec<f64> = values_in(&sp_stairs, &t_range)
            .chain(values_in(&pos, &t_range))
            .collect();
        let y = padded_range(&vals, 0.06, 0.0, -1.0..1.0);
        let mut chart = time_chart(
            &ov_pos,
            &t_range,
            &y,
            top,
            false,
            "",
            "position − start [µm]",
        )?;
        shade(
            &mut chart,
            (zoom.start, zoom.end),
            (y.start, y.end),
            ZOOM_SHADE,
            ZOOM_SHADE_ALPHA,
        )?;
        draw_trace(&mut chart, &sp_stairs, &t_range, SETPOINT_COLOR, LINE_WIDTH)?;
        draw_trace(&mut chart, &pos, &t_range, POSITION_COLOR, 1)?;
        frame(&chart)?;
        panel_legend(root, &ov_pos, &chart, &entries)?;
    }
    // Whole record: command.
    {
        let entries = [
            entry(
                "current command (held over each sample period)",
                Swatch::Line(COMMAND_COLOR, LINE_WIDTH),
            ),
            entry(
                format!("peak |command| {:.3} A", m.peak_command_a),
                Swatch::Text,
            ),
        ];
        let top = legend_height(&ov_cmd, &entries)? + 6;
        let vals: Vec<f64> = values_in(&cmd_stairs, &t_range).collect();
        let y = padded_range(&vals, 0.06, 0.0, -1.0..1.0);
        let mut chart = time_chart(&ov_cmd, &t_range, &y, top, false, "", "current command [A]")?;
        shade(
            &mut chart,
            (zoom.start, zoom.end),
            (y.start, y.end),
            ZOOM_SHADE,
            ZOOM_SHADE_ALPHA,
        )?;
        draw_trace(&mut chart, &cmd_stairs, &t_range, COMMAND_COLOR, 1)?;
        frame(&chart)?;
        panel_legend(root, &ov_cmd, &chart, &entries)?;
    }
    // Whole record: error, with the steady-state window.
    {
        let entries = [
            entry("setpoint − position", Swatch::Line(ERROR_COLOR, LINE_WIDTH)),
            entry(
                format!(
                    "steady-state window (last {} s): mean {:.1} nm, σ {:.1} nm",
                    fmt_sig(m.steady_state_window_s, 3),
                    m.steady_state_error_mean_nm,
                    m.steady_state_error_std_nm
                ),
                Swatch::Fill(STEADY_COLOR, 0.25),
            ),
        ];
        let top = legend_height(&ov_err, &entries)? + 6;
        let err = pairs(t, &error_um);
        let vals: Vec<f64> = values_in(&err, &t_range).collect();
        let y = padded_range(&vals, 0.06, 0.0, -1.0..1.0);
        let mut chart = time_chart(&ov_err, &t_range, &y, top, true, "Time [s]", "error [µm]")?;
        if let Some(t0) = t_at(e.steady_state_from) {
            shade(
                &mut chart,
                (t0, t_range.end),
                (y.start, y.end),
                STEADY_COLOR,
                0.12,
            )?;
        }
        draw_trace(&mut chart, &err, &t_range, ERROR_COLOR, 1)?;
        frame(&chart)?;
        panel_legend(root, &ov_err, &chart, &entries)?;
    }

    // The zoom, in ms since the step.
    let ms = |v: f64| (v - t_step) * 1e3;
    let z = ms(zoom.start)..ms(zoom.end);
    let to_ms =
        |pts: &[(f64, f64)]| -> Vec<(f64, f64)> { pts.iter().map(|&(x, y)| (ms(x), y)).collect() };
    let (sp_z, pos_z, cmd_z) = (to_ms(&sp_stairs), to_ms(&pos), to_ms(&cmd_stairs));
    let smooth_z = to_ms(&pairs(t, p.smoothed_um));
    let event = |k: Option<usize>| {
        k.and_then(|k| Some((ms(t_at(k)?), p.smoothed_um.get(k).copied()?)))
            .filter(|(x, _)| *x >= z.start && *x <= z.end)
    };
    let rise = (event(e.rise_from), event(e.rise_to));
    let settled = event(e.settled);
    let peak = event(e.peak).filter(|_| m.overshoot_pct > 0.0);
    let band = (
        step_um * (1.0 - SETTLING_BAND),
        step_um * (1.0 + SETTLING_BAND),
    );

    let mut items = vec![(
        0.0,
        format!("step of {} µm", fmt_sig(step_um, 3)),
        MARKER_COLOR,
    )];
    let mut notes = Vec::new();
    match (rise, m.rise_time_s) {
        ((Some(a), Some(b)), Some(rt)) => items.push((
            0.5 * (a.0 + b.0),
            format!("rise 10–90 %: {}", fmt_ms(rt)),
            RISE_COLOR,
        )),
        _ => notes.push(entry("rise 10–90 %: not reached", Swatch::Text)),
    }
    match (settled, m.settling_time_s) {
        (Some(s), Some(ts)) => items.push((
            s.0,
            format!(
                "settled (±{} %): {}",
                fmt_sig(SETTLING_BAND * 100.0, 3),
                fmt_ms(ts)
            ),
            SETTLE_COLOR,
        )),
        _ => notes.push(entry("not settled by the end of the record", Swatch::Text)),
    }
    match peak {
        Some(pk) => items.push((
            pk.0,
            format!(
                "overshoot {:.1} % ({} µm at {})",
                m.overshoot_pct,
                fmt_sig(pk.1, 4),
                fmt_ms(pk.0 * 1e-3)
            ),
            OVERSHOOT_COLOR,
        )),
        None => notes.push(entry("no overshoot", Swatch::Text)),
    }
    let mut entries = vec![
        entry("setpoint", Swatch::Line(SETPOINT_COLOR, LINE_WIDTH)),
        entry(
            "position (probe)",
            Swatch::Line(POSITION_RAW_COLOR, LINE_WIDTH),
        ),
        entry(
            format!(
                "position, {} moving average (the metrics')",
                fmt_ms(SMOOTHING_S)
            ),
            Swatch::Line(SMOOTHED_COLOR, LINE_WIDTH),
        ),
        entry(
            format!(
                "±{} % band (±{} µm)",
                fmt_sig(SETTLING_BAND * 100.0, 3),
                fmt_sig(step_um.abs() * SETTLING_BAND, 3)
            ),
            Swatch::Fill(BAND_COLOR, BAND_ALPHA),
        ),
    ];
    entries.extend(notes);
    // Zoom: position.
    {
        let (px0, px1) = plot_columns(&zoom_pos);
        let span = z.end - z.start;
        let (labels, rows) = layout_marker_labels(&zoom_pos, items, |x| {
            px0 + (f64::from(px1 - px0) * (x - z.start) / span) as i32
        })?;
        let legend_h = legend_height(&zoom_pos, &entries)?;
        let top = legend_h + 8 + u32::try_from(rows)? * u32::try_from(marker_row_height())?;
        let vals: Vec<f64> = values_in(&sp_z, &z)
            .chain(values_in(&pos_z, &z))
            .chain(values_in(&smooth_z, &z))
            .chain([band.0, band.1])
            .collect();
        let y = padded_range(&vals, 0.06, 0.0, -1.0..1.0);
        let mut chart = time_chart(&zoom_pos, &z, &y, top, false, "", "position − start [µm]")?;
        shade(
            &mut chart,
            (0.0f64.max(z.start), z.end),
            band,
            BAND_COLOR,
            BAND_ALPHA,
        )?;
        draw_trace(&mut chart, &pos_z, &z, POSITION_RAW_COLOR, 1)?;
        draw_trace(&mut chart, &sp_z, &z, SETPOINT_COLOR, LINE_WIDTH)?;
        draw_trace(&mut chart, &smooth_z, &z, SMOOTHED_COLOR, LINE_WIDTH)?;
        vline(&mut chart, 0.0, &y, MARKER_COLOR, 1)?;
        if let (Some(a), Some(b)) = rise {
            for pt in [a, b] {
                vline(&mut chart, pt.0, &y, RISE_COLOR, LINE_WIDTH)?;
                chart.draw_series(std::iter::once(Circle::new(pt, 5, RISE_COLOR.filled())))?;
            }
        }
        if let Some(s) = settled {
            vline(&mut chart, s.0, &y, SETTLE_COLOR, LINE_WIDTH)?;
            chart.draw_series(std::iter::once(Circle::new(s, 5, SETTLE_COLOR.filled())))?;
        }
        if let Some(pk) = peak {
            vline(&mut chart, pk.0, &y, OVERSHOOT_COLOR, LINE_WIDTH)?;
            chart.draw_series(std::iter::once(Circle::new(
                pk,
                6,
                OVERSHOOT_COLOR.filled(),
            )))?;
        }
        frame(&chart)?;
        panel_legend(root, &zoom_pos, &chart, &entries)?;
        draw_marker_labels(root, &chart, &labels, y.end)?;
    }
    // Zoom: command.
    {
        let entries = [entry(
            "current command (held over each sample period)",
            Swatch::Line(COMMAND_COLOR, LINE_WIDTH),
        )];
        let top = legend_height(&zoom_cmd, &entries)? + 6;
        let vals: Vec<f64> = values_in(&cmd_z, &z).collect();
        let y = padded_range(&vals, 0.06, 0.0, -1.0..1.0);
        let mut chart = time_chart(
            &zoom_cmd,
            &z,
            &y,
            top,
            true,
            "Time since the step [ms]",
            "current command [A]",
        )?;
        vline(&mut chart, 0.0, &y, MARKER_COLOR, 1)?;
        draw_trace(&mut chart, &cmd_z, &z, COMMAND_COLOR, LINE_WIDTH)?;
        frame(&chart)?;
        panel_legend(root, &zoom_cmd, &chart, &entries)?;
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
            pair: None,
        }
    }

    /// The pair zoom of the example: two made-up modes near 400 Hz.
    fn example_pair() -> PairZoom<'static> {
        PairZoom::Resolved {
            pair: PairVerdict {
                lower_hz: 400.0,
                upper_hz: 430.0,
                band_hz: (150.0, 700.0),
                net_phase_deg: -350.0,
                net_phase_multiple_deg: -360.0,
                cmp_cnmp: true,
            },
            band_phase_deg: (-190.0, -540.0),
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
    fn plot_bode_with_a_pair_zoom_is_1400x1650() {
        let dir = tempfile::tempdir().unwrap();
        let e = example();
        for (i, pair) in [
            example_pair(),
            PairZoom::Unresolved {
                reason: "only one resonance",
            },
        ]
        .into_iter()
        .enumerate()
        {
            let path = dir.path().join(format!("bode{i}.png"));
            let plot = BodePlot {
                pair: Some(pair),
                ..bode(&e, &[70.9, 400.0, 430.0])
            };
            write_bode_png(&path, Existing::Refuse, &plot).unwrap();
            assert_eq!(png_size(&path), (1400, 1650));
        }
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
            pair: None,
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
                pair: None,
            };
            let path = dir.path().join(format!("case{i}.png"));
            write_bode_png(&path, Existing::Refuse, &plot)
                .unwrap_or_else(|e| panic!("case {i}: {e}"));
            assert_eq!(png_size(&path), (1400, 1000), "case {i}");
            // The same with a pair zoom, resolved or not.
            for (j, pair) in [example_pair(), PairZoom::Unresolved { reason: "none" }]
                .into_iter()
                .enumerate()
            {
                let plot = BodePlot {
                    pair: Some(pair),
                    ..plot
                };
                let path = dir.path().join(format!("case{i}-{j}.png"));
                write_bode_png(&path, Existing::Refuse, &plot)
                    .unwrap_or_else(|e| panic!("case {i}-{j}: {e}"));
                assert_eq!(png_size(&path), (1400, 1650), "case {i}-{j}");
            }
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

    /// The first, lowest, highest and last point of each column survive,
    /// in order; short series are left alone.
    #[test]
    fn plot_decimate_keeps_the_envelope_in_order() {
        let pts: Vec<(f64, f64)> = (0..1000)
            .map(|i| {
                (
                    f64::from(i) * 0.001,
                    if i == 503 { 9.0 } else { f64::from(i % 7) },
                )
            })
            .collect();
        let d = decimate(&pts, &(0.0..1.0), 10);
        assert!(d.len() <= 40, "{}", d.len());
        assert!(d.windows(2).all(|w| w[0].0 <= w[1].0), "order kept");
        assert_eq!(d.first(), pts.first());
        assert_eq!(d.last(), pts.last());
        assert!(d.contains(&(0.503, 9.0)), "the spike survives");
        // Each column keeps its own minimum (0) and maximum (6 or the spike).
        for c in 0..10 {
            let col: Vec<f64> = d
                .iter()
                .filter(|p| (p.0 * 10.0).floor() as i32 == c)
                .map(|p| p.1)
                .collect();
            assert!(col.contains(&0.0), "column {c}: {col:?}");
            assert!(col.iter().any(|&v| v >= 6.0), "column {c}: {col:?}");
        }
        assert_eq!(decimate(&pts[..30], &(0.0..1.0), 10), pts[..30].to_vec());
    }

    #[test]
    fn plot_staircase_holds_each_sample_until_the_next() {
        let t = [0.0, 1.0, 2.0, 3.0];
        let v = [5.0, 6.0, f64::NAN, 8.0];
        let s = staircase(&t, &v);
        assert_eq!(&s[..4], &[(0.0, 5.0), (1.0, 5.0), (1.0, 6.0), (2.0, 6.0)]);
        assert!(s[4].1.is_nan() && s[5].1.is_nan());
        assert_eq!(s[6], (3.0, 8.0));
        assert_eq!(s.len(), 7);
        // The NaN period breaks the line into two runs.
        assert_eq!(runs(&s, &(0.0..3.0), false).len(), 2);
    }

    fn metrics(rise: Option<f64>, settle: Option<f64>) -> StepMetrics {
        StepMetrics {
            step_m: 1e-5,
            rise_time_s: rise,
            settling_time_s: settle,
            overshoot_pct: 0.0,
            steady_state_error_mean_nm: 0.0,
            steady_state_error_std_nm: 0.0,
            steady_state_window_s: 1.0,
            peak_command_a: 0.0,
        }
    }

    /// The zoom window rule of `write_step_png`, worked by hand.
    #[test]
    fn plot_step_zoom_window() {
        let rec = 0.0..4.0;
        let w = step_zoom(&rec, 0.2, 2e-4, &metrics(Some(0.005), Some(0.1)));
        // post = max(0.2, 0.02, 0.004) = 0.2, pre = 0.02.
        assert!(
            (w.start - 0.18).abs() < 1e-12 && (w.end - 0.4).abs() < 1e-12,
            "{w:?}"
        );
        let w = step_zoom(&rec, 0.2, 2e-4, &metrics(Some(0.05), Some(0.01)));
        // post = 4 x rise = 0.2.
        assert!((w.end - 0.4).abs() < 1e-12, "{w:?}");
        let w = step_zoom(&rec, 0.2, 2e-4, &metrics(Some(1e-5), Some(0.0)));
        // post = 20 periods = 4 ms, pre = 2 periods = 0.4 ms.
        assert!(
            (w.start - 0.1996).abs() < 1e-12 && (w.end - 0.204).abs() < 1e-12,
            "{w:?}"
        );
        // Never settled: to the end of the record.
        let w = step_zoom(&rec, 0.2, 2e-4, &metrics(None, None));
        assert!((w.end - 4.0).abs() < 1e-12 && w.start == 0.0, "{w:?}");
        // Bounded by the record: a step at its start has no lead.
        let w = step_zoom(&rec, 0.0, 2e-4, &metrics(Some(0.005), Some(0.1)));
        assert_eq!(w.start, 0.0);
        let w = step_zoom(&rec, 3.9, 2e-4, &metrics(Some(0.005), Some(0.5)));
        assert!((w.end - 4.0).abs() < 1e-12, "{w:?}");
    }

    #[test]
    fn plot_pair_window() {
        let PairZoom::Resolved { pair, .. } = example_pair() else {
            unreachable!()
        };
        let w = pair_window(&pair, &(1.0..1000.0));
        assert_eq!(w, 370.0..460.0);
        // Cut to the measured band when the pair stays inside it.
        let w = pair_window(&pair, &(1.0..440.0));
        assert_eq!(w, 370.0..440.0);
        // A pair at the edge keeps its own window.
        let w = pair_window(&pair, &(1.0..420.0));
        assert_eq!(w, 370.0..460.0);
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

    /// Writes `/tmp/bode-example.png`, `/tmp/bode-pair-example.png` and
    /// `/tmp/time-example.png` for visual inspection:
    /// `cargo test --lib plot -- --ignored`.
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
        write_bode_png(
            Path::new("/tmp/bode-pair-example.png"),
            Existing::Replace,
            &BodePlot {
                pair: Some(example_pair()),
                ..bode(&e, &[70.9, 400.0, 430.0])
            },
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
