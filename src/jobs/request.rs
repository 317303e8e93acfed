//! Job requests: what a chirp or a closed-loop step is asked to do, one
//! serde type per job kind. `bench chirp|control` build them from their
//! flags, `bench serve` deserialises them from a request's `params`, and
//! `--daemon` sends them serialised. Applied to a [`BenchConfig`], a
//! request writes its values into the config and checks the result, in one
//! place: [`ChirpRequest::apply`], [`ControlRequest::apply`].
//!
//! Errors name the config key or the request field, never a command-line
//! flag: only the CLI knows its flags.

pub use super::analyze::AnalyzeRequest;
pub use super::design::DesignRequest;
pub use super::fit::FitRequest;
pub use super::map::MapRequest;
pub use super::plot::PlotRequest;
pub use super::point::OperatingPoint;
use super::verify::{DEFAULT_AMPLITUDE_OF_CHIRP, DEFAULT_DURATION_S};
use crate::config::{ranges, BenchConfig, ChirpKind};
use bench_hal::sim::{FaultInjection, ScheduledFault};
use serde::{Deserialize, Serialize};

/// Why a request cannot run on a config.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RequestError {
    /// With the request applied, the config does not describe a usable run.
    #[error("{key}: {reason}")]
    Invalid {
        /// Dotted config key (e.g. `chirp.duration_s`).
        key: String,
        /// Why.
        reason: String,
    },
    /// A request field that does not parse, or names nothing in the config.
    #[error("{field} {value:?}: {reason}")]
    Field {
        /// The field (e.g. `inject_fault`).
        field: &'static str,
        /// Its value as given.
        value: String,
        /// Why.
        reason: String,
    },
}

/// A job for the bench, as the daemon takes it: `{"cmd": KIND, "params":
/// {...}}` with the fields of the kind's request as `params`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "cmd", content = "params", rename_all = "lowercase")]
pub enum JobRequest {
    /// `bench chirp`.
    Chirp(ChirpRequest),
    /// `bench control`.
    Control(ControlRequest),
    /// `bench fit`.
    Fit(FitRequest),
    /// `bench design`.
    Design(DesignRequest),
    /// `bench analyze`.
    Analyze(AnalyzeRequest),
    /// `bench map`.
    Map(MapRequest),
    /// `bench plot bode|nyquist`.
    Plot(PlotRequest),
    /// `bench campaign run --submit`.
    Campaign(CampaignRequest),
}

impl JobRequest {
    /// Every job kind, as the daemon's `cmd`.
    pub const KINDS: [&'static str; 8] = [
        "chirp", "control", "fit", "design", "analyze", "map", "plot", "campaign",
    ];

    /// The job kind, as the daemon's `cmd`: one of [`Self::KINDS`].
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Chirp(_) => "chirp",
            Self::Control(_) => "control",
            Self::Fit(_) => "fit",
            Self::Design(_) => "design",
            Self::Analyze(_) => "analyze",
            Self::Map(_) => "map",
            Self::Plot(_) => "plot",
            Self::Campaign(_) => "campaign",
        }
    }

    /// Whether the job drives the bench (chirp, control): it runs on the
    /// real-time loop and makes a recording. The others compute from
    /// files and the model and never touch the bench.
    pub fn uses_bench(&self) -> bool {
        matches!(self, Self::Chirp(_) | Self::Control(_))
    }
}

/// A chirp (`bench chirp`, the daemon's `chirp`). Every field is optional:
/// absent, the config's value holds.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChirpRequest {
    /// Simulator noise seed. Not a config value: absent, the runner's
    /// default holds (`sim.seed`, or `bench serve --seed`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// Current amplitude, A (`chirp.amplitude_a`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub amplitude_a: Option<f64>,
    /// Sweep start frequency, Hz (`chirp.f_start_hz`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub f_start_hz: Option<f64>,
    /// Sweep end frequency, Hz (`chirp.f_end_hz`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub f_end_hz: Option<f64>,
    /// Sweep duration, s (`chirp.duration_s`). Each fade (`chirp.taper_s`)
    /// shrinks to at most a quarter of it. Refused with `chirp.kind =
    /// "multisine"` (naming `chirp.duration_s`): a multisine's length is
    /// its `[multisine]` table's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub duration_s: Option<f64>,
    /// Pacing on the simulator ([`Pace`]: a factor of real time, or
    /// `"off"`); checked by [`check_pace`]. Absent: the runner's default
    /// (a local run in virtual time, unpaced unless it serves a live view;
    /// a daemon's job in real time).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pace: Option<Pace>,
}

