//! Automatic full-band modal fit of a measured FRF (`bench fit`).
//!
//! # Model
//! The measured current → x1 response (m/A) is fitted on its whole grid by
//!
//! ```text
//! Ĥ(jω) = D(jω) · [ Σᵢ Aᵢ / (s² + 2ζᵢωᵢ s + ωᵢ²)  +  L / s²  +  U ],   s = jω
//! D(jω) = e^{−jωτ} · sinc(ωT/2) / (1 + jω/ω_a)
//! ```
//!
//! - `Aᵢ` (m/(A·s²)) is the real modal constant of mode `i`: the force
//!   constant times the modal residue `αᵢ` of thesis Eq. 4-15 (1/kg).
//!   Its sign is the mode's direction (thesis 3.2.1).
//! - `L` (m/(A·s²)) and `U` (m/A) are the lower and upper residual terms:
//!   the mass line of modes below the band and the static compliance of
//!   modes above it (Ewins, *Modal Testing*, §4.2.2).
//! - `D` is the path outside the mechanics: the zero-order hold of the
//!   sampled current (`sinc(ωT/2)` and half a period of delay), the
//!   amplifier's first-order current loop of bandwidth `ω_a` (from the
//!   config), and the delay `τ`, fitted (it starts at `T/2`; a real loop
//!   adds its latency on top).
//!
//! # Method
//! A grid denser than [`MAX_POINTS_PER_DECADE`] is thinned to it first.
//!
//! Nonlinear least squares on the relative, coherence-weighted error
//!
//! ```text
//! rₖ = wₖ (Ĥₖ − Hₖ) / |Hₖ|,      wₖ = 1 / √((1 − γₖ²)/γₖ² + ε²)
//! ```
//!
//! (the real and imaginary parts of `rₖ`; `(1 − γ²)/γ²` is the normalised
//! random error of an H1 estimate per average, Bendat & Piersol, *Random
//! Data*, Eq. 9.90; `ε` = [`MODEL_ERROR_FLOOR`] bounds the weight of
//! noise-free points). The model order is not chosen by the user:
//!
//! 1. Start from the peaks of |H| that rise [`PEAK_PROMINENCE`] (1 dB) above
//!    their flanks, each placed by the grid of step 2, all refined
//!    together (`Aᵢ`, `L`, `U` are linear: for fixed poles they come from a
//!    linear least-squares solve, the LSFD step of Peeters et al., *The
//!    PolyMAX frequency-domain method*, 2004).
//! 2. Where the weighted residual concentrates (a sliding ±1 % window over
//!    the points with γ² ≥ [`MIN_COHERENCE`]), try a mode: a grid of
//!    frequencies and damping ratios around it, each scored by the linear
//!    solve (variable projection, Golub & Pereyra 1973), the best refined
//!    with all parameters by Levenberg-Marquardt (`levenberg-marquardt`
//!    crate, MINPACK's algorithm).
//! 3. Keep the mode if it lowers the residual by more than
//!    [`MIN_IMPROVEMENT`], is lightly damped (ζ < [`MAX_DAMPING`]) and lies
//!    in the coherent band; repeat from 2.
//! 4. Drop, one at a time, the mode whose modal constant is least
//!    significant while it is less than [`MIN_SIGNIFICANCE`] standard
//!    deviations from zero, refitting after each.
//!
//! The 1σ uncertainties come from the Jacobian at the optimum,
//! `Σ = s² (JᵀJ)⁻¹` with `s²` the residual variance per degree of freedom
//! (so they hold whatever the absolute noise level).

use super::frf::{Frf, C64, MIN_COHERENCE};
use super::lsq::{self, Residuals};
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Relative model error added to every line's variance (0.02 %): what
/// the fit's path model (a `sinc` and a delay for the exact zero-order
/// hold, a first-order amplifier) cannot represent, so that lines with a
/// very high signal-to-noise ratio do not get unbounded weight. Measured
/// on the simulator (`tests/uncertainty.rs`): with it, the fit's χ²/ν is
/// 0.67–0.91 over random benches (the LPM's noise estimate plus this
/// floor covers the residual) and the 1σ cover the truth.
pub const MODEL_ERROR_FLOOR: f64 = 2e-4;
/// A mode is kept only if it lowers the weighted residual sum of squares
/// by at least this fraction (5 %).
pub const MIN_IMPROVEMENT: f64 = 0.05;
/// Largest damping ratio of a fitted mode; a broader term is out-of-band
/// dynamics for the residual terms.
pub const MAX_DAMPING: f64 = 0.2;
/// Smallest damping ratio of a fitted mode (1e-5: a quality factor of
/// 50 000, far lighter than any flexure); below it the refinement has run
/// a pole onto the axis between two measured lines.
pub const MIN_DAMPING: f64 = 1e-5;
/// A kept mode's modal constant is at least this many standard deviations
/// from zero (its sign is then known).
pub const MIN_SIGNIFICANCE: f64 = 3.0;
/// The densest grid the fit uses, points per decade (a step of 0.23 % in
/// frequency, under the 0.4 % smoothing window of the default estimate
/// and a third of the half-power bandwidth 2ζf of a mode with ζ = 0.004):
/// a denser FRF is thinned to it first. Its neighbouring points share
/// most of their DFT bins, so they add cost, not information: the fit's
/// cost grows faster than the number of points (36 991 points, 10 000 per
/// decade over 0.1-500 Hz: 66 s against 0.08 s for the default 400 per
/// decade), and the 1σ of correlated points taken as independent would
/// shrink with the density alone.
pub const MAX_POINTS_PER_DECADE: f64 = 1000.0;
/// At most this many modes are fitted.
pub const MAX_MODES: usize = 10;
/// Adjacent fitted modes closer than this frequency ratio are one mode.
pub const MIN_SEPARATION: f64 = 1.003;
/// A peak of |H| this much above the lower of its flanking minima within
/// ±5 % (1 dB) starts as a mode.
pub const PEAK_PROMINENCE: f64 = 1.122;
/// Largest RMS relative error over the coherent points of a fit that
/// explains the measurement (5 %); above it the fit missed part of the
/// response and decides nothing.
pub const MAX_FIT_ERROR: f64 = 0.05;

/// The measured FRF as the fit uses it.
#[derive(Debug, Clone)]
pub struct FrfData {
    /// Grid, Hz, ascending.
    pub frequency_hz: Vec<f64>,
    /// Complex response, m/A.
    pub response: Vec<C64>,
    /// γ², 0 … 1.
    pub coherence: Vec<f64>,
    /// 1σ of the complex response per line, `√E|Ĥ − H|²`, m/A, estimated
    /// from the data (the LPM's noise variance, or H1's from coherence).
    /// NaN on any line: not estimated (an FRF CSV of four columns); the fit
    /// then weights by coherence alone and scales its 1σ by the residual.
    pub sigma_m_per_a: Vec<f64>,
    /// Width of the band of DFT bins each line's estimate draws on, Hz:
    /// lines whose bands do not overlap have independent errors. 0: every
    /// line independent; NaN: unknown (the fit then thins only to
    /// [`MAX_POINTS_PER_DECADE`]).
    pub resolution_hz: Vec<f64>,
}

impl FrfData {
    /// From an estimated [`Frf`] (magnitude and unwrapped phase).
    pub fn from_frf(frf: &Frf) -> Self {
        Self {
            sigma_m_per_a: frf.sigma_m_per_a.clone(),
            resolution_hz: frf.resolution_hz.clone(),
            frequency_hz: frf.frequency_hz.clone(),
            response: frf
                .magnitude_m_per_a
                .iter()
                .zip(&frf.phase_deg)
                .map(|(m, p)| C64::from_polar(*m, p.to_radians()))
                .collect(),
            coherence: frf.coherence.clone(),
        }
    }
}

/// The known path outside the mechanics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Path {
    /// Sample period of the current demand (zero-order hold), s.
    pub period_s: f64,
    /// −3 dB bandwidth of the current amplifier, Hz.
    pub amplifier_bandwidth_hz: f64,
}

impl Path {
    /// `D(jω)` without the delay: hold gain `sinc(ωT/2)` and amplifier lag.
    fn gain(&self, w: f64) -> C64 {
        let x = 0.5 * w * self.period_s;
        let sinc = if x.abs() < 1e-12 { 1.0 } else { x.sin() / x };
        C64::new(sinc, 0.0) / C64::new(1.0, w / (2.0 * PI * self.amplifier_bandwidth_hz))
    }

    /// `D(jω) = e^{−jωτ} sinc(ωT/2) / (1 + jω/ω_a)` at `frequency_hz`
    /// with the delay `delay_s` (dimensionless: the current the coil gets
    /// per ampere demanded).
    pub fn response(&self, frequency_hz: f64, delay_s: f64) -> C64 {
        let w = 2.0 * PI * frequency_hz;
        self.gain(w) * C64::from_polar(1.0, -w * delay_s)
    }
}

