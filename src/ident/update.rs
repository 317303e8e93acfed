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
//!   (`bench_hal::model`); `βᵢ` (1/kg) are its modal residues.
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
use bench_hal::model::{ranges, ParamError, Sr4dof, Sr4dofParams};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

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
}

impl Parameter {
    /// All, in report order.
    pub const ALL: [Self; 6] = [
        Self::ParallelogramStiffness,
        Self::MassAsymmetry,
        Self::ZetaRigid,
        Self::ZetaCsm,
        Self::ForceConstant,
        Self::OperatingPoint,
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
        }
    }

    /// Unit of the value (`1`: dimensionless).
    pub fn unit(self) -> &'static str {
        match self {
            Self::ParallelogramStiffness => "N/m",
            Self::ForceConstant => "N/A",
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
            Self::ParallelogramStiffness | Self::MassAsymmetry | Self::OperatingPoint
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
    /// The six parameters, free and held.
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
    #[error("{0} does not change the natural frequencies (with frequencies only parallelogram_stiffness_n_per_m, mass_asymmetry and operating_point_m can be updated)")]
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

/// The least-squares target.
enum Target<'a> {
    /// Measured natural frequencies, Hz, each paired with a model mode.
    Frequencies {
        measured_hz: &'a [f64],
        mode: Vec<usize>,
    },
    /// A measured FRF; the last fitted coordinate is `τ/T`.
    Frf(&'a Prepared<'a>),
}

/// Per-point FRF data.
struct Prepared<'a> {
    frequency_hz: &'a [f64],
    h: &'a [C64],
    /// Weight of each line (the modal fit's, [`modal_fit::weights`]).
    scale: Vec<f64>,
    /// The weights are inverse standard deviations from the data.
    noise_estimated: bool,
    /// The path without its delay.
    gain: Vec<C64>,
    coherent: Vec<bool>,
    period_s: f64,
}

impl<'a> Prepared<'a> {
    fn new(data: &'a FrfData, path: &Path) -> Self {
        let w = modal_fit::weights(data);
        Self {
            frequency_hz: &data.frequency_hz,
            h: &data.response,
            scale: w.scale,
            noise_estimated: w.noise_estimated,
            gain: data
                .frequency_hz
                .iter()
                .map(|&f| path.response(f, 0.0))
                .collect(),
            coherent: data.coherence.iter().map(|g| *g >= MIN_COHERENCE).collect(),
            period_s: path.period_s,
        }
    }

    /// `G·D` at point `k` for `model`, per N/A of force constant.
    fn g(&self, model: &Sr4dof, k: usize, tau_s: f64) -> C64 {
        let f = self.frequency_hz[k];
        model.force_frf(f) * self.gain[k] * C64::from_polar(1.0, -2.0 * PI * f * tau_s)
    }

    /// Weighted least-squares force constant for `model` and `tau_s`.
    fn best_force_constant(&self, model: &Sr4dof, tau_s: f64) -> f64 {
        let (mut num, mut den) = (0.0, 0.0);
        for k in 0..self.h.len() {
            let g = self.g(model, k, tau_s);
            let s2 = self.scale[k] * self.scale[k];
            num += s2 * (g.conj() * self.h[k]).re;
            den += s2 * g.norm_sqr();
        }
        num / den
    }

    /// RMS relative error over the coherent points.
    fn rms_error(&self, b: &Bench, model: &Sr4dof, tau_s: f64) -> f64 {
        let (mut sum, mut n) = (0.0, 0usize);
        for k in (0..self.h.len()).filter(|&k| self.coherent[k]) {
            let e = self.g(model, k, tau_s) * b.force_constant_n_per_a - self.h[k];
            sum += e.norm_sqr() / self.h[k].norm_sqr();
            n += 1;
        }
        (sum / n.max(1) as f64).sqrt()
    }
}

/// One least-squares problem: the free parameters of `start` against a
/// target.
struct Problem<'a> {
    start: Bench,
    free: &'a [Parameter],
    target: &'a Target<'a>,
    /// The start's coordinates.
    x0: DVector<f64>,
}

impl<'a> Problem<'a> {
    fn new(start: Bench, free: &'a [Parameter], target: &'a Target<'a>, tau_s: f64) -> Self {
        let mut x: Vec<f64> = free
            .iter()
            .map(|p| p.to_x(&start, p.value(&start)))
            .collect();
        if let Target::Frf(prep) = target {
            x.push(tau_s / prep.period_s);
        }
        Self {
            start,
            free,
            target,
            x0: DVector::from_vec(x),
        }
    }

