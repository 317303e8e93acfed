//! What the daemon makes of a job request: the job's options with the
//! daemon's own output names ([`job_spec`], checked when the request
//! arrives, the same checks as the CLI's), and the library job that runs
//! them on a worker thread ([`run`]). Chirp and control run on the
//! daemon's loop and record; fit, design, analyze, map, plot and campaign compute from
//! files and the model and never touch the bench (their paths must be
//! absolute: the daemon's working directory is not its clients').

use super::protocol::{to_json, ApiError, ApiErrorKind};
use super::Ctx;
use crate::campaign::file::Campaign;
use crate::campaign::job::{prepare, start, threads};
use crate::campaign::run::{CampaignRunError, RunOptions};
use crate::error::RunError;
use crate::jobs::analyze::{run_analyze, AnalyzeOptions};
use crate::jobs::catalogue::{check_options, run_catalogue, CatalogueOptions};
use crate::jobs::chirp::{run_chirp_on, ChirpOptions};
use crate::jobs::control::{run_control_from, ControlOptions, StageSource};
use crate::jobs::design::{run_design, DesignInput, DesignOptions};
use crate::jobs::fit::{run_fit, FitOptions};
use crate::jobs::map::{run_map, MapOptions};
use crate::jobs::plot::{run_plot, PlotInput, PlotOptions};
use crate::jobs::request::{check_pace, pace_on_hardware, JobRequest, Pace, RequestError};
use crate::jobs::session::Runner;
use crate::jobs::verify::VerifyOptions;
use crate::outputs::{beside, Existing, Origin};
use crate::rt::service::ServiceClient;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::sync::Arc;

/// A job ready to run: its options, paths resolved.
pub(super) enum JobSpec {
    Chirp(Box<ChirpOptions>),
    Control(Box<ControlOptions>),
    Fit(Box<FitOptions>),
    Design(Box<DesignOptions>),
    Analyze(Box<AnalyzeOptions>),
    Map(Box<MapOptions>),
    Plot(Box<PlotOptions>),
    Campaign(Box<CampaignJob>),
    Catalogue(Box<CatalogueOptions>),
}

/// A campaign to start: the loaded file, its new directory, the threads.
pub(super) struct CampaignJob {
    campaign: Campaign,
    dir: PathBuf,
    threads: usize,
    design: Option<crate::design::Strategy>,
}

impl JobSpec {
    /// Whether the job runs on the real-time loop (else it only computes).
    pub(super) fn uses_loop(&self) -> bool {
        matches!(self, Self::Chirp(_) | Self::Control(_))
    }
}

/// A job accepted: what it is, its progress total, and its recording (the
/// jobs that drive the bench) or `None`.
pub(super) struct Accepted {
    pub(super) spec: JobSpec,
    pub(super) kind: &'static str,
    /// Ticks of a bench job; 0 for a job without progress.
    pub(super) total: u64,
    pub(super) recording: Option<PathBuf>,
}

/// What a job's worker thread sends back: the summary, or the answer and
/// the run's error (none for a campaign's).
pub(super) type JobResult = Result<Value, (ApiError, Option<RunError>)>;

/// `dir/PREFIX-<stamp>-job<id>.mcap`: a job's recording, and the stem of
/// its other outputs ([`beside`]).
pub(super) fn recording_path(dir: &Path, prefix: &str, id: u64) -> PathBuf {
    crate::outputs::stamped_recording(dir, prefix, &format!("-job{id}"))
}

fn bad_params(message: impl Into<String>) -> ApiError {
    ApiError::new(ApiErrorKind::BadParams, message)
}

/// Refuses a relative path in `params.FIELD`.
fn absolute(field: &str, path: Option<&Path>) -> Result<(), ApiError> {
    match path {
        Some(p) if !p.is_absolute() => Err(bad_params(format!(
            "params.{field}: {} is not an absolute path (the daemon's working directory is not the client's)",
            p.display()
        ))),
        _ => Ok(()),
    }
}

/// A request's error as the daemon answers it: `bad_params`, naming the
/// field as `params.FIELD`.
fn refused(e: &RunError) -> ApiError {
    match e.option_message(|key| format!("params.{key}")) {
        Some(message) => bad_params(message),
        None => ApiError::from_run(e),
    }
}

