//! `bench control`: check a controller against the plant (the loop check,
//! [`crate::control::loop_check`]), then run a closed-loop step on the
//! stage and measure it.
//!
//! The experiment: the setpoint starts at the measured position (bumpless:
//! zero error, zero controller state, 0 A), holds it for `settle_s`, steps
//! by `step_m` (optionally as a raised-cosine ramp over `smooth_s`) and
//! holds until `duration_s`. Metrics (step response `r = (y − y₀)/step`):
//! - rise time: from r = 0.1 to r = 0.9 (first crossings), s;
//! - settling time: from the step until r stays within 1 ± 0.02, s;
//! - overshoot: `max r − 1`, % (0 when none);
//!
//! (these three on the reading smoothed by a centred moving average over
//! [`SMOOTHING_S`], so probe noise — 40 nm RMS against a 200 nm band for a
//! 10 µm step — does not count as motion; the average is far shorter than
//! the responses it measures);
//! - steady-state error `setpoint − y` over the final
//!   `steady_state_window_s`: mean and standard deviation, nm.

use crate::config::BenchConfig;
use crate::control::loop_check::{check_loop, LoopCheck, MeasuredFrf};
use crate::control::{ControllerConfig, DiscreteController};
use crate::error::RunError;
use crate::jobs::session::{
    finish, open_recording, run_recorded, Collected, Kept, Recorded, Runner, SessionOptions,
    TimingSummary,
};
use crate::outputs::{Existing, Origin, OutputPlan};
use crate::plot::{write_step_png, StepPlot};
use crate::rt::backend::{self, BackendSpec};
use crate::rt::service::{LoopReply, LoopRequest, ServiceClient};
use crate::rt::{Job, JobOutput};
use bench_hal::model::Sr4dof;
use bench_hal::sim::ScheduledFault;
use bench_hal::Sample;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::sync::Arc;

/// The closed-loop step job. Real-time safe: no allocation in `tick`.
#[derive(Debug, Clone, Copy)]
pub struct ControlJob {
    ctrl: DiscreteController,
    start_m: Option<f64>,
    step_m: f64,
    settle_ticks: u64,
    smooth_ticks: u64,
    total_ticks: u64,
}

impl ControlJob {
    /// A step of `step_m` after `settle_ticks`, ramped over `smooth_ticks`
    /// (0: sharp), ending after `total_ticks`.
    pub fn new(
        ctrl: DiscreteController,
        step_m: f64,
        settle_ticks: u64,
        smooth_ticks: u64,
        total_ticks: u64,
    ) -> Self {
        Self {
            ctrl,
            start_m: None,
            step_m,
            settle_ticks,
            smooth_ticks,
            total_ticks,
        }
    }

    /// Setpoint offset from the start position at `tick`, m.
    pub fn profile_m(&self, tick: u64) -> f64 {
        if tick < self.settle_ticks {
            0.0
        } else if self.smooth_ticks == 0 || tick >= self.settle_ticks + self.smooth_ticks {
            self.step_m
        } else {
            let x = (tick - self.settle_ticks) as f64 / self.smooth_ticks as f64;
            self.step_m * 0.5 * (1.0 - (PI * x).cos())
        }
    }
}

impl Job for ControlJob {
    #[inline]
    fn tick(&mut self, tick: u64, sample: &Sample) -> JobOutput {
        let y = sample.position_m;
        // Bumpless start: the first finite reading is the start position.
        if self.start_m.is_none() && y.is_finite() {
            self.start_m = Some(y);
        }
        let setpoint = self.start_m.unwrap_or(0.0) + self.profile_m(tick);
        let command_a = self.ctrl.update(setpoint - y);
        JobOutput {
            command_a,
            excitation_a: f64::NAN,
            setpoint_m: setpoint,
            done: tick + 1 >= self.total_ticks,
        }
    }
}

/// Step-response figures.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct StepMetrics {
    /// Step size, m.
    pub step_m: f64,
    /// 10–90 % rise time, s (`None` if never reached).
    pub rise_time_s: Option<f64>,
    /// 2 % settling time after the step, s (`None` if never settled).
    pub settling_time_s: Option<f64>,
    /// Overshoot, % of the step.
    pub overshoot_pct: f64,
    /// Mean of `setpoint − position` over the final window, nm.
    pub steady_state_error_mean_nm: f64,
    /// Standard deviation of `setpoint − position` over the final window, nm.
    pub steady_state_error_std_nm: f64,
    /// Length of that window, s.
    pub steady_state_window_s: f64,
    /// Largest |command|, A.
    pub peak_command_a: f64,
}

