//! The constrained search: maximise performance (the sensitivity
//! bandwidth) over the input FRFs subject to the margins on every one of
//! them, over a family's parameters ([`super::family`]).
//!
//! The constraints are turned into one violation `v ≥ 0` (0: all met),
//! each term scaled to about 1 per tolerable miss, summed over the FRFs:
//!
//! ```text
//! Σ_crossings max(0, PM_min − |PM_i|)/10°  +  max(0, GM_min − GM)/6 dB
//!   + max(0, 20 log10(‖S‖∞/S_max))/1 dB  +  10·(RHP closed-loop poles)
//!   + 10·(no crossover)  +  max(0, |L|_edge − EDGE_GAIN_MAX_DB)/6 dB
//! ```
//!
//! The search minimises the exact penalty `−½ (ln ω* + ln ω_4.5) + 30 v`
//! (ω* the performance weight's bandwidth, [`Evaluation::objective_rad_s`];
//! ω_4.5 where |S| first reaches −4.5 dB, [`Evaluation::level_rad_s`]) with
//! the Nelder–Mead simplex (`argmin`'s; Nelder & Mead, *Comput. J.* 7,
//! 1965), from the thesis-scaled start and [`STARTS`] − 1 starts around it
//! drawn from a fixed SplitMix64 stream (deterministic: the same inputs
//! give the same controller), each polished once more from its best
//! vertex.

use super::family::Family;
use super::loops::{figures, open_loop, DesignFrf, LoopFigures};
use crate::control::loop_check::{resolving, unresolved};
use crate::control::{ControllerConfig, DiscreteController};
use crate::ident::C64;
use crate::splitmix::{splitmix64, GAMMA};
use argmin::core::{CostFunction, Error, Executor, State};
use argmin::solver::neldermead::NelderMead;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Starts of the multi-start search.
pub const STARTS: usize = 8;
/// Nelder–Mead iterations per run.
pub const ITERATIONS: u64 = 1500;
/// The discretisation's error on a line above which the search judges
/// what runs rather than the design ([`Problem::discretized_as`]), dB:
/// the least-squares discretisation's target up to f_s/10
/// ([`crate::control::DiscretizationReport`]).
pub const CORRECTION_FROM_DB: f64 = 0.1;
/// … and in phase, degrees.
pub const CORRECTION_FROM_DEG: f64 = 1.0;
/// Highest loop gain |L| left at the highest coherent line of an FRF, dB:
/// above the measurement the plant is unknown, and a loop that still has
/// gain there cannot be certified.
pub const EDGE_GAIN_MAX_DB: f64 = -10.0;

/// The margins a design must meet on every FRF.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Requirements {
    /// Phase margin at every gain crossover, degrees.
    pub phase_margin_min_deg: f64,
    /// Gain margin, dB.
    pub gain_margin_min_db: f64,
    /// Largest ‖S‖∞ (1 / modulus margin).
    pub sensitivity_peak_max: f64,
}

/// The constraint that binds (or is violated most), for reports and for
/// the error when no controller of a family meets the margins.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Binding {
    /// The input FRF.
    pub input: String,
    /// `phase margin`, `gain margin`, `sensitivity peak`, `Nyquist`,
    /// `no crossover` or `band edge`.
    pub constraint: String,
    /// Its value (degrees, dB, ratio, poles, dB).
    pub value: f64,
    /// Its limit.
    pub limit: f64,
    /// Where, rad/s (`None`: not at one frequency).
    pub at_rad_s: Option<f64>,
}

