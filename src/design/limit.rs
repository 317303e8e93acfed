//! The performance limit of a bench: the largest performance bandwidth
//! ω* that **any** stabilising linear time-invariant controller reaches
//! on a stable plant known on frequency lines, by the convex Youla
//! problem (Boyd & Barratt, *Linear Controller Design: Limits of
//! Performance*, 1991, Ch. 6 and 15).
//!
//! # The measure
//! The standard performance weight (Skogestad & Postlethwaite,
//! *Multivariable Feedback Control*, 2nd ed., §2.8.2 Eq. 2.105, §5.7)
//!
//! `W_P(s) = (s/M + ω*) / s`,
//!
//! with `M` the largest |S| allowed (`--s-max`) and ω* (rad/s) the
//! performance bandwidth: a loop with `|W_P(jω) S(jω)| ≤ 1` at every ω
//! has |S| ≤ ω/ω* well below ω*, |S| ≤ M everywhere, and its −3 dB
//! sensitivity bandwidth ω_B near ω*. Unlike ω_B alone it cannot be
//! bought by letting |S| hover just under −3 dB over a wide band.
//!
//! # The Youla problem
//! For a stable plant `P` every stabilising controller is
//! `C = Q / (1 − P Q)` with `Q` stable, and `S = 1 − P Q` is affine in `Q`
//! (Youla–Kučera; Boyd & Barratt §7.2). With `Q(z) = Σᵢ qᵢ Bᵢ(z)` on a
//! fixed stable basis `Bᵢ` (finite impulse response taps `z⁻ᵏ` and
//! partial fractions `1/(z − p)` on poles `p` placed from the plant, see
//! [`Basis`]), `γ(ω*) = min_q max_k |W_P(jω_k) (1 − P_k Q(e^{jω_k T}))|`
//! over the lines `k` is a second-order cone program (one 3-dimensional
//! cone per line), solved by Clarabel (Goulart & Chen, 2024), and γ grows
//! with ω* (|W_P(jω)| does at every ω). The limit is the ω* where γ = 1,
//! found by a false-position search on `ln γ(ln ω*)`. A finite basis gives
//! an **inner** approximation (a Q that exists: the limit is reached by a
//! real controller), and a finite set of lines an outer one (between
//! lines nothing is asked): the lines
//! should include the fitted model's between the measured ones.
//!
//! # The analytic bound of a right-half-plane zero
//! At a zero `z` of `P` with Re z > 0, `S(z) = 1` for every stabilising
//! controller, so `|W_P(z)| ≤ ‖W_P S‖∞ ≤ 1` (maximum modulus principle;
//! Skogestad & Postlethwaite §5.7.1 Eq. 5.49, Theorem 5.3):
//! `|1/M + ω*/z| ≤ 1`. [`rhp_zero_bound_rad_s`] solves it for ω*: for a
//! real zero `ω* ≤ z (1 − 1/M)`; for the pair 2π(1.7 ± 83j) Hz of the
//! shipped bench and M = 2, 446 rad/s. The delay and the amplifier lower
//! the limit further; the Youla problem accounts for both, since they are
//! in the measured lines.

use crate::ident::C64;
use clarabel::algebra::CscMatrix;
use clarabel::solver::{DefaultSettings, DefaultSolver, IPSolver, SolverStatus, SupportedConeT};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// The relative width of the bracket at which the search on ω* stops.
pub const RELATIVE_TOLERANCE: f64 = 1e-2;

/// Largest number of lines one cone program holds; more lines are thinned
/// (every resonance's neighbourhood kept) and the dropped ones checked on
/// the solution, the worst added back ([`performance_limit`]). 150: one
/// default chirp's limit 3.4–4.0 s where 300 took 3.5–5.1 s (beside the
/// climbs, dev profile), the limits of `tests/data/limit_cases.json`'s
/// true plants within 0.1 % (unbounded) and 1 % of what 300 gave.
pub const MAX_ACTIVE_LINES: usize = 150;

/// Lines either side of a local maximum whose magnitudes judge its
/// prominence ([`thinned_lines`]): a resonance stands out over them, a
/// noisy line's maximum over its neighbours does not.
const PROMINENCE_SPAN: usize = 3;
/// A local maximum at least this many times the larger of the lines
/// [`PROMINENCE_SPAN`] away is a resonance the programs start with,
/// beyond the `n/3` most prominent. Every local maximum of a measured
/// FRF's noise joined before: 20 FRFs' programs started with 680–720
/// lines where they were to hold 150, and the design took 66 s; with
/// only the prominent ones (1.1) they start with about 300, and it takes
/// 33 s at the same ω* (351.8 of the workspace's 358.0 rad/s, where
/// 351.4; dev profile). At 1.25, 31 s and 351.0; with the n/6 most
/// prominent alone, 22 s but 269 rad/s: the climb needs every input's
/// resonances. One FRF keeps its noise's peaks (fewer than n/3 of them):
/// without them the README's recording's climb reached 333 rad/s where
/// it reaches 369.
const PROMINENCE_MIN: f64 = 1.1;

/// `|W_P(jω)|` for `W_P(s) = (s/M + ω*)/s`: `|jω/M + ω*| / ω`.
///
/// Units: ω and ω* in rad/s; dimensionless. Source: Skogestad &
/// Postlethwaite Eq. 2.105.
pub fn performance_weight_magnitude(omega_rad_s: f64, bandwidth_rad_s: f64, s_max: f64) -> f64 {
    C64::new(bandwidth_rad_s, omega_rad_s / s_max).norm() / omega_rad_s
}

/// The performance bandwidth ω* of a loop known on lines: the largest ω*
/// with `|W_P(jω_k) S_k| ≤ 1` on every line `k`,
/// `min_k ω_k √(1/|S_k|² − 1/M²)` (from `|S_k| |jω_k/M + ω*| ≤ ω_k`).
///
/// Shapes: `omega_rad_s` (rad/s) and `sensitivity_abs` (|S|, one per
/// line) of equal length. `None` when a line has |S| > M (no ω* ≥ 0
/// meets the weight there) or there are no lines; a line with S = 0
/// bounds nothing.
pub fn loop_performance_bandwidth_rad_s(
    omega_rad_s: &[f64],
    sensitivity_abs: &[f64],
    s_max: f64,
) -> Option<f64> {
    if omega_rad_s.is_empty() || omega_rad_s.len() != sensitivity_abs.len() {
        return None;
    }
    let mut best = f64::INFINITY;
    for (&w, &s) in omega_rad_s.iter().zip(sensitivity_abs) {
        if s.is_nan() || s > s_max {
            return None;
        }
        if s > 0.0 {
            best = best.min(w * (1.0 / (s * s) - 1.0 / (s_max * s_max)).max(0.0).sqrt());
        }
    }
    Some(best)
}

/// The largest ω* (rad/s) that `|W_P(z)| ≤ 1` allows at a right-half-plane
/// zero `z` (rad/s, Re z > 0) with `M = s_max`: the root of
/// `|1/M + ω* u|² = 1`, `u = 1/z`, i.e. of
/// `|u|² ω*² + (2 Re u / M) ω* + 1/M² − 1 = 0`.
///
/// `None` for a zero not in the open right half plane or `M ≤ 1` (no ω*
/// ≥ 0 then satisfies the bound). Source: Skogestad & Postlethwaite
/// §5.7.1, Eq. 5.49 (S(z) = 1 for every stabilising controller).
pub fn rhp_zero_bound_rad_s(zero_rad_s: C64, s_max: f64) -> Option<f64> {
    if zero_rad_s.re <= 0.0 || s_max <= 1.0 || !zero_rad_s.is_finite() {
        return None;
    }
    let u = 1.0 / zero_rad_s;
    let a = u.norm_sqr();
    let b = 2.0 * u.re / s_max;
    let c = 1.0 / (s_max * s_max) - 1.0;
    let disc = b * b - 4.0 * a * c;
    Some((-b + disc.sqrt()) / (2.0 * a))
}

/// One term of the basis of Q.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Term {
    /// `z⁻ᵏ` (a finite impulse response tap).
    Delay(u32),
    /// `(1 − p)/(z − p)` for a real pole `p` in (−1, 1) (unit gain at
    /// z = 1 for p > 0).
    Real(f64),
    /// The real and the imaginary part of a pole pair:
    /// `g (1/(z − p) + 1/(z − p̄))` (`false`) or
    /// `g j (1/(z − p) − 1/(z − p̄))` (`true`), `p` with Im p > 0 and
    /// |p| < 1, `g = 1 − |p|` (so each peaks near 1 on the unit circle).
    Pair {
        /// Re p.
        re: f64,
        /// Im p (> 0).
        im: f64,
        /// The imaginary-part term.
        quadrature: bool,
    },
}

impl Term {
    /// The term at `z` on the unit circle.
    pub fn at(&self, z: C64) -> C64 {
        match *self {
            Term::Delay(k) => z.powi(-(k as i32)),
            Term::Real(p) => C64::new(1.0 - p, 0.0) / (z - p),
            Term::Pair { re, im, quadrature } => {
                let p = C64::new(re, im);
                let g = 1.0 - p.norm();
                let a = 1.0 / (z - p);
                let b = 1.0 / (z - p.conj());
                if quadrature {
                    C64::new(0.0, g) * (a - b)
                } else {
                    (a + b) * g
                }
            }
        }
    }
}

/// The stable basis Q is a real combination of: FIR taps and partial
/// fractions on discrete poles `e^{sT}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Basis {
    /// The terms, in the order of the coefficients.
    pub terms: Vec<Term>,
}

impl Basis {
    /// `taps` FIR taps `z⁰ … z^{−(taps−1)}`, and for each continuous-time
    /// pole `s` (rad/s, Re s < 0; a complex one given once, with Im s > 0)
    /// the term(s) of `e^{sT}`. Poles at or beyond the Nyquist frequency
    /// (|Im s| T ≥ π) or not stable are left out.
    pub fn new(taps: u32, poles_rad_s: &[C64], period_s: f64) -> Self {
        let mut terms: Vec<Term> = (0..taps).map(Term::Delay).collect();
        for s in poles_rad_s {
            if !s.is_finite() || s.re >= 0.0 || s.im.abs() * period_s >= PI {
                continue;
            }
            let p = (s * period_s).exp();
            if s.im.abs() * period_s < 1e-9 {
                terms.push(Term::Real(p.re));
            } else {
                for quadrature in [false, true] {
                    terms.push(Term::Pair {
                        re: p.re,
                        im: p.im.abs(),
                        quadrature,
                    });
                }
            }
        }
        Self { terms }
    }

