//! The files a run writes (recording, FRF CSV, plot): the rules that keep
//! a run from losing or damaging a file, in one place.
//!
//! # Rules
//!
//! 1. **Nothing is replaced without `--overwrite`** but a product derived
//!    from an input that stays ([`Origin::Regenerated`]: `bench fit`'s
//!    default plot and exported model beside its FRF), which a rerun on
//!    the same input replaces. An output path that
//!    exists is refused before the run ([`Existing::Refuse`]), and the final
//!    rename never replaces a file that appeared while the run was writing
//!    ([`commit`] uses `renameat2(RENAME_NOREPLACE)`, or a hard link where
//!    the file system has no such rename). With `--overwrite`
//!    ([`Existing::Replace`]) an existing *regular file* is replaced, and only
//!    once its successor is complete. The daemon never replaces anything:
//!    its jobs name their own outputs.
//! 2. **Only regular files are ever replaced.** An existing output path that
//!    is a symbolic link, a device node, a FIFO, a socket or a directory is
//!    refused even with `--overwrite`: as root, `--plot /dev/null` would
//!    otherwise replace `/dev/null`, and a link would redirect the write to
//!    wherever it points. Directories above the file may be links.
//! 3. **Default names are unique.** [`claim_recording`] stamps the name to
//!    the millisecond and claims it by creating its `.part` file with
//!    `O_CREAT | O_EXCL`. A name whose `.part` or any companion (the
//!    recording itself, its FRF CSV or plot) exists is skipped for the next
//!    counter suffix (`-1`, `-2`, …). Two runs can never hold one name.
//! 4. **Every output is written under a temporary name in its directory**
//!    (the recording as `<name>.part`, the others as a hidden
//!    `.<name>.<pid>.<n>.tmp`), synced, and renamed to its final name only
//!    when complete ([`write_atomically`]). A failed write (a full disk)
//!    removes the temporary file: nothing incomplete carries a final name.
//! 5. **No two outputs of a run may be the same file**, however spelled
//!    (`./a` and `a`, `d/../a`, a linked directory): [`OutputPlan::check`]
//!    compares the canonical directory and the file name of every output,
//!    the recording's `.part` name included, and refuses the run.
//! 6. **An output never replaces an input**, even with `--overwrite`: an
//!    output path (given, derived or a `.part` name) that is one of the
//!    job's input files ([`OutputPlan::with_input`]: the FRFs, the
//!    config, the recording it reads) is refused. Files are compared by
//!    device and inode, links followed (by canonical path for an input
//!    that cannot be looked at), so `./X.csv`, `d/../X.csv`, a symbolic
//!    link to it and a hard link of it are all `X.csv`.
//! 7. **Paths are checked before anything is enabled**
//!    ([`OutputPlan::check`]): valid UTF-8 (summaries and recordings carry
//!    them as JSON strings), a file name, an existing directory that can be
//!    written, and rules 1, 2, 5 and 6.
//! 8. **Files are created with mode [`FILE_MODE`] (0640)**, given to the
//!    open call (never a chmod afterwards, so no instant is world-readable),
//!    and narrowed further by the umask: the owner writes, the owner's group
//!    may read, others get nothing. This follows the daemon's socket, which
//!    is owner-only, or shared with one group (`--socket-group`).
//!
//! # Errors
//!
//! Refusals are [`RunError::BadOption`] naming the option (`out`,
//! `frf_csv`, `plot`; the CLI shows `--out`, `--frf-csv`, `--plot`), the
//! path and the reason; a collision names the other option in the reason.
//! Writers return [`io::Error`]s: [`io::ErrorKind::AlreadyExists`] when the
//! final name appeared meanwhile, [`io::ErrorKind::InvalidInput`] when it
//! became something other than a regular file.
//!
//! The checks run before the run, the final renames after it; a file that
//! changes type between the two (another process replacing a regular file
//! with a device node in that window) is refused again by [`commit`], but
//! an attacker who can write the output directory can always race a rename.
//! Output directories should not be writable by untrusted users.
//!
//! Layer rule: may use `error`.

use crate::error::RunError;
use std::ffi::OsString;
use std::fs::{self, File, OpenOptions};
use std::io;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Suffix appended to the final file name while it is written.
pub const PART_SUFFIX: &str = ".part";

/// `<final_path>.part`: where a file is written until it is complete.
pub fn part_path_for(final_path: &Path) -> PathBuf {
    let mut s = final_path.as_os_str().to_owned();
    s.push(PART_SUFFIX);
    PathBuf::from(s)
}

/// Mode of every file `bench` creates (recordings, `.part` files, FRF CSVs,
/// plots, the daemon's event log), before the umask: `rw-r-----`.
pub const FILE_MODE: u32 = 0o640;

/// Mode of a directory `bench` creates for its recordings (the daemon's
/// `--recordings`): 0750, the directory counterpart of [`FILE_MODE`],
/// narrowed by the umask.
pub const DIR_MODE: u32 = 0o750;

/// Largest counter suffix [`claim_recording`] tries in one millisecond.
const MAX_CLAIM_ATTEMPTS: u32 = 10_000;

/// What to do with an output path that exists.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Existing {
    /// Refuse the run, and never replace a file at the final rename (the
    /// default, and always in the daemon).
    #[default]
    Refuse,
    /// `--overwrite`: replace an existing regular file once its successor
    /// is complete. Anything but a regular file is still refused.
    Replace,
}

impl Existing {
    /// [`Existing::Replace`] when `overwrite`, else [`Existing::Refuse`].
    pub fn overwrite(overwrite: bool) -> Self {
        if overwrite {
            Self::Replace
        } else {
            Self::Refuse
        }
    }
}

/// The paths a local run's flags gave its outputs, by output name: the
/// option key its errors name (`out`, `png`, `csv`, `model_out`, …).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Given(Vec<(&'static str, PathBuf)>);

impl Given {
    /// With `path` as output `name`'s, when a flag gave one.
    pub fn with(mut self, name: &'static str, path: Option<PathBuf>) -> Self {
        if let Some(p) = path {
            self.0.push((name, p));
        }
        self
    }

    /// The path given for output `name`.
    pub fn get(&self, name: &str) -> Option<&PathBuf> {
        self.0.iter().find(|(n, _)| *n == name).map(|(_, p)| p)
    }
}

