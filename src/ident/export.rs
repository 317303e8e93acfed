//! The fitted modal model as a linear time-invariant system a control
//! toolbox loads: transfer function, zeros/poles/gain or state space
//! (`bench fit … --export-model tf|zpk|ss`), written as JSON, a MATLAB
//! script or a Python (python-control) script.
//!
//! The system is the continuous-time response from the demanded coil
//! current (A) to the probe position `x1` (m) that the modal fit
//! ([`super::modal_fit`]) identified:
//!
//! ```text
//! G(s) = M(s) · ω_a / (s + ω_a),   delay τ
//! M(s) = Σᵢ Aᵢ / (s² + 2ζᵢωᵢ s + ωᵢ²) + L / s² + U      (m/A)
//! ```
//!
//! with `ωᵢ = 2π fᵢ` (rad/s), the modal constants `Aᵢ` (m/(A·s²)), the
//! lower and upper residual terms `L` (m/(A·s²)) and `U` (m/A), the
//! amplifier's −3 dB bandwidth `ω_a` = 2π `amplifier_bandwidth_hz` (the
//! fit's path model: a first-order lag) and the fitted delay `τ` (s), which
//! holds the loop's computation delay and the zero-order hold's half
//! period. The hold's magnitude `sinc(ωT/2)` is not a rational function
//! and is left out (−0.05 dB at 300 Hz at 5 kHz): `G(jω) e^{−jωτ}
//! sinc(ωT/2)` is what the fit compares with the FRF. For a discrete
//! model, `c2d(G, T, 'zoh')` adds the hold back, half a period of delay
//! included: use `τ − T/2` as its input delay.
//!
//! The forms (SI units, frequencies in rad/s, polynomials highest power
//! first as MATLAB's `tf` and python-control's `tf` take them):
//! - `tf`: `num`, `den` over the common denominator
//!   `s²·Πᵢ(s² + 2ζᵢωᵢ s + ωᵢ²)·(s + ω_a)` (the `s²` only when `L ≠ 0`).
//!   Its coefficients span many decades (ωᵢ⁸ ≈ 1e22 for three modes near
//!   85 Hz): prefer `zpk` or `ss` for anything but a look.
//! - `zpk`: the roots of `num` and `den` and the gain (the ratio of their
//!   leading coefficients); zeros from the eigenvalues of the numerator's
//!   companion matrix.
//! - `ss`: modal (block-diagonal) form, states `[qᵢ, q̇ᵢ]…, [r, ṙ], i_c`:
//!   each mode `q̈ᵢ = −ωᵢ² qᵢ − 2ζᵢωᵢ q̇ᵢ + i_c`, the lower residual
//!   `r̈ = i_c`, the coil current `i̇_c = ω_a (u − i_c)`;
//!   `y = Σ Aᵢ qᵢ + L r + U i_c`, `D = 0`.

use super::modal_fit::{ModalFit, Path};
use super::C64;
use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Which form of the model to export (`--export-model`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelForm {
    /// Transfer function: numerator and denominator polynomials.
    Tf,
    /// Zeros, poles and gain.
    Zpk,
    /// State space (modal form).
    Ss,
}

/// The file format of an exported model (`--model-format`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelFormat {
    /// JSON ([`ExportedModel`]).
    #[default]
    Json,
    /// A MATLAB script that defines `G` (Control System Toolbox `tf`,
    /// `zpk` or `ss`, with `'InputDelay'`).
    Matlab,
    /// A Python script that defines `G` with python-control (≥ 0.10) and
    /// `delay_s`.
    Python,
}

impl ModelFormat {
    /// The file extension of the format.
    pub fn extension(self) -> &'static str {
        match self {
            ModelFormat::Json => "json",
            ModelFormat::Matlab => "m",
            ModelFormat::Python => "py",
        }
    }
}

/// A transfer function `num(s)/den(s)`, highest power first.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransferFunction {
    /// Numerator coefficients, m/A · (rad/s)^k.
    pub num: Vec<f64>,
    /// Denominator coefficients (monic).
    pub den: Vec<f64>,
}

/// Zeros, poles (rad/s, `[re, im]`) and gain.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ZerosPolesGain {
    /// Zeros, rad/s, `[re, im]`.
    pub zeros: Vec<[f64; 2]>,
    /// Poles, rad/s, `[re, im]`.
    pub poles: Vec<[f64; 2]>,
    /// Gain: `G(s) = k Π(s − zᵢ) / Π(s − pᵢ)`.
    pub gain: f64,
}

