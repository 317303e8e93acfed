//! The daemon's uploader: a thread of its own (`bench-upload`, nice 10,
//! off the loop's CPU) with a tokio runtime, which uploads what the
//! journal holds pending, then each recording the daemon queues
//! ([`Uploader::queue_recording`]), one item at a time, in order.
//!
//! A failed item is retried after a backoff that doubles from
//! [`FIRST_BACKOFF_S`] to [`MAX_BACKOFF_S`] (reset by a success) for as
//! long as the daemon runs, and after a restart from the journal; the
//! items behind it wait (the order of a recording's files is kept: its
//! catalogue row goes up last). An item that cannot go up (its file gone,
//! another object of its name in the store) is dropped with the reason.
//! Each outcome is reported through the `on_event` callback (the
//! daemon's event stream and log).

use super::journal::{now_utc, Journal, Line, Pending};
use super::transfer::{transfer, upload_set_of, Item, TransferError, Transferred};
use super::Store;
use std::collections::VecDeque;
use std::path::Path;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::mpsc;

/// The first wait after a failure, seconds.
pub const FIRST_BACKOFF_S: f64 = 1.0;
/// The longest wait between two tries, seconds.
pub const MAX_BACKOFF_S: f64 = 60.0;

/// What the uploader reports.
#[derive(Debug, Clone, PartialEq)]
pub enum UploadEvent {
    /// The store confirmed an item.
    Confirmed(Transferred),
    /// An item failed; tried again in `retry_in_s`.
    Failed {
        /// The object's key.
        key: String,
        /// Why.
        error: String,
        /// The wait before the next try, s.
        retry_in_s: f64,
    },
    /// An item dropped from the queue (its local file is kept).
    Dropped {
        /// The object's key.
        key: String,
        /// Why.
        reason: String,
    },
}

/// The callback that receives [`UploadEvent`]s (on the uploader's thread).
pub type OnEvent = Box<dyn Fn(UploadEvent) + Send>;

/// The uploader's counts since it started (the daemon's metrics:
/// `bench_uploads_total{outcome}`, `bench_upload_pending`).
#[derive(Debug, Default)]
pub struct UploadCounts {
    /// Items the store confirmed.
    pub confirmed: AtomicU64,
    /// Failed tries (each retried).
    pub failed: AtomicU64,
    /// Items dropped.
    pub dropped: AtomicU64,
    /// Items queued and not yet confirmed or dropped.
    pub pending: AtomicUsize,
}

/// The running uploader; dropping it stops it (an item in flight is
/// abandoned and stays pending in the journal).
pub struct Uploader {
    store: Store,
    journal: Arc<Mutex<Journal>>,
    tx: Option<mpsc::UnboundedSender<Vec<Item>>>,
    counts: Arc<UploadCounts>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Uploader {
    /// Opens the journal at `journal_path`, and starts the thread that
    /// uploads its pending items for this store, then what is queued.
    /// Pending items of another store stay in the journal (reported).
    ///
    /// # Errors
    /// The journal cannot be opened, or the thread cannot start.
    pub fn start(
        store: Store,
        journal_path: &Path,
        loop_cpu: Option<usize>,
        on_event: OnEvent,
    ) -> Result<Self, String> {
        let (journal, pending) = Journal::open(journal_path)?;
        let url = store.url.to_string();
        let (mine, others): (Vec<Pending>, Vec<Pending>) =
            pending.into_iter().partition(|p| p.store == url);
        if !others.is_empty() {
            tracing::warn!(
                "{} file(s) in {} are queued for another store ({}); they stay there until a daemon uploads to it",
                others.len(),
                journal_path.display(),
                others[0].store
            );
        }
        if !mine.is_empty() {
            tracing::info!(
                "{} file(s) pending in {}: uploading them first",
                mine.len(),
                journal_path.display()
            );
        }
        let journal = Arc::new(Mutex::new(journal));
        let count = Arc::new(UploadCounts {
            pending: AtomicUsize::new(mine.len()),
            ..UploadCounts::default()
        });
        let (tx, rx) = mpsc::unbounded_channel();
        let (stop, stopped) = tokio::sync::oneshot::channel();
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| format!("tokio: {e}"))?;
        let thread = {
            let (store, journal, count) = (store.clone(), Arc::clone(&journal), Arc::clone(&count));
            let queue: VecDeque<Item> = mine.into_iter().map(|p| p.item).collect();
            std::thread::Builder::new()
                .name("bench-upload".into())
                .spawn(move || {
                    bench_hal::os::keep_off_cpu(loop_cpu);
                    rt.block_on(async move {
                        tokio::select! {
                            () = run(&store, &journal, &count, queue, rx, &on_event) => {}
                            _ = stopped => {}
                        }
                    });
                })
                .map_err(|e| format!("cannot start the upload thread: {e}"))?
        };
        Ok(Self {
            store,
            journal,
            tx: Some(tx),
            counts: count,
            stop: Some(stop),
            thread: Some(thread),
        })
    }