impl ChirpRequest {
    /// Writes the request into `cfg` and checks the whole config.
    ///
    /// # Errors
    /// [`RequestError::Invalid`] naming the first offending config key
    /// (`cfg` keeps the request's values).
    pub fn apply(&self, cfg: &mut BenchConfig) -> Result<(), RequestError> {
        if let (Some(_), Some(taper_s), Some(duration_s)) =
            (self.duration_s, cfg.chirp.taper_s, cfg.chirp.duration_s)
        {
            // The fades shrink below: the configured ones must be valid
            // first, or a short sweep would hide a bad chirp.taper_s.
            if !taper_s.is_finite() || taper_s < 0.0 || 2.0 * taper_s > duration_s {
                return Err(RequestError::Invalid {
                    key: "chirp.taper_s".into(),
                    reason: format!(
                        "{taper_s} s is not a fade that fits in the configured chirp.duration_s = {duration_s} s"
                    ),
                });
            }
        }
        let c = &mut cfg.chirp;
        set(&mut c.amplitude_a, self.amplitude_a);
        set(&mut c.f_start_hz, self.f_start_hz);
        set(&mut c.f_end_hz, self.f_end_hz);
        if let Some(v) = self.duration_s {
            // With chirp.kind = "multisine" the check below refuses it,
            // naming chirp.duration_s (a multisine does not sweep).
            c.duration_s = Some(v);
            // Keep the fades inside a short sweep.
            if v.is_finite() && v > 0.0 {
                c.taper_s = c.taper_s.map(|t| t.min(0.25 * v));
            }
        }
        check(cfg)
    }
}

/// A closed-loop step (`bench control`, the daemon's `control`). Absent
/// optional fields leave the config's `[step]` values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlRequest {
    /// The controller: `slow`, `fast` or any `[controller.NAME]` of the
    /// config.
    pub controller: String,
    /// Step size, m (`step.step_m`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub step_m: Option<f64>,
    /// Run time, s (`step.duration_s`). The steady-state window
    /// (`step.steady_state_window_s`) shrinks to at most half of it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub duration_s: Option<f64>,
    /// Raised-cosine ramp of the step, s (`step.smooth_s`; 0: sharp).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub smooth_s: Option<f64>,
    /// Simulator noise seed, as [`ChirpRequest::seed`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// A simulator fault to inject, `KIND@T_S` ([`parse_fault`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inject_fault: Option<String>,
    /// Run even when the loop check refuses (simulator only).
    #[serde(default)]
    pub override_check: bool,
    /// After the step, inject a chirp at the plant input and measure the
    /// loop ([`crate::jobs::verify`]).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub verify: bool,
    /// The injected chirp's amplitude, A (`verify` only) [default:
    /// [`DEFAULT_AMPLITUDE_OF_CHIRP`] of `chirp.amplitude_a`, at least
    /// 0.1 mA].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub verify_amplitude_a: Option<f64>,
    /// Its sweep duration, s (`verify` only) [default:
    /// [`DEFAULT_DURATION_S`]].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub verify_duration_s: Option<f64>,
    /// Pacing on the simulator, as [`ChirpRequest::pace`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pace: Option<Pace>,
}

/// The verify's amplitude (A) and sweep duration (s), resolved and
/// checked ([`ControlRequest::verify_settings`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VerifySettings {
    /// Chirp amplitude at the plant input, A.
    pub amplitude_a: f64,
    /// Sweep duration, s.
    pub duration_s: f64,
}

impl ControlRequest {
    /// A step of `controller` with the config's `[step]` values.
    pub fn new(controller: impl Into<String>) -> Self {
        Self {
            controller: controller.into(),
            step_m: None,
            duration_s: None,
            smooth_s: None,
            seed: None,
            inject_fault: None,
            override_check: false,
            verify: false,
            verify_amplitude_a: None,
            verify_duration_s: None,
            pace: None,
        }
    }

