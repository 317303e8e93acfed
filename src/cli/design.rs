//! `bench design`: its flags, the design job they make
//! (`bench::jobs::design`), and the printed report.

use super::serve::via_daemon;
use super::{finish, refuse_local_only, run_failed};
use bench::campaign::job::design_inputs;
use bench::design::Strategy;
use bench::jobs::design::{plan_design, run_design, DesignRequest, DesignSummary, ModelChoice};
use bench::jobs::request::JobRequest;
use bench::outputs::{Destination, Given};
use clap::Args;
use std::f64::consts::PI;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Debug, Args)]
#[command(
    mut_arg("config", |a| a.long_help("Bench description (TOML): the loop period, the amplifier, the computation delay's default and the limits, and the bench the controller is added to; its model only with --model config [default: the config the first recording holds, else the first campaign's bench.toml, else the built-in Chapter 5 bench]")),
    mut_arg("out", |a| a.value_name("FILE.toml").help("The bench config with [controller.NAME] added [default: beside the first input, <stem>.designed.toml; a campaign: DIR/designed.toml]")),
    mut_arg("png", |a| a.help("The figure: Nyquist of every input's loop with the modulus-margin circle, Bode of L and S, the worst input highlighted [default: beside --out, <stem>.png]")),
)]
pub(super) struct DesignArgs {
    /// The measured FRFs: `bench chirp` CSVs, recordings (`.mcap`), or
    /// campaign directories (every done cell's FRF). All from the same
    /// bench wiring; their frequency grids may differ.
    #[arg(required = true, value_name = "INPUT")]
    inputs: Vec<PathBuf>,
    /// `slow` (integrator + low-pass, crossover 10 % of the first
    /// resonance, thesis Eq. 6-6), `fast` (lead, low-passes, notch between
    /// the pair when the residue signs alternate, Eq. 6-7), `limit` (the
    /// Youla program's own controller, reduced to at most 12 sections:
    /// the bandwidth the limit allows), or `auto` (every one; the one
    /// that meets the margins with the highest performance bandwidth ω*).
    #[arg(long, default_value = "auto", value_parser = ["slow", "fast", "limit", "auto"])]
    strategy: String,
    /// Phase margin at every gain crossover of every input, degrees; range
    /// [20, 80].
    #[arg(long, value_name = "DEG", default_value_t = bench::jobs::design::PM_MIN_DEG, allow_hyphen_values = true)]
    pm_min_deg: f64,
    /// Gain margin on every input, dB; range [2, 20].
    #[arg(long, value_name = "DB", default_value_t = bench::jobs::design::GM_MIN_DB, allow_hyphen_values = true)]
    gm_min_db: f64,
    /// Largest peak of the sensitivity |S| on every input (2: a modulus
    /// margin of 0.5, 6 dB); range [1.2, 4].
    #[arg(long, value_name = "RATIO", default_value_t = bench::jobs::design::S_MAX, allow_hyphen_values = true)]
    s_max: f64,
    /// Computation delay added to every FRF, s; range 0 to 10 loop periods
    /// [default: one loop period].
    #[arg(long, value_name = "S", allow_hyphen_values = true)]
    computation_delay_s: Option<f64>,
    /// Longest 2 % settling of the step predicted on the model ([step] of
    /// the config), s: among the search's candidates that meet the
    /// margins, the highest ω_B that settles within it [default: no limit].
    #[arg(long, value_name = "S", allow_hyphen_values = true)]
    settling_max_s: Option<f64>,
    /// Name of the controller: the config written holds it as
    /// [controller.NAME], for `bench control --controller NAME`.
    #[arg(long, default_value = bench::jobs::design::NAME)]
    name: String,
    /// The model the design is predicted and certified on besides the
    /// measured lines: `fit` (each input's modal fit, the bench's own
    /// model) or `config` (the config's lumped model: a nominal
    /// description, not the bench measured).
    #[arg(long, default_value = "fit", value_parser = ["fit", "config"])]
    model: String,
    #[command(flatten)]
    config: super::ConfigFlag,
    #[command(flatten)]
    out: super::OutFlag,
    #[command(flatten)]
    figure: super::FigureFlags,
    #[command(flatten)]
    job: super::JobFlags,
    #[command(flatten)]
    outputs: super::OutputFlags,
}

impl DesignArgs {
    fn request(&self) -> DesignRequest {
        DesignRequest {
            inputs: self.inputs.clone(),
            config: self.config.config.clone(),
            strategy: self.strategy.parse::<Strategy>().unwrap_or(Strategy::Auto),
            pm_min_deg: Some(self.pm_min_deg),
            gm_min_db: Some(self.gm_min_db),
            s_max: Some(self.s_max),
            computation_delay_s: self.computation_delay_s,
            settling_max_s: self.settling_max_s,
            name: Some(self.name.clone()),
            model: self.model.parse::<ModelChoice>().unwrap_or_default(),
            no_plot: self.figure.no_plot.no_plot,
        }
    }
}

