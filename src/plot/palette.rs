//! Every colour of every figure, in one place: the base colours (the
//! Tableau 10 set plotting libraries default to), then what each one
//! means in a figure, then the cycles for series without a meaning of
//! their own. The public ones are re-exported from [`super`] so tests can
//! look for them in the pixels.

use plotters::style::RGBColor;

const BLUE: RGBColor = RGBColor(31, 119, 180);
const RED: RGBColor = RGBColor(214, 39, 40);
const GREEN: RGBColor = RGBColor(44, 160, 44);
const ORANGE: RGBColor = RGBColor(255, 127, 14);
const PURPLE: RGBColor = RGBColor(148, 103, 189);
const BROWN: RGBColor = RGBColor(140, 86, 75);
const PINK: RGBColor = RGBColor(227, 119, 194);
const CYAN: RGBColor = RGBColor(23, 190, 207);

// ---------------------------------------------------------------------------
// Panels

/// Labelled grid lines.
pub(super) const GRID_BOLD: RGBColor = RGBColor(200, 200, 200);
/// Grid-only lines (the minor ticks of a log axis).
pub(super) const GRID_LIGHT: RGBColor = RGBColor(232, 232, 232);
/// Shading of a zoomed window on the overview panels.
pub(super) const ZOOM_SHADE: RGBColor = RGBColor(120, 120, 120);
/// Opacity of [`ZOOM_SHADE`] (its legend swatch twice that).
pub(super) const ZOOM_SHADE_ALPHA: f64 = 0.12;
/// Colour of the resonance markers and of the step instant.
pub const MARKER_COLOR: RGBColor = RGBColor(90, 90, 90);

// ---------------------------------------------------------------------------
// Bode figure

/// Colour of the measured FRF (coherence at or above
/// [`MIN_COHERENCE`](crate::ident::frf::MIN_COHERENCE)), and of the
/// measured-verdict markers on the CNMP map.
pub const MEASURED_COLOR: RGBColor = BLUE;
/// Colour of measured FRF points below
/// [`MIN_COHERENCE`](crate::ident::frf::MIN_COHERENCE) (the measured
/// colour at 30 % on white).
pub const FAINT_COLOR: RGBColor = RGBColor(188, 214, 233);
/// The model overlay (dashed).
pub(super) const MODEL_COLOR: RGBColor = RED;
/// The phase at the start of the pair's band (pair zoom).
pub(super) const BAND_START_COLOR: RGBColor = GREEN;
/// The phase at the end of the pair's band (pair zoom).
pub(super) const BAND_END_COLOR: RGBColor = PURPLE;

// ---------------------------------------------------------------------------
// Step figure

/// The setpoint.
pub(super) const SETPOINT_COLOR: RGBColor = BLUE;
/// The probe reading on the whole record.
pub(super) const POSITION_COLOR: RGBColor = RED;
/// The raw probe reading under its moving average in the zoom.
pub(super) const POSITION_RAW_COLOR: RGBColor = RGBColor(240, 160, 160);
/// The moving average the metrics are computed on.
pub(super) const SMOOTHED_COLOR: RGBColor = RGBColor(120, 20, 20);
/// Colour of the current command of the step figure.
pub const COMMAND_COLOR: RGBColor = GREEN;
/// The error `setpoint − position`.
pub(super) const ERROR_COLOR: RGBColor = BLUE;
/// The settling band around the final value.
pub(super) const BAND_COLOR: RGBColor = GREEN;
/// Opacity of [`BAND_COLOR`].
pub(super) const BAND_ALPHA: f64 = 0.18;
/// Colour of the rise-time markers (10 % and 90 % crossings).
pub const RISE_COLOR: RGBColor = PURPLE;
/// Colour of the settling-time marker (and of the coherence threshold).
pub const SETTLE_COLOR: RGBColor = ORANGE;
/// Colour of the overshoot marker.
pub const OVERSHOOT_COLOR: RGBColor = BROWN;
/// The steady-state window.
pub(super) const STEADY_COLOR: RGBColor = CYAN;

// ---------------------------------------------------------------------------
// Design figure

/// Colour of the worst loop of the design figure (drawn thick, on top).
pub const WORST_LOOP_COLOR: RGBColor = BLUE;
/// Colour of the other loops of the design figure (drawn thin, below).
pub const OTHER_LOOP_COLOR: RGBColor = RGBColor(150, 172, 196);
/// The ‖S‖∞ limit: the modulus-margin circle and the s_max line.
pub(super) const SENSITIVITY_LIMIT_COLOR: RGBColor = ORANGE;
/// The phase-margin sector on the unit circle and the phase-margin line.
pub(super) const PHASE_MARGIN_COLOR: RGBColor = PURPLE;
/// The sensitivity bandwidth ω_B and the −3 dB line.
pub(super) const BANDWIDTH_COLOR: RGBColor = GREEN;

// ---------------------------------------------------------------------------
// Model-analysis figures (pole-zero map, CNMP map)

/// A CMP-CNMP zero; the mode-crossing line of the map.
pub(super) const CNMP_COLOR: RGBColor = RGBColor(200, 30, 30);
/// An RMP-RNMP zero.
pub(super) const RNMP_COLOR: RGBColor = ORANGE;
/// An MMP zero.
pub(super) const MMP_COLOR: RGBColor = RGBColor(60, 60, 60);
/// Shade of a map cell with CMP-CNMP zeros in both models.
pub const MAP_CNMP_BOTH: RGBColor = RGBColor(30, 30, 30);
/// Shade of a cell with CMP-CNMP zeros only without damping.
pub const MAP_CNMP_UNDAMPED_ONLY: RGBColor = RGBColor(150, 150, 150);

// ---------------------------------------------------------------------------
// Series without a meaning of their own

/// The curves of a time-series panel, in order (cycled).
pub(super) const SERIES: [RGBColor; 8] = [BLUE, RED, GREEN, ORANGE, PURPLE, BROWN, PINK, CYAN];
/// The modes of the decomposed-mode plot and the asymmetries of the
/// veering plot, in order (cycled): the same colours without red, which
/// marks CMP-CNMP in the model-analysis figures, and pink.
pub(super) const MODE_SERIES: [RGBColor; 6] = [BLUE, ORANGE, GREEN, PURPLE, BROWN, CYAN];
