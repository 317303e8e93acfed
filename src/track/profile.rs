//! Point-to-point moves: third- and fourth-order motion profiles planned
//! against limits on velocity, acceleration, jerk and (fourth order) snap,
//! after Lambrechts, Boerlage and Steinbuch, "Trajectory planning and
//! feedforward design for electromechanical motion systems", Control
//! Engineering Practice 13(2), 2005, §3.
//!
//! A symmetric fourth-order profile over a distance `d` is the step `d·H(t)`
//! smoothed by four unit-area boxes `b_w(t) = 1[0,w](t)/w` of widths
//! `w₁ ≤ w₂ ≤ w₃ ≤ w₄`: `x = d·H * b_{w₁} * b_{w₂} * b_{w₃} * b_{w₄}`.
//! With the widths nested (`w₃ ≥ w₁ + w₂`, `w₄ ≥ w₁ + w₂ + w₃`) the
//! derivatives' pulses do not overlap and their peaks are
//! `v̂ = d/w₄`, `â = d/(w₃w₄)`, `ĵ = d/(w₂w₃w₄)`, `ŝ = d/(w₁w₂w₃w₄)`.
//! In the paper's terms `w₁ = t_s` (constant snap), `w₂ = t_s + t_j`
//! (constant jerk), `w₃ = 2t_s + t_j + t_a` (constant acceleration) and
//! `w₄ = 4t_s + 2t_j + t_a + t_v` (constant velocity); the move lasts
//! `w₁ + w₂ + w₃ + w₄ = 8t_s + 4t_j + 2t_a + t_v`. A third-order profile
//! drops the snap box (`w₁ = 0`: the jerk steps).
//!
//! The planner takes the widths in the paper's order, each as long as the
//! limits allow with the later phases still empty (Lambrechts et al.,
//! §3.2): `t_s = min((d/8s)^¼, (v/2s)^⅓, (a/s)^½, j/s)`, then the jerk
//! phase, the acceleration phase and the velocity phase in turn. Every
//! limit holds; each is reached unless the distance or a lower limit ends
//! its phase first.

use serde::{Deserialize, Serialize};

/// The limits a move is planned against, SI units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct MoveLimits {
    /// Peak velocity, m/s.
    pub velocity_m_s: f64,
    /// Peak acceleration, m/s².
    pub acceleration_m_s2: f64,
    /// Peak jerk, m/s³.
    pub jerk_m_s3: f64,
    /// Peak snap, m/s⁴: a fourth-order profile; `None`: third order.
    pub snap_m_s4: Option<f64>,
}

/// A planned move: its distance and box widths (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct MoveProfile {
    /// The distance, m (either sign).
    pub distance_m: f64,
    /// `w₁ … w₄`, s (`w₁ = 0` for a third-order profile).
    pub widths_s: [f64; 4],
}

