//! Running the cells: in parallel on the simulator, on a hardware backend
//! or through the daemon; one cell from scratch to its durable `done` entry.

use super::*;

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
    // The cells count against the memory budget of the job that runs the
    // campaign, if it has one (a daemon's job: `crate::job_memory`).
    let memory = crate::job_memory::JobMemory::current();
    let cell_loop = || loop {
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
    };
    std::thread::scope(|s| {
        for _ in 0..opts.threads.max(1) {
            s.spawn(|| {
                let _counted = memory.as_ref().map(crate::job_memory::JobMemory::enter);
                cell_loop();
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
pub(super) fn run_cell(
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
    let row_file = dir.join(cell_row(cell.index));
    clear_cell(&cdir, &row_file)?;
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
                // The cell's row goes to the campaign's catalogue folder
                // (below), not beside its recording.
                catalogue: false,
            };
            let mut summary = run_chirp(&opts, chirp_outputs(&opts), stop.clone(), None)
                .map_err(|e| cell_err(e.to_string()))?;
            // Its row, read from the recording before what is not kept
            // goes.
            summary.catalogue = Some(crate::jobs::catalogue::catalogue_cell(
                &opts.out,
                &row_file,
                keep.keeps(0),
            ));
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
            let summary =
                chirp_on_daemon(socket, *submit, &config, seed, keep, &cdir).map_err(cell_err)?;
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

/// Removes what an interrupted attempt at a cell left (its directory, its
/// catalogue row and the row's hidden temporary: none is a result), and
/// makes the cell's directory anew.
fn clear_cell(cdir: &Path, row_file: &Path) -> Result<(), CampaignRunError> {
    if cdir.exists() {
        fs::remove_dir_all(cdir).map_err(io_at(cdir))?;
    }
    match fs::remove_file(row_file) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(io_at(row_file)(e));
        }
        _ => {}
    }
    crate::outputs::remove_stale_temporaries(row_file).map_err(io_at(row_file))?;
    fs::create_dir_all(cdir).map_err(io_at(cdir))
}

/// A cell's chirp as a job of the daemon on `socket`: its summary, with
/// the FRF and the plot the campaign keeps copied into the cell's
/// directory `cdir` (the recording stays where the daemon wrote it).
///
/// # Errors
/// Why the cell has no result: the daemon's answer, a summary that does
/// not parse, or a copy that failed.
fn chirp_on_daemon(
    socket: &Path,
    submit: SubmitJob,
    config: &crate::config::BenchConfig,
    seed: u64,
    keep: Keep,
    cdir: &Path,
) -> Result<ChirpSummary, String> {
    let c = &config.chirp;
    let job = JobRequest::Chirp(crate::jobs::request::ChirpRequest {
        seed: Some(seed),
        amplitude_a: Some(c.amplitude_a),
        f_start_hz: Some(c.f_start_hz),
        f_end_hz: Some(c.f_end_hz),
        duration_s: c.duration_s,
        pace: None,
    });
    let v = submit(socket, &job).map_err(|e| format!("daemon {}: {e}", socket.display()))?;
    let summary: ChirpSummary = serde_json::from_value(v)
        .map_err(|e| format!("the daemon's summary does not parse: {e}"))?;
    // The FRF and the plot beside the cell's summary; the
    // recording stays where the daemon wrote it.
    for (from, i) in [(&summary.frf_csv, 1), (&summary.plot, 2)] {
        if !keep.keeps(i) {
            continue;
        }
        let to = cdir.join(CELL_FILES[i]);
        fs::copy(from, &to).map_err(|e| {
            format!(
                "copying the daemon's {} to {}: {e}",
                from.display(),
                to.display()
            )
        })?;
    }

    Ok(summary)
}
