//! `bench fit` as a job: the automatic modal fit of a measured FRF and the
//! CMP-CNMP verdict ([`crate::ident::modal_fit`], [`crate::ident::verdict`]),
//! and the model update ([`crate::ident::update`]) to the FRF or to
//! measured natural frequencies.
//!
//! A [`FitRequest`] is what `bench fit`'s flags and the daemon's `fit`
//! params say; with its output paths it makes the [`FitOptions`] that
//! [`run_fit`] runs. Errors are [`RunError::BadOption`] naming the request
//! field or option (`input`, `config`, `free`, `frequencies_hz`, `update`,
//! `png`, `out`), never a flag: only the CLI knows its flags.

use crate::config::BenchConfig;
use crate::error::RunError;
use crate::ident::export::{export, ModelForm, ModelFormat};
use crate::ident::frf::{log_grid, Frf};
use crate::ident::modal_fit::{self, FittedMode, ModalFit};
use crate::ident::update::{
    update_to_frequencies, update_to_frf, updated_toml, Bench, Parameter, Update, UpdateError,
};
use crate::ident::verdict::Verdict;
use crate::jobs::chirp::{identify, Identified, MODEL_POINTS_PER_DECADE};
use crate::outputs::{beside, write_atomically, Destination, Existing, Origin, OutputPlan};
use crate::plot::{bode_curve, write_bode_png, BodePlot, BodeSeries, PairZoom};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Most natural frequencies an update to frequencies takes (the SR4DoF
/// model has 4 modes).
pub const MAX_FREQUENCIES: usize = 4;

/// A fit (`bench fit`, the daemon's `fit`). Paths are read by the process
/// that runs the job: the daemon takes absolute paths only.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitRequest {
    /// The measured FRF: a `bench chirp` CSV
    /// (`frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz`,
    /// or the 4-column one of earlier versions) or a
    /// recording (`.mcap`, or the `.mcap.part` of a killed run; its
    /// `/sysid/frf`). Absent with [`Self::frequencies_hz`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub input: Option<PathBuf>,
    /// Bench config (TOML): the loop period and amplifier bandwidth of the
    /// fit's path model, and the start bench of an update. Absent: the
    /// config a recording holds, else the built-in bench.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub config: Option<PathBuf>,
    /// Update the bench's physical parameters ([`Self::free`]) to the
    /// measured FRF.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub update: bool,
    /// Update to these measured natural frequencies instead of an FRF, Hz:
    /// 1 to [`MAX_FREQUENCIES`], ascending, below the Nyquist frequency of
    /// the config's loop rate.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frequencies_hz: Option<Vec<f64>>,
    /// The parameters to update, by name ([`Parameter::name`]). Absent:
    /// [`Parameter::FRF_DEFAULT`] for an FRF,
    /// [`Parameter::FREQUENCIES_DEFAULT`] for frequencies.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub free: Option<Vec<String>>,
    /// Write no measured vs fitted Bode PNG.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub no_plot: bool,
    /// Export the fitted model as a linear system in this form
    /// ([`crate::ident::export`]: `tf`, `zpk` or `ss`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub export_model: Option<ModelForm>,
    /// The exported model's file format (`json`, `matlab`, `python`;
    /// default `json`). Only with [`Self::export_model`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model_format: Option<ModelFormat>,
}

/// A fit to run: the request and where its outputs go.
#[derive(Debug, Clone, Default)]
pub struct FitOptions {
    /// What to fit.
    pub request: FitRequest,
    /// The Bode PNG; `None`: beside the input, `<stem>.fit.png` (none with
    /// `request.no_plot` or frequencies).
    pub png: Option<PathBuf>,
    /// The updated bench (TOML); `None`: with `request.update` beside the
    /// input, `<stem>.updated.toml`; with frequencies none (the result is
    /// only returned).
    pub out: Option<PathBuf>,
    /// The exported model (with `request.export_model`); `None`: beside
    /// the input ([`model_path`]).
    pub model_out: Option<PathBuf>,
    /// What to do with an existing output (`--overwrite`; the daemon
    /// always refuses).
    pub existing: Existing,
}

