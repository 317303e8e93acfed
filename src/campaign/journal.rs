//! The campaign journal: an append-only log of what a campaign has done,
//! durable after each cell.
//!
//! `journal.jsonl` holds one entry per line, `<json>\t<sha256 of json>\n`.
//! [`Journal::append`] writes a whole line with one `write` call and then
//! `fsync`s the file, so once it returns the entry survives a SIGKILL and a
//! power loss. A process killed during the write leaves at most one torn
//! last line; [`read`] keeps the longest prefix of lines whose checksum
//! matches (anything after the first bad line is ignored, there can be
//! nothing valid after it in an append-only file), and [`Journal::open`]
//! truncates the file to that prefix before appending again.
//!
//! A cell counts as done only when its [`Entry::Done`] line is in the valid
//! prefix, and that line is written after the cell's outputs are complete
//! and synced, with their SHA-256 checksums: a half-finished cell is never
//! counted, a done cell is never lost.

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::fs::{File, OpenOptions};
use std::io::{self, Read, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

/// Name of the journal file in a campaign directory (the catalogue and the
/// uploads know a campaign directory by it).
pub const JOURNAL_FILE: &str = crate::catalogue::CAMPAIGN_JOURNAL_FILE;

/// Journal format version written in the header.
pub const JOURNAL_VERSION: u32 = 1;

/// An output file of a cell with its checksum.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileSum {
    /// Path relative to the campaign directory.
    pub path: String,
    /// Size, bytes.
    pub bytes: u64,
    /// SHA-256 of the contents, lower-case hex.
    pub sha256: String,
}

/// One journal entry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "entry", rename_all = "snake_case")]
pub enum Entry {
    /// First line: what the campaign is. Resuming with a campaign file or
    /// bench config whose hash differs is refused (unless forced).
    Header {
        /// [`JOURNAL_VERSION`].
        version: u32,
        /// SHA-256 of the campaign file's text, hex.
        campaign_sha256: String,
        /// SHA-256 of the bench config's text, hex.
        config_sha256: String,
        /// The campaign file's text (to say what changed on a refused
        /// resume).
        #[serde(default)]
        campaign_text: String,
        /// The bench config's text.
        #[serde(default)]
        config_text: String,
        /// Number of cells of the grid.
        cells: usize,
        /// When the campaign was created, UTC (RFC 3339).
        created_utc: String,
    },
    /// A cell was started (its outputs may be incomplete until `Done`).
    Started {
        /// Cell index in the grid's row-major order.
        cell: usize,
    },
    /// A cell finished: its outputs are complete, synced and checksummed.
    Done {
        /// Cell index in the grid's row-major order.
        cell: usize,
        /// Operating point Y1o, m.
        operating_point_m: f64,
        /// Mass asymmetry Δm23 = m2/m3 − 1 of the grid.
        mass_asymmetry: f64,
        /// The asymmetry the operator set with whole trim masses, when it
        /// differs from the grid's (hardware campaigns).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        achieved_mass_asymmetry: Option<f64>,
        /// Simulator noise seed of the cell.
        seed: u64,
        /// Measured CMP-CNMP verdict (`None`: undecided, see `reason`).
        verdict: Option<bool>,
        /// Why the verdict is undecided, or why the two tests disagree.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        reason: Option<String>,
        /// The cell's output files.
        files: Vec<FileSum>,
    },
    /// The operator skipped a cell (hardware campaigns).
    Skipped {
        /// Cell index.
        cell: usize,
    },
}

