//! The run catalogue as jobs ([`crate::catalogue`]): the row every chirp
//! and control run appends when its recording is finished
//! ([`append_run`], [`catalogue_ended_run`]), and `bench catalogue`, which
//! rebuilds one compacted catalogue from a directory's recordings
//! ([`run_catalogue`]).
//!
//! A run's row never fails the run: a row that cannot be written is a
//! warning (on stderr, in the daemon's log, and in the summary's
//! `catalogue.warning`), and the run's outcome and exit status are the
//! run's own.

use crate::catalogue::file::{in_column_order, write_rows, write_values};
use crate::catalogue::{row_of_recording, row_path, CatalogueError, CatalogueRow, Value, COLUMNS};
use crate::error::RunError;
use crate::outputs::{
    write_buffered_atomically, Destination, Existing, Origin, OutputPlan, DIR_MODE,
};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A run's row in the catalogue, as the run's summary reports it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct CatalogueEntry {
    /// The row's file, `<recordings>/catalogue/<recording stem>.parquet`;
    /// `null` when it could not be written.
    pub row: Option<PathBuf>,
    /// Why the row could not be written (the run itself is unaffected;
    /// `bench catalogue` rebuilds the catalogue from the recordings);
    /// absent when it was.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warning: Option<String>,
}

impl CatalogueEntry {
    /// The summary's line: `catalogue   PATH`, or why there is none.
    pub fn line(&self) -> String {
        match (&self.row, &self.warning) {
            (Some(p), _) => format!("catalogue   {}", p.display()),
            (None, Some(w)) => format!("catalogue   not written: {w}"),
            (None, None) => "catalogue   not written".to_string(),
        }
    }
}

/// Appends the row of the finished recording `recording` to the
/// catalogue beside it: reads the row from the recording
/// ([`row_of_recording`]) and writes it atomically to [`row_path`]
/// (creating the `catalogue` directory with mode [`DIR_MODE`]; a row of
/// the same name, from a recording since replaced with `--overwrite`, is
/// replaced). Returns the row's file.
///
/// # Errors
/// [`CatalogueError`]: the recording cannot be read, or the row cannot
/// be written.
pub fn append_run(recording: &Path) -> Result<PathBuf, CatalogueError> {
    let row = row_of_recording(recording)?;
    write_row_file(&row, &row_path(recording))
}

/// Writes `row` alone to the row file `path`, atomically (creating its
/// directory with mode [`DIR_MODE`]; an existing file is replaced).
/// Returns `path`, absolute.
///
/// # Errors
/// [`CatalogueError::Write`].
pub fn write_row_file(row: &CatalogueRow, path: &Path) -> Result<PathBuf, CatalogueError> {
    let write = |source| CatalogueError::Write {
        path: path.to_path_buf(),
        source,
    };
    if let Some(dir) = path.parent() {
        use std::os::unix::fs::DirBuilderExt;
        std::fs::DirBuilder::new()
            .recursive(true)
            .mode(DIR_MODE)
            .create(dir)
            .map_err(write)?;
    }
    write_buffered_atomically(path, Existing::Replace, |w| {
        write_rows(std::slice::from_ref(row), w)
    })
    .map_err(write)?;
    Ok(std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf()))
}

/// A campaign cell's row: read from the cell's finished `recording` and
/// written to `row_file` (the campaign's `catalogue/cell-NNN.parquet`),
/// its `recording` the recording's absolute path when the campaign keeps
/// it, else null (the cell's results are in the row, its recording is
/// about to be removed). Never fails the cell: a failure is a warning,
/// logged and returned.
pub fn catalogue_cell(recording: &Path, row_file: &Path, keeps_recording: bool) -> CatalogueEntry {
    let written = row_of_recording(recording).and_then(|mut row| {
        if !keeps_recording {
            row.recording = None;
        }
        write_row_file(&row, row_file)
    });
    entry_of(written, "the cell is unaffected")
}

