//! The loop's shared vocabulary: the supervisor's states, the kinds of
//! fault it latches and the kinds of event the loop reports. The
//! supervisor decides them, the recorder writes them (by their `as_str`
//! names), the daemon and the summaries report them; all three use these
//! types, and this module uses nothing of the crate (a leaf).
//!
//! Layer rule: may use nothing of the crate.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// Supervisor state (README, *Safety: limits and stalls*), recorded as
/// its `as_str` name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum SupervisorState {
    /// Amplifier disabled, 0 A.
    Disabled,
    /// Amplifier enabled, no job output applied yet.
    Enabled,
    /// A job drives the command.
    Running,
    /// A fault latched: 0 A, amplifier disabled until an explicit reset.
    Faulted,
}

impl SupervisorState {
    /// Every state.
    pub const ALL: [Self; 4] = [Self::Disabled, Self::Enabled, Self::Running, Self::Faulted];

    /// Lower-case name used in recordings and summaries.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Disabled => "disabled",
            Self::Enabled => "enabled",
            Self::Running => "running",
            Self::Faulted => "faulted",
        }
    }
}

/// What happened (`/bench/event`), recorded as its `as_str` name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum EventKind {
    /// The loop started (first tick).
    LoopStarted,
    /// Supervisor state changed; `state` in the record is the new state.
    StateChanged,
    /// The job started driving the command.
    JobStarted,
    /// The job finished normally.
    JobFinished,
    /// A fault latched; `fault` says which.
    Fault,
    /// Stopped by SIGINT/SIGTERM; the command went to 0 A.
    Interrupted,
    /// The loop stopped (last tick).
    LoopStopped,
    /// A tick without a usable sample (timeout or corrupt frames on a
    /// hardware link): the last reading and command were held; `value` is
    /// the count of consecutive bad samples.
    SampleMissing,
    /// The stage ran on a held command for longer than a period: the
    /// loop woke late and missed deadlines (host stall; real time only),
    /// or the device ran on late commands (a run of samples flagged
    /// `command_late`, reported when it ends). `value` is the stall, s
    /// (missed deadlines × period, or late samples × period). Open-loop
    /// identification leaves the span it distorted out of the FRF.
    Stall,
}

impl EventKind {
    /// Every kind.
    pub const ALL: [Self; 9] = [
        Self::LoopStarted,
        Self::StateChanged,
        Self::JobStarted,
        Self::JobFinished,
        Self::Fault,
        Self::Interrupted,
        Self::LoopStopped,
        Self::SampleMissing,
        Self::Stall,
    ];

    /// Snake-case name used in recordings.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::LoopStarted => "loop_started",
            Self::StateChanged => "state_changed",
            Self::JobStarted => "job_started",
            Self::JobFinished => "job_finished",
            Self::Fault => "fault",
            Self::Interrupted => "interrupted",
            Self::LoopStopped => "loop_stopped",
            Self::SampleMissing => "sample_missing",
            Self::Stall => "stall",
        }
    }
}

/// Why the supervisor faulted, recorded as its `as_str` name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    /// |position| beyond the software position limit.
    PositionLimit,
    /// Probe flagged out of range.
    ProbeOutOfRange,
    /// Probe reading not finite.
    ProbeNotFinite,
    /// The job's command was not finite.
    CommandNotFinite,
    /// The real-time loop ran behind its deadlines for longer than
    /// `safety.max_overrun_s` (value: how long, s).
    Overruns,
    /// The HAL returned an error on read or write.
    Hal,
    /// Too many consecutive stale samples (sequence not advancing: a frozen
    /// device).
    StaleSample,
    /// The probe reading jumped further in one tick than the stage can move.
    PositionJump,
    /// The I²t budget above the continuous current rating is spent.
    I2t,
    /// The link to the device failed: more than `max_missed_samples`
    /// consecutive samples missing (sequence gap, timeout) or corrupt, or
    /// the link is gone (disconnect, bus-off).
    Link,
    /// The device ran on commands that did not answer its previous sample
    /// (the link delivers them late) for longer than
    /// `safety.max_command_latency_s`.
    LinkLatency,
    /// The recording failed (a write error such as a full disk killed the
    /// writer): the run cannot keep its promise to record, so it stops.
    Recording,
    /// The probe's reading stayed bit-identical over more fresh samples
    /// than its noise makes plausible (value: how many).
    ProbeFrozen,
    /// The current moved the stage, by the plant's quasi-static
    /// compliance, and the probe did not see it (value: the predicted
    /// motion, m).
    ProbeImplausible,
}

impl FaultKind {
    /// Every fault.
    pub const ALL: [Self; 14] = [
        Self::PositionLimit,
        Self::ProbeOutOfRange,
        Self::ProbeNotFinite,
        Self::CommandNotFinite,
        Self::Overruns,
        Self::Hal,
        Self::StaleSample,
        Self::PositionJump,
        Self::I2t,
        Self::Link,
        Self::LinkLatency,
        Self::Recording,
        Self::ProbeFrozen,
        Self::ProbeImplausible,
    ];

    /// Snake-case name used in recordings and exit messages.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::PositionLimit => "position_limit",
            Self::ProbeOutOfRange => "probe_out_of_range",
            Self::ProbeNotFinite => "probe_not_finite",
            Self::CommandNotFinite => "command_not_finite",
            Self::Overruns => "overruns",
            Self::Hal => "hal",
            Self::StaleSample => "stale_sample",
            Self::PositionJump => "position_jump",
            Self::I2t => "i2t",
            Self::Link => "link",
            Self::LinkLatency => "link_latency",
            Self::Recording => "recording",
            Self::ProbeFrozen => "probe_frozen",
            Self::ProbeImplausible => "probe_implausible",
        }
    }
}
