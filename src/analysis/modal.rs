//! The modes of the actuator-to-probe path and the zeros they make.
//!
//! For the SR4DoF (`bench_plant::model::Sr4dof`, thesis Eq. 2-5) with force
//! input `q = [1, α, −2α, 0]ᵀ` and probe output `c = [1, 0, 0, 0]ᵀ`, each
//! mode `i` of `K φ = ω² M φ` contributes `αᵢ / (s² + 2ζᵢωᵢ s + ωᵢ²)` to
//! the force → x1 transfer function, with the modal residue of Eq. 4-15
//!
//! ```text
//! αᵢ = (cᵀφ̂ᵢ)(qᵀφ̂ᵢ) / m̃ᵢ,    m̃ᵢ = φ̂ᵢᵀ M φ̂ᵢ,    |φ̂ᵢ| = 1
//! ```
//!
//! in 1/kg (m/(N·s²): metres of x1 per newton of actuator force, times
//! s²). It equals the `residue` of [`bench_plant::model::Mode`] (computed
//! there from the mass-normalised shape), which the tests check.

use bench_plant::model::{Sr4dof, ZeroType};
use nalgebra::{Complex, Vector4};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// A mode whose probe participation `|cᵀφ̂|` (unit-length shape) is below
/// this fraction of the largest mode's is unobservable in x1; the same
/// for the actuator participation `|qᵀφ̂|` (not driven). At Y1o > 0 the
/// Y mode of stages ①②③ keeps an x1 motion of about 1e-4 of the X
/// rigid-body mode's (thesis 4.4.2 calls it unobservable); the pair's
/// hidden mode at Δm23 = 0 has about 1e-16.
pub const PARTICIPATION_RATIO: f64 = 1e-3;

/// A mode whose `|αᵢ|` is below this fraction of the largest residue is
/// outside the path: its pole and a zero cancel to within the model's
/// accuracy, and the sequence of dominant modes leaves it out.
pub const RESIDUE_RATIO: f64 = 1e-4;

/// One mode of the actuator-to-probe path.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ModalTerm {
    /// Mode number, 1-based, ascending in frequency.
    pub mode: usize,
    /// Name in the thesis' notation: `u` and `v` for the closely spaced
    /// pair (lower, upper), `R` for the remainder mode that dominates the
    /// rest of the path, `m<N>` for any other mode.
    pub label: String,
    /// Undamped natural frequency, Hz.
    pub frequency_hz: f64,
    /// Modal damping ratio (Rayleigh), dimensionless.
    pub damping_ratio: f64,
    /// Modal mass `φ̂ᵀ M φ̂` of the unit-length shape, kg (Eq. 4-15).
    pub modal_mass_kg: f64,
    /// Unit-length mode shape over `[x1, y1, y2, y3]`, dimensionless, sign
    /// chosen so that its largest-magnitude entry is positive.
    pub shape: [f64; 4],
    /// Mass-normalised mode shape (`φᵀ M φ = 1`), m/√kg.
    pub shape_mass_normalised: [f64; 4],
    /// Probe participation `cᵀφ̂` (x1 entry of the unit shape).
    pub sensor_participation: f64,
    /// Actuator participation `qᵀφ̂`.
    pub actuator_participation: f64,
    /// Modal residue `αᵢ` of Eq. 4-15, 1/kg (= m/(N·s²)); its sign is the
    /// mode's direction (thesis 3.2.1: positive is 0°, negative 180°).
    /// `residue` in JSON.
    #[serde(rename = "residue")]
    pub residue_per_kg: f64,
    /// Sign of the residue: +1, −1, or 0 for a mode outside the path.
    pub sign: i8,
    /// The probe sees the mode ([`PARTICIPATION_RATIO`]).
    pub observable: bool,
    /// The actuator drives it ([`PARTICIPATION_RATIO`]).
    pub controllable: bool,
    /// The mode appears in the force → x1 transfer function
    /// ([`RESIDUE_RATIO`]).
    pub in_path: bool,
}

impl ModalTerm {
    /// Natural frequency, rad/s.
    pub fn omega_rad_s(&self) -> f64 {
        2.0 * PI * self.frequency_hz
    }
}

