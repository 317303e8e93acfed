//! The machinery every recorded job shares: open the recording, run the
//! real-time loop on its own thread with the writer draining the queue,
//! show progress, and turn how the loop stopped into a result.

use crate::config::BenchConfig;
use crate::error::RunError;
use crate::ident::frf::C64;
use crate::outputs::OutputPlan;
use crate::record::topics::{FaultKind, Record};
use crate::record::{spawn_writer, ChunkPolicy, Recorder};
use crate::rt::backend::{AnyStage, LinkCounters};
use crate::rt::service::{JobTicket, LoopReply, LoopRequest, ServiceClient};
use crate::rt::supervisor::{fault_message, CurrentLimits, StallBounds};
use crate::rt::{self, Job, LoopOptions, LoopReport, Pacing, RecordQueue, StopReason};
use bench_hal::DeviceInfo;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Capacity of the record queue, records (≈ 13 s at 5 kHz).
const QUEUE_CAPACITY: usize = 1 << 16;

/// How the loop of a run was paced, as its summary says.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum PacingMode {
    /// Virtual time, as fast as it goes ([`Pacing::Virtual`]).
    Virtual,
    /// Virtual time paced against the wall clock at `pace_factor` × real
    /// time ([`Pacing::Paced`]).
    Paced,
    /// Real time: absolute deadlines ([`Pacing::RealTime`]).
    Realtime,
}

impl PacingMode {
    /// The mode's name, as serialised (`virtual`, `paced`, `realtime`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Virtual => "virtual",
            Self::Paced => "paced",
            Self::Realtime => "realtime",
        }
    }
}

/// Loop timing in the summary.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct TimingSummary {
    /// Ticks run.
    pub ticks: u64,
    /// Pacing: `virtual` (virtual time as fast as it goes), `paced`
    /// (virtual time paced against the wall clock at `pace_factor`) or
    /// `realtime` (absolute deadlines).
    pub mode: PacingMode,
    /// The factor of real time a `paced` run was paced at (1: real time,
    /// 0.1: ten times slower, 10: ten times faster); absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pace_factor: Option<f64>,
    /// Ticks a `paced` run released per sleep (as many as fit in 1 ms of
    /// wall time, at least 1; [`crate::rt::pace_batch_ticks`]); absent
    /// otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pace_batch_ticks: Option<u64>,
    /// Loop rate, Hz.
    pub rate_hz: f64,
    /// Median wake-up latency (actual wake − deadline), µs: the headline
    /// figure. 0 in unpaced virtual time; in `paced` mode, how late each
    /// batch was released behind its schedule (one value per batch; caught
    /// up, never a fault: virtual time has no deadline). Quantiles come
    /// from an HDR histogram and are at most 1 % above the true value.
    pub wake_latency_p50_us: f64,
    /// Wake-up latency p99, µs (0 in unpaced virtual time).
    pub wake_latency_p99_us: f64,
    /// Wake-up latency p99.9, µs (0 in unpaced virtual time).
    pub wake_latency_p999_us: f64,
    /// Largest wake-up latency, µs (exact).
    pub wake_latency_max_us: f64,
    /// Mean wake-up latency, µs (one preemption can dominate it; the median
    /// is the figure to quote).
    pub wake_latency_mean_us: f64,
    /// Median compute time per tick (wake timestamp → command written,
    /// less one clock read), µs: the headline figure.
    pub compute_p50_us: f64,
    /// Compute time p99, µs.
    pub compute_p99_us: f64,
    /// Compute time p99.9, µs.
    pub compute_p999_us: f64,
    /// Largest compute time, µs (exact).
    pub compute_max_us: f64,
    /// Mean compute time per tick, µs (one preemption can dominate it).
    pub compute_mean_us: f64,
    /// `/dev/cpu_dma_latency`: `held at 0 µs`, `unavailable (reason)` or
    /// `not requested (virtual time)`.
    pub cpu_dma_latency: String,
    /// Ticks that ended after the next deadline.
    pub overruns: u64,
    /// Records dropped because the writer fell behind.
    pub dropped_records: u64,
    /// Wall time of the loop, s.
    pub wall_s: f64,
    /// Real-time setup warnings.
    pub warnings: Vec<String>,
}