/// A row's file as the run or cell reports it, or the warning (logged:
/// the row was not written; `unaffected` says what is not) that never
/// fails it.
fn entry_of(written: Result<PathBuf, CatalogueError>, unaffected: &str) -> CatalogueEntry {
    match written {
        Ok(row) => CatalogueEntry {
            row: Some(row),
            warning: None,
        },
        Err(e) => {
            let warning = crate::error::error_chain(&e);
            tracing::warn!("the catalogue row was not written: {warning}; {unaffected}");
            CatalogueEntry {
                row: None,
                warning: Some(warning),
            }
        }
    }
}

/// [`append_run`] as a run reports it: the row, or a warning (logged,
/// and returned for the summary) that never fails the run.
pub fn catalogue_run(recording: &Path) -> CatalogueEntry {
    entry_of(
        append_run(recording),
        "the run is unaffected (`bench catalogue` rebuilds the catalogue from the recordings)",
    )
}

/// The row of a run that ended with `error`: appended when the error
/// says its recording was finished (a fault, a hardware error, a stop, the
/// tick budget); nothing otherwise (the run never started, or its
/// recording is incomplete). A failure is a warning only.
pub fn catalogue_ended_run(error: &RunError, recording: &Path) {
    let finished = match error {
        RunError::Fault { recording: r, .. }
        | RunError::Hal { recording: r, .. }
        | RunError::Interrupted { recording: r, .. }
        | RunError::TickLimit { recording: r, .. } => Path::new(r) == recording,
        _ => false,
    };
    if finished {
        catalogue_run(recording);
    }
}

/// The `--json` summary of a run that ended with `error` and without its
/// job's summary ([`RunError::summary_json`]: outcome, fault, recording),
/// with the run's catalogue row as an ok run's summary names it
/// (`"catalogue": {"row": PATH}`) when its finished recording has one.
/// The local CLI prints it, and the daemon answers with it
/// (`error.summary`), so that a client's `--json` is the same either way.
/// `None` for errors before anything ran.
pub fn ended_run_summary(error: &RunError) -> Option<serde_json::Value> {
    let mut v = error.summary_json()?;
    let row = v
        .get("recording")
        .and_then(|r| r.as_str())
        .map(|r| row_path(Path::new(r)))
        .filter(|p| p.is_file());
    if let (Some(o), Some(row)) = (v.as_object_mut(), row) {
        let row = std::path::absolute(&row).unwrap_or(row);
        o.insert("catalogue".into(), serde_json::json!({ "row": row }));
    }
    Some(v)
}

/// `bench catalogue` as a job request (the daemon's `catalogue`; the CLI
/// runs [`CatalogueOptions`] made from its flags).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CatalogueRequest {
    /// The directory whose recordings are catalogued (the daemon takes an
    /// absolute path); `None`: the runner's recordings directory (the
    /// daemon's `--recordings`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recordings: Option<PathBuf>,
    /// Where the recordings are kept as objects (`s3://lab-bench/recordings`):
    /// each row's `recording` is then this prefix and the file's name
    /// ([`object_url`]) instead of its local path.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recording_url: Option<String>,
}

/// What `bench catalogue` rebuilds.
#[derive(Debug, Clone)]
pub struct CatalogueOptions {
    /// The directory whose recordings (`*.mcap`, not the `.part` of a
    /// running or killed run) are catalogued, with its subdirectories
    /// ([`sources_in`]: campaign cells).
    pub recordings: PathBuf,
    /// The compacted catalogue to write (a `.parquet` file).
    pub out: PathBuf,
    /// Where `out` came from (for the messages).
    pub out_origin: Origin,
    /// What to do with an existing `out`.
    pub existing: Existing,
    /// The recordings' object prefix, if they are kept in a bucket (see
    /// [`CatalogueRequest::recording_url`]).
    pub recording_url: Option<String>,
}

