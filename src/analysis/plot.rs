//! PNG figures of the model analysis: the pole-zero map and the
//! decomposed-mode Bode plot of one bench (`bench analyze`), the CNMP map
//! (`bench map`, thesis Fig 2-5 / 5-2 / 5-10) and the veering plot
//! (`bench map --veering`, Fig 2-6). Written through
//! [`crate::plot`]'s atomic PNG writer (same rules as every output).

use super::map::{MapCell, VeeringCurve};
use super::modal::{ModalTerm, TypedZero};
use crate::outputs::Existing;
use crate::plot::{write_png_atomically, Area, BoxError, PlotError, FONT};
use bench_hal::model::{Sr4dof, ZeroType};
use nalgebra::Complex;
use plotters::prelude::*;
use std::f64::consts::PI;
use std::path::Path;

const SIZE: (u32, u32) = (1400, 1000);
const TITLE: u32 = 26;
const LABEL: u32 = 18;
const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(23, 190, 207),
];
const CNMP_COLOR: RGBColor = RGBColor(200, 30, 30);
const RNMP_COLOR: RGBColor = RGBColor(255, 127, 14);
const MMP_COLOR: RGBColor = RGBColor(60, 60, 60);
/// Shade of a map cell with CMP-CNMP zeros in both models.
pub const MAP_CNMP_BOTH: RGBColor = RGBColor(30, 30, 30);
/// Shade of a cell with CMP-CNMP zeros only without damping.
pub const MAP_CNMP_UNDAMPED_ONLY: RGBColor = RGBColor(150, 150, 150);
/// Colour of the measured-verdict markers.
pub const MEASURED_COLOR: RGBColor = RGBColor(31, 119, 180);

fn zero_color(k: ZeroType) -> RGBColor {
    match k {
        ZeroType::Mmp => MMP_COLOR,
        ZeroType::RmpRnmp => RNMP_COLOR,
        ZeroType::CmpCnmp => CNMP_COLOR,
    }
}

fn font(size: u32) -> TextStyle<'static> {
    (FONT, size).into_font().into()
}

