//! What the daemon makes of a job request: the job's options with the
//! daemon's own output names ([`job_spec`], checked when the request
//! arrives, the same checks as the CLI's), and the library job that runs
//! them on a worker thread ([`run`]). Chirp and control run on the
//! daemon's loop and record; fit, design, analyze, map, plot, campaign,
//! catalogue, export, recover and upload compute from (or send) files and
//! never touch the bench (their paths must be
//! absolute: the daemon's working directory is not its clients').

use super::protocol::{to_json, ApiError, ApiErrorKind};
use super::Ctx;
use crate::campaign::file::Campaign;
use crate::campaign::job::{design_inputs, plot_inputs, prepare, start, threads};
use crate::campaign::run::{CampaignRunError, RunOptions};
use crate::error::RunError;
use crate::jobs::analyze::{plan_analyze, run_analyze, AnalyzeOptions};
use crate::jobs::catalogue::{check_options, plan_catalogue, run_catalogue, CatalogueOptions};
use crate::jobs::chirp::{run_chirp_on, ChirpOptions, ChirpOutputs};
use crate::jobs::control::{run_control_from, ControlOptions, StageSource};
use crate::jobs::design::{plan_design, run_design, DesignOptions};
use crate::jobs::export::{plan_export, run_export, ExportOptions};
use crate::jobs::fit::{plan_fit, run_fit, FitOptions};
use crate::jobs::map::{plan_map, run_map, MapOptions};
use crate::jobs::plot::{plan_plot, run_plot, PlotOptions};
use crate::jobs::recover::{plan_recover, run_recover, RecoverOptions};
use crate::jobs::request::{
    check_pace, pace_on_hardware, AnalyzeRequest, CampaignRequest, CatalogueRequest, ChirpRequest,
    ControlRequest, DesignRequest, ExportRequest, FitRequest, JobRequest, MapRequest, Pace,
    PlotRequest, RecoverRequest, RequestError, UploadRequest,
};
use crate::jobs::session::Runner;
use crate::jobs::track::run_track_from;
use crate::jobs::track::TrackOptions;
use crate::jobs::track_request::{TrackRequest, TrackRunner};
use crate::jobs::verify::{StepOutputs, VerifyOptions};
use crate::outputs::{beside, Destination};
use crate::rt::service::ServiceClient;
use crate::upload::once::{upload_recordings, UploadError, UploadOptions};
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
    Export(Box<ExportOptions>),
    Recover(Box<RecoverOptions>),
    Upload(Box<UploadOptions>),
    Track(Box<TrackOptions>),
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
        matches!(self, Self::Chirp(_) | Self::Control(_) | Self::Track(_))
    }
}

/// A job accepted: what it runs, its progress total, and its recording
/// (the jobs that drive the bench) or `None`. Its kind is the request's
/// ([`JobRequest::kind`]).
pub(super) struct Accepted {
    pub(super) spec: JobSpec,
    /// Ticks of a bench job; 0 for a job without progress.
    pub(super) total: u64,
    pub(super) recording: Option<PathBuf>,
}

impl Accepted {
    /// A job that computes from files: no progress total, no recording.
    fn computing(spec: JobSpec) -> Self {
        Self {
            spec,
            total: 0,
            recording: None,
        }
    }
}

/// What a job's worker thread sends back: the summary, or the answer and
/// the run's error (none for a campaign's).
pub(super) type JobResult = Result<Value, (ApiError, Option<RunError>)>;

/// `dir/PREFIX-<stamp>-job<id>.mcap`: a job's recording, and the stem of
/// its other outputs ([`beside`]).
pub(super) fn recording_path(dir: &Path, prefix: &str, id: u64) -> PathBuf {
    crate::outputs::stamped_recording(dir, prefix, &format!("-job{id}"))
}

