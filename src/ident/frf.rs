//! Frequency-response (FRF) estimation from a chirp record: H1 estimator
//! with magnitude-squared coherence on a log-spaced grid with
//! frequency-dependent resolution (in the spirit of MATLAB `spafdr`), plus
//! the resonance finder and the CMP-CNMP phase test of the summary.
//!
//! # Method
//! 1. The whole record (lead-in, sweep, ring-down tail) of input `u[n]` (A)
//!    and output `y[n]` (m, probe offset removed) is zero-padded to a fast
//!    length `N` and transformed once: both channels packed as one complex
//!    signal `u + i·y` and transformed in the record's own memory by a
//!    four-step FFT ([`crate::ident::fft`], `rustfft` for the short
//!    transforms), giving `U[k]`, `Y[k]` up to the band's top, bin spacing
//!    `Δf = f_s / N`. Because the excitation
//!    starts and ends at rest, the record holds the complete response and the
//!    full-record transform needs no time window.
//! 2. At each grid frequency `f` the cross- and auto-spectra are averaged
//!    over neighbouring bins with a Hann (cos²) weight `w_k` of half width
//!    `h(f) = max(ρ f / 2, n_min Δf / 2)`, ρ the relative resolution:
//!    ```text
//!    S_uu = Σ w_k |U_k|²,  S_yy = Σ w_k |Y_k|²,  S_yu = Σ w_k Y_k U_k*
//!    H1(f) = S_yu / S_uu                              (m/A)
//!    γ²(f) = |S_yu|² / (S_uu S_yy)                    (0 … 1)
//!    ```
//!    (Bendat & Piersol, *Random Data*, §9.2; frequency-smoothed spectra as
//!    in Ljung, *System Identification*, §6.4.) Noise on `y` leaves H1
//!    unbiased and lowers γ²; γ² = 1 for a noise-free linear system.
//! 3. The phase is unwrapped along the grid.
//!
//! The grid is log-spaced with `points_per_decade` points from the sweep's
//! start to its end frequency, so resolution and density both scale with `f`.

use crate::config::IdentificationConfig;
use crate::ident::fft::PackedSpectrum;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::io::Write;
use std::path::Path;

/// Complex number type used for spectra.
pub use super::C64;

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
fn half_width_hz(relative_resolution: f64, min_bins: usize, bin_hz: f64, f_hz: f64) -> f64 {
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

/// Why an FRF could not be estimated from a record.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FrfError {
    /// A sample of the record is NaN or infinite.
    #[error(
        "the record's {channel} is not finite at sample {index} ({value}): a spectrum of it \
         would be NaN at every line"
    )]
    NonFiniteSample {
        /// `"input u (A)"` or `"output y (m)"`.
        channel: &'static str,
        /// Sample index (tick from the record's start).
        index: usize,
        /// The value.
        value: f64,
    },
    /// A DFT bin the estimate reads is NaN or infinite (a record that
    /// was not checked with [`check_record`]).
    #[error(
        "the spectrum of the record's {channel} is not finite at {frequency_hz:.4} Hz: the record \
         holds a NaN or infinite sample"
    )]
    NonFiniteSpectrum {
        /// `"input u (A)"` or `"output y (m)"`.
        channel: &'static str,
        /// The bin's frequency, Hz.
        frequency_hz: f64,
    },
    /// The band holds fewer DFT bins than the LPM's local window.
    #[error(
        "the record is too short for the LPM's local window: the band {f_lo_hz}–{f_hi_hz} Hz holds \
         {band_bins} DFT bins of {bin_hz:.4} Hz (the record's length is 1/{bin_hz:.4} Hz = \
         {record_s:.2} s), the window needs 2n + 1 = {window_bins} \
         (identification.lpm_half_width_bins = {half_width_bins}): lengthen the record \
         (chirp.duration_s, chirp.tail_s), widen the band, lower lpm_half_width_bins or use \
         identification.estimator = \"h1\""
    )]
    TooShort {
        /// Lowest grid frequency, Hz.
        f_lo_hz: f64,
        /// Highest grid frequency, Hz.
        f_hi_hz: f64,
        /// DFT bins in the band.
        band_bins: usize,
        /// Bin spacing, Hz.
        bin_hz: f64,
        /// `1 / bin_hz`, s (the padded record's length).
        record_s: f64,
        /// `2n + 1`.
        window_bins: usize,
        /// `n`.
        half_width_bins: usize,
    },
    /// LPM options that leave the local fit too few degrees of freedom.
    #[error(
        "identification.lpm_half_width_bins = {half_width_bins} with identification.lpm_degree = \
         {degree} leaves {dof} degrees of freedom for the noise variance (2n + 1 − 2(R + 1)); at \
         least 3 are needed: lpm_half_width_bins ≥ lpm_degree + 2"
    )]
    Options {
        /// `n`.
        half_width_bins: usize,
        /// `R`.
        degree: usize,
        /// `2n + 1 − 2(R + 1)` (negative: fewer bins than unknowns).
        dof: i64,
    },
}

