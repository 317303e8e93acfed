//! The design figure ([`write_design_png`]) of `bench design`: the open
//! loop `L = C·P` of every measured FRF as a Nyquist plot against the
//! modulus-margin circle and the phase-margin sector, and as Bode plots of
//! `L` and of the sensitivity `S = 1/(1 + L)`, the worst loop highlighted.
//!
//! The figure takes plain slices: it does not know the design job (layer
//! rule in [`super`]).

use std::f64::consts::PI;
use std::ops::Range;
use std::path::Path;

use nalgebra::Complex;
use plotters::coord::ranged1d::Ranged;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::axes::{
    frame, freq_chart, linear_axis, mesh, panel_chart, plot_columns, plot_rows, Chart, Ticked,
    X_LABEL_AREA,
};
use super::bode::bode_curve;
use super::draw::{draw_polyline, draw_runs, hline, pairs, runs, runs_in_box, values_in, vline};
use super::legend::{
    area_legend, entry, legend_height, marker_style, panel_legend, titled, Entry, Swatch,
};
use super::measured::to_db;
use super::palette::{
    BANDWIDTH_COLOR, MARKER_COLOR, MODEL_COLOR, OTHER_LOOP_COLOR, PHASE_MARGIN_COLOR,
    SENSITIVITY_LIMIT_COLOR, WORST_LOOP_COLOR,
};
use super::png::{invalid, write_png_atomically};
use super::style::LINE_WIDTH;
use super::ticks::{
    fmt_sig, fmt_tick, linear_ticks, log_range, padded_range, phase_ticks, ticks_every,
};
use super::{Area, BoxError, PlotError};
use crate::outputs::Existing;

/// One open loop of the design figure.
#[derive(Debug, Clone, Copy)]
pub struct DesignLoop<'a> {
    /// The input FRF's name (the legend names the worst loop by it).
    pub label: &'a str,
    /// Frequency grid, rad/s: finite, > 0, strictly ascending.
    pub omega_rad_s: &'a [f64],
    /// `L(jω) = C(jω)·P(jω)`, dimensionless, one per `omega_rad_s`, finite.
    pub loop_gain: &'a [Complex<f64>],
    /// Drawn highlighted: thick, in [`WORST_LOOP_COLOR`], on top of the
    /// others, and named in the legend.
    pub worst: bool,
}

/// Everything shown in the design figure (see [`write_design_png`]).
#[derive(Debug, Clone, Copy)]
pub struct DesignPlot<'a> {
    /// Figure title, drawn above the panels (omitted when empty).
    pub title: &'a str,
    /// The loops of the measured FRFs; those not `worst` are drawn thin in
    /// [`OTHER_LOOP_COLOR`].
    pub loops: &'a [DesignLoop<'a>],
    /// The model's loop (dashed, optional), on its own grid; clipped to the
    /// loops' frequency band in the Bode panels (its `worst` is ignored).
    pub model: Option<DesignLoop<'a>>,
    /// The ‖S‖∞ limit `s_max` (> 0): the circle of radius `1/s_max` about
    /// −1 in the Nyquist panel (a loop outside it has `|S| ≤ s_max`), and a
    /// line at `20·log10(s_max)` dB in the |S| panel.
    pub sensitivity_peak_max: f64,
    /// The least phase margin, degrees (0 to 180): the unit circle is
    /// marked from `180° − PM` to `180° + PM`, where a loop may not cross
    /// it, and the phase panel has a line at `−180° + PM`.
    pub phase_margin_min_deg: f64,
    /// The gain crossover, rad/s: a vertical marker in the Bode panels.
    pub crossover_rad_s: Option<f64>,
    /// The sensitivity bandwidth ω_B, rad/s, where |S| first reaches −3 dB:
    /// a vertical marker in the |S| panel, with the −3 dB line.
    pub sensitivity_bandwidth_rad_s: Option<f64>,
}

