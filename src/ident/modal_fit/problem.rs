//! The least-squares problem of the fit: the parameters, the weight of each
//! line, the model on the grid with its linear part solved for fixed poles
//! (variable projection), the Levenberg-Marquardt refinement and the 1σ
//! from the Jacobian.

use super::*;

/// Full parameter set: nonlinear (per mode f, ζ; delay) and linear.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Params {
    pub(super) f_hz: Vec<f64>,
    pub(super) zeta: Vec<f64>,
    pub(super) a: Vec<f64>,
    pub(super) l: f64,
    pub(super) u: f64,
    pub(super) tau_s: f64,
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
/// - When a line's variance is estimated with fewer than
///   [`MIN_SIGMA_DOF`] degrees of freedom ([`FrfData::sigma_dof`]: the
///   cost test and the covariance then have no finite reference, and a
///   weight `1/σ̂²` of 4 degrees of freedom has an infinite variance):
///   the relative error `wₖ = 1/(ε|Hₖ|)`, one weight for every line's
///   relative error (the coherence, made from the same σ̂, is not used
///   either).
///
/// Each line's effective degrees of freedom (`dof`) are those of its
/// weight's variance `σ̂ₖ² + (ε|Hₖ|)²`, of which only `σ̂ₖ²` is estimated
/// (Satterthwaite: `dₖ / ρₖ²`, `ρₖ = σ̂ₖ² / (σ̂ₖ² + (ε|Hₖ|)²)`); infinite
/// where the variance is known or not stated.
pub fn weights(data: &FrfData) -> Weights {
    let has_sigma = !data.sigma_m_per_a.is_empty()
        && data.sigma_m_per_a.len() == data.response.len()
        && data.sigma_m_per_a.iter().all(|s| s.is_finite() && *s > 0.0);
    let stated = |k: usize| {
        data.sigma_dof
            .get(k)
            .copied()
            .filter(|d| !d.is_nan())
            .unwrap_or(f64::INFINITY)
    };
    let least_dof = (0..data.response.len())
        .map(stated)
        .fold(f64::INFINITY, f64::min);
    let noise_refused = (has_sigma && least_dof < MIN_SIGMA_DOF).then(|| {
        format!(
            "σ per line is estimated with {least_dof} degrees of freedom, fewer than \
             {MIN_SIGMA_DOF} (a multisine of fewer than 4 realizations, or one realization of \
             fewer than 4 periods): the fit's cost and covariance have no finite reference \
             with it (nor does the coherence made from it), so it weights every line's relative \
             error alike and scales its 1σ by the residual"
        )
    });
    let noise_estimated = has_sigma && noise_refused.is_none();
    let least_dof = Some(least_dof).filter(|d| d.is_finite());
    let dof = if noise_estimated {
        data.response
            .iter()
            .zip(&data.sigma_m_per_a)
            .enumerate()
            .map(|(k, (h, s))| {
                let floor = MODEL_ERROR_FLOOR * h.norm();
                let rho = s * s / (s * s + floor * floor);
                stated(k) / (rho * rho)
            })
            .collect()
    } else {
        vec![f64::INFINITY; data.response.len()]
    };
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
        // A refused σ̂ also made the coherence (γ² = |Ĝ|²/(|Ĝ|² + σ̂²)):
        // weighted by it, the estimate would scatter as with σ̂ itself
        // (a weight of infinite variance at 4 degrees of freedom). Then
        // every line has the same relative weight.
        let refused = noise_refused.is_some();
        data.response
            .iter()
            .zip(&data.coherence)
            .map(|(h, g)| {
                let g = if refused { 1.0 } else { g.clamp(1e-6, 1.0) };
                let var = (1.0 - g) / g + MODEL_ERROR_FLOOR * MODEL_ERROR_FLOOR;
                1.0 / (var.sqrt() * h.norm().max(f64::MIN_POSITIVE))
            })
            .collect()
    };
    Weights {
        scale,
        noise_estimated,
        dof,
        least_dof,
        noise_refused,
    }
}

