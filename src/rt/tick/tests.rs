//! Tests of the loop ([`super`]) on a scripted backend.

use super::*;
use crate::rt::supervisor::SupervisorConfig;
use crate::rt::{HoldJob, StopReason};
use bench_hal::{ErrorKind, SampleFlags};
use std::collections::VecDeque;

/// A scripted backend error.
#[derive(Debug)]
struct ScriptError(ErrorKind);

impl std::fmt::Display for ScriptError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "scripted {:?}", self.0)
    }
}

impl bench_hal::Error for ScriptError {
    fn kind(&self) -> ErrorKind {
        self.0
    }
}

/// A stage that plays a script of reads and logs what the loop did.
#[derive(Default)]
struct Script {
    reads: VecDeque<Result<f64, ErrorKind>>,
    seq: u64,
    enable_error: Option<ErrorKind>,
    write_error_at: Option<usize>,
    writes: Vec<f64>,
    enables: u32,
    disables: u32,
}

impl Script {
    fn new(reads: impl IntoIterator<Item = Result<f64, ErrorKind>>) -> Self {
        Self {
            reads: reads.into_iter().collect(),
            ..Default::default()
        }
    }
}

impl Stage for Script {
    type Error = ScriptError;
    fn configure(&mut self, _period_ns: u64) -> Result<bench_hal::DeviceInfo, ScriptError> {
        unreachable!()
    }
    fn enable(&mut self) -> Result<(), ScriptError> {
        self.enables += 1;
        self.enable_error.map_or(Ok(()), |k| Err(ScriptError(k)))
    }
    fn read_sample(&mut self) -> Result<Sample, ScriptError> {
        let x = self.reads.pop_front().unwrap_or(Ok(0.0));
        let x = x.map_err(ScriptError)?;
        self.seq += 1;
        Ok(Sample {
            seq: self.seq,
            device_time_ns: self.seq * 200_000,
            position_m: x,
            measured_current_a: f64::NAN,
            flags: SampleFlags::default(),
        })
    }
    fn write_command(&mut self, c: Command) -> Result<(), ScriptError> {
        self.writes.push(c.current_a);
        if self.write_error_at == Some(self.writes.len()) {
            return Err(ScriptError(ErrorKind::Link));
        }
        Ok(())
    }
    fn disable(&mut self) -> Result<(), ScriptError> {
        self.disables += 1;
        Ok(())
    }
}

fn opts() -> LoopOptions {
    LoopOptions {
        period_ns: 200_000,
        pacing: Pacing::Virtual,
        timing_interval_ticks: 10,
        safety: SupervisorConfig {
            position_limit_m: 0.8e-3,
            peak_current_a: 2.0,
            max_missed_deadlines: 3,
            max_missed_samples: 3,
            max_position_step_m: 50e-6,
            max_late_commands: 10,
            continuous_current_a: 1.0,
            i2t_peak_duration_s: 1.0,
            period_s: 2e-4,
            reach: crate::rt::supervisor::ReachEnvelope::NONE,
            watchdog_s: None,
            probe: crate::rt::supervisor::ProbeValidity::OFF,
        },
        max_ticks: 1000,
    }
}

/// Demands `current_a` for `n` ticks, then is done.
struct Constant {
    current_a: f64,
    n: u64,
}

impl Job for Constant {
    fn tick(&mut self, tick: u64, _s: &Sample) -> JobOutput {
        JobOutput {
            command_a: self.current_a,
            excitation_a: self.current_a,
            setpoint_m: f64::NAN,
            done: tick + 1 >= self.n,
        }
    }
}

/// Runs a job of 25 ticks at 0.5 A on `lp`.
fn run_constant(lp: &mut Loop<'_, Script>, tx: &mut RecordQueue) -> JobEnd<ScriptError> {
    lp.run_job(
        &mut Constant {
            current_a: 0.5,
            n: 25,
        },
        tx,
        1000,
        &AtomicBool::new(false),
        &AtomicU64::new(0),
    )
}

fn records(mut c: rtrb::Consumer<Record>) -> Vec<Record> {
    std::iter::from_fn(|| c.pop().ok()).collect()
}

