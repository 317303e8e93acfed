//! The request of `bench track` (and of the daemon's `track` job): what
//! its flags or a request's `params` say, and the one place they become
//! [`TrackOptions`] ([`TrackRequest::options`]): the model and the
//! reference read, the fault parsed, the scan built. Its errors name the
//! request's field (`amplitude_m`); the CLI names it as its flag
//! (`--amplitude-m`), the daemon as `params.amplitude_m`.

use super::request::{parse_fault, Pace};
use super::track::{read_reference, trajectory_name, TrackOptions};
use crate::config::BenchConfig;
use crate::error::RunError;
use crate::rt::backend::BackendSpec;
use crate::track::{FeedforwardKind, MoveLimits, Scan, ScanKind};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub use crate::config::SnapLimit;

/// A move's peak velocity by default, m/s.
pub const DEFAULT_MAX_VELOCITY_M_S: f64 = 1e-3;
/// A move's peak acceleration by default, m/s².
pub const DEFAULT_MAX_ACCELERATION_M_S2: f64 = 0.1;
/// A move's peak jerk by default, m/s³.
pub const DEFAULT_MAX_JERK_M_S3: f64 = 40.0;
/// A move's peak snap by default, m/s⁴.
pub const DEFAULT_MAX_SNAP_M_S4: f64 = 2e4;
/// The band a move settles into by default, ± m.
pub const DEFAULT_SETTLE_BAND_M: f64 = 10e-9;
/// A scan's amplitude by default, m.
pub const DEFAULT_AMPLITUDE_M: f64 = 5e-6;
/// A scan's line rate by default, Hz.
pub const DEFAULT_LINE_RATE_HZ: f64 = 10.0;
/// Learning trials at most by default.
pub const DEFAULT_TRIALS: u32 = 10;
/// The learning gain α by default.
pub const DEFAULT_LEARNING_GAIN: f64 = 0.7;
/// Measured lines per trial by default.
pub const DEFAULT_PERIODS: u32 = 5;

/// A tracking run (`bench track`, the daemon's `track`). Every field is
/// optional: absent, the default of `bench track --help` holds. Paths
/// are the daemon's (absolute there).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrackRequest {
    /// The controller: `slow`, `fast` or any `[controller.NAME]` of the
    /// config [default: `fast`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub controller: Option<String>,
    /// A bench config whose `[plant]` is the model of the feedforward and
    /// the learning ([`TrackOptions::model`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<PathBuf>,
    /// A learned table to replay ([`TrackOptions::feedforward`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub feedforward: Option<PathBuf>,
    /// A `bench control --verify` recording whose PS the learning filter
    /// inverts ([`TrackOptions::learning_ps`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub learning_ps: Option<PathBuf>,
    /// The scan [default: triangle].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scan: Option<ScanKind>,
    /// The line of `scan` `csv` ([`read_reference`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<PathBuf>,
    /// Amplitude about the start (a move's distance), m [default: 5e-6;
    /// a CSV's own].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub amplitude_m: Option<f64>,
    /// Lines per second, Hz [default: 10; a CSV's own].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub line_rate_hz: Option<f64>,
    /// The harmonics' cut-off, Hz [default: the plan's].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cutoff_hz: Option<f64>,
    /// The feedforward trial's feedforward [default: inverse].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub feedforward_kind: Option<FeedforwardKind>,
    /// A move's peak velocity, m/s [default: 1e-3].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_velocity_m_s: Option<f64>,
    /// A move's peak acceleration, m/s² [default: 0.1].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_acceleration_m_s2: Option<f64>,
    /// A move's peak jerk, m/s³ [default: 40].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_jerk_m_s3: Option<f64>,
    /// A move's peak snap [default: 2e4 m/s⁴].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_snap_m_s4: Option<SnapLimit>,
    /// The band a move settles into, ± m [default: 1e-8].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub settle_band_m: Option<f64>,
    /// Learning trials at most [default: 10].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trials: Option<u32>,
    /// The learning gain α [default: 0.7].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub learning_gain: Option<f64>,
    /// Measured lines per trial [default: 5].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub periods: Option<u32>,
    /// Simulator noise seed [default: the runner's].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// A simulator fault, `KIND@T_S` from the first trial's start.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inject_fault: Option<String>,
    /// Pacing on the daemon's simulator, as
    /// [`super::request::ChirpRequest::pace`] (the CLI has `--realtime`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pace: Option<Pace>,
}

/// Where a track request runs: what the runner (the CLI or the daemon)
/// supplies beside the request.
#[derive(Debug, Clone)]
pub struct TrackRunner {
    /// The validated bench config and where it came from.
    pub config: (BenchConfig, PathBuf),
    /// The output directory.
    pub out_dir: PathBuf,
    /// The backend (`None`: the config's `[backend]`).
    pub backend: Option<BackendSpec>,
    /// Real-time pacing asked for (hardware always).
    pub realtime: bool,
    /// A factor of real time for virtual time on a simulator.
    pub pace: Option<f64>,
    /// Replace existing outputs.
    pub overwrite: bool,
    /// The seed when the request gives none.
    pub seed: u64,
}