/// A state-space model `ẋ = A x + B u`, `y = C x + D u` (row-major).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StateSpace {
    /// `n × n`, 1/s and 1/s².
    pub a: Vec<Vec<f64>>,
    /// `n × 1`.
    pub b: Vec<Vec<f64>>,
    /// `1 × n`.
    pub c: Vec<Vec<f64>>,
    /// `1 × 1`, m/A.
    pub d: Vec<Vec<f64>>,
    /// What each state is (`q_R`, `qdot_R`, …, `r`, `rdot`, `i_c`).
    pub states: Vec<String>,
}

/// One fitted mode with its 1σ, as exported.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExportedMode {
    /// The fit's label (`u`, `v`, `R`, `m<N>`).
    pub label: String,
    /// Natural frequency, Hz, and its 1σ (`null`: not determined).
    pub frequency_hz: f64,
    /// 1σ of `frequency_hz`, Hz.
    pub frequency_sigma_hz: Option<f64>,
    /// Damping ratio.
    pub damping_ratio: f64,
    /// 1σ of `damping_ratio`.
    pub damping_ratio_sigma: Option<f64>,
    /// Modal constant, m/(A·s²).
    pub modal_constant: f64,
    /// 1σ of `modal_constant`, m/(A·s²).
    pub modal_constant_sigma: Option<f64>,
}

/// The exported model (the JSON format; the scripts hold the same
/// numbers).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExportedModel {
    /// The form exported.
    pub form: ModelForm,
    /// Input and output: `"coil current demand (A) -> x1 (m)"`.
    pub io: String,
    /// The delay τ to apply at the input, s (the fit's, with its 1σ).
    pub delay_s: f64,
    /// 1σ of `delay_s`, s.
    pub delay_sigma_s: Option<f64>,
    /// The loop's sample period the FRF was measured at, s (its hold's
    /// `sinc(ωT/2)` is not in the model).
    pub hold_period_s: f64,
    /// The amplifier bandwidth in the model, Hz.
    pub amplifier_bandwidth_hz: f64,
    /// The fit's modes.
    pub modes: Vec<ExportedMode>,
    /// Lower residual `L`, m/(A·s²).
    pub lower_residual: f64,
    /// Upper residual `U`, m/A.
    pub upper_residual_m_per_a: f64,
    /// The fit's quality flags: a flagged fit's model is not to be
    /// trusted (empty when it passed its checks).
    pub flags: Vec<String>,
    /// With `form` = `tf`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tf: Option<TransferFunction>,
    /// With `form` = `zpk`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub zpk: Option<ZerosPolesGain>,
    /// With `form` = `ss`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ss: Option<StateSpace>,
}

/// Why a model cannot be exported.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ExportError {
    /// The fit found no mode.
    #[error("the fit found no mode: there is no model to export")]
    NoMode,
    /// A parameter is not finite or out of its physical range.
    #[error("the fit's {0} is not a finite, physical value")]
    NotPhysical(&'static str),
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// `a · b`, polynomials highest power first.
fn mul(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, x) in a.iter().enumerate() {
        for (j, y) in b.iter().enumerate() {
            out[i + j] += x * y;
        }
    }
    out
}

/// `a + b`, aligned at the constant term.
fn add(a: &[f64], b: &[f64]) -> Vec<f64> {
    let n = a.len().max(b.len());
    let mut out = vec![0.0; n];
    for (k, x) in a.iter().rev().enumerate() {
        out[n - 1 - k] += x;
    }
    for (k, x) in b.iter().rev().enumerate() {
        out[n - 1 - k] += x;
    }
    out
}

fn scale(a: &[f64], k: f64) -> Vec<f64> {
    a.iter().map(|x| x * k).collect()
}

/// The roots of `p` (highest power first, leading zeros dropped): the
/// eigenvalues of its companion matrix.
pub fn roots(p: &[f64]) -> Vec<C64> {
    let start = p.iter().position(|c| *c != 0.0).unwrap_or(p.len());
    let p = &p[start..];
    if p.len() < 2 {
        return Vec::new();
    }
    let n = p.len() - 1;
    let mut c = DMatrix::<f64>::zeros(n, n);
    for j in 0..n {
        c[(0, j)] = -p[j + 1] / p[0];
    }
    for i in 1..n {
        c[(i, i - 1)] = 1.0;
    }
    let mut r: Vec<C64> = c.complex_eigenvalues().iter().copied().collect();
    r.sort_by(|a, b| a.im.total_cmp(&b.im).then(a.re.total_cmp(&b.re)));
    r
}

