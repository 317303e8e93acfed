//! The real-time loop (README, *Architecture* and *Safety: limits and stalls*).
//!
//! A [`Loop`] owns the stage's tick for as long as it lives: a local run
//! makes one for one job ([`run`]); the daemon keeps one for its whole life
//! and runs the hold job between jobs ([`crate::rt::service`]). One
//! [`Supervisor`] lives in the loop, so every safety rule applies on every
//! tick, in a job or between jobs. Per tick, in this order (each step is
//! one method of [`Loop`]):
//!
//! 1. **wait** ([`Loop::wait`]): real-time mode sleeps until the tick's
//!    absolute deadline (`clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)`);
//!    virtual time does not wait, except when paced
//!    ([`Pacing::Paced`]): then the first tick of each batch of about 1 ms
//!    of wall time sleeps until the batch's last tick is due (tick `k` at
//!    `start + k·period/factor`), and how late that release came goes into
//!    the wake-up latency; a device-clocked backend waits inside
//!    `read_sample`;
//! 2. **read** the sample ([`Loop::read`]). A failed read goes to the
//!    supervisor's one HAL-error rule ([`Supervisor::hal_error`]): a read
//!    without a usable sample (timeout, corrupt frames) counts towards the
//!    link fault (K in a row); host-clocked, the tick runs on the last
//!    reading and command held, device-clocked, no tick runs until a sample
//!    arrives. A lost link (disconnect, bus-off) is the link fault at once;
//! 3. **supervise the sample** ([`Loop::supervise_sample`]);
//! 4. run the **job** ([`Loop::job_output`]): excitation, controller, or the
//!    hold job; it does not run on a tick without a sample;
//! 5. **supervise and write the command** ([`Loop::command`]); on a fault in
//!    this tick: 0 A and disable the amplifier now
//!    ([`bench_hal::Stage::zero_and_disable`], the one safe stop);
//! 6. **push the record** ([`Emitter::push`]) to the job's wait-free SPSC
//!    queue (`rtrb`); in real-time mode a full queue drops the record and
//!    counts it, it never waits; in virtual time (no deadlines) the loop
//!    yields until the writer makes room, so a simulated run never loses a
//!    record. Between jobs nothing is recorded;
//! 7. **timing** ([`Loop::timing`]): wake-up latency, compute time and
//!    overrun. A tick that ends more than one period after its deadline is
//!    an overrun; the deadlines it made the loop miss are skipped, not
//!    caught up back to back, and counted: deadlines missed in a row for
//!    longer than `safety.max_overrun_s` are the `overruns` fault
//!    ([`Supervisor::check_overrun`]), the same stall judged the same at
//!    any rate.
//!
//! Wake-up latency is the wake timestamp (`CLOCK_MONOTONIC`, read right
//! after the sleep returns) minus the deadline. Compute time runs from that
//! timestamp to the one taken when the command is out, minus the cost of
//! one clock read (measured when the loop is made: the smallest of 1000
//! back-to-back reads), so neither the sleep nor the timer calls count.
//! Both go into HDR histograms allocated before the first tick
//! ([`crate::rt::timing`], ≤ 1 % relative error).
//!
//! Real-time pacing also holds `/dev/cpu_dma_latency` at 0 for the loop's
//! life, as `cyclictest` does ([`bench_hal::os::CpuDmaLatency`]); when it cannot be
//! opened the loop says so in its warnings and the report.
//!
//! Nothing on the tick allocates, locks, logs or does I/O other than the
//! HAL calls (the `alloc` integration test counts allocations to prove it,
//! including a faulting tick). A job's end comes back raw ([`JobEnd`]);
//! only [`JobEnd::into_report`], after the loop, formats messages. Setup
//! before the first tick (scheduling, memory locking) may allocate.

use crate::record::queue::{Emitter, RecordQueue};
use crate::record::topics::{
    EventKind, EventRecord, FaultKind, Record, SampleRecord, SupervisorState, TimingRecord,
};
use crate::rt::backend::LinkCounters;
use crate::rt::job::{pace_batch_ticks, Job, JobOutput, LoopOptions, Pacing};
use crate::rt::report::{JobEnd, LoopReport, RawStop};
use crate::rt::supervisor::{HalCall, HalVerdict, StallBounds, Supervisor};
use crate::rt::tap::LoopTap;
use crate::rt::timing::TickTiming;
use bench_hal::os::{
    make_realtime, monotonic_ns as now_ns, sleep_until_ns, CpuDmaLatency, DmaLatency,
};
use bench_hal::{Clock, Command, Error as _, Sample, Stage};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// Virtual time measures the compute time of one tick in this many: no
/// deadline depends on it, and two clock reads and two histogram updates a
/// tick were a quarter of the virtual-time loop's CPU. Real time measures
/// every tick.
pub const VIRTUAL_TIMING_STRIDE: u64 = 16;

