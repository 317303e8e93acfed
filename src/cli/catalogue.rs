//! `bench catalogue`: rebuild the run catalogue of a recordings directory
//! as one compacted Parquet file.

use super::serve::via_daemon;
use super::{emit, refuse_local_only, run_failed, ExitCode};
use bench::jobs::catalogue::{plan_catalogue, run_catalogue, CatalogueRequest, CatalogueSummary};
use bench::jobs::request::JobRequest;
use bench::outputs::{Destination, Given};
use clap::Args;
use std::path::PathBuf;

#[derive(Debug, Args)]
#[command(
    mut_arg("out", |a| a.value_name("FILE").help("The catalogue to write (.parquet) [default: catalogue.parquet in the recordings directory, beside its catalogue/ of per-run rows]")),
)]
pub(super) struct CatalogueArgs {
    /// The recordings to catalogue: every *.mcap in this directory and
    /// its subdirectories (campaign cells), with the rows of campaign
    /// cells whose recordings were not kept [default: ./recordings if it
    /// exists, else $XDG_DATA_HOME/bench/recordings].
    #[arg(long, value_name = "DIR")]
    recordings: Option<PathBuf>,
    #[command(flatten)]
    out: super::OutFlag,
    /// Where the recordings are kept as objects (e.g.
    /// s3://lab-bench/recordings): each row's recording is then this
    /// prefix and the file's name instead of its local path.
    #[arg(long, value_name = "URL")]
    recording_url: Option<String>,
    #[command(flatten)]
    job: super::JobFlags,
    #[command(flatten)]
    outputs: super::OutputFlags,
}

pub(super) fn catalogue(a: CatalogueArgs) -> ExitCode {
    if let Some(sock) = &a.job.daemon {
        if let Some(code) = refuse_local_only(
            &[
                (a.out.out.is_some(), "--out"),
                (a.outputs.overwrite, "--overwrite"),
            ],
            "the daemon names its catalogue in its recordings directory",
        ) {
            return code;
        }
        let request = CatalogueRequest {
            recordings: a.recordings.as_deref().map(super::absolute_path),
            recording_url: a.recording_url.clone(),
        };
        return via_daemon(
            sock,
            &JobRequest::Catalogue(request),
            a.job.json.json,
            print_summary,
        );
    }
    let request = CatalogueRequest {
        recordings: a.recordings.clone(),
        recording_url: a.recording_url.clone(),
    };
    let given = Given::default().with("out", a.out.out.clone());
    let opts = match plan_catalogue(request, &Destination::local(given, a.outputs.overwrite)) {
        Ok(o) => o,
        Err(e) => return run_failed(&e),
    };
    match run_catalogue(&opts) {
        Ok(summary) => match emit(&summary, a.job.json.json, print_summary) {
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
