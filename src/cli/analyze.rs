//! `bench analyze` (one bench: modes, residues, sequence, zeros, the
//! three-mode test, two PNGs) and `bench map` (the CNMP map over operating
//! point × mass asymmetry, or with `--veering` the pair's frequencies
//! against operating point).

use super::point::PointArgs;
use super::{bad_input, emit, load_config, status, CONFIG_HELP};
use bench::analysis::map::{
    agreement, cnmp_map, linspace, model_at, nearest_cell, veering_curve, MapCell, VeeringCurve,
};
use bench::analysis::plot::{
    write_decomposed_bode_png, write_map_png, write_pole_zero_png, write_veering_png, MeasuredPoint,
};
use bench::analysis::{analyze as analyze_model, Analysis};
use bench::config::BenchConfig;
use bench::outputs::Existing;
use bench_hal::model::{ranges, Sr4dof, Sr4dofParams};
use clap::Args;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// The bench to analyse: the config and the same operating-point and
/// asymmetry flags as `bench chirp`.
#[derive(Debug, Args)]
pub(super) struct BenchPointArgs {
    #[arg(long, value_name = "FILE", help = CONFIG_HELP)]
    config: Option<PathBuf>,
    #[command(flatten)]
    point: PointArgs,
}

impl BenchPointArgs {
    /// The config's name in messages.
    fn config_name(&self) -> String {
        self.config
            .as_ref()
            .map_or(bench::config::BUILTIN_CONFIG_NAME.to_string(), |p| {
                p.display().to_string()
            })
    }

    /// The config's plant with the flags applied and checked, or the exit.
    fn plant(&self) -> Result<(BenchConfig, Sr4dofParams), ExitCode> {
        let (cfg, _) = load_config(self.config.as_deref()).map_err(bad_input)?;
        let mut p = cfg.plant;
        if let Err(e) = self.point.point().check() {
            return Err(super::refused_request(e, Path::new(""), |key| {
                self.point.flag_for(key)
            }));
        }
        self.point.point().apply(&mut p);
        if let Err(e) = p.validate("plant") {
            return Err(match self.point.flag_for(&e.key) {
                Some(f) => bad_input(format!("{f}: {}", e.reason)),
                None => bad_input(format!("{}: {e}", self.config_name())),
            });
        }
        Ok((cfg, p))
    }
}

