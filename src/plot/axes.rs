//! Panels and their axes: the panel geometry (margins, label areas), an
//! axis whose labelled and grid-only ticks are chosen explicitly
//! ([`Ticked`]), and building a panel with its mesh and frame.

use std::ops::Range;

use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, ValueFormatter};
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use super::palette::{GRID_BOLD, GRID_LIGHT};
use super::style::{DESC_SIZE, FONT, TICK_SIZE};
use super::ticks::{fmt_tick, linear_ticks, log_ticks, tick_formatter};
use super::{Area, BoxError};

/// Width left of a panel's frame for the y tick labels and description, px.
const Y_LABEL_AREA: u32 = 100;
/// Height below a bottom panel's frame for the x tick labels and
/// description, px.
pub(super) const X_LABEL_AREA: u32 = 60;
/// Space left of the y label area, px.
const MARGIN_LEFT: u32 = 10;
/// Space right of the frame, px.
const MARGIN_RIGHT: u32 = 30;
/// Least space above a frame, px (more when a legend strip sits there).
pub(super) const MARGIN_TOP: u32 = 12;

/// A panel: a chart on the bitmap with a [`Ticked`] linear y axis.
pub(super) type Chart<'a, 'b, X> =
    ChartContext<'a, super::canvas::Canvas<'b>, Cartesian2d<X, Ticked<RangedCoordf64>>>;

/// A logarithmic frequency axis over `range` with ticks labelled at `bold`
/// and grid lines also at `light`.
pub(super) fn freq_axis(range: &Range<f64>, bold: &[f64], light: &[f64]) -> Ticked<LogCoord<f64>> {
    Ticked {
        inner: range.clone().log_scale().into(),
        bold: bold.to_vec(),
        light: light.to_vec(),
    }
}

/// A linear axis over `range` labelled at `bold`.
pub(super) fn linear_axis(range: &Range<f64>, bold: Vec<f64>) -> Ticked<RangedCoordf64> {
    Ticked {
        inner: range.clone().into(),
        bold,
        light: Vec::new(),
    }
}

/// A coordinate axis with explicitly chosen labelled (bold) and grid-only
/// (light) tick positions. plotters' own `WithKeyPoints` cannot be used on
/// `f64` ranges because it loses their value formatter.
pub(super) struct Ticked<R> {
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
pub(super) fn panel_chart<'a, 'b: 'a, X: Ranged<ValueType = f64>>(
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
pub(super) fn plot_columns(area: &Area<'_>) -> (i32, i32) {
    let (x0, _) = area.get_base_pixel();
    let (w, _) = area.dim_in_pixel();
    plot_columns_at(x0, w)
}

/// [`plot_columns`] of an area `w` px wide starting at column `x0`.
pub(super) fn plot_columns_at(x0: i32, w: u32) -> (i32, i32) {
    let w = i32::try_from(w).unwrap_or(i32::MAX);
    let left = x0 + (MARGIN_LEFT + Y_LABEL_AREA) as i32;
    let right = (x0 + w - MARGIN_RIGHT as i32).max(left + 1);
    (left, right)
}

/// The pixel rows (absolute) of the plotting area that [`panel_chart`]
/// builds on `area` with `margin_top` and `bottom`, before it is built
/// (for an equal aspect ratio).
pub(super) fn plot_rows(area: &Area<'_>, margin_top: u32, bottom: bool) -> (i32, i32) {
    let (_, y0) = area.get_base_pixel();
    let (_, h) = area.dim_in_pixel();
    let h = i32::try_from(h).unwrap_or(i32::MAX);
    let below = if bottom { 10 + X_LABEL_AREA } else { 0 };
    let top = y0 + i32::try_from(margin_top).unwrap_or(i32::MAX);
    let end = (y0 + h - below as i32).max(top + 1);
    (top, end)
}

/// Draws the grid, the tick labels (`x_fmt`, `y_fmt`) and the axis
/// descriptions of `chart`; `x_desc` only on a bottom panel.
pub(super) fn mesh<'a, 'b: 'a, X>(
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
pub(super) fn frame<X: Ranged<ValueType = f64>>(chart: &Chart<'_, '_, X>) -> Result<(), BoxError> {
    let area = chart.plotting_area().strip_coord_spec();
    let (w, h) = area.dim_in_pixel();
    let (w, h) = (i32::try_from(w)?, i32::try_from(h)?);
    area.draw(&Rectangle::new(
        [(0, 0), (w - 1, h - 1)],
        BLACK.stroke_width(1),
    ))?;
    Ok(())
}

/// A panel on a logarithmic frequency axis over `x_range` (ticks from
/// [`log_ticks`]) with its mesh drawn, labelled at `y_ticks`; `bottom`
/// panels label the x axis with `x_desc`.
#[allow(clippy::too_many_arguments)]
pub(super) fn freq_chart<'a, 'b: 'a>(
    area: &'a Area<'b>,
    x_range: &Range<f64>,
    y_range: &Range<f64>,
    y_ticks: Vec<f64>,
    top: u32,
    bottom: bool,
    x_desc: &str,
    y_desc: &str,
) -> Result<Chart<'a, 'b, Ticked<LogCoord<f64>>>, BoxError> {
    let (x_bold, x_light) = log_ticks(x_range);
    let y_fmt = tick_formatter(&y_ticks);
    let x_fmt = |v: &f64| fmt_tick(*v);
    let no_fmt = |_: &f64| String::new();
    let x = freq_axis(x_range, &x_bold, &x_light);
    let mut chart = panel_chart(area, x, y_range, y_ticks, top, bottom)?;
    let x_fmt: &dyn Fn(&f64) -> String = if bottom { &x_fmt } else { &no_fmt };
    mesh(&mut chart, bottom.then_some(x_desc), y_desc, x_fmt, &y_fmt)?;
    Ok(chart)
}

/// A linear time panel with its mesh drawn; `bottom` panels label the x
/// axis with `x_desc`.
pub(super) fn time_chart<'a, 'b: 'a>(
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
