//! Loop timing statistics kept on the real-time tick: HDR histograms
//! (`hdrhistogram`) of fixed range, allocated before the loop starts, so
//! recording never allocates.
//!
//! Resolution: two significant figures, i.e. 128 linear sub-buckets per
//! power of two, so a quantile is reported as the upper edge of a bucket at
//! most 1/128 ≈ 0.8 % wider than its lower edge: at most 1 % above the true
//! order statistic, never below it (Gil Tene's HdrHistogram,
//! <https://hdrhistogram.github.io/HdrHistogram/>). The range is 1 ns to
//! 10 s; a longer duration counts as 10 s (the exact maximum is kept apart).
//! Count, sum (for the mean) and maximum are kept exactly.

use hdrhistogram::Histogram as Hdr;

/// Longest duration the histograms resolve, ns (10 s); longer ones count
/// as this in the quantiles (the maximum is exact).
pub const HIGHEST_NS: u64 = 10_000_000_000;
/// Significant decimal figures of the histograms (relative error ≤ 1 %).
pub const SIGNIFICANT_FIGURES: u8 = 2;

/// A histogram of durations in ns, ≤ 1 % relative error on its quantiles.
/// [`Histogram::new`] allocates (about 28 kB); recording does not.
#[derive(Debug, Clone)]
pub struct Histogram {
    h: Hdr<u64>,
    sum_ns: f64,
    max_ns: u64,
}

impl Default for Histogram {
    fn default() -> Self {
        Self::new()
    }
}

impl Histogram {
    /// An empty histogram covering 1 ns to [`HIGHEST_NS`]. Allocates: create
    /// it before the loop.
    pub fn new() -> Self {
        let mut h = Hdr::new_with_bounds(1, HIGHEST_NS, SIGNIFICANT_FIGURES)
            .expect("constant, valid histogram bounds");
        h.auto(false);
        Self {
            h,
            sum_ns: 0.0,
            max_ns: 0,
        }
    }

    /// Adds one duration, ns (longer than [`HIGHEST_NS`] counts as that in
    /// the quantiles). Real-time safe: no allocation.
    #[inline]
    pub fn record(&mut self, ns: u64) {
        self.h.saturating_record(ns);
        self.sum_ns += ns as f64;
        self.max_ns = self.max_ns.max(ns);
    }

    /// Number of values.
    pub fn count(&self) -> u64 {
        self.h.len()
    }

    /// Mean, ns (0 when empty). One long stall moves it; prefer
    /// [`Histogram::quantile_ns`] with 0.5.
    pub fn mean_ns(&self) -> f64 {
        match self.count() {
            0 => 0.0,
            n => self.sum_ns / n as f64,
        }
    }

    /// Largest value, ns (exact; 0 when empty).
    pub fn max_ns(&self) -> f64 {
        self.max_ns as f64
    }

    /// The `q` quantile (0 < q ≤ 1), ns: the smallest recorded value `v`
    /// with at least `⌈q·n⌉` values ≤ `v`, reported as the upper edge of its
    /// bucket (≤ 1 % above), capped at the exact maximum. 0 when empty. No
    /// allocation.
    pub fn quantile_ns(&self, q: f64) -> f64 {
        if self.count() == 0 {
            return 0.0;
        }
        (self.h.value_at_quantile(q).min(self.max_ns)) as f64
    }

    /// Forgets every value (keeps the allocation). No allocation.
    pub fn reset(&mut self) {
        self.h.reset();
        self.sum_ns = 0.0;
        self.max_ns = 0;
    }

    /// Count, mean, p50, p99, p99.9 and maximum. No allocation.
    pub fn stats(&self) -> LatencyStats {
        LatencyStats {
            count: self.count(),
            mean_ns: self.mean_ns(),
            p50_ns: self.quantile_ns(0.5),
            p99_ns: self.quantile_ns(0.99),
            p999_ns: self.quantile_ns(0.999),
            max_ns: self.max_ns(),
        }
    }
}

