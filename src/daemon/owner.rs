//! The owner thread: the daemon's side of the real-time loop. It turns
//! requests into loop requests and jobs ([`crate::rt::service`]) and keeps
//! the state `status` shows. May use `rt::service`, `jobs`; never the
//! socket.

use super::protocol::{event, to_json, ApiError, ApiErrorKind, FaultStatus, Status};
use super::{lock, Ctx};
use crate::error::RunError;
use crate::jobs::chirp::{run_chirp_on, ChirpOptions};
use crate::jobs::request::{JobRequest, RequestError};
use crate::jobs::session::beside;
use crate::jobs::session::Runner;
use crate::jobs::step::{run_control_from, ControlOptions, StageSource};
use crate::record::topics::FaultKind;
use crate::rt::service::{LoopReply, LoopRequest, ServiceClient};
use crate::rt::{Job, RawStop, StopReason};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::sync::{mpsc, Arc, Mutex};
use tokio::sync::{broadcast, oneshot};

/// A job's handles shared with the socket side.
#[derive(Debug, Clone)]
pub(super) struct JobHandle {
    pub(super) id: u64,
    pub(super) stop: Arc<AtomicBool>,
    pub(super) ticks: Arc<AtomicU64>,
}

pub(super) type Reply<T> = oneshot::Sender<Result<T, ApiError>>;

pub(super) enum JobSpec {
    Chirp(Box<ChirpOptions>),
    Control(Box<ControlOptions>),
}

pub(super) enum OwnerCmd {
    Enable(Reply<()>),
    Disable(Reply<()>),
    Reset(Reply<()>),
    Job(JobSpec, JobHandle, Reply<Value>),
    Shutdown,
}

/// What the owner thread shares with the socket side.
pub(super) struct OwnerShared {
    pub(super) status: Arc<Mutex<Status>>,
    pub(super) events: broadcast::Sender<String>,
    /// Makes a fresh hold job for each `enable` (`[daemon]
    /// hold_controller`), if one is configured.
    pub(super) hold: Option<HoldFactory>,
}

/// Makes the hold controller's job: the controller holds the position the
/// stage is at on its first tick, for ever.
pub(super) type HoldFactory = Box<dyn Fn() -> Box<dyn Job + Send> + Send>;

/// A fault the loop latched between jobs, as `status` reports it: the
/// supervisor's fault name and what caused it.
pub(super) fn between_jobs_fault(r: LoopReply) -> Option<FaultStatus> {
    let LoopReply::Fault {
        kind,
        value,
        link_error,
        hal_error,
    } = r
    else {
        return None;
    };
    let stop = match hal_error {
        Some((call, error)) if kind == FaultKind::Hal => RawStop::Hal {
            call,
            error,
            tick: 0,
        },
        _ => RawStop::Fault {
            kind,
            value,
            tick: 0,
            link_error,
        },
    };
    let message = match stop.describe() {
        StopReason::Hal { message, .. } => message,
        StopReason::Fault {
            detail: Some(d), ..
        } => d,
        _ => format!("value {value:e}"),
    };
    Some(FaultStatus {
        kind: kind.as_str(),
        message: format!(
            "between jobs: {} ({message}); 0 A, amplifier disabled",
            kind.as_str()
        ),
    })
}

