//! `bench upload`: finished recordings, with their companions and
//! catalogue rows, to an S3-compatible store or a directory.

use super::serve::via_daemon_then;
use super::{absolute_path, bad_input, emit, status, ExitCode};
use bench::jobs::request::{JobRequest, UploadRequest};
use bench::upload::once::{upload_recordings, UploadError, UploadOptions, UploadSummary};
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
        default_value_t = bench::upload::once::DEFAULT_RETRY_FOR_S,
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
    /// Finished recordings (*.mcap, not a .part): each goes up with every
    /// file of its stem beside it (FRF CSV, plots, summary) and its
    /// catalogue row, whose recording is the object's URL. Or campaign
    /// directories: each goes up whole as PREFIX/NAME/…, its cells' rows
    /// naming their recordings' objects.
    #[arg(value_name = "RECORDING", required = true)]
    recordings: Vec<PathBuf>,
    #[command(flatten)]
    job: super::JobFlags,
}

pub(super) fn upload(a: UploadArgs) -> ExitCode {
    let request = UploadRequest {
        to: a.to.clone(),
        recordings: a.recordings.clone(),
        retry_for_s: Some(a.retry_for),
        store_timeout_s: Some(a.store_timeout),
    };
    if let Some(sock) = &a.job.daemon {
        let request = UploadRequest {
            recordings: a.recordings.iter().map(|p| absolute_path(p)).collect(),
            ..request
        };
        return via_daemon_then(
            sock,
            &JobRequest::Upload(request),
            a.job.json.json,
            print_summary,
            incomplete,
        );
    }
    let result = UploadOptions::from_request(&request).and_then(|o| upload_recordings(&o));
    match result {
        Ok(summary) => match emit(&summary, a.job.json.json, print_summary) {
            Ok(()) => incomplete(&summary).unwrap_or(ExitCode::SUCCESS),
            Err(code) => code,
        },
        Err(e) => bad_input(refusal(&e, &a.to)),
    }
}

/// An upload's refusal (nothing was uploaded), naming its argument.
fn refusal(e: &UploadError, to: &str) -> String {
    match e {
        UploadError::Url { .. } => format!("--to {e}"),
        UploadError::Recording { path, reason } => format!(
            "RECORDING {}: {reason}; nothing was uploaded",
            path.display()
        ),
        UploadError::Store(reason) => format!("--to {to}: {reason}; nothing was uploaded"),
        UploadError::RetryFor(reason) => format!("--retry-for: {reason}"),
        UploadError::Timeout(reason) => format!("--store-timeout: {reason}"),
    }
}

/// The exit status of an upload that left files unconfirmed
/// ([`status::ERROR`], said on stderr naming the store); `None` when all
/// went up.
fn incomplete(s: &UploadSummary) -> Option<ExitCode> {
    if s.complete() {
        return None;
    }
    errln!(
        "error: --to {}: {} file(s) not confirmed by the store; the local copies are kept",
        s.store,
        s.failed.len() + s.dropped.len()
    );
    Some(ExitCode::from(status::ERROR))
}

fn print_summary(s: &UploadSummary) {
    for line in s.lines() {
        outln!("{line}");
    }
}