/// Summary of one [`Histogram`], ns (all 0 when empty).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LatencyStats {
    /// Number of values.
    pub count: u64,
    /// Mean, ns (one stall can dominate it; the median is the headline).
    pub mean_ns: f64,
    /// Median, ns (≤ 1 % above the true value).
    pub p50_ns: f64,
    /// 99th percentile, ns (≤ 1 % above).
    pub p99_ns: f64,
    /// 99.9th percentile, ns (≤ 1 % above).
    pub p999_ns: f64,
    /// Largest value, ns (exact).
    pub max_ns: f64,
}

/// The histograms of a span of ticks. Allocates when created; recording
/// and [`TickTiming::reset`] do not.
#[derive(Debug, Clone, Default)]
pub struct TickTiming {
    /// Wake-up latency (actual wake − deadline), ns.
    pub wake: Histogram,
    /// Compute time (wake timestamp → command written, minus the cost of
    /// one clock read), ns.
    pub compute: Histogram,
    /// Ticks that ended after the next deadline.
    pub overruns: u64,
}

impl TickTiming {
    /// Forgets everything (keeps the allocation).
    pub fn reset(&mut self) {
        self.wake.reset();
        self.compute.reset();
        self.overruns = 0;
    }

    /// The summary of the span. No allocation.
    pub fn stats(&self) -> TimingStats {
        TimingStats {
            wake: self.wake.stats(),
            compute: self.compute.stats(),
            overruns: self.overruns,
        }
    }
}

/// Timing of a span of ticks, summarised (what a job reports).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TimingStats {
    /// Wake-up latency, ns.
    pub wake: LatencyStats,
    /// Compute time, ns.
    pub compute: LatencyStats,
    /// Ticks that ended after the next deadline.
    pub overruns: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Quantile of the uniform integers 1..=n by the definition the
    /// histogram documents: the ⌈q·n⌉-th smallest value is ⌈q·n⌉ itself.
    fn exact_uniform(n: u64, q: f64) -> f64 {
        (q * n as f64).ceil()
    }

    #[test]
    fn quantiles_of_a_uniform_distribution_within_one_percent() {
        let n = 100_000;
        let mut h = Histogram::new();
        for ns in 1..=n {
            h.record(ns);
        }
        assert_eq!(h.count(), n);
        // Mean of 1..=n is (n + 1) / 2, exactly.
        assert_eq!(h.mean_ns(), 50_000.5);
        assert_eq!(h.max_ns(), 100_000.0);
        for q in [0.01, 0.1, 0.5, 0.9, 0.99, 0.999] {
            let want = exact_uniform(n, q);
            let got = h.quantile_ns(q);
            assert!(
                got >= want && got <= want * 1.01,
                "q {q}: {got} ns against {want} ns"
            );
        }
        let s = h.stats();
        assert!((s.p50_ns / 50_000.0 - 1.0).abs() <= 0.01, "{s:?}");
        assert!((s.p99_ns / 99_000.0 - 1.0).abs() <= 0.01, "{s:?}");
        assert!((s.p999_ns / 99_900.0 - 1.0).abs() <= 0.01, "{s:?}");
    }

    #[test]
    fn one_long_stall_moves_the_mean_not_the_median() {
        let mut h = Histogram::new();
        for _ in 0..999 {
            h.record(10_000);
        }
        // One 50 ms preemption.
        h.record(50_000_000);
        assert!(h.mean_ns() > 5.0 * 10_000.0);
        assert!((h.quantile_ns(0.5) / 10_000.0 - 1.0).abs() <= 0.01);
        assert_eq!(h.max_ns(), 50e6);
        // The 1000th of 1000 is the stall: p99.9 sees it.
        assert!((h.quantile_ns(0.999) / 10_000.0 - 1.0).abs() <= 0.01);
        assert!((h.quantile_ns(1.0) / 50e6 - 1.0).abs() <= 0.01);
    }

    #[test]
    fn beyond_the_range_saturates_and_reset_empties() {
        let mut h = Histogram::new();
        h.record(0);
        h.record(20_000_000_000);
        assert_eq!(h.count(), 2);
        assert_eq!(h.max_ns(), 2e10);
        assert!(h.quantile_ns(1.0) <= 2e10);
        assert!(h.quantile_ns(1.0) >= HIGHEST_NS as f64);
        h.reset();
        assert_eq!(h.stats(), LatencyStats::default());
    }
}
