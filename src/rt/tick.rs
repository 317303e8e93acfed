//! The real-time loop (README, *Layout*: the HAL lifecycle and who paces the loop).
//!
//! One dedicated OS thread runs [`run`]. Per tick, in this order:
//!
//! 1. wait: real-time mode sleeps until the tick's absolute deadline
//!    (`clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)`); virtual time does
//!    not wait; a device-clocked backend waits inside `read_sample`;
//! 2. read the sample (HAL). A read that brings no usable sample (timeout,
//!    corrupt frames) counts towards the supervisor's link fault (K in a
//!    row); host-clocked, the tick runs on the last reading and command
//!    held, device-clocked, no tick runs until a sample arrives. A lost link
//!    (disconnect, bus-off) is the link fault at once;
//! 3. supervise the sample;
//! 4. run the job (excitation or controller);
//! 5. supervise and clip the command, write it (HAL); on a fault in this
//!    tick: 0 A and disable the amplifier now;
//! 6. push the tick's record to the wait-free SPSC queue (`rtrb`); in
//!    real-time mode a full queue drops the record and counts it, it never
//!    waits; in virtual time (no deadlines) the loop yields until the writer
//!    makes room, so a simulated run never loses a record;
//! 7. measure wake-up latency, compute time and overrun. A tick that ends
//!    more than one period after its deadline is an overrun; the deadlines
//!    it made the loop miss are skipped, not caught up back to back, so one
//!    stall (a VM hiccup, an SMI) costs one overrun and only a loop that
//!    keeps missing its deadlines reaches `max_consecutive_overruns`.
//!
//! Nothing on the tick allocates, locks, logs or does I/O other than the
//! HAL calls (the `alloc` integration test counts allocations to prove it).
//! Setup before the first tick (scheduling, memory locking) and teardown
//! after the last may do all of these.

use crate::record::topics::{
    EventKind, EventRecord, FaultKind, Record, SampleRecord, SupervisorState, TimingRecord,
};
use crate::rt::supervisor::{Supervisor, SupervisorConfig};
use crate::rt::timing::TickTiming;
use bench_hal::device::{monotonic_ns as now_ns, sleep_until_ns};
use bench_hal::{Clock, Command, Error as _, ErrorKind, Sample, Stage};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// What a job produces each tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JobOutput {
    /// Current demand, A (before the supervisor's limits).
    pub command_a: f64,
    /// Excitation part of the demand, A (`NaN` if none).
    pub excitation_a: f64,
    /// Position setpoint, m (`NaN` in open loop).
    pub setpoint_m: f64,
    /// The job is complete after this tick.
    pub done: bool,
}

/// A job driven by the loop: excitation or controller.
pub trait Job {
    /// Computes this tick's output from the sample. Called on the real-time
    /// thread: must not allocate, lock, log or block.
    fn tick(&mut self, tick: u64, sample: &Sample) -> JobOutput;
}

/// How the loop is paced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pacing {
    /// As fast as possible; loop time is `tick × period` (simulator only).
    Virtual,
    /// Absolute deadlines on `CLOCK_MONOTONIC`, with SCHED_FIFO at
    /// `priority`, `mlockall` and optional CPU pinning when permitted.
    RealTime {
        /// SCHED_FIFO priority, 1–99.
        priority: i32,
        /// CPU to pin to.
        cpu: Option<usize>,
    },
}

/// Loop parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopOptions {
    /// Tick period, ns.
    pub period_ns: u64,
    /// Pacing.
    pub pacing: Pacing,
    /// Ticks between `/bench/timing` records.
    pub timing_interval_ticks: u64,
    /// Supervisor limits.
    pub safety: SupervisorConfig,
    /// Hard cap on ticks (the job normally ends first).
    pub max_ticks: u64,
}

/// Why the loop stopped.
#[derive(Debug, Clone, PartialEq)]
pub enum StopReason {
    /// The job finished.
    Finished,
    /// The supervisor latched a fault at `tick`; `value` caused it.
    Fault {
        /// Which fault.
        kind: FaultKind,
        /// The offending value (position in m, command in A, overrun count).
        value: f64,
        /// Tick of the fault.
        tick: u64,
        /// What the backend said, for link faults.
        detail: Option<String>,
    },
    /// A HAL call failed (the supervisor faulted with [`FaultKind::Hal`]).
    Hal {
        /// The backend's message.
        message: String,
        /// Tick of the failure.
        tick: u64,
    },
    /// The stop flag was raised (SIGINT/SIGTERM).
    Interrupted {
        /// Tick at which the loop stopped.
        tick: u64,
    },
    /// `max_ticks` reached before the job finished.
    TickLimit,
}