/// The schedule of paced virtual time ([`Pacing::Paced`]): when each tick
/// of the current job is due on the wall clock. It decides when ticks run,
/// never whether they may: no rule of the supervisor reads it, and a
/// release that comes late is caught up (the simulated plant advances by
/// the period whatever the wall clock did).
#[derive(Debug, Clone, Copy)]
struct PaceClock {
    /// Wall time per tick, ns (`period / factor`).
    tick_ns: f64,
    /// Ticks released per sleep ([`pace_batch_ticks`]).
    batch: u64,
    /// Monotonic time of the job's tick 0, ns (set when it is released).
    origin_ns: Option<u64>,
}

impl PaceClock {
    /// The schedule of `pacing`, if it is paced.
    fn of(pacing: Pacing, period_ns: u64) -> Option<Self> {
        match pacing {
            Pacing::Paced { factor } => Some(Self {
                tick_ns: period_ns as f64 / factor,
                batch: pace_batch_ticks(period_ns, factor),
                origin_ns: None,
            }),
            _ => None,
        }
    }

    /// Releases `tick` (job ticks): the first tick of a batch sleeps until
    /// the batch's last tick is due, so no tick runs before its time and
    /// the loop sleeps once per batch. Returns how late the batch was
    /// released, ns (after the sleep, or at once when already behind), on
    /// a batch's first tick; `None` on the others. No allocation.
    #[inline]
    fn release(&mut self, tick: u64) -> Option<u64> {
        if !tick.is_multiple_of(self.batch) {
            return None;
        }
        let now = now_ns();
        let origin = *self.origin_ns.get_or_insert(now);
        let due = origin + ((tick + self.batch - 1) as f64 * self.tick_ns) as u64;
        if now >= due {
            return Some(now - due);
        }
        sleep_until_ns(due);
        Some(now_ns().saturating_sub(due))
    }
}

/// Records one event with the supervisor's state (and its fault, for a
/// fault event). Real-time safe.
trait EmitEvent {
    fn event(&mut self, tick: u64, t_s: f64, kind: EventKind, sup: &Supervisor, value: f64);
}

impl EmitEvent for Emitter<'_> {
    fn event(&mut self, tick: u64, t_s: f64, kind: EventKind, sup: &Supervisor, value: f64) {
        if !self.records() {
            return;
        }
        self.push(Record::Event(EventRecord {
            tick,
            t_s,
            kind,
            state: sup.state(),
            fault: if kind == EventKind::Fault {
                sup.fault().map(|f| f.0)
            } else {
                None
            },
            value,
        }));
    }
}

/// A failed HAL call, kept unformatted: which call, and the backend's
/// error.
pub type HalFailure<E> = (HalCall, E);

/// What [`Loop::read`] got.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Read {
    /// A sample.
    Sample(Sample),
    /// No usable sample this tick (timeout, corrupt frames, lost link, a
    /// failed read); `fault` when the read latched a fault.
    Missing {
        /// This read latched a fault.
        fault: bool,
    },
}

/// Per-job bookkeeping of the loop (tick counts, timing windows, what the
/// job last asked for).
struct JobCursor {
    /// Job ticks so far.
    tick: u64,
    /// Device time the job's loop time counts from, s.
    origin_s: f64,
    /// Loop time of the last tick, s (job time).
    last_t_s: f64,
    /// The job's last output (held on a tick without a sample).
    held: JobOutput,
    /// Monotonic time the job's `wake_s` counts from, ns (set on its first
    /// tick).
    origin_ns: Option<u64>,
    window_ticks: u64,
}

/// One tick's result for the caller.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TickResult {
    /// The tick ran; `done` if the job said so.
    Ran {
        /// The job is complete.
        done: bool,
    },
    /// Device-clocked and no sample came: no tick ran.
    NoTick,
}

