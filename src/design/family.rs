//! The controller families a design searches, written as the config writes
//! controllers (`form = "unity_dc"`, the error in µm, one integrator), and
//! their parameter vectors.
//!
//! - **Slow** (thesis §6.1.1, Eq. 6-6): `C(s) = g/s · ω_lp²/(s² + 2·0.7·ω_lp s + ω_lp²)`
//!   with ω_lp at half the first resonance ω_R. The parameter is `ln g`.
//! - **Fast** (thesis §6.1.2, Eq. 6-7):
//!   `C(s) = g/s · (1 + s/z)/(1 + s/p) · 1/(1 + s/p₁) · N_a(s) · LP₂(s) · [notch]`
//!   with a lead `z < p`, a first-order low-pass `p₁`, a phase-boosting
//!   complex zero pair `N_a = (s² + 2ζ_a ω_a s + ω_a²)/ω_a²`, a
//!   second-order low-pass `LP₂` at ω₂ with ζ = 0.7 and, when the closely
//!   spaced pair's residue signs alternate (§6.1.2.1), a notch
//!   `(s² + 2ζ_z ω_z s + ω_z²)/ω_z² · ω_p²/(s² + 2ζ_p ω_p s + ω_p²)` whose
//!   centre ω_z lies **between** the pair's modes u and v (the thesis'
//!   rule: u and v on opposite sides), enforced by the parametrisation
//!   `ω_z = ω_u + (ω_v − ω_u)·σ(t)` (σ the logistic function).
//!   Without the notch it is the conventional lead + low-pass the thesis
//!   recommends for non-alternating signs (§6.1.2.2).
//!
//! Parameters are logarithms of frequencies and damping ratios (so the
//! search moves in ratios), clamped into [`FREQ_MIN_FRACTION`] ω_R … 0.9 ×
//! Nyquist and the damping ranges below.

use crate::config::controller::CORNER_RAD_S;
use crate::control::{ComplexPair, ControllerConfig, Discretization, ErrorUnit, Form};
use std::f64::consts::PI;

/// Lowest corner a family may place, as a fraction of ω_R.
pub const FREQ_MIN_FRACTION: f64 = 0.02;
/// Damping ratio of the second-order low-pass (both families; thesis).
pub const LOW_PASS_ZETA: f64 = 0.7;

/// The family and what it is built around.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Family {
    /// Integrator and low-pass at `first_resonance_rad_s / 2`.
    Slow {
        /// ω_R, rad/s.
        first_resonance_rad_s: f64,
    },
    /// Lead, low-passes, phase-boosting pair, and a notch between u and v
    /// when `pair` is given.
    Fast {
        /// ω_R, rad/s.
        first_resonance_rad_s: f64,
        /// (ω_u, ω_v), rad/s, when the pair's signs alternate.
        pair: Option<(f64, f64)>,
        /// The loop's Nyquist frequency, rad/s.
        nyquist_rad_s: f64,
    },
}

fn sigmoid(t: f64) -> f64 {
    1.0 / (1.0 + (-t).exp())
}

fn logit(x: f64) -> f64 {
    (x / (1.0 - x)).ln()
}

impl Family {
    /// The controller for parameters `theta` (clamped into the family's
    /// ranges; the first entry is always `ln g`).
    pub fn controller(&self, theta: &[f64]) -> ControllerConfig {
        let mut c = ControllerConfig {
            description: String::new(),
            error_unit: ErrorUnit::Micrometre,
            form: Form::UnityDc,
            gain: theta[0].exp(),
            integrators: 1,
            real_zeros_rad_s: vec![],
            real_poles_rad_s: vec![],
            complex_zeros: vec![],
            complex_poles: vec![],
            discretization: Discretization::LeastSquares,
        };
        match *self {
            Self::Slow {
                first_resonance_rad_s,
            } => c.complex_poles.push(ComplexPair {
                omega_rad_s: first_resonance_rad_s / 2.0,
                zeta: LOW_PASS_ZETA,
            }),
            Self::Fast {
                first_resonance_rad_s: wr,
                pair,
                nyquist_rad_s,
            } => {
                let f = |x: f64| x.exp().clamp(FREQ_MIN_FRACTION * wr, 0.9 * nyquist_rad_s);
                let z = |x: f64, lo: f64, hi: f64| x.exp().clamp(lo, hi);
                let lead_zero = f(theta[1]);
                let lead_pole =
                    (lead_zero * theta[2].exp().clamp(1.0, 100.0)).min(0.9 * nyquist_rad_s);
                c.real_zeros_rad_s.push(lead_zero);
                c.real_poles_rad_s.push(lead_pole);
                c.real_poles_rad_s.push(f(theta[3]));
                c.complex_zeros.push(ComplexPair {
                    omega_rad_s: f(theta[4]),
                    zeta: z(theta[5], 0.05, 1.5),
                });
                c.complex_poles.push(ComplexPair {
                    omega_rad_s: f(theta[6]),
                    zeta: LOW_PASS_ZETA,
                });
                if let Some((wu, wv)) = pair {
                    let wz = wu + (wv - wu) * sigmoid(theta[7]);
                    c.complex_zeros.push(ComplexPair {
                        omega_rad_s: wz,
                        zeta: z(theta[8], 1e-3, 0.3),
                    });
                    c.complex_poles.push(ComplexPair {
                        omega_rad_s: (wz * theta[9].exp().clamp(0.8, 1.5)).min(0.9 * nyquist_rad_s),
                        zeta: z(theta[10], 0.02, 1.0),
                    });
                }
            }
        }
        // Every corner within what a config can hold (a plant whose
        // first resonance is near 0.01 rad/s scales the thesis' corners
        // below it): the controller judged is the one written.
        let (lo, hi) = CORNER_RAD_S;
        for w in c.real_zeros_rad_s.iter_mut().chain(&mut c.real_poles_rad_s) {
            *w = w.clamp(lo, hi);
        }
        for p in c.complex_zeros.iter_mut().chain(&mut c.complex_poles) {
            p.omega_rad_s = p.omega_rad_s.clamp(lo, hi);
        }
        c
    }

