//! `bench recover` as a job: the `.part` file a killed run left, turned
//! into a complete, indexed recording ([`crate::record::recover`]), planned
//! and run the same way by the command line and the daemon.

use crate::error::RunError;
use crate::outputs::{Destination, OutputPlan};
use crate::record::recover::{recover, RecoverError, Recovered};
use crate::record::PART_SUFFIX;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// `bench recover` as a job request (the daemon's `recover`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecoverRequest {
    /// The `.part` file a killed or failed run left (`<name>.mcap.part`;
    /// the daemon takes an absolute path).
    pub part: PathBuf,
}

/// A recovery planned: the request and its checked output.
#[derive(Debug, Clone)]
pub struct RecoverOptions {
    /// What to recover.
    pub request: RecoverRequest,
    /// The complete recording written.
    pub out: PathBuf,
    /// Whether an existing `out` is replaced.
    pub existing: crate::outputs::Existing,
}

/// `x.mcap.part` → `x.mcap`; `None` for a name without `.part`.
fn without_part(part: &Path) -> Option<PathBuf> {
    let s = part.to_str()?;
    s.strip_suffix(PART_SUFFIX)
        .filter(|s| !s.is_empty())
        .map(PathBuf::from)
}

/// Plans a recovery: the input checked as a recording ([`crate::input_file`]:
/// a regular file within a recording's limit), the output at `dest`
/// (locally, by default, the name without `.part`; on the daemon
/// `recover-<stamp>-job<N>.mcap`) checked by the output rules
/// ([`crate::outputs`]: never the `.part` it reads, however spelled),
/// before anything is written.
///
/// # Errors
/// [`RunError::BadOption`] naming `part` (unreadable, not a regular file,
/// too large; locally without `--out`, a name without `.part`) or `out`.
pub fn plan_recover(
    request: RecoverRequest,
    dest: &Destination,
) -> Result<RecoverOptions, RunError> {
    let part = &request.part;
    crate::input_file::open(part, crate::input_file::Kind::Recording, "part")
        .map_err(|e| RunError::option("part", part.display(), e.reason()))?;
    let (out, origin) = dest.output("out", ".mcap", || {
        without_part(part).ok_or_else(|| {
            RunError::option(
                "part",
                part.display(),
                format!("does not end in {PART_SUFFIX}; give --out"),
            )
        })
    })?;
    let existing = dest.existing();
    OutputPlan::new(existing)
        .derived_from("the .part file")
        .with_output("out", &out, origin)
        .with_input("part", part)
        .check()?;
    Ok(RecoverOptions {
        request,
        out,
        existing,
    })
}

/// Runs a planned recovery. Data lost (a damaged chunk dropped) is not an
/// error: the summary says so ([`Recovered::lost`]), and the recording is
/// written with everything intact.
///
/// # Errors
/// [`RunError::BadOption`] naming `part` for an input that is no
/// recoverable recording; [`RunError::Output`] when writing fails
/// (nothing is left under the output's name).
pub fn run_recover(opts: &RecoverOptions) -> Result<Recovered, RunError> {
    let part = &opts.request.part;
    recover(part, &opts.out, opts.existing).map_err(|e| match e {
        RecoverError::Read { source } => RunError::option("part", part.display(), source.reason()),
        RecoverError::NotARecording { reason, .. } => RunError::option(
            "part",
            part.display(),
            format!("not a recoverable recording: {reason}"),
        ),
        RecoverError::Write { path, reason } => RunError::Output { path, reason },
    })
}