/// The real-time loop over a configured stage: its deadlines, its one
/// supervisor and the state a tick carries to the next.
pub struct Loop<'s, S: Stage> {
    stage: &'s mut S,
    sup: Supervisor,
    period_ns: u64,
    period_s: f64,
    timing_interval_ticks: u64,
    clock: Clock,
    host_paced: bool,
    backpressure: bool,
    /// Paced virtual time's schedule ([`Pacing::Paced`]).
    pace: Option<PaceClock>,
    /// The thread's SCHED_FIFO priority as real-time pacing set it up
    /// (restored by [`Loop::set_pacing`] after a job in virtual time).
    fifo_priority: Option<i32>,
    /// Deadline of the next tick, ns (host-paced).
    next_deadline_ns: u64,
    last_good: Option<Sample>,
    /// The first HAL error of the current job, kept as-is.
    hal_error: Option<HalFailure<S::Error>>,
    /// The latest bad-sample or lost-link error.
    link_error: Option<S::Error>,
    /// When the last sample was read (or the job started), monotonic ns:
    /// how long the link has been silent when a read times out.
    last_sample_ns: u64,
    /// Real-time setup warnings.
    warnings: Vec<String>,
    /// Where the last reading and command are published (m and A, as
    /// `f64::to_bits`).
    published: Option<(&'s AtomicU64, &'s AtomicU64)>,
    /// Timing over the current job (allocated once, reset per job).
    total: TickTiming,
    /// Timing over the current `/bench/timing` window.
    window: TickTiming,
    /// Cost of one clock read, ns (taken off the compute time).
    clock_read_ns: u64,
    /// The `/dev/cpu_dma_latency` request, held while the loop lives.
    _dma_guard: Option<CpuDmaLatency>,
    dma_latency: DmaLatency,
    /// The daemon's metrics: counts of the real-time ticks, handed off
    /// wait-free ([`Loop::set_tap`]).
    tap: Option<LoopTap>,
    /// Reads the backend's link counters for the tap (hardware).
    link_probe: Option<fn(&S) -> Option<LinkCounters>>,
}

/// The cost of one `CLOCK_MONOTONIC` read, ns: the smallest difference of
/// two back-to-back reads over 1000 tries (the interval between two reads
/// spans about one call).
fn clock_read_cost_ns() -> u64 {
    (0..1000)
        .map(|_| {
            let a = now_ns();
            now_ns().saturating_sub(a)
        })
        .min()
        .unwrap_or(0)
}

impl<'s, S: Stage> Loop<'s, S> {
    /// A loop on `stage` (configured, amplifier disabled). Real-time pacing
    /// applies SCHED_FIFO and memory locking to the calling thread, which
    /// must be the one that runs the ticks.
    pub fn new(stage: &'s mut S, opts: &LoopOptions, clock: Clock) -> Self {
        let mut warnings = Vec::new();
        let mut fifo_priority = None;
        let (dma_guard, dma_latency) = match opts.pacing {
            Pacing::RealTime { priority, cpu } => {
                warnings.extend(make_realtime(priority, cpu));
                fifo_priority = bench_hal::os::fifo_priority();
                let (guard, status) = CpuDmaLatency::try_hold();
                if guard.is_none() {
                    warnings.push(format!(
                        "{} {status}: deep CPU idle states may add wake-up latency",
                        bench_hal::os::CPU_DMA_LATENCY_PATH
                    ));
                }
                (guard, status)
            }
            Pacing::Virtual | Pacing::Paced { .. } => (None, DmaLatency::NotRequested),
        };
        Self {
            stage,
            sup: Supervisor::new(opts.safety),
            period_ns: opts.period_ns,
            period_s: opts.period_ns as f64 * 1e-9,
            timing_interval_ticks: opts.timing_interval_ticks.max(1),
            clock,
            host_paced: matches!(opts.pacing, Pacing::RealTime { .. }) && clock == Clock::Host,
            backpressure: !matches!(opts.pacing, Pacing::RealTime { .. }),
            pace: PaceClock::of(opts.pacing, opts.period_ns),
            fifo_priority,
            next_deadline_ns: now_ns() + opts.period_ns,
            last_good: None,
            hal_error: None,
            link_error: None,
            last_sample_ns: now_ns(),
            warnings,
            published: None,
            total: TickTiming::default(),
            window: TickTiming::default(),
            clock_read_ns: clock_read_cost_ns(),
            _dma_guard: dma_guard,
            dma_latency,
            tap: None,
            link_probe: None,
        }
    }

    /// Counts every tick the loop runs in real time into `tap` from now
    /// on, for the daemon's metrics ([`crate::rt::tap`]); `link_probe`
    /// reads the backend's link counters at each offer. Not on a tick.
    pub fn set_tap(&mut self, tap: LoopTap, link_probe: Option<fn(&S) -> Option<LinkCounters>>) {
        self.tap = Some(tap);
        self.link_probe = link_probe;
    }

    /// Offers the tap's counts now (with the link counters). No
    /// allocation.
    #[inline]
    fn offer_tap(&mut self) {
        if let Some(tap) = self.tap.as_mut() {
            let link = self.link_probe.and_then(|probe| probe(&*self.stage));
            tap.offer(link);
        }
    }

