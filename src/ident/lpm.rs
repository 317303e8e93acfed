//! The local polynomial method (LPM): the FRF of a record with transient
//! and leakage removed, and a noise variance per line from the data.
//!
//! Pintelon & Schoukens, *System Identification: A Frequency Domain
//! Approach*, 2nd ed. 2012, §7.2; R. Pintelon, J. Schoukens, G. Vandersteen,
//! K. Barbé, "Estimation of nonparametric noise and FRF models for
//! multivariable systems — Part I: Theory", *Mechanical Systems and Signal
//! Processing* 24 (2010) 573–595. Here for one input and one output.
//!
//! # Method
//! The spectra are those of [`Spectra`]: the whole record (lead-in, sweep,
//! tail) of the input `u[t]` (A) and the output `y[t]` (m), zero-padded to
//! `N` samples and transformed once, `U[k]`, `Y[k]` unnormalised
//! (`Σ x[t] e^(−2πi kt/N)`), bin spacing `Δf = f_s / N`. For a linear system
//! the exact relation at every bin is
//! ```text
//! Y(k) = G(k) U(k) + T(k) + V(k)
//! ```
//! with `T` the transient (what the record's start and end leave: initial
//! and final state; a smooth function of `k`) and `V` the output noise's
//! DFT (circular complex, variance `σ²_V(k)`, smooth in `k`). Around a
//! bin `k`, over the `2n + 1` bins `k + r`, `r = −n … n`, `G` and `T` are
//! replaced by polynomials of degree `R` in `s = r / n`:
//! ```text
//! Y(k+r) = Σ_j g_j s^j U(k+r) + Σ_j t_j s^j + V(k+r),   j = 0 … R
//! ```
//! `2(R + 1)` complex unknowns `θ = [g_0 … g_R, t_0 … t_R]` fitted by linear
//! least squares, `Y_w = K θ + V_w` with `K` the `(2n + 1) × 2(R + 1)`
//! regressor matrix (rows `[U(k+r) s^j | s^j]`):
//! ```text
//! θ̂ = (Kᴴ K)⁻¹ Kᴴ Y_w                                      (Ĝ(k) = ĝ_0)
//! σ̂²_V(k) = ‖Y_w − K θ̂‖² / q,    q = 2n + 1 − 2(R + 1)       (m², per bin)
//! Cov(θ̂) = σ̂²_V(k) (Kᴴ K)⁻¹
//! ```
//! (Pintelon et al. 2010, §3–4: the local model, the residual's
//! noise-variance estimate with `q` degrees of freedom, and the covariance
//! of the FRF estimate). The FRF at a frequency `f` between bins is the
//! polynomial evaluated at the fractional offset, `Ĝ(f) = aᵀ θ̂` with
//! `a = [1, s_f, …, s_f^R, 0 … 0]`, `s_f = (f/Δf − k_c) / n`, `k_c` the
//! window's centre bin, and
//! ```text
//! σ_G(f)² = E|Ĝ(f) − G(f)|² = σ̂²_V aᵀ (Kᴴ K)⁻¹ a              (m²/A²)
//! ```
//! the variance of the complex estimate (circular: half in the real part,
//! half in the imaginary). In the code `U` and `Y` are scaled by their RMS
//! over the window, `Kᴴ K` and `Kᴴ Y` are formed from the window's moments
//! (`Σ|U|² s^m`, `Σ U s^m`, `Σ s^m`, `Σ U* Y s^j`, `Σ Y s^j`: every entry is
//! one of them) and solved by Cholesky, the residual is taken row by row,
//! and the results are scaled back.
//!
//! **Grid and window.** The estimate is evaluated on the log grid of
//! [`Frf::estimate`] (`points_per_decade`): for grid frequency `f`, the
//! window is centred on the bin nearest `f`. It spans `2n + 1` bins, or
//! where that is narrower than `ρ f` (`identification.relative_resolution`,
//! the width H1 smooths over) the `2n(f) + 1` bins of
//! `n(f) = ⌊ρ f / (2 Δf)⌋`. A fixed `2n + 1` bins would use, at high
//! frequency, a sliver of the bins between two grid points (at 425 Hz on
//! the default record, 13 of the 160): the per-line noise there was about
//! half of |G|, and the modal fit took it for modes. With `ρ` the window
//! stays narrow against the modes where it matters: a mode's half-power
//! band is `2ζ f`, so the window is `ρ / 2ζ` of it at every frequency
//! (half, for ζ = 0.004 and the default ρ = 0.4 %). **Edges:** where the
//! window would reach below bin 1 (the DC bin is never used: it holds what
//! is left of the probe offset) or above the highest bin kept, it is
//! shifted inward, keeping its width, and the polynomial is evaluated at
//! the larger offset; the variance comes from the same covariance and
//! grows with it.
//!
//! **Resolution.** Line `f` draws on `(2n(f) + 1) Δf` Hz
//! ([`Frf::resolution_hz`]); the noise of bins further apart is
//! uncorrelated (white noise's DFT is uncorrelated across bins; coloured
//! noise nearly so over a long record), so lines further apart than that
//! have independent errors, and closer ones share bins. `q` grows with the
//! window.
//!
//! **Coherence.** For the users of γ² (the design's γ² ≥ 0.5, the plots, the
//! fit's weights) the LPM reports its signal-to-noise form at the bin `k`
//! nearest `f`:
//! ```text
//! γ² = |Ĝ U(k)|² / (|Ĝ U(k)|² + σ̂²_V(k))
//! ```
//! which is what the magnitude-squared coherence of a linear system with
//! noise at the output alone tends to: the coherent output power over the
//! total, `γ² = |H|² G_uu / (|H|² G_uu + G_nn)` (Bendat & Piersol, *Random
//! Data*, 4th ed. 2010, ch. 6, single-input/single-output models with
//! output noise). Per line it scatters with `σ̂²_V` (q degrees of freedom).
//!
//! **How honest is σ?** `|Ĝ − G|² / σ_G²` is `χ²₂/2` when `σ_G` is known;
//! with `σ̂²_V` estimated from `q` degrees of freedom (`χ²_{2q}/(2q)`,
//! independent of `Ĝ` in a linear LS fit) the ratio
//! `|Ĝ − G|² / σ̂_G²` is `F(2, 2q)`-distributed, so
//! ```text
//! P(|Ĝ − G| ≤ c σ̂_G) = 1 − (1 + c²/q)^(−q)       (c = 2, q = 7: 0.958)
//! E[|Ĝ − G|² / σ̂_G²] = q / (q − 1)                (q = 7: 1.167)
//! E|Ĝ − G|² = E[σ̂_G²]                             (σ̂² unbiased)
//! ```
//! (`tests/cli/lpm.rs` checks these by Monte Carlo on the simulated bench.)
//!
//! **Bias.** The polynomials approximate `G` and `T`; the part they miss
//! biases `Ĝ` and inflates `σ̂²_V`. It grows with the window against the
//! narrowest feature of `G`, a mode's half-power band `2ζf`.
//!
//! # Defaults: R = 2, n = 6
//! `R = 2` is the textbook choice (Pintelon et al. 2010): the FRF's slope
//! and curvature across the window are followed, the transient's too.
//! `n = 6` (13 bins) gives `q = 7` degrees of freedom where the window is
//! narrowest, so `σ̂` spreads by `1/√(2q)` ≈ 27 % about its mean and the
//! 2σ coverage is 0.958 (n = 5, q = 5: 0.947, mean ratio 1.25 against
//! 1.17). And it stays narrow: on the default chirp record (65.5 s,
//! `Δf` = 0.0153 Hz) the window is 0.20 Hz up to 46 Hz, 38 % of the
//! half-power band of the X rigid-body mode (ζ = 0.009 at 29.3 Hz:
//! 0.53 Hz); above, `ρ f`. Measured without noise (`tests/cli/lpm.rs`): the
//! bias is 1.2e-3 of |G| at the 29.3 Hz peak and 4.0e-3 at the pair's
//! upper peak (84.5 Hz, ζ = 0.004), where H1 is 2.9e-2 off; 5e-10 away
//! from the modes.