/// One fitted mode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct FittedMode {
    /// Name: `u`, `v` for the closely spaced pair, `R` for the remainder
    /// mode, `m<N>` otherwise (as in `bench analyze`).
    pub label: String,
    /// Undamped natural frequency, Hz.
    pub frequency_hz: f64,
    /// 1σ of the natural frequency, Hz (`null` in JSON: not determined).
    #[serde(with = "sigma")]
    #[schemars(with = "Option<f64>")]
    pub frequency_sigma_hz: f64,
    /// Modal damping ratio.
    pub damping_ratio: f64,
    /// 1σ of the damping ratio (`null` in JSON: not determined).
    #[serde(with = "sigma")]
    #[schemars(with = "Option<f64>")]
    pub damping_ratio_sigma: f64,
    /// Modal constant `Aᵢ`, m/(A·s²) (force constant × residue αᵢ), signed.
    pub modal_constant: f64,
    /// 1σ of the modal constant, m/(A·s²) (`null` in JSON: not determined).
    #[serde(with = "sigma")]
    #[schemars(with = "Option<f64>")]
    pub modal_constant_sigma: f64,
    /// Sign of the modal constant: +1 or −1.
    pub sign: i8,
    /// The mode is in the actuator-to-probe path as `bench analyze` counts
    /// it: `|Aᵢ|` at least `RESIDUE_RATIO` (1e-4) of the largest. Modes
    /// outside it are listed but left out of the sequence and the zeros.
    pub in_path: bool,
}

/// A 1σ in JSON: a number, or `null` when the data do not determine the
/// parameter (a singular `JᵀJ`; held as `f64::INFINITY`).
mod sigma {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() {
            s.serialize_f64(*v)
        } else {
            s.serialize_none()
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::INFINITY))
    }
}

/// A zero of the fitted modal model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct FittedZero {
    /// Real part, Hz (`s / 2π`).
    pub re_hz: f64,
    /// Imaginary part, Hz.
    pub im_hz: f64,
    /// `MMP`, `RMP-RNMP` or `CMP-CNMP` (thesis 3.2.1).
    #[serde(rename = "type")]
    pub kind: String,
}

/// The result of [`fit`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ModalFit {
    /// The modes, ascending in frequency.
    pub modes: Vec<FittedMode>,
    /// Lower residual `L` (term `L/s²`), m/(A·s²), and its 1σ.
    pub lower_residual: f64,
    /// 1σ of `lower_residual`.
    #[serde(with = "sigma")]
    #[schemars(with = "Option<f64>")]
    pub lower_residual_sigma: f64,
    /// Upper residual `U` (static compliance of modes above the band), m/A.
    pub upper_residual_m_per_a: f64,
    /// 1σ of `upper_residual_m_per_a`.
    #[serde(with = "sigma")]
    #[schemars(with = "Option<f64>")]
    pub upper_residual_sigma_m_per_a: f64,
    /// Fitted delay τ of the path (hold, amplifier transport, latency), s.
    pub delay_s: f64,
    /// 1σ of the delay, s.
    #[serde(with = "sigma")]
    #[schemars(with = "Option<f64>")]
    pub delay_sigma_s: f64,
    /// RMS relative error `|Ĥ − H| / |H|` over the points with
    /// γ² ≥ [`MIN_COHERENCE`].
    pub rms_relative_error: f64,
    /// Points with γ² ≥ [`MIN_COHERENCE`] (the coherent band), of the
    /// grid the fit used (at most [`MAX_POINTS_PER_DECADE`]).
    pub coherent_points: usize,
    /// Sign sequence in thesis notation, e.g. `α_R > 0, α_u < 0, α_v > 0`.
    pub sign_sequence: String,
    /// Sequence of dominant modes (thesis 3.2.1), e.g. `[R]-[u]-[v]`.
    pub dominant_sequence: String,
    /// Zeros of the fitted modal sum with its damping (residual terms
    /// left out: they are the model's truncation, not the structure's),
    /// typed.
    pub zeros: Vec<FittedZero>,
    /// The fitted model has CMP-CNMP zeros.
    pub cmp_cnmp: bool,
    /// How far the fit can be trusted: the residual against the noise and
    /// the flags ([`FitQuality`]). Absent in JSON written before it
    /// existed (read as unchecked).
    #[serde(default)]
    pub quality: FitQuality,
    /// Why the labels R, u, v could be other modes
    /// ([`crate::analysis::modal::PairLabels::unsure`]); `None` when sure.
    #[serde(default)]
    pub labels_unsure: Option<String>,
}

impl ModalFit {
    /// The fit passed every check of [`FitQuality`].
    pub fn trusted(&self) -> bool {
        self.quality.checked && self.quality.flags.is_empty()
    }
}

/// Lags of the whiteness test ([`FitQuality::whiteness_q`]).
pub const WHITENESS_LAGS: usize = 10;

/// Significance of the residual tests: a fit that explains the data is
/// flagged by chance once in a thousand.
pub const RESIDUAL_TEST_LEVEL: f64 = 1e-3;

/// The checks of a fit that can be wrong without failing (issue 28: "no
/// silent wrong answer"). Each flag names the mode or the statistic and
/// the reason; a fit with any flag is not trusted
/// ([`ModalFit::trusted`]): the verdict does not decide from it and
/// `bench fit --update` does not write a config from it.
///
/// The residual tests run on the normalised residuals
/// `eₖ = wₖ (Ĥₖ − Hₖ)` of the lines the fit used (independent lines,
/// [`independent_lines`]), with `wₖ` the inverse standard deviation of
/// line `k` ([`weights`]):
/// - **χ² test** (only with a noise estimate per line): `χ² = Σ|eₖ|²`
///   against its distribution with `ν = 2N − p` degrees of freedom
///   (`N` lines, `p` parameters); flagged above the `1 − α` quantile,
///   α = [`RESIDUAL_TEST_LEVEL`], by the Wilson–Hilferty approximation
///   `ν (1 − 2/(9ν) + z_α √(2/(9ν)))³` (Johnson, Kotz & Balakrishnan,
///   *Continuous Univariate Distributions* 1, Eq. 18.24).
/// - **Whiteness along frequency against the noise** (Ljung–Box, for
///   complex residuals): `ρⱼ = Σₖ eₖ e*ₖ₊ⱼ / E`, `Q = 2N Σⱼ₌₁..h |ρⱼ|²`
///   with h = [`WHITENESS_LAGS`]; for circular white residuals each
///   `2N|ρⱼ|²` is χ²₂, so `Q ~ χ²(2h)` (Ljung & Box 1978,
///   Biometrika 65); flagged above its `1 − α` quantile. `E = max(Σ|eₖ|²,
///   2N)` (each part of `eₖ` has unit variance under the noise alone):
///   correlation is measured against the noise, so a smooth model
///   error far below the noise (which cannot move the parameters by their
///   1σ) does not flag. Only with a noise estimate per line: without one
///   there is nothing to judge a correlation against (a noise-free FRF's
///   residual is all model error). A model that misses a mode or a shape
///   leaves residuals that run in long same-signed stretches.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema, Default)]
pub struct FitQuality {
    /// The checks ran (false only for a fit read from JSON written before
    /// they existed).
    pub checked: bool,
    /// The weights are inverse standard deviations estimated from the
    /// data (LPM or H1 σ per line), so the 1σ are the noise's own; false:
    /// only relative weights (an FRF CSV without σ), the 1σ scaled by the
    /// residual.
    pub noise_estimated: bool,
    /// Lines the fit used (independent: their bands do not overlap).
    pub lines: usize,
    /// `χ²/ν` of the normalised residuals (≈ 1 when the model explains the
    /// data to the noise); `null` without a noise estimate.
    pub chi2_per_dof: Option<f64>,
    /// The `1 − α` bound of `χ²/ν` at this `ν`.
    pub chi2_per_dof_bound: Option<f64>,
    /// Ljung–Box `Q` of the normalised residuals; `null` without a noise
    /// estimate (nothing to judge a correlation against).
    pub whiteness_q: Option<f64>,
    /// Its `1 − α` bound (χ² with `2h` degrees of freedom).
    pub whiteness_q_bound: f64,
    /// Why the fit is not to be trusted; empty when it passed.
    pub flags: Vec<String>,
}

/// Standard normal quantile at `1 − RESIDUAL_TEST_LEVEL` (3.0902).
const Z_LEVEL: f64 = 3.090_232_306_167_813;

