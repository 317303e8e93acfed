//! The SR4DoF lumped-parameter model of the thesis (Chapter 2, Eq. 2-5).
//!
//! Coordinates `z = [x1, y1, y2, y3]` (m): X of the motion stage ①, Y of ①,
//! Y of the secondary stages ② and ③ relative to ①. Input: the actuator
//! force `P` (N) on stage ④ in X; output: `x1`.
//!
//! ```text
//! M z'' + C z' + K z = q P,   q = [1, α, −2α, 0]ᵀ,   x1 = cᵀ z,  c = [1, 0, 0, 0]ᵀ
//! α = 0.6 · Y1o / L                                                  (Eq. 2-6)
//! k12 = k24 = k13 = k35 = 24 E I / L³,  I = H T³ / 12      (unless given explicitly)
//! m2 ← m2 · (1 + Δm23)                           (mass asymmetry, Δm23 = m2/m3 − 1)
//! C = a M + b K                                               (Rayleigh damping)
//! ```
//!
//! With `24EI/L³` (≈ 7.86 kN/m for Table 2-1) the mode shapes of Table 2-2
//! come out to about three decimals; the X rigid-body frequency matches
//! (18.2 Hz) but the three Y modes come out 4–6 % low (26.1 vs 27.6 Hz,
//! 147.6 vs 153.2 Hz, 148.5 vs 154.3 Hz). `bench fit --frequencies` on
//! Table 2-2 gives 1.093 × `24EI/L³`, with which all four are within 2 %;
//! the shipped configs set `parallelogram_stiffness_n_per_m` to that
//! (README, *Calibration of the shipped benches*). Without it a config gets
//! the textbook value.
//!
//! Rayleigh coefficients `a`, `b` are fitted so that the X rigid-body mode
//! (of modes 1 and 2, the one whose mass-normalised shape has the larger
//! `|x1|`) has damping ratio `zeta_rigid` and the mean natural frequency of
//! the closely spaced pair (modes 3 and 4) has `zeta_csm`; modal damping is
//! then `ζᵢ = a / (2ωᵢ) + b ωᵢ / 2`.

use nalgebra::{Complex, DMatrix, Matrix4, SymmetricEigen, Vector4};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Beam geometry and material of the parallelogram flexures (Table 2-1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Beam {
    /// Beam length `L`, m.
    pub length_m: f64,
    /// Beam height `H` (out of plane), m.
    pub height_m: f64,
    /// Beam thickness `T` (in the bending direction), m.
    pub thickness_m: f64,
    /// Young's modulus `E`, Pa.
    pub youngs_modulus_pa: f64,
}

impl Beam {
    /// Second moment of area `I = H T³ / 12`, m⁴.
    pub fn second_moment_m4(&self) -> f64 {
        self.height_m * self.thickness_m.powi(3) / 12.0
    }

    /// Y bending stiffness of one parallelogram (two fixed-guided beams),
    /// `24 E I / L³`, N/m (thesis §2.2.1, [30]).
    pub fn parallelogram_stiffness_n_per_m(&self) -> f64 {
        24.0 * self.youngs_modulus_pa * self.second_moment_m4() / self.length_m.powi(3)
    }
}

/// Damping targets for the Rayleigh fit (thesis §5.2.2: 0.009 and 0.004).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Damping {
    /// Damping ratio of the X rigid-body mode.
    pub zeta_rigid: f64,
    /// Damping ratio at the mean frequency of the closely spaced pair.
    pub zeta_csm: f64,
}

/// Physical parameters of the SR4DoF (the `[plant]` table of a bench config).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sr4dofParams {
    /// Motion stage ① mass, kg.
    pub m1_kg: f64,
    /// Secondary stage ② nominal mass, kg (before the asymmetry).
    pub m2_kg: f64,
    /// Secondary stage ③ mass, kg.
    pub m3_kg: f64,
    /// Intermediate stage ④ mass (with the actuator's moving coil), kg.
    pub m4_kg: f64,
    /// Intermediate stage ⑤ mass (with the balance mass), kg.
    pub m5_kg: f64,
    /// X bearing stiffness of stage ④, N/m.
    pub k4_n_per_m: f64,
    /// X bearing stiffness of stage ⑤, N/m.
    pub k5_n_per_m: f64,
    /// Operating point `Y1o`: static Y displacement of stage ①, m.
    pub operating_point_m: f64,
    /// Mass asymmetry `Δm23 = m2/m3 − 1`, applied as `m2 ← m2 (1 + Δm23)`.
    pub mass_asymmetry: f64,
    /// Parallelogram beam geometry.
    pub beam: Beam,
    /// Explicit parallelogram Y stiffness, N/m; `None` → `24 E I / L³`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parallelogram_stiffness_n_per_m: Option<f64>,
    /// Damping targets.
    pub damping: Damping,
    /// Optional force disturbance (`[plant.disturbance]`), simulator only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub disturbance: Option<Disturbance>,
}

