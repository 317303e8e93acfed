//! The `bench` command line (flag parsing and printing; may use the whole
//! library, and is the only place that maps config keys to flag names and
//! outcomes to exit statuses). `main` is the one place that turns outcomes
//! into exit statuses:
//!
//! | status | meaning |
//! |---|---|
//! | 0 | success |
//! | 1 | unexpected error (I/O after the run, internal) |
//! | 2 | bad input: config or arguments; nothing was enabled, no recording left |
//! | 3 | safety fault: the supervisor latched; 0 A, amplifier disabled, recording finished |
//! | 4 | hardware (HAL) error; 0 A, amplifier disabled, recording finished |
//! | 130 | interrupted by SIGINT/SIGTERM; 0 A, amplifier disabled, recording finished |
//! | 5 | `--daemon`: the daemon refused the job (busy, or a latched fault) |

use anyhow::Context;
use bench::config::{BenchConfig, ChirpKind, ConfigError, DEFAULT_CONFIG};
use bench::error::RunError;
use bench::jobs::chirp::{run_chirp, ChirpOptions, ChirpSummary};
use bench::jobs::request::{
    parse_fault, ChirpRequest, ControlRequest, JobRequest, LocalOverrides, OperatingPoint,
    RequestError,
};
use bench::jobs::step::{run_control, ControlOptions, ControlSummary};
use bench::rt::backend::BackendSpec;
use bench_hal::emulator::serial::{Pty, SerialEmulatorOptions};
use bench_hal::emulator::{DeviceCore, EmulatorStatus, LinkFault, ScheduledLinkFault};
use bench_hal::sim::ScheduledFault;
use clap::{Args, Parser, Subcommand, ValueEnum};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// Runs a precision flexure stage (SR4DoF) on a lab bench: chirp
/// identification in a real-time loop, recorded to MCAP. Without hardware it
/// runs the thesis' lumped model as a simulated plant.
#[derive(Debug, Parser)]
#[command(name = "bench", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Excite the stage with a chirp, record it, estimate the FRF, plot it
    /// beside the model and report the modes and the CMP-CNMP phase test.
    Chirp(ChirpArgs),
    /// Check a controller against the plant, then run a closed-loop step
    /// under the supervisor and report rise, settling, overshoot and the
    /// steady-state positioning noise.
    Control(ControlArgs),
    /// Run the simulated plant as a DAQ device (serial over a
    /// pseudo-terminal, or SocketCAN), so the hardware backends can be
    /// exercised without hardware.
    #[command(subcommand)]
    Emulate(EmulateCommand),
    /// Own the bench: keep it safe between jobs and serve chirp and control
    /// jobs, one at a time, as JSON lines on a Unix socket.
    Serve(ServeArgs),
}

#[derive(Debug, Args)]
struct ServeArgs {
    /// Bench description (TOML).
    #[arg(long, value_name = "FILE", default_value = DEFAULT_CONFIG)]
    config: PathBuf,
    /// Socket path [default: $XDG_RUNTIME_DIR/bench.sock, else
    /// /run/bench/bench.sock]. Its directory must not be world-writable.
    #[arg(long, value_name = "PATH")]
    socket: Option<PathBuf>,
    /// Let this group use the socket (mode 0660; default owner-only 0600).
    #[arg(long, value_name = "GROUP")]
    socket_group: Option<String>,
    /// Directory for the job recordings and the rolling event log.
    #[arg(long, value_name = "DIR", default_value = "recordings")]
    recordings: PathBuf,
    /// Backend [default: [backend] of the config].
    #[arg(long, value_name = "BACKEND")]
    backend: Option<BackendSpec>,
    /// Simulator seed [default: sim.seed].
    #[arg(long, value_name = "N")]
    seed: Option<u64>,
    /// Inject a simulator fault T_S seconds after start, between jobs (for
    /// testing supervision): KIND@T_S with KIND one of nan, frozen, drop,
    /// jump, out_of_range.
    #[arg(long, value_name = "KIND@T_S")]
    inject_fault: Option<String>,
}

#[derive(Debug, Subcommand)]
enum EmulateCommand {
    /// Serial DAQ on a new pseudo-terminal: prints its path on the first
    /// line of stdout, then serves `bench ... --backend serial:PATH`.
    Serial(EmulateArgs),
    /// CAN analog I/O module on a SocketCAN interface.
    Can {
        /// CAN interface, e.g. vcan0 (overrides backend.can.interface).
        #[arg(long, value_name = "IFACE")]
        iface: Option<String>,
        #[command(flatten)]
        common: EmulateArgs,
    },
}

