//! `bench map` as a job: the CNMP map over operating point × mass
//! asymmetry (thesis Fig 2-5, 5-2) with measured verdicts overlaid and
//! judged against the damped model (Fig 5-10), or the curve veering of
//! the closely spaced pair (Fig 2-6).
//!
//! A [`MapRequest`] is what `bench map`'s flags and the daemon's `map`
//! params say; with its output paths it makes the [`MapOptions`] that
//! [`run_map`] runs. The measured-verdict CSV is read by
//! [`read_measured`]. Errors are [`RunError::BadOption`] naming the
//! request field (`operating_points`, `measured`), never a flag.

use super::analyze::absolute;
use super::point::percent_of_length_m;
use crate::analysis::map::{
    agreement, cnmp_map, linspace, model_at, nearest_cell, veering_curve, MapCell, VeeringCurve,
};
use crate::config::BenchConfig;
use crate::error::RunError;
use crate::outputs::{beside, write_atomically, Destination, Existing, Origin, OutputPlan};
use crate::plot::{write_map_png, write_veering_png, MeasuredPoint};
use bench_plant::model::{ranges, Sr4dofParams};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Most curves of `veering_asymmetries` (one colour each in the plot).
pub const MAX_VEERING_CURVES: usize = 6;
/// Most operating points of `localisation_at_pct`.
pub const MAX_LOCALISATION_POINTS: usize = 20;
/// Largest number of points along one axis of the grid.
pub const MAX_GRID_POINTS: usize = 401;

/// The defaults of a [`MapRequest`] (and of `bench map`'s flags).
pub mod defaults {
    /// Lowest operating point of the grid, % of L.
    pub const OPERATING_POINT_FROM_PCT: f64 = 0.0;
    /// Highest operating point of the grid, % of L.
    pub const OPERATING_POINT_TO_PCT: f64 = 10.0;
    /// Operating points of the grid.
    pub const OPERATING_POINTS: usize = 101;
    /// Lowest mass asymmetry of the grid (fraction).
    pub const MASS_ASYMMETRY_FROM: f64 = -0.10;
    /// Highest mass asymmetry of the grid (fraction).
    pub const MASS_ASYMMETRY_TO: f64 = 0.10;
    /// Asymmetries of the grid.
    pub const MASS_ASYMMETRIES: usize = 81;
    /// Asymmetries of the veering curves (fractions).
    pub const VEERING_ASYMMETRIES: [f64; 3] = [0.0, 0.01, 0.05];
}

/// A map (`bench map`, the daemon's `map`). Absent fields take
/// [`defaults`]; a path is read by the process that runs the job (the
/// daemon takes absolute paths only).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapRequest {
    /// Bench config (TOML); absent: the built-in bench. Its operating
    /// point and asymmetry are replaced by the grid.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub config: Option<PathBuf>,
    /// Lowest operating point of the grid, % of L (0 … 20).
    pub operating_point_from_pct: f64,
    /// Highest operating point of the grid, % of L (above the lowest).
    pub operating_point_to_pct: f64,
    /// Number of operating points (2 … [`MAX_GRID_POINTS`]; 3 … with
    /// `veering`).
    pub operating_points: usize,
    /// Lowest mass asymmetry Δm23 of the grid (fraction, −0.33 … 0.5).
    pub mass_asymmetry_from: f64,
    /// Highest mass asymmetry of the grid (fraction, above the lowest).
    pub mass_asymmetry_to: f64,
    /// Number of asymmetries (2 … [`MAX_GRID_POINTS`]).
    pub mass_asymmetries: usize,
    /// Measured verdicts to overlay: a CSV whose header names
    /// `operating_point_m`, `mass_asymmetry` and `verdict` or `cnmp`
    /// ([`read_measured`]). Not with `veering`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measured: Option<PathBuf>,
    /// Instead of the map: the pair's natural frequencies against
    /// operating point for each of `veering_asymmetries`.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub veering: bool,
    /// Asymmetries of the veering curves (fractions; 1 …
    /// [`MAX_VEERING_CURVES`]).
    pub veering_asymmetries: Vec<f64>,
    /// Operating points (% of L, 0 … 20) at which to report the pair's
    /// mode-shape localisation with `veering` (at most
    /// [`MAX_LOCALISATION_POINTS`]).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub localisation_at_pct: Vec<f64>,
    /// Write the cells as a CSV (the daemon's `map`: beside its PNG; a
    /// local run names the file in [`MapOptions::csv`]). Not with
    /// `veering`.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub csv: bool,
}

