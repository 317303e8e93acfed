//! `bench control`: its flags, the job request they make, and the printed
//! loop check and step summary.

use super::serve::via_daemon_then;
use super::{
    bad_input, emit, job_thread, load_config, refuse_local_only, refused_request, run_failed,
    run_failed_json, status,
};
use bench::jobs::control::{run_control, ControlOptions, ControlSummary};
use bench::jobs::request::{parse_seed, ControlRequest, JobRequest};
use bench::jobs::verify::{StepOutputs, Verify, VerifyOptions};
use bench::outputs::{Destination, Given};
use bench::rt::backend::BackendSpec;
use clap::Args;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

#[derive(Debug, Args)]
#[command(
    mut_arg("out", |a| a.value_name("FILE.mcap").help("MCAP recording [default: control-<name>-<UTC time>.mcap in ./recordings if it exists, else in $XDG_DATA_HOME/bench/recordings]")),
    mut_arg("png", |a| a.help("Step plot [default: beside --out, <stem>.step.png]")),
)]
#[command(group(clap::ArgGroup::new("which").required(true).args(["slow", "fast", "controller"])))]
pub(super) struct ControlArgs {
    /// The slow controller of Eq. (6-6) (`[controller.slow]`).
    #[arg(long)]
    slow: bool,
    /// The fast controller of Eq. (6-7) (`[controller.fast]`).
    #[arg(long)]
    fast: bool,
    /// Any `[controller.NAME]` of the config.
    #[arg(long, value_name = "NAME")]
    controller: Option<String>,
    #[command(flatten)]
    config: super::ConfigFlag,
    /// Step size, m (overrides step.step_m).
    #[arg(long, value_name = "M", allow_hyphen_values = true)]
    step_m: Option<f64>,
    /// Run time, s (overrides step.duration_s).
    #[arg(long, value_name = "S", allow_hyphen_values = true)]
    duration_s: Option<f64>,
    /// Smooth the step with a raised-cosine ramp of this length, s
    /// (overrides step.smooth_s).
    #[arg(long, value_name = "S", allow_hyphen_values = true)]
    smooth_s: Option<f64>,
    #[command(flatten)]
    out: super::OutFlag,
    #[command(flatten)]
    png: super::PngFlag,
    /// Pace the loop in real time.
    #[arg(long)]
    realtime: bool,
    #[command(flatten)]
    live: super::LiveArgs,
    #[command(flatten)]
    pace: super::PaceArgs,
    /// Print the loop check and exit without enabling anything.
    #[arg(long)]
    check_only: bool,
    /// Also check the margins on a measured FRF (a `bench chirp` CSV).
    #[arg(long, value_name = "FILE.csv")]
    frf: Option<PathBuf>,
    /// Run even when the loop check refuses (simulator only).
    #[arg(long)]
    override_check: bool,
    /// Simulator noise seed [default: sim.seed].
    #[arg(long, value_name = "N", allow_hyphen_values = true, value_parser = parse_seed)]
    seed: Option<u64>,
    /// Inject a simulator fault: KIND@T_S with KIND one of nan, frozen,
    /// drop (10 samples), jump (0.2 mm), out_of_range, dead (the probe reads
    /// 0 m without noise), blind (it reads its noise, not the stage); e.g.
    /// nan@1.5.
    #[arg(long, value_name = "KIND@T_S")]
    inject_fault: Option<String>,
    /// Backend: sim, serial:PATH, socketcan:IFACE or ethercat:IFACE [default: [backend] of
    /// the config]. Hardware always runs in real time.
    #[arg(long, value_name = "BACKEND")]
    backend: Option<BackendSpec>,
    /// After the step, holding its setpoint, inject a chirp (the band and
    /// amplitude profile of [chirp]) at the plant input, added to the
    /// controller's command, and measure the sensitivity S = u/d, T = 1 − S
    /// and PS = y/d with coherence; report the measured ‖S‖∞ and
    /// crossovers beside the loop check's. Exit 8 when they differ by more
    /// than 1 dB or 5 % (the run and its files are complete). The
    /// amplitude is checked on the model against the current, I²t and
    /// position limits before anything is enabled.
    #[arg(long)]
    verify: bool,
    /// The injected chirp's amplitude at the plant input, A (before the
    /// [chirp] amplitude profile's scale) [default: 10 % of
    /// chirp.amplitude_a, 0.05 A on the Chapter 5 bench]. Range: 0.1 mA to
    /// actuator.peak_current_a, and the room the limits leave (predicted).
    #[arg(
        long,
        value_name = "A",
        allow_hyphen_values = true,
        requires = "verify"
    )]
    verify_amplitude_a: Option<f64>,
    /// The injected chirp's sweep duration, s [default: 10]. Range: 0.1 to
    /// 600 s. The run grows by chirp.lead_in_s + this + chirp.tail_s.
    #[arg(
        long,
        value_name = "S",
        allow_hyphen_values = true,
        requires = "verify"
    )]
    verify_duration_s: Option<f64>,
    #[command(flatten)]
    job: super::JobFlags,
    #[command(flatten)]
    outputs: super::OutputFlags,
}