use super::C64;
use crate::config::IdentificationConfig;
use crate::ident::frf::{log_grid, unwrap_deg, Frf, FrfError, Spectra};

/// Default `R`, the degree of the local polynomials.
pub use crate::config::DEFAULT_LPM_DEGREE as DEFAULT_DEGREE;
/// Default `n`, the window's half width in DFT bins (see the module docs).
pub use crate::config::DEFAULT_LPM_HALF_WIDTH_BINS as DEFAULT_HALF_WIDTH_BINS;
/// Fewest degrees of freedom `q` the local fit must leave for the noise
/// variance.
pub const MIN_DOF: i64 = 3;

/// The local window and polynomial degree.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LpmOptions {
    /// `n`, the least half width, bins: the window is the `2n + 1` bins
    /// `k − n … k + n`, or wider at high frequency
    /// ([`Self::half_width_at`]).
    pub half_width_bins: usize,
    /// `R`: degree of the polynomials of the FRF and of the transient.
    pub degree: usize,
    /// `ρ`: where `ρ f` is wider than `2n + 1` bins, the window spans it
    /// (0: always `2n + 1` bins).
    pub relative_resolution: f64,
}

impl Default for LpmOptions {
    /// `n` = [`DEFAULT_HALF_WIDTH_BINS`], `R` = [`DEFAULT_DEGREE`], `ρ` =
    /// `identification.relative_resolution`'s default (0.004).
    fn default() -> Self {
        Self {
            half_width_bins: DEFAULT_HALF_WIDTH_BINS,
            degree: DEFAULT_DEGREE,
            relative_resolution: IdentificationConfig::default().relative_resolution,
        }
    }
}

