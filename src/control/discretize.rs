//! From the continuous design to the discrete sections (see
//! *Discretisation* in [`crate::control`]): Tustin with pre-warp, matched
//! poles with least-squares numerators, and the cascade's response and
//! error against the design. Runs once, when a controller is made; never on
//! the tick.

use super::continuous::{sections, ContinuousSection};
use super::Discretization;
use super::{Biquad, ControllerConfig, MAX_SECTIONS};
use nalgebra::{Complex, DMatrix};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// How closely the discrete controller follows the continuous design:
/// the largest error of `C_d(e^{jωT}) / C(jω)` from 0.1 Hz to `up_to_hz`
/// (f_s/10, target 0.1 dB / 1°) and to `wide_up_to_hz` (f_s/4, target
/// [`WIDE_MAX_ERROR_DB`] / [`WIDE_MAX_ERROR_DEG`]), and the gain above.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct DiscretizationReport {
    /// The method that runs.
    pub method: Discretization,
    /// Largest |20 log10 |C_d/C|| up to `up_to_hz`, dB.
    pub max_error_db: f64,
    /// Largest |∠(C_d/C)| up to `up_to_hz`, degrees.
    pub max_error_deg: f64,
    /// Upper end of the band, Hz (a tenth of the sample rate).
    pub up_to_hz: f64,
    /// Largest |20 log10 |C_d/C|| up to `wide_up_to_hz`, dB. Absent in
    /// JSON written before it existed (read as NaN: not stated).
    #[serde(default = "not_stated")]
    pub wide_max_error_db: f64,
    /// Largest |∠(C_d/C)| up to `wide_up_to_hz`, degrees.
    #[serde(default = "not_stated")]
    pub wide_max_error_deg: f64,
    /// Upper end of the wide band, Hz (a quarter of the sample rate).
    #[serde(default = "not_stated")]
    pub wide_up_to_hz: f64,
    /// Largest `20 log10 |C_d/C|` from `up_to_hz` to Nyquist, dB: how far
    /// the discrete gain rises above the design where it is not fitted
    /// (negative: it stays below).
    pub above_band_max_excess_db: f64,
}

fn not_stated() -> f64 {
    f64::NAN
}

impl DiscretizationReport {
    /// One line for a report: both bands' errors and the gain above, and
    /// whether the wide band's target holds.
    pub fn line(&self) -> String {
        let miss = if self.within_wide_target() {
            String::new()
        } else {
            format!(
                " — outside {WIDE_MAX_ERROR_DB} dB / {WIDE_MAX_ERROR_DEG}° up to f_s/4: the continuous design's figures do not hold for what runs there; the loop check's are the discrete controller's"
            )
        };
        format!(
            "discretisation {}: within {:.3} dB / {:.2}° of the continuous design up to {:.0} Hz (f_s/10), {:.3} dB / {:.2}° up to {:.0} Hz (f_s/4); above, at most {:+.2} dB{miss}",
            self.method.as_str(),
            self.max_error_db,
            self.max_error_deg,
            self.up_to_hz,
            self.wide_max_error_db,
            self.wide_max_error_deg,
            self.wide_up_to_hz,
            self.above_band_max_excess_db
        )
    }

    /// The discrete controller is within [`WIDE_MAX_ERROR_DB`] /
    /// [`WIDE_MAX_ERROR_DEG`] of the design up to f_s/4.
    pub fn within_wide_target(&self) -> bool {
        self.wide_max_error_db <= WIDE_MAX_ERROR_DB && self.wide_max_error_deg <= WIDE_MAX_ERROR_DEG
    }
}

/// Largest gain error of the discrete controller up to f_s/4, dB: beyond
/// the measured band (a chirp's 500 Hz is f_s/10 at 5 kHz) the design is
/// judged on its continuous response, so what runs must stay near it
/// (issue 45).
pub const WIDE_MAX_ERROR_DB: f64 = 0.5;
/// Largest phase error of the discrete controller up to f_s/4, degrees.
pub const WIDE_MAX_ERROR_DEG: f64 = 3.0;

