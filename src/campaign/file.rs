//! The campaign file (TOML): which bench, which grid, which chirp, and the
//! cells it makes.
//!
//! ```toml
//! description = "thesis Fig 5-10"
//! config = "sr4dof-ch5.toml"        # bench config, relative to this file
//! seed = 510                        # cell seeds derive from it
//! settle_s = 1.0                    # wait before each cell's chirp, s
//! mass_increment_kg = 0.0005        # one trim mass, kg (hardware prompts)
//!
//! [grid]
//! operating_point_pct = { from = 0.6, to = 9.0, step = 0.6 }  # % of L
//! mass_asymmetry = { from = -0.08, to = 0.10, step = 0.02 }   # fraction
//!
//! [chirp]                           # overrides of the config's [chirp]
//! duration_s = 60.0
//! ```
//!
//! Each axis is a list (`[0.6, 1.2]`) or a range (`{ from, to, step }`,
//! both ends included), given in SI (`operating_point_m`,
//! `mass_asymmetry`) or in percent (`operating_point_pct` of the beam
//! length L, `mass_asymmetry_pct`), one form per axis. Unknown keys are
//! refused.

use crate::config::BenchConfig;
use bench_hal::param::ParamError;
use bench_plant::model::ranges;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The shipped campaign (`bench-config/campaign-fig5-10.toml`, the
/// thesis' Fig 5-10 grid on the Chapter 5 bench), built in: `bench campaign
/// run` without a file runs it with the built-in bench config, and `bench
/// campaign default` prints it.
pub const BUILTIN_CAMPAIGN_TOML: &str = include_str!("../../bench-config/campaign-fig5-10.toml");

/// How messages and the campaign directory's origin name the built-in
/// campaign.
pub const BUILTIN_CAMPAIGN_NAME: &str = "built-in (campaign-fig5-10)";

/// What each cell keeps on disk (`keep` in the campaign file, `--keep` on
/// `bench campaign run`). The summary (`summary.json`, with the verdict,
/// the modal fit and the FRF's figures) is always kept.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize, serde::Serialize, schemars::JsonSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum Keep {
    /// Everything a `bench chirp` writes: the recording (`chirp.mcap`), the
    /// FRF CSV, the Bode plot and the summary (a default 60 s cell: 5.8 MB).
    #[default]
    Recording,
    /// The FRF CSV and the summary (~100 kB a cell): enough for `bench
    /// fit`, `bench design` and `bench plot` on the cells, not to look at
    /// the time series again.
    Frf,
    /// The summary only (~6.5 kB a cell, and its 9 kB catalogue row): the
    /// verdicts and the map.
    Summary,
}

impl Keep {
    /// The name in files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Recording => "recording",
            Self::Frf => "frf",
            Self::Summary => "summary",
        }
    }

    /// Whether a cell keeps its `i`th file of
    /// [`crate::campaign::run::CELL_FILES`] (recording, FRF CSV, plot,
    /// summary).
    pub fn keeps(self, i: usize) -> bool {
        match self {
            Self::Recording => true,
            Self::Frf => i == 1 || i == 3,
            Self::Summary => i == 3,
        }
    }
}

impl std::str::FromStr for Keep {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "recording" => Ok(Self::Recording),
            "frf" => Ok(Self::Frf),
            "summary" => Ok(Self::Summary),
            _ => Err(format!(
                "{s:?} is not one of recording, frf, summary (what each cell keeps)"
            )),
        }
    }
}

/// Where a campaign's bench config is read from.
#[derive(Debug, Clone, Copy)]
pub enum ConfigFrom<'a> {
    /// The file the campaign's `config` key names (relative to the
    /// campaign file).
    Named,
    /// This file instead (a campaign directory's copy).
    File(&'a Path),
    /// This text, named `name` in messages (the built-in config, or a
    /// text already read).
    Text {
        /// How messages name it.
        name: &'a Path,
        /// The TOML.
        text: &'a str,
    },
}

/// Most cells of one campaign: 10 000 chirps of 60 s are a week of bench
/// time; a larger grid is a typo.
pub const MAX_CELLS: usize = 10_000;

/// Range of `settle_s`, s: 0 to 10 minutes.
pub const SETTLE_S: (f64, f64) = (0.0, 600.0);

/// Range of `mass_increment_kg`, kg: 10 mg to 100 g.
pub const MASS_INCREMENT_KG: (f64, f64) = (1e-5, 0.1);

/// Two grid values closer than this (relative to the axis span, or
/// absolute 1e-12 for a zero span) are the same cell.
pub const DUPLICATE_TOLERANCE: f64 = 1e-9;

