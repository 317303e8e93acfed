//! Running a campaign on the simulator: the campaign directory, the cells
//! in parallel, the journal after each cell, resuming, and the results
//! (`cells.csv`, the map, the agreement with the model).
//!
//! # The campaign directory
//!
//! ```text
//! DIR/campaign.toml        the campaign file as it was at `run` (verbatim)
//! DIR/bench.toml           the bench config as it was at `run` (verbatim)
//! DIR/origin.json          where the two came from (absolute paths)
//! DIR/journal.jsonl        the journal (see `journal`)
//! DIR/cells/NNN/           one directory per cell (NNN = cell index):
//!     chirp.mcap, frf.csv, bode.png, summary.json
//! DIR/cells.csv            one row per cell (written after every run)
//! DIR/map.png              measured verdicts on the model's map
//! DIR/summary.json         the campaign summary
//! ```
//!
//! A cell is done when its `done` journal entry is durable: that entry is
//! appended only after the cell's four files are complete and synced, and
//! carries their SHA-256 checksums. A cell directory without one is
//! removed and the cell run again from scratch.

use super::file::{changed_keys, Campaign, Cell, Keep};
use super::journal::{self, file_sum, sha256_hex, Entry, Journal, JournalError, ReadJournal};
use crate::analysis::map::{agreement, cnmp_map, linspace, model_at, MapCell};
use crate::analysis::modal::model_cnmp_damped;
use crate::jobs::chirp::{chirp_outputs, run_chirp, ChirpOptions, ChirpSummary};
use crate::jobs::request::JobRequest;
use crate::outputs::{write_atomically, Existing};
use crate::plot::{write_map_png, MeasuredPoint};
use crate::rt::backend::BackendSpec;
use serde::{Deserialize, Serialize};
use std::fs::{self, File};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

/// The copy of the campaign file in a campaign directory.
pub const CAMPAIGN_COPY: &str = "campaign.toml";
/// The copy of the bench config in a campaign directory.
pub const CONFIG_COPY: &str = "bench.toml";
/// Where the copies came from.
pub const ORIGIN_FILE: &str = "origin.json";
/// Per-cell results.
pub const CELLS_CSV: &str = "cells.csv";
/// The map.
pub const MAP_PNG: &str = "map.png";
/// The campaign summary.
pub const SUMMARY_JSON: &str = "summary.json";

/// Errors of a campaign run.
#[derive(Debug, thiserror::Error)]
pub enum CampaignRunError {
    /// Bad input (exit 2): the message names the argument or file.
    #[error("{0}")]
    BadInput(String),
    /// An option that cannot be used (exit 2): `key` as the job's options
    /// and requests spell it (`out`, `threads`); the CLI shows its flag.
    #[error("{key}{}: {reason}", if value.is_empty() { String::new() } else { format!(" {value}") })]
    BadOption {
        /// The option.
        key: &'static str,
        /// Its value as given (a path, a number), or empty.
        value: String,
        /// Why it is refused.
        reason: String,
    },
    /// The journal failed.
    #[error(transparent)]
    Journal(#[from] JournalError),
    /// An output could not be written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// The OS error.
        source: io::Error,
    },
    /// A cell's run failed (not a verdict: the chirp itself).
    #[error("cell {cell} ({operating_point_m} m, Δm23 = {mass_asymmetry}): {reason}")]
    Cell {
        /// Cell index.
        cell: usize,
        /// Operating point, m.
        operating_point_m: f64,
        /// Mass asymmetry.
        mass_asymmetry: f64,
        /// What failed.
        reason: String,
    },
    /// Stopped by SIGINT/SIGTERM; every completed cell is in the journal.
    #[error("stopped after {done} of {cells} cells; `bench campaign resume {}` goes on", dir.display())]
    Stopped {
        /// The campaign directory.
        dir: PathBuf,
        /// Cells done.
        done: usize,
        /// Cells in all.
        cells: usize,
    },
}

fn io_at(path: &Path) -> impl FnOnce(io::Error) -> CampaignRunError + '_ {
    move |source| CampaignRunError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Where a campaign's files came from (`origin.json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Origin {
    /// The campaign file given to `run`, absolute.
    pub campaign_file: PathBuf,
    /// The bench config it named, absolute.
    pub config_file: PathBuf,
}

/// One row of `cells.csv` and of the summary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CellResult {
    /// Cell index (row-major, asymmetry slowest).
    pub index: usize,
    /// Operating point Y1o, m.
    pub operating_point_m: f64,
    /// Mass asymmetry Δm23 of the grid.
    pub mass_asymmetry: f64,
    /// The asymmetry set with whole trim masses, where it differs from the
    /// grid's (hardware); the model's verdict is taken there.
    pub achieved_mass_asymmetry: Option<f64>,
    /// `done`, `skipped` or `pending`.
    pub status: String,
    /// Measured verdict (`None`: undecided or not run).
    pub verdict: Option<bool>,
    /// Why undecided, or why the two measured tests disagree.
    pub reason: Option<String>,
    /// The damped model's verdict at this cell (CMP-CNMP zeros).
    pub model_cnmp: bool,
    /// Simulator seed.
    pub seed: u64,
    /// The cell's directory, relative to the campaign directory.
    pub dir: String,
}

/// The campaign summary (`summary.json`, `--json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CampaignSummary {
    /// The campaign directory, absolute.
    pub dir: PathBuf,
    /// Cells in the grid.
    pub cells: usize,
    /// Cells done.
    pub done: usize,
    /// Cells skipped by the operator.
    pub skipped: usize,
    /// Cells not yet run.
    pub pending: usize,
    /// Done cells with a verdict.
    pub decided: usize,
    /// Decided cells whose verdict equals the model's.
    pub agree: usize,
    /// Decided cells whose verdict differs from the model's.
    pub disagreements: Vec<CellResult>,
    /// Every cell.
    pub results: Vec<CellResult>,
    /// `cells.csv`, absolute.
    pub cells_csv: PathBuf,
    /// The map PNG, absolute (absent until a cell is done).
    pub map_png: Option<PathBuf>,
    /// The controller designed over every done cell (`--design`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub design: Option<Box<crate::jobs::design::DesignSummary>>,
}