/// The reference of a fit's weighted cost `Σₖ|eₖ|²` under the noise
/// alone, over lines whose variances have `dof` effective degrees of
/// freedom ([`Weights::dof`]) with `params` parameters fitted: each line
/// adds `2F(2, d)` (`χ²₂` for a known variance), of mean `2d/(d − 2)` and
/// variance `4d³/((d − 2)²(d − 4))` ([`MIN_SIGMA_DOF`]), both reduced by
/// `ν/2N` for the fitted parameters (`ν = 2N − p`). The cost is about
/// `g χ²_h` (Satterthwaite's scaled χ², matching the mean and the
/// variance; exact, `g = 1`, `h = ν`, for known variances). Returns
/// `(mean, bound)`: the expected cost and its `1 −`
/// [`RESIDUAL_TEST_LEVEL`] quantile `g ·` [`chi2_quantile`]`(h)`.
pub(crate) fn cost_reference(dof: &[f64], params: usize) -> (f64, f64) {
    let lines = dof.len();
    let nu = (2 * lines).saturating_sub(params).max(1) as f64;
    let shrink = nu / (2 * lines).max(1) as f64;
    let (mut mean, mut var) = (0.0, 0.0);
    for &d in dof {
        if d.is_finite() {
            // 2d/(d − 2) and 4d³/((d − 2)²(d − 4)), written in 1/d so that
            // a large d (1e196 in a CSV) gives the known-variance 2 and 4,
            // not ∞/∞.
            let r = 1.0 / d;
            mean += 2.0 / (1.0 - 2.0 * r);
            var += 4.0 / ((1.0 - 2.0 * r).powi(2) * (1.0 - 4.0 * r));
        } else {
            mean += 2.0;
            var += 4.0;
        }
    }
    let (mean, var) = (mean * shrink, var * shrink);
    let g = var / (2.0 * mean);
    (mean, g * chi2_quantile(mean / g))
}

/// The middle of the sandwich covariance `(JᵀJ)⁻¹ B (JᵀJ)⁻¹` of a fit
/// weighted by variances of `dof` effective degrees of freedom (one per
/// line, [`Weights::dof`]; `j` with rows `2k`, `2k + 1` for line `k`):
/// each line's `JₖᵀJₖ` times `d/(d − 4)`, `E[w²]σ²/E[w]` of a weight
/// `1/σ̂²` with `σ̂²` of `d` degrees of freedom (Pintelon & Schoukens 2012,
/// §10.3, whose `(M − 2)/(M − 3)` over the known-variance covariance is
/// this times the `(d − 2)/d` by which the estimated weights' `JᵀJ`
/// overstates the known one's). `None` when every variance is known (then
/// `B = JᵀJ`) or the rows do not match the lines.
pub(crate) fn weight_scatter(j: &DMatrix<f64>, dof: &[f64]) -> Option<DMatrix<f64>> {
    if !dof.iter().any(|d| d.is_finite()) || j.nrows() != 2 * dof.len() {
        return None;
    }
    let mut b = DMatrix::zeros(j.ncols(), j.ncols());
    for (k, d) in dof.iter().enumerate() {
        let x = if d.is_finite() { d / (d - 4.0) } else { 1.0 };
        let rows = j.rows(2 * k, 2);
        b += (rows.transpose() * rows) * x;
    }
    Some(b)
}