/// The fit of `request` with its outputs where `dest` puts them: locally
/// the flags' paths (`--png`, `--out`, `--model-out`; [`run_fit`] names
/// the others beside the input), on the daemon its stamped names for
/// the outputs the request asks for (the plot of an FRF fit, the updated
/// bench of an FRF update, the exported model). The command line and the
/// daemon both plan a fit here.
pub fn plan_fit(request: FitRequest, dest: &Destination) -> FitOptions {
    let format = request.model_format.unwrap_or_default();
    FitOptions {
        png: dest.optional("png", request.input.is_some() && !request.no_plot, |stem| {
            beside(stem, ".fit.png")
        }),
        // An update to frequencies is only answered.
        out: dest.optional("out", request.update, |stem| beside(stem, ".updated.toml")),
        model_out: dest.optional("model_out", request.export_model.is_some(), |stem| {
            model_path(stem, format)
        }),
        existing: dest.existing(),
        request,
    }
}

/// The default file of an exported model beside `input`:
/// `<stem>.model.json`, or for a script `<stem>_model.m` / `.py` with the
/// stem made an identifier (every character other than a letter, a digit
/// or `_` becomes `_`, and an `m` goes before a leading digit): MATLAB
/// runs a script by its name and Python imports a module by its name.
pub fn model_path(input: &Path, format: ModelFormat) -> PathBuf {
    if format == ModelFormat::Json {
        return beside(input, ".model.json");
    }
    let plain = beside(input, "");
    let stem = plain
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut id: String = stem
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if !id.starts_with(|c: char| c.is_ascii_alphabetic()) {
        id.insert(0, 'm');
    }
    plain.with_file_name(format!("{id}_model.{}", format.extension()))
}

/// The result of a fit of an FRF (`bench fit INPUT`).
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct FitSummary {
    /// The FRF fitted, as given.
    pub input: PathBuf,
    /// Sample period of the path model, s.
    pub period_s: f64,
    /// Amplifier bandwidth of the path model, Hz.
    pub amplifier_bandwidth_hz: f64,
    /// The fit (`null` when none could be made; see `verdict.reason`).
    pub fit: Option<ModalFit>,
    /// `fit.modes`, repeated at the top level for scripts.
    pub modes: Vec<FittedMode>,
    /// Both tests and the CMP-CNMP verdict.
    pub verdict: Verdict,
    /// The Bode PNG written, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plot: Option<PathBuf>,
    /// The model update (`update`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub update: Option<Update>,
    /// Where the updated bench was written.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub updated_config: Option<PathBuf>,
    /// Why the updated bench was not written although `update` was asked
    /// for: the update is flagged ([`Update::flags`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub update_not_written: Option<String>,
    /// Where the exported model was written (`export_model`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<PathBuf>,
}

impl FitSummary {
    /// The fit or the update is flagged: a result not to be trusted
    /// (`bench fit` exits 9).
    pub fn flagged(&self) -> bool {
        self.fit.as_ref().is_some_and(|f| !f.trusted())
            || self.update.as_ref().is_some_and(|u| !u.flags.is_empty())
    }
}

/// The result of an update to natural frequencies (`bench fit
/// --frequencies`).
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct FrequencySummary {
    /// The measured natural frequencies, Hz.
    pub frequencies_hz: Vec<f64>,
    /// The update.
    pub update: Update,
    /// Where the updated bench was written, if anywhere.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub updated_config: Option<PathBuf>,
}

/// What a fit job gives: one of the two summaries (as JSON, the summary
/// itself).
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(untagged)]
pub enum FitResult {
    /// A fit of an FRF.
    Fit(Box<FitSummary>),
    /// An update to natural frequencies.
    Frequencies(Box<FrequencySummary>),
}