fn events(r: &[Record]) -> Vec<EventKind> {
    r.iter()
        .filter_map(|r| match r {
            Record::Event(e) => Some(e.kind),
            _ => None,
        })
        .collect()
}

/// Demands 0.5 A; at tick `at` the writer dies (its consumer is
/// dropped, as `spawn_writer` does on a write error).
struct WriterDies {
    consumer: Option<rtrb::Consumer<Record>>,
    at: u64,
}

impl Job for WriterDies {
    fn tick(&mut self, tick: u64, _s: &Sample) -> JobOutput {
        if tick == self.at {
            self.consumer = None;
        }
        JobOutput {
            command_a: 0.5,
            excitation_a: 0.5,
            setpoint_m: f64::NAN,
            done: false,
        }
    }
}

#[test]
fn a_lost_recording_is_zero_amps_and_disable_on_the_next_tick() {
    let mut st = Script::new([]);
    let (mut tx, rx) = RecordQueue::new(4096);
    let mut lp = Loop::new(&mut st, &opts(), Clock::Host);
    let mut job = WriterDies {
        consumer: Some(rx),
        at: 10,
    };
    let end = lp.run_job(
        &mut job,
        &mut tx,
        1000,
        &AtomicBool::new(false),
        &AtomicU64::new(0),
    );
    let end = end.into_report(Vec::new());
    match end.stop {
        StopReason::Fault { kind, tick, .. } => {
            assert_eq!(kind, FaultKind::Recording);
            assert_eq!(tick, 11, "the tick after the writer died");
        }
        other => panic!("{other:?}"),
    }
    drop(lp);
    // Ticks 0..=10 drove 0.5 A; tick 11 wrote 0 A, then disabled.
    assert_eq!(&st.writes[..11], &[0.5; 11]);
    assert!(st.writes[11..].iter().all(|&i| i == 0.0), "{:?}", st.writes);
    assert!(st.disables >= 1);
}

#[test]
fn read_maps_errors_through_the_supervisor() {
    let mut st = Script::new([
        Ok(0.0),
        Err(ErrorKind::Timeout),
        Err(ErrorKind::Crc),
        Err(ErrorKind::Timeout),
        Err(ErrorKind::Crc),
    ]);
    let mut lp = Loop::new(&mut st, &opts(), Clock::Host);
    assert!(matches!(lp.read(), Read::Sample(_)));
    for _ in 0..3 {
        assert_eq!(lp.read(), Read::Missing { fault: false });
    }
    // The fourth missing sample in a row is more than K = 3.
    assert_eq!(lp.read(), Read::Missing { fault: true });
    assert_eq!(lp.supervisor().fault().map(|f| f.0), Some(FaultKind::Link));
    let (link, hal) = lp.take_errors();
    assert_eq!(link.map(|e| e.0), Some(ErrorKind::Crc));
    assert!(hal.is_none());
    // Any other read error is the HAL fault, kept with its call.
    let mut st = Script::new([Err(ErrorKind::Protocol)]);
    let mut lp = Loop::new(&mut st, &opts(), Clock::Host);
    assert_eq!(lp.read(), Read::Missing { fault: true });
    assert_eq!(lp.supervisor().fault().map(|f| f.0), Some(FaultKind::Hal));
    let (_, hal) = lp.take_errors();
    assert_eq!(
        hal.map(|(c, e)| (c, e.0)),
        Some((HalCall::ReadSample, ErrorKind::Protocol))
    );
}

#[test]
fn command_clips_and_a_fault_is_zero_then_disable_at_once() {
    let mut st = Script::new([]);
    let mut lp = Loop::new(&mut st, &opts(), Clock::Host);
    lp.enable().unwrap();
    lp.sup.running();
    assert_eq!(lp.command(5.0, 1, false), (2.0, false));
    assert_eq!(lp.command(f64::NAN, 2, false), (0.0, true));
    // A fault found earlier in the tick also stops it now.
    let mut st2 = Script::new([]);
    let mut lp2 = Loop::new(&mut st2, &opts(), Clock::Host);
    lp2.enable().unwrap();
    lp2.sup.running();
    assert!(lp2.command(1.0, 1, true).1);
    drop(lp2);
    // 1 A was written, then the safe stop: 0 A and one disable.
    assert_eq!(st2.writes, vec![1.0, 0.0]);
    assert_eq!(st2.disables, 1);
    drop(lp);
    assert_eq!(st.writes, vec![2.0, 0.0, 0.0]);
    assert_eq!(st.disables, 1);
    // A failed write is the HAL fault with the command as its value.
    let mut st = Script {
        write_error_at: Some(1),
        ..Script::new([])
    };
    let mut lp = Loop::new(&mut st, &opts(), Clock::Host);
    lp.enable().unwrap();
    lp.sup.running();
    assert_eq!(lp.command(1.5, 1, false), (1.5, true));
    assert_eq!(lp.supervisor().fault(), Some((FaultKind::Hal, 1.5)));
}

