//! `bench campaign`: run a grid of chirps (thesis Fig 5-10) on the
//! simulator, resumable after a crash; its status and its map.

use super::{bad_input, emit, status};
use bench::campaign::file::Campaign;
use bench::campaign::journal::Journal;
use bench::campaign::run::{
    create, damaged_cells, load_dir, run_attended, run_cells, summarize, write_results,
    CampaignRunError, CampaignSummary, CellBench, LineOperator, RunOptions,
};
use bench::rt::backend::BackendSpec;
use clap::{Args, Subcommand};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
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
}

#[derive(Debug, Args)]
pub(super) struct RunArgs {
    /// The campaign file (TOML; `bench-config/campaign-fig5-10.toml` is
    /// the thesis' grid).
    file: PathBuf,
    /// Campaign directory: must not exist or be empty [default: the
    /// file's `out`].
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    #[command(flatten)]
    how: HowArgs,
}

/// Where and how the cells run, for `run` and `resume`.
#[derive(Debug, Args)]
pub(super) struct HowArgs {
    /// Cells run at once on the simulator, 1 … 64 [default: the number of
    /// cores].
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
    /// Hardware: serial:PATH or socketcan:IFACE (else `[backend]` of the
    /// bench config). On hardware the cells run one at a time, each after
    /// the operator has made and confirmed the setup they are told.
    #[arg(long, value_name = "SPEC")]
    backend: Option<BackendSpec>,
    /// Run each cell as a chirp job of the running `bench serve` on
    /// SOCKET [default: $XDG_RUNTIME_DIR/bench.sock, else
    /// /run/bench/bench.sock]; the daemon's config and backend apply. The
    /// operator is asked before each cell as on hardware.
    #[arg(long, value_name = "SOCKET", num_args = 0..=1, default_missing_value = "", conflicts_with = "backend")]
    daemon: Option<String>,
    /// Print the summary as one JSON object on stdout.
    #[arg(long)]
    json: bool,
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
}

#[derive(Debug, Args)]
pub(super) struct DirArgs {
    /// The campaign directory.
    dir: PathBuf,
    /// Print the summary as one JSON object on stdout.
    #[arg(long)]
    json: bool,
}

/// Largest `--threads`.
const MAX_THREADS: usize = 64;

fn threads(given: Option<usize>) -> Result<usize, ExitCode> {
    match given {
        Some(n) if (1..=MAX_THREADS).contains(&n) => Ok(n),
        Some(n) => Err(bad_input(format!(
            "--threads {n}: must be 1 … {MAX_THREADS} (cells run at once)"
        ))),
        None => Ok(std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)),
    }
}

pub(super) fn campaign(cmd: CampaignCommand, stop: Arc<AtomicBool>) -> ExitCode {
    match cmd {
        CampaignCommand::Run(a) => run(a, stop),
        CampaignCommand::Resume(a) => resume(a, stop),
        CampaignCommand::Status(a) => status_cmd(a),
        CampaignCommand::Map(a) => map_cmd(a),
    }
}

fn run(a: RunArgs, stop: Arc<AtomicBool>) -> ExitCode {
    let threads = match threads(a.how.threads) {
        Ok(n) => n,
        Err(code) => return code,
    };
    let campaign = match Campaign::load(&a.file) {
        Ok(c) => c,
        Err(e) => return bad_input(e),
    };
    let Some(dir) = a.out.clone().or_else(|| campaign.spec.out.clone()) else {
        return bad_input(format!(
            "{}: no output directory: give --out DIR or `out = \"DIR\"` in the campaign file",
            a.file.display()
        ));
    };
    if let Err(e) = create(&campaign, &dir) {
        return failed(&e);
    }
    let (journal, read) = match Journal::open(&dir) {
        Ok(j) => j,
        Err(e) => return failed(&e.into()),
    };
    let bench = target(a.how.backend.as_ref(), a.how.daemon.as_deref(), &campaign);
    go(
        &campaign, &dir, journal, &read, threads, bench, stop, a.how.json,
    )
}