/// The Student-t weight `uₖ = (dₖ + 2)/(dₖ + |eₖ|²)` of each line at
/// `p`: `eₖ` the line's residual in the estimated standard deviations
/// ([`Prepared::cost`]'s), `dₖ` its variance's effective degrees of
/// freedom ([`Weights::dof`]; `uₖ = 1` where known). It is the
/// iteratively reweighted least-squares weight of the likelihood of `eₖ`
/// with `σ̂ₖ²` of `dₖ` degrees of freedom for its variance: the complex
/// residual over `σ̂ₖ` is a bivariate Student t of `dₖ` degrees of
/// freedom (`|eₖ|²/2 ~ F(2, dₖ)`), whose negative log-likelihood is
/// `(dₖ + 2)/2 · ln(1 + |eₖ|²/dₖ)` (Lange, Little & Taylor, *Robust
/// statistical modeling using the t distribution*, JASA 84, 1989, §3;
/// Pintelon & Schoukens 2012, §10.3, for the sample variances).
pub(super) fn student_t_weights(prep: &Prepared, p: &Params) -> Vec<f64> {
    (0..prep.len())
        .map(|k| {
            let d = prep.dof[k];
            if d.is_finite() {
                let e2 = ((prep.model(k, p) - prep.h[k]) * prep.scale[k]).norm_sqr();
                (d + 2.0) / (d + e2)
            } else {
                1.0
            }
        })
        .collect()
}

/// The bread `A = Σₖ dₖ/(dₖ + 2) · JₖᵀJₖ` of the Student-t estimate's
/// sandwich covariance `A⁻¹ (JᵀJ) A⁻¹`, for `j` the Jacobian of the
/// residuals weighted by `√uₖ` ([`student_t_weights`]; rows `2k`, `2k + 1`
/// for line `k`) and `dof` each line's degrees of freedom.
///
/// With `r` the line's residual in the true standard deviations and
/// `W = dₖσ̂²/σ² ~ χ²_d` independent of it, the estimating function is
/// `Gᵀ(d + 2) r/(W + |r|²)` (`G` the known-variance Jacobian).
/// `T = W + |r|² ~ χ²_{d+2}` is independent of `r₁²/T ~ Beta(½, (d + 1)/2)`,
/// so its slope is `E[(d + 2)(1/T − 2r₁²/T²)] = 1` and its variance
/// `(d + 2)² E[r₁²/T²] = (d + 2)/d`: the covariance is `(d + 2)/d ·
/// (GᵀG)⁻¹`, against `(d − 2)/(d − 4)` for weights `1/σ̂²` ([`weight_scatter`];
/// 4/3 against 2 at the default multisine's d = 6). `GᵀG` is estimated
/// by `d/(d + 2) · JᵀJ`, as `E[uₖ σ²/σ̂ₖ²] = E[(d + 2)/T] = (d + 2)/d`.
pub(crate) fn student_t_bread(j: &DMatrix<f64>, dof: &[f64]) -> DMatrix<f64> {
    let mut a = DMatrix::zeros(j.ncols(), j.ncols());
    for (k, d) in dof.iter().enumerate() {
        let x = if d.is_finite() { d / (d + 2.0) } else { 1.0 };
        let rows = j.rows(2 * k, 2);
        a += (rows.transpose() * rows) * x;
    }
    a
}

/// The Student-t estimate from `start` (an estimate weighted by the
/// variances as if known): the refinement reweighted by
/// [`student_t_weights`] until no weight moves by 10⁻⁴ (at most
/// [`STUDENT_T_ROUNDS`] rounds), and the prepared data carrying the final
/// weights ([`Prepared::student`], for its covariance). `None` when no
/// line's variance is estimated (then the start is the estimate).
pub(super) fn student_t<'a>(
    prep: &Prepared<'a>,
    start: &Params,
    period_s: f64,
) -> Option<(Prepared<'a>, Params)> {
    if !prep.noise_estimated || prep.dof.iter().all(|d| !d.is_finite()) {
        return None;
    }
    let mut p = start.clone();
    let mut robust = prep.clone();
    robust.student = Some(student_t_weights(prep, &p));
    for round in 1..=STUDENT_T_ROUNDS {
        p = super::search::sorted(refine(&robust, &p, period_s));
        let u = student_t_weights(prep, &p);
        let moved = u
            .iter()
            .zip(robust.student.as_deref().unwrap_or_default())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        robust.student = Some(u);
        if moved < 1e-4 || round == STUDENT_T_ROUNDS {
            tracing::debug!(round, moved, "modal fit: the Student-t reweighting");
            break;
        }
    }
    Some((robust, p))
}

