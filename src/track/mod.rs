//! Tracking a periodic scan: the reference, the model-inverse feedforward
//! and frequency-domain iterative learning control (ILC), for `bench
//! track` ([`crate::jobs::track`]).
//!
//! Every signal here is periodic with the scan's period of `N` ticks and is
//! held as its harmonics: `x[n] = X₀ + Σₖ Re(Xₖ·e^{j2πkn/N})`, `k = 1…K`
//! ([`Harmonics`]). The tick plays one period of each as a table
//! ([`TrackJob`]); the analysis between trials works on the harmonics.
//!
//! - **Reference** ([`Scan`]): a sine, a point-to-point move and back
//!   (a 3rd- or 4th-order profile, [`profile`], played whole; its settling
//!   measured by [`settle()`]), or a triangle (a raster line) of
//!   amplitude `A` whose Fourier series `(8A/π²)·Σ_{k odd} (−1)^{(k−1)/2}
//!   sin(kωt)/k²` is truncated below the cut-off and smoothed with the
//!   Lanczos σ factors `sinc(k/k_c)` (Gibbs' overshoot removed; Lanczos,
//!   *Applied Analysis*, 1956, §IV.6).
//! - **The band the zeros close** ([`ZeroBand`]): every zero `z` of the
//!   plant takes its factor `|1 − jω/z|·|1 − jω/z̄| ≈ |1 − ω²/|z|²|`
//!   (lightly damped pair) below ½ for `ω` within `[|z|/√2, |z|·√1.5]`: there the plant answers
//!   at most half what it would without the zero, and at the zero itself
//!   nothing, whatever the controller (`T(z) = 0`) and whatever the
//!   feedforward costs. The default cut-off is the lowest band's lower
//!   edge.
//! - **Feedforward** ([`model_inverse`]): with `u = C(r − y) + f` the error
//!   is `e = r − y = S·(r − P·f)`, so `F_k = R_k / P(jω_k)` tracks every
//!   kept harmonic exactly on the model. For a periodic reference this is
//!   the stable (non-causal) inversion of Devasia, Chen and Paden (IEEE
//!   TAC 41(7), 1996) with a whole period of preview: the non-minimum-phase
//!   zeros need no causal inverse. The alternative, [`DerivativeGains`],
//!   feeds forward the reference's derivatives with the gains of `1/P`'s
//!   Taylor series (acceleration and snap feedforward).
//! - **ILC** ([`Learning`]): `F_{j+1,k} = Q_k·(F_{j,k} + L_k·E_{j,k})`
//!   with `L_k = α / PS_model(jω_k)` and `Q_k` 1 on the learned harmonics
//!   (below the cut-off), 0 elsewhere (Bristow, Tharayil and Alleyne, IEEE
//!   CSM 26(3), 2006, §"frequency-domain design"). On the true plant the
//!   error of a learned harmonic is multiplied each trial by `1 − L_k·PS_k`;
//!   monotonic convergence needs `|Q_k(1 − L_k·PS_k)| < 1` on every line.
//!   With a measured `PS` ([`measured`]) `L_k = α / P̂S(jω_k)` and `Q_k`
//!   is 1 only where that condition holds at the measurement's 2σ.
//!
//! Layer rule: may use `analysis`, `config`, `control`, `ident`, `rt`.

use crate::control::verify::ModelLoop;
use crate::control::DiscreteController;
use crate::rt::{Job, JobOutput};
use bench_hal::Sample;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

use crate::ident::C64;

pub mod measured;
pub mod profile;
pub mod settle;
pub use profile::{MoveLimits, MoveProfile};
pub use settle::{settle, Settle};

/// How far below a zero's frequency its band reaches, as a factor: `1/√2`,
/// where a lightly damped zero pair's factor `|1 − ω²/|z|²|` rises to ½.
pub const ZERO_BAND_LOW: f64 = std::f64::consts::FRAC_1_SQRT_2;

/// How far above a zero's frequency its band reaches, as a factor: `√1.5`,
/// where the factor `|1 − ω²/|z|²|` falls to ½.
pub const ZERO_BAND_HIGH: f64 = 1.224_744_871_391_589;

