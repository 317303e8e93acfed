//! The sign sequence and the sequence of dominant modes (thesis 3.2.1).
//!
//! For an undamped structural transfer function (Assumptions A3-1 to A3-3)
//!
//! ```text
//! G(jω) = Σᵢ αᵢ / (ωᵢ² − ω²)        (Eq. 3-2 at s = jω: real)
//! ```
//!
//! the phase is 0° or 180° and follows the *dominant mode*. A mode takes
//! over (a) near its own resonance, where its contribution outgrows the
//! rest (rule 3), and (b) at a real zero `ω₀` of `G` (an MMP zero) whose
//! sign change it causes: `G(ω₀⁺)·Gₓ(ω₀) > 0` (rule 1). When several modes
//! qualify at a zero, rule 2 keeps those that would still make a zero
//! near `ω₀` with the non-candidates alone; if several or none remain, an
//! abstract mode takes over, written `[DC]`/`[-DC]` below all its
//! members' resonances and `[DI]`/`[-DI]` above them (the sign is that of
//! the members' summed residue). At `ω → 0` the mode whose static gain
//! `αᵢ/ωᵢ²` carries the sign of `G(0)` and outweighs all others dominates,
//! else `[DC]`/`[-DC]`. A mode never takes over twice in a row (rule 4).
//!
//! Modes adjacent in frequency with residues of the same sign are written
//! as one group (`[Ru]`, `[uv]`), as in Tables 3-1 to 3-4: in-phase modes
//! alternate with their zeros whatever their sizes, so only the group
//! matters for the zero types.
//!
//! Computed this way, (sign sequence, dominant sequence) determines the
//! zero types as in Table 3-3; `tests` check that on sampled residues.

use bench_plant::model::{poly_mul, poly_roots, ZeroType};
use nalgebra::Complex;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// "Sufficiently close" of rule 2a: a candidate's own zero (with the
/// non-candidates alone) within a factor of 2 in frequency of `ω₀`.
pub const NEAR_ZERO_LN: f64 = std::f64::consts::LN_2;

/// One mode of an undamped modal sum.
#[derive(Debug, Clone, PartialEq)]
pub struct SeqTerm {
    /// Name (`R`, `u`, `v`, …).
    pub label: String,
    /// Natural frequency, rad/s (> 0).
    pub omega_rad_s: f64,
    /// Modal residue (any unit; only ratios matter), non-zero.
    pub residue: f64,
}

/// Why a mode takes over.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum TakeOverCause {
    /// Dominant at low frequency (ω → 0).
    LowFrequency,
    /// Near its own resonance (rule 3).
    Resonance,
    /// At an MMP zero it causes (rule 1, 2).
    Zero,
}

/// A take-over: from `frequency_hz` upwards `to` dominates.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct TakeOver {
    /// Frequency of the take-over, Hz (0 for the low-frequency one).
    pub frequency_hz: f64,
    /// The mode or group that takes over (`R`, `Ru`, `DI`, …).
    pub to: String,
    /// Why.
    pub cause: TakeOverCause,
}

/// The sequence of dominant modes with its sign sequence.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DominantSequence {
    /// Thesis notation, e.g. `[R]-[u]-[v]`, `[Ru]-[v]-[DI]`.
    pub notation: String,
    /// Sign sequence in frequency order, e.g. `α_R > 0, α_u < 0, α_v > 0`.
    pub signs: String,
    /// `true` if adjacent modes alternate in sign all along (Condition
    /// C4-1 for three modes).
    pub alternating: bool,
    /// The take-overs, ascending in frequency, repeats removed.
    pub take_overs: Vec<TakeOver>,
}

/// `G(ω)` of the undamped sum at real frequency `w` (rad/s).
fn g(terms: &[&SeqTerm], w: f64) -> f64 {
    terms
        .iter()
        .map(|t| t.residue / (t.omega_rad_s.powi(2) - w * w))
        .sum()
}

/// Sign of `dG/dω` at `w` (`dG/dω = 2ω Σ αᵢ/(ωᵢ² − ω²)²`).
fn g_slope(terms: &[&SeqTerm], w: f64) -> f64 {
    terms
        .iter()
        .map(|t| t.residue / (t.omega_rad_s.powi(2) - w * w).powi(2))
        .sum()
}