impl ControlArgs {
    /// The controller the flags select.
    fn controller(&self) -> String {
        if self.slow {
            "slow".to_string()
        } else if self.fast {
            "fast".to_string()
        } else {
            self.controller.clone().unwrap_or_default()
        }
    }

    /// The job request of the flags.
    fn request(&self) -> ControlRequest {
        ControlRequest {
            controller: self.controller(),
            step_m: self.step_m,
            duration_s: self.duration_s,
            smooth_s: self.smooth_s,
            seed: self.seed,
            inject_fault: self.inject_fault.clone(),
            override_check: self.override_check,
            verify: self.verify,
            verify_amplitude_a: self.verify_amplitude_a,
            verify_duration_s: self.verify_duration_s,
            pace: self.pace.given(),
        }
    }

    /// The flag that set a config key or request field (for error
    /// messages), with its value where the message needs it.
    fn flag_for(&self, key: &str) -> Option<String> {
        match key {
            "step.step_m" if self.step_m.is_some() => Some("--step-m".into()),
            "step.duration_s" if self.duration_s.is_some() => Some("--duration-s".into()),
            "step.smooth_s" if self.smooth_s.is_some() => Some("--smooth-s".into()),
            "controller" if self.slow => Some("--slow".into()),
            "controller" if self.fast => Some("--fast".into()),
            "controller" => Some(format!("--controller {}", self.controller())),
            "inject_fault" => self
                .inject_fault
                .as_ref()
                .map(|f| format!("--inject-fault {f}")),
            "verify_amplitude_a" => Some("--verify-amplitude-a".into()),
            "verify_duration_s" => Some("--verify-duration-s".into()),
            _ => None,
        }
    }
}