pub use crate::config::ScanKind;

/// A scan definition: what the user asks for.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Scan {
    /// Sine or triangle.
    pub kind: ScanKind,
    /// Amplitude about the start position, m (the triangle's peak before
    /// smoothing).
    pub amplitude_m: f64,
    /// Lines per second: the scan's fundamental, Hz.
    pub line_rate_hz: f64,
    /// Harmonics at or above this frequency are removed, Hz (a move's
    /// reference is played whole; its feedforward and learning stop
    /// there).
    pub cutoff_hz: f64,
    /// A move's limits (its profile: [`MoveProfile::plan`]); `None` for a
    /// scan.
    #[serde(default)]
    pub move_limits: Option<MoveLimits>,
    /// A reference read from a CSV: the file (`None` for the other
    /// kinds).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_csv: Option<std::path::PathBuf>,
    /// Its line, one position per tick about the start position, m (not
    /// in the JSON: the file holds it).
    #[serde(skip)]
    #[schemars(skip)]
    pub reference: Option<Vec<f64>>,
}

/// One period's harmonics `X₀, X₁ … X_K` of a signal of period `N` ticks
/// (module docs); units those of the signal.
#[derive(Debug, Clone, PartialEq)]
pub struct Harmonics {
    /// `X₀ … X_K`.
    pub coef: Vec<C64>,
    /// Ticks per period.
    pub period_ticks: usize,
}

impl Harmonics {
    /// All zero, harmonics `0…k_max`.
    pub fn zeros(k_max: usize, period_ticks: usize) -> Self {
        Self {
            coef: vec![C64::new(0.0, 0.0); k_max + 1],
            period_ticks,
        }
    }

    /// One period of samples, `N` values.
    pub fn synthesize(&self) -> Vec<f64> {
        let n = self.period_ticks;
        (0..n)
            .map(|i| {
                let th = 2.0 * PI * i as f64 / n as f64;
                self.coef
                    .iter()
                    .enumerate()
                    .map(|(k, c)| {
                        if k == 0 {
                            c.re
                        } else {
                            (c * C64::from_polar(1.0, k as f64 * th)).re
                        }
                    })
                    .sum()
            })
            .collect()
    }

    /// The harmonics `0…k_max` of one period `x` (`N` = its length): the
    /// discrete Fourier sums `X₀ = Σx/N`, `X_k = 2·Σ x[n]e^{−j2πkn/N}/N`.
    pub fn analyze(x: &[f64], k_max: usize) -> Self {
        let n = x.len();
        let coef = (0..=k_max)
            .map(|k| {
                let s: C64 = x
                    .iter()
                    .enumerate()
                    .map(|(i, v)| C64::from_polar(*v, -2.0 * PI * (k * i % n) as f64 / n as f64))
                    .sum();
                if k == 0 {
                    s / n as f64
                } else {
                    s * 2.0 / n as f64
                }
            })
            .collect();
        Self {
            coef,
            period_ticks: n,
        }
    }

    /// The frequency of harmonic `k` at `line_rate_hz`, Hz.
    pub fn frequency_hz(k: usize, line_rate_hz: f64) -> f64 {
        k as f64 * line_rate_hz
    }

    /// RMS over one period, from Parseval: `√(X₀² + Σ|X_k|²/2)`.
    pub fn rms(&self) -> f64 {
        let dc = self.coef.first().map_or(0.0, |c| c.re * c.re);
        let ac: f64 = self.coef.iter().skip(1).map(|c| c.norm_sqr() / 2.0).sum();
        (dc + ac).sqrt()
    }
}

/// The frequency band around one zero of the plant in which it answers at
/// most half (module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ZeroBand {
    /// The zero's frequency `|z|/2π`, Hz.
    pub zero_hz: f64,
    /// MMP, RMP-RNMP or CMP-CNMP.
    pub kind: String,
    /// Lower edge `|z|/(2π·√2)`, Hz.
    pub low_hz: f64,
    /// Upper edge `|z|·√1.5/2π`, Hz.
    pub high_hz: f64,
}