/// Roots `u = s²` of the numerator `N(u) = Σᵢ αᵢ Πⱼ≠ᵢ (u + ωⱼ²)` of an
/// undamped modal sum, computed in `u/ω̄²` (ω̄ the geometric mean
/// frequency) for conditioning. `None` if the eigensolver fails.
pub fn numerator_roots(terms: &[(f64, f64)]) -> Option<Vec<Complex<f64>>> {
    if terms.is_empty() {
        return Some(Vec::new());
    }
    let scale = (terms.iter().map(|(w, _)| (w * w).ln()).sum::<f64>() / terms.len() as f64).exp();
    let mut num = vec![0.0; terms.len()];
    for (i, (_, a)) in terms.iter().enumerate() {
        let mut p = vec![*a];
        for (j, (w, _)) in terms.iter().enumerate() {
            if i != j {
                p = poly_mul(&p, &[1.0, w * w / scale]);
            }
        }
        let off = num.len() - p.len();
        for (k, c) in p.into_iter().enumerate() {
            num[off + k] += c;
        }
    }
    Some(poly_roots(&num)?.into_iter().map(|v| v * scale).collect())
}

/// Real zero frequencies (rad/s, ascending) of an undamped modal sum: the
/// MMP roots `u < 0`, `ω₀ = √−u`.
fn real_zero_frequencies(terms: &[&SeqTerm]) -> Vec<f64> {
    let pairs: Vec<(f64, f64)> = terms.iter().map(|t| (t.omega_rad_s, t.residue)).collect();
    let mut out: Vec<f64> = numerator_roots(&pairs)
        .unwrap_or_default()
        .into_iter()
        .filter(|u| ZeroType::of_u(*u) == ZeroType::Mmp)
        .map(|u| (-u.re).sqrt())
        .filter(|w| {
            terms
                .iter()
                .all(|t| (t.omega_rad_s - w).abs() > 1e-9 * t.omega_rad_s)
        })
        .collect();
    out.sort_by(f64::total_cmp);
    out
}

