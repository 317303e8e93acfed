//! The periodic multisine excitation of `excitation.kind = "multisine"`
//! (README, *Configuration reference*: `[multisine]`), and the layout of
//! its record for the best linear approximation ([`crate::ident::bla`]).
//!
//! # Signal
//! One period of realization `m` is, at tick `n = 0 … N − 1` of a loop of
//! period `T_s` (period `T_p = N T_s`):
//! ```text
//! u_m[n] = Σ_l A_l cos(2π k_l n / N + φ_{m,l})            (A)
//! ```
//! on the DFT lines `k_l` (frequency `k_l / T_p`) of
//! [`MultisineConfig::excited_lines`]: every line from `⌈f_start T_p⌉` up
//! to where the lines grow sparser than `lines_per_decade`, a log-spaced
//! choice of them above, to `⌊f_end T_p⌋` (Pintelon & Schoukens, *System
//! Identification*, 2nd ed. 2012, ch. 5: a log-spaced multisine keeps the
//! power per line in a log band constant). The amplitudes follow
//! `chirp.amplitude_profile`, `A_l ∝ s(f_l)` (1 without a profile), and
//! are scaled together so that the largest `|u|` over every realization
//! is `chirp.amplitude_a`: the supervisor sees the same peak current as
//! for a sweep. The phases are
//! - `random`: independent, uniform on [0, 2π), a new draw for each
//!   realization, from SplitMix64 ([`crate::splitmix`]) seeded by the
//!   run's seed: the same seed gives the same signal;
//! - `schroeder`: with `p_l = A_l² / Σ A_j²` the line's share of the power,
//!   `φ_l = −2π Σ_{j<l} p_j (k_l − k_j)` (M. R. Schroeder, "Synthesis of
//!   low-peak-factor signals and binary sequences with low
//!   autocorrelation", *IEEE Trans. Inf. Theory* 16, 1970, with
//!   the line numbers `k_l` in place of consecutive harmonics): the phase
//!   of a sweep that spends a time proportional to `p_l` at each line, so
//!   the signal's envelope is nearly flat. On many flat consecutive lines
//!   its crest factor (peak / RMS) tends to a sweep's √2 times the Fresnel
//!   overshoot of the band's edges, 1.17: 1.66 (`tests/cli/multisine.rs`),
//!   against `√(2 ln 2F)` and more for random phases. On sparse
//!   (log-spaced) lines the gaps alias that sweep and the crest factor is
//!   no better than random; so the phases are then refined by the
//!   time–frequency swapping algorithm ([`lower_crest`], deterministic,
//!   starting from Schroeder's), which brings it to about 1.7. One
//!   deterministic signal: one realization.
//!
//! The table of `M × N` values is computed before the loop starts (one
//! inverse FFT of `N` points per realization, `rustfft`); the tick reads
//! one value: no allocation, no trigonometry.
//!
//! # Record
//! `lead-in | M × (T_tr transient periods + P measured periods) | tail`,
//! the lead-in and tail quiet (0 A, `chirp.lead_in_s`, `chirp.tail_s`).
//! Each realization starts with its transient periods, discarded while the
//! plant's response to the previous one decays.

use crate::config::{ChirpConfig, ExcitationKind, MultisineConfig, MultisinePhases};
use crate::ident::chirp::Chirp;
use crate::ident::C64;
use std::f64::consts::PI;

/// Why a multisine cannot be built (naming the config key).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {reason}")]
pub struct MultisineError {
    /// Dotted config key.
    pub key: &'static str,
    /// Why.
    pub reason: String,
}

/// A multisine record sampled at the loop rate, with its precomputed table.
#[derive(Clone)]
pub struct Multisine {
    lines: Vec<u64>,
    amplitudes_a: Vec<f64>,
    /// `realizations × lines`, rad.
    phases_rad: Vec<f64>,
    kind: MultisinePhases,
    period_ticks: usize,
    periods: usize,
    transient_periods: usize,
    realizations: usize,
    lead_in_ticks: u64,
    tail_ticks: u64,
    tick_s: f64,
    /// `realizations × period_ticks`, A.
    table: Box<[f64]>,
}