impl FitRequest {
    /// Checks the request's shape before anything is read: an input or
    /// frequencies, not both; `update` and `free` only when updating.
    ///
    /// # Errors
    /// [`RunError::BadOption`] naming the field.
    pub fn check(&self) -> Result<(), RunError> {
        match (&self.input, &self.frequencies_hz) {
            (Some(_), Some(_)) => {
                return Err(RunError::option(
                    "frequencies_hz",
                    "",
                    "not with an input FRF: an update goes to the FRF or to natural frequencies",
                ))
            }
            (None, None) => {
                return Err(RunError::option(
                    "input",
                    "",
                    "give an FRF (CSV or recording), or natural frequencies to update to",
                ))
            }
            _ => {}
        }
        if self.update && self.input.is_none() {
            return Err(RunError::option("update", "", "needs an input FRF"));
        }
        if self.model_format.is_some() && self.export_model.is_none() {
            return Err(RunError::option(
                "model_format",
                "",
                "only with export_model (tf, zpk or ss)",
            ));
        }
        if self.export_model.is_some() && self.input.is_none() {
            return Err(RunError::option(
                "export_model",
                "",
                "needs an input FRF to fit (natural frequencies give no modal model)",
            ));
        }
        if self.free.is_some() && !self.updating() {
            return Err(RunError::option(
                "free",
                "",
                "only when updating the model (to the FRF or to natural frequencies)",
            ));
        }
        Ok(())
    }

    /// Whether the request updates the model.
    pub fn updating(&self) -> bool {
        self.update || self.frequencies_hz.is_some()
    }
}

/// Runs a fit: reads the input and the config, checks every output (the
/// rules of [`crate::outputs`]) before anything is computed, fits,
/// updates, writes the PNG and the updated bench.
///
/// # Errors
/// [`RunError::BadOption`] for a request or an output that cannot be used
/// (naming the field or option), an unreadable input or config, or an
/// update that cannot be made; [`RunError::Output`] when an output cannot
/// be written.
pub fn run_fit(opts: &FitOptions) -> Result<FitResult, RunError> {
    let req = &opts.request;
    req.check()?;
    if opts.out.is_some() && !req.updating() {
        return Err(RunError::option(
            "out",
            "",
            "only when updating the model (to the FRF or to natural frequencies)",
        ));
    }
    match (&req.input, &req.frequencies_hz) {
        (Some(input), _) => fit_frf(opts, input).map(|s| FitResult::Fit(Box::new(s))),
        (None, Some(f)) => fit_frequencies(opts, f).map(|s| FitResult::Frequencies(Box::new(s))),
        (None, None) => unreachable!("checked: an input or frequencies"),
    }
}

fn is_recording(p: &Path) -> bool {
    let name = p.to_string_lossy();
    name.ends_with(".mcap") || name.ends_with(".mcap.part")
}

/// The config of `path` (its file checks), else the built-in bench.
fn load_config(path: Option<&Path>) -> Result<BenchConfig, RunError> {
    match path {
        Some(p) => BenchConfig::load(p),
        None => BenchConfig::builtin(),
    }
    .map_err(super::config_error)
}

/// The `free` list, or `default`.
///
/// # Errors
/// [`RunError::BadOption`] naming `free`: an unknown name, one given
/// twice, an empty list.
pub fn parse_free(
    list: Option<&[String]>,
    default: &[Parameter],
) -> Result<Vec<Parameter>, RunError> {
    let Some(list) = list else {
        return Ok(default.to_vec());
    };
    let mut out = Vec::new();
    for name in list {
        let name = name.trim();
        let p = Parameter::from_name(name).ok_or_else(|| {
            let names: Vec<&str> = Parameter::ALL.iter().map(|p| p.name()).collect();
            RunError::option(
                "free",
                format!("{name:?}"),
                format!(
                    "not a parameter the update fits (one of {})",
                    names.join(", ")
                ),
            )
        })?;
        if out.contains(&p) {
            return Err(RunError::option("free", name, "given twice"));
        }
        out.push(p);
    }
    if out.is_empty() {
        return Err(RunError::option("free", "", "no parameter given"));
    }
    Ok(out)
}