/// Errors of the journal.
#[derive(Debug, thiserror::Error)]
pub enum JournalError {
    /// Reading, writing or syncing failed.
    #[error("journal {}: {source}", path.display())]
    Io {
        /// The journal file.
        path: PathBuf,
        /// The OS error.
        source: io::Error,
    },
    /// The journal is not a regular file, or larger than
    /// [`Kind::CampaignState`](crate::input_file::Kind::CampaignState)'s
    /// limit ([`crate::input_file`]).
    #[error("journal {}: {}", source.path.display(), source.reason())]
    Refused {
        /// Why.
        source: crate::input_file::InputError,
    },
    /// The journal has no valid header line.
    #[error("journal {}: {reason}", path.display())]
    NotAJournal {
        /// The journal file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
}

/// SHA-256 of `bytes`, lower-case hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    let digest = Sha256::digest(bytes);
    let mut s = String::with_capacity(64);
    for b in digest {
        s.push_str(&format!("{b:02x}"));
    }
    s
}

/// SHA-256 and size of a file, streamed: a cell's file, opened as every
/// input is ([`crate::input_file`]: a regular file, never a FIFO waited on
/// or a device read forever, of at most a recording's limit, the largest
/// file a cell holds).
///
/// # Errors
/// The OS error of opening or reading it; a refusal as
/// [`io::ErrorKind::InvalidInput`].
pub fn file_sum(dir: &Path, relative: &str) -> io::Result<FileSum> {
    use crate::input_file::{open, InputError, Kind};
    let mut f = open(&dir.join(relative), Kind::Recording, "dir")
        .map_err(InputError::into_io)?
        .into_file()
        .take(Kind::Recording.limit_bytes());
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    let mut bytes = 0u64;
    loop {
        let n = f.read(&mut buf)?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
        bytes += n as u64;
    }
    let mut sha256 = String::with_capacity(64);
    for b in h.finalize() {
        sha256.push_str(&format!("{b:02x}"));
    }
    Ok(FileSum {
        path: relative.to_string(),
        bytes,
        sha256,
    })
}

/// One journal line for `entry` (with its checksum and newline).
fn line_of(entry: &Entry) -> String {
    let json = serde_json::to_string(entry).expect("journal entries serialise");
    format!("{json}\t{}\n", sha256_hex(json.as_bytes()))
}

/// What [`read`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadJournal {
    /// The entries of the valid prefix, in order.
    pub entries: Vec<Entry>,
    /// Byte length of the valid prefix.
    pub valid_bytes: u64,
    /// Bytes after it (a torn or corrupted tail), ignored.
    pub ignored_bytes: u64,
}

impl ReadJournal {
    /// The header, if the first entry is one.
    pub fn header(&self) -> Option<&Entry> {
        self.entries
            .first()
            .filter(|e| matches!(e, Entry::Header { .. }))
    }

    /// The last `Done` entry of each cell (a cell redone after its files
    /// were found damaged has several), by cell index.
    pub fn done(&self) -> std::collections::BTreeMap<usize, &Entry> {
        let mut out = std::collections::BTreeMap::new();
        for e in &self.entries {
            if let Entry::Done { cell, .. } = e {
                out.insert(*cell, e);
            }
        }
        out
    }

    /// Cells the operator skipped (and did not do later).
    pub fn skipped(&self) -> std::collections::BTreeSet<usize> {
        let done = self.done();
        self.entries
            .iter()
            .filter_map(|e| match e {
                Entry::Skipped { cell } if !done.contains_key(cell) => Some(*cell),
                _ => None,
            })
            .collect()
    }
}

/// Parses journal bytes: the longest prefix of complete lines whose
/// checksums match and whose JSON parses.
pub fn parse(bytes: &[u8]) -> ReadJournal {
    let mut entries = Vec::new();
    let mut valid = 0usize;
    while valid < bytes.len() {
        let rest = &bytes[valid..];
        let Some(nl) = rest.iter().position(|&b| b == b'\n') else {
            break;
        };
        let line = &rest[..nl];
        let Some(tab) = line.iter().rposition(|&b| b == b'\t') else {
            break;
        };
        let (json, sum) = (&line[..tab], &line[tab + 1..]);
        if sha256_hex(json).as_bytes() != sum {
            break;
        }
        let Ok(entry) = serde_json::from_slice::<Entry>(json) else {
            break;
        };
        entries.push(entry);
        valid += nl + 1;
    }
    ReadJournal {
        entries,
        valid_bytes: valid as u64,
        ignored_bytes: (bytes.len() - valid) as u64,
    }
}