fn span(values: impl Iterator<Item = f64>, pad: f64, min_span: f64) -> std::ops::Range<f64> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return -1.0..1.0;
    }
    let s = (hi - lo).max(min_span);
    let mid = 0.5 * (lo + hi);
    (mid - 0.5 * s * (1.0 + pad))..(mid + 0.5 * s * (1.0 + pad))
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
        SIZE,
        |root: &Area<'_>| -> Result<(), BoxError> {
            let root = root.titled(title, font(TITLE))?;
            let (left, right) = root.split_horizontally(SIZE.0 / 2);
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
                    .caption(caption, font(LABEL + 2))
                    .margin(15)
                    .x_label_area_size(50)
                    .y_label_area_size(80)
                    .build_cartesian_2d(xr.clone(), yr.clone())?;
                chart
                    .configure_mesh()
                    .x_desc("Re s / 2π (Hz)")
                    .y_desc("Im s / 2π (Hz)")
                    .label_style(font(LABEL - 2))
                    .axis_desc_style(font(LABEL))
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
                    .label_font(font(LABEL - 2))
                    .draw()?;
            }
            Ok(())
        },
    )
}

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
        SIZE,
        |root: &Area<'_>| -> Result<(), BoxError> {
            let root = root.titled(title, font(TITLE))?;
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
                let area = &areas[k];
                if log {
                    let mut chart = ChartBuilder::on(area)
                        .caption(caption, font(LABEL))
                        .margin(10)
                        .x_label_area_size(40)
                        .y_label_area_size(80)
                        .build_cartesian_2d((xr.clone()).log_scale(), yr.clone())?;
                    chart
                        .configure_mesh()
                        .x_desc("frequency (Hz)")
                        .y_desc("dB re 1 m/N")
                        .label_style(font(LABEL - 4))
                        .axis_desc_style(font(LABEL - 2))
                        .draw()?;
                    for (i, (label, s)) in series.iter().enumerate() {
                        let c = PALETTE[i % PALETTE.len()];
                        chart
                            .draw_series(LineSeries::new(
                                freqs
                                    .iter()
                                    .copied()
                                    .zip(s.iter().copied())
                                    .filter(|(f, v)| sel(*f) && yr.contains(v)),
                                c.stroke_width(2),
                            ))?
                            .label(label.clone())
                            .legend(move |(x, y)| {
                                PathElement::new([(x, y), (x + 20, y)], c.stroke_width(2))
                            });
                    }
                    chart
                        .draw_series(LineSeries::new(
                            freqs
                                .iter()
                                .copied()
                                .zip(total_db.iter().copied())
                                .filter(|(f, v)| sel(*f) && yr.contains(v)),
                            BLACK.stroke_width(3),
                        ))?
                        .label("total G(s)")
                        .legend(|(x, y)| {
                            PathElement::new([(x, y), (x + 20, y)], BLACK.stroke_width(3))
                        });
                    chart
                        .configure_series_labels()
                        .position(SeriesLabelPosition::LowerLeft)
                        .background_style(WHITE.mix(0.85))
                        .border_style(BLACK.mix(0.3))
                        .label_font(font(LABEL - 4))
                        .draw()?;
                } else {
                    let mut chart = ChartBuilder::on(area)
                        .caption(caption, font(LABEL))
                        .margin(10)
                        .x_label_area_size(40)
                        .y_label_area_size(80)
                        .build_cartesian_2d(xr.clone(), yr.clone())?;
                    chart
                        .configure_mesh()
                        .x_desc("frequency (Hz)")
                        .y_desc("dB re 1 m/N")
                        .label_style(font(LABEL - 4))
                        .axis_desc_style(font(LABEL - 2))
                        .draw()?;
                    for (i, (_, s)) in series.iter().enumerate() {
                        let c = PALETTE[i % PALETTE.len()];
                        chart.draw_series(LineSeries::new(
                            freqs
                                .iter()
                                .copied()
                                .zip(s.iter().copied())
                                .filter(|(f, v)| sel(*f) && yr.contains(v)),
                            c.stroke_width(2),
                        ))?;
                    }
                    chart.draw_series(LineSeries::new(
                        freqs
                            .iter()
                            .copied()
                            .zip(total_db.iter().copied())
                            .filter(|(f, v)| sel(*f) && yr.contains(v)),
                        BLACK.stroke_width(3),
                    ))?;
                }
            }
            let pr = span(phase.iter().copied(), 0.1, 90.0);
            let mut chart = ChartBuilder::on(&areas[2])
                .caption("phase of the total", font(LABEL))
                .margin(10)
                .x_label_area_size(40)
                .y_label_area_size(80)
                .build_cartesian_2d((lo..hi).log_scale(), pr)?;
            chart
                .configure_mesh()
                .x_desc("frequency (Hz)")
                .y_desc("phase (deg)")
                .label_style(font(LABEL - 4))
                .axis_desc_style(font(LABEL - 2))
                .draw()?;
            chart.draw_series(LineSeries::new(
                freqs.iter().copied().zip(phase.iter().copied()),
                BLACK.stroke_width(3),
            ))?;
            Ok(())
        },
    )
}

/// A measured verdict to overlay on the map (thesis Fig 5-10).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasuredPoint {
    /// Operating point, m.
    pub operating_point_m: f64,
    /// Mass asymmetry Δm23.
    pub mass_asymmetry: f64,
    /// CMP-CNMP measured (`true`: square) or not (`false`: circle).
    pub cnmp: bool,
}