    /// Paces the ticks from now on by `pacing` instead of the loop's own
    /// (the daemon: a job in virtual time, paced or not, on its real-time
    /// loop, and real time again after it). Leaving real time, the thread
    /// leaves SCHED_FIFO (a virtual-time job has no deadline to meet, and
    /// an unpaced one would hold a CPU at real-time priority for its whole
    /// run); back in real time it takes its FIFO priority again (the
    /// daemon was permitted it when it started; were that withdrawn since,
    /// the loop would go on without it, on a simulator daemon, the only
    /// kind that runs jobs in virtual time), and the next deadline is a
    /// period from now. Between jobs, not on a tick; no allocation.
    pub fn set_pacing(&mut self, pacing: Pacing) {
        let realtime = matches!(pacing, Pacing::RealTime { .. });
        self.host_paced = realtime && self.clock == Clock::Host;
        self.backpressure = !realtime;
        self.pace = PaceClock::of(pacing, self.period_ns);
        if let Some(priority) = self.fifo_priority {
            if realtime {
                bench_hal::os::set_fifo_priority(priority);
            } else {
                bench_hal::os::set_normal_scheduling();
            }
        }
        self.next_deadline_ns = now_ns() + self.period_ns;
    }

    /// Whether this loop holds `/dev/cpu_dma_latency` at 0.
    pub fn cpu_dma_latency(&self) -> DmaLatency {
        self.dma_latency
    }

    /// Publishes every good reading into `position_bits` (m) and every
    /// command into `command_bits` (A), as `f64::to_bits`.
    pub fn publish(&mut self, position_bits: &'s AtomicU64, command_bits: &'s AtomicU64) {
        self.published = Some((position_bits, command_bits));
    }

    /// Between jobs, with the amplifier enabled: the hold job's demand
    /// goes through (the supervisor's `running` state), instead of 0 A.
    pub fn drive(&mut self) {
        self.sup.running();
    }

    /// The supervisor.
    pub fn supervisor(&self) -> &Supervisor {
        &self.sup
    }

    /// The stage (between ticks).
    pub fn stage(&mut self) -> &mut S {
        self.stage
    }

    /// Real-time setup warnings.
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// The latest bad-sample or lost-link error and the first HAL error
    /// since the last call, taken (to describe a fault between jobs).
    pub fn take_errors(&mut self) -> (Option<S::Error>, Option<HalFailure<S::Error>>) {
        (self.link_error.take(), self.hal_error.take())
    }

    /// Enables the amplifier at 0 A (between jobs or at a job's start).
    /// Refused (`Err(None)`) while a fault is latched; a HAL failure is the
    /// `hal` fault, with the amplifier disabled again.
    ///
    /// # Errors
    /// `None` when faulted, else the backend's error.
    pub fn enable(&mut self) -> Result<(), Option<S::Error>> {
        if self.sup.state() == SupervisorState::Faulted {
            return Err(None);
        }
        if self.sup.state() != SupervisorState::Disabled {
            return Ok(());
        }
        match self.stage.enable() {
            Ok(()) => {
                self.sup.enabled();
                Ok(())
            }
            Err(e) => {
                self.sup.hal_error(HalCall::Enable, e.kind(), f64::NAN);
                let _ = self.stage.zero_and_disable(0);
                Err(Some(e))
            }
        }
    }

    /// 0 A and amplifier disabled; the supervisor goes back to `disabled`
    /// unless a fault is latched.
    pub fn disable(&mut self) {
        let _ = self.stage.zero_and_disable(0);
        self.sup.disabled();
    }

    /// Clears a latched fault (amplifier disabled, supervisor `disabled`).
    pub fn reset(&mut self) {
        let _ = self.stage.zero_and_disable(0);
        self.sup.reset();
        self.link_error = None;
        self.hal_error = None;
    }

    /// Step 1: waits for the tick's deadline (host-paced); returns it.
    #[inline]
    pub fn wait(&self) -> u64 {
        let deadline = self.next_deadline_ns;
        if self.host_paced {
            sleep_until_ns(deadline);
        }
        deadline
    }

    /// Step 2: reads the sample; a failure goes to the supervisor's HAL
    /// rule (a timed-out read with how long the link has been silent, s).
    #[inline]
    pub fn read(&mut self) -> Read {
        let read = self.stage.read_sample();
        let now = now_ns();
        match read {
            Ok(s) => {
                self.last_sample_ns = now;
                Read::Sample(s)
            }
            Err(e) => match self.sup.hal_error(
                HalCall::ReadSample,
                e.kind(),
                now.saturating_sub(self.last_sample_ns) as f64 * 1e-9,
            ) {
                HalVerdict::SampleMissing { tripped } => {
                    self.link_error = Some(e);
                    Read::Missing { fault: tripped }
                }
                HalVerdict::Fault { kind, tripped } => {
                    if kind == FaultKind::Link {
                        self.link_error = Some(e);
                    } else if self.hal_error.is_none() {
                        self.hal_error = Some((HalCall::ReadSample, e));
                    }
                    Read::Missing { fault: tripped }
                }
            },
        }
    }