    fn bench_at(&self, x: &DVector<f64>) -> Bench {
        let mut b = self.start;
        for (i, p) in self.free.iter().enumerate() {
            p.set(&mut b, p.value_at_x(&self.start, x[i]));
        }
        b
    }

    fn tau_at(&self, x: &DVector<f64>) -> f64 {
        match self.target {
            Target::Frf(prep) => x[self.free.len()] * prep.period_s,
            Target::Frequencies { .. } => 0.0,
        }
    }

    fn len(&self) -> usize {
        match self.target {
            Target::Frequencies { measured_hz, .. } => measured_hz.len(),
            Target::Frf(prep) => 2 * prep.h.len(),
        }
    }

    /// The residuals at `x`; `None` outside the ranges.
    fn residuals_at(&self, x: &DVector<f64>) -> Option<DVector<f64>> {
        if x.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let b = self.bench_at(x);
        let model = b.model()?;
        let r = match self.target {
            Target::Frequencies { measured_hz, mode } => DVector::from_iterator(
                measured_hz.len(),
                measured_hz
                    .iter()
                    .zip(mode)
                    .map(|(f, &i)| model.modes()[i].frequency_hz() / f - 1.0),
            ),
            Target::Frf(prep) => {
                let tau = self.tau_at(x);
                let mut r = DVector::zeros(2 * prep.h.len());
                for k in 0..prep.h.len() {
                    let e = (prep.g(&model, k, tau) * b.force_constant_n_per_a - prep.h[k])
                        * prep.scale[k];
                    r[2 * k] = e.re;
                    r[2 * k + 1] = e.im;
                }
                r
            }
        };
        r.iter().all(|v| v.is_finite()).then_some(r)
    }

    /// Central-difference Jacobian at `x`.
    fn jacobian_at(&self, x: &DVector<f64>) -> Option<DMatrix<f64>> {
        let mut j = DMatrix::zeros(self.len(), x.len());
        for c in 0..x.len() {
            let h = JACOBIAN_STEP * x[c].abs().max(1.0);
            let (mut xp, mut xm) = (x.clone(), x.clone());
            xp[c] += h;
            xm[c] -= h;
            match (self.residuals_at(&xp), self.residuals_at(&xm)) {
                (Some(rp), Some(rm)) => j.set_column(c, &((rp - rm) / (2.0 * h))),
                // At a range edge: one-sided.
                (Some(rp), None) => j.set_column(c, &((rp - self.residuals_at(x)?) / h)),
                (None, Some(rm)) => j.set_column(c, &((self.residuals_at(x)? - rm) / h)),
                (None, None) => return None,
            }
        }
        Some(j)
    }

    fn cost_at(&self, x: &DVector<f64>) -> f64 {
        self.residuals_at(x)
            .map_or(f64::INFINITY, |r| r.norm_squared())
    }
}

impl Residuals for Problem<'_> {
    fn residuals(&self, x: &DVector<f64>) -> Option<DVector<f64>> {
        // Outside the ranges: a residual larger than any fit's, so that
        // Levenberg-Marquardt shortens the step instead of stopping.
        Some(
            self.residuals_at(x)
                .unwrap_or_else(|| DVector::from_element(self.len(), 1e10)),
        )
    }

    fn jacobian(&self, x: &DVector<f64>) -> Option<DMatrix<f64>> {
        self.jacobian_at(x)
    }
}

/// Minimises from the problem's start; returns the optimum and its cost.
fn minimise(problem: Problem) -> (DVector<f64>, f64) {
    let x0 = problem.x0.clone();
    let c0 = problem.cost_at(&x0);
    let x = lsq::minimise(&problem, x0.clone(), 50);
    let c = problem.cost_at(&x);
    if c <= c0 {
        (x, c)
    } else {
        (x0, c0)
    }
}