#[derive(Debug, Args)]
pub(super) struct AnalyzeArgs {
    #[command(flatten)]
    bench: BenchPointArgs,
    /// Pole-zero map PNG [default: analyze-<UTC time>.pole-zero.png in the
    /// recordings directory].
    #[arg(long, value_name = "FILE.png")]
    pole_zero_png: Option<PathBuf>,
    /// Decomposed-mode Bode PNG [default: analyze-<UTC time>.modes.png in
    /// the recordings directory].
    #[arg(long, value_name = "FILE.png")]
    modes_png: Option<PathBuf>,
    /// Write no PNG.
    #[arg(long, conflicts_with_all = ["pole_zero_png", "modes_png"])]
    no_plots: bool,
    /// Replace existing PNGs (regular files only).
    #[arg(long)]
    overwrite: bool,
    /// Print the result as one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

/// `bench analyze --json`.
#[derive(Debug, Serialize)]
struct AnalyzeSummary {
    /// Where the bench came from.
    config: String,
    /// Beam length L, m.
    beam_length_m: f64,
    #[serde(flatten)]
    analysis: Analysis,
    /// The PNGs written (absolute paths).
    pole_zero_png: Option<String>,
    modes_png: Option<String>,
}

/// A default output path in the recordings directory (the rule of
/// [`super::default_recordings`], created if missing):
/// `<dir>/<prefix>-<UTC stamp><suffix>`; `flag` names the flag that
/// overrides it in the error.
fn default_output(prefix: &str, suffix: &str, flag: &str) -> Result<PathBuf, ExitCode> {
    let dir = super::default_recordings(true, flag).map_err(bad_input)?;
    let stem = bench::outputs::stamped_recording(&dir, prefix, "");
    Ok(bench::outputs::beside(&stem, suffix))
}

fn absolute(p: &Path) -> String {
    std::path::absolute(p)
        .unwrap_or_else(|_| p.to_path_buf())
        .display()
        .to_string()
}

fn plot_failed(e: impl std::fmt::Display) -> ExitCode {
    errln!("error: {e}");
    ExitCode::from(status::ERROR)
}

pub(super) fn analyze(args: AnalyzeArgs) -> ExitCode {
    let (_, params) = match args.bench.plant() {
        Ok(p) => p,
        Err(code) => return code,
    };
    let model = match Sr4dof::new(params) {
        Ok(m) => m,
        Err(e) => return bad_input(format!("{}: {e}", args.bench.config_name())),
    };
    let a = analyze_model(&model);
    let existing = Existing::overwrite(args.overwrite);
    let (mut pz, mut modes) = (None, None);
    if !args.no_plots {
        let pz_path = match &args.pole_zero_png {
            Some(p) => p.clone(),
            None => match default_output("analyze", ".pole-zero.png", "--pole-zero-png") {
                Ok(p) => p,
                Err(code) => return code,
            },
        };
        let modes_path = match (&args.modes_png, &args.pole_zero_png) {
            (Some(p), _) => p.clone(),
            // Same stamp as the pole-zero map when both are defaults.
            (None, None) => pz_path.with_file_name(
                pz_path
                    .file_name()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .replace(".pole-zero.png", ".modes.png"),
            ),
            (None, Some(_)) => match default_output("analyze", ".modes.png", "--modes-png") {
                Ok(p) => p,
                Err(code) => return code,
            },
        };
        let what = format!(
            "Y1o = {:.3} mm ({:.2} % of L), Δm23 = {:+.1} %",
            a.operating_point_m * 1e3,
            a.operating_point_m / params.beam.length_m * 100.0,
            a.mass_asymmetry * 100.0
        );
        let title = format!("Poles and zeros, force → x1 — {what}");
        if let Err(e) = write_pole_zero_png(
            &pz_path,
            existing,
            &title,
            &model,
            &a.zeros_damped,
            &a.modes,
        ) {
            return plot_failed(e);
        }
        let title = format!("Decomposed modes {} — {what}", a.sequence);
        if let Err(e) = write_decomposed_bode_png(&modes_path, existing, &title, &a.modes) {
            return plot_failed(e);
        }
        pz = Some(absolute(&pz_path));
        modes = Some(absolute(&modes_path));
    }
    let summary = AnalyzeSummary {
        config: args.bench.config_name(),
        beam_length_m: params.beam.length_m,
        analysis: a,
        pole_zero_png: pz,
        modes_png: modes,
    };
    match emit(&summary, args.json, print_analysis) {
        Ok(()) => ExitCode::SUCCESS,
        Err(code) => code,
    }
}

fn print_analysis(s: &AnalyzeSummary) {
    let a = &s.analysis;
    outln!(
        "bench {}: Y1o = {:.3} mm ({:.2} % of L), Δm23 = {:+.2} %, α = 0.6·Y1o/L = {:.4}",
        s.config,
        a.operating_point_m * 1e3,
        a.operating_point_m / s.beam_length_m * 100.0,
        a.mass_asymmetry * 100.0,
        a.coupling_alpha
    );
    outln!(
        "modes (residue α of Eq. 4-15 in 1/kg = m/(N·s²); shape unit-length over [x1 y1 y2 y3]):"
    );
    for m in &a.modes {
        outln!(
            "  {} [{:>2}] {:8.2} Hz  ζ {:.4}  modal mass {:.4} kg  α {:+.4e}  shape [{:+.3} {:+.3} {:+.3} {:+.3}]{}",
            m.mode,
            m.label,
            m.frequency_hz,
            m.damping_ratio,
            m.modal_mass_kg,
            m.residue_per_kg,
            m.shape[0],
            m.shape[1],
            m.shape[2],
            m.shape[3],
            match (m.observable, m.controllable) {
                (true, true) => "",
                (false, true) => "  unobservable in x1",
                (true, false) => "  not driven by the actuator",
                (false, false) => "  unobservable and not driven",
            }
        );
    }
    outln!("sign sequence: {}", a.sign_sequence);
    outln!("sequence of dominant modes: {}", a.sequence);
    for (label, zs) in [("undamped", &a.zeros_undamped), ("damped", &a.zeros_damped)] {
        outln!("zeros ({label}):");
        for z in zs.iter().filter(|z| z.im_rad_s >= 0.0) {
            outln!(
                "  {:>9.3} {:+9.3}j Hz  |s|/2π {:8.2} Hz  {}{}",
                z.re_rad_s / (2.0 * std::f64::consts::PI),
                z.im_rad_s / (2.0 * std::f64::consts::PI),
                z.frequency_hz,
                z.kind.as_str(),
                if z.nmp() { "  (right half plane)" } else { "" }
            );
        }
    }
    outln!(
        "CMP-CNMP zeros: {} undamped (Δ of Eq. 2-8 = {:.3e}), {} damped",
        if a.cnmp { "yes" } else { "no" },
        a.discriminant,
        if a.cnmp_damped { "yes" } else { "no" }
    );
    match &a.three_mode {
        Some(t) => {
            outln!(
                "three-mode test (Ch. 4, R as a double integrator): b̂2 = {:.4e}, b̂21 = {}, b̂22 = {}",
                t.b2_hat,
                t.b21_hat.map_or("–".into(), |b| format!("{b:.4e}")),
                t.b22_hat.map_or("–".into(), |b| format!("{b:.4e}")),
            );
            outln!(
                "  C4-1 (alternating signs) {}, C4-2 {} → P4-1: {}; exact (full model): {}",
                yes_no(t.c4_1),
                yes_no(t.c4_2),
                if t.p4_1_cnmp {
                    "CMP-CNMP"
                } else {
                    "no CMP-CNMP"
                },
                if a.cnmp { "CMP-CNMP" } else { "no CMP-CNMP" }
            );
            if !t.p4_1_decisive {
                outln!(
                    "  (not decisive: b̂2 is within {:.2e}, the error of taking R at {:.1} Hz as a double integrator, of a critical value)",
                    t.remainder_error_hat, t.frequency_r_hz
                );
            }
        }
        None => {
            outln!("three-mode test: not applicable (no remainder mode or no pair in the path)")
        }
    }
    for (what, p) in [
        ("pole-zero map", &s.pole_zero_png),
        ("decomposed modes", &s.modes_png),
    ] {
        if let Some(p) = p {
            outln!("{what}: {p}");
        }
    }
}

fn yes_no(b: bool) -> &'static str {
    if b {
        "met"
    } else {
        "not met"
    }
}