/// The modes of `model`'s force → x1 path, ascending in frequency, labelled
/// (see [`ModalTerm::label`]; the pair is [`closely_spaced_pair`]).
pub fn modal_terms(model: &Sr4dof) -> Vec<ModalTerm> {
    let m = model.mass();
    let q = model.input();
    // Per mode: unit shape, modal mass, sensor and actuator participation.
    type Raw = (Vector4<f64>, f64, f64, f64);
    let raw: Vec<Raw> = model
        .modes()
        .iter()
        .map(|mode| {
            let unit = mode.unit_shape();
            let modal_mass_kg = (unit.transpose() * m * unit)[(0, 0)];
            (unit, modal_mass_kg, unit[0], q.dot(&unit))
        })
        .collect();
    let max_of = |f: fn(&Raw) -> f64| raw.iter().map(f).fold(0.0, f64::max);
    let max_sensor = max_of(|r| r.2.abs());
    let max_actuator = max_of(|r| r.3.abs());
    let max_residue = max_of(|r| (r.2 * r.3 / r.1).abs());
    let mut terms: Vec<ModalTerm> = model
        .modes()
        .iter()
        .zip(&raw)
        .enumerate()
        .map(|(i, (mode, &(unit, modal_mass_kg, sensor, actuator)))| {
            let residue = sensor * actuator / modal_mass_kg;
            let in_path = residue.abs() >= RESIDUE_RATIO * max_residue;
            ModalTerm {
                mode: i + 1,
                label: format!("m{}", i + 1),
                frequency_hz: mode.frequency_hz(),
                damping_ratio: mode.zeta,
                modal_mass_kg,
                shape: [unit[0], unit[1], unit[2], unit[3]],
                shape_mass_normalised: [mode.shape[0], mode.shape[1], mode.shape[2], mode.shape[3]],
                sensor_participation: sensor,
                actuator_participation: actuator,
                residue_per_kg: residue,
                sign: if !in_path {
                    0
                } else if residue > 0.0 {
                    1
                } else {
                    -1
                },
                observable: sensor.abs() >= PARTICIPATION_RATIO * max_sensor,
                controllable: actuator.abs() >= PARTICIPATION_RATIO * max_actuator,
                in_path,
            }
        })
        .collect();
    label_terms(&mut terms);
    terms
}

/// Indices `(u, v)` into `terms` (ascending in frequency) of the
/// structurally closely spaced pair: the two adjacent modes with the
/// smallest frequency ratio, whatever their residues (thesis Assumption
/// A3-7 / A4-4; in the SR4DoF the 3rd and 4th modes, dominated by the
/// secondary stages): the veering of `bench map`, where a mode hidden by
/// symmetry still veers. The labels `u`, `v` of the path are
/// [`pair_and_remainder`]'s. `None` with fewer than two modes.
pub fn closely_spaced_pair(terms: &[ModalTerm]) -> Option<(usize, usize)> {
    (1..terms.len())
        .min_by(|&x, &y| {
            let r = |i: usize| terms[i].frequency_hz / terms[i - 1].frequency_hz;
            r(x).total_cmp(&r(y))
        })
        .map(|v| (v - 1, v))
}

/// Names the pair `u`, `v` and the remainder mode `R`
/// ([`pair_and_remainder`] over the model's modes).
fn label_terms(terms: &mut [ModalTerm]) {
    let l = term_labels(terms);
    if let Some((u, v)) = l.pair {
        terms[u].label = "u".into();
        terms[v].label = "v".into();
    }
    if let (Some(_), Some(r)) = (l.pair, l.remainder) {
        terms[r].label = "R".into();
    }
}

/// [`pair_and_remainder`] of modal terms.
pub fn term_labels(terms: &[ModalTerm]) -> PairLabels {
    let f: Vec<f64> = terms.iter().map(|t| t.frequency_hz).collect();
    let zeta: Vec<f64> = terms.iter().map(|t| t.damping_ratio).collect();
    let residue: Vec<f64> = terms
        .iter()
        .map(|t| if t.in_path { t.residue_per_kg } else { 0.0 })
        .collect();
    let strength = visibility(&f, &zeta, &residue);
    pair_and_remainder(&f, &residue, &strength, VISIBILITY, CLOSE_PAIR_RATIO)
}

