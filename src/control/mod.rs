//! Feedback controllers written as the thesis writes them (Eq. 6-6, 6-7):
//! factored continuous-time transfer functions, discretised (Tustin, or
//! matched poles with least-squares numerators) into second-order sections
//! run in f64.
//!
//! Design time and run time are kept apart. `continuous.rs` holds the
//! controller as designed (`[controller.NAME]`, its validation, `C(s)` and
//! its continuous sections); `discretize.rs` turns it into discrete
//! sections and reports how closely they follow it; `section.rs` holds
//! what runs on the tick, the biquads and [`DiscreteController::update`]
//! (allocation-free); [`loop_check`] judges a controller against the plant
//! before anything is enabled, and [`step_metrics`] judges the closed-loop
//! step it then runs (rise, settling, overshoot, steady-state error, from
//! the recorded signals); [`verify`] measures the loop that runs
//! (`bench control --verify`: S, T and PS from a chirp injected at the
//! plant input) and compares it with the loop check's prediction. The
//! items are used through this module.
//!
//! May use `nalgebra` and `bench_plant::model`/`bench_plant::sim` (the plant
//! the loop check closes the loop around); the loop check also reads the
//! `[actuator]`/`[safety]` limits of [`crate::config`] and reports through
//! [`crate::error::RunError`]. Never the loop, the recorder or the daemon.
//!
//! # Continuous form
//! ```text
//! C(s) = g · s^(−n) · Π (s + zᵢ) / Π (s + pⱼ) · Π (s² + 2ζₖωₖ s + ωₖ²) / Π (s² + 2ζₗωₗ s + ωₗ²)
//! ```
//! with `form = "monic"` (Eq. 6-7 as printed), or with every factor divided
//! by its value at `s = 0` (`form = "unity_dc"`: `zᵢ/(s+zᵢ)`-style factors,
//! Eq. 6-6 as printed). Real zeros and poles are given as positive corner
//! frequencies in rad/s (the root is at `−z`); complex pairs as
//! `(omega_rad_s, zeta)`. The controller maps the position error, in
//! `error_unit` (the thesis uses µm), to the current demand in A; the code
//! converts the error from metres explicitly.
//!
//! # Discretisation
//! ## Tustin (`discretization = "tustin"`, the default)
//! The factors are grouped into second-order sections (each complex pole
//! pair, least damped first, with the nearest complex zero pair left, else
//! with the nearest real zeros; remaining real poles and integrators in
//! pairs; the most damped sections run first: see `continuous::sections`,
//! the rule of `scipy.signal.zpk2sos`), and each section is
//! mapped with Tustin's substitution `s = K (1 − z⁻¹)/(1 + z⁻¹)`,
//! pre-warped at the section's own critical frequency,
//! `K = ω_w / tan(ω_w T / 2)`: ω_w is the zero pair's ω for a notch-type
//! section (complex zeros over complex poles), the pole pair's ω for other
//! complex sections, the larger corner for a real lead/lag, and `K = 2/T`
//! (no pre-warp) for sections with integrators. Pre-warping keeps notch
//! centres and lead corners exactly where the continuous design put them;
//! Tustin keeps stability (left half plane → unit disc) and has no phase
//! lag of its own. Each section runs in direct form II transposed.
//!
//! Tustin compresses the frequency axis (`ω_c = (2/T) tan(ω_d T/2)`), so
//! far above the corners the discrete magnitude falls faster than the
//! continuous one, by about `slope × log10(1 + (ωT)²/12)`. At a 5 kHz loop
//! (measured by `frequency_response_matches_the_continuous_controller`):
//! Eq. (6-6) is within 0.1 dB / 1° up to 150 Hz (0.88 dB, 0.08° at 500 Hz);
//! Eq. (6-7) is within 0.1 dB / 1° up to 240 Hz (0.53 dB, 1.3° at 500 Hz).
//! No bilinear map reaches 0.1 dB at f_s/10 on a controller that rolls off
//! there (see `tustin_integrator_droop_at_fs_over_10`).
//!
//! ## Least squares (`discretization = "least_squares"`)
//! Same sections, but each section's poles are matched, `z = e^{pT}` (the
//! integrator at z = 1, exactly), and the numerators `[b0, b1, b2]` of all
//! sections, plus one extra all-zero section (poles at z = 0, three more
//! taps), are fitted to the continuous response `C(jω)` on a log grid of
//! 600 points from f_s/10 · 10⁻⁵ to f_s/10. The error is relative,
//! `C_d(e^{jωT})/C(jω) − 1`. With all other sections held, the product is
//! linear in one section's numerator, so each step is a 3-unknown weighted
//! least-squares problem, solved by SVD. 60 sweeps in plain
//! least squares are followed by 30 with Lawson's
//! reweighting (`w ← w·√(|e|/max|e|)`) towards the minimax fit. This is
//! the fixed-pole step of vector fitting (Gustavsen & Semlyen, 1999) and
//! the idea behind MATLAB's `c2d(..., 'least')`.
//!
//! Poles are matched, so the controller's own stability and its integral
//! action are those of the design. The numerator zeros may lie anywhere,
//! which is harmless in a controller. Above f_s/10 nothing is fitted:
//! [`DiscretizationReport::above_band_max_excess_db`] says how far the
//! gain rises above the design there. The loop check runs on this
//! discrete controller, so that gain is judged. If the fit is worse than
//! Tustin on the 0.1 dB / 1° scale, or fails numerically, Tustin runs and
//! the report says so. The report also states the error up to f_s/4, which is
//! reported, not fitted (issue 45: a fit to f_s/4 cost the loop ten times
//! the accuracy where its margins are read; `docs/src/jobs/control.md`). Eq. (6-6) and (6-7) come within 0.001 dB / 0.004°
//! and 0.003 dB / 0.02° up to 500 Hz at 5 kHz.
//!
//! # Anti-windup and bumpless start
//! The command is clipped to the amplifier's peak current. When it is
//! clipped and the error would drive it further into the limit, the section
//! states are not updated (conditional integration): the integrator cannot
//! wind up while the amplifier saturates. The controller starts from zero
//! state with the setpoint at the measured position, so the first command
//! is 0 A.
//!
//! Layer rule: may use `config`, `error`, `ident`, `input_file`.

mod continuous;
mod discretize;
pub mod loop_check;
mod section;
pub mod step_metrics;
pub mod verify;

pub use crate::config::controller::{
    ComplexPair, ControllerConfig, ControllerError, Discretization, ErrorUnit, Form, CORNER_RAD_S,
    GAIN_ABS, MAX_INTEGRATORS, MAX_SECTIONS, ZETA,
};
pub use discretize::DiscretizationReport;
pub use section::{Biquad, DiscreteController};
