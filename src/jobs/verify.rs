//! `bench control --verify` (README, *`bench control`*, `--verify`): the
//! injection planned and checked against the limits before anything is
//! enabled ([`plan`]), then, after the run, the closed-loop estimates and
//! their comparison with the loop check ([`analyze`]) and their outputs
//! ([`write_outputs`]): the `/control/verify` message,
//! `<stem>.verify.csv` and `<stem>.verify.png`.
//!
//! The estimation and the comparison are [`crate::control::verify`]. The
//! I²t of the planned current is judged by the supervisor's own rule (a
//! [`Supervisor`] fed the planned commands), so no safety rule has a
//! second copy here; at run time the injection is part of the job's
//! command and the one supervisor of the loop judges it like any other.

use crate::config::BenchConfig;
use crate::control::loop_check::Margins;
use crate::control::verify::{
    chirp_config, ClosedLoopFrf, Envelope, ModelLoop, VerifyRecord, VerifyResult,
};
use crate::error::RunError;
use crate::ident::chirp::Chirp;
use crate::ident::frf::{log_grid, C64};
use crate::jobs::chirp::StallReport;
use crate::jobs::session::Collected;
use crate::outputs::{Destination, Existing, Origin, OutputPlan};
use crate::plot::{bode_curve, write_bode_png, BodePlot, BodeSeries};
use crate::record::Recorder;
use crate::rt::supervisor::{CurrentLimits, Supervisor};
use bench_hal::{Clock, DeviceInfo};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::PathBuf;

/// The default injection amplitude as a fraction of `chirp.amplitude_a`
/// (0.05 A on the Chapter 5 bench; README, `--verify`).
pub const DEFAULT_AMPLITUDE_OF_CHIRP: f64 = 0.1;

/// The default sweep duration, s.
pub const DEFAULT_DURATION_S: f64 = 10.0;

/// The header of `<stem>.verify.csv`: the measured S, T and PS (their
/// magnitudes and unwrapped phases), `coherence` the γ² of S that selects
/// the lines, `ps_coherence` PS's, `ps_sigma_m_per_a` PS's 1σ as a complex
/// number.
pub const VERIFY_CSV_HEADER: &str = "frequency_hz,s_magnitude,s_phase_deg,t_magnitude,t_phase_deg,ps_magnitude_m_per_a,ps_phase_deg,coherence,ps_coherence,ps_sigma_m_per_a";

/// The topic of the verify's result.
pub const TOPIC_VERIFY: &str = "/control/verify";

/// A closed-loop step's outputs beside its recording `<stem>.mcap`: the
/// one place their names are made, for `bench control` (where `--plot`
/// may name another) and the daemon's jobs alike.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StepOutputs {
    /// `<stem>.step.png`: the step response.
    pub plot: PathBuf,
    /// With `--verify`: `<stem>.verify.csv` (the measured loop) and
    /// `<stem>.verify.png`.
    pub verify: Option<(PathBuf, PathBuf)>,
}

impl StepOutputs {
    /// The suffixes: step plot, verify CSV, verify plot.
    const SUFFIXES: [&'static str; 3] = [".step.png", ".verify.csv", ".verify.png"];

    /// The suffixes a recording's name must leave free
    /// ([`crate::outputs::claim_recording`]'s companions).
    pub fn companions(verify: bool) -> &'static [&'static str] {
        if verify {
            &Self::SUFFIXES
        } else {
            &Self::SUFFIXES[..1]
        }
    }

