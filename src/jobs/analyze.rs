//! `bench analyze` as a job: the model of one bench explained
//! ([`crate::analysis::analyze`]: modes, residues and their signs, the
//! sequence of dominant modes, the typed zeros, Chapter 4's three-mode
//! test), with the pole-zero map and the decomposed-mode Bode plot.
//!
//! An [`AnalyzeRequest`] is what `bench analyze`'s flags and the daemon's
//! `analyze` params say; with the PNG paths it makes the
//! [`AnalyzeOptions`] that [`run_analyze`] runs. Errors name the request
//! field (`operating_point_pct`) or the config, never a flag.

use super::point::PlantPoint;
use crate::analysis::{analyze, Analysis};
use crate::config::BenchConfig;
use crate::error::RunError;
use crate::jobs::request::RequestError;
use crate::outputs::{beside, Destination, Existing, Origin, OutputPlan};
use crate::plot::{write_decomposed_bode_png, write_pole_zero_png};
use bench_plant::model::{Sr4dof, Sr4dofParams};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// An analysis (`bench analyze`, the daemon's `analyze`): the config's
/// bench, its operating point and asymmetry replaced by those of `point`
/// that are given (`{"point": {"operating_point_pct": 6}}`). A path is
/// read by the process that runs the job: the daemon takes absolute paths
/// only.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnalyzeRequest {
    /// Bench config (TOML); absent: the built-in bench.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub config: Option<PathBuf>,
    /// The operating point and asymmetry; absent fields: the config's.
    #[serde(default, skip_serializing_if = "PlantPoint::is_empty")]
    pub point: PlantPoint,
    /// Write no PNG.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub no_plots: bool,
}

impl AnalyzeRequest {
    /// The config's name in messages and the summary: its path, or
    /// [`crate::config::BUILTIN_CONFIG_NAME`].
    pub fn config_name(&self) -> String {
        self.config
            .as_ref()
            .map_or(crate::config::BUILTIN_CONFIG_NAME.to_string(), |p| {
                p.display().to_string()
            })
    }

    /// The bench to analyse: the config's plant with the point applied and
    /// checked.
    ///
    /// # Errors
    /// [`RunError::BadInput`] for a config that does not load or a plant
    /// it refuses; [`RunError::BadOption`] naming the point field that
    /// set a value out of range.
    pub fn plant(&self) -> Result<Sr4dofParams, RunError> {
        let cfg = match &self.config {
            Some(p) => BenchConfig::load(p),
            None => BenchConfig::builtin(),
        }
        .map_err(super::config_error)?;
        let point = self.point;
        point.check().map_err(field_error)?;
        let mut p = cfg.plant;
        point.apply(&mut p);
        if let Err(e) = p.validate("plant") {
            return Err(match point.field_for(&e.key) {
                Some(field) => RunError::option(field, "", e.reason),
                None => RunError::BadInput(format!("{}: {e}", self.config_name())),
            });
        }
        Ok(p)
    }
}

/// A point field's refusal as a run option's.
pub(super) fn field_error(e: RequestError) -> RunError {
    match e {
        RequestError::Field {
            field,
            value,
            reason,
        } => RunError::option(field, value, reason),
        RequestError::Invalid { key, reason } => RunError::BadInput(format!("{key}: {reason}")),
    }
}

/// An analysis to run: the request and its PNGs.
#[derive(Debug, Clone, Default)]
pub struct AnalyzeOptions {
    /// What to analyse.
    pub request: AnalyzeRequest,
    /// The pole-zero map PNG (1400 × 1000); `None`: none.
    pub pole_zero_png: Option<PathBuf>,
    /// The decomposed-mode Bode PNG; `None`: none.
    pub modes_png: Option<PathBuf>,
    /// What to do with an existing PNG (`--overwrite`; the daemon always
    /// refuses).
    pub existing: Existing,
}

/// The analysis of `request` with its PNGs where `dest` puts them (none
/// with `no_plots`): locally the flags' paths (`--pole-zero-png`,
/// `--modes-png`), else one stamped name `analyze-<stamp>` in the default
/// recordings directory for both; on the daemon its stamped names. The
/// command line and the daemon both plan an analysis here.
///
/// # Errors
/// The request's bench refused ([`AnalyzeRequest::plant`]), checked
/// before a default name is made (and the recordings directory with it);
/// [`RunError::BadOption`] naming a PNG when it needs a default name and
/// there is no default recordings directory.
pub fn plan_analyze(
    request: AnalyzeRequest,
    dest: &Destination,
) -> Result<AnalyzeOptions, RunError> {
    request.plant()?;
    let (mut pole_zero_png, mut modes_png) = (None, None);
    if !request.no_plots {
        // One stamp for both default names.
        let mut stem: Option<PathBuf> = None;
        let mut named = |name: &'static str, suffix: &str| {
            dest.output(name, suffix, || {
                let s = match &stem {
                    Some(s) => s.clone(),
                    None => stem.insert(dest.stem("analyze", name)?).clone(),
                };
                Ok(beside(&s, suffix))
            })
            .map(|(path, _)| path)
        };
        pole_zero_png = Some(named("pole_zero_png", ".pole-zero.png")?);
        modes_png = Some(named("modes_png", ".modes.png")?);
    }
    Ok(AnalyzeOptions {
        request,
        pole_zero_png,
        modes_png,
        existing: dest.existing(),
    })
}