impl TrackRequest {
    /// The controller named, `fast` by default.
    pub fn controller(&self) -> String {
        self.controller
            .clone()
            .unwrap_or_else(|| "fast".to_string())
    }

    /// The request as the options of [`super::track::run_track`]: the
    /// model config loaded, the fault parsed, a CSV reference read (at
    /// the config's loop rate), the scan built.
    ///
    /// # Errors
    /// [`RunError::BadInput`] for a bench config with a key out of its
    /// range (naming it); [`RunError::BadOption`] naming the field: a
    /// `model` that does not load or validate; an `inject_fault` that does not parse; `scan` `csv` without
    /// `reference`, `reference` with another scan, or a table
    /// [`read_reference`] refuses; `amplitude_m` given with a CSV;
    /// `line_rate_hz` given with a CSV and not the one its rows make.
    /// The ranges of every other field are checked when the run plans
    /// ([`super::track::run_track`]).
    pub fn options(&self, runner: TrackRunner) -> Result<TrackOptions, RunError> {
        // Every key of the bench config in its range before anything uses
        // it (the supervisor's limits, the loop, the trajectory).
        runner
            .config
            .0
            .validate(&runner.config.1)
            .map_err(super::config_error)?;
        let (req, filled) = self.with_trajectory(&runner.config.0, &runner.config.1);
        let mut opts = req.options_as_given(runner)?;
        opts.from_trajectory = filled;
        Ok(opts)
    }

    /// The request with the config's `[trajectory]` filling the fields it
    /// leaves out, and the fields so filled. A key applies only where it
    /// can: `reference` with a csv scan (the config's), `amplitude_m` and
    /// `line_rate_hz` with any other; a relative `reference` is taken
    /// from the config file's directory.
    pub fn with_trajectory(
        &self,
        cfg: &BenchConfig,
        config_path: &Path,
    ) -> (TrackRequest, Vec<&'static str>) {
        let t = &cfg.trajectory;
        let mut r = self.clone();
        let mut filled = Vec::new();
        // The key fills a field the request left out, where it applies.
        fn fill<T: Clone>(
            filled: &mut Vec<&'static str>,
            name: &'static str,
            field: &mut Option<T>,
            key: Option<&T>,
        ) {
            if let (None, Some(v)) = (&field, key) {
                *field = Some(v.clone());
                filled.push(name);
            }
        }
        fill(&mut filled, "scan", &mut r.scan, t.scan.as_ref());
        let csv = r.scan == Some(ScanKind::Csv);
        let dir = config_path
            .parent()
            .filter(|_| config_path != Path::new(crate::config::BUILTIN_CONFIG_NAME));
        let reference = t
            .reference
            .as_ref()
            .filter(|_| csv && t.scan == Some(ScanKind::Csv))
            .map(|p| dir.map_or_else(|| p.clone(), |d| d.join(p)));
        fill(
            &mut filled,
            "reference",
            &mut r.reference,
            reference.as_ref(),
        );
        let not_csv = |v: &Option<f64>| v.filter(|_| !csv);
        fill(
            &mut filled,
            "amplitude_m",
            &mut r.amplitude_m,
            not_csv(&t.amplitude_m).as_ref(),
        );
        fill(
            &mut filled,
            "line_rate_hz",
            &mut r.line_rate_hz,
            not_csv(&t.line_rate_hz).as_ref(),
        );
        fill(
            &mut filled,
            "cutoff_hz",
            &mut r.cutoff_hz,
            t.cutoff_hz.as_ref(),
        );
        fill(
            &mut filled,
            "max_velocity_m_s",
            &mut r.max_velocity_m_s,
            t.max_velocity_m_s.as_ref(),
        );
        fill(
            &mut filled,
            "max_acceleration_m_s2",
            &mut r.max_acceleration_m_s2,
            t.max_acceleration_m_s2.as_ref(),
        );
        fill(
            &mut filled,
            "max_jerk_m_s3",
            &mut r.max_jerk_m_s3,
            t.max_jerk_m_s3.as_ref(),
        );
        fill(
            &mut filled,
            "max_snap_m_s4",
            &mut r.max_snap_m_s4,
            t.max_snap_m_s4.as_ref(),
        );
        fill(
            &mut filled,
            "settle_band_m",
            &mut r.settle_band_m,
            t.settle_band_m.as_ref(),
        );
        (r, filled)
    }

    /// How an error names field `key`: as `trajectory.KEY` of the config
    /// when the config's `[trajectory]` gave it, else by `field` (the
    /// CLI's flag, the daemon's `params.KEY`).
    pub fn name_of(
        &self,
        cfg: &BenchConfig,
        config_path: &Path,
        key: &str,
        field: impl FnOnce(&str) -> String,
    ) -> String {
        let (_, filled) = self.with_trajectory(cfg, config_path);
        trajectory_name(&filled, config_path, key, field)
    }

