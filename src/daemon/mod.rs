//! `bench serve`: the daemon that owns the bench (README, *`bench serve`: the daemon*).
//!
//! The backend is opened once; one real-time loop ([`crate::rt::service`])
//! with one supervisor runs it for the daemon's life: the hold job between
//! jobs (every safety rule applies, faults latch), jobs handed over on a
//! tick. The **owner thread** (`owner.rs`) is the daemon's side of that loop:
//! it starts each job on a worker thread that prepares it (recording, loop
//! check), relays the worker's requests to the loop, and keeps the state
//! `status` shows; a job stopped during its preparation is abandoned
//! before it reaches the loop. What each request becomes (its options,
//! with the daemon's output names) and the library job that runs it live
//! in `jobs.rs`: chirp and control drive the bench through the loop; fit,
//! design, analyze, map, plot and campaign only compute (from files and the model, a
//! campaign on the simulator) and never touch the bench, but they hold
//! the one job slot all the same. The **socket side** (`socket.rs`) is a single-threaded tokio
//! runtime serving JSON lines on a Unix domain socket; it talks to the
//! owner through a channel, so nothing on it can block the loop. The wire
//! format lives in `protocol.rs`, the client of `--daemon` in [`client`].
//! With `--metrics`, [`metrics`] serves Prometheus metrics from a thread
//! and runtime of its own: the loop hands it its counts wait-free
//! ([`crate::rt::tap`]), the owner thread its jobs and faults.
//! The CLI uses it (its layer rule is at the end of this header).
//!
//! # Protocol
//!
//! One JSON object per line. A request is
//! `{"id": ANY, "cmd": NAME, "params": {...}}` (`id` and `params` optional).
//! Each request gets exactly one response with the same `id`:
//! `{"id": .., "ok": true, "result": {...}}` or
//! `{"id": .., "ok": false, "error": {"kind": KIND, "message": ".."}}`;
//! a job that ended on a fault, a HAL error or a stop, with its recording
//! finished, adds `"summary"` to the error: the run's outcome, fault,
//! recording and catalogue row, as the local CLI's `--json` prints them.
//! Events are lines with an `"event"` key and no `id`.
//!
//! | cmd | params | result |
//! |---|---|---|
//! | `status` | – | state, fault and cause, job and progress, backend, last reading, the store of `--upload` |
//! | `enable` / `disable` | – | amplifier enabled at 0 A / disabled (refused while faulted) |
//! | `reset` | – | clears a latched fault (back to `disabled`) |
//! | `chirp` | the fields of a [`ChirpRequest`], and `detach` | the `bench chirp --json` summary |
//! | `control` | the fields of a [`ControlRequest`], and `detach` | the `bench control --json` summary |
//! | `fit` | the fields of a [`FitRequest`], and `detach` | the `bench fit --json` summary |
//! | `design` | the fields of a [`DesignRequest`], and `detach` | the `bench design --json` summary |
//! | `analyze` | the fields of an [`AnalyzeRequest`], and `detach` | the `bench analyze --json` summary |
//! | `map` | the fields of a [`MapRequest`], and `detach` | the `bench map --json` summary |
//! | `plot` | the fields of a [`PlotRequest`], and `detach` | the `bench plot bode\|nyquist --json` summary |
//! | `campaign` | the fields of a [`CampaignRequest`], and `detach` | the `bench campaign run --json` summary |
//! | `catalogue` | the fields of a [`CatalogueRequest`], and `detach` | the `bench catalogue --json` summary |
//! | `export` | the fields of an [`ExportRequest`], and `detach` | the `bench export --json` summary |
//! | `recover` | the fields of a [`RecoverRequest`], and `detach` | the `bench recover --json` summary |
//! | `upload` | the fields of an [`UploadRequest`], and `detach` | the `bench upload --json` summary (the store's credentials are the daemon's environment's; `stop` ends it, keeping every local file) |
//! | `track` | the fields of a [`TrackRequest`], and `detach` | the `bench track --json` summary (the trials in `track-<UTC>-job<N>/`; progress counts trials) |
//! | `stop` | – | the running job stops safely (0 A, recording finished) |
//! | `subscribe` | – | this connection receives every event from now on |
//! | `shutdown` | – | stops the job, then the daemon |
//!
//! [`ChirpRequest`]: crate::jobs::request::ChirpRequest
//! [`ControlRequest`]: crate::jobs::request::ControlRequest
//! [`FitRequest`]: crate::jobs::fit::FitRequest
//! [`DesignRequest`]: crate::jobs::design::DesignRequest
//! [`AnalyzeRequest`]: crate::jobs::analyze::AnalyzeRequest
//! [`MapRequest`]: crate::jobs::map::MapRequest
//! [`PlotRequest`]: crate::jobs::plot::PlotRequest
//! [`CampaignRequest`]: crate::jobs::request::CampaignRequest
//! [`CatalogueRequest`]: crate::jobs::catalogue::CatalogueRequest
//! [`ExportRequest`]: crate::jobs::export::ExportRequest
//! [`RecoverRequest`]: crate::jobs::recover::RecoverRequest
//! [`UploadRequest`]: crate::jobs::request::UploadRequest
//! [`TrackRequest`]: crate::jobs::track_request::TrackRequest
//!
//! The jobs that compute take their files by absolute path (the daemon's
//! working directory is not its clients'), read them with the daemon's
//! permissions, and write their outputs in the recordings directory under
//! stamped names (`fit-<UTC>-job<N>.fit.png`, `analyze-…-job<N>.modes.png`,
//! `map-…-job<N>.png`, `plot-…-job<N>.bode.png`, `campaign-…-job<N>/`,
//! `catalogue-…-job<N>.parquet`, `export-…-job<N>.bench-sample.csv`,
//! `recover-…-job<N>.mcap`); the request names none. Each job's outputs
//! are planned by the same function as the CLI's (`plan_*` with a
//! [`crate::outputs::Destination`]) where the job has one.
//! Their summaries are the local run's.
//!
//! Lines are at most [`MAX_LINE_BYTES`], UTF-8, one JSON object with no
//! key twice at any level; the `id` is echoed byte for byte (any JSON
//! value). Each client has at most [`MAX_PENDING_BYTES`] of output queued
//! and at most [`MAX_CLIENTS`] are served at once (see the constants).
//!
//! Error kinds: `bad_request` (not UTF-8, not JSON, a duplicate key, no
//! `cmd`, a line too long), `unknown_command`,
//! `bad_params`, `busy` (a job is running), `faulted` (reset first),
//! `refused` (loop check), `fault`, `hal`, `interrupted`, `error`.
//!
//! **One job at a time**: a second job gets `busy`. Jobs are never queued.
//!
//! **Unattended rule**: when the client that submitted a job disconnects,
//! the job is stopped safely (0 A, recording finished), unless the request
//! said `"detach": true`. A detached job runs to its own end and no
//! further. A client is gone when its socket hangs up (it closed its end)
//! or a write to it fails; one that only shut down its sending side (end
//! of input, as `socat` does) still gets its job's events and answer, and
//! the daemon closes the connection once everything is answered.
//!
//! Layer rule: may use `analysis`, `campaign`, `config`, `control`, `design`, `error`, `ident`, `job_memory`, `jobs`, `outputs`, `plot`, `record`, `rt`, `upload`, `vocab`.

