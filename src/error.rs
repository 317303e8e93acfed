//! How a run ends when it does not produce a summary: one error type for
//! every job, mapped to exit statuses by the CLI and to error kinds by the
//! daemon; and the table of those exit statuses ([`EXIT_STATUSES`]).
//!
//! Layer rule: may use `input_file`.

use std::io;
use std::path::PathBuf;

/// The exit statuses of the `bench` command line, by name: the codes of
/// [`EXIT_STATUSES`].
pub mod exit {
    /// Success.
    pub const SUCCESS: u8 = 0;
    /// An unexpected error (I/O after the run, internal).
    pub const ERROR: u8 = 1;
    /// Bad input: config or arguments; nothing was enabled.
    pub const BAD_INPUT: u8 = 2;
    /// A safety fault: the supervisor latched.
    pub const FAULT: u8 = 3;
    /// A hardware (HAL) error.
    pub const HAL: u8 = 4;
    /// `--daemon`, `bench daemon`: the daemon refused.
    pub const DAEMON_REFUSED: u8 = 5;
    /// `bench daemon`: no daemon answers at the socket.
    pub const NO_DAEMON: u8 = 6;
    /// `bench recover`: data was lost.
    pub const DATA_LOST: u8 = 7;
    /// `bench control --verify`: the measured loop disagrees.
    pub const VERIFY_FAILED: u8 = 8;
    /// `bench fit`, `bench plot`: a fit is flagged.
    pub const FLAGGED: u8 = 9;
    /// Interrupted by SIGINT or SIGTERM (128 + SIGINT).
    pub const INTERRUPTED: u8 = 130;
    /// The reader of standard output went away (128 + SIGPIPE).
    pub const STDOUT_CLOSED: u8 = 141;
}

/// One exit status of the `bench` command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ExitStatus {
    /// The status.
    pub code: u8,
    /// The commands that exit with it (`daemon` for `bench daemon …`);
    /// empty: any command.
    pub commands: &'static [&'static str],
    /// What it means, in a few words (`bench --help` lists them; the
    /// README's table says more, in a row that holds these words).
    pub meaning: &'static str,
}

/// Every exit status of the `bench` command line, ascending: the one
/// table the command line's exit codes ([`exit`]), `bench --help`, each
/// command's `--help` and the README's *Exit status* table follow (a test
/// holds each of them to it).
pub const EXIT_STATUSES: &[ExitStatus] = &[
    ExitStatus {
        code: exit::SUCCESS,
        commands: &[],
        meaning: "success",
    },
    ExitStatus {
        code: exit::ERROR,
        commands: &[],
        meaning: "unexpected error",
    },
    ExitStatus {
        code: exit::BAD_INPUT,
        commands: &[],
        meaning: "bad input",
    },
    ExitStatus {
        code: exit::FAULT,
        commands: &["chirp", "control", "track", "campaign", "daemon"],
        meaning: "safety fault",
    },
    ExitStatus {
        code: exit::HAL,
        commands: &["chirp", "control", "track", "campaign"],
        meaning: "hardware (HAL) error",
    },
    ExitStatus {
        code: exit::DAEMON_REFUSED,
        // `bench daemon`, and every command that submits with `--daemon`.
        commands: &[
            "daemon",
            "chirp",
            "control",
            "analyze",
            "map",
            "campaign",
            "catalogue",
            "fit",
            "design",
            "plot",
            "export",
            "recover",
            "upload",
            "track",
        ],
        meaning: "the daemon refused",
    },
    ExitStatus {
        code: exit::NO_DAEMON,
        commands: &["daemon"],
        meaning: "no daemon answers at the socket",
    },
    ExitStatus {
        code: exit::DATA_LOST,
        commands: &["recover"],
        meaning: "data was lost",
    },
    ExitStatus {
        code: exit::VERIFY_FAILED,
        commands: &["control"],
        meaning: "the measured loop disagrees with the prediction",
    },
    ExitStatus {
        code: exit::FLAGGED,
        commands: &["fit", "plot"],
        meaning: "a fit is flagged, not to be trusted",
    },
    ExitStatus {
        code: exit::INTERRUPTED,
        commands: &[],
        meaning: "interrupted by SIGINT or SIGTERM",
    },
    ExitStatus {
        code: exit::STDOUT_CLOSED,
        commands: &[],
        meaning: "the reader of its standard output went away",
    },
];

