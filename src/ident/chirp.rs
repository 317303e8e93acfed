//! Chirp excitation for identification (thesis §5.2.2; README, *Configuration reference*: `[chirp]`):
//! the sweep [`crate::ident::excitation::Excitation`] plays, and whose
//! amplitude profile a multisine's lines follow.
//!
//! The record is `lead-in | sweep | tail`, all at the loop rate:
//!
//! ```text
//! u(t) = A · s(f(t)) · w(t) · sin θ(t)                     0 ≤ t < T (sweep time)
//! exponential:  f(t) = f0 · r^(t/T),  r = f1/f0,
//!               θ(t) = 2π f0 T / ln r · (r^(t/T) − 1)
//! linear:       f(t) = f0 + (f1 − f0) t / T,
//!               θ(t) = 2π (f0 t + (f1 − f0) t² / (2T))
//! w(t) = raised-cosine fade over `taper_s` at each end, 1 in between
//! s(f) = amplitude profile: piecewise linear in log f through the
//!        configured breakpoints, held beyond them (1 when none)
//! ```
//!
//! The lead-in (zero current) lets the probe offset be estimated; the tail
//! (zero current) lets the lightly damped modes ring down inside the record,
//! so the full-record DFT ratio is free of leakage. Values are computed in
//! closed form from the tick index: no tables, no allocation on the tick.

use crate::config::{ChirpConfig, ExcitationKind, MAX_PROFILE_POINTS};
use std::f64::consts::PI;

/// A chirp sampled at the loop rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Chirp {
    kind: ExcitationKind,
    f_start_hz: f64,
    f_end_hz: f64,
    amplitude_a: f64,
    taper_s: f64,
    /// Amplitude profile breakpoints `(ln f, scale)`; `profile_len` used.
    profile: [(f64, f64); MAX_PROFILE_POINTS],
    profile_len: usize,
    period_s: f64,
    lead_in_ticks: u64,
    sweep_ticks: u64,
    tail_ticks: u64,
    /// Sweep time T, s (`sweep_ticks × period_s`).
    sweep_s: f64,
    /// `ln(f_end / f_start)`.
    ln_ratio: f64,
    /// `ln(f_start)`.
    ln_f_start: f64,
}

impl Chirp {
    /// Builds the chirp of `cfg` swept by the law of `excitation` for a
    /// loop of period `period_s` (s). The config is assumed validated
    /// ([`crate::config::BenchConfig::validate`]): a sweep's `duration_s`
    /// and `taper_s` are present (absent: a one-tick sweep without
    /// taper). A multisine config's sweep (the injection of `bench
    /// control --verify`, which sets its own duration) is exponential
    /// ([`ExcitationKind::sweep_law`]).
    pub fn new(cfg: &ChirpConfig, excitation: ExcitationKind, period_s: f64) -> Self {
        // Checked: a duration beyond the tick range saturates (the job
        // refuses more than `ranges::JOB_TICKS_MAX` ticks), never wraps.
        let ticks = |s: f64| crate::config::ticks_in(s, period_s).unwrap_or(u64::MAX);
        let sweep_ticks = ticks(cfg.duration_s.unwrap_or(0.0)).max(1);
        let mut profile = [(0.0, 1.0); MAX_PROFILE_POINTS];
        let profile_len = cfg.amplitude_profile.len().min(MAX_PROFILE_POINTS);
        for (slot, [f, scale]) in profile.iter_mut().zip(&cfg.amplitude_profile) {
            *slot = (f.ln(), *scale);
        }
        Self {
            kind: excitation.sweep_law(),
            f_start_hz: cfg.f_start_hz,
            f_end_hz: cfg.f_end_hz,
            amplitude_a: cfg.amplitude_a,
            taper_s: cfg.taper_s.unwrap_or(0.0),
            profile,
            profile_len,
            period_s,
            lead_in_ticks: ticks(cfg.lead_in_s),
            sweep_ticks,
            tail_ticks: ticks(cfg.tail_s),
            sweep_s: sweep_ticks as f64 * period_s,
            ln_ratio: (cfg.f_end_hz / cfg.f_start_hz).ln(),
            ln_f_start: cfg.f_start_hz.ln(),
        }
    }