/// Band-limited random force disturbance acting where the actuator acts
/// (an input disturbance: floor vibration, air, cable forces).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Disturbance {
    /// RMS force, N.
    pub rms_n: f64,
    /// Pass band `[low, high]`, Hz: white Gaussian noise through a
    /// second-order Butterworth high-pass at `low` and low-pass at `high`.
    pub band_hz: [f64; 2],
}

/// A parameter that cannot describe a physical bench.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {reason}")]
pub struct ParamError {
    /// Dotted key of the offending value (e.g. `plant.m1_kg`).
    pub key: String,
    /// Why it is refused.
    pub reason: String,
}

impl ParamError {
    /// Builds an error for `key`.
    pub fn new(key: impl Into<String>, reason: impl Into<String>) -> Self {
        Self {
            key: key.into(),
            reason: reason.into(),
        }
    }
}

/// Checks that `value` is finite and > 0.
///
/// # Errors
/// [`ParamError`] naming `key`.
pub fn positive(key: &str, value: f64) -> Result<(), ParamError> {
    if !value.is_finite() {
        Err(ParamError::new(
            key,
            format!("must be a finite number, got {value}"),
        ))
    } else if value <= 0.0 {
        Err(ParamError::new(key, format!("must be > 0, got {value}")))
    } else {
        Ok(())
    }
}

/// Checks that `value` is finite and ≥ 0.
///
/// # Errors
/// [`ParamError`] naming `key`.
pub fn non_negative(key: &str, value: f64) -> Result<(), ParamError> {
    if !value.is_finite() {
        Err(ParamError::new(
            key,
            format!("must be a finite number, got {value}"),
        ))
    } else if value < 0.0 {
        Err(ParamError::new(key, format!("must be >= 0, got {value}")))
    } else {
        Ok(())
    }
}

/// The documented ranges of the `[plant]` keys (README, *Configuration
/// reference*; the comments in `bench-config/*.toml`): a lumped model of a
/// flexure stage on a lab bench, with margins of one to three decades
/// around the thesis' benches, so that a value outside describes no bench
/// (and no value inside can overflow the model's arithmetic).
pub mod ranges {
    /// Each stage mass, kg: 0.1 g (below the thesis' 0.5 g trim masses) to
    /// 100 kg. The asymmetry is applied on top of `m2_kg`.
    pub const MASS_KG: (f64, f64) = (1e-4, 100.0);
    /// X bearing stiffnesses `k4_n_per_m`, `k5_n_per_m` and the
    /// parallelogram Y stiffness (explicit or `24 E I / L³`), N/m: 1 N/m to
    /// 10 MN/m (the thesis' flexures: 4.4 to 36 kN/m).
    pub const STIFFNESS_N_PER_M: (f64, f64) = (1.0, 1e7);
    /// `beam.length_m`, m: 1 mm to 0.5 m.
    pub const BEAM_LENGTH_M: (f64, f64) = (1e-3, 0.5);
    /// `beam.height_m`, m: 0.1 mm to 0.2 m.
    pub const BEAM_HEIGHT_M: (f64, f64) = (1e-4, 0.2);
    /// `beam.thickness_m`, m: 10 µm to 10 mm, and at most a tenth of the
    /// length (a slender beam: the `24 E I / L³` of a fixed-guided beam).
    pub const BEAM_THICKNESS_M: (f64, f64) = (1e-5, 1e-2);
    /// `beam.youngs_modulus_pa`, Pa: 100 MPa (stiff polymers) to 1 TPa
    /// (diamond is 1.2 TPa; aluminium 69 GPa).
    pub const YOUNGS_MODULUS_PA: (f64, f64) = (1e8, 1e12);
    /// `mass_asymmetry` Δm23 = m2/m3 − 1, a fraction (0.10 = +10 %):
    /// −0.33 to +0.5, the heavier secondary stage at most about 1.5 times
    /// the lighter. The model is about two nominally identical secondary
    /// stages with a small parametric asymmetry (manufacturing tolerances,
    /// added masses: thesis §2.2.1, §5.2.1); within this range their
    /// uncoupled frequencies stay within √1.5 ≈ 1.22 of each other, the
    /// closely spaced pair (within 25 %) whose CMP-CNMP zeros the bench
    /// studies. The thesis' experimental grid spans −8 % to +10 %
    /// (Fig 5-10).
    pub const MASS_ASYMMETRY: (f64, f64) = (-0.33, 0.5);
    /// `|operating_point_m|` at most this fraction of the beam length:
    /// Eq. (2-1) is a small-rotation result (the thesis' bench goes to
    /// about 10 %).
    pub const OPERATING_POINT_OF_L: f64 = 0.2;
    /// `damping.zeta_rigid`, `damping.zeta_csm`: [0, 1) (lightly damped;
    /// 1 is critical damping).
    pub const ZETA: (f64, f64) = (0.0, 1.0);
    /// `disturbance.rms_n`, N: 0 (none) to 10 N (a tenth of the coil's
    /// 111 N peak force).
    pub const DISTURBANCE_RMS_N: (f64, f64) = (0.0, 10.0);
    /// Lowest `disturbance.band_hz` edge, Hz; the highest is below the
    /// Nyquist frequency of the loop (checked with the loop rate).
    pub const DISTURBANCE_MIN_HZ: f64 = 0.01;
    /// The keys the model's matrices are built from: an error of the
    /// assembled model (not positive definite, an eigenvalue problem that
    /// does not converge) names these.
    pub const MODEL_KEYS: &str = "plant.m1_kg, plant.m2_kg, plant.m3_kg, plant.m4_kg, \
plant.m5_kg, plant.k4_n_per_m, plant.k5_n_per_m, plant.operating_point_m, \
plant.mass_asymmetry, plant.beam.length_m, plant.beam.height_m, plant.beam.thickness_m, \
plant.beam.youngs_modulus_pa, plant.parallelogram_stiffness_n_per_m";
}