/// Reads the journal of campaign directory `dir`.
///
/// # Errors
/// [`JournalError::Io`] if it cannot be read, [`JournalError::NotAJournal`]
/// if its valid prefix does not start with a header.
pub fn read(dir: &Path) -> Result<ReadJournal, JournalError> {
    use crate::input_file::{Kind, Problem};
    let path = dir.join(JOURNAL_FILE);
    let bytes = crate::input_file::read(&path, Kind::CampaignState, "dir").map_err(|e| match e
        .problem
    {
        Problem::Open(source) | Problem::Read(source) => JournalError::Io {
            path: path.clone(),
            source,
        },
        _ => JournalError::Refused { source: e },
    })?;
    let j = parse(&bytes);
    if j.header().is_none() {
        return Err(JournalError::NotAJournal {
            path,
            reason: "no valid header line: not a bench campaign journal".into(),
        });
    }
    Ok(j)
}

/// An open journal, appending.
#[derive(Debug)]
pub struct Journal {
    file: File,
    path: PathBuf,
}

impl Journal {
    /// Creates the journal of a new campaign in `dir` (which must not hold
    /// one) with its header, synced (file and directory).
    ///
    /// # Errors
    /// [`JournalError::Io`], also if the journal exists.
    pub fn create(dir: &Path, header: &Entry) -> Result<Self, JournalError> {
        let path = dir.join(JOURNAL_FILE);
        let io_err = |source| JournalError::Io {
            path: path.clone(),
            source,
        };
        let file = OpenOptions::new()
            .append(true)
            .create_new(true)
            .mode(0o640)
            .open(&path)
            .map_err(io_err)?;
        let mut j = Self { file, path };
        j.append(header)?;
        File::open(dir)
            .and_then(|d| d.sync_all())
            .map_err(|source| JournalError::Io {
                path: dir.to_path_buf(),
                source,
            })?;
        Ok(j)
    }

    /// Opens the journal of `dir` for appending after its valid prefix
    /// (a torn tail is cut off first), returning what it holds.
    ///
    /// # Errors
    /// As [`read`], and [`JournalError::Io`] if it cannot be truncated or
    /// opened.
    pub fn open(dir: &Path) -> Result<(Self, ReadJournal), JournalError> {
        let read = read(dir)?;
        let path = dir.join(JOURNAL_FILE);
        let io_err = |source| JournalError::Io {
            path: path.clone(),
            source,
        };
        let file = OpenOptions::new()
            .append(true)
            .open(&path)
            .map_err(io_err)?;
        if read.ignored_bytes > 0 {
            file.set_len(read.valid_bytes).map_err(io_err)?;
            file.sync_all().map_err(io_err)?;
        }
        Ok((Self { file, path }, read))
    }