/// Width of the centred moving average applied before the rise, settling
/// and overshoot figures, s.
pub const SMOOTHING_S: f64 = 2e-3;

/// Centred moving average of `x` over `2h + 1` samples (shorter at the ends).
fn moving_average(x: &[f64], h: usize) -> Vec<f64> {
    let mut prefix = Vec::with_capacity(x.len() + 1);
    prefix.push(0.0);
    for v in x {
        prefix.push(prefix.last().copied().unwrap_or(0.0) + v);
    }
    (0..x.len())
        .map(|k| {
            let (a, b) = (k.saturating_sub(h), (k + h + 1).min(x.len()));
            (prefix[b] - prefix[a]) / (b - a) as f64
        })
        .collect()
}

/// Step response level at which the rise time starts (10 %).
pub const RISE_FROM: f64 = 0.1;
/// Step response level at which the rise time ends (90 %).
pub const RISE_TO: f64 = 0.9;
/// Half width of the settling band around the final value, as a fraction
/// of the step (2 %).
pub const SETTLING_BAND: f64 = 0.02;

/// Where, in the recorded samples, the events behind [`StepMetrics`] happen
/// (indices into the columns of [`Collected`]), for the plot's markers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StepEvents {
    /// The sample at which the step starts (`settle_s / period_s`, rounded).
    pub step: usize,
    /// First sample after the step at which the smoothed response reaches
    /// [`RISE_FROM`] of the step (`None` if never).
    pub rise_from: Option<usize>,
    /// First sample after the step at which it reaches [`RISE_TO`].
    pub rise_to: Option<usize>,
    /// First sample from which it stays within ±[`SETTLING_BAND`] of the
    /// step (`None` if it never settles before the end of the record).
    pub settled: Option<usize>,
    /// Sample of the largest smoothed response after the step (`None` if
    /// nothing follows the step).
    pub peak: Option<usize>,
    /// First sample of the steady-state window (which runs to the end).
    pub steady_state_from: usize,
}

/// The step metrics, where their events happen, and the smoothed reading
/// they are computed on.
#[derive(Debug, Clone, PartialEq)]
pub struct StepAnalysis {
    /// The figures.
    pub metrics: StepMetrics,
    /// Where they come from.
    pub events: StepEvents,
    /// The probe reading smoothed by the centred moving average over
    /// [`SMOOTHING_S`], m (same length as [`Collected::position_m`]).
    pub smoothed_position_m: Vec<f64>,
}

/// Computes the step metrics from the recorded signals.
pub fn step_metrics(
    d: &Collected,
    settle_s: f64,
    step_m: f64,
    window_s: f64,
    period_s: f64,
) -> StepMetrics {
    step_analysis(d, settle_s, step_m, window_s, period_s).metrics
}

/// Computes the step metrics (see the module documentation), where their
/// events happen and the smoothed reading, from the recorded signals.
pub fn step_analysis(
    d: &Collected,
    settle_s: f64,
    step_m: f64,
    window_s: f64,
    period_s: f64,
) -> StepAnalysis {
    let n = d.position_m.len();
    let k0 = ((settle_s / period_s).round() as usize).min(n);
    let y0 = d.setpoint_m.first().copied().unwrap_or(0.0);
    let h = ((SMOOTHING_S / period_s / 2.0).round() as usize).max(1);
    let smoothed_position_m = moving_average(&d.position_m, h);
    let r: Vec<f64> = smoothed_position_m
        .iter()
        .map(|y| (y - y0) / step_m)
        .collect();
    let first = |thr: f64| (k0..n).find(|&k| r[k] >= thr);
    let (rise_from, rise_to) = (first(RISE_FROM), first(RISE_TO));
    let rise_time_s = match (rise_from, rise_to) {
        (Some(a), Some(b)) => Some((b - a) as f64 * period_s),
        _ => None,
    };
    let settled = match (k0..n).rev().find(|&k| (r[k] - 1.0).abs() > SETTLING_BAND) {
        None => Some(k0),
        Some(k) if k + 1 < n => Some(k + 1),
        Some(_) => None,
    };
    let settling_time_s = settled.map(|k| (k - k0) as f64 * period_s);
    // The first largest value; NaN readings (a dropped probe sample spreads
    // over the average) are no peak.
    let peak = (k0..n).fold(None, |best: Option<usize>, k| match best {
        _ if r[k].is_nan() => best,
        Some(b) if r[b] >= r[k] => Some(b),
        _ => Some(k),
    });
    let overshoot_pct = (peak.map_or(f64::NEG_INFINITY, |k| r[k]) - 1.0).max(0.0) * 100.0;
    let w = ((window_s / period_s).round() as usize)
        .min(n.saturating_sub(k0))
        .max(1);
    let e: Vec<f64> = (n - w..n)
        .map(|k| d.setpoint_m[k] - d.position_m[k])
        .collect();
    let mean = e.iter().sum::<f64>() / e.len() as f64;
    let var = e.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (e.len().max(2) - 1) as f64;
    let metrics = StepMetrics {
        step_m,
        rise_time_s,
        settling_time_s,
        overshoot_pct,
        steady_state_error_mean_nm: mean * 1e9,
        steady_state_error_std_nm: var.sqrt() * 1e9,
        steady_state_window_s: w as f64 * period_s,
        peak_command_a: d
            .current_command_a
            .iter()
            .fold(0.0, |m: f64, v| m.max(v.abs())),
    };
    StepAnalysis {
        metrics,
        events: StepEvents {
            step: k0,
            rise_from,
            rise_to,
            settled,
            peak,
            steady_state_from: n - w,
        },
        smoothed_position_m,
    }
}