/// Checks that `value` is finite and in `[lo, hi]` (`unit` for the
/// message), with `why` the documented reason for the range. `key` is
/// only formatted on failure (the map validates tens of thousands of
/// benches).
///
/// # Errors
/// [`ParamError`] naming `key`.
pub fn within(
    key: impl std::fmt::Display,
    value: f64,
    (lo, hi): (f64, f64),
    unit: &str,
    why: &str,
) -> Result<(), ParamError> {
    if !value.is_finite() {
        return Err(ParamError::new(
            key.to_string(),
            format!("must be a finite number, got {value}"),
        ));
    }
    if !(lo..=hi).contains(&value) {
        return Err(ParamError::new(
            key.to_string(),
            format!("{value:?} {unit} is outside [{lo:?}, {hi:?}] {unit}: {why}"),
        ));
    }
    Ok(())
}

impl Sr4dofParams {
    /// Checks every value against its documented range ([`ranges`]);
    /// `prefix` is prepended to key names (e.g. `"plant"`). The disturbance
    /// band's upper edge is checked against the loop's Nyquist frequency by
    /// the caller (the model does not know the loop rate).
    ///
    /// # Errors
    /// The first offending key with the reason.
    pub fn validate(&self, prefix: &str) -> Result<(), ParamError> {
        // The dotted key, formatted only when a check fails.
        struct Key<'a>(&'a str, &'a str);
        impl std::fmt::Display for Key<'_> {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                write!(f, "{}.{}", self.0, self.1)
            }
        }
        let k = |name| Key(prefix, name);
        for (name, v) in [
            ("m1_kg", self.m1_kg),
            ("m2_kg", self.m2_kg),
            ("m3_kg", self.m3_kg),
            ("m4_kg", self.m4_kg),
            ("m5_kg", self.m5_kg),
        ] {
            within(k(name), v, ranges::MASS_KG, "kg", "0.1 g to 100 kg")?;
        }
        for (name, v) in [
            ("k4_n_per_m", self.k4_n_per_m),
            ("k5_n_per_m", self.k5_n_per_m),
        ] {
            within(
                k(name),
                v,
                ranges::STIFFNESS_N_PER_M,
                "N/m",
                "1 N/m to 10 MN/m",
            )?;
        }
        let b = &self.beam;
        within(
            k("beam.length_m"),
            b.length_m,
            ranges::BEAM_LENGTH_M,
            "m",
            "1 mm to 0.5 m",
        )?;
        within(
            k("beam.height_m"),
            b.height_m,
            ranges::BEAM_HEIGHT_M,
            "m",
            "0.1 mm to 0.2 m",
        )?;
        within(
            k("beam.thickness_m"),
            b.thickness_m,
            ranges::BEAM_THICKNESS_M,
            "m",
            "10 µm to 10 mm",
        )?;
        if b.thickness_m > 0.1 * b.length_m {
            return Err(ParamError::new(
                k("beam.thickness_m").to_string(),
                format!(
                    "{} m is more than a tenth of {prefix}.beam.length_m = {} m: not a slender beam (24 E I / L³)",
                    b.thickness_m, b.length_m
                ),
            ));
        }
        within(
            k("beam.youngs_modulus_pa"),
            b.youngs_modulus_pa,
            ranges::YOUNGS_MODULUS_PA,
            "Pa",
            "100 MPa to 1 TPa",
        )?;
        match self.parallelogram_stiffness_n_per_m {
            Some(kp) => within(
                k("parallelogram_stiffness_n_per_m"),
                kp,
                ranges::STIFFNESS_N_PER_M,
                "N/m",
                "1 N/m to 10 MN/m",
            )?,
            None => {
                let kp = b.parallelogram_stiffness_n_per_m();
                let (lo, hi) = ranges::STIFFNESS_N_PER_M;
                if !(lo..=hi).contains(&kp) {
                    return Err(ParamError::new(
                        k("beam").to_string(),
                        format!(
                            "24 E I / L³ from {p}.beam.length_m, {p}.beam.height_m, {p}.beam.thickness_m and {p}.beam.youngs_modulus_pa is {kp:.4e} N/m, outside [{lo:?}, {hi:?}] N/m (1 N/m to 10 MN/m)",
                            p = prefix
                        ),
                    ));
                }
            }
        }
        if !self.operating_point_m.is_finite() {
            return Err(ParamError::new(
                k("operating_point_m").to_string(),
                format!("must be a finite number, got {}", self.operating_point_m),
            ));
        }
        // Eq. (2-1) is a small-rotation result; beyond ~15 % of L the beams
        // are far outside the model (the thesis' bench goes to ~10 %).
        if self.operating_point_m.abs() > ranges::OPERATING_POINT_OF_L * b.length_m {
            return Err(ParamError::new(
                k("operating_point_m").to_string(),
                format!(
                    "|{}| m is beyond 20 % of the beam length {prefix}.beam.length_m = {} m: outside the model's validity",
                    self.operating_point_m, b.length_m
                ),
            ));
        }
        within(
            k("mass_asymmetry"),
            self.mass_asymmetry,
            ranges::MASS_ASYMMETRY,
            "",
            "the heavier secondary stage at most about 1.5 times the lighter, so the two stay a closely spaced pair (thesis §2.2.1, §5.2.1; its grid spans -0.08 to +0.10)",
        )?;
        if let Some(d) = &self.disturbance {
            within(
                k("disturbance.rms_n"),
                d.rms_n,
                ranges::DISTURBANCE_RMS_N,
                "N",
                "0 to a tenth of the coil's 111 N peak force",
            )?;
            for (i, name) in ["disturbance.band_hz[0]", "disturbance.band_hz[1]"]
                .into_iter()
                .enumerate()
            {
                within(
                    k(name),
                    d.band_hz[i],
                    (ranges::DISTURBANCE_MIN_HZ, f64::MAX),
                    "Hz",
                    "at least 0.01 Hz (and below the loop's Nyquist frequency)",
                )?;
            }
            if d.band_hz[0] >= d.band_hz[1] {
                return Err(ParamError::new(
                    k("disturbance.band_hz[0]").to_string(),
                    format!(
                        "low edge {} Hz must be below the high edge {prefix}.disturbance.band_hz[1] = {} Hz",
                        d.band_hz[0], d.band_hz[1]
                    ),
                ));
            }
        }
        for (name, z) in [
            ("damping.zeta_rigid", self.damping.zeta_rigid),
            ("damping.zeta_csm", self.damping.zeta_csm),
        ] {
            let (lo, hi) = ranges::ZETA;
            if !z.is_finite() || z < lo || z >= hi {
                return Err(ParamError::new(
                    k(name).to_string(),
                    format!("{z:?} is outside [0, 1): a damping ratio of a lightly damped flexure"),
                ));
            }
        }
        Ok(())
    }

    /// Coupling coefficient `α = 0.6 Y1o / L` (Eq. 2-6), dimensionless.
    pub fn alpha(&self) -> f64 {
        0.6 * self.operating_point_m / self.beam.length_m
    }

    /// Parallelogram Y stiffness in force, N/m: the explicit value or
    /// `24 E I / L³`.
    pub fn parallelogram_stiffness(&self) -> f64 {
        self.parallelogram_stiffness_n_per_m
            .unwrap_or_else(|| self.beam.parallelogram_stiffness_n_per_m())
    }

    /// The mass matrix M, stiffness matrix K and generalised input `q` of
    /// Eq. (2-5) over `[x1, y1, y2, y3]` (M in kg, K in N/m, q
    /// dimensionless: generalised force per newton of actuator force),
    /// with `m2 = m2_kg·(1 + mass_asymmetry)` and all four parallelogram
    /// stiffnesses `k12 = k24 = k13 = k35` equal to
    /// [`parallelogram_stiffness`](Self::parallelogram_stiffness). Not
    /// validated: see [`validate`](Self::validate).
    pub fn matrices(&self) -> Matrices {
        let a = self.alpha();
        let (m1, m3, m4, m5) = (self.m1_kg, self.m3_kg, self.m4_kg, self.m5_kg);
        let m2 = self.m2_kg * (1.0 + self.mass_asymmetry);
        let (k4, k5) = (self.k4_n_per_m, self.k5_n_per_m);
        let kp = self.parallelogram_stiffness();
        let (k12, k24, k13, k35) = (kp, kp, kp, kp);
        let a2 = a * a;

        #[rustfmt::skip]
        let mass = Matrix4::new(
            m1 + m2 + m3 + m4 + m5, a * (m2 + m4 - m3 - m5), -a * (m2 + 2.0 * m4), a * (m3 + 2.0 * m5),
            a * (m2 + m4 - m3 - m5), m1 + a2 * (m2 + m3 + m4 + m5), -a2 * (m2 + 2.0 * m4), -a2 * (m3 + 2.0 * m5),
            -a * (m2 + 2.0 * m4), -a2 * (m2 + 2.0 * m4), m2 + a2 * m2 + 4.0 * a2 * m4, 0.0,
            a * (m3 + 2.0 * m5), -a2 * (m3 + 2.0 * m5), 0.0, m3 + a2 * m3 + 4.0 * a2 * m5,
        );
        #[rustfmt::skip]
        let stiffness = Matrix4::new(
            k4 + k5, a * (k4 - k5), -2.0 * a * k4, 2.0 * a * k5,
            a * (k4 - k5), k12 + k13 + a2 * (k4 + k5), -2.0 * a2 * k4 - k12, -2.0 * a2 * k5 - k13,
            -2.0 * a * k4, -2.0 * a2 * k4 - k12, 4.0 * a2 * k4 + k24 + k12, 0.0,
            2.0 * a * k5, -2.0 * a2 * k5 - k13, 0.0, 4.0 * a2 * k5 + k13 + k35,
        );
        Matrices {
            mass,
            stiffness,
            input: Vector4::new(1.0, a, -2.0 * a, 0.0),
        }
    }
}

