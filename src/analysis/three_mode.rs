//! Chapter 4's three-mode test: the closely spaced pair u, v and the
//! remainder R taken as a double integrator (Assumptions A4-1 to A4-5,
//! Eq. 4-1), the normalised parabola coefficients (Eq. 4-9, 4-10),
//! Conditions C4-1, C4-2 and the verdict of Proposition P4-1.
//!
//! ```text
//! G(s) = α_R/s² + α_u/(s² + ω_u²) + α_v/(s² + ω_v²)                  (4-1)
//! N(x) = b₂x² + b₁x + b₀,  x = s²                                        (4-3)
//!   b₂ = α_R + α_u + α_v
//!   b₁ = (ω_u² + ω_v²)α_R + α_u ω_v² + α_v ω_u²
//!   b₀ = α_R ω_u² ω_v²
//! b̂₂ = (ω_v² − ω_u²) b₂ / ω_u²                                          (4-9)
//! b̂₂₁,₂₂ = sign(α_v) (ω_v √|α_v| ∓ ω_u √|α_u|)² / ω_u²,  α_u α_v < 0    (4-10)
//! C4-1: α_R, α_u, α_v alternate in sign
//! C4-2: b̂₂₂ > b̂₂ > b̂₂₁ > 0 (α_u < 0 < α_v)  or  b̂₂₂ < b̂₂ < b̂₂₁ < 0 (α_u > 0 > α_v)
//! P4-1: CMP-CNMP ⇔ C4-1 ∧ C4-2
//! ```
//!
//! Eq. 4-9's second form in the thesis, `ω_Δ(ω_v + ω_u)(…)/ω_u²` with
//! `ω_Δ = ω_u − ω_v`, has the opposite sign of its first form and of the
//! normalisation Eq. 4-7; the first form is used (it is the one consistent
//! with Eq. 4-10 and with `N(x)`'s roots, which the tests check).

use super::modal::ModalTerm;
use serde::{Deserialize, Serialize};

/// The result of the three-mode test for one bench.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ThreeModeTest {
    /// Remainder residue α_R, 1/kg.
    pub alpha_r_per_kg: f64,
    /// Residue α_u of the lower mode of the pair, 1/kg.
    pub alpha_u_per_kg: f64,
    /// Residue α_v of the upper mode of the pair, 1/kg.
    pub alpha_v_per_kg: f64,
    /// Natural frequency of mode u, Hz.
    pub frequency_u_hz: f64,
    /// Natural frequency of mode v, Hz.
    pub frequency_v_hz: f64,
    /// Normalised second-order coefficient b̂₂ (Eq. 4-9), 1/kg.
    pub b2_hat: f64,
    /// Critical value b̂₂₁ (Eq. 4-10, the smaller magnitude), 1/kg; `None`
    /// unless α_u α_v < 0.
    pub b21_hat: Option<f64>,
    /// Critical value b̂₂₂ (Eq. 4-10, the larger magnitude), 1/kg.
    pub b22_hat: Option<f64>,
    /// Condition C4-1: alternating signs.
    pub c4_1: bool,
    /// Condition C4-2 (Eq. 4-11 or 4-12).
    pub c4_2: bool,
    /// Verdict of Proposition P4-1 (C4-1 ∧ C4-2): CMP-CNMP zeros in the
    /// three-mode model.
    pub p4_1_cnmp: bool,
    /// Natural frequency of the remainder mode R, Hz (0: a true double
    /// integrator).
    pub frequency_r_hz: f64,
    /// How much taking R as a double integrator (Assumption A4-5) moves
    /// b̂₂ at the pair: R's contribution at `ω_u` is `α_R/(ω_R² − ω_u²)`
    /// instead of `−α_R/ω_u²`, an effective residue larger by
    /// `α_R ω_R²/(ω_u² − ω_R²)`, times the normalisation of Eq. 4-9. 1/kg.
    pub remainder_error_hat: f64,
    /// `b̂₂` is farther than `remainder_error_hat` from both critical
    /// values (or they do not exist), and the labels R, u, v are sure
    /// (`labels_unsure` is `None`): the assumptions of P4-1 hold well
    /// enough for its verdict to be decisive here.
    pub p4_1_decisive: bool,
    /// Why the labels R, u, v could be other modes
    /// ([`super::modal::PairLabels::unsure`]); `None` when they are sure.
    #[serde(default)]
    pub labels_unsure: Option<String>,
}