    /// Step 3: supervises a sample; `true` if it latched a fault.
    #[inline]
    pub fn supervise_sample(&mut self, sample: &Sample) -> bool {
        let fault = self.sup.check_sample(sample).is_some();
        self.last_good = Some(*sample);
        if let Some((bits, _)) = self.published {
            bits.store(sample.position_m.to_bits(), Ordering::Relaxed);
        }
        fault
    }

    /// Step 4: the job's output, or the last one held on a tick without a
    /// sample (the job does not run then).
    #[inline]
    pub fn job_output<J: Job + ?Sized>(
        job: &mut J,
        tick: u64,
        sample: Option<&Sample>,
        held: JobOutput,
    ) -> JobOutput {
        match sample {
            Some(s) => job.tick(tick, s),
            None => JobOutput {
                done: false,
                ..held
            },
        }
    }

    /// Step 5: supervises and clips the demand, writes it; on a fault
    /// latched in this tick (`fault_before` or here), 0 A and disable now.
    /// Returns the current sent (A) and whether the tick faulted.
    #[inline]
    pub fn command(&mut self, demand_a: f64, answers_seq: u64, fault_before: bool) -> (f64, bool) {
        let (command_a, cmd_fault) = self.sup.command(demand_a);
        let mut fault = fault_before | cmd_fault.is_some();
        if let Err(e) = self.stage.write_command(Command {
            current_a: command_a,
            answers_seq,
        }) {
            if let HalVerdict::Fault { tripped: true, .. } =
                self.sup
                    .hal_error(HalCall::WriteCommand, e.kind(), command_a)
            {
                fault = true;
                if self.hal_error.is_none() {
                    self.hal_error = Some((HalCall::WriteCommand, e));
                }
            }
        }
        if fault {
            let _ = self.stage.zero_and_disable(answers_seq);
        }
        if let Some((_, bits)) = self.published {
            let sent = if fault { 0.0 } else { command_a };
            bits.store(sent.to_bits(), Ordering::Relaxed);
        }
        (command_a, fault)
    }

    /// Step 7: wake-up latency, compute time, overrun (and the overrun
    /// rule; a trip is 0 A and disable now). Returns the deadlines this
    /// tick made the loop miss (0 on time) and whether the overrun rule
    /// latched a fault. Times in ns on `CLOCK_MONOTONIC`.
    #[inline]
    pub fn timing(&mut self, deadline: u64, wake: u64, end: u64, answers_seq: u64) -> (u64, bool) {
        let overran = self.host_paced && end > deadline + self.period_ns;
        let wake_ns = if self.host_paced {
            wake.saturating_sub(deadline)
        } else {
            0
        };
        let compute_ns = end.saturating_sub(wake).saturating_sub(self.clock_read_ns);
        // Paced virtual time records its releases instead (`tick`).
        let paced = self.pace.is_some();
        for t in [&mut self.window, &mut self.total] {
            if !paced {
                t.wake.record(wake_ns);
            }
            t.compute.record(compute_ns);
        }
        // The metrics count real-time ticks only.
        if let (Some(tap), false) = (self.tap.as_mut(), self.backpressure) {
            tap.timed(wake_ns, compute_ns, overran);
        }
        let mut next = deadline + self.period_ns;
        // Deadlines this tick made the loop miss (0 on time).
        let mut missed = 0;
        if overran {
            self.window.overruns += 1;
            self.total.overruns += 1;
            // Skip the deadlines already missed instead of running catch-up
            // ticks back to back.
            missed = (end - deadline) / self.period_ns;
            next += missed * self.period_ns;
        }
        self.next_deadline_ns = next;
        if self.host_paced && self.sup.check_overrun(missed).is_some() {
            let _ = self.stage.zero_and_disable(answers_seq);
            return (missed, true);
        }
        (missed, false)
    }

    /// The job's stall bounds (see [`StallBounds`]); the supervisor's
    /// others stay.
    pub fn set_stall_bounds(&mut self, b: StallBounds) {
        self.sup.set_stall_bounds(b);
    }

