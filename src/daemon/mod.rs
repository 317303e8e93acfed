//! `bench serve`: the daemon that owns the bench (README, *`bench serve`: the daemon*).
//!
//! One **owner thread** holds the backend, opened once. Between jobs it
//! keeps reading the device at the loop rate with the amplifier disabled
//! (or enabled at 0 A after `enable`), so the link stays supervised. A job
//! runs on that same stage through the usual real-time loop
//! ([`run_chirp_on`], [`run_control_from`]), which leaves it disabled at
//! 0 A. The **socket side** is a single-threaded tokio runtime serving JSON
//! lines on a Unix domain socket. It talks to the owner through a channel;
//! nothing on the socket side can block the loop.
//!
//! # Protocol
//!
//! One JSON object per line. A request is
//! `{"id": ANY, "cmd": NAME, "params": {...}}` (`id` and `params` optional).
//! Each request gets exactly one response with the same `id`:
//! `{"id": .., "ok": true, "result": {...}}` or
//! `{"id": .., "ok": false, "error": {"kind": KIND, "message": ".."}}`.
//! Events are lines with an `"event"` key and no `id`.
//!
//! | cmd | params | result |
//! |---|---|---|
//! | `status` | – | state, fault and cause, job and progress, backend, last reading |
//! | `enable` / `disable` | – | amplifier enabled at 0 A / disabled (refused while faulted) |
//! | `reset` | – | clears a latched fault (back to `disabled`) |
//! | `chirp` | the fields of a [`ChirpRequest`], and `detach` | the `bench chirp --json` summary |
//! | `control` | the fields of a [`ControlRequest`], and `detach` | the `bench control --json` summary |
//! | `stop` | – | the running job stops safely (0 A, recording finished) |
//! | `subscribe` | – | this connection receives every event from now on |
//! | `shutdown` | – | stops the job, then the daemon |
//!
//! [`ChirpRequest`]: crate::jobs::request::ChirpRequest
//! [`ControlRequest`]: crate::jobs::request::ControlRequest
//!
//! Error kinds: `bad_request` (not JSON, no `cmd`), `unknown_command`,
//! `bad_params`, `busy` (a job is running), `faulted` (reset first),
//! `refused` (loop check), `fault`, `hal`, `interrupted`, `error`.
//!
//! **One job at a time**: a second job gets `busy`. Jobs are never queued.
//!
//! **Unattended rule**: when the client that submitted a job disconnects,
//! the job is stopped safely (0 A, recording finished), unless the request
//! said `"detach": true`. A detached job runs to its own end and no
//! further.

pub mod client;

use crate::config::BenchConfig;
use crate::error::RunError;
use crate::jobs::chirp::{run_chirp_on, ChirpOptions};
use crate::jobs::request::{JobRequest, RequestError};
use crate::jobs::session::beside;
use crate::jobs::session::Runner;
use crate::jobs::step::{run_control_from, ControlOptions, StageSource};
use crate::record::topics::FaultKind;
use crate::rt::backend::{self, BackendSpec};
use crate::rt::service::{run_service, LoopReply, LoopRequest, LoopStatus, ServiceClient};
use crate::rt::{LoopOptions, Pacing, RawStop, StopReason};
use serde::Serialize;
use serde_json::{json, Value};
use std::io::Write as _;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt};
use tokio::sync::{broadcast, oneshot};

/// The socket when `--socket` is not given: `$XDG_RUNTIME_DIR/bench.sock`,
/// else `/run/bench/bench.sock`.
pub fn default_socket_path() -> PathBuf {
    match std::env::var_os("XDG_RUNTIME_DIR") {
        Some(d) if !d.is_empty() => PathBuf::from(d).join("bench.sock"),
        _ => PathBuf::from("/run/bench/bench.sock"),
    }
}

/// Rolling event log: rotated to `.1` past this size.
const EVENT_LOG_MAX_BYTES: u64 = 10 << 20;

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
    pub inject: Option<bench_hal::sim::ScheduledFault>,
}

/// Why the daemon did not start or stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// Bad input before anything was opened (exit 2).
    #[error("{0}")]
    BadInput(String),
    /// Anything else (exit 1).
    #[error("{0}")]
    Other(String),
}

/// An error response.
#[derive(Debug, Clone, Serialize)]
struct ApiError {
    kind: &'static str,
    message: String,
}