/// One axis as written: a list or an inclusive range.
#[derive(Debug, Clone, PartialEq)]
pub enum AxisSpec {
    /// Explicit values.
    List(Vec<f64>),
    /// `from`, `from + step`, … up to `to` (included).
    Range {
        /// First value.
        from: f64,
        /// Last value.
        to: f64,
        /// Increment, > 0.
        step: f64,
    },
}

/// `[grid]` as written (each axis a list or a `{ from, to, step }`
/// table, read by [`AxisSpec::from_value`] so that a refusal names the
/// element).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridSpec {
    /// Operating points Y1o, m.
    pub operating_point_m: Option<toml::Value>,
    /// Operating points in % of the beam length L.
    pub operating_point_pct: Option<toml::Value>,
    /// Mass asymmetries Δm23 = m2/m3 − 1 (fractions, 0.02 = 2 %).
    pub mass_asymmetry: Option<toml::Value>,
    /// Mass asymmetries in %.
    pub mass_asymmetry_pct: Option<toml::Value>,
}

impl AxisSpec {
    /// An axis from its TOML value: an array of numbers, or a table with
    /// exactly `from`, `to` and `step`.
    ///
    /// # Errors
    /// `(key, reason)`: the dotted key of the offending element
    /// (`grid.mass_asymmetry[2]`, `grid.operating_point_pct.step`).
    pub fn from_value(key: &str, v: &toml::Value) -> Result<Self, (String, String)> {
        let number = |k: String, v: &toml::Value| match v {
            toml::Value::Float(f) => Ok(*f),
            toml::Value::Integer(i) => Ok(*i as f64),
            other => Err((k, format!("expected a number, got {}", other.type_str()))),
        };
        match v {
            toml::Value::Array(a) => a
                .iter()
                .enumerate()
                .map(|(i, x)| number(format!("{key}[{i}]"), x))
                .collect::<Result<Vec<_>, _>>()
                .map(Self::List),
            toml::Value::Table(t) => {
                if let Some(k) = t
                    .keys()
                    .find(|k| !["from", "to", "step"].contains(&k.as_str()))
                {
                    return Err((
                        format!("{key}.{k}"),
                        "unknown key: a range has from, to and step".into(),
                    ));
                }
                let get = |name: &str| match t.get(name) {
                    Some(x) => number(format!("{key}.{name}"), x),
                    None => Err((
                        format!("{key}.{name}"),
                        "missing: a range has from, to and step".into(),
                    )),
                };
                Ok(Self::Range {
                    from: get("from")?,
                    to: get("to")?,
                    step: get("step")?,
                })
            }
            other => Err((
                key.to_string(),
                format!(
                    "expected a list [a, b, ...] or a range {{ from, to, step }}, got {}",
                    other.type_str()
                ),
            )),
        }
    }
}

/// The campaign file as written.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CampaignSpec {
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// Bench config file, relative to the campaign file's directory.
    pub config: PathBuf,
    /// Campaign seed: each cell's simulator seed derives from it and the
    /// cell ([`cell_seed`]).
    pub seed: u64,
    /// Settle time before each cell's chirp, s.
    #[serde(default)]
    pub settle_s: f64,
    /// Mass of one trim mass the operator adds to stage 2 or 3, kg
    /// (thesis 5.2.1: 0.5 g).
    #[serde(default = "default_mass_increment")]
    pub mass_increment_kg: f64,
    /// Default output directory (relative to the working directory);
    /// `--out` overrides it.
    pub out: Option<PathBuf>,
    /// The grid.
    pub grid: GridSpec,
    /// Overrides of the bench config's `[chirp]` table (same keys, same
    /// ranges).
    #[serde(default)]
    pub chirp: Option<toml::Table>,
    /// Overrides of the bench config's `[excitation]` table (same keys,
    /// same values).
    #[serde(default)]
    pub excitation: Option<toml::Table>,
    /// What each cell keeps on disk.
    #[serde(default)]
    pub keep: Keep,
}

/// The campaign's `[chirp]` and `[excitation]` overrides, their old
/// spellings moved by the rule of a config's
/// ([`crate::config::move_old_spellings`], warning with `path`).
fn overrides(
    spec: &CampaignSpec,
    path: &Path,
) -> Result<(toml::Table, toml::Table), (String, String)> {
    let mut t = toml::Table::new();
    for (name, over) in [("chirp", &spec.chirp), ("excitation", &spec.excitation)] {
        if let Some(over) = over {
            t.insert(name.into(), toml::Value::Table(over.clone()));
        }
    }
    if let Some(note) = crate::config::move_old_spellings(&mut t)? {
        tracing::warn!("{}: {note}", path.display());
    }
    let section = |name: &str| {
        t.get(name)
            .and_then(|v| v.as_table())
            .cloned()
            .unwrap_or_default()
    };
    Ok((section("chirp"), section("excitation")))
}

