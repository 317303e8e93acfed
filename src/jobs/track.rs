//! `bench track`: a periodic scan tracked by the feedback loop, then with
//! the model-inverse feedforward, then learned trial by trial (ILC) until
//! the error reaches the noise floor ([`crate::track`] for the reference,
//! the feedforward and the learning law).
//!
//! The trials, each one real-time run recorded to its own MCAP file in the
//! output directory:
//! 1. `standstill`: the loop holds its start position, no reference: the
//!    error's RMS over the measured periods is the noise floor.
//! 2. `feedback`: the scan, the controller alone.
//! 3. `feedforward`: the scan plus the model-inverse feedforward.
//! 4. `learning-N`: the feedforward learned from the trial before.
//!
//! Every trial runs its warm-up periods ([`WARM_UP_PERIODS`] at least, and
//! [`WARM_UP_TIME_CONSTANTS`] of the loop's slowest: the first faded in), then
//! the measured periods, then one period fading the scan out and one
//! holding the start ([`TrackJob`]: the stage ends still where it began,
//! so the next trial takes it at rest); the error (setpoint − reading) of
//! the measured periods, averaged period by period, is what the learning
//! reads.
//!
//! Learning stops when a trial's RMS error is within
//! [`CONVERGED_OF_NOISE_FLOOR`] of the noise floor (`converged`), when it
//! grew beyond its 2σ two trials in a row (`diverged`: the best trial's
//! feedforward is kept; [`stop_rule`]), after the trial budget (`budget`), or before a trial whose
//! learned feedforward would exceed the current limits on the model
//! (`limit`: that trial is not run). The best feedforward is
//! written as a CSV table (`feedforward.csv`), the summary and its figure,
//! rewritten after every trial, as `track.json` and `track.png`
//! ([`write_track_png`]): a fault ends the learning with every recording
//! finished and the summary and figure of the trials before it on disk;
//! when a learning trial faults, the best feedforward learned before it is
//! written too (`stop`: `fault`).
//! Every RMS error carries its 1σ from the scatter between the measured
//! lines ([`measured_error`]).
//!
//! Before anything is enabled the scan is planned on the model: its
//! line must last a whole number of ticks, its fundamental must lie below
//! the band of the plant's lowest zero (else no loop follows it at all),
//! and the predicted command of the feedforward trial (`u = CS·r + S·f`)
//! must stay within the peak current and, as RMS, the continuous current
//! in force; its peak position within the position limit.

use crate::config::BenchConfig;
use crate::control::loop_check::check_loop;
use crate::control::verify::ModelLoop;
use crate::control::DiscreteController;
use crate::error::RunError;
use crate::jobs::control::StageSource;
use crate::jobs::session::{finish, open_recording, run_recorded, Kept, Runner, SessionOptions};
use crate::outputs::{Existing, Origin, OutputPlan};
use crate::plot::{write_track_png, TrackPlot, TrackTrialPlot};
use crate::rt::backend::BackendSpec;
use crate::rt::supervisor::StallBounds;
use crate::track::measured::MeasuredPs;
use crate::track::{
    model_inverse, predict, settle, DerivativeGains, FeedforwardKind, Harmonics, Learning,
    MoveLimits, MoveProfile, Scan, ScanKind, TrackJob, ZeroBand,
};
use bench_plant::model::Sr4dof;
use bench_plant::sim::{ScheduledFault, ZohPlant};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::sync::Arc;

/// Periods run before the measured ones at least: the first faded in, the
/// second for the loop's transient to decay.
pub const WARM_UP_PERIODS: u64 = 2;

/// The warm-up lasts at least this many of the loop's slowest time
/// constants (on the model): the fade-in's transient decays to `e⁻⁵`,
/// 0.7 % of its start, before a line is measured. A lightly damped mode
/// the loop leaves alone (ζ 1 % at 22 Hz: τ = 0.72 s) outlasts two lines
/// of a 10 Hz scan by far; the part left of it differs from line to line
/// and is no error learning can remove.
pub const WARM_UP_TIME_CONSTANTS: f64 = 5.0;

/// A learning trial whose RMS error is within this factor of the noise
/// floor has converged (issue 44: "the error within 1.5× its noise floor").
pub const CONVERGED_OF_NOISE_FLOOR: f64 = 1.5;

/// The summary a run writes in its directory, rewritten after every trial
/// (a directory that holds it is a track run's: `bench upload` sends it
/// whole).
pub const TRACK_SUMMARY_FILE: &str = "track.json";

/// Everything `bench track` needs.
#[derive(Debug, Clone)]
pub struct TrackOptions {
    /// Validated config.
    pub config: BenchConfig,
    /// Where it came from.
    pub config_path: PathBuf,
    /// Controller name.
    pub controller: String,
    /// The scan (its `cutoff_hz` is set by the plan).
    pub scan: Scan,
    /// `--cutoff-hz`; `None`: the default smoothing (module docs).
    pub cutoff_hz: Option<f64>,
    /// Learning trials at most, 1–100.
    pub trials: u32,
    /// The learning gain `α`, (0, 1].
    pub learning_gain: f64,
    /// Measured periods per trial, 1–1000.
    pub periods: u32,
    /// The output directory.
    pub out_dir: PathBuf,
    /// Simulator seed.
    pub seed: u64,
    /// `--backend` (else `[backend]` of the config).
    pub backend: Option<BackendSpec>,
    /// Real-time pacing (hardware always).
    pub realtime: bool,
    /// Virtual time at this factor of real time on a simulator (the
    /// daemon's `pace`); `None`: as fast as it goes, or real time.
    pub pace: Option<f64>,
    /// Replace existing outputs.
    pub overwrite: bool,
    /// The model the feedforward and the learning law are computed on: a
    /// bench config (`bench fit --update`'s, say) and where it came from;
    /// `None`: the bench config's own `[plant]`.
    pub model: Option<(BenchConfig, PathBuf)>,
    /// `--feedforward`: a learned table (`feedforward.csv`) replayed in
    /// place of the model-inverse feedforward, learning going on from it.
    pub feedforward: Option<PathBuf>,
    /// A simulator fault, its time counted from the first trial's start
    /// (`--inject-fault`; refused on hardware).
    pub inject_fault: Option<ScheduledFault>,
    /// The band a move settles into, ± m (`--settle-band-m`).
    pub settle_band_m: f64,
    /// The feedforward trial's feedforward (`--feedforward-kind`).
    pub feedforward_kind: FeedforwardKind,
    /// `--learning-ps`: a `bench control --verify` recording of this
    /// loop, whose measured PS the learning filter inverts
    /// ([`crate::track::measured`]); `None`: the model's PS.
    pub learning_ps: Option<PathBuf>,
    /// The fields the config's `[trajectory]` gave (an error about one
    /// names it `trajectory.KEY`: [`TrackOptions::name_of`]).
    pub from_trajectory: Vec<&'static str>,
}

impl TrackOptions {
    /// How an error names option `key`: `trajectory.KEY of CONFIG` when
    /// the config's `[trajectory]` gave it, else by `field` (the CLI's
    /// flag, the daemon's `params.KEY`).
    pub fn name_of(&self, key: &str, field: impl FnOnce(&str) -> String) -> String {
        trajectory_name(&self.from_trajectory, &self.config_path, key, field)
    }
}

/// The scan as planned on the model before the first trial.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct TrackPlan {
    /// The model the feedforward and the learning law are computed on:
    /// the config file whose `[plant]` it is.
    pub model: PathBuf,
    /// The scan, with the cut-off in force.
    pub scan: Scan,
    /// Ticks per line.
    pub period_ticks: usize,
    /// The highest harmonic kept (and learned).
    pub harmonics: usize,
    /// The bands the plant's zeros close, ascending.
    pub zero_bands: Vec<ZeroBand>,
    /// The reference's harmonics inside a zero band, each `(k, Hz)`: kept
    /// only with a cut-off given (`--cutoff-hz`), and warned about.
    pub harmonics_in_zero_bands: Vec<(usize, f64)>,
    /// The harmonics below the default cut-off that the smoothing removed
    /// because they lie in a zero's band, each `(k, Hz)`.
    pub harmonics_removed: Vec<(usize, f64)>,
    /// The harmonics (number, Hz) the learning leaves as they are: those
    /// inside a zero's band ([`Learning::leave_out_bands`]).
    pub harmonics_not_learned: Vec<(usize, f64)>,
    /// Predicted peak of the feedforward trial's command, A.
    pub predicted_peak_current_a: f64,
    /// Predicted RMS of its command, A.
    pub predicted_rms_current_a: f64,
    /// Peak of the reference about the start, m.
    pub peak_reference_m: f64,
    /// Predicted RMS error of feedback alone on the model, m.
    pub predicted_feedback_rms_error_m: f64,
    /// The learning gain `α`.
    pub learning_gain: f64,
    /// Largest `|1 − L_k·PS_k|` on the model over the learned harmonics:
    /// the error's contraction per trial (`1 − α` on the model itself).
    pub model_contraction: f64,
    /// The feedforward trial's feedforward: the model's inverse or the
    /// reference's derivatives.
    pub feedforward_kind: FeedforwardKind,
    /// The derivatives' gains (`snap`), fitted on the model; null for
    /// the inverse.
    pub derivative_gains: Option<DerivativeGains>,
    /// A move's planned profile (its widths `w₁…w₄`, s); null for a scan.
    pub move_profile: Option<MoveProfile>,
    /// The band a move settles into, ± m; null for a scan.
    pub settle_band_m: Option<f64>,
    /// A move's reference inside the right-half-plane zeros' bands,
    /// `Σ|R_k|` over those harmonics, m: no loop tracks it, only the
    /// feedforward does, as well as the model is right there (warned
    /// when above the settle band); null for a scan.
    pub move_in_zero_bands_m: Option<f64>,
    /// The slower limits that bring that content within the settle band,
    /// when the move's own do not and a slower move still fits the line.
    pub smoother_move: Option<MoveLimits>,
    /// What the learning filter inverts: `model` (the model's PS) or
    /// `measured` (the PS of `learning_ps`).
    pub learning_filter: String,
    /// The `bench control --verify` recording the measured PS is from.
    pub learning_ps: Option<PathBuf>,
    /// With a measured PS, each harmonic's check: the measured PS with
    /// its 1σ beside the model's, the contraction bound at 2σ of the
    /// measured and of the model's `L`, and whether it is learned
    /// (empty with the model's PS).
    pub learning_checks: Vec<crate::track::measured::HarmonicCheck>,
    /// With a measured PS, `1 − max |1 − L_k·PS_k|` at 2σ over the learned
    /// harmonics: the monotonic-convergence margin the measurement
    /// vouches for (null with the model's PS, or nothing learned).
    pub convergence_margin: Option<f64>,
    /// The harmonic's frequency that sets it, Hz.
    pub convergence_margin_at_hz: Option<f64>,
    /// The slowest time constant of the closed loop on the model,
    /// `−T/ln|z|` of its largest pole `z`, s.
    pub slowest_time_constant_s: f64,
    /// Lines run before the measured ones: [`WARM_UP_PERIODS`] at least,
    /// and [`WARM_UP_TIME_CONSTANTS`] of the slowest time constant.
    pub warm_up_periods: u64,
}