/// The most reweighting rounds of [`student_t`].
pub(super) const STUDENT_T_ROUNDS: usize = 30;

/// The weights of [`weights`].
#[derive(Debug, Clone)]
pub struct Weights {
    /// `wₖ` per line, A/m.
    pub scale: Vec<f64>,
    /// The weights are inverse standard deviations estimated from the data
    /// (the weighted residual sum of squares is then a χ²); otherwise they
    /// are relative and the noise level comes from the residual.
    pub noise_estimated: bool,
    /// Effective degrees of freedom of each line's variance (infinite:
    /// known, or no noise estimate).
    pub dof: Vec<f64>,
    /// The fewest degrees of freedom any line's variance is stated with
    /// ([`FrfData::sigma_dof`]); `None`: known or not stated.
    pub least_dof: Option<f64>,
    /// Why σ per line was not used as the noise (too few degrees of
    /// freedom), when it was given.
    pub noise_refused: Option<String>,
}

/// Precomputed per-point data.
#[derive(Clone)]
pub(super) struct Prepared<'a> {
    pub(super) w: Vec<f64>,
    pub(super) h: &'a [C64],
    /// Weight over |H|: the residual is `scale · (Ĥ − H)`.
    pub(super) scale: Vec<f64>,
    /// The weights are inverse standard deviations ([`Weights`]).
    pub(super) noise_estimated: bool,
    /// Effective degrees of freedom of each line's variance ([`Weights::dof`]).
    pub(super) dof: Vec<f64>,
    /// [`Weights::noise_refused`].
    pub(super) noise_refused: Option<String>,
    /// [`Weights::least_dof`].
    pub(super) least_dof: Option<f64>,
    pub(super) gain: Vec<C64>,
    pub(super) coherent: Vec<bool>,
    /// The Student-t weight `uₖ` of each line ([`student_t_weights`]),
    /// by which the refinement's objective multiplies the line's squared
    /// residual; `None`: every `uₖ = 1`, the estimated variances taken as
    /// known (the search's objective).
    pub(super) student: Option<Vec<f64>>,
}

impl<'a> Prepared<'a> {
    pub(super) fn new(data: &'a FrfData, path: &Path) -> Self {
        let w: Vec<f64> = data.frequency_hz.iter().map(|f| 2.0 * PI * f).collect();
        let Weights {
            scale,
            noise_estimated,
            dof,
            least_dof,
            noise_refused,
        } = weights(data);
        let gain = w.iter().map(|&w| path.gain(w)).collect();
        let coherent = data.coherence.iter().map(|g| *g >= MIN_COHERENCE).collect();
        Self {
            w,
            h: &data.response,
            scale,
            noise_estimated,
            dof,
            noise_refused,
            least_dof,
            gain,
            coherent,
            student: None,
        }
    }

    /// The weight of line `k` in the refinement's objective: `scale[k]`
    /// times `√uₖ` under [`Self::student`].
    pub(super) fn fit_scale(&self, k: usize) -> f64 {
        match &self.student {
            Some(u) => self.scale[k] * u[k].sqrt(),
            None => self.scale[k],
        }
    }

    /// The refinement's objective `Σₖ uₖ|eₖ|²` ([`Self::cost`] without
    /// [`Self::student`]).
    pub(super) fn objective(&self, p: &Params) -> f64 {
        (0..self.len())
            .map(|k| ((self.model(k, p) - self.h[k]) * self.fit_scale(k)).norm_sqr())
            .sum()
    }

    pub(super) fn len(&self) -> usize {
        self.w.len()
    }

    /// `D(jω)` at point `k` with delay `tau_s`.
    pub(super) fn d(&self, k: usize, tau_s: f64) -> C64 {
        self.gain[k] * C64::from_polar(1.0, -self.w[k] * tau_s)
    }