/// The directory of cell `index`, relative to the campaign directory.
pub fn cell_dir(index: usize) -> String {
    format!("cells/{index:03}")
}

/// The files of a done cell, relative to its directory.
pub const CELL_FILES: [&str; 4] = ["chirp.mcap", "frf.csv", "bode.png", "summary.json"];

/// Checks that `dir` can hold a new campaign: it does not exist (its
/// parent is writable) or is an empty directory.
///
/// # Errors
/// [`CampaignRunError::BadOption`] naming `out`, the directory and the
/// reason.
pub fn check_new_dir(dir: &Path) -> Result<(), CampaignRunError> {
    let bad = |reason: String| CampaignRunError::BadOption {
        key: "out",
        value: dir.display().to_string(),
        reason,
    };
    match fs::symlink_metadata(dir) {
        Ok(m) if !m.is_dir() => Err(bad("exists and is not a directory".into())),
        Ok(_) => match fs::read_dir(dir) {
            Ok(mut it) => {
                if it.next().is_some() {
                    Err(bad(
                        "is not empty: a campaign never overwrites (use `bench campaign resume` for a campaign directory)"
                            .into(),
                    ))
                } else {
                    Ok(())
                }
            }
            Err(e) => Err(bad(format!("cannot be read: {e}"))),
        },
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            let parent = dir
                .parent()
                .filter(|p| !p.as_os_str().is_empty())
                .unwrap_or(Path::new("."));
            if !parent.is_dir() {
                return Err(bad(format!(
                    "its parent {} is not a directory",
                    parent.display()
                )));
            }
            // SAFETY-free probe: access(2) on the parent for write + search.
            let c = std::ffi::CString::new(parent.as_os_str().as_encoded_bytes())
                .map_err(|_| bad("the path holds a NUL byte".into()))?;
            // SAFETY: `c` is a valid NUL-terminated path for the call.
            if unsafe { libc::access(c.as_ptr(), libc::W_OK | libc::X_OK) } != 0 {
                return Err(bad(format!(
                    "its parent {} is not writable: {}",
                    parent.display(),
                    io::Error::last_os_error()
                )));
            }
            Ok(())
        }
        Err(e) => Err(bad(e.to_string())),
    }
}

/// Creates campaign directory `dir` for `campaign`: the copies, the
/// origin, and the journal with its header. `dir` must pass
/// [`check_new_dir`].
///
/// # Errors
/// [`CampaignRunError`] if anything cannot be written (nothing is left
/// looking like a campaign then: the journal is written last).
pub fn create(campaign: &Campaign, dir: &Path) -> Result<(), CampaignRunError> {
    check_new_dir(dir)?;
    fs::create_dir_all(dir).map_err(io_at(dir))?;
    let put = |name: &str, text: &str| {
        let p = dir.join(name);
        write_atomically(&p, Existing::Refuse, |f| f.write_all(text.as_bytes())).map_err(io_at(&p))
    };
    put(CAMPAIGN_COPY, &campaign.text)?;
    put(CONFIG_COPY, &campaign.config_text)?;
    // A built-in text is named as such, not as a file here.
    let abs = |p: &Path| {
        if p == Path::new(super::file::BUILTIN_CAMPAIGN_NAME)
            || p == Path::new(crate::config::BUILTIN_CONFIG_NAME)
        {
            return p.to_path_buf();
        }
        std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf())
    };
    let origin = Origin {
        campaign_file: abs(&campaign.path),
        config_file: abs(&campaign.config_path),
    };
    put(
        ORIGIN_FILE,
        &(serde_json::to_string_pretty(&origin).expect("origin serialises") + "\n"),
    )?;
    Journal::create(dir, &header_of(campaign))?;
    Ok(())
}

/// The journal header of `campaign`: its texts and their hashes.
fn header_of(campaign: &Campaign) -> Entry {
    Entry::Header {
        version: journal::JOURNAL_VERSION,
        campaign_sha256: sha256_hex(campaign.text.as_bytes()),
        config_sha256: sha256_hex(campaign.config_text.as_bytes()),
        campaign_text: campaign.text.clone(),
        config_text: campaign.config_text.clone(),
        cells: campaign.cells().len(),
        created_utc: now_utc(),
    }
}

fn now_utc() -> String {
    time::OffsetDateTime::now_utc()
        .format(&time::format_description::well_known::Rfc3339)
        .unwrap_or_default()
}

/// What the journal says the campaign is now: the header's hashes and
/// texts, or those of the last `--force` resume.
struct Current {
    campaign_sha256: String,
    config_sha256: String,
    campaign_text: String,
    config_text: String,
}

fn current(j: &ReadJournal) -> Current {
    let mut out = Current {
        campaign_sha256: String::new(),
        config_sha256: String::new(),
        campaign_text: String::new(),
        config_text: String::new(),
    };
    for e in &j.entries {
        if let Entry::Header {
            campaign_sha256,
            config_sha256,
            campaign_text,
            config_text,
            ..
        } = e
        {
            out = Current {
                campaign_sha256: campaign_sha256.clone(),
                config_sha256: config_sha256.clone(),
                campaign_text: campaign_text.clone(),
                config_text: config_text.clone(),
            };
        }
    }
    out
}

