//! `bench fit`: the automatic modal fit of a measured FRF and the CMP-CNMP
//! verdict (`bench::ident::modal_fit`, `bench::ident::verdict`).

use super::{bad_input, emit, load_config, status, CONFIG_HELP};
use bench::ident::frf::{log_grid, Frf};
use bench::ident::modal_fit::{self, ModalFit};
use bench::ident::update::{
    update_to_frequencies, update_to_frf, updated_toml, Bench, Parameter, Update, UpdateError,
};
use bench::ident::verdict::Verdict;
use bench::outputs::{beside, Existing, OutputPlan};
use bench::plot::{bode_curve, write_bode_png, BodePlot, BodeSeries, PairZoom};
use clap::Args;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Debug, Args)]
pub(super) struct FitArgs {
    /// The measured FRF: a `bench chirp` CSV
    /// (frequency_hz,magnitude_m_per_a,phase_deg,coherence) or recording
    /// (`.mcap`, or the `.mcap.part` of a killed run; its /sysid/frf).
    #[arg(required_unless_present = "frequencies")]
    input: Option<PathBuf>,
    #[arg(long, value_name = "FILE", help = CONFIG_HELP, long_help = "Bench description (TOML): the loop period and the amplifier bandwidth of the fit's path model, and the start bench of --update and --frequencies [default: the config a recording holds; for a CSV the built-in Chapter 5 bench]")]
    config: Option<PathBuf>,
    /// Update the bench's physical parameters (--free) to the measured FRF
    /// and write the updated bench as TOML (--out).
    #[arg(long, requires = "input")]
    update: bool,
    /// Update to measured natural frequencies instead of an FRF, Hz,
    /// ascending, 1 to 4 of them (e.g. 18.2,27.6,153.2,154.3).
    #[arg(long, value_name = "F1,F2,...", value_delimiter = ',', allow_hyphen_values = true, conflicts_with_all = ["input", "update", "png", "no_plot"])]
    frequencies: Option<Vec<String>>,
    /// The parameters to update, comma separated, from
    /// parallelogram_stiffness_n_per_m, mass_asymmetry, zeta_rigid,
    /// zeta_csm, force_constant_n_per_a, operating_point_m [default with
    /// --update: all but operating_point_m; with --frequencies:
    /// parallelogram_stiffness_n_per_m].
    #[arg(long, value_name = "NAMES", value_delimiter = ',')]
    free: Option<Vec<String>>,
    /// The updated bench (TOML) [default with --update: beside the input,
    /// <stem>.updated.toml; with --frequencies: none, the result is only
    /// printed].
    #[arg(long, value_name = "FILE.toml")]
    out: Option<PathBuf>,
    /// Measured vs fitted Bode PNG with the pair zoom [default: beside the
    /// input, <stem>.fit.png].
    #[arg(long, value_name = "FILE.png")]
    png: Option<PathBuf>,
    /// Write no PNG.
    #[arg(long, conflicts_with = "png")]
    no_plot: bool,
    /// Replace existing output files (regular files only).
    #[arg(long)]
    overwrite: bool,
    /// Print the result as one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

/// What `bench fit` prints.
#[derive(Debug, Serialize)]
struct FitSummary {
    input: PathBuf,
    /// Sample period and amplifier bandwidth the path model used.
    period_s: f64,
    amplifier_bandwidth_hz: f64,
    /// The fit (`null` when none could be made; see `verdict.reason`).
    fit: Option<ModalFit>,
    /// `fit.modes`, repeated at the top level for scripts.
    modes: Vec<modal_fit::FittedMode>,
    verdict: Verdict,
    #[serde(skip_serializing_if = "Option::is_none")]
    plot: Option<PathBuf>,
    /// The model update (`--update`).
    #[serde(skip_serializing_if = "Option::is_none")]
    update: Option<Update>,
    /// Where the updated bench was written.
    #[serde(skip_serializing_if = "Option::is_none")]
    updated_config: Option<PathBuf>,
}

/// What `bench fit --frequencies` prints.
#[derive(Debug, Serialize)]
struct FrequencySummary {
    /// The measured natural frequencies, Hz.
    frequencies_hz: Vec<f64>,
    update: Update,
    #[serde(skip_serializing_if = "Option::is_none")]
    updated_config: Option<PathBuf>,
}

fn is_recording(p: &Path) -> bool {
    let name = p.to_string_lossy();
    name.ends_with(".mcap") || name.ends_with(".mcap.part")
}

/// The `--free` list, or `default`.
fn parse_free(list: Option<&[String]>, default: &[Parameter]) -> Result<Vec<Parameter>, String> {
    let Some(list) = list else {
        return Ok(default.to_vec());
    };
    let mut out = Vec::new();
    for name in list {
        let name = name.trim();
        let p = Parameter::from_name(name).ok_or_else(|| {
            let names: Vec<&str> = Parameter::ALL.iter().map(|p| p.name()).collect();
            format!(
                "--free {name:?}: not a parameter the update fits (one of {})",
                names.join(", ")
            )
        })?;
        if out.contains(&p) {
            return Err(format!("--free {name}: given twice"));
        }
        out.push(p);
    }
    if out.is_empty() {
        return Err("--free: no parameter given".into());
    }
    Ok(out)
}

/// The start bench's TOML text: `--config`, the recording's, or the
/// built-in.
fn start_toml(config: Option<&Path>, recorded: Option<&str>) -> Result<String, String> {
    match (config, recorded) {
        (Some(p), _) => {
            std::fs::read_to_string(p).map_err(|e| format!("--config {}: {e}", p.display()))
        }
        (None, Some(t)) => Ok(t.to_string()),
        (None, None) => Ok(bench::config::BUILTIN_CONFIG_TOML.to_string()),
    }
}

fn start_bench(cfg: &bench::config::BenchConfig) -> Bench {
    Bench {
        plant: cfg.plant,
        force_constant_n_per_a: cfg.actuator.force_constant_n_per_a,
    }
}

/// Writes the updated bench to `out`, checked by the config loader first.
fn write_updated(
    out: &Path,
    overwrite: bool,
    start_toml: &str,
    update: &Update,
    from: &str,
) -> Result<(), ExitCode> {
    let mut header = format!(
        "# Updated by `bench fit` ({}) from {from}, {}:\n# RMS relative error {:.3} % (start {:.3} %).\n",
        update.source,
        bench::outputs::stamp(),
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
        .map_err(|e| bad_input(format!("--out {}: {e}", out.display())))?;
    if let Err(e) = bench::config::BenchConfig::from_toml(&text, out) {
        return Err(bad_input(format!(
            "--out {}: the updated bench is not a valid config: {e}",
            out.display()
        )));
    }
    bench::outputs::write_atomically(out, Existing::overwrite(overwrite), |f| {
        use std::io::Write;
        f.write_all(text.as_bytes())
    })
    .map_err(|e| {
        errln!("error: --out {}: {e}", out.display());
        ExitCode::from(status::ERROR)
    })
}

/// Parses and checks `--frequencies`: numbers, finite, positive, below
/// `nyquist_hz`, strictly ascending, one to four.
fn parse_frequencies(list: &[String], nyquist_hz: f64) -> Result<Vec<f64>, String> {
    if list.is_empty() || list.len() > 4 {
        return Err(format!(
            "--frequencies: {} values; give 1 to 4 natural frequencies (the SR4DoF model has 4 modes)",
            list.len()
        ));
    }
    let mut out: Vec<f64> = Vec::with_capacity(list.len());
    for (i, s) in list.iter().enumerate() {
        let n = i + 1;
        let f: f64 = s
            .trim()
            .parse()
            .map_err(|_| format!("--frequencies: value {n} {s:?} is not a number (Hz)"))?;
        if !f.is_finite() || f <= 0.0 {
            return Err(format!(
                "--frequencies: value {n} ({s}) must be a finite frequency > 0 Hz"
            ));
        }
        if f >= nyquist_hz {
            return Err(format!(
                "--frequencies: value {n} ({f} Hz) is at or above the Nyquist frequency {nyquist_hz} Hz of the config's loop rate"
            ));
        }
        if let Some(prev) = out.last().filter(|p| f <= **p) {
            return Err(format!(
                "--frequencies: value {n} ({f} Hz) is not above the one before ({prev} Hz): give them ascending, each mode once"
            ));
        }
        out.push(f);
    }
    Ok(out)
}

fn fit_frequencies(a: &FitArgs, list: &[String]) -> ExitCode {
    let (cfg, _) = match load_config(a.config.as_deref()) {
        Ok(c) => c,
        Err(e) => return bad_input(e),
    };
    let nyquist = 0.5 / (cfg.loop_.period_ns() as f64 * 1e-9);
    let measured = match parse_frequencies(list, nyquist) {
        Ok(f) => f,
        Err(e) => return bad_input(e),
    };
    let free = match parse_free(a.free.as_deref(), &Parameter::FREQUENCIES_DEFAULT) {
        Ok(f) => f,
        Err(e) => return bad_input(e),
    };
    if let Some(out) = &a.out {
        let plan = OutputPlan::new(Existing::overwrite(a.overwrite)).with_output(
            "out",
            out,
            super::origin(true),
        );
        if let Err(e) = plan.check() {
            return super::run_failed(&e);
        }
    }
    let start = match start_toml(a.config.as_deref(), None) {
        Ok(t) => t,
        Err(e) => return bad_input(e),
    };
    let update = match update_to_frequencies(&start_bench(&cfg), &free, &measured) {
        Ok(u) => u,
        Err(e @ (UpdateError::NotFromFrequencies(_) | UpdateError::NoFreeParameter)) => {
            return bad_input(format!("--free: {e}"))
        }
        Err(e) => return bad_input(format!("--frequencies: {e}")),
    };
    if let Some(out) = &a.out {
        let from = format!("--frequencies {}", list.join(","));
        if let Err(code) = write_updated(out, a.overwrite, &start, &update, &from) {
            return code;
        }
    }
    let summary = FrequencySummary {
        frequencies_hz: measured,
        update,
        updated_config: a.out.clone(),
    };
    match emit(&summary, a.json, |s| {
        outln!(
            "bench fit --frequencies {}",
            s.frequencies_hz
                .iter()
                .map(|f| f.to_string())
                .collect::<Vec<_>>()
                .join(",")
        );
        print_update(&s.update, s.updated_config.as_deref());
    }) {
        Ok(()) => ExitCode::SUCCESS,
        Err(code) => code,
    }
}

pub(super) fn fit(a: FitArgs) -> ExitCode {
    if a.frequencies.is_none() && !a.update {
        for (flag, given) in [("--out", a.out.is_some()), ("--free", a.free.is_some())] {
            if given {
                return bad_input(format!("{flag}: only with --update or --frequencies"));
            }
        }
    }
    if let Some(list) = &a.frequencies {
        return fit_frequencies(&a, list);
    }
    let Some(input_path) = a.input.clone() else {
        return bad_input("INPUT: give an FRF (CSV or recording), or --frequencies");
    };
    let input = input_path.display().to_string();
    let free = match parse_free(a.free.as_deref(), &Parameter::FRF_DEFAULT) {
        Ok(f) => f,
        Err(e) => return bad_input(e),
    };
    let bytes = match std::fs::read(&input_path) {
        Ok(b) => b,
        Err(e) => return bad_input(format!("{input}: {e}")),
    };
    let (frf, recorded_config) = if is_recording(&input_path) {
        match bench::record::read_frf(&bytes) {
            Ok(r) => (r.frf, r.config_toml),
            Err(e) => return bad_input(format!("{input}: {e}")),
        }
    } else {
        let Ok(text) = String::from_utf8(bytes) else {
            return bad_input(format!("{input}: not a text CSV (not UTF-8)"));
        };
        match Frf::read_csv(&text) {
            Ok(f) => (f, None),
            Err(e) => return bad_input(format!("{input}: {e}")),
        }
    };
    let cfg = match (&a.config, &recorded_config) {
        (None, Some(toml)) => match bench::config::BenchConfig::from_toml(toml, &input_path) {
            Ok(c) => c,
            Err(e) => return bad_input(format!("{input}: its recorded bench.config: {e}")),
        },
        (path, _) => match load_config(path.as_deref()) {
            Ok((c, _)) => c,
            Err(e) => return bad_input(e),
        },
    };
    let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
    let nyquist = 0.5 / period_s;
    if let Some(f) = frf.frequency_hz.last().filter(|f| **f >= nyquist) {
        return bad_input(format!(
            "{input}: frequency_hz: {f} Hz is at or above the Nyquist frequency {nyquist} Hz of the config's loop rate"
        ));
    }
    let plot = (!a.no_plot).then(|| {
        a.png
            .clone()
            .unwrap_or_else(|| beside(&input_path, ".fit.png"))
    });
    let out = a.update.then(|| {
        a.out
            .clone()
            .unwrap_or_else(|| beside(&input_path, ".updated.toml"))
    });
    // Every output checked before anything is computed: the one rule of
    // `bench::outputs` (nothing replaced without --overwrite, regular
    // files only, no two outputs the same file).
    let mut plan = OutputPlan::new(Existing::overwrite(a.overwrite)).derived_from("the input");
    if let Some(p) = &plot {
        plan = plan.with_output("png", p, super::origin(a.png.is_some()));
    }
    if let Some(o) = &out {
        plan = plan.with_output("out", o, super::origin(a.out.is_some()));
    }
    if let Err(e) = plan.check() {
        return super::run_failed(&e);
    }
    let start = match &out {
        Some(_) => {
            match start_toml(a.config.as_deref(), recorded_config.as_deref()) {
                Ok(t) => Some(t),
                Err(e) => return bad_input(e),
            }
        }
        None => None,
    };
    let id = bench::jobs::chirp::identify(&frf, period_s, cfg.actuator.bandwidth_hz);
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
                return bad_input(format!("--update: the start bench: {e}"))
            }
            Err(e) => return bad_input(format!("{input}: --update: {e}")),
        },
        None => None,
    };
    if let (Some(p), Some(f)) = (&plot, &id.fit) {
        if let Err(e) = write_plot(p, Existing::overwrite(a.overwrite), &frf, f, &id) {
            errln!("error: --png {}: {e}", p.display());
            return ExitCode::from(status::ERROR);
        }
    }
    if let (Some(o), Some(u), Some(s)) = (&out, &update, &start) {
        if let Err(code) = write_updated(o, a.overwrite, s, u, &input) {
            return code;
        }
    }
    let summary = FitSummary {
        input: input_path,
        period_s,
        amplifier_bandwidth_hz: cfg.actuator.bandwidth_hz,
        modes: id.fit.as_ref().map(|f| f.modes.clone()).unwrap_or_default(),
        fit: id.fit.clone(),
        verdict: id.verdict.clone(),
        plot: plot.filter(|_| id.fit.is_some()),
        update,
        updated_config: out,
    };
    match emit(&summary, a.json, print_summary) {
        Ok(()) => ExitCode::SUCCESS,
        Err(code) => code,
    }
}

