//! The config's sections other than the plant and the controllers: what
//! each table of the TOML file holds (`[daemon]`, `[backend]`,
//! `[emulator]`, `[step]`, `[loop]`, `[stage]`, `[safety]`, `[chirp]`,
//! `[identification]`, `[sim]`), with its serde defaults. Their ranges are
//! checked in [`super::validate`]; SI units, the unit in every key name.

use serde::{Deserialize, Serialize};

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
    /// The simulated plant in-process (`bench_plant::sim`).
    #[default]
    Sim,
    /// A serial DAQ speaking `hal/protocol/PROTOCOL.md`.
    Serial,
    /// A CAN analog I/O module on SocketCAN.
    Socketcan,
    /// A CiA 402 drive on EtherCAT (`bench_hal::ethercat`).
    Ethercat,
}

/// `[backend]`: which hardware runs the jobs. `--backend` overrides `kind`
/// and the device.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BackendConfig {
    /// `sim`, `serial`, `socketcan` or `ethercat`.
    #[serde(default)]
    pub kind: BackendKind,
    /// `[backend.serial]`: the serial DAQ. Safety ranges:
    /// `sample_timeout_periods` in [1, 1000] periods and at most
    /// [`super::limits::SAMPLE_TIMEOUT_MAX_S`] (200 ms) at the loop rate;
    /// `handshake_timeout_ms` in [`super::limits::HANDSHAKE_TIMEOUT_MS`]
    /// (1 ms … 10 s); and `(safety.max_missed_samples + 1)` sample timeouts
    /// at most [`super::limits::LINK_FAULT_MAX_S`] (1 s).
    #[serde(default)]
    pub serial: bench_hal::serial::SerialConfig,
    /// `[backend.can]`: the SocketCAN module and its frame map. Safety
    /// ranges: `sample_timeout_ms` in [0.1, 200] ms (and the same 1 s to the
    /// link fault as the serial link), `peak_current_a` in (0, 20] A and
    /// `continuous_current_a` in (0, `peak_current_a`], as for
    /// `[actuator]`.
    #[serde(default)]
    pub can: bench_hal::can::CanConfig,
    /// `[backend.ethercat]`: the EtherCAT segment, profile, identity, PDO
    /// map and SM watchdog (`bench_hal::ethercat::EthercatConfig`). Safety
    /// ranges: `watchdog_ms` in [max(0.2 ms, two loop periods), 1000] ms,
    /// currents as for `[actuator]`.
    #[serde(default)]
    pub ethercat: bench_hal::ethercat::EthercatConfig,
}

/// `[emulator]`: the device side run by `bench emulate`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EmulatorConfig {
    /// Device watchdog: with no valid command for this long while enabled,
    /// the device drops the current to 0 A and latches a fault, ms.
    /// Range: at least 1 ms and two loop periods (commands come once a
    /// period), at most [`super::limits::WATCHDOG_MAX_MS`] (1 s: a dead host must
    /// not leave current flowing longer).
    #[serde(default = "default_watchdog_ms")]
    pub watchdog_ms: f64,
    /// Size of one probe count on the serial link, m. Range:
    /// `probe.range_m / (2³¹ − 1)` (the whole probe range fits the 32-bit
    /// count) to [`super::limits::POSITION_LSB_MAX_M`] (1 µm: a coarser count would
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
    /// Range: [`super::limits::POSITION_LIMIT_MIN_M`] (1 µm, well above the probe's
    /// 40 nm RMS noise) up to, not including, [`super::limits::STROKE_M`] (the
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
    /// above 0 and at most [`super::limits::BLIND_MAX_S`] (0.1 s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_overrun_s: Option<f64>,
    /// The tick count that `max_overrun_s` replaced; refused with a hint
    /// (never written).
    #[serde(default, skip_serializing)]
    pub max_consecutive_overruns: Option<serde::de::IgnoredAny>,
    /// Consecutive samples that may be missing (sequence gap, timeout,
    /// corrupt frames) or stale (sequence not advancing) before the
    /// supervisor faults (K). Range: 0 (every missing sample faults) to the
    /// ticks of [`super::limits::BLIND_MAX_S`] (0.1 s; 500 at 5 kHz), and K + 1
    /// sample timeouts (`[backend.serial] sample_timeout_periods`,
    /// `[backend.can] sample_timeout_ms`) at most
    /// [`super::limits::LINK_FAULT_MAX_S`] (1 s, the longest device watchdog).
    #[serde(default = "default_max_missed")]
    pub max_missed_samples: u32,
    /// Largest plausible change of the probe reading between two ticks, m;
    /// a larger jump faults (a glitch or a lost target, not motion).
    /// Range: [`super::limits::POSITION_STEP_MIN_M`] (1 µm, 25 × the probe's RMS
    /// noise) to [`super::limits::STAGE_SPEED_MAX_M_PER_S`] × one period (1 m/s,
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
    /// [`super::limits::BLIND_MAX_S`] (0.1 s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_command_latency_s: Option<f64>,
    /// How long the peak current may flow from cold, s: the I²t budget is
    /// `(I_peak² − I_cont²) · this`; the accumulator integrates
    /// `i² − I_cont²` (never below 0) and faults when it exceeds the budget.
    /// Range: [`super::limits::I2T_PEAK_DURATION_S`] (10 ms to 10 s: a coil's peak
    /// rating is a rating for seconds, not minutes).
    #[serde(default = "default_i2t_s")]
    pub i2t_peak_duration_s: f64,
    /// Smallest phase margin the loop check accepts, degrees. Range:
    /// [`super::limits::MIN_PHASE_MARGIN_DEG`] (20° up to, not including, 90°:
    /// below 20° a loop rings and small plant changes destabilise it).
    #[serde(default = "default_min_pm")]
    pub min_phase_margin_deg: f64,
    /// Largest peak of |S| the loop check accepts (2.0 = 6 dB, modulus
    /// margin 0.5). Range: above 1 (no loop does better) up to
    /// [`super::limits::MAX_SENSITIVITY_PEAK`] (6, modulus margin 0.17).
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