/// Where a job's outputs go: the one thing the command line and the
/// daemon decide differently about a job, so that the rest of its plan is
/// one function for both (`plan_*` in [`crate::jobs`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Destination {
    /// A local run: each output where its flag put it, else the job's
    /// default name (beside its input, or stamped in the default
    /// recordings directory); an existing file replaced only as
    /// `existing` says (`--overwrite`).
    Local {
        /// The outputs' paths the flags gave (`--out`, `--png`, …).
        given: Given,
        /// `--overwrite` or not.
        existing: Existing,
    },
    /// A daemon's job: its outputs beside `stem`, the daemon's stamped name
    /// in its recordings directory (`export-<stamp>-job<N>.mcap`); nothing
    /// is ever replaced.
    Daemon {
        /// The job's stamped stem ([`stamped_recording`]).
        stem: PathBuf,
    },
}

impl Destination {
    /// A local run's: the paths `given`, an existing file replaced when
    /// `overwrite` (`--overwrite`).
    pub fn local(given: Given, overwrite: bool) -> Self {
        Self::Local {
            given,
            existing: Existing::overwrite(overwrite),
        }
    }

    /// What an existing output meets: the local `--overwrite`, never a
    /// replacement on the daemon.
    pub fn existing(&self) -> Existing {
        match self {
            Self::Local { existing, .. } => *existing,
            Self::Daemon { .. } => Existing::Refuse,
        }
    }

    /// The path a flag gave output `name` (a local run's; `None` on the
    /// daemon, which names its own).
    pub fn given(&self, name: &str) -> Option<PathBuf> {
        match self {
            Self::Local { given, .. } => given.get(name).cloned(),
            Self::Daemon { .. } => None,
        }
    }

    /// Output `name`: its flag's path ([`Origin::Given`]), else
    /// `default()` locally ([`Origin::Derived`]; its error when the job
    /// has no default for that input), or the daemon's stem with `suffix`
    /// ([`beside`], [`Origin::Default`]).
    ///
    /// # Errors
    /// `default`'s.
    pub fn output(
        &self,
        name: &str,
        suffix: &str,
        default: impl FnOnce() -> Result<PathBuf, RunError>,
    ) -> Result<(PathBuf, Origin), RunError> {
        Ok(match self {
            Self::Local { given, .. } => match given.get(name) {
                Some(p) => (p.clone(), Origin::Given),
                None => (default()?, Origin::Derived),
            },
            Self::Daemon { stem } => (beside(stem, suffix), Origin::Default),
        })
    }

    /// An output the job names itself when it runs locally: the flag's
    /// path or `None` (the job's own default, beside its input), and on
    /// the daemon `daemon_name(stem)` when the request `wants` the output.
    pub fn optional(
        &self,
        name: &str,
        wants: bool,
        daemon_name: impl FnOnce(&Path) -> PathBuf,
    ) -> Option<PathBuf> {
        match self {
            Self::Local { given, .. } => given.get(name).cloned(),
            Self::Daemon { stem } => wants.then(|| daemon_name(stem)),
        }
    }

    /// The stem of outputs that have no input to stand beside: the
    /// daemon's, or locally a fresh stamped name `PREFIX-<stamp>` in the
    /// default recordings directory ([`default_recordings`], created if
    /// missing; the name is not claimed).
    ///
    /// # Errors
    /// [`RunError::BadOption`] naming output `name` when there is no
    /// default recordings directory.
    pub fn stem(&self, prefix: &str, name: &'static str) -> Result<PathBuf, RunError> {
        match self {
            Self::Local { .. } => {
                let dir = default_recordings(true, "its path")
                    .map_err(|reason| RunError::option(name, "", reason))?;
                Ok(stamped_recording(&dir, prefix, ""))
            }
            Self::Daemon { stem } => Ok(stem.clone()),
        }
    }
}

impl Destination {
    /// The recording of a job that records (chirp, control) and the plan
    /// its outputs join: locally `--out` (which must end in `.mcap`), else
    /// a fresh name `PREFIX-<stamp>.mcap` in the default recordings
    /// directory, claimed at once with its `companions`' names left free
    /// ([`claim_recording`]); on the daemon its stem. With `claim` false
    /// (`--check-only`, which writes nothing) a local default name is
    /// neither claimed nor checked, and the directory not created.
    ///
    /// # Errors
    /// [`RunError::BadOption`] naming `out`: not `.mcap`, no default
    /// recordings directory, or no name could be claimed.
    pub fn recording(
        &self,
        prefix: &str,
        companions: &[&str],
        claim: bool,
    ) -> Result<(PathBuf, OutputPlan), RunError> {
        let plan = OutputPlan::new(self.existing());
        let no_dir = |reason| RunError::option("out", "", reason);
        let (out, plan) = match self {
            Self::Daemon { stem } => (stem.clone(), plan.with_recording(stem, Origin::Default)),
            Self::Local { given, .. } => match given.get("out") {
                Some(out) if !claim => (out.clone(), plan),
                Some(out) => (out.clone(), plan.with_recording(out, Origin::Given)),
                None if !claim => {
                    let dir = default_recordings(false, "--out FILE.mcap").map_err(no_dir)?;
                    (stamped_recording(&dir, prefix, ""), plan)
                }
                None => {
                    let dir = default_recordings(true, "--out FILE.mcap").map_err(no_dir)?;
                    let claim = claim_recording(&dir, prefix, companions)?;
                    (
                        claim.path().to_path_buf(),
                        plan.with_claimed_recording(claim),
                    )
                }
            },
        };
        if out.extension().and_then(|e| e.to_str()) != Some("mcap") {
            return Err(RunError::option(
                "out",
                out.display(),
                "the recording must end in .mcap",
            ));
        }
        Ok((out, plan))
    }

    /// Output `name` beside a recording: its flag's path
    /// ([`Origin::Given`]), else `default` ([`Origin::Derived`]).
    pub fn beside_recording(&self, name: &str, default: PathBuf) -> (PathBuf, Origin) {
        match self.given(name) {
            Some(p) => (p, Origin::Given),
            None => (default, Origin::Derived),
        }
    }
}

/// The recordings directory in the working directory that, when it
/// exists, takes the recordings (a checkout of the repository has one).
pub const LOCAL_RECORDINGS: &str = "recordings";