    /// The start of the search: the thesis' own design scaled to this
    /// plant (Eq. 6-7's corners as ratios of its ω_R = 179 rad/s, the
    /// notch centre at the pair's geometric mean), gain `ln g` = 0 (the
    /// caller scales it to a crossover).
    pub fn start(&self) -> Vec<f64> {
        match *self {
            Self::Slow { .. } => vec![0.0],
            Self::Fast {
                first_resonance_rad_s: wr,
                pair,
                ..
            } => {
                let r = wr / 179.0;
                let mut t = vec![
                    0.0,
                    (88.7 * r).ln(),
                    (625.0f64 / 88.7).ln(),
                    (893.0 * r).ln(),
                    (175.0 * r).ln(),
                    0.4f64.ln(),
                    (700.0 * r).ln(),
                ];
                if let Some((wu, wv)) = pair {
                    let wz = (wu * wv).sqrt();
                    t.extend([
                        logit(((wz - wu) / (wv - wu)).clamp(0.05, 0.95)),
                        0.01f64.ln(),
                        (555.0f64 / 520.0).ln(),
                        0.1f64.ln(),
                    ]);
                }
                t
            }
        }
    }

    /// The thesis-scaled start ([`Self::start`]) with the gain of `theta`.
    pub fn start_scaled(&self, theta: &[f64]) -> Vec<f64> {
        let mut t = self.start();
        t[0] = theta[0];
        t
    }
}

/// The loop's Nyquist frequency for `period_s`, rad/s.
pub fn nyquist_rad_s(period_s: f64) -> f64 {
    PI / period_s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fast family's start on the thesis' own ω_R = 179 rad/s and a
    /// pair at 510/532 rad/s is Eq. (6-7)'s structure with its corners:
    /// the response's shape (gain aside) matches Eq. 6-7 within the
    /// notch's move to the pair's geometric mean.
    #[test]
    fn fast_start_is_the_thesis_design() {
        let fam = Family::Fast {
            first_resonance_rad_s: 179.0,
            pair: Some((510.0, 532.0)),
            nyquist_rad_s: nyquist_rad_s(2e-4),
        };
        let c = fam.controller(&fam.start());
        assert!((c.real_zeros_rad_s[0] - 88.7).abs() < 1e-9);
        assert!((c.real_poles_rad_s[0] - 625.0).abs() < 1e-9);
        assert!((c.real_poles_rad_s[1] - 893.0).abs() < 1e-9);
        assert!((c.complex_zeros[0].omega_rad_s - 175.0).abs() < 1e-9);
        let wz = c.complex_zeros[1].omega_rad_s;
        assert!(wz > 510.0 && wz < 532.0);
        assert!((c.complex_poles[1].omega_rad_s / wz - 555.0 / 520.0).abs() < 1e-9);
        c.validate("controller.designed").unwrap();
        // The notch stays between u and v whatever the parameter says.
        let mut t = fam.start();
        for x in [-1e3, -5.0, 0.0, 5.0, 1e3] {
            t[7] = x;
            let wz = fam.controller(&t).complex_zeros[1].omega_rad_s;
            assert!((510.0..=532.0).contains(&wz), "{x}: {wz}");
        }
    }
}