/// The 1σ of each coordinate, `s² (JᵀJ)⁻¹` (`None` where not estimable).
/// `s²` is the residual variance per degree of freedom, or with
/// `noise_estimated` (weights that are inverse standard deviations from
/// the data, [`modal_fit::weights`]) `max(1, χ²/ν)`: the noise's own
/// covariance, widened when the model leaves more than the noise.
fn coordinate_sigmas(
    problem: &Problem,
    x: &DVector<f64>,
    cost: f64,
    noise_estimated: bool,
) -> Vec<Option<f64>> {
    let n = x.len();
    let dof = problem.len() as f64 - n as f64;
    let Some(j) = problem.jacobian_at(x).filter(|_| dof > 0.0) else {
        return vec![None; n];
    };
    let s2 = if noise_estimated {
        (cost / dof).max(1.0)
    } else {
        cost / dof
    };
    let jtj = j.transpose() * &j;
    match jtj.try_inverse() {
        Some(cov) => (0..n)
            .map(|i| {
                let v = s2 * cov[(i, i)];
                (v.is_finite() && v >= 0.0).then(|| v.sqrt())
            })
            .collect(),
        None => vec![None; n],
    }
}

/// Every strictly increasing map of `n` measured modes into the model's
/// four.
fn order_preserving(n: usize) -> Vec<Vec<usize>> {
    let mut out = Vec::new();
    for mask in 0u32..16 {
        if mask.count_ones() as usize == n {
            out.push((0..4).filter(|i| mask & (1 << i) != 0).collect());
        }
    }
    out
}

/// The result of step 1: the bench, the model mode of each measured
/// frequency, the cost and the 1σ of each free coordinate.
type FrequencyFit = (Bench, Vec<usize>, f64, Vec<Option<f64>>);

/// Step 1: the frequency-shaping free parameters fitted to `measured_hz`
/// from `start`, with the best order-preserving pairing.
fn fit_frequencies(start: Bench, free: &[Parameter], measured_hz: &[f64]) -> Option<FrequencyFit> {
    let mut best: Option<FrequencyFit> = None;
    for mode in order_preserving(measured_hz.len()) {
        let target = Target::Frequencies { measured_hz, mode };
        let problem = Problem::new(start, free, &target, 0.0);
        let (x, cost) = minimise(problem);
        if !cost.is_finite() || best.as_ref().is_some_and(|b| b.2 <= cost) {
            continue;
        }
        let problem = Problem::new(start, free, &target, 0.0);
        let sig = coordinate_sigmas(&problem, &x, cost, false);
        let bench = problem.bench_at(&x);
        let Target::Frequencies { mode, .. } = target else {
            unreachable!()
        };
        best = Some((bench, mode, cost, sig));
    }
    best
}

fn check_start(start: &Bench) -> Result<Sr4dof, UpdateError> {
    let (lo, hi) = FORCE_CONSTANT_N_PER_A;
    if !(lo..=hi).contains(&start.force_constant_n_per_a) {
        return Err(UpdateError::Start(ParamError::new(
            "actuator.force_constant_n_per_a",
            format!("must be in [{lo}, {hi}] N/A"),
        )));
    }
    Sr4dof::new(start.plant).map_err(UpdateError::Start)
}

fn parameter_report(
    start: &Bench,
    updated: &Bench,
    free: &[Parameter],
    sigma: &[Option<f64>],
) -> Vec<UpdatedParameter> {
    Parameter::ALL
        .iter()
        .map(|&p| {
            let i = free.iter().position(|&q| q == p);
            let value = p.value(updated);
            UpdatedParameter {
                name: p.name().into(),
                key: p.key().into(),
                unit: p.unit().into(),
                free: i.is_some(),
                start: p.value(start),
                value,
                sigma: i
                    .and_then(|i| sigma[i])
                    .map(|s| s * p.dv_dx(start, value).abs()),
            }
        })
        .collect()
}

/// MAC of two real vectors.
fn mac_real(a: &nalgebra::Vector4<f64>, b: &nalgebra::Vector4<f64>) -> f64 {
    let d = a.dot(b);
    d * d / (a.norm_squared() * b.norm_squared())
}

/// MAC of two complex vectors, `|aᴴb|² / (aᴴa · bᴴb)`.
fn mac_complex(a: &[C64], b: &[C64]) -> f64 {
    let d: C64 = a.iter().zip(b).map(|(x, y)| x.conj() * y).sum();
    let na: f64 = a.iter().map(|x| x.norm_sqr()).sum();
    let nb: f64 = b.iter().map(|x| x.norm_sqr()).sum();
    d.norm_sqr() / (na * nb)
}

