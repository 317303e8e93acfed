//! What a fit could have missed: the detection limit of a further mode
//! ([`DetectionLimit`]).

use super::*;

/// Probability with which a mode at the detection limit is found.
pub const DETECTION_PROBABILITY: f64 = 0.95;
/// Grid points per decade of the detection limit over the coherent band.
pub const DETECTION_POINTS_PER_DECADE: f64 = 20.0;
/// The unresolved band around a fitted mode, in half-power overlaps
/// ([`DetectionLimit`]).
pub const UNRESOLVED_FACTOR: f64 = 2.0;
/// Distances from each fitted mode at which the limit is also stated (a
/// partner of a closely spaced pair), as frequency ratios.
pub const BESIDE_RATIOS: [f64; 3] = [1.01, 1.02, 1.05];

/// The weakest further mode the fit would have found, over its band.
///
/// A mode the fit does not hold, of modal constant `A` (m/(A·s²)) at
/// `f₀` with damping `ζ₀`, lowers the weighted cost, every fitted
/// parameter refitted, by `A² q(f₀)` to first order, with
/// `q = ‖(I − U Uᵀ) v‖²`: `v` the weighted response of a unit mode
/// `D(jω)/(s² + 2ζ₀ω₀s + ω₀²)` on every line (real and imaginary parts,
/// the residual's weights) and `U` an orthonormal basis of the columns of
/// the fit's Jacobian at its optimum — the part of the mode the fitted
/// model cannot absorb (a mode beside a fitted one is mostly absorbed by
/// moving it). With the noise, the cost it removes, in noise variances
/// (the cost per degree of freedom `s²` of [`UndecidedMode`]), is a
/// noncentral `χ²₃` (frequency, damping and modal constant fitted) of
/// noncentrality `λ = A² q / s²`. The fit reports a mode (adds it, or
/// names it undecided) when that exceeds the level `c` of
/// [`UndecidedMode`] (`χ²₃` at [`RESIDUAL_TEST_LEVEL`]` / N`): with
/// probability `P = P(χ²₃(λ) > c)`. The limit at `f₀` is the `|A|` of the
/// `λ` that gives [`DETECTION_PROBABILITY`]: `√(λ s² / q(f₀))`; a mode
/// weaker than it may be missed, and is not flagged.
///
/// Two modes whose half-power bands overlap (`|f₀ − fᵢ| < ζᵢfᵢ + ζ₀f₀`)
/// are not told apart at any strength by a fit (one mode between them
/// explains both; Ewins, *Modal Testing*, §4.3), and up to about twice
/// that the first-order analysis above overstates what the data show: a
/// fitted mode does more than move, it stands for both (a pair 1.1 %
/// apart with opposite constants, −0.21 and +0.074 m/(A·s²), fitted at
/// 10 % probe noise as one mode of −0.145 with 72 % of the truth's
/// damping: the partner 3.3 times the first-order limit, the residual
/// white; `tests/cli/real_links.rs`). Around each fitted mode the band
/// `|f₀ − fᵢ| < `[`UNRESOLVED_FACTOR`]` (ζᵢfᵢ + ζ₀f₀)` is stated as
/// unresolved, with no limit.
///
/// `ζ₀` follows Rayleigh's law `ζ = α/(2ω) + βω/2` fitted to the fitted
/// modes (the plant model's damping, thesis §5.2.2; least squares on the
/// relative error, `α, β ≥ 0`); with one fitted mode, the law whose
/// least damping is that mode's, at its frequency. Only
/// with a noise estimate per line (without one the fit adds modes by
/// [`MIN_IMPROVEMENT`], not against a noise) and at least one fitted mode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct DetectionLimit {
    /// Probability with which a mode at the limit is found.
    pub probability: f64,
    /// The cost a mode must remove to be reported, in noise variances.
    pub delta_chi2_level: f64,
    /// The noncentrality `λ` that reaches it with `probability`.
    pub noncentrality: f64,
    /// Rayleigh's `α` of the assumed damping, 1/s.
    pub rayleigh_alpha_per_s: f64,
    /// Rayleigh's `β`, s.
    pub rayleigh_beta_s: f64,
    /// Around each fitted mode, in its order, the band `[lo, hi]` (Hz)
    /// within [`UNRESOLVED_FACTOR`] half-power overlaps of it: no limit
    /// there.
    pub unresolved_hz: Vec<[f64; 2]>,
    /// Frequencies, Hz, ascending: a log grid of
    /// [`DETECTION_POINTS_PER_DECADE`] over the coherent band and the
    /// points [`BESIDE_RATIOS`] from each fitted mode, outside the
    /// unresolved bands.
    pub frequency_hz: Vec<f64>,
    /// The limit `|A|` at each, m/(A·s²).
    pub modal_constant: Vec<f64>,
    /// The limit beside each fitted mode, in its order: the larger of the
    /// two sides at each of [`BESIDE_RATIOS`], m/(A·s²).
    pub beside_modes: Vec<BesideMode>,
}

