//! `bench serve --upload URL`: the daemon's side of the uploads
//! ([`crate::upload`]): the store opened and probed in the background,
//! the bench opened once the probe answered or after
//! [`STORE_PROBE_GRACE_MS`] ([`start`]), the store's state kept for
//! `status` ([`StoreProbe`]), and each finished job's recording queued
//! with its summary ([`after_job`]).

use super::jobs::JobResult;
use super::lock;
use super::protocol::{event, StoreState, StoreStatus};
use super::STORE_PROBE_GRACE_MS;
use crate::error::RunError;
use crate::upload::journal::JOURNAL_FILE;
use crate::upload::worker::{UploadEvent, Uploader, FIRST_BACKOFF_S, MAX_BACKOFF_S};
use crate::upload::{ProbeError, Store, StoreUrl};
use serde_json::json;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::broadcast;

/// The store's state, shared by the probe's thread, the uploader's
/// (a confirmed upload: the store answers) and the socket (`status`).
struct ProbeShared {
    inner: Mutex<ProbeInner>,
    /// Notified at each change of the state (the grace's wait).
    changed: Condvar,
    events: broadcast::Sender<String>,
    /// The journal, for the messages.
    journal: PathBuf,
}

struct ProbeInner {
    status: StoreStatus,
    /// The grace is over and the daemon went on to open the bench: a
    /// refusal found from now on is reported, never fatal.
    started: bool,
}

impl ProbeShared {
    /// Sets the store's state and reason; a change is logged, sent as an
    /// `upload_store` event and, for the outcomes an operator must see
    /// (the store not answering, refusing after the daemon started), said
    /// on stderr.
    fn set(&self, state: StoreState, reason: Option<String>) {
        let mut g = lock(&self.inner);
        let was = g.status.state;
        g.status.state = state;
        g.status.reason.clone_from(&reason);
        let url = g.status.url.clone();
        let started = g.started;
        drop(g);
        self.changed.notify_all();
        if was == state {
            return;
        }
        let why = reason.as_deref().unwrap_or("");
        let journal = self.journal.display();
        match state {
            StoreState::Probing => {}
            StoreState::Answering => tracing::info!(url = %url, "the store answers"),
            StoreState::Unreachable => {
                tracing::warn!(url = %url, "the store does not answer: {why}");
                let _ = writeln!(
                    std::io::stderr(),
                    "bench serve: warning: --upload {url}: {why}; the recordings are kept and queued in {journal}, and uploaded when the store answers (`status` shows the store)"
                );
            }
            // Before the grace is over the refusal stops the daemon
            // ([`start`] says so); after it the daemon runs on.
            StoreState::Refused if started => {
                tracing::error!(url = %url, "the store refused: {why}");
                let _ = writeln!(
                    std::io::stderr(),
                    "bench serve: error: --upload {url}: {why}; the daemon runs on and keeps the recordings queued in {journal} (retried with the uploader's backoff); fix the store, or restart the daemon with another --upload"
                );
            }
            StoreState::Refused => {}
        }
        let _ = self.events.send(event(
            "upload_store",
            json!({ "url": url, "state": state, "reason": reason }),
        ));
    }
}

/// The store of `--upload` as the daemon knows it: probed in the
/// background (a listing under the prefix, [`Store::probe`]) until it
/// answers or refuses, the probe tried again while it does not answer
/// (backoff from [`FIRST_BACKOFF_S`] doubling to [`MAX_BACKOFF_S`]).
/// Dropping it stops the probe (not waited for).
pub(super) struct StoreProbe {
    shared: Arc<ProbeShared>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
}

impl StoreProbe {
    /// The store's state now, for `status`.
    pub(super) fn status(&self) -> StoreStatus {
        lock(&self.shared.inner).status.clone()
    }
}

impl Drop for StoreProbe {
    fn drop(&mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
    }
}

/// Probes `store` on a thread of its own (`bench-store-probe`, off the
/// loop's CPU) until it answers or refuses, each probe bounded by the
/// store's timeout, reporting each outcome to `shared`.
fn spawn_probe(
    store: Store,
    shared: Arc<ProbeShared>,
    loop_cpu: Option<usize>,
) -> Result<tokio::sync::oneshot::Sender<()>, String> {
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| format!("tokio: {e}"))?;
    std::thread::Builder::new()
        .name("bench-store-probe".into())
        .spawn(move || {
            bench_hal::os::keep_off_cpu(loop_cpu);
            rt.block_on(async move {
                let probing = async {
                    let mut backoff_s = FIRST_BACKOFF_S;
                    loop {
                        match store.probe().await {
                            Ok(()) => return shared.set(StoreState::Answering, None),
                            Err(ProbeError::Refused(m)) => {
                                return shared.set(StoreState::Refused, Some(m));
                            }
                            Err(ProbeError::Unreachable(m)) => {
                                // A confirmed upload may have found it
                                // answering meanwhile.
                                if lock(&shared.inner).status.state == StoreState::Answering {
                                    return;
                                }
                                shared.set(StoreState::Unreachable, Some(m));
                            }
                        }
                        tokio::time::sleep(Duration::from_secs_f64(backoff_s)).await;
                        backoff_s = (backoff_s * 2.0).min(MAX_BACKOFF_S);
                        if lock(&shared.inner).status.state == StoreState::Answering {
                            return;
                        }
                    }
                };
                tokio::select! {
                    () = probing => {}
                    _ = stopped => {}
                }
            });
            // A probe of a directory store that hangs (a NAS) holds a
            // blocking thread: not waited for.
            rt.shutdown_timeout(Duration::from_millis(100));
        })
        .map_err(|e| format!("cannot start the store's probe thread: {e}"))?;
    Ok(stop)
}

