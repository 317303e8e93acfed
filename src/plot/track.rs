//! The tracking figure ([`write_track_png`], `bench track`): the reference
//! against the position over one line, the RMS error of every trial, and
//! the error's spectrum beside the bands the plant's zeros close.

use std::ops::Range;
use std::path::Path;

use plotters::prelude::*;

use super::axes::{frame, freq_axis, linear_axis, mesh, panel_chart, time_chart, MARGIN_TOP};
use super::draw::{draw_trace, hline, pairs, shade, values_in};
use super::legend::{entry, legend_height, panel_legend, titled, Entry, Swatch};
use super::palette::{BAND_ALPHA, BAND_COLOR, MARKER_COLOR, SERIES, SETPOINT_COLOR};
use super::png::{invalid, write_png_atomically};
use super::style::LINE_WIDTH;
use super::ticks::{fmt_sig, log_ticks, padded_range, positive_extent};
use super::{Area, BoxError, PlotError};
use crate::outputs::Existing;

/// One trial of a tracking run (see [`write_track_png`]).
#[derive(Debug, Clone, Copy)]
pub struct TrackTrialPlot<'a> {
    /// `standstill`, `feedback`, `feedforward`, `learning-N`, …
    pub name: &'a str,
    /// RMS error over the measured lines, nm.
    pub rms_error_nm: f64,
    /// Its 1σ, nm (NaN: none drawn).
    pub rms_error_sigma_nm: f64,
    /// The mean line of the position, µm (empty: not drawn in the top
    /// panel), one value per `TrackPlot::t_s`.
    pub position_um: &'a [f64],
    /// The amplitude of each harmonic of the mean line of the error, nm,
    /// one per `TrackPlot::harmonic_hz` (empty: not drawn in the spectrum).
    pub error_amplitude_nm: &'a [f64],
}

/// A tracking run (see [`write_track_png`]).
#[derive(Debug, Clone)]
pub struct TrackPlot<'a> {
    /// Figure title (omitted when empty).
    pub title: &'a str,
    /// Time within one line, s.
    pub t_s: &'a [f64],
    /// The reference over that line, µm.
    pub reference_um: &'a [f64],
    /// The harmonics' frequencies, Hz (the line rate times 1, 2, …).
    pub harmonic_hz: &'a [f64],
    /// The trials in order, the first the standstill one.
    pub trials: Vec<TrackTrialPlot<'a>>,
    /// The noise floor (the standstill trial's RMS error, or the reading's
    /// quantisation floor when that is larger), nm.
    pub noise_floor_nm: f64,
    /// What the noise floor is, for the legend ("the standstill").
    pub noise_floor_of: &'a str,
    /// The reference's cut-off, Hz.
    pub cutoff_hz: f64,
    /// The bands the plant's zeros close: (label, low, high), Hz.
    pub zero_bands: Vec<(String, f64, f64)>,
}

/// Size of the tracking figure, px.
const TRACK_SIZE: (u32, u32) = (1400, 1500);

/// Writes a tracking run as a 1400×1500 px PNG (SVG, PDF by the extension)
/// to `path`, three panels:
/// * the reference and the mean line of the position (µm) of every trial
///   that has one, over one line (ms);
/// * the RMS error of every trial (nm, logarithmic) with its ±1σ bar, the
///   noise floor and 1.5× the noise floor (where learning stops,
///   converged) dashed;
/// * the amplitude of the mean error line's harmonics (nm, logarithmic;
///   a dot per harmonic, joined by a thin line) against frequency (Hz,
///   logarithmic) for every trial that has them,
///   the zeros' bands shaded and the reference's cut-off dashed.
///
/// # Errors
/// [`PlotError::InvalidData`] if a slice differs in length from the axis
/// it is drawn on, or there are no trials; otherwise as for
/// [`write_bode_png`](super::write_bode_png).
pub fn write_track_png(
    path: &Path,
    existing: Existing,
    plot: &TrackPlot<'_>,
) -> Result<(), PlotError> {
    if plot.trials.is_empty() {
        return Err(invalid(path, "no trials to plot".to_string()));
    }
    if plot.reference_um.len() != plot.t_s.len() {
        return Err(invalid(
            path,
            format!(
                "the reference has {} samples but t_s has {}",
                plot.reference_um.len(),
                plot.t_s.len()
            ),
        ));
    }
    for t in &plot.trials {
        let pos = t.position_um.len();
        let amp = t.error_amplitude_nm.len();
        if (pos != 0 && pos != plot.t_s.len()) || (amp != 0 && amp != plot.harmonic_hz.len()) {
            return Err(invalid(
                path,
                format!(
                    "trial {}: {pos} positions for {} times, {amp} amplitudes for {} harmonics",
                    t.name,
                    plot.t_s.len(),
                    plot.harmonic_hz.len()
                ),
            ));
        }
    }
    write_png_atomically(path, existing, TRACK_SIZE, |root| draw_track(root, plot))
}

