//! The frequency response `cᵀ (pI − M)⁻¹ b` of one fixed real state
//! matrix `M` at many complex points `p`, in O(n²) a point instead of an
//! O(n³) LU factorisation each.
//!
//! `M = Q H Qᵀ` with `H` upper Hessenberg and `Q` orthogonal (Householder
//! reduction, Golub & Van Loan, *Matrix Computations*, 4th ed., §7.4.3;
//! the frequency-response use is Laub, IEEE TAC 26(2), 1981), so
//! `cᵀ (pI − M)⁻¹ b = (Qᵀc)ᵀ (pI − H)⁻¹ (Qᵀb)`, and `pI − H`, whose only
//! entries below the diagonal are on the first subdiagonal, is solved by
//! Gaussian elimination with partial pivoting between adjacent rows
//! (backward stable as the full LU is, §3.4). The reduction is done once.

use nalgebra::{Complex, DMatrix, SMatrix, SVector};

/// `cᵀ (pI − M)⁻¹ b` for an `N × N` real `M` (see the module doc).
#[derive(Debug, Clone)]
pub(crate) struct HessenbergResponse<const N: usize> {
    /// `H = Qᵀ M Q`, upper Hessenberg.
    h: SMatrix<f64, N, N>,
    /// `Qᵀ b`.
    b: SVector<f64, N>,
    /// `Qᵀ c`.
    c: SVector<f64, N>,
}

impl<const N: usize> HessenbergResponse<N> {
    /// Reduces `m` once; `b` is the input vector, `c` the output vector.
    pub(crate) fn new(m: SMatrix<f64, N, N>, b: SVector<f64, N>, c: SVector<f64, N>) -> Self {
        let (q, h) =
            nalgebra::linalg::Hessenberg::new(DMatrix::from_column_slice(N, N, m.as_slice()))
                .unpack();
        let qt = SMatrix::<f64, N, N>::from_fn(|i, j| q[(j, i)]);
        Self {
            h: SMatrix::from_fn(|i, j| h[(i, j)]),
            b: qt * b,
            c: qt * c,
        }
    }

    /// `cᵀ (pI − M)⁻¹ b` at `p`; NaN where `pI − M` is singular (`p` an
    /// eigenvalue of `M`). No allocation.
    pub(crate) fn at(&self, p: Complex<f64>) -> Complex<f64> {
        let zero = Complex::new(0.0, 0.0);
        let mut a = [[zero; N]; N];
        for (i, row) in a.iter_mut().enumerate() {
            for (j, x) in row.iter_mut().enumerate().skip(i.saturating_sub(1)) {
                *x = Complex::new(-self.h[(i, j)], 0.0);
            }
            row[i] += p;
        }
        let mut y: [Complex<f64>; N] = std::array::from_fn(|i| Complex::new(self.b[i], 0.0));
        for k in 0..N.saturating_sub(1) {
            // Partial pivoting: rows k and k + 1 are the only candidates.
            if a[k + 1][k].norm_sqr() > a[k][k].norm_sqr() {
                a.swap(k, k + 1);
                y.swap(k, k + 1);
            }
            if a[k][k] == zero {
                continue; // the column is already zero below: singular
            }
            let l = a[k + 1][k] / a[k][k];
            let (upper, lower) = a.split_at_mut(k + 1);
            for (x, u) in lower[0][k + 1..].iter_mut().zip(&upper[k][k + 1..]) {
                *x -= l * u;
            }
            let yk = y[k];
            y[k + 1] -= l * yk;
        }
        let mut out = zero;
        for i in (0..N).rev() {
            if a[i][i] == zero {
                return Complex::new(f64::NAN, f64::NAN);
            }
            let mut s = y[i];
            for j in i + 1..N {
                s -= a[i][j] * y[j];
            }
            y[i] = s / a[i][i];
            out += self.c[i] * y[i];
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The direct LU solve, the reference.
    fn direct<const N: usize>(
        m: &SMatrix<f64, N, N>,
        b: &SVector<f64, N>,
        c: &SVector<f64, N>,
        p: Complex<f64>,
    ) -> Complex<f64> {
        let a = DMatrix::<Complex<f64>>::from_fn(N, N, |i, j| {
            let d = if i == j { p } else { Complex::new(0.0, 0.0) };
            d - Complex::new(m[(i, j)], 0.0)
        });
        let rhs = DMatrix::<Complex<f64>>::from_fn(N, 1, |i, _| Complex::new(b[i], 0.0));
        match a.lu().solve(&rhs) {
            Some(x) => (0..N).map(|i| x[i] * c[i]).sum(),
            None => Complex::new(f64::NAN, f64::NAN),
        }
    }

    /// Random dense matrices (entries over two decades), points on and
    /// off the unit circle and the imaginary axis: the reduced solve agrees
    /// with the direct LU to within 1e-9 relative. (Both are backward
    /// stable, so on ill-conditioned matrices they agree only to the
    /// condition number times the rounding; the plant's own matrices are
    /// checked in the hal's `sim` tests.)
    #[test]
    fn agrees_with_the_direct_solve() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for case in 0..200 {
            let m = SMatrix::<f64, 9, 9>::from_fn(|_, _| next() * 10f64.powf(next()));
            let b = SVector::<f64, 9>::from_fn(|_, _| next());
            let c = SVector::<f64, 9>::from_fn(|_, _| next());
            let r = HessenbergResponse::new(m, b, c);
            for k in 0..50 {
                let w = 10f64.powf(-2.0 + 6.0 * f64::from(k) / 49.0);
                for p in [
                    Complex::new(0.0, w),
                    Complex::from_polar(1.0, w.min(3.1)),
                    Complex::new(0.3 * next(), w),
                ] {
                    let (got, want) = (r.at(p), direct(&m, &b, &c, p));
                    assert!(
                        (got - want).norm() <= 1e-9 * want.norm().max(1e-300),
                        "case {case}, p {p}: {got} against {want}"
                    );
                }
            }
        }
    }

    /// At an eigenvalue the response is NaN, as the direct solve's
    /// refusal is.
    #[test]
    fn an_eigenvalue_gives_nan() {
        let m = SMatrix::<f64, 2, 2>::new(0.0, 1.0, -4.0, 0.0); // ±2j
        let r = HessenbergResponse::new(m, SVector::from([0.0, 1.0]), SVector::from([1.0, 0.0]));
        assert!(r.at(Complex::new(0.0, 2.0)).re.is_nan());
        // 1/(s² + 4) at s = j: 1/3.
        assert!((r.at(Complex::new(0.0, 1.0)) - Complex::new(1.0 / 3.0, 0.0)).norm() < 1e-15);
    }
}