/// The dominant-mode sequence of `terms` (the modes of the path, any
/// order; residues must be non-zero and frequencies distinct and > 0).
pub fn dominant_sequence(terms: &[SeqTerm]) -> DominantSequence {
    let mut sorted: Vec<&SeqTerm> = terms.iter().collect();
    sorted.sort_by(|a, b| a.omega_rad_s.total_cmp(&b.omega_rad_s));
    // Groups of in-phase neighbours.
    let mut groups: Vec<Vec<&SeqTerm>> = Vec::new();
    for t in &sorted {
        match groups.last_mut() {
            Some(gr) if gr[0].residue.signum() == t.residue.signum() => gr.push(t),
            _ => groups.push(vec![t]),
        }
    }
    let name = |gr: &[&SeqTerm]| gr.iter().map(|t| t.label.as_str()).collect::<String>();
    let all: Vec<&SeqTerm> = sorted.clone();

    let mut events: Vec<TakeOver> = Vec::new();
    // ω → 0.
    if !groups.is_empty() {
        events.push(low_frequency_take_over(&all, &groups));
    }
    // Resonances.
    for gr in &groups {
        for t in gr {
            events.push(TakeOver {
                frequency_hz: t.omega_rad_s / (2.0 * PI),
                to: name(gr),
                cause: TakeOverCause::Resonance,
            });
        }
    }
    // Real zeros: candidates are single modes (rule 1); the label is the
    // chosen mode's group.
    let group_of = |t: &SeqTerm| {
        groups
            .iter()
            .position(|gr| gr.iter().any(|m| std::ptr::eq(*m, t)))
            .expect("every mode is in a group")
    };
    let poles: Vec<f64> = sorted.iter().map(|t| t.omega_rad_s).collect();
    for w0 in real_zero_frequencies(&all) {
        let after = g_slope(&all, w0).signum();
        let cands: Vec<&SeqTerm> = all
            .iter()
            .copied()
            .filter(|t| g(&[t], w0).signum() == after)
            .collect();
        // Rule 2a: candidate x, with the non-candidates alone, still takes
        // over at a zero between the same two poles of G; of those, the
        // one whose zero is nearest ω₀ (in log frequency).
        let (lo, hi) = poles_around(&poles, w0);
        let rest: Vec<&SeqTerm> = all
            .iter()
            .copied()
            .filter(|t| !cands.iter().any(|c| std::ptr::eq(*c, *t)))
            .collect();
        // Inside the span of in-phase neighbours (between two of their
        // resonances) the group keeps dominating: Tables 3-1 to 3-4 write
        // such stretches [uv] whatever happens between the poles.
        if let Some(gr) = groups.iter().find(|gr| {
            gr.len() > 1
                && gr.first().unwrap().omega_rad_s < w0
                && gr.last().unwrap().omega_rad_s > w0
        }) {
            events.push(TakeOver {
                frequency_hz: w0 / (2.0 * PI),
                to: name(gr),
                cause: TakeOverCause::Zero,
            });
            continue;
        }
        let standalone: Vec<(&SeqTerm, f64)> = if cands.len() <= 1 {
            cands.iter().map(|c| (*c, 0.0)).collect()
        } else {
            cands
                .iter()
                .filter_map(|&c| {
                    let mut sys = rest.clone();
                    sys.push(c);
                    real_zero_frequencies(&sys)
                        .into_iter()
                        .filter(|&w| {
                            w > lo && w < hi && g(&[c], w).signum() == g_slope(&sys, w).signum()
                        })
                        .map(|w| (w / w0).ln().abs())
                        .min_by(f64::total_cmp)
                        .filter(|d| *d <= NEAR_ZERO_LN)
                        .map(|d| (c, d))
                })
                .collect()
        };
        let members: Vec<&SeqTerm> = if standalone.is_empty() {
            cands.clone()
        } else {
            standalone.iter().map(|(c, _)| *c).collect()
        };
        let sum: f64 = members.iter().map(|t| t.residue).sum();
        let sign = if sum >= 0.0 { "" } else { "-" };
        let mut gids: Vec<usize> = members.iter().map(|t| group_of(t)).collect();
        gids.dedup();
        let to = if gids.len() == 1 {
            // One mode, or in-phase neighbours: the group, written [DI] /
            // [DC] beyond all its (two or more) members' resonances.
            let gr = &groups[gids[0]];
            if gr.len() > 1 && gr.iter().all(|t| t.omega_rad_s < w0) {
                format!("{sign}DI")
            } else if gr.len() > 1 && gr.iter().all(|t| t.omega_rad_s > w0) {
                format!("{sign}DC")
            } else {
                name(gr)
            }
        } else if members.iter().all(|t| t.omega_rad_s < w0) {
            format!("{sign}DI")
        } else if members.iter().all(|t| t.omega_rad_s > w0) {
            format!("{sign}DC")
        } else if let Some((c, _)) = standalone.iter().min_by(|a, b| a.1.total_cmp(&b.1)) {
            name(&groups[group_of(c)])
        } else {
            name(&members)
        };
        events.push(TakeOver {
            frequency_hz: w0 / (2.0 * PI),
            to,
            cause: TakeOverCause::Zero,
        });
    }
    events.sort_by(|a, b| a.frequency_hz.total_cmp(&b.frequency_hz));
    // Rule 4.
    let mut take_overs: Vec<TakeOver> = Vec::new();
    for e in events {
        if take_overs.last().map(|l| l.to == e.to) != Some(true) {
            take_overs.push(e);
        }
    }
    let notation = take_overs
        .iter()
        .map(|t| format!("[{}]", t.to))
        .collect::<Vec<_>>()
        .join("-");
    let signs = residue_signs(&sorted);
    let alternating = sorted.windows(2).all(|w| w[0].residue * w[1].residue < 0.0);
    DominantSequence {
        notation,
        signs,
        alternating,
        take_overs,
    }
}

