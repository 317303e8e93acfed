//! Is the probe alive? Two rules of the supervisor that judge a reading
//! that is finite, in range and flagged good by its device, but dead
//! (README, *Safety: a dead probe*):
//!
//! - **Frozen** ([`FaultKind::ProbeFrozen`]): the reading is bit-identical
//!   over more fresh samples (sequence advancing) than the probe's noise
//!   makes plausible. A live probe of white noise σ (`probe.noise_rms_m`)
//!   read through codes of width q (`probe.quantization_m` plus the link's
//!   count, [`bench_hal::DeviceInfo::probe_lsb_m`]) lands on any one code
//!   with probability at most `p = q / (σ √(2π))` (the Gaussian's peak
//!   density times the code's width; the stage's own motion only spreads
//!   the readings further). N readings in a row on the code of the first
//!   has probability at most `p^N`, so N = ⌈ln ε / ln p⌉ with
//!   ε = [`FROZEN_FALSE_ALARM`] per sample: a day at 20 kHz has 1.7e9
//!   samples, so a healthy probe trips it once in 600 000 years. The
//!   shipped bench (σ 40 nm, q 30 nm): p = 0.30, N = 29 samples (5.8 ms at
//!   5 kHz); over EtherCAT (the ADC's 30.5 nm count added): p = 0.60,
//!   N = 69 (13.8 ms). Without noise (σ = 0) or with codes coarser than
//!   the noise (p ≥ 1) a still stage reads one code for ever and the rule
//!   cannot decide: it is off, and the plausibility rule remains.
//! - **Implausible** ([`FaultKind::ProbeImplausible`]): the current moved
//!   the stage (by the plant's quasi-static compliance) and the probe did
//!   not see it. Both the command in force and the reading pass the same
//!   2nd-order Butterworth low-pass at `f₁ / 20` (`f₁` the plant's lowest
//!   mode: the resonance, amplified 1/(2ζ) ≈ 55× on the shipped bench, is
//!   attenuated 400×, so what passes is the quasi-static response
//!   `x ≈ G(0) i`). From the moment a job drives the stage, the predicted
//!   quasi-static motion is `Δx̂ = G(0) (ī − ī₀)` and the seen one
//!   `Δȳ = ȳ − ȳ₀`. The rule trips when `|Δx̂|` reaches the motion of
//!   [`IMPLAUSIBLE_CURRENT_FRACTION`] of the coil's continuous rating and the
//!   probe saw less than [`IMPLAUSIBLE_SEEN_FRACTION`] of it in the
//!   predicted direction: a healthy stage would have to be 5× stiffer
//!   than its model. The shipped bench's G(0) is 154 µm/A, so the rule
//!   decides at 90 µm predicted (0.585 A filtered), 2 250 σ of the probe's
//!   noise; the filter's group delay (√2 / (2π f_c) = 0.20 s at f_c = 1.13 Hz) lets a
//!   controller winding up at 4.5 A/s (a dead probe under the fast loop)
//!   reach about 1.5 A (1.49 A measured, a blind probe under the fast step),
//!   below the 2.34 A continuous rating. Thermal drift
//!   the loop holds against counts as predicted motion the probe does not
//!   see; a flexure drifts nanometres to micrometres, not 90 µm.
//!
//! Both rules run while a job drives the stage (`running`) only, and reset
//! whenever it stops driving it. Per tick: one comparison of bits, two
//! biquads and a few comparisons (`cargo bench --bench control --
//! probe_validity`).

use crate::vocab::FaultKind;
use std::f64::consts::PI;

/// False-alarm probability per sample of the frozen rule.
pub const FROZEN_FALSE_ALARM: f64 = 1e-15;

/// The plausibility rule decides once the predicted quasi-static motion
/// is that of this fraction of the coil's continuous current rating.
pub const IMPLAUSIBLE_CURRENT_FRACTION: f64 = 0.25;

/// ... and trips when the probe saw less than this fraction of it.
pub const IMPLAUSIBLE_SEEN_FRACTION: f64 = 0.2;

