//! The learning filter from the bench's measured process sensitivity
//! (`bench track --learning-ps`): `L_k = α / P̂S(jω_k)` with `P̂S` the
//! `PS = y/d` that `bench control --verify` measured on the same loop, and
//! the robustness filter `Q_k` from its uncertainty.
//!
//! On the bench each learned harmonic's error is multiplied every trial by
//! `1 − L_k·PS_k` (Bristow, Tharayil and Alleyne, IEEE CSM 26(3), 2006).
//! With `PS_k = P̂S_k + δ_k` and `|δ_k| ≤ 2σ_k` (2σ of the H1 estimate as
//! a complex number, [`crate::control::verify::ClosedLoopFrf`]):
//!
//! ```text
//! |1 − L_k·PS_k| ≤ |1 − L_k·P̂S_k| + |L_k|·2σ_k = (1 − α) + 2α·σ_k/|P̂S_k|
//! ```
//!
//! the monotonic-convergence condition checked with the measurement's
//! 2σ. `Q_k = 1` (harmonic learned) where that bound is below 1, `Q_k = 0`
//! where it is not or where no coherent measured line brackets `ω_k`: a
//! harmonic the measurement cannot vouch for is not learned. The margin
//! reported is `1 − max_k bound_k` over the learned harmonics.
//!
//! `P̂S` at `ω_k` is interpolated linearly (complex) between the two
//! adjacent grid lines that bracket it, both coherent; its σ is the larger
//! of theirs. The identification grid is dense (400 lines a decade on the
//! Chapter 5 bench: 0.58 % apart, against the modes' half-power bands of
//! 2ζ ≥ 2 %), so the interpolation's own error is well below the
//! estimate's.

use crate::control::verify::ModelLoop;
use crate::ident::C64;
use serde::{Deserialize, Serialize};

use super::{Harmonics, Learning};

/// A process sensitivity measured on a grid of lines.
#[derive(Debug, Clone, PartialEq)]
pub struct MeasuredPs {
    /// Grid, Hz (ascending).
    pub frequency_hz: Vec<f64>,
    /// `PS = y/d`, m/A.
    pub ps: Vec<C64>,
    /// 1σ of `PS` as a complex number, m/A.
    pub sigma_m_per_a: Vec<f64>,
    /// Whether each line counts (coherent, finite, not biased by a stall).
    pub counts: Vec<bool>,
}

impl MeasuredPs {
    /// `P̂S` (m/A) and its 1σ (m/A) at `f_hz`, linearly interpolated
    /// between the two adjacent lines that bracket it (a line itself when
    /// `f_hz` is on it), both counted; `None` outside the grid or where
    /// either line does not count.
    pub fn at(&self, f_hz: f64) -> Option<(C64, f64)> {
        let f = &self.frequency_hz;
        if !f_hz.is_finite() || f.is_empty() || f_hz < f[0] || f_hz > f[f.len() - 1] {
            return None;
        }
        let i = f.partition_point(|&x| x < f_hz);
        if f[i] == f_hz {
            return self.counts[i].then(|| (self.ps[i], self.sigma_m_per_a[i]));
        }
        let (a, b) = (i - 1, i);
        if !(self.counts[a] && self.counts[b]) {
            return None;
        }
        let w = (f_hz - f[a]) / (f[b] - f[a]);
        let ps = self.ps[a] * (1.0 - w) + self.ps[b] * w;
        Some((ps, self.sigma_m_per_a[a].max(self.sigma_m_per_a[b])))
    }
}

/// One harmonic's check of the learning filter against the measurement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct HarmonicCheck {
    /// The harmonic `k` of the line rate.
    pub harmonic: usize,
    /// Its frequency, Hz.
    pub frequency_hz: f64,
    /// The measured `|P̂S|`, m/A (`null`: no coherent line brackets it).
    pub measured_ps_magnitude_m_per_a: Option<f64>,
    /// The measured `∠P̂S`, degrees.
    pub measured_ps_phase_deg: Option<f64>,
    /// Its 1σ as a complex number, m/A.
    pub measured_ps_sigma_m_per_a: Option<f64>,
    /// The model's `|PS|`, m/A.
    pub model_ps_magnitude_m_per_a: f64,
    /// The model's `∠PS`, degrees.
    pub model_ps_phase_deg: f64,
    /// `|1 − L_k·P̂S_k| + |L_k|·2σ_k` with the measured `L_k = α/P̂S_k`:
    /// the most the harmonic's error is multiplied by per trial at 2σ
    /// (`null` unmeasured).
    pub contraction_bound: Option<f64>,
    /// The same bound for the model's `L_k = α/PS_model,k`: what learning
    /// on the model would do on this bench.
    pub model_contraction_bound: Option<f64>,
    /// Whether the harmonic is learned (`Q_k = 1`): measured, its bound
    /// below 1 and outside the zeros' bands.
    pub learned: bool,
}