impl std::fmt::Display for Binding {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let at = self.at_rad_s.map_or(String::new(), |w| {
            format!(
                " at {w:.1} rad/s ({:.2} Hz)",
                w / (2.0 * std::f64::consts::PI)
            )
        });
        let (v, l, i) = (self.value, self.limit, &self.input);
        match self.constraint.as_str() {
            "phase margin" => {
                let rel = if v < l { "below" } else { "against" };
                write!(f, "phase margin {v:.1}° {rel} {l:.1}°{at} on {i}")
            }
            "gain margin" => {
                let rel = if v < l { "below" } else { "against" };
                write!(f, "gain margin {v:.2} dB {rel} {l:.2} dB{at} on {i}")
            }
            "sensitivity peak" => {
                let rel = if v > l { "above" } else { "against" };
                write!(f, "‖S‖∞ {v:.3} {rel} {l:.3}{at} on {i}")
            }
            "Nyquist" => write!(
                f,
                "closed loop unstable by the Nyquist count ({v} right-half-plane poles) on {i}"
            ),
            "no crossover" => write!(f, "no gain crossover on {i}"),
            _ => {
                let rel = if v > l { "above" } else { "against" };
                write!(f, "|L| {v:.1} dB {rel} {l:.1} dB at the highest coherent line{at} of {i} (the loop's gain where the measurement ends)")
            }
        }
    }
}

/// One candidate judged on every FRF.
#[derive(Debug, Clone)]
pub struct Evaluation {
    /// The controller.
    pub controller: ControllerConfig,
    /// Figures per FRF, in input order.
    pub figures: Vec<LoopFigures>,
    /// Total violation (0: feasible).
    pub violation: f64,
    /// Violation per FRF, in input order.
    pub per_input_violation: Vec<f64>,
    /// The worst violated constraint, or the tightest one when feasible.
    pub binding: Option<Binding>,
    /// Smallest ω_B over the FRFs, rad/s.
    pub sensitivity_bandwidth_min_rad_s: f64,
    /// What the search maximises, rad/s: the largest ω* for which
    /// `|S(jω)| ≤ 1/|W_P(jω)|` on every line of every FRF (a model's from
    /// the lowest measured line up: [`Problem::with_models`]), with the
    /// standard performance weight `W_P(s) = (s/M + ω*)/s` (Skogestad &
    /// Postlethwaite §2.8.2, Eq. 2.72 with A = 0: integral action; M =
    /// `sensitivity_peak_max`): `ω* = min ω √(1/|S|² − 1/M²)`. It asks
    /// |S| to rise no faster than a first-order high-pass of corner ω*,
    /// so the loop cannot buy a high −3 dB crossing with |S| hovering just
    /// under −3 dB far below it (a slow tail in the step: the thesis'
    /// "deep" in T, §6.2.1). Where |S| = 1/√2 the weight's bound gives
    /// ω_B ≥ ω*/√(2 − 1/M²) (≈ 0.76 ω* for M = 2).
    pub objective_rad_s: f64,
    /// The smallest frequency over the FRFs at which |S| first reaches
    /// −4.5 dB (1.5 dB inside the −3 dB of ω_B), rad/s.
    pub level_rad_s: f64,
}

impl Evaluation {
    /// Whether every constraint holds.
    pub fn feasible(&self) -> bool {
        self.violation <= 0.0
    }

    /// The search's cost.
    pub fn cost(&self) -> f64 {
        -0.5 * (self.objective_rad_s.ln() + self.level_rad_s.ln()) + 30.0 * self.violation
    }
}

/// The FRFs on one frequency axis: every distinct line once, so that the
/// controller is evaluated once per line whatever the number of inputs.
#[derive(Debug, Clone)]
pub struct Problem<'a> {
    frfs: Vec<&'a DesignFrf>,
    omega_rad_s: Vec<f64>,
    index: Vec<Vec<usize>>,
    unit_per_metre: f64,
    req: Requirements,
    /// ω* is read from here up, rad/s: the lowest measured line when
    /// models join the inputs (below it a model only extrapolates the
    /// fit, and the limit has no constraint there), else 0.
    objective_from_rad_s: f64,
    /// The discretisation's error `C_d(e^{jωT}) / C(jω)` on every line,
    /// of the controller it was taken from ([`Self::discretized_as`]):
    /// [`Self::evaluate`] judges `C · r`, what runs, not the continuous
    /// design. Empty: the continuous design.
    correction: Vec<C64>,
    /// How many of `frfs`, at their end, are models (analytic responses on
    /// a dense grid, [`Self::with_models`]) rather than measured lines.
    models: usize,
}