impl ZeroBand {
    /// The bands of the zeros of the model ([`crate::analysis::modal::damped_zeros`]),
    /// one per pair: the right-half-plane zeros in the upper half plane
    /// (and on the real axis), and the minimum-phase ones that mirror none
    /// (MMP); ascending.
    pub fn of(zeros: &[crate::analysis::modal::TypedZero]) -> Vec<Self> {
        use bench_plant::model::ZeroType;
        let mut out: Vec<Self> = zeros
            .iter()
            .filter(|z| z.im_rad_s >= 0.0 && z.frequency_hz > 0.0)
            .filter(|z| z.nmp() || z.kind == ZeroType::Mmp)
            .map(|z| Self {
                zero_hz: z.frequency_hz,
                kind: z.kind.as_str().to_string(),
                low_hz: z.frequency_hz * ZERO_BAND_LOW,
                high_hz: z.frequency_hz * ZERO_BAND_HIGH,
            })
            .collect();
        out.sort_by(|a, b| a.zero_hz.total_cmp(&b.zero_hz));
        out
    }

    /// Whether the band is a right-half-plane zero's (RMP-RNMP or
    /// CMP-CNMP): no loop tracks there (`T(z) = 0`); an MMP band only
    /// closes itself.
    pub fn right_half_plane(&self) -> bool {
        self.kind != "MMP"
    }

    /// Whether `f_hz` lies in the band.
    pub fn contains(&self, f_hz: f64) -> bool {
        f_hz >= self.low_hz && f_hz <= self.high_hz
    }
}

/// Lanczos' σ factor of harmonic `k` below the cut-off harmonic `k_c`
/// (`sinc(k/k_c)`; 1 at `k = 0`).
fn lanczos_sigma(k: usize, k_c: f64) -> f64 {
    let x = PI * k as f64 / k_c;
    if x == 0.0 {
        1.0
    } else {
        x.sin() / x
    }
}

impl Scan {
    /// Whether the reference is played whole, as planned or read (a move,
    /// a CSV): the cut-off bounds only its feedforward and learning, and
    /// nothing is removed from it.
    pub fn played_whole(&self) -> bool {
        matches!(self.kind, ScanKind::Move | ScanKind::Csv)
    }

    /// The highest harmonic kept: the last `k` with `k·line_rate < cutoff`.
    pub fn k_max(&self) -> usize {
        let k = (self.cutoff_hz / self.line_rate_hz).ceil() as usize;
        k.saturating_sub(1)
    }

    /// What the scan is, for a title: `triangle scan ±5.00 µm at 10
    /// lines/s`, or `move of 10.00 µm and back at 1 lines/s`.
    pub fn describe(&self) -> String {
        let um = self.amplitude_m * 1e6;
        let line = self.line_rate_hz;
        match self.kind {
            ScanKind::Sine => format!("sine scan ±{um:.2} µm at {line} lines/s"),
            ScanKind::Triangle => format!("triangle scan ±{um:.2} µm at {line} lines/s"),
            ScanKind::Move => format!("move of {um:.2} µm and back at {line} lines/s"),
            ScanKind::Csv => format!(
                "reference {} (peak {um:.2} µm) at {line} lines/s",
                self.reference_csv
                    .as_ref()
                    .and_then(|p| p.file_name())
                    .map_or("from a CSV".into(), |n| n.to_string_lossy())
            ),
        }
    }

    /// A move's profile: the amplitude within the limits; `None` for a
    /// scan.
    pub fn move_profile(&self) -> Option<MoveProfile> {
        match (self.kind, &self.move_limits) {
            (ScanKind::Move, Some(l)) => Some(MoveProfile::plan(self.amplitude_m, l)),
            _ => None,
        }
    }