/// The CNMP map in the style of the thesis' Fig 2-5 / 5-2: operating
/// point (% of L) across, mass asymmetry (%) up; cells with CMP-CNMP zeros
/// in both the undamped and the damped model black, in the undamped one
/// only grey; a dashed vertical line at the mode-crossing operating point
/// (of the symmetric stage); measured verdicts as squares (CMP-CNMP) and
/// circles (none), as Fig 5-10.
///
/// # Errors
/// [`PlotError`] as for every PNG.
#[allow(clippy::too_many_arguments)]
pub fn write_map_png(
    path: &Path,
    existing: Existing,
    title: &str,
    beam_length_m: f64,
    operating_points_m: &[f64],
    mass_asymmetries: &[f64],
    cells: &[MapCell],
    crossing_operating_point_m: Option<f64>,
    measured: &[MeasuredPoint],
) -> Result<(), PlotError> {
    let pct_l = |m: f64| m / beam_length_m * 100.0;
    let step = |v: &[f64]| {
        if v.len() > 1 {
            (v[1] - v[0]).abs()
        } else {
            1e-3
        }
    };
    let (dx, dy) = (
        pct_l(step(operating_points_m)),
        step(mass_asymmetries) * 100.0,
    );
    let xr = span(operating_points_m.iter().map(|&m| pct_l(m)), 0.0, 0.1);
    let xr = (xr.start - 0.5 * dx)..(xr.end + 0.5 * dx);
    let yr = span(mass_asymmetries.iter().map(|d| d * 100.0), 0.0, 0.1);
    let yr = (yr.start - 0.5 * dy)..(yr.end + 0.5 * dy);
    write_png_atomically(
        path,
        existing,
        SIZE,
        |root: &Area<'_>| -> Result<(), BoxError> {
            let mut chart = ChartBuilder::on(root)
                .caption(title, font(TITLE))
                .margin(20)
                .x_label_area_size(60)
                .y_label_area_size(90)
                .build_cartesian_2d(xr.clone(), yr.clone())?;
            chart
                .configure_mesh()
                .disable_mesh()
                .x_desc("operating point Y1o (% of L)")
                .y_desc("mass asymmetry Δm23 (%)")
                .label_style(font(LABEL))
                .axis_desc_style(font(LABEL + 2))
                .draw()?;
            for (shade, pick, label) in [
                (
                    MAP_CNMP_BOTH,
                    (true, true),
                    "CMP-CNMP zeros (undamped and damped model)",
                ),
                (
                    MAP_CNMP_UNDAMPED_ONLY,
                    (true, false),
                    "CMP-CNMP zeros (undamped model only)",
                ),
            ] {
                chart
                    .draw_series(
                        cells
                            .iter()
                            .filter(|c| (c.cnmp, c.cnmp_damped) == pick)
                            .map(|c| {
                                let x = pct_l(c.operating_point_m);
                                let y = c.mass_asymmetry * 100.0;
                                Rectangle::new(
                                    [(x - 0.5 * dx, y - 0.5 * dy), (x + 0.5 * dx, y + 0.5 * dy)],
                                    shade.filled(),
                                )
                            }),
                    )?
                    .label(label)
                    .legend(move |(x, y)| {
                        Rectangle::new([(x, y - 6), (x + 14, y + 6)], shade.filled())
                    });
            }
            if let Some(op) = crossing_operating_point_m {
                let x = pct_l(op);
                chart
                    .draw_series(DashedLineSeries::new(
                        [(x, yr.start), (x, yr.end)],
                        10,
                        6,
                        CNMP_COLOR.stroke_width(2),
                    ))?
                    .label(format!("mode crossing (Δm23 = 0) at {x:.2} % of L"))
                    .legend(|(x, y)| {
                        PathElement::new([(x, y), (x + 20, y)], CNMP_COLOR.stroke_width(2))
                    });
            }
            if !measured.is_empty() {
                chart
                    .draw_series(measured.iter().filter(|m| m.cnmp).map(|m| {
                        let p = (pct_l(m.operating_point_m), m.mass_asymmetry * 100.0);
                        EmptyElement::at(p)
                            + Rectangle::new([(-8, -8), (8, 8)], WHITE.filled())
                            + Rectangle::new([(-8, -8), (8, 8)], MEASURED_COLOR.stroke_width(3))
                    }))?
                    .label("measured: CMP-CNMP")
                    .legend(|(x, y)| {
                        Rectangle::new(
                            [(x, y - 6), (x + 12, y + 6)],
                            MEASURED_COLOR.stroke_width(3),
                        )
                    });
                chart
                    .draw_series(measured.iter().filter(|m| !m.cnmp).map(|m| {
                        let p = (pct_l(m.operating_point_m), m.mass_asymmetry * 100.0);
                        EmptyElement::at(p)
                            + Circle::new((0, 0), 8, WHITE.filled())
                            + Circle::new((0, 0), 8, MEASURED_COLOR.stroke_width(3))
                    }))?
                    .label("measured: none")
                    .legend(|(x, y)| Circle::new((x + 6, y), 6, MEASURED_COLOR.stroke_width(3)));
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::LowerLeft)
                .background_style(WHITE.mix(0.9))
                .border_style(BLACK.mix(0.4))
                .label_font(font(LABEL - 2))
                .draw()?;
            Ok(())
        },
    )
}

