//! `[safety]`, the actuator's current limits against its coil's ratings,
//! and the links of `[backend]`.

use super::*;

impl BenchConfig {
    /// `[safety]`: every key inside its range ([`limits`]).
    pub(super) fn check_safety(&self) -> Result<(), ParamError> {
        let s = &self.safety;
        let lim = s.position_limit_m;
        in_range(
            "safety.position_limit_m",
            lim,
            Range::closed_open(limits::POSITION_LIMIT_MIN_M, limits::STROKE_M),
            "m",
            "above the probe noise and inside the ±1 mm travel of the bench (thesis §5.1.2)",
        )?;
        if lim >= self.stage.mechanical_stop_m {
            return Err(ParamError::new(
                "safety.position_limit_m",
                format!(
                    "{lim} m must be inside the mechanical stop (stage.mechanical_stop_m = {} m)",
                    self.stage.mechanical_stop_m
                ),
            ));
        }
        if lim >= self.probe.range_m {
            return Err(ParamError::new(
                "safety.position_limit_m",
                format!(
                    "{lim} m must be inside the probe range (probe.range_m = {} m)",
                    self.probe.range_m
                ),
            ));
        }
        if s.max_consecutive_overruns.is_some() {
            return Err(ParamError::new(
                "safety.max_consecutive_overruns",
                "was replaced: the stall bound now comes from the loop (delay margin, reach of the position limit), and safety.max_overrun_s (s, optional) may only tighten it; a tick count judged the same stall differently at each loop rate; delete the key, or write e.g. `max_overrun_s = 0.002`".to_string(),
            ));
        }
        if let Some(v) = s.max_overrun_s {
            in_range(
                "safety.max_overrun_s",
                v,
                Range::open_closed(0.0, limits::BLIND_MAX_S),
                "s",
                "above 0 and at most 0.1 s (at the peak force the stage crosses its stroke in less); delete the key for the loop's own bound",
            )?;
        }
        let blind = self.ticks_in(limits::BLIND_MAX_S);
        in_count(
            "safety.max_missed_samples",
            s.max_missed_samples,
            0,
            blind,
            "at most 0.1 s of ticks at loop.rate_hz",
        )?;
        let period_s = 1.0 / self.loop_.rate_hz;
        let step_max = limits::STAGE_SPEED_MAX_M_PER_S * period_s;
        in_range(
            "safety.max_position_step_m",
            s.max_position_step_m,
            Range::closed(limits::POSITION_STEP_MIN_M, step_max),
            "m",
            "above the probe noise and at most 1 m/s × one period (1 / loop.rate_hz; the stage moves at most about 0.5 m/s)",
        )?;
        if s.max_position_step_m >= lim {
            return Err(ParamError::new(
                "safety.max_position_step_m",
                format!(
                    "{} m must be below safety.position_limit_m = {lim} m (a larger step would pass from one side of the limit to the other unnoticed)",
                    s.max_position_step_m
                ),
            ));
        }
        if let Some(v) = s.max_command_latency_s {
            in_range(
                "safety.max_command_latency_s",
                v,
                Range::open_closed(0.0, limits::BLIND_MAX_S),
                "s",
                "above 0 and at most 0.1 s (the stage crosses its stroke in less); delete the key for the loop's own bound",
            )?;
        }
        let (lo, hi) = limits::I2T_PEAK_DURATION_S;
        in_range(
            "safety.i2t_peak_duration_s",
            s.i2t_peak_duration_s,
            Range::closed(lo, hi),
            "s",
            "a coil's peak current is rated for seconds, not minutes",
        )?;
        let (lo, hi) = limits::MIN_PHASE_MARGIN_DEG;
        in_range(
            "safety.min_phase_margin_deg",
            s.min_phase_margin_deg,
            Range::closed_open(lo, hi),
            "°",
            "below 20° a loop rings and small plant changes destabilise it",
        )?;
        in_range(
            "safety.max_sensitivity_peak",
            s.max_sensitivity_peak,
            Range::open_closed(1.0, limits::MAX_SENSITIVITY_PEAK),
            "",
            "above 1 (no loop has a lower sensitivity peak) and at most 6 (modulus margin 0.17)",
        )?;
        Ok(())
    }

