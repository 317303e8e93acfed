//! Bench configuration: one TOML file describes the bench (plant, actuator,
//! probe, stop, safety) and the default job parameters. SI units, with the
//! unit in every key name; unknown keys are errors.
//!
//! Loading is two steps: [`BenchConfig::from_toml`] parses (syntax, types,
//! unknown keys), [`BenchConfig::validate`] checks physics and limits. Both
//! report the dotted key and the reason.

use crate::control::ControllerConfig;
use bench_hal::model::{non_negative, positive, ParamError, Sr4dofParams};
use bench_hal::sim::{ActuatorParams, ProbeParams, SimParams};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Default bench description, relative to the working directory.
pub const DEFAULT_CONFIG: &str = "bench-config/sr4dof-ch5.toml";

/// A configuration problem, with the file and the key.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Syntax, type or unknown-key error (the message names the key).
    #[error("config {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message (line, column, key).
        message: String,
    },
    /// A value that cannot describe a usable bench.
    #[error("config {path}: {key}: {reason}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// Dotted key.
        key: String,
        /// Why.
        reason: String,
    },
}

/// The whole bench description.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BenchConfig {
    /// Free-text description of the bench.
    #[serde(default)]
    pub description: String,
    /// The real-time loop.
    #[serde(rename = "loop")]
    pub loop_: LoopConfig,
    /// The mechanism (SR4DoF lumped model, Eq. 2-5).
    pub plant: Sr4dofParams,
    /// Amplifier and voice coil.
    pub actuator: ActuatorParams,
    /// Position probe.
    pub probe: ProbeParams,
    /// Mechanical limits of the stage.
    pub stage: StageConfig,
    /// Supervisor limits.
    pub safety: SafetyConfig,
    /// Chirp excitation defaults.
    pub chirp: ChirpConfig,
    /// FRF estimation settings.
    #[serde(default)]
    pub identification: IdentificationConfig,
    /// Simulator settings.
    #[serde(default)]
    pub sim: SimConfig,
    /// Feedback controllers by name (`[controller.slow]`, `[controller.fast]`,
    /// any `[controller.NAME]`).
    #[serde(default)]
    pub controller: BTreeMap<String, ControllerConfig>,
    /// Closed-loop step defaults.
    #[serde(default)]
    pub step: StepConfig,
    /// Which hardware runs the jobs (`[backend]`, default: the simulator).
    #[serde(default)]
    pub backend: BackendConfig,
    /// The device emulator of `bench emulate` (`[emulator]`).
    #[serde(default)]
    pub emulator: EmulatorConfig,
    /// `bench serve` (`[daemon]`).
    #[serde(default)]
    pub daemon: DaemonConfig,
}

/// `[daemon]`: what `bench serve` does between jobs.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DaemonConfig {
    /// The controller (a `[controller.NAME]`) that holds the position the
    /// stage is at when the amplifier is enabled between jobs; absent: the
    /// hold job commands 0 A. It must pass the loop check on the model when
    /// the daemon starts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hold_controller: Option<String>,
}

/// Backend kinds (`[backend] kind`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BackendKind {
    /// The simulated plant in-process (`bench_hal::sim`).
    #[default]
    Sim,
    /// A serial DAQ speaking `hal/PROTOCOL.md`.
    Serial,
    /// A CAN analog I/O module on SocketCAN.
    Socketcan,
}

/// `[backend]`: which hardware runs the jobs. `--backend` overrides `kind`
/// and the device.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BackendConfig {
    /// `sim`, `serial` or `socketcan`.
    #[serde(default)]
    pub kind: BackendKind,
    /// `[backend.serial]`: the serial DAQ.
    #[serde(default)]
    pub serial: bench_hal::serial::SerialConfig,
    /// `[backend.can]`: the SocketCAN module and its frame map.
    #[serde(default)]
    pub can: bench_hal::can::CanConfig,
}