/// Checks that every sample of a packed record `u[n] + i·y[n]` is finite.
///
/// # Errors
/// [`FrfError::NonFiniteSample`] naming the first channel and sample
/// that is not.
pub fn check_record(record: &[C64]) -> Result<(), FrfError> {
    for (index, z) in record.iter().enumerate() {
        for (channel, value) in [("input u (A)", z.re), ("output y (m)", z.im)] {
            if !value.is_finite() {
                return Err(FrfError::NonFiniteSample {
                    channel,
                    index,
                    value,
                });
            }
        }
    }
    Ok(())
}

/// A measured frequency response on a grid: one entry per line in every
/// column (all of equal length).
#[derive(Debug, Clone, Serialize)]
pub struct Frf {
    /// Grid, Hz (ascending).
    pub frequency_hz: Vec<f64>,
    /// |Ĥ|, m/A.
    pub magnitude_m_per_a: Vec<f64>,
    /// arg Ĥ, degrees, unwrapped along the grid.
    pub phase_deg: Vec<f64>,
    /// γ², 0 … 1: the magnitude-squared coherence of H1, or the LPM's
    /// signal-to-noise form `|Ĝ U|² / (|Ĝ U|² + σ̂²_V)`
    /// ([`crate::ident::lpm`]).
    pub coherence: Vec<f64>,
    /// 1σ of the complex response, `sqrt(E|Ĥ − H|²)` (circular complex
    /// noise: real and imaginary parts each carry half), m/A, estimated
    /// from the data: by the LPM from its residual
    /// ([`crate::ident::lpm`]), for H1 from the coherence
    /// ([`h1_sigma_m_per_a`]). NaN: unknown (an FRF read from the 4-column
    /// CSV or from a recording made before the column existed).
    pub sigma_m_per_a: Vec<f64>,
    /// Width of the band of DFT bins the line's estimate draws on, Hz:
    /// lines further apart than this have independent errors. LPM:
    /// `(2n + 1) Δf`; H1: the Hann window's full width `2 h(f)`. NaN:
    /// unknown (as for `sigma_m_per_a`).
    pub resolution_hz: Vec<f64>,
}

/// The columns of the FRF CSV, in order.
pub const CSV_COLUMNS: [&str; 6] = [
    "frequency_hz",
    "magnitude_m_per_a",
    "phase_deg",
    "coherence",
    "sigma_m_per_a",
    "resolution_hz",
];

/// The header of the FRF CSV `bench chirp` writes.
pub const CSV_HEADER: &str =
    "frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz";

/// The header of the 4-column FRF CSV of earlier versions, still read
/// (σ and resolution unknown).
pub const CSV_HEADER_4: &str = "frequency_hz,magnitude_m_per_a,phase_deg,coherence";

/// The 1σ of an H1 estimate from its coherence, m/A:
/// ```text
/// E|Ĥ1 − H|² ≈ |H|² (1 − γ²) / (γ² n_d)
/// ```
/// the sum of the gain's and the phase's random errors,
/// `ε[|Ĥ|] ≈ s.d.[φ̂] ≈ √(1 − γ²) / (|γ| √(2 n_d))` (Bendat & Piersol,
/// *Random Data*, 4th ed. 2010, ch. 9, errors of frequency response
/// function estimates), with `n_d` the equivalent number of averages
/// ([`Estimate::equivalent_averages`]). First order in the error: for
/// `γ² n_d ≫ 1`. Infinite for γ² = 0; NaN for a NaN response.
pub fn h1_sigma_m_per_a(response: C64, coherence: f64, equivalent_averages: f64) -> f64 {
    if coherence <= 0.0 || equivalent_averages <= 0.0 {
        return if response.norm().is_nan() {
            f64::NAN
        } else {
            f64::INFINITY
        };
    }
    response.norm() * ((1.0 - coherence).max(0.0) / (coherence * equivalent_averages)).sqrt()
}

/// Log-spaced grid from `f_lo` to `f_hi` (Hz) with `per_decade` points per
/// decade, both ends included.
pub fn log_grid(f_lo: f64, f_hi: f64, per_decade: usize) -> Vec<f64> {
    let decades = (f_hi / f_lo).log10();
    let n = ((decades * per_decade as f64).ceil() as usize).max(1);
    (0..=n)
        .map(|i| f_lo * (f_hi / f_lo).powf(i as f64 / n as f64))
        .collect()
}

/// Unwraps a phase sequence in degrees (jumps > 180° folded by 360°).
pub fn unwrap_deg(phase_deg: &mut [f64]) {
    let mut offset = 0.0;
    for i in 1..phase_deg.len() {
        let prev = phase_deg[i - 1];
        let mut cur = phase_deg[i] + offset;
        while cur - prev > 180.0 {
            cur -= 360.0;
            offset -= 360.0;
        }
        while cur - prev < -180.0 {
            cur += 360.0;
            offset += 360.0;
        }
        phase_deg[i] = cur;
    }
}