impl LpmOptions {
    /// `identification.lpm_half_width_bins`, `identification.lpm_degree`
    /// and `identification.relative_resolution`.
    pub fn from_config(cfg: &IdentificationConfig) -> Self {
        Self {
            half_width_bins: cfg.lpm_half_width_bins,
            degree: cfg.lpm_degree,
            relative_resolution: cfg.relative_resolution,
        }
    }

    /// The half width of the window at `frequency_hz` on bins of `bin_hz`:
    /// `max(n, ⌊ρ f / (2 Δf)⌋)`, so that the window spans `2n + 1` bins or
    /// `ρ f`, whichever is wider.
    pub fn half_width_at(&self, frequency_hz: f64, bin_hz: f64) -> usize {
        let wide = (self.relative_resolution * frequency_hz / (2.0 * bin_hz)).floor();
        if wide.is_finite() && wide > self.half_width_bins as f64 {
            wide as usize
        } else {
            self.half_width_bins
        }
    }

    /// `2n + 1`, bins: the narrowest window.
    pub fn window_bins(&self) -> usize {
        2 * self.half_width_bins + 1
    }

    /// `2(R + 1)`, the complex unknowns of the local fit.
    pub fn unknowns(&self) -> usize {
        2 * (self.degree + 1)
    }

    /// `q = 2n + 1 − 2(R + 1)`, the residual's degrees of freedom in the
    /// narrowest window (wider windows have more).
    pub fn dof(&self) -> i64 {
        self.window_bins() as i64 - self.unknowns() as i64
    }

    /// Checks that the fit leaves at least [`MIN_DOF`] degrees of freedom.
    ///
    /// # Errors
    /// [`FrfError::Options`].
    pub fn check(&self) -> Result<(), FrfError> {
        if self.half_width_bins == 0 || self.dof() < MIN_DOF {
            return Err(FrfError::Options {
                half_width_bins: self.half_width_bins,
                degree: self.degree,
                dof: self.dof(),
            });
        }
        Ok(())
    }
}