#[test]
fn job_output_is_held_without_a_sample() {
    let mut job = Constant {
        current_a: 0.7,
        n: 10,
    };
    let held = JobOutput {
        command_a: 0.3,
        done: true,
        ..JobOutput::ZERO
    };
    let s = Sample {
        seq: 0,
        device_time_ns: 0,
        position_m: 0.0,
        measured_current_a: f64::NAN,
        flags: SampleFlags::default(),
    };
    type L<'a> = Loop<'a, Script>;
    assert_eq!(L::job_output(&mut job, 0, Some(&s), held).command_a, 0.7);
    let h = L::job_output(&mut job, 1, None, held);
    assert_eq!(h.command_a, 0.3);
    // A held output never ends the job.
    assert!(!h.done);
}

#[test]
fn timing_counts_overruns_skips_missed_deadlines_and_faults_after_m() {
    let mut st = Script::new([]);
    let mut lp = Loop::new(&mut st, &opts(), Clock::Host);
    // As if paced in real time (without SCHED_FIFO on the test thread).
    lp.host_paced = true;
    let p = 200_000;
    // Disabled, or enabled at 0 A between jobs: a stall of any length is
    // counted and skipped, never latched.
    for _ in 0..3 {
        assert_eq!(
            lp.timing(500_000, 500_000, 500_000 + 100 * p, 0),
            (100, false)
        );
        lp.sup.enabled();
    }
    assert_eq!(lp.supervisor().state(), SupervisorState::Enabled);
    assert_eq!(lp.supervisor().missed_deadlines(), 0);
    lp.total.reset();
    lp.window.reset();
    // A job drives the stage: the bound applies.
    lp.sup.running();
    // On time: the next deadline is a period later.
    assert!(!lp.timing(1_000_000, 1_000_010, 1_000_100, 0).1);
    assert_eq!(lp.next_deadline_ns, 1_000_000 + p);
    assert_eq!(lp.total.overruns, 0);
    // Ends 3.5 periods late: one overrun, three deadlines missed and
    // skipped; 3 in a row are tolerated.
    assert_eq!(
        lp.timing(2_000_000, 2_000_000, 2_000_000 + 7 * p / 2, 0),
        (3, false)
    );
    assert_eq!(lp.total.overruns, 1);
    assert_eq!(lp.window.overruns, 1);
    assert_eq!(lp.next_deadline_ns, 2_000_000 + 4 * p);
    assert_eq!(lp.supervisor().missed_deadlines(), 3);
    // On time again: the streak ends.
    assert!(!lp.timing(2_800_000, 2_800_000, 2_800_100, 0).1);
    assert_eq!(lp.supervisor().missed_deadlines(), 0);
    // 2 + 2 missed in a row are more than 3: the fault (and the stage
    // stopped), its value the time behind, 4 periods.
    assert!(!lp.timing(3_000_000, 3_000_000, 3_000_000 + 2 * p + 1, 0).1);
    assert!(lp.timing(4_000_000, 4_000_000, 4_000_000 + 2 * p + 1, 0).1);
    let (kind, behind_s) = lp.supervisor().fault().unwrap();
    assert_eq!(kind, FaultKind::Overruns);
    assert!((behind_s - 4.0 * 2e-4).abs() < 1e-12, "{behind_s}");
    // Wake-up latency: 10 ns, then 0 ns; compute 90 ns less one clock
    // read at most.
    assert_eq!(lp.total.wake.count(), 5);
    assert_eq!(lp.total.wake.max_ns(), 10.0);
    assert!(lp.total.compute.quantile_ns(0.2) <= 90.0);
    drop(lp);
    assert_eq!(st.disables, 1);
}

