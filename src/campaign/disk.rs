//! The disk a campaign will use, estimated before it starts, against the
//! space left where it writes.
//!
//! A cell writes what `bench chirp` writes, less what the campaign does
//! not keep ([`Keep`]). The sizes are measured (2026-11-24, a default
//! 60 s cell on the simulator at 5 kHz, this project's build):
//! * the recording: [`RECORDING_FIXED_BYTES`] plus
//!   [`RECORDING_BYTES_PER_TICK`] a loop tick (the LZ4-compressed samples,
//!   envelope and timing; 5.5 MB for the 327 500 ticks of a default cell;
//!   linear in the ticks within 0.3 % from 5 s to 60 s chirps);
//! * the FRF CSV: [`FRF_CSV_BYTES`] (its lines are the estimator's, about
//!   1 500 whatever the duration);
//! * the Bode plot: [`PLOT_BYTES`];
//! * the summary: [`SUMMARY_BYTES`];
//! * the cell's catalogue row: [`CATALOGUE_ROW_BYTES`], whatever is kept.
//!
//! The estimate is stated ±[`ESTIMATE_REL_UNCERTAINTY`]: compression
//! depends on the noise, a plot on what it shows. `tests/cli/campaign.rs`
//! compares it with the bytes a small campaign wrote.

use std::path::Path;

use super::file::{Campaign, Keep};

/// Recording bytes a loop tick (LZ4-compressed), measured.
pub const RECORDING_BYTES_PER_TICK: f64 = 16.7;
/// Recording bytes whatever its length (metadata, the FRF message, the
/// summary index), measured.
pub const RECORDING_FIXED_BYTES: f64 = 53_000.0;
/// An FRF CSV, bytes, measured.
pub const FRF_CSV_BYTES: f64 = 91_000.0;
/// A Bode plot PNG, bytes, measured.
pub const PLOT_BYTES: f64 = 258_000.0;
/// A cell's `summary.json` (pretty-printed), bytes, measured (12.5 kB on
/// 2026-11-28, the small campaign of `tests/cli/campaign.rs`; 6.5 kB
/// before the fit stated its detection limit, about 80 points).
pub const SUMMARY_BYTES: f64 = 12_500.0;
/// A cell's catalogue row (`catalogue/cell-NNN.parquet`, one Parquet row
/// of every column), bytes, measured: kept whatever `keep` says.
pub const CATALOGUE_ROW_BYTES: f64 = 9_000.0;
/// Relative uncertainty of the estimate (1σ-like bound, from the spread
/// of the measured sizes).
pub const ESTIMATE_REL_UNCERTAINTY: f64 = 0.10;

/// What the cells still to run will write.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, schemars::JsonSchema)]
pub struct DiskEstimate {
    /// Cells still to run.
    pub cells: usize,
    /// What each keeps.
    pub keep: Keep,
    /// Bytes a cell keeps (estimate).
    pub cell_bytes: f64,
    /// Bytes all of them keep (estimate).
    pub total_bytes: f64,
    /// Relative uncertainty of both.
    pub rel_uncertainty: f64,
    /// Bytes a running cell holds on disk at most before what is not
    /// kept is removed (a recording is written, then removed).
    pub peak_cell_bytes: f64,
    /// Space left on the file system of the campaign directory, bytes
    /// (`None`: could not be read).
    pub available_bytes: Option<u64>,
}

impl DiskEstimate {
    /// For `cells` cells of `campaign`, written under `dir` (which need
    /// not exist yet: its nearest existing ancestor is asked).
    pub fn of(campaign: &Campaign, cells: usize, dir: &Path) -> Self {
        let cfg = &campaign.config;
        let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
        let ticks =
            crate::ident::excitation::Excitation::total_ticks_of(cfg, period_s).unwrap_or(0) as f64;
        let files = [
            RECORDING_FIXED_BYTES + RECORDING_BYTES_PER_TICK * ticks,
            FRF_CSV_BYTES,
            PLOT_BYTES,
            SUMMARY_BYTES,
        ];
        let keep = campaign.spec.keep;
        let cell_bytes: f64 = (0..4)
            .filter(|&i| keep.keeps(i))
            .map(|i| files[i])
            .sum::<f64>()
            + CATALOGUE_ROW_BYTES;
        let available_bytes = dir
            .ancestors()
            .map(|p| {
                if p.as_os_str().is_empty() {
                    Path::new(".")
                } else {
                    p
                }
            })
            .find(|p| p.exists())
            .and_then(|p| bench_hal::os::available_bytes(p).ok());
        Self {
            cells,
            keep,
            cell_bytes,
            total_bytes: cell_bytes * cells as f64,
            rel_uncertainty: ESTIMATE_REL_UNCERTAINTY,
            peak_cell_bytes: files.iter().sum::<f64>() + CATALOGUE_ROW_BYTES,
            available_bytes,
        }
    }

    /// Whether it cannot fit: the estimate's upper bound, plus one peak
    /// cell per running thread, exceeds the space left.
    pub fn too_big(&self, threads: usize) -> bool {
        let need = self.total_bytes * (1.0 + self.rel_uncertainty)
            + self.peak_cell_bytes * threads.min(self.cells) as f64;
        self.available_bytes.is_some_and(|a| need > a as f64)
    }

    /// One line for the operator: the estimate, what is kept, the space
    /// left.
    pub fn describe(&self) -> String {
        let free = self
            .available_bytes
            .map_or("free space unknown".to_string(), |a| {
                format!("{} free there", human(a as f64))
            });
        if self.cells == 0 {
            return format!("disk: no cell left to run; {free}");
        }
        format!(
            "disk: about {} for {} cells ({} a cell, ±{:.0} %, keep = {}); {free}",
            human(self.total_bytes),
            self.cells,
            human(self.cell_bytes),
            100.0 * self.rel_uncertainty,
            self.keep.name()
        )
    }
}

/// Bytes in kB / MB / GB (powers of 1000), 3 significant figures.
pub fn human(bytes: f64) -> String {
    let (v, unit) = if bytes >= 1e9 {
        (bytes / 1e9, "GB")
    } else if bytes >= 1e6 {
        (bytes / 1e6, "MB")
    } else {
        (bytes / 1e3, "kB")
    };
    let decimals = if v >= 100.0 {
        0
    } else if v >= 10.0 {
        1
    } else {
        2
    };
    format!("{v:.decimals$} {unit}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_grid_is_about_880_mb() {
        let c = Campaign::builtin().unwrap();
        let e = DiskEstimate::of(&c, c.cells().len(), Path::new("/tmp/x/y"));
        // 150 cells × 5.8 MB (measured sizes of a default cell).
        assert!((e.total_bytes / 150.0 / 5.8e6 - 1.0).abs() < 0.05, "{e:?}");
        assert!(e.available_bytes.is_some());
        let s = c.clone().with_keep(Keep::Summary).unwrap();
        let e = DiskEstimate::of(&s, 150, Path::new("."));
        assert_eq!(e.cell_bytes, SUMMARY_BYTES + CATALOGUE_ROW_BYTES);
        assert!(e.describe().contains("keep = summary"), "{}", e.describe());
    }

    #[test]
    fn human_sizes() {
        assert_eq!(human(5_800_000.0), "5.80 MB");
        assert_eq!(human(880e6), "880 MB");
        assert_eq!(human(5_000.0), "5.00 kB");
        assert_eq!(human(1.2e10), "12.0 GB");
    }
}
