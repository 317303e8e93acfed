//! The Bode figure ([`write_bode_png`]): magnitude, phase and coherence
//! of a measured FRF on a logarithmic frequency axis, with an optional
//! model overlay, resonance markers and, below, the zoom on the closely
//! spaced pair ([`super::pair_zoom`]).

use std::ops::Range;
use std::path::Path;

use plotters::prelude::*;

use super::axes::{frame, freq_chart, plot_columns, Chart, Ticked, MARGIN_TOP, X_LABEL_AREA};
use super::draw::{draw_runs, hline, pairs, runs, shade, values_in, vline};
use super::legend::{
    draw_marker_labels, entry, layout_marker_labels, legend_height, marker_row_height,
    panel_legend, titled, Swatch,
};
use super::measured::{draw_measured, to_db, BodeCurves};
use super::pair_zoom::{draw_no_pair, draw_pair_zoom, pair_window, PairZoom, ZoomLabels};
use super::palette::{
    FAINT_COLOR, MARKER_COLOR, MEASURED_COLOR, MODEL_COLOR, SETTLE_COLOR, ZOOM_SHADE,
    ZOOM_SHADE_ALPHA,
};
use super::png::{invalid, write_png_atomically};
use super::style::LINE_WIDTH;
use super::ticks::{fmt_sig, linear_ticks, log_range, padded_range, phase_ticks, positive_extent};
use super::{Area, BoxError, PlotError};
use crate::ident::frf::MIN_COHERENCE;
use crate::outputs::Existing;

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
    /// The measured `frf` as a figure's curve with the legend `label`
    /// (naming the estimator that made it where it is known).
    pub fn measured(frf: &'a crate::ident::frf::Frf, label: &'a str) -> Self {
        Self {
            label,
            frequency_hz: &frf.frequency_hz,
            magnitude: &frf.magnitude_m_per_a,
            phase_deg: &frf.phase_deg,
        }
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
    /// The magnitude axis' label, with its unit: [`MAGNITUDE_M_PER_A`]
    /// for a plant's response, e.g. `|S| [dB]` for a dimensionless one.
    pub magnitude_axis: &'a str,
}

/// The magnitude axis of a response in m/A ([`BodePlot::magnitude_axis`]).
pub const MAGNITUDE_M_PER_A: &str = "Magnitude [dB re 1 m/A]";

/// Width of every figure, and height of the Bode figure's main panels, px.
const BODE_SIZE: (u32, u32) = (1400, 1000);

/// Height added to the Bode figure by the pair zoom, px.
const BODE_ZOOM_H: u32 = 650;

/// Writes a Bode figure of `plot` as a PNG to `path`: 1400x1000 px, or
/// 1400x1650 px with a pair zoom.
///
/// Main panels from top to bottom: magnitude in dB (20·log10 of the
/// linear magnitude; dB re 1 m/A for a plant, labelled by
/// [`BodePlot::magnitude_axis`]), unwrapped phase in degrees and coherence
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

/// Checks that the columns of `s` have one value per frequency.
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

/// The curves of `plot` in plot units.
fn curves(plot: &BodePlot<'_>) -> BodeCurves {
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
    BodeCurves {
        meas_db: db(meas.frequency_hz, meas.magnitude),
        meas_phase: pairs(meas.frequency_hz, meas.phase_deg),
        coh: pairs(meas.frequency_hz, plot.coherence),
        good: plot.coherence.iter().map(|&c| c >= MIN_COHERENCE).collect(),
        model_db,
        model_phase,
    }
}

/// Draws the figure of [`write_bode_png`]: the main panels, then the pair
/// zoom below them when there is one.
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
    let curves = curves(plot);
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
                let labels = ZoomLabels {
                    measured: plot.measured.label,
                    model: plot.model.as_ref().map(|m| m.label),
                    magnitude_axis: plot.magnitude_axis,
                };
                draw_pair_zoom(root, &area, &labels, &curves, &pair, band_phase_deg, &w)?;
            }
            (PairZoom::Unresolved { reason }, _) => draw_no_pair(root, &area, reason)?,
            _ => {}
        }
    }
    Ok(())
}

/// The legend of the Bode figure's magnitude panel: the measurement (and
/// its faint, incoherent lines), the model, the resonance markers and the
/// zoomed window, each when drawn.
fn main_legend(plot: &BodePlot<'_>, markers: bool, window: bool) -> Vec<super::legend::Entry> {
    let meas = &plot.measured;
    let mut entries = vec![
        entry(meas.label, Swatch::Line(MEASURED_COLOR, LINE_WIDTH)),
        entry(
            format!("{}, coherence < {}", meas.label, fmt_sig(MIN_COHERENCE, 3)),
            Swatch::Line(FAINT_COLOR, LINE_WIDTH),
        ),
    ];
    if let Some(m) = plot.model.as_ref() {
        entries.push(entry(m.label, Swatch::Dashed(MODEL_COLOR)));
    }
    if markers {
        entries.push(entry("resonance found", Swatch::Dashed(MARKER_COLOR)));
    }
    if window {
        entries.push(entry(
            "zoomed below",
            Swatch::Fill(ZOOM_SHADE, ZOOM_SHADE_ALPHA * 2.0),
        ));
    }
    entries
}

/// The main panels on `area`: magnitude (with the legend and the marker
/// labels above it), phase and coherence on `x_range`, the pair zoom's
/// `window` shaded.
fn draw_bode_main(
    root: &Area<'_>,
    area: &Area<'_>,
    plot: &BodePlot<'_>,
    c: &BodeCurves,
    x_range: &Range<f64>,
    window: Option<&Range<f64>>,
) -> Result<(), BoxError> {
    let body = titled(area, plot.title)?;
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
    let entries = main_legend(plot, !markers.is_empty(), window.is_some());
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
        let mut chart = freq_chart(
            &mag_area,
            x_range,
            &db_range,
            y_ticks,
            mag_top,
            false,
            "",
            plot.magnitude_axis,
        )?;
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
        let mut chart = freq_chart(
            &phase_area,
            x_range,
            &phase_range,
            y_ticks,
            MARGIN_TOP,
            false,
            "",
            "Phase [°]",
        )?;
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
        let mut chart = freq_chart(
            &coh_area,
            x_range,
            &coh_range,
            y_ticks,
            coh_top,
            true,
            "Frequency [Hz]",
            "Coherence [-]",
        )?;
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