/// Where a local run's recordings go by default, as an absolute path:
/// `./recordings` when that directory exists in the working directory,
/// else `$XDG_DATA_HOME/bench/recordings`, with `XDG_DATA_HOME` defaulting
/// to `$HOME/.local/share` when it is unset, empty or relative (XDG Base
/// Directory specification). With `create`, the XDG directory and its
/// parents are made with mode [`DIR_MODE`].
///
/// # Errors
/// A message that ends by asking to `give` the path (`--out`,
/// `--recordings`) when neither `XDG_DATA_HOME` nor `HOME` is an absolute
/// path, or the directory cannot be created.
pub fn default_recordings(create: bool, give: &str) -> Result<PathBuf, String> {
    let cwd = std::env::current_dir()
        .map_err(|e| format!("the working directory is unreadable ({e}): give {give}"))?;
    let local = cwd.join(LOCAL_RECORDINGS);
    if local.is_dir() {
        return Ok(local);
    }
    let absolute = |var: &str| {
        std::env::var_os(var)
            .map(PathBuf::from)
            .filter(|p| p.is_absolute())
    };
    let data_home = absolute("XDG_DATA_HOME")
        .or_else(|| absolute("HOME").map(|h| h.join(".local/share")))
        .ok_or_else(|| {
            format!(
                "no ./recordings here, and neither XDG_DATA_HOME nor HOME is an absolute path: give {give}, or create ./recordings"
            )
        })?;
    let dir = data_home.join("bench").join("recordings");
    if create {
        use std::os::unix::fs::DirBuilderExt;
        fs::DirBuilder::new()
            .recursive(true)
            .mode(DIR_MODE)
            .create(&dir)
            .map_err(|e| format!("cannot create {} ({e}): give {give}", dir.display()))?;
    }
    Ok(dir)
}

/// Where an output's path came from (for the messages).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Origin {
    /// Given on the command line.
    Given,
    /// Derived from the recording's name (`<stem>.frf.csv`, …).
    Derived,
    /// A default name chosen by `bench`.
    Default,
    /// Derived from an input that stays (a fit's plot or exported model
    /// beside its FRF): the input's own product, which a rerun on the same
    /// input makes again. An existing regular file is replaced (once its
    /// successor is complete) without `--overwrite`: a derived output never
    /// blocks a rerun. Never a recording, an updated bench or anything a
    /// user may have edited.
    Regenerated,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    /// An output file.
    File(Origin),
    /// The `.part` name of the recording.
    Part,
    /// The `.part` name of a claimed recording (it exists: it is ours).
    ClaimedPart,
}

#[derive(Debug)]
struct Output {
    key: &'static str,
    path: PathBuf,
    role: Role,
}

impl Output {
    /// How a message names this output, e.g. `--plot`, `the default
    /// --frf-csv (derived from --out)`; `derived_from` names what a derived
    /// path comes from.
    fn describe(&self, derived_from: &str) -> String {
        let flag = flag(self.key);
        match self.role {
            Role::File(Origin::Given) => flag.to_string(),
            Role::File(Origin::Derived | Origin::Regenerated) => {
                format!("the default {flag} (derived from {derived_from})")
            }
            Role::File(Origin::Default) => format!("the default {flag}"),
            Role::Part | Role::ClaimedPart => format!("the temporary name of the {flag} recording"),
        }
    }
}

/// The flag of an output option (for messages that name a second option).
fn flag(key: &str) -> &str {
    match key {
        "out" => "--out",
        "frf_csv" => "--frf-csv",
        // The figure of `bench chirp` and `control` (`--png`; `--plot`,
        // its old spelling, is read as it).
        "plot" | "png" => "--png",
        other => other,
    }
}

/// A default recording name claimed by [`claim_recording`]: its `.part`
/// file exists, empty, created by this process. Dropped unused (the run was
/// refused before recording), it removes that file.
#[derive(Debug)]
pub struct Claim {
    path: PathBuf,
    part: PathBuf,
    file: Option<File>,
}

impl Claim {
    /// The recording's final path.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for Claim {
    fn drop(&mut self) {
        if self.file.take().is_some() {
            let _ = fs::remove_file(&self.part);
        }
    }
}

/// The file that goes with `path` (a recording or a table): `<stem><suffix>`
/// in the same directory, where `<stem>` is the file name without a
/// trailing `.part` and then without one `.mcap` or `.csv`
/// (`x.mcap.part`, `x.mcap` and `x.csv` all give `x`; `x.frf.csv` gives
/// `x.frf`; any other name is kept whole). The one rule for every default
/// output beside another file: the FRF CSV and plots beside a recording
/// (`.frf.csv`, `.bode.png`, `.step.png`), the fit's plot and updated bench
/// beside its input (`.fit.png`, `.updated.toml`), the daemon's and
/// `bench analyze`'s outputs beside a stamped name.
pub fn beside(path: &Path, suffix: &str) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name = name.strip_suffix(".part").unwrap_or(&name);
    let stem = [".mcap", ".csv"]
        .iter()
        .find_map(|ext| name.strip_suffix(ext))
        .unwrap_or(name);
    path.with_file_name(format!("{stem}{suffix}"))
}

/// `dir/PREFIX-YYYYmmddTHHMMSS.mmmZSUFFIX.mcap` (UTC, to the millisecond):
/// a stamped recording name (the daemon's jobs: `SUFFIX` is `-job<N>`), or
/// the stem of stamped outputs through [`beside`]. The name is not claimed:
/// a job refuses it if it exists. Local runs claim theirs with
/// [`claim_recording`].
pub fn stamped_recording(dir: &Path, prefix: &str, suffix: &str) -> PathBuf {
    dir.join(format!("{prefix}-{}{suffix}.mcap", stamp()))
}

/// `YYYYmmddTHHMMSS.mmmZ` (UTC, ISO 8601 basic format with milliseconds).
pub fn stamp() -> String {
    let now = time::OffsetDateTime::now_utc();
    let fmt = time::macros::format_description!(
        "[year][month][day]T[hour][minute][second].[subsecond digits:3]Z"
    );
    now.format(&fmt).unwrap_or_else(|_| "now".into())
}

/// Claims a fresh default recording name `dir/PREFIX-<stamp>[-N].mcap`
/// (see rule 3 of the [module docs](self)): creates its `.part` file with
/// `O_EXCL` and mode [`FILE_MODE`], and skips names whose `.part`, final
/// name, or `<stem>COMPANION` (e.g. `.frf.csv`) exists.
///
/// # Errors
/// [`RunError::BadOption`] naming `out` when `dir` is missing or not
/// writable, or (never in practice) every counter is taken.
pub fn claim_recording(dir: &Path, prefix: &str, companions: &[&str]) -> Result<Claim, RunError> {
    claim_with_stamp(dir, prefix, &stamp(), companions)
}