fn default_mass_increment() -> f64 {
    0.0005
}

/// One cell of the grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cell {
    /// Index in row-major order (asymmetry slowest, operating point
    /// fastest), as in `cells.csv` and the journal.
    pub index: usize,
    /// Operating point Y1o, m.
    pub operating_point_m: f64,
    /// Mass asymmetry Δm23.
    pub mass_asymmetry: f64,
    /// Index on the operating-point axis.
    pub op_index: usize,
    /// Index on the asymmetry axis.
    pub dm_index: usize,
}

/// A validated campaign.
#[derive(Debug, Clone)]
pub struct Campaign {
    /// The campaign file.
    pub path: PathBuf,
    /// Its text (hashed into the journal).
    pub text: String,
    /// As parsed.
    pub spec: CampaignSpec,
    /// The bench config file.
    pub config_path: PathBuf,
    /// Its text (hashed into the journal).
    pub config_text: String,
    /// The bench config with the campaign's `[chirp]` overrides, validated.
    pub config: BenchConfig,
    /// Operating points, m, ascending as given.
    pub operating_points_m: Vec<f64>,
    /// Mass asymmetries, as given.
    pub mass_asymmetries: Vec<f64>,
}

/// Errors of the campaign file.
#[derive(Debug, thiserror::Error)]
pub enum CampaignError {
    /// The file could not be read, or is refused: not a regular file, or
    /// larger than [`Kind::Campaign`](crate::input_file::Kind::Campaign)'s
    /// limit ([`crate::input_file`]).
    #[error("campaign file {}: {}", source.path.display(), source.reason())]
    Read {
        /// Why (the file, its kind, the reason).
        #[from]
        source: crate::input_file::InputError,
    },
    /// TOML syntax, a type or an unknown key.
    #[error("campaign file {}: {message}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message, naming the key.
        message: String,
    },
    /// A value outside its range, an empty or duplicate grid.
    #[error("campaign file {}: {key}: {reason}", path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// Dotted key.
        key: String,
        /// Why.
        reason: String,
    },
    /// The bench config it names is unusable.
    #[error("campaign file {}: config: {source}", path.display())]
    Config {
        /// The campaign file.
        path: PathBuf,
        /// The config's error.
        source: crate::config::ConfigError,
    },
}

/// The seed of cell `(op_index, dm_index)` of a campaign seeded `seed`:
/// SplitMix64 (Steele, Lea & Flood 2014) over the three, so that cells get
/// unrelated noise and a re-run of the same campaign gets the same.
pub fn cell_seed(seed: u64, op_index: usize, dm_index: usize) -> u64 {
    use crate::splitmix::splitmix64 as mix;
    mix(mix(mix(seed) ^ op_index as u64) ^ ((dm_index as u64) << 32 | 0x5eed))
}

impl Campaign {
    /// Reads, parses and validates a campaign file and the bench config it
    /// names.
    ///
    /// # Errors
    /// [`CampaignError`] naming the file and the key.
    pub fn load(path: &Path) -> Result<Self, CampaignError> {
        let text =
            crate::input_file::read_to_string(path, crate::input_file::Kind::Campaign, "file")?;
        Self::from_text(path, text)
    }

    /// [`Self::load`] from text already read; `path` locates the config
    /// and names the file in messages.
    ///
    /// # Errors
    /// As [`Self::load`].
    pub fn from_text(path: &Path, text: String) -> Result<Self, CampaignError> {
        Self::from_text_with_config(path, text, None)
    }

    /// [`Self::from_text`] with the bench config read from `config_file`
    /// instead of the file the campaign names (a campaign directory's
    /// copy).
    ///
    /// # Errors
    /// As [`Self::load`].
    pub fn from_text_with_config(
        path: &Path,
        text: String,
        config_file: Option<&Path>,
    ) -> Result<Self, CampaignError> {
        Self::from_parts(
            path,
            text,
            config_file.map_or(ConfigFrom::Named, ConfigFrom::File),
        )
    }

