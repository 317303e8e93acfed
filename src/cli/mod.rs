//! The `bench` command line (flag parsing and printing; may use the whole
//! library, and is the only place that maps config keys to flag names and
//! outcomes to exit statuses). `main` is the one place that turns outcomes
//! into exit statuses, by the one table of them,
//! [`bench::error::EXIT_STATUSES`] (`bench --help` lists it; the README's
//! *Exit status* table and every command's `--help` are tested against it).
//!
//! One file per command (`chirp.rs`, `control.rs`, `emulate.rs`,
//! `serve.rs`: its flags and its printing); this file holds the command
//! tree, the exit statuses and what the commands share.

/// `outln!` for the command line's output: a reader that went away or a
/// failed write stops the printing, not the command ([`console`]).
macro_rules! outln {
    () => {
        $crate::cli::console::write(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::cli::console::write(format_args!("{}\n", format_args!($($arg)*)))
    };
}

/// `errln!`, the command line's `eprintln!` that never panics: a standard
/// error that cannot be written (`2>/dev/full`, a log on a full disk) loses
/// the line, never the command's exit status ([`console::write_err`]).
macro_rules! errln {
    () => {
        $crate::cli::console::write_err(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::cli::console::write_err(format_args!("{}\n", format_args!($($arg)*)))
    };
}

mod analyze;
mod campaign;
mod catalogue;
mod chirp;
mod config_cmd;
mod console;
mod control;
mod daemon_cmd;
mod design;
mod docs;
mod emulate;
mod export;
mod fit;
mod job_thread;
mod plot;
mod point;
mod recover;
mod serve;
mod track;
mod upload;

use analyze::{analyze, map, AnalyzeArgs, MapArgs};
use anyhow::Context;
use bench::config::{BenchConfig, ConfigError};
use bench::error::RunError;
use bench::jobs::request::RequestError;
use campaign::{campaign, CampaignCommand};
use catalogue::{catalogue, CatalogueArgs};
use chirp::{chirp, ChirpArgs};
use clap::{Parser, Subcommand};
use config_cmd::{config_command, ConfigCommand};
use control::{control, ControlArgs};
use daemon_cmd::{daemon, DaemonArgs};
use docs::{completions, man, CompletionsArgs, ManArgs};
use emulate::{emulate, EmulateCommand};
use export::{export, ExportArgs};
use fit::FitArgs;
use recover::{recover, RecoverArgs};
use serve::{serve, ServeArgs};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// Runs a precision flexure stage (SR4DoF) on a lab bench: chirp
/// identification in a real-time loop, recorded to MCAP. Without hardware it
/// runs the thesis' lumped model as a simulated plant.
#[derive(Debug, Parser)]
#[command(name = "bench", version, about, long_about = None, after_help = exit_statuses_help())]
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
    /// Track a periodic scan (triangle raster line or sine): feedback
    /// alone, then with the model-inverse feedforward, then learned trial
    /// by trial (ILC) until the error reaches the noise floor; one
    /// recording per trial, the learned feedforward as a table.
    Track(track::TrackArgs),
    /// Run the simulated plant as a DAQ device (serial over a
    /// pseudo-terminal, or SocketCAN), so the hardware backends can be
    /// exercised without hardware.
    #[command(subcommand)]
    Emulate(EmulateCommand),
    /// Own the bench: keep it safe between jobs and serve every job (chirp,
    /// control, fit, design, analyze, map, plot, campaign), one at a time,
    /// as JSON lines on a Unix socket.
    Serve(ServeArgs),
    /// Talk to a running `bench serve` without writing JSON: show its
    /// status, reset a latched fault, enable or disable the amplifier,
    /// stop the running job, shut the daemon down.
    Daemon(DaemonArgs),
    /// Turn the `.part` file of a killed or failed run into a complete,
    /// indexed recording (every completely written chunk, the metadata).
    Recover(RecoverArgs),
    /// Analyse the model of one bench: modes, modal residues and their
    /// signs, the sequence of dominant modes, the zeros typed MMP /
    /// RMP-RNMP / CMP-CNMP and Chapter 4's three-mode test; pole-zero and
    /// decomposed-mode plots.
    Analyze(AnalyzeArgs),
    /// Map where CMP-CNMP zeros appear over operating point × mass
    /// asymmetry (thesis Fig 2-5), with measured verdicts overlaid; or,
    /// with --veering, the closely spaced pair against operating point.
    Map(MapArgs),
    /// Run the thesis' Fig 5-10 experiment over a grid of operating point ×
    /// mass asymmetry: one chirp and one verdict per cell, on the
    /// simulator in parallel, journaled so a killed run resumes where it
    /// stopped; the measured map against the model's.
    #[command(subcommand)]
    Campaign(CampaignCommand),
    /// Fit the modes of a measured FRF (CSV or recording) automatically:
    /// frequency, damping ratio and signed modal constant of each mode with
    /// 1σ, residual terms, the sequence of dominant modes, the typed zeros
    /// and the CMP-CNMP verdict; measured vs fitted Bode PNG. With
    /// --update, the bench's physical parameters fitted to the FRF and
    /// written as TOML; with --frequencies, to measured natural frequencies
    Fit(FitArgs),
    /// Design a controller from measured FRFs (CSV, recordings, campaign
    /// directories): the thesis' slow or fast family, its crossover
    /// pushed as far as the margins allow on every input, written as a
    /// bench config with [controller.NAME]; report, figure and the step
    /// predicted on the model.
    Design(design::DesignArgs),
    /// Overlay several measured FRFs (CSVs, recordings, a campaign's
    /// cells) on one Bode or Nyquist figure, each fitted as `bench fit`
    /// fits it and labelled with its CMP-CNMP verdict, with the model and
    /// the zoom on the closely spaced pairs.
    #[command(subcommand)]
    Plot(plot::PlotCommand),
    /// Export a recording's channel as a CSV or Parquet table (one column
    /// per field, the unit in its name) for numpy and pandas.
    Export(ExportArgs),
    /// Rebuild the run catalogue (one Parquet row per run: when, where,
    /// which bench and operating point, how it ended, the fitted modes,
    /// margins and step figures) from a directory's recordings, as one
    /// compacted file for DuckDB or pandas.
    Catalogue(CatalogueArgs),
    /// Copy finished recordings, with their FRF CSVs, plots, summaries and
    /// catalogue rows, to an S3-compatible store or a directory; each
    /// object confirmed by its SHA-256 read back, none uploaded twice.
    Upload(upload::UploadArgs),
    /// The built-in bench description: print it as a commented TOML file
    /// to start from, or check a file.
    #[command(subcommand)]
    Config(ConfigCommand),
    /// Print the shell completion script for SHELL to stdout.
    Completions(CompletionsArgs),
    /// Print the man page (roff) to stdout, or write one page per command
    /// with --out DIR.
    Man(ManArgs),
}

/// Exit statuses: the codes of [`bench::error::EXIT_STATUSES`].
pub(super) use bench::error::exit as status;

/// `bench --help`'s list of the exit statuses, from
/// [`bench::error::EXIT_STATUSES`].
fn exit_statuses_help() -> String {
    let rows: Vec<String> = bench::error::EXIT_STATUSES
        .iter()
        .map(|s| {
            let who = if s.commands.is_empty() {
                String::new()
            } else {
                let names: Vec<String> = s.commands.iter().map(|c| format!("bench {c}")).collect();
                format!(" ({})", names.join(", "))
            };
            format!("  {:>3}  {}{who}", s.code, s.meaning)
        })
        .collect();
    format!("Exit status:\n{}", rows.join("\n"))
}

/// Logging to stderr, as the Rust ecosystem does it: the filter comes from
/// `RUST_LOG` (`BENCH_LOG` is kept as an alias; `RUST_LOG` wins), by
/// default `info` for `bench serve` (each job's start and end, with its
/// recording, goes to the journal) and `warn` for the other commands.
/// Colour codes only when stderr is a terminal and `NO_COLOR` is unset,
/// never into a file or a pipe.
fn init_logging(daemon: bool) {
    use std::io::IsTerminal;
    use tracing_subscriber::EnvFilter;
    let default = if daemon { "info" } else { "warn" };
    let filter = ["RUST_LOG", "BENCH_LOG"]
        .iter()
        .find_map(|v| std::env::var(v).ok().filter(|s| !s.trim().is_empty()))
        .map_or_else(
            || EnvFilter::new(default),
            |spec| {
                EnvFilter::try_new(&spec).unwrap_or_else(|e| {
                    errln!("warning: RUST_LOG={spec:?} is not a log filter ({e}); using {default}");
                    EnvFilter::new(default)
                })
            },
        );
    let ansi = std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none();
    // `log_internal_errors(false)`: a failed write to stderr is dropped;
    // with it, tracing reports the failure with `eprintln!`, which panics
    // on that same stderr.
    let format = tracing_subscriber::fmt::format()
        .with_ansi(ansi)
        .with_target(false);
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .log_internal_errors(false)
        .with_env_filter(filter)
        .with_ansi(ansi)
        .event_format(ExplainRefusals(format))
        .init();
}

/// The log's format, except for the `foxglove` crate's "Dropping client
/// ADDR: handshake failed", which says nothing of why: that line becomes
/// a warning that says which clients the live view serves
/// ([`bench::live::refusal_message`]).
struct ExplainRefusals<F>(F);

impl<S, N, F> tracing_subscriber::fmt::FormatEvent<S, N> for ExplainRefusals<F>
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
    N: for<'a> tracing_subscriber::fmt::FormatFields<'a> + 'static,
    F: tracing_subscriber::fmt::FormatEvent<S, N>,
{
    fn format_event(
        &self,
        ctx: &tracing_subscriber::fmt::FmtContext<'_, S, N>,
        mut w: tracing_subscriber::fmt::format::Writer<'_>,
        event: &tracing::Event<'_>,
    ) -> std::fmt::Result {
        use tracing_subscriber::fmt::time::FormatTime;
        let Some(addr) = bench::live::refused_handshake(event) else {
            return self.0.format_event(ctx, w, event);
        };
        // As the default format lays a line out: time, level, message.
        tracing_subscriber::fmt::time::SystemTime.format_time(&mut w)?;
        let level = if w.has_ansi_escapes() {
            "\x1b[33m WARN\x1b[0m"
        } else {
            " WARN"
        };
        writeln!(w, " {level} {}", bench::live::refusal_message(&addr))
    }
}

pub fn main() -> ExitCode {
    let cli = Cli::parse();
    init_logging(matches!(cli.command, Command::Serve(_)));
    let stop = Arc::new(AtomicBool::new(false));
    if let Err(e) = install_signal_handlers(&stop) {
        errln!("error: {e:#}");
        return ExitCode::from(status::ERROR);
    }
    let code = match cli.command {
        Command::Chirp(args) => chirp(args, stop),
        Command::Control(args) => control(args, stop),
        Command::Track(args) => track::track(args, stop),
        Command::Emulate(cmd) => emulate(cmd, stop),
        Command::Serve(args) => serve(args),
        Command::Daemon(args) => daemon(args),
        Command::Recover(args) => recover(args),
        Command::Analyze(args) => analyze(args),
        Command::Map(args) => map(args),
        Command::Campaign(cmd) => campaign(cmd, stop),
        Command::Export(args) => export(args),
        Command::Catalogue(args) => catalogue(args),
        Command::Upload(args) => upload::upload(args),
        Command::Fit(args) => fit::fit(args),
        Command::Design(args) => design::design(args),
        Command::Plot(cmd) => plot::plot(cmd),
        Command::Config(cmd) => config_command(cmd),
        Command::Completions(args) => completions(&args),
        Command::Man(args) => man(&args),
    };
    // Output that could not be written changes a success's status only.
    console::status(code == ExitCode::SUCCESS).map_or(code, ExitCode::from)
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

/// `--live [IP:PORT]`, shared by `chirp`, `control` and `serve`.
#[derive(Debug, clap::Args)]
pub(super) struct LiveArgs {
    /// Serve a live view of the run for Foxglove on IP:PORT (WebSocket,
    /// protocol foxglove.sdk.v1): every recorded channel as it is written.
    /// Without a value 127.0.0.1:8765, loopback only; another interface
    /// only when named (e.g. 0.0.0.0:8765). Port 0: the OS picks one
    /// (printed).
    #[arg(long, value_name = "IP:PORT", num_args = 0..=1, default_missing_value = bench::live::DEFAULT_ADDR)]
    live: Option<String>,
}

impl LiveArgs {
    /// Whether `--live` was given.
    pub(super) fn given(&self) -> bool {
        self.live.is_some()
    }

    /// Starts the live view when asked and says where on stderr; exit 2
    /// naming `--live` when the address is refused or cannot be served.
    /// `loop_cpu`: the CPU the real-time loop is pinned to (`loop.cpu`),
    /// which the server keeps off.
    pub(super) fn start(
        &self,
        loop_cpu: Option<usize>,
    ) -> Result<Option<bench::live::LiveServer>, ExitCode> {
        let Some(given) = &self.live else {
            return Ok(None);
        };
        let server = bench::live::parse_addr(given)
            .and_then(|a| bench::live::LiveServer::start(a, loop_cpu))
            .map_err(bad_input)?;
        errln!(
            "live view on {} (Foxglove: Open connection > Foxglove WebSocket)",
            server.url()
        );
        Ok(Some(server))
    }
}

/// `--pace FACTOR|off`, shared by `chirp` and `control`.
#[derive(Debug, clap::Args)]
pub(super) struct PaceArgs {
    /// Pace the simulator's virtual time against the wall clock: a factor
    /// of real time from 0.01 to 100 (1: real time, 0.1: ten times slower,
    /// 10: ten times faster), or off (as fast as it goes) [default: 1 with
    /// --live, else off]. The loop sleeps once per ~1 ms batch of ticks; a
    /// late batch is caught up, never a fault. Not with --realtime; the
    /// simulator only (hardware always runs in real time).
    #[arg(long, value_name = "FACTOR|off", allow_hyphen_values = true, value_parser = bench::jobs::request::parse_pace)]
    pace: Option<bench::jobs::request::Pace>,
}

impl PaceArgs {
    /// The pace as given.
    pub(super) fn given(&self) -> Option<bench::jobs::request::Pace> {
        self.pace
    }

    /// Exit 2 naming both flags when `--pace` comes with `--realtime`.
    pub(super) fn check_realtime(&self, realtime: bool) -> Result<(), ExitCode> {
        match self.pace {
            Some(p) if realtime => Err(bad_input(format!(
                "--pace {p} cannot be used with --realtime: --realtime runs the loop on absolute deadlines in real time (SCHED_FIFO), --pace paces the simulator's virtual time; give one of them"
            ))),
            _ => Ok(()),
        }
    }

    /// The pace of a local run (the factor, `None`: unpaced or real time)
    /// on `backend`: `--pace` as given; without it, 1 (real time) when a
    /// live view (`live`) watches a run in virtual time, said on stderr
    /// with how to run unpaced. Exit 2 naming `--pace` on hardware, which
    /// runs in real time.
    pub(super) fn local(
        &self,
        realtime: bool,
        live: bool,
        backend: &bench::rt::backend::BackendSpec,
    ) -> Result<Option<f64>, ExitCode> {
        match self.pace {
            Some(p) if !backend.is_sim() => Err(bad_input(format!(
                "--pace {p}: {}",
                bench::jobs::request::pace_on_hardware(&backend.to_string())
            ))),
            Some(p) => Ok(p.factor()),
            None if live && !realtime && backend.is_sim() => {
                errln!("{DEFAULT_LIVE_PACE_NOTE}");
                Ok(Some(1.0))
            }
            None => Ok(None),
        }
    }
}

/// What a run with `--live` in virtual time and no `--pace` says on
/// stderr.
pub(super) const DEFAULT_LIVE_PACE_NOTE: &str = "note: --live without --realtime: the simulator's virtual time is paced at 1× real time so the live view shows the run as it happens (--pace FACTOR for another pace, --pace off to run as fast as possible)";

pub(super) fn bad_input(msg: impl std::fmt::Display) -> ExitCode {
    errln!("error: {msg}");
    ExitCode::from(status::BAD_INPUT)
}

pub(super) use bench::outputs::default_recordings;

/// With `--daemon`: exit 2 for the first of `flags` (`(given, "--flag")`)
/// that only a local run takes, saying `why`.
pub(super) fn refuse_local_only(flags: &[(bool, &str)], why: &str) -> Option<ExitCode> {
    flags
        .iter()
        .find(|(given, _)| *given)
        .map(|(_, flag)| bad_input(format!("{flag}: not with --daemon ({why})")))
}

/// `path` as an absolute path (against the working directory), for a job
/// submitted to the daemon, which runs elsewhere; as given if the working
/// directory cannot be read (the daemon then names it).
pub(super) fn absolute_path(path: &Path) -> PathBuf {
    std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf())
}

/// The config of `--config FILE` (read with the file checks of
/// [`BenchConfig::load`]), else the built-in bench; with the name messages
/// and recordings give it (the file, or [`bench::config::BUILTIN_CONFIG_NAME`]).
pub(super) fn load_config(path: Option<&Path>) -> Result<(BenchConfig, PathBuf), ConfigError> {
    match path {
        Some(p) => Ok((BenchConfig::load(p)?, p.to_path_buf())),
        None => Ok((
            BenchConfig::builtin()?,
            PathBuf::from(bench::config::BUILTIN_CONFIG_NAME),
        )),
    }
}

/// The flags of every job command (`bench chirp`, `fit`, … `upload`):
/// how it answers and where it runs.
#[derive(Debug, clap::Args)]
pub(super) struct JobFlags {
    #[command(flatten)]
    pub(super) json: JsonFlag,
    /// Submit the job to a running `bench serve` instead of running it
    /// here [SOCKET default: $XDG_RUNTIME_DIR/bench.sock, else
    /// /run/bench/bench.sock]. The daemon reads the input files (their
    /// paths made absolute here) with its own permissions, runs a bench
    /// job (chirp, control) with the bench config and backend it was
    /// started with, and names every output in its recordings directory:
    /// the flags that name a local output are refused.
    #[arg(long, value_name = "SOCKET", num_args = 0..=1, default_missing_value = "")]
    pub(super) daemon: Option<String>,
}

/// `--json`, on every job command and on `bench campaign status` and
/// `map`: the summary as one JSON object.
#[derive(Debug, clap::Args)]
pub(super) struct JsonFlag {
    /// Print the summary as one JSON object on stdout (its fields: the
    /// book's reference, JSON outputs).
    #[arg(long)]
    pub(super) json: bool,
}

/// The output flags every job command that writes files shares.
#[derive(Debug, clap::Args)]
pub(super) struct OutputFlags {
    /// Replace existing output files (regular files only), each once its
    /// successor is complete. Without it an existing output is refused.
    #[arg(long)]
    pub(super) overwrite: bool,
}

/// `--config`, the bench description a command reads: one flag with one
/// short help on every command that takes it. A command whose use of the
/// file goes further (what it reads, another default) says so in its long
/// help (`#[command(mut_arg("config", |a| a.long_help(…)))]`).
#[derive(Debug, clap::Args)]
pub(super) struct ConfigFlag {
    /// Bench description (TOML) [default: the built-in Chapter 5 bench;
    /// `bench config default` prints it]
    #[arg(long, value_name = "FILE")]
    pub(super) config: Option<PathBuf>,
}

/// `--out`, where a job writes its main output: one flag on every job
/// command that has one. Each command names the output and its default in
/// its help (`#[command(mut_arg("out", |a| a.value_name(…).help(…)))]`);
/// with `--daemon` it is refused (the daemon names its outputs).
#[derive(Debug, clap::Args)]
pub(super) struct OutFlag {
    /// The job's main output [default: named by the job]
    #[arg(long, value_name = "FILE")]
    pub(super) out: Option<PathBuf>,
}

/// `--png`, where a job draws its figure: one flag on every job command
/// that draws one (`bench chirp`, `control`, `fit`, `design`, `map`). Each
/// command names the figure and its default in its help
/// (`#[command(mut_arg("png", |a| a.help(…)))]`); with `--daemon` it is
/// refused (the daemon names its outputs). `--plot`, the spelling `bench
/// chirp` and `bench control` had, is read as `--png`.
#[derive(Debug, clap::Args)]
pub(super) struct PngFlag {
    /// The figure [default: beside the main output]
    #[arg(long, value_name = "FILE.png|svg|pdf", alias = "plot")]
    pub(super) png: Option<PathBuf>,
}

/// The figure flags of a job whose one figure is optional (`bench fit`,
/// `design`): `--png` or `--no-plot`, never both.
#[derive(Debug, clap::Args)]
#[command(mut_arg("no_plot", |a| a.conflicts_with("png")))]
pub(super) struct FigureFlags {
    #[command(flatten)]
    pub(super) png: PngFlag,
    #[command(flatten)]
    pub(super) no_plot: NoPlotFlag,
}

/// `--no-plot`: write no figure, on every job whose figures are optional
/// (`bench fit`, `design`, `analyze`); it conflicts with the command's
/// figure paths (`#[command(mut_arg("no_plot", |a| a.conflicts_with(…)))]`).
/// `--no-plots`, the spelling `bench analyze` had, is read as `--no-plot`.
#[derive(Debug, clap::Args)]
pub(super) struct NoPlotFlag {
    /// Write no figure.
    #[arg(long, alias = "no-plots")]
    pub(super) no_plot: bool,
}

/// Prints a summary: one JSON object with `--json`, else the human form.
pub(super) fn emit<T: serde::Serialize + schemars::JsonSchema>(
    summary: &T,
    json: bool,
    human: fn(&T),
) -> Result<(), ExitCode> {
    if json {
        let s = serde_json::to_string(summary).map_err(|e| {
            errln!("error: {e}");
            ExitCode::from(status::ERROR)
        })?;
        outln!("{s}");
    } else {
        human(summary);
    }
    Ok(())
}

/// Prints a job's summary ([`emit`]) or its error ([`run_failed`]), and
/// returns the exit status.
pub(super) fn finish<T: serde::Serialize + schemars::JsonSchema>(
    result: Result<T, RunError>,
    json: bool,
    human: fn(&T),
) -> ExitCode {
    match result {
        Ok(summary) => match emit(&summary, json, human) {
            Ok(()) => ExitCode::SUCCESS,
            Err(code) => code,
        },
        Err(e) => run_failed(&e),
    }
}

/// Exit for a job request the config refuses, naming the flag when one set
/// the offending config key or request field (`flag`), else the file.
pub(super) fn refused_request(
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

/// The flag of a run option or request field (`RunError::BadOption`'s
/// key): `--` and the key with `-` for `_` (`frf_csv` → `--frf-csv`,
/// `operating_point_pct` → `--operating-point-pct`), but for
/// `frequencies_hz` (`--frequencies`), `labels` (`--label`), `plot`
/// (`--png`, the figure of `bench chirp` and `control`) and the
/// positional `input` (`""`: its value names it).
pub(super) fn option_flag(key: &str) -> String {
    match key {
        "input" | "inputs" => String::new(),
        // Positional arguments: bench export RECORDING, bench recover PART.
        "recording" => "RECORDING".into(),
        "part" => "PART".into(),
        "frequencies_hz" => "--frequencies".into(),
        "labels" => "--label".into(),
        // The figure of `bench chirp` and `control`.
        "plot" => "--png".into(),
        key => format!("--{}", key.replace('_', "-")),
    }
}

/// As [`run_failed`], and with `--json` the run's summary with the fault
/// ([`RunError::summary_json`]) on stdout first.
pub(super) fn run_failed_json(e: &RunError, json: bool) -> ExitCode {
    if json {
        if let Some(v) = bench::jobs::catalogue::ended_run_summary(e) {
            outln!("{v}");
        }
    }
    run_failed(e)
}

/// Prints a run's error (options by their flags) and returns its exit
/// status.
pub(super) fn run_failed(e: &RunError) -> ExitCode {
    match e {
        e @ RunError::BadOption { .. } => {
            errln!(
                "error: {}",
                e.option_message(option_flag).unwrap_or_default()
            );
        }
        e => errln!("error: {}", bench::error::error_chain(e)),
    }
    exit_for(e)
}

fn exit_for(e: &RunError) -> ExitCode {
    ExitCode::from(match e {
        RunError::BadInput(_) | RunError::BadOption { .. } | RunError::Refused(_) => {
            status::BAD_INPUT
        }
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