impl<'a> Problem<'a> {
    /// The problem of the inputs `frfs` (measured lines) and the `models`
    /// (their fits' or a config's response on a dense grid) under `req`:
    /// every constraint on every point of both, ω* from the lowest
    /// measured line up, as [`crate::design::limit`] bounds it.
    pub fn with_models(
        frfs: &'a [DesignFrf],
        models: &'a [DesignFrf],
        req: Requirements,
        unit_per_metre: f64,
    ) -> Self {
        let lowest = frfs
            .iter()
            .filter_map(|f| f.omega_rad_s.first().copied())
            .fold(f64::INFINITY, f64::min);
        Self {
            objective_from_rad_s: if lowest.is_finite() { lowest } else { 0.0 },
            models: models.len(),
            ..Self::new(frfs.iter().chain(models).collect(), req, unit_per_metre)
        }
    }

    /// The models of this problem on grids that resolve `resonances`
    /// (rad/s: frequency and half-width, a controller's lightly damped
    /// poles, [`DiscreteController::resonances`]), with the points
    /// [`resolving`] adds interpolated linearly in `ln ω` between the
    /// model's own (its plant is smooth on the scale of its dense grid:
    /// 0.06 % of ω apart, where the slowest mode a fit keeps is about 1 %
    /// wide). Empty when every model already resolves them.
    pub fn models_resolving(&self, resonances: &[(f64, f64)]) -> Vec<DesignFrf> {
        let models = &self.frfs[self.frfs.len() - self.models..];
        if models
            .iter()
            .all(|m| unresolved(&m.omega_rad_s, resonances).is_empty())
        {
            return Vec::new();
        }
        models
            .iter()
            .map(|m| {
                let grid = resolving(&m.omega_rad_s, resonances);
                let plant = grid.iter().map(|&w| interpolated(m, w)).collect();
                DesignFrf {
                    label: m.label.clone(),
                    lines_total: grid.len(),
                    omega_rad_s: grid,
                    plant_m_per_a: plant,
                }
            })
            .collect()
    }

    /// This problem with its models replaced by `models` (as many, in the
    /// same order: [`Self::models_resolving`]'s).
    pub fn with_models_replaced<'b>(&'b self, models: &'b [DesignFrf]) -> Problem<'b> {
        let measured = self.frfs.len() - self.models;
        Problem {
            objective_from_rad_s: self.objective_from_rad_s,
            models: models.len(),
            ..Problem::new(
                self.frfs[..measured]
                    .iter()
                    .copied()
                    .chain(models)
                    .collect(),
                self.req,
                self.unit_per_metre,
            )
        }
    }

    /// The problem of `frfs` (non-empty, each with lines) under `req`,
    /// for controllers whose error unit is `unit_per_metre` per metre.
    pub fn new(frfs: Vec<&'a DesignFrf>, req: Requirements, unit_per_metre: f64) -> Self {
        let mut omega: Vec<f64> = frfs
            .iter()
            .flat_map(|f| f.omega_rad_s.iter().copied())
            .collect();
        omega.sort_by(f64::total_cmp);
        omega.dedup();
        let index = frfs
            .iter()
            .map(|f| {
                f.omega_rad_s
                    .iter()
                    .map(|w| omega.partition_point(|x| x < w))
                    .collect()
            })
            .collect();
        Self {
            frfs,
            omega_rad_s: omega,
            index,
            unit_per_metre,
            req,
            objective_from_rad_s: 0.0,
            correction: Vec::new(),
            models: 0,
        }
    }