/// The model of `fit` on `path` in `form` (see the module docs).
///
/// # Errors
/// [`ExportError::NoMode`] for a fit without modes;
/// [`ExportError::NotPhysical`] for a non-finite parameter, a natural
/// frequency or damping ratio not positive, or an amplifier bandwidth not
/// positive.
pub fn export(fit: &ModalFit, path: &Path, form: ModelForm) -> Result<ExportedModel, ExportError> {
    if fit.modes.is_empty() {
        return Err(ExportError::NoMode);
    }
    for m in &fit.modes {
        if !(m.frequency_hz.is_finite() && m.frequency_hz > 0.0) {
            return Err(ExportError::NotPhysical("natural frequency"));
        }
        if !(m.damping_ratio.is_finite() && m.damping_ratio > 0.0) {
            return Err(ExportError::NotPhysical("damping ratio"));
        }
        if !m.modal_constant.is_finite() {
            return Err(ExportError::NotPhysical("modal constant"));
        }
    }
    if !fit.lower_residual.is_finite() || !fit.upper_residual_m_per_a.is_finite() {
        return Err(ExportError::NotPhysical("residual term"));
    }
    if !(fit.delay_s.is_finite() && fit.delay_s >= 0.0) {
        return Err(ExportError::NotPhysical("delay"));
    }
    if !(path.amplifier_bandwidth_hz.is_finite() && path.amplifier_bandwidth_hz > 0.0) {
        return Err(ExportError::NotPhysical("amplifier bandwidth"));
    }
    let wa = 2.0 * PI * path.amplifier_bandwidth_hz;
    let modes: Vec<(f64, f64, f64)> = fit
        .modes
        .iter()
        .map(|m| (2.0 * PI * m.frequency_hz, m.damping_ratio, m.modal_constant))
        .collect();
    let l = fit.lower_residual;
    let u = fit.upper_residual_m_per_a;
    let mut out = ExportedModel {
        form,
        io: "coil current demand (A) -> x1 (m)".into(),
        delay_s: fit.delay_s,
        delay_sigma_s: finite(fit.delay_sigma_s),
        hold_period_s: path.period_s,
        amplifier_bandwidth_hz: path.amplifier_bandwidth_hz,
        modes: fit
            .modes
            .iter()
            .map(|m| ExportedMode {
                label: m.label.clone(),
                frequency_hz: m.frequency_hz,
                frequency_sigma_hz: finite(m.frequency_sigma_hz),
                damping_ratio: m.damping_ratio,
                damping_ratio_sigma: finite(m.damping_ratio_sigma),
                modal_constant: m.modal_constant,
                modal_constant_sigma: finite(m.modal_constant_sigma),
            })
            .collect(),
        lower_residual: l,
        upper_residual_m_per_a: u,
        flags: fit.quality.flags.clone(),
        tf: None,
        zpk: None,
        ss: None,
    };
    match form {
        ModelForm::Tf | ModelForm::Zpk => {
            let (num, den) = transfer_function(&modes, l, u, wa);
            if form == ModelForm::Tf {
                out.tf = Some(TransferFunction { num, den });
            } else {
                let pair = |z: C64| [z.re, z.im];
                let lead_num = num.iter().find(|c| **c != 0.0).copied().unwrap_or(0.0);
                // Poles in closed form (the denominator's factors), not
                // from its ill-conditioned coefficients.
                let mut poles = Vec::new();
                for &(w, z, _) in &modes {
                    let wd = w * (1.0 - z * z).max(0.0).sqrt();
                    poles.push(C64::new(-z * w, wd));
                    poles.push(C64::new(-z * w, -wd));
                }
                if l != 0.0 {
                    poles.push(C64::new(0.0, 0.0));
                    poles.push(C64::new(0.0, 0.0));
                }
                poles.push(C64::new(-wa, 0.0));
                out.zpk = Some(ZerosPolesGain {
                    zeros: roots(&num).into_iter().map(pair).collect(),
                    poles: poles.into_iter().map(pair).collect(),
                    gain: lead_num / den[0],
                });
            }
        }
        ModelForm::Ss => out.ss = Some(state_space(fit, &modes, l, u, wa)),
    }
    Ok(out)
}

