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

/// Samples of the white input [`DiscreteController::rounding_error`] runs
/// (0.8 s at 20 kHz, 3.3 s at 5 kHz: several decay times of a pole at the
/// radius the design allows, 2 s⁻¹).
pub const ROUNDING_TEST_SAMPLES: usize = 16_384;

/// A double-double number `hi + lo`, |lo| ≤ ulp(hi)/2 (Dekker 1971):
/// the reference the cascade's `f64` rounding is measured against.
#[derive(Debug, Clone, Copy)]
struct Dd {
    hi: f64,
    lo: f64,
}

impl Dd {
    const ZERO: Dd = Dd { hi: 0.0, lo: 0.0 };

    /// `a + b` exactly, as a double-double (Knuth's two-sum).
    fn two_sum(a: f64, b: f64) -> Dd {
        let s = a + b;
        let bb = s - a;
        Dd {
            hi: s,
            lo: (a - (s - bb)) + (b - bb),
        }
    }

    /// `self + o`.
    fn add(self, o: Dd) -> Dd {
        let s = Dd::two_sum(self.hi, o.hi);
        let t = Dd::two_sum(self.lo, o.lo);
        let r = Dd::two_sum(s.hi, s.lo + t.hi);
        Dd::two_sum(r.hi, r.lo + t.lo)
    }

    /// `self × c` for an `f64` coefficient (two-product by fused
    /// multiply-add).
    fn mul(self, c: f64) -> Dd {
        let p = self.hi * c;
        let e = self.hi.mul_add(c, -p);
        Dd::two_sum(p, e + self.lo * c)
    }
}