impl TimingSummary {
    /// The summary's loop lines, as `bench chirp` and `bench control`
    /// print them: medians first, then p99, p99.9 and max, µs.
    pub fn lines(&self) -> Vec<String> {
        let q = |p50: f64, p99: f64, p999: f64, max: f64, mean: f64| {
            format!("p50 {p50:.2} µs, p99 {p99:.2} µs, p99.9 {p999:.2} µs, max {max:.1} µs (mean {mean:.2} µs)")
        };
        let measured = q(
            self.wake_latency_p50_us,
            self.wake_latency_p99_us,
            self.wake_latency_p999_us,
            self.wake_latency_max_us,
            self.wake_latency_mean_us,
        );
        let factor = self.pace_factor.unwrap_or(f64::NAN);
        let (mode, wake) = match self.mode {
            PacingMode::Virtual => ("virtual".to_string(), "none (virtual time)".to_string()),
            PacingMode::Paced => (
                format!("virtual, paced at {factor}× real time"),
                format!(
                    "{measured}: behind the paced schedule, one release per {} ticks (caught up; virtual time has no deadline)",
                    self.pace_batch_ticks.unwrap_or(1)
                ),
            ),
            PacingMode::Realtime => ("realtime".to_string(), measured),
        };
        vec![
            format!(
                "loop: {} ticks at {:.0} Hz ({}), {:.2} s wall; overruns {}; dropped {}; /dev/cpu_dma_latency {}",
                self.ticks,
                self.rate_hz,
                mode,
                self.wall_s,
                self.overruns,
                self.dropped_records,
                self.cpu_dma_latency
            ),
            format!("  wake-up latency {wake}"),
            format!(
                "  compute         {}",
                q(
                    self.compute_p50_us,
                    self.compute_p99_us,
                    self.compute_p999_us,
                    self.compute_max_us,
                    self.compute_mean_us
                )
            ),
        ]
    }

    fn new(r: &LoopReport, pacing: Pacing, period_ns: u64, wall_s: f64) -> Self {
        let t = &r.timing;
        let (mode, pace_factor) = match pacing {
            Pacing::Virtual => (PacingMode::Virtual, None),
            Pacing::Paced { factor } => (PacingMode::Paced, Some(factor)),
            Pacing::RealTime { .. } => (PacingMode::Realtime, None),
        };
        Self {
            ticks: r.ticks,
            mode,
            pace_factor,
            pace_batch_ticks: pace_factor.map(|f| crate::rt::pace_batch_ticks(period_ns, f)),
            rate_hz: 1e9 / period_ns as f64,
            wake_latency_p50_us: t.wake.p50_ns * 1e-3,
            wake_latency_p99_us: t.wake.p99_ns * 1e-3,
            wake_latency_p999_us: t.wake.p999_ns * 1e-3,
            wake_latency_max_us: t.wake.max_ns * 1e-3,
            wake_latency_mean_us: t.wake.mean_ns * 1e-3,
            compute_p50_us: t.compute.p50_ns * 1e-3,
            compute_p99_us: t.compute.p99_ns * 1e-3,
            compute_p999_us: t.compute.p999_ns * 1e-3,
            compute_max_us: t.compute.max_ns * 1e-3,
            compute_mean_us: t.compute.mean_ns * 1e-3,
            cpu_dma_latency: r.cpu_dma_latency.to_string(),
            overruns: t.overruns,
            dropped_records: r.dropped_records,
            wall_s,
            warnings: r.warnings.clone(),
        }
    }
}

/// Per-tick signals kept by the writer for the analysis after the run.
#[derive(Debug, Default, Clone)]
pub struct Collected {
    /// Loop time, s.
    pub t_s: Vec<f64>,
    /// Probe reading, m.
    pub position_m: Vec<f64>,
    /// Setpoint, m (NaN in open loop).
    pub setpoint_m: Vec<f64>,
    /// Command after the supervisor, A.
    pub current_command_a: Vec<f64>,
    /// Excitation part of the command, A (NaN where none runs).
    pub excitation_a: Vec<f64>,
    /// The FRF record, packed: excitation (A) + i · probe reading (m), 16
    /// bytes a tick, with room reserved for the FFT's zero padding
    /// ([`crate::ident::frf::Spectra::from_record`] transforms it in place).
    pub frf_record: Vec<C64>,
    /// Stall events: tick, length (s).
    pub stalls: Vec<(u64, f64)>,
}

