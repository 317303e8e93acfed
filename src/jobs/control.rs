//! `bench control`: check a controller against the plant (the loop check,
//! [`crate::control::loop_check`]), then run a closed-loop step on the
//! stage and measure it.
//!
//! The experiment: the setpoint starts at the measured position (bumpless:
//! zero error, zero controller state, 0 A), holds it for `settle_s`, steps
//! by `step_m` (optionally as a raised-cosine ramp over `smooth_s`) and
//! holds until `duration_s`. The metrics (rise, settling, overshoot on the
//! reading smoothed over [`SMOOTHING_S`]; steady-state error over the final
//! `steady_state_window_s`) are defined and computed in
//! [`crate::control::step_metrics`], re-exported here; the step figure is
//! [`crate::plot::write_step_png`]. With `--verify` the job goes on after
//! the step, holding its setpoint, with a chirp added at the plant input
//! ([`ControlJob::with_verify`]; planned, checked and analysed in
//! [`crate::jobs::verify`]); the step's metrics and figure are the step's
//! ticks alone.

use crate::config::BenchConfig;
use crate::control::loop_check::{check_loop, LoopCheck, MeasuredFrf};
use crate::control::step_metrics::{analyze_step, step_profile_m, StepSignals};
pub use crate::control::step_metrics::{
    StepAnalysis, StepEvents, StepMetrics, RISE_FROM, RISE_TO, SETTLING_BAND, SMOOTHING_S,
};
use crate::control::verify::ModelLoop;
use crate::control::{ControllerConfig, DiscreteController};
use crate::error::RunError;
use crate::ident::chirp::Chirp;
use crate::jobs::session::{
    finish, open_recording, run_recorded, Collected, Kept, Recorded, Runner, SessionOptions,
    TimingSummary,
};
use crate::jobs::verify::{self as verify, Verify, VerifyOptions};
use crate::outputs::{Existing, Origin, OutputPlan};
use crate::plot::{write_step_png, StepPlot};
use crate::rt::backend::{self, BackendSpec};
use crate::rt::service::{LoopReply, LoopRequest, ServiceClient};
use crate::rt::{Job, JobOutput};
use bench_hal::Sample;
use bench_plant::model::Sr4dof;
use bench_plant::sim::{ScheduledFault, ZohPlant};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::sync::Arc;

/// The closed-loop step job, optionally followed by the verify's
/// injection ([`ControlJob::with_verify`]). Real-time safe: no allocation
/// in `tick` (the chirp is computed in closed form from the tick index).
#[derive(Debug, Clone, Copy)]
pub struct ControlJob {
    ctrl: DiscreteController,
    start_m: Option<f64>,
    step_m: f64,
    settle_ticks: u64,
    smooth_ticks: u64,
    total_ticks: u64,
    /// The verify's chirp, added to the command from `verify_start` on.
    verify: Option<Chirp>,
    /// The job tick the verify's record (its lead-in) starts at: the end
    /// of the step.
    verify_start: u64,
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
            verify: None,
            verify_start: total_ticks,
        }
    }

    /// The same step, then, holding its final setpoint, `chirp` (lead-in,
    /// sweep, tail) added at the plant input: the command is the
    /// controller's plus the chirp's value (`bench control --verify`). The
    /// job runs `chirp.total_ticks()` longer.
    pub fn with_verify(self, chirp: Chirp) -> Self {
        let start = self.step_ticks();
        Self {
            verify: Some(chirp),
            verify_start: start,
            total_ticks: start.saturating_add(chirp.total_ticks()),
            ..self
        }
    }

    /// Ticks of the step (before the verify's injection, if any).
    pub fn step_ticks(&self) -> u64 {
        if self.verify.is_some() {
            self.verify_start
        } else {
            self.total_ticks
        }
    }

    /// Ticks of the whole job.
    pub fn total_ticks(&self) -> u64 {
        self.total_ticks
    }

    /// The injection at `tick`, A: the verify's chirp from the end of the
    /// step on (0 in its lead-in and tail), NaN before it or without one.
    #[inline]
    pub fn injection_a(&self, tick: u64) -> f64 {
        match self.verify {
            Some(c) if tick >= self.verify_start => c.value_a(tick - self.verify_start),
            _ => f64::NAN,
        }
    }

    /// Setpoint offset from the start position at `tick`, m.
    pub fn profile_m(&self, tick: u64) -> f64 {
        step_profile_m(tick, self.settle_ticks, self.smooth_ticks, self.step_m)
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
        let d = self.injection_a(tick);
        // u = C·e + d: the injection at the plant input.
        let command_a = self.ctrl.update(setpoint - y) + if d.is_nan() { 0.0 } else { d };
        JobOutput {
            command_a,
            excitation_a: d,
            setpoint_m: setpoint,
            done: tick + 1 >= self.total_ticks,
        }
    }
}

