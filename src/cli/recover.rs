//! `bench recover FILE.mcap.part`: a killed run's `.part` file → a
//! complete, indexed recording.

use super::{bad_input, emit, status};
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
    if out == args.part {
        return bad_input("--out: the output must not be the .part file itself");
    }
    match std::fs::symlink_metadata(&out) {
        Ok(m) if !m.is_file() => {
            return bad_input(format!(
                "--out: {} exists and is not a regular file",
                out.display()
            ))
        }
        Ok(_) if !args.overwrite => {
            return bad_input(format!(
                "--out: {} exists (give --overwrite to replace it)",
                out.display()
            ))
        }
        _ => {}
    }
    let tmp = PathBuf::from(format!(
        "{}.recover-{}.tmp",
        out.display(),
        std::process::id()
    ));
    let result = recover_part(&args.part, &tmp, &out).and_then(|r| {
        commit(&tmp, &out, args.overwrite).map_err(|reason| RecoverError::Write {
            path: out.clone(),
            reason,
        })?;
        Ok(r)
    });
    match result {
        Ok(r) => match emit(&r, args.json, human) {
            Ok(()) => ExitCode::SUCCESS,
            Err(code) => code,
        },
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            match e {
                RecoverError::NotARecording { .. } => bad_input(format!("PART: {e}")),
                RecoverError::Read { .. } => bad_input(format!("PART: {e}")),
                RecoverError::Write { .. } => {
                    eprintln!("error: {e}");
                    ExitCode::from(status::ERROR)
                }
            }
        }
    }
}

/// Renames the finished `tmp` to `out`; without `overwrite`, never replaces
/// a file that appeared meanwhile (a hard link fails on an existing name).
fn commit(tmp: &Path, out: &Path, overwrite: bool) -> Result<(), String> {
    if overwrite {
        std::fs::rename(tmp, out).map_err(|e| e.to_string())?;
    } else {
        std::fs::hard_link(tmp, out).map_err(|e| e.to_string())?;
        std::fs::remove_file(tmp).map_err(|e| e.to_string())?;
    }
    let dir = match out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

fn human(r: &Recovered) {
    println!(
        "recovered {} messages and {} metadata records ({:.3} s of loop time) from {}",
        r.messages,
        r.metadata,
        r.last_log_time_s,
        r.from.display()
    );
    println!("  reading stopped at: {}", r.stopped);
    println!("  recording           {}", r.to.display());
}