/// Which columns of [`Collected`] a job keeps; the others stay empty.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Kept {
    /// [`Collected::t_s`]
    pub t_s: bool,
    /// [`Collected::position_m`]
    pub position_m: bool,
    /// [`Collected::setpoint_m`]
    pub setpoint_m: bool,
    /// [`Collected::current_command_a`]
    pub current_command_a: bool,
    /// [`Collected::excitation_a`]
    pub excitation_a: bool,
    /// [`Collected::frf_record`]
    pub frf_record: bool,
}

impl Kept {
    /// A chirp's FRF estimate: excitation and position, packed (16 bytes a
    /// tick, and the FFT runs in them).
    pub const CHIRP: Self = Self {
        t_s: false,
        position_m: false,
        setpoint_m: false,
        current_command_a: false,
        excitation_a: false,
        frf_record: true,
    };
    /// A closed-loop step's metrics and plot: no excitation (32 bytes a
    /// tick).
    pub const STEP: Self = Self {
        t_s: true,
        position_m: true,
        setpoint_m: true,
        current_command_a: true,
        excitation_a: false,
        frf_record: false,
    };
    /// A closed-loop step followed by the verify's injection: the step's
    /// columns and the injection (40 bytes a tick).
    pub const STEP_VERIFY: Self = Self {
        excitation_a: true,
        ..Self::STEP
    };
}

/// Finishes the recording, returning its path for messages.
///
/// # Errors
/// [`RunError::Record`] with the recorder's error.
pub fn finish(recorder: Recorder) -> Result<String, RunError> {
    let path = recorder.finish()?;
    Ok(path.display().to_string())
}

/// What a recorded run needs besides the job.
#[derive(Debug, Clone, Copy)]
pub struct SessionOptions<'a> {
    /// Job name (`chirp`, `control`), recorded and shown.
    pub command: &'static str,
    /// Where the config came from.
    pub config_path: &'a Path,
    /// The recording.
    pub out: &'a Path,
    /// Real-time pacing.
    pub realtime: bool,
    /// Without `realtime`: virtual time paced at this factor of real time
    /// ([`Pacing::Paced`]); `None`: as fast as it goes.
    pub pace: Option<f64>,
    /// Show a progress bar (real-time or paced).
    pub progress: bool,
    /// Simulator seed.
    pub seed: u64,
    /// Tick budget (the job normally ends first).
    pub max_ticks: u64,
    /// The per-tick signals the job's analysis reads: only these are
    /// collected (and their memory reserved up front, `max_ticks` each).
    pub keep: Kept,
    /// Where the loop publishes its tick count (a watcher's progress), if
    /// anywhere.
    pub ticks: Option<&'a Arc<AtomicU64>>,
    /// The job's stall bounds: a closed loop's from its loop check
    /// ([`crate::control::loop_check::StallLimit`]); `None`: only the
    /// user's `safety.max_overrun_s` / `max_command_latency_s`, if set
    /// (open-loop identification).
    pub stall: Option<crate::rt::supervisor::StallBounds>,
    /// Where the stall bound comes from, for fault messages (empty: the
    /// config keys).
    pub stall_source: &'a str,
}

impl SessionOptions<'_> {
    /// How the loop runs: real time, paced virtual time or virtual time.
    pub fn pacing(&self, cfg: &BenchConfig) -> Pacing {
        match (self.realtime, self.pace) {
            (true, _) => Pacing::RealTime {
                priority: cfg.loop_.priority,
                cpu: cfg.loop_.cpu,
            },
            (false, Some(factor)) => Pacing::Paced { factor },
            (false, None) => Pacing::Virtual,
        }
    }

    /// The mode of [`Self::pacing`], as the summary and the recording
    /// name it.
    pub fn pacing_mode(&self) -> PacingMode {
        match (self.realtime, self.pace) {
            (true, _) => PacingMode::Realtime,
            (false, Some(_)) => PacingMode::Paced,
            (false, None) => PacingMode::Virtual,
        }
    }
}

