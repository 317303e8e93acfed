//! `bench design` as a job: read the input FRFs (CSV, recordings, the done
//! cells of campaign directories), identify their modes, design the
//! controller ([`crate::design`]), predict it on the bench's model, and
//! write the bench config with the new `[controller.NAME]` and the figure.
//!
//! A [`DesignRequest`] is what `bench design`'s flags and the daemon's
//! `design` params say. Campaign directories are expanded into their cells
//! by the caller ([`DesignInput::Cells`]; the campaign layer reads its own
//! journal). Errors are [`RunError::BadOption`] naming the request field
//! (`inputs`, `config`, `name`, `pm_min_deg`, `gm_min_db`, `s_max`,
//! `computation_delay_s`, `out`, `png`) or [`RunError::BadInput`] for
//! margins no controller of the family meets (exit 2, nothing written).

use crate::config::{BenchConfig, BUILTIN_CONFIG_TOML};
use crate::control::ControllerConfig;
use crate::design::ceiling::{bench_limit, ClimbLines, LimitReport};
use crate::design::fitted::FittedPlant;
use crate::design::limit::loop_performance_bandwidth_rad_s;
use crate::design::loops::LoopFigures;
use crate::design::modes::PlantModes;
use crate::design::predict::{model_frf_on, predict_on, BenchModel, ModelPrediction};
use crate::design::search::{Binding, Requirements};
use crate::design::sigma::{figure_sigmas, performance_bandwidth_sigma, FigureSigmas};
use crate::design::{design, prepare, DesignError, DesignSpec, InputFrf, InputUse, Strategy};
use crate::error::RunError;
use crate::ident::frf::{read_frf, Frf};
use crate::ident::modal_fit::Path as FitPath;
use crate::input_file::{read, read_to_string, Kind};
use crate::outputs::{beside, write_atomically, Destination, Existing, Origin, OutputPlan};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Default `pm_min_deg`, degrees.
pub const PM_MIN_DEG: f64 = 40.0;
/// Default `gm_min_db`, dB.
pub const GM_MIN_DB: f64 = 6.0;
/// Default `s_max` (a 6 dB modulus margin).
pub const S_MAX: f64 = 2.0;
/// Default controller name.
pub const NAME: &str = "designed";

/// A design (`bench design`, the daemon's `design`). Paths are read by
/// the process that runs the job: the daemon takes absolute paths only.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DesignRequest {
    /// The FRFs: `bench chirp` CSVs, recordings (`.mcap`, `.mcap.part`)
    /// or campaign directories (all their done cells).
    pub inputs: Vec<PathBuf>,
    /// Bench config (TOML): the loop period, the amplifier, the model of
    /// the prediction, and the bench the designed controller is added to.
    /// Absent: the config the first recording holds, else the first
    /// campaign's, else the built-in bench.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub config: Option<PathBuf>,
    /// `slow`, `fast` or `auto` (default).
    #[serde(default = "auto")]
    pub strategy: Strategy,
    /// Phase margin at every crossover, degrees (default 40).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pm_min_deg: Option<f64>,
    /// Gain margin, dB (default 6).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gm_min_db: Option<f64>,
    /// Largest ‖S‖∞ (default 2).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub s_max: Option<f64>,
    /// Computation delay added to every FRF, s (default one loop period).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub computation_delay_s: Option<f64>,
    /// Longest 2 % settling of the step predicted on the model, s: among
    /// the search's candidates that meet the margins, the highest ω_B that
    /// settles within it (default: no limit, the highest ω_B).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub settling_max_s: Option<f64>,
    /// Name of the controller (`[controller.NAME]`; default `designed`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// The model predicted and certified on besides the measured lines:
    /// `fit` (default: each input's modal fit, the bench's own model) or
    /// `config` (the config's lumped model, only when asked).
    #[serde(default)]
    pub model: ModelChoice,
    /// Write no figure.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub no_plot: bool,
}

fn auto() -> Strategy {
    Strategy::Auto
}

/// Which model a design predicts and certifies on (`--model`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelChoice {
    /// Each input's modal fit (the bench's own model).
    #[default]
    Fit,
    /// The config's lumped model (thesis Eq. 2-5): a nominal description,
    /// not the bench measured.
    Config,
}

impl std::str::FromStr for ModelChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "fit" => Ok(Self::Fit),
            "config" => Ok(Self::Config),
            _ => Err(format!("`{s}` is not a model: fit or config")),
        }
    }
}

impl Default for DesignRequest {
    fn default() -> Self {
        Self {
            inputs: vec![],
            config: None,
            strategy: Strategy::Auto,
            pm_min_deg: None,
            gm_min_db: None,
            s_max: None,
            computation_delay_s: None,
            settling_max_s: None,
            name: None,
            model: ModelChoice::Fit,
            no_plot: false,
        }
    }
}

/// One input as the job reads it.
#[derive(Debug, Clone, PartialEq)]
pub enum DesignInput {
    /// A CSV or a recording.
    File(PathBuf),
    /// A campaign directory's done cells.
    Cells {
        /// The directory.
        dir: PathBuf,
        /// Its bench config's text (`bench.toml`).
        config_toml: String,
        /// `(cell index, its frf.csv)`.
        cells: Vec<(usize, PathBuf)>,
    },
}

/// A design to run: the request, its inputs resolved, where outputs go.
#[derive(Debug, Clone)]
pub struct DesignOptions {
    /// What to design.
    pub request: DesignRequest,
    /// The inputs (campaign directories expanded), in request order.
    pub inputs: Vec<DesignInput>,
    /// The bench config written; `None`: beside the first input,
    /// `<stem>.designed.toml` (a campaign: `DIR/designed.toml`).
    pub out: Option<PathBuf>,
    /// The figure; `None`: beside `out`, `<stem>.png`.
    pub png: Option<PathBuf>,
    /// What to do with existing outputs.
    pub existing: Existing,
}

