//! `bench serve --upload URL`: the daemon's side of the uploads
//! ([`crate::upload`]): the store opened and probed before the bench is
//! opened ([`start`]), and each finished job's recording queued with its
//! summary ([`after_job`]).

use super::jobs::JobResult;
use super::protocol::event;
use crate::error::RunError;
use crate::upload::journal::JOURNAL_FILE;
use crate::upload::worker::{UploadEvent, Uploader};
use crate::upload::{ProbeError, Store, StoreUrl};
use serde_json::json;
use std::io::Write as _;
use std::path::Path;
use tokio::sync::broadcast;

/// Opens the store of `--upload`, probes it, and starts the uploader with
/// the journal in `recordings`. A store that refuses (no such bucket,
/// credentials refused, an `http://` endpoint not allowed) stops the
/// daemon before it opens the bench; one that does not answer is an
/// outage: the daemon starts, says so on stderr, and uploads when it
/// answers.
///
/// # Errors
/// [`RunError::BadOption`] naming `upload`.
pub(super) fn start(
    url: StoreUrl,
    recordings: &Path,
    loop_cpu: Option<usize>,
    events: broadcast::Sender<String>,
) -> Result<Uploader, RunError> {
    let shown = url.to_string();
    let refuse = |reason: String| RunError::option("upload", &shown, reason);
    let timeout = std::time::Duration::from_secs_f64(crate::upload::store::DEFAULT_TIMEOUT_S);
    let store = Store::open(url, timeout).map_err(refuse)?;
    let probe = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| refuse(format!("tokio: {e}")))?
        .block_on(store.probe());
    match probe {
        Ok(()) => {}
        Err(ProbeError::Refused(reason)) => return Err(refuse(reason)),
        Err(ProbeError::Unreachable(reason)) => {
            let _ = writeln!(
                std::io::stderr(),
                "bench serve: warning: --upload {shown}: {reason}; the recordings are kept and queued in {}, and uploaded when the store answers",
                recordings.join(JOURNAL_FILE).display()
            );
        }
    }
    let on_event = Box::new(move |ev: UploadEvent| {
        let line = match &ev {
            UploadEvent::Confirmed(t) => {
                tracing::info!(
                    url = %t.url,
                    size_bytes = t.size_bytes,
                    uploaded = t.uploaded,
                    "upload confirmed (SHA-256 read back)"
                );
                event("upload_confirmed", json!(t))
            }
            UploadEvent::Failed {
                key,
                error,
                retry_in_s,
            } => {
                tracing::warn!(key = %key, retry_in_s, "upload failed: {error}");
                event(
                    "upload_failed",
                    json!({ "key": key, "error": error, "retry_in_s": retry_in_s }),
                )
            }
            UploadEvent::Dropped { key, reason } => {
                tracing::error!(key = %key, "upload dropped (the local file is kept): {reason}");
                event("upload_dropped", json!({ "key": key, "reason": reason }))
            }
        };
        let _ = events.send(line);
    });
    Uploader::start(store, &recordings.join(JOURNAL_FILE), loop_cpu, on_event).map_err(refuse)
}

/// After a job that wrote `recording`: when the recording is finished
/// (the file exists; a job that never started or was killed left none or
/// a `.part`), writes the job's summary beside it (`<stem>.summary.json`:
/// the summary a client got, or for a run that ended without one the
/// `error.summary` the daemon answered with, as `--json` prints it) and queues them for the store.
/// Never fails the job: a problem is logged.
pub(super) fn after_job(uploader: &Uploader, recording: &Path, result: &JobResult) {
    if !recording.is_file() {
        return;
    }
    let summary = match result {
        Ok(v) => {
            let mut v = v.clone();
            if let Some(o) = v.as_object_mut() {
                o.insert("recording".into(), json!(recording));
            }
            v
        }
        Err((api, _)) => api.summary.as_deref().cloned().unwrap_or_else(|| {
            json!({
                "outcome": api.kind,
                "error": api.message,
                "recording": recording,
            })
        }),
    };
    let path = crate::outputs::beside(recording, ".summary.json");
    let written = crate::outputs::write_atomically(&path, crate::outputs::Existing::Refuse, |f| {
        serde_json::to_writer_pretty(&mut *f, &summary)?;
        f.write_all(b"\n")
    });
    if let Err(e) = written {
        tracing::warn!("the summary {} was not written: {e}", path.display());
    }
    queue(uploader, recording);
}

/// Queues `path` (a recording or a campaign directory), saying so in the
/// log; a failure is logged, never the job's.
fn queue(uploader: &Uploader, path: &Path) {
    match uploader.queue_recording(path) {
        Ok(n) => tracing::info!(
            path = %path.display(),
            "{n} file(s) queued for {}",
            uploader.url()
        ),
        Err(e) => tracing::error!(
            path = %path.display(),
            "not queued for {}: {e}",
            uploader.url()
        ),
    }
}

/// After a campaign job: a campaign that finished (every cell done) is
/// queued as its directory ([`crate::upload::campaign_upload_set`]: the
/// cells' kept files, their catalogue rows, the campaign's results). One
/// that was stopped or failed is not (its results would change when it
/// is resumed, and the store never overwrites): the log says so, and
/// `bench upload --to URL DIR` uploads it once `bench campaign resume`
/// has finished it. Never fails the job.
pub(super) fn after_campaign(uploader: &Uploader, result: &JobResult) {
    let dir = match result {
        Ok(v) => v
            .get("dir")
            .and_then(|d| d.as_str())
            .map(std::path::PathBuf::from),
        Err((api, _)) => {
            tracing::warn!(
                "the campaign did not finish ({}): not queued for {}; `bench campaign resume` it, then `bench upload --to {} DIR`",
                api.message,
                uploader.url(),
                uploader.url()
            );
            return;
        }
    };
    let Some(dir) = dir else {
        tracing::error!("the campaign's summary names no directory: not queued");
        return;
    };
    queue(uploader, &dir);
}
