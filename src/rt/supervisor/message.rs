//! Fault messages a person can act on: the quantity and its unit, the
//! bound it broke and where the bound came from.

use super::{StallRule, SupervisorConfig};
use crate::vocab::FaultKind;

/// A fault as a person can act on it: the quantity and its unit, the bound
/// it broke and where the bound came from, e.g. `stall 29.6 ms > 2.1 ms
/// (delay margin of controller fast at 8.0 % of L (model, 284 rad/s))`.
/// `value` is the supervisor's ([`super::Supervisor::fault`]); `stall_source`
/// names where the stall bound came from; `detail` is what a backend said
/// (link faults). Allocates: never on the tick.
pub fn fault_message(
    kind: FaultKind,
    value: f64,
    cfg: &SupervisorConfig,
    stall: Option<(f64, StallRule, f64)>,
    stall_source: &str,
    detail: Option<&str>,
) -> String {
    let stall_bound = |default_periods: u64| {
        match stall {
        Some((bound_s, StallRule::Reach, held_a)) => format!(
            "{:.1} ms (the held {held_a:.3} A could carry x1 to the {:.1} µm position limit in that time: the model's reach)",
            bound_s * 1e3,
            cfg.position_limit_m * 1e6
        ),
        Some((bound_s, StallRule::Bound, _)) => {
            format!("{:.1} ms ({stall_source})", bound_s * 1e3)
        }
        Some((bound_s, StallRule::Watchdog, _)) => format!(
            "{:.1} ms (the device's watchdog: silent longer, the device is dead or has stopped the current itself)",
            bound_s * 1e3
        ),
        None => format!(
            "{:.1} ms ({stall_source})",
            default_periods as f64 * cfg.period_s * 1e3
        ),
    }
    };
    let um = |m: f64| m * 1e6;
    let ms = |s: f64| s * 1e3;
    let periods_ms = |n: u64| n as f64 * cfg.period_s * 1e3;
    match kind {
        FaultKind::PositionLimit => format!(
            "|x1| = {:.1} µm > {:.1} µm position limit (safety.position_limit_m)",
            um(value.abs()),
            um(cfg.position_limit_m)
        ),
        FaultKind::ProbeOutOfRange => format!(
            "probe out of range: reading {:.1} µm at the end of its range (probe.range_m)",
            um(value)
        ),
        FaultKind::ProbeNotFinite => format!(
            "probe reading {value} m is not a number (or the device flags that it has no valid reading)"
        ),
        FaultKind::ProbeFrozen => format!(
            "probe reading bit-identical for {value} samples in a row ≥ {} that its noise makes plausible (probe.noise_rms_m, probe.quantization_m and the link's count: a false alarm below {:.0e} per sample): the probe is dead or its value frozen",
            cfg.probe.frozen_samples,
            super::FROZEN_FALSE_ALARM
        ),
        FaultKind::ProbeImplausible => match cfg.probe.plausibility {
            Some(p) => format!(
                "the current moved the stage by {:.1} µm quasi-static (model compliance {:.1} µm/A, below {:.2} Hz) and the probe saw less than {:.0} % of it: the probe does not see the stage (decided at {:.1} µm: {:.0} % of the {:.2} A continuous rating)",
                um(value),
                um(p.dc_gain_m_per_a),
                p.corner_hz,
                super::IMPLAUSIBLE_SEEN_FRACTION * 100.0,
                um(p.decide_m),
                super::IMPLAUSIBLE_CURRENT_FRACTION * 100.0,
                cfg.continuous_current_a
            ),
            None => format!("the current moved the stage by {:.1} µm and the probe did not see it", um(value)),
        },
        FaultKind::CommandNotFinite => {
            format!("controller output {value} A is not a number (0 A sent instead)")
        }
        FaultKind::PositionJump => format!(
            "reading moved {:.1} µm in one tick > {:.1} µm (safety.max_position_step_m: faster than the stage can move)",
            um(value),
            um(cfg.max_position_step_m)
        ),
        FaultKind::I2t => {
            let budget = (cfg.peak_current_a.powi(2) - cfg.continuous_current_a.powi(2)).max(0.0)
                * cfg.i2t_peak_duration_s;
            format!(
                "I²t {value:.3} A²s > budget {budget:.3} A²s = (peak {} A² − continuous {} A²) × safety.i2t_peak_duration_s {} s: the coil has carried more than its continuous rating for too long",
                cfg.peak_current_a, cfg.continuous_current_a, cfg.i2t_peak_duration_s
            )
        }
        FaultKind::Overruns => format!(
            "stall {:.1} ms > {}: the loop ran behind its deadlines on a held command",
            ms(value),
            stall_bound(cfg.max_missed_deadlines)
        ),
        FaultKind::LinkLatency => format!(
            "commands late for {:.1} ms > {}: the device ran on held commands",
            ms(value),
            stall_bound(cfg.max_late_commands)
        ),
        FaultKind::StaleSample => format!(
            "{value} stale samples in a row > {} (safety.max_missed_samples): the device repeats its sequence number",
            cfg.max_missed_samples
        ),
        FaultKind::Link => match detail {
            Some(d) if value.is_nan() => d.to_string(),
            Some(d) if stall.is_some() => format!("{d} > {}", stall_bound(cfg.max_late_commands)),
            Some(d) => format!(
                "{d} > {} (safety.max_missed_samples, {:.1} ms)",
                cfg.max_missed_samples,
                periods_ms(u64::from(cfg.max_missed_samples))
            ),
            None => format!("{value} consecutive samples missing > {}", cfg.max_missed_samples),
        },
        FaultKind::Recording => match detail {
            Some(d) => d.to_string(),
            None => format!("the recording failed ({value} records not handed over)"),
        },
        FaultKind::Hal => match detail {
            Some(d) => d.to_string(),
            None => format!("hardware error (value {value})"),
        },
    }
}
