//! `bench campaign`: run a grid of chirps (thesis Fig 5-10) on the
//! simulator, resumable after a crash; its status and its map.

use super::serve::via_daemon;
use super::{emit, status};
use bench::campaign::file::{Campaign, Keep};
use bench::campaign::job::{self, Ready};
use bench::campaign::run::{
    damaged_cells, load_dir, summarize, write_results, CampaignRunError, CampaignSummary,
    CellBench, LineOperator, RunOptions,
};
use bench::jobs::request::{CampaignRequest, JobRequest};
use bench::rt::backend::BackendSpec;
use clap::{Args, Subcommand};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

#[derive(Debug, Subcommand)]
pub(super) enum CampaignCommand {
    /// Start a campaign: create its directory and run every cell.
    Run(RunArgs),
    /// Go on with a campaign whose run was stopped or killed: from the
    /// first unfinished cell, never running a done cell again.
    Resume(ResumeArgs),
    /// What a campaign directory holds: cells done, pending, skipped,
    /// verdicts against the model, damaged files.
    Status(DirArgs),
    /// Write the campaign's cells.csv and its map (measured verdicts on
    /// the model's CNMP map, thesis Fig 5-10) again from its journal.
    Map(DirArgs),
    /// Print the built-in campaign file (the thesis' Fig 5-10 grid on the
    /// built-in bench; `bench campaign run` without a file runs it).
    Default,
}

#[derive(Debug, Args)]
#[command(
    mut_arg("out", |a| a.value_name("DIR").help("Campaign directory: must not exist or be empty [default: the file's `out`]")),
    mut_arg("daemon", |a| a
        .long_help("Run the whole campaign as one job of a running `bench serve`, as --daemon runs any job [SOCKET default: $XDG_RUNTIME_DIR/bench.sock, else /run/bench/bench.sock]: the daemon reads the campaign file and runs the cells on the simulator, in parallel, in a new directory of its recordings (as `run` without --backend here). No cell runs on the daemon's bench (that is --cells-on-daemon)")
        .conflicts_with_all(["out", "backend", "cells_on_daemon"])),
)]
pub(super) struct RunArgs {
    /// The campaign file (TOML) [default: the built-in campaign, the
    /// thesis' Fig 5-10 grid on the built-in bench; `bench campaign
    /// default` prints it].
    file: Option<PathBuf>,
    /// What each cell keeps: recording (everything: recording, FRF CSV,
    /// Bode plot, summary; 5.8 MB a default cell), frf (the FRF CSV and
    /// the summary, ~100 kB) or summary (~6.5 kB); each cell also writes
    /// its 9 kB catalogue row [default: the campaign
    /// file's `keep`, else recording]. Recorded in the campaign's copy of
    /// the file, so a resume keeps the same.
    #[arg(long, value_name = "WHAT", value_parser = parse_keep)]
    keep: Option<Keep>,
    #[command(flatten)]
    out: super::OutFlag,
    #[command(flatten)]
    how: HowArgs,
    #[command(flatten)]
    job: super::JobFlags,
    /// The old spelling of --daemon: refused, naming it.
    #[arg(long, hide = true, value_name = "SOCKET", num_args = 0..=1, default_missing_value = "")]
    submit: Option<String>,
}

/// Where and how the cells run, for `run` and `resume`.
#[derive(Debug, Args)]
pub(super) struct HowArgs {
    /// Cells run at once on the simulator, 1 … 64 [default: the number of
    /// cores].
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
    /// Hardware: serial:PATH, socketcan:IFACE or ethercat:IFACE (else `[backend]` of the
    /// bench config). On hardware the cells run one at a time, each after
    /// the operator has made and confirmed the setup they are told.
    #[arg(long, value_name = "SPEC")]
    backend: Option<BackendSpec>,
    /// Run each cell as a chirp job of the running `bench serve` on
    /// SOCKET, on the daemon's bench [default: $XDG_RUNTIME_DIR/bench.sock,
    /// else /run/bench/bench.sock]; the daemon's config and backend apply.
    /// The operator is asked before each cell as on hardware.
    #[arg(long, value_name = "SOCKET", num_args = 0..=1, default_missing_value = "", conflicts_with = "backend")]
    cells_on_daemon: Option<String>,
    /// At the end, design one controller over every done cell's FRF
    /// (`bench design DIR --strategy STRATEGY`): DIR/designed.toml and
    /// DIR/designed.png, the report in the summary.
    #[arg(long, value_name = "STRATEGY", value_parser = ["slow", "fast", "limit", "auto"])]
    design: Option<String>,
}

