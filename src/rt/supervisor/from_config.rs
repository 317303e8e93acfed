//! The supervisor's settings from the bench's config, on a configured
//! backend (an `impl` of [`crate::config::BenchConfig`]: the config holds
//! the numbers, the rules live here).

/// The supervisor's settings from the bench's config, on a configured
/// backend: the rules here, the numbers there.
impl crate::config::BenchConfig {
    /// The current limits in force on a configured backend (`info`): the
    /// smaller of `[actuator]`'s and the device's, each
    /// ([`crate::rt::supervisor::CurrentLimits::in_force`]).
    pub fn current_limits(
        &self,
        info: &bench_hal::DeviceInfo,
    ) -> crate::rt::supervisor::CurrentLimits {
        crate::rt::supervisor::CurrentLimits::in_force(
            self.actuator.peak_current_a,
            self.actuator.continuous_current_a,
            info,
        )
    }

    /// How far the held current can carry x1 on this bench
    /// ([`crate::rt::supervisor::ReachEnvelope`], the model at `period_s`);
    /// none if the model cannot be built (the config's validation refuses
    /// that before any job).
    pub fn reach_envelope(&self, period_s: f64) -> crate::rt::supervisor::ReachEnvelope {
        match bench_plant::model::Sr4dof::new(self.plant) {
            Ok(m) => crate::rt::supervisor::ReachEnvelope::of(&bench_plant::sim::ZohPlant::new(
                &m,
                &self.actuator,
                period_s,
            )),
            Err(_) => crate::rt::supervisor::ReachEnvelope::NONE,
        }
    }

    /// The dead-probe rules for a configured backend (`info`) at
    /// `period_s`, with a coil of continuous rating `continuous_current_a`:
    /// the probe's noise and quantisation (`[probe]`) with the link's count
    /// ([`bench_hal::DeviceInfo::probe_lsb_m`]), and the model's
    /// quasi-static compliance G(0) and lowest mode
    /// ([`crate::rt::supervisor::ProbeValidity::derive`]). Without a model
    /// (refused by validation before any job), the plausibility rule is
    /// off.
    pub fn probe_validity(
        &self,
        info: &bench_hal::DeviceInfo,
        continuous_current_a: f64,
    ) -> crate::rt::supervisor::ProbeValidity {
        let period_s = info.period_ns as f64 * 1e-9;
        let (dc_gain, lowest_hz) = match bench_plant::model::Sr4dof::new(self.plant) {
            Ok(m) => (
                bench_plant::sim::ZohPlant::new(&m, &self.actuator, period_s)
                    .frf_continuous(0.0)
                    .re,
                m.modes()
                    .iter()
                    .map(|m| m.frequency_hz())
                    .fold(f64::INFINITY, f64::min),
            ),
            Err(_) => (f64::NAN, f64::NAN),
        };
        crate::rt::supervisor::ProbeValidity::derive(
            self.probe.noise_rms_m,
            self.probe.quantization_m + info.probe_lsb_m,
            dc_gain,
            lowest_hz,
            continuous_current_a,
            period_s,
        )
    }

    /// The supervisor's limits for a configured backend (`info`) at its
    /// period; the currents are [`Self::current_limits`].
    pub fn supervisor(
        &self,
        info: &bench_hal::DeviceInfo,
    ) -> crate::rt::supervisor::SupervisorConfig {
        let currents = self.current_limits(info);
        crate::rt::supervisor::SupervisorConfig {
            position_limit_m: self.safety.position_limit_m,
            peak_current_a: currents.peak_current_a,
            max_missed_deadlines: self.safety.max_overrun_s.map_or(u64::MAX, |b| {
                crate::rt::supervisor::whole_periods(b, info.period_ns as f64 * 1e-9)
            }),
            max_missed_samples: self.safety.max_missed_samples,
            max_position_step_m: self.safety.max_position_step_m,
            max_late_commands: self.safety.max_command_latency_s.map_or(u64::MAX, |b| {
                crate::rt::supervisor::whole_periods(b, info.period_ns as f64 * 1e-9)
            }),
            continuous_current_a: currents.continuous_current_a,
            reach: self.reach_envelope(info.period_ns as f64 * 1e-9),
            watchdog_s: info.watchdog_s,
            i2t_peak_duration_s: self.safety.i2t_peak_duration_s,
            period_s: info.period_ns as f64 * 1e-9,
            probe: self.probe_validity(info, currents.continuous_current_a),
        }
    }
}