#[derive(Debug, Args)]
struct EmulateArgs {
    /// Bench description (TOML): plant, rate, [emulator] watchdog.
    #[arg(long, value_name = "FILE", default_value = DEFAULT_CONFIG)]
    config: PathBuf,
    /// Plant noise seed [default: sim.seed].
    #[arg(long, value_name = "N")]
    seed: Option<u64>,
    /// Inject a fault at device time T_S (repeatable): link faults
    /// bitflip:BITS[xFRAMES], drop:FRAMES, delay:S, stall:S, disconnect;
    /// plant faults nan, frozen, jump, out_of_range. E.g. stall:0.5@2.
    #[arg(long = "fault", value_name = "KIND@T_S")]
    faults: Vec<String>,
    /// Protocol version to announce (serial; for testing refusal).
    #[arg(long, value_name = "N")]
    protocol_version: Option<u16>,
    /// Lockstep test mode (serial): while enabled, the device waits for the
    /// answer to each sample before taking the next, so results do not
    /// depend on scheduling.
    #[arg(long)]
    lockstep: bool,
    /// Stop after this long, s (default: until SIGINT/SIGTERM).
    #[arg(long, value_name = "S")]
    duration_s: Option<f64>,
}

#[derive(Debug, Args)]
#[command(group(clap::ArgGroup::new("which").required(true).args(["slow", "fast", "controller"])))]
struct ControlArgs {
    /// The slow controller of Eq. (6-6) (`[controller.slow]`).
    #[arg(long)]
    slow: bool,
    /// The fast controller of Eq. (6-7) (`[controller.fast]`).
    #[arg(long)]
    fast: bool,
    /// Any `[controller.NAME]` of the config.
    #[arg(long, value_name = "NAME")]
    controller: Option<String>,
    /// Bench description (TOML).
    #[arg(long, value_name = "FILE", default_value = DEFAULT_CONFIG)]
    config: PathBuf,
    /// Step size, m (overrides step.step_m).
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    step_m: Option<f64>,
    /// Run time, s (overrides step.duration_s).
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    duration_s: Option<f64>,
    /// Smooth the step with a raised-cosine ramp of this length, s
    /// (overrides step.smooth_s).
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    smooth_s: Option<f64>,
    /// MCAP recording [default: recordings/control-<name>-<UTC time>.mcap].
    #[arg(long, value_name = "FILE.mcap")]
    out: Option<PathBuf>,
    /// Step plot PNG [default: beside --out, <stem>.step.png].
    #[arg(long, value_name = "FILE.png")]
    plot: Option<PathBuf>,
    /// Print the summary as one JSON object on stdout.
    #[arg(long)]
    json: bool,
    /// Pace the loop in real time.
    #[arg(long)]
    realtime: bool,
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
    #[arg(long, value_name = "N")]
    seed: Option<u64>,
    /// Inject a simulator fault: KIND@T_S with KIND one of nan, frozen,
    /// drop (10 samples), jump (0.2 mm), out_of_range; e.g. nan@1.5.
    #[arg(long, value_name = "KIND@T_S")]
    inject_fault: Option<String>,
    /// Backend: sim, serial:PATH or socketcan:IFACE [default: [backend] of
    /// the config]. Hardware always runs in real time.
    #[arg(long, value_name = "BACKEND")]
    backend: Option<BackendSpec>,
    /// Submit to a running `bench serve` instead of opening the bench here
    /// [SOCKET default: $XDG_RUNTIME_DIR/bench.sock, else
    /// /run/bench/bench.sock]. The daemon's config and backend apply.
    #[arg(long, value_name = "SOCKET", num_args = 0..=1, default_missing_value = "")]
    daemon: Option<String>,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum KindArg {
    Exponential,
    Linear,
}

#[derive(Debug, Args)]
struct ChirpArgs {
    /// Bench description (TOML).
    #[arg(long, value_name = "FILE", default_value = DEFAULT_CONFIG)]
    config: PathBuf,
    /// MCAP recording [default: recordings/chirp-<UTC time>.mcap].
    #[arg(long, value_name = "FILE.mcap")]
    out: Option<PathBuf>,
    /// FRF CSV [default: beside --out, <stem>.frf.csv].
    #[arg(long, value_name = "FILE")]
    frf_csv: Option<PathBuf>,
    /// Bode plot PNG [default: beside --out, <stem>.bode.png].
    #[arg(long, value_name = "FILE.png")]
    plot: Option<PathBuf>,
    /// Pace the loop in real time (absolute deadlines, SCHED_FIFO and
    /// mlockall when permitted) instead of virtual time.
    #[arg(long)]
    realtime: bool,
    /// Simulator noise seed [default: sim.seed from the config].
    #[arg(long, value_name = "N")]
    seed: Option<u64>,
    /// Print the summary as one JSON object on stdout.
    #[arg(long)]
    json: bool,
    /// Operating point Y1o, m (overrides plant.operating_point_m).
    #[arg(
        long,
        value_name = "M",
        allow_negative_numbers = true,
        conflicts_with = "operating_point_pct"
    )]
    operating_point_m: Option<f64>,
    /// Operating point Y1o in % of the beam length L.
    #[arg(long, value_name = "PERCENT", allow_negative_numbers = true)]
    operating_point_pct: Option<f64>,
    /// Mass asymmetry Δm23 = m2/m3 − 1, e.g. 0.1 for +10 % (overrides
    /// plant.mass_asymmetry).
    #[arg(long, value_name = "X", allow_negative_numbers = true)]
    mass_asymmetry: Option<f64>,
    /// Chirp current amplitude, A (overrides chirp.amplitude_a).
    #[arg(long, value_name = "A", allow_negative_numbers = true)]
    amplitude_a: Option<f64>,
    /// Sweep start frequency, Hz (overrides chirp.f_start_hz).
    #[arg(long, value_name = "HZ", allow_negative_numbers = true)]
    f_start_hz: Option<f64>,
    /// Sweep end frequency, Hz (overrides chirp.f_end_hz).
    #[arg(long, value_name = "HZ", allow_negative_numbers = true)]
    f_end_hz: Option<f64>,
    /// Sweep duration, s (overrides chirp.duration_s).
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    duration_s: Option<f64>,
    /// Sweep law (overrides chirp.kind).
    #[arg(long, value_enum)]
    chirp_kind: Option<KindArg>,
    /// Backend: sim, serial:PATH or socketcan:IFACE [default: [backend] of
    /// the config]. Hardware always runs in real time.
    #[arg(long, value_name = "BACKEND")]
    backend: Option<BackendSpec>,
    /// Submit to a running `bench serve` instead of opening the bench here
    /// [SOCKET default: $XDG_RUNTIME_DIR/bench.sock, else
    /// /run/bench/bench.sock]. The daemon's config and backend apply.
    #[arg(long, value_name = "SOCKET", num_args = 0..=1, default_missing_value = "")]
    daemon: Option<String>,
}

