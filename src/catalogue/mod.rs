//! The run catalogue (issue 30, part 3): one flat row per finished run,
//! in Parquet, for DuckDB, pandas or any Parquet reader to query a
//! folder, or a bucket, of them.
//!
//! A row ([`CatalogueRow`]) is read from a finished recording alone
//! ([`row_of_recording`]): its `bench.run` and `bench.config` metadata,
//! its events (how the run ended) and the job's results recorded in it
//! (`/sysid/summary`; `/control/loop_check`, `/control/metrics`,
//! `/control/summary`). So the row a run appends when it finishes and the
//! row `bench catalogue` rebuilds from the same recording later are the
//! same row, by construction. The results are read field by field, by the
//! JSON pointers of [`RESULT_READS`], each checked against the schema its
//! writer records.
//!
//! Parquet files are immutable, so "append" is one small file per run,
//! `<recordings>/catalogue/<recording stem>.parquet` ([`row_path`]),
//! written atomically ([`crate::outputs::write_atomically`]); `bench
//! catalogue` compacts a directory's recordings into one file
//! ([`file::write_rows`]), which queries read much faster than thousands
//! of small ones.
//!
//! # Columns
//!
//! SI units, the unit in the name; every column is nullable (a value the
//! run did not produce, or a recording of an older version that did not
//! record it, is null). [`COLUMNS`] lists them with their Parquet type,
//! unit and source; the README's *Run catalogue* table is the same list.
//! Non-finite numbers are written as null.
//!
//! Layer rule: may use `input_file`, `record`.

pub mod file;
mod from_recording;

pub use from_recording::{row_of_recording, CatalogueError, ResultReads, RESULT_READS};

use std::path::{Path, PathBuf};

/// The directory beside the recordings that holds one row file per run.
pub const CATALOGUE_DIR: &str = "catalogue";

/// A campaign directory's journal: what makes a directory a campaign's
/// for `bench catalogue` and `bench upload` (`crate::campaign` lays its
/// directory out with these names).
pub const CAMPAIGN_JOURNAL_FILE: &str = "journal.jsonl";
/// A campaign's cells, each in `cells/NNN/`.
pub const CAMPAIGN_CELLS_DIR: &str = "cells";
/// A cell's recording, in its directory.
pub const CELL_RECORDING_FILE: &str = "chirp.mcap";

/// A campaign cell's row, relative to the campaign directory:
/// `catalogue/cell-NNN.parquet` (the campaign's own catalogue folder).
pub fn cell_row(index: usize) -> String {
    format!("{CATALOGUE_DIR}/cell-{index:03}.parquet")
}

/// A campaign cell's directory, relative to the campaign directory:
/// `cells/NNN`.
pub fn cell_dir(index: usize) -> String {
    format!("{CAMPAIGN_CELLS_DIR}/{index:03}")
}

/// The recording, relative to the campaign directory, of the cell whose
/// row file is named `row_name` (`cell-003.parquet` → `cells/003/chirp.mcap`);
/// `None` for another name.
pub fn cell_recording_of_row(row_name: &str) -> Option<PathBuf> {
    let n = row_name.strip_prefix("cell-")?.strip_suffix(".parquet")?;
    (!n.is_empty() && n.bytes().all(|b| b.is_ascii_digit())).then(|| {
        Path::new(CAMPAIGN_CELLS_DIR)
            .join(n)
            .join(CELL_RECORDING_FILE)
    })
}

/// The default name of the compacted catalogue `bench catalogue` writes
/// in the recordings directory (beside [`CATALOGUE_DIR`], not in it, so a
/// query over `catalogue/*.parquet` never counts a run twice).
pub const COMPACTED_NAME: &str = "catalogue.parquet";

/// How a run ended, as the catalogue's `outcome` column names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// The job ran to its end and recorded its results.
    Ok,
    /// The supervisor latched a fault (`fault_kind` names it; `hal` for a
    /// hardware error): 0 A, amplifier disabled.
    Fault,
    /// The loop ended without a fault and without the job's results: its
    /// tick budget ran out, or its results could not be computed; or the
    /// run was killed (its recording recovered by `bench recover`).
    Error,
    /// Stopped by SIGINT/SIGTERM, `stop`, or a daemon client that left.
    Stopped,
}

