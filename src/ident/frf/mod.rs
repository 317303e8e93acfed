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

mod csv;
mod recorded;
mod resonance;
mod spectra;
pub use csv::*;
pub use recorded::*;
pub use resonance::*;
pub use spectra::*;
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
    /// Degrees of freedom of the variance `σ̂²` behind `sigma_m_per_a`
    /// (real, as of a χ²): `σ̂²/σ² ~ χ²_d / d`. A multisine's BLA from M
    /// realizations: `2(M − 1)` (one realization: `2(P − 1)` from its P
    /// periods). Infinite: the variance is known, or weighted as known:
    /// H1, whose σ is the first-order formula from the coherence
    /// ([`h1_sigma_m_per_a`], its own interval [`h1_radius_95`]), and the
    /// LPM, whose σ̂ has `2q` degrees of freedom but also holds the local
    /// polynomials' approximation error, so that the fits on it follow
    /// the known-variance law (`crate::ident::lpm::estimate`). NaN: not
    /// stated (an FRF read from a CSV or a recording made before the
    /// column existed), taken as known. A residual against σ̂ then follows
    /// `|Ĥ − H|²/σ̂² ~ F(2, d)`, not `χ²₂/2` ([`radius_95`]).
    pub sigma_dof: Vec<f64>,
}

/// Fewest degrees of freedom of a line's variance estimate that a fit
/// weights with (6: M = 4 realizations of a multisine). With `d` degrees
/// of freedom the cost of a fit weighted by `1/σ̂²` has the expectation
/// `d/(d − 2)` and the variance `d³/((d − 2)²(d − 4))` times those of a
/// known variance (`F(2, d)` per line) and its parameters' covariance
/// `(d − 2)/(d − 4)` times (Pintelon & Schoukens, *System
/// Identification*, 2nd ed. 2012, §10.3, the sample maximum likelihood
/// estimator: `(M − 1)/(M − 2)` and `(M − 2)/(M − 3)` at `d = 2(M − 1)`):
/// at `d ≤ 4` the cost test and the covariance have no finite reference.
pub const MIN_SIGMA_DOF: f64 = 6.0;

/// Radius of the 95 % confidence circle of a response whose complex 1σ
/// `sigma` (m/A, `√E|Ĥ − H|²`) is estimated with `dof` real degrees of
/// freedom ([`Frf::sigma_dof`]; infinite or NaN: known), in the unit of
/// `sigma`: `|Ĥ − H|²/σ̂² ~ F(2, d)`, whose quantile is closed-form,
/// `F(2, d; p) = (d/2)((1 − p)^{−2/d} − 1)`, and `−ln(1 − p)` for a known
/// variance. So `r = 2.27 σ̂` at `d = 6` (a multisine's four
/// realizations), `1.73 σ̂` for a known variance (Pintelon & Schoukens
/// 2012, ch. 4; the H1 form is [`h1_radius_95`]). Infinite for `dof` ≤ 0.
pub fn radius_95(sigma: f64, dof: f64) -> f64 {
    let p = 0.95f64;
    let f = if dof.is_nan() || dof.is_infinite() {
        -(1.0 - p).ln()
    } else if dof > 0.0 {
        0.5 * dof * ((1.0 - p).powf(-2.0 / dof) - 1.0)
    } else {
        f64::INFINITY
    };
    sigma * f.sqrt()
}

/// The columns of the FRF CSV, in order.
pub const CSV_COLUMNS: [&str; 7] = [
    "frequency_hz",
    "magnitude_m_per_a",
    "phase_deg",
    "coherence",
    "sigma_m_per_a",
    "resolution_hz",
    "sigma_dof",
];

/// The header of the FRF CSV `bench chirp` writes.
pub const CSV_HEADER: &str =
    "frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz,sigma_dof";

/// The header of the 6-column FRF CSV of earlier versions, still read
/// (σ's degrees of freedom not stated: taken as known).
pub const CSV_HEADER_6: &str =
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

/// Radius of the 95 % confidence circle of an H1 estimate, in the unit
/// of `response`: the finite-sample interval
/// ```text
/// |H − Ĥ|² ≤ 2/(2n_d − 2) · F(2, 2n_d − 2; 0.95) · (1 − γ²)/γ² · |Ĥ|²
/// ```
/// (Bendat & Piersol, *Random Data*, 4th ed. 2010, ch. 9, the confidence
/// interval of a frequency response estimate; the noise variance
/// estimated with `2n_d − 2` degrees of freedom), where the F quantile
/// with two numerator degrees of freedom is closed-form,
/// `F(2, ν; p) = (ν/2)((1 − p)^{−2/ν} − 1)`, so
/// `r = |Ĥ| √((0.05^{−1/(n_d − 1)} − 1)(1 − γ²)/γ²)`. Unlike the
/// first-order σ ([`h1_sigma_m_per_a`]) it holds for few averages:
/// √3 times the complex 1σ for many averages, 2.4 times for `n_d` = 5. Infinite for
/// γ² = 0 or `n_d` ≤ 1; NaN for a NaN response.
pub fn h1_radius_95(response: C64, coherence: f64, equivalent_averages: f64) -> f64 {
    if response.norm().is_nan() {
        return f64::NAN;
    }
    if coherence <= 0.0 || equivalent_averages <= 1.0 {
        return f64::INFINITY;
    }
    let f = 0.05f64.powf(-1.0 / (equivalent_averages - 1.0)) - 1.0;
    response.norm() * (f * (1.0 - coherence).max(0.0) / coherence).sqrt()
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
            // H1's σ is the first-order formula from the coherence, not a
            // variance estimate with a χ² law (its finite-sample interval
            // is `h1_radius_95`'s): weighted as known.
            sigma_dof: vec![f64::INFINITY; frequency_hz.len()],
            phase_deg,
            frequency_hz,
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
            sigma_dof: Vec::new(),
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
                out.sigma_dof.push(self.sigma_dof[i]);
            }
        }
        out
    }

    /// The complex response of line `i`, m/A (from magnitude and phase).
    pub fn response(&self, i: usize) -> C64 {
        C64::from_polar(self.magnitude_m_per_a[i], self.phase_deg[i].to_radians())
    }
}

#[cfg(test)]
mod tests;
