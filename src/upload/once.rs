//! `bench upload --to URL RECORDING…`: finished recordings (and campaign
//! directories) to the store
//! now, from the command line, retried with the uploader's backoff for at
//! most `--retry-for` seconds. Without a journal: a second run over the
//! same recordings finds what the first confirmed in the store (same
//! SHA-256, read back) and uploads only the rest.

use super::store::{ProbeError, Store, StoreUrl};
use super::transfer::{transfer, upload_set_of, Item, TransferError, Transferred};
use super::worker::{FIRST_BACKOFF_S, MAX_BACKOFF_S};
use crate::jobs::request::UploadRequest;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The longest `--retry-for`, s (a day).
pub const MAX_RETRY_FOR_S: f64 = 86_400.0;

/// What `bench upload` does.
#[derive(Debug, Clone)]
pub struct UploadOptions {
    /// The store (`--to`).
    pub to: StoreUrl,
    /// The finished recordings, and campaign directories
    /// ([`super::campaign_upload_set`]).
    pub recordings: Vec<PathBuf>,
    /// How long a failing store is retried, s (`--retry-for`, 0 to
    /// [`MAX_RETRY_FOR_S`]).
    pub retry_for_s: f64,
    /// How long the store has to connect and to answer a request, s
    /// (`--store-timeout`, [`super::store::TIMEOUT_RANGE_S`]).
    pub timeout_s: f64,
    /// Set to stop (the daemon's `stop`): nothing more is tried, what was
    /// not confirmed is reported as failed, and the local files are kept.
    pub stop: Option<Arc<AtomicBool>>,
}

/// `--retry-for`'s default, s.
pub const DEFAULT_RETRY_FOR_S: f64 = 60.0;

impl UploadOptions {
    /// The upload a request asks for (its store URL parsed, the defaults
    /// filled in); the ranges are checked by [`upload_recordings`].
    ///
    /// # Errors
    /// [`UploadError::Url`] for a `to` that is no store URL.
    pub fn from_request(r: &UploadRequest) -> Result<Self, UploadError> {
        Ok(Self {
            to: StoreUrl::parse(&r.to).map_err(|reason| UploadError::Url {
                url: r.to.clone(),
                reason,
            })?,
            recordings: r.recordings.clone(),
            retry_for_s: r.retry_for_s.unwrap_or(DEFAULT_RETRY_FOR_S),
            timeout_s: r.store_timeout_s.unwrap_or(super::store::DEFAULT_TIMEOUT_S),
            stop: None,
        })
    }

    fn stopped(&self) -> bool {
        self.stop
            .as_ref()
            .is_some_and(|s| s.load(Ordering::Relaxed))
    }
}

/// An item that did not go up.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct NotUploaded {
    /// The object's key.
    pub key: String,
    /// The local file (or, for a catalogue row, its recording).
    pub local: PathBuf,
    /// Why.
    pub reason: String,
}

/// What `bench upload` did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct UploadSummary {
    /// The store.
    pub store: String,
    /// Each item confirmed by the store (uploaded now or found there).
    pub confirmed: Vec<Transferred>,
    /// Items the store could not take in `retry_for_s` (still local).
    pub failed: Vec<NotUploaded>,
    /// Items that cannot go up (another object of the name in the store;
    /// the local file is kept).
    pub dropped: Vec<NotUploaded>,
    /// Wall time, s.
    pub elapsed_s: f64,
}

impl UploadSummary {
    /// The summary's lines.
    pub fn lines(&self) -> Vec<String> {
        let mut out = Vec::new();
        for t in &self.confirmed {
            out.push(format!(
                "{}  {}  {} bytes  sha256 {}",
                if t.uploaded { "uploaded" } else { "in store" },
                t.url,
                t.size_bytes,
                t.sha256
            ));
        }
        for (what, list) in [("FAILED  ", &self.failed), ("DROPPED ", &self.dropped)] {
            for n in list {
                out.push(format!(
                    "{what}{} ({}): {}",
                    n.key,
                    n.local.display(),
                    n.reason
                ));
            }
        }
        let uploaded = self.confirmed.iter().filter(|t| t.uploaded).count();
        out.push(format!(
            "{} confirmed in {} ({} uploaded, {} already there), {} failed, {} dropped, {:.1} s; local copies kept",
            self.confirmed.len(),
            self.store,
            uploaded,
            self.confirmed.len() - uploaded,
            self.failed.len(),
            self.dropped.len(),
            self.elapsed_s
        ));
        out
    }

    /// Everything confirmed.
    pub fn complete(&self) -> bool {
        self.failed.is_empty() && self.dropped.is_empty()
    }
}

/// Why `bench upload` did not start.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UploadError {
    /// A recording that is not a finished recording (nothing uploaded).
    #[error("{path}: {reason}")]
    Recording {
        /// The argument.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// `--to`: not a store URL.
    #[error("{url:?}: {reason}")]
    Url {
        /// The URL as given.
        url: String,
        /// Why.
        reason: String,
    },
    /// `--to`: the store cannot be opened or refused (no bucket, wrong
    /// credentials).
    #[error("{0}")]
    Store(String),
    /// `--retry-for` out of range.
    #[error("{0}")]
    RetryFor(String),
    /// `--store-timeout` out of range.
    #[error("{0}")]
    Timeout(String),
}