#[test]
fn a_stall_shows_as_a_gap_in_wake_s_while_t_s_stays_even() {
    const STALL_AT: u64 = 20;
    const STALL: std::time::Duration = std::time::Duration::from_millis(20);
    /// Sleeps in its HAL read at the `STALL_AT`-th read.
    struct Stalling(Script);
    impl Stage for Stalling {
        type Error = ScriptError;
        fn configure(&mut self, p: u64) -> Result<bench_hal::DeviceInfo, ScriptError> {
            self.0.configure(p)
        }
        fn enable(&mut self) -> Result<(), ScriptError> {
            self.0.enable()
        }
        fn read_sample(&mut self) -> Result<Sample, ScriptError> {
            if self.0.seq == STALL_AT {
                std::thread::sleep(STALL);
            }
            self.0.read_sample()
        }
        fn write_command(&mut self, c: Command) -> Result<(), ScriptError> {
            self.0.write_command(c)
        }
        fn disable(&mut self) -> Result<(), ScriptError> {
            self.0.disable()
        }
    }
    let mut st = Stalling(Script::new([]));
    let mut o = opts();
    // The stall must not stop the job here.
    o.safety.max_missed_deadlines = u64::MAX;
    let mut lp = Loop::new(&mut st, &o, Clock::Host);
    // Host-paced as in real time (without SCHED_FIFO on the test
    // thread), records dropped rather than waited for.
    lp.host_paced = true;
    lp.backpressure = false;
    lp.next_deadline_ns = now_ns() + 200_000;
    let (mut tx, rx) = RecordQueue::new(4096);
    let end = lp.run_job(
        &mut Constant {
            current_a: 0.1,
            n: 50,
        },
        &mut tx,
        1000,
        &AtomicBool::new(false),
        &AtomicU64::new(0),
    );
    assert!(matches!(end.stop, RawStop::Finished));
    assert!(end.timing.overruns >= 1);
    // The stall was inside the tick (its HAL read): that tick's compute
    // time holds it; the deadlines it spanned were skipped.
    assert!(end.timing.compute.max_ns >= 20e6, "{:?}", end.timing);
    drop(lp);
    let samples: Vec<SampleRecord> = records(rx)
        .into_iter()
        .filter_map(|r| match r {
            Record::Sample(s) => Some(s),
            _ => None,
        })
        .collect();
    assert_eq!(samples.len(), 50);
    for (i, s) in samples.iter().enumerate() {
        // Nominal time: one period a tick, whatever happened.
        assert_eq!(s.t_s, i as f64 * 2e-4);
        // No tick wakes before its deadline.
        assert!(s.wake_s >= s.t_s, "{i}: {s:?}");
    }
    let gaps: Vec<f64> = samples
        .windows(2)
        .map(|w| w[1].wake_s - w[0].wake_s)
        .collect();
    assert!(gaps.iter().all(|g| *g > 0.0), "{gaps:?}");
    // The tick that read the 21st sample stalled: the next one woke at
    // least the stall later.
    let k = STALL_AT as usize;
    assert!(gaps[k] >= STALL.as_secs_f64(), "{:?}", &gaps[k - 2..k + 2]);
}

/// Virtual time times one tick in [`VIRTUAL_TIMING_STRIDE`] (the
/// first of each stride), without backpressure every tick.
#[test]
fn virtual_time_times_one_tick_in_the_stride() {
    let (mut tx, _rx) = RecordQueue::new(1024);
    let mut st = Script::new([]);
    let mut lp = Loop::new(&mut st, &opts(), Clock::Host);
    let end = run_constant(&mut lp, &mut tx);
    assert_eq!(end.ticks, 25);
    // Ticks 0 and 16 of 25.
    assert_eq!(lp.total.compute.count(), 2);
    lp.backpressure = false;
    let end = run_constant(&mut lp, &mut tx);
    assert_eq!(end.ticks, 25);
    assert_eq!(lp.total.compute.count(), 25);
}

