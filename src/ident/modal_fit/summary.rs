//! From fitted parameters to a [`ModalFit`]: the modes with their 1σ, the
//! labels of `bench analyze`, the zeros and their types (thesis ch. 3), and
//! the model's response on any frequency.

use super::*;

pub(super) fn summarise(prep: &Prepared, data: &FrfData, p: &Params, period_s: f64) -> ModalFit {
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
        covariance: covariance(prep, p, period_s).as_slice().to_vec(),
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
        crate::ident::frf::CLOSE_PAIR_RATIO,
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
    use bench_plant::model::{poly_mul, poly_roots};
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

/// The 1σ of the fitted model [`evaluate`] at `frequency_hz` (m/A): the
/// root of `E|δĤ|² = gᵣᵀ Σ gᵣ + gᵢᵀ Σ gᵢ`, `g` the analytic gradient of
/// `Ĥ` over the parameters `[f…, ζ…, A…, L, U, τ]` and `Σ` the fit's
/// [`ModalFit::covariance`] (first-order propagation, e.g. Pintelon &
/// Schoukens, *System Identification*, 2nd ed., §7.2). With
/// `D_i = s² + 2ζ_i ω_i s + ω_i²`, `ω_i = 2π f_i`, `G` the path with the
/// delay: `∂Ĥ/∂A_i = G/D_i`, `∂Ĥ/∂f_i = −2π G A_i (2ζ_i s + 2ω_i)/D_i²`,
/// `∂Ĥ/∂ζ_i = −G A_i 2ω_i s/D_i²`, `∂Ĥ/∂L = G/s²`, `∂Ĥ/∂U = G`,
/// `∂Ĥ/∂τ = −jω Ĥ`. NaN when the covariance is not known (a fit read
/// from JSON) or not finite (a parameter the data do not determine).
pub fn evaluate_sigma(fit: &ModalFit, path: &Path, frequency_hz: f64) -> f64 {
    let n = fit.modes.len();
    let np = 3 * n + 3;
    if fit.covariance.len() != np * np {
        return f64::NAN;
    }
    let w = 2.0 * PI * frequency_hz;
    let s = C64::new(0.0, w);
    let g = path.gain(w) * C64::from_polar(1.0, -w * fit.delay_s);
    let mut grad = vec![C64::new(0.0, 0.0); np];
    for (i, md) in fit.modes.iter().enumerate() {
        let wn = 2.0 * PI * md.frequency_hz;
        let d = s * s + s * (2.0 * md.damping_ratio * wn) + wn * wn;
        let ad2 = g * md.modal_constant / (d * d);
        grad[i] = -ad2 * (s * (2.0 * md.damping_ratio) + 2.0 * wn) * (2.0 * PI);
        grad[n + i] = -ad2 * s * (2.0 * wn);
        grad[2 * n + i] = g / d;
    }
    grad[3 * n] = g / (s * s);
    grad[3 * n + 1] = g;
    grad[3 * n + 2] = -s * evaluate(fit, path, frequency_hz);
    // gᵣᵀ Σ gᵣ + gᵢᵀ Σ gᵢ = Σ_ab Σ_ab Re(g_a g_b*).
    let mut v = 0.0;
    for (a, ga) in grad.iter().enumerate() {
        for (b, gb) in grad.iter().enumerate() {
            v += fit.covariance[a * np + b] * (ga.re * gb.re + ga.im * gb.im);
        }
    }
    if v >= 0.0 && v.is_finite() {
        v.sqrt()
    } else {
        f64::NAN
    }
}