fn local_of(item: &Item) -> PathBuf {
    match &item.source {
        super::Source::File(p) => p.clone(),
        super::Source::CatalogueRow { recording, .. } => recording.clone(),
    }
}

/// Uploads the recordings of `opts` with their companions and rows.
///
/// A store that does not answer costs at most `retry_for_s` plus one
/// timeout: the probe and every try are retried only while the next try
/// would start within `retry_for_s`, and no request waits longer than the
/// timeout for an answer ([`Store::open`]).
///
/// # Errors
/// [`UploadError`]: a recording is not finished, `--retry-for` or
/// `--store-timeout` is out of range, or the store cannot be opened or
/// refuses (before anything is uploaded).
pub fn upload_recordings(opts: &UploadOptions) -> Result<UploadSummary, UploadError> {
    let started = Instant::now();
    if !(0.0..=MAX_RETRY_FOR_S).contains(&opts.retry_for_s) {
        return Err(UploadError::RetryFor(format!(
            "{} s is out of range (0 to {MAX_RETRY_FOR_S} s)",
            opts.retry_for_s
        )));
    }
    let mut items = Vec::new();
    for r in &opts.recordings {
        let set = upload_set_of(&opts.to, r).map_err(|reason| UploadError::Recording {
            path: r.clone(),
            reason,
        })?;
        for i in set {
            if !items.iter().any(|j: &Item| j.key == i.key) {
                items.push(i);
            }
        }
    }
    let timeout = super::store::check_timeout_s(opts.timeout_s).map_err(UploadError::Timeout)?;
    let store = Store::open(opts.to.clone(), timeout).map_err(UploadError::Store)?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| UploadError::Store(format!("tokio: {e}")))?;
    let result = rt.block_on(async {
        let deadline = started + Duration::from_secs_f64(opts.retry_for_s);
        // The probe is the first try: a store that did not answer it is
        // tried again only if there is time for a second try.
        let unreachable = match store.probe().await {
            Ok(()) => None,
            Err(ProbeError::Refused(m)) => return Err(UploadError::Store(m)),
            Err(ProbeError::Unreachable(m)) => {
                let again = Instant::now() + Duration::from_secs_f64(FIRST_BACKOFF_S);
                (again > deadline).then_some(m)
            }
        };
        let mut summary = UploadSummary {
            store: opts.to.to_string(),
            confirmed: Vec::new(),
            failed: Vec::new(),
            dropped: Vec::new(),
            elapsed_s: 0.0,
        };
        let mut backoff_s = FIRST_BACKOFF_S;
        let mut given_up = false;
        for item in &items {
            if let Some(reason) = &unreachable {
                summary.failed.push(NotUploaded {
                    key: item.key.clone(),
                    local: local_of(item),
                    reason: reason.clone(),
                });
                continue;
            }
            loop {
                if opts.stopped() {
                    summary.failed.push(NotUploaded {
                        key: item.key.clone(),
                        local: local_of(item),
                        reason: "not tried: the upload was stopped".into(),
                    });
                    break;
                }
                if given_up {
                    summary.failed.push(NotUploaded {
                        key: item.key.clone(),
                        local: local_of(item),
                        reason: "not tried: the store failed before it".into(),
                    });
                    break;
                }
                match transfer(&store, item).await {
                    Ok(t) => {
                        backoff_s = FIRST_BACKOFF_S;
                        summary.confirmed.push(t);
                        break;
                    }
                    Err(TransferError::Drop(reason)) => {
                        summary.dropped.push(NotUploaded {
                            key: item.key.clone(),
                            local: local_of(item),
                            reason,
                        });
                        break;
                    }
                    Err(TransferError::Retry(reason)) => {
                        let now = Instant::now();
                        if now + Duration::from_secs_f64(backoff_s) > deadline {
                            given_up = true;
                            summary.failed.push(NotUploaded {
                                key: item.key.clone(),
                                local: local_of(item),
                                reason,
                            });
                            break;
                        }
                        tracing::warn!("{}: {reason}; again in {backoff_s} s", item.key);
                        // In slices, so that a stop ends the wait.
                        let again = Instant::now() + Duration::from_secs_f64(backoff_s);
                        while Instant::now() < again && !opts.stopped() {
                            let left = again.saturating_duration_since(Instant::now());
                            tokio::time::sleep(left.min(Duration::from_millis(100))).await;
                        }
                        backoff_s = (backoff_s * 2.0).min(MAX_BACKOFF_S);
                    }
                }
            }
        }
        summary.elapsed_s = started.elapsed().as_secs_f64();
        Ok(summary)
    });
    // A call on a directory store that hangs (a NAS) holds a blocking
    // thread: not waited for.
    rt.shutdown_timeout(Duration::from_millis(100));
    result
}
