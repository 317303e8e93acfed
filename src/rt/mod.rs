//! The real-time side: the loop ([`run`]) and what runs on its thread, the
//! safety supervisor, tick timing statistics, and the choice of HAL backend.
//!
//! Uses `bench_hal` (the stage, and its `os` module for clock and
//! scheduling), the records and queue of [`crate::record`], the shared
//! vocabulary of [`crate::vocab`] and the limits of [`crate::config`].
//! Nothing here allocates, locks, logs or blocks on the tick; the
//! `alloc` integration test proves it.
//!
//! Layer rule: may use `config`, `error`, `record`, `vocab`.

pub mod backend;
mod job;
mod report;
pub mod service;
pub mod supervisor;
pub mod tap;
mod tick;
pub mod timing;

pub use crate::record::queue::{Emitter, QueueRoom, RecordQueue};
pub use job::{pace_batch_ticks, HoldJob, Job, JobOutput, LoopOptions, Pacing, PACE_BATCH_NS};
pub use report::{JobEnd, LoopReport, RawStop, StopReason};
pub use tick::{run, HalFailure, Loop, Read, TickResult};
