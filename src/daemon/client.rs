//! The client side of `bench serve`: `bench chirp|control --daemon [SOCKET]`
//! submit their job over the socket, show its progress, and get the same
//! summary as a local run; `bench daemon …` sends one command
//! ([`request`]).

use crate::daemon::ApiErrorKind;
use crate::jobs::request::JobRequest;
use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::Path;

/// Why a request did not get its answer.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The socket could not be reached (no daemon, no permission).
    #[error("daemon socket {path}: {reason}")]
    Connect {
        /// The socket.
        path: String,
        /// Why.
        reason: String,
    },
    /// The path cannot be a daemon's socket at all: it is a directory or
    /// another kind of file, or it is too long for a socket address.
    #[error("daemon socket {path}: {reason}")]
    NotASocket {
        /// The path.
        path: String,
        /// What it is instead.
        reason: String,
    },
    /// The daemon answered with an error.
    #[error("daemon: {}: {message}", serde_json::to_value(kind).ok().and_then(|v| v.as_str().map(str::to_string)).unwrap_or_default())]
    Api {
        /// Error kind.
        kind: ApiErrorKind,
        /// Message.
        message: String,
        /// The run's summary, for a job that ended without its own (a
        /// fault, a HAL error, a stop) but with a finished recording: the
        /// outcome, the fault, the recording and its catalogue row, as a
        /// local run's `--json` prints it.
        summary: Option<Value>,
    },
    /// The connection broke or the daemon sent something unexpected.
    #[error("daemon connection: {0}")]
    Io(String),
}

/// Connects to the daemon at `socket`. A failure says why in the
/// operator's terms: nothing serving there, permission, or a path that is
/// not a socket.
fn connect(socket: &Path) -> Result<UnixStream, ClientError> {
    UnixStream::connect(socket).map_err(|e| {
        let path = socket.display().to_string();
        use std::os::unix::fs::FileTypeExt;
        let what = match std::fs::metadata(socket) {
            Ok(m) if m.is_dir() => Some("a directory"),
            Ok(m) if !m.file_type().is_socket() => Some("a file that is not a socket"),
            _ => None,
        };
        if let Some(what) = what {
            return ClientError::NotASocket {
                path,
                reason: format!("is {what}; give the socket `bench serve` listens on"),
            };
        }
        match e.kind() {
            std::io::ErrorKind::InvalidInput => ClientError::NotASocket {
                path,
                reason: format!("not usable as a socket address ({e})"),
            },
            std::io::ErrorKind::NotFound | std::io::ErrorKind::ConnectionRefused => {
                ClientError::Connect {
                    path,
                    reason: format!(
                        "no daemon is serving there ({e}); start one with `bench serve`"
                    ),
                }
            }
            std::io::ErrorKind::PermissionDenied => ClientError::Connect {
                path,
                reason: format!("permission denied ({e}): the socket is owner-only unless the daemon ran with --socket-group"),
            },
            _ => ClientError::Connect {
                path,
                reason: e.to_string(),
            },
        }
    })
}

/// Sends the request `line` (its `id` is 1) to the daemon at `socket` and
/// waits for its response; events in between go to `on_event`.
fn exchange(
    socket: &Path,
    line: &Value,
    mut on_event: impl FnMut(&Value),
) -> Result<Value, ClientError> {
    let mut stream = connect(socket)?;
    stream
        .write_all(format!("{line}\n").as_bytes())
        .map_err(|e| ClientError::Io(e.to_string()))?;
    let reader = BufReader::new(stream);
    for line in reader.lines() {
        let line = line.map_err(|e| ClientError::Io(e.to_string()))?;
        let v: Value = serde_json::from_str(&line)
            .map_err(|e| ClientError::Io(format!("not JSON from the daemon: {e}")))?;
        if v.get("event").is_some() {
            on_event(&v);
            continue;
        }
        if v.get("id") == Some(&json!(1)) {
            if v["ok"] == json!(true) {
                return Ok(v["result"].clone());
            }
            return Err(ClientError::Api {
                kind: serde_json::from_value(v["error"]["kind"].clone())
                    .unwrap_or(ApiErrorKind::Error),
                message: v["error"]["message"].as_str().unwrap_or("").to_string(),
                summary: v["error"].get("summary").filter(|s| s.is_object()).cloned(),
            });
        }
    }
    Err(ClientError::Io(
        "the daemon closed the connection before answering".into(),
    ))
}

/// Submits `job` to the daemon at `socket` (`{"id": 1, "cmd": KIND,
/// "params": {...}}`, attached: the job stops if this client goes away)
/// and waits for the response, the job's summary. Events in between go to
/// `on_event`.
///
/// # Errors
/// [`ClientError`].
pub fn submit(
    socket: &Path,
    job: &JobRequest,
    on_event: impl FnMut(&Value),
) -> Result<Value, ClientError> {
    let mut line = serde_json::to_value(job).map_err(|e| ClientError::Io(e.to_string()))?;
    line["id"] = json!(1);
    exchange(socket, &line, on_event)
}

/// Sends one command to the daemon at `socket` (`{"id": 1, "cmd": CMD,
/// "params": PARAMS}`) and returns its `result`. For the commands that
/// answer at once (`status`, `enable`, `disable`, `reset`, `stop`,
/// `shutdown`); a job's events would be skipped.
///
/// # Errors
/// [`ClientError`]: [`ClientError::Api`] when the daemon refuses.
pub fn request(socket: &Path, cmd: &str, params: Value) -> Result<Value, ClientError> {
    exchange(
        socket,
        &json!({ "id": 1, "cmd": cmd, "params": params }),
        |_| {},
    )
}