/// Exit statuses (see the module docs).
mod status {
    pub const ERROR: u8 = 1;
    pub const BAD_INPUT: u8 = 2;
    pub const FAULT: u8 = 3;
    pub const HAL: u8 = 4;
    pub const INTERRUPTED: u8 = 130;
    pub const DAEMON_REFUSED: u8 = 5;
}

pub fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("BENCH_LOG")
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .with_target(false)
        .init();
    let cli = Cli::parse();
    let stop = Arc::new(AtomicBool::new(false));
    if let Err(e) = install_signal_handlers(&stop) {
        eprintln!("error: {e:#}");
        return ExitCode::from(status::ERROR);
    }
    match cli.command {
        Command::Chirp(args) => chirp(args, stop),
        Command::Control(args) => control(args, stop),
        Command::Emulate(cmd) => emulate(cmd, stop),
        Command::Serve(args) => serve(args),
    }
}

/// First SIGINT/SIGTERM raises `stop` (the loop winds down safely); a second
/// one exits at once.
fn install_signal_handlers(stop: &Arc<AtomicBool>) -> anyhow::Result<()> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    for sig in [SIGINT, SIGTERM] {
        signal_hook::flag::register_conditional_shutdown(
            sig,
            i32::from(status::INTERRUPTED),
            Arc::clone(stop),
        )
        .context("installing signal handlers")?;
        signal_hook::flag::register(sig, Arc::clone(stop)).context("installing signal handlers")?;
    }
    Ok(())
}

fn bad_input(msg: impl std::fmt::Display) -> ExitCode {
    eprintln!("error: {msg}");
    ExitCode::from(status::BAD_INPUT)
}

/// `recordings/<prefix>-YYYYmmddTHHMMSSZ.mcap`
fn default_recording(prefix: &str) -> PathBuf {
    bench::jobs::session::stamped_recording(Path::new("recordings"), prefix, "")
}

use bench::jobs::session::beside;

