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
//!    deviations from zero, refitting after each; where the noise is
//!    estimated, also a mode whose removal raises χ² by less than the
//!    level of an undecided mode (the data do not decide it).
//!
//! The 1σ uncertainties come from the Jacobian at the optimum,
//! `Σ = s² (JᵀJ)⁻¹` with `s²` the residual variance per degree of freedom
//! (so they hold whatever the absolute noise level).

use super::frf::{Frf, C64, MIN_COHERENCE, MIN_SIGMA_DOF};
use super::lsq::{self, Residuals};
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

mod detection;
mod problem;
mod quality;
mod search;
mod summary;
pub use detection::*;
pub use problem::*;
pub use quality::*;
pub use search::*;
pub use summary::*;

/// Relative model error added to every line's variance (0.02 %): what
/// the fit's path model (a `sinc` and a delay for the exact zero-order
/// hold, a first-order amplifier) cannot represent, so that lines with a
/// very high signal-to-noise ratio do not get unbounded weight. Measured
/// on the simulator (`tests/cli/uncertainty.rs`): with it, the fit's χ²/ν is
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
    /// Degrees of freedom of each line's variance estimate
    /// ([`Frf::sigma_dof`]; infinite or NaN: known). Empty: known.
    pub sigma_dof: Vec<f64>,
}