/// `num`, `den` of `G(s)` over the common denominator (module docs).
fn transfer_function(modes: &[(f64, f64, f64)], l: f64, u: f64, wa: f64) -> (Vec<f64>, Vec<f64>) {
    let factors: Vec<Vec<f64>> = modes
        .iter()
        .map(|&(w, z, _)| vec![1.0, 2.0 * z * w, w * w])
        .collect();
    let product = |skip: Option<usize>| {
        factors
            .iter()
            .enumerate()
            .filter(|(i, _)| Some(*i) != skip)
            .fold(vec![1.0], |acc, (_, f)| mul(&acc, f))
    };
    let s2 = if l != 0.0 {
        vec![1.0, 0.0, 0.0]
    } else {
        vec![1.0]
    };
    let all = product(None);
    // M(s) = N(s) / (s²·Π dᵢ): N = Σ Aᵢ s² Π_{j≠i} dⱼ + L Π dⱼ + U s² Π dⱼ.
    let mut n = vec![0.0];
    for (i, &(_, _, a)) in modes.iter().enumerate() {
        n = add(&n, &scale(&mul(&s2, &product(Some(i))), a));
    }
    if l != 0.0 {
        n = add(&n, &scale(&all, l));
    }
    n = add(&n, &scale(&mul(&s2, &all), u));
    let den = mul(&mul(&s2, &all), &[1.0, wa]);
    (scale(&n, wa), den)
}

fn state_space(fit: &ModalFit, modes: &[(f64, f64, f64)], l: f64, u: f64, wa: f64) -> StateSpace {
    let lower = l != 0.0;
    let n = 2 * modes.len() + if lower { 2 } else { 0 } + 1;
    let ic = n - 1;
    let mut a = vec![vec![0.0; n]; n];
    let mut c = vec![vec![0.0; n]];
    let mut states = Vec::with_capacity(n);
    for (i, &(w, z, amp)) in modes.iter().enumerate() {
        let (q, qd) = (2 * i, 2 * i + 1);
        a[q][qd] = 1.0;
        a[qd][q] = -w * w;
        a[qd][qd] = -2.0 * z * w;
        a[qd][ic] = 1.0;
        c[0][q] = amp;
        states.push(format!("q_{}", fit.modes[i].label));
        states.push(format!("qdot_{}", fit.modes[i].label));
    }
    if lower {
        let (r, rd) = (2 * modes.len(), 2 * modes.len() + 1);
        a[r][rd] = 1.0;
        a[rd][ic] = 1.0;
        c[0][r] = l;
        states.push("r".into());
        states.push("rdot".into());
    }
    a[ic][ic] = -wa;
    c[0][ic] = u;
    states.push("i_c".into());
    let mut b = vec![vec![0.0]; n];
    b[ic][0] = wa;
    StateSpace {
        a,
        b,
        c,
        d: vec![vec![0.0]],
        states,
    }
}

impl ExportedModel {
    /// `G(jω)` of the exported form at `frequency_hz`, without the delay
    /// (evaluated from the form's own numbers: a check of the export).
    pub fn response(&self, frequency_hz: f64) -> C64 {
        let s = C64::new(0.0, 2.0 * PI * frequency_hz);
        let poly = |p: &[f64]| p.iter().fold(C64::new(0.0, 0.0), |acc, c| acc * s + c);
        if let Some(tf) = &self.tf {
            return poly(&tf.num) / poly(&tf.den);
        }
        if let Some(z) = &self.zpk {
            let prod = |r: &[[f64; 2]]| {
                r.iter().fold(C64::new(1.0, 0.0), |acc, x| {
                    acc * (s - C64::new(x[0], x[1]))
                })
            };
            return prod(&z.zeros) / prod(&z.poles) * z.gain;
        }
        let ss = self.ss.as_ref().expect("one form is set");
        let n = ss.a.len();
        let m = DMatrix::<C64>::from_fn(n, n, |i, j| {
            let d = if i == j { s } else { C64::new(0.0, 0.0) };
            d - C64::new(ss.a[i][j], 0.0)
        });
        let b = DMatrix::<C64>::from_fn(n, 1, |i, _| C64::new(ss.b[i][0], 0.0));
        let x = m
            .lu()
            .solve(&b)
            .expect("s is not an eigenvalue on the jω axis");
        (0..n).fold(C64::new(ss.d[0][0], 0.0), |acc, i| acc + x[i] * ss.c[0][i])
    }

