//! Model analysis (thesis Chapters 2–4): the modes of the actuator-to-probe
//! path with their modal residues and signs, the sequence of dominant
//! modes, the zeros typed MMP / RMP-RNMP / CMP-CNMP, Chapter 4's
//! three-mode test, the CNMP map and curve veering.
//!
//! Everything here is computed from a [`bench_hal::model::Sr4dof`], so it
//! works for any bench a config describes. `bench analyze` and `bench map`
//! print it; the fit, the campaign and a controller designer reuse it.

pub mod map;
pub mod modal;
pub mod plot;
pub mod sequence;
pub mod three_mode;

use bench_hal::model::Sr4dof;
use modal::{damped_zeros, has_cmp_cnmp, modal_terms, undamped_zeros, ModalTerm, TypedZero};
use sequence::{dominant_sequence, SeqTerm, TakeOver};
use serde::Serialize;
use three_mode::ThreeModeTest;

/// Everything `bench analyze` reports for one bench.
#[derive(Debug, Clone, PartialEq, Serialize)]
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
