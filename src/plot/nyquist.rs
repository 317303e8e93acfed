//! The Nyquist overlay ([`write_nyquist_png`]): several measured FRFs in
//! the complex plane (Re H, Im H in m/A, equal scales), the whole band
//! left and the band of the closely spaced pairs right, each trace in its
//! colour with its direction and its fitted modes marked, the model once.

use std::ops::Range;
use std::path::Path;

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::axes::{frame, linear_axis, mesh, panel_chart, plot_columns, plot_rows, Chart};
use super::draw::{draw_polyline, draw_runs, runs_in_box};
use super::legend::{
    area_legend, entry, legend_height, marker_style, panel_legend, titled, Swatch,
};
use super::overlay::{
    band, check, draw_trace_table, good, pairs_window, resolved, trace_table, trace_width,
    OverlayPlot,
};
use super::pair_zoom::draw_no_pair;
use super::palette::{faint, MODEL_COLOR};
use super::png::write_png_atomically;
use super::ticks::{fmt_sig, linear_ticks, padded_range, tick_formatter, ticks_every};
use super::{Area, BoxError, PlotError};
use crate::ident::frf::MIN_COHERENCE;
use crate::outputs::Existing;
use plotters::coord::types::RangedCoordf64;

/// Width of the figure, px.
const WIDTH: u32 = 1400;
/// Height of the title, the strip of the marks' legend and the panels, px.
const PANELS_H: u32 = 860;
/// Width of the whole band's panel (left), px; the pairs' band takes the
/// rest.
const LEFT_W: u32 = 700;
/// Traces up to which each fitted mode's dot is labelled with its
/// frequency.
const LABELS_MAX: usize = 4;
/// Traces up to which the pairs' panel dots every grid point.
const DOTS_MAX: usize = 3;
/// Half-length of a direction arrow, px.
const ARROW: f64 = 8.0;

/// Writes the Nyquist overlay of `plot` to `path`: 1400 px wide, 860 px
/// high plus the traces' legend (24 px a row).
///
/// Top, the traces' legend as in
/// [`write_bode_overlay_png`](super::write_bode_overlay_png), then a strip
/// naming the marks. Left, every trace over the whole band in the complex
/// plane, Re H against Im H in m/A with equal scales (a circle stays a
/// circle), the axes spanning the points of good coherence of every trace
/// (all points when none is good) with 6 % to spare; right, the same over
/// the pair zoom's window (the union of every resolved pair's window, as
/// in the Bode overlay; a dot per grid point for up to three traces), or
/// a panel saying no pair was resolved. Each
/// trace in its colour, its points below [`MIN_COHERENCE`] in
/// [`faint`] of it; a filled arrowhead at the middle (by length on the
/// figure) of its longest coherent run points the way frequency
/// increases; a dot with a black rim on the grid point nearest each of its
/// fitted modes, labelled with the frequency for up to four traces (a
/// pair's modes in the pairs' panel only). The
/// model dashed over the same band, clipped to the axes. The origin is
/// marked `+`.
///
/// # Errors
/// As [`write_bode_overlay_png`](super::write_bode_overlay_png).
pub fn write_nyquist_png(
    path: &Path,
    existing: Existing,
    plot: &OverlayPlot<'_>,
) -> Result<(), PlotError> {
    check(path, plot)?;
    let table = trace_table(path, plot, WIDTH)?;
    let legend_h = table.height() + 8;
    let size = (WIDTH, PANELS_H + legend_h);
    write_png_atomically(path, existing, size, |root| {
        let body = titled(root, plot.title)?;
        let (legend, rest) = body.split_vertically(legend_h);
        draw_trace_table(root, &legend, &table)?;
        let c = Curves::new(plot);
        let mut marks = Vec::new();
        if let Some(m) = &plot.model {
            marks.push(entry(m.label, Swatch::Dashed(MODEL_COLOR)));
        }
        marks.extend([
            entry("▶ increasing frequency", Swatch::Text),
            entry("● the fitted modes of each input", Swatch::Text),
            entry(
                format!(
                    "coherence < {}: faint, in each trace's colour",
                    fmt_sig(MIN_COHERENCE, 3)
                ),
                Swatch::Line(faint(plot.traces[0].color), 3),
            ),
        ]);
        let strip_h = legend_height(&rest, &marks)? + 6;
        let (strip, panels) = rest.split_vertically(strip_h);
        area_legend(root, &strip, &marks)?;
        let (left, right) = panels.split_horizontally(LEFT_W);
        let whole = format!(
            "whole band {}–{} Hz",
            fmt_sig(c.x_range.start, 3),
            fmt_sig(c.x_range.end, 4)
        );
        draw_panel(root, &left, plot, &c, &c.x_range, &whole, false)?;
        match &c.window {
            Some(w) => {
                let caption = format!(
                    "the pairs' band {}–{} Hz ({} of {} inputs resolved a pair){}",
                    fmt_sig(w.start, 4),
                    fmt_sig(w.end, 4),
                    resolved(plot),
                    plot.traces.len(),
                    if plot.traces.len() <= DOTS_MAX {
                        "; a dot per grid point"
                    } else {
                        ""
                    }
                );
                draw_panel(root, &right, plot, &c, w, &caption, true)
            }
            None => draw_no_pair(
                root,
                &right,
                &format!("on none of the {} inputs", plot.traces.len()),
            ),
        }
    })
}