/// The quasi-static filter's corner as a fraction of the plant's lowest
/// mode.
pub const QUASI_STATIC_CORNER: f64 = 1.0 / 20.0;

/// The probe-validity rules' settings, derived before the job from the
/// probe, the link and the plant ([`ProbeValidity::derive`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbeValidity {
    /// Bit-identical fresh readings in a row that trip `probe_frozen`
    /// (`u64::MAX`: the rule is off).
    pub frozen_samples: u64,
    /// The plausibility rule, if the plant's compliance is known.
    pub plausibility: Option<Plausibility>,
}

/// The plausibility rule's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plausibility {
    /// The plant's quasi-static compliance G(0), from the current to x1,
    /// m/A.
    pub dc_gain_m_per_a: f64,
    /// Predicted quasi-static motion at which the rule decides, m.
    pub decide_m: f64,
    /// The low-pass's corner, Hz.
    pub corner_hz: f64,
    /// The low-pass (shared by the command and the reading).
    pub filter: LowPass,
}

/// A 2nd-order Butterworth low-pass (bilinear, pre-warped), direct form I
/// coefficients, unit gain at DC.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LowPass {
    b: [f64; 3],
    a: [f64; 2],
}

impl LowPass {
    /// Corner `corner_hz` at a sample period `period_s` (RBJ cookbook,
    /// Q = 1/√2). The corner is held below 0.45 of Nyquist.
    pub fn butterworth(corner_hz: f64, period_s: f64) -> Self {
        let w0 = 2.0 * PI * (corner_hz * period_s).min(0.45 * 0.5);
        let alpha = w0.sin() * std::f64::consts::FRAC_1_SQRT_2;
        let c = w0.cos();
        let a0 = 1.0 + alpha;
        let b = (1.0 - c) / 2.0 / a0;
        Self {
            b: [b, 2.0 * b, b],
            a: [-2.0 * c / a0, (1.0 - alpha) / a0],
        }
    }
}

/// One filter's state (the last two inputs and outputs).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct FilterState {
    x: [f64; 2],
    y: [f64; 2],
}

impl FilterState {
    /// At rest on `v` (its steady state for a constant input `v`).
    fn at(v: f64) -> Self {
        Self {
            x: [v, v],
            y: [v, v],
        }
    }

    #[inline]
    fn step(&mut self, f: &LowPass, v: f64) -> f64 {
        let y = f.b[0] * v + f.b[1] * self.x[0] + f.b[2] * self.x[1]
            - f.a[0] * self.y[0]
            - f.a[1] * self.y[1];
        self.x = [v, self.x[0]];
        self.y = [y, self.y[0]];
        y
    }
}

impl ProbeValidity {
    /// Both rules off.
    pub const OFF: Self = Self {
        frozen_samples: u64::MAX,
        plausibility: None,
    };

    /// The settings for a probe of noise `noise_rms_m` read through codes of
    /// `code_m` (the acquisition's quantisation plus the link's count, m),
    /// on a plant of quasi-static compliance `dc_gain_m_per_a` (m/A) whose
    /// lowest mode is at `lowest_mode_hz`, a coil of continuous rating
    /// `continuous_current_a`, at a loop period `period_s`. A compliance or
    /// mode that is not finite and positive leaves the plausibility rule
    /// off; see the [module docs](self) for the numbers.
    pub fn derive(
        noise_rms_m: f64,
        code_m: f64,
        dc_gain_m_per_a: f64,
        lowest_mode_hz: f64,
        continuous_current_a: f64,
        period_s: f64,
    ) -> Self {
        let plausibility = (dc_gain_m_per_a.is_finite()
            && dc_gain_m_per_a != 0.0
            && lowest_mode_hz.is_finite()
            && lowest_mode_hz > 0.0
            && continuous_current_a.is_finite()
            && continuous_current_a > 0.0)
            .then(|| {
                let corner_hz = lowest_mode_hz * QUASI_STATIC_CORNER;
                Plausibility {
                    dc_gain_m_per_a,
                    decide_m: dc_gain_m_per_a.abs()
                        * IMPLAUSIBLE_CURRENT_FRACTION
                        * continuous_current_a,
                    corner_hz,
                    filter: LowPass::butterworth(corner_hz, period_s),
                }
            });
        Self {
            frozen_samples: frozen_samples(noise_rms_m, code_m),
            plausibility,
        }
    }
}