fn resume(a: ResumeArgs, stop: Arc<AtomicBool>) -> ExitCode {
    let threads = match threads(a.how.threads) {
        Ok(n) => n,
        Err(code) => return code,
    };
    let (campaign, _, note) = match load_dir(&a.dir, a.campaign.as_deref(), a.force) {
        Ok(x) => x,
        Err(e) => return failed(&e),
    };
    if let Some(n) = note {
        errln!("note: {n}");
    }
    let (mut journal, read) = match Journal::open(&a.dir) {
        Ok(j) => j,
        Err(e) => return failed(&e.into()),
    };
    if a.force {
        if let Err(e) = bench::campaign::run::adopt_changed(&a.dir, &mut journal, &campaign) {
            return failed(&e);
        }
    }
    let damaged = damaged_cells(&a.dir, &read);
    if !damaged.is_empty() {
        let list: Vec<String> = damaged
            .iter()
            .map(|(c, why)| format!("cell {c}: {why}"))
            .collect();
        return bad_input(format!(
            "{}: files of done cells are missing or changed ({}); the campaign's results would not be what it measured. Restore them, or start a new campaign",
            a.dir.display(),
            list.join("; ")
        ));
    }
    let bench = target(a.how.backend.as_ref(), a.how.daemon.as_deref(), &campaign);
    go(
        &campaign, &a.dir, journal, &read, threads, bench, stop, a.how.json,
    )
}

/// Where the cells run: the daemon, a hardware backend (flag or
/// `[backend]`), or the simulator.
fn target(backend: Option<&BackendSpec>, daemon: Option<&str>, campaign: &Campaign) -> CellBench {
    if let Some(sock) = daemon {
        return CellBench::Daemon(if sock.is_empty() {
            bench::daemon::default_socket_path()
        } else {
            PathBuf::from(sock)
        });
    }
    match BackendSpec::resolve(backend, &campaign.config) {
        BackendSpec::Sim => CellBench::Sim,
        spec => CellBench::Backend(spec),
    }
}

#[allow(clippy::too_many_arguments)]
fn go(
    campaign: &Campaign,
    dir: &Path,
    journal: Journal,
    read: &bench::campaign::journal::ReadJournal,
    threads: usize,
    bench: CellBench,
    stop: Arc<AtomicBool>,
    json: bool,
) -> ExitCode {
    if bench != CellBench::Sim {
        let on = match &bench {
            CellBench::Daemon(s) => format!("the daemon at {}", s.display()),
            CellBench::Backend(spec) => spec.to_string(),
            CellBench::Sim => unreachable!(),
        };
        // Instructions and answers on the terminal (stderr, so that
        // --json keeps stdout for the summary).
        let mut operator = LineOperator {
            input: std::io::stdin().lock(),
            out: std::io::stderr(),
        };
        errln!(
            "campaign {} on {on}: {} cells, one at a time; change the setup as told, then answer",
            dir.display(),
            campaign.cells().len() - read.done().len() - read.skipped().len()
        );
        return match run_attended(campaign, dir, journal, read, &bench, &mut operator, &stop) {
            Ok(s) => match emit(&s, json, print_summary) {
                Ok(()) => ExitCode::SUCCESS,
                Err(code) => code,
            },
            Err(e) => failed(&e),
        };
    }
    let total = campaign.cells().len();
    let bar = (std::io::stderr().is_terminal() && !json).then(|| {
        let b = indicatif::ProgressBar::new(total as u64);
        b.set_style(
            indicatif::ProgressStyle::with_template(
                "{bar:40} {pos}/{len} cells  {elapsed_precise} elapsed, ETA {eta_precise}",
            )
            .expect("a valid template"),
        );
        b.set_position(read.done().len() as u64);
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
    let result = run_cells(campaign, dir, journal, read, &opts);
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    match result {
        Ok(s) => match emit(&s, json, print_summary) {
            Ok(()) => ExitCode::SUCCESS,
            Err(code) => code,
        },
        Err(e) => failed(&e),
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
    match emit(&s, a.json, print_summary) {
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
        Ok(s) => match emit(&s, a.json, print_summary) {
            Ok(()) => ExitCode::SUCCESS,
            Err(code) => code,
        },
        Err(e) => failed(&e),
    }
}

fn failed(e: &CampaignRunError) -> ExitCode {
    errln!("error: {}", bench::error::error_chain(&e));
    ExitCode::from(match e {
        CampaignRunError::BadInput(_) => status::BAD_INPUT,
        CampaignRunError::Stopped { .. } => status::INTERRUPTED,
        _ => status::ERROR,
    })
}

fn print_summary(s: &CampaignSummary) {
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
