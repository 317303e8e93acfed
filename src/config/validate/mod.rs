//! Validation: every key against its physically meaningful range
//! ([`super::limits`], [`super::ranges`]) and the keys against each other,
//! each refusal naming the dotted key and the reason; and the messages of
//! TOML syntax and type errors, naming the key path.

use super::*;
use bench_hal::param::{non_negative, ParamError};

mod excitation;
mod safety;
mod toml_error;
pub use toml_error::*;

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
        // The model every run builds (the simulator, the loop check, the
        // predictions), built here by the same constructor: a config is
        // refused by this check for exactly what the runs refuse in it
        // (a Rayleigh fit that gives a mode negative damping, matrices
        // that are not positive definite, modes that do not converge).
        bench_plant::model::Sr4dof::new(self.plant)?;
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
        self.check_trajectory()?;
        self.check_identification()
    }

    /// `[trajectory]`: each key given in its range
    /// ([`super::trajectory::TrajectoryConfig`]); what needs the model
    /// (the line rate against the zeros' bands, a move within its line,
    /// the predicted current) is checked when `bench track` plans it.
    fn check_trajectory(&self) -> Result<(), ParamError> {
        let t = &self.trajectory;
        let limit = self.safety.position_limit_m;
        let rate = self.loop_.rate_hz;
        let csv = t.scan == Some(ScanKind::Csv);
        match (csv, &t.reference) {
            (true, None) => {
                return Err(ParamError::new(
                    "trajectory.reference",
                    "scan = \"csv\" needs a reference (FILE.csv), the line to track",
                ))
            }
            (false, Some(p)) => {
                return Err(ParamError::new(
                    "trajectory.reference",
                    format!("{} is the line of scan = \"csv\" only", p.display()),
                ))
            }
            _ => {}
        }
        for (key, v) in [
            ("trajectory.amplitude_m", t.amplitude_m),
            ("trajectory.line_rate_hz", t.line_rate_hz),
        ] {
            if csv && v.is_some() {
                return Err(ParamError::new(
                    key,
                    "a csv scan's reference has its own amplitude and line rate (its rows): leave it out",
                ));
            }
        }
        if let Some(a) = t.amplitude_m {
            in_range(
                "trajectory.amplitude_m",
                a,
                Range::open(0.0, limit),
                "m",
                "about the start position, inside safety.position_limit_m",
            )?;
        }
        if let Some(l) = t.line_rate_hz {
            in_range(
                "trajectory.line_rate_hz",
                l,
                Range::open_closed(0.0, rate / 8.0),
                "Hz",
                "a line of 8 ticks of loop.rate_hz at least",
            )?;
        }
        if let Some(c) = t.cutoff_hz {
            in_range(
                "trajectory.cutoff_hz",
                c,
                Range::open_closed(t.line_rate_hz.unwrap_or(0.0), rate / 2.0),
                "Hz",
                "above the line rate, at most the Nyquist frequency of loop.rate_hz",
            )?;
        }
        for (order, key, unit, v) in [
            (1, "trajectory.max_velocity_m_s", "m/s", t.max_velocity_m_s),
            (
                2,
                "trajectory.max_acceleration_m_s2",
                "m/s²",
                t.max_acceleration_m_s2,
            ),
            (3, "trajectory.max_jerk_m_s3", "m/s³", t.max_jerk_m_s3),
            (
                4,
                "trajectory.max_snap_m_s4",
                "m/s⁴",
                t.max_snap_m_s4.and_then(SnapLimit::limit),
            ),
        ] {
            if let Some(v) = v {
                in_range(
                    key,
                    v,
                    Range::open_closed(0.0, trajectory::move_limit_max(order, 2.0 * limit, rate)),
                    unit,
                    "above 0, and at most what crosses the whole stroke (2 safety.position_limit_m) within one tick of loop.rate_hz (the move must then fit a quarter of the line, checked when it is planned)",
                )?;
            }
        }
        if let Some(b) = t.settle_band_m {
            in_range(
                "trajectory.settle_band_m",
                b,
                Range::open(0.0, limit),
                "m",
                "the band a move settles into, inside safety.position_limit_m (and below the move's distance)",
            )?;
        }
        Ok(())
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