    /// The built-in campaign ([`BUILTIN_CAMPAIGN_TOML`]) on the built-in
    /// bench config ([`crate::config::BUILTIN_CONFIG_TOML`]).
    ///
    /// # Errors
    /// None for the shipped texts (tested); as [`Self::load`] otherwise.
    pub fn builtin() -> Result<Self, CampaignError> {
        Self::from_parts(
            Path::new(BUILTIN_CAMPAIGN_NAME),
            BUILTIN_CAMPAIGN_TOML.to_string(),
            ConfigFrom::Text {
                name: Path::new(crate::config::BUILTIN_CONFIG_NAME),
                text: crate::config::BUILTIN_CONFIG_TOML,
            },
        )
    }

    /// Whether this is the built-in campaign.
    pub fn is_builtin(&self) -> bool {
        self.path == Path::new(BUILTIN_CAMPAIGN_NAME)
    }

    /// This campaign with `keep` set in its text (a comment says it came
    /// from the command line), so that the campaign directory's copy, and
    /// a resume, keep the same files.
    ///
    /// # Errors
    /// As [`Self::load`] (cannot fail for a campaign that loaded).
    pub fn with_keep(self, keep: Keep) -> Result<Self, CampaignError> {
        if keep == self.spec.keep {
            return Ok(self);
        }
        let mut doc: toml_edit::DocumentMut =
            self.text
                .parse()
                .map_err(|e: toml_edit::TomlError| CampaignError::Parse {
                    path: self.path.clone(),
                    message: e.to_string(),
                })?;
        let mut v = toml_edit::Value::from(keep.name());
        v.decor_mut()
            .set_suffix("   # what each cell keeps (set by --keep): recording, frf or summary");
        // A top-level value is written before the tables.
        doc.insert("keep", toml_edit::Item::Value(v));
        let text = doc.to_string();
        Self::from_parts(
            &self.path,
            text,
            ConfigFrom::Text {
                name: &self.config_path,
                text: &self.config_text,
            },
        )
    }

    /// [`Self::load`] from its parts: the campaign's path and text, and
    /// where its bench config comes from.
    ///
    /// # Errors
    /// As [`Self::load`].
    pub fn from_parts(
        path: &Path,
        text: String,
        config_from: ConfigFrom<'_>,
    ) -> Result<Self, CampaignError> {
        let invalid = |key: &str, reason: String| CampaignError::Invalid {
            path: path.to_path_buf(),
            key: key.to_string(),
            reason,
        };
        let spec: CampaignSpec = toml::from_str(&text).map_err(|e| CampaignError::Parse {
            path: path.to_path_buf(),
            message: crate::config::toml_error_message(&text, &e),
        })?;
        let (lo, hi) = SETTLE_S;
        if !(spec.settle_s.is_finite() && (lo..=hi).contains(&spec.settle_s)) {
            return Err(invalid(
                "settle_s",
                format!(
                    "{:?} s is outside [{lo}, {hi}] s (0 to 10 minutes)",
                    spec.settle_s
                ),
            ));
        }
        let (lo, hi) = MASS_INCREMENT_KG;
        if !(spec.mass_increment_kg.is_finite() && (lo..=hi).contains(&spec.mass_increment_kg)) {
            return Err(invalid(
                "mass_increment_kg",
                format!(
                    "{:?} kg is outside [{lo:e}, {hi}] kg (10 mg to 100 g; the thesis' trim masses are 0.5 g = 0.0005)",
                    spec.mass_increment_kg
                ),
            ));
        }
        let (config_path, config_text, config) = campaign_config(path, &spec, config_from)?;
        let length_m = config.plant.beam.length_m;
        let ops = pick_axis(
            path,
            (
                "grid.operating_point_m",
                spec.grid.operating_point_m.as_ref(),
            ),
            (
                "grid.operating_point_pct",
                spec.grid.operating_point_pct.as_ref(),
            ),
            // The campaign grid's own rounding of % of L (see the function).
            crate::jobs::point::campaign_percent_factor(length_m),
        )?;
        let dms = pick_axis(
            path,
            ("grid.mass_asymmetry", spec.grid.mass_asymmetry.as_ref()),
            (
                "grid.mass_asymmetry_pct",
                spec.grid.mass_asymmetry_pct.as_ref(),
            ),
            0.01,
        )?;
        let (op_key, op_values, op_scale, op_range) = ops;
        let (dm_key, dm_values, dm_scale, dm_range) = dms;
        // The key of value i: `key[i]` for a list; for a range, `key.from`
        // for the first value and `key.to` for any later one (the values
        // ascend, so a later value out of range means `to` is).
        let name = |key: &str, range: bool, i: usize| match (range, i) {
            (false, _) => format!("{key}[{i}]"),
            (true, 0) => format!("{key}.from"),
            (true, _) => format!("{key}.to"),
        };
        if op_values.len() * dm_values.len() > MAX_CELLS {
            return Err(invalid(
                "grid",
                format!(
                    "{} × {} = {} cells is more than {MAX_CELLS} (a week of 60 s chirps)",
                    op_values.len(),
                    dm_values.len(),
                    op_values.len() * dm_values.len()
                ),
            ));
        }
        // Every value within the model's validity, named by its key and
        // position.
        for (i, &op) in op_values.iter().enumerate() {
            let lim = ranges::OPERATING_POINT_OF_L * length_m;
            if op.abs() > lim {
                return Err(invalid(
                    &name(&op_key, op_range, i),
                    format!(
                        "{} ({op} m) is beyond 20 % of the beam length {length_m} m: outside the model's validity",
                        op / op_scale
                    ),
                ));
            }
        }
        for (i, &dm) in dm_values.iter().enumerate() {
            let (lo, hi) = ranges::MASS_ASYMMETRY;
            if !(lo..=hi).contains(&dm) {
                return Err(invalid(
                    &name(&dm_key, dm_range, i),
                    format!(
                        "{} (Δm23 = {dm}) is outside [{lo}, {hi}]: the model's mass-asymmetry range (0.02 = 2 %)",
                        dm / dm_scale
                    ),
                ));
            }
        }
        // And the model builds at every cell.
        for &dm in &dm_values {
            for &op in &op_values {
                crate::analysis::map::model_at(&config.plant, op, dm).map_err(
                    |e: ParamError| {
                        invalid(
                            "grid",
                            format!("the model at {op} m, {dm}: {}: {}", e.key, e.reason),
                        )
                    },
                )?;
            }
        }
        Ok(Self {
            path: path.to_path_buf(),
            text,
            spec,
            config_path,
            config_text,
            config,
            operating_points_m: op_values,
            mass_asymmetries: dm_values,
        })
    }