pub(super) fn control(args: ControlArgs, stop: Arc<AtomicBool>) -> ExitCode {
    if let Err(code) = args.pace.check_realtime(args.realtime) {
        return code;
    }
    if let Some(sock) = &args.job.daemon {
        let local_only = [
            (
                args.config.config.is_some(),
                "--config (the daemon runs the bench config it was started with: bench serve --config)",
            ),
            (args.out.out.is_some(), "--out"),
            (args.png.png.is_some(), "--png"),
            (args.outputs.overwrite, "--overwrite"),
            (args.backend.is_some(), "--backend"),
            (args.check_only, "--check-only"),
            (args.frf.is_some(), "--frf"),
            (
                args.live.given(),
                "--live (bench serve --live shows the daemon's jobs)",
            ),
        ];
        if let Some(code) = refuse_local_only(
            &local_only,
            "run it locally, or let the daemon choose the recording",
        ) {
            return code;
        }
        let job = JobRequest::Control(args.request());
        return via_daemon_then(
            sock,
            &job,
            args.job.json.json,
            print_control_summary,
            verify_status,
        );
    }
    let (mut cfg, config_path) = match load_config(args.config.config.as_deref()) {
        Ok(c) => c,
        Err(e) => return bad_input(e),
    };
    let request = args.request();
    let inject = match request.apply(&mut cfg) {
        Ok(f) => f,
        Err(e) => return refused_request(e, &config_path, |key| args.flag_for(key)),
    };
    let verify = match request.verify_settings(&cfg) {
        Ok(v) => v,
        Err(e) => return refused_request(e, &config_path, |key| args.flag_for(key)),
    };
    // Before any output is claimed. --check-only runs no loop: nothing to
    // pace.
    let backend = BackendSpec::resolve(args.backend.as_ref(), &cfg);
    let live_run = args.live.given() && !args.check_only;
    let pace = match args.pace.local(args.realtime, live_run, &backend) {
        Ok(p) => p,
        Err(code) => return code,
    };
    let name = request.controller.clone();
    let given = Given::default()
        .with("out", args.out.out.clone())
        .with("plot", args.png.png.clone());
    let dest = Destination::local(given, args.outputs.overwrite);
    let planned = StepOutputs::plan(
        &dest,
        &format!("control-{name}"),
        verify.is_some(),
        // --check-only writes nothing: no name is claimed, no path checked.
        !args.check_only,
    );
    let (out, beside_out, outputs) = match planned {
        Ok(p) => p,
        Err(e) => return run_failed(&e),
    };
    let plot = beside_out.plot;
    let verify = verify
        .zip(beside_out.verify)
        .map(|(v, (csv, plot))| VerifyOptions {
            amplitude_a: v.amplitude_a,
            duration_s: v.duration_s,
            csv,
            plot,
        });
    let opts = ControlOptions {
        plot,
        out,
        seed: request.seed.unwrap_or(cfg.sim.seed),
        config: cfg,
        config_path,
        controller: name,
        check_only: args.check_only,
        frf: args.frf.clone(),
        override_check: request.override_check,
        realtime: args.realtime,
        pace,
        progress: std::io::stderr().is_terminal(),
        inject,
        backend: args.backend.clone(),
        verify,
        catalogue: true,
    };
    // Kept until the run has ended: the live view serves while it runs.
    let _live = match args.live.start(opts.config.loop_.cpu) {
        Ok(l) => l,
        Err(code) => return code,
    };
    let result = job_thread::run_job(stop, move |stop, ticks| {
        run_control(&opts, outputs, stop, Some(&ticks))
    });
    let result = match result {
        Ok(r) => r,
        Err(code) => return code,
    };
    match result {
        Ok(summary) => {
            if let Err(code) = emit(&summary, args.job.json.json, print_control_summary) {
                return code;
            }
            if args.check_only && !summary.loop_check.passed() {
                errln!(
                    "error: loop check refuses controller {}: {}",
                    summary.controller,
                    summary.loop_check.failures.join("; ")
                );
                return ExitCode::from(status::BAD_INPUT);
            }
            verify_status(&summary).unwrap_or(ExitCode::SUCCESS)
        }
        Err(e) => run_failed_json(&e, args.job.json.json),
    }
}

/// Exit 8 for a run whose verification disagrees with the prediction
/// (said on stderr too); `None` otherwise.
fn verify_status(s: &ControlSummary) -> Option<ExitCode> {
    if !s.verify_failed() {
        return None;
    }
    let r = s.verify.as_ref()?.result.as_ref()?;
    errln!(
        "error: bench control --verify: {} (the run completed; its recording and files are written)",
        r.verdict_line()
    );
    Some(ExitCode::from(status::VERIFY_FAILED))
}

pub(super) fn print_margins(label: &str, m: &bench::control::loop_check::Margins) {
    let wc: Vec<String> = m
        .crossovers_rad_s
        .iter()
        .map(|w| format!("{w:.1}"))
        .collect();
    outln!(
        "  {label}: crossover(s) {} rad/s; phase margin {}; gain margin {}; peak |S| {:.2} ({:.1} dB) at {:.0} rad/s",
        if wc.is_empty() { "none".to_string() } else { wc.join(", ") },
        m.phase_margin_deg.map_or("–".to_string(), |p| format!("{p:.1}°")),
        m.gain_margin_db.map_or("∞".to_string(), |g| format!("{g:.1} dB")),
        m.sensitivity_peak,
        20.0 * m.sensitivity_peak.log10(),
        m.sensitivity_peak_at_rad_s
    );
}