/// The colour of trial `i` (the standstill one draws none of its own).
fn trial_color(i: usize) -> RGBColor {
    SERIES[(i + 1) % SERIES.len()]
}

/// Draws the three panels of [`write_track_png`].
fn draw_track(root: &Area<'_>, plot: &TrackPlot<'_>) -> Result<(), BoxError> {
    let body = titled(root, plot.title)?;
    let (_, h) = body.dim_in_pixel();
    let (top, rest) = body.split_vertically(h * 36 / 100);
    let (middle, bottom) = rest.split_vertically(h * 28 / 100);
    draw_lines(root, &top, plot)?;
    draw_trials(root, &middle, plot)?;
    draw_spectrum(root, &bottom, plot)
}

/// The reference against the position over one line.
fn draw_lines(root: &Area<'_>, area: &Area<'_>, plot: &TrackPlot<'_>) -> Result<(), BoxError> {
    let t_ms: Vec<f64> = plot.t_s.iter().map(|t| t * 1e3).collect();
    let mut entries = vec![entry(
        "reference",
        Swatch::Line(SETPOINT_COLOR, LINE_WIDTH + 2),
    )];
    let mut curves = vec![(
        SETPOINT_COLOR,
        LINE_WIDTH + 2,
        pairs(&t_ms, plot.reference_um),
    )];
    for (i, t) in plot.trials.iter().enumerate() {
        if !t.position_um.is_empty() {
            entries.push(entry(
                format!("position, {} (mean line)", t.name),
                Swatch::Line(trial_color(i), LINE_WIDTH),
            ));
            curves.push((trial_color(i), LINE_WIDTH, pairs(&t_ms, t.position_um)));
        }
    }
    let x = padded_range(&t_ms, 0.0, 0.0, 0.0..1.0);
    let vals: Vec<f64> = curves.iter().flat_map(|c| values_in(&c.2, &x)).collect();
    let y = padded_range(&vals, 0.06, 0.0, -1.0..1.0);
    let top = MARGIN_TOP.max(legend_height(area, &entries)? + 6);
    let mut chart = time_chart(
        area,
        &x,
        &y,
        top,
        true,
        "time within a line [ms]",
        "position [µm]",
    )?;
    for (color, width, pts) in &curves {
        draw_trace(&mut chart, pts, &x, *color, *width)?;
    }
    frame(&chart)?;
    panel_legend(root, area, &chart, &entries)
}

/// A logarithmic value axis in log10 units over `values` (positive),
/// labelled in the values' own unit: its range and its ticks.
fn log_value_axis(values: impl Iterator<Item = f64>) -> (Range<f64>, Vec<f64>) {
    let (lo, hi) = positive_extent(values).unwrap_or((1.0, 10.0));
    let (lo, hi) = (lo / 1.5, hi * 1.5);
    let (bold, _) = log_ticks(&(lo..hi));
    (
        lo.log10()..hi.log10(),
        bold.iter().map(|v| v.log10()).collect(),
    )
}

/// A log10 value formatted in its own unit.
fn fmt_log(v: &f64) -> String {
    fmt_sig(10f64.powf(*v), 3)
}

