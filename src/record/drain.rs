//! The writer thread ([`spawn_writer`]): drains a job's record queue into
//! its [`Recorder`] in batches, off the real-time thread, and wakes the
//! virtual-time loop when it has made room ([`QueueRoom`]).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::error::RecordError;
use crate::record::queue::QueueRoom;
use crate::record::topics::{EventKind, EventRecord, FaultKind, Record, SupervisorState};
use crate::record::writer::log_time_ns;
use crate::record::{ChunkPolicy, Recorder};

/// The writer looks at the wall clock once per this many records (a few
/// µs of writing): the chunk deadline is met to within that, and the clock
/// read stays off the per-record cost.
const WALL_CHECK_RECORDS: u64 = 32;
/// Largest number of records taken from the queue in one batch by the writer
/// thread (slots are released to the producer after each batch).
const MAX_BATCH: usize = 1024;

/// Counters returned by the writer thread ([`spawn_writer`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WriterStats {
    /// Records popped from the queue and written, count.
    pub records_written: u64,
    /// Chunks closed and flushed by the thread, count.
    pub chunks_flushed: u64,
}

fn record_log_time(r: &Record) -> u64 {
    log_time_ns(match r {
        Record::Sample(s) => s.t_s,
        Record::Timing(t) => t.t_s,
        Record::Event(e) => e.t_s,
    })
}

/// Starts the writer thread (named `bench-writer`): it pops every record from
/// `consumer`, writes it with [`Recorder::write_record`], then calls
/// `on_record` on it (e.g. to collect samples for identification). After
/// each batch it tells `room` how full the queue still is
/// ([`QueueRoom::made_room`]): a virtual-time loop parked on the full queue
/// is woken once half of it is free.
///
/// **Chunks reach the disk on a wall-clock deadline.** It closes and
/// flushes a chunk ([`Recorder::flush_chunk`], a `write(2)` to the file)
/// whenever `chunks.wall` of wall time has passed since the last flush, or
/// the log time (loop time, ns) of the written records has advanced by
/// `chunks.loop_time` ([`ChunkPolicy`]); the wall deadline is checked every
/// 32 records (a few µs), so a writer that is behind
/// still flushes on time. With 50 ms of wall time, a killed process loses
/// at most that plus what sits in the queue (a few ms when the writer keeps
/// up), under the 100 ms the README promises. When the queue is empty it sleeps
/// ~1 ms. `priority`: in real-time runs the thread takes `SCHED_FIFO` at
/// this priority (one below the loop's), so a loaded machine does not starve
/// it; without the permission it runs normally (best effort, no error).
///
/// It exits once `done` is set (or the producer was dropped) **and** the
/// queue is empty — the queue is drained fully — flushes the last chunk, and
/// returns the recorder, **not finished**, so the caller can add e.g.
/// `/sysid/frf` and then call [`Recorder::finish`].
///
/// **On a write error** (e.g. `ENOSPC`) the thread tries to write a
/// `fault`/`recording` event (it may fail too), drops the recorder (leaving
/// the `.part` file, see [`Recorder`]'s `Drop`) and returns the error at
/// once. Dropping its consumer abandons the queue: the loop sees that on its
/// next tick ([`crate::rt::Emitter::recording_lost`]) and stops on the
/// `recording` fault (0 A, disabled); a loop parked on `room` is woken.
///
/// # Panics
/// If the OS cannot spawn a thread.
pub fn spawn_writer<F>(
    mut consumer: rtrb::Consumer<Record>,
    room: Arc<QueueRoom>,
    mut recorder: Recorder,
    done: Arc<AtomicBool>,
    chunks: ChunkPolicy,
    priority: Option<i32>,
    mut on_record: F,
) -> JoinHandle<Result<(Recorder, WriterStats), RecordError>>
where
    F: FnMut(&Record) + Send + 'static,
{
    std::thread::Builder::new()
        .name("bench-writer".into())
        .spawn(move || {
            if let Some(p) = priority {
                // The loop's own setup (mlockall is process-wide: again is
                // a no-op); not permitted, the writer runs normally.
                for w in bench_hal::os::make_realtime(p, None) {
                    tracing::debug!("bench-writer: {w}");
                }
            }
            let mut last: Option<(u64, f64)> = None;
            let result = write_queue(
                &mut consumer,
                &room,
                &mut recorder,
                &done,
                chunks,
                &mut on_record,
                &mut last,
            );
            match result {
                Ok(stats) => Ok((recorder, stats)),
                Err(e) => {
                    let (tick, t_s) = last.unwrap_or((0, 0.0));
                    let _ = recorder.write_record(&Record::Event(EventRecord {
                        tick,
                        t_s,
                        kind: EventKind::Fault,
                        state: SupervisorState::Faulted,
                        fault: Some(FaultKind::Recording),
                        value: f64::NAN,
                    }));
                    drop(recorder);
                    drop(consumer);
                    // A loop parked on the full queue sees it abandoned now.
                    room.release();
                    Err(e)
                }
            }
        })
        .expect("cannot spawn the bench-writer thread")
}