/// What the loop reports when it ends.
#[derive(Debug, Clone)]
pub struct LoopReport {
    /// Ticks run.
    pub ticks: u64,
    /// Why it stopped.
    pub stop: StopReason,
    /// Timing over the whole run.
    pub timing: TickTiming,
    /// Records dropped because the queue was full.
    pub dropped_records: u64,
    /// Real-time setup problems (not permitted, etc.), one line each.
    pub warnings: Vec<String>,
    /// Final supervisor state.
    pub final_state: SupervisorState,
}

/// Applies SCHED_FIFO, `mlockall` and CPU pinning to the calling thread.
/// Returns one warning line per thing that was not permitted.
pub fn make_realtime(priority: i32, cpu: Option<usize>) -> Vec<String> {
    let mut warnings = Vec::new();
    // SAFETY: plain libc calls on the current thread with valid arguments.
    unsafe {
        if libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) != 0 {
            warnings.push(format!(
                "mlockall failed ({}): page faults may add latency",
                std::io::Error::last_os_error()
            ));
        }
        let param = libc::sched_param {
            sched_priority: priority,
        };
        let r = libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param);
        if r != 0 {
            warnings.push(format!(
                "SCHED_FIFO priority {priority} not permitted ({}): running with normal scheduling, expect jitter",
                std::io::Error::from_raw_os_error(r)
            ));
        }
        if let Some(cpu) = cpu {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_SET(cpu, &mut set);
            if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) != 0 {
                warnings.push(format!(
                    "pinning to CPU {cpu} failed ({})",
                    std::io::Error::last_os_error()
                ));
            }
        }
    }
    warnings
}

struct Emitter<'a> {
    out: &'a mut rtrb::Producer<Record>,
    dropped: u64,
    /// Virtual time: wait for queue space instead of dropping.
    backpressure: bool,
}

