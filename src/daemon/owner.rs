//! The owner thread: the daemon's side of the real-time loop. It turns
//! requests into loop requests and jobs ([`crate::rt::service`]) and keeps
//! the state `status` shows. May use `rt::service`, `jobs`; never the
//! socket.

use super::jobs::{JobResult, JobSpec};
use super::lock;
use super::protocol::{event, AbandonedJob, ApiError, ApiErrorKind, FaultStatus, Status};
use crate::error::RunError;
use crate::job_memory::JobMemory;
use crate::record::topics::FaultKind;
use crate::record::topics::SupervisorState;
use crate::rt::service::{LoopReply, LoopRequest, ServiceClient};
use crate::rt::timing::TimingStats;
use crate::rt::{Job, JobEnd, RawStop, StopReason};
use serde_json::{json, Value};
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::sync::{mpsc, Arc, Mutex};
use tokio::sync::{broadcast, oneshot};

/// A job's handles shared with the socket side.
#[derive(Debug, Clone)]
pub(super) struct JobHandle {
    pub(super) id: u64,
    /// The request's `cmd` ([`crate::jobs::request::JobRequest::kind`]).
    pub(super) kind: &'static str,
    pub(super) stop: Arc<AtomicBool>,
    pub(super) ticks: Arc<AtomicU64>,
}

pub(super) type Reply<T> = oneshot::Sender<Result<T, ApiError>>;