    /// One line of the reference as the tick plays it, `period_ticks`
    /// values, m: a scan's harmonics ([`Self::harmonics`]) synthesised; a
    /// move's profile itself, up from tick 0 and back down from the middle
    /// of the line (`t = 1/(2·line_rate)`); a CSV's line as read (its
    /// length is the line's: the plan checks it).
    pub fn table(&self, period_ticks: usize) -> Vec<f64> {
        if let Some(r) = &self.reference {
            return r.clone();
        }
        if self.kind == ScanKind::Csv {
            // A CSV scan without its line (read back from JSON, where the
            // line is not) stands still; its harmonics analyse this table.
            return vec![0.0; period_ticks];
        }
        match self.move_profile() {
            Some(p) => {
                let dt = 1.0 / (self.line_rate_hz * period_ticks as f64);
                let half = 0.5 / self.line_rate_hz;
                (0..period_ticks)
                    .map(|i| {
                        let t = i as f64 * dt;
                        if t < half {
                            p.at(t)[0]
                        } else {
                            self.amplitude_m - p.at(t - half)[0]
                        }
                    })
                    .collect()
            }
            None => self.harmonics(period_ticks).synthesize(),
        }
    }

    /// The reference's harmonics at `period_ticks` per line, m: 0 at the
    /// start of the period, rising (module docs); a move's those of its
    /// table below the cut-off.
    pub fn harmonics(&self, period_ticks: usize) -> Harmonics {
        let k_max = self.k_max();
        let mut h = Harmonics::zeros(k_max, period_ticks);
        match self.kind {
            ScanKind::Move | ScanKind::Csv => {
                return Harmonics::analyze(&self.table(period_ticks), k_max)
            }
            ScanKind::Sine => {
                if k_max >= 1 {
                    h.coef[1] = C64::new(0.0, -self.amplitude_m);
                }
            }
            ScanKind::Triangle => {
                let k_c = self.cutoff_hz / self.line_rate_hz;
                for k in (1..=k_max).step_by(2) {
                    let sign = if (k / 2) % 2 == 0 { 1.0 } else { -1.0 };
                    let a = 8.0 * self.amplitude_m / (PI * PI) * sign / (k * k) as f64
                        * lanczos_sigma(k, k_c);
                    // a·sin(kθ) = Re(−j·a·e^{jkθ})
                    h.coef[k] = C64::new(0.0, -a);
                }
            }
        }
        h
    }
}

/// The model-inverse feedforward of `reference` (m) on `model`, A:
/// `F_k = R_k / P(jω_k)` (module docs), `F₀ = 0` (the controller's
/// integrator holds the mean).
pub fn model_inverse(reference: &Harmonics, model: &ModelLoop<'_>, line_rate_hz: f64) -> Harmonics {
    let mut f = Harmonics::zeros(reference.coef.len() - 1, reference.period_ticks);
    for (k, r) in reference.coef.iter().enumerate().skip(1) {
        f.coef[k] = r / model.plant(Harmonics::frequency_hz(k, line_rate_hz));
    }
    f
}

/// Which feedforward the feedforward trial plays.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum FeedforwardKind {
    /// The model's inverse on every kept harmonic ([`model_inverse`]).
    Inverse,
    /// Position, velocity, acceleration, jerk and snap feedforward
    /// ([`DerivativeGains`]).
    Snap,
}

impl std::str::FromStr for FeedforwardKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "inverse" => Ok(Self::Inverse),
            "snap" => Ok(Self::Snap),
            _ => Err(format!("{s:?} is not a feedforward (inverse or snap)")),
        }
    }
}

/// The feedforward of the reference's derivatives,
/// `f = c₀r + c₁ṙ + c₂r̈ + c₃r⃛ + c₄r⁽⁴⁾` (Lambrechts, Boerlage and
/// Steinbuch, Control Eng. Practice 13(2), 2005, §4: acceleration
/// feedforward from the mass, snap feedforward from the compliance): the
/// gains are the Taylor coefficients of `1/P(s)` at `s = 0`, the stage's
/// stiffness (`c₀`, A/m), damping and the loop's delay (`c₁`, A·s/m),
/// mass (`c₂`, A·s²/m), and the higher terms (`c₃`, A·s³/m; `c₄`,
/// A·s⁴/m, which holds the compliance of the modes above). That series
/// converges only below the plant's lowest zero (a pole of `1/P`), so
/// this feedforward is right for content well below it, and the model
/// inverse everywhere else.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct DerivativeGains {
    /// `c₀ … c₄`, A·sᵐ/m.
    pub gains: [f64; 5],
    /// The frequencies they were fitted on, Hz: the lowest and the
    /// highest.
    pub fitted_hz: (f64, f64),
}

