//! The spectra of a record and the H1 estimate with its coherence at any
//! frequency (steps 1–3 of the [module docs](super)).

use super::*;

/// The spectra of one record, ready to be averaged at any frequency up to
/// the one it was made for.
#[derive(Debug, Clone)]
pub struct Spectra {
    spectrum: PackedSpectrum,
    bin_hz: f64,
    relative_resolution: f64,
    min_bins: usize,
}

/// A smoothed estimate at one frequency.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// H1 = S_yu / S_uu, m/A.
    pub response: C64,
    /// Magnitude-squared coherence, 0 … 1.
    pub coherence: f64,
    /// Equivalent number of averages of the Hann weights,
    /// `n_d = (Σ w_k)² / Σ w_k²` (bins; 1 for a single bin).
    pub equivalent_averages: f64,
}

/// Smallest `n ≥ len` of the form 2^a 3^b 5^c (fast FFT sizes; the record
/// is zero-padded to it, so a record reserves this many ticks).
pub fn fast_len(len: usize) -> usize {
    let mut n = len.max(2);
    loop {
        let mut m = n;
        for p in [2, 3, 5] {
            while m.is_multiple_of(p) {
                m /= p;
            }
        }
        if m == 1 {
            return n;
        }
        n += 1;
    }
}

/// Half width of the smoothing window at `f`, Hz: `max(ρ f / 2, n_min Δf / 2)`.
pub(super) fn half_width_hz(
    relative_resolution: f64,
    min_bins: usize,
    bin_hz: f64,
    f_hz: f64,
) -> f64 {
    (0.5 * relative_resolution * f_hz).max(0.5 * min_bins as f64 * bin_hz)
}

impl Spectra {
    /// Transforms the record, keeping every bin up to Nyquist. `u` (A) and
    /// `y` (m) are sampled at `rate_hz`.
    ///
    /// # Panics
    /// If `u` and `y` differ in length.
    pub fn new(u: &[f64], y: &[f64], rate_hz: f64, cfg: &IdentificationConfig) -> Self {
        assert_eq!(
            u.len(),
            y.len(),
            "input and output records differ in length"
        );
        let mut record = Vec::with_capacity(fast_len(u.len()));
        record.extend(u.iter().zip(y).map(|(a, b)| C64::new(*a, *b)));
        Self::from_record(record, rate_hz, cfg, f64::INFINITY)
    }

    /// Transforms a packed record `u[n] + i·y[n]` (A, m; sampled at
    /// `rate_hz`) in its own memory ([`crate::ident::fft`]): zero-padded to
    /// [`fast_len`] (within the reserved capacity if the caller reserved
    /// it), and only the bins that estimates up to `f_max_hz` read are kept.
    /// Peak memory: the record's 16 bytes a tick plus `O(√N)`.
    pub fn from_record(
        mut record: Vec<C64>,
        rate_hz: f64,
        cfg: &IdentificationConfig,
        f_max_hz: f64,
    ) -> Self {
        let n = fast_len(record.len());
        record.resize(n, C64::new(0.0, 0.0));
        let bin_hz = rate_hz / n as f64;
        let k_max = if f_max_hz.is_finite() {
            let top_hz =
                f_max_hz + half_width_hz(cfg.relative_resolution, cfg.min_bins, bin_hz, f_max_hz);
            // H1's window, or the LPM's 2n + 1 bins around the nearest bin.
            ((top_hz / bin_hz).ceil() as usize + 1)
                .max((f_max_hz / bin_hz).round() as usize + cfg.lpm_half_width_bins + 1)
        } else {
            n / 2
        };
        Self {
            spectrum: PackedSpectrum::transform(record, k_max),
            bin_hz,
            relative_resolution: cfg.relative_resolution,
            min_bins: cfg.min_bins,
        }
    }

    /// DFT bin spacing, Hz.
    pub fn bin_hz(&self) -> f64 {
        self.bin_hz
    }

    /// Highest DFT bin kept (the estimates read bins `0 ..= k_max`).
    pub fn k_max(&self) -> usize {
        self.spectrum.k_max()
    }

    /// `(U[k], Y[k])`: the unnormalised DFTs of the input (A) and the
    /// output (m) at bin `k` (`Σ x[n] e^(−2πi kn/N)`), `N` the padded
    /// record length.
    ///
    /// # Panics
    /// If `k > k_max`.
    pub fn bin(&self, k: usize) -> (C64, C64) {
        self.spectrum.bin(k)
    }

    /// Half width of the smoothing window at `f`, Hz.
    pub fn half_width_hz(&self, frequency_hz: f64) -> f64 {
        half_width_hz(
            self.relative_resolution,
            self.min_bins,
            self.bin_hz,
            frequency_hz,
        )
    }

    /// The smoothed H1 estimate and coherence at `frequency_hz` with the
    /// configured resolution.
    pub fn estimate(&self, frequency_hz: f64) -> Estimate {
        self.estimate_with(frequency_hz, self.half_width_hz(frequency_hz))
    }

    /// The smoothed estimate with an explicit half width, Hz.
    pub fn estimate_with(&self, frequency_hz: f64, half_width_hz: f64) -> Estimate {
        let lo = ((frequency_hz - half_width_hz) / self.bin_hz)
            .ceil()
            .max(0.0) as usize;
        let top = ((frequency_hz + half_width_hz) / self.bin_hz).floor() as usize;
        let nyquist = self.spectrum.fft_len() / 2;
        if top > self.spectrum.k_max() && self.spectrum.k_max() < nyquist {
            // Above the band the spectra were kept for.
            return Estimate {
                response: C64::new(f64::NAN, f64::NAN),
                coherence: 0.0,
                equivalent_averages: 0.0,
            };
        }
        let hi = top.min(self.spectrum.k_max());
        let (mut suu, mut syy, mut syu) = (0.0, 0.0, C64::new(0.0, 0.0));
        let (mut sw, mut sw2) = (0.0, 0.0);
        for k in lo..=hi {
            let d = (k as f64 * self.bin_hz - frequency_hz) / half_width_hz;
            let w = (0.5 * PI * d).cos().powi(2);
            sw += w;
            sw2 += w * w;
            let (u, y) = self.spectrum.bin(k);
            suu += w * u.norm_sqr();
            syy += w * y.norm_sqr();
            syu += y * u.conj() * w;
        }
        if suu <= 0.0 {
            return Estimate {
                response: C64::new(f64::NAN, f64::NAN),
                coherence: 0.0,
                equivalent_averages: 0.0,
            };
        }
        let coherence = if syy > 0.0 {
            (syu.norm_sqr() / (suu * syy)).min(1.0)
        } else {
            0.0
        };
        Estimate {
            response: syu / suu,
            coherence,
            equivalent_averages: sw * sw / sw2,
        }
    }
}