    /// The recording of a step named `PREFIX-…` (`control-fast`) and its
    /// outputs where `dest` puts them ([`Destination::recording`]; `--plot`
    /// beside it unless given, the `--verify` CSV and plot always beside
    /// it), with the plan that checks them. With `claim` false
    /// (`--check-only`, which writes nothing) no name is claimed and the
    /// recording is not in the plan. The
    /// command line and the daemon both name a step's outputs here.
    ///
    /// # Errors
    /// The recording's ([`Destination::recording`]).
    pub fn plan(
        dest: &Destination,
        prefix: &str,
        verify: bool,
        claim: bool,
    ) -> Result<(PathBuf, Self, OutputPlan), RunError> {
        let (out, plan) = dest.recording(prefix, Self::companions(verify), claim)?;
        let beside = Self::beside(&out, verify);
        let (plot, origin) = dest.beside_recording("plot", beside.plot);
        let named = Self {
            plot,
            verify: beside.verify,
        };
        let plan = plan.with_output("plot", &named.plot, origin);
        let plan = match &named.verify {
            Some((csv, plot)) => plan
                .with_output("verify_csv", csv, Origin::Derived)
                .with_output("verify_plot", plot, Origin::Derived),
            None => plan,
        };
        Ok((out, named, plan))
    }

    /// The outputs beside the recording `out` ([`crate::outputs::beside`]).
    pub fn beside(out: &std::path::Path, verify: bool) -> Self {
        use crate::outputs::beside;
        let [plot, csv, verify_plot] = Self::SUFFIXES;
        Self {
            plot: beside(out, plot),
            verify: verify.then(|| (beside(out, csv), beside(out, verify_plot))),
        }
    }
}

/// What `--verify` asks for, with the outputs beside the recording.
#[derive(Debug, Clone, PartialEq)]
pub struct VerifyOptions {
    /// Chirp amplitude at the plant input, A.
    pub amplitude_a: f64,
    /// Sweep duration, s.
    pub duration_s: f64,
    /// `<stem>.verify.csv`.
    pub csv: PathBuf,
    /// `<stem>.verify.png`.
    pub plot: PathBuf,
}

/// The injection as planned, and the model's prediction of what it does,
/// checked against the limits in force before anything is enabled.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct VerifyPlan {
    /// Chirp amplitude at the plant input, A (before the `[chirp]`
    /// amplitude profile's scale).
    pub amplitude_a: f64,
    /// Sweep duration, s.
    pub duration_s: f64,
    /// Sweep band, Hz (`[chirp]`).
    pub f_start_hz: f64,
    /// Sweep band's end, Hz.
    pub f_end_hz: f64,
    /// Loop time the verify's record starts at (the end of the step), s.
    pub start_s: f64,
    /// Quiet lead-in before the sweep (`chirp.lead_in_s`), s.
    pub lead_in_s: f64,
    /// Quiet tail after it (`chirp.tail_s`), s.
    pub tail_s: f64,
    /// The whole run: the step and the verify, s.
    pub run_s: f64,
    /// The command that holds the step's setpoint on the model (the step
    /// over the plant's static gain), A.
    pub steady_command_a: f64,
    /// Largest `s(f)·|S(f)|` over the band on the model (command per
    /// ampere injected; `s` the amplitude profile's scale), A/A.
    pub sensitivity_envelope: f64,
    /// Where, Hz.
    pub sensitivity_envelope_at_hz: f64,
    /// Predicted peak command: `|steady_command_a| + amplitude_a ×
    /// sensitivity_envelope`, A.
    pub peak_current_a: f64,
    /// The peak current in force (the supervisor clips to it), A.
    pub peak_current_limit_a: f64,
    /// Largest `s(f)·|PS(f)|` over the band on the model, m/A.
    pub process_sensitivity_envelope_m_per_a: f64,
    /// Where, Hz.
    pub process_sensitivity_envelope_at_hz: f64,
    /// Predicted peak excursion from the start position: `|step.step_m| +
    /// amplitude_a × process_sensitivity_envelope_m_per_a`, m.
    pub peak_excursion_m: f64,
    /// `safety.position_limit_m`, m.
    pub position_limit_m: f64,
    /// Predicted largest change of the reading in one tick, m.
    pub reading_step_m: f64,
    /// `safety.max_position_step_m`, m.
    pub max_position_step_m: f64,
    /// Largest I²t the planned command reaches from cold (the
    /// supervisor's accumulator fed the steady command plus `|S|` times
    /// the chirp, tick by tick), A²·s.
    pub i2t_peak_a2s: f64,
    /// The supervisor's I²t budget, A²·s.
    pub i2t_budget_a2s: f64,
    /// The current limits the plan was checked against.
    pub current_limits: CurrentLimits,
}

