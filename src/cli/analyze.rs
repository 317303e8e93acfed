//! `bench analyze` (one bench: modes, residues, sequence, zeros, the
//! three-mode test, two PNGs) and `bench map` (the CNMP map over operating
//! point × mass asymmetry, or with `--veering` the pair's frequencies
//! against operating point): their flags, the jobs they make
//! (`bench::jobs::analyze`, `bench::jobs::map`), and the printed summaries.

use super::point::PointArgs;
use super::serve::via_daemon;
use super::{finish, refuse_local_only, run_failed};
use bench::analysis::map::MapCell;
use bench::jobs::analyze::{plan_analyze, run_analyze, AnalyzeRequest, AnalyzeSummary};
use bench::jobs::map::{
    defaults, plan_map, run_map, MapRequest, MapResult, MapSummary, VeeringSummary,
};
use bench::jobs::request::JobRequest;
use bench::outputs::{Destination, Given};
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Debug, Args)]
#[command(
    mut_arg("no_plot", |a| a.conflicts_with_all(["pole_zero_png", "modes_png"])),
)]
pub(super) struct AnalyzeArgs {
    #[command(flatten)]
    config: super::ConfigFlag,
    #[command(flatten)]
    point: PointArgs,
    /// Pole-zero map PNG [default: analyze-<UTC time>.pole-zero.png in the
    /// recordings directory].
    #[arg(long, value_name = "FILE.png|svg|pdf")]
    pole_zero_png: Option<PathBuf>,
    /// Decomposed-mode Bode PNG [default: analyze-<UTC time>.modes.png in
    /// the recordings directory].
    #[arg(long, value_name = "FILE.png|svg|pdf")]
    modes_png: Option<PathBuf>,
    #[command(flatten)]
    no_plot: super::NoPlotFlag,
    #[command(flatten)]
    job: super::JobFlags,
    #[command(flatten)]
    outputs: super::OutputFlags,
}

impl AnalyzeArgs {
    /// The analysis request of the flags.
    fn request(&self) -> AnalyzeRequest {
        AnalyzeRequest {
            config: self.config.config.clone(),
            point: self.point.point(),
            no_plots: self.no_plot.no_plot,
        }
    }
}

pub(super) fn analyze(args: AnalyzeArgs) -> ExitCode {
    let request = args.request();
    if let Some(sock) = &args.job.daemon {
        if let Some(code) = refuse_local_only(
            &[
                (args.pole_zero_png.is_some(), "--pole-zero-png"),
                (args.modes_png.is_some(), "--modes-png"),
                (args.outputs.overwrite, "--overwrite"),
            ],
            "the daemon writes its PNGs in its recordings directory",
        ) {
            return code;
        }
        let request = AnalyzeRequest {
            config: request.config.as_deref().map(super::absolute_path),
            ..request
        };
        return via_daemon(
            sock,
            &JobRequest::Analyze(request),
            args.job.json.json,
            print_analysis,
        );
    }
    let given = Given::default()
        .with("pole_zero_png", args.pole_zero_png.clone())
        .with("modes_png", args.modes_png.clone());
    let opts = match plan_analyze(request, &Destination::local(given, args.outputs.overwrite)) {
        Ok(o) => o,
        Err(e) => return run_failed(&e),
    };
    finish(run_analyze(&opts), args.job.json.json, print_analysis)
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
#[command(
    mut_arg("config", |a| a.long_help("Bench description (TOML) [default: the built-in Chapter 5 bench]; its operating point and asymmetry are replaced by the grid")),
    mut_arg("png", |a| a.help("The map (or veering) figure [default: map-<UTC time>.png or veering-<UTC time>.png in the recordings directory]")),
)]
pub(super) struct MapArgs {
    #[command(flatten)]
    config: super::ConfigFlag,
    /// Lowest operating point of the grid, % of L.
    #[arg(
        long,
        value_name = "PERCENT",
        default_value_t = defaults::OPERATING_POINT_FROM_PCT,
        allow_hyphen_values = true
    )]
    operating_point_from_pct: f64,
    /// Highest operating point of the grid, % of L.
    #[arg(
        long,
        value_name = "PERCENT",
        default_value_t = defaults::OPERATING_POINT_TO_PCT,
        allow_hyphen_values = true
    )]
    operating_point_to_pct: f64,
    /// Number of operating points (2 … 401).
    #[arg(long, value_name = "N", default_value_t = defaults::OPERATING_POINTS)]
    operating_points: usize,
    /// Lowest mass asymmetry Δm23 of the grid (fraction: −0.1 = −10 %).
    #[arg(long, value_name = "X", default_value_t = defaults::MASS_ASYMMETRY_FROM, allow_hyphen_values = true)]
    mass_asymmetry_from: f64,
    /// Highest mass asymmetry of the grid (fraction).
    #[arg(
        long,
        value_name = "X",
        default_value_t = defaults::MASS_ASYMMETRY_TO,
        allow_hyphen_values = true
    )]
    mass_asymmetry_to: f64,
    /// Number of asymmetries (2 … 401; 1 with --veering).
    #[arg(long, value_name = "N", default_value_t = defaults::MASS_ASYMMETRIES)]
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
    #[command(flatten)]
    png: super::PngFlag,
    /// One row per cell: operating_point_m,mass_asymmetry,cnmp,cnmp_damped
    /// [FILE default: the PNG's name with .csv; with --daemon give no
    /// FILE: the daemon names it].
    #[arg(long, value_name = "FILE.csv", num_args = 0..=1)]
    csv: Option<Option<PathBuf>>,
    #[command(flatten)]
    job: super::JobFlags,
    #[command(flatten)]
    outputs: super::OutputFlags,
}