impl Frf {
    /// The unwrapped phase, degrees, at the first grid point at or above
    /// `frequency_hz` (the last one above the grid; NaN for an empty grid):
    /// the phase the verdict's phase test takes at the edges of its band.
    pub fn phase_at_deg(&self, frequency_hz: f64) -> f64 {
        let grid = &self.frequency_hz;
        if grid.is_empty() {
            return f64::NAN;
        }
        let i = grid
            .partition_point(|g| *g < frequency_hz)
            .min(grid.len() - 1);
        self.phase_deg[i]
    }

    /// Estimates the FRF with H1 on the log grid `f_lo … f_hi` (Hz), σ of
    /// each line from its coherence ([`h1_sigma_m_per_a`]), resolution
    /// the Hann window's full width `2 h(f)`.
    pub fn estimate(spectra: &Spectra, f_lo: f64, f_hi: f64, cfg: &IdentificationConfig) -> Self {
        let frequency_hz = log_grid(f_lo, f_hi, cfg.points_per_decade);
        let est: Vec<Estimate> = frequency_hz.iter().map(|&f| spectra.estimate(f)).collect();
        let mut phase_deg: Vec<f64> = est.iter().map(|e| e.response.arg().to_degrees()).collect();
        unwrap_deg(&mut phase_deg);
        Self {
            magnitude_m_per_a: est.iter().map(|e| e.response.norm()).collect(),
            coherence: est.iter().map(|e| e.coherence).collect(),
            sigma_m_per_a: est
                .iter()
                .map(|e| h1_sigma_m_per_a(e.response, e.coherence, e.equivalent_averages))
                .collect(),
            resolution_hz: frequency_hz
                .iter()
                .map(|&f| 2.0 * spectra.half_width_hz(f))
                .collect(),
            phase_deg,
            frequency_hz,
        }
    }

    /// Estimates the FRF on the log grid `f_lo … f_hi` (Hz) with the
    /// configured estimator (`cfg.estimator`): the LPM
    /// ([`crate::ident::lpm::estimate`]) or H1 ([`Self::estimate`]).
    ///
    /// # Errors
    /// The LPM's ([`FrfError`]); H1 has none.
    pub fn from_spectra(
        spectra: &Spectra,
        f_lo: f64,
        f_hi: f64,
        cfg: &IdentificationConfig,
    ) -> Result<Self, FrfError> {
        match cfg.estimator {
            crate::config::Estimator::Lpm => crate::ident::lpm::estimate(
                spectra,
                f_lo,
                f_hi,
                cfg.points_per_decade,
                &crate::ident::lpm::LpmOptions::from_config(cfg),
            ),
            crate::config::Estimator::H1 => Ok(Self::estimate(spectra, f_lo, f_hi, cfg)),
        }
    }

    /// An empty FRF (no lines).
    pub fn empty() -> Self {
        Self {
            frequency_hz: Vec::new(),
            magnitude_m_per_a: Vec::new(),
            phase_deg: Vec::new(),
            coherence: Vec::new(),
            sigma_m_per_a: Vec::new(),
            resolution_hz: Vec::new(),
        }
    }

    /// The lines for which `keep(i)` holds, every column alike.
    pub fn select(&self, mut keep: impl FnMut(usize) -> bool) -> Self {
        let mut out = Self::empty();
        for i in 0..self.frequency_hz.len() {
            if keep(i) {
                out.frequency_hz.push(self.frequency_hz[i]);
                out.magnitude_m_per_a.push(self.magnitude_m_per_a[i]);
                out.phase_deg.push(self.phase_deg[i]);
                out.coherence.push(self.coherence[i]);
                out.sigma_m_per_a.push(self.sigma_m_per_a[i]);
                out.resolution_hz.push(self.resolution_hz[i]);
            }
        }
        out
    }

    /// The complex response of line `i`, m/A (from magnitude and phase).
    pub fn response(&self, i: usize) -> C64 {
        C64::from_polar(self.magnitude_m_per_a[i], self.phase_deg[i].to_radians())
    }

    /// Writes the CSV
    /// `frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz`
    /// ([`CSV_HEADER`]) to `path` through a temporary file renamed when complete
    /// ([`outputs::write_atomically`](crate::outputs::write_atomically)):
    /// a failed write leaves nothing under `path`, and an existing `path`
    /// is replaced only with [`Existing::Replace`](crate::outputs::Existing::Replace).
    ///
    /// # Errors
    /// I/O errors from creating, writing or renaming the file.
    pub fn write_csv(
        &self,
        path: &Path,
        existing: crate::outputs::Existing,
    ) -> std::io::Result<()> {
        crate::outputs::write_atomically(path, existing, |f| {
            let mut w = std::io::BufWriter::new(f);
            self.write_csv_to(&mut w)?;
            w.flush()
        })
    }