/// The design of `request` on `inputs` (its paths, campaign directories
/// expanded: [`crate::campaign::job::design_inputs`]) with its outputs
/// where `dest` puts them: locally the flags' paths (`--out`, `--png`;
/// [`run_design`] names the others beside the first input), on the
/// daemon its stamped names (the figure unless `no_plot`). The command
/// line and the daemon both plan a design here.
pub fn plan_design(
    request: DesignRequest,
    inputs: Vec<DesignInput>,
    dest: &Destination,
) -> DesignOptions {
    DesignOptions {
        png: dest.optional("png", !request.no_plot, |stem| beside(stem, ".design.png")),
        out: dest.optional("out", true, |stem| beside(stem, ".designed.toml")),
        request,
        inputs,
        existing: dest.existing(),
    }
}

/// Figures of the design on one input.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct InputFigures {
    /// The input.
    pub input: String,
    /// Its loop figures.
    pub figures: LoopFigures,
    /// The performance bandwidth ω* on its lines, rad/s (`null`: |S|
    /// passes M on a line).
    pub performance_bandwidth_rad_s: Option<f64>,
    /// The 1σ of its figures from the FRF's noise (first order).
    pub sigma: FigureSigmas,
}

/// What [`evaluation_figures`] gives.
struct EvaluationFigures {
    /// ω* over the inputs' lines and the models' grids, rad/s (`None`
    /// where |S| passes M).
    performance_bandwidth_rad_s: Option<f64>,
    /// Each input's ω*, rad/s.
    per_input_rad_s: Vec<Option<f64>>,
    /// Each input's 1σ.
    per_input_sigma: Vec<FigureSigmas>,
    /// The 1σ of the figures over the inputs.
    sigma: FigureSigmas,
}

/// What [`evaluation_figures`] reads a controller's figures on: the
/// inputs and the models with their relative 1σ, and the loop.
#[derive(Clone, Copy)]
struct FiguresOn<'a> {
    frfs: &'a [crate::design::loops::DesignFrf],
    models: &'a [crate::design::loops::DesignFrf],
    relative_sigma: &'a [Vec<f64>],
    model_relative_sigma: &'a [Vec<f64>],
    /// s.
    computation_delay_s: f64,
    /// s.
    period_s: f64,
    /// A.
    peak_current_a: f64,
    /// M of W_P.
    s_max: f64,
}

/// The figures of `e`'s controller (discrete at `period_s` with
/// `peak_current_a`) and their 1σ. ω* (`M = s_max`) on every input's lines
/// and on every model's grid from the lowest measured line up (below it a
/// model only extrapolates the fit), each with the computation delay
/// `computation_delay_s` and without it, as the certificate reads it
/// ([`crate::design::search::Evaluation::objective_rad_s`]): the least,
/// rad/s (`None` where |S| passes M), and each input's. The 1σ from each
/// input's relative line noise `relative_sigma` (first order,
/// [`crate::design::sigma`]) and each model's `model_relative_sigma` (the
/// fit's covariance; NaN: unknown): each input's, and those of the
/// figures over the inputs, each from the input or model that sets it.
/// All `None` for an evaluation without figures (a strategy refused
/// before its certificate).
fn evaluation_figures(
    on: &FiguresOn<'_>,
    e: &crate::design::search::Evaluation,
) -> EvaluationFigures {
    let FiguresOn {
        frfs,
        models,
        relative_sigma,
        model_relative_sigma,
        computation_delay_s,
        period_s,
        peak_current_a,
        s_max,
    } = *on;
    if e.figures.len() < frfs.len() {
        // A strategy refused before it was certified: no figures to read.
        let n = frfs.len();
        return EvaluationFigures {
            performance_bandwidth_rad_s: None,
            per_input_rad_s: vec![None; n],
            per_input_sigma: vec![FigureSigmas::default(); n],
            sigma: FigureSigmas::default(),
        };
    }
    let ctrl = crate::control::DiscreteController::new(&e.controller, period_s, peak_current_a);
    let unit = ctrl.error_per_metre();
    let loop_of = |f: &crate::design::loops::DesignFrf| -> Vec<crate::ident::C64> {
        f.omega_rad_s
            .iter()
            .zip(&f.plant_m_per_a)
            .map(|(w, p)| ctrl.response(*w, period_s) * p * unit)
            .collect()
    };
    let reach = |omega: &[f64], l: &[crate::ident::C64]| {
        let s: Vec<f64> = l.iter().map(|l| 1.0 / (l + 1.0).norm()).collect();
        loop_performance_bandwidth_rad_s(omega, &s, s_max)
    };
    // ω* and its 1σ on the lines of `f` from index `k` up (relative 1σ
    // `r`), as the certificate reads them: the least of the loop with the
    // computation delay and without it ([`DesignFrf::undelayed`]), the 1σ
    // from whichever sets it.
    let reach_both = |f: &crate::design::loops::DesignFrf, k: usize, r: &[f64]| {
        let at = |f: &crate::design::loops::DesignFrf| {
            let (omega, l) = (&f.omega_rad_s[k..], &loop_of(f)[k..]);
            (
                reach(omega, l),
                performance_bandwidth_sigma(omega, l, &r[k..], s_max),
            )
        };
        let (with, without) = (at(f), at(&f.undelayed(computation_delay_s)));
        match (with.0, without.0) {
            (Some(a), Some(b)) if b < a => without,
            (Some(_), Some(_)) => with,
            _ => (None, None),
        }
    };
    let loops: Vec<Vec<crate::ident::C64>> = frfs.iter().map(loop_of).collect();
    let (per_input, per_input_w_sigma): (Vec<Option<f64>>, Vec<Option<f64>>) = frfs
        .iter()
        .zip(relative_sigma)
        .map(|(f, r)| reach_both(f, 0, r))
        .unzip();
    let lowest = frfs
        .iter()
        .map(|f| f.omega_rad_s[0])
        .fold(f64::INFINITY, f64::min);
    // Each model's ω* from the lowest measured line up, and its 1σ from
    // the fit's covariance.
    let (on_models, model_sigma): (Vec<Option<f64>>, Vec<Option<f64>>) = models
        .iter()
        .zip(model_relative_sigma)
        .map(|(m, r)| reach_both(m, m.omega_rad_s.partition_point(|w| *w < lowest), r))
        .unzip();
    let performance_bandwidth_rad_s = per_input
        .iter()
        .chain(&on_models)
        .try_fold(f64::INFINITY, |m, w| w.map(|w| m.min(w)));
    let sigmas: Vec<FigureSigmas> = frfs
        .iter()
        .zip(&loops)
        .zip(relative_sigma)
        .zip(&e.figures)
        .zip(&per_input_w_sigma)
        .map(|((((f, l), r), g), w)| FigureSigmas {
            performance_bandwidth_rad_s: *w,
            ..figure_sigmas(&f.omega_rad_s, l, r, g, s_max)
        })
        .collect();
    let pick = |key: &dyn Fn(usize) -> Option<f64>, least: bool| {
        (0..frfs.len())
            .filter_map(|i| key(i).map(|v| (i, v)))
            .min_by(|a, b| {
                if least {
                    a.1.total_cmp(&b.1)
                } else {
                    b.1.total_cmp(&a.1)
                }
            })
            .map(|(i, _)| i)
    };
    let summary = FigureSigmas {
        // From the input or the model that sets the least ω*.
        performance_bandwidth_rad_s: pick(&|i| per_input[i], true)
            .filter(|&i| per_input[i] == performance_bandwidth_rad_s)
            .map(|i| sigmas[i].performance_bandwidth_rad_s)
            .or_else(|| {
                on_models
                    .iter()
                    .position(|w| *w == performance_bandwidth_rad_s)
                    .map(|i| model_sigma[i])
            })
            .flatten(),
        sensitivity_bandwidth_rad_s: pick(&|i| e.figures[i].sensitivity_bandwidth_rad_s, true)
            .and_then(|i| sigmas[i].sensitivity_bandwidth_rad_s),
        phase_margin_min_deg: pick(&|i| e.figures[i].phase_margin_min_deg, true)
            .and_then(|i| sigmas[i].phase_margin_min_deg),
        gain_margin_db: pick(&|i| e.figures[i].margins.gain_margin_db, true)
            .and_then(|i| sigmas[i].gain_margin_db),
        sensitivity_peak: pick(&|i| Some(e.figures[i].margins.sensitivity_peak), false)
            .and_then(|i| sigmas[i].sensitivity_peak),
    };
    EvaluationFigures {
        performance_bandwidth_rad_s,
        per_input_rad_s: per_input,
        per_input_sigma: sigmas,
        sigma: summary,
    }
}