impl From<f64> for Dd {
    fn from(v: f64) -> Self {
        Dd { hi: v, lo: 0.0 }
    }
}

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

    /// One sample of direct form II transposed: the output for input `x`
    /// with state `s`, and the next state. The tick's arithmetic, in this
    /// order (the rounding check runs the same).
    #[inline]
    pub fn step(&self, s: [f64; 2], x: f64) -> (f64, [f64; 2]) {
        let y = self.b[0] * x + s[0];
        (
            y,
            [
                self.b[1] * x - self.a[0] * y + s[1],
                self.b[2] * x - self.a[1] * y,
            ],
        )
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

    /// The complex pole pairs of the sections as resonances: each pair
    /// `z = r·e^{±jθ}` as `(θ/T, −ln r / T)`, its frequency and its
    /// half-width (the decay rate σ, where |C| is 3 dB below its peak),
    /// both rad/s, `T` = `period_s`. A lightly damped pair's peak is a few
    /// σ wide: a grid must sample it finer than that to see the loop there
    /// ([`crate::control::loop_check::resolving`]).
    pub fn resonances(&self, period_s: f64) -> Vec<(f64, f64)> {
        self.sections()
            .iter()
            .filter_map(|s| {
                let [a1, a2] = s.a;
                // z² + a1 z + a2 = 0: complex when a1² < 4 a2.
                if a1 * a1 >= 4.0 * a2 || a2 <= 0.0 {
                    return None;
                }
                let r = a2.sqrt();
                let theta = (-a1 / (2.0 * r)).clamp(-1.0, 1.0).acos();
                Some((theta / period_s, -r.ln() / period_s))
            })
            .collect()
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
            let (y, st) = s.step(self.state[i], x);
            next[i] = st;
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

    /// How much of the cascade's output is its own rounding: the RMS
    /// difference between this cascade run in `f64` (as the tick runs it)
    /// and the same sections run in double-double arithmetic (about 32
    /// digits; Dekker's two-sum and two-product, T. J. Dekker, *Numer.
    /// Math.* 18, 1971), over the RMS of the latter, for
    /// [`ROUNDING_TEST_SAMPLES`] samples of a fixed white input.
    /// Dimensionless; a well-paired cascade gives 1e-15 to 1e-12. Sections
    /// that amplify the signal by decades before later ones take it back
    /// make the rounding ring at the least damped poles: a 24-pole
    /// controller paired by position gives 52 (a rounding error 52 times
    /// its signal; 2e-14 paired by nearness). Runs once per check, never
    /// on the tick.
    pub fn rounding_error(&self) -> f64 {
        let secs = self.sections();
        let mut lo = [[0.0_f64; 2]; MAX_SECTIONS];
        let mut hi = [[Dd::ZERO; 2]; MAX_SECTIONS];
        // A fixed white input (xorshift64*, uniform on [−1, 1)).
        let mut seed: u64 = 0x9E37_79B9_7F4A_7C15;
        let (mut err2, mut out2) = (0.0, 0.0);
        for _ in 0..ROUNDING_TEST_SAMPLES {
            seed ^= seed >> 12;
            seed ^= seed << 25;
            seed ^= seed >> 27;
            let r = seed.wrapping_mul(0x2545_F491_4F6C_DD1D);
            let x0 = (r >> 11) as f64 / (1u64 << 52) as f64 - 1.0;
            let (mut x, mut xd) = (x0, Dd::from(x0));
            for (i, s) in secs.iter().enumerate() {
                (x, lo[i]) = s.step(lo[i], x);
                let yd = xd.mul(s.b[0]).add(hi[i][0]);
                hi[i] = [
                    xd.mul(s.b[1]).add(yd.mul(-s.a[0])).add(hi[i][1]),
                    xd.mul(s.b[2]).add(yd.mul(-s.a[1])),
                ];
                xd = yd;
            }
            let exact = xd.hi + xd.lo;
            err2 += (x - exact) * (x - exact);
            out2 += exact * exact;
        }
        if out2 > 0.0 && out2.is_finite() {
            (err2 / out2).sqrt()
        } else if err2 == 0.0 {
            0.0
        } else {
            f64::INFINITY
        }
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
    use crate::control::continuous::tests::{bare, fast};
    use crate::control::ErrorUnit;

    /// The 24-pole controller `bench design` wrote for a random bench
    /// (`unity_dc`, error in µm, 5 kHz): zeros and poles as it listed
    /// them, highest first.
    fn climbed() -> ControllerConfig {
        let pairs = |v: &[(f64, f64)]| {
            v.iter()
                .map(|&(omega_rad_s, zeta)| crate::control::ComplexPair { omega_rad_s, zeta })
                .collect::<Vec<_>>()
        };
        ControllerConfig {
            form: crate::control::Form::UnityDc,
            error_unit: ErrorUnit::Micrometre,
            integrators: 1,
            real_poles_rad_s: vec![4624.52],
            complex_zeros: pairs(&[
                (98982.19, 0.21436),
                (33089.52, 0.11075),
                (18357.86, 0.09957),
                (11804.25, 0.08577),
                (4312.70, 0.90875),
                (7595.47, 0.09034),
                (2957.71, 0.08015),
                (951.75, 0.36239),
                (577.08, 0.0039040),
                (517.55, 0.036870),
                (510.54, 0.0038162),
                (185.47, 0.0095970),
            ]),
            complex_poles: pairs(&[
                (98924.64, 0.21127),
                (33113.13, 0.10948),
                (18380.74, 0.09897),
                (11824.06, 0.08678),
                (5408.01, 0.61683),
                (7600.03, 0.09494),
                (2879.32, 0.12768),
                (952.03, 0.36066),
                (556.14, 0.0037275),
                (532.47, 0.0037760),
                (518.19, 0.033409),
            ]),
            discretization: crate::control::Discretization::Bilinear,
            ..bare(4.8312)
        }
    }

    /// Every section's lightly damped pole pair is a resonance where the
    /// discrete response peaks, 3 dB down one half-width either side:
    /// found on a dense scan of `C_d(e^{jωT})`, independent of the roots.
    #[test]
    fn resonances_are_where_the_response_peaks() {
        let t = 2e-4;
        let pair = |omega_rad_s: f64, zeta: f64| crate::control::ComplexPair { omega_rad_s, zeta };
        let cfg = ControllerConfig {
            complex_poles: vec![pair(14_000.0, 2.0 / 14_000.0), pair(900.0, 0.01)],
            complex_zeros: vec![pair(14_100.0, 0.02), pair(2000.0, 0.5)],
            discretization: crate::control::Discretization::Bilinear,
            ..bare(1.0)
        };
        let d = DiscreteController::new(&cfg, t, f64::INFINITY);
        let mut r = d.resonances(t);
        r.sort_by(|a, b| a.0.total_cmp(&b.0));
        assert_eq!(r.len(), 2, "{r:?}");
        for &(w, sigma) in &r {
            let mag = |x: f64| d.response(x, t).norm();
            let scan: Vec<f64> = (-200_000..=200_000)
                .map(|k| w + 20.0 * sigma * f64::from(k) / 200_000.0)
                .collect();
            let peak_at = scan
                .iter()
                .copied()
                .max_by(|a, b| mag(*a).total_cmp(&mag(*b)))
                .unwrap();
            assert!(
                (peak_at - w).abs() < 0.05 * sigma,
                "peak at {peak_at}, pole at {w} ± {sigma}"
            );
            let peak = mag(peak_at);
            for side in [-1.0, 1.0] {
                let db = 20.0 * (mag(w + side * sigma) / peak).log10();
                assert!((db + 3.01).abs() < 0.3, "{db} dB one half-width from {w}");
            }
        }
    }

    /// The cascade's rounding, measured against double-double: the
    /// climbed controller as `sections` pairs it (nearest zeros, least
    /// damped last) rounds at the level of f64; the same factors paired by
    /// position (each pole with the zero the list's end offers, as the
    /// pairing was before: 98924 rad/s over 185 rad/s) lose more than the
    /// signal, and the loop check's bound lies between the two.
    #[test]
    fn rounding_of_a_well_and_a_badly_paired_cascade() {
        let t = 2e-4;
        let cfg = climbed();
        let good = DiscreteController::new(&cfg, t, f64::INFINITY);
        let e_good = good.rounding_error();
        // By position: plain bilinear of each pole with the zero popped
        // from the end of the list, then the leftover zero over the real
        // pole and the integrator.
        let k = 2.0 / t;
        let bilinear = |b: [f64; 3], a: [f64; 3]| {
            let map = |c: [f64; 3]| {
                [
                    c[2] * k * k + c[1] * k + c[0],
                    -2.0 * c[2] * k * k + 2.0 * c[0],
                    c[2] * k * k - c[1] * k + c[0],
                ]
            };
            let (n, d) = (map(b), map(a));
            Biquad {
                b: [n[0] / d[0], n[1] / d[0], n[2] / d[0]],
                a: [d[1] / d[0], d[2] / d[0]],
            }
        };
        let quad = |q: &crate::control::ComplexPair| {
            let w2 = q.omega_rad_s * q.omega_rad_s;
            [1.0, 2.0 * q.zeta / q.omega_rad_s, 1.0 / w2]
        };
        let mut zeros = cfg.complex_zeros.clone();
        let mut bad = good;
        let mut n = 0;
        for p in &cfg.complex_poles {
            bad.sections[n] = bilinear(quad(&zeros.pop().unwrap()), quad(p));
            n += 1;
        }
        let pole = cfg.real_poles_rad_s[0];
        bad.sections[n] = bilinear(quad(&zeros.pop().unwrap()), [0.0, 1.0, 1.0 / pole]);
        bad.n = n + 1;
        assert_eq!(bad.n, good.n);
        // The same transfer function: the pairing changes only the numbers.
        for w in [10.0, 300.0, 1000.0, 5000.0] {
            let (g, b) = (good.response(w, t), bad.response(w, t));
            assert!((g / b - 1.0).norm() < 1e-6, "{w} rad/s: {g} vs {b}");
        }
        let e_bad = bad.rounding_error();
        eprintln!("rounding: paired by nearness {e_good:.1e}, by position {e_bad:.1e}");
        assert!(e_good < 1e-12, "paired by nearness: {e_good:e}");
        assert!(e_bad > 1e-2, "paired by position: {e_bad:e}");
        assert!(e_good < crate::control::loop_check::ROUNDING_ERROR_MAX);
        assert!(e_bad > crate::control::loop_check::ROUNDING_ERROR_MAX);
    }

    /// Eq. (6-7)'s notch stays one section: its pole pair at 555 rad/s
    /// takes the zero pair at 520 rad/s whatever the lists' order.
    #[test]
    fn the_notch_of_eq_6_7_is_paired_with_its_pole_whatever_the_order() {
        let mut cfg = fast();
        let d = DiscreteController::new(&cfg, 2e-4, f64::INFINITY);
        cfg.complex_zeros.reverse();
        let r = DiscreteController::new(&cfg, 2e-4, f64::INFINITY);
        assert_eq!(d.sections(), r.sections());
        // The angle of a biquad's complex roots, as a frequency (rad/s).
        let angle = |c0: f64, c1: f64, c2: f64| {
            let disc = c1 * c1 - 4.0 * c0 * c2;
            (disc < 0.0).then(|| Complex::new(-c1, (-disc).sqrt()).arg() / 2e-4)
        };
        let notch = d.sections().iter().find(|s| {
            let zero = angle(s.b[0], s.b[1], s.b[2]);
            zero.is_some_and(|w| (w - 520.0).abs() < 0.5)
        });
        let notch = notch.expect("a section with the zeros at 520 rad/s (pre-warped)");
        let pole = angle(1.0, notch.a[0], notch.a[1]).expect("complex poles");
        assert!(
            (pole - 555.0).abs() < 5.0,
            "the notch's poles at {pole} rad/s"
        );
    }

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