impl ApiError {
    fn new(kind: &'static str, message: impl Into<String>) -> Self {
        Self {
            kind,
            message: message.into(),
        }
    }

    fn from_run(e: &RunError) -> Self {
        let kind = match e {
            RunError::BadInput(_) => "bad_params",
            RunError::Refused(_) => "refused",
            RunError::Fault { .. } => "fault",
            RunError::Hal { .. } => "hal",
            RunError::Interrupted { .. } => "interrupted",
            RunError::TickLimit { .. }
            | RunError::Record(_)
            | RunError::Output { .. }
            | RunError::Json(_)
            | RunError::Thread(_) => "error",
        };
        Self::new(kind, format!("{e:#}"))
    }
}

/// The daemon's state, as `status` reports it.
#[derive(Debug, Clone, Serialize)]
struct Status {
    /// `disabled`, `enabled`, `running` or `faulted`.
    state: &'static str,
    /// The latched fault: `{kind, message}`.
    fault: Option<ApiError>,
    /// The running job.
    job: Option<JobStatus>,
    backend: String,
    rate_hz: f64,
    /// Last reading between jobs, m.
    position_m: f64,
    jobs_run: u64,
    last_recording: Option<String>,
}

#[derive(Debug, Clone, Serialize)]
struct JobStatus {
    id: u64,
    kind: &'static str,
    ticks: u64,
    total_ticks: u64,
    recording: String,
    detach: bool,
}

/// A job's handles shared with the socket side.
#[derive(Debug, Clone)]
struct JobHandle {
    id: u64,
    stop: Arc<AtomicBool>,
    ticks: Arc<AtomicU64>,
}

type Reply<T> = oneshot::Sender<Result<T, ApiError>>;

enum JobSpec {
    Chirp(Box<ChirpOptions>),
    Control(Box<ControlOptions>),
}

enum OwnerCmd {
    Enable(Reply<()>),
    Disable(Reply<()>),
    Reset(Reply<()>),
    Job(JobSpec, JobHandle, Reply<Value>),
    Shutdown,
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
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Checks the socket path and clears a stale socket: refuses a
/// world-writable directory, a non-socket file, and a socket another
/// daemon answers on.
fn prepare_socket(path: &Path) -> Result<(), ServeError> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let meta = std::fs::metadata(&dir).map_err(|e| {
        ServeError::BadInput(format!(
            "--socket {}: directory {}: {e}",
            path.display(),
            dir.display()
        ))
    })?;
    if meta.permissions().mode() & 0o002 != 0 {
        return Err(ServeError::BadInput(format!(
            "--socket {}: directory {} is world-writable (mode {:o}); use a private directory such as $XDG_RUNTIME_DIR",
            path.display(),
            dir.display(),
            meta.permissions().mode() & 0o7777
        )));
    }
    match std::fs::symlink_metadata(path) {
        Err(_) => Ok(()),
        Ok(m) => {
            use std::os::unix::fs::FileTypeExt;
            if !m.file_type().is_socket() {
                return Err(ServeError::BadInput(format!(
                    "--socket {}: exists and is not a socket; not touching it",
                    path.display()
                )));
            }
            match std::os::unix::net::UnixStream::connect(path) {
                Ok(_) => Err(ServeError::BadInput(format!(
                    "--socket {}: another bench daemon is serving there",
                    path.display()
                ))),
                Err(_) => std::fs::remove_file(path).map_err(|e| {
                    ServeError::BadInput(format!(
                        "--socket {}: stale socket cannot be removed: {e}",
                        path.display()
                    ))
                }),
            }
        }
    }
}

