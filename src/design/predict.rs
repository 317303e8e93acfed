//! What a designed controller does on the bench's model: its loop figures
//! up to the Nyquist frequency (the band no measurement covers included)
//! and its closed-loop step (`[step]` of the config, noise-free), with the
//! same computation delay the design assumed.
//!
//! The model is the bench's own ([`BenchModel::Fitted`]: the modal fit of
//! a measured input, [`super::fitted`]) unless a config's lumped model is
//! asked for ([`BenchModel::Config`], `bench design --model config`): a
//! lab's config is a nominal description, its measurement is the truth.

use super::fitted::FittedPlant;
use super::loops::{figures, LoopFigures};
use super::{derr, DesignError};
use crate::config::BenchConfig;
use crate::control::loop_check::{model_grid, resolving};
use crate::control::step_metrics::{analyze_step, step_profile_m, StepMetrics, StepSignals};
use crate::control::{ControllerConfig, DiscreteController};
use crate::ident::C64;
use bench_plant::model::Sr4dof;
use bench_plant::sim::{ZohPlant, STATES};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// The model a design is predicted and certified on.
#[derive(Debug, Clone, Copy)]
pub enum BenchModel<'a> {
    /// The modal fit of the measured input named `input`.
    Fitted {
        /// The input's label.
        input: &'a str,
        /// Its fit as a plant.
        plant: &'a FittedPlant,
    },
    /// The lumped model (thesis Eq. 2-5) of the config read from `source`.
    Config {
        /// Where the config came from.
        source: &'a str,
    },
}

impl BenchModel<'_> {
    /// The model's name in reports: `the fit of INPUT (N modes, RMS
    /// error E %)` or `the config's model (SOURCE)`.
    pub fn name(&self) -> String {
        match self {
            Self::Fitted { input, plant } => format!(
                "the fit of {input} ({} modes, RMS error {:.2} %)",
                plant.fit().modes.len(),
                100.0 * plant.fit().rms_relative_error
            ),
            Self::Config { source } => format!("the config's model ({source})"),
        }
    }
}

/// The design on the model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ModelPrediction {
    /// The model predicted on ([`BenchModel::name`]).
    #[serde(default)]
    pub model: String,
    /// Loop figures on the model (zero-order hold, amplifier, computation
    /// delay), 0.1 rad/s to Nyquist.
    pub figures: LoopFigures,
    /// The noise-free closed-loop step of `[step]`.
    pub step: StepMetrics,
}

/// The model loop `L = C_d · P_zoh · e^{−jωτ}` of `controller` on `cfg`'s
/// bench, on [`model_grid`], rad/s and dimensionless.
///
/// # Errors
/// The `[plant]` of `cfg` cannot be modelled.
pub fn model_loop(
    cfg: &BenchConfig,
    controller: &ControllerConfig,
    delay_s: f64,
) -> Result<(Vec<f64>, Vec<C64>), DesignError> {
    model_loop_on(BenchModel::Config { source: "" }, cfg, controller, delay_s)
}

/// The loop `L = C_d · P · e^{−jωτ}` of `controller` on `model` (the
/// loop rate and amplifier limit from `cfg`), on [`model_grid`] with the
/// controller's lightly damped poles resolved ([`resolving`]), rad/s and
/// dimensionless.
///
/// # Errors
/// A config model whose `[plant]` cannot be modelled.
pub fn model_loop_on(
    model: BenchModel<'_>,
    cfg: &BenchConfig,
    controller: &ControllerConfig,
    delay_s: f64,
) -> Result<(Vec<f64>, Vec<C64>), DesignError> {
    let t = cfg.loop_.period_ns() as f64 * 1e-9;
    let ctrl = DiscreteController::new(controller, t, cfg.actuator.peak_current_a);
    let grid = resolving(&model_grid(t), &ctrl.resonances(t));
    let p = model_frf_at(model, cfg, delay_s, grid)?;
    let k = ctrl.error_per_metre();
    let l = p
        .omega_rad_s
        .iter()
        .zip(&p.plant_m_per_a)
        .map(|(&w, p)| ctrl.response(w, t) * p * k)
        .collect();
    Ok((p.omega_rad_s, l))
}