    /// The cells in row-major order (asymmetry slowest).
    pub fn cells(&self) -> Vec<Cell> {
        let n_op = self.operating_points_m.len();
        let mut out = Vec::with_capacity(n_op * self.mass_asymmetries.len());
        for (j, &dm) in self.mass_asymmetries.iter().enumerate() {
            for (i, &op) in self.operating_points_m.iter().enumerate() {
                out.push(Cell {
                    index: j * n_op + i,
                    operating_point_m: op,
                    mass_asymmetry: dm,
                    op_index: i,
                    dm_index: j,
                });
            }
        }
        out
    }

    /// The order an operator runs the cells in: one asymmetry at a time
    /// (changing masses is the slow step), the operating points up, then
    /// down for the next asymmetry (a serpentine), so that each step
    /// changes one setting by one grid step.
    pub fn serpentine(&self) -> Vec<Cell> {
        let n_op = self.operating_points_m.len();
        let cells = self.cells();
        let mut out = Vec::with_capacity(cells.len());
        for row in cells.chunks(n_op) {
            if (row[0].dm_index) % 2 == 0 {
                out.extend_from_slice(row);
            } else {
                out.extend(row.iter().rev());
            }
        }
        out
    }

    /// The simulator seed of `cell`.
    pub fn seed_of(&self, cell: &Cell) -> u64 {
        cell_seed(self.spec.seed, cell.op_index, cell.dm_index)
    }
}

