//! `bench recover`: turns the `.part` file a killed run left into a
//! complete, indexed recording that any MCAP reader opens (the README's
//! `make_reader` example needs the summary and footer a killed process
//! never wrote).
//!
//! What is kept ([`super::salvage`]): every message of every intact chunk
//! (the chunks are closed every 50 ms, see [`super::spawn_writer`]), in
//! file order, on its original channel and schema, and every intact
//! metadata record (`bench.config`, `bench.run`). A damaged chunk is
//! dropped whole and the intact chunks after it are kept. A metadata record
//! `bench.recovered` is added: the `.part` file it came from, the number of
//! messages and chunks, what was dropped (chunk index, byte offset and
//! length, message count and loop-time span when known, reason), the cut
//! chunk of a killed run, and whether anything was lost
//! ([`Recovered::lost`]).

use std::collections::BTreeMap;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::salvage::{salvage, Orphaned, RegionKind};
use crate::outputs::{write_atomically, Existing};

/// Errors of [`recover`].
#[derive(Debug, thiserror::Error)]
pub enum RecoverError {
    /// The input could not be read, or is refused: not a regular file,
    /// or larger than a recording may be ([`crate::input_file`]).
    #[error("{}: {}", source.path.display(), source.reason())]
    Read {
        /// The input, its kind and why.
        #[from]
        source: crate::input_file::InputError,
    },
    /// The input is not an MCAP file (no valid header), or holds no message.
    #[error("{path} is not a recoverable recording: {reason}")]
    NotARecording {
        /// The input.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// Writing the recovered recording failed (nothing is left under the
    /// output name).
    #[error("cannot write {path}: {reason}")]
    Write {
        /// The output.
        path: PathBuf,
        /// Why.
        reason: String,
    },
}

/// What [`recover`] did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Recovered {
    /// The `.part` file read.
    pub from: PathBuf,
    /// The complete recording written.
    pub to: PathBuf,
    /// Messages copied, count.
    pub messages: u64,
    /// Intact chunks read, count.
    pub chunks: u64,
    /// Metadata records copied (besides `bench.recovered`), count.
    pub metadata: u64,
    /// Loop time of the last message kept, s (its log time less the run's
    /// start).
    pub last_log_time_s: f64,
    /// Why reading stopped: the cut (e.g. a chunk that runs past the end of
    /// the file: the one being written when the run was killed), or `clean
    /// end`.
    pub stopped: String,
    /// The incomplete record at the end of the file (the expected end of a
    /// killed run's `.part` file: not a loss), if any.
    pub cut: Option<CutRegion>,
    /// Damaged regions dropped whole, in file order.
    pub dropped: Vec<DroppedRegion>,
    /// Messages of intact chunks dropped because their channel's definition
    /// was lost with a damaged chunk and could not be rebuilt.
    pub orphaned: Vec<Orphaned>,
    /// Channel definitions lost with a damaged chunk and rebuilt, if any:
    /// which, and from what.
    pub rebuilt: Option<String>,
    /// Whether anything written is missing besides the cut: a dropped
    /// chunk, metadata record or unreadable bytes, or orphaned messages
    /// (`bench recover` then exits 7). A damaged message index loses
    /// nothing (it is rebuilt).
    pub lost: bool,
}

/// A damaged region of the `.part` file, dropped whole.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct DroppedRegion {
    /// What it held.
    pub kind: RegionKind,
    /// The chunk's index, every chunk of the file counted from 0 in file
    /// order (chunk 0 holds the channel definitions); for a region that is
    /// no chunk, the next chunk's.
    pub chunk_index: u64,
    /// Where it starts, bytes from the file's start.
    pub offset_bytes: u64,
    /// Its length, bytes.
    pub length_bytes: u64,
    /// Messages lost with it, count, when its message index survived.
    pub messages: Option<u64>,
    /// Loop time its messages span, s (first, last), when known: from the
    /// chunk's header, or between the neighbouring messages kept.
    pub loop_time_s: Option<[f64; 2]>,
    /// Why it was dropped.
    pub reason: String,
    /// Whether data was lost with it (all but a message index).
    pub lost: bool,
}

/// The incomplete record at the end of a killed run's `.part` file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct CutRegion {
    /// What it was, as far as its opcode says.
    pub kind: RegionKind,
    /// The chunk's index when it was a chunk.
    pub chunk_index: u64,
    /// Where it starts, bytes from the file's start.
    pub offset_bytes: u64,
    /// The bytes of it in the file.
    pub length_bytes: u64,
    /// What is missing.
    pub reason: String,
}