/// The permutation `p` of the four modes maximising `Σ mac[i][p[i]]`.
fn best_permutation(mac: &[[f64; 4]; 4]) -> [usize; 4] {
    let mut best = ([0, 1, 2, 3], f64::NEG_INFINITY);
    for a in 0..4 {
        for b in (0..4).filter(|&b| b != a) {
            for c in (0..4).filter(|&c| c != a && c != b) {
                let d = 6 - a - b - c;
                let s = mac[0][a] + mac[1][b] + mac[2][c] + mac[3][d];
                if s > best.1 {
                    best = ([a, b, c, d], s);
                }
            }
        }
    }
    best.0
}

/// The injective assignment of model modes to measured modes (or none)
/// that maximises the sum of `mac` over pairs with MAC ≥ [`MIN_PAIR_MAC`].
fn best_assignment(mac: &[Vec<f64>]) -> Vec<Option<usize>> {
    fn go(
        i: usize,
        mac: &[Vec<f64>],
        used: &mut Vec<bool>,
        cur: &mut Vec<Option<usize>>,
        best: &mut (Vec<Option<usize>>, f64),
        sum: f64,
    ) {
        if i == mac.len() {
            if sum > best.1 {
                *best = (cur.clone(), sum);
            }
            return;
        }
        cur.push(None);
        go(i + 1, mac, used, cur, best, sum);
        cur.pop();
        for j in 0..used.len() {
            if !used[j] && mac[i][j] >= MIN_PAIR_MAC {
                used[j] = true;
                cur.push(Some(j));
                go(i + 1, mac, used, cur, best, sum + mac[i][j]);
                cur.pop();
                used[j] = false;
            }
        }
    }
    let n = mac.first().map_or(0, Vec::len);
    let mut best = (vec![None; mac.len()], -1.0);
    go(0, mac, &mut vec![false; n], &mut Vec::new(), &mut best, 0.0);
    best.0
}

/// The updated model's modes, paired with the start's by shape MAC.
fn mode_report(start: &Sr4dof, updated: &Sr4dof, kf: f64) -> (Vec<UpdatedMode>, bool) {
    let (sm, um) = (start.modes(), updated.modes());
    let mut mac = [[0.0; 4]; 4];
    for i in 0..4 {
        for j in 0..4 {
            mac[i][j] = mac_real(&um[i].shape, &sm[j].shape);
        }
    }
    let perm = best_permutation(&mac);
    let modes = (0..4)
        .map(|i| UpdatedMode {
            frequency_hz: um[i].frequency_hz(),
            damping_ratio: um[i].zeta,
            modal_constant: kf * um[i].residue,
            start_mode: perm[i] + 1,
            start_mac: mac[i][perm[i]],
            start_frequency_hz: sm[perm[i]].frequency_hz(),
            measured_frequency_hz: None,
            measured_mac: None,
        })
        .collect();
    (modes, perm[2] == 3 && perm[3] == 2)
}

/// Updates the free parameters of `start` to measured natural
/// frequencies `measured_hz` (ascending, at most four), step 1 of the
/// [module docs](self).
///
/// # Errors
/// [`UpdateError`]: nothing free, a free parameter the frequencies do not
/// determine, fewer frequencies than free parameters or more than four, a
/// start that is no bench, or no fit.
pub fn update_to_frequencies(
    start: &Bench,
    free: &[Parameter],
    measured_hz: &[f64],
) -> Result<Update, UpdateError> {
    if free.is_empty() {
        return Err(UpdateError::NoFreeParameter);
    }
    if let Some(p) = free.iter().find(|p| !p.shapes_frequencies()) {
        return Err(UpdateError::NotFromFrequencies(p.name()));
    }
    if measured_hz.len() > 4 {
        return Err(UpdateError::TooManyFrequencies(measured_hz.len()));
    }
    if measured_hz.len() < free.len() {
        return Err(UpdateError::TooFewFrequencies {
            given: measured_hz.len(),
            free: free.len(),
        });
    }
    let start_model = check_start(start)?;
    let (bench, mode, cost, sig) = fit_frequencies(*start, free, measured_hz)
        .ok_or_else(|| UpdateError::NoFit("no pairing of the frequencies converged".into()))?;
    let model = bench
        .model()
        .ok_or_else(|| UpdateError::NoFit("the result is outside the ranges".into()))?;
    let (mut modes, crossed) = mode_report(&start_model, &model, bench.force_constant_n_per_a);
    for (j, &i) in mode.iter().enumerate() {
        modes[i].measured_frequency_hz = Some(measured_hz[j]);
    }
    let start_err: f64 = measured_hz
        .iter()
        .zip(&mode)
        .map(|(f, &i)| (start_model.modes()[i].frequency_hz() / f - 1.0).powi(2))
        .sum();
    let n = measured_hz.len() as f64;
    let warning = (measured_hz.len() == free.len()).then(|| {
        format!(
            "{} frequencies for {} parameters: no residual is left to estimate the uncertainty",
            measured_hz.len(),
            free.len()
        )
    });
    Ok(Update {
        source: "frequencies".into(),
        parameters: parameter_report(start, &bench, free, &sig),
        modes,
        rms_relative_error: (cost / n).sqrt(),
        start_rms_relative_error: (start_err / n).sqrt(),
        delay_s: None,
        delay_sigma_s: None,
        crossed_veering: crossed,
        cmp_cnmp: model.has_cnmp_zeros(),
        stiffness_over_beam: stiffness_over_beam(&bench),
        warning,
        flags: Vec::new(),
        bench: Some(bench),
    })
}