    /// This problem judging every controller with the discretisation's
    /// error of `controller` at `period_s` (`C_d/C` on every line, the
    /// least-squares discretisation that will run): near `controller` the
    /// search then sees what runs, not the continuous design (the error
    /// changes little with the parameters: the search refreshes it from
    /// its latest design, and the certificate judges the exact `C_d`).
    /// Issue 45: the discretised controller may be up to 0.8 dB / 6° off
    /// the design at f_s/4, where an FRF measured that far has lines.
    /// Where the error stays within [`CORRECTION_FROM_DB`] /
    /// [`CORRECTION_FROM_DEG`] on every line (an FRF measured to f_s/10,
    /// the default chirp's 500 Hz at 5 kHz, where the discretisation is
    /// fitted), the continuous design is what runs to that accuracy and
    /// is judged as it is.
    pub fn discretized_as(&self, controller: &ControllerConfig, period_s: f64) -> Self {
        let d = DiscreteController::new(controller, period_s, f64::INFINITY);
        let correction: Vec<C64> = self
            .omega_rad_s
            .iter()
            .map(|&w| {
                let r = d.response(w, period_s) / controller.response(w);
                if r.re.is_finite() && r.im.is_finite() && r.norm() > 0.0 {
                    r
                } else {
                    C64::new(1.0, 0.0)
                }
            })
            .collect();
        let material = correction.iter().any(|r| {
            (20.0 * r.norm().log10()).abs() > CORRECTION_FROM_DB
                || r.arg().to_degrees().abs() > CORRECTION_FROM_DEG
        });
        Self {
            correction: if material { correction } else { Vec::new() },
            ..self.clone()
        }
    }

