//! `bench chirp`: its flags, the job request and local overrides they make,
//! and the printed summary.

use super::point::PointArgs;
use super::serve::via_daemon;
use super::{
    bad_input, emit, job_thread, load_config, refuse_local_only, refused_request, run_failed,
    run_failed_json,
};
use bench::config::ExcitationKind;
use bench::jobs::chirp::{run_chirp, ChirpOptions, ChirpOutputs, ChirpSummary};
use bench::jobs::request::{parse_fault, parse_seed, ChirpRequest, JobRequest, LocalOverrides};
use bench::outputs::{Destination, Given};
use bench::rt::backend::BackendSpec;
use clap::{Args, ValueEnum};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

#[derive(Debug, Clone, Copy, ValueEnum)]
pub(super) enum KindArg {
    Exponential,
    Linear,
    Multisine,
}

#[derive(Debug, Args)]
#[command(
    mut_arg("out", |a| a.value_name("FILE.mcap").help("MCAP recording [default: chirp-<UTC time>.mcap in ./recordings if it exists, else in $XDG_DATA_HOME/bench/recordings]")),
    mut_arg("png", |a| a.help("Bode plot [default: beside --out, <stem>.bode.png]")),
)]
pub(super) struct ChirpArgs {
    #[command(flatten)]
    config: super::ConfigFlag,
    #[command(flatten)]
    out: super::OutFlag,
    /// FRF CSV [default: beside --out, <stem>.frf.csv].
    #[arg(long, value_name = "FILE")]
    frf_csv: Option<PathBuf>,
    #[command(flatten)]
    png: super::PngFlag,
    /// Pace the loop in real time (absolute deadlines, SCHED_FIFO and
    /// mlockall when permitted) instead of virtual time.
    #[arg(long)]
    realtime: bool,
    #[command(flatten)]
    live: super::LiveArgs,
    #[command(flatten)]
    pace: super::PaceArgs,
    /// Simulator noise seed [default: sim.seed from the config].
    #[arg(long, value_name = "N", allow_hyphen_values = true, value_parser = parse_seed)]
    seed: Option<u64>,
    #[command(flatten)]
    point: PointArgs,
    /// Chirp current amplitude, A (overrides chirp.amplitude_a).
    #[arg(long, value_name = "A", allow_hyphen_values = true)]
    amplitude_a: Option<f64>,
    /// Sweep start frequency, Hz (overrides chirp.f_start_hz).
    #[arg(long, value_name = "HZ", allow_hyphen_values = true)]
    f_start_hz: Option<f64>,
    /// Sweep end frequency, Hz (overrides chirp.f_end_hz).
    #[arg(long, value_name = "HZ", allow_hyphen_values = true)]
    f_end_hz: Option<f64>,
    /// Sweep duration, s (overrides chirp.duration_s).
    #[arg(long, value_name = "S", allow_hyphen_values = true)]
    duration_s: Option<f64>,
    /// What to play (overrides excitation.kind): a sweep law, or multisine
    /// ([multisine] of the config, or its defaults; the config's
    /// chirp.duration_s and chirp.taper_s are set aside). A sweep sets
    /// aside the config's [multisine] and needs a chirp.duration_s (or
    /// --duration-s); without chirp.taper_s it does not fade. Also read
    /// as --chirp-kind, its name before [excitation].
    #[arg(long, value_enum, alias = "chirp-kind")]
    excitation: Option<KindArg>,
    /// The BLA CSV of a multisine run (per line: the estimate, its
    /// total, noise and nonlinear 1σ, the distortion p-value) [default:
    /// beside --out, <stem>.bla.csv]. Refused with a sweep.
    #[arg(long, value_name = "FILE")]
    bla_csv: Option<PathBuf>,
    /// Inject a simulator fault: KIND@T_S with KIND one of nan, frozen,
    /// drop (10 samples), jump (0.2 mm), out_of_range, dead, blind, stall:MS (the host
    /// stalls once for MS ms; with --realtime); e.g. stall:30@5.
    #[arg(long, value_name = "KIND@T_S")]
    inject_fault: Option<String>,
    /// Backend: sim, serial:PATH, socketcan:IFACE or ethercat:IFACE [default: [backend] of
    /// the config]. Hardware always runs in real time.
    #[arg(long, value_name = "BACKEND")]
    backend: Option<BackendSpec>,
    #[command(flatten)]
    job: super::JobFlags,
    #[command(flatten)]
    outputs: super::OutputFlags,
}

