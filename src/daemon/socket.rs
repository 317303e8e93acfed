//! The socket side: socket checks and binding, the JSON-lines connection
//! handler, job submission and progress, the rolling event log. Runs on a
//! single-threaded tokio runtime and talks to the owner through a channel;
//! nothing here can block the loop.

use super::owner::{job_spec, JobHandle, OwnerCmd, Reply};
use super::protocol::{event, job_request, respond, ApiError, ApiErrorKind, JobStatus};
use super::{lock, Ctx, ServeError};
use crate::error::RunError;
use serde_json::{json, Value};
use std::io::Write as _;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use tokio::io::{AsyncBufReadExt, AsyncWriteExt};
use tokio::sync::{broadcast, oneshot};

/// Rolling event log: rotated to `.1` past this size.
pub(super) const EVENT_LOG_MAX_BYTES: u64 = 10 << 20;

/// Checks the socket path and clears a stale socket: refuses a
/// world-writable directory, a non-socket file, and a socket another
/// daemon answers on.
pub(super) fn prepare_socket(path: &Path) -> Result<(), ServeError> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let meta = std::fs::metadata(&dir).map_err(|e| {
        ServeError::Input(RunError::option(
            "socket",
            path.display(),
            format!("directory {}: {e}", dir.display()),
        ))
    })?;
    if meta.permissions().mode() & 0o002 != 0 {
        return Err(ServeError::Input(RunError::option("socket", path.display(), format!("directory {} is world-writable (mode {:o}); use a private directory such as $XDG_RUNTIME_DIR", dir.display(), meta.permissions().mode() & 0o7777))));
    }
    match std::fs::symlink_metadata(path) {
        Err(_) => Ok(()),
        Ok(m) => {
            use std::os::unix::fs::FileTypeExt;
            if !m.file_type().is_socket() {
                return Err(ServeError::Input(RunError::option(
                    "socket",
                    path.display(),
                    "exists and is not a socket; not touching it",
                )));
            }
            match std::os::unix::net::UnixStream::connect(path) {
                Ok(_) => Err(ServeError::Input(RunError::option(
                    "socket",
                    path.display(),
                    "another bench daemon is serving there",
                ))),
                Err(_) => std::fs::remove_file(path).map_err(|e| {
                    ServeError::Input(RunError::option(
                        "socket",
                        path.display(),
                        format!("stale socket cannot be removed: {e}"),
                    ))
                }),
            }
        }
    }
}

/// Binds the socket owner-only (0600), or 0660 with `group`.
pub(super) fn bind_socket(
    path: &Path,
    group: Option<&str>,
) -> Result<tokio::net::UnixListener, ServeError> {
    // SAFETY: umask is process-wide and only read/written here, before any
    // other thread creates files.
    let old = unsafe { libc::umask(0o177) };
    let listener = tokio::net::UnixListener::bind(path);
    // SAFETY: as above.
    unsafe { libc::umask(old) };
    let listener = listener.map_err(|e| {
        ServeError::Input(RunError::option(
            "socket",
            path.display(),
            format!("cannot bind: {e}"),
        ))
    })?;
    if let Some(g) = group {
        let cname = std::ffi::CString::new(g).map_err(|_| {
            ServeError::Input(RunError::option(
                "socket_group",
                format!("{g:?}"),
                "not a name",
            ))
        })?;
        // SAFETY: valid C string; getgrnam returns null or a static record.
        let gr = unsafe { libc::getgrnam(cname.as_ptr()) };
        if gr.is_null() {
            let _ = std::fs::remove_file(path);
            return Err(ServeError::Input(RunError::option(
                "socket_group",
                g,
                "no such group",
            )));
        }
        // SAFETY: gr is non-null.
        let gid = unsafe { (*gr).gr_gid };
        let cpath = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).map_err(|_| {
            ServeError::Input(RunError::option("socket", "", "path has a NUL byte"))
        })?;
        // SAFETY: valid path; uid -1 keeps the owner.
        if unsafe { libc::chown(cpath.as_ptr(), u32::MAX, gid) } != 0 {
            let e = std::io::Error::last_os_error();
            let _ = std::fs::remove_file(path);
            return Err(ServeError::Input(RunError::option(
                "socket_group",
                g,
                format!("cannot give the socket to the group: {e}"),
            )));
        }
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o660))
            .map_err(|e| ServeError::Other(format!("chmod socket: {e}")))?;
    }
    Ok(listener)
}

/// Appends events to `dir/daemon-events.jsonl`, rotating to `.1` past
/// [`EVENT_LOG_MAX_BYTES`].
pub(super) async fn event_log(dir: PathBuf, mut rx: broadcast::Receiver<String>) {
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
        // Created with the mode of every output (crate::outputs::FILE_MODE).
        if let Ok(mut f) = std::os::unix::fs::OpenOptionsExt::mode(
            std::fs::OpenOptions::new().create(true).append(true),
            crate::outputs::FILE_MODE,
        )
        .open(&path)
        {
            let _ = writeln!(f, "{line}");
        }
    }
}

pub(super) async fn owner_call<T>(
    ctx: &Ctx,
    make: impl FnOnce(Reply<T>) -> OwnerCmd,
) -> Result<T, ApiError> {
    let (tx, rx) = oneshot::channel();
    lock(&ctx.owner)
        .send(make(tx))
        .map_err(|_| ApiError::new(ApiErrorKind::Error, "the bench owner thread is gone"))?;
    rx.await
        .map_err(|_| ApiError::new(ApiErrorKind::Error, "the bench owner thread is gone"))?
}

/// Serves one connection.
pub(super) async fn connection(ctx: Arc<Ctx>, stream: tokio::net::UnixStream) {
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
                    Err(ApiError::new(
                        ApiErrorKind::BadRequest,
                        format!("not JSON: {e}"),
                    )),
                ));
                continue;
            }
        };
        let id = req.get("id").cloned().unwrap_or(Value::Null);
        let Some(cmd) = req.get("cmd").and_then(Value::as_str).map(str::to_string) else {
            let _ = out.send(respond(
                &id,
                Err(ApiError::new(ApiErrorKind::BadRequest, "no \"cmd\" string")),
            ));
            continue;
        };
        let params = req.get("params").cloned().unwrap_or(Value::Null);
        let r = match cmd.as_str() {
            "status" => {
                let mut s = lock(&ctx.status).clone();
                s.position_m = ctx.loop_status.position_m();
                s.command_a = ctx.loop_status.command_a();
                if let (Some(j), Some(h)) = (s.job.as_mut(), lock(&ctx.running).as_ref()) {
                    j.ticks = h.ticks.load(Ordering::Relaxed);
                }
                serde_json::to_value(s).map_err(|e| ApiError::new(ApiErrorKind::Error, e.to_string()))
            }
            "enable" | "disable" | "reset" if lock(&ctx.running).is_some() => Err(ApiError::new(
                ApiErrorKind::Busy,
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
                ApiErrorKind::UnknownCommand,
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
pub(super) fn submit(
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
                ApiErrorKind::Busy,
                format!("job {} is running; one job at a time", r.id),
            ));
        }
        if status.state == "faulted" {
            return Err(ApiError::new(
                ApiErrorKind::Faulted,
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
        return Err(ApiError::new(
            ApiErrorKind::Error,
            "the bench owner thread is gone",
        ));
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
                r = &mut rx => break r.unwrap_or_else(|_| Err(ApiError::new(ApiErrorKind::Error, "the bench owner thread is gone"))),
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