/// Binds the socket owner-only (0600), or 0660 with `group`.
fn bind_socket(path: &Path, group: Option<&str>) -> Result<tokio::net::UnixListener, ServeError> {
    // SAFETY: umask is process-wide and only read/written here, before any
    // other thread creates files.
    let old = unsafe { libc::umask(0o177) };
    let listener = tokio::net::UnixListener::bind(path);
    // SAFETY: as above.
    unsafe { libc::umask(old) };
    let listener = listener.map_err(|e| {
        ServeError::BadInput(format!("--socket {}: cannot bind: {e}", path.display()))
    })?;
    if let Some(g) = group {
        let cname = std::ffi::CString::new(g)
            .map_err(|_| ServeError::BadInput(format!("--socket-group {g:?}: not a name")))?;
        // SAFETY: valid C string; getgrnam returns null or a static record.
        let gr = unsafe { libc::getgrnam(cname.as_ptr()) };
        if gr.is_null() {
            let _ = std::fs::remove_file(path);
            return Err(ServeError::BadInput(format!(
                "--socket-group {g}: no such group"
            )));
        }
        // SAFETY: gr is non-null.
        let gid = unsafe { (*gr).gr_gid };
        let cpath = std::ffi::CString::new(path.as_os_str().as_encoded_bytes())
            .map_err(|_| ServeError::BadInput("--socket: path has a NUL byte".into()))?;
        // SAFETY: valid path; uid -1 keeps the owner.
        if unsafe { libc::chown(cpath.as_ptr(), u32::MAX, gid) } != 0 {
            let e = std::io::Error::last_os_error();
            let _ = std::fs::remove_file(path);
            return Err(ServeError::BadInput(format!(
                "--socket-group {g}: cannot give the socket to the group: {e}"
            )));
        }
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o660))
            .map_err(|e| ServeError::Other(format!("chmod socket: {e}")))?;
    }
    Ok(listener)
}

fn event(kind: &str, fields: Value) -> String {
    let mut v = json!({ "event": kind, "unix_time_s": unix_time_s() });
    if let (Some(o), Value::Object(f)) = (v.as_object_mut(), fields) {
        o.extend(f);
    }
    v.to_string()
}

fn unix_time_s() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// A job summary as JSON (the response's `result`).
fn to_json<T: Serialize>(summary: T) -> Result<Value, (ApiError, RunError)> {
    serde_json::to_value(summary)
        .map_err(|e| (ApiError::new("error", e.to_string()), RunError::Json(e)))
}

/// What the owner thread shares with the socket side.
struct OwnerShared {
    status: Arc<Mutex<Status>>,
    events: broadcast::Sender<String>,
}

/// A fault the loop latched between jobs, as `status` reports it: the
/// supervisor's fault name and what caused it.
fn between_jobs_fault(r: LoopReply) -> Option<ApiError> {
    let LoopReply::Fault {
        kind,
        value,
        link_error,
        hal_error,
    } = r
    else {
        return None;
    };
    let stop = match hal_error {
        Some((call, error)) if kind == FaultKind::Hal => RawStop::Hal {
            call,
            error,
            tick: 0,
        },
        _ => RawStop::Fault {
            kind,
            value,
            tick: 0,
            link_error,
        },
    };
    let message = match stop.describe() {
        StopReason::Hal { message, .. } => message,
        StopReason::Fault {
            detail: Some(d), ..
        } => d,
        _ => format!("value {value:e}"),
    };
    Some(ApiError::new(
        kind.as_str(),
        format!(
            "between jobs: {} ({message}); 0 A, amplifier disabled",
            kind.as_str()
        ),
    ))
}

