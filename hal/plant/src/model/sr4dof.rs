//! The SR4DoF's equations of motion (Eq. 2-5) solved: its modes, its
//! force → x1 response, and its zeros with their types (thesis ch. 3).

use super::*;

/// The matrices of Eq. (2-5) ([`Sr4dofParams::matrices`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Matrices {
    /// Mass matrix M, kg.
    pub mass: Matrix4<f64>,
    /// Stiffness matrix K, N/m.
    pub stiffness: Matrix4<f64>,
    /// Generalised force per unit actuator force, `q = [1, α, −2α, 0]ᵀ`.
    pub input: Vector4<f64>,
}

/// One mode of the undamped model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mode {
    /// Natural frequency, rad/s.
    pub omega_rad_s: f64,
    /// Mass-normalised mode shape (`φᵀ M φ = 1`), over `[x1, y1, y2, y3]`,
    /// units m/√kg.
    pub shape: Vector4<f64>,
    /// Modal damping ratio from the Rayleigh fit.
    pub zeta: f64,
    /// Modal residue of the force→x1 transfer function,
    /// `βᵢ = (cᵀφᵢ)(φᵢᵀq)`, m/(N·s²) — `G(s) = Σ βᵢ / (s² + 2ζᵢωᵢ s + ωᵢ²)`
    /// (Eq. 2-7 with damping).
    pub residue: f64,
}

impl Mode {
    /// Natural frequency, Hz.
    pub fn frequency_hz(&self) -> f64 {
        self.omega_rad_s / (2.0 * PI)
    }

    /// The mode shape scaled to unit Euclidean length, sign chosen so that
    /// the largest-magnitude entry is positive (the convention of Table 2-2
    /// aside from sign).
    pub fn unit_shape(&self) -> Vector4<f64> {
        let v = self.shape.normalize();
        let imax = v.iamax();
        if v[imax] < 0.0 {
            -v
        } else {
            v
        }
    }
}

/// Type of a zero pair / quartet of a lightly damped flexible system
/// (thesis Chapter 3; `u = s²` roots of the undamped numerator).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ZeroType {
    /// Marginally minimum phase: `u < 0`, a pair on the imaginary axis
    /// (slightly into the left half plane with damping): an anti-resonance.
    Mmp,
    /// Real minimum / non-minimum phase pair: `u > 0`, `s = ±√u`.
    RmpRnmp,
    /// Complex minimum / non-minimum phase quartet: complex `u`,
    /// `s = ±a ± jb` — two zeros in the right half plane.
    CmpCnmp,
}

impl ZeroType {
    /// Relative size of `Im u` below which a root `u = s²` counts as real
    /// (the roots come from a companion-matrix eigensolver, accurate to a
    /// few ulps of `|u|` times the conditioning).
    pub const REAL_TOLERANCE: f64 = 1e-9;

    /// The type of the zeros `s = ±√u` of an undamped transfer function
    /// from a root `u` (rad/s)² of its numerator in `u = s²` (thesis 3.2.1):
    /// complex `u` (`|Im u| > REAL_TOLERANCE·|u|`) → CMP-CNMP, real
    /// `u < 0` → MMP, real `u ≥ 0` → RMP-RNMP.
    pub fn of_u(u: Complex<f64>) -> Self {
        if u.im.abs() > Self::REAL_TOLERANCE * u.norm() {
            Self::CmpCnmp
        } else if u.re < 0.0 {
            Self::Mmp
        } else {
            Self::RmpRnmp
        }
    }

    /// The thesis' abbreviation.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Mmp => "MMP",
            Self::RmpRnmp => "RMP-RNMP",
            Self::CmpCnmp => "CMP-CNMP",
        }
    }
}

/// A root `u` of the undamped numerator `N(u)` (Eq. 2-7), with its type.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UndampedZero {
    /// Root in `u = s²`, (rad/s)².
    pub u: Complex<f64>,
    /// Its type.
    pub kind: ZeroType,
}

/// The assembled SR4DoF model.
#[derive(Debug, Clone)]
pub struct Sr4dof {
    params: Sr4dofParams,
    alpha: f64,
    mass: Matrix4<f64>,
    stiffness: Matrix4<f64>,
    damping: Matrix4<f64>,
    input: Vector4<f64>,
    rayleigh: (f64, f64),
    modes: [Mode; 4],
    zeros: Vec<Complex<f64>>,
    undamped_zeros: Vec<UndampedZero>,
}

