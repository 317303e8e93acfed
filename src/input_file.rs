//! The files `bench` reads because someone named them (a flag, an
//! argument, a daemon request's parameter, a path a campaign directory or
//! a recordings directory holds): opened, checked and read with a bound,
//! in one place. Every reader of such a file goes through [`open`],
//! [`read`] or [`read_to_string`].
//!
//! # Rules
//!
//! 1. **Only regular files.** The path's type is looked at first
//!    (`stat`, links followed: a device is never opened, as opening some
//!    has effects), then the file is opened with `O_NONBLOCK | O_NOCTTY`
//!    (opening a FIFO with no writer returns at once instead of waiting
//!    for one) and the *opened descriptor* is checked again (`fstat`), so
//!    a path swapped in between is caught. A FIFO, a character or block
//!    device (`/dev/zero`), a socket or a directory is refused before a
//!    byte is read. `O_NONBLOCK` is then cleared.
//! 2. **A size limit per kind** ([`Kind::limit_bytes`]), checked on the
//!    descriptor's size before anything is read, and the read itself
//!    bounded (`Read::take(limit + 1)`), so that a file that grows while
//!    it is read is refused as well, never read to the end of memory.
//! 3. **Errors name the argument, the file and the reason**
//!    ([`InputError`]): the kind of file found, or the size and the
//!    limit, e.g. `--config /dev/zero: not a regular file (a character
//!    device); bench reads configs only from regular files`.
//!
//! # Limits
//!
//! Each is far above what `bench` writes or a measurement holds, and far
//! below what would hurt the machine reading it:
//!
//! | kind | limit | why |
//! |---|---|---|
//! | [`Kind::Config`] | 1 MiB | the shipped bench descriptions are under 16 KiB |
//! | [`Kind::Campaign`] | 1 MiB | the built-in campaign file is 2 kB; a grid of 10 000 cells with every value listed is under 200 KiB |
//! | [`Kind::FrfCsv`] | 16 MiB | the densest FRF `bench` writes (10 000 points a decade from 0.01 Hz to 50 kHz, 67 000 lines of about 70 bytes) is under 5 MB; a default chirp's is 91 kB (1 500 lines). The line count is bounded too (`ident::frf::MAX_CSV_POINTS`) |
//! | [`Kind::MeasuredMap`] | 16 MiB | a map's measured verdicts: one line per cell, at most 10 000 cells |
//! | [`Kind::Recording`] | 4 GiB | the longest job is 2²⁵ ticks (`config::ranges::JOB_TICKS_MAX`); a tick's samples take 34 bytes before compression (16.7 after, measured), so 2²⁵ × 128 bytes leaves room for the envelope, events, older per-tick JSON recordings and the results |
//! | [`Kind::CampaignState`] | 64 MiB | a campaign directory's journal and origin note: the journal's header holds the campaign file and the bench config (1 MiB each, escaped), then about 1 kB per cell for at most 10 000 cells |
//! | [`Kind::CatalogueRow`] | 1 MiB | a campaign cell's catalogue row is one Parquet row, about 9 kB |
//!
//! Layer rule: may use nothing of the crate.

use std::fs::{File, OpenOptions};
use std::io::{self, Read};
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::{Path, PathBuf};

/// What a file is read as; each kind has its own size limit (see the
/// [module docs](self)).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A bench description (TOML): `--config`, a campaign's `config`,
    /// `bench fit --update`'s start bench.
    Config,
    /// A campaign file (TOML), or a campaign directory's copy of it.
    Campaign,
    /// An FRF CSV (`bench chirp --frf-csv`'s format): the inputs of
    /// `fit`, `design`, `plot`, `control --frf`, a campaign cell's.
    FrfCsv,
    /// The measured verdicts of `bench map --measured` (CSV).
    MeasuredMap,
    /// An MCAP recording or the `.part` of a killed run.
    Recording,
    /// A campaign directory's own files: its journal, its origin note.
    CampaignState,
    /// A campaign cell's catalogue row (Parquet).
    CatalogueRow,
    /// A learned feedforward table (`bench track --feedforward`, the
    /// `feedforward.csv` of a run).
    Feedforward,
    /// A reference line (`bench track --scan csv --reference`).
    Reference,
}

