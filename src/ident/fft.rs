//! The spectra of a long two-channel record, computed in the record's own
//! memory.
//!
//! A chirp record of `M` ticks holds two real signals, the input `u[n]` (A)
//! and the output `y[n]` (m). They are kept packed as one complex signal
//! `z[n] = u[n] + i·y[n]` (16 bytes a tick: the two `f64` columns and no
//! more) and transformed in place with the four-step FFT. With `M = N1·N2`
//! and `W_L = exp(−2πi/L)`:
//! ```text
//! Z[k1 + N1·k2] = Σ_{n2} W_N2^(n2·k2) · W_M^(n2·k1) · Σ_{n1} z[N2·n1 + n2] · W_N1^(n1·k1)
//! ```
//! (D. H. Bailey, "FFTs in external or hierarchical memory", *J.
//! Supercomputing* 4, 1990; C. Van Loan, *Computational Frameworks for the
//! Fast Fourier Transform*, SIAM 1992, §3.3). Step 1 runs `N2` strided
//! column transforms of length `N1` and multiplies by the twiddle factors
//! `W_M^(n2·k1)`; step 2 runs `N1` contiguous row transforms of length `N2`.
//! Both are done in place (the short transforms by `rustfft`), so the
//! scratch is `O(N1 + N2) = O(√M)`, and `Z[k1 + N1·k2]` ends at index
//! `N2·k1 + k2`. The two real spectra follow from the Hermitian symmetry of
//! a real signal's transform:
//! ```text
//! U[k] = (Z[k] + Z*[M − k]) / 2,    Y[k] = (Z[k] − Z*[M − k]) / (2i)
//! ```
//! Only the bins an estimate reads are kept: `Z[k]` for `k ≤ k_max` and
//! their mirrors `Z[M − k]`. They are moved to the front of the same buffer
//! (row by row, never overtaking an unread value) and the buffer is shrunk,
//! so the record's memory is the whole of the estimate's memory: 16 bytes a
//! tick at the peak, `32·k_max / M` after.

use super::C64;
use rustfft::FftPlanner;
use std::f64::consts::PI;

/// Columns gathered at a time in step 1: eight `Complex<f64>` are two
/// 64-byte cache lines of each row.
const BLOCK: usize = 8;

/// Twiddle factors are recomputed exactly every this many rotations
/// (the rounding of the recurrence stays below 1e-14).
const REANCHOR: usize = 32;

/// `U[k]` and `Y[k]` for `k ≤ k_max` of a packed record, in `O(k_max)`
/// memory.
#[derive(Debug, Clone)]
pub struct PackedSpectrum {
    /// Kept values of `Z`, row by row (see [`Self::z_at`]).
    z: Vec<C64>,
    /// Transform length `M`.
    len: usize,
    /// Row count `N1` (`Z[k]` is in row `k mod N1`).
    n1: usize,
    /// Highest bin kept.
    k_max: usize,
    /// Per row: index of its first kept value in `z`.
    row_start: Vec<usize>,
    /// Per row: kept values with `k ≤ k_max` (`q = k div N1` from 0).
    n_low: Vec<usize>,
    /// Per row: first `q` of the kept mirror bins `k ≥ M − k_max`.
    q_high: Vec<usize>,
    /// Each channel was divided by its largest magnitude before the
    /// transform (so the rounding of the larger one does not swamp the
    /// smaller: A against m): `(u, y)` scales to multiply back.
    scale: (f64, f64),
}

/// The divisor of `m` nearest `√m` from below (1 when `m` is prime).
fn divisor_near_sqrt(m: usize) -> usize {
    let mut d = ((m as f64).sqrt() as usize).max(1);
    while d > 1 && !m.is_multiple_of(d) {
        d -= 1;
    }
    d
}

/// `W_m^j = exp(−2πi j / m)`.
fn unit(j: usize, m: usize) -> C64 {
    let a = -2.0 * PI * j as f64 / m as f64;
    C64::new(a.cos(), a.sin())
}

