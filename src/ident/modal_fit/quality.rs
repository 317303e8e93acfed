//! The checks of a fit that can be wrong without failing: the χ² and
//! whiteness tests of the normalised residuals, and the per-mode flags
//! ([`FitQuality`]).

use super::*;

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
///   against its distribution under the noise alone (`N` lines, `p`
///   parameters, `ν = 2N − p`): `χ²_ν` when the variances are known, and
///   when they are estimated with `d` degrees of freedom
///   ([`crate::ident::frf::Frf::sigma_dof`]: a multisine's `2(M − 1)`)
///   a sum of `2F(2, d)`, whose mean is `d/(d − 2)` times larger
///   (`(M − 1)/(M − 2)`, 1.5 at M = 4: Pintelon & Schoukens, *System
///   Identification*, 2nd ed. 2012, §10.3) and whose tail is longer,
///   taken as the scaled `g χ²_h` of the same mean and variance
///   ([`cost_reference`]); flagged above its `1 − α` quantile,
///   α = [`RESIDUAL_TEST_LEVEL`], by the Wilson–Hilferty approximation
///   `h (1 − 2/(9h) + z_α √(2/(9h)))³` (Johnson, Kotz & Balakrishnan,
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
    /// `χ²/ν` of the normalised residuals (≈ `chi2_per_dof_expected`
    /// when the model explains the data to the noise); `null` without a
    /// noise estimate.
    pub chi2_per_dof: Option<f64>,
    /// What `χ²/ν` is expected to be under the noise alone: 1 for known
    /// variances, `d/(d − 2)` for variances of `d` degrees of freedom
    /// (1.5 for a multisine's four realizations; less where the model
    /// error floor, known, dominates a line's weight). Absent in JSON
    /// written before it existed.
    #[serde(default)]
    pub chi2_per_dof_expected: Option<f64>,
    /// The `1 − α` bound of `χ²/ν` at this `ν` and these degrees of
    /// freedom.
    pub chi2_per_dof_bound: Option<f64>,
    /// The fewest degrees of freedom of a line's variance estimate
    /// ([`crate::ident::frf::Frf::sigma_dof`]); `null`: known or not
    /// stated.
    #[serde(default)]
    pub sigma_dof: Option<f64>,
    /// Why σ per line was not taken as the noise (too few degrees of
    /// freedom); `null` when it was, or none was given.
    #[serde(default)]
    pub noise_refused: Option<String>,
    /// Ljung–Box `Q` of the normalised residuals; `null` without a noise
    /// estimate (nothing to judge a correlation against).
    pub whiteness_q: Option<f64>,
    /// Its `1 − α` bound (χ² with `2h` degrees of freedom).
    pub whiteness_q_bound: f64,
    /// Why the fit is not to be trusted; empty when it passed.
    pub flags: Vec<String>,
    /// Further modes the data hint at but cannot decide (see
    /// [`UndecidedMode`]): not in the model, reported so that a reader
    /// knows the model order could be one more. Absent in JSON written
    /// before it existed.
    #[serde(default)]
    pub undecided_modes: Vec<UndecidedMode>,
    /// The weakest further mode the fit would have found, over its band
    /// ([`DetectionLimit`]): a weaker one may be missed without a flag.
    /// `null` without a noise estimate per line or a fitted mode; absent
    /// in JSON written before it existed.
    #[serde(default)]
    pub detection_limit: Option<DetectionLimit>,
}