/// Takes the one given form of an axis, expands it and checks it: not
/// empty, finite, no duplicates. `pct_scale` converts the percent form.
fn pick_axis(
    path: &Path,
    si: (&str, Option<&toml::Value>),
    pct: (&str, Option<&toml::Value>),
    pct_scale: f64,
) -> Result<(String, Vec<f64>, f64, bool), CampaignError> {
    let invalid = |key: &str, reason: String| CampaignError::Invalid {
        path: path.to_path_buf(),
        key: key.to_string(),
        reason,
    };
    let (key, value, scale) = match (si.1, pct.1) {
        (Some(_), Some(_)) => {
            return Err(invalid(
                pct.0,
                format!("give one of {} and {}, not both", si.0, pct.0),
            ))
        }
        (Some(s), None) => (si.0, s, 1.0),
        (None, Some(s)) => (pct.0, s, pct_scale),
        (None, None) => {
            return Err(invalid(
                si.0,
                format!("missing: give {} or {}", si.0, pct.0),
            ))
        }
    };
    let spec = AxisSpec::from_value(key, value).map_err(|(k, why)| invalid(&k, why))?;
    let is_range = matches!(spec, AxisSpec::Range { .. });
    let values: Vec<f64> = match &spec {
        AxisSpec::List(v) => {
            if v.is_empty() {
                return Err(invalid(key, "empty list: the grid has no cells".into()));
            }
            for (i, x) in v.iter().enumerate() {
                if !x.is_finite() {
                    return Err(invalid(
                        &format!("{key}[{i}]"),
                        format!("{x} is not finite"),
                    ));
                }
            }
            v.clone()
        }
        AxisSpec::Range { from, to, step } => {
            for (name, x) in [("from", from), ("to", to), ("step", step)] {
                if !x.is_finite() {
                    return Err(invalid(
                        &format!("{key}.{name}"),
                        format!("{x} is not finite"),
                    ));
                }
            }
            if *step <= 0.0 {
                return Err(invalid(
                    &format!("{key}.step"),
                    format!("{step} must be > 0"),
                ));
            }
            if to < from {
                return Err(invalid(
                    &format!("{key}.to"),
                    format!("{to} is below from = {from}: the range is reversed"),
                ));
            }
            let n = ((to - from) / step + 1e-9).floor();
            if n + 1.0 > MAX_CELLS as f64 {
                return Err(invalid(
                    &format!("{key}.step"),
                    format!("{step} makes more than {MAX_CELLS} values from {from} to {to}"),
                ));
            }
            (0..=n as usize).map(|k| from + k as f64 * step).collect()
        }
    };
    let values: Vec<f64> = values.iter().map(|v| v * scale).collect();
    let span = values
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    let mut sorted: Vec<(f64, usize)> = values.iter().copied().zip(0..).collect();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    let tol = (DUPLICATE_TOLERANCE * span).max(1e-12);
    for w in sorted.windows(2) {
        if w[1].0 - w[0].0 <= tol {
            let (a, b) = (w[0].1.min(w[1].1), w[0].1.max(w[1].1));
            return Err(invalid(
                &format!("{key}[{b}]"),
                format!("duplicates {key}[{a}]: the same cell twice"),
            ));
        }
    }
    Ok((key.to_string(), values, scale, is_range))
}

/// The keys whose values differ between two TOML texts, dotted
/// (`chirp.duration_s`, `grid.mass_asymmetry`), for "what changed" when a
/// campaign is resumed with edited files. Unparsable text counts as one
/// change, `(whole file)`.
pub fn changed_keys(old: &str, new: &str) -> Vec<String> {
    fn flatten(prefix: &str, v: &toml::Value, out: &mut BTreeMap<String, String>) {
        match v {
            toml::Value::Table(t) => {
                for (k, v) in t {
                    let key = if prefix.is_empty() {
                        k.clone()
                    } else {
                        format!("{prefix}.{k}")
                    };
                    flatten(&key, v, out);
                }
            }
            other => {
                out.insert(prefix.to_string(), other.to_string());
            }
        }
    }
    let parse = |s: &str| s.parse::<toml::Table>().ok();
    let (Some(a), Some(b)) = (parse(old), parse(new)) else {
        return vec!["(whole file)".into()];
    };
    let (mut fa, mut fb) = (BTreeMap::new(), BTreeMap::new());
    flatten("", &toml::Value::Table(a), &mut fa);
    flatten("", &toml::Value::Table(b), &mut fb);
    let mut keys: Vec<String> = fa
        .keys()
        .chain(fb.keys())
        .filter(|k| fa.get(*k) != fb.get(*k))
        .cloned()
        .collect();
    keys.sort();
    keys.dedup();
    keys
}