/// Size of the design figure, px.
const DESIGN_SIZE: (u32, u32) = (1400, 1000);
/// Width of the Nyquist column (left), px; the Bode panels take the rest.
const NYQUIST_W: u32 = 720;
/// The real axis the Nyquist panel shows at least, and the half-height of
/// the imaginary axis (centred on 0): the region around −1 where the
/// margins are read. The longer side of the panel shows more, for an equal
/// aspect ratio.
const NYQUIST_RE: Range<f64> = -3.0..1.0;
const NYQUIST_IM_HALF: f64 = 2.0;
/// Line widths of the worst loop and of the others, px.
const WORST_WIDTH: u32 = 3;
const OTHER_WIDTH: u32 = 1;
/// The |L| and |S| panels show no more than this far from 0 dB (|L| goes
/// to infinity at the integrator, |S| to zero).
const DB_LIMIT: f64 = 100.0;
/// The |S| panel shows no more than this far below its top.
const S_DB_SPAN: f64 = 70.0;

/// Writes the design figure of `plot` as a 1400×1000 px PNG to `path`.
///
/// Left, the Nyquist plane (Re L, Im L) with an equal aspect ratio, showing
/// at least [−3, 1] × [−2, 2] (curves are clipped to it: the loops go to
/// infinity at low frequency with the integrator): every loop, the critical
/// point −1, the unit circle (thin), the modulus-margin circle of radius
/// `1/s_max` about −1 labelled `‖S‖∞ = s_max`, and the phase-margin sector
/// `180° ± PM_min` on the unit circle with its rays from the origin.
///
/// Right, on one logarithmic ω axis (rad/s) spanning the loops' grids: |L|
/// in dB with the 0 dB line; ∠L in degrees (unwrapped, and shifted by whole
/// turns so that the lowest frequency lies within 180° of −90°, the phase
/// of an integrator) with lines at −180° and −180° + PM_min; |S| = |1/(1 +
/// L)| in dB with the `s_max` and −3 dB lines. The crossover is marked on
/// all three, ω_B on the |S| panel; a marker outside the ω axis is left
/// out.
///
/// The loops not marked `worst` are drawn thin in a muted colour, the
/// model dashed, the worst loops thick on top. The legend strip above the
/// panels names the worst loops, counts the others ("other inputs (N)")
/// and names the model.
///
/// # Errors
///
/// [`PlotError::InvalidData`], naming the loop, if a loop's `omega_rad_s`
/// and `loop_gain` differ in length, a frequency is not finite and
/// positive or not above the one before, or a loop gain is not finite; also
/// if `sensitivity_peak_max` is not finite and positive,
/// `phase_margin_min_deg` is not within 0 to 180, or a marker frequency is
/// not finite and positive. Otherwise as for
/// [`write_bode_png`](super::write_bode_png).
pub fn write_design_png(
    path: &Path,
    existing: Existing,
    plot: &DesignPlot<'_>,
) -> Result<(), PlotError> {
    for l in plot.loops {
        check_loop(path, "loop", l)?;
    }
    if let Some(m) = &plot.model {
        check_loop(path, "model loop", m)?;
    }
    let s_max = plot.sensitivity_peak_max;
    if !(s_max.is_finite() && s_max > 0.0) {
        return Err(invalid(
            path,
            format!("sensitivity_peak_max {s_max} is not a positive finite number"),
        ));
    }
    let pm = plot.phase_margin_min_deg;
    if !(0.0..=180.0).contains(&pm) {
        return Err(invalid(
            path,
            format!("phase_margin_min_deg {pm} is not within 0 to 180"),
        ));
    }
    for (name, w) in [
        ("crossover_rad_s", plot.crossover_rad_s),
        (
            "sensitivity_bandwidth_rad_s",
            plot.sensitivity_bandwidth_rad_s,
        ),
    ] {
        if let Some(w) = w.filter(|w| !(w.is_finite() && *w > 0.0)) {
            return Err(invalid(
                path,
                format!("{name} {w} is not a positive finite frequency"),
            ));
        }
    }
    write_png_atomically(path, existing, DESIGN_SIZE, |root| draw_design(root, plot))
}