impl Default for MapRequest {
    fn default() -> Self {
        use defaults::*;
        Self {
            config: None,
            operating_point_from_pct: OPERATING_POINT_FROM_PCT,
            operating_point_to_pct: OPERATING_POINT_TO_PCT,
            operating_points: OPERATING_POINTS,
            mass_asymmetry_from: MASS_ASYMMETRY_FROM,
            mass_asymmetry_to: MASS_ASYMMETRY_TO,
            mass_asymmetries: MASS_ASYMMETRIES,
            measured: None,
            veering: false,
            veering_asymmetries: VEERING_ASYMMETRIES.to_vec(),
            localisation_at_pct: Vec::new(),
            csv: false,
        }
    }
}

/// A map to run: the request and where its outputs go.
#[derive(Debug, Clone, Default)]
pub struct MapOptions {
    /// What to map.
    pub request: MapRequest,
    /// The map (or veering) PNG.
    pub png: PathBuf,
    /// The cells CSV (`operating_point_m,mass_asymmetry,cnmp,cnmp_damped`),
    /// if asked for.
    pub csv: Option<PathBuf>,
    /// What to do with an existing output (`--overwrite`; the daemon
    /// always refuses).
    pub existing: Existing,
}

/// The map of `request` with its outputs where `dest` puts them: locally
/// `--png` (else a stamped `map-<stamp>.png`, or `veering-…`, in the
/// default recordings directory) and `--csv FILE` (else the PNG's name
/// as `.csv`); on the daemon its stamped names. The command line and the
/// daemon both plan a map here.
///
/// # Errors
/// The request refused ([`MapRequest::check`]), checked before a default
/// name is made (and the recordings directory with it);
/// [`RunError::BadOption`] naming `png` when it needs a default name and
/// there is no default recordings directory.
pub fn plan_map(request: MapRequest, dest: &Destination) -> Result<MapOptions, RunError> {
    request.check()?;
    let prefix = if request.veering { "veering" } else { "map" };
    let (png, _) = dest.output("png", ".png", || {
        Ok(beside(&dest.stem(prefix, "png")?, ".png"))
    })?;
    let csv = if request.csv {
        Some(
            dest.output("csv", ".csv", || Ok(png.with_extension("csv")))?
                .0,
        )
    } else {
        None
    };
    Ok(MapOptions {
        request,
        png,
        csv,
        existing: dest.existing(),
    })
}

/// A measured cell whose verdict differs from the damped model's at the
/// nearest grid cell.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Disagreement {
    /// Operating point, m.
    pub operating_point_m: f64,
    /// Mass asymmetry Δm23.
    pub mass_asymmetry: f64,
    /// The measured verdict: CMP-CNMP zeros.
    pub measured_cnmp: bool,
    /// The undamped model's verdict at the nearest cell.
    pub model_cnmp: bool,
    /// The damped model's verdict at the nearest cell (what is compared).
    pub model_cnmp_damped: bool,
}

/// The result of `bench map`.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct MapSummary {
    /// Where the bench came from.
    pub config: String,
    /// Beam length L, m.
    pub beam_length_m: f64,
    /// The grid's operating points, m.
    pub operating_points_m: Vec<f64>,
    /// The grid's asymmetries.
    pub mass_asymmetries: Vec<f64>,
    /// Mode-crossing operating point of the symmetric stage (Δm23 = 0), m.
    pub crossing_operating_point_m: Option<f64>,
    /// Every cell, asymmetry slowest.
    pub cells: Vec<MapCell>,
    /// Cells with CMP-CNMP zeros (undamped).
    pub cnmp_cells: usize,
    /// Cells with CMP-CNMP zeros (damped).
    pub cnmp_damped_cells: usize,
    /// Measured cells with a verdict.
    pub measured: usize,
    /// Measured cells without one (not drawn).
    pub measured_undecided: usize,
    /// Measured cells against the damped model at the nearest grid cell.
    pub disagreements: Vec<Disagreement>,
    /// The PNG (absolute path).
    pub png: String,
    /// The cells CSV (absolute path), if written.
    pub csv: Option<String>,
}

