//! `[controller.NAME]`: a controller's definition as the config holds it
//! (its continuous transfer function, Eq. 6-6 and 6-7 of the thesis in
//! general form, and its discretisation method) and its validation. The
//! mathematics on it (`C(s)`, sections, discretisation, the loop check)
//! is [`crate::control`]'s.

use serde::{Deserialize, Serialize};

/// Most second-order sections a controller may have.
pub const MAX_SECTIONS: usize = 12;

/// Range of a corner frequency (`real_zeros_rad_s`, `real_poles_rad_s`,
/// `omega_rad_s` of a complex pair), rad/s: 1 mrad/s to 1 Mrad/s (above
/// the Nyquist frequency of the fastest loop, 100 kHz = 314 krad/s).
pub const CORNER_RAD_S: (f64, f64) = (1e-3, 1e6);
/// Range of a damping ratio `zeta` of a complex pair: 0 (a notch) to 10
/// (two well separated real roots).
pub const ZETA: (f64, f64) = (0.0, 10.0);
/// Range of `|gain|`, A per error unit (× s^n for n integrators and, for
/// `monic`, × rad/s per excess pole): wide, since a monic high-order
/// controller's gain carries its corner frequencies.
pub const GAIN_ABS: (f64, f64) = (1e-20, 1e20);
/// Most `integrators`.
pub const MAX_INTEGRATORS: u32 = 3;

/// Unit of the error the controller's gain expects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ErrorUnit {
    /// metres
    #[serde(rename = "m")]
    Metre,
    /// micrometres (the thesis' controllers)
    #[serde(rename = "um")]
    Micrometre,
    /// nanometres
    #[serde(rename = "nm")]
    Nanometre,
}

impl ErrorUnit {
    /// Multiplier from metres to this unit.
    pub fn per_metre(self) -> f64 {
        match self {
            Self::Metre => 1.0,
            Self::Micrometre => 1e6,
            Self::Nanometre => 1e9,
        }
    }
}

/// How the factors are normalised.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Form {
    /// Factors as written: `(s + z)`, `(s² + 2ζωs + ω²)` (Eq. 6-7).
    Monic,
    /// Each factor divided by its value at s = 0 (Eq. 6-6: `ω²/(s²+…)`).
    UnityDc,
}

/// A complex pair `s² + 2ζωs + ω²`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ComplexPair {
    /// Natural frequency ω, rad/s.
    pub omega_rad_s: f64,
    /// Damping ratio ζ.
    pub zeta: f64,
}

/// `[controller.NAME]`
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControllerConfig {
    /// What it is (shown in summaries).
    #[serde(default)]
    pub description: String,
    /// Unit of the position error the gain expects.
    pub error_unit: ErrorUnit,
    /// Factor normalisation.
    pub form: Form,
    /// Gain g, A per error unit (times s^n for n integrators).
    pub gain: f64,
    /// Number of integrators n (poles at s = 0).
    #[serde(default)]
    pub integrators: u32,
    /// Real zeros: corner frequencies z (root at −z), rad/s.
    #[serde(default)]
    pub real_zeros_rad_s: Vec<f64>,
    /// Real poles: corner frequencies p (root at −p), rad/s.
    #[serde(default)]
    pub real_poles_rad_s: Vec<f64>,
    /// Complex zero pairs.
    #[serde(default)]
    pub complex_zeros: Vec<ComplexPair>,
    /// Complex pole pairs.
    #[serde(default)]
    pub complex_poles: Vec<ComplexPair>,
    /// Discretisation method (default `tustin`).
    #[serde(default)]
    pub discretization: Discretization,
}

/// A controller definition that cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {reason}")]
pub struct ControllerError {
    /// Dotted config key.
    pub key: String,
    /// Why.
    pub reason: String,
}

fn cerr(key: String, reason: impl Into<String>) -> ControllerError {
    ControllerError {
        key,
        reason: reason.into(),
    }
}

impl ControllerConfig {
    /// The complex pole pairs as resonances: each `(ω√(1 − ζ²), ζω)`, the
    /// frequency of its peak and its half-width (the decay rate σ), both
    /// rad/s: the continuous counterpart of
    /// [`crate::control::DiscreteController::resonances`], for
    /// [`crate::control::loop_check::resolving`].
    pub fn resonances(&self) -> Vec<(f64, f64)> {
        self.complex_poles
            .iter()
            .map(|p| {
                (
                    p.omega_rad_s * (1.0 - p.zeta * p.zeta).max(0.0).sqrt(),
                    p.zeta * p.omega_rad_s,
                )
            })
            .collect()
    }

