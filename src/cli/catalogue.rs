//! `bench catalogue`: rebuild the run catalogue of a recordings directory
//! as one compacted Parquet file.

use super::{default_recordings, emit, origin, run_failed, ExitCode};
use bench::catalogue::COMPACTED_NAME;
use bench::jobs::catalogue::{run_catalogue, CatalogueOptions, CatalogueSummary};
use bench::outputs::Existing;
use clap::Args;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub(super) struct CatalogueArgs {
    /// The recordings to catalogue: every *.mcap in this directory (not
    /// its subdirectories) [default: ./recordings if it exists, else
    /// $XDG_DATA_HOME/bench/recordings].
    #[arg(long, value_name = "DIR")]
    recordings: Option<PathBuf>,
    /// The catalogue to write (.parquet) [default: catalogue.parquet in
    /// the recordings directory, beside its catalogue/ of per-run rows].
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Replace an existing catalogue (a regular file) once the new one is
    /// complete.
    #[arg(long)]
    overwrite: bool,
    /// Print the summary as one JSON object.
    #[arg(long)]
    json: bool,
}

pub(super) fn catalogue(a: CatalogueArgs) -> ExitCode {
    let recordings = match a.recordings {
        Some(d) => d,
        None => match default_recordings(false, "--recordings DIR") {
            Ok(d) => d,
            Err(reason) => return super::bad_input(format!("--recordings: {reason}")),
        },
    };
    let opts = CatalogueOptions {
        out: a
            .out
            .clone()
            .unwrap_or_else(|| recordings.join(COMPACTED_NAME)),
        out_origin: origin(a.out.is_some()),
        recordings,
        existing: Existing::overwrite(a.overwrite),
    };
    match run_catalogue(&opts) {
        Ok(summary) => match emit(&summary, a.json, print_summary) {
            Ok(()) => ExitCode::SUCCESS,
            Err(code) => code,
        },
        Err(e) => run_failed(&e),
    }
}

fn print_summary(s: &CatalogueSummary) {
    for line in s.lines() {
        outln!("{line}");
    }
}