/// Loads the campaign of directory `dir` for `resume` / `status` / `map`:
/// from the copies in `dir`, or from `campaign_file` if given. The hashes
/// must match the journal's unless `force`; a mismatch names the keys that
/// changed. Also returns a note when the original files have changed since
/// `run` (they are not used then).
///
/// # Errors
/// [`CampaignRunError::BadInput`]: not a campaign directory, a hash
/// mismatch without `force`, or an unusable campaign file.
pub fn load_dir(
    dir: &Path,
    campaign_file: Option<&Path>,
    force: bool,
) -> Result<(Campaign, ReadJournal, Option<String>), CampaignRunError> {
    let not_campaign = |why: String| {
        CampaignRunError::BadInput(format!(
            "{}: not a bench campaign directory ({why})",
            dir.display()
        ))
    };
    if !dir.is_dir() {
        return Err(not_campaign("not a directory".into()));
    }
    let j = journal::read(dir).map_err(|e| not_campaign(e.to_string()))?;
    let copy = dir.join(CAMPAIGN_COPY);
    let copy_text =
        fs::read_to_string(&copy).map_err(|e| not_campaign(format!("{}: {e}", copy.display())))?;
    let config_copy = dir.join(CONFIG_COPY);
    let config_copy_text = fs::read_to_string(&config_copy)
        .map_err(|e| not_campaign(format!("{}: {e}", config_copy.display())))?;
    let was = current(&j);
    let campaign = match campaign_file {
        Some(p) => Campaign::load(p).map_err(|e| CampaignRunError::BadInput(e.to_string()))?,
        None => Campaign::from_text_with_config(&copy, copy_text.clone(), Some(&config_copy))
            .map_err(|e| CampaignRunError::BadInput(e.to_string()))?,
    };
    let mut changed = Vec::new();
    if sha256_hex(campaign.text.as_bytes()) != was.campaign_sha256 {
        changed.extend(
            changed_keys(&was.campaign_text, &campaign.text)
                .into_iter()
                .map(|k| format!("campaign {k}")),
        );
        if changed.is_empty() {
            changed.push("campaign file (comments or layout)".into());
        }
    }
    if sha256_hex(campaign.config_text.as_bytes()) != was.config_sha256 {
        let keys = changed_keys(&was.config_text, &campaign.config_text);
        if keys.is_empty() {
            changed.push("bench config (comments or layout)".into());
        }
        changed.extend(keys.into_iter().map(|k| format!("config {k}")));
    }
    if !changed.is_empty() && !force {
        return Err(CampaignRunError::BadInput(format!(
            "{}: the campaign changed since it was started ({}); resuming would mix two experiments. Pass --force to go on with the changed files (done cells at the same operating point and asymmetry are kept)",
            dir.display(),
            changed.join(", ")
        )));
    }
    // Say so when the originals changed but the copies are used.
    let mut note = None;
    if campaign_file.is_none() {
        if let Ok(text) = fs::read_to_string(dir.join(ORIGIN_FILE)) {
            if let Ok(origin) = serde_json::from_str::<Origin>(&text) {
                let differs = |p: &Path, was: &str| {
                    fs::read_to_string(p).map(|now| now != was).unwrap_or(false)
                };
                let mut which = Vec::new();
                if differs(&origin.campaign_file, &copy_text) {
                    which.push(origin.campaign_file.display().to_string());
                }
                if differs(&origin.config_file, &config_copy_text) {
                    which.push(origin.config_file.display().to_string());
                }
                if !which.is_empty() {
                    note = Some(format!(
                        "{} changed since the campaign started; it goes on with its copies in {} (pass --campaign FILE --force to use the changed files)",
                        which.join(" and "),
                        dir.display()
                    ));
                }
            }
        }
    }
    Ok((campaign, j, note))
}

/// Records in the journal (and the copies) that a forced resume goes on
/// with changed files.
///
/// # Errors
/// [`CampaignRunError`] on a write failure.
pub fn adopt_changed(
    dir: &Path,
    journal: &mut Journal,
    campaign: &Campaign,
) -> Result<(), CampaignRunError> {
    for (name, text) in [
        (CAMPAIGN_COPY, &campaign.text),
        (CONFIG_COPY, &campaign.config_text),
    ] {
        let p = dir.join(name);
        write_atomically(&p, Existing::Replace, |f| f.write_all(text.as_bytes()))
            .map_err(io_at(&p))?;
    }
    journal.append(&header_of(campaign))?;
    Ok(())
}

/// The done entry of `cell` in `j`, if one matches its coordinates.
fn done_entry<'a>(j: &'a ReadJournal, cell: &Cell) -> Option<&'a Entry> {
    j.done().get(&cell.index).copied().filter(|e| {
        matches!(e, Entry::Done { operating_point_m, mass_asymmetry, .. }
            if *operating_point_m == cell.operating_point_m && *mass_asymmetry == cell.mass_asymmetry)
    })
}

/// Options of [`run_cells`].
pub struct RunOptions<'a> {
    /// Worker threads (cells at once), ≥ 1.
    pub threads: usize,
    /// Raised by SIGINT/SIGTERM: the cells running finish or stop, none
    /// is started after.
    pub stop: Arc<AtomicBool>,
    /// Called after each cell with (cells done, cells in all).
    pub on_cell: Option<&'a (dyn Fn(usize, usize) + Sync)>,
}

