//! The model-order search: where the residual concentrates, trial modes
//! around it, the acceptance and pruning rules, and the thinning of the grid
//! to independent lines.

use super::*;

/// Frequencies (Hz) where the weighted residual of `p` concentrates: the
/// local maxima of its energy in a ±1 % window over coherent points,
/// largest first, at least 3 % apart, away from the modes of `p`.
pub(super) fn residual_peaks(prep: &Prepared, freq_hz: &[f64], p: &Params, max: usize) -> Vec<f64> {
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
pub(super) fn magnitude_peaks(
    prep: &Prepared,
    freq_hz: &[f64],
    p: &Params,
    max: usize,
) -> Vec<(f64, f64)> {
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
pub(super) struct Trial {
    pub(super) f_hz: f64,
    pub(super) zeta: f64,
    pub(super) gain: f64,
    /// The window's cost without the mode.
    pub(super) baseline: f64,
}

pub(super) fn try_mode(
    prep: &Prepared,
    freq_hz: &[f64],
    current: &Params,
    f0: f64,
) -> Option<Trial> {
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
pub(super) fn add_mode(
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
    tracing::debug!(
        f_hz = trial.f_hz,
        modes = start.f_hz.len(),
        "modal fit: a trial mode refined"
    );
    Some([sorted(refine(prep, &start, period_s)), sorted(start)])
}

/// Modes sorted ascending in frequency.
pub(super) fn sorted(p: Params) -> Params {
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
pub(super) fn acceptable(prep: &Prepared, freq_hz: &[f64], p: &Params) -> bool {
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
pub(super) fn coincident(p: &Params) -> Option<usize> {
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
pub(super) fn prune(prep: &Prepared, mut p: Params, period_s: f64) -> Params {
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
            match least_decided(prep, &p, &sd, period_s) {
                Some(next) => {
                    p = next;
                    continue;
                }
                None => return p,
            }
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

/// `p` without its least significant mode when the data do not decide
/// it: where the noise is estimated, a mode whose removal (refitted)
/// raises the cost by less than the level at which the fit reports an
/// undecided mode ([`reporting_level`]: `χ²₃` at
/// [`RESIDUAL_TEST_LEVEL`]` / N`, as its frequency could lie on any of
/// the `N` lines). Only modes whose modal constant is within
/// `√level` standard deviations of zero are tried (`z²` is the removal's
/// `Δχ²` to first order with its frequency and damping held); `None`:
/// every mode is decided. (At 10 % probe noise a mode of `z` 3.2 at
/// 153 Hz fitted two neighbouring lines' noise, `Δχ²` below the level,
/// on one of 60 benches.)
fn least_decided(prep: &Prepared, p: &Params, sd: &[f64], period_s: f64) -> Option<Params> {
    if !prep.noise_estimated {
        return None;
    }
    let n = p.f_hz.len();
    let (per_dof, level) = reporting_level(prep, p);
    let cost = prep.cost(p);
    let mut weak: Vec<(usize, f64)> = (0..n)
        .map(|i| (i, p.a[i].abs() / sd[2 * n + i]))
        .filter(|(_, z)| z * z < level)
        .collect();
    weak.sort_by(|a, b| a.1.total_cmp(&b.1));
    weak.into_iter().find_map(|(i, _)| {
        let q = without(prep, p, i, period_s)?;
        ((prep.cost(&q) - cost) / per_dof < level).then_some(q)
    })
}

/// `s²` of the 1σ: when the weights are the data's own noise, the
/// weighted cost over its expectation under the noise alone
/// ([`cost_reference`]), at least 1 (see [`sigmas`]); otherwise the cost
/// per degree of freedom (`2m − (3n + 3)` for `m` lines and `n` modes).
pub(super) fn residual_variance(prep: &Prepared, p: &Params, cost: f64) -> f64 {
    let params = 3 * p.f_hz.len() + 3;
    let dof = (2.0 * prep.len() as f64 - params as f64).max(1.0);
    if prep.noise_estimated {
        (cost / cost_reference(&prep.dof, params).0).max(1.0)
    } else {
        cost / dof
    }
}

/// The bound on evaluations of the refit after a mode is removed, × (n + 1)
/// for n parameters, a quarter of [`PATIENCE`]. The refit starts from the
/// fitted model less one mode: on data the model describes it converges
/// within 3.1 (n + 1) (16 default chirps of the shipped bench); those
/// chirps' fits print the same with 5 as with 20, and
/// `tests/cli/real_links.rs` and `tests/cli/mode_count.rs` count and list
/// the same fits. One that runs longer is on data the model does not
/// describe: with a fifth of the lines corrupted, pruning ten modes to
/// three ran six refits of 320–596 evaluations, five of them to the full
/// bound (2.3 s of a 3.3 s fit; with 5, 0.55 s of 1.4 s). A refit's result
/// is kept only where it lowers the cost ([`refine`]).
const REMOVAL_PATIENCE: usize = 5;

/// `p` without mode `i`, the linear part re-solved and all refined (at
/// most [`REMOVAL_PATIENCE`]).
pub(super) fn without(prep: &Prepared, p: &Params, i: usize, period_s: f64) -> Option<Params> {
    let mut f = p.f_hz.clone();
    let mut zeta = p.zeta.clone();
    f.remove(i);
    zeta.remove(i);
    let start = with_linear(prep, f, zeta, p.tau_s)?;
    Some(sorted(refine_within(
        prep,
        &start,
        period_s,
        REMOVAL_PATIENCE,
    )))
}

/// The lines of `data` the fit uses: a line is kept when its frequency is
/// at least `1 + ln 10 / per_decade` times the last one kept (the step of
/// a log grid of `per_decade` points) and, where the lines' bands are
/// known ([`FrfData::resolution_hz`]), its band does not overlap the last
/// kept one's (`f − f_last ≥ (b + b_last)/2`): the kept lines' errors are
/// independent, so their weighted residual is a χ² and the 1σ of the fit
/// do not shrink with the density of the grid. `None` when every line is
/// kept.
pub(super) fn thin(data: &FrfData, per_decade: f64) -> Option<FrfData> {
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
        sigma_dof: pick(&data.sigma_dof),
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
pub(super) fn coherent_band(prep: &Prepared, freq_hz: &[f64]) -> (f64, f64) {
    let first = prep.coherent.iter().position(|c| *c).unwrap_or(0);
    let last = prep.coherent.iter().rposition(|c| *c).unwrap_or(0);
    (freq_hz[first], freq_hz[last])
}

/// Trial modes ([`try_mode`]) at the three largest peaks of the weighted
/// residual and of |H| beyond `current`, the largest gain first. The
/// candidates' grids are independent: tried side by side (in the
/// candidates' order, so the result does not depend on it).
pub(super) fn ranked_trials(prep: &Prepared, freq_hz: &[f64], current: &Params) -> Vec<Trial> {
    let mut candidates = residual_peaks(prep, freq_hz, current, 3);
    candidates.extend(
        magnitude_peaks(prep, freq_hz, current, 3)
            .into_iter()
            .map(|(f, _)| f),
    );
    let mut trials: Vec<Trial> = candidates
        .into_par_iter()
        .filter_map(|f0| try_mode(prep, freq_hz, current, f0))
        .collect();
    trials.sort_by(|a, b| b.gain.total_cmp(&a.gain));
    trials
}

/// The best further mode the data offer beyond `current`: the trial
/// modes at the residual's and the magnitude's peaks, the two best
/// refined, the lowest cost kept if acceptable. Returns it with the cost
/// it removes.
pub(super) fn probe(
    prep: &Prepared,
    freq_hz: &[f64],
    current: &Params,
    period_s: f64,
) -> Option<(Params, f64)> {
    let cost = prep.cost(current);
    let trials = ranked_trials(prep, freq_hz, current);
    trials
        .iter()
        .take(2)
        .filter_map(|t| add_mode(prep, current, t, period_s))
        .flatten()
        .filter(|p| acceptable(prep, freq_hz, p))
        .map(|p| {
            let c = prep.cost(&p);
            (p, cost - c)
        })
        .max_by(|a, b| a.1.total_cmp(&b.1))
}

/// The noise variance a further mode's cost is counted in beyond
/// `current` (the cost per degree of freedom, at least its expectation
/// under the noise alone), and the level `Δχ²` must pass for the fit to
/// report the mode: the `χ²₃` quantile at [`RESIDUAL_TEST_LEVEL`]` / N`
/// ([`UndecidedMode`], [`DetectionLimit`]).
pub(super) fn reporting_level(prep: &Prepared, current: &Params) -> (f64, f64) {
    let params = 3 * current.f_hz.len() + 3;
    let nu = (2 * prep.len()).saturating_sub(params).max(1) as f64;
    let (mean, _) = cost_reference(&prep.dof, params);
    let per_dof = (prep.cost(current) / nu).max(mean / nu);
    let level = chi2_3_quantile(RESIDUAL_TEST_LEVEL / prep.len().max(1) as f64);
    (per_dof, level)
}

/// The mode the data cannot decide beyond `current` ([`UndecidedMode`]),
/// if any: only where the noise is estimated and the residual is the noise
/// (otherwise the search would have added it, or there is no noise to
/// judge it by).
pub(super) fn undecided(
    prep: &Prepared,
    freq_hz: &[f64],
    current: &Params,
    period_s: f64,
) -> Option<UndecidedMode> {
    if !prep.noise_estimated || !residual_tests(prep, current).residual_is_noise() {
        return None;
    }
    let (per_dof, level) = reporting_level(prep, current);
    let (p, removed) = probe(prep, freq_hz, current, period_s)?;
    let delta_chi2 = removed / per_dof;
    if delta_chi2 < level {
        return None;
    }
    // The new mode: the one of `p` farthest from every mode of `current`
    // (a mode split in two moves both halves).
    let apart = |i: usize| {
        current
            .f_hz
            .iter()
            .map(|f| (p.f_hz[i] / f).ln().abs())
            .fold(f64::INFINITY, f64::min)
    };
    let n = p.f_hz.len();
    let i = (0..n).max_by(|&a, &b| apart(a).total_cmp(&apart(b)))?;
    let sd = sigmas(prep, &p, period_s);
    let z = p.a[i].abs() / sd[2 * n + i];
    (z >= MIN_SIGNIFICANCE).then(|| UndecidedMode {
        frequency_hz: p.f_hz[i],
        damping_ratio: p.zeta[i],
        modal_constant: p.a[i],
        modal_constant_z: z,
        delta_chi2,
        delta_chi2_level: level,
    })
}

/// Why the pair's labels are unsure when the undecided mode `m` lies
/// among the closely spaced pair (closer to `u` or `v` than the pair's own
/// frequency ratio): with it the sequence of signs could be another.
pub(super) fn near_the_pair(fit: &ModalFit, m: &UndecidedMode) -> Option<String> {
    let u = fit.modes.iter().find(|x| x.label == "u")?.frequency_hz;
    let v = fit.modes.iter().find(|x| x.label == "v")?.frequency_hz;
    let r = v / u;
    (m.frequency_hz > u / r && m.frequency_hz < v * r).then(|| {
        format!(
            "a further mode near {:.2} Hz, which the data cannot decide, lies within the pair's ratio {r:.4} of u ({u:.2} Hz) and v ({v:.2} Hz): the pair could be another",
            m.frequency_hz
        )
    })
}