    /// The verify's amplitude and duration on `cfg` (the request applied):
    /// `None` without `verify`. The amplitude defaults to
    /// [`DEFAULT_AMPLITUDE_OF_CHIRP`] of `chirp.amplitude_a` (at least the
    /// 0.1 mA a chirp may have), the duration to [`DEFAULT_DURATION_S`].
    /// Ranges, as `[chirp]`'s: amplitude in [0.1 mA,
    /// `actuator.peak_current_a`], duration in [0.1 s, 600 s], and the
    /// whole run (the step, the lead-in, the sweep, the tail) at most
    /// [`ranges::JOB_TICKS_MAX`] ticks. Whether the limits leave room for
    /// the amplitude is judged on the model before enable
    /// ([`crate::jobs::verify::plan`]).
    ///
    /// # Errors
    /// [`RequestError::Field`] naming `verify_amplitude_a` or
    /// `verify_duration_s`: a value outside its range, or given without
    /// `verify`.
    pub fn verify_settings(
        &self,
        cfg: &BenchConfig,
    ) -> Result<Option<VerifySettings>, RequestError> {
        let field = |field: &'static str, v: f64, reason: String| RequestError::Field {
            field,
            value: v.to_string(),
            reason,
        };
        if !self.verify {
            for (name, v) in [
                ("verify_amplitude_a", self.verify_amplitude_a),
                ("verify_duration_s", self.verify_duration_s),
            ] {
                if let Some(v) = v {
                    return Err(field(
                        name,
                        v,
                        format!("{v} is given without verify (it sets the verify's chirp)"),
                    ));
                }
            }
            return Ok(None);
        }
        let peak = cfg.actuator.peak_current_a;
        let a = self.verify_amplitude_a.unwrap_or(
            (DEFAULT_AMPLITUDE_OF_CHIRP * cfg.chirp.amplitude_a).max(ranges::CHIRP_AMPLITUDE_MIN_A),
        );
        if !(a.is_finite() && a >= ranges::CHIRP_AMPLITUDE_MIN_A && a <= peak) {
            return Err(field(
                "verify_amplitude_a",
                a,
                format!(
                    "{a:?} A is outside [{}, {peak}] A: the injected chirp's amplitude, at least 0.1 mA (as chirp.amplitude_a) and at most the amplifier's peak current actuator.peak_current_a",
                    ranges::CHIRP_AMPLITUDE_MIN_A
                ),
            ));
        }
        let d = self.verify_duration_s.unwrap_or(DEFAULT_DURATION_S);
        let (lo, hi) = ranges::CHIRP_DURATION_S;
        if !(d.is_finite() && (lo..=hi).contains(&d)) {
            return Err(field(
                "verify_duration_s",
                d,
                format!(
                    "{d:?} s is outside [{lo}, {hi}] s: the verify's sweep, as chirp.duration_s (0.1 s to 10 minutes)"
                ),
            ));
        }
        let run_s = cfg.step.duration_s + cfg.chirp.lead_in_s + d + cfg.chirp.tail_s;
        let ticks = run_s * cfg.loop_.rate_hz;
        if ticks > ranges::JOB_TICKS_MAX as f64 {
            return Err(field(
                "verify_duration_s",
                d,
                format!(
                    "{d} s makes the run (step.duration_s + chirp.lead_in_s + the sweep + chirp.tail_s = {run_s} s) {ticks:.0} ticks at loop.rate_hz = {} Hz: a job is at most {} ticks",
                    cfg.loop_.rate_hz,
                    ranges::JOB_TICKS_MAX
                ),
            ));
        }
        Ok(Some(VerifySettings {
            amplitude_a: a,
            duration_s: d,
        }))
    }

    /// Checks the controller against `cfg`, writes the step into it, checks
    /// the whole config and the verify's settings
    /// ([`Self::verify_settings`]), and parses the fault to inject.
    ///
    /// # Errors
    /// [`RequestError::Field`] for a controller the config does not have,
    /// a verify setting out of its range, or a fault that does not parse;
    /// [`RequestError::Invalid`] naming the
    /// first offending config key (`cfg` keeps the request's values).
    pub fn apply(&self, cfg: &mut BenchConfig) -> Result<Option<ScheduledFault>, RequestError> {
        if !cfg.controller.contains_key(&self.controller) {
            let known: Vec<&str> = cfg.controller.keys().map(String::as_str).collect();
            return Err(RequestError::Field {
                field: "controller",
                value: self.controller.clone(),
                reason: format!(
                    "no [controller.{}] in the config (known: {})",
                    self.controller,
                    if known.is_empty() {
                        "none".to_string()
                    } else {
                        known.join(", ")
                    }
                ),
            });
        }
        if self.duration_s.is_some() {
            // The window shrinks below: the configured one must be valid
            // first, or a short run would hide a bad steady_state_window_s.
            let s = &cfg.step;
            let w = s.steady_state_window_s;
            if !w.is_finite() || w <= 0.0 || w > s.duration_s - s.settle_s - s.smooth_s {
                return Err(RequestError::Invalid {
                    key: "step.steady_state_window_s".into(),
                    reason: format!(
                        "{w} s is not a window that fits after the configured step (step.duration_s - step.settle_s - step.smooth_s)"
                    ),
                });
            }
        }
        let s = &mut cfg.step;
        set(&mut s.step_m, self.step_m);
        if let Some(v) = self.duration_s {
            s.duration_s = v;
            // Keep the steady-state window inside a short run.
            if v.is_finite() && v > 0.0 {
                s.steady_state_window_s = s.steady_state_window_s.min(0.5 * v);
            }
        }
        set(&mut s.smooth_s, self.smooth_s);
        check(cfg)?;
        self.verify_settings(cfg)?;
        self.inject_fault
            .as_deref()
            .map(|f| {
                parse_fault(f).map_err(|reason| RequestError::Field {
                    field: "inject_fault",
                    value: f.to_string(),
                    reason,
                })
            })
            .transpose()
    }
}