/// The catalogue of `request` with its file where `dest` puts it. The
/// recordings catalogued: the request's directory, else locally the
/// default recordings directory
/// ([`crate::outputs::default_recordings`]) and on the daemon its own
/// (where its stem is). The file: locally `--out`, else
/// `catalogue.parquet` in that directory; on the daemon its stamped name.
/// The command line and the daemon both plan a catalogue here.
///
/// # Errors
/// [`RunError::BadOption`] naming `recordings` when there is no default
/// recordings directory.
pub fn plan_catalogue(
    request: CatalogueRequest,
    dest: &Destination,
) -> Result<CatalogueOptions, RunError> {
    let recordings = match (request.recordings, dest) {
        (Some(dir), _) => dir,
        (None, Destination::Daemon { stem }) => {
            stem.parent().map(Path::to_path_buf).unwrap_or_default()
        }
        (None, Destination::Local { .. }) => {
            crate::outputs::default_recordings(false, "--recordings DIR")
                .map_err(|reason| RunError::option("recordings", "", reason))?
        }
    };
    let (out, out_origin) = dest.output("out", ".parquet", || {
        Ok(recordings.join(crate::catalogue::COMPACTED_NAME))
    })?;
    Ok(CatalogueOptions {
        recordings,
        out,
        out_origin,
        existing: dest.existing(),
        recording_url: request.recording_url,
    })
}

/// The object URL of the file `name` under `prefix`: `prefix/name`, one
/// `/` between them, the name percent-encoded but for RFC 3986's
/// unreserved characters (`A–Z a–z 0–9 - . _ ~`).
pub fn object_url(prefix: &str, name: &str) -> String {
    let mut url = prefix.trim_end_matches('/').to_string();
    url.push('/');
    for b in name.bytes() {
        if b.is_ascii_alphanumeric() || b"-._~".contains(&b) {
            url.push(char::from(b));
        } else {
            url.push_str(&format!("%{b:02X}"));
        }
    }
    url
}

/// The object URL of the file at `rel` (a path relative to the
/// recordings directory) under `prefix`: [`object_url`] of each path
/// segment, joined by `/`.
pub fn object_url_of_path(prefix: &str, rel: &Path) -> String {
    let mut url = prefix.trim_end_matches('/').to_string();
    for c in rel.components() {
        url = object_url(&url, &c.as_os_str().to_string_lossy());
    }
    url
}

/// Index of the column `name` in [`COLUMNS`] (one of its names).
fn column(name: &str) -> usize {
    COLUMNS
        .iter()
        .position(|c| c.name == name)
        .unwrap_or_else(|| unreachable!("{name} is a catalogue column"))
}

/// Checks a recordings' object prefix: `SCHEME://REST`, the scheme a
/// letter then letters, digits, `+`, `-` or `.` (RFC 3986), something
/// after `://`, and no space or control character.
///
/// # Errors
/// [`RunError::BadOption`] naming `recording_url` and the reason.
pub fn check_recording_url(url: &str) -> Result<(), RunError> {
    let bad = |reason: &str| RunError::option("recording_url", url, reason);
    let Some((scheme, rest)) = url.split_once("://") else {
        return Err(bad(
            "is not a URL prefix SCHEME://…, e.g. s3://lab-bench/recordings",
        ));
    };
    let mut chars = scheme.chars();
    let scheme_ok = chars.next().is_some_and(|c| c.is_ascii_alphabetic())
        && chars.all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c));
    if !scheme_ok {
        return Err(bad(&format!(
            "{scheme:?} is not a URL scheme (a letter, then letters, digits, +, - or .)"
        )));
    }
    if rest.trim_matches('/').is_empty() {
        return Err(bad(
            "names no bucket or host after :// (a URL prefix such as s3://lab-bench/recordings)",
        ));
    }
    if url.chars().any(|c| c.is_whitespace() || c.is_control()) {
        return Err(bad(
            "holds a space or a control character, which a URL prefix cannot",
        ));
    }
    Ok(())
}

/// A recording left out of the rebuilt catalogue.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct SkippedRecording {
    /// The recording.
    pub recording: PathBuf,
    /// Why it gave no row.
    pub reason: String,
}