pub(super) enum OwnerCmd {
    Enable(Reply<()>),
    Disable(Reply<()>),
    Reset(Reply<()>),
    /// A job, and the state the daemon was in before it (a job that does
    /// not use the loop leaves it as it was).
    Job(JobSpec, JobHandle, &'static str, Reply<Value>),
    Shutdown,
}

/// What the owner thread shares with the socket side.
pub(super) struct OwnerShared {
    pub(super) status: Arc<Mutex<Status>>,
    pub(super) events: broadcast::Sender<String>,
    /// The loop's limits between jobs (for the faults' messages).
    pub(super) safety: crate::rt::supervisor::SupervisorConfig,
    /// Makes a fresh hold job for each `enable` (`[daemon]
    /// hold_controller`), if one is configured.
    pub(super) hold: Option<HoldFactory>,
    /// `--metrics`: jobs, faults and the recorder are counted here.
    pub(super) metrics: Option<Arc<super::metrics::Metrics>>,
    /// `--upload`: each finished job's recording is queued here.
    pub(super) uploader: Option<crate::upload::worker::Uploader>,
}

/// Makes the hold controller's job: the controller holds the position the
/// stage is at on its first tick, for ever.
pub(super) type HoldFactory = Box<dyn Fn() -> Box<dyn Job + Send> + Send>;

/// A fault the loop latched between jobs, as `status` reports it: the
/// supervisor's fault name and its physical reason, with the quantity, the
/// bound and where it came from
/// ([`crate::rt::supervisor::fault_message`]).
pub(super) fn between_jobs_fault(
    r: LoopReply,
    safety: &crate::rt::supervisor::SupervisorConfig,
) -> Option<FaultStatus> {
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
            stall: None,
        },
    };
    let message = match stop.describe() {
        StopReason::Hal { message, .. } => message,
        StopReason::Fault { detail, stall, .. } => crate::rt::supervisor::fault_message(
            kind,
            value,
            safety,
            stall,
            "the hold controller's stall bound",
            detail.as_deref(),
        ),
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

/// A job being prepared or run. Its worker thread prepares it and runs it
/// through a [`ServiceClient`] of its own, whose queues the owner relays
/// to the loop: the owner stays free to answer, and it alone decides
/// whether the job reaches the loop.
struct Active {
    handle: JobHandle,
    reply: Reply<Value>,
    done: mpsc::Receiver<JobResult>,
    /// The worker's loop requests.
    requests: rtrb::Consumer<LoopRequest>,
    /// The loop's answers, for the worker.
    replies: rtrb::Producer<LoopReply>,
    /// The job was handed to the loop (it may have enabled the stage).
    in_loop: bool,
    /// The loop gave the job back (0 A, disabled), or the job was
    /// stopped as it was about to reach the loop.
    loop_done: bool,
    /// When `stop` was first seen.
    stop_seen: Option<std::time::Instant>,
    /// A job that only computes (fit, analyze, map, campaign): it never
    /// reaches the loop, is never abandoned (a stop reaches the job, and a
    /// campaign ends after its running cells), and leaves the daemon in
    /// this state (unless a fault latched meanwhile).
    compute: Option<&'static str>,
    /// The memory budget of a job that computes (`None`: a bench job,
    /// bounded by its length, `config::ranges::JOB_TICKS_MAX` ticks).
    memory: Option<JobMemory>,
}

/// How long a job stopped during its preparation is given to reach the
/// loop (it then ends `interrupted` before its first tick, its recording
/// finished) or to return, before it is abandoned.
const PREPARATION_STOP_GRACE: std::time::Duration = std::time::Duration::from_millis(200);

/// [`super::JOB_STOP_TIMEOUT_MS`].
const JOB_STOP_TIMEOUT: std::time::Duration =
    std::time::Duration::from_millis(super::JOB_STOP_TIMEOUT_MS);

/// How an active job ended, for the owner.
enum Outcome {
    /// The worker returned.
    Finished(JobResult),
    /// Its worker is left behind, for this reason.
    Abandoned(Abandon),
}

/// Why a job was abandoned (its thread left to end on its own).
#[derive(Debug, Clone, Copy)]
enum Abandon {
    /// Stopped before it reached the loop: nothing was enabled.
    Preparing,
    /// The daemon shut down while the job was finishing.
    Shutdown,
    /// Stopped, and not done [`JOB_STOP_TIMEOUT`] later.
    NoAnswer,
    /// Over its memory budget: this allocation (bytes) was refused.
    OverBudget(u64),
}

/// A job abandoned whose thread has not ended yet.
struct Left {
    id: u64,
    kind: &'static str,
    done: mpsc::Receiver<JobResult>,
    memory: Option<JobMemory>,
    /// Its recording (empty: none), finished by its thread if it can.
    recording: String,
}

impl Left {
    /// `None` while its thread runs; then what it returned (`Some(None)`:
    /// it panicked).
    fn ended(&self) -> Option<Option<JobResult>> {
        match self.done.try_recv() {
            Ok(r) => Some(Some(r)),
            Err(mpsc::TryRecvError::Disconnected) => Some(None),
            Err(mpsc::TryRecvError::Empty) => None,
        }
    }

    /// What its threads hold, bytes (0 for a job without a budget).
    fn held_bytes(&self) -> u64 {
        self.memory.as_ref().map_or(0, JobMemory::live_bytes)
    }
}

/// A rayon pool for a job that computes, whose threads count against its
/// budget (`rayon`'s global pool is shared by every thread). `None`
/// when it cannot be built: the job then uses the global pool, uncounted.
fn job_pool(memory: &JobMemory, id: u64) -> Option<rayon::ThreadPool> {
    let m = memory.clone();
    rayon::ThreadPoolBuilder::new()
        .num_threads(rayon::current_num_threads())
        .thread_name(move |i| format!("bench-job{id}-{i}"))
        .start_handler(move |_| m.attach_thread())
        .exit_handler(|_| crate::job_memory::detach_thread())
        .build()
        .map_err(|e| {
            tracing::warn!("job {id}: no pool of its own ({e}); its rayon work is not counted")
        })
        .ok()
}

impl Active {
    /// Starts the worker thread of `job`.
    fn start(
        job: JobSpec,
        handle: JobHandle,
        before: &'static str,
        reply: Reply<Value>,
        client: &ServiceClient,
        memory: Option<JobMemory>,
    ) -> Result<Self, (Reply<Value>, ApiError)> {
        let compute = (!job.uses_loop()).then_some(before);
        let kind = handle.kind;
        let (req_tx, req_rx) = rtrb::RingBuffer::<LoopRequest>::new(4);
        let (rep_tx, rep_rx) = rtrb::RingBuffer::<LoopReply>::new(4);
        let mut proxy = ServiceClient::new(req_tx, rep_rx, client.info.clone(), client.hardware);
        let (done_tx, done) = mpsc::channel();
        let (stop, ticks) = (Arc::clone(&handle.stop), Arc::clone(&handle.ticks));
        let hardware = client.hardware;
        let (id, counted) = (handle.id, memory.clone());
        let spawned = std::thread::Builder::new()
            .name(format!("bench-job{id}"))
            .spawn(move || {
                let _counted = counted.as_ref().map(JobMemory::enter);
                crate::daemon::testing::prepare_hang_hook();
                crate::daemon::testing::allocate_hook(kind);
                let run = || super::jobs::run(job, &mut proxy, hardware, stop, &ticks);
                let result = match counted.as_ref().and_then(|m| job_pool(m, id)) {
                    Some(pool) => pool.install(run),
                    None => run(),
                };
                let _ = done_tx.send(result);
            });
        match spawned {
            Ok(_) => Ok(Self {
                handle,
                reply,
                done,
                requests: req_rx,
                replies: rep_tx,
                in_loop: false,
                loop_done: false,
                stop_seen: None,
                compute,
                memory,
            }),
            Err(e) => Err((
                reply,
                ApiError::new(
                    ApiErrorKind::Error,
                    format!("cannot start the job thread: {e}"),
                ),
            )),
        }
    }

    /// Relays the worker's requests to the loop (a job's run blocks here
    /// until the loop gives it back; `stop` ends it within a tick) and
    /// says whether the job is over. A job stopped before it reached the
    /// loop never gets there: it ends `interrupted` before its first tick
    /// (amplifier disabled, as at the end of any job; its recording
    /// finished by the worker), or, when its preparation does not get that
    /// far within [`PREPARATION_STOP_GRACE`], it is abandoned: it never
    /// touched the stage. Any other job still running [`JOB_STOP_TIMEOUT`]
    /// after its stop is abandoned too, and a job that computes as soon as
    /// it goes over its memory budget. With `shutting_down` (the daemon
    /// has given the job its time already) a stopped job is not waited for.
    fn step(
        &mut self,
        client: &mut ServiceClient,
        shutting_down: bool,
        metrics: Option<&super::metrics::Metrics>,
    ) -> Option<Outcome> {
        let stopped = || self.handle.stop.load(std::sync::atomic::Ordering::Relaxed);
        while let Ok(req) = self.requests.pop() {
            let reply = match req {
                LoopRequest::Job(mut ticket) if stopped() => {
                    if client.call(LoopRequest::Disable).is_none() {
                        return Some(Outcome::Finished(Err(gone_loop())));
                    }
                    ticket.end = Some(JobEnd {
                        ticks: 0,
                        stop: RawStop::Interrupted { tick: 0 },
                        timing: TimingStats::default(),
                        cpu_dma_latency: Default::default(),
                        dropped_records: 0,
                        final_state: SupervisorState::Disabled,
                    });
                    self.loop_done = true;
                    LoopReply::JobDone(ticket)
                }
                LoopRequest::Job(ticket) => {
                    self.in_loop = true;
                    if let Some(m) = metrics {
                        m.job_in_loop(Arc::clone(&ticket.out.room));
                    }
                    let r = client.call(LoopRequest::Job(ticket));
                    self.loop_done = true;
                    match r {
                        Some(r) => {
                            if let (Some(m), LoopReply::JobDone(t)) = (metrics, &r) {
                                m.job_out_of_loop(t.end.as_ref().map_or(0, |e| e.dropped_records));
                            }
                            r
                        }
                        None => return Some(Outcome::Finished(Err(gone_loop()))),
                    }
                }
                req => match client.call(req) {
                    Some(r) => r,
                    None => return Some(Outcome::Finished(Err(gone_loop()))),
                },
            };
            // The worker waits for each answer: there is room.
            let _ = self.replies.push(reply);
        }
        match self.done.try_recv() {
            Ok(r) => Some(Outcome::Finished(r)),
            Err(mpsc::TryRecvError::Disconnected) => Some(Outcome::Finished(Err((
                ApiError::new(ApiErrorKind::Error, "the job thread panicked"),
                Some(RunError::Thread("the job thread panicked".into())),
            )))),
            Err(mpsc::TryRecvError::Empty) => {
                if let Some(size) = self.memory.as_ref().and_then(JobMemory::over_budget) {
                    return Some(Outcome::Abandoned(Abandon::OverBudget(size)));
                }
                if !stopped() {
                    return None;
                }
                let seen = *self.stop_seen.get_or_insert_with(std::time::Instant::now);
                let preparing = self.compute.is_none() && !self.in_loop && !self.loop_done;
                if preparing && (shutting_down || seen.elapsed() >= PREPARATION_STOP_GRACE) {
                    Some(Outcome::Abandoned(Abandon::Preparing))
                } else if shutting_down {
                    Some(Outcome::Abandoned(Abandon::Shutdown))
                } else {
                    (seen.elapsed() >= JOB_STOP_TIMEOUT)
                        .then_some(Outcome::Abandoned(Abandon::NoAnswer))
                }
            }
        }
    }
}

/// The answer to the client of a job abandoned for `why`: its error kind
/// and message. `recording`: the job's (empty: none); `memory`: its budget.
fn abandoned_answer(
    why: Abandon,
    recording: &str,
    memory: Option<&JobMemory>,
) -> (ApiErrorKind, String) {
    let safe = "0 A, amplifier disabled";
    let rec = if recording.is_empty() {
        String::new()
    } else {
        format!(
            "; its recording is finished by its thread if it can, else left as {recording}{} for `bench recover`",
            crate::outputs::PART_SUFFIX
        )
    };
    match why {
        Abandon::Preparing => (
            ApiErrorKind::Interrupted,
            "stopped while the job was being prepared; nothing was enabled, no recording".into(),
        ),
        Abandon::Shutdown => (
            ApiErrorKind::Interrupted,
            format!("the daemon shut down while the job was finishing{rec}; {safe}"),
        ),
        Abandon::NoAnswer => (
            ApiErrorKind::Interrupted,
            format!(
                "stopped, and not done {} ms later (JOB_STOP_TIMEOUT_MS): abandoned, its thread left to end on its own{rec}; {safe}",
                JOB_STOP_TIMEOUT.as_millis()
            ),
        ),
        Abandon::OverBudget(size) => (
            ApiErrorKind::Error,
            format!(
                "the job went over its memory budget of {} MiB (a quarter of the daemon's memory limit) at an allocation of {size} bytes: abandoned, its thread parked for good (what it holds, {} MiB, is kept until the daemon restarts); {safe}",
                memory.map_or(0, |m| m.limit_bytes() >> 20),
                memory.map_or(0, |m| m.live_bytes() >> 20),
            ),
        ),
    }
}

/// The answer when the real-time loop is gone.
fn gone() -> ApiError {
    ApiError::new(ApiErrorKind::Error, "the real-time loop is gone")
}

fn gone_loop() -> (ApiError, Option<RunError>) {
    (
        ApiError::new(ApiErrorKind::Error, "the real-time loop is gone"),
        Some(RunError::Thread("the daemon's loop is gone".into())),
    )
}

/// The owner thread: the daemon's side of the loop. It hands requests and
/// jobs to the real-time loop ([`crate::rt::service`]), which runs the
/// hold job and the one supervisor between them, and reports faults the
/// loop latched between jobs. Jobs are prepared on a worker thread each,
/// so the owner keeps answering while one is prepared, and a job stopped
/// (or a daemon shut down) during its preparation ends at once.
pub(super) fn owner(client: ServiceClient, rx: mpsc::Receiver<OwnerCmd>, shared: OwnerShared) {
    let mut o = Owner {
        client,
        shared,
        active: None,
        left: Vec::new(),
        shutting_down: false,
    };
    loop {
        let wait = std::time::Duration::from_millis(if o.active.is_some() { 1 } else { 10 });
        match rx.recv_timeout(wait) {
            Err(mpsc::RecvTimeoutError::Disconnected) => {
                o.shutting_down = true;
                std::thread::sleep(wait);
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Ok(cmd) => o.command(cmd),
        }
        o.step_active();
        o.reap_left();
        if o.shutting_down && o.active.is_none() {
            break;
        }
        o.report_faults();
    }
    let _ = o.client.call(LoopRequest::Shutdown);
}

/// The owner thread's state.
struct Owner {
    client: ServiceClient,
    shared: OwnerShared,
    /// The job being prepared or run.
    active: Option<Active>,
    /// Jobs abandoned whose threads still run (or sleep, parked over their
    /// budget), with what they hold.
    left: Vec<Left>,
    shutting_down: bool,
}

impl Owner {
    fn metrics(&self) -> Option<&super::metrics::Metrics> {
        self.shared.metrics.as_deref()
    }

    /// Sets the daemon's state and tells the event stream; every latch
    /// comes here once, with its fault.
    fn set_state(&self, state: &'static str, fault: Option<FaultStatus>) {
        if let (Some(m), "faulted", Some(f)) = (self.metrics(), state, fault.as_ref()) {
            m.fault(f.kind);
        }
        let mut s = lock(&self.shared.status);
        s.state = state;
        if fault.is_some() || state != "faulted" {
            s.fault = fault;
        }
        let _ = self
            .shared
            .events
            .send(event("state", json!({ "state": state, "fault": s.fault })));
    }

    /// The abandoned jobs, as `status` shows them.
    fn show_left(&self) {
        lock(&self.shared.status).abandoned_jobs = self
            .left
            .iter()
            .map(|l| AbandonedJob {
                id: l.id,
                kind: l.kind,
                memory_bytes: l.held_bytes(),
            })
            .collect();
    }

    /// Answers one command; while a job runs, every one but `Shutdown` is
    /// refused as busy.
    fn command(&mut self, cmd: OwnerCmd) {
        let busy = || ApiError::new(ApiErrorKind::Busy, "a job is running: `stop` it first");
        match cmd {
            OwnerCmd::Enable(reply) | OwnerCmd::Disable(reply) | OwnerCmd::Reset(reply)
                if self.active.is_some() =>
            {
                let _ = reply.send(Err(busy()));
            }
            OwnerCmd::Job(_, _, _, reply) if self.active.is_some() => {
                let _ = reply.send(Err(busy()));
            }
            OwnerCmd::Enable(reply) => {
                let _ = reply.send(self.enable());
            }
            OwnerCmd::Disable(reply) => {
                let r = match self.client.call(LoopRequest::Disable) {
                    Some(_) => {
                        if lock(&self.shared.status).state != "faulted" {
                            self.set_state("disabled", None);
                        }
                        Ok(())
                    }
                    None => Err(gone()),
                };
                let _ = reply.send(r);
            }
            OwnerCmd::Reset(reply) => {
                let r = match self.client.call(LoopRequest::Reset) {
                    Some(_) => {
                        // Faults reported before the reset are cleared by
                        // it; one that latches again after it is reported.
                        self.client.forget_earlier_faults();
                        if let Some(f) = lock(&self.shared.status).fault.as_ref() {
                            tracing::info!(fault = f.kind, "reset: the latched fault is cleared");
                        }
                        self.set_state("disabled", None);
                        Ok(())
                    }
                    None => Err(gone()),
                };
                let _ = reply.send(r);
            }
            OwnerCmd::Job(job, handle, before, reply) => self.start_job(job, handle, before, reply),
            OwnerCmd::Shutdown => self.shutting_down = true,
        }
    }

    /// `enable`: the hold job (if one is configured) on the loop; an
    /// enable the HAL refuses latches a fault.
    fn enable(&mut self) -> Result<(), ApiError> {
        let hold = self.shared.hold.as_ref().map(|f| f());
        match self.client.call(LoopRequest::Enable(hold)) {
            Some(LoopReply::Enabled(Ok(()), _)) => {
                self.set_state("enabled", None);
                Ok(())
            }
            Some(LoopReply::Enabled(Err(None), _)) => Err(ApiError::new(
                ApiErrorKind::Faulted,
                "a fault is latched: reset first",
            )),
            Some(LoopReply::Enabled(Err(Some(e)), _)) => {
                let api = ApiError::new(ApiErrorKind::Hal, format!("enable failed: {e}"));
                tracing::error!(
                    fault = FaultKind::Hal.as_str(),
                    "{}; between jobs, fault latched",
                    api.message
                );
                self.set_state(
                    "faulted",
                    Some(FaultStatus {
                        kind: FaultKind::Hal.as_str(),
                        message: api.message.to_string(),
                    }),
                );
                Err(api)
            }
            _ => Err(gone()),
        }
    }

    /// A job that computes gets a budget, if what abandoned jobs hold
    /// leaves room for it in half the memory limit (`Ok(None)`: a job of
    /// the loop, no budget).
    fn job_memory(&self, job: &JobSpec) -> Result<Option<JobMemory>, ApiError> {
        if job.uses_loop() {
            return Ok(None);
        }
        let limit = crate::job_memory::memory_limit_bytes();
        let budget = limit / crate::job_memory::JOB_SHARE_DIVISOR;
        let held: u64 = self.left.iter().map(Left::held_bytes).sum();
        if held.saturating_add(budget) > limit / 2 {
            let mib = |b: u64| b / (1 << 20);
            return Err(ApiError::new(
                ApiErrorKind::Busy,
                format!(
                    "{} abandoned job(s) still hold {} MiB; a new job's budget of {} MiB would take the daemon over half its memory limit of {} MiB: restart the daemon to free them",
                    self.left.len(),
                    mib(held),
                    mib(budget),
                    mib(limit)
                ),
            ));
        }
        Ok(Some(JobMemory::new(budget)))
    }

    /// Starts a job's worker, or answers why not.
    fn start_job(
        &mut self,
        job: JobSpec,
        handle: JobHandle,
        before: &'static str,
        reply: Reply<Value>,
    ) {
        let memory = match self.job_memory(&job) {
            Ok(m) => m,
            Err(e) => {
                tracing::error!(job = handle.id, "job refused: {}", e.message);
                lock(&self.shared.status).job = None;
                self.set_state(before, None);
                let _ = reply.send(Err(e));
                return;
            }
        };
        match Active::start(job, handle, before, reply, &self.client, memory) {
            Ok(a) => {
                if let Some(j) = lock(&self.shared.status).job.as_ref() {
                    tracing::info!(
                        job = j.id,
                        kind = j.kind,
                        recording = j.recording.as_deref().unwrap_or("none"),
                        "job started"
                    );
                }
                self.active = Some(a);
            }
            Err((reply, e)) => {
                tracing::error!(error = %e.message, "job not started");
                lock(&self.shared.status).job = None;
                self.set_state("disabled", None);
                let _ = reply.send(Err(e));
            }
        }
    }

    /// Relays the active job's requests to the loop, and ends it when it
    /// finished or must be abandoned.
    fn step_active(&mut self) {
        let metrics = self.shared.metrics.as_deref();
        let Some(a) = self.active.as_mut() else {
            return;
        };
        if self.shutting_down {
            a.handle
                .stop
                .store(true, std::sync::atomic::Ordering::Relaxed);
        }
        match a.step(&mut self.client, self.shutting_down, metrics) {
            None => {}
            Some(Outcome::Finished(result)) => {
                let (reply, compute) = match self.active.take() {
                    Some(a) => (Some(a.reply), a.compute),
                    None => (None, None),
                };
                self.finished(&result, compute);
                if let Some(reply) = reply {
                    let _ = reply.send(result.map_err(|(api, _)| api));
                }
            }
            Some(Outcome::Abandoned(why)) => {
                if let Some(a) = self.active.take() {
                    self.abandoned(a, why);
                }
            }
        }
    }

    /// A job's end: counted, logged, its recording uploaded, and the state
    /// it leaves (a fault latched, or the state before a job that did not
    /// use the loop).
    fn finished(&mut self, result: &JobResult, compute: Option<&'static str>) {
        let metrics = self.metrics();
        let mut finished_recording = None;
        let is_campaign;
        {
            let mut s = lock(&self.shared.status);
            is_campaign = s.job.as_ref().is_some_and(|j| j.kind == "campaign");
            s.jobs_run += 1;
            if let (Some(m), Some(j)) = (metrics, s.job.as_ref()) {
                let outcome = match result {
                    Ok(_) => "ok",
                    Err((api, _)) => api.kind.as_str(),
                };
                let rec = j.recording.as_deref().map(std::path::Path::new);
                m.job_finished(j.kind, outcome, rec);
            }
            if let Some(j) = s.job.take() {
                log_job_end(&j, result);
                if j.recording.is_some() {
                    finished_recording.clone_from(&j.recording);
                    s.last_recording = j.recording;
                }
            }
        }
        let uploader = self.shared.uploader.as_ref();
        if let (Some(u), Some(rec)) = (uploader, finished_recording) {
            super::uploads::after_job(u, std::path::Path::new(&rec), result);
        } else if let (Some(u), true) = (uploader, is_campaign) {
            super::uploads::after_campaign(u, result);
        }
        match result {
            // The latched fault is reported by its supervisor name.
            Err((api, Some(RunError::Fault { kind, .. }))) => {
                let fault = FaultStatus {
                    kind,
                    message: api.message.to_string(),
                };
                self.set_state("faulted", Some(fault));
            }
            Err((api, Some(RunError::Hal { .. }))) => {
                let fault = FaultStatus {
                    kind: FaultKind::Hal.as_str(),
                    message: api.message.to_string(),
                };
                self.set_state("faulted", Some(fault));
            }
            // A job that did not use the loop leaves the stage
            // as it was, and a fault that latched meanwhile.
            _ => match compute {
                Some(_) if lock(&self.shared.status).state == "faulted" => {}
                Some(before) => self.set_state(before, None),
                None => self.set_state("disabled", None),
            },
        }
    }

    /// Abandons a job for `why`: its thread is left to end on its own,
    /// the loop disabled, and the client told.
    fn abandoned(&mut self, a: Active, why: Abandon) {
        // Dropping the worker's queues: whatever it asks of
        // the loop from now on gets "the loop is gone".
        let Active {
            handle,
            reply,
            done,
            memory,
            ..
        } = a;
        let (kind, recording) = lock(&self.shared.status)
            .job
            .as_ref()
            .map(|j| (j.kind, j.recording.clone().unwrap_or_default()))
            .unwrap_or_default();
        let (api_kind, message) = abandoned_answer(why, &recording, memory.as_ref());
        if let Some(m) = self.metrics().filter(|_| !kind.is_empty()) {
            let rec = Some(std::path::Path::new(&recording)).filter(|_| !recording.is_empty());
            m.job_finished(kind, api_kind.as_str(), rec);
        }
        tracing::warn!(
            job = handle.id,
            recording = %recording,
            "job abandoned, its thread left to end on its own: {message}"
        );
        // A job ends disabled, this one too: 0 A, enable off.
        let r = self.client.call(LoopRequest::Disable);
        lock(&self.shared.status).job = None;
        self.set_state("disabled", None);
        self.left.push(Left {
            id: handle.id,
            kind,
            done,
            memory,
            recording,
        });
        self.show_left();
        let _ = reply.send(Err(if r.is_some() {
            ApiError::new(api_kind, message)
        } else {
            gone()
        }));
    }

    /// Forgets the abandoned jobs whose threads have ended; a recording
    /// such a thread finished after all goes up too.
    fn reap_left(&mut self) {
        let before = self.left.len();
        let mut i = 0;
        while i < self.left.len() {
            let Some(result) = self.left[i].ended() else {
                i += 1;
                continue;
            };
            let l = self.left.remove(i);
            tracing::info!(job = l.id, "the thread of abandoned job {} has ended", l.id);
            if let (Some(u), Some(result)) = (self.shared.uploader.as_ref(), result) {
                if !l.recording.is_empty() {
                    super::uploads::after_job(u, std::path::Path::new(&l.recording), &result);
                }
            }
        }
        if self.left.len() != before {
            self.show_left();
        }
    }

    /// Latches and logs the faults the loop reported between jobs.
    fn report_faults(&mut self) {
        for f in self.client.take_faults() {
            if let Some(api) = between_jobs_fault(f, &self.shared.safety) {
                let last = lock(&self.shared.status).last_recording.clone();
                tracing::error!(
                    fault = api.kind,
                    last_recording = last.as_deref().unwrap_or("none"),
                    "{}; no job was running (nothing recorded); jobs and enable are refused until reset",
                    api.message
                );
                self.set_state("faulted", Some(api));
            }
        }
    }
}

/// Logs a job's end: finished, on a fault or a HAL error (both latch), or
/// with an error.
fn log_job_end(j: &super::protocol::JobStatus, result: &JobResult) {
    let recording = j.recording.as_deref().unwrap_or("none");
    match result {
        Ok(_) => tracing::info!(job = j.id, kind = j.kind, recording, "job finished"),
        Err((api, Some(RunError::Fault { kind: fault, .. }))) => tracing::error!(
            job = j.id,
            kind = j.kind,
            fault = *fault,
            recording,
            error = %api.message,
            "job ended on a fault; 0 A, amplifier disabled, fault latched"
        ),
        Err((api, Some(RunError::Hal { .. }))) => tracing::error!(
            job = j.id,
            kind = j.kind,
            fault = FaultKind::Hal.as_str(),
            recording,
            error = %api.message,
            "job ended on a HAL error; 0 A, amplifier disabled, fault latched"
        ),
        Err((api, _)) => tracing::warn!(
            job = j.id,
            kind = j.kind,
            recording,
            error = %api.message,
            "job ended with an error"
        ),
    }
}