/// The matrices of Eq. (2-5) ([`Sr4dofParams::matrices`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Matrices {
    /// Mass matrix M, kg.
    pub mass: Matrix4<f64>,
    /// Stiffness matrix K, N/m.
    pub stiffness: Matrix4<f64>,
    /// Generalised force per unit actuator force, `q = [1, α, −2α, 0]ᵀ`.
    pub input: Vector4<f64>,
}

/// One mode of the undamped model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mode {
    /// Natural frequency, rad/s.
    pub omega_rad_s: f64,
    /// Mass-normalised mode shape (`φᵀ M φ = 1`), over `[x1, y1, y2, y3]`,
    /// units m/√kg.
    pub shape: Vector4<f64>,
    /// Modal damping ratio from the Rayleigh fit.
    pub zeta: f64,
    /// Modal residue of the force→x1 transfer function,
    /// `βᵢ = (cᵀφᵢ)(φᵢᵀq)`, m/(N·s²) — `G(s) = Σ βᵢ / (s² + 2ζᵢωᵢ s + ωᵢ²)`
    /// (Eq. 2-7 with damping).
    pub residue: f64,
}

impl Mode {
    /// Natural frequency, Hz.
    pub fn frequency_hz(&self) -> f64 {
        self.omega_rad_s / (2.0 * PI)
    }