/// Whether a parameter is determined only by the closely spaced pair
/// (the Y modes' stiffness, the asymmetry, the operating point, and the
/// damping ratio at the pair).
fn needs_the_pair(p: Parameter) -> bool {
    p.shapes_frequencies() || p == Parameter::ZetaCsm
}

/// Updates the free parameters of `start` to the measured FRF `data`
/// (steps 1–4 of the [module docs](self)). `fit` is the modal fit of the
/// same data (`modal_fit::fit`), for the start of step 2 and the pairing;
/// without it step 1 is skipped and `τ` starts at `T/2`.
///
/// **A pair the FRF does not show.** When neither mode of the updated
/// model's closely spaced pair pairs with a fitted mode (MAC ≥
/// [`MIN_PAIR_MAC`]), e.g. near zero operating point where the Y modes
/// barely couple into x1, the parameters only the pair determines
/// (stiffness, asymmetry, operating point, `zeta_csm`) are not measured by
/// this FRF: they are held at their start values, the others refitted, and
/// the warning says so. (Without this, the fit uses the invisible pair to
/// fit noise and reports a wrong stiffness with a small 1σ.)
///
/// # Errors
/// [`UpdateError`]: nothing free, a start that is no bench, too few
/// coherent points, or no fit.
pub fn update_to_frf(
    start: &Bench,
    free: &[Parameter],
    data: &FrfData,
    path: &Path,
    fit: Option<&ModalFit>,
) -> Result<Update, UpdateError> {
    let u = update_frf_once(start, free, data, path, fit)?;
    let pair_seen = u.modes[2..]
        .iter()
        .any(|m| m.measured_frequency_hz.is_some());
    let held: Vec<Parameter> = free
        .iter()
        .copied()
        .filter(|p| needs_the_pair(*p))
        .collect();
    if fit.is_none() || pair_seen || held.is_empty() {
        return Ok(u);
    }
    let names: Vec<&str> = held.iter().map(|p| p.name()).collect();
    let why = format!(
        "the closely spaced pair is not seen in this FRF (no fitted mode pairs with either of its modes): {} not updated, held at the start values",
        names.join(", ")
    );
    let rest: Vec<Parameter> = free
        .iter()
        .copied()
        .filter(|p| !needs_the_pair(*p))
        .collect();
    if rest.is_empty() {
        return Err(UpdateError::NoFit(why));
    }
    let mut u = update_frf_once(start, &rest, data, path, fit)?;
    u.warning = Some(match u.warning {
        Some(w) => format!("{why}; {w}"),
        None => why,
    });
    Ok(u)
}

