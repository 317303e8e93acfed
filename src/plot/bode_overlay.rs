//! The Bode overlay ([`write_bode_overlay_png`]): several measured FRFs
//! on one figure, each in its colour with its verdict in the legend, the
//! model once, and below the zoom on the closely spaced pairs of all of
//! them.

use std::ops::Range;
use std::path::Path;

use plotters::coord::ranged1d::Ranged;
use plotters::prelude::*;

use super::axes::{
    frame, freq_chart, linear_axis, mesh, panel_chart, Chart, Ticked, MARGIN_TOP, X_LABEL_AREA,
};
use super::bode::bode_curve;
use super::draw::{draw_polyline, draw_runs, hline, pairs, runs, shade, values_in};
use super::legend::{
    entry, header_height, header_lines, legend_height, panel_legend, titled, Entry, Swatch,
};
use super::measured::{draw_measured_as, to_db, MeasuredStyle};
use super::overlay::{
    band, check, draw_trace_table, good, pairs_window, resolved, trace_table, trace_width,
    OverlayPlot,
};
use super::pair_zoom::draw_no_pair;
use super::palette::{faint, MODEL_COLOR, SETTLE_COLOR, ZOOM_SHADE, ZOOM_SHADE_ALPHA};
use super::png::write_png_atomically;
use super::ticks::{fmt_sig, linear_ticks, padded_range, phase_ticks, tick_formatter};
use super::{Area, BoxError, PlotError};
use crate::ident::frf::MIN_COHERENCE;
use crate::outputs::Existing;

/// Width of the figure, px.
const WIDTH: u32 = 1400;
/// Height of the title and the three main panels, px (the Bode figure's).
const MAIN_H: u32 = 1000;
/// Height of the pair zoom, px.
const ZOOM_H: u32 = 650;
/// Traces up to which the pair zoom dots every grid point.
const DOTS_MAX: usize = 3;

/// Writes the Bode overlay of `plot` to `path`: 1400 px wide, 1650 px
/// high plus the traces' legend (24 px a row).
///
/// Top, the legend of the traces: each in its colour with its entry in
/// full (its name and verdict, on up to two rows) for up to 12 traces,
/// else the short entries in two columns (up to 48) or three; the colours'
/// note above it. Then the three panels of the Bode figure on one
/// logarithmic frequency axis spanning every trace: magnitude in dB re
/// 1 m/A, unwrapped phase in degrees, coherence with the
/// [`MIN_COHERENCE`] line. Each trace is drawn in its colour, its points
/// below [`MIN_COHERENCE`] in [`faint`] of it (left out of the axis
/// ranges); the model once, dashed, clipped to the traces' band, its
/// phase on the branch of the trace that starts lowest. Traces are 2 px
/// wide up to eight of them, else 1 px, drawn in order (the last on top).
///
/// Below, the pair zoom: magnitude and phase on a linear frequency axis
/// over the union of the windows the Bode figure takes for each trace's
/// pair (`lower − d … upper + d`, `d = max(upper − lower, 1 % of lower)`),
/// shaded on the main panels, with each pair's two modes marked ▼ at the
/// top in its trace's colour (a dot per grid point for up to three
/// traces). Without any pair, the section says so.
///
/// # Errors
/// [`PlotError::InvalidData`] for no trace or more than
/// [`MAX_OVERLAY_TRACES`](super::MAX_OVERLAY_TRACES), or columns of unequal
/// lengths; otherwise as for [`write_bode_png`](super::write_bode_png).
pub fn write_bode_overlay_png(
    path: &Path,
    existing: Existing,
    plot: &OverlayPlot<'_>,
) -> Result<(), PlotError> {
    check(path, plot)?;
    let table = trace_table(path, plot, WIDTH)?;
    let legend_h = table.height() + 8;
    let size = (WIDTH, MAIN_H + legend_h + ZOOM_H);
    write_png_atomically(path, existing, size, |root| {
        let (main, zoom) = root.split_vertically(MAIN_H + legend_h);
        let body = titled(&main, plot.title)?;
        let (legend, panels) = body.split_vertically(legend_h);
        draw_trace_table(root, &legend, &table)?;
        let c = Curves::new(plot);
        draw_main(root, &panels, plot, &c)?;
        match &c.window {
            Some(w) => draw_zoom(root, &zoom, plot, &c, w),
            None => draw_no_pair(
                root,
                &zoom,
                &format!(
                    "on none of the {} inputs (each input's reason: the legend above)",
                    plot.traces.len()
                ),
            ),
        }
    })
}

