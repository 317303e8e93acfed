//! Finished recordings to object storage: `bench serve --upload URL` and
//! `bench upload --to URL RECORDING…` copy each finished recording with its
//! companions (FRF CSV, plots, summary) and its catalogue row to an
//! S3-compatible store (`s3://bucket/prefix`) or a directory (`file:///…`,
//! a NAS), through the `object_store` crate.
//!
//! What holds:
//! - **Only finished files.** A recording is uploaded only when it is a
//!   finished MCAP recording of `bench` (its catalogue row can be read from
//!   it, [`crate::catalogue::row_of_recording`]); a `.part` never is. An
//!   object appears whole or not at all: a single PUT, or a multipart
//!   upload (files over [`MULTIPART_THRESHOLD_BYTES`], parts of
//!   [`PART_BYTES`]) that the store assembles when it completes.
//! - **Confirmed by checksum.** After the upload the object is read back
//!   from the store and its SHA-256 compared with the local file's; only
//!   then is the file *confirmed*. The local copy is never removed by
//!   `bench` (a lab prunes confirmed files with its own retention).
//! - **Nothing twice.** Before uploading, the store is asked for the
//!   object: one of the same size whose SHA-256 (read back) equals the
//!   local file's is confirmed without a second upload (a run killed after
//!   its upload but before its journal line). An object of the same name
//!   with other contents is never overwritten: the file is dropped from
//!   the queue with the reason, and kept locally.
//! - **Nothing lost.** The daemon journals every file it queues
//!   ([`journal`]) before it tries it, and retries with a backoff
//!   ([`worker`]) until the store confirms, across restarts.
//! - **Never on the loop's path.** Uploads run on their own thread
//!   (`bench-upload`, nice 10, off the loop's CPU) and a failed upload
//!   never fails a run.
//!
//! Layer rule: may use `catalogue`, `error`, `jobs`, `outputs`.

pub mod journal;
pub mod once;
pub mod store;
pub mod transfer;
pub mod worker;

pub use store::{ProbeError, Store, StoreUrl};
pub use transfer::{campaign_upload_set, upload_set, upload_set_of, Item, Source, Transferred};

/// Files larger than this go up as a multipart upload (5 MiB parts),
/// smaller ones in one PUT.
pub const MULTIPART_THRESHOLD_BYTES: u64 = 8 * 1024 * 1024;

/// The part size of a multipart upload: S3's smallest part, 5 MiB
/// (but for the last).
pub const PART_BYTES: usize = 5 * 1024 * 1024;