/// One trial's result.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct TrialReport {
    /// `standstill`, `feedback`, `feedforward` or `learning-N`.
    pub name: String,
    /// RMS of the error over the measured periods, m.
    pub rms_error_m: f64,
    /// 1σ of `rms_error_m` from the scatter between the measured lines, m
    /// (null with one line).
    pub rms_error_sigma_m: f64,
    /// Largest |error| over them, m.
    pub peak_error_m: f64,
    /// RMS error over the noise floor (1 for the standstill trial).
    pub of_noise_floor: f64,
    /// 1σ of `of_noise_floor`, both RMS errors' σ propagated to first
    /// order (the standstill trial's own: its σ alone).
    pub of_noise_floor_sigma: f64,
    /// RMS of the feedforward played, A.
    pub feedforward_rms_a: f64,
    /// RMS of the command (feedback + feedforward) over the measured
    /// lines, A: what the coil carried.
    pub command_rms_a: f64,
    /// The command's RMS predicted before the trial, A: on the model for
    /// the feedforward trial (`u = CS·r + S·f`), from the last trial's
    /// measured command for a learning trial (`u + S·Δf`); null for the
    /// others.
    pub predicted_command_rms_a: Option<f64>,
    /// A move's move-and-settle time: from each move's start until the
    /// reference has arrived and the error, averaged over the lines and a
    /// 1 ms window, stays within the settle band to the middle of the
    /// dwell, the slower of a line's two moves, s
    /// ([`crate::track::settle()`]); null for a scan, the standstill, or a
    /// move that did not settle before the next.
    pub settle_time_s: Option<f64>,
    /// The 1σ noise of that averaged error, m (null for a scan).
    pub settle_noise_sigma_m: Option<f64>,
    /// Whether the settle band is at least 4σ of that noise
    /// ([`crate::track::Settle::trusted`]): a settle time judged on a
    /// narrower band may be noise (null for a scan).
    pub settle_trusted: Option<bool>,
    /// The recording.
    pub recording: PathBuf,
}

/// Result of `bench track`.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct TrackSummary {
    /// Controller name.
    pub controller: String,
    /// Backend.
    pub backend: String,
    /// Seed.
    pub seed: u64,
    /// The plan.
    pub plan: TrackPlan,
    /// The noise floor, m: the larger of the standstill trial's RMS error
    /// and the reading's quantisation floor (`quantization_floor_m`). The
    /// trials' `of_noise_floor` and the `converged` rule are relative to
    /// it.
    pub noise_floor_m: f64,
    /// 1σ of `noise_floor_m`, m: the standstill trial's when it is the
    /// floor; 0 when the quantisation floor is (a stated code width, not a
    /// measurement).
    pub noise_floor_sigma_m: f64,
    /// The reading's quantisation floor, m: `q/√12`, `q` the wider of the
    /// probe's code (`probe.quantization_m`) and the link's count
    /// ([`bench_hal::DeviceInfo::probe_lsb_m`]; 0 on the simulator). It is
    /// the RMS of the quantisation error of a reading that crosses many
    /// codes, and, for any reference, the RMS distance from the reference
    /// to the nearest code with the probe's zero anywhere within a code
    /// (Widrow & Kollár, *Quantization Noise*, 2008: the uniform model,
    /// variance `q²/12`). The wider code, not the two combined: the two
    /// may describe the same converter, and two in series leave at least
    /// the wider one's. A scan's error is about this at best (0.95× on
    /// one bench with a 1 µm code, where the zero sat well); a standstill
    /// reading that stays on one code does not show it when the probe's
    /// noise is below about one code.
    pub quantization_floor_m: f64,
    /// The trials so far, in order.
    pub trials: Vec<TrialReport>,
    /// Why learning stopped: `converged`, `diverged`, `budget`, `limit`
    /// (the next learned feedforward would exceed the current limits,
    /// predicted on the model: not run) or `fault` (a learning trial
    /// faulted: the best feedforward before it is kept); absent while it
    /// runs, or after a fault before learning began.
    pub stop: Option<String>,
    /// The trial with the least RMS error among those with a scan.
    pub best_trial: Option<String>,
    /// Feedback-alone RMS error over the best trial's.
    pub improvement: Option<f64>,
    /// 1σ of `improvement`, both RMS errors' σ propagated to first order.
    pub improvement_sigma: Option<f64>,
    /// The best feedforward's table (`feedforward.csv`).
    pub feedforward_csv: Option<PathBuf>,
    /// A move: the feedback trial's settling time over the feedforward
    /// (or replayed) trial's; null when either did not settle or was
    /// judged on an untrusted band.
    pub settle_speedup: Option<f64>,
}

fn ticks_per_line(cfg: &BenchConfig, line_rate_hz: f64) -> Result<usize, RunError> {
    let rate = cfg.loop_.rate_hz;
    if !(line_rate_hz.is_finite() && line_rate_hz > 0.0) {
        return Err(RunError::option(
            "line_rate_hz",
            line_rate_hz,
            "must be a frequency > 0 Hz".to_string(),
        ));
    }
    let n = rate / line_rate_hz;
    let whole = n.round();
    if (n - whole).abs() > 1e-9 * n || whole < 8.0 {
        return Err(RunError::option(
            "line_rate_hz",
            line_rate_hz,
            format!(
                "a line must last a whole number of ticks, at least 8: loop.rate_hz {rate} / {line_rate_hz} = {n:.4}"
            ),
        ));
    }
    Ok(whole as usize)
}

/// A harmonic of the reference below this fraction of its amplitude is
/// nothing (a CSV's rounding, not content): not listed as inside a band.
const NEGLIGIBLE_OF_AMPLITUDE: f64 = 1e-6;

/// Checks the scan against the plant's zero bands and sets the default
/// cut-off; returns the scan in force and the harmonics inside a band.
fn plan_scan(
    scan: &Scan,
    cutoff_hz: Option<f64>,
    bands: &[ZeroBand],
    (rate_hz, stroke_m): (f64, f64),
    n: usize,
) -> Result<(Scan, Vec<(usize, f64)>), RunError> {
    let a = scan.amplitude_m;
    if !(a.is_finite() && a > 0.0) {
        return Err(RunError::option(
            "amplitude_m",
            a,
            "must be a length > 0 m".to_string(),
        ));
    }
    let nyquist = rate_hz / 2.0;
    // Above the lowest right-half-plane zero's band no feedforward helps
    // (module docs); an MMP band only closes itself.
    let nmp = bands.iter().find(|b| b.right_half_plane());
    let lowest = nmp.map_or(nyquist, |b| b.low_hz.min(nyquist));
    let closing = bands.iter().find(|b| b.contains(scan.line_rate_hz));
    if scan.line_rate_hz >= lowest || closing.is_some() {
        let why = match closing.or(nmp) {
            Some(b) => format!(
                "lies in or above the band {:.1}–{:.1} Hz that the {} zero at {:.1} Hz closes",
                b.low_hz, b.high_hz, b.kind, b.zero_hz
            ),
            None => format!("is at or above the Nyquist frequency {nyquist} Hz"),
        };
        return Err(RunError::option(
            "line_rate_hz",
            scan.line_rate_hz,
            format!("the loop cannot follow this line at all: its fundamental {why}"),
        ));
    }
    // A move's reference is played whole: its cut-off bounds only the
    // feedforward and the learning, by default at 4× the highest band's
    // upper edge (every zero's band inverted, module docs).
    let default_cutoff = if scan.played_whole() {
        let top = bands.iter().map(|b| b.high_hz).fold(0.0, f64::max);
        if top > 0.0 {
            (4.0 * top).min(nyquist)
        } else {
            nyquist
        }
    } else {
        lowest
    };
    let cutoff = cutoff_hz.unwrap_or(default_cutoff);
    if !(cutoff.is_finite() && cutoff > scan.line_rate_hz && cutoff <= nyquist) {
        return Err(RunError::option(
            "cutoff_hz",
            cutoff,
            format!(
                "must lie above the line rate {} Hz and at most at the Nyquist frequency {nyquist} Hz",
                scan.line_rate_hz
            ),
        ));
    }
    let scan = Scan {
        cutoff_hz: cutoff,
        ..scan.clone()
    };
    check_move(&scan, rate_hz, stroke_m)?;
    let r = scan.harmonics(n);
    let inside: Vec<(usize, f64)> = (1..=scan.k_max())
        .map(|k| (k, Harmonics::frequency_hz(k, scan.line_rate_hz)))
        .filter(|(k, f)| {
            bands.iter().any(|b| b.contains(*f)) && r.coef[*k].norm() > NEGLIGIBLE_OF_AMPLITUDE * a
        })
        .collect();
    Ok((scan, inside))
}

/// A move's limits in their ranges (`stroke_m` the stroke) and its
/// profile within a quarter of the line:
/// each move is followed by a dwell at least as long, in which it settles.
fn check_move(scan: &Scan, rate_hz: f64, stroke_m: f64) -> Result<(), RunError> {
    if scan.kind != ScanKind::Move {
        return Ok(());
    }
    let Some(limits) = scan.move_limits else {
        return Err(RunError::BadInput(
            "a move needs its limits (max_velocity_m_s, max_acceleration_m_s2, max_jerk_m_s3)"
                .to_string(),
        ));
    };
    limits.validate(stroke_m, rate_hz).map_err(|(name, v, max)| {
        RunError::option(
            name,
            v,
            format!("must lie above 0 and at most {max:e}, which crosses the whole stroke (2 safety.position_limit_m) within one tick"),
        )
    })?;
    let p = scan.move_profile().expect("a move with limits");
    let d = p.duration_s();
    let quarter = 0.25 / scan.line_rate_hz;
    if d > quarter || d * rate_hz < 2.0 {
        return Err(RunError::option(
            "line_rate_hz",
            scan.line_rate_hz,
            format!(
                "a move of {:.2} ms within these limits needs a line of at least 4× it (a dwell as long as the move after each of its two moves): at most {:.3} lines/s, or faster limits; and a move must last 2 ticks at least",
                d * 1e3,
                0.25 / d
            ),
        ));
    }
    Ok(())
}

