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
//!   reach about 1.3 A, below the 2.34 A continuous rating. Thermal drift
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
