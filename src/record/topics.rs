//! Fixed-size records that leave the real-time tick through the wait-free
//! queue (`rtrb`) to the writer thread. Every type here is `Copy` and holds no
//! heap data, so pushing one never allocates.
//!
//! Each record is also its recorded message: the writer thread serialises it
//! with `serde_json` (a non-finite `f64` becomes `null`), the channel's JSON
//! Schema is generated from it ([`crate::record::schema_of`]; a field's doc
//! comment, with its unit, is its description) and the reader deserialises
//! the same type (`null` gives NaN, [`crate::record::nan_if_null`]).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::record::nan_if_null;
pub use crate::vocab::{EventKind, FaultKind, SupervisorState};

/// NaN: the value of a field a recording made before it existed lacks.
fn nan() -> f64 {
    f64::NAN
}

/// One loop tick as seen by the recorder (`/bench/sample`). Non-finite
/// numbers are written as null.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct SampleRecord {
    /// Tick index since the loop started, ticks (0-based).
    pub tick: u64,
    /// Loop time of the tick, s: `tick × period`, the tick's nominal sample
    /// instant, in virtual and real-time mode alike (device time for
    /// device-clocked backends).
    #[serde(deserialize_with = "nan_if_null")]
    pub t_s: f64,
    /// When the tick actually woke, s: `CLOCK_MONOTONIC` (the clock of the
    /// loop's deadlines) since the job's first deadline, so `wake_s − t_s`
    /// is the tick's wake-up latency plus the periods lost in stalls: a
    /// 50 ms stall shows as a 50 ms gap in `wake_s` while `t_s` goes on
    /// one period a tick. Device-clocked, since the job's first sample
    /// (whose `wake_s` is its `t_s`). Virtual time has no wall clock:
    /// `wake_s = t_s`. Recordings made before this field read it as `NaN`.
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub wake_s: f64,
    /// Current commanded to the amplifier at this tick, A (after limits).
    #[serde(deserialize_with = "nan_if_null")]
    pub current_command_a: f64,
    /// Probe reading at this tick, m (`NaN`, written as null, when the probe
    /// gave none).
    #[serde(deserialize_with = "nan_if_null")]
    pub position_m: f64,
    /// Excitation part of the command, A (`NaN`, written as null, when no
    /// excitation runs).
    #[serde(deserialize_with = "nan_if_null")]
    pub excitation_a: f64,
    /// Position setpoint, m (`NaN`, written as null, in open loop).
    #[serde(deserialize_with = "nan_if_null")]
    pub setpoint_m: f64,
    /// Supervisor state at the end of the tick (no unit).
    pub state: SupervisorState,
    /// Probe reported out of range at this tick (no unit).
    pub out_of_range: bool,
}