/// What `bench chirp` plays (`[excitation] kind`): a sweep law
/// (`[chirp]`), or a periodic multisine (`[multisine]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ExcitationKind {
    /// Exponential (logarithmic) sweep: equal time per octave.
    #[default]
    Exponential,
    /// Linear sweep: constant df/dt.
    Linear,
    /// A periodic multisine on the DFT lines of `[multisine] period_s`,
    /// several periods of several random-phase realizations, for the best
    /// linear approximation with its noise and nonlinear distortion
    /// ([`crate::config::MultisineConfig`]).
    Multisine,
}

impl ExcitationKind {
    /// A swept sine (exponential or linear), which `chirp.duration_s` and
    /// `chirp.taper_s` describe.
    pub fn is_sweep(self) -> bool {
        !matches!(self, Self::Multisine)
    }

    /// The sweep law a sweep of this excitation uses (the injection of
    /// `bench control --verify`): the kind itself, exponential for a
    /// multisine.
    pub fn sweep_law(self) -> Self {
        match self {
            Self::Multisine => Self::Exponential,
            k => k,
        }
    }

    /// The config spelling (`exponential`, `linear`, `multisine`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Exponential => "exponential",
            Self::Linear => "linear",
            Self::Multisine => "multisine",
        }
    }
}

/// Most breakpoints in `chirp.amplitude_profile`.
pub const MAX_PROFILE_POINTS: usize = 16;

/// `[excitation]`: what `bench chirp` plays. Before it had its own
/// table the kind was `[chirp] kind`; that spelling is still read, moved
/// here with a deprecation warning ([`move_old_spellings`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExcitationConfig {
    /// `exponential` (default) or `linear`: a swept sine (`[chirp]`'s
    /// band, amplitude, duration and fades); `multisine`: a periodic
    /// multisine (`[chirp]`'s band and amplitude, the `[multisine]`
    /// table).
    #[serde(default)]
    pub kind: ExcitationKind,
}

/// Moves the keys of `table` (a bench config, as parsed) that an older
/// version spelled elsewhere to where they are now: `[chirp] kind` to
/// `[excitation] kind` (issue 43: the field's word is excitation).
/// Returns the deprecation note to show (`None`: nothing was moved).
///
/// # Errors
/// The old key's name and the reason, when both spellings are set.
pub fn move_old_spellings(table: &mut toml::Table) -> Result<Option<String>, (String, String)> {
    let Some(toml::Value::Table(chirp)) = table.get_mut("chirp") else {
        return Ok(None);
    };
    let Some(kind) = chirp.remove("kind") else {
        return Ok(None);
    };
    let excitation = table
        .entry("excitation")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    let toml::Value::Table(excitation) = excitation else {
        return Err(("excitation".into(), "must be a table".into()));
    };
    if excitation.contains_key("kind") {
        return Err((
            "chirp.kind".into(),
            "is the old spelling of excitation.kind, which is set too: remove chirp.kind".into(),
        ));
    }
    let note = format!(
        "chirp.kind is deprecated: write [excitation] kind = {kind} (read as that for now)"
    );
    excitation.insert("kind".into(), kind);
    Ok(Some(note))
}

