//! `bench fit`: its flags, the fit job they make
//! (`bench::jobs::fit`), and the printed summary.

use super::serve::via_daemon;
use super::{bad_input, finish, refuse_local_only};
use bench::ident::export::{ModelForm, ModelFormat};
use bench::ident::modal_fit::ModalFit;
use bench::ident::update::{Parameter, Update};
use bench::ident::verdict::Verdict;
use bench::jobs::fit::{plan_fit, run_fit, FitRequest, FitResult, FitSummary, FrequencySummary};
use bench::jobs::request::JobRequest;
use bench::outputs::{Destination, Given};
use clap::Args;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// `--export-model`.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum FormArg {
    /// Transfer function (num, den).
    Tf,
    /// Zeros, poles, gain.
    Zpk,
    /// State space, modal form.
    Ss,
}

/// `--model-format`.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum FormatArg {
    /// JSON.
    Json,
    /// MATLAB script (Control System Toolbox).
    Matlab,
    /// Python script (python-control).
    Python,
}

#[derive(Debug, Args)]
#[command(
    mut_arg("config", |a| a.long_help("Bench description (TOML): the loop period and the amplifier bandwidth of the fit's path model, and the start bench of --update and --frequencies [default: the config a recording holds; for a CSV the built-in Chapter 5 bench]")),
    mut_arg("out", |a| a.value_name("FILE.toml").help("The updated bench (TOML) [default with --update: beside the input, <stem>.updated.toml; with --frequencies: none, the result is only printed]")),
    mut_arg("png", |a| a.help("Measured vs fitted Bode figure with the pair zoom [default: beside the input, <stem>.fit.png]")),
)]
pub(super) struct FitArgs {
    /// The measured FRF: a `bench chirp` CSV
    /// (frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz,
    /// or the first four alone) or recording
    /// (`.mcap`, or the `.mcap.part` of a killed run; its /sysid/frf).
    #[arg(required_unless_present = "frequencies")]
    input: Option<PathBuf>,
    #[command(flatten)]
    config: super::ConfigFlag,
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
    /// zeta_csm, force_constant_n_per_a, operating_point_m, m1_kg (the
    /// stage's mass), k4_n_per_m (the X bearings, k5 in its ratio)
    /// [default with --update: the first five; with --frequencies:
    /// parallelogram_stiffness_n_per_m]. Free m1_kg and k4_n_per_m with
    /// the force constant held: the three scale one FRF alike.
    #[arg(long, value_name = "NAMES", value_delimiter = ',')]
    free: Option<Vec<String>>,
    #[command(flatten)]
    out: super::OutFlag,
    #[command(flatten)]
    figure: super::FigureFlags,
    /// Export the fitted model as a continuous-time linear system, SI
    /// units: transfer function, zeros/poles/gain or state space (modal
    /// form), from the demanded current (A) to x1 (m), with the fitted
    /// delay as the input delay.
    #[arg(long, value_name = "FORM", requires = "input")]
    export_model: Option<FormArg>,
    /// The exported model's format: JSON, a MATLAB script (tf/zpk/ss with
    /// 'InputDelay') or a python-control script [default: json].
    #[arg(long, value_name = "FORMAT", requires = "export_model")]
    model_format: Option<FormatArg>,
    /// The exported model's file [default: beside the input,
    /// <stem>.model.json, or <stem>_model.m / _model.py with the stem made
    /// an identifier].
    #[arg(long, value_name = "FILE", requires = "export_model")]
    model_out: Option<PathBuf>,
    #[command(flatten)]
    job: super::JobFlags,
    #[command(flatten)]
    outputs: super::OutputFlags,
}

impl FitArgs {
    /// The fit request of the flags; `--frequencies` parsed as numbers.
    fn request(&self) -> Result<FitRequest, String> {
        let frequencies_hz = self
            .frequencies
            .as_ref()
            .map(|list| {
                list.iter()
                    .enumerate()
                    .map(|(i, s)| {
                        s.trim().parse::<f64>().map_err(|_| {
                            format!("--frequencies: value {} {s:?} is not a number (Hz)", i + 1)
                        })
                    })
                    .collect::<Result<Vec<f64>, String>>()
            })
            .transpose()?;
        Ok(FitRequest {
            input: self.input.clone(),
            config: self.config.config.clone(),
            update: self.update,
            frequencies_hz,
            free: self.free.clone(),
            no_plot: self.figure.no_plot.no_plot,
            export_model: self.export_model.map(|f| match f {
                FormArg::Tf => ModelForm::Tf,
                FormArg::Zpk => ModelForm::Zpk,
                FormArg::Ss => ModelForm::Ss,
            }),
            model_format: self.model_format.map(|f| match f {
                FormatArg::Json => ModelFormat::Json,
                FormatArg::Matlab => ModelFormat::Matlab,
                FormatArg::Python => ModelFormat::Python,
            }),
        })
    }
}

