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
#[command(after_help = after_help())]
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

/// `bench recover --help`'s closing paragraphs: what is checked, and the
/// exit statuses (their codes from [`status`]).
fn after_help() -> String {
    let exit = bench::error::exit_status_help(&[
        (
            status::SUCCESS,
            "when everything written was recovered (the chunk cut by the kill, the one being \
             written, incomplete at the end of the file, is expected and named, not a loss)",
        ),
        (
            status::DATA_LOST,
            "when data was lost: a damaged chunk, metadata record or unreadable bytes were \
             dropped (the recording is still written, with everything intact)",
        ),
        (
            status::BAD_INPUT,
            "for input that is no recording or an output refused",
        ),
        (status::ERROR, "when writing the output failed"),
    ]);
    format!(
        "Every chunk is checked on its own (length, lz4, CRC of its records, its log times); a \
         damaged chunk is dropped whole and every intact chunk after it is kept. The summary \
         and the `bench.recovered` metadata name what was dropped (chunk index, byte offset, \
         messages and loop time when known, reason).\n\n{exit}"
    )
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
    // A regular file within a recording's limit (bench::input_file),
    // refused before anything is written; recover_part reads it so again.
    if let Err(e) = bench::input_file::open(&args.part, bench::input_file::Kind::Recording, "part")
    {
        return bad_input(format!("PART: {e}"));
    }
    let Some(out) = args.out.clone().or_else(|| default_out(&args.part)) else {
        return bad_input(format!(
            "PART: {} does not end in {PART_SUFFIX}; give --out",
            args.part.display()
        ));
    };
    let existing = Existing::overwrite(args.overwrite);
    // Never the .part it reads, however spelled (rule 6 of bench::outputs).
    if let Err(e) = OutputPlan::new(existing)
        .with_output("out", &out, Origin::Given)
        .with_input("part", &args.part)
        .check()
    {
        return run_failed(&e);
    }
    match recover_part(&args.part, &out, existing) {
        Ok(r) => match emit(&r, args.json, human) {
            Ok(()) if r.lost => {
                errln!(
                    "error: {}: data lost: {}; {} recovered without it",
                    r.from.display(),
                    lost_in_words(&r),
                    r.to.display()
                );
                ExitCode::from(status::DATA_LOST)
            }
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

/// What was lost, in a few words: the dropped regions and orphaned
/// messages, counted.
fn lost_in_words(r: &Recovered) -> String {
    let mut parts = Vec::new();
    let lost: Vec<_> = r.dropped.iter().filter(|d| d.lost).collect();
    if !lost.is_empty() {
        let chunks: Vec<String> = lost
            .iter()
            .map(|d| format!("{} {}", d.kind.as_str(), d.chunk_index))
            .collect();
        parts.push(format!("dropped {}", chunks.join(", ")));
    }
    let orphaned: u64 = r.orphaned.iter().map(|o| o.messages).sum();
    if orphaned > 0 {
        parts.push(format!(
            "{orphaned} messages whose channel definition was lost"
        ));
    }
    parts.join("; ")
}

fn human(r: &Recovered) {
    outln!(
        "recovered {} messages of {} chunks and {} metadata records ({:.3} s of loop time) from {}",
        r.messages,
        r.chunks,
        r.metadata,
        r.last_log_time_s,
        r.from.display()
    );
    for d in &r.dropped {
        let mut what = String::new();
        if let Some(n) = d.messages {
            what.push_str(&format!(", {n} messages"));
        }
        if let Some([a, b]) = d.loop_time_s {
            what.push_str(&format!(", loop time {a:.3} s to {b:.3} s"));
        }
        outln!(
            "  dropped {} {} at byte {} ({} bytes{what}){}: {}",
            d.kind.as_str(),
            d.chunk_index,
            d.offset_bytes,
            d.length_bytes,
            if d.lost {
                ""
            } else {
                ", nothing lost: rebuilt"
            },
            d.reason
        );
    }
    for o in &r.orphaned {
        outln!(
            "  dropped {} messages on channel {}: its definition was lost",
            o.messages,
            o.channel_id
        );
    }
    if let Some(note) = &r.rebuilt {
        outln!("  rebuilt: {note}");
    }
    if let Some(c) = &r.cut {
        outln!(
            "  cut by the kill     {} {} at byte {} ({} bytes present): {}",
            c.kind.as_str(),
            c.chunk_index,
            c.offset_bytes,
            c.length_bytes,
            c.reason
        );
    } else {
        outln!("  reading stopped at: {}", r.stopped);
    }
    outln!("  recording           {}", r.to.display());
}