impl Outcome {
    /// The name in the catalogue: `ok`, `fault`, `error`, `stopped`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Ok => "ok",
            Self::Fault => "fault",
            Self::Error => "error",
            Self::Stopped => "stopped",
        }
    }
}

/// A column's Parquet type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColumnType {
    /// `INT64`, logical type `TIMESTAMP(MICROS, isAdjustedToUTC = true)`:
    /// DuckDB's `TIMESTAMP WITH TIME ZONE`, pandas' `datetime64[us, UTC]`.
    TimestampUtc,
    /// `BYTE_ARRAY`, logical type `STRING` (UTF-8).
    Text,
    /// `DOUBLE`.
    Real,
    /// `BOOLEAN`.
    Flag,
    /// `INT64`, logical type `INTEGER(64, unsigned)` (DuckDB `UBIGINT`).
    Unsigned,
    /// `INT64`.
    Count,
}

impl ColumnType {
    /// The type as the README's table names it.
    pub fn name(self) -> &'static str {
        match self {
            Self::TimestampUtc => "timestamp (µs, UTC)",
            Self::Text => "string",
            Self::Real => "double",
            Self::Flag => "boolean",
            Self::Unsigned => "uint64",
            Self::Count => "int64",
        }
    }
}

/// One cell: its column's type and the value, `None` for null.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// µs since the Unix epoch, UTC.
    TimestampUtc(Option<i64>),
    /// A string.
    Text(Option<String>),
    /// A real (never non-finite: those are null).
    Real(Option<f64>),
    /// A boolean.
    Flag(Option<bool>),
    /// An unsigned integer.
    Unsigned(Option<u64>),
    /// A signed integer.
    Count(Option<i64>),
}

impl Value {
    /// The column type.
    pub fn column_type(&self) -> ColumnType {
        match self {
            Self::TimestampUtc(_) => ColumnType::TimestampUtc,
            Self::Text(_) => ColumnType::Text,
            Self::Real(_) => ColumnType::Real,
            Self::Flag(_) => ColumnType::Flag,
            Self::Unsigned(_) => ColumnType::Unsigned,
            Self::Count(_) => ColumnType::Count,
        }
    }

    /// Whether the cell is null.
    pub fn is_null(&self) -> bool {
        match self {
            Self::TimestampUtc(v) => v.is_none(),
            Self::Text(v) => v.is_none(),
            Self::Real(v) => v.is_none(),
            Self::Flag(v) => v.is_none(),
            Self::Unsigned(v) => v.is_none(),
            Self::Count(v) => v.is_none(),
        }
    }
}

/// A real as the catalogue keeps it: `None` unless finite.
pub(crate) fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

/// The modes of a fit the catalogue has columns for (`mode1_…` to
/// `mode4_…`, ascending in frequency); `fit_modes` counts them all.
pub const MODE_COLUMNS: usize = 4;