/// Checks one loop: equal lengths, a finite, positive, strictly ascending
/// grid and finite loop gains.
fn check_loop(path: &Path, which: &str, l: &DesignLoop<'_>) -> Result<(), PlotError> {
    let name = format!("{which} {:?}", l.label);
    let (w, g) = (l.omega_rad_s, l.loop_gain);
    let bad = |reason: String| Err(invalid(path, format!("{name}: {reason}")));
    if w.len() != g.len() {
        return bad(format!(
            "{} frequencies but {} loop gains",
            w.len(),
            g.len()
        ));
    }
    if let Some((k, v)) = w
        .iter()
        .enumerate()
        .find(|(_, v)| !(v.is_finite() && **v > 0.0))
    {
        return bad(format!(
            "frequency {k} is {v} rad/s, not positive and finite"
        ));
    }
    if let Some(k) = (1..w.len()).find(|&k| w[k] <= w[k - 1]) {
        return bad(format!(
            "frequencies not ascending at {k}: {} rad/s after {} rad/s",
            w[k],
            w[k - 1]
        ));
    }
    if let Some((k, v)) = g
        .iter()
        .enumerate()
        .find(|(_, v)| !(v.re.is_finite() && v.im.is_finite()))
    {
        return bad(format!("loop gain {k} is {v}, not finite"));
    }
    Ok(())
}

/// How a loop is drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Role {
    /// Thin and muted, below the others.
    Other,
    /// Dashed.
    Model,
    /// Thick, on top.
    Worst,
}

/// One loop in plot units.
struct LoopCurves {
    role: Role,
    /// `(Re L, Im L)`.
    nyquist: Vec<(f64, f64)>,
    /// `(ω, |L| dB)`.
    mag_db: Vec<(f64, f64)>,
    /// `(ω, ∠L °)`, unwrapped, the low-frequency end near −90°.
    phase_deg: Vec<(f64, f64)>,
    /// `(ω, |S| dB)`.
    s_db: Vec<(f64, f64)>,
}

impl LoopCurves {
    fn new(l: &DesignLoop<'_>, role: Role) -> Self {
        let (mag, phase) = bode_curve(l.loop_gain, Some(-90.0));
        let db: Vec<f64> = mag.into_iter().map(to_db).collect();
        let s_db: Vec<f64> = l
            .loop_gain
            .iter()
            .map(|g| to_db(1.0 / (g + 1.0).norm()))
            .collect();
        Self {
            role,
            nyquist: l.loop_gain.iter().map(|g| (g.re, g.im)).collect(),
            mag_db: pairs(l.omega_rad_s, &db),
            phase_deg: pairs(l.omega_rad_s, &phase),
            s_db: pairs(l.omega_rad_s, &s_db),
        }
    }

    /// Draws `runs` of this loop in its style.
    fn draw<X: Ranged<ValueType = f64>>(
        &self,
        chart: &mut Chart<'_, '_, X>,
        runs: &[Vec<(f64, f64)>],
    ) -> Result<(), BoxError> {
        match self.role {
            Role::Model => draw_runs(chart, runs, MODEL_COLOR, true),
            Role::Other | Role::Worst => {
                let (color, width) = if self.role == Role::Worst {
                    (WORST_LOOP_COLOR, WORST_WIDTH)
                } else {
                    (OTHER_LOOP_COLOR, OTHER_WIDTH)
                };
                for run in runs {
                    draw_polyline(chart, run, color, width)?;
                }
                Ok(())
            }
        }
    }
}

/// The loops in drawing order: the others, the model, the worst on top.
fn loop_curves(plot: &DesignPlot<'_>) -> Vec<LoopCurves> {
    let mut out: Vec<LoopCurves> = plot
        .loops
        .iter()
        .filter(|l| !l.worst)
        .map(|l| LoopCurves::new(l, Role::Other))
        .collect();
    out.extend(plot.model.iter().map(|m| LoopCurves::new(m, Role::Model)));
    out.extend(
        plot.loops
            .iter()
            .filter(|l| l.worst)
            .map(|l| LoopCurves::new(l, Role::Worst)),
    );
    out
}