/// The move's content in the right-half-plane zeros' bands (module docs
/// of [`crate::track`]), which no loop tracks and only the feedforward
/// does, as well as the model is right there: `Σ|R_k|` over the
/// harmonics of its table inside any such band, m, and the limits
/// slowed by the least `λ` ([`MoveLimits::slower`], 1.25ⁱ up to 16)
/// that brings the content within `band_m`, if one does and the move
/// still fits the line.
fn move_in_zero_bands(
    scan: &Scan,
    n: usize,
    bands: &[ZeroBand],
    band_m: f64,
) -> (f64, Option<MoveLimits>) {
    let line = scan.line_rate_hz;
    let bands: Vec<&ZeroBand> = bands.iter().filter(|b| b.right_half_plane()).collect();
    let top = bands.iter().map(|b| b.high_hz).fold(0.0, f64::max);
    let k_top = ((top / line) as usize).min(n / 2);
    let content = |s: &Scan| -> f64 {
        let h = Harmonics::analyze(&s.table(n), k_top);
        (1..=k_top)
            .filter(|&k| {
                let f = Harmonics::frequency_hz(k, line);
                bands.iter().any(|b| b.contains(f))
            })
            .map(|k| h.coef[k].norm())
            .sum()
    };
    let now = content(scan);
    if now <= band_m || k_top == 0 {
        return (now, None);
    }
    let limits = scan.move_limits.expect("a move");
    let mut lambda = 1.0;
    while lambda < 16.0 {
        lambda *= 1.25;
        let limits = limits.slower(lambda);
        let slower = Scan {
            move_limits: Some(limits),
            ..scan.clone()
        };
        let fits = slower
            .move_profile()
            .is_some_and(|p| p.duration_s() <= 0.25 / line);
        if !fits {
            break;
        }
        if content(&slower) <= band_m {
            return (now, Some(limits));
        }
    }
    (now, None)
}

/// Plans the scan on the model (module docs): the reference and the
/// model-inverse feedforward's harmonics, the learning law and the plan.
fn plan(
    opts: &TrackOptions,
    model: &ModelLoop<'_>,
    bands: Vec<ZeroBand>,
    measured_ps: Option<&MeasuredPs>,
) -> Result<(TrackPlan, Harmonics, Harmonics, Learning), RunError> {
    let cfg = &opts.config;
    let n = ticks_per_line(cfg, opts.scan.line_rate_hz)?;
    let (scan, inside) = plan_scan(
        &opts.scan,
        opts.cutoff_hz,
        &bands,
        (cfg.loop_.rate_hz, 2.0 * cfg.safety.position_limit_m),
        n,
    )?;
    let is_move = scan.kind == ScanKind::Move;
    let g = opts.learning_gain;
    if !(g.is_finite() && g > 0.0 && g <= 1.0) {
        return Err(RunError::option(
            "learning_gain",
            g,
            "must lie in (0, 1]: the share of the last trial's error learned".to_string(),
        ));
    }
    let mut r = scan.harmonics(n);
    // The default smoothing also removes what lies in a band below the
    // cut-off (an MMP zero's); a cut-off given keeps it, with a warning.
    // A move's reference is its profile: nothing is removed from it (its
    // feedforward inverts the bands too, below); only its harmonics in a
    // right-half-plane band are listed.
    let mut inside = inside;
    if scan.played_whole() {
        inside.retain(|(_, f)| bands.iter().any(|b| b.right_half_plane() && b.contains(*f)));
    }
    let (inside, removed) = if opts.cutoff_hz.is_none() && !scan.played_whole() {
        for (k, _) in &inside {
            r.coef[*k] = crate::ident::C64::new(0.0, 0.0);
        }
        (Vec::new(), inside)
    } else {
        (inside, Vec::new())
    };
    // A move's feedforward inverts the model on every harmonic below the
    // cut-off, inside the zeros' bands too: a move cannot avoid them (a
    // step has content at every frequency), and the periodic inversion
    // with a whole line of preview handles a right-half-plane zero
    // exactly on the model (module docs of `crate::track`), where no
    // loop can (`T(z) = 0`). The current check below judges its cost.
    // The series of 1/P converges below the plant's lowest zero; a plant
    // without one is fitted up to the Nyquist frequency's 30 %.
    let f_zero_hz = bands
        .iter()
        .map(|b| b.zero_hz)
        .fold(cfg.loop_.rate_hz / 2.0, f64::min);
    let gains = (opts.feedforward_kind == FeedforwardKind::Snap)
        .then(|| DerivativeGains::fit(model, f_zero_hz));
    let f = match &gains {
        None => model_inverse(&r, model, scan.line_rate_hz),
        Some(g) => g.feedforward(&r, scan.line_rate_hz),
    };
    let (peak_u, rms_u) = predicted_current(&r, &f, model, scan.line_rate_hz);
    let (_, e_fb) = predict(
        &r,
        &Harmonics::zeros(r.coef.len() - 1, n),
        model,
        scan.line_rate_hz,
    );
    let peak_r = scan.table(n).iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let settle_band_m = opts.settle_band_m;
    if is_move && !(settle_band_m.is_finite() && settle_band_m > 0.0 && settle_band_m < peak_r) {
        return Err(RunError::option(
            "settle_band_m",
            settle_band_m,
            format!("must lie above 0 and below the move's {peak_r:.3e} m"),
        ));
    }
    let (in_bands, slower) = if is_move {
        let (c, l) = move_in_zero_bands(&scan, n, &bands, settle_band_m);
        (Some(c), l)
    } else {
        (None, None)
    };
    let (mut learning, mut checks) = match measured_ps {
        Some(m) => crate::track::measured::learning(m, model, g, scan.k_max(), scan.line_rate_hz),
        None => (
            Learning::new(model, g, scan.k_max(), scan.line_rate_hz),
            Vec::new(),
        ),
    };
    let not_learned = learning.leave_out_bands(&bands, scan.line_rate_hz);
    for c in &mut checks {
        c.learned &= !not_learned.contains(&c.harmonic);
    }
    let margin = crate::track::measured::margin(&checks);
    let (tau_s, warm_up) = warm_up_of(model, n, cfg.loop_.rate_hz);
    let contraction = learning
        .contraction(&learning.ps_model)
        .into_iter()
        .enumerate()
        .filter(|(i, _)| learning.learns(i + 1))
        .map(|(_, c)| c)
        .fold(0.0, f64::max);
    let plan = TrackPlan {
        model: opts
            .model
            .as_ref()
            .map_or(opts.config_path.clone(), |(_, p)| p.clone()),
        scan: scan.clone(),
        period_ticks: n,
        harmonics: scan.k_max(),
        zero_bands: bands,
        harmonics_in_zero_bands: inside,
        harmonics_removed: removed,
        harmonics_not_learned: not_learned
            .iter()
            .map(|&k| (k, Harmonics::frequency_hz(k, scan.line_rate_hz)))
            .collect(),
        predicted_peak_current_a: peak_u,
        predicted_rms_current_a: rms_u,
        peak_reference_m: peak_r,
        predicted_feedback_rms_error_m: e_fb.rms(),
        learning_gain: g,
        model_contraction: contraction,
        feedforward_kind: opts.feedforward_kind,
        derivative_gains: gains,
        move_profile: scan.move_profile(),
        settle_band_m: is_move.then_some(settle_band_m),
        move_in_zero_bands_m: in_bands,
        smoother_move: slower,
        learning_filter: if measured_ps.is_some() {
            "measured"
        } else {
            "model"
        }
        .to_string(),
        learning_ps: measured_ps.and(opts.learning_ps.clone()),
        learning_checks: checks,
        convergence_margin: margin.map(|(m, _)| m),
        convergence_margin_at_hz: margin
            .map(|(_, k)| Harmonics::frequency_hz(k, scan.line_rate_hz)),
        slowest_time_constant_s: tau_s,
        warm_up_periods: warm_up,
    };
    check_limits(cfg, &plan)?;
    Ok((plan, r, f, learning))
}

/// The loop's slowest time constant on `model` (s; NaN for a loop the
/// check will refuse) and the warm-up lines it needs at `n` ticks a line
/// ([`WARM_UP_TIME_CONSTANTS`], [`WARM_UP_PERIODS`] at least).
fn warm_up_of(model: &ModelLoop<'_>, n: usize, rate_hz: f64) -> (f64, u64) {
    let (poles, stable) = crate::control::loop_check::closed_loop_poles(
        model.plant,
        model.ctrl,
        model.link_delay_periods,
    );
    let slowest = poles.iter().map(|z| z.norm()).fold(0.0, f64::max);
    let tau_ticks = -1.0 / slowest.ln();
    if !(stable && tau_ticks.is_finite() && tau_ticks > 0.0) {
        return (f64::NAN, WARM_UP_PERIODS);
    }
    let lines = (WARM_UP_TIME_CONSTANTS * tau_ticks / n as f64).ceil();
    (tau_ticks / rate_hz, (lines as u64).max(WARM_UP_PERIODS))
}

/// The feedforward trial's command predicted on the model,
/// `u = CS·r + S·f`: its peak and its RMS, A.
fn predicted_current(
    r: &Harmonics,
    f: &Harmonics,
    model: &ModelLoop<'_>,
    line_rate_hz: f64,
) -> (f64, f64) {
    let (u, _) = predict(r, f, model, line_rate_hz);
    let peak = u.synthesize().iter().fold(0.0f64, |m, v| m.max(v.abs()));
    (peak, u.rms())
}

/// The next learning trial's command, predicted from the last one's as
/// measured: `u_next = u_measured + S·(f_next − f_last)`, its peak and its
/// RMS, A. Only the change goes through the model, so a model that is off
/// (which the learning is there to correct) misjudges only the change,
/// not the whole current: on a bench whose feedforward needs 20 % more
/// current than the model says, the model alone would predict the command
/// 20 % low. `u_measured` is the last trial's mean command line (A).
fn predicted_next_current(
    u_measured: &[f64],
    df: &Harmonics,
    model: &ModelLoop<'_>,
    line_rate_hz: f64,
) -> (f64, f64) {
    let mut du = Harmonics::zeros(df.coef.len() - 1, df.period_ticks);
    for k in 1..df.coef.len() {
        du.coef[k] = model.sensitivity(Harmonics::frequency_hz(k, line_rate_hz)) * df.coef[k];
    }
    let u: Vec<f64> = u_measured
        .iter()
        .zip(du.synthesize())
        .map(|(a, b)| a + b)
        .collect();
    let peak = u.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    (peak, rms(&u))
}