    /// The mode shape scaled to unit Euclidean length, sign chosen so that
    /// the largest-magnitude entry is positive (the convention of Table 2-2
    /// aside from sign).
    pub fn unit_shape(&self) -> Vector4<f64> {
        let v = self.shape.normalize();
        let imax = v.iamax();
        if v[imax] < 0.0 {
            -v
        } else {
            v
        }
    }
}

/// Type of a zero pair / quartet of a lightly damped flexible system
/// (thesis Chapter 3; `u = s²` roots of the undamped numerator).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ZeroType {
    /// Marginally minimum phase: `u < 0`, a pair on the imaginary axis
    /// (slightly into the left half plane with damping): an anti-resonance.
    Mmp,
    /// Real minimum / non-minimum phase pair: `u > 0`, `s = ±√u`.
    RmpRnmp,
    /// Complex minimum / non-minimum phase quartet: complex `u`,
    /// `s = ±a ± jb` — two zeros in the right half plane.
    CmpCnmp,
}

impl ZeroType {
    /// Relative size of `Im u` below which a root `u = s²` counts as real
    /// (the roots come from a companion-matrix eigensolver, accurate to a
    /// few ulps of `|u|` times the conditioning).
    pub const REAL_TOLERANCE: f64 = 1e-9;

    /// The type of the zeros `s = ±√u` of an undamped transfer function
    /// from a root `u` (rad/s)² of its numerator in `u = s²` (thesis 3.2.1):
    /// complex `u` (`|Im u| > REAL_TOLERANCE·|u|`) → CMP-CNMP, real
    /// `u < 0` → MMP, real `u ≥ 0` → RMP-RNMP.
    pub fn of_u(u: Complex<f64>) -> Self {
        if u.im.abs() > Self::REAL_TOLERANCE * u.norm() {
            Self::CmpCnmp
        } else if u.re < 0.0 {
            Self::Mmp
        } else {
            Self::RmpRnmp
        }
    }

    /// The thesis' abbreviation.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Mmp => "MMP",
            Self::RmpRnmp => "RMP-RNMP",
            Self::CmpCnmp => "CMP-CNMP",
        }
    }
}

/// A root `u` of the undamped numerator `N(u)` (Eq. 2-7), with its type.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UndampedZero {
    /// Root in `u = s²`, (rad/s)².
    pub u: Complex<f64>,
    /// Its type.
    pub kind: ZeroType,
}

/// The assembled SR4DoF model.
#[derive(Debug, Clone)]
pub struct Sr4dof {
    params: Sr4dofParams,
    alpha: f64,
    mass: Matrix4<f64>,
    stiffness: Matrix4<f64>,
    damping: Matrix4<f64>,
    input: Vector4<f64>,
    rayleigh: (f64, f64),
    modes: [Mode; 4],
    zeros: Vec<Complex<f64>>,
    undamped_zeros: Vec<UndampedZero>,
}