    /// The linear basis at point `k` (before `D`): modes, `1/s²`, `1`.
    pub(super) fn basis(&self, k: usize, f_hz: &[f64], zeta: &[f64], out: &mut Vec<C64>) {
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
    pub(super) fn solve_linear(
        &self,
        f_hz: &[f64],
        zeta: &[f64],
        tau_s: f64,
    ) -> Option<(Vec<f64>, f64)> {
        self.solve_linear_in(0..self.len(), f_hz, zeta, tau_s)
    }

    /// [`Self::solve_linear`] over the points `range` only.
    pub(super) fn solve_linear_in(
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
            let d = self.d(k, tau_s) * self.fit_scale(k);
            self.basis(k, f_hz, zeta, &mut row);
            row.iter_mut().for_each(|c| *c *= d);
            let t = self.h[k] * self.fit_scale(k);
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
            let d = self.d(k, tau_s) * self.fit_scale(k);
            self.basis(k, f_hz, zeta, &mut row);
            let m: C64 = row.iter().zip(&coef).map(|(c, x)| c * x).sum();
            cost += (m * d - self.h[k] * self.fit_scale(k)).norm_sqr();
        }
        cost.is_finite().then_some((coef, cost))
    }

    /// The model at point `k`.
    pub(super) fn model(&self, k: usize, p: &Params) -> C64 {
        let s = C64::new(0.0, self.w[k]);
        let mut m = C64::new(p.l, 0.0) / (s * s) + p.u;
        for i in 0..p.f_hz.len() {
            let wn = 2.0 * PI * p.f_hz[i];
            m += p.a[i] / (s * s + s * (2.0 * p.zeta[i] * wn) + wn * wn);
        }
        self.d(k, p.tau_s) * m
    }

    /// The weighted cost `Σₖ|eₖ|²` (the χ² statistic of
    /// [`cost_reference`]), without [`Self::student`]'s weights.
    pub(super) fn cost(&self, p: &Params) -> f64 {
        (0..self.len())
            .map(|k| ((self.model(k, p) - self.h[k]) * self.scale[k]).norm_sqr())
            .sum()
    }
}

/// The Levenberg-Marquardt problem over all parameters:
/// `[ln f₁…, ln ζ₁…, A₁…, L, U, τ/T]`, with `A`, `L`, `U` scaled by their
/// starting magnitudes.
pub(super) struct Problem<'p, 'a> {
    pub(super) prep: &'p Prepared<'a>,
    pub(super) n_modes: usize,
    /// The start's coordinates.
    pub(super) x0: DVector<f64>,
    /// Scales of A₁…, L, U.
    pub(super) lin_scale: Vec<f64>,
    pub(super) period_s: f64,
}