/// Most iterations of an eigenvalue solver (modes, polynomial roots, the
/// loop check's closed-loop poles): a 4×4 or a 30×30 problem converges in
/// a few dozen; non-finite or absurd input would otherwise iterate forever.
pub const MAX_EIGEN_ITERATIONS: usize = 10_000;

impl Sr4dof {
    /// Assembles M and K of Eq. (2-5), solves the generalised eigenproblem
    /// `K φ = ω² M φ` and fits Rayleigh damping.
    ///
    /// # Errors
    /// [`ParamError`] from [`Sr4dofParams::validate`] (keys under `plant.`),
    /// or if the matrices are not positive definite.
    pub fn new(params: Sr4dofParams) -> Result<Self, ParamError> {
        params.validate("plant")?;
        let a = params.alpha();
        let Matrices {
            mass,
            stiffness,
            input,
        } = params.matrices();

        let model_err =
            |what: &str| ParamError::new("plant", format!("{what} (from {})", ranges::MODEL_KEYS));
        let chol = mass
            .cholesky()
            .ok_or_else(|| model_err("mass matrix is not positive definite"))?;
        let l_inv = chol
            .l()
            .try_inverse()
            .ok_or_else(|| model_err("mass matrix is singular"))?;
        // Symmetric standard form A = L⁻¹ K L⁻ᵀ; φ = L⁻ᵀ v is mass-normalised.
        let sym = l_inv * stiffness * l_inv.transpose();
        let sym = (sym + sym.transpose()) * 0.5;
        if sym.iter().any(|v| !v.is_finite()) {
            return Err(model_err("the stiffness and mass matrices are not finite"));
        }
        let eig = SymmetricEigen::try_new(sym, f64::EPSILON, MAX_EIGEN_ITERATIONS)
            .ok_or_else(|| model_err("the modes do not converge"))?;
        let mut order: Vec<usize> = (0..4).collect();
        order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
        let mut modes = [Mode {
            omega_rad_s: 0.0,
            shape: Vector4::zeros(),
            zeta: 0.0,
            residue: 0.0,
        }; 4];
        for (slot, &i) in order.iter().enumerate() {
            let lam = eig.eigenvalues[i];
            if lam <= 0.0 {
                return Err(model_err(
                    "stiffness matrix is not positive definite (a mode has ω² <= 0)",
                ));
            }
            let shape = l_inv.transpose() * eig.eigenvectors.column(i);
            modes[slot] = Mode {
                omega_rad_s: lam.sqrt(),
                shape,
                zeta: 0.0,
                residue: shape[0] * shape.dot(&input),
            };
        }

        // Rayleigh fit: ζ(ω) = a/(2ω) + bω/2 through the X rigid-body mode
        // and the mean of the closely spaced pair.
        let rigid = if modes[0].shape[0].abs() >= modes[1].shape[0].abs() {
            0
        } else {
            1
        };
        let w_r = modes[rigid].omega_rad_s;
        let w_c = 0.5 * (modes[2].omega_rad_s + modes[3].omega_rad_s);
        let (z_r, z_c) = (params.damping.zeta_rigid, params.damping.zeta_csm);
        // Solve [1/(2w_r) w_r/2; 1/(2w_c) w_c/2] [a b]ᵀ = [z_r z_c]ᵀ.
        let det = (w_c / w_r - w_r / w_c) / 4.0;
        let ra = (z_r * w_c / 2.0 - z_c * w_r / 2.0) / det;
        let rb = (z_c / (2.0 * w_r) - z_r / (2.0 * w_c)) / det;
        for m in &mut modes {
            m.zeta = ra / (2.0 * m.omega_rad_s) + rb * m.omega_rad_s / 2.0;
        }
        if modes.iter().any(|m| m.zeta.is_nan() || m.zeta < 0.0) {
            return Err(ParamError::new(
                "plant.damping.zeta_rigid",
                "the Rayleigh fit gives negative modal damping: plant.damping.zeta_rigid and plant.damping.zeta_csm are too far apart",
            ));
        }
        let damping = mass * ra + stiffness * rb;
        let mut model = Self {
            params,
            alpha: a,
            mass,
            stiffness,
            damping,
            input,
            rayleigh: (ra, rb),
            modes,
            zeros: Vec::new(),
            undamped_zeros: Vec::new(),
        };
        model.undamped_zeros = model
            .compute_undamped_zeros()
            .ok_or_else(|| model_err("the zeros of the model do not converge"))?;
        model.zeros = model.compute_zeros();
        Ok(model)
    }