/// The detection limit beside one fitted mode ([`DetectionLimit`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct BesideMode {
    /// The fitted mode's frequency, Hz.
    pub frequency_hz: f64,
    /// Its modal constant, m/(A·s²).
    pub modal_constant: f64,
    /// The limit at each of [`BESIDE_RATIOS`] (the larger side),
    /// m/(A·s²); `None` where both sides are unresolved.
    pub limit: Vec<Option<f64>>,
}

impl DetectionLimit {
    /// Damping ratio assumed for a mode at `frequency_hz`.
    pub fn damping_at(&self, frequency_hz: f64) -> f64 {
        rayleigh(
            self.rayleigh_alpha_per_s,
            self.rayleigh_beta_s,
            frequency_hz,
        )
    }

    /// The limit at `frequency_hz`, m/(A·s²), interpolated in log–log
    /// between the grid's points; `None` outside the grid or in an
    /// unresolved band.
    pub fn at(&self, frequency_hz: f64) -> Option<f64> {
        if self.unresolved(frequency_hz) {
            return None;
        }
        let f = &self.frequency_hz;
        let i = f.partition_point(|x| *x < frequency_hz);
        if i == 0 || i == f.len() {
            return (f.first() == Some(&frequency_hz)).then(|| self.modal_constant[0]);
        }
        let t = (frequency_hz / f[i - 1]).ln() / (f[i] / f[i - 1]).ln();
        let (a, b) = (self.modal_constant[i - 1].ln(), self.modal_constant[i].ln());
        Some((a + t * (b - a)).exp())
    }

    /// Whether `frequency_hz` lies in a fitted mode's unresolved band.
    pub fn unresolved(&self, frequency_hz: f64) -> bool {
        self.unresolved_hz
            .iter()
            .any(|[lo, hi]| (*lo..=*hi).contains(&frequency_hz))
    }