/// 1 MiB, bytes.
const MIB: u64 = 1 << 20;

impl Kind {
    /// Every kind (for tests and documentation).
    pub const ALL: [Kind; 9] = [
        Kind::Config,
        Kind::Campaign,
        Kind::FrfCsv,
        Kind::MeasuredMap,
        Kind::Recording,
        Kind::CampaignState,
        Kind::CatalogueRow,
        Kind::Feedforward,
        Kind::Reference,
    ];

    /// The largest file of this kind `bench` reads, bytes (see the
    /// [module docs](self) for why).
    pub const fn limit_bytes(self) -> u64 {
        match self {
            Kind::Config | Kind::Campaign | Kind::CatalogueRow => MIB,
            Kind::FrfCsv | Kind::MeasuredMap | Kind::Feedforward | Kind::Reference => 16 * MIB,
            Kind::Recording => 4 * 1024 * MIB,
            Kind::CampaignState => 64 * MIB,
        }
    }

    /// The kind in the plural, for messages (`configs`, `FRF CSVs`).
    pub const fn plural(self) -> &'static str {
        match self {
            Kind::Config => "configs",
            Kind::Campaign => "campaign files",
            Kind::FrfCsv => "FRF CSVs",
            Kind::MeasuredMap => "measured map CSVs",
            Kind::Recording => "recordings",
            Kind::CampaignState => "campaign journals",
            Kind::CatalogueRow => "catalogue rows",
            Kind::Feedforward => "feedforward tables",
            Kind::Reference => "reference tables",
        }
    }

    /// The kind in the singular, with its article (`a config`, `an FRF
    /// CSV`).
    pub const fn singular(self) -> &'static str {
        match self {
            Kind::Config => "a config",
            Kind::Campaign => "a campaign file",
            Kind::FrfCsv => "an FRF CSV",
            Kind::MeasuredMap => "a measured map CSV",
            Kind::Recording => "a recording",
            Kind::CampaignState => "a campaign journal",
            Kind::CatalogueRow => "a catalogue row",
            Kind::Feedforward => "a feedforward table",
            Kind::Reference => "a reference table",
        }
    }
}

/// A size in bytes as the messages give a limit: `16 MiB`, `4 GiB`.
fn size_text(bytes: u64) -> String {
    if bytes >= 1024 * MIB && bytes.is_multiple_of(1024 * MIB) {
        format!("{} GiB", bytes / (1024 * MIB))
    } else if bytes >= MIB && bytes.is_multiple_of(MIB) {
        format!("{} MiB", bytes / MIB)
    } else {
        format!("{bytes} bytes")
    }
}

/// What is wrong with an input file.
#[derive(Debug)]
pub enum Problem {
    /// It could not be looked at or opened (missing, permission denied).
    Open(io::Error),
    /// Not a regular file: what it is (`a FIFO`, `a character device`).
    NotRegular(&'static str),
    /// Larger than the kind's limit: its size, bytes.
    TooLarge(u64),
    /// It grew past the limit while it was read.
    Grew,
    /// Reading it failed.
    Read(io::Error),
    /// A text kind that is not UTF-8.
    NotUtf8,
}

/// An input file refused: the argument that named it (`key`, as the job
/// options and requests spell it: `config`, `inputs`, `frf`, …), the file,
/// its kind and why. Its text is `PATH: REASON`; [`InputError::reason`]
/// alone is what an option's message (`--config PATH: REASON`) takes.
#[derive(Debug, thiserror::Error)]
#[error("{}: {}", path.display(), self.reason())]
pub struct InputError {
    /// The argument, request field or config key that named the file.
    pub key: &'static str,
    /// The file.
    pub path: PathBuf,
    /// What it was read as.
    pub kind: Kind,
    /// Why it is refused.
    pub problem: Problem,
}

impl InputError {
    /// Why the file is refused, in words, with the limit where one
    /// applies.
    pub fn reason(&self) -> String {
        let kind = self.kind;
        let limit = size_text(kind.limit_bytes());
        match &self.problem {
            Problem::Open(e) => e.to_string(),
            Problem::NotRegular(what) => format!(
                "not a regular file ({what}); bench reads {} only from regular files",
                kind.plural()
            ),
            Problem::TooLarge(bytes) => format!(
                "{bytes} bytes, larger than the {limit} bench reads as {}",
                kind.singular()
            ),
            Problem::Grew => format!(
                "grew past the {limit} bench reads as {} while it was read",
                kind.singular()
            ),
            Problem::Read(e) => format!("cannot read it: {e}"),
            Problem::NotUtf8 => format!("not UTF-8 text: not {}", kind.singular()),
        }
    }

