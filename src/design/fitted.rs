//! The bench's own model: the modal fit of a measured FRF (`bench fit`'s
//! model, [`crate::ident::modal_fit`]) as a plant a design can be judged
//! and simulated on, in place of a config's nominal lumped model.
//!
//! # Model
//! The fit's continuous model (module docs of `modal_fit`),
//!
//! ```text
//! Ĥ(s) = e^{−s(τ − T/2)} · ZOH · 1/(1 + s/ω_a) · [ Σᵢ Aᵢ/(s² + 2ζᵢωᵢ s + ωᵢ²) + L/s² + U ]
//! ```
//!
//! (the fit's `sinc(ωT/2) e^{−jωT/2}` is the zero-order hold; its delay τ
//! starts at T/2), as a state space with the amplifier's current `i`, each
//! mode's displacement and velocity, and the lower residual's double
//! integrator when `L ≠ 0`:
//!
//! ```text
//! i' = ω_a (u − i),   qᵢ'' = −2ζᵢωᵢ qᵢ' − ωᵢ² qᵢ + Aᵢ i,   r'' = L i,
//! y  = Σᵢ qᵢ + U i + r
//! ```
//!
//! discretised exactly for a zero-order-hold input of period T
//! (`[Φ Γ; 0 1] = exp([A B; 0 0] T)`, Franklin, Powell & Workman,
//! *Digital Control of Dynamic Systems*, 3rd ed., §4.3.3), and the rest
//! of the delay, `τ − T/2`, rounded to whole periods.
//!
//! Units: u in A, y in m; Aᵢ and L in m/(A·s²), U in m/A, ω in rad/s.

use crate::ident::modal_fit::{evaluate, evaluate_sigma, ModalFit, Path};
use crate::ident::C64;
use nalgebra::{DMatrix, DVector};
use std::f64::consts::PI;

/// A modal fit as a discrete plant (see the module docs).
#[derive(Debug, Clone)]
pub struct FittedPlant {
    fit: ModalFit,
    path: Path,
    phi: DMatrix<f64>,
    gamma: DVector<f64>,
    output: DVector<f64>,
    /// Whole periods of delay after the hold, `round((τ − T/2)/T)` (≥ 0).
    pub delay_periods: usize,
}

impl FittedPlant {
    /// The plant of `fit` on the loop `path` (its sample period and
    /// amplifier bandwidth, as the fit used them).
    pub fn new(fit: &ModalFit, path: Path) -> Self {
        let t = path.period_s;
        let wa = 2.0 * PI * path.amplifier_bandwidth_hz;
        let lower = fit.lower_residual != 0.0 && fit.lower_residual.is_finite();
        let n = 1 + 2 * fit.modes.len() + if lower { 2 } else { 0 };
        let mut a = DMatrix::<f64>::zeros(n + 1, n + 1);
        let mut c = DVector::<f64>::zeros(n);
        a[(0, 0)] = -wa;
        a[(0, n)] = wa; // the input, held over the period
        c[0] = fit.upper_residual_m_per_a;
        for (k, m) in fit.modes.iter().enumerate() {
            let (q, v) = (1 + 2 * k, 2 + 2 * k);
            let w = 2.0 * PI * m.frequency_hz;
            a[(q, v)] = 1.0;
            a[(v, q)] = -w * w;
            a[(v, v)] = -2.0 * m.damping_ratio * w;
            a[(v, 0)] = m.modal_constant;
            c[q] = 1.0;
        }
        if lower {
            let (r, v) = (n - 2, n - 1);
            a[(r, v)] = 1.0;
            a[(v, 0)] = fit.lower_residual;
            c[r] = 1.0;
        }
        let e = (a * t).exp();
        let phi = e.view((0, 0), (n, n)).into_owned();
        let gamma = e.view((0, n), (n, 1)).column(0).into_owned();
        let delay_periods = ((fit.delay_s - 0.5 * t) / t).round().max(0.0) as usize;
        Self {
            fit: fit.clone(),
            path,
            phi,
            gamma,
            output: c,
            delay_periods,
        }
    }

