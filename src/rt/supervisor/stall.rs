//! How long a job may leave the stage on a held command: the job's stall
//! bounds (a closed loop's delay rule) and the reach of the held current
//! (README, *Safety: limits and stalls*).

use super::whole_periods;

/// How long a job may leave the stage on a held command: the loop behind
/// its deadlines (host stall), or the device running on late commands.
/// Set per job ([`super::Supervisor::set_stall_bounds`]): a closed loop's bound
/// comes from its loop check (delay margin, the position reachable under
/// the held peak current; [`crate::control::loop_check::StallLimit`]);
/// open-loop identification has none (a late command distorts the record,
/// it endangers nothing: the stall is recorded and its span left out of the
/// FRF); between jobs at 0 A nothing is checked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StallBounds {
    /// Deadlines that may be missed in a row; `u64::MAX`: no bound.
    pub max_missed_deadlines: u64,
    /// Late commands that may run in a row; `u64::MAX`: no bound.
    pub max_late_commands: u64,
}

impl StallBounds {
    /// A stall bound of `bound_s` at a loop period of `period_s`, in whole
    /// periods ([`whole_periods`]), for both rules.
    pub fn of(bound_s: f64, period_s: f64) -> Self {
        let n = if bound_s.is_finite() {
            whole_periods(bound_s, period_s)
        } else {
            u64::MAX
        };
        Self {
            max_missed_deadlines: n,
            max_late_commands: n,
        }
    }

    /// How long the missed-deadline rule lets the loop go without a fresh
    /// sample at a loop period of `period_s`, s: `max_missed_deadlines ×
    /// period_s` (infinite when unbounded). What a backend that waits for
    /// its link may wait before the wait is a fault anyway
    /// ([`AnyStage::set_stall_bound_s`](crate::rt::backend::AnyStage::set_stall_bound_s)).
    pub fn missed_deadlines_s(&self, period_s: f64) -> f64 {
        if self.max_missed_deadlines == u64::MAX {
            f64::INFINITY
        } else {
            self.max_missed_deadlines as f64 * period_s
        }
    }
}

/// Points of a [`ReachEnvelope`].
pub const REACH_POINTS: usize = 64;
/// First and last time of a [`ReachEnvelope`], s (log-spaced between).
pub const REACH_SPAN_S: (f64, f64) = (1e-4, 1.0);

/// How far x1 can move under a held current: the largest |x1| the model
/// reaches from rest under a 1 A step held for `t` (zero-order hold,
/// amplifier lag included), per ampere, at [`REACH_POINTS`] times
/// log-spaced over [`REACH_SPAN_S`]. The plant is linear, so `I` amperes
/// reach `I` times as far. The supervisor judges a stall with it: the held
/// command, the room left to the position limit and this give the time the
/// stall may last ([`ReachEnvelope::time_to_reach_s`]). Plain data, `Copy`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReachEnvelope {
    /// Largest |x1| by `t_i`, m per A (non-decreasing).
    pub m_per_a: [f64; REACH_POINTS],
}

impl ReachEnvelope {
    /// No reach known: every held current is taken as harmless (tests).
    pub const NONE: Self = Self {
        m_per_a: [0.0; REACH_POINTS],
    };

    /// The time of point `i`, s.
    pub fn t_s(i: usize) -> f64 {
        let (a, b) = REACH_SPAN_S;
        a * (b / a).powf(i as f64 / (REACH_POINTS - 1) as f64)
    }

    /// The envelope of `plant` (the model at the loop's period).
    pub fn of(plant: &bench_plant::sim::ZohPlant) -> Self {
        let mut x = nalgebra::SVector::<f64, { bench_plant::sim::STATES }>::zeros();
        let mut m_per_a = [0.0; REACH_POINTS];
        let mut t = 0.0;
        let mut peak = 0.0f64;
        for (i, slot) in m_per_a.iter_mut().enumerate() {
            let until = Self::t_s(i);
            while t < until {
                plant.step(&mut x, 1.0, 0.0);
                t += plant.period_s;
                peak = peak.max(x[0].abs());
            }
            *slot = peak;
        }
        Self { m_per_a }
    }

    /// How long `held_a` amperes may be held before x1 could have moved
    /// `room_m`, s: the last envelope time at which it provably has not
    /// (conservative by one grid step, at most 16 %); infinite if it never
    /// does within the span. Real-time safe.
    pub fn time_to_reach_s(&self, held_a: f64, room_m: f64) -> f64 {
        let held = held_a.abs();
        if room_m.is_nan() || room_m <= 0.0 {
            return 0.0;
        }
        if held == 0.0 {
            return f64::INFINITY;
        }
        match self.m_per_a.iter().position(|&r| held * r > room_m) {
            None => f64::INFINITY,
            Some(0) => 0.0,
            Some(i) => Self::t_s(i - 1),
        }
    }
}

/// Which rule set the bound a stall broke (for its message).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StallRule {
    /// The job's bound in whole periods (a closed loop's delay rule, or a
    /// user's `safety.max_overrun_s` / `max_command_latency_s`).
    Bound,
    /// The held command could have carried x1 to the position limit.
    Reach,
    /// The device's own watchdog time: a device silent for longer is dead
    /// (or has stopped the current itself), the link with it.
    Watchdog,
}