impl ChirpArgs {
    /// The job request of the flags.
    fn request(&self) -> ChirpRequest {
        ChirpRequest {
            seed: self.seed,
            amplitude_a: self.amplitude_a,
            f_start_hz: self.f_start_hz,
            f_end_hz: self.f_end_hz,
            duration_s: self.duration_s,
            pace: self.pace.given(),
        }
    }

    /// The local-only overrides of the flags.
    fn local_overrides(&self) -> LocalOverrides {
        LocalOverrides {
            operating_point: self.point.point().operating_point(),
            mass_asymmetry: self.point.point().mass_asymmetry(),
            excitation: self.excitation.map(|k| match k {
                KindArg::Exponential => ExcitationKind::Exponential,
                KindArg::Linear => ExcitationKind::Linear,
                KindArg::Multisine => ExcitationKind::Multisine,
            }),
        }
    }

    /// The flag that set a config key (for error messages).
    fn flag_for(&self, key: &str) -> Option<String> {
        if let Some(f) = self.point.flag_for(key) {
            return Some(f);
        }
        let flag = match key {
            "chirp.amplitude_a" if self.amplitude_a.is_some() => "--amplitude-a",
            "chirp.f_start_hz" if self.f_start_hz.is_some() => "--f-start-hz",
            "chirp.f_end_hz" if self.f_end_hz.is_some() => "--f-end-hz",
            "chirp.duration_s" if self.duration_s.is_some() => "--duration-s",
            _ => return None,
        };
        Some(flag.to_string())
    }
}

pub(super) fn chirp(args: ChirpArgs, stop: Arc<AtomicBool>) -> ExitCode {
    if let Err(code) = args.pace.check_realtime(args.realtime) {
        return code;
    }
    if let Some(sock) = &args.job.daemon {
        let mut local_only = vec![
            (
                args.config.config.is_some(),
                "--config (the daemon runs the bench config it was started with: bench serve --config)",
            ),
            (args.out.out.is_some(), "--out"),
            (args.frf_csv.is_some(), "--frf-csv"),
            (args.png.png.is_some(), "--png"),
            (args.bla_csv.is_some(), "--bla-csv"),
            (args.outputs.overwrite, "--overwrite"),
            (
                args.live.given(),
                "--live (bench serve --live shows the daemon's jobs)",
            ),
        ];
        local_only.extend(args.point.given());
        local_only.extend([
            (args.backend.is_some(), "--backend"),
            (args.excitation.is_some(), "--excitation"),
            (args.inject_fault.is_some(), "--inject-fault"),
        ]);
        if let Some(code) = refuse_local_only(
            &local_only,
            "the daemon owns the bench, its config and where recordings go",
        ) {
            return code;
        }
        let job = JobRequest::Chirp(args.request());
        return via_daemon(sock, &job, args.job.json.json, print_summary);
    }
    let (mut cfg, config_path) = match load_config(args.config.config.as_deref()) {
        Ok(c) => c,
        Err(e) => return bad_input(e),
    };
    if let Err(e) = args.point.point().check() {
        return refused_request(e, &config_path, |key| args.flag_for(key));
    }
    let request = args.request();
    let inject = match args.inject_fault.as_deref().map(parse_fault).transpose() {
        Ok(f) => f,
        Err(reason) => {
            return bad_input(format!(
                "--inject-fault {}: {reason}",
                args.inject_fault.as_deref().unwrap_or_default()
            ))
        }
    };
    args.local_overrides().apply(&mut cfg);
    if let Err(e) = request.apply(&mut cfg) {
        return refused_request(e, &config_path, |key| args.flag_for(key));
    }
    // Before any output is claimed.
    let backend = BackendSpec::resolve(args.backend.as_ref(), &cfg);
    let pace = match args.pace.local(args.realtime, args.live.given(), &backend) {
        Ok(p) => p,
        Err(code) => return code,
    };
    let given = Given::default()
        .with("out", args.out.out.clone())
        .with("frf_csv", args.frf_csv.clone())
        .with("plot", args.png.png.clone())
        .with("bla_csv", args.bla_csv.clone());
    let dest = Destination::local(given, args.outputs.overwrite);
    let (out, named, outputs) = match ChirpOutputs::plan(&dest, cfg.excitation.kind) {
        Ok(p) => p,
        Err(e) => return run_failed(&e),
    };
    let ChirpOutputs {
        frf_csv,
        plot,
        bla_csv,
    } = named;
    let opts = ChirpOptions {
        frf_csv,
        plot,
        bla_csv,
        out,
        seed: request.seed.unwrap_or(cfg.sim.seed),
        config: cfg,
        config_path,
        realtime: args.realtime,
        pace,
        progress: std::io::stderr().is_terminal(),
        backend: args.backend.clone(),
        inject,
        catalogue: true,
    };
    // On a worker thread, with the loop's tick count for the preparation
    // watch (a stop before the first tick ends the run at once).
    // Kept until the run has ended: the live view serves while it runs.
    let _live = match args.live.start(opts.config.loop_.cpu) {
        Ok(l) => l,
        Err(code) => return code,
    };
    let stopped = Arc::clone(&stop);
    let result = job_thread::run_job(stop, move |stop, ticks| {
        run_chirp(&opts, outputs, stop, Some(&ticks))
    });
    let result = match result {
        Ok(r) => r,
        Err(code) => return code,
    };
    match result {
        Ok(summary) => match emit(&summary, args.job.json.json, print_summary) {
            // SIGINT/SIGTERM after the sweep, during the FRF, the fit and
            // the plot (under a second at the densest grid the config
            // allows): those were finished, and nothing is missing.
            Ok(()) if stopped.load(std::sync::atomic::Ordering::Relaxed) => {
                errln!(
                    "note: interrupted after the sweep, while the FRF, the modal fit and the plot were computed: they were finished first; the recording {} and every output are complete",
                    summary.recording.display()
                );
                ExitCode::SUCCESS
            }
            Ok(()) => ExitCode::SUCCESS,
            Err(code) => code,
        },
        Err(e) => run_failed_json(&e, args.job.json.json),
    }
}