fn load_config(path: &Path) -> Result<BenchConfig, ConfigError> {
    BenchConfig::load(path)
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
        }
    }

    /// The local-only overrides of the flags.
    fn local_overrides(&self) -> LocalOverrides {
        LocalOverrides {
            operating_point: self.operating_point_m.map(OperatingPoint::Metres).or(self
                .operating_point_pct
                .map(OperatingPoint::PercentOfBeamLength)),
            mass_asymmetry: self.mass_asymmetry,
            chirp_kind: self.chirp_kind.map(|k| match k {
                KindArg::Exponential => ChirpKind::Exponential,
                KindArg::Linear => ChirpKind::Linear,
            }),
        }
    }

    /// The flag that set a config key (for error messages).
    fn flag_for(&self, key: &str) -> Option<String> {
        let flag = match key {
            "plant.operating_point_m" if self.operating_point_m.is_some() => "--operating-point-m",
            "plant.operating_point_m" if self.operating_point_pct.is_some() => {
                "--operating-point-pct"
            }
            "plant.mass_asymmetry" if self.mass_asymmetry.is_some() => "--mass-asymmetry",
            "chirp.amplitude_a" if self.amplitude_a.is_some() => "--amplitude-a",
            "chirp.f_start_hz" if self.f_start_hz.is_some() => "--f-start-hz",
            "chirp.f_end_hz" if self.f_end_hz.is_some() => "--f-end-hz",
            "chirp.duration_s" if self.duration_s.is_some() => "--duration-s",
            _ => return None,
        };
        Some(flag.to_string())
    }
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
            _ => None,
        }
    }
}

fn chirp(args: ChirpArgs, stop: Arc<AtomicBool>) -> ExitCode {
    if let Some(sock) = &args.daemon {
        let local_only = [
            (args.out.is_some(), "--out"),
            (args.frf_csv.is_some(), "--frf-csv"),
            (args.plot.is_some(), "--plot"),
            (args.operating_point_m.is_some(), "--operating-point-m"),
            (args.operating_point_pct.is_some(), "--operating-point-pct"),
            (args.mass_asymmetry.is_some(), "--mass-asymmetry"),
            (args.backend.is_some(), "--backend"),
            (args.chirp_kind.is_some(), "--chirp-kind"),
        ];
        if let Some((_, flag)) = local_only.iter().find(|(set, _)| *set) {
            return bad_input(format!(
                "{flag}: not with --daemon (the daemon owns the bench, its config and where recordings go)"
            ));
        }
        let job = JobRequest::Chirp(args.request());
        return via_daemon(sock, &job, args.json, print_summary);
    }
    let mut cfg = match load_config(&args.config) {
        Ok(c) => c,
        Err(e) => return bad_input(e),
    };
    let request = args.request();
    args.local_overrides().apply(&mut cfg);
    if let Err(e) = request.apply(&mut cfg) {
        return refused_request(e, &args.config, |key| args.flag_for(key));
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| default_recording("chirp"));
    if out.extension().and_then(|e| e.to_str()) != Some("mcap") {
        return bad_input(format!(
            "--out {}: the recording must end in .mcap",
            out.display()
        ));
    }
    let opts = ChirpOptions {
        frf_csv: args
            .frf_csv
            .clone()
            .unwrap_or_else(|| beside(&out, ".frf.csv")),
        plot: args
            .plot
            .clone()
            .unwrap_or_else(|| beside(&out, ".bode.png")),
        out,
        seed: request.seed.unwrap_or(cfg.sim.seed),
        config: cfg,
        config_path: args.config.clone(),
        realtime: args.realtime,
        progress: std::io::stderr().is_terminal(),
        backend: args.backend.clone(),
    };
    match run_chirp(&opts, stop) {
        Ok(summary) => match emit(&summary, args.json, print_summary) {
            Ok(()) => ExitCode::SUCCESS,
            Err(code) => code,
        },
        Err(e) => {
            eprintln!("error: {e:#}");
            exit_for(&e)
        }
    }
}

fn print_summary(s: &ChirpSummary) {
    println!("bench chirp on {} (seed {})", s.backend, s.seed);
    println!(
        "  operating point Y1o = {:.3} mm ({:.1} % of L), mass asymmetry Δm23 = {:+.1} %",
        s.operating_point_m * 1e3,
        s.operating_point_fraction_of_l * 100.0,
        s.mass_asymmetry * 100.0
    );
    println!("  peak |x1| = {:.1} µm", s.peak_position_m * 1e6);
    println!("  recording   {}", s.recording.display());
    println!("  FRF (CSV)   {}", s.frf_csv.display());
    println!("  Bode plot   {}", s.plot.display());
    println!("resonances (measured):");
    for r in &s.resonances {
        match r.damping_ratio {
            Some(z) => println!(
                "  {:8.2} Hz  |H| = {:.3e} m/A  ζ ≈ {:.4}",
                r.frequency_hz, r.magnitude_m_per_a, z
            ),
            None => println!(
                "  {:8.2} Hz  |H| = {:.3e} m/A",
                r.frequency_hz, r.magnitude_m_per_a
            ),
        }
    }
    let f: Vec<String> = s
        .model
        .natural_frequencies_hz
        .iter()
        .map(|f| format!("{f:.2}"))
        .collect();
    println!("model natural frequencies: {} Hz", f.join(", "));
    match &s.closely_spaced_pair {
        Some(p) => {
            println!(
                "closely spaced pair: {:.2} Hz and {:.2} Hz; net phase over {:.1}–{:.1} Hz: {:.0}° (≈ {:.0}°)",
                p.lower_hz, p.upper_hz, p.band_hz.0, p.band_hz.1, p.net_phase_deg, p.net_phase_multiple_deg
            );
            if p.cmp_cnmp {
                println!("  → CMP-CNMP zeros: the pair shows the net −360° phase drop");
            } else {
                println!("  → no CMP-CNMP zeros: the zeros between the modes give back phase");
            }
        }
        None => println!(
            "closely spaced pair: not resolved (no two adjacent resonances within 25 %): CMP-CNMP verdict undetermined"
        ),
    }
    println!(
        "model zeros: {} (CMP-CNMP: {})",
        s.model.zero_types.join(", "),
        if s.model.cmp_cnmp { "yes" } else { "no" }
    );
    let t = &s.timing;
    println!(
        "loop: {} ticks at {:.0} Hz ({}), {:.2} s wall; compute mean {:.2} µs, p99 {:.2} µs, max {:.1} µs; wake p99 {:.1} µs; overruns {}; dropped {}",
        t.ticks, t.rate_hz, t.mode, t.wall_s, t.compute_mean_us, t.compute_p99_us, t.compute_max_us,
        t.wake_latency_p99_us, t.overruns, t.dropped_records
    );
}

