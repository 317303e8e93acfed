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
//!
//! Layer rule: may use nothing of the crate.

use bench_hal::param::{within, ParamError};
use nalgebra::{Complex, DMatrix, Matrix4, SymmetricEigen, Vector4};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

mod poly;
mod sr4dof;
pub use poly::*;
pub use sr4dof::*;

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

impl Sr4dofParams {
    /// Checks every value against its documented range ([`ranges`]);
    /// `prefix` is prepended to key names (e.g. `"plant"`). The disturbance
    /// band's upper edge is checked against the loop's Nyquist frequency by
    /// the caller (the model does not know the loop rate).
    ///
    /// # Errors
    /// The first offending key with the reason.
    pub fn validate(&self, prefix: &str) -> Result<(), ParamError> {
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
        self.validate_beam(prefix)?;
        let b = &self.beam;
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
            validate_disturbance(d, prefix)?;
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

    /// The beam's checks of [`Self::validate`]: its dimensions, its
    /// modulus, and the parallelogram stiffness given or made from them.
    fn validate_beam(&self, prefix: &str) -> Result<(), ParamError> {
        let k = |name| Key(prefix, name);
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

/// A dotted config key (`PREFIX.NAME`), formatted only when a check fails.
struct Key<'a>(&'a str, &'a str);

impl std::fmt::Display for Key<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}.{}", self.0, self.1)
    }
}

/// The disturbance's checks of [`Sr4dofParams::validate`]: its RMS force and
/// its band.
fn validate_disturbance(d: &Disturbance, prefix: &str) -> Result<(), ParamError> {
    let k = |name| Key(prefix, name);
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
    Ok(())
}