/// Computes the step metrics from the recorded signals (see
/// [`analyze_step`]).
pub fn step_metrics(
    d: &Collected,
    settle_s: f64,
    step_m: f64,
    window_s: f64,
    period_s: f64,
) -> StepMetrics {
    step_analysis(d, settle_s, step_m, window_s, period_s).metrics
}

/// Computes the step metrics ([`crate::control::step_metrics`]), where
/// their events happen and the smoothed reading, from the recorded signals.
pub fn step_analysis(
    d: &Collected,
    settle_s: f64,
    step_m: f64,
    window_s: f64,
    period_s: f64,
) -> StepAnalysis {
    let signals = StepSignals {
        position_m: &d.position_m,
        setpoint_m: &d.setpoint_m,
        current_command_a: &d.current_command_a,
    };
    analyze_step(signals, settle_s, step_m, window_s, period_s)
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
    /// Virtual time paced at this factor of real time, as
    /// [`crate::jobs::chirp::ChirpOptions::pace`].
    pub pace: Option<f64>,
    /// Seed.
    pub seed: u64,
    /// Progress bar.
    pub progress: bool,
    /// A simulator fault to inject.
    pub inject: Option<ScheduledFault>,
    /// `--backend` (else `[backend]` of the config).
    pub backend: Option<BackendSpec>,
    /// `--verify`: after the step, the chirp injected at the plant input
    /// and the loop measured ([`crate::jobs::verify`]).
    pub verify: Option<VerifyOptions>,
    /// Append the run's row to the run catalogue beside its recording
    /// once the recording is finished ([`crate::jobs::catalogue`]).
    pub catalogue: bool,
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
    /// `--verify`: the injection planned, and the loop measured against
    /// the prediction (absent without `--verify`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub verify: Option<Verify>,
    /// The run's row in the run catalogue, or why it was not written;
    /// absent when nothing was recorded (`--check-only`) and in the
    /// summary recorded in the recording, which the row is read from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub catalogue: Option<crate::jobs::catalogue::CatalogueEntry>,
}

impl ControlSummary {
    /// Whether the run's verification disagrees with the prediction
    /// (`bench control` then exits 8).
    pub fn verify_failed(&self) -> bool {
        self.verify.as_ref().is_some_and(Verify::flagged)
    }
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
    let result = run_control_with(opts, &mut outputs, stop, StageSource::Open, ticks);
    catalogued(opts, result)
}

/// `result` with the run's row appended to the catalogue (when
/// `opts.catalogue` and a recording was made): a summary reports it; an
/// error whose recording was finished appends it too. Never changes the
/// outcome.
fn catalogued(
    opts: &ControlOptions,
    result: Result<ControlSummary, RunError>,
) -> Result<ControlSummary, RunError> {
    if !opts.catalogue {
        return result;
    }
    match result {
        Ok(mut summary) => {
            if summary.recording.is_some() {
                summary.catalogue = Some(crate::jobs::catalogue::catalogue_run(&opts.out));
            }
            Ok(summary)
        }
        Err(e) => {
            crate::jobs::catalogue::catalogue_ended_run(&e, &opts.out);
            Err(e)
        }
    }
}

/// The outputs of a control run, none replaced (the daemon's jobs: their
/// names are derived from the recording's).
pub fn control_outputs(opts: &ControlOptions) -> OutputPlan {
    let plan = OutputPlan::new(Existing::Refuse)
        .with_recording(&opts.out, Origin::Default)
        .with_output("plot", &opts.plot, Origin::Derived);
    match &opts.verify {
        Some(v) => plan
            .with_output("verify_csv", &v.csv, Origin::Derived)
            .with_output("verify_plot", &v.plot, Origin::Derived),
        None => plan,
    }
}