/// How strongly each mode shows in the path (see [`VISIBILITY`]): modes
/// of frequencies `f_hz` (Hz), damping ratios `zeta`, residues `residue`
/// (0: outside the path).
pub fn visibility(f_hz: &[f64], zeta: &[f64], residue: &[f64]) -> Vec<f64> {
    let n = f_hz.len();
    let w = |i: usize| 2.0 * PI * f_hz[i];
    (0..n)
        .map(|i| {
            let wi = w(i);
            let own = residue[i].abs() / (2.0 * zeta[i].max(VISIBILITY_MIN_DAMPING) * wi * wi);
            let rest: Complex<f64> = (0..n)
                .filter(|&j| j != i)
                .map(|j| {
                    let wj = w(j);
                    Complex::new(residue[j], 0.0)
                        / Complex::new(wj * wj - wi * wi, 2.0 * zeta[j] * wj * wi)
                })
                .sum();
            if own == 0.0 {
                0.0
            } else {
                own / rest.norm().max(f64::MIN_POSITIVE)
            }
        })
        .collect()
}

/// A mode shows in the path when its resonant contribution
/// `|αᵢ| / (2ζᵢωᵢ²)` is at least this fraction of the rest of the path at
/// its frequency, `|Σⱼ≠ᵢ αⱼ / (ωⱼ² − ωᵢ² + 2jζⱼωⱼωᵢ)|`: it moves |H| by
/// about 1 dB or more there. The Y mode of stages ①②③ (an x1 residue of
/// about 1e-5 of the X rigid-body mode's) shows at about 1e-4 of this;
/// the pair's weaker mode at 0.2 % mass asymmetry at about 2.5.
pub const VISIBILITY: f64 = 0.1;

/// Largest ratio between two adjacent resonances for them to count as a
/// closely spaced pair.
pub const CLOSE_PAIR_RATIO: f64 = 1.25;

/// Damping ratio floor of the visibility (an undamped model's modes would
/// otherwise all show, however small their residue).
const VISIBILITY_MIN_DAMPING: f64 = 1e-3;

/// The labels of [`pair_and_remainder`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PairLabels {
    /// The closely spaced pair `(u, v)`.
    pub pair: Option<(usize, usize)>,
    /// The remainder mode `R`.
    pub remainder: Option<usize>,
    /// How strongly each mode shows in the path (the caller's measure:
    /// [`visibility`] for the model, `|Aᵢ|/σ` for a fit).
    pub strength: Vec<f64>,
    /// Why the labels could be other ones (`None`: they are sure):
    /// Chapter 4's three-mode test is then never decisive.
    pub unsure: Option<String>,
}

