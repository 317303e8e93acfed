//! `bench plot bode|nyquist`: its flags, the overlay job they make
//! (`bench::jobs::plot`), and the printed summary.

use super::serve::via_daemon_then;
use super::{finish, refuse_local_only, status};
use bench::campaign::job::plot_inputs;
use bench::jobs::plot::{plan_plot, run_plot, PlotKind, PlotRequest, PlotSummary};
use bench::jobs::request::JobRequest;
use bench::outputs::{Destination, Given};
use clap::{Args, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

/// The exit statuses of `bench plot` (its --help).
const EXIT_STATUS: &str = "Exit status: 0 the figure is written; 2 bad input (an input that is \
not an FRF, a campaign without a done cell, an existing --out without --overwrite, a missing \
directory: nothing written); 9 the figure is written but an input's modal fit is flagged, not \
to be trusted (FLAGGED in its legend entry and on stderr); 1 the figure could not be written.";

/// The figure.
#[derive(Debug, Subcommand)]
pub(super) enum PlotCommand {
    /// Bode overlay: magnitude, phase and coherence of every input on one
    /// log-frequency axis, the model dashed, and the zoom on the closely
    /// spaced pairs below; each input's CMP-CNMP verdict in its legend
    /// entry.
    #[command(after_help = EXIT_STATUS)]
    Bode(PlotArgs),
    /// Nyquist overlay: Re H against Im H (m/A, equal scales) of every
    /// input, the whole band and the pairs' band side by side, with the
    /// direction of increasing frequency and the fitted modes marked; each
    /// input's CMP-CNMP verdict in its legend entry.
    #[command(after_help = EXIT_STATUS)]
    Nyquist(PlotArgs),
}

#[derive(Debug, Args)]
#[command(
    mut_arg("config", |a| a.long_help("Bench description (TOML): the model drawn, and the loop period and amplifier bandwidth of every input's fit (as `bench fit --config`) [default: each input is fitted as `bench fit` fits it (a recording with the config it holds, a campaign's cell with the campaign's bench.toml, a CSV with the built-in Chapter 5 bench); the model is the first recording's config, else the first campaign's, else the built-in bench]")),
    mut_arg("out", |a| a.value_name("FILE.png|svg|pdf").help("The figure [default: beside the first input, <stem>.bode-overlay.png or <stem>.nyquist-overlay.png; a campaign: DIR/bode-overlay.png]")),
)]
pub(super) struct PlotArgs {
    /// The FRFs: `bench chirp` CSVs, recordings (`.mcap`, `.mcap.part`:
    /// their /sysid/frf) or campaign directories (every done cell's FRF,
    /// ordered and coloured by mass asymmetry and operating point). Their
    /// frequency grids may differ. At most 200 FRFs in all.
    #[arg(required = true, value_name = "INPUT")]
    inputs: Vec<PathBuf>,
    #[command(flatten)]
    config: super::ConfigFlag,
    /// Draw no model.
    #[arg(long)]
    no_model: bool,
    /// The name of an input in the legend, once per INPUT, in order (a
    /// campaign's cells become `NAME cell NNN …`) [default: the file's or
    /// the directory's name].
    #[arg(long, value_name = "NAME")]
    label: Vec<String>,
    /// The figure's title [default: "Bode of N measured FRFs (x1 /
    /// current)", or Nyquist].
    #[arg(long, value_name = "TEXT")]
    title: Option<String>,
    #[command(flatten)]
    out: super::OutFlag,
    #[command(flatten)]
    job: super::JobFlags,
    #[command(flatten)]
    outputs: super::OutputFlags,
}

pub(super) fn plot(cmd: PlotCommand) -> ExitCode {
    let (kind, a) = match cmd {
        PlotCommand::Bode(a) => (PlotKind::Bode, a),
        PlotCommand::Nyquist(a) => (PlotKind::Nyquist, a),
    };
    let request = PlotRequest {
        kind,
        inputs: a.inputs.clone(),
        config: a.config.config.clone(),
        no_model: a.no_model,
        labels: (!a.label.is_empty()).then(|| a.label.clone()),
        title: a.title.clone(),
    };
    if let Some(sock) = &a.job.daemon {
        if let Some(code) = refuse_local_only(
            &[
                (a.out.out.is_some(), "--out"),
                (a.outputs.overwrite, "--overwrite"),
            ],
            "the daemon writes the figure in its recordings directory",
        ) {
            return code;
        }
        let request = PlotRequest {
            inputs: request
                .inputs
                .iter()
                .map(|p| super::absolute_path(p))
                .collect(),
            config: request.config.as_deref().map(super::absolute_path),
            ..request
        };
        return via_daemon_then(
            sock,
            &JobRequest::Plot(request),
            a.job.json.json,
            print_summary,
            flagged_status,
        );
    }
    if let Err(e) = request.check() {
        return super::run_failed(&e);
    }
    let inputs = match plot_inputs(&request.inputs) {
        Ok(i) => i,
        Err(e) => return super::run_failed(&e),
    };
    let given = Given::default().with("out", a.out.out.clone());
    let opts = plan_plot(
        request,
        inputs,
        &Destination::local(given, a.outputs.overwrite),
    );
    let result = run_plot(&opts);
    let flagged = result.as_ref().ok().and_then(flagged_status);
    let code = finish(result, a.job.json.json, print_summary);
    match flagged {
        Some(f) if code == ExitCode::SUCCESS => f,
        _ => code,
    }
}

/// Exit 9, saying which inputs, when a trace's fit is flagged.
fn flagged_status(s: &PlotSummary) -> Option<ExitCode> {
    let flagged = s.flagged();
    if flagged.is_empty() {
        return None;
    }
    errln!(
        "error: bench plot: FLAGGED, not to be trusted: the modal fit of {} (the figure is written; the flags are in the JSON, fit.quality.flags)",
        flagged.join("; ")
    );
    Some(ExitCode::from(status::FLAGGED))
}

fn print_summary(s: &PlotSummary) {
    let n = s.traces.len();
    outln!(
        "bench plot {}: {n} FRF{}",
        s.kind.as_str(),
        if n == 1 { "" } else { "s" }
    );
    match &s.model {
        Some(m) => outln!(
            "  model       {} (Y1o {:.1} % of L, Δm23 {:+.1} %)",
            m.config,
            100.0 * m.operating_point_fraction_of_l,
            100.0 * m.mass_asymmetry
        ),
        None => outln!("  model       none"),
    }
    if let Some(note) = &s.colors_note {
        outln!("  {note}");
    }
    for t in &s.traces {
        outln!("  {}  {}", t.color, t.legend);
        if t.flagged {
            for flag in t.fit.iter().flat_map(|f| &f.quality.flags) {
                outln!("           FLAGGED: {flag}");
            }
        }
    }
    match s.pair_zoom_hz {
        Some([lo, hi]) => outln!(
            "  pair zoom   {lo:.2}–{hi:.2} Hz ({} of {n} inputs resolved a pair)",
            s.traces
                .iter()
                .filter(|t| t.verdict.phase_test.pair.is_some())
                .count()
        ),
        None => outln!("  pair zoom   none (no input resolved a closely spaced pair)"),
    }
    outln!("  plot        {}", s.plot.display());
}