/// A mode the data cannot decide. Modes are added while the residual is
/// not the noise (the χ² and whiteness tests of [`FitQuality`]); those
/// tests judge the whole band, and a weak mode that changes a few lines
/// passes them. So once they pass, the best further mode is still sought
/// ([`probe`]): it is reported when it lowers the weighted cost by
/// `delta_chi2` noise variances (the cost removed over the expected cost
/// per degree of freedom), more than the noise alone gives at the best of
/// the `N` lines it could sit on, the `χ²₃` quantile at
/// [`RESIDUAL_TEST_LEVEL`]` / N` (a mode is three parameters; Bonferroni
/// over the lines: 30.1 for 767 lines), and its modal constant lies at
/// least [`MIN_SIGNIFICANCE`] of its 1σ from zero. It is not added: the
/// path model's error and a multisine's heavy-tailed variance estimates
/// reach that level on some fits without a mode (`tests/cli/mode_count.rs`:
/// a few in a hundred, at 14–22 Hz where the chirp's amplitude falls),
/// and a real mode there is the weak one of a pair closer than its
/// half-power bandwidth, which a chirp's smoothed estimate cannot
/// separate. Where it lies among the closely spaced pair, the pair's labels
/// are unsure ([`ModalFit::labels_unsure`]), and the phase test does not
/// decide.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct UndecidedMode {
    /// Natural frequency, Hz.
    pub frequency_hz: f64,
    /// Damping ratio.
    pub damping_ratio: f64,
    /// Modal constant, m/(A·s²).
    pub modal_constant: f64,
    /// `|A| / σ_A` of the modal constant in the model with the mode.
    pub modal_constant_z: f64,
    /// The cost it removes over the expected cost per degree of freedom
    /// (`Δχ²` in noise variances).
    pub delta_chi2: f64,
    /// The level `Δχ²` exceeds: the `χ²₃` quantile at
    /// [`RESIDUAL_TEST_LEVEL`]` / N` over the fit's `N` lines.
    pub delta_chi2_level: f64,
}

impl UndecidedMode {
    /// One line for a report.
    pub fn line(&self) -> String {
        format!(
            "a further mode near {:.2} Hz (damping {:.4}, modal constant {:+.3e} m/(A·s²), {:.1}σ) would lower χ² by {:.1}, above the {:.1} the noise reaches at the best of all lines once in a thousand fits, while the residual is already the noise: the data cannot decide it, not added",
            self.frequency_hz,
            self.damping_ratio,
            self.modal_constant,
            self.modal_constant_z,
            self.delta_chi2,
            self.delta_chi2_level
        )
    }
}

/// Standard normal quantile at `1 − RESIDUAL_TEST_LEVEL` (3.0902).
pub(super) const Z_LEVEL: f64 = 3.090_232_306_167_813;

/// The `1 − α` quantile of χ² with `nu` degrees of freedom
/// (Wilson–Hilferty, [`FitQuality`]).
pub fn chi2_quantile(nu: f64) -> f64 {
    let a = 2.0 / (9.0 * nu);
    nu * (1.0 - a + Z_LEVEL * a.sqrt()).powi(3)
}

/// `P(χ²₃ > x)`: `erfc(√(x/2)) + √(2x/π) e^{−x/2}` (Abramowitz & Stegun
/// 26.4.5 for three degrees of freedom).
pub fn chi2_3_tail(x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    libm::erfc((0.5 * x).sqrt()) + (2.0 * x / PI).sqrt() * (-0.5 * x).exp()
}

