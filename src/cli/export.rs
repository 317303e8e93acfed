//! `bench export`: a recording's channel as a CSV or Parquet table.

use super::serve::via_daemon;
use super::{absolute_path, emit, refuse_local_only, run_failed};
use bench::jobs::export::{plan_export, run_export, ExportRequest, ExportSummary};
use bench::jobs::request::JobRequest;
use bench::outputs::{Destination, Given};
use bench::record::export::ExportFormat;
use clap::{Args, ValueEnum};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Debug, Clone, Copy, ValueEnum)]
pub(super) enum FormatArg {
    Csv,
    Parquet,
}

#[derive(Debug, Args)]
#[command(
    mut_arg("out", |a| a.value_name("FILE").help("Output file [default: beside the recording, <stem>.<topic>.<csv|parquet>]")),
)]
pub(super) struct ExportArgs {
    /// The recording (`.mcap`, or the `.mcap.part` of a killed run).
    recording: PathBuf,
    /// Table format.
    #[arg(long, value_enum)]
    to: FormatArg,
    /// The channel: /bench/sample (one row per tick), /bench/envelope (one
    /// per 5 ms), /bench/timing, /bench/event, /sysid/frf (one row
    /// per frequency line; as CSV the FRF CSV of bench chirp, which bench
    /// fit, design and control --frf read), or any other recorded topic.
    #[arg(long, value_name = "TOPIC", default_value = bench::jobs::export::DEFAULT_TOPIC)]
    topic: String,
    #[command(flatten)]
    out: super::OutFlag,
    #[command(flatten)]
    job: super::JobFlags,
    #[command(flatten)]
    outputs: super::OutputFlags,
}

pub(super) fn export(a: ExportArgs) -> ExitCode {
    let request = ExportRequest {
        recording: a.recording.clone(),
        to: match a.to {
            FormatArg::Csv => ExportFormat::Csv,
            FormatArg::Parquet => ExportFormat::Parquet,
        },
        topic: Some(a.topic.clone()),
    };
    if let Some(sock) = &a.job.daemon {
        if let Some(code) = refuse_local_only(
            &[
                (a.out.out.is_some(), "--out"),
                (a.outputs.overwrite, "--overwrite"),
            ],
            "the daemon names its table in its recordings directory",
        ) {
            return code;
        }
        let request = ExportRequest {
            recording: absolute_path(&a.recording),
            ..request
        };
        return via_daemon(
            sock,
            &JobRequest::Export(request),
            a.job.json.json,
            print_summary,
        );
    }
    let dest = Destination::local(
        Given::default().with("out", a.out.out.clone()),
        a.outputs.overwrite,
    );
    let result = plan_export(request, &dest).and_then(|opts| run_export(&opts));
    match result {
        Ok(summary) => match emit(&summary, a.job.json.json, print_summary) {
            Ok(()) => ExitCode::SUCCESS,
            Err(code) => code,
        },
        Err(e) => run_failed(&e),
    }
}

fn print_summary(s: &ExportSummary) {
    outln!("{} rows of {} -> {}", s.rows, s.topic, s.out.display());
}