/// Bit-identical readings in a row that a live probe of noise `noise_rms_m`
/// read through codes of `code_m` produces with probability below
/// [`FROZEN_FALSE_ALARM`]: `⌈ln ε / ln p⌉`, `p = code / (σ √(2π))`, at
/// least 2; `u64::MAX` (off) when `p` is not below 1 (no noise, or codes
/// coarser than it).
pub fn frozen_samples(noise_rms_m: f64, code_m: f64) -> u64 {
    if !(noise_rms_m.is_finite() && noise_rms_m > 0.0 && code_m.is_finite() && code_m >= 0.0) {
        return u64::MAX;
    }
    let p = code_m / (noise_rms_m * (2.0 * PI).sqrt());
    if p >= 1.0 {
        return u64::MAX;
    }
    if p <= 0.0 {
        return 2;
    }
    ((FROZEN_FALSE_ALARM.ln() / p.ln()).ceil() as u64).max(2)
}

/// The rules' running state (real-time safe, no allocation).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(super) struct ProbeWatch {
    /// The last fresh reading's bits and how many fresh readings in a row
    /// had them.
    last_bits: Option<u64>,
    same: u64,
    /// The filters' states, and the filtered command and reading when the
    /// job took the stage (the reference).
    started: bool,
    command: FilterState,
    reading: FilterState,
    ref_command_a: f64,
    ref_reading_m: f64,
    /// The last predicted and seen quasi-static motions, m.
    pub(super) predicted_m: f64,
    pub(super) seen_m: f64,
}

impl ProbeWatch {
    /// Forget everything (the job stopped driving the stage).
    pub(super) fn reset(&mut self) {
        *self = Self::default();
    }

