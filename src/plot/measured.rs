//! The measured and model curves of a Bode figure in plot units
//! ([`BodeCurves`]: dB and degrees against Hz), and how a measured curve is
//! drawn (faint below [`MIN_COHERENCE`](crate::ident::frf::MIN_COHERENCE), solid above, dotted on request):
//! shared by the Bode figure's main panels, its pair zoom, the overlay
//! and the design figure.

use std::ops::Range;

use plotters::coord::ranged1d::Ranged;
use plotters::prelude::*;

use super::axes::Chart;
use super::draw::{draw_polyline, runs};
use super::palette::{FAINT_COLOR, MEASURED_COLOR};
use super::style::LINE_WIDTH;
use super::BoxError;

/// Magnitude in dB (20·log10), NaN where it has no logarithm.
pub(super) fn to_db(m: f64) -> f64 {
    if m > 0.0 && m.is_finite() {
        20.0 * m.log10()
    } else {
        f64::NAN
    }
}

/// The curves of a Bode figure in plot units.
pub(super) struct BodeCurves {
    /// Measured magnitude, `(Hz, dB re 1 m/A)`.
    pub(super) meas_db: Vec<(f64, f64)>,
    /// Measured phase, `(Hz, °)`.
    pub(super) meas_phase: Vec<(f64, f64)>,
    /// Coherence, `(Hz, γ²)`.
    pub(super) coh: Vec<(f64, f64)>,
    /// Coherence at or above [`MIN_COHERENCE`](crate::ident::frf::MIN_COHERENCE) (NaN is not).
    pub(super) good: Vec<bool>,
    /// Model magnitude, `(Hz, dB re 1 m/A)` (empty without a model).
    pub(super) model_db: Vec<(f64, f64)>,
    /// Model phase, `(Hz, °)`.
    pub(super) model_phase: Vec<(f64, f64)>,
}

impl BodeCurves {
    /// The y values inside `x_range` that set an axis: the measured points
    /// of good coherence (all of them if none is good) and the model's.
    pub(super) fn y_values(
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
pub(super) fn draw_measured<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    pts: &[(f64, f64)],
    good: &[bool],
    x_range: &Range<f64>,
    log_x: bool,
    dots: bool,
) -> Result<(), BoxError> {
    let style = MeasuredStyle {
        color: MEASURED_COLOR,
        faint: Some(FAINT_COLOR),
        width: LINE_WIDTH,
        dots,
    };
    draw_measured_as(chart, pts, good, x_range, log_x, &style)
}

/// How a measured curve is drawn ([`draw_measured_as`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct MeasuredStyle {
    /// The points of good coherence.
    pub(super) color: RGBColor,
    /// The points below [`MIN_COHERENCE`](crate::ident::frf::MIN_COHERENCE) (`None`: not drawn, e.g.
    /// drawn for every curve first, under all the good points).
    pub(super) faint: Option<RGBColor>,
    /// Line width, px.
    pub(super) width: u32,
    /// A dot on each grid point.
    pub(super) dots: bool,
}

/// [`draw_measured`] in `style`'s colours and width.
pub(super) fn draw_measured_as<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    pts: &[(f64, f64)],
    good: &[bool],
    x_range: &Range<f64>,
    log_x: bool,
    style: &MeasuredStyle,
) -> Result<(), BoxError> {
    if let Some(faint) = style.faint {
        for run in runs(pts, x_range, log_x) {
            draw_polyline(chart, &run, faint, style.width)?;
        }
    }
    let solid: Vec<(f64, f64)> = pts
        .iter()
        .zip(good)
        .map(|(p, g)| if *g { *p } else { (p.0, f64::NAN) })
        .collect();
    for run in runs(&solid, x_range, log_x) {
        draw_polyline(chart, &run, style.color, style.width)?;
    }
    if style.dots {
        let inside = |p: &(f64, f64)| p.0 >= x_range.start && p.0 <= x_range.end && p.1.is_finite();
        chart.draw_series(
            pts.iter()
                .zip(good)
                .filter(|(p, g)| inside(p) && (**g || style.faint.is_some()))
                .map(|(p, g)| {
                    let c = match (g, style.faint) {
                        (false, Some(f)) => f,
                        _ => style.color,
                    };
                    Circle::new(*p, 3, c.filled())
                }),
        )?;
    }
    Ok(())
}
