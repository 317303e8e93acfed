//! Model updating: the SR4DoF's physical parameters from a measured FRF
//! or from measured natural frequencies (`bench fit --update`,
//! `bench fit --frequencies`).
//!
//! # Model
//! The measured current → x1 response (m/A) is compared with
//!
//! ```text
//! Ĥ(jω; θ) = k_f · G(jω; θ) · D(jω),   G(jω) = Σᵢ βᵢ / (ωᵢ² − ω² + 2jζᵢωᵢω)
//! ```
//!
//! - `G` (m/N) is the force → x1 response of the lumped model, Eq. 2-5
//!   with Rayleigh damping fitted to `zeta_rigid` and `zeta_csm`
//!   (`bench_plant::model`); `βᵢ` (1/kg) are its modal residues.
//! - `k_f` (N/A) is the voice coil's force constant.
//! - `D` is the path of the modal fit (`modal_fit::Path::response`): the
//!   zero-order hold, the configured amplifier lag and a delay `τ`, fitted
//!   alongside (a nuisance parameter, reported).
//! - `θ` are the free [`Parameter`]s; every other key keeps its value from
//!   the start bench (masses, X bearings, beam, loop).
//!
//! # Method
//! 1. **Frequencies.** The free parameters that shape the natural
//!    frequencies (parallelogram stiffness, mass asymmetry, operating
//!    point) are fitted to the measured natural frequencies by
//!    Levenberg-Marquardt (`levenberg-marquardt` crate, MINPACK's
//!    algorithm) on the relative errors `f_model/f_measured − 1`. A
//!    measured frequency is paired with a model mode by order: the
//!    eigenvalues of the symmetric pencil `(K, M)` never cross, so across
//!    the veering the sorted order is the physical pairing while the mode
//!    *shapes* exchange. With fewer measured modes than the model's four
//!    (a mode hidden when `Δm23 = 0`, or merged), every order-preserving
//!    assignment is tried and the best kept. With `--frequencies` this is
//!    the whole update.
//! 2. **FRF.** From the result of step 1 (started from several mass
//!    asymmetries: the start's, its opposite and ±5 points, since the
//!    frequencies alone leave the side of the veering open), all free
//!    parameters and `τ` are fitted to the complex FRF by
//!    Levenberg-Marquardt on the residual of the modal fit,
//!    `rₖ = wₖ (Ĥₖ − Hₖ)/|Hₖ|` with `wₖ = 1/√((1 − γₖ²)/γₖ² + ε²)`
//!    (coherence-weighted, Bendat & Piersol Eq. 9.90). `k_f` starts at its
//!    linear least-squares value for the start's `G`. The lowest cost wins.
//! 3. **Uncertainty.** `Σ = s² (JᵀJ)⁻¹` at the optimum, `J` by central
//!    differences, `s²` the residual variance per degree of freedom (with
//!    frequencies only: when there are more frequencies than parameters;
//!    otherwise not estimable, reported as `null`).
//! 4. **Pairing by MAC** (reported per mode). Each updated mode is paired
//!    with the start model's mode of the largest MAC of the
//!    mass-normalised shapes over `[x1, y1, y2, y3]` (Allemang, *The modal
//!    assurance criterion*, 2003): when the update moves the bench across
//!    the veering, the pair's shapes exchange and the pairing says so.
//!    With an FRF, each updated mode is also paired with a mode of the
//!    modal fit by the MAC of the two modes' frequency-response
//!    contributions over the coherent band (one measured output, so the
//!    "shape" is the contribution `Aᵢ/(ωᵢ² − ω² + 2jζᵢωᵢω)` over
//!    frequency), at least [`MIN_PAIR_MAC`], the assignment that maximises
//!    the sum.

use super::frf::{C64, MIN_COHERENCE};
use super::lsq::{self, Residuals};
use super::modal_fit::{self, FrfData, ModalFit, Path};
use bench_hal::param::ParamError;
use bench_plant::model::{ranges, Sr4dof, Sr4dofParams};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

mod config_text;
mod pairing;
mod problem;
mod solve;
pub use config_text::*;
use pairing::*;
use problem::*;
pub use solve::*;