    /// One line for a report: the largest limit beyond 5 % of every
    /// fitted mode, the unresolved bands, and beside each fitted mode the
    /// limit as a share of its own modal constant.
    pub fn line(&self) -> String {
        let far = |f: f64| {
            self.beside_modes
                .iter()
                .all(|m| (f / m.frequency_hz).ln().abs() > 0.05f64.ln_1p())
        };
        let worst = self
            .frequency_hz
            .iter()
            .zip(&self.modal_constant)
            .filter(|(f, _)| far(**f))
            .max_by(|a, b| a.1.total_cmp(b.1));
        let mut s = format!(
            "a further mode is found with {:.0} % probability when its |modal constant| reaches the limit (damping by the fitted modes' Rayleigh law ζ = {:.3}/(2ω) + {:.2e}·ω/2)",
            100.0 * self.probability,
            self.rayleigh_alpha_per_s,
            self.rayleigh_beta_s
        );
        if let Some((f, a)) = worst {
            s += &format!(
                "; beyond 5 % of every fitted mode the highest limit is {a:.2e} m/(A·s²), at {f:.1} Hz"
            );
        }
        let bands: Vec<String> = self
            .unresolved_hz
            .iter()
            .map(|[lo, hi]| format!("{lo:.2}–{hi:.2} Hz"))
            .collect();
        if !bands.is_empty() {
            s += &format!(
                "; within twice a fitted mode's half-power overlap a second mode is not told apart at any strength: {}",
                bands.join(", ")
            );
        }
        let beside: Vec<String> = self
            .beside_modes
            .iter()
            .map(|m| {
                let shares: Vec<String> = BESIDE_RATIOS
                    .iter()
                    .zip(&m.limit)
                    .map(|(r, l)| {
                        let away = 100.0 * (r - 1.0);
                        match l {
                            Some(l) => format!(
                                "{away:.0} % away {:.2} %",
                                100.0 * l / m.modal_constant.abs()
                            ),
                            None => format!("{away:.0} % away unresolved"),
                        }
                    })
                    .collect();
                format!("{:.2} Hz: {}", m.frequency_hz, shares.join(", "))
            })
            .collect();
        if !beside.is_empty() {
            s += &format!(
                "; beside each fitted mode, the limit as a share of its own modal constant: {}; a weaker mode may be missed without a flag",
                beside.join("; ")
            );
        }
        s
    }
}

/// `ζ(f) = α/(2ω) + βω/2`, clamped to the fit's damping range.
fn rayleigh(alpha: f64, beta: f64, frequency_hz: f64) -> f64 {
    let w = 2.0 * PI * frequency_hz;
    (alpha / (2.0 * w) + beta * w / 2.0).clamp(MIN_DAMPING, MAX_DAMPING)
}

/// Rayleigh's `(α, β ≥ 0)` for the modes `(f_hz, zeta)`: least squares on
/// the relative error (both terms, or the better of either alone when
/// both would have one negative); for one mode, the law whose least
/// damping is that mode's, at its frequency (`α = ζω`, `β = ζ/ω`: away
/// from it a mode is assumed more damped, so harder to see, and the
/// limit errs high). `None` without a mode.
fn rayleigh_fit(f_hz: &[f64], zeta: &[f64]) -> Option<(f64, f64)> {
    let pts: Vec<(f64, f64)> = f_hz
        .iter()
        .zip(zeta)
        .filter(|(f, z)| f.is_finite() && z.is_finite() && **z > 0.0)
        .map(|(f, z)| (2.0 * PI * f, *z))
        .collect();
    let err = |a: f64, b: f64| -> f64 {
        pts.iter()
            .map(|(w, z)| ((a / (2.0 * w) + b * w / 2.0) / z - 1.0).powi(2))
            .sum()
    };
    // One term alone: Σ (c xᵢ − 1)² is least at c = Σxᵢ / Σxᵢ².
    let alone = |x: &dyn Fn(f64, f64) -> f64| -> f64 {
        let (s1, s2) = pts.iter().fold((0.0, 0.0), |(s1, s2), (w, z)| {
            let v = x(*w, *z);
            (s1 + v, s2 + v * v)
        });
        s1 / s2
    };
    match pts.len() {
        0 => None,
        1 => {
            let (w, z) = pts[0];
            Some((z * w, z / w))
        }
        _ => {
            // Both: the 2×2 normal equations of rows [1/(2ωζ), ω/(2ζ)].
            let (mut g11, mut g12, mut g22, mut r1, mut r2) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for (w, z) in &pts {
                let (x1, x2) = (1.0 / (2.0 * w * z), w / (2.0 * z));
                g11 += x1 * x1;
                g12 += x1 * x2;
                g22 += x2 * x2;
                r1 += x1;
                r2 += x2;
            }
            let det = g11 * g22 - g12 * g12;
            let both = (det.abs() > 0.0)
                .then(|| ((g22 * r1 - g12 * r2) / det, (g11 * r2 - g12 * r1) / det))
                .filter(|(a, b)| *a >= 0.0 && *b >= 0.0 && a.is_finite() && b.is_finite());
            let a_only = alone(&|w, z| 1.0 / (2.0 * w * z));
            let b_only = alone(&|w, z| w / (2.0 * z));
            [both, Some((a_only, 0.0)), Some((0.0, b_only))]
                .into_iter()
                .flatten()
                .filter(|(a, b)| a.is_finite() && b.is_finite())
                .min_by(|x, y| err(x.0, x.1).total_cmp(&err(y.0, y.1)))
        }
    }
}