/// The RMS error of every trial, with its 1σ and the noise floor.
fn draw_trials(root: &Area<'_>, area: &Area<'_>, plot: &TrackPlot<'_>) -> Result<(), BoxError> {
    let floor = plot.noise_floor_nm;
    let (y, y_ticks) = log_value_axis(
        plot.trials
            .iter()
            .flat_map(|t| [t.rms_error_nm, t.rms_error_nm + t.rms_error_sigma_nm])
            .chain([floor, 1.5 * floor]),
    );
    let n = plot.trials.len();
    let x = -0.5..(n as f64 - 0.5);
    let x_ticks: Vec<f64> = (0..n).map(|i| i as f64).collect();
    let mut entries: Vec<Entry> = plot
        .trials
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let sigma = if t.rms_error_sigma_nm.is_finite() {
                format!(" ± {}", fmt_sig(t.rms_error_sigma_nm, 2))
            } else {
                String::new()
            };
            entry(
                format!("{i}: {} {}{sigma} nm", t.name, fmt_sig(t.rms_error_nm, 3)),
                Swatch::Line(trial_color(i), LINE_WIDTH),
            )
        })
        .collect();
    entries.push(entry(
        format!(
            "noise floor {} nm ({}), and 1.5× it",
            fmt_sig(floor, 3),
            plot.noise_floor_of
        ),
        Swatch::Dashed(MARKER_COLOR),
    ));
    let top = MARGIN_TOP.max(legend_height(area, &entries)? + 6);
    let mut chart = panel_chart(area, linear_axis(&x, x_ticks), &y, y_ticks, top, true)?;
    let x_fmt = |v: &f64| format!("{v:.0}");
    mesh(
        &mut chart,
        Some("trial (± 1σ from the scatter between lines)"),
        "RMS error [nm]",
        &x_fmt,
        &fmt_log,
    )?;
    for f in [floor, 1.5 * floor] {
        if f > 0.0 && f.is_finite() {
            hline(&mut chart, f.log10(), &x, MARKER_COLOR)?;
        }
    }
    for (i, t) in plot.trials.iter().enumerate() {
        let c = trial_color(i);
        let xi = i as f64;
        if t.rms_error_sigma_nm.is_finite() && t.rms_error_sigma_nm > 0.0 {
            let lo = (t.rms_error_nm - t.rms_error_sigma_nm).max(t.rms_error_nm * 1e-3);
            let hi = t.rms_error_nm + t.rms_error_sigma_nm;
            chart.draw_series(std::iter::once(PathElement::new(
                [(xi, lo.log10()), (xi, hi.log10())],
                c.stroke_width(LINE_WIDTH),
            )))?;
        }
        if t.rms_error_nm > 0.0 && t.rms_error_nm.is_finite() {
            chart.draw_series(std::iter::once(Circle::new(
                (xi, t.rms_error_nm.log10()),
                7,
                c.filled(),
            )))?;
        }
    }
    frame(&chart)?;
    panel_legend(root, area, &chart, &entries)
}