/// The verify's part of `bench control`'s summary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Verify {
    /// The injection and its prediction, checked before enable.
    pub plan: VerifyPlan,
    /// The measurement against the prediction (`null` with
    /// `--check-only`).
    pub result: Option<VerifyResult>,
    /// The estimates as CSV (`null` with `--check-only`).
    pub csv: Option<PathBuf>,
    /// Measured and predicted |S| (`null` with `--check-only`).
    pub plot: Option<PathBuf>,
}

impl Verify {
    /// Whether the run's verification disagrees with the prediction.
    pub fn flagged(&self) -> bool {
        self.result.as_ref().is_some_and(|r| r.flagged)
    }
}

/// The device a plan is checked against before any is opened
/// (`--check-only`): the host's `[actuator]` limits at the config's rate.
pub fn host_device(cfg: &BenchConfig) -> DeviceInfo {
    DeviceInfo {
        name: "host config".into(),
        clock: Clock::Host,
        period_ns: cfg.loop_.period_ns(),
        peak_current_a: cfg.actuator.peak_current_a,
        continuous_current_a: cfg.actuator.continuous_current_a,
        probe_range_m: cfg.probe.range_m,
        probe_lsb_m: 0.0,
        watchdog_s: None,
    }
}

/// The planned command tick by tick from the verify's first tick: the
/// steady command plus the chirp times the model's `|S|` at the sweep's
/// instantaneous frequency (the steady-state envelope of `S·d`).
fn planned_commands<'a>(
    chirp: &'a Chirp,
    env: &'a Envelope,
    steady_a: f64,
    period_s: f64,
) -> impl Iterator<Item = f64> + 'a {
    let lead = chirp.lead_in_ticks();
    (0..chirp.total_ticks()).map(move |k| {
        let d = chirp.value_a(k);
        if d == 0.0 {
            return steady_a;
        }
        let t = (k - lead) as f64 * period_s;
        steady_a + env.sensitivity_at(chirp.frequency_hz(t)) * d
    })
}

/// The largest I²t the supervisor's rule reaches on `commands` from cold,
/// and whether it trips; `sup` fresh, with the limits in force.
fn i2t_of(mut sup: Supervisor, commands: impl Iterator<Item = f64>) -> (f64, bool) {
    sup.enabled();
    sup.running();
    let mut peak = 0.0f64;
    for i in commands {
        let (_, fault) = sup.command(i);
        peak = peak.max(sup.i2t_a2s());
        if fault.is_some() {
            return (peak, true);
        }
    }
    (peak, false)
}