/// One trace in plot units.
struct Trace {
    /// `(Re H, Im H)`, m/A.
    pts: Vec<(f64, f64)>,
    frequency_hz: Vec<f64>,
    good: Vec<bool>,
}

/// Every curve of the figure, the band and the pair window.
struct Curves {
    traces: Vec<Trace>,
    model: Vec<(f64, f64)>,
    model_hz: Vec<f64>,
    x_range: Range<f64>,
    window: Option<Range<f64>>,
}

impl Curves {
    fn new(plot: &OverlayPlot<'_>) -> Self {
        let traces = plot
            .traces
            .iter()
            .map(|t| {
                let f = t.frf;
                let pts = (0..f.frequency_hz.len())
                    .map(|i| {
                        let h = f.response(i);
                        (h.re, h.im)
                    })
                    .collect();
                Trace {
                    pts,
                    frequency_hz: f.frequency_hz.clone(),
                    good: good(f),
                }
            })
            .collect();
        let (model, model_hz) = match &plot.model {
            Some(m) => (
                m.response_m_per_a.iter().map(|h| (h.re, h.im)).collect(),
                m.frequency_hz.to_vec(),
            ),
            None => (Vec::new(), Vec::new()),
        };
        let x_range = band(plot);
        let window = pairs_window(plot, &x_range);
        Self {
            traces,
            model,
            model_hz,
            x_range,
            window,
        }
    }
}

/// `pts` with the points whose frequency is outside `band` made NaN (a
/// break in the curve).
fn in_band(pts: &[(f64, f64)], hz: &[f64], band: &Range<f64>) -> Vec<(f64, f64)> {
    pts.iter()
        .zip(hz)
        .map(|(p, f)| {
            if *f >= band.start && *f <= band.end {
                *p
            } else {
                (f64::NAN, f64::NAN)
            }
        })
        .collect()
}

/// The axes of a panel whose frame spans `cols` × `rows` px showing the
/// extents `re` and `im` (each widened by 6 %, at least a little around
/// a single point) with equal scales: the longer side shows more, centred
/// on the same middle.
fn equal_axes(re: &[f64], im: &[f64], cols: f64, rows: f64) -> (Range<f64>, Range<f64>) {
    let r = padded_range(re, 0.06, 0.0, -1e-6..1e-6);
    let i = padded_range(im, 0.06, 0.0, -1e-6..1e-6);
    let per_px = ((r.end - r.start) / cols.max(1.0)).max((i.end - i.start) / rows.max(1.0));
    let (rm, im_mid) = (0.5 * (r.start + r.end), 0.5 * (i.start + i.end));
    let (rh, ih) = (0.5 * cols * per_px, 0.5 * rows * per_px);
    ((rm - rh)..(rm + rh), (im_mid - ih)..(im_mid + ih))
}

/// A panel in the complex plane.
type PlaneChart<'a, 'b> = Chart<'a, 'b, super::axes::Ticked<RangedCoordf64>>;