/// A run that finished its job.
#[derive(Debug)]
pub struct Recorded {
    /// The recording, open for the job's results.
    pub recorder: Recorder,
    /// The per-tick signals.
    pub data: Collected,
    /// Loop timing.
    pub timing: TimingSummary,
    /// Log time of the end of the run, ns.
    pub end_ns: u64,
    /// Link counters of this job (hardware backends), as JSON.
    pub link: Option<serde_json::Value>,
    /// The current limits in force and where each came from.
    pub current_limits: CurrentLimits,
    /// The stalls seen (`/bench/event` `stall`): the tick at which each
    /// ended and how long it was, s.
    pub stalls: Vec<(u64, f64)>,
}

/// Where a recorded job runs.
pub enum Runner<'a> {
    /// A stage opened for this run: the loop runs this one job on a thread
    /// of its own and gives the stage back disabled at 0 A.
    Local {
        /// The configured stage.
        stage: &'a mut AnyStage,
        /// What it reported.
        info: &'a DeviceInfo,
    },
    /// The daemon's loop, which runs the hold job before and after.
    Service(&'a mut ServiceClient),
}

impl Runner<'_> {
    /// The device the job runs on.
    pub fn info(&self) -> &DeviceInfo {
        match self {
            Self::Local { info, .. } => info,
            Self::Service(c) => &c.info,
        }
    }
}

/// The config file's text as given (comments and layout; recorded as
/// `bench.config` `source`, so `bench fit --update` can keep them): the
/// built-in text, or the file at `path` read as every config is
/// ([`crate::config::read_text`]: a regular file of at most
/// [`crate::config::MAX_CONFIG_BYTES`], never a FIFO read twice).
/// `None` when it cannot be read again.
fn config_source(path: &Path) -> Option<String> {
    if path == Path::new(crate::config::BUILTIN_CONFIG_NAME) {
        return Some(crate::config::BUILTIN_CONFIG_TOML.to_string());
    }
    crate::config::read_text(path).ok()
}

/// Creates the recording `opts.out` (as `.part`, by the rules of
/// `outputs`: the claimed `.part` file if `outputs` holds one) with the
/// resolved config and the run description as metadata.
///
/// # Errors
/// [`RunError::BadOption`] naming `out` when the file cannot be created.
pub fn open_recording(
    opts: &SessionOptions,
    cfg: &BenchConfig,
    info: &DeviceInfo,
    outputs: &mut OutputPlan,
) -> Result<Recorder, RunError> {
    let mut recorder =
        Recorder::create_with(opts.out, outputs.existing(), outputs.take_claimed_part())
            .map_err(|e| RunError::option("out", "", e.to_string()))?;
    let start = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    let start_ns = u64::try_from(start.as_nanos()).unwrap_or(u64::MAX);
    recorder.set_time_origin_ns(start_ns);
    let toml = cfg.to_toml();
    let config_sha256 = cfg.sha256_hex();
    let mut meta = BTreeMap::new();
    meta.insert("toml".to_string(), toml);
    meta.insert("path".to_string(), opts.config_path.display().to_string());
    if let Some(source) = config_source(opts.config_path) {
        meta.insert("source".to_string(), source);
    }
    meta.insert("sha256".to_string(), config_sha256.clone());
    recorder.write_metadata("bench.config", &meta)?;
    let mut run_meta = BTreeMap::new();
    run_meta.insert("command".to_string(), opts.command.to_string());
    run_meta.insert("backend".to_string(), info.name.clone());
    run_meta.insert("seed".to_string(), opts.seed.to_string());
    let mode = opts.pacing_mode();
    run_meta.insert("mode".to_string(), mode.as_str().to_string());
    if let (PacingMode::Paced, Some(f)) = (mode, opts.pace) {
        run_meta.insert("pace_factor".to_string(), f.to_string());
    }
    run_meta.insert(
        "rate_hz".to_string(),
        (1e9 / info.period_ns as f64).to_string(),
    );
    run_meta.insert("version".to_string(), env!("CARGO_PKG_VERSION").to_string());
    run_meta.insert("start_time_unix_ns".to_string(), start_ns.to_string());
    run_meta.insert(
        "start_time_utc".to_string(),
        time::OffsetDateTime::from_unix_timestamp_nanos(i128::from(start_ns))
            .ok()
            .and_then(|t| {
                t.format(&time::format_description::well_known::Rfc3339)
                    .ok()
            })
            .unwrap_or_default(),
    );
    run_meta.insert("host".to_string(), host_name());
    // The current limits in force and where each came from (the host's
    // config or the device), as JSON.
    run_meta.insert(
        "current_limits".to_string(),
        serde_json::to_string(&cfg.current_limits(info)).unwrap_or_default(),
    );
    run_meta.insert("config_sha256".to_string(), config_sha256);
    run_meta.insert(
        "log_time_unit".to_string(),
        "ns since the Unix epoch: start_time_unix_ns + loop time (tick × period)".to_string(),
    );
    recorder.write_metadata("bench.run", &run_meta)?;
    Ok(recorder)
}

