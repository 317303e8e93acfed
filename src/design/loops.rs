//! The open loops a design is judged on: the controller times each measured
//! FRF (and the computation delay), and their figures: every gain
//! crossover with its phase margin, the gain margin, the modulus margin
//! `‖S‖∞`, the sensitivity bandwidth ω_B and the Nyquist count.
//!
//! Shapes: an FRF's lines are ascending in ω (rad/s); every vector of one
//! [`DesignFrf`] has one entry per line. Units: the plant in m/A, the
//! controller in A per error unit, `unit_per_metre` the error unit per
//! metre (10⁶ for µm), so that `L = C · P · unit_per_metre` is
//! dimensionless.
//!
//! # The Nyquist count
//! Closed-loop poles in the right half plane, from the Nyquist criterion
//! on the lines (e.g. Skogestad & Postlethwaite §4.9; Åström & Murray
//! §10.2).
//!
//! For a stable plant and a controller whose only poles on the imaginary
//! axis are `n` integrators, the closed loop has as many poles in the
//! right half plane as the contour's image encircles −1: twice the turn
//! of `arg(1 + L(jω))` from ω → 0⁺ to ω → ∞ (the negative frequencies
//! mirror it), less the `n·π` that the small indentation around s = 0
//! sweeps, over 2π. The turn runs from the first line (which must lie
//! where the integrators dominate: `1 + L ≈ L` there) to the last (where
//! `1 + L → 1`), following the phase line to line by the shortest turn.
//! A stable loop turns by `n·π/2`, from `−n·π/2` to 0; a loop with a
//! pair of unstable poles turns a whole turn less (two encirclements);
//! a loop whose gain has the wrong sign at s → 0 starts from `π − n·π/2`
//! and cannot end at an even count (one real closed-loop pole in the
//! right half plane: `1 + L(s)` is large and negative just right of
//! s = 0 and tends to 1 as s → +∞). A step of more than 0.9π between two
//! lines cannot be followed reliably and counts as two.

use crate::control::loop_check::{MarginScan, Margins};
use crate::ident::C64;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// One input FRF as the design uses it: its coherent lines only, with the
/// computation delay applied.
#[derive(Debug, Clone)]
pub struct DesignFrf {
    /// The input's name in reports (a path, or a campaign cell).
    pub label: String,
    /// Lines used, rad/s, ascending.
    pub omega_rad_s: Vec<f64>,
    /// `P(e^{jωT}) · e^{−jωτ}` at each line, m/A: the measured plant
    /// (current demand to position, hold and amplifier included) times
    /// the computation delay τ the design adds.
    pub plant_m_per_a: Vec<C64>,
    /// Lines the input had before the coherence threshold.
    pub lines_total: usize,
}

impl DesignFrf {
    /// The same lines without the computation delay `tau_s` the design
    /// added (`P·e^{+jωτ}`), labelled so: every input and model is judged
    /// with τ and with none (a command may reach the amplifier at once or
    /// one period later).
    pub fn undelayed(&self, tau_s: f64) -> Self {
        Self {
            label: format!("{} (no computation delay)", self.label),
            omega_rad_s: self.omega_rad_s.clone(),
            plant_m_per_a: self
                .plant_m_per_a
                .iter()
                .zip(&self.omega_rad_s)
                .map(|(p, w)| p * C64::from_polar(1.0, w * tau_s))
                .collect(),
            lines_total: self.lines_total,
        }
    }

    /// The same FRF on fewer lines for the search: every line within
    /// ±`band` (a fraction) of a frequency in `near_rad_s` (the resonances,
    /// where the response turns within a few lines), every `every`-th line
    /// elsewhere, and the first and last lines.
    pub fn decimated(&self, near_rad_s: &[f64], band: f64, every: usize) -> Self {
        let n = self.omega_rad_s.len();
        let keep: Vec<usize> = (0..n)
            .filter(|&k| {
                let w = self.omega_rad_s[k];
                k == 0
                    || k + 1 == n
                    || k % every.max(1) == 0
                    || near_rad_s.iter().any(|r| (w / r - 1.0).abs() <= band)
            })
            .collect();
        Self {
            label: self.label.clone(),
            omega_rad_s: keep.iter().map(|&k| self.omega_rad_s[k]).collect(),
            plant_m_per_a: keep.iter().map(|&k| self.plant_m_per_a[k]).collect(),
            lines_total: self.lines_total,
        }
    }
}

