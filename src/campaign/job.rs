//! `bench campaign run|resume` as a job: a campaign made ready to run
//! ([`start`] a new one, [`resume`] one in its directory), then run on the
//! simulator in parallel ([`Ready::run_parallel`]) or one cell at a time
//! after the operator's answer ([`Ready::run_attended`]). The CLI turns its
//! flags into these calls and shows progress; the daemon's `campaign` job
//! ([`crate::jobs::request::CampaignRequest`]) starts a new campaign in its
//! recordings directory and runs it on the simulator.

use super::disk::DiskEstimate;
use super::file::{Campaign, Keep};
use super::journal::{Journal, ReadJournal};
use super::run::{
    adopt_changed, create, damaged_cells, load_dir, run_attended, run_cells, CampaignRunError,
    CampaignSummary, CellBench, Operator, RunOptions,
};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// Most cells run at once.
pub const MAX_THREADS: usize = 64;

/// Cells run at once: `given` (1 … [`MAX_THREADS`]), else one per core.
///
/// # Errors
/// [`CampaignRunError::BadOption`] naming `threads`.
pub fn threads(given: Option<usize>) -> Result<usize, CampaignRunError> {
    match given {
        Some(n) if (1..=MAX_THREADS).contains(&n) => Ok(n),
        Some(n) => Err(CampaignRunError::BadOption {
            key: "threads",
            value: n.to_string(),
            reason: format!("must be 1 … {MAX_THREADS} (cells run at once)"),
        }),
        None => Ok(std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)),
    }
}

/// A campaign ready to run: loaded, its directory created (a new one) or
/// checked (a resumed one), its journal open.
pub struct Ready {
    /// The campaign.
    pub campaign: Campaign,
    /// Its directory.
    pub dir: PathBuf,
    /// What the operator should know before it goes on (the original
    /// files changed since `run`; the copies are used).
    pub note: Option<String>,
    /// The disk its cells still to run will use, and the space left.
    pub disk: DiskEstimate,
    journal: Journal,
    read: ReadJournal,
}

/// The campaign to run: `file`, or the built-in one
/// ([`Campaign::builtin`]) when `None`; with `keep` set when given; and
/// checked against `design` (a design needs the cells' FRFs, which `keep =
/// "summary"` does not keep).
///
/// # Errors
/// [`CampaignRunError::BadInput`] naming the file and key;
/// [`CampaignRunError::BadOption`] naming `keep` for a design without
/// FRFs.
pub fn prepare(
    file: Option<&Path>,
    keep: Option<Keep>,
    design: bool,
) -> Result<Campaign, CampaignRunError> {
    let bad = |e: super::file::CampaignError| CampaignRunError::BadInput(e.to_string());
    let mut campaign = match file {
        Some(f) => Campaign::load(f).map_err(bad)?,
        None => Campaign::builtin().map_err(bad)?,
    };
    if let Some(k) = keep {
        campaign = campaign.with_keep(k).map_err(bad)?;
    }
    if design && campaign.spec.keep == Keep::Summary {
        return Err(CampaignRunError::BadOption {
            key: "keep",
            value: "summary".into(),
            reason: "keeps no cell's FRF, and the design at the end needs them: keep frf or recording, or design later".into(),
        });
    }
    Ok(campaign)
}

/// Refuses a campaign whose cells cannot fit on the disk ([`DiskEstimate::too_big`]).
fn check_disk(disk: &DiskEstimate, threads: usize, dir: &Path) -> Result<(), CampaignRunError> {
    if disk.too_big(threads) {
        return Err(CampaignRunError::BadOption {
            key: "keep",
            value: disk.keep.name().into(),
            reason: format!(
                "{}: the cells will not fit ({}); keep less per cell (frf: the FRF CSV and the summary; summary: the summary only), or free space",
                dir.display(),
                disk.describe()
            ),
        });
    }
    Ok(())
}

/// Starts a new campaign of `campaign` in `dir` (`None`: the campaign
/// file's `out`): creates the directory ([`create`]) and opens its
/// journal.
///
/// # Errors
/// [`CampaignRunError::BadOption`] naming `out` when there is no
/// directory or it cannot hold a new campaign; journal and I/O errors.
pub fn start(
    campaign: Campaign,
    dir: Option<&Path>,
    threads: usize,
) -> Result<Ready, CampaignRunError> {
    let Some(dir) = dir
        .map(Path::to_path_buf)
        .or_else(|| campaign.spec.out.clone())
    else {
        return Err(CampaignRunError::BadOption {
            key: "out",
            value: String::new(),
            reason: format!(
                "{}: no output directory: give one, or `out = \"DIR\"` in the campaign file",
                campaign.path.display()
            ),
        });
    };
    super::run::check_new_dir(&dir)?;
    let disk = DiskEstimate::of(&campaign, campaign.cells().len(), &dir);
    check_disk(&disk, threads, &dir)?;
    create(&campaign, &dir)?;
    let (journal, read) = Journal::open(&dir)?;
    Ok(Ready {
        campaign,
        dir,
        note: None,
        disk,
        journal,
        read,
    })
}