/// Where job `id`'s outputs go: beside its stamped stem `PREFIX-<stamp>-job<id>`
/// in the daemon's recordings directory.
fn daemon_dest(ctx: &Ctx, prefix: &str, id: u64) -> Destination {
    Destination::Daemon {
        stem: recording_path(&ctx.recordings, prefix, id),
    }
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

/// As [`refused`], a bad option named by `name_of`.
fn named_refusal(e: &RunError, name_of: impl FnOnce(&str) -> String) -> ApiError {
    match e {
        RunError::BadOption { key, .. } => {
            let key: &str = key;
            bad_params(e.option_message(|_| name_of(key)).unwrap_or_default())
        }
        e => ApiError::from_run(e),
    }
}

/// An upload's refusal as the daemon answers it (nothing was uploaded):
/// `bad_params` naming the parameter at fault.
fn upload_refused(e: &UploadError) -> ApiError {
    let field = match e {
        UploadError::Url { .. } | UploadError::Store(_) => "to",
        UploadError::Recording { .. } => "recordings",
        UploadError::RetryFor(_) => "retry_for_s",
        UploadError::Timeout(_) => "store_timeout_s",
    };
    bad_params(format!("params.{field}: {e}; nothing was uploaded"))
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
    match request {
        JobRequest::Chirp(req) => chirp_job(ctx, req, id),
        JobRequest::Control(req) => control_job(ctx, req, id),
        JobRequest::Fit(req) => fit_job(ctx, req, id),
        JobRequest::Design(req) => design_job(ctx, req, id),
        JobRequest::Plot(req) => plot_job(ctx, req, id),
        JobRequest::Catalogue(req) => catalogue_job(ctx, req, id),
        JobRequest::Analyze(req) => analyze_job(ctx, req, id),
        JobRequest::Campaign(req) => campaign_job(ctx, req, id),
        JobRequest::Export(req) => export_job(ctx, req, id),
        JobRequest::Recover(req) => recover_job(ctx, req, id),
        JobRequest::Upload(req) => upload_job(req),
        JobRequest::Map(req) => map_job(ctx, req, id),
        JobRequest::Track(req) => track_job(ctx, req, id),
    }
}

/// A request that does not apply, as the daemon answers it: a field is a
/// parameter (`params.FIELD`), a config key is named as it is.
fn request_refused(e: RequestError) -> ApiError {
    let message = match e {
        RequestError::Field { .. } => format!("params.{e}"),
        RequestError::Invalid { .. } => e.to_string(),
    };
    bad_params(message)
}

/// A bench job's pace, checked as `--pace` is: the daemon's jobs run in
/// its loop's real time unless they ask for virtual time (or the daemon
/// was started with `--pace`), which only a simulator has.
fn pace_of(ctx: &Ctx, p: Option<Pace>) -> Result<Option<Pace>, ApiError> {
    let p = check_pace(p).map_err(request_refused)?;
    match p {
        Some(p) if !ctx.spec.is_sim() => Err(bad_params(format!(
            "params.pace {p}: {}",
            pace_on_hardware(&ctx.spec.to_string())
        ))),
        p => Ok(p),
    }
}

/// The daemon's `chirp` job ([`job_spec`]).
fn chirp_job(ctx: &Ctx, req: &ChirpRequest, id: u64) -> Result<Accepted, ApiError> {
    let mut cfg = ctx.cfg.clone();
    let pace = pace_of(ctx, req.pace.or(ctx.default_pace))?;
    req.apply(&mut cfg).map_err(request_refused)?;
    // A multisine refused at the device's period is refused here,
    // before the job is queued.
    let total = crate::ident::excitation::Excitation::total_ticks_of(&cfg, ctx.period_s)
        .map_err(|e| bad_params(format!("config: {e}")))?;
    // Its plan is checked as the job starts ([`crate::jobs::chirp::chirp_outputs`]).
    let (out, named, _) = ChirpOutputs::plan(&daemon_dest(ctx, "chirp", id), cfg.excitation.kind)
        .map_err(|e| refused(&e))?;
    let ChirpOutputs {
        frf_csv,
        plot,
        bla_csv,
    } = named;
    let opts = ChirpOptions {
        frf_csv,
        plot,
        bla_csv,
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
        total,
        recording: Some(out),
    })
}