/// Loop timing statistics over a reporting window (`/bench/timing`).
/// Non-finite numbers are written as null.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct TimingRecord {
    /// Last tick covered by this window, ticks (0-based index).
    pub tick: u64,
    /// Loop time at the end of the window, s.
    #[serde(deserialize_with = "nan_if_null")]
    pub t_s: f64,
    /// Ticks in the window, count.
    pub ticks: u64,
    /// Mean wake-up latency (actual wake − deadline), ns (0 in virtual
    /// time).
    #[serde(deserialize_with = "nan_if_null")]
    pub wake_latency_mean_ns: f64,
    /// Median wake-up latency, ns (HDR histogram, ≤ 1 % above the true
    /// value; `NaN` in recordings made before this field).
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub wake_latency_p50_ns: f64,
    /// 99th percentile of wake-up latency, ns (HDR histogram, ≤ 1 % above
    /// the true value).
    #[serde(deserialize_with = "nan_if_null")]
    pub wake_latency_p99_ns: f64,
    /// 99.9th percentile of wake-up latency, ns (≤ 1 % above; `NaN` in
    /// recordings made before this field).
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub wake_latency_p999_ns: f64,
    /// Largest wake-up latency in the window, ns.
    #[serde(deserialize_with = "nan_if_null")]
    pub wake_latency_max_ns: f64,
    /// Mean compute time (wake timestamp → command written, less one clock
    /// read), ns.
    #[serde(deserialize_with = "nan_if_null")]
    pub compute_mean_ns: f64,
    /// Median compute time, ns (≤ 1 % above; `NaN` in recordings made
    /// before this field).
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub compute_p50_ns: f64,
    /// 99th percentile of compute time, ns (HDR histogram, ≤ 1 % above the
    /// true value).
    #[serde(deserialize_with = "nan_if_null")]
    pub compute_p99_ns: f64,
    /// 99.9th percentile of compute time, ns (≤ 1 % above; `NaN` in
    /// recordings made before this field).
    #[serde(default = "nan", deserialize_with = "nan_if_null")]
    pub compute_p999_ns: f64,
    /// Largest compute time in the window, ns.
    #[serde(deserialize_with = "nan_if_null")]
    pub compute_max_ns: f64,
    /// Ticks in the window that finished after the next deadline, count.
    pub overruns: u64,
    /// Records the queue could not take (writer too slow) since start,
    /// count.
    pub dropped_records: u64,
}

/// One event (`/bench/event`): something that happened in the loop (start,
/// state change, fault, …). Non-finite numbers are written as null.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct EventRecord {
    /// Tick at which it happened, ticks (0-based index).
    pub tick: u64,
    /// Loop time of the event, s.
    #[serde(deserialize_with = "nan_if_null")]
    pub t_s: f64,
    /// What happened (no unit).
    pub kind: EventKind,
    /// Supervisor state after the event (no unit).
    pub state: SupervisorState,
    /// The fault for kind `fault`, else null (no unit).
    pub fault: Option<FaultKind>,
    /// A number that qualifies the event, unit depending on the kind and
    /// fault (e.g. the offending position in m for `position_limit`); `NaN`,
    /// written as null, when none.
    #[serde(deserialize_with = "nan_if_null")]
    pub value: f64,
}

/// Seconds and nanoseconds since the Unix epoch (Foxglove's `time`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
pub struct FoxgloveTime {
    /// Whole seconds since 1970-01-01T00:00:00Z, s.
    pub sec: u32,
    /// Nanoseconds within the second, ns (0 … 999 999 999).
    pub nsec: u32,
}

impl FoxgloveTime {
    /// From nanoseconds since the Unix epoch.
    pub fn from_unix_ns(ns: u64) -> Self {
        Self {
            sec: u32::try_from(ns / 1_000_000_000).unwrap_or(u32::MAX),
            nsec: (ns % 1_000_000_000) as u32,
        }
    }
}

/// A log line in Foxglove's well-known `foxglove.Log` schema (JSON
/// encoding; <https://docs.foxglove.dev/docs/visualization/message-schemas/log>):
/// every `/bench/event` is also written as one on `/bench/log`, so that
/// Foxglove's and Lichtblick's Log panel lists the run's events.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct FoxgloveLog {
    /// When it happened, since the Unix epoch (the message's log time).
    pub timestamp: FoxgloveTime,
    /// Severity: 1 debug, 2 info, 3 warning, 4 error, 5 fatal (no unit).
    pub level: u8,
    /// What happened, in words (no unit).
    pub message: String,
    /// Source: `bench` (no unit).
    pub name: String,
    /// Source file: empty (no unit).
    pub file: String,
    /// Source line: 0 (no unit).
    pub line: u32,
}