/// The result of `bench analyze`.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct AnalyzeSummary {
    /// Where the bench came from (a path, or the built-in's name).
    pub config: String,
    /// Beam length L, m.
    pub beam_length_m: f64,
    /// The analysis.
    #[serde(flatten)]
    pub analysis: Analysis,
    /// The pole-zero map written (absolute path).
    pub pole_zero_png: Option<String>,
    /// The decomposed-mode plot written (absolute path).
    pub modes_png: Option<String>,
}

/// `p` as an absolute path, for summaries.
pub(super) fn absolute(p: &Path) -> String {
    std::path::absolute(p)
        .unwrap_or_else(|_| p.to_path_buf())
        .display()
        .to_string()
}

/// Analyses the bench of `opts.request` and writes the PNGs asked for.
///
/// # Errors
/// As [`AnalyzeRequest::plant`]; [`RunError::BadInput`] for a bench the
/// model refuses; [`RunError::Output`] when a PNG cannot be written.
pub fn run_analyze(opts: &AnalyzeOptions) -> Result<AnalyzeSummary, RunError> {
    let req = &opts.request;
    let params = req.plant()?;
    let model = Sr4dof::new(params)
        .map_err(|e| RunError::BadInput(format!("{}: {e}", req.config_name())))?;
    // The output rules (crate::outputs), checked before anything is
    // computed: never the config read.
    let mut plan = OutputPlan::new(opts.existing);
    if let Some(p) = &opts.pole_zero_png {
        plan = plan.with_output("pole_zero_png", p, Origin::Given);
    }
    if let Some(p) = &opts.modes_png {
        plan = plan.with_output("modes_png", p, Origin::Given);
    }
    if let Some(c) = &req.config {
        plan = plan.with_input("config", c);
    }
    plan.check()?;
    let a = analyze(&model);
    let what = format!(
        "Y1o = {:.3} mm ({:.2} % of L), Δm23 = {:+.1} %",
        a.operating_point_m * 1e3,
        a.operating_point_m / params.beam.length_m * 100.0,
        a.mass_asymmetry * 100.0
    );
    let plot_failed = |path: &Path, e: crate::plot::PlotError| RunError::Output {
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    if let Some(path) = &opts.pole_zero_png {
        let verdict = match (a.cnmp, a.cnmp_damped) {
            (_, true) => "CMP-CNMP zeros",
            (true, false) => "CMP-CNMP zeros in the undamped model only",
            (false, false) => "no CMP-CNMP zeros",
        };
        let title = format!("Poles and zeros, force → x1 — {what}: {verdict}");
        write_pole_zero_png(
            path,
            opts.existing,
            &title,
            &model,
            &a.zeros_damped,
            &a.modes,
        )
        .map_err(|e| plot_failed(path, e))?;
    }
    if let Some(path) = &opts.modes_png {
        let title = format!("Decomposed modes {} — {what}", a.sequence);
        write_decomposed_bode_png(path, opts.existing, &title, &a.modes)
            .map_err(|e| plot_failed(path, e))?;
    }
    Ok(AnalyzeSummary {
        config: req.config_name(),
        beam_length_m: params.beam.length_m,
        analysis: a,
        pole_zero_png: opts.pole_zero_png.as_deref().map(absolute),
        modes_png: opts.modes_png.as_deref().map(absolute),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_out_of_range_names_its_field() {
        for (r, key) in [
            (
                PlantPoint {
                    operating_point_pct: Some(25.0),
                    ..Default::default()
                },
                "operating_point_pct",
            ),
            (
                PlantPoint {
                    mass_asymmetry: Some(0.9),
                    ..Default::default()
                },
                "mass_asymmetry",
            ),
        ] {
            let r = AnalyzeRequest {
                point: r,
                ..Default::default()
            };
            match r.plant() {
                Err(RunError::BadOption { key: k, .. }) => assert_eq!(k, key),
                other => panic!("{r:?}: {other:?}"),
            }
        }
        let point = PlantPoint {
            operating_point_pct: Some(6.0),
            mass_asymmetry_pct: Some(4.0),
            ..Default::default()
        };
        let p = AnalyzeRequest {
            point,
            ..Default::default()
        }
        .plant()
        .unwrap();
        assert_eq!(p.operating_point_m, 6.0 / 100.0 * p.beam.length_m);
        assert_eq!(p.mass_asymmetry, 0.04);
    }

    /// The summary reads back as it was written (the daemon's answer is
    /// printed by the client from it).
    #[test]
    fn the_summary_round_trips() {
        let s = run_analyze(&AnalyzeOptions::default()).unwrap();
        let v = serde_json::to_value(&s).unwrap();
        let back: AnalyzeSummary = serde_json::from_value(v.clone()).unwrap();
        assert_eq!(serde_json::to_value(&back).unwrap(), v);
    }
}