    /// Reads the CSV `bench chirp` writes ([`CSV_HEADER`]:
    /// `frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz`),
    /// or the 4-column one of earlier versions ([`CSV_HEADER_4`], without
    /// the last two: σ and resolution are then NaN, unknown), checking
    /// every field: frequencies positive, finite and ascending; magnitudes
    /// positive and finite; phases finite; coherence in 0 … 1; σ finite and
    /// ≥ 0; resolution finite and > 0; at least [`MIN_CSV_POINTS`] rows.
    ///
    /// # Errors
    /// The reason, naming the line (1-based, the header is line 1) and the
    /// column.
    pub fn read_csv(text: &str) -> Result<Self, String> {
        let mut lines = text.lines();
        let columns = match lines.next() {
            Some(h) if h.trim_end() == CSV_HEADER => 6,
            Some(h) if h.trim_end() == CSV_HEADER_4 => 4,
            Some(h) => {
                return Err(format!(
                    "line 1: the header is {h:?}, not {CSV_HEADER} (the CSV bench chirp writes) \
                     or {CSV_HEADER_4} (that of earlier versions)"
                ))
            }
            None => {
                return Err(format!(
                    "the file is empty (expected the header {CSV_HEADER})"
                ))
            }
        };
        let mut frf = Self::empty();
        for (i, line) in lines.enumerate() {
            let n = i + 2;
            if line.trim().is_empty() {
                continue;
            }
            let fields: Vec<&str> = line.split(',').collect();
            if fields.len() != columns {
                return Err(format!(
                    "line {n}: {} fields, expected {columns} ({})",
                    fields.len(),
                    CSV_COLUMNS[..columns].join(",")
                ));
            }
            let mut v = [f64::NAN; 6];
            for (j, f) in fields.iter().enumerate() {
                v[j] = f.trim().parse::<f64>().map_err(|e| {
                    format!(
                        "line {n}: {}: {:?} is not a number ({e})",
                        CSV_COLUMNS[j],
                        f.trim()
                    )
                })?;
                if j >= 4 && !v[j].is_finite() {
                    return Err(format!(
                        "line {n}: {}: {} is not finite (only the 4-column CSV leaves it unknown)",
                        CSV_COLUMNS[j], v[j]
                    ));
                }
            }
            frf.push_checked(v).map_err(|e| format!("line {n}: {e}"))?;
        }
        if frf.frequency_hz.len() < MIN_CSV_POINTS {
            return Err(format!(
                "{} data lines; an FRF needs at least {MIN_CSV_POINTS}",
                frf.frequency_hz.len()
            ));
        }
        Ok(frf)
    }

    /// Appends the point `[frequency_hz, magnitude_m_per_a, phase_deg,
    /// coherence, sigma_m_per_a, resolution_hz]` after checking it: the
    /// first four finite, frequency positive and above the last one,
    /// magnitude positive, coherence in 0 … 1; σ NaN (unknown) or finite
    /// and ≥ 0; resolution NaN (unknown) or finite and > 0.
    ///
    /// # Errors
    /// The reason, naming the column; nothing is appended.
    pub fn push_checked(&mut self, v: [f64; 6]) -> Result<(), String> {
        if let Some(j) = v[..4].iter().position(|x| !x.is_finite()) {
            return Err(format!("{}: {} is not finite", CSV_COLUMNS[j], v[j]));
        }
        if v[0] <= 0.0 {
            return Err(format!("frequency_hz: {} is not positive", v[0]));
        }
        if let Some(last) = self.frequency_hz.last().filter(|f| **f >= v[0]) {
            return Err(format!(
                "frequency_hz: {} does not ascend (the point before has {last})",
                v[0]
            ));
        }
        if v[1] <= 0.0 {
            return Err(format!("magnitude_m_per_a: {} is not positive", v[1]));
        }
        if !(0.0..=1.0).contains(&v[3]) {
            return Err(format!("coherence: {} is outside 0 … 1", v[3]));
        }
        if !(v[4].is_nan() || (v[4].is_finite() && v[4] >= 0.0)) {
            return Err(format!(
                "sigma_m_per_a: {} is not a standard deviation (finite, ≥ 0)",
                v[4]
            ));
        }
        if !(v[5].is_nan() || (v[5].is_finite() && v[5] > 0.0)) {
            return Err(format!(
                "resolution_hz: {} is not a band width (finite, > 0)",
                v[5]
            ));
        }
        self.frequency_hz.push(v[0]);
        self.magnitude_m_per_a.push(v[1]);
        self.phase_deg.push(v[2]);
        self.coherence.push(v[3]);
        self.sigma_m_per_a.push(v[4]);
        self.resolution_hz.push(v[5]);
        Ok(())
    }

    /// Writes the CSV rows (with the header [`CSV_HEADER`]) to `w`.
    ///
    /// # Errors
    /// The writer's.
    pub fn write_csv_to(&self, w: &mut impl Write) -> std::io::Result<()> {
        writeln!(w, "{CSV_HEADER}")?;
        for i in 0..self.frequency_hz.len() {
            writeln!(
                w,
                "{:.6},{:.6e},{:.3},{:.5},{:.6e},{:.6e}",
                self.frequency_hz[i],
                self.magnitude_m_per_a[i],
                self.phase_deg[i],
                self.coherence[i],
                self.sigma_m_per_a[i],
                self.resolution_hz[i]
            )?;
        }
        w.flush()
    }
}