/// Prints a summary: one JSON object with `--json`, else the human form.
fn emit<T: serde::Serialize>(summary: &T, json: bool, human: fn(&T)) -> Result<(), ExitCode> {
    if json {
        let s = serde_json::to_string(summary).map_err(|e| {
            eprintln!("error: {e}");
            ExitCode::from(status::ERROR)
        })?;
        println!("{s}");
    } else {
        human(summary);
    }
    Ok(())
}

/// Exit for a job request the config refuses, naming the flag when one set
/// the offending config key or request field (`flag`), else the file.
fn refused_request(
    e: RequestError,
    config: &Path,
    flag: impl Fn(&str) -> Option<String>,
) -> ExitCode {
    match e {
        RequestError::Invalid { key, reason } => match flag(&key) {
            Some(flag) => bad_input(format!("{flag} (config key {key}): {reason}")),
            None => bad_input(ConfigError::Invalid {
                path: config.to_path_buf(),
                key,
                reason,
            }),
        },
        RequestError::Field {
            field,
            value,
            reason,
        } => match flag(field) {
            Some(flag) => bad_input(format!("{flag}: {reason}")),
            None => bad_input(format!("{field} {value:?}: {reason}")),
        },
    }
}

fn exit_for(e: &RunError) -> ExitCode {
    ExitCode::from(match e {
        RunError::BadInput(_) | RunError::Refused(_) => status::BAD_INPUT,
        RunError::Fault { .. } => status::FAULT,
        RunError::Hal { .. } => status::HAL,
        RunError::Interrupted { .. } => status::INTERRUPTED,
        RunError::TickLimit { .. }
        | RunError::Record(_)
        | RunError::Output { .. }
        | RunError::Json(_)
        | RunError::Thread(_) => status::ERROR,
    })
}

fn control(args: ControlArgs, stop: Arc<AtomicBool>) -> ExitCode {
    if let Some(sock) = &args.daemon {
        let local_only = [
            (args.out.is_some(), "--out"),
            (args.plot.is_some(), "--plot"),
            (args.backend.is_some(), "--backend"),
            (args.check_only, "--check-only"),
            (args.frf.is_some(), "--frf"),
        ];
        if let Some((_, flag)) = local_only.iter().find(|(set, _)| *set) {
            return bad_input(format!(
                "{flag}: not with --daemon (run it locally, or let the daemon choose the recording)"
            ));
        }
        let job = JobRequest::Control(args.request());
        return via_daemon(sock, &job, args.json, print_control_summary);
    }
    let mut cfg = match load_config(&args.config) {
        Ok(c) => c,
        Err(e) => return bad_input(e),
    };
    let request = args.request();
    let inject = match request.apply(&mut cfg) {
        Ok(f) => f,
        Err(e) => return refused_request(e, &args.config, |key| args.flag_for(key)),
    };
    let name = request.controller.clone();
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| default_recording(&format!("control-{name}")));
    if out.extension().and_then(|e| e.to_str()) != Some("mcap") {
        return bad_input(format!(
            "--out {}: the recording must end in .mcap",
            out.display()
        ));
    }
    let opts = ControlOptions {
        plot: args
            .plot
            .clone()
            .unwrap_or_else(|| beside(&out, ".step.png")),
        out,
        seed: request.seed.unwrap_or(cfg.sim.seed),
        config: cfg,
        config_path: args.config.clone(),
        controller: name,
        check_only: args.check_only,
        frf: args.frf.clone(),
        override_check: request.override_check,
        realtime: args.realtime,
        progress: std::io::stderr().is_terminal(),
        inject,
        backend: args.backend.clone(),
    };
    match run_control(&opts, stop) {
        Ok(summary) => {
            if let Err(code) = emit(&summary, args.json, print_control_summary) {
                return code;
            }
            if args.check_only && !summary.loop_check.passed() {
                eprintln!(
                    "error: loop check refuses controller {}: {}",
                    summary.controller,
                    summary.loop_check.failures.join("; ")
                );
                return ExitCode::from(status::BAD_INPUT);
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e:#}");
            exit_for(&e)
        }
    }
}

