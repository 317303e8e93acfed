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

mod run;
pub use run::*;

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
}

#[cfg(test)]
mod tests;