    /// The model in `format`, with a header naming its source `source`.
    pub fn render(&self, format: ModelFormat, source: &str) -> String {
        match format {
            ModelFormat::Json => {
                serde_json::to_string_pretty(self).expect("the model serializes") + "\n"
            }
            ModelFormat::Matlab => self.matlab(source),
            ModelFormat::Python => self.python(source),
        }
    }

    fn header(&self, comment: &str, source: &str) -> String {
        let mut h = String::new();
        let mut line = |t: String| {
            h += comment;
            h += " ";
            h += &t;
            h += "\n";
        };
        line(format!("Modal model of {source}, fitted by bench fit."));
        line(format!(
            "G: {}, continuous time, SI units (rad/s).",
            self.io
        ));
        line(format!(
            "Input delay {:.6e} s (1σ {}): the loop's delay and the hold's half period.",
            self.delay_s,
            self.delay_sigma_s
                .map_or("unknown".into(), |s| format!("{s:.1e} s"))
        ));
        line(format!(
            "Hold sinc(wT/2) of T = {:e} s not included; for c2d(G, T, 'zoh') use delay - T/2.",
            self.hold_period_s
        ));
        for m in &self.modes {
            let sd = |v: Option<f64>| v.map_or("unknown".into(), |s| format!("{s:.2e}"));
            line(format!(
                "mode {}: f = {:.4} Hz (1σ {}), zeta = {:.6} (1σ {}), A = {:.6e} m/(A s^2) (1σ {})",
                m.label,
                m.frequency_hz,
                sd(m.frequency_sigma_hz),
                m.damping_ratio,
                sd(m.damping_ratio_sigma),
                m.modal_constant,
                sd(m.modal_constant_sigma)
            ));
        }
        if self.flags.is_empty() {
            line("The fit passed its checks.".into());
        } else {
            for f in &self.flags {
                line(format!("FLAGGED, not to be trusted: {f}"));
            }
        }
        h
    }

    fn matlab(&self, source: &str) -> String {
        let mut t = self.header("%", source);
        let row = |v: &[f64]| {
            v.iter()
                .map(|x| format!("{x:.17e}"))
                .collect::<Vec<_>>()
                .join(" ")
        };
        let complex = |v: &[[f64; 2]]| {
            v.iter()
                .map(|z| format!("{:.17e}{:+.17e}i", z[0], z[1]))
                .collect::<Vec<_>>()
                .join("; ")
        };
        let mat = |m: &[Vec<f64>]| m.iter().map(|r| row(r)).collect::<Vec<_>>().join("; ");
        t += &format!("delay_s = {:.17e};\n", self.delay_s);
        if let Some(tf) = &self.tf {
            t += &format!("num = [{}];\n", row(&tf.num));
            t += &format!("den = [{}];\n", row(&tf.den));
            t += "G = tf(num, den, 'InputDelay', delay_s);\n";
        }
        if let Some(z) = &self.zpk {
            t += &format!("z = [{}];\n", complex(&z.zeros));
            t += &format!("p = [{}];\n", complex(&z.poles));
            t += &format!("k = {:.17e};\n", z.gain);
            t += "G = zpk(z, p, k, 'InputDelay', delay_s);\n";
        }
        if let Some(ss) = &self.ss {
            t += &format!("A = [{}];\n", mat(&ss.a));
            t += &format!("B = [{}];\n", mat(&ss.b));
            t += &format!("C = [{}];\n", mat(&ss.c));
            t += &format!("D = [{}];\n", mat(&ss.d));
            t += "G = ss(A, B, C, D, 'InputDelay', delay_s);\n";
        }
        t
    }