impl FoxgloveLog {
    /// The log line of `e`, at `unix_ns` ns since the Unix epoch: level
    /// error for a fault, warning for an interruption, a missing sample or
    /// a stall, info otherwise.
    pub fn of_event(e: &EventRecord, unix_ns: u64) -> Self {
        let level = match e.kind {
            EventKind::Fault => 4,
            EventKind::Interrupted | EventKind::SampleMissing | EventKind::Stall => 3,
            _ => 2,
        };
        let mut message = e.kind.as_str().to_string();
        if let Some(f) = e.fault {
            message.push_str(": ");
            message.push_str(f.as_str());
        }
        if e.value.is_finite() {
            message.push_str(&format!(" (value {})", e.value));
        }
        message.push_str(&format!(
            "; state {}; tick {}, t = {:.6} s",
            e.state.as_str(),
            e.tick,
            e.t_s
        ));
        Self {
            timestamp: FoxgloveTime::from_unix_ns(unix_ns),
            level,
            message,
            name: "bench".into(),
            file: String::new(),
            line: 0,
        }
    }
}

/// Anything the tick sends to the writer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Record {
    /// `/bench/sample`
    Sample(SampleRecord),
    /// `/bench/timing`
    Timing(TimingRecord),
    /// `/bench/event`
    Event(EventRecord),
}

/// Keeps the `ALL` lists complete: a new variant stops this compiling until
/// it is added here, and the test below then checks it is in `ALL`.
#[allow(dead_code)]
fn variant_index(r: (SupervisorState, EventKind, FaultKind)) -> (usize, usize, usize) {
    use EventKind as E;
    use FaultKind as F;
    use SupervisorState as S;
    let s = match r.0 {
        S::Disabled => 0,
        S::Enabled => 1,
        S::Running => 2,
        S::Faulted => 3,
    };
    let e = match r.1 {
        E::LoopStarted => 0,
        E::StateChanged => 1,
        E::JobStarted => 2,
        E::JobFinished => 3,
        E::Fault => 4,
        E::Interrupted => 5,
        E::LoopStopped => 6,
        E::SampleMissing => 7,
        E::Stall => 8,
    };
    let f = match r.2 {
        F::PositionLimit => 0,
        F::ProbeOutOfRange => 1,
        F::ProbeNotFinite => 2,
        F::CommandNotFinite => 3,
        F::Overruns => 4,
        F::Hal => 5,
        F::StaleSample => 6,
        F::PositionJump => 7,
        F::I2t => 8,
        F::Link => 9,
        F::LinkLatency => 10,
        F::Recording => 11,
        F::ProbeFrozen => 12,
        F::ProbeImplausible => 13,
    };
    (s, e, f)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `ALL[i]` is the variant with index i, and names are distinct.
    #[test]
    fn all_lists_are_complete_and_names_distinct() {
        for (i, s) in SupervisorState::ALL.iter().enumerate() {
            assert_eq!(variant_index((*s, EventKind::Fault, FaultKind::Hal)).0, i);
        }
        for (i, e) in EventKind::ALL.iter().enumerate() {
            assert_eq!(
                variant_index((SupervisorState::Faulted, *e, FaultKind::Hal)).1,
                i
            );
        }
        for (i, f) in FaultKind::ALL.iter().enumerate() {
            assert_eq!(
                variant_index((SupervisorState::Faulted, EventKind::Fault, *f)).2,
                i
            );
        }
        let mut names: Vec<&str> = FaultKind::ALL.iter().map(|f| f.as_str()).collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), FaultKind::ALL.len());
    }

    /// The recorded (serde) name of every variant is its `as_str` name, and
    /// reads back.
    #[test]
    fn serde_names_are_as_str() {
        fn check<T>(all: &[T], name: fn(&T) -> &'static str)
        where
            T: Serialize + for<'de> Deserialize<'de> + PartialEq + std::fmt::Debug,
        {
            for v in all {
                let json = serde_json::to_value(v).unwrap();
                assert_eq!(json, serde_json::Value::from(name(v)), "{v:?}");
                assert_eq!(&serde_json::from_value::<T>(json).unwrap(), v);
            }
        }
        check(&SupervisorState::ALL, |s| s.as_str());
        check(&EventKind::ALL, |k| k.as_str());
        check(&FaultKind::ALL, |f| f.as_str());
    }
}