impl std::fmt::Debug for Multisine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Multisine")
            .field("lines", &self.lines.len())
            .field("phases", &self.kind)
            .field("period_ticks", &self.period_ticks)
            .field("periods", &self.periods)
            .field("transient_periods", &self.transient_periods)
            .field("realizations", &self.realizations)
            .field("lead_in_ticks", &self.lead_in_ticks)
            .field("tail_ticks", &self.tail_ticks)
            .finish_non_exhaustive()
    }
}

/// Domain constant mixed into the seed of the random phases, so they are
/// not the simulator's noise stream.
const PHASE_STREAM: u64 = 0x6d75_6c74_6973_696e; // "multisin"

impl Multisine {
    /// Builds the multisine of `chirp` (band, peak current, profile,
    /// lead-in, tail) and `ms` for a loop of period `tick_s` (s), random
    /// phases drawn from `seed`. Allocates the `M × N` table and runs `M`
    /// inverse FFTs of `N` points: call it before the loop.
    ///
    /// # Errors
    /// [`MultisineError`] naming the key when, at this tick period (a
    /// device's may differ from `loop.rate_hz`), the period does not reach
    /// down to `f_start_hz`, fewer than
    /// [`crate::config::ranges::MULTISINE_LINES_MIN`] lines are excited, or
    /// the record exceeds [`crate::config::ranges::JOB_TICKS_MAX`] ticks.
    pub fn new(
        chirp: &ChirpConfig,
        ms: &MultisineConfig,
        tick_s: f64,
        seed: u64,
    ) -> Result<Self, MultisineError> {
        let Shape {
            n,
            lines,
            lead_in_ticks,
            tail_ticks,
        } = Shape::of(chirp, ms, tick_s)?;
        let t_p = n as f64 * tick_s;
        let m = ms.realizations.max(1) as usize;
        // Relative amplitudes: the profile's scale at each line.
        let sweep = Chirp::new(chirp, ExcitationKind::Multisine, tick_s);
        let rel: Vec<f64> = lines
            .iter()
            .map(|&k| sweep.profile_scale(k as f64 / t_p))
            .collect();
        let phases_rad = match ms.phases {
            MultisinePhases::Random => random_phases(seed, m, lines.len()),
            MultisinePhases::Schroeder => {
                let one = lower_crest(
                    &lines,
                    &rel,
                    &schroeder_phases(&lines, &rel),
                    n,
                    crest_iterations(n),
                );
                one.iter().cycle().take(m * lines.len()).copied().collect()
            }
        };
        let mut table = vec![0.0; m * n].into_boxed_slice();
        let mut planner = rustfft::FftPlanner::<f64>::new();
        let fft = planner.plan_fft_inverse(n);
        let mut buf = vec![C64::new(0.0, 0.0); n];
        for r in 0..m {
            buf.fill(C64::new(0.0, 0.0));
            for (i, &k) in lines.iter().enumerate() {
                buf[k as usize] = C64::from_polar(rel[i], phases_rad[r * lines.len() + i]);
            }
            // Σ_k X[k] e^{+2πi k n / N}: its real part is Σ A cos(· + φ).
            fft.process(&mut buf);
            for (out, z) in table[r * n..(r + 1) * n].iter_mut().zip(&buf) {
                *out = z.re;
            }
        }
        let peak = table.iter().fold(0.0_f64, |a, x| a.max(x.abs()));
        let scale = chirp.amplitude_a / peak;
        for x in table.iter_mut() {
            *x *= scale;
        }
        Ok(Self {
            amplitudes_a: rel.iter().map(|r| r * scale).collect(),
            lines,
            phases_rad,
            kind: ms.phases,
            period_ticks: n,
            periods: ms.periods as usize,
            transient_periods: ms.transient_periods as usize,
            realizations: m,
            lead_in_ticks,
            tail_ticks,
            tick_s,
            table,
        })
    }