/// The writer thread's loop (see [`spawn_writer`]). `last` is the tick and
/// loop time of the newest record written.
fn write_queue<F: FnMut(&Record)>(
    consumer: &mut rtrb::Consumer<Record>,
    room: &QueueRoom,
    recorder: &mut Recorder,
    done: &AtomicBool,
    chunks: ChunkPolicy,
    on_record: &mut F,
    last: &mut Option<(u64, f64)>,
) -> Result<WriterStats, RecordError> {
    let interval_ns = u64::try_from(chunks.loop_time.as_nanos()).unwrap_or(u64::MAX);
    let chunk_interval = chunks.wall;
    let mut stats = WriterStats::default();
    let mut last_flush_wall = Instant::now();
    // Log time of the last record written before the previous flush (or of
    // the first record ever).
    let mut last_flush_log: Option<u64> = None;
    // Log time of the newest record written.
    let mut last_written_log: Option<u64> = None;
    let mut dirty = false;
    loop {
        // Read `done` before looking at the queue: if it was set, every
        // record pushed before it is visible to the `slots()` below.
        let finishing = done.load(Ordering::Acquire) || consumer.is_abandoned();
        let queued = consumer.slots();
        room.observe_queue(queued, consumer.buffer().capacity());
        let n = queued.min(MAX_BATCH);
        if n > 0 {
            let chunk = consumer
                .read_chunk(n)
                .expect("slots() said these are available");
            let (a, b) = chunk.as_slices();
            for r in a.iter().chain(b) {
                recorder.write_record(r)?;
                on_record(r);
                stats.records_written += 1;
                dirty = true;
                *last = Some(record_tick_time(r));
                let t = record_log_time(r);
                last_written_log = Some(t);
                let base = *last_flush_log.get_or_insert(t);
                if t.saturating_sub(base) >= interval_ns
                    || (stats.records_written.is_multiple_of(WALL_CHECK_RECORDS)
                        && last_flush_wall.elapsed() >= chunk_interval)
                {
                    recorder.flush_chunk()?;
                    stats.chunks_flushed += 1;
                    flushed(recorder, room);
                    dirty = false;
                    last_flush_log = Some(t);
                    last_flush_wall = Instant::now();
                }
            }
            chunk.commit_all();
            room.made_room(consumer.slots(), consumer.buffer().capacity());
        }
        if dirty && last_flush_wall.elapsed() >= chunk_interval {
            recorder.flush_chunk()?;
            stats.chunks_flushed += 1;
            flushed(recorder, room);
            dirty = false;
            last_flush_wall = Instant::now();
            last_flush_log = last_written_log;
        }
        if n == 0 {
            if finishing {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    if dirty {
        recorder.flush_chunk()?;
        stats.chunks_flushed += 1;
        flushed(recorder, room);
    }
    Ok(stats)
}

/// After a chunk flush: the recording's size on disk, for the daemon's
/// metrics (one `stat`, on the writer thread).
fn flushed(recorder: &Recorder, room: &QueueRoom) {
    if let Ok(m) = std::fs::metadata(recorder.part_path()) {
        room.set_file_bytes(m.len());
    }
}

fn record_tick_time(r: &Record) -> (u64, f64) {
    match r {
        Record::Sample(s) => (s.tick, s.t_s),
        Record::Timing(t) => (t.tick, t.t_s),
        Record::Event(e) => (e.tick, e.t_s),
    }
}