/// One trace in plot units.
struct Trace {
    db: Vec<(f64, f64)>,
    phase: Vec<(f64, f64)>,
    coh: Vec<(f64, f64)>,
    good: Vec<bool>,
    /// Its colour, width and dots; no faint colour (drawn first for all).
    style: MeasuredStyle,
    /// Its points below [`MIN_COHERENCE`].
    faint: RGBColor,
}

/// Every curve of the figure in plot units, the band and the pair window.
struct Curves {
    traces: Vec<Trace>,
    model_db: Vec<(f64, f64)>,
    model_phase: Vec<(f64, f64)>,
    x_range: Range<f64>,
    window: Option<Range<f64>>,
}

impl Curves {
    fn new(plot: &OverlayPlot<'_>) -> Self {
        let width = trace_width(plot);
        let dots = plot.traces.len() <= DOTS_MAX;
        let traces = plot
            .traces
            .iter()
            .map(|t| {
                let f = t.frf;
                let db: Vec<f64> = f.magnitude_m_per_a.iter().map(|&m| to_db(m)).collect();
                Trace {
                    db: pairs(&f.frequency_hz, &db),
                    phase: pairs(&f.frequency_hz, &f.phase_deg),
                    coh: pairs(&f.frequency_hz, &f.coherence),
                    good: good(f),
                    style: MeasuredStyle {
                        color: t.color,
                        faint: None,
                        width,
                        dots,
                    },
                    faint: faint(t.color),
                }
            })
            .collect();
        // The model's phase on the branch of the trace that starts lowest.
        let reference = plot
            .traces
            .iter()
            .filter(|t| !t.frf.frequency_hz.is_empty())
            .min_by(|a, b| a.frf.frequency_hz[0].total_cmp(&b.frf.frequency_hz[0]))
            .and_then(|t| t.frf.phase_deg.first().copied());
        let (model_db, model_phase) = match &plot.model {
            Some(m) => {
                let (mag, phase) = bode_curve(m.response_m_per_a, reference);
                let db: Vec<f64> = mag.into_iter().map(to_db).collect();
                (pairs(m.frequency_hz, &db), pairs(m.frequency_hz, &phase))
            }
            None => (Vec::new(), Vec::new()),
        };
        let x_range = band(plot);
        let window = pairs_window(plot, &x_range);
        Self {
            traces,
            model_db,
            model_phase,
            x_range,
            window,
        }
    }

    /// The values inside `x` that set a panel's axis: every trace's points
    /// of good coherence (all points when none is good) and the model's.
    fn y_values(
        &self,
        of: impl Fn(&Trace) -> &[(f64, f64)],
        model: &[(f64, f64)],
        x: &Range<f64>,
    ) -> Vec<f64> {
        let inside = |p: &(f64, f64)| p.0 >= x.start && p.0 <= x.end && p.1.is_finite();
        let pick = |only_good: bool| -> Vec<f64> {
            self.traces
                .iter()
                .flat_map(|t| {
                    of(t)
                        .iter()
                        .zip(&t.good)
                        .filter(move |(p, g)| (**g || !only_good) && inside(p))
                        .map(|(p, _)| p.1)
                })
                .collect()
        };
        let mut v = pick(true);
        if v.is_empty() {
            v = pick(false);
        }
        v.extend(model.iter().filter(|p| inside(p)).map(|p| p.1));
        v
    }
}

/// The legend entry of the faint points.
fn faint_entry(plot: &OverlayPlot<'_>) -> Entry {
    let c = plot.traces[0].color;
    entry(
        format!(
            "coherence < {}: drawn faint, each in its trace's colour",
            fmt_sig(MIN_COHERENCE, 3)
        ),
        Swatch::Line(faint(c), 3),
    )
}

