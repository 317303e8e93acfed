//! `bench fit`: the automatic modal fit of a measured FRF and the CMP-CNMP
//! verdict (`bench::ident::modal_fit`, `bench::ident::verdict`).

use super::{bad_input, emit, load_config, status, CONFIG_HELP};
use bench::ident::frf::{log_grid, Frf};
use bench::ident::modal_fit::{self, ModalFit};
use bench::ident::verdict::Verdict;
use bench::outputs::Existing;
use bench::plot::{write_bode_png, BodePlot, BodeSeries, PairZoom};
use clap::Args;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Debug, Args)]
pub(super) struct FitArgs {
    /// The measured FRF: a `bench chirp` CSV
    /// (frequency_hz,magnitude_m_per_a,phase_deg,coherence) or recording
    /// (`.mcap`, or the `.mcap.part` of a killed run; its /sysid/frf).
    input: PathBuf,
    #[arg(long, value_name = "FILE", help = CONFIG_HELP, long_help = "Bench description (TOML) for the loop period and the amplifier bandwidth of the fit's path model [default: the config a recording holds; for a CSV the built-in Chapter 5 bench]")]
    config: Option<PathBuf>,
    /// Measured vs fitted Bode PNG with the pair zoom [default: beside the
    /// input, <stem>.fit.png].
    #[arg(long, value_name = "FILE.png")]
    png: Option<PathBuf>,
    /// Write no PNG.
    #[arg(long, conflicts_with = "png")]
    no_plot: bool,
    /// Replace an existing PNG (a regular file).
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
}

fn is_recording(p: &Path) -> bool {
    let name = p.to_string_lossy();
    name.ends_with(".mcap") || name.ends_with(".mcap.part")
}

pub(super) fn fit(a: FitArgs) -> ExitCode {
    let input = a.input.display().to_string();
    let bytes = match std::fs::read(&a.input) {
        Ok(b) => b,
        Err(e) => return bad_input(format!("{input}: {e}")),
    };
    let (frf, recorded_config) = if is_recording(&a.input) {
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
    let cfg = match (&a.config, recorded_config) {
        (None, Some(toml)) => match bench::config::BenchConfig::from_toml(&toml, &a.input) {
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
        a.png.clone().unwrap_or_else(|| {
            let name = a
                .input
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            let stem = name
                .trim_end_matches(".part")
                .trim_end_matches(".mcap")
                .trim_end_matches(".csv")
                .to_string();
            a.input.with_file_name(format!("{stem}.fit.png"))
        })
    });
    if let Some(p) = &plot {
        if p.exists() && !a.overwrite {
            return bad_input(format!(
                "--png {}: exists (pass --overwrite to replace it)",
                p.display()
            ));
        }
    }
    let id = bench::jobs::chirp::identify(&frf, period_s, cfg.actuator.bandwidth_hz);
    if let (Some(p), Some(f)) = (&plot, &id.fit) {
        if let Err(e) = write_plot(p, Existing::overwrite(a.overwrite), &frf, f, &id) {
            eprintln!("error: --png {}: {e}", p.display());
            return ExitCode::from(status::ERROR);
        }
    }
    let summary = FitSummary {
        input: a.input.clone(),
        period_s,
        amplifier_bandwidth_hz: cfg.actuator.bandwidth_hz,
        modes: id.fit.as_ref().map(|f| f.modes.clone()).unwrap_or_default(),
        fit: id.fit.clone(),
        verdict: id.verdict.clone(),
        plot: plot.filter(|_| id.fit.is_some()),
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
    let mag: Vec<f64> = h.iter().map(|h| h.norm()).collect();
    let mut phase: Vec<f64> = h.iter().map(|h| h.arg().to_degrees()).collect();
    bench::ident::frf::unwrap_deg(&mut phase);
    if let (Some(m0), Some(p0)) = (phase.first().copied(), frf.phase_deg.first().copied()) {
        let shift = ((p0 - m0) / 360.0).round() * 360.0;
        phase.iter_mut().for_each(|p| *p += shift);
    }
    let markers: Vec<f64> = fit
        .modes
        .iter()
        .filter(|m| m.in_path)
        .map(|m| m.frequency_hz)
        .collect();
    let reason = id.verdict.phase_test.reason.clone().unwrap_or_default();
    let pair = match &id.verdict.phase_test.pair {
        Some(p) => PairZoom::Resolved {
            pair: *p,
            band_phase_deg: (frf.phase_at_deg(p.band_hz.0), frf.phase_at_deg(p.band_hz.1)),
        },
        None => PairZoom::Unresolved { reason: &reason },
    };
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
            measured: BodeSeries {
                label: "measured (H1)",
                frequency_hz: &frf.frequency_hz,
                magnitude: &frf.magnitude_m_per_a,
                phase_deg: &frf.phase_deg,
            },
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
    println!("bench fit {}", s.input.display());
    match &s.fit {
        Some(f) => print_fit(f),
        None => println!("modal fit: none"),
    }
    print_verdict(&s.verdict);
    if let Some(p) = &s.plot {
        println!("  Bode plot   {}", p.display());
    }
}

/// Prints a modal fit (also in `bench chirp`'s summary).
pub(super) fn print_fit(f: &ModalFit) {
    println!(
        "modal fit ({} coherent points, rms relative error {:.2} %, delay {:.1} ± {:.1} µs):",
        f.coherent_points,
        100.0 * f.rms_relative_error,
        f.delay_s * 1e6,
        f.delay_sigma_s * 1e6
    );
    println!("  mode  frequency (Hz)         damping ratio          modal constant (m/(A·s²))");
    for m in &f.modes {
        println!(
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
    println!(
        "  residual terms: lower {:+.3e} m/(A·s²), upper {:+.3e} m/A",
        f.lower_residual, f.upper_residual_m_per_a
    );
    println!("  signs: {}", f.sign_sequence);
    println!("  sequence of dominant modes: {}", f.dominant_sequence);
    let zeros: Vec<String> = f
        .zeros
        .iter()
        .filter(|z| z.im_hz >= 0.0)
        .map(|z| format!("{:+.2}{:+.2}j Hz {}", z.re_hz, z.im_hz, z.kind))
        .collect();
    println!("  zeros: {}", zeros.join(", "));
}

/// Prints the verdict with both tests.
pub(super) fn print_verdict(v: &Verdict) {
    match &v.phase_test.pair {
        Some(p) => println!(
            "phase test: pair {:.2} Hz and {:.2} Hz, net phase over {:.1}–{:.1} Hz: {:.0}° (≈ {:.0}°): {}",
            p.lower_hz,
            p.upper_hz,
            p.band_hz.0,
            p.band_hz.1,
            p.net_phase_deg,
            p.net_phase_multiple_deg,
            answer(v.phase_test.cmp_cnmp)
        ),
        None => println!("phase test: {}", answer(None)),
    }
    if let Some(r) = &v.phase_test.reason {
        println!("  ({r})");
    }
    println!(
        "residue test: {} [{}], confidence {:.0} %: {}",
        v.residue_test.dominant_sequence,
        v.residue_test.sign_sequence,
        100.0 * v.residue_test.confidence,
        answer(v.residue_test.cmp_cnmp)
    );
    if let Some(r) = &v.residue_test.reason {
        println!("  ({r})");
    }
    println!("verdict: {}", answer(v.cmp_cnmp));
    if let Some(r) = &v.reason {
        println!("  ({r})");
    }
}

fn answer(v: Option<bool>) -> &'static str {
    match v {
        Some(true) => "CMP-CNMP zeros",
        Some(false) => "no CMP-CNMP zeros",
        None => "undecided",
    }
}