/// The pair's localisation at one operating point of a veering curve.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct LocalisationAt {
    /// Mass asymmetry of the curve.
    pub mass_asymmetry: f64,
    /// Operating point, m.
    pub operating_point_m: f64,
    /// Natural frequency of mode u, Hz.
    pub frequency_u_hz: f64,
    /// Natural frequency of mode v, Hz.
    pub frequency_v_hz: f64,
    /// Localisation of u (+1 stage ②, −1 stage ③).
    pub localisation_u: f64,
    /// Localisation of v.
    pub localisation_v: f64,
}

/// The result of `bench map --veering`.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct VeeringSummary {
    /// Where the bench came from.
    pub config: String,
    /// Beam length L, m.
    pub beam_length_m: f64,
    /// One curve per asymmetry.
    pub curves: Vec<VeeringCurve>,
    /// The localisation at the points asked for.
    pub localisation: Vec<LocalisationAt>,
    /// The PNG (absolute path).
    pub png: String,
}

/// What a map job gives: one of the two summaries (as JSON, the summary
/// itself).
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(untagged)]
pub enum MapResult {
    /// The CNMP map.
    Map(Box<MapSummary>),
    /// The veering curves.
    Veering(Box<VeeringSummary>),
}

impl MapRequest {
    /// Checks the grid against the model's range; the grid in m and
    /// fractions.
    ///
    /// # Errors
    /// [`RunError::BadOption`] naming the field.
    pub fn grid(&self, p: &Sr4dofParams) -> Result<(Vec<f64>, Vec<f64>), RunError> {
        let bad = |key: &'static str, reason: String| RunError::option(key, "", reason);
        let max_pct = ranges::OPERATING_POINT_OF_L * 100.0;
        for (key, v) in [
            ("operating_point_from_pct", self.operating_point_from_pct),
            ("operating_point_to_pct", self.operating_point_to_pct),
        ] {
            if !(v.is_finite() && (0.0..=max_pct).contains(&v)) {
                let hint = if v > max_pct && v <= max_pct * 100.0 {
                    " (the grid is in % of L: 5 means 5 %)"
                } else {
                    ""
                };
                return Err(bad(key, format!(
                    "{v} is outside 0 … {max_pct} % of L (the model's small-rotation range, Eq. 2-1){hint}"
                )));
            }
        }
        if self.operating_point_to_pct <= self.operating_point_from_pct {
            return Err(bad(
                "operating_point_to_pct",
                format!(
                    "{} must be above the lowest operating point ({})",
                    self.operating_point_to_pct, self.operating_point_from_pct
                ),
            ));
        }
        let (lo, hi) = ranges::MASS_ASYMMETRY;
        let mut asymmetries = vec![
            ("mass_asymmetry_from", self.mass_asymmetry_from),
            ("mass_asymmetry_to", self.mass_asymmetry_to),
        ];
        if self.veering {
            asymmetries.extend(
                self.veering_asymmetries
                    .iter()
                    .map(|v| ("veering_asymmetries", *v)),
            );
        }
        for (key, v) in asymmetries {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(bad(key, format!(
                    "{v} is outside {lo} … {hi} (a fraction, 0.10 = 10 %: the heavier secondary stage at most about 1.5 times the lighter)"
                )));
            }
        }
        if self.mass_asymmetry_to <= self.mass_asymmetry_from && !self.veering {
            return Err(bad(
                "mass_asymmetry_to",
                format!(
                    "{} must be above the lowest asymmetry ({})",
                    self.mass_asymmetry_to, self.mass_asymmetry_from
                ),
            ));
        }
        for (key, n, min) in [
            (
                "operating_points",
                self.operating_points,
                if self.veering { 3 } else { 2 },
            ),
            ("mass_asymmetries", self.mass_asymmetries, 2),
        ] {
            if !(min..=MAX_GRID_POINTS).contains(&n) {
                return Err(bad(
                    key,
                    format!("{n} is outside {min} … {MAX_GRID_POINTS}"),
                ));
            }
        }
        if self.veering && self.veering_asymmetries.is_empty() {
            return Err(bad(
                "veering_asymmetries",
                "give at least one asymmetry".into(),
            ));
        }
        if self.veering_asymmetries.len() > MAX_VEERING_CURVES {
            return Err(bad(
                "veering_asymmetries",
                format!(
                    "{} curves; at most {MAX_VEERING_CURVES} (one colour each in the plot)",
                    self.veering_asymmetries.len()
                ),
            ));
        }
        if self.localisation_at_pct.len() > MAX_LOCALISATION_POINTS {
            return Err(bad(
                "localisation_at_pct",
                format!(
                    "{} points; at most {MAX_LOCALISATION_POINTS}",
                    self.localisation_at_pct.len()
                ),
            ));
        }
        for v in &self.localisation_at_pct {
            if !(v.is_finite() && (0.0..=max_pct).contains(v)) {
                return Err(bad(
                    "localisation_at_pct",
                    format!("{v} is outside 0 … {max_pct} % of L"),
                ));
            }
        }
        let l = p.beam.length_m;
        Ok((
            linspace(
                percent_of_length_m(self.operating_point_from_pct, l),
                percent_of_length_m(self.operating_point_to_pct, l),
                self.operating_points,
            ),
            linspace(
                self.mass_asymmetry_from,
                self.mass_asymmetry_to,
                self.mass_asymmetries,
            ),
        ))
    }

    /// Checks the request before anything is written: the config loads,
    /// the grid is in range ([`Self::grid`]), `measured` and `csv` only
    /// with the map, and the model takes the grid's corners (the rest of
    /// the plant is checked there once). The measured CSV is read by
    /// [`run_map`].
    ///
    /// # Errors
    /// As [`run_map`], but for the measured CSV and the outputs.
    pub fn check(&self) -> Result<(), RunError> {
        self.prepare().map(|_| ())
    }

    fn prepare(&self) -> Result<Prepared, RunError> {
        let (cfg, config) = match &self.config {
            Some(p) => (BenchConfig::load(p), p.display().to_string()),
            None => (
                BenchConfig::builtin(),
                crate::config::BUILTIN_CONFIG_NAME.to_string(),
            ),
        };
        let p = cfg.map_err(super::config_error)?.plant;
        let (ops, dms) = self.grid(&p)?;
        self.check_combinations()?;
        for (op, dm) in [
            (ops[0], dms[0]),
            (*ops.last().unwrap(), *dms.last().unwrap()),
        ] {
            model_at(&p, op, dm).map_err(|e| RunError::BadInput(format!("{config}: {e}")))?;
        }
        Ok(Prepared {
            p,
            config,
            ops,
            dms,
        })
    }

    /// `measured` and `csv` only with the map.
    fn check_combinations(&self) -> Result<(), RunError> {
        if self.veering && self.measured.is_some() {
            return Err(RunError::option(
                "measured",
                "",
                "not with veering (it overlays the map)",
            ));
        }
        if self.veering && self.csv {
            return Err(RunError::option(
                "csv",
                "",
                "not with veering (the map's cells; the summary holds the curves)",
            ));
        }
        Ok(())
    }
}