    /// The default basis for a plant whose lightly damped zeros (rad/s,
    /// any half plane) are `zeros_rad_s`: 32 FIR taps; real poles at 16
    /// frequencies spaced evenly in log from `lowest_rad_s` to 0.8 of the
    /// Nyquist frequency; a pole pair of damping ratio 0.5 at each of
    /// these frequencies; and each zero as a pole pair of Q (a zero in the
    /// right half plane mirrored into the left: Q then inverts its
    /// magnitude, never its phase). Q ≈ P⁻¹ where the loop has gain needs
    /// P's zeros among Q's poles.
    ///
    /// The size trades the limit's reach for its time: each program's
    /// KKT factorisation costs about lines × terms². With these sizes (86
    /// terms on the shipped bench) one default chirp's limit takes
    /// 3.2–3.8 s beside the climbs and comes 1.6 %, 4.9 % and 4.5 % under
    /// the reference of `tests/data/limit_reference.json` (ch5, held-out
    /// a and b). Tried and dropped: 24 taps and 12 frequencies (66 terms),
    /// 1.8–2.0 s and 3.7 %, 5.6 %, 5.6 % under, but a 20-cell campaign's
    /// limit fell to 348.4 rad/s, under the 350.5 its own design reached
    /// (an inner approximation: a smaller Q basis can only lower it).
    pub fn for_plant(zeros_rad_s: &[C64], lowest_rad_s: f64, period_s: f64) -> Self {
        Self::sized(32, 16, zeros_rad_s, lowest_rad_s, period_s)
    }

    /// [`Self::for_plant`] with `taps` FIR taps and `log_poles`
    /// frequencies of real and ζ = 0.5 poles.
    pub fn sized(
        taps: u32,
        log_poles: usize,
        zeros_rad_s: &[C64],
        lowest_rad_s: f64,
        period_s: f64,
    ) -> Self {
        let nyquist = PI / period_s;
        let lo = lowest_rad_s.max(1e-3).min(nyquist / 10.0);
        let n = log_poles.max(2);
        let mut poles = Vec::new();
        for i in 0..n {
            let w = lo * (nyquist * 0.8 / lo).powf(i as f64 / (n - 1) as f64);
            poles.push(C64::new(-w, 0.0));
            poles.push(C64::new(-0.5 * w, w * 0.75f64.sqrt()));
        }
        for z in zeros_rad_s {
            if z.im.abs() < 1e-9 * z.norm() {
                poles.push(C64::new(-z.re.abs(), 0.0));
            } else {
                poles.push(C64::new(-z.re.abs(), z.im.abs()));
            }
        }
        Self::new(taps, &poles, period_s)
    }

    /// Q at `z` for the coefficients `q` (A/m per unit of the plant's
    /// scale, see [`Limit::plant_scale`]).
    pub fn q_at(&self, q: &[f64], z: C64) -> C64 {
        self.terms.iter().zip(q).map(|(t, c)| t.at(z) * *c).sum()
    }
}

/// Lines the limit is asked on: one input (or a model between its lines).
#[derive(Debug, Clone)]
pub struct Lines<'a> {
    /// The input's name in reports.
    pub label: &'a str,
    /// Frequencies, rad/s, ascending, below the Nyquist frequency.
    pub omega_rad_s: &'a [f64],
    /// The plant at each line, m/A, everything between the controller's
    /// output and the probe included (hold, amplifier, computation delay).
    pub plant_m_per_a: &'a [C64],
    /// The 1σ of each `plant_m_per_a` relative to |P| (a measured line's
    /// noise, a fit's covariance; NaN: unknown; empty: all unknown), for
    /// the limit's 1σ ([`Limit::performance_bandwidth_sigma_rad_s`]).
    pub relative_sigma: &'a [f64],
    /// Whether the lines' errors are one fit's (correlated from line to
    /// line: the limit's 1σ adds them as if fully correlated, the
    /// cautious bound) rather than independent measured lines.
    pub correlated: bool,
    /// Measured lines' stand-in: a smooth model of the same plant at the
    /// same lines (m/A, the fit). Where a line's 2σ (`relative_sigma`)
    /// cannot resolve the bound on |S| that the weight sets there
    /// (`2σ |W_P| > `[`NOISE_RESOLUTION`]), the model stands in for it.
    /// `None`: the lines stand for themselves (a model's).
    pub noise: Option<LineNoise<'a>>,
}

/// The model that stands in for measured lines where their noise hides
/// the bound (see [`Lines::noise`]).
#[derive(Debug, Clone, Copy)]
pub struct LineNoise<'a> {
    /// The model at each line, m/A.
    pub model_m_per_a: &'a [C64],
    /// The model's 1σ at each line relative to its magnitude (the fit's
    /// covariance; NaN: unknown).
    pub model_relative_sigma: &'a [f64],
}

/// A measured line decides the constraint `|W_P S| ≤ 1` only where its
/// noise moves `|W_P S|` by less than this (2σ): `S = 1 − P Q` with
/// `P Q ≈ 1` carries the line's relative error into S whole, so a line
/// with 0.1 % noise cannot tell |S| = 10⁻⁴ from 10⁻³, which the weight
/// asks for well below ω*.
pub const NOISE_RESOLUTION: f64 = 0.5;

/// What a loop must keep besides `|W_P S| ≤ 1`, the same in the limit and
/// in a design (so that a design's ω* is a fraction of a limit on the
/// same terms).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopBounds {
    /// The largest control effort `|K S| = |Q|` on every line, A/m
    /// (`f64::INFINITY`: none): [`LoopBounds::effort_for_step`].
    pub effort_max_a_per_m: f64,
    /// From this line up (rad/s), `|T| = |P Q| ≤` [`Self::band_edge_t_max`]:
    /// the loop does not rely on the plant where it was not measured
    /// (`f64::INFINITY`: nowhere).
    pub band_edge_rad_s: f64,
    /// `|T|` from the band edge up.
    pub band_edge_t_max: f64,
}

impl LoopBounds {
    /// No bound but `|W_P S| ≤ 1`.
    pub const NONE: Self = Self {
        effort_max_a_per_m: f64::INFINITY,
        band_edge_rad_s: f64::INFINITY,
        band_edge_t_max: f64::INFINITY,
    };

    /// The effort bound of the coil's peak current for a setpoint step:
    /// `|K S| ≤ I_pk / |r|` (A/m), so that a setpoint or probe error of the
    /// step's size `r` at any frequency (a step's edge holds them all)
    /// asks at most the peak current `I_pk` (A) of the amplifier. Probe
    /// noise is far below it: 40 nm RMS at 1 A/µm is 40 mA.
    pub fn effort_for_step(peak_current_a: f64, step_m: f64) -> f64 {
        peak_current_a / step_m.abs()
    }
}

/// The line where the limit binds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct BindingLine {
    /// The input (or model) the line belongs to.
    pub input: String,
    /// The line, rad/s.
    pub omega_rad_s: f64,
    /// `|W_P S|` there at the limit (1 when binding).
    pub weighted_sensitivity: f64,
}

/// The bound of one right-half-plane zero.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ZeroBound {
    /// The zero, real and imaginary part, Hz (s/2π).
    pub re_hz: f64,
    /// Imaginary part, Hz.
    pub im_hz: f64,
    /// The largest ω* it allows, rad/s ([`rhp_zero_bound_rad_s`]).
    pub bound_rad_s: f64,
}

/// Why no limit was computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LimitError {
    /// No lines, or a line not finite, or not below the Nyquist frequency.
    #[error("{0}")]
    BadLines(String),
    /// A sample period that is not a positive time, M ≤ 1, or a search
    /// upper end that is not a positive frequency.
    #[error("{0}")]
    BadArgument(String),
    /// The cone program did not solve.
    #[error("the cone program at ω* = {bandwidth_rad_s:.1} rad/s ended {status}: the limit cannot be certified")]
    Solver {
        /// The ω* tried.
        bandwidth_rad_s: f64,
        /// Clarabel's status.
        status: String,
    },
}

/// The limit and the Q that reaches it.
#[derive(Debug, Clone)]
pub struct Limit {
    /// The largest ω* (rad/s) for which a Q of the basis keeps
    /// `|W_P S| ≤ 1` on every line (the lower end of the last bracket).
    pub performance_bandwidth_rad_s: f64,
    /// The 1σ of `performance_bandwidth_rad_s` from the lines' errors
    /// (rad/s; `None`: a line that binds has no known 1σ, or no program
    /// ran above the limit): first order, the 1σ of the optimum γ at the
    /// limit through the program's dual ([`gamma_sigma`]) over the slope
    /// of ln γ against ln ω* across the last bracket.
    pub performance_bandwidth_sigma_rad_s: Option<f64>,
    /// The upper end of the last bracket: no Q of the basis reaches it.
    pub infeasible_above_rad_s: f64,
    /// `M`.
    pub s_max: f64,
    /// The basis of Q.
    pub basis: Basis,
    /// The coefficients at the limit, for the plant divided by
    /// `plant_scale`.
    pub q: Vec<f64>,
    /// The plant's scale, m/A (|P| at its lowest line): Q in A/m is
    /// `basis.q_at(q, z) / plant_scale`.
    pub plant_scale: f64,
    /// Where `|W_P S|` is within 1 % of its largest value at the limit.
    pub binding: Vec<BindingLine>,
    /// The line (rad/s) where `|Q| = |K S|` is within 2 % of the effort
    /// bound at the limit (`None`: it does not hold the limit).
    pub effort_binds_at_rad_s: Option<f64>,
    /// The line (rad/s) where `|T|` is within 2 % of the band edge's
    /// bound at the limit (`None`: it does not hold the limit).
    pub band_edge_binds_at_rad_s: Option<f64>,
    /// Measured lines whose noise hid the bound at the limit, so that
    /// the model stood in for them ([`NOISE_RESOLUTION`]).
    pub stand_in_lines: usize,
    /// Cone programs solved.
    pub solves: usize,
}

impl Limit {
    /// Q(e^{jωT}) in A/m.
    pub fn q_at(&self, omega_rad_s: f64, period_s: f64) -> C64 {
        let z = C64::from_polar(1.0, omega_rad_s * period_s);
        self.basis.q_at(&self.q, z) / self.plant_scale
    }
}

/// One line of the cone program: the plant (scaled) and the basis terms
/// at `z`.
struct Row {
    input: usize,
    omega_rad_s: f64,
    plant: C64,
    /// The model that stands in where the line is noisy, and the model's
    /// relative 1σ (NaN: unknown); only for a line whose 1σ is known.
    stand_in: Option<(C64, f64)>,
    /// The relative 1σ of `plant` (NaN: unknown).
    sigma: f64,
    /// The index of the fit whose lines these are (their errors are
    /// correlated), `None` for a measured line.
    fit: Option<usize>,
    terms: Vec<C64>,
    /// Whether the effort bound `|Q|` is kept at this line: Q is one
    /// function for every input, so one line per 0.1 % of frequency
    /// carries it (20 inputs' lines at the same frequencies would repeat
    /// the same cone 20 times).
    effort: bool,
}