    /// Whether the file was not there (or could not be looked at): the
    /// callers that say "cannot read" keep their wording for it.
    pub fn is_open_error(&self) -> bool {
        matches!(self.problem, Problem::Open(_))
    }

    /// As an [`io::Error`], for readers whose errors are I/O errors: the
    /// OS's error as it was, a refusal as [`io::ErrorKind::InvalidInput`]
    /// with [`reason`](Self::reason) as its text.
    pub fn into_io(self) -> io::Error {
        match self.problem {
            Problem::Open(e) | Problem::Read(e) => e,
            _ => io::Error::new(io::ErrorKind::InvalidInput, self.reason()),
        }
    }
}

/// A file type in words (`a FIFO`), `None` for a regular file.
fn irregular(t: &std::fs::FileType) -> Option<&'static str> {
    Some(if t.is_file() {
        return None;
    } else if t.is_dir() {
        "a directory"
    } else if t.is_fifo() {
        "a FIFO"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "a special file"
    })
}

/// An input file, open and checked (rules 1 and 2 of the [module
/// docs](self)): a regular file of at most its kind's limit when it was
/// opened. Read it whole ([`Opened::read_all`], bounded to the limit + 1
/// byte) or by position ([`Opened::into_file`]).
#[derive(Debug)]
pub struct Opened {
    file: File,
    len: u64,
    key: &'static str,
    path: PathBuf,
    kind: Kind,
}

impl Opened {
    /// The open file, for reading by position (a recording's summary,
    /// read from its end): the size limit holds for what was opened, the
    /// reader bounds its own reads.
    pub fn into_file(self) -> File {
        self.file
    }

    /// Its size when it was opened, bytes (at most the kind's limit).
    pub fn len(&self) -> u64 {
        self.len
    }

    /// Whether it was empty when it was opened.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// All of it, at most the kind's limit: a file that grew past it
    /// while it was read is refused ([`Problem::Grew`]).
    ///
    /// # Errors
    /// [`Problem::Read`], [`Problem::Grew`].
    pub fn read_all(self) -> Result<Vec<u8>, InputError> {
        let limit = self.kind.limit_bytes();
        let Self {
            file,
            len,
            key,
            path,
            kind,
        } = self;
        let fail = |problem| InputError {
            key,
            path: path.clone(),
            kind,
            problem,
        };
        // Room for what fstat said, plus a little for a file still
        // being appended to (never more than the limit).
        let mut bytes = Vec::with_capacity(len.min(limit) as usize + 1);
        file.take(limit + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| fail(Problem::Read(e)))?;
        if bytes.len() as u64 > limit {
            return Err(fail(Problem::Grew));
        }
        Ok(bytes)
    }
}

