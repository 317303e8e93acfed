//! `bench upload`: finished recordings, with their companions and
//! catalogue rows, to an S3-compatible store or a directory.

use super::{bad_input, emit, status, ExitCode};
use bench::upload::once::{upload_recordings, UploadError, UploadOptions, UploadSummary};
use bench::upload::StoreUrl;
use clap::Args;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub(super) struct UploadArgs {
    /// The store: s3://BUCKET[/PREFIX] (an S3-compatible store; endpoint,
    /// region and credentials from AWS_ENDPOINT, AWS_REGION,
    /// AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY, AWS_ALLOW_HTTP) or
    /// file:///DIRECTORY (a mounted NAS; the directory must exist).
    #[arg(long, value_name = "URL")]
    to: String,
    /// How long a store that fails or does not answer is retried, with a
    /// backoff from 1 s doubling to 60 s, seconds (0 to 86400). What is
    /// still not confirmed then is reported (exit 1); the local files are
    /// kept and a second run uploads only what is missing.
    #[arg(
        long,
        value_name = "SECONDS",
        default_value_t = 60.0,
        allow_negative_numbers = true
    )]
    retry_for: f64,
    /// How long the store has to take a connection, and to answer each
    /// request (from sending it to the answer's first byte, then between
    /// two reads), seconds (0.5 to 300). A store that does not answer
    /// costs at most --retry-for plus this.
    #[arg(
        long,
        value_name = "SECONDS",
        default_value_t = bench::upload::store::DEFAULT_TIMEOUT_S,
        allow_negative_numbers = true
    )]
    store_timeout: f64,
    /// Print the summary as one JSON object.
    #[arg(long)]
    json: bool,
    /// Finished recordings (*.mcap, not a .part): each goes up with every
    /// file of its stem beside it (FRF CSV, plots, summary) and its
    /// catalogue row, whose recording is the object's URL. Or campaign
    /// directories: each goes up whole as PREFIX/NAME/…, its cells' rows
    /// naming their recordings' objects.
    #[arg(value_name = "RECORDING", required = true)]
    recordings: Vec<PathBuf>,
}

pub(super) fn upload(a: UploadArgs) -> ExitCode {
    let to = match StoreUrl::parse(&a.to) {
        Ok(u) => u,
        Err(reason) => return bad_input(format!("--to {:?}: {reason}", a.to)),
    };
    let opts = UploadOptions {
        to,
        recordings: a.recordings,
        retry_for_s: a.retry_for,
        timeout_s: a.store_timeout,
    };
    match upload_recordings(&opts) {
        Ok(summary) => {
            if let Err(code) = emit(&summary, a.json, print_summary) {
                return code;
            }
            if summary.complete() {
                ExitCode::SUCCESS
            } else {
                errln!(
                    "error: --to {}: {} file(s) not confirmed by the store; the local copies are kept",
                    a.to,
                    summary.failed.len() + summary.dropped.len()
                );
                ExitCode::from(status::ERROR)
            }
        }
        Err(UploadError::Recording { path, reason }) => bad_input(format!(
            "RECORDING {}: {reason}; nothing was uploaded",
            path.display()
        )),
        Err(UploadError::Store(reason)) => {
            bad_input(format!("--to {}: {reason}; nothing was uploaded", a.to))
        }
        Err(UploadError::RetryFor(reason)) => bad_input(format!("--retry-for: {reason}")),
        Err(UploadError::Timeout(reason)) => bad_input(format!("--store-timeout: {reason}")),
    }
}

fn print_summary(s: &UploadSummary) {
    for line in s.lines() {
        outln!("{line}");
    }
}
