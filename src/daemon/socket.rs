//! The socket side: socket checks and binding, the JSON-lines connection
//! handler, job submission and progress, the rolling event log. Runs on a
//! single-threaded tokio runtime and talks to the owner through a channel;
//! nothing here can block the loop.

use super::jobs::{job_spec, Accepted};
use super::owner::{JobHandle, OwnerCmd, Reply};
use super::protocol::{
    event, job_request, null_id, parse_request, respond, ApiError, ApiErrorKind, Id, JobStatus,
    Request,
};
use super::{
    lock, Ctx, ServeError, ACCEPT_BACKOFF_MS, CLIENT_GONE_POLL_MS, MAX_CLIENTS, MAX_LINE_BYTES,
    MAX_PENDING_BYTES, WRITE_STALL_TIMEOUT_S,
};
use crate::error::RunError;
use crate::jobs::request::JobRequest;
use serde_json::{json, Value};
use std::io::Write as _;
use std::os::fd::AsRawFd;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use tokio::io::{AsyncBufReadExt, AsyncWriteExt};
use tokio::sync::{broadcast, oneshot};

/// Rolling event log: rotated to `.1` past this size.
pub(super) const EVENT_LOG_MAX_BYTES: u64 = 10 << 20;

/// Checks the socket path and clears a stale socket: refuses a
/// world-writable directory, a non-socket file, and a socket another
/// daemon answers on. The default directory
/// ([`FALLBACK_SOCKET_DIR`](super::FALLBACK_SOCKET_DIR)) is created when
/// missing: mode 0750 (`outputs::DIR_MODE`), given to `group` so its
/// members can reach a 0660 socket.
pub(super) fn prepare_socket(path: &Path, group: Option<&str>) -> Result<(), ServeError> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    if dir == Path::new(super::FALLBACK_SOCKET_DIR) && !dir.exists() {
        create_socket_dir(path, &dir, group)?;
    }
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

/// Creates the default socket directory `dir` (not its parents): mode
/// 0750, its group `group` when given.
fn create_socket_dir(path: &Path, dir: &Path, group: Option<&str>) -> Result<(), ServeError> {
    use std::os::unix::fs::DirBuilderExt;
    let refuse = |why: String| {
        ServeError::Input(RunError::option(
            "socket",
            path.display(),
            format!(
                "{why}: give another socket path with --socket, or set XDG_RUNTIME_DIR to an \
                 absolute path (the default socket is then $XDG_RUNTIME_DIR/bench.sock), or create {} \
                 for this user (systemd: RuntimeDirectory=bench)",
                dir.display()
            ),
        ))
    };
    let gid = group.map(group_id).transpose()?;
    std::fs::DirBuilder::new()
        .mode(crate::outputs::DIR_MODE)
        .create(dir)
        .map_err(|e| refuse(format!("cannot create directory {}: {e}", dir.display())))?;
    // The umask may have taken bits the policy wants: 0750 exactly.
    std::fs::set_permissions(
        dir,
        std::fs::Permissions::from_mode(crate::outputs::DIR_MODE),
    )
    .map_err(|e| refuse(format!("chmod {}: {e}", dir.display())))?;
    if let (Some(g), Some(gid)) = (group, gid) {
        chown_group(dir, gid).map_err(|e| {
            let _ = std::fs::remove_dir(dir);
            ServeError::Input(RunError::option(
                "socket_group",
                g,
                format!("cannot give {} to the group: {e}", dir.display()),
            ))
        })?;
    }
    tracing::info!(dir = %dir.display(), "created the socket directory");
    Ok(())
}

/// The id of group `g`.
fn group_id(g: &str) -> Result<libc::gid_t, ServeError> {
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
        return Err(ServeError::Input(RunError::option(
            "socket_group",
            g,
            "no such group",
        )));
    }
    // SAFETY: gr is non-null.
    Ok(unsafe { (*gr).gr_gid })
}