fn print_margins(label: &str, m: &bench::control::loop_check::Margins) {
    let wc: Vec<String> = m
        .crossovers_rad_s
        .iter()
        .map(|w| format!("{w:.1}"))
        .collect();
    println!(
        "  {label}: crossover(s) {} rad/s; phase margin {}; gain margin {}; peak |S| {:.2} ({:.1} dB) at {:.0} rad/s",
        if wc.is_empty() { "none".to_string() } else { wc.join(", ") },
        m.phase_margin_deg.map_or("–".to_string(), |p| format!("{p:.1}°")),
        m.gain_margin_db.map_or("∞".to_string(), |g| format!("{g:.1} dB")),
        m.sensitivity_peak,
        20.0 * m.sensitivity_peak.log10(),
        m.sensitivity_peak_at_rad_s
    );
}

fn print_control_summary(s: &ControlSummary) {
    println!(
        "bench control --controller {} on {} (seed {})",
        s.controller, s.backend, s.seed
    );
    if !s.description.is_empty() {
        println!("  {}", s.description);
    }
    let c = &s.loop_check;
    println!("loop check:");
    let d = &c.discretization;
    println!(
        "  discretisation {}: within {:.3} dB / {:.2}° of the continuous design up to {:.0} Hz; above, at most {:+.2} dB",
        d.method.as_str(),
        d.max_error_db,
        d.max_error_deg,
        d.up_to_hz,
        d.above_band_max_excess_db
    );
    print_margins("model, amplifier included", &c.model);
    print_margins(
        "model, amplifier lag excluded",
        &c.model_without_amplifier_lag,
    );
    if let Some(m) = &c.measured {
        print_margins("measured FRF", m);
    }
    println!(
        "  closed loop {} (largest pole |z| = {:.5})",
        if c.closed_loop_stable {
            "stable"
        } else {
            "UNSTABLE"
        },
        c.largest_pole_magnitude
    );
    if c.passed() {
        println!("  → passed");
    } else {
        for f in &c.failures {
            println!("  → refused: {f}");
        }
    }
    if let Some(m) = &s.metrics {
        let opt = |v: Option<f64>, unit: &str, scale: f64| {
            v.map_or("–".to_string(), |x| format!("{:.4} {unit}", x * scale))
        };
        println!("step of {:.2} µm:", m.step_m * 1e6);
        println!("  rise time (10–90 %) {}", opt(m.rise_time_s, "s", 1.0));
        println!("  settling time (2 %) {}", opt(m.settling_time_s, "s", 1.0));
        println!("  overshoot {:.1} %", m.overshoot_pct);
        println!(
            "  steady-state error over the last {:.1} s: mean {:.1} nm, σ {:.1} nm",
            m.steady_state_window_s, m.steady_state_error_mean_nm, m.steady_state_error_std_nm
        );
        println!("  peak command {:.3} A", m.peak_command_a);
    }
    if s.disturbance_rms_n > 0.0 {
        println!("disturbance: {:.4} N RMS", s.disturbance_rms_n);
    }
    if let Some(p) = &s.recording {
        println!("recording   {}", p.display());
    }
    if let Some(p) = &s.plot {
        println!("step plot   {}", p.display());
    }
    if let Some(t) = &s.timing {
        println!(
            "loop: {} ticks at {:.0} Hz ({}), {:.2} s wall; compute mean {:.2} µs, p99 {:.2} µs; overruns {}",
            t.ticks, t.rate_hz, t.mode, t.wall_s, t.compute_mean_us, t.compute_p99_us, t.overruns
        );
    }
}

/// Parses an emulator `--fault KIND@T_S`: a link fault or a plant fault.
fn parse_emulator_fault(s: &str) -> Result<EmulatorFault, String> {
    let (kind, at) = s
        .rsplit_once('@')
        .ok_or_else(|| format!("--fault {s}: expected KIND@T_S, e.g. stall:0.5@2"))?;
    let at_s: f64 = at
        .parse()
        .ok()
        .filter(|t: &f64| t.is_finite() && *t >= 0.0)
        .ok_or_else(|| {
            format!("--fault {s}: time {at:?} is not a non-negative number of seconds")
        })?;
    match LinkFault::parse(kind) {
        Ok(kind) => Ok(EmulatorFault::Link(ScheduledLinkFault { at_s, kind })),
        Err(link_err) => match parse_fault(s) {
            Ok(f) => Ok(EmulatorFault::Plant(f)),
            Err(_) => Err(format!(
                "--fault {s}: {link_err}; or a plant fault nan, frozen, drop, jump, out_of_range"
            )),
        },
    }
}

