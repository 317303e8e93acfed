//! What runs on the tick: the discrete sections (direct form II
//! transposed) and [`DiscreteController::update`], with the anti-windup and
//! the bumpless start (see *Anti-windup and bumpless start* in
//! [`crate::control`]). `update` allocates, locks and logs nothing (the
//! `alloc` integration test counts its allocations on the tick). The
//! realisation and the response of the cascade (for the loop check) sit
//! beside it.

use super::discretize::{cascade_response, discretize};
use super::{ControllerConfig, DiscretizationReport, MAX_SECTIONS};
use nalgebra::{Complex, DMatrix};

/// One discrete biquad in direct form II transposed:
/// `y = b0 x + s1; s1 = b1 x − a1 y + s2; s2 = b2 x − a2 y`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Biquad {
    /// Numerator `[b0, b1, b2]`.
    pub b: [f64; 3],
    /// Denominator `[1, a1, a2]` (stored as `[a1, a2]`).
    pub a: [f64; 2],
}

impl Biquad {
    /// Frequency response at `z = e^{jθ}`.
    pub fn response(&self, theta: f64) -> Complex<f64> {
        let z1 = Complex::from_polar(1.0, -theta);
        let z2 = z1 * z1;
        (z1 * self.b[1] + z2 * self.b[2] + self.b[0]) / (z1 * self.a[0] + z2 * self.a[1] + 1.0)
    }
}

/// The discrete controller run on the tick: gain × cascade of biquads, with
/// the error converted from metres and the output clipped with conditional
/// integration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiscreteController {
    sections: [Biquad; MAX_SECTIONS],
    n: usize,
    gain: f64,
    error_per_metre: f64,
    state: [[f64; 2]; MAX_SECTIONS],
    limit_a: f64,
    saturated: bool,
    report: DiscretizationReport,
}

impl DiscreteController {
    /// Discretises `cfg` at `period_s` with output limit `limit_a` (A).
    /// The config must have passed [`ControllerConfig::validate`].
    pub fn new(cfg: &ControllerConfig, period_s: f64, limit_a: f64) -> Self {
        let (biquads, report) = discretize(cfg, period_s);
        let mut sections = [Biquad::default(); MAX_SECTIONS];
        for (slot, s) in sections.iter_mut().zip(&biquads) {
            *slot = *s;
        }
        Self {
            sections,
            n: biquads.len().min(MAX_SECTIONS),
            gain: cfg.gain,
            error_per_metre: cfg.error_unit.per_metre(),
            state: [[0.0; 2]; MAX_SECTIONS],
            limit_a,
            saturated: false,
            report,
        }
    }

    /// The same controller with the output clipped at `limit_a` (A).
    pub fn with_limit(self, limit_a: f64) -> Self {
        Self { limit_a, ..self }
    }

    /// Which discretisation runs and how closely it follows the
    /// continuous design up to f_s/10.
    pub fn discretization(&self) -> DiscretizationReport {
        self.report
    }

    /// The sections in use.
    pub fn sections(&self) -> &[Biquad] {
        &self.sections[..self.n]
    }

    /// The overall gain (A per error unit).
    pub fn gain(&self) -> f64 {
        self.gain
    }

    /// Error unit per metre.
    pub fn error_per_metre(&self) -> f64 {
        self.error_per_metre
    }

    /// Discrete response at frequency `omega_rad_s` (rad/s) for a sample
    /// period `period_s`: `C(e^{jωT})`, A per error unit.
    pub fn response(&self, omega_rad_s: f64, period_s: f64) -> Complex<f64> {
        cascade_response(self.gain, self.sections(), omega_rad_s * period_s)
    }

    /// Clears the state (bumpless restart from the current position).
    pub fn reset(&mut self) {
        self.state = [[0.0; 2]; MAX_SECTIONS];
        self.saturated = false;
    }

    /// Whether the last output was clipped.
    pub fn saturated(&self) -> bool {
        self.saturated
    }

    /// One step: position error in metres → current demand in A, clipped
    /// to ±limit. Real-time safe. A non-finite error returns NaN and leaves
    /// the state untouched (the supervisor faults on it).
    #[inline]
    pub fn update(&mut self, error_m: f64) -> f64 {
        let x0 = error_m * self.error_per_metre;
        if !x0.is_finite() {
            return f64::NAN;
        }
        // Output with the current state, then the candidate next state.
        let mut x = x0;
        let mut next = self.state;
        for (i, s) in self.sections[..self.n].iter().enumerate() {
            let st = self.state[i];
            let y = s.b[0] * x + st[0];
            next[i] = [s.b[1] * x - s.a[0] * y + st[1], s.b[2] * x - s.a[1] * y];
            x = y;
        }
        let u = self.gain * x;
        if !u.is_finite() {
            return f64::NAN;
        }
        let clipped = u.clamp(-self.limit_a, self.limit_a);
        self.saturated = clipped != u;
        // Conditional integration: hold the state while the output is
        // clipped and the error pushes further into the limit.
        let winding = self.saturated && (u.signum() == (x0 * self.gain).signum());
        if !winding {
            self.state = next;
        }
        clipped
    }