/// Tustin with pre-warp of a continuous section.
fn tustin(sec: &ContinuousSection, period_s: f64) -> Biquad {
    let k = match sec.prewarp_rad_s {
        Some(w) if w * period_s < PI * 0.9 => w / (w * period_s / 2.0).tan(),
        _ => 2.0 / period_s,
    };
    let k2 = k * k;
    // Multiply through by (1 + z⁻¹)^order, order = the section's degree, so
    // a first-order section stays first order (no cancelled pole at z = −1).
    let second_order = sec.b[2] != 0.0 || sec.a[2] != 0.0;
    let map = |c: &[f64; 3]| {
        if second_order {
            [
                c[2] * k2 + c[1] * k + c[0],
                -2.0 * c[2] * k2 + 2.0 * c[0],
                c[2] * k2 - c[1] * k + c[0],
            ]
        } else {
            [c[1] * k + c[0], -c[1] * k + c[0], 0.0]
        }
    };
    let n = map(&sec.b);
    let d = map(&sec.a);
    Biquad {
        b: [n[0] / d[0], n[1] / d[0], n[2] / d[0]],
        a: [d[1] / d[0], d[2] / d[0]],
    }
}

/// Matched denominator `[a1, a2]` of `1 + a1 z⁻¹ + a2 z⁻²`: each pole `p`
/// of the section maps to `z = e^{pT}` (integrators to `z = 1`).
fn matched_denominator(sec: &ContinuousSection, period_s: f64) -> [f64; 2] {
    let z: Vec<Complex<f64>> = sec.poles().iter().map(|p| (p * period_s).exp()).collect();
    match z.as_slice() {
        [] => [0.0, 0.0],
        [z1] => [-z1.re, 0.0],
        [z1, z2] => [-(z1 + z2).re, (z1 * z2).re],
        _ => unreachable!("a section has at most two poles"),
    }
}

/// Points of the least-squares fit grid (log-spaced, 5 decades below the
/// top of the band).
const FIT_POINTS: usize = 600;
/// Plain block-coordinate sweeps before the minimax reweighting.
const FIT_SWEEPS: usize = 60;
/// Lawson reweighting sweeps (towards the minimax fit).
const FIT_LAWSON_SWEEPS: usize = 30;

/// Weighted least squares for one numerator `[b0, b1, b2]`: minimises
/// `Σ w_k² |(b0 + b1 z_k⁻¹ + b2 z_k⁻²) g_k − 1|²` over the grid.
fn fit_numerator(zinv: &[Complex<f64>], g: &[Complex<f64>], w: &[f64]) -> Option<[f64; 3]> {
    let rows: Vec<usize> = (0..g.len())
        .filter(|&k| g[k].re.is_finite() && g[k].im.is_finite() && w[k] > 0.0)
        .collect();
    let m = rows.len();
    if m < 3 {
        return None;
    }
    let mut a = DMatrix::<f64>::zeros(2 * m, 3);
    let mut r = DMatrix::<f64>::zeros(2 * m, 1);
    for (row, &k) in rows.iter().enumerate() {
        let mut basis = g[k] * w[k];
        for col in 0..3 {
            a[(row, col)] = basis.re;
            a[(m + row, col)] = basis.im;
            basis *= zinv[k];
        }
        r[(row, 0)] = w[k];
    }
    if a.iter().chain(r.iter()).any(|v| !v.is_finite()) {
        return None;
    }
    // A = Q R (Householder, Q with orthonormal columns): the least squares
    // of `A b ≈ r` are those of `R b ≈ Qᵀ r`, a 3 × 3 problem, solved by
    // the SVD (rank-revealing; A's singular values are R's). Bounded: an
    // SVD that does not converge is a failed fit (Tustin runs).
    let qr = a.qr();
    let mut qtr = r;
    qr.q_tr_mul(&mut qtr);
    let b = qr
        .r()
        .try_svd(
            true,
            true,
            f64::EPSILON,
            bench_plant::model::MAX_EIGEN_ITERATIONS,
        )?
        .solve(&qtr.rows(0, 3), 1e-300)
        .ok()?;
    let out = [b[(0, 0)], b[(1, 0)], b[(2, 0)]];
    out.iter().all(|x| x.is_finite()).then_some(out)
}