/// The owner thread: the daemon's side of the loop. It hands requests and
/// jobs to the real-time loop ([`crate::rt::service`]), which runs the
/// hold job and the one supervisor between them, and reports faults the
/// loop latched between jobs.
fn owner(mut client: ServiceClient, rx: mpsc::Receiver<OwnerCmd>, shared: OwnerShared) {
    let OwnerShared { status, events } = shared;
    let hardware = client.hardware;
    let set_state = |state: &'static str, fault: Option<ApiError>| {
        let mut s = lock(&status);
        s.state = state;
        if fault.is_some() || state != "faulted" {
            s.fault = fault;
        }
        let _ = events.send(event("state", json!({ "state": state, "fault": s.fault })));
    };
    let gone = || ApiError::new("error", "the real-time loop is gone");
    loop {
        let cmd = rx.recv_timeout(std::time::Duration::from_millis(10));
        match cmd {
            Ok(OwnerCmd::Shutdown) | Err(mpsc::RecvTimeoutError::Disconnected) => break,
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Ok(OwnerCmd::Enable(reply)) => {
                let r = match client.call(LoopRequest::Enable) {
                    Some(LoopReply::Enabled(Ok(()))) => {
                        set_state("enabled", None);
                        Ok(())
                    }
                    Some(LoopReply::Enabled(Err(None))) => {
                        Err(ApiError::new("faulted", "a fault is latched: reset first"))
                    }
                    Some(LoopReply::Enabled(Err(Some(e)))) => {
                        let api = ApiError::new("hal", format!("enable failed: {e}"));
                        set_state("faulted", Some(api.clone()));
                        Err(api)
                    }
                    _ => Err(gone()),
                };
                let _ = reply.send(r);
            }
            Ok(OwnerCmd::Disable(reply)) => {
                let r = match client.call(LoopRequest::Disable) {
                    Some(_) => {
                        if lock(&status).state != "faulted" {
                            set_state("disabled", None);
                        }
                        Ok(())
                    }
                    None => Err(gone()),
                };
                let _ = reply.send(r);
            }
            Ok(OwnerCmd::Reset(reply)) => {
                let r = match client.call(LoopRequest::Reset) {
                    Some(_) => {
                        // Faults reported before the reset are cleared by
                        // it; one that latches again after it is reported.
                        client.forget_earlier_faults();
                        set_state("disabled", None);
                        Ok(())
                    }
                    None => Err(gone()),
                };
                let _ = reply.send(r);
            }
            Ok(OwnerCmd::Job(job, handle, reply)) => {
                let result = match job {
                    JobSpec::Chirp(opts) => run_chirp_on(
                        &mut Runner::Service(&mut client),
                        hardware,
                        &opts,
                        Arc::clone(&handle.stop),
                        Some(&handle.ticks),
                    )
                    .map_err(|e| (ApiError::from_run(&e), e))
                    .and_then(to_json),
                    JobSpec::Control(opts) => run_control_from(
                        &opts,
                        Arc::clone(&handle.stop),
                        StageSource::Service(&mut client),
                        Some(&handle.ticks),
                    )
                    .map_err(|e| (ApiError::from_run(&e), e))
                    .and_then(to_json),
                };
                {
                    let mut s = lock(&status);
                    s.jobs_run += 1;
                    if let Some(j) = s.job.take() {
                        s.last_recording = Some(j.recording);
                    }
                }
                match &result {
                    // The latched fault is reported by its supervisor name.
                    Err((api, RunError::Fault { kind, .. })) => {
                        set_state("faulted", Some(ApiError::new(kind, api.message.clone())));
                    }
                    Err((api, RunError::Hal { .. })) => {
                        set_state("faulted", Some(api.clone()));
                    }
                    _ => set_state("disabled", None),
                }
                let _ = reply.send(result.map_err(|(api, _)| api));
            }
        }
        for f in client.take_faults() {
            if let Some(api) = between_jobs_fault(f) {
                set_state("faulted", Some(api));
            }
        }
    }
    let _ = client.call(LoopRequest::Shutdown);
}

/// Appends events to `dir/daemon-events.jsonl`, rotating to `.1` past
/// [`EVENT_LOG_MAX_BYTES`].
async fn event_log(dir: PathBuf, mut rx: broadcast::Receiver<String>) {
    let path = dir.join("daemon-events.jsonl");
    loop {
        let line = match rx.recv().await {
            Ok(l) => l,
            Err(broadcast::error::RecvError::Lagged(n)) => {
                event("log_lagged", json!({ "lost": n }))
            }
            Err(broadcast::error::RecvError::Closed) => return,
        };
        if std::fs::metadata(&path).map_or(0, |m| m.len()) > EVENT_LOG_MAX_BYTES {
            let _ = std::fs::rename(&path, dir.join("daemon-events.jsonl.1"));
        }
        if let Ok(mut f) = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
        {
            let _ = writeln!(f, "{line}");
        }
    }
}

/// Deserialises `params` (an object, or absent) as `T`, naming the
/// parameter at fault: `params.KEY: why`.
fn from_params<T: serde::de::DeserializeOwned>(params: Value) -> Result<T, ApiError> {
    use serde::de::{value::MapAccessDeserializer, DeserializeSeed, IntoDeserializer, MapAccess};
    /// The object's entries; `at` is the key being read until its value
    /// has been read.
    struct Entries {
        iter: serde_json::map::IntoIter,
        value: Option<Value>,
        at: Option<String>,
    }
    impl<'de> MapAccess<'de> for Entries {
        type Error = serde_json::Error;
        fn next_key_seed<K: DeserializeSeed<'de>>(
            &mut self,
            seed: K,
        ) -> Result<Option<K::Value>, Self::Error> {
            let Some((k, v)) = self.iter.next() else {
                return Ok(None);
            };
            self.value = Some(v);
            self.at = Some(k.clone());
            seed.deserialize(k.into_deserializer()).map(Some)
        }
        fn next_value_seed<V: DeserializeSeed<'de>>(
            &mut self,
            seed: V,
        ) -> Result<V::Value, Self::Error> {
            let v = seed.deserialize(self.value.take().unwrap_or(Value::Null))?;
            self.at = None;
            Ok(v)
        }
    }
    let map = match params {
        Value::Null => serde_json::Map::new(),
        Value::Object(m) => m,
        _ => return Err(ApiError::new("bad_params", "params must be an object")),
    };
    let mut entries = Entries {
        iter: map.into_iter(),
        value: None,
        at: None,
    };
    let parsed = T::deserialize(MapAccessDeserializer::new(&mut entries));
    parsed.map_err(|e| {
        let at = entries.at.map_or(String::new(), |k| format!(".{k}"));
        ApiError::new("bad_params", format!("params{at}: {e}"))
    })
}