    /// One fresh, finite reading `x_m`, taken at the end of a period that
    /// ran on `command_a`, while a job drives the stage. Returns the fault
    /// and its value (the frozen count, or the predicted motion, m).
    #[inline]
    pub(super) fn check(
        &mut self,
        cfg: &ProbeValidity,
        x_m: f64,
        command_a: f64,
    ) -> Option<(FaultKind, f64)> {
        let bits = x_m.to_bits();
        if self.last_bits == Some(bits) {
            self.same += 1;
        } else {
            self.last_bits = Some(bits);
            self.same = 1;
        }
        let frozen = self.same >= cfg.frozen_samples;
        let mut implausible = None;
        if let Some(p) = cfg.plausibility.as_ref() {
            if !self.started {
                self.started = true;
                self.command = FilterState::at(command_a);
                self.reading = FilterState::at(x_m);
                self.ref_command_a = command_a;
                self.ref_reading_m = x_m;
            }
            let i = self.command.step(&p.filter, command_a);
            let y = self.reading.step(&p.filter, x_m);
            let predicted = p.dc_gain_m_per_a * (i - self.ref_command_a);
            let seen = (y - self.ref_reading_m) * predicted.signum();
            self.predicted_m = predicted;
            self.seen_m = seen;
            if predicted.abs() >= p.decide_m && seen < IMPLAUSIBLE_SEEN_FRACTION * predicted.abs() {
                implausible = Some((FaultKind::ProbeImplausible, predicted));
            }
        }
        if frozen {
            return Some((FaultKind::ProbeFrozen, self.same as f64));
        }
        implausible
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::splitmix::{splitmix64, GAMMA};

    /// A standard normal draw (Box–Muller) from a splitmix64 stream.
    fn normal(state: &mut u64) -> f64 {
        let mut u = || {
            *state = state.wrapping_add(GAMMA);
            ((splitmix64(*state) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (u1, u2) = (u(), u());
        (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
    }

    #[test]
    fn frozen_count_is_the_documented_one_and_off_without_noise() {
        // The shipped bench: σ 40 nm, q 30 nm: p = 0.2992, ⌈ln 1e-15 / ln p⌉.
        let p: f64 = 30e-9 / (40e-9 * (2.0 * PI).sqrt());
        assert!((p - 0.2992).abs() < 1e-4);
        assert_eq!(frozen_samples(40e-9, 30e-9), 29);
        assert!(p.powi(29) < 1e-15 && p.powi(28) > 1e-15);
        // Over the analog terminal: the ADC's count (1 mm / 32767) added.
        assert_eq!(frozen_samples(40e-9, 30e-9 + 1e-3 / 32767.0), 69);
        // No noise, codes coarser than the noise, nonsense: off.
        for (s, q) in [
            (0.0, 30e-9),
            (10e-9, 30e-9),
            (f64::NAN, 1e-9),
            (1e-9, f64::INFINITY),
        ] {
            assert_eq!(frozen_samples(s, q), u64::MAX, "σ {s}, q {q}");
        }
        // An unquantised reading: two identical readings are implausible.
        assert_eq!(frozen_samples(40e-9, 0.0), 2);
    }

    /// The bound the frozen rule rests on: a quantised Gaussian reading
    /// lands on the code of the previous one with probability at most
    /// `p = q / (σ √(2π))`, wherever the stage sits within a code and
    /// however it moves (here: still, the worst case). 200 000 pairs per
    /// offset: the estimate's 1σ is about 0.001.
    #[test]
    fn same_code_in_a_row_is_below_the_bound_monte_carlo() {
        let mut st = 7u64;
        for (sigma, q) in [(40e-9, 30e-9), (40e-9, 60.5e-9), (10e-9, 20e-9)] {
            let p = q / (sigma * (2.0 * PI).sqrt());
            for offset in [0.0, 0.25, 0.5] {
                let code = |st: &mut u64| ((offset * q + sigma * normal(st)) / q).round() as i64;
                let n = 200_000;
                let mut prev = code(&mut st);
                let mut same = 0;
                for _ in 0..n {
                    let c = code(&mut st);
                    same += usize::from(c == prev);
                    prev = c;
                }
                let f = same as f64 / n as f64;
                assert!(
                    f <= p + 0.005,
                    "σ {sigma}, q {q}, offset {offset}: {f} > {p}"
                );
                // And the bound is not loose by orders: at least half.
                assert!(f >= 0.5 * p, "σ {sigma}, q {q}, offset {offset}: {f} ≪ {p}");
            }
        }
    }

    /// The quasi-static low-pass against the analog 2nd-order Butterworth
    /// magnitude 1/√(1 + (f/f_c)⁴): exact at the corner (pre-warped), and
    /// within 1 % of it (and of the thesis bench's 400× attenuation at the
    /// lowest mode) where f ≪ the sampling rate.
    #[test]
    fn low_pass_is_a_butterworth_at_the_corner() {
        let (fc, ts) = (22.6 / 20.0, 2e-4);
        let lp = LowPass::butterworth(fc, ts);
        let h = |f: f64| {
            let w = 2.0 * PI * f * ts;
            let z1 = crate::ident::frf::C64::from_polar(1.0, -w);
            let z2 = z1 * z1;
            let num = lp.b[0] + lp.b[1] * z1 + lp.b[2] * z2;
            let den = 1.0 + lp.a[0] * z1 + lp.a[1] * z2;
            (num / den).norm()
        };
        // Unit DC gain to the rounding of coefficients of order 1e-6.
        assert!((h(0.0) - 1.0).abs() < 1e-8, "{}", h(0.0));
        for f in [0.01, 0.3, fc, 3.0, 22.6, 100.0] {
            let analog = 1.0 / (1.0 + (f / fc).powi(4)).sqrt();
            assert!(
                (h(f) / analog - 1.0).abs() < 0.01,
                "{f} Hz: {} vs {analog}",
                h(f)
            );
        }
        assert!((1.0 / h(22.6) - 400.0).abs() < 5.0, "{}", 1.0 / h(22.6));
        // The state steps as the coefficients say: a constant passes.
        let mut st = FilterState::at(0.0);
        let y = (0..200_000).map(|_| st.step(&lp, 1.0)).last().unwrap();
        assert!((y - 1.0).abs() < 1e-9);
    }

    /// The shipped bench's settings, with a plant whose stage follows the
    /// quasi-static model `x = G(0) i` exactly through a ramp to twice the
    /// continuous rating (no trip), one 10× stiffer than its model (trips
    /// once the predicted motion reaches a quarter of the rating's), and a
    /// dead probe (trips at the same point), the current negative too.
    #[test]
    fn plausibility_trips_on_motion_not_seen_and_never_on_the_model() {
        let (g0, cont, ts) = (154.4e-6, 2.34, 2e-4);
        let cfg = ProbeValidity::derive(0.0, 30e-9, g0, 22.6, cont, ts);
        assert_eq!(cfg.frozen_samples, u64::MAX);
        let p = cfg.plausibility.unwrap();
        assert!((p.decide_m - g0 * 0.25 * cont).abs() < 1e-12);
        assert!((p.corner_hz - 1.13).abs() < 1e-12);
        for sign in [1.0, -1.0] {
            for (what, seen_fraction) in [("model", 1.0), ("stiff", 0.1), ("dead", 0.0)] {
                let mut w = ProbeWatch::default();
                let mut tripped = None;
                // 4.5 A/s for 1.04 s: to 4.68 A, twice the rating.
                for k in 0..5200 {
                    let i = sign * 4.5 * k as f64 * ts;
                    // What the probe reads: the quasi-static motion of
                    // the period's current, scaled.
                    let x = seen_fraction * g0 * i;
                    if let Some((kind, v)) = w.check(&cfg, x, i) {
                        assert_eq!(kind, FaultKind::ProbeImplausible);
                        tripped = Some((k, v, i));
                        break;
                    }
                }
                match (what, tripped) {
                    ("model", None) => {}
                    ("model", Some(t)) => panic!("{sign} model: tripped {t:?}"),
                    (_, None) => panic!("{sign} {what}: never tripped"),
                    (_, Some((k, v, i))) => {
                        assert!(v.abs() >= p.decide_m && v.signum() == sign, "{what}: {v}");
                        // Before the rating: the filter's lag (0.2 s at
                        // 4.5 A/s, 0.9 A) on top of the 0.585 A decided.
                        assert!(i.abs() < cont, "{sign} {what}: {i} A at tick {k}");
                        assert!(i.abs() > 0.25 * cont, "{sign} {what}: {i} A");
                    }
                }
            }
        }
    }

    #[test]
    fn frozen_counts_fresh_identical_readings_and_resets_on_change() {
        let cfg = ProbeValidity {
            frozen_samples: 5,
            plausibility: None,
        };
        let mut w = ProbeWatch::default();
        for _ in 0..4 {
            assert_eq!(w.check(&cfg, 1e-6, 0.1), None);
        }
        // One different reading starts the count again.
        assert_eq!(w.check(&cfg, 1.03e-6, 0.1), None);
        for _ in 0..3 {
            assert_eq!(w.check(&cfg, 1.03e-6, 0.1), None);
        }
        assert_eq!(
            w.check(&cfg, 1.03e-6, 0.1),
            Some((FaultKind::ProbeFrozen, 5.0))
        );
        // 0.0 and -0.0 differ in bits: a sign flip is a change.
        w.reset();
        for k in 0..10 {
            let x = if k % 2 == 0 { 0.0 } else { -0.0 };
            assert_eq!(w.check(&cfg, x, 0.0), None);
        }
    }
}