/// Multiplies `col[k1]` by `W_m^(n2·k1)`.
fn twiddle(col: &mut [C64], n2: usize, m: usize) {
    if n2 == 0 {
        return;
    }
    let step = unit(n2, m);
    let mut w = C64::new(1.0, 0.0);
    for (k1, c) in col.iter_mut().enumerate() {
        if k1.is_multiple_of(REANCHOR) {
            // n2·k1 < N2·N1 = m: no reduction needed.
            w = unit(n2 * k1, m);
        }
        *c *= w;
        w *= step;
    }
}

impl PackedSpectrum {
    /// Transforms the packed record `z[n] = u[n] + i·y[n]` in its own
    /// memory and keeps the bins `0 ..= k_max` (capped at `M/2`) of `U` and
    /// `Y`. `M = z.len()`; any length works, and the scratch is `O(√M)`
    /// when `M` has a divisor near `√M` (the callers pad to 2^a 3^b 5^c).
    pub fn transform(mut z: Vec<C64>, k_max: usize) -> Self {
        let m = z.len().max(1);
        z.resize(m, C64::default());
        let peak = |f: fn(&C64) -> f64| {
            let p = z.iter().fold(0.0_f64, |a, v| a.max(f(v).abs()));
            if p > 0.0 && p.is_finite() {
                p
            } else {
                1.0
            }
        };
        let scale = (peak(|v| v.re), peak(|v| v.im));
        for v in &mut z {
            *v = C64::new(v.re / scale.0, v.im / scale.1);
        }
        let n1 = divisor_near_sqrt(m);
        let n2 = m / n1;
        let mut planner = FftPlanner::<f64>::new();
        let f1 = planner.plan_fft_forward(n1);
        let f2 = planner.plan_fft_forward(n2);
        let mut scratch = vec![
            C64::default();
            f1.get_inplace_scratch_len()
                .max(f2.get_inplace_scratch_len())
        ];

        // Step 1: the columns z[N2·n1 + n2], n1 = 0 … N1−1, BLOCK at a time.
        let mut cols = vec![C64::default(); BLOCK * n1];
        let mut c0 = 0;
        while c0 < n2 {
            let b = BLOCK.min(n2 - c0);
            for (i, row) in z.chunks_exact(n2).enumerate() {
                for (j, v) in row[c0..c0 + b].iter().enumerate() {
                    cols[j * n1 + i] = *v;
                }
            }
            for (j, col) in cols.chunks_exact_mut(n1).take(b).enumerate() {
                f1.process_with_scratch(col, &mut scratch);
                twiddle(col, c0 + j, m);
            }
            for (k1, row) in z.chunks_exact_mut(n2).enumerate() {
                for (j, v) in row[c0..c0 + b].iter_mut().enumerate() {
                    *v = cols[j * n1 + k1];
                }
            }
            c0 += b;
        }
        drop(cols);
        // Step 2: each row (contiguous) in place; Z[k1 + N1·k2] at N2·k1 + k2.
        f2.process_with_scratch(&mut z, &mut scratch);
        drop(scratch);

        // Keep Z[k], k ≤ k_max, and Z[M − k]: per row r (k = q·N1 + r) a
        // low run q < n_low and a high run q ≥ q_high, moved to the front.
        let k_max = k_max.min(m / 2);
        let first_mirror = m - k_max;
        let (mut row_start, mut n_low, mut q_high) = (
            Vec::with_capacity(n1),
            Vec::with_capacity(n1),
            Vec::with_capacity(n1),
        );
        let mut dst = 0;
        for r in 0..n1 {
            let low = if r <= k_max {
                ((k_max - r) / n1 + 1).min(n2)
            } else {
                0
            };
            let high = if first_mirror > r {
                (first_mirror - r).div_ceil(n1)
            } else {
                0
            }
            .clamp(low, n2);
            let src = n2 * r;
            // dst ≤ src (every row keeps at most N2 values) and low ≤ high:
            // both moves go towards the front over values already read.
            z.copy_within(src..src + low, dst);
            z.copy_within(src + high..src + n2, dst + low);
            row_start.push(dst);
            n_low.push(low);
            q_high.push(high);
            dst += low + (n2 - high);
        }
        z.truncate(dst);
        z.shrink_to_fit();
        Self {
            z,
            len: m,
            n1,
            k_max,
            row_start,
            n_low,
            q_high,
            scale,
        }
    }

