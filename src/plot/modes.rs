//! The decomposed-mode Bode plot of one bench's model
//! ([`write_decomposed_bode_png`], `bench analyze`): each mode's
//! contribution beside the total, whole band and zoomed on the pair.

use std::f64::consts::PI;
use std::path::Path;

use nalgebra::Complex;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;

use super::palette::MODE_SERIES;
use super::png::write_png_atomically;
use super::style::{analysis_font, ANALYSIS_LABEL_SIZE, ANALYSIS_SIZE, ANALYSIS_TITLE_SIZE};
use super::ticks::span;
use super::{Area, BoxError, PlotError};
use crate::analysis::modal::ModalTerm;
use crate::outputs::Existing;

/// The decomposed-mode Bode plot (thesis Fig 3-3, 3-11, 4-8): the
/// magnitude of each mode's contribution `αᵢ/(ωᵢ² − ω² + 2jζᵢωᵢω)` (m/N,
/// in dB) beside the total, over the full band (top) and zoomed on the
/// closely spaced pair (middle), and the total's phase (bottom). Each
/// mode is labelled with the sign of its residue.
///
/// # Errors
/// [`PlotError`] as for every PNG.
pub fn write_decomposed_bode_png(
    path: &Path,
    existing: Existing,
    title: &str,
    terms: &[ModalTerm],
) -> Result<(), PlotError> {
    let in_path: Vec<&ModalTerm> = terms.iter().filter(|t| t.in_path).collect();
    let fmin = in_path
        .iter()
        .map(|t| t.frequency_hz)
        .fold(f64::INFINITY, f64::min)
        .min(1e6);
    let fmax = in_path
        .iter()
        .map(|t| t.frequency_hz)
        .fold(0.0, f64::max)
        .max(fmin * 2.0);
    let (lo, hi) = ((fmin * 0.3).max(1e-3), fmax * 3.0);
    let n = 3000;
    let freqs: Vec<f64> = (0..n)
        .map(|i| lo * (hi / lo).powf(i as f64 / (n - 1) as f64))
        .collect();
    let contribution = |t: &ModalTerm, f: f64| {
        let w = 2.0 * PI * f;
        let wi = t.omega_rad_s();
        Complex::new(t.residue_per_kg, 0.0)
            / Complex::new(wi * wi - w * w, 2.0 * t.damping_ratio * wi * w)
    };
    let total: Vec<Complex<f64>> = freqs
        .iter()
        .map(|&f| in_path.iter().map(|t| contribution(t, f)).sum())
        .collect();
    let db = |c: Complex<f64>| 20.0 * c.norm().max(1e-300).log10();
    let mut phase = Vec::with_capacity(n);
    let mut prev = 0.0;
    for (i, c) in total.iter().enumerate() {
        let p = c.arg().to_degrees();
        let p = if i == 0 {
            // Start in (−360°, 0°]: a structural plant at low frequency.
            if p > 0.0 {
                p - 360.0
            } else {
                p
            }
        } else {
            p - 360.0 * ((p - prev) / 360.0).round()
        };
        phase.push(p);
        prev = p;
    }
    let pair: Vec<f64> = terms
        .iter()
        .filter(|t| t.label == "u" || t.label == "v")
        .map(|t| t.frequency_hz)
        .collect();
    let (plo, phi) = match (pair.first(), pair.last()) {
        (Some(a), Some(b)) => {
            let w = (b - a).abs().max(0.01 * b) * 2.0;
            (a.min(*b) - w, a.max(*b) + w)
        }
        _ => (lo, hi),
    };
    let series: Vec<(String, Vec<f64>)> = in_path
        .iter()
        .map(|t| {
            (
                format!(
                    "mode {} [{}], {:.1} Hz, α {} 0",
                    t.mode,
                    t.label,
                    t.frequency_hz,
                    if t.residue_per_kg > 0.0 { ">" } else { "<" }
                ),
                freqs.iter().map(|&f| db(contribution(t, f))).collect(),
            )
        })
        .collect();
    let total_db: Vec<f64> = total.iter().map(|c| db(*c)).collect();
    write_png_atomically(
        path,
        existing,
        ANALYSIS_SIZE,
        |root: &Area<'_>| -> Result<(), BoxError> {
            let root = root.titled(title, analysis_font(ANALYSIS_TITLE_SIZE))?;
            let areas = root.split_evenly((3, 1));
            let mag_range = |sel: &dyn Fn(f64) -> bool| {
                let vals = total_db
                    .iter()
                    .zip(&freqs)
                    .filter(|(_, f)| sel(**f))
                    .map(|(v, _)| *v)
                    .chain(series.iter().flat_map(|(_, s)| {
                        s.iter()
                            .zip(&freqs)
                            .filter(|(_, f)| sel(**f))
                            .map(|(v, _)| *v)
                    }));
                let r = span(vals, 0.1, 10.0);
                r.start.max(r.end - 200.0)..r.end
            };
            let panels: [(&str, std::ops::Range<f64>, bool); 2] = [
                ("magnitude, full band", lo..hi, true),
                ("magnitude, closely spaced pair", plo..phi, false),
            ];
            for (k, (caption, xr, log)) in panels.into_iter().enumerate() {
                let sel = |f: f64| f >= xr.start && f <= xr.end;
                let yr = mag_range(&sel);
                let panel = MagnitudePanel {
                    caption,
                    sel: &sel,
                    yr,
                    freqs: &freqs,
                    series: &series,
                    total_db: &total_db,
                };
                if log {
                    panel.draw(&areas[k], xr.clone().log_scale(), true)?;
                } else {
                    panel.draw(&areas[k], xr.clone(), false)?;
                }
            }
            let pr = span(phase.iter().copied(), 0.1, 90.0);
            let mut chart = ChartBuilder::on(&areas[2])
                .caption("phase of the total", analysis_font(ANALYSIS_LABEL_SIZE))
                .margin(10)
                .x_label_area_size(40)
                .y_label_area_size(80)
                .build_cartesian_2d((lo..hi).log_scale(), pr)?;
            chart
                .configure_mesh()
                .x_desc("frequency (Hz)")
                .y_desc("phase (deg)")
                .label_style(analysis_font(ANALYSIS_LABEL_SIZE - 4))
                .axis_desc_style(analysis_font(ANALYSIS_LABEL_SIZE - 2))
                .draw()?;
            chart.draw_series(LineSeries::new(
                freqs.iter().copied().zip(phase.iter().copied()),
                BLACK.stroke_width(3),
            ))?;
            Ok(())
        },
    )
}