/// Plans the injection of `opts` after the step of `cfg` on `device` (its
/// period and the current limits in force), predicts it on `model` and
/// refuses an amplitude the limits do not leave room for.
///
/// # Errors
/// [`RunError::BadOption`] naming `verify_amplitude_a`, with the
/// predicted figures, the limits and the largest amplitude each allows,
/// when the predicted peak command is above the peak current, the
/// predicted excursion (with the step) reaches `safety.position_limit_m`,
/// the predicted change per tick exceeds `safety.max_position_step_m`, or
/// the planned command spends the I²t budget; nothing is enabled.
pub fn plan(
    cfg: &BenchConfig,
    model: &ModelLoop<'_>,
    opts: &VerifyOptions,
    device: &DeviceInfo,
) -> Result<(VerifyPlan, Chirp), RunError> {
    let period_s = device.period_ns as f64 * 1e-9;
    let a = opts.amplitude_a;
    let chirp = Chirp::new(
        &chirp_config(&cfg.chirp, a, opts.duration_s),
        cfg.excitation.kind,
        period_s,
    );
    let env = Envelope::of(
        model,
        &chirp,
        cfg.chirp.f_start_hz,
        cfg.chirp.f_end_hz,
        cfg.identification.points_per_decade,
    );
    let step_m = cfg.step.step_m;
    let steady = step_m / model.static_gain_m_per_a();
    let limits = cfg.current_limits(device);
    let sup_cfg = cfg.supervisor(device);
    let sup = Supervisor::new(sup_cfg);
    let budget = sup.i2t_budget_a2s();
    let (i2t, tripped) = i2t_of(
        sup.clone(),
        planned_commands(&chirp, &env, steady, period_s),
    );
    let step_s = cfg.step.duration_s;
    let plan = VerifyPlan {
        amplitude_a: a,
        duration_s: opts.duration_s,
        f_start_hz: cfg.chirp.f_start_hz,
        f_end_hz: cfg.chirp.f_end_hz,
        start_s: step_s,
        lead_in_s: cfg.chirp.lead_in_s,
        tail_s: cfg.chirp.tail_s,
        run_s: step_s + chirp.total_ticks() as f64 * period_s,
        steady_command_a: steady,
        sensitivity_envelope: env.current_gain,
        sensitivity_envelope_at_hz: env.current_gain_at_hz,
        peak_current_a: steady.abs() + a * env.current_gain,
        peak_current_limit_a: limits.peak_current_a,
        process_sensitivity_envelope_m_per_a: env.excursion_m_per_a,
        process_sensitivity_envelope_at_hz: env.excursion_at_hz,
        peak_excursion_m: step_m.abs() + a * env.excursion_m_per_a,
        position_limit_m: cfg.safety.position_limit_m,
        reading_step_m: a * env.reading_step_m_per_a,
        max_position_step_m: cfg.safety.max_position_step_m,
        i2t_peak_a2s: i2t,
        i2t_budget_a2s: budget,
        current_limits: limits,
    };
    let mut why = Vec::new();
    let numbers = [
        plan.steady_command_a,
        plan.peak_current_a,
        plan.peak_excursion_m,
        plan.reading_step_m,
        plan.i2t_peak_a2s,
    ];
    if numbers.iter().any(|v| !v.is_finite()) {
        why.push(format!(
            "the model's prediction is not finite (steady command {} A, peak command {} A, excursion {} m, step per tick {} m, I²t {} A²s): check [plant] and the controller",
            numbers[0], numbers[1], numbers[2], numbers[3], numbers[4]
        ));
    }
    if plan.peak_current_a > plan.peak_current_limit_a {
        why.push(format!(
            "predicted peak command {:.3} A = steady command {:.3} A + {a} A × |S| {:.3} (model, at {:.1} Hz) is above the peak current in force {} A ({}); at most {:.4} A",
            plan.peak_current_a,
            steady.abs(),
            env.current_gain,
            env.current_gain_at_hz,
            limits.peak_current_a,
            limits.peak_from.as_str(),
            (limits.peak_current_a - steady.abs()).max(0.0) / env.current_gain,
        ));
    }
    if plan.peak_excursion_m >= plan.position_limit_m {
        why.push(format!(
            "predicted peak excursion {:.1} µm = step {:.1} µm + {a} A × |PS| {:.3e} m/A (model, at {:.1} Hz) reaches safety.position_limit_m = {:.1} µm; at most {:.4} A",
            plan.peak_excursion_m * 1e6,
            step_m.abs() * 1e6,
            env.excursion_m_per_a,
            env.excursion_at_hz,
            plan.position_limit_m * 1e6,
            (plan.position_limit_m - step_m.abs()).max(0.0) / env.excursion_m_per_a,
        ));
    }
    if plan.reading_step_m > plan.max_position_step_m {
        why.push(format!(
            "predicted change of the reading {:.1} µm per tick (model, at {:.1} Hz) is above safety.max_position_step_m = {:.1} µm (the position_jump fault); at most {:.4} A",
            plan.reading_step_m * 1e6,
            env.reading_step_at_hz,
            plan.max_position_step_m * 1e6,
            plan.max_position_step_m / env.reading_step_m_per_a,
        ));
    }
    if tripped {
        // The largest amplitude whose planned command keeps within the
        // budget, by bisection on the same rule.
        let trips = |x: f64| {
            let c = Chirp::new(
                &chirp_config(&cfg.chirp, x, opts.duration_s),
                cfg.excitation.kind,
                period_s,
            );
            i2t_of(sup.clone(), planned_commands(&c, &env, steady, period_s)).1
        };
        let (mut lo, mut hi) = (0.0, a);
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if trips(mid) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        why.push(format!(
            "the planned command spends the I²t budget {budget:.1} A²s ((peak {} A)² − (continuous {} A)², × safety.i2t_peak_duration_s = {} s) within the {} s sweep; at most {lo:.4} A, or a shorter --verify-duration-s",
            limits.peak_current_a,
            limits.continuous_current_a,
            cfg.safety.i2t_peak_duration_s,
            opts.duration_s,
        ));
    }
    if !why.is_empty() {
        return Err(RunError::option(
            "verify_amplitude_a",
            a,
            format!("{}; nothing was enabled", why.join("; ")),
        ));
    }
    Ok((plan, chirp))
}

