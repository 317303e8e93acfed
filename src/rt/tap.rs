//! The loop's counts for the daemon's metrics (`bench serve --metrics`,
//! README *Metrics: `--metrics`*), and their wait-free hand-off to a
//! thread that is not the loop's.
//!
//! The tick adds each tick's wake-up latency and compute time to fixed
//! buckets ([`Buckets`], bounds [`BOUNDS_NS`]: the Prometheus histograms'
//! own, so a bucket's count is exact, not interpolated), and counts
//! overruns, ticks (of a job, or of the hold between jobs) and late
//! commands, in a [`LoopCounts`] the tap owns. About every
//! [`OFFER_INTERVAL_S`] of loop time it pushes them by value into a
//! wait-free SPSC queue (`rtrb`) and starts again from zero; when the queue
//! is full (nobody reads it) it keeps them, and the next offer carries
//! everything since the last one taken: nothing is lost and nothing waits.
//! The reader adds the batches up ([`LoopCounts::add`]). On the tick: no
//! allocation, lock, system call or formatting (`tests/it/alloc.rs`).
//!
//! Only ticks the loop runs in real time are counted: a job a simulator
//! daemon runs in virtual time (paced or not) has no deadline, and its
//! ticks would say nothing of the loop's real-time behaviour.

use crate::rt::backend::LinkCounters;

/// Upper bounds of the buckets, ns (each bucket holds the values `v` with
/// `previous bound < v ≤ bound`; one more bucket holds the values above
/// the last bound). From 0.25 µs to 100 ms, a little denser than a 1-2-5
/// series where a loop at 1-20 kHz lives (compute a few µs, wake-up
/// latency 5-50 µs, a period 50-1000 µs).
pub const BOUNDS_NS: [u64; 37] = [
    250,
    500,
    750,
    1_000,
    1_500,
    2_000,
    2_500,
    3_000,
    4_000,
    5_000,
    6_000,
    8_000,
    10_000,
    12_000,
    15_000,
    20_000,
    25_000,
    30_000,
    40_000,
    50_000,
    60_000,
    80_000,
    100_000,
    120_000,
    150_000,
    200_000,
    250_000,
    300_000,
    400_000,
    500_000,
    1_000_000,
    2_000_000,
    5_000_000,
    10_000_000,
    20_000_000,
    50_000_000,
    100_000_000,
];

/// Buckets, [`BOUNDS_NS`] and the one above them.
pub const BUCKETS: usize = BOUNDS_NS.len() + 1;

/// How often the tick offers its counts, s of loop time (rounded to whole
/// ticks, at least one): a scrape sees the loop as it was at most this
/// long ago.
pub const OFFER_INTERVAL_S: f64 = 0.1;

/// Batches the queue holds: about 6 s of loop time at
/// [`OFFER_INTERVAL_S`]; the reader takes them every 0.1 s.
pub const QUEUE_BATCHES: usize = 64;

/// A histogram of durations with the fixed bounds [`BOUNDS_NS`]: the count
/// in each bucket (not cumulative) and the exact sum. Recording is a
/// binary search and two additions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Buckets {
    /// Values in each bucket: `counts[i]` for `BOUNDS_NS[i - 1] < v ≤
    /// BOUNDS_NS[i]`, the last one for `v > 100 ms`.
    pub counts: [u64; BUCKETS],
    /// Sum of the values, ns (saturating; 584 years of 1 ms values).
    pub sum_ns: u64,
}

impl Default for Buckets {
    fn default() -> Self {
        Self {
            counts: [0; BUCKETS],
            sum_ns: 0,
        }
    }
}

impl Buckets {
    /// Adds one value, ns. Real-time safe.
    #[inline]
    pub fn record(&mut self, ns: u64) {
        let i = BOUNDS_NS.partition_point(|&b| b < ns);
        self.counts[i] += 1;
        self.sum_ns = self.sum_ns.saturating_add(ns);
    }

    /// Number of values.
    pub fn count(&self) -> u64 {
        self.counts.iter().sum()
    }

    /// Adds `other`'s values to these.
    pub fn add(&mut self, other: &Self) {
        for (a, b) in self.counts.iter_mut().zip(other.counts) {
            *a += b;
        }
        self.sum_ns = self.sum_ns.saturating_add(other.sum_ns);
    }
}

/// What the loop counted over a span of real-time ticks.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LoopCounts {
    /// Wake-up latency (wake − deadline), ns, as in the job summaries: 0
    /// on a device-clocked backend, whose device paces the loop.
    pub wake: Buckets,
    /// Compute time (wake → command written, less one clock read), ns.
    pub compute: Buckets,
    /// Ticks that ended after the next deadline.
    pub overruns: u64,
    /// Ticks of jobs.
    pub job_ticks: u64,
    /// Ticks of the hold between jobs.
    pub hold_ticks: u64,
    /// Samples flagged `command_late` (the command in force had not
    /// answered the previous sample: the link's round trip took longer
    /// than a period). Hardware backends only; the simulator never flags.
    pub late_commands: u64,
    /// The backend's link counters at the end of the span (since the
    /// device was opened; `None` on the simulator).
    pub link: Option<LinkCounters>,
}

impl LoopCounts {
    /// Ticks counted.
    pub fn ticks(&self) -> u64 {
        self.job_ticks + self.hold_ticks
    }

    /// Adds a later span: counts add up, the link counters are the later
    /// span's (they count since the device was opened).
    pub fn add(&mut self, later: &Self) {
        self.wake.add(&later.wake);
        self.compute.add(&later.compute);
        self.overruns += later.overruns;
        self.job_ticks += later.job_ticks;
        self.hold_ticks += later.hold_ticks;
        self.late_commands += later.late_commands;
        if later.link.is_some() {
            self.link = later.link;
        }
    }
}

