//! The least-squares problem of an update: the target (measured natural
//! frequencies or a measured FRF), the residuals in the free parameters'
//! coordinates, the minimisation and the 1σ from the Jacobian.

use super::*;

/// The least-squares target.
pub(super) enum Target<'a> {
    /// Measured natural frequencies, Hz, each paired with a model mode.
    Frequencies {
        measured_hz: &'a [f64],
        mode: Vec<usize>,
    },
    /// A measured FRF; the last fitted coordinate is `τ/T`.
    Frf(&'a Prepared<'a>),
}

/// Per-point FRF data.
pub(super) struct Prepared<'a> {
    pub(super) frequency_hz: &'a [f64],
    pub(super) h: &'a [C64],
    /// Weight of each line (the modal fit's, [`modal_fit::weights`]).
    pub(super) scale: Vec<f64>,
    /// The weights are inverse standard deviations from the data.
    pub(super) noise_estimated: bool,
    /// Effective degrees of freedom of each line's variance
    /// ([`modal_fit::Weights::dof`]).
    pub(super) dof: Vec<f64>,
    /// The path without its delay.
    pub(super) gain: Vec<C64>,
    pub(super) coherent: Vec<bool>,
    pub(super) period_s: f64,
}

impl<'a> Prepared<'a> {
    pub(super) fn new(data: &'a FrfData, path: &Path) -> Self {
        let w = modal_fit::weights(data);
        Self {
            frequency_hz: &data.frequency_hz,
            h: &data.response,
            scale: w.scale,
            noise_estimated: w.noise_estimated,
            dof: w.dof,
            gain: data
                .frequency_hz
                .iter()
                .map(|&f| path.response(f, 0.0))
                .collect(),
            coherent: data.coherence.iter().map(|g| *g >= MIN_COHERENCE).collect(),
            period_s: path.period_s,
        }
    }

    /// `G·D` at point `k` for `model`, per N/A of force constant.
    pub(super) fn g(&self, model: &Sr4dof, k: usize, tau_s: f64) -> C64 {
        let f = self.frequency_hz[k];
        model.force_frf(f) * self.gain[k] * C64::from_polar(1.0, -2.0 * PI * f * tau_s)
    }

    /// Weighted least-squares force constant for `model` and `tau_s`.
    pub(super) fn best_force_constant(&self, model: &Sr4dof, tau_s: f64) -> f64 {
        let (mut num, mut den) = (0.0, 0.0);
        for k in 0..self.h.len() {
            let g = self.g(model, k, tau_s);
            let s2 = self.scale[k] * self.scale[k];
            num += s2 * (g.conj() * self.h[k]).re;
            den += s2 * g.norm_sqr();
        }
        num / den
    }

    /// RMS relative error over the coherent points.
    pub(super) fn rms_error(&self, b: &Bench, model: &Sr4dof, tau_s: f64) -> f64 {
        let (mut sum, mut n) = (0.0, 0usize);
        for k in (0..self.h.len()).filter(|&k| self.coherent[k]) {
            let e = self.g(model, k, tau_s) * b.force_constant_n_per_a - self.h[k];
            sum += e.norm_sqr() / self.h[k].norm_sqr();
            n += 1;
        }
        (sum / n.max(1) as f64).sqrt()
    }
}

/// One least-squares problem: the free parameters of `start` against a
/// target.
pub(super) struct Problem<'a> {
    pub(super) start: Bench,
    pub(super) free: &'a [Parameter],
    pub(super) target: &'a Target<'a>,
    /// The start's coordinates.
    pub(super) x0: DVector<f64>,
}

impl<'a> Problem<'a> {
    pub(super) fn new(
        start: Bench,
        free: &'a [Parameter],
        target: &'a Target<'a>,
        tau_s: f64,
    ) -> Self {
        let mut x: Vec<f64> = free
            .iter()
            .map(|p| p.to_x(&start, p.value(&start)))
            .collect();
        if let Target::Frf(prep) = target {
            x.push(tau_s / prep.period_s);
        }
        Self {
            start,
            free,
            target,
            x0: DVector::from_vec(x),
        }
    }

    pub(super) fn bench_at(&self, x: &DVector<f64>) -> Bench {
        let mut b = self.start;
        for (i, p) in self.free.iter().enumerate() {
            p.set(&mut b, p.value_at_x(&self.start, x[i]));
        }
        b
    }

    pub(super) fn tau_at(&self, x: &DVector<f64>) -> f64 {
        match self.target {
            Target::Frf(prep) => x[self.free.len()] * prep.period_s,
            Target::Frequencies { .. } => 0.0,
        }
    }

    pub(super) fn len(&self) -> usize {
        match self.target {
            Target::Frequencies { measured_hz, .. } => measured_hz.len(),
            Target::Frf(prep) => 2 * prep.h.len(),
        }
    }

    /// The residuals at `x`; `None` outside the ranges.
    pub(super) fn residuals_at(&self, x: &DVector<f64>) -> Option<DVector<f64>> {
        if x.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let b = self.bench_at(x);
        let model = b.model()?;
        let r = match self.target {
            Target::Frequencies { measured_hz, mode } => DVector::from_iterator(
                measured_hz.len(),
                measured_hz
                    .iter()
                    .zip(mode)
                    .map(|(f, &i)| model.modes()[i].frequency_hz() / f - 1.0),
            ),
            Target::Frf(prep) => {
                let tau = self.tau_at(x);
                let mut r = DVector::zeros(2 * prep.h.len());
                for k in 0..prep.h.len() {
                    let e = (prep.g(&model, k, tau) * b.force_constant_n_per_a - prep.h[k])
                        * prep.scale[k];
                    r[2 * k] = e.re;
                    r[2 * k + 1] = e.im;
                }
                r
            }
        };
        r.iter().all(|v| v.is_finite()).then_some(r)
    }