impl Row {
    /// The plant the program uses at ω* = `w_star`: the line, or the
    /// model where the line's noise cannot resolve the bound.
    fn plant_at(&self, w_star: f64, s_max: f64) -> C64 {
        match self.stand_in {
            Some((m, _)) if self.noisy_at(w_star, s_max) => m,
            _ => self.plant,
        }
    }

    /// The relative 1σ of [`Self::plant_at`] and the fit it comes from
    /// (`None`: an independent measured line).
    fn sigma_at(&self, w_star: f64, s_max: f64) -> (f64, Option<usize>) {
        match self.stand_in {
            Some((_, model_sigma)) if self.noisy_at(w_star, s_max) => {
                (model_sigma, Some(self.input))
            }
            _ => (self.sigma, self.fit),
        }
    }

    /// Whether the line's noise hides the bound at ω* = `w_star`.
    fn noisy_at(&self, w_star: f64, s_max: f64) -> bool {
        self.stand_in.is_some() && noise_hides_bound(self.omega_rad_s, self.sigma, w_star, s_max)
    }

    /// Q at this line for the basis coefficients `q`.
    fn q_at(&self, q: &[f64]) -> C64 {
        self.terms.iter().zip(q).map(|(t, c)| t * *c).sum()
    }

    /// `|Q|` over the effort bound at this line (`qz` = Q here).
    fn effort_ratio(&self, qz: C64, bounds: &LoopBounds) -> f64 {
        qz.norm() / bounds.effort_max_a_per_m
    }

    /// `|P Q|` over the band edge's bound at this line, 0 below the band
    /// edge (`qz` = Q here, the plant the program uses at `w_star`).
    fn edge_ratio(&self, qz: C64, w_star: f64, s_max: f64, bounds: &LoopBounds) -> f64 {
        if self.omega_rad_s >= bounds.band_edge_rad_s {
            (self.plant_at(w_star, s_max) * qz).norm() / bounds.band_edge_t_max
        } else {
            0.0
        }
    }
}

/// Whether a measured line at `omega_rad_s` with relative 1σ
/// `relative_sigma` cannot decide the bound the weight sets on |S| there
/// at ω* = `w_star`: `2σ |W_P| >` [`NOISE_RESOLUTION`] (the fit stands in
/// for it, in the limit and in a design's program alike).
pub(super) fn noise_hides_bound(
    omega_rad_s: f64,
    relative_sigma: f64,
    w_star: f64,
    s_max: f64,
) -> bool {
    2.0 * relative_sigma * performance_weight_magnitude(omega_rad_s, w_star, s_max)
        > NOISE_RESOLUTION
}

/// The arguments of [`performance_limit`], checked.
fn check_arguments(
    period_s: f64,
    s_max: f64,
    upper_rad_s: Option<f64>,
    bounds: &LoopBounds,
) -> Result<(), LimitError> {
    if !(period_s.is_finite() && period_s > 0.0) {
        return Err(LimitError::BadArgument(format!(
            "the sample period {period_s} s is not a positive time"
        )));
    }
    if !(s_max.is_finite() && s_max > 1.0) {
        return Err(LimitError::BadArgument(format!(
            "M = {s_max}: the largest |S| allowed must be above 1 (no loop with feedback keeps |S| ≤ 1 at every frequency: Bode's sensitivity integral)"
        )));
    }
    if let Some(u) = upper_rad_s {
        if !(u.is_finite() && u > 0.0) {
            return Err(LimitError::BadArgument(format!(
                "the upper end of the search {u} rad/s is not a positive frequency"
            )));
        }
    }
    let e = bounds.effort_max_a_per_m;
    if e.is_nan() || e <= 0.0 {
        return Err(LimitError::BadArgument(format!(
            "the effort bound {} A/m is not a positive current per metre (Q = 0 is the only controller it admits; infinite: no bound)",
            bounds.effort_max_a_per_m
        )));
    }
    let (t_max, edge) = (bounds.band_edge_t_max, bounds.band_edge_rad_s);
    if t_max.is_nan() || t_max <= 0.0 || edge.is_nan() || edge < 0.0 {
        return Err(LimitError::BadArgument(format!(
            "the band edge's bound |T| ≤ {} from {} rad/s up: the bound must be positive and the edge a frequency (infinite: none)",
            bounds.band_edge_t_max, bounds.band_edge_rad_s
        )));
    }
    Ok(())
}

