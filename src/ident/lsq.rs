//! The least-squares plumbing the modal fit ([`super::modal_fit`]) and the
//! model update ([`super::update`]) share: a problem given by its residual
//! and Jacobian at any point of its coordinates, minimised by
//! Levenberg-Marquardt (the `levenberg-marquardt` crate, a port of
//! MINPACK's `lmder`; Moré, *The Levenberg-Marquardt algorithm:
//! implementation and theory*, 1978). What each problem's coordinates,
//! residuals and acceptance of the result mean stays with it.

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{DMatrix, DVector, Dyn, Owned};

/// A nonlinear least-squares problem: minimise `|r(x)|²` over `x`.
pub(crate) trait Residuals {
    /// The residuals `r(x)` (length m); `None` where they cannot be
    /// computed, which makes the minimiser shorten its step.
    fn residuals(&self, x: &DVector<f64>) -> Option<DVector<f64>>;
    /// The Jacobian `∂r/∂x` at `x` (m × n); `None` where it cannot be
    /// computed.
    fn jacobian(&self, x: &DVector<f64>) -> Option<DMatrix<f64>>;
}

/// The crate's view of a [`Residuals`]: the current point and the problem.
struct AtPoint<'r, R> {
    problem: &'r R,
    x: DVector<f64>,
}

impl<R: Residuals> LeastSquaresProblem<f64, Dyn, Dyn> for AtPoint<'_, R> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, x: &DVector<f64>) {
        self.x.copy_from(x);
    }

    fn params(&self) -> DVector<f64> {
        self.x.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        self.problem.residuals(&self.x)
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        self.problem.jacobian(&self.x)
    }
}

/// Minimises `problem` by Levenberg-Marquardt from `x0`, `patience` being
/// the crate's bound on evaluations (× (n + 1)); returns where it stopped.
/// Whether that is better than `x0` is the caller's to judge (each keeps
/// its start when it is not).
pub(crate) fn minimise<R: Residuals>(
    problem: &R,
    x0: DVector<f64>,
    patience: usize,
) -> DVector<f64> {
    let t0 = std::time::Instant::now();
    let n = x0.len();
    let (at, report) = LevenbergMarquardt::new()
        .with_patience(patience)
        .minimize(AtPoint { problem, x: x0 });
    tracing::debug!(
        n,
        evaluations = report.number_of_evaluations,
        termination = ?report.termination,
        time_s = t0.elapsed().as_secs_f64(),
        "least squares: one minimisation"
    );
    at.x
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `y = a e^{b t}` through three exact points: the minimiser finds
    /// `a = 2`, `b = −0.5` from `a = 1`, `b = 0`.
    struct Exponential {
        t: [f64; 3],
        y: [f64; 3],
    }

    impl Residuals for Exponential {
        fn residuals(&self, x: &DVector<f64>) -> Option<DVector<f64>> {
            Some(DVector::from_iterator(
                3,
                (0..3).map(|i| x[0] * (x[1] * self.t[i]).exp() - self.y[i]),
            ))
        }
        fn jacobian(&self, x: &DVector<f64>) -> Option<DMatrix<f64>> {
            Some(DMatrix::from_fn(3, 2, |i, j| {
                let e = (x[1] * self.t[i]).exp();
                if j == 0 {
                    e
                } else {
                    x[0] * self.t[i] * e
                }
            }))
        }
    }

    #[test]
    fn fits_an_exponential() {
        let t = [0.0, 1.0, 2.0];
        let p = Exponential {
            t,
            y: t.map(|t| 2.0 * (-0.5 * t).exp()),
        };
        let x = minimise(&p, DVector::from_vec(vec![1.0, 0.0]), 100);
        assert!(
            (x[0] - 2.0).abs() < 1e-9 && (x[1] + 0.5).abs() < 1e-9,
            "{x}"
        );
    }
}