/// One strategy tried.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct StrategyOutcome {
    /// `slow`, `fast` or `limit`.
    pub strategy: String,
    /// Meets every margin on every input.
    pub meets_margins: bool,
    /// Smallest ω_B over the inputs, rad/s.
    pub sensitivity_bandwidth_rad_s: f64,
    /// Its performance bandwidth ω* over the inputs and models, rad/s.
    pub performance_bandwidth_rad_s: f64,
    /// The structure and why.
    pub structure: String,
    /// The binding (or most violated) constraint.
    pub binding: Option<Binding>,
    /// 1σ of this strategy's figures from the inputs' line noise (first
    /// order, each from the input that sets it; ω*'s from the fit's
    /// covariance when a fit sets it; `null` when the certificate's ω*
    /// above is not the one [`evaluation_figures`] reads).
    #[serde(default)]
    pub sigma: FigureSigmas,
}

/// The result of a design.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct DesignSummary {
    /// The inputs and the lines used from each.
    pub inputs: Vec<InputUse>,
    /// Where the bench config came from.
    pub config: String,
    /// The modes found on each input.
    pub modes: PlantModes,
    /// The strategy delivered: `slow` or `fast`.
    pub strategy: String,
    /// Why, in words (the thesis' rule, the sign sequence).
    pub why: String,
    /// The margins required.
    pub requirements: Requirements,
    /// The computation delay added to every FRF, s.
    pub computation_delay_s: f64,
    /// The controller's name in the written config.
    pub name: String,
    /// The controller (as `[controller.NAME]` holds it).
    #[schemars(skip)]
    pub controller: ControllerConfig,
    /// Figures on every input (the discrete controller that will run).
    pub figures: Vec<InputFigures>,
    /// The input with the least margin (the binding constraint's).
    pub worst_input: String,
    /// The binding constraint.
    pub binding: Option<Binding>,
    /// First gain crossover on the worst input, rad/s.
    pub crossover_rad_s: Option<f64>,
    /// Smallest ω_B over the inputs, rad/s.
    pub sensitivity_bandwidth_rad_s: f64,
    /// Least phase margin (angle to −1) at any crossover of any input, degrees.
    pub phase_margin_min_deg: Option<f64>,
    /// Least gain margin over the inputs, dB (`null`: no phase crossover).
    pub gain_margin_min_db: Option<f64>,
    /// Largest ‖S‖∞ over the inputs.
    pub sensitivity_peak: f64,
    /// The performance bandwidth ω* of `W_P(s) = (s/M + ω*)/s`, M =
    /// `s_max`: the least over every input's lines and the models' from
    /// the lowest measured line to Nyquist, each with the computation
    /// delay and without it, rad/s (`null`: |S| passes M somewhere).
    pub performance_bandwidth_rad_s: Option<f64>,
    /// The 1σ of the summary's figures (each from the input or the fit it
    /// is read on; `null` where that input's noise or the fit's covariance
    /// is unknown).
    pub sigma: FigureSigmas,
    /// The best ω* any LTI controller reaches on the same inputs.
    pub limit: LimitReport,
    /// `performance_bandwidth_rad_s / limit.performance_bandwidth_rad_s`.
    pub limit_fraction: Option<f64>,
    /// On the bench's model (named in `model.model`): figures to Nyquist
    /// and the predicted step.
    pub model: ModelPrediction,
    /// Every strategy tried.
    pub strategies: Vec<StrategyOutcome>,
    /// The bench config written.
    pub config_out: PathBuf,
    /// The figure written, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plot: Option<PathBuf>,
    /// Wall time of the design (fits, search, certificate), s.
    pub design_time_s: f64,
    /// How closely the discrete controller that runs follows the
    /// continuous design (to f_s/10 and f_s/4, and the gain above);
    /// `null` for a design made in discrete time (`discretization =
    /// "bilinear"`: what runs is the design). Absent in JSON written
    /// before it existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub discretization: Option<crate::control::DiscretizationReport>,
}