pub(super) fn fit(a: FitArgs) -> ExitCode {
    let request = match a.request() {
        Ok(r) => r,
        Err(e) => return bad_input(e),
    };
    if let Some(sock) = &a.job.daemon {
        if let Some(code) = refuse_local_only(
            &[
                (a.out.out.is_some(), "--out"),
                (a.figure.png.png.is_some(), "--png"),
                (a.model_out.is_some(), "--model-out"),
                (a.outputs.overwrite, "--overwrite"),
            ],
            "the daemon writes its outputs in its recordings directory",
        ) {
            return code;
        }
        // The daemon runs elsewhere: the paths as this shell means them.
        let absolute = |p: &Option<PathBuf>| p.as_deref().map(super::absolute_path);
        let request = FitRequest {
            input: absolute(&request.input),
            config: absolute(&request.config),
            ..request
        };
        return via_daemon(
            sock,
            &JobRequest::Fit(request),
            a.job.json.json,
            print_result,
        );
    }
    let given = Given::default()
        .with("png", a.figure.png.png.clone())
        .with("out", a.out.out.clone())
        .with("model_out", a.model_out.clone());
    let opts = plan_fit(request, &Destination::local(given, a.outputs.overwrite));
    let result = run_fit(&opts);
    let flagged = match &result {
        Ok(FitResult::Fit(s)) if s.flagged() => Some(
            s.update_not_written
                .clone()
                .unwrap_or_else(|| "the modal fit is flagged".to_string()),
        ),
        _ => None,
    };
    let code = finish(result, a.job.json.json, print_result);
    match flagged {
        Some(why) if code == ExitCode::SUCCESS => {
            errln!("error: bench fit: FLAGGED, not to be trusted: {why} (every file asked for is written, except an updated bench)");
            ExitCode::from(super::status::FLAGGED)
        }
        _ => code,
    }
}

fn print_result(r: &FitResult) {
    match r {
        FitResult::Fit(s) => print_summary(s),
        FitResult::Frequencies(s) => print_frequencies(s),
    }
}

fn print_frequencies(s: &FrequencySummary) {
    outln!(
        "bench fit --frequencies {}",
        s.frequencies_hz
            .iter()
            .map(|f| f.to_string())
            .collect::<Vec<_>>()
            .join(",")
    );
    print_update(&s.update, s.updated_config.as_deref());
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
    if let Some(m) = &s.model {
        outln!("  model       {}", m.display());
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
    for f in &u.flags {
        outln!("  FLAGGED: {f}");
    }
    match out {
        Some(p) => outln!("  updated bench {}", p.display()),
        None if !u.flags.is_empty() => {
            outln!("  no updated bench written: the update is flagged")
        }
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
            "  {:<4}  {:>9.4} ± {:<9.1e}  {:>8.6} ± {:<9.1e}  {:>+11.4e} ± {:.1e}{}",
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
    print_quality(f);
}

/// The fit's checks (`modal_fit::FitQuality`): the residual against the
/// noise, its whiteness, and every flag.
pub(super) fn print_quality(f: &ModalFit) {
    let q = &f.quality;
    if !q.checked {
        return;
    }
    let chi2 = match (q.chi2_per_dof, q.chi2_per_dof_bound) {
        (Some(c), Some(b)) => {
            let dof = q.sigma_dof.map_or(String::new(), |d| {
                format!(", σ from {d} degrees of freedom")
            });
            format!(
                "χ²/ν {c:.2} (expected {:.2}, bound {b:.2}{dof})",
                q.chi2_per_dof_expected.unwrap_or(1.0)
            )
        }
        _ => "no noise estimate per line: 1σ scaled by the residual".to_string(),
    };
    let white = q.whiteness_q.map_or(String::new(), |w| {
        format!(", whiteness Q {w:.1} (bound {:.1})", q.whiteness_q_bound)
    });
    outln!("  checks over {} independent lines: {chi2}{white}", q.lines);
    if let Some(why) = &q.noise_refused {
        outln!("  noise: {why}");
    }
    for m in &q.undecided_modes {
        outln!("  undecided: {}", m.line());
    }
    if let Some(d) = &q.detection_limit {
        outln!("  detection limit: {}", d.line());
    }
    if let Some(u) = &f.labels_unsure {
        outln!("  labels unsure: {u}");
    }
    for flag in &q.flags {
        outln!("  FLAGGED: {flag}");
    }
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
