//! The step figure ([`write_step_png`]): a closed-loop step response,
//! the whole record above and the transient zoomed below, with the
//! settling band and the rise, settling and overshoot marked.

use std::ops::Range;
use std::path::Path;

use plotters::prelude::*;

use super::axes::{frame, plot_columns, time_chart, X_LABEL_AREA};
use super::draw::{draw_trace, pairs, shade, staircase, values_in, vline};
use super::legend::{
    draw_marker_labels, entry, layout_marker_labels, legend_height, marker_row_height,
    panel_legend, titled, Swatch,
};
use super::palette::{
    BAND_ALPHA, BAND_COLOR, COMMAND_COLOR, ERROR_COLOR, MARKER_COLOR, OVERSHOOT_COLOR,
    POSITION_COLOR, POSITION_RAW_COLOR, RISE_COLOR, SETPOINT_COLOR, SETTLE_COLOR, SMOOTHED_COLOR,
    STEADY_COLOR, ZOOM_SHADE, ZOOM_SHADE_ALPHA,
};
use super::png::{invalid, write_png_atomically};
use super::style::LINE_WIDTH;
use super::ticks::{fmt_sig, padded_range};
use super::{Area, BoxError, PlotError};
use crate::control::step_metrics::{StepEvents, StepMetrics, SETTLING_BAND, SMOOTHING_S};
use crate::outputs::Existing;

/// A closed-loop step response with its metrics (see [`write_step_png`]).
/// All slices have one value per recorded sample.
#[derive(Debug, Clone, Copy)]
pub struct StepPlot<'a> {
    /// Figure title (omitted when empty).
    pub title: &'a str,
    /// Time of each sample, s.
    pub t_s: &'a [f64],
    /// Setpoint relative to the start position, µm.
    pub setpoint_um: &'a [f64],
    /// Probe reading relative to the start position, µm.
    pub position_um: &'a [f64],
    /// The reading the metrics are computed on (centred moving average over
    /// [`SMOOTHING_S`]), relative to the start position, µm.
    pub smoothed_um: &'a [f64],
    /// Coil current command, A.
    pub command_a: &'a [f64],
    /// The figures written on the plot
    /// ([`analyze_step`](crate::control::step_metrics::analyze_step)).
    pub metrics: &'a StepMetrics,
    /// Where they happen (sample indices), from the same analysis.
    pub events: &'a StepEvents,
}

/// Size of the step figure, px.
const STEP_SIZE: (u32, u32) = (1400, 1700);

/// Writes a closed-loop step response as a 1400x1700 px PNG to `path`.
///
/// The upper half shows the whole record on one time axis (s): setpoint and
/// probe reading (µm from the start position), the coil current command
/// (A) and the error `setpoint − position` (µm) with the steady-state window
/// shaded and its mean and σ written in the legend; the zoomed window is
/// shaded on the first two.
///
/// The lower half zooms on the transient, in ms since the step: from `pre`
/// before the step to `post` after it, `post = max(2 × settling time, 4 ×
/// rise time, 20 sample periods)` (to the end of the record when the
/// response never settled), `pre = post / 10` (at least two sample periods),
/// both bounded by the record. Its upper panel shows the setpoint, the raw
/// reading (light), the moving average the metrics are computed on (dark),
/// the ±[`SETTLING_BAND`] band around the final value, and labelled markers:
/// the 10 % and 90 % crossings (rise time), the settling instant and the
/// overshoot peak, with the values of `plot.metrics`. Its lower panel shows
/// the current command. Sampled signals (setpoint, command) are drawn as
/// held between samples (a staircase).
///
/// # Errors
///
/// [`PlotError::InvalidData`] if the slices differ in length or an event
/// index lies outside them; otherwise as for
/// [`write_bode_png`](super::write_bode_png).
pub fn write_step_png(
    path: &Path,
    existing: Existing,
    plot: &StepPlot<'_>,
) -> Result<(), PlotError> {
    let n = plot.t_s.len();
    for (name, v) in [
        ("setpoint_um", plot.setpoint_um),
        ("position_um", plot.position_um),
        ("smoothed_um", plot.smoothed_um),
        ("command_a", plot.command_a),
    ] {
        if v.len() != n {
            return Err(invalid(
                path,
                format!("{name} has {} samples but t_s has {n}", v.len()),
            ));
        }
    }
    let e = plot.events;
    let indices = [
        Some(e.step),
        e.rise_from,
        e.rise_to,
        e.settled,
        e.peak,
        Some(e.steady_state_from),
    ];
    if let Some(k) = indices.into_iter().flatten().find(|&k| k > n) {
        return Err(invalid(
            path,
            format!("step event at sample {k} but the record has {n} samples"),
        ));
    }
    write_png_atomically(path, existing, STEP_SIZE, |root| draw_step(root, plot))
}

