//! The modes a design is built around, from `bench fit`'s modal fit of
//! every input ([`crate::ident::modal_fit`]): the first resonance ω_R (the
//! lowest mode in the actuator-to-probe path), the closely spaced pair u,
//! v and the sign sequence of their modal constants (thesis §3.2, §6.1.2).

use super::{derr, DesignError, InputFrf};
use crate::ident::modal_fit::{self, FrfData, Path};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// The modes of one input.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct InputModes {
    /// The input.
    pub input: String,
    /// Lowest in-path mode, Hz (with its 1σ).
    pub first_resonance_hz: f64,
    /// 1σ of it, Hz (`null`: not determined).
    pub first_resonance_sigma_hz: Option<f64>,
    /// Mode u of the closely spaced pair, Hz.
    pub u_hz: Option<f64>,
    /// Mode v, Hz.
    pub v_hz: Option<f64>,
    /// The fit's sign sequence, e.g. `α_R > 0, α_u < 0, α_v > 0`.
    pub sign_sequence: String,
    /// `alternating` (α_u opposite α_R, α_v with it: §6.1.2.1),
    /// `non-alternating` (§6.1.2.2), `in phase` (u and v of one sign) or
    /// `no pair`.
    pub pair_signs: String,
    /// The fit's RMS relative error.
    pub fit_error: f64,
}

/// The modes over all inputs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct PlantModes {
    /// ω_R: the median over the inputs of their first resonance, rad/s.
    pub first_resonance_rad_s: f64,
    /// Per input.
    pub inputs: Vec<InputModes>,
}

impl PlantModes {
    /// Fits every input with the path model `path`.
    ///
    /// # Errors
    /// Naming the input whose fit fails or finds no mode.
    pub fn identify(inputs: &[InputFrf], path: Path) -> Result<Self, DesignError> {
        Self::identify_with_fits(inputs, path).map(|(m, _)| m)
    }

    /// [`Self::identify`], and every input's modal fit (in input order):
    /// the bench's own model, which the design predicts and certifies on.
    ///
    /// # Errors
    /// Naming the input whose fit fails or finds no mode.
    pub fn identify_with_fits(
        inputs: &[InputFrf],
        path: Path,
    ) -> Result<(Self, Vec<modal_fit::ModalFit>), DesignError> {
        use rayon::prelude::*;
        let both: Vec<(InputModes, modal_fit::ModalFit)> = inputs
            .par_iter()
            .map(|inp| -> Result<(InputModes, modal_fit::ModalFit), DesignError> {
            let fit = modal_fit::fit(&FrfData::from_frf(&inp.frf), &path)
                .map_err(|e| derr(&inp.label, format!("modal fit: {e}")))?;
            let in_path: Vec<_> = fit.modes.iter().filter(|m| m.in_path).collect();
            let Some(first) = in_path.first() else {
                return Err(derr(&inp.label, "the modal fit finds no mode in the actuator-to-probe path: the FRF shows no resonance to design around"));
            };
            let find = |l: &str| fit.modes.iter().find(|m| m.label == l);
            let (u, v, r) = (find("u"), find("v"), find("R"));
            let pair_signs = match (u, v) {
                (Some(u), Some(v)) if u.sign == v.sign => "in phase",
                (Some(u), Some(v)) => {
                    let r_sign = r.map_or(first.sign, |r| r.sign);
                    if u.sign != r_sign && v.sign == r_sign {
                        "alternating"
                    } else {
                        "non-alternating"
                    }
                }
                _ => "no pair",
            };
            Ok((InputModes {
                input: inp.label.clone(),
                first_resonance_hz: first.frequency_hz,
                first_resonance_sigma_hz: first
                    .frequency_sigma_hz
                    .is_finite()
                    .then_some(first.frequency_sigma_hz),
                u_hz: u.map(|m| m.frequency_hz),
                v_hz: v.map(|m| m.frequency_hz),
                sign_sequence: fit.sign_sequence.clone(),
                pair_signs: pair_signs.into(),
                fit_error: fit.rms_relative_error,
            }, fit))
            })
            .collect::<Result<_, _>>()?;
        let (out, fits): (Vec<InputModes>, Vec<modal_fit::ModalFit>) = both.into_iter().unzip();
        let mut f: Vec<f64> = out.iter().map(|m| m.first_resonance_hz).collect();
        f.sort_by(f64::total_cmp);
        Ok((
            Self {
                first_resonance_rad_s: 2.0 * PI * f[f.len() / 2],
                inputs: out,
            },
            fits,
        ))
    }