impl DerivativeGains {
    /// The gains fitted by least squares to the model's `1/P(jω)` on 40
    /// lines log-spaced from 1 % to 30 % of `f_zero_hz` (the plant's
    /// lowest zero): `Re(1/P) = c₀ − c₂ω² + c₄ω⁴`, `Im(1/P) = c₁ω − c₃ω³`,
    /// each solved in `ω/ω_z` (scaled, so the columns are of one size).
    pub fn fit(model: &ModelLoop<'_>, f_zero_hz: f64) -> Self {
        use nalgebra::{DMatrix, DVector};
        let (lo, hi) = (0.01 * f_zero_hz, 0.3 * f_zero_hz);
        let n = 40;
        let f: Vec<f64> = (0..n)
            .map(|i| lo * (hi / lo).powf(i as f64 / (n - 1) as f64))
            .collect();
        let wz = 2.0 * PI * f_zero_hz;
        let inv: Vec<C64> = f.iter().map(|&f| 1.0 / model.plant(f)).collect();
        let x: Vec<f64> = f.iter().map(|&f| 2.0 * PI * f / wz).collect();
        let solve = |cols: &[&dyn Fn(f64) -> f64], y: &dyn Fn(usize) -> f64| -> Vec<f64> {
            let a = DMatrix::from_fn(n, cols.len(), |i, j| cols[j](x[i]));
            let b = DVector::from_fn(n, |i, _| y(i));
            a.svd(true, true)
                .solve(&b, 1e-14)
                .map_or(vec![f64::NAN; cols.len()], |v| v.iter().copied().collect())
        };
        let even = solve(&[&|_| 1.0, &|x: f64| -x * x, &|x: f64| x.powi(4)], &|i| {
            inv[i].re
        });
        let odd = solve(&[&|x| x, &|x: f64| -x.powi(3)], &|i| inv[i].im);
        Self {
            gains: [
                even[0],
                odd[0] / wz,
                even[1] / wz.powi(2),
                odd[1] / wz.powi(3),
                even[2] / wz.powi(4),
            ],
            fitted_hz: (lo, hi),
        }
    }

    /// The polynomial `Σ_m c_m·(jω)^m` at `f_hz`, A/m: the fitted `1/P`.
    pub fn at(&self, f_hz: f64) -> C64 {
        let jw = C64::new(0.0, 2.0 * PI * f_hz);
        self.gains
            .iter()
            .enumerate()
            .map(|(m, c)| c * jw.powi(m as i32))
            .sum()
    }

    /// The feedforward of `reference`'s harmonics, A:
    /// `F_k = Σ_m c_m·(jω_k)^m·R_k`, `F₀ = 0` (the integrator holds the
    /// mean).
    pub fn feedforward(&self, reference: &Harmonics, line_rate_hz: f64) -> Harmonics {
        let mut f = Harmonics::zeros(reference.coef.len() - 1, reference.period_ticks);
        for (k, r) in reference.coef.iter().enumerate().skip(1) {
            f.coef[k] = self.at(Harmonics::frequency_hz(k, line_rate_hz)) * r;
        }
        f
    }
}

/// The model's answer to a reference and a feedforward: the command
/// `u = CS·r + S·f` (A) and the error `e = S·(r − P·f)` (m), as harmonics.
pub fn predict(
    reference: &Harmonics,
    feedforward: &Harmonics,
    model: &ModelLoop<'_>,
    line_rate_hz: f64,
) -> (Harmonics, Harmonics) {
    let k_max = reference.coef.len() - 1;
    let mut u = Harmonics::zeros(k_max, reference.period_ticks);
    let mut e = Harmonics::zeros(k_max, reference.period_ticks);
    for k in 1..=k_max {
        let f_hz = Harmonics::frequency_hz(k, line_rate_hz);
        let s = model.sensitivity(f_hz);
        let c = model.controller(f_hz);
        let p = model.plant(f_hz);
        let (r, ff) = (reference.coef[k], feedforward.coef[k]);
        u.coef[k] = c * s * r + s * ff;
        e.coef[k] = s * (r - p * ff);
    }
    (u, e)
}