/// A campaign (`bench campaign run --submit`, the daemon's `campaign`): a
/// new campaign of the file's grid, run on the simulator in virtual time,
/// cells in parallel, in a directory the runner names (the daemon: in its
/// recordings directory; the file's `out` does not apply). See
/// [`crate::campaign`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CampaignRequest {
    /// The campaign file (TOML; its `config` relative to it). The daemon
    /// takes an absolute path. `None`: the built-in campaign (thesis Fig
    /// 5-10 on the built-in bench).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<std::path::PathBuf>,
    /// Cells run at once, 1 … 64 [default: the runner's cores].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threads: Option<usize>,
    /// What each cell keeps: `recording`, `frf` or `summary` [default: the
    /// campaign file's `keep`, else `recording`]
    /// (`crate::campaign::file::Keep`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub keep: Option<String>,
    /// Design one controller over every done cell at the end (`slow`,
    /// `fast` or `auto`), as `bench campaign run --design` does.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub design: Option<crate::design::Strategy>,
}

/// What a local run may change besides its job request: the simulated
/// plant's operating point and mass asymmetry, and the sweep law. A daemon
/// takes none of them: its bench and config stay as it was started.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LocalOverrides {
    /// Operating point Y1o (`plant.operating_point_m`).
    pub operating_point: Option<OperatingPoint>,
    /// Mass asymmetry Δm23 = m2/m3 − 1 (`plant.mass_asymmetry`).
    pub mass_asymmetry: Option<f64>,
    /// What `bench chirp` plays (`chirp.kind`). The keys of the other
    /// kind are set aside with it, as the flag asks: a multisine drops
    /// the sweep's `chirp.duration_s` and `chirp.taper_s` (and takes the
    /// `[multisine]` table, or its defaults); a sweep drops the
    /// `[multisine]` table, needs a `chirp.duration_s` (the config's or
    /// `--duration-s`) and fades by the config's `chirp.taper_s`, 0 s
    /// (none) when the config has none.
    pub chirp_kind: Option<ChirpKind>,
}

impl LocalOverrides {
    /// Writes the overrides into `cfg`. It does not check: apply the job
    /// request after it, which checks the whole config.
    pub fn apply(&self, cfg: &mut BenchConfig) {
        if let Some(op) = self.operating_point {
            cfg.plant.operating_point_m = op.metres(cfg.plant.beam.length_m);
        }
        set(&mut cfg.plant.mass_asymmetry, self.mass_asymmetry);
        if let Some(kind) = self.chirp_kind {
            cfg.chirp.kind = kind;
            if kind.is_sweep() {
                cfg.multisine = None;
                cfg.chirp.taper_s.get_or_insert(0.0);
            } else {
                cfg.chirp.duration_s = None;
                cfg.chirp.taper_s = None;
            }
        }
    }
}

fn set<T>(slot: &mut T, value: Option<T>) {
    if let Some(v) = value {
        *slot = v;
    }
}

fn check(cfg: &BenchConfig) -> Result<(), RequestError> {
    cfg.check().map_err(|e| RequestError::Invalid {
        key: e.key,
        reason: e.reason,
    })
}

/// Parses a simulator seed (`seed`, `--seed`): an integer in
/// `0..=2^64 − 1`, with a message that says so for anything else (a
/// negative number, a fraction, text).
///
/// # Errors
/// Why it does not parse (the caller names the field or flag).
pub fn parse_seed(s: &str) -> Result<u64, String> {
    s.trim().parse::<u64>().map_err(|_| {
        format!(
            "{s:?} is not a seed: an integer in 0..={} (2^64 - 1)",
            u64::MAX
        )
    })
}

/// The slowest pace, × real time: a hundredth (a 10 s sweep takes about
/// 17 minutes; a 10 kHz loop releases 100 ticks a second).
pub const PACE_MIN: f64 = 0.01;
/// The fastest pace, × real time. Past it a pace has nothing left to show
/// (a 10 s sweep passes in a tenth of a second) and comes near the
/// machine's own speed: the default chirp's loop runs 650–1 300× real time
/// unpaced on a 2-core VM (README, *Measured performance*), where a pace
/// would no longer pace; `off` runs as fast as it goes and says so.
pub const PACE_MAX: f64 = 100.0;

