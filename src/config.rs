//! Bench configuration: one TOML file describes the bench (plant, actuator,
//! probe, stop, safety) and the default job parameters. SI units, with the
//! unit in every key name; unknown keys are errors.
//!
//! Loading is two steps: [`BenchConfig::from_toml`] parses (syntax, types,
//! unknown keys), [`BenchConfig::validate`] checks physics and limits. Both
//! report the dotted key and the reason.

use crate::control::ControllerConfig;
use bench_hal::model::{non_negative, ParamError, Sr4dofParams};
use bench_hal::sim::{ActuatorParams, ProbeParams, SimParams};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Largest config file `bench` reads, bytes (1 MiB; the shipped ones are
/// about 8 KiB).
pub const MAX_CONFIG_BYTES: u64 = 1 << 20;

/// The shipped bench description in the repository (the Chapter 5 bench),
/// relative to the repository root. `bench` does not read it at run time:
/// its text is built in ([`BUILTIN_CONFIG_TOML`]).
pub const DEFAULT_CONFIG: &str = "bench-config/sr4dof-ch5.toml";

/// The built-in bench description: the text of
/// `bench-config/sr4dof-ch5.toml` (the Chapter 5/6 bench of the thesis,
/// Fig 5-9: +10 % mass asymmetry, Y1o = 8 % of L), compiled into the
/// binary. It applies when no `--config` is given, so an installed `bench`
/// runs from any directory; `bench config default` prints it.
pub const BUILTIN_CONFIG_TOML: &str = include_str!("../bench-config/sr4dof-ch5.toml");

/// How messages, summaries and recordings (`bench.config` metadata `path`)
/// name the built-in config.
pub const BUILTIN_CONFIG_NAME: &str = "built-in (sr4dof-ch5)";

/// A hint for a value that looks given in the wrong unit: a mass asymmetry
/// in percent (`10` for 10 %: `0.10` is meant; magnitudes of 1 or more,
/// i.e. at least 100 % as a fraction) or an operating point in
/// millimetres (`3` for 3 mm: `0.003` is meant). `None` unless the value is
/// outside the key's range ([`bench_hal::model::ranges`]) and the rescaled
/// one is inside it. `beam_length_m` bounds the operating point.
#[must_use]
pub fn unit_hint(key: &str, value: f64, beam_length_m: f64) -> Option<String> {
    use bench_hal::model::ranges;
    if !value.is_finite() {
        return None;
    }
    match key {
        "plant.mass_asymmetry" => {
            let (lo, hi) = ranges::MASS_ASYMMETRY;
            let inside = |x: f64| (lo..=hi).contains(&x);
            (value.abs() >= 1.0 && !inside(value) && inside(value / 100.0)).then(|| {
                format!(
                    "Δm23 is a fraction, 0.10 = 10 %: for {value} % give {}",
                    value / 100.0
                )
            })
        }
        "plant.operating_point_m" => {
            let max = ranges::OPERATING_POINT_OF_L * beam_length_m;
            (value.abs() > max && (value / 1000.0).abs() <= max).then(|| {
                format!(
                    "the operating point is in metres: {value} mm = {} m",
                    value / 1000.0
                )
            })
        }
        _ => None,
    }
}

/// The bounds of the safety keys (`[safety]`, `[actuator]`, `[emulator]`
/// and the link timeouts of `[backend]`), with why each is where it is.
/// [`BenchConfig::check`] refuses a value outside its range, naming the key;
/// the README's configuration reference and the comments in
/// `bench-config/*.toml` give the same ranges.
pub mod limits {
    /// Largest `[emulator] watchdog_ms`, ms: a host that dies leaves the
    /// current flowing at most this long (plus one period).
    pub const WATCHDOG_MAX_MS: f64 = 1000.0;
    /// Smallest `[emulator] watchdog_ms`, ms (the serial hello announces it
    /// in whole ms). It must also cover two loop periods.
    pub const WATCHDOG_MIN_MS: f64 = 1.0;
    /// Largest peak current (`actuator.peak_current_a`,
    /// `backend.can.peak_current_a`), A: twice the rated peak of the bench's
    /// coil (LA24-20-000A: 111 N at 11.12 N/A = 9.98 A, thesis §5.1.2), room
    /// for another coil of this size, but not for a value no amplifier of
    /// this bench delivers (the supervisor clips commands to it, the I²t
    /// budget grows with its square).
    pub const PEAK_CURRENT_MAX_A: f64 = 20.0;
    /// Smallest ratio of `actuator.peak_current_a` to
    /// `actuator.continuous_current_a`: 1.25. The I²t budget is
    /// `(I_peak² − I_cont²) · t_peak`; at a ratio of 1 it is zero and the
    /// protection can never trip (no current above the peak flows, and the
    /// accumulator only grows above the continuous rating), so the
    /// protection would be configured off. At 1.25 the budget is at least
    /// `0.56 · I_cont² · t_peak`. Coils are rated with a peak 3–5 times the
    /// continuous current (LA24-20-000A: 4.3).
    pub const PEAK_TO_CONTINUOUS_MIN: f64 = 1.25;
    /// The X travel of stage 1 on the thesis bench, m: ±1 mm, a factor of
    /// two against yielding, with a mechanical stop there (§5.1.2); the
    /// probe reads ±1 mm too. `safety.position_limit_m` is below it.
    pub const STROKE_M: f64 = 1.0e-3;
    /// Smallest `safety.position_limit_m`, m: well above the probe's noise
    /// (40 nm RMS, 400 nm peak to peak).
    pub const POSITION_LIMIT_MIN_M: f64 = 1.0e-6;
    /// Smallest `safety.max_position_step_m`, m: 25 × the probe's RMS noise,
    /// so noise alone never trips the jump check.
    pub const POSITION_STEP_MIN_M: f64 = 1.0e-6;
    /// Fastest plausible motion of stage 1, m/s: within its ±1 mm it cannot
    /// exceed about 0.5 m/s (the peak force, 111 N, on the 2.1 kg moving
    /// mass across the whole stroke; or a full 1 mm swing at the 80 Hz
    /// modes); twice that. `safety.max_position_step_m` is at most this
    /// times one loop period (200 µm at 5 kHz).
    pub const STAGE_SPEED_MAX_M_PER_S: f64 = 1.0;
    /// Longest time the loop may run late or without a sample before the
    /// supervisor faults, s: `safety.max_overrun_s`,
    /// `safety.max_command_latency_s` and `safety.max_missed_samples` (in
    /// ticks: 500 at 5 kHz) are at most this. At the peak force the stage crosses its stroke in
    /// well under this, so a larger count protects nothing.
    pub const BLIND_MAX_S: f64 = 0.1;
    /// Longest time from the last sample to the link fault when every read
    /// times out, s: `(safety.max_missed_samples + 1)` × the sample timeout
    /// is at most this, as long as the longest device watchdog.
    pub const LINK_FAULT_MAX_S: f64 = 1.0;
    /// Longest wait for one sample (`[backend.serial]
    /// sample_timeout_periods` × period, `[backend.can] sample_timeout_ms`),
    /// s. The tests on a loaded 2-core VM need 40 ms; USB bursts are a few
    /// ms.
    pub const SAMPLE_TIMEOUT_MAX_S: f64 = 0.2;
    /// Shortest `[backend.can] sample_timeout_ms`, ms: about one CAN frame
    /// at 1 Mbit/s.
    pub const CAN_SAMPLE_TIMEOUT_MIN_MS: f64 = 0.1;
    /// `[backend.serial] handshake_timeout_ms` range, ms: long enough for a
    /// USB device to answer, short enough that a silent device cannot hold
    /// the disable (which waits for its acknowledgement) for more than
    /// 10 s.
    pub const HANDSHAKE_TIMEOUT_MS: (f64, f64) = (1.0, 10_000.0);
    /// `safety.i2t_peak_duration_s` range, s: a coil's peak rating holds for
    /// seconds (the shipped 1 s), not minutes; below 10 ms the budget is
    /// spent in a few ticks.
    pub const I2T_PEAK_DURATION_S: (f64, f64) = (0.01, 10.0);
    /// `safety.min_phase_margin_deg` range, degrees: `[20, 90)`. Below 20°
    /// a loop rings badly and a small plant change destabilises it; 90° and
    /// above no useful loop reaches.
    pub const MIN_PHASE_MARGIN_DEG: (f64, f64) = (20.0, 90.0);
    /// Largest `safety.max_sensitivity_peak` (‖S‖∞): 6 (15.6 dB), a modulus
    /// margin of 0.17. It must be above 1, which no loop beats.
    pub const MAX_SENSITIVITY_PEAK: f64 = 6.0;
    /// Largest `[emulator] position_lsb_m`, m: 1 µm, the smallest jump the
    /// supervisor looks for. The smallest is `probe.range_m / (2³¹ − 1)`.
    pub const POSITION_LSB_MAX_M: f64 = 1.0e-6;
}

/// The bounds of the other numeric keys: what a flexure stage on a lab
/// bench, its amplifier, probe and jobs can be, with room around the
/// thesis' benches (the model's own ranges are in
/// [`bench_hal::model::ranges`]). The README's configuration reference and
/// the comments in `bench-config/*.toml` give the same ranges.
pub mod ranges {
    /// `loop.rate_hz`, Hz.
    pub const RATE_HZ: (f64, f64) = (100.0, 100_000.0);
    /// `loop.timing_interval_s`, s.
    pub const TIMING_INTERVAL_S: (f64, f64) = (0.01, 60.0);
    /// `loop.cpu` is below this (the kernel's `CPU_SETSIZE`) and below the
    /// number of CPUs online.
    pub const CPU_SETSIZE: usize = 1024;
    /// `actuator.force_constant_n_per_a`, N/A: voice coils are 1–100 N/A.
    pub const FORCE_CONSTANT_N_PER_A: (f64, f64) = (0.01, 1000.0);
    /// `actuator.bandwidth_hz`, Hz: current loops of linear amplifiers.
    pub const AMPLIFIER_BANDWIDTH_HZ: (f64, f64) = (10.0, 100_000.0);
    /// `probe.range_m` and `stage.mechanical_stop_m`, m: 10 µm to 10 mm.
    pub const TRAVEL_M: (f64, f64) = (1e-5, 1e-2);
    /// `probe.noise_rms_m` and `probe.quantization_m`, m: 0 to 1 µm (the
    /// smallest jump the supervisor looks for), and below `probe.range_m`.
    pub const PROBE_RESOLUTION_M: (f64, f64) = (0.0, 1e-6);
    /// `[backend.serial] baud`, Bd.
    pub const BAUD: (u32, u32) = (50, 20_000_000);
    /// Lowest chirp frequency (`chirp.f_start_hz`, the profile's
    /// breakpoints), Hz; the highest is below Nyquist.
    pub const CHIRP_F_MIN_HZ: f64 = 0.01;
    /// Smallest `chirp.amplitude_a`, A (0.1 mA); the largest is
    /// `actuator.peak_current_a`.
    pub const CHIRP_AMPLITUDE_MIN_A: f64 = 1e-4;
    /// Scale of an `chirp.amplitude_profile` breakpoint.
    pub const PROFILE_SCALE: (f64, f64) = (1e-3, 1.0);
    /// `chirp.duration_s`, s: 0.1 s to 10 minutes.
    pub const CHIRP_DURATION_S: (f64, f64) = (0.1, 600.0);
    /// `chirp.lead_in_s`, `chirp.tail_s`, s: at most a minute each.
    pub const CHIRP_QUIET_MAX_S: f64 = 60.0;
    /// `step.duration_s`, s: at most an hour.
    pub const STEP_DURATION_MAX_S: f64 = 3600.0;
    /// `step.settle_s`, `step.smooth_s`, s: at most a minute each.
    pub const STEP_PHASE_MAX_S: f64 = 60.0;
    /// Smallest `|step.step_m|`, m (1 nm); the largest is below
    /// `safety.position_limit_m`.
    pub const STEP_MIN_M: f64 = 1e-9;
    /// Smallest `step.steady_state_window_s`, s.
    pub const STEADY_STATE_WINDOW_MIN_S: f64 = 1e-3;
    /// Most ticks of one job (a chirp's lead-in + sweep + tail, a step's
    /// duration) at the loop rate: 2²⁵ (1.9 h at 5 kHz, 5.6 min at
    /// 100 kHz), so that the job's record fits in memory.
    pub const JOB_TICKS_MAX: u64 = 1 << 25;
    /// `identification.points_per_decade`, at most; also at most
    /// [`points_per_decade_max`] for the relative resolution.
    pub const POINTS_PER_DECADE: (usize, usize) = (10, 10_000);
    /// Grid points per smoothing window, at most: a handful draw the
    /// smoothed curve (its narrowest feature is the window); ten leave a
    /// margin for the plots, more add post-processing time and file size,
    /// not detail.
    pub const POINTS_PER_WINDOW: f64 = 10.0;

    /// The densest meaningful FRF grid, points per decade, for the
    /// smoothing window's full width `relative_resolution × f`:
    /// [`POINTS_PER_WINDOW`] points per window, `10 ln(10) /
    /// relative_resolution` rounded down (5756 at the default 0.4 %), and
    /// at most [`POINTS_PER_DECADE`]'s 10 000 (from 0.23 % down). A window is also at least
    /// `min_bins` DFT bins wide, so this is never finer than the record's
    /// DFT resolution allows either.
    pub fn points_per_decade_max(relative_resolution: f64) -> usize {
        // Rounded down (a product on the bound by 1e-12 is on it).
        let most = (POINTS_PER_WINDOW * std::f64::consts::LN_10 / relative_resolution
            * (1.0 + 1e-12))
            .floor();
        if most.is_finite() && most < POINTS_PER_DECADE.1 as f64 {
            most as usize
        } else {
            POINTS_PER_DECADE.1
        }
    }
    /// `identification.relative_resolution`.
    pub const RELATIVE_RESOLUTION: (f64, f64) = (1e-4, 0.5);
    /// `identification.min_bins`.
    pub const MIN_BINS: (usize, usize) = (3, 1000);
}

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
    /// Not a config file: not a regular file (a FIFO, a device, a
    /// directory), or larger than [`MAX_CONFIG_BYTES`].
    #[error("--config {path}: {reason}")]
    NotAConfigFile {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
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
    /// Amplifier and voice coil. Safety ranges: `peak_current_a` in
    /// (0, [`limits::PEAK_CURRENT_MAX_A`]] (20 A, twice the coil's rated
    /// 9.98 A peak: the supervisor clips every command to it and the I²t
    /// budget grows with its square), `continuous_current_a` in
    /// (0, `peak_current_a`].
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
    /// Its link timeouts and the CAN device's current ratings have safety
    /// ranges (see [`BackendConfig`]).
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
    /// `[backend.serial]`: the serial DAQ. Safety ranges:
    /// `sample_timeout_periods` in [1, 1000] periods and at most
    /// [`limits::SAMPLE_TIMEOUT_MAX_S`] (200 ms) at the loop rate;
    /// `handshake_timeout_ms` in [`limits::HANDSHAKE_TIMEOUT_MS`]
    /// (1 ms … 10 s); and `(safety.max_missed_samples + 1)` sample timeouts
    /// at most [`limits::LINK_FAULT_MAX_S`] (1 s).
    #[serde(default)]
    pub serial: bench_hal::serial::SerialConfig,
    /// `[backend.can]`: the SocketCAN module and its frame map. Safety
    /// ranges: `sample_timeout_ms` in [0.1, 200] ms (and the same 1 s to the
    /// link fault as the serial link), `peak_current_a` in (0, 20] A and
    /// `continuous_current_a` in (0, `peak_current_a`], as for
    /// `[actuator]`.
    #[serde(default)]
    pub can: bench_hal::can::CanConfig,
}

/// `[emulator]`: the device side run by `bench emulate`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EmulatorConfig {
    /// Device watchdog: with no valid command for this long while enabled,
    /// the device drops the current to 0 A and latches a fault, ms.
    /// Range: at least 1 ms and two loop periods (commands come once a
    /// period), at most [`limits::WATCHDOG_MAX_MS`] (1 s: a dead host must
    /// not leave current flowing longer).
    #[serde(default = "default_watchdog_ms")]
    pub watchdog_ms: f64,
    /// Size of one probe count on the serial link, m. Range:
    /// `probe.range_m / (2³¹ − 1)` (the whole probe range fits the 32-bit
    /// count) to [`limits::POSITION_LSB_MAX_M`] (1 µm: a coarser count would
    /// hide motion the position limit and jump checks must see).
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

/// `[safety]`. Every key has a range (below, and in the README's
/// configuration reference); a value outside it is refused naming the key,
/// so no config can switch a protection off.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SafetyConfig {
    /// Software position limit on |x1|, m: beyond it the supervisor faults.
    /// Range: [`limits::POSITION_LIMIT_MIN_M`] (1 µm, well above the probe's
    /// 40 nm RMS noise) up to, not including, [`limits::STROKE_M`] (the
    /// ±1 mm X travel of the thesis bench, §5.1.2), and inside
    /// `stage.mechanical_stop_m` and `probe.range_m`.
    pub position_limit_m: f64,
    /// Optional upper limit on how long the real-time loop may run behind
    /// its deadlines in a closed-loop job, s (whole periods tolerated, so a
    /// stall is judged the same at any `loop.rate_hz`). Absent (the
    /// default): the bound comes from the loop itself, the smaller of its
    /// delay margin and the time the held peak current takes to reach the
    /// position limit ([`crate::control::loop_check::StallLimit`]). Set,
    /// it may only tighten that bound (a value above it is refused by the
    /// loop check with both numbers) and it applies to every job, open-loop
    /// identification included. Open-loop jobs without it never stop on a
    /// stall: the stall is recorded and its span left out of the FRF.
    /// Between jobs at 0 A stalls are reported, never latched. Range:
    /// above 0 and at most [`limits::BLIND_MAX_S`] (0.1 s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_overrun_s: Option<f64>,
    /// The tick count that `max_overrun_s` replaced; refused with a hint
    /// (never written).
    #[serde(default, skip_serializing)]
    pub max_consecutive_overruns: Option<serde::de::IgnoredAny>,
    /// Consecutive samples that may be missing (sequence gap, timeout,
    /// corrupt frames) or stale (sequence not advancing) before the
    /// supervisor faults (K). Range: 0 (every missing sample faults) to the
    /// ticks of [`limits::BLIND_MAX_S`] (0.1 s; 500 at 5 kHz), and K + 1
    /// sample timeouts (`[backend.serial] sample_timeout_periods`,
    /// `[backend.can] sample_timeout_ms`) at most
    /// [`limits::LINK_FAULT_MAX_S`] (1 s, the longest device watchdog).
    #[serde(default = "default_max_missed")]
    pub max_missed_samples: u32,
    /// Largest plausible change of the probe reading between two ticks, m;
    /// a larger jump faults (a glitch or a lost target, not motion).
    /// Range: [`limits::POSITION_STEP_MIN_M`] (1 µm, 25 × the probe's RMS
    /// noise) to [`limits::STAGE_SPEED_MAX_M_PER_S`] × one period (1 m/s,
    /// twice what the peak force can reach over the 2 mm stroke; 200 µm at
    /// 5 kHz), and below `position_limit_m`.
    #[serde(default = "default_max_step")]
    pub max_position_step_m: f64,
    /// Optional upper limit on how long the device may run on commands
    /// that do not answer its previous sample (a late link), s: the device
    /// flags each such sample ([`bench_hal::SampleFlags::command_late`]),
    /// and in a closed-loop job more than the bound of them in a row is the
    /// `link_latency` fault (whole periods tolerated). Absent (the
    /// default): the loop's own stall bound, as for `max_overrun_s`; set,
    /// it may only tighten it (above it: refused with both numbers) and
    /// applies to every job. Range: above 0 and at most
    /// [`limits::BLIND_MAX_S`] (0.1 s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_command_latency_s: Option<f64>,
    /// How long the peak current may flow from cold, s: the I²t budget is
    /// `(I_peak² − I_cont²) · this`; the accumulator integrates
    /// `i² − I_cont²` (never below 0) and faults when it exceeds the budget.
    /// Range: [`limits::I2T_PEAK_DURATION_S`] (10 ms to 10 s: a coil's peak
    /// rating is a rating for seconds, not minutes).
    #[serde(default = "default_i2t_s")]
    pub i2t_peak_duration_s: f64,
    /// Smallest phase margin the loop check accepts, degrees. Range:
    /// [`limits::MIN_PHASE_MARGIN_DEG`] (20° up to, not including, 90°:
    /// below 20° a loop rings and small plant changes destabilise it).
    #[serde(default = "default_min_pm")]
    pub min_phase_margin_deg: f64,
    /// Largest peak of |S| the loop check accepts (2.0 = 6 dB, modulus
    /// margin 0.5). Range: above 1 (no loop does better) up to
    /// [`limits::MAX_SENSITIVITY_PEAK`] (6, modulus margin 0.17).
    #[serde(default = "default_max_s")]
    pub max_sensitivity_peak: f64,
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
        use std::io::Read;
        use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
        let read_err = |source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        };
        let not_config = |reason: String| ConfigError::NotAConfigFile {
            path: path.to_path_buf(),
            reason,
        };
        // Non-blocking, so that opening a FIFO does not wait for a writer;
        // nothing is read before the type and size are known.
        let file = std::fs::OpenOptions::new()
            .read(true)
            .custom_flags(libc::O_NONBLOCK)
            .open(path)
            .map_err(read_err)?;
        let meta = file.metadata().map_err(read_err)?;
        let t = meta.file_type();
        if !t.is_file() {
            let kind = if t.is_dir() {
                "a directory"
            } else if t.is_fifo() {
                "a FIFO"
            } else if t.is_char_device() {
                "a character device"
            } else if t.is_block_device() {
                "a block device"
            } else if t.is_socket() {
                "a socket"
            } else {
                "not a regular file"
            };
            return Err(not_config(format!(
                "{kind}: a config must be a regular TOML file"
            )));
        }
        let too_large = || {
            not_config(format!(
                "larger than {MAX_CONFIG_BYTES} bytes (1 MiB): not a bench description"
            ))
        };
        if meta.len() > MAX_CONFIG_BYTES {
            return Err(too_large());
        }
        let mut bytes = Vec::new();
        file.take(MAX_CONFIG_BYTES + 1)
            .read_to_end(&mut bytes)
            .map_err(read_err)?;
        if bytes.len() as u64 > MAX_CONFIG_BYTES {
            return Err(too_large());
        }
        let text = String::from_utf8(bytes)
            .map_err(|e| read_err(std::io::Error::new(std::io::ErrorKind::InvalidData, e)))?;
        Self::from_toml(&text, path)
    }

    /// Parses TOML text; `path` is only used in messages.
    ///
    /// # Errors
    /// [`ConfigError::Parse`] naming the key and position, with the
    /// parser's multi-line display (the line and a caret under the
    /// offending span).
    pub fn from_toml(text: &str, path: &Path) -> Result<Self, ConfigError> {
        toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.to_path_buf(),
            message: toml_error_message(text, &e),
        })
    }

    /// The built-in bench ([`BUILTIN_CONFIG_TOML`]), parsed (no physical
    /// validation, as [`Self::load`]).
    ///
    /// # Errors
    /// [`ConfigError::Parse`] (never for the shipped text: a unit test
    /// parses and validates it).
    pub fn builtin() -> Result<Self, ConfigError> {
        Self::from_toml(BUILTIN_CONFIG_TOML, Path::new(BUILTIN_CONFIG_NAME))
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
        let (lo, hi) = ranges::RATE_HZ;
        in_range(
            "loop.rate_hz",
            self.loop_.rate_hz,
            Range::closed(lo, hi),
            "Hz",
            "100 Hz to 100 kHz",
        )?;
        if let Some(cpu) = self.loop_.cpu {
            let online = online_cpus();
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
        let (lo, hi) = ranges::CHIRP_DURATION_S;
        in_range(
            "chirp.duration_s",
            c.duration_s,
            Range::closed(lo, hi),
            "s",
            "0.1 s to 10 minutes",
        )?;
        non_negative("chirp.taper_s", c.taper_s)?;
        if 2.0 * c.taper_s > c.duration_s {
            return Err(ParamError::new(
                "chirp.taper_s",
                format!(
                    "2 × {} s of taper does not fit in chirp.duration_s = {} s",
                    c.taper_s, c.duration_s
                ),
            ));
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
        self.check_job_ticks("chirp.duration_s", c.lead_in_s + c.duration_s + c.tail_s)?;
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
        match bench_hal::model::Sr4dof::new(self.plant) {
            Ok(m) => crate::rt::supervisor::ReachEnvelope::of(&bench_hal::sim::ZohPlant::new(
                &m,
                &self.actuator,
                period_s,
            )),
            Err(_) => crate::rt::supervisor::ReachEnvelope::NONE,
        }
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
        }
    }

    /// The resolved config as TOML (recorded as MCAP metadata).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_else(|e| format!("# not serialisable: {e}"))
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
fn key_path_at(text: &str, span: std::ops::Range<usize>) -> Option<String> {
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

/// The CPUs online (at least 1).
fn online_cpus() -> usize {
    // SAFETY: sysconf has no preconditions.
    let n = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) };
    usize::try_from(n).unwrap_or(1).max(1)
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
    fn the_builtin_config_is_the_shipped_chapter_5_file() {
        let (c, p) = shipped("sr4dof-ch5.toml");
        let text = std::fs::read_to_string(&p).unwrap();
        assert_eq!(BUILTIN_CONFIG_TOML, text);
        let b = BenchConfig::builtin().unwrap();
        b.validate(Path::new(BUILTIN_CONFIG_NAME)).unwrap();
        assert_eq!(b, c);
    }

    #[test]
    fn a_toml_error_keeps_its_caret_display_and_names_the_file() {
        let e = BenchConfig::from_toml("[loop]\nrate_hz = \"fast\"\n", Path::new("my.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("config my.toml: "), "{e}");
        // Multi-line, not joined into one line (the caret display itself
        // draws its gutter with " | ").
        assert!(e.lines().count() >= 4, "{e}");
        // The offending line, and a caret line under it.
        let lines: Vec<&str> = e.lines().collect();
        assert!(
            lines.iter().any(|l| l.contains("rate_hz = \"fast\"")),
            "{e}"
        );
        assert!(
            lines.iter().any(|l| l
                .trim_start()
                .trim_start_matches('|')
                .trim()
                .starts_with('^')),
            "{e}"
        );
    }

    #[test]
    fn a_toml_error_names_its_key_path_array_elements_included() {
        // The span of the offending value `"a"` → its key path.
        for (text, key) in [
            ("[loop]\nrate_hz = \"a\"\n", "loop.rate_hz"),
            (
                "[chirp]\nx = [\n  [1.0, 2.0],\n  [3.0, \"a\"],\n]\n",
                "chirp.x[1][1]",
            ),
            ("[c.f]\np = [\n  1.0,\n  \"a\",\n]\n", "c.f.p[1]"),
            ("[c]\nz = [{ w = 1.0 }, { w = \"a\" }]\n", "c.z[1].w"),
            ("t = { u = [0, [1, \"a\"]] }\n", "t.u[1][1]"),
        ] {
            let at = text.find("\"a\"").unwrap();
            assert_eq!(
                key_path_at(text, at..at + 3).as_deref(),
                Some(key),
                "{text}"
            );
        }
        // A syntax error has no key path.
        assert_eq!(key_path_at("[a\nb = 1", 0..1), None);
        // The message of a type error in the bench's own structure.
        let text = BUILTIN_CONFIG_TOML.replacen("f_end_hz = 500.0", "f_end_hz = [\n 1,\n]", 1);
        let e = BenchConfig::from_toml(&text, Path::new("b.toml")).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("config b.toml: chirp.f_end_hz: TOML parse error"),
            "{e}"
        );
    }

    #[test]
    fn values_in_the_wrong_unit_get_a_hint() {
        let (mut c, _) = shipped("sr4dof-ch5.toml");
        c.plant.mass_asymmetry = 10.0;
        let e = c.check().unwrap_err();
        assert_eq!(e.key, "plant.mass_asymmetry");
        assert!(
            e.reason.contains("0.10 = 10 %") && e.reason.contains("give 0.1"),
            "{}",
            e.reason
        );
        // A plausible-looking fraction out of range: no percent hint.
        c.plant.mass_asymmetry = 0.9;
        assert!(!c.check().unwrap_err().reason.contains("0.10 = 10 %"));
        c.plant.mass_asymmetry = 0.1;
        c.plant.operating_point_m = 3.0;
        let e = c.check().unwrap_err();
        assert_eq!(e.key, "plant.operating_point_m");
        assert!(e.reason.contains("3 mm = 0.003 m"), "{}", e.reason);
        // 20 % of L = 9.5 mm: 0.05 m is out of range, but 0.05 mm is not
        // what was meant either way; 50 (mm) is out of range in metres too.
        c.plant.operating_point_m = 50.0;
        assert!(!c.check().unwrap_err().reason.contains("mm ="));
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
