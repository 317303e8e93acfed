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
const OLIVE: RGBColor = RGBColor(188, 189, 34);

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
/// Colour of the model overlay (dashed).
pub const MODEL_COLOR: RGBColor = RED;
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

// ---------------------------------------------------------------------------
// Overlays of several FRFs (`bench plot`)

/// The traces of an overlay of a few FRFs, in order: Tableau 10 without
/// red (the model, dashed) and grey (the markers). Up to eight traces get
/// one each ([`overlay_colors`]).
pub const OVERLAY_QUALITATIVE: [RGBColor; 8] =
    [BLUE, ORANGE, GREEN, PURPLE, BROWN, PINK, OLIVE, CYAN];

/// matplotlib's viridis at 0, 0.1, …, 1 (its published 256-entry table,
/// every 25.5th entry): perceptually uniform, readable in grey and by the
/// colour-blind.
const VIRIDIS: [(u8, u8, u8); 11] = [
    (0x44, 0x01, 0x54),
    (0x48, 0x24, 0x75),
    (0x41, 0x44, 0x87),
    (0x35, 0x5f, 0x8d),
    (0x2a, 0x78, 0x8e),
    (0x21, 0x91, 0x8c),
    (0x22, 0xa8, 0x84),
    (0x44, 0xbf, 0x70),
    (0x7a, 0xd1, 0x51),
    (0xbd, 0xdf, 0x26),
    (0xfd, 0xe7, 0x25),
];

/// The end of viridis a trace may take: beyond it the yellow is too light
/// to read as a line on white.
const VIRIDIS_END: f64 = 0.85;

/// viridis at `t` (0 … 1, clamped) linearly between its tabulated
/// points, on the part up to [`VIRIDIS_END`].
pub fn viridis(t: f64) -> RGBColor {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    } * VIRIDIS_END;
    let x = t * (VIRIDIS.len() - 1) as f64;
    let i = (x.floor() as usize).min(VIRIDIS.len() - 2);
    let f = x - i as f64;
    let (a, b) = (VIRIDIS[i], VIRIDIS[i + 1]);
    let mix = |p: u8, q: u8| (f64::from(p) + f * (f64::from(q) - f64::from(p))).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// How the traces of an overlay are coloured.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OverlayPalette {
    /// [`OVERLAY_QUALITATIVE`] in order: a few unrelated FRFs.
    Qualitative,
    /// [`viridis`] from its dark end to [`VIRIDIS_END`] in the traces'
    /// order: many FRFs, or FRFs ordered by a quantity (a campaign's cells
    /// by asymmetry and operating point).
    Sequential,
}

/// The colours of `n` overlaid traces: [`OVERLAY_QUALITATIVE`] (cycled
/// beyond eight, which [`OverlayPalette::Sequential`] is for), or
/// [`viridis`] spread evenly over its part (one trace: its middle).
pub fn overlay_colors(palette: OverlayPalette, n: usize) -> Vec<RGBColor> {
    match palette {
        OverlayPalette::Qualitative => (0..n)
            .map(|i| OVERLAY_QUALITATIVE[i % OVERLAY_QUALITATIVE.len()])
            .collect(),
        OverlayPalette::Sequential if n == 1 => vec![viridis(0.5)],
        OverlayPalette::Sequential => (0..n).map(|i| viridis(i as f64 / (n - 1) as f64)).collect(),
    }
}

/// `c` at 30 % on white: the colour of a trace's points below
/// [`MIN_COHERENCE`](crate::ident::frf::MIN_COHERENCE) (as
/// [`FAINT_COLOR`] is of [`MEASURED_COLOR`]).
pub fn faint(c: RGBColor) -> RGBColor {
    let f = |v: u8| (0.3 * f64::from(v) + 0.7 * 255.0).round() as u8;
    RGBColor(f(c.0), f(c.1), f(c.2))
}