/// The `1 − alpha` quantile of χ²₃ ([`chi2_3_tail`] solved by bisection;
/// `alpha` in (0, 1)).
pub fn chi2_3_quantile(alpha: f64) -> f64 {
    let (mut lo, mut hi) = (0.0_f64, 1.0_f64);
    while chi2_3_tail(hi) > alpha && hi < 1e4 {
        hi *= 2.0;
    }
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if chi2_3_tail(mid) > alpha {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Trial damping ratios of [`try_mode`]: a mode whose damping still
/// equals one of them after the final refinement was never refined.
pub(super) const TRIAL_DAMPING: [f64; 3] = [0.003, 0.01, 0.03];

/// The checks of [`FitQuality`] for parameters `p` with 1σ `sd`
/// ([`sigmas`]).
pub(super) fn quality(prep: &Prepared, p: &Params, sd: &[f64]) -> FitQuality {
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
    let t = residual_tests(prep, p);
    let (chi2_per_dof, chi2_per_dof_bound) = match t.chi2_per_dof {
        Some((c, bound)) => {
            if c > bound {
                flags.push(format!(
                    "the residual exceeds the estimated noise: χ²/ν = {c:.2} over {} lines (expected {:.2}, bound {bound:.2} at the {} level): the model misses part of the response",
                    t.lines, t.chi2_per_dof_expected.unwrap_or(1.0), RESIDUAL_TEST_LEVEL
                ));
            }
            (Some(c), Some(bound))
        }
        None => (None, None),
    };
    let (q, q_bound) = (t.whiteness_q, t.whiteness_q_bound);
    if let Some(q) = q.filter(|q| *q > q_bound) {
        flags.push(format!(
            "the residual is not white along frequency: Ljung–Box Q = {q:.1} over {WHITENESS_LAGS} lags (bound {q_bound:.1} at the {RESIDUAL_TEST_LEVEL} level): a structure the model does not have"
        ));
    }
    FitQuality {
        checked: true,
        noise_estimated: prep.noise_estimated,
        lines: t.lines,
        chi2_per_dof,
        chi2_per_dof_expected: t.chi2_per_dof_expected,
        chi2_per_dof_bound,
        sigma_dof: prep.least_dof,
        noise_refused: prep.noise_refused.clone(),
        whiteness_q: q,
        whiteness_q_bound: q_bound,
        flags,
        undecided_modes: Vec::new(),
        detection_limit: None,
    }
}

/// The two residual tests of [`FitQuality`] for parameters `p`: χ²/ν
/// against the estimated noise with its bound, and the Ljung–Box Q of
/// the residual along frequency with its bound, both at
/// [`RESIDUAL_TEST_LEVEL`] (`None` without a noise estimate).
pub(super) struct ResidualTests {
    pub lines: usize,
    /// (χ²/ν, its bound).
    pub chi2_per_dof: Option<(f64, f64)>,
    /// χ²/ν's expectation under the noise alone.
    pub chi2_per_dof_expected: Option<f64>,
    pub whiteness_q: Option<f64>,
    pub whiteness_q_bound: f64,
}

impl ResidualTests {
    /// Whether both tests pass: the residual is the noise, and no further
    /// mode can be told from it at the tests' level.
    pub fn residual_is_noise(&self) -> bool {
        matches!(self.chi2_per_dof, Some((c, b)) if c <= b)
            && self
                .whiteness_q
                .is_some_and(|q| q <= self.whiteness_q_bound)
    }
}

pub(super) fn residual_tests(prep: &Prepared, p: &Params) -> ResidualTests {
    let n = p.f_hz.len();
    let e: Vec<C64> = (0..prep.len())
        .map(|k| (prep.model(k, p) - prep.h[k]) * prep.scale[k])
        .collect();
    let lines = e.len();
    let params = 3 * n + 3;
    let nu = (2 * lines).saturating_sub(params).max(1) as f64;
    let chi2: f64 = e.iter().map(|v| v.norm_sqr()).sum();
    let (mean, bound) = cost_reference(&prep.dof, params);
    let chi2_per_dof = prep.noise_estimated.then(|| (chi2 / nu, bound / nu));
    let chi2_per_dof_expected = prep.noise_estimated.then_some(mean / nu);
    // Against the estimated noise: the lag products are compared with
    // what unit-variance noise gives (N), so a correlated residual far
    // below the noise (χ²/ν ≪ 1: a model error the data cannot see) does
    // not count; a residual above the noise is scaled to it (the χ² test
    // has judged its size). Without a noise estimate there is nothing to
    // judge a correlation against: not tested.
    let whiteness_q_bound = chi2_quantile(2.0 * WHITENESS_LAGS as f64);
    let whiteness_q = prep.noise_estimated.then(|| {
        // Unit variance in each part: E|eₖ|² = 2 under a known noise
        // (2d/(d − 2) under one estimated with d degrees of freedom).
        // (The unshrunk expectation: `mean` is less the fitted parameters.)
        let energy = chi2.max(mean * 2.0 * lines as f64 / nu);
        (1..=WHITENESS_LAGS.min(lines.saturating_sub(1)))
            .map(|j| {
                let r: C64 = (0..lines - j).map(|k| e[k] * e[k + j].conj()).sum();
                (r / energy).norm_sqr()
            })
            .sum::<f64>()
            * 2.0
            * lines as f64
    });
    ResidualTests {
        lines,
        chi2_per_dof,
        chi2_per_dof_expected,
        whiteness_q,
        whiteness_q_bound,
    }
}