/// The three main panels on `area`.
fn draw_main(
    root: &Area<'_>,
    area: &Area<'_>,
    plot: &OverlayPlot<'_>,
    c: &Curves,
) -> Result<(), BoxError> {
    let x = &c.x_range;
    let mut entries = Vec::new();
    if let Some(m) = &plot.model {
        entries.push(entry(m.label, Swatch::Dashed(MODEL_COLOR)));
    }
    entries.push(faint_entry(plot));
    if c.window.is_some() {
        entries.push(entry(
            "the pairs, zoomed below",
            Swatch::Fill(ZOOM_SHADE, ZOOM_SHADE_ALPHA * 2.0),
        ));
    }
    let mag_top = MARGIN_TOP + legend_height(area, &entries)? + 4;
    let coh_entries = [entry(
        format!(
            "γ² = {}: points below are drawn faint",
            fmt_sig(MIN_COHERENCE, 3)
        ),
        Swatch::Dashed(SETTLE_COLOR),
    )];
    let coh_top = legend_height(area, &coh_entries)? + 6;
    let (_, h) = area.dim_in_pixel();
    let plot_h = f64::from(h.saturating_sub(X_LABEL_AREA + mag_top + coh_top + MARGIN_TOP));
    let (mag_area, rest) = area.split_vertically((plot_h * 0.42) as u32 + mag_top);
    let (phase_area, coh_area) = rest.split_vertically((plot_h * 0.31) as u32 + MARGIN_TOP);

    let db_range = padded_range(
        &c.y_values(|t| &t.db, &c.model_db, x),
        0.06,
        10.0,
        -100.0..0.0,
    );
    let phase_range = padded_range(
        &c.y_values(|t| &t.phase, &c.model_phase, x),
        0.06,
        45.0,
        -180.0..0.0,
    );
    let coh_range = c
        .traces
        .iter()
        .flat_map(|t| values_in(&t.coh, x))
        .fold(0.0f64..1.05f64, |r, v| r.start.min(v)..r.end.max(v));
    let shade_window =
        |chart: &mut Chart<'_, '_, Ticked<LogCoord<f64>>>, y: &Range<f64>| match &c.window {
            Some(w) => shade(
                chart,
                (w.start, w.end),
                (y.start, y.end),
                ZOOM_SHADE,
                ZOOM_SHADE_ALPHA,
            ),
            None => Ok(()),
        };
    let model_runs = |pts: &[(f64, f64)]| runs(pts, x, true);

    {
        let mut chart = freq_chart(
            &mag_area,
            x,
            &db_range,
            linear_ticks(&db_range, 8),
            mag_top,
            false,
            "",
            super::MAGNITUDE_M_PER_A,
        )?;
        shade_window(&mut chart, &db_range)?;
        draw_traces(&mut chart, c, |t| &t.db, x, true, false)?;
        draw_runs(&mut chart, &model_runs(&c.model_db), MODEL_COLOR, true)?;
        frame(&chart)?;
        panel_legend(root, &mag_area, &chart, &entries)?;
    }
    {
        let mut chart = freq_chart(
            &phase_area,
            x,
            &phase_range,
            phase_ticks(&phase_range),
            MARGIN_TOP,
            false,
            "",
            "Phase [°]",
        )?;
        shade_window(&mut chart, &phase_range)?;
        draw_traces(&mut chart, c, |t| &t.phase, x, true, false)?;
        draw_runs(&mut chart, &model_runs(&c.model_phase), MODEL_COLOR, true)?;
        frame(&chart)?;
    }
    {
        let y_ticks: Vec<f64> = (0..=5).map(|i| f64::from(i) * 0.2).collect();
        let mut chart = freq_chart(
            &coh_area,
            x,
            &coh_range,
            y_ticks,
            coh_top,
            true,
            "Frequency [Hz]",
            "Coherence [-]",
        )?;
        shade_window(&mut chart, &coh_range)?;
        hline(&mut chart, MIN_COHERENCE, x, SETTLE_COLOR)?;
        for t in &c.traces {
            // The coherence itself: every point in the trace's colour.
            for run in runs(&t.coh, x, true) {
                draw_polyline(&mut chart, &run, t.style.color, t.style.width)?;
            }
        }
        frame(&chart)?;
        panel_legend(root, &coh_area, &chart, &coh_entries)?;
    }
    Ok(())
}

/// Draws every trace's curve `of`: first the points below
/// [`MIN_COHERENCE`] of all of them, faint, then the good points in order
/// (so no faint line covers a good one); `zoom`: with the dots per grid
/// point, if the traces have them.
fn draw_traces<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    c: &Curves,
    of: impl Fn(&Trace) -> &[(f64, f64)],
    x: &Range<f64>,
    log_x: bool,
    zoom: bool,
) -> Result<(), BoxError> {
    for t in &c.traces {
        for run in runs(of(t), x, log_x) {
            draw_polyline(chart, &run, t.faint, t.style.width)?;
        }
    }
    for t in &c.traces {
        let style = MeasuredStyle {
            dots: zoom && t.style.dots,
            ..t.style
        };
        draw_measured_as(chart, of(t), &t.good, x, log_x, &style)?;
    }
    Ok(())
}