    /// Total record length, ticks (lead-in + sweep + tail).
    pub fn total_ticks(&self) -> u64 {
        self.lead_in_ticks
            .saturating_add(self.sweep_ticks)
            .saturating_add(self.tail_ticks)
    }

    /// Ticks of quiet lead-in before the sweep.
    pub fn lead_in_ticks(&self) -> u64 {
        self.lead_in_ticks
    }

    /// The sweep's length T, s.
    pub fn sweep_s(&self) -> f64 {
        self.sweep_s
    }

    /// The sweep rate df/dt at sweep time `t`, Hz/s: `f(t) ln(f1/f0) / T`
    /// (exponential) or `(f1 − f0) / T` (linear).
    pub fn sweep_rate_hz_per_s(&self, t: f64) -> f64 {
        match self.kind {
            ExcitationKind::Linear => (self.f_end_hz - self.f_start_hz) / self.sweep_s,
            _ => self.frequency_hz(t) * self.ln_ratio / self.sweep_s,
        }
    }

    /// Instantaneous frequency at sweep time `t` (s from the sweep start), Hz.
    pub fn frequency_hz(&self, t: f64) -> f64 {
        let big_t = self.sweep_s;
        let (f0, f1) = (self.f_start_hz, self.f_end_hz);
        match self.kind {
            ExcitationKind::Linear => f0 + (f1 - f0) * t / big_t,
            _ => f0 * (f1 / f0).powf(t / big_t),
        }
    }

    /// Amplitude scale at frequency `f` (Hz) from the profile.
    pub fn profile_scale(&self, frequency_hz: f64) -> f64 {
        self.profile_scale_ln(frequency_hz.ln())
    }

    /// [`Chirp::profile_scale`] at `x = ln f` (f in Hz).
    fn profile_scale_ln(&self, x: f64) -> f64 {
        let p = &self.profile[..self.profile_len];
        let (Some(first), Some(last)) = (p.first(), p.last()) else {
            return 1.0;
        };
        if x <= first.0 {
            return first.1;
        }
        if x >= last.0 {
            return last.1;
        }
        let i = p.partition_point(|q| q.0 <= x);
        let (a, b) = (p[i - 1], p[i]);
        a.1 + (b.1 - a.1) * (x - a.0) / (b.0 - a.0)
    }

    /// Excitation current at `tick`, A. Real-time safe (closed form).
    #[inline]
    pub fn value_a(&self, tick: u64) -> f64 {
        if tick < self.lead_in_ticks || tick >= self.lead_in_ticks + self.sweep_ticks {
            return 0.0;
        }
        let t = (tick - self.lead_in_ticks) as f64 * self.period_s;
        let big_t = self.sweep_s;
        let (f0, f1) = (self.f_start_hz, self.f_end_hz);
        let theta = match self.kind {
            ExcitationKind::Linear => 2.0 * PI * (f0 * t + (f1 - f0) * t * t / (2.0 * big_t)),
            _ => {
                let ln_r = self.ln_ratio;
                2.0 * PI * f0 * big_t / ln_r * ((t / big_t * ln_r).exp() - 1.0)
            }
        };
        // ln f(t) in closed form for the exponential sweep,
        // ln f0 + (t/T)·ln(f1/f0): no pow and no ln on the tick.
        let scale = match (self.profile_len, self.kind) {
            (0, _) => 1.0,
            (_, ExcitationKind::Linear) => self.profile_scale(self.frequency_hz(t)),
            _ => self.profile_scale_ln(self.ln_f_start + t / big_t * self.ln_ratio),
        };
        self.amplitude_a * scale * self.window(t, big_t) * theta.sin()
    }