/// Runs every cell of `campaign` not yet done in `dir` (created with
/// [`create`]) on the simulator, `opts.threads` at a time, journaling each,
/// then writes the results.
///
/// # Errors
/// [`CampaignRunError`]: a cell that failed (the others that completed are
/// kept), a journal or output failure, or a stop.
pub fn run_cells(
    campaign: &Campaign,
    dir: &Path,
    journal: Journal,
    already: &ReadJournal,
    opts: &RunOptions<'_>,
) -> Result<CampaignSummary, CampaignRunError> {
    let cells = campaign.cells();
    let skipped = already.skipped();
    let todo: Vec<Cell> = campaign
        .serpentine()
        .into_iter()
        .filter(|c| done_entry(already, c).is_none() && !skipped.contains(&c.index))
        .collect();
    let total = cells.len();
    let done_count = AtomicUsize::new(total - todo.len());
    let next = AtomicUsize::new(0);
    let journal = Mutex::new(journal);
    let first_error: Mutex<Option<CampaignRunError>> = Mutex::new(None);
    let failed = AtomicBool::new(false);
    std::thread::scope(|s| {
        for _ in 0..opts.threads.max(1) {
            s.spawn(|| loop {
                if opts.stop.load(Ordering::SeqCst) || failed.load(Ordering::SeqCst) {
                    break;
                }
                let k = next.fetch_add(1, Ordering::SeqCst);
                let Some(cell) = todo.get(k) else { break };
                match run_cell(
                    campaign,
                    dir,
                    cell,
                    &journal,
                    &opts.stop,
                    &CellBench::Sim,
                    None,
                ) {
                    Ok(()) => {
                        let n = done_count.fetch_add(1, Ordering::SeqCst) + 1;
                        if let Some(f) = opts.on_cell {
                            f(n, total);
                        }
                    }
                    Err(e) => {
                        failed.store(true, Ordering::SeqCst);
                        let mut slot = first_error.lock().unwrap_or_else(|p| p.into_inner());
                        if slot.is_none() && !opts.stop.load(Ordering::SeqCst) {
                            *slot = Some(e);
                        }
                        break;
                    }
                }
            });
        }
    });
    if let Some(e) = first_error.into_inner().unwrap_or_else(|p| p.into_inner()) {
        let _ = write_results(campaign, dir);
        return Err(e);
    }
    let summary = write_results(campaign, dir)?;
    if summary.pending > 0 {
        return Err(CampaignRunError::Stopped {
            dir: dir.to_path_buf(),
            done: summary.done,
            cells: summary.cells,
        });
    }
    Ok(summary)
}

/// Submits a job to the `bench serve` daemon at a socket and returns its
/// summary (the `result` JSON), or why not. The caller gives it (the CLI:
/// `bench::daemon::client::submit`), so that a campaign, which the daemon
/// runs too, does not depend on the daemon.
pub type SubmitJob = fn(&Path, &JobRequest) -> Result<serde_json::Value, String>;

/// Where a cell's chirp runs.
#[derive(Debug, Clone)]
pub enum CellBench {
    /// The simulator, in virtual time.
    Sim,
    /// A hardware backend (`serial:…`, `socketcan:…`), in real time.
    Backend(BackendSpec),
    /// A chirp job of the `bench serve` daemon on this socket (its own
    /// config and backend; the campaign sends the seed and the chirp),
    /// submitted by the function given.
    Daemon(PathBuf, SubmitJob),
}