/// Most iterations of an eigenvalue solver (modes, polynomial roots, the
/// loop check's closed-loop poles): a 4×4 or a 30×30 problem converges in
/// a few dozen; non-finite or absurd input would otherwise iterate forever.
pub const MAX_EIGEN_ITERATIONS: usize = 10_000;

impl Sr4dof {
    /// Assembles M and K of Eq. (2-5), solves the generalised eigenproblem
    /// `K φ = ω² M φ` and fits Rayleigh damping.
    ///
    /// # Errors
    /// [`ParamError`] from [`Sr4dofParams::validate`] (keys under `plant.`),
    /// or if the matrices are not positive definite.
    pub fn new(params: Sr4dofParams) -> Result<Self, ParamError> {
        params.validate("plant")?;
        let a = params.alpha();
        let Matrices {
            mass,
            stiffness,
            input,
        } = params.matrices();

        let model_err =
            |what: &str| ParamError::new("plant", format!("{what} (from {})", ranges::MODEL_KEYS));
        let chol = mass
            .cholesky()
            .ok_or_else(|| model_err("mass matrix is not positive definite"))?;
        let l_inv = chol
            .l()
            .try_inverse()
            .ok_or_else(|| model_err("mass matrix is singular"))?;
        // Symmetric standard form A = L⁻¹ K L⁻ᵀ; φ = L⁻ᵀ v is mass-normalised.
        let sym = l_inv * stiffness * l_inv.transpose();
        let sym = (sym + sym.transpose()) * 0.5;
        if sym.iter().any(|v| !v.is_finite()) {
            return Err(model_err("the stiffness and mass matrices are not finite"));
        }
        let eig = SymmetricEigen::try_new(sym, f64::EPSILON, MAX_EIGEN_ITERATIONS)
            .ok_or_else(|| model_err("the modes do not converge"))?;
        let mut order: Vec<usize> = (0..4).collect();
        order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
        let mut modes = [Mode {
            omega_rad_s: 0.0,
            shape: Vector4::zeros(),
            zeta: 0.0,
            residue: 0.0,
        }; 4];
        for (slot, &i) in order.iter().enumerate() {
            let lam = eig.eigenvalues[i];
            if lam <= 0.0 {
                return Err(model_err(
                    "stiffness matrix is not positive definite (a mode has ω² <= 0)",
                ));
            }
            let shape = l_inv.transpose() * eig.eigenvectors.column(i);
            modes[slot] = Mode {
                omega_rad_s: lam.sqrt(),
                shape,
                zeta: 0.0,
                residue: shape[0] * shape.dot(&input),
            };
        }

        // Rayleigh fit: ζ(ω) = a/(2ω) + bω/2 through the X rigid-body mode
        // and the mean of the closely spaced pair.
        let rigid = if modes[0].shape[0].abs() >= modes[1].shape[0].abs() {
            0
        } else {
            1
        };
        let w_r = modes[rigid].omega_rad_s;
        let w_c = 0.5 * (modes[2].omega_rad_s + modes[3].omega_rad_s);
        let (z_r, z_c) = (params.damping.zeta_rigid, params.damping.zeta_csm);
        // Solve [1/(2w_r) w_r/2; 1/(2w_c) w_c/2] [a b]ᵀ = [z_r z_c]ᵀ.
        let det = (w_c / w_r - w_r / w_c) / 4.0;
        let ra = (z_r * w_c / 2.0 - z_c * w_r / 2.0) / det;
        let rb = (z_c / (2.0 * w_r) - z_r / (2.0 * w_c)) / det;
        for m in &mut modes {
            m.zeta = ra / (2.0 * m.omega_rad_s) + rb * m.omega_rad_s / 2.0;
        }
        if modes.iter().any(|m| m.zeta.is_nan() || m.zeta < 0.0) {
            return Err(ParamError::new(
                "plant.damping.zeta_rigid",
                "the Rayleigh fit gives negative modal damping: plant.damping.zeta_rigid and plant.damping.zeta_csm are too far apart",
            ));
        }
        let damping = mass * ra + stiffness * rb;
        let mut model = Self {
            params,
            alpha: a,
            mass,
            stiffness,
            damping,
            input,
            rayleigh: (ra, rb),
            modes,
            zeros: Vec::new(),
            undamped_zeros: Vec::new(),
        };
        model.undamped_zeros = model
            .compute_undamped_zeros()
            .ok_or_else(|| model_err("the zeros of the model do not converge"))?;
        model.zeros = model.compute_zeros();
        Ok(model)
    }

    /// The parameters the model was built from.
    pub fn params(&self) -> &Sr4dofParams {
        &self.params
    }

    /// Coupling coefficient α (Eq. 2-6).
    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    /// Mass matrix M (Eq. 2-5), kg (kg·m for the mixed entries: all
    /// coordinates are lengths, so all entries are kg).
    pub fn mass(&self) -> &Matrix4<f64> {
        &self.mass
    }