    /// State-space realisation `(A, B, C, D)` of the whole cascade (gain
    /// included), input error unit → output A, for closed-loop analysis.
    pub fn state_space(&self) -> (DMatrix<f64>, DMatrix<f64>, DMatrix<f64>, f64) {
        let n = 2 * self.n;
        let mut a = DMatrix::zeros(n, n);
        let mut b = DMatrix::zeros(n, 1);
        let mut c = DMatrix::zeros(1, n);
        // Input of section i: u_i = C_prev x + D_prev u. Track the map from
        // (x, input) to the current signal as row vector `cx` and scalar `d`.
        let mut cx = DMatrix::<f64>::zeros(1, n);
        let mut d = 1.0;
        for (i, s) in self.sections().iter().enumerate() {
            let (r0, r1) = (2 * i, 2 * i + 1);
            // DF2T: y = b0 u + s1; s1' = b1 u − a1 y + s2 = (b1 − a1 b0) u − a1 s1 + s2;
            //       s2' = b2 u − a2 y = (b2 − a2 b0) u − a2 s1.
            let g1 = s.b[1] - s.a[0] * s.b[0];
            let g2 = s.b[2] - s.a[1] * s.b[0];
            for j in 0..n {
                a[(r0, j)] += g1 * cx[(0, j)];
                a[(r1, j)] += g2 * cx[(0, j)];
            }
            a[(r0, r0)] += -s.a[0];
            a[(r0, r1)] += 1.0;
            a[(r1, r0)] += -s.a[1];
            b[(r0, 0)] += g1 * d;
            b[(r1, 0)] += g2 * d;
            // Output of this section: y = b0 (cx x + d u) + s1.
            let mut ncx = cx.clone() * s.b[0];
            ncx[(0, r0)] += 1.0;
            cx = ncx;
            d *= s.b[0];
        }
        for j in 0..n {
            c[(0, j)] = cx[(0, j)] * self.gain;
        }
        (a, b, c, d * self.gain)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::design::tests::{bare, fast};
    use crate::control::ErrorUnit;

    #[test]
    fn step_response_of_an_integrator_and_anti_windup() {
        // 10/s on a 1 µm error: the output ramps at 10 A/s.
        let cfg = ControllerConfig {
            error_unit: ErrorUnit::Micrometre,
            integrators: 1,
            ..bare(10.0)
        };
        let t = 1e-3;
        let mut d = DiscreteController::new(&cfg, t, 2.0);
        let mut u = 0.0;
        for _ in 0..100 {
            u = d.update(1e-6);
        }
        // Trapezoidal integration of a step: 10 · (99.5 · 1 ms).
        assert!((u - 0.995).abs() < 1e-9, "{u}");
        // Saturate for a long time, then reverse: recovery is immediate.
        for _ in 0..10_000 {
            u = d.update(1e-6);
        }
        assert_eq!(u, 2.0);
        assert!(d.saturated());
        let mut steps = 0;
        while d.update(-1e-6) > 1.9 {
            steps += 1;
        }
        assert!(steps < 30, "wound up: {steps} ticks to leave saturation");
    }

    #[test]
    fn state_space_matches_the_cascade() {
        let t = 200e-6;
        let d = DiscreteController::new(&fast(), t, f64::INFINITY);
        let (a, b, c, dd) = d.state_space();
        for w in [10.0, 287.0, 520.0, 3000.0] {
            let z = Complex::from_polar(1.0, w * t);
            let n = a.nrows();
            let m = DMatrix::<Complex<f64>>::from_fn(n, n, |i, j| {
                (if i == j { z } else { Complex::new(0.0, 0.0) }) - Complex::new(a[(i, j)], 0.0)
            });
            let rhs = DMatrix::<Complex<f64>>::from_fn(n, 1, |i, _| Complex::new(b[(i, 0)], 0.0));
            let x = m.lu().solve(&rhs).unwrap();
            let h: Complex<f64> = (0..n).map(|j| x[(j, 0)] * c[(0, j)]).sum::<Complex<f64>>() + dd;
            let hd = d.response(w, t);
            assert!((h - hd).norm() < 1e-9 * hd.norm(), "{w}: {h} vs {hd}");
        }
    }
}