enum EmulatorFault {
    Link(ScheduledLinkFault),
    Plant(ScheduledFault),
}

fn emulate(cmd: EmulateCommand, stop: Arc<AtomicBool>) -> ExitCode {
    let (args, can_iface) = match cmd {
        EmulateCommand::Serial(a) => (a, None),
        EmulateCommand::Can { iface, common } => (common, Some(iface)),
    };
    let cfg = match load_config(&args.config).and_then(|c| c.validate(&args.config).map(|_| c)) {
        Ok(c) => c,
        Err(e) => return bad_input(e),
    };
    let mut link_faults = Vec::new();
    let mut plant_faults = Vec::new();
    for f in &args.faults {
        match parse_emulator_fault(f) {
            Ok(EmulatorFault::Link(l)) => link_faults.push(l),
            Ok(EmulatorFault::Plant(p)) => plant_faults.push(p),
            Err(e) => return bad_input(e),
        }
    }
    if let Some(d) = args.duration_s {
        if !(d.is_finite() && d > 0.0) {
            return bad_input(format!(
                "--duration-s {d}: must be a positive number of seconds"
            ));
        }
    }
    let seed = args.seed.unwrap_or(cfg.sim.seed);
    let watchdog_ns = (cfg.emulator.watchdog_ms * 1e6) as u64;
    let mut core = match DeviceCore::new(cfg.sim_params(seed), cfg.loop_.period_ns(), watchdog_ns) {
        Ok(c) => c,
        Err(e) => return bad_input(format!("config {}: {e}", args.config.display())),
    };
    for f in plant_faults {
        core.inject(f);
    }
    let priority = (cfg.emulator.priority > 0).then_some(cfg.emulator.priority);
    let status = Arc::new(EmulatorStatus::default());
    let rate_hz = cfg.loop_.rate_hz;
    if let Some(d) = args.duration_s {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_secs_f64(d));
            stop.store(true, std::sync::atomic::Ordering::Relaxed);
        });
    }
    let result = match can_iface {
        None => {
            let pty = match Pty::open() {
                Ok(p) => p,
                Err(e) => {
                    eprintln!("error: cannot create a pseudo-terminal: {e}");
                    return ExitCode::from(status::ERROR);
                }
            };
            println!("{}", pty.path());
            eprintln!(
                "serial DAQ emulator on {} at {rate_hz} Hz, watchdog {} ms, protocol v{}; connect with --backend serial:{}; Ctrl-C stops",
                pty.path(),
                cfg.emulator.watchdog_ms,
                args.protocol_version.unwrap_or(bench_hal::protocol::VERSION),
                pty.path()
            );
            let opts = SerialEmulatorOptions {
                protocol_version: args
                    .protocol_version
                    .unwrap_or(bench_hal::protocol::VERSION),
                position_lsb_m: cfg.emulator.position_lsb_m,
                link_faults,
                seed,
                realtime_priority: priority,
                lockstep: args.lockstep,
            };
            let st = Arc::clone(&status);
            let s = Arc::clone(&stop);
            std::thread::Builder::new()
                .name("bench-emulator".into())
                .spawn(move || bench_hal::emulator::serial::run(pty, core, &opts, &s, &st))
                .map_err(|e| e.to_string())
                .and_then(|t| t.join().map_err(|_| "emulator thread panicked".to_string()))
                .and_then(|r| r.map_err(|e| e.to_string()))
        }
        Some(iface) => {
            if args.protocol_version.is_some() {
                return bad_input(
                    "--protocol-version: only the serial emulator has a protocol version",
                );
            }
            let ccfg = bench_hal::can::CanConfig {
                interface: iface.unwrap_or_else(|| cfg.backend.can.interface.clone()),
                ..cfg.backend.can.clone()
            };
            let sock = match bench_hal::can::open_socket(&ccfg.interface) {
                Ok(s) => s,
                Err(e) => return bad_input(format!("--iface {}: {e}", ccfg.interface)),
            };
            println!("{}", ccfg.interface);
            eprintln!(
                "CAN DAQ emulator on {} node {} at {rate_hz} Hz, watchdog {} ms; connect with --backend socketcan:{}; Ctrl-C stops",
                ccfg.interface, ccfg.node_id, cfg.emulator.watchdog_ms, ccfg.interface
            );
            let st = Arc::clone(&status);
            let s = Arc::clone(&stop);
            std::thread::Builder::new()
                .name("bench-emulator".into())
                .spawn(move || {
                    if let Some(p) = priority {
                        bench::rt::make_realtime(p, None);
                    }
                    bench_hal::emulator::can::run_emulator(sock, &ccfg, core, &link_faults, &s, &st)
                })
                .map_err(|e| e.to_string())
                .and_then(|t| t.join().map_err(|_| "emulator thread panicked".to_string()))
                .and_then(|r| r.map_err(|e| e.to_string()))
        }
    };
    use std::sync::atomic::Ordering::Relaxed;
    eprintln!(
        "emulator stopped: {} samples sent, {} commands, {} bad frames, {} late commands, largest tick lateness {} µs, watchdog {}",
        status.samples_sent.load(Relaxed),
        status.commands_received.load(Relaxed),
        status.bad_frames.load(Relaxed),
        status.late_commands.load(Relaxed),
        status.max_tick_lateness_ns.load(Relaxed) / 1000,
        if status.watchdog_trip_mono_ns.load(Relaxed) != 0 {
            "tripped"
        } else {
            "never tripped"
        }
    );
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: emulator: {e}");
            ExitCode::from(status::ERROR)
        }
    }
}

