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
    /// Virtual time paced against the wall clock (simulator only): tick
    /// `k` of a job is released no earlier than `start + k·period/factor`
    /// on `CLOCK_MONOTONIC`, `start` being its first tick's release.
    /// `factor` 1 runs the simulated plant at real time, 0.1 ten times
    /// slower, 10 ten times faster. The loop sleeps once per batch of
    /// ticks (about [`PACE_BATCH_NS`] of wall time, see
    /// [`pace_batch_ticks`]), not on every tick, so a 10–20 kHz loop does
    /// not spend its time in `clock_nanosleep`; a tick runs at most one
    /// batch late. No SCHED_FIFO, no `mlockall`; the records wait for the
    /// writer as in [`Pacing::Virtual`]. A late release is caught up and
    /// is no fault: the simulated plant advances by the period whatever
    /// the wall clock did, and no rule of the supervisor reads the pacing
    /// (its deadline rules apply in [`Pacing::RealTime`] only).
    Paced {
        /// Loop time per wall time, > 0 (the CLI and the daemon accept
        /// 0.01 to 100, `jobs::request::Pace`).
        factor: f64,
    },
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

/// How long a paced loop runs between two sleeps, ns of wall time (1 ms):
/// the batch of [`Pacing::Paced`].
pub const PACE_BATCH_NS: f64 = 1e6;

/// Ticks a paced loop releases per sleep at `period_ns` and `factor`: as
/// many as fit in [`PACE_BATCH_NS`] of wall time, at least 1 (5 at 5 kHz
/// and factor 1, 20 at 20 kHz, 50 at 5 kHz and factor 10; 1 for a factor
/// of 0.2 or less at 5 kHz).
pub fn pace_batch_ticks(period_ns: u64, factor: f64) -> u64 {
    let tick_ns = period_ns as f64 / factor;
    if tick_ns.is_finite() && tick_ns > 0.0 {
        ((PACE_BATCH_NS / tick_ns).floor() as u64).max(1)
    } else {
        1
    }
}