/// One magnitude panel of [`write_decomposed_bode_png`]: each mode's
/// contribution and the total (dB re 1 m/N) over the frequencies `sel`
/// keeps, clipped to `yr`.
struct MagnitudePanel<'a> {
    caption: &'a str,
    sel: &'a dyn Fn(f64) -> bool,
    yr: std::ops::Range<f64>,
    freqs: &'a [f64],
    series: &'a [(String, Vec<f64>)],
    total_db: &'a [f64],
}

impl MagnitudePanel<'_> {
    /// Draws the panel on `area` over the frequency axis `x` (logarithmic
    /// or linear), with the series' legend at lower left when `legend`.
    fn draw<X>(&self, area: &Area<'_>, x: X, legend: bool) -> Result<(), BoxError>
    where
        X: AsRangedCoord<Value = f64>,
        X::CoordDescType: ValueFormatter<f64>,
    {
        let (sel, yr) = (self.sel, &self.yr);
        let mut chart = ChartBuilder::on(area)
            .caption(self.caption, analysis_font(ANALYSIS_LABEL_SIZE))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(80)
            .build_cartesian_2d(x, yr.clone())?;
        chart
            .configure_mesh()
            .x_desc("frequency (Hz)")
            .y_desc("dB re 1 m/N")
            .label_style(analysis_font(ANALYSIS_LABEL_SIZE - 4))
            .axis_desc_style(analysis_font(ANALYSIS_LABEL_SIZE - 2))
            .draw()?;
        let line = |values: &[f64]| {
            self.freqs
                .iter()
                .copied()
                .zip(values.iter().copied())
                .filter(|(f, v)| sel(*f) && yr.contains(v))
                .collect::<Vec<_>>()
        };
        for (i, (label, s)) in self.series.iter().enumerate() {
            let c = MODE_SERIES[i % MODE_SERIES.len()];
            let drawn = chart.draw_series(LineSeries::new(line(s), c.stroke_width(2)))?;
            if legend {
                drawn.label(label.clone()).legend(move |(x, y)| {
                    PathElement::new([(x, y), (x + 20, y)], c.stroke_width(2))
                });
            }
        }
        let drawn =
            chart.draw_series(LineSeries::new(line(self.total_db), BLACK.stroke_width(3)))?;
        if legend {
            drawn
                .label("total G(s)")
                .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK.stroke_width(3)));
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::LowerLeft)
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK.mix(0.3))
                .label_font(analysis_font(ANALYSIS_LABEL_SIZE - 4))
                .draw()?;
        }
        Ok(())
    }
}