/// Runs one cell from scratch and journals it. `achieved`: the mass
/// asymmetry the operator set (hardware), where it differs from the
/// grid's.
fn run_cell(
    campaign: &Campaign,
    dir: &Path,
    cell: &Cell,
    journal: &Mutex<Journal>,
    stop: &Arc<AtomicBool>,
    bench: &CellBench,
    achieved: Option<f64>,
) -> Result<(), CampaignRunError> {
    let rel = cell_dir(cell.index);
    let cdir = dir.join(&rel);
    let keep = campaign.spec.keep;
    // Whatever an interrupted attempt left is not a result.
    if cdir.exists() {
        fs::remove_dir_all(&cdir).map_err(io_at(&cdir))?;
    }
    fs::create_dir_all(&cdir).map_err(io_at(&cdir))?;
    journal
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .append(&Entry::Started { cell: cell.index })?;
    let mut config = campaign.config.clone();
    config.plant.operating_point_m = cell.operating_point_m;
    // On hardware the model (FRF plot, summary) is of the asymmetry the
    // operator could set with whole trim masses.
    let achieved = achieved.filter(|a| *a != cell.mass_asymmetry);
    config.plant.mass_asymmetry = achieved.unwrap_or(cell.mass_asymmetry);
    let seed = campaign.seed_of(cell);
    config.sim.seed = seed;
    let cell_err = |reason: String| CampaignRunError::Cell {
        cell: cell.index,
        operating_point_m: cell.operating_point_m,
        mass_asymmetry: cell.mass_asymmetry,
        reason,
    };
    // The recording's path as the journal names it: in the cell's
    // directory, or the daemon's (absolute).
    let mut recording = format!("{rel}/{}", CELL_FILES[0]);
    let summary: ChirpSummary = match bench {
        CellBench::Sim | CellBench::Backend(_) => {
            let opts = ChirpOptions {
                config,
                config_path: campaign.config_path.clone(),
                out: cdir.join(CELL_FILES[0]),
                frf_csv: cdir.join(CELL_FILES[1]),
                plot: cdir.join(CELL_FILES[2]),
                // A campaign keeps its cells' three files; a multisine
                // cell's noise and distortion are in its summary.
                bla_csv: None,
                realtime: !matches!(bench, CellBench::Sim),
                pace: None,
                seed,
                progress: false,
                backend: match bench {
                    CellBench::Backend(b) => Some(b.clone()),
                    _ => None,
                },
                inject: None,
            };
            let summary = run_chirp(&opts, chirp_outputs(&opts), stop.clone(), None)
                .map_err(|e| cell_err(e.to_string()))?;
            // What the campaign does not keep goes once the chirp is done
            // (a cell's recording is on disk while it runs).
            for (i, path) in [(0, &opts.out), (1, &opts.frf_csv), (2, &opts.plot)] {
                if !keep.keeps(i) {
                    fs::remove_file(path).map_err(io_at(path))?;
                }
            }
            summary
        }
        CellBench::Daemon(socket, submit) => {
            let c = &config.chirp;
            let job = JobRequest::Chirp(crate::jobs::request::ChirpRequest {
                seed: Some(seed),
                amplitude_a: Some(c.amplitude_a),
                f_start_hz: Some(c.f_start_hz),
                f_end_hz: Some(c.f_end_hz),
                duration_s: c.duration_s,
                pace: None,
            });
            let v = submit(socket, &job)
                .map_err(|e| cell_err(format!("daemon {}: {e}", socket.display())))?;
            let summary: ChirpSummary = serde_json::from_value(v)
                .map_err(|e| cell_err(format!("the daemon's summary does not parse: {e}")))?;
            // The FRF and the plot beside the cell's summary; the
            // recording stays where the daemon wrote it.
            for (from, i) in [(&summary.frf_csv, 1), (&summary.plot, 2)] {
                if !keep.keeps(i) {
                    continue;
                }
                let to = cdir.join(CELL_FILES[i]);
                fs::copy(from, &to).map_err(|e| {
                    cell_err(format!(
                        "copying the daemon's {} to {}: {e}",
                        from.display(),
                        to.display()
                    ))
                })?;
            }
            recording = summary.recording.display().to_string();
            summary
        }
    };
    let reason = match summary.cmp_cnmp {
        Some(_) => None,
        None => Some(
            summary
                .verdict
                .reason
                .clone()
                .unwrap_or_else(|| "the verdict is undecided".to_string()),
        ),
    };
    let summary_path = cdir.join(CELL_FILES[3]);
    let mut value = serde_json::to_value(&summary).expect("summaries serialise");
    if keep != Keep::Recording {
        // The files the cell did not keep are named as not kept.
        for (i, key) in [(0, "recording"), (1, "frf_csv"), (2, "plot")] {
            let daemon_recording = i == 0 && matches!(bench, CellBench::Daemon(..));
            if !(keep.keeps(i) || daemon_recording) {
                value[key] = serde_json::Value::Null;
            }
        }
        value["kept"] = keep.name().into();
    }
    let json = serde_json::to_string_pretty(&value).expect("summaries serialise") + "\n";
    write_atomically(&summary_path, Existing::Refuse, |f| {
        f.write_all(json.as_bytes())
    })
    .map_err(io_at(&summary_path))?;
    // Every output synced before the entry that counts it.
    let mut files = Vec::new();
    for (i, name) in CELL_FILES.iter().enumerate() {
        // The daemon keeps its recording (in its own directory) whatever
        // the campaign keeps.
        let daemon_recording = i == 0 && matches!(bench, CellBench::Daemon(..));
        if !(keep.keeps(i) || daemon_recording) {
            continue;
        }
        let path = if i == 0 {
            recording.clone()
        } else {
            format!("{rel}/{name}")
        };
        let p = dir.join(&path);
        File::open(&p)
            .and_then(|f| f.sync_all())
            .map_err(io_at(&p))?;
        files.push(file_sum(dir, &path).map_err(io_at(&p))?);
    }
    File::open(&cdir)
        .and_then(|d| d.sync_all())
        .map_err(io_at(&cdir))?;
    journal
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .append(&Entry::Done {
            cell: cell.index,
            operating_point_m: cell.operating_point_m,
            mass_asymmetry: cell.mass_asymmetry,
            achieved_mass_asymmetry: achieved,
            seed,
            verdict: summary.cmp_cnmp,
            reason,
            files,
        })?;
    Ok(())
}

/// The state of every cell from the journal, against the model.
///
/// # Errors
/// [`CampaignRunError::BadInput`] if the model fails at a cell (cannot
/// happen for a validated campaign).
pub fn results(campaign: &Campaign, j: &ReadJournal) -> Result<Vec<CellResult>, CampaignRunError> {
    let skipped = j.skipped();
    campaign
        .cells()
        .iter()
        .map(|c| {
            let (status, verdict, reason, seed, achieved) = match done_entry(j, c) {
                Some(Entry::Done {
                    verdict,
                    reason,
                    seed,
                    achieved_mass_asymmetry,
                    ..
                }) => (
                    "done",
                    *verdict,
                    reason.clone(),
                    *seed,
                    *achieved_mass_asymmetry,
                ),
                _ if skipped.contains(&c.index) => {
                    ("skipped", None, None, campaign.seed_of(c), None)
                }
                _ => ("pending", None, None, campaign.seed_of(c), None),
            };
            let model = model_at(
                &campaign.config.plant,
                c.operating_point_m,
                achieved.unwrap_or(c.mass_asymmetry),
            )
            .map_err(|e| CampaignRunError::BadInput(e.to_string()))?;
            Ok(CellResult {
                index: c.index,
                operating_point_m: c.operating_point_m,
                mass_asymmetry: c.mass_asymmetry,
                achieved_mass_asymmetry: achieved,
                status: status.to_string(),
                verdict,
                reason,
                model_cnmp: model_cnmp_damped(&model),
                seed,
                dir: cell_dir(c.index),
            })
        })
        .collect()
}

/// Checks the files of every done cell against the journal's checksums:
/// the cells whose files are missing or changed, with the first reason.
pub fn damaged_cells(dir: &Path, j: &ReadJournal) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    for (cell, e) in j.done() {
        let Entry::Done { files, .. } = e else {
            continue;
        };
        for f in files {
            match file_sum(dir, &f.path) {
                Ok(now) if now == *f => {}
                Ok(_) => {
                    out.push((cell, format!("{} changed since it was recorded", f.path)));
                    break;
                }
                Err(e) => {
                    out.push((cell, format!("{}: {e}", f.path)));
                    break;
                }
            }
        }
    }
    out
}