    /// Queues the finished recording `recording` with its companions and
    /// catalogue row ([`super::upload_set`]), or a campaign directory's files
    /// ([`super::campaign_upload_set`]): journalled (synced) before this
    /// returns. Returns the number of items queued.
    ///
    /// # Errors
    /// `recording` is neither a finished recording nor a campaign
    /// directory, or the journal cannot be written (nothing queued then).
    pub fn queue_recording(&self, recording: &Path) -> Result<usize, String> {
        let items = upload_set_of(&self.store.url, recording)?;
        let store = self.store.url.to_string();
        {
            let mut j = lock(&self.journal);
            for item in &items {
                j.append(&Line::Queued {
                    store: store.clone(),
                    item: item.clone(),
                    time_utc: now_utc(),
                })?;
            }
        }
        let n = items.len();
        self.counts.pending.fetch_add(n, Ordering::Relaxed);
        if let Some(tx) = &self.tx {
            let _ = tx.send(items);
        }
        Ok(n)
    }

    /// Items not yet confirmed or dropped.
    pub fn pending(&self) -> usize {
        self.counts.pending.load(Ordering::Relaxed)
    }

    /// Its counts, shared.
    pub fn counts(&self) -> Arc<UploadCounts> {
        Arc::clone(&self.counts)
    }

    /// The store's URL.
    pub fn url(&self) -> String {
        self.store.url.to_string()
    }
}

impl Drop for Uploader {
    fn drop(&mut self) {
        self.tx.take();
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The uploader's loop: the queue's first item until it is confirmed or
/// dropped, waiting a backoff after each failure.
async fn run(
    store: &Store,
    journal: &Mutex<Journal>,
    count: &UploadCounts,
    mut queue: VecDeque<Item>,
    mut rx: mpsc::UnboundedReceiver<Vec<Item>>,
    on_event: &OnEvent,
) {
    let url = store.url.to_string();
    let mut backoff_s = FIRST_BACKOFF_S;
    loop {
        while let Ok(items) = rx.try_recv() {
            queue.extend(items);
        }
        let Some(item) = queue.front().cloned() else {
            match rx.recv().await {
                Some(items) => {
                    queue.extend(items);
                    continue;
                }
                None => return,
            }
        };
        let journal_line = match transfer(store, &item).await {
            Ok(t) => {
                backoff_s = FIRST_BACKOFF_S;
                count.confirmed.fetch_add(1, Ordering::Relaxed);
                let line = Line::Confirmed {
                    store: url.clone(),
                    key: t.key.clone(),
                    size_bytes: t.size_bytes,
                    sha256: t.sha256.clone(),
                    uploaded: t.uploaded,
                    time_utc: now_utc(),
                };
                on_event(UploadEvent::Confirmed(t));
                line
            }
            Err(TransferError::Drop(reason)) => {
                count.dropped.fetch_add(1, Ordering::Relaxed);
                on_event(UploadEvent::Dropped {
                    key: item.key.clone(),
                    reason: reason.clone(),
                });
                Line::Dropped {
                    store: url.clone(),
                    key: item.key.clone(),
                    reason,
                    time_utc: now_utc(),
                }
            }
            Err(TransferError::Retry(error)) => {
                count.failed.fetch_add(1, Ordering::Relaxed);
                on_event(UploadEvent::Failed {
                    key: item.key.clone(),
                    error,
                    retry_in_s: backoff_s,
                });
                tokio::time::sleep(Duration::from_secs_f64(backoff_s)).await;
                backoff_s = (backoff_s * 2.0).min(MAX_BACKOFF_S);
                continue;
            }
        };
        if let Err(e) = lock(journal).append(&journal_line) {
            // The item is done; only its line is missing: after a
            // restart it is found in the store and not uploaded again.
            tracing::error!("{e}");
        }
        queue.pop_front();
        count.pending.fetch_sub(1, Ordering::Relaxed);
    }
}