/// Figures of one open loop on one FRF (or the model): the loop check's
/// [`Margins`] (every gain crossover with its phase margin, the gain
/// margin, ‖S‖∞; on the lines, crossings interpolated) and what a design
/// needs besides.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct LoopFigures {
    /// Crossovers, phase margins (180° + ∠L, wrapped to (−180°, 180°]),
    /// gain margin, ‖S‖∞ and where.
    #[serde(flatten)]
    pub margins: Margins,
    /// The smallest angle between L and −1 at a crossover, degrees: the
    /// least |phase margin| (a crossing at ∠L = +80° is 100° from −1
    /// whichever way L turns; `None`: no crossover).
    pub phase_margin_min_deg: Option<f64>,
    /// Sensitivity bandwidth ω_B: the lowest frequency at which |S| reaches
    /// 1/√2 (−3 dB) from below, rad/s (`None`: not within the lines).
    pub sensitivity_bandwidth_rad_s: Option<f64>,
    /// Closed-loop poles in the right half plane by the Nyquist count over
    /// the lines (0: the closed loop is stable, for a stable plant; see
    /// the module docs, *The Nyquist count*).
    pub rhp_closed_loop_poles: u32,
    /// |L| at the highest line, dB: how much loop gain is left where the
    /// measurement ends.
    pub edge_gain_db: f64,
}

/// The figures of the loop `l` (one value per line of `omega_rad_s`,
/// ascending) of a controller with `integrators` poles at s = 0, in one
/// pass over the lines. The margins are the loop check's own
/// ([`MarginScan`], crossings placed by linear interpolation in log ω, as
/// [`crate::control::loop_check::measured_margins`] places them); the test
/// `figures_agree_with_the_loop_check` compares the two.
pub fn figures(omega_rad_s: &[f64], l: &[C64], integrators: u32) -> LoopFigures {
    let n = l.len();
    let mut scan = MarginScan::default();
    let mut wb: Option<f64> = None;
    let s_target = 0.5f64.sqrt();
    // Nyquist: the turn of the phase of 1 + L from the first line, line
    // by line (see the module's doc).
    let mut turn = 0.0;
    let mut ambiguous = false;
    for k in 0..n {
        let lk = l[k];
        scan.push(omega_rad_s[k], lk, None);
        let one = lk + 1.0;
        let s = 1.0 / one.norm();
        if k == 0 {
            continue;
        }
        let (w0, w1) = (omega_rad_s[k - 1].ln(), omega_rad_s[k].ln());
        let l0 = l[k - 1];
        if wb.is_none() && s >= s_target {
            let s0 = 1.0 / (l0 + 1.0).norm();
            let (a, b, t) = (s0.ln(), s.ln(), s_target.ln());
            let f = if b > a {
                ((t - a) / (b - a)).clamp(0.0, 1.0)
            } else {
                1.0
            };
            wb = Some((w0 + f * (w1 - w0)).exp());
        }
        let d = (one / (l0 + 1.0)).arg();
        ambiguous |= d.abs() > 0.9 * PI;
        turn += d;
    }
    // Encirclements of −1 over the whole contour: the turn over ω > 0
    // twice (the negative frequencies mirror it), less the n·π the
    // integrators' indentation around s = 0 sweeps.
    let encirclements = ((2.0 * turn - integrators as f64 * PI) / (2.0 * PI)).round();
    let margins = scan.finish();
    LoopFigures {
        phase_margin_min_deg: margins
            .phase_margins_deg
            .iter()
            .map(|p: &f64| p.abs())
            .reduce(f64::min),
        margins,
        sensitivity_bandwidth_rad_s: if n > 0 && 1.0 / (l[0] + 1.0).norm() >= s_target {
            None
        } else {
            wb
        },
        rhp_closed_loop_poles: (encirclements.abs() as u32).max(2 * u32::from(ambiguous)),
        edge_gain_db: 20.0 * l.last().map_or(0.0, |v| v.norm()).log10(),
    }
}

