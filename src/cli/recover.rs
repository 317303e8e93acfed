//! `bench recover FILE.mcap.part`: a killed run's `.part` file → a
//! complete, indexed recording.

use super::serve::via_daemon_then;
use super::{absolute_path, emit, refuse_local_only, run_failed, status};
use bench::jobs::recover::{plan_recover, run_recover, RecoverRequest};
use bench::jobs::request::JobRequest;
use bench::outputs::{Destination, Given};
use bench::record::recover::Recovered;
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;

/// `bench recover` arguments.
#[derive(Debug, Args)]
#[command(
    after_help = after_help(),
    mut_arg("out", |a| a
        .value_name("FILE.mcap")
        .help("The complete recording to write (default: the name without `.part`)")
        .long_help("The complete recording to write (default: the name without `.part`). An existing file is never replaced unless `--overwrite` is given")),
)]
pub struct RecoverArgs {
    /// The `.part` file a killed or failed run left (`<name>.mcap.part`).
    part: PathBuf,
    #[command(flatten)]
    out: super::OutFlag,
    #[command(flatten)]
    job: super::JobFlags,
    #[command(flatten)]
    outputs: super::OutputFlags,
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

/// Runs `bench recover`.
pub fn recover(args: RecoverArgs) -> ExitCode {
    let request = RecoverRequest {
        part: args.part.clone(),
    };
    if let Some(sock) = &args.job.daemon {
        if let Some(code) = refuse_local_only(
            &[
                (args.out.out.is_some(), "--out"),
                (args.outputs.overwrite, "--overwrite"),
            ],
            "the daemon names the recovered recording in its recordings directory",
        ) {
            return code;
        }
        let request = RecoverRequest {
            part: absolute_path(&args.part),
        };
        return via_daemon_then(
            sock,
            &JobRequest::Recover(request),
            args.job.json.json,
            human,
            data_lost,
        );
    }
    let dest = Destination::local(
        Given::default().with("out", args.out.out.clone()),
        args.outputs.overwrite,
    );
    match plan_recover(request, &dest).and_then(|opts| run_recover(&opts)) {
        Ok(r) => match emit(&r, args.job.json.json, human) {
            Ok(()) => data_lost(&r).unwrap_or(ExitCode::SUCCESS),
            Err(code) => code,
        },
        Err(e) => run_failed(&e),
    }
}

/// The exit status of a recovery that lost data ([`status::DATA_LOST`],
/// said on stderr); `None` when nothing was lost.
fn data_lost(r: &Recovered) -> Option<ExitCode> {
    if !r.lost {
        return None;
    }
    errln!(
        "error: {}: data lost: {}; {} recovered without it",
        r.from.display(),
        lost_in_words(r),
        r.to.display()
    );
    Some(ExitCode::from(status::DATA_LOST))
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