/// The result of `bench catalogue`.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct CatalogueSummary {
    /// The catalogue written (absolute).
    pub catalogue: PathBuf,
    /// The directory read (absolute).
    pub recordings: PathBuf,
    /// Rows written: one per recording read, and one per campaign cell
    /// whose recording the campaign did not keep (`carried`).
    pub rows: usize,
    /// Rows of campaign cells whose recordings were not kept (`keep =
    /// "frf"` or `"summary"`): not rebuilt (there is no recording) but taken
    /// as they are from the campaign's `catalogue/` folder.
    #[serde(default)]
    pub carried: usize,
    /// Rows by outcome (`ok`, `fault`, `error`, `stopped`).
    pub outcomes: BTreeMap<String, usize>,
    /// Recordings that gave no row (unreadable, not MCAP, not finished, not
    /// a recording of bench), each with the reason.
    pub skipped: Vec<SkippedRecording>,
    /// Wall time of the rebuild, s.
    pub elapsed_s: f64,
}

impl CatalogueSummary {
    /// The printed summary.
    pub fn lines(&self) -> Vec<String> {
        let mut v = vec![
            format!(
                "catalogue of {}: {} runs ({}) in {:.2} s",
                self.recordings.display(),
                self.rows,
                if self.outcomes.is_empty() {
                    "none".to_string()
                } else {
                    self.outcomes
                        .iter()
                        .map(|(k, n)| format!("{n} {k}"))
                        .collect::<Vec<_>>()
                        .join(", ")
                },
                self.elapsed_s
            ),
            format!("  catalogue   {}", self.catalogue.display()),
        ];
        if self.carried > 0 {
            v.push(format!(
                "  {} of them campaign cells whose recordings were not kept (their rows taken from the campaigns' catalogue folders)",
                self.carried
            ));
        }
        if !self.skipped.is_empty() {
            v.push(format!(
                "  skipped {} recording(s) that gave no row:",
                self.skipped.len()
            ));
            for s in &self.skipped {
                v.push(format!("    {}: {}", s.recording.display(), s.reason));
            }
        }
        v
    }
}

/// How deep `bench catalogue` looks below its recordings directory (a
/// daemon's campaign cell is `DIR/campaign-…/cells/NNN/chirp.mcap`, 3 below).
pub const MAX_DEPTH: usize = 8;

/// What `bench catalogue` reads below a directory ([`sources_in`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CatalogueSources {
    /// Every regular `*.mcap` file (not a link, not a `.part`), in this
    /// directory and its subdirectories (campaign cells), sorted by path.
    pub recordings: Vec<PathBuf>,
    /// The row files of campaigns' catalogue folders
    /// (`CAMPAIGN/catalogue/*.parquet`, a campaign directory being one
    /// with a campaign journal), sorted by path.
    pub campaign_rows: Vec<PathBuf>,
    /// Subdirectories that could not be read, with the reason.
    pub unreadable: Vec<SkippedRecording>,
}

/// The recordings and campaign rows `bench catalogue` reads under `dir`,
/// at most [`MAX_DEPTH`] directories down; links are not followed, and a
/// recordings directory's own `catalogue/` folder (the per-run rows,
/// which the rebuild replaces) is not read.
///
/// # Errors
/// [`RunError::BadOption`] naming `recordings` when `dir` itself cannot
/// be read (a subdirectory that cannot is listed in `unreadable`).
pub fn sources_in(dir: &Path) -> Result<CatalogueSources, RunError> {
    let mut out = CatalogueSources::default();
    walk(dir, 0, &mut out)
        .map_err(|e| RunError::option("recordings", dir.display(), e.to_string()))?;
    out.recordings.sort();
    out.campaign_rows.sort();
    Ok(out)
}