/// Why a feedforward is refused by the current limits of the config, or
/// `None` (`peak_a`, `rms_a` predicted as `how` says).
fn beyond_current_limits(cfg: &BenchConfig, peak_a: f64, rms_a: f64, how: &str) -> Option<String> {
    let peak_limit = cfg.actuator.peak_current_a;
    let cont_limit = cfg.actuator.continuous_current_a;
    // A NaN prediction is beyond every limit.
    if peak_a.is_nan() || peak_a > peak_limit {
        Some(format!(
            "needs {peak_a:.2} A peak ({how}), above actuator.peak_current_a {peak_limit} A"
        ))
    } else if rms_a.is_nan() || rms_a > cont_limit {
        Some(format!(
            "needs {rms_a:.2} A RMS ({how}), above actuator.continuous_current_a {cont_limit} A (I²t)"
        ))
    } else {
        None
    }
}

/// The planned scan within the position limit and the current limits of
/// the config (the device's, if lower, are checked again by the
/// supervisor on the tick).
fn check_limits(cfg: &BenchConfig, p: &TrackPlan) -> Result<(), RunError> {
    // A CSV's amplitude is its own: the refusal names the file.
    let bad = |why: String| match &p.scan.reference_csv {
        Some(path) => RunError::option("reference", path.display(), why),
        None => RunError::option("amplitude_m", p.scan.amplitude_m, why),
    };
    let limit_m = cfg.safety.position_limit_m;
    if p.peak_reference_m >= limit_m {
        return Err(bad(format!(
            "the scan reaches {:.3e} m from the start, beyond safety.position_limit_m {limit_m} m",
            p.peak_reference_m
        )));
    }
    if let Some(why) = beyond_current_limits(
        cfg,
        p.predicted_peak_current_a,
        p.predicted_rms_current_a,
        "predicted on the model",
    ) {
        return Err(bad(format!(
            "the scan with its feedforward {why}: lower the amplitude or the line rate"
        )));
    }
    Ok(())
}

/// The paths of the outputs in `dir`: one recording per trial, the
/// feedforward table and the summary.
fn trial_path(dir: &Path, index: usize, name: &str) -> PathBuf {
    dir.join(format!("trial-{index:02}-{name}.mcap"))
}

/// The error (setpoint − reading) of a trial's measured ticks.
#[derive(Debug, Clone)]
pub struct MeasuredError {
    /// RMS over the measured ticks, m.
    pub rms_m: f64,
    /// 1σ of `rms_m` from the scatter of the lines' mean squares
    /// (`σ(MS)/(2·RMS)`, `σ(MS)` the standard error of the mean of the
    /// lines' mean squares), m; NaN with a single line.
    pub rms_sigma_m: f64,
    /// Largest |error|, m.
    pub peak_m: f64,
    /// The mean line: the error averaged line by line, `n` values, m.
    pub mean_line_m: Vec<f64>,
    /// The error of every measured tick, m.
    pub error_m: Vec<f64>,
}

/// The RMS of `x` (0 when empty).
fn rms(x: &[f64]) -> f64 {
    (x.iter().map(|v| v * v).sum::<f64>() / x.len().max(1) as f64).sqrt()
}

/// The error (setpoint − reading, m) of a trial's ticks after `warm_up`,
/// cut in lines of `n` ticks (a last partial line is left out of the mean
/// line and the σ, kept in the RMS and the peak).
pub fn measured_error(
    setpoint_m: &[f64],
    position_m: &[f64],
    n: usize,
    warm_up: usize,
) -> MeasuredError {
    let e: Vec<f64> = setpoint_m
        .iter()
        .zip(position_m)
        .skip(warm_up)
        .map(|(s, y)| s - y)
        .collect();
    let rms_m = rms(&e);
    let peak_m = e.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    let mean_line_m = mean_line(&e, n);
    let ms: Vec<f64> = e.chunks_exact(n.max(1)).map(|l| rms(l).powi(2)).collect();
    let rms_sigma_m = if ms.len() < 2 {
        f64::NAN
    } else {
        let k = ms.len() as f64;
        let mean = ms.iter().sum::<f64>() / k;
        let var = ms.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (k - 1.0);
        (var / k).sqrt() / (2.0 * rms_m.max(f64::MIN_POSITIVE))
    };
    MeasuredError {
        rms_m,
        rms_sigma_m,
        peak_m,
        mean_line_m,
        error_m: e,
    }
}

/// Highest frequency of the figure's error spectrum, Hz: 4× the reference's
/// cut-off or the highest zero band's upper edge, whichever is higher,
/// below the loop's Nyquist frequency and at most 1000 harmonics.
fn spectrum_top_hz(p: &TrackPlan, rate_hz: f64) -> f64 {
    let top = p
        .zero_bands
        .iter()
        .map(|b| b.high_hz)
        .fold(p.scan.cutoff_hz, f64::max);
    (4.0 * top)
        .min(0.5 * rate_hz)
        .min(1000.0 * p.scan.line_rate_hz)
}

/// `track.png` ([`write_track_png`]) of the trials so far; `lines` holds
/// the mean error line (m) of the trials drawn in full, by index.
fn write_figure(
    dir: &Path,
    s: &TrackSummary,
    rate_hz: f64,
    r_t: &[f64],
    lines: &[(usize, Vec<f64>)],
    existing: Existing,
) -> Result<(), RunError> {
    let path = dir.join("track.png");
    let n = r_t.len();
    let line_rate = s.plan.scan.line_rate_hz;
    let k_max = ((spectrum_top_hz(&s.plan, rate_hz) / line_rate) as usize).clamp(1, n / 2);
    let t_s: Vec<f64> = (0..n).map(|i| i as f64 / rate_hz).collect();
    let reference_um: Vec<f64> = r_t.iter().map(|v| v * 1e6).collect();
    let harmonic_hz: Vec<f64> = (1..=k_max).map(|k| k as f64 * line_rate).collect();
    let drawn: Vec<(usize, Vec<f64>, Vec<f64>)> = lines
        .iter()
        .map(|(i, e)| {
            let pos = r_t.iter().zip(e).map(|(r, e)| (r - e) * 1e6).collect();
            let h = Harmonics::analyze(e, k_max);
            let amp = h.coef[1..].iter().map(|c| c.norm() * 1e9).collect();
            (*i, pos, amp)
        })
        .collect();
    let trials = s
        .trials
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let d = drawn.iter().find(|d| d.0 == i);
            TrackTrialPlot {
                name: &t.name,
                rms_error_nm: t.rms_error_m * 1e9,
                rms_error_sigma_nm: t.rms_error_sigma_m * 1e9,
                position_um: d.map_or(&[][..], |d| &d.1),
                error_amplitude_nm: d.map_or(&[][..], |d| &d.2),
            }
        })
        .collect();
    let title = format!(
        "bench track --controller {}: {}",
        s.controller,
        s.plan.scan.describe()
    );
    let plot = TrackPlot {
        title: &title,
        t_s: &t_s,
        reference_um: &reference_um,
        harmonic_hz: &harmonic_hz,
        trials,
        noise_floor_nm: s.noise_floor_m * 1e9,
        noise_floor_of: if s.floor_is_quantization() {
            "the reading's quantisation q/√12"
        } else {
            "the standstill"
        },
        cutoff_hz: s.plan.scan.cutoff_hz,
        zero_bands: s
            .plan
            .zero_bands
            .iter()
            .map(|b| {
                (
                    format!("{} zero {:.1} Hz", b.kind, b.zero_hz),
                    b.low_hz,
                    b.high_hz,
                )
            })
            .collect(),
    };
    write_track_png(&path, existing, &plot).map_err(|e| RunError::Output {
        path,
        reason: e.to_string(),
    })
}

/// The mean of the whole lines of `n` values in `x`: `n` values (zeros
/// when `x` holds no whole line).
pub fn mean_line(x: &[f64], n: usize) -> Vec<f64> {
    let m = x.len() / n.max(1);
    (0..n)
        .map(|i| (0..m).map(|p| x[p * n + i]).sum::<f64>() / m.max(1) as f64)
        .collect()
}

/// The 1σ of each harmonic `0…k_max` of the mean of the whole lines of
/// `n` values in `e` (m): the scatter of the lines' own harmonics about
/// their mean, over √(lines) (NaN with fewer than two lines).
pub fn harmonic_sigma(e: &[f64], n: usize, k_max: usize) -> Vec<f64> {
    let lines: Vec<Harmonics> = e
        .chunks_exact(n.max(1))
        .map(|l| Harmonics::analyze(l, k_max))
        .collect();
    let m = lines.len();
    if m < 2 {
        return vec![f64::NAN; k_max + 1];
    }
    (0..=k_max)
        .map(|k| {
            let mean = lines.iter().map(|h| h.coef[k]).sum::<crate::ident::C64>() / m as f64;
            let var = lines
                .iter()
                .map(|h| (h.coef[k] - mean).norm_sqr())
                .sum::<f64>()
                / (m - 1) as f64;
            (var / m as f64).sqrt()
        })
        .collect()
}

/// The summary and the files of a run so far, written after every trial.
fn write_summary(dir: &Path, s: &TrackSummary, existing: Existing) -> Result<(), RunError> {
    let path = dir.join(TRACK_SUMMARY_FILE);
    let text = serde_json::to_string_pretty(s).map_err(|e| RunError::BadInput(e.to_string()))?;
    crate::outputs::write_atomically(&path, existing, |f| {
        std::io::Write::write_all(f, text.as_bytes())
    })
    .map_err(|e| RunError::Output {
        path,
        reason: e.to_string(),
    })
}

/// The best feedforward's period as a CSV table: tick in the line, time
/// (s), reference (m), feedforward (A); a comment line first with the
/// loop rate, the line rate and the controller it was learned with.
fn write_feedforward(
    path: &Path,
    opts: &TrackOptions,
    scan: &Scan,
    reference_m: &[f64],
    feedforward_a: &[f64],
    existing: Existing,
) -> Result<(), RunError> {
    let rate = opts.config.loop_.rate_hz;
    crate::outputs::write_buffered_atomically(path, existing, |w| {
        use std::io::Write;
        writeln!(
            w,
            "# bench track feedforward: loop.rate_hz {rate}, line_rate_hz {}, controller {}, config {}",
            opts.scan.line_rate_hz,
            opts.controller,
            opts.config_path.display()
        )?;
        writeln!(w, "# {}", FeedforwardIdentity::of(opts, scan, reference_m.len()).to_json())?;
        writeln!(w, "tick,time_s,reference_m,feedforward_a")?;
        for (i, (r, f)) in reference_m.iter().zip(feedforward_a).enumerate() {
            writeln!(w, "{i},{:.9},{r:e},{f:e}", i as f64 / rate)?;
        }
        Ok(())
    })
    .map_err(|e| RunError::Output {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })
}