    fn python(&self, source: &str) -> String {
        let mut t = self.header("#", source);
        let list = |v: &[f64]| {
            v.iter()
                .map(|x| format!("{x:.17e}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let complex = |v: &[[f64; 2]]| {
            v.iter()
                .map(|z| format!("complex({:.17e}, {:.17e})", z[0], z[1]))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let mat = |m: &[Vec<f64>]| {
            m.iter()
                .map(|r| format!("[{}]", list(r)))
                .collect::<Vec<_>>()
                .join(", ")
        };
        t += "import control\n\n";
        t += &format!("delay_s = {:.17e}\n", self.delay_s);
        if let Some(tf) = &self.tf {
            t += &format!("num = [{}]\n", list(&tf.num));
            t += &format!("den = [{}]\n", list(&tf.den));
            t += "G = control.tf(num, den)\n";
        }
        if let Some(z) = &self.zpk {
            t += &format!("zeros = [{}]\n", complex(&z.zeros));
            t += &format!("poles = [{}]\n", complex(&z.poles));
            t += &format!("gain = {:.17e}\n", z.gain);
            t += "G = control.zpk(zeros, poles, gain)\n";
        }
        if let Some(ss) = &self.ss {
            t += &format!("A = [{}]\n", mat(&ss.a));
            t += &format!("B = [{}]\n", mat(&ss.b));
            t += &format!("C = [{}]\n", mat(&ss.c));
            t += &format!("D = [{}]\n", mat(&ss.d));
            t += "G = control.ss(A, B, C, D)\n";
        }
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ident::modal_fit::{evaluate, FitQuality, FittedMode};

    fn fit() -> ModalFit {
        let mode = |label: &str, f: f64, z: f64, a: f64| FittedMode {
            label: label.into(),
            frequency_hz: f,
            frequency_sigma_hz: 0.01,
            damping_ratio: z,
            damping_ratio_sigma: 1e-4,
            modal_constant: a,
            modal_constant_sigma: 1e-3,
            sign: a.signum() as i8,
            in_path: true,
        };
        ModalFit {
            modes: vec![
                mode("R", 29.27, 0.009, 5.24),
                mode("u", 81.16, 0.0042, -0.357),
                mode("v", 84.66, 0.0041, 0.233),
            ],
            lower_residual: -6e-5,
            lower_residual_sigma: 1e-5,
            upper_residual_m_per_a: 2e-9,
            upper_residual_sigma_m_per_a: 1e-9,
            delay_s: 1e-4,
            delay_sigma_s: 2e-7,
            rms_relative_error: 0.01,
            coherent_points: 500,
            sign_sequence: String::new(),
            dominant_sequence: String::new(),
            zeros: Vec::new(),
            cmp_cnmp: true,
            quality: FitQuality::default(),
            labels_unsure: None,
            covariance: Vec::new(),
        }
    }

    /// Every form gives the fit's own response (modal sum times the
    /// amplifier lag) to rounding: the closed-form `evaluate` of the fit
    /// without the hold's sinc and the delay is the reference.
    #[test]
    fn every_form_is_the_fits_response() {
        let fit = fit();
        let path = Path {
            period_s: 2e-4,
            amplifier_bandwidth_hz: 5000.0,
        };
        for form in [ModelForm::Tf, ModelForm::Zpk, ModelForm::Ss] {
            let m = export(&fit, &path, form).unwrap();
            for f in [1.0, 10.0, 29.27, 50.0, 81.16, 83.0, 84.66, 200.0, 1000.0] {
                let w = 2.0 * PI * f;
                let x = 0.5 * w * path.period_s;
                let reference = evaluate(&fit, &path, f)
                    / (x.sin() / x)
                    / C64::from_polar(1.0, -w * fit.delay_s);
                let got = m.response(f);
                let rel = (got - reference).norm() / reference.norm();
                assert!(
                    rel < 1e-8,
                    "{form:?} at {f} Hz: {got} against {reference} ({rel:e})"
                );
            }
        }
    }

    #[test]
    fn a_fit_without_modes_or_with_a_nan_is_refused() {
        let path = Path {
            period_s: 2e-4,
            amplifier_bandwidth_hz: 5000.0,
        };
        let mut f = fit();
        f.modes.clear();
        assert_eq!(export(&f, &path, ModelForm::Tf), Err(ExportError::NoMode));
        let mut f = fit();
        f.modes[1].damping_ratio = f64::NAN;
        assert_eq!(
            export(&f, &path, ModelForm::Ss),
            Err(ExportError::NotPhysical("damping ratio"))
        );
    }

    #[test]
    fn roots_of_a_known_polynomial() {
        // (s + 1)(s² + 2s + 5): roots −1, −1 ± 2j.
        let r = roots(&mul(&[1.0, 1.0], &[1.0, 2.0, 5.0]));
        let want = [
            C64::new(-1.0, -2.0),
            C64::new(-1.0, 0.0),
            C64::new(-1.0, 2.0),
        ];
        for (a, b) in r.iter().zip(want) {
            assert!((a - b).norm() < 1e-12, "{r:?}");
        }
    }
}