impl Problem<'_, '_> {
    pub(super) fn new<'p, 'a>(
        prep: &'p Prepared<'a>,
        p: &Params,
        period_s: f64,
    ) -> Problem<'p, 'a> {
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
    pub(super) fn params_at(&self, x: &DVector<f64>) -> Params {
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
    pub(super) fn jacobian_of(&self, p: &Params) -> DMatrix<f64> {
        let n = self.n_modes;
        let m = self.prep.len();
        let mut j = DMatrix::<f64>::zeros(2 * m, 3 * n + 3);
        for k in 0..m {
            let s = C64::new(0.0, self.prep.w[k]);
            let sc = self.prep.fit_scale(k);
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
            let e = (self.prep.model(k, &p) - self.prep.h[k]) * self.prep.fit_scale(k);
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
pub(super) fn refine(prep: &Prepared, start: &Params, period_s: f64) -> Params {
    refine_within(prep, start, period_s, PATIENCE)
}

/// The refinement's bound on evaluations, × (n + 1) for n parameters.
pub(super) const PATIENCE: usize = 20;

/// [`refine`] with its bound on evaluations, `patience` × (n + 1).
pub(super) fn refine_within(
    prep: &Prepared,
    start: &Params,
    period_s: f64,
    patience: usize,
) -> Params {
    let problem = Problem::new(prep, start, period_s);
    let x = lsq::minimise(&problem, problem.x0.clone(), patience);
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
    if ok && prep.objective(&p) <= prep.objective(start) {
        p
    } else {
        start.clone()
    }
}

/// 1σ of every parameter in natural units (`[f…, ζ…, A…, L, U, τ]`),
/// from `s² (JᵀJ)⁻¹`: the square roots of [`covariance`]'s diagonal
/// (infinite where the data do not determine the parameter, never 0).
pub(super) fn sigmas(prep: &Prepared, p: &Params, period_s: f64) -> Vec<f64> {
    let cov = covariance(prep, p, period_s);
    (0..cov.nrows())
        .map(|i| {
            let v = cov[(i, i)];
            if v > 0.0 && v.is_finite() {
                v.sqrt()
            } else {
                f64::INFINITY
            }
        })
        .collect()
}

/// The parameters' covariance in natural units (`[f…, ζ…, A…, L, U, τ]`:
/// Hz, 1, m/A·(rad/s)², m/(A·s²), m/A, s; shape `(3n+3)²`), `s² (JᵀJ)⁻¹`
/// mapped from the fit's coordinates (`ln f`, `ln ζ`, the scaled linear
/// part, `τ/T`) by their derivatives. Its entries are infinite where
/// `JᵀJ` is not finite or cannot be inverted; a variance that is not
/// positive marks a parameter the data do not determine.
pub(super) fn covariance(prep: &Prepared, p: &Params, period_s: f64) -> DMatrix<f64> {
    let problem = Problem::new(prep, p, period_s);
    let j = problem.jacobian_of(p);
    let n = p.f_hz.len();
    // With σ per line from the data the weighted cost is a χ² with
    // 2m − (3n + 3) degrees of freedom: the 1σ come from (JᵀJ)⁻¹ as they
    // are, widened by the cost over its expectation when the model leaves
    // more than the noise (Birge ratio); without, the noise level is the
    // residual's.
    debug_assert_eq!(j.nrows(), 2 * prep.len());
    let s2 = residual_variance(prep, p, prep.cost(p));
    let jtj = j.transpose() * &j;
    // A weight from a variance of d degrees of freedom is random: the
    // estimate scatters as the sandwich A⁻¹ B A⁻¹ (`weight_scatter`,
    // `student_t_bread`).
    let (bread, meat) = match prep.student {
        Some(_) => (student_t_bread(&j, &prep.dof), Some(jtj)),
        None => {
            let b = weight_scatter(&j, &prep.dof);
            (jtj, b)
        }
    };
    let unknown = DMatrix::from_element(3 * n + 3, 3 * n + 3, f64::INFINITY);
    let cov = if !bread.iter().all(|v| v.is_finite()) {
        unknown
    } else {
        match bread.clone().try_inverse() {
            Some(c) => c,
            None => bread
                .try_svd(true, true, f64::EPSILON, 500)
                .and_then(|svd| svd.pseudo_inverse(1e-300).ok())
                .unwrap_or(unknown),
        }
    };
    let cov = match meat {
        Some(b) if cov.iter().all(|v| v.is_finite()) => &cov * b * &cov,
        _ => cov,
    };
    // d(natural)/d(coordinate) of each parameter.
    let scale: Vec<f64> = p
        .f_hz
        .iter()
        .chain(&p.zeta)
        .copied()
        .chain((0..n + 2).map(|i| problem.lin_scale[i]))
        .chain([period_s])
        .collect();
    DMatrix::from_fn(3 * n + 3, 3 * n + 3, |a, b| {
        s2 * cov[(a, b)] * scale[a] * scale[b]
    })
}

/// Parameters with the linear part re-solved for the given poles/delay.
pub(super) fn with_linear(
    prep: &Prepared,
    f_hz: Vec<f64>,
    zeta: Vec<f64>,
    tau_s: f64,
) -> Option<Params> {
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