/// Submits a job to the daemon, shows its progress on stderr and prints the
/// summary as the local run does.
fn via_daemon<T: serde::de::DeserializeOwned + serde::Serialize>(
    socket: &str,
    job: &JobRequest,
    json: bool,
    human: fn(&T),
) -> ExitCode {
    let cmd = job.kind();
    let socket = if socket.is_empty() {
        bench::daemon::default_socket_path()
    } else {
        PathBuf::from(socket)
    };
    let show = std::io::stderr().is_terminal();
    let result = bench::daemon::client::submit(&socket, job, |ev| {
        if !show {
            return;
        }
        match ev["event"].as_str() {
            Some("progress") => {
                let (t, n) = (
                    ev["ticks"].as_f64().unwrap_or(0.0),
                    ev["total_ticks"].as_f64().unwrap_or(1.0),
                );
                eprint!("\r{cmd} on the daemon: {:5.1} %", 100.0 * t / n.max(1.0));
            }
            Some("job_started") => {
                eprintln!("{cmd} job {} started: {}", ev["job"], ev["recording"])
            }
            Some("job_finished") => eprintln!(),
            _ => {}
        }
    });
    match result {
        Ok(v) => match serde_json::from_value::<T>(v.clone()) {
            Ok(summary) => {
                if let Some(r) = v.get("recording").and_then(|r| r.as_str()) {
                    if !json {
                        println!("recording (daemon) {r}");
                    }
                }
                match emit(&summary, json, human) {
                    Ok(()) => ExitCode::SUCCESS,
                    Err(code) => code,
                }
            }
            Err(e) => {
                eprintln!("error: the daemon's summary does not parse: {e}");
                ExitCode::from(status::ERROR)
            }
        },
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(match &e {
                bench::daemon::client::ClientError::Connect { .. } => status::BAD_INPUT,
                bench::daemon::client::ClientError::Io(_) => status::ERROR,
                bench::daemon::client::ClientError::Api { kind, .. } => {
                    use bench::daemon::ApiErrorKind as K;
                    match kind {
                        K::BadParams | K::BadRequest | K::UnknownCommand | K::Refused => {
                            status::BAD_INPUT
                        }
                        K::Busy | K::Faulted => status::DAEMON_REFUSED,
                        K::Fault => status::FAULT,
                        K::Hal => status::HAL,
                        K::Interrupted => status::INTERRUPTED,
                        K::Error => status::ERROR,
                    }
                }
            })
        }
    }
}

fn serve(args: ServeArgs) -> ExitCode {
    let cfg = match load_config(&args.config).and_then(|c| c.validate(&args.config).map(|_| c)) {
        Ok(c) => c,
        Err(e) => return bad_input(e),
    };
    let inject = match args.inject_fault.as_deref().map(parse_fault).transpose() {
        Ok(f) => f,
        Err(e) => return bad_input(format!("--inject-fault: {e}")),
    };
    let opts = bench::daemon::ServeOptions {
        inject,
        seed: args.seed.unwrap_or(cfg.sim.seed),
        config: cfg,
        config_path: args.config,
        socket: args
            .socket
            .unwrap_or_else(bench::daemon::default_socket_path),
        socket_group: args.socket_group,
        recordings: args.recordings,
        backend: args.backend,
    };
    match bench::daemon::serve(opts) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e @ bench::daemon::ServeError::BadInput(_)) => bad_input(e),
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(status::ERROR)
        }
    }
}