    /// The modes of input `k` alone (its first resonance as ω_R); `None`
    /// for an index past the inputs.
    pub fn of_input(&self, k: usize) -> Option<Self> {
        self.inputs.get(k).map(|m| Self {
            first_resonance_rad_s: 2.0 * PI * m.first_resonance_hz,
            inputs: vec![m.clone()],
        })
    }

    /// Every resonance found on any input (ω_R, u, v), rad/s.
    pub fn resonances_rad_s(&self) -> Vec<f64> {
        self.inputs
            .iter()
            .flat_map(|m| [Some(m.first_resonance_hz), m.u_hz, m.v_hz])
            .flatten()
            .map(|f| 2.0 * PI * f)
            .collect()
    }

    /// Where the fast family's notch goes, `(ω_u, ω_v)` in rad/s (the
    /// interval its centre must lie in on every input), or `None` with the
    /// thesis' reason; and the structure in words.
    pub fn notch_plan(&self) -> (Option<(f64, f64)>, String) {
        let hz = |w: f64| w / (2.0 * PI);
        let conventional = "conventional lead + 2nd-order low-pass (ζ 0.7) with the phase-boosting pair, no notch (thesis §6.1.2.2: \"apply a conventional controller\")";
        if let Some(m) = self
            .inputs
            .iter()
            .find(|m| m.pair_signs == "non-alternating")
        {
            return (None, format!(
                "non-alternating signs on {} ({}): after any notch the pair's two resonance circles turn the same way, and phase-stabilising both needs an added mode damped no more than the pair (ζ ≈ 0.004), which can neither be built nor predicted (thesis §6.1.2.2); the sign sequence, not the CMP-CNMP zeros, decides this: {conventional}",
                m.input, m.sign_sequence
            ));
        }
        if let Some(m) = self.inputs.iter().find(|m| m.pair_signs == "in phase") {
            return (
                None,
                format!(
                    "the pair's modes are in phase on {} ({}): no out-of-phase pair to place a notch between: {conventional}",
                    m.input, m.sign_sequence
                ),
            );
        }
        // Inputs where the pair does not show (at Y1o = 0 it leaves the
        // actuator-to-probe path) do not constrain the notch.
        let with_pair: Vec<&InputModes> = self
            .inputs
            .iter()
            .filter(|m| m.pair_signs == "alternating")
            .collect();
        if with_pair.is_empty() {
            return (
                None,
                format!("no closely spaced pair in any input: {conventional}"),
            );
        }
        let without = self.inputs.len() - with_pair.len();
        let u = with_pair.iter().filter_map(|m| m.u_hz).fold(0.0, f64::max);
        let v = with_pair
            .iter()
            .filter_map(|m| m.v_hz)
            .fold(f64::INFINITY, f64::min);
        if u >= v {
            return (None, format!("the pair moves over the inputs (u up to {u:.2} Hz, v down to {v:.2} Hz): no notch centre lies between u and v on all of them: {conventional}"));
        }
        let w = (2.0 * PI * u, 2.0 * PI * v);
        (Some(w), format!(
            "alternating signs ({}) on all {} inputs that show the pair{}: notch centred between u and v, in ({:.2}, {:.2}) Hz, so that u and v lie on opposite sides (thesis §6.1.2.1), lead for phase at crossover, low-pass roll-off (the Eq. 6-7 family)",
            with_pair[0].sign_sequence,
            with_pair.len(),
            if without > 0 {
                format!(" ({without} without it, where the notch changes nothing)")
            } else {
                String::new()
            },
            hz(w.0),
            hz(w.1)
        ))
    }
}