/// The labels' rule, shared by `bench analyze` (model modes) and the modal
/// fit (fitted modes). Modes ascending in frequency `f_hz` (Hz), with
/// residues (or modal constants) `residue` in the actuator-to-sensor path
/// and a `strength` each: only modes at or above `threshold` show in the
/// path and take part (the model: [`visibility`] against [`VISIBILITY`];
/// a fit: `|Aᵢ|/σ` against its significance):
/// - the closely spaced pair `(u, v)`: the two adjacent showing modes with
///   the smallest frequency ratio, if it is at most `max_ratio` (thesis
///   Assumption A3-7 / A4-4);
/// - the remainder mode `R`: with a pair, the showing mode outside it with
///   the largest contribution `|αᵢ / (ωᵢ² − ω²)|` at the pair's mean
///   frequency ω (Assumption A4-4: the remainder is dominated by a single
///   mode); without one, the largest static contribution `|αᵢ / ωᵢ²|`.
///
/// The labels are unsure ([`PairLabels::unsure`]) when a mode that does
/// not show lies closer to a mode of the pair than the pair's own ratio
/// (a partner the threshold decided), when a labelled mode's visibility is
/// within a factor 3 of the threshold, or when another two adjacent
/// showing modes are within `max_ratio` too (two closely spaced pairs:
/// Chapter 4 assumes one).
///
/// # Panics
/// If the three slices differ in length.
pub fn pair_and_remainder(
    f_hz: &[f64],
    residue: &[f64],
    strength: &[f64],
    threshold: f64,
    max_ratio: f64,
) -> PairLabels {
    assert!(f_hz.len() == residue.len() && f_hz.len() == strength.len());
    let n = f_hz.len();
    let w = |i: usize| 2.0 * PI * f_hz[i];
    let visibility = strength;
    let shows: Vec<usize> = (0..n).filter(|&i| visibility[i] >= threshold).collect();
    // Adjacent showing modes by ratio, closest first.
    let mut pairs: Vec<(f64, usize, usize)> = shows
        .windows(2)
        .map(|p| (f_hz[p[1]] / f_hz[p[0]], p[0], p[1]))
        .collect();
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let pair = pairs
        .first()
        .filter(|p| p.0 <= max_ratio)
        .map(|p| (p.1, p.2));
    let w2 = pair.map_or(0.0, |(u, v)| (0.5 * (w(u) + w(v))).powi(2));
    let remainder = shows
        .iter()
        .copied()
        .filter(|&i| pair.is_none_or(|(u, v)| i != u && i != v))
        .max_by(|&x, &y| {
            let c = |i: usize| (residue[i] / (w(i).powi(2) - w2)).abs();
            c(x).total_cmp(&c(y))
        });
    let mut unsure = None;
    if let Some((u, v)) = pair {
        let ratio = f_hz[v] / f_hz[u];
        let name = |i: usize| format!("mode {} ({:.2} Hz)", i + 1, f_hz[i]);
        if let Some(h) = (0..n).find(|&h| {
            visibility[h] < threshold
                && [u, v]
                    .iter()
                    .any(|&m| (f_hz[h] / f_hz[m]).max(f_hz[m] / f_hz[h]) < ratio)
        }) {
            unsure = Some(format!(
                "{} does not show in the path (strength {:.1e}, threshold {threshold}) but lies closer to the pair than its own ratio {ratio:.4}: the pair could be another",
                name(h),
                visibility[h]
            ));
        } else if let Some(&m) = [Some(u), Some(v), remainder]
            .iter()
            .flatten()
            .find(|&&m| visibility[m] < 3.0 * threshold)
        {
            unsure = Some(format!(
                "{} barely shows in the path (strength {:.2}, threshold {threshold}): its label is not sure",
                name(m),
                visibility[m]
            ));
        } else if let Some(next) = pairs.get(1).filter(|p| p.0 <= max_ratio) {
            unsure = Some(format!(
                "{} and {} are a closely spaced pair too (ratio {:.4} against {ratio:.4}): Chapter 4 assumes one pair (A4-4), which one it means is not sure",
                name(next.1),
                name(next.2),
                next.0
            ));
        }
    }
    PairLabels {
        pair,
        remainder,
        strength: visibility.to_vec(),
        unsure,
    }
}

/// A zero of a transfer function with its type (thesis 3.2.1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct TypedZero {
    /// Real part, rad/s.
    pub re_rad_s: f64,
    /// Imaginary part, rad/s.
    pub im_rad_s: f64,
    /// `|s| / 2π`, Hz.
    pub frequency_hz: f64,
    /// MMP, RMP-RNMP or CMP-CNMP.
    #[serde(
        serialize_with = "serialize_zero_type",
        deserialize_with = "deserialize_zero_type"
    )]
    #[schemars(with = "String")]
    pub kind: ZeroType,
}

fn serialize_zero_type<S: serde::Serializer>(k: &ZeroType, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(k.as_str())
}

/// A zero type by its name ([`ZeroType::as_str`]).
fn deserialize_zero_type<'de, D: serde::Deserializer<'de>>(d: D) -> Result<ZeroType, D::Error> {
    let name = String::deserialize(d)?;
    [ZeroType::Mmp, ZeroType::RmpRnmp, ZeroType::CmpCnmp]
        .into_iter()
        .find(|k| k.as_str() == name)
        .ok_or_else(|| serde::de::Error::custom(format!("{name:?} is not a zero type")))
}

impl TypedZero {
    fn new(s: Complex<f64>, kind: ZeroType) -> Self {
        Self {
            re_rad_s: s.re,
            im_rad_s: s.im,
            frequency_hz: s.norm() / (2.0 * PI),
            kind,
        }
    }