    /// One tick of `job` (steps 1–7). `cur` is the job's bookkeeping; `em`
    /// where its records go.
    fn tick<J: Job + ?Sized>(
        &mut self,
        job: &mut J,
        cur: &mut JobCursor,
        em: &mut Emitter<'_>,
    ) -> TickResult {
        // Paced virtual time: the batch's release, and how late it came.
        if let Some(late_ns) = self.pace.as_mut().and_then(|p| p.release(cur.tick)) {
            for t in [&mut self.window, &mut self.total] {
                t.wake.record(late_ns);
            }
        }
        let deadline = self.wait();
        // Virtual time times one tick in VIRTUAL_TIMING_STRIDE.
        let timed = !self.backpressure || cur.tick.is_multiple_of(VIRTUAL_TIMING_STRIDE);
        let mut wake = if timed { now_ns() } else { 0 };
        let read = self.read();
        let device_clocked = matches!(self.clock, Clock::Device { .. });
        if let (Read::Missing { fault: false }, true) = (read, device_clocked) {
            // The device clocks the loop: no sample, no tick. The device
            // holds the last command; the next read waits again.
            em.event(
                cur.tick,
                cur.last_t_s,
                EventKind::SampleMissing,
                &self.sup,
                self.sup.missing_samples() as f64,
            );
            return TickResult::NoTick;
        }
        if device_clocked && timed {
            // Device-clocked, the tick starts when its sample arrives.
            wake = now_ns();
        }
        let (sample, mut fault) = match read {
            Read::Sample(s) => (Some(s), false),
            Read::Missing { fault } => (None, fault),
        };
        let t_s = match (self.clock, sample) {
            (Clock::Host, _) => cur.tick as f64 * self.period_s,
            (Clock::Device { .. }, Some(s)) => s.device_time_ns as f64 * 1e-9 - cur.origin_s,
            // Device time of a held sample: a period after the last.
            (Clock::Device { .. }, None) => cur.last_t_s + self.period_s,
        };
        cur.last_t_s = t_s;
        // Monotonic wake time since the job's first deadline (host-paced)
        // or its first sample (device-clocked: the first wake_s is its
        // t_s); virtual time has no wall clock: wake_s = t_s.
        let origin_ns = *cur.origin_ns.get_or_insert_with(|| {
            if self.host_paced {
                deadline
            } else {
                wake.saturating_sub((t_s.max(0.0) * 1e9) as u64)
            }
        });
        let wake_s = if self.backpressure {
            t_s
        } else {
            wake.saturating_sub(origin_ns) as f64 * 1e-9
        };
        if em.recording_lost() {
            fault |= self.sup.recording_lost(em.dropped).is_some();
        }
        let late_before = self.sup.late_commands();
        match &sample {
            Some(s) => fault |= self.supervise_sample(s),
            None => em.event(
                cur.tick,
                t_s,
                EventKind::SampleMissing,
                &self.sup,
                self.sup.missing_samples() as f64,
            ),
        }
        // A tick without a sample holds the last reading.
        let shown = sample.or(self.last_good);
        let out = if self.last_good.is_some() {
            Self::job_output(job, cur.tick, sample.as_ref(), cur.held)
        } else {
            JobOutput {
                done: false,
                ..cur.held
            }
        };
        cur.held = out;
        let seq = shown.map_or(cur.tick, |s| s.seq);
        let (command_a, tick_fault) = self.command(out.command_a, seq, fault);
        fault = tick_fault;
        // Compute time ends when the command is out; queueing the record
        // comes after (in virtual time it may wait for the writer).
        let end = if timed { now_ns() } else { wake };
        // Timing before the record: a stall that faults this tick shows in
        // its sample (0 A, faulted), as any other fault of the tick does.
        let (missed, timing_fault) = if timed {
            self.timing(deadline, wake, end, seq)
        } else {
            (0, false)
        };
        if let (Some(tap), false) = (self.tap.as_mut(), self.backpressure) {
            let late = sample.is_some_and(|s| s.flags.command_late);
            if tap.ticked(em.records(), late) {
                self.offer_tap();
            }
        }
        if missed > 0 {
            em.event(
                cur.tick,
                t_s,
                EventKind::Stall,
                &self.sup,
                missed as f64 * self.period_s,
            );
        }
        // A run of late commands that ended at this sample.
        if late_before > 0 && self.sup.late_commands() == 0 {
            em.event(
                cur.tick,
                t_s,
                EventKind::Stall,
                &self.sup,
                late_before as f64 * self.period_s,
            );
        }
        em.push(Record::Sample(SampleRecord {
            tick: cur.tick,
            t_s,
            wake_s,
            // What is in force after this tick: 0 A once it faulted (the
            // stop was sent in this tick).
            current_command_a: if fault || timing_fault {
                0.0
            } else {
                command_a
            },
            position_m: sample.map_or(shown.map_or(f64::NAN, |s| s.position_m), |s| s.position_m),
            excitation_a: out.excitation_a,
            setpoint_m: out.setpoint_m,
            state: self.sup.state(),
            out_of_range: shown.is_some_and(|s| s.flags.out_of_range),
        }));
        if fault || timing_fault {
            let value = self.sup.fault().map_or(f64::NAN, |f| f.1);
            em.event(cur.tick, t_s, EventKind::Fault, &self.sup, value);
        }
        cur.window_ticks += 1;
        if cur.window_ticks >= self.timing_interval_ticks {
            if em.records() {
                em.push(timing_record(
                    cur.tick,
                    t_s,
                    cur.window_ticks,
                    &self.window,
                    em.dropped,
                ));
            }
            self.window.reset();
            cur.window_ticks = 0;
        }
        cur.tick += 1;
        TickResult::Ran { done: out.done }
    }