/// The learning law: `L_k = α/PS_model(jω_k)` on the learned harmonics
/// `1…K` (`Q_k = 1`), nothing elsewhere (`Q_k = 0`).
#[derive(Debug, Clone)]
pub struct Learning {
    /// `α`, the learning gain, (0, 1].
    pub gain: f64,
    /// `L_k`, A/m, `k = 0…K` (`L₀ = 0`: the integrator's).
    pub l: Vec<C64>,
    /// The `PS_k` the law inverts, m/A: the model's ([`Learning::new`]),
    /// or on the learned harmonics the one `bench control --verify`
    /// measured ([`measured::learning`]).
    pub ps_model: Vec<C64>,
}

impl Learning {
    /// The law on `model` for harmonics up to `k_max` at `line_rate_hz`.
    pub fn new(model: &ModelLoop<'_>, gain: f64, k_max: usize, line_rate_hz: f64) -> Self {
        let ps_model: Vec<C64> = (0..=k_max)
            .map(|k| model.process_sensitivity(Harmonics::frequency_hz(k, line_rate_hz)))
            .collect();
        let l = ps_model
            .iter()
            .enumerate()
            .map(|(k, ps)| {
                if k == 0 || ps.norm() == 0.0 {
                    C64::new(0.0, 0.0)
                } else {
                    gain / ps
                }
            })
            .collect();
        Self { gain, l, ps_model }
    }

    /// The law with nothing learned (`L_k = 0`: the feedforward of harmonic
    /// `k` stays as it is) on the harmonics inside a zero's band: there
    /// `|P|` and `|PS|` fall to their zero's and the model's relative error
    /// in `PS` grows without bound (a zero a few % off moves `PS_model`
    /// by its whole size), so `|1 − L·PS|` on the bench can exceed 1
    /// whatever the model says: the error of an unlearned harmonic stays,
    /// a learned one there can grow. Returns the harmonics left out.
    pub fn leave_out_bands(&mut self, bands: &[ZeroBand], line_rate_hz: f64) -> Vec<usize> {
        let mut out = Vec::new();
        for k in 1..self.l.len() {
            let f = Harmonics::frequency_hz(k, line_rate_hz);
            if bands.iter().any(|b| b.contains(f)) {
                self.l[k] = C64::new(0.0, 0.0);
                out.push(k);
            }
        }
        out
    }

    /// Whether harmonic `k` is learned (`L_k ≠ 0`).
    pub fn learns(&self, k: usize) -> bool {
        self.l.get(k).is_some_and(|l| l.norm() > 0.0)
    }

    /// One update: `F ← Q(F + L·E)`, `E` the trial's error harmonics (m).
    pub fn update(&self, f: &Harmonics, e: &Harmonics) -> Harmonics {
        let mut next = Harmonics::zeros(self.l.len() - 1, f.period_ticks);
        for k in 1..self.l.len() {
            next.coef[k] = f.coef[k] + self.l[k] * e.coef[k];
        }
        next
    }

    /// [`Self::update`] on the harmonics whose error stands out of the
    /// trial's noise: harmonic `k` is learned only when `|E_k| > 2σ_k`
    /// (`sigma[k]`, m: the 1σ of `E_k` from the scatter between the
    /// measured lines), else its feedforward stays. Learning what is noise
    /// feeds the noise back amplified by `|L_k| = α/|PS_k|`, which grows
    /// as the plant rolls off: on a bench whose scan keeps harmonics to
    /// 2.5 kHz, learning them all drove 0.65 A RMS of noise into the coil
    /// for a 5 µm scan that needs 0.03 A. A NaN `σ_k` (one measured line)
    /// learns the harmonic.
    pub fn update_significant(&self, f: &Harmonics, e: &Harmonics, sigma: &[f64]) -> Harmonics {
        let mut next = self.update(f, e);
        for k in 1..self.l.len() {
            let s = sigma.get(k).copied().unwrap_or(f64::NAN);
            if e.coef[k].norm() <= 2.0 * s {
                next.coef[k] = f.coef[k];
            }
        }
        next
    }