/// Checks measured natural frequencies: finite, positive, below
/// `nyquist_hz`, strictly ascending, 1 to [`MAX_FREQUENCIES`].
///
/// # Errors
/// [`RunError::BadOption`] naming `frequencies_hz` and the value (1-based).
pub fn check_frequencies(f_hz: &[f64], nyquist_hz: f64) -> Result<(), RunError> {
    let bad = |reason: String| RunError::option("frequencies_hz", "", reason);
    if f_hz.is_empty() || f_hz.len() > MAX_FREQUENCIES {
        return Err(bad(format!(
            "{} values; give 1 to {MAX_FREQUENCIES} natural frequencies (the SR4DoF model has 4 modes)",
            f_hz.len()
        )));
    }
    for (i, &f) in f_hz.iter().enumerate() {
        let n = i + 1;
        if !f.is_finite() || f <= 0.0 {
            return Err(bad(format!(
                "value {n} ({f}) must be a finite frequency > 0 Hz"
            )));
        }
        if f >= nyquist_hz {
            return Err(bad(format!(
                "value {n} ({f} Hz) is at or above the Nyquist frequency {nyquist_hz} Hz of the config's loop rate"
            )));
        }
        if let Some(prev) = i.checked_sub(1).map(|j| f_hz[j]).filter(|p| f <= *p) {
            return Err(bad(format!(
                "value {n} ({f} Hz) is not above the one before ({prev} Hz): give them ascending, each mode once"
            )));
        }
    }
    Ok(())
}

/// The start bench's TOML text: `config`, the recording's, or the
/// built-in.
fn start_toml(
    config: Option<&Path>,
    recorded: Option<&str>,
    source: Option<&str>,
) -> Result<String, RunError> {
    match (config, recorded) {
        (Some(p), _) => Ok(crate::input_file::read_to_string(
            p,
            crate::input_file::Kind::Config,
            "config",
        )?),
        // The recording's config in the layout of the file it was run
        // with (comments kept); the resolved text alone when the
        // recording has no source or the two cannot be merged.
        (None, Some(t)) => Ok(source
            .and_then(|s| crate::config::in_source_layout(s, t).ok())
            .unwrap_or_else(|| t.to_string())),
        (None, None) => Ok(crate::config::BUILTIN_CONFIG_TOML.to_string()),
    }
}

fn start_bench(cfg: &BenchConfig) -> Bench {
    Bench {
        plant: cfg.plant,
        force_constant_n_per_a: cfg.actuator.force_constant_n_per_a,
    }
}

fn sample_period_s(cfg: &BenchConfig) -> f64 {
    cfg.loop_.period_ns() as f64 * 1e-9
}

