//! The time-series figure ([`write_time_png`]): stacked panels sharing
//! one time axis, each with its own y range and legend strip.

use std::path::Path;

use plotters::prelude::*;

use super::axes::{frame, time_chart, MARGIN_TOP, X_LABEL_AREA};
use super::draw::{draw_trace, pairs, values_in};
use super::legend::{entry, legend_height, panel_legend, titled, Entry, Swatch};
use super::palette::SERIES;
use super::png::{invalid, write_png_atomically};
use super::style::LINE_WIDTH;
use super::ticks::padded_range;
use super::{Area, BoxError, PlotError};
use crate::outputs::Existing;

/// One panel of a time-series figure (see [`write_time_png`]).
#[derive(Debug, Clone, Default)]
pub struct TimePanel<'a> {
    /// Y-axis description including the unit, e.g. `"Position [µm]"`.
    pub y_label: &'a str,
    /// Curves as `(label, t_s, values)`; `t_s` and `values` must have equal
    /// length. Curves with an empty label get no legend entry.
    pub series: Vec<(&'a str, &'a [f64], &'a [f64])>,
}

/// Writes stacked time-series `panels` sharing one time axis (s) as a PNG to
/// `path`, with `title` above them (omitted when empty).
///
/// The image is 1400 px wide and 1000 px high for up to three panels, growing
/// by 300 px per additional panel (capped at 8000 px). Each panel gets its own y range (from its
/// data, with a margin) and a legend strip of its labelled series above it.
/// Non-finite samples are skipped and break the line.
///
/// # Errors
///
/// [`PlotError::InvalidData`] if `panels` is empty or a series has
/// `t_s.len() != values.len()`; otherwise as for
/// [`write_bode_png`](super::write_bode_png).
pub fn write_time_png(
    path: &Path,
    existing: Existing,
    title: &str,
    panels: &[TimePanel<'_>],
) -> Result<(), PlotError> {
    if panels.is_empty() {
        return Err(invalid(path, "no panels to plot".to_string()));
    }
    for (i, panel) in panels.iter().enumerate() {
        for (label, t, v) in &panel.series {
            if t.len() != v.len() {
                return Err(invalid(
                    path,
                    format!(
                        "panel {i} ({:?}), series {label:?}: {} time stamps but {} values",
                        panel.y_label,
                        t.len(),
                        v.len()
                    ),
                ));
            }
        }
    }
    let extra = u32::try_from(panels.len().saturating_sub(3)).unwrap_or(u32::MAX);
    let height = 1000u32.saturating_add(extra.saturating_mul(300)).min(8000);
    write_png_atomically(path, existing, (1400, height), |root| {
        draw_time(root, title, panels)
    })
}

/// Draws the panels of [`write_time_png`] under `title`.
fn draw_time(root: &Area<'_>, title: &str, panels: &[TimePanel<'_>]) -> Result<(), BoxError> {
    let body = titled(root, title)?;
    let t_all: Vec<f64> = panels
        .iter()
        .flat_map(|p| p.series.iter())
        .flat_map(|(_, t, v)| t.iter().zip(v.iter()))
        .filter(|(t, v)| t.is_finite() && v.is_finite())
        .map(|(t, _)| *t)
        .collect();
    let t_range = padded_range(&t_all, 0.0, 0.0, 0.0..1.0);

    let (_, h) = body.dim_in_pixel();
    let n = u32::try_from(panels.len())?;
    let panel_h = h.saturating_sub(X_LABEL_AREA) / n;
    let mut rest = body;
    for (i, panel) in panels.iter().enumerate() {
        let bottom = i + 1 == panels.len();
        let area = if bottom {
            rest.clone()
        } else {
            let (top, below) = rest.split_vertically(panel_h);
            rest = below;
            top
        };
        let curves: Vec<(RGBColor, Vec<(f64, f64)>)> = panel
            .series
            .iter()
            .enumerate()
            .map(|(k, (_, t, v))| (SERIES[k % SERIES.len()], pairs(t, v)))
            .collect();
        let values: Vec<f64> = curves
            .iter()
            .flat_map(|(_, p)| values_in(p, &t_range))
            .collect();
        let entries: Vec<Entry> = panel
            .series
            .iter()
            .zip(&curves)
            .filter(|((label, _, _), _)| !label.is_empty())
            .map(|((label, _, _), (color, _))| entry(*label, Swatch::Line(*color, LINE_WIDTH)))
            .collect();
        let top = MARGIN_TOP.max(legend_height(&area, &entries)? + 6);
        let y_range = padded_range(&values, 0.06, 0.0, -1.0..1.0);
        let mut chart = time_chart(
            &area,
            &t_range,
            &y_range,
            top,
            bottom,
            "Time [s]",
            panel.y_label,
        )?;
        for (color, pts) in &curves {
            draw_trace(&mut chart, pts, &t_range, *color, LINE_WIDTH)?;
        }
        frame(&chart)?;
        panel_legend(root, &area, &chart, &entries)?;
    }
    Ok(())
}