/// The `1 − α` quantile of χ² with `nu` degrees of freedom
/// (Wilson–Hilferty, [`FitQuality`]).
pub fn chi2_quantile(nu: f64) -> f64 {
    let a = 2.0 / (9.0 * nu);
    nu * (1.0 - a + Z_LEVEL * a.sqrt()).powi(3)
}

/// Trial damping ratios of [`try_mode`]: a mode whose damping still
/// equals one of them after the final refinement was never refined.
const TRIAL_DAMPING: [f64; 3] = [0.003, 0.01, 0.03];

/// The checks of [`FitQuality`] for parameters `p` with 1σ `sd`
/// ([`sigmas`]).
fn quality(prep: &Prepared, p: &Params, sd: &[f64]) -> FitQuality {
    let n = p.f_hz.len();
    let mut flags = Vec::new();
    let name = |i: usize| format!("mode {} at {:.2} Hz", i + 1, p.f_hz[i]);
    // Never refined: the damping is a trial value to rounding.
    for i in 0..n {
        if TRIAL_DAMPING
            .iter()
            .any(|z| (p.zeta[i] / z - 1.0).abs() < 1e-9)
        {
            flags.push(format!(
                "{}: damping ratio {} is the trial grid's starting value, never refined by the fit",
                name(i),
                p.zeta[i]
            ));
        }
    }
    // A 1σ the data do not give (a singular JᵀJ).
    for i in 0..n {
        if [sd[i], sd[n + i], sd[2 * n + i]]
            .iter()
            .any(|v| !v.is_finite())
        {
            flags.push(format!(
                "{}: its 1σ could not be computed (the data do not determine it)",
                name(i)
            ));
        }
    }
    // A split mode: two modes inside each other's half-power bands with
    // opposite modal constants that cancel (their sum under half the
    // larger): one resonance described as a difference of two.
    for i in 1..n {
        let (a, b) = (p.a[i - 1], p.a[i]);
        let overlap =
            p.f_hz[i] - p.f_hz[i - 1] < p.zeta[i - 1] * p.f_hz[i - 1] + p.zeta[i] * p.f_hz[i];
        if overlap && a * b < 0.0 && (a + b).abs() < 0.5 * a.abs().max(b.abs()) {
            flags.push(format!(
                "{} and {}: inside each other's half-power band with opposite modal constants ({:.3e}, {:.3e} m/(A·s²)) that cancel: one mode split in two",
                name(i - 1),
                name(i),
                a,
                b
            ));
        }
    }
    // The residual tests over the lines used.
    let e: Vec<C64> = (0..prep.len())
        .map(|k| (prep.model(k, p) - prep.h[k]) * prep.scale[k])
        .collect();
    let lines = e.len();
    let params = 3 * n + 3;
    let nu = (2 * lines).saturating_sub(params).max(1) as f64;
    let chi2: f64 = e.iter().map(|v| v.norm_sqr()).sum();
    let (chi2_per_dof, chi2_per_dof_bound) = if prep.noise_estimated {
        let bound = chi2_quantile(nu) / nu;
        if chi2 / nu > bound {
            flags.push(format!(
                "the residual exceeds the estimated noise: χ²/ν = {:.2} over {lines} lines (bound {:.2} at the {} level): the model misses part of the response",
                chi2 / nu,
                bound,
                RESIDUAL_TEST_LEVEL
            ));
        }
        (Some(chi2 / nu), Some(bound))
    } else {
        (None, None)
    };
    // Against the estimated noise: the lag products are compared with
    // what unit-variance noise gives (N), so a correlated residual far
    // below the noise (χ²/ν ≪ 1: a model error the data cannot see) does
    // not count; a residual above the noise is scaled to it (the χ² test
    // has judged its size). Without a noise estimate there is nothing to
    // judge a correlation against: not tested.
    let q_bound = chi2_quantile(2.0 * WHITENESS_LAGS as f64);
    let q = prep.noise_estimated.then(|| {
        // Unit variance in each part: E|eₖ|² = 2 under the noise alone.
        let energy = chi2.max(2.0 * lines as f64);
        (1..=WHITENESS_LAGS.min(lines.saturating_sub(1)))
            .map(|j| {
                let r: C64 = (0..lines - j).map(|k| e[k] * e[k + j].conj()).sum();
                (r / energy).norm_sqr()
            })
            .sum::<f64>()
            * 2.0
            * lines as f64
    });
    if let Some(q) = q.filter(|q| *q > q_bound) {
        flags.push(format!(
            "the residual is not white along frequency: Ljung–Box Q = {q:.1} over {WHITENESS_LAGS} lags (bound {q_bound:.1} at the {RESIDUAL_TEST_LEVEL} level): a structure the model does not have"
        ));
    }
    FitQuality {
        checked: true,
        noise_estimated: prep.noise_estimated,
        lines,
        chi2_per_dof,
        chi2_per_dof_bound,
        whiteness_q: q,
        whiteness_q_bound: q_bound,
        flags,
    }
}

/// Why no fit could be made.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FitError {
    /// Too few points with adequate coherence.
    #[error("only {coherent} of {total} FRF points have coherence >= {MIN_COHERENCE}; at least {needed} are needed")]
    TooFewPoints {
        /// Points with γ² ≥ MIN_COHERENCE.
        coherent: usize,
        /// All points.
        total: usize,
        /// Needed.
        needed: usize,
    },
}

/// Fewest coherent points a fit needs.
pub const MIN_POINTS: usize = 20;

/// Full parameter set: nonlinear (per mode f, ζ; delay) and linear.
#[derive(Debug, Clone, PartialEq)]
struct Params {
    f_hz: Vec<f64>,
    zeta: Vec<f64>,
    a: Vec<f64>,
    l: f64,
    u: f64,
    tau_s: f64,
}

/// The weight of each line: the residual of a model `Ĥ` at line `k` is
/// `(Ĥₖ − Hₖ) · wₖ`.
///
/// - With a 1σ per line from the data ([`FrfData::sigma_m_per_a`] finite
///   and positive on every line): `wₖ = √2/√(σₖ² + (ε|Hₖ|)²)`, the inverse
///   standard deviation of each of the line's real and imaginary parts
///   (σ² is `E|ΔH|²` of circular complex noise, half in each part; the
///   maximum-likelihood weighting of
///   Pintelon & Schoukens, *System Identification*, 2nd ed., §7.3 and
///   ch. 9), with `ε` = [`MODEL_ERROR_FLOOR`] for what the model cannot
///   represent; the residual is then in standard deviations.
/// - Without: `wₖ = 1/(|Hₖ| √((1 − γₖ²)/γₖ² + ε²))`, the relative,
///   coherence-weighted error (Bendat & Piersol, *Random Data*, Eq. 9.90),
///   which knows the noise only up to a common scale.
pub fn weights(data: &FrfData) -> Weights {
    let noise_estimated = !data.sigma_m_per_a.is_empty()
        && data.sigma_m_per_a.len() == data.response.len()
        && data.sigma_m_per_a.iter().all(|s| s.is_finite() && *s > 0.0);
    let scale = if noise_estimated {
        data.response
            .iter()
            .zip(&data.sigma_m_per_a)
            .map(|(h, s)| {
                // σ² is E|ΔH|² of circular complex noise: half in each of
                // the real and imaginary parts, which are the residuals.
                let floor = MODEL_ERROR_FLOOR * h.norm();
                (2.0 / (s * s + floor * floor)).sqrt().min(f64::MAX)
            })
            .collect()
    } else {
        data.response
            .iter()
            .zip(&data.coherence)
            .map(|(h, g)| {
                let g = g.clamp(1e-6, 1.0);
                let var = (1.0 - g) / g + MODEL_ERROR_FLOOR * MODEL_ERROR_FLOOR;
                1.0 / (var.sqrt() * h.norm().max(f64::MIN_POSITIVE))
            })
            .collect()
    };
    Weights {
        scale,
        noise_estimated,
    }
}

/// The weights of [`weights`].
#[derive(Debug, Clone)]
pub struct Weights {
    /// `wₖ` per line, A/m.
    pub scale: Vec<f64>,
    /// The weights are inverse standard deviations estimated from the data
    /// (the weighted residual sum of squares is then a χ²); otherwise they
    /// are relative and the noise level comes from the residual.
    pub noise_estimated: bool,
}

/// Precomputed per-point data.
struct Prepared<'a> {
    w: Vec<f64>,
    h: &'a [C64],
    /// Weight over |H|: the residual is `scale · (Ĥ − H)`.
    scale: Vec<f64>,
    /// The weights are inverse standard deviations ([`Weights`]).
    noise_estimated: bool,
    gain: Vec<C64>,
    coherent: Vec<bool>,
}