pub(super) fn print_summary(s: &ChirpSummary) {
    outln!("bench chirp on {} (seed {})", s.backend, s.seed);
    outln!(
        "  operating point Y1o = {:.3} mm ({:.1} % of L), mass asymmetry Δm23 = {:+.1} %",
        s.operating_point_m * 1e3,
        s.operating_point_fraction_of_l * 100.0,
        s.mass_asymmetry * 100.0
    );
    outln!("  peak |x1| = {:.1} µm", s.peak_position_m * 1e6);
    outln!("  recording   {}", s.recording.display());
    outln!("  FRF (CSV)   {}", s.frf_csv.display());
    if let Some(note) = s.frf_estimator.as_ref().and_then(|e| e.note.as_ref()) {
        outln!("  estimator   {note}");
    }
    outln!("  Bode plot   {}", s.plot.display());
    if let Some(c) = &s.catalogue {
        outln!("  {}", c.line());
    }
    if let Some(p) = s.multisine.as_ref().and_then(|m| m.bla_csv.as_ref()) {
        outln!("  BLA (CSV)   {}", p.display());
    }
    if let Some(m) = &s.multisine {
        for line in m.lines() {
            outln!("{line}");
        }
    }
    match &s.fit {
        Some(fit) => super::fit::print_fit(fit),
        None => outln!("modal fit: none"),
    }
    let f: Vec<String> = s
        .model
        .natural_frequencies_hz
        .iter()
        .map(|f| format!("{f:.2}"))
        .collect();
    outln!("model natural frequencies: {} Hz", f.join(", "));
    super::fit::print_verdict(&s.verdict);
    outln!(
        "model zeros: {} (CMP-CNMP: {})",
        s.model.zero_types.join(", "),
        if s.model.cmp_cnmp { "yes" } else { "no" }
    );
    if let Some(l) = &s.current_limits {
        outln!("{}", l.line());
    }
    outln!("{}", s.stalls.line());
    for line in s.timing.lines() {
        outln!("{line}");
    }
}