/// Least-squares discretisation of the sections (the product of whose
/// responses is `target(ω) = C(jω)/g`): poles matched, then the section
/// numerators are fitted jointly, one at a time with the others held
/// (each step is linear), first in plain least squares on the relative
/// error, then with Lawson's reweighting towards the smallest largest
/// error, on a log grid up to `f_max_hz`. `None` when the fit fails
/// numerically.
fn least_squares(
    secs: &[ContinuousSection],
    target: &dyn Fn(f64) -> Complex<f64>,
    period_s: f64,
    f_max_hz: f64,
) -> Option<Vec<Biquad>> {
    let f_lo = f_max_hz * 1e-5;
    let omega: Vec<f64> = (0..FIT_POINTS)
        .map(|k| 2.0 * PI * f_lo * (f_max_hz / f_lo).powf(k as f64 / (FIT_POINTS - 1) as f64))
        .collect();
    let zinv: Vec<Complex<f64>> = omega
        .iter()
        .map(|w| Complex::from_polar(1.0, -w * period_s))
        .collect();
    let h: Vec<Complex<f64>> = omega.iter().map(|w| target(*w)).collect();
    let dens: Vec<[f64; 2]> = secs
        .iter()
        .map(|s| matched_denominator(s, period_s))
        .collect();
    let den = |i: usize, k: usize| {
        let z = zinv[k];
        Complex::new(1.0, 0.0) + z * dens[i][0] + z * z * dens[i][1]
    };
    let num = |b: &[f64; 3], k: usize| {
        let z = zinv[k];
        z * b[1] + z * z * b[2] + b[0]
    };
    let mut w = vec![1.0; FIT_POINTS];
    // Start: each section fitted to its own continuous response.
    let mut nums: Vec<[f64; 3]> = Vec::with_capacity(secs.len());
    for (i, sec) in secs.iter().enumerate() {
        let g: Vec<Complex<f64>> = (0..FIT_POINTS)
            .map(|k| 1.0 / (den(i, k) * sec.eval(Complex::new(0.0, omega[k]))))
            .collect();
        nums.push(fit_numerator(&zinv, &g, &w)?);
    }
    let mut g = vec![Complex::new(0.0, 0.0); FIT_POINTS];
    for sweep in 0..FIT_SWEEPS + FIT_LAWSON_SWEEPS {
        for i in 0..secs.len() {
            for (k, gk) in g.iter_mut().enumerate() {
                let mut other = Complex::new(1.0, 0.0) / (den(i, k) * h[k]);
                for (j, b) in nums.iter().enumerate() {
                    if j != i {
                        other *= num(b, k) / den(j, k);
                    }
                }
                *gk = other;
            }
            nums[i] = fit_numerator(&zinv, &g, &w)?;
        }
        if sweep >= FIT_SWEEPS {
            let e: Vec<f64> = (0..FIT_POINTS)
                .map(|k| {
                    let mut r = Complex::new(1.0, 0.0) / h[k];
                    for (j, b) in nums.iter().enumerate() {
                        r *= num(b, k) / den(j, k);
                    }
                    let e = (r - 1.0).norm();
                    if e.is_finite() {
                        e
                    } else {
                        0.0
                    }
                })
                .collect();
            let e_max = e.iter().copied().fold(0.0, f64::max);
            if e_max <= 0.0 {
                break;
            }
            for (wk, ek) in w.iter_mut().zip(&e) {
                *wk = *wk * (ek / e_max).sqrt() + 1e-12;
            }
            let w_max = w.iter().copied().fold(0.0, f64::max);
            w.iter_mut().for_each(|x| *x /= w_max);
        }
    }
    Some(
        nums.iter()
            .zip(&dens)
            .map(|(b, a)| Biquad { b: *b, a: *a })
            .collect(),
    )
}