pub mod client;
mod jobs;
pub mod metrics;
mod owner;
mod protocol;
mod socket;
pub mod testing;
mod uploads;

/// The longest request line the daemon reads, in bytes (the newline not
/// counted). A longer line gets a `bad_request` answer naming this limit
/// and the connection is closed; the rest of the line is never read.
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// Answers and events queued for one client and not yet taken by its
/// socket, in bytes (about 2000 `status` answers). A client that lets its
/// queue reach this (it sends requests and does not read the answers) is
/// disconnected; other clients are not slowed down.
pub const MAX_PENDING_BYTES: usize = 1024 * 1024;

/// How long one write to a client may wait for room in its socket, in
/// seconds, before the client is disconnected as not reading.
pub const WRITE_STALL_TIMEOUT_S: u64 = 10;

/// How often a client that has shut down its sending side (end of input,
/// as `socat` does) is checked for having gone away altogether, in
/// milliseconds. Such a client's attached job runs on until it hangs up
/// (closes its socket) or a write to it fails; it is then stopped within
/// this time.
pub const CLIENT_GONE_POLL_MS: u64 = 100;

/// Clients connected at once. One more is answered `busy` ("too many
/// clients") and closed.
pub const MAX_CLIENTS: usize = 64;

/// How long the daemon stops accepting after running out of file
/// descriptors, in milliseconds. The client that could not be accepted is
/// answered `busy` and closed through a reserved descriptor; connected
/// clients keep being served.
pub const ACCEPT_BACKOFF_MS: u64 = 100;