    /// The record length of [`Self::new`]'s multisine, ticks, without
    /// computing its table (the daemon's progress total).
    ///
    /// # Errors
    /// As [`Self::new`].
    pub fn total_ticks_of(
        chirp: &ChirpConfig,
        ms: &MultisineConfig,
        tick_s: f64,
    ) -> Result<u64, MultisineError> {
        Ok(Shape::of(chirp, ms, tick_s)?.total_ticks(ms))
    }

    /// Total record length, ticks (lead-in + every period + tail).
    pub fn total_ticks(&self) -> u64 {
        self.lead_in_ticks + self.body_ticks() + self.tail_ticks
    }

    fn body_ticks(&self) -> u64 {
        (self.realizations * (self.transient_periods + self.periods) * self.period_ticks) as u64
    }

    /// Ticks of quiet lead-in.
    pub fn lead_in_ticks(&self) -> u64 {
        self.lead_in_ticks
    }

    /// Excitation current at `tick`, A: 0 in the lead-in and the tail, a
    /// table lookup in between. Real-time safe (integer arithmetic and one
    /// read; no allocation, no trigonometry).
    #[inline]
    pub fn value_a(&self, tick: u64) -> f64 {
        let Some(k) = tick.checked_sub(self.lead_in_ticks) else {
            return 0.0;
        };
        if k >= self.body_ticks() {
            return 0.0;
        }
        let k = k as usize;
        let n = self.period_ticks;
        let realization = k / (n * (self.transient_periods + self.periods));
        self.table[realization * n + k % n]
    }

    /// The excited DFT line numbers `k_l`, ascending.
    pub fn lines(&self) -> &[u64] {
        &self.lines
    }

    /// The excited frequencies `k_l / T_p`, Hz.
    pub fn frequency_hz(&self) -> Vec<f64> {
        let t_p = self.period_s();
        self.lines.iter().map(|&k| k as f64 / t_p).collect()
    }

    /// Each line's amplitude `A_l`, A.
    pub fn amplitudes_a(&self) -> &[f64] {
        &self.amplitudes_a
    }

    /// The phases `φ_{m,l}` of realization `m`, rad.
    ///
    /// # Panics
    /// If `m` is not below [`Self::realizations`].
    pub fn phases_rad(&self, m: usize) -> &[f64] {
        let l = self.lines.len();
        &self.phases_rad[m * l..(m + 1) * l]
    }

    /// One period of realization `m`, A (`N` values).
    ///
    /// # Panics
    /// If `m` is not below [`Self::realizations`].
    pub fn period_a(&self, m: usize) -> &[f64] {
        &self.table[m * self.period_ticks..(m + 1) * self.period_ticks]
    }

    /// The phases' kind.
    pub fn phases(&self) -> MultisinePhases {
        self.kind
    }

    /// Period T_p, s.
    pub fn period_s(&self) -> f64 {
        self.period_ticks as f64 * self.tick_s
    }

    /// Realizations M.
    pub fn realizations(&self) -> usize {
        self.realizations
    }

    /// Crest factor of the played signal, peak / RMS over every
    /// realization: `amplitude_a / √(Σ A_l² / 2)` (the RMS of a sum of
    /// sines on distinct DFT lines, over whole periods).
    pub fn crest_factor(&self) -> f64 {
        let peak = self.table.iter().fold(0.0_f64, |a, x| a.max(x.abs()));
        let ms: f64 = self.amplitudes_a.iter().map(|a| 0.5 * a * a).sum();
        peak / ms.sqrt()
    }