impl<'a> Prepared<'a> {
    fn new(data: &'a FrfData, path: &Path) -> Self {
        let w: Vec<f64> = data.frequency_hz.iter().map(|f| 2.0 * PI * f).collect();
        let Weights {
            scale,
            noise_estimated,
        } = weights(data);
        let gain = w.iter().map(|&w| path.gain(w)).collect();
        let coherent = data.coherence.iter().map(|g| *g >= MIN_COHERENCE).collect();
        Self {
            w,
            h: &data.response,
            scale,
            noise_estimated,
            gain,
            coherent,
        }
    }

    fn len(&self) -> usize {
        self.w.len()
    }

    /// `D(jω)` at point `k` with delay `tau_s`.
    fn d(&self, k: usize, tau_s: f64) -> C64 {
        self.gain[k] * C64::from_polar(1.0, -self.w[k] * tau_s)
    }

    /// The linear basis at point `k` (before `D`): modes, `1/s²`, `1`.
    fn basis(&self, k: usize, f_hz: &[f64], zeta: &[f64], out: &mut Vec<C64>) {
        out.clear();
        let s = C64::new(0.0, self.w[k]);
        for (f, z) in f_hz.iter().zip(zeta) {
            let wn = 2.0 * PI * f;
            out.push(C64::new(1.0, 0.0) / (s * s + s * (2.0 * z * wn) + wn * wn));
        }
        out.push(C64::new(1.0, 0.0) / (s * s));
        out.push(C64::new(1.0, 0.0));
    }

    /// Solves the linear coefficients for fixed poles and delay (weighted
    /// least squares over all points, by the normal equations of the
    /// column-scaled basis, solved by SVD); returns them and the cost.
    fn solve_linear(&self, f_hz: &[f64], zeta: &[f64], tau_s: f64) -> Option<(Vec<f64>, f64)> {
        self.solve_linear_in(0..self.len(), f_hz, zeta, tau_s)
    }

    /// [`Self::solve_linear`] over the points `range` only.
    fn solve_linear_in(
        &self,
        range: std::ops::Range<usize>,
        f_hz: &[f64],
        zeta: &[f64],
        tau_s: f64,
    ) -> Option<(Vec<f64>, f64)> {
        let p = f_hz.len() + 2;
        let mut g = DMatrix::<f64>::zeros(p, p);
        let mut rhs = DVector::<f64>::zeros(p);
        let mut row = Vec::with_capacity(p);
        for k in range.clone() {
            let d = self.d(k, tau_s) * self.scale[k];
            self.basis(k, f_hz, zeta, &mut row);
            row.iter_mut().for_each(|c| *c *= d);
            let t = self.h[k] * self.scale[k];
            for i in 0..p {
                let ci = row[i].conj();
                rhs[i] += (ci * t).re;
                for j in i..p {
                    g[(i, j)] += (ci * row[j]).re;
                }
            }
        }
        for i in 0..p {
            for j in 0..i {
                g[(i, j)] = g[(j, i)];
            }
        }
        let norms: Vec<f64> = (0..p)
            .map(|j| g[(j, j)].sqrt().max(f64::MIN_POSITIVE))
            .collect();
        for i in 0..p {
            rhs[i] /= norms[i];
            for j in 0..p {
                g[(i, j)] /= norms[i] * norms[j];
            }
        }
        if !(g.iter().chain(rhs.iter()).all(|v| v.is_finite())) {
            return None;
        }
        // Bounded iterations: nalgebra's SVD never returns on some inputs.
        let x = g
            .try_svd(true, true, f64::EPSILON, 500)?
            .solve(&rhs, 1e-13)
            .ok()?;
        let coef: Vec<f64> = x.iter().zip(&norms).map(|(v, n)| v / n).collect();
        let mut cost = 0.0;
        for k in range {
            let d = self.d(k, tau_s) * self.scale[k];
            self.basis(k, f_hz, zeta, &mut row);
            let m: C64 = row.iter().zip(&coef).map(|(c, x)| c * x).sum();
            cost += (m * d - self.h[k] * self.scale[k]).norm_sqr();
        }
        cost.is_finite().then_some((coef, cost))
    }

    /// The model at point `k`.
    fn model(&self, k: usize, p: &Params) -> C64 {
        let s = C64::new(0.0, self.w[k]);
        let mut m = C64::new(p.l, 0.0) / (s * s) + p.u;
        for i in 0..p.f_hz.len() {
            let wn = 2.0 * PI * p.f_hz[i];
            m += p.a[i] / (s * s + s * (2.0 * p.zeta[i] * wn) + wn * wn);
        }
        self.d(k, p.tau_s) * m
    }

    fn cost(&self, p: &Params) -> f64 {
        (0..self.len())
            .map(|k| ((self.model(k, p) - self.h[k]) * self.scale[k]).norm_sqr())
            .sum()
    }
}

/// The Levenberg-Marquardt problem over all parameters:
/// `[ln f₁…, ln ζ₁…, A₁…, L, U, τ/T]`, with `A`, `L`, `U` scaled by their
/// starting magnitudes.
struct Problem<'p, 'a> {
    prep: &'p Prepared<'a>,
    n_modes: usize,
    /// The start's coordinates.
    x0: DVector<f64>,
    /// Scales of A₁…, L, U.
    lin_scale: Vec<f64>,
    period_s: f64,
}

impl Problem<'_, '_> {
    fn new<'p, 'a>(prep: &'p Prepared<'a>, p: &Params, period_s: f64) -> Problem<'p, 'a> {
        let n = p.f_hz.len();
        let lin: Vec<f64> = p.a.iter().chain([&p.l, &p.u]).copied().collect();
        let lin_scale: Vec<f64> = lin.iter().map(|v| v.abs().max(1e-30)).collect();
        let mut x = DVector::<f64>::zeros(3 * n + 3);
        for i in 0..n {
            x[i] = p.f_hz[i].ln();
            x[n + i] = p.zeta[i].ln();
        }
        for (j, v) in lin.iter().enumerate() {
            x[2 * n + j] = v / lin_scale[j];
        }
        x[3 * n + 2] = p.tau_s / period_s;
        Problem {
            prep,
            n_modes: n,
            x0: x,
            lin_scale,
            period_s,
        }
    }

    /// The parameters at coordinates `x`.
    fn params_at(&self, x: &DVector<f64>) -> Params {
        let n = self.n_modes;
        Params {
            f_hz: (0..n).map(|i| x[i].exp()).collect(),
            zeta: (0..n).map(|i| x[n + i].exp()).collect(),
            a: (0..n).map(|i| x[2 * n + i] * self.lin_scale[i]).collect(),
            l: x[3 * n] * self.lin_scale[n],
            u: x[3 * n + 1] * self.lin_scale[n + 1],
            tau_s: x[3 * n + 2] * self.period_s,
        }
    }

    /// The Jacobian of the residuals with respect to `x` (analytic).
    fn jacobian_of(&self, p: &Params) -> DMatrix<f64> {
        let n = self.n_modes;
        let m = self.prep.len();
        let mut j = DMatrix::<f64>::zeros(2 * m, 3 * n + 3);
        for k in 0..m {
            let s = C64::new(0.0, self.prep.w[k]);
            let sc = self.prep.scale[k];
            let d = self.prep.d(k, p.tau_s) * sc;
            let mut put = |col: usize, v: C64| {
                j[(2 * k, col)] = v.re;
                j[(2 * k + 1, col)] = v.im;
            };
            let mut total = C64::new(p.l, 0.0) / (s * s) + p.u;
            for i in 0..n {
                let wn = 2.0 * PI * p.f_hz[i];
                let den = s * s + s * (2.0 * p.zeta[i] * wn) + wn * wn;
                let inv = C64::new(1.0, 0.0) / den;
                total += p.a[i] * inv;
                let inv2 = inv * inv;
                // ∂/∂ln f = ω ∂/∂ω: −A (2ζ s ω + 2ω²) / den².
                put(
                    i,
                    -d * p.a[i] * (s * (2.0 * p.zeta[i] * wn) + 2.0 * wn * wn) * inv2,
                );
                // ∂/∂ln ζ = ζ ∂/∂ζ: −A 2ζω s / den².
                put(n + i, -d * p.a[i] * s * (2.0 * p.zeta[i] * wn) * inv2);
                put(2 * n + i, d * inv * self.lin_scale[i]);
            }
            put(3 * n, d / (s * s) * self.lin_scale[n]);
            put(3 * n + 1, d * self.lin_scale[n + 1]);
            put(3 * n + 2, -s * d * total * self.period_s);
        }
        j
    }
}