/// Curve veering (thesis Fig 2-6): the pair's natural frequencies against
/// operating point (% of L) for each asymmetry, with the operating-point
/// intervals of CMP-CNMP zeros (undamped) shaded in the curve's colour and
/// the closest approach marked (top); the localisation
/// `(y2² − y3²)/(y2² + y3²)` of each mode's shape (bottom: +1 on stage ②,
/// −1 on ③).
///
/// # Errors
/// [`PlotError`] as for every PNG.
pub fn write_veering_png(
    path: &Path,
    existing: Existing,
    title: &str,
    beam_length_m: f64,
    curves: &[VeeringCurve],
) -> Result<(), PlotError> {
    let pct_l = |m: f64| m / beam_length_m * 100.0;
    let xr = span(
        curves
            .iter()
            .flat_map(|c| c.points.iter().map(|p| pct_l(p.operating_point_m))),
        0.0,
        0.1,
    );
    let yr = span(
        curves.iter().flat_map(|c| {
            c.points
                .iter()
                .flat_map(|p| [p.frequency_u_hz, p.frequency_v_hz])
        }),
        0.1,
        1.0,
    );
    write_png_atomically(
        path,
        existing,
        SIZE,
        |root: &Area<'_>| -> Result<(), BoxError> {
            let root = root.titled(title, font(TITLE))?;
            let (top, bottom) = root.split_vertically(SIZE.1 * 6 / 10);
            let mut chart = ChartBuilder::on(&top)
                .caption(
                    "natural frequencies of the closely spaced pair (shaded: CMP-CNMP zeros)",
                    font(LABEL),
                )
                .margin(10)
                .x_label_area_size(45)
                .y_label_area_size(80)
                .build_cartesian_2d(xr.clone(), yr.clone())?;
            chart
                .configure_mesh()
                .x_desc("operating point Y1o (% of L)")
                .y_desc("frequency (Hz)")
                .label_style(font(LABEL - 2))
                .axis_desc_style(font(LABEL))
                .draw()?;
            let band = (yr.end - yr.start) / (2.0 * curves.len().max(1) as f64);
            for (i, c) in curves.iter().enumerate() {
                let col = PALETTE[i % PALETTE.len()];
                // Shaded interval: a band at the bottom of the panel per curve.
                for iv in &c.cnmp_intervals_m {
                    chart.draw_series([Rectangle::new(
                        [
                            (pct_l(iv[0]), yr.start + band * i as f64 * 0.2),
                            (pct_l(iv[1]).max(pct_l(iv[0]) + 0.01), yr.end),
                        ],
                        col.mix(0.12).filled(),
                    )])?;
                }
                chart
                    .draw_series(LineSeries::new(
                        c.points
                            .iter()
                            .map(|p| (pct_l(p.operating_point_m), p.frequency_u_hz)),
                        col.stroke_width(2),
                    ))?
                    .label(format!(
                        "Δm23 = {:+.1} %: closest {:.2} Hz apart at {:.2} % of L",
                        c.mass_asymmetry * 100.0,
                        c.closest_gap_hz,
                        pct_l(c.closest_operating_point_m)
                    ))
                    .legend(move |(x, y)| {
                        PathElement::new([(x, y), (x + 20, y)], col.stroke_width(2))
                    });
                chart.draw_series(LineSeries::new(
                    c.points
                        .iter()
                        .map(|p| (pct_l(p.operating_point_m), p.frequency_v_hz)),
                    col.stroke_width(2),
                ))?;
                let x = pct_l(c.closest_operating_point_m);
                let half = 0.5 * c.closest_gap_hz;
                chart.draw_series([
                    Circle::new((x, c.closest_frequency_hz - half), 6, col.filled()),
                    Circle::new((x, c.closest_frequency_hz + half), 6, col.filled()),
                ])?;
            }
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .background_style(WHITE.mix(0.9))
                .border_style(BLACK.mix(0.4))
                .label_font(font(LABEL - 4))
                .draw()?;
            let mut chart = ChartBuilder::on(&bottom)
            .caption("localisation of the mode shapes: +1 on stage ②, −1 on stage ③ (solid u, dashed v)", font(LABEL))
            .margin(10)
            .x_label_area_size(45)
            .y_label_area_size(80)
            .build_cartesian_2d(xr.clone(), -1.1f64..1.1f64)?;
            chart
                .configure_mesh()
                .x_desc("operating point Y1o (% of L)")
                .y_desc("(y2² − y3²)/(y2² + y3²)")
                .label_style(font(LABEL - 2))
                .axis_desc_style(font(LABEL))
                .draw()?;
            for (i, c) in curves.iter().enumerate() {
                let col = PALETTE[i % PALETTE.len()];
                chart.draw_series(LineSeries::new(
                    c.points
                        .iter()
                        .map(|p| (pct_l(p.operating_point_m), p.localisation_u)),
                    col.stroke_width(2),
                ))?;
                chart.draw_series(DashedLineSeries::new(
                    c.points
                        .iter()
                        .map(|p| (pct_l(p.operating_point_m), p.localisation_v)),
                    8,
                    5,
                    col.stroke_width(2),
                ))?;
            }
            Ok(())
        },
    )
}
