//! The daemon's loop: one [`Loop`] and one supervisor for the daemon's
//! whole life. Between jobs the loop runs the hold job (0 A; every rule of
//! the supervisor applies, the device keeps being read, nothing is
//! recorded); a job is prepared on another thread and handed over on a
//! tick, so no sample backlog builds up, and handed back when it ends.
//!
//! Requests and replies cross wait-free SPSC queues (`rtrb`), so nothing on
//! the tick locks, allocates or formats: a job, its record queue and its
//! stop flag arrive boxed ([`JobTicket`]) and go back boxed, to be dropped
//! off the real-time thread; errors come back unformatted.

use crate::rt::backend::{AnyError, AnyStage, LinkCounters};
use crate::rt::{HalFailure, HoldJob, Job, JobEnd, Loop, LoopOptions, Pacing};
use crate::vocab::{FaultKind, SupervisorState};
use bench_hal::Clock;
use bench_plant::sim::ScheduledFault;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

/// A job handed to the loop, with everything it needs on the tick.
pub struct JobTicket {
    /// The job.
    pub job: Box<dyn Job + Send>,
    /// Its record queue (the writer drains the other end).
    pub out: crate::rt::RecordQueue,
    /// Tick budget.
    pub max_ticks: u64,
    /// The job's stall bounds (closed loop: its loop check's; open loop:
    /// none but the user's; see [`crate::rt::supervisor::StallBounds`]).
    pub stall: crate::rt::supervisor::StallBounds,
    /// The job's seed: the simulator's noise restarts from it at the
    /// job's first sample ([`AnyStage::reseed`]), so the job records what a
    /// local run with that seed records. Ignored on hardware.
    pub seed: u64,
    /// How the job is paced when not in the loop's real time: virtual
    /// time, paced or not, on a simulator daemon ([`Loop::set_pacing`];
    /// the loop is back in real time for the hold after it). `None`: the
    /// loop's own real time.
    pub pacing: Option<Pacing>,
    /// Raised to stop the job safely.
    pub stop: Arc<AtomicBool>,
    /// The job's tick count.
    pub progress: Arc<AtomicU64>,
    /// How it ended (filled in by the loop).
    pub end: Option<JobEnd<AnyError>>,
    /// Link counters before and after the job (hardware; filled in by the
    /// loop).
    pub link: Option<(LinkCounters, LinkCounters)>,
    /// The hold job the job took over from (filled in by the loop), to be
    /// dropped off the tick.
    pub old_hold: Option<Box<dyn Job + Send>>,
}

/// What the daemon asks of its loop.
pub enum LoopRequest {
    /// Enable the amplifier at 0 A (refused while faulted); with a hold
    /// job (a controller holding the position it starts at), that job then
    /// drives the stage between jobs.
    Enable(Option<Box<dyn Job + Send>>),
    /// 0 A, amplifier disabled.
    Disable,
    /// Clear a latched fault.
    Reset,
    /// Schedule a simulator fault, `at_s` from now (tests).
    Inject(ScheduledFault),
    /// Run a job now.
    Job(Box<JobTicket>),
    /// End the loop (0 A, disabled).
    Shutdown,
}

/// What the loop answers.
pub enum LoopReply {
    /// The answer to [`LoopRequest::Enable`]: `Err(None)` while faulted;
    /// the hold job it replaced, to be dropped off the tick.
    Enabled(Result<(), Option<AnyError>>, Option<Box<dyn Job + Send>>),
    /// The answer to [`LoopRequest::Disable`], with the hold job it ended.
    Disabled(Option<Box<dyn Job + Send>>),
    /// The answer to [`LoopRequest::Reset`], with the hold job it ended.
    Reset(Option<Box<dyn Job + Send>>),
    /// The answer to [`LoopRequest::Inject`] (refused on hardware).
    Injected(bool),
    /// A job ended; its ticket comes back, with how it ended, to be
    /// dropped off the tick.
    JobDone(Box<JobTicket>),
    /// A fault latched between jobs.
    Fault {
        /// Which.
        kind: FaultKind,
        /// The offending value.
        value: f64,
        /// The last bad-sample or lost-link error.
        link_error: Option<AnyError>,
        /// The HAL error, for `hal` faults.
        hal_error: Option<HalFailure<AnyError>>,
    },
    /// The loop ended.
    Stopped,
}