    fn window(&self, t: f64, big_t: f64) -> f64 {
        let tp = self.taper_s;
        if tp <= 0.0 {
            return 1.0;
        }
        let edge = t.min(big_t - t);
        if edge >= tp {
            1.0
        } else {
            0.5 * (1.0 - (PI * edge.max(0.0) / tp).cos())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> ChirpConfig {
        ChirpConfig {
            f_start_hz: 1.0,
            f_end_hz: 100.0,
            amplitude_a: 0.5,
            duration_s: Some(10.0),
            taper_s: Some(0.5),
            lead_in_s: 0.2,
            tail_s: 1.0,
            amplitude_profile: Vec::new(),
        }
    }

    /// Instantaneous frequency from zero crossings matches the sweep law.
    #[test]
    fn zero_crossings_follow_the_sweep_law() {
        for kind in [ExcitationKind::Exponential, ExcitationKind::Linear] {
            let fs = 20_000.0;
            let c = Chirp::new(&cfg(), kind, 1.0 / fs);
            let lead = c.lead_in_ticks();
            let x: Vec<f64> = (0..c.total_ticks()).map(|k| c.value_a(k)).collect();
            // Upward zero crossings between 2 s and 8 s of sweep time.
            let mut crossings = Vec::new();
            for k in (lead + 40_000) as usize..(lead + 160_000) as usize {
                if x[k - 1] < 0.0 && x[k] >= 0.0 {
                    let frac = -x[k - 1] / (x[k] - x[k - 1]);
                    crossings.push(((k - 1 - lead as usize) as f64 + frac) / fs);
                }
            }
            for w in crossings.windows(2) {
                let t_mid = 0.5 * (w[0] + w[1]);
                let f_meas = 1.0 / (w[1] - w[0]);
                // Analytic law, independent of the implementation.
                let f_true = match kind {
                    ExcitationKind::Linear => 1.0 + 99.0 * t_mid / 10.0,
                    _ => 100f64.powf(t_mid / 10.0),
                };
                assert!(
                    (f_meas / f_true - 1.0).abs() < 0.01,
                    "{kind:?} t={t_mid}: {f_meas} vs {f_true}"
                );
            }
        }
    }

    #[test]
    fn quiet_outside_the_sweep_and_bounded_inside() {
        let c = Chirp::new(&cfg(), ExcitationKind::Exponential, 1e-4);
        assert_eq!(c.total_ticks(), 2_000 + 100_000 + 10_000);
        assert_eq!(c.value_a(0), 0.0);
        assert_eq!(c.value_a(1_999), 0.0);
        assert_eq!(c.value_a(102_000), 0.0);
        let peak = (0..c.total_ticks())
            .map(|k| c.value_a(k).abs())
            .fold(0.0, f64::max);
        assert!(peak <= 0.5 + 1e-12 && peak > 0.49);
        // Taper: small at the very start and end of the sweep.
        assert!(c.value_a(2_001).abs() < 1e-3);
        assert!(c.value_a(101_999).abs() < 0.01);
    }

    #[test]
    fn amplitude_profile_is_log_linear_and_held() {
        let mut p = cfg();
        p.amplitude_profile = vec![[10.0, 1.0], [20.0, 0.1], [40.0, 0.1], [80.0, 1.0]];
        let c = Chirp::new(&p, ExcitationKind::Exponential, 1e-4);
        assert_eq!(c.profile_scale(1.0), 1.0);
        assert_eq!(c.profile_scale(10.0), 1.0);
        assert!((c.profile_scale(200f64.sqrt()) - 0.55).abs() < 1e-12);
        assert!((c.profile_scale(30.0) - 0.1).abs() < 1e-12);
        assert_eq!(c.profile_scale(1000.0), 1.0);
        // Envelope near 30 Hz (sweep time t: 100^(t/10) = 30) is 0.05 A.
        let t30 = 10.0 * 30f64.ln() / 100f64.ln();
        let k = 2_000 + (t30 * 1e4) as u64;
        let env = (k - 300..k + 300)
            .map(|i| c.value_a(i).abs())
            .fold(0.0, f64::max);
        assert!((env - 0.05).abs() < 1e-3, "{env}");
        // On the slope (√200 Hz, halfway between 1 and 0.1 in ln f) the
        // envelope is 0.5 × 0.55 A, within the slope's change over ±30 ms.
        let t = 10.0 * 200f64.sqrt().ln() / 100f64.ln();
        let k = 2_000 + (t * 1e4) as u64;
        let env = (k - 300..k + 300)
            .map(|i| c.value_a(i).abs())
            .fold(0.0, f64::max);
        assert!((env - 0.275).abs() < 0.01, "{env}");
    }
}