/// One Nyquist panel on `area`: every trace over `band`, captioned;
/// `zoom`: the pairs' band (a dot per grid point for up to
/// [`DOTS_MAX`] traces, the pairs' modes labelled).
fn draw_panel(
    root: &Area<'_>,
    area: &Area<'_>,
    plot: &OverlayPlot<'_>,
    c: &Curves,
    band: &Range<f64>,
    caption: &str,
    zoom: bool,
) -> Result<(), BoxError> {
    let entries = [entry(caption, Swatch::Text)];
    let top = legend_height(area, &entries)? + 6;
    let shown: Vec<Vec<(f64, f64)>> = c
        .traces
        .iter()
        .map(|t| in_band(&t.pts, &t.frequency_hz, band))
        .collect();
    // The extent: the points of good coherence, else all.
    let extent = |only_good: bool| -> (Vec<f64>, Vec<f64>) {
        c.traces
            .iter()
            .zip(&shown)
            .flat_map(|(t, pts)| {
                pts.iter()
                    .zip(&t.good)
                    .filter(move |(p, g)| (**g || !only_good) && p.0.is_finite() && p.1.is_finite())
                    .map(|(p, _)| *p)
            })
            .unzip()
    };
    let (mut re_v, mut im_v) = extent(true);
    if re_v.is_empty() {
        (re_v, im_v) = extent(false);
    }
    let (c0, c1) = plot_columns(area);
    let (r0, r1) = plot_rows(area, top, true);
    let (re, im) = equal_axes(&re_v, &im_v, f64::from(c1 - c0), f64::from(r1 - r0));
    let re_ticks = linear_ticks(&re, 6);
    let step = match re_ticks.as_slice() {
        [a, b, ..] if b > a => b - a,
        _ => re.end - re.start,
    };
    let im_ticks = if step.is_finite() && step > 0.0 && (im.end - im.start) / step < 100.0 {
        ticks_every(&im, step)
    } else {
        linear_ticks(&im, 6)
    };
    let re_fmt = tick_formatter(&re_ticks);
    let im_fmt = tick_formatter(&im_ticks);
    let mut chart = panel_chart(area, linear_axis(&re, re_ticks), &im, im_ticks, top, true)?;
    mesh(
        &mut chart,
        Some("Re H [m/A]"),
        "Im H [m/A]",
        &re_fmt,
        &im_fmt,
    )?;
    if re.contains(&0.0) && im.contains(&0.0) {
        chart.draw_series(std::iter::once(Cross::new(
            (0.0, 0.0),
            6,
            BLACK.stroke_width(1),
        )))?;
    }
    let width = trace_width(plot);
    // Every trace faint first, then the good points of each on top.
    for (pts, tr) in shown.iter().zip(plot.traces) {
        for run in runs_in_box(pts, &re, &im) {
            draw_polyline(&mut chart, &run, faint(tr.color), width)?;
        }
    }
    let solids: Vec<Vec<Vec<(f64, f64)>>> = c
        .traces
        .iter()
        .zip(&shown)
        .map(|(t, pts)| runs_in_box(&solid(pts, &t.good), &re, &im))
        .collect();
    let dots = zoom && plot.traces.len() <= DOTS_MAX;
    for (runs, tr) in solids.iter().zip(plot.traces) {
        for run in runs {
            draw_polyline(&mut chart, run, tr.color, width)?;
        }
        if dots {
            chart.draw_series(
                runs.iter()
                    .flatten()
                    .map(|p| Circle::new(*p, 3, tr.color.filled())),
            )?;
        }
    }
    let model = in_band(&c.model, &c.model_hz, band);
    draw_runs(
        &mut chart,
        &runs_in_box(&model, &re, &im),
        MODEL_COLOR,
        true,
    )?;
    // Modes inside the pairs' window are labelled in the zoom only.
    let labelled = |f: f64| zoom || c.window.as_ref().is_none_or(|w| !w.contains(&f));
    for ((t, runs), tr) in c.traces.iter().zip(&solids).zip(plot.traces) {
        arrow(root, &chart, runs, tr.color)?;
        mode_dots(
            root,
            &chart,
            t,
            tr,
            band,
            (&re, &im),
            plot.traces.len(),
            &labelled,
        )?;
    }
    frame(&chart)?;
    panel_legend(root, area, &chart, &entries)
}

