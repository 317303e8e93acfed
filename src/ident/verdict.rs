//! The measured CMP-CNMP verdict: two tests on one FRF and how they
//! combine.
//!
//! 1. **Phase test** (thesis §2.2.2, Fig 5-9b): the net unwrapped phase of
//!    the measured FRF across the band of the closely spaced pair, the pair
//!    taken from the modal fit ([`super::modal_fit`]) so that a mode that
//!    barely rises above its flanks still counts. Each lightly damped pole
//!    pair in the band contributes −180°, each minimum-phase zero pair
//!    +180°, a CMP-CNMP quartet 0°: two poles with a net of −360° mean
//!    CMP-CNMP zeros. The phase of the path outside the mechanics (hold,
//!    amplifier, fitted delay) across the band is taken off first.
//! 2. **Residue test** (thesis 3.2.1, Table 3-3): the zeros of the fitted
//!    modal model, from the fitted frequencies, damping ratios and signed
//!    modal constants. Its confidence is the fraction of [`DRAWS`] draws of
//!    the parameters from their fitted 1σ (independent normals) that give
//!    the same answer; it decides at [`MIN_CONFIDENCE`] or more, and only
//!    when the fit has a mode and explains the measurement (RMS relative
//!    error at most [`MAX_FIT_ERROR`]).
//!
//! The verdict is the tests' common answer when both decide; the one that
//! decides when the other cannot (with the other's reason); and `null`
//! with a reason when neither decides or they disagree, so a verdict is
//! never a guess.

use super::frf::{Frf, PairVerdict, CLOSE_PAIR_RATIO, MIN_COHERENCE};
use super::modal_fit::{damped_numerator_roots, ModalFit, MAX_FIT_ERROR};
use serde::{Deserialize, Serialize};

/// Draws of the fitted parameters for the residue test's confidence.
pub const DRAWS: usize = 400;
/// Smallest fraction of the draws that must agree for the residue test to
/// decide (95 %).
pub const MIN_CONFIDENCE: f64 = 0.95;
/// Largest distance of the net phase from its multiple of 180° for the
/// phase test to decide, degrees.
pub const MAX_PHASE_OFFSET_DEG: f64 = 45.0;
/// Largest phase change between adjacent grid points in the band, degrees:
/// beyond it the grid is too coarse for the unwrapping to be trusted.
pub const MAX_PHASE_STEP_DEG: f64 = 120.0;

/// The residue test.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ResidueTest {
    /// The fitted model's answer (`null` when it cannot decide).
    pub cmp_cnmp: Option<bool>,
    /// Fraction of the parameter draws that agree with the fitted
    /// parameters' answer, 0 … 1.
    pub confidence: f64,
    /// Sign sequence of the fitted modes in the path.
    pub sign_sequence: String,
    /// Sequence of dominant modes of the fit.
    pub dominant_sequence: String,
    /// Why it does not decide.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// The phase test.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct PhaseTest {
    /// The answer (`null` when it cannot decide).
    pub cmp_cnmp: Option<bool>,
    /// The pair, band and net phase (mechanical: the path's phase across
    /// the band taken off), when a pair was fitted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pair: Option<PairVerdict>,
    /// Why it does not decide.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// The combined verdict.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Verdict {
    /// CMP-CNMP zeros between the closely spaced pair: `true`, `false`, or
    /// `null` when the data cannot decide (see `reason`).
    pub cmp_cnmp: Option<bool>,
    /// Why the verdict is `null`, or what one test could not decide.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// The phase test.
    pub phase_test: PhaseTest,
    /// The residue test.
    pub residue_test: ResidueTest,
}

/// The fitted pair `(u, v)` (indices into `fit.modes`): the in-path modes
/// labelled `u` and `v`.
fn pair(fit: &ModalFit) -> Option<(usize, usize)> {
    let u = fit.modes.iter().position(|m| m.label == "u")?;
    let v = fit.modes.iter().position(|m| m.label == "v")?;
    Some((u, v))
}