#[derive(Debug, Args)]
pub(super) struct ResumeArgs {
    /// The campaign directory.
    dir: PathBuf,
    /// Go on with this campaign file instead of the directory's copy
    /// (refused if it differs from what the campaign started with, unless
    /// --force).
    #[arg(long, value_name = "FILE")]
    campaign: Option<PathBuf>,
    /// Go on although the campaign file or bench config changed; done
    /// cells at the same operating point and asymmetry are kept.
    #[arg(long)]
    force: bool,
    #[command(flatten)]
    how: HowArgs,
    #[command(flatten)]
    json: super::JsonFlag,
}

#[derive(Debug, Args)]
pub(super) struct DirArgs {
    /// The campaign directory.
    dir: PathBuf,
    #[command(flatten)]
    json: super::JsonFlag,
}

pub(super) fn campaign(cmd: CampaignCommand, stop: Arc<AtomicBool>) -> ExitCode {
    match cmd {
        CampaignCommand::Run(a) => run(a, stop),
        CampaignCommand::Resume(a) => resume(a, stop),
        CampaignCommand::Status(a) => status_cmd(a),
        CampaignCommand::Map(a) => map_cmd(a),
        CampaignCommand::Default => {
            print!("{}", bench::campaign::file::BUILTIN_CAMPAIGN_TOML);
            ExitCode::SUCCESS
        }
    }
}

fn parse_keep(s: &str) -> Result<Keep, String> {
    s.parse()
}

fn run(a: RunArgs, stop: Arc<AtomicBool>) -> ExitCode {
    if a.submit.is_some() {
        return super::bad_input(
            "--submit is now --daemon: `bench campaign run --daemon [SOCKET]` runs the whole campaign as one job of the daemon, as --daemon runs every command's job (each cell as a job of the daemon's bench: --cells-on-daemon [SOCKET])"
                .to_string(),
        );
    }
    if let Some(sock) = &a.job.daemon {
        let request = CampaignRequest {
            file: a.file.as_deref().map(super::absolute_path),
            threads: a.how.threads,
            keep: a.keep.map(|k| k.name().to_string()),
            design: a.how.design.as_deref().and_then(|s| s.parse().ok()),
        };
        return via_daemon(
            sock,
            &JobRequest::Campaign(request),
            a.job.json.json,
            print_summary,
        );
    }
    let threads = match job::threads(a.how.threads) {
        Ok(n) => n,
        Err(e) => return failed(&e),
    };
    let campaign = match job::prepare(a.file.as_deref(), a.keep, a.how.design.is_some()) {
        Ok(c) => c,
        Err(e) => return failed(&e),
    };
    let bench = target(
        a.how.backend.as_ref(),
        a.how.cells_on_daemon.as_deref(),
        &campaign,
    );
    match job::start(campaign, a.out.out.as_deref(), threads) {
        Ok(ready) => go(
            ready,
            threads,
            bench,
            stop,
            a.job.json.json,
            a.how.design.as_deref(),
        ),
        Err(e) => failed(&e),
    }
}

