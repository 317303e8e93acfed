//! How a job ended: the raw stop the loop hands back ([`JobEnd`],
//! [`RawStop`], unformatted, from the tick) and the report with its
//! messages formatted after the loop ([`LoopReport`], [`StopReason`]).

use crate::rt::supervisor::HalCall;
use crate::rt::timing::TimingStats;
use crate::vocab::{FaultKind, SupervisorState};
use bench_hal::os::DmaLatency;

/// Why the loop stopped.
#[derive(Debug, Clone, PartialEq)]
pub enum StopReason {
    /// The job finished.
    Finished,
    /// The supervisor latched a fault at `tick`; `value` caused it.
    Fault {
        /// Which fault.
        kind: FaultKind,
        /// The offending value (position in m, command in A, time behind
        /// schedule in s).
        value: f64,
        /// Tick of the fault.
        tick: u64,
        /// What the backend said, for link faults.
        detail: Option<String>,
        /// For a stall fault: the bound it broke, s, which rule, the
        /// command held, A.
        stall: Option<(f64, crate::rt::supervisor::StallRule, f64)>,
    },
    /// A HAL call failed (the supervisor faulted with [`FaultKind::Hal`]).
    Hal {
        /// The backend's message.
        message: String,
        /// Tick of the failure.
        tick: u64,
    },
    /// The stop flag was raised (SIGINT/SIGTERM).
    Interrupted {
        /// Tick at which the loop stopped.
        tick: u64,
    },
    /// `max_ticks` reached before the job finished.
    TickLimit,
}

/// How a job ended, as the tick saw it: HAL errors kept unformatted (a
/// message would allocate); [`JobEnd::into_report`] formats them.
#[derive(Debug)]
pub enum RawStop<E> {
    /// The job finished.
    Finished,
    /// The supervisor latched a fault.
    Fault {
        /// Which fault.
        kind: FaultKind,
        /// The offending value.
        value: f64,
        /// Tick of the fault (job ticks).
        tick: u64,
        /// The last bad-sample or lost-link error, for link faults.
        link_error: Option<E>,
        /// For a stall fault: the bound it broke, s, which rule, the
        /// command held, A ([`crate::rt::supervisor::Supervisor::stall_bound`]).
        stall: Option<(f64, crate::rt::supervisor::StallRule, f64)>,
    },
    /// A HAL call failed.
    Hal {
        /// The call.
        call: HalCall,
        /// The backend's error.
        error: E,
        /// Tick of the failure (job ticks).
        tick: u64,
    },
    /// The stop flag was raised.
    Interrupted {
        /// Tick at which the job stopped.
        tick: u64,
    },
    /// The tick budget ran out.
    TickLimit,
}

/// A job's end, straight from the loop.
#[derive(Debug)]
pub struct JobEnd<E> {
    /// Job ticks run.
    pub ticks: u64,
    /// Why it stopped.
    pub stop: RawStop<E>,
    /// Timing over the job.
    pub timing: TimingStats,
    /// Records dropped because the queue was full.
    pub dropped_records: u64,
    /// Supervisor state after the job.
    pub final_state: SupervisorState,
    /// Whether the loop held `/dev/cpu_dma_latency` at 0.
    pub cpu_dma_latency: DmaLatency,
}

impl<E: std::fmt::Display> JobEnd<E> {
    /// The report with messages formatted (allocates; not on the tick).
    pub fn into_report(self, warnings: Vec<String>) -> LoopReport {
        LoopReport {
            ticks: self.ticks,
            stop: self.stop.describe(),
            timing: self.timing,
            dropped_records: self.dropped_records,
            warnings,
            final_state: self.final_state,
            cpu_dma_latency: self.cpu_dma_latency,
        }
    }
}

impl<E: std::fmt::Display> RawStop<E> {
    /// The stop reason with the backend's messages formatted.
    pub fn describe(self) -> StopReason {
        match self {
            Self::Finished => StopReason::Finished,
            Self::TickLimit => StopReason::TickLimit,
            Self::Interrupted { tick } => StopReason::Interrupted { tick },
            Self::Hal { call, error, tick } => StopReason::Hal {
                message: format!("{}: {error}", call.as_str()),
                tick,
            },
            Self::Fault {
                kind,
                value,
                tick,
                link_error,
                stall,
            } => {
                let detail = match (kind, link_error) {
                    (FaultKind::Link, Some(e)) if value.is_nan() => Some(format!("link lost: {e}")),
                    (FaultKind::Link, Some(e)) if stall.is_some() => {
                        Some(format!("no sample for {:.1} ms (last: {e})", value * 1e3))
                    }
                    (FaultKind::Link, Some(e)) => Some(format!(
                        "{value} consecutive samples missing or corrupt (last: {e})"
                    )),
                    (FaultKind::Link, None) => Some(format!(
                        "{value} consecutive samples missing (sequence gap)"
                    )),
                    _ => None,
                };
                StopReason::Fault {
                    kind,
                    value,
                    tick,
                    detail,
                    stall,
                }
            }
        }
    }
}

/// What the loop reports when it ends.
#[derive(Debug, Clone)]
pub struct LoopReport {
    /// Ticks run.
    pub ticks: u64,
    /// Why it stopped.
    pub stop: StopReason,
    /// Timing over the whole run.
    pub timing: TimingStats,
    /// Records dropped because the queue was full.
    pub dropped_records: u64,
    /// Real-time setup problems (not permitted, etc.), one line each.
    pub warnings: Vec<String>,
    /// Final supervisor state.
    pub final_state: SupervisorState,
    /// Whether the loop held `/dev/cpu_dma_latency` at 0.
    pub cpu_dma_latency: DmaLatency,
}