    /// Central-difference Jacobian at `x`.
    pub(super) fn jacobian_at(&self, x: &DVector<f64>) -> Option<DMatrix<f64>> {
        let mut j = DMatrix::zeros(self.len(), x.len());
        for c in 0..x.len() {
            let h = JACOBIAN_STEP * x[c].abs().max(1.0);
            let (mut xp, mut xm) = (x.clone(), x.clone());
            xp[c] += h;
            xm[c] -= h;
            match (self.residuals_at(&xp), self.residuals_at(&xm)) {
                (Some(rp), Some(rm)) => j.set_column(c, &((rp - rm) / (2.0 * h))),
                // At a range edge: one-sided.
                (Some(rp), None) => j.set_column(c, &((rp - self.residuals_at(x)?) / h)),
                (None, Some(rm)) => j.set_column(c, &((self.residuals_at(x)? - rm) / h)),
                (None, None) => return None,
            }
        }
        Some(j)
    }

    pub(super) fn cost_at(&self, x: &DVector<f64>) -> f64 {
        self.residuals_at(x)
            .map_or(f64::INFINITY, |r| r.norm_squared())
    }
}

impl Residuals for Problem<'_> {
    fn residuals(&self, x: &DVector<f64>) -> Option<DVector<f64>> {
        // Outside the ranges: a residual larger than any fit's, so that
        // Levenberg-Marquardt shortens the step instead of stopping.
        Some(
            self.residuals_at(x)
                .unwrap_or_else(|| DVector::from_element(self.len(), 1e10)),
        )
    }

    fn jacobian(&self, x: &DVector<f64>) -> Option<DMatrix<f64>> {
        self.jacobian_at(x)
    }
}

/// Minimises from the problem's start; returns the optimum and its cost.
pub(super) fn minimise(problem: Problem) -> (DVector<f64>, f64) {
    let x0 = problem.x0.clone();
    let c0 = problem.cost_at(&x0);
    let x = lsq::minimise(&problem, x0.clone(), 50);
    let c = problem.cost_at(&x);
    if c <= c0 {
        (x, c)
    } else {
        (x0, c0)
    }
}

/// The 1σ of each coordinate, `s² (JᵀJ)⁻¹` (`None` where not estimable).
/// `s²` is the residual variance per degree of freedom, or with
/// `noise_estimated` (weights that are inverse standard deviations from
/// the data, [`modal_fit::weights`]) the cost over its expectation under
/// the noise alone, at least 1: the noise's own covariance, widened when
/// the model leaves more than the noise. With variances of `line_dof`
/// degrees of freedom (one per FRF line; empty: known) the covariance is
/// the sandwich of weights `1/σ̂²` taken as known, each line's `JₖᵀJₖ`
/// times `d/(d − 4)` (`modal_fit::weight_scatter`; the update is not
/// reweighted, the modal fit's final estimate is its Student t).
pub(super) fn coordinate_sigmas(
    problem: &Problem,
    x: &DVector<f64>,
    cost: f64,
    noise_estimated: bool,
    line_dof: &[f64],
) -> Vec<Option<f64>> {
    let n = x.len();
    let dof = problem.len() as f64 - n as f64;
    let Some(j) = problem.jacobian_at(x).filter(|_| dof > 0.0) else {
        return vec![None; n];
    };
    let s2 = if noise_estimated && !line_dof.is_empty() {
        (cost / modal_fit::cost_reference(line_dof, n).0).max(1.0)
    } else if noise_estimated {
        (cost / dof).max(1.0)
    } else {
        cost / dof
    };
    let jtj = j.transpose() * &j;
    let sandwich = modal_fit::weight_scatter(&j, line_dof);
    match jtj.try_inverse() {
        Some(cov) => {
            let cov = match sandwich {
                Some(b) => &cov * b * &cov,
                None => cov,
            };
            (0..n)
                .map(|i| {
                    let v = s2 * cov[(i, i)];
                    (v.is_finite() && v >= 0.0).then(|| v.sqrt())
                })
                .collect()
        }
        None => vec![None; n],
    }
}

/// Every strictly increasing map of `n` measured modes into the model's
/// four.
pub(super) fn order_preserving(n: usize) -> Vec<Vec<usize>> {
    let mut out = Vec::new();
    for mask in 0u32..16 {
        if mask.count_ones() as usize == n {
            out.push((0..4).filter(|i| mask & (1 << i) != 0).collect());
        }
    }
    out
}

/// The result of step 1: the bench, the model mode of each measured
/// frequency, the cost and the 1σ of each free coordinate.
pub(super) type FrequencyFit = (Bench, Vec<usize>, f64, Vec<Option<f64>>);

/// Step 1: the frequency-shaping free parameters fitted to `measured_hz`
/// from `start`, with the best order-preserving pairing.
pub(super) fn fit_frequencies(
    start: Bench,
    free: &[Parameter],
    measured_hz: &[f64],
) -> Option<FrequencyFit> {
    let mut best: Option<FrequencyFit> = None;
    for mode in order_preserving(measured_hz.len()) {
        let target = Target::Frequencies { measured_hz, mode };
        let problem = Problem::new(start, free, &target, 0.0);
        let (x, cost) = minimise(problem);
        if !cost.is_finite() || best.as_ref().is_some_and(|b| b.2 <= cost) {
            continue;
        }
        let problem = Problem::new(start, free, &target, 0.0);
        let sig = coordinate_sigmas(&problem, &x, cost, false, &[]);
        let bench = problem.bench_at(&x);
        let Target::Frequencies { mode, .. } = target else {
            unreachable!()
        };
        best = Some((bench, mode, cost, sig));
    }
    best
}
