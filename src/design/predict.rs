//! What a designed controller does on the bench's model: its loop figures
//! up to the Nyquist frequency (the band no measurement covers included)
//! and its closed-loop step (`[step]` of the config, noise-free), with the
//! same computation delay the design assumed.

use super::loops::{figures, LoopFigures};
use super::{derr, DesignError};
use crate::config::BenchConfig;
use crate::control::loop_check::model_grid;
use crate::control::step_metrics::{analyze_step, step_profile_m, StepMetrics, StepSignals};
use crate::control::{ControllerConfig, DiscreteController};
use crate::ident::C64;
use bench_hal::model::Sr4dof;
use bench_hal::sim::{ZohPlant, STATES};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// The design on the model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ModelPrediction {
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
    let p = model_frf(cfg, delay_s)?;
    let t = cfg.loop_.period_ns() as f64 * 1e-9;
    let ctrl = DiscreteController::new(controller, t, cfg.actuator.peak_current_a);
    let k = ctrl.error_per_metre();
    let l = p
        .omega_rad_s
        .iter()
        .zip(&p.plant_m_per_a)
        .map(|(&w, p)| ctrl.response(w, t) * p * k)
        .collect();
    Ok((p.omega_rad_s, l))
}

/// The bench's model as one more "FRF" for the certificate: the
/// zero-order-hold plant of `cfg` (m/A) times the computation delay on
/// [`model_grid`].
///
/// # Errors
/// The `[plant]` of `cfg` cannot be modelled.
pub fn model_frf(cfg: &BenchConfig, delay_s: f64) -> Result<super::loops::DesignFrf, DesignError> {
    let model = Sr4dof::new(cfg.plant).map_err(|e| derr("config", e.to_string()))?;
    let t = cfg.loop_.period_ns() as f64 * 1e-9;
    let plant = ZohPlant::new(&model, &cfg.actuator, t);
    let grid = model_grid(t);
    let p = grid
        .iter()
        .map(|&w| plant.frf(w / (2.0 * PI)) * C64::from_polar(1.0, -w * delay_s))
        .collect();
    Ok(super::loops::DesignFrf {
        label: "the config's model".into(),
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
    let (grid, l) = model_loop(cfg, controller, delay_s)?;
    Ok(ModelPrediction {
        figures: figures(&grid, &l, controller.integrators),
        step: predict_step(cfg, controller, delay_s)?,
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
    let model = Sr4dof::new(cfg.plant).map_err(|e| derr("config", e.to_string()))?;
    let t = cfg.loop_.period_ns() as f64 * 1e-9;
    let plant = ZohPlant::new(&model, &cfg.actuator, t);
    let mut ctrl = DiscreteController::new(controller, t, cfg.actuator.peak_current_a);
    let s = &cfg.step;
    let n = (s.duration_s / t).round() as usize;
    let settle = (s.settle_s / t).round() as u64;
    let smooth = (s.smooth_s / t).round() as u64;
    let delay = (delay_s / t).round() as usize;
    let mut queue = vec![0.0; delay + 1];
    let mut x = nalgebra::SVector::<f64, STATES>::zeros();
    let (mut y, mut r, mut u) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    for i in 0..n {
        let setpoint = step_profile_m(i as u64, settle, smooth, s.step_m);
        let pos = x[0];
        let cmd = ctrl.update(setpoint - pos);
        queue[i % (delay + 1)] = cmd;
        let applied = queue[(i + 1) % (delay + 1)];
        y.push(pos);
        r.push(setpoint);
        u.push(cmd);
        plant.step(&mut x, applied, 0.0);
    }
    Ok(analyze_step(
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
    .metrics)
}