/// What a feedforward table was learned for: the loop, the amplifier, the
/// controller and the scan's line. A table is replayed only where all
/// match ([`read_feedforward`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct FeedforwardIdentity {
    rate_hz: f64,
    line_rate_hz: f64,
    period_ticks: usize,
    scan: Scan,
    controller: String,
    controller_table: crate::control::ControllerConfig,
    actuator: bench_plant::sim::ActuatorParams,
}

impl FeedforwardIdentity {
    /// A CSV's line is not part of the identity (as in the plan's JSON):
    /// the table's reference column is checked tick by tick.
    fn of(opts: &TrackOptions, scan: &Scan, period_ticks: usize) -> Self {
        Self {
            rate_hz: opts.config.loop_.rate_hz,
            line_rate_hz: opts.scan.line_rate_hz,
            period_ticks,
            scan: Scan {
                reference: None,
                ..scan.clone()
            },
            controller: opts.controller.clone(),
            controller_table: opts.config.controller[&opts.controller].clone(),
            actuator: opts.config.actuator,
        }
    }

    fn to_json(&self) -> String {
        serde_json::to_string(self).unwrap_or_default()
    }

    /// What differs from `other` (this run's), for the refusal.
    fn differences(&self, other: &Self) -> Vec<String> {
        let mut d = Vec::new();
        if self.rate_hz != other.rate_hz {
            d.push(format!(
                "loop.rate_hz {} (this run: {})",
                self.rate_hz, other.rate_hz
            ));
        }
        if self.line_rate_hz != other.line_rate_hz || self.period_ticks != other.period_ticks {
            d.push(format!(
                "a line of {} Hz, {} ticks (this run: {} Hz, {} ticks)",
                self.line_rate_hz, self.period_ticks, other.line_rate_hz, other.period_ticks
            ));
        }
        if self.scan != other.scan {
            let s = |x: &Scan| {
                format!(
                    "a {:?} scan of {:e} m cut off at {:.3} Hz",
                    x.kind, x.amplitude_m, x.cutoff_hz
                )
            };
            d.push(format!("{} (this run: {})", s(&self.scan), s(&other.scan)));
        }
        if self.controller != other.controller || self.controller_table != other.controller_table {
            d.push(format!(
                "[controller.{}] as it was then (this run: [controller.{}] as it is now)",
                self.controller, other.controller
            ));
        }
        if self.actuator != other.actuator {
            d.push("another [actuator]".to_string());
        }
        d
    }
}

/// Reads a `feedforward.csv` for this run: its identity must match the
/// run's loop, amplifier, controller and line, and its reference column
/// the planned reference (within 1e-9 of the amplitude); returns the
/// feedforward column, A.
///
/// # Errors
/// [`RunError::BadOption`] naming `feedforward`: unreadable, not such a
/// table, or learned for another loop, controller, line or scan.
fn read_feedforward(
    path: &Path,
    opts: &TrackOptions,
    scan: &Scan,
    reference_m: &[f64],
) -> Result<Vec<f64>, RunError> {
    let bad = |why: String| RunError::option("feedforward", path.display(), why);
    let text = crate::input_file::read_to_string(
        path,
        crate::input_file::Kind::Feedforward,
        "feedforward",
    )?;
    let mut lines = text.lines();
    let id: FeedforwardIdentity = lines
        .nth(1)
        .and_then(|l| l.strip_prefix("# "))
        .and_then(|l| serde_json::from_str(l).ok())
        .ok_or_else(|| bad("not a feedforward table of bench track (its second line names what it was learned for)".into()))?;
    let here = FeedforwardIdentity::of(opts, scan, reference_m.len());
    let diff = id.differences(&here);
    if !diff.is_empty() {
        return Err(bad(format!("was learned with {}", diff.join(", "))));
    }
    if lines.next() != Some("tick,time_s,reference_m,feedforward_a") {
        return Err(bad(
            "its third line is not the header tick,time_s,reference_m,feedforward_a".into(),
        ));
    }
    let mut ff = Vec::with_capacity(reference_m.len());
    for (i, line) in lines.enumerate() {
        let cols: Vec<&str> = line.split(',').collect();
        let parsed = (cols.len() == 4).then(|| {
            (
                cols[0].parse::<usize>(),
                cols[2].parse::<f64>(),
                cols[3].parse::<f64>(),
            )
        });
        let Some((Ok(tick), Ok(r), Ok(f))) = parsed else {
            return Err(bad(format!(
                "line {}: not tick,time_s,reference_m,feedforward_a",
                i + 4
            )));
        };
        if tick != i || i >= reference_m.len() || !f.is_finite() {
            return Err(bad(format!("line {}: tick {tick} out of order, beyond the line, or a feedforward that is not finite", i + 4)));
        }
        if (r - reference_m[i]).abs() > 1e-9 * opts.scan.amplitude_m.abs().max(1e-12) {
            return Err(bad(format!(
                "was learned for another scan: its reference at tick {i} is {r:e} m, this run's {:e} m",
                reference_m[i]
            )));
        }
        ff.push(f);
    }
    if ff.len() != reference_m.len() {
        return Err(bad(format!(
            "holds {} ticks of a line of {}",
            ff.len(),
            reference_m.len()
        )));
    }
    Ok(ff)
}

/// The header of a reference table (`bench track --scan csv
/// --reference`): one row per tick of one line, `time_s` the tick's time
/// from the line's start (`i / loop.rate_hz`), `position_m` the reference
/// about the start position.
pub const REFERENCE_CSV_HEADER: &str = "time_s,position_m";

/// Reads the reference line of `--scan csv --reference FILE` at the loop
/// rate of `cfg`: the header [`REFERENCE_CSV_HEADER`] (after any `#`
/// comment lines), then one row per tick, its time `i / loop.rate_hz`
/// within 0.1 % of a period. Returns the positions (m) and the line rate
/// they make, `loop.rate_hz / rows` (Hz). The plan judges the rest: the
/// line's length and fundamental, the position and current limits.
///
/// # Errors
/// [`RunError::BadOption`] naming `reference`: unreadable, another
/// header, a row that is not two numbers, a time off the loop's ticks, a
/// position that is not finite, fewer than 8 rows, or a line that never
/// leaves the start position.
pub fn read_reference(path: &Path, cfg: &BenchConfig) -> Result<(Vec<f64>, f64), RunError> {
    let bad = |why: String| RunError::option("reference", path.display(), why);
    let text =
        crate::input_file::read_to_string(path, crate::input_file::Kind::Reference, "reference")?;
    let rate = cfg.loop_.rate_hz;
    let period_s = 1.0 / rate;
    let mut rows = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.starts_with('#'));
    match rows.next() {
        Some((_, h)) if h.trim_end() == REFERENCE_CSV_HEADER => {}
        _ => {
            return Err(bad(format!(
                "its first line (after # comments) is not the header {REFERENCE_CSV_HEADER}"
            )))
        }
    }
    let mut x = Vec::new();
    for (i, (line_no, l)) in rows.enumerate() {
        let at = line_no + 1;
        let cols: Vec<&str> = l.trim_end().split(',').collect();
        let parsed = (cols.len() == 2).then(|| (cols[0].parse::<f64>(), cols[1].parse::<f64>()));
        let Some((Ok(t), Ok(p))) = parsed else {
            return Err(bad(format!("line {at}: not time_s,position_m")));
        };
        if !t.is_finite() || (t - i as f64 * period_s).abs() > 1e-3 * period_s {
            return Err(bad(format!(
                "line {at}: time {t} s is not tick {i} of loop.rate_hz {rate} ({:.9} s): one row per tick from 0",
                i as f64 * period_s
            )));
        }
        if !p.is_finite() {
            return Err(bad(format!("line {at}: position {p} is not a length")));
        }
        x.push(p);
    }
    if x.len() < 8 {
        return Err(bad(format!(
            "{} rows: a line needs at least 8 ticks",
            x.len()
        )));
    }
    if x.iter().all(|&p| p == 0.0) {
        return Err(bad("every position is 0: the line never moves".to_string()));
    }
    let line_rate_hz = rate / x.len() as f64;
    Ok((x, line_rate_hz))
}

/// Reads the measured PS of `--learning-ps` for this run: a `bench
/// control --verify` recording ([`crate::jobs::verify::read_verify`]) of
/// the same loop: the same controller (name and table), loop rate,
/// amplifier, bench (`[plant]` of the config) and kind of backend (sim,
/// serial, socketcan, ethercat).
///
/// # Errors
/// [`RunError::BadOption`] naming `learning_ps`: unreadable, not such a
/// recording, or measured on another loop (what differs named).
fn read_learning_ps(
    path: &Path,
    opts: &TrackOptions,
    backend: &BackendSpec,
) -> Result<MeasuredPs, RunError> {
    let bad = |why: String| RunError::option("learning_ps", path.display(), why);
    let bytes = crate::input_file::read(path, crate::input_file::Kind::Recording, "learning_ps")?;
    let rec = crate::jobs::verify::read_verify(&bytes).map_err(bad)?;
    let then = BenchConfig::from_toml(&rec.config_toml, path)
        .map_err(|e| bad(format!("its recorded config does not load: {e}")))?;
    let cfg = &opts.config;
    let mut d = Vec::new();
    if then.loop_.rate_hz != cfg.loop_.rate_hz {
        d.push(format!(
            "loop.rate_hz {} (this run: {})",
            then.loop_.rate_hz, cfg.loop_.rate_hz
        ));
    }
    let table = |c: &BenchConfig, name: &str| c.controller.get(name).cloned();
    if rec.controller != opts.controller
        || table(&then, &rec.controller) != table(cfg, &opts.controller)
    {
        d.push(format!(
            "[controller.{}] as it was then (this run: [controller.{}] as it is now)",
            rec.controller, opts.controller
        ));
    }
    if then.actuator != cfg.actuator {
        d.push("another [actuator]".to_string());
    }
    if then.plant != cfg.plant {
        d.push("another bench ([plant] of its config)".to_string());
    }
    // The kind of device (sim, serial, socketcan, ethercat): a simulated
    // loop's PS is the model's, not the bench's, and the links differ in
    // delay.
    let kind = |name: &str| name.split(':').next().unwrap_or_default().to_string();
    let here = kind(&backend.to_string());
    match rec.backend.as_deref().map(kind) {
        Some(there) if there == here => {}
        there => d.push(format!(
            "the backend {} (this run: {here})",
            there.as_deref().unwrap_or("not recorded")
        )),
    }
    if !d.is_empty() {
        return Err(bad(format!(
            "its PS was measured with {}: a learning filter must come from the loop it learns on",
            d.join(", ")
        )));
    }
    if !rec.ps.counts.iter().any(|&c| c) {
        return Err(bad(
            "no line of its PS is coherent (γ² ≥ 0.5): nothing to learn from".to_string(),
        ));
    }
    Ok(rec.ps)
}