pub(super) fn design(a: DesignArgs) -> ExitCode {
    let request = a.request();
    if let Some(sock) = &a.job.daemon {
        if let Some(code) = refuse_local_only(
            &[
                (a.out.out.is_some(), "--out"),
                (a.figure.png.png.is_some(), "--png"),
                (a.outputs.overwrite, "--overwrite"),
            ],
            "the daemon writes its outputs in its recordings directory",
        ) {
            return code;
        }
        let request = DesignRequest {
            inputs: request
                .inputs
                .iter()
                .map(|p| super::absolute_path(p))
                .collect(),
            config: request.config.as_deref().map(super::absolute_path),
            ..request
        };
        return via_daemon(
            sock,
            &JobRequest::Design(request),
            a.job.json.json,
            print_summary,
        );
    }
    let inputs = match design_inputs(&request.inputs) {
        Ok(i) => i,
        Err(e) => return run_failed(&e),
    };
    let given = Given::default()
        .with("out", a.out.out.clone())
        .with("png", a.figure.png.png.clone());
    let opts = plan_design(
        request,
        inputs,
        &Destination::local(given, a.outputs.overwrite),
    );
    finish(run_design(&opts), a.job.json.json, print_summary)
}

fn opt_num(v: Option<f64>, digits: usize, unit: &str) -> String {
    v.map_or("none".into(), |v| format!("{v:.digits$}{unit}"))
}

/// `v ± σ unit` (1σ from the FRF's noise; `σ unknown` when not known).
fn with_sigma(v: Option<f64>, sigma: Option<f64>, digits: usize, unit: &str) -> String {
    match (v, sigma) {
        (None, _) => "none".into(),
        // A 1σ smaller than the last digit shown keeps two significant
        // digits: `± 0.0` would read as exact.
        (Some(v), Some(s)) if s < 0.5 * 10f64.powi(-(digits as i32)) => {
            format!("{v:.digits$} ± {s:.1e}{unit}")
        }
        (Some(v), Some(s)) => format!("{v:.digits$} ± {s:.digits$}{unit}"),
        (Some(v), None) => format!("{v:.digits$}{unit} (σ unknown)"),
    }
}

pub(super) fn print_summary(s: &DesignSummary) {
    outln!(
        "bench design: {} controller `{}` ({:.2} s)",
        s.strategy,
        s.name,
        s.design_time_s
    );
    outln!("config: {}", s.config);
    outln!("inputs (lines with coherence ≥ the identification threshold):");
    for u in &s.inputs {
        outln!(
            "  {}: {} of {} lines, {:.2}–{:.1} Hz",
            u.input,
            u.lines_used,
            u.lines_total,
            u.band_hz[0],
            u.band_hz[1]
        );
    }
    for m in &s.modes.inputs {
        outln!(
            "  modes of {}: first resonance {:.2} Hz, pair {} / {} Hz, {} ({})",
            m.input,
            m.first_resonance_hz,
            opt_num(m.u_hz, 2, ""),
            opt_num(m.v_hz, 2, ""),
            m.pair_signs,
            m.sign_sequence
        );
    }
    outln!("why: {}", s.why);
    let r = &s.requirements;
    outln!(
        "required on every input: phase margin ≥ {}° at every crossover, gain margin ≥ {} dB, ‖S‖∞ ≤ {}, computation delay {:.1} µs",
        r.phase_margin_min_deg,
        r.gain_margin_min_db,
        r.sensitivity_peak_max,
        s.computation_delay_s * 1e6
    );
    outln!("per input (the discrete controller that will run):");
    outln!(
        "  {:<40} {:>10} {:>10} {:>9} {:>8} {:>7}",
        "input",
        "ω_B rad/s",
        "ω_c rad/s",
        "PM min °",
        "GM dB",
        "‖S‖∞"
    );
    for f in &s.figures {
        let g = &f.figures;
        let mark = if f.input == s.worst_input {
            " ← worst"
        } else {
            ""
        };
        outln!(
            "  {:<40} {:>10} {:>10} {:>9} {:>8} {:>7.3}{mark}",
            f.input,
            opt_num(g.sensitivity_bandwidth_rad_s, 1, ""),
            opt_num(g.margins.crossovers_rad_s.first().copied(), 1, ""),
            opt_num(g.phase_margin_min_deg, 1, ""),
            opt_num(g.margins.gain_margin_db, 2, ""),
            g.margins.sensitivity_peak
        );
    }
    let g = &s.sigma;
    outln!(
        "result (1σ from the FRF's noise): ω_B {} ({:.1} Hz), first crossover {} rad/s, least phase margin {}, least gain margin {}, ‖S‖∞ {}",
        with_sigma(Some(s.sensitivity_bandwidth_rad_s), g.sensitivity_bandwidth_rad_s, 1, " rad/s"),
        s.sensitivity_bandwidth_rad_s / (2.0 * PI),
        opt_num(s.crossover_rad_s, 1, ""),
        with_sigma(s.phase_margin_min_deg, g.phase_margin_min_deg, 1, "°"),
        with_sigma(s.gain_margin_min_db, g.gain_margin_db, 2, " dB"),
        with_sigma(Some(s.sensitivity_peak), g.sensitivity_peak, 3, "")
    );
    if let Some(b) = &s.binding {
        outln!("tightest: {b}");
    }
    match &s.discretization {
        Some(d) => outln!("{}", d.line()),
        None => outln!(
            "discretisation: none, designed in discrete time (the config holds its bilinear image, run through the same map): what runs is the design"
        ),
    }
    print_limit(s);
    let m = &s.model;
    outln!("model: {}", m.model);
    outln!(
        "on the model (to Nyquist): ω_B {} rad/s, least phase margin {}°, ‖S‖∞ {:.3}, closed loop {}",
        opt_num(m.figures.sensitivity_bandwidth_rad_s, 1, ""),
        opt_num(m.figures.phase_margin_min_deg, 1, ""),
        m.figures.margins.sensitivity_peak,
        if m.figures.rhp_closed_loop_poles == 0 { "stable".to_string() } else { format!("UNSTABLE ({} right-half-plane poles)", m.figures.rhp_closed_loop_poles) }
    );
    outln!(
        "predicted step of {} µm: rise {}, settling (2 %) {}, overshoot {:.1} %, peak command {:.2} A",
        m.step.step_m * 1e6,
        opt_num(m.step.rise_time_s.map(|t| t * 1e3), 1, " ms"),
        opt_num(m.step.settling_time_s.map(|t| t * 1e3), 1, " ms"),
        m.step.overshoot_pct,
        m.step.peak_command_a
    );
    if let Some(g) = m.step.settling_margin {
        outln!("  settling margin: {}", g.describe());
    }
    print_strategies(s);
    outln!(
        "config: {} (bench control --config {} --controller {})",
        s.config_out.display(),
        s.config_out.display(),
        s.name
    );
    if let Some(p) = &s.plot {
        outln!("figure: {}", p.display());
    }
}