/// The job request of a `chirp` or `control` command, and whether it asked
/// to `detach` (a transport option of the daemon, not part of the job).
fn job_request(cmd: &str, params: &Value) -> Result<(JobRequest, bool), ApiError> {
    let mut params = params.clone();
    let detach = match params.as_object_mut().and_then(|m| m.remove("detach")) {
        None | Some(Value::Null) => false,
        Some(Value::Bool(d)) => d,
        Some(v) => {
            return Err(ApiError::new(
                "bad_params",
                format!("params.detach: expected true or false, got {v}"),
            ))
        }
    };
    let request = if cmd == "chirp" {
        JobRequest::Chirp(from_params(params)?)
    } else {
        JobRequest::Control(from_params(params)?)
    };
    Ok((request, detach))
}

fn recording_path(dir: &Path, prefix: &str, id: u64) -> PathBuf {
    crate::jobs::session::stamped_recording(dir, prefix, &format!("-job{id}"))
}

/// Builds a job from a request; `Err` for bad parameters.
fn job_spec(
    ctx: &Ctx,
    request: &JobRequest,
    id: u64,
) -> Result<(JobSpec, &'static str, u64, PathBuf), ApiError> {
    let mut cfg = ctx.cfg.clone();
    // The request names a config key or its field; a field is a parameter.
    let bad = |e: RequestError| {
        let message = match e {
            RequestError::Field { .. } => format!("params.{e}"),
            RequestError::Invalid { .. } => e.to_string(),
        };
        ApiError::new("bad_params", message)
    };
    match request {
        JobRequest::Chirp(req) => {
            req.apply(&mut cfg).map_err(bad)?;
            let chirp = crate::ident::excitation::Chirp::new(&cfg.chirp, ctx.period_s);
            let out = recording_path(&ctx.recordings, "chirp", id);
            let opts = ChirpOptions {
                frf_csv: beside(&out, ".frf.csv"),
                plot: beside(&out, ".bode.png"),
                out: out.clone(),
                seed: req.seed.unwrap_or(ctx.seed),
                config: cfg,
                config_path: ctx.config_path.clone(),
                realtime: true,
                progress: false,
                backend: Some(ctx.spec.clone()),
            };
            Ok((
                JobSpec::Chirp(Box::new(opts)),
                request.kind(),
                chirp.total_ticks(),
                out,
            ))
        }
        JobRequest::Control(req) => {
            let inject = req.apply(&mut cfg).map_err(bad)?;
            let out = recording_path(&ctx.recordings, &format!("control-{}", req.controller), id);
            let total = (cfg.step.duration_s / ctx.period_s).round() as u64;
            let opts = ControlOptions {
                plot: beside(&out, ".step.png"),
                out: out.clone(),
                controller: req.controller.clone(),
                check_only: false,
                frf: None,
                override_check: req.override_check,
                realtime: true,
                seed: req.seed.unwrap_or(ctx.seed),
                progress: false,
                inject,
                backend: Some(ctx.spec.clone()),
                config: cfg,
                config_path: ctx.config_path.clone(),
            };
            Ok((JobSpec::Control(Box::new(opts)), request.kind(), total, out))
        }
    }
}

async fn owner_call<T>(ctx: &Ctx, make: impl FnOnce(Reply<T>) -> OwnerCmd) -> Result<T, ApiError> {
    let (tx, rx) = oneshot::channel();
    lock(&ctx.owner)
        .send(make(tx))
        .map_err(|_| ApiError::new("error", "the bench owner thread is gone"))?;
    rx.await
        .map_err(|_| ApiError::new("error", "the bench owner thread is gone"))?
}

