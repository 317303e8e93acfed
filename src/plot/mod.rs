//! PNG figures: every plot `bench` writes (identification, closed loop,
//! model analysis), and the pieces they are drawn with.
//!
//! The figures, one file each:
//! * [`write_bode_png`] (`bode.rs`): a Bode figure, 1400 px wide. Its top
//!   1000 px hold three stacked panels sharing a logarithmic frequency
//!   axis: magnitude in dB re 1 m/A, phase in degrees and coherence, with
//!   an optional model overlay and vertical markers at identified
//!   resonances. Points whose coherence is below [`MIN_COHERENCE`] are
//!   drawn faint (and left out of the axis ranges). With a [`PairZoom`]
//!   (`pair_zoom.rs`) a further 650 px hold two panels zoomed on the
//!   closely spaced pair, with the net phase and the CMP-CNMP verdict
//!   written above them, or the reason no pair was resolved.
//! * [`write_step_png`] (`step.rs`): a closed-loop step response, the whole
//!   record (position, command, error) above and the transient zoomed
//!   below, with the settling band and the rise, settling and overshoot
//!   marked.
//! * [`write_time_png`] (`time.rs`): one or more stacked time-series panels
//!   sharing a time axis.
//! * [`write_track_png`] (`track.rs`; `bench track`): the reference against
//!   the position over one line, the RMS error of every trial with its 1σ
//!   and the noise floor, and the error's harmonics beside the bands the
//!   plant's zeros close.
//! * [`write_design_png`] (`design.rs`; `bench design`): the open loop of
//!   every input FRF, 1400×1000 px: the Nyquist plane left (equal scales,
//!   around −1, with the unit circle, the modulus-margin circle and the
//!   phase-margin sector), |L|, ∠L and |S| on a logarithmic ω axis right;
//!   the worst loop highlighted. It takes plain slices, not the design
//!   job's types.
//! * [`write_bode_overlay_png`] (`bode_overlay.rs`; `bench plot bode`):
//!   several measured FRFs on the Bode figure's three panels, each in its
//!   colour with its verdict in a legend table above (as tall as it needs
//!   to be), the model once, and the zoom on all their closely spaced
//!   pairs below. [`write_nyquist_png`] (`nyquist.rs`; `bench plot
//!   nyquist`): the same FRFs in the complex plane with equal scales, the
//!   whole band and the pairs' band side by side, with direction arrows
//!   and the fitted modes marked. Both take an [`OverlayPlot`]
//!   (`overlay.rs`, with what they share); the colours are
//!   [`overlay_colors`].
//! * The model-analysis figures, 1400×1000 px, drawn with plotters' own
//!   captions and series-label boxes: [`write_pole_zero_png`]
//!   (`pole_zero.rs`) and [`write_decomposed_bode_png`] (`modes.rs`) of one
//!   bench (`bench analyze`); [`write_map_png`], the CNMP map with
//!   [`MeasuredPoint`]s overlaid, and [`write_veering_png`] (`map.rs`;
//!   `bench map`, `bench campaign`).
//!
//! The pieces: `palette.rs` (every colour), `style.rs` (the embedded font,
//! text sizes, line width), `axes.rs` (panel geometry, axes with chosen
//! ticks, mesh and frame), `ticks.rs` (axis ranges, tick positions, number
//! formatting), `draw.rs` (curves and guide lines), `legend.rs` (legend
//! strips, marker labels, header lines, the title) and `png.rs` (writing
//! the file).
//! Unit tests of the figures as files are in `tests.rs`, of the overlays
//! in `overlay_tests.rs`. The `write_*_png` functions write SVG and PDF
//! as well, by the path's extension.
//!
//! In the Bode, step, time-series, design and overlay figures legends sit in strips
//! above the panels, outside the plotted area, so they never hide a trace.
//! Rendering draws on a [`canvas::Canvas`] (`canvas.rs`): the plotters
//! bitmap backend for a PNG, its SVG backend for `.svg` and `.pdf` (the
//! SVG converted by svg2pdf), chosen by the file's extension, with an
//! embedded DejaVu Sans font, so no system font libraries are needed.
//! Non-finite samples (and non-positive magnitudes or frequencies, which
//! have no logarithm) are skipped and break the line instead of failing.
//! Lines are drawn segment by segment, and time series are first reduced to
//! the first, lowest, highest and last sample of each pixel column (the
//! same picture): plotters fills a wide polyline as one polygon, which
//! leaves holes where a dense trace turns back on itself. The image is
//! drawn in memory, encoded to a hidden temporary file next to the target
//! and renamed to it when complete, by the rules of [`crate::outputs`]: a
//! reader never sees a half-written PNG, and an existing file is replaced
//! only with [`Existing::Replace`](crate::outputs::Existing::Replace)
//! (`--overwrite`), never when it is not a regular file.
//!
//! # Layer
//! A low layer: the figures draw data the layers below compute, and run
//! nothing. May use [`crate::ident`] (the FRF, the pair verdict,
//! [`MIN_COHERENCE`]), [`crate::control`] (the step metrics),
//! [`crate::analysis`] (modal terms, typed zeros, map cells, veering
//! curves), [`crate::outputs`] (how a file is written) and
//! `bench_plant::model` (the plant's modes and zero types); never `jobs`,
//! `cli`, `daemon`, `campaign` or `rt` (nor `record`, `config`, `live`):
//! they call the figures, not the reverse.
//!
//! Layer rule: may use `analysis`, `control`, `ident`, `outputs`.