    /// The zero as a complex number, rad/s.
    pub fn s(&self) -> Complex<f64> {
        Complex::new(self.re_rad_s, self.im_rad_s)
    }

    /// In the right half plane (non-minimum phase).
    pub fn nmp(&self) -> bool {
        self.re_rad_s > 0.0
    }
}

/// The zeros in `s` of the undamped transfer function (Eq. 2-7 / 3-2), two
/// per root `u` of its numerator in `u = s²`: `s = ±√u`, typed by
/// [`ZeroType::of_u`]. Ascending in `|s|`, the upper-half-plane (or
/// positive real) one of each pair first.
pub fn undamped_zeros(model: &Sr4dof) -> Vec<TypedZero> {
    let mut out = Vec::new();
    for z in model.undamped_zeros() {
        let r = z.u.sqrt();
        // Principal square root: re ≥ 0. Put the upper-half-plane root first.
        let first = if r.im < 0.0 { -r } else { r };
        for s in [first, -first] {
            out.push(TypedZero::new(snap_axis(s, z.kind), z.kind));
        }
    }
    out
}

/// For an undamped MMP pair the zeros are on the imaginary axis, for an
/// RMP-RNMP pair on the real axis: drop the rounding residue of the other
/// part so that the printed zero sits where the theory puts it.
fn snap_axis(s: Complex<f64>, kind: ZeroType) -> Complex<f64> {
    match kind {
        ZeroType::Mmp => Complex::new(0.0, s.im),
        ZeroType::RmpRnmp => Complex::new(s.re, 0.0),
        ZeroType::CmpCnmp => s,
    }
}

/// Relative distance within which a left-half-plane zero counts as the
/// mirror image `−s̄` of a right-half-plane one (the partner of an RNMP or
/// CNMP zero). Light damping (ζ ≲ 0.05) moves the partners apart by about
/// `2ζ|s|`; MMP zeros have no right-half-plane partner at all.
pub const MIRROR_TOLERANCE: f64 = 0.1;

/// The zeros of the damped transfer function (`Sr4dof::zeros`), typed:
/// a right-half-plane zero is RNMP (real) or CNMP (complex); a
/// left-half-plane zero within [`MIRROR_TOLERANCE`]·|s| of the mirror
/// image `−s̄` of a right-half-plane zero takes that zero's type (its RMP /
/// CMP partner); any other left-half-plane zero is MMP (an undamped
/// imaginary-axis pair moved slightly left by damping).
pub fn damped_zeros(model: &Sr4dof) -> Vec<TypedZero> {
    type_damped_zeros(model.zeros())
}

/// The type of a right-half-plane zero `s` (rad/s) of a damped transfer
/// function: CMP-CNMP if complex (`|Im s| > √REAL_TOLERANCE·|s|`, looser
/// than for `u = s²` since `s = √u` halves the digits), else RMP-RNMP.
pub fn nmp_kind(s: Complex<f64>) -> ZeroType {
    if s.im.abs() > ZeroType::REAL_TOLERANCE.sqrt() * s.norm() {
        ZeroType::CmpCnmp
    } else {
        ZeroType::RmpRnmp
    }
}

/// `has_cmp_cnmp(&undamped_zeros(model))` without building the list (the
/// map's inner loop).
pub fn model_cnmp_undamped(model: &Sr4dof) -> bool {
    model
        .undamped_zeros()
        .iter()
        .any(|z| z.kind == ZeroType::CmpCnmp)
}

/// `has_cmp_cnmp(&damped_zeros(model))` without building the list: a
/// left-half-plane zero is typed CMP-CNMP only as the mirror partner of a
/// right-half-plane one ([`type_damped_zeros`]), so this is "some
/// right-half-plane zero is complex".
pub fn model_cnmp_damped(model: &Sr4dof) -> bool {
    model
        .zeros()
        .iter()
        .any(|&s| s.re > 0.0 && nmp_kind(s) == ZeroType::CmpCnmp)
}

