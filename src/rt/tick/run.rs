//! One tick of a job (steps 1–7 of the [module docs](super)), a job's run
//! from its first tick to its end, the hold between jobs, and [`run`]: one
//! loop for one job.

use super::*;

impl<'s, S: Stage> Loop<'s, S> {
    /// One tick of `job` (steps 1–7). `cur` is the job's bookkeeping; `em`
    /// where its records go.
    pub(super) fn tick<J: Job + ?Sized>(
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
        self.stall_events(em, cur.tick, t_s, missed, late_before);
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
        self.count_timing_window(cur, t_s, em);
        cur.tick += 1;
        TickResult::Ran { done: out.done }
    }

    /// The stall events of a tick (no allocation): `missed` deadlines
    /// (host stall), and a run of `late_before` late commands that ended
    /// at this sample (the device ran on held commands).
    #[inline]
    fn stall_events(
        &self,
        em: &mut Emitter<'_>,
        tick: u64,
        t_s: f64,
        missed: u64,
        late_before: u64,
    ) {
        if missed > 0 {
            em.event(
                tick,
                t_s,
                EventKind::Stall,
                &self.sup,
                missed as f64 * self.period_s,
            );
        }
        if late_before > 0 && self.sup.late_commands() == 0 {
            em.event(
                tick,
                t_s,
                EventKind::Stall,
                &self.sup,
                late_before as f64 * self.period_s,
            );
        }
    }

    /// Counts the tick in the timing window; a full window is recorded
    /// (`/bench/timing`) and starts anew (no allocation).
    #[inline]
    fn count_timing_window(&mut self, cur: &mut JobCursor, t_s: f64, em: &mut Emitter<'_>) {
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
    }

    /// A new job's bookkeeping; resets the timing histograms (no
    /// allocation).
    pub(super) fn cursor(&mut self) -> JobCursor {
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
    pub(super) fn fault_stop(&mut self, tick: u64) -> RawStop<S::Error> {
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

pub(super) fn timing_record(
    tick: u64,
    t_s: f64,
    ticks: u64,
    w: &TickTiming,
    dropped: u64,
) -> Record {
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