fn claim_with_stamp(
    dir: &Path,
    prefix: &str,
    stamp: &str,
    companions: &[&str],
) -> Result<Claim, RunError> {
    for n in 0..MAX_CLAIM_ATTEMPTS {
        let name = if n == 0 {
            format!("{prefix}-{stamp}")
        } else {
            format!("{prefix}-{stamp}-{n}")
        };
        let path = dir.join(format!("{name}.mcap"));
        let part = part_path_for(&path);
        let file = match create_new(&part) {
            Ok(f) => f,
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => continue,
            Err(e) => {
                return Err(RunError::option(
                    "out",
                    dir.display(),
                    format!("cannot create a recording in this directory: {e}"),
                ))
            }
        };
        let claim = Claim {
            path,
            part,
            file: Some(file),
        };
        let taken = std::iter::once(claim.path.clone())
            .chain(companions.iter().map(|c| dir.join(format!("{name}{c}"))))
            .any(|p| p.symlink_metadata().is_ok());
        if taken {
            continue; // dropping the claim removes its .part
        }
        return Ok(claim);
    }
    Err(RunError::option(
        "out",
        dir.display(),
        format!("no free recording name {prefix}-{stamp}-N"),
    ))
}

/// An input of the run ([`OutputPlan::with_input`]), which no output may
/// be.
#[derive(Debug)]
struct Input {
    key: &'static str,
    path: PathBuf,
}

/// How a message names an input: its flag, or `the input` for a
/// positional argument.
fn input_name(key: &str) -> String {
    match key {
        "config" | "frf" | "measured" | "campaign" => format!("--{key}"),
        "recording" | "recordings" | "part" => "the recording".into(),
        _ => "the input".into(),
    }
}

/// The identity of an existing file: (device, inode), links followed.
fn file_id(path: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt;
    fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
}

/// The outputs of one run, checked together before anything is enabled
/// (rules 1, 2, 5, 6 and 7 of the [module docs](self)), and the policy
/// their writers follow.
#[derive(Debug)]
pub struct OutputPlan {
    existing: Existing,
    outputs: Vec<Output>,
    inputs: Vec<Input>,
    claim: Option<Claim>,
    derived_from: &'static str,
}

impl OutputPlan {
    /// An empty plan; derived outputs are named as derived from `--out`
    /// ([`Self::derived_from`]).
    pub fn new(existing: Existing) -> Self {
        Self {
            existing,
            outputs: Vec::new(),
            inputs: Vec::new(),
            claim: None,
            derived_from: "--out",
        }
    }

    /// Says in messages that the [`Origin::Derived`] paths derive from
    /// `what` (`--out` unless set; `bench fit`: `the input`).
    pub fn derived_from(mut self, what: &'static str) -> Self {
        self.derived_from = what;
        self
    }

    /// Adds the recording (`out`) at `path`, and its `.part` name.
    pub fn with_recording(mut self, path: &Path, origin: Origin) -> Self {
        self.outputs.push(Output {
            key: "out",
            path: path.to_path_buf(),
            role: Role::File(origin),
        });
        self.outputs.push(Output {
            key: "out",
            path: part_path_for(path),
            role: Role::Part,
        });
        self
    }

    /// Adds a recording whose name [`claim_recording`] claimed; its `.part`
    /// file is handed to the recorder by [`take_claimed_part`](Self::take_claimed_part).
    pub fn with_claimed_recording(mut self, claim: Claim) -> Self {
        self.outputs.push(Output {
            key: "out",
            path: claim.path.clone(),
            role: Role::File(Origin::Default),
        });
        self.outputs.push(Output {
            key: "out",
            path: claim.part.clone(),
            role: Role::ClaimedPart,
        });
        self.claim = Some(claim);
        self
    }

    /// Adds the output `key` (`frf_csv`, `plot`) at `path`.
    pub fn with_output(mut self, key: &'static str, path: &Path, origin: Origin) -> Self {
        self.outputs.push(Output {
            key,
            path: path.to_path_buf(),
            role: Role::File(origin),
        });
        self
    }

    /// Adds an input of the run, named by `key` (`inputs`, `config`,
    /// `frf`, `recording`, …): [`check`](Self::check) refuses any output
    /// that is the same file (rule 6 of the [module docs](self)). A path
    /// that does not exist (the built-in config's name) is no file, and
    /// nothing can be written over it.
    pub fn with_input(mut self, key: &'static str, path: &Path) -> Self {
        self.add_input(key, path);
        self
    }

    /// [`with_input`](Self::with_input) on a plan built elsewhere.
    pub fn add_input(&mut self, key: &'static str, path: &Path) {
        self.inputs.push(Input {
            key,
            path: path.to_path_buf(),
        });
    }

    /// [`with_input`](Self::with_input) for each of `paths`.
    pub fn with_inputs<P: AsRef<Path>>(
        mut self,
        key: &'static str,
        paths: impl IntoIterator<Item = P>,
    ) -> Self {
        for p in paths {
            self.add_input(key, p.as_ref());
        }
        self
    }

    /// Refuses `o` when it is one of the inputs (rule 6): the same device
    /// and inode as an existing input (links followed: a symbolic or hard
    /// link is the file); for an input that cannot be looked at, the same
    /// canonical path. One `stat` per input: a catalogue's thousands of
    /// recordings cost milliseconds.
    fn check_not_an_input(&self, o: &Output) -> Result<(), RunError> {
        if self.inputs.is_empty() {
            return Ok(());
        }
        let out_id = file_id(&o.path);
        let out_canonical = std::cell::OnceCell::new();
        let out_canonical = || {
            out_canonical
                .get_or_init(|| {
                    o.path.canonicalize().ok().or_else(|| {
                        let name = o.path.file_name()?;
                        Some(parent_dir(&o.path).canonicalize().ok()?.join(name))
                    })
                })
                .clone()
        };
        for i in &self.inputs {
            let in_id = file_id(&i.path);
            let same = match (out_id, in_id) {
                // Two files that exist: one file when one inode.
                (Some(a), Some(b)) => a == b,
                // A new output is no input that exists.
                (None, Some(_)) => false,
                // An input that could not be looked at: by the canonical
                // path.
                (_, None) => out_canonical().is_some_and(|c| Some(c) == i.path.canonicalize().ok()),
            };
            if same {
                let what = match o.role {
                    Role::Part | Role::ClaimedPart => {
                        format!("the temporary name {} of the recording", o.path.display())
                    }
                    Role::File(_) => "the output".into(),
                };
                return Err(RunError::option(
                    o.key,
                    o.path.display(),
                    format!(
                        "{what} is the same file as {} {}; bench never writes over a file it reads, even with --overwrite",
                        input_name(i.key),
                        i.path.display()
                    ),
                ));
            }
        }
        Ok(())
    }