impl Emitter<'_> {
    #[inline]
    fn push(&mut self, r: Record) {
        let mut r = r;
        loop {
            match self.out.push(r) {
                Ok(()) => return,
                Err(rtrb::PushError::Full(back)) => {
                    if !self.backpressure || self.out.is_abandoned() {
                        self.dropped += 1;
                        return;
                    }
                    r = back;
                    std::thread::yield_now();
                }
            }
        }
    }

    fn event(&mut self, tick: u64, t_s: f64, kind: EventKind, sup: &Supervisor, value: f64) {
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

/// Runs `job` on `stage` until it finishes, a fault latches, `stop` is
/// raised or `max_ticks` pass. The stage must be configured; `run` enables
/// the amplifier before the first tick and always leaves it disabled at
/// 0 A. `progress` is set to the tick count as the loop goes.
pub fn run<S: Stage, J: Job>(
    stage: &mut S,
    job: &mut J,
    opts: &LoopOptions,
    clock: Clock,
    out: &mut rtrb::Producer<Record>,
    stop: &AtomicBool,
    progress: &AtomicU64,
) -> LoopReport {
    let mut warnings = Vec::new();
    if let Pacing::RealTime { priority, cpu } = opts.pacing {
        warnings.extend(make_realtime(priority, cpu));
    }
    let mut sup = Supervisor::new(opts.safety);
    let mut em = Emitter {
        out,
        dropped: 0,
        backpressure: opts.pacing == Pacing::Virtual,
    };
    let period_s = opts.period_ns as f64 * 1e-9;
    let mut total = TickTiming::default();
    let mut window = TickTiming::default();
    let mut window_ticks = 0u64;

    em.event(0, 0.0, EventKind::LoopStarted, &sup, f64::NAN);
    if let Err(e) = stage.enable() {
        let _ = stage.disable();
        sup.trip(FaultKind::Hal, f64::NAN);
        em.event(0, 0.0, EventKind::Fault, &sup, f64::NAN);
        return LoopReport {
            ticks: 0,
            stop: StopReason::Hal {
                message: format!("enable failed: {e}"),
                tick: 0,
            },
            timing: total,
            dropped_records: em.dropped,
            warnings,
            final_state: sup.state(),
        };
    }
    sup.enabled();
    em.event(0, 0.0, EventKind::StateChanged, &sup, f64::NAN);
    sup.running();
    em.event(0, 0.0, EventKind::JobStarted, &sup, f64::NAN);

    let host_paced = matches!(opts.pacing, Pacing::RealTime { .. }) && clock == Clock::Host;
    // Deadlines are start + tick × period, shifted by the periods skipped
    // after a stall (see below).
    let mut start_ns = now_ns() + opts.period_ns;
    let mut stop_reason = StopReason::TickLimit;
    let mut tick = 0u64;
    // The first HAL error, kept as-is (formatting would allocate on the
    // tick); it becomes a message after the loop.
    let mut hal_error: Option<(&'static str, S::Error)> = None;
    // The latest bad-sample or lost-link error (for the link fault's
    // message).
    let mut link_error: Option<S::Error> = None;
    let mut last_good: Option<Sample> = None;
    let mut last_t_s = -period_s;
    let mut last_command_a = 0.0;
    let mut last_excitation_a = f64::NAN;
    let mut last_setpoint_m = f64::NAN;
    while tick < opts.max_ticks {
        let deadline = start_ns + tick * opts.period_ns;
        if host_paced {
            sleep_until_ns(deadline);
        }
        let mut wake = now_ns();

        let mut fault_now = false;
        // A read without a usable sample (timeout, corrupt frames) counts
        // towards the link fault. Host-clocked, the tick still runs and
        // holds the last reading and command; device-clocked, there is no
        // tick until a sample comes. A lost link faults at once; any other
        // HAL error is a HAL fault.
        let mut missing = false;
        let sample = match stage.read_sample() {
            Ok(s) => s,
            Err(e) => {
                match e.kind() {
                    ErrorKind::Timeout | ErrorKind::Crc => {
                        let tripped = sup.sample_missing().is_some();
                        link_error = Some(e);
                        if !tripped && matches!(clock, Clock::Device { .. }) {
                            // The device clocks the loop: no sample, no
                            // tick. The device holds the last command; the
                            // next read waits again.
                            em.event(
                                tick,
                                last_t_s,
                                EventKind::SampleMissing,
                                &sup,
                                sup.missing_samples() as f64,
                            );
                            if stop.load(Ordering::Relaxed) {
                                em.event(tick, last_t_s, EventKind::Interrupted, &sup, f64::NAN);
                                stop_reason = StopReason::Interrupted {
                                    tick: tick.saturating_sub(1),
                                };
                                break;
                            }
                            continue;
                        }
                        missing = true;
                        fault_now |= tripped;
                    }
                    ErrorKind::Link => {
                        fault_now |= sup.link_lost();
                        link_error = Some(e);
                    }
                    _ => {
                        if hal_error.is_none() {
                            hal_error = Some(("read_sample", e));
                        }
                        fault_now |= sup.trip(FaultKind::Hal, f64::NAN);
                    }
                }
                Sample {
                    seq: last_good.map_or(tick, |s| s.seq),
                    device_time_ns: last_good.map_or(0, |s| s.device_time_ns),
                    position_m: last_good.map_or(f64::NAN, |s| s.position_m),
                    measured_current_a: f64::NAN,
                    flags: last_good.map_or(Default::default(), |s| s.flags),
                }
            }
        };
        if let Clock::Device { .. } = clock {
            // Device-clocked, the tick starts when its sample arrives.
            wake = now_ns();
        }
        let t_s = match clock {
            Clock::Host => tick as f64 * period_s,
            // Device time of the sample; a held one is a period later.
            Clock::Device { .. } if missing => last_t_s + period_s,
            Clock::Device { .. } => sample.device_time_ns as f64 * 1e-9,
        };
        last_t_s = t_s;
        if missing {
            em.event(
                tick,
                t_s,
                EventKind::SampleMissing,
                &sup,
                sup.missing_samples() as f64,
            );
        } else {
            fault_now |= sup.check_sample(&sample).is_some();
            last_good = Some(sample);
        }
        let job_out = if missing || last_good.is_none() {
            // Hold: the job does not run on a tick without a sample.
            JobOutput {
                command_a: last_command_a,
                excitation_a: last_excitation_a,
                setpoint_m: last_setpoint_m,
                done: false,
            }
        } else {
            job.tick(tick, &sample)
        };
        last_excitation_a = job_out.excitation_a;
        last_setpoint_m = job_out.setpoint_m;
        let (command_a, cmd_fault) = sup.command(job_out.command_a);
        fault_now |= cmd_fault.is_some();
        last_command_a = job_out.command_a;
        if let Err(e) = stage.write_command(Command {
            current_a: command_a,
            answers_seq: sample.seq,
        }) {
            if hal_error.is_none() {
                hal_error = Some(("write_command", e));
            }
            fault_now |= sup.trip(FaultKind::Hal, command_a);
        }
        if fault_now {
            // Same tick: 0 A and amplifier off.
            let _ = stage.write_command(Command {
                current_a: 0.0,
                answers_seq: sample.seq,
            });
            let _ = stage.disable();
        }
        // Compute time ends when the command is out; queueing the record
        // comes after (in virtual time it may wait for the writer).
        let end = now_ns();

        em.push(Record::Sample(SampleRecord {
            tick,
            t_s,
            current_command_a: command_a,
            position_m: sample.position_m,
            excitation_a: job_out.excitation_a,
            setpoint_m: job_out.setpoint_m,
            state: sup.state(),
            out_of_range: sample.flags.out_of_range,
        }));
        if fault_now {
            let value = sup.fault().map(|f| f.1).unwrap_or(f64::NAN);
            em.event(tick, t_s, EventKind::Fault, &sup, value);
        }

        let overran = host_paced && end > deadline + opts.period_ns;
        if host_paced {
            window.wake.record(wake as f64 - deadline as f64);
        } else {
            window.wake.record(0.0);
        }
        window.compute.record(end as f64 - wake as f64);
        if overran {
            window.overruns += 1;
            // A stall longer than a period: skip the deadlines already
            // missed instead of running catch-up ticks back to back (their
            // samples would not be a period apart). One stall is one
            // overrun; only a loop that keeps missing faults.
            let missed = (end - deadline) / opts.period_ns;
            start_ns += missed * opts.period_ns;
        }
        if host_paced && sup.check_overrun(overran).is_some() {
            let _ = stage.write_command(Command {
                current_a: 0.0,
                answers_seq: sample.seq,
            });
            let _ = stage.disable();
            em.event(
                tick,
                t_s,
                EventKind::Fault,
                &sup,
                sup.fault().map(|f| f.1).unwrap_or(f64::NAN),
            );
        }
        window_ticks += 1;
        if window_ticks >= opts.timing_interval_ticks {
            em.push(timing_record(tick, t_s, window_ticks, &window, em.dropped));
            total.merge(&window);
            window = TickTiming::default();
            window_ticks = 0;
        }

        tick += 1;
        progress.store(tick, Ordering::Relaxed);
        if sup.state() == SupervisorState::Faulted {
            let (kind, value) = sup.fault().unwrap_or((FaultKind::Hal, f64::NAN));
            stop_reason = match (hal_error.take(), link_error.take()) {
                (Some((call, e)), _) if kind == FaultKind::Hal => StopReason::Hal {
                    message: format!("{call}: {e}"),
                    tick: tick - 1,
                },
                (_, Some(e)) if kind == FaultKind::Link => StopReason::Fault {
                    kind,
                    value,
                    tick: tick - 1,
                    detail: Some(if value.is_nan() {
                        format!("link lost: {e}")
                    } else {
                        format!("{value} consecutive samples missing or corrupt (last: {e})")
                    }),
                },
                (_, None) if kind == FaultKind::Link => StopReason::Fault {
                    kind,
                    value,
                    tick: tick - 1,
                    detail: Some(format!(
                        "{value} consecutive samples missing (sequence gap)"
                    )),
                },
                _ => StopReason::Fault {
                    kind,
                    value,
                    tick: tick - 1,
                    detail: None,
                },
            };
            break;
        }
        if job_out.done {
            em.event(tick - 1, t_s, EventKind::JobFinished, &sup, f64::NAN);
            stop_reason = StopReason::Finished;
            break;
        }
        if stop.load(Ordering::Relaxed) {
            em.event(tick - 1, t_s, EventKind::Interrupted, &sup, f64::NAN);
            stop_reason = StopReason::Interrupted { tick: tick - 1 };
            break;
        }
    }
    // Teardown: always 0 A and disabled.
    let _ = stage.write_command(Command {
        current_a: 0.0,
        answers_seq: 0,
    });
    let _ = stage.disable();
    sup.disabled();
    let t_end = tick as f64 * period_s;
    em.event(
        tick.saturating_sub(1),
        t_end,
        EventKind::StateChanged,
        &sup,
        f64::NAN,
    );
    if window_ticks > 0 {
        em.push(timing_record(
            tick.saturating_sub(1),
            t_end,
            window_ticks,
            &window,
            em.dropped,
        ));
        total.merge(&window);
    }
    em.event(
        tick.saturating_sub(1),
        t_end,
        EventKind::LoopStopped,
        &sup,
        f64::NAN,
    );
    LoopReport {
        ticks: tick,
        stop: stop_reason,
        timing: total,
        dropped_records: em.dropped,
        warnings,
        final_state: sup.state(),
    }
}

fn timing_record(tick: u64, t_s: f64, ticks: u64, w: &TickTiming, dropped: u64) -> Record {
    Record::Timing(TimingRecord {
        tick,
        t_s,
        ticks,
        wake_latency_mean_ns: w.wake.mean_ns(),
        wake_latency_p99_ns: w.wake.quantile_ns(0.99),
        wake_latency_max_ns: w.wake.max_ns(),
        compute_mean_ns: w.compute.mean_ns(),
        compute_p99_ns: w.compute.quantile_ns(0.99),
        compute_max_ns: w.compute.max_ns(),
        overruns: w.overruns,
        dropped_records: dropped,
    })
}