/// Where `bench control` gets its stage.
pub enum StageSource<'a> {
    /// Open the backend of the options (and drop it after the run).
    Open,
    /// The daemon's loop (its stage stays with it; between jobs it holds
    /// 0 A).
    Service(&'a mut ServiceClient),
}

/// The stage a job runs on ([`StageSource::stage`]).
pub(crate) enum Stage<'a> {
    /// Opened for this run, dropped (disabled at 0 A) after it.
    Opened(backend::AnyStage, bench_hal::DeviceInfo),
    /// The daemon's loop.
    Service(&'a mut ServiceClient),
}

impl<'a> StageSource<'a> {
    /// The stage: the backend `spec` opened with `inject` scheduled and
    /// `stall_bound_s` its stall bound, or the daemon's loop with `inject`
    /// scheduled on it. Either must run at the period the controller was
    /// discretised for ([`check_device_period`]).
    ///
    /// # Errors
    /// [`backend::open`]'s; a fault on a daemon that is no simulator; a
    /// device at another period.
    pub(crate) fn stage(
        self,
        spec: &BackendSpec,
        cfg: &BenchConfig,
        config_path: &std::path::Path,
        seed: u64,
        inject: Option<ScheduledFault>,
        stall_bound_s: f64,
    ) -> Result<Stage<'a>, RunError> {
        let mut stage = match self {
            Self::Open => {
                let (s, i) = backend::open(spec, cfg, config_path, seed, inject, stall_bound_s)?;
                Stage::Opened(s, i)
            }
            Self::Service(client) => {
                if let Some(f) = inject {
                    inject_on_service(client, f)?;
                }
                Stage::Service(client)
            }
        };
        check_device_period(stage.runner().info(), cfg, spec)?;
        Ok(stage)
    }
}

impl Stage<'_> {
    /// The runner of a job on this stage.
    pub(crate) fn runner(&mut self) -> Runner<'_> {
        match self {
            Stage::Opened(stage, info) => Runner::Local { stage, info },
            Stage::Service(client) => Runner::Service(client),
        }
    }
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
    let result = run_control_with(opts, &mut outputs, stop, source, progress_ticks);
    catalogued(opts, result)
}

/// The verify's injection, predicted on the model and checked against the
/// host's limits before anything is opened (again later against the
/// limits in force once the device has announced its own). `None`: no
/// `--verify`.
fn host_verify_plan(
    opts: &ControlOptions,
    plant: &ZohPlant,
    ctrl: &DiscreteController,
    spec: &BackendSpec,
) -> Result<Option<Verify>, RunError> {
    let Some(v) = &opts.verify else {
        return Ok(None);
    };
    let model_loop = ModelLoop {
        plant,
        ctrl,
        link_delay_periods: spec.process_data_delay_periods(),
    };
    let cfg = &opts.config;
    let (plan, _) = verify::plan(cfg, &model_loop, v, &verify::host_device(cfg))?;
    Ok(Some(Verify {
        plan,
        result: None,
        csv: None,
        plot: None,
    }))
}

/// The `[step]` job of `ctrl` at the device's period: each duration in
/// ticks, within the job's tick limit.
fn step_job(
    opts: &ControlOptions,
    ctrl: DiscreteController,
    period_s: f64,
) -> Result<ControlJob, RunError> {
    let step = &opts.config.step;
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
    Ok(ControlJob::new(ctrl, step.step_m, settle, smooth, total))
}

/// The step's figure (`opts.plot`) on its first `n` ticks, in µm from the
/// initial setpoint.
fn write_step_figure(
    opts: &ControlOptions,
    existing: Existing,
    data: &Collected,
    n: usize,
    analysis: &StepAnalysis,
) -> Result<(), RunError> {
    let step = &opts.config.step;
    let StepAnalysis {
        metrics,
        events,
        smoothed_position_m,
    } = analysis;
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
        existing,
        &StepPlot {
            title: &title,
            t_s: &data.t_s[..n],
            setpoint_um: &um(&data.setpoint_m[..n], y0),
            position_um: &um(&data.position_m[..n], y0),
            smoothed_um: &um(smoothed_position_m, y0),
            command_a: &data.current_command_a[..n],
            metrics,
            events,
        },
    )
    .map_err(|e| RunError::Output {
        path: opts.plot.clone(),
        reason: e.to_string(),
    })
}