/// The campaign summary from the journal of `dir` (no files written).
///
/// # Errors
/// As [`results`].
pub fn summarize(
    campaign: &Campaign,
    dir: &Path,
    j: &ReadJournal,
) -> Result<CampaignSummary, CampaignRunError> {
    let results = results(campaign, j)?;
    let count = |s: &str| results.iter().filter(|r| r.status == s).count();
    // Done cells against the damped model at each cell.
    let done_cells: Vec<&CellResult> = results.iter().filter(|r| r.status == "done").collect();
    let agreed = agreement(done_cells.iter().map(|r| (r.verdict, r.model_cnmp)));
    let disagreements: Vec<CellResult> = agreed
        .disagreements
        .iter()
        .map(|&i| done_cells[i].clone())
        .collect();
    let abs = std::path::absolute(dir).unwrap_or_else(|_| dir.to_path_buf());
    let done = count("done");
    Ok(CampaignSummary {
        dir: abs.clone(),
        cells: results.len(),
        done,
        skipped: count("skipped"),
        pending: count("pending"),
        decided: agreed.decided,
        agree: agreed.agree,
        disagreements,
        cells_csv: abs.join(CELLS_CSV),
        map_png: (done > 0).then(|| abs.join(MAP_PNG)),
        results,
        design: None,
    })
}

/// Writes `cells.csv`, the map and `summary.json` of `dir` from its
/// journal (replacing earlier ones).
///
/// # Errors
/// [`CampaignRunError`] on a write failure.
pub fn write_results(campaign: &Campaign, dir: &Path) -> Result<CampaignSummary, CampaignRunError> {
    let j = journal::read(dir)?;
    let summary = summarize(campaign, dir, &j)?;
    let csv_path = dir.join(CELLS_CSV);
    let mut csv = String::from(
        "index,operating_point_m,mass_asymmetry,status,verdict,model_cnmp,agrees,seed,reason,recording,frf_csv,summary\n",
    );
    let done = j.done();
    for r in &summary.results {
        let verdict = r.verdict.map(|v| v.to_string()).unwrap_or_default();
        let agrees = r
            .verdict
            .map(|v| (v == r.model_cnmp).to_string())
            .unwrap_or_default();
        let reason = r
            .reason
            .clone()
            .unwrap_or_default()
            .replace(['"', ','], ";");
        // The files the done entry counts (a cell keeps what the
        // campaign's `keep` said when it ran).
        let kept: Vec<&str> = match done.get(&r.index) {
            Some(Entry::Done { files, .. }) if r.status == "done" => {
                files.iter().map(|f| f.path.as_str()).collect()
            }
            _ => Vec::new(),
        };
        let file = |i: usize| {
            let rel = format!("{}/{}", r.dir, CELL_FILES[i]);
            let named = kept
                .iter()
                .find(|p| **p == rel || (i == 0 && p.ends_with(".mcap")));
            named.map(|p| p.to_string()).unwrap_or_default()
        };
        csv.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{},{}\n",
            r.index,
            r.operating_point_m,
            r.mass_asymmetry,
            r.status,
            verdict,
            r.model_cnmp,
            agrees,
            r.seed,
            reason,
            file(0),
            file(1),
            file(3)
        ));
    }
    write_atomically(&csv_path, Existing::Replace, |f| {
        f.write_all(csv.as_bytes())
    })
    .map_err(io_at(&csv_path))?;
    if summary.done > 0 {
        write_map(campaign, dir, &summary)?;
    }
    let sum_path = dir.join(SUMMARY_JSON);
    let json = serde_json::to_string_pretty(&summary).expect("summaries serialise") + "\n";
    write_atomically(&sum_path, Existing::Replace, |f| {
        f.write_all(json.as_bytes())
    })
    .map_err(io_at(&sum_path))?;
    Ok(summary)
}

/// The map PNG: the damped model's CNMP map over the campaign's range
/// (half a grid step beyond each edge), the measured verdicts as squares
/// (CMP-CNMP) and circles (none), as the thesis' Fig 5-10.
fn write_map(
    campaign: &Campaign,
    dir: &Path,
    summary: &CampaignSummary,
) -> Result<(), CampaignRunError> {
    let p = &campaign.config.plant;
    // Half a grid step beyond the outer cells, within the model's range;
    // an axis of values ≥ 0 stays ≥ 0 (the thesis' maps start there).
    let edge = |v: &[f64], lo: f64, hi: f64| {
        let (min, max) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                (a.min(*x), b.max(*x))
            });
        let half = if v.len() > 1 {
            0.5 * (max - min) / (v.len() - 1) as f64
        } else {
            0.01 * (hi - lo)
        };
        let lo = if min >= 0.0 { lo.max(0.0) } else { lo };
        ((min - half).max(lo), (max + half).min(hi))
    };
    let lim = bench_hal::model::ranges::OPERATING_POINT_OF_L * p.beam.length_m;
    let (op_lo, op_hi) = edge(&campaign.operating_points_m, -lim, lim);
    let (dlo, dhi) = bench_hal::model::ranges::MASS_ASYMMETRY;
    let (dm_lo, dm_hi) = edge(&campaign.mass_asymmetries, dlo, dhi);
    let ops = linspace(op_lo, op_hi, 121);
    let dms = linspace(dm_lo, dm_hi, 91);
    let cells: Vec<MapCell> =
        cnmp_map(p, &ops, &dms).map_err(|e| CampaignRunError::BadInput(format!("map: {e}")))?;
    let measured: Vec<MeasuredPoint> = summary
        .results
        .iter()
        .filter_map(|r| {
            r.verdict.map(|v| MeasuredPoint {
                operating_point_m: r.operating_point_m,
                mass_asymmetry: r.achieved_mass_asymmetry.unwrap_or(r.mass_asymmetry),
                cnmp: v,
            })
        })
        .collect();
    let title = format!(
        "Measured verdicts ({} of {} decided, {} disagree) on the model's CNMP map",
        summary.decided,
        summary.cells,
        summary.disagreements.len()
    );
    let png = dir.join(MAP_PNG);
    write_map_png(
        &png,
        Existing::Replace,
        &title,
        p.beam.length_m,
        &ops,
        &dms,
        &cells,
        None,
        &measured,
        None,
    )
    .map_err(|e| CampaignRunError::Io {
        path: png.clone(),
        source: io::Error::other(e.to_string()),
    })
}