/// How long a stopped job has to end, in milliseconds, before it is
/// abandoned: its slot is freed, the amplifier disabled at 0 A, its client
/// answered `interrupted`, and its thread left to end on its own (`status`
/// lists it under `abandoned_jobs` until it does). What a job does after
/// `stop` sets it: a bench job's loop ends within one tick, and its
/// worker then finishes the recording, the tail of at most one chunk
/// (chunks close every 50 ms, `record::writer::ChunkPolicy::REAL_TIME`),
/// the summary and the index, written and synced: 8 ms here
/// (`tests/cli/daemon_hostile.rs` measures it). A campaign's cells stop the
/// same way. A job that computes (fit, design, plot…) does not look at
/// `stop`: it is abandoned after this time. One second leaves a slow or
/// busy disk a hundred times that, and the rest of [`SHUTDOWN_BOUND_MS`]
/// for disabling the amplifier and leaving.
pub const JOB_STOP_TIMEOUT_MS: u64 = 1000;

/// SIGTERM or SIGINT ends the daemon within this, in milliseconds, whatever
/// its job does: the job is stopped and given [`JOB_STOP_TIMEOUT_MS`],
/// then abandoned; the amplifier is disabled at 0 A, the loop and the
/// socket closed, and the process exits. A thread blocked in a read (a
/// FIFO) cannot be ended: the process exits around it.
pub const SHUTDOWN_BOUND_MS: u64 = 2000;

/// How long `bench serve --upload` waits for the store's first answer
/// before it opens the bench, in milliseconds. A store that refuses
/// within it (no such bucket, credentials refused, an `http://` endpoint
/// not allowed) stops the daemon (exit 2, naming `--upload`); one that
/// has not answered by then does not hold the daemon: it opens the bench
/// and its socket, and the probe goes on in the background, bounded by
/// `--store-timeout` and tried again while the store does not answer
/// (`status` shows the store's `state`: `probing`, `answering`,
/// `unreachable` or `refused`; a refusal found then is reported, and the
/// daemon runs on). An answer, a refusal included, takes a few round
/// trips (TCP and TLS handshakes, one listing): milliseconds on a lab's
/// network. A second leaves a distant store that margin, and delays the
/// socket of a daemon whose store is silent by no more.
pub const STORE_PROBE_GRACE_MS: u64 = 1000;

/// Deepest nesting of arrays and objects in a request (the `id` included),
/// in levels; deeper is a `bad_request`.
pub const MAX_JSON_DEPTH: usize = 64;

pub use protocol::ApiErrorKind;

use crate::config::BenchConfig;
use crate::control::loop_check::check_loop;
use crate::control::DiscreteController;
use crate::error::RunError;
use crate::jobs::control::ControlJob;
use crate::rt::backend::{self, BackendSpec};
use crate::rt::service::{run_service, LoopReply, LoopRequest, LoopStatus, ServiceClient};
use crate::rt::{Job, LoopOptions, Pacing};
use owner::{owner, JobHandle, OwnerCmd, OwnerShared};
use protocol::{event, Status};
use serde_json::json;
use socket::{bind_socket, event_log, prepare_socket};
use std::io::Write as _;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use tokio::sync::broadcast;