/// A checked request: the plant, the config's name, the grid.
struct Prepared {
    p: Sr4dofParams,
    config: String,
    ops: Vec<f64>,
    dms: Vec<f64>,
}

/// Reads measured verdicts (see [`MapRequest::measured`]): a CSV with a
/// header naming `operating_point_m`, `mass_asymmetry` and `verdict` (or
/// `cnmp`; `true`/`false`/`1`/`0`/`yes`/`no`, empty, `null` or `none` for
/// undecided); extra columns are ignored, blank lines and `#` lines
/// skipped. Rows with an empty verdict are skipped and counted. At most 16
/// MiB; each operating point within the model's range of the plant `p`,
/// each asymmetry within its range.
///
/// # Errors
/// [`RunError::BadOption`] naming `measured` and the file (with the line,
/// 1-based, where one is at fault) and the column.
pub fn read_measured(
    path: &Path,
    p: &Sr4dofParams,
) -> Result<(Vec<MeasuredPoint>, usize), RunError> {
    let at_file = |reason: String| RunError::option("measured", path.display(), reason);
    let at_line = |i: usize, reason: String| {
        RunError::option("measured", format!("{}:{}", path.display(), i + 1), reason)
    };
    // A regular file within the measured map's limit (crate::input_file).
    let text =
        crate::input_file::read_to_string(path, crate::input_file::Kind::MeasuredMap, "measured")?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !l.starts_with('#'));
    let (_, header) = lines.next().ok_or_else(|| at_file("empty file".into()))?;
    let cols: Vec<&str> = header.split(',').map(str::trim).collect();
    let find = |names: &[&str]| cols.iter().position(|c| names.contains(c));
    let (Some(iop), Some(idm), Some(iv)) = (
        find(&["operating_point_m"]),
        find(&["mass_asymmetry"]),
        find(&["verdict", "cnmp"]),
    ) else {
        return Err(at_file(format!(
            "the header must name operating_point_m, mass_asymmetry and verdict (or cnmp); it is {header:?}"
        )));
    };
    let (mut out, mut undecided) = (Vec::new(), 0);
    for (i, line) in lines {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let at = |k: usize, name: &str| -> Result<&str, RunError> {
            f.get(k)
                .copied()
                .ok_or_else(|| at_line(i, format!("no {name} column")))
        };
        let num = |k: usize, name: &str| -> Result<f64, RunError> {
            let s = at(k, name)?;
            s.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| at_line(i, format!("{name} {s:?} is not a finite number")))
        };
        let op = num(iop, "operating_point_m")?;
        let dm = num(idm, "mass_asymmetry")?;
        let max_op = ranges::OPERATING_POINT_OF_L * p.beam.length_m;
        if op.abs() > max_op {
            return Err(at_line(
                i,
                format!(
                    "operating_point_m {op} is beyond {max_op} m ({} % of L); is it in mm?",
                    ranges::OPERATING_POINT_OF_L * 100.0
                ),
            ));
        }
        let (lo, hi) = ranges::MASS_ASYMMETRY;
        if !(lo..=hi).contains(&dm) {
            return Err(at_line(
                i,
                format!("mass_asymmetry {dm} is outside {lo} … {hi} (a fraction: 0.1 = 10 %)"),
            ));
        }
        let cnmp = match at(iv, "verdict")?.to_ascii_lowercase().as_str() {
            "" | "null" | "none" => {
                undecided += 1;
                continue;
            }
            "true" | "1" | "yes" => true,
            "false" | "0" | "no" => false,
            other => {
                return Err(at_line(
                    i,
                    format!("verdict {other:?} is not true, false or empty"),
                ))
            }
        };
        out.push(MeasuredPoint {
            operating_point_m: op,
            mass_asymmetry: dm,
            cnmp,
        });
    }
    Ok((out, undecided))
}

