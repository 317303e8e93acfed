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
pub use super::catalogue::CatalogueRequest;
pub use super::design::DesignRequest;
pub use super::export::ExportRequest;
pub use super::fit::FitRequest;
pub use super::map::MapRequest;
pub use super::plot::PlotRequest;
pub use super::point::OperatingPoint;
pub use super::recover::RecoverRequest;
pub use super::track_request::{SnapLimit, TrackRequest};
use super::verify::{DEFAULT_AMPLITUDE_OF_CHIRP, DEFAULT_DURATION_S};
use crate::config::{ranges, BenchConfig, ExcitationKind};
use bench_plant::sim::{FaultInjection, ScheduledFault};
use serde::{Deserialize, Serialize};

mod values;
pub use values::*;

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
    /// `bench campaign run --daemon`.
    Campaign(CampaignRequest),
    /// `bench catalogue`.
    Catalogue(CatalogueRequest),
    /// `bench export`.
    Export(ExportRequest),
    /// `bench recover`.
    Recover(RecoverRequest),
    /// `bench upload`.
    Upload(UploadRequest),
    /// `bench track`.
    Track(TrackRequest),
}

impl JobRequest {
    /// Every job kind, as the daemon's `cmd`.
    pub const KINDS: [&'static str; 13] = [
        "chirp",
        "control",
        "fit",
        "design",
        "analyze",
        "map",
        "plot",
        "campaign",
        "catalogue",
        "export",
        "recover",
        "upload",
        "track",
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
            Self::Catalogue(_) => "catalogue",
            Self::Export(_) => "export",
            Self::Recover(_) => "recover",
            Self::Upload(_) => "upload",
            Self::Track(_) => "track",
        }
    }

    /// Whether the job drives the bench (chirp, control, track): it runs
    /// on the real-time loop and makes recordings. The others compute
    /// from files and the model and never touch the bench.
    pub fn uses_bench(&self) -> bool {
        matches!(self, Self::Chirp(_) | Self::Control(_) | Self::Track(_))
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
    /// shrinks to at most a quarter of it. Refused with `excitation.kind =
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
            // With excitation.kind = "multisine" the check below refuses it,
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

/// `bench upload` as a job request (the daemon's `upload`): finished
/// recordings, with their companions and catalogue rows, to a store. The
/// store's credentials are the runner's (the daemon's environment).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UploadRequest {
    /// The store: `s3://BUCKET[/PREFIX]` or `file:///DIRECTORY` (`--to`).
    pub to: String,
    /// Finished recordings (`*.mcap`) or campaign directories (the daemon
    /// takes absolute paths).
    pub recordings: Vec<std::path::PathBuf>,
    /// How long a failing store is retried, s (`--retry-for`, 0 to a
    /// day); `None`: the runner's default (60 s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub retry_for_s: Option<f64>,
    /// How long the store has to connect and to answer each request, s
    /// (`--store-timeout`, 0.5 to 300); `None`: the default (10 s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub store_timeout_s: Option<f64>,
}

/// A campaign (`bench campaign run --daemon`, the daemon's `campaign`): a
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
    /// What `bench chirp` plays (`excitation.kind`). The keys of the other
    /// kind are set aside with it, as the flag asks: a multisine drops
    /// the sweep's `chirp.duration_s` and `chirp.taper_s` (and takes the
    /// `[multisine]` table, or its defaults); a sweep drops the
    /// `[multisine]` table, needs a `chirp.duration_s` (the config's or
    /// `--duration-s`) and fades by the config's `chirp.taper_s`, 0 s
    /// (none) when the config has none.
    pub excitation: Option<ExcitationKind>,
}

impl LocalOverrides {
    /// Writes the overrides into `cfg`. It does not check: apply the job
    /// request after it, which checks the whole config.
    pub fn apply(&self, cfg: &mut BenchConfig) {
        if let Some(op) = self.operating_point {
            cfg.plant.operating_point_m = op.metres(cfg.plant.beam.length_m);
        }
        set(&mut cfg.plant.mass_asymmetry, self.mass_asymmetry);
        if let Some(kind) = self.excitation {
            cfg.excitation.kind = kind;
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

#[cfg(test)]
mod tests;