fn respond(id: &Value, r: Result<Value, ApiError>) -> String {
    match r {
        Ok(v) => json!({ "id": id, "ok": true, "result": v }).to_string(),
        Err(e) => json!({ "id": id, "ok": false, "error": e }).to_string(),
    }
}

/// Serves one connection.
async fn connection(ctx: Arc<Ctx>, stream: tokio::net::UnixStream) {
    let (rd, mut wr) = stream.into_split();
    let (out, mut out_rx) = tokio::sync::mpsc::unbounded_channel::<String>();
    let writer = tokio::spawn(async move {
        while let Some(line) = out_rx.recv().await {
            if wr.write_all(line.as_bytes()).await.is_err() || wr.write_all(b"\n").await.is_err() {
                break;
            }
        }
    });
    let mut lines = tokio::io::BufReader::new(rd).lines();
    // Jobs this client submitted without `detach`.
    let mut attached: Vec<JobHandle> = Vec::new();
    while let Ok(Some(line)) = lines.next_line().await {
        if line.trim().is_empty() {
            continue;
        }
        let req: Value = match serde_json::from_str(&line) {
            Ok(v) => v,
            Err(e) => {
                let _ = out.send(respond(
                    &Value::Null,
                    Err(ApiError::new("bad_request", format!("not JSON: {e}"))),
                ));
                continue;
            }
        };
        let id = req.get("id").cloned().unwrap_or(Value::Null);
        let Some(cmd) = req.get("cmd").and_then(Value::as_str).map(str::to_string) else {
            let _ = out.send(respond(
                &id,
                Err(ApiError::new("bad_request", "no \"cmd\" string")),
            ));
            continue;
        };
        let params = req.get("params").cloned().unwrap_or(Value::Null);
        let r = match cmd.as_str() {
            "status" => {
                let mut s = lock(&ctx.status).clone();
                s.position_m = ctx.loop_status.position_m();
                if let (Some(j), Some(h)) = (s.job.as_mut(), lock(&ctx.running).as_ref()) {
                    j.ticks = h.ticks.load(Ordering::Relaxed);
                }
                serde_json::to_value(s).map_err(|e| ApiError::new("error", e.to_string()))
            }
            "enable" | "disable" | "reset" if lock(&ctx.running).is_some() => Err(ApiError::new(
                "busy",
                format!("a job is running: `stop` it first ({cmd} acts between jobs)"),
            )),
            "enable" => owner_call(&ctx, OwnerCmd::Enable).await.map(|()| json!({ "state": "enabled" })),
            "disable" => owner_call(&ctx, OwnerCmd::Disable).await.map(|()| json!({ "state": "disabled" })),
            "reset" => owner_call(&ctx, OwnerCmd::Reset).await.map(|()| json!({ "state": "disabled" })),
            "stop" => match lock(&ctx.running).as_ref() {
                Some(h) => {
                    h.stop.store(true, Ordering::Relaxed);
                    Ok(json!({ "stopping": h.id }))
                }
                None => Ok(json!({ "stopping": null })),
            },
            "subscribe" => {
                let mut rx = ctx.events.subscribe();
                let out = out.clone();
                tokio::spawn(async move {
                    loop {
                        match rx.recv().await {
                            Ok(l) => {
                                if out.send(l).is_err() {
                                    return;
                                }
                            }
                            Err(broadcast::error::RecvError::Lagged(_)) => {}
                            Err(broadcast::error::RecvError::Closed) => return,
                        }
                    }
                });
                Ok(json!({ "subscribed": true }))
            }
            "shutdown" => {
                ctx.shutdown.notify_one();
                Ok(json!({ "shutting_down": true }))
            }
            "chirp" | "control" => {
                match submit(&ctx, &cmd, &params, &id, &out) {
                    Ok(attach) => {
                        attached.extend(attach);
                        continue; // the job task responds
                    }
                    Err(e) => Err(e),
                }
            }
            other => Err(ApiError::new(
                "unknown_command",
                format!("unknown command {other:?} (status, enable, disable, reset, chirp, control, stop, subscribe, shutdown)"),
            )),
        };
        let _ = out.send(respond(&id, r));
    }
    // The client is gone: its attached jobs stop (the unattended rule).
    for h in attached {
        if lock(&ctx.running).as_ref().is_some_and(|r| r.id == h.id) {
            h.stop.store(true, Ordering::Relaxed);
            let _ = ctx.events.send(event(
                "client_left",
                json!({ "job": h.id, "action": "job stopped (not detached)" }),
            ));
        }
    }
    drop(out);
    let _ = writer.await;
}