/// Opens the store of `--upload` (`timeout_s`: `--store-timeout`, s, to
/// connect and to answer each request), probes it in the background and
/// starts the uploader with the journal in `recordings`.
///
/// Waits at most [`STORE_PROBE_GRACE_MS`] for the probe: a store that
/// refuses within it (no such bucket, credentials refused, an `http://`
/// endpoint not allowed) stops the daemon before it opens the bench. One
/// that has not answered by then, or does not answer, is an outage: the
/// daemon starts (its socket answers), the probe goes on, and
/// [`StoreProbe::status`] reports what it finds; a refusal found then is
/// logged and reported, and the daemon runs on with the recordings queued.
///
/// # Errors
/// [`RunError::BadOption`] naming `store_timeout` (out of
/// [`crate::upload::store::TIMEOUT_RANGE_S`]) or `upload` (no credentials,
/// a refusal within the grace, the journal unreadable, a thread that
/// cannot start).
pub(super) fn start(
    url: StoreUrl,
    timeout_s: f64,
    recordings: &Path,
    loop_cpu: Option<usize>,
    events: broadcast::Sender<String>,
) -> Result<(Uploader, StoreProbe), RunError> {
    let shown = url.to_string();
    let refuse = |reason: String| RunError::option("upload", &shown, reason);
    let timeout = crate::upload::store::check_timeout_s(timeout_s)
        .map_err(|reason| RunError::option("store_timeout", "", reason))?;
    let store = Store::open(url, timeout).map_err(refuse)?;
    let journal = recordings.join(JOURNAL_FILE);
    let shared = Arc::new(ProbeShared {
        inner: Mutex::new(ProbeInner {
            status: StoreStatus {
                url: shown.clone(),
                state: StoreState::Probing,
                reason: None,
                timeout_s: timeout.as_secs_f64(),
            },
            started: false,
        }),
        changed: Condvar::new(),
        events: events.clone(),
        journal: journal.clone(),
    });
    let stop = spawn_probe(store.clone(), Arc::clone(&shared), loop_cpu).map_err(refuse)?;
    let probe = StoreProbe {
        shared: Arc::clone(&shared),
        stop: Some(stop),
    };
    {
        let grace = Duration::from_millis(STORE_PROBE_GRACE_MS);
        let deadline = Instant::now() + grace;
        let mut g = lock(&shared.inner);
        while g.status.state == StoreState::Probing {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            g = shared
                .changed
                .wait_timeout(g, left)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
        if g.status.state == StoreState::Refused {
            return Err(refuse(g.status.reason.clone().unwrap_or_default()));
        }
        if g.status.state == StoreState::Probing {
            tracing::info!(
                url = %shown,
                "the store has not answered within {STORE_PROBE_GRACE_MS} ms: the daemon starts, the probe goes on (`status` shows the store)"
            );
        }
        g.started = true;
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
                // The store answered, whatever the probe last found.
                shared.set(StoreState::Answering, None);
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
    let uploader = Uploader::start(store, &journal, loop_cpu, on_event).map_err(refuse)?;
    Ok((uploader, probe))
}

/// After a job that wrote `recording`: when the recording is finished
/// (the file exists; a job that never started or was killed left none or
/// a `.part`), writes the job's summary beside it (`<stem>.summary.json`:
/// the summary a client got, or for a run that ended without one the
/// `error.summary` the daemon answered with, as `--json` prints it) and queues them for the store.
/// A track job's `recording` is its directory: queued whole, whatever the
/// outcome. Never fails the job: a problem is logged.
pub(super) fn after_job(uploader: &Uploader, recording: &Path, result: &JobResult) {
    if recording.is_dir() {
        // A track job's directory, whatever its outcome (a run that
        // faulted keeps every trial finished and is never resumed): its
        // summary is its own `track.json`.
        if recording
            .join(crate::jobs::track::TRACK_SUMMARY_FILE)
            .is_file()
        {
            queue(uploader, recording);
        }
        return;
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn file_store(dir: &Path) -> StoreUrl {
        StoreUrl::parse(&format!("file://{}", dir.display())).unwrap()
    }

    #[test]
    fn a_store_that_answers_within_the_grace_is_answering_and_announced() {
        let store = tempfile::tempdir().unwrap();
        let recordings = tempfile::tempdir().unwrap();
        let (events, mut rx) = broadcast::channel(16);
        let (_uploader, probe) = start(
            file_store(store.path()),
            2.0,
            recordings.path(),
            None,
            events,
        )
        .unwrap();
        let s = probe.status();
        assert_eq!(s.state, StoreState::Answering, "{s:?}");
        assert_eq!(s.reason, None);
        assert_eq!(s.timeout_s, 2.0);
        assert_eq!(s.url, file_store(store.path()).to_string());
        let ev: serde_json::Value = serde_json::from_str(&rx.blocking_recv().unwrap()).unwrap();
        assert_eq!(ev["event"], "upload_store");
        assert_eq!(ev["state"], "answering");
    }

    #[test]
    fn a_store_timeout_out_of_range_names_its_flag() {
        let store = tempfile::tempdir().unwrap();
        let recordings = tempfile::tempdir().unwrap();
        for bad in [0.0, 0.49, 300.5, f64::NAN, f64::INFINITY, -1.0] {
            let (events, _) = broadcast::channel(16);
            let Err(e) = start(
                file_store(store.path()),
                bad,
                recordings.path(),
                None,
                events,
            ) else {
                panic!("{bad} s accepted");
            };
            assert!(
                matches!(
                    e,
                    RunError::BadOption {
                        key: "store_timeout",
                        ..
                    }
                ),
                "{bad}: {e:?}"
            );
        }
    }
}