fn walk(dir: &Path, depth: usize, out: &mut CatalogueSources) -> std::io::Result<()> {
    let campaign = dir.join(crate::catalogue::CAMPAIGN_JOURNAL_FILE).is_file();
    for e in std::fs::read_dir(dir)? {
        let e = e?;
        let path = e.path();
        let Ok(t) = e.file_type() else { continue };
        if t.is_file() && path.extension().is_some_and(|x| x == "mcap") {
            out.recordings.push(path);
        } else if t.is_dir() && e.file_name() == crate::catalogue::CATALOGUE_DIR {
            if campaign {
                let rows = std::fs::read_dir(&path).and_then(|d| {
                    d.map(|e| e.map(|e| (e.path(), e.file_type())))
                        .collect::<std::io::Result<Vec<_>>>()
                });
                match rows {
                    Ok(rows) => out
                        .campaign_rows
                        .extend(rows.into_iter().filter_map(|(p, t)| {
                            (t.is_ok_and(|t| t.is_file())
                                && p.extension().is_some_and(|x| x == "parquet"))
                            .then_some(p)
                        })),
                    Err(e) => out.unreadable.push(SkippedRecording {
                        recording: path,
                        reason: e.to_string(),
                    }),
                }
            }
        } else if t.is_dir() && depth < MAX_DEPTH {
            if let Err(e) = walk(&path, depth + 1, out) {
                out.unreadable.push(SkippedRecording {
                    recording: path,
                    reason: e.to_string(),
                });
            }
        }
    }
    Ok(())
}

/// Checks the options of `bench catalogue` before anything is read:
/// the recordings directory exists, `out` is a `.parquet` file that may be
/// written (the rules of [`crate::outputs`]).
///
/// # Errors
/// [`RunError::BadOption`] naming `recordings` or `out` and the reason.
pub fn check_options(opts: &CatalogueOptions) -> Result<(), RunError> {
    let dir = &opts.recordings;
    match dir.metadata() {
        Ok(m) if m.is_dir() => {}
        Ok(_) => {
            return Err(RunError::option(
                "recordings",
                dir.display(),
                "is not a directory",
            ))
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(RunError::option(
                "recordings",
                dir.display(),
                "does not exist",
            ))
        }
        Err(e) => return Err(RunError::option("recordings", dir.display(), e.to_string())),
    }
    if let Some(url) = &opts.recording_url {
        check_recording_url(url)?;
    }
    if opts.out.extension().and_then(|e| e.to_str()) != Some("parquet") {
        return Err(RunError::option(
            "out",
            opts.out.display(),
            "the catalogue must end in .parquet",
        ));
    }
    OutputPlan::new(opts.existing)
        .derived_from("--recordings")
        .with_output("out", &opts.out, opts.out_origin)
        .check()
}