/// How a run on the simulator is paced against the wall clock (`--pace`,
/// the request's `pace`): in JSON a number (the factor) or `"off"`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pace {
    /// Virtual time as fast as it goes ([`crate::rt::Pacing::Virtual`]).
    Off,
    /// Virtual time at this factor of real time
    /// ([`crate::rt::Pacing::Paced`]): 1 real time, 0.1 ten times slower,
    /// 10 ten times faster. In [[`PACE_MIN`], [`PACE_MAX`]] once checked
    /// ([`check_pace`]).
    Factor(f64),
}

impl Pace {
    /// The factor of real time, `None` for [`Pace::Off`].
    pub fn factor(self) -> Option<f64> {
        match self {
            Self::Off => None,
            Self::Factor(f) => Some(f),
        }
    }
}

impl std::fmt::Display for Pace {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Off => f.write_str("off"),
            Self::Factor(x) => write!(f, "{x}"),
        }
    }
}

impl Serialize for Pace {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Self::Off => s.serialize_str("off"),
            Self::Factor(x) => s.serialize_f64(*x),
        }
    }
}

impl<'de> Deserialize<'de> for Pace {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = Pace;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a factor of real time (a number, 1: real time) or \"off\"")
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<Pace, E> {
                Ok(Pace::Factor(v))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Pace, E> {
                Ok(Pace::Factor(v as f64))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Pace, E> {
                Ok(Pace::Factor(v as f64))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Pace, E> {
                if v == "off" {
                    Ok(Pace::Off)
                } else {
                    Err(E::invalid_value(serde::de::Unexpected::Str(v), &self))
                }
            }
        }
        d.deserialize_any(V)
    }
}

/// Why `factor` is not a pace, or the factor: in [[`PACE_MIN`],
/// [`PACE_MAX`]], finite. The one check of `--pace` and of a request's
/// `pace`.
///
/// # Errors
/// The reason, and what a pace is (the caller names the flag or field).
pub fn check_pace_factor(factor: f64) -> Result<f64, String> {
    let why = if factor.is_nan() {
        "not a number".to_string()
    } else if factor <= 0.0 {
        format!("{factor}× would stop time or run it backwards")
    } else if factor > PACE_MAX {
        format!(
            "{factor}× is faster than a pace can serve: past {PACE_MAX}× a live view shows nothing (a 10 s sweep passes in a tenth of a second) and the loop nears its unpaced speed (650–1 300× real time on a 2-core VM; give off to run as fast as it goes)"
        )
    } else if factor < PACE_MIN {
        format!("{factor}× is slower than a hundredth of real time (at {PACE_MIN}× a 10 s sweep already takes 17 minutes)")
    } else {
        return Ok(factor);
    };
    Err(format!(
        "{why}; a pace is a factor of real time from {PACE_MIN} to {PACE_MAX} (1: real time, 0.1: ten times slower, 10: ten times faster) or off (virtual time as fast as it goes)"
    ))
}

/// Parses a pace (`--pace`): `off`, or a factor of real time checked by
/// [`check_pace_factor`].
///
/// # Errors
/// Why it is not a pace (the caller names the flag).
pub fn parse_pace(s: &str) -> Result<Pace, String> {
    let t = s.trim();
    if t == "off" {
        return Ok(Pace::Off);
    }
    let factor: f64 = t.parse().map_err(|_| {
        format!(
            "{s:?} is not a number; a pace is a factor of real time from {PACE_MIN} to {PACE_MAX} (1: real time, 0.1: ten times slower, 10: ten times faster) or off"
        )
    })?;
    check_pace_factor(factor).map(Pace::Factor)
}

/// A request's `pace`, checked as `--pace` is ([`check_pace_factor`]).
///
/// # Errors
/// [`RequestError::Field`] naming `pace`.
pub fn check_pace(pace: Option<Pace>) -> Result<Option<Pace>, RequestError> {
    match pace {
        Some(Pace::Factor(f)) => {
            check_pace_factor(f)
                .map(|f| Some(Pace::Factor(f)))
                .map_err(|reason| RequestError::Field {
                    field: "pace",
                    value: f.to_string(),
                    reason,
                })
        }
        other => Ok(other),
    }
}

/// Why a pace is refused on a hardware backend (`backend` as named, e.g.
/// `serial:/dev/ttyUSB0`): hardware runs in real time.
pub fn pace_on_hardware(backend: &str) -> String {
    format!(
        "the {backend} backend runs in real time, always: a physical plant moves at its own pace, so the loop keeps its deadlines and cannot run slower or faster than the wall clock; a pace applies to the simulator (backend sim)"
    )
}

