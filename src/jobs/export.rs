//! `bench export` as a job: a recording's channel as a table
//! ([`crate::record::export`]), except that the FRF channel exported as CSV
//! is written in the FRF CSV format of `bench chirp`
//! (`frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz,sigma_dof`,
//! [`crate::ident::frf::Frf::write_csv_to`]), the one `bench fit`,
//! `bench design` and `bench control --frf` read: an exported FRF travels
//! to the other commands as it is. Parquet keeps the generic table
//! (`log_time_ns` and the fields, one row per line).

use crate::error::RunError;
use crate::ident::frf::read_frf;
use crate::outputs::{beside, write_atomically, Destination, Existing, OutputPlan};
use crate::record::export::{export, ExportError, ExportFormat};
use crate::record::TOPIC_FRF;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Exports `topic` of `recording` to `out` in `format` (see the module
/// docs); returns the rows written.
///
/// # Errors
/// [`ExportError`]: an unreadable recording or FRF payload, no such topic,
/// or an output that cannot be written.
pub fn export_topic(
    recording: &Path,
    topic: &str,
    format: ExportFormat,
    out: &Path,
    existing: Existing,
) -> Result<usize, ExportError> {
    if topic != TOPIC_FRF || format != ExportFormat::Csv {
        return export(recording, topic, format, out, existing);
    }
    let bytes = crate::record::export::read_recording(recording)?;
    // No FRF channel: the generic error, with the topics the recording has.
    let frf = match read_frf(&bytes) {
        Ok(r) => r.frf,
        Err(_) => return export(recording, topic, format, out, existing),
    };
    write_atomically(out, existing, |f| frf.write_csv_to(f)).map_err(|source| {
        ExportError::Output {
            path: out.to_path_buf(),
            source,
        }
    })?;
    Ok(frf.frequency_hz.len())
}

/// The channel exported when a request names none: one row per tick.
pub const DEFAULT_TOPIC: &str = crate::record::TOPIC_SAMPLE;

/// `bench export` as a job request (the daemon's `export`; the CLI makes
/// the same request from its flags).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExportRequest {
    /// The recording (`.mcap`, or the `.mcap.part` of a killed run; the
    /// daemon takes an absolute path).
    pub recording: PathBuf,
    /// The table format (`--to`).
    pub to: ExportFormat,
    /// The channel (`--topic`); `None`: [`DEFAULT_TOPIC`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub topic: Option<String>,
}

impl ExportRequest {
    /// The channel exported.
    pub fn topic(&self) -> &str {
        self.topic.as_deref().unwrap_or(DEFAULT_TOPIC)
    }

    /// `<stem>.<topic>.<csv|parquet>`'s suffix: the topic without its
    /// leading slash, `/` as `-`, only ASCII letters, digits, `-` and `_`.
    fn suffix(&self) -> String {
        let topic: String = self
            .topic()
            .trim_start_matches('/')
            .replace('/', "-")
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '_')
            .collect();
        format!(".{topic}.{}", self.to.extension())
    }
}

/// An export planned: the request and its checked output.
#[derive(Debug, Clone)]
pub struct ExportOptions {
    /// What to export.
    pub request: ExportRequest,
    /// The table written.
    pub out: PathBuf,
    /// Whether an existing `out` is replaced.
    pub existing: Existing,
}

/// What an export wrote (`bench export --json`, the daemon's answer).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ExportSummary {
    /// The recording read.
    pub recording: PathBuf,
    /// The channel exported.
    pub topic: String,
    /// The table's format.
    pub format: ExportFormat,
    /// The table written (absolute).
    pub out: PathBuf,
    /// Rows written: ticks, envelopes, events or frequency lines.
    pub rows: usize,
}

/// Plans an export: the output at `dest` (locally, by default,
/// `<stem>.<topic>.<csv|parquet>` beside the recording), checked by the
/// output rules ([`crate::outputs`]: nothing replaced without
/// `--overwrite`, only a regular file, never the recording read), before
/// anything is read.
///
/// # Errors
/// [`RunError::BadOption`] naming `out` (or `recording` when the output
/// would be the recording itself).
pub fn plan_export(request: ExportRequest, dest: &Destination) -> Result<ExportOptions, RunError> {
    let suffix = request.suffix();
    let (out, origin) = dest.output("out", &suffix, || Ok(beside(&request.recording, &suffix)))?;
    OutputPlan::new(dest.existing())
        .derived_from("the recording")
        .with_output("out", &out, origin)
        .with_input("recording", &request.recording)
        .check()?;
    Ok(ExportOptions {
        request,
        out,
        existing: dest.existing(),
    })
}

/// Runs a planned export.
///
/// # Errors
/// [`RunError::BadOption`] naming `recording` for a recording that cannot
/// be read or has no such topic (the reason lists the topics it has);
/// [`RunError::Output`] when the table cannot be written.
pub fn run_export(opts: &ExportOptions) -> Result<ExportSummary, RunError> {
    let r = &opts.request;
    let rows = export_topic(&r.recording, r.topic(), r.to, &opts.out, opts.existing).map_err(
        |e| match e {
            ExportError::Recording { path, reason } => {
                RunError::option("recording", path.display(), reason)
            }
            ExportError::NoTopic {
                path,
                topic,
                topics,
            } => RunError::option(
                "recording",
                path.display(),
                format!("no messages on {topic} (the recording has: {topics})"),
            ),
            ExportError::Output { path, source } => RunError::Output {
                path,
                reason: source.to_string(),
            },
        },
    )?;
    Ok(ExportSummary {
        recording: r.recording.clone(),
        topic: r.topic().to_string(),
        format: r.to,
        out: std::path::absolute(&opts.out).unwrap_or_else(|_| opts.out.clone()),
        rows,
    })
}