    /// What the writers do with a file that exists.
    pub fn existing(&self) -> Existing {
        self.existing
    }

    /// The claimed recording's `.part` file, opened for writing, once (see
    /// [`with_claimed_recording`](Self::with_claimed_recording)).
    pub fn take_claimed_part(&mut self) -> Option<File> {
        self.claim.as_mut().and_then(|c| c.file.take())
    }

    /// Checks every output against the inputs, then alone, then every
    /// pair (rules 1, 2, 5, 6, 7).
    ///
    /// # Errors
    /// [`RunError::BadOption`] naming the output's option and path: the
    /// same file as an input (the reason names it; with or without
    /// `--overwrite`); not UTF-8; no file name; directory missing, not a
    /// directory or not writable; an existing symlink or non-regular file;
    /// an existing file without [`Existing::Replace`]; the same file as
    /// another output (the reason names it).
    pub fn check(&self) -> Result<(), RunError> {
        for o in &self.outputs {
            self.check_not_an_input(o)?;
        }
        let mut seen: Vec<(&Output, (PathBuf, OsString))> = Vec::with_capacity(self.outputs.len());
        for o in &self.outputs {
            let id = self.check_one(o)?;
            if let Some((first, _)) = seen.iter().find(|(_, other)| *other == id) {
                // Report it under the option the user gave, if any.
                let (a, b) = if matches!(o.role, Role::File(Origin::Given)) {
                    (o, *first)
                } else {
                    (*first, o)
                };
                return Err(RunError::option(
                    a.key,
                    a.path.display(),
                    format!(
                        "is the same file as {} ({}): one would be lost",
                        b.describe(self.derived_from),
                        b.path.display()
                    ),
                ));
            }
            seen.push((o, id));
        }
        Ok(())
    }

    /// Checks one output; returns its identity (canonical directory, file
    /// name).
    fn check_one(&self, o: &Output) -> Result<(PathBuf, OsString), RunError> {
        let subject = o.path.display();
        let bad = |reason: String| RunError::option(o.key, &subject, reason);
        if o.path.to_str().is_none() {
            return Err(bad(
                "is not valid UTF-8 (summaries and recordings name their files in JSON)".into(),
            ));
        }
        let name = match o.path.file_name() {
            Some(n) if !o.path.as_os_str().as_bytes().ends_with(b"/") => n.to_os_string(),
            _ => return Err(bad("is not a file path".into())),
        };
        let dir = parent_dir(&o.path);
        match dir.metadata() {
            Ok(m) if m.is_dir() => {}
            Ok(_) => return Err(bad(format!("{} is not a directory", dir.display()))),
            Err(e) => return Err(bad(format!("directory {}: {e}", dir.display()))),
        }
        match o.path.symlink_metadata() {
            Ok(m) if m.file_type().is_symlink() => {
                return Err(bad(
                    "is a symbolic link; bench writes only to regular files (give the link's target)"
                        .into(),
                ))
            }
            Ok(m) if !m.is_file() => {
                return Err(bad(format!(
                    "is {}, not a regular file; bench never replaces one, even with --overwrite",
                    kind_of(&m.file_type())
                )))
            }
            Ok(_) if o.role == Role::ClaimedPart => {}
            Ok(_) if o.role == Role::File(Origin::Regenerated) => {}
            Ok(_) if self.existing == Existing::Refuse => {
                return Err(bad(match o.role {
                    Role::Part => format!(
                        "the partial recording {} of an earlier run exists; read or move it, or give --overwrite",
                        o.path.display()
                    ),
                    _ => format!(
                        "exists{}; bench never replaces a file unless --overwrite is given",
                        match o.role {
                            Role::File(Origin::Derived) =>
                                format!(" (the default name, derived from {})", self.derived_from),
                            _ => String::new(),
                        }
                    ),
                }))
            }
            Ok(_) => {}
            Err(e) if e.kind() == io::ErrorKind::NotFound => {}
            Err(e) => return Err(bad(e.to_string())),
        }
        // Writable: create and remove a temporary file where the output's
        // temporary file will go.
        if matches!(o.role, Role::File(_)) {
            let probe = temp_path(&o.path);
            match create_new(&probe) {
                Ok(_) => {
                    let _ = fs::remove_file(&probe);
                }
                Err(e) => return Err(bad(format!("cannot write in {}: {e}", dir.display()))),
            }
        }
        let canonical = dir
            .canonicalize()
            .map_err(|e| bad(format!("directory {}: {e}", dir.display())))?;
        Ok((canonical, name))
    }
}

/// A file type in words.
fn kind_of(t: &fs::FileType) -> &'static str {
    if t.is_dir() {
        "a directory"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_fifo() {
        "a FIFO"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_symlink() {
        "a symbolic link"
    } else {
        "a special file"
    }
}

/// The directory of `path` (`.` for a bare file name).
fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Creates `path` exclusively (`O_CREAT | O_EXCL`, which also refuses a
/// symbolic link) with mode [`FILE_MODE`].
///
/// # Errors
/// The OS error; [`io::ErrorKind::AlreadyExists`] when `path` exists.
pub fn create_new(path: &Path) -> io::Result<File> {
    OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(FILE_MODE)
        .open(path)
}

/// Creates a recording's `.part` file: exclusively, or with
/// [`Existing::Replace`] after removing a regular file of that name (the
/// partial recording of an earlier run).
///
/// # Errors
/// The OS error; [`io::ErrorKind::AlreadyExists`] when it exists and may not
/// be replaced, [`io::ErrorKind::InvalidInput`] when it is not a regular
/// file.
pub fn create_part(part: &Path, existing: Existing) -> io::Result<File> {
    match create_new(part) {
        Err(e) if e.kind() == io::ErrorKind::AlreadyExists && existing == Existing::Replace => {
            ensure_regular(part)?;
            fs::remove_file(part)?;
            create_new(part)
        }
        r => r,
    }
}

/// Errors unless `path` is a regular file or does not exist.
fn ensure_regular(path: &Path) -> io::Result<()> {
    match path.symlink_metadata() {
        Ok(m) if !m.is_file() => Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!(
                "{} is {}, not a regular file; not replaced",
                path.display(),
                kind_of(&m.file_type())
            ),
        )),
        _ => Ok(()),
    }
}