/// Checks that the band `f_lo_hz … f_hi_hz` holds at least `2n + 1` DFT
/// bins of `bin_hz` (bin 0 not counted): a record long enough for the
/// local window. `bench chirp` calls it before the run, with the bin
/// spacing the record will have.
///
/// # Errors
/// [`FrfError::TooShort`], or [`FrfError::Options`] for `opts`.
pub fn check_band(
    bin_hz: f64,
    f_lo_hz: f64,
    f_hi_hz: f64,
    opts: &LpmOptions,
) -> Result<(), FrfError> {
    check_band_in(bin_hz, f_lo_hz, f_hi_hz, opts, usize::MAX)
}

fn check_band_in(
    bin_hz: f64,
    f_lo_hz: f64,
    f_hi_hz: f64,
    opts: &LpmOptions,
    k_max: usize,
) -> Result<(), FrfError> {
    opts.check()?;
    let lo = ((f_lo_hz / bin_hz).ceil().max(1.0)) as usize;
    let hi = ((f_hi_hz / bin_hz).floor().max(0.0) as usize).min(k_max);
    let band_bins = (hi + 1).saturating_sub(lo);
    if band_bins < opts.window_bins() {
        return Err(FrfError::TooShort {
            f_lo_hz,
            f_hi_hz,
            band_bins,
            bin_hz,
            record_s: 1.0 / bin_hz,
            window_bins: opts.window_bins(),
            half_width_bins: opts.half_width_bins,
        });
    }
    Ok(())
}

/// The LPM estimate at one frequency.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LpmLine {
    /// `Ĝ(f)`, m/A (NaN when the window holds no excitation).
    pub response: C64,
    /// `σ_G(f) = sqrt(E|Ĝ − G|²)`, m/A.
    pub sigma_m_per_a: f64,
    /// `σ̂²_V`, the variance of the output noise's DFT per bin, m² (of the
    /// unnormalised DFT: `N σ²` for white noise of variance `σ²` m²).
    pub noise_variance_m2: f64,
    /// `|Ĝ U|² / (|Ĝ U|² + σ̂²_V)` at the bin nearest `f`, 0 … 1.
    pub coherence: f64,
    /// First bin of the window (`k_c − n`, or shifted inward at an edge).
    pub first_bin: usize,
    /// The window's half width here, bins ([`LpmOptions::half_width_at`]);
    /// the window is `2n + 1` bins, `(2n + 1) Δf` Hz.
    pub half_width_bins: usize,
}

impl LpmLine {
    fn nan(first_bin: usize, half_width_bins: usize) -> Self {
        Self {
            response: C64::new(f64::NAN, f64::NAN),
            sigma_m_per_a: f64::NAN,
            noise_variance_m2: f64::NAN,
            coherence: 0.0,
            first_bin,
            half_width_bins,
        }
    }
}

/// The local fit over one record's spectra, with its work space
/// allocated once (a line allocates nothing).
#[derive(Debug, Clone)]
pub struct Lpm<'s> {
    spectra: &'s Spectra,
    opts: LpmOptions,
    /// Window: `U`, `Y` of the `2n + 1` bins (then scaled).
    u: Vec<C64>,
    y: Vec<C64>,
    /// The window's moments `Σ|Ũ|² s^m`, `Σ Ũ s^m`, `Σ s^m`, m = 0 … 2R.
    m_uu: Vec<f64>,
    m_u: Vec<C64>,
    m_1: Vec<f64>,
    /// Cholesky factor of `Kᴴ K`, row-major lower triangle.
    l: Vec<C64>,
    /// `Kᴴ Y`, then θ.
    b: Vec<C64>,
    /// Scratch of the substitutions.
    z: Vec<C64>,
}