/// The phase test on `frf` with the pair of `fit`; `path_phase_deg(f)` is
/// the phase of the path outside the mechanics at `f` (degrees).
pub fn phase_test(frf: &Frf, fit: &ModalFit, path_phase_deg: impl Fn(f64) -> f64) -> PhaseTest {
    let undecided = |pair, reason: String| PhaseTest {
        cmp_cnmp: None,
        pair,
        reason: Some(reason),
    };
    let Some((u, v)) = pair(fit) else {
        return undecided(None, no_pair_reason(fit));
    };
    let fa = fit.modes[u].frequency_hz;
    let fb = fit.modes[v].frequency_hz;
    let grid = &frf.frequency_hz;
    let (Some(&first), Some(&last)) = (grid.first(), grid.last()) else {
        return undecided(None, "the FRF is empty".into());
    };
    // The band comes from the fit's pair: a flagged fit's pair (split or
    // unrefined modes) is not the plant's, nor are labels it is unsure of.
    if fit.quality.checked && !fit.quality.flags.is_empty() {
        return undecided(
            None,
            format!(
                "the pair's band comes from a flagged fit: {}",
                fit.quality.flags.join("; ")
            ),
        );
    }
    if let Some(why) = &fit.labels_unsure {
        return undecided(None, format!("the fit's pair labels are unsure: {why}"));
    }
    let below = fit.modes[..u].last().map_or(first, |m| m.frequency_hz);
    let above = fit.modes.get(v + 1).map_or(last, |m| m.frequency_hz);
    let band = ((below * fa).sqrt(), (fb * above).sqrt());
    let lo = grid.partition_point(|f| *f < band.0).min(grid.len() - 1);
    let hi = grid.partition_point(|f| *f < band.1).min(grid.len() - 1);
    let path = path_phase_deg(grid[hi]) - path_phase_deg(grid[lo]);
    let net = frf.phase_deg[hi] - frf.phase_deg[lo] - path;
    let multiple = (net / 180.0).round() * 180.0;
    let verdict = PairVerdict {
        lower_hz: fa,
        upper_hz: fb,
        band_hz: (grid[lo], grid[hi]),
        net_phase_deg: net,
        net_phase_multiple_deg: multiple,
        cmp_cnmp: multiple <= -360.0,
    };
    if let Some(k) = (lo..=hi).find(|&k| frf.coherence[k] < MIN_COHERENCE) {
        return undecided(
            Some(verdict),
            format!(
                "coherence {:.2} at {:.2} Hz in the pair's band {:.1}-{:.1} Hz is below {MIN_COHERENCE}",
                frf.coherence[k], grid[k], grid[lo], grid[hi]
            ),
        );
    }
    if let Some(k) =
        (lo..hi).find(|&k| (frf.phase_deg[k + 1] - frf.phase_deg[k]).abs() > MAX_PHASE_STEP_DEG)
    {
        return undecided(
            Some(verdict),
            format!(
                "the phase changes by {:.0}° between {:.2} and {:.2} Hz: the grid is too coarse to unwrap it",
                frf.phase_deg[k + 1] - frf.phase_deg[k],
                grid[k],
                grid[k + 1]
            ),
        );
    }
    if (net - multiple).abs() > MAX_PHASE_OFFSET_DEG {
        return undecided(
            Some(verdict),
            format!("the net phase across the pair, {net:.0}°, is not near a multiple of 180°"),
        );
    }
    PhaseTest {
        cmp_cnmp: Some(verdict.cmp_cnmp),
        pair: Some(verdict),
        reason: None,
    }
}

fn no_pair_reason(fit: &ModalFit) -> String {
    let path: Vec<f64> = fit
        .modes
        .iter()
        .filter(|m| m.in_path)
        .map(|m| m.frequency_hz)
        .collect();
    match path.len() {
        0 => "the fit found no mode".into(),
        1 => format!("the fit found one mode ({:.2} Hz)", path[0]),
        _ => {
            let (a, b) = path
                .windows(2)
                .map(|w| (w[0], w[1]))
                .min_by(|x, y| (x.1 / x.0).total_cmp(&(y.1 / y.0)))
                .expect("two modes");
            format!(
                "the closest fitted modes, {a:.2} Hz and {b:.2} Hz, are {:.0} % apart (a pair is within {:.0} %)",
                (b / a - 1.0) * 100.0,
                (CLOSE_PAIR_RATIO - 1.0) * 100.0
            )
        }
    }
}

/// CMP-CNMP zeros in the modal sum of the in-path modes with these
/// parameters.
fn cnmp_of(f_hz: &[f64], zeta: &[f64], a: &[f64]) -> bool {
    use crate::analysis::modal::{has_cmp_cnmp, type_damped_zeros};
    has_cmp_cnmp(&type_damped_zeros(&damped_numerator_roots(f_hz, zeta, a)))
}