    /// The parameters the model was built from.
    pub fn params(&self) -> &Sr4dofParams {
        &self.params
    }

    /// Coupling coefficient α (Eq. 2-6).
    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    /// Mass matrix M (Eq. 2-5), kg (kg·m for the mixed entries: all
    /// coordinates are lengths, so all entries are kg).
    pub fn mass(&self) -> &Matrix4<f64> {
        &self.mass
    }

    /// Stiffness matrix K (Eq. 2-5), N/m.
    pub fn stiffness(&self) -> &Matrix4<f64> {
        &self.stiffness
    }

    /// Rayleigh damping matrix `C = a M + b K`, N·s/m.
    pub fn damping(&self) -> &Matrix4<f64> {
        &self.damping
    }

    /// Rayleigh coefficients `(a` in 1/s, `b` in s`)`.
    pub fn rayleigh(&self) -> (f64, f64) {
        self.rayleigh
    }

    /// Generalised force per unit actuator force, `q = [1, α, −2α, 0]ᵀ`.
    pub fn input(&self) -> &Vector4<f64> {
        &self.input
    }

    /// The four modes, ascending in frequency.
    pub fn modes(&self) -> &[Mode; 4] {
        &self.modes
    }

    /// Index (0 or 1) of the X rigid-body mode: of the first two modes, the
    /// one whose mass-normalised shape has the larger `|x1|`.
    pub fn rigid_body_mode(&self) -> usize {
        if self.modes[0].shape[0].abs() >= self.modes[1].shape[0].abs() {
            0
        } else {
            1
        }
    }

    /// Force → x1 frequency response at `frequency_hz`, m/N, from the modal
    /// sum `Σ βᵢ / (ωᵢ² − ω² + 2jζᵢωᵢω)` (exact for Rayleigh damping).
    pub fn force_frf(&self, frequency_hz: f64) -> Complex<f64> {
        let w = 2.0 * PI * frequency_hz;
        self.modes
            .iter()
            .map(|m| {
                let wn = m.omega_rad_s;
                m.residue / Complex::new(wn * wn - w * w, 2.0 * m.zeta * wn * w)
            })
            .sum()
    }

    /// Force → x1 frequency response by direct solution of
    /// `(K − ω² M + jω C) z = q`, m/N. Same result as
    /// [`force_frf`](Self::force_frf); kept as an independent check.
    pub fn force_frf_direct(&self, frequency_hz: f64) -> Complex<f64> {
        let w = 2.0 * PI * frequency_hz;
        let dynamic: Matrix4<Complex<f64>> = Matrix4::from_fn(|i, j| {
            Complex::new(
                self.stiffness[(i, j)] - w * w * self.mass[(i, j)],
                w * self.damping[(i, j)],
            )
        });
        let rhs: Vector4<Complex<f64>> = self.input.map(|v| Complex::new(v, 0.0));
        match dynamic.lu().solve(&rhs) {
            Some(z) => z[0],
            None => Complex::new(f64::NAN, f64::NAN),
        }
    }

    /// Coefficients of the undamped numerator `N(u) = Σᵢ βᵢ Πⱼ≠ᵢ (u + ωⱼ²)`
    /// (Eq. 2-7, `u = s²`), highest power first: `[b3, b2, b1, b0]`.
    pub fn undamped_numerator(&self) -> [f64; 4] {
        let mut n = [0.0; 4];
        for (i, mi) in self.modes.iter().enumerate() {
            // Π_{j≠i} (u + ωj²) = u³ + e1 u² + e2 u + e3 with e the
            // elementary symmetric polynomials of the other three ωj².
            let mut p = [1.0, 0.0, 0.0, 0.0];
            let mut deg = 0;
            for (j, mj) in self.modes.iter().enumerate() {
                if i != j {
                    let w2 = mj.omega_rad_s * mj.omega_rad_s;
                    deg += 1;
                    for k in (1..=deg).rev() {
                        p[k] += w2 * p[k - 1];
                    }
                }
            }
            for (acc, c) in n.iter_mut().zip(p) {
                *acc += mi.residue * c;
            }
        }
        n
    }