impl<'s> Lpm<'s> {
    /// A fit over `spectra` with `opts`.
    ///
    /// # Errors
    /// [`FrfError::Options`]; [`FrfError::TooShort`] when the spectra hold
    /// fewer than `2n + 1` bins above DC.
    pub fn new(spectra: &'s Spectra, opts: LpmOptions) -> Result<Self, FrfError> {
        opts.check()?;
        if spectra.k_max() < opts.window_bins() {
            let top = spectra.k_max() as f64 * spectra.bin_hz();
            check_band_in(spectra.bin_hz(), 0.0, top, &opts, spectra.k_max())?;
        }
        let (w, p) = (opts.window_bins(), opts.unknowns());
        let moments = 2 * opts.degree + 1;
        Ok(Self {
            spectra,
            opts,
            u: vec![C64::default(); w],
            y: vec![C64::default(); w],
            m_uu: vec![0.0; moments],
            m_u: vec![C64::default(); moments],
            m_1: vec![0.0; moments],
            l: vec![C64::default(); p * p],
            b: vec![C64::default(); p],
            z: vec![C64::default(); p],
        })
    }

    /// The estimate at `frequency_hz`: the local fit over the `2n + 1`
    /// bins around the nearest one (shifted inward at the edges), the
    /// polynomial evaluated at `frequency_hz`. NaN (coherence 0) above the
    /// bins kept, or where the window holds no excitation.
    ///
    /// # Errors
    /// [`FrfError::NonFiniteSpectrum`] when a bin of the window is not
    /// finite.
    pub fn line(&mut self, frequency_hz: f64) -> Result<LpmLine, FrfError> {
        let bin_hz = self.spectra.bin_hz();
        let k_max = self.spectra.k_max();
        // At least the configured n (new() checked that 2n + 1 bins fit in
        // 1 … k_max), wider at high frequency, never more than fit.
        let n = self
            .opts
            .half_width_at(frequency_hz, bin_hz)
            .min((k_max - 1) / 2)
            .max(self.opts.half_width_bins);
        let w = 2 * n + 1;
        let p1 = self.opts.degree + 1;
        let p = 2 * p1;
        let x = frequency_hz / bin_hz;
        if !x.is_finite() || x < 0.0 || x.round() as usize > k_max {
            return Ok(LpmLine::nan(0, n));
        }
        if self.u.len() < w {
            // A wider window than any before (high frequency): grown once.
            self.u.resize(w, C64::default());
            self.y.resize(w, C64::default());
        }
        let nearest = (x.round() as usize).clamp(1, k_max);
        // Inward at the edges: bins 1 … k_max, 2n + 1 of them (new()
        // checked that there are).
        let first = nearest.saturating_sub(n).max(1).min(k_max + 1 - w);
        let centre = first + n;
        let (mut uu, mut yy) = (0.0, 0.0);
        for r in 0..w {
            let (u, y) = self.spectra.bin(first + r);
            for (channel, v) in [("input u (A)", u), ("output y (m)", y)] {
                if !(v.re.is_finite() && v.im.is_finite()) {
                    return Err(FrfError::NonFiniteSpectrum {
                        channel,
                        frequency_hz: (first + r) as f64 * bin_hz,
                    });
                }
            }
            uu += u.norm_sqr();
            yy += y.norm_sqr();
            self.u[r] = u;
            self.y[r] = y;
        }
        let us = (uu / w as f64).sqrt();
        let ys = if yy > 0.0 {
            (yy / w as f64).sqrt()
        } else {
            1.0
        };
        if us == 0.0 || !us.is_finite() || !ys.is_finite() {
            return Ok(LpmLine::nan(first, n));
        }
        // KᴴK and KᴴỸ of the regressor rows [Ũ s^j | s^j] (Ũ = U/us,
        // Ỹ = Y/ys), from the window's moments: every entry is one of
        // Σ|Ũ|² s^m (real), Σ Ũ s^m, Σ s^m (real), m = 0 … 2R, and the
        // right-hand side Σ Ũ* Ỹ s^j, Σ Ỹ s^j, j = 0 … R.
        self.m_uu.fill(0.0);
        self.m_u.fill(C64::default());
        self.m_1.fill(0.0);
        self.b.fill(C64::default());
        let inv_n = 1.0 / n as f64;
        for r in 0..w {
            let s = (r as f64 - n as f64) * inv_n;
            let ut = self.u[r] / us;
            let yt = self.y[r] / ys;
            self.u[r] = ut;
            self.y[r] = yt;
            let (uu, uy) = (ut.norm_sqr(), ut.conj() * yt);
            let mut pw = 1.0;
            for m in 0..=2 * self.opts.degree {
                self.m_uu[m] += uu * pw;
                self.m_u[m] += ut * pw;
                self.m_1[m] += pw;
                if m < p1 {
                    self.b[m] += uy * pw;
                    self.b[p1 + m] += yt * pw;
                }
                pw *= s;
            }
        }
        // Lower triangle: A[i][j] = Σ conj(K_ri) K_rj.
        for i in 0..p {
            for j in 0..=i {
                self.l[i * p + j] = match (i < p1, j < p1) {
                    (true, _) => C64::new(self.m_uu[i + j], 0.0),
                    (false, true) => self.m_u[i - p1 + j],
                    (false, false) => C64::new(self.m_1[i - p1 + j - p1], 0.0),
                };
            }
        }
        if !cholesky(&mut self.l, p) {
            return Ok(LpmLine::nan(first, n));
        }
        // θ = A⁻¹ b: L z = b, Lᴴ θ = z.
        forward(&self.l, p, &mut self.b);
        backward_conj(&self.l, p, &mut self.b);
        let theta = &self.b;
        // The residual, row by row (not ‖Ỹ‖² − bᴴθ, which cancels when the
        // fit is near exact): Ỹ − (G(s) Ũ + T(s)), Horner in s.
        let mut ss = 0.0;
        for r in 0..w {
            let s = (r as f64 - n as f64) * inv_n;
            let (mut g, mut t) = (theta[p1 - 1], theta[p - 1]);
            for j in (0..p1 - 1).rev() {
                g = g * s + theta[j];
                t = t * s + theta[p1 + j];
            }
            ss += (self.y[r] - (g * self.u[r] + t)).norm_sqr();
        }
        let q = (w - p) as f64;
        // σ̂²_V in the scaled units, then m².
        let var_scaled = ss / q;
        let noise_variance_m2 = var_scaled * ys * ys;
        // Ĝ(f) and aᵀ A⁻¹ a at s_f.
        let sf = (x - centre as f64) / n as f64;
        let mut g = C64::default();
        let mut pw = 1.0;
        self.z.fill(C64::default());
        for (z, t) in self.z.iter_mut().zip(theta).take(p1) {
            *z = C64::new(pw, 0.0);
            g += t * pw;
            pw *= sf;
        }
        forward(&self.l, p, &mut self.z);
        let quad: f64 = self.z.iter().map(|v| v.norm_sqr()).sum();
        let response = g * (ys / us);
        let variance = var_scaled * quad * (ys / us).powi(2);
        let (u_near, _) = self.spectra.bin(nearest);
        let signal = (response * u_near).norm_sqr();
        let coherence = if signal + noise_variance_m2 > 0.0 {
            signal / (signal + noise_variance_m2)
        } else {
            0.0
        };
        Ok(LpmLine {
            response,
            sigma_m_per_a: variance.sqrt(),
            noise_variance_m2,
            coherence,
            first_bin: first,
            half_width_bins: n,
        })
    }
}

