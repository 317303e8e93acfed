//! A job's record queue: the wait-free SPSC queue (`rtrb`) from the
//! real-time tick to the writer thread, and the tick's end of it
//! ([`Emitter`]). The loop pushes; the writer ([`crate::record::spawn_writer`])
//! pops. Nothing here allocates, locks or logs on the push.

use crate::record::topics::Record;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// The longest the virtual-time loop stays parked without a wake-up from
/// the writer ([`QueueRoom`]): a safety net only (a writer that died, a
/// wake-up lost to a bug), never the pacing. Long against the tens of ms
/// the writer takes to empty half the 65 536-record queue of a job.
pub const ROOM_WAIT_TIMEOUT: std::time::Duration = std::time::Duration::from_millis(200);

/// Room in a job's record queue, for the virtual-time loop's wait on the
/// writer: the loop parks ([`std::thread::park_timeout`]) while the queue
/// is full, and the writer unparks it once it has emptied half the queue
/// ([`QueueRoom::made_room`]). No spinning, no lock: one flag, one thread
/// handle. One per job; the writer and the loop share it.
///
/// The hand-over is the store-fence-load pattern on both sides: the loop
/// raises `waiting`, fences, then looks at the queue; the writer frees
/// slots, fences, then takes `waiting`. Either the loop sees the room, or
/// the writer sees the flag and unparks (an unpark before the park makes
/// the park return at once).
///
/// The writer also leaves here what it last saw, for the daemon's metrics
/// (read by another thread, never by the loop): how full the queue was
/// when it came for a batch ([`QueueRoom::fill_ratio`]) and how many bytes
/// of the recording were on disk at its last chunk flush
/// ([`QueueRoom::file_bytes`]).
#[derive(Debug, Default)]
pub struct QueueRoom {
    waiting: AtomicBool,
    parked: std::sync::OnceLock<std::thread::Thread>,
    /// Wake-ups given by the writer.
    unparks: AtomicU64,
    /// Parks that ended on [`ROOM_WAIT_TIMEOUT`] instead of a wake-up.
    timeouts: AtomicU64,
    /// Records waiting when the writer last came for a batch.
    queued: AtomicU64,
    /// The queue's capacity, records (0 until the writer's first look).
    capacity: AtomicU64,
    /// Bytes of the recording file at the writer's last chunk flush.
    file_bytes: AtomicU64,
}

impl QueueRoom {
    /// Writer side, after it has taken records off the queue: `queued` are
    /// still in it, out of `capacity`. Wakes the loop if it waits and half
    /// the queue is free.
    pub fn made_room(&self, queued: usize, capacity: usize) {
        std::sync::atomic::fence(Ordering::SeqCst);
        if queued <= capacity / 2 {
            self.wake();
        }
    }

    /// Writer side, when it ends (done or failed): wakes a waiting loop so
    /// it sees the queue abandoned at once.
    pub fn release(&self) {
        std::sync::atomic::fence(Ordering::SeqCst);
        self.wake();
    }

    fn wake(&self) {
        if self.waiting.swap(false, Ordering::SeqCst) {
            if let Some(t) = self.parked.get() {
                self.unparks.fetch_add(1, Ordering::Relaxed);
                t.unpark();
            }
        }
    }