/// A campaign's bench config: read from where `config_from` says (the
/// campaign's `config`, relative to its directory), its old spellings
/// moved, the campaign's `[chirp]` and `[excitation]` overrides merged on
/// top, and checked. Returns its path, its text as read, and the merged
/// config.
///
/// # Errors
/// [`CampaignError`] naming the campaign or the config file and the key.
fn campaign_config(
    path: &Path,
    spec: &CampaignSpec,
    config_from: ConfigFrom<'_>,
) -> Result<(PathBuf, String, BenchConfig), CampaignError> {
    let invalid = |key: &str, reason: String| CampaignError::Invalid {
        path: path.to_path_buf(),
        key: key.to_string(),
        reason,
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    let config_err = |source| CampaignError::Config {
        path: path.to_path_buf(),
        source,
    };
    let (config_path, config_text) = match config_from {
        ConfigFrom::Text { name, text } => {
            BenchConfig::from_toml(text, name).map_err(config_err)?;
            (name.to_path_buf(), text.to_string())
        }
        ConfigFrom::File(_) | ConfigFrom::Named => {
            let config_path = if let ConfigFrom::File(p) = config_from {
                p.to_path_buf()
            } else if spec.config.is_absolute() {
                spec.config.clone()
            } else {
                dir.join(&spec.config)
            };
            // Read once, with the file checks of every config
            // (regular file, size: crate::input_file).
            let config_text = crate::config::read_text(&config_path).map_err(config_err)?;
            BenchConfig::from_toml(&config_text, &config_path).map_err(config_err)?;
            (config_path, config_text)
        }
    };
    let mut table: toml::Table = toml::from_str(&config_text).map_err(|e| {
        config_err(crate::config::ConfigError::Parse {
            path: config_path.clone(),
            message: e.to_string(),
        })
    })?;
    // The bench config's old spellings where they are now (its own
    // load above warned), then the campaign's overrides on top: its
    // `[chirp] kind`, the old spelling, is `[excitation] kind`.
    crate::config::move_old_spellings(&mut table).map_err(|(k, why)| invalid(&k, why))?;
    let (chirp_over, excitation_over) =
        overrides(spec, path).map_err(|(k, why)| invalid(&k, why))?;
    for (name, over) in [("chirp", &chirp_over), ("excitation", &excitation_over)] {
        if over.is_empty() {
            continue;
        }
        let section = table
            .entry(name)
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        let toml::Value::Table(section) = section else {
            return Err(invalid(
                name,
                format!("the bench config's {name} is not a table"),
            ));
        };
        for (k, v) in over {
            section.insert(k.clone(), v.clone());
        }
    }
    // From the table, not its text: the error names the key (the
    // merged text's line numbers are no file's).
    let config = BenchConfig::deserialize(table).map_err(|e| CampaignError::Parse {
        path: path.to_path_buf(),
        message: format!(
            "[chirp] and [excitation] overrides on {}: {}",
            config_path.display(),
            e.to_string().trim_end()
        ),
    })?;
    config.check().map_err(|e| {
        let overridden = (e.key.starts_with("chirp.") && spec.chirp.is_some())
            || (e.key.starts_with("excitation.") && spec.excitation.is_some());
        let key = if overridden {
            e.key.clone()
        } else {
            format!("config ({}): {}", config_path.display(), e.key)
        };
        invalid(&key, e.reason)
    })?;
    Ok((config_path, config_text, config))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, text: &str) -> PathBuf {
        std::fs::copy(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"),
            dir.join("sr4dof-ch5.toml"),
        )
        .unwrap();
        let p = dir.join("campaign.toml");
        std::fs::write(&p, text).unwrap();
        p
    }

    const FIG_5_10: &str = r#"
config = "sr4dof-ch5.toml"
seed = 510
[grid]
operating_point_pct = { from = 0.6, to = 9.0, step = 0.6 }
mass_asymmetry = { from = -0.08, to = 0.10, step = 0.02 }
"#;

    #[test]
    fn the_fig_5_10_grid_has_15_by_10_cells_at_the_thesis_values() {
        let d = tempfile::tempdir().unwrap();
        let c = Campaign::load(&write(d.path(), FIG_5_10)).unwrap();
        let l = c.config.plant.beam.length_m;
        assert_eq!(c.operating_points_m.len(), 15);
        assert_eq!(c.mass_asymmetries.len(), 10);
        for (k, op) in c.operating_points_m.iter().enumerate() {
            assert!((op / l - 0.006 * (k + 1) as f64).abs() < 1e-12, "{k}: {op}");
        }
        for (k, dm) in c.mass_asymmetries.iter().enumerate() {
            assert!((dm - (-0.08 + 0.02 * k as f64)).abs() < 1e-12, "{k}: {dm}");
        }
        assert_eq!(c.cells().len(), 150);
    }

    #[test]
    fn the_serpentine_visits_every_cell_once_changing_one_setting_one_step_at_a_time() {
        let d = tempfile::tempdir().unwrap();
        let c = Campaign::load(&write(d.path(), FIG_5_10)).unwrap();
        let s = c.serpentine();
        let mut seen: Vec<usize> = s.iter().map(|c| c.index).collect();
        seen.sort();
        assert_eq!(seen, (0..150).collect::<Vec<_>>());
        for w in s.windows(2) {
            let d_op = w[0].op_index.abs_diff(w[1].op_index);
            let d_dm = w[0].dm_index.abs_diff(w[1].dm_index);
            assert_eq!(d_op + d_dm, 1, "{:?} -> {:?}", w[0], w[1]);
        }
    }

    #[test]
    fn cell_seeds_are_distinct_and_reproducible() {
        let mut seeds: Vec<u64> = (0..15)
            .flat_map(|i| (0..10).map(move |j| cell_seed(510, i, j)))
            .collect();
        assert_eq!(cell_seed(510, 3, 4), cell_seed(510, 3, 4));
        assert_ne!(cell_seed(510, 3, 4), cell_seed(511, 3, 4));
        seeds.sort();
        seeds.dedup();
        assert_eq!(seeds.len(), 150);
    }

    fn refused(text: &str) -> String {
        let d = tempfile::tempdir().unwrap();
        match Campaign::load(&write(d.path(), text)) {
            Ok(_) => panic!("accepted:\n{text}"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn bad_grids_are_refused_naming_the_key() {
        let base = |grid: &str| format!("config = \"sr4dof-ch5.toml\"\nseed = 1\n[grid]\n{grid}\n");
        for (grid, key, why) in [
            ("operating_point_pct = []\nmass_asymmetry = [0.0]", "grid.operating_point_pct", "empty"),
            ("operating_point_pct = [1.0, 2.0, 1.0]\nmass_asymmetry = [0.0]", "grid.operating_point_pct[2]", "duplicates"),
            ("operating_point_pct = { from = 9.0, to = 0.6, step = 0.6 }\nmass_asymmetry = [0.0]", "grid.operating_point_pct.to", "reversed"),
            ("operating_point_pct = { from = 0.6, to = 9.0, step = 0.0 }\nmass_asymmetry = [0.0]", "grid.operating_point_pct.step", "> 0"),
            ("operating_point_pct = [25.0]\nmass_asymmetry = [0.0]", "grid.operating_point_pct[0]", "validity"),
            ("operating_point_pct = [1.0]\nmass_asymmetry = [0.0, 0.9]", "grid.mass_asymmetry[1]", "outside"),
            ("operating_point_pct = [1.0]\nmass_asymmetry_pct = [0.0, 60.0]", "grid.mass_asymmetry_pct[1]", "outside"),
            ("operating_point_pct = [1.0]\noperating_point_m = [0.001]\nmass_asymmetry = [0.0]", "grid.operating_point_pct", "not both"),
            ("mass_asymmetry = [0.0]", "grid.operating_point_m", "missing"),
            ("operating_point_pct = { from = 0.0, to = 9.0, step = 1e-6 }\nmass_asymmetry = [0.0]", "grid.operating_point_pct.step", "more than"),
        ] {
            let e = refused(&base(grid));
            assert!(e.contains(key) && e.contains(why), "{grid}: {e}");
        }
        let e = refused(&format!("{}\nbogus = 1\n", FIG_5_10));
        assert!(e.contains("bogus"), "{e}");
        let e = refused(&format!("settle_s = -1.0\n{FIG_5_10}"));
        assert!(e.contains("settle_s"), "{e}");
        let e = refused(&format!("mass_increment_kg = 5.0\n{FIG_5_10}"));
        assert!(e.contains("mass_increment_kg"), "{e}");
        let e = refused(&format!("{FIG_5_10}\n[chirp]\nduration_s = -5.0\n"));
        assert!(e.contains("chirp.duration_s"), "{e}");
        let e = refused(&format!("{FIG_5_10}\n[chirp]\nnot_a_key = 1\n"));
        assert!(e.contains("not_a_key"), "{e}");
    }

    #[test]
    fn chirp_overrides_reach_the_config() {
        let d = tempfile::tempdir().unwrap();
        let c = Campaign::load(&write(
            d.path(),
            &format!("{FIG_5_10}\n[chirp]\nduration_s = 5.0\n"),
        ))
        .unwrap();
        assert_eq!(c.config.chirp.duration_s, Some(5.0));
    }

    #[test]
    fn changed_keys_names_what_differs() {
        assert_eq!(
            changed_keys(FIG_5_10, &FIG_5_10.replace("seed = 510", "seed = 511")),
            ["seed"]
        );
        assert_eq!(
            changed_keys(FIG_5_10, &FIG_5_10.replace("to = 9.0", "to = 8.4")),
            ["grid.operating_point_pct.to"]
        );
        assert!(changed_keys(FIG_5_10, FIG_5_10).is_empty());
        assert_eq!(changed_keys(FIG_5_10, "[["), ["(whole file)"]);
    }
}