/// One run: the catalogue's row. Field names are the column names; see
/// [`COLUMNS`] for each one's unit and source.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CatalogueRow {
    /// Start of the run, µs since the Unix epoch (UTC).
    pub start_utc_us: Option<i64>,
    /// Host name of the machine that ran it.
    pub host: Option<String>,
    /// The bench: the config file's stem (`sr4dof-ch5`).
    pub bench_name: Option<String>,
    /// SHA-256 (hex) of the resolved config TOML.
    pub config_sha256: Option<String>,
    /// Version of `bench` that ran it.
    pub bench_version: Option<String>,
    /// The job: `chirp` or `control`.
    pub job_kind: Option<String>,
    /// The backend that ran it (`sim:sr4dof`, …).
    pub backend: Option<String>,
    /// `virtual`, `paced` or `realtime`.
    pub pacing: Option<String>,
    /// Loop rate, Hz.
    pub rate_hz: Option<f64>,
    /// Operating point Y1o, m.
    pub operating_point_m: Option<f64>,
    /// Y1o / L.
    pub operating_point_fraction_of_l: Option<f64>,
    /// Mass asymmetry Δm23 = m2/m3 − 1.
    pub mass_asymmetry: Option<f64>,
    /// Simulator seed.
    pub seed: Option<u64>,
    /// Loop time the run lasted, s.
    pub duration_s: Option<f64>,
    /// How it ended ([`Outcome::as_str`]).
    pub outcome: Option<String>,
    /// The fault that ended it.
    pub fault_kind: Option<String>,
    /// Modes of the chirp's modal fit.
    pub fit_modes: Option<i64>,
    /// Natural frequencies of the first [`MODE_COLUMNS`] fitted modes, Hz.
    pub mode_frequency_hz: [Option<f64>; MODE_COLUMNS],
    /// Their damping ratios.
    pub mode_damping_ratio: [Option<f64>; MODE_COLUMNS],
    /// The closely spaced pair's lower mode (`u`), Hz.
    pub pair_u_frequency_hz: Option<f64>,
    /// Its upper mode (`v`), Hz.
    pub pair_v_frequency_hz: Option<f64>,
    /// The fit passed its checks.
    pub fit_trusted: Option<bool>,
    /// The measured CMP-CNMP verdict (null: undecided).
    pub verdict_cmp_cnmp: Option<bool>,
    /// The configured model's CMP-CNMP answer.
    pub model_cmp_cnmp: Option<bool>,
    /// Largest |x1| of the chirp, m.
    pub peak_position_m: Option<f64>,
    /// The controller of a control run.
    pub controller: Option<String>,
    /// The loop check passed.
    pub loop_check_passed: Option<bool>,
    /// First gain crossover, rad/s.
    pub crossover_rad_s: Option<f64>,
    /// Phase margin there, degrees.
    pub phase_margin_deg: Option<f64>,
    /// Gain margin, dB.
    pub gain_margin_db: Option<f64>,
    /// Modulus margin 1 / ‖S‖∞.
    pub modulus_margin: Option<f64>,
    /// Step size, m.
    pub step_m: Option<f64>,
    /// 10–90 % rise time, s.
    pub rise_time_s: Option<f64>,
    /// 2 % settling time, s.
    pub settling_time_s: Option<f64>,
    /// Overshoot, % of the step.
    pub overshoot_pct: Option<f64>,
    /// Steady-state positioning noise (1σ of the error), m.
    pub steady_state_error_std_m: Option<f64>,
    /// Largest |command|, A.
    pub peak_command_a: Option<f64>,
    /// `--verify` disagreed with the prediction (null without `--verify`).
    pub verify_flagged: Option<bool>,
    /// The recording: its absolute path (or object URL).
    pub recording: Option<String>,
}

/// A column: name, type, unit and where its value comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Column {
    /// The column's name.
    pub name: &'static str,
    /// Its Parquet type.
    pub column_type: ColumnType,
    /// Its unit (`—` for names, flags and counts).
    pub unit: &'static str,
    /// Where the value comes from in the recording.
    pub source: &'static str,
}

const fn col(
    name: &'static str,
    column_type: ColumnType,
    unit: &'static str,
    source: &'static str,
) -> Column {
    Column {
        name,
        column_type,
        unit,
        source,
    }
}

use ColumnType::{Count, Flag, Real, Text, TimestampUtc, Unsigned};