fn is_recording(p: &Path) -> bool {
    let name = p.to_string_lossy();
    name.ends_with(".mcap") || name.ends_with(".mcap.part")
}

/// Checks a controller name: a TOML bare key of 1 to 64 letters, digits,
/// `_` or `-`.
fn check_name(name: &str) -> Result<(), RunError> {
    let ok = !name.is_empty()
        && name.len() <= 64
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
    if ok {
        Ok(())
    } else {
        Err(RunError::option(
            "name",
            format!("{name:?}"),
            "a controller name is 1 to 64 letters, digits, `_` or `-` (it becomes [controller.NAME])",
        ))
    }
}

struct ReadInputs {
    frfs: Vec<InputFrf>,
    config_toml: Option<(String, String)>,
}

fn read_inputs(inputs: &[DesignInput]) -> Result<ReadInputs, RunError> {
    let mut frfs = Vec::new();
    let mut config_toml: Option<(String, String)> = None;
    // Every file through crate::input_file: a regular file within its
    // kind's limit, read with that bound.
    let read_csv = |label: &str, path: &Path| -> Result<Frf, RunError> {
        let bad = |r: String| RunError::option("inputs", label, r);
        let text = read_to_string(path, Kind::FrfCsv, "inputs").map_err(|e| bad(e.reason()))?;
        Frf::read_csv(&text).map_err(bad)
    };
    for inp in inputs {
        match inp {
            DesignInput::File(p) => {
                let label = p.display().to_string();
                let frf = if is_recording(p) {
                    let bytes = read(p, Kind::Recording, "inputs")?;
                    let r = read_frf(&bytes).map_err(|e| RunError::option("inputs", &label, e))?;
                    if config_toml.is_none() {
                        // In the layout of the file it was run with.
                        let source = r.config_source;
                        config_toml = r.config_toml.map(|t| {
                            let text = source
                                .and_then(|s| crate::config::in_source_layout(&s, &t).ok())
                                .unwrap_or(t);
                            (text, format!("recorded in {label}"))
                        });
                    }
                    r.frf
                } else {
                    read_csv(&label, p)?
                };
                frfs.push(InputFrf { label, frf });
            }
            DesignInput::Cells {
                dir,
                config_toml: t,
                cells,
            } => {
                if cells.is_empty() {
                    return Err(RunError::option(
                        "inputs",
                        dir.display(),
                        "the campaign has no done cell: nothing to design from (run or resume it first)",
                    ));
                }
                if config_toml.is_none() {
                    config_toml = Some((t.clone(), format!("{}/bench.toml", dir.display())));
                }
                for (i, csv) in cells {
                    let label = format!("{} cell {i:03}", dir.display());
                    let frf = read_csv(&label, csv)?;
                    frfs.push(InputFrf { label, frf });
                }
            }
        }
    }
    Ok(ReadInputs { frfs, config_toml })
}

/// The figures' option key of a design error: an input's label, a
/// request field, or the margins.
fn design_error(e: DesignError) -> RunError {
    let key: Option<&'static str> = match e.what.as_str() {
        "pm_min_deg" => Some("pm_min_deg"),
        "gm_min_db" => Some("gm_min_db"),
        "s_max" => Some("s_max"),
        "computation_delay_s" => Some("computation_delay_s"),
        "config" => Some("config"),
        _ => None,
    };
    match key {
        Some(k) => RunError::option(k, "", e.reason),
        None if e.what == "margins" => RunError::BadInput(format!("the margins: {}", e.reason)),
        None => RunError::option("inputs", e.what, e.reason),
    }
}

/// The bench config a design reads: its text, where it came from, and
/// the config itself.
struct DesignBench {
    base_toml: String,
    config_source: String,
    cfg: BenchConfig,
}

/// The bench config of a design: `--config`, else the first recording's or
/// campaign's, else the built-in bench; `name` must be new in it.
fn design_bench(
    req: &DesignRequest,
    read: &ReadInputs,
    name: &str,
) -> Result<DesignBench, RunError> {
    let (base_toml, config_source) = match (&req.config, &read.config_toml) {
        (Some(p), _) => (
            read_to_string(p, Kind::Config, "config")?,
            p.display().to_string(),
        ),
        (None, Some((t, from))) => (t.clone(), from.clone()),
        (None, None) => (
            BUILTIN_CONFIG_TOML.to_string(),
            "built-in (sr4dof-ch5)".to_string(),
        ),
    };
    let cfg_path = req
        .config
        .clone()
        .unwrap_or_else(|| PathBuf::from(&config_source));
    let cfg = BenchConfig::from_toml(&base_toml, &cfg_path)
        .map_err(|e| RunError::option("config", &config_source, e.to_string()))?;
    if cfg.controller.contains_key(name) {
        return Err(RunError::option(
            "name",
            name,
            format!("[controller.{name}] exists in the bench config ({config_source}): choose another name"),
        ));
    }
    Ok(DesignBench {
        base_toml,
        config_source,
        cfg,
    })
}

/// The requirements and the delay of a design, checked against the
/// config's loop: the settling bound within the predicted step, every
/// input below the loop's Nyquist frequency.
fn design_spec(
    req: &DesignRequest,
    cfg: &BenchConfig,
    read: &ReadInputs,
) -> Result<DesignSpec, RunError> {
    let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
    let spec = DesignSpec {
        strategy: req.strategy,
        requirements: Requirements {
            phase_margin_min_deg: req.pm_min_deg.unwrap_or(PM_MIN_DEG),
            gain_margin_min_db: req.gm_min_db.unwrap_or(GM_MIN_DB),
            sensitivity_peak_max: req.s_max.unwrap_or(S_MAX),
        },
        computation_delay_s: req.computation_delay_s.unwrap_or(period_s),
    };
    spec.validate(period_s).map_err(design_error)?;
    if let Some(t) = req.settling_max_s {
        let longest = cfg.step.duration_s - cfg.step.settle_s;
        if !t.is_finite() || t <= 0.0 || t > longest {
            return Err(RunError::option(
                "settling_max_s",
                t,
                format!("must be in (0, {longest}] s: the step the model predicts lasts [step] duration_s − settle_s"),
            ));
        }
    }
    let nyquist = 0.5 / period_s;
    for f in &read.frfs {
        if let Some(top) = f.frf.frequency_hz.last().filter(|x| **x >= nyquist) {
            return Err(RunError::option(
                "inputs",
                &f.label,
                format!("frequency {top} Hz is at or above the Nyquist frequency {nyquist} Hz of the config's loop rate: an FRF of another loop"),
            ));
        }
    }
    Ok(spec)
}

