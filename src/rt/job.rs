//! What the loop runs: a [`Job`] (one tick's output from one sample), the
//! hold job between jobs, and the loop's options (pacing, safety limits).

use crate::rt::supervisor::SupervisorConfig;
use bench_hal::Sample;

/// What a job produces each tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JobOutput {
    /// Current demand, A (before the supervisor's limits).
    pub command_a: f64,
    /// Excitation part of the demand, A (`NaN` if none).
    pub excitation_a: f64,
    /// Position setpoint, m (`NaN` in open loop).
    pub setpoint_m: f64,
    /// The job is complete after this tick.
    pub done: bool,
}

impl JobOutput {
    /// 0 A, no excitation, no setpoint, not done: what the hold job gives
    /// and what a job holds before its first sample.
    pub const ZERO: Self = Self {
        command_a: 0.0,
        excitation_a: f64::NAN,
        setpoint_m: f64::NAN,
        done: false,
    };
}

/// A job driven by the loop: excitation, controller, or the hold job.
pub trait Job {
    /// Computes this tick's output from the sample; `tick` counts from 0 at
    /// the job's first tick. Called on the real-time thread: must not
    /// allocate, lock, log or block.
    fn tick(&mut self, tick: u64, sample: &Sample) -> JobOutput;
}

impl<J: Job + ?Sized> Job for Box<J> {
    #[inline]
    fn tick(&mut self, tick: u64, sample: &Sample) -> JobOutput {
        (**self).tick(tick, sample)
    }
}

/// The hold job run between jobs: 0 A, never finishes. (The supervisor
/// gives 0 A anyway unless a job runs; holding a position would need a
/// controller and is not offered.)
#[derive(Debug, Clone, Copy, Default)]
pub struct HoldJob;

impl Job for HoldJob {
    #[inline]
    fn tick(&mut self, _tick: u64, _sample: &Sample) -> JobOutput {
        JobOutput::ZERO
    }
}

/// How the loop is paced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pacing {
    /// As fast as possible; loop time is `tick × period` (simulator only).
    Virtual,
    /// Absolute deadlines on `CLOCK_MONOTONIC`, with SCHED_FIFO at
    /// `priority`, `mlockall` and optional CPU pinning when permitted.
    RealTime {
        /// SCHED_FIFO priority, 1–99.
        priority: i32,
        /// CPU to pin to.
        cpu: Option<usize>,
    },
}

/// Loop parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopOptions {
    /// Tick period, ns.
    pub period_ns: u64,
    /// Pacing.
    pub pacing: Pacing,
    /// Ticks between `/bench/timing` records.
    pub timing_interval_ticks: u64,
    /// Supervisor limits.
    pub safety: SupervisorConfig,
    /// Hard cap on a job's ticks (the job normally ends first).
    pub max_ticks: u64,
}
