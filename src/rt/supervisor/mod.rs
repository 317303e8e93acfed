//! The safety supervisor that runs on every tick (README, *Safety: limits and stalls*).
//!
//! States: `disabled → enabled → running → faulted`. A fault latches: the
//! command is 0 A from the faulting tick on and the loop disables the
//! amplifier in the same tick; only [`Supervisor::reset`] leaves `faulted`.
//!
//! Link supervision: a tick without a usable sample (corrupt frames;
//! [`Supervisor::sample_missing`]) and a sequence gap both count missing
//! samples; more than `max_missed_samples` (K) in a row is the `link`
//! fault, as is a link that is gone ([`Supervisor::link_lost`]). A link
//! that is merely silent (reads time out, no frame at all: a USB hiccup, a
//! device that hangs) loses nothing yet; with the device's watchdog known
//! it is judged by how long it has been silent, against the watchdog, the
//! job's stall bound and the reach of the held command
//! ([`Supervisor::link_silent`]).
//! A tick without a sample and the gap it leaves in the sequence are the
//! same missing samples: the count is the larger of the two, never their
//! sum. So K corrupt frames (K bad reads, then a gap of K) and K dropped
//! ones (a gap of K) are both K missing samples, and neither trips; K + 1
//! of either does. (That a corrupt frame never costs its neighbour's
//! sample too is the backend's part: `bench_hal::serial`.)
//!
//! Checks, in order, on each sample: sequence advancing (at most K
//! consecutive samples missing, else `link`; at most K stale, else
//! `stale_sample`), commands arriving in time (the device flags each
//! sample whose period ran on a command that did not answer the previous
//! sample; more than `safety.max_command_latency_s` of those in a row is
//! `link_latency`: a uniformly late link is as unsafe as a lost one, since
//! the loop check assumed one period of delay), probe value
//! finite, probe in range, |position| within the software limit, change
//! since the last sample plausible (`max_position_step_m` per tick); on each
//! command: finite, I²t budget not spent; on each tick in real-time mode:
//! deadlines missed in a row for at most `safety.max_overrun_s` (counted in
//! whole periods, so a stall is judged by its length whatever the rate;
//! [`Supervisor::check_overrun`]); on each tick of a recorded job: the
//! recording still alive (`recording`, see [`Supervisor::recording_lost`]).
//! Commands are clipped to the amplifier's peak current.
//!
//! I²t (thermal protection of the coil): the accumulator integrates
//! `i² − I_cont²` over time, never going below zero, and faults when it
//! exceeds the budget `(I_peak² − I_cont²) · t_peak`: from cold, the peak
//! current may flow for `t_peak`, and any current at or below the continuous
//! rating may flow for ever.

use crate::vocab::{FaultKind, SupervisorState};

mod from_config;
mod limits;
mod message;
mod stall;

use bench_hal::{ErrorKind, Sample};
pub use limits::{check_announced, CurrentLimits, LimitSource, ANNOUNCED_CURRENT_MAX_A};
pub use message::fault_message;
pub use stall::{ReachEnvelope, StallBounds, StallRule, REACH_POINTS, REACH_SPAN_S};

/// The HAL call that failed (see [`Supervisor::hal_error`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HalCall {
    /// `Stage::enable`.
    Enable,
    /// `Stage::read_sample`.
    ReadSample,
    /// `Stage::write_command`.
    WriteCommand,
}

impl HalCall {
    /// The call's name, as messages show it.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Enable => "enable",
            Self::ReadSample => "read_sample",
            Self::WriteCommand => "write_command",
        }
    }
}

/// What a failed HAL call means for the loop ([`Supervisor::hal_error`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HalVerdict {
    /// A read brought no usable sample (timeout, corrupt frames): it counts
    /// towards the link fault; `tripped` when this one made it more than K
    /// in a row.
    SampleMissing {
        /// This call latched the link fault.
        tripped: bool,
    },
    /// The call is a fault of this kind at once: `link` for a read on a
    /// link that is gone, `hal` for anything else.
    Fault {
        /// The fault.
        kind: FaultKind,
        /// This call latched it (false when a fault was already latched).
        tripped: bool,
    },
}

/// The whole periods of `period_s` in a time bound `bound_s` (s), as the
/// supervisor counts its in-a-row rules in ticks: `⌊bound / period⌋`, with
/// a relative slack of 1e-9 so that 2 ms at 200 µs is 10 periods despite
/// rounding. A bound under one period tolerates none.
pub fn whole_periods(bound_s: f64, period_s: f64) -> u64 {
    (bound_s / period_s + 1e-9).floor() as u64
}