#[derive(Debug, Args)]
pub(super) struct MapArgs {
    /// Bench description (TOML) [default: the built-in Chapter 5 bench];
    /// its operating point and asymmetry are replaced by the grid.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Lowest operating point of the grid, % of L.
    #[arg(
        long,
        value_name = "PERCENT",
        default_value_t = 0.0,
        allow_hyphen_values = true
    )]
    operating_point_from_pct: f64,
    /// Highest operating point of the grid, % of L.
    #[arg(
        long,
        value_name = "PERCENT",
        default_value_t = 10.0,
        allow_hyphen_values = true
    )]
    operating_point_to_pct: f64,
    /// Number of operating points (2 … 401).
    #[arg(long, value_name = "N", default_value_t = 101)]
    operating_points: usize,
    /// Lowest mass asymmetry Δm23 of the grid (fraction: −0.1 = −10 %).
    #[arg(long, value_name = "X", default_value_t = -0.10, allow_hyphen_values = true)]
    mass_asymmetry_from: f64,
    /// Highest mass asymmetry of the grid (fraction).
    #[arg(
        long,
        value_name = "X",
        default_value_t = 0.10,
        allow_hyphen_values = true
    )]
    mass_asymmetry_to: f64,
    /// Number of asymmetries (2 … 401; 1 with --veering).
    #[arg(long, value_name = "N", default_value_t = 81)]
    mass_asymmetries: usize,
    /// Measured verdicts to overlay (CSV with a header naming
    /// `operating_point_m`, `mass_asymmetry` and `verdict` or `cnmp`:
    /// true/false, empty for undecided).
    #[arg(long, value_name = "FILE.csv")]
    measured: Option<PathBuf>,
    /// Instead of the map: the natural frequencies of the closely spaced
    /// pair against operating point (curve veering), for each asymmetry
    /// of --veering-asymmetries.
    #[arg(long)]
    veering: bool,
    /// Asymmetries of the veering curves (fractions, comma-separated; 1 … 6
    /// of them).
    #[arg(
        long,
        value_name = "X,X,…",
        value_delimiter = ',',
        default_value = "0,0.01,0.05",
        allow_hyphen_values = true
    )]
    veering_asymmetries: Vec<f64>,
    /// Operating points (% of L) at which to print the pair's mode-shape
    /// localisation with --veering (comma-separated; at most 20).
    #[arg(
        long,
        value_name = "PERCENT,…",
        value_delimiter = ',',
        allow_hyphen_values = true
    )]
    localisation_at_pct: Vec<f64>,
    /// The map (or veering) PNG [default: map-<UTC time>.png or
    /// veering-<UTC time>.png in the recordings directory].
    #[arg(long, value_name = "FILE.png")]
    png: Option<PathBuf>,
    /// One row per cell: operating_point_m,mass_asymmetry,cnmp,cnmp_damped.
    #[arg(long, value_name = "FILE.csv")]
    csv: Option<PathBuf>,
    /// Replace existing output files (regular files only).
    #[arg(long)]
    overwrite: bool,
    /// Print the result as one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

