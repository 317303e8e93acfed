//! `bench export`: a recording's channel as a CSV or Parquet table.

use super::{bad_input, status};
use bench::jobs::export::export_topic as export_table;
use bench::outputs::{Existing, Origin, OutputPlan};
use bench::record::export::{ExportError, ExportFormat};
use clap::{Args, ValueEnum};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Debug, Clone, Copy, ValueEnum)]
pub(super) enum FormatArg {
    Csv,
    Parquet,
}

#[derive(Debug, Args)]
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
    #[arg(long, value_name = "TOPIC", default_value = "/bench/sample")]
    topic: String,
    /// Output file [default: beside the recording, <stem>.<topic>.<csv|parquet>].
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Replace an existing output file (a regular file) once the new one
    /// is complete.
    #[arg(long)]
    overwrite: bool,
}

pub(super) fn export(a: ExportArgs) -> ExitCode {
    let format = match a.to {
        FormatArg::Csv => ExportFormat::Csv,
        FormatArg::Parquet => ExportFormat::Parquet,
    };
    let out = a.out.clone().unwrap_or_else(|| {
        let name = a
            .recording
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let stem = name
            .strip_suffix(".part")
            .unwrap_or(&name)
            .strip_suffix(".mcap")
            .unwrap_or(&name)
            .to_string();
        let topic: String = a
            .topic
            .trim_start_matches('/')
            .replace('/', "-")
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '_')
            .collect();
        a.recording
            .with_file_name(format!("{stem}.{topic}.{}", format.extension()))
    });
    // The output rules (bench::outputs): nothing replaced without
    // --overwrite, only a regular file, and never the recording read.
    let given = if a.out.is_some() {
        Origin::Given
    } else {
        Origin::Derived
    };
    if let Err(e) = OutputPlan::new(Existing::overwrite(a.overwrite))
        .derived_from("the recording")
        .with_output("out", &out, given)
        .with_input("recording", &a.recording)
        .check()
    {
        return super::run_failed(&e);
    }
    match export_table(
        &a.recording,
        &a.topic,
        format,
        &out,
        Existing::overwrite(a.overwrite),
    ) {
        Ok(rows) => {
            let abs = std::path::absolute(&out).unwrap_or(out);
            outln!("{rows} rows of {} -> {}", a.topic, abs.display());
            ExitCode::SUCCESS
        }
        Err(e @ (ExportError::Recording { .. } | ExportError::NoTopic { .. })) => bad_input(e),
        Err(e) => {
            errln!("error: {}", bench::error::error_chain(&e));
            ExitCode::from(status::ERROR)
        }
    }
}