    /// A new job's bookkeeping; resets the timing histograms (no
    /// allocation).
    fn cursor(&mut self) -> JobCursor {
        self.total.reset();
        self.window.reset();
        if let Some(p) = self.pace.as_mut() {
            // Each job's schedule starts at its own first tick.
            p.origin_ns = None;
        }
        JobCursor {
            tick: 0,
            // A job on a running loop counts its time from the last sample.
            origin_s: self
                .last_good
                .map_or(0.0, |s| s.device_time_ns as f64 * 1e-9),
            last_t_s: -self.period_s,
            held: JobOutput::ZERO,
            origin_ns: None,
            window_ticks: 0,
        }
    }

    /// Runs `job` until it finishes, a fault latches, `stop` is raised or
    /// `max_ticks` pass, recording into `out`. Enables the amplifier before
    /// the first tick and always leaves it disabled at 0 A. `progress` is
    /// set to the job's tick count as it goes. A latched fault refuses the
    /// job before anything is enabled. Nothing here allocates.
    pub fn run_job<J: Job + ?Sized>(
        &mut self,
        job: &mut J,
        out: &mut RecordQueue,
        max_ticks: u64,
        stop: &AtomicBool,
        progress: &AtomicU64,
    ) -> JobEnd<S::Error> {
        let room = self.backpressure.then_some(&*out.room);
        let mut em = Emitter::new(&mut out.producer, room);
        let mut cur = self.cursor();
        self.hal_error = None;
        self.link_error = None;
        self.last_sample_ns = now_ns();
        em.event(0, 0.0, EventKind::LoopStarted, &self.sup, f64::NAN);
        let mut stop_reason = match self.enable() {
            Ok(()) => None,
            Err(e) => {
                em.event(0, 0.0, EventKind::Fault, &self.sup, f64::NAN);
                Some(match e {
                    Some(error) => RawStop::Hal {
                        call: HalCall::Enable,
                        error,
                        tick: 0,
                    },
                    None => {
                        let (kind, value) = self.sup.fault().unwrap_or((FaultKind::Hal, f64::NAN));
                        RawStop::Fault {
                            kind,
                            value,
                            tick: 0,
                            link_error: None,
                            stall: None,
                        }
                    }
                })
            }
        };
        if stop_reason.is_none() {
            em.event(0, 0.0, EventKind::StateChanged, &self.sup, f64::NAN);
            self.sup.running();
            em.event(0, 0.0, EventKind::JobStarted, &self.sup, f64::NAN);
        }
        while stop_reason.is_none() {
            if cur.tick >= max_ticks {
                stop_reason = Some(RawStop::TickLimit);
                break;
            }
            let result = self.tick(job, &mut cur, &mut em);
            progress.store(cur.tick, Ordering::Relaxed);
            let last = cur.tick.saturating_sub(1);
            if self.sup.state() == SupervisorState::Faulted {
                stop_reason = Some(self.fault_stop(last));
            } else if result == (TickResult::Ran { done: true }) {
                em.event(
                    last,
                    cur.last_t_s,
                    EventKind::JobFinished,
                    &self.sup,
                    f64::NAN,
                );
                stop_reason = Some(RawStop::Finished);
            } else if stop.load(Ordering::Relaxed) {
                em.event(
                    last,
                    cur.last_t_s,
                    EventKind::Interrupted,
                    &self.sup,
                    f64::NAN,
                );
                stop_reason = Some(RawStop::Interrupted { tick: last });
            }
        }
        // Teardown: always 0 A and disabled.
        self.disable();
        let last = cur.tick.saturating_sub(1);
        let t_end = cur.tick as f64 * self.period_s;
        if matches!(
            stop_reason,
            Some(RawStop::Interrupted { .. } | RawStop::TickLimit)
        ) && cur.tick > 0
        {
            // The stop came after the last tick's command was sent: one
            // more sample shows the 0 A and the state the teardown left.
            let shown = self.last_good;
            em.push(Record::Sample(SampleRecord {
                tick: cur.tick,
                t_s: cur.last_t_s + self.period_s,
                wake_s: f64::NAN,
                current_command_a: 0.0,
                position_m: shown.map_or(f64::NAN, |s| s.position_m),
                excitation_a: f64::NAN,
                setpoint_m: cur.held.setpoint_m,
                state: self.sup.state(),
                out_of_range: shown.is_some_and(|s| s.flags.out_of_range),
            }));
        }
        em.event(last, t_end, EventKind::StateChanged, &self.sup, f64::NAN);
        if cur.window_ticks > 0 {
            em.push(timing_record(
                last,
                t_end,
                cur.window_ticks,
                &self.window,
                em.dropped,
            ));
        }
        em.event(last, t_end, EventKind::LoopStopped, &self.sup, f64::NAN);
        // The job's last ticks reach the metrics now, not 0.1 s later.
        self.offer_tap();
        JobEnd {
            ticks: cur.tick,
            stop: stop_reason.unwrap_or(RawStop::TickLimit),
            timing: self.total.stats(),
            dropped_records: em.dropped,
            final_state: self.sup.state(),
            cpu_dma_latency: self.dma_latency,
        }
    }