/// The config's model as one more "FRF" for the certificate: the
/// zero-order-hold plant of `cfg` (m/A) times the computation delay on
/// [`model_grid`].
///
/// # Errors
/// The `[plant]` of `cfg` cannot be modelled.
pub fn model_frf(cfg: &BenchConfig, delay_s: f64) -> Result<super::loops::DesignFrf, DesignError> {
    model_frf_on(BenchModel::Config { source: "" }, cfg, delay_s)
}

/// `model` as one more "FRF" for the certificate: its plant (m/A, hold
/// and amplifier included) times the computation delay `delay_s` on
/// [`model_grid`] of `cfg`'s loop period, labelled with
/// [`BenchModel::name`].
///
/// # Errors
/// A config model whose `[plant]` cannot be modelled.
pub fn model_frf_on(
    model: BenchModel<'_>,
    cfg: &BenchConfig,
    delay_s: f64,
) -> Result<super::loops::DesignFrf, DesignError> {
    let t = cfg.loop_.period_ns() as f64 * 1e-9;
    model_frf_at(model, cfg, delay_s, model_grid(t))
}

/// [`model_frf_on`] on `grid` (rad/s, ascending).
fn model_frf_at(
    model: BenchModel<'_>,
    cfg: &BenchConfig,
    delay_s: f64,
    grid: Vec<f64>,
) -> Result<super::loops::DesignFrf, DesignError> {
    let t = cfg.loop_.period_ns() as f64 * 1e-9;
    let delay = |w: f64| C64::from_polar(1.0, -w * delay_s);
    let p: Vec<C64> = match model {
        BenchModel::Fitted { plant, .. } => grid.iter().map(|&w| plant.frf(w) * delay(w)).collect(),
        BenchModel::Config { .. } => {
            let m = Sr4dof::new(cfg.plant).map_err(|e| derr("config", e.to_string()))?;
            let plant = ZohPlant::new(&m, &cfg.actuator, t);
            grid.iter()
                .map(|&w| plant.frf(w / (2.0 * PI)) * delay(w))
                .collect()
        }
    };
    Ok(super::loops::DesignFrf {
        label: match model {
            BenchModel::Config { source: "" } => "the config's model".into(),
            m => m.name(),
        },
        lines_total: grid.len(),
        omega_rad_s: grid,
        plant_m_per_a: p,
    })
}

/// The prediction of `controller` on `cfg`'s model with the computation
/// delay `delay_s`: the loop figures to Nyquist and [`predict_step`].
///
/// # Errors
/// The `[plant]` of `cfg` cannot be modelled.
pub fn predict(
    cfg: &BenchConfig,
    controller: &ControllerConfig,
    delay_s: f64,
) -> Result<ModelPrediction, DesignError> {
    predict_on(BenchModel::Config { source: "" }, cfg, controller, delay_s)
}

/// The prediction of `controller` on `model` (the loop, the amplifier and
/// `[step]` from `cfg`) with the computation delay `delay_s`: the loop
/// figures to Nyquist and the step ([`predict_step_on`]).
///
/// # Errors
/// A config model whose `[plant]` cannot be modelled.
pub fn predict_on(
    model: BenchModel<'_>,
    cfg: &BenchConfig,
    controller: &ControllerConfig,
    delay_s: f64,
) -> Result<ModelPrediction, DesignError> {
    let (grid, l) = model_loop_on(model, cfg, controller, delay_s)?;
    Ok(ModelPrediction {
        model: model.name(),
        figures: figures(&grid, &l, controller.integrators),
        step: predict_step_on(model, cfg, controller, delay_s)?,
    })
}