impl Residuals for Problem<'_, '_> {
    fn residuals(&self, x: &DVector<f64>) -> Option<DVector<f64>> {
        let p = self.params_at(x);
        if p.zeta.iter().any(|z| !(z.is_finite() && *z < 10.0)) {
            return None;
        }
        let m = self.prep.len();
        let mut r = DVector::<f64>::zeros(2 * m);
        for k in 0..m {
            let e = (self.prep.model(k, &p) - self.prep.h[k]) * self.prep.scale[k];
            r[2 * k] = e.re;
            r[2 * k + 1] = e.im;
        }
        r.iter().all(|v| v.is_finite()).then_some(r)
    }

    fn jacobian(&self, x: &DVector<f64>) -> Option<DMatrix<f64>> {
        let j = self.jacobian_of(&self.params_at(x));
        j.iter().all(|v| v.is_finite()).then_some(j)
    }
}

/// Refines all parameters from `start` by Levenberg-Marquardt; returns the
/// refined parameters (or `start` if the refinement made it worse).
fn refine(prep: &Prepared, start: &Params, period_s: f64) -> Params {
    let problem = Problem::new(prep, start, period_s);
    let x = lsq::minimise(&problem, problem.x0.clone(), 20);
    let p = problem.params_at(&x);
    let ok = p
        .f_hz
        .iter()
        .chain(&p.zeta)
        .chain(&p.a)
        .chain([&p.l, &p.u, &p.tau_s])
        .all(|v| v.is_finite())
        // An undamped pole (ln ζ run off to −∞) is no mode: a line fitted
        // between two measured points.
        && p.zeta.iter().all(|z| *z >= MIN_DAMPING);
    if ok && prep.cost(&p) <= prep.cost(start) {
        p
    } else {
        start.clone()
    }
}

/// 1σ of every parameter in natural units (`[f…, ζ…, A…, L, U, τ]`),
/// from `s² (JᵀJ)⁻¹`.
fn sigmas(prep: &Prepared, p: &Params, period_s: f64) -> Vec<f64> {
    let problem = Problem::new(prep, p, period_s);
    let j = problem.jacobian_of(p);
    let n = p.f_hz.len();
    // With σ per line from the data the weighted cost is a χ² with
    // 2m − (3n + 3) degrees of freedom: the 1σ come from (JᵀJ)⁻¹ as they
    // are, widened by χ²/ν when the model leaves more than the noise
    // (Birge ratio); without, the noise level is the residual's.
    debug_assert_eq!(j.nrows(), 2 * prep.len());
    let s2 = residual_variance(prep, p, prep.cost(p));
    let jtj = j.transpose() * &j;
    let unknown = DMatrix::from_element(3 * n + 3, 3 * n + 3, f64::INFINITY);
    let cov = if !jtj.iter().all(|v| v.is_finite()) {
        unknown
    } else {
        match jtj.clone().try_inverse() {
            Some(c) => c,
            None => jtj
                .clone()
                .try_svd(true, true, f64::EPSILON, 500)
                .and_then(|svd| svd.pseudo_inverse(1e-300).ok())
                .unwrap_or(unknown),
        }
    };
    // A variance that is not positive comes from a (near-)singular JᵀJ:
    // the parameter is not determined by the data, its 1σ unknown (never 0).
    let sd = |i: usize| {
        let v = s2 * cov[(i, i)];
        if v > 0.0 && v.is_finite() {
            v.sqrt()
        } else {
            f64::INFINITY
        }
    };
    let mut out = Vec::with_capacity(3 * n + 3);
    for i in 0..n {
        out.push(sd(i) * p.f_hz[i]);
    }
    for i in 0..n {
        out.push(sd(n + i) * p.zeta[i]);
    }
    for i in 0..n {
        out.push(sd(2 * n + i) * problem.lin_scale[i]);
    }
    out.push(sd(3 * n) * problem.lin_scale[n]);
    out.push(sd(3 * n + 1) * problem.lin_scale[n + 1]);
    out.push(sd(3 * n + 2) * period_s);
    out
}

/// Parameters with the linear part re-solved for the given poles/delay.
fn with_linear(prep: &Prepared, f_hz: Vec<f64>, zeta: Vec<f64>, tau_s: f64) -> Option<Params> {
    let (coef, _) = prep.solve_linear(&f_hz, &zeta, tau_s)?;
    let n = f_hz.len();
    Some(Params {
        a: coef[..n].to_vec(),
        l: coef[n],
        u: coef[n + 1],
        f_hz,
        zeta,
        tau_s,
    })
}

/// Frequencies (Hz) where the weighted residual of `p` concentrates: the
/// local maxima of its energy in a ±1 % window over coherent points,
/// largest first, at least 3 % apart, away from the modes of `p`.
fn residual_peaks(prep: &Prepared, freq_hz: &[f64], p: &Params, max: usize) -> Vec<f64> {
    let n = prep.len();
    let e: Vec<f64> = (0..n)
        .map(|k| {
            if prep.coherent[k] {
                ((prep.model(k, p) - prep.h[k]) * prep.scale[k]).norm_sqr()
            } else {
                0.0
            }
        })
        .collect();
    // Sliding window sums over ±1 % (two pointers on the ascending grid).
    let mut energy = vec![0.0; n];
    let (mut lo, mut hi, mut acc) = (0usize, 0usize, 0.0);
    for k in 0..n {
        while hi < n && freq_hz[hi] <= freq_hz[k] * 1.01 {
            acc += e[hi];
            hi += 1;
        }
        while freq_hz[lo] < freq_hz[k] / 1.01 {
            acc -= e[lo];
            lo += 1;
        }
        energy[k] = acc.max(0.0);
    }
    let mut order: Vec<usize> = (0..n).filter(|&k| prep.coherent[k]).collect();
    order.sort_by(|&a, &b| energy[b].total_cmp(&energy[a]));
    let mut out: Vec<f64> = Vec::new();
    for k in order {
        let f = freq_hz[k];
        let far = |g: &f64| (f / g).ln().abs() > 0.03_f64.ln_1p();
        let near_mode = p.f_hz.iter().any(|m| (f / m).ln().abs() < 0.003);
        if energy[k] > 0.0 && !near_mode && out.iter().all(far) {
            out.push(f);
            if out.len() == max {
                break;
            }
        }
    }
    out
}

/// Peaks of the measured |H| over coherent points (local maxima), the
/// most prominent first (height over the lower minimum within ±5 %), away
/// from the modes of `p`: the classic peak-picking start.
fn magnitude_peaks(prep: &Prepared, freq_hz: &[f64], p: &Params, max: usize) -> Vec<(f64, f64)> {
    let n = prep.len();
    let mag: Vec<f64> = prep.h.iter().map(|h| h.norm()).collect();
    let mut peaks: Vec<(f64, f64)> = (1..n.saturating_sub(1))
        .filter(|&k| prep.coherent[k] && mag[k] > mag[k - 1] && mag[k] >= mag[k + 1])
        .filter(|&k| !p.f_hz.iter().any(|m| (freq_hz[k] / m).ln().abs() < 0.003))
        .map(|k| {
            let lo = freq_hz.partition_point(|f| *f < freq_hz[k] / 1.05);
            let hi = freq_hz.partition_point(|f| *f <= freq_hz[k] * 1.05);
            let left = mag[lo..=k].iter().fold(f64::INFINITY, |a, b| a.min(*b));
            let right = mag[k..hi].iter().fold(f64::INFINITY, |a, b| a.min(*b));
            (freq_hz[k], mag[k] / left.max(right))
        })
        .collect();
    peaks.sort_by(|a, b| b.1.total_cmp(&a.1));
    peaks.truncate(max);
    peaks
}

/// A mode tried near `f0`: the best of a grid over frequency (±4 % in
/// 0.25 % steps) and damping, scored by the linear solve over the points
/// within ±15 % of `f0`, with the cost it removes there.
struct Trial {
    f_hz: f64,
    zeta: f64,
    gain: f64,
    /// The window's cost without the mode.
    baseline: f64,
}

fn try_mode(prep: &Prepared, freq_hz: &[f64], current: &Params, f0: f64) -> Option<Trial> {
    let lo = freq_hz.partition_point(|f| *f < f0 / 1.15);
    let hi = freq_hz.partition_point(|f| *f <= f0 * 1.15);
    let window = lo..hi;
    let (_, baseline) =
        prep.solve_linear_in(window.clone(), &current.f_hz, &current.zeta, current.tau_s)?;
    let mut best: Option<Trial> = None;
    let mut fs = current.f_hz.clone();
    let mut zs = current.zeta.clone();
    fs.push(f0);
    zs.push(0.01);
    let last = fs.len() - 1;
    for k in -16..=16 {
        for z in [0.003, 0.01, 0.03] {
            fs[last] = f0 * (1.0 + 0.0025 * k as f64);
            zs[last] = z;
            if let Some((_, cost)) = prep.solve_linear_in(window.clone(), &fs, &zs, current.tau_s) {
                let gain = baseline - cost;
                if best.as_ref().is_none_or(|b| gain > b.gain) {
                    best = Some(Trial {
                        f_hz: fs[last],
                        zeta: z,
                        gain,
                        baseline,
                    });
                }
            }
        }
    }
    best
}