/// `Exit status: 0 …; 7 …`: a command's `--help` paragraph on its exit
/// statuses, each code with what it means for that command.
pub fn exit_status_help(items: &[(u8, &str)]) -> String {
    let items: Vec<String> = items.iter().map(|(c, m)| format!("{c} {m}")).collect();
    format!("Exit status: {}.", items.join("; "))
}

/// Why a run did not produce a summary.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// Bad input detected before anything was enabled (exit 2): the
    /// message names the config key or file it is about.
    #[error("{0}")]
    BadInput(String),
    /// A run option is unusable, found before anything was enabled (exit
    /// 2). `key` is the option's name as the job options and requests spell
    /// it (`out`, `plot`, `frf_csv`, `frf`, `backend`, `controller`,
    /// `override_check`, `inject_fault`); the CLI shows its flag instead.
    #[error("{key}{}: {reason}", if subject.is_empty() { String::new() } else { format!(" {subject}") })]
    BadOption {
        /// The option.
        key: &'static str,
        /// What was given (a path, a backend), or empty.
        subject: String,
        /// Why it is refused.
        reason: String,
    },
    /// The loop check refused the controller before enabling (exit 2).
    #[error("{0}")]
    Refused(String),
    /// The supervisor latched a fault (exit 3). The recording was finished.
    #[error("safety fault: {kind} at tick {tick} ({detail}); 0 A, amplifier disabled; recording {recording}")]
    Fault {
        /// Fault name.
        kind: &'static str,
        /// Offending value.
        value: f64,
        /// `value …`, or what the backend said (link faults).
        detail: String,
        /// Tick.
        tick: u64,
        /// The finished recording.
        recording: String,
        /// What `--json` prints beside the fault: the job, backend,
        /// current limits, loop timing and link counters of the run.
        context: Box<serde_json::Value>,
    },
    /// The HAL failed (exit 4). The recording was finished.
    #[error(
        "hardware error at tick {tick}: {message}; 0 A, amplifier disabled; recording {recording}"
    )]
    Hal {
        /// Backend message.
        message: String,
        /// Tick.
        tick: u64,
        /// The finished recording.
        recording: String,
    },
    /// Stopped by SIGINT/SIGTERM (exit 130). The recording was finished.
    #[error("interrupted at tick {tick}: 0 A, amplifier disabled; recording {recording} finished")]
    Interrupted {
        /// Tick.
        tick: u64,
        /// The finished recording.
        recording: String,
    },
    /// The job did not finish within its tick budget (exit 1). The
    /// recording was finished.
    #[error("the {job} did not finish within its tick budget; recording {recording}")]
    TickLimit {
        /// The job (`chirp`, `control`).
        job: &'static str,
        /// The finished recording.
        recording: String,
    },
    /// The recording could not be written (exit 1).
    #[error(transparent)]
    Record(#[from] RecordError),
    /// A result file beside the recording (FRF CSV, plot) could not be
    /// written (exit 1).
    #[error("cannot write {}: {reason}", path.display())]
    Output {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// A result could not be encoded as JSON (exit 1).
    #[error("encoding a result as JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// A loop or writer thread could not start or panicked (exit 1).
    #[error("{0}")]
    Thread(String),
}

impl RunError {
    /// The summary `--json` prints on stdout for a run that ended without
    /// its job's summary: `{"outcome": …, "error": message, …}` with the
    /// fault (kind, value, tick, message), the recording and, for a fault,
    /// the run's context (backend, current limits, timing); `None` for
    /// errors before anything ran (bad input: stderr only).
    pub fn summary_json(&self) -> Option<serde_json::Value> {
        use serde_json::json;
        let message = format!("{self:#}");
        match self {
            Self::Fault {
                kind,
                value,
                detail,
                tick,
                recording,
                context,
            } => {
                let mut v = json!({
                    "outcome": "fault",
                    "error": message,
                    "fault": {
                        "kind": kind,
                        "value": value.is_finite().then_some(*value),
                        "message": detail,
                        "tick": tick,
                    },
                    "recording": recording,
                });
                if let (Some(o), Some(c)) = (v.as_object_mut(), context.as_object()) {
                    for (k, x) in c {
                        o.insert(k.clone(), x.clone());
                    }
                }
                Some(v)
            }
            Self::Hal {
                message: m,
                tick,
                recording,
            } => Some(json!({
                "outcome": "hal",
                "error": message,
                "hal": {"message": m, "tick": tick},
                "recording": recording,
            })),
            Self::Interrupted { tick, recording } => Some(json!({
                "outcome": "interrupted",
                "error": message,
                "tick": tick,
                "recording": recording,
            })),
            Self::TickLimit { job, recording } => Some(json!({
                "outcome": "tick_limit",
                "error": message,
                "job": job,
                "recording": recording,
            })),
            _ => None,
        }
    }

    /// A [`RunError::BadOption`]'s message with its option as `name`
    /// calls it (the CLI's flag, the daemon's `params.KEY`): `NAME
    /// SUBJECT: REASON`, the parts that are not empty (a positional
    /// argument's name is, its value names it). `None` for any other
    /// error.
    pub fn option_message(&self, name: impl FnOnce(&'static str) -> String) -> Option<String> {
        let Self::BadOption {
            key,
            subject,
            reason,
        } = self
        else {
            return None;
        };
        let name = name(key);
        let what: Vec<&str> = [name.as_str(), subject.as_str()]
            .into_iter()
            .filter(|s| !s.is_empty())
            .collect();
        Some(format!("{}: {reason}", what.join(" ")))
    }

    /// A [`RunError::BadOption`].
    pub fn option(key: &'static str, subject: impl ToString, reason: impl Into<String>) -> Self {
        Self::BadOption {
            key,
            subject: subject.to_string(),
            reason: reason.into(),
        }
    }
}

impl From<crate::input_file::InputError> for RunError {
    /// An input file refused ([`crate::input_file`]): a
    /// [`RunError::BadOption`] naming its argument, the file and the
    /// reason (exit 2).
    fn from(e: crate::input_file::InputError) -> Self {
        Self::option(e.key, e.path.display(), e.reason())
    }
}

/// `error: cause: cause …`, each source once (a wrapper that repeats its
/// source's text is not repeated): the whole chain of `e`, so that the
/// OS's reason under a library's wrapper (`No space left on device (os
/// error 28)` under mcap's `I/O error from writing`) reaches the message.
pub fn error_chain(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut cur = e.source();
    while let Some(c) = cur {
        let c_text = c.to_string();
        if !text.contains(&c_text) {
            text.push_str(": ");
            text.push_str(&c_text);
        }
        cur = c.source();
    }
    text
}

/// Errors of the recorder.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The recording file could not be created (directory missing, not
    /// writable, …).
    #[error(
        "cannot create recording file {} (in directory {}): {source}",
        path.display(),
        dir.display()
    )]
    Create {
        /// The file that could not be created (the `.part` file).
        path: PathBuf,
        /// Its directory.
        dir: PathBuf,
        /// The OS reason.
        source: io::Error,
    },
    /// Writing, flushing or syncing the recording failed.
    #[error("I/O error on recording {}: {source}", path.display())]
    Io {
        /// The file being written.
        path: PathBuf,
        /// The OS reason.
        source: io::Error,
    },
    /// The mcap writer reported an error.
    #[error("MCAP error on recording {}: {source}", path.display())]
    Mcap {
        /// The file being written.
        path: PathBuf,
        /// The mcap crate's error.
        source: mcap::McapError,
    },
    /// Renaming the finished `.part` file to its final name failed.
    #[error("cannot rename {} to {}: {source}", from.display(), to.display())]
    Rename {
        /// The `.part` file.
        from: PathBuf,
        /// The final path.
        to: PathBuf,
        /// The OS reason.
        source: io::Error,
    },
    /// A message could not be serialized to JSON.
    #[error("cannot serialize message to JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// A [`crate::record::Channel`] that this recorder did not hand out.
    #[error("unknown channel handle {0}")]
    UnknownChannel(usize),
    /// The arrays given to [`crate::record::Recorder::write_frf`] differ in length.
    #[error(
        "FRF arrays differ in length: frequency {frequency}, magnitude {magnitude}, \
         phase {phase}, coherence {coherence}, sigma {sigma}, resolution {resolution}, \
         sigma_dof {dof}"
    )]
    FrfLength {
        /// Length of `frequency_hz`.
        frequency: usize,
        /// Length of `magnitude_m_per_a`.
        magnitude: usize,
        /// Length of `phase_deg`.
        phase: usize,
        /// Length of `coherence`.
        coherence: usize,
        /// Length of `sigma_m_per_a`.
        sigma: usize,
        /// Length of `resolution_hz`.
        resolution: usize,
        /// Length of `sigma_dof`.
        dof: usize,
    },
}
