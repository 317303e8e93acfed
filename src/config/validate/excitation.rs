//! `[chirp]`: the excitation's keys, a sweep's and a multisine's.

use super::*;

impl BenchConfig {
    pub(super) fn check_chirp(&self) -> Result<(), ParamError> {
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
        if self.excitation.kind.is_sweep() {
            self.check_sweep()
        } else {
            self.check_multisine()
        }
    }

    /// A sweep's own keys: `chirp.duration_s` and `chirp.taper_s` present
    /// and in range, no `[multisine]` table.
    pub(super) fn check_sweep(&self) -> Result<(), ParamError> {
        let c = &self.chirp;
        let kind = self.excitation.kind.as_str();
        if self.multisine.is_some() {
            return Err(ParamError::new(
                "multisine",
                format!(
                    "the [multisine] table is set but excitation.kind = \"{kind}\" plays a sweep, which would not use it: set excitation.kind = \"multisine\", or delete the table"
                ),
            ));
        }
        let missing = |key: &str, what: &str| {
            ParamError::new(
                key,
                format!("missing: the sweep (excitation.kind = \"{kind}\") needs its {what}"),
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

    /// `excitation.kind = "multisine"`: no sweep keys, and the `[multisine]`
    /// table (or its defaults) in range: the phases' realizations, the
    /// period against the band's start, at least
    /// [`ranges::MULTISINE_LINES_MIN`] excited lines, the record at most
    /// [`ranges::JOB_TICKS_MAX`] ticks.
    pub(super) fn check_multisine(&self) -> Result<(), ParamError> {
        let c = &self.chirp;
        for (key, set) in [
            ("chirp.duration_s", c.duration_s.is_some()),
            ("chirp.taper_s", c.taper_s.is_some()),
        ] {
            if set {
                return Err(ParamError::new(
                    key,
                    "is a sweep's key and excitation.kind = \"multisine\" would not use it (the record's length is multisine.realizations × (multisine.transient_periods + multisine.periods) × multisine.period_s; a periodic signal has no ends to fade): delete it, or set excitation.kind to a sweep",
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
                "random phases need four realizations at least: the variance over M realizations has 2(M − 1) degrees of freedom, and a fit weighted by fewer than 6 has no finite reference for its cost or its 1σ (Pintelon & Schoukens 2012, §10.3)",
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