/// [`damped_zeros`] for any list of zeros (rad/s) of a real, lightly
/// damped transfer function.
pub fn type_damped_zeros(zeros: &[Complex<f64>]) -> Vec<TypedZero> {
    zeros
        .iter()
        .map(|&s| {
            if s.re > 0.0 {
                return TypedZero::new(s, nmp_kind(s));
            }
            let partner = zeros
                .iter()
                .filter(|w| w.re > 0.0)
                .find(|w| (-w.conj() - s).norm() <= MIRROR_TOLERANCE * s.norm());
            match partner {
                Some(&w) => TypedZero::new(s, nmp_kind(w)),
                None => TypedZero::new(s, ZeroType::Mmp),
            }
        })
        .collect()
}

/// `true` if any zero is CMP-CNMP.
pub fn has_cmp_cnmp(zeros: &[TypedZero]) -> bool {
    zeros.iter().any(|z| z.kind == ZeroType::CmpCnmp)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::BenchConfig;

    fn ch5(op_fraction: f64, dm: f64) -> Sr4dof {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
        let cfg = BenchConfig::load(&path).unwrap();
        let mut p = cfg.plant;
        p.operating_point_m = op_fraction * p.beam.length_m;
        p.mass_asymmetry = dm;
        Sr4dof::new(p).unwrap()
    }

    #[test]
    fn residues_of_eq_4_15_equal_the_models_mass_normalised_residues() {
        // Two derivations: unit shape over modal mass here, mass-normalised
        // shape in the model. They must agree.
        let model = ch5(0.05, 0.04);
        for (t, m) in modal_terms(&model).iter().zip(model.modes()) {
            assert!(
                (t.residue_per_kg - m.residue).abs() <= 1e-9 * m.residue.abs().max(1e-12),
                "mode {}: {} vs {}",
                t.mode,
                t.residue_per_kg,
                m.residue
            );
        }
    }

    #[test]
    fn the_y_mode_is_unobservable_and_the_hidden_pair_mode_appears_with_asymmetry() {
        // Thesis 4.4.2: one mode (Y of stages ①②③) is unobservable in x1
        // at any operating point; 2.2.2: with Δm23 = 0 one mode of the pair
        // is hidden, with Δm23 ≠ 0 both appear.
        let sym = modal_terms(&ch5(0.03, 0.0));
        assert_eq!(sym.iter().filter(|t| !t.in_path).count(), 2, "{sym:#?}");
        let asym = modal_terms(&ch5(0.03, 0.05));
        assert_eq!(asym.iter().filter(|t| !t.in_path).count(), 1, "{asym:#?}");
        let hidden = asym.iter().find(|t| !t.in_path).unwrap();
        assert!(!hidden.observable, "{hidden:?}");
        // The hidden one is the Y mode, the lowest on the Chapter 5 bench.
        assert_eq!(hidden.mode, 1, "{hidden:?}");
        let labels: Vec<&str> = asym.iter().map(|t| t.label.as_str()).collect();
        assert_eq!(labels.iter().filter(|l| **l == "u").count(), 1);
        assert_eq!(labels.iter().filter(|l| **l == "v").count(), 1);
        let r = asym.iter().find(|t| t.label == "R").unwrap();
        // R is the X rigid-body mode: x1 dominates its shape.
        assert!(r.shape[0].abs() > 0.9, "{r:?}");
    }

    #[test]
    fn damped_typing_keeps_quartets_and_pairs_together() {
        // A CMP-CNMP quartet moved by damping, an RMP-RNMP pair and an MMP
        // pair: every zero gets its analytic type.
        let zs = [
            Complex::new(3.0, 900.0),
            Complex::new(3.0, -900.0),
            Complex::new(-5.0, 901.0),
            Complex::new(-5.0, -901.0),
            Complex::new(400.0, 0.0),
            Complex::new(-402.0, 0.0),
            Complex::new(-0.5, 120.0),
            Complex::new(-0.5, -120.0),
        ];
        let kinds: Vec<ZeroType> = type_damped_zeros(&zs).iter().map(|z| z.kind).collect();
        use ZeroType::*;
        assert_eq!(
            kinds,
            [CmpCnmp, CmpCnmp, CmpCnmp, CmpCnmp, RmpRnmp, RmpRnmp, Mmp, Mmp]
        );
    }
}