/// Runs a map: checks the request and the grid, reads the measured
/// verdicts, computes the map (or the veering curves) and writes the PNG
/// and the CSV asked for.
///
/// # Errors
/// [`RunError::BadOption`] naming the request field at fault;
/// [`RunError::BadInput`] for a config that does not load or a bench the
/// model refuses; [`RunError::Output`] when an output cannot be written.
pub fn run_map(opts: &MapOptions) -> Result<MapResult, RunError> {
    let req = &opts.request;
    let Prepared {
        p,
        config,
        ops,
        dms,
    } = req.prepare()?;
    if opts.csv.is_some() && req.veering {
        return Err(RunError::option(
            "csv",
            "",
            "not with veering (the map's cells; the summary holds the curves)",
        ));
    }
    let measured = match &req.measured {
        Some(path) => Some(read_measured(path, &p)?),
        None => None,
    };
    // The output rules (crate::outputs), checked before anything is
    // computed: never the config or the measured verdicts read.
    let mut plan = OutputPlan::new(opts.existing).with_output("png", &opts.png, Origin::Given);
    if let Some(c) = &opts.csv {
        plan = plan.with_output("csv", c, Origin::Given);
    }
    if let Some(c) = &req.config {
        plan = plan.with_input("config", c);
    }
    if let Some(m) = &req.measured {
        plan = plan.with_input("measured", m);
    }
    plan.check()?;
    let bad_bench = |e: bench_hal::param::ParamError| RunError::BadInput(format!("{config}: {e}"));
    let png = &opts.png;
    let plot_failed = |e: crate::plot::PlotError| RunError::Output {
        path: png.clone(),
        reason: e.to_string(),
    };
    if req.veering {
        let curves = req
            .veering_asymmetries
            .iter()
            .map(|&dm| veering_curve(&p, dm, &ops))
            .collect::<Result<Vec<_>, _>>()
            .map_err(bad_bench)?;
        let localisation = localisation_at(&p, &curves, &req.localisation_at_pct);
        let title = "Curve veering of the closely spaced pair";
        write_veering_png(png, opts.existing, title, p.beam.length_m, &curves)
            .map_err(plot_failed)?;
        return Ok(MapResult::Veering(Box::new(VeeringSummary {
            config,
            beam_length_m: p.beam.length_m,
            curves,
            localisation,
            png: absolute(png),
        })));
    }
    let cells = cnmp_map(&p, &ops, &dms).map_err(bad_bench)?;
    let crossing = {
        let l = p.beam.length_m;
        let sweep = linspace(0.0, ranges::OPERATING_POINT_OF_L * l * 0.99, 199);
        veering_curve(&p, 0.0, &sweep)
            .ok()
            .filter(|c| c.closest_gap_hz < 1e-3 * c.closest_frequency_hz)
            .map(|c| c.closest_operating_point_m)
    };
    let (points, undecided) = measured.unwrap_or_default();
    // Each measured cell against the damped model at the nearest grid cell.
    let judged: Vec<(&MeasuredPoint, MapCell)> = points
        .iter()
        .filter_map(|m| {
            nearest_cell(
                &cells,
                m.operating_point_m,
                m.mass_asymmetry,
                p.beam.length_m,
            )
            .map(|c| (m, c))
        })
        .collect();
    let disagreements: Vec<Disagreement> =
        agreement(judged.iter().map(|(m, c)| (Some(m.cnmp), c.cnmp_damped)))
            .disagreements
            .iter()
            .map(|&i| {
                let (m, c) = judged[i];
                Disagreement {
                    operating_point_m: m.operating_point_m,
                    mass_asymmetry: m.mass_asymmetry,
                    measured_cnmp: m.cnmp,
                    model_cnmp: c.cnmp,
                    model_cnmp_damped: c.cnmp_damped,
                }
            })
            .collect();
    let title = "CMP-CNMP zeros of force → x1 over the workspace";
    write_map_png(
        png,
        opts.existing,
        title,
        p.beam.length_m,
        &ops,
        &dms,
        &cells,
        crossing,
        &points,
        Some((p.operating_point_m, p.mass_asymmetry)),
    )
    .map_err(plot_failed)?;
    let csv = match &opts.csv {
        Some(path) => Some(write_cells_csv(path, opts.existing, &cells)?),
        None => None,
    };
    Ok(MapResult::Map(Box::new(MapSummary {
        config,
        beam_length_m: p.beam.length_m,
        cnmp_cells: cells.iter().filter(|c| c.cnmp).count(),
        cnmp_damped_cells: cells.iter().filter(|c| c.cnmp_damped).count(),
        operating_points_m: ops,
        mass_asymmetries: dms,
        crossing_operating_point_m: crossing,
        cells,
        measured: points.len(),
        measured_undecided: undecided,
        disagreements,
        png: absolute(png),
        csv,
    })))
}