/// Force constant range, N/A (the `actuator.force_constant_n_per_a` key).
pub const FORCE_CONSTANT_N_PER_A: (f64, f64) = (0.01, 1000.0);

/// Smallest frequency-response MAC for a measured mode to pair with a
/// model mode.
pub const MIN_PAIR_MAC: f64 = 0.5;

/// Above this RMS relative error over the coherent band the updated model
/// does not explain the FRF, and the result says so.
pub const MAX_UPDATE_ERROR: f64 = 0.1;

/// Relative step of the central-difference Jacobian (in the transformed
/// parameters).
const JACOBIAN_STEP: f64 = 1e-6;

/// A parameter of the bench that the update may fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Parameter {
    /// `plant.parallelogram_stiffness_n_per_m`, N/m.
    ParallelogramStiffness,
    /// `plant.mass_asymmetry`, fraction.
    MassAsymmetry,
    /// `plant.damping.zeta_rigid`.
    ZetaRigid,
    /// `plant.damping.zeta_csm`.
    ZetaCsm,
    /// `actuator.force_constant_n_per_a`, N/A.
    ForceConstant,
    /// `plant.operating_point_m`, m.
    OperatingPoint,
    /// `plant.m1_kg`, kg: the motion stage's mass.
    StageMass,
    /// `plant.k4_n_per_m`, N/m: the X bearings' stiffness, `k5_n_per_m`
    /// kept in its ratio to it.
    BearingStiffness,
}

impl Parameter {
    /// All, in report order.
    pub const ALL: [Self; 8] = [
        Self::ParallelogramStiffness,
        Self::MassAsymmetry,
        Self::ZetaRigid,
        Self::ZetaCsm,
        Self::ForceConstant,
        Self::OperatingPoint,
        Self::StageMass,
        Self::BearingStiffness,
    ];
    /// Free by default when fitting an FRF (the operating point is set on
    /// the bench, so it is known unless asked for).
    pub const FRF_DEFAULT: [Self; 5] = [
        Self::ParallelogramStiffness,
        Self::MassAsymmetry,
        Self::ZetaRigid,
        Self::ZetaCsm,
        Self::ForceConstant,
    ];
    /// Free by default when fitting natural frequencies.
    pub const FREQUENCIES_DEFAULT: [Self; 1] = [Self::ParallelogramStiffness];