fn resume(a: ResumeArgs, stop: Arc<AtomicBool>) -> ExitCode {
    let threads = match job::threads(a.how.threads) {
        Ok(n) => n,
        Err(e) => return failed(&e),
    };
    let ready = match job::resume(&a.dir, a.campaign.as_deref(), a.force, threads) {
        Ok(r) => r,
        Err(e) => return failed(&e),
    };
    if let Some(n) = &ready.note {
        errln!("note: {n}");
    }
    let bench = target(
        a.how.backend.as_ref(),
        a.how.cells_on_daemon.as_deref(),
        &ready.campaign,
    );
    go(
        ready,
        threads,
        bench,
        stop,
        a.json.json,
        a.how.design.as_deref(),
    )
}

/// Where the cells run: the daemon, a hardware backend (flag or
/// `[backend]`), or the simulator.
fn target(backend: Option<&BackendSpec>, daemon: Option<&str>, campaign: &Campaign) -> CellBench {
    if let Some(sock) = daemon {
        let socket = if sock.is_empty() {
            bench::daemon::default_socket_path()
        } else {
            PathBuf::from(sock)
        };
        return CellBench::Daemon(socket, |socket, job| {
            bench::daemon::client::submit(socket, job, |_| {}).map_err(|e| e.to_string())
        });
    }
    match BackendSpec::resolve(backend, &campaign.config) {
        BackendSpec::Sim => CellBench::Sim,
        spec => CellBench::Backend(spec),
    }
}

/// Runs a ready campaign: attended on hardware or the daemon (the
/// operator on the terminal), else on the simulator with a progress bar.
fn go(
    ready: Ready,
    threads: usize,
    bench: CellBench,
    stop: Arc<AtomicBool>,
    json: bool,
    design: Option<&str>,
) -> ExitCode {
    // Before anything runs: what the cells will take, and what is left.
    errln!("{}", ready.disk.describe());
    let on = match &bench {
        CellBench::Sim => None,
        CellBench::Daemon(s, _) => Some(format!("the daemon at {}", s.display())),
        CellBench::Backend(spec) => Some(spec.to_string()),
    };
    if let Some(on) = on {
        // Instructions and answers on the terminal (stderr, so that
        // --json keeps stdout for the summary).
        let mut operator = LineOperator {
            input: std::io::stdin().lock(),
            out: std::io::stderr(),
        };
        errln!(
            "campaign {} on {on}: {} cells, one at a time; change the setup as told, then answer",
            ready.dir.display(),
            ready.to_run()
        );
        return match ready.run_attended(&bench, &mut operator, &stop) {
            Ok(s) => finish_with_design(s, design, json),
            Err(e) => failed(&e),
        };
    }
    let bar = (std::io::stderr().is_terminal() && !json).then(|| {
        let b = indicatif::ProgressBar::new(ready.cells() as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template(
                "{bar:40} {pos}/{len} cells  {elapsed_precise} elapsed, ETA {eta_precise}",
            )
            .expect("a valid template"),
        );
        b.set_position(ready.done() as u64);
        b
    });
    let on_cell = |n: usize, _total: usize| {
        if let Some(b) = &bar {
            b.set_position(n as u64);
        }
    };
    let opts = RunOptions {
        threads,
        stop,
        on_cell: Some(&on_cell),
    };
    let result = ready.run_parallel(&opts);
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    match result {
        Ok(s) => finish_with_design(s, design, json),
        Err(e) => failed(&e),
    }
}

/// The summary of a finished run, with the design over its cells when
/// `--design` asked for one. A design the margins refuse is reported after
/// the campaign's summary (exit 2); the campaign's results stay.
fn finish_with_design(s: CampaignSummary, design: Option<&str>, json: bool) -> ExitCode {
    let Some(strategy) = design.and_then(|d| d.parse::<bench::design::Strategy>().ok()) else {
        return match emit(&s, json, print_summary) {
            Ok(()) => ExitCode::SUCCESS,
            Err(code) => code,
        };
    };
    match bench::campaign::job::design_over(&s.dir, strategy) {
        Ok(d) => {
            let s = CampaignSummary {
                design: Some(Box::new(d)),
                ..s
            };
            match emit(&s, json, print_summary) {
                Ok(()) => ExitCode::SUCCESS,
                Err(code) => code,
            }
        }
        Err(e) => {
            let _ = emit(&s, json, print_summary);
            super::run_failed(&e)
        }
    }
}