    /// Stiffness matrix K (Eq. 2-5), N/m.
    pub fn stiffness(&self) -> &Matrix4<f64> {
        &self.stiffness
    }

    /// Rayleigh damping matrix `C = a M + b K`, N·s/m.
    pub fn damping(&self) -> &Matrix4<f64> {
        &self.damping
    }

    /// Rayleigh coefficients `(a` in 1/s, `b` in s`)`.
    pub fn rayleigh(&self) -> (f64, f64) {
        self.rayleigh
    }

    /// Generalised force per unit actuator force, `q = [1, α, −2α, 0]ᵀ`.
    pub fn input(&self) -> &Vector4<f64> {
        &self.input
    }

    /// The four modes, ascending in frequency.
    pub fn modes(&self) -> &[Mode; 4] {
        &self.modes
    }

    /// Index (0 or 1) of the X rigid-body mode: of the first two modes, the
    /// one whose mass-normalised shape has the larger `|x1|`.
    pub fn rigid_body_mode(&self) -> usize {
        if self.modes[0].shape[0].abs() >= self.modes[1].shape[0].abs() {
            0
        } else {
            1
        }
    }

    /// Force → x1 frequency response at `frequency_hz`, m/N, from the modal
    /// sum `Σ βᵢ / (ωᵢ² − ω² + 2jζᵢωᵢω)` (exact for Rayleigh damping).
    pub fn force_frf(&self, frequency_hz: f64) -> Complex<f64> {
        let w = 2.0 * PI * frequency_hz;
        self.modes
            .iter()
            .map(|m| {
                let wn = m.omega_rad_s;
                m.residue / Complex::new(wn * wn - w * w, 2.0 * m.zeta * wn * w)
            })
            .sum()
    }

    /// Force → x1 frequency response by direct solution of
    /// `(K − ω² M + jω C) z = q`, m/N. Same result as
    /// [`force_frf`](Self::force_frf); kept as an independent check.
    pub fn force_frf_direct(&self, frequency_hz: f64) -> Complex<f64> {
        let w = 2.0 * PI * frequency_hz;
        let dynamic: Matrix4<Complex<f64>> = Matrix4::from_fn(|i, j| {
            Complex::new(
                self.stiffness[(i, j)] - w * w * self.mass[(i, j)],
                w * self.damping[(i, j)],
            )
        });
        let rhs: Vector4<Complex<f64>> = self.input.map(|v| Complex::new(v, 0.0));
        match dynamic.lu().solve(&rhs) {
            Some(z) => z[0],
            None => Complex::new(f64::NAN, f64::NAN),
        }
    }

    /// Coefficients of the undamped numerator `N(u) = Σᵢ βᵢ Πⱼ≠ᵢ (u + ωⱼ²)`
    /// (Eq. 2-7, `u = s²`), highest power first: `[b3, b2, b1, b0]`.
    pub fn undamped_numerator(&self) -> [f64; 4] {
        let mut n = [0.0; 4];
        for (i, mi) in self.modes.iter().enumerate() {
            // Π_{j≠i} (u + ωj²) = u³ + e1 u² + e2 u + e3 with e the
            // elementary symmetric polynomials of the other three ωj².
            let mut p = [1.0, 0.0, 0.0, 0.0];
            let mut deg = 0;
            for (j, mj) in self.modes.iter().enumerate() {
                if i != j {
                    let w2 = mj.omega_rad_s * mj.omega_rad_s;
                    deg += 1;
                    for k in (1..=deg).rev() {
                        p[k] += w2 * p[k - 1];
                    }
                }
            }
            for (acc, c) in n.iter_mut().zip(p) {
                *acc += mi.residue * c;
            }
        }
        n
    }

    /// Discriminant of the cubic `N(u)` (Eq. 2-8):
    /// `Δ = 18 b3 b2 b1 b0 − 4 b2³ b0 + b2² b1² − 4 b3 b1³ − 27 b3² b0²`.
    /// `Δ < 0` ⇔ a complex pair of `u` roots ⇔ CMP-CNMP zeros.
    pub fn cnmp_discriminant(&self) -> f64 {
        let [b3, b2, b1, b0] = self.undamped_numerator();
        18.0 * b3 * b2 * b1 * b0 - 4.0 * b2.powi(3) * b0 + b2 * b2 * b1 * b1
            - 4.0 * b3 * b1.powi(3)
            - 27.0 * b3 * b3 * b0 * b0
    }

    /// Roots `u = s²` of the undamped numerator, classified (Chapter 3).
    pub fn undamped_zeros(&self) -> &[UndampedZero] {
        &self.undamped_zeros
    }

    fn compute_undamped_zeros(&self) -> Option<Vec<UndampedZero>> {
        let scale = self.frequency_scale().powi(2);
        let n = self.undamped_numerator();
        // Scale u = scale · v to keep the coefficients well conditioned.
        let scaled: Vec<f64> = n
            .iter()
            .enumerate()
            .map(|(k, c)| c * scale.powi(3 - k as i32))
            .collect();
        let mut out: Vec<UndampedZero> =
            poly_roots_cubic(&[scaled[0], scaled[1], scaled[2], scaled[3]])?
                .into_iter()
                .map(|v| v * scale)
                .map(|u| {
                    let kind = ZeroType::of_u(u);
                    UndampedZero { u, kind }
                })
                .collect();
        out.sort_by(|a, b| a.u.norm().total_cmp(&b.u.norm()));
        Some(out)
    }