/// This machine's host name (`gethostname`), empty if it has none.
fn host_name() -> String {
    let mut buf = [0u8; 256];
    // SAFETY: `buf` is valid for `buf.len()` bytes; gethostname writes at
    // most that many and we read up to the first NUL within them.
    let rc = unsafe { libc::gethostname(buf.as_mut_ptr().cast(), buf.len()) };
    if rc != 0 {
        return String::new();
    }
    let end = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
    String::from_utf8_lossy(&buf[..end]).into_owned()
}

impl Collected {
    /// Room for `n` ticks in each column `keep` keeps (the FRF record at
    /// its FFT length), none in the others.
    fn reserved(keep: Kept, n: usize) -> Self {
        let reserve = |kept: bool| Vec::with_capacity(if kept { n } else { 0 });
        Self {
            t_s: reserve(keep.t_s),
            position_m: reserve(keep.position_m),
            setpoint_m: reserve(keep.setpoint_m),
            current_command_a: reserve(keep.current_command_a),
            excitation_a: reserve(keep.excitation_a),
            frf_record: Vec::with_capacity(if keep.frf_record {
                crate::ident::frf::fast_len(n)
            } else {
                0
            }),
            stalls: Vec::new(),
        }
    }
}

/// Collects one record on the writer thread (never the real-time one):
/// the kept columns of a sample, the stalls of the events.
fn collect(sink: &Mutex<Collected>, keep: Kept, r: &Record) {
    if let Record::Event(e) = r {
        if e.kind == crate::record::topics::EventKind::Stall {
            sink.lock()
                .expect("collector poisoned")
                .stalls
                .push((e.tick, e.value));
        }
        return;
    }
    if let Record::Sample(s) = r {
        let mut c = sink.lock().expect("collector poisoned");
        let push = |v: &mut Vec<f64>, kept: bool, x: f64| {
            if kept {
                v.push(x);
            }
        };
        push(&mut c.t_s, keep.t_s, s.t_s);
        push(&mut c.position_m, keep.position_m, s.position_m);
        push(&mut c.setpoint_m, keep.setpoint_m, s.setpoint_m);
        push(
            &mut c.current_command_a,
            keep.current_command_a,
            s.current_command_a,
        );
        push(&mut c.excitation_a, keep.excitation_a, s.excitation_a);
        if keep.frf_record {
            c.frf_record.push(C64::new(s.excitation_a, s.position_m));
        }
    }
}

/// The error of a run whose writer died on a write error: the loop saw its
/// queue abandoned and stopped on the `recording` fault (0 A, disabled).
/// What was written stays in the `.part` file, which is not renamed.
fn writer_failed(
    e: crate::record::RecordError,
    stop: &StopReason,
    part_path: &Path,
    opts: &SessionOptions,
    info: &DeviceInfo,
    current_limits: CurrentLimits,
) -> RunError {
    match *stop {
        StopReason::Fault {
            kind: FaultKind::Recording,
            value,
            tick,
            ..
        } => RunError::Fault {
            kind: FaultKind::Recording.as_str(),
            value,
            detail: format!("the recording failed: {}", crate::error::error_chain(&e)),
            tick,
            recording: format!("incomplete, left as {}", part_path.display()),
            context: Box::new(serde_json::json!({
                "command": opts.command,
                "backend": info.name,
                "current_limits": current_limits,
            })),
        },
        _ => RunError::Record(e),
    }
}