impl FrfData {
    /// From an estimated [`Frf`] (magnitude and unwrapped phase).
    pub fn from_frf(frf: &Frf) -> Self {
        Self {
            sigma_m_per_a: frf.sigma_m_per_a.clone(),
            resolution_hz: frf.resolution_hz.clone(),
            sigma_dof: frf.sigma_dof.clone(),
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
    /// The parameters' covariance in natural units, row-major `(3n+3)²`
    /// over `[f…, ζ…, A…, L, U, τ]` (n = `modes.len()`, the modes' order),
    /// from `s² (JᵀJ)⁻¹` ([`evaluate_sigma`] reads it). Not written to
    /// JSON: a fit read back has it empty, and its response's 1σ unknown.
    #[serde(skip)]
    #[schemars(skip)]
    pub covariance: Vec<f64>,
}

impl ModalFit {
    /// The fit passed every check of [`FitQuality`].
    pub fn trusted(&self) -> bool {
        self.quality.checked && self.quality.flags.is_empty()
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
    /// The residual terms alone (the start of every fit) have no finite
    /// least-squares solution on the data: numbers the fit cannot compute
    /// with (the FRF readers refuse them first:
    /// [`crate::ident::frf::MAGNITUDE_RANGE_M_PER_A`]).
    #[error("the FRF's numbers leave the fit no finite solution (magnitudes from {lo:e} to {hi:e} m/A, frequencies from {f_lo:e} to {f_hi:e} Hz)")]
    NoSolution {
        /// Smallest |H|, m/A.
        lo: f64,
        /// Largest |H|, m/A.
        hi: f64,
        /// Lowest frequency, Hz.
        f_lo: f64,
        /// Highest frequency, Hz.
        f_hi: f64,
    },
}

/// Fewest coherent points a fit needs.
pub const MIN_POINTS: usize = 20;

/// Fits the modal model to `data` (see the module docs).
///
/// # Errors
/// [`FitError::TooFewPoints`] when fewer than [`MIN_POINTS`] points have
/// γ² ≥ [`MIN_COHERENCE`]; [`FitError::NoSolution`] when even the residual
/// terms alone have no finite solution on the data.
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
    let Some(mut current) = with_linear(&prep, Vec::new(), Vec::new(), 0.5 * period_s) else {
        let mags = || data.response.iter().map(|h| h.norm());
        let f = &data.frequency_hz;
        return Err(FitError::NoSolution {
            lo: mags().fold(f64::INFINITY, f64::min),
            hi: mags().fold(0.0, f64::max),
            f_lo: f.first().copied().unwrap_or(f64::NAN),
            f_hi: f.last().copied().unwrap_or(f64::NAN),
        });
    };
    let mut cost = prep.cost(&current);
    // Peak picking: every peak at least 1 dB above its flanks, placed by
    // grids, then all refined together. Two placements are tried, and the
    // refined start of lower cost kept:
    // - each peak alone (one at a time, a mode stretches over the others
    //   not yet fitted);
    // - the most prominent first, each with the peaks placed before it in
    //   the model. (Placed alone, a small peak's grid reaches 4 % to the
    //   flank of a larger neighbour and explains that one instead: the
    //   shipped bench's v peak at 84.7 Hz was placed at 81.5 Hz, beside
    //   u, and the refinement of two modes on one resonance never
    //   recovered; on other benches the alone placement refines better.)
    let starts = &peak_starts(&prep, &data.frequency_hz, &current)[..];
    let refined: Vec<Params> = starts
        .par_iter()
        .map(|s0| sorted(refine(&prep, s0, period_s)))
        .collect();
    // The refined starts first (the lower cost), the unrefined after.
    let pick = |options: &[Params]| {
        options
            .iter()
            .map(|p| (prep.cost(p), p))
            .filter(|(c, p)| *c < cost && acceptable(&prep, &data.frequency_hz, p))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(c, p)| (c, p.clone()))
    };
    if let Some((c, p)) = pick(&refined).or_else(|| pick(starts)) {
        current = p;
        cost = c;
    }
    'grow: while current.f_hz.len() < MAX_MODES {
        // The model order by the residual tests: once the residual is the
        // noise (χ²/ν and the Ljung–Box Q within their bounds at
        // RESIDUAL_TEST_LEVEL), no further mode can be told from it, and
        // a mode added then would fit the noise. A model that misses them
        // only because it holds modes the data do not support (an early
        // mode pulled into a poor local minimum: the refinement cannot
        // leave it while the mode is there) passes them once pruned, and
        // then the pruned model is the fit. (A campaign cell's fit added
        // six modes at the rigid-body resonance, each a refinement that
        // lost patience, and took 11 s; the final `prune` dropped them
        // all again.)
        let t = residual_tests(&prep, &current);
        tracing::debug!(
            f_hz = ?current.f_hz,
            chi2_per_dof = ?t.chi2_per_dof,
            whiteness_q = ?t.whiteness_q,
            whiteness_q_bound = t.whiteness_q_bound,
            "modal fit: the residual tests before a mode is added"
        );
        if t.residual_is_noise() {
            break;
        }
        let pruned = prune(&prep, current.clone(), period_s);
        if pruned.f_hz.len() < current.f_hz.len()
            && residual_tests(&prep, &pruned).residual_is_noise()
        {
            tracing::debug!(
                from = current.f_hz.len(),
                to = pruned.f_hz.len(),
                "modal fit: pruned to a model whose residual is the noise"
            );
            current = pruned;
            break;
        }
        let trials = ranked_trials(&prep, &data.frequency_hz, &current);
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
    // The variances estimated from few realisations: each line weighted
    // as the Student t its residual over σ̂ is (issue 45, item 1). The
    // model order above is the search's, on the variances as if known.
    let (fitted_prep, estimate) = match student_t(&prep, &current, period_s) {
        Some((robust, p)) => (robust, p),
        None => (prep.clone(), current.clone()),
    };
    let mut fitted = summarise(&fitted_prep, data, &estimate, period_s);
    if let Some(m) = undecided(&prep, &data.frequency_hz, &current, period_s) {
        if fitted.labels_unsure.is_none() {
            fitted.labels_unsure = near_the_pair(&fitted, &m);
        }
        fitted.quality.undecided_modes.push(m);
    }
    fitted.quality.detection_limit = detection_limit(&prep, &data.frequency_hz, &current, period_s);
    Ok(fitted)
}

/// The peak-picked starts of [`fit`]: every peak at least
/// [`PEAK_PROMINENCE`] above its flanks, placed by grids in two ways (each
/// peak alone; the most prominent first, each with those placed before it),
/// each start kept to the coherent band and its residual terms solved; one
/// start when both placements agree.
fn peak_starts(prep: &Prepared, frequency_hz: &[f64], current: &Params) -> Vec<Params> {
    let peaks: Vec<f64> = magnitude_peaks(prep, frequency_hz, current, MAX_MODES)
        .into_iter()
        .filter(|(_, prominence)| *prominence >= PEAK_PROMINENCE)
        .map(|(f, _)| f)
        .collect();
    let mut alone: Vec<(f64, f64)> = peaks
        .par_iter()
        .filter_map(|&f0| try_mode(prep, frequency_hz, current, f0))
        .map(|t| (t.f_hz, t.zeta))
        .collect();
    alone.sort_by(|a, b| a.0.total_cmp(&b.0));
    alone.dedup_by(|b, a| b.0 / a.0 <= MIN_SEPARATION);
    let mut in_turn: Vec<(f64, f64)> = Vec::new();
    for &f0 in &peaks {
        let placed = Params {
            f_hz: in_turn.iter().map(|x| x.0).collect(),
            zeta: in_turn.iter().map(|x| x.1).collect(),
            ..current.clone()
        };
        if let Some(t) = try_mode(prep, frequency_hz, &placed, f0) {
            let apart = in_turn
                .iter()
                .all(|(f, _)| (t.f_hz / f).ln().abs() > MIN_SEPARATION.ln());
            if apart {
                in_turn.push((t.f_hz, t.zeta));
            }
        }
    }
    in_turn.sort_by(|a, b| a.0.total_cmp(&b.0));
    // A trial grid reaches 4 % past its peak: one at the edge of the
    // coherent band (a short sweep's end) would make the whole start
    // unacceptable.
    let (band_lo, band_hi) = coherent_band(prep, frequency_hz);
    let mut starts: Vec<Params> = [alone, in_turn]
        .into_iter()
        .map(|mut start| {
            start.retain(|(f, _)| (band_lo..=band_hi).contains(f));
            start
        })
        .filter(|start| !start.is_empty())
        .filter_map(|start| {
            with_linear(
                prep,
                start.iter().map(|x| x.0).collect(),
                start.iter().map(|x| x.1).collect(),
                current.tau_s,
            )
        })
        .collect();
    if starts.len() == 2 && starts[0].f_hz == starts[1].f_hz {
        starts.truncate(1);
    }
    starts
}

#[cfg(test)]
mod tests;