#[test]
fn a_job_runs_enabled_and_ends_disabled_at_zero_amps() {
    let (mut tx, rx) = RecordQueue::new(1024);
    let mut st = Script::new([]);
    let mut lp = Loop::new(&mut st, &opts(), Clock::Host);
    let end = run_constant(&mut lp, &mut tx);
    assert!(matches!(end.stop, RawStop::Finished));
    assert_eq!(end.ticks, 25);
    assert_eq!(end.final_state, SupervisorState::Disabled);
    drop(lp);
    assert_eq!(st.enables, 1);
    assert_eq!(st.disables, 1);
    assert_eq!(st.writes.len(), 26);
    assert_eq!(st.writes.last(), Some(&0.0));
    let r = records(rx);
    assert_eq!(
        events(&r),
        [
            EventKind::LoopStarted,
            EventKind::StateChanged,
            EventKind::JobStarted,
            EventKind::JobFinished,
            EventKind::StateChanged,
            EventKind::LoopStopped
        ]
    );
    let samples = r.iter().filter(|r| matches!(r, Record::Sample(_))).count();
    assert_eq!(samples, 25);
}

/// CPU time of the calling thread, s.
fn thread_cpu_s() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid timespec to write into.
    assert_eq!(
        unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) },
        0
    );
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// Virtual time waits for a full queue without spinning: blocked for
/// 0.15 s of wall time behind a stalled writer, the loop thread uses a
/// small fraction of that in CPU (a spinning wait uses all of it), no
/// record is dropped, and every wait ends on the writer's wake-up, none
/// on the safety timeout (a lost wake-up would show as one).
#[test]
fn backpressure_parks_until_the_writer_makes_room() {
    let (mut q, mut rx) = RecordQueue::new(64);
    let room = std::sync::Arc::clone(&q.room);
    let event = |tick| {
        Record::Event(EventRecord {
            tick,
            t_s: 0.0,
            kind: EventKind::LoopStarted,
            state: SupervisorState::Disabled,
            fault: None,
            value: f64::NAN,
        })
    };
    const N: u64 = 64 * 200;
    let writer = std::thread::spawn(move || {
        // Stalled for less than the safety timeout.
        std::thread::sleep(std::time::Duration::from_millis(150));
        let mut ticks = Vec::new();
        while (ticks.len() as u64) < N {
            // Drains a few at a time, as the writer's batches do.
            let n = rx.slots().min(7);
            if n == 0 {
                std::thread::sleep(std::time::Duration::from_micros(50));
                continue;
            }
            for _ in 0..n {
                if let Ok(Record::Event(e)) = rx.pop() {
                    ticks.push(e.tick);
                }
            }
            room.made_room(rx.slots(), 64);
        }
        room.release();
        ticks
    });
    let mut em = Emitter::new(&mut q.producer, Some(&*q.room));
    let (wall, cpu) = (std::time::Instant::now(), thread_cpu_s());
    for tick in 0..N {
        em.push(event(tick));
    }
    let (wall_s, cpu_s) = (wall.elapsed().as_secs_f64(), thread_cpu_s() - cpu);
    assert_eq!(em.dropped, 0);
    assert!(wall_s >= 0.12, "did not wait: {wall_s} s");
    assert!(
        cpu_s < 0.25 * wall_s,
        "{cpu_s:.3} s of CPU over {wall_s:.3} s waiting"
    );
    assert_eq!(writer.join().unwrap(), (0..N).collect::<Vec<_>>());
    let (unparks, timeouts) = q.room.counts();
    assert!(unparks >= 1, "never woken by the writer");
    assert_eq!(timeouts, 0, "{timeouts} waits ended on the safety timeout");
}

/// A writer that dies while the loop waits frees it at once: the push
/// that waited is dropped (counted), nothing hangs.
#[test]
fn backpressure_ends_when_the_writer_is_gone() {
    let (mut q, rx) = RecordQueue::new(4);
    let room = std::sync::Arc::clone(&q.room);
    let writer = std::thread::spawn(move || {
        std::thread::sleep(std::time::Duration::from_millis(50));
        drop(rx);
        room.release();
    });
    let mut em = Emitter::new(&mut q.producer, Some(&*q.room));
    let r = Record::Event(EventRecord {
        tick: 0,
        t_s: 0.0,
        kind: EventKind::LoopStarted,
        state: SupervisorState::Disabled,
        fault: None,
        value: f64::NAN,
    });
    for _ in 0..6 {
        em.push(r);
    }
    writer.join().unwrap();
    assert_eq!(em.dropped, 2);
    assert!(em.recording_lost());
    assert_eq!(
        q.room.counts().1,
        0,
        "woken by the timeout, not the release"
    );
}