    /// Name as `--free` takes it (the last part of the key).
    pub fn name(self) -> &'static str {
        match self {
            Self::ParallelogramStiffness => "parallelogram_stiffness_n_per_m",
            Self::MassAsymmetry => "mass_asymmetry",
            Self::ZetaRigid => "zeta_rigid",
            Self::ZetaCsm => "zeta_csm",
            Self::ForceConstant => "force_constant_n_per_a",
            Self::OperatingPoint => "operating_point_m",
            Self::StageMass => "m1_kg",
            Self::BearingStiffness => "k4_n_per_m",
        }
    }

    /// The config key.
    pub fn key(self) -> &'static str {
        match self {
            Self::ParallelogramStiffness => "plant.parallelogram_stiffness_n_per_m",
            Self::MassAsymmetry => "plant.mass_asymmetry",
            Self::ZetaRigid => "plant.damping.zeta_rigid",
            Self::ZetaCsm => "plant.damping.zeta_csm",
            Self::ForceConstant => "actuator.force_constant_n_per_a",
            Self::OperatingPoint => "plant.operating_point_m",
            Self::StageMass => "plant.m1_kg",
            Self::BearingStiffness => "plant.k4_n_per_m",
        }
    }

    /// Unit of the value (`1`: dimensionless).
    pub fn unit(self) -> &'static str {
        match self {
            Self::ParallelogramStiffness | Self::BearingStiffness => "N/m",
            Self::ForceConstant => "N/A",
            Self::StageMass => "kg",
            Self::OperatingPoint => "m",
            _ => "1",
        }
    }

    /// Parses a name of [`Parameter::name`].
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.name() == name)
    }

    /// Whether the natural frequencies depend on it.
    pub fn shapes_frequencies(self) -> bool {
        matches!(
            self,
            Self::ParallelogramStiffness
                | Self::MassAsymmetry
                | Self::OperatingPoint
                | Self::StageMass
                | Self::BearingStiffness
        )
    }

    /// Its value in `b`, in the unit of [`Parameter::unit`].
    pub fn value(self, b: &Bench) -> f64 {
        match self {
            Self::ParallelogramStiffness => b.plant.parallelogram_stiffness(),
            Self::MassAsymmetry => b.plant.mass_asymmetry,
            Self::ZetaRigid => b.plant.damping.zeta_rigid,
            Self::ZetaCsm => b.plant.damping.zeta_csm,
            Self::ForceConstant => b.force_constant_n_per_a,
            Self::OperatingPoint => b.plant.operating_point_m,
            Self::StageMass => b.plant.m1_kg,
            Self::BearingStiffness => b.plant.k4_n_per_m,
        }
    }

    fn set(self, b: &mut Bench, v: f64) {
        match self {
            Self::ParallelogramStiffness => b.plant.parallelogram_stiffness_n_per_m = Some(v),
            Self::MassAsymmetry => b.plant.mass_asymmetry = v,
            Self::ZetaRigid => b.plant.damping.zeta_rigid = v,
            Self::ZetaCsm => b.plant.damping.zeta_csm = v,
            Self::ForceConstant => b.force_constant_n_per_a = v,
            Self::OperatingPoint => b.plant.operating_point_m = v,
            Self::StageMass => b.plant.m1_kg = v,
            Self::BearingStiffness => {
                // Both bearings scale together: their ratio is the start's.
                let ratio = b.plant.k5_n_per_m / b.plant.k4_n_per_m;
                b.plant.k4_n_per_m = v;
                b.plant.k5_n_per_m = v * ratio;
            }
        }
    }

    /// The fitted coordinate: the logarithm of the positive parameters,
    /// the asymmetry as is, the operating point over the beam length.
    fn to_x(self, b: &Bench, v: f64) -> f64 {
        match self {
            Self::MassAsymmetry => v,
            Self::OperatingPoint => v / b.plant.beam.length_m,
            // A damping ratio of 0 is in range; the fit starts it at 1e-4.
            _ => v.max(1e-4).ln(),
        }
    }

    fn value_at_x(self, b: &Bench, x: f64) -> f64 {
        match self {
            Self::MassAsymmetry => x,
            Self::OperatingPoint => x * b.plant.beam.length_m,
            _ => x.exp(),
        }
    }

    /// `dv/dx` at `v` (to carry the 1σ to the parameter's unit).
    fn dv_dx(self, b: &Bench, v: f64) -> f64 {
        match self {
            Self::MassAsymmetry => 1.0,
            Self::OperatingPoint => b.plant.beam.length_m,
            _ => v,
        }
    }
}

/// What the update changes: the `[plant]` table and the force constant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bench {
    /// The mechanism.
    pub plant: Sr4dofParams,
    /// Voice-coil force constant, N/A.
    pub force_constant_n_per_a: f64,
}

impl Bench {
    /// The model, if the parameters describe a bench (ranges of
    /// `Sr4dofParams::validate` and [`FORCE_CONSTANT_N_PER_A`]).
    fn model(&self) -> Option<Sr4dof> {
        let (lo, hi) = FORCE_CONSTANT_N_PER_A;
        if !(lo..=hi).contains(&self.force_constant_n_per_a) {
            return None;
        }
        Sr4dof::new(self.plant).ok()
    }
}

/// One parameter after the update.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct UpdatedParameter {
    /// Name ([`Parameter::name`]).
    pub name: String,
    /// Config key.
    pub key: String,
    /// Unit of `start`, `value`, `sigma` (`1`: dimensionless; the mass
    /// asymmetry is a fraction, 0.01 = 1 %).
    pub unit: String,
    /// Whether it was fitted (else held at `start`).
    pub free: bool,
    /// Value in the start bench.
    pub start: f64,
    /// Updated value.
    pub value: f64,
    /// 1σ, `null` when held or not estimable.
    pub sigma: Option<f64>,
}