pub(super) fn print_control_summary(s: &ControlSummary) {
    outln!(
        "bench control --controller {} on {} (seed {})",
        s.controller,
        s.backend,
        s.seed
    );
    if !s.description.is_empty() {
        outln!("  {}", s.description);
    }
    let c = &s.loop_check;
    outln!("loop check:");
    let d = &c.discretization;
    outln!("  {}", d.line());
    if c.link_delay_periods > 0 {
        outln!(
            "  the link's pure delay in the loop: {} period(s), {:.0} µs (model, measured FRF, poles and stall bound with it)",
            c.link_delay_periods,
            c.link_delay_s * 1e6
        );
    }
    print_margins("model, amplifier included", &c.model);
    print_margins(
        "model, amplifier lag excluded",
        &c.model_without_amplifier_lag,
    );
    if let Some(m) = &c.continuous {
        print_margins(
            "continuous, as the thesis computes (no hold, no amplifier)",
            m,
        );
    }
    if let Some(m) = &c.measured {
        print_margins("measured FRF", m);
    }
    outln!(
        "  closed loop {} (largest pole |z| = {:.5})",
        if c.closed_loop_stable {
            "stable"
        } else {
            "UNSTABLE"
        },
        c.largest_pole_magnitude
    );
    outln!("  {}", c.stall.line());
    if c.passed() {
        outln!("  → passed");
    } else {
        for f in &c.failures {
            outln!("  → refused: {f}");
        }
    }
    if let Some(m) = &s.metrics {
        let opt = |v: Option<f64>, unit: &str, scale: f64| {
            v.map_or("–".to_string(), |x| format!("{:.4} {unit}", x * scale))
        };
        outln!("step of {:.2} µm:", m.step_m * 1e6);
        outln!("  rise time (10–90 %) {}", opt(m.rise_time_s, "s", 1.0));
        outln!(
            "  settling time (2 %) {}{}",
            opt(m.settling_time_s, "s", 1.0),
            m.settling_margin
                .map_or(String::new(), |g| format!(" ({})", g.describe()))
        );
        outln!("  overshoot {:.1} % (before settling)", m.overshoot_pct);
        outln!(
            "  steady-state error over the last {:.1} s: mean {:.1} nm, σ {:.1} nm",
            m.steady_state_window_s,
            m.steady_state_error_mean_nm,
            m.steady_state_error_std_nm
        );
        outln!("  peak command {:.3} A", m.peak_command_a);
    }
    if let Some(v) = &s.verify {
        print_verify(v);
    }
    if s.disturbance_rms_n > 0.0 {
        outln!("disturbance: {:.4} N RMS", s.disturbance_rms_n);
    }
    if let Some(l) = &s.current_limits {
        outln!("{}", l.line());
    }
    if let Some(p) = &s.recording {
        outln!("recording   {}", p.display());
    }
    if let Some(p) = &s.plot {
        outln!("step plot   {}", p.display());
    }
    if let Some(c) = &s.catalogue {
        outln!("{}", c.line());
    }
    if let Some(t) = &s.timing {
        for line in t.lines() {
            outln!("{line}");
        }
    }
}