/// Most curves of `--veering-asymmetries` (the plot's palette).
pub const MAX_VEERING_CURVES: usize = 6;
/// Most operating points of `--localisation-at-pct`.
pub const MAX_LOCALISATION_POINTS: usize = 20;

/// Largest number of points along one axis of the grid.
pub const MAX_GRID_POINTS: usize = 401;

impl MapArgs {
    /// Checks the grid flags against the model's range; the grid in m and
    /// fractions.
    fn grid(&self, p: &Sr4dofParams) -> Result<(Vec<f64>, Vec<f64>), String> {
        let max_pct = ranges::OPERATING_POINT_OF_L * 100.0;
        for (flag, v) in [
            ("--operating-point-from-pct", self.operating_point_from_pct),
            ("--operating-point-to-pct", self.operating_point_to_pct),
        ] {
            if !(v.is_finite() && (0.0..=max_pct).contains(&v)) {
                let hint = if v > max_pct && v <= max_pct * 100.0 {
                    " (the grid is in % of L: 5 means 5 %)"
                } else {
                    ""
                };
                return Err(format!(
                    "{flag}: {v} is outside 0 … {max_pct} % of L (the model's small-rotation range, Eq. 2-1){hint}"
                ));
            }
        }
        if self.operating_point_to_pct <= self.operating_point_from_pct {
            return Err(format!(
                "--operating-point-to-pct: {} must be above --operating-point-from-pct ({})",
                self.operating_point_to_pct, self.operating_point_from_pct
            ));
        }
        let (lo, hi) = ranges::MASS_ASYMMETRY;
        let mut asym_flags = vec![
            ("--mass-asymmetry-from", self.mass_asymmetry_from),
            ("--mass-asymmetry-to", self.mass_asymmetry_to),
        ];
        if self.veering {
            asym_flags.extend(
                self.veering_asymmetries
                    .iter()
                    .map(|v| ("--veering-asymmetries", *v)),
            );
        }
        for (flag, v) in asym_flags {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(format!(
                    "{flag}: {v} is outside {lo} … {hi} (a fraction, 0.10 = 10 %: the heavier secondary stage at most about 1.5 times the lighter)"
                ));
            }
        }
        if self.mass_asymmetry_to <= self.mass_asymmetry_from && !self.veering {
            return Err(format!(
                "--mass-asymmetry-to: {} must be above --mass-asymmetry-from ({})",
                self.mass_asymmetry_to, self.mass_asymmetry_from
            ));
        }
        for (flag, n, min) in [
            (
                "--operating-points",
                self.operating_points,
                if self.veering { 3 } else { 2 },
            ),
            ("--mass-asymmetries", self.mass_asymmetries, 2),
        ] {
            if !(min..=MAX_GRID_POINTS).contains(&n) {
                return Err(format!("{flag}: {n} is outside {min} … {MAX_GRID_POINTS}"));
            }
        }
        if self.veering && self.veering_asymmetries.is_empty() {
            return Err("--veering-asymmetries: give at least one asymmetry".into());
        }
        if self.veering_asymmetries.len() > MAX_VEERING_CURVES {
            return Err(format!(
                "--veering-asymmetries: {} curves; at most {MAX_VEERING_CURVES} (one colour each in the plot)",
                self.veering_asymmetries.len()
            ));
        }
        if self.localisation_at_pct.len() > MAX_LOCALISATION_POINTS {
            return Err(format!(
                "--localisation-at-pct: {} points; at most {MAX_LOCALISATION_POINTS}",
                self.localisation_at_pct.len()
            ));
        }
        for v in &self.localisation_at_pct {
            if !(v.is_finite() && (0.0..=max_pct).contains(v)) {
                return Err(format!(
                    "--localisation-at-pct: {v} is outside 0 … {max_pct} % of L"
                ));
            }
        }
        let l = p.beam.length_m;
        Ok((
            linspace(
                self.operating_point_from_pct / 100.0 * l,
                self.operating_point_to_pct / 100.0 * l,
                self.operating_points,
            ),
            linspace(
                self.mass_asymmetry_from,
                self.mass_asymmetry_to,
                self.mass_asymmetries,
            ),
        ))
    }
}

