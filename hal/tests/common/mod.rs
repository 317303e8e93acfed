//! Parameter sets shared by the hal tests: the Table 2-1 mechanism and the
//! Chapter 5 bench, from the thesis.
#![allow(dead_code)]

use bench_hal::model::{Beam, Damping, Sr4dofParams};

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