/// The legend entries of the loops.
fn loop_entries(plot: &DesignPlot<'_>) -> Vec<Entry> {
    let mut entries: Vec<Entry> = plot
        .loops
        .iter()
        .filter(|l| l.worst)
        .map(|l| {
            entry(
                format!("worst: {}", l.label),
                Swatch::Line(WORST_LOOP_COLOR, WORST_WIDTH),
            )
        })
        .collect();
    let others = plot.loops.iter().filter(|l| !l.worst).count();
    if others > 0 {
        entries.push(entry(
            format!("other inputs ({others})"),
            Swatch::Line(OTHER_LOOP_COLOR, OTHER_WIDTH),
        ));
    }
    if let Some(m) = &plot.model {
        let text = if m.label.is_empty() || m.label == "model" {
            "model".to_string()
        } else {
            format!("model ({})", m.label)
        };
        entries.push(entry(text, Swatch::Dashed(MODEL_COLOR)));
    }
    entries
}

/// Draws the figure of [`write_design_png`]: the loops' legend strip
/// across the top, the Nyquist panel left, the Bode panels right.
fn draw_design(root: &Area<'_>, plot: &DesignPlot<'_>) -> Result<(), BoxError> {
    let body = titled(root, plot.title)?;
    let entries = loop_entries(plot);
    let strip_h = legend_height(&body, &entries)?;
    let (strip, panels) = body.split_vertically(strip_h + 4);
    area_legend(root, &strip, &entries)?;
    let (left, right) = panels.split_horizontally(NYQUIST_W);
    let curves = loop_curves(plot);
    draw_nyquist(root, &left, plot, &curves)?;
    draw_bode_column(root, &right, plot, &curves)
}

/// `s` with its hyphen-minus signs as the minus sign the legends use.
fn minus(s: &str) -> String {
    s.replace('-', "−")
}

/// A point on the circle of `radius` about `centre` at `angle` (rad).
fn on_circle(centre: (f64, f64), radius: f64, angle: f64) -> (f64, f64) {
    (
        centre.0 + radius * angle.cos(),
        centre.1 + radius * angle.sin(),
    )
}

/// The arc of the circle of `radius` about `centre` from angle `a0` to
/// `a1` (rad), as a polyline of about one point per degree.
fn arc(centre: (f64, f64), radius: f64, a0: f64, a1: f64) -> Vec<(f64, f64)> {
    let n = ((a1 - a0).abs().to_degrees().ceil() as usize).max(2);
    (0..=n)
        .map(|i| on_circle(centre, radius, a0 + (a1 - a0) * i as f64 / n as f64))
        .collect()
}

/// The axes of the Nyquist panel with its frame spanning `cols` × `rows`
/// px: equal scales, at least [`NYQUIST_RE`] × ±[`NYQUIST_IM_HALF`], the
/// longer side showing more (centred on the same middle).
fn nyquist_axes(cols: f64, rows: f64) -> (Range<f64>, Range<f64>) {
    let (re_span, im_span) = (NYQUIST_RE.end - NYQUIST_RE.start, 2.0 * NYQUIST_IM_HALF);
    let per_px = (re_span / cols.max(1.0)).max(im_span / rows.max(1.0));
    let re_mid = 0.5 * (NYQUIST_RE.start + NYQUIST_RE.end);
    let (re_half, im_half) = (0.5 * cols * per_px, 0.5 * rows * per_px);
    ((re_mid - re_half)..(re_mid + re_half), -im_half..im_half)
}