use std::error::Error as StdError;
use std::io;
use std::path::PathBuf;

use plotters::coord::Shift;
use plotters::prelude::*;

mod axes;
mod bode;
mod bode_overlay;
mod canvas;
mod design;
mod draw;
mod legend;
mod map;
mod measured;
mod modes;
mod nyquist;
mod overlay;
#[cfg(test)]
mod overlay_tests;
mod pair_zoom;
mod palette;
mod png;
mod pole_zero;
mod step;
mod style;
#[cfg(test)]
mod tests;
mod ticks;
mod time;
mod track;

pub use crate::ident::frf::MIN_COHERENCE;
pub use bode::{bode_curve, write_bode_png, BodePlot, BodeSeries, MAGNITUDE_M_PER_A};
pub use bode_overlay::write_bode_overlay_png;
pub use design::{write_design_png, DesignLoop, DesignPlot};
pub use map::{write_map_png, write_veering_png, MeasuredPoint};
pub use modes::write_decomposed_bode_png;
pub use nyquist::write_nyquist_png;
pub use overlay::{OverlayModel, OverlayPlot, OverlayTrace, FULL_LEGEND_MAX, MAX_OVERLAY_TRACES};
pub use pair_zoom::PairZoom;
pub use palette::{
    faint, overlay_colors, viridis, OverlayPalette, COMMAND_COLOR, FAINT_COLOR, MAP_CNMP_BOTH,
    MAP_CNMP_UNDAMPED_ONLY, MARKER_COLOR, MEASURED_COLOR, MODEL_COLOR, OTHER_LOOP_COLOR,
    OVERLAY_QUALITATIVE, OVERSHOOT_COLOR, RISE_COLOR, SETTLE_COLOR, WORST_LOOP_COLOR,
};
pub use pole_zero::write_pole_zero_png;
pub use step::{write_step_png, StepPlot};
pub use time::{write_time_png, TimePanel};
pub use track::{write_track_png, TrackPlot, TrackTrialPlot};

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

/// Any error while drawing (plotters' own, or a pixel count that does not
/// fit); becomes [`PlotError::Draw`].
type BoxError = Box<dyn StdError>;
/// The whole image, or a part of it split off for a panel.
type Area<'b> = DrawingArea<canvas::Canvas<'b>, Shift>;
