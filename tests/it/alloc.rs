//! The real-time tick allocates nothing once running (copper-rs style
//! counting allocator): a chirp's (virtual time, paced virtual time, real
//! time), a multisine's, a closed loop's, the daemon's hold and its switch
//! to a paced job and back. Counts only on the loop's own thread, from the
//! 100th tick on, across everything the tick does: HAL read (simulator
//! step, noise), supervisor, job, HAL write, queue push, timing.

use bench::config::BenchConfig;
use bench::ident::chirp::Chirp;
use bench::jobs::chirp::ChirpJob;
use bench::rt::{self, Job, JobOutput, LoopOptions, Pacing, StopReason};
use bench_hal::{Sample, Stage};
use bench_plant::sim::SimStage;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64};

struct Counting;

thread_local! {
    /// Counting switched on for this thread.
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    /// Allocations made by this thread while counting (per thread, so
    /// tests running in parallel do not see each other's).
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

fn count_one() {
    // `try_with`: thread-locals may be gone during thread teardown.
    let _ = COUNTING.try_with(|c| {
        if c.get() {
            let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        }
    });
}

/// Stops counting on this thread and returns the count.
fn stop_counting() -> u64 {
    COUNTING.with(|c| c.set(false));
    ALLOCATIONS.with(|n| n.get())
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count_one();
        System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count_one();
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Wraps a job and switches counting on at `from_tick` on the loop thread.
struct Counted<J> {
    inner: J,
    from_tick: u64,
}

impl<J: Job> Job for Counted<J> {
    fn tick(&mut self, tick: u64, sample: &Sample) -> JobOutput {
        if tick == self.from_tick {
            COUNTING.with(|c| c.set(true));
        }
        self.inner.tick(tick, sample)
    }
}

/// Runs `job` on `stage` in a fresh loop thread, counting that thread's
/// allocations from tick 100 on, with the queue drained on another thread
/// (which may allocate: it is not counted). Returns the report, the
/// allocations and the records drained.
fn run_counted_job<S: Stage + Send + 'static, J: Job + Send + 'static>(
    mut stage: S,
    job: J,
    opts: LoopOptions,
    clock: bench_hal::Clock,
) -> (rt::LoopReport, u64, u64) {
    let (mut producer, mut consumer) = rt::RecordQueue::new(1 << 16);
    let room = std::sync::Arc::clone(&producer.room);
    let drain = std::thread::spawn(move || {
        let mut n = 0u64;
        while !consumer.is_abandoned() || !consumer.is_empty() {
            while consumer.pop().is_ok() {
                n += 1;
            }
            // Wakes a virtual-time loop parked on the full queue.
            room.made_room(0, 1 << 16);
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        n
    });
    let (report, allocations) = std::thread::spawn(move || {
        let mut job = Counted {
            inner: job,
            from_tick: 100,
        };
        let mut lp = rt::Loop::new(&mut stage, &opts, clock);
        let end = lp.run_job(
            &mut job,
            &mut producer,
            opts.max_ticks,
            &AtomicBool::new(false),
            &AtomicU64::new(0),
        );
        // Counted up to here: every tick, the faulting one and the
        // teardown. Formatting the report (after the loop) may allocate.
        let allocations = stop_counting();
        (end.into_report(Vec::new()), allocations)
    })
    .join()
    .unwrap();
    (report, allocations, drain.join().unwrap())
}

fn ch5() -> BenchConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    BenchConfig::load(&path).unwrap()
}

/// A 0.8 s chirp (0.5 s sweep) on the simulator with real-time loop
/// options (no overrun fault: a test host may stall), for the tests of the
/// daemon's loop: the configured stage, its device info, the
/// chirp and the loop options.
fn short_real_time_chirp() -> (SimStage, bench_hal::DeviceInfo, Chirp, LoopOptions) {
    let mut cfg = ch5();
    cfg.chirp.duration_s = Some(0.5);
    cfg.chirp.taper_s = Some(0.1);
    cfg.chirp.lead_in_s = 0.1;
    cfg.chirp.tail_s = 0.1;
    cfg.validate(Path::new("ch5")).unwrap();
    let mut stage = SimStage::new(cfg.sim_params(7)).unwrap();
    let info = stage.configure(cfg.loop_.period_ns()).unwrap();
    let chirp = Chirp::new(
        &cfg.chirp,
        cfg.excitation.kind,
        info.period_ns as f64 * 1e-9,
    );
    let opts = LoopOptions {
        period_ns: info.period_ns,
        pacing: Pacing::RealTime {
            priority: 10,
            cpu: None,
        },
        timing_interval_ticks: 500,
        safety: bench::rt::supervisor::SupervisorConfig {
            max_missed_deadlines: u64::MAX,
            ..cfg.supervisor(&info)
        },
        max_ticks: chirp.total_ticks(),
    };
    (stage, info, chirp, opts)
}

fn run_counted(pacing: Pacing, seconds: f64) -> (u64, u64) {
    let mut cfg = ch5();
    cfg.chirp.duration_s = Some(seconds);
    cfg.chirp.taper_s = Some(0.1);
    cfg.chirp.f_start_hz = 5.0;
    cfg.validate(Path::new("ch5")).unwrap();
    let mut stage = SimStage::new(cfg.sim_params(7)).unwrap();
    let info = stage.configure(cfg.loop_.period_ns()).unwrap();
    let chirp = Chirp::new(
        &cfg.chirp,
        cfg.excitation.kind,
        info.period_ns as f64 * 1e-9,
    );
    let opts = LoopOptions {
        period_ns: info.period_ns,
        pacing,
        timing_interval_ticks: 500,
        safety: bench::rt::supervisor::SupervisorConfig {
            max_missed_deadlines: u64::MAX,
            ..cfg.supervisor(&info)
        },
        max_ticks: chirp.total_ticks(),
    };
    let (report, allocations, records) =
        run_counted_job(stage, ChirpJob::new(chirp), opts, info.clock);
    assert_eq!(report.stop, StopReason::Finished);
    assert!(records >= report.ticks);
    (allocations, report.ticks)
}

#[test]
fn tick_allocates_nothing() {
    let (allocs, ticks) = run_counted(Pacing::Virtual, 4.0);
    assert!(ticks > 20_000);
    assert_eq!(
        allocs, 0,
        "{allocs} allocations in {ticks} virtual-time ticks"
    );
    let (allocs, ticks) = run_counted(
        Pacing::RealTime {
            priority: 10,
            cpu: None,
        },
        0.5,
    );
    assert!(ticks > 2_000);
    assert_eq!(allocs, 0, "{allocs} allocations in {ticks} real-time ticks");
    // Paced virtual time: its releases and sleeps (20× real time, 1 ms
    // batches of 100 ticks).
    let (allocs, ticks) = run_counted(Pacing::Paced { factor: 20.0 }, 1.0);
    assert!(ticks > 5_000);
    assert_eq!(allocs, 0, "{allocs} allocations in {ticks} paced ticks");
}

/// The daemon's loop runs a paced job on its real-time loop and goes back
/// to real time for the hold ([`rt::Loop::set_pacing`], between jobs on
/// the loop's thread): the switches, the paced job's ticks and the hold
/// after it allocate nothing.
#[test]
fn a_paced_job_on_a_real_time_loop_and_back_allocate_nothing() {
    let (mut stage, info, chirp, opts) = short_real_time_chirp();
    let (mut producer, mut consumer) = rt::RecordQueue::new(1 << 16);
    let room = std::sync::Arc::clone(&producer.room);
    let drain = std::thread::spawn(move || {
        while !consumer.is_abandoned() || !consumer.is_empty() {
            while consumer.pop().is_ok() {}
            room.made_room(0, 1 << 16);
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
    });
    let (end, allocations) = std::thread::spawn(move || {
        let mut lp = rt::Loop::new(&mut stage, &opts, info.clock);
        let mut job = ChirpJob::new(chirp);
        COUNTING.with(|c| c.set(true));
        lp.set_pacing(Pacing::Paced { factor: 10.0 });
        let end = lp.run_job(
            &mut job,
            &mut producer,
            opts.max_ticks,
            &AtomicBool::new(false),
            &AtomicU64::new(0),
        );
        lp.set_pacing(opts.pacing);
        let mut n = 0u64;
        lp.hold(&mut rt::HoldJob, |_| {
            n += 1;
            n >= 1_000
        });
        let allocations = stop_counting();
        (end.into_report(Vec::new()), allocations)
    })
    .join()
    .unwrap();
    drain.join().unwrap();
    assert_eq!(end.stop, StopReason::Finished);
    assert!(end.ticks > 3_000 && end.timing.wake.count > 0);
    assert_eq!(allocations, 0, "{allocations} allocations");
}

/// The same with a multisine (`excitation.kind = "multisine"`, random phases):
/// the table is built before the loop, the tick reads it; counted from
/// tick 100 through the lead-in's end, every realization's periods
/// (transient and measured) and the tail.
#[test]
fn multisine_tick_allocates_nothing() {
    use bench::config::{ExcitationKind, MultisineConfig};
    use bench::ident::excitation::Excitation;
    let mut cfg = ch5();
    cfg.excitation.kind = ExcitationKind::Multisine;
    cfg.chirp.duration_s = None;
    cfg.chirp.taper_s = None;
    cfg.chirp.f_start_hz = 5.0;
    cfg.chirp.lead_in_s = 0.1;
    cfg.chirp.tail_s = 0.1;
    cfg.multisine = Some(MultisineConfig {
        period_s: Some(0.2),
        periods: 2,
        realizations: 4,
        transient_periods: 1,
        ..Default::default()
    });
    cfg.validate(Path::new("ch5-multisine")).unwrap();
    let mut stage = SimStage::new(cfg.sim_params(7)).unwrap();
    let info = stage.configure(cfg.loop_.period_ns()).unwrap();
    let excitation = Excitation::new(&cfg, info.period_ns as f64 * 1e-9, 7).unwrap();
    assert!(matches!(excitation, Excitation::Multisine(_)));
    let total = excitation.total_ticks();
    assert_eq!(total, 500 + 4 * 3 * 1000 + 500);
    let opts = LoopOptions {
        period_ns: info.period_ns,
        pacing: Pacing::Virtual,
        timing_interval_ticks: 500,
        safety: cfg.supervisor(&info),
        max_ticks: total,
    };
    let (report, allocations, records) =
        run_counted_job(stage, ChirpJob::new(excitation), opts, info.clock);
    assert_eq!(report.stop, StopReason::Finished);
    assert!(records >= report.ticks);
    assert_eq!(report.ticks, total);
    assert_eq!(
        allocations, 0,
        "{allocations} allocations in {} multisine ticks",
        report.ticks
    );
}

/// The same with the fast controller (Eq. 6-7) and the supervisor closing
/// the loop, disturbance on.
#[test]
fn closed_loop_tick_allocates_nothing() {
    use bench::control::DiscreteController;
    use bench::jobs::control::ControlJob;
    let cfg = ch5();
    assert!(cfg.plant.disturbance.is_some());
    let mut stage = SimStage::new(cfg.sim_params(7)).unwrap();
    let info = stage.configure(cfg.loop_.period_ns()).unwrap();
    let period_s = info.period_ns as f64 * 1e-9;
    let ctrl = DiscreteController::new(&cfg.controller["fast"], period_s, info.peak_current_a);
    let total = 20_000;
    let opts = LoopOptions {
        period_ns: info.period_ns,
        pacing: Pacing::Virtual,
        timing_interval_ticks: 500,
        safety: cfg.supervisor(&info),
        max_ticks: total,
    };
    let job = ControlJob::new(ctrl, 1e-5, 1000, 0, total);
    let (report, allocations, records) = run_counted_job(stage, job, opts, info.clock);
    assert!(records >= total);
    assert_eq!(report.stop, StopReason::Finished);
    assert_eq!(
        allocations, 0,
        "{allocations} allocations in {} closed-loop ticks",
        report.ticks
    );
}

/// `bench track`'s job: the controller on the scan's reference table
/// plus the feedforward table, faded in and then played period after
/// period, counted from tick 100 on.
#[test]
fn track_tick_allocates_nothing() {
    use bench::control::DiscreteController;
    use bench::track::{Scan, ScanKind, TrackJob};
    let cfg = ch5();
    let mut stage = SimStage::new(cfg.sim_params(7)).unwrap();
    let info = stage.configure(cfg.loop_.period_ns()).unwrap();
    let period_s = info.period_ns as f64 * 1e-9;
    let ctrl = DiscreteController::new(&cfg.controller["fast"], period_s, info.peak_current_a);
    let n = (0.1 / period_s).round() as usize;
    let scan = Scan {
        kind: ScanKind::Triangle,
        move_limits: None,
        amplitude_m: 5e-6,
        line_rate_hz: 10.0,
        cutoff_hz: 55.0,
        reference_csv: None,
        reference: None,
    };
    let reference = scan.harmonics(n).synthesize();
    let feedforward: Vec<f64> = reference.iter().map(|r| r * 1e3).collect();
    let job = TrackJob::new(ctrl, reference, feedforward, 8);
    let total = job.total_ticks();
    let opts = LoopOptions {
        period_ns: info.period_ns,
        pacing: Pacing::Virtual,
        timing_interval_ticks: 500,
        safety: cfg.supervisor(&info),
        max_ticks: total,
    };
    let (report, allocations, records) = run_counted_job(stage, job, opts, info.clock);
    assert!(records >= total);
    assert_eq!(report.stop, StopReason::Finished);
    assert_eq!(
        allocations, 0,
        "{allocations} allocations in {} tracking ticks",
        report.ticks
    );
}

/// The same with `bench control --verify`'s injection: the step, then
/// the chirp added to the controller's command at the plant input (its
/// lead-in, sweep and tail), counted from tick 100 to the end.
#[test]
fn closed_loop_verify_tick_allocates_nothing() {
    use bench::control::verify::chirp_config;
    use bench::control::DiscreteController;
    use bench::jobs::control::ControlJob;
    let cfg = ch5();
    let mut stage = SimStage::new(cfg.sim_params(7)).unwrap();
    let info = stage.configure(cfg.loop_.period_ns()).unwrap();
    let period_s = info.period_ns as f64 * 1e-9;
    let ctrl = DiscreteController::new(&cfg.controller["fast"], period_s, info.peak_current_a);
    let mut chirp_cfg = chirp_config(&cfg.chirp, 0.05, 2.0);
    chirp_cfg.f_start_hz = 5.0;
    chirp_cfg.tail_s = 0.5;
    let chirp = Chirp::new(&chirp_cfg, cfg.excitation.kind, period_s);
    let job = ControlJob::new(ctrl, 1e-5, 1000, 0, 5_000).with_verify(chirp);
    let total = job.total_ticks();
    assert_eq!(total, 5_000 + chirp.total_ticks());
    let opts = LoopOptions {
        period_ns: info.period_ns,
        pacing: Pacing::Virtual,
        timing_interval_ticks: 500,
        safety: cfg.supervisor(&info),
        max_ticks: total,
    };
    let (report, allocations, records) = run_counted_job(stage, job, opts, info.clock);
    assert_eq!(report.stop, StopReason::Finished);
    assert!(records >= total);
    assert_eq!(
        allocations, 0,
        "{allocations} allocations in {} closed-loop ticks with the injection",
        report.ticks
    );
}

/// The same over the serial backend (protocol encode/decode, pty I/O),
/// against the emulator in lockstep on another thread (not counted).
#[test]
fn serial_tick_allocates_nothing() {
    use bench::control::DiscreteController;
    use bench::jobs::control::ControlJob;
    use bench_devices::emulator::serial::{self as serial_emulator, Pty, SerialEmulatorOptions};
    use bench_devices::emulator::{DeviceCore, EmulatorStatus};
    use bench_hal::serial::{SerialConfig, SerialStage};
    use std::sync::Arc;
    let cfg = ch5();
    let period_ns = cfg.loop_.period_ns();
    let core = DeviceCore::new(cfg.sim_params(7), period_ns, 1_000_000_000).unwrap();
    let pty = Pty::open().unwrap();
    let path = pty.path().to_string();
    let stop = Arc::new(AtomicBool::new(false));
    let status = Arc::new(EmulatorStatus::default());
    let (s, st) = (Arc::clone(&stop), Arc::clone(&status));
    let emu = std::thread::spawn(move || {
        let opts = SerialEmulatorOptions {
            lockstep: true,
            ..Default::default()
        };
        serial_emulator::run(pty, core, &opts, &s, &st)
    });
    let mut stage = SerialStage::open(&SerialConfig {
        path,
        sample_timeout_periods: 1000.0,
        ..Default::default()
    })
    .unwrap();
    let info = stage.configure(period_ns).unwrap();
    let period_s = info.period_ns as f64 * 1e-9;
    let ctrl = DiscreteController::new(&cfg.controller["fast"], period_s, info.peak_current_a);
    let total = 4_000;
    let opts = LoopOptions {
        period_ns: info.period_ns,
        pacing: Pacing::RealTime {
            priority: 10,
            cpu: None,
        },
        timing_interval_ticks: 500,
        safety: bench::rt::supervisor::SupervisorConfig {
            max_missed_samples: 1000,
            ..cfg.supervisor(&info)
        },
        max_ticks: total,
    };
    let job = ControlJob::new(ctrl, 1e-5, 1000, 0, total);
    let (report, allocations, _) = run_counted_job(stage, job, opts, info.clock);
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    emu.join().unwrap().unwrap();
    assert_eq!(report.stop, StopReason::Finished, "{:?}", report.stop);
    assert_eq!(
        allocations, 0,
        "{allocations} allocations in {} serial ticks",
        report.ticks
    );
}

/// A faulting tick allocates nothing either: for every simulator fault,
/// the tick that latches it (0 A, disable), the fault event and the
/// teardown are counted.
#[test]
fn faulting_tick_allocates_nothing() {
    use bench::record::topics::FaultKind;
    use bench_plant::sim::{FaultInjection, ScheduledFault};
    let cfg = ch5();
    for (kind, expect) in [
        (FaultInjection::Nan, FaultKind::ProbeNotFinite),
        (FaultInjection::Frozen, FaultKind::StaleSample),
        (FaultInjection::Drop(10), FaultKind::Link),
        (FaultInjection::Jump(2e-4), FaultKind::PositionJump),
        (FaultInjection::OutOfRange, FaultKind::ProbeOutOfRange),
    ] {
        let mut stage = SimStage::new(cfg.sim_params(7)).unwrap();
        let info = stage.configure(cfg.loop_.period_ns()).unwrap();
        stage.inject(ScheduledFault { at_s: 0.2, kind });
        let period_s = info.period_ns as f64 * 1e-9;
        let chirp = Chirp::new(&cfg.chirp, cfg.excitation.kind, period_s);
        let opts = LoopOptions {
            period_ns: info.period_ns,
            pacing: Pacing::Virtual,
            timing_interval_ticks: 500,
            safety: cfg.supervisor(&info),
            max_ticks: chirp.total_ticks(),
        };
        let (report, allocations, _) =
            run_counted_job(stage, ChirpJob::new(chirp), opts, info.clock);
        match report.stop {
            StopReason::Fault { kind: k, tick, .. } => {
                assert_eq!(k, expect, "{kind:?}");
                assert!(
                    tick > 100,
                    "{kind:?} faulted at tick {tick}, before counting"
                );
            }
            other => panic!("{kind:?}: {other:?}"),
        }
        assert_eq!(allocations, 0, "{kind:?}: {allocations} allocations");
    }
}

/// The daemon's hold between jobs allocates nothing, including a fault
/// that latches during the hold.
#[test]
fn hold_and_a_fault_between_jobs_allocate_nothing() {
    use bench::record::topics::{FaultKind, SupervisorState};
    use bench_plant::sim::{FaultInjection, ScheduledFault};
    let cfg = ch5();
    let mut stage = SimStage::new(cfg.sim_params(7)).unwrap();
    let info = stage.configure(cfg.loop_.period_ns()).unwrap();
    stage.inject(ScheduledFault {
        at_s: 0.2,
        kind: FaultInjection::Nan,
    });
    let opts = LoopOptions {
        period_ns: info.period_ns,
        pacing: Pacing::Virtual,
        timing_interval_ticks: 500,
        safety: cfg.supervisor(&info),
        max_ticks: u64::MAX,
    };
    let (fault, allocations) = std::thread::spawn(move || {
        let mut lp = rt::Loop::new(&mut stage, &opts, info.clock);
        let mut n = 0u64;
        let latched = lp.hold(&mut rt::HoldJob, |_| {
            n += 1;
            if n == 100 {
                COUNTING.with(|c| c.set(true));
            }
            n >= 3_000
        });
        let allocations = stop_counting();
        assert!(latched);
        assert_eq!(lp.supervisor().state(), SupervisorState::Faulted);
        (lp.supervisor().fault().map(|f| f.0), allocations)
    })
    .join()
    .unwrap();
    assert_eq!(fault, Some(FaultKind::ProbeNotFinite));
    assert_eq!(allocations, 0, "{allocations} allocations in the hold");
}

/// The daemon's metrics tap (`bench serve --metrics`) on the real-time
/// tick allocates nothing: a job and the hold after it, counted into the
/// buckets and offered every 0.1 s of loop time, the queue drained by
/// another thread (not counted), the offers at the job's end included.
#[test]
fn the_metrics_tap_allocates_nothing() {
    let (mut stage, info, chirp, opts) = short_real_time_chirp();
    let (tap, mut counts) = rt::tap::loop_tap(info.period_ns);
    let (mut producer, mut consumer) = rt::RecordQueue::new(1 << 16);
    let room = std::sync::Arc::clone(&producer.room);
    let loop_done = std::sync::Arc::new(AtomicBool::new(false));
    let done = std::sync::Arc::clone(&loop_done);
    let drain = std::thread::spawn(move || {
        let mut total = rt::tap::LoopCounts::default();
        let mut batches = 0u64;
        while !done.load(std::sync::atomic::Ordering::Acquire) || !counts.is_empty() {
            while consumer.pop().is_ok() {}
            room.made_room(0, 1 << 16);
            while let Ok(c) = counts.pop() {
                total.add(&c);
                batches += 1;
            }
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        (total, batches)
    });
    let (end, allocations) = std::thread::spawn(move || {
        let mut lp = rt::Loop::new(&mut stage, &opts, info.clock);
        lp.set_tap(tap, Some(|_: &SimStage| None));
        let mut job = Counted {
            inner: ChirpJob::new(chirp),
            from_tick: 100,
        };
        let end = lp.run_job(
            &mut job,
            &mut producer,
            opts.max_ticks,
            &AtomicBool::new(false),
            &AtomicU64::new(0),
        );
        // 0.4 s of hold: four more offers.
        let mut n = 0u64;
        lp.hold(&mut rt::HoldJob, |_| {
            n += 1;
            n >= 2_000
        });
        let allocations = stop_counting();
        (end.into_report(Vec::new()), allocations)
    })
    .join()
    .unwrap();
    loop_done.store(true, std::sync::atomic::Ordering::Release);
    let (total, batches) = drain.join().unwrap();
    assert_eq!(end.stop, StopReason::Finished);
    assert_eq!(allocations, 0, "{allocations} allocations");
    // Every tick reached the reader: the job's and the hold's, offered
    // about every 500 ticks (0.1 s at 5 kHz).
    assert_eq!(total.job_ticks, end.ticks);
    assert_eq!(total.hold_ticks, 2_000);
    assert_eq!(total.wake.count(), end.ticks + 2_000);
    assert!(batches >= (end.ticks + 2_000) / 500, "{batches} batches");
}

/// The counter does count: a tick that allocates is caught.
#[test]
fn counter_sees_an_allocating_job() {
    struct Leaky;
    impl Job for Leaky {
        fn tick(&mut self, tick: u64, _s: &Sample) -> JobOutput {
            let v: Vec<u64> = std::iter::repeat_n(tick, 4).collect();
            JobOutput {
                command_a: 0.0,
                excitation_a: v.len() as f64 * 0.0,
                setpoint_m: f64::NAN,
                done: tick >= 200,
            }
        }
    }
    let cfg = ch5();
    let mut stage = SimStage::new(cfg.sim_params(7)).unwrap();
    let info = stage.configure(cfg.loop_.period_ns()).unwrap();
    let opts = LoopOptions {
        period_ns: info.period_ns,
        pacing: Pacing::Virtual,
        timing_interval_ticks: 50,
        safety: cfg.supervisor(&info),
        max_ticks: 1_000,
    };
    let (_, allocations, _) = run_counted_job(stage, Leaky, opts, info.clock);
    assert!(allocations >= 100, "{allocations}");
}