/// The noise-free closed-loop step of `[step]` on `cfg`'s model
/// (zero-order-hold plant with the amplifier), the command applied
/// `delay_s` later (whole periods), judged by the step job's metrics.
///
/// # Errors
/// The `[plant]` of `cfg` cannot be modelled.
pub fn predict_step(
    cfg: &BenchConfig,
    controller: &ControllerConfig,
    delay_s: f64,
) -> Result<StepMetrics, DesignError> {
    predict_step_on(BenchModel::Config { source: "" }, cfg, controller, delay_s)
}

/// The noise-free closed-loop step of `cfg`'s `[step]` on `model`
/// (zero-order-hold plant with the amplifier; a fit with its own delay),
/// the command applied `delay_s` later (whole periods), judged by the
/// step job's metrics.
///
/// # Errors
/// A config model whose `[plant]` cannot be modelled.
pub fn predict_step_on(
    model: BenchModel<'_>,
    cfg: &BenchConfig,
    controller: &ControllerConfig,
    delay_s: f64,
) -> Result<StepMetrics, DesignError> {
    let t = cfg.loop_.period_ns() as f64 * 1e-9;
    match model {
        BenchModel::Fitted { plant, .. } => Ok(closed_loop_step(
            cfg,
            controller,
            delay_s,
            &mut plant.simulation(),
        )),
        BenchModel::Config { .. } => {
            let m = Sr4dof::new(cfg.plant).map_err(|e| derr("config", e.to_string()))?;
            let mut sim = ConfigSimulation {
                plant: ZohPlant::new(&m, &cfg.actuator, t),
                x: nalgebra::SVector::<f64, STATES>::zeros(),
            };
            Ok(closed_loop_step(cfg, controller, delay_s, &mut sim))
        }
    }
}

struct ConfigSimulation {
    plant: ZohPlant,
    x: nalgebra::SVector<f64, STATES>,
}

impl Plant for ConfigSimulation {
    fn position_m(&self) -> f64 {
        self.x[0]
    }
    fn apply(&mut self, current_a: f64) {
        self.plant.step(&mut self.x, current_a, 0.0);
    }
}

impl Plant for super::fitted::Simulation<'_> {
    fn position_m(&self) -> f64 {
        super::fitted::Simulation::position_m(self)
    }
    fn apply(&mut self, current_a: f64) {
        super::fitted::Simulation::apply(self, current_a);
    }
}

/// A plant simulated period by period.
trait Plant {
    /// The position at the start of the period, m.
    fn position_m(&self) -> f64;
    /// The demand held over the period, A.
    fn apply(&mut self, current_a: f64);
}

/// The step of `cfg.step` in closed loop with `plant`, which takes the
/// demand applied over one period (A) and returns the position at that
/// period's start (m).
fn closed_loop_step(
    cfg: &BenchConfig,
    controller: &ControllerConfig,
    delay_s: f64,
    plant: &mut dyn Plant,
) -> StepMetrics {
    let t = cfg.loop_.period_ns() as f64 * 1e-9;
    let mut ctrl = DiscreteController::new(controller, t, cfg.actuator.peak_current_a);
    let s = &cfg.step;
    let n = (s.duration_s / t).round() as usize;
    let settle = (s.settle_s / t).round() as u64;
    let smooth = (s.smooth_s / t).round() as u64;
    let delay = (delay_s / t).round() as usize;
    let mut queue = vec![0.0; delay + 1];
    let (mut y, mut r, mut u) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    // Each period: the position now, the command from it, the command of
    // `delay` periods ago applied over the period.
    for i in 0..n {
        let pos = plant.position_m();
        let setpoint = step_profile_m(i as u64, settle, smooth, s.step_m);
        let cmd = ctrl.update(setpoint - pos);
        queue[i % (delay + 1)] = cmd;
        let applied = queue[(i + 1) % (delay + 1)];
        y.push(pos);
        r.push(setpoint);
        u.push(cmd);
        plant.apply(applied);
    }
    analyze_step(
        StepSignals {
            position_m: &y,
            setpoint_m: &r,
            current_command_a: &u,
        },
        s.settle_s,
        s.step_m,
        s.steady_state_window_s,
        t,
    )
    .metrics
}