/// Everything `bench control` needs.
#[derive(Debug, Clone)]
pub struct ControlOptions {
    /// Validated config (overrides applied).
    pub config: BenchConfig,
    /// Where it came from.
    pub config_path: PathBuf,
    /// Controller name (`slow`, `fast`, or any `[controller.NAME]`).
    pub controller: String,
    /// Only print the loop check.
    pub check_only: bool,
    /// A measured FRF to check the margins on.
    pub frf: Option<PathBuf>,
    /// Run even if the check refuses (simulator only).
    pub override_check: bool,
    /// The recording.
    pub out: PathBuf,
    /// The step plot.
    pub plot: PathBuf,
    /// Real-time pacing.
    pub realtime: bool,
    /// Seed.
    pub seed: u64,
    /// Progress bar.
    pub progress: bool,
    /// A simulator fault to inject.
    pub inject: Option<ScheduledFault>,
    /// `--backend` (else `[backend]` of the config).
    pub backend: Option<BackendSpec>,
}

/// Result of `bench control`.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ControlSummary {
    /// Controller name.
    pub controller: String,
    /// Its description.
    pub description: String,
    /// The loop check.
    pub loop_check: LoopCheck,
    /// Step metrics (`None` with `--check-only`).
    pub metrics: Option<StepMetrics>,
    /// The recording (`None` with `--check-only`).
    pub recording: Option<PathBuf>,
    /// The step plot.
    pub plot: Option<PathBuf>,
    /// Backend.
    pub backend: String,
    /// Seed.
    pub seed: u64,
    /// Disturbance force RMS, N (0: none).
    pub disturbance_rms_n: f64,
    /// Link counters of a hardware backend; absent on the simulator.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub link: Option<serde_json::Value>,
    /// Loop timing.
    pub timing: Option<TimingSummary>,
    /// The current limits in force and where each came from (`None` with
    /// `--check-only`).
    #[serde(default)]
    pub current_limits: Option<crate::rt::supervisor::CurrentLimits>,
}

fn controller_config<'a>(
    cfg: &'a BenchConfig,
    name: &str,
) -> Result<&'a ControllerConfig, RunError> {
    cfg.controller.get(name).ok_or_else(|| {
        let known: Vec<&str> = cfg.controller.keys().map(|k| k.as_str()).collect();
        RunError::option(
            "controller",
            name,
            format!(
                "no [controller.{name}] in the config (known: {})",
                if known.is_empty() {
                    "none".to_string()
                } else {
                    known.join(", ")
                }
            ),
        )
    })
}

/// Runs `bench control`.
///
/// # Errors
/// [`RunError::BadInput`] for an unknown controller, an unusable FRF file or
/// output path; [`RunError::Refused`] when the loop check fails (without
/// `override_check`); otherwise as [`run_recorded`].
///
/// The outputs in `outputs` (the paths of `opts`; see [`crate::outputs`])
/// are checked after the loop check and before the backend is opened;
/// `--check-only` writes none. `ticks`, if given, follows the loop's tick
/// count (progress, and the CLI's preparation watch).
pub fn run_control(
    opts: &ControlOptions,
    mut outputs: OutputPlan,
    stop: Arc<AtomicBool>,
    ticks: Option<&Arc<AtomicU64>>,
) -> Result<ControlSummary, RunError> {
    run_control_with(opts, &mut outputs, stop, StageSource::Open, ticks)
}