/// The take-over as ω → 0: the group of in-phase neighbours whose static
/// gain dominates the whole static gain, else the static gain itself (`DC`,
/// `-DC` when negative).
fn low_frequency_take_over(all: &[&SeqTerm], groups: &[Vec<&SeqTerm>]) -> TakeOver {
    let g0 = g(all, 0.0);
    let statics: Vec<f64> = groups.iter().map(|gr| g(gr, 0.0)).collect();
    let (best, &s_best) = statics
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
        .expect("non-empty");
    let to = if s_best.signum() == g0.signum() && s_best.abs() > (g0 - s_best).abs() {
        groups[best].iter().map(|t| t.label.as_str()).collect()
    } else if g0 >= 0.0 {
        "DC".into()
    } else {
        "-DC".into()
    };
    TakeOver {
        frequency_hz: 0.0,
        to,
        cause: TakeOverCause::LowFrequency,
    }
}

/// The poles of G nearest below and above `w0`, rad/s (0 and ∞ when none).
fn poles_around(poles: &[f64], w0: f64) -> (f64, f64) {
    let lo = poles
        .iter()
        .copied()
        .filter(|p| *p < w0)
        .fold(0.0, f64::max);
    let hi = poles
        .iter()
        .copied()
        .filter(|p| *p > w0)
        .fold(f64::INFINITY, f64::min);
    (lo, hi)
}