    /// Transform length `M`.
    pub fn fft_len(&self) -> usize {
        self.len
    }

    /// Highest bin kept.
    pub fn k_max(&self) -> usize {
        self.k_max
    }

    /// `Z[k]` for a kept `k` (`k ≤ k_max` or `k ≥ M − k_max`).
    fn z_at(&self, k: usize) -> C64 {
        let (q, r) = (k / self.n1, k % self.n1);
        let i = if q < self.n_low[r] {
            self.row_start[r] + q
        } else {
            debug_assert!(q >= self.q_high[r], "bin {k} was not kept");
            self.row_start[r] + self.n_low[r] + (q - self.q_high[r])
        };
        self.z[i]
    }

    /// `(U[k], Y[k])`, the unnormalised DFTs of the two channels
    /// (`Σ x[n] e^(−2πi kn/M)`).
    ///
    /// # Panics
    /// If `k > k_max`.
    pub fn bin(&self, k: usize) -> (C64, C64) {
        assert!(k <= self.k_max, "bin {k} above the kept {}", self.k_max);
        let a = self.z_at(k);
        let b = self.z_at((self.len - k) % self.len).conj();
        (
            (a + b) * (0.5 * self.scale.0),
            (a - b) * C64::new(0.0, -0.5 * self.scale.1),
        )
    }

    /// Bytes held.
    pub fn heap_bytes(&self) -> usize {
        self.z.capacity() * std::mem::size_of::<C64>() + 3 * self.n1 * std::mem::size_of::<usize>()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The textbook DFT, O(M²): the independent reference.
    fn dft(x: &[f64], k: usize) -> C64 {
        let m = x.len();
        x.iter()
            .enumerate()
            .map(|(n, v)| unit((n * k) % m, m) * *v)
            .sum()
    }

    #[test]
    fn equals_the_direct_dft_of_both_channels() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        // Smooth, prime and square lengths; k_max below, at and above M/2.
        for (m, k_max) in [
            (360, 40),
            (360, 180),
            (1000, 999),
            (97, 10),
            (1024, 300),
            (2, 1),
        ] {
            let u: Vec<f64> = (0..m).map(|_| rng.random_range(-1.0..1.0)).collect();
            let y: Vec<f64> = (0..m).map(|_| rng.random_range(-1e-3..1e-3)).collect();
            let z = u.iter().zip(&y).map(|(a, b)| C64::new(*a, *b)).collect();
            let s = PackedSpectrum::transform(z, k_max);
            assert_eq!(s.k_max(), k_max.min(m / 2));
            for k in 0..=s.k_max() {
                let (uk, yk) = s.bin(k);
                let (ru, ry) = (dft(&u, k), dft(&y, k));
                assert!(
                    (uk - ru).norm() < 1e-10 * (m as f64),
                    "M {m} k {k}: {uk} vs {ru}"
                );
                assert!(
                    (yk - ry).norm() < 1e-13 * (m as f64),
                    "M {m} k {k}: {yk} vs {ry}"
                );
            }
        }
    }

    #[test]
    fn keeps_only_the_band() {
        let m = 2 * 3 * 5 * 1000;
        let z = vec![C64::new(1.0, 0.0); m];
        let s = PackedSpectrum::transform(z, m / 10);
        // Two spectra of M/10 bins each: a fifth of the record, plus rows.
        assert!(
            s.heap_bytes() <= m * 16 / 5 + 16 * 700,
            "{}",
            s.heap_bytes()
        );
        // A constant: all of U in bin 0.
        assert!((s.bin(0).0.re - m as f64).abs() < 1e-9);
        assert!(s.bin(7).0.norm() < 1e-9);
    }
}