/// Goes on with the campaign in `dir` ([`load_dir`]: its copies, or
/// `campaign_file`; with `force` although the files changed, the change
/// journaled). Refused while a done cell's files are missing or changed.
///
/// # Errors
/// [`CampaignRunError::BadInput`]: not a campaign directory, a change
/// without `force`, damaged cells; journal and I/O errors.
pub fn resume(
    dir: &Path,
    campaign_file: Option<&Path>,
    force: bool,
    threads: usize,
) -> Result<Ready, CampaignRunError> {
    let (campaign, j, note) = load_dir(dir, campaign_file, force)?;
    let left = campaign
        .cells()
        .len()
        .saturating_sub(j.done().len() + j.skipped().len());
    let disk = DiskEstimate::of(&campaign, left, dir);
    check_disk(&disk, threads, dir)?;
    let (mut journal, read) = Journal::open(dir)?;
    if force {
        adopt_changed(dir, &mut journal, &campaign)?;
    }
    let damaged = damaged_cells(dir, &read);
    if !damaged.is_empty() {
        let list: Vec<String> = damaged
            .iter()
            .map(|(c, why)| format!("cell {c}: {why}"))
            .collect();
        return Err(CampaignRunError::BadInput(format!(
            "{}: files of done cells are missing or changed ({}); the campaign's results would not be what it measured. Restore them, or start a new campaign",
            dir.display(),
            list.join("; ")
        )));
    }
    Ok(Ready {
        campaign,
        dir: dir.to_path_buf(),
        note,
        disk,
        journal,
        read,
    })
}

impl Ready {
    /// Cells in the grid.
    pub fn cells(&self) -> usize {
        self.campaign.cells().len()
    }

    /// Cells done (journaled) already.
    pub fn done(&self) -> usize {
        self.read.done().len()
    }

    /// Cells left to run: neither done nor skipped.
    pub fn to_run(&self) -> usize {
        self.cells() - self.done() - self.read.skipped().len()
    }

    /// Runs the cells left on the simulator, `opts.threads` at a time
    /// ([`run_cells`]).
    ///
    /// # Errors
    /// As [`run_cells`].
    pub fn run_parallel(self, opts: &RunOptions<'_>) -> Result<CampaignSummary, CampaignRunError> {
        run_cells(&self.campaign, &self.dir, self.journal, &self.read, opts)
    }

    /// Runs the cells left on `bench` (a backend or the daemon), one at a
    /// time after the operator's answer ([`run_attended`]).
    ///
    /// # Errors
    /// As [`run_attended`].
    pub fn run_attended(
        self,
        bench: &CellBench,
        operator: &mut dyn Operator,
        stop: &Arc<AtomicBool>,
    ) -> Result<CampaignSummary, CampaignRunError> {
        run_attended(
            &self.campaign,
            &self.dir,
            self.journal,
            &self.read,
            bench,
            operator,
            stop,
        )
    }
}

/// Designs one controller over every done cell of the campaign in `dir`
/// (`bench campaign run|resume --design STRATEGY`): `DIR/designed.toml`
/// (the campaign's bench with `[controller.designed]`) and
/// `DIR/designed.png`, replaced when a resumed campaign designs again.
///
/// # Errors
/// As [`crate::jobs::design::run_design`]; the campaign's own results are
/// untouched.
pub fn design_over(
    dir: &Path,
    strategy: crate::design::Strategy,
) -> Result<crate::jobs::design::DesignSummary, crate::error::RunError> {
    use crate::jobs::design::{run_design, DesignOptions, DesignRequest};
    let input = design_input(dir).map_err(|e| crate::error::RunError::BadInput(e.to_string()))?;
    let opts = DesignOptions {
        request: DesignRequest {
            inputs: vec![dir.to_path_buf()],
            strategy,
            ..DesignRequest::default()
        },
        inputs: vec![input],
        out: Some(dir.join("designed.toml")),
        png: Some(dir.join("designed.png")),
        existing: crate::outputs::Existing::Replace,
    };
    run_design(&opts)
}

/// The inputs of `bench design` (and of its daemon job): each path a
/// file as it is, or a campaign directory as its done cells
/// ([`design_input`]).
///
/// # Errors
/// [`crate::error::RunError::BadOption`] naming `inputs`: a campaign
/// directory that cannot be read.
pub fn design_inputs(
    paths: &[PathBuf],
) -> Result<Vec<crate::jobs::design::DesignInput>, crate::error::RunError> {
    expand(paths, design_input, crate::jobs::design::DesignInput::File)
}