fn update_frf_once(
    start: &Bench,
    free: &[Parameter],
    data: &FrfData,
    path: &Path,
    fit: Option<&ModalFit>,
) -> Result<Update, UpdateError> {
    if free.is_empty() {
        return Err(UpdateError::NoFreeParameter);
    }
    let start_model = check_start(start)?;
    let lines = modal_fit::independent_lines(data);
    let prep = Prepared::new(&lines, path);
    let coherent = prep.coherent.iter().filter(|c| **c).count();
    if coherent < modal_fit::MIN_POINTS {
        return Err(UpdateError::TooFewCoherentPoints(coherent));
    }
    let tau0 = fit.map_or(0.5 * path.period_s, |f| f.delay_s);

    // Step 1: frequency-shaping parameters to the fitted in-path modes,
    // from several asymmetries.
    let freq_free: Vec<Parameter> = free
        .iter()
        .copied()
        .filter(|p| p.shapes_frequencies())
        .collect();
    let measured = fit.map(measured_modes).unwrap_or_default();
    let mut starts = vec![*start];
    if free.contains(&Parameter::MassAsymmetry) {
        let a0 = start.plant.mass_asymmetry;
        for a in [-a0, a0 - 0.05, a0 + 0.05] {
            let (lo, hi) = ranges::MASS_ASYMMETRY;
            if a > lo
                && a < hi
                && starts
                    .iter()
                    .all(|s| (s.plant.mass_asymmetry - a).abs() > 1e-3)
            {
                let mut s = *start;
                s.plant.mass_asymmetry = a;
                starts.push(s);
            }
        }
    }
    let mut candidates: Vec<Bench> = Vec::new();
    for s in &starts {
        let b = if freq_free.is_empty() || measured.is_empty() {
            *s
        } else {
            fit_frequencies(*s, &freq_free, &measured).map_or(*s, |r| r.0)
        };
        candidates.push(b);
    }
    // Damping from the fitted modes paired by frequency, when free.
    let (zr, zc) = fit.map_or((None, None), |f| fitted_damping(f, &start_model));

    // Step 2: all free parameters and τ to the complex FRF, from the
    // three candidates of lowest cost.
    let target = Target::Frf(&prep);
    let mut scored: Vec<(f64, Bench)> = candidates
        .into_iter()
        .filter_map(|mut b| {
            if free.contains(&Parameter::ZetaRigid) {
                b.plant.damping.zeta_rigid = zr.unwrap_or(b.plant.damping.zeta_rigid);
            }
            if free.contains(&Parameter::ZetaCsm) {
                b.plant.damping.zeta_csm = zc.unwrap_or(b.plant.damping.zeta_csm);
            }
            let m = b.model().or_else(|| {
                b.plant.damping = start.plant.damping;
                b.model()
            })?;
            if free.contains(&Parameter::ForceConstant) {
                let kf = prep.best_force_constant(&m, tau0);
                if kf.is_finite() && kf > 0.0 {
                    b.force_constant_n_per_a = kf;
                }
            }
            let c = Problem::new(b, free, &target, tau0).cost_at(&DVector::from_vec(
                free.iter()
                    .map(|p| p.to_x(&b, p.value(&b)))
                    .chain([tau0 / path.period_s])
                    .collect(),
            ));
            c.is_finite().then_some((c, b))
        })
        .collect();
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut best: Option<(DVector<f64>, f64, Bench)> = None;
    for (_, b) in scored.into_iter().take(3) {
        let (x, cost) = minimise(Problem::new(b, free, &target, tau0));
        if best.as_ref().is_none_or(|(_, c, _)| cost < *c) {
            best = Some((x, cost, b));
        }
    }
    let (x, cost, origin) =
        best.ok_or_else(|| UpdateError::NoFit("no start gave a bench in range".into()))?;
    let problem = Problem::new(origin, free, &target, tau0);
    let bench = problem.bench_at(&x);
    let tau = problem.tau_at(&x);
    let model = bench
        .model()
        .ok_or_else(|| UpdateError::NoFit("the result is outside the ranges".into()))?;
    let sig = coordinate_sigmas(&problem, &x, cost, prep.noise_estimated);
    // The σ of a log or scaled coordinate of `origin` maps to the unit the
    // same way as for `start` (the transforms do not depend on the values).
    let parameters = parameter_report(start, &bench, free, &sig);
    let (mut modes, crossed) = mode_report(&start_model, &model, bench.force_constant_n_per_a);
    if let Some(f) = fit {
        pair_with_fit(&mut modes, f, &prep);
    }
    let rms = prep.rms_error(&bench, &model, tau);
    let mut flags: Vec<String> = Vec::new();
    if let Some(f) = fit.filter(|f| f.quality.checked && !f.quality.flags.is_empty()) {
        flags.push(format!(
            "the modal fit it starts from is flagged ({})",
            f.quality.flags.join("; ")
        ));
    }
    if prep.noise_estimated {
        let nu = (problem.len() as f64 - x.len() as f64).max(1.0);
        let bound = modal_fit::chi2_quantile(nu) / nu;
        if cost / nu > bound {
            flags.push(format!(
                "the updated model leaves more than the estimated noise: χ²/ν = {:.2} over {} lines (bound {bound:.2} at the {} level): the SR4DoF with these free parameters does not explain this FRF",
                cost / nu,
                prep.h.len(),
                modal_fit::RESIDUAL_TEST_LEVEL
            ));
        }
    }
    let mut start_kf = *start;
    start_kf.force_constant_n_per_a = bench.force_constant_n_per_a;
    let start_rms = prep.rms_error(&start_kf, &start_model, tau);
    let mut warning = None;
    if rms > MAX_UPDATE_ERROR {
        warning = Some(format!(
            "the updated model leaves an RMS error of {:.1} % over the coherent band (more than {:.0} %): the SR4DoF model does not explain this FRF",
            100.0 * rms,
            100.0 * MAX_UPDATE_ERROR
        ));
    } else if let Some(p) = parameters
        .iter()
        .find(|p| p.free && p.sigma.is_none_or(|s| s > 0.5 * p.value.abs().max(1e-3)))
    {
        warning = Some(format!(
            "{} is not determined by this FRF (1σ {}): at an operating point near 0 the Y modes barely couple into x1",
            p.name,
            p.sigma.map_or("not estimable".into(), |s| format!("{s:.3e} {}", p.unit))
        ));
    }
    Ok(Update {
        source: "frf".into(),
        parameters,
        modes,
        rms_relative_error: rms,
        start_rms_relative_error: start_rms,
        delay_s: Some(tau),
        delay_sigma_s: sig[free.len()].map(|s| s * path.period_s),
        crossed_veering: crossed,
        cmp_cnmp: model.has_cnmp_zeros(),
        stiffness_over_beam: stiffness_over_beam(&bench),
        warning,
        flags,
        bench: Some(bench),
    })
}