/// What the loop publishes for `status` without a lock (last reading and
/// command).
#[derive(Debug)]
pub struct LoopStatus {
    /// Last reading, m, as `f64::to_bits`.
    pub position_bits: AtomicU64,
    /// Last current commanded, A, as `f64::to_bits`.
    pub command_bits: AtomicU64,
}

impl Default for LoopStatus {
    fn default() -> Self {
        Self {
            position_bits: AtomicU64::new(f64::NAN.to_bits()),
            command_bits: AtomicU64::new(0f64.to_bits()),
        }
    }
}

impl LoopStatus {
    /// The last reading, m.
    pub fn position_m(&self) -> f64 {
        f64::from_bits(self.position_bits.load(Ordering::Relaxed))
    }

    /// The last current commanded, A.
    pub fn command_a(&self) -> f64 {
        f64::from_bits(self.command_bits.load(Ordering::Relaxed))
    }
}

/// Runs the daemon's loop on the calling thread until
/// [`LoopRequest::Shutdown`] (or the request queue's other end is gone).
/// Leaves the stage at 0 A, disabled. With `tap`, every real-time tick
/// is counted for the daemon's metrics, with the backend's link counters
/// ([`crate::rt::tap`]).
pub fn run_service(
    stage: &mut AnyStage,
    opts: &LoopOptions,
    clock: Clock,
    mut requests: rtrb::Consumer<LoopRequest>,
    mut replies: rtrb::Producer<LoopReply>,
    status: &LoopStatus,
    tap: Option<crate::rt::tap::LoopTap>,
) {
    let period_s = opts.period_ns as f64 * 1e-9;
    let mut lp = Loop::new(stage, opts, clock);
    if let Some(tap) = tap {
        lp.set_tap(tap, Some(AnyStage::link_counters));
    }
    for w in lp.warnings() {
        tracing::warn!("{w}");
    }
    lp.publish(&status.position_bits, &status.command_bits);
    // The hold job of the last `Enable` (None: 0 A).
    let mut hold: Option<Box<dyn Job + Send>> = None;
    let reply = |r: LoopReply, replies: &mut rtrb::Producer<LoopReply>| {
        // The daemon drains replies continuously; a full queue means it is
        // gone.
        let _ = replies.push(r);
    };
    loop {
        let mut pending = None;
        let was_faulted = lp.supervisor().state() == SupervisorState::Faulted;
        let mut zero = HoldJob;
        let job: &mut dyn Job = match hold.as_mut() {
            Some(h) => h,
            None => &mut zero,
        };
        let newly_faulted = lp.hold(job, |lp| {
            if !was_faulted && lp.supervisor().state() == SupervisorState::Faulted {
                return true;
            }
            if requests.is_abandoned() && requests.is_empty() {
                pending = Some(LoopRequest::Shutdown);
                return true;
            }
            match requests.pop() {
                Ok(r) => {
                    pending = Some(r);
                    true
                }
                Err(_) => false,
            }
        });
        if newly_faulted {
            let (kind, value) = lp
                .supervisor()
                .fault()
                .unwrap_or((FaultKind::Hal, f64::NAN));
            let (link_error, hal_error) = lp.take_errors();
            reply(
                LoopReply::Fault {
                    kind,
                    value,
                    link_error,
                    hal_error,
                },
                &mut replies,
            );
        }
        let Some(req) = pending else { continue };
        match req {
            LoopRequest::Enable(job) => {
                let r = lp.enable();
                let old = hold.take();
                if r.is_ok() && job.is_some() {
                    // The hold controller drives from the next tick on.
                    hold = job;
                    lp.drive();
                }
                reply(LoopReply::Enabled(r, old), &mut replies);
            }
            LoopRequest::Disable => {
                lp.disable();
                reply(LoopReply::Disabled(hold.take()), &mut replies);
            }
            LoopRequest::Reset => {
                lp.reset();
                reply(LoopReply::Reset(hold.take()), &mut replies);
            }
            LoopRequest::Inject(f) => {
                let ok = lp.stage().inject(f).is_ok();
                reply(LoopReply::Injected(ok), &mut replies);
            }
            LoopRequest::Job(mut ticket) => {
                // The job takes over from the hold controller; it ends
                // disabled, so the hold does not resume by itself.
                ticket.old_hold = hold.take();
                let before = lp.stage().link_counters();
                lp.stage().reseed(ticket.seed);
                let t = &mut *ticket;
                // The job's stall bounds while it runs, the hold's after.
                let hold_bounds = lp.supervisor().stall_bounds();
                lp.set_stall_bounds(t.stall);
                // A link's exchange deadline follows the job's bound too
                // (arithmetic on the stage; the loop is between ticks).
                lp.stage()
                    .set_stall_bound_s(t.stall.missed_deadlines_s(period_s));
                if let Some(p) = t.pacing {
                    lp.set_pacing(p);
                }
                t.end = Some(lp.run_job(&mut t.job, &mut t.out, t.max_ticks, &t.stop, &t.progress));
                if t.pacing.is_some() {
                    lp.set_pacing(opts.pacing);
                }
                t.link = before.zip(lp.stage().link_counters());
                lp.set_stall_bounds(hold_bounds);
                lp.stage()
                    .set_stall_bound_s(hold_bounds.missed_deadlines_s(period_s));
                reply(LoopReply::JobDone(ticket), &mut replies);
            }
            LoopRequest::Shutdown => break,
        }
    }
    lp.disable();
    reply(LoopReply::Stopped, &mut replies);
}