/// `[emulator]`: the device side run by `bench emulate`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EmulatorConfig {
    /// Device watchdog: with no valid command for this long while enabled,
    /// the device drops the current to 0 A and latches a fault, ms.
    #[serde(default = "default_watchdog_ms")]
    pub watchdog_ms: f64,
    /// Size of one probe count on the serial link, m.
    #[serde(default = "default_position_lsb_m")]
    pub position_lsb_m: f64,
    /// SCHED_FIFO priority of the emulator's device thread (0: normal
    /// scheduling). Keep it below `[loop] priority`.
    #[serde(default = "default_emulator_priority")]
    pub priority: i32,
}

fn default_watchdog_ms() -> f64 {
    50.0
}
fn default_position_lsb_m() -> f64 {
    1e-10
}
fn default_emulator_priority() -> i32 {
    70
}

impl Default for EmulatorConfig {
    fn default() -> Self {
        Self {
            watchdog_ms: default_watchdog_ms(),
            position_lsb_m: default_position_lsb_m(),
            priority: default_emulator_priority(),
        }
    }
}

/// `[step]`: the closed-loop step experiment of `bench control`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepConfig {
    /// Step size, m.
    #[serde(default = "default_step_m")]
    pub step_m: f64,
    /// Time at the start position before the step, s.
    #[serde(default = "default_settle_s")]
    pub settle_s: f64,
    /// Total run time, s (settle + step + hold).
    #[serde(default = "default_step_duration_s")]
    pub duration_s: f64,
    /// Raised-cosine ramp time of a smoothed step, s (0: a sharp step).
    #[serde(default)]
    pub smooth_s: f64,
    /// Final window for the steady-state error statistics, s.
    #[serde(default = "default_ss_window_s")]
    pub steady_state_window_s: f64,
}

fn default_step_m() -> f64 {
    1e-5
}
fn default_settle_s() -> f64 {
    0.2
}
fn default_step_duration_s() -> f64 {
    4.0
}
fn default_ss_window_s() -> f64 {
    3.0
}

impl Default for StepConfig {
    fn default() -> Self {
        Self {
            step_m: default_step_m(),
            settle_s: default_settle_s(),
            duration_s: default_step_duration_s(),
            smooth_s: 0.0,
            steady_state_window_s: default_ss_window_s(),
        }
    }
}

/// `[loop]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoopConfig {
    /// Loop (sample) rate, Hz.
    pub rate_hz: f64,
    /// CPU to pin the loop thread to in real-time mode (none: no pinning).
    #[serde(default)]
    pub cpu: Option<usize>,
    /// SCHED_FIFO priority in real-time mode (1–99).
    #[serde(default = "default_priority")]
    pub priority: i32,
    /// Interval between `/bench/timing` reports, s.
    #[serde(default = "default_timing_interval")]
    pub timing_interval_s: f64,
}

fn default_priority() -> i32 {
    80
}
fn default_timing_interval() -> f64 {
    1.0
}

impl LoopConfig {
    /// Loop period, ns (rounded to the nearest ns).
    pub fn period_ns(&self) -> u64 {
        (1e9 / self.rate_hz).round() as u64
    }
}

/// `[stage]`
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageConfig {
    /// Mechanical stop on x1: travel is blocked beyond ±this, m.
    pub mechanical_stop_m: f64,
}

/// `[safety]`
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SafetyConfig {
    /// Software position limit on |x1|, m: beyond it the supervisor faults.
    /// Must be inside the mechanical stop and the probe range.
    pub position_limit_m: f64,
    /// Consecutive loop overruns that fault the supervisor (real-time mode).
    #[serde(default = "default_max_overruns")]
    pub max_consecutive_overruns: u32,
    /// Consecutive samples that may be missing (sequence gap) or stale
    /// (sequence not advancing) before the supervisor faults.
    #[serde(default = "default_max_missed")]
    pub max_missed_samples: u32,
    /// Largest plausible change of the probe reading between two ticks, m;
    /// a larger jump faults (a glitch or a lost target, not motion).
    #[serde(default = "default_max_step")]
    pub max_position_step_m: f64,
    /// How long the peak current may flow from cold, s: the I²t budget is
    /// `(I_peak² − I_cont²) · this`; the accumulator integrates
    /// `i² − I_cont²` (never below 0) and faults when it exceeds the budget.
    #[serde(default = "default_i2t_s")]
    pub i2t_peak_duration_s: f64,
    /// Smallest phase margin the loop check accepts, degrees.
    #[serde(default = "default_min_pm")]
    pub min_phase_margin_deg: f64,
    /// Largest peak of |S| the loop check accepts (2.0 = 6 dB, modulus
    /// margin 0.5).
    #[serde(default = "default_max_s")]
    pub max_sensitivity_peak: f64,
}