    /// The actuator's current limits against its coil's datasheet ratings:
    /// `rated_peak_current_a` in (0, [`limits::PEAK_CURRENT_MAX_A`]],
    /// `rated_continuous_current_a` below it; `peak_current_a` at most the
    /// rated peak; `continuous_current_a` at most the rated continuous
    /// current and at most `peak_current_a /`
    /// [`limits::PEAK_TO_CONTINUOUS_MIN`], so the I²t protection cannot be
    /// configured off.
    pub(super) fn check_actuator_ratings(&self) -> Result<(), ParamError> {
        let a = &self.actuator;
        in_range(
            "actuator.rated_peak_current_a",
            a.rated_peak_current_a,
            Range::open_closed(0.0, limits::PEAK_CURRENT_MAX_A),
            "A",
            "the coil's datasheet peak force over its force constant (LA24-20-000A: 111 N / 11.12 N/A = 9.98 A); at most twice that",
        )?;
        in_range(
            "actuator.rated_continuous_current_a",
            a.rated_continuous_current_a,
            Range::open(0.0, a.rated_peak_current_a),
            "A",
            &format!(
                "the coil's datasheet continuous force over its force constant (LA24-20-000A: 26 N / 11.12 N/A = 2.34 A), below actuator.rated_peak_current_a = {} A",
                a.rated_peak_current_a
            ),
        )?;
        in_range(
            "actuator.peak_current_a",
            a.peak_current_a,
            Range::open_closed(0.0, a.rated_peak_current_a),
            "A",
            &format!(
                "at most the coil's rating actuator.rated_peak_current_a = {} A",
                a.rated_peak_current_a
            ),
        )?;
        let by_ratio = a.peak_current_a / limits::PEAK_TO_CONTINUOUS_MIN;
        let (hi, why) = if a.rated_continuous_current_a <= by_ratio {
            (
                a.rated_continuous_current_a,
                format!(
                    "at most the coil's rating actuator.rated_continuous_current_a = {} A",
                    a.rated_continuous_current_a
                ),
            )
        } else {
            (
                by_ratio,
                format!(
                    "at most actuator.peak_current_a / {} = {by_ratio:.4} A: a continuous rating this close to the peak leaves no I2t budget, which would switch the coil's thermal protection off",
                    limits::PEAK_TO_CONTINUOUS_MIN
                ),
            )
        };
        in_range(
            "actuator.continuous_current_a",
            a.continuous_current_a,
            Range::open_closed(0.0, hi),
            "A",
            &why,
        )
    }

    /// Peak and continuous current ratings under `prefix` (a CAN device):
    /// inside (0, [`limits::PEAK_CURRENT_MAX_A`]], continuous
    /// at most peak (the tables' own checks refuse the rest).
    pub(super) fn check_current_ratings(
        &self,
        prefix: &str,
        peak_a: f64,
        continuous_a: f64,
    ) -> Result<(), ParamError> {
        in_range(
            &format!("{prefix}.peak_current_a"),
            peak_a,
            Range::open_closed(0.0, limits::PEAK_CURRENT_MAX_A),
            "A",
            "twice the 9.98 A peak of the bench's voice coil (LA24-20-000A, thesis §5.1.2)",
        )?;
        in_range(
            &format!("{prefix}.continuous_current_a"),
            continuous_a,
            Range::open_closed(0.0, peak_a),
            "A",
            &format!("positive and at most {prefix}.peak_current_a"),
        )
    }

