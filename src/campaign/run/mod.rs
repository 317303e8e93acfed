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

mod attended;
mod cells;
mod dir;
mod results;
pub use attended::*;
pub use cells::*;
pub use dir::*;
pub use results::*;

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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
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
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
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

/// The directory of cell `index`, relative to the campaign directory
/// (`cells/NNN`), and its row in the run catalogue
/// (`catalogue/cell-NNN.parquet`: the campaign's own catalogue folder;
/// `bench catalogue` reads it, and a glob `DIR/**/catalogue/*.parquet`
/// finds it). The catalogue owns these names: it finds the cells by them.
pub use crate::catalogue::{cell_dir, cell_row};

/// The files of a done cell, relative to its directory.
pub const CELL_FILES: [&str; 4] = [
    crate::catalogue::CELL_RECORDING_FILE,
    "frf.csv",
    "bode.png",
    "summary.json",
];

#[cfg(test)]
mod tests;
