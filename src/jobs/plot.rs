//! `bench plot bode|nyquist` as a job: several measured FRFs (CSVs,
//! recordings, the done cells of campaign directories) on one figure,
//! each fitted as `bench fit` fits it ([`super::fit::fit_on`]) so that its
//! legend entry gives the verdict `bench fit` prints for it, the model of
//! the bench once, and the zoom on the closely spaced pairs
//! ([`crate::plot::write_bode_overlay_png`],
//! [`crate::plot::write_nyquist_png`]).
//!
//! A [`PlotRequest`] is what `bench plot`'s flags and the daemon's `plot`
//! params say; campaign directories are expanded into their cells by the
//! caller ([`PlotInput::Cells`]; the campaign layer reads its own
//! journal). Errors are [`RunError::BadOption`] naming the request field
//! (`inputs`, `config`, `labels`, `title`, `out`), or
//! [`RunError::Output`] when the figure cannot be written; nothing is
//! written on an error.

use crate::config::{BenchConfig, BUILTIN_CONFIG_NAME, BUILTIN_CONFIG_TOML};
use crate::error::RunError;
use crate::ident::frf::{log_grid, Frf, C64, MIN_COHERENCE};
use crate::ident::modal_fit::ModalFit;
use crate::ident::verdict::Verdict;
use crate::jobs::chirp::MODEL_POINTS_PER_DECADE;
use crate::jobs::fit::{fit_on, read_frf_input};
use crate::outputs::{beside, Destination, Existing, Origin, OutputPlan};
use crate::plot::{
    overlay_colors, write_bode_overlay_png, write_nyquist_png, OverlayModel, OverlayPalette,
    OverlayPlot, OverlayTrace, FULL_LEGEND_MAX, MAX_OVERLAY_TRACES,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Longest label or title, characters.
pub const MAX_TEXT_CHARS: usize = 120;

/// The figure: Bode or Nyquist.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum PlotKind {
    /// Magnitude, phase and coherence against frequency, and the pair
    /// zoom ([`crate::plot::write_bode_overlay_png`]).
    Bode,
    /// Re H against Im H, the whole band and the pairs' band
    /// ([`crate::plot::write_nyquist_png`]).
    Nyquist,
}

impl PlotKind {
    /// `bode` or `nyquist`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Bode => "bode",
            Self::Nyquist => "nyquist",
        }
    }
}

/// An overlay (`bench plot bode|nyquist`, the daemon's `plot`). Paths are
/// read by the process that runs the job: the daemon takes absolute paths
/// only.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlotRequest {
    /// `bode` or `nyquist`.
    pub kind: PlotKind,
    /// The FRFs: `bench chirp` CSVs, recordings (`.mcap`, `.mcap.part`:
    /// their `/sysid/frf`) or campaign directories (every done cell's
    /// `cells/NNN/frf.csv`). Their frequency grids may differ.
    pub inputs: Vec<PathBuf>,
    /// Bench config (TOML): the model drawn, and the path model of every
    /// fit (as `bench fit --config`). Absent: each input is fitted with
    /// the config a recording holds, a campaign's `bench.toml`, else the
    /// built-in bench; the model is the first recording's config, else the
    /// first campaign's, else the built-in bench.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub config: Option<PathBuf>,
    /// Draw no model.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub no_model: bool,
    /// One name per input, in order (a campaign's names its cells
    /// `NAME cell NNN`). Absent: a file's name, a campaign directory's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub labels: Option<Vec<String>>,
    /// The figure's title. Absent: what is drawn and how many FRFs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub title: Option<String>,
}

impl PlotRequest {
    /// An overlay of `kind` of `inputs` with the defaults.
    pub fn new(kind: PlotKind, inputs: Vec<PathBuf>) -> Self {
        Self {
            kind,
            inputs,
            config: None,
            no_model: false,
            labels: None,
            title: None,
        }
    }