fn default_max_overruns() -> u32 {
    5
}
fn default_max_missed() -> u32 {
    3
}
fn default_max_step() -> f64 {
    50e-6
}
fn default_i2t_s() -> f64 {
    1.0
}
fn default_min_pm() -> f64 {
    30.0
}
fn default_max_s() -> f64 {
    2.5
}

/// Sweep law of the chirp.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ChirpKind {
    /// Exponential (logarithmic) sweep: equal time per octave.
    Exponential,
    /// Linear sweep: constant df/dt.
    Linear,
}

/// Most breakpoints in `chirp.amplitude_profile`.
pub const MAX_PROFILE_POINTS: usize = 16;

/// `[chirp]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChirpConfig {
    /// Sweep law.
    #[serde(default = "default_kind")]
    pub kind: ChirpKind,
    /// Start frequency, Hz.
    pub f_start_hz: f64,
    /// End frequency, Hz (below the Nyquist frequency).
    pub f_end_hz: f64,
    /// Current amplitude, A (at most the amplifier's peak current).
    pub amplitude_a: f64,
    /// Optional amplitude schedule over the sweep: `[frequency_hz, scale]`
    /// breakpoints, ascending in frequency, scale in (0, 1]; the amplitude at
    /// instantaneous frequency f is `amplitude_a · scale(f)`, interpolated
    /// linearly in log f and held beyond the ends. Use it to pass a lightly
    /// damped resonance gently while keeping the signal-to-noise ratio
    /// elsewhere. Empty: constant amplitude.
    #[serde(default)]
    pub amplitude_profile: Vec<[f64; 2]>,
    /// Sweep duration, s.
    pub duration_s: f64,
    /// Raised-cosine fade-in and fade-out at each end of the sweep, s.
    pub taper_s: f64,
    /// Quiet time before the sweep (probe offset estimate), s.
    pub lead_in_s: f64,
    /// Quiet tail after the sweep for ring-down, s.
    pub tail_s: f64,
}

fn default_kind() -> ChirpKind {
    ChirpKind::Exponential
}

/// `[identification]`
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IdentificationConfig {
    /// Points of the log-spaced output grid per decade.
    #[serde(default = "default_ppd")]
    pub points_per_decade: usize,
    /// Frequency resolution as a fraction of frequency (full width of the
    /// smoothing window): 0.004 = 0.4 % of f.
    #[serde(default = "default_resolution")]
    pub relative_resolution: f64,
    /// Fewest DFT bins averaged at any grid point (sets the resolution where
    /// `relative_resolution · f` is finer than the record allows).
    #[serde(default = "default_min_bins")]
    pub min_bins: usize,
}

fn default_ppd() -> usize {
    400
}
fn default_resolution() -> f64 {
    0.004
}
fn default_min_bins() -> usize {
    5
}

impl Default for IdentificationConfig {
    fn default() -> Self {
        Self {
            points_per_decade: default_ppd(),
            relative_resolution: default_resolution(),
            min_bins: default_min_bins(),
        }
    }
}

/// `[sim]`
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimConfig {
    /// Seed of the simulator's noise generator (default 1, with or without
    /// a `[sim]` table).
    #[serde(default = "default_seed")]
    pub seed: u64,
}

fn default_seed() -> u64 {
    1
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            seed: default_seed(),
        }
    }
}