fn stiffness_over_beam(b: &Bench) -> f64 {
    b.plant.parallelogram_stiffness() / b.plant.beam.parallelogram_stiffness_n_per_m()
}

/// The in-path fitted modes step 1 pairs with the model's: at most four,
/// the highest peaks `|A|/(2ζω²)`, ascending in frequency.
fn measured_modes(fit: &ModalFit) -> Vec<f64> {
    let mut m: Vec<(f64, f64)> = fit
        .modes
        .iter()
        .filter(|m| m.in_path)
        .map(|m| {
            let w = 2.0 * PI * m.frequency_hz;
            (
                m.frequency_hz,
                m.modal_constant.abs() / (2.0 * m.damping_ratio.max(1e-6) * w * w),
            )
        })
        .collect();
    m.sort_by(|a, b| b.1.total_cmp(&a.1));
    m.truncate(4);
    let mut f: Vec<f64> = m.into_iter().map(|m| m.0).collect();
    f.sort_by(f64::total_cmp);
    f
}

/// Starting damping ratios from the modal fit: the fitted mode nearest
/// the start model's X rigid-body mode (`zeta_rigid`), and the mean over
/// the fitted modes near the closely spaced pair (`zeta_csm`); each only
/// when a fitted mode lies within 20 %.
fn fitted_damping(fit: &ModalFit, start: &Sr4dof) -> (Option<f64>, Option<f64>) {
    let near = |f0: f64| {
        fit.modes
            .iter()
            .filter(|m| m.in_path && (m.frequency_hz / f0 - 1.0).abs() < 0.2)
            .min_by(|a, b| {
                (a.frequency_hz / f0 - 1.0)
                    .abs()
                    .total_cmp(&(b.frequency_hz / f0 - 1.0).abs())
            })
    };
    let rigid =
        near(start.modes()[start.rigid_body_mode()].frequency_hz()).map(|m| m.damping_ratio);
    let pair: Vec<f64> = [2, 3]
        .iter()
        .filter_map(|&i| near(start.modes()[i].frequency_hz()).map(|m| m.damping_ratio))
        .collect();
    let csm = (!pair.is_empty()).then(|| pair.iter().sum::<f64>() / pair.len() as f64);
    (rigid, csm)
}