/// `g · Π sections(e^{jθ})`: the discrete controller's response at
/// `θ = ωT` (rad/sample).
pub(super) fn cascade_response(gain: f64, sections: &[Biquad], theta: f64) -> Complex<f64> {
    sections
        .iter()
        .fold(Complex::new(gain, 0.0), |acc, s| acc * s.response(theta))
}

/// Largest `20 log10 |C_d/C|` from `f_lo_hz` to just below Nyquist, dB.
fn above_band_excess_db(
    cfg: &ControllerConfig,
    sections: &[Biquad],
    period_s: f64,
    f_lo_hz: f64,
) -> f64 {
    let f_hi = 0.498 / period_s;
    let points = 800;
    (0..=points)
        .map(|i| {
            let w = 2.0 * PI * (f_lo_hz + (f_hi - f_lo_hz) * i as f64 / points as f64);
            let hd = cascade_response(cfg.gain, sections, w * period_s);
            20.0 * (hd.norm() / cfg.response(w).norm()).log10()
        })
        .filter(|x| x.is_finite())
        .fold(f64::NEG_INFINITY, f64::max)
}

/// Largest |dB| and |°| error of the cascade `g·Π sections` against
/// `C(jω)` on a log grid from 0.1 Hz to `f_max_hz` (points where either is
/// 0 or not finite, e.g. the centre of an undamped notch, are skipped).
fn cascade_error(
    cfg: &ControllerConfig,
    sections: &[Biquad],
    period_s: f64,
    f_max_hz: f64,
) -> (f64, f64) {
    let (mut db, mut deg) = (0.0f64, 0.0f64);
    let points = 800;
    for i in 0..=points {
        let f = 0.1 * (f_max_hz / 0.1f64).powf(i as f64 / points as f64);
        let w = 2.0 * PI * f;
        let r = cascade_response(cfg.gain, sections, w * period_s) / cfg.response(w);
        if r.norm() > 0.0 && r.re.is_finite() && r.im.is_finite() {
            db = db.max((20.0 * r.norm().log10()).abs());
            deg = deg.max(r.arg().to_degrees().abs());
        }
    }
    (db, deg)
}