/// The Nyquist panel on `area`.
fn draw_nyquist(
    root: &Area<'_>,
    area: &Area<'_>,
    plot: &DesignPlot<'_>,
    curves: &[LoopCurves],
) -> Result<(), BoxError> {
    let s_max = plot.sensitivity_peak_max;
    let pm = plot.phase_margin_min_deg;
    let radius = 1.0 / s_max;
    let entries = [
        entry("unit circle |L| = 1", Swatch::Line(MARKER_COLOR, 1)),
        entry(
            format!(
                "‖S‖∞ = {}: |1 + L| = {} about −1",
                fmt_sig(s_max, 3),
                fmt_sig(radius, 3)
            ),
            Swatch::Line(SENSITIVITY_LIMIT_COLOR, LINE_WIDTH),
        ),
        entry(
            format!("phase margin < {}°", fmt_sig(pm, 3)),
            Swatch::Line(PHASE_MARGIN_COLOR, 5),
        ),
    ];
    let top = legend_height(area, &entries)? + 6;
    let (c0, c1) = plot_columns(area);
    let (r0, r1) = plot_rows(area, top, true);
    let (re, im) = nyquist_axes(f64::from(c1 - c0), f64::from(r1 - r0));
    let re_ticks = linear_ticks(&re, 8);
    let step = match re_ticks.as_slice() {
        [a, b, ..] => b - a,
        _ => 1.0,
    };
    let im_ticks = ticks_every(&im, step);
    let fmt = |v: &f64| fmt_tick(if v.abs() < 1e-9 { 0.0 } else { *v });
    let mut chart = panel_chart(area, linear_axis(&re, re_ticks), &im, im_ticks, top, true)?;
    mesh(&mut chart, Some("Re L [-]"), "Im L [-]", &fmt, &fmt)?;

    let clip = |pts: &[(f64, f64)]| runs_in_box(pts, &re, &im);
    for run in clip(&arc((0.0, 0.0), 1.0, 0.0, 2.0 * PI)) {
        draw_polyline(&mut chart, &run, MARKER_COLOR, 1)?;
    }
    if pm > 0.0 {
        let (a0, a1) = (PI - pm.to_radians(), PI + pm.to_radians());
        for a in [a0, a1] {
            let ray = [(0.0, 0.0), on_circle((0.0, 0.0), 1.0, a)];
            draw_runs(&mut chart, &clip(&ray), PHASE_MARGIN_COLOR, true)?;
        }
        for run in clip(&arc((0.0, 0.0), 1.0, a0, a1)) {
            draw_polyline(&mut chart, &run, PHASE_MARGIN_COLOR, 5)?;
        }
    }
    for run in clip(&arc((-1.0, 0.0), radius, 0.0, 2.0 * PI)) {
        draw_polyline(&mut chart, &run, SENSITIVITY_LIMIT_COLOR, LINE_WIDTH)?;
    }
    for c in curves {
        c.draw(&mut chart, &clip(&c.nyquist))?;
    }
    // The labels last, over the curves: the circle's upper left (clear of
    // the loops, which come from below, and of the phase-margin arc).
    let label_at = on_circle((-1.0, 0.0), radius, 0.75 * PI);
    if re.contains(&label_at.0) && im.contains(&label_at.1) {
        let mut style = marker_style(SENSITIVITY_LIMIT_COLOR);
        style.pos = Pos::new(HPos::Right, VPos::Bottom);
        chart.draw_series(std::iter::once(Text::new(
            format!("‖S‖∞ = {}", fmt_sig(s_max, 3)),
            label_at,
            style,
        )))?;
    }
    chart.draw_series(std::iter::once(Cross::new(
        (-1.0, 0.0),
        6,
        BLACK.stroke_width(2),
    )))?;
    // "−1" above left of the cross, clear of the loops (which pass below).
    let (px, py) = chart.backend_coord(&(-1.0, 0.0));
    root.draw(&Text::new("−1", (px - 12, py - 4), marker_style(BLACK)))?;
    frame(&chart)?;
    panel_legend(root, area, &chart, &entries)
}

/// The dB range of `values` (at least `min_span`), kept within
/// `floor..ceil`.
fn db_range(values: &[f64], min_span: f64, floor: f64, ceil: f64) -> Range<f64> {
    let r = padded_range(values, 0.06, min_span, -40.0..40.0);
    let (lo, hi) = (r.start.max(floor), r.end.min(ceil));
    if lo < hi {
        lo..hi
    } else {
        r
    }
}