/// `[chirp]`: the swept sine's definition (and the band and amplitude a
/// multisine shares).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChirpConfig {
    /// Start frequency, Hz: the sweep's, or the lowest excited line of a
    /// multisine.
    pub f_start_hz: f64,
    /// End frequency, Hz (below the Nyquist frequency): the sweep's, or
    /// the highest excited line of a multisine.
    pub f_end_hz: f64,
    /// Current amplitude, A (at most the amplifier's peak current): the
    /// sweep's largest amplitude, or the multisine's peak current.
    pub amplitude_a: f64,
    /// Optional amplitude schedule: `[frequency_hz, scale]` breakpoints,
    /// ascending in frequency, scale in (0, 1], interpolated linearly in
    /// log f and held beyond the ends. A sweep's amplitude at instantaneous
    /// frequency f is `amplitude_a · scale(f)`; a multisine's line at f has
    /// an amplitude proportional to `scale(f)` (the whole signal then
    /// scaled to the peak `amplitude_a`). Use it to pass a lightly damped
    /// resonance gently while keeping the signal-to-noise ratio elsewhere.
    /// Empty: constant amplitude.
    #[serde(default)]
    pub amplitude_profile: Vec<[f64; 2]>,
    /// Sweep duration, s. Required for a sweep; refused with
    /// `excitation.kind = "multisine"` (its length is `[multisine]`'s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub duration_s: Option<f64>,
    /// Raised-cosine fade-in and fade-out at each end of the sweep, s.
    /// Required for a sweep; refused with `excitation.kind = "multisine"` (a
    /// periodic signal has no ends to fade; its transient periods are
    /// discarded instead).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub taper_s: Option<f64>,
    /// Quiet time before the sweep (probe offset estimate), s.
    pub lead_in_s: f64,
    /// Quiet tail after the sweep for ring-down, s.
    pub tail_s: f64,
}

/// The FRF estimator of `bench chirp` (`identification.estimator`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Estimator {
    /// The local polynomial method (`ident::lpm`): a noise
    /// variance per line from the local fit's residual, transient and
    /// leakage removed.
    #[default]
    Lpm,
    /// H1 on frequency-smoothed spectra (`ident::frf`), σ from
    /// the coherence.
    H1,
}

impl Estimator {
    /// The config spelling: `"lpm"`, `"h1"`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Lpm => "lpm",
            Self::H1 => "h1",
        }
    }
}

/// Phases of the multisine's lines (`[multisine] phases`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MultisinePhases {
    /// Independent phases, uniform on [0, 2π), drawn from the run's seed:
    /// each realization is a new draw, so the nonlinear distortion differs
    /// between realizations and the best linear approximation can tell it
    /// from the noise. Needs `realizations` ≥ 2.
    #[default]
    Random,
    /// Schroeder's phases (deterministic, low crest factor): one signal,
    /// so `realizations` must be 1 and the nonlinear distortion cannot be
    /// told from the response (it stays in the estimate as a bias).
    Schroeder,
}

impl MultisinePhases {
    /// The config spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Random => "random",
            Self::Schroeder => "schroeder",
        }
    }
}

/// `[multisine]`: the periodic excitation of `excitation.kind = "multisine"`
/// (its band and peak current are `[chirp]`'s `f_start_hz`, `f_end_hz`,
/// `amplitude_a`, its line amplitudes follow `amplitude_profile`; its
/// record is `chirp.lead_in_s | realizations × (transient_periods +
/// periods) × period_s | chirp.tail_s`). The table is refused with a
/// sweep kind (it would not be played). Ranges are in the README's
/// configuration reference and [`super::ranges`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MultisineConfig {
    /// Period T_p, s, rounded to whole loop ticks; the lines are at
    /// `l / T_p`. Range: `[1 / chirp.f_start_hz, 600]` s (the lowest line
    /// at or below `f_start_hz`). Absent: `1 / chirp.f_start_hz` rounded up
    /// to whole ticks.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub period_s: Option<f64>,
    /// Periods P measured in each realization (after the transient ones).
    /// Range [2, 1000]: two at least for the noise variance. Default 2.
    #[serde(default = "default_ms_periods")]
    pub periods: u32,
    /// Realizations M (independent phase draws). Range [2, 1000] with
    /// random phases (two at least for the variance over realizations;
    /// four or more recommended), exactly 1 with Schroeder phases.
    /// Default 4.
    #[serde(default = "default_ms_realizations")]
    pub realizations: u32,
    /// Periods played and discarded at the start of each realization,
    /// while the plant's transient from the previous one decays (make it
    /// several `1 / (ζ ω)` of the slowest mode). Range [0, 100]. Default 1.
    #[serde(default = "default_ms_transient")]
    pub transient_periods: u32,
    /// `random` (default) or `schroeder`.
    #[serde(default)]
    pub phases: MultisinePhases,
    /// Most excited lines per decade: every DFT line where the lines are
    /// sparser than this (below `lines_per_decade / (T_p ln 10)` Hz), a
    /// log-spaced choice above it, so each line keeps its power. Range
    /// [10, 10 000]. Default 300.
    #[serde(default = "default_ms_lines_per_decade")]
    pub lines_per_decade: u32,
}