    /// Where the record's periods are, for the estimator.
    pub fn layout(&self) -> Layout {
        Layout {
            lead_in_ticks: self.lead_in_ticks as usize,
            period_ticks: self.period_ticks,
            transient_periods: self.transient_periods,
            periods: self.periods,
            realizations: self.realizations,
            lines: self.lines.clone(),
            tick_s: self.tick_s,
        }
    }
}

/// The sizes of a multisine's record, checked.
struct Shape {
    /// Ticks per period.
    n: usize,
    lines: Vec<u64>,
    lead_in_ticks: u64,
    tail_ticks: u64,
}

impl Shape {
    fn of(chirp: &ChirpConfig, ms: &MultisineConfig, tick_s: f64) -> Result<Self, MultisineError> {
        use crate::config::ranges;
        let n = ms
            .period_ticks(chirp.f_start_hz, tick_s)
            .ok_or_else(|| MultisineError {
                key: "multisine.period_s",
                reason: format!("not a whole number of ticks of {tick_s} s up to a job's length"),
            })? as usize;
        let t_p = n as f64 * tick_s;
        if t_p * chirp.f_start_hz < 1.0 - 1e-9 {
            return Err(MultisineError {
                key: "multisine.period_s",
                reason: format!(
                    "{t_p} s ({n} ticks of {tick_s} s) is shorter than 1 / chirp.f_start_hz = {} s",
                    1.0 / chirp.f_start_hz
                ),
            });
        }
        let lines = ms.excited_lines(chirp.f_start_hz, chirp.f_end_hz, n as u64, tick_s);
        if lines.len() < ranges::MULTISINE_LINES_MIN {
            return Err(MultisineError {
                key: "multisine.lines_per_decade",
                reason: format!(
                    "{} lines in {} … {} Hz with a period of {t_p} s: at least {}",
                    lines.len(),
                    chirp.f_start_hz,
                    chirp.f_end_hz,
                    ranges::MULTISINE_LINES_MIN
                ),
            });
        }
        let per = u64::from(ms.transient_periods) + u64::from(ms.periods);
        let ticks = |s: f64| crate::config::ticks_in(s, tick_s).unwrap_or(u64::MAX);
        let (lead_in_ticks, tail_ticks) = (ticks(chirp.lead_in_s), ticks(chirp.tail_s));
        let body = u64::from(ms.realizations.max(1))
            .saturating_mul(per)
            .saturating_mul(n as u64);
        if lead_in_ticks
            .saturating_add(body)
            .saturating_add(tail_ticks)
            > ranges::JOB_TICKS_MAX
        {
            return Err(MultisineError {
                key: "multisine.periods",
                reason: format!(
                    "the record (lead-in, {} × {per} periods of {n} ticks, tail) is more than {} ticks",
                    ms.realizations,
                    ranges::JOB_TICKS_MAX
                ),
            });
        }
        Ok(Self {
            n,
            lines,
            lead_in_ticks,
            tail_ticks,
        })
    }

    fn total_ticks(&self, ms: &MultisineConfig) -> u64 {
        let per = u64::from(ms.transient_periods) + u64::from(ms.periods);
        self.lead_in_ticks
            + u64::from(ms.realizations.max(1)) * per * self.n as u64
            + self.tail_ticks
    }
}

/// Where a multisine record's periods lie: `lead_in_ticks`, then per
/// realization `transient_periods + periods` periods of `period_ticks`.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    /// Quiet ticks before the first period.
    pub lead_in_ticks: usize,
    /// Ticks per period, N.
    pub period_ticks: usize,
    /// Discarded periods at the start of each realization.
    pub transient_periods: usize,
    /// Measured periods per realization, P.
    pub periods: usize,
    /// Realizations, M.
    pub realizations: usize,
    /// Excited DFT lines `k_l` (frequency `k_l / (N T_s)`), ascending.
    pub lines: Vec<u64>,
    /// Loop period T_s, s.
    pub tick_s: f64,
}