/// The daemon's `control` job ([`job_spec`]).
fn control_job(ctx: &Ctx, req: &ControlRequest, id: u64) -> Result<Accepted, ApiError> {
    let mut cfg = ctx.cfg.clone();
    let pace = pace_of(ctx, req.pace.or(ctx.default_pace))?;
    let inject = req.apply(&mut cfg).map_err(request_refused)?;
    let verify = req.verify_settings(&cfg).map_err(request_refused)?;
    let prefix = format!("control-{}", req.controller);
    // Its plan is checked as the job starts ([`crate::jobs::control::control_outputs`]).
    let (out, outputs, _) = StepOutputs::plan(
        &daemon_dest(ctx, &prefix, id),
        &prefix,
        verify.is_some(),
        true,
    )
    .map_err(|e| refused(&e))?;
    let mut total = (cfg.step.duration_s / ctx.period_s).round() as u64;
    let verify = verify.zip(outputs.verify).map(|(v, (csv, plot))| {
        let chirp = crate::ident::chirp::Chirp::new(
            &crate::control::verify::chirp_config(&cfg.chirp, v.amplitude_a, v.duration_s),
            cfg.excitation.kind,
            ctx.period_s,
        );
        total = total.saturating_add(chirp.total_ticks());
        VerifyOptions {
            amplitude_a: v.amplitude_a,
            duration_s: v.duration_s,
            csv,
            plot,
        }
    });
    let opts = ControlOptions {
        plot: outputs.plot,
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
        total,
        recording: Some(out),
    })
}

/// The daemon's `fit` job ([`job_spec`]).
fn fit_job(ctx: &Ctx, req: &FitRequest, id: u64) -> Result<Accepted, ApiError> {
    absolute("input", req.input.as_deref())?;
    absolute("config", req.config.as_deref())?;
    req.check().map_err(|e| refused(&e))?;
    let opts = plan_fit(req.clone(), &daemon_dest(ctx, "fit", id));
    Ok(Accepted::computing(JobSpec::Fit(Box::new(opts))))
}

/// The daemon's `design` job ([`job_spec`]).
fn design_job(ctx: &Ctx, req: &DesignRequest, id: u64) -> Result<Accepted, ApiError> {
    for p in &req.inputs {
        absolute("inputs", Some(p))?;
    }
    absolute("config", req.config.as_deref())?;
    let inputs = design_inputs(&req.inputs).map_err(|e| refused(&e))?;
    let opts = plan_design(req.clone(), inputs, &daemon_dest(ctx, "design", id));
    Ok(Accepted::computing(JobSpec::Design(Box::new(opts))))
}

/// The daemon's `plot` job ([`job_spec`]).
fn plot_job(ctx: &Ctx, req: &PlotRequest, id: u64) -> Result<Accepted, ApiError> {
    for p in &req.inputs {
        absolute("inputs", Some(p))?;
    }
    absolute("config", req.config.as_deref())?;
    req.check().map_err(|e| refused(&e))?;
    let inputs = plot_inputs(&req.inputs).map_err(|e| refused(&e))?;
    let opts = plan_plot(req.clone(), inputs, &daemon_dest(ctx, "plot", id));
    Ok(Accepted::computing(JobSpec::Plot(Box::new(opts))))
}

/// The daemon's `catalogue` job ([`job_spec`]).
fn catalogue_job(ctx: &Ctx, req: &CatalogueRequest, id: u64) -> Result<Accepted, ApiError> {
    absolute("recordings", req.recordings.as_deref())?;
    let opts =
        plan_catalogue(req.clone(), &daemon_dest(ctx, "catalogue", id)).map_err(|e| refused(&e))?;
    check_options(&opts).map_err(|e| refused(&e))?;
    Ok(Accepted::computing(JobSpec::Catalogue(Box::new(opts))))
}

/// The daemon's `analyze` job ([`job_spec`]).
fn analyze_job(ctx: &Ctx, req: &AnalyzeRequest, id: u64) -> Result<Accepted, ApiError> {
    absolute("config", req.config.as_deref())?;
    let opts =
        plan_analyze(req.clone(), &daemon_dest(ctx, "analyze", id)).map_err(|e| refused(&e))?;
    Ok(Accepted::computing(JobSpec::Analyze(Box::new(opts))))
}

/// The daemon's `campaign` job ([`job_spec`]).
fn campaign_job(ctx: &Ctx, req: &CampaignRequest, id: u64) -> Result<Accepted, ApiError> {
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
        total,
        recording: None,
    })
}