/// The residue test of `fit` (see the module docs).
pub fn residue_test(fit: &ModalFit) -> ResidueTest {
    let modes: Vec<_> = fit.modes.iter().filter(|m| m.in_path).collect();
    let f: Vec<f64> = modes.iter().map(|m| m.frequency_hz).collect();
    let z: Vec<f64> = modes.iter().map(|m| m.damping_ratio).collect();
    let a: Vec<f64> = modes.iter().map(|m| m.modal_constant).collect();
    let nominal = fit.cmp_cnmp;
    // SplitMix64 + Box-Muller, fixed seed: the same fit gives the same
    // confidence.
    use crate::splitmix::{splitmix64, GAMMA};
    let mut state: u64 = GAMMA;
    let mut uniform = || {
        let x = splitmix64(state);
        state = state.wrapping_add(GAMMA);
        ((x >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let mut normal = || {
        let (u1, u2) = (uniform(), uniform());
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    };
    let mut agree = 0usize;
    let (mut fs, mut zs, mut as_) = (f.clone(), z.clone(), a.clone());
    for _ in 0..DRAWS {
        for (i, m) in modes.iter().enumerate() {
            fs[i] = m.frequency_hz + normal() * m.frequency_sigma_hz;
            zs[i] = (m.damping_ratio + normal() * m.damping_ratio_sigma).max(0.0);
            as_[i] = m.modal_constant + normal() * m.modal_constant_sigma;
        }
        if cnmp_of(&fs, &zs, &as_) == nominal {
            agree += 1;
        }
    }
    let confidence = agree as f64 / DRAWS as f64;
    let uncertain = modes.iter().any(|m| {
        !(m.frequency_sigma_hz.is_finite()
            && m.damping_ratio_sigma.is_finite()
            && m.modal_constant_sigma.is_finite())
    });
    let misfit = if modes.is_empty() {
        Some("the fit found no mode".to_string())
    } else if modes.len() >= 2 && fit.zeros.is_empty() {
        Some("the zeros of the fitted model could not be computed".to_string())
    } else if uncertain {
        Some("the fit's uncertainties could not be computed (singular Jacobian)".to_string())
    } else if fit.quality.checked && !fit.quality.flags.is_empty() {
        Some(format!(
            "the fit is flagged: {}",
            fit.quality.flags.join("; ")
        ))
    } else if fit.rms_relative_error > MAX_FIT_ERROR {
        Some(format!(
            "the fit leaves an RMS relative error of {:.1} % (at most {:.0} % for a fit that explains the measurement)",
            100.0 * fit.rms_relative_error,
            100.0 * MAX_FIT_ERROR
        ))
    } else {
        None
    };
    if let Some(reason) = misfit {
        return ResidueTest {
            cmp_cnmp: None,
            confidence,
            sign_sequence: fit.sign_sequence.clone(),
            dominant_sequence: fit.dominant_sequence.clone(),
            reason: Some(reason),
        };
    }
    let decided = confidence >= MIN_CONFIDENCE;
    ResidueTest {
        cmp_cnmp: decided.then_some(nominal),
        confidence,
        sign_sequence: fit.sign_sequence.clone(),
        dominant_sequence: fit.dominant_sequence.clone(),
        reason: (!decided).then(|| {
            format!(
                "within the fit's 1σ uncertainties the zeros are CMP-CNMP in {:.0} % of parameter draws (a verdict needs {:.0} % either way)",
                100.0 * if nominal { confidence } else { 1.0 - confidence },
                100.0 * MIN_CONFIDENCE
            )
        }),
    }
}

/// Combines the two tests (see the module docs).
pub fn combine(phase_test: PhaseTest, residue_test: ResidueTest) -> Verdict {
    let yes_no = |b: bool| if b { "CMP-CNMP" } else { "no CMP-CNMP" };
    let (cmp_cnmp, reason) = match (phase_test.cmp_cnmp, residue_test.cmp_cnmp) {
        (Some(p), Some(r)) if p == r => (Some(p), None),
        (Some(p), Some(r)) => (
            None,
            Some(format!(
                "the tests disagree: the net phase across the pair says {}, the fitted residues ({}, {}) say {}",
                yes_no(p),
                residue_test.sign_sequence,
                residue_test.dominant_sequence,
                yes_no(r)
            )),
        ),
        (None, Some(r)) => (
            Some(r),
            Some(format!(
                "from the fitted residues; phase test undecided: {}",
                phase_test.reason.clone().unwrap_or_default()
            )),
        ),
        (Some(p), None) => (
            Some(p),
            Some(format!(
                "from the net phase; residue test undecided: {}",
                residue_test.reason.clone().unwrap_or_default()
            )),
        ),
        (None, None) => (
            None,
            Some(format!(
                "phase test: {}; residue test: {}",
                phase_test.reason.clone().unwrap_or_default(),
                residue_test.reason.clone().unwrap_or_default()
            )),
        ),
    };
    Verdict {
        cmp_cnmp,
        reason,
        phase_test,
        residue_test,
    }
}

/// Both tests and their combination for `frf` and its `fit`.
pub fn verdict(frf: &Frf, fit: &ModalFit, path_phase_deg: impl Fn(f64) -> f64) -> Verdict {
    combine(phase_test(frf, fit, path_phase_deg), residue_test(fit))
}

/// The verdict when no fit could be made.
pub fn without_fit(reason: &str) -> Verdict {
    let r = format!("no modal fit: {reason}");
    Verdict {
        cmp_cnmp: None,
        reason: Some(r.clone()),
        phase_test: PhaseTest {
            cmp_cnmp: None,
            pair: None,
            reason: Some(r.clone()),
        },
        residue_test: ResidueTest {
            cmp_cnmp: None,
            confidence: 0.0,
            sign_sequence: String::new(),
            dominant_sequence: String::new(),
            reason: Some(r),
        },
    }
}