    /// Checks the transfer function: finite positive gain, positive
    /// frequencies, 0 ≤ ζ, proper (zeros ≤ poles), at most
    /// [`MAX_SECTIONS`] sections. `prefix` is e.g. `controller.fast`.
    ///
    /// # Errors
    /// The first offending key with the reason.
    pub fn validate(&self, prefix: &str) -> Result<(), ControllerError> {
        if !self.gain.is_finite() || !(GAIN_ABS.0..=GAIN_ABS.1).contains(&self.gain.abs()) {
            return Err(cerr(
                format!("{prefix}.gain"),
                format!(
                    "must be finite with |gain| in [{:?}, {:?}], got {}",
                    GAIN_ABS.0, GAIN_ABS.1, self.gain
                ),
            ));
        }
        if self.integrators > MAX_INTEGRATORS {
            return Err(cerr(
                format!("{prefix}.integrators"),
                format!(
                    "at most {MAX_INTEGRATORS} integrators, got {}",
                    self.integrators
                ),
            ));
        }
        let corner = |x: f64| x.is_finite() && (CORNER_RAD_S.0..=CORNER_RAD_S.1).contains(&x);
        // Zeros may lie in the right half plane (a negative corner or ζ):
        // a controller's zeros need not be stable, its poles must.
        for (name, v, zeros) in [
            ("real_zeros_rad_s", &self.real_zeros_rad_s, true),
            ("real_poles_rad_s", &self.real_poles_rad_s, false),
        ] {
            for (i, x) in v.iter().enumerate() {
                let ok = if zeros { corner(x.abs()) } else { corner(*x) };
                if !ok {
                    let range = if zeros {
                        format!(
                            "|corner| in [{:?}, {:?}] rad/s (negative: a zero in the right half plane)",
                            CORNER_RAD_S.0, CORNER_RAD_S.1
                        )
                    } else {
                        format!("in [{:?}, {:?}] rad/s", CORNER_RAD_S.0, CORNER_RAD_S.1)
                    };
                    return Err(cerr(
                        format!("{prefix}.{name}[{i}]"),
                        format!(
                            "corner frequency must be {range}, got {x} (use `integrators` for s = 0)"
                        ),
                    ));
                }
            }
        }
        for (name, v, zeros) in [
            ("complex_zeros", &self.complex_zeros, true),
            ("complex_poles", &self.complex_poles, false),
        ] {
            for (i, p) in v.iter().enumerate() {
                if !corner(p.omega_rad_s) {
                    return Err(cerr(
                        format!("{prefix}.{name}[{i}].omega_rad_s"),
                        format!(
                            "must be in [{:?}, {:?}] rad/s, got {}",
                            CORNER_RAD_S.0, CORNER_RAD_S.1, p.omega_rad_s
                        ),
                    ));
                }
                let lo = if zeros { -ZETA.1 } else { ZETA.0 };
                if !p.zeta.is_finite() || !(lo..=ZETA.1).contains(&p.zeta) {
                    return Err(cerr(
                        format!("{prefix}.{name}[{i}].zeta"),
                        format!("must be in [{lo:?}, {:?}], got {}", ZETA.1, p.zeta),
                    ));
                }
            }
        }
        let zeros = self.real_zeros_rad_s.len() + 2 * self.complex_zeros.len();
        let poles =
            self.integrators as usize + self.real_poles_rad_s.len() + 2 * self.complex_poles.len();
        if zeros > poles {
            return Err(cerr(
                prefix.to_string(),
                format!("improper: {zeros} zeros ({prefix}.real_zeros_rad_s, {prefix}.complex_zeros) but {poles} poles ({prefix}.integrators, {prefix}.real_poles_rad_s, {prefix}.complex_poles): a controller must have at least as many poles as zeros"),
            ));
        }
        if poles == 0 {
            return Err(cerr(
                prefix.to_string(),
                "empty transfer function: no poles",
            ));
        }
        if poles.div_ceil(2) > MAX_SECTIONS {
            return Err(cerr(
                prefix.to_string(),
                format!("{poles} poles ({prefix}.integrators, {prefix}.real_poles_rad_s, {prefix}.complex_poles) need more than {MAX_SECTIONS} second-order sections"),
            ));
        }
        Ok(())
    }
}

/// How the continuous controller becomes the discrete one
/// (`discretization` key; see the module docs).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum Discretization {
    /// Tustin per section, pre-warped at the section's critical frequency.
    #[default]
    Tustin,
    /// Poles matched (`z = e^{sT}`), numerators fitted by weighted least
    /// squares to the continuous response up to f_s/10.
    LeastSquares,
    /// The bilinear map `s = (2/T)(z − 1)/(z + 1)` on every section, no
    /// pre-warp: exact for a controller designed in discrete time and
    /// written in `s` by the inverse map (`bench design --strategy limit`).
    Bilinear,
}

impl Discretization {
    /// The config spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Tustin => "tustin",
            Self::LeastSquares => "least_squares",
            Self::Bilinear => "bilinear",
        }
    }
}