/// The recorder of a run that finished; a run that stopped otherwise
/// (fault, HAL error, interrupt, tick limit) has its recording finished
/// and returns the error, a fault's with its message (`safety`'s bounds)
/// and `context`.
fn unless_stopped(
    stop: StopReason,
    recorder: Recorder,
    opts: &SessionOptions,
    safety: &crate::rt::supervisor::SupervisorConfig,
    context: serde_json::Value,
) -> Result<Recorder, RunError> {
    match stop {
        StopReason::Finished => Ok(recorder),
        StopReason::Fault {
            kind,
            value,
            tick,
            detail,
            stall,
        } => {
            let recording = finish(recorder)?;
            let source = if opts.stall_source.is_empty() {
                match kind {
                    FaultKind::LinkLatency => "safety.max_command_latency_s",
                    _ => "safety.max_overrun_s",
                }
            } else {
                opts.stall_source
            };
            let message = fault_message(kind, value, safety, stall, source, detail.as_deref());
            Err(RunError::Fault {
                kind: kind.as_str(),
                value,
                detail: message,
                tick,
                recording,
                context: Box::new(context),
            })
        }
        StopReason::Hal { message, tick } => {
            let recording = finish(recorder)?;
            Err(RunError::Hal {
                message,
                tick,
                recording,
            })
        }
        StopReason::Interrupted { tick } => {
            let recording = finish(recorder)?;
            Err(RunError::Interrupted { tick, recording })
        }
        StopReason::TickLimit => {
            let recording = finish(recorder)?;
            Err(RunError::TickLimit {
                job: opts.command,
                recording,
            })
        }
    }
}

/// Runs `job` on `stage` (configured, described by `info`) into `recorder`.
/// The loop thread borrows the stage and gives it back disabled at 0 A
/// whatever happens, so an owner (the daemon) keeps its device across jobs.
/// `stop` is raised by SIGINT/SIGTERM.
///
/// # Errors
/// [`RunError::Fault`], [`RunError::Hal`], [`RunError::Interrupted`] with
/// the recording finished and the amplifier disabled; [`RunError::Thread`]
/// or [`RunError::Record`] for thread or recording failures.
pub fn run_recorded<J: Job + Send + 'static>(
    runner: &mut Runner<'_>,
    job: J,
    cfg: &BenchConfig,
    recorder: Recorder,
    opts: &SessionOptions,
    stop: Arc<AtomicBool>,
) -> Result<Recorded, RunError> {
    let info = runner.info().clone();
    let period_s = info.period_ns as f64 * 1e-9;
    let (producer, consumer) = RecordQueue::new(QUEUE_CAPACITY);
    // The config bounds a job to `ranges::JOB_TICKS_MAX` ticks; reserve
    // only the columns the job reads.
    let n = opts.max_ticks.min(crate::config::ranges::JOB_TICKS_MAX) as usize;
    let keep = opts.keep;
    let collected = Arc::new(Mutex::new(Collected::reserved(keep, n)));
    let sink = Arc::clone(&collected);
    let writer_done = Arc::new(AtomicBool::new(false));
    let part_path = recorder.part_path().to_path_buf();
    // Runs on the writer thread (never the real-time one).
    let writer = spawn_writer(
        consumer,
        Arc::clone(&producer.room),
        recorder,
        Arc::clone(&writer_done),
        if opts.realtime {
            ChunkPolicy::REAL_TIME
        } else {
            ChunkPolicy::VIRTUAL_TIME
        },
        // One below the loop's priority, in real-time runs only.
        opts.realtime
            .then(|| cfg.loop_.priority.saturating_sub(1).max(1)),
        move |r| collect(&sink, keep, r),
    );

    let loop_opts = LoopOptions {
        period_ns: info.period_ns,
        pacing: opts.pacing(cfg),
        timing_interval_ticks: ((cfg.loop_.timing_interval_s / period_s).round() as u64).max(1),
        safety: cfg.supervisor(&info),
        max_ticks: opts.max_ticks,
    };
    let mut loop_opts = loop_opts;
    if let Some(b) = opts.stall {
        loop_opts.safety.max_missed_deadlines = b.max_missed_deadlines;
        loop_opts.safety.max_late_commands = b.max_late_commands;
    }
    let stall = StallBounds {
        max_missed_deadlines: loop_opts.safety.max_missed_deadlines,
        max_late_commands: loop_opts.safety.max_late_commands,
    };
    let current_limits = cfg.current_limits(&info);
    let wall = Instant::now();
    let progress = opts.ticks.cloned().unwrap_or_default();
    let (report, link) = match runner {
        Runner::Local { stage, .. } => {
            let report = run_local(
                stage, info.clock, job, &loop_opts, producer, &stop, &progress, opts,
            )?;
            (report, stage.link_stats())
        }
        Runner::Service(client) => {
            let ticket = Box::new(JobTicket {
                job: Box::new(job),
                out: producer,
                max_ticks: opts.max_ticks,
                seed: opts.seed,
                stall,
                // A job in virtual time (paced or not) on the daemon's
                // real-time loop.
                pacing: (!opts.realtime).then_some(loop_opts.pacing),
                stop: Arc::clone(&stop),
                progress: Arc::clone(&progress),
                end: None,
                link: None,
                old_hold: None,
            });
            match client.call(LoopRequest::Job(ticket)) {
                Some(LoopReply::JobDone(mut ticket)) => match ticket.end.take() {
                    // The ticket is dropped here, off the real-time thread.
                    Some(end) => (
                        end.into_report(Vec::new()),
                        ticket.link.map(|(b, a)| LinkCounters::between(b, a)),
                    ),
                    None => return Err(RunError::Thread("the daemon's loop lost a job".into())),
                },
                _ => return Err(RunError::Thread("the daemon's loop is gone".into())),
            }
        }
    };
    let wall_s = wall.elapsed().as_secs_f64();
    writer_done.store(true, Ordering::Release);
    let written = writer
        .join()
        .map_err(|_| RunError::Thread("the writer thread panicked".into()))?;
    let (recorder, _stats) = match written {
        Ok(w) => w,
        // The writer died on a write error: the loop saw its queue
        // abandoned and stopped on the `recording` fault (0 A, disabled).
        // What was written stays in the `.part` file, which is not renamed.
        Err(e) => {
            return Err(writer_failed(
                e,
                &report.stop,
                &part_path,
                opts,
                &info,
                current_limits,
            ))
        }
    };
    let timing = TimingSummary::new(&report, loop_opts.pacing, info.period_ns, wall_s);
    for w in &timing.warnings {
        tracing::warn!("{w}");
    }

    let end_ns = crate::record::log_time_ns(report.ticks as f64 * period_s);
    let context = serde_json::json!({
        "command": opts.command,
        "backend": info.name,
        "current_limits": current_limits,
        "timing": timing,
        "link": link,
    });
    let recorder = unless_stopped(report.stop, recorder, opts, &loop_opts.safety, context)?;
    let data = std::mem::take(&mut *collected.lock().expect("collector poisoned"));
    let stalls = data.stalls.clone();
    Ok(Recorded {
        recorder,
        data,
        timing,
        end_ns,
        link,
        current_limits,
        stalls,
    })
}