/// A loop check that failed refuses the run, unless `--override-check`
/// (sim only, checked before) runs it anyway with a warning.
fn refuse_failed_check(opts: &ControlOptions, check: &LoopCheck) -> Result<(), RunError> {
    if check.passed() {
        return Ok(());
    }
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
    Ok(())
}

/// Schedules `--inject-fault` on the daemon's loop, which only its sim
/// backend accepts.
fn inject_on_service(client: &mut ServiceClient, fault: ScheduledFault) -> Result<(), RunError> {
    match client.call(LoopRequest::Inject(fault)) {
        Some(LoopReply::Injected(true)) => Ok(()),
        _ => Err(RunError::BadInput(
            "inject_fault: only the sim backend injects faults".into(),
        )),
    }
}

/// The device must run at the period the controller was discretised for.
fn check_device_period(
    info: &bench_hal::DeviceInfo,
    cfg: &BenchConfig,
    spec: &BackendSpec,
) -> Result<(), RunError> {
    if info.period_ns == cfg.loop_.period_ns() {
        return Ok(());
    }
    Err(RunError::option(
        "backend",
        spec,
        format!(
            "runs every {} ns, the controller was discretised for {} ns; nothing was enabled",
            info.period_ns,
            cfg.loop_.period_ns()
        ),
    ))
}

/// The recorded session of a control run.
fn control_session<'a>(
    opts: &'a ControlOptions,
    spec: &BackendSpec,
    job: &ControlJob,
    verify: bool,
    progress_ticks: Option<&'a Arc<AtomicU64>>,
    check: &'a LoopCheck,
    period_s: f64,
) -> SessionOptions<'a> {
    SessionOptions {
        command: "control",
        config_path: &opts.config_path,
        out: &opts.out,
        // Hardware runs in real time whatever the flag says.
        realtime: opts.realtime || !spec.is_sim(),
        pace: opts.pace,
        progress: opts.progress,
        seed: opts.seed,
        max_ticks: job.total_ticks(),
        keep: if verify {
            Kept::STEP_VERIFY
        } else {
            Kept::STEP
        },
        ticks: progress_ticks,
        // Closed loop: a stall longer than the loop's own bound (delay
        // margin, reach of the position limit) is the overruns or
        // link_latency fault.
        stall: Some(crate::rt::supervisor::StallBounds::of(
            check.stall.bound_s,
            period_s,
        )),
        stall_source: &check.stall.source,
    }
}

/// What the verify's analysis reads of a run.
struct VerifyRun<'a> {
    data: &'a Collected,
    /// The tick the verify's record starts at: the end of the step.
    step_ticks: usize,
    chirp: &'a Chirp,
    stalls: &'a [(u64, f64)],
    period_s: f64,
    check: &'a LoopCheck,
    model_loop: &'a ModelLoop<'a>,
}

/// The verify's analysis of a run, in the summary `s`, the recording and
/// its own CSV and figure.
fn write_verify(
    opts: &ControlOptions,
    v: &VerifyOptions,
    run: &VerifyRun<'_>,
    s: &mut Verify,
    recorder: &mut crate::record::Recorder,
    end_ns: u64,
    existing: Existing,
) -> Result<(), RunError> {
    let analysis = verify::analyze(
        run.data,
        run.step_ticks,
        run.chirp,
        &opts.config,
        run.period_s,
        run.stalls,
        &run.check.model,
        run.model_loop,
    );
    s.result = Some(analysis.result.clone());
    s.csv = Some(v.csv.clone());
    s.plot = Some(v.plot.clone());
    let title = format!(
        "S = u/d, bench control --controller {} --verify ({} A, seed {}): {}",
        opts.controller,
        v.amplitude_a,
        opts.seed,
        if analysis.result.flagged {
            "VERIFY FAILED"
        } else {
            "agrees"
        }
    );
    verify::write_outputs(
        recorder,
        end_ns,
        &analysis,
        run.model_loop,
        s,
        v,
        existing,
        &title,
    )
}