    /// Judges `controller` on every FRF, with `response` its frequency
    /// response (the continuous design while searching, the discrete
    /// controller that will run when certifying).
    pub fn evaluate_with(
        &self,
        controller: ControllerConfig,
        response: &dyn Fn(f64) -> C64,
    ) -> Evaluation {
        let c_all: Vec<C64> = self.omega_rad_s.iter().map(|&w| response(w)).collect();
        let mut figs = Vec::with_capacity(self.frfs.len());
        let mut violation = 0.0;
        let mut worst: Option<(f64, Binding)> = None;
        let mut tightest: Option<(f64, Binding)> = None;
        let mut wb_min = f64::INFINITY;
        let mut objective = f64::INFINITY;
        let mut level = f64::INFINITY;
        let mut per_input = Vec::with_capacity(self.frfs.len());
        let req = self.req;
        for (&frf, idx) in self.frfs.iter().zip(&self.index) {
            let c: Vec<C64> = idx.iter().map(|&i| c_all[i]).collect();
            let l = open_loop(frf, &c, self.unit_per_metre);
            let f = figures(&frf.omega_rad_s, &l, controller.integrators);
            let before = violation;
            let mut judge = |term: f64, slack: f64, b: Binding| {
                violation += term.max(0.0);
                if term > 0.0 && worst.as_ref().is_none_or(|(t, _)| term > *t) {
                    worst = Some((term, b.clone()));
                }
                if tightest.as_ref().is_none_or(|(s, _)| slack < *s) {
                    tightest = Some((slack, b));
                }
            };
            let b = |constraint: &str, value: f64, limit: f64, at: Option<f64>| Binding {
                input: frf.label.clone(),
                constraint: constraint.into(),
                value,
                limit,
                at_rad_s: at,
            };
            for (w, pm) in f
                .margins
                .crossovers_rad_s
                .iter()
                .zip(&f.margins.phase_margins_deg)
            {
                let m = req.phase_margin_min_deg;
                // The angle between L and −1, whichever way L turns.
                let pm = pm.abs();
                judge(
                    (m - pm) / 10.0,
                    (pm - m) / 10.0,
                    b("phase margin", pm, m, Some(*w)),
                );
            }
            if f.margins.crossovers_rad_s.is_empty() {
                judge(10.0, -10.0, b("no crossover", 0.0, 1.0, None));
            }
            if let Some(gm) = f.margins.gain_margin_db {
                let m = req.gain_margin_min_db;
                judge(
                    (m - gm) / 6.0,
                    (gm - m) / 6.0,
                    b("gain margin", gm, m, f.margins.gain_margin_at_rad_s),
                );
            }
            let s_db = 20.0 * (f.margins.sensitivity_peak / req.sensitivity_peak_max).log10();
            judge(
                s_db,
                -s_db,
                b(
                    "sensitivity peak",
                    f.margins.sensitivity_peak,
                    req.sensitivity_peak_max,
                    Some(f.margins.sensitivity_peak_at_rad_s),
                ),
            );
            if f.rhp_closed_loop_poles > 0 {
                judge(
                    10.0 * f.rhp_closed_loop_poles as f64,
                    -10.0,
                    b("Nyquist", f.rhp_closed_loop_poles as f64, 0.0, None),
                );
            }
            let e = (f.edge_gain_db - EDGE_GAIN_MAX_DB) / 6.0;
            judge(
                e,
                -e,
                b(
                    "band edge",
                    f.edge_gain_db,
                    EDGE_GAIN_MAX_DB,
                    frf.omega_rad_s.last().copied(),
                ),
            );
            let wb = f.sensitivity_bandwidth_rad_s.unwrap_or(frf.omega_rad_s[0]);
            wb_min = wb_min.min(wb);
            // The performance weight's bandwidth (see `objective_rad_s`):
            // ω* ≤ ω √(1/|S|² − 1/M²) on every line from the lowest
            // measured one up.
            let m2 = 1.0 / (req.sensitivity_peak_max * req.sensitivity_peak_max);
            let reach = frf
                .omega_rad_s
                .iter()
                .zip(&l)
                .filter(|(w, _)| **w >= self.objective_from_rad_s)
                .map(|(w, v)| w * ((v + 1.0).norm_sqr() - m2).max(1e-12).sqrt())
                .fold(f64::INFINITY, f64::min);
            objective = objective.min(reach);
            let s_level = 10f64.powf(-4.5 / 20.0);
            let w = &frf.omega_rad_s;
            let s_at = |k: usize| 1.0 / (l[k] + 1.0).norm();
            let lv = match (0..l.len()).find(|&k| s_at(k) >= s_level) {
                None => w[w.len() - 1],
                Some(0) => w[0],
                Some(k) => {
                    let (a, b) = (s_at(k - 1).ln(), s_at(k).ln());
                    let t = ((s_level.ln() - a) / (b - a)).clamp(0.0, 1.0);
                    (w[k - 1].ln() + t * (w[k].ln() - w[k - 1].ln())).exp()
                }
            };
            level = level.min(lv);
            figs.push(f);
            per_input.push(violation - before);
        }
        Evaluation {
            controller,
            figures: figs,
            violation,
            per_input_violation: per_input,
            binding: worst.or(tightest).map(|(_, b)| b),
            sensitivity_bandwidth_min_rad_s: wb_min,
            objective_rad_s: objective,
            level_rad_s: level,
        }
    }

    /// The FRFs, in order.
    pub fn frfs(&self) -> &[&'a DesignFrf] {
        &self.frfs
    }

    /// Judges `controller`: its continuous design, times the
    /// discretisation's error when the problem holds one
    /// ([`Self::discretized_as`]).
    pub fn evaluate(&self, controller: ControllerConfig) -> Evaluation {
        let c = controller.clone();
        if self.correction.is_empty() {
            return self.evaluate_with(controller, &|w| c.response(w));
        }
        let omega = &self.omega_rad_s;
        let r = &self.correction;
        self.evaluate_with(controller, &|w| {
            let i = omega.partition_point(|x| *x < w).min(omega.len() - 1);
            c.response(w) * r[i]
        })
    }