/// The zoom window of a step figure on the `t_s` axis (see
/// [`write_step_png`]).
fn step_zoom(t_range: &Range<f64>, t_step: f64, period_s: f64, m: &StepMetrics) -> Range<f64> {
    let rest = (t_range.end - t_step).max(0.0);
    let post = match m.settling_time_s {
        Some(ts) => (2.0 * ts)
            .max(4.0 * m.rise_time_s.unwrap_or(0.0))
            .max(20.0 * period_s),
        None => rest,
    }
    .min(rest);
    let pre = (post / 10.0)
        .max(2.0 * period_s)
        .min(t_step - t_range.start)
        .max(0.0);
    let r = (t_step - pre)..(t_step + post);
    if r.end > r.start && r.start.is_finite() && r.end.is_finite() {
        r
    } else {
        t_range.clone()
    }
}

/// Formats a duration in s as ms with three significant digits.
fn fmt_ms(s: f64) -> String {
    format!("{} ms", fmt_sig(s * 1e3, 3))
}

/// The whole record's position panel: setpoint and probe reading, the
/// zoomed window shaded.
fn draw_overview_position(
    root: &Area<'_>,
    area: &Area<'_>,
    t_range: &Range<f64>,
    zoom: &Range<f64>,
    sp_stairs: &[(f64, f64)],
    pos: &[(f64, f64)],
) -> Result<(), BoxError> {
    let entries = [
        entry("setpoint", Swatch::Line(SETPOINT_COLOR, LINE_WIDTH)),
        entry("position (probe)", Swatch::Line(POSITION_COLOR, LINE_WIDTH)),
        entry(
            format!(
                "zoomed below ({} to {} s)",
                fmt_sig(zoom.start, 4),
                fmt_sig(zoom.end, 4)
            ),
            Swatch::Fill(ZOOM_SHADE, ZOOM_SHADE_ALPHA * 2.0),
        ),
    ];
    let top = legend_height(area, &entries)? + 6;
    let vals: Vec<f64> = values_in(sp_stairs, t_range)
        .chain(values_in(pos, t_range))
        .collect();
    let y = padded_range(&vals, 0.06, 0.0, -1.0..1.0);
    let mut chart = time_chart(area, t_range, &y, top, false, "", "position − start [µm]")?;
    shade(
        &mut chart,
        (zoom.start, zoom.end),
        (y.start, y.end),
        ZOOM_SHADE,
        ZOOM_SHADE_ALPHA,
    )?;
    draw_trace(&mut chart, sp_stairs, t_range, SETPOINT_COLOR, LINE_WIDTH)?;
    draw_trace(&mut chart, pos, t_range, POSITION_COLOR, 1)?;
    frame(&chart)?;
    panel_legend(root, area, &chart, &entries)?;
    Ok(())
}