    /// `|Q_k(1 − L_k·PS_k)|` per learned harmonic for a plant `ps` (m/A,
    /// `k = 0…K`): the factor the error of harmonic `k` is multiplied by
    /// each trial.
    pub fn contraction(&self, ps: &[C64]) -> Vec<f64> {
        (1..self.l.len())
            .map(|k| (C64::new(1.0, 0.0) - self.l[k] * ps[k]).norm())
            .collect()
    }
}

/// The tracking job: the controller on the reference table plus the
/// feedforward table, both periodic. Both are faded in over the first
/// period with a raised cosine (bumpless: no step in the setpoint or the
/// current at the start), played at full amplitude to the end of line
/// `lines`, faded out over the next period, and held at zero for one more:
/// the stage ends where it started, still, before the loop lets it go (the
/// next job takes it at rest, as the supervisor's probe rules assume). The
/// setpoint is the first finite reading plus the reference. Real-time
/// safe: the tables are built before the run; the tick only indexes them.
#[derive(Debug, Clone)]
pub struct TrackJob {
    ctrl: DiscreteController,
    start_m: Option<f64>,
    reference_m: Box<[f64]>,
    feedforward_a: Box<[f64]>,
    lines: u64,
    /// `(lines + 2)·N`, set once.
    total_ticks: u64,
}

impl TrackJob {
    /// `reference_m` and `feedforward_a`: one period each, equal lengths
    /// (≥ 1); `lines` (≥ 1) periods played, the first faded in, then the
    /// fade-out and the hold.
    ///
    /// # Panics
    /// If the tables differ in length or are empty.
    pub fn new(
        ctrl: DiscreteController,
        reference_m: Vec<f64>,
        feedforward_a: Vec<f64>,
        lines: u64,
    ) -> Self {
        assert!(!reference_m.is_empty() && reference_m.len() == feedforward_a.len());
        let lines = lines.max(1);
        Self {
            total_ticks: (lines + 2) * reference_m.len() as u64,
            ctrl,
            start_m: None,
            reference_m: reference_m.into_boxed_slice(),
            feedforward_a: feedforward_a.into_boxed_slice(),
            lines,
        }
    }

    /// The weight of both tables at `tick`: `(1 − cos(π·tick/N))/2` over
    /// the first period, 1 to the end of line `lines`, `(1 + cos(π·t/N))/2`
    /// over the next period (`t` ticks into it), then 0.
    #[inline]
    pub fn fade(&self, tick: u64) -> f64 {
        let n = self.reference_m.len() as u64;
        let end = self.lines * n;
        if tick >= end + n {
            0.0
        } else if tick >= end {
            0.5 * (1.0 + (PI * (tick - end) as f64 / n as f64).cos())
        } else if tick >= n {
            1.0
        } else {
            0.5 * (1.0 - (PI * tick as f64 / n as f64).cos())
        }
    }

    /// Ticks of the trial: `lines + 2` periods.
    pub fn total_ticks(&self) -> u64 {
        self.total_ticks
    }
}

impl Job for TrackJob {
    #[inline]
    fn tick(&mut self, tick: u64, sample: &Sample) -> JobOutput {
        let y = sample.position_m;
        if self.start_m.is_none() && y.is_finite() {
            self.start_m = Some(y);
        }
        let i = (tick % self.reference_m.len() as u64) as usize;
        let w = self.fade(tick);
        let setpoint = self.start_m.unwrap_or(0.0) + w * self.reference_m[i];
        let ff = w * self.feedforward_a[i];
        JobOutput {
            command_a: self.ctrl.update(setpoint - y) + ff,
            excitation_a: ff,
            setpoint_m: setpoint,
            done: tick + 1 >= self.total_ticks,
        }
    }
}

#[cfg(test)]
mod tests;