/// `--override-check` only on the sim; the outputs, before the loop
/// check's work (with `--check-only` none is written), none a file the run
/// reads (rule 6 of crate::outputs).
fn check_outputs(
    opts: &ControlOptions,
    spec: &BackendSpec,
    outputs: &mut OutputPlan,
) -> Result<(), RunError> {
    if opts.override_check && !spec.is_sim() {
        return Err(RunError::option(
            "override_check",
            "",
            format!("only allowed on the sim backend, not {spec}"),
        ));
    }
    if !opts.check_only {
        outputs.add_input("config", &opts.config_path);
        if let Some(frf) = &opts.frf {
            outputs.add_input("frf", frf);
        }
        outputs.check()?;
    }
    Ok(())
}

impl ControlSummary {
    /// The summary before the run: the controller, its loop check and the
    /// verify's plan on the host's limits.
    fn before_run(
        opts: &ControlOptions,
        ccfg: &ControllerConfig,
        check: &LoopCheck,
        spec: &BackendSpec,
        verify: Option<Verify>,
    ) -> Self {
        Self {
            controller: opts.controller.clone(),
            description: ccfg.description.clone(),
            loop_check: check.clone(),
            metrics: None,
            recording: None,
            plot: None,
            backend: spec.to_string(),
            seed: opts.seed,
            disturbance_rms_n: opts.config.plant.disturbance.map_or(0.0, |d| d.rms_n),
            link: None,
            timing: None,
            current_limits: None,
            verify,
            catalogue: None,
        }
    }
}

/// The step judged on its first `n` ticks ([`analyze_step`]), its metrics
/// recorded on `/control/metrics` at `end_ns`.
fn judge_step(
    recorder: &mut crate::record::Recorder,
    data: &Collected,
    n: usize,
    cfg: &BenchConfig,
    end_ns: u64,
) -> Result<StepAnalysis, RunError> {
    let analysis = analyze_step(
        StepSignals {
            position_m: &data.position_m[..n],
            setpoint_m: &data.setpoint_m[..n],
            current_command_a: &data.current_command_a[..n],
        },
        cfg.step.settle_s,
        cfg.step.step_m,
        cfg.step.steady_state_window_s,
        cfg.loop_.period_ns() as f64 * 1e-9,
    );
    let metrics_ch =
        recorder.add_channel_for::<StepMetrics>("/control/metrics", "bench.StepMetrics")?;
    recorder.write(metrics_ch, end_ns, &analysis.metrics)?;
    Ok(analysis)
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
    check_outputs(opts, &spec, outputs)?;
    // The loop check needs no device: with --check-only nothing is opened.
    let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
    let ctrl = DiscreteController::new(ccfg, period_s, cfg.actuator.peak_current_a);
    // The link's pure delay (EtherCAT: one period) is in the loop checked.
    let check = check_loop(
        cfg,
        &model,
        &opts.controller,
        &ctrl,
        period_s,
        measured.as_ref(),
        cfg.step.step_m,
        spec.process_data_delay_periods(),
    );
    let plant = ZohPlant::new(&model, &cfg.actuator, period_s);
    let verify = host_verify_plan(opts, &plant, &ctrl, &spec)?;
    let mut summary = ControlSummary::before_run(opts, ccfg, &check, &spec, verify);
    if opts.check_only {
        return Ok(summary);
    }
    refuse_failed_check(opts, &check)?;
    let mut stage = source.stage(
        &spec,
        cfg,
        &opts.config_path,
        opts.seed,
        opts.inject,
        check.stall.bound_s,
    )?;
    let mut runner = stage.runner();
    let info = runner.info().clone();
    summary.backend = info.name.clone();
    // Anti-windup at the peak current in force (the smaller of the
    // host's and the device's; same sections).
    let ctrl = ctrl.with_limit(cfg.current_limits(&info).peak_current_a);
    let mut job = step_job(opts, ctrl, period_s)?;
    let model_loop = ModelLoop {
        plant: &plant,
        ctrl: &ctrl,
        link_delay_periods: spec.process_data_delay_periods(),
    };
    let verify_chirp = match &opts.verify {
        Some(v) => {
            let (plan, chirp) = verify::plan(cfg, &model_loop, v, &info)?;
            if let Some(s) = summary.verify.as_mut() {
                s.plan = plan;
            }
            job = job.with_verify(chirp);
            Some(chirp)
        }
        None => None,
    };
    crate::jobs::request::refuse_pace_on_hardware(opts.pace, !spec.is_sim(), &info.name)?;
    let session = control_session(
        opts,
        &spec,
        &job,
        verify_chirp.is_some(),
        progress_ticks,
        &check,
        period_s,
    );
    let mut recorder = open_recording(&session, cfg, &info, outputs)?;
    let check_ch =
        recorder.add_channel_for::<LoopCheck>("/control/loop_check", "bench.LoopCheck")?;
    recorder.write(check_ch, 0, &check)?;
    recorder.flush_chunk()?;
    let step_ticks = job.step_ticks() as usize;
    let recorded = run_recorded(&mut runner, job, cfg, recorder, &session, stop);
    let Recorded {
        mut recorder,
        data,
        timing,
        end_ns,
        link,
        current_limits,
        stalls,
    } = recorded?;
    summary.link = link;
    summary.current_limits = Some(current_limits);

    // The step is judged on its own ticks: the verify's injection after
    // it is not part of its steady state.
    let n = step_ticks.min(data.position_m.len());
    let analysis = judge_step(&mut recorder, &data, n, &opts.config, end_ns)?;

    write_step_figure(opts, outputs.existing(), &data, n, &analysis)?;
    summary.metrics = Some(analysis.metrics);
    summary.plot = Some(opts.plot.clone());
    summary.timing = Some(timing);
    if let (Some(v), Some(chirp), Some(s)) = (&opts.verify, verify_chirp, summary.verify.as_mut()) {
        let run = VerifyRun {
            data: &data,
            step_ticks,
            chirp: &chirp,
            stalls: &stalls,
            period_s,
            check: &check,
            model_loop: &model_loop,
        };
        write_verify(opts, v, &run, s, &mut recorder, end_ns, outputs.existing())?;
    }
    let ch =
        recorder.add_channel_for::<ControlSummary>("/control/summary", "bench.ControlSummary")?;
    recorder.write(ch, end_ns, &summary)?;
    summary.recording = Some(PathBuf::from(finish(recorder)?));
    Ok(summary)
}