/// The outputs of a run of at most `trials` learning trials, checked
/// together before anything is enabled.
fn outputs(opts: &TrackOptions) -> Result<Vec<PathBuf>, RunError> {
    let dir = &opts.out_dir;
    std::fs::create_dir_all(dir)
        .map_err(|e| RunError::option("out", dir.display(), format!("cannot create it: {e}")))?;
    let names = [
        "standstill".to_string(),
        "feedback".into(),
        if opts.feedforward.is_some() {
            "replayed".into()
        } else {
            "feedforward".into()
        },
    ]
    .into_iter()
    .chain((1..=opts.trials).map(|j| format!("learning-{j}")));
    let recordings: Vec<PathBuf> = names
        .enumerate()
        .map(|(i, n)| trial_path(dir, i, &n))
        .collect();
    let mut plan = OutputPlan::new(Existing::overwrite(opts.overwrite));
    for r in &recordings {
        plan = plan.with_recording(r, Origin::Derived);
    }
    plan = plan
        .with_output("out", &dir.join(TRACK_SUMMARY_FILE), Origin::Derived)
        .with_output("out", &dir.join("feedforward.csv"), Origin::Derived)
        .with_output("out", &dir.join("track.png"), Origin::Derived)
        .with_input("config", &opts.config_path);
    if let Some(p) = &opts.feedforward {
        plan = plan.with_input("feedforward", p);
    }
    if let Some((_, p)) = &opts.model {
        plan = plan.with_input("model", p);
    }
    if let Some(p) = &opts.learning_ps {
        plan = plan.with_input("learning_ps", p);
    }
    plan.check()?;
    Ok(recordings)
}

/// What every trial of a run shares.
struct Trials<'a> {
    opts: &'a TrackOptions,
    ctrl: DiscreteController,
    /// The model the learned feedforward's current is predicted on.
    model: &'a ModelLoop<'a>,
    recordings: &'a [PathBuf],
    stop: &'a Arc<AtomicBool>,
    stall: StallBounds,
    stall_source: &'a str,
    /// The learned harmonics' count `K`.
    k_max: usize,
    /// Lines run before the measured ones.
    warm_up_periods: u64,
    /// The trials done, for the daemon's progress.
    progress: Option<&'a Arc<AtomicU64>>,
}

/// What a trial measured, beside its report.
struct Outcome {
    report: TrialReport,
    /// The mean line of the error, m.
    error_line_m: Vec<f64>,
    /// The 1σ of each harmonic `0…K` of that mean line, m
    /// ([`harmonic_sigma`]).
    error_sigma_m: Vec<f64>,
    /// The mean line of the command, A.
    command_line_a: Vec<f64>,
}

impl Trials<'_> {
    /// Runs trial `index` on `runner` and measures its error and command.
    fn run(
        &self,
        runner: &mut Runner<'_>,
        index: usize,
        name: &str,
        reference_m: &[f64],
        feedforward_a: &[f64],
    ) -> Result<Outcome, RunError> {
        let opts = self.opts;
        let recording = &self.recordings[index];
        let n = reference_m.len();
        let warm_up = self.warm_up_periods * n as u64;
        let lines = self.warm_up_periods + u64::from(opts.periods);
        let job = TrackJob::new(
            self.ctrl,
            reference_m.to_vec(),
            feedforward_a.to_vec(),
            lines,
        );
        let total = job.total_ticks();
        let measured_end = (lines * n as u64) as usize;
        let cfg = &opts.config;
        let info = runner.info().clone();
        let spec = BackendSpec::resolve(opts.backend.as_ref(), cfg);
        let session = SessionOptions {
            command: "track",
            config_path: &opts.config_path,
            out: recording,
            realtime: opts.realtime || !spec.is_sim(),
            pace: opts.pace,
            progress: false,
            seed: opts.seed,
            max_ticks: total,
            keep: Kept::STEP,
            ticks: None,
            stall: Some(self.stall),
            stall_source: self.stall_source,
        };
        let mut plan = OutputPlan::new(Existing::overwrite(opts.overwrite))
            .with_recording(recording, Origin::Derived);
        let recorder = open_recording(&session, cfg, &info, &mut plan)?;
        let recorded = run_recorded(runner, job, cfg, recorder, &session, Arc::clone(self.stop))?;
        let data = &recorded.data;
        let setpoint = &data.setpoint_m[..measured_end.min(data.setpoint_m.len())];
        let position = &data.position_m[..measured_end.min(data.position_m.len())];
        let measured = measured_error(setpoint, position, n, warm_up as usize);
        let error_sigma_m = harmonic_sigma(&measured.error_m, n, self.k_max);
        let end = measured_end.min(data.current_command_a.len());
        let measured_u = &data.current_command_a[(warm_up as usize).min(end)..end];
        let command = mean_line(measured_u, n);
        let command_rms_a = rms(measured_u);
        let ff_rms = rms(feedforward_a);
        let rate_hz = cfg.loop_.rate_hz;
        let settled = (opts.scan.kind == ScanKind::Move && name != "standstill").then(|| {
            let move_ticks = opts
                .scan
                .move_profile()
                .map_or(0, |p| (p.duration_s() * rate_hz).ceil() as usize);
            settle(
                &measured.error_m,
                n,
                &[0, n / 2],
                move_ticks,
                rate_hz,
                opts.settle_band_m,
            )
        });
        let mut recorder = recorded.recorder;
        let report = TrialReport {
            name: name.to_string(),
            rms_error_m: measured.rms_m,
            rms_error_sigma_m: measured.rms_sigma_m,
            peak_error_m: measured.peak_m,
            of_noise_floor: f64::NAN,
            of_noise_floor_sigma: f64::NAN,
            feedforward_rms_a: ff_rms,
            command_rms_a,
            predicted_command_rms_a: None,
            settle_time_s: settled.and_then(|s| s.time_s),
            settle_noise_sigma_m: settled.map(|s| s.noise_sigma_m),
            settle_trusted: settled.map(|s| s.trusted(opts.settle_band_m)),
            recording: recording.clone(),
        };
        let ch = recorder.add_channel_for::<TrialReport>("/track/trial", "bench.TrackTrial")?;
        recorder.write(ch, recorded.end_ns, &report)?;
        finish(recorder)?;
        if let Some(p) = self.progress {
            p.store(index as u64 + 1, std::sync::atomic::Ordering::Relaxed);
        }
        Ok(Outcome {
            report,
            error_line_m: measured.mean_line_m,
            error_sigma_m,
            command_line_a: command,
        })
    }

    /// The trials in order (module docs), the summary written after each.
    fn learn(
        &self,
        runner: &mut Runner<'_>,
        r: &Harmonics,
        (f_model, start_name): (Harmonics, &str),
        learning: &Learning,
        summary: &mut TrackSummary,
    ) -> Result<(), RunError> {
        let n = r.period_ticks;
        let r_t = summary.plan.scan.table(n);
        let still = vec![0.0; n];
        let t = self.run(runner, 0, "standstill", &still, &still)?.report;
        summary.set_noise_floor(&t);
        summary.push(t);
        let mut lines = Vec::new();
        let first = Existing::overwrite(self.opts.overwrite);
        self.report(summary, &r_t, &lines, first)?;
        // From here on the summary and the figure replace the run's own.
        let o = self.run(runner, 1, "feedback", &r_t, &still)?;
        summary.push(o.report);
        lines.push((1, o.error_line_m));
        self.report(summary, &r_t, &lines, Existing::Replace)?;
        let mut f = f_model;
        let mut f_t = f.synthesize();
        let line_rate = summary.plan.scan.line_rate_hz;
        let mut last = self.run(runner, 2, start_name, &r_t, &f_t)?;
        let mut t = last.report.clone();
        t.predicted_command_rms_a = Some(predicted_current(r, &f, self.model, line_rate).1);
        let mut best = (t.rms_error_m, t.name.clone(), f_t.clone());
        let fb = &summary.trials[1];
        if let (Some(a), Some(b), Some(true), Some(true)) = (
            fb.settle_time_s,
            t.settle_time_s,
            fb.settle_trusted,
            t.settle_trusted,
        ) {
            // A move lasts 2 ticks at least (`check_move`): b > 0.
            summary.settle_speedup = Some(a / b);
        }
        let mut errors = vec![(t.rms_error_m, t.rms_error_sigma_m)];
        summary.push(t);
        lines.push((2, last.error_line_m.clone()));
        self.report(summary, &r_t, &lines, Existing::Replace)?;
        let budget = self.opts.trials as usize;
        let mut why = stop_rule(&errors, summary.noise_floor_m, budget + 1);
        let mut j = 0;
        let mut why_limit = None;
        let mut e = Harmonics::analyze(&last.error_line_m, self.k_max);
        while why.is_none() {
            j += 1;
            let next = learning.update_significant(&f, &e, &last.error_sigma_m);
            let mut df = next.clone();
            for (d, c) in df.coef.iter_mut().zip(&f.coef) {
                *d -= c;
            }
            let (peak_a, rms_a) =
                predicted_next_current(&last.command_line_a, &df, self.model, line_rate);
            if let Some(why) = beyond_current_limits(
                &self.opts.config,
                peak_a,
                rms_a,
                "predicted from the last trial's measured command",
            ) {
                tracing::warn!("learning stops before trial {j}: its feedforward {why}");
                why_limit = Some("limit");
                break;
            }
            f = next;
            f_t = f.synthesize();
            let name = format!("learning-{j}");
            last = match self.run(runner, 2 + j, &name, &r_t, &f_t) {
                Ok(r) => r,
                Err(e) => {
                    // The learning so far is kept; the fault is the run's end.
                    self.keep_best(summary, &r_t, best, Some("fault"))?;
                    return Err(e);
                }
            };
            let mut t = last.report.clone();
            t.predicted_command_rms_a = Some(rms_a);
            e = Harmonics::analyze(&last.error_line_m, self.k_max);
            if t.rms_error_m < best.0 {
                best = (t.rms_error_m, name, f_t.clone());
            }
            errors.push((t.rms_error_m, t.rms_error_sigma_m));
            summary.push(t);
            // Feedback, the first feedforward and the latest learning trial.
            lines.truncate(2);
            lines.push((2 + j, last.error_line_m.clone()));
            why = stop_rule(&errors, summary.noise_floor_m, budget + 1);
            self.report(summary, &r_t, &lines, Existing::Replace)?;
        }
        self.keep_best(summary, &r_t, best, why.or(why_limit))
    }

    /// Ends the learning: the best trial's feedforward written as
    /// `feedforward.csv` and the summary with why it stopped.
    fn keep_best(
        &self,
        summary: &mut TrackSummary,
        r_t: &[f64],
        best: (f64, String, Vec<f64>),
        why: Option<&str>,
    ) -> Result<(), RunError> {
        let dir = &self.opts.out_dir;
        let csv = dir.join("feedforward.csv");
        let scan = summary.plan.scan.clone();
        write_feedforward(
            &csv,
            self.opts,
            &scan,
            r_t,
            &best.2,
            Existing::overwrite(self.opts.overwrite),
        )?;
        summary.stop = why.map(str::to_string);
        let fb = &summary.trials[1];
        let best_sigma = summary
            .trials
            .iter()
            .find(|t| t.name == best.1)
            .map_or(f64::NAN, |t| t.rms_error_sigma_m);
        let (imp, imp_sigma) = ratio((fb.rms_error_m, fb.rms_error_sigma_m), (best.0, best_sigma));
        summary.improvement = Some(imp);
        summary.improvement_sigma = Some(imp_sigma);
        summary.best_trial = Some(best.1);
        summary.feedforward_csv = Some(csv);
        write_summary(dir, summary, Existing::Replace)
    }

    /// Writes the summary (`track.json`) and the figure (`track.png`) of
    /// the trials so far; `lines` as for [`write_figure`].
    fn report(
        &self,
        summary: &TrackSummary,
        r_t: &[f64],
        lines: &[(usize, Vec<f64>)],
        existing: Existing,
    ) -> Result<(), RunError> {
        let dir = &self.opts.out_dir;
        write_summary(dir, summary, existing)?;
        let rate_hz = self.opts.config.loop_.rate_hz;
        write_figure(dir, summary, rate_hz, r_t, lines, existing)
    }
}

