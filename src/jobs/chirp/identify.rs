//! From an FRF to the summary's modes: the model's modes, the resonances
//! found in the measurement and the CMP-CNMP pair.

use super::*;

pub(super) fn model_summary(m: &Sr4dof) -> ModelSummary {
    let two_pi = 2.0 * std::f64::consts::PI;
    ModelSummary {
        natural_frequencies_hz: m.modes().iter().map(|md| md.frequency_hz()).collect(),
        damping_ratios: m.modes().iter().map(|md| md.zeta).collect(),
        rigid_body_mode: m.rigid_body_mode(),
        zeros_hz: m
            .zeros()
            .iter()
            .map(|z| [z.re / two_pi, z.im / two_pi])
            .collect(),
        zero_types: m
            .undamped_zeros()
            .iter()
            .map(|z| z.kind.as_str().to_string())
            .collect::<Vec<_>>(),
        cnmp_discriminant: m.cnmp_discriminant(),
        cmp_cnmp: m.has_cnmp_zeros(),
    }
}

/// What the modal fit and the verdict make of a measured FRF.
#[derive(Debug, Clone)]
pub struct Identified {
    /// The fit (`None` if it could not be made).
    pub fit: Option<crate::ident::modal_fit::ModalFit>,
    /// The verdict.
    pub verdict: crate::ident::verdict::Verdict,
    /// The fitted modes as resonances.
    pub resonances: Vec<Resonance>,
    /// The path outside the mechanics the fit assumed.
    pub path: crate::ident::modal_fit::Path,
}

/// Fits `frf` ([`crate::ident::modal_fit::fit`]) for a loop of period
/// `period_s` and an amplifier of bandwidth `amplifier_bandwidth_hz`, and
/// gives the verdict ([`crate::ident::verdict`]).
pub fn identify(frf: &Frf, period_s: f64, amplifier_bandwidth_hz: f64) -> Identified {
    use crate::ident::modal_fit::{self, FrfData, Path};
    use crate::ident::verdict;
    let path = Path {
        period_s,
        amplifier_bandwidth_hz,
    };
    match modal_fit::fit(&FrfData::from_frf(frf), &path) {
        Ok(fit) => {
            let v = verdict::verdict(frf, &fit, |f| modal_fit::path_phase_deg(&fit, &path, f));
            let resonances = fit
                .modes
                .iter()
                .filter(|m| m.in_path)
                .map(|m| as_resonance(frf, m.frequency_hz, m.damping_ratio))
                .collect();
            Identified {
                fit: Some(fit),
                verdict: v,
                resonances,
                path,
            }
        }
        Err(e) => Identified {
            fit: None,
            verdict: verdict::without_fit(&e.to_string()),
            resonances: Vec::new(),
            path,
        },
    }
}

/// A fitted mode as a [`Resonance`]: measured |H| at the grid point
/// nearest `frequency_hz`, prominence over the lower of the minima within
/// ±5 % on each side.
pub(super) fn as_resonance(frf: &Frf, frequency_hz: f64, damping_ratio: f64) -> Resonance {
    let g = &frf.frequency_hz;
    let m = &frf.magnitude_m_per_a;
    let k = g.partition_point(|f| *f < frequency_hz).min(g.len() - 1);
    let lo = g.partition_point(|f| *f < frequency_hz / 1.05);
    let hi = g.partition_point(|f| *f <= frequency_hz * 1.05).max(k + 1);
    let left = m[lo..=k].iter().fold(f64::INFINITY, |a, b| a.min(*b));
    let right = m[k..hi].iter().fold(f64::INFINITY, |a, b| a.min(*b));
    Resonance {
        frequency_hz,
        magnitude_m_per_a: m[k],
        damping_ratio: Some(damping_ratio),
        prominence_db: 20.0 * (m[k] / left.min(right)).log10(),
    }
}