impl Layout {
    /// First tick of measured period `p` of realization `m`.
    pub fn period_start(&self, m: usize, p: usize) -> usize {
        self.lead_in_ticks
            + (m * (self.transient_periods + self.periods) + self.transient_periods + p)
                * self.period_ticks
    }

    /// The ticks of realization `m`'s measured periods.
    pub fn measured(&self, m: usize) -> std::ops::Range<usize> {
        self.period_start(m, 0)..self.period_start(m, self.periods)
    }

    /// Ticks the record must have (up to the last measured period's end).
    pub fn needed_ticks(&self) -> usize {
        self.period_start(self.realizations.saturating_sub(1), self.periods)
    }

    /// Period T_p, s.
    pub fn period_s(&self) -> f64 {
        self.period_ticks as f64 * self.tick_s
    }
}

/// `m × lines` phases uniform on [0, 2π) from a SplitMix64 stream of `seed`
/// (53-bit uniforms).
fn random_phases(seed: u64, m: usize, lines: usize) -> Vec<f64> {
    use crate::splitmix::{splitmix64, GAMMA};
    let mut state = seed ^ PHASE_STREAM;
    (0..m * lines)
        .map(|_| {
            let x = splitmix64(state);
            state = state.wrapping_add(GAMMA);
            2.0 * PI * ((x >> 11) as f64 / (1u64 << 53) as f64)
        })
        .collect()
}

/// Schroeder's phases for lines `k` with relative amplitudes `a`:
/// `φ_l = −2π Σ_{j<l} p_j (k_l − k_j)`, `p_j = a_j² / Σ a²`, computed as
/// `−2π (k_l C_l − D_l)` with the running sums `C_l = Σ_{j<l} p_j`,
/// `D_l = Σ_{j<l} p_j k_j` (linear time), reduced to [0, 2π).
pub fn schroeder_phases(k: &[u64], a: &[f64]) -> Vec<f64> {
    let total: f64 = a.iter().map(|x| x * x).sum();
    let (mut c, mut d) = (0.0_f64, 0.0_f64);
    k.iter()
        .zip(a)
        .map(|(&kl, al)| {
            let phi = (-2.0 * PI * (kl as f64 * c - d)).rem_euclid(2.0 * PI);
            let p = al * al / total;
            c += p;
            d += p * kl as f64;
            phi
        })
        .collect()
}

/// Most iterations of [`lower_crest`].
pub const CREST_ITERATIONS_MAX: usize = 200;

/// The iterations [`lower_crest`] runs on a period of `n` ticks:
/// [`CREST_ITERATIONS_MAX`], fewer for long periods so that the two FFTs
/// per iteration stay within about `2·10⁸ · log₂` operations (a period of
/// 10 s at 5 kHz gets all 200; of 10 minutes, 3), at least 1.
pub fn crest_iterations(n: usize) -> usize {
    let work = n as f64 * (n as f64).log2().max(1.0);
    ((2e8 / work) as usize).clamp(1, CREST_ITERATIONS_MAX)
}