/// Opens `path`, named by `key`, as a file of `kind`: rules 1 and 2 of the
/// [module docs](self), nothing read yet.
///
/// # Errors
/// [`InputError`]: [`Problem::Open`] (missing, permission denied),
/// [`Problem::NotRegular`], [`Problem::TooLarge`].
pub fn open(path: &Path, kind: Kind, key: &'static str) -> Result<Opened, InputError> {
    let fail = |problem| InputError {
        key,
        path: path.to_path_buf(),
        kind,
        problem,
    };
    // The path's type first: a device is refused without being opened.
    let meta = std::fs::metadata(path).map_err(|e| fail(Problem::Open(e)))?;
    if let Some(what) = irregular(&meta.file_type()) {
        return Err(fail(Problem::NotRegular(what)));
    }
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(path)
        .map_err(|e| fail(Problem::Open(e)))?;
    // Then the descriptor's: what was opened, whatever the path is now.
    let meta = file.metadata().map_err(|e| fail(Problem::Open(e)))?;
    if let Some(what) = irregular(&meta.file_type()) {
        return Err(fail(Problem::NotRegular(what)));
    }
    if meta.len() > kind.limit_bytes() {
        return Err(fail(Problem::TooLarge(meta.len())));
    }
    clear_nonblocking(&file).map_err(|e| fail(Problem::Open(e)))?;
    Ok(Opened {
        file,
        len: meta.len(),
        key,
        path: path.to_path_buf(),
        kind,
    })
}