/// The verify's estimates and their comparison.
#[derive(Debug, Clone)]
pub struct Analysis {
    /// S, T and PS with their coherences.
    pub frf: ClosedLoopFrf,
    /// The lines no stall biased.
    pub keep: Vec<bool>,
    /// The comparison with the prediction.
    pub result: VerifyResult,
}

/// Estimates S, T and PS from the verify's part of `data` (from job tick
/// `start` on, `chirp` injected), leaves out the lines a stall biased
/// (the rule of `bench chirp`, [`StallReport`]), and compares the rest
/// with the loop check's `predicted` margins.
#[allow(clippy::too_many_arguments)]
pub fn analyze(
    data: &Collected,
    start: usize,
    chirp: &Chirp,
    cfg: &BenchConfig,
    period_s: f64,
    stalls: &[(u64, f64)],
    predicted: &Margins,
    model: &ModelLoop<'_>,
) -> Analysis {
    let n = data
        .excitation_a
        .len()
        .min(data.current_command_a.len())
        .min(data.position_m.len());
    let start = start.min(n);
    let rec = VerifyRecord {
        d: &data.excitation_a[start..n],
        u: &data.current_command_a[start..n],
        y: &data.position_m[start..n],
        quiet_ticks: chirp.lead_in_ticks() as usize,
    };
    let frf = ClosedLoopFrf::estimate(
        &rec,
        1.0 / period_s,
        &cfg.identification,
        cfg.chirp.f_start_hz,
        cfg.chirp.f_end_hz,
    );
    // Stalls in the verify's time (its first tick is 0).
    let ours: Vec<(u64, f64)> = stalls
        .iter()
        .filter(|(t, _)| *t >= start as u64)
        .map(|&(t, s)| (t - start as u64, s))
        .collect();
    let report = StallReport::of(
        &ours,
        chirp,
        period_s,
        cfg.identification.relative_resolution,
    );
    let keep: Vec<bool> = frf
        .frequency_hz
        .iter()
        .map(|f| !report.bands_hz.iter().any(|[lo, hi]| f >= lo && f <= hi))
        .collect();
    let result = VerifyResult::of(&frf, &keep, predicted, model);
    Analysis { frf, keep, result }
}

