//! The current limits in force: the host's `[actuator]` limits against what
//! the device announces, the smaller of each, range-checked at the
//! handshake (README, *Safety: limits and stalls*).

/// Where a current limit in force came from ([`CurrentLimits`]).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum LimitSource {
    /// The host's config (`[actuator]`): the smaller, or equal.
    HostConfig,
    /// The device's announcement (serial hello, `[backend.can]`): smaller
    /// than the host's.
    Device,
}

impl LimitSource {
    /// As the summary names it.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::HostConfig => "host config",
            Self::Device => "device",
        }
    }
}

/// The current limits in force for a run: each the smaller of the host's
/// config (`actuator.peak_current_a`, `actuator.continuous_current_a`) and
/// what the device announced ([`bench_hal::DeviceInfo`]), so a device can
/// lower the host's limits and never raise them. The supervisor clips
/// commands to `peak_current_a`, the I²t protection and the controllers'
/// anti-windup use these values, and the summary and the recording
/// (`bench.run` metadata `current_limits`) state them with their sources.
#[derive(
    Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema,
)]
pub struct CurrentLimits {
    /// Peak current in force, A.
    pub peak_current_a: f64,
    /// Where it came from.
    pub peak_from: LimitSource,
    /// Continuous current rating in force (I²t), A.
    pub continuous_current_a: f64,
    /// Where it came from.
    pub continuous_from: LimitSource,
    /// The host's `actuator.peak_current_a`, A.
    pub host_peak_current_a: f64,
    /// The host's `actuator.continuous_current_a`, A.
    pub host_continuous_current_a: f64,
    /// The device's announced peak current, A.
    pub device_peak_current_a: f64,
    /// The device's announced continuous current, A.
    pub device_continuous_current_a: f64,
}

impl CurrentLimits {
    /// The smaller of the host's and the device's, each; the device's
    /// values must have passed [`check_announced`] (NaN never wins a
    /// comparison here: a NaN announcement is refused before).
    pub fn in_force(
        host_peak_a: f64,
        host_continuous_a: f64,
        device: &bench_hal::DeviceInfo,
    ) -> Self {
        let pick = |host: f64, dev: f64| {
            if dev < host {
                (dev, LimitSource::Device)
            } else {
                (host, LimitSource::HostConfig)
            }
        };
        let (peak, peak_from) = pick(host_peak_a, device.peak_current_a);
        let (cont, continuous_from) = pick(host_continuous_a, device.continuous_current_a);
        Self {
            peak_current_a: peak,
            peak_from,
            continuous_current_a: cont,
            continuous_from,
            host_peak_current_a: host_peak_a,
            host_continuous_current_a: host_continuous_a,
            device_peak_current_a: device.peak_current_a,
            device_continuous_current_a: device.continuous_current_a,
        }
    }

    /// One line for the summary: `peak 1 A (host config; device 9.98 A),
    /// continuous 0.5 A (host config; device 2.34 A)`.
    pub fn line(&self) -> String {
        format!(
            "current limits: peak {} A ({}; host {} A, device {} A), continuous {} A ({}; host {} A, device {} A)",
            self.peak_current_a,
            self.peak_from.as_str(),
            self.host_peak_current_a,
            self.device_peak_current_a,
            self.continuous_current_a,
            self.continuous_from.as_str(),
            self.host_continuous_current_a,
            self.device_continuous_current_a,
        )
    }
}

/// The largest current a device may announce, A
/// ([`crate::config::limits::PEAK_CURRENT_MAX_A`]: twice the thesis coil's
/// peak).
pub const ANNOUNCED_CURRENT_MAX_A: f64 = crate::config::limits::PEAK_CURRENT_MAX_A;

/// Checks what a device announced at its handshake (serial hello, the CAN
/// device's `[backend.can]` ratings) against the physical ranges: peak and
/// continuous current finite, positive, at most
/// [`ANNOUNCED_CURRENT_MAX_A`], continuous at most peak; probe range
/// finite, positive, at most 10 mm. A device outside them is refused before
/// anything is enabled.
///
/// # Errors
/// The values named, with the range each broke.
pub fn check_announced(device: &bench_hal::DeviceInfo) -> Result<(), String> {
    let mut bad = Vec::new();
    for (name, v) in [
        ("peak current", device.peak_current_a),
        ("continuous current", device.continuous_current_a),
    ] {
        if !(v.is_finite() && v > 0.0 && v <= ANNOUNCED_CURRENT_MAX_A) {
            bad.push(format!(
                "{name} {v:e} A is outside (0, {ANNOUNCED_CURRENT_MAX_A}] A"
            ));
        }
    }
    if bad.is_empty() && device.continuous_current_a > device.peak_current_a {
        bad.push(format!(
            "continuous current {} A is above its peak current {} A",
            device.continuous_current_a, device.peak_current_a
        ));
    }
    let r = device.probe_range_m;
    if !(r.is_finite() && r > 0.0 && r <= 1e-2) {
        bad.push(format!("probe range {r:e} m is outside (0, 0.01] m"));
    }
    if bad.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "the device {} announced values outside their physical ranges: {}",
            device.name,
            bad.join("; ")
        ))
    }
}
