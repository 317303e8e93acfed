//! Figures over operating point × mass asymmetry (`bench map`, `bench
//! campaign`): the CNMP map with measured verdicts overlaid
//! ([`write_map_png`]) and curve veering ([`write_veering_png`]).

use std::path::Path;

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::palette::{
    CNMP_COLOR, MAP_CNMP_BOTH, MAP_CNMP_UNDAMPED_ONLY, MEASURED_COLOR, MODE_SERIES,
};
use super::png::write_png_atomically;
use super::style::{analysis_font, ANALYSIS_LABEL_SIZE, ANALYSIS_SIZE, ANALYSIS_TITLE_SIZE};
use super::ticks::span;
use super::{Area, BoxError, PlotError};
use crate::analysis::map::{MapCell, VeeringCurve};
use crate::outputs::Existing;

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
/// circles (none), as Fig 5-10; the configured bench (`configured`:
/// operating point, m, and mass asymmetry) as a cross.
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
    configured: Option<(f64, f64)>,
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
        ANALYSIS_SIZE,
        |root: &Area<'_>| -> Result<(), BoxError> {
            // The legend in a strip below the map, off the cells.
            let mut legend: Vec<(String, MapSwatch)> = Vec::new();
            let rows = 2
                + u32::from(crossing_operating_point_m.is_some())
                + 2 * u32::from(!measured.is_empty())
                + u32::from(configured.is_some());
            let legend_h = LEGEND_ROW_PX * rows.div_ceil(2) + 20;
            let (top, strip) = root.split_vertically(ANALYSIS_SIZE.1 - legend_h);
            let mut chart = ChartBuilder::on(&top)
                .caption(title, analysis_font(ANALYSIS_TITLE_SIZE))
                .margin(20)
                .x_label_area_size(60)
                .y_label_area_size(90)
                .build_cartesian_2d(xr.clone(), yr.clone())?;
            chart
                .configure_mesh()
                .disable_mesh()
                .x_desc("operating point Y1o (% of L)")
                .y_desc("mass asymmetry Δm23 (%)")
                .label_style(analysis_font(ANALYSIS_LABEL_SIZE))
                .axis_desc_style(analysis_font(ANALYSIS_LABEL_SIZE + 2))
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
                chart.draw_series(
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
                )?;
                legend.push((label.to_string(), MapSwatch::Fill(shade)));
            }
            if let Some(op) = crossing_operating_point_m {
                let x = pct_l(op);
                chart.draw_series(DashedLineSeries::new(
                    [(x, yr.start), (x, yr.end)],
                    10,
                    6,
                    CNMP_COLOR.stroke_width(2),
                ))?;
                legend.push((
                    format!("mode crossing (Δm23 = 0) at {x:.2} % of L"),
                    MapSwatch::Dashed(CNMP_COLOR),
                ));
            }
            if !measured.is_empty() {
                chart.draw_series(measured.iter().filter(|m| m.cnmp).map(|m| {
                    let p = (pct_l(m.operating_point_m), m.mass_asymmetry * 100.0);
                    EmptyElement::at(p)
                        + Rectangle::new([(-8, -8), (8, 8)], WHITE.filled())
                        + Rectangle::new([(-8, -8), (8, 8)], MEASURED_COLOR.stroke_width(3))
                }))?;
                legend.push((
                    "measured: CMP-CNMP".into(),
                    MapSwatch::Square(MEASURED_COLOR),
                ));
                chart.draw_series(measured.iter().filter(|m| !m.cnmp).map(|m| {
                    let p = (pct_l(m.operating_point_m), m.mass_asymmetry * 100.0);
                    EmptyElement::at(p)
                        + Circle::new((0, 0), 8, WHITE.filled())
                        + Circle::new((0, 0), 8, MEASURED_COLOR.stroke_width(3))
                }))?;
                legend.push(("measured: none".into(), MapSwatch::Circle(MEASURED_COLOR)));
            }
            if let Some((op, dm)) = configured {
                let p = (pct_l(op), dm * 100.0);
                let cross = |(x, y): (i32, i32), r: i32| {
                    [
                        PathElement::new(
                            [(x - r, y - r), (x + r, y + r)],
                            CNMP_COLOR.stroke_width(3),
                        ),
                        PathElement::new(
                            [(x - r, y + r), (x + r, y - r)],
                            CNMP_COLOR.stroke_width(3),
                        ),
                    ]
                };
                let [a, b] = cross((0, 0), 8);
                chart.draw_series(std::iter::once(
                    EmptyElement::at(p) + Circle::new((0, 0), 11, WHITE.mix(0.8).filled()) + a + b,
                ))?;
                legend.push((
                    format!("configured bench ({:.2} % of L, Δm23 = {:+.1} %)", p.0, p.1),
                    MapSwatch::Cross(CNMP_COLOR),
                ));
            }
            draw_map_legend(&strip, &legend)?;
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
        ANALYSIS_SIZE,
        |root: &Area<'_>| -> Result<(), BoxError> {
            let root = root.titled(title, analysis_font(ANALYSIS_TITLE_SIZE))?;
            let (top, bottom) = root.split_vertically(ANALYSIS_SIZE.1 * 6 / 10);
            let mut chart = ChartBuilder::on(&top)
                .caption(
                    "natural frequencies of the closely spaced pair (shaded: CMP-CNMP zeros)",
                    analysis_font(ANALYSIS_LABEL_SIZE),
                )
                .margin(10)
                .x_label_area_size(45)
                .y_label_area_size(80)
                .build_cartesian_2d(xr.clone(), yr.clone())?;
            chart
                .configure_mesh()
                .x_desc("operating point Y1o (% of L)")
                .y_desc("frequency (Hz)")
                .label_style(analysis_font(ANALYSIS_LABEL_SIZE - 2))
                .axis_desc_style(analysis_font(ANALYSIS_LABEL_SIZE))
                .draw()?;
            let band = (yr.end - yr.start) / (2.0 * curves.len().max(1) as f64);
            for (i, c) in curves.iter().enumerate() {
                let col = MODE_SERIES[i % MODE_SERIES.len()];
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
                .label_font(analysis_font(ANALYSIS_LABEL_SIZE - 4))
                .draw()?;
            let caption = "localisation of the mode shapes: +1 on stage ②, −1 on stage ③ \
                           (solid u, dashed v)";
            let mut chart = ChartBuilder::on(&bottom)
                .caption(caption, analysis_font(ANALYSIS_LABEL_SIZE))
                .margin(10)
                .x_label_area_size(45)
                .y_label_area_size(80)
                .build_cartesian_2d(xr.clone(), -1.1f64..1.1f64)?;
            chart
                .configure_mesh()
                .x_desc("operating point Y1o (% of L)")
                .y_desc("(y2² − y3²)/(y2² + y3²)")
                .label_style(analysis_font(ANALYSIS_LABEL_SIZE - 2))
                .axis_desc_style(analysis_font(ANALYSIS_LABEL_SIZE))
                .draw()?;
            for (i, c) in curves.iter().enumerate() {
                let col = MODE_SERIES[i % MODE_SERIES.len()];
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

/// Height of a row of the map's legend strip, px.
const LEGEND_ROW_PX: u32 = 28;

/// The swatch of a map legend entry.
#[derive(Clone, Copy)]
enum MapSwatch {
    /// A filled cell.
    Fill(RGBColor),
    /// A dashed line.
    Dashed(RGBColor),
    /// An open square (a measured CMP-CNMP cell).
    Square(RGBColor),
    /// An open circle (a measured cell without).
    Circle(RGBColor),
    /// A cross (the configured bench).
    Cross(RGBColor),
}

/// The map's legend in `strip` (below the map): two columns of entries,
/// each a swatch and its text.
fn draw_map_legend(strip: &Area<'_>, entries: &[(String, MapSwatch)]) -> Result<(), BoxError> {
    let (w, _) = strip.dim_in_pixel();
    let left = 110_i32;
    let col_w = (i32::try_from(w)? - left) / 2;
    let half = entries.len().div_ceil(2);
    for (k, (text, swatch)) in entries.iter().enumerate() {
        let x = left + col_w * i32::try_from(k / half)?;
        let y = 14 + i32::try_from(LEGEND_ROW_PX)? * i32::try_from(k % half)?;
        match *swatch {
            MapSwatch::Fill(c) => {
                strip.draw(&Rectangle::new([(x, y - 8), (x + 20, y + 8)], c.filled()))?;
            }
            MapSwatch::Dashed(c) => {
                for d in [0, 12] {
                    strip.draw(&PathElement::new(
                        [(x + d, y), (x + d + 8, y)],
                        c.stroke_width(2),
                    ))?;
                }
            }
            MapSwatch::Square(c) => {
                strip.draw(&Rectangle::new(
                    [(x + 2, y - 8), (x + 18, y + 8)],
                    c.stroke_width(3),
                ))?;
            }
            MapSwatch::Circle(c) => {
                strip.draw(&Circle::new((x + 10, y), 8, c.stroke_width(3)))?;
            }
            MapSwatch::Cross(c) => {
                strip.draw(&PathElement::new(
                    [(x + 2, y - 8), (x + 18, y + 8)],
                    c.stroke_width(3),
                ))?;
                strip.draw(&PathElement::new(
                    [(x + 2, y + 8), (x + 18, y - 8)],
                    c.stroke_width(3),
                ))?;
            }
        }
        strip.draw(&Text::new(
            text.clone(),
            (x + 30, y),
            analysis_font(ANALYSIS_LABEL_SIZE - 2).pos(Pos::new(HPos::Left, VPos::Center)),
        ))?;
    }
    Ok(())
}