/// Every column, in file order (the README's *Run catalogue* table).
pub const COLUMNS: &[Column] = &[
    col("start_utc", TimestampUtc, "instant (UTC)", "`bench.run` `start_time_unix_ns`: the run's start"),
    col("host", Text, "—", "`bench.run` `host`"),
    col("bench_name", Text, "—", "the stem of `bench.config` `path` (`bench-config/sr4dof-ch2.toml` → `sr4dof-ch2`; the built-in bench → `sr4dof-ch5`)"),
    col("config_sha256", Text, "—", "`bench.run` `config_sha256`: SHA-256 (hex) of the resolved config TOML"),
    col("bench_version", Text, "—", "`bench.run` `version`"),
    col("job_kind", Text, "—", "`bench.run` `command`: `chirp` or `control`"),
    col("backend", Text, "—", "`bench.run` `backend` (`sim:sr4dof`, `serial:…`, `can:…`)"),
    col("pacing", Text, "—", "`bench.run` `mode`: `virtual`, `paced` or `realtime`"),
    col("rate_hz", Real, "Hz", "`bench.run` `rate_hz`"),
    col("operating_point_m", Real, "m", "`plant.operating_point_m` of `bench.config` `toml`"),
    col("operating_point_fraction_of_l", Real, "1", "`plant.operating_point_m` / `plant.beam.length_m`"),
    col("mass_asymmetry", Real, "1", "`plant.mass_asymmetry` (Δm23 = m2/m3 − 1)"),
    col("seed", Unsigned, "—", "`bench.run` `seed`"),
    col("duration_s", Real, "s", "loop time: the `loop_stopped` event's `t_s` (ticks × period); null when the loop never stopped (a killed run's recording recovered by `bench recover`)"),
    col("outcome", Text, "—", "`ok` (the job's summary is recorded), `fault` (a `fault` event), `stopped` (an `interrupted` event), `error` (none of these: the tick budget ran out, no result could be computed, or the run was killed and its recording recovered by `bench recover`)"),
    col("fault_kind", Text, "—", "the first `fault` event's `fault` (`position_limit`, `i2t`, `hal`, …)"),
    col("fit_modes", Count, "—", "chirp: modes of the modal fit (`/sysid/summary` `fit.modes`)"),
    col("mode1_frequency_hz", Real, "Hz", "chirp: the fit's 1st mode by frequency, `frequency_hz`"),
    col("mode2_frequency_hz", Real, "Hz", "chirp: its 2nd mode"),
    col("mode3_frequency_hz", Real, "Hz", "chirp: its 3rd mode"),
    col("mode4_frequency_hz", Real, "Hz", "chirp: its 4th mode"),
    col("mode1_damping_ratio", Real, "1", "chirp: the 1st mode's `damping_ratio`"),
    col("mode2_damping_ratio", Real, "1", "chirp: the 2nd mode's"),
    col("mode3_damping_ratio", Real, "1", "chirp: the 3rd mode's"),
    col("mode4_damping_ratio", Real, "1", "chirp: the 4th mode's"),
    col("pair_u_frequency_hz", Real, "Hz", "chirp: the fitted mode labelled `u` (the closely spaced pair's lower)"),
    col("pair_v_frequency_hz", Real, "Hz", "chirp: the mode labelled `v` (its upper)"),
    col("fit_trusted", Flag, "—", "chirp: `fit.quality` checked and no flag"),
    col("verdict_cmp_cnmp", Flag, "—", "chirp: `cmp_cnmp`, the measured verdict (null: undecided)"),
    col("model_cmp_cnmp", Flag, "—", "chirp: `model.cmp_cnmp`, the configured model's answer"),
    col("peak_position_m", Real, "m", "chirp: `peak_position_m`, the largest |x1|"),
    col("controller", Text, "—", "control: `/control/loop_check` `controller`"),
    col("loop_check_passed", Flag, "—", "control: the loop check has no `failures`"),
    col("crossover_rad_s", Real, "rad/s", "control: `model.crossovers_rad_s[0]` of the loop check (model, amplifier included)"),
    col("phase_margin_deg", Real, "deg", "control: `model.phase_margin_deg`"),
    col("gain_margin_db", Real, "dB", "control: `model.gain_margin_db`"),
    col("modulus_margin", Real, "1", "control: 1 / `model.sensitivity_peak` (1 / ‖S‖∞)"),
    col("step_m", Real, "m", "control: `/control/metrics` `step_m`"),
    col("rise_time_s", Real, "s", "control: `rise_time_s` (10–90 %)"),
    col("settling_time_s", Real, "s", "control: `settling_time_s` (2 %)"),
    col("overshoot_pct", Real, "% of the step", "control: `overshoot_pct`"),
    col("steady_state_error_std_m", Real, "m", "control: `steady_state_error_std_nm` × 1e-9"),
    col("peak_command_a", Real, "A", "control: `peak_command_a`"),
    col("verify_flagged", Flag, "—", "control `--verify`: `/control/summary` `verify.result.flagged` (null without `--verify`)"),
    col("recording", Text, "—", "the recording's absolute path (`bench catalogue --recording-url`: its object's URL)"),
];