/// The `/control/verify` message: the summary and the estimates.
#[derive(Debug, Clone, Serialize, schemars::JsonSchema)]
pub struct VerifyMessage {
    /// As `/control/summary`'s `verify`.
    pub verify: Verify,
    /// Grid, Hz.
    pub frequency_hz: Vec<f64>,
    /// |S| = |u/d|, dimensionless.
    pub s_magnitude: Vec<f64>,
    /// ∠S, degrees, unwrapped.
    pub s_phase_deg: Vec<f64>,
    /// γ²(d → u), 0 … 1: the lines at or above the threshold count.
    pub s_coherence: Vec<f64>,
    /// |T| = |(d − u)/d|, dimensionless.
    pub t_magnitude: Vec<f64>,
    /// ∠T, degrees, unwrapped.
    pub t_phase_deg: Vec<f64>,
    /// γ²(d → d − u), 0 … 1.
    pub t_coherence: Vec<f64>,
    /// |PS| = |y/d|, m/A.
    pub ps_magnitude_m_per_a: Vec<f64>,
    /// ∠PS, degrees, unwrapped.
    pub ps_phase_deg: Vec<f64>,
    /// γ²(d → y), 0 … 1.
    pub ps_coherence: Vec<f64>,
    /// 1σ of PS as a complex number, m/A (the H1 estimate's
    /// `√E|P̂S − PS|²`; absent from recordings made before it).
    pub ps_sigma_m_per_a: Vec<f64>,
    /// The line counts (coherent, not biased by a stall).
    pub used: Vec<bool>,
    /// The model's |S| at the lines, dimensionless.
    pub model_s_magnitude: Vec<f64>,
    /// The model's ∠S at the lines, degrees, unwrapped.
    pub model_s_phase_deg: Vec<f64>,
}