/// Gives `path` to group `gid`, keeping its owner.
fn chown_group(path: &Path, gid: libc::gid_t) -> std::io::Result<()> {
    let cpath = std::ffi::CString::new(path.as_os_str().as_encoded_bytes())
        .map_err(|_| std::io::Error::other("path has a NUL byte"))?;
    // SAFETY: valid path; uid -1 keeps the owner.
    if unsafe { libc::chown(cpath.as_ptr(), u32::MAX, gid) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

/// Binds the socket owner-only (0600), or 0660 with `group`. With a
/// group the socket is bound under a temporary name beside `path`, given
/// to the group and made 0660 there, then renamed to `path`: it appears at
/// its path only with its final owner and mode (bound and listening under
/// the temporary name, a client of the group could otherwise meet it at
/// 0600 for a moment and be refused).
pub(super) fn bind_socket(
    path: &Path,
    group: Option<&str>,
) -> Result<tokio::net::UnixListener, ServeError> {
    let gid = match group {
        Some(g) => Some((g, group_id(g)?)),
        None => None,
    };
    let bound = match gid {
        Some(_) => {
            let mut name = path.as_os_str().to_owned();
            name.push(format!(".{}.tmp", std::process::id()));
            PathBuf::from(name)
        }
        None => path.to_path_buf(),
    };
    // SAFETY: umask is process-wide and only read/written here, before any
    // other thread creates files.
    let old = unsafe { libc::umask(0o177) };
    let listener = tokio::net::UnixListener::bind(&bound);
    // SAFETY: as above.
    unsafe { libc::umask(old) };
    let listener = listener.map_err(|e| {
        ServeError::Input(RunError::option(
            "socket",
            path.display(),
            format!("cannot bind: {e}"),
        ))
    })?;
    if let Some((g, gid)) = gid {
        if let Err(e) = chown_group(&bound, gid) {
            let _ = std::fs::remove_file(&bound);
            return Err(ServeError::Input(RunError::option(
                "socket_group",
                g,
                format!("cannot give the socket to the group: {e}"),
            )));
        }
        let placed = std::fs::set_permissions(&bound, std::fs::Permissions::from_mode(0o660))
            .and_then(|()| std::fs::rename(&bound, path));
        if let Err(e) = placed {
            let _ = std::fs::remove_file(&bound);
            return Err(ServeError::Other(format!("place the socket: {e}")));
        }
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

/// What a connection queues for its client: lines, counted in bytes
/// against [`MAX_PENDING_BYTES`]. A client whose queue would overflow is
/// disconnected (it does not read its answers); so is one whose socket
/// accepts nothing for [`WRITE_STALL_TIMEOUT_S`].
#[derive(Clone)]
pub(super) struct Outbox {
    tx: tokio::sync::mpsc::UnboundedSender<String>,
    pending: Arc<AtomicUsize>,
    cut: Arc<Cut>,
}

/// Raised when the client is to be disconnected.
#[derive(Default)]
struct Cut {
    flag: AtomicBool,
    notify: tokio::sync::Notify,
}

impl Cut {
    fn raise(&self) {
        self.flag.store(true, Ordering::Relaxed);
        self.notify.notify_one();
    }
}

impl Outbox {
    /// Queues `line` for the client; `false` when the client is gone, or
    /// has just been disconnected because its queue is full.
    pub(super) fn send(&self, line: String) -> bool {
        if self.cut.flag.load(Ordering::Relaxed) {
            return false;
        }
        let n = line.len() + 1;
        if self.pending.fetch_add(n, Ordering::Relaxed) + n > MAX_PENDING_BYTES {
            self.pending.fetch_sub(n, Ordering::Relaxed);
            self.cut.raise();
            return false;
        }
        if self.tx.send(line).is_err() {
            self.pending.fetch_sub(n, Ordering::Relaxed);
            return false;
        }
        true
    }
}

/// Writes a connection's queue to its socket, one line at a time.
async fn write_lines(
    mut wr: tokio::net::unix::OwnedWriteHalf,
    mut rx: tokio::sync::mpsc::UnboundedReceiver<String>,
    pending: Arc<AtomicUsize>,
    cut: Arc<Cut>,
) {
    let stall = std::time::Duration::from_secs(WRITE_STALL_TIMEOUT_S);
    while let Some(line) = rx.recv().await {
        let n = line.len() + 1;
        let mut bytes = line.into_bytes();
        bytes.push(b'\n');
        match tokio::time::timeout(stall, wr.write_all(&bytes)).await {
            Ok(Ok(())) => {}
            // Gone, or not reading for WRITE_STALL_TIMEOUT_S.
            Ok(Err(_)) | Err(_) => {
                cut.raise();
                return;
            }
        }
        pending.fetch_sub(n, Ordering::Relaxed);
    }
}

/// How a bounded line read ended.
enum LineRead {
    /// A line is in the buffer (its newline and a trailing CR removed; a
    /// last line without newline counts).
    Line,
    /// The client closed its side.
    Eof,
    /// More than [`MAX_LINE_BYTES`] without a newline; the rest is left
    /// unread.
    TooLong,
}

/// Reads one line into `buf` (cleared first); `buf` never holds more than
/// `max` bytes.
async fn read_line_bounded<R: tokio::io::AsyncBufRead + Unpin>(
    r: &mut R,
    buf: &mut Vec<u8>,
    max: usize,
) -> std::io::Result<LineRead> {
    buf.clear();
    loop {
        let chunk = r.fill_buf().await?;
        if chunk.is_empty() {
            return Ok(if buf.is_empty() {
                LineRead::Eof
            } else {
                LineRead::Line
            });
        }
        let (content, used) = match chunk.iter().position(|&b| b == b'\n') {
            Some(i) => (i, Some(i + 1)),
            None => (chunk.len(), None),
        };
        if buf.len() + content > max {
            return Ok(LineRead::TooLong);
        }
        buf.extend_from_slice(&chunk[..content]);
        r.consume(used.unwrap_or(content));
        if used.is_some() {
            if buf.last() == Some(&b'\r') {
                buf.pop();
            }
            return Ok(LineRead::Line);
        }
    }
}

/// Accepts clients for ever: at most [`MAX_CLIENTS`] at once (one more is
/// told `busy` and closed). Out of file descriptors, it refuses the
/// waiting client through a reserved descriptor (so it does not hang in
/// the backlog) and pauses accepting for [`ACCEPT_BACKOFF_MS`] instead of
/// spinning; connected clients are served all along.
pub(super) async fn accept_clients(ctx: Arc<Ctx>, listener: tokio::net::UnixListener) {
    let slots = Arc::new(tokio::sync::Semaphore::new(MAX_CLIENTS));
    let reserve_fd = || std::fs::File::open("/dev/null").ok();
    let mut reserve = reserve_fd();
    // Warn once per run of exhaustion, not every back-off.
    let mut exhausted_since_accept = false;
    let refuse = |stream: tokio::net::UnixStream, why: String| {
        let line = respond(&null_id(), Err(ApiError::new(ApiErrorKind::Busy, why))) + "\n";
        // Best effort, without waiting: the line fits in an empty socket
        // buffer. (tokio's `try_write` would refuse a stream whose
        // readiness the runtime has not seen yet.)
        if let Ok(s) = stream.into_std() {
            let _ = (&s).write(line.as_bytes());
        }
    };
    loop {
        match listener.accept().await {
            Ok((stream, _)) => match Arc::clone(&slots).try_acquire_owned() {
                Ok(slot) => {
                    exhausted_since_accept = false;
                    tokio::spawn(connection(Arc::clone(&ctx), stream, slot));
                }
                Err(_) => refuse(
                    stream,
                    format!("too many clients: at most {MAX_CLIENTS} at once; try again later"),
                ),
            },
            Err(e) => {
                let exhausted = matches!(
                    e.raw_os_error(),
                    Some(libc::EMFILE | libc::ENFILE | libc::ENOBUFS | libc::ENOMEM)
                );
                if exhausted {
                    if reserve.take().is_some() {
                        let zero = std::time::Duration::ZERO;
                        if let Ok(Ok((stream, _))) =
                            tokio::time::timeout(zero, listener.accept()).await
                        {
                            refuse(
                                stream,
                                format!(
                                    "the daemon is out of file descriptors ({e}); try again later"
                                ),
                            );
                        }
                        reserve = reserve_fd();
                    }
                    if !std::mem::replace(&mut exhausted_since_accept, true) {
                        tracing::warn!(
                            "accept: {e}; refusing new clients and pausing {ACCEPT_BACKOFF_MS} ms between tries until descriptors are free"
                        );
                    }
                    tokio::time::sleep(std::time::Duration::from_millis(ACCEPT_BACKOFF_MS)).await;
                } else {
                    // Transient (e.g. a client that gave up): do not spin.
                    tokio::time::sleep(std::time::Duration::from_millis(10)).await;
                }
            }
        }
    }
}

/// Serves one connection; `_slot` is its place among [`MAX_CLIENTS`].
pub(super) async fn connection(
    ctx: Arc<Ctx>,
    stream: tokio::net::UnixStream,
    _slot: tokio::sync::OwnedSemaphorePermit,
) {
    let (rd, wr) = stream.into_split();
    let (tx, rx) = tokio::sync::mpsc::unbounded_channel::<String>();
    let out = Outbox {
        tx,
        pending: Arc::new(AtomicUsize::new(0)),
        cut: Arc::new(Cut::default()),
    };
    let mut writer = tokio::spawn(write_lines(
        wr,
        rx,
        Arc::clone(&out.pending),
        Arc::clone(&out.cut),
    ));
    let mut reader = tokio::io::BufReader::new(rd);
    let mut buf = Vec::new();
    // Jobs this client submitted without `detach`.
    let mut attached: Vec<JobHandle> = Vec::new();
    // Why reading stopped (a cut client is `Gone`).
    let mut ended = Ended::Gone;
    loop {
        let read = tokio::select! {
            r = read_line_bounded(&mut reader, &mut buf, MAX_LINE_BYTES) => r,
            () = out.cut.notify.notified() => break,
        };
        match read {
            Ok(LineRead::Line) => {}
            Ok(LineRead::TooLong) => {
                out.send(respond(
                    &null_id(),
                    Err(ApiError::new(
                        ApiErrorKind::BadRequest,
                        format!(
                            "request line longer than {MAX_LINE_BYTES} bytes; closing the connection"
                        ),
                    )),
                ));
                ended = Ended::Closing;
                break;
            }
            Ok(LineRead::Eof) => {
                ended = Ended::HalfClosed;
                break;
            }
            Err(_) => break,
        }
        // A client that pipelines does not hold the runtime.
        tokio::task::consume_budget().await;
        if buf.iter().all(u8::is_ascii_whitespace) {
            continue;
        }
        let (id, cmd, params) = match parse_request(&buf) {
            Ok(Request { id, cmd, params }) => (id, cmd, params),
            Err((id, e)) => {
                out.send(respond(&id, Err(e)));
                continue;
            }
        };
        let r = match cmd.as_str() {
            "status" => status_now(&ctx),
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
                subscribe(&ctx, &out);
                Ok(json!({ "subscribed": true }))
            }
            "shutdown" => {
                ctx.shutdown.notify_one();
                Ok(json!({ "shutting_down": true }))
            }
            cmd if JobRequest::KINDS.contains(&cmd) => {
                match submit(&ctx, cmd, &params, &id, &out) {
                    Ok(attach) => {
                        attached.extend(attach);
                        continue; // the job task responds
                    }
                    Err(e) => Err(e),
                }
            }
            other => Err(ApiError::new(
                ApiErrorKind::UnknownCommand,
                format!("unknown command {other:?} (status, enable, disable, reset, {}, stop, subscribe, shutdown)", JobRequest::KINDS.join(", ")),
            )),
        };
        out.send(respond(&id, r));
    }
    // Nothing more is read: a disconnected client's unread input stays
    // unread. `reader` is kept until the end: its descriptor is the one
    // watched for the client's hang-up.
    let fd = reader.get_ref().as_ref().as_raw_fd();
    if matches!(ended, Ended::HalfClosed) && !out.cut.flag.load(Ordering::Relaxed) {
        // End of input is not the client leaving: a client that has shut
        // down its sending side (`socat` at the end of its input) still
        // reads. Its jobs run on, their events and answers go out, and the
        // connection closes once everything is answered (the writer ends
        // when the last job task and subscription let go of the outbox),
        // unless the client goes away meanwhile: its socket hangs up or a
        // write fails.
        let cut = Arc::clone(&out.cut);
        drop(out);
        let gone = tokio::select! {
            biased;
            // Everything answered, or a write failed (the writer cut it).
            _ = &mut writer => cut.flag.load(Ordering::Relaxed),
            () = cut.notify.notified() => true,
            () = hung_up(fd) => true,
        };
        if gone {
            stop_attached(&ctx, attached);
            writer.abort();
        }
        drop(reader);
        return;
    }
    // The client is gone: its attached jobs stop (the unattended rule).
    stop_attached(&ctx, attached);
    if out.cut.flag.load(Ordering::Relaxed) {
        // Disconnected: what is queued is dropped with the socket.
        writer.abort();
        return;
    }
    let cut = Arc::clone(&out.cut);
    drop(out);
    // Answers still queued (and those of a detached job's task) go out,
    // unless the client stops reading or hangs up.
    tokio::select! {
        _ = &mut writer => {}
        () = cut.notify.notified() => writer.abort(),
        () = hung_up(fd) => writer.abort(),
    }
    drop(reader);
}

/// The answer to `status`: the daemon's state, with the loop's last
/// reading, the store's state and the running job's progress as of now.
fn status_now(ctx: &Ctx) -> Result<Value, ApiError> {
    let mut s = lock(&ctx.status).clone();
    s.position_m = ctx.loop_status.position_m();
    s.command_a = ctx.loop_status.command_a();
    s.store = ctx.store.as_ref().map(super::uploads::StoreProbe::status);
    if let (Some(j), Some(h)) = (s.job.as_mut(), lock(&ctx.running).as_ref()) {
        j.ticks = h.ticks.load(Ordering::Relaxed);
    }
    serde_json::to_value(s).map_err(|e| ApiError::new(ApiErrorKind::Error, e.to_string()))
}

/// `subscribe`: every event from now on goes to `out`, until the client
/// is gone or the daemon ends (a client too slow to keep up loses the
/// events it lagged behind, never the connection).
fn subscribe(ctx: &Ctx, out: &Outbox) {
    let mut rx = ctx.events.subscribe();
    let out = out.clone();
    tokio::spawn(async move {
        loop {
            match rx.recv().await {
                Ok(l) => {
                    if !out.send(l) {
                        return;
                    }
                }
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => return,
            }
        }
    });
}

/// How a connection's reading ended.
enum Ended {
    /// End of input: the client shut down its sending side (or closed;
    /// [`hung_up`] tells which).
    HalfClosed,
    /// The daemon closes the connection (a line over the limit).
    Closing,
    /// A read failed, or the client was cut off (not reading).
    Gone,
}

/// The client is gone: the jobs it submitted without `detach` stop (the
/// unattended rule), each with a `client_left` event.
fn stop_attached(ctx: &Ctx, attached: Vec<JobHandle>) {
    for h in attached {
        if lock(&ctx.running).as_ref().is_some_and(|r| r.id == h.id) {
            h.stop.store(true, Ordering::Relaxed);
            let _ = ctx.events.send(event(
                "client_left",
                json!({ "job": h.id, "action": "job stopped (not detached)" }),
            ));
        }
    }
}

/// Whether the peer of the Unix stream socket `fd` is gone: it closed its
/// end (or shut down both directions), so nothing written reaches anyone.
/// A peer that only shut down its sending side is not gone. Linux reports
/// the difference as `POLLHUP` (both directions shut down on this socket)
/// or `POLLERR`; a half-close alone raises neither.
fn peer_gone(fd: std::os::fd::RawFd) -> bool {
    let mut p = libc::pollfd {
        fd,
        events: 0,
        revents: 0,
    };
    // SAFETY: one valid pollfd, a zero timeout; `fd` is open (the caller
    // holds the stream).
    let n = unsafe { libc::poll(&mut p, 1, 0) };
    n > 0 && p.revents & (libc::POLLHUP | libc::POLLERR) != 0
}

/// Completes when the client of `fd` is gone ([`peer_gone`]), checked at
/// once and then every [`CLIENT_GONE_POLL_MS`].
async fn hung_up(fd: std::os::fd::RawFd) {
    let mut every = tokio::time::interval(std::time::Duration::from_millis(CLIENT_GONE_POLL_MS));
    every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        every.tick().await;
        if peer_gone(fd) {
            return;
        }
    }
}

/// Starts a job: checks busy/faulted, hands it to the owner, and spawns
/// the task that streams progress and sends the response. Returns the job
/// to stop when this client leaves (`None`: detached).
pub(super) fn submit(
    ctx: &Arc<Ctx>,
    cmd: &str,
    params: &Value,
    id: &Id,
    out: &Outbox,
) -> Result<Option<JobHandle>, ApiError> {
    let job_id = ctx.next_job.fetch_add(1, Ordering::Relaxed) + 1;
    let (request, detach) = job_request(cmd, params)?;
    let Accepted {
        spec,
        total,
        recording,
    } = job_spec(ctx, &request, job_id)?;
    let kind = request.kind();
    let handle = JobHandle {
        id: job_id,
        kind,
        stop: Arc::new(AtomicBool::new(false)),
        ticks: Arc::new(AtomicU64::new(0)),
    };
    let before = {
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
        let before = status.state;
        status.state = "running";
        status.job = Some(JobStatus {
            id: job_id,
            kind,
            ticks: 0,
            total_ticks: total,
            recording: recording.as_ref().map(|r| r.display().to_string()),
            detach,
        });
        before
    };
    let (tx, rx) = oneshot::channel();
    if lock(&ctx.owner)
        .send(OwnerCmd::Job(spec, handle.clone(), before, tx))
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
    out.send(started);
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
                    out.send(p.clone());
                    let _ = ctx.events.send(p);
                }
            }
        };
        *lock(&ctx.running) = None;
        // A bench job's summary names its recording (it does already;
        // kept for clients of older summaries). The other jobs' summaries
        // are sent as the library gives them, equal to a local run's.
        let result = result.map(|mut v| {
            if let (Some(o), Some(r)) = (v.as_object_mut(), &recording) {
                o.insert("recording".into(), json!(r));
            }
            v
        });
        let fin = event(
            "job_finished",
            json!({ "job": h.id, "kind": kind, "ok": result.is_ok(), "error": result.as_ref().err() }),
        );
        let _ = ctx.events.send(fin.clone());
        out.send(fin);
        out.send(respond(&id, result));
    });
    Ok((!detach).then_some(handle))
}

#[cfg(test)]
mod tests {
    use super::*;

    async fn lines(input: &[u8], max: usize) -> Vec<Result<Vec<u8>, &'static str>> {
        let mut r = tokio::io::BufReader::with_capacity(4, input);
        let mut buf = Vec::new();
        let mut out = Vec::new();
        loop {
            match read_line_bounded(&mut r, &mut buf, max).await.unwrap() {
                LineRead::Line => out.push(Ok(buf.clone())),
                LineRead::TooLong => {
                    out.push(Err("too long"));
                    return out;
                }
                LineRead::Eof => return out,
            }
        }
    }

    #[test]
    fn lines_are_bounded() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        rt.block_on(async {
            assert_eq!(
                lines(b"ab\r\n\ncdefgh\nxy", 6).await,
                vec![
                    Ok(b"ab".to_vec()),
                    Ok(vec![]),
                    Ok(b"cdefgh".to_vec()),
                    Ok(b"xy".to_vec())
                ]
            );
            assert_eq!(
                lines(b"abc\nabcdefg\nnever read", 6).await,
                vec![Ok(b"abc".to_vec()), Err("too long")]
            );
            assert_eq!(lines(b"abcdefg", 6).await, vec![Err("too long")]);
        });
    }
}
