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
//! finite (a device flags a reading it has none of as NaN: serial's
//! invalid position, CAN's reserved code, an EtherCAT analog terminal's
//! error bit), probe in range (the device's flag: over- and underrange),
//! |position| within the software limit, change
//! since the last sample plausible (`max_position_step_m` per tick), and,
//! while a job drives the stage, the probe alive: not frozen, and seeing
//! the motion the current makes ([`ProbeValidity`]: `probe_frozen`,
//! `probe_implausible`); on each
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
mod probe;
mod stall;

use bench_hal::{ErrorKind, Sample};
pub use limits::{check_announced, CurrentLimits, LimitSource, ANNOUNCED_CURRENT_MAX_A};
pub use message::fault_message;
pub use probe::{
    frozen_samples, LowPass, Plausibility, ProbeValidity, FROZEN_FALSE_ALARM,
    IMPLAUSIBLE_CURRENT_FRACTION, IMPLAUSIBLE_SEEN_FRACTION, QUASI_STATIC_CORNER,
};
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
    /// The dead-probe rules (`probe_frozen`, `probe_implausible`), derived
    /// from the probe, the link and the plant ([`ProbeValidity::derive`]).
    pub probe: ProbeValidity,
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
    /// The dead-probe rules' state.
    watch: probe::ProbeWatch,
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
            watch: probe::ProbeWatch::default(),
        }
    }

    /// The dead-probe rules' last predicted and seen quasi-static motions,
    /// m (0 before a job drives the stage; see [`ProbeValidity`]).
    pub fn probe_motion_m(&self) -> (f64, f64) {
        (self.watch.predicted_m, self.watch.seen_m)
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

    /// The amplifier was enabled. Ignored while faulted. The sequence
    /// starts again from the next sample: a backend that exchanges its own
    /// frames to enable (the CiA 402 state machine over EtherCAT, one
    /// frame per step) used samples the loop never read, which are not
    /// samples the link lost.
    pub fn enabled(&mut self) {
        if self.state == SupervisorState::Disabled {
            self.state = SupervisorState::Enabled;
            self.last_seq = None;
            self.watch.reset();
        }
    }

    /// A job took over the command. Ignored unless enabled.
    pub fn running(&mut self) {
        if self.state == SupervisorState::Enabled {
            self.state = SupervisorState::Running;
            self.watch.reset();
        }
    }

    /// The amplifier was disabled normally. Ignored while faulted. The
    /// sequence starts again from the next sample, as after
    /// [`Self::enabled`].
    pub fn disabled(&mut self) {
        if self.state != SupervisorState::Faulted {
            self.state = SupervisorState::Disabled;
            self.last_seq = None;
            self.watch.reset();
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
        self.watch.reset();
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

    /// A stall against its two rules: `held` periods that one command has
    /// stayed in force against the reach of that command, and `stalled`
    /// periods in a row (deadlines missed, or late commands) against the
    /// job's bound in periods (`bound`). Returns the rule that broke, and
    /// records its bound.
    fn stall_broken(&mut self, held: u64, stalled: u64, bound: u64) -> Option<StallRule> {
        let held_s = held as f64 * self.cfg.period_s;
        let reach = self.reach_time_s();
        let (rule, bound_s) = if held_s > reach {
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
                .stall_broken(self.late, self.late, self.cfg.max_late_commands)
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
        // The dead-probe rules, on fresh readings while a job drives the
        // stage, with the command in force over the period that ended here.
        let probe = match (fault, stale, self.state) {
            (None, false, SupervisorState::Running) => {
                self.watch.check(&self.cfg.probe, x, self.last_command_a)
            }
            _ => None,
        };
        let fault = fault.or(probe.map(|p| p.0));
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
            // How many readings in a row, or the predicted motion, m.
            Some(FaultKind::ProbeFrozen | FaultKind::ProbeImplausible) => probe.map_or(x, |p| p.1),
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
    /// before the next deadline, which ends the streak), judged by two
    /// rules:
    /// - the reach: the command sent before this tick stayed in force for
    ///   this tick's own lateness; longer than the held current needs to
    ///   carry x1 to the position limit trips. A streak of late ticks
    ///   refreshes the command at every tick, so the streak is not a hold.
    /// - the bound: deadlines missed in a row add up; more than
    ///   `max_missed_deadlines` of them (the whole periods in the job's
    ///   stall bound, from the loop's delay margin) trip. So one stall of a
    ///   given length trips or not whatever the loop rate, and so does a
    ///   loop that keeps ending a little late.
    ///
    /// Either trips [`FaultKind::Overruns`] with the time it judged as its
    /// value, s. Returns the fault if this call tripped it.
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
        let judged =
            match self.stall_broken(missed, self.missed_deadlines, self.cfg.max_missed_deadlines) {
                Some(StallRule::Reach) => missed,
                Some(StallRule::Bound | StallRule::Watchdog) => self.missed_deadlines,
                None => return None,
            };
        self.trip(FaultKind::Overruns, judged as f64 * self.cfg.period_s)
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
mod tests;