/// The whole record's command panel, with the peak command, the zoomed
/// window shaded.
fn draw_overview_command(
    root: &Area<'_>,
    area: &Area<'_>,
    t_range: &Range<f64>,
    zoom: &Range<f64>,
    cmd_stairs: &[(f64, f64)],
    m: &StepMetrics,
) -> Result<(), BoxError> {
    let entries = [
        entry(
            "current command (held over each sample period)",
            Swatch::Line(COMMAND_COLOR, LINE_WIDTH),
        ),
        entry(
            format!("peak |command| {:.3} A", m.peak_command_a),
            Swatch::Text,
        ),
    ];
    let top = legend_height(area, &entries)? + 6;
    let vals: Vec<f64> = values_in(cmd_stairs, t_range).collect();
    let y = padded_range(&vals, 0.06, 0.0, -1.0..1.0);
    let mut chart = time_chart(area, t_range, &y, top, false, "", "current command [A]")?;
    shade(
        &mut chart,
        (zoom.start, zoom.end),
        (y.start, y.end),
        ZOOM_SHADE,
        ZOOM_SHADE_ALPHA,
    )?;
    draw_trace(&mut chart, cmd_stairs, t_range, COMMAND_COLOR, 1)?;
    frame(&chart)?;
    panel_legend(root, area, &chart, &entries)?;
    Ok(())
}

/// The whole record's error panel, the steady-state window (from
/// `steady_from_s`) shaded, with its mean and σ.
fn draw_overview_error(
    root: &Area<'_>,
    area: &Area<'_>,
    t_range: &Range<f64>,
    steady_from_s: Option<f64>,
    err: &[(f64, f64)],
    m: &StepMetrics,
) -> Result<(), BoxError> {
    let entries = [
        entry("setpoint − position", Swatch::Line(ERROR_COLOR, LINE_WIDTH)),
        entry(
            format!(
                "steady-state window (last {} s): mean {:.1} nm, σ {:.1} nm",
                fmt_sig(m.steady_state_window_s, 3),
                m.steady_state_error_mean_nm,
                m.steady_state_error_std_nm
            ),
            Swatch::Fill(STEADY_COLOR, 0.25),
        ),
    ];
    let top = legend_height(area, &entries)? + 6;
    let vals: Vec<f64> = values_in(err, t_range).collect();
    let y = padded_range(&vals, 0.06, 0.0, -1.0..1.0);
    let mut chart = time_chart(area, t_range, &y, top, true, "Time [s]", "error [µm]")?;
    if let Some(t0) = steady_from_s {
        shade(
            &mut chart,
            (t0, t_range.end),
            (y.start, y.end),
            STEADY_COLOR,
            0.12,
        )?;
    }
    draw_trace(&mut chart, err, t_range, ERROR_COLOR, 1)?;
    frame(&chart)?;
    panel_legend(root, area, &chart, &entries)?;
    Ok(())
}

/// The zoom's command panel, in ms since the step.
fn draw_zoom_command(
    root: &Area<'_>,
    area: &Area<'_>,
    z: &Range<f64>,
    cmd_z: &[(f64, f64)],
) -> Result<(), BoxError> {
    let entries = [entry(
        "current command (held over each sample period)",
        Swatch::Line(COMMAND_COLOR, LINE_WIDTH),
    )];
    let top = legend_height(area, &entries)? + 6;
    let vals: Vec<f64> = values_in(cmd_z, z).collect();
    let y = padded_range(&vals, 0.06, 0.0, -1.0..1.0);
    let mut chart = time_chart(
        area,
        z,
        &y,
        top,
        true,
        "Time since the step [ms]",
        "current command [A]",
    )?;
    vline(&mut chart, 0.0, &y, MARKER_COLOR, 1)?;
    draw_trace(&mut chart, cmd_z, z, COMMAND_COLOR, LINE_WIDTH)?;
    frame(&chart)?;
    panel_legend(root, area, &chart, &entries)?;
    Ok(())
}

/// A mark on the zoom: (ms since the step, µm).
type Mark = (f64, f64);

