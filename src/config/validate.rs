//! Validation: every key against its physically meaningful range
//! ([`super::limits`], [`super::ranges`]) and the keys against each other,
//! each refusal naming the dotted key and the reason; and the messages of
//! TOML syntax and type errors, naming the key path.

use super::*;
use bench_hal::model::{non_negative, ParamError};

impl BenchConfig {
    /// [`Self::validate`] without a file: for a config changed in memory
    /// (a job request applied to it).
    ///
    /// # Errors
    /// [`ParamError`] with the first offending dotted key.
    pub fn check(&self) -> Result<(), ParamError> {
        if let Some(name) = &self.daemon.hold_controller {
            if !self.controller.contains_key(name) {
                return Err(ParamError::new(
                    "daemon.hold_controller",
                    format!(
                        "no [controller.{name}] in the config (known: {})",
                        self.controller
                            .keys()
                            .cloned()
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                ));
            }
        }
        let (lo, hi) = ranges::RATE_HZ;
        in_range(
            "loop.rate_hz",
            self.loop_.rate_hz,
            Range::closed(lo, hi),
            "Hz",
            "100 Hz to 100 kHz",
        )?;
        if let Some(cpu) = self.loop_.cpu {
            let online = bench_hal::os::online_cpus();
            if cpu >= ranges::CPU_SETSIZE || cpu >= online {
                return Err(ParamError::new(
                    "loop.cpu",
                    format!(
                        "CPU {cpu} does not exist: {online} CPUs are online (0–{})",
                        online.saturating_sub(1)
                    ),
                ));
            }
        }
        if !(1..=99).contains(&self.loop_.priority) {
            return Err(ParamError::new(
                "loop.priority",
                format!(
                    "SCHED_FIFO priority must be 1–99, got {}",
                    self.loop_.priority
                ),
            ));
        }
        let (lo, hi) = ranges::TIMING_INTERVAL_S;
        in_range(
            "loop.timing_interval_s",
            self.loop_.timing_interval_s,
            Range::closed(lo, hi),
            "s",
            "10 ms to a minute",
        )?;
        self.plant.validate("plant").map_err(|mut e| {
            let value = match e.key.as_str() {
                "plant.mass_asymmetry" => self.plant.mass_asymmetry,
                "plant.operating_point_m" => self.plant.operating_point_m,
                _ => return e,
            };
            if let Some(hint) = unit_hint(&e.key, value, self.plant.beam.length_m) {
                e.reason = format!("{}; {hint}", e.reason);
            }
            e
        })?;
        let nyquist = self.loop_.rate_hz / 2.0;
        if let Some(d) = &self.plant.disturbance {
            if d.band_hz[1] >= nyquist {
                return Err(ParamError::new(
                    "plant.disturbance.band_hz[1]",
                    format!(
                        "{} Hz is at or above the Nyquist frequency {nyquist} Hz of the loop (loop.rate_hz = {} Hz)",
                        d.band_hz[1], self.loop_.rate_hz
                    ),
                ));
            }
        }
        let (lo, hi) = ranges::FORCE_CONSTANT_N_PER_A;
        in_range(
            "actuator.force_constant_n_per_a",
            self.actuator.force_constant_n_per_a,
            Range::closed(lo, hi),
            "N/A",
            "voice coils are 1–100 N/A",
        )?;
        let (lo, hi) = ranges::AMPLIFIER_BANDWIDTH_HZ;
        in_range(
            "actuator.bandwidth_hz",
            self.actuator.bandwidth_hz,
            Range::closed(lo, hi),
            "Hz",
            "the current loop of a linear amplifier",
        )?;
        // The ratings first: their messages name both keys.
        self.check_actuator_ratings()?;
        self.actuator.validate("actuator")?;
        let (lo, hi) = ranges::TRAVEL_M;
        in_range(
            "probe.range_m",
            self.probe.range_m,
            Range::closed(lo, hi),
            "m",
            "10 µm to 10 mm",
        )?;
        let (lo, hi) = ranges::PROBE_RESOLUTION_M;
        for (key, v) in [
            ("probe.noise_rms_m", self.probe.noise_rms_m),
            ("probe.quantization_m", self.probe.quantization_m),
        ] {
            in_range(
                key,
                v,
                Range::closed(lo, hi),
                "m",
                "0 to 1 µm, the smallest jump the supervisor looks for (and below probe.range_m)",
            )?;
        }
        self.probe.validate("probe")?;
        let (lo, hi) = ranges::TRAVEL_M;
        in_range(
            "stage.mechanical_stop_m",
            self.stage.mechanical_stop_m,
            Range::closed(lo, hi),
            "m",
            "10 µm to 10 mm",
        )?;
        self.check_safety()?;
        self.check_links()?;
        self.check_chirp()?;
        for (name, c) in &self.controller {
            c.validate(&format!("controller.{name}"))
                .map_err(|e| ParamError::new(e.key, e.reason))?;
        }
        self.check_step()?;
        self.check_identification()
    }

    /// `[step]`: each key in its range ([`ranges`]), the phases inside the
    /// run, the run at most [`ranges::JOB_TICKS_MAX`] ticks.
    fn check_step(&self) -> Result<(), ParamError> {
        let st = &self.step;
        if !st.step_m.is_finite() || st.step_m.abs() < ranges::STEP_MIN_M {
            return Err(ParamError::new(
                "step.step_m",
                format!(
                    "must be finite with |step_m| at least {} m (1 nm), got {}",
                    ranges::STEP_MIN_M,
                    st.step_m
                ),
            ));
        }
        if st.step_m.abs() >= self.safety.position_limit_m {
            return Err(ParamError::new(
                "step.step_m",
                format!(
                    "{} m is not inside the software position limit safety.position_limit_m = {} m",
                    st.step_m, self.safety.position_limit_m
                ),
            ));
        }
        for (key, v) in [
            ("step.settle_s", st.settle_s),
            ("step.smooth_s", st.smooth_s),
        ] {
            in_range(
                key,
                v,
                Range::closed(0.0, ranges::STEP_PHASE_MAX_S),
                "s",
                "0 to a minute",
            )?;
        }
        in_range(
            "step.duration_s",
            st.duration_s,
            Range::open_closed(0.0, ranges::STEP_DURATION_MAX_S),
            "s",
            "a closed-loop step runs at most an hour",
        )?;
        self.check_job_ticks("step.duration_s", st.duration_s)?;
        if st.settle_s + st.smooth_s >= st.duration_s {
            return Err(ParamError::new(
                "step.duration_s",
                format!(
                    "{} s leaves no time after step.settle_s + step.smooth_s = {} s",
                    st.duration_s,
                    st.settle_s + st.smooth_s
                ),
            ));
        }
        in_range(
            "step.steady_state_window_s",
            st.steady_state_window_s,
            Range::closed(
                ranges::STEADY_STATE_WINDOW_MIN_S,
                st.duration_s - st.settle_s - st.smooth_s,
            ),
            "s",
            "at least 1 ms, and it must fit after the step (step.duration_s - step.settle_s - step.smooth_s)",
        )?;
        Ok(())
    }

    /// `[identification]`: each key in its range ([`ranges`]).
    fn check_identification(&self) -> Result<(), ParamError> {
        let id = &self.identification;
        let (lo, hi) = ranges::POINTS_PER_DECADE;
        if !(lo..=hi).contains(&id.points_per_decade) {
            return Err(ParamError::new(
                "identification.points_per_decade",
                format!("must be {lo}–{hi}, got {}", id.points_per_decade),
            ));
        }
        let (rlo, rhi) = ranges::RELATIVE_RESOLUTION;
        in_range(
            "identification.relative_resolution",
            id.relative_resolution,
            Range::closed(rlo, rhi),
            "",
            "a fraction of the frequency, 0.01 % to 50 %",
        )?;
        let most = ranges::points_per_decade_max(id.relative_resolution);
        if id.points_per_decade > most {
            return Err(ParamError::new(
                "identification.points_per_decade",
                format!(
                    "{} points per decade is denser than the FRF estimate resolves: each point \
                     averages a window of identification.relative_resolution = {} × f (and at \
                     least identification.min_bins DFT bins, so the grid cannot usefully be \
                     denser than the record's DFT resolution either), ln(10) / {} = {:.0} \
                     independent points per decade; more than {} points per window add time, \
                     not detail. Range [{lo}, {most}] at this relative_resolution",
                    id.points_per_decade,
                    id.relative_resolution,
                    id.relative_resolution,
                    std::f64::consts::LN_10 / id.relative_resolution,
                    ranges::POINTS_PER_WINDOW,
                ),
            ));
        }
        let (lo, hi) = ranges::MIN_BINS;
        if !(lo..=hi).contains(&id.min_bins) {
            return Err(ParamError::new(
                "identification.min_bins",
                format!(
                    "must be {lo}–{hi} (coherence needs averaging over bins), got {}",
                    id.min_bins
                ),
            ));
        }
        let (lo, hi) = ranges::LPM_DEGREE;
        if !(lo..=hi).contains(&id.lpm_degree) {
            return Err(ParamError::new(
                "identification.lpm_degree",
                format!(
                    "must be {lo}–{hi} (the degree of the LPM's local polynomials; 2 is the \
                     textbook choice), got {}",
                    id.lpm_degree
                ),
            ));
        }
        let lo = id.lpm_degree + ranges::LPM_HALF_WIDTH_OVER_DEGREE_MIN;
        let hi = ranges::LPM_HALF_WIDTH_MAX;
        if !(lo..=hi).contains(&id.lpm_half_width_bins) {
            return Err(ParamError::new(
                "identification.lpm_half_width_bins",
                format!(
                    "must be {lo}–{hi} at identification.lpm_degree = {}, got {}: at least \
                     lpm_degree + 2, so that the local window of 2n + 1 bins keeps 3 or more \
                     degrees of freedom for the noise variance after the 2(R + 1) \
                     coefficients; at most {hi} bins, or the window is no longer local against \
                     the modes' half-power bands",
                    id.lpm_degree, id.lpm_half_width_bins
                ),
            ));
        }
        Ok(())
    }

    /// A job of `seconds` at the loop rate is at most
    /// [`ranges::JOB_TICKS_MAX`] ticks (its record is held in memory).
    fn check_job_ticks(&self, key: &str, seconds: f64) -> Result<(), ParamError> {
        let ticks = seconds * self.loop_.rate_hz;
        if !ticks.is_finite() || ticks > ranges::JOB_TICKS_MAX as f64 {
            return Err(ParamError::new(
                key,
                format!(
                    "{seconds} s at loop.rate_hz = {} Hz is {ticks:.0} ticks: a job is at most {} ticks",
                    self.loop_.rate_hz,
                    ranges::JOB_TICKS_MAX
                ),
            ));
        }
        Ok(())
    }

    /// The ticks in `seconds` at the loop rate (rounded down; the rate is
    /// checked first).
    fn ticks_in(&self, seconds: f64) -> u64 {
        (seconds * self.loop_.rate_hz * TIME_TOLERANCE).floor() as u64
    }

    /// `[safety]`: every key inside its range ([`limits`]).
    fn check_safety(&self) -> Result<(), ParamError> {
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
    fn check_actuator_ratings(&self) -> Result<(), ParamError> {
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
    fn check_current_ratings(
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
    fn check_links(&self) -> Result<(), ParamError> {
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

    fn check_chirp(&self) -> Result<(), ParamError> {
        let c = &self.chirp;
        let nyquist = self.loop_.rate_hz / 2.0;
        in_range(
            "chirp.f_start_hz",
            c.f_start_hz,
            Range::closed(ranges::CHIRP_F_MIN_HZ, f64::MAX),
            "Hz",
            "at least 0.01 Hz, and below chirp.f_end_hz",
        )?;
        in_range(
            "chirp.f_end_hz",
            c.f_end_hz,
            Range::closed(ranges::CHIRP_F_MIN_HZ, f64::MAX),
            "Hz",
            "above chirp.f_start_hz and below the Nyquist frequency",
        )?;
        if c.f_end_hz >= nyquist {
            return Err(ParamError::new(
                "chirp.f_end_hz",
                format!(
                    "{} Hz is at or above the Nyquist frequency {nyquist} Hz of the loop (loop.rate_hz = {} Hz)",
                    c.f_end_hz, self.loop_.rate_hz
                ),
            ));
        }
        if c.f_start_hz >= c.f_end_hz {
            return Err(ParamError::new(
                "chirp.f_start_hz",
                format!(
                    "{} Hz must be below chirp.f_end_hz = {} Hz",
                    c.f_start_hz, c.f_end_hz
                ),
            ));
        }
        in_range(
            "chirp.amplitude_a",
            c.amplitude_a,
            Range::closed(ranges::CHIRP_AMPLITUDE_MIN_A, f64::MAX),
            "A",
            "at least 0.1 mA and at most actuator.peak_current_a",
        )?;
        if c.amplitude_a > self.actuator.peak_current_a {
            return Err(ParamError::new(
                "chirp.amplitude_a",
                format!(
                    "{} A is above the amplifier's peak current actuator.peak_current_a = {} A",
                    c.amplitude_a, self.actuator.peak_current_a
                ),
            ));
        }
        if c.amplitude_profile.len() > MAX_PROFILE_POINTS {
            return Err(ParamError::new(
                "chirp.amplitude_profile",
                format!(
                    "at most {MAX_PROFILE_POINTS} breakpoints, got {}",
                    c.amplitude_profile.len()
                ),
            ));
        }
        for (i, [f, scale]) in c.amplitude_profile.iter().enumerate() {
            let key = format!("chirp.amplitude_profile[{i}]");
            in_range(
                &format!("{key}[0]"),
                *f,
                Range::closed_open(ranges::CHIRP_F_MIN_HZ, nyquist),
                "Hz",
                "a breakpoint frequency from 0.01 Hz to below the Nyquist frequency (loop.rate_hz / 2)",
            )?;
            let (lo, hi) = ranges::PROFILE_SCALE;
            in_range(
                &format!("{key}[1]"),
                *scale,
                Range::closed(lo, hi),
                "",
                "a scale of amplitude_a (the largest amplitude), 0.001 to 1",
            )?;
            if i > 0 && *f <= c.amplitude_profile[i - 1][0] {
                return Err(ParamError::new(
                    format!("{key}[0]"),
                    format!(
                        "{f} Hz must be above chirp.amplitude_profile[{}][0] = {} Hz (frequencies strictly ascending)",
                        i - 1,
                        c.amplitude_profile[i - 1][0]
                    ),
                ));
            }
        }
        for (key, v) in [("chirp.lead_in_s", c.lead_in_s), ("chirp.tail_s", c.tail_s)] {
            in_range(
                key,
                v,
                Range::closed(0.0, ranges::CHIRP_QUIET_MAX_S),
                "s",
                "0 to a minute of quiet time",
            )?;
        }
        if c.kind.is_sweep() {
            self.check_sweep()
        } else {
            self.check_multisine()
        }
    }

    /// A sweep's own keys: `chirp.duration_s` and `chirp.taper_s` present
    /// and in range, no `[multisine]` table.
    fn check_sweep(&self) -> Result<(), ParamError> {
        let c = &self.chirp;
        let kind = c.kind.as_str();
        if self.multisine.is_some() {
            return Err(ParamError::new(
                "multisine",
                format!(
                    "the [multisine] table is set but chirp.kind = \"{kind}\" plays a sweep, which would not use it: set chirp.kind = \"multisine\", or delete the table"
                ),
            ));
        }
        let missing = |key: &str, what: &str| {
            ParamError::new(
                key,
                format!("missing: the sweep (chirp.kind = \"{kind}\") needs its {what}"),
            )
        };
        let duration_s = c
            .duration_s
            .ok_or_else(|| missing("chirp.duration_s", "duration, s; range [0.1, 600]"))?;
        let taper_s = c.taper_s.ok_or_else(|| {
            missing(
                "chirp.taper_s",
                "fade at each end, s (0 for none); range [0, duration_s / 2]",
            )
        })?;
        let (lo, hi) = ranges::CHIRP_DURATION_S;
        in_range(
            "chirp.duration_s",
            duration_s,
            Range::closed(lo, hi),
            "s",
            "0.1 s to 10 minutes",
        )?;
        non_negative("chirp.taper_s", taper_s)?;
        if 2.0 * taper_s > duration_s {
            return Err(ParamError::new(
                "chirp.taper_s",
                format!(
                    "2 × {taper_s} s of taper does not fit in chirp.duration_s = {duration_s} s"
                ),
            ));
        }
        self.check_job_ticks("chirp.duration_s", c.lead_in_s + duration_s + c.tail_s)?;
        Ok(())
    }

    /// `chirp.kind = "multisine"`: no sweep keys, and the `[multisine]`
    /// table (or its defaults) in range: the phases' realizations, the
    /// period against the band's start, at least
    /// [`ranges::MULTISINE_LINES_MIN`] excited lines, the record at most
    /// [`ranges::JOB_TICKS_MAX`] ticks.
    fn check_multisine(&self) -> Result<(), ParamError> {
        let c = &self.chirp;
        for (key, set) in [
            ("chirp.duration_s", c.duration_s.is_some()),
            ("chirp.taper_s", c.taper_s.is_some()),
        ] {
            if set {
                return Err(ParamError::new(
                    key,
                    "is a sweep's key and chirp.kind = \"multisine\" would not use it (the record's length is multisine.realizations × (multisine.transient_periods + multisine.periods) × multisine.period_s; a periodic signal has no ends to fade): delete it, or set chirp.kind to a sweep",
                ));
            }
        }
        let ms = self.multisine.unwrap_or_default();
        let count = |key: &str, v: u32, (lo, hi): (u32, u32), why: &str| {
            in_count(key, v, u64::from(lo), u64::from(hi), why)
        };
        count(
            "multisine.periods",
            ms.periods,
            ranges::MULTISINE_PERIODS,
            "two periods at least for the noise variance",
        )?;
        count(
            "multisine.transient_periods",
            ms.transient_periods,
            ranges::MULTISINE_TRANSIENT_PERIODS,
            "discarded periods while the transient decays",
        )?;
        count(
            "multisine.lines_per_decade",
            ms.lines_per_decade,
            ranges::MULTISINE_LINES_PER_DECADE,
            "the densest line grid per decade",
        )?;
        match ms.phases {
            MultisinePhases::Random => count(
                "multisine.realizations",
                ms.realizations,
                ranges::MULTISINE_REALIZATIONS,
                "random phases need two realizations at least for the variance over them (four or more recommended)",
            )?,
            MultisinePhases::Schroeder => {
                if ms.realizations != 1 {
                    return Err(ParamError::new(
                        "multisine.realizations",
                        format!(
                            "{} with multisine.phases = \"schroeder\": Schroeder phases are one deterministic signal, so every realization would be the same and the nonlinear distortion could not average out; give 1, or phases = \"random\"",
                            ms.realizations
                        ),
                    ));
                }
            }
        }
        let tick_s = 1.0 / self.loop_.rate_hz;
        let lowest_s = 1.0 / c.f_start_hz;
        if let Some(p) = ms.period_s {
            in_range(
                "multisine.period_s",
                p,
                Range::closed(lowest_s * (1.0 - 1e-9), ranges::MULTISINE_PERIOD_MAX_S),
                "s",
                "at least 1 / chirp.f_start_hz (the lowest line 1 / period_s must reach down to the band's start) and at most 10 minutes",
            )?;
        }
        let Some(ticks) = ms.period_ticks(c.f_start_hz, tick_s) else {
            return Err(ParamError::new(
                "multisine.period_s",
                format!(
                    "{} s at loop.rate_hz = {} Hz is more ticks than a job may have ({})",
                    ms.period_s.unwrap_or(lowest_s),
                    self.loop_.rate_hz,
                    ranges::JOB_TICKS_MAX
                ),
            ));
        };
        let t_p = ticks as f64 * tick_s;
        if t_p * c.f_start_hz < 1.0 - 1e-9 {
            return Err(ParamError::new(
                "multisine.period_s",
                format!(
                    "{t_p} s (rounded to {ticks} ticks of loop.rate_hz = {} Hz) is shorter than 1 / chirp.f_start_hz = {lowest_s} s: the lowest line 1 / period_s would lie above the band's start",
                    self.loop_.rate_hz
                ),
            ));
        }
        if t_p > ranges::MULTISINE_PERIOD_MAX_S * (1.0 + 1e-9) {
            return Err(ParamError::new(
                "multisine.period_s",
                format!(
                    "absent, it is 1 / chirp.f_start_hz = {t_p} s, above the longest period, {} s: give a period, or raise chirp.f_start_hz",
                    ranges::MULTISINE_PERIOD_MAX_S
                ),
            ));
        }
        let lines = ms
            .excited_lines(c.f_start_hz, c.f_end_hz, ticks, tick_s)
            .len();
        if lines < ranges::MULTISINE_LINES_MIN {
            return Err(ParamError::new(
                "multisine.lines_per_decade",
                format!(
                    "{lines} DFT lines l / multisine.period_s ({t_p} s) fall in chirp.f_start_hz … chirp.f_end_hz ({} … {} Hz) at {} lines per decade: at least {} are needed (an FRF has at least that many points); raise multisine.lines_per_decade or multisine.period_s, or widen the band",
                    c.f_start_hz,
                    c.f_end_hz,
                    ms.lines_per_decade,
                    ranges::MULTISINE_LINES_MIN
                ),
            ));
        }
        let per_realization = u64::from(ms.transient_periods) + u64::from(ms.periods);
        let record_s = f64::from(ms.realizations) * per_realization as f64 * t_p;
        let total_s = c.lead_in_s + record_s + c.tail_s;
        let total_ticks = total_s * self.loop_.rate_hz;
        if !total_ticks.is_finite() || total_ticks > ranges::JOB_TICKS_MAX as f64 {
            return Err(ParamError::new(
                "multisine.periods",
                format!(
                    "the record, chirp.lead_in_s + multisine.realizations × (multisine.transient_periods + multisine.periods) × multisine.period_s + chirp.tail_s = {} + {} × {} × {t_p} + {} = {total_s} s, is {total_ticks:.0} ticks at loop.rate_hz = {} Hz: a job is at most {} ticks",
                    c.lead_in_s,
                    ms.realizations,
                    per_realization,
                    c.tail_s,
                    self.loop_.rate_hz,
                    ranges::JOB_TICKS_MAX
                ),
            ));
        }
        Ok(())
    }
}

/// Products of periods and counts are compared with the time bounds of
/// [`limits`] with this relative slack, so that a value exactly on a bound
/// (1000 periods at 5 kHz = 200 ms) is not refused for a rounding error.
const TIME_TOLERANCE: f64 = 1.0 + 1e-9;

/// A range of a real value; either end open or closed.
#[derive(Debug, Clone, Copy)]
struct Range {
    lo: f64,
    lo_closed: bool,
    hi: f64,
    hi_closed: bool,
}

impl Range {
    /// `[lo, hi]`
    fn closed(lo: f64, hi: f64) -> Self {
        Self {
            lo,
            lo_closed: true,
            hi,
            hi_closed: true,
        }
    }
    /// `[lo, hi)`
    fn closed_open(lo: f64, hi: f64) -> Self {
        Self {
            hi_closed: false,
            ..Self::closed(lo, hi)
        }
    }
    /// `(lo, hi)`
    fn open(lo: f64, hi: f64) -> Self {
        Self {
            lo_closed: false,
            hi_closed: false,
            ..Self::closed(lo, hi)
        }
    }
    /// `(lo, hi]`
    fn open_closed(lo: f64, hi: f64) -> Self {
        Self {
            lo_closed: false,
            ..Self::closed(lo, hi)
        }
    }

    fn contains(&self, v: f64) -> bool {
        let above = if self.lo_closed {
            v >= self.lo
        } else {
            v > self.lo
        };
        let below = if self.hi_closed {
            v <= self.hi
        } else {
            v < self.hi
        };
        above && below
    }
}

impl std::fmt::Display for Range {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}{:?}, {:?}{}",
            if self.lo_closed { '[' } else { '(' },
            self.lo,
            self.hi,
            if self.hi_closed { ']' } else { ')' }
        )
    }
}

/// `value` finite and inside `range` (in `unit`), else an error naming
/// `key` with the range and `why`.
fn in_range(key: &str, value: f64, range: Range, unit: &str, why: &str) -> Result<(), ParamError> {
    if !value.is_finite() {
        return Err(ParamError::new(
            key,
            format!("must be a finite number, got {value}"),
        ));
    }
    if !range.contains(value) {
        let unit = if unit.is_empty() {
            String::new()
        } else {
            format!(" {unit}")
        };
        return Err(ParamError::new(
            key,
            format!("{value:?}{unit} is outside {range}{unit}: {why}"),
        ));
    }
    Ok(())
}

/// The ticks in `seconds` at a loop period of `period_s`, rounded to the
/// nearest: `None` unless both are finite, `seconds` is non-negative,
/// `period_s` positive and the count at most [`ranges::JOB_TICKS_MAX`].
pub fn ticks_in(seconds: f64, period_s: f64) -> Option<u64> {
    if !(seconds.is_finite() && seconds >= 0.0 && period_s.is_finite() && period_s > 0.0) {
        return None;
    }
    let t = (seconds / period_s).round();
    (t <= ranges::JOB_TICKS_MAX as f64).then_some(t as u64)
}

/// The message of a TOML error in `text`, the key it is about first: the
/// parser names a line, and the key only when it is on that line, so the
/// full key path comes first, array elements by index
/// (`chirp.amplitude_profile[1][1]: TOML parse error at line 86, …`),
/// also for an element on a line of its own. Without a key (a syntax
/// error), the parser's message alone.
pub fn toml_error_message(text: &str, e: &toml::de::Error) -> String {
    let message = e.to_string().trim_end().to_string();
    match e.span().and_then(|span| key_path_at(text, span)) {
        Some(key) => format!("{key}: {message}"),
        None => message,
    }
}

/// The dotted key path of the innermost key or value of `text` whose span
/// holds `span` (a parse error's): tables and inline tables by name, array
/// elements and arrays of tables by index (`controller.fast.real_poles_rad_s[1]`,
/// `chirp.amplitude_profile[1][1]`). `None` for text that is no TOML
/// document (a syntax error) or a span outside every key.
pub(super) fn key_path_at(text: &str, span: std::ops::Range<usize>) -> Option<String> {
    use toml_edit::{Item, Table, Value};
    /// The best (shortest containing) span so far, and its path.
    type Best = Option<(usize, String)>;
    fn consider(
        at: Option<std::ops::Range<usize>>,
        span: &std::ops::Range<usize>,
        path: &str,
        best: &mut Best,
    ) {
        if let Some(at) = at {
            let holds = at.start <= span.start && span.end <= at.end;
            if holds && best.as_ref().is_none_or(|(len, _)| at.len() <= *len) {
                *best = Some((at.len(), path.to_string()));
            }
        }
    }
    fn join(path: &str, key: &str) -> String {
        if path.is_empty() {
            key.to_string()
        } else {
            format!("{path}.{key}")
        }
    }
    fn value(v: &Value, path: &str, span: &std::ops::Range<usize>, best: &mut Best) {
        consider(v.span(), span, path, best);
        match v {
            Value::Array(a) => {
                for (i, x) in a.iter().enumerate() {
                    value(x, &format!("{path}[{i}]"), span, best);
                }
            }
            Value::InlineTable(t) => {
                for (k, x) in t.iter() {
                    let p = join(path, k);
                    consider(t.key(k).and_then(toml_edit::Key::span), span, &p, best);
                    value(x, &p, span, best);
                }
            }
            _ => {}
        }
    }
    fn item(it: &Item, path: &str, span: &std::ops::Range<usize>, best: &mut Best) {
        match it {
            Item::Value(v) => value(v, path, span, best),
            Item::Table(t) => table(t, path, span, best),
            Item::ArrayOfTables(a) => {
                for (i, t) in a.iter().enumerate() {
                    table(t, &format!("{path}[{i}]"), span, best);
                }
            }
            Item::None => {}
        }
    }
    fn table(t: &Table, path: &str, span: &std::ops::Range<usize>, best: &mut Best) {
        if !path.is_empty() {
            consider(t.span(), span, path, best);
        }
        for (k, it) in t.iter() {
            let p = join(path, k);
            consider(t.key(k).and_then(toml_edit::Key::span), span, &p, best);
            item(it, &p, span, best);
        }
    }
    let doc = toml_edit::ImDocument::parse(text).ok()?;
    let mut best = None;
    table(doc.as_table(), "", &span, &mut best);
    best.map(|(_, path)| path)
}

/// A count inside `lo..=hi`, else an error naming `key`.
fn in_count(key: &str, value: u32, lo: u64, hi: u64, why: &str) -> Result<(), ParamError> {
    if (lo..=hi).contains(&u64::from(value)) {
        Ok(())
    } else {
        Err(ParamError::new(
            key,
            format!("{value} is outside {lo}…{hi}: {why}"),
        ))
    }
}