/// `current` with the mode of `trial` added: all parameters refined, and
/// the unrefined start (poles from the grid, linear terms solved), for
/// when the refinement drifts (a mode stretched over modes not yet fitted).
fn add_mode(
    prep: &Prepared,
    current: &Params,
    trial: &Trial,
    period_s: f64,
) -> Option<[Params; 2]> {
    let mut fs = current.f_hz.clone();
    let mut zs = current.zeta.clone();
    fs.push(trial.f_hz);
    zs.push(trial.zeta);
    let start = with_linear(prep, fs, zs, current.tau_s)?;
    Some([sorted(refine(prep, &start, period_s)), sorted(start)])
}

/// Modes sorted ascending in frequency.
fn sorted(p: Params) -> Params {
    let mut idx: Vec<usize> = (0..p.f_hz.len()).collect();
    idx.sort_by(|&a, &b| p.f_hz[a].total_cmp(&p.f_hz[b]));
    Params {
        f_hz: idx.iter().map(|&i| p.f_hz[i]).collect(),
        zeta: idx.iter().map(|&i| p.zeta[i]).collect(),
        a: idx.iter().map(|&i| p.a[i]).collect(),
        ..p
    }
}

/// Whether `p` is an acceptable model while modes are added: every mode
/// lightly damped, inside the coherent band and apart from the others.
/// (Significance is judged once all modes are in, by [`prune`]: before,
/// the residual variance that scales the uncertainties still holds the
/// modes not yet fitted.)
fn acceptable(prep: &Prepared, freq_hz: &[f64], p: &Params) -> bool {
    let (lo, hi) = coherent_band(prep, freq_hz);
    (0..p.f_hz.len()).all(|i| {
        p.zeta[i] < MAX_DAMPING
            && p.f_hz[i] >= lo
            && p.f_hz[i] <= hi
            && (i == 0 || p.f_hz[i] / p.f_hz[i - 1] > MIN_SEPARATION)
    })
}

/// The first adjacent pair of modes of `p` closer than [`MIN_SEPARATION`]:
/// the index of the one with the smaller modal constant.
fn coincident(p: &Params) -> Option<usize> {
    let i = (1..p.f_hz.len()).find(|&i| p.f_hz[i] / p.f_hz[i - 1] <= MIN_SEPARATION)?;
    Some(if p.a[i].abs() < p.a[i - 1].abs() {
        i
    } else {
        i - 1
    })
}

/// Removes, one at a time, the mode whose modal constant is least
/// significant while it is below [`MIN_SIGNIFICANCE`] standard deviations,
/// refitting after each removal; two modes a refit pulls within
/// [`MIN_SEPARATION`] are merged (the weaker dropped, refitted).
fn prune(prep: &Prepared, mut p: Params, period_s: f64) -> Params {
    loop {
        let n = p.f_hz.len();
        if n == 0 {
            return p;
        }
        let sd = sigmas(prep, &p, period_s);
        let (worst, z) = (0..n)
            .map(|i| (i, p.a[i].abs() / sd[2 * n + i]))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .expect("n > 0");
        if z >= MIN_SIGNIFICANCE {
            return p;
        }
        // Two modes the refit pulls together are one: the weaker goes (a
        // split mode's halves carry large opposite constants whose 1σ the
        // singular JᵀJ cannot give).
        let mut drop = Some(worst);
        while let Some(i) = drop {
            let Some(next) = without(prep, &p, i, period_s) else {
                return p;
            };
            p = next;
            drop = coincident(&p);
        }
    }
}

/// `s²` of the 1σ: the weighted cost per degree of freedom
/// (`2m − (3n + 3)` for `m` lines and `n` modes), at least 1 when the
/// weights are the data's own noise (see [`sigmas`]).
fn residual_variance(prep: &Prepared, p: &Params, cost: f64) -> f64 {
    let dof = (2.0 * prep.len() as f64 - (3 * p.f_hz.len() + 3) as f64).max(1.0);
    if prep.noise_estimated {
        (cost / dof).max(1.0)
    } else {
        cost / dof
    }
}

/// `p` without mode `i`, the linear part re-solved and all refined.
fn without(prep: &Prepared, p: &Params, i: usize, period_s: f64) -> Option<Params> {
    let mut f = p.f_hz.clone();
    let mut zeta = p.zeta.clone();
    f.remove(i);
    zeta.remove(i);
    let start = with_linear(prep, f, zeta, p.tau_s)?;
    Some(sorted(refine(prep, &start, period_s)))
}

/// The lines of `data` the fit uses: a line is kept when its frequency is
/// at least `1 + ln 10 / per_decade` times the last one kept (the step of
/// a log grid of `per_decade` points) and, where the lines' bands are
/// known ([`FrfData::resolution_hz`]), its band does not overlap the last
/// kept one's (`f − f_last ≥ (b + b_last)/2`): the kept lines' errors are
/// independent, so their weighted residual is a χ² and the 1σ of the fit
/// do not shrink with the density of the grid. `None` when every line is
/// kept.
fn thin(data: &FrfData, per_decade: f64) -> Option<FrfData> {
    let step = 1.0 + std::f64::consts::LN_10 / per_decade;
    let band = |k: usize| {
        data.resolution_hz
            .get(k)
            .copied()
            .filter(|b| b.is_finite())
            .unwrap_or(0.0)
    };
    let mut keep: Vec<usize> = Vec::with_capacity(data.frequency_hz.len());
    for (k, &f) in data.frequency_hz.iter().enumerate() {
        let fresh = keep.last().is_none_or(|&j| {
            let last = data.frequency_hz[j];
            f >= last * step && f - last >= 0.5 * (band(k) + band(j))
        });
        if fresh {
            keep.push(k);
        }
    }
    let pick = |v: &[f64]| -> Vec<f64> {
        keep.iter()
            .map(|&k| v.get(k).copied().unwrap_or(f64::NAN))
            .collect()
    };
    (keep.len() < data.frequency_hz.len()).then(|| FrfData {
        frequency_hz: pick(&data.frequency_hz),
        response: keep.iter().map(|&k| data.response[k]).collect(),
        coherence: pick(&data.coherence),
        sigma_m_per_a: pick(&data.sigma_m_per_a),
        resolution_hz: pick(&data.resolution_hz),
    })
}

/// The lines of `data` the fit and the model update use: no denser than
/// [`MAX_POINTS_PER_DECADE`], and with independent errors where the lines'
/// bands are known (see [`FrfData::resolution_hz`]).
pub fn independent_lines(data: &FrfData) -> std::borrow::Cow<'_, FrfData> {
    match thin(data, MAX_POINTS_PER_DECADE) {
        Some(t) => std::borrow::Cow::Owned(t),
        None => std::borrow::Cow::Borrowed(data),
    }
}

/// First and last frequency with γ² ≥ [`MIN_COHERENCE`].
fn coherent_band(prep: &Prepared, freq_hz: &[f64]) -> (f64, f64) {
    let first = prep.coherent.iter().position(|c| *c).unwrap_or(0);
    let last = prep.coherent.iter().rposition(|c| *c).unwrap_or(0);
    (freq_hz[first], freq_hz[last])
}