/// The design's outputs (the bench config and, unless `no_plot`, the
/// figure), checked against what exists and against every input.
fn plan_design_outputs(opts: &DesignOptions) -> Result<(PathBuf, Option<PathBuf>), RunError> {
    let req = &opts.request;
    let out = opts.out.clone().unwrap_or_else(|| match &opts.inputs[0] {
        DesignInput::File(p) => beside(p, ".designed.toml"),
        DesignInput::Cells { dir, .. } => dir.join("designed.toml"),
    });
    let png = (!req.no_plot).then(|| {
        opts.png
            .clone()
            .unwrap_or_else(|| out.with_extension("png"))
    });
    let origin = |given: bool| {
        if given {
            Origin::Given
        } else {
            Origin::Derived
        }
    };
    let mut plan = OutputPlan::new(opts.existing)
        .derived_from("the first input")
        .with_output("out", &out, origin(opts.out.is_some()));
    if let Some(p) = &png {
        plan = plan.with_output("png", p, origin(opts.png.is_some()));
    }
    // Never written over an input (rule 6 of crate::outputs).
    for inp in &opts.inputs {
        match inp {
            DesignInput::File(p) => plan.add_input("inputs", p),
            DesignInput::Cells { cells, .. } => {
                for (_, csv) in cells {
                    plan.add_input("inputs", csv);
                }
            }
        }
    }
    if let Some(c) = &req.config {
        plan.add_input("config", c);
    }
    plan.check()?;
    Ok((out, png))
}

/// What a design works on: the inputs' lines prepared for the loop, what
/// each is used for, their modes, and their modal fits as plants.
struct Measured {
    frfs: Vec<crate::design::loops::DesignFrf>,
    uses: Vec<InputUse>,
    modes: PlantModes,
    plants: Vec<FittedPlant>,
    /// Each input's relative 1σ on its coherent lines.
    relative_sigma: Vec<Vec<f64>>,
}

impl Measured {
    /// The lines first (the fit needs finite, ascending data), then the
    /// modes, then the wiring against the first resonance.
    fn identify(read: &ReadInputs, spec: &DesignSpec, path: FitPath) -> Result<Self, RunError> {
        prepare(&read.frfs, spec.computation_delay_s, None).map_err(design_error)?;
        let (modes, fits) =
            PlantModes::identify_with_fits(&read.frfs, path).map_err(design_error)?;
        let (frfs, uses) = prepare(
            &read.frfs,
            spec.computation_delay_s,
            Some(modes.first_resonance_rad_s),
        )
        .map_err(design_error)?;
        let plants = fits.iter().map(|f| FittedPlant::new(f, path)).collect();
        Ok(Self {
            frfs,
            uses,
            modes,
            plants,
            relative_sigma: crate::design::coherent_relative_sigma(&read.frfs),
        })
    }

    /// The `limit` strategy climbs on the limit's lines (all inputs', and
    /// a workspace's most demanding input's own), with the effort bound of
    /// the limit and the design alike: the peak current for the config's
    /// setpoint step.
    fn climb_inputs(
        &self,
        spec: &DesignSpec,
        period_s: f64,
        cfg: &BenchConfig,
    ) -> crate::design::ClimbInputs {
        let effort_max_a_per_m = crate::design::limit::LoopBounds::effort_for_step(
            cfg.actuator.peak_current_a,
            cfg.step.step_m,
        );
        let delay_s = spec.computation_delay_s;
        let s_max = spec.requirements.sensitivity_peak_max;
        let (frfs, sigma, plants) = (&self.frfs, &self.relative_sigma, &self.plants);
        crate::design::ClimbInputs {
            effort_max_a_per_m,
            lines: ClimbLines::new(frfs, sigma, plants, (period_s, delay_s)),
            computation_delay_s: delay_s,
            nominal: crate::design::nominal_input(plants, s_max).map(|k| crate::design::Nominal {
                input: k,
                lines: ClimbLines::new(
                    &frfs[k..=k],
                    &sigma[k..=k],
                    &plants[k..=k],
                    (period_s, delay_s),
                ),
            }),
        }
    }