/// Discretises `cfg` at `period_s` (see the module docs): Tustin with
/// pre-warp per section or, when asked for and no worse, matched poles with
/// fitted numerators. Returns the sections that run and the report on them.
pub(super) fn discretize(
    cfg: &ControllerConfig,
    period_s: f64,
) -> (Vec<Biquad>, DiscretizationReport) {
    let mut secs = sections(cfg);
    if cfg.discretization == Discretization::Bilinear {
        for s in &mut secs {
            s.prewarp_rad_s = None;
        }
    }
    let up_to_hz = 0.1 / period_s;
    let wide_up_to_hz = 0.25 / period_s;
    let tustin: Vec<Biquad> = secs.iter().map(|s| tustin(s, period_s)).collect();
    let tustin_error = cascade_error(cfg, &tustin, period_s, up_to_hz);
    let plain = if cfg.discretization == Discretization::Bilinear {
        Discretization::Bilinear
    } else {
        Discretization::Tustin
    };
    let mut chosen = (plain, tustin, tustin_error);
    if cfg.discretization == Discretization::LeastSquares {
        let target = |w: f64| cfg.response(w) / cfg.gain;
        // One extra all-zero section (poles at z = 0) gives the fit
        // three more numerator taps when there is room for it.
        let mut fit_secs = secs.clone();
        if fit_secs.len() < MAX_SECTIONS {
            fit_secs.push(ContinuousSection {
                b: [1.0, 0.0, 0.0],
                a: [1.0, 0.0, 0.0],
                prewarp_rad_s: None,
            });
        }
        if let Some(fit) = least_squares(&fit_secs, &target, period_s, up_to_hz) {
            let e = cascade_error(cfg, &fit, period_s, up_to_hz);
            // Keep the fit unless it is worse than Tustin (on the scale
            // of the 0.1 dB / 1° target); the report says what runs.
            if (e.0 / 0.1).max(e.1) <= (tustin_error.0 / 0.1).max(tustin_error.1) {
                chosen = (Discretization::LeastSquares, fit, e);
            }
        }
    }
    let (method, biquads, (max_error_db, max_error_deg)) = chosen;
    // The wide band is reported, not fitted: a fit to f_s/4 (tolerance 3
    // above f_s/10) met 0.5 dB / 3° there but left Eq. (6-7) 0.04 dB /
    // 0.25° off up to f_s/10 and |C_d/C − 1| = 4.9e-3 where its margins
    // are read, ten times what the fit to f_s/10 leaves (issue 45).
    let (wide_db, wide_deg) = cascade_error(cfg, &biquads, period_s, wide_up_to_hz);
    let report = DiscretizationReport {
        method,
        max_error_db,
        max_error_deg,
        up_to_hz,
        wide_max_error_db: wide_db,
        wide_max_error_deg: wide_deg,
        wide_up_to_hz,
        above_band_max_excess_db: above_band_excess_db(cfg, &biquads, period_s, up_to_hz),
    };
    (biquads, report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::continuous::tests::{bare, fast, slow};
    use crate::control::{ComplexPair, DiscreteController, Form};

    /// Largest |dB| and |deg| error of the discrete response vs the
    /// continuous one on a log grid from 0.1 Hz to `f_max_hz`.
    fn max_error(cfg: &ControllerConfig, period_s: f64, f_max_hz: f64) -> (f64, f64) {
        let d = DiscreteController::new(cfg, period_s, f64::INFINITY);
        let (mut db, mut deg) = (0.0f64, 0.0f64);
        for i in 0..=400 {
            let f = 0.1 * (f_max_hz / 0.1f64).powf(i as f64 / 400.0);
            let w = 2.0 * PI * f;
            let (hc, hd) = (cfg.response(w), d.response(w, period_s));
            db = db.max((20.0 * (hd.norm() / hc.norm()).log10()).abs());
            deg = deg.max((hd / hc).arg().to_degrees().abs());
        }
        (db, deg)
    }

    fn with(cfg: ControllerConfig, d: Discretization) -> ControllerConfig {
        ControllerConfig {
            discretization: d,
            ..cfg
        }
    }

    /// The shipped config's controllers, as they run.
    fn shipped() -> Vec<(String, ControllerConfig)> {
        let p =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
        let cfg = crate::config::BenchConfig::load(&p).unwrap();
        ["slow", "fast"]
            .iter()
            .map(|n| (n.to_string(), cfg.controller[*n].clone()))
            .collect()
    }

    /// Issue acceptance: each discrete controller matches the continuous
    /// one within 0.1 dB / 1° up to a tenth of the sample rate. The
    /// reference is the continuous factored form (checked against the
    /// printed equations above), evaluated independently of the sections.
    #[test]
    fn frequency_response_matches_the_continuous_controller() {
        let t = 200e-6; // 5 kHz: f_s/10 = 500 Hz
        let ship = shipped();
        let same = |a: &ControllerConfig, b: ControllerConfig| {
            assert_eq!(
                ControllerConfig {
                    description: String::new(),
                    ..a.clone()
                },
                ControllerConfig {
                    description: String::new(),
                    ..with(b, Discretization::LeastSquares)
                }
            )
        };
        same(&ship[0].1, slow());
        same(&ship[1].1, fast());
        for (name, cfg) in &ship {
            let (db, deg) = max_error(cfg, t, 500.0);
            eprintln!("{name} (least squares): to 500 Hz max {db:.4} dB, {deg:.4}°");
            assert!(db <= 0.1 && deg <= 1.0, "{name} to f_s/10: {db} dB, {deg}°");
            let d = DiscreteController::new(cfg, t, f64::INFINITY);
            let r = d.discretization();
            assert_eq!(r.method, Discretization::LeastSquares);
            assert!((r.up_to_hz - 500.0).abs() < 1e-9);
            assert!((r.max_error_db - db).abs() < 0.02 && (r.max_error_deg - deg).abs() < 0.2);
        }
        // Tustin with pre-warp: the documented ranges, 0.1 dB / 1° to
        // 150 Hz (slow) and 240 Hz (fast).
        for (name, cfg, f) in [("slow", slow(), 150.0), ("fast", fast(), 240.0)] {
            for f in [100.0, 150.0, 200.0, 300.0, 500.0] {
                let (db, deg) = max_error(&cfg, t, f);
                eprintln!("{name} (Tustin): up to {f} Hz max {db:.3} dB, {deg:.3}°");
            }
            let (db, deg) = max_error(&cfg, t, f);
            assert!(db <= 0.1 && deg <= 1.0, "{name} to {f} Hz: {db} dB, {deg}°");
            let (db, deg) = max_error(&cfg, t, 500.0);
            assert!(db <= 0.9 && deg <= 1.5, "{name} to fs/10: {db} dB, {deg}°");
            assert_eq!(
                DiscreteController::new(&cfg, t, f64::INFINITY)
                    .discretization()
                    .method,
                Discretization::Tustin
            );
        }
    }

    /// Above the fitted band (f_s/10 to Nyquist) the least-squares
    /// controllers exceed the continuous gain by at most 1.5 dB, where the
    /// design is already far below crossover, and the report says by how
    /// much. (Tustin, whose zeros at z = −1 pull it to nothing at Nyquist,
    /// has less gain there.)
    #[test]
    fn least_squares_gain_above_the_band_is_bounded_and_reported() {
        let t = 200e-6;
        for (name, cfg) in shipped() {
            let d = DiscreteController::new(&cfg, t, f64::INFINITY);
            let mut worst = (f64::NEG_INFINITY, 0.0);
            for i in 0..=400 {
                let f = 500.0 + (2490.0 - 500.0) * i as f64 / 400.0;
                let w = 2.0 * PI * f;
                let db = 20.0 * (d.response(w, t).norm() / cfg.response(w).norm()).log10();
                if db > worst.0 {
                    worst = (db, f);
                }
            }
            eprintln!(
                "{name}: above f_s/10 at most {:.3} dB over the design (at {:.0} Hz)",
                worst.0, worst.1
            );
            assert!(worst.0 < 1.5, "{name}: {} dB at {} Hz", worst.0, worst.1);
            let r = d.discretization().above_band_max_excess_db;
            assert!(
                (r - worst.0).abs() < 0.05,
                "reported {r} dB, found {} dB",
                worst.0
            );
        }
    }

    /// Issue 45: the report states the error up to f_s/4 as an
    /// independent grid finds it, and whether the 0.5 dB / 3° target
    /// holds there (the slow controller's does; the fast one's gain rises
    /// above it between f_s/10 and f_s/4, and the report says so).
    #[test]
    fn the_report_states_the_error_to_a_quarter_of_the_rate() {
        let t = 200e-6;
        let mut cases = shipped();
        cases.push((
            "slow, least squares".into(),
            with(slow(), Discretization::LeastSquares),
        ));
        cases.push((
            "fast, least squares".into(),
            with(fast(), Discretization::LeastSquares),
        ));
        for (name, cfg) in cases {
            let (db, deg) = max_error(&cfg, t, 1250.0);
            let d = DiscreteController::new(&cfg, t, f64::INFINITY);
            let r = d.discretization();
            eprintln!("{name}: to f_s/4 max {db:.3} dB, {deg:.3}°; {}", r.line());
            assert!((r.wide_up_to_hz - 1250.0).abs() < 1e-9);
            assert!(
                (r.wide_max_error_db - db).abs() < 0.05 && (r.wide_max_error_deg - deg).abs() < 0.3,
                "{name}: {r:?}"
            );
            assert_eq!(
                r.within_wide_target(),
                db <= WIDE_MAX_ERROR_DB && deg <= WIDE_MAX_ERROR_DEG,
                "{name}"
            );
        }
    }

    #[test]
    fn least_squares_poles_are_matched() {
        let t = 200e-6;
        let cfg = with(fast(), Discretization::LeastSquares);
        let d = DiscreteController::new(&cfg, t, f64::INFINITY);
        let mut got: Vec<Complex<f64>> = Vec::new();
        // The fit's extra all-zero section (poles at z = 0) adds no pole.
        for s in d.sections().iter().filter(|s| s.a != [0.0, 0.0]) {
            let (a1, a2) = (s.a[0], s.a[1]);
            let disc = Complex::new(a1 * a1 - 4.0 * a2, 0.0).sqrt();
            if a2 == 0.0 {
                got.push(Complex::new(-a1, 0.0));
            } else {
                got.push((-a1 + disc) / 2.0);
                got.push((-a1 - disc) / 2.0);
            }
        }
        let pair = |w: f64, z: f64| {
            let p = Complex::new(-z * w, w * (1.0 - z * z).sqrt());
            [(p * t).exp(), (p.conj() * t).exp()]
        };
        let mut want = vec![
            Complex::new(1.0, 0.0),
            Complex::new((-625.0 * t).exp(), 0.0),
            Complex::new((-893.0 * t).exp(), 0.0),
        ];
        want.extend(pair(700.0, 0.7));
        want.extend(pair(555.0, 0.1));
        assert_eq!(got.len(), want.len());
        for w in &want {
            let best = got
                .iter()
                .map(|g| (g - w).norm())
                .fold(f64::INFINITY, f64::min);
            assert!(best < 1e-9, "pole {w} not found in {got:?}");
        }
    }

    /// Beyond the thesis: other controllers a lab writes (PI + roll-off,
    /// lead-lag, double integrator, an undamped notch) are never worse
    /// with least squares than with Tustin, and within 0.1 dB / 1° to
    /// f_s/10 (the centre of the undamped notch, where C = 0, excepted).
    #[test]
    fn least_squares_on_other_controllers() {
        let t = 200e-6;
        let base = with(bare(1.0), Discretization::LeastSquares);
        let pi_rolloff = ControllerConfig {
            integrators: 1,
            real_zeros_rad_s: vec![30.0],
            real_poles_rad_s: vec![2000.0],
            ..base.clone()
        };
        let lead_lag = ControllerConfig {
            real_zeros_rad_s: vec![5.0, 300.0],
            real_poles_rad_s: vec![0.5, 3000.0],
            ..base.clone()
        };
        let double_integrator = ControllerConfig {
            integrators: 2,
            real_zeros_rad_s: vec![50.0],
            real_poles_rad_s: vec![1500.0],
            ..base.clone()
        };
        let undamped_notch = ControllerConfig {
            integrators: 1,
            complex_zeros: vec![ComplexPair {
                omega_rad_s: 1000.0,
                zeta: 0.0,
            }],
            complex_poles: vec![ComplexPair {
                omega_rad_s: 1000.0,
                zeta: 0.3,
            }],
            ..base.clone()
        };
        for (name, cfg) in [
            ("PI + roll-off", pi_rolloff),
            ("lead-lag", lead_lag),
            ("double integrator", double_integrator),
            ("undamped notch", undamped_notch),
        ] {
            let (db, deg) = max_error(&cfg, t, 500.0);
            let (tdb, tdeg) = max_error(&with(cfg.clone(), Discretization::Tustin), t, 500.0);
            eprintln!("{name}: least squares {db:.4} dB {deg:.4}°; Tustin {tdb:.4} dB {tdeg:.4}°");
            assert!(
                (db / 0.1).max(deg) <= (tdb / 0.1).max(tdeg) + 1e-9,
                "{name}"
            );
            assert!(db <= 0.1 && deg <= 1.0, "{name}: {db} dB, {deg}°");
        }
    }

    /// A controller that fills all sections leaves no room for the extra
    /// all-zero section; the fit still runs and is never worse than Tustin.
    #[test]
    fn least_squares_with_every_section_in_use() {
        let t = 200e-6;
        let pairs = |w0: f64, z: f64| {
            (0..MAX_SECTIONS)
                .map(|i| ComplexPair {
                    omega_rad_s: w0 * 1.4f64.powi(i as i32),
                    zeta: z,
                })
                .collect::<Vec<_>>()
        };
        let cfg = ControllerConfig {
            form: Form::UnityDc,
            complex_zeros: pairs(60.0, 0.3),
            complex_poles: pairs(50.0, 0.5),
            discretization: Discretization::LeastSquares,
            ..bare(1.0)
        };
        cfg.validate("controller.big").unwrap();
        let d = DiscreteController::new(&cfg, t, f64::INFINITY);
        assert_eq!(d.sections().len(), MAX_SECTIONS);
        let (db, deg) = max_error(&cfg, t, 500.0);
        let (tdb, tdeg) = max_error(&with(cfg, Discretization::Tustin), t, 500.0);
        eprintln!("12 sections: least squares {db:.4} dB {deg:.4}°; Tustin {tdb:.4} dB {tdeg:.4}°");
        assert!((db / 0.1).max(deg) <= (tdb / 0.1).max(tdeg) + 1e-9);
    }

    /// Why 0.1 dB at f_s/10 is out of reach for any bilinear map: for
    /// 1/s, `s = K(z−1)/(z+1)` gives `|C_d/C| = ω / (K tan(ωT/2))`, which
    /// is `2/(KT)` at low frequency and falls by `(θ/2)/tan(θ/2)` at
    /// θ = ωT. The best K splits that droop evenly, and even that leaves
    /// ±0.147 dB at θ = 2π/10. Our integrator section (K = 2/T) shows the
    /// whole droop, −0.29 dB, exactly as the formula says.
    #[test]
    fn tustin_integrator_droop_at_fs_over_10() {
        let t = 200e-6;
        let cfg = ControllerConfig {
            integrators: 1,
            ..bare(1.0)
        };
        let d = DiscreteController::new(&cfg, t, f64::INFINITY);
        let w = 2.0 * PI * 500.0;
        let theta = w * t;
        let droop = (theta / 2.0) / (theta / 2.0).tan();
        let ratio = d.response(w, t) / cfg.response(w);
        assert!(
            (ratio.norm() - droop).abs() < 1e-12,
            "{} vs {droop}",
            ratio.norm()
        );
        assert!(ratio.arg().abs() < 1e-12, "Tustin's integrator keeps −90°");
        // The best any K can do is half the droop in dB, still above 0.1.
        let best_db = -10.0 * droop.log10();
        assert!(
            (best_db - 0.147).abs() < 0.001 && best_db > 0.1,
            "{best_db}"
        );
    }

    #[test]
    fn notch_centre_is_kept_by_the_prewarp() {
        let t = 200e-6;
        let c = fast();
        let d = DiscreteController::new(&c, t, f64::INFINITY);
        let argmin = |f: &dyn Fn(f64) -> f64| {
            let mut best = (0.0, f64::INFINITY);
            let mut w = 500.0;
            while w < 540.0 {
                if f(w) < best.1 {
                    best = (w, f(w));
                }
                w += 0.005;
            }
            best.0
        };
        let wc = argmin(&|w| c.response(w).norm());
        let wd = argmin(&|w| d.response(w, t).norm());
        assert!(
            (wd / wc - 1.0).abs() < 2e-4,
            "notch at {wd} rad/s, continuous {wc} rad/s"
        );
    }
}