fn write_plot(
    path: &Path,
    existing: Existing,
    frf: &Frf,
    fit: &ModalFit,
    id: &bench::jobs::chirp::Identified,
) -> Result<(), String> {
    let (lo, hi) = (frf.frequency_hz[0], *frf.frequency_hz.last().unwrap());
    let f = log_grid(lo, hi, bench::jobs::chirp::MODEL_POINTS_PER_DECADE);
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
            measured: BodeSeries::measured_h1(frf),
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

fn print_summary(s: &FitSummary) {
    outln!("bench fit {}", s.input.display());
    match &s.fit {
        Some(f) => print_fit(f),
        None => outln!("modal fit: none"),
    }
    print_verdict(&s.verdict);
    if let Some(p) = &s.plot {
        outln!("  Bode plot   {}", p.display());
    }
    if let Some(u) = &s.update {
        print_update(u, s.updated_config.as_deref());
    }
}

/// Prints a model update.
fn print_update(u: &Update, out: Option<&Path>) {
    let free = u.parameters.iter().filter(|p| p.free).count();
    outln!(
        "model update ({}, {free} free parameter{}): RMS relative error {:.3} % (start {:.3} %){}",
        if u.source == "frf" {
            "to the FRF"
        } else {
            "to the natural frequencies"
        },
        if free == 1 { "" } else { "s" },
        100.0 * u.rms_relative_error,
        100.0 * u.start_rms_relative_error,
        match (u.delay_s, u.delay_sigma_s) {
            (Some(d), Some(s)) => format!(", delay {:.1} ± {:.1} µs", d * 1e6, s * 1e6),
            (Some(d), None) => format!(", delay {:.1} µs", d * 1e6),
            _ => String::new(),
        }
    );
    outln!("  parameter                          start           updated ± 1σ");
    for p in &u.parameters {
        let sigma = p.sigma.map_or("—".into(), |s| format!("{s:.3e}"));
        if p.free {
            outln!(
                "  {:<33}  {:<14.6e}  {:.6e} ± {sigma} {}",
                p.name,
                p.start,
                p.value,
                p.unit
            );
            if p.name == Parameter::ParallelogramStiffness.name() {
                outln!(
                    "  {:<33}  = {:.4} × 24 E I / L³ of the configured beam",
                    "",
                    u.stiffness_over_beam
                );
            }
        } else {
            outln!("  {:<33}  {:<14.6e}  (held) {}", p.name, p.value, p.unit);
        }
    }
    outln!("  modes of the updated model (start mode by shape MAC; measured by order or FRF MAC):");
    for (i, m) in u.modes.iter().enumerate() {
        let measured = match (m.measured_frequency_hz, m.measured_mac) {
            (Some(f), Some(mac)) => format!("measured {f:.3} Hz (MAC {mac:.2})"),
            (Some(f), None) => format!("measured {f:.3} Hz"),
            _ => "not measured".into(),
        };
        outln!(
            "  {}  {:>9.3} Hz  ζ {:.5}  A {:+.3e} m/(A·s²)  start mode {} at {:.3} Hz (MAC {:.2}), {measured}",
            i + 1,
            m.frequency_hz,
            m.damping_ratio,
            m.modal_constant,
            m.start_mode,
            m.start_frequency_hz,
            m.start_mac
        );
    }
    if u.crossed_veering {
        outln!("  the update crossed the veering: the closely spaced pair's shapes exchanged");
    }
    outln!(
        "  updated model: {}",
        if u.cmp_cnmp {
            "CMP-CNMP zeros"
        } else {
            "no CMP-CNMP zeros"
        }
    );
    if let Some(w) = &u.warning {
        outln!("  warning: {w}");
    }
    match out {
        Some(p) => outln!("  updated bench {}", p.display()),
        None => outln!("  (no --out: nothing written)"),
    }
}

/// Prints a modal fit (also in `bench chirp`'s summary).
pub(super) fn print_fit(f: &ModalFit) {
    outln!(
        "modal fit ({} coherent points, rms relative error {:.2} %, delay {:.1} ± {:.1} µs):",
        f.coherent_points,
        100.0 * f.rms_relative_error,
        f.delay_s * 1e6,
        f.delay_sigma_s * 1e6
    );
    outln!("  mode  frequency (Hz)         damping ratio          modal constant (m/(A·s²))");
    for m in &f.modes {
        outln!(
            "  {:<4}  {:>9.3} ± {:<9.3}  {:>8.5} ± {:<9.5}  {:>+11.4e} ± {:.1e}{}",
            m.label,
            m.frequency_hz,
            m.frequency_sigma_hz,
            m.damping_ratio,
            m.damping_ratio_sigma,
            m.modal_constant,
            m.modal_constant_sigma,
            if m.in_path {
                ""
            } else {
                "  (outside the path)"
            }
        );
    }
    outln!(
        "  residual terms: lower {:+.3e} m/(A·s²), upper {:+.3e} m/A",
        f.lower_residual,
        f.upper_residual_m_per_a
    );
    outln!("  signs: {}", f.sign_sequence);
    outln!("  sequence of dominant modes: {}", f.dominant_sequence);
    let zeros: Vec<String> = f
        .zeros
        .iter()
        .filter(|z| z.im_hz >= 0.0)
        .map(|z| format!("{:+.2}{:+.2}j Hz {}", z.re_hz, z.im_hz, z.kind))
        .collect();
    outln!("  zeros: {}", zeros.join(", "));
}

/// Prints the verdict with both tests.
pub(super) fn print_verdict(v: &Verdict) {
    match &v.phase_test.pair {
        Some(p) => outln!(
            "phase test: pair {:.2} Hz and {:.2} Hz, net phase over {:.1}–{:.1} Hz: {:.0}° (≈ {:.0}°): {}",
            p.lower_hz,
            p.upper_hz,
            p.band_hz.0,
            p.band_hz.1,
            p.net_phase_deg,
            p.net_phase_multiple_deg,
            answer(v.phase_test.cmp_cnmp)
        ),
        None => outln!("phase test: {}", answer(None)),
    }
    if let Some(r) = &v.phase_test.reason {
        outln!("  ({r})");
    }
    outln!(
        "residue test: {} [{}], confidence {:.0} %: {}",
        v.residue_test.dominant_sequence,
        v.residue_test.sign_sequence,
        100.0 * v.residue_test.confidence,
        answer(v.residue_test.cmp_cnmp)
    );
    if let Some(r) = &v.residue_test.reason {
        outln!("  ({r})");
    }
    outln!("verdict: {}", answer(v.cmp_cnmp));
    if let Some(r) = &v.reason {
        outln!("  ({r})");
    }
}

fn answer(v: Option<bool>) -> &'static str {
    match v {
        Some(true) => "CMP-CNMP zeros",
        Some(false) => "no CMP-CNMP zeros",
        None => "undecided",
    }
}