/// Fewest rows of an FRF CSV.
pub const MIN_CSV_POINTS: usize = 10;

/// A resonance found in a measured FRF.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Resonance {
    /// Peak frequency, Hz (refined between grid points; in `bench chirp`'s
    /// summary the fitted natural frequency).
    pub frequency_hz: f64,
    /// Peak magnitude, m/A.
    pub magnitude_m_per_a: f64,
    /// Damping ratio: in `bench chirp`'s summary the modal fit's; from
    /// [`find_resonances`] the half-power (−3 dB) bandwidth,
    /// `ζ ≈ (f₊ − f₋) / (2 f_n)`, when both half-power points are found
    /// before a neighbouring feature.
    pub damping_ratio: Option<f64>,
    /// Peak height above the lower of the two flanking minima, dB.
    pub prominence_db: f64,
}

/// Smallest magnitude-squared coherence γ² at which an FRF point is taken
/// as data: a resonance must peak at or above it, and the Bode plot draws
/// the points below it faint (at γ² = 0.5 as much of the output power is
/// noise or nonlinearity as is explained by the input; Bendat & Piersol,
/// *Random Data*, §9.2.3).
pub const MIN_COHERENCE: f64 = 0.5;

/// Relative distance at which a lightly damped peak must have dropped by
/// [`SHARPNESS_DB`] on at least one side.
pub const SHARPNESS_SPAN: f64 = 0.03;
/// Drop required within ±[`SHARPNESS_SPAN`] of a peak, dB.
pub const SHARPNESS_DB: f64 = 3.0;

/// Finds lightly damped resonances: local maxima of |H| on the grid that
/// rise at least `min_prominence_db` above the higher of the two flanking
/// minima, have coherence ≥ [`MIN_COHERENCE`], and are sharp — |H| is at least
/// [`SHARPNESS_DB`] lower at `f·(1 ± SHARPNESS_SPAN)` on one side or the
/// other (a single mode passes this for ζ ≲ 0.03; the broad hump that
/// follows an anti-resonance does not). Each peak is then refined on a
/// quarter-bin sweep of the lightly smoothed estimate, and its damping is
/// estimated from the half-power bandwidth.
pub fn find_resonances(frf: &Frf, spectra: &Spectra, min_prominence_db: f64) -> Vec<Resonance> {
    let db: Vec<f64> = frf
        .magnitude_m_per_a
        .iter()
        .map(|m| {
            if *m > 0.0 {
                20.0 * m.log10()
            } else {
                f64::NEG_INFINITY
            }
        })
        .collect();
    let n = db.len();
    let mut out = Vec::new();
    for i in 1..n.saturating_sub(1) {
        if !(db[i] > db[i - 1] && db[i] >= db[i + 1]) || frf.coherence[i] < MIN_COHERENCE {
            continue;
        }
        // Flanking minima: walk down until the curve rises above the peak.
        let flank = |range: &mut dyn Iterator<Item = usize>| {
            let mut lowest = db[i];
            for j in range {
                if db[j] > db[i] {
                    break;
                }
                lowest = lowest.min(db[j]);
            }
            lowest
        };
        let left = flank(&mut (0..i).rev());
        let right = flank(&mut (i + 1..n));
        let prominence = db[i] - left.max(right);
        if prominence < min_prominence_db {
            continue;
        }
        let f = frf.frequency_hz[i];
        let db_at = |x: f64| {
            let j = frf.frequency_hz.partition_point(|g| *g < x).min(n - 1);
            db[j]
        };
        let drop = (db[i] - db_at(f * (1.0 - SHARPNESS_SPAN)))
            .max(db[i] - db_at(f * (1.0 + SHARPNESS_SPAN)));
        if drop < SHARPNESS_DB {
            continue;
        }
        out.push(refine_peak(frf, spectra, i, prominence));
    }
    out
}

fn refine_peak(frf: &Frf, spectra: &Spectra, i: usize, prominence_db: f64) -> Resonance {
    let f = &frf.frequency_hz;
    let (lo, hi) = (f[i - 1], f[i + 1]);
    // Light smoothing (3 bins) so the peak is not flattened by the window.
    let hw = 1.5 * spectra.bin_hz();
    let mag = |x: f64| spectra.estimate_with(x, hw).response.norm();
    let step = spectra.bin_hz() / 4.0;
    let (mut best_f, mut best_m) = (f[i], mag(f[i]));
    let mut x = lo;
    while x <= hi {
        let m = mag(x);
        if m > best_m {
            best_m = m;
            best_f = x;
        }
        x += step;
    }
    // Parabolic interpolation of |H| in dB around the best sample.
    let (a, b, c) = (
        20.0 * mag(best_f - step).log10(),
        20.0 * best_m.log10(),
        20.0 * mag(best_f + step).log10(),
    );
    let denom = a - 2.0 * b + c;
    if denom < 0.0 {
        best_f += 0.5 * step * (a - c) / denom;
    }
    // Half-power points: walk out until |H| < peak/√2, stop at a rise.
    let target = best_m / 2f64.sqrt();
    let walk = |dir: f64| -> Option<f64> {
        let mut prev = best_m;
        let mut x = best_f;
        for _ in 0..20_000 {
            x += dir * step;
            let m = mag(x);
            if m < target {
                // Linear interpolation between the last two samples.
                let frac = (prev - target) / (prev - m);
                return Some(x - dir * step * (1.0 - frac));
            }
            if m > prev * 1.05 {
                return None;
            }
            prev = m;
        }
        None
    };
    let damping_ratio = match (walk(-1.0), walk(1.0)) {
        (Some(f1), Some(f2)) => Some((f2 - f1) / (2.0 * best_f)),
        _ => None,
    };
    Resonance {
        frequency_hz: best_f,
        magnitude_m_per_a: best_m,
        damping_ratio,
        prominence_db,
    }
}