/// Lowers the crest factor of the multisine with lines `k`, relative
/// amplitudes `a` and starting phases `phi` on a period of `n` ticks by
/// the time–frequency swapping algorithm (E. Van der Ouderaa, J.
/// Schoukens, J. Renneboog, "Peak factor minimization using a
/// time-frequency domain swapping algorithm", *IEEE Trans. Instrum.
/// Meas.* 37, 1988; Pintelon & Schoukens 2012, ch. 5): synthesise one
/// period, clip it at 80 % of its peak, take the phases of the clipped
/// signal's DFT at the lines (the amplitudes stay `a`), `iterations`
/// times; the phases of the lowest peak seen (the start included) are
/// returned. Deterministic. Schroeder's phases are low-crest for dense
/// lines (≈ 1.66 for many flat consecutive lines) but not for a sparse,
/// log-spaced choice, whose gaps alias the sweep they describe (≈ 4 for
/// 300 lines per decade over 1–500 Hz with a 1 s period); 200 iterations
/// bring that to ≈ 1.7.
pub fn lower_crest(k: &[u64], a: &[f64], phi: &[f64], n: usize, iterations: usize) -> Vec<f64> {
    let mut planner = rustfft::FftPlanner::<f64>::new();
    let (inverse, forward) = (planner.plan_fft_inverse(n), planner.plan_fft_forward(n));
    let mut buf = vec![C64::new(0.0, 0.0); n];
    let mut phi = phi.to_vec();
    let mut best = phi.clone();
    let mut best_peak = f64::INFINITY;
    for it in 0..=iterations {
        buf.fill(C64::new(0.0, 0.0));
        for ((&kl, al), pl) in k.iter().zip(a).zip(&phi) {
            buf[kl as usize] = C64::from_polar(*al, *pl);
        }
        inverse.process(&mut buf);
        let peak = buf.iter().fold(0.0_f64, |m, z| m.max(z.re.abs()));
        if peak < best_peak {
            best_peak = peak;
            best.copy_from_slice(&phi);
        }
        if it == iterations {
            break;
        }
        let clip = 0.8 * peak;
        for z in buf.iter_mut() {
            *z = C64::new(z.re.clamp(-clip, clip), 0.0);
        }
        forward.process(&mut buf);
        for (pl, &kl) in phi.iter_mut().zip(k) {
            *pl = buf[kl as usize].arg().rem_euclid(2.0 * PI);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chirp() -> ChirpConfig {
        ChirpConfig {
            f_start_hz: 1.0,
            f_end_hz: 200.0,
            amplitude_a: 0.5,
            amplitude_profile: Vec::new(),
            duration_s: None,
            taper_s: None,
            lead_in_s: 0.1,
            tail_s: 0.2,
        }
    }

    fn ms(phases: MultisinePhases, realizations: u32) -> MultisineConfig {
        MultisineConfig {
            period_s: Some(1.0),
            periods: 2,
            realizations,
            transient_periods: 1,
            phases,
            lines_per_decade: 100,
        }
    }

    /// The lines, the layout and the values at known ticks, by hand.
    #[test]
    fn layout_and_lookup() {
        let s = Multisine::new(&chirp(), &ms(MultisinePhases::Random, 3), 1e-3, 7).unwrap();
        // lead-in 100 ticks, 3 × 3 periods of 1000, tail 200.
        assert_eq!(s.total_ticks(), 100 + 9_000 + 200);
        assert_eq!(s.value_a(99), 0.0);
        assert_eq!(s.value_a(9_100), 0.0);
        // Realization 1 starts at 100 + 3000; its second period repeats it.
        assert_eq!(s.value_a(3_100 + 17), s.period_a(1)[17]);
        assert_eq!(s.value_a(3_100 + 1_000 + 17), s.period_a(1)[17]);
        assert_eq!(s.value_a(100 + 8 * 1_000 + 999), s.period_a(2)[999]);
        let l = s.layout();
        assert_eq!(l.period_start(0, 0), 1_100);
        assert_eq!(l.period_start(2, 1), 100 + 8_000);
        assert_eq!(l.needed_ticks(), 9_100);
        // Lines 1 … 200 at 100 per decade: every line below
        // 1 / (10^(1/100) − 1) = 43, then about 100 per decade.
        let lines = s.lines();
        assert_eq!(lines[0], 1);
        assert_eq!(*lines.last().unwrap(), 200);
        assert!(lines[..43]
            .iter()
            .enumerate()
            .all(|(i, k)| *k == i as u64 + 1));
        let above = lines.iter().filter(|k| **k > 43).count() as f64;
        let expected = 100.0 * (200f64 / 43.0).log10();
        assert!((above - expected).abs() < 3.0, "{above} vs {expected}");
        // The peak is amplitude_a exactly.
        let peak = (0..s.total_ticks())
            .map(|k| s.value_a(k).abs())
            .fold(0.0, f64::max);
        assert!((peak - 0.5).abs() < 1e-12);
    }

    /// Each period is the sum of cosines it claims to be, evaluated
    /// directly at a few ticks.
    #[test]
    fn table_is_the_sum_of_cosines() {
        let s = Multisine::new(&chirp(), &ms(MultisinePhases::Random, 2), 1e-3, 3).unwrap();
        for m in 0..2 {
            for n in [0usize, 1, 333, 999] {
                let direct: f64 = s
                    .lines()
                    .iter()
                    .zip(s.amplitudes_a())
                    .zip(s.phases_rad(m))
                    .map(|((&k, a), phi)| a * (2.0 * PI * k as f64 * n as f64 / 1000.0 + phi).cos())
                    .sum();
                assert!((direct - s.period_a(m)[n]).abs() < 1e-12, "{m} {n}");
            }
        }
        // Realizations differ; the same seed repeats them.
        assert_ne!(s.period_a(0), s.period_a(1));
        let again = Multisine::new(&chirp(), &ms(MultisinePhases::Random, 2), 1e-3, 3).unwrap();
        assert_eq!(s.period_a(1), again.period_a(1));
    }

    /// Schroeder's phases by hand for three flat consecutive lines
    /// (`−π k(k−1)/F`, Schroeder 1970's flat-spectrum phases),
    /// and for two unequal lines.
    #[test]
    fn schroeder_phases_by_hand() {
        let phi = schroeder_phases(&[1, 2, 3], &[1.0, 1.0, 1.0]);
        // φ_1 = 0, φ_2 = −2π/3, φ_3 = −2π (2/3 + 1/3) = −2π.
        let want = [0.0, -2.0 * PI / 3.0, -2.0 * PI];
        for (p, w) in phi.iter().zip(want) {
            assert!((p - w.rem_euclid(2.0 * PI)).abs() < 1e-12, "{phi:?}");
        }
        // Two lines 1 and 5, powers 0.8 and 0.2: φ_5 = −2π · 0.8 · 4.
        let phi = schroeder_phases(&[1, 5], &[2.0, 1.0]);
        let w = (-2.0 * PI * 0.8 * 4.0).rem_euclid(2.0 * PI);
        assert!((phi[1] - w).abs() < 1e-12);
    }

    /// The amplitude profile shapes the line amplitudes (log-linear in
    /// f), as it shapes a sweep's envelope.
    #[test]
    fn profile_shapes_the_lines() {
        let mut c = chirp();
        c.amplitude_profile = vec![[10.0, 1.0], [100.0, 0.1]];
        let s = Multisine::new(&c, &ms(MultisinePhases::Schroeder, 1), 1e-3, 0).unwrap();
        let f = s.frequency_hz();
        let a = s.amplitudes_a();
        let a10 = a[f.iter().position(|x| (*x - 10.0).abs() < 1e-9).unwrap()];
        // 1 up to 10 Hz, 0.1 from 100 Hz, linear in ln f between.
        let scale = |hz: f64| {
            if hz <= 10.0 {
                1.0
            } else if hz >= 100.0 {
                0.1
            } else {
                1.0 - 0.9 * (hz / 10.0).ln() / 10f64.ln()
            }
        };
        for (hz, al) in f.iter().zip(a) {
            assert!((al / a10 - scale(*hz)).abs() < 1e-12, "{hz} Hz");
        }
    }

    #[test]
    fn refuses_a_period_short_of_the_band_start() {
        let mut m = ms(MultisinePhases::Random, 2);
        m.period_s = Some(0.5);
        let e = Multisine::new(&chirp(), &m, 1e-3, 0).unwrap_err();
        assert_eq!(e.key, "multisine.period_s");
    }
}