/// The tick's end of the hand-off: counts since the last offer taken,
/// and the queue. Made with [`loop_tap`]; given to the loop with
/// [`crate::rt::Loop::set_tap`].
pub struct LoopTap {
    acc: LoopCounts,
    out: rtrb::Producer<LoopCounts>,
    /// Ticks since the last offer.
    since_offer: u64,
    /// Ticks between offers.
    offer_every: u64,
}

impl std::fmt::Debug for LoopTap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LoopTap")
            .field("ticks", &self.acc.ticks())
            .field("offer_every", &self.offer_every)
            .finish()
    }
}

/// A tap for a loop of period `period_ns` and the reader's end of its
/// queue ([`QUEUE_BATCHES`] batches). Allocates: make it before the loop.
pub fn loop_tap(period_ns: u64) -> (LoopTap, rtrb::Consumer<LoopCounts>) {
    let (out, rx) = rtrb::RingBuffer::new(QUEUE_BATCHES);
    let offer_every = ((OFFER_INTERVAL_S * 1e9 / period_ns.max(1) as f64).round() as u64).max(1);
    (
        LoopTap {
            acc: LoopCounts::default(),
            out,
            since_offer: 0,
            offer_every,
        },
        rx,
    )
}

impl LoopTap {
    /// One timed tick: its wake-up latency and compute time, ns, and
    /// whether it overran. Real-time safe.
    #[inline]
    pub fn timed(&mut self, wake_ns: u64, compute_ns: u64, overran: bool) {
        self.acc.wake.record(wake_ns);
        self.acc.compute.record(compute_ns);
        self.acc.overruns += u64::from(overran);
    }

    /// One tick ran: of a job (`job`) or of the hold; whether its sample
    /// said the command was late. Returns whether an offer is due.
    /// Real-time safe.
    #[inline]
    pub fn ticked(&mut self, job: bool, late_command: bool) -> bool {
        if job {
            self.acc.job_ticks += 1;
        } else {
            self.acc.hold_ticks += 1;
        }
        self.acc.late_commands += u64::from(late_command);
        self.since_offer += 1;
        self.since_offer >= self.offer_every
    }

    /// Offers the counts so far, with the link counters `link`, to the
    /// reader: pushed by value, then counting starts from zero; a full
    /// queue keeps them for the next offer. Nothing to offer (no tick
    /// counted since the last): nothing pushed. Real-time safe: no
    /// allocation, no waiting.
    #[inline]
    pub fn offer(&mut self, link: Option<LinkCounters>) {
        self.since_offer = 0;
        if self.acc.ticks() == 0 {
            return;
        }
        self.acc.link = link;
        if self.out.push(self.acc).is_ok() {
            self.acc = LoopCounts::default();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_value_on_a_bound_is_in_that_bound_s_bucket() {
        let mut b = Buckets::default();
        // ≤ bound: in its bucket; just above: the next one.
        b.record(0);
        b.record(250);
        b.record(251);
        b.record(100_000_000);
        b.record(100_000_001);
        assert_eq!(b.counts[0], 2);
        assert_eq!(b.counts[1], 1);
        assert_eq!(b.counts[BOUNDS_NS.len() - 1], 1);
        assert_eq!(b.counts[BOUNDS_NS.len()], 1);
        assert_eq!(b.count(), 5);
        assert_eq!(b.sum_ns, 250 + 251 + 100_000_000 + 100_000_001);
    }

    #[test]
    fn every_bucket_takes_the_values_between_its_bounds() {
        let mut b = Buckets::default();
        let mut lower = 0;
        for &upper in &BOUNDS_NS {
            b.record(lower + 1);
            b.record(upper);
            lower = upper;
        }
        assert!(BOUNDS_NS.windows(2).all(|w| w[0] < w[1]));
        for (i, n) in b.counts.iter().enumerate().take(BOUNDS_NS.len()) {
            assert_eq!(*n, 2, "bucket {i}");
        }
        assert_eq!(b.counts[BOUNDS_NS.len()], 0);
    }

    #[test]
    fn a_full_queue_keeps_the_counts_for_the_next_offer() {
        let (mut tap, mut rx) = loop_tap(200_000);
        assert_eq!(tap.offer_every, 500);
        // Nothing counted: nothing pushed.
        tap.offer(None);
        assert!(rx.pop().is_err());
        let mut pushed = 0u64;
        for round in 0..(QUEUE_BATCHES as u64 + 10) {
            for i in 0..500u64 {
                tap.timed(1_000 + i, 2_000, i == 0);
                let due = tap.ticked(round % 2 == 0, false);
                assert_eq!(due, i == 499);
            }
            tap.offer(None);
            pushed += 500;
        }
        // The queue took QUEUE_BATCHES batches; the rest waits in the tap.
        let mut total = LoopCounts::default();
        let mut batches = 0;
        while let Ok(c) = rx.pop() {
            total.add(&c);
            batches += 1;
        }
        assert_eq!(batches, QUEUE_BATCHES);
        assert_eq!(total.ticks(), QUEUE_BATCHES as u64 * 500);
        tap.offer(None);
        let rest = rx.pop().unwrap();
        total.add(&rest);
        assert_eq!(total.ticks(), pushed);
        assert_eq!(total.wake.count(), pushed);
        assert_eq!(total.compute.count(), pushed);
        assert_eq!(total.overruns, pushed / 500);
        assert_eq!(
            total.job_ticks,
            500 * (QUEUE_BATCHES as u64 + 10).div_ceil(2)
        );
    }
}