/// The zoom's traces and marks, in ms since the step (see
/// [`write_step_png`]): a mark is a point (ms, µm).
struct Zoom {
    /// The window, ms.
    z: Range<f64>,
    sp: Vec<(f64, f64)>,
    pos: Vec<(f64, f64)>,
    smooth: Vec<(f64, f64)>,
    /// The 10 % and 90 % crossings.
    rise: (Option<Mark>, Option<Mark>),
    settled: Option<Mark>,
    peak: Option<Mark>,
    /// The settling band, µm.
    band: (f64, f64),
}

/// The zoom's position panel: setpoint, raw and smoothed reading, the
/// settling band, and the labelled markers `items`.
fn draw_zoom_position(
    root: &Area<'_>,
    area: &Area<'_>,
    zm: &Zoom,
    items: Vec<(f64, String, RGBColor)>,
    entries: &[super::legend::Entry],
) -> Result<(), BoxError> {
    let (px0, px1) = plot_columns(area);
    let z = &zm.z;
    let span = z.end - z.start;
    let (labels, rows) = layout_marker_labels(area, items, |x| {
        px0 + (f64::from(px1 - px0) * (x - z.start) / span) as i32
    })?;
    let legend_h = legend_height(area, entries)?;
    let top = legend_h + 8 + u32::try_from(rows)? * u32::try_from(marker_row_height())?;
    let vals: Vec<f64> = values_in(&zm.sp, z)
        .chain(values_in(&zm.pos, z))
        .chain(values_in(&zm.smooth, z))
        .chain([zm.band.0, zm.band.1])
        .collect();
    let y = padded_range(&vals, 0.06, 0.0, -1.0..1.0);
    let mut chart = time_chart(area, z, &y, top, false, "", "position − start [µm]")?;
    shade(
        &mut chart,
        (0.0f64.max(z.start), z.end),
        zm.band,
        BAND_COLOR,
        BAND_ALPHA,
    )?;
    draw_trace(&mut chart, &zm.pos, z, POSITION_RAW_COLOR, 1)?;
    draw_trace(&mut chart, &zm.sp, z, SETPOINT_COLOR, LINE_WIDTH)?;
    draw_trace(&mut chart, &zm.smooth, z, SMOOTHED_COLOR, LINE_WIDTH)?;
    vline(&mut chart, 0.0, &y, MARKER_COLOR, 1)?;
    if let (Some(a), Some(b)) = zm.rise {
        for pt in [a, b] {
            vline(&mut chart, pt.0, &y, RISE_COLOR, LINE_WIDTH)?;
            chart.draw_series(std::iter::once(Circle::new(pt, 5, RISE_COLOR.filled())))?;
        }
    }
    if let Some(s) = zm.settled {
        vline(&mut chart, s.0, &y, SETTLE_COLOR, LINE_WIDTH)?;
        chart.draw_series(std::iter::once(Circle::new(s, 5, SETTLE_COLOR.filled())))?;
    }
    if let Some(pk) = zm.peak {
        vline(&mut chart, pk.0, &y, OVERSHOOT_COLOR, LINE_WIDTH)?;
        chart.draw_series(std::iter::once(Circle::new(
            pk,
            6,
            OVERSHOOT_COLOR.filled(),
        )))?;
    }
    frame(&chart)?;
    panel_legend(root, area, &chart, entries)?;
    draw_marker_labels(root, &chart, &labels, y.end)?;
    Ok(())
}