impl TrackSummary {
    /// Sets the noise floor from the standstill trial `t`: its RMS error
    /// with its 1σ, or the quantisation floor with 0 when that is larger
    /// ([`Self::quantization_floor_m`]).
    fn set_noise_floor(&mut self, t: &TrialReport) {
        (self.noise_floor_m, self.noise_floor_sigma_m) =
            if t.rms_error_m >= self.quantization_floor_m {
                (t.rms_error_m, t.rms_error_sigma_m)
            } else {
                (self.quantization_floor_m, 0.0)
            };
    }

    /// Whether the noise floor is the reading's quantisation floor (larger
    /// than the standstill's RMS error), not the standstill's.
    pub fn floor_is_quantization(&self) -> bool {
        self.trials
            .first()
            .is_some_and(|t| t.rms_error_m < self.noise_floor_m)
    }

    /// Adds a trial, its error relative to the noise floor set. The
    /// standstill trial that is the floor is 1, with its own relative 1σ.
    fn push(&mut self, mut t: TrialReport) {
        let floor = (self.noise_floor_m, self.noise_floor_sigma_m);
        let (of, sigma) = ratio((t.rms_error_m, t.rms_error_sigma_m), floor);
        t.of_noise_floor = of;
        t.of_noise_floor_sigma = if self.trials.is_empty() && t.rms_error_m == floor.0 {
            t.rms_error_sigma_m / t.rms_error_m
        } else {
            sigma
        };
        self.trials.push(t);
    }
}

/// `a/b` and its 1σ from `a`'s and `b`'s (value, 1σ), to first order:
/// `σ = (a/b)·√((σa/a)² + (σb/b)²)`, written `√((σa/b)² + (a·σb/b²)²)`
/// so that `a = 0` (a standstill on one code) has the 1σ `σa/b`.
pub fn ratio(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
    let r = a.0 / b.0;
    (r, ((a.1 / b.0).powi(2) + (r * b.1 / b.0).powi(2)).sqrt())
}

/// Why learning stops after `rms` (the learning trials' RMS errors so far,
/// each `(value, 1σ)`, m; the first the feedforward trial's), or `None` to
/// go on: `converged` within [`CONVERGED_OF_NOISE_FLOOR`] of the noise
/// floor, `diverged` when the error grew two trials in a row, `budget`
/// after `budget` trials. A growth counts when it exceeds 2σ of the
/// difference, `2·√(σ_a² + σ_b²)` (a 1σ that is not finite, one measured
/// line, counts as 0): a plateau whose RMS wanders within its noise is not
/// a divergence (a spurious stop: 68.09 → 68.23 → 68.33 nm, each ±1.3–3.3
/// nm, ended a run on a plateau at 1.51× the floor).
pub fn stop_rule(rms: &[(f64, f64)], noise_floor_m: f64, budget: usize) -> Option<&'static str> {
    let last = rms.last()?.0;
    if last <= CONVERGED_OF_NOISE_FLOOR * noise_floor_m {
        return Some("converged");
    }
    let grew = |a: (f64, f64), b: (f64, f64)| {
        let s = |x: f64| if x.is_finite() { x } else { 0.0 };
        b.0 - a.0 > 2.0 * s(a.1).hypot(s(b.1))
    };
    let n = rms.len();
    if n >= 3 && grew(rms[n - 2], rms[n - 1]) && grew(rms[n - 3], rms[n - 2]) {
        return Some("diverged");
    }
    (n >= budget).then_some("budget")
}

/// Warns of what the plan keeps that no loop tracks: a scan's harmonics
/// in a zero's band, a move's content in the right-half-plane bands.
fn warn_plan(plan: &TrackPlan) {
    let inside = &plan.harmonics_in_zero_bands;
    if let (ScanKind::Csv, Some(first), Some(last)) =
        (plan.scan.kind, inside.first(), inside.last())
    {
        tracing::warn!(
            "{} harmonics of the reference ({:.1}–{:.1} Hz) lie in the bands the plant's right-half-plane zeros close: no loop tracks them, only the feedforward, as well as the model is right there; smooth the reference below {:.1} Hz to remove them",
            inside.len(),
            first.1,
            last.1,
            plan.zero_bands.iter().find(|b| b.right_half_plane()).map_or(f64::NAN, |b| b.low_hz)
        );
    }
    for (k, f_hz) in inside {
        if plan.scan.played_whole() {
            // A move's content there is warned about as a whole (below), a
            // CSV's above.
            break;
        }
        tracing::warn!(
            "harmonic {k} of the scan ({f_hz:.1} Hz) lies in a band the plant's zeros close: no loop tracks it, and its feedforward costs current; the default smoothing (no --cutoff-hz) removes it"
        );
    }
    if let (Some(c), Some(band)) = (plan.move_in_zero_bands_m, plan.settle_band_m) {
        if c > band {
            let offer = plan.smoother_move.map_or(
                "no slower move that still fits the line removes it: lower the line rate"
                    .to_string(),
                |l| {
                    let d = MoveProfile::plan(plan.scan.amplitude_m, &l).duration_s();
                    format!(
                        "{} (a move of {:.2} ms) brings it within the band",
                        l.flags(),
                        d * 1e3
                    )
                },
            );
            tracing::warn!(
                "the move puts {:.1} nm of its reference in the bands the plant's right-half-plane zeros close, above the settle band ±{:.1} nm: no loop tracks it, only the feedforward, as well as the model is right there; {offer}",
                c * 1e9,
                band * 1e9
            );
        }
    }
}

/// The feedforward the first feedforward trial plays and its name: the
/// replayed table of `--feedforward` (checked against the current limits
/// on the model), else the model's.
fn start_feedforward(
    opts: &TrackOptions,
    plan: &TrackPlan,
    r: &Harmonics,
    f_model: Harmonics,
    model_loop: &ModelLoop<'_>,
) -> Result<(Harmonics, &'static str), RunError> {
    let Some(p) = &opts.feedforward else {
        return Ok((f_model, "feedforward"));
    };
    let table = read_feedforward(p, opts, &plan.scan, &plan.scan.table(r.period_ticks))?;
    let mut f = Harmonics::analyze(&table, r.coef.len() - 1);
    // The loop's integrator holds the mean: no feedforward has one.
    f.coef[0] = crate::ident::C64::new(0.0, 0.0);
    let (peak, rms) = predicted_current(r, &f, model_loop, plan.scan.line_rate_hz);
    if let Some(why) = beyond_current_limits(&opts.config, peak, rms, "predicted on the model") {
        return Err(RunError::option(
            "feedforward",
            p.display(),
            format!("the scan with this feedforward {why}; nothing was enabled"),
        ));
    }
    Ok((f, "replayed"))
}

/// Runs `bench track` (module docs).
///
/// # Errors
/// [`RunError::BadOption`] naming the option for a scan the plan refuses,
/// an unusable output; [`RunError::BadInput`] for an unknown controller;
/// the errors of [`run_recorded`] for a trial that faults (its recording
/// and every earlier one finished, `track.json` holding the trials before).
pub fn run_track(opts: &TrackOptions, stop: Arc<AtomicBool>) -> Result<TrackSummary, RunError> {
    run_track_from(opts, stop, StageSource::Open, None)
}