/// Checks the outputs together ([`OutputPlan::check`]).
/// `inputs`: the files the fit reads (`input`, `config`), which no output
/// may be (rule 6 of [`crate::outputs`]).
fn check_outputs(
    existing: Existing,
    inputs: &[(&'static str, &Path)],
    png: Option<(&Path, bool)>,
    out: Option<(&Path, bool)>,
    model: Option<(&Path, bool)>,
) -> Result<(), RunError> {
    let origin = |given: bool| {
        if given {
            Origin::Given
        } else {
            Origin::Derived
        }
    };
    // The plot and the model are the input's own products: a rerun
    // replaces them; the updated bench may have been edited: never.
    let product = |given: bool| {
        if given {
            Origin::Given
        } else {
            Origin::Regenerated
        }
    };
    let mut plan = OutputPlan::new(existing).derived_from("the input");
    for (key, path) in inputs {
        plan.add_input(key, path);
    }
    if let Some((p, given)) = png {
        plan = plan.with_output("png", p, product(given));
    }
    if let Some((o, given)) = out {
        plan = plan.with_output("out", o, origin(given));
    }
    if let Some((m, given)) = model {
        plan = plan.with_output("model_out", m, product(given));
    }
    plan.check()
}

fn fit_frequencies(opts: &FitOptions, measured: &[f64]) -> Result<FrequencySummary, RunError> {
    let req = &opts.request;
    if opts.png.is_some() {
        return Err(RunError::option(
            "png",
            "",
            "not with natural frequencies (there is no FRF to plot)",
        ));
    }
    if opts.model_out.is_some() {
        return Err(RunError::option(
            "model_out",
            "",
            "not with natural frequencies (there is no modal fit to export)",
        ));
    }
    let cfg = load_config(req.config.as_deref())?;
    check_frequencies(measured, 0.5 / sample_period_s(&cfg))?;
    let free = parse_free(req.free.as_deref(), &Parameter::FREQUENCIES_DEFAULT)?;
    if let Some(out) = &opts.out {
        let inputs: Vec<(&'static str, &Path)> =
            req.config.iter().map(|c| ("config", c.as_path())).collect();
        check_outputs(opts.existing, &inputs, None, Some((out, true)), None)?;
    }
    let start = start_toml(req.config.as_deref(), None, None)?;
    let update = match update_to_frequencies(&start_bench(&cfg), &free, measured) {
        Ok(u) => u,
        Err(e @ (UpdateError::NotFromFrequencies(_) | UpdateError::NoFreeParameter)) => {
            return Err(RunError::option("free", "", e.to_string()))
        }
        Err(e) => return Err(RunError::option("frequencies_hz", "", e.to_string())),
    };
    if let Some(out) = &opts.out {
        let list: Vec<String> = measured.iter().map(|f| f.to_string()).collect();
        let from = format!("--frequencies {}", list.join(","));
        write_updated(out, opts.existing, &start, &update, &from)?;
    }
    Ok(FrequencySummary {
        frequencies_hz: measured.to_vec(),
        update,
        updated_config: opts.out.clone(),
    })
}

/// An FRF as `bench fit` reads its input ([`read_frf_input`]).
#[derive(Debug, Clone)]
pub struct FrfInput {
    /// The FRF: the CSV's lines, or the recording's `/sysid/frf`.
    pub frf: Frf,
    /// The bench config (TOML) a recording holds (`None` for a CSV).
    pub recorded_config: Option<String>,
    /// The config file's text a recording holds (`bench.config` `source`:
    /// comments and layout), when it does.
    pub recorded_source: Option<String>,
}

/// Reads `path` as `bench fit` reads its input: a recording (`.mcap`,
/// `.mcap.part`: its `/sysid/frf` and recorded config) or else an FRF CSV
/// ([`Frf::read_csv`]).
///
/// # Errors
/// Why it is not an FRF (unreadable, not a regular file, larger than its
/// kind's limit ([`crate::input_file`]), not UTF-8, a bad header or line,
/// a recording without `/sysid/frf`); the caller names the field.
pub fn read_frf_input(path: &Path) -> Result<FrfInput, String> {
    use crate::input_file::{read, Kind};
    // Through crate::input_file: a regular file within its kind's limit.
    let kind = if is_recording(path) {
        Kind::Recording
    } else {
        Kind::FrfCsv
    };
    let bytes = read(path, kind, "input").map_err(|e| e.reason())?;
    if is_recording(path) {
        let r = crate::ident::frf::read_frf(&bytes)?;
        Ok(FrfInput {
            frf: r.frf,
            recorded_config: r.config_toml,
            recorded_source: r.config_source,
        })
    } else {
        let text =
            String::from_utf8(bytes).map_err(|_| "not a text CSV (not UTF-8)".to_string())?;
        Ok(FrfInput {
            frf: Frf::read_csv(&text)?,
            recorded_config: None,
            recorded_source: None,
        })
    }
}

/// The modal fit and CMP-CNMP verdict of `frf` on the path of `cfg` (its
/// loop period and amplifier bandwidth): what `bench fit` reports for it.
///
/// # Errors
/// The FRF reaches the Nyquist frequency of `cfg`'s loop rate (the
/// reason, naming `frequency_hz`): it was measured on another loop.
pub fn fit_on(frf: &Frf, cfg: &BenchConfig) -> Result<Identified, String> {
    below_nyquist(frf, cfg)?;
    Ok(identify(
        frf,
        sample_period_s(cfg),
        cfg.actuator.bandwidth_hz,
    ))
}

/// Refuses an FRF that reaches the Nyquist frequency of `cfg`'s loop.
fn below_nyquist(frf: &Frf, cfg: &BenchConfig) -> Result<(), String> {
    let nyquist = 0.5 / sample_period_s(cfg);
    match frf.frequency_hz.last().filter(|f| **f >= nyquist) {
        Some(f) => Err(format!(
            "frequency_hz: {f} Hz is at or above the Nyquist frequency {nyquist} Hz of the config's loop rate"
        )),
        None => Ok(()),
    }
}

fn fit_frf(opts: &FitOptions, input_path: &Path) -> Result<FitSummary, RunError> {
    let req = &opts.request;
    let input = input_path.display().to_string();
    let bad_input = |reason: String| RunError::option("input", &input, reason);
    let free = parse_free(req.free.as_deref(), &Parameter::FRF_DEFAULT)?;
    let FrfInput {
        frf,
        recorded_config,
        recorded_source,
    } = read_frf_input(input_path).map_err(bad_input)?;
    let cfg = match (&req.config, &recorded_config) {
        (None, Some(toml)) => BenchConfig::from_toml(toml, input_path)
            .map_err(|e| bad_input(format!("its recorded bench.config: {e}")))?,
        (path, _) => load_config(path.as_deref())?,
    };
    let period_s = sample_period_s(&cfg);
    // Refused before any output is checked.
    below_nyquist(&frf, &cfg).map_err(bad_input)?;
    let plot = (!req.no_plot).then(|| {
        opts.png
            .clone()
            .unwrap_or_else(|| beside(input_path, ".fit.png"))
    });
    let out = req.update.then(|| {
        opts.out
            .clone()
            .unwrap_or_else(|| beside(input_path, ".updated.toml"))
    });
    if opts.model_out.is_some() && req.export_model.is_none() {
        return Err(RunError::option(
            "model_out",
            "",
            "only with export_model (tf, zpk or ss)",
        ));
    }
    let format = req.model_format.unwrap_or_default();
    let model_out = req.export_model.map(|_| {
        opts.model_out
            .clone()
            .unwrap_or_else(|| model_path(input_path, format))
    });
    // Every output checked before anything is computed.
    let mut inputs: Vec<(&'static str, &Path)> = vec![("input", input_path)];
    inputs.extend(req.config.iter().map(|c| ("config", c.as_path())));
    check_outputs(
        opts.existing,
        &inputs,
        plot.as_deref().map(|p| (p, opts.png.is_some())),
        out.as_deref().map(|o| (o, opts.out.is_some())),
        model_out.as_deref().map(|m| (m, opts.model_out.is_some())),
    )?;
    let start = match &out {
        Some(_) => Some(start_toml(
            req.config.as_deref(),
            recorded_config.as_deref(),
            recorded_source.as_deref(),
        )?),
        None => None,
    };
    let id = fit_on(&frf, &cfg).map_err(bad_input)?;
    let update = match &start {
        Some(_) => match update_to_frf(
            &start_bench(&cfg),
            &free,
            &modal_fit::FrfData::from_frf(&frf),
            &id.path,
            id.fit.as_ref(),
        ) {
            Ok(u) => Some(u),
            Err(UpdateError::Start(e)) => {
                return Err(RunError::option(
                    "update",
                    "",
                    format!("the start bench: {e}"),
                ))
            }
            Err(e) => return Err(RunError::option("update", &input, e.to_string())),
        },
        None => None,
    };
    // A default plot or model replaces the one an earlier run on the same
    // input made (checked above: a regular file); a given path follows
    // --overwrite.
    let regenerated = |given: bool| {
        if given {
            opts.existing
        } else {
            Existing::Replace
        }
    };
    if let (Some(p), Some(f)) = (&plot, &id.fit) {
        write_plot(p, regenerated(opts.png.is_some()), &frf, f, &id).map_err(|reason| {
            RunError::Output {
                path: p.clone(),
                reason,
            }
        })?;
    }
    // The model of a flagged fit is exported with its flags in the file
    // (and the exit status says so); no fit, no model.
    let exported = match (&model_out, req.export_model) {
        (Some(m), Some(form)) => {
            let fit = id.fit.as_ref().ok_or_else(|| {
                RunError::option(
                    "export_model",
                    &input,
                    format!(
                        "no modal fit to export: {}",
                        id.verdict.reason.as_deref().unwrap_or("the fit failed")
                    ),
                )
            })?;
            let model = export(fit, &id.path, form)
                .map_err(|e| RunError::option("export_model", &input, e.to_string()))?;
            let text = model.render(format, &input);
            write_atomically(m, regenerated(opts.model_out.is_some()), |f| {
                use std::io::Write;
                f.write_all(text.as_bytes())
            })
            .map_err(|e| RunError::Output {
                path: m.clone(),
                reason: e.to_string(),
            })?;
            Some(m.clone())
        }
        _ => None,
    };
    // A flagged update is reported, never written as a bench to use.
    let update_not_written = update
        .as_ref()
        .filter(|u| !u.flags.is_empty() && out.is_some())
        .map(|u| format!("the update is flagged: {}", u.flags.join("; ")));
    let out = out.filter(|_| update_not_written.is_none());
    if let (Some(o), Some(u), Some(s)) = (&out, &update, &start) {
        write_updated(o, opts.existing, s, u, &input)?;
    }
    Ok(FitSummary {
        input: input_path.to_path_buf(),
        period_s,
        amplifier_bandwidth_hz: cfg.actuator.bandwidth_hz,
        modes: id.fit.as_ref().map(|f| f.modes.clone()).unwrap_or_default(),
        fit: id.fit.clone(),
        verdict: id.verdict.clone(),
        plot: plot.filter(|_| id.fit.is_some()),
        update,
        updated_config: out,
        update_not_written,
        model: exported,
    })
}

/// Writes the updated bench to `out`, checked by the config loader first,
/// with a header saying where it came from (`from`) and the result.
fn write_updated(
    out: &Path,
    existing: Existing,
    start_toml: &str,
    update: &Update,
    from: &str,
) -> Result<(), RunError> {
    let mut header = format!(
        "# Updated by `bench fit` ({}) from {from}, {}:\n# RMS relative error {:.3} % (start {:.3} %).\n",
        update.source,
        crate::outputs::stamp(),
        100.0 * update.rms_relative_error,
        100.0 * update.start_rms_relative_error
    );
    for p in update.parameters.iter().filter(|p| p.free) {
        header.push_str(&format!(
            "# {} = {:.6e} {} (1 sigma {}; start {:.6e})\n",
            p.key,
            p.value,
            p.unit,
            p.sigma
                .map_or("not estimable".into(), |s| format!("{s:.2e}")),
            p.start
        ));
    }
    let text = updated_toml(start_toml, update, &header)
        .map_err(|e| RunError::option("out", out.display(), e))?;
    if let Err(e) = BenchConfig::from_toml(&text, out) {
        return Err(RunError::option(
            "out",
            out.display(),
            format!("the updated bench is not a valid config: {e}"),
        ));
    }
    write_atomically(out, existing, |f| {
        use std::io::Write;
        f.write_all(text.as_bytes())
    })
    .map_err(|e| RunError::Output {
        path: out.to_path_buf(),
        reason: e.to_string(),
    })
}

/// The measured vs fitted Bode PNG with the pair zoom.
fn write_plot(
    path: &Path,
    existing: Existing,
    frf: &Frf,
    fit: &ModalFit,
    id: &Identified,
) -> Result<(), String> {
    let (lo, hi) = (frf.frequency_hz[0], *frf.frequency_hz.last().unwrap());
    let f = log_grid(lo, hi, MODEL_POINTS_PER_DECADE);
    let h: Vec<_> = f
        .iter()
        .map(|&f| modal_fit::evaluate(fit, &id.path, f))
        .collect();
    let (mag, phase) = bode_curve(&h, frf.phase_deg.first().copied());
    let markers: Vec<f64> = fit
        .modes
        .iter()
        .filter(|m| m.in_path)
        .map(|m| m.frequency_hz)
        .collect();
    let reason = PairZoom::reason_of(&id.verdict.phase_test);
    let pair = PairZoom::of(&id.verdict.phase_test, frf, &reason);
    let title = format!(
        "modal fit: {} modes, sequence {}",
        markers.len(),
        fit.dominant_sequence
    );
    write_bode_png(
        path,
        existing,
        &BodePlot {
            title: &title,
            magnitude_axis: crate::plot::MAGNITUDE_M_PER_A,
            measured: BodeSeries::measured(frf, "measured"),
            coherence: &frf.coherence,
            model: Some(BodeSeries {
                label: "modal fit",
                frequency_hz: &f,
                magnitude: &mag,
                phase_deg: &phase,
            }),
            markers_hz: &markers,
            pair: Some(pair),
        },
    )
    .map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn option_key(e: RunError) -> &'static str {
        match e {
            RunError::BadOption { key, .. } => key,
            e => panic!("{e}"),
        }
    }

    #[test]
    fn request_shapes() {
        let frf = FitRequest {
            input: Some("a.csv".into()),
            ..Default::default()
        };
        assert!(frf.check().is_ok());
        for (r, key) in [
            (FitRequest::default(), "input"),
            (
                FitRequest {
                    frequencies_hz: Some(vec![20.0]),
                    ..frf.clone()
                },
                "frequencies_hz",
            ),
            (
                FitRequest {
                    free: Some(vec!["mass_asymmetry".into()]),
                    ..frf.clone()
                },
                "free",
            ),
            (
                FitRequest {
                    update: true,
                    frequencies_hz: Some(vec![20.0]),
                    ..Default::default()
                },
                "update",
            ),
        ] {
            assert_eq!(option_key(r.check().unwrap_err()), key, "{r:?}");
        }
    }

    #[test]
    fn frequencies_and_free_are_checked() {
        assert!(check_frequencies(&[18.2, 27.6, 153.2, 154.3], 2500.0).is_ok());
        for bad in [
            &[][..],
            &[1.0, 2.0, 3.0, 4.0, 5.0],
            &[0.0],
            &[f64::NAN],
            &[2500.0],
            &[20.0, 20.0],
        ] {
            let e = check_frequencies(bad, 2500.0).unwrap_err();
            assert_eq!(option_key(e), "frequencies_hz", "{bad:?}");
        }
        assert_eq!(
            parse_free(None, &Parameter::FRF_DEFAULT).unwrap(),
            Parameter::FRF_DEFAULT
        );
        for bad in [
            vec!["nope".to_string()],
            vec!["mass_asymmetry".into(), "mass_asymmetry".into()],
            vec![],
        ] {
            let e = parse_free(Some(&bad), &Parameter::FRF_DEFAULT).unwrap_err();
            assert_eq!(option_key(e), "free", "{bad:?}");
        }
    }

    #[test]
    fn wire_form() {
        let r: FitRequest = serde_json::from_value(serde_json::json!({
            "input": "/x/chirp.frf.csv", "update": true, "free": ["mass_asymmetry"]
        }))
        .unwrap();
        assert!(r.update && !r.no_plot);
        assert_eq!(
            serde_json::to_value(&r).unwrap(),
            serde_json::json!({ "input": "/x/chirp.frf.csv", "update": true, "free": ["mass_asymmetry"] })
        );
        let e = serde_json::from_value::<FitRequest>(serde_json::json!({ "png": "/x.png" }))
            .unwrap_err();
        assert!(e.to_string().contains("png"), "{e}");
    }
}