fn print_verify(v: &Verify) {
    let p = &v.plan;
    outln!(
        "verify: chirp {:.3} A at the plant input, {}–{} Hz in {} s, from {:.2} s (lead-in {} s, tail {} s; run {:.2} s)",
        p.amplitude_a,
        p.f_start_hz,
        p.f_end_hz,
        p.duration_s,
        p.start_s,
        p.lead_in_s,
        p.tail_s,
        p.run_s
    );
    outln!(
        "  predicted before enable: peak command {:.3} A of {} A (steady {:.3} A + |S| {:.2} at {:.1} Hz); peak excursion {:.1} µm of {:.1} µm (|PS| {:.2e} m/A at {:.1} Hz); {:.2} µm per tick of {:.1} µm; I²t {:.2} A²s of {:.1} A²s",
        p.peak_current_a,
        p.peak_current_limit_a,
        p.steady_command_a,
        p.sensitivity_envelope,
        p.sensitivity_envelope_at_hz,
        p.peak_excursion_m * 1e6,
        p.position_limit_m * 1e6,
        p.process_sensitivity_envelope_m_per_a,
        p.process_sensitivity_envelope_at_hz,
        p.reading_step_m * 1e6,
        p.max_position_step_m * 1e6,
        p.i2t_peak_a2s,
        p.i2t_budget_a2s
    );
    let Some(r) = &v.result else {
        return;
    };
    let band = r
        .used_band_hz
        .map_or(String::new(), |[a, b]| format!(", {a:.2}–{b:.2} Hz"));
    outln!(
        "  lines used: {} of {} with γ²(d → u) ≥ {}{band}{}",
        r.lines_used,
        r.lines_total,
        r.coherence_threshold,
        if r.lines_excluded_by_stalls > 0 {
            format!("; {} more left out for stalls", r.lines_excluded_by_stalls)
        } else {
            String::new()
        }
    );
    let rad = |v: &[f64]| {
        if v.is_empty() {
            "none".to_string()
        } else {
            v.iter()
                .map(|w| format!("{w:.1}"))
                .collect::<Vec<_>>()
                .join(", ")
        }
    };
    let db = |x: f64| 20.0 * x.log10();
    let pr = &r.predicted;
    if let Some(m) = &r.measured {
        outln!(
            "  ‖S‖∞   measured {:.3} ± {} (1σ; {:.2} dB) at {:.1} rad/s (γ² {}); predicted {:.3} ({:.2} dB) at {:.1} rad/s; {} ({} at 95 % confidence on the {} lines that resolve 1 dB, against the model's {} there{})",
            m.sensitivity_peak,
            r.sensitivity_peak_sigma
                .map_or("–".to_string(), |s| format!("{s:.3}")),
            db(m.sensitivity_peak),
            m.sensitivity_peak_at_rad_s,
            r.sensitivity_peak_coherence
                .map_or("–".to_string(), |g| format!("{g:.3}")),
            pr.sensitivity_peak,
            db(pr.sensitivity_peak),
            pr.sensitivity_peak_at_rad_s,
            r.sensitivity_peak_difference_db
                .map_or("–".to_string(), |d| format!("{d:+.2} dB")),
            r.sensitivity_peak_difference_range_db
                .map_or("–".to_string(), |[lo, hi]| format!("{lo:+.2} … {hi:+.2} dB")),
            r.lines_resolving_tolerance,
            r.model_sensitivity_peak_on_resolving_lines
                .map_or("–".to_string(), |m| format!("{m:.3}")),
            if r.sensitivity_peak_in_resolved_band == Some(false) {
                "; the predicted peak lies outside them"
            } else {
                ""
            }
        );
        outln!(
            "  crossover(s) measured {} rad/s; predicted {} rad/s; first {}",
            rad(&m.crossovers_rad_s),
            rad(&pr.crossovers_rad_s),
            r.crossover_difference_pct
                .map_or("–".to_string(), |d| format!("{d:+.2} %"))
        );
        outln!(
            "  measured phase margin {}; gain margin {}",
            m.phase_margin_deg
                .map_or("–".to_string(), |p| format!("{p:.1}°")),
            m.gain_margin_db
                .map_or("∞ (none in the band)".to_string(), |g| format!(
                    "{g:.1} dB"
                ))
        );
    }
    if let (Some(w), Some(rms)) = (r.s_model_difference_max_db, r.s_model_difference_rms_db) {
        outln!("  |S| against the model at the lines used: at most {w:.2} dB, RMS {rms:.3} dB");
    }
    outln!("  → {}", r.verdict_line());
    if let Some(p) = &v.csv {
        outln!("verify CSV  {}", p.display());
    }
    if let Some(p) = &v.plot {
        outln!("verify plot {}", p.display());
    }
}