/// Supervisor limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SupervisorConfig {
    /// Software limit on |x1|, m.
    pub position_limit_m: f64,
    /// Amplifier peak current, A: commands are clipped to ±this.
    pub peak_current_a: f64,
    /// Deadlines that may be missed in a row (the whole periods in the
    /// job's stall bound, [`StallBounds`]); one more is the `overruns`
    /// fault. Checked in real-time (host-paced) mode, while a job or a
    /// hold controller drives the stage (`running`) only; `u64::MAX`:
    /// never (open-loop identification).
    pub max_missed_deadlines: u64,
    /// Consecutive missing (gap, timeout, corrupt) or stale samples
    /// tolerated (K).
    pub max_missed_samples: u32,
    /// Largest plausible change of the reading per tick, m.
    pub max_position_step_m: f64,
    /// Consecutive samples flagged `command_late` tolerated (the whole
    /// periods in the job's stall bound); one more is the `link_latency`
    /// fault. Checked while `running` only; `u64::MAX`: never.
    pub max_late_commands: u64,
    /// Continuous current rating, A.
    pub continuous_current_a: f64,
    /// How long the peak current may flow from cold, s.
    pub i2t_peak_duration_s: f64,
    /// Loop period, s (I²t integration step).
    pub period_s: f64,
    /// How far the held command can carry x1 in a stall (the model's).
    pub reach: ReachEnvelope,
    /// The device's watchdog time, s, when it announces one
    /// ([`bench_hal::DeviceInfo::watchdog_s`]). With it, a read that times
    /// out (no frame at all: the link is silent) is judged by how long the
    /// link has been silent ([`Supervisor::link_silent`]); without it, a
    /// timed-out read is a missing sample (K rule).
    pub watchdog_s: Option<f64>,
}

/// The supervisor. All methods are real-time safe.
#[derive(Debug, Clone)]
pub struct Supervisor {
    cfg: SupervisorConfig,
    state: SupervisorState,
    fault: Option<(FaultKind, f64)>,
    /// Deadlines missed in a row.
    missed_deadlines: u64,
    last_seq: Option<u64>,
    last_position_m: f64,
    /// Consecutive stale samples.
    stale: u64,
    /// Consecutive missing samples (ticks without one, or a gap).
    missing: u64,
    /// Consecutive reads that timed out on a silent link (judged by time
    /// when the device announced its watchdog).
    silent_reads: u64,
    /// Consecutive samples on which the device ran on a late command.
    late: u64,
    i2t_a2s: f64,
    i2t_budget_a2s: f64,
    /// The last command sent, A (what the device holds in a stall).
    last_command_a: f64,
    /// The bound the latched stall fault broke, s, which rule, and the
    /// command held, A.
    stall_bound: Option<(f64, StallRule, f64)>,
}

impl Supervisor {
    /// A supervisor in the `disabled` state.
    pub fn new(cfg: SupervisorConfig) -> Self {
        let ic2 = cfg.continuous_current_a * cfg.continuous_current_a;
        Self {
            cfg,
            state: SupervisorState::Disabled,
            fault: None,
            missed_deadlines: 0,
            last_seq: None,
            last_position_m: f64::NAN,
            stale: 0,
            missing: 0,
            silent_reads: 0,
            late: 0,
            i2t_a2s: 0.0,
            i2t_budget_a2s: (cfg.peak_current_a * cfg.peak_current_a - ic2).max(0.0)
                * cfg.i2t_peak_duration_s,
            last_command_a: 0.0,
            stall_bound: None,
        }
    }

    /// The I²t accumulator, A²·s (0 when cold).
    pub fn i2t_a2s(&self) -> f64 {
        self.i2t_a2s
    }

    /// The I²t budget the accumulator is held to, A²·s:
    /// `(I_peak² − I_cont²) · t_peak`.
    pub fn i2t_budget_a2s(&self) -> f64 {
        self.i2t_budget_a2s
    }

    /// Current state.
    pub fn state(&self) -> SupervisorState {
        self.state
    }

    /// The latched fault and the value that caused it.
    pub fn fault(&self) -> Option<(FaultKind, f64)> {
        self.fault
    }

    /// The amplifier was enabled. Ignored while faulted.
    pub fn enabled(&mut self) {
        if self.state == SupervisorState::Disabled {
            self.state = SupervisorState::Enabled;
        }
    }

    /// A job took over the command. Ignored unless enabled.
    pub fn running(&mut self) {
        if self.state == SupervisorState::Enabled {
            self.state = SupervisorState::Running;
        }
    }

    /// The amplifier was disabled normally. Ignored while faulted.
    pub fn disabled(&mut self) {
        if self.state != SupervisorState::Faulted {
            self.state = SupervisorState::Disabled;
        }
    }

    /// Latches a fault (the first one wins). Returns `true` if this call
    /// faulted the supervisor.
    pub fn trip(&mut self, kind: FaultKind, value: f64) -> bool {
        if self.state == SupervisorState::Faulted {
            return false;
        }
        self.state = SupervisorState::Faulted;
        self.fault = Some((kind, value));
        true
    }

    /// The stall bounds of the job that starts (and of the hold job after
    /// it): see [`StallBounds`]. Real-time safe.
    pub fn set_stall_bounds(&mut self, b: StallBounds) {
        self.cfg.max_missed_deadlines = b.max_missed_deadlines;
        self.cfg.max_late_commands = b.max_late_commands;
        self.missed_deadlines = 0;
        self.late = 0;
    }

    /// The stall bounds in force.
    pub fn stall_bounds(&self) -> StallBounds {
        StallBounds {
            max_missed_deadlines: self.cfg.max_missed_deadlines,
            max_late_commands: self.cfg.max_late_commands,
        }
    }

    /// Consecutive samples so far on which the device ran on a late
    /// command.
    pub fn late_commands(&self) -> u64 {
        self.late
    }