/// Writes the verify's outputs: the `/control/verify` message (log time
/// `end_ns`) into `recorder`, and the CSV and the plot of `opts` by the
/// rules of `existing`. `title` heads the plot.
///
/// # Errors
/// [`RunError::Record`] for the message; [`RunError::Output`] naming the
/// CSV or the plot.
#[allow(clippy::too_many_arguments)]
pub fn write_outputs(
    recorder: &mut Recorder,
    end_ns: u64,
    a: &Analysis,
    model: &ModelLoop<'_>,
    verify: &Verify,
    opts: &VerifyOptions,
    existing: Existing,
    title: &str,
) -> Result<(), RunError> {
    let f = &a.frf.frequency_hz;
    let (s_mag, s_phase) = ClosedLoopFrf::bode(&a.frf.s);
    let (t_mag, t_phase) = ClosedLoopFrf::bode(&a.frf.t);
    let (ps_mag, ps_phase) = ClosedLoopFrf::bode(&a.frf.ps);
    let model_s: Vec<C64> = f.iter().map(|&f| model.sensitivity(f)).collect();
    let (model_mag, model_phase) = bode_curve(&model_s, s_phase.first().copied());
    let used: Vec<bool> = (0..f.len()).map(|i| a.frf.counts(i) && a.keep[i]).collect();
    crate::outputs::write_atomically(&opts.csv, existing, |file| {
        let mut w = std::io::BufWriter::new(file);
        writeln!(w, "{VERIFY_CSV_HEADER}")?;
        for i in 0..f.len() {
            writeln!(
                w,
                "{:.6},{:.6e},{:.3},{:.6e},{:.3},{:.6e},{:.3},{:.5},{:.5},{:.6e}",
                f[i],
                s_mag[i],
                s_phase[i],
                t_mag[i],
                t_phase[i],
                ps_mag[i],
                ps_phase[i],
                a.frf.s_coherence[i],
                a.frf.ps_coherence[i],
                a.frf.ps_sigma_m_per_a[i]
            )?;
        }
        w.flush()
    })
    .map_err(|e| RunError::Output {
        path: opts.csv.clone(),
        reason: e.to_string(),
    })?;
    // The model on a grid as dense as chirp's Bode plot draws it.
    let dense = log_grid(
        f.first().copied().unwrap_or(1.0),
        f.last().copied().unwrap_or(10.0),
        crate::control::verify::ENVELOPE_POINTS_PER_DECADE,
    );
    let dense_s: Vec<C64> = dense.iter().map(|&f| model.sensitivity(f)).collect();
    let (dense_mag, dense_phase) = bode_curve(&dense_s, s_phase.first().copied());
    write_bode_png(
        &opts.plot,
        existing,
        &BodePlot {
            title,
            magnitude_axis: "|S| [dB]",
            measured: BodeSeries {
                label: "measured S = u/d (H1)",
                frequency_hz: f,
                magnitude: &s_mag,
                phase_deg: &s_phase,
            },
            coherence: &a.frf.s_coherence,
            model: Some(BodeSeries {
                label: "predicted S = 1/(1 + L) (model: ZOH, amplifier, discrete controller)",
                frequency_hz: &dense,
                magnitude: &dense_mag,
                phase_deg: &dense_phase,
            }),
            markers_hz: &[],
            pair: None,
        },
    )
    .map_err(|e| RunError::Output {
        path: opts.plot.clone(),
        reason: e.to_string(),
    })?;
    let ch = recorder.add_channel_for::<VerifyMessage>(TOPIC_VERIFY, "bench.VerifyMessage")?;
    recorder.write(
        ch,
        end_ns,
        &VerifyMessage {
            verify: verify.clone(),
            frequency_hz: f.clone(),
            s_magnitude: s_mag,
            s_phase_deg: s_phase,
            s_coherence: a.frf.s_coherence.clone(),
            t_magnitude: t_mag,
            t_phase_deg: t_phase,
            t_coherence: a.frf.t_coherence.clone(),
            ps_magnitude_m_per_a: ps_mag,
            ps_phase_deg: ps_phase,
            ps_coherence: a.frf.ps_coherence.clone(),
            ps_sigma_m_per_a: a.frf.ps_sigma_m_per_a.clone(),
            used,
            model_s_magnitude: model_mag,
            model_s_phase_deg: model_phase,
        },
    )?;
    Ok(())
}

/// What a `bench control --verify` recording holds for `bench track
/// --learning-ps`: the measured PS with its 1σ, the controller it was
/// measured with and the resolved config of the run.
#[derive(Debug, Clone)]
pub struct RecordedVerify {
    /// The measured process sensitivity; a line counts when the verify
    /// used it (coherent in S, not biased by a stall), `γ²(d → y)` is at
    /// least [`crate::ident::frf::MIN_COHERENCE`] and PS and its σ are
    /// finite.
    pub ps: crate::track::measured::MeasuredPs,
    /// `/control/summary`'s `controller`.
    pub controller: String,
    /// The `toml` of the `bench.config` metadata (the run's resolved
    /// config).
    pub config_toml: String,
    /// The `backend` of the `bench.run` metadata: the device the loop was
    /// measured on (`sim:sr4dof`, `serial:/dev/ttyACM0 (protocol v3)`).
    pub backend: Option<String>,
}

/// The fields of `/control/verify` the learning filter reads (a
/// recording made before PS's σ was recorded has none: refused).
#[derive(Deserialize)]
struct VerifyPs {
    frequency_hz: Vec<f64>,
    ps_magnitude_m_per_a: Vec<f64>,
    ps_phase_deg: Vec<f64>,
    ps_coherence: Vec<f64>,
    #[serde(default)]
    ps_sigma_m_per_a: Vec<f64>,
    used: Vec<bool>,
}