    /// The latched fault as a stop reason, with the error that explains it.
    fn fault_stop(&mut self, tick: u64) -> RawStop<S::Error> {
        let (kind, value) = self.sup.fault().unwrap_or((FaultKind::Hal, f64::NAN));
        match (kind, self.hal_error.take()) {
            (FaultKind::Hal, Some((call, error))) => RawStop::Hal { call, error, tick },
            _ => RawStop::Fault {
                kind,
                value,
                tick,
                link_error: if kind == FaultKind::Link {
                    self.link_error.take()
                } else {
                    None
                },
                stall: self.sup.stall_bound(),
            },
        }
    }

    /// Runs `job` as the hold job between jobs ([`crate::rt::HoldJob`]: 0 A; a
    /// controller holds position once [`Loop::drive`] let it), nothing
    /// recorded, until `until` (checked once per tick, after it) returns
    /// `true`. Every rule of the supervisor applies; a fault is 0 A and
    /// disable at its tick, then the hold goes on (the device keeps being
    /// read). Returns `true` if a fault latched during the hold.
    pub fn hold<J: Job + ?Sized>(
        &mut self,
        job: &mut J,
        mut until: impl FnMut(&Self) -> bool,
    ) -> bool {
        let mut em = Emitter::none();
        let mut cur = self.cursor();
        let faulted_before = self.sup.state() == SupervisorState::Faulted;
        loop {
            let r = self.tick(job, &mut cur, &mut em);
            if r == TickResult::NoTick && self.sup.state() == SupervisorState::Faulted {
                // A device that is gone answers at once: do not spin.
                std::thread::sleep(std::time::Duration::from_nanos(self.period_ns));
            }
            if until(self) {
                break;
            }
        }
        !faulted_before && self.sup.state() == SupervisorState::Faulted
    }
}

/// Runs `job` on `stage` in a loop of its own until it finishes, a fault
/// latches, `stop` is raised or `max_ticks` pass. The stage must be
/// configured; `run` enables the amplifier before the first tick and
/// always leaves it disabled at 0 A. `progress` is set to the tick count as
/// the loop goes.
pub fn run<S: Stage, J: Job + ?Sized>(
    stage: &mut S,
    job: &mut J,
    opts: &LoopOptions,
    clock: Clock,
    out: &mut RecordQueue,
    stop: &AtomicBool,
    progress: &AtomicU64,
) -> LoopReport {
    let mut lp = Loop::new(stage, opts, clock);
    let end = lp.run_job(job, out, opts.max_ticks, stop, progress);
    let warnings = std::mem::take(&mut lp.warnings);
    // The loop (and its /dev/cpu_dma_latency request) ends here.
    drop(lp);
    end.into_report(warnings)
}

fn timing_record(tick: u64, t_s: f64, ticks: u64, w: &TickTiming, dropped: u64) -> Record {
    let s = w.stats();
    Record::Timing(TimingRecord {
        tick,
        t_s,
        ticks,
        wake_latency_mean_ns: s.wake.mean_ns,
        wake_latency_p50_ns: s.wake.p50_ns,
        wake_latency_p99_ns: s.wake.p99_ns,
        wake_latency_p999_ns: s.wake.p999_ns,
        wake_latency_max_ns: s.wake.max_ns,
        compute_mean_ns: s.compute.mean_ns,
        compute_p50_ns: s.compute.p50_ns,
        compute_p99_ns: s.compute.p99_ns,
        compute_p999_ns: s.compute.p999_ns,
        compute_max_ns: s.compute.max_ns,
        overruns: w.overruns,
        dropped_records: dropped,
    })
}

#[cfg(test)]
#[path = "tick_tests.rs"]
mod tests;