/// `bench catalogue`: one row per recording of `opts.recordings` (as
/// each run appended it: [`row_of_recording`]; with
/// `opts.recording_url`, `recording` is the object's URL), sorted by start time,
/// written atomically to `opts.out` as one Parquet file. A recording that
/// gives no row is skipped, named and counted in the summary, never a
/// failure of the rebuild.
///
/// # Errors
/// [`RunError::BadOption`] naming `recordings` or `out` (see
/// [`check_options`]); [`RunError::Output`] when the catalogue cannot be
/// written.
pub fn run_catalogue(opts: &CatalogueOptions) -> Result<CatalogueSummary, RunError> {
    let started = Instant::now();
    check_options(opts)?;
    let sources = sources_in(&opts.recordings)?;
    // Never written over a file it reads (rule 6 of crate::outputs): a
    // campaign's row, or a recording under another name (a hard link).
    OutputPlan::new(opts.existing)
        .with_output("out", &opts.out, opts.out_origin)
        .with_inputs("recordings", &sources.campaign_rows)
        .with_inputs("recordings", &sources.recordings)
        .check()?;
    let recordings = &sources.recordings;
    let read: Vec<Result<CatalogueRow, CatalogueError>> = {
        use rayon::prelude::*;
        recordings.par_iter().map(|p| row_of_recording(p)).collect()
    };
    let mut rows: Vec<Vec<Value>> = Vec::with_capacity(read.len());
    let mut skipped = sources.unreadable.clone();
    for (path, r) in recordings.iter().zip(read) {
        match r {
            Ok(mut row) => {
                if let Some(url) = &opts.recording_url {
                    let rel = path.strip_prefix(&opts.recordings).unwrap_or(path);
                    row.recording = Some(object_url_of_path(url, rel));
                }
                rows.push(row.values())
            }
            Err(e) => {
                let reason = match &e {
                    CatalogueError::Io { source, .. } => source.to_string(),
                    CatalogueError::Recording { reason, .. } => reason.clone(),
                    CatalogueError::Write { source, .. } => source.to_string(),
                };
                tracing::warn!("skipped {}: {reason}", path.display());
                skipped.push(SkippedRecording {
                    recording: std::path::absolute(path).unwrap_or_else(|_| path.clone()),
                    reason,
                });
            }
        }
    }
    // Campaign cells whose recordings were not kept: their rows as the
    // campaign wrote them (the others are rebuilt from their recordings).
    let (start_col, outcome_col, recording_col) =
        (column("start_utc"), column("outcome"), column("recording"));
    let mut carried = 0;
    for path in &sources.campaign_rows {
        let read = crate::catalogue::file::read_rows(path).and_then(|rs| {
            rs.iter()
                .map(|r| {
                    in_column_order(r).ok_or_else(|| {
                        std::io::Error::other("its columns are not this catalogue's")
                    })
                })
                .collect::<std::io::Result<Vec<_>>>()
        });
        match read {
            Ok(read) => {
                for row in read {
                    if row[recording_col].is_null() {
                        rows.push(row);
                        carried += 1;
                    }
                }
            }
            Err(e) => {
                tracing::warn!("skipped {}: {e}", path.display());
                skipped.push(SkippedRecording {
                    recording: std::path::absolute(path).unwrap_or_else(|_| path.clone()),
                    reason: e.to_string(),
                });
            }
        }
    }
    // By start time (then the recording): a reader's time filter then
    // meets sorted statistics.
    let key = |r: &Vec<Value>| match (&r[start_col], &r[recording_col]) {
        (Value::TimestampUtc(t), Value::Text(rec)) => (*t, rec.clone()),
        _ => (None, None),
    };
    rows.sort_by_key(key);
    let mut outcomes = BTreeMap::new();
    for r in &rows {
        let outcome = match &r[outcome_col] {
            Value::Text(Some(o)) => o.clone(),
            _ => "unknown".into(),
        };
        *outcomes.entry(outcome).or_insert(0) += 1;
    }
    write_buffered_atomically(&opts.out, opts.existing, |w| write_values(&rows, w)).map_err(
        |e| RunError::Output {
            path: opts.out.clone(),
            reason: e.to_string(),
        },
    )?;
    let abs = |p: &Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    Ok(CatalogueSummary {
        catalogue: abs(&opts.out),
        recordings: abs(&opts.recordings),
        rows: rows.len(),
        carried,
        outcomes,
        skipped,
        elapsed_s: started.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_object_url_is_the_prefix_and_the_encoded_name() {
        assert_eq!(
            object_url("s3://lab/recordings/", "chirp-20261124T041336.739Z.mcap"),
            "s3://lab/recordings/chirp-20261124T041336.739Z.mcap"
        );
        assert_eq!(
            object_url("gs://b", "a b+ü.mcap"),
            "gs://b/a%20b%2B%C3%BC.mcap"
        );
    }

    #[test]
    fn a_recording_url_must_be_a_url_prefix() {
        for ok in [
            "s3://lab-bench/recordings",
            "https://minio.lab:9000/bench/",
            "gs://b",
        ] {
            assert!(check_recording_url(ok).is_ok(), "{ok}");
        }
        for bad in [
            "",
            "lab-bench/recordings",
            "s3://",
            "s3:///",
            "3s://b",
            "s 3://b",
            "s3://a b",
            "s3://a\tb",
            "://b",
        ] {
            let e = check_recording_url(bad).unwrap_err();
            assert!(
                matches!(
                    e,
                    RunError::BadOption {
                        key: "recording_url",
                        ..
                    }
                ),
                "{bad}: {e}"
            );
        }
    }
}