#[cfg(test)]
mod tests {
    /// With the verify's chirp the job is the same step, then the same
    /// controller plus the chirp: on the same readings the commands
    /// differ by exactly the chirp's value from the end of the step on,
    /// and `excitation_a` is NaN before it and the chirp after.
    #[test]
    fn the_injection_is_added_at_the_plant_input_after_the_step() {
        use super::*;
        use crate::control::verify::chirp_config;
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
        let cfg = BenchConfig::load(&path).unwrap();
        let t = 2e-4;
        let ctrl = DiscreteController::new(&cfg.controller["fast"], t, 9.98);
        let chirp = Chirp::new(&chirp_config(&cfg.chirp, 0.05, 1.0), cfg.excitation.kind, t);
        let mut plain = ControlJob::new(ctrl, 1e-5, 100, 0, 1_000);
        let mut with = ControlJob::new(ctrl, 1e-5, 100, 0, 1_000).with_verify(chirp);
        assert_eq!(with.step_ticks(), 1_000);
        assert_eq!(with.total_ticks(), 1_000 + chirp.total_ticks());
        let mut plain_done = false;
        for k in 0..with.total_ticks() {
            let sample = Sample {
                seq: k,
                device_time_ns: k * 200_000,
                position_m: 1e-6 * (k as f64 * 0.01).sin(),
                measured_current_a: f64::NAN,
                flags: Default::default(),
            };
            let a = plain.tick(k, &sample);
            let b = with.tick(k, &sample);
            plain_done |= a.done;
            assert_eq!(a.setpoint_m, b.setpoint_m, "tick {k}");
            if k < 1_000 {
                assert_eq!(a.command_a, b.command_a, "tick {k}");
                assert!(b.excitation_a.is_nan() && !b.done, "tick {k}");
            } else {
                let d = chirp.value_a(k - 1_000);
                assert_eq!(b.excitation_a, d, "tick {k}");
                assert!((b.command_a - a.command_a - d).abs() < 1e-12, "tick {k}");
            }
            assert_eq!(b.done, k + 1 == with.total_ticks(), "tick {k}");
        }
        assert!(plain_done);
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
                    probe: crate::rt::supervisor::ProbeValidity::OFF,
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