/// Reads measured verdicts (see `--measured`). Rows with an empty verdict
/// are skipped and counted.
///
/// # Errors
/// A message naming the file, line and column.
pub(super) fn read_measured(
    path: &Path,
    p: &Sr4dofParams,
) -> Result<(Vec<MeasuredPoint>, usize), String> {
    let meta =
        std::fs::metadata(path).map_err(|e| format!("--measured {}: {e}", path.display()))?;
    if !meta.is_file() || meta.len() > bench::config::MAX_CONFIG_BYTES * 16 {
        return Err(format!(
            "--measured {}: not a regular file of at most 16 MiB",
            path.display()
        ));
    }
    let text =
        std::fs::read_to_string(path).map_err(|e| format!("--measured {}: {e}", path.display()))?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !l.starts_with('#'));
    let (_, header) = lines
        .next()
        .ok_or_else(|| format!("--measured {}: empty file", path.display()))?;
    let cols: Vec<&str> = header.split(',').map(str::trim).collect();
    let find = |names: &[&str]| cols.iter().position(|c| names.contains(c));
    let (Some(iop), Some(idm), Some(iv)) = (
        find(&["operating_point_m"]),
        find(&["mass_asymmetry"]),
        find(&["verdict", "cnmp"]),
    ) else {
        return Err(format!(
            "--measured {}: the header must name operating_point_m, mass_asymmetry and verdict (or cnmp); it is {header:?}",
            path.display()
        ));
    };
    let (mut out, mut undecided) = (Vec::new(), 0);
    for (i, line) in lines {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let at = |k: usize, name: &str| -> Result<&str, String> {
            f.get(k)
                .copied()
                .ok_or_else(|| format!("--measured {}:{}: no {name} column", path.display(), i + 1))
        };
        let num = |k: usize, name: &str| -> Result<f64, String> {
            let s = at(k, name)?;
            s.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    format!(
                        "--measured {}:{}: {name} {s:?} is not a finite number",
                        path.display(),
                        i + 1
                    )
                })
        };
        let op = num(iop, "operating_point_m")?;
        let dm = num(idm, "mass_asymmetry")?;
        let max_op = ranges::OPERATING_POINT_OF_L * p.beam.length_m;
        if op.abs() > max_op {
            return Err(format!(
                "--measured {}:{}: operating_point_m {op} is beyond {max_op} m ({} % of L); is it in mm?",
                path.display(),
                i + 1,
                ranges::OPERATING_POINT_OF_L * 100.0
            ));
        }
        let (lo, hi) = ranges::MASS_ASYMMETRY;
        if !(lo..=hi).contains(&dm) {
            return Err(format!(
                "--measured {}:{}: mass_asymmetry {dm} is outside {lo} … {hi} (a fraction: 0.1 = 10 %)",
                path.display(),
                i + 1
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
                return Err(format!(
                    "--measured {}:{}: verdict {other:?} is not true, false or empty",
                    path.display(),
                    i + 1
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

/// A measured cell whose verdict differs from the model's nearest cell.
#[derive(Debug, Serialize)]
struct Disagreement {
    operating_point_m: f64,
    mass_asymmetry: f64,
    measured_cnmp: bool,
    model_cnmp: bool,
    model_cnmp_damped: bool,
}

#[derive(Debug, Serialize)]
struct MapSummary {
    config: String,
    beam_length_m: f64,
    operating_points_m: Vec<f64>,
    mass_asymmetries: Vec<f64>,
    /// Mode-crossing operating point of the symmetric stage (Δm23 = 0), m.
    crossing_operating_point_m: Option<f64>,
    cells: Vec<MapCell>,
    cnmp_cells: usize,
    cnmp_damped_cells: usize,
    measured: usize,
    measured_undecided: usize,
    /// Measured cells against the damped model at the nearest grid cell.
    disagreements: Vec<Disagreement>,
    png: String,
    csv: Option<String>,
}

#[derive(Debug, Serialize)]
struct VeeringSummary {
    config: String,
    beam_length_m: f64,
    curves: Vec<VeeringCurve>,
    localisation: Vec<LocalisationAt>,
    png: String,
}

#[derive(Debug, Serialize)]
struct LocalisationAt {
    mass_asymmetry: f64,
    operating_point_m: f64,
    frequency_u_hz: f64,
    frequency_v_hz: f64,
    localisation_u: f64,
    localisation_v: f64,
}

pub(super) fn map(args: MapArgs) -> ExitCode {
    let (cfg, config_path) = match load_config(args.config.as_deref()) {
        Ok(c) => c,
        Err(e) => return bad_input(e),
    };
    let config_name = config_path.display().to_string();
    let p = cfg.plant;
    let (ops, dms) = match args.grid(&p) {
        Ok(g) => g,
        Err(msg) => return bad_input(msg),
    };
    let measured = match &args.measured {
        Some(path) if !args.veering => match read_measured(path, &p) {
            Ok(m) => Some(m),
            Err(msg) => return bad_input(msg),
        },
        Some(_) => return bad_input("--measured: not with --veering (it overlays the map)"),
        None => None,
    };
    if args.veering && args.csv.is_some() {
        return bad_input("--csv: not with --veering (the map's cells; use --json for the curves)");
    }
    // Every cell must describe a bench: the model checks the rest of the
    // plant once, at the grid's corners.
    for (op, dm) in [
        (ops[0], dms[0]),
        (*ops.last().unwrap(), *dms.last().unwrap()),
    ] {
        if let Err(e) = model_at(&p, op, dm) {
            return bad_input(format!("{}: {e}", config_name));
        }
    }
    let existing = Existing::overwrite(args.overwrite);
    let png = match &args.png {
        Some(p) => p.clone(),
        None => match default_output(
            if args.veering { "veering" } else { "map" },
            ".png",
            "--png",
        ) {
            Ok(p) => p,
            Err(code) => return code,
        },
    };
    let config = config_name.clone();
    if args.veering {
        let curves = match args
            .veering_asymmetries
            .iter()
            .map(|&dm| veering_curve(&p, dm, &ops))
            .collect::<Result<Vec<_>, _>>()
        {
            Ok(c) => c,
            Err(e) => return bad_input(format!("{}: {e}", config_name)),
        };
        let mut localisation = Vec::new();
        for c in &curves {
            for &pct in &args.localisation_at_pct {
                let op = pct / 100.0 * p.beam.length_m;
                if let Ok(one) = veering_curve(&p, c.mass_asymmetry, &[op]) {
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
        let title = "Curve veering of the closely spaced pair";
        if let Err(e) = write_veering_png(&png, existing, title, p.beam.length_m, &curves) {
            return plot_failed(e);
        }
        let s = VeeringSummary {
            config,
            beam_length_m: p.beam.length_m,
            curves,
            localisation,
            png: absolute(&png),
        };
        return match emit(&s, args.json, print_veering) {
            Ok(()) => ExitCode::SUCCESS,
            Err(code) => code,
        };
    }
    let cells = match cnmp_map(&p, &ops, &dms) {
        Ok(c) => c,
        Err(e) => return bad_input(format!("{}: {e}", config_name)),
    };
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
            nearest_cell(&cells, m.operating_point_m, m.mass_asymmetry, p.beam.length_m)
                .map(|c| (m, c))
        })
        .collect();
    let disagreements: Vec<Disagreement> = agreement(judged.iter().map(|(m, c)| (Some(m.cnmp), c.cnmp_damped)))
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
    if let Err(e) = write_map_png(
        &png,
        existing,
        title,
        p.beam.length_m,
        &ops,
        &dms,
        &cells,
        crossing,
        &points,
    ) {
        return plot_failed(e);
    }
    let csv = match &args.csv {
        Some(path) => {
            let mut text = String::from("operating_point_m,mass_asymmetry,cnmp,cnmp_damped\n");
            for c in &cells {
                text.push_str(&format!(
                    "{},{},{},{}\n",
                    c.operating_point_m, c.mass_asymmetry, c.cnmp, c.cnmp_damped
                ));
            }
            if let Err(e) = bench::outputs::write_atomically(path, existing, |f| {
                use std::io::Write;
                f.write_all(text.as_bytes())
            }) {
                return plot_failed(format!("--csv {}: {e}", path.display()));
            }
            Some(absolute(path))
        }
        None => None,
    };
    let s = MapSummary {
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
        png: absolute(&png),
        csv,
    };
    match emit(&s, args.json, print_map) {
        Ok(()) => ExitCode::SUCCESS,
        Err(code) => code,
    }
}

fn print_map(s: &MapSummary) {
    let l = s.beam_length_m;
    outln!(
        "CNMP map of {}: {} operating points {:.2} … {:.2} % of L × {} asymmetries {:+.1} … {:+.1} %",
        s.config,
        s.operating_points_m.len(),
        s.operating_points_m[0] / l * 100.0,
        s.operating_points_m.last().unwrap() / l * 100.0,
        s.mass_asymmetries.len(),
        s.mass_asymmetries[0] * 100.0,
        s.mass_asymmetries.last().unwrap() * 100.0
    );
    outln!(
        "cells with CMP-CNMP zeros: {} of {} undamped, {} damped",
        s.cnmp_cells,
        s.cells.len(),
        s.cnmp_damped_cells
    );
    match s.crossing_operating_point_m {
        Some(op) => outln!(
            "mode crossing of the symmetric stage at Y1o = {:.3} mm ({:.2} % of L)",
            op * 1e3,
            op / l * 100.0
        ),
        None => outln!("no mode crossing of the symmetric stage within the model's range"),
    }
    // Per asymmetry, the operating-point extent of the region (damped).
    for &dm in &s.mass_asymmetries {
        let row: Vec<&MapCell> = s
            .cells
            .iter()
            .filter(|c| c.mass_asymmetry == dm && c.cnmp_damped)
            .collect();
        if let (Some(a), Some(b)) = (row.first(), row.last()) {
            let whole_pct = ((dm * 100.0) - (dm * 100.0).round()).abs() < 1e-6;
            if s.mass_asymmetries.len() <= 21 || whole_pct {
                outln!(
                    "  Δm23 = {:+5.1} %: CMP-CNMP (damped) from {:.2} to {:.2} % of L",
                    dm * 100.0,
                    a.operating_point_m / l * 100.0,
                    b.operating_point_m / l * 100.0
                );
            }
        }
    }
    if s.measured > 0 || s.measured_undecided > 0 {
        outln!(
            "measured: {} cells ({} undecided, not drawn); {} disagree with the damped model:",
            s.measured,
            s.measured_undecided,
            s.disagreements.len()
        );
        for d in &s.disagreements {
            outln!(
                "  Y1o {:.2} % of L, Δm23 {:+.1} %: measured {}, model {}",
                d.operating_point_m / l * 100.0,
                d.mass_asymmetry * 100.0,
                if d.measured_cnmp { "CMP-CNMP" } else { "none" },
                if d.model_cnmp_damped {
                    "CMP-CNMP"
                } else {
                    "none"
                }
            );
        }
    }
    outln!("map: {}", s.png);
    if let Some(c) = &s.csv {
        outln!("cells: {c}");
    }
}

fn print_veering(s: &VeeringSummary) {
    let l = s.beam_length_m;
    for c in &s.curves {
        outln!(
            "Δm23 = {:+.1} %: closest approach {:.3} Hz apart at Y1o = {:.2} % of L ({:.1} Hz){}",
            c.mass_asymmetry * 100.0,
            c.closest_gap_hz,
            c.closest_operating_point_m / l * 100.0,
            c.closest_frequency_hz,
            if c.closest_gap_hz < 1e-3 * c.closest_frequency_hz {
                " — mode crossing"
            } else {
                " — veering"
            }
        );
        let show = |iv: &[[f64; 2]]| {
            if iv.is_empty() {
                "none".to_string()
            } else {
                iv.iter()
                    .map(|[a, b]| format!("{:.2} … {:.2} %", a / l * 100.0, b / l * 100.0))
                    .collect::<Vec<_>>()
                    .join(", ")
            }
        };
        outln!(
            "  CMP-CNMP zeros over Y1o: undamped {}; damped {}",
            show(&c.cnmp_intervals_m),
            show(&c.cnmp_damped_intervals_m)
        );
    }
    for p in &s.localisation {
        outln!(
            "  Δm23 = {:+.1} %, Y1o = {:.2} % of L: u {:.2} Hz localisation {:+.2}, v {:.2} Hz localisation {:+.2} (+1 stage ②, −1 stage ③)",
            p.mass_asymmetry * 100.0,
            p.operating_point_m / l * 100.0,
            p.frequency_u_hz,
            p.localisation_u,
            p.frequency_v_hz,
            p.localisation_v
        );
    }
    outln!("veering plot: {}", s.png);
}