/// The owner thread: the daemon's side of the loop. It hands requests and
/// jobs to the real-time loop ([`crate::rt::service`]), which runs the
/// hold job and the one supervisor between them, and reports faults the
/// loop latched between jobs.
pub(super) fn owner(mut client: ServiceClient, rx: mpsc::Receiver<OwnerCmd>, shared: OwnerShared) {
    let OwnerShared {
        status,
        events,
        hold,
    } = shared;
    let hardware = client.hardware;
    let set_state = |state: &'static str, fault: Option<FaultStatus>| {
        let mut s = lock(&status);
        s.state = state;
        if fault.is_some() || state != "faulted" {
            s.fault = fault;
        }
        let _ = events.send(event("state", json!({ "state": state, "fault": s.fault })));
    };
    let gone = || ApiError::new(ApiErrorKind::Error, "the real-time loop is gone");
    loop {
        let cmd = rx.recv_timeout(std::time::Duration::from_millis(10));
        match cmd {
            Ok(OwnerCmd::Shutdown) | Err(mpsc::RecvTimeoutError::Disconnected) => break,
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Ok(OwnerCmd::Enable(reply)) => {
                let r = match client.call(LoopRequest::Enable(hold.as_ref().map(|f| f()))) {
                    Some(LoopReply::Enabled(Ok(()), _)) => {
                        set_state("enabled", None);
                        Ok(())
                    }
                    Some(LoopReply::Enabled(Err(None), _)) => Err(ApiError::new(
                        ApiErrorKind::Faulted,
                        "a fault is latched: reset first",
                    )),
                    Some(LoopReply::Enabled(Err(Some(e)), _)) => {
                        let api = ApiError::new(ApiErrorKind::Hal, format!("enable failed: {e}"));
                        set_state(
                            "faulted",
                            Some(FaultStatus {
                                kind: FaultKind::Hal.as_str(),
                                message: api.message.clone(),
                            }),
                        );
                        Err(api)
                    }
                    _ => Err(gone()),
                };
                let _ = reply.send(r);
            }
            Ok(OwnerCmd::Disable(reply)) => {
                let r = match client.call(LoopRequest::Disable) {
                    Some(_) => {
                        if lock(&status).state != "faulted" {
                            set_state("disabled", None);
                        }
                        Ok(())
                    }
                    None => Err(gone()),
                };
                let _ = reply.send(r);
            }
            Ok(OwnerCmd::Reset(reply)) => {
                let r = match client.call(LoopRequest::Reset) {
                    Some(_) => {
                        // Faults reported before the reset are cleared by
                        // it; one that latches again after it is reported.
                        client.forget_earlier_faults();
                        set_state("disabled", None);
                        Ok(())
                    }
                    None => Err(gone()),
                };
                let _ = reply.send(r);
            }
            Ok(OwnerCmd::Job(job, handle, reply)) => {
                let result = match job {
                    JobSpec::Chirp(opts) => run_chirp_on(
                        &mut Runner::Service(&mut client),
                        hardware,
                        &opts,
                        Arc::clone(&handle.stop),
                        Some(&handle.ticks),
                    )
                    .map_err(|e| (ApiError::from_run(&e), e))
                    .and_then(to_json),
                    JobSpec::Control(opts) => run_control_from(
                        &opts,
                        Arc::clone(&handle.stop),
                        StageSource::Service(&mut client),
                        Some(&handle.ticks),
                    )
                    .map_err(|e| (ApiError::from_run(&e), e))
                    .and_then(to_json),
                };
                {
                    let mut s = lock(&status);
                    s.jobs_run += 1;
                    if let Some(j) = s.job.take() {
                        s.last_recording = Some(j.recording);
                    }
                }
                match &result {
                    // The latched fault is reported by its supervisor name.
                    Err((api, RunError::Fault { kind, .. })) => {
                        let fault = FaultStatus {
                            kind,
                            message: api.message.clone(),
                        };
                        set_state("faulted", Some(fault));
                    }
                    Err((api, RunError::Hal { .. })) => {
                        let fault = FaultStatus {
                            kind: FaultKind::Hal.as_str(),
                            message: api.message.clone(),
                        };
                        set_state("faulted", Some(fault));
                    }
                    _ => set_state("disabled", None),
                }
                let _ = reply.send(result.map_err(|(api, _)| api));
            }
        }
        for f in client.take_faults() {
            if let Some(api) = between_jobs_fault(f) {
                set_state("faulted", Some(api));
            }
        }
    }
    let _ = client.call(LoopRequest::Shutdown);
}

pub(super) fn recording_path(dir: &Path, prefix: &str, id: u64) -> PathBuf {
    crate::jobs::session::stamped_recording(dir, prefix, &format!("-job{id}"))
}

/// Builds a job from a request; `Err` for bad parameters.
pub(super) fn job_spec(
    ctx: &Ctx,
    request: &JobRequest,
    id: u64,
) -> Result<(JobSpec, &'static str, u64, PathBuf), ApiError> {
    let mut cfg = ctx.cfg.clone();
    // The request names a config key or its field; a field is a parameter.
    let bad = |e: RequestError| {
        let message = match e {
            RequestError::Field { .. } => format!("params.{e}"),
            RequestError::Invalid { .. } => e.to_string(),
        };
        ApiError::new(ApiErrorKind::BadParams, message)
    };
    match request {
        JobRequest::Chirp(req) => {
            req.apply(&mut cfg).map_err(bad)?;
            let chirp = crate::ident::excitation::Chirp::new(&cfg.chirp, ctx.period_s);
            let out = recording_path(&ctx.recordings, "chirp", id);
            let opts = ChirpOptions {
                frf_csv: beside(&out, ".frf.csv"),
                plot: beside(&out, ".bode.png"),
                out: out.clone(),
                seed: req.seed.unwrap_or(ctx.seed),
                config: cfg,
                config_path: ctx.config_path.clone(),
                realtime: true,
                progress: false,
                backend: Some(ctx.spec.clone()),
            };
            Ok((
                JobSpec::Chirp(Box::new(opts)),
                request.kind(),
                chirp.total_ticks(),
                out,
            ))
        }
        JobRequest::Control(req) => {
            let inject = req.apply(&mut cfg).map_err(bad)?;
            let out = recording_path(&ctx.recordings, &format!("control-{}", req.controller), id);
            let total = (cfg.step.duration_s / ctx.period_s).round() as u64;
            let opts = ControlOptions {
                plot: beside(&out, ".step.png"),
                out: out.clone(),
                controller: req.controller.clone(),
                check_only: false,
                frf: None,
                override_check: req.override_check,
                realtime: true,
                seed: req.seed.unwrap_or(ctx.seed),
                progress: false,
                inject,
                backend: Some(ctx.spec.clone()),
                config: cfg,
                config_path: ctx.config_path.clone(),
            };
            Ok((JobSpec::Control(Box::new(opts)), request.kind(), total, out))
        }
    }
}
