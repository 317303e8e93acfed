//! Loop timing statistics kept on the real-time tick: fixed-size log-scale
//! histograms, no allocation.

/// Buckets per octave of the log-scale histograms.
const PER_OCTAVE: f64 = 4.0;
/// Number of buckets: 2^(128/4) ns ≈ 4.3 s at the top.
const BUCKETS: usize = 128;

/// A log-scale histogram of durations in ns (bucket width ≈ 19 %).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Histogram {
    counts: [u64; BUCKETS],
    n: u64,
    sum_ns: f64,
    max_ns: f64,
}

impl Default for Histogram {
    fn default() -> Self {
        Self {
            counts: [0; BUCKETS],
            n: 0,
            sum_ns: 0.0,
            max_ns: 0.0,
        }
    }
}

impl Histogram {
    /// Adds one duration, ns (negative values count as 0). Real-time safe.
    #[inline]
    pub fn record(&mut self, ns: f64) {
        let ns = ns.max(0.0);
        let idx = if ns < 1.0 {
            0
        } else {
            ((ns.log2() * PER_OCTAVE) as usize + 1).min(BUCKETS - 1)
        };
        self.counts[idx] += 1;
        self.n += 1;
        self.sum_ns += ns;
        self.max_ns = self.max_ns.max(ns);
    }

    /// Number of values.
    pub fn count(&self) -> u64 {
        self.n
    }

    /// Mean, ns (0 when empty).
    pub fn mean_ns(&self) -> f64 {
        if self.n == 0 {
            0.0
        } else {
            self.sum_ns / self.n as f64
        }
    }

    /// Largest value, ns.
    pub fn max_ns(&self) -> f64 {
        self.max_ns
    }

    /// Upper edge of the bucket holding the `p` quantile (0 < p ≤ 1), ns,
    /// capped at the maximum seen.
    pub fn quantile_ns(&self, p: f64) -> f64 {
        if self.n == 0 {
            return 0.0;
        }
        let target = (p * self.n as f64).ceil() as u64;
        let mut acc = 0;
        for (i, c) in self.counts.iter().enumerate() {
            acc += c;
            if acc >= target {
                let edge = if i == 0 {
                    1.0
                } else {
                    2f64.powf(i as f64 / PER_OCTAVE)
                };
                return edge.min(self.max_ns);
            }
        }
        self.max_ns
    }

    /// Adds another histogram into this one.
    pub fn merge(&mut self, other: &Histogram) {
        for (a, b) in self.counts.iter_mut().zip(other.counts.iter()) {
            *a += b;
        }
        self.n += other.n;
        self.sum_ns += other.sum_ns;
        self.max_ns = self.max_ns.max(other.max_ns);
    }
}

/// Timing of a span of ticks.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TickTiming {
    /// Wake-up latency (actual wake − deadline), ns.
    pub wake: Histogram,
    /// Compute time (wake → command written and record queued), ns.
    pub compute: Histogram,
    /// Ticks that ended after the next deadline.
    pub overruns: u64,
}

impl TickTiming {
    /// Merges another span.
    pub fn merge(&mut self, other: &TickTiming) {
        self.wake.merge(&other.wake);
        self.compute.merge(&other.compute);
        self.overruns += other.overruns;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_within_a_bucket() {
        let mut h = Histogram::default();
        for k in 1..=1000 {
            h.record(k as f64 * 1000.0);
        }
        assert_eq!(h.count(), 1000);
        assert!((h.mean_ns() - 500_500.0).abs() < 1e-6);
        assert_eq!(h.max_ns(), 1e6);
        // True p50 = 500 µs, p99 = 990 µs; buckets are 19 % wide.
        let p50 = h.quantile_ns(0.5);
        assert!((500e3..500e3 * 1.2).contains(&p50), "{p50}");
        let p99 = h.quantile_ns(0.99);
        assert!((990e3..=1e6).contains(&p99), "{p99}");
    }
}