/// `P(χ²₃(λ) > x)`, the tail of the noncentral χ² with three degrees of
/// freedom: the Poisson mixture `Σⱼ e^{−λ/2}(λ/2)ʲ/j! · Q(3/2 + j, x/2)`
/// (Johnson, Kotz & Balakrishnan, *Continuous Univariate Distributions*
/// 2, Eq. 29.2), `Q` the regularised upper incomplete gamma function by
/// its recurrence `Q(a + 1, y) = Q(a, y) + yᵃe^{−y}/Γ(a + 1)` from
/// `Q(3/2, y)` = [`chi2_3_tail`]`(2y)` (A&S 6.5.21).
pub fn noncentral_chi2_3_tail(lambda: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let mu = 0.5 * lambda.max(0.0);
    let y = 0.5 * x;
    let mut q = chi2_3_tail(x);
    // yᵃe^{−y}/Γ(a + 1) at a = 3/2, Γ(5/2) = 3√π/4.
    let mut t = (1.5 * y.ln() - y - (0.75 * PI.sqrt()).ln()).exp();
    let mut a = 1.5;
    let mut weight = (-mu).exp();
    let mut sum = weight * q;
    let mut total = weight;
    let last = (mu + 12.0 * mu.sqrt() + 40.0) as usize;
    for j in 1..=last {
        q += t;
        t *= y / (a + 1.0);
        a += 1.0;
        weight *= mu / j as f64;
        sum += weight * q.min(1.0);
        total += weight;
        if total > 1.0 - 1e-16 && j as f64 > mu {
            break;
        }
    }
    sum.clamp(0.0, 1.0)
}