/// Reads `part` tolerantly and writes every complete message and metadata
/// record to `to`: an MCAP with lz4 chunks, summary, indexes and footer,
/// written under a temporary name and renamed when complete
/// ([`crate::outputs::write_atomically`]: mode 0640, an existing `to` is
/// replaced only with [`Existing::Replace`] and only if it is a regular
/// file). Check `to` first with [`crate::outputs::OutputPlan::check`].
///
/// # Errors
/// [`RecoverError::Read`], [`RecoverError::NotARecording`] (no header, no
/// message), [`RecoverError::Write`] (nothing is left under `to`).
pub fn recover(part: &Path, to: &Path, existing: Existing) -> Result<Recovered, RecoverError> {
    let bytes = crate::input_file::read(part, crate::input_file::Kind::Recording, "part")?;
    let not = |reason: String| RecoverError::NotARecording {
        path: part.to_path_buf(),
        reason,
    };
    let read = salvage(&bytes).map_err(not)?;
    if read.messages.is_empty() {
        return Err(not(match read.first_problem() {
            Some(e) => format!("no complete message ({e})"),
            None => "it holds no message".into(),
        }));
    }
    let metadata = &read.metadata;
    // The run's start (`bench.run` start_time_unix_ns): log times are that
    // plus loop time; recordings made before hold loop time alone.
    let origin_ns = metadata
        .iter()
        .find(|m| m.name == "bench.run")
        .and_then(|m| m.metadata.get("start_time_unix_ns"))
        .and_then(|s| s.parse::<u64>().ok())
        .unwrap_or(0);
    let loop_time_s = |ns: u64| ns.saturating_sub(origin_ns) as f64 * 1e-9;
    let cut = read.cut.as_ref().map(|c| CutRegion {
        kind: c.kind,
        chunk_index: c.chunk_index,
        offset_bytes: c.offset_bytes,
        length_bytes: c.length_bytes,
        reason: c.reason.clone(),
    });
    let report = Recovered {
        from: part.to_path_buf(),
        to: to.to_path_buf(),
        messages: read.messages.len() as u64,
        chunks: read.chunks,
        metadata: metadata.len() as u64,
        last_log_time_s: read
            .messages
            .last()
            .map_or(0.0, |m| loop_time_s(m.log_time)),
        stopped: read.cut.as_ref().map_or_else(
            || "clean end".to_string(),
            |c| format!("cut at byte {}: {}", c.offset_bytes, c.reason),
        ),
        cut,
        dropped: read
            .dropped
            .iter()
            .map(|d| DroppedRegion {
                kind: d.kind,
                chunk_index: d.chunk_index,
                offset_bytes: d.offset_bytes,
                length_bytes: d.length_bytes,
                messages: d.messages,
                loop_time_s: d.log_time_ns.map(|(a, b)| [loop_time_s(a), loop_time_s(b)]),
                reason: d.reason.clone(),
                lost: d.lost(),
            })
            .collect(),
        orphaned: read.orphaned.clone(),
        rebuilt: read.rebuilt.clone(),
        lost: read.lost(),
    };
    let mcap_err = |e: mcap::McapError| std::io::Error::other(crate::error::error_chain(&e));
    write_atomically(to, existing, |file| {
        let mut w = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Lz4))
            .profile("")
            .library(concat!("bench-", env!("CARGO_PKG_VERSION"), " (mcap-rs)"))
            .create(BufWriter::new(&mut *file))
            .map_err(mcap_err)?;
        for m in &read.messages {
            w.write(m).map_err(mcap_err)?;
        }
        for m in metadata {
            w.write_metadata(m).map_err(mcap_err)?;
        }
        w.write_metadata(&mcap::records::Metadata {
            name: "bench.recovered".into(),
            metadata: BTreeMap::from([
                ("from".to_string(), part.display().to_string()),
                ("messages".to_string(), report.messages.to_string()),
                ("stopped".to_string(), report.stopped.clone()),
                ("chunks".to_string(), report.chunks.to_string()),
                ("lost".to_string(), report.lost.to_string()),
                ("dropped".to_string(), to_json(&report.dropped)),
                ("cut".to_string(), to_json(&report.cut)),
                ("orphaned".to_string(), to_json(&report.orphaned)),
                (
                    "rebuilt".to_string(),
                    report.rebuilt.clone().unwrap_or_default(),
                ),
            ]),
        })
        .map_err(mcap_err)?;
        w.finish().map_err(mcap_err)?;
        w.into_inner().flush()
    })
    .map_err(|e| RecoverError::Write {
        path: to.to_path_buf(),
        reason: e.to_string(),
    })?;
    Ok(report)
}

/// JSON text of a report field, for the `bench.recovered` metadata (whose
/// values are strings). These plain structs always serialise.
fn to_json<T: Serialize>(v: &T) -> String {
    serde_json::to_string(v).unwrap_or_else(|e| e.to_string())
}