    /// The model input `i` is predicted on: its fit, or the config's model
    /// (read from `config_source`) when asked.
    fn model<'a>(
        &'a self,
        choice: ModelChoice,
        config_source: &'a str,
        i: usize,
    ) -> BenchModel<'a> {
        match choice {
            ModelChoice::Fit => BenchModel::Fitted {
                input: &self.frfs[i].label,
                plant: &self.plants[i],
            },
            ModelChoice::Config => BenchModel::Config {
                source: config_source,
            },
        }
    }

    /// The certificate's models, every input's fit (or the config's
    /// model), and each model's relative 1σ on its grid: the fit's
    /// covariance (a config's model has none: NaN).
    fn certificate_models(
        &self,
        choice: ModelChoice,
        config_source: &str,
        cfg: &BenchConfig,
        spec: &DesignSpec,
    ) -> Result<(Vec<crate::design::loops::DesignFrf>, Vec<Vec<f64>>), RunError> {
        let delay_s = spec.computation_delay_s;
        let models = match choice {
            ModelChoice::Fit => (0..self.frfs.len())
                .map(|i| model_frf_on(self.model(choice, config_source, i), cfg, delay_s))
                .collect::<Result<Vec<_>, _>>(),
            ModelChoice::Config => {
                model_frf_on(self.model(choice, config_source, 0), cfg, delay_s).map(|m| vec![m])
            }
        }
        .map_err(design_error)?;
        let sigma = models
            .iter()
            .enumerate()
            .map(|(i, m)| match choice {
                ModelChoice::Fit => m
                    .omega_rad_s
                    .iter()
                    .map(|w| self.plants[i].frf_relative_sigma(*w))
                    .collect(),
                ModelChoice::Config => vec![f64::NAN; m.omega_rad_s.len()],
            })
            .collect();
        Ok((models, sigma))
    }

    /// The limit ([`bench_limit`]) and the design ([`design`]) of these
    /// inputs. They are independent: side by side, the limit on a thread of
    /// its own, outside the pool the design's searches and climbs share. (In
    /// the pool, on two cores, the limit held one of its two threads for its
    /// whole run, and the second climb waited for it: one default chirp's
    /// design 6.6 s, 5.8 s with the limit on its own thread; dev profile,
    /// the shipped bench.)
    fn limit_beside_design(
        &self,
        models: &[crate::design::loops::DesignFrf],
        settling: Option<&crate::design::SettlingLimit<'_>>,
        spec: &DesignSpec,
        period_s: f64,
        peak_current_a: f64,
        climb: &crate::design::ClimbInputs,
    ) -> (LimitReport, Result<crate::design::Designed, DesignError>) {
        std::thread::scope(|scope| {
            let limit = scope.spawn(|| {
                bench_limit(
                    &self.frfs,
                    &self.plants,
                    &climb.lines.across_modes,
                    period_s,
                    spec.requirements.sensitivity_peak_max,
                    climb.effort_max_a_per_m,
                )
            });
            let d = design(
                &self.frfs,
                models,
                settling,
                &self.modes,
                spec,
                period_s,
                peak_current_a,
                Some(climb),
            );
            let limit = limit
                .join()
                .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
            (limit, d)
        })
    }
}

/// The least margins over every input's loop.
struct LeastMargins {
    /// The least phase margin over every crossing, deg (`None`: no
    /// crossing).
    phase_margin_min_deg: Option<f64>,
    /// The least gain margin, dB (`None`: none defined).
    gain_margin_min_db: Option<f64>,
    /// The largest ‖S‖∞.
    sensitivity_peak: f64,
}

impl LeastMargins {
    fn of(figures: &[LoopFigures]) -> Self {
        Self {
            phase_margin_min_deg: figures
                .iter()
                .filter_map(|f| f.phase_margin_min_deg)
                .reduce(f64::min),
            gain_margin_min_db: figures
                .iter()
                .filter_map(|f| f.margins.gain_margin_db)
                .reduce(f64::min),
            sensitivity_peak: figures
                .iter()
                .map(|f| f.margins.sensitivity_peak)
                .fold(0.0, f64::max),
        }
    }
}

/// The bench config with `[controller.NAME]` added, checked to load as it
/// will be run (read as if from `out`).
fn designed_config(
    base_toml: &str,
    name: &str,
    controller: &ControllerConfig,
    why: &str,
    out: &Path,
) -> Result<String, RunError> {
    let text = designed_toml(base_toml, name, controller, why)
        .map_err(|e| RunError::BadInput(format!("the bench config with the design added: {e}")))?;
    BenchConfig::from_toml(&text, out).map_err(|e| {
        RunError::BadInput(format!(
            "the bench config with the design added does not load: {e}"
        ))
    })?;
    Ok(text)
}

/// How closely the discrete controller that runs follows a continuous
/// design. A design made in discrete time (the `limit` strategy: its
/// config form is the bilinear image, run through the same map) is what
/// runs: `None`.
fn discretization_of(
    controller: &ControllerConfig,
    period_s: f64,
    peak_current_a: f64,
) -> Option<crate::control::DiscretizationReport> {
    (controller.discretization != crate::control::Discretization::Bilinear).then(|| {
        crate::control::DiscreteController::new(controller, period_s, peak_current_a)
            .discretization()
    })
}

/// Every input's figures with its ω* and their 1σ, in input order.
fn input_figures(
    frfs: &[crate::design::loops::DesignFrf],
    figures: &[LoopFigures],
    per_input_rad_s: &[Option<f64>],
    sigmas: &[FigureSigmas],
) -> Vec<InputFigures> {
    frfs.iter()
        .zip(figures)
        .zip(per_input_rad_s)
        .zip(sigmas)
        .map(|(((f, g), w), sg)| InputFigures {
            input: f.label.clone(),
            figures: g.clone(),
            performance_bandwidth_rad_s: *w,
            sigma: sg.clone(),
        })
        .collect()
}

/// Writes a design's outputs: the figure first (a failure leaves no config
/// behind), then the config (`summary.config_out`; a failure removes the
/// figure).
fn write_outputs(
    summary: &mut DesignSummary,
    text: &str,
    png: Option<&Path>,
    existing: Existing,
    figure: impl FnOnce(&Path, &DesignSummary) -> Result<(), RunError>,
) -> Result<(), RunError> {
    if let Some(png) = png {
        figure(png, summary)?;
        summary.plot = Some(png.to_path_buf());
    }
    let out = &summary.config_out;
    write_atomically(out, existing, |f| f.write_all(text.as_bytes())).map_err(|e| {
        if let Some(p) = &summary.plot {
            let _ = std::fs::remove_file(p);
        }
        RunError::option("out", out.display(), e.to_string())
    })
}

/// The design's ω* as a fraction of the limit's (`None`: either unknown).
fn fraction_of_limit(performance_bandwidth_rad_s: Option<f64>, limit: &LimitReport) -> Option<f64> {
    match (
        performance_bandwidth_rad_s,
        limit.performance_bandwidth_rad_s,
    ) {
        (Some(w), Some(l)) if l > 0.0 => Some(w / l),
        _ => None,
    }
}

/// The input whose loop binds, by label and index (the first input when
/// none binds).
fn binding_input(
    binding: Option<&Binding>,
    frfs: &[crate::design::loops::DesignFrf],
) -> (String, usize) {
    let label = binding.map_or_else(|| frfs[0].label.clone(), |b| b.input.clone());
    let index = frfs.iter().position(|f| f.label == label).unwrap_or(0);
    (label, index)
}