/// `pts` with the points of low coherence made NaN.
fn solid(pts: &[(f64, f64)], good: &[bool]) -> Vec<(f64, f64)> {
    pts.iter()
        .zip(good)
        .map(|(p, g)| if *g { *p } else { (f64::NAN, f64::NAN) })
        .collect()
}

/// A filled arrowhead in `color` at the middle, by length on the figure,
/// of the longest of `runs`, pointing along it (the way frequency
/// increases).
fn arrow(
    root: &Area<'_>,
    chart: &PlaneChart<'_, '_>,
    runs: &[Vec<(f64, f64)>],
    color: RGBColor,
) -> Result<(), BoxError> {
    let px = |p: &(f64, f64)| {
        let (x, y) = chart.backend_coord(p);
        (f64::from(x), f64::from(y))
    };
    let length = |run: &Vec<(f64, f64)>| -> f64 {
        run.windows(2)
            .map(|w| {
                let (a, b) = (px(&w[0]), px(&w[1]));
                (b.0 - a.0).hypot(b.1 - a.1)
            })
            .sum()
    };
    let Some(run) = runs.iter().max_by(|a, b| length(a).total_cmp(&length(b))) else {
        return Ok(());
    };
    let total = length(run);
    if total < 4.0 * ARROW {
        return Ok(());
    }
    let mut left = 0.5 * total;
    for w in run.windows(2) {
        let (a, b) = (px(&w[0]), px(&w[1]));
        let d = (b.0 - a.0).hypot(b.1 - a.1);
        if d <= 0.0 {
            continue;
        }
        if left > d {
            left -= d;
            continue;
        }
        let (ux, uy) = ((b.0 - a.0) / d, (b.1 - a.1) / d);
        let (mx, my) = (a.0 + ux * left, a.1 + uy * left);
        let tip = (mx + ux * ARROW, my + uy * ARROW);
        let back = (mx - ux * ARROW, my - uy * ARROW);
        let wing = 0.7 * ARROW;
        let pts = [
            tip,
            (back.0 - uy * wing, back.1 + ux * wing),
            (back.0 + uy * wing, back.1 - ux * wing),
        ];
        let pts: Vec<(i32, i32)> = pts
            .iter()
            .map(|p| (p.0.round() as i32, p.1.round() as i32))
            .collect();
        root.draw(&Polygon::new(pts.clone(), color.filled()))?;
        root.draw(&PathElement::new(
            vec![pts[0], pts[1], pts[2], pts[0]],
            BLACK.stroke_width(1),
        ))?;
        return Ok(());
    }
    Ok(())
}

/// Dots on the grid points nearest the fitted modes of `tr` inside `band`
/// and the axes, labelled with the frequency for up to [`LABELS_MAX`]
/// traces where `labelled` says so.
#[allow(clippy::too_many_arguments)]
fn mode_dots(
    root: &Area<'_>,
    chart: &PlaneChart<'_, '_>,
    t: &Trace,
    tr: &super::overlay::OverlayTrace<'_>,
    band: &Range<f64>,
    (re, im): (&Range<f64>, &Range<f64>),
    traces: usize,
    labelled: &dyn Fn(f64) -> bool,
) -> Result<(), BoxError> {
    let f = &t.frequency_hz;
    for &mode in tr.modes_hz.iter().filter(|m| band.contains(m)) {
        let k = f.partition_point(|x| *x < mode);
        let k = match (k.checked_sub(1), f.get(k)) {
            (Some(j), Some(&above)) if mode - f[j] < above - mode => j,
            (Some(j), None) => j,
            _ => k,
        };
        let Some(&p) = t.pts.get(k) else { continue };
        if !(re.contains(&p.0) && im.contains(&p.1)) {
            continue;
        }
        let (x, y) = chart.backend_coord(&p);
        root.draw(&Circle::new((x, y), 5, tr.color.filled()))?;
        root.draw(&Circle::new((x, y), 5, BLACK.stroke_width(1)))?;
        if traces <= LABELS_MAX && labelled(mode) {
            let mut style = marker_style(tr.color);
            style.pos = Pos::new(HPos::Left, VPos::Bottom);
            root.draw(&Text::new(
                format!("{} Hz", fmt_sig(mode, 4)),
                (x + 7, y - 5),
                style,
            ))?;
        }
    }
    Ok(())
}