/// A panel on the logarithmic ω axis.
type OmegaChart<'a, 'b> = Chart<'a, 'b, Ticked<LogCoord<f64>>>;

/// The Bode panels on `area`: |L|, ∠L and |S| on one ω axis.
fn draw_bode_column(
    root: &Area<'_>,
    area: &Area<'_>,
    plot: &DesignPlot<'_>,
    curves: &[LoopCurves],
) -> Result<(), BoxError> {
    // The loops' grids set the ω axis; only without them does the model.
    let x = if plot.loops.iter().any(|l| !l.omega_rad_s.is_empty()) {
        log_range(
            plot.loops
                .iter()
                .flat_map(|l| l.omega_rad_s.iter().copied()),
        )
    } else {
        log_range(
            plot.model
                .iter()
                .flat_map(|l| l.omega_rad_s.iter().copied()),
        )
    };
    let in_x = |w: Option<f64>| w.filter(|w| x.contains(w));
    let crossover = in_x(plot.crossover_rad_s);
    let bandwidth = in_x(plot.sensitivity_bandwidth_rad_s);
    let s_max_db = to_db(plot.sensitivity_peak_max);
    let pm_line = -180.0 + plot.phase_margin_min_deg;

    let mut mag_entries = vec![entry("|L| = 1 (0 dB)", Swatch::Line(BLACK, 1))];
    mag_entries.extend(crossover.map(|w| {
        entry(
            format!("crossover {} rad/s", fmt_sig(w, 3)),
            Swatch::Dashed(MARKER_COLOR),
        )
    }));
    let phase_entries = vec![
        entry("−180°", Swatch::Line(BLACK, 1)),
        entry(
            format!("−180° + PM_min = {}°", minus(&fmt_sig(pm_line, 3))),
            Swatch::Dashed(PHASE_MARGIN_COLOR),
        ),
    ];
    let mut s_entries = vec![
        entry(
            format!(
                "‖S‖∞ limit {} ({} dB)",
                fmt_sig(plot.sensitivity_peak_max, 3),
                minus(&fmt_sig(s_max_db, 3))
            ),
            Swatch::Dashed(SENSITIVITY_LIMIT_COLOR),
        ),
        entry("−3 dB", Swatch::Line(BANDWIDTH_COLOR, 1)),
    ];
    s_entries.extend(bandwidth.map(|w| {
        entry(
            format!("ω_B {} rad/s", fmt_sig(w, 3)),
            Swatch::Dashed(BANDWIDTH_COLOR),
        )
    }));

    let tops = [
        legend_height(area, &mag_entries)? + 6,
        legend_height(area, &phase_entries)? + 6,
        legend_height(area, &s_entries)? + 6,
    ];
    let (_, h) = area.dim_in_pixel();
    let plot_h = f64::from(h.saturating_sub(X_LABEL_AREA + 10 + tops.iter().sum::<u32>()));
    let (mag_area, rest) = area.split_vertically((plot_h * 0.34) as u32 + tops[0]);
    let (phase_area, s_area) = rest.split_vertically((plot_h * 0.30) as u32 + tops[1]);
    let panel = |area, which, top, entries| LoopPanel {
        area,
        x: x.clone(),
        which,
        top,
        entries,
    };
    let axis_line = |chart: &mut OmegaChart<'_, '_>, y: f64, color: RGBColor| {
        draw_polyline(chart, &[(x.start, y), (x.end, y)], color, 1)
    };
    let crossover_line = |chart: &mut OmegaChart<'_, '_>, y: &Range<f64>| match crossover {
        Some(w) => vline(chart, w, y, MARKER_COLOR, LINE_WIDTH),
        None => Ok(()),
    };

    let p = panel(mag_area, Panel::Magnitude, tops[0], mag_entries);
    let y = db_range(&p.values(curves, &[0.0]), 20.0, -DB_LIMIT, DB_LIMIT);
    p.draw(
        root,
        curves,
        &y,
        linear_ticks(&y, 8),
        "|L| [dB]",
        &|chart| {
            axis_line(chart, 0.0, BLACK)?;
            crossover_line(chart, &y)
        },
    )?;

    let p = panel(phase_area, Panel::Phase, tops[1], phase_entries);
    let y = padded_range(
        &p.values(curves, &[-180.0, pm_line]),
        0.06,
        90.0,
        -270.0..0.0,
    );
    p.draw(root, curves, &y, phase_ticks(&y), "∠L [°]", &|chart| {
        axis_line(chart, -180.0, BLACK)?;
        hline(chart, pm_line, &x, PHASE_MARGIN_COLOR)?;
        crossover_line(chart, &y)
    })?;

    let p = panel(s_area, Panel::Sensitivity, tops[2], s_entries);
    let v = p.values(curves, &[s_max_db, -3.0]);
    let top = padded_range(&v, 0.06, 20.0, -40.0..10.0).end;
    let y = db_range(&v, 20.0, (top - S_DB_SPAN).max(-DB_LIMIT), DB_LIMIT);
    p.draw(
        root,
        curves,
        &y,
        linear_ticks(&y, 8),
        "|S| [dB]",
        &|chart| {
            axis_line(chart, -3.0, BANDWIDTH_COLOR)?;
            hline(chart, s_max_db, &x, SENSITIVITY_LIMIT_COLOR)?;
            crossover_line(chart, &y)?;
            match bandwidth {
                Some(w) => vline(chart, w, &y, BANDWIDTH_COLOR, LINE_WIDTH),
                None => Ok(()),
            }
        },
    )
}