impl ThreeModeTest {
    /// The test from residues (1/kg), the remainder's frequency `omega_r`
    /// (rad/s; 0 for a double integrator) and the pair's (rad/s,
    /// `omega_r < ω_u < ω_v`).
    pub fn from_residues(
        alpha_r: f64,
        alpha_u: f64,
        alpha_v: f64,
        omega_r: f64,
        omega_u: f64,
        omega_v: f64,
    ) -> Self {
        let (wu2, wv2) = (omega_u * omega_u, omega_v * omega_v);
        let b2 = alpha_r + alpha_u + alpha_v;
        let b2_hat = (wv2 - wu2) * b2 / wu2;
        let (b21_hat, b22_hat) = if alpha_u * alpha_v < 0.0 {
            let a = omega_v * alpha_v.abs().sqrt();
            let b = omega_u * alpha_u.abs().sqrt();
            let sign = alpha_v.signum();
            (
                Some(sign * (a - b).powi(2) / wu2),
                Some(sign * (a + b).powi(2) / wu2),
            )
        } else {
            (None, None)
        };
        let c4_1 = alpha_r * alpha_u < 0.0 && alpha_u * alpha_v < 0.0;
        let c4_2 = match (b21_hat, b22_hat) {
            (Some(b21), Some(b22)) if alpha_u < 0.0 && alpha_v > 0.0 => {
                b22 > b2_hat && b2_hat > b21 && b21 > 0.0
            }
            (Some(b21), Some(b22)) if alpha_u > 0.0 && alpha_v < 0.0 => {
                b22 < b2_hat && b2_hat < b21 && b21 < 0.0
            }
            _ => false,
        };
        let remainder_error_hat =
            ((wv2 - wu2) / wu2 * alpha_r * omega_r * omega_r / (wu2 - omega_r * omega_r)).abs();
        let p4_1_decisive = [b21_hat, b22_hat]
            .iter()
            .flatten()
            .all(|b| (b - b2_hat).abs() > remainder_error_hat);
        Self {
            alpha_r_per_kg: alpha_r,
            alpha_u_per_kg: alpha_u,
            alpha_v_per_kg: alpha_v,
            frequency_u_hz: omega_u / (2.0 * std::f64::consts::PI),
            frequency_v_hz: omega_v / (2.0 * std::f64::consts::PI),
            b2_hat,
            b21_hat,
            b22_hat,
            c4_1,
            c4_2,
            p4_1_cnmp: c4_1 && c4_2,
            frequency_r_hz: omega_r / (2.0 * std::f64::consts::PI),
            remainder_error_hat,
            p4_1_decisive,
            labels_unsure: None,
        }
    }

    /// The test for labelled modal terms (`R`, `u`, `v` from
    /// [`super::modal::modal_terms`]); `None` if the bench has no remainder
    /// mode in the path or no pair.
    pub fn from_terms(terms: &[ModalTerm]) -> Option<Self> {
        let find = |l: &str| terms.iter().find(|t| t.label == l);
        let (r, u, v) = (find("R")?, find("u")?, find("v")?);
        let mut t = Self::from_residues(
            r.residue_per_kg,
            u.residue_per_kg,
            v.residue_per_kg,
            r.omega_rad_s(),
            u.omega_rad_s(),
            v.omega_rad_s(),
        );
        t.labels_unsure = super::modal::term_labels(terms).unsure;
        t.p4_1_decisive &= t.labels_unsure.is_none();
        Some(t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// CMP-CNMP in Eq. 4-1 exactly: the quadratic N(x) of Eq. 4-3 has
    /// complex roots (negative discriminant).
    fn quadratic_cnmp(ar: f64, au: f64, av: f64, wu: f64, wv: f64) -> bool {
        let (wu2, wv2) = (wu * wu, wv * wv);
        let b2 = ar + au + av;
        let b1 = (wu2 + wv2) * ar + au * wv2 + av * wu2;
        let b0 = ar * wu2 * wv2;
        b1 * b1 - 4.0 * b2 * b0 < 0.0
    }

    #[test]
    fn proposition_p4_1_matches_the_quadratic_discriminant() {
        // P4-1 is an if-and-only-if: on residues sampled over six decades
        // and both sign patterns, the verdict equals the exact one.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(41);
        let (mut yes, mut no) = (0, 0);
        for _ in 0..20000 {
            let wu = 2.0 * std::f64::consts::PI * 150.0;
            let wv = wu * rng.random_range(1.0001..1.3);
            let s =
                |rng: &mut rand_chacha::ChaCha8Rng| if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let m = |rng: &mut rand_chacha::ChaCha8Rng| 10f64.powf(rng.random_range(-3.0..3.0));
            let ar = s(&mut rng) * m(&mut rng);
            let au = s(&mut rng) * m(&mut rng);
            let av = s(&mut rng) * m(&mut rng);
            let exact = quadratic_cnmp(ar, au, av, wu, wv);
            let t = ThreeModeTest::from_residues(ar, au, av, 0.0, wu, wv);
            // Skip points within rounding of the tangency (b̂₂ = b̂₂₁,₂₂).
            let edge = [t.b21_hat, t.b22_hat]
                .iter()
                .flatten()
                .any(|b| (b - t.b2_hat).abs() <= 1e-9 * b.abs());
            if edge {
                continue;
            }
            assert_eq!(
                t.p4_1_cnmp,
                exact,
                "α_R {ar} α_u {au} α_v {av} ω_v/ω_u {}",
                wv / wu
            );
            if exact {
                yes += 1;
            } else {
                no += 1;
            }
        }
        assert!(yes > 100 && no > 100, "{yes} CMP-CNMP, {no} not");
    }

    #[test]
    fn eq_4_5_critical_remainders_bound_the_cnmp_interval() {
        // Thesis 4.2.2's example: α_u = −1, α_v = 1, ω_u² = 1, ω_v² = 2.
        // Eq. 4-5: α_R1,2 = (α_v ω_u² − α_u ω_v² ± 2 ω_u ω_v √(−α_u α_v)) /
        // (ω_v² − ω_u²) = 3 ± 2√2; CMP-CNMP strictly between.
        let (wu, wv) = (1.0, 2f64.sqrt());
        let lo = 3.0 - 2.0 * 2f64.sqrt();
        let hi = 3.0 + 2.0 * 2f64.sqrt();
        for (ar, want) in [
            (lo * 0.99, false),
            (lo * 1.01, true),
            (3.0, true),
            (hi * 0.99, true),
            (hi * 1.01, false),
        ] {
            assert_eq!(
                ThreeModeTest::from_residues(ar, -1.0, 1.0, 0.0, wu, wv).p4_1_cnmp,
                want,
                "α_R {ar}"
            );
        }
    }
}
