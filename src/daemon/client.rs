//! The client side of `bench serve`: `bench chirp|control --daemon [SOCKET]`
//! submit their job over the socket, show its progress, and get the same
//! summary as a local run.

use crate::daemon::ApiErrorKind;
use crate::jobs::request::JobRequest;
use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Write};
use std::path::Path;

/// Why a submitted job did not produce a summary.
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
    /// The daemon answered with an error.
    #[error("daemon: {}: {message}", serde_json::to_value(kind).ok().and_then(|v| v.as_str().map(str::to_string)).unwrap_or_default())]
    Api {
        /// Error kind.
        kind: ApiErrorKind,
        /// Message.
        message: String,
    },
    /// The connection broke or the daemon sent something unexpected.
    #[error("daemon connection: {0}")]
    Io(String),
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
    mut on_event: impl FnMut(&Value),
) -> Result<Value, ClientError> {
    let mut line = serde_json::to_value(job).map_err(|e| ClientError::Io(e.to_string()))?;
    line["id"] = json!(1);
    let mut stream = std::os::unix::net::UnixStream::connect(socket).map_err(|e| {
        ClientError::Connect {
            path: socket.display().to_string(),
            reason: match e.kind() {
                std::io::ErrorKind::NotFound | std::io::ErrorKind::ConnectionRefused => {
                    format!("no daemon is serving there ({e}); start one with `bench serve`")
                }
                std::io::ErrorKind::PermissionDenied => {
                    format!("permission denied ({e}): the socket is owner-only unless the daemon ran with --socket-group")
                }
                _ => e.to_string(),
            },
        }
    })?;
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
            });
        }
    }
    Err(ClientError::Io(
        "the daemon closed the connection before answering".into(),
    ))
}
