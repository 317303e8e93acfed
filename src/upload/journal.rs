//! The upload journal: an append-only file of JSON lines
//! (`<recordings>/upload-journal.jsonl` for the daemon), one line per
//! file queued, confirmed or dropped, each written and synced
//! (`fdatasync`) before the daemon goes on. What was queued and is neither
//! confirmed nor dropped is pending: after a restart the daemon uploads it
//! first. A line torn by a crash (the last, incomplete) is cut off when
//! the journal is next opened.
//!
//! A line:
//! - `{"op":"queued","store":URL,"item":{"key":…,"source":…},"time_utc":…}`
//! - `{"op":"confirmed","store":URL,"key":…,"size_bytes":N,"sha256":HEX,"uploaded":BOOL,"time_utc":…}`
//! - `{"op":"dropped","store":URL,"key":…,"reason":…,"time_utc":…}`
//!
//! When the journal grows over [`COMPACT_BYTES`] it is rewritten at open
//! with its pending lines only (atomically: a crash leaves the old or the
//! new file).

use super::transfer::Item;
use crate::outputs::{write_buffered_atomically, Existing, FILE_MODE};
use serde::{Deserialize, Serialize};
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

/// The journal's file name in the recordings directory.
pub const JOURNAL_FILE: &str = "upload-journal.jsonl";

/// Size over which the journal is compacted when opened, bytes.
pub const COMPACT_BYTES: u64 = 4 * 1024 * 1024;

/// One line of the journal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case")]
pub enum Line {
    /// A file queued for `store`.
    Queued {
        /// The store's URL.
        store: String,
        /// What goes up.
        item: Item,
        /// When, RFC 3339 UTC.
        time_utc: String,
    },
    /// The store confirmed `key` (read back, same SHA-256).
    Confirmed {
        /// The store's URL.
        store: String,
        /// The object's key.
        key: String,
        /// Its size, bytes.
        size_bytes: u64,
        /// Its SHA-256, hex.
        sha256: String,
        /// Uploaded now (`false`: found in the store already).
        uploaded: bool,
        /// When, RFC 3339 UTC.
        time_utc: String,
    },
    /// `key` will not go up (its file is gone, the store holds another
    /// object of that name); the local file is kept.
    Dropped {
        /// The store's URL.
        store: String,
        /// The object's key.
        key: String,
        /// Why.
        reason: String,
        /// When, RFC 3339 UTC.
        time_utc: String,
    },
}

/// Now, RFC 3339 UTC.
pub fn now_utc() -> String {
    time::OffsetDateTime::now_utc()
        .format(&time::format_description::well_known::Rfc3339)
        .unwrap_or_default()
}

/// The journal, open for appending.
#[derive(Debug)]
pub struct Journal {
    path: PathBuf,
    file: File,
}

/// A pending entry: its store and item.
#[derive(Debug, Clone, PartialEq)]
pub struct Pending {
    /// The store's URL it was queued for.
    pub store: String,
    /// The item.
    pub item: Item,
}