/// Whole trim masses on the two secondary stages that set a mass
/// asymmetry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrimMasses {
    /// Trim masses on stage 2.
    pub stage2: u32,
    /// Trim masses on stage 3.
    pub stage3: u32,
    /// The asymmetry they give, `(m2 + n2·δ)/(m3 + n3·δ) − 1`.
    pub achieved_mass_asymmetry: f64,
}

/// The whole number of trim masses of `increment_kg` on stage 2 (for
/// Δm23 ≥ m2/m3 − 1) or stage 3 (below) nearest to mass asymmetry
/// `target`, for secondary stages of `m2_kg`, `m3_kg` without trim masses
/// (thesis 5.2.1: 0.5 g masses on the 60 g stages, 0.8 % each).
/// Δm23 = m2/m3 − 1.
pub fn trim_masses(m2_kg: f64, m3_kg: f64, increment_kg: f64, target: f64) -> TrimMasses {
    let (n2, n3) = if m2_kg <= m3_kg * (1.0 + target) {
        (
            ((m3_kg * (1.0 + target) - m2_kg) / increment_kg).round(),
            0.0,
        )
    } else {
        (
            0.0,
            ((m2_kg / (1.0 + target) - m3_kg) / increment_kg).round(),
        )
    };
    TrimMasses {
        stage2: n2 as u32,
        stage3: n3 as u32,
        achieved_mass_asymmetry: (m2_kg + n2 * increment_kg) / (m3_kg + n3 * increment_kg) - 1.0,
    }
}

/// What the operator answers before a cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OperatorAnswer {
    /// The setup is changed: run the cell.
    Run,
    /// Skip this cell (journaled as skipped).
    Skip,
    /// Run the previous cell again first.
    RedoPrevious,
    /// Stop the campaign (resumable).
    Stop,
}

/// The person at the bench: shown the instructions, answers.
pub trait Operator {
    /// Shows `instructions` and waits for the answer.
    ///
    /// # Errors
    /// The I/O error of asking (a closed input counts as
    /// [`OperatorAnswer::Stop`], not an error).
    fn ask(&mut self, instructions: &str) -> io::Result<OperatorAnswer>;
}

/// An operator on a text stream: instructions to `out`, one answer per
/// line from `input` (empty line: run; `s`: skip; `r`: redo the previous
/// cell; `q`: stop; end of input: stop). Anything else is asked again.
pub struct LineOperator<R, W> {
    /// Answers.
    pub input: R,
    /// Where the instructions go.
    pub out: W,
}

impl<R: io::BufRead, W: Write> Operator for LineOperator<R, W> {
    fn ask(&mut self, instructions: &str) -> io::Result<OperatorAnswer> {
        loop {
            write!(
                self.out,
                "{instructions}\n  [Enter] run · s skip · r redo the previous cell · q stop: "
            )?;
            self.out.flush()?;
            let mut line = String::new();
            if self.input.read_line(&mut line)? == 0 {
                writeln!(self.out)?;
                return Ok(OperatorAnswer::Stop);
            }
            match line.trim() {
                "" => return Ok(OperatorAnswer::Run),
                "s" | "skip" => return Ok(OperatorAnswer::Skip),
                "r" | "redo" => return Ok(OperatorAnswer::RedoPrevious),
                "q" | "quit" | "stop" => return Ok(OperatorAnswer::Stop),
                other => writeln!(self.out, "  not an answer: {other:?}")?,
            }
        }
    }
}

/// The setup of the bench: operating point and trim masses.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Setup {
    operating_point_m: f64,
    masses: TrimMasses,
}

/// What the operator must change from `from` (unknown at the start of a
/// session) to reach `cell`.
fn instructions(
    campaign: &Campaign,
    position: (usize, usize),
    cell: &Cell,
    from: Option<&Setup>,
    to: &Setup,
) -> String {
    let mm = |m: f64| m * 1e3;
    let mut s = format!(
        "cell {} of {} (grid cell {}): operating point Y1o = {:.3} mm ({:.2} % of L)",
        position.0,
        position.1,
        cell.index,
        mm(to.operating_point_m),
        100.0 * to.operating_point_m / campaign.config.plant.beam.length_m
    );
    if let Some(f) = from {
        let d = to.operating_point_m - f.operating_point_m;
        if d == 0.0 {
            s.push_str(", unchanged");
        } else {
            s.push_str(&format!(
                ", move {:+.3} mm from {:.3} mm",
                mm(d),
                mm(f.operating_point_m)
            ));
        }
    }
    let g = campaign.spec.mass_increment_kg * 1e3;
    let change = |now: u32, was: Option<u32>| match was {
        Some(w) if now > w => format!(" (add {})", now - w),
        Some(w) if now < w => format!(" (remove {})", w - now),
        Some(_) => " (unchanged)".to_string(),
        None => String::new(),
    };
    s.push_str(&format!(
        "\n  trim masses of {g} g: {} on stage 2{}, {} on stage 3{} -> Δm23 = {:+.2} % (grid {:+.2} %)",
        to.masses.stage2,
        change(to.masses.stage2, from.map(|f| f.masses.stage2)),
        to.masses.stage3,
        change(to.masses.stage3, from.map(|f| f.masses.stage3)),
        100.0 * to.masses.achieved_mass_asymmetry,
        100.0 * cell.mass_asymmetry
    ));
    s.push_str("\n  the amplifier is disabled at 0 A until you answer");
    s
}