/// In-place Cholesky `A = L Lᴴ` of the Hermitian matrix whose lower
/// triangle is in `a` (row-major `m × m`); `false` when `A` is not
/// numerically positive definite (a pivot below 1e-12 of its diagonal).
fn cholesky(a: &mut [C64], m: usize) -> bool {
    for i in 0..m {
        for j in 0..=i {
            let mut s = a[i * m + j];
            for k in 0..j {
                s -= a[i * m + k] * a[j * m + k].conj();
            }
            if i == j {
                let d = s.re;
                let diag = a[i * m + i].re;
                if !(d > 1e-12 * diag && d.is_finite()) {
                    return false;
                }
                a[i * m + i] = C64::new(d.sqrt(), 0.0);
            } else {
                a[i * m + j] = s / a[j * m + j].re;
            }
        }
    }
    true
}

/// `v ← L⁻¹ v` (forward substitution, `L` lower triangular row-major).
fn forward(l: &[C64], m: usize, v: &mut [C64]) {
    for i in 0..m {
        let mut s = v[i];
        for k in 0..i {
            s -= l[i * m + k] * v[k];
        }
        v[i] = s / l[i * m + i].re;
    }
}

/// `v ← L⁻ᴴ v` (back substitution with `Lᴴ`).
fn backward_conj(l: &[C64], m: usize, v: &mut [C64]) {
    for i in (0..m).rev() {
        let mut s = v[i];
        for k in i + 1..m {
            s -= l[k * m + i].conj() * v[k];
        }
        v[i] = s / l[i * m + i].re;
    }
}