/// The residues' signs in frequency order, `α_u > 0, α_v < 0, …`.
fn residue_signs(sorted: &[&SeqTerm]) -> String {
    sorted
        .iter()
        .map(|t| {
            format!(
                "α_{} {} 0",
                t.label,
                if t.residue > 0.0 { ">" } else { "<" }
            )
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// Thesis Table 3-3 (a double integrator R and two modes u < v): the zero
/// types that a sign pattern `(sign α_R, sign α_u, sign α_v)` and a
/// sequence of dominant modes map to, with CMP-CNMP and dual RMP-RNMP as
/// one class written `"NMP"` (the table's "CMP-CNMP or dual RMP-RNMP";
/// the sequence cannot tell them apart). `None` for a pair the table does
/// not list.
pub fn table_3_3_zero_types(
    signs: (i8, i8, i8),
    sequence: &str,
) -> Option<&'static [&'static str]> {
    const DUAL_MMP: &[&str] = &["MMP", "MMP"];
    const MMP_RNMP: &[&str] = &["MMP", "RMP-RNMP"];
    const NMP: &[&str] = &["NMP", "NMP"];
    Some(match (signs, sequence) {
        ((1, -1, 1), "[R]-[u]-[v]") => NMP,
        ((1, -1, 1), "[R]-[u]-[R]-[v]") => DUAL_MMP,
        ((1, -1, 1), "[R]-[u]-[v]-[u]") => MMP_RNMP,
        ((1, -1, 1), "[R]-[v]-[u]-[v]") => DUAL_MMP,
        ((1, -1, 1), "[R]-[u]-[v]-[u]-[DI]") => DUAL_MMP,
        ((1, 1, -1), "[Ru]-[v]") => MMP_RNMP,
        ((1, 1, -1), "[Ru]-[v]-[DI]") => DUAL_MMP,
        ((1, -1, -1), "[R]-[uv]-[R]") => DUAL_MMP,
        ((1, -1, -1), "[R]-[uv]") => MMP_RNMP,
        ((1, 1, 1), "[Ruv]") => DUAL_MMP,
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn t(label: &str, w: f64, a: f64) -> SeqTerm {
        SeqTerm {
            label: label.into(),
            omega_rad_s: w,
            residue: a,
        }
    }

    /// Zero types of an undamped sum, sorted by name: the exact reference.
    fn zero_types(terms: &[SeqTerm]) -> Vec<&'static str> {
        let pairs: Vec<(f64, f64)> = terms.iter().map(|t| (t.omega_rad_s, t.residue)).collect();
        let mut v: Vec<&'static str> = numerator_roots(&pairs)
            .unwrap()
            .into_iter()
            .map(|u| ZeroType::of_u(u).as_str())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn eq_3_4_mmp_and_rmp_rnmp_cases() {
        // Thesis Eq. 3-4 / Fig 3-5: α_v = −0.5 → [u]-[v]-[u] (MMP),
        // α_v = −5 → [u]-[v] (RMP-RNMP).
        let mmp = [t("u", 1.0, 1.0), t("v", 10.0, -0.5)];
        assert_eq!(dominant_sequence(&mmp).notation, "[u]-[v]-[u]");
        assert_eq!(zero_types(&mmp), ["MMP"]);
        let rnmp = [t("u", 1.0, 1.0), t("v", 10.0, -5.0)];
        assert_eq!(dominant_sequence(&rnmp).notation, "[u]-[v]");
        assert_eq!(zero_types(&rnmp), ["RMP-RNMP"]);
    }

    #[test]
    fn eq_3_9_dual_mmp_cmp_cnmp_and_dual_rmp_rnmp() {
        // Thesis Eq. 3-9 / Fig 3-12 (α_R = 1 at 1 rad/s, α_u = −α0 at 10,
        // α_v = α0 at 11): α0 = 0.01 dual MMP [R]-[u]-[R]-[v]; α0 = 5
        // CMP-CNMP and α0 = 21 dual RMP-RNMP, both [R]-[u]-[v].
        let sys = |a0: f64| [t("R", 1.0, 1.0), t("u", 10.0, -a0), t("v", 11.0, a0)];
        let s = dominant_sequence(&sys(0.01));
        assert_eq!(s.notation, "[R]-[u]-[R]-[v]");
        assert!(s.alternating);
        assert_eq!(zero_types(&sys(0.01)), ["MMP", "MMP"]);
        assert_eq!(dominant_sequence(&sys(5.0)).notation, "[R]-[u]-[v]");
        assert_eq!(zero_types(&sys(5.0)), ["CMP-CNMP", "CMP-CNMP"]);
        assert_eq!(dominant_sequence(&sys(21.0)).notation, "[R]-[u]-[v]");
        assert_eq!(zero_types(&sys(21.0)), ["RMP-RNMP", "RMP-RNMP"]);
    }

    #[test]
    fn sequences_map_to_zero_types_as_in_table_3_3() {
        // Sampled residues for every sign pattern of Table 3-3, with mode R
        // a near double integrator (ω_R ≪ ω_u < ω_v): the sequence must be
        // a row of the table and the exact zero types those of the row.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(33);
        let mut seen = std::collections::BTreeSet::new();
        let mut unmatched = Vec::new();
        for _ in 0..4000 {
            let wu = 10.0;
            let wv = wu * rng.random_range(1.01..1.5);
            let signs = [(1, -1, 1), (1, 1, -1), (1, -1, -1), (1, 1, 1)][rng.random_range(0..4)];
            let mag = |rng: &mut rand_chacha::ChaCha8Rng| 10f64.powf(rng.random_range(-3.0..2.0));
            let au = signs.1 as f64 * mag(&mut rng);
            let av = signs.2 as f64 * mag(&mut rng);
            let sys = [t("R", 0.01, 1.0), t("u", wu, au), t("v", wv, av)];
            let seq = dominant_sequence(&sys).notation;
            // Exact types, CMP-CNMP and RMP-RNMP as one class ("NMP").
            let types: Vec<&str> = zero_types(&sys)
                .into_iter()
                .map(|k| if k == "MMP" { "MMP" } else { "NMP" })
                .collect::<std::collections::BTreeSet<_>>()
                .into_iter()
                .collect();
            match table_3_3_zero_types(signs, &seq) {
                Some(row) => {
                    let want: Vec<&str> = row
                        .iter()
                        .map(|k| if *k == "MMP" { "MMP" } else { "NMP" })
                        .collect::<std::collections::BTreeSet<_>>()
                        .into_iter()
                        .collect();
                    assert_eq!(
                        types, want,
                        "signs {signs:?} α_u {au} α_v {av} ω_v {wv}: {seq}"
                    );
                    seen.insert((signs, seq));
                }
                None => unmatched.push(format!(
                    "{signs:?} α_u {au:.3e} α_v {av:.3e} ω_v {wv:.3}: {seq}"
                )),
            }
        }
        assert!(
            unmatched.len() < 40,
            "{} sequences not in Table 3-3, e.g. {:?}",
            unmatched.len(),
            &unmatched[..unmatched.len().min(10)]
        );
        // Most rows of the table are reached.
        assert!(seen.len() >= 8, "{seen:?}");
    }
}