/// The noncentrality at which `χ²₃(λ)` exceeds `level` with probability
/// `p` (bisection on [`noncentral_chi2_3_tail`]).
pub fn noncentrality_for(level: f64, p: f64) -> f64 {
    let (mut lo, mut hi) = (0.0_f64, 1.0_f64);
    while noncentral_chi2_3_tail(hi, level) < p && hi < 1e4 {
        hi *= 2.0;
    }
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if noncentral_chi2_3_tail(mid, level) < p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// The detection limit of `current` on `prep` ([`DetectionLimit`]);
/// `None` without a noise estimate per line, without a fitted mode, or
/// when the Jacobian cannot be factored.
pub(super) fn detection_limit(
    prep: &Prepared,
    freq_hz: &[f64],
    current: &Params,
    period_s: f64,
) -> Option<DetectionLimit> {
    if !prep.noise_estimated || current.f_hz.is_empty() {
        return None;
    }
    let (alpha, beta) = rayleigh_fit(&current.f_hz, &current.zeta)?;
    let (per_dof, level) = reporting_level(prep, current);
    let lambda = noncentrality_for(level, DETECTION_PROBABILITY);
    let j = with_second_order(
        prep,
        current,
        Problem::new(prep, current, period_s).jacobian_of(current),
    );
    if !j.iter().all(|v| v.is_finite()) {
        return None;
    }
    let svd = j.svd(true, false);
    let u = svd.u?;
    let s_max = svd.singular_values.iter().copied().fold(0.0, f64::max);
    let kept: Vec<usize> = (0..svd.singular_values.len())
        .filter(|&i| svd.singular_values[i] > s_max * 1e-10)
        .collect();
    let limit_at = |f0: f64| -> Option<f64> {
        let w0 = 2.0 * PI * f0;
        let z0 = rayleigh(alpha, beta, f0);
        let mut v = DVector::<f64>::zeros(2 * prep.len());
        for k in 0..prep.len() {
            let s = C64::new(0.0, prep.w[k]);
            let e =
                prep.d(k, current.tau_s) * prep.scale[k] / (s * s + s * (2.0 * z0 * w0) + w0 * w0);
            v[2 * k] = e.re;
            v[2 * k + 1] = e.im;
        }
        let total = v.norm_squared();
        let along: f64 = kept.iter().map(|&i| u.column(i).dot(&v).powi(2)).sum();
        let q = total - along;
        (q > total * 1e-12 && q.is_finite()).then(|| (lambda * per_dof / q).sqrt())
    };
    let (lo, hi) = coherent_band(prep, freq_hz);
    // Half-power bands that overlap a fitted mode's: a mode of the
    // assumed damping at f overlaps mode i when |f − fᵢ| < ζᵢfᵢ + ζ₀(f)f.
    let unresolved_hz: Vec<[f64; 2]> = current
        .f_hz
        .iter()
        .zip(&current.zeta)
        .map(|(&m, &z)| {
            let reach = |side: f64| {
                // Solve |f − m| = k (z m + ζ₀(f) f) by fixed-point steps.
                let mut f = m;
                for _ in 0..20 {
                    f = m + side * UNRESOLVED_FACTOR * (z * m + rayleigh(alpha, beta, f) * f);
                }
                f
            };
            [reach(-1.0), reach(1.0)]
        })
        .collect();
    let apart = |f: f64| {
        !unresolved_hz.iter().any(|[a, b]| (*a..=*b).contains(&f))
            && current
                .f_hz
                .iter()
                .all(|m| (f / m).ln().abs() > MIN_SEPARATION.ln())
    };
    let n_grid = ((hi / lo).log10() * DETECTION_POINTS_PER_DECADE)
        .ceil()
        .max(1.0) as usize;
    let mut grid: Vec<f64> = (0..=n_grid)
        .map(|i| lo * (hi / lo).powf(i as f64 / n_grid as f64))
        .collect();
    for m in &current.f_hz {
        for r in BESIDE_RATIOS {
            grid.extend([m * r, m / r]);
        }
    }
    grid.retain(|f| (lo..=hi).contains(f) && apart(*f));
    grid.sort_by(f64::total_cmp);
    grid.dedup();
    let limits: Vec<(f64, f64)> = grid
        .par_iter()
        .filter_map(|&f| limit_at(f).map(|a| (f, a)))
        .collect();
    let beside_modes = current
        .f_hz
        .iter()
        .zip(&current.a)
        .map(|(&m, &a)| BesideMode {
            frequency_hz: m,
            modal_constant: a,
            limit: BESIDE_RATIOS
                .iter()
                .map(|r| {
                    [m * r, m / r]
                        .into_iter()
                        .filter(|f| apart(*f))
                        .filter_map(&limit_at)
                        .reduce(f64::max)
                })
                .collect(),
        })
        .collect();
    Some(DetectionLimit {
        probability: DETECTION_PROBABILITY,
        delta_chi2_level: level,
        noncentrality: lambda,
        rayleigh_alpha_per_s: alpha,
        rayleigh_beta_s: beta,
        unresolved_hz,
        frequency_hz: limits.iter().map(|x| x.0).collect(),
        modal_constant: limits.iter().map(|x| x.1).collect(),
        beside_modes,
    })
}

/// `j` (the fit's Jacobian, rows `2k`, `2k + 1` for line `k`) with, for
/// each fitted mode, the weighted second derivatives of its term in
/// `ln f` and `ln ζ` (`∂²/∂x²`, `∂²/∂x∂y`, `∂²/∂y²`): a fitted mode can
/// stretch over a partner further than its first-order change reaches
/// (one mode fitted to a close pair), and what it can absorb that way is
/// not counted as seen.
fn with_second_order(prep: &Prepared, p: &Params, j: DMatrix<f64>) -> DMatrix<f64> {
    let n = p.f_hz.len();
    let cols = j.ncols();
    let mut out = j.resize_horizontally(cols + 3 * n, 0.0);
    for k in 0..prep.len() {
        let s = C64::new(0.0, prep.w[k]);
        let d = prep.d(k, p.tau_s) * prep.scale[k];
        for i in 0..n {
            let wn = 2.0 * PI * p.f_hz[i];
            let zw = p.zeta[i] * wn;
            let den = s * s + s * (2.0 * zw) + wn * wn;
            let (d2, d3) = (den * den, den * den * den);
            let dx = s * (2.0 * zw) + 2.0 * wn * wn;
            let dy = s * (2.0 * zw);
            let a = p.a[i];
            let xx = -a * (s * (2.0 * zw) + 4.0 * wn * wn) / d2 + 2.0 * a * dx * dx / d3;
            let xy = -a * dy / d2 + 2.0 * a * dx * dy / d3;
            let yy = -a * dy / d2 + 2.0 * a * dy * dy / d3;
            for (c, v) in [xx, xy, yy].into_iter().enumerate() {
                let v = d * v;
                out[(2 * k, cols + 3 * i + c)] = v.re;
                out[(2 * k + 1, cols + 3 * i + c)] = v.im;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The noncentral χ²₃ tail and the noncentrality for 95 % against
    /// scipy 1.x: `scipy.stats.ncx2.sf(x, 3, lam)`, and
    /// `brentq(lambda l: ncx2.sf(x, 3, l) - 0.95, 0.01, 1000, xtol=1e-12)`.
    #[test]
    fn noncentral_chi2_3_matches_scipy() {
        for (lam, x, sf) in [
            (1.0, 5.0, 0.292_539_510_111_638_2),
            (10.0, 20.0, 0.148_620_721_050_413_93),
            (50.8, 30.0, 0.964_891_285_592_941_5),
            (100.0, 60.0, 0.991_048_230_015_172_4),
            (5.0, 30.0, 0.001_529_063_638_123_276_9),
        ] {
            let got = noncentral_chi2_3_tail(lam, x);
            assert!((got / sf - 1.0).abs() < 1e-9, "{lam} {x}: {got} vs {sf}");
        }
        assert!(
            (noncentral_chi2_3_tail(0.0, 16.266) / 0.001_000_111_604_662_117 - 1.0).abs() < 1e-9
        );
        for (x, lam) in [
            (20.0, 35.069_975_278_148_01),
            (30.0, 48.438_056_566_340_59),
            (40.0, 61.262_577_251_888_33),
        ] {
            let got = noncentrality_for(x, 0.95);
            assert!((got / lam - 1.0).abs() < 1e-8, "{x}: {got} vs {lam}");
        }
    }

    /// Rayleigh's law through two modes is exact; one mode gets its own
    /// damping; negative coefficients are never returned.
    #[test]
    fn rayleigh_fit_recovers_the_law() {
        let (a, b) = (3.0, 2e-5);
        let f = [20.0, 80.0, 300.0];
        let z: Vec<f64> = f.iter().map(|&f| rayleigh(a, b, f)).collect();
        let (fa, fb) = rayleigh_fit(&f, &z).unwrap();
        assert!((fa / a - 1.0).abs() < 1e-9 && (fb / b - 1.0).abs() < 1e-9);
        let (fa, fb) = rayleigh_fit(&[50.0], &[0.004]).unwrap();
        assert!((rayleigh(fa, fb, 50.0) / 0.004 - 1.0).abs() < 1e-12);
        // Damping falling faster than 1/ω: only α.
        let (fa, fb) = rayleigh_fit(&[10.0, 100.0], &[0.1, 0.001]).unwrap();
        assert!(fa > 0.0 && fb == 0.0);
    }
}