    /// Clears a latched fault: back to `disabled`.
    pub fn reset(&mut self) {
        self.state = SupervisorState::Disabled;
        self.fault = None;
        self.missed_deadlines = 0;
        self.last_seq = None;
        self.last_position_m = f64::NAN;
        self.stale = 0;
        self.missing = 0;
        self.silent_reads = 0;
        self.late = 0;
        self.stall_bound = None;
    }

    /// The bound the latched `overruns` or `link_latency` fault broke: the
    /// bound, s, which rule set it, and the command held, A.
    pub fn stall_bound(&self) -> Option<(f64, StallRule, f64)> {
        self.stall_bound
    }

    /// How long the stage may run on the command now held before it could
    /// reach the position limit from the last reading, s (infinite: not
    /// within a second). Real-time safe.
    pub fn reach_time_s(&self) -> f64 {
        let x = if self.last_position_m.is_finite() {
            self.last_position_m.abs()
        } else {
            0.0
        };
        self.cfg
            .reach
            .time_to_reach_s(self.last_command_a, self.cfg.position_limit_m - x)
    }

    /// A stall of `stalled` periods (deadlines missed, or late commands,
    /// in a row) against its two rules: the job's bound in periods
    /// (`bound`), and the reach of the held command. Returns the rule that
    /// broke, and records its bound.
    fn stall_broken(&mut self, stalled: u64, bound: u64) -> Option<StallRule> {
        let stalled_s = stalled as f64 * self.cfg.period_s;
        let reach = self.reach_time_s();
        let (rule, bound_s) = if stalled_s > reach {
            (StallRule::Reach, reach)
        } else if stalled > bound {
            (StallRule::Bound, bound as f64 * self.cfg.period_s)
        } else {
            return None;
        };
        if self.state != SupervisorState::Faulted {
            self.stall_bound = Some((bound_s, rule, self.last_command_a));
        }
        Some(rule)
    }

    /// A tick had no usable sample (timeout, corrupt frames). Trips
    /// [`FaultKind::Link`] when more than K in a row are missing; returns
    /// the fault if this call tripped it.
    pub fn sample_missing(&mut self) -> Option<FaultKind> {
        self.missing += 1;
        let n = self.missing;
        (n > u64::from(self.cfg.max_missed_samples) && self.trip(FaultKind::Link, n as f64))
            .then_some(FaultKind::Link)
    }

    /// Consecutive missing samples (and reads that timed out on a silent
    /// link) so far.
    pub fn missing_samples(&self) -> u64 {
        self.missing + self.silent_reads
    }

    /// A read timed out with no frame at all: the link has been silent for
    /// `silent_s` since the last sample (or since the job started). With a
    /// device watchdog announced ([`SupervisorConfig::watchdog_s`]) the
    /// silence is judged by its length, as a stall, never by a count of
    /// timeouts: the `link` fault trips when it exceeds the smallest of
    /// the device's watchdog (a device silent for longer is dead, or has
    /// stopped the current itself), the job's stall bound while it drives
    /// the stage (`running`: the device holds the last command, as in any
    /// stall; [`StallBounds`]) and the reach of the held command. So an
    /// open-loop chirp rides out a USB hiccup shorter than the watchdog,
    /// and a closed loop stops exactly when the silence exceeds its delay
    /// bound. Without a watchdog, the read counts as a missing sample
    /// ([`Supervisor::sample_missing`]). Returns the fault if this call
    /// tripped it; the fault's value is `silent_s`.
    pub fn link_silent(&mut self, silent_s: f64) -> Option<FaultKind> {
        let Some(watchdog_s) = self.cfg.watchdog_s else {
            return self.sample_missing();
        };
        self.silent_reads += 1;
        let mut bound = (watchdog_s, StallRule::Watchdog);
        if self.state == SupervisorState::Running && self.cfg.max_late_commands != u64::MAX {
            let b = self.cfg.max_late_commands as f64 * self.cfg.period_s;
            if b < bound.0 {
                bound = (b, StallRule::Bound);
            }
        }
        let reach = self.reach_time_s();
        if reach < bound.0 {
            bound = (reach, StallRule::Reach);
        }
        if silent_s.is_nan() || silent_s <= bound.0 {
            return None;
        }
        if self.state != SupervisorState::Faulted {
            self.stall_bound = Some((bound.0, bound.1, self.last_command_a));
        }
        self.trip(FaultKind::Link, silent_s)
            .then_some(FaultKind::Link)
    }

    /// The link is gone (disconnect, bus-off): [`FaultKind::Link`] at once.
    /// Returns `true` if this call tripped it.
    pub fn link_lost(&mut self) -> bool {
        self.trip(FaultKind::Link, f64::NAN)
    }