impl MapArgs {
    /// The map request of the flags.
    fn request(&self) -> MapRequest {
        MapRequest {
            config: self.config.config.clone(),
            operating_point_from_pct: self.operating_point_from_pct,
            operating_point_to_pct: self.operating_point_to_pct,
            operating_points: self.operating_points,
            mass_asymmetry_from: self.mass_asymmetry_from,
            mass_asymmetry_to: self.mass_asymmetry_to,
            mass_asymmetries: self.mass_asymmetries,
            measured: self.measured.clone(),
            veering: self.veering,
            veering_asymmetries: self.veering_asymmetries.clone(),
            localisation_at_pct: self.localisation_at_pct.clone(),
            csv: self.csv.is_some(),
        }
    }
}

pub(super) fn map(args: MapArgs) -> ExitCode {
    let request = args.request();
    if let Some(sock) = &args.job.daemon {
        let csv_named = matches!(args.csv, Some(Some(_)));
        if let Some(code) = refuse_local_only(
            &[
                (args.png.png.is_some(), "--png"),
                (csv_named, "--csv FILE (--csv alone asks for the cells CSV)"),
                (args.outputs.overwrite, "--overwrite"),
            ],
            "the daemon writes its PNG and CSV in its recordings directory",
        ) {
            return code;
        }
        let request = MapRequest {
            config: request.config.as_deref().map(super::absolute_path),
            measured: request.measured.as_deref().map(super::absolute_path),
            ..request
        };
        return via_daemon(
            sock,
            &JobRequest::Map(request),
            args.job.json.json,
            print_result,
        );
    }
    let given = Given::default()
        .with("png", args.png.png.clone())
        .with("csv", args.csv.clone().flatten());
    let opts = match plan_map(request, &Destination::local(given, args.outputs.overwrite)) {
        Ok(o) => o,
        Err(e) => return run_failed(&e),
    };
    finish(run_map(&opts), args.job.json.json, print_result)
}

fn print_result(r: &MapResult) {
    match r {
        MapResult::Map(s) => print_map(s),
        MapResult::Veering(s) => print_veering(s),
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

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Map {
        #[command(flatten)]
        args: MapArgs,
    }

    /// The flags' defaults are the request's (the daemon's `map` without
    /// params is `bench map`).
    #[test]
    fn map_flags_default_to_the_request_defaults() {
        let m = Map::try_parse_from(["map"]).unwrap();
        assert_eq!(m.args.request(), MapRequest::default());
    }
}