/// The daemon's side of the loop's queues (not real-time): sends a
/// request and waits for its answer.
pub struct ServiceClient {
    requests: rtrb::Producer<LoopRequest>,
    replies: rtrb::Consumer<LoopReply>,
    /// The device the loop runs.
    pub info: bench_hal::DeviceInfo,
    /// Not the simulator: jobs run in real time.
    pub hardware: bool,
    /// Faults between jobs that arrived while waiting for an answer.
    faults: Vec<LoopReply>,
}

/// How often the daemon polls the loop's answers.
const POLL: std::time::Duration = std::time::Duration::from_millis(1);

impl ServiceClient {
    /// The client of a loop fed by `requests` and answering on `replies`.
    pub fn new(
        requests: rtrb::Producer<LoopRequest>,
        replies: rtrb::Consumer<LoopReply>,
        info: bench_hal::DeviceInfo,
        hardware: bool,
    ) -> Self {
        Self {
            requests,
            replies,
            info,
            hardware,
            faults: Vec::new(),
        }
    }

    /// Sends `req` and waits for its answer (the next reply that is not a
    /// fault between jobs; those are kept for [`Self::take_faults`]).
    /// `None` when the loop is gone.
    pub fn call(&mut self, req: LoopRequest) -> Option<LoopReply> {
        let mut req = req;
        loop {
            match self.requests.push(req) {
                Ok(()) => break,
                Err(rtrb::PushError::Full(r)) => {
                    if self.requests.is_abandoned() {
                        return None;
                    }
                    req = r;
                    std::thread::sleep(POLL);
                }
            }
        }
        loop {
            match self.replies.pop() {
                Ok(r @ LoopReply::Fault { .. }) => self.faults.push(r),
                Ok(LoopReply::Stopped) => return None,
                Ok(r) => return Some(r),
                Err(_) if self.replies.is_abandoned() => return None,
                Err(_) => std::thread::sleep(POLL),
            }
        }
    }

    /// Forgets the faults that arrived before the last answer (a reset
    /// cleared them); later ones stay queued.
    pub fn forget_earlier_faults(&mut self) {
        self.faults.clear();
    }

    /// Faults between jobs reported since the last call, oldest first.
    pub fn take_faults(&mut self) -> Vec<LoopReply> {
        while let Ok(r) = self.replies.pop() {
            if let LoopReply::Fault { .. } = r {
                self.faults.push(r);
            }
        }
        std::mem::take(&mut self.faults)
    }
}