#[test]
fn a_latched_fault_refuses_the_next_job_and_a_failed_enable_is_a_hal_stop() {
    let (mut tx, _rx) = RecordQueue::new(1024);
    let mut st = Script::new([Ok(0.0), Ok(f64::NAN)]);
    let mut lp = Loop::new(&mut st, &opts(), Clock::Host);
    // Between jobs: the hold sees the NaN and latches.
    let mut n = 0;
    assert!(lp.hold(&mut HoldJob, |_| {
        n += 1;
        n >= 5
    }));
    let end = run_constant(&mut lp, &mut tx);
    assert!(matches!(
        end.stop,
        RawStop::Fault {
            kind: FaultKind::ProbeNotFinite,
            tick: 0,
            ..
        }
    ));
    assert_eq!(end.ticks, 0);
    drop(lp);
    // Never enabled; nothing but 0 A was written.
    assert_eq!(st.enables, 0);
    assert!(st.writes.iter().all(|w| *w == 0.0));
    let mut st = Script {
        enable_error: Some(ErrorKind::AmplifierFault),
        ..Script::new([])
    };
    let mut lp = Loop::new(&mut st, &opts(), Clock::Host);
    let end = run_constant(&mut lp, &mut tx);
    let stop = end.stop.describe();
    assert!(
        matches!(&stop, StopReason::Hal { message, tick: 0 } if message.starts_with("enable: ")),
        "{stop:?}"
    );
}

/// Notes the monotonic time of each tick; sleeps `stall` in tick
/// `stall_at` (the host stalled), done after `n` ticks.
struct Clocked {
    n: u64,
    at_ns: Vec<u64>,
    stall_at: u64,
    stall: std::time::Duration,
}

impl Job for Clocked {
    fn tick(&mut self, tick: u64, _s: &Sample) -> JobOutput {
        if tick == self.stall_at {
            std::thread::sleep(self.stall);
        }
        self.at_ns.push(now_ns());
        JobOutput {
            command_a: 0.1,
            excitation_a: 0.1,
            setpoint_m: f64::NAN,
            done: tick + 1 >= self.n,
        }
    }
}

/// Paced virtual time releases no tick before `start + k·period/factor`:
/// at factor 2 and 200 µs, 100 µs of wall time a tick, 10 ticks a batch
/// (1 ms), one sleep (and one wake-up latency) per batch. `start` is no
/// earlier than the time taken before the job.
#[test]
fn paced_time_releases_no_tick_before_its_time() {
    let mut o = opts();
    o.pacing = Pacing::Paced { factor: 2.0 };
    assert_eq!(pace_batch_ticks(o.period_ns, 2.0), 10);
    let mut st = Script::new([]);
    let mut lp = Loop::new(&mut st, &o, Clock::Host);
    assert!(!lp.host_paced && lp.backpressure);
    let (mut tx, _rx) = RecordQueue::new(4096);
    let mut job = Clocked {
        n: 400,
        at_ns: Vec::with_capacity(400),
        stall_at: u64::MAX,
        stall: std::time::Duration::ZERO,
    };
    let before = now_ns();
    let end = lp.run_job(
        &mut job,
        &mut tx,
        1000,
        &AtomicBool::new(false),
        &AtomicU64::new(0),
    );
    assert!(matches!(end.stop, RawStop::Finished));
    assert_eq!(end.ticks, 400);
    for (k, t) in job.at_ns.iter().enumerate() {
        let due = before + k as u64 * 100_000;
        assert!(*t >= due, "tick {k} ran {} ns early", due - t);
    }
    // One release measured per batch of 10.
    assert_eq!(lp.total.wake.count(), 40);
    // A new job starts its own schedule, at its own first tick, not the
    // first job's.
    std::thread::sleep(std::time::Duration::from_millis(40));
    let second = now_ns();
    let end = run_constant(&mut lp, &mut tx);
    assert!(matches!(end.stop, RawStop::Finished));
    assert!(lp.pace.unwrap().origin_ns.unwrap() >= second);
}