/// One row per line of every input, with the basis' values at the line
/// (z = e^{jωT}) and the effort bound kept on one line per 0.1 % of
/// frequency.
fn rows_of(lines: &[Lines<'_>], basis: &Basis, period_s: f64) -> Result<Vec<Row>, LimitError> {
    let nyquist = PI / period_s;
    let mut rows = Vec::new();
    for (i, l) in lines.iter().enumerate() {
        if l.omega_rad_s.len() != l.plant_m_per_a.len() {
            return Err(LimitError::BadLines(format!(
                "{}: {} frequencies and {} responses",
                l.label,
                l.omega_rad_s.len(),
                l.plant_m_per_a.len()
            )));
        }
        if let Some(n) = &l.noise {
            if l.relative_sigma.len() != l.omega_rad_s.len()
                || n.model_m_per_a.len() != l.omega_rad_s.len()
                || n.model_relative_sigma.len() != l.omega_rad_s.len()
            {
                return Err(LimitError::BadLines(format!(
                    "{}: {} lines, {} noise figures, {} model values and {} model 1σ",
                    l.label,
                    l.omega_rad_s.len(),
                    l.relative_sigma.len(),
                    n.model_m_per_a.len(),
                    n.model_relative_sigma.len()
                )));
            }
        }
        if !l.relative_sigma.is_empty() && l.relative_sigma.len() != l.omega_rad_s.len() {
            return Err(LimitError::BadLines(format!(
                "{}: {} lines and {} 1σ",
                l.label,
                l.omega_rad_s.len(),
                l.relative_sigma.len()
            )));
        }
        for (j, (&w, &p)) in l.omega_rad_s.iter().zip(l.plant_m_per_a).enumerate() {
            if !(w > 0.0 && w < nyquist && p.is_finite()) || p.norm() == 0.0 {
                return Err(LimitError::BadLines(format!(
                    "{}: the line at {w} rad/s is not a finite, non-zero response below the Nyquist frequency {nyquist:.1} rad/s",
                    l.label
                )));
            }
            let z = C64::from_polar(1.0, w * period_s);
            let sigma = l.relative_sigma.get(j).copied().unwrap_or(f64::NAN);
            rows.push(Row {
                input: i,
                omega_rad_s: w,
                plant: p,
                stand_in: l.noise.and_then(|n| {
                    let m = n.model_m_per_a[j];
                    (sigma.is_finite() && sigma > 0.0 && m.is_finite() && m.norm() > 0.0)
                        .then_some((m, n.model_relative_sigma[j]))
                }),
                sigma,
                fit: l.correlated.then_some(i),
                terms: basis.terms.iter().map(|t| t.at(z)).collect(),
                effort: false,
            });
        }
    }
    {
        let mut order: Vec<usize> = (0..rows.len()).collect();
        order.sort_by(|a, b| rows[*a].omega_rad_s.total_cmp(&rows[*b].omega_rad_s));
        let mut last = 0.0;
        for k in order {
            if rows[k].omega_rad_s > 1.001 * last {
                rows[k].effort = true;
                last = rows[k].omega_rad_s;
            }
        }
    }
    if rows.is_empty() {
        return Err(LimitError::BadLines("no lines".into()));
    }
    Ok(rows)
}

/// The cone program at ω* = `mid` on the `active` lines, with constraint
/// generation: γ > 1 on the active lines is γ > 1 on all of them (more
/// lines only raise the min-max); otherwise the worst lines left out are
/// added until none passes 1, so that a q declared feasible keeps
/// |W_P S| ≤ 1 on every line, not only the active ones. Returns γ, q and
/// the 1σ of γ; `solves` counts the programs.
fn solve_generating(
    rows: &[Row],
    active: &mut Vec<usize>,
    n: usize,
    mid: f64,
    s_max: f64,
    bounds: &LoopBounds,
    solves: &mut usize,
) -> Result<(f64, Vec<f64>, f64), LimitError> {
    loop {
        let Solved {
            gamma,
            q,
            gamma_sigma,
        } = solve(rows, active, n, mid, s_max, bounds)?;
        *solves += 1;
        tracing::debug!(
            bandwidth_rad_s = mid,
            gamma,
            lines = active.len(),
            "performance limit: one cone program"
        );
        if gamma > 1.0 {
            return Ok((gamma, q, gamma_sigma));
        }
        let worst = violations(rows, &q, mid, s_max, 1.0, bounds);
        let added: Vec<usize> = worst
            .into_iter()
            .filter(|k| active.binary_search(k).is_err())
            .take(64)
            .collect();
        if added.is_empty() {
            return Ok((gamma, q, gamma_sigma));
        }
        active.extend(added);
        active.sort_unstable();
    }
}

/// The largest ω* any Q of `basis` reaches on all `lines` with |S| ≤
/// `s_max` (the module's Youla problem), to [`RELATIVE_TOLERANCE`].
///
/// `period_s` is the controller's sample period T (z = e^{jωT}). The
/// search starts from `[0, upper_rad_s]` (the Nyquist frequency when
/// `None`). Lines beyond [`MAX_ACTIVE_LINES`] are handled by constraint
/// generation: the program runs on a thinned set, the solution is checked
/// on every line and the worst violated ones are added until none is.
/// `bounds` adds `|Q| ≤ effort` on every line and `|P Q| ≤ t_max` from
/// the band edge up (each a cone per line; Q = 0 meets both, so every
/// program stays feasible).
///
/// # Errors
/// [`LimitError::BadArgument`] for a period that is not a positive time,
/// `s_max` ≤ 1 or an `upper_rad_s` that is not a positive frequency; [`LimitError::BadLines`] for no lines or a line that
/// is not finite;
/// [`LimitError::Solver`] when Clarabel neither solves nor proves a
/// program infeasible.
pub fn performance_limit(
    lines: &[Lines<'_>],
    basis: Basis,
    period_s: f64,
    s_max: f64,
    upper_rad_s: Option<f64>,
    bounds: LoopBounds,
) -> Result<Limit, LimitError> {
    check_arguments(period_s, s_max, upper_rad_s, &bounds)?;
    let nyquist = PI / period_s;
    let mut rows = rows_of(lines, &basis, period_s)?;
    let lowest = rows
        .iter()
        .min_by(|a, b| a.omega_rad_s.total_cmp(&b.omega_rad_s))
        .map(|r| r.plant.norm())
        .unwrap_or(1.0);
    for r in &mut rows {
        r.plant /= lowest;
        if let Some((m, _)) = &mut r.stand_in {
            *m /= lowest;
        }
    }
    // The bounds on the scaled plant: Q in A/m is (B q)/lowest.
    let bounds = LoopBounds {
        effort_max_a_per_m: bounds.effort_max_a_per_m * lowest,
        ..bounds
    };
    // The basis orthonormalised on the lines (below).
    let back = orthonormalise(&mut rows);
    let n = back.ncols();
    let mut active = thinned(&rows, MAX_ACTIVE_LINES);
    let mut solves = 0;
    let mut lo = 0.0_f64;
    let mut hi = upper_rad_s.unwrap_or(nyquist).min(nyquist);
    // ln γ at the bracket's ends, where a program gave it.
    let (mut f_lo, mut f_hi): (Option<f64>, Option<f64>) = (None, None);
    // Which end the last point replaced (Illinois: the other end's ln γ
    // is halved when it is kept twice, so that the false position cannot
    // stall on one side).
    let mut replaced_low: Option<bool> = None;
    let mut best: Option<Vec<f64>> = None;
    // ln γ and the 1σ of ln γ at the feasible end, and ln γ at the
    // infeasible end, as the programs gave them (the false position's
    // halving aside): the limit's 1σ.
    let mut at_lo: Option<(f64, f64)> = None;
    let mut ln_gamma_hi: Option<f64> = None;
    // The root of ln γ(ln ω*) by the Illinois false position (Dowell &
    // Jarratt, BIT 11, 1971) inside a bracket that only shrinks: γ grows
    // with ω*, and is smooth where it crosses 1. The first point is an
    // eighth of the top (γ at the top is rarely ≤ 1), or the top itself
    // when the caller gave it; the second, with γ
    // known only at the top, is the top over γ^(4/3) (γ grew about as
    // ω*^0.75 between the limit and the top on the benches of
    // `tests/data/limit_cases.json`: this lands just under the limit,
    // where an eighth of the top again landed far under it and took two
    // more feasible points, each a few programs of constraint
    // generation), within [1/64, 1/2] of the top; without a value at both
    // ends the next is the geometric mean. A point predicted within
    // the tolerance of an end is pushed a tolerance inside, so that it
    // closes the bracket from the other side.
    while (hi - lo) > RELATIVE_TOLERANCE * hi {
        let mid = match (lo > 0.0, f_lo, f_hi) {
            (false, _, Some(b)) => hi * (-4.0 / 3.0 * b).exp().clamp(1.0 / 64.0, 0.5),
            // A top the caller knows the limit to be just under (a
            // right-half-plane zero's bound): the top itself, one program
            // that is rarely feasible and gives γ there for the next
            // point. From [0, 470] rad/s (1.05 times the shipped bench's
            // zero bound) an eighth of it took 21 programs, four feasible
            // points each with its constraint generation.
            (false, _, _) if upper_rad_s.is_some() && solves == 0 => hi,
            (false, _, _) => hi / 8.0,
            (true, Some(a), Some(b)) if b > a => {
                let (x0, x1) = (lo.ln(), hi.ln());
                let x = x1 - b * (x1 - x0) / (b - a);
                // 0.9 of the tolerance in ln ω*: a point there on the
                // far side of the root ends the search.
                let margin = (-0.9 * (1.0 - RELATIVE_TOLERANCE).ln()).min(0.5 * (x1 - x0));
                x.clamp(x0 + margin, x1 - margin).exp()
            }
            _ => (lo * hi).sqrt(),
        };
        let (gamma, q, gamma_sigma) =
            solve_generating(&rows, &mut active, n, mid, s_max, &bounds, &mut solves)?;
        let f = gamma.max(f64::MIN_POSITIVE).ln();
        let low_side = gamma <= 1.0;
        if low_side {
            lo = mid;
            f_lo = Some(f);
            at_lo = Some((f, gamma_sigma / gamma));
            best = Some(q);
            if replaced_low == Some(true) {
                f_hi = f_hi.map(|v| 0.5 * v);
            }
        } else {
            hi = mid;
            f_hi = Some(f);
            ln_gamma_hi = Some(f);
            if replaced_low == Some(false) {
                f_lo = f_lo.map(|v| 0.5 * v);
            }
        }
        replaced_low = Some(low_side);
    }
    // The limit moves where ln γ(ln ω*) crosses 0: by σ_ln γ over the
    // slope of ln γ across the last bracket.
    let performance_bandwidth_sigma_rad_s = match (at_lo, ln_gamma_hi) {
        (Some((f0, s0)), Some(f1)) if f1 > f0 && hi > lo => {
            let slope = (f1 - f0) / (hi / lo).ln();
            Some(lo * s0 / slope).filter(|v| v.is_finite() && *v >= 0.0)
        }
        _ => None,
    };
    let y = best.unwrap_or_else(|| vec![0.0; n]);
    let binding = binding_lines(&rows, &y, lo, s_max, lines);
    // The bounds that hold the limit's Q: within 2 % of their value, at
    // the line where each is closest.
    let closest = |ratio: &dyn Fn(&Row, C64) -> f64| {
        rows.iter()
            .map(|r| (ratio(r, r.q_at(&y)), r.omega_rad_s))
            .filter(|(x, _)| x.is_finite())
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .filter(|(x, _)| *x >= 0.98)
            .map(|(_, w)| w)
    };
    let effort_binds_at_rad_s = closest(&|r, qz| r.effort_ratio(qz, &bounds));
    let band_edge_binds_at_rad_s =
        closest(&|r, qz| r.edge_ratio(qz, lo.max(f64::MIN_POSITIVE), s_max, &bounds));
    let q = (&back * nalgebra::DVector::from_vec(y)).as_slice().to_vec();
    let stand_in_lines = rows
        .iter()
        .filter(|r| r.noisy_at(lo.max(f64::MIN_POSITIVE), s_max))
        .count();
    Ok(Limit {
        stand_in_lines,
        performance_bandwidth_rad_s: lo,
        performance_bandwidth_sigma_rad_s,
        infeasible_above_rad_s: hi,
        s_max,
        basis,
        q,
        plant_scale: lowest,
        binding,
        effort_binds_at_rad_s,
        band_edge_binds_at_rad_s,
        solves,
    })
}

/// Replaces each row's basis values by those of an orthonormal basis of
/// the same span over the lines (the left singular vectors of the real
/// matrix `[Re B; Im B]`, lines × terms stacked; directions whose
/// singular value is under 1e-9 of the largest dropped: terms that
/// differ by nothing the lines can see). Returns the map back,
/// `q = V Σ⁻¹ y` (terms × kept), from the new coefficients `y`. Nearly
/// collinear terms (partial fractions on close poles, FIR taps at low
/// frequency) otherwise leave the interior point ill-conditioned.
fn orthonormalise(rows: &mut [Row]) -> nalgebra::DMatrix<f64> {
    let (m, n) = (rows.len(), rows.first().map_or(0, |r| r.terms.len()));
    let x = nalgebra::DMatrix::from_fn(2 * m, n, |i, j| {
        let t = rows[i % m].terms[j];
        if i < m {
            t.re
        } else {
            t.im
        }
    });
    let map = orthonormal_map(&x);
    let u = &x * &map;
    for (i, r) in rows.iter_mut().enumerate() {
        r.terms = (0..map.ncols())
            .map(|k| C64::new(u[(i, k)], u[(m + i, k)]))
            .collect();
    }
    map
}

/// The map `D V Σ⁻¹` (cols × kept) of the thin SVD `x D = U Σ Vᵀ`, `D`
/// the diagonal that scales each column of `x` to unit norm, so that
/// `x · D V Σ⁻¹ = U` has orthonormal columns; directions whose singular
/// value is under 1e-9 of the largest are dropped (nothing the rows can
/// see). A change of variables for an interior point whose columns are
/// nearly collinear (here: partial fractions on close poles, FIR taps or
/// powers of `1 − z⁻¹`, which span 10⁻⁴ to 10⁷ over the lines: unscaled,
/// the largest would hide the low-frequency directions under the
/// cut-off).
pub(super) fn orthonormal_map(x: &nalgebra::DMatrix<f64>) -> nalgebra::DMatrix<f64> {
    let n = x.ncols();
    let scale: Vec<f64> = (0..n)
        .map(|j| {
            let c = x.column(j).norm();
            if c > 0.0 && c.is_finite() {
                1.0 / c
            } else {
                1.0
            }
        })
        .collect();
    let mut xs = x.clone();
    for (j, s) in scale.iter().enumerate() {
        xs.column_mut(j).scale_mut(*s);
    }
    let svd = xs.svd(false, true);
    let Some(v_t) = svd.v_t else {
        return nalgebra::DMatrix::from_fn(n, n, |i, j| if i == j { scale[i] } else { 0.0 });
    };
    let top = svd.singular_values.max();
    let keep: Vec<usize> = (0..svd.singular_values.len())
        .filter(|&k| svd.singular_values[k] > 1e-9 * top)
        .collect();
    nalgebra::DMatrix::from_fn(n, keep.len(), |i, j| {
        scale[i] * v_t[(keep[j], i)] / svd.singular_values[keep[j]]
    })
}

/// Balances a cone program's rows for the interior point, in place: each
/// second-order cone's rows of `[A b]` (triplets `ri`, `vals` and `b`)
/// scaled together to unit norm (a cone is unchanged by a positive
/// scale), each nonnegative or zero (equality) row to unit norm alone. Returns the scale of
/// every row, `D`: the program's constraint is then `D (b − A x) ∈ K`,
/// the same set, and the dual of the original is `D z`.
///
/// Clarabel's own equilibration (Ruiz, on `A` alone) is turned off where
/// this is used: on these programs it scaled the cones' rows apart (a
/// cone's rows span 10⁻⁷ to 10²) and the interior point took 50–55 steps;
/// balanced here, with it off, 15–28 at the same optimum (the 94 step
/// programs and 11 limit programs of a default chirp's design, relative
/// difference of the optima under 10⁻³, each Solved).
pub(super) fn balance_rows(
    ri: &[usize],
    vals: &mut [f64],
    b: &mut [f64],
    cones: &[SupportedConeT<f64>],
) -> Vec<f64> {
    let mut norm2 = b.iter().map(|v| v * v).collect::<Vec<f64>>();
    for (&r, v) in ri.iter().zip(vals.iter()) {
        norm2[r] += v * v;
    }
    let mut scale = vec![1.0; b.len()];
    let mut r0 = 0;
    for cone in cones {
        let (dim, together) = match cone {
            SupportedConeT::SecondOrderConeT(d) => (*d, true),
            SupportedConeT::NonnegativeConeT(d) | SupportedConeT::ZeroConeT(d) => (*d, false),
            _ => unreachable!("balance_rows: only second-order, nonnegative and zero cones"),
        };
        let rows = r0..r0 + dim;
        if together {
            let n = rows.clone().map(|r| norm2[r]).sum::<f64>().sqrt();
            if n > 0.0 {
                scale[rows].fill(1.0 / n);
            }
        } else {
            for r in rows {
                if norm2[r] > 0.0 {
                    scale[r] = 1.0 / norm2[r].sqrt();
                }
            }
        }
        r0 += dim;
    }
    for (&r, v) in ri.iter().zip(vals.iter_mut()) {
        *v *= scale[r];
    }
    for (r, v) in b.iter_mut().enumerate() {
        *v *= scale[r];
    }
    scale
}

/// `|W_P S|` at row `r` for coefficients `q`.
fn weighted(r: &Row, q: &[f64], w_star: f64, s_max: f64) -> f64 {
    let s = C64::new(1.0, 0.0) - r.plant_at(w_star, s_max) * r.q_at(q);
    s.norm() * performance_weight_magnitude(r.omega_rad_s, w_star, s_max)
}

/// Rows (indices) where `|W_P S|` exceeds `above` or a bound of `bounds`
/// (scaled) is passed, worst first (each as its ratio to its bound).
fn violations(
    rows: &[Row],
    q: &[f64],
    w_star: f64,
    s_max: f64,
    above: f64,
    bounds: &LoopBounds,
) -> Vec<usize> {
    let mut v: Vec<(usize, f64)> = rows
        .iter()
        .enumerate()
        .map(|(k, r)| {
            let qz = r.q_at(q);
            let mut x = weighted(r, q, w_star, s_max) / above;
            if r.effort {
                x = x.max(r.effort_ratio(qz, bounds));
            }
            (k, x.max(r.edge_ratio(qz, w_star, s_max, bounds)))
        })
        .filter(|(_, x)| *x > 1.0 + 1e-6)
        .collect();
    v.sort_by(|a, b| b.1.total_cmp(&a.1));
    v.into_iter().map(|(k, _)| k).collect()
}

fn binding_lines(
    rows: &[Row],
    q: &[f64],
    w_star: f64,
    s_max: f64,
    lines: &[Lines<'_>],
) -> Vec<BindingLine> {
    let ws: Vec<f64> = rows.iter().map(|r| weighted(r, q, w_star, s_max)).collect();
    let top = ws.iter().copied().fold(0.0, f64::max);
    // Local maxima within 1 % of the top, one per peak.
    let mut out: Vec<BindingLine> = Vec::new();
    for (k, r) in rows.iter().enumerate() {
        let left = k.checked_sub(1).filter(|&j| rows[j].input == r.input);
        let right = Some(k + 1).filter(|&j| j < rows.len() && rows[j].input == r.input);
        let peak = left.is_none_or(|j| ws[j] <= ws[k]) && right.is_none_or(|j| ws[j] < ws[k]);
        if peak && ws[k] >= 0.99 * top {
            out.push(BindingLine {
                input: lines[r.input].label.to_string(),
                omega_rad_s: r.omega_rad_s,
                weighted_sensitivity: ws[k],
            });
        }
    }
    out
}

/// At most `n` row indices: evenly spread in index, plus every local
/// maximum of |P| and its two neighbours (the resonances).
fn thinned(rows: &[Row], n: usize) -> Vec<usize> {
    let m: Vec<f64> = rows.iter().map(|r| r.plant.norm()).collect();
    thinned_lines(&m, n)
}

/// Whether `value[k]` is a local maximum: above its left neighbour and
/// not below its right one (one index per plateau); a missing neighbour
/// (the ends) passes.
pub(super) fn local_peak(value: &[f64], k: usize) -> bool {
    k.checked_sub(1).is_none_or(|j| value[k] > value[j])
        && value.get(k + 1).is_none_or(|&r| value[k] >= r)
}

/// About `n` indices of lines with plant magnitudes `magnitude`: the
/// `n/3` most prominent local maxima and every other prominent one, each
/// with its two neighbours (the resonances: prominence is the peak over
/// the larger of the lines [`PROMINENCE_SPAN`] away, prominent at least
/// [`PROMINENCE_MIN`]), then evenly spread in index, and the last line.
pub(super) fn thinned_lines(magnitude: &[f64], n: usize) -> Vec<usize> {
    let len = magnitude.len();
    if len <= n {
        return (0..len).collect();
    }
    let mut peaks: Vec<(usize, f64)> = (1..len.saturating_sub(1))
        .filter(|&k| local_peak(magnitude, k))
        .map(|k| {
            let left = magnitude[k.saturating_sub(PROMINENCE_SPAN)];
            let right = magnitude[(k + PROMINENCE_SPAN).min(len - 1)];
            (k, magnitude[k] / left.max(right))
        })
        .collect();
    // The n/3 most prominent (their lines alone would fill the budget),
    // and any other that is prominent.
    peaks.sort_by(|a, b| b.1.total_cmp(&a.1));
    let peaks = peaks
        .into_iter()
        .enumerate()
        .filter(|&(rank, (_, prominence))| rank < n / 3 || prominence >= PROMINENCE_MIN)
        .map(|(_, peak)| peak);
    let mut keep = std::collections::BTreeSet::new();
    for (k, _) in peaks {
        keep.extend([k - 1, k, k + 1]);
    }
    let step = len as f64 / n.saturating_sub(keep.len()).max(n / 2) as f64;
    let mut x = 0.0;
    while (x as usize) < len {
        keep.insert(x as usize);
        x += step;
    }
    keep.insert(len - 1);
    keep.into_iter().collect()
}

/// `min_q max_{k ∈ active} |W_P S_k|` at ω* = `w_star`: the cone program
/// `min t  s.t. (t, |W_k| Re(1 − P_k b_kᵀq), |W_k| Im(…)) ∈ SOC(3)`.
///
/// Solved to the end: the search interpolates ln γ, so γ must be the
/// optimum, not the first iterate under 1. The γ returned is the exact
/// max over the active lines for the `q` returned (its own certificate),
/// with its 1σ from the lines' ([`gamma_sigma`]).
fn solve(
    rows: &[Row],
    active: &[usize],
    n: usize,
    w_star: f64,
    s_max: f64,
    bounds: &LoopBounds,
) -> Result<Solved, LimitError> {
    let m = 3 * active.len();
    let (mut ri, mut ci, mut vals) = (Vec::new(), Vec::new(), Vec::new());
    let mut b = vec![0.0; m];
    // The bounds' cones after the weight's: (effort, Re Q, Im Q) on every
    // line, (t_max, Re PQ, Im PQ) from the band edge up.
    let mut extra = 0usize;
    // The band edge's cones: (their first row, their line).
    let mut edge_cones: Vec<(usize, usize)> = Vec::new();
    let mut bound_cone = |head: f64, cols: Vec<C64>, b: &mut Vec<f64>| {
        let r0 = m + 3 * extra;
        b.extend([head, 0.0, 0.0]);
        for (i, c) in cols.into_iter().enumerate() {
            ri.push(r0 + 1);
            ci.push(i);
            vals.push(-c.re);
            ri.push(r0 + 2);
            ci.push(i);
            vals.push(-c.im);
        }
        extra += 1;
    };
    for &k in active {
        let r = &rows[k];
        if r.effort && bounds.effort_max_a_per_m.is_finite() {
            bound_cone(bounds.effort_max_a_per_m, r.terms.clone(), &mut b);
        }
        if r.omega_rad_s >= bounds.band_edge_rad_s && bounds.band_edge_t_max.is_finite() {
            let p = r.plant_at(w_star, s_max);
            edge_cones.push((b.len(), k));
            bound_cone(
                bounds.band_edge_t_max,
                r.terms.iter().map(|t| p * t).collect(),
                &mut b,
            );
        }
    }
    let m = m + 3 * extra;
    for (j, &k) in active.iter().enumerate() {
        let r = &rows[k];
        let w = performance_weight_magnitude(r.omega_rad_s, w_star, s_max);
        // s = b − A x: s0 = t, s1 = w(1 − Re(P bᵀq)), s2 = −w Im(P bᵀq).
        ri.push(3 * j);
        ci.push(n);
        vals.push(-1.0);
        b[3 * j + 1] = w;
        for (i, t) in r.terms.iter().enumerate() {
            let pb = r.plant_at(w_star, s_max) * t * w;
            ri.push(3 * j + 1);
            ci.push(i);
            vals.push(pb.re);
            ri.push(3 * j + 2);
            ci.push(i);
            vals.push(pb.im);
        }
    }
    // The coefficients in the program's own orthonormal coordinates
    // ([`orthonormal_map`] of the rows' q columns, stacked): the basis is
    // orthonormal on the lines, but the rows weigh it by the plant and by
    // |W_P|, and its partial fractions are nearly collinear there. In the
    // raw coefficients the interior point stopped short of the optimum
    // (held-out a without bounds: 1424 rad/s without refinement, where it
    // is 1793 rad/s here and 1803-1812 in the reference, which had stopped
    // short the same way); here it takes about 25 steps where it took
    // 40-50. q = `back` · x.
    let (mut a, back) = in_orthonormal_coordinates(m, n, &ri, &ci, &vals);
    let kept = back.ncols();
    let nv = kept + 1; // x, then t
    let p = CscMatrix::zeros((nv, nv));
    let mut c = vec![0.0; nv];
    c[kept] = 1.0;
    let cones: Vec<SupportedConeT<f64>> = (0..m / 3)
        .map(|_| SupportedConeT::SecondOrderConeT(3))
        .collect();
    let exact = |q: &[f64]| {
        active
            .iter()
            .map(|&k| weighted(&rows[k], q, w_star, s_max))
            .fold(0.0, f64::max)
    };
    // Tolerances 10⁻⁷: at 10⁻⁶ the q of a program whose optimum is just
    // under 1 often evaluates just over it, and the limit comes out 7 %
    // low (held-out benches of `tests/data/limit_cases.json`).
    // Without iterative refinement of the KKT solves: the q found is
    // judged by its exact max (below), and in these coordinates the
    // programs solve to the same limit without it, at about two thirds of
    // the time.
    let settings = DefaultSettings::<f64> {
        verbose: false,
        iterative_refinement_enable: false,
        tol_gap_abs: 1e-7,
        tol_gap_rel: 1e-6,
        tol_feas: 1e-7,
        equilibrate_enable: false,
        ..DefaultSettings::default()
    };
    let row_scale = balance_rows(&a.rowval, &mut a.nzval, &mut b, &cones);
    let failed = |status: String| LimitError::Solver {
        bandwidth_rad_s: w_star,
        status,
    };
    let mut solver = DefaultSolver::new(&p, &c, &a, &b, &cones, settings)
        .map_err(|e| failed(format!("{e:?}")))?;
    solver.solve();
    match solver.solution.status {
        // The q found is its own certificate: γ is its exact max.
        SolverStatus::Solved | SolverStatus::AlmostSolved => {
            let x = nalgebra::DVector::from_column_slice(&solver.solution.x[..kept]);
            let q = (&back * x).as_slice().to_vec();
            // The dual of the unbalanced program.
            let z: Vec<f64> = solver
                .solution
                .z
                .iter()
                .zip(&row_scale)
                .map(|(z, d)| z * d)
                .collect();
            let mut cones: Vec<(usize, f64, C64)> = active
                .iter()
                .enumerate()
                .map(|(j, &k)| {
                    let w = performance_weight_magnitude(rows[k].omega_rad_s, w_star, s_max);
                    (k, w, C64::new(z[3 * j + 1], -z[3 * j + 2]))
                })
                .collect();
            // |T| ≤ t_max: s = (t_max, Re PQ, Im PQ), the opposite sign.
            cones.extend(
                edge_cones
                    .iter()
                    .map(|&(r0, k)| (k, -1.0, C64::new(z[r0 + 1], -z[r0 + 2]))),
            );
            let gamma_sigma = gamma_sigma(rows, &q, &cones, w_star, s_max);
            Ok(Solved {
                gamma: exact(&q),
                q,
                gamma_sigma,
            })
        }
        s => Err(failed(format!("{s:?}"))),
    }
}

/// The program's constraint matrix (`m` rows; triplets `ri`, `ci`, `vals`
/// over the `n` coefficients of q, then t in column `n`) with q in the
/// orthonormal coordinates x of [`orthonormal_map`]: the matrix over (x,
/// t), and `back`, q = `back` · x.
fn in_orthonormal_coordinates(
    m: usize,
    n: usize,
    ri: &[usize],
    ci: &[usize],
    vals: &[f64],
) -> (CscMatrix<f64>, nalgebra::DMatrix<f64>) {
    let mut dense = nalgebra::DMatrix::<f64>::zeros(m, n);
    let mut t_rows = Vec::new();
    for ((&r, &c), &v) in ri.iter().zip(ci).zip(vals) {
        if c == n {
            t_rows.push((r, v));
        } else {
            dense[(r, c)] += v;
        }
    }
    let back = orthonormal_map(&dense);
    let reduced = &dense * &back;
    let kept = back.ncols();
    let (mut ri, mut ci, mut vals) = (Vec::new(), Vec::new(), Vec::new());
    for col in 0..kept {
        for (row, &v) in reduced.column(col).iter().enumerate() {
            if v != 0.0 {
                ri.push(row);
                ci.push(col);
                vals.push(v);
            }
        }
    }
    for (r, v) in t_rows {
        ri.push(r);
        ci.push(kept);
        vals.push(v);
    }
    (
        CscMatrix::new_from_triplets(m, kept + 1, ri, ci, vals),
        back,
    )
}

/// One cone program's answer: `min max |W_P S|` over the active lines,
/// the coefficients that reach it, and its 1σ.
struct Solved {
    gamma: f64,
    q: Vec<f64>,
    /// 1σ of `gamma` from the lines' errors (NaN: unknown).
    gamma_sigma: f64,
}

/// The 1σ of a cone program's optimum γ from the errors of the plant on
/// its lines, to first order through the program's dual (the sensitivity
/// of a conic program's optimum to its data, e.g. Boyd & Vandenberghe,
/// *Convex Optimization*, §5.6): for `min t` s.t. `b − A x ∈ K` with dual
/// `z`, `dγ = −zᵀ d(b − A x)`. A line's plant error `δP = P ε` moves its
/// cone `(t, w(1 − Re PQ), −w Im PQ)` by `−w (Re, Im)(P ε Q)`, so
/// `dγ = Re(C_k ε_k)` with `C_k = Σ_cones w (z₁ − j z₂) P_k Q_k` (`w` the
/// weight |W_P|, −1 for the band edge's `(t_max, Re PQ, Im PQ)`). With
/// `ε` circular of relative 1σ `σ_k` (`Var Re(C ε) = |C|² σ²/2`):
/// independent measured lines add in quadrature; one fit's lines (whose
/// errors are correlated) add linearly, `(Σ |C_k| σ_k)²/2`, the cautious
/// bound. `cones`: (line, `w`, `z₁ − j z₂`). NaN when a line that moves
/// γ (|C_k| above 10⁻⁶ of the largest) has no known 1σ.
fn gamma_sigma(
    rows: &[Row],
    q: &[f64],
    cones: &[(usize, f64, C64)],
    w_star: f64,
    s_max: f64,
) -> f64 {
    let mut per_line: std::collections::BTreeMap<usize, C64> = Default::default();
    for &(k, w, zc) in cones {
        let r = &rows[k];
        *per_line.entry(k).or_default() += zc * w * r.plant_at(w_star, s_max) * r.q_at(q);
    }
    let largest = per_line.values().map(|c| c.norm()).fold(0.0, f64::max);
    let mut independent = 0.0;
    let mut fits: std::collections::BTreeMap<usize, f64> = Default::default();
    for (&k, c) in &per_line {
        if c.norm() <= 1e-6 * largest {
            continue;
        }
        let (sigma, fit) = rows[k].sigma_at(w_star, s_max);
        if !(sigma.is_finite() && sigma >= 0.0) {
            return f64::NAN;
        }
        match fit {
            None => independent += (c.norm() * sigma).powi(2),
            Some(f) => *fits.entry(f).or_default() += c.norm() * sigma,
        }
    }
    ((independent + fits.values().map(|v| v * v).sum::<f64>()) / 2.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Balanced rows describe the same program: each cone's rows of
    /// `[A b]` at unit norm together, each nonnegative and zero row alone, the
    /// returned scale what multiplied them; and Clarabel finds the same
    /// optimum, and the original's dual from the balanced one's (`D z`
    /// meets the dual's stationarity `c + Aᵀ z = 0` on the original
    /// data). The program: min t s.t. ‖(x − 3, 2(y + 1))‖ ≤ t scaled by
    /// 10⁴, w = x scaled by 10³, w ≥ 1 scaled by 10⁻³, y ≤ −2: the
    /// optimum t = 2 at x = w = 3, y = −2.
    #[test]
    fn balanced_rows_are_the_same_program() {
        // Variables (x, y, t, w); rows s = b − A x, triplets of A.
        // Cone: (1e4 t, 1e4 (x − 3), 1e4·2(y + 1)); then 10³(x − w) = 0;
        // then 10⁻³(w − 1) ≥ 0 and −2 − y ≥ 0.
        let trip = [
            (0, 2, -1e4),
            (1, 0, -1e4),
            (2, 1, -2e4),
            (3, 0, -1e3),
            (3, 3, 1e3),
            (4, 3, -1e-3),
            (5, 1, 1.0),
        ];
        let ri: Vec<usize> = trip.iter().map(|t| t.0).collect();
        let ci: Vec<usize> = trip.iter().map(|t| t.1).collect();
        let vals: Vec<f64> = trip.iter().map(|t| t.2).collect();
        let b0 = vec![0.0, -3e4, 2e4, 0.0, -1e-3, -2.0];
        let cones = [
            SupportedConeT::SecondOrderConeT(3),
            SupportedConeT::ZeroConeT(1),
            SupportedConeT::NonnegativeConeT(2),
        ];
        let solve = |balance: bool| {
            let mut a = CscMatrix::new_from_triplets(6, 4, ri.clone(), ci.clone(), vals.clone());
            let mut b = b0.clone();
            let d = if balance {
                balance_rows(&a.rowval, &mut a.nzval, &mut b, &cones)
            } else {
                vec![1.0; 6]
            };
            if balance {
                // Each block at unit norm.
                let mut norm2 = b.iter().map(|v| v * v).collect::<Vec<f64>>();
                for (&r, v) in a.rowval.iter().zip(&a.nzval) {
                    norm2[r] += v * v;
                }
                assert!((norm2[..3].iter().sum::<f64>() - 1.0).abs() < 1e-12);
                for (r, n2) in norm2.iter().enumerate().skip(3) {
                    assert!((n2 - 1.0).abs() < 1e-12, "row {r}: {n2}");
                }
                assert_eq!(d[0], d[1]);
                assert_eq!(d[1], d[2]);
            }
            let settings = DefaultSettings::<f64> {
                verbose: false,
                equilibrate_enable: !balance,
                ..DefaultSettings::default()
            };
            let p = CscMatrix::zeros((4, 4));
            let mut solver =
                DefaultSolver::new(&p, &[0.0, 0.0, 1.0, 0.0], &a, &b, &cones, settings).unwrap();
            solver.solve();
            assert_eq!(solver.solution.status, SolverStatus::Solved);
            let z: Vec<f64> = solver
                .solution
                .z
                .iter()
                .zip(&d)
                .map(|(z, d)| z * d)
                .collect();
            (solver.solution.x.clone(), z)
        };
        for balance in [false, true] {
            let (x, z) = solve(balance);
            assert!(
                (x[0] - 3.0).abs() < 1e-6 && (x[1] + 2.0).abs() < 1e-6,
                "{x:?}"
            );
            assert!(
                (x[2] - 2.0).abs() < 1e-6 && (x[3] - 3.0).abs() < 1e-6,
                "{x:?}"
            );
            // The dual's stationarity on the original data: c + Aᵀ z = 0.
            let mut atz = [0.0; 4];
            for ((&r, &c), &v) in ri.iter().zip(&ci).zip(&vals) {
                atz[c] += v * z[r];
            }
            let c = [0.0, 0.0, 1.0, 0.0];
            for k in 0..4 {
                assert!(
                    (atz[k] + c[k]).abs() < 1e-6,
                    "balanced {balance}: Aᵀz {atz:?}"
                );
            }
        }
    }

    /// The thinning keeps the resonances of many noisy inputs within its
    /// budget, and every peak of one input's few: 3000 lines of ±1 %
    /// noise (about a thousand local maxima) with two resonances (20×,
    /// ten lines wide) keep both resonances and their neighbours, and at
    /// most about 2n lines in all (every local maximum: some 3000); 400
    /// lines with 20 ripples of 0.5 % (fewer than n/3, none prominent)
    /// keep every ripple's maximum.
    #[test]
    fn the_thinning_keeps_the_resonances_and_not_the_noise_s_peaks() {
        let n = 150;
        let noise = |k: usize| ((k as u64 * 2_654_435_761) % 1000) as f64 / 1000.0 - 0.5;
        let resonances = [1000usize, 2200];
        let magnitude: Vec<f64> = (0..3000)
            .map(|k| {
                let peaks: f64 = resonances
                    .iter()
                    .map(|&c| 19.0 / (1.0 + ((k as f64 - c as f64) / 5.0).powi(2)))
                    .sum();
                (1.0 + peaks) * (1.0 + 0.02 * noise(k))
            })
            .collect();
        let maxima = (1..2999).filter(|&k| local_peak(&magnitude, k)).count();
        assert!(maxima > 500, "{maxima} local maxima: not a noisy input");
        let kept = thinned_lines(&magnitude, n);
        for c in resonances {
            let top = (c - 3..=c + 3)
                .max_by(|a, b| magnitude[*a].total_cmp(&magnitude[*b]))
                .unwrap();
            for k in [top - 1, top, top + 1] {
                assert!(
                    kept.binary_search(&k).is_ok(),
                    "line {k} of the resonance at {c}"
                );
            }
        }
        assert!(
            kept.len() <= 2 * n,
            "{} lines kept of a budget of {n}",
            kept.len()
        );

        let ripples_400: Vec<f64> = (0..400)
            .map(|k| 1.0 + 0.005 * (2.0 * PI * k as f64 / 20.0).sin())
            .collect();
        let kept = thinned_lines(&ripples_400, n);
        let tops: Vec<usize> = (1..399).filter(|&k| local_peak(&ripples_400, k)).collect();
        assert_eq!(tops.len(), 20, "{tops:?}");
        for k in tops {
            assert!(kept.binary_search(&k).is_ok(), "ripple maximum {k}");
        }
    }

    /// The shipped bench's RHP pair 2π(1.7 ± 83j) Hz at M = 2: 446 rad/s
    /// (issue 41), and a real zero: z(1 − 1/M).
    #[test]
    fn the_rhp_zero_bound_is_the_maximum_modulus_bound() {
        let z = C64::new(1.7, 83.0) * (2.0 * PI);
        let b = rhp_zero_bound_rad_s(z, 2.0).unwrap();
        assert!((b - 446.0).abs() < 1.0, "{b}");
        // At the bound |W_P(z)| = 1 exactly.
        let wp = (z / 2.0 + b) / z;
        assert!((wp.norm() - 1.0).abs() < 1e-12);
        let r = rhp_zero_bound_rad_s(C64::new(100.0, 0.0), 2.0).unwrap();
        assert!((r - 50.0).abs() < 1e-9, "{r}");
        assert_eq!(rhp_zero_bound_rad_s(C64::new(-1.0, 3.0), 2.0), None);
        assert_eq!(rhp_zero_bound_rad_s(C64::new(1.0, 3.0), 1.0), None);
    }

    /// Each argument outside its physical range is refused, naming it:
    /// the period, M, the search's upper end, the lines.
    #[test]
    fn arguments_outside_their_range_are_refused() {
        let t = 2e-4;
        let w = [10.0, 100.0];
        let p = [C64::new(1e-5, 0.0), C64::new(-1e-6, 1e-7)];
        let ok = [Lines {
            label: "frf",
            omega_rad_s: &w,
            plant_m_per_a: &p,
            relative_sigma: &[],
            correlated: false,
            noise: None,
        }];
        let basis = || Basis::new(4, &[], t);
        let bad = |r: Result<Limit, LimitError>, words: &str| match r {
            Err(e) => assert!(e.to_string().contains(words), "{e}"),
            Ok(l) => panic!("accepted: ω* {}", l.performance_bandwidth_rad_s),
        };
        for period in [0.0, -t, f64::NAN, f64::INFINITY] {
            bad(
                performance_limit(&ok, basis(), period, 2.0, None, LoopBounds::NONE),
                "sample period",
            );
        }
        for m in [1.0, 0.5, f64::NAN] {
            bad(
                performance_limit(&ok, basis(), t, m, None, LoopBounds::NONE),
                "M =",
            );
        }
        for u in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            bad(
                performance_limit(&ok, basis(), t, 2.0, Some(u), LoopBounds::NONE),
                "upper end",
            );
        }
        bad(
            performance_limit(&[], basis(), t, 2.0, None, LoopBounds::NONE),
            "no lines",
        );
        let effort = |e| LoopBounds {
            effort_max_a_per_m: e,
            ..LoopBounds::NONE
        };
        let edge = |w, t_max| LoopBounds {
            band_edge_rad_s: w,
            band_edge_t_max: t_max,
            ..LoopBounds::NONE
        };
        for (b, needle) in [
            (effort(0.0), "effort bound"),
            (effort(-1.0), "effort bound"),
            (effort(f64::NAN), "effort bound"),
            (edge(0.0, 0.0), "band edge"),
            (edge(0.0, -0.1), "band edge"),
            (edge(0.0, f64::NAN), "band edge"),
            (edge(f64::NAN, 0.24), "band edge"),
            (edge(-1.0, 0.24), "band edge"),
        ] {
            bad(performance_limit(&ok, basis(), t, 2.0, None, b), needle);
        }
        for (wl, pl) in [
            (1e9, C64::new(1e-5, 0.0)),
            (10.0, C64::new(f64::NAN, 0.0)),
            (10.0, C64::new(0.0, 0.0)),
        ] {
            let (wa, pa) = ([wl], [pl]);
            let l = [Lines {
                label: "frf",
                omega_rad_s: &wa,
                plant_m_per_a: &pa,
                relative_sigma: &[],
                correlated: false,
                noise: None,
            }];
            bad(
                performance_limit(&l, basis(), t, 2.0, None, LoopBounds::NONE),
                "frf: the line",
            );
        }
    }

    /// The closed form against a bisection on |W_P S| ≤ 1 for the loop
    /// S = s/(s + ω_c) (ω* = ω_c/√(1 − 1/M²)·… found numerically here).
    #[test]
    fn the_loop_bandwidth_is_the_largest_weight_met_on_every_line() {
        let wc = 50.0;
        let omega: Vec<f64> = (0..300).map(|k| 0.1 * 1.05f64.powi(k)).collect();
        let s_abs: Vec<f64> = omega
            .iter()
            .map(|&w| (C64::new(0.0, w) / C64::new(wc, w)).norm())
            .collect();
        let got = loop_performance_bandwidth_rad_s(&omega, &s_abs, 2.0).unwrap();
        let meets = |ws: f64| {
            omega
                .iter()
                .zip(&s_abs)
                .all(|(&w, &s)| s * performance_weight_magnitude(w, ws, 2.0) <= 1.0 + 1e-12)
        };
        let (mut lo, mut hi) = (0.0, 1e4);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if meets(mid) {
                lo = mid
            } else {
                hi = mid
            }
        }
        assert!((got - lo).abs() < 1e-9 * lo, "{got} vs {lo}");
        // For S = s/(s + ω_c) the weight binds as ω → 0: ω* → ω_c.
        assert!((got - wc).abs() < 0.01 * wc, "{got}");
        // |S| above M anywhere: no ω*.
        assert_eq!(
            loop_performance_bandwidth_rad_s(&[1.0, 2.0], &[0.5, 2.5], 2.0),
            None
        );
    }

    /// The limit on the true plant of the shipped bench and of two
    /// held-out benches (`tests/data/limit_cases.json`), with the
    /// design's bounds and without them, within 10 % of the
    /// independent reference (`tests/data/limit_reference.py`: cvxpy and
    /// Clarabel on the plant built from scratch with scipy, its own basis;
    /// the stored `limit_reference.json`), and each right-half-plane
    /// zeros' bound within 1 % of the reference's (its zeros from scipy's
    /// `ss2zpk`, ours from the modal sum's numerator). The plant here is
    /// the config's model on every 10th line of its grid within the
    /// reference's band (π rad/s to 0.98 of the Nyquist frequency), Q's
    /// poles from the model's modes as a fit would give them. (The band
    /// matters: on a delay-limited bench the lines in the top 2 % below
    /// Nyquist bind, and with them the limit is 8-11 % lower.)
    #[test]
    fn the_limit_matches_the_independent_reference_on_three_benches() {
        use serde_json::Value;
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/");
        let read = |f: &str| -> Value {
            serde_json::from_str(&std::fs::read_to_string(format!("{dir}{f}")).unwrap()).unwrap()
        };
        let cases = read("limit_cases.json");
        let refs = read("limit_reference.json");
        let shipped = crate::config::BenchConfig::load(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/bench-config/sr4dof-ch5.toml"
        )))
        .unwrap();
        for (c, r) in cases["cases"]
            .as_array()
            .unwrap()
            .iter()
            .zip(refs["cases"].as_array().unwrap())
        {
            assert_eq!(c["name"], r["name"]);
            let f = |k: &str| c[k].as_f64().unwrap();
            let m: Vec<f64> = c["m_kg"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            let mut cfg = shipped.clone();
            let p = &mut cfg.plant;
            (p.m1_kg, p.m2_kg, p.m3_kg, p.m4_kg, p.m5_kg) = (m[0], m[1], m[2], m[3], m[4]);
            p.k4_n_per_m = f("k4_n_per_m");
            p.k5_n_per_m = f("k5_n_per_m");
            p.parallelogram_stiffness_n_per_m = Some(f("kp_n_per_m"));
            p.operating_point_m = f("y1o_fraction_of_l") * p.beam.length_m;
            p.mass_asymmetry = f("mass_asymmetry");
            let t = 1.0 / cfg.loop_.rate_hz;
            let frf = crate::design::predict::model_frf(&cfg, f("delay_periods") * t).unwrap();
            let band = |w: &f64| *w >= PI && *w <= 0.98 * PI / t;
            let omega: Vec<f64> = frf
                .omega_rad_s
                .iter()
                .step_by(10)
                .copied()
                .filter(band)
                .collect();
            let plant: Vec<C64> = frf
                .omega_rad_s
                .iter()
                .zip(&frf.plant_m_per_a)
                .step_by(10)
                .filter(|(w, _)| band(w))
                .map(|(_, p)| *p)
                .collect();
            let model = bench_plant::model::Sr4dof::new(cfg.plant).unwrap();
            let modes = model.modes();
            let zeros = crate::ident::modal_fit::damped_numerator_roots(
                &modes.iter().map(|m| m.frequency_hz()).collect::<Vec<_>>(),
                &modes.iter().map(|m| m.zeta).collect::<Vec<_>>(),
                &modes.iter().map(|m| m.residue).collect::<Vec<_>>(),
            );
            let lines = [Lines {
                label: "model",
                omega_rad_s: &omega,
                plant_m_per_a: &plant,
                relative_sigma: &[],
                correlated: false,
                noise: None,
            }];
            let basis = Basis::for_plant(&zeros, omega[0], t);
            // With the design's bounds (the case's peak current and step,
            // its band edge) and without them.
            let bounds = LoopBounds {
                effort_max_a_per_m: LoopBounds::effort_for_step(f("peak_current_a"), f("step_m")),
                band_edge_rad_s: 2.0 * PI * f("edge_fraction") * f("band_top_hz"),
                band_edge_t_max: f("edge_t_max"),
            };
            let mut got = 0.0;
            for (b, key) in [
                (LoopBounds::NONE, "limit_without_bounds_rad_s"),
                (bounds, "limit_rad_s"),
            ] {
                let l = performance_limit(&lines, basis.clone(), t, f("s_max"), None, b).unwrap();
                let want = r[key].as_f64().unwrap();
                got = l.performance_bandwidth_rad_s;
                // The limit's Q is its certificate: the bounds hold on
                // every line, not only on those its last program held
                // (lines join by constraint generation).
                for (&w, &p) in omega.iter().zip(&plant) {
                    let q = l.q_at(w, t);
                    assert!(
                        q.norm() <= b.effort_max_a_per_m * (1.0 + 1e-5),
                        "{} {w} rad/s: |Q| {}",
                        c["name"],
                        q.norm()
                    );
                    if w >= b.band_edge_rad_s {
                        assert!(
                            (p * q).norm() <= b.band_edge_t_max * (1.0 + 1e-5),
                            "{} {w} rad/s: |T| {}",
                            c["name"],
                            (p * q).norm()
                        );
                    }
                }
                if key == "limit_rad_s" {
                    assert!(
                        l.effort_binds_at_rad_s.is_some() || l.band_edge_binds_at_rad_s.is_some(),
                        "{}: no bound holds the limit, the check above is empty",
                        c["name"]
                    );
                }
                eprintln!("{} {key}: {got:.1} rad/s, reference {want:.1}", c["name"]);
                assert!(
                    (got / want - 1.0).abs() <= 0.10,
                    "{} {key}: {got} vs {want}",
                    c["name"]
                );
            }
            for b in r["rhp_zero_bounds"].as_array().unwrap() {
                let zr = C64::new(b["re_hz"].as_f64().unwrap(), b["im_hz"].as_f64().unwrap());
                let ours = zeros
                    .iter()
                    .filter(|z| z.re > 0.0 && z.im >= 0.0)
                    .min_by(|a, b| {
                        (**a / (2.0 * PI) - zr)
                            .norm()
                            .total_cmp(&(**b / (2.0 * PI) - zr).norm())
                    })
                    .unwrap_or_else(|| panic!("{}: no RHP zero near {zr}", c["name"]));
                let bound = rhp_zero_bound_rad_s(*ours, f("s_max")).unwrap();
                let want = b["bound_rad_s"].as_f64().unwrap();
                assert!(
                    (bound / want - 1.0).abs() < 0.01,
                    "{}: {bound} vs {want}",
                    c["name"]
                );
                assert!(
                    got <= bound * 1.01,
                    "{}: {got} above the zero's bound {bound}",
                    c["name"]
                );
            }
        }
    }

    /// `P(s) = (1 − s/z)/(1 + s/a)²`, z = 100 rad/s (a real RHP zero),
    /// a = 30 rad/s, on 600 log-spaced lines from 0.05 rad/s to 0.999 of
    /// the Nyquist frequency at T = 10⁻⁴ s.
    struct RhpZeroPlant {
        z: f64,
        t: f64,
        lowest: f64,
        omega: Vec<f64>,
        plant: Vec<C64>,
    }

    impl RhpZeroPlant {
        fn new() -> Self {
            let (z, a, t, lowest) = (100.0, 30.0, 1e-4, 0.05);
            let omega: Vec<f64> = (0..600)
                .map(|k| lowest * (0.999 * PI / t / lowest).powf(k as f64 / 599.0))
                .collect();
            let plant = omega
                .iter()
                .map(|&w| {
                    let s = C64::new(0.0, w);
                    (1.0 - s / z) / ((1.0 + s / a) * (1.0 + s / a))
                })
                .collect();
            Self {
                z,
                t,
                lowest,
                omega,
                plant,
            }
        }
    }

    /// G(s) = (1 − s/z)/(1 + s/a)², sampled fast, no delay: the limit
    /// approaches the analytic bound z(1 − 1/M) from below (the bound is
    /// tight for a single real RHP zero as the delay vanishes). The lines
    /// span 0.05 rad/s (z/2000) to 0.999 of the Nyquist frequency: the
    /// bound holds where |W_P S| ≤ 1 holds on the whole axis, and below
    /// the lowest line the weight (ω*/ω there) is not enforced. From 0.5
    /// rad/s the limit was 50.7 rad/s, 1.4 % over the bound, at any
    /// sample period (10⁻⁴ to 10⁻⁵ s: not the sampling); from 0.05 rad/s
    /// 49.7, from 0.005 49.6.
    #[test]
    fn the_limit_of_a_real_rhp_zero_plant_is_near_its_analytic_bound() {
        let RhpZeroPlant {
            z,
            t,
            lowest,
            omega,
            plant,
        } = RhpZeroPlant::new();
        let lines = [Lines {
            label: "analytic",
            omega_rad_s: &omega,
            plant_m_per_a: &plant,
            relative_sigma: &[],
            correlated: false,
            noise: None,
        }];
        let basis = Basis::for_plant(&[C64::new(z, 0.0)], lowest, t);
        let l = performance_limit(&lines, basis, t, 2.0, Some(200.0), LoopBounds::NONE).unwrap();
        let bound = rhp_zero_bound_rad_s(C64::new(z, 0.0), 2.0).unwrap();
        let w = l.performance_bandwidth_rad_s;
        // Lines only constrain the lines: between them (and above the
        // last) |W_P S| may pass 1 by a little, so the limit on lines may
        // pass the bound by as much.
        assert!(w <= bound * 1.01, "{w} above the bound {bound}");
        assert!(w >= 0.8 * bound, "{w} far under the bound {bound}");
        // The Q returned is the certificate: its loop, S = 1 − P Q, meets
        // the weight of the limit on every line, and binds somewhere.
        let s_abs: Vec<f64> = omega
            .iter()
            .zip(&plant)
            .map(|(&om, &p)| (1.0 - p * l.q_at(om, t)).norm())
            .collect();
        let reached = loop_performance_bandwidth_rad_s(&omega, &s_abs, 2.0).unwrap();
        assert!(
            reached >= w * (1.0 - 1e-9),
            "its Q reaches {reached}, not {w}"
        );
        assert!(!l.binding.is_empty());
        for b in &l.binding {
            assert!(
                b.weighted_sensitivity <= 1.0 + 1e-9 && b.weighted_sensitivity > 0.95,
                "{b:?}"
            );
        }
        // A sample period or an M no loop can have.
        for (period, m) in [
            (0.0, 2.0),
            (f64::NAN, 2.0),
            (t, 1.0),
            (t, 0.5),
            (t, f64::INFINITY),
        ] {
            let e = performance_limit(
                &lines,
                Basis::new(4, &[], t),
                period,
                m,
                None,
                LoopBounds::NONE,
            )
            .unwrap_err();
            assert!(matches!(e, LimitError::BadArgument(_)), "{period} {m}: {e}");
        }
    }

    /// The limit's 1σ ([`Limit::performance_bandwidth_sigma_rad_s`],
    /// first order through the program's dual) against sampling: the
    /// analytic RHP-zero plant above on 600 lines, each with 2 % circular
    /// complex noise, its σ given, and the exact plant as the model that
    /// stands in where a line's noise hides the bound (as a design's fit
    /// does; here with no error of its own). Over 24 draws the mean stated
    /// 1σ is 0.56 rad/s and the limit's spread 0.27 rad/s (mean 46.7 of
    /// the noise-free 49.7; 0.57 and 0.35 with another 24 draws): cautious,
    /// as the design's first-order 1σ are
    /// (many binding lines, each taken at its full weight); the test asks
    /// 0.8–2.5× (the spread of 24 draws is itself uncertain by about
    /// 15 %). Without the σ the limit's 1σ is unknown, not 0.
    #[test]
    fn the_limit_s_1_sigma_matches_the_spread_over_noisy_lines() {
        let RhpZeroPlant {
            z,
            t,
            lowest,
            omega,
            plant: exact,
        } = RhpZeroPlant::new();
        let sigma_r = 0.02;
        let sigma = vec![sigma_r; omega.len()];
        let exact_sigma = vec![0.0; omega.len()];
        let normal = crate::splitmix::standard_normal;
        let limit = |plant: &[C64], sigma: &[f64]| {
            let lines = [Lines {
                label: "noisy",
                omega_rad_s: &omega,
                plant_m_per_a: plant,
                relative_sigma: sigma,
                correlated: false,
                noise: (!sigma.is_empty()).then_some(LineNoise {
                    model_m_per_a: &exact,
                    model_relative_sigma: &exact_sigma,
                }),
            }];
            let basis = Basis::for_plant(&[C64::new(z, 0.0)], lowest, t);
            performance_limit(&lines, basis, t, 2.0, Some(200.0), LoopBounds::NONE).unwrap()
        };
        let unknown = limit(&exact, &[]);
        assert_eq!(unknown.performance_bandwidth_sigma_rad_s, None);
        let draws = 24;
        let (mut w, mut stated) = (Vec::new(), Vec::new());
        for d in 0..draws {
            let noisy: Vec<C64> = exact
                .iter()
                .enumerate()
                .map(|(k, p)| {
                    let i = (d * 10_000 + k) as u64 * 2;
                    p * (1.0 + C64::new(normal(i), normal(i + 1)) * (sigma_r / 2f64.sqrt()))
                })
                .collect();
            let l = limit(&noisy, &sigma);
            w.push(l.performance_bandwidth_rad_s);
            stated.push(l.performance_bandwidth_sigma_rad_s.expect("a 1σ"));
        }
        let n = draws as f64;
        let mean = w.iter().sum::<f64>() / n;
        let spread = (w.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        let said = stated.iter().sum::<f64>() / n;
        assert!(
            (0.8..=2.5).contains(&(said / spread)),
            "stated 1σ {said} rad/s, spread {spread} rad/s over {draws} draws (mean {mean})"
        );
    }
}