/// The outputs of a control run, none replaced (the daemon's jobs: their
/// names are derived from the recording's).
pub fn control_outputs(opts: &ControlOptions) -> OutputPlan {
    OutputPlan::new(Existing::Refuse)
        .with_recording(&opts.out, Origin::Default)
        .with_output("plot", &opts.plot, Origin::Derived)
}

/// Where `bench control` gets its stage.
pub enum StageSource<'a> {
    /// Open the backend of the options (and drop it after the run).
    Open,
    /// The daemon's loop (its stage stays with it; between jobs it holds
    /// 0 A).
    Service(&'a mut ServiceClient),
}

/// [`run_control`] on a stage from `source`; `ticks`, if given, follows
/// the loop's tick count (progress).
///
/// # Errors
/// As [`run_control`].
pub fn run_control_from(
    opts: &ControlOptions,
    stop: Arc<AtomicBool>,
    source: StageSource<'_>,
    progress_ticks: Option<&Arc<AtomicU64>>,
) -> Result<ControlSummary, RunError> {
    let mut outputs = control_outputs(opts);
    run_control_with(opts, &mut outputs, stop, source, progress_ticks)
}

fn run_control_with(
    opts: &ControlOptions,
    outputs: &mut OutputPlan,
    stop: Arc<AtomicBool>,
    source: StageSource<'_>,
    progress_ticks: Option<&Arc<AtomicU64>>,
) -> Result<ControlSummary, RunError> {
    let cfg = &opts.config;
    let ccfg = controller_config(cfg, &opts.controller)?;
    let measured = opts.frf.as_deref().map(MeasuredFrf::read_csv).transpose()?;
    let model = Sr4dof::new(cfg.plant)
        .map_err(|e| RunError::BadInput(format!("config {}: {e}", opts.config_path.display())))?;
    let spec = BackendSpec::resolve(opts.backend.as_ref(), cfg);
    if opts.override_check && !spec.is_sim() {
        return Err(RunError::option(
            "override_check",
            "",
            format!("only allowed on the sim backend, not {spec}"),
        ));
    }
    // The loop check needs no device: with --check-only nothing is opened.
    let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
    let ctrl = DiscreteController::new(ccfg, period_s, cfg.actuator.peak_current_a);
    let check = check_loop(
        cfg,
        &model,
        &opts.controller,
        &ctrl,
        period_s,
        measured.as_ref(),
        cfg.step.step_m,
    );
    let mut summary = ControlSummary {
        controller: opts.controller.clone(),
        description: ccfg.description.clone(),
        loop_check: check.clone(),
        metrics: None,
        recording: None,
        plot: None,
        backend: spec.to_string(),
        seed: opts.seed,
        disturbance_rms_n: cfg.plant.disturbance.map_or(0.0, |d| d.rms_n),
        link: None,
        timing: None,
        current_limits: None,
    };
    if opts.check_only {
        return Ok(summary);
    }
    if !check.passed() {
        if !opts.override_check {
            return Err(RunError::Refused(format!(
                "loop check refused controller {}: {}; nothing was enabled",
                opts.controller,
                check.failures.join("; ")
            )));
        }
        tracing::warn!(
            "loop check failed ({}); running anyway on the simulator (--override-check)",
            check.failures.join("; ")
        );
    }
    let step = &cfg.step;
    outputs.check()?;
    let mut opened;
    let opened_info;
    let mut runner = match source {
        StageSource::Open => {
            let (s, i) = backend::open(&spec, cfg, &opts.config_path, opts.seed, opts.inject)?;
            opened = s;
            opened_info = i;
            Runner::Local {
                stage: &mut opened,
                info: &opened_info,
            }
        }
        StageSource::Service(client) => {
            if let Some(f) = opts.inject {
                match client.call(LoopRequest::Inject(f)) {
                    Some(LoopReply::Injected(true)) => {}
                    _ => {
                        return Err(RunError::BadInput(
                            "inject_fault: only the sim backend injects faults".into(),
                        ))
                    }
                }
            }
            Runner::Service(client)
        }
    };
    let info = runner.info().clone();
    summary.backend = info.name.clone();
    if info.period_ns != cfg.loop_.period_ns() {
        return Err(RunError::option(
            "backend",
            &spec,
            format!(
                "runs every {} ns, the controller was discretised for {} ns; nothing was enabled",
                info.period_ns,
                cfg.loop_.period_ns()
            ),
        ));
    }
    // Anti-windup at the peak current in force (the smaller of the
    // host's and the device's; same sections).
    let ctrl = ctrl.with_limit(cfg.current_limits(&info).peak_current_a);
    let ticks = |key: &str, s: f64| {
        crate::config::ticks_in(s, period_s).ok_or_else(|| {
            RunError::BadInput(format!(
                "config {}: {key}: {s} s is more than {} ticks at the device's period",
                opts.config_path.display(),
                crate::config::ranges::JOB_TICKS_MAX
            ))
        })
    };
    let total = ticks("step.duration_s", step.duration_s)?;
    let settle = ticks("step.settle_s", step.settle_s)?;
    let smooth = ticks("step.smooth_s", step.smooth_s)?;
    let session = SessionOptions {
        command: "control",
        config_path: &opts.config_path,
        out: &opts.out,
        // Hardware runs in real time whatever the flag says.
        realtime: opts.realtime || !spec.is_sim(),
        progress: opts.progress,
        seed: opts.seed,
        max_ticks: total,
        keep: Kept::STEP,
        ticks: progress_ticks,
        // Closed loop: a stall longer than the loop's own bound (delay
        // margin, reach of the position limit) is the overruns or
        // link_latency fault.
        stall: Some(crate::rt::supervisor::StallBounds::of(
            check.stall.bound_s,
            period_s,
        )),
        stall_source: &check.stall.source,
    };
    let mut recorder = open_recording(&session, cfg, &info, outputs)?;
    let check_ch =
        recorder.add_channel_for::<LoopCheck>("/control/loop_check", "bench.LoopCheck")?;
    recorder.write(check_ch, 0, &check)?;
    recorder.flush_chunk()?;
    let job = ControlJob::new(ctrl, step.step_m, settle, smooth, total);
    let recorded = run_recorded(&mut runner, job, cfg, recorder, &session, stop);
    let Recorded {
        mut recorder,
        data,
        timing,
        end_ns,
        link,
        current_limits,
        ..
    } = recorded?;
    summary.link = link;
    summary.current_limits = Some(current_limits);

    let StepAnalysis {
        metrics,
        events,
        smoothed_position_m,
    } = step_analysis(
        &data,
        step.settle_s,
        step.step_m,
        step.steady_state_window_s,
        period_s,
    );
    let metrics_ch =
        recorder.add_channel_for::<StepMetrics>("/control/metrics", "bench.StepMetrics")?;
    recorder.write(metrics_ch, end_ns, &metrics)?;

    let um = |v: &[f64], off: f64| v.iter().map(|x| (x - off) * 1e6).collect::<Vec<f64>>();
    let y0 = data.setpoint_m.first().copied().unwrap_or(0.0);
    let title = format!(
        "bench control --controller {}: {:.1} µm step (seed {})",
        opts.controller,
        step.step_m * 1e6,
        opts.seed
    );
    write_step_png(
        &opts.plot,
        outputs.existing(),
        &StepPlot {
            title: &title,
            t_s: &data.t_s,
            setpoint_um: &um(&data.setpoint_m, y0),
            position_um: &um(&data.position_m, y0),
            smoothed_um: &um(&smoothed_position_m, y0),
            command_a: &data.current_command_a,
            metrics: &metrics,
            events: &events,
        },
    )
    .map_err(|e| RunError::Output {
        path: opts.plot.clone(),
        reason: e.to_string(),
    })?;
    summary.metrics = Some(metrics);
    summary.plot = Some(opts.plot.clone());
    summary.timing = Some(timing);
    let ch =
        recorder.add_channel_for::<ControlSummary>("/control/summary", "bench.ControlSummary")?;
    recorder.write(ch, end_ns, &summary)?;
    summary.recording = Some(PathBuf::from(finish(recorder)?));
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Metrics of a known first-order step response y = 1 − e^{−t/τ}:
    /// rise 10–90 % = τ ln 9, 2 % settling = τ ln 50, no overshoot.
    #[test]
    fn metrics_of_a_first_order_response() {
        let dt = 1e-4;
        let tau = 0.01;
        let settle = 0.1;
        let n = 10_000;
        let mut d = Collected::default();
        for k in 0..n {
            let t = k as f64 * dt;
            let y = if t < settle {
                0.0
            } else {
                1e-5 * (1.0 - (-(t - settle + dt) / tau).exp())
            };
            d.t_s.push(t);
            d.position_m.push(y);
            d.setpoint_m.push(if t < settle { 0.0 } else { 1e-5 });
            d.current_command_a.push(0.1);
        }
        let m = step_metrics(&d, settle, 1e-5, 0.5, dt);
        assert!((m.rise_time_s.unwrap() - tau * 9f64.ln()).abs() < 2.0 * dt);
        assert!((m.settling_time_s.unwrap() - tau * 50f64.ln()).abs() < 2.0 * dt);
        assert!(m.overshoot_pct < 1e-6);
        assert!(m.steady_state_error_mean_nm.abs() < 1e-3);
        assert_eq!(m.peak_command_a, 0.1);
    }

    /// Overshoot of an underdamped second-order step response:
    /// `exp(−ζπ/√(1−ζ²))` (Ogata, *Modern Control Engineering*, §5-3).
    #[test]
    fn overshoot_of_a_second_order_response() {
        let (dt, wn, zeta) = (1e-4, 60.0, 0.3);
        let wd = wn * (1.0f64 - zeta * zeta).sqrt();
        let mut d = Collected::default();
        for k in 0..30_000 {
            let t = k as f64 * dt - 0.1;
            let r = if t < 0.0 {
                0.0
            } else {
                1.0 - (-zeta * wn * t).exp() * ((wd * t).cos() + zeta * wn / wd * (wd * t).sin())
            };
            d.t_s.push(t + 0.1);
            d.position_m.push(1e-5 * r);
            d.setpoint_m.push(if t < 0.0 { 0.0 } else { 1e-5 });
            d.current_command_a.push(0.0);
        }
        let m = step_metrics(&d, 0.1, 1e-5, 1.0, dt);
        let expected = 100.0 * (-zeta * PI / (1.0f64 - zeta * zeta).sqrt()).exp();
        assert!(
            (m.overshoot_pct - expected).abs() < 0.2,
            "{} vs {expected}",
            m.overshoot_pct
        );
    }

    mod property {
        use super::super::*;
        use crate::rt::supervisor::{Supervisor, SupervisorConfig};
        use bench_hal::SampleFlags;
        use proptest::prelude::*;

        fn reading() -> impl Strategy<Value = f64> {
            prop_oneof![
                4 => -1e-3..1e-3f64,
                1 => Just(f64::NAN),
                1 => Just(f64::INFINITY),
                1 => Just(f64::NEG_INFINITY),
                1 => prop::num::f64::ANY,
                1 => -1e300..1e300f64,
            ]
        }

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(300))]
            /// No sequence of sample values makes the command non-finite or
            /// larger than the peak current: the controller, then the
            /// supervisor, exactly as the tick chains them.
            #[test]
            fn command_is_always_finite_and_limited(
                values in prop::collection::vec(reading(), 1..400),
                fast in any::<bool>(),
                oor in prop::collection::vec(any::<bool>(), 400),
            ) {
                let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
                let cfg = BenchConfig::load(&path).unwrap();
                let name = if fast { "fast" } else { "slow" };
                let peak = cfg.actuator.peak_current_a;
                let ctrl = DiscreteController::new(&cfg.controller[name], 2e-4, peak);
                let mut job = ControlJob::new(ctrl, 1e-5, 10, 0, 1_000_000);
                let mut sup = Supervisor::new(SupervisorConfig {
                    position_limit_m: 0.8e-3,
                    peak_current_a: peak,
                    max_missed_deadlines: 10,
                    max_missed_samples: 3,
                    max_position_step_m: 50e-6,
                    max_late_commands: 10,
                    continuous_current_a: cfg.actuator.continuous_current_a,
                    i2t_peak_duration_s: 1.0,
                    period_s: 2e-4,
                    reach: crate::rt::supervisor::ReachEnvelope::NONE,
                    watchdog_s: None,
                });
                sup.enabled();
                sup.running();
                for (k, x) in values.iter().enumerate() {
                    let sample = Sample {
                        seq: k as u64,
                        device_time_ns: k as u64 * 200_000,
                        position_m: *x,
                        measured_current_a: f64::NAN,
                        flags: SampleFlags { out_of_range: oor[k], ..Default::default() },
                    };
                    sup.check_sample(&sample);
                    let out = job.tick(k as u64, &sample);
                    let (cmd, _) = sup.command(out.command_a);
                    prop_assert!(cmd.is_finite(), "tick {k}: {cmd}");
                    prop_assert!(cmd.abs() <= peak, "tick {k}: {cmd}");
                }
            }
        }
    }
}