    /// The fitted model's frequency response at `omega_rad_s`, m/A (the
    /// fit's own `Ĥ`, hold and amplifier included).
    pub fn frf(&self, omega_rad_s: f64) -> C64 {
        evaluate(&self.fit, &self.path, omega_rad_s / (2.0 * PI))
    }

    /// The 1σ of [`Self::frf`] relative to its magnitude at `omega_rad_s`
    /// (dimensionless): the fit's covariance propagated to first order
    /// ([`evaluate_sigma`]); NaN when the covariance is not known.
    pub fn frf_relative_sigma(&self, omega_rad_s: f64) -> f64 {
        let f_hz = omega_rad_s / (2.0 * PI);
        evaluate_sigma(&self.fit, &self.path, f_hz) / evaluate(&self.fit, &self.path, f_hz).norm()
    }

    /// The fit.
    pub fn fit(&self) -> &ModalFit {
        &self.fit
    }

    /// A simulation from rest: [`Simulation::step`] takes the current
    /// demand of one period (A) and returns the position sampled at the
    /// start of that period (m).
    pub fn simulation(&self) -> Simulation<'_> {
        Simulation {
            plant: self,
            x: DVector::zeros(self.phi.nrows()),
            queue: vec![0.0; self.delay_periods + 1],
            tick: 0,
        }
    }

    /// Whether the fit has a mass line (`L/s²`): a plant with a free
    /// mass is not stable, and the Youla form needs a stable plant.
    /// Judged by its share of the fitted response at `omega_rad_s` (the
    /// lowest measured line): above 10 %, and more than 3σ from zero.
    pub fn mass_line_share(&self, omega_rad_s: f64) -> f64 {
        let l = self.fit.lower_residual;
        // Not significant, or σ unknown (NaN): no mass line.
        let significant = l.abs() > 3.0 * self.fit.lower_residual_sigma;
        if l == 0.0 || !significant {
            return 0.0;
        }
        let h = self.frf(omega_rad_s).norm();
        let s = self.path.response(omega_rad_s / (2.0 * PI), 0.0).norm();
        (l.abs() * s / (omega_rad_s * omega_rad_s)) / h
    }
}

/// One run of a [`FittedPlant`] from rest.
pub struct Simulation<'a> {
    plant: &'a FittedPlant,
    x: DVector<f64>,
    queue: Vec<f64>,
    tick: usize,
}

impl Simulation<'_> {
    /// One period: the position now (m), then the demand `current_a`
    /// (A) held for the period after the plant's delay.
    pub fn step(&mut self, current_a: f64) -> f64 {
        let y = self.position_m();
        self.apply(current_a);
        y
    }

    /// The position at the start of the period, m.
    pub fn position_m(&self) -> f64 {
        self.plant.output.dot(&self.x)
    }

    /// The demand of this period, A: held over the period after the
    /// plant's delay (the state moves on one period).
    pub fn apply(&mut self, current_a: f64) {
        let p = self.plant;
        let d = self.queue.len();
        self.queue[self.tick % d] = current_a;
        let applied = self.queue[(self.tick + 1) % d];
        self.tick += 1;
        self.x = &p.phi * &self.x + &p.gamma * applied;
    }
}

/// Fits made by hand, for tests.
#[cfg(test)]
pub(crate) mod test_support {
    use crate::ident::modal_fit::{FitQuality, FittedMode, ModalFit};

    pub(crate) fn mode(f_hz: f64, zeta: f64, a: f64) -> FittedMode {
        FittedMode {
            label: "m".into(),
            frequency_hz: f_hz,
            frequency_sigma_hz: 0.0,
            damping_ratio: zeta,
            damping_ratio_sigma: 0.0,
            modal_constant: a,
            modal_constant_sigma: 0.0,
            sign: a.signum() as i8,
            in_path: true,
        }
    }