/// Removes the hidden temporaries ([`temp_path`]) that writes of `path`
/// killed before their rename left beside it (`.<name>.<pid>.<n>.tmp`):
/// call it only where no other writer of `path` can be running (a
/// campaign cell about to be run again). A missing directory is none.
///
/// # Errors
/// Reading the directory or removing a temporary.
pub fn remove_stale_temporaries(path: &Path) -> io::Result<()> {
    let prefix = format!(
        ".{}.",
        path.file_name().unwrap_or_default().to_string_lossy()
    );
    let entries = match fs::read_dir(parent_dir(path)) {
        Ok(e) => e,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(e),
    };
    // Exactly `temp_path`'s form: the file's own, not one of a longer
    // name that starts with it (`.<name>.x.<pid>.<n>.tmp`).
    let is_number = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    for entry in entries {
        let entry = entry?;
        let name = entry.file_name();
        let name = name.to_string_lossy();
        let ours = name
            .strip_prefix(&prefix)
            .and_then(|rest| rest.strip_suffix(".tmp"))
            .and_then(|rest| rest.split_once('.'))
            .is_some_and(|(pid, n)| is_number(pid) && is_number(n));
        if ours {
            fs::remove_file(entry.path())?;
        }
    }
    Ok(())
}

/// A fresh hidden temporary name beside `path`:
/// `.<name>.<pid>.<n>.tmp`.
fn temp_path(path: &Path) -> PathBuf {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let mut name = OsString::from(".");
    name.push(path.file_name().unwrap_or_default());
    name.push(format!(
        ".{}.{}.tmp",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    parent_dir(path).join(name)
}

/// [`write_atomically`] through a buffer: `write` gets a buffered writer
/// of the temporary file, flushed before the file is synced.
///
/// # Errors
/// As [`write_atomically`].
pub fn write_buffered_atomically(
    path: &Path,
    existing: Existing,
    write: impl FnOnce(&mut io::BufWriter<&mut File>) -> io::Result<()>,
) -> io::Result<()> {
    write_atomically(path, existing, |f| {
        let mut w = io::BufWriter::new(f);
        write(&mut w)?;
        io::Write::flush(&mut w)
    })
}

/// Writes `path` through a temporary file beside it (rule 4 of the
/// [module docs](self)): `write` fills the temporary file (mode
/// [`FILE_MODE`]), which is synced, [`commit`]ted to `path`, and the
/// directory synced (best effort). On any
/// error the temporary file is removed and nothing is left under `path`.
///
/// # Errors
/// The error of `write`, of syncing, or of [`commit`].
pub fn write_atomically(
    path: &Path,
    existing: Existing,
    write: impl FnOnce(&mut File) -> io::Result<()>,
) -> io::Result<()> {
    let tmp = temp_path(path);
    let mut file = create_new(&tmp)?;
    let result = write(&mut file)
        .and_then(|()| file.sync_all())
        .and_then(|()| {
            drop(file);
            commit(&tmp, path, existing)
        });
    match result {
        Ok(()) => {
            if let Ok(d) = File::open(parent_dir(path)) {
                let _ = d.sync_all();
            }
            Ok(())
        }
        Err(e) => {
            let _ = fs::remove_file(&tmp);
            Err(e)
        }
    }
}

/// Renames the complete file `tmp` to `dest` (same directory; the caller
/// syncs the directory). With [`Existing::Refuse`] an existing `dest`
/// is never replaced: `renameat2(RENAME_NOREPLACE)`, or where the file
/// system lacks it, a hard link and an unlink. With [`Existing::Replace`] a
/// regular file is replaced; anything else is still refused.
///
/// # Errors
/// [`io::ErrorKind::AlreadyExists`] when `dest` exists (and may not be
/// replaced), [`io::ErrorKind::InvalidInput`] when it is not a regular
/// file, else the OS error. `tmp` is left in place on error.
pub fn commit(tmp: &Path, dest: &Path, existing: Existing) -> io::Result<()> {
    let exists = |e: io::Error| {
        if e.kind() == io::ErrorKind::AlreadyExists {
            io::Error::new(
                io::ErrorKind::AlreadyExists,
                format!(
                    "{} appeared while the run was writing it; not replaced (the complete file is {})",
                    dest.display(),
                    tmp.display()
                ),
            )
        } else {
            e
        }
    };
    match existing {
        Existing::Replace => {
            ensure_regular(dest)?;
            fs::rename(tmp, dest)?;
        }
        Existing::Refuse => match rename_noreplace(tmp, dest) {
            Ok(()) => {}
            Err(e) if matches!(e.raw_os_error(), Some(libc::EINVAL) | Some(libc::ENOSYS)) => {
                // No RENAME_NOREPLACE here: link(2) never replaces either.
                fs::hard_link(tmp, dest).map_err(exists)?;
                fs::remove_file(tmp)?;
            }
            Err(e) => return Err(exists(e)),
        },
    }
    Ok(())
}

fn rename_noreplace(from: &Path, to: &Path) -> io::Result<()> {
    let c = |p: &Path| {
        std::ffi::CString::new(p.as_os_str().as_bytes())
            .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "path has a NUL byte"))
    };
    let (from, to) = (c(from)?, c(to)?);
    // SAFETY: two valid NUL-terminated paths, relative to the cwd.
    let r = unsafe {
        libc::renameat2(
            libc::AT_FDCWD,
            from.as_ptr(),
            libc::AT_FDCWD,
            to.as_ptr(),
            libc::RENAME_NOREPLACE,
        )
    };
    if r == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::io::Write;
    use std::os::unix::fs::PermissionsExt;

    /// A write killed before its rename leaves `temp_path`'s temporary:
    /// `remove_stale_temporaries` removes those of that file only.
    #[test]
    fn stale_temporaries_of_one_file_are_removed_and_no_other() {
        let dir = tempfile::tempdir().unwrap();
        let row = dir.path().join("cell-002.parquet");
        let stale = temp_path(&row);
        let other = temp_path(&dir.path().join("cell-003.parquet"));
        // A longer name that starts with the row's.
        let longer = temp_path(&dir.path().join("cell-002.parquet.old"));
        for p in [&stale, &other, &longer, &row] {
            fs::write(p, b"x").unwrap();
        }
        remove_stale_temporaries(&row).unwrap();
        assert!(!stale.exists());
        assert!(other.exists() && longer.exists() && row.exists());
        remove_stale_temporaries(&dir.path().join("gone/cell.parquet")).unwrap();
    }

    /// One rule for the files beside another: a recording's, a table's, a
    /// partial recording's, and any other name kept whole.
    #[test]
    fn beside_names() {
        for (path, want) in [
            ("d/x.mcap", "d/x.fit.png"),
            ("d/x.mcap.part", "d/x.fit.png"),
            ("x.csv", "x.fit.png"),
            ("d/x.frf.csv", "d/x.frf.fit.png"),
            ("/a.b/x.csv.mcap", "/a.b/x.csv.fit.png"),
            ("x.toml", "x.toml.fit.png"),
            ("x", "x.fit.png"),
        ] {
            assert_eq!(
                beside(Path::new(path), ".fit.png"),
                Path::new(want),
                "{path}"
            );
        }
    }

    /// The process umask, from /proc (reading it with umask(2) would change
    /// it for the other tests' threads).
    fn umask() -> u32 {
        let status = fs::read_to_string("/proc/self/status").unwrap();
        let line = status.lines().find(|l| l.starts_with("Umask:")).unwrap();
        u32::from_str_radix(line.split_whitespace().nth(1).unwrap(), 8).unwrap()
    }

    fn mode(p: &Path) -> u32 {
        p.symlink_metadata().unwrap().permissions().mode() & 0o777
    }

    /// Names in `dir`, sorted.
    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn a_write_that_fails_midway_leaves_nothing_under_the_final_name() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("frf.csv");
        for existing in [Existing::Refuse, Existing::Replace] {
            let err = write_atomically(&path, existing, |f| {
                f.write_all(b"frequency_hz,magnitude_m_per_a\n1,2\n")?;
                Err(io::Error::from_raw_os_error(libc::ENOSPC))
            })
            .unwrap_err();
            assert_eq!(err.raw_os_error(), Some(libc::ENOSPC));
            assert!(names(dir.path()).is_empty(), "{:?}", names(dir.path()));
        }
        // With a previous file under the name, it is kept as it was.
        fs::write(&path, b"previous").unwrap();
        let err = write_atomically(&path, Existing::Replace, |f| {
            f.write_all(b"half")?;
            Err(io::Error::other("injected"))
        })
        .unwrap_err();
        assert_eq!(err.to_string(), "injected");
        assert_eq!(fs::read(&path).unwrap(), b"previous");
        assert_eq!(names(dir.path()), ["frf.csv"]);
    }

    #[test]
    fn the_final_rename_never_replaces_a_file_that_appeared_meanwhile() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("plot.png");
        let err = write_atomically(&path, Existing::Refuse, |f| {
            fs::write(&path, b"someone else's")?;
            f.write_all(b"ours")
        })
        .unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::AlreadyExists, "{err}");
        assert_eq!(fs::read(&path).unwrap(), b"someone else's");
        assert_eq!(names(dir.path()), ["plot.png"]);
        // --overwrite replaces a regular file, once complete, with mode 0640.
        write_atomically(&path, Existing::Replace, |f| f.write_all(b"ours")).unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"ours");
        assert_eq!(mode(&path), FILE_MODE & !umask());
        // ... but never anything else, even if it appears meanwhile.
        let fifo = dir.path().join("fifo");
        let c = std::ffi::CString::new(fifo.as_os_str().as_bytes()).unwrap();
        // SAFETY: a valid path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let err = write_atomically(&fifo, Existing::Replace, |f| f.write_all(b"x")).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidInput, "{err}");
        assert!(fifo.symlink_metadata().unwrap().file_type().is_fifo());
        assert_eq!(names(dir.path()), ["fifo", "plot.png"]);
    }

    #[test]
    fn rename_noreplace_and_the_hard_link_fallback_never_replace() {
        // commit's two ways (the link where renameat2 is missing).
        let dir = tempfile::tempdir().unwrap();
        let (tmp, dest) = (dir.path().join("t"), dir.path().join("d"));
        fs::write(&tmp, b"new").unwrap();
        fs::write(&dest, b"old").unwrap();
        assert!(rename_noreplace(&tmp, &dest).is_err());
        assert_eq!(
            fs::hard_link(&tmp, &dest).unwrap_err().kind(),
            io::ErrorKind::AlreadyExists
        );
        assert_eq!(fs::read(&dest).unwrap(), b"old");
    }

    #[test]
    fn a_recording_part_file_has_the_output_mode_from_creation() {
        let dir = tempfile::tempdir().unwrap();
        let final_path = dir.path().join("run.mcap");
        let rec = crate::record::Recorder::create(&final_path).unwrap();
        // While the recorder is open (the run is going on).
        assert_eq!(mode(rec.part_path()), FILE_MODE & !umask());
        let part = rec.part_path().to_path_buf();
        let done = rec.finish().unwrap();
        assert_eq!(mode(&done), FILE_MODE & !umask());
        assert!(!part.exists());
        // A leftover .part (a killed run) is refused, not truncated.
        fs::write(&part, b"killed run").unwrap();
        assert!(
            crate::record::Recorder::create(&final_path).is_err(),
            "an existing .part must be refused"
        );
        assert_eq!(fs::read(&part).unwrap(), b"killed run");
        // ... and the finished recording is not replaced by a new one.
        fs::remove_file(&part).unwrap();
        let before = fs::read(&done).unwrap();
        let rec = crate::record::Recorder::create(&final_path).unwrap();
        assert!(rec.finish().is_err());
        assert_eq!(fs::read(&done).unwrap(), before);
    }

    #[test]
    fn claims_in_the_same_millisecond_get_distinct_names() {
        let dir = tempfile::tempdir().unwrap();
        let companions = [".step.png"];
        let a = claim_with_stamp(dir.path(), "control-fast", "T0", &companions).unwrap();
        let b = claim_with_stamp(dir.path(), "control-fast", "T0", &companions).unwrap();
        assert_eq!(a.path(), dir.path().join("control-fast-T0.mcap"));
        assert_eq!(b.path(), dir.path().join("control-fast-T0-1.mcap"));
        // A name whose companion exists is skipped.
        fs::write(dir.path().join("control-fast-T0-2.step.png"), b"x").unwrap();
        let c = claim_with_stamp(dir.path(), "control-fast", "T0", &companions).unwrap();
        assert_eq!(c.path(), dir.path().join("control-fast-T0-3.mcap"));
        // The claim is the .part file, created with the output mode.
        assert_eq!(mode(&part_path_for(c.path())), FILE_MODE & !umask());
        // Unused claims are given back.
        drop((a, b, c));
        assert_eq!(names(dir.path()), ["control-fast-T0-2.step.png"]);
    }

    #[test]
    fn concurrent_claims_never_share_a_name() {
        let dir = tempfile::tempdir().unwrap();
        let claims: Vec<Claim> = std::thread::scope(|s| {
            let hs: Vec<_> = (0..8)
                .map(|_| s.spawn(|| claim_with_stamp(dir.path(), "chirp", "T", &[]).unwrap()))
                .collect();
            hs.into_iter().map(|h| h.join().unwrap()).collect()
        });
        let mut paths: Vec<&Path> = claims.iter().map(Claim::path).collect();
        paths.sort();
        paths.dedup();
        assert_eq!(paths.len(), 8);
    }

    fn err_text(r: Result<(), RunError>) -> String {
        match r.unwrap_err() {
            e @ RunError::BadOption { .. } => e.to_string(),
            e => panic!("not a BadOption: {e:?}"),
        }
    }

    #[test]
    fn a_non_utf8_path_is_refused_by_its_option() {
        let dir = tempfile::tempdir().unwrap();
        let bad = dir
            .path()
            .join(std::ffi::OsStr::from_bytes(b"run-\xff.mcap"));
        let plan = OutputPlan::new(Existing::Replace).with_recording(&bad, Origin::Given);
        let msg = err_text(plan.check());
        assert!(msg.starts_with("out ") && msg.contains("UTF-8"), "{msg}");
        let plan = OutputPlan::new(Existing::Refuse).with_output("plot", &bad, Origin::Given);
        assert!(err_text(plan.check()).starts_with("plot "));
        assert!(names(dir.path()).is_empty());
    }

    /// A spelling of `dir/sub/name`: with `./`, `sub/../sub/`, doubled
    /// slashes, or through a link to `sub`, relative to `dir` or absolute.
    fn spelling(dir: &Path, name: &str, how: u8) -> PathBuf {
        let rel = match how % 6 {
            0 => format!("sub/{name}"),
            1 => format!("./sub/./{name}"),
            2 => format!("sub//{name}"),
            3 => format!("sub/../sub/{name}"),
            4 => format!("link/{name}"),
            _ => format!("./link/../sub/{name}"),
        };
        if how < 6 {
            dir.join(rel)
        } else {
            PathBuf::from(format!("{}/{rel}", dir.display()))
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Any two spellings of one file collide, whichever two options
        /// they are given to; two different names never do.
        #[test]
        fn every_spelling_of_one_file_collides(
            a in 0u8..12,
            b in 0u8..12,
            keys in prop::sample::select(vec![("out", "frf_csv"), ("out", "plot"), ("frf_csv", "plot")]),
            name in "[a-z]{1,6}",
            other in "[A-Z]{1,6}",
        ) {
            let dir = tempfile::tempdir().unwrap();
            fs::create_dir(dir.path().join("sub")).unwrap();
            std::os::unix::fs::symlink("sub", dir.path().join("link")).unwrap();
            let plan = |second: &str| {
                let first = spelling(dir.path(), &name, a);
                let second = spelling(dir.path(), second, b);
                let p = OutputPlan::new(Existing::Refuse);
                let p = if keys.0 == "out" {
                    p.with_recording(&first, Origin::Given)
                } else {
                    p.with_output(keys.0, &first, Origin::Given)
                };
                p.with_output(keys.1, &second, Origin::Given)
            };
            let msg = err_text(plan(&name).check());
            prop_assert!(msg.starts_with(keys.1), "{}", msg);
            prop_assert!(msg.contains(flag(keys.0)), "{}", msg);
            prop_assert!(plan(&other).check().is_ok());
            // The recording's .part name is an output too.
            if keys.0 == "out" {
                let part = format!("{name}.part");
                let msg = err_text(plan(&part).check());
                prop_assert!(msg.contains("temporary name of the --out recording"), "{}", msg);
            }
            prop_assert_eq!(names(dir.path()), ["link", "sub"]);
        }
    }

    /// Rule 6: every spelling of an input, a symbolic link to it and a
    /// hard link of it are refused as any output, even with
    /// `--overwrite`; another file is not, nor is an input that does not
    /// exist (the built-in config's name).
    #[test]
    fn no_spelling_or_link_of_an_input_is_an_output() {
        let dir = tempfile::tempdir().unwrap();
        fs::create_dir(dir.path().join("sub")).unwrap();
        std::os::unix::fs::symlink("sub", dir.path().join("link")).unwrap();
        let input = dir.path().join("sub/x.csv");
        fs::write(&input, b"measured").unwrap();
        std::os::unix::fs::symlink(&input, dir.path().join("sym.csv")).unwrap();
        fs::hard_link(&input, dir.path().join("hard.csv")).unwrap();
        let mut outs: Vec<PathBuf> = (0..12)
            .map(|how| spelling(dir.path(), "x.csv", how))
            .collect();
        outs.push(dir.path().join("sym.csv"));
        outs.push(dir.path().join("hard.csv"));
        for out in &outs {
            for key in ["out", "png", "frf_csv"] {
                for existing in [Existing::Refuse, Existing::Replace] {
                    let plan = OutputPlan::new(existing)
                        .with_output(key, out, Origin::Given)
                        .with_input("inputs", &spelling(dir.path(), "x.csv", 3))
                        .with_input("config", Path::new("(built-in)"));
                    let msg = err_text(plan.check());
                    assert!(
                        msg.starts_with(&format!("{key} {}", out.display())),
                        "{msg}"
                    );
                    assert!(
                        msg.contains("the output is the same file as the input")
                            && msg.contains("even with --overwrite"),
                        "{msg}"
                    );
                }
            }
            // Another output, whichever spelling names the input.
            let plan = OutputPlan::new(Existing::Replace)
                .with_output("out", &dir.path().join("other.csv"), Origin::Given)
                .with_input("config", out);
            assert!(plan.check().is_ok(), "{out:?}");
        }
        let part_input = dir.path().join("sub/r.mcap.part");
        fs::write(&part_input, b"killed run").unwrap();
        let msg = err_text(
            OutputPlan::new(Existing::Replace)
                .with_recording(&dir.path().join("link/r.mcap"), Origin::Given)
                .with_input("part", &part_input)
                .check(),
        );
        assert!(
            msg.contains("temporary name") && msg.contains("same file as the recording"),
            "{msg}"
        );
        assert_eq!(fs::read(&input).unwrap(), b"measured");
        assert_eq!(fs::read(&part_input).unwrap(), b"killed run");
    }
}