/// Parses a simulator fault `KIND@T_S`: KIND one of nan, frozen, drop (10
/// samples), jump (0.2 mm), out_of_range, or `stall:MS` (the host stalls
/// once for MS milliseconds, 0 < MS ≤ 10 000); T_S the loop time, s.
///
/// # Errors
/// Why it does not parse (the caller names the field or flag).
pub fn parse_fault(s: &str) -> Result<ScheduledFault, String> {
    let (kind, at) = s
        .split_once('@')
        .ok_or_else(|| "expected KIND@T_S, e.g. nan@1.5".to_string())?;
    let at_s: f64 = at
        .parse()
        .ok()
        .filter(|t: &f64| t.is_finite() && *t >= 0.0)
        .ok_or_else(|| format!("time {at:?} is not a non-negative number of seconds"))?;
    let kind = match kind {
        "nan" => FaultInjection::Nan,
        "frozen" => FaultInjection::Frozen,
        "drop" => FaultInjection::Drop(10),
        "jump" => FaultInjection::Jump(0.2e-3),
        "out_of_range" => FaultInjection::OutOfRange,
        other => {
            match other.strip_prefix("stall:") {
                Some(ms) => {
                    let ms: f64 = ms
                    .parse()
                    .ok()
                    .filter(|m: &f64| m.is_finite() && *m > 0.0 && *m <= 10_000.0)
                    .ok_or_else(|| {
                        format!("stall {ms:?} is not a duration in ms in (0, 10000], e.g. stall:30@1.5")
                    })?;
                    FaultInjection::Stall(ms * 1e-3)
                }
                None => {
                    return Err(format!(
                        "unknown kind {other:?} (nan, frozen, drop, jump, out_of_range, stall:MS)"
                    ))
                }
            }
        }
    };
    Ok(ScheduledFault { at_s, kind })
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;
    use std::path::Path;

    fn ch5() -> BenchConfig {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
        let cfg = BenchConfig::load(&path).unwrap();
        cfg.validate(&path).unwrap();
        cfg
    }

    type Expect = fn(&mut BenchConfig);

    /// `pace` in JSON: a number or "off", checked as `--pace` is; it
    /// writes nothing into the config.
    #[test]
    fn pace_reads_a_number_or_off_and_is_checked_as_the_flag() {
        let r: ChirpRequest = serde_json::from_value(json!({"pace": 0.5})).unwrap();
        assert_eq!(r.pace, Some(Pace::Factor(0.5)));
        assert_eq!(check_pace(r.pace), Ok(Some(Pace::Factor(0.5))));
        let r: ControlRequest =
            serde_json::from_value(json!({"controller": "fast", "pace": "off"})).unwrap();
        assert_eq!(r.pace, Some(Pace::Off));
        assert_eq!(serde_json::to_value(&r).unwrap()["pace"], json!("off"));
        let r: ChirpRequest = serde_json::from_value(json!({"pace": 2})).unwrap();
        assert_eq!(serde_json::to_value(&r).unwrap()["pace"], json!(2.0));
        for bad in [
            json!("fast"),
            json!("1"),
            json!(true),
            json!([1]),
            json!({}),
        ] {
            assert!(serde_json::from_value::<ChirpRequest>(json!({ "pace": bad })).is_err());
        }
        for f in [0.0, -1.0, 1e-3, 100.5, 1e300, f64::INFINITY, f64::NAN] {
            let e = check_pace(Some(Pace::Factor(f))).unwrap_err();
            let RequestError::Field { field, reason, .. } = &e else {
                panic!("{e:?}")
            };
            assert_eq!(*field, "pace");
            // The flag's reason, word for word.
            assert_eq!(Err(reason.clone()), check_pace_factor(f));
        }
        for (given, want) in [
            ("off", Pace::Off),
            ("1", Pace::Factor(1.0)),
            (" 0.01 ", Pace::Factor(0.01)),
            ("100", Pace::Factor(100.0)),
        ] {
            assert_eq!(parse_pace(given), Ok(want), "{given}");
        }
        let mut got = ch5();
        ChirpRequest {
            pace: Some(Pace::Factor(3.0)),
            ..Default::default()
        }
        .apply(&mut got)
        .unwrap();
        assert_eq!(got, ch5());
    }

    /// Each field lands on its config key and nowhere else.
    #[test]
    fn chirp_fields_land_on_their_keys() {
        let cases: [(ChirpRequest, Expect); 5] = [
            (
                ChirpRequest {
                    amplitude_a: Some(0.25),
                    ..Default::default()
                },
                |c| c.chirp.amplitude_a = 0.25,
            ),
            (
                ChirpRequest {
                    f_start_hz: Some(5.0),
                    ..Default::default()
                },
                |c| c.chirp.f_start_hz = 5.0,
            ),
            (
                ChirpRequest {
                    f_end_hz: Some(400.0),
                    ..Default::default()
                },
                |c| c.chirp.f_end_hz = 400.0,
            ),
            // A long sweep keeps the fades; a short one shrinks them.
            (
                ChirpRequest {
                    duration_s: Some(20.0),
                    ..Default::default()
                },
                |c| c.chirp.duration_s = Some(20.0),
            ),
            (
                ChirpRequest {
                    duration_s: Some(1.0),
                    ..Default::default()
                },
                |c| {
                    c.chirp.duration_s = Some(1.0);
                    c.chirp.taper_s = Some(0.25);
                },
            ),
        ];
        for (request, expect) in cases {
            let mut got = ch5();
            request.apply(&mut got).unwrap();
            let mut want = ch5();
            expect(&mut want);
            assert_eq!(got, want, "{request:?}");
        }
        // The seed is not a config value.
        let mut got = ch5();
        ChirpRequest {
            seed: Some(42),
            ..Default::default()
        }
        .apply(&mut got)
        .unwrap();
        assert_eq!(got, ch5());
    }

    #[test]
    fn control_fields_land_on_their_keys() {
        let with = |f: fn(&mut ControlRequest)| {
            let mut r = ControlRequest::new("fast");
            f(&mut r);
            r
        };
        let cases: [(ControlRequest, Expect); 5] = [
            (with(|r| r.step_m = Some(-5e-6)), |c| c.step.step_m = -5e-6),
            (with(|r| r.duration_s = Some(8.0)), |c| {
                c.step.duration_s = 8.0
            }),
            (with(|r| r.duration_s = Some(1.5)), |c| {
                c.step.duration_s = 1.5;
                c.step.steady_state_window_s = 0.75;
            }),
            (with(|r| r.smooth_s = Some(0.05)), |c| {
                c.step.smooth_s = 0.05
            }),
            // Not config values.
            (
                with(|r| {
                    r.seed = Some(7);
                    r.override_check = true;
                }),
                |_| {},
            ),
        ];
        for (request, expect) in cases {
            let mut got = ch5();
            assert_eq!(request.apply(&mut got).unwrap(), None);
            let mut want = ch5();
            expect(&mut want);
            assert_eq!(got, want, "{request:?}");
        }
        let mut got = ch5();
        let fault = with(|r| r.inject_fault = Some("jump@0.3".into()))
            .apply(&mut got)
            .unwrap();
        assert_eq!(
            fault,
            Some(ScheduledFault {
                at_s: 0.3,
                kind: FaultInjection::Jump(0.2e-3)
            })
        );
        assert_eq!(got, ch5());
    }

    /// `verify`: the defaults (10 % of `chirp.amplitude_a`, 10 s), the
    /// values given, their ranges, and neither without `verify`.
    #[test]
    fn verify_settings() {
        let cfg = ch5();
        let mut r = ControlRequest::new("fast");
        assert_eq!(r.verify_settings(&cfg).unwrap(), None);
        r.verify = true;
        assert_eq!(
            r.verify_settings(&cfg).unwrap(),
            Some(VerifySettings {
                amplitude_a: 0.05,
                duration_s: 10.0
            })
        );
        r.verify_amplitude_a = Some(0.2);
        r.verify_duration_s = Some(3.0);
        assert_eq!(
            r.verify_settings(&cfg).unwrap(),
            Some(VerifySettings {
                amplitude_a: 0.2,
                duration_s: 3.0
            })
        );
        let field = |r: &ControlRequest| match r.apply(&mut ch5()) {
            Err(RequestError::Field { field, .. }) => field,
            other => panic!("{r:?}: {other:?}"),
        };
        for a in [f64::NAN, -1.0, 0.0, 9.9e-5, 9.981, f64::INFINITY] {
            let mut bad = r.clone();
            bad.verify_amplitude_a = Some(a);
            assert_eq!(field(&bad), "verify_amplitude_a", "{a}");
        }
        for d in [f64::NAN, 0.0, 0.099, 600.1, -5.0] {
            let mut bad = r.clone();
            bad.verify_duration_s = Some(d);
            assert_eq!(field(&bad), "verify_duration_s", "{d}");
        }
        // A run beyond the job's tick budget: 600 s at 100 kHz.
        let mut fast_loop = ch5();
        fast_loop.loop_.rate_hz = 100_000.0;
        let mut long = r.clone();
        long.verify_duration_s = Some(600.0);
        assert!(matches!(
            long.verify_settings(&fast_loop),
            Err(RequestError::Field {
                field: "verify_duration_s",
                ..
            })
        ));
        r.verify = false;
        assert_eq!(field(&r), "verify_amplitude_a");
        // The wire form carries them; absent, they stay out.
        let wire = serde_json::to_value(JobRequest::Control(ControlRequest::new("fast"))).unwrap();
        assert_eq!(
            wire,
            json!({ "cmd": "control", "params": { "controller": "fast", "override_check": false } })
        );
        let v: ControlRequest = serde_json::from_value(
            json!({ "controller": "fast", "verify": true, "verify_amplitude_a": 0.1 }),
        )
        .unwrap();
        assert!(v.verify && v.verify_amplitude_a == Some(0.1));
    }

    #[test]
    fn local_overrides_land_on_their_keys() {
        let mut got = ch5();
        LocalOverrides {
            operating_point: Some(OperatingPoint::PercentOfBeamLength(5.0)),
            mass_asymmetry: Some(0.05),
            chirp_kind: Some(ChirpKind::Linear),
        }
        .apply(&mut got);
        let mut want = ch5();
        want.plant.operating_point_m = 0.05 * want.plant.beam.length_m;
        want.plant.mass_asymmetry = 0.05;
        want.chirp.kind = ChirpKind::Linear;
        assert_eq!(got, want);
        LocalOverrides {
            operating_point: Some(OperatingPoint::Metres(1e-3)),
            ..Default::default()
        }
        .apply(&mut got);
        assert_eq!(got.plant.operating_point_m, 1e-3);
    }

    /// A bad value is refused naming the config key it set.
    #[test]
    fn bad_values_name_the_key() {
        let chirp = |f: fn(&mut ChirpRequest)| {
            let mut r = ChirpRequest::default();
            f(&mut r);
            r.apply(&mut ch5()).unwrap_err()
        };
        let invalid = |key: &str, e: &RequestError| matches!(e, RequestError::Invalid { key: k, .. } if k == key);
        for (e, key) in [
            (chirp(|r| r.amplitude_a = Some(12.0)), "chirp.amplitude_a"),
            (chirp(|r| r.f_start_hz = Some(f64::NAN)), "chirp.f_start_hz"),
            (chirp(|r| r.f_end_hz = Some(2500.0)), "chirp.f_end_hz"),
            (chirp(|r| r.duration_s = Some(-3.0)), "chirp.duration_s"),
        ] {
            assert!(invalid(key, &e), "{key}: {e}");
            assert!(e.to_string().starts_with(key), "{e}");
        }
        let control = |f: fn(&mut ControlRequest)| {
            let mut r = ControlRequest::new("slow");
            f(&mut r);
            r.apply(&mut ch5()).unwrap_err()
        };
        for (e, key) in [
            (control(|r| r.step_m = Some(1e-3)), "step.step_m"),
            (control(|r| r.duration_s = Some(0.1)), "step.duration_s"),
            (control(|r| r.smooth_s = Some(-1.0)), "step.smooth_s"),
        ] {
            assert!(invalid(key, &e), "{key}: {e}");
        }
        let e = control(|r| r.controller = "nope".into());
        assert!(
            matches!(&e, RequestError::Field { field: "controller", value, reason }
                if value == "nope" && reason.contains("fast, slow")),
            "{e}"
        );
        let e = control(|r| r.inject_fault = Some("smoke@1".into()));
        assert!(
            matches!(&e, RequestError::Field { field: "inject_fault", reason, .. }
                if reason.contains("unknown kind")),
            "{e}"
        );
        for bad in ["nan", "nan@-1", "nan@x"] {
            assert!(parse_fault(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn unknown_fields_are_refused() {
        let e = serde_json::from_value::<ChirpRequest>(json!({ "amplitude": 0.1 })).unwrap_err();
        assert!(e.to_string().contains("amplitude"), "{e}");
        let e = serde_json::from_value::<ControlRequest>(
            json!({ "controller": "fast", "detach": true }),
        )
        .unwrap_err();
        assert!(e.to_string().contains("detach"), "{e}");
        let e = serde_json::from_value::<JobRequest>(
            json!({ "cmd": "control", "params": { "controller": "fast", "step": 1e-6 } }),
        )
        .unwrap_err();
        assert!(e.to_string().contains("step"), "{e}");
    }

    /// The daemon's wire form: `cmd` and `params`; absent fields stay out.
    #[test]
    fn wire_form() {
        let chirp = JobRequest::Chirp(ChirpRequest {
            duration_s: Some(3.0),
            ..Default::default()
        });
        let v = serde_json::to_value(&chirp).unwrap();
        assert_eq!(
            v,
            json!({ "cmd": "chirp", "params": { "duration_s": 3.0 } })
        );
        assert_eq!(serde_json::from_value::<JobRequest>(v).unwrap(), chirp);
        let control: ControlRequest =
            serde_json::from_value(json!({ "controller": "fast", "seed": null })).unwrap();
        assert_eq!(control, ControlRequest::new("fast"));
        assert_eq!(JobRequest::Control(control).kind(), "control");
    }
}