/// Starts a job: checks busy/faulted, hands it to the owner, and spawns
/// the task that streams progress and sends the response. Returns the job
/// to stop when this client leaves (`None`: detached).
fn submit(
    ctx: &Arc<Ctx>,
    cmd: &str,
    params: &Value,
    id: &Value,
    out: &tokio::sync::mpsc::UnboundedSender<String>,
) -> Result<Option<JobHandle>, ApiError> {
    let job_id = ctx.next_job.fetch_add(1, Ordering::Relaxed) + 1;
    let (request, detach) = job_request(cmd, params)?;
    let (spec, kind, total, recording) = job_spec(ctx, &request, job_id)?;
    let handle = JobHandle {
        id: job_id,
        stop: Arc::new(AtomicBool::new(false)),
        ticks: Arc::new(AtomicU64::new(0)),
    };
    {
        // Check and claim under the lock: two clients cannot both start.
        let mut running = lock(&ctx.running);
        let mut status = lock(&ctx.status);
        if let Some(r) = running.as_ref() {
            return Err(ApiError::new(
                "busy",
                format!("job {} is running; one job at a time", r.id),
            ));
        }
        if status.state == "faulted" {
            return Err(ApiError::new(
                "faulted",
                format!(
                    "a fault is latched ({}): reset first",
                    status.fault.as_ref().map_or("?", |f| f.kind)
                ),
            ));
        }
        *running = Some(handle.clone());
        status.state = "running";
        status.job = Some(JobStatus {
            id: job_id,
            kind,
            ticks: 0,
            total_ticks: total,
            recording: recording.display().to_string(),
            detach,
        });
    }
    let (tx, rx) = oneshot::channel();
    if lock(&ctx.owner)
        .send(OwnerCmd::Job(spec, handle.clone(), tx))
        .is_err()
    {
        *lock(&ctx.running) = None;
        return Err(ApiError::new("error", "the bench owner thread is gone"));
    }
    let started = event(
        "job_started",
        json!({ "job": job_id, "kind": kind, "total_ticks": total, "recording": recording, "detach": detach }),
    );
    let _ = ctx.events.send(started.clone());
    let _ = out.send(started);
    let ctx = Arc::clone(ctx);
    let out = out.clone();
    let id = id.clone();
    let h = handle.clone();
    tokio::spawn(async move {
        let mut rx = rx;
        let mut tick = tokio::time::interval(std::time::Duration::from_millis(250));
        let result = loop {
            tokio::select! {
                r = &mut rx => break r.unwrap_or_else(|_| Err(ApiError::new("error", "the bench owner thread is gone"))),
                _ = tick.tick() => {
                    let p = event("progress", json!({
                        "job": h.id, "ticks": h.ticks.load(Ordering::Relaxed), "total_ticks": total
                    }));
                    let _ = out.send(p.clone());
                    let _ = ctx.events.send(p);
                }
            }
        };
        *lock(&ctx.running) = None;
        let result = result.map(|mut v| {
            if let Some(o) = v.as_object_mut() {
                o.insert("recording".into(), json!(recording));
            }
            v
        });
        let fin = event(
            "job_finished",
            json!({ "job": h.id, "kind": kind, "ok": result.is_ok(), "error": result.as_ref().err() }),
        );
        let _ = ctx.events.send(fin.clone());
        let _ = out.send(fin);
        let _ = out.send(respond(&id, result));
    });
    Ok((!detach).then_some(handle))
}