fn status_cmd(a: DirArgs) -> ExitCode {
    let (campaign, read, note) = match load_dir(&a.dir, None, true) {
        Ok(x) => x,
        Err(e) => return failed(&e),
    };
    if let Some(n) = note {
        errln!("note: {n}");
    }
    let s = match summarize(&campaign, &a.dir, &read) {
        Ok(s) => s,
        Err(e) => return failed(&e),
    };
    for (c, why) in damaged_cells(&a.dir, &read) {
        errln!("warning: cell {c}: {why}");
    }
    match emit(&s, a.json.json, print_summary) {
        Ok(()) => ExitCode::SUCCESS,
        Err(code) => code,
    }
}

fn map_cmd(a: DirArgs) -> ExitCode {
    let (campaign, _, _) = match load_dir(&a.dir, None, true) {
        Ok(x) => x,
        Err(e) => return failed(&e),
    };
    match write_results(&campaign, &a.dir) {
        Ok(s) => match emit(&s, a.json.json, print_summary) {
            Ok(()) => ExitCode::SUCCESS,
            Err(code) => code,
        },
        Err(e) => failed(&e),
    }
}

fn failed(e: &CampaignRunError) -> ExitCode {
    match e {
        // An option by its flag.
        CampaignRunError::BadOption { key, value, reason } if value.is_empty() => {
            errln!("error: {}: {reason}", super::option_flag(key));
        }
        CampaignRunError::BadOption { key, value, reason } => {
            errln!("error: {} {value}: {reason}", super::option_flag(key));
        }
        e => errln!("error: {}", bench::error::error_chain(e)),
    }
    ExitCode::from(match e {
        CampaignRunError::BadInput(_) | CampaignRunError::BadOption { .. } => status::BAD_INPUT,
        CampaignRunError::Stopped { .. } => status::INTERRUPTED,
        _ => status::ERROR,
    })
}

fn print_summary(s: &CampaignSummary) {
    print_campaign(s);
    if let Some(d) = &s.design {
        outln!();
        super::design::print_summary(d);
    }
}

fn print_campaign(s: &CampaignSummary) {
    outln!("campaign {}", s.dir.display());
    outln!(
        "  cells: {} done, {} pending, {} skipped of {}",
        s.done,
        s.pending,
        s.skipped,
        s.cells
    );
    outln!(
        "  verdicts: {} decided, {} undecided; {} agree with the model, {} disagree",
        s.decided,
        s.done - s.decided,
        s.agree,
        s.disagreements.len()
    );
    if !s.disagreements.is_empty() {
        outln!("  cells where measurement and model disagree:");
        outln!("    cell  operating point   asymmetry  measured  model");
        for d in &s.disagreements {
            outln!(
                "    {:>4}  {:>9.3} mm      {:>+7.1} %  {:>8}  {}",
                d.index,
                d.operating_point_m * 1e3,
                d.mass_asymmetry * 100.0,
                if d.verdict == Some(true) {
                    "CMP-CNMP"
                } else {
                    "none"
                },
                if d.model_cnmp { "CMP-CNMP" } else { "none" }
            );
        }
    }
    let undecided: Vec<_> = s
        .results
        .iter()
        .filter(|r| r.status == "done" && r.verdict.is_none())
        .collect();
    if !undecided.is_empty() {
        outln!("  undecided cells:");
        for r in undecided {
            outln!(
                "    {:>4}  {:>9.3} mm  {:>+7.1} %  {}",
                r.index,
                r.operating_point_m * 1e3,
                r.mass_asymmetry * 100.0,
                r.reason.as_deref().unwrap_or("")
            );
        }
    }
    outln!("  cells.csv: {}", s.cells_csv.display());
    if let Some(p) = &s.map_png {
        outln!("  map: {}", p.display());
    }
}