/// A late paced release is no fault: a 30 ms host stall in a paced job,
/// with the tightest stall bound the supervisor has (1 missed deadline),
/// is caught up, recorded as wake-up latency, and the job finishes with
/// no stall or fault event. The same stall in real time is the overruns
/// fault (the supervisor's rule, the only one).
#[test]
fn a_late_paced_release_is_caught_up_and_no_fault() {
    let stall = std::time::Duration::from_millis(30);
    let mut o = opts();
    o.safety.max_missed_deadlines = 1;
    o.pacing = Pacing::Paced { factor: 1.0 };
    let mut st = Script::new([]);
    let mut lp = Loop::new(&mut st, &o, Clock::Host);
    let (mut tx, rx) = RecordQueue::new(8192);
    let mut job = Clocked {
        n: 500,
        at_ns: Vec::with_capacity(500),
        stall_at: 100,
        stall,
    };
    let end = lp.run_job(
        &mut job,
        &mut tx,
        1000,
        &AtomicBool::new(false),
        &AtomicU64::new(0),
    );
    assert!(matches!(end.stop, RawStop::Finished), "{:?}", end.stop);
    assert_eq!(end.ticks, 500);
    assert_eq!(end.timing.overruns, 0);
    // The batch after the stall was released ~30 ms behind its schedule.
    assert!(end.timing.wake.max_ns >= 25e6, "{:?}", end.timing.wake);
    let ev = events(&records(rx));
    assert!(
        !ev.contains(&EventKind::Stall) && !ev.contains(&EventKind::Fault),
        "{ev:?}"
    );
    assert_eq!(lp.supervisor().state(), SupervisorState::Disabled);
    drop(lp);
    // Real time, the same stall: the overruns fault.
    let mut st = Script::new([]);
    let mut lp = Loop::new(&mut st, &opts(), Clock::Host);
    lp.host_paced = true;
    lp.backpressure = false;
    lp.sup = Supervisor::new(SupervisorConfig {
        max_missed_deadlines: 1,
        ..opts().safety
    });
    lp.next_deadline_ns = now_ns() + 200_000;
    let (mut tx, _rx) = RecordQueue::new(8192);
    let mut job = Clocked {
        n: 500,
        at_ns: Vec::with_capacity(500),
        stall_at: 100,
        stall,
    };
    let end = lp.run_job(
        &mut job,
        &mut tx,
        1000,
        &AtomicBool::new(false),
        &AtomicU64::new(0),
    );
    assert!(
        matches!(
            end.stop,
            RawStop::Fault {
                kind: FaultKind::Overruns,
                ..
            }
        ),
        "{:?}",
        end.stop
    );
}

/// The daemon's switch: a loop in real time runs a job paced, then is
/// back in real time (host-paced, its next deadline a period from now),
/// and the other way round.
#[test]
fn set_pacing_switches_a_loop_and_back() {
    let mut st = Script::new([]);
    let mut lp = Loop::new(&mut st, &opts(), Clock::Host);
    lp.set_pacing(Pacing::Paced { factor: 5.0 });
    assert!(!lp.host_paced && lp.backpressure && lp.pace.is_some());
    let (mut tx, _rx) = RecordQueue::new(1024);
    let end = run_constant(&mut lp, &mut tx);
    assert!(matches!(end.stop, RawStop::Finished));
    // 25 ticks at 40 µs, 25 a batch: one release.
    assert_eq!(end.timing.wake.count, 1);
    lp.set_pacing(Pacing::RealTime {
        priority: 10,
        cpu: None,
    });
    let now = now_ns();
    assert!(lp.host_paced && !lp.backpressure && lp.pace.is_none());
    assert!(lp.next_deadline_ns > now && lp.next_deadline_ns <= now + 200_000);
    lp.set_pacing(Pacing::Virtual);
    assert!(!lp.host_paced && lp.backpressure && lp.pace.is_none());
}
