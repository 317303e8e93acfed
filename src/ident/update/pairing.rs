//! Modes paired by shape (the modal assurance criterion, MAC, Allemang &
//! Brown 1982): the start's and the updated model's, the model's and the
//! fit's; and the report of each parameter and mode.

use super::*;

pub(super) fn check_start(start: &Bench) -> Result<Sr4dof, UpdateError> {
    let (lo, hi) = FORCE_CONSTANT_N_PER_A;
    if !(lo..=hi).contains(&start.force_constant_n_per_a) {
        return Err(UpdateError::Start(ParamError::new(
            "actuator.force_constant_n_per_a",
            format!("must be in [{lo}, {hi}] N/A"),
        )));
    }
    Sr4dof::new(start.plant).map_err(UpdateError::Start)
}

pub(super) fn parameter_report(
    start: &Bench,
    updated: &Bench,
    free: &[Parameter],
    sigma: &[Option<f64>],
) -> Vec<UpdatedParameter> {
    Parameter::ALL
        .iter()
        .map(|&p| {
            let i = free.iter().position(|&q| q == p);
            let value = p.value(updated);
            UpdatedParameter {
                name: p.name().into(),
                key: p.key().into(),
                unit: p.unit().into(),
                free: i.is_some(),
                start: p.value(start),
                value,
                sigma: i
                    .and_then(|i| sigma[i])
                    .map(|s| s * p.dv_dx(start, value).abs()),
            }
        })
        .collect()
}

/// MAC of two real vectors.
pub(super) fn mac_real(a: &nalgebra::Vector4<f64>, b: &nalgebra::Vector4<f64>) -> f64 {
    let d = a.dot(b);
    d * d / (a.norm_squared() * b.norm_squared())
}

/// MAC of two complex vectors, `|aᴴb|² / (aᴴa · bᴴb)`.
pub(super) fn mac_complex(a: &[C64], b: &[C64]) -> f64 {
    let d: C64 = a.iter().zip(b).map(|(x, y)| x.conj() * y).sum();
    let na: f64 = a.iter().map(|x| x.norm_sqr()).sum();
    let nb: f64 = b.iter().map(|x| x.norm_sqr()).sum();
    d.norm_sqr() / (na * nb)
}

/// The permutation `p` of the four modes maximising `Σ mac[i][p[i]]`.
pub(super) fn best_permutation(mac: &[[f64; 4]; 4]) -> [usize; 4] {
    let mut best = ([0, 1, 2, 3], f64::NEG_INFINITY);
    for a in 0..4 {
        for b in (0..4).filter(|&b| b != a) {
            for c in (0..4).filter(|&c| c != a && c != b) {
                let d = 6 - a - b - c;
                let s = mac[0][a] + mac[1][b] + mac[2][c] + mac[3][d];
                if s > best.1 {
                    best = ([a, b, c, d], s);
                }
            }
        }
    }
    best.0
}

/// The injective assignment of model modes to measured modes (or none)
/// that maximises the sum of `mac` over pairs with MAC ≥ [`MIN_PAIR_MAC`].
pub(super) fn best_assignment(mac: &[Vec<f64>]) -> Vec<Option<usize>> {
    fn go(
        i: usize,
        mac: &[Vec<f64>],
        used: &mut Vec<bool>,
        cur: &mut Vec<Option<usize>>,
        best: &mut (Vec<Option<usize>>, f64),
        sum: f64,
    ) {
        if i == mac.len() {
            if sum > best.1 {
                *best = (cur.clone(), sum);
            }
            return;
        }
        cur.push(None);
        go(i + 1, mac, used, cur, best, sum);
        cur.pop();
        for j in 0..used.len() {
            if !used[j] && mac[i][j] >= MIN_PAIR_MAC {
                used[j] = true;
                cur.push(Some(j));
                go(i + 1, mac, used, cur, best, sum + mac[i][j]);
                cur.pop();
                used[j] = false;
            }
        }
    }
    let n = mac.first().map_or(0, Vec::len);
    let mut best = (vec![None; mac.len()], -1.0);
    go(0, mac, &mut vec![false; n], &mut Vec::new(), &mut best, 0.0);
    best.0
}