/// Draws the figure of [`write_step_png`].
fn draw_step(root: &Area<'_>, p: &StepPlot<'_>) -> Result<(), BoxError> {
    let body = titled(root, p.title)?;
    let (m, e) = (p.metrics, p.events);
    let t = p.t_s;
    let t_at = |k: usize| t.get(k).copied().filter(|v| v.is_finite());
    let t_all: Vec<f64> = t.iter().copied().filter(|v| v.is_finite()).collect();
    let t_range = padded_range(&t_all, 0.0, 0.0, 0.0..1.0);
    let period_s = match (t_all.first(), t_all.last()) {
        (Some(a), Some(b)) if t_all.len() > 1 => (b - a) / (t_all.len() - 1) as f64,
        _ => 0.0,
    };
    let t_step = t_at(e.step)
        .or(t_all.last().copied())
        .unwrap_or(t_range.start);
    let zoom = step_zoom(&t_range, t_step, period_s, m);
    let step_um = m.step_m * 1e6;
    let error_um: Vec<f64> = p
        .setpoint_um
        .iter()
        .zip(p.position_um)
        .map(|(s, y)| s - y)
        .collect();

    // Heights: the whole record above, the zoom below.
    let (_, body_h) = body.dim_in_pixel();
    let h = |frac: f64| (f64::from(body_h) * frac) as u32;
    let (ov_pos, rest) = body.split_vertically(h(0.18));
    let (ov_cmd, rest) = rest.split_vertically(h(0.13));
    let (ov_err, rest) = rest.split_vertically(h(0.13) + X_LABEL_AREA + 10);
    let (_, rest) = rest.split_vertically(24);
    let (zoom_pos, zoom_cmd) = rest.split_vertically(h(0.30));

    let sp_stairs = staircase(t, p.setpoint_um);
    let cmd_stairs = staircase(t, p.command_a);
    let pos = pairs(t, p.position_um);

    draw_overview_position(root, &ov_pos, &t_range, &zoom, &sp_stairs, &pos)?;
    draw_overview_command(root, &ov_cmd, &t_range, &zoom, &cmd_stairs, m)?;
    let err = pairs(t, &error_um);
    let steady_from_s = t_at(e.steady_state_from);
    draw_overview_error(root, &ov_err, &t_range, steady_from_s, &err, m)?;

    // The zoom, in ms since the step.
    let ms = |v: f64| (v - t_step) * 1e3;
    let z = ms(zoom.start)..ms(zoom.end);
    let to_ms =
        |pts: &[(f64, f64)]| -> Vec<(f64, f64)> { pts.iter().map(|&(x, y)| (ms(x), y)).collect() };
    let (sp_z, pos_z, cmd_z) = (to_ms(&sp_stairs), to_ms(&pos), to_ms(&cmd_stairs));
    let smooth_z = to_ms(&pairs(t, p.smoothed_um));
    let event = |k: Option<usize>| {
        k.and_then(|k| Some((ms(t_at(k)?), p.smoothed_um.get(k).copied()?)))
            .filter(|(x, _)| *x >= z.start && *x <= z.end)
    };
    let rise = (event(e.rise_from), event(e.rise_to));
    let settled = event(e.settled);
    let peak = event(e.peak).filter(|_| m.overshoot_pct > 0.0);
    let band = (
        step_um * (1.0 - SETTLING_BAND),
        step_um * (1.0 + SETTLING_BAND),
    );

    let mut items = vec![(
        0.0,
        format!("step of {} µm", fmt_sig(step_um, 3)),
        MARKER_COLOR,
    )];
    let mut notes = Vec::new();
    match (rise, m.rise_time_s) {
        ((Some(a), Some(b)), Some(rt)) => items.push((
            0.5 * (a.0 + b.0),
            format!("rise 10–90 %: {}", fmt_ms(rt)),
            RISE_COLOR,
        )),
        _ => notes.push(entry("rise 10–90 %: not reached", Swatch::Text)),
    }
    match (settled, m.settling_time_s) {
        (Some(s), Some(ts)) => items.push((
            s.0,
            format!(
                "settled (±{} %): {}",
                fmt_sig(SETTLING_BAND * 100.0, 3),
                fmt_ms(ts)
            ),
            SETTLE_COLOR,
        )),
        _ => notes.push(entry("not settled by the end of the record", Swatch::Text)),
    }
    // The note says what the summary says (`m.overshoot_pct`); the marker
    // only where the zoom shows the peak.
    match (peak, m.overshoot_pct > 0.0) {
        (Some(pk), _) => items.push((
            pk.0,
            format!(
                "overshoot {:.1} % ({} µm at {})",
                m.overshoot_pct,
                fmt_sig(pk.1, 4),
                fmt_ms(pk.0 * 1e-3)
            ),
            OVERSHOOT_COLOR,
        )),
        (None, true) => notes.push(entry(
            format!(
                "overshoot {:.1} % (its peak at {}, outside this zoom)",
                m.overshoot_pct,
                e.peak
                    .and_then(t_at)
                    .map_or("?".into(), |t| fmt_ms(t - t_step))
            ),
            Swatch::Text,
        )),
        (None, false) => notes.push(entry("no overshoot", Swatch::Text)),
    }
    let mut entries = vec![
        entry("setpoint", Swatch::Line(SETPOINT_COLOR, LINE_WIDTH)),
        entry(
            "position (probe)",
            Swatch::Line(POSITION_RAW_COLOR, LINE_WIDTH),
        ),
        entry(
            format!(
                "position, {} moving average (the metrics')",
                fmt_ms(SMOOTHING_S)
            ),
            Swatch::Line(SMOOTHED_COLOR, LINE_WIDTH),
        ),
        entry(
            format!(
                "±{} % band (±{} µm)",
                fmt_sig(SETTLING_BAND * 100.0, 3),
                fmt_sig(step_um.abs() * SETTLING_BAND, 3)
            ),
            Swatch::Fill(BAND_COLOR, BAND_ALPHA),
        ),
    ];
    entries.extend(notes);
    let zm = Zoom {
        z,
        sp: sp_z,
        pos: pos_z,
        smooth: smooth_z,
        rise,
        settled,
        peak,
        band,
    };
    draw_zoom_position(root, &zoom_pos, &zm, items, &entries)?;
    draw_zoom_command(root, &zoom_cmd, &zm.z, &cmd_z)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn metrics(rise: Option<f64>, settle: Option<f64>) -> StepMetrics {
        StepMetrics {
            step_m: 1e-5,
            rise_time_s: rise,
            settling_time_s: settle,
            settling_margin: None,
            overshoot_pct: 0.0,
            steady_state_error_mean_nm: 0.0,
            steady_state_error_std_nm: 0.0,
            steady_state_window_s: 1.0,
            peak_command_a: 0.0,
        }
    }

    /// The zoom window rule of `write_step_png`, worked by hand.
    #[test]
    fn plot_step_zoom_window() {
        let rec = 0.0..4.0;
        let w = step_zoom(&rec, 0.2, 2e-4, &metrics(Some(0.005), Some(0.1)));
        // post = max(0.2, 0.02, 0.004) = 0.2, pre = 0.02.
        assert!(
            (w.start - 0.18).abs() < 1e-12 && (w.end - 0.4).abs() < 1e-12,
            "{w:?}"
        );
        let w = step_zoom(&rec, 0.2, 2e-4, &metrics(Some(0.05), Some(0.01)));
        // post = 4 x rise = 0.2.
        assert!((w.end - 0.4).abs() < 1e-12, "{w:?}");
        let w = step_zoom(&rec, 0.2, 2e-4, &metrics(Some(1e-5), Some(0.0)));
        // post = 20 periods = 4 ms, pre = 2 periods = 0.4 ms.
        assert!(
            (w.start - 0.1996).abs() < 1e-12 && (w.end - 0.204).abs() < 1e-12,
            "{w:?}"
        );
        // Never settled: to the end of the record.
        let w = step_zoom(&rec, 0.2, 2e-4, &metrics(None, None));
        assert!((w.end - 4.0).abs() < 1e-12 && w.start == 0.0, "{w:?}");
        // Bounded by the record: a step at its start has no lead.
        let w = step_zoom(&rec, 0.0, 2e-4, &metrics(Some(0.005), Some(0.1)));
        assert_eq!(w.start, 0.0);
        let w = step_zoom(&rec, 3.9, 2e-4, &metrics(Some(0.005), Some(0.5)));
        assert!((w.end - 4.0).abs() < 1e-12, "{w:?}");
    }
}