/// The phase test for CMP-CNMP zeros across a closely spaced pair.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct PairVerdict {
    /// Lower mode of the pair, Hz.
    pub lower_hz: f64,
    /// Upper mode of the pair, Hz.
    pub upper_hz: f64,
    /// Band over which the net phase is taken, Hz.
    pub band_hz: (f64, f64),
    /// Net phase change over the band, degrees (unwrapped).
    pub net_phase_deg: f64,
    /// Net phase rounded to a multiple of 180°.
    pub net_phase_multiple_deg: f64,
    /// `true`: two poles and no net phase from the zeros between them —
    /// the −360° signature of CMP-CNMP zeros (thesis §2.2.2, Fig 5-9b).
    pub cmp_cnmp: bool,
}

pub use crate::analysis::modal::CLOSE_PAIR_RATIO;

/// The FRF and the bench config a `bench chirp` recording holds.
#[derive(Debug, Clone)]
pub struct RecordedFrf {
    /// `/sysid/frf` (the last one if several).
    pub frf: Frf,
    /// The `toml` entry of the `bench.config` metadata record (the
    /// resolved config), if present.
    pub config_toml: Option<String>,
    /// The `source` entry of the `bench.config` metadata record (the
    /// config file's text as given, comments and all, before the command
    /// line's overrides), if present.
    pub config_source: Option<String>,
}