    /// Checks the request's shape before anything is read: at least one
    /// input, one label per input (1 to [`MAX_TEXT_CHARS`] printable
    /// characters each), a title of at most [`MAX_TEXT_CHARS`] printable
    /// characters.
    ///
    /// # Errors
    /// [`RunError::BadOption`] naming `inputs`, `labels` or `title`.
    pub fn check(&self) -> Result<(), RunError> {
        if self.inputs.is_empty() {
            return Err(RunError::option(
                "inputs",
                "",
                "at least one FRF (CSV, recording or campaign directory) is needed",
            ));
        }
        let printable = |s: &str| !s.chars().any(char::is_control);
        if let Some(labels) = &self.labels {
            if labels.len() != self.inputs.len() {
                return Err(RunError::option(
                    "labels",
                    "",
                    format!(
                        "{} label{} for {} input{}: give one per input, in order",
                        labels.len(),
                        if labels.len() == 1 { "" } else { "s" },
                        self.inputs.len(),
                        if self.inputs.len() == 1 { "" } else { "s" }
                    ),
                ));
            }
            for l in labels {
                let n = l.chars().count();
                if l.trim().is_empty() || n > MAX_TEXT_CHARS || !printable(l) {
                    return Err(RunError::option(
                        "labels",
                        format!("{l:?}"),
                        format!("a label is 1 to {MAX_TEXT_CHARS} printable characters, not blank"),
                    ));
                }
            }
        }
        if let Some(t) = &self.title {
            if t.chars().count() > MAX_TEXT_CHARS || !printable(t) {
                return Err(RunError::option(
                    "title",
                    format!("{t:?}"),
                    format!("a title is at most {MAX_TEXT_CHARS} printable characters"),
                ));
            }
        }
        Ok(())
    }
}

/// A done cell of a campaign, as the overlay reads it.
#[derive(Debug, Clone, PartialEq)]
pub struct PlotCell {
    /// Cell index in the grid.
    pub index: usize,
    /// Operating point Y1o, m.
    pub operating_point_m: f64,
    /// Mass asymmetry Δm23 (the one the trim masses gave, on hardware).
    pub mass_asymmetry: f64,
    /// Its FRF (`DIR/cells/NNN/frf.csv`).
    pub frf_csv: PathBuf,
}

/// One input as the job reads it.
#[derive(Debug, Clone, PartialEq)]
pub enum PlotInput {
    /// A CSV or a recording.
    File(PathBuf),
    /// A campaign directory's done cells.
    Cells {
        /// The directory.
        dir: PathBuf,
        /// Its bench config's text (`bench.toml`).
        config_toml: String,
        /// Its beam length L, m (for Y1o in % of L).
        beam_length_m: f64,
        /// The done cells.
        cells: Vec<PlotCell>,
    },
}

/// An overlay to run: the request, its inputs resolved, where it goes.
#[derive(Debug, Clone)]
pub struct PlotOptions {
    /// What to draw.
    pub request: PlotRequest,
    /// The inputs (campaign directories expanded), in request order.
    pub inputs: Vec<PlotInput>,
    /// The figure; `None`: beside the first input, `<stem>.bode-overlay.png`
    /// or `<stem>.nyquist-overlay.png` (a campaign: `DIR/bode-overlay.png`).
    pub out: Option<PathBuf>,
    /// What to do with an existing figure.
    pub existing: Existing,
}

/// The overlay of `request` on `inputs` (its paths, campaign directories
/// expanded: [`crate::campaign::job::plot_inputs`]) with its figure where
/// `dest` puts it: locally `--out` ([`run_plot`] names it beside the first
/// input otherwise), on the daemon its stamped name. The command line and
/// the daemon both plan an overlay here.
pub fn plan_plot(request: PlotRequest, inputs: Vec<PlotInput>, dest: &Destination) -> PlotOptions {
    let suffix = format!(".{}.png", request.kind.as_str());
    PlotOptions {
        out: dest.optional("out", true, |stem| beside(stem, &suffix)),
        request,
        inputs,
        existing: dest.existing(),
    }
}

/// The model drawn.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
#[schemars(rename = "PlottedModel")]
pub struct ModelSummary {
    /// Where its bench config came from.
    pub config: String,
    /// Its operating point Y1o, m.
    pub operating_point_m: f64,
    /// Its operating point as a fraction of the beam length L.
    pub operating_point_fraction_of_l: f64,
    /// Its mass asymmetry Δm23.
    pub mass_asymmetry: f64,
}