/// Which Bode panel of the design figure.
#[derive(Debug, Clone, Copy)]
enum Panel {
    /// |L| in dB.
    Magnitude,
    /// ∠L in degrees.
    Phase,
    /// |S| in dB (the bottom panel, with the ω axis labelled).
    Sensitivity,
}

impl LoopCurves {
    /// The curve of this loop shown in `panel`.
    fn of(&self, panel: Panel) -> &[(f64, f64)] {
        match panel {
            Panel::Magnitude => &self.mag_db,
            Panel::Phase => &self.phase_deg,
            Panel::Sensitivity => &self.s_db,
        }
    }
}

/// One Bode panel of the design figure, before it is drawn.
struct LoopPanel<'b> {
    area: Area<'b>,
    x: Range<f64>,
    which: Panel,
    /// Space above the frame, for the legend strip, px.
    top: u32,
    entries: Vec<Entry>,
}

impl LoopPanel<'_> {
    /// The values of the loops' curves inside the ω axis, and `extra`
    /// (the guide lines, which set the range too).
    fn values(&self, curves: &[LoopCurves], extra: &[f64]) -> Vec<f64> {
        let mut v: Vec<f64> = curves
            .iter()
            .flat_map(|c| values_in(c.of(self.which), &self.x))
            .collect();
        v.extend_from_slice(extra);
        v
    }

    /// Draws the panel over `y` (labelled at `ticks`): its mesh, `guides`,
    /// the loops in drawing order, the frame and the legend strip.
    fn draw(
        &self,
        root: &Area<'_>,
        curves: &[LoopCurves],
        y: &Range<f64>,
        ticks: Vec<f64>,
        y_desc: &str,
        guides: &dyn Fn(&mut OmegaChart<'_, '_>) -> Result<(), BoxError>,
    ) -> Result<(), BoxError> {
        let bottom = matches!(self.which, Panel::Sensitivity);
        let x_desc = "Frequency ω [rad/s]";
        let mut chart = freq_chart(
            &self.area, &self.x, y, ticks, self.top, bottom, x_desc, y_desc,
        )?;
        guides(&mut chart)?;
        for c in curves {
            c.draw(&mut chart, &runs(c.of(self.which), &self.x, true))?;
        }
        frame(&chart)?;
        panel_legend(root, &self.area, &chart, &self.entries)
    }
}