    /// The one mapping from a HAL error to the supervisor's rules. A read
    /// that times out is a silent link ([`Supervisor::link_silent`], with
    /// `value` the time since the last sample, s); a read that brings only
    /// corrupt frames is a missing sample (K in a row are tolerated); a
    /// read on a lost link (disconnect, bus-off) is the link fault at once;
    /// any other failure of any call is the `hal` fault, with `value` (the
    /// command in A for a write, else NaN).
    pub fn hal_error(&mut self, call: HalCall, kind: ErrorKind, value: f64) -> HalVerdict {
        match (call, kind) {
            (HalCall::ReadSample, ErrorKind::Timeout) => HalVerdict::SampleMissing {
                tripped: self.link_silent(value).is_some(),
            },
            (HalCall::ReadSample, ErrorKind::Crc) => HalVerdict::SampleMissing {
                tripped: self.sample_missing().is_some(),
            },
            (HalCall::ReadSample, ErrorKind::Link) => HalVerdict::Fault {
                kind: FaultKind::Link,
                tripped: self.link_lost(),
            },
            _ => HalVerdict::Fault {
                kind: FaultKind::Hal,
                tripped: self.trip(FaultKind::Hal, value),
            },
        }
    }

    /// Checks a sample; trips and returns the fault if it is bad.
    pub fn check_sample(&mut self, s: &Sample) -> Option<FaultKind> {
        let x = s.position_m;
        // Sequence: a gap counts the samples missing (together with the
        // ticks that had none), a repeat counts stale.
        let mut ticks_since = 1u64;
        let mut gap = 0u64;
        let stale = match self.last_seq {
            None => false,
            Some(last) if s.seq > last => {
                gap = s.seq - last - 1;
                ticks_since = s.seq - last;
                false
            }
            Some(_) => true,
        };
        let missing = self.missing.max(gap);
        if stale {
            self.stale += 1;
        } else {
            self.stale = 0;
            self.missing = 0;
            self.silent_reads = 0;
            self.last_seq = Some(s.seq);
        }
        let jump = (x - self.last_position_m).abs();
        let k = u64::from(self.cfg.max_missed_samples);
        // Late commands: counted on fresh samples, in ticks since the last
        // one (a gap of late samples is as late).
        if !stale {
            self.late = if s.flags.command_late {
                self.late + ticks_since
            } else {
                0
            };
        }
        let fault = if missing > k {
            Some(FaultKind::Link)
        } else if self.state == SupervisorState::Running
            && self.late > 0
            && self
                .stall_broken(self.late, self.cfg.max_late_commands)
                .is_some()
        {
            Some(FaultKind::LinkLatency)
        } else if self.stale > k {
            Some(FaultKind::StaleSample)
        } else if !x.is_finite() {
            Some(FaultKind::ProbeNotFinite)
        } else if s.flags.out_of_range {
            Some(FaultKind::ProbeOutOfRange)
        } else if x.abs() > self.cfg.position_limit_m {
            Some(FaultKind::PositionLimit)
        } else if jump > self.cfg.max_position_step_m * ticks_since as f64 {
            Some(FaultKind::PositionJump)
        } else {
            None
        };
        if !stale && x.is_finite() {
            self.last_position_m = x;
        }
        let value = match fault {
            Some(FaultKind::Link) => missing as f64,
            Some(FaultKind::StaleSample) => self.stale as f64,
            // How long the device has run on late commands, s.
            Some(FaultKind::LinkLatency) => self.late as f64 * self.cfg.period_s,
            // How far the reading moved per tick, m.
            Some(FaultKind::PositionJump) => jump / ticks_since as f64,
            _ => x,
        };
        fault.filter(|k| self.trip(*k, value))
    }

    /// The job's recording is lost (its writer died on a write error, e.g.
    /// a full disk): trips [`FaultKind::Recording`] at once, whatever the
    /// state, so the tick that sees it commands 0 A and disables. `value`
    /// is the number of records the tick could not hand over so far.
    /// Returns the fault if this call tripped it.
    pub fn recording_lost(&mut self, dropped_records: u64) -> Option<FaultKind> {
        self.trip(FaultKind::Recording, dropped_records as f64)
            .then_some(FaultKind::Recording)
    }

    /// Records how many deadlines this tick made the loop miss (0: it ended
    /// before the next deadline, which ends the streak). Deadlines missed
    /// in a row add up; more than `max_missed_deadlines` of them (the whole
    /// periods in `safety.max_overrun_s`) trip [`FaultKind::Overruns`],
    /// with the time the loop has been behind as its value, s. So one
    /// stall of a given length trips or not whatever the loop rate, and so
    /// does a loop that keeps ending a little late. Returns the fault if
    /// this call tripped it.
    ///
    /// Only while `running` (a job or a hold controller drives the stage):
    /// disabled, or enabled at 0 A between jobs, a late loop holds 0 A and
    /// endangers nothing, so the stall is reported (events, timing) and
    /// never latched.
    pub fn check_overrun(&mut self, missed: u64) -> Option<FaultKind> {
        if missed == 0 || self.state != SupervisorState::Running {
            self.missed_deadlines = 0;
            return None;
        }
        self.missed_deadlines = self.missed_deadlines.saturating_add(missed);
        let behind_s = self.missed_deadlines as f64 * self.cfg.period_s;
        (self
            .stall_broken(self.missed_deadlines, self.cfg.max_missed_deadlines)
            .is_some()
            && self.trip(FaultKind::Overruns, behind_s))
        .then_some(FaultKind::Overruns)
    }

    /// Deadlines missed in a row so far.
    pub fn missed_deadlines(&self) -> u64 {
        self.missed_deadlines
    }