/// Runs the cells of `campaign` not yet done or skipped on hardware
/// (`bench`: a backend or the daemon), one at a time in the serpentine order, each only after the
/// operator confirmed the setup they were told to make. Between cells the
/// backend is closed (the amplifier disabled at 0 A, as every chirp leaves
/// it); nothing is opened before the answer.
///
/// # Errors
/// As [`run_cells`]; [`CampaignRunError::Stopped`] when the operator
/// stops or the input ends.
pub fn run_attended(
    campaign: &Campaign,
    dir: &Path,
    journal: Journal,
    already: &ReadJournal,
    bench: &CellBench,
    operator: &mut dyn Operator,
    stop: &Arc<AtomicBool>,
) -> Result<CampaignSummary, CampaignRunError> {
    let p = &campaign.config.plant;
    let setup_of = |c: &Cell| Setup {
        operating_point_m: c.operating_point_m,
        masses: trim_masses(
            p.m2_kg,
            p.m3_kg,
            campaign.spec.mass_increment_kg,
            c.mass_asymmetry,
        ),
    };
    let skipped = already.skipped();
    let mut todo: std::collections::VecDeque<Cell> = campaign
        .serpentine()
        .into_iter()
        .filter(|c| done_entry(already, c).is_none() && !skipped.contains(&c.index))
        .collect();
    let total = todo.len();
    let journal = Mutex::new(journal);
    let mut current: Option<Setup> = None;
    let mut previous: Option<Cell> = None;
    let mut finished = 0;
    let mut stopped = false;
    while let Some(cell) = todo.front().copied() {
        if stop.load(Ordering::SeqCst) {
            stopped = true;
            break;
        }
        let to = setup_of(&cell);
        let text = instructions(
            campaign,
            ((finished + 1).min(total), total),
            &cell,
            current.as_ref(),
            &to,
        );
        let answer = operator.ask(&text).map_err(|e| CampaignRunError::Io {
            path: PathBuf::from("(operator)"),
            source: e,
        })?;
        match answer {
            OperatorAnswer::Stop => {
                stopped = true;
                break;
            }
            OperatorAnswer::Skip => {
                journal
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .append(&Entry::Skipped { cell: cell.index })?;
                todo.pop_front();
                finished += 1;
                previous = Some(cell);
            }
            OperatorAnswer::RedoPrevious => {
                if let Some(prev) = previous.take() {
                    todo.push_front(prev);
                }
            }
            OperatorAnswer::Run => {
                run_cell(
                    campaign,
                    dir,
                    &cell,
                    &journal,
                    stop,
                    bench,
                    Some(to.masses.achieved_mass_asymmetry),
                )?;
                current = Some(to);
                todo.pop_front();
                finished += 1;
                previous = Some(cell);
            }
        }
    }
    let summary = write_results(campaign, dir)?;
    if stopped || summary.pending > 0 {
        return Err(CampaignRunError::Stopped {
            dir: dir.to_path_buf(),
            done: summary.done,
            cells: summary.cells,
        });
    }
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trim_masses_give_the_thesis_steps() {
        // Thesis 5.2.1: a 0.5 g mass is 0.8 % of the 60 g secondary stage.
        let one = trim_masses(0.06, 0.06, 0.0005, 0.008);
        assert_eq!((one.stage2, one.stage3), (1, 0));
        assert!((one.achieved_mass_asymmetry - 0.0005 / 0.06).abs() < 1e-15);
        // −2 %: masses on stage 3, m2/(m3 + n δ) − 1 nearest −0.02.
        let neg = trim_masses(0.06, 0.06, 0.0005, -0.02);
        assert_eq!((neg.stage2, neg.stage3), (0, 2));
        assert!((neg.achieved_mass_asymmetry - (0.06 / 0.061 - 1.0)).abs() < 1e-15);
        let zero = trim_masses(0.06, 0.06, 0.0005, 0.0);
        assert_eq!(
            (zero.stage2, zero.stage3, zero.achieved_mass_asymmetry),
            (0, 0, 0.0)
        );
        // Every target within half a mass of what it gets.
        for k in -80..=100 {
            let t = k as f64 * 1e-3;
            let m = trim_masses(0.06, 0.06, 0.0005, t);
            let per_mass = 0.0005 / 0.06;
            assert!(
                (m.achieved_mass_asymmetry - t).abs() <= 0.5 * per_mass * 1.1,
                "{t}: {m:?}"
            );
        }
    }

    #[test]
    fn the_line_operator_reads_answers_and_stops_at_the_end_of_input() {
        let mut out = Vec::new();
        let mut op = LineOperator {
            input: io::Cursor::new("\nx\ns\nr\nq\n"),
            out: &mut out,
        };
        let answers: Vec<OperatorAnswer> = (0..5).map(|_| op.ask("cell").unwrap()).collect();
        assert_eq!(
            answers,
            [
                OperatorAnswer::Run,
                OperatorAnswer::Skip,
                OperatorAnswer::RedoPrevious,
                OperatorAnswer::Stop,
                OperatorAnswer::Stop
            ]
        );
        assert!(String::from_utf8(out)
            .unwrap()
            .contains("not an answer: \"x\""));
    }
}