/// `L = C · P · unit_per_metre` on the lines of `frf`, with `c` the
/// controller's response at each of them.
pub fn open_loop(frf: &DesignFrf, c: &[C64], unit_per_metre: f64) -> Vec<C64> {
    frf.plant_m_per_a
        .iter()
        .zip(c)
        .map(|(p, c)| c * p * unit_per_metre)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> Vec<f64> {
        (0..=4000)
            .map(|i| 0.01 * 10f64.powf(i as f64 / 1000.0))
            .collect()
    }

    /// L(s) = k/(s(s+1)): stable for every k > 0 (the textbook second-order
    /// loop), its |S| reaches −3 dB where |1 + L|² = 2, solved in closed
    /// form below; and L = k/(s(s+1)(s/10+1)) is unstable above k = 11
    /// (Routh: s³/10 + 1.1 s² + s + k, stable iff 1.1 > k/10).
    #[test]
    fn textbook_loops() {
        let w = grid();
        let l1 = |k: f64| -> Vec<C64> {
            w.iter()
                .map(|&w| {
                    let s = C64::new(0.0, w);
                    C64::new(k, 0.0) / (s * (s + 1.0))
                })
                .collect()
        };
        let f = figures(&w, &l1(1.0), 1);
        assert_eq!(f.rhp_closed_loop_poles, 0);
        // |S(jω)| = 1/√2 found by bisection on the exact expression.
        let s_mag = |w: f64| {
            let s = C64::new(0.0, w);
            1.0 / (C64::new(1.0, 0.0) / (s * (s + 1.0)) + 1.0).norm()
        };
        let (mut a, mut b): (f64, f64) = (0.01, 10.0);
        for _ in 0..100 {
            let m: f64 = (a * b).sqrt();
            if s_mag(m) < 0.5f64.sqrt() {
                a = m;
            } else {
                b = m;
            }
        }
        let wb = f.sensitivity_bandwidth_rad_s.unwrap();
        assert!((wb / a - 1.0).abs() < 2e-3, "{wb} against {a}");
        let l3 = |k: f64| -> Vec<C64> {
            w.iter()
                .map(|&w| {
                    let s = C64::new(0.0, w);
                    C64::new(k, 0.0) / (s * (s + 1.0) * (s / 10.0 + 1.0))
                })
                .collect()
        };
        assert_eq!(figures(&w, &l3(10.0), 1).rhp_closed_loop_poles, 0);
        assert_eq!(figures(&w, &l3(12.0), 1).rhp_closed_loop_poles, 2);
        assert_eq!(figures(&w, &l3(100.0), 1).rhp_closed_loop_poles, 2);
        // A negative gain: s² + s − 1 has the root (√5 − 1)/2 > 0, one
        // real closed-loop pole in the right half plane, however large
        // the phase margin its crossing shows.
        assert_eq!(figures(&w, &l1(-1.0), 1).rhp_closed_loop_poles, 1);
        // s³/10 + 1.1 s² + s − 0.5: one sign change, one root in the RHP.
        assert_eq!(figures(&w, &l3(-0.5), 1).rhp_closed_loop_poles, 1);
        // No integrator: L = k/(s + 1), closed-loop pole at s = −1 − k:
        // stable for k = −0.5, unstable for k = −2.
        let l0 = |k: f64| -> Vec<C64> {
            w.iter()
                .map(|&w| C64::new(k, 0.0) / (C64::new(1.0, w)))
                .collect()
        };
        assert_eq!(figures(&w, &l0(-0.5), 0).rhp_closed_loop_poles, 0);
        assert_eq!(figures(&w, &l0(-2.0), 0).rhp_closed_loop_poles, 1);
        assert_eq!(figures(&w, &l0(3.0), 0).rhp_closed_loop_poles, 0);
    }

    /// The one-pass figures are the loop check's on measured data: the
    /// Eq. (6-7)-like loop with a lightly damped pair, three crossings.
    #[test]
    fn figures_agree_with_the_loop_check() {
        let w = grid();
        let l: Vec<C64> = w
            .iter()
            .map(|&w| {
                let s = C64::new(0.0, w);
                let pair = (s * s + s * 0.02 + 4.0) / (s * s + s * 0.01 * 2.2 + 4.84);
                C64::new(3.0, 0.0) / (s * (s + 1.0)) * pair * C64::from_polar(1.0, -0.05 * w)
            })
            .collect();
        let f = figures(&w, &l, 1);
        let lookup = |x: f64| l[w.partition_point(|g| *g < x).min(w.len() - 1)];
        let m = crate::control::loop_check::margins(&lookup, &w, false);
        assert_eq!(f.margins, m);
    }
}