/// Reads the measured PS, the controller and the config of the `bench
/// control --verify` recording in `bytes` (complete, or the `.part` of a
/// killed run whose verify message was written).
///
/// # Errors
/// The reason, in words: not a readable MCAP; no `/control/verify`
/// message (a recording of `bench control` without `--verify`, or of
/// another job: its topics named); a payload that is not the verify's,
/// columns of different lengths, a recording made before PS's 1σ was
/// recorded; no `/control/summary` or no `bench.config` metadata.
pub fn read_verify(bytes: &[u8]) -> Result<RecordedVerify, String> {
    let read = crate::record::read_messages_tolerant(bytes);
    if read.messages.is_empty() {
        return Err(match read.error {
            Some(e) => format!("not a readable MCAP recording: {e}"),
            None => "no messages: an empty recording".into(),
        });
    }
    let last = |topic: &str| {
        read.messages
            .iter()
            .rev()
            .find(|m| m.channel.topic == topic)
    };
    let Some(msg) = last(TOPIC_VERIFY) else {
        return Err(format!(
            "no {TOPIC_VERIFY} message: not a recording of bench control --verify (its topics: {})",
            read.topics().join(", ")
        ));
    };
    let v: VerifyPs = serde_json::from_slice(&msg.data)
        .map_err(|e| format!("{TOPIC_VERIFY}: not the verify's measurement: {e}"))?;
    let n = v.frequency_hz.len();
    if v.ps_sigma_m_per_a.is_empty() && n > 0 {
        return Err(format!(
            "{TOPIC_VERIFY} has no ps_sigma_m_per_a: recorded by a bench before PS's 1σ was; run bench control --verify again"
        ));
    }
    for (name, len) in [
        ("ps_magnitude_m_per_a", v.ps_magnitude_m_per_a.len()),
        ("ps_phase_deg", v.ps_phase_deg.len()),
        ("ps_coherence", v.ps_coherence.len()),
        ("ps_sigma_m_per_a", v.ps_sigma_m_per_a.len()),
        ("used", v.used.len()),
    ] {
        if len != n {
            return Err(format!(
                "{TOPIC_VERIFY}: {name} has {len} values for {n} frequencies"
            ));
        }
    }
    if !v.frequency_hz.windows(2).all(|w| w[0] < w[1])
        || !v.frequency_hz.iter().all(|f| f.is_finite() && *f > 0.0)
    {
        return Err(format!(
            "{TOPIC_VERIFY}: frequency_hz is not an ascending grid of positive frequencies"
        ));
    }
    let ps: Vec<C64> = (0..n)
        .map(|i| C64::from_polar(v.ps_magnitude_m_per_a[i], v.ps_phase_deg[i].to_radians()))
        .collect();
    let counts = (0..n)
        .map(|i| {
            v.used[i]
                && v.ps_coherence[i] >= crate::ident::frf::MIN_COHERENCE
                && ps[i].re.is_finite()
                && ps[i].im.is_finite()
                && ps[i].norm() > 0.0
                && v.ps_sigma_m_per_a[i].is_finite()
                && v.ps_sigma_m_per_a[i] >= 0.0
        })
        .collect();
    #[derive(Deserialize)]
    struct Summary {
        controller: String,
    }
    let summary: Summary = last("/control/summary")
        .ok_or("no /control/summary message: the run did not finish".to_string())
        .and_then(|m| {
            serde_json::from_slice(&m.data)
                .map_err(|e| format!("/control/summary: not a control summary: {e}"))
        })?;
    let config_toml = read
        .metadata_entry("bench.config", "toml")
        .ok_or("no bench.config metadata: the run's config is not recorded")?
        .to_string();
    let backend = read
        .metadata_entry("bench.run", "backend")
        .map(str::to_string);
    Ok(RecordedVerify {
        ps: crate::track::measured::MeasuredPs {
            frequency_hz: v.frequency_hz,
            ps,
            sigma_m_per_a: v.ps_sigma_m_per_a,
            counts,
        },
        controller: summary.controller,
        config_toml,
        backend,
    })
}