/// The socket's directory when `XDG_RUNTIME_DIR` is unset, empty or
/// relative: `bench serve` creates it (mode 0750, given to
/// `--socket-group`) when it is missing.
pub const FALLBACK_SOCKET_DIR: &str = "/run/bench";

/// The socket when `--socket` is not given, for the server (`bench serve`)
/// and the clients (`--daemon` without a path) alike:
/// `$XDG_RUNTIME_DIR/bench.sock` when `XDG_RUNTIME_DIR` is an absolute
/// path, else `/run/bench/bench.sock` ([`FALLBACK_SOCKET_DIR`]). An empty
/// or relative `XDG_RUNTIME_DIR` is ignored, as the XDG Base Directory
/// specification says.
pub fn default_socket_path() -> PathBuf {
    match std::env::var_os("XDG_RUNTIME_DIR") {
        Some(d) if std::path::Path::new(&d).is_absolute() => PathBuf::from(d).join("bench.sock"),
        _ => PathBuf::from(FALLBACK_SOCKET_DIR).join("bench.sock"),
    }
}

/// What `bench serve` needs.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    /// Validated config.
    pub config: BenchConfig,
    /// Where it came from.
    pub config_path: PathBuf,
    /// The socket path.
    pub socket: PathBuf,
    /// Group allowed on the socket (0660); `None`: owner only (0600).
    pub socket_group: Option<String>,
    /// Directory of the job recordings and the event log.
    pub recordings: PathBuf,
    /// `--backend` (else the config's).
    pub backend: Option<BackendSpec>,
    /// Simulator seed.
    pub seed: u64,
    /// A simulator fault to inject, `at_s` after the daemon starts (tests
    /// of supervision between jobs).
    pub inject: Option<bench_plant::sim::ScheduledFault>,
    /// Serve Prometheus metrics on this address (`--metrics`,
    /// [`metrics::parse_addr`]); `None`: no metrics server.
    pub metrics: Option<std::net::SocketAddr>,
    /// Upload each finished job's recording, companions, summary and
    /// catalogue row to this store (`--upload`); `None`: no uploads.
    pub upload: Option<crate::upload::StoreUrl>,
    /// How long the store of `upload` has to connect and to answer each
    /// request, s (`--store-timeout`, within
    /// [`crate::upload::store::TIMEOUT_RANGE_S`]; default
    /// [`crate::upload::store::DEFAULT_TIMEOUT_S`]).
    pub store_timeout_s: f64,
    /// The pace of a job whose request gives none (`--pace`): `None`, real
    /// time on the loop's deadlines; the simulator only. Between jobs the
    /// loop keeps real time.
    pub default_pace: Option<crate::jobs::request::Pace>,
}

/// Why the daemon did not start or stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// Bad input before anything was opened (exit 2): an option
    /// (`socket`, `socket_group`, `recordings`, `backend`, `metrics`,
    /// `upload`, `store_timeout`) or the config.
    #[error(transparent)]
    Input(RunError),
    /// Anything else (exit 1).
    #[error("{0}")]
    Other(String),
}