/// Runs a design.
///
/// # Errors
/// See the module docs; nothing is written on an error.
pub fn run_design(opts: &DesignOptions) -> Result<DesignSummary, RunError> {
    let t0 = Instant::now();
    let req = &opts.request;
    if opts.inputs.is_empty() {
        return Err(RunError::option(
            "inputs",
            "",
            "at least one FRF (CSV, recording or campaign directory) is needed",
        ));
    }
    let name = req.name.clone().unwrap_or_else(|| NAME.to_string());
    check_name(&name)?;
    let read = read_inputs(&opts.inputs)?;
    let DesignBench {
        base_toml,
        config_source,
        cfg,
    } = design_bench(req, &read, &name)?;
    let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
    let spec = design_spec(req, &cfg, &read)?;
    // Outputs, checked before anything is computed.
    let (out, png) = plan_design_outputs(opts)?;

    let path = FitPath {
        period_s,
        amplifier_bandwidth_hz: cfg.actuator.bandwidth_hz,
    };
    let measured = Measured::identify(&read, &spec, path)?;
    let Measured {
        frfs,
        uses,
        modes,
        relative_sigma,
        ..
    } = &measured;
    let model_of = |i: usize| measured.model(req.model, &config_source, i);
    let (models, model_sigma) =
        measured.certificate_models(req.model, &config_source, &cfg, &spec)?;
    let settle_of = |c: &ControllerConfig| {
        crate::design::predict::predict_step_on(model_of(0), &cfg, c, spec.computation_delay_s)
            .ok()
            .and_then(|m| m.settling_time_s)
    };
    let settling = req
        .settling_max_s
        .map(|max_s| crate::design::SettlingLimit {
            max_s,
            settling_s: &settle_of,
        });
    let climb = measured.climb_inputs(&spec, period_s, &cfg);
    let (limit, d) = measured.limit_beside_design(
        &models,
        settling.as_ref(),
        &spec,
        period_s,
        cfg.actuator.peak_current_a,
        &climb,
    );
    let d = d.map_err(design_error)?;
    let e = &d.chosen.evaluation;
    let least = LeastMargins::of(&e.figures);
    let mut controller = e.controller.clone();
    controller.description = format!(
        "bench design ({}): ω_B {:.0} rad/s, least phase margin {:.0}°, ‖S‖∞ {:.2} on {} FRF(s)",
        d.chosen.strategy,
        e.sensitivity_bandwidth_min_rad_s,
        least.phase_margin_min_deg.unwrap_or(f64::INFINITY),
        least.sensitivity_peak,
        frfs.len()
    );
    let figures_on = FiguresOn {
        frfs,
        models: &models,
        relative_sigma,
        model_relative_sigma: &model_sigma,
        computation_delay_s: spec.computation_delay_s,
        period_s,
        peak_current_a: cfg.actuator.peak_current_a,
        s_max: spec.requirements.sensitivity_peak_max,
    };
    // ω* of the discrete controller on every input's lines and on every
    // model's grid, and the 1σ of the figures. (The chosen evaluation's
    // controller is `controller` but for its description.)
    let EvaluationFigures {
        performance_bandwidth_rad_s,
        per_input_rad_s: per_input,
        per_input_sigma: sigmas,
        sigma: summary_sigma,
    } = evaluation_figures(&figures_on, e);
    let (worst_input, worst_index) = binding_input(e.binding.as_ref(), frfs);
    let model = predict_on(
        model_of(worst_index),
        &cfg,
        &controller,
        spec.computation_delay_s,
    )
    .map_err(design_error)?;
    let text = designed_config(&base_toml, &name, &controller, &d.why, &out)?;
    let mut summary = DesignSummary {
        discretization: discretization_of(&controller, period_s, cfg.actuator.peak_current_a),
        inputs: uses.clone(),
        config: config_source.clone(),
        modes: modes.clone(),
        strategy: d.chosen.strategy.to_string(),
        why: d.why.clone(),
        requirements: spec.requirements,
        computation_delay_s: spec.computation_delay_s,
        name: name.clone(),
        controller: controller.clone(),
        figures: input_figures(frfs, &e.figures, &per_input, &sigmas),
        crossover_rad_s: e.figures[worst_index]
            .margins
            .crossovers_rad_s
            .first()
            .copied(),
        worst_input,
        binding: e.binding.clone(),
        sensitivity_bandwidth_rad_s: e.sensitivity_bandwidth_min_rad_s,
        phase_margin_min_deg: least.phase_margin_min_deg,
        gain_margin_min_db: least.gain_margin_min_db,
        sensitivity_peak: least.sensitivity_peak,
        performance_bandwidth_rad_s,
        sigma: summary_sigma,
        limit_fraction: fraction_of_limit(performance_bandwidth_rad_s, &limit),
        limit,
        model,
        strategies: strategy_outcomes(&figures_on, &d.attempts),
        config_out: out.clone(),
        plot: None,
        design_time_s: t0.elapsed().as_secs_f64(),
    };
    let worst_model = model_of(worst_index);
    write_outputs(
        &mut summary,
        &text,
        png.as_deref(),
        opts.existing,
        |p, s| write_figure(p, opts.existing, frfs, &cfg, worst_model, s, worst_index),
    )?;
    Ok(summary)
}

/// Every strategy tried, as the summary lists it: the certificate's ω*
/// with its 1σ (kept only while the two are the same figure).
fn strategy_outcomes(
    figures_on: &FiguresOn<'_>,
    attempts: &[crate::design::Attempt],
) -> Vec<StrategyOutcome> {
    attempts
        .iter()
        .map(|a| {
            let f = evaluation_figures(figures_on, &a.evaluation);
            // The row states the certificate's ω*, which is the one read
            // here; the 1σ is kept only while the two are the same figure.
            let same = f
                .performance_bandwidth_rad_s
                .is_some_and(|w| (w - a.evaluation.objective_rad_s).abs() <= 1e-9 * w.abs());
            let sigma = FigureSigmas {
                performance_bandwidth_rad_s: f.sigma.performance_bandwidth_rad_s.filter(|_| same),
                ..f.sigma
            };
            StrategyOutcome {
                strategy: a.strategy.to_string(),
                meets_margins: a.evaluation.feasible(),
                sensitivity_bandwidth_rad_s: a.evaluation.sensitivity_bandwidth_min_rad_s,
                performance_bandwidth_rad_s: a.evaluation.objective_rad_s,
                structure: a.structure.clone(),
                binding: a.evaluation.binding.clone(),
                sigma,
            }
        })
        .collect()
}