/// A campaign's error as the daemon answers it: `bad_params` for bad
/// input (naming the field as `params.FIELD`), `interrupted` when stopped
/// (every completed cell is kept), `error` otherwise.
fn campaign_answer(e: &CampaignRunError) -> ApiError {
    let message = crate::error::error_chain(e);
    match e {
        CampaignRunError::BadOption { .. } => bad_params(format!("params.{message}")),
        CampaignRunError::BadInput(_) => bad_params(message),
        CampaignRunError::Stopped { .. } => ApiError::new(ApiErrorKind::Interrupted, message),
        _ => ApiError::new(ApiErrorKind::Error, message),
    }
}

/// Builds the job of `request` (job `id`) with the daemon's config, backend
/// and output names; `Err` (`bad_params`) for a request the CLI would
/// refuse too.
pub(super) fn job_spec(ctx: &Ctx, request: &JobRequest, id: u64) -> Result<Accepted, ApiError> {
    let mut cfg = ctx.cfg.clone();
    // The request names a config key or its field; a field is a parameter.
    let bad = |e: RequestError| {
        let message = match e {
            RequestError::Field { .. } => format!("params.{e}"),
            RequestError::Invalid { .. } => e.to_string(),
        };
        bad_params(message)
    };
    let kind = request.kind();
    // A bench job's pace, checked as `--pace` is: the daemon's jobs run in
    // its loop's real time unless they ask for virtual time (or the daemon
    // was started with `--pace`), which only a simulator has.
    let pace = |p: Option<Pace>| -> Result<Option<Pace>, ApiError> {
        let p = check_pace(p).map_err(bad)?;
        match p {
            Some(p) if !ctx.spec.is_sim() => Err(bad_params(format!(
                "params.pace {p}: {}",
                pace_on_hardware(&ctx.spec.to_string())
            ))),
            p => Ok(p),
        }
    };
    match request {
        JobRequest::Chirp(req) => {
            let pace = pace(req.pace.or(ctx.default_pace))?;
            req.apply(&mut cfg).map_err(bad)?;
            // A multisine refused at the device's period is refused here,
            // before the job is queued.
            let total = crate::ident::excitation::Excitation::total_ticks_of(&cfg, ctx.period_s)
                .map_err(|e| bad_params(format!("config: {e}")))?;
            let out = recording_path(&ctx.recordings, "chirp", id);
            let opts = ChirpOptions {
                frf_csv: beside(&out, ".frf.csv"),
                plot: beside(&out, ".bode.png"),
                bla_csv: (!cfg.excitation.kind.is_sweep()).then(|| beside(&out, ".bla.csv")),
                out: out.clone(),
                seed: req.seed.unwrap_or(ctx.seed),
                config: cfg,
                config_path: ctx.config_path.clone(),
                realtime: pace.is_none(),
                pace: pace.and_then(Pace::factor),
                progress: false,
                backend: Some(ctx.spec.clone()),
                inject: None,
                catalogue: true,
            };
            Ok(Accepted {
                spec: JobSpec::Chirp(Box::new(opts)),
                kind,
                total,
                recording: Some(out),
            })
        }
        JobRequest::Control(req) => {
            let pace = pace(req.pace.or(ctx.default_pace))?;
            let inject = req.apply(&mut cfg).map_err(bad)?;
            let verify = req.verify_settings(&cfg).map_err(bad)?;
            let out = recording_path(&ctx.recordings, &format!("control-{}", req.controller), id);
            let mut total = (cfg.step.duration_s / ctx.period_s).round() as u64;
            let verify = verify.map(|v| {
                let chirp = crate::ident::chirp::Chirp::new(
                    &crate::control::verify::chirp_config(&cfg.chirp, v.amplitude_a, v.duration_s),
                    cfg.excitation.kind,
                    ctx.period_s,
                );
                total = total.saturating_add(chirp.total_ticks());
                VerifyOptions {
                    amplitude_a: v.amplitude_a,
                    duration_s: v.duration_s,
                    csv: beside(&out, ".verify.csv"),
                    plot: beside(&out, ".verify.png"),
                }
            });
            let opts = ControlOptions {
                plot: beside(&out, ".step.png"),
                out: out.clone(),
                controller: req.controller.clone(),
                check_only: false,
                frf: None,
                override_check: req.override_check,
                realtime: pace.is_none(),
                pace: pace.and_then(Pace::factor),
                seed: req.seed.unwrap_or(ctx.seed),
                progress: false,
                inject,
                backend: Some(ctx.spec.clone()),
                config: cfg,
                config_path: ctx.config_path.clone(),
                verify,
                catalogue: true,
            };
            Ok(Accepted {
                spec: JobSpec::Control(Box::new(opts)),
                kind,
                total,
                recording: Some(out),
            })
        }
        JobRequest::Fit(req) => {
            absolute("input", req.input.as_deref())?;
            absolute("config", req.config.as_deref())?;
            req.check().map_err(|e| refused(&e))?;
            let stem = recording_path(&ctx.recordings, "fit", id);
            let opts = FitOptions {
                png: (req.input.is_some() && !req.no_plot).then(|| beside(&stem, ".fit.png")),
                // As a local run: the updated bench of an FRF update; an
                // update to frequencies is only answered.
                out: req.update.then(|| beside(&stem, ".updated.toml")),
                model_out: req.export_model.map(|_| {
                    crate::jobs::fit::model_path(&stem, req.model_format.unwrap_or_default())
                }),
                request: req.clone(),
                existing: Existing::Refuse,
            };
            Ok(Accepted {
                spec: JobSpec::Fit(Box::new(opts)),
                kind,
                total: 0,
                recording: None,
            })
        }
        JobRequest::Design(req) => {
            for p in &req.inputs {
                absolute("inputs", Some(p))?;
            }
            absolute("config", req.config.as_deref())?;
            let inputs = req
                .inputs
                .iter()
                .map(|p| {
                    if p.is_dir() {
                        crate::campaign::job::design_input(p)
                            .map_err(|e| bad_params(format!("params.inputs: {e}")))
                    } else {
                        Ok(DesignInput::File(p.clone()))
                    }
                })
                .collect::<Result<Vec<_>, _>>()?;
            let stem = recording_path(&ctx.recordings, "design", id);
            let out = beside(&stem, ".designed.toml");
            let opts = DesignOptions {
                png: (!req.no_plot).then(|| beside(&stem, ".design.png")),
                out: Some(out),
                request: req.clone(),
                inputs,
                existing: Existing::Refuse,
            };
            Ok(Accepted {
                spec: JobSpec::Design(Box::new(opts)),
                kind,
                total: 0,
                recording: None,
            })
        }
        JobRequest::Plot(req) => {
            for p in &req.inputs {
                absolute("inputs", Some(p))?;
            }
            absolute("config", req.config.as_deref())?;
            req.check().map_err(|e| refused(&e))?;
            let inputs = req
                .inputs
                .iter()
                .map(|p| {
                    if p.is_dir() {
                        crate::campaign::job::plot_input(p)
                            .map_err(|e| bad_params(format!("params.inputs: {e}")))
                    } else {
                        Ok(PlotInput::File(p.clone()))
                    }
                })
                .collect::<Result<Vec<_>, _>>()?;
            let stem = recording_path(&ctx.recordings, "plot", id);
            let opts = PlotOptions {
                out: Some(beside(&stem, &format!(".{}.png", req.kind.as_str()))),
                request: req.clone(),
                inputs,
                existing: Existing::Refuse,
            };
            Ok(Accepted {
                spec: JobSpec::Plot(Box::new(opts)),
                kind,
                total: 0,
                recording: None,
            })
        }
        JobRequest::Catalogue(req) => {
            absolute("recordings", req.recordings.as_deref())?;
            let stem = recording_path(&ctx.recordings, "catalogue", id);
            let opts = CatalogueOptions {
                recordings: req
                    .recordings
                    .clone()
                    .unwrap_or_else(|| ctx.recordings.clone()),
                out: beside(&stem, ".parquet"),
                out_origin: Origin::Default,
                existing: Existing::Refuse,
                recording_url: req.recording_url.clone(),
            };
            check_options(&opts).map_err(|e| refused(&e))?;
            Ok(Accepted {
                spec: JobSpec::Catalogue(Box::new(opts)),
                kind,
                total: 0,
                recording: None,
            })
        }
        JobRequest::Analyze(req) => {
            absolute("config", req.config.as_deref())?;
            req.plant().map_err(|e| refused(&e))?;
            let stem = recording_path(&ctx.recordings, "analyze", id);
            let png = |suffix: &str| (!req.no_plots).then(|| beside(&stem, suffix));
            let opts = AnalyzeOptions {
                pole_zero_png: png(".pole-zero.png"),
                modes_png: png(".modes.png"),
                request: req.clone(),
                existing: Existing::Refuse,
            };
            Ok(Accepted {
                spec: JobSpec::Analyze(Box::new(opts)),
                kind,
                total: 0,
                recording: None,
            })
        }
        JobRequest::Campaign(req) => {
            absolute("file", req.file.as_deref())?;
            let threads = threads(req.threads).map_err(|e| campaign_answer(&e))?;
            let keep = req
                .keep
                .as_deref()
                .map(str::parse::<crate::campaign::file::Keep>)
                .transpose()
                .map_err(|e| bad_params(format!("params.keep: {e}")))?;
            let campaign =
                prepare(req.file.as_deref(), keep, req.design.is_some()).map_err(|e| match e {
                    CampaignRunError::BadInput(m) => bad_params(format!("params.file: {m}")),
                    e => campaign_answer(&e),
                })?;
            let total = campaign.cells().len() as u64;
            // `campaign-<stamp>-job<id>`: a new, empty directory.
            let dir = beside(&recording_path(&ctx.recordings, "campaign", id), "");
            Ok(Accepted {
                spec: JobSpec::Campaign(Box::new(CampaignJob {
                    campaign,
                    design: req.design,
                    dir,
                    threads,
                })),
                kind,
                total,
                recording: None,
            })
        }
        JobRequest::Map(req) => {
            absolute("config", req.config.as_deref())?;
            absolute("measured", req.measured.as_deref())?;
            req.check().map_err(|e| refused(&e))?;
            let prefix = if req.veering { "veering" } else { "map" };
            let stem = recording_path(&ctx.recordings, prefix, id);
            let opts = MapOptions {
                png: beside(&stem, ".png"),
                csv: req.csv.then(|| beside(&stem, ".csv")),
                request: req.clone(),
                existing: Existing::Refuse,
            };
            Ok(Accepted {
                spec: JobSpec::Map(Box::new(opts)),
                kind,
                total: 0,
                recording: None,
            })
        }
    }
}