struct Ctx {
    cfg: BenchConfig,
    config_path: PathBuf,
    recordings: PathBuf,
    seed: u64,
    spec: BackendSpec,
    period_s: f64,
    status: Arc<Mutex<Status>>,
    /// What the real-time loop publishes (last reading, supervisor state).
    loop_status: Arc<LoopStatus>,
    owner: Mutex<mpsc::Sender<OwnerCmd>>,
    events: broadcast::Sender<String>,
    next_job: AtomicU64,
    running: Mutex<Option<JobHandle>>,
    shutdown: tokio::sync::Notify,
    /// `--upload`: the store's state, for `status` (its probe stops when
    /// this is dropped).
    store: Option<uploads::StoreProbe>,
    /// `--pace`: a job's pace when its request gives none.
    default_pace: Option<crate::jobs::request::Pace>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The hold controller of `[daemon] hold_controller`, checked once: it must
/// pass the loop check on the model (at the device's rate and current
/// limit), or the daemon does not start. With it, its stall bounds (the
/// loop check's [`crate::control::loop_check::StallLimit`]), which apply
/// between jobs while it drives the stage. The loop is checked with the
/// link's pure delay of `link_delay_periods` loop periods in it.
fn hold_factory(
    cfg: &BenchConfig,
    info: &bench_hal::DeviceInfo,
    link_delay_periods: u32,
) -> Result<Option<(owner::HoldFactory, crate::rt::supervisor::StallBounds)>, ServeError> {
    let Some(name) = cfg.daemon.hold_controller.clone() else {
        return Ok(None);
    };
    let refuse = |reason: String| {
        ServeError::Input(RunError::BadInput(format!(
            "daemon.hold_controller {name}: {reason}; nothing was enabled"
        )))
    };
    let ccfg = cfg
        .controller
        .get(&name)
        .ok_or_else(|| refuse("no such [controller.NAME]".into()))?;
    let period_s = info.period_ns as f64 * 1e-9;
    if info.period_ns != cfg.loop_.period_ns() {
        return Err(refuse(format!(
            "the device runs every {} ns, the controller is discretised for {} ns",
            info.period_ns,
            cfg.loop_.period_ns()
        )));
    }
    let model = bench_plant::model::Sr4dof::new(cfg.plant).map_err(|e| refuse(e.to_string()))?;
    let ctrl = DiscreteController::new(ccfg, period_s, cfg.current_limits(info).peak_current_a);
    let check = check_loop(
        cfg,
        &model,
        &name,
        &ctrl,
        period_s,
        None,
        0.0,
        link_delay_periods,
    );
    if !check.passed() {
        return Err(refuse(format!(
            "the loop check refused it: {}",
            check.failures.join("; ")
        )));
    }
    let bounds = crate::rt::supervisor::StallBounds::of(check.stall.bound_s, period_s);
    tracing::info!("hold controller {name}: {}", check.stall.line());
    Ok(Some((
        Box::new(move || {
            // Step 0, never done: holds the position of its first tick.
            Box::new(ControlJob::new(ctrl, 0.0, 0, 0, u64::MAX)) as Box<dyn Job + Send>
        }),
        bounds,
    )))
}

/// The recordings directory, created if need be; it follows the files'
/// policy (owner writes, group reads; `outputs::DIR_MODE`), whatever the
/// umask lets through. Every path the daemon hands out (recordings, their
/// CSV and plots, the event log) is absolute: its clients run elsewhere.
fn recordings_dir(dir: &std::path::Path) -> Result<PathBuf, ServeError> {
    let bad = |e: std::io::Error| {
        ServeError::Input(RunError::option("recordings", dir.display(), e.to_string()))
    };
    {
        use std::os::unix::fs::DirBuilderExt;
        std::fs::DirBuilder::new()
            .recursive(true)
            .mode(crate::outputs::DIR_MODE)
            .create(dir)
    }
    .map_err(bad)?;
    std::path::absolute(dir).map_err(bad)
}

/// The daemon's status before its first request: disabled, holding as
/// `[daemon] hold_controller` says.
fn initial_status(opts: &ServeOptions, info: &bench_hal::DeviceInfo) -> Status {
    Status {
        state: "disabled",
        fault: None,
        job: None,
        backend: info.name.clone(),
        rate_hz: 1e9 / info.period_ns as f64,
        position_m: f64::NAN,
        command_a: 0.0,
        hold: opts
            .config
            .daemon
            .hold_controller
            .as_ref()
            .map_or("zero_current".into(), |c| {
                format!("position (controller {c})")
            }),
        pace: opts.default_pace,
        jobs_run: 0,
        last_recording: None,
        abandoned_jobs: Vec::new(),
        store: None,
    }
}

/// The real-time loop's options: paced in real time at the device's
/// period, with the one supervisor; between jobs only the hold controller
/// drives the stage (the timing rules are checked while it does, on its
/// bounds).
fn loop_options(
    cfg: &BenchConfig,
    info: &bench_hal::DeviceInfo,
    hold_bounds: Option<crate::rt::supervisor::StallBounds>,
) -> LoopOptions {
    let period_s = info.period_ns as f64 * 1e-9;
    let mut safety = cfg.supervisor(info);
    if let Some(b) = hold_bounds {
        // Between jobs only the hold controller drives the stage (the
        // timing rules are checked while it does).
        safety.max_missed_deadlines = safety.max_missed_deadlines.min(b.max_missed_deadlines);
        safety.max_late_commands = safety.max_late_commands.min(b.max_late_commands);
    }
    LoopOptions {
        period_ns: info.period_ns,
        pacing: Pacing::RealTime {
            priority: cfg.loop_.priority,
            cpu: cfg.loop_.cpu,
        },
        timing_interval_ticks: ((cfg.loop_.timing_interval_s / period_s).round() as u64).max(1),
        safety,
        max_ticks: u64::MAX,
    }
}

/// The metrics: the loop's counts handed off wait-free to the metrics
/// thread, which serves them on `listener` with the owner's.
fn start_metrics(
    listener: std::net::TcpListener,
    status: &Arc<Mutex<Status>>,
    cfg: &BenchConfig,
    info: &bench_hal::DeviceInfo,
    uploads: Option<Arc<crate::upload::worker::UploadCounts>>,
) -> Result<
    (
        crate::rt::tap::LoopTap,
        (Arc<metrics::Metrics>, metrics::MetricsServer),
    ),
    ServeError,
> {
    let (tap, counts) = crate::rt::tap::loop_tap(info.period_ns);
    let m = Arc::new(metrics::Metrics::new(
        Arc::clone(status),
        counts,
        metrics::BuildInfo {
            version: env!("CARGO_PKG_VERSION"),
            config_hash: cfg.sha256_hex(),
            backend: info.name.clone(),
        },
        uploads,
    ));
    let server = metrics::MetricsServer::start(listener, Arc::clone(&m), cfg.loop_.cpu)
        .map_err(ServeError::Other)?;
    // Never a panic on a stderr that cannot be written.
    let _ = writeln!(
        std::io::stderr(),
        "bench serve: metrics on {}",
        server.url()
    );
    Ok((tap, (m, server)))
}

/// Joins the threads, none waited for past the shutdown bound from
/// `shutdown_at` (now if unknown): a thread stuck in a device call cannot
/// be ended, and the device's own watchdog drops the current when the
/// process is gone.
fn join_within_bound(
    shutdown_at: Option<std::time::Instant>,
    threads: [(&str, std::thread::JoinHandle<()>); 2],
) {
    let bound = shutdown_at
        .unwrap_or_else(std::time::Instant::now)
        .checked_add(std::time::Duration::from_millis(SHUTDOWN_BOUND_MS - 100));
    for (name, thread) in threads {
        while !thread.is_finished() && bound.is_some_and(|b| std::time::Instant::now() < b) {
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        if thread.is_finished() {
            let _ = thread.join();
        } else {
            tracing::error!(
                "the {name} thread did not end within {SHUTDOWN_BOUND_MS} ms of the shutdown; leaving without it"
            );
        }
    }
}

/// Serves clients on the socket until `shutdown`, SIGTERM or SIGINT, then
/// stops safely: the running job ends at 0 A with its recording finished,
/// or is abandoned by the owner JOB_STOP_TIMEOUT_MS after the stop; then
/// the owner disables and returns. `shutdown_at`: when the shutdown began.
async fn serve_until_shutdown(
    ctx: &Arc<Ctx>,
    socket_path: &std::path::Path,
    socket_group: Option<&str>,
    shutdown_at: &Mutex<Option<std::time::Instant>>,
) -> Result<(), ServeError> {
    let listener = bind_socket(socket_path, socket_group)?;
    tokio::spawn(event_log(ctx.recordings.clone(), ctx.events.subscribe()));
    let _ = ctx.events.send(event(
        "daemon_started",
        json!({ "socket": socket_path, "backend": lock(&ctx.status).backend }),
    ));
    // Never a panic on a stderr that cannot be written (`/dev/full`).
    let _ = writeln!(
        std::io::stderr(),
        "bench serve: {} on {} (backend {})",
        std::process::id(),
        socket_path.display(),
        lock(&ctx.status).backend
    );
    let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
        .map_err(|e| ServeError::Other(format!("signals: {e}")))?;
    let mut int = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::interrupt())
        .map_err(|e| ServeError::Other(format!("signals: {e}")))?;
    tokio::select! {
        () = socket::accept_clients(Arc::clone(ctx), listener) => {}
        _ = term.recv() => {}
        _ = int.recv() => {}
        () = ctx.shutdown.notified() => {}
    }
    // Stop safely: the running job ends at 0 A with its recording
    // finished, or is abandoned by the owner JOB_STOP_TIMEOUT_MS after
    // the stop; then the owner disables and returns.
    *lock(shutdown_at) = Some(std::time::Instant::now());
    let running = lock(&ctx.running).clone();
    if let Some(h) = running {
        h.stop.store(true, Ordering::Relaxed);
        // Let the job's client get its (interrupted) response.
        let wait = std::time::Duration::from_millis(JOB_STOP_TIMEOUT_MS + 200);
        let t0 = std::time::Instant::now();
        while lock(&ctx.running).is_some() && t0.elapsed() < wait {
            tokio::time::sleep(std::time::Duration::from_millis(10)).await;
        }
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    let _ = lock(&ctx.owner).send(OwnerCmd::Shutdown);
    Ok(())
}

/// Runs the daemon until `shutdown`, SIGTERM or SIGINT.
///
/// # Errors
/// [`ServeError::Input`] for an unusable socket path, a busy socket, a
/// device that cannot be opened, a `store_timeout_s` out of its range, a
/// store of `upload` without credentials or that refused within
/// [`STORE_PROBE_GRACE_MS`]; [`ServeError::Other`] otherwise.
pub fn serve(opts: ServeOptions) -> Result<(), ServeError> {
    // First: an address in use stops the daemon before anything else.
    let metrics_listener = opts
        .metrics
        .map(|addr| {
            metrics::bind(addr)
                .map_err(|reason| ServeError::Input(RunError::option("metrics", addr, reason)))
        })
        .transpose()?;
    prepare_socket(&opts.socket, opts.socket_group.as_deref())?;
    let recordings = recordings_dir(&opts.recordings)?;
    if !crate::job_memory::installed() {
        tracing::warn!(
            "bench::job_memory::BudgetAllocator is not this program's global allocator: the jobs' memory budgets are not enforced"
        );
    }
    let (events, _) = broadcast::channel::<String>(1024);
    let spec = BackendSpec::resolve(opts.backend.as_ref(), &opts.config);
    // A pace is virtual time: the simulator's only, refused before
    // anything is opened.
    crate::jobs::request::refuse_pace_on_hardware(
        opts.default_pace,
        !spec.is_sim(),
        &spec.to_string(),
    )
    .map_err(ServeError::Input)?;
    // The store refuses (no bucket, credentials) within the probe's
    // grace: stop before the bench is opened; one that has not answered
    // by then only delays the uploads, its probe going on meanwhile.
    let (uploader, store_probe) = opts
        .upload
        .clone()
        .map(|url| {
            let cpu = opts.config.loop_.cpu;
            uploads::start(url, opts.store_timeout_s, &recordings, cpu, events.clone())
        })
        .transpose()
        .map_err(ServeError::Input)?
        .unzip();
    let (mut stage, info) = backend::open(
        &spec,
        &opts.config,
        &opts.config_path,
        opts.seed,
        opts.inject,
        // Until the hold controller's bound is known (below): the user's.
        opts.config.safety.max_overrun_s.unwrap_or(f64::INFINITY),
    )
    .map_err(ServeError::Input)?;
    let status = Arc::new(Mutex::new(initial_status(&opts, &info)));
    let (owner_tx, owner_rx) = mpsc::channel();
    // The real-time loop: one Loop and one supervisor for the daemon's
    // life, paced in real time (jobs on a daemon always are).
    let loop_status = Arc::new(LoopStatus::default());
    let (req_tx, req_rx) = rtrb::RingBuffer::<LoopRequest>::new(16);
    let (rep_tx, rep_rx) = rtrb::RingBuffer::<LoopReply>::new(64);
    let period_s = info.period_ns as f64 * 1e-9;
    let (hold, hold_bounds) =
        hold_factory(&opts.config, &info, spec.process_data_delay_periods())?.unzip();
    // The link's wait follows the hold controller's stall bound between
    // jobs, each job's own while it runs (`run_service`).
    if let Some(b) = hold_bounds {
        stage.set_stall_bound_s(b.missed_deadlines_s(period_s));
    }
    let loop_opts = loop_options(&opts.config, &info, hold_bounds);
    let counts = uploader
        .as_ref()
        .map(crate::upload::worker::Uploader::counts);
    let (tap, metrics) = metrics_listener
        .map(|l| start_metrics(l, &status, &opts.config, &info, counts))
        .transpose()?
        .unzip();
    let rt_thread = {
        let loop_status = Arc::clone(&loop_status);
        let clock = info.clock;
        std::thread::Builder::new()
            .name("bench-rt".into())
            .spawn(move || {
                run_service(
                    &mut stage,
                    &loop_opts,
                    clock,
                    req_rx,
                    rep_tx,
                    &loop_status,
                    tap,
                );
                drop(stage);
            })
            .map_err(|e| ServeError::Other(format!("cannot start the real-time thread: {e}")))?
    };
    let client = ServiceClient::new(req_tx, rep_rx, info.clone(), !spec.is_sim());
    let owner_thread = {
        let shared = OwnerShared {
            status: Arc::clone(&status),
            events: events.clone(),
            safety: loop_opts.safety,
            hold,
            metrics: metrics.as_ref().map(|(m, _)| Arc::clone(m)),
            uploader,
        };
        std::thread::Builder::new()
            .name("bench-owner".into())
            .spawn(move || owner(client, owner_rx, shared))
            .map_err(|e| ServeError::Other(format!("cannot start the owner thread: {e}")))?
    };
    let ctx = Arc::new(Ctx {
        period_s: info.period_ns as f64 * 1e-9,
        cfg: opts.config.clone(),
        config_path: opts.config_path.clone(),
        recordings: recordings.clone(),
        seed: opts.seed,
        spec,
        status,
        loop_status,
        owner: Mutex::new(owner_tx),
        events,
        next_job: AtomicU64::new(0),
        running: Mutex::new(None),
        shutdown: tokio::sync::Notify::new(),
        store: store_probe,
        default_pace: opts.default_pace,
    });
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| ServeError::Other(format!("tokio: {e}")))?;
    // When the shutdown began (a signal, `shutdown`): the bound's start.
    let shutdown_at: Mutex<Option<std::time::Instant>> = Mutex::new(None);
    let result = rt.block_on(serve_until_shutdown(
        &ctx,
        &opts.socket,
        opts.socket_group.as_deref(),
        &shutdown_at,
    ));
    // Also when the block above ended early with an error (the socket
    // could not be bound): the owner must see Shutdown, or the joins below
    // wait for ever.
    let _ = lock(&ctx.owner).send(OwnerCmd::Shutdown);
    // The owner finishes the job (its recording) before it sees Shutdown,
    // then has the loop disable the amplifier and stop.
    join_within_bound(
        *lock(&shutdown_at),
        [("owner", owner_thread), ("real-time loop", rt_thread)],
    );
    // The metrics are served until the loop has stopped.
    drop(metrics);
    let _ = std::fs::remove_file(&opts.socket);
    result
}