/// The limit's lines of [`print_summary`]: ω* against the limit any
/// linear controller reaches, what binds it, and the RHP zeros' bounds.
fn print_limit(s: &DesignSummary) {
    let g = &s.sigma;
    let l = &s.limit;
    let wp = format!(
        "W_P(s) = (s/{} + ω*)/s",
        s.requirements.sensitivity_peak_max
    );
    match (s.performance_bandwidth_rad_s, l.performance_bandwidth_rad_s) {
        (Some(w), Some(lim)) => outln!(
            "performance bandwidth ω* {} ({wp}): {:.2} of the limit {} that any linear controller reaches on these inputs ({} measured and {} fitted lines, {} cone programs, {:.2} s)",
            with_sigma(Some(w), g.performance_bandwidth_rad_s, 1, " rad/s"),
            w / lim,
            with_sigma(Some(lim), l.performance_bandwidth_sigma_rad_s, 1, " rad/s"),
            l.lines[0],
            l.lines[1],
            l.solves,
            l.time_s
        ),
        (w, _) => outln!(
            "performance bandwidth ω* {} ({wp}); limit not computed: {}",
            with_sigma(w, g.performance_bandwidth_rad_s, 1, " rad/s"),
            l.not_computed.as_deref().unwrap_or("unknown")
        ),
    }
    if l.performance_bandwidth_rad_s.is_some() {
        outln!("  the limit is bound by {}", l.binds);
        if l.fit_stood_in_lines > 0 {
            outln!(
                "  {} measured lines too noisy to resolve the bound on |S| there (2σ |W_P| > 0.5): the fit stood in",
                l.fit_stood_in_lines
            );
        }
    }
    for z in &l.rhp_zeros {
        outln!(
            "  right-half-plane zero {:.2} ± {:.2}j Hz: ω* ≤ {:.1} rad/s for every controller (|1/M + ω*/z| ≤ 1)",
            z.re_hz,
            z.im_hz,
            z.bound_rad_s
        );
    }
}

/// The strategies [`print_summary`] tried, each with its ω* and ω_B (1σ),
/// or what it missed.
fn print_strategies(s: &DesignSummary) {
    for o in &s.strategies {
        outln!(
            "  tried {}: {}",
            o.strategy,
            if o.meets_margins {
                format!(
                    "meets the margins (ω* {}, ω_B {})",
                    with_sigma(
                        Some(o.performance_bandwidth_rad_s),
                        o.sigma.performance_bandwidth_rad_s,
                        1,
                        " rad/s"
                    ),
                    with_sigma(
                        Some(o.sensitivity_bandwidth_rad_s),
                        o.sigma.sensitivity_bandwidth_rad_s,
                        1,
                        " rad/s"
                    )
                )
            } else {
                match &o.binding {
                    Some(b) => format!("misses: {b}"),
                    None => format!("refused: {}", o.structure),
                }
            }
        );
    }
}
