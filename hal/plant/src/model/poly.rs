//! Polynomials, coefficients highest power first: products and roots.

use super::*;

/// Product of two polynomials, coefficients highest power first.
pub fn poly_mul(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; a.len() + b.len() - 1];
    for (i, x) in a.iter().enumerate() {
        for (j, y) in b.iter().enumerate() {
            out[i + j] += x * y;
        }
    }
    out
}

/// Roots of a cubic (coefficients highest power first) as the eigenvalues
/// of its 3×3 companion matrix on the stack: the same method as
/// [`poly_roots`] without a heap allocation per matrix (the map solves
/// tens of thousands). A zero leading coefficient falls back to
/// [`poly_roots`].
pub fn poly_roots_cubic(c: &[f64; 4]) -> Option<Vec<Complex<f64>>> {
    if c[0] == 0.0 {
        return poly_roots(c);
    }
    let mut comp = nalgebra::Matrix3::<f64>::zeros();
    for j in 0..3 {
        comp[(0, j)] = -c[j + 1] / c[0];
    }
    for i in 1..3 {
        comp[(i, i - 1)] = 1.0;
    }
    if comp.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let schur = nalgebra::Schur::try_new(comp, f64::EPSILON, MAX_EIGEN_ITERATIONS)?;
    Some(schur.complex_eigenvalues().iter().copied().collect())
}

/// Roots of a polynomial (coefficients highest power first) as the
/// eigenvalues of its companion matrix. Leading zero coefficients are
/// dropped. `None` if a coefficient is not finite or the eigenvalue
/// iteration does not converge in [`MAX_EIGEN_ITERATIONS`].
pub fn poly_roots(coeffs: &[f64]) -> Option<Vec<Complex<f64>>> {
    let first = coeffs
        .iter()
        .position(|c| *c != 0.0)
        .unwrap_or(coeffs.len());
    let c = &coeffs[first..];
    let n = c.len().saturating_sub(1);
    if n == 0 {
        return Some(Vec::new());
    }
    let mut comp = DMatrix::<f64>::zeros(n, n);
    for j in 0..n {
        comp[(0, j)] = -c[j + 1] / c[0];
    }
    for i in 1..n {
        comp[(i, i - 1)] = 1.0;
    }
    if comp.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let schur = nalgebra::Schur::try_new(comp, f64::EPSILON, MAX_EIGEN_ITERATIONS)?;
    Some(schur.complex_eigenvalues().iter().copied().collect())
}