/// One mode of the updated model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct UpdatedMode {
    /// Natural frequency, Hz.
    pub frequency_hz: f64,
    /// Modal damping ratio (Rayleigh).
    pub damping_ratio: f64,
    /// Modal constant `k_f βᵢ`, m/(A·s²) (sign: the mode's direction).
    pub modal_constant: f64,
    /// The start model's mode (1-based, by frequency) this mode continues:
    /// the largest MAC of the mass-normalised shapes.
    pub start_mode: usize,
    /// That MAC, 0 … 1.
    pub start_mac: f64,
    /// The start mode's natural frequency, Hz.
    pub start_frequency_hz: f64,
    /// The measured natural frequency paired with it, Hz (`null`: none).
    pub measured_frequency_hz: Option<f64>,
    /// The frequency-response MAC of that pairing (`null` with
    /// `--frequencies`, where pairing is by order).
    pub measured_mac: Option<f64>,
}

/// The result of an update (as JSON without [`Update::bench`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Update {
    /// `frf` or `frequencies`.
    pub source: String,
    /// The eight parameters, free and held.
    pub parameters: Vec<UpdatedParameter>,
    /// The four modes of the updated model, ascending.
    pub modes: Vec<UpdatedMode>,
    /// FRF: RMS of `|Ĥ − H|/|H|` over the points with γ² ≥ 0.5.
    /// Frequencies: RMS of `f_model/f_measured − 1`.
    pub rms_relative_error: f64,
    /// The same with the start bench (FRF: with `k_f` and `τ` of the
    /// update, so that it measures the mechanics).
    pub start_rms_relative_error: f64,
    /// Fitted path delay `τ`, s (FRF only).
    pub delay_s: Option<f64>,
    /// Its 1σ, s.
    pub delay_sigma_s: Option<f64>,
    /// The pair's shapes exchanged between the start and the updated
    /// model: the update crossed the veering.
    pub crossed_veering: bool,
    /// The updated model has CMP-CNMP zeros.
    pub cmp_cnmp: bool,
    /// The updated parallelogram stiffness over `24 E I / L³` of the
    /// configured beam (the correction the calibration of the README
    /// derives), dimensionless.
    pub stiffness_over_beam: f64,
    /// Why the result should not be trusted, when it should not (the
    /// model does not explain the data, or a parameter is not determined).
    pub warning: Option<String>,
    /// Why this update is not to be trusted (issue 28, no silent wrong
    /// answer): the modal fit it started from is flagged
    /// ([`ModalFit::trusted`]), or the updated model leaves more than the
    /// estimated noise (the χ² test of [`modal_fit::FitQuality`] on its
    /// residual). Empty: trusted. `bench fit --update` writes no config
    /// from a flagged update.
    #[serde(default)]
    pub flags: Vec<String>,
    /// The updated bench (`None` in an update read back from JSON, which
    /// does not carry it).
    #[serde(skip)]
    #[schemars(skip)]
    pub bench: Option<Bench>,
}

/// Why no update could be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum UpdateError {
    /// Nothing is free.
    #[error("no parameter to update")]
    NoFreeParameter,
    /// A parameter the frequencies do not determine.
    #[error("{0} does not change the natural frequencies (with frequencies only parallelogram_stiffness_n_per_m, mass_asymmetry, operating_point_m, m1_kg and k4_n_per_m can be updated)")]
    NotFromFrequencies(&'static str),
    /// Fewer frequencies than parameters.
    #[error("{given} natural frequencies for {free} free parameters: give at least one frequency per parameter")]
    TooFewFrequencies {
        /// Frequencies given.
        given: usize,
        /// Free parameters.
        free: usize,
    },
    /// More frequencies than the model has modes.
    #[error("{0} natural frequencies, but the SR4DoF model has 4 modes")]
    TooManyFrequencies(usize),
    /// The start bench is not a model.
    #[error("the start bench: {0}")]
    Start(ParamError),
    /// Too little coherent data.
    #[error("the FRF has {0} points with coherence >= {MIN_COHERENCE}; the update needs at least {min}", min = modal_fit::MIN_POINTS)]
    TooFewCoherentPoints(usize),
    /// The least-squares problem gave no physical bench.
    #[error("the update found no bench that fits: {0}")]
    NoFit(String),
}

#[cfg(test)]
mod tests;