/// The daemon's `export` job ([`job_spec`]).
fn export_job(ctx: &Ctx, req: &ExportRequest, id: u64) -> Result<Accepted, ApiError> {
    absolute("recording", Some(&req.recording))?;
    let opts =
        plan_export(req.clone(), &daemon_dest(ctx, "export", id)).map_err(|e| refused(&e))?;
    Ok(Accepted::computing(JobSpec::Export(Box::new(opts))))
}

/// The daemon's `recover` job ([`job_spec`]).
fn recover_job(ctx: &Ctx, req: &RecoverRequest, id: u64) -> Result<Accepted, ApiError> {
    absolute("part", Some(&req.part))?;
    let opts =
        plan_recover(req.clone(), &daemon_dest(ctx, "recover", id)).map_err(|e| refused(&e))?;
    Ok(Accepted::computing(JobSpec::Recover(Box::new(opts))))
}

/// The daemon's `upload` job ([`job_spec`]).
fn upload_job(req: &UploadRequest) -> Result<Accepted, ApiError> {
    for p in &req.recordings {
        absolute("recordings", Some(p))?;
    }
    let opts = UploadOptions::from_request(req).map_err(|e| upload_refused(&e))?;
    Ok(Accepted::computing(JobSpec::Upload(Box::new(opts))))
}

/// The daemon's `map` job ([`job_spec`]).
fn map_job(ctx: &Ctx, req: &MapRequest, id: u64) -> Result<Accepted, ApiError> {
    absolute("config", req.config.as_deref())?;
    absolute("measured", req.measured.as_deref())?;
    let prefix = if req.veering { "veering" } else { "map" };
    let opts = plan_map(req.clone(), &daemon_dest(ctx, prefix, id)).map_err(|e| refused(&e))?;
    Ok(Accepted::computing(JobSpec::Map(Box::new(opts))))
}

/// The daemon's `track` job ([`job_spec`]): its trials in a new
/// directory `track-<stamp>-job<id>` of the recordings directory, its
/// progress the trials done of the most it may run.
fn track_job(ctx: &Ctx, req: &TrackRequest, id: u64) -> Result<Accepted, ApiError> {
    for (field, path) in req.inputs() {
        absolute(field, path)?;
    }
    let pace = pace_of(ctx, req.pace.or(ctx.default_pace))?;
    let dir = beside(&recording_path(&ctx.recordings, "track", id), "");
    let runner = TrackRunner {
        config: (ctx.cfg.clone(), ctx.config_path.clone()),
        out_dir: dir.clone(),
        backend: Some(ctx.spec.clone()),
        realtime: pace.is_none(),
        pace: pace.and_then(Pace::factor),
        overwrite: false,
        seed: ctx.seed,
    };
    let opts = req.options(runner).map_err(|e| {
        named_refusal(&e, |key| {
            req.name_of(&ctx.cfg, &ctx.config_path, key, |k| format!("params.{k}"))
        })
    })?;
    // Standstill, feedback, feedforward, then the learning trials.
    let total = 3 + u64::from(opts.trials);
    Ok(Accepted {
        spec: JobSpec::Track(Box::new(opts)),
        total,
        recording: Some(dir),
    })
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
        JobSpec::Track(opts) => {
            run_track_from(&opts, stop, StageSource::Service(proxy), Some(ticks))
                .map_err(|e| match &e {
                    // The plan refuses a field before anything is enabled:
                    // named as the request (or the config's
                    // [trajectory]) names it.
                    RunError::BadOption { .. } => (
                        named_refusal(&e, |key| opts.name_of(key, |k| format!("params.{k}"))),
                        Some(e),
                    ),
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
        JobSpec::Export(opts) => run_export(&opts).map_err(answer).and_then(json),
        JobSpec::Recover(opts) => run_recover(&opts).map_err(answer).and_then(json),
        JobSpec::Upload(opts) => {
            let opts = UploadOptions {
                stop: Some(stop),
                ..*opts
            };
            upload_recordings(&opts)
                .map_err(|e| (upload_refused(&e), None))
                .and_then(json)
        }
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