impl BenchConfig {
    /// Reads and parses a config file (no physical validation).
    ///
    /// # Errors
    /// [`ConfigError::Read`] or [`ConfigError::Parse`].
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_toml(&text, path)
    }

    /// Parses TOML text; `path` is only used in messages.
    ///
    /// # Errors
    /// [`ConfigError::Parse`] naming the key and position.
    pub fn from_toml(text: &str, path: &Path) -> Result<Self, ConfigError> {
        toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.to_path_buf(),
            message: e.to_string().trim_end().replace('\n', " | "),
        })
    }

    /// Checks every value for physical sense and mutual consistency.
    ///
    /// # Errors
    /// [`ConfigError::Invalid`] with the first offending key.
    pub fn validate(&self, path: &Path) -> Result<(), ConfigError> {
        self.check().map_err(|e| ConfigError::Invalid {
            path: path.to_path_buf(),
            key: e.key,
            reason: e.reason,
        })
    }

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
        positive("loop.rate_hz", self.loop_.rate_hz)?;
        if !(100.0..=100_000.0).contains(&self.loop_.rate_hz) {
            return Err(ParamError::new(
                "loop.rate_hz",
                format!("{} Hz is outside 100 Hz … 100 kHz", self.loop_.rate_hz),
            ));
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
        positive("loop.timing_interval_s", self.loop_.timing_interval_s)?;
        self.backend.serial.validate("backend.serial")?;
        self.backend.can.validate("backend.can")?;
        positive("emulator.watchdog_ms", self.emulator.watchdog_ms)?;
        positive("emulator.position_lsb_m", self.emulator.position_lsb_m)?;
        if !(0..=99).contains(&self.emulator.priority) {
            return Err(ParamError::new(
                "emulator.priority",
                format!(
                    "SCHED_FIFO priority must be 0 (none) or 1–99, got {}",
                    self.emulator.priority
                ),
            ));
        }
        self.plant.validate("plant")?;
        self.actuator.validate("actuator")?;
        self.probe.validate("probe")?;
        positive("stage.mechanical_stop_m", self.stage.mechanical_stop_m)?;
        let lim = self.safety.position_limit_m;
        positive("safety.position_limit_m", lim)?;
        if lim >= self.stage.mechanical_stop_m {
            return Err(ParamError::new(
                "safety.position_limit_m",
                format!(
                    "{lim} m must be inside the mechanical stop ({} m)",
                    self.stage.mechanical_stop_m
                ),
            ));
        }
        if lim >= self.probe.range_m {
            return Err(ParamError::new(
                "safety.position_limit_m",
                format!(
                    "{lim} m must be inside the probe range ({} m)",
                    self.probe.range_m
                ),
            ));
        }
        positive(
            "safety.max_position_step_m",
            self.safety.max_position_step_m,
        )?;
        positive(
            "safety.i2t_peak_duration_s",
            self.safety.i2t_peak_duration_s,
        )?;
        positive(
            "safety.min_phase_margin_deg",
            self.safety.min_phase_margin_deg,
        )?;
        positive(
            "safety.max_sensitivity_peak",
            self.safety.max_sensitivity_peak,
        )?;
        if self.safety.max_sensitivity_peak < 1.0 {
            return Err(ParamError::new(
                "safety.max_sensitivity_peak",
                "must be >= 1 (no loop has a sensitivity peak below 1)",
            ));
        }
        if self.safety.max_consecutive_overruns == 0 {
            return Err(ParamError::new(
                "safety.max_consecutive_overruns",
                "must be >= 1",
            ));
        }
        self.check_chirp()?;
        for (name, c) in &self.controller {
            c.validate(&format!("controller.{name}"))
                .map_err(|e| ParamError::new(e.key, e.reason))?;
        }
        let st = &self.step;
        if !st.step_m.is_finite() || st.step_m == 0.0 {
            return Err(ParamError::new(
                "step.step_m",
                format!("must be finite and non-zero, got {}", st.step_m),
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
        positive("step.duration_s", st.duration_s)?;
        non_negative("step.settle_s", st.settle_s)?;
        non_negative("step.smooth_s", st.smooth_s)?;
        if st.settle_s + st.smooth_s >= st.duration_s {
            return Err(ParamError::new(
                "step.duration_s",
                format!(
                    "{} s leaves no time after settle_s + smooth_s = {} s",
                    st.duration_s,
                    st.settle_s + st.smooth_s
                ),
            ));
        }
        positive("step.steady_state_window_s", st.steady_state_window_s)?;
        if st.steady_state_window_s > st.duration_s - st.settle_s - st.smooth_s {
            return Err(ParamError::new(
                "step.steady_state_window_s",
                "must fit after the step (duration_s - settle_s - smooth_s)",
            ));
        }
        let id = &self.identification;
        if id.points_per_decade < 10 || id.points_per_decade > 10_000 {
            return Err(ParamError::new(
                "identification.points_per_decade",
                format!("must be 10–10000, got {}", id.points_per_decade),
            ));
        }
        positive("identification.relative_resolution", id.relative_resolution)?;
        if id.relative_resolution > 0.5 {
            return Err(ParamError::new(
                "identification.relative_resolution",
                "must be <= 0.5 (a fraction of the frequency)",
            ));
        }
        if id.min_bins < 3 {
            return Err(ParamError::new(
                "identification.min_bins",
                "must be >= 3 (coherence needs averaging over bins)",
            ));
        }
        Ok(())
    }

    fn check_chirp(&self) -> Result<(), ParamError> {
        let c = &self.chirp;
        positive("chirp.f_start_hz", c.f_start_hz)?;
        positive("chirp.f_end_hz", c.f_end_hz)?;
        let nyquist = self.loop_.rate_hz / 2.0;
        if c.f_end_hz >= nyquist {
            return Err(ParamError::new(
                "chirp.f_end_hz",
                format!(
                    "{} Hz is at or above the Nyquist frequency {nyquist} Hz of the {} Hz loop",
                    c.f_end_hz, self.loop_.rate_hz
                ),
            ));
        }
        if c.f_start_hz >= c.f_end_hz {
            return Err(ParamError::new(
                "chirp.f_start_hz",
                format!(
                    "{} Hz must be below f_end_hz = {} Hz",
                    c.f_start_hz, c.f_end_hz
                ),
            ));
        }
        positive("chirp.amplitude_a", c.amplitude_a)?;
        if c.amplitude_a > self.actuator.peak_current_a {
            return Err(ParamError::new(
                "chirp.amplitude_a",
                format!(
                    "{} A is above the amplifier's peak current {} A",
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
            positive(&key, *f)?;
            positive(&key, *scale)?;
            if *scale > 1.0 {
                return Err(ParamError::new(
                    key,
                    format!("scale {scale} must be <= 1 (amplitude_a is the largest amplitude)"),
                ));
            }
            if i > 0 && *f <= c.amplitude_profile[i - 1][0] {
                return Err(ParamError::new(
                    key,
                    "frequencies must be strictly ascending",
                ));
            }
        }
        positive("chirp.duration_s", c.duration_s)?;
        if c.duration_s > 3600.0 {
            return Err(ParamError::new(
                "chirp.duration_s",
                "must be at most 3600 s",
            ));
        }
        non_negative("chirp.taper_s", c.taper_s)?;
        if 2.0 * c.taper_s > c.duration_s {
            return Err(ParamError::new(
                "chirp.taper_s",
                format!(
                    "2 × {} s of taper does not fit in duration_s = {} s",
                    c.taper_s, c.duration_s
                ),
            ));
        }
        non_negative("chirp.lead_in_s", c.lead_in_s)?;
        non_negative("chirp.tail_s", c.tail_s)?;
        Ok(())
    }

    /// The simulator's parameters.
    pub fn sim_params(&self, seed: u64) -> SimParams {
        SimParams {
            plant: self.plant,
            actuator: self.actuator,
            probe: self.probe,
            mechanical_stop_m: self.stage.mechanical_stop_m,
            seed,
        }
    }

    /// The supervisor's limits for a configured backend (`info`) at its
    /// period.
    pub fn supervisor(
        &self,
        info: &bench_hal::DeviceInfo,
    ) -> crate::rt::supervisor::SupervisorConfig {
        crate::rt::supervisor::SupervisorConfig {
            position_limit_m: self.safety.position_limit_m,
            peak_current_a: info.peak_current_a,
            max_consecutive_overruns: self.safety.max_consecutive_overruns,
            max_missed_samples: self.safety.max_missed_samples,
            max_position_step_m: self.safety.max_position_step_m,
            continuous_current_a: info.continuous_current_a,
            i2t_peak_duration_s: self.safety.i2t_peak_duration_s,
            period_s: info.period_ns as f64 * 1e-9,
        }
    }

    /// The resolved config as TOML (recorded as MCAP metadata).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_else(|e| format!("# not serialisable: {e}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shipped(name: &str) -> (BenchConfig, PathBuf) {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("bench-config")
            .join(name);
        (BenchConfig::load(&path).unwrap(), path)
    }

    #[test]
    fn shipped_configs_parse_and_validate() {
        for name in ["sr4dof-ch5.toml", "sr4dof-ch2.toml"] {
            let (c, p) = shipped(name);
            c.validate(&p).unwrap();
            // Round trip through the recorded form.
            let again = BenchConfig::from_toml(&c.to_toml(), &p).unwrap();
            assert_eq!(again, c);
        }
    }

    #[test]
    fn ch5_is_the_chapter_5_bench() {
        let (c, _) = shipped("sr4dof-ch5.toml");
        assert!((c.plant.operating_point_m / c.plant.beam.length_m - 0.08).abs() < 1e-12);
        assert!((c.plant.mass_asymmetry - 0.10).abs() < 1e-12);
        // 72 N for 1 mm (§5.1.2).
        assert!((c.plant.k4_n_per_m + c.plant.k5_n_per_m - 72e3).abs() < 1e-9);
        assert!(
            (c.actuator.peak_current_a * c.actuator.force_constant_n_per_a - 111.0).abs() < 0.1
        );
    }

    /// One default seed: no `[sim]` table and a `[sim]` table without
    /// `seed` both give 1.
    #[test]
    fn default_seed_with_and_without_the_sim_table() {
        let (c, p) = shipped("sr4dof-ch5.toml");
        let text = c.to_toml();
        let start = text.find("[sim]").unwrap();
        let end = text[start..]
            .find("\n[")
            .map_or(text.len(), |e| start + e + 1);
        let without_table = format!("{}{}", &text[..start], &text[end..]);
        let without_seed = format!("{}[sim]\n{}", &text[..start], &text[end..]);
        for t in [without_table, without_seed] {
            assert_eq!(BenchConfig::from_toml(&t, &p).unwrap().sim.seed, 1, "{t}");
        }
        assert_eq!(SimConfig::default().seed, 1);
    }

    #[test]
    fn unknown_key_is_named() {
        let (c, p) = shipped("sr4dof-ch5.toml");
        let text = c.to_toml().replace("[plant]", "[plant]\nm6_kg = 1.0");
        let err = BenchConfig::from_toml(&text, &p).unwrap_err().to_string();
        assert!(err.contains("m6_kg"), "{err}");
    }

    #[test]
    fn invalid_values_name_the_key() {
        let (c, p) = shipped("sr4dof-ch5.toml");
        type Mutation = Box<dyn Fn(&mut BenchConfig)>;
        let cases: Vec<(Mutation, &str)> = vec![
            (Box::new(|c| c.plant.m1_kg = 0.0), "plant.m1_kg"),
            (Box::new(|c| c.plant.k5_n_per_m = -3.0), "plant.k5_n_per_m"),
            (Box::new(|c| c.plant.m2_kg = f64::NAN), "plant.m2_kg"),
            (Box::new(|c| c.chirp.f_end_hz = 2500.0), "chirp.f_end_hz"),
            (
                Box::new(|c| c.chirp.amplitude_a = 12.0),
                "chirp.amplitude_a",
            ),
            (
                Box::new(|c| c.safety.position_limit_m = 1.5e-3),
                "safety.position_limit_m",
            ),
            (
                Box::new(|c| c.actuator.continuous_current_a = 20.0),
                "actuator.continuous_current_a",
            ),
        ];
        for (mutate, key) in cases {
            let mut bad = c.clone();
            mutate(&mut bad);
            match bad.validate(&p) {
                Err(ConfigError::Invalid { key: k, .. }) => assert_eq!(k, key),
                other => panic!("{key}: expected Invalid, got {other:?}"),
            }
        }
    }
}
