//! `bench recover`: turns the `.part` file a killed run left into a
//! complete, indexed recording that any MCAP reader opens (the README's
//! `make_reader` example needs the summary and footer a killed process
//! never wrote).
//!
//! What is kept: every message of every chunk that was completely written
//! (the chunks are closed every 50 ms, see [`super::spawn_writer`]), in file
//! order, on its original channel and schema, and every metadata record
//! (`bench.config`, `bench.run`). A metadata record `bench.recovered` is
//! added: the `.part` file it came from, the number of messages, and why
//! reading stopped (the cut chunk of a killed run, or `clean end`).

use std::collections::BTreeMap;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use serde::Serialize;

use super::reader::read_messages_tolerant;
use crate::outputs::{write_atomically, Existing};

/// Errors of [`recover`].
#[derive(Debug, thiserror::Error)]
pub enum RecoverError {
    /// The input could not be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The input.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
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
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Recovered {
    /// The `.part` file read.
    pub from: PathBuf,
    /// The complete recording written.
    pub to: PathBuf,
    /// Messages copied, count.
    pub messages: u64,
    /// Metadata records copied (besides `bench.recovered`), count.
    pub metadata: u64,
    /// Loop time of the last message kept, s (its log time less the run's
    /// start).
    pub last_log_time_s: f64,
    /// Why reading stopped: the error at the cut (e.g. an unexpected end of
    /// file inside the chunk being written when the run was killed), or
    /// `clean end`.
    pub stopped: String,
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
    let bytes = std::fs::read(part).map_err(|source| RecoverError::Read {
        path: part.to_path_buf(),
        source,
    })?;
    let not = |reason: String| RecoverError::NotARecording {
        path: part.to_path_buf(),
        reason,
    };
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(not("it does not start with the MCAP magic".into()));
    }
    let read = read_messages_tolerant(&bytes);
    if read.messages.is_empty() {
        return Err(not(match read.error {
            Some(e) => format!("no complete message ({e})"),
            None => "it holds no message".into(),
        }));
    }
    // Top-level metadata records (written outside chunks), up to the cut.
    let mut metadata = Vec::new();
    if let Ok(records) = mcap::read::LinearReader::new_with_options(
        &bytes,
        mcap::read::Options::IgnoreEndMagic.into(),
    ) {
        for r in records {
            match r {
                Ok(mcap::records::Record::Metadata(m)) => metadata.push(m),
                Ok(_) => {}
                Err(_) => break,
            }
        }
    }
    // The run's start (`bench.run` start_time_unix_ns): log times are that
    // plus loop time; recordings made before hold loop time alone.
    let origin_ns = metadata
        .iter()
        .find(|m| m.name == "bench.run")
        .and_then(|m| m.metadata.get("start_time_unix_ns"))
        .and_then(|s| s.parse::<u64>().ok())
        .unwrap_or(0);
    let stopped = read
        .error
        .as_ref()
        .map_or_else(|| "clean end".to_string(), ToString::to_string);
    let report = Recovered {
        from: part.to_path_buf(),
        to: to.to_path_buf(),
        messages: read.messages.len() as u64,
        metadata: metadata.len() as u64,
        last_log_time_s: read
            .messages
            .last()
            .map_or(0, |m| m.log_time.saturating_sub(origin_ns)) as f64
            * 1e-9,
        stopped,
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
        for m in &metadata {
            w.write_metadata(m).map_err(mcap_err)?;
        }
        w.write_metadata(&mcap::records::Metadata {
            name: "bench.recovered".into(),
            metadata: BTreeMap::from([
                ("from".to_string(), part.display().to_string()),
                ("messages".to_string(), report.messages.to_string()),
                ("stopped".to_string(), report.stopped.clone()),
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