fn default_ms_periods() -> u32 {
    2
}
fn default_ms_realizations() -> u32 {
    4
}
fn default_ms_transient() -> u32 {
    1
}
fn default_ms_lines_per_decade() -> u32 {
    300
}

impl Default for MultisineConfig {
    fn default() -> Self {
        Self {
            period_s: None,
            periods: default_ms_periods(),
            realizations: default_ms_realizations(),
            transient_periods: default_ms_transient(),
            phases: MultisinePhases::default(),
            lines_per_decade: default_ms_lines_per_decade(),
        }
    }
}

impl MultisineConfig {
    /// Ticks in one period at a loop period of `tick_s` (s): `period_s`
    /// rounded to the nearest tick, or, absent, `1 / f_start_hz` rounded up.
    /// `None` for a non-finite or non-positive result, or one above
    /// [`super::ranges::JOB_TICKS_MAX`].
    pub fn period_ticks(&self, f_start_hz: f64, tick_s: f64) -> Option<u64> {
        let t = match self.period_s {
            Some(p) => (p / tick_s).round(),
            None => (1.0 / (f_start_hz * tick_s) * (1.0 - 1e-12)).ceil(),
        };
        (t.is_finite() && t >= 1.0 && t <= super::ranges::JOB_TICKS_MAX as f64).then_some(t as u64)
    }

    /// The excited DFT line indices `l` (line frequency `l / T_p`,
    /// `T_p = period_ticks · tick_s`), ascending: from
    /// `l_lo = ⌈f_start T_p⌉` to `l_hi = ⌊f_end T_p⌋` (to 1e-9 of a line),
    /// the log-spaced grid `l_lo (l_hi / l_lo)^(i/n)`, `i = 0 … n`,
    /// `n = ⌈lines_per_decade · log10(l_hi / l_lo)⌉`, each point rounded
    /// to the nearest line, duplicates removed. Where the grid's step is
    /// below one line (`l < 1 / (10^(1/lines_per_decade) − 1)`) it meets
    /// every line, so all low lines are excited; above, about
    /// `lines_per_decade` per decade. Empty when no line lies in the band.
    pub fn excited_lines(
        &self,
        f_start_hz: f64,
        f_end_hz: f64,
        period_ticks: u64,
        tick_s: f64,
    ) -> Vec<u64> {
        let t_p = period_ticks as f64 * tick_s;
        let lo = (f_start_hz * t_p - 1e-9).ceil().max(1.0);
        // Below Nyquist: a line at or above N/2 is not a sine of the table.
        let nyquist_line = ((period_ticks as f64 - 1.0) / 2.0).floor();
        let hi = (f_end_hz * t_p + 1e-9).floor().min(nyquist_line);
        if !(lo.is_finite() && hi.is_finite()) || hi < lo {
            return Vec::new();
        }
        let n = (f64::from(self.lines_per_decade) * (hi / lo).log10()).ceil() as u64;
        let mut lines: Vec<u64> = Vec::new();
        for i in 0..=n {
            let g = if n == 0 {
                lo
            } else {
                lo * (hi / lo).powf(i as f64 / n as f64)
            };
            let l = (g.round()).clamp(lo, hi) as u64;
            if lines.last() != Some(&l) {
                lines.push(l);
            }
        }
        lines
    }
}