    /// The command to send for a job's demand `current_a`: 0 A unless
    /// running, clipped to the peak current; a non-finite demand trips.
    pub fn command(&mut self, current_a: f64) -> (f64, Option<FaultKind>) {
        if !current_a.is_finite() {
            let tripped = self.trip(FaultKind::CommandNotFinite, current_a);
            return (0.0, tripped.then_some(FaultKind::CommandNotFinite));
        }
        if self.state != SupervisorState::Running {
            self.last_command_a = 0.0;
            return (0.0, None);
        }
        let p = self.cfg.peak_current_a;
        let i = current_a.clamp(-p, p);
        self.last_command_a = i;
        let ic = self.cfg.continuous_current_a;
        self.i2t_a2s = (self.i2t_a2s + (i * i - ic * ic) * self.cfg.period_s).max(0.0);
        if self.i2t_a2s > self.i2t_budget_a2s && self.trip(FaultKind::I2t, self.i2t_a2s) {
            return (0.0, Some(FaultKind::I2t));
        }
        (i, None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bench_hal::SampleFlags;

    fn config() -> SupervisorConfig {
        SupervisorConfig {
            position_limit_m: 0.8e-3,
            peak_current_a: 9.98,
            max_missed_deadlines: 3,
            max_missed_samples: 3,
            max_position_step_m: 50e-6,
            max_late_commands: 10,
            continuous_current_a: 2.34,
            i2t_peak_duration_s: 1.0,
            period_s: 2e-4,
            reach: crate::rt::supervisor::ReachEnvelope::NONE,
            watchdog_s: None,
        }
    }

    fn sup() -> Supervisor {
        let mut s = Supervisor::new(config());
        s.enabled();
        s.running();
        s
    }

    fn sample(x: f64, oor: bool) -> Sample {
        seq_sample(0, x, oor)
    }

    /// A silent link (reads that time out) is judged by time when the
    /// device announced its watchdog: the watchdog between jobs and in open
    /// loop, the job's stall bound while running in closed loop (here 10
    /// periods, 2 ms), never by the count of timeouts; without a watchdog,
    /// each timeout is a missing sample (K = 3).
    #[test]
    fn a_silent_link_is_judged_by_how_long_it_was_silent() {
        let timeout = |s: &mut Supervisor, silent_s: f64| {
            s.hal_error(HalCall::ReadSample, ErrorKind::Timeout, silent_s)
        };
        let watchdog = SupervisorConfig {
            watchdog_s: Some(50e-3),
            ..config()
        };
        // Idle (disabled): only the watchdog; many timeouts below it are fine.
        let mut s = Supervisor::new(watchdog);
        for i in 1..=9 {
            assert_eq!(
                timeout(&mut s, f64::from(i) * 5e-3),
                HalVerdict::SampleMissing { tripped: false }
            );
        }
        assert_eq!(
            timeout(&mut s, 50.1e-3),
            HalVerdict::SampleMissing { tripped: true }
        );
        assert_eq!(s.fault(), Some((FaultKind::Link, 50.1e-3)));
        assert_eq!(s.stall_bound().map(|b| b.1), Some(StallRule::Watchdog));
        // A sample ends the silence: the count starts again.
        let mut s = Supervisor::new(watchdog);
        timeout(&mut s, 40e-3);
        assert_eq!(s.check_sample(&seq_sample(1, 0.0, false)), None);
        assert_eq!(
            timeout(&mut s, 40e-3),
            HalVerdict::SampleMissing { tripped: false }
        );
        // Running under a closed loop's bound of 10 periods (2 ms).
        let mut s = Supervisor::new(watchdog);
        s.enabled();
        s.running();
        assert_eq!(
            timeout(&mut s, 2e-3),
            HalVerdict::SampleMissing { tripped: false }
        );
        assert_eq!(
            timeout(&mut s, 2.1e-3),
            HalVerdict::SampleMissing { tripped: true }
        );
        assert_eq!(
            s.stall_bound().map(|b| (b.0, b.1)),
            Some((2e-3, StallRule::Bound))
        );
        // Open loop (no bound): the watchdog.
        let mut s = Supervisor::new(SupervisorConfig {
            max_late_commands: u64::MAX,
            ..watchdog
        });
        s.enabled();
        s.running();
        assert_eq!(
            timeout(&mut s, 45e-3),
            HalVerdict::SampleMissing { tripped: false }
        );
        // No watchdog: the fourth timeout in a row is K + 1 missing samples.
        let mut s = sup();
        for _ in 0..3 {
            assert_eq!(
                timeout(&mut s, 1e-3),
                HalVerdict::SampleMissing { tripped: false }
            );
        }
        assert_eq!(
            timeout(&mut s, 1e-3),
            HalVerdict::SampleMissing { tripped: true }
        );
        assert_eq!(s.fault(), Some((FaultKind::Link, 4.0)));
    }

    fn seq_sample(seq: u64, x: f64, oor: bool) -> Sample {
        Sample {
            seq,
            device_time_ns: 0,
            position_m: x,
            measured_current_a: f64::NAN,
            flags: SampleFlags {
                out_of_range: oor,
                ..Default::default()
            },
        }
    }

    fn late_sample(seq: u64, late: bool) -> Sample {
        let mut s = seq_sample(seq, 0.0, false);
        s.flags.command_late = late;
        s
    }

    /// N late commands in a row (N = the periods in
    /// `max_command_latency_s`, 10 here) pass, N + 1 trip `link_latency`
    /// with the time run on late commands; one on-time command resets the
    /// count, and a gap of late samples counts its missing ticks.
    #[test]
    fn more_than_the_bound_of_late_commands_in_a_row_is_the_latency_fault() {
        let mut sv = sup();
        let mut seq = 0;
        for _ in 0..10 {
            assert_eq!(sv.check_sample(&late_sample(seq, true)), None);
            seq += 1;
        }
        // One in time: the count starts again.
        assert_eq!(sv.check_sample(&late_sample(seq, false)), None);
        seq += 1;
        for _ in 0..10 {
            assert_eq!(sv.check_sample(&late_sample(seq, true)), None);
            seq += 1;
        }
        assert_eq!(
            sv.check_sample(&late_sample(seq, true)),
            Some(FaultKind::LinkLatency)
        );
        let (kind, value) = sv.fault().unwrap();
        assert_eq!(kind, FaultKind::LinkLatency);
        assert!((value - 11.0 * 2e-4).abs() < 1e-12, "{value}");
        assert_eq!(sv.command(1.0), (0.0, None));
        // A gap of 2 between late samples counts 3 ticks late.
        let mut sv = sup();
        for seq in [0, 3, 6, 9] {
            assert_eq!(sv.check_sample(&late_sample(seq, true)), None);
        }
        assert_eq!(
            sv.check_sample(&late_sample(12, true)),
            Some(FaultKind::LinkLatency)
        );
    }

    #[test]
    fn faults_latch_and_zero_the_command() {
        for (x, oor, kind) in [
            (f64::NAN, false, FaultKind::ProbeNotFinite),
            (f64::INFINITY, false, FaultKind::ProbeNotFinite),
            (1e-3, true, FaultKind::ProbeOutOfRange),
            (-0.81e-3, false, FaultKind::PositionLimit),
        ] {
            let mut s = sup();
            assert_eq!(s.command(1.0).0, 1.0);
            assert_eq!(s.check_sample(&sample(x, oor)), Some(kind));
            assert_eq!(s.state(), SupervisorState::Faulted);
            assert_eq!(s.command(1.0).0, 0.0);
            // Good samples do not clear it.
            assert_eq!(s.check_sample(&sample(0.0, false)), None);
            s.enabled();
            s.running();
            assert_eq!(s.state(), SupervisorState::Faulted);
            assert_eq!(s.command(1.0).0, 0.0);
            s.reset();
            assert_eq!(s.state(), SupervisorState::Disabled);
        }
    }

    #[test]
    fn command_clipped_and_non_finite_trips() {
        let mut s = sup();
        assert_eq!(s.command(50.0).0, 9.98);
        assert_eq!(s.command(-50.0).0, -9.98);
        assert_eq!(
            s.command(f64::NAN),
            (0.0, Some(FaultKind::CommandNotFinite))
        );
        assert_eq!(s.state(), SupervisorState::Faulted);
    }

    #[test]
    fn missing_and_stale_samples() {
        let mut s = sup();
        for k in 0..10 {
            assert_eq!(s.check_sample(&seq_sample(k, 0.0, false)), None);
        }
        // A gap of 3 is tolerated (max 3), then recovery resets the count.
        assert_eq!(s.check_sample(&seq_sample(13, 0.0, false)), None);
        assert_eq!(s.check_sample(&seq_sample(14, 0.0, false)), None);
        // The same sequence number four times: stale.
        for _ in 0..3 {
            assert_eq!(s.check_sample(&seq_sample(14, 0.0, false)), None);
        }
        assert_eq!(
            s.check_sample(&seq_sample(14, 0.0, false)),
            Some(FaultKind::StaleSample)
        );
        // A gap of 4 at once is the link fault.
        let mut s = sup();
        s.check_sample(&seq_sample(0, 0.0, false));
        assert_eq!(
            s.check_sample(&seq_sample(5, 0.0, false)),
            Some(FaultKind::Link)
        );
        assert_eq!(s.fault(), Some((FaultKind::Link, 4.0)));
    }

    #[test]
    fn ticks_without_a_sample_and_the_gap_they_leave_count_once() {
        // Two timeouts, then the next sample shows the gap of the two it
        // missed: 2 missing, not 4, so K = 3 holds.
        let mut s = sup();
        s.check_sample(&seq_sample(0, 0.0, false));
        assert_eq!(s.sample_missing(), None);
        assert_eq!(s.sample_missing(), None);
        assert_eq!(s.check_sample(&seq_sample(3, 0.0, false)), None);
        assert_eq!(s.missing_samples(), 0);
        // Four in a row trip on the fourth.
        for _ in 0..3 {
            assert_eq!(s.sample_missing(), None);
        }
        assert_eq!(s.sample_missing(), Some(FaultKind::Link));
        assert_eq!(s.command(1.0), (0.0, None));
        // A disconnect trips at once (but a latched fault is not replaced).
        let mut s = sup();
        assert!(s.link_lost());
        assert_eq!(s.fault().map(|f| f.0), Some(FaultKind::Link));
    }

    /// "More than K" means the same for corrupt and dropped frames: K of
    /// either are tolerated, K + 1 trip, at any K; a bad read and the gap
    /// it leaves count once.
    #[test]
    fn k_corrupt_frames_count_as_k_dropped_ones() {
        use bench_hal::ErrorKind as E;
        for k in [0u32, 1, 2, 3, 7, 50] {
            let sup_k = || {
                let mut s = Supervisor::new(SupervisorConfig {
                    max_missed_samples: k,
                    ..config()
                });
                s.enabled();
                s.running();
                assert_eq!(s.check_sample(&seq_sample(0, 0.0, false)), None);
                s
            };
            let n = u64::from(k);
            // Dropped: a gap of K is tolerated, K + 1 trips (value K + 1).
            let mut s = sup_k();
            assert_eq!(
                s.check_sample(&seq_sample(n + 1, 0.0, false)),
                None,
                "k={k}"
            );
            assert_eq!(s.state(), SupervisorState::Running);
            let mut s = sup_k();
            assert_eq!(
                s.check_sample(&seq_sample(n + 2, 0.0, false)),
                Some(FaultKind::Link),
                "k={k}"
            );
            assert_eq!(s.fault(), Some((FaultKind::Link, (n + 1) as f64)));
            // Corrupt (or timed out), each read a tick without a sample,
            // then the gap they leave: K and the gap of K are K, not 2K.
            for kind in [E::Crc, E::Timeout] {
                for bad_reads in 0..=n {
                    let mut s = sup_k();
                    for _ in 0..bad_reads {
                        assert_eq!(
                            s.hal_error(HalCall::ReadSample, kind, f64::NAN),
                            HalVerdict::SampleMissing { tripped: false },
                            "k={k}"
                        );
                    }
                    assert_eq!(
                        s.check_sample(&seq_sample(n + 1, 0.0, false)),
                        None,
                        "k={k}, {bad_reads} bad reads then a gap of {k}"
                    );
                    assert_eq!(s.missing_samples(), 0);
                    // The count starts again: K more are tolerated.
                    for _ in 0..n {
                        s.hal_error(HalCall::ReadSample, kind, f64::NAN);
                    }
                    assert_eq!(s.check_sample(&seq_sample(2 * n + 2, 0.0, false)), None);
                    assert_eq!(s.state(), SupervisorState::Running, "k={k}");
                }
                // K + 1 bad reads trip on the last one.
                let mut s = sup_k();
                for i in 0..=n {
                    assert_eq!(
                        s.hal_error(HalCall::ReadSample, kind, f64::NAN),
                        HalVerdict::SampleMissing { tripped: i == n },
                        "k={k}, read {i}"
                    );
                }
                assert_eq!(s.fault(), Some((FaultKind::Link, (n + 1) as f64)));
                // K bad reads, then a gap of K + 1: the sample that shows
                // the (K + 1)th missing one trips.
                let mut s = sup_k();
                for _ in 0..n {
                    s.hal_error(HalCall::ReadSample, kind, f64::NAN);
                }
                assert_eq!(
                    s.check_sample(&seq_sample(n + 2, 0.0, false)),
                    Some(FaultKind::Link),
                    "k={k}"
                );
                assert_eq!(s.fault(), Some((FaultKind::Link, (n + 1) as f64)));
            }
        }
    }

    #[test]
    fn hal_errors_map_to_one_rule() {
        use bench_hal::ErrorKind as K;
        // Timeouts and corrupt frames on a read are missing samples: K = 3
        // tolerated, the fourth trips the link fault.
        for kind in [K::Timeout, K::Crc] {
            let mut s = sup();
            for _ in 0..3 {
                assert_eq!(
                    s.hal_error(HalCall::ReadSample, kind, f64::NAN),
                    HalVerdict::SampleMissing { tripped: false }
                );
            }
            assert_eq!(
                s.hal_error(HalCall::ReadSample, kind, f64::NAN),
                HalVerdict::SampleMissing { tripped: true }
            );
            assert_eq!(s.fault(), Some((FaultKind::Link, 4.0)));
        }
        // A lost link on a read is the link fault at once.
        let mut s = sup();
        assert_eq!(
            s.hal_error(HalCall::ReadSample, K::Link, f64::NAN),
            HalVerdict::Fault {
                kind: FaultKind::Link,
                tripped: true
            }
        );
        // Everything else is a HAL fault, whatever the call; the first
        // fault stays latched.
        for (call, kind) in [
            (HalCall::ReadSample, K::Protocol),
            (HalCall::ReadSample, K::AmplifierFault),
            (HalCall::WriteCommand, K::Link),
            (HalCall::WriteCommand, K::Timeout),
            (HalCall::Enable, K::AmplifierFault),
        ] {
            let mut s = sup();
            assert_eq!(
                s.hal_error(call, kind, 1.5),
                HalVerdict::Fault {
                    kind: FaultKind::Hal,
                    tripped: true
                },
                "{call:?} {kind:?}"
            );
            assert_eq!(s.fault(), Some((FaultKind::Hal, 1.5)));
            assert_eq!(
                s.hal_error(HalCall::ReadSample, K::Link, f64::NAN),
                HalVerdict::Fault {
                    kind: FaultKind::Link,
                    tripped: false
                }
            );
            assert_eq!(s.fault(), Some((FaultKind::Hal, 1.5)));
        }
    }

    #[test]
    fn position_jump() {
        let mut s = sup();
        assert_eq!(s.check_sample(&seq_sample(0, 0.0, false)), None);
        assert_eq!(s.check_sample(&seq_sample(1, 40e-6, false)), None);
        assert_eq!(
            s.check_sample(&seq_sample(2, 100e-6, false)),
            Some(FaultKind::PositionJump)
        );
    }

    /// I²t: the peak current is allowed for 1 s from cold, the continuous
    /// current for ever (analytic budget (9.98² − 2.34²) A² · 1 s).
    #[test]
    fn i2t_budget() {
        let mut s = sup();
        for _ in 0..100_000 {
            assert_eq!(s.command(2.34).1, None);
        }
        assert_eq!(s.i2t_a2s(), 0.0);
        let mut ticks = 0;
        while s.command(9.98).1.is_none() {
            ticks += 1;
            assert!(ticks < 10_000);
        }
        // 1 s at 5 kHz.
        assert!((4999..=5001).contains(&ticks), "{ticks}");
        assert_eq!(s.state(), SupervisorState::Faulted);
        assert_eq!(s.command(1.0).0, 0.0);
    }

    #[test]
    fn overruns_in_a_row() {
        let mut s = sup();
        // 3 deadlines may be missed in a row; the fourth trips.
        assert_eq!(s.check_overrun(2), None);
        assert_eq!(s.check_overrun(1), None);
        assert_eq!(s.check_overrun(0), None);
        assert_eq!(s.missed_deadlines(), 0);
        assert_eq!(s.check_overrun(1), None);
        assert_eq!(s.check_overrun(2), None);
        assert_eq!(s.check_overrun(1), Some(FaultKind::Overruns));
        // The value is how long the loop was behind: 4 periods of 200 µs.
        let (_, behind_s) = s.fault().unwrap();
        assert!((behind_s - 4.0 * 2e-4).abs() < 1e-12, "{behind_s}");
    }

    /// The supervisor at `rate_hz` with the shipped bound of 2 ms, the
    /// missed deadlines converted as the config does.
    fn sup_at(rate_hz: f64) -> Supervisor {
        let period_s = 1.0 / rate_hz;
        let mut s = Supervisor::new(SupervisorConfig {
            max_missed_deadlines: whole_periods(2e-3, period_s),
            period_s,
            ..config()
        });
        s.enabled();
        s.running();
        s
    }

    /// One tick stalled `stall_s` at `rate_hz`: it ends `stall_s` after
    /// its deadline, so it misses ⌊stall / period⌋ deadlines, then the loop
    /// is on time again. Returns whether the overrun rule tripped.
    fn one_stall_trips(rate_hz: f64, stall_s: f64) -> bool {
        let mut s = sup_at(rate_hz);
        let missed = (stall_s * rate_hz).floor() as u64;
        let tripped = [0, 0, missed, 0, 0]
            .into_iter()
            .any(|m| s.check_overrun(m).is_some());
        assert_eq!(tripped, s.fault().is_some());
        tripped
    }

    /// A loop that ends every tick a little more than a period late for
    /// `late_s` in all: one deadline missed per tick. Returns whether the
    /// rule tripped.
    fn slow_ticks_trip(rate_hz: f64, late_s: f64) -> bool {
        let mut s = sup_at(rate_hz);
        let ticks = (late_s * rate_hz).round() as u64;
        (0..ticks).any(|_| s.check_overrun(1).is_some())
    }

    #[test]
    fn the_same_stall_is_judged_the_same_at_5_10_and_20_khz() {
        for rate_hz in [5e3, 10e3, 20e3] {
            // Behind schedule longer than 2 ms: the fault, at every rate.
            for stall_s in [2.5e-3, 3e-3, 50e-3] {
                assert!(
                    one_stall_trips(rate_hz, stall_s),
                    "{rate_hz} Hz {stall_s} s"
                );
                assert!(
                    slow_ticks_trip(rate_hz, stall_s),
                    "{rate_hz} Hz {stall_s} s"
                );
            }
            // Up to 2 ms: tolerated, at every rate (at 20 kHz 1.5 ms is 30
            // missed deadlines, which M = 5 ticks used to fault on).
            for stall_s in [0.3e-3, 1.5e-3, 1.9e-3] {
                assert!(
                    !one_stall_trips(rate_hz, stall_s),
                    "{rate_hz} Hz {stall_s} s"
                );
                assert!(
                    !slow_ticks_trip(rate_hz, stall_s),
                    "{rate_hz} Hz {stall_s} s"
                );
            }
        }
    }

    #[test]
    fn whole_periods_of_a_bound() {
        // 2 ms is 10 periods at 5 kHz despite 2e-3 / 2e-4 rounding below.
        assert_eq!(whole_periods(2e-3, 2e-4), 10);
        assert_eq!(whole_periods(2e-3, 1e-4), 20);
        assert_eq!(whole_periods(2e-3, 5e-5), 40);
        assert_eq!(whole_periods(2e-3, 1e-2), 0);
        assert_eq!(whole_periods(0.1, 1.0 / 3.0), 0);
    }
}