/// Largest `w` in `[lo, hi]` with `f(w) ≤ target`, `f` increasing, by
/// bisection to 1e-15 s.
fn largest_below(f: impl Fn(f64) -> f64, target: f64, mut lo: f64, mut hi: f64) -> f64 {
    if f(hi) <= target {
        return hi;
    }
    if f(lo) > target {
        return lo;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if f(mid) <= target {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-15 {
            break;
        }
    }
    lo
}

impl MoveLimits {
    /// Checks every limit is above 0 and at most
    /// [`crate::config::trajectory::move_limit_max`] of `stroke_m` at
    /// `rate_hz` (the limit that crosses the stroke within one tick);
    /// names the one that is not, with that bound.
    ///
    /// # Errors
    /// The limit's name, its value and its bound.
    pub fn validate(&self, stroke_m: f64, rate_hz: f64) -> Result<(), (&'static str, f64, f64)> {
        let all = [
            (1, "max_velocity_m_s", Some(self.velocity_m_s)),
            (2, "max_acceleration_m_s2", Some(self.acceleration_m_s2)),
            (3, "max_jerk_m_s3", Some(self.jerk_m_s3)),
            (4, "max_snap_m_s4", self.snap_m_s4),
        ];
        for (order, name, v) in all {
            if let Some(v) = v {
                let max = crate::config::trajectory::move_limit_max(order, stroke_m, rate_hz);
                if !(v > 0.0 && v <= max) {
                    return Err((name, v, max));
                }
            }
        }
        Ok(())
    }

    /// The limits as `bench track` flags, for a message.
    pub fn flags(&self) -> String {
        let snap = self
            .snap_m_s4
            .map_or(" --max-snap-m-s4 none".to_string(), |s| {
                format!(" --max-snap-m-s4 {s:.3e}")
            });
        format!(
            "--max-velocity-m-s {:.3e} --max-acceleration-m-s2 {:.3e} --max-jerk-m-s3 {:.3e}{snap}",
            self.velocity_m_s, self.acceleration_m_s2, self.jerk_m_s3
        )
    }

    /// The same profile `λ` times slower (`λ > 1`): every limit of order
    /// `n` divided by `λⁿ`.
    pub fn slower(&self, lambda: f64) -> Self {
        Self {
            velocity_m_s: self.velocity_m_s / lambda,
            acceleration_m_s2: self.acceleration_m_s2 / lambda.powi(2),
            jerk_m_s3: self.jerk_m_s3 / lambda.powi(3),
            snap_m_s4: self.snap_m_s4.map(|s| s / lambda.powi(4)),
        }
    }
}

impl MoveProfile {
    /// Plans a move over `distance_m` (≠ 0, finite) within `limits`
    /// (validated: [`MoveLimits::validate`]), module docs.
    pub fn plan(distance_m: f64, limits: &MoveLimits) -> Self {
        let d = distance_m.abs();
        let (v, a, j) = (
            limits.velocity_m_s,
            limits.acceleration_m_s2,
            limits.jerk_m_s3,
        );
        // Constant snap: the later phases empty (w₂ = w₁, w₃ = 2w₁,
        // w₄ = 4w₁): d = 8s·w₁⁴, v̂ = 2s·w₁³, â = s·w₁², ĵ = s·w₁.
        let w1 = match limits.snap_m_s4 {
            Some(s) => (d / (8.0 * s))
                .powf(0.25)
                .min((v / (2.0 * s)).cbrt())
                .min((a / s).sqrt())
                .min(j / s),
            None => 0.0,
        };
        // Constant jerk: w₃ = w₁ + w₂, w₄ = 2(w₁ + w₂); ĵ = d/(w₂w₃w₄)
        // at the jerk reached, â = ĵ·w₂, v̂ = ĵ·w₂·w₃, d = v̂·w₄.
        let j_reached = match limits.snap_m_s4 {
            Some(s) => s * w1,
            None => j,
        };
        let w2 = if limits.snap_m_s4.is_some() && j_reached < j * (1.0 - 1e-12) {
            // The snap phase already ended on a distance, velocity or
            // acceleration limit: no constant-jerk phase.
            w1
        } else {
            let hi = (a / j_reached)
                .min((-w1 + (w1 * w1 + 4.0 * v / j_reached).sqrt()) / 2.0)
                .max(w1);
            largest_below(|w2| 2.0 * j_reached * w2 * (w1 + w2).powi(2), d, w1, hi)
        };
        // Constant acceleration: w₄ = w₁ + w₂ + w₃; â = ĵ·w₂,
        // v̂ = â·w₃, d = v̂·w₄.
        let a_reached = j_reached * w2;
        let s12 = w1 + w2;
        let w3 = (v / a_reached)
            .min((-s12 + (s12 * s12 + 4.0 * d / a_reached).sqrt()) / 2.0)
            .max(s12);
        // Constant velocity: the rest of the distance.
        let v_reached = a_reached * w3;
        let w4 = (d / v_reached).max(s12 + w3);
        Self {
            distance_m,
            widths_s: [w1, w2, w3, w4],
        }
    }

    /// How long the move lasts, s: `w₁ + w₂ + w₃ + w₄`.
    pub fn duration_s(&self) -> f64 {
        self.widths_s.iter().sum()
    }

    /// Position, velocity, acceleration, jerk and snap at `t_s` (s from
    /// the move's start), SI units: `d·Δ_{w₁}…Δ_{w₄}[t₊^{m}/m!]/Πw` with
    /// `Δ_w f(t) = f(t) − f(t − w)` and `m` the order of the derivative's
    /// antiderivative (module docs). The third-order profile (`w₁ = 0`)
    /// has no snap (0 returned).
    pub fn at(&self, t_s: f64) -> [f64; 5] {
        let widths: Vec<f64> = self.widths_s.iter().copied().filter(|w| *w > 0.0).collect();
        let order = widths.len();
        let scale = self.distance_m / widths.iter().product::<f64>();
        let mut out = [0.0; 5];
        // Each of the 2^order shifted ramps t₊^p/p! with sign (−1)^{bits}.
        for mask in 0..(1usize << order) {
            let mut shift = 0.0;
            let mut sign = 1.0;
            for (i, w) in widths.iter().enumerate() {
                if mask & (1 << i) != 0 {
                    shift += w;
                    sign = -sign;
                }
            }
            let tau = t_s - shift;
            if tau <= 0.0 {
                continue;
            }
            // Derivative m of x is Δ…Δ[t₊^{order−m}/(order−m)!].
            for (m, o) in out.iter_mut().enumerate() {
                if m > order {
                    break;
                }
                let p = order - m;
                let ramp = tau.powi(p as i32) / factorial(p);
                *o += sign * ramp;
            }
        }
        for o in &mut out {
            *o *= scale;
        }
        if t_s >= self.duration_s() {
            out = [self.distance_m, 0.0, 0.0, 0.0, 0.0];
        }
        out
    }

    /// The peaks `|v̂|, |â|, |ĵ|, |ŝ|` of the plan (module docs), SI
    /// units; `ŝ` is infinite for a third-order profile.
    pub fn peaks(&self) -> [f64; 4] {
        let d = self.distance_m.abs();
        let [w1, w2, w3, w4] = self.widths_s;
        [
            d / w4,
            d / (w3 * w4),
            d / (w2 * w3 * w4),
            d / (w1 * w2 * w3 * w4),
        ]
    }
}

fn factorial(p: usize) -> f64 {
    (1..=p).map(|i| i as f64).product()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits(snap: Option<f64>) -> MoveLimits {
        MoveLimits {
            velocity_m_s: 1e-3,
            acceleration_m_s2: 0.5,
            jerk_m_s3: 500.0,
            snap_m_s4: snap,
        }
    }

    /// Every limit reached: the widths are the ratios of the limits
    /// (`w₁ = j/s`, `w₂ = a/j`, `w₃ = v/a`, `w₄ = d/v`, module docs) and
    /// the move's end is the distance, still.
    #[test]
    fn a_long_move_reaches_every_limit_and_lasts_the_sum_of_their_ratios() {
        let l = limits(Some(1e6));
        let p = MoveProfile::plan(1e-4, &l);
        let want = [500.0 / 1e6, 0.5 / 500.0, 1e-3 / 0.5, 1e-4 / 1e-3];
        for (w, e) in p.widths_s.iter().zip(want) {
            assert!((w - e).abs() < 1e-12, "{:?} against {want:?}", p.widths_s);
        }
        let end = p.at(p.duration_s() - 1e-12);
        assert!(
            (end[0] - 1e-4).abs() < 1e-12 && end[1].abs() < 1e-9,
            "{end:?}"
        );
    }

    /// The profile's derivatives against its position by finite
    /// differences, its peaks against the limits, on a grid of moves
    /// short and long, third and fourth order.
    #[test]
    fn the_profile_stays_within_its_limits_and_its_derivatives_match() {
        for snap in [Some(1e6), Some(1e4), None] {
            for d in [1e-8, 1e-6, 1e-5, 1e-4, -3e-5] {
                let l = limits(snap);
                let p = MoveProfile::plan(d, &l);
                let t_end = p.duration_s();
                let dt = t_end / 4000.0;
                let mut peak = [0.0f64; 4];
                for i in 0..4000 {
                    let t = (i as f64 + 0.5) * dt;
                    let x = p.at(t);
                    for m in 0..4 {
                        peak[m] = peak[m].max(x[m + 1].abs());
                    }
                    // Central differences of the position and velocity.
                    let h = t_end * 1e-6;
                    let (a, b) = (p.at(t - h), p.at(t + h));
                    let v_fd = (b[0] - a[0]) / (2.0 * h);
                    assert!(
                        (v_fd - x[1]).abs() <= 1e-4 * x[1].abs().max(d.abs() / t_end),
                        "{d} {snap:?} t {t}: {v_fd} against {x:?}, {p:?}"
                    );
                }
                let lim = [l.velocity_m_s, l.acceleration_m_s2, l.jerk_m_s3];
                for m in 0..3 {
                    assert!(peak[m] <= lim[m] * (1.0 + 1e-6), "{d} {snap:?}: {peak:?}");
                }
                if let Some(s) = snap {
                    assert!(peak[3] <= s * (1.0 + 1e-6), "{d}: {peak:?}");
                }
                let end = p.at(t_end);
                assert_eq!(end[0], d);
                assert!((p.at(t_end * (1.0 - 1e-9))[0] - d).abs() < 1e-9 * d.abs());
            }
        }
    }

    /// A short move reaches no limit but the snap: `d = 8s·w₁⁴`, so it
    /// lasts `8·(d/8s)^¼` (Lambrechts et al., §3.2).
    #[test]
    fn a_short_move_is_all_snap() {
        let l = limits(Some(1e6));
        let d = 1e-9;
        let p = MoveProfile::plan(d, &l);
        let t = 8.0 * (d / 8e6).powf(0.25);
        assert!((p.duration_s() - t).abs() < 1e-9 * t, "{}", p.duration_s());
    }
}