/// Runs `job` in a loop of its own on a scoped real-time thread (the stage
/// comes back disabled at 0 A), with the progress bar if asked.
#[allow(clippy::too_many_arguments)]
fn run_local<J: Job + Send>(
    stage: &mut AnyStage,
    clock: bench_hal::Clock,
    mut job: J,
    loop_opts: &LoopOptions,
    mut producer: RecordQueue,
    stop: &AtomicBool,
    progress: &AtomicU64,
    opts: &SessionOptions,
) -> Result<LoopReport, RunError> {
    std::thread::scope(|scope| {
        let rt_thread = std::thread::Builder::new()
            .name("bench-rt".into())
            .spawn_scoped(scope, || {
                rt::run(
                    stage,
                    &mut job,
                    loop_opts,
                    clock,
                    &mut producer,
                    stop,
                    progress,
                )
            })
            .map_err(|e| RunError::Thread(format!("cannot spawn the real-time thread: {e}")))?;
        if (opts.realtime || opts.pace.is_some()) && opts.progress {
            let bar = indicatif::ProgressBar::new(opts.max_ticks);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    &format!("{{spinner}} {} [{{bar:40}}] {{percent:>3}}% {{elapsed_precise}} / ~{{duration_precise}}", opts.command),
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            while !rt_thread.is_finished() {
                bar.set_position(progress.load(Ordering::Relaxed));
                std::thread::sleep(Duration::from_millis(100));
            }
            bar.finish_and_clear();
        }
        rt_thread
            .join()
            .map_err(|_| RunError::Thread("the real-time thread panicked".into()))
    })
}
