//! The pole-zero map of one bench's model ([`write_pole_zero_png`],
//! `bench analyze`): poles and zeros typed MMP / RMP-RNMP / CMP-CNMP,
//! whole and zoomed on the closely spaced pair.

use std::f64::consts::PI;
use std::path::Path;

use bench_plant::model::{Sr4dof, ZeroType};
use nalgebra::Complex;
use plotters::prelude::*;

use super::palette::{CNMP_COLOR, MMP_COLOR, RNMP_COLOR};
use super::png::write_png_atomically;
use super::style::{analysis_font, ANALYSIS_LABEL_SIZE, ANALYSIS_SIZE, ANALYSIS_TITLE_SIZE};
use super::{Area, BoxError, PlotError};
use crate::analysis::modal::{ModalTerm, TypedZero};
use crate::outputs::Existing;

/// The colour of a zero of type `k` in the pole-zero map.
fn zero_color(k: ZeroType) -> RGBColor {
    match k {
        ZeroType::Mmp => MMP_COLOR,
        ZeroType::RmpRnmp => RNMP_COLOR,
        ZeroType::CmpCnmp => CNMP_COLOR,
    }
}

/// The damped poles of `model`, rad/s: `−ζω ± jω√(1−ζ²)` per mode.
fn poles(model: &Sr4dof) -> Vec<Complex<f64>> {
    model
        .modes()
        .iter()
        .flat_map(|m| {
            let w = m.omega_rad_s;
            let wd = w * (1.0 - m.zeta * m.zeta).max(0.0).sqrt();
            [
                Complex::new(-m.zeta * w, wd),
                Complex::new(-m.zeta * w, -wd),
            ]
        })
        .collect()
}

/// Pole-zero map of the damped force → x1 transfer function: the whole
/// map (left) and a zoom on the closely spaced pair (right), in Hz
/// (`s/2π`). Poles `×` (black); zeros `○` coloured by type: MMP grey,
/// RMP-RNMP orange, CMP-CNMP red. Modes outside the path are drawn as
/// poles too (they cancel with a zero in the full model).
///
/// # Errors
/// [`PlotError`] as for every PNG.
pub fn write_pole_zero_png(
    path: &Path,
    existing: Existing,
    title: &str,
    model: &Sr4dof,
    zeros: &[TypedZero],
    terms: &[ModalTerm],
) -> Result<(), PlotError> {
    let to_hz = |s: Complex<f64>| (s.re / (2.0 * PI), s.im / (2.0 * PI));
    let ps: Vec<(f64, f64)> = poles(model).into_iter().map(to_hz).collect();
    let zs: Vec<((f64, f64), ZeroType)> = zeros.iter().map(|z| (to_hz(z.s()), z.kind)).collect();
    let pair: Vec<f64> = terms
        .iter()
        .filter(|t| t.label == "u" || t.label == "v")
        .map(|t| t.frequency_hz)
        .collect();
    write_png_atomically(
        path,
        existing,
        ANALYSIS_SIZE,
        |root: &Area<'_>| -> Result<(), BoxError> {
            let root = root.titled(title, analysis_font(ANALYSIS_TITLE_SIZE))?;
            let (left, right) = root.split_horizontally(ANALYSIS_SIZE.0 / 2);
            let all_im = ps.iter().map(|p| p.1).chain(zs.iter().map(|z| z.0 .1));
            let ymax = all_im.fold(1.0f64, |a, v| a.max(v.abs())) * 1.1;
            let xmax = ps
                .iter()
                .map(|p| p.0.abs())
                .chain(zs.iter().map(|z| z.0 .0.abs()))
                .fold(0.05 * ymax, f64::max)
                * 1.2;
            let full = (-xmax..xmax, -ymax..ymax);
            let (flo, fhi) = match (pair.first(), pair.last()) {
                (Some(a), Some(b)) => (a.min(*b), a.max(*b)),
                _ => (0.0, ymax),
            };
            let band = ((fhi - flo).max(0.02 * fhi)) * 1.5;
            let zy = (flo - band)..(fhi + band);
            let in_band = |y: f64| y >= zy.start && y <= zy.end;
            let zx = ps
                .iter()
                .filter(|p| in_band(p.1))
                .map(|p| p.0.abs())
                .chain(zs.iter().filter(|z| in_band(z.0 .1)).map(|z| z.0 .0.abs()))
                .fold(1e-3 * fhi.max(1.0), f64::max)
                * 1.5;
            for (area, (xr, yr), caption) in [
                (&left, full, "whole map"),
                (
                    &right,
                    (-zx..zx, zy.clone()),
                    "zoom on the closely spaced pair",
                ),
            ] {
                let mut chart = ChartBuilder::on(area)
                    .caption(caption, analysis_font(ANALYSIS_LABEL_SIZE + 2))
                    .margin(15)
                    .x_label_area_size(50)
                    .y_label_area_size(80)
                    .build_cartesian_2d(xr.clone(), yr.clone())?;
                chart
                    .configure_mesh()
                    .x_desc("Re s / 2π (Hz)")
                    .y_desc("Im s / 2π (Hz)")
                    .label_style(analysis_font(ANALYSIS_LABEL_SIZE - 2))
                    .axis_desc_style(analysis_font(ANALYSIS_LABEL_SIZE))
                    .draw()?;
                chart.draw_series(LineSeries::new(
                    [(0.0, yr.start), (0.0, yr.end)],
                    BLACK.mix(0.4),
                ))?;
                chart
                    .draw_series(
                        ps.iter()
                            .filter(|p| xr.contains(&p.0) && yr.contains(&p.1))
                            .map(|p| Cross::new(*p, 8, BLACK.stroke_width(2))),
                    )?
                    .label("pole")
                    .legend(|(x, y)| Cross::new((x + 10, y), 6, BLACK.stroke_width(2)));
                for kind in [ZeroType::Mmp, ZeroType::RmpRnmp, ZeroType::CmpCnmp] {
                    let c = zero_color(kind);
                    chart
                        .draw_series(
                            zs.iter()
                                .filter(|z| {
                                    z.1 == kind && xr.contains(&z.0 .0) && yr.contains(&z.0 .1)
                                })
                                .map(|z| Circle::new(z.0, 8, c.stroke_width(3))),
                        )?
                        .label(format!("zero, {}", kind.as_str()))
                        .legend(move |(x, y)| Circle::new((x + 10, y), 6, c.stroke_width(3)));
                }
                chart
                    .configure_series_labels()
                    .position(SeriesLabelPosition::UpperLeft)
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK.mix(0.3))
                    .label_font(analysis_font(ANALYSIS_LABEL_SIZE - 2))
                    .draw()?;
            }
            Ok(())
        },
    )
}