impl Journal {
    /// Opens (or creates, mode [`FILE_MODE`]) the journal at `path` and
    /// returns it with its pending entries, in the order they were queued.
    ///
    /// # Errors
    /// The file cannot be read, written, or holds a line that is not a
    /// journal line (but for a torn last line).
    pub fn open(path: &Path) -> Result<(Self, Vec<Pending>), String> {
        let ctx = |e: std::io::Error| format!("the upload journal {}: {e}", path.display());
        let mut pending: Vec<Pending> = Vec::new();
        let mut size = 0;
        // Where a torn last line starts (cut off below).
        let mut torn_at = None;
        if let Ok(bytes) = std::fs::read(path) {
            size = bytes.len() as u64;
            let mut at = 0usize;
            let n_lines = bytes.split(|b| *b == b'\n').count();
            for (i, raw) in bytes.split(|b| *b == b'\n').enumerate() {
                let start = at;
                at += raw.len() + 1;
                let l = String::from_utf8_lossy(raw);
                if l.trim().is_empty() {
                    continue;
                }
                let line: Line = match serde_json::from_str(&l) {
                    Ok(line) => line,
                    // A crash while appending: the torn last line.
                    Err(_) if i + 1 == n_lines => {
                        torn_at = Some(start as u64);
                        break;
                    }
                    Err(e) => {
                        return Err(format!(
                            "the upload journal {} line {}: {e}",
                            path.display(),
                            i + 1
                        ))
                    }
                };
                match line {
                    Line::Queued { store, item, .. } => {
                        pending.retain(|p| !(p.store == store && p.item.key == item.key));
                        pending.push(Pending { store, item });
                    }
                    Line::Confirmed { store, key, .. } | Line::Dropped { store, key, .. } => {
                        pending.retain(|p| !(p.store == store && p.item.key == key));
                    }
                }
            }
        }
        if let Some(at) = torn_at {
            let f = OpenOptions::new().write(true).open(path).map_err(ctx)?;
            f.set_len(at).and_then(|()| f.sync_data()).map_err(ctx)?;
            size = at;
        }
        if size > COMPACT_BYTES {
            let time_utc = now_utc();
            write_buffered_atomically(path, Existing::Replace, |w| {
                for p in &pending {
                    let line = Line::Queued {
                        store: p.store.clone(),
                        item: p.item.clone(),
                        time_utc: time_utc.clone(),
                    };
                    serde_json::to_writer(&mut *w, &line)?;
                    w.write_all(b"\n")?;
                }
                Ok(())
            })
            .map_err(ctx)?;
        }
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .mode(FILE_MODE)
            .open(path)
            .map_err(ctx)?;
        Ok((
            Self {
                path: path.to_path_buf(),
                file,
            },
            pending,
        ))
    }

    /// Appends `line` and syncs it to the disk.
    ///
    /// # Errors
    /// The write or the sync failed.
    pub fn append(&mut self, line: &Line) -> Result<(), String> {
        let mut s = serde_json::to_string(line).map_err(|e| e.to_string())?;
        s.push('\n');
        self.file
            .write_all(s.as_bytes())
            .and_then(|()| self.file.sync_data())
            .map_err(|e| format!("the upload journal {}: {e}", self.path.display()))
    }

    /// Its path.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::upload::Source;

    fn queued(key: &str) -> Line {
        Line::Queued {
            store: "s3://lab".into(),
            item: Item {
                key: key.into(),
                source: Source::File(PathBuf::from(format!("/r/{key}"))),
            },
            time_utc: now_utc(),
        }
    }

    #[test]
    fn pending_is_queued_minus_confirmed_and_dropped_across_reopens_and_a_torn_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(JOURNAL_FILE);
        {
            let (mut j, p) = Journal::open(&path).unwrap();
            assert!(p.is_empty());
            for k in ["a", "b", "c"] {
                j.append(&queued(k)).unwrap();
            }
            j.append(&Line::Confirmed {
                store: "s3://lab".into(),
                key: "a".into(),
                size_bytes: 1,
                sha256: "00".into(),
                uploaded: true,
                time_utc: now_utc(),
            })
            .unwrap();
            j.append(&Line::Dropped {
                store: "s3://lab".into(),
                key: "c".into(),
                reason: "gone".into(),
                time_utc: now_utc(),
            })
            .unwrap();
        }
        // A crash in the middle of a line.
        {
            let mut f = OpenOptions::new().append(true).open(&path).unwrap();
            f.write_all(br#"{"op":"queued","store":"s3://la"#).unwrap();
        }
        let (mut j, p) = Journal::open(&path).unwrap();
        let keys: Vec<_> = p.iter().map(|p| p.item.key.as_str()).collect();
        assert_eq!(keys, ["b"]);
        j.append(&queued("d")).unwrap();
        drop(j);
        let (_, p) = Journal::open(&path).unwrap();
        let keys: Vec<_> = p.iter().map(|p| p.item.key.as_str()).collect();
        assert_eq!(keys, ["b", "d"]);
        // A line that is not the last and does not parse is an error.
        std::fs::write(&path, "garbage\n{}\n").unwrap();
        assert!(Journal::open(&path).unwrap_err().contains("line 1"));
    }
}