    /// The device emulator and the link timeouts of `[backend]`, each in
    /// its range, and the time to the link fault (K + 1 timeouts) at most
    /// [`limits::LINK_FAULT_MAX_S`].
    pub(super) fn check_links(&self) -> Result<(), ParamError> {
        let period_s = 1.0 / self.loop_.rate_hz;
        self.backend.serial.validate("backend.serial")?;
        let serial = &self.backend.serial;
        let (lo, hi) = ranges::BAUD;
        if !(lo..=hi).contains(&serial.baud) {
            return Err(ParamError::new(
                "backend.serial.baud",
                format!("{} Bd is outside {lo}…{hi} Bd", serial.baud),
            ));
        }
        let (lo, hi) = limits::HANDSHAKE_TIMEOUT_MS;
        in_range(
            "backend.serial.handshake_timeout_ms",
            serial.handshake_timeout_ms,
            Range::closed(lo, hi),
            "ms",
            "a silent device must not hold the disable longer",
        )?;
        let serial_timeout_s = serial.sample_timeout_periods * period_s;
        if serial_timeout_s > limits::SAMPLE_TIMEOUT_MAX_S * TIME_TOLERANCE {
            return Err(ParamError::new(
                "backend.serial.sample_timeout_periods",
                format!(
                    "{} periods = {:.1} ms at loop.rate_hz = {} Hz is above the longest sample timeout, {} ms",
                    serial.sample_timeout_periods,
                    serial_timeout_s * 1e3,
                    self.loop_.rate_hz,
                    limits::SAMPLE_TIMEOUT_MAX_S * 1e3
                ),
            ));
        }
        let can = &self.backend.can;
        self.check_current_ratings("backend.can", can.peak_current_a, can.continuous_current_a)?;
        can.validate("backend.can")?;
        if let Some(ms) = can.sample_timeout_ms {
            in_range(
                "backend.can.sample_timeout_ms",
                ms,
                Range::closed(
                    limits::CAN_SAMPLE_TIMEOUT_MIN_MS,
                    limits::SAMPLE_TIMEOUT_MAX_S * 1e3,
                ),
                "ms",
                "about one CAN frame to the longest sample timeout",
            )?;
        }
        let period_ns = self.loop_.period_ns();
        let can_timeout_s = can.sample_timeout_ns(period_ns).max(period_ns) as f64 * 1e-9;
        let k = f64::from(self.safety.max_missed_samples);
        for (what, timeout_s) in [
            ("backend.serial.sample_timeout_periods", serial_timeout_s),
            ("backend.can.sample_timeout_ms", can_timeout_s),
        ] {
            if (k + 1.0) * timeout_s > limits::LINK_FAULT_MAX_S * TIME_TOLERANCE {
                return Err(ParamError::new(
                    "safety.max_missed_samples",
                    format!(
                        "{k} missing samples + 1, each a {:.1} ms timeout ({what}), is {:.3} s to the link fault: at most {} s",
                        timeout_s * 1e3,
                        (k + 1.0) * timeout_s,
                        limits::LINK_FAULT_MAX_S
                    ),
                ));
            }
        }
        let ec = &self.backend.ethercat;
        self.check_current_ratings(
            "backend.ethercat",
            ec.peak_current_a,
            ec.continuous_current_a,
        )?;
        ec.validate("backend.ethercat")?;
        in_range(
            "backend.ethercat.watchdog_ms",
            ec.watchdog_ms,
            Range::closed(
                0.2f64.max(2e3 * self.loop_.period_ns() as f64 * 1e-9),
                limits::WATCHDOG_MAX_MS,
            ),
            "ms",
            "at least two loop periods (the drive must not trip between frames), at most 1 s of current after the host is gone",
        )?;
        let e = &self.emulator;
        in_range(
            "emulator.watchdog_ms",
            e.watchdog_ms,
            Range::closed(
                limits::WATCHDOG_MIN_MS.max(2e3 * period_s),
                limits::WATCHDOG_MAX_MS,
            ),
            "ms",
            "at least two loop periods (1 / loop.rate_hz) and 1 ms, at most 1 s of current after the host is gone",
        )?;
        in_range(
            "emulator.position_lsb_m",
            e.position_lsb_m,
            Range::closed(
                self.probe.range_m / f64::from(i32::MAX),
                limits::POSITION_LSB_MAX_M,
            ),
            "m",
            "the 32-bit count must cover probe.range_m, and be finer than the smallest jump the supervisor looks for",
        )?;
        if !(0..=99).contains(&e.priority) {
            return Err(ParamError::new(
                "emulator.priority",
                format!(
                    "SCHED_FIFO priority must be 0 (none) or 1–99, got {}",
                    e.priority
                ),
            ));
        }
        Ok(())
    }
}