/// Runs `job` on this (worker) thread: a bench job through `proxy`, the
/// daemon's loop; `stop` ends it safely, `ticks` follows its progress.
/// A summary as the response's `result`.
fn json<T: serde::Serialize>(summary: T) -> JobResult {
    to_json(summary).map_err(|(api, e)| (api, Some(e)))
}

pub(super) fn run(
    job: JobSpec,
    proxy: &mut ServiceClient,
    hardware: bool,
    stop: Arc<AtomicBool>,
    ticks: &Arc<AtomicU64>,
) -> JobResult {
    let answer = |e: RunError| (refused(&e), Some(e));
    let answer_run = |e: RunError| (ApiError::from_run(&e), Some(e));
    match job {
        JobSpec::Chirp(opts) => run_chirp_on(
            &mut Runner::Service(proxy),
            hardware,
            &opts,
            stop,
            Some(ticks),
        )
        .map_err(answer_run)
        .and_then(json),
        JobSpec::Control(opts) => {
            run_control_from(&opts, stop, StageSource::Service(proxy), Some(ticks))
                .map_err(|e| match &e {
                    // A parameter judged on the model before enable: named
                    // as the request names it.
                    RunError::BadOption {
                        key: "verify_amplitude_a",
                        ..
                    } => answer(e),
                    _ => answer_run(e),
                })
                .and_then(json)
        }
        JobSpec::Fit(opts) => run_fit(&opts).map_err(answer).and_then(json),
        JobSpec::Design(opts) => run_design(&opts).map_err(answer).and_then(json),
        JobSpec::Analyze(opts) => run_analyze(&opts).map_err(answer).and_then(json),
        JobSpec::Catalogue(opts) => run_catalogue(&opts).map_err(answer).and_then(json),
        JobSpec::Map(opts) => run_map(&opts).map_err(answer).and_then(json),
        JobSpec::Plot(opts) => run_plot(&opts).map_err(answer).and_then(json),
        JobSpec::Campaign(job) => {
            // Progress: the cells done.
            let on_cell = |done: usize, _cells: usize| {
                ticks.store(done as u64, std::sync::atomic::Ordering::Relaxed);
            };
            let opts = RunOptions {
                threads: job.threads,
                stop,
                on_cell: Some(&on_cell),
            };
            let summary = start(job.campaign, Some(&job.dir), job.threads)
                .and_then(|ready| ready.run_parallel(&opts))
                .map_err(|e| (campaign_answer(&e), None))?;
            match job.design {
                None => json(summary),
                Some(strategy) => {
                    let design = crate::campaign::job::design_over(&summary.dir, strategy)
                        .map_err(answer)?;
                    json(crate::campaign::run::CampaignSummary {
                        design: Some(Box::new(design)),
                        ..summary
                    })
                }
            }
        }
    }
}