/// [`run_track`] on a stage from `source` (the daemon's loop: its stage
/// stays with it and holds 0 A between the trials); `progress`, if given,
/// counts the trials done.
///
/// # Errors
/// As [`run_track`].
pub fn run_track_from(
    opts: &TrackOptions,
    stop: Arc<AtomicBool>,
    source: StageSource<'_>,
    progress: Option<&Arc<AtomicU64>>,
) -> Result<TrackSummary, RunError> {
    let cfg = &opts.config;
    let ccfg = cfg.controller.get(&opts.controller).ok_or_else(|| {
        RunError::option(
            "controller",
            &opts.controller,
            "no [controller.NAME] of that name in the config".to_string(),
        )
    })?;
    if !(1..=100).contains(&opts.trials) {
        return Err(RunError::option(
            "trials",
            opts.trials,
            "must be 1 to 100".to_string(),
        ));
    }
    if !(1..=1000).contains(&opts.periods) {
        return Err(RunError::option(
            "periods",
            opts.periods,
            "must be 1 to 1000".to_string(),
        ));
    }
    let (plant_params, model_path) = opts
        .model
        .as_ref()
        .map_or((cfg.plant, &opts.config_path), |(c, p)| (c.plant, p));
    let model = Sr4dof::new(plant_params)
        .map_err(|e| RunError::BadInput(format!("config {}: {e}", model_path.display())))?;
    let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
    let spec = BackendSpec::resolve(opts.backend.as_ref(), cfg);
    let ctrl = DiscreteController::new(ccfg, period_s, cfg.actuator.peak_current_a);
    let plant = ZohPlant::new(&model, &cfg.actuator, period_s);
    let model_loop = ModelLoop {
        plant: &plant,
        ctrl: &ctrl,
        link_delay_periods: spec.process_data_delay_periods(),
    };
    let bands = ZeroBand::of(&crate::analysis::modal::damped_zeros(&model));
    let measured_ps = match &opts.learning_ps {
        Some(p) => Some(read_learning_ps(p, opts, &spec)?),
        None => None,
    };
    let (plan, r, f_model, learning) = plan(opts, &model_loop, bands, measured_ps.as_ref())?;
    let (f_start, start_name) = start_feedforward(opts, &plan, &r, f_model, &model_loop)?;
    let total = (plan.warm_up_periods + u64::from(opts.periods) + 2) * plan.period_ticks as u64;
    if total > crate::config::ranges::JOB_TICKS_MAX {
        return Err(RunError::option(
            "periods",
            opts.periods,
            format!("a trial of {total} ticks is longer than a job may be"),
        ));
    }
    warn_plan(&plan);
    // The loop on the model first: an unstable or marginal loop never runs.
    let check = check_loop(
        cfg,
        &model,
        &opts.controller,
        &ctrl,
        period_s,
        None,
        plan.peak_reference_m,
        spec.process_data_delay_periods(),
    );
    if !check.passed() {
        return Err(RunError::Refused(format!(
            "loop check refused controller {}: {}; nothing was enabled",
            opts.controller,
            check.failures.join("; ")
        )));
    }
    let recordings = outputs(opts)?;
    let mut stage = source.stage(
        &spec,
        cfg,
        &opts.config_path,
        opts.seed,
        opts.inject_fault,
        check.stall.bound_s,
    )?;
    let mut runner = stage.runner();
    let info = runner.info().clone();
    let ctrl = ctrl.with_limit(cfg.current_limits(&info).peak_current_a);
    let mut summary = TrackSummary {
        controller: opts.controller.clone(),
        backend: info.name.clone(),
        seed: opts.seed,
        plan,
        noise_floor_m: f64::NAN,
        noise_floor_sigma_m: f64::NAN,
        quantization_floor_m: cfg.probe.quantization_m.max(info.probe_lsb_m) / 12f64.sqrt(),
        trials: Vec::new(),
        stop: None,
        best_trial: None,
        improvement: None,
        improvement_sigma: None,
        feedforward_csv: None,
        settle_speedup: None,
    };
    let period_s_stall = StallBounds::of(check.stall.bound_s, period_s);
    let run = Trials {
        opts,
        ctrl,
        model: &model_loop,
        recordings: &recordings,
        stop: &stop,
        stall: period_s_stall,
        stall_source: &check.stall.source,
        k_max: learning.l.len() - 1,
        warm_up_periods: summary.plan.warm_up_periods,
        progress,
    };
    run.learn(
        &mut runner,
        &r,
        (f_start, start_name),
        &learning,
        &mut summary,
    )?;
    Ok(summary)
}

/// `trajectory.KEY of CONFIG` when `KEY` is among the fields the config's
/// `[trajectory]` gave (`filled`), else `field(KEY)`: how an error names
/// an option ([`crate::jobs::track_request::TrackRequest::name_of`], [`TrackOptions::name_of`]).
pub fn trajectory_name(
    filled: &[&'static str],
    config_path: &Path,
    key: &str,
    field: impl FnOnce(&str) -> String,
) -> String {
    if filled.contains(&key) {
        format!("trajectory.{key} of {}", config_path.display())
    } else {
        field(key)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The stop rule on the RMS errors of bench 0 of the five-bench run
    /// (50 lines, α 0.4): a plateau at 1.51× the floor whose RMS wanders
    /// within its 1σ runs to the budget, not to `diverged`; growth beyond
    /// 2σ twice is `diverged`, as is any growth with one measured line (no
    /// σ); once is not; within 1.5× the floor is `converged`.
    #[test]
    fn only_a_growth_beyond_the_noise_is_a_divergence() {
        let nm = |v: &[(f64, f64)]| -> Vec<(f64, f64)> {
            v.iter().map(|(a, s)| (a * 1e-9, s * 1e-9)).collect()
        };
        let floor = 45e-9;
        let plateau = nm(&[
            (137.44, 1.31),
            (96.86, 1.61),
            (80.26, 1.04),
            (73.67, 1.93),
            (68.09, 1.34),
            (68.23, 3.21),
            (68.33, 3.25),
        ]);
        for n in 1..=plateau.len() {
            assert_eq!(stop_rule(&plateau[..n], floor, 8), None, "{n}");
        }
        assert_eq!(stop_rule(&plateau, floor, 7), Some("budget"));
        let growing = nm(&[(80.0, 1.0), (86.0, 1.0), (92.0, 1.5)]);
        assert_eq!(stop_rule(&growing, floor, 10), Some("diverged"));
        assert_eq!(stop_rule(&growing[..2], floor, 10), None);
        let once = nm(&[(80.0, 1.0), (86.0, 1.0), (85.0, 1.0), (91.0, 1.0)]);
        assert_eq!(stop_rule(&once, floor, 10), None);
        let one_line = nm(&[(80.0, f64::NAN), (80.1, f64::NAN), (80.2, f64::NAN)]);
        assert_eq!(stop_rule(&one_line, floor, 10), Some("diverged"));
        assert_eq!(
            stop_rule(&nm(&[(90.0, 1.0), (67.4, 1.0)]), floor, 10),
            Some("converged")
        );
        assert_eq!(stop_rule(&[], floor, 10), None);
    }
    use crate::splitmix::standard_normal;

    /// White Gaussian noise of σ = 40 nm in 400 lines of 100 ticks: the
    /// RMS is σ within its own 1σ, and that 1σ is the analytic one of an
    /// RMS of `N` independent samples, `σ/√(2N)` (the mean square's
    /// variance is `2σ⁴/N`), within 15 %.
    #[test]
    fn the_rms_error_sigma_is_that_of_white_noise() {
        let (n, lines, sigma) = (100, 400, 40e-9);
        let y: Vec<f64> = (0..n * lines)
            .map(|i| sigma * standard_normal(i as u64))
            .collect();
        let r = vec![0.0; y.len()];
        let m = measured_error(&r, &y, n, 0);
        let analytic = sigma / (2.0 * (n * lines) as f64).sqrt();
        assert!(
            (m.rms_sigma_m / analytic - 1.0).abs() < 0.15,
            "{m:?} {analytic}"
        );
        assert!((m.rms_m - sigma).abs() < 3.0 * analytic, "{m:?}");
        assert_eq!(m.mean_line_m.len(), n);
        // One line: no scatter to measure.
        assert!(measured_error(&r[..n], &y[..n], n, 0).rms_sigma_m.is_nan());
    }

    /// The default 10 µm move (25 ms) on the shipped bench puts more
    /// than 10 nm in the CNMP band; the smoother limits offered put at
    /// most 10 nm there, and the next faster step (λ/1.25) more: the
    /// offer is the least slowing that does it. The content is judged
    /// here on the band's harmonics of the table, by the DFT sum written
    /// out, not the function's own sum.
    #[test]
    fn the_smoother_move_offered_is_the_least_slowing_that_empties_the_band() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
        let cfg = BenchConfig::load(&path).unwrap();
        let model = Sr4dof::new(cfg.plant).unwrap();
        let bands = ZeroBand::of(&crate::analysis::modal::damped_zeros(&model));
        let limits = MoveLimits {
            velocity_m_s: 1e-3,
            acceleration_m_s2: 0.1,
            jerk_m_s3: 40.0,
            snap_m_s4: Some(2e4),
        };
        let scan = |l: MoveLimits| Scan {
            kind: ScanKind::Move,
            amplitude_m: 10e-6,
            line_rate_hz: 1.0,
            cutoff_hz: 408.0,
            move_limits: Some(l),
            reference_csv: None,
            reference: None,
        };
        let n = 5000;
        let in_band = |l: MoveLimits| -> f64 {
            let x = scan(l).table(n);
            (1..=n / 2)
                .filter(|&k| {
                    bands
                        .iter()
                        .any(|b| b.right_half_plane() && b.contains(k as f64))
                })
                .map(|k| {
                    let (mut re, mut im) = (0.0, 0.0);
                    for (i, v) in x.iter().enumerate() {
                        let th = 2.0 * std::f64::consts::PI * (k * i % n) as f64 / n as f64;
                        re += v * th.cos();
                        im -= v * th.sin();
                    }
                    2.0 * (re * re + im * im).sqrt() / n as f64
                })
                .sum()
        };
        let (now, offer) = move_in_zero_bands(&scan(limits), n, &bands, 10e-9);
        assert!((now / in_band(limits) - 1.0).abs() < 1e-9, "{now}");
        assert!(now > 10e-9, "{now}");
        let offer = offer.expect("a slower move fits a 1 s line");
        let lambda = limits.velocity_m_s / offer.velocity_m_s;
        assert!(in_band(offer) <= 10e-9);
        assert!(in_band(limits.slower(lambda / 1.25)) > 10e-9, "λ {lambda}");
    }

    /// The ratio's first-order 1σ: 10 ± 1 over 2 ± 0.1 is 5 ± 5·√(0.01 + 0.0025).
    #[test]
    fn a_ratio_carries_both_sigmas() {
        let (r, s) = ratio((10.0, 1.0), (2.0, 0.1));
        assert!((r - 5.0).abs() < 1e-12);
        assert!((s - 5.0 * 0.0125f64.sqrt()).abs() < 1e-12);
        // A zero numerator (a standstill on one code) keeps its own 1σ
        // over the floor, σa/b, where (a/b)·(σa/a) is 0·∞.
        let (r, s) = ratio((0.0, 0.5), (2.0, 0.0));
        assert_eq!(r, 0.0);
        assert!((s - 0.25).abs() < 1e-12, "{s}");
    }
}