/// Marks each resolved pair's two modes with a ▼ in its trace's colour
/// at the top of `chart` (whose y axis ends at `y_top`).
fn mark_pairs<X: Ranged<ValueType = f64>>(
    root: &Area<'_>,
    chart: &Chart<'_, '_, X>,
    plot: &OverlayPlot<'_>,
    window: &Range<f64>,
    y_top: f64,
) -> Result<(), BoxError> {
    for t in plot.traces {
        let Some(p) = &t.pair else { continue };
        for f in [p.lower_hz, p.upper_hz] {
            if !window.contains(&f) {
                continue;
            }
            let (px, py) = chart.backend_coord(&(f, y_top));
            root.draw(&Polygon::new(
                vec![(px - 6, py + 1), (px + 6, py + 1), (px, py + 11)],
                t.color.filled(),
            ))?;
        }
    }
    Ok(())
}

/// The pair zoom on `area` over `window`.
fn draw_zoom(
    root: &Area<'_>,
    area: &Area<'_>,
    plot: &OverlayPlot<'_>,
    c: &Curves,
    window: &Range<f64>,
) -> Result<(), BoxError> {
    let area = area.margin(14, 0, 0, 0);
    let n = plot.traces.len();
    let lines = [
        format!(
            "Closely spaced pairs: resolved on {} of {n} input{}; zoom {}–{} Hz (shaded above)",
            resolved(plot),
            if n == 1 { "" } else { "s" },
            fmt_sig(window.start, 4),
            fmt_sig(window.end, 4)
        ),
        "▼ the two modes of each input's pair, in its colour; each net phase and verdict: the legend at the top".to_string(),
    ];
    let (head, panels) = area.split_vertically(header_height(lines.len()));
    header_lines(root, &head, &lines)?;

    let x_ticks = linear_ticks(window, 10);
    let x_fmt = tick_formatter(&x_ticks);
    let no_fmt = |_: &f64| String::new();
    let db_range = padded_range(
        &c.y_values(|t| &t.db, &c.model_db, window),
        0.08,
        10.0,
        -100.0..0.0,
    );
    let phase_range = padded_range(
        &c.y_values(|t| &t.phase, &c.model_phase, window),
        0.08,
        45.0,
        -180.0..0.0,
    );
    let mut mag_entries = Vec::new();
    if n <= DOTS_MAX {
        mag_entries.push(entry("a dot per grid point", Swatch::Text));
    }
    if let Some(m) = &plot.model {
        mag_entries.push(entry(m.label, Swatch::Dashed(MODEL_COLOR)));
    }
    mag_entries.push(faint_entry(plot));
    let mag_top = legend_height(&panels, &mag_entries)? + 6 + 12;
    let phase_top = MARGIN_TOP + 12;
    let (_, h) = panels.dim_in_pixel();
    let plot_h = f64::from(h.saturating_sub(X_LABEL_AREA + mag_top + phase_top + 10));
    let (mag_area, phase_area) = panels.split_vertically((plot_h * 0.5) as u32 + mag_top);
    let model = |pts: &[(f64, f64)]| runs(pts, window, false);

    {
        let y_ticks = linear_ticks(&db_range, 6);
        let y_fmt = tick_formatter(&y_ticks);
        let xa = linear_axis(window, x_ticks.clone());
        let mut chart = panel_chart(&mag_area, xa, &db_range, y_ticks, mag_top, false)?;
        mesh(&mut chart, None, super::MAGNITUDE_M_PER_A, &no_fmt, &y_fmt)?;
        draw_traces(&mut chart, c, |t| &t.db, window, false, true)?;
        draw_runs(&mut chart, &model(&c.model_db), MODEL_COLOR, true)?;
        frame(&chart)?;
        mark_pairs(root, &chart, plot, window, db_range.end)?;
        panel_legend(root, &mag_area, &chart, &mag_entries)?;
    }
    {
        let y_ticks = phase_ticks(&phase_range);
        let y_fmt = tick_formatter(&y_ticks);
        let xa = linear_axis(window, x_ticks.clone());
        let mut chart = panel_chart(&phase_area, xa, &phase_range, y_ticks, phase_top, true)?;
        mesh(
            &mut chart,
            Some("Frequency [Hz]"),
            "Phase [°]",
            &x_fmt,
            &y_fmt,
        )?;
        draw_traces(&mut chart, c, |t| &t.phase, window, false, true)?;
        draw_runs(&mut chart, &model(&c.model_phase), MODEL_COLOR, true)?;
        frame(&chart)?;
        mark_pairs(root, &chart, plot, window, phase_range.end)?;
    }
    Ok(())
}