/// The localisation of each veering curve's pair at each of `pcts` (% of
/// the beam length), where the model resolves the pair there.
fn localisation_at(p: &Sr4dofParams, curves: &[VeeringCurve], pcts: &[f64]) -> Vec<LocalisationAt> {
    let mut localisation = Vec::new();
    for c in curves {
        for &pct in pcts {
            let op = percent_of_length_m(pct, p.beam.length_m);
            if let Ok(one) = veering_curve(p, c.mass_asymmetry, &[op]) {
                let pt = one.points[0];
                localisation.push(LocalisationAt {
                    mass_asymmetry: c.mass_asymmetry,
                    operating_point_m: op,
                    frequency_u_hz: pt.frequency_u_hz,
                    frequency_v_hz: pt.frequency_v_hz,
                    localisation_u: pt.localisation_u,
                    localisation_v: pt.localisation_v,
                });
            }
        }
    }
    localisation
}

/// The map's cells as CSV (`operating_point_m,mass_asymmetry,cnmp,cnmp_damped`,
/// one row per cell) at `path`, written atomically; its absolute path.
fn write_cells_csv(
    path: &std::path::Path,
    existing: crate::outputs::Existing,
    cells: &[MapCell],
) -> Result<String, RunError> {
    let mut text = String::from("operating_point_m,mass_asymmetry,cnmp,cnmp_damped\n");
    for c in cells {
        text.push_str(&format!(
            "{},{},{},{}\n",
            c.operating_point_m, c.mass_asymmetry, c.cnmp, c.cnmp_damped
        ));
    }
    write_atomically(path, existing, |f| {
        use std::io::Write;
        f.write_all(text.as_bytes())
    })
    .map_err(|e| RunError::Output {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    Ok(absolute(path))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key_of(e: RunError) -> (&'static str, String) {
        match e {
            RunError::BadOption {
                key,
                subject,
                reason,
            } => (key, format!("{subject}: {reason}")),
            e => panic!("{e}"),
        }
    }

    #[test]
    fn the_grid_is_checked_naming_the_field() {
        let p = BenchConfig::builtin().unwrap().plant;
        let (ops, dms) = MapRequest::default().grid(&p).unwrap();
        assert_eq!((ops.len(), dms.len()), (101, 81));
        assert_eq!(ops[100], percent_of_length_m(10.0, p.beam.length_m));
        for (r, key) in [
            (
                MapRequest {
                    operating_point_to_pct: 500.0,
                    ..Default::default()
                },
                "operating_point_to_pct",
            ),
            (
                MapRequest {
                    operating_points: 1,
                    ..Default::default()
                },
                "operating_points",
            ),
            (
                MapRequest {
                    mass_asymmetry_to: -0.2,
                    ..Default::default()
                },
                "mass_asymmetry_to",
            ),
            (
                MapRequest {
                    veering: true,
                    veering_asymmetries: vec![0.0; 7],
                    ..Default::default()
                },
                "veering_asymmetries",
            ),
            (
                MapRequest {
                    localisation_at_pct: vec![30.0],
                    ..Default::default()
                },
                "localisation_at_pct",
            ),
        ] {
            assert_eq!(key_of(r.grid(&p).unwrap_err()).0, key, "{r:?}");
        }
        let r = MapRequest {
            veering: true,
            csv: true,
            ..Default::default()
        };
        assert_eq!(key_of(r.check_combinations().unwrap_err()).0, "csv");
    }

    #[test]
    fn measured_verdicts_name_the_line() {
        let dir = tempfile::tempdir().unwrap();
        let p = BenchConfig::builtin().unwrap().plant;
        let path = dir.path().join("m.csv");
        std::fs::write(
            &path,
            "# comment\nmass_asymmetry,operating_point_m,verdict,x\n0.02,0.001,true,a\n-0.05,0.003,,b\n0.1,0.002,no,c\n",
        )
        .unwrap();
        let (points, undecided) = read_measured(&path, &p).unwrap();
        assert_eq!(undecided, 1);
        assert_eq!(
            points,
            [
                MeasuredPoint {
                    operating_point_m: 0.001,
                    mass_asymmetry: 0.02,
                    cnmp: true
                },
                MeasuredPoint {
                    operating_point_m: 0.002,
                    mass_asymmetry: 0.1,
                    cnmp: false
                }
            ]
        );
        std::fs::write(
            &path,
            "operating_point_m,mass_asymmetry,cnmp\n0.001,0.02,maybe\n",
        )
        .unwrap();
        let (key, msg) = key_of(read_measured(&path, &p).unwrap_err());
        assert_eq!(key, "measured");
        assert!(msg.contains("m.csv:2: verdict \"maybe\""), "{msg}");
    }

    #[test]
    fn wire_form_defaults_are_the_flags_defaults() {
        let r: MapRequest =
            serde_json::from_value(serde_json::json!({ "operating_points": 21 })).unwrap();
        assert_eq!(
            r,
            MapRequest {
                operating_points: 21,
                ..Default::default()
            }
        );
        let e = serde_json::from_value::<MapRequest>(serde_json::json!({ "png": "/x.png" }))
            .unwrap_err();
        assert!(e.to_string().contains("png"), "{e}");
    }
}