/// Runs the daemon until `shutdown`, SIGTERM or SIGINT.
///
/// # Errors
/// [`ServeError::BadInput`] for an unusable socket path, a busy socket, a
/// device that cannot be opened; [`ServeError::Other`] otherwise.
pub fn serve(opts: ServeOptions) -> Result<(), ServeError> {
    prepare_socket(&opts.socket)?;
    std::fs::create_dir_all(&opts.recordings).map_err(|e| {
        ServeError::BadInput(format!("--recordings {}: {e}", opts.recordings.display()))
    })?;
    let spec = BackendSpec::resolve(opts.backend.as_ref(), &opts.config);
    let (mut stage, info) = backend::open(
        &spec,
        &opts.config,
        &opts.config_path,
        opts.seed,
        opts.inject,
    )
    .map_err(|e| ServeError::BadInput(e.to_string()))?;
    let (events, _) = broadcast::channel::<String>(1024);
    let status = Arc::new(Mutex::new(Status {
        state: "disabled",
        fault: None,
        job: None,
        backend: info.name.clone(),
        rate_hz: 1e9 / info.period_ns as f64,
        position_m: f64::NAN,
        jobs_run: 0,
        last_recording: None,
    }));
    let (owner_tx, owner_rx) = mpsc::channel();
    // The real-time loop: one Loop and one supervisor for the daemon's
    // life, paced in real time (jobs on a daemon always are).
    let loop_status = Arc::new(LoopStatus::default());
    let (req_tx, req_rx) = rtrb::RingBuffer::<LoopRequest>::new(16);
    let (rep_tx, rep_rx) = rtrb::RingBuffer::<LoopReply>::new(64);
    let period_s = info.period_ns as f64 * 1e-9;
    let loop_opts = LoopOptions {
        period_ns: info.period_ns,
        pacing: Pacing::RealTime {
            priority: opts.config.loop_.priority,
            cpu: opts.config.loop_.cpu,
        },
        timing_interval_ticks: ((opts.config.loop_.timing_interval_s / period_s).round() as u64)
            .max(1),
        safety: opts.config.supervisor(&info),
        max_ticks: u64::MAX,
    };
    let rt_thread = {
        let loop_status = Arc::clone(&loop_status);
        let clock = info.clock;
        std::thread::Builder::new()
            .name("bench-rt".into())
            .spawn(move || {
                run_service(&mut stage, &loop_opts, clock, req_rx, rep_tx, &loop_status);
                drop(stage);
            })
            .map_err(|e| ServeError::Other(format!("cannot start the real-time thread: {e}")))?
    };
    let client = ServiceClient::new(req_tx, rep_rx, info.clone(), !spec.is_sim());
    let owner_thread = {
        let shared = OwnerShared {
            status: Arc::clone(&status),
            events: events.clone(),
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
        recordings: opts.recordings.clone(),
        seed: opts.seed,
        spec,
        status,
        loop_status,
        owner: Mutex::new(owner_tx),
        events,
        next_job: AtomicU64::new(0),
        running: Mutex::new(None),
        shutdown: tokio::sync::Notify::new(),
    });
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| ServeError::Other(format!("tokio: {e}")))?;
    let result = rt.block_on(async {
        let listener = bind_socket(&opts.socket, opts.socket_group.as_deref())?;
        tokio::spawn(event_log(opts.recordings.clone(), ctx.events.subscribe()));
        let _ = ctx.events.send(event(
            "daemon_started",
            json!({ "socket": opts.socket, "backend": lock(&ctx.status).backend }),
        ));
        eprintln!(
            "bench serve: {} on {} (backend {})",
            std::process::id(),
            opts.socket.display(),
            lock(&ctx.status).backend
        );
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
            .map_err(|e| ServeError::Other(format!("signals: {e}")))?;
        let mut int = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::interrupt())
            .map_err(|e| ServeError::Other(format!("signals: {e}")))?;
        loop {
            tokio::select! {
                a = listener.accept() => {
                    if let Ok((stream, _)) = a {
                        tokio::spawn(connection(Arc::clone(&ctx), stream));
                    }
                }
                _ = term.recv() => break,
                _ = int.recv() => break,
                _ = ctx.shutdown.notified() => break,
            }
        }
        // Stop safely: the running job ends at 0 A with its recording
        // finished, then the owner disables and returns.
        let running = lock(&ctx.running).clone();
        if let Some(h) = running {
            h.stop.store(true, Ordering::Relaxed);
            // Let the job's client get its (interrupted) response.
            for _ in 0..400 {
                if lock(&ctx.running).is_none() {
                    break;
                }
                tokio::time::sleep(std::time::Duration::from_millis(25)).await;
            }
            tokio::time::sleep(std::time::Duration::from_millis(50)).await;
        }
        let _ = lock(&ctx.owner).send(OwnerCmd::Shutdown);
        Ok::<(), ServeError>(())
    });
    // The owner finishes the job (its recording) before it sees Shutdown.
    let _ = owner_thread.join();
    let _ = rt_thread.join();
    let _ = std::fs::remove_file(&opts.socket);
    result
}