/// The design figure: every input's loop with the discrete controller that
/// will run, the model's loop dashed, the worst input highlighted.
fn write_figure(
    png: &Path,
    existing: Existing,
    frfs: &[crate::design::loops::DesignFrf],
    cfg: &BenchConfig,
    model: BenchModel<'_>,
    s: &DesignSummary,
    worst: usize,
) -> Result<(), RunError> {
    use crate::plot::{write_design_png, DesignLoop, DesignPlot};
    let t = cfg.loop_.period_ns() as f64 * 1e-9;
    let d = crate::control::DiscreteController::new(&s.controller, t, cfg.actuator.peak_current_a);
    let k = d.error_per_metre();
    let loops: Vec<Vec<crate::ident::C64>> = frfs
        .iter()
        .map(|f| {
            f.omega_rad_s
                .iter()
                .zip(&f.plant_m_per_a)
                .map(|(w, p)| d.response(*w, t) * p * k)
                .collect()
        })
        .collect();
    let (mgrid, ml) =
        crate::design::predict::model_loop_on(model, cfg, &s.controller, s.computation_delay_s)
            .map_err(|e| RunError::BadInput(e.to_string()))?;
    let drawn: Vec<DesignLoop<'_>> = frfs
        .iter()
        .zip(&loops)
        .enumerate()
        .map(|(i, (f, l))| DesignLoop {
            label: &f.label,
            omega_rad_s: &f.omega_rad_s,
            loop_gain: l,
            worst: i == worst,
        })
        .collect();
    // `v ± σ`, σ to one significant digit (at most three decimals): the
    // title must fit the figure.
    let pm = |v: f64, sigma: Option<f64>| match sigma {
        Some(g) if g > 0.0 => {
            let d = (-g.log10().floor()).clamp(0.0, 3.0) as usize;
            format!("{v:.1} ± {g:.d$}")
        }
        _ => format!("{v:.1}"),
    };
    let of_limit = match (
        s.performance_bandwidth_rad_s,
        s.limit.performance_bandwidth_rad_s,
    ) {
        (Some(w), Some(l)) => format!(
            ", ω* {}, {:.2} of the limit {} rad/s",
            pm(w, s.sigma.performance_bandwidth_rad_s),
            w / l,
            pm(l, s.limit.performance_bandwidth_sigma_rad_s)
        ),
        (Some(w), None) => format!(
            ", ω* {} rad/s (no limit)",
            pm(w, s.sigma.performance_bandwidth_rad_s)
        ),
        _ => String::new(),
    };
    let title = format!(
        "bench design: {} `{}`, ω_B {:.0} rad/s, ‖S‖∞ {:.2}{of_limit}",
        s.strategy, s.name, s.sensitivity_bandwidth_rad_s, s.sensitivity_peak
    );
    let plot = DesignPlot {
        title: &title,
        loops: &drawn,
        model: Some(DesignLoop {
            label: &s.model.model,
            omega_rad_s: &mgrid,
            loop_gain: &ml,
            worst: false,
        }),
        sensitivity_peak_max: s.requirements.sensitivity_peak_max,
        phase_margin_min_deg: s.requirements.phase_margin_min_deg,
        crossover_rad_s: s.crossover_rad_s,
        sensitivity_bandwidth_rad_s: Some(s.sensitivity_bandwidth_rad_s),
    };
    write_design_png(png, existing, &plot)
        .map_err(|e| RunError::option("png", png.display(), e.to_string()))
}

/// `base` (a bench config's TOML) with `[controller.NAME]` added after its
/// other controllers, every other key and comment kept.
///
/// # Errors
/// `base` is not TOML, or its `controller` is not a table.
pub fn designed_toml(
    base: &str,
    name: &str,
    c: &ControllerConfig,
    why: &str,
) -> Result<String, String> {
    use toml_edit::{value, Array, DocumentMut, InlineTable, Item, Table};
    let mut doc: DocumentMut = base
        .parse()
        .map_err(|e: toml_edit::TomlError| e.to_string())?;
    let controllers = doc
        .entry("controller")
        .or_insert_with(|| {
            let mut t = Table::new();
            t.set_implicit(true);
            Item::Table(t)
        })
        .as_table_mut()
        .ok_or("`controller` is not a table")?;
    let mut t = Table::new();
    t.decor_mut().set_prefix(format!(
        "\n# Designed by `bench design`: {why}\n# C(s) = gain/s · Π factors, each with unit gain at s = 0 (form = \"unity_dc\"), error in µm, output in A.\n"
    ));
    t.insert("description", value(c.description.clone()));
    t.insert("error_unit", value("um"));
    t.insert("form", value("unity_dc"));
    t.insert("gain", value(c.gain));
    t.insert("discretization", value(c.discretization.as_str()));
    t.insert("integrators", value(i64::from(c.integrators)));
    let reals = |v: &[f64]| {
        let mut a = Array::new();
        for x in v {
            a.push(*x);
        }
        value(a)
    };
    let pairs = |v: &[crate::control::ComplexPair]| {
        let mut a = Array::new();
        for p in v {
            let mut it = InlineTable::new();
            it.insert("omega_rad_s", p.omega_rad_s.into());
            it.insert("zeta", p.zeta.into());
            a.push(it);
        }
        value(a)
    };
    if !c.real_zeros_rad_s.is_empty() {
        t.insert("real_zeros_rad_s", reals(&c.real_zeros_rad_s));
    }
    if !c.real_poles_rad_s.is_empty() {
        t.insert("real_poles_rad_s", reals(&c.real_poles_rad_s));
    }
    if !c.complex_zeros.is_empty() {
        t.insert("complex_zeros", pairs(&c.complex_zeros));
    }
    if !c.complex_poles.is_empty() {
        t.insert("complex_poles", pairs(&c.complex_poles));
    }
    controllers.insert(name, Item::Table(t));
    Ok(doc.to_string())
}