/// Clears `O_NONBLOCK` on a descriptor (a regular file ignores it; cleared
/// so that nothing downstream sees it).
fn clear_nonblocking(file: &File) -> io::Result<()> {
    use std::os::fd::AsRawFd;
    let fd = file.as_raw_fd();
    // SAFETY: fcntl on a descriptor this `File` owns, with integer
    // arguments only.
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
    if flags < 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: as above.
    if unsafe { libc::fcntl(fd, libc::F_SETFL, flags & !libc::O_NONBLOCK) } < 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

/// The bytes of `path`, named by `key`, read as a file of `kind` under the
/// rules of the [module docs](self).
///
/// # Errors
/// [`InputError`], naming `key`, the file and the reason.
pub fn read(path: &Path, kind: Kind, key: &'static str) -> Result<Vec<u8>, InputError> {
    open(path, kind, key)?.read_all()
}

/// [`read`], as UTF-8 text.
///
/// # Errors
/// As [`read`], and [`Problem::NotUtf8`].
pub fn read_to_string(path: &Path, kind: Kind, key: &'static str) -> Result<String, InputError> {
    String::from_utf8(read(path, kind, key)?).map_err(|_| InputError {
        key,
        path: path.to_path_buf(),
        kind,
        problem: Problem::NotUtf8,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, Instant};

    fn mkfifo(path: &Path) {
        let c = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    }

    #[test]
    fn every_kind_refuses_a_fifo_at_once_a_device_and_a_directory() {
        let d = tempfile::tempdir().unwrap();
        let fifo = d.path().join("fifo");
        mkfifo(&fifo);
        let sock_path = d.path().join("sock");
        let _sock = std::os::unix::net::UnixListener::bind(&sock_path).unwrap();
        for kind in Kind::ALL {
            for (path, what) in [
                (fifo.as_path(), "a FIFO"),
                (Path::new("/dev/zero"), "a character device"),
                (Path::new("/dev/null"), "a character device"),
                (d.path(), "a directory"),
                (sock_path.as_path(), "a socket"),
            ] {
                let t0 = Instant::now();
                let e = read(path, kind, "config").unwrap_err();
                assert!(t0.elapsed() < Duration::from_secs(1));
                assert!(
                    matches!(e.problem, Problem::NotRegular(w) if w == what),
                    "{e}"
                );
                let text = e.to_string();
                assert!(
                    text.starts_with(&format!("{}: not a regular file ({what})", path.display())),
                    "{text}"
                );
                assert!(
                    text.ends_with(&format!(
                        "bench reads {} only from regular files",
                        kind.plural()
                    )),
                    "{text}"
                );
            }
        }
    }

    #[test]
    fn a_link_to_a_fifo_is_a_fifo_and_a_link_to_a_file_is_read() {
        let d = tempfile::tempdir().unwrap();
        let fifo = d.path().join("fifo");
        mkfifo(&fifo);
        let link = d.path().join("link");
        std::os::unix::fs::symlink(&fifo, &link).unwrap();
        let e = read(&link, Kind::FrfCsv, "inputs").unwrap_err();
        assert!(matches!(e.problem, Problem::NotRegular("a FIFO")), "{e}");
        let file = d.path().join("f.csv");
        std::fs::write(&file, "x,y\n").unwrap();
        let link2 = d.path().join("link2");
        std::os::unix::fs::symlink(&file, &link2).unwrap();
        assert_eq!(read(&link2, Kind::FrfCsv, "inputs").unwrap(), b"x,y\n");
    }

    #[test]
    fn the_limit_is_checked_before_reading_and_names_the_size() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("big.toml");
        let f = File::create(&p).unwrap();
        // Sparse: one byte over the limit, nothing written.
        f.set_len(Kind::Config.limit_bytes() + 1).unwrap();
        let e = read(&p, Kind::Config, "config").unwrap_err();
        assert!(matches!(e.problem, Problem::TooLarge(n) if n == (1 << 20) + 1));
        assert_eq!(
            e.reason(),
            "1048577 bytes, larger than the 1 MiB bench reads as a config"
        );
        // At the limit: read.
        f.set_len(Kind::Config.limit_bytes()).unwrap();
        assert_eq!(read(&p, Kind::Config, "config").unwrap().len(), 1 << 20);
        // A recording's limit is 4 GiB: a sparse 5 GiB file is refused
        // without reading it.
        let r = d.path().join("huge.mcap");
        File::create(&r).unwrap().set_len(5 << 30).unwrap();
        let e = open(&r, Kind::Recording, "recording").unwrap_err();
        assert!(
            e.reason()
                .ends_with("larger than the 4 GiB bench reads as a recording"),
            "{e}"
        );
    }

    #[test]
    fn a_file_that_grows_while_read_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("growing.csv");
        std::fs::write(&p, "x").unwrap();
        let opened = open(&p, Kind::Config, "config").unwrap();
        assert_eq!(opened.len(), 1);
        // Grows past the limit after the check, before the read.
        File::options()
            .write(true)
            .open(&p)
            .unwrap()
            .set_len(Kind::Config.limit_bytes() + 10)
            .unwrap();
        let e = opened.read_all().unwrap_err();
        assert!(matches!(e.problem, Problem::Grew), "{e}");
        assert!(e.reason().contains("grew past the 1 MiB"), "{e}");
    }

    #[test]
    fn missing_unreadable_and_not_utf8() {
        let d = tempfile::tempdir().unwrap();
        let e = read(&d.path().join("nope"), Kind::FrfCsv, "frf").unwrap_err();
        assert!(e.is_open_error());
        assert!(e.to_string().contains("No such file"), "{e}");
        let p = d.path().join("bin.csv");
        std::fs::write(&p, [0xff, 0xfe]).unwrap();
        let e = read_to_string(&p, Kind::FrfCsv, "frf").unwrap_err();
        assert_eq!(e.reason(), "not UTF-8 text: not an FRF CSV");
    }

    #[test]
    fn limits_are_the_documented_ones() {
        assert_eq!(Kind::Config.limit_bytes(), 1 << 20);
        assert_eq!(Kind::Campaign.limit_bytes(), 1 << 20);
        assert_eq!(Kind::FrfCsv.limit_bytes(), 16 << 20);
        assert_eq!(Kind::MeasuredMap.limit_bytes(), 16 << 20);
        assert_eq!(Kind::Recording.limit_bytes(), 4 << 30);
        assert_eq!(Kind::CampaignState.limit_bytes(), 64 << 20);
        assert_eq!(Kind::CatalogueRow.limit_bytes(), 1 << 20);
        assert_eq!(size_text(16 << 20), "16 MiB");
        assert_eq!(size_text(4 << 30), "4 GiB");
        assert_eq!(size_text(1000), "1000 bytes");
    }
}