/// Fits the modal model to `data` (see the module docs).
///
/// # Errors
/// [`FitError::TooFewPoints`] when fewer than [`MIN_POINTS`] points have
/// γ² ≥ [`MIN_COHERENCE`].
pub fn fit(data: &FrfData, path: &Path) -> Result<ModalFit, FitError> {
    let lines = independent_lines(data);
    let data: &FrfData = &lines;
    let prep = Prepared::new(data, path);
    let coherent = prep.coherent.iter().filter(|c| **c).count();
    if coherent < MIN_POINTS {
        return Err(FitError::TooFewPoints {
            coherent,
            total: data.frequency_hz.len(),
            needed: MIN_POINTS,
        });
    }
    let period_s = path.period_s;
    // The residual terms alone, the delay at the hold's half period (a
    // delay fitted without any mode would wander off to explain the
    // resonances' phase).
    let mut current = with_linear(&prep, Vec::new(), Vec::new(), 0.5 * period_s)
        .expect("the residual terms alone always solve");
    let mut cost = prep.cost(&current);
    // Peak picking: every peak at least 1 dB above its flanks at once, each
    // placed by its own grid, then all refined together (one at a time, a
    // mode stretches over the others not yet fitted).
    let mut start: Vec<(f64, f64)> =
        magnitude_peaks(&prep, &data.frequency_hz, &current, MAX_MODES)
            .into_par_iter()
            .filter(|(_, prominence)| *prominence >= PEAK_PROMINENCE)
            .filter_map(|(f0, _)| try_mode(&prep, &data.frequency_hz, &current, f0))
            .map(|t| (t.f_hz, t.zeta))
            .collect();
    start.sort_by(|a, b| a.0.total_cmp(&b.0));
    start.dedup_by(|b, a| b.0 / a.0 <= MIN_SEPARATION);
    // A trial grid reaches 4 % past its peak: one at the edge of the
    // coherent band (a short sweep's end) would make the whole start
    // unacceptable.
    let (band_lo, band_hi) = coherent_band(&prep, &data.frequency_hz);
    start.retain(|(f, _)| (band_lo..=band_hi).contains(f));
    if let Some(s0) = with_linear(
        &prep,
        start.iter().map(|x| x.0).collect(),
        start.iter().map(|x| x.1).collect(),
        current.tau_s,
    )
    .filter(|_| !start.is_empty())
    {
        for p in [sorted(refine(&prep, &s0, period_s)), s0] {
            let c = prep.cost(&p);
            if c < cost && acceptable(&prep, &data.frequency_hz, &p) {
                current = p;
                cost = c;
                break;
            }
        }
    }
    'grow: while current.f_hz.len() < MAX_MODES {
        let mut candidates = residual_peaks(&prep, &data.frequency_hz, &current, 3);
        candidates.extend(
            magnitude_peaks(&prep, &data.frequency_hz, &current, 3)
                .into_iter()
                .map(|(f, _)| f),
        );
        // The candidates' grids are independent: tried side by side (in
        // the candidates' order, so the result does not depend on it).
        let mut trials: Vec<Trial> = candidates
            .into_par_iter()
            .filter_map(|f0| try_mode(&prep, &data.frequency_hz, &current, f0))
            .collect();
        trials.sort_by(|a, b| b.gain.total_cmp(&a.gain));
        for trial in &trials {
            // Only a trial that removes a good part of the misfit is refined
            // (its window's half at the start, when the misfit is spread
            // over the whole band).
            let worth = trial.gain >= 0.8 * MIN_IMPROVEMENT * cost
                || (current.f_hz.is_empty() && trial.gain >= 0.5 * trial.baseline);
            if !worth {
                continue;
            }
            let Some(options) = add_mode(&prep, &current, trial, period_s) else {
                continue;
            };
            for p in options {
                let c = prep.cost(&p);
                if c < (1.0 - MIN_IMPROVEMENT) * cost && acceptable(&prep, &data.frequency_hz, &p) {
                    current = p;
                    cost = c;
                    continue 'grow;
                }
            }
        }
        break;
    }
    let current = prune(&prep, current, period_s);
    // Every parameter refined together once more: a mode kept from its
    // trial grid (the unrefined option of `add_mode`) gets its own
    // frequency and damping here, or the quality check says it did not.
    let current = sorted(refine(&prep, &current, period_s));
    Ok(summarise(&prep, data, &current, period_s))
}

fn summarise(prep: &Prepared, data: &FrfData, p: &Params, period_s: f64) -> ModalFit {
    use crate::analysis::modal::{has_cmp_cnmp, type_damped_zeros};
    use crate::analysis::sequence::{dominant_sequence, SeqTerm};
    let n = p.f_hz.len();
    let sd = sigmas(prep, p, period_s);
    let amax = p.a.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    let in_path: Vec<bool> =
        p.a.iter()
            .map(|a| a.abs() >= crate::analysis::modal::RESIDUE_RATIO * amax)
            .collect();
    let path_idx: Vec<usize> = (0..n).filter(|&i| in_path[i]).collect();
    let path_f: Vec<f64> = path_idx.iter().map(|&i| p.f_hz[i]).collect();
    let path_z: Vec<f64> = path_idx.iter().map(|&i| p.zeta[i]).collect();
    let path_a: Vec<f64> = path_idx.iter().map(|&i| p.a[i]).collect();
    let mut labels: Vec<String> = (0..n).map(|i| format!("m{}", i + 1)).collect();
    let path_sd: Vec<f64> = path_idx.iter().map(|&i| sd[2 * n + i]).collect();
    let (path_labels, labels_unsure) = self::labels(&path_f, &path_a, &path_sd);
    for (k, l) in path_labels.into_iter().enumerate() {
        if !l.starts_with('m') {
            labels[path_idx[k]] = l;
        }
    }
    let modes: Vec<FittedMode> = (0..n)
        .map(|i| FittedMode {
            label: labels[i].clone(),
            frequency_hz: p.f_hz[i],
            frequency_sigma_hz: sd[i],
            damping_ratio: p.zeta[i],
            damping_ratio_sigma: sd[n + i],
            modal_constant: p.a[i],
            modal_constant_sigma: sd[2 * n + i],
            sign: if p.a[i] >= 0.0 { 1 } else { -1 },
            in_path: in_path[i],
        })
        .collect();
    let seq_terms: Vec<SeqTerm> = modes
        .iter()
        .filter(|m| m.in_path)
        .map(|m| SeqTerm {
            label: m.label.clone(),
            omega_rad_s: 2.0 * PI * m.frequency_hz,
            residue: m.modal_constant,
        })
        .collect();
    let seq = if seq_terms.is_empty() {
        None
    } else {
        Some(dominant_sequence(&seq_terms))
    };
    let roots = damped_numerator_roots(&path_f, &path_z, &path_a);
    let typed = type_damped_zeros(&roots);
    let mut sum_sq = 0.0;
    let mut count = 0usize;
    for k in 0..prep.len() {
        if prep.coherent[k] {
            let h = data.response[k];
            sum_sq += ((prep.model(k, p) - h) / h.norm()).norm_sqr();
            count += 1;
        }
    }
    ModalFit {
        modes,
        lower_residual: p.l,
        lower_residual_sigma: sd[3 * n],
        upper_residual_m_per_a: p.u,
        upper_residual_sigma_m_per_a: sd[3 * n + 1],
        delay_s: p.tau_s,
        delay_sigma_s: sd[3 * n + 2],
        rms_relative_error: (sum_sq / count.max(1) as f64).sqrt(),
        coherent_points: count,
        sign_sequence: seq.as_ref().map(|s| s.signs.clone()).unwrap_or_default(),
        dominant_sequence: seq.map(|s| s.notation).unwrap_or_default(),
        quality: quality(prep, p, &sd),
        labels_unsure,
        zeros: typed
            .iter()
            .map(|z| FittedZero {
                re_hz: z.s().re / (2.0 * PI),
                im_hz: z.s().im / (2.0 * PI),
                kind: z.kind.as_str().to_string(),
            })
            .collect(),
        cmp_cnmp: has_cmp_cnmp(&typed),
    }
}

/// Labels as `bench analyze` gives them
/// ([`crate::analysis::modal::pair_and_remainder`]) for fitted modes of
/// frequencies `f_hz` and modal constants `a` with 1σ `a_sigma`: a mode
/// shows in the path when its constant is at least [`MIN_SIGNIFICANCE`]
/// standard deviations from zero (every mode the fit keeps); the closely
/// spaced pair (the adjacent such modes with the smallest frequency
/// ratio, at most `CLOSE_PAIR_RATIO` = 1.25) `u`, `v`; `R` the remainder
/// mode; the rest `m<N>`. With the reason the labels are unsure, if they
/// are.
pub fn labels(f_hz: &[f64], a: &[f64], a_sigma: &[f64]) -> (Vec<String>, Option<String>) {
    let mut out: Vec<String> = (0..f_hz.len()).map(|i| format!("m{}", i + 1)).collect();
    let strength: Vec<f64> = a
        .iter()
        .zip(a_sigma)
        .map(|(a, s)| if *s > 0.0 { a.abs() / s } else { f64::INFINITY })
        .collect();
    let l = crate::analysis::modal::pair_and_remainder(
        f_hz,
        a,
        &strength,
        MIN_SIGNIFICANCE,
        super::frf::CLOSE_PAIR_RATIO,
    );
    if let Some((u, v)) = l.pair {
        out[u] = "u".into();
        out[v] = "v".into();
    }
    if let Some(r) = l.remainder {
        out[r] = "R".into();
    }
    (out, l.unsure)
}