    pub(crate) fn fit(modes: Vec<FittedMode>, upper: f64, delay_s: f64) -> ModalFit {
        ModalFit {
            modes,
            lower_residual: 0.0,
            lower_residual_sigma: 0.0,
            upper_residual_m_per_a: upper,
            upper_residual_sigma_m_per_a: 0.0,
            delay_s,
            delay_sigma_s: 0.0,
            rms_relative_error: 0.0,
            coherent_points: 0,
            sign_sequence: String::new(),
            dominant_sequence: String::new(),
            zeros: vec![],
            cmp_cnmp: false,
            quality: FitQuality::default(),
            labels_unsure: None,
            covariance: Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::test_support::{fit, mode};
    use super::*;

    /// A constant demand settles at the static gain Σ Aᵢ/ωᵢ² + U (the
    /// model's value at s = 0); a sine's steady amplitude and phase, read
    /// by correlation, match the sampled response of the fit's Ĥ (hold,
    /// amplifier and the delay in whole periods, aliases summed) within
    /// 0.2 % and 0.5°.
    #[test]
    fn the_simulation_is_the_fitted_response() {
        let t = 2e-4;
        let path = Path {
            period_s: t,
            amplifier_bandwidth_hz: 1000.0,
        };
        let f = fit(
            vec![mode(22.0, 0.02, 3.0), mode(80.0, 0.01, -1.5)],
            1e-6,
            0.5 * t + 2.0 * t,
        );
        let p = FittedPlant::new(&f, path);
        assert_eq!(p.delay_periods, 2);
        let mut sim = p.simulation();
        let mut y = 0.0;
        for _ in 0..200_000 {
            y = sim.step(1.0);
        }
        let w1 = 2.0 * PI * 22.0;
        let w2 = 2.0 * PI * 80.0;
        let dc = 3.0 / (w1 * w1) - 1.5 / (w2 * w2) + 1e-6;
        assert!((y / dc - 1.0).abs() < 1e-6, "{y} vs {dc}");
        for f_hz in [5.0, 30.0, 200.0] {
            let mut sim = p.simulation();
            let n_period = (1.0 / (f_hz * t)).round() as usize;
            let w = 2.0 * PI / (n_period as f64 * t);
            // 40 s: the start's free response (ζω ≥ 2.7/s) has died out
            // over the second half.
            let cycles = (40.0 * f_hz) as usize;
            let mut acc = C64::new(0.0, 0.0);
            let total = n_period * cycles;
            for k in 0..total {
                let u = (w * k as f64 * t).sin();
                let y = sim.step(u);
                if k >= total / 2 {
                    acc += y * C64::from_polar(1.0, -w * k as f64 * t);
                }
            }
            // y ≈ Im(H e^{jωt}) → H = 2j·mean(y e^{−jωt}).
            let h = acc * C64::new(0.0, 2.0) / (total - total / 2) as f64;
            // The sampled response of the held input, aliases included
            // (Franklin, Powell & Workman Eq. 4.60): Σₖ of the fit's Ĥ at
            // ω + k·2π/T; its k = 0 term is the fit's own Ĥ.
            let ws = 2.0 * PI / t;
            let want: C64 = (-4000..=4000)
                .map(|k| {
                    let wk = w + f64::from(k) * ws;
                    evaluate(&f, &path, wk / (2.0 * PI))
                })
                .sum();
            let alias = (want / p.frf(w) - 1.0).norm();
            eprintln!("{f_hz} Hz: the aliases move H by {:.2} %", 100.0 * alias);
            assert!(
                (h.norm() / want.norm() - 1.0).abs() < 2e-3,
                "{f_hz} Hz: |H| {} vs {}",
                h.norm(),
                want.norm()
            );
            let dphi = (h / want).arg().to_degrees();
            assert!(dphi.abs() < 0.5, "{f_hz} Hz: {dphi}°");
        }
    }
}