/// `[identification]`
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IdentificationConfig {
    /// Points of the log-spaced output grid per decade.
    #[serde(default = "default_ppd")]
    pub points_per_decade: usize,
    /// Frequency resolution as a fraction of frequency: the full width of
    /// H1's smoothing window, and of the LPM's local window where that is
    /// wider than `2 lpm_half_width_bins + 1` bins: 0.004 = 0.4 % of f.
    #[serde(default = "default_resolution")]
    pub relative_resolution: f64,
    /// Fewest DFT bins averaged at any grid point (sets the resolution where
    /// `relative_resolution · f` is finer than the record allows). H1 only.
    #[serde(default = "default_min_bins")]
    pub min_bins: usize,
    /// The FRF estimator (default the LPM).
    #[serde(default)]
    pub estimator: Estimator,
    /// LPM: least half width `n` of the local window, DFT bins (the window
    /// is `2n + 1` bins, or `relative_resolution · f` where wider). Default
    /// [`DEFAULT_LPM_HALF_WIDTH_BINS`].
    #[serde(default = "default_lpm_half_width")]
    pub lpm_half_width_bins: usize,
    /// LPM: degree `R` of the local polynomials of the FRF and the
    /// transient. Default [`DEFAULT_LPM_DEGREE`].
    #[serde(default = "default_lpm_degree")]
    pub lpm_degree: usize,
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
/// Default `n` of the LPM, the window's half width in DFT bins: with
/// `R` = 2 the noise variance of a line has `q = 2n + 1 − 2(R + 1)` = 7
/// degrees of freedom (Pintelon & Schoukens 2012, §7.2; `ident::lpm`).
pub const DEFAULT_LPM_HALF_WIDTH_BINS: usize = 6;
/// Default `R` of the LPM, the degree of the local polynomials.
pub const DEFAULT_LPM_DEGREE: usize = 2;

fn default_lpm_half_width() -> usize {
    DEFAULT_LPM_HALF_WIDTH_BINS
}
fn default_lpm_degree() -> usize {
    DEFAULT_LPM_DEGREE
}

impl Default for IdentificationConfig {
    fn default() -> Self {
        Self {
            points_per_decade: default_ppd(),
            relative_resolution: default_resolution(),
            min_bins: default_min_bins(),
            estimator: Estimator::default(),
            lpm_half_width_bins: default_lpm_half_width(),
            lpm_degree: default_lpm_degree(),
        }
    }
}

/// `[sim]`
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimConfig {
    /// Seed of the simulator's noise generator (default 1, with or without
    /// a `[sim]` table): any u64. TOML's integers are signed 64-bit, so a
    /// seed from 2^63 up is written (and read) as a string of decimal
    /// digits, `seed = "11494561977276947931"` ([`seed_toml`]): a
    /// campaign's cell seeds span the whole range, and each cell's
    /// recording holds its resolved config.
    #[serde(default = "default_seed", with = "seed_toml")]
    pub seed: u64,
}

/// `[sim] seed` in TOML: an integer 0 ..= 2^63 − 1, or a string of decimal
/// digits 0 ..= 2^64 − 1 (written as one only when the integer cannot be).
pub mod seed_toml {
    use serde::{de, Deserializer, Serializer};
    use std::fmt;

    /// What the key takes, as its errors say.
    pub const EXPECTED: &str =
        "a seed: an integer 0 ..= 2^63 - 1, or a string of decimal digits 0 ..= 18446744073709551615 (2^64 - 1)";

    /// An integer when it fits TOML's, else the decimal string.
    ///
    /// # Errors
    /// The serializer's.
    pub fn serialize<S: Serializer>(seed: &u64, s: S) -> Result<S::Ok, S::Error> {
        match i64::try_from(*seed) {
            Ok(i) => s.serialize_i64(i),
            Err(_) => s.serialize_str(&seed.to_string()),
        }
    }

    /// Either form.
    ///
    /// # Errors
    /// A negative integer, a string that is not decimal digits of a u64,
    /// or another type, each saying [`EXPECTED`].
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
        struct Seed;
        impl de::Visitor<'_> for Seed {
            type Value = u64;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(EXPECTED)
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<u64, E> {
                Ok(v)
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<u64, E> {
                u64::try_from(v).map_err(|_| E::invalid_value(de::Unexpected::Signed(v), &self))
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<u64, E> {
                if v.is_empty() || !v.bytes().all(|b| b.is_ascii_digit()) {
                    return Err(E::invalid_value(de::Unexpected::Str(v), &self));
                }
                v.parse::<u64>()
                    .map_err(|_| E::invalid_value(de::Unexpected::Str(v), &self))
            }
        }
        d.deserialize_any(Seed)
    }
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