impl Frf {
    /// Estimates the FRF on the log grid `f_lo … f_hi` (Hz) with the
    /// configured estimator (`cfg.estimator`): the LPM ([`estimate`]) or
    /// H1 ([`Self::estimate`]). (Defined here, beside the LPM: the FRF's
    /// own module does not depend on its estimators.)
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
            crate::config::Estimator::Lpm => estimate(
                spectra,
                f_lo,
                f_hi,
                cfg.points_per_decade,
                &LpmOptions::from_config(cfg),
            ),
            crate::config::Estimator::H1 => Ok(Self::estimate(spectra, f_lo, f_hi, cfg)),
        }
    }
}

/// The LPM FRF on the log grid `f_lo … f_hi` (Hz, `points_per_decade`
/// points per decade, as [`Frf::estimate`]): magnitude, unwrapped phase,
/// the SNR-form coherence, σ per line, the resolution `(2n + 1) Δf` and
/// σ's real degrees of freedom `2q` (`q` of the line's window).
///
/// # Errors
/// [`FrfError::Options`] (too few degrees of freedom),
/// [`FrfError::TooShort`] (the band holds fewer than `2n + 1` bins),
/// [`FrfError::NonFiniteSpectrum`] (a NaN or infinite bin).
pub fn estimate(
    spectra: &Spectra,
    f_lo: f64,
    f_hi: f64,
    points_per_decade: usize,
    opts: &LpmOptions,
) -> Result<Frf, FrfError> {
    check_band_in(spectra.bin_hz(), f_lo, f_hi, opts, spectra.k_max())?;
    let mut lpm = Lpm::new(spectra, *opts)?;
    let frequency_hz = log_grid(f_lo, f_hi, points_per_decade);
    let mut frf = Frf::empty();
    for &f in &frequency_hz {
        let line = lpm.line(f)?;
        frf.magnitude_m_per_a.push(line.response.norm());
        frf.phase_deg.push(line.response.arg().to_degrees());
        frf.coherence.push(line.coherence);
        frf.sigma_m_per_a.push(line.sigma_m_per_a);
        frf.resolution_hz
            .push((2 * line.half_width_bins + 1) as f64 * spectra.bin_hz());
        // σ̂²_V has 2q real degrees of freedom (q in this line's window,
        // wider windows more): a fit's cost reference is then F-shaped,
        // its mean q/(q − 1) (1.17 at q = 7), where the known-variance
        // law flagged fits of the true model at 10 % noise (χ²/ν
        // 1.13–1.17 against a bound of 1.13, `tests/cli/real_links.rs`).
        // Where the model error floor dominates (low noise) the fit's
        // Satterthwaite degrees of freedom grow and it weighs as known.
        let q = (2 * line.half_width_bins + 1) as f64 - opts.unknowns() as f64;
        frf.sigma_dof.push(2.0 * q);
    }
    unwrap_deg(&mut frf.phase_deg);
    frf.frequency_hz = frequency_hz;
    Ok(frf)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A record whose spectrum is known: `y = g0 u + g1 u[t−1]` (an FIR,
    /// `G(e^{jω}) = g0 + g1 e^{−jω}`, a first-degree trigonometric
    /// polynomial the local quadratic follows closely) driven by a random
    /// input, no noise: Ĝ matches G (independent: the closed form), σ is
    /// tiny against |G|.
    #[test]
    fn an_fir_without_noise() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let n = 20_000;
        let fs = 1000.0;
        let mut u: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        // Start and end at rest: the record holds the whole response.
        u[n - 1] = 0.0;
        let (g0, g1) = (2e-3, -1e-3);
        let y: Vec<f64> = (0..n)
            .map(|t| g0 * u[t] + if t > 0 { g1 * u[t - 1] } else { 0.0 })
            .collect();
        let cfg = IdentificationConfig::default();
        let s = Spectra::new(&u, &y, fs, &cfg);
        let frf = estimate(&s, 1.0, 400.0, 50, &LpmOptions::default()).unwrap();
        for (i, f) in frf.frequency_hz.iter().enumerate() {
            let w = 2.0 * std::f64::consts::PI * f / fs;
            let g = C64::new(g0, 0.0) + C64::from_polar(g1, -w);
            let e = (frf.response(i) - g).norm() / g.norm();
            assert!(e < 1e-6, "{f} Hz: relative error {e}");
            assert!(frf.sigma_m_per_a[i] < 1e-6 * g.norm(), "{f} Hz");
            assert!(frf.coherence[i] > 0.999_999);
            // 2n + 1 bins, or 0.4 % of f where wider (bins of 0.05 Hz: from
            // 162.5 Hz on).
            let bin_hz = fs / crate::ident::frf::fast_len(n) as f64;
            let half = ((0.004 * f / (2.0 * bin_hz)).floor() as usize).max(6);
            let res = (2 * half + 1) as f64 * bin_hz;
            assert!((frf.resolution_hz[i] - res).abs() < 1e-9, "{f} Hz");
        }
    }

    #[test]
    fn options_and_short_records_are_refused_naming_the_keys() {
        let bad = LpmOptions {
            half_width_bins: 3,
            degree: 2,
            ..LpmOptions::default()
        };
        let e = bad.check().unwrap_err().to_string();
        assert!(
            e.contains("identification.lpm_half_width_bins = 3") && e.contains("lpm_degree = 2"),
            "{e}"
        );
        assert_eq!(bad.dof(), 1);
        // 10 s at 100 Hz: Δf = 0.1 Hz; 1.05–1.95 Hz holds bins 11 … 19,
        // 9 < 13.
        let u = vec![0.0; 1000];
        let s = Spectra::new(&u, &u, 100.0, &IdentificationConfig::default());
        let e = estimate(&s, 1.05, 1.95, 50, &LpmOptions::default()).unwrap_err();
        assert!(
            matches!(
                e,
                FrfError::TooShort {
                    band_bins: 9,
                    window_bins: 13,
                    ..
                }
            ),
            "{e:?}"
        );
        assert!(e.to_string().contains("lpm_half_width_bins = 6"), "{e}");
        // 1.05–2.35 Hz holds bins 11 … 23, 13: enough (no excitation: NaN
        // lines).
        let frf = estimate(&s, 1.05, 2.35, 50, &LpmOptions::default()).unwrap();
        assert!(frf.magnitude_m_per_a.iter().all(|m| m.is_nan()));
    }

    #[test]
    fn a_non_finite_record_is_refused_naming_the_channel() {
        let mut u = vec![1.0; 1000];
        let y = vec![0.0; 1000];
        u[17] = f64::NAN;
        let record: Vec<C64> = u.iter().zip(&y).map(|(a, b)| C64::new(*a, *b)).collect();
        let e = crate::ident::frf::check_record(&record).unwrap_err();
        assert_eq!(
            e.to_string().split(':').next().unwrap(),
            "the record's input u (A) is not finite at sample 17 (NaN)"
        );
        let s = Spectra::new(&u, &y, 100.0, &IdentificationConfig::default());
        let e = estimate(&s, 1.0, 20.0, 50, &LpmOptions::default()).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("the spectrum of the record's input u (A) is not finite"),
            "{e}"
        );
    }
}