/// The error's harmonics beside the zeros' bands and the cut-off.
fn draw_spectrum(root: &Area<'_>, area: &Area<'_>, plot: &TrackPlot<'_>) -> Result<(), BoxError> {
    let shown: Vec<(usize, &TrackTrialPlot<'_>)> = plot
        .trials
        .iter()
        .enumerate()
        .filter(|(_, t)| !t.error_amplitude_nm.is_empty())
        .collect();
    let (y, y_ticks) = log_value_axis(
        shown
            .iter()
            .flat_map(|(_, t)| t.error_amplitude_nm.iter().copied()),
    );
    let (f_lo, f_hi) = positive_extent(plot.harmonic_hz.iter().copied()).unwrap_or((1.0, 1e3));
    let x = f_lo..f_hi.max(f_lo * 10.0);
    let mut entries: Vec<Entry> = shown
        .iter()
        .map(|(i, t)| {
            entry(
                format!("error, {}", t.name),
                Swatch::Line(trial_color(*i), LINE_WIDTH),
            )
        })
        .collect();
    for (label, lo, hi) in &plot.zero_bands {
        entries.push(entry(
            format!(
                "{label}: no loop tracks {}–{} Hz",
                fmt_sig(*lo, 3),
                fmt_sig(*hi, 3)
            ),
            Swatch::Fill(BAND_COLOR, BAND_ALPHA * 2.0),
        ));
    }
    entries.push(entry(
        format!("reference cut-off {} Hz", fmt_sig(plot.cutoff_hz, 3)),
        Swatch::Dashed(MARKER_COLOR),
    ));
    let top = MARGIN_TOP.max(legend_height(area, &entries)? + 6);
    let (bold, light) = log_ticks(&x);
    let mut chart = panel_chart(area, freq_axis(&x, &bold, &light), &y, y_ticks, top, true)?;
    let x_fmt = |v: &f64| fmt_sig(*v, 3);
    mesh(
        &mut chart,
        Some("frequency [Hz]"),
        "error amplitude [nm]",
        &x_fmt,
        &fmt_log,
    )?;
    for (_, lo, hi) in &plot.zero_bands {
        if *hi > x.start && *lo < x.end {
            shade(
                &mut chart,
                (lo.max(x.start), hi.min(x.end)),
                (y.start, y.end),
                BAND_COLOR,
                BAND_ALPHA,
            )?;
        }
    }
    if plot.cutoff_hz > x.start && plot.cutoff_hz < x.end {
        super::draw::vline(&mut chart, plot.cutoff_hz, &y, MARKER_COLOR, LINE_WIDTH)?;
    }
    for (i, t) in &shown {
        let pts: Vec<(f64, f64)> = plot
            .harmonic_hz
            .iter()
            .zip(t.error_amplitude_nm)
            .filter(|(_, a)| **a > 0.0)
            .map(|(f, a)| (*f, a.log10()))
            .collect();
        draw_trace(&mut chart, &pts, &x, trial_color(*i), 1)?;
        chart.draw_series(
            pts.iter()
                .filter(|p| p.0 >= x.start && p.0 <= x.end)
                .map(|p| Circle::new(*p, 4, trial_color(*i).filled())),
        )?;
    }
    frame(&chart)?;
    panel_legend(root, area, &chart, &entries)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plot_track_figure_is_written_and_checks_its_lengths() {
        let dir = tempfile::tempdir().unwrap();
        let n = 200;
        let t: Vec<f64> = (0..n).map(|i| i as f64 * 1e-3 / 2.0).collect();
        let r: Vec<f64> = t
            .iter()
            .map(|t| 5.0 * (2.0 * std::f64::consts::PI * 10.0 * t).sin())
            .collect();
        let y: Vec<f64> = r.iter().map(|v| 0.9 * v).collect();
        let f: Vec<f64> = (1..=20).map(|k| 10.0 * f64::from(k)).collect();
        let a: Vec<f64> = f.iter().map(|f| 1e3 / f).collect();
        let trial = |name, rms, pos, amp| TrackTrialPlot {
            name,
            rms_error_nm: rms,
            rms_error_sigma_nm: rms * 0.05,
            position_um: pos,
            error_amplitude_nm: amp,
        };
        let mut plot = TrackPlot {
            title: "track",
            t_s: &t,
            reference_um: &r,
            harmonic_hz: &f,
            trials: vec![
                trial("standstill", 43.0, &[], &[]),
                trial("feedback", 1293.0, &y, &a),
                trial("learning-1", 50.0, &r, &a),
            ],
            noise_floor_nm: 43.0,
            noise_floor_of: "the standstill",
            cutoff_hz: 58.9,
            zero_bands: vec![("CMP-CNMP 83.3 Hz".into(), 58.9, 102.0)],
        };
        let path = dir.path().join("track.png");
        write_track_png(&path, Existing::Refuse, &plot).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), TRACK_SIZE);
        plot.trials[1].position_um = &r[..10];
        let err = write_track_png(&dir.path().join("bad.png"), Existing::Refuse, &plot);
        assert!(matches!(err, Err(PlotError::InvalidData { .. })), "{err:?}");
        assert!(!dir.path().join("bad.png").exists());
    }
}