impl CatalogueRow {
    /// The row's cells in [`COLUMNS`] order.
    pub fn values(&self) -> Vec<Value> {
        let r = |x: Option<f64>| Value::Real(x.and_then(finite));
        let t = |x: &Option<String>| Value::Text(x.clone());
        let mut v = vec![
            Value::TimestampUtc(self.start_utc_us),
            t(&self.host),
            t(&self.bench_name),
            t(&self.config_sha256),
            t(&self.bench_version),
            t(&self.job_kind),
            t(&self.backend),
            t(&self.pacing),
            r(self.rate_hz),
            r(self.operating_point_m),
            r(self.operating_point_fraction_of_l),
            r(self.mass_asymmetry),
            Value::Unsigned(self.seed),
            r(self.duration_s),
            t(&self.outcome),
            t(&self.fault_kind),
            Value::Count(self.fit_modes),
        ];
        v.extend(self.mode_frequency_hz.iter().map(|x| r(*x)));
        v.extend(self.mode_damping_ratio.iter().map(|x| r(*x)));
        v.extend([
            r(self.pair_u_frequency_hz),
            r(self.pair_v_frequency_hz),
            Value::Flag(self.fit_trusted),
            Value::Flag(self.verdict_cmp_cnmp),
            Value::Flag(self.model_cmp_cnmp),
            r(self.peak_position_m),
            t(&self.controller),
            Value::Flag(self.loop_check_passed),
            r(self.crossover_rad_s),
            r(self.phase_margin_deg),
            r(self.gain_margin_db),
            r(self.modulus_margin),
            r(self.step_m),
            r(self.rise_time_s),
            r(self.settling_time_s),
            r(self.overshoot_pct),
            r(self.steady_state_error_std_m),
            r(self.peak_command_a),
            Value::Flag(self.verify_flagged),
            t(&self.recording),
        ]);
        v
    }
}

/// Where a run's own row goes: `<dir>/catalogue/<stem>.parquet` for the
/// recording `<dir>/<stem>.mcap`.
pub fn row_path(recording: &Path) -> PathBuf {
    let dir = recording.parent().unwrap_or(Path::new(""));
    let name = recording
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let stem = name.strip_suffix(".mcap").unwrap_or(&name);
    dir.join(CATALOGUE_DIR).join(format!("{stem}.parquet"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_columns_and_the_row_agree_in_number_and_type() {
        let values = CatalogueRow::default().values();
        assert_eq!(values.len(), COLUMNS.len());
        for (v, c) in values.iter().zip(COLUMNS) {
            assert_eq!(v.column_type(), c.column_type, "{}", c.name);
            assert!(v.is_null(), "{}", c.name);
        }
        let mut names: Vec<&str> = COLUMNS.iter().map(|c| c.name).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), COLUMNS.len(), "a column name twice");
    }

    #[test]
    fn a_row_file_sits_in_the_catalogue_directory_beside_its_recording() {
        assert_eq!(
            row_path(Path::new("/r/chirp-20261124T041336.739Z.mcap")),
            Path::new("/r/catalogue/chirp-20261124T041336.739Z.parquet")
        );
        assert_eq!(
            row_path(Path::new("run.mcap")),
            Path::new("catalogue/run.parquet")
        );
    }
}