    /// The gain `ln g` that puts |L| = 1 at `omega_rad_s` on the first FRF
    /// for the shape `theta[1..]` of `family`.
    pub fn gain_for_crossover(&self, family: &Family, theta: &[f64], omega_rad_s: f64) -> f64 {
        let mut t = theta.to_vec();
        t[0] = 0.0;
        let c = family.controller(&t);
        let frf = self.frfs[0];
        let i = frf
            .omega_rad_s
            .partition_point(|w| *w < omega_rad_s)
            .min(frf.omega_rad_s.len() - 1);
        let l = c.response(frf.omega_rad_s[i]) * frf.plant_m_per_a[i] * self.unit_per_metre;
        -l.norm().ln()
    }
}

struct Cost<'p, 'a> {
    problem: &'p Problem<'a>,
    family: Family,
}

impl CostFunction for Cost<'_, '_> {
    type Param = Vec<f64>;
    type Output = f64;

    fn cost(&self, theta: &Self::Param) -> Result<f64, Error> {
        let c = self.problem.evaluate(self.family.controller(theta)).cost();
        Ok(if c.is_finite() { c } else { 1e9 })
    }
}

/// One Nelder–Mead run from `start` with an initial simplex of steps
/// `step` (in the log parameters).
fn nelder_mead(problem: &Problem<'_>, family: Family, start: &[f64], step: f64) -> Vec<f64> {
    let n = start.len();
    let mut simplex = vec![start.to_vec()];
    for i in 0..n {
        let mut v = start.to_vec();
        v[i] += step;
        simplex.push(v);
    }
    let solver = NelderMead::new(simplex)
        .with_sd_tolerance(1e-7)
        .expect("a positive tolerance");
    let run = Executor::new(Cost { problem, family }, solver)
        .configure(|s| s.max_iters(ITERATIONS))
        .run();
    match run {
        Ok(r) => r
            .state()
            .get_best_param()
            .cloned()
            .unwrap_or_else(|| start.to_vec()),
        Err(_) => start.to_vec(),
    }
}

/// One start refined: `start` run twice (a warm start after the active
/// set grew).
pub fn polish(problem: &Problem<'_>, family: Family, start: &[f64]) -> (Vec<f64>, Evaluation) {
    let a = nelder_mead(problem, family, start, 0.05);
    let b = nelder_mead(problem, family, &a, 0.02);
    let e = problem.evaluate(family.controller(&b));
    (b, e)
}

/// The best parameters of `family` on `problem` from `start` (with the
/// gain already scaled) and their evaluation: [`STARTS`] deterministic
/// starts, each run twice.
pub fn search(problem: &Problem<'_>, family: Family, start: &[f64]) -> (Vec<f64>, Evaluation) {
    search_all(problem, family, start)
        .into_iter()
        .next()
        .expect("STARTS > 0")
}

/// Every start's result, best (lowest cost) first.
pub fn search_all(
    problem: &Problem<'_>,
    family: Family,
    start: &[f64],
) -> Vec<(Vec<f64>, Evaluation)> {
    let n = start.len();
    let starts: Vec<Vec<f64>> = (0..STARTS)
        .map(|k| {
            let mut s = start.to_vec();
            if k > 0 {
                let mut z = (k as u64).wrapping_mul(0x5851_f42d_4c95_7f2d);
                for (i, x) in s.iter_mut().enumerate() {
                    z = z.wrapping_add(GAMMA);
                    let u = (splitmix64(z) >> 11) as f64 / (1u64 << 53) as f64;
                    // ±0.35 in the logarithm (±40 % in a ratio); the gain a
                    // little less.
                    let span = if i == 0 { 0.2 } else { 0.35 };
                    *x += span * (2.0 * u - 1.0);
                }
            }
            s
        })
        .collect();
    debug_assert!(n > 0);
    let mut all: Vec<(Vec<f64>, Evaluation)> = starts
        .par_iter()
        .map(|s| {
            let a = nelder_mead(problem, family, s, 0.15);
            let b = nelder_mead(problem, family, &a, 0.05);
            let e = problem.evaluate(family.controller(&b));
            (b, e)
        })
        .collect();
    all.sort_by(|a, b| a.1.cost().total_cmp(&b.1.cost()));
    all
}

