//! Parameter sets shared by the plant's and the devices' tests: the Table
//! 2-1 mechanism and the Chapter 5 bench, from the thesis.
#![allow(dead_code)]

use bench_plant::model::{Beam, Damping, Sr4dofParams};
use bench_plant::sim::{ActuatorParams, ProbeParams, SimParams};

/// Table 2-1 parameters at operating point `y1o_frac` of L.
pub fn ch2(y1o_frac: f64, dm23: f64, kp: Option<f64>) -> Sr4dofParams {
    Sr4dofParams {
        m1_kg: 0.284,
        m2_kg: 0.018,
        m3_kg: 0.018,
        m4_kg: 0.177,
        m5_kg: 0.177,
        k4_n_per_m: 4.4e3,
        k5_n_per_m: 4.4e3,
        operating_point_m: y1o_frac * 0.0475,
        mass_asymmetry: dm23,
        beam: Beam {
            length_m: 0.0475,
            height_m: 0.025,
            thickness_m: 0.000625,
            youngs_modulus_pa: 6.9e10,
        },
        parallelogram_stiffness_n_per_m: kp,
        damping: Damping {
            zeta_rigid: 0.009,
            zeta_csm: 0.004,
        },
        disturbance: None,
    }
}

/// Chapter 5 bench.
pub fn ch5(y1o_frac: f64, dm23: f64) -> Sr4dofParams {
    Sr4dofParams {
        m1_kg: 0.4,
        m2_kg: 0.06,
        m3_kg: 0.06,
        m4_kg: 0.8,
        m5_kg: 0.8,
        k4_n_per_m: 36e3,
        k5_n_per_m: 36e3,
        beam: Beam {
            height_m: 0.0254,
            ..ch2(0.0, 0.0, None).beam
        },
        ..ch2(y1o_frac, dm23, None)
    }
}

/// The simulated Chapter 5 bench at `y1o_frac` of L, Δm23 = +10 %: BEI Kimco
/// LA24-20-000A voice coil on an MP111 amplifier (§5.2.1), a ±1 mm probe
/// with `noise_rms_m` white noise and no quantisation, the ±1 mm stop.
pub fn ch5_bench(y1o_frac: f64, noise_rms_m: f64, seed: u64) -> SimParams {
    SimParams {
        plant: ch5(y1o_frac, 0.1),
        actuator: ActuatorParams {
            force_constant_n_per_a: 11.12,
            bandwidth_hz: 1000.0,
            peak_current_a: 9.98,
            continuous_current_a: 2.34,
            rated_peak_current_a: 9.98,
            rated_continuous_current_a: 2.34,
        },
        probe: ProbeParams {
            range_m: 1e-3,
            noise_rms_m,
            quantization_m: 0.0,
        },
        mechanical_stop_m: 1e-3,
        seed,
    }
}