/// One FRF of the overlay: what it is, how it is drawn, and its fit and
/// verdict as `bench fit` gives them.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct TraceSummary {
    /// Its name in the legend.
    pub label: String,
    /// The file read: the input, or the cell's `frf.csv`.
    pub input: PathBuf,
    /// The campaign directory of a cell.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub campaign: Option<PathBuf>,
    /// The cell's index in its campaign's grid.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cell: Option<usize>,
    /// A cell's operating point Y1o, m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub operating_point_m: Option<f64>,
    /// A cell's mass asymmetry Δm23.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass_asymmetry: Option<f64>,
    /// Its colour, `#rrggbb`.
    pub color: String,
    /// The bench config of its fit's path model: `--config`, the one the
    /// recording holds, the campaign's `bench.toml`, or the built-in one.
    pub config: String,
    /// Sample period of the fit's path model, s.
    pub period_s: f64,
    /// Amplifier bandwidth of the fit's path model, Hz.
    pub amplifier_bandwidth_hz: f64,
    /// Lines of the FRF.
    pub points: usize,
    /// Lines with coherence at or above the identification threshold
    /// (0.5; the others are drawn faint).
    pub coherent_points: usize,
    /// Its lowest and highest frequency, Hz.
    pub band_hz: [f64; 2],
    /// Its legend entry in full: the label, the verdict and why.
    pub legend: String,
    /// The modal fit, as `bench fit --json` gives it (`null`: none could
    /// be made; see `verdict.reason`).
    pub fit: Option<ModalFit>,
    /// Both tests and the CMP-CNMP verdict, as `bench fit --json` gives
    /// them.
    pub verdict: Verdict,
    /// The fit is flagged ([`ModalFit::trusted`] is false): not to be
    /// trusted, its flags in `fit.quality.flags`.
    pub flagged: bool,
}

/// The result of an overlay.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct PlotSummary {
    /// `bode` or `nyquist`.
    pub kind: PlotKind,
    /// The figure written.
    pub plot: PathBuf,
    /// Its title.
    pub title: String,
    /// `qualitative` or `sequential` (viridis).
    pub palette: String,
    /// What the colours' order means, when sequential.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub colors_note: Option<String>,
    /// The model drawn (`null` with `no_model`).
    pub model: Option<ModelSummary>,
    /// The frequency axis, Hz: every trace's band.
    pub band_hz: [f64; 2],
    /// The pair zoom's window, Hz (`null`: no input resolved a pair).
    pub pair_zoom_hz: Option<[f64; 2]>,
    /// The FRFs in drawing order (the last on top).
    pub traces: Vec<TraceSummary>,
}

impl PlotSummary {
    /// The labels of the traces whose fit is flagged (`bench plot` exits
    /// 9 when there are any).
    pub fn flagged(&self) -> Vec<&str> {
        self.traces
            .iter()
            .filter(|t| t.flagged)
            .map(|t| t.label.as_str())
            .collect()
    }
}

/// One FRF read, before its fit.
struct Loaded {
    label: String,
    /// The label of a legend in columns (a cell's without `cell` and the
    /// quantities' names).
    short_label: String,
    input: PathBuf,
    campaign: Option<PathBuf>,
    cell: Option<PlotCell>,
    frf: Frf,
    cfg: BenchConfig,
    config_source: String,
}

/// The bench config given with `config`, with its name.
fn given_config(path: &Path) -> Result<(BenchConfig, String), RunError> {
    BenchConfig::load(path)
        .map(|c| (c, path.display().to_string()))
        .map_err(|e| match e {
            // Refused as an input (crate::input_file): `config PATH: why`.
            e @ crate::config::ConfigError::NotAConfigFile { .. } => super::config_error(e),
            e => RunError::option("config", path.display(), e.to_string()),
        })
}

fn builtin() -> Result<(BenchConfig, String), RunError> {
    BenchConfig::from_toml(BUILTIN_CONFIG_TOML, Path::new(BUILTIN_CONFIG_NAME))
        .map(|c| (c, BUILTIN_CONFIG_NAME.to_string()))
        .map_err(|e| RunError::BadInput(e.to_string()))
}