/// `frf`'s plant at `w_rad_s`, linear in `ln ω` between its two nearest
/// points (the end point beyond its range).
fn interpolated(frf: &DesignFrf, w_rad_s: f64) -> C64 {
    let g = &frf.omega_rad_s;
    let p = &frf.plant_m_per_a;
    let i = g.partition_point(|x| *x < w_rad_s);
    if i == 0 {
        return p[0];
    }
    if i == g.len() {
        return p[g.len() - 1];
    }
    if g[i] == w_rad_s {
        return p[i];
    }
    let f = (w_rad_s / g[i - 1]).ln() / (g[i] / g[i - 1]).ln();
    p[i - 1] * (1.0 - f) + p[i] * f
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::predict::model_frf;
    use std::f64::consts::PI;

    /// On an FRF measured to f_s/4 the search sees what runs: for the
    /// shipped fast controller (Eq. 6-7, 0.79 dB / 4.7° off its design at
    /// f_s/4), the problem with its discretisation's error judges it as
    /// the certificate does (the discrete controller's own response),
    /// where the continuous design's loop gain at the band's last line is
    /// off by more than 0.3 dB; on the same FRF cut at f_s/10 the error
    /// is within the target and the design is judged as it is.
    #[test]
    fn the_search_judges_what_runs_where_the_discretisation_departs() {
        let p =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
        let cfg = crate::config::BenchConfig::load(&p).unwrap();
        let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
        let c = cfg.controller["fast"].clone();
        let req = Requirements {
            phase_margin_min_deg: 30.0,
            gain_margin_min_db: 6.0,
            sensitivity_peak_max: 2.0,
        };
        let model = model_frf(&cfg, period_s).unwrap();
        let cut = |top_hz: f64| {
            let keep: Vec<usize> = (0..model.omega_rad_s.len())
                .filter(|&k| model.omega_rad_s[k] >= 2.0 * PI * 1.0)
                .filter(|&k| model.omega_rad_s[k] <= 2.0 * PI * top_hz)
                .step_by(10)
                .collect();
            DesignFrf {
                label: "model".into(),
                lines_total: keep.len(),
                omega_rad_s: keep.iter().map(|&k| model.omega_rad_s[k]).collect(),
                plant_m_per_a: keep.iter().map(|&k| model.plant_m_per_a[k]).collect(),
            }
        };
        let wide = cut(0.25 / period_s);
        let problem = Problem::new(vec![&wide], req, 1e6);
        let runs = crate::design::certify(&problem, c.clone(), period_s, f64::INFINITY);
        let seen = problem.discretized_as(&c, period_s).evaluate(c.clone());
        let design = problem.evaluate(c.clone());
        let edge = |e: &Evaluation| e.figures[0].edge_gain_db;
        assert!(
            (edge(&seen) - edge(&runs)).abs() < 1e-9,
            "{} {}",
            edge(&seen),
            edge(&runs)
        );
        assert!(
            (seen.figures[0].margins.sensitivity_peak / runs.figures[0].margins.sensitivity_peak
                - 1.0)
                .abs()
                < 1e-12
        );
        assert!(
            (edge(&design) - edge(&runs)).abs() > 0.3,
            "the design's edge gain {} dB, what runs {} dB",
            edge(&design),
            edge(&runs)
        );
        // To f_s/10: within the target, the design as it is.
        let narrow = cut(0.1 / period_s);
        let problem = Problem::new(vec![&narrow], req, 1e6);
        assert!(problem.discretized_as(&c, period_s).correction.is_empty());
    }
}