/// The learning law on the measured `ps` ([module docs](self)): `L_k =
/// α/P̂S_k` on the harmonics `1…k_max` the measurement vouches for (their
/// contraction bound at 2σ below 1), `L_k = 0` elsewhere; with each
/// harmonic's check, the model's `PS` beside it.
pub fn learning(
    ps: &MeasuredPs,
    model: &ModelLoop<'_>,
    gain: f64,
    k_max: usize,
    line_rate_hz: f64,
) -> (Learning, Vec<HarmonicCheck>) {
    let zero = C64::new(0.0, 0.0);
    let one = C64::new(1.0, 0.0);
    let mut l = vec![zero; k_max + 1];
    let mut ps_used = vec![zero; k_max + 1];
    let mut checks = Vec::with_capacity(k_max);
    for k in 1..=k_max {
        let f = Harmonics::frequency_hz(k, line_rate_hz);
        let p_model = model.process_sensitivity(f);
        ps_used[k] = p_model;
        let measured = ps.at(f).filter(|(p, s)| p.norm() > 0.0 && s.is_finite());
        let (bound, model_bound) = match measured {
            Some((p, s)) => {
                let lk = gain / p;
                let b = (one - lk * p).norm() + lk.norm() * 2.0 * s;
                let lm = gain / p_model;
                let bm = (one - lm * p).norm() + lm.norm() * 2.0 * s;
                (Some(b), bm.is_finite().then_some(bm))
            }
            None => (None, None),
        };
        let learned = bound.is_some_and(|b| b < 1.0);
        if let (true, Some((p, _))) = (learned, measured) {
            l[k] = gain / p;
            ps_used[k] = p;
        }
        checks.push(HarmonicCheck {
            harmonic: k,
            frequency_hz: f,
            measured_ps_magnitude_m_per_a: measured.map(|(p, _)| p.norm()),
            measured_ps_phase_deg: measured.map(|(p, _)| p.arg().to_degrees()),
            measured_ps_sigma_m_per_a: measured.map(|(_, s)| s),
            model_ps_magnitude_m_per_a: p_model.norm(),
            model_ps_phase_deg: p_model.arg().to_degrees(),
            contraction_bound: bound,
            model_contraction_bound: model_bound,
            learned,
        });
    }
    let learning = Learning {
        gain,
        l,
        ps_model: ps_used,
    };
    (learning, checks)
}

/// The convergence margin `1 − max bound_k` over the learned harmonics and
/// the harmonic that sets it (`None` when none is learned).
pub fn margin(checks: &[HarmonicCheck]) -> Option<(f64, usize)> {
    checks
        .iter()
        .filter(|c| c.learned)
        .filter_map(|c| c.contraction_bound.map(|b| (1.0 - b, c.harmonic)))
        .min_by(|a, b| a.0.total_cmp(&b.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> MeasuredPs {
        // PS = 1/(1 + j f/10) m/A on 1…100 Hz, 1σ 1 % of it.
        let f: Vec<f64> = (0..=200).map(|i| 10f64.powf(i as f64 / 100.0)).collect();
        let ps: Vec<C64> = f
            .iter()
            .map(|&f| C64::new(1.0, 0.0) / C64::new(1.0, f / 10.0))
            .collect();
        MeasuredPs {
            sigma_m_per_a: ps.iter().map(|p| 0.01 * p.norm()).collect(),
            counts: vec![true; f.len()],
            frequency_hz: f,
            ps,
        }
    }

    /// Between lines the interpolation is within the chord's error of the
    /// smooth response (the grid is 2.3 % apart here); on a line it is the
    /// line; outside the grid or next to a line that does not count it is
    /// nothing.
    #[test]
    fn interpolation_between_counted_lines_only() {
        let mut m = grid();
        for f in [1.0, 3.3, 10.0, 47.0, 99.9] {
            let (p, s) = m.at(f).unwrap();
            let exact = C64::new(1.0, 0.0) / C64::new(1.0, f / 10.0);
            assert!(
                (p - exact).norm() < 1e-3 * exact.norm(),
                "{f}: {p} vs {exact}"
            );
            assert!((s / (0.01 * exact.norm()) - 1.0).abs() < 0.03, "{f}: σ {s}");
        }
        assert!(m.at(0.99).is_none() && m.at(100.01).is_none() && m.at(f64::NAN).is_none());
        let i = m.frequency_hz.partition_point(|&x| x < 20.0);
        m.counts[i] = false;
        assert!(m.at(20.0).is_none());
        assert!(m.at(m.frequency_hz[i]).is_none());
        assert!(m.at(m.frequency_hz[i + 1]).is_some());
    }
}