    /// Loop side: parks until half of `out` is free or its writer is gone.
    fn wait(&self, out: &rtrb::Producer<Record>) {
        let half = (out.buffer().capacity() / 2).max(1);
        let me = self.parked.get_or_init(std::thread::current);
        debug_assert_eq!(
            me.id(),
            std::thread::current().id(),
            "one loop thread per job"
        );
        loop {
            self.waiting.store(true, Ordering::SeqCst);
            std::sync::atomic::fence(Ordering::SeqCst);
            if out.slots() >= half || out.is_abandoned() {
                self.waiting.store(false, Ordering::SeqCst);
                return;
            }
            let t0 = std::time::Instant::now();
            std::thread::park_timeout(ROOM_WAIT_TIMEOUT);
            if t0.elapsed() >= ROOM_WAIT_TIMEOUT {
                self.timeouts.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// Wake-ups the writer gave, and parks that timed out instead.
    pub fn counts(&self) -> (u64, u64) {
        (
            self.unparks.load(Ordering::Relaxed),
            self.timeouts.load(Ordering::Relaxed),
        )
    }

    /// Writer side, as it comes for a batch: `queued` records wait, out
    /// of `capacity`.
    pub fn observe_queue(&self, queued: usize, capacity: usize) {
        self.queued.store(queued as u64, Ordering::Relaxed);
        self.capacity.store(capacity as u64, Ordering::Relaxed);
    }

    /// How full the queue was when the writer last came for a batch, 0 to
    /// 1 (0 before its first look).
    pub fn fill_ratio(&self) -> f64 {
        match self.capacity.load(Ordering::Relaxed) {
            0 => 0.0,
            c => self.queued.load(Ordering::Relaxed) as f64 / c as f64,
        }
    }

    /// Writer side, after a chunk flush: the recording file's size, bytes.
    pub fn set_file_bytes(&self, bytes: u64) {
        self.file_bytes.store(bytes, Ordering::Relaxed);
    }

    /// Bytes of the recording file at the writer's last chunk flush.
    pub fn file_bytes(&self) -> u64 {
        self.file_bytes.load(Ordering::Relaxed)
    }
}

/// A job's record queue, the loop's end: the producer, and the
/// [`QueueRoom`] the writer signals.
pub struct RecordQueue {
    /// The loop's end of the queue.
    pub producer: rtrb::Producer<Record>,
    /// Shared with the writer (pass it to
    /// [`spawn_writer`](crate::record::spawn_writer)).
    pub room: std::sync::Arc<QueueRoom>,
}

impl RecordQueue {
    /// A queue of `capacity` records: the loop's end, and the writer's.
    pub fn new(capacity: usize) -> (Self, rtrb::Consumer<Record>) {
        let (producer, consumer) = rtrb::RingBuffer::new(capacity);
        (
            Self {
                producer,
                room: Default::default(),
            },
            consumer,
        )
    }
}

/// Where a job's records go: its own queue, or nowhere (between jobs).
pub struct Emitter<'q> {
    out: Option<&'q mut rtrb::Producer<Record>>,
    /// Records dropped because the queue was full (real time).
    pub dropped: u64,
    /// Virtual time: wait for queue space instead of dropping.
    room: Option<&'q QueueRoom>,
}

impl<'q> Emitter<'q> {
    /// Records into `out`; with `room` (virtual time only) a full queue
    /// is waited for instead of dropping.
    pub fn new(out: &'q mut rtrb::Producer<Record>, room: Option<&'q QueueRoom>) -> Self {
        Self {
            out: Some(out),
            dropped: 0,
            room,
        }
    }

    /// Whether anything is recorded (not between jobs).
    #[inline]
    pub fn records(&self) -> bool {
        self.out.is_some()
    }

    /// Records nothing (the hold job between jobs).
    pub fn none() -> Self {
        Self {
            out: None,
            dropped: 0,
            room: None,
        }
    }

    /// The job records, and its writer is gone (it died on a write error):
    /// the recording is lost. One atomic load; real-time safe.
    #[inline]
    pub fn recording_lost(&self) -> bool {
        self.out
            .as_deref()
            .is_some_and(rtrb::Producer::is_abandoned)
    }

    /// Step 6: pushes one record; never allocates. In real time a full
    /// queue drops the record (counted). In virtual time (a [`QueueRoom`])
    /// the loop parks until the writer has emptied half the queue and wakes
    /// it, so a run bound by the writer costs one wake-up per half queue
    /// instead of one `sched_yield` per record.
    #[inline]
    pub fn push(&mut self, r: Record) {
        let Some(out) = self.out.as_deref_mut() else {
            return;
        };
        let mut r = r;
        loop {
            match out.push(r) {
                Ok(()) => return,
                Err(rtrb::PushError::Full(back)) => match self.room {
                    Some(room) if !out.is_abandoned() => {
                        r = back;
                        room.wait(out);
                    }
                    _ => {
                        self.dropped += 1;
                        return;
                    }
                },
            }
        }
    }
}