/// Roots (rad/s) of the numerator of `Σᵢ Aᵢ / (s² + 2ζᵢωᵢ s + ωᵢ²)`,
/// computed in `s/ω̄` (ω̄ the geometric mean natural frequency).
pub fn damped_numerator_roots(f_hz: &[f64], zeta: &[f64], a: &[f64]) -> Vec<C64> {
    use bench_hal::model::{poly_mul, poly_roots};
    let n = f_hz.len();
    let finite = f_hz.iter().chain(zeta).chain(a).all(|v| v.is_finite());
    if n < 2 || !finite {
        return Vec::new();
    }
    let wbar = (f_hz.iter().map(|f| (2.0 * PI * f).ln()).sum::<f64>() / n as f64).exp();
    let amax = a
        .iter()
        .fold(0.0_f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    let mut num = vec![0.0; 2 * n - 1];
    for (i, ai) in a.iter().enumerate() {
        let mut poly = vec![ai / amax];
        for j in 0..n {
            if i != j {
                let w = 2.0 * PI * f_hz[j] / wbar;
                poly = poly_mul(&poly, &[1.0, 2.0 * zeta[j] * w, w * w]);
            }
        }
        let off = num.len() - poly.len();
        for (k, c) in poly.into_iter().enumerate() {
            num[off + k] += c;
        }
    }
    poly_roots(&num)
        .unwrap_or_default()
        .into_iter()
        .map(|r| r * wbar)
        .collect()
}

/// Phase of the path outside the mechanics at `frequency_hz` with the
/// fitted delay, degrees (continuous, not wrapped):
/// `−atan(f/f_a) − 360° f τ` (the hold's sinc is positive below the
/// sample rate).
pub fn path_phase_deg(fit: &ModalFit, path: &Path, frequency_hz: f64) -> f64 {
    -(frequency_hz / path.amplifier_bandwidth_hz)
        .atan()
        .to_degrees()
        - 360.0 * frequency_hz * fit.delay_s
}

/// The fitted model `Ĥ` at `frequency_hz` (m/A), for plots.
pub fn evaluate(fit: &ModalFit, path: &Path, frequency_hz: f64) -> C64 {
    let w = 2.0 * PI * frequency_hz;
    let s = C64::new(0.0, w);
    let mut m = C64::new(fit.lower_residual, 0.0) / (s * s) + fit.upper_residual_m_per_a;
    for md in &fit.modes {
        let wn = 2.0 * PI * md.frequency_hz;
        m += md.modal_constant / (s * s + s * (2.0 * md.damping_ratio * wn) + wn * wn);
    }
    path.gain(w) * C64::from_polar(1.0, -w * fit.delay_s) * m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_grid_denser_than_the_fit_uses_is_thinned_and_a_default_one_is_not() {
        let data = |per_decade| {
            let f = crate::ident::frf::log_grid(0.1, 500.0, per_decade);
            let n = f.len();
            FrfData {
                response: (0..n).map(|k| C64::new(k as f64, 0.0)).collect(),
                coherence: vec![1.0; n],
                sigma_m_per_a: vec![f64::NAN; n],
                resolution_hz: vec![f64::NAN; n],
                frequency_hz: f,
            }
        };
        for per_decade in [10, 400, 1000] {
            assert!(thin(&data(per_decade), MAX_POINTS_PER_DECADE).is_none());
        }
        let dense = data(10_000);
        let t = thin(&dense, MAX_POINTS_PER_DECADE).unwrap();
        // 3.7 decades: about 3 700 points, every 10th, each with its own
        // response and coherence.
        let decades = (500.0_f64 / 0.1).log10();
        assert!((t.frequency_hz.len() as f64 - decades * 1000.0).abs() < 10.0);
        for w in t.frequency_hz.windows(2) {
            assert!(w[1] / w[0] >= 1.0 + std::f64::consts::LN_10 / 1000.0);
        }
        for (f, h) in t.frequency_hz.iter().zip(&t.response) {
            assert_eq!(dense.frequency_hz[h.re as usize], *f);
        }
    }
    use crate::analysis::modal::modal_terms;
    use crate::config::BenchConfig;
    use bench_hal::model::Sr4dof;
    use bench_hal::sim::ZohPlant;

    fn ch5() -> BenchConfig {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
        BenchConfig::load(&path).unwrap()
    }

    /// The exact sampled response of the Chapter 5 bench (ZOH plant with
    /// the amplifier), noise-free, on the chirp's grid.
    fn exact(op: f64, dm: f64) -> (FrfData, Sr4dof, Path, f64) {
        let cfg = ch5();
        let mut p = cfg.plant;
        p.operating_point_m = op * p.beam.length_m;
        p.mass_asymmetry = dm;
        let model = Sr4dof::new(p).unwrap();
        let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
        let zoh = ZohPlant::new(&model, &cfg.actuator, period_s);
        let f = super::super::frf::log_grid(0.1, 500.0, 400);
        let data = FrfData {
            response: f.iter().map(|&f| zoh.frf(f)).collect(),
            coherence: vec![1.0; f.len()],
            sigma_m_per_a: vec![f64::NAN; f.len()],
            resolution_hz: vec![f64::NAN; f.len()],
            frequency_hz: f,
        };
        let path = Path {
            period_s,
            amplifier_bandwidth_hz: cfg.actuator.bandwidth_hz,
        };
        (data, model, path, cfg.actuator.force_constant_n_per_a)
    }

    /// A mode split in two (a duplicate 0.01 % above the 29 Hz mode, as the
    /// growth's refits can leave) is merged back by pruning: the modes come
    /// out as the model's, each once, and no 1σ is 0.
    #[test]
    fn pruning_merges_a_split_mode() {
        let (data, model, path, _) = exact(0.08, 0.1);
        let terms: Vec<_> = modal_terms(&model)
            .into_iter()
            .filter(|t| t.in_path)
            .collect();
        let mut f: Vec<f64> = terms.iter().map(|t| t.frequency_hz).collect();
        let mut zeta: Vec<f64> = terms.iter().map(|t| t.damping_ratio).collect();
        let rigid = (0..f.len()).min_by(|&a, &b| f[a].total_cmp(&f[b])).unwrap();
        f.push(f[rigid] * 1.0001);
        zeta.push(zeta[rigid]);
        let prep = Prepared::new(&data, &path);
        let start = sorted(with_linear(&prep, f, zeta, 0.5 * path.period_s).unwrap());
        let p = prune(&prep, start, path.period_s);
        assert_eq!(p.f_hz.len(), terms.len(), "{:?}", p.f_hz);
        for t in &terms {
            assert!(
                p.f_hz
                    .iter()
                    .any(|f| (f / t.frequency_hz - 1.0).abs() < 1e-4),
                "{} Hz not in {:?}",
                t.frequency_hz,
                p.f_hz
            );
        }
        let sd = sigmas(&prep, &p, path.period_s);
        assert!(sd.iter().all(|s| *s > 0.0), "{sd:?}");
    }

    /// An undetermined 1σ is `null` in JSON and reads back as unknown.
    #[test]
    fn unknown_sigma_is_null_in_json() {
        #[derive(Serialize, Deserialize)]
        struct S {
            #[serde(with = "sigma")]
            v: f64,
        }
        let text = serde_json::to_string(&S { v: f64::INFINITY }).unwrap();
        assert_eq!(text, r#"{"v":null}"#);
        let back: S = serde_json::from_str(&text).unwrap();
        assert!(back.v.is_infinite());
        let back: S = serde_json::from_str(r#"{"v":0.5}"#).unwrap();
        assert_eq!(back.v, 0.5);
    }

    /// The exact sampled response of the Chapter 5 bench on both sides of
    /// the CMP-CNMP boundary: the fitted modes are the model's (frequency
    /// 1e-4, damping 2 %, modal constant 1 % = force constant × residue of
    /// Eq. 4-15), and so is the CMP-CNMP answer.
    #[test]
    fn exact_response_gives_the_model_modes() {
        for (op, dm) in [(0.08, 0.1), (0.006, -0.08)] {
            let (data, model, path, kf) = exact(op, dm);
            let fit = fit(&data, &path).unwrap();
            let terms: Vec<_> = modal_terms(&model)
                .into_iter()
                .filter(|t| t.in_path)
                .collect();
            for t in &terms {
                let m = fit
                    .modes
                    .iter()
                    .find(|m| (m.frequency_hz / t.frequency_hz - 1.0).abs() < 1e-3)
                    .unwrap_or_else(|| {
                        panic!("{op} {dm}: no {} Hz in {:?}", t.frequency_hz, fit.modes)
                    });
                assert!(
                    (m.frequency_hz / t.frequency_hz - 1.0).abs() < 1e-4,
                    "{m:?} {t:?}"
                );
                assert!(
                    (m.damping_ratio / t.damping_ratio - 1.0).abs() < 0.02,
                    "{m:?} {t:?}"
                );
                let a = t.residue_per_kg * kf;
                assert!((m.modal_constant / a - 1.0).abs() < 0.01, "{m:?} {t:?}");
            }
            assert_eq!(
                fit.cmp_cnmp,
                crate::analysis::modal::model_cnmp_damped(&model)
            );
        }
    }
}