/// Pairs the updated modes with the fitted ones by the MAC of their
/// frequency-response contributions over the coherent points.
fn pair_with_fit(modes: &mut [UpdatedMode], fit: &ModalFit, prep: &Prepared) {
    let points: Vec<f64> = (0..prep.h.len())
        .filter(|&k| prep.coherent[k])
        .map(|k| prep.frequency_hz[k])
        .collect();
    let contribution = |f_hz: f64, zeta: f64, a: f64| -> Vec<C64> {
        let wn = 2.0 * PI * f_hz;
        points
            .iter()
            .map(|&f| {
                let w = 2.0 * PI * f;
                C64::new(a, 0.0) / C64::new(wn * wn - w * w, 2.0 * zeta * wn * w)
            })
            .collect()
    };
    let measured: Vec<Vec<C64>> = fit
        .modes
        .iter()
        .map(|m| contribution(m.frequency_hz, m.damping_ratio, m.modal_constant))
        .collect();
    let mac: Vec<Vec<f64>> = modes
        .iter()
        .map(|m| {
            let c = contribution(m.frequency_hz, m.damping_ratio, m.modal_constant);
            measured.iter().map(|d| mac_complex(&c, d)).collect()
        })
        .collect();
    for (i, j) in best_assignment(&mac).into_iter().enumerate() {
        if let Some(j) = j {
            modes[i].measured_frequency_hz = Some(fit.modes[j].frequency_hz);
            modes[i].measured_mac = Some(mac[i][j]);
        }
    }
}

/// The start bench's TOML text with the free parameters set to their
/// updated values: comments, layout and every other key kept, each
/// changed key commented with its start value and 1σ, and `header`
/// (comment lines, each starting with `#`) put on top.
///
/// # Errors
/// The start text does not parse as TOML, or a table the keys belong in
/// is missing.
pub fn updated_toml(start_toml: &str, update: &Update, header: &str) -> Result<String, String> {
    let mut doc: toml_edit::DocumentMut = start_toml
        .parse()
        .map_err(|e: toml_edit::TomlError| format!("the start config: {e}"))?;
    for p in update.parameters.iter().filter(|p| p.free) {
        let mut path: Vec<&str> = p.key.split('.').collect();
        let last = path.pop().unwrap_or_default();
        let mut item = doc.as_item_mut();
        for part in &path {
            item = item
                .get_mut(part)
                .ok_or_else(|| format!("the start config has no {part} table for {}", p.key))?;
        }
        let table = item
            .as_table_like_mut()
            .ok_or_else(|| format!("the start config: {} is not a table", path.join(".")))?;
        let sigma = p
            .sigma
            .map_or("not estimable".into(), |s| format!("{s:.3e}"));
        let mut value = toml_edit::Value::from(p.value);
        // Inline-table members keep no comments; top-level keys do.
        if path.len() == 1 {
            value.decor_mut().set_suffix(format!(
                "  # updated by bench fit: 1 sigma {sigma}, start {}",
                p.start
            ));
        }
        match table.get_mut(last) {
            Some(existing) => {
                if let Some(old) = existing.as_value() {
                    if path.len() > 1 {
                        *value.decor_mut() = old.decor().clone();
                    } else if let Some(prefix) = old.decor().prefix() {
                        value.decor_mut().set_prefix(prefix.clone());
                    }
                }
                *existing = toml_edit::Item::Value(value);
            }
            None => {
                table.insert(last, toml_edit::Item::Value(value));
            }
        }
    }
    Ok(format!("{header}{doc}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn order_preserving_pairings_are_the_combinations() {
        assert_eq!(order_preserving(4), vec![vec![0, 1, 2, 3]]);
        assert_eq!(order_preserving(3).len(), 4);
        assert_eq!(order_preserving(2).len(), 6);
        assert!(order_preserving(3).contains(&vec![0, 1, 3]));
    }

    #[test]
    fn assignment_maximises_the_sum_and_skips_weak_pairs() {
        let mac = vec![vec![0.9, 0.8], vec![0.85, 0.1], vec![0.2, 0.3]];
        // 0→1, 1→0 (0.8 + 0.85) beats 0→0 alone (0.9); 2 pairs with none.
        assert_eq!(best_assignment(&mac), vec![Some(1), Some(0), None]);
    }

    #[test]
    fn names_round_trip() {
        for p in Parameter::ALL {
            assert_eq!(Parameter::from_name(p.name()), Some(p));
            assert!(p.key().ends_with(p.name()));
        }
    }
}