/// The updated model's modes, paired with the start's by shape MAC.
pub(super) fn mode_report(start: &Sr4dof, updated: &Sr4dof, kf: f64) -> (Vec<UpdatedMode>, bool) {
    let (sm, um) = (start.modes(), updated.modes());
    let mut mac = [[0.0; 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            mac[i][j] = mac_real(&um[i].shape, &sm[j].shape);
        }
    }
    let perm = best_permutation(&mac);
    let modes = (0..4)
        .map(|i| UpdatedMode {
            frequency_hz: um[i].frequency_hz(),
            damping_ratio: um[i].zeta,
            modal_constant: kf * um[i].residue,
            start_mode: perm[i] + 1,
            start_mac: mac[i][perm[i]],
            start_frequency_hz: sm[perm[i]].frequency_hz(),
            measured_frequency_hz: None,
            measured_mac: None,
        })
        .collect();
    (modes, perm[2] == 3 && perm[3] == 2)
}

pub(super) fn stiffness_over_beam(b: &Bench) -> f64 {
    b.plant.parallelogram_stiffness() / b.plant.beam.parallelogram_stiffness_n_per_m()
}

/// The in-path fitted modes step 1 pairs with the model's: at most four,
/// the highest peaks `|A|/(2ζω²)`, ascending in frequency.
pub(super) fn measured_modes(fit: &ModalFit) -> Vec<f64> {
    let mut m: Vec<(f64, f64)> = fit
        .modes
        .iter()
        .filter(|m| m.in_path)
        .map(|m| {
            let w = 2.0 * PI * m.frequency_hz;
            (
                m.frequency_hz,
                m.modal_constant.abs() / (2.0 * m.damping_ratio.max(1e-6) * w * w),
            )
        })
        .collect();
    m.sort_by(|a, b| b.1.total_cmp(&a.1));
    m.truncate(4);
    let mut f: Vec<f64> = m.into_iter().map(|m| m.0).collect();
    f.sort_by(f64::total_cmp);
    f
}

/// Starting damping ratios from the modal fit: the fitted mode nearest
/// the start model's X rigid-body mode (`zeta_rigid`), and the mean over
/// the fitted modes near the closely spaced pair (`zeta_csm`); each only
/// when a fitted mode lies within 20 %.
pub(super) fn fitted_damping(fit: &ModalFit, start: &Sr4dof) -> (Option<f64>, Option<f64>) {
    let near = |f0: f64| {
        fit.modes
            .iter()
            .filter(|m| m.in_path && (m.frequency_hz / f0 - 1.0).abs() < 0.2)
            .min_by(|a, b| {
                (a.frequency_hz / f0 - 1.0)
                    .abs()
                    .total_cmp(&(b.frequency_hz / f0 - 1.0).abs())
            })
    };
    let rigid =
        near(start.modes()[start.rigid_body_mode()].frequency_hz()).map(|m| m.damping_ratio);
    let pair: Vec<f64> = [2, 3]
        .iter()
        .filter_map(|&i| near(start.modes()[i].frequency_hz()).map(|m| m.damping_ratio))
        .collect();
    let csm = (!pair.is_empty()).then(|| pair.iter().sum::<f64>() / pair.len() as f64);
    (rigid, csm)
}

/// Pairs the updated modes with the fitted ones by the MAC of their
/// frequency-response contributions over the coherent points.
pub(super) fn pair_with_fit(modes: &mut [UpdatedMode], fit: &ModalFit, prep: &Prepared) {
    let points: Vec<f64> = (0..prep.h.len())
        .filter(|&k| prep.coherent[k])
        .map(|k| prep.frequency_hz[k])
        .collect();
    let contribution = |f_hz: f64, zeta: f64, a: f64| -> Vec<C64> {
        let wn = 2.0 * PI * f_hz;
        points
            .iter()
            .map(|&f| {
                let w = 2.0 * PI * f;
                C64::new(a, 0.0) / C64::new(wn * wn - w * w, 2.0 * zeta * wn * w)
            })
            .collect()
    };
    let measured: Vec<Vec<C64>> = fit
        .modes
        .iter()
        .map(|m| contribution(m.frequency_hz, m.damping_ratio, m.modal_constant))
        .collect();
    let mac: Vec<Vec<f64>> = modes
        .iter()
        .map(|m| {
            let c = contribution(m.frequency_hz, m.damping_ratio, m.modal_constant);
            measured.iter().map(|d| mac_complex(&c, d)).collect()
        })
        .collect();
    for (i, j) in best_assignment(&mac).into_iter().enumerate() {
        if let Some(j) = j {
            modes[i].measured_frequency_hz = Some(fit.modes[j].frequency_hz);
            modes[i].measured_mac = Some(mac[i][j]);
        }
    }
}