/// Reads the `/sysid/frf` message and the `bench.config` metadata of the
/// recording in `bytes` (complete, or the `.part` of a killed run).
///
/// # Errors
/// The reason: not a readable MCAP, no `/sysid/frf` channel (with the
/// topics it has), or a `/sysid/frf` payload that is not an FRF (naming
/// the field).
pub fn read_frf(bytes: &[u8]) -> Result<RecordedFrf, String> {
    #[derive(serde::Deserialize)]
    struct Payload {
        frequency_hz: Vec<f64>,
        magnitude_m_per_a: Vec<f64>,
        phase_deg: Vec<f64>,
        coherence: Vec<f64>,
        // Absent in recordings made before the columns existed; a
        // non-finite value is written as null.
        #[serde(default)]
        sigma_m_per_a: Option<Vec<Option<f64>>>,
        #[serde(default)]
        resolution_hz: Option<Vec<Option<f64>>>,
    }
    let read = crate::record::read_messages_tolerant(bytes);
    if read.messages.is_empty() {
        return Err(match read.error {
            Some(e) => format!("not a readable MCAP recording: {e}"),
            None => "no messages: an empty recording".into(),
        });
    }
    let Some(msg) = read
        .messages
        .iter()
        .rev()
        .find(|m| m.channel.topic == crate::record::TOPIC_FRF)
    else {
        let topics = read.topics();
        return Err(format!(
            "no {} channel (a bench chirp recording has one; this one has {})",
            crate::record::TOPIC_FRF,
            topics.join(", ")
        ));
    };
    let p: Payload = serde_json::from_slice(&msg.data).map_err(|e| {
        format!(
            "{}: the payload is not an FRF: {e}",
            crate::record::TOPIC_FRF
        )
    })?;
    let n = p.frequency_hz.len();
    let unknown = |v: Option<Vec<Option<f64>>>| -> Vec<f64> {
        v.map(|v| v.into_iter().map(|x| x.unwrap_or(f64::NAN)).collect())
            .unwrap_or_else(|| vec![f64::NAN; n])
    };
    let sigma = unknown(p.sigma_m_per_a);
    let resolution = unknown(p.resolution_hz);
    for (name, len) in [
        ("magnitude_m_per_a", p.magnitude_m_per_a.len()),
        ("phase_deg", p.phase_deg.len()),
        ("coherence", p.coherence.len()),
        ("sigma_m_per_a", sigma.len()),
        ("resolution_hz", resolution.len()),
    ] {
        if len != n {
            return Err(format!(
                "{}: {name} has {len} values for {n} frequencies",
                crate::record::TOPIC_FRF
            ));
        }
    }
    let mut frf = Frf::empty();
    for k in 0..n {
        frf.push_checked([
            p.frequency_hz[k],
            p.magnitude_m_per_a[k],
            p.phase_deg[k],
            p.coherence[k],
            sigma[k],
            resolution[k],
        ])
        .map_err(|e| format!("{}: point {}: {e}", crate::record::TOPIC_FRF, k + 1))?;
    }
    if n < MIN_CSV_POINTS {
        return Err(format!(
            "{}: {n} points; an FRF needs at least {}",
            crate::record::TOPIC_FRF,
            MIN_CSV_POINTS
        ));
    }
    let config = mcap::read::LinearReader::new_with_options(
        bytes,
        mcap::read::Options::IgnoreEndMagic.into(),
    )
    .ok()
    .and_then(|r| {
        r.filter_map(Result::ok).find_map(|rec| match rec {
            mcap::records::Record::Metadata(m) if m.name == "bench.config" => Some(m.metadata),
            _ => None,
        })
    });
    Ok(RecordedFrf {
        frf,
        config_toml: config.as_ref().and_then(|m| m.get("toml").cloned()),
        config_source: config.and_then(|mut m| m.remove("source")),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A second-order system driven by white noise: the estimate matches the
    /// analytic FRF (independent reference) and coherence tracks the SNR.
    #[test]
    fn h1_of_a_known_filter() {
        use rand::{Rng, SeedableRng};
        let fs = 1000.0;
        let n = 200_000;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let u: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        // y[n] = u[n] − 0.5 u[n−1]: H(e^{jω}) = 1 − 0.5 e^{−jω}.
        let y: Vec<f64> = (0..n)
            .map(|k| u[k] - if k > 0 { 0.5 * u[k - 1] } else { 0.0 })
            .collect();
        let cfg = IdentificationConfig {
            points_per_decade: 50,
            relative_resolution: 0.05,
            min_bins: 31,
            ..IdentificationConfig::default()
        };
        let s = Spectra::new(&u, &y, fs, &cfg);
        let frf = Frf::estimate(&s, 1.0, 400.0, &cfg);
        for (i, f) in frf.frequency_hz.iter().enumerate() {
            let w = 2.0 * PI * f / fs;
            let h = C64::new(1.0 - 0.5 * w.cos(), 0.5 * w.sin());
            assert!(
                (frf.magnitude_m_per_a[i] / h.norm() - 1.0).abs() < 0.02,
                "{f} Hz"
            );
            let dphi = frf.phase_deg[i] - h.arg().to_degrees();
            assert!(dphi.abs() < 1.0, "{f} Hz phase {dphi}");
            assert!(frf.coherence[i] > 0.999);
        }
        // With output noise of equal power, γ² ≈ |H|²/(|H|²+σ²/σu²).
        let ynoisy: Vec<f64> = y.iter().map(|v| v + rng.random_range(-1.0..1.0)).collect();
        let s = Spectra::new(&u, &ynoisy, fs, &cfg);
        // With random excitation the coherence-based σ is honest: the mean
        // of |Ĥ − H|²/σ² over the lines is 1 (lines overlap by about one
        // window, so ~130 lines give a spread of ~10 %).
        let frf = Frf::estimate(&s, 1.0, 400.0, &cfg);
        let mut ratio = 0.0;
        for (i, f) in frf.frequency_hz.iter().enumerate() {
            let w = 2.0 * PI * f / fs;
            let h = C64::new(1.0 - 0.5 * w.cos(), 0.5 * w.sin());
            ratio += (frf.response(i) - h).norm_sqr() / frf.sigma_m_per_a[i].powi(2);
            assert!((frf.resolution_hz[i] - 2.0 * s.half_width_hz(*f)).abs() < 1e-12);
        }
        let ratio = ratio / frf.frequency_hz.len() as f64;
        assert!((0.75..=1.25).contains(&ratio), "mean |ΔH|²/σ² = {ratio}");
        let e = s.estimate(250.0);
        let h2 = C64::new(1.0 - 0.5 * (PI / 2.0).cos(), 0.5 * (PI / 2.0).sin()).norm_sqr();
        let expected = h2 / (h2 + 1.0);
        assert!(
            (e.coherence - expected).abs() < 0.05,
            "{} vs {expected}",
            e.coherence
        );
    }

    /// An FRF of a few lines with σ and resolution.
    fn small_frf() -> Frf {
        let mut frf = Frf::empty();
        for i in 0..12 {
            let f = 1.0 + i as f64;
            frf.push_checked([f, 1e-4 / f, -10.0 * f, 0.9, 1e-6 / f, 0.2])
                .unwrap();
        }
        frf
    }

    #[test]
    fn the_csv_round_trips_and_the_four_column_form_still_reads() {
        let frf = small_frf();
        let mut out = Vec::new();
        frf.write_csv_to(&mut out).unwrap();
        let text = String::from_utf8(out).unwrap();
        assert!(text.starts_with(
            "frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz\n"
        ));
        let back = Frf::read_csv(&text).unwrap();
        for i in 0..12 {
            assert!((back.sigma_m_per_a[i] / frf.sigma_m_per_a[i] - 1.0).abs() < 1e-6);
            assert!((back.resolution_hz[i] - 0.2).abs() < 1e-9);
        }
        // The 4-column form: σ and resolution unknown (NaN).
        let four: String = text
            .lines()
            .map(|l| l.split(',').take(4).collect::<Vec<_>>().join(",") + "\n")
            .collect();
        let old = Frf::read_csv(&four).unwrap();
        assert_eq!(old.frequency_hz, back.frequency_hz);
        assert!(old.sigma_m_per_a.iter().all(|s| s.is_nan()));
        assert!(old.resolution_hz.iter().all(|r| r.is_nan()));
        // In the 6-column form σ and resolution must be given.
        for (from, to, col) in [
            (",1.000000e-6,", ",NaN,", "sigma_m_per_a"),
            (",1.000000e-6,", ",-1e-9,", "sigma_m_per_a"),
            (",2.000000e-1\n", ",0\n", "resolution_hz"),
            (",2.000000e-1\n", ",inf\n", "resolution_hz"),
        ] {
            assert!(text.contains(from), "{from}");
            let e = Frf::read_csv(&text.replacen(from, to, 1)).unwrap_err();
            assert!(e.starts_with("line 2: ") && e.contains(col), "{to}: {e}");
        }
        // Four fields under the 6-column header, six under the 4-column one.
        let e = Frf::read_csv(&text.replacen(",1.000000e-6,2.000000e-1", "", 1)).unwrap_err();
        assert!(e.starts_with("line 2: 4 fields, expected 6"), "{e}");
        let mixed = four.replacen("1.000000,", "1.000000,1,1,", 2);
        assert!(Frf::read_csv(&mixed).is_err());
    }

    /// A recording written before σ and resolution existed: `read_frf`
    /// gives them as unknown (NaN); one with them (a null: unknown too)
    /// reads them back.
    #[test]
    fn recordings_with_and_without_sigma_read() {
        let write = |payload: serde_json::Value| -> Vec<u8> {
            let mut buf = std::io::Cursor::new(Vec::new());
            {
                let mut w = mcap::Writer::new(&mut buf).unwrap();
                let ch = w
                    .add_channel(
                        0,
                        crate::record::TOPIC_FRF,
                        "json",
                        &std::collections::BTreeMap::new(),
                    )
                    .unwrap();
                w.write_to_known_channel(
                    &mcap::records::MessageHeader {
                        channel_id: ch,
                        sequence: 0,
                        log_time: 1,
                        publish_time: 1,
                    },
                    &serde_json::to_vec(&payload).unwrap(),
                )
                .unwrap();
                w.finish().unwrap();
            }
            buf.into_inner()
        };
        let frf = small_frf();
        let old = serde_json::json!({
            "frequency_hz": frf.frequency_hz,
            "magnitude_m_per_a": frf.magnitude_m_per_a,
            "phase_deg": frf.phase_deg,
            "coherence": frf.coherence,
        });
        let r = read_frf(&write(old.clone())).unwrap().frf;
        assert_eq!(r.frequency_hz, frf.frequency_hz);
        assert!(r.sigma_m_per_a.iter().all(|s| s.is_nan()));
        assert!(r.resolution_hz.iter().all(|s| s.is_nan()));
        let mut new = old.clone();
        let mut sigma: Vec<serde_json::Value> =
            frf.sigma_m_per_a.iter().map(|s| (*s).into()).collect();
        sigma[3] = serde_json::Value::Null;
        new["sigma_m_per_a"] = sigma.into();
        new["resolution_hz"] = frf.resolution_hz.clone().into();
        let r = read_frf(&write(new.clone())).unwrap().frf;
        assert_eq!(r.sigma_m_per_a[0], frf.sigma_m_per_a[0]);
        assert!(r.sigma_m_per_a[3].is_nan());
        assert_eq!(r.resolution_hz, frf.resolution_hz);
        // Wrong lengths and values are refused naming the field.
        new["resolution_hz"] = vec![0.2; 3].into();
        let e = read_frf(&write(new.clone())).unwrap_err();
        assert!(e.contains("resolution_hz has 3 values"), "{e}");
        new["resolution_hz"] = vec![-0.2; 12].into();
        let e = read_frf(&write(new)).unwrap_err();
        assert!(e.contains("point 1: resolution_hz"), "{e}");
    }

    #[test]
    fn unwrap_and_grid() {
        let mut p = vec![170.0, -170.0, -10.0, 175.0, -175.0];
        unwrap_deg(&mut p);
        // Each step takes the representative nearest the previous value.
        assert_eq!(p, vec![170.0, 190.0, 350.0, 175.0, 185.0]);
        let g = log_grid(1.0, 1000.0, 10);
        assert_eq!(g.len(), 31);
        assert!((g[10] - 10.0).abs() < 1e-9 && (g[30] - 1000.0).abs() < 1e-9);
        assert_eq!(fast_len(7), 8);
        assert_eq!(fast_len(121), 125);
    }
}