    /// Zeros in `s` (rad/s) of the damped force→x1 transfer function
    /// `G(s) = Σ βᵢ / (s² + 2ζᵢωᵢ s + ωᵢ²)`, ascending in magnitude.
    ///
    /// With Rayleigh damping `C = aM + bK` each modal factor is
    /// `s² + (a + bωᵢ²)s + ωᵢ² = (1 + bs)(λ + ωᵢ²)` with
    /// `λ = (s² + as)/(1 + bs)`, so the degree-6 numerator is
    /// `(1 + bs)³ N(λ)` with `N(u)` the undamped numerator of Eq. (2-7):
    /// each root `u` of `N` gives two damped zeros, the roots of
    /// `s² + (a − bu)s − u = 0` (for `a = b = 0`, `s = ±√u`).
    pub fn zeros(&self) -> &[Complex<f64>] {
        &self.zeros
    }

    fn compute_zeros(&self) -> Vec<Complex<f64>> {
        let (a, b) = self.rayleigh;
        let mut z: Vec<Complex<f64>> = Vec::with_capacity(6);
        for root in &self.undamped_zeros {
            let u = root.u;
            let p = Complex::new(a, 0.0) - u * b;
            let d = (p * p + u * 4.0).sqrt();
            // The larger root without cancellation, the other from the
            // product of the roots (−u).
            let s1 = if (-p).re * d.re + (-p).im * d.im >= 0.0 {
                (-p + d) * 0.5
            } else {
                (-p - d) * 0.5
            };
            let s2 = if s1.norm() > 0.0 { -u / s1 } else { -p - s1 };
            z.push(s1);
            z.push(s2);
        }
        z.sort_by(|a, b| a.norm().total_cmp(&b.norm()));
        z
    }

    /// `true` if the model's transfer function has CMP-CNMP zeros: complex
    /// zeros with positive real part (damped model).
    pub fn has_cnmp_zeros(&self) -> bool {
        self.zeros()
            .iter()
            .any(|z| z.re > 0.0 && z.im.abs() > 1e-6 * z.norm())
    }

    /// Geometric mean of the natural frequencies, rad/s (polynomial scaling).
    fn frequency_scale(&self) -> f64 {
        (self.modes.iter().map(|m| m.omega_rad_s.ln()).sum::<f64>() / 4.0).exp()
    }
}

/// Product of two polynomials, coefficients highest power first.
pub fn poly_mul(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, x) in a.iter().enumerate() {
        for (j, y) in b.iter().enumerate() {
            out[i + j] += x * y;
        }
    }
    out
}

/// Roots of a cubic (coefficients highest power first) as the eigenvalues
/// of its 3×3 companion matrix on the stack: the same method as
/// [`poly_roots`] without a heap allocation per matrix (the map solves
/// tens of thousands). A zero leading coefficient falls back to
/// [`poly_roots`].
pub fn poly_roots_cubic(c: &[f64; 4]) -> Option<Vec<Complex<f64>>> {
    if c[0] == 0.0 {
        return poly_roots(c);
    }
    let mut comp = nalgebra::Matrix3::<f64>::zeros();
    for j in 0..3 {
        comp[(0, j)] = -c[j + 1] / c[0];
    }
    for i in 1..3 {
        comp[(i, i - 1)] = 1.0;
    }
    if comp.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let schur = nalgebra::Schur::try_new(comp, f64::EPSILON, MAX_EIGEN_ITERATIONS)?;
    Some(schur.complex_eigenvalues().iter().copied().collect())
}

/// Roots of a polynomial (coefficients highest power first) as the
/// eigenvalues of its companion matrix. Leading zero coefficients are
/// dropped. `None` if a coefficient is not finite or the eigenvalue
/// iteration does not converge in [`MAX_EIGEN_ITERATIONS`].
pub fn poly_roots(coeffs: &[f64]) -> Option<Vec<Complex<f64>>> {
    let first = coeffs
        .iter()
        .position(|c| *c != 0.0)
        .unwrap_or(coeffs.len());
    let c = &coeffs[first..];
    let n = c.len().saturating_sub(1);
    if n == 0 {
        return Some(Vec::new());
    }
    let mut comp = DMatrix::<f64>::zeros(n, n);
    for j in 0..n {
        comp[(0, j)] = -c[j + 1] / c[0];
    }
    for i in 1..n {
        comp[(i, i - 1)] = 1.0;
    }
    if comp.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let schur = nalgebra::Schur::try_new(comp, f64::EPSILON, MAX_EIGEN_ITERATIONS)?;
    Some(schur.complex_eigenvalues().iter().copied().collect())
}