    /// Appends `entry` as one line (one `write`) and syncs the file: when
    /// this returns the entry is durable.
    ///
    /// # Errors
    /// [`JournalError::Io`].
    pub fn append(&mut self, entry: &Entry) -> Result<(), JournalError> {
        let line = line_of(entry);
        let io_err = |source| JournalError::Io {
            path: self.path.clone(),
            source,
        };
        self.file.write_all(line.as_bytes()).map_err(io_err)?;
        self.file.sync_data().map_err(io_err)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> Entry {
        Entry::Header {
            version: JOURNAL_VERSION,
            campaign_sha256: sha256_hex(b"campaign"),
            config_sha256: sha256_hex(b"config"),
            campaign_text: "seed = 1\n".into(),
            config_text: "[plant]\nm1_kg = 0.1\n".into(),
            cells: 3,
            created_utc: "2026-11-22T10:00:00Z".into(),
        }
    }

    fn done(cell: usize) -> Entry {
        Entry::Done {
            cell,
            operating_point_m: 0.001 * cell as f64,
            mass_asymmetry: -0.02,
            achieved_mass_asymmetry: None,
            seed: 7 + cell as u64,
            verdict: Some(cell.is_multiple_of(2)),
            reason: None,
            files: vec![FileSum {
                path: format!("cells/{cell}/chirp.mcap"),
                bytes: 12,
                sha256: sha256_hex(b"x"),
            }],
        }
    }

    #[test]
    fn sha256_matches_the_fips_180_2_example() {
        // FIPS 180-2, Appendix B.1: SHA-256("abc").
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }

    #[test]
    fn every_cut_of_the_file_keeps_exactly_the_complete_entries_before_it() {
        // A kill can stop the write anywhere: at every byte length, the
        // valid prefix holds exactly the entries whose lines are complete.
        let entries = [header(), Entry::Started { cell: 0 }, done(0), done(2)];
        let lines: Vec<String> = entries.iter().map(line_of).collect();
        let all: String = lines.concat();
        let ends: Vec<usize> = lines
            .iter()
            .scan(0, |acc, l| {
                *acc += l.len();
                Some(*acc)
            })
            .collect();
        for cut in 0..=all.len() {
            let j = parse(&all.as_bytes()[..cut]);
            let complete = ends.iter().filter(|&&e| e <= cut).count();
            assert_eq!(j.entries, entries[..complete], "cut at {cut}");
            assert_eq!(
                j.valid_bytes as usize,
                if complete == 0 { 0 } else { ends[complete - 1] }
            );
        }
    }

    #[test]
    fn a_flipped_byte_ends_the_valid_prefix_at_its_line() {
        let entries = [header(), done(0), done(1), done(2)];
        let all: String = entries.iter().map(line_of).collect();
        let first_len = line_of(&entries[0]).len();
        let second_end = first_len + line_of(&entries[1]).len();
        for pos in first_len..second_end - 1 {
            let mut b = all.clone().into_bytes();
            b[pos] ^= 0x01;
            let j = parse(&b);
            assert_eq!(j.entries, entries[..1], "byte {pos} flipped");
        }
    }

    #[test]
    fn open_cuts_a_torn_tail_and_appends_after_the_valid_prefix() {
        let dir = tempfile::tempdir().unwrap();
        let mut j = Journal::create(dir.path(), &header()).unwrap();
        j.append(&done(0)).unwrap();
        drop(j);
        // A torn write of the next entry.
        let torn = line_of(&done(1));
        let mut f = OpenOptions::new()
            .append(true)
            .open(dir.path().join(JOURNAL_FILE))
            .unwrap();
        f.write_all(&torn.as_bytes()[..torn.len() / 2]).unwrap();
        drop(f);
        let (mut j, read) = Journal::open(dir.path()).unwrap();
        assert_eq!(read.entries, [header(), done(0)]);
        assert!(read.ignored_bytes > 0);
        j.append(&done(1)).unwrap();
        let again = super::read(dir.path()).unwrap();
        assert_eq!(again.entries, [header(), done(0), done(1)]);
        assert_eq!(again.ignored_bytes, 0);
        assert_eq!(again.done().keys().copied().collect::<Vec<_>>(), [0, 1]);
    }

    #[test]
    fn a_file_without_a_header_is_not_a_journal() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join(JOURNAL_FILE), line_of(&done(0))).unwrap();
        assert!(matches!(
            read(dir.path()),
            Err(JournalError::NotAJournal { .. })
        ));
        std::fs::write(dir.path().join(JOURNAL_FILE), "hello\n").unwrap();
        assert!(matches!(
            read(dir.path()),
            Err(JournalError::NotAJournal { .. })
        ));
    }

    #[test]
    fn create_refuses_an_existing_journal() {
        let dir = tempfile::tempdir().unwrap();
        Journal::create(dir.path(), &header()).unwrap();
        assert!(Journal::create(dir.path(), &header()).is_err());
    }
}
