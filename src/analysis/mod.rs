//! Model analysis (thesis Chapters 2–4): the modes of the actuator-to-probe
//! path with their modal residues and signs, the sequence of dominant
//! modes, the zeros typed MMP / RMP-RNMP / CMP-CNMP, Chapter 4's
//! three-mode test, the CNMP map and curve veering.
//!
//! Everything here is computed from a [`bench_plant::model::Sr4dof`], so it
//! works for any bench a config describes. `bench analyze` and `bench map`
//! print it; the fit, the campaign and a controller designer reuse it.
//!
//! Layer rule: may use `config`.

pub mod map;
pub mod modal;
pub mod sequence;
pub mod three_mode;

use bench_plant::model::Sr4dof;
use modal::{damped_zeros, has_cmp_cnmp, modal_terms, undamped_zeros, ModalTerm, TypedZero};
use sequence::{dominant_sequence, SeqTerm, TakeOver};
use serde::{Deserialize, Serialize};
use three_mode::ThreeModeTest;

/// Everything `bench analyze` reports for one bench.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Analysis {
    /// Operating point Y1o, m.
    pub operating_point_m: f64,
    /// Mass asymmetry Δm23 = m2/m3 − 1.
    pub mass_asymmetry: f64,
    /// Coupling coefficient α = 0.6·Y1o/L (Eq. 2-6).
    pub coupling_alpha: f64,
    /// The four modes, ascending in frequency.
    pub modes: Vec<ModalTerm>,
    /// The sequence of dominant modes of the modes in the path in the
    /// thesis' notation (3.2.1, Table 3-3), e.g. `[R]-[u]-[v]`.
    pub sequence: String,
    /// The sign sequence of their residues in frequency order, e.g.
    /// `α_R > 0, α_u < 0, α_v > 0`.
    pub sign_sequence: String,
    /// Adjacent modes alternate in sign all along.
    pub alternating_signs: bool,
    /// The take-overs behind `sequence`, ascending in frequency.
    pub take_overs: Vec<TakeOver>,
    /// Zeros of the undamped transfer function (Eq. 2-7 / 3-2), typed.
    pub zeros_undamped: Vec<TypedZero>,
    /// Zeros of the damped transfer function, typed.
    pub zeros_damped: Vec<TypedZero>,
    /// Discriminant Δ of Eq. 2-8 (negative ⇔ CMP-CNMP, undamped).
    pub discriminant: f64,
    /// CMP-CNMP zeros in the undamped model.
    pub cnmp: bool,
    /// CMP-CNMP zeros in the damped model.
    pub cnmp_damped: bool,
    /// Chapter 4's three-mode test (absent without a remainder mode or a
    /// pair in the path).
    pub three_mode: Option<ThreeModeTest>,
}

/// Analyses one bench.
pub fn analyze(model: &Sr4dof) -> Analysis {
    let modes = modal_terms(model);
    let seq_terms: Vec<SeqTerm> = modes
        .iter()
        .filter(|t| t.in_path && t.residue_per_kg != 0.0)
        .map(|t| SeqTerm {
            label: t.label.clone(),
            omega_rad_s: t.omega_rad_s(),
            residue: t.residue_per_kg,
        })
        .collect();
    let zeros_undamped = undamped_zeros(model);
    let zeros_damped = damped_zeros(model);
    let p = model.params();
    let seq = dominant_sequence(&seq_terms);
    Analysis {
        operating_point_m: p.operating_point_m,
        mass_asymmetry: p.mass_asymmetry,
        coupling_alpha: model.alpha(),
        sequence: seq.notation,
        sign_sequence: seq.signs,
        alternating_signs: seq.alternating,
        take_overs: seq.take_overs,
        cnmp: has_cmp_cnmp(&zeros_undamped),
        cnmp_damped: has_cmp_cnmp(&zeros_damped),
        discriminant: model.cnmp_discriminant(),
        three_mode: ThreeModeTest::from_terms(&modes),
        zeros_undamped,
        zeros_damped,
        modes,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::BenchConfig;
    use bench_plant::model::ZeroType;

    fn ch5_at(op_fraction: f64, dm: f64) -> Analysis {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
        let mut p = BenchConfig::load(&path).unwrap().plant;
        p.operating_point_m = op_fraction * p.beam.length_m;
        p.mass_asymmetry = dm;
        analyze(&Sr4dof::new(p).unwrap())
    }

    fn signs(a: &Analysis) -> Vec<(String, i8)> {
        a.modes
            .iter()
            .filter(|m| m.in_path)
            .map(|m| (m.label.clone(), m.sign))
            .collect()
    }

    #[test]
    fn chapter_5_bench_at_8_percent_alternates_signs_only_for_positive_asymmetry() {
        // Thesis 6.2.1 (Fig 6-9): Chapter 5 bench at Y1o = 8 % of L:
        // Δm23 = +10 % gives α_R > 0, α_u < 0, α_v > 0 (alternating) and
        // CMP-CNMP zeros; −10 % gives α_R > 0, α_u > 0, α_v < 0 and none.
        let pos = ch5_at(0.08, 0.10);
        assert_eq!(
            signs(&pos),
            [("R".into(), 1), ("u".into(), -1), ("v".into(), 1)],
            "{pos:#?}"
        );
        assert!(pos.alternating_signs);
        assert!(pos.cnmp && pos.cnmp_damped);
        assert_eq!(pos.sequence, "[R]-[u]-[v]");
        let neg = ch5_at(0.08, -0.10);
        assert_eq!(
            signs(&neg),
            [("R".into(), 1), ("u".into(), 1), ("v".into(), -1)],
            "{neg:#?}"
        );
        assert!(!neg.alternating_signs && !neg.cnmp && !neg.cnmp_damped);
        // (+, +, −): MMP + RMP-RNMP or dual MMP (Table 3-3), never CMP-CNMP.
        assert!(neg
            .zeros_undamped
            .iter()
            .all(|z| z.kind != ZeroType::CmpCnmp));
        assert!(neg.sequence.starts_with("[Ru]-[v]"), "{}", neg.sequence);
        // Leave out the zero that cancels the hidden Y mode's pole.
        let hidden: Vec<f64> = neg
            .modes
            .iter()
            .filter(|m| !m.in_path)
            .map(|m| m.frequency_hz)
            .collect();
        let of_path = |z: &&modal::TypedZero| {
            hidden
                .iter()
                .all(|f| (z.frequency_hz / f - 1.0).abs() > 0.01)
        };
        let mmp = neg
            .zeros_undamped
            .iter()
            .filter(of_path)
            .filter(|z| z.kind == ZeroType::Mmp)
            .count();
        let rnmp = neg
            .zeros_undamped
            .iter()
            .filter(of_path)
            .filter(|z| z.kind == ZeroType::RmpRnmp)
            .count();
        match neg.sequence.as_str() {
            "[Ru]-[v]" => assert_eq!(
                (mmp, rnmp),
                (2, 2),
                "MMP + RMP-RNMP: {:?}",
                neg.zeros_undamped
            ),
            "[Ru]-[v]-[DI]" => {
                assert_eq!((mmp, rnmp), (4, 0), "dual MMP: {:?}", neg.zeros_undamped)
            }
            other => panic!("not a Table 3-3 row for (+, +, −): {other}"),
        }
    }
}