/// The default figure beside the first input.
fn default_out(first: &PlotInput, kind: PlotKind) -> PathBuf {
    match first {
        PlotInput::File(p) => beside(p, &format!(".{}-overlay.png", kind.as_str())),
        PlotInput::Cells { dir, .. } => dir.join(format!("{}-overlay.png", kind.as_str())),
    }
}

/// The name of `p` for a legend: its file name.
fn file_name(p: &Path) -> String {
    p.file_name().map_or_else(
        || p.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// Reads every input (campaign cells sorted by asymmetry, then operating
/// point) with the config its fit uses.
fn read_inputs(
    opts: &PlotOptions,
    given: Option<&(BenchConfig, String)>,
) -> Result<Vec<Loaded>, RunError> {
    let req = &opts.request;
    // Files by their names, unless two share one: then as given.
    let names: Vec<String> = opts
        .inputs
        .iter()
        .filter_map(|i| match i {
            PlotInput::File(p) => Some(file_name(p)),
            PlotInput::Cells { .. } => None,
        })
        .collect();
    let unique = |n: &String| names.iter().filter(|m| *m == n).count() == 1;
    let several = opts.inputs.len() > 1;
    let mut out = Vec::new();
    for (k, input) in opts.inputs.iter().enumerate() {
        let user = req.labels.as_ref().map(|l| l[k].clone());
        match input {
            PlotInput::File(p) => {
                let subject = p.display().to_string();
                let bad = |reason: String| RunError::option("inputs", &subject, reason);
                let read = read_frf_input(p).map_err(bad)?;
                let (cfg, config_source) = match (given, &read.recorded_config) {
                    (Some((c, s)), _) => (c.clone(), s.clone()),
                    (None, Some(t)) => (
                        BenchConfig::from_toml(t, p)
                            .map_err(|e| bad(format!("its recorded bench.config: {e}")))?,
                        format!("recorded in {subject}"),
                    ),
                    (None, None) => builtin()?,
                };
                let label = user.unwrap_or_else(|| {
                    let n = file_name(p);
                    if unique(&n) {
                        n
                    } else {
                        subject.clone()
                    }
                });
                out.push(Loaded {
                    short_label: label.clone(),
                    label,
                    input: p.clone(),
                    campaign: None,
                    cell: None,
                    frf: read.frf,
                    cfg,
                    config_source,
                });
            }
            PlotInput::Cells {
                dir,
                config_toml,
                beam_length_m,
                cells,
            } => {
                if cells.is_empty() {
                    return Err(RunError::option(
                        "inputs",
                        dir.display(),
                        "the campaign has no done cell: nothing to plot (run or resume it first)",
                    ));
                }
                let bench_toml = dir.join("bench.toml");
                let (cfg, config_source) = match given {
                    Some((c, s)) => (c.clone(), s.clone()),
                    None => (
                        BenchConfig::from_toml(config_toml, &bench_toml).map_err(|e| {
                            RunError::option("inputs", dir.display(), e.to_string())
                        })?,
                        bench_toml.display().to_string(),
                    ),
                };
                let prefix = user.or_else(|| several.then(|| file_name(dir)));
                let mut sorted = cells.clone();
                sorted.sort_by(|a, b| {
                    a.mass_asymmetry
                        .total_cmp(&b.mass_asymmetry)
                        .then(a.operating_point_m.total_cmp(&b.operating_point_m))
                        .then(a.index.cmp(&b.index))
                });
                for c in sorted {
                    let name = format!(
                        "cell {:03} (Y1o {:.1} % of L, Δm23 {:+.1} %)",
                        c.index,
                        100.0 * c.operating_point_m / beam_length_m,
                        100.0 * c.mass_asymmetry
                    );
                    let short = format!(
                        "{:03} ({:.1} %, {:+.1} %)",
                        c.index,
                        100.0 * c.operating_point_m / beam_length_m,
                        100.0 * c.mass_asymmetry
                    );
                    let (label, short_label) = match &prefix {
                        Some(p) => (format!("{p} {name}"), format!("{p} {short}")),
                        None => (name, short),
                    };
                    let subject = format!("{} cell {:03}", dir.display(), c.index);
                    let read = read_frf_input(&c.frf_csv)
                        .map_err(|r| RunError::option("inputs", &subject, r))?;
                    out.push(Loaded {
                        label,
                        short_label,
                        input: c.frf_csv.clone(),
                        campaign: Some(dir.clone()),
                        cell: Some(c),
                        frf: read.frf,
                        cfg: cfg.clone(),
                        config_source: config_source.clone(),
                    });
                }
            }
        }
        if out.len() > MAX_OVERLAY_TRACES {
            return Err(RunError::option(
                "inputs",
                "",
                format!(
                    "more than {MAX_OVERLAY_TRACES} FRFs: an overlay draws at most {MAX_OVERLAY_TRACES} (plot fewer inputs or cells)"
                ),
            ));
        }
    }
    Ok(out)
}

/// The model's bench config: `config`, else the first recording's, else
/// the first campaign's, else the built-in one.
fn model_config(
    opts: &PlotOptions,
    given: Option<&(BenchConfig, String)>,
    loaded: &[Loaded],
) -> Result<(BenchConfig, String), RunError> {
    if let Some(g) = given {
        return Ok(g.clone());
    }
    let recorded = loaded
        .iter()
        .find(|l| l.config_source.starts_with("recorded in "));
    if let Some(l) = recorded {
        return Ok((l.cfg.clone(), l.config_source.clone()));
    }
    let campaign = opts.inputs.iter().find_map(|i| match i {
        PlotInput::Cells { dir, .. } => loaded.iter().find(|l| l.campaign.as_ref() == Some(dir)),
        PlotInput::File(_) => None,
    });
    match campaign {
        Some(l) => Ok((l.cfg.clone(), l.config_source.clone())),
        None => builtin(),
    }
}

fn answer(v: Option<bool>) -> &'static str {
    match v {
        Some(true) => "CMP-CNMP zeros",
        Some(false) => "no CMP-CNMP zeros",
        None => "undecided",
    }
}

/// The legend entries of a trace, in full (`label`) and in short
/// (`short_label`, for a legend in columns): the verdict with the net
/// phase across the pair and how sure it is, as `bench fit` prints them
/// (the same numbers, the same reasons); in short the answer and the net
/// phase first, then how sure (`both tests`, `one test`, or why
/// undecided), cut to the column by the figure.
fn legend_texts(label: &str, short_label: &str, flagged: bool, v: &Verdict) -> (String, String) {
    let flag = if flagged { "FLAGGED fit, " } else { "" };
    let net = v
        .phase_test
        .pair
        .map(|p| format!(", net phase {:.0}°", p.net_phase_deg))
        .unwrap_or_default();
    let head = format!("{label}: {flag}{}{net}", answer(v.cmp_cnmp));
    let full = match &v.reason {
        Some(r) => format!("{head} ({r})"),
        None => format!(
            "{head} (both tests; residue confidence {:.0} %)",
            100.0 * v.residue_test.confidence
        ),
    };
    let short_answer = match v.cmp_cnmp {
        Some(true) => "CMP-CNMP",
        Some(false) => "no CMP-CNMP",
        None => "undecided",
    };
    let short_net = v
        .phase_test
        .pair
        .map(|p| format!(" {:.0}°", p.net_phase_deg))
        .unwrap_or_default();
    let short_head = format!("{short_label}: {flag}{short_answer}{short_net}");
    let short = match (&v.reason, v.cmp_cnmp) {
        (None, _) => format!("{short_head}, both tests"),
        (Some(_), Some(_)) => format!("{short_head}, one test"),
        (Some(r), None) => format!("{short_head}: {r}"),
    };
    (full, short)
}

fn hex(c: plotters::style::RGBColor) -> String {
    format!("#{:02x}{:02x}{:02x}", c.0, c.1, c.2)
}

/// Runs an overlay.
///
/// # Errors
/// See the module docs; nothing is written on an error.
pub fn run_plot(opts: &PlotOptions) -> Result<PlotSummary, RunError> {
    let req = &opts.request;
    req.check()?;
    if opts.inputs.len() != req.inputs.len() {
        return Err(RunError::option(
            "inputs",
            "",
            "the resolved inputs do not match the request's",
        ));
    }
    let given = req.config.as_deref().map(given_config).transpose()?;
    let loaded = read_inputs(opts, given.as_ref())?;
    // The figure, checked before anything is computed.
    let out = opts
        .out
        .clone()
        .unwrap_or_else(|| default_out(&opts.inputs[0], req.kind));
    let origin = if opts.out.is_some() {
        Origin::Given
    } else {
        Origin::Derived
    };
    // Never written over an input (rule 6 of crate::outputs).
    let mut plan = OutputPlan::new(opts.existing)
        .derived_from("the first input")
        .with_output("out", &out, origin)
        .with_inputs("inputs", loaded.iter().map(|l| &l.input));
    if let Some(c) = &req.config {
        plan = plan.with_input("config", c);
    }
    plan.check()?;
    let ids = fit_traces(&loaded)?;
    let model = if req.no_model {
        None
    } else {
        Some(model_config(opts, given.as_ref(), &loaded)?)
    };

    let n = loaded.len();
    let (palette, colors_note) = overlay_palette(&loaded, &opts.inputs);
    let colors = overlay_colors(palette, n);

    let texts: Vec<(String, String)> = loaded
        .iter()
        .zip(&ids)
        .map(|(l, id)| {
            let flagged = id.fit.as_ref().is_some_and(|f| !f.trusted());
            legend_texts(&l.label, &l.short_label, flagged, &id.verdict)
        })
        .collect();
    let modes: Vec<Vec<f64>> = ids
        .iter()
        .map(|id| {
            id.fit.as_ref().map_or_else(Vec::new, |f| {
                f.modes
                    .iter()
                    .filter(|m| m.in_path)
                    .map(|m| m.frequency_hz)
                    .collect()
            })
        })
        .collect();
    let traces: Vec<OverlayTrace<'_>> = loaded
        .iter()
        .enumerate()
        .map(|(i, l)| OverlayTrace {
            legend: &texts[i].0,
            legend_short: &texts[i].1,
            frf: &l.frf,
            color: colors[i],
            pair: ids[i].verdict.phase_test.pair,
            modes_hz: &modes[i],
        })
        .collect();

    // The model over the traces' band.
    let shell = OverlayPlot {
        title: "",
        traces: &traces,
        colors_note: colors_note.as_deref(),
        model: None,
    };
    let band = shell.band_hz();
    let window = shell.pair_zoom_hz();
    let model_curve = match &model {
        Some((cfg, _)) => Some(model_response(cfg, &band, window.as_ref())?),
        None => None,
    };
    let model_label = model.as_ref().map(|(cfg, source)| {
        format!(
            "model: {source}, Y1o {:.1} % of L, Δm23 {:+.1} %",
            100.0 * cfg.plant.operating_point_m / cfg.plant.beam.length_m,
            100.0 * cfg.plant.mass_asymmetry
        )
    });
    let title = req.title.clone().unwrap_or_else(|| {
        format!(
            "{} of {n} measured FRF{} (x1 / current)",
            match req.kind {
                PlotKind::Bode => "Bode",
                PlotKind::Nyquist => "Nyquist",
            },
            if n == 1 { "" } else { "s" }
        )
    });
    let plot = OverlayPlot {
        title: &title,
        model: match (&model_curve, &model_label) {
            (Some((f, h)), Some(label)) => Some(OverlayModel {
                label,
                frequency_hz: f,
                response_m_per_a: h,
            }),
            _ => None,
        },
        ..shell
    };
    let pair_zoom_hz = window.map(|w| [w.start, w.end]);
    match req.kind {
        PlotKind::Bode => write_bode_overlay_png(&out, opts.existing, &plot),
        PlotKind::Nyquist => write_nyquist_png(&out, opts.existing, &plot),
    }
    .map_err(|e| RunError::Output {
        path: out.clone(),
        reason: e.to_string(),
    })?;

    let summaries = trace_summaries(loaded, ids, texts, &colors);
    Ok(PlotSummary {
        kind: req.kind,
        plot: out,
        title,
        palette: match palette {
            OverlayPalette::Qualitative => "qualitative",
            OverlayPalette::Sequential => "sequential",
        }
        .to_string(),
        colors_note,
        model: model.map(|(cfg, source)| ModelSummary {
            config: source,
            operating_point_m: cfg.plant.operating_point_m,
            operating_point_fraction_of_l: cfg.plant.operating_point_m / cfg.plant.beam.length_m,
            mass_asymmetry: cfg.plant.mass_asymmetry,
        }),
        band_hz: [band.start, band.end],
        pair_zoom_hz,
        traces: summaries,
    })
}

/// Every trace fitted as `bench fit` fits it, in parallel.
///
/// # Errors
/// [`RunError::BadOption`] naming `inputs` and the input (or campaign
/// cell) whose FRF cannot be fitted.
fn fit_traces(loaded: &[Loaded]) -> Result<Vec<crate::jobs::chirp::Identified>, RunError> {
    let fits = loaded
        .par_iter()
        .map(|l| fit_on(&l.frf, &l.cfg))
        .collect::<Vec<_>>();
    let mut ids = Vec::with_capacity(fits.len());
    for (l, f) in loaded.iter().zip(fits) {
        let subject = match (&l.campaign, &l.cell) {
            (Some(d), Some(c)) => format!("{} cell {:03}", d.display(), c.index),
            _ => l.input.display().to_string(),
        };
        ids.push(f.map_err(|r| RunError::option("inputs", subject, r))?);
    }
    Ok(ids)
}

/// The overlay's colours: a campaign's cells (and only they) by a
/// sequential map in their order; a few files each its own; many,
/// sequential in order. With the sequential map, the note that says how
/// to read it.
fn overlay_palette(loaded: &[Loaded], inputs: &[PlotInput]) -> (OverlayPalette, Option<String>) {
    let n = loaded.len();
    let one_campaign = loaded.iter().all(|l| l.cell.is_some())
        && inputs
            .iter()
            .filter(|i| matches!(i, PlotInput::Cells { .. }))
            .count()
            == 1;
    let palette = if (one_campaign && n > 1) || n > crate::plot::OVERLAY_QUALITATIVE.len() {
        OverlayPalette::Sequential
    } else {
        OverlayPalette::Qualitative
    };
    let colors_note = (palette == OverlayPalette::Sequential).then(|| {
        if one_campaign {
            let distinct = |f: fn(&PlotCell) -> f64| {
                let mut v: Vec<f64> = loaded
                    .iter()
                    .filter_map(|l| l.cell.as_ref().map(f))
                    .collect();
                v.sort_by(f64::total_cmp);
                v.dedup();
                v.len()
            };
            let order = match (
                distinct(|c| c.mass_asymmetry),
                distinct(|c| c.operating_point_m),
            ) {
                (1, _) => "by operating point Y1o",
                (_, 1) => "by mass asymmetry Δm23",
                _ => "by mass asymmetry Δm23, then operating point Y1o",
            };
            format!(
                "colours: viridis, dark to light {order} (the order of the legend){}",
                if n > FULL_LEGEND_MAX {
                    "; cells as NNN (Y1o in % of L, Δm23)"
                } else {
                    ""
                }
            )
        } else {
            format!(
                "colours: viridis, dark to light in the order of the legend{}",
                if n > FULL_LEGEND_MAX && loaded.iter().any(|l| l.cell.is_some()) {
                    "; cells as NNN (Y1o in % of L, Δm23)"
                } else {
                    ""
                }
            )
        }
    });
    (palette, colors_note)
}

/// Each trace's summary: its input, its cell, its colour, its fit and
/// verdict.
fn trace_summaries(
    loaded: Vec<Loaded>,
    ids: Vec<crate::jobs::chirp::Identified>,
    texts: Vec<(String, String)>,
    colors: &[plotters::style::RGBColor],
) -> Vec<TraceSummary> {
    loaded
        .into_iter()
        .zip(ids)
        .zip(texts)
        .enumerate()
        .map(|(i, ((l, id), (legend, _)))| {
            let f = &l.frf.frequency_hz;
            TraceSummary {
                label: l.label,
                input: l.input,
                campaign: l.campaign,
                cell: l.cell.as_ref().map(|c| c.index),
                operating_point_m: l.cell.as_ref().map(|c| c.operating_point_m),
                mass_asymmetry: l.cell.as_ref().map(|c| c.mass_asymmetry),
                color: hex(colors[i]),
                config: l.config_source,
                period_s: id.path.period_s,
                amplifier_bandwidth_hz: id.path.amplifier_bandwidth_hz,
                points: f.len(),
                coherent_points: l
                    .frf
                    .coherence
                    .iter()
                    .filter(|c| **c >= MIN_COHERENCE)
                    .count(),
                band_hz: [
                    f.first().copied().unwrap_or(f64::NAN),
                    f.last().copied().unwrap_or(f64::NAN),
                ],
                legend,
                flagged: id.fit.as_ref().is_some_and(|f| !f.trusted()),
                fit: id.fit,
                verdict: id.verdict,
            }
        })
        .collect()
}

/// Lines of the model inside the pair zoom's window, on top of its log
/// grid: its lightly damped pair keeps its shape in the zoom (and as
/// circles in the Nyquist plane).
const MODEL_POINTS_IN_WINDOW: usize = 4000;

/// The model of `cfg` (the zero-order-hold plant with its amplifier, as
/// `bench chirp` draws it) on a log grid over `band`,
/// [`MODEL_POINTS_PER_DECADE`] a decade, and [`MODEL_POINTS_IN_WINDOW`]
/// evenly spaced over the pair zoom's `window`.
///
/// # Errors
/// [`RunError::BadOption`] naming `config` when its `[plant]` cannot be
/// modelled.
fn model_response(
    cfg: &BenchConfig,
    band: &std::ops::Range<f64>,
    window: Option<&std::ops::Range<f64>>,
) -> Result<(Vec<f64>, Vec<C64>), RunError> {
    let model = bench_plant::model::Sr4dof::new(cfg.plant)
        .map_err(|e| RunError::option("config", "", format!("the model: {e}")))?;
    let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
    let zoh = bench_plant::sim::ZohPlant::new(&model, &cfg.actuator, period_s);
    let mut f = log_grid(band.start, band.end, MODEL_POINTS_PER_DECADE);
    if let Some(w) = window.filter(|w| w.end > w.start) {
        let n = MODEL_POINTS_IN_WINDOW;
        f.extend((0..=n).map(|i| w.start + (w.end - w.start) * i as f64 / n as f64));
        f.sort_by(f64::total_cmp);
        f.dedup();
    }
    let h = f.iter().map(|&f| zoh.frf(f)).collect();
    Ok((f, h))
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn key(e: RunError) -> &'static str {
        match e {
            RunError::BadOption { key, .. } => key,
            e => panic!("{e}"),
        }
    }

    #[test]
    fn request_shapes() {
        let ok = PlotRequest::new(PlotKind::Bode, vec!["a.csv".into(), "b.csv".into()]);
        assert!(ok.check().is_ok());
        let with = |f: fn(&mut PlotRequest)| {
            let mut r = ok.clone();
            f(&mut r);
            r
        };
        for (r, k) in [
            (with(|r| r.inputs.clear()), "inputs"),
            (with(|r| r.labels = Some(vec!["a".into()])), "labels"),
            (
                with(|r| r.labels = Some(vec!["a".into(), " ".into()])),
                "labels",
            ),
            (
                with(|r| r.labels = Some(vec!["a".into(), "b\nc".into()])),
                "labels",
            ),
            (
                with(|r| r.labels = Some(vec!["a".into(), "x".repeat(121)])),
                "labels",
            ),
            (with(|r| r.title = Some("t\u{7}".into())), "title"),
            (with(|r| r.title = Some("t".repeat(121))), "title"),
        ] {
            assert_eq!(key(r.check().unwrap_err()), k, "{r:?}");
        }
    }

    #[test]
    fn wire_form() {
        let r: PlotRequest = serde_json::from_value(json!({
            "kind": "nyquist", "inputs": ["/x/a.mcap"], "labels": ["a"]
        }))
        .unwrap();
        assert_eq!(r.kind, PlotKind::Nyquist);
        assert_eq!(
            serde_json::to_value(&r).unwrap(),
            json!({ "kind": "nyquist", "inputs": ["/x/a.mcap"], "labels": ["a"] })
        );
        for bad in [
            json!({ "kind": "polar", "inputs": [] }),
            json!({ "kind": "bode", "inputs": [], "out": "/x.png" }),
            json!({ "inputs": [] }),
        ] {
            assert!(
                serde_json::from_value::<PlotRequest>(bad.clone()).is_err(),
                "{bad}"
            );
        }
    }
}