    /// Discriminant of the cubic `N(u)` (Eq. 2-8):
    /// `Δ = 18 b3 b2 b1 b0 − 4 b2³ b0 + b2² b1² − 4 b3 b1³ − 27 b3² b0²`.
    /// `Δ < 0` ⇔ a complex pair of `u` roots ⇔ CMP-CNMP zeros.
    pub fn cnmp_discriminant(&self) -> f64 {
        let [b3, b2, b1, b0] = self.undamped_numerator();
        18.0 * b3 * b2 * b1 * b0 - 4.0 * b2.powi(3) * b0 + b2 * b2 * b1 * b1
            - 4.0 * b3 * b1.powi(3)
            - 27.0 * b3 * b3 * b0 * b0
    }

    /// Roots `u = s²` of the undamped numerator, classified (Chapter 3).
    pub fn undamped_zeros(&self) -> &[UndampedZero] {
        &self.undamped_zeros
    }

    fn compute_undamped_zeros(&self) -> Option<Vec<UndampedZero>> {
        let scale = self.frequency_scale().powi(2);
        let n = self.undamped_numerator();
        // Scale u = scale · v to keep the coefficients well conditioned.
        let scaled: Vec<f64> = n
            .iter()
            .enumerate()
            .map(|(k, c)| c * scale.powi(3 - k as i32))
            .collect();
        let mut out: Vec<UndampedZero> =
            poly_roots_cubic(&[scaled[0], scaled[1], scaled[2], scaled[3]])?
                .into_iter()
                .map(|v| v * scale)
                .map(|u| {
                    let kind = ZeroType::of_u(u);
                    UndampedZero { u, kind }
                })
                .collect();
        out.sort_by(|a, b| a.u.norm().total_cmp(&b.u.norm()));
        Some(out)
    }

    /// Zeros in `s` (rad/s) of the damped force→x1 transfer function
    /// `G(s) = Σ βᵢ / (s² + 2ζᵢωᵢ s + ωᵢ²)`, ascending in magnitude.
    ///
    /// With Rayleigh damping `C = aM + bK` each modal factor is
    /// `s² + (a + bωᵢ²)s + ωᵢ² = (1 + bs)(λ + ωᵢ²)` with
    /// `λ = (s² + as)/(1 + bs)`, so the degree-6 numerator is
    /// `(1 + bs)³ N(λ)` with `N(u)` the undamped numerator of Eq. (2-7):
    /// each root `u` of `N` gives two damped zeros, the roots of
    /// `s² + (a − bu)s − u = 0` (for `a = b = 0`, `s = ±√u`).
    pub fn zeros(&self) -> &[Complex<f64>] {
        &self.zeros
    }

    fn compute_zeros(&self) -> Vec<Complex<f64>> {
        let (a, b) = self.rayleigh;
        let mut z: Vec<Complex<f64>> = Vec::with_capacity(6);
        for root in &self.undamped_zeros {
            let u = root.u;
            let p = Complex::new(a, 0.0) - u * b;
            let d = (p * p + u * 4.0).sqrt();
            // The larger root without cancellation, the other from the
            // product of the roots (−u).
            let s1 = if (-p).re * d.re + (-p).im * d.im >= 0.0 {
                (-p + d) * 0.5
            } else {
                (-p - d) * 0.5
            };
            let s2 = if s1.norm() > 0.0 { -u / s1 } else { -p - s1 };
            z.push(s1);
            z.push(s2);
        }
        z.sort_by(|a, b| a.norm().total_cmp(&b.norm()));
        z
    }

    /// `true` if the model's transfer function has CMP-CNMP zeros: complex
    /// zeros with positive real part (damped model).
    pub fn has_cnmp_zeros(&self) -> bool {
        self.zeros()
            .iter()
            .any(|z| z.re > 0.0 && z.im.abs() > 1e-6 * z.norm())
    }

    /// Geometric mean of the natural frequencies, rad/s (polynomial scaling).
    fn frequency_scale(&self) -> f64 {
        (self.modes.iter().map(|m| m.omega_rad_s.ln()).sum::<f64>() / 4.0).exp()
    }
}
