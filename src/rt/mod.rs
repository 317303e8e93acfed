//! The real-time side: the loop ([`run`]) and what runs on its thread, the
//! safety supervisor, tick timing statistics, and the choice of HAL backend.
//!
//! May use `bench_hal` and [`crate::record::topics`] (the records the tick
//! emits). Nothing here allocates, locks, logs or blocks on the tick; the
//! `alloc` integration test proves it.

pub mod backend;
pub mod latency;
pub mod service;
pub mod supervisor;
mod tick;
pub mod timing;

pub use tick::{
    make_realtime, run, Emitter, HalFailure, HoldJob, Job, JobEnd, JobOutput, Loop, LoopOptions,
    LoopReport, Pacing, QueueRoom, RawStop, Read, RecordQueue, StopReason, TickResult,
};
