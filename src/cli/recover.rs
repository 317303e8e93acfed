//! `bench recover FILE.mcap.part`: a killed run's `.part` file → a
//! complete, indexed recording.

use super::{bad_input, emit, run_failed, status};
use bench::outputs::{Existing, Origin, OutputPlan};
use bench::record::recover::{recover as recover_part, RecoverError, Recovered};
use bench::record::PART_SUFFIX;
use clap::Args;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// `bench recover` arguments.
#[derive(Debug, Args)]
pub struct RecoverArgs {
    /// The `.part` file a killed or failed run left (`<name>.mcap.part`).
    part: PathBuf,
    /// The complete recording to write (default: the name without `.part`).
    /// An existing file is never replaced unless `--overwrite` is given.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Replace an existing `--out` (a regular file only).
    #[arg(long)]
    overwrite: bool,
    /// Print the result as JSON on stdout.
    #[arg(long)]
    json: bool,
}

/// The default output: `x.mcap.part` → `x.mcap`.
fn default_out(part: &Path) -> Option<PathBuf> {
    let s = part.to_str()?;
    s.strip_suffix(PART_SUFFIX)
        .filter(|s| !s.is_empty())
        .map(PathBuf::from)
}

/// Runs `bench recover`.
pub fn recover(args: RecoverArgs) -> ExitCode {
    match std::fs::symlink_metadata(&args.part) {
        Ok(m) if m.is_file() => {}
        Ok(_) => {
            return bad_input(format!(
                "PART: {} is not a regular file",
                args.part.display()
            ))
        }
        Err(e) => return bad_input(format!("PART: {}: {e}", args.part.display())),
    }
    let Some(out) = args.out.clone().or_else(|| default_out(&args.part)) else {
        return bad_input(format!(
            "PART: {} does not end in {PART_SUFFIX}; give --out",
            args.part.display()
        ));
    };
    let existing = Existing::overwrite(args.overwrite);
    let same = |a: &Path, b: &Path| {
        a.canonicalize()
            .ok()
            .zip(b.canonicalize().ok())
            .is_some_and(|(a, b)| a == b)
    };
    if same(&out, &args.part) {
        return bad_input("--out: the output must not be the .part file it is read from");
    }
    if let Err(e) = OutputPlan::new(existing)
        .with_output("out", &out, Origin::Given)
        .check()
    {
        return run_failed(&e);
    }
    match recover_part(&args.part, &out, existing) {
        Ok(r) => match emit(&r, args.json, human) {
            Ok(()) => ExitCode::SUCCESS,
            Err(code) => code,
        },
        Err(e @ (RecoverError::NotARecording { .. } | RecoverError::Read { .. })) => {
            bad_input(format!("PART: {e}"))
        }
        Err(e @ RecoverError::Write { .. }) => {
            errln!("error: {}", bench::error::error_chain(&e));
            ExitCode::from(status::ERROR)
        }
    }
}

fn human(r: &Recovered) {
    outln!(
        "recovered {} messages and {} metadata records ({:.3} s of loop time) from {}",
        r.messages,
        r.metadata,
        r.last_log_time_s,
        r.from.display()
    );
    outln!("  reading stopped at: {}", r.stopped);
    outln!("  recording           {}", r.to.display());
}