/// The inputs of `bench plot` (and of its daemon job), as
/// [`design_inputs`] ([`plot_input`]).
///
/// # Errors
/// As [`design_inputs`].
pub fn plot_inputs(
    paths: &[PathBuf],
) -> Result<Vec<crate::jobs::plot::PlotInput>, crate::error::RunError> {
    expand(paths, plot_input, crate::jobs::plot::PlotInput::File)
}

fn expand<T>(
    paths: &[PathBuf],
    campaign: fn(&Path) -> Result<T, CampaignRunError>,
    file: fn(PathBuf) -> T,
) -> Result<Vec<T>, crate::error::RunError> {
    paths
        .iter()
        .map(|p| {
            if p.is_dir() {
                campaign(p).map_err(|e| crate::error::RunError::option("inputs", "", e.to_string()))
            } else {
                Ok(file(p.clone()))
            }
        })
        .collect()
}

/// The campaign in `dir` as the input of `bench design`: its bench
/// config's text and the FRF of every done cell (`cells/NNN/frf.csv`),
/// each checked against the journal's checksum.
///
/// # Errors
/// [`CampaignRunError::BadInput`]: not a campaign directory, or a done
/// cell whose files are missing or changed since they were recorded.
fn design_input(dir: &Path) -> Result<crate::jobs::design::DesignInput, CampaignRunError> {
    let (campaign, j, _) = load_dir(dir, None, false)?;
    if let Some((cell, why)) = damaged_cells(dir, &j).into_iter().next() {
        return Err(CampaignRunError::BadInput(format!(
            "{}: cell {cell:03}: {why} (bench campaign resume runs it again)",
            dir.display()
        )));
    }
    // The done cells that kept their FRF (`keep = "summary"` keeps none).
    let cells: Vec<(usize, std::path::PathBuf)> = j
        .done()
        .iter()
        .filter_map(|(&i, e)| {
            let rel = format!("{}/{}", super::run::cell_dir(i), super::run::CELL_FILES[1]);
            match e {
                super::journal::Entry::Done { files, .. }
                    if files.iter().any(|f| f.path == rel) =>
                {
                    Some((i, dir.join(rel)))
                }
                _ => None,
            }
        })
        .collect();
    if cells.is_empty() && !j.done().is_empty() {
        return Err(CampaignRunError::BadInput(format!(
            "{}: no done cell kept its FRF (the campaign keeps {}): run it with keep = \"frf\" or \"recording\" to design over it",
            dir.display(),
            campaign.spec.keep.name()
        )));
    }
    Ok(crate::jobs::design::DesignInput::Cells {
        dir: dir.to_path_buf(),
        config_toml: campaign.config_text.clone(),
        cells,
    })
}

/// The campaign in `dir` as an input of `bench plot`: its bench config's
/// text and the FRF of every done cell with the cell's operating point and
/// mass asymmetry (the asymmetry the trim masses gave, on hardware), each
/// cell checked against the journal's checksum as [`design_input`] does.
///
/// # Errors
/// As [`design_input`].
fn plot_input(dir: &Path) -> Result<crate::jobs::plot::PlotInput, CampaignRunError> {
    use super::journal::Entry;
    let (campaign, j, _) = load_dir(dir, None, false)?;
    if let Some((cell, why)) = damaged_cells(dir, &j).into_iter().next() {
        return Err(CampaignRunError::BadInput(format!(
            "{}: cell {cell:03}: {why} (bench campaign resume runs it again)",
            dir.display()
        )));
    }
    let cells = j
        .done()
        .into_iter()
        .filter_map(|(i, e)| match e {
            Entry::Done {
                operating_point_m,
                mass_asymmetry,
                achieved_mass_asymmetry,
                ..
            } => Some(crate::jobs::plot::PlotCell {
                index: i,
                operating_point_m: *operating_point_m,
                mass_asymmetry: achieved_mass_asymmetry.unwrap_or(*mass_asymmetry),
                frf_csv: dir
                    .join(super::run::cell_dir(i))
                    .join(super::run::CELL_FILES[1]),
            }),
            _ => None,
        })
        .collect();
    Ok(crate::jobs::plot::PlotInput::Cells {
        dir: dir.to_path_buf(),
        config_toml: campaign.config_text.clone(),
        beam_length_m: campaign.config.plant.beam.length_m,
        cells,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn threads_are_bounded() {
        assert_eq!(threads(Some(3)).unwrap(), 3);
        assert!(threads(None).unwrap() >= 1);
        for n in [0, MAX_THREADS + 1] {
            assert!(matches!(
                threads(Some(n)),
                Err(CampaignRunError::BadOption { key: "threads", .. })
            ));
        }
    }
}
