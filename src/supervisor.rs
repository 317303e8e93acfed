//! The safety supervisor that runs on every tick (SPEC §7).
//!
//! States: `disabled → enabled → running → faulted`. A fault latches: the
//! command is 0 A from the faulting tick on and the loop disables the
//! amplifier in the same tick; only [`Supervisor::reset`] leaves `faulted`.
//!
//! Checks, in order, on each sample: probe value finite, probe in range,
//! |position| within the software limit; on each command: finite; on each
//! tick in real-time mode: fewer than M consecutive overruns. Commands are
//! clipped to the amplifier's peak current.

use crate::records::{FaultKind, SupervisorState};
use bench_hal::Sample;

/// Supervisor limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SupervisorConfig {
    /// Software limit on |x1|, m.
    pub position_limit_m: f64,
    /// Amplifier peak current, A: commands are clipped to ±this.
    pub peak_current_a: f64,
    /// Consecutive overruns that fault (0 disables the check, virtual time).
    pub max_consecutive_overruns: u32,
}

/// The supervisor. All methods are real-time safe.
#[derive(Debug, Clone)]
pub struct Supervisor {
    cfg: SupervisorConfig,
    state: SupervisorState,
    fault: Option<(FaultKind, f64)>,
    consecutive_overruns: u32,
}

impl Supervisor {
    /// A supervisor in the `disabled` state.
    pub fn new(cfg: SupervisorConfig) -> Self {
        Self {
            cfg,
            state: SupervisorState::Disabled,
            fault: None,
            consecutive_overruns: 0,
        }
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

    /// Clears a latched fault: back to `disabled`.
    pub fn reset(&mut self) {
        self.state = SupervisorState::Disabled;
        self.fault = None;
        self.consecutive_overruns = 0;
    }

    /// Checks a sample; trips and returns the fault if it is bad.
    pub fn check_sample(&mut self, s: &Sample) -> Option<FaultKind> {
        let x = s.position_m;
        let fault = if !x.is_finite() {
            Some(FaultKind::ProbeNotFinite)
        } else if s.flags.out_of_range {
            Some(FaultKind::ProbeOutOfRange)
        } else if x.abs() > self.cfg.position_limit_m {
            Some(FaultKind::PositionLimit)
        } else {
            None
        };
        fault.filter(|k| self.trip(*k, x))
    }

    /// Records whether this tick overran; trips after M in a row.
    pub fn check_overrun(&mut self, overran: bool) -> Option<FaultKind> {
        if !overran {
            self.consecutive_overruns = 0;
            return None;
        }
        self.consecutive_overruns += 1;
        let m = self.cfg.max_consecutive_overruns;
        if m > 0
            && self.consecutive_overruns >= m
            && self.trip(FaultKind::Overruns, self.consecutive_overruns as f64)
        {
            Some(FaultKind::Overruns)
        } else {
            None
        }
    }

    /// The command to send for a job's demand `current_a`: 0 A unless
    /// running, clipped to the peak current; a non-finite demand trips.
    pub fn command(&mut self, current_a: f64) -> (f64, Option<FaultKind>) {
        if !current_a.is_finite() {
            let tripped = self.trip(FaultKind::CommandNotFinite, current_a);
            return (0.0, tripped.then_some(FaultKind::CommandNotFinite));
        }
        if self.state != SupervisorState::Running {
            return (0.0, None);
        }
        let p = self.cfg.peak_current_a;
        (current_a.clamp(-p, p), None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bench_hal::SampleFlags;

    fn sup() -> Supervisor {
        let mut s = Supervisor::new(SupervisorConfig {
            position_limit_m: 0.8e-3,
            peak_current_a: 9.98,
            max_consecutive_overruns: 3,
        });
        s.enabled();
        s.running();
        s
    }

    fn sample(x: f64, oor: bool) -> Sample {
        Sample {
            seq: 0,
            device_time_ns: 0,
            position_m: x,
            measured_current_a: f64::NAN,
            flags: SampleFlags {
                out_of_range: oor,
                ..Default::default()
            },
        }
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
    fn overruns_in_a_row() {
        let mut s = sup();
        assert_eq!(s.check_overrun(true), None);
        assert_eq!(s.check_overrun(true), None);
        assert_eq!(s.check_overrun(false), None);
        assert_eq!(s.check_overrun(true), None);
        assert_eq!(s.check_overrun(true), None);
        assert_eq!(s.check_overrun(true), Some(FaultKind::Overruns));
    }
}