    /// [`Self::options`] of the request as it stands (no `[trajectory]`).
    fn options_as_given(&self, runner: TrackRunner) -> Result<TrackOptions, RunError> {
        let (cfg, config_path) = runner.config;
        let model = self
            .model
            .as_ref()
            .map(|p| {
                BenchConfig::load(p)
                    .and_then(|c| c.validate(p).map(|()| c))
                    .map(|c| (c, p.clone()))
                    .map_err(|e| RunError::option("model", p.display(), e.to_string()))
            })
            .transpose()?;
        let inject_fault = self
            .inject_fault
            .as_deref()
            .map(|f| parse_fault(f).map_err(|e| RunError::option("inject_fault", f, e)))
            .transpose()?;
        let kind = self.scan.unwrap_or(ScanKind::Triangle);
        let (reference, amplitude_m, line_rate_hz) = self.scan_line(kind, &cfg)?;
        let snap = self
            .max_snap_m_s4
            .unwrap_or(SnapLimit::Limit(DEFAULT_MAX_SNAP_M_S4));
        Ok(TrackOptions {
            seed: self.seed.unwrap_or(runner.seed),
            config: cfg,
            config_path,
            controller: self.controller(),
            scan: Scan {
                kind,
                amplitude_m,
                line_rate_hz,
                cutoff_hz: f64::NAN,
                move_limits: (kind == ScanKind::Move).then_some(MoveLimits {
                    velocity_m_s: self.max_velocity_m_s.unwrap_or(DEFAULT_MAX_VELOCITY_M_S),
                    acceleration_m_s2: self
                        .max_acceleration_m_s2
                        .unwrap_or(DEFAULT_MAX_ACCELERATION_M_S2),
                    jerk_m_s3: self.max_jerk_m_s3.unwrap_or(DEFAULT_MAX_JERK_M_S3),
                    snap_m_s4: snap.limit(),
                }),
                reference_csv: self.reference.clone(),
                reference,
            },
            settle_band_m: self.settle_band_m.unwrap_or(DEFAULT_SETTLE_BAND_M),
            feedforward_kind: self.feedforward_kind.unwrap_or(FeedforwardKind::Inverse),
            cutoff_hz: self.cutoff_hz,
            trials: self.trials.unwrap_or(DEFAULT_TRIALS),
            learning_gain: self.learning_gain.unwrap_or(DEFAULT_LEARNING_GAIN),
            periods: self.periods.unwrap_or(DEFAULT_PERIODS),
            out_dir: runner.out_dir,
            backend: runner.backend,
            realtime: runner.realtime,
            pace: runner.pace,
            overwrite: runner.overwrite,
            model,
            feedforward: self.feedforward.clone(),
            learning_ps: self.learning_ps.clone(),
            inject_fault,
            from_trajectory: Vec::new(),
        })
    }

    /// The reference line of a CSV scan and the scan's amplitude and line
    /// rate: a CSV's own (its peak and `loop.rate_hz / rows`), else the
    /// request's or their defaults.
    fn scan_line(
        &self,
        kind: ScanKind,
        cfg: &BenchConfig,
    ) -> Result<(Option<Vec<f64>>, f64, f64), RunError> {
        match (kind, &self.reference) {
            (ScanKind::Csv, Some(p)) => {
                let (x, line_rate_hz) = read_reference(p, cfg)?;
                if let Some(a) = self.amplitude_m {
                    return Err(RunError::option(
                        "amplitude_m",
                        a,
                        "a csv scan's reference has its own amplitude: leave it out",
                    ));
                }
                if let Some(l) = self
                    .line_rate_hz
                    .filter(|l| (l / line_rate_hz - 1.0).abs() > 1e-9)
                {
                    return Err(RunError::option(
                        "line_rate_hz",
                        l,
                        format!(
                            "the reference's {} rows at loop.rate_hz {} make a line rate of {line_rate_hz} Hz",
                            x.len(),
                            cfg.loop_.rate_hz
                        ),
                    ));
                }
                let peak = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                Ok((Some(x), peak, line_rate_hz))
            }
            (ScanKind::Csv, None) => Err(RunError::option(
                "reference",
                "",
                "a csv scan needs a reference (FILE.csv), the line to track",
            )),
            (_, Some(p)) => Err(RunError::option(
                "reference",
                p.display(),
                "is the line of a csv scan only",
            )),
            (_, None) => Ok((
                None,
                self.amplitude_m.unwrap_or(DEFAULT_AMPLITUDE_M),
                self.line_rate_hz.unwrap_or(DEFAULT_LINE_RATE_HZ),
            )),
        }
    }

    /// The request's input files (for the daemon's absolute-path check),
    /// each with its field.
    pub fn inputs(&self) -> [(&'static str, Option<&Path>); 4] {
        [
            ("model", self.model.as_deref()),
            ("feedforward", self.feedforward.as_deref()),
            ("learning_ps", self.learning_ps.as_deref()),
            ("reference", self.reference.as_deref()),
        ]
    }
}
