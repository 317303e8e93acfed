//! The best linear approximation (BLA) of the plant from a multisine
//! record ([`crate::ident::multisine`]), with its noise and its stochastic
//! nonlinear distortion told apart: the robust method of Pintelon &
//! Schoukens, *System Identification: A Frequency Domain Approach*, 2nd
//! ed., Wiley–IEEE 2012, §3.7 and ch. 4 (and Schoukens, Pintelon &
//! Rolain, "Identification of linear systems with nonlinear distortions",
//! *Automatica* 41, 2005).
//!
//! # Method
//! For realization `m = 1 … M`, measured period `p = 1 … P` (the
//! transient periods skipped), the `N`-point DFT of that period's input
//! `u` (A) and output `y` (m) at each excited line `k` gives
//! `G^[m,p](k) = Y^[m,p](k) / U^[m,p](k)` (m/A). Then, per line:
//! ```text
//! Ĝ^[m]    = (1/P) Σ_p G^[m,p]
//! σ̂²_n[m]  = 1/(P(P−1)) Σ_p |G^[m,p] − Ĝ^[m]|²                 noise variance of Ĝ^[m]
//! Ĝ_BLA    = (1/M) Σ_m Ĝ^[m]
//! σ̂²_BLA   = 1/(M(M−1)) Σ_m |Ĝ^[m] − Ĝ_BLA|²                  total variance of Ĝ_BLA
//! σ̂²_n     = (1/M²) Σ_m σ̂²_n[m]                               its noise part
//! σ̂²_S     = M (σ̂²_BLA − σ̂²_n), clipped at 0                  the distortion's variance
//! ```
//! `σ̂_S` is the standard deviation of the stochastic nonlinear
//! distortion `G_S` of one realization (it is periodic, the same in every
//! period of a realization, and new with each phase draw); on `Ĝ_BLA` it
//! adds `σ̂²_S / M`, so `σ̂²_BLA = σ̂²_n + σ̂²_S / M`. The noise is the
//! output noise (probe, disturbance force); the input is the generated
//! excitation, known exactly.
//!
//! `σ̂_BLA` is the 1σ of the complex estimate, `√E|Ĝ_BLA − G_BLA|²`: what a
//! fit should weight with. With one realization (Schroeder phases) it is
//! `σ̂_n` alone and the distortion is not assessed: it stays in `Ĝ` as a
//! bias that no σ covers.
//!
//! # Test for nonlinear distortion
//! Without distortion (`σ²_S = 0`) and with circular complex Gaussian
//! noise, `F = σ̂²_BLA / σ̂²_n` follows Fisher's `F(2(M−1), 2M(P−1))` (the
//! numerator is the spread of `M` means, the denominator the pooled
//! spread of `M(P−1)` deviations, independent of it; P&S 2012 ch. 4). A
//! line's p-value is `P(F ≥ f)`; it is distorted at level
//! [`LINE_LEVEL`] (5 %) when below it. With `L` independent lines (distinct DFT lines are, asymptotically)
//! the count `K` of such lines is binomial `B(L, 0.05)` when there is no
//! distortion; nonlinear distortion is *detected* when
//! `P(B(L, 0.05) ≥ K) <` [`DETECTION_LEVEL`] (0.1 %).
//!
//! Coherence is given in its signal-to-noise form,
//! `γ² = |Ĝ_BLA|² / (|Ĝ_BLA|² + σ̂²_BLA)`: `γ² ≥ 0.5` exactly when the
//! estimate's σ is at most its magnitude.

use crate::ident::frf::{unwrap_deg, Frf};
use crate::ident::multisine::Layout;
use crate::ident::C64;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::Path;

/// Level of the per-line F test: 5 %.
pub const LINE_LEVEL: f64 = 0.05;
/// Level of the test over all lines (the binomial count): 0.1 %.
pub const DETECTION_LEVEL: f64 = 1e-3;

/// Why a BLA cannot be estimated (naming the config key or the input).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BlaError {
    /// Fewer than two measured periods.
    #[error("multisine.periods: {periods} measured period(s) per realization: the noise variance needs at least 2")]
    TooFewPeriods {
        /// Periods per realization.
        periods: usize,
    },
    /// No realization to estimate from.
    #[error("multisine.realizations: {reason}")]
    NoRealization {
        /// Why (e.g. every realization left out for stalls).
        reason: String,
    },
    /// The record ends before the last measured period.
    #[error("record: {ticks} ticks, but the multisine's measured periods end at tick {needed} (the run stopped early?)")]
    ShortRecord {
        /// Ticks in the record.
        ticks: usize,
        /// Ticks needed.
        needed: usize,
    },
    /// A value of the record is NaN or infinite.
    #[error("record: {what} at tick {tick} is {value}, not a finite number")]
    NotFinite {
        /// `excitation_a` or `position_m`.
        what: &'static str,
        /// Tick.
        tick: usize,
        /// The value.
        value: f64,
    },
    /// The layout has no line below Nyquist, or a period under 2 ticks.
    #[error("multisine: {0}")]
    Layout(String),
    /// An excited line carries no input.
    #[error("record: no excitation at {frequency_hz} Hz (realization {realization}, period {period}): is the record a multisine's?")]
    NoInput {
        /// The line, Hz.
        frequency_hz: f64,
        /// Realization (0-based).
        realization: usize,
        /// Period (0-based).
        period: usize,
    },
}

/// The BLA on the excited lines, with its standard deviations.
#[derive(Debug, Clone, PartialEq)]
pub struct Bla {
    /// Excited lines, Hz (ascending).
    pub frequency_hz: Vec<f64>,
    /// `Ĝ_BLA`, m/A.
    pub response: Vec<C64>,
    /// `σ̂_BLA`, the 1σ of the complex `Ĝ_BLA` (noise and distortion),
    /// m/A; `σ̂_n` with one realization.
    pub sigma_bla_m_per_a: Vec<f64>,
    /// `σ̂_n`, the noise part of `σ̂_BLA`, m/A.
    pub sigma_noise_m_per_a: Vec<f64>,
    /// `σ̂_S`, the 1σ of one realization's stochastic nonlinear
    /// distortion, m/A (clipped at 0; NaN with one realization).
    pub sigma_nonlinear_m_per_a: Vec<f64>,
    /// The per-line p-value of `F = σ̂²_BLA / σ̂²_n` under no distortion
    /// (NaN with one realization).
    pub distortion_p_value: Vec<f64>,
    /// Realizations used, M.
    pub realizations: usize,
    /// Periods per realization, P.
    pub periods: usize,
    /// Line spacing `1 / T_p`, Hz: each line is one DFT bin of a period.
    pub resolution_hz: f64,
}

/// The test for nonlinear distortion over all lines (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct DistortionTest {
    /// Lines tested.
    pub lines: usize,
    /// Lines whose distortion is significant at [`LINE_LEVEL`] (5 %).
    pub lines_distorted: usize,
    /// Lines expected by chance at that level without distortion,
    /// `0.05 L`.
    pub expected_by_chance: f64,
    /// `P(B(L, 0.05) ≥ lines_distorted)`: the chance of that many or more
    /// without distortion.
    pub p_value: f64,
    /// `p_value` below [`DETECTION_LEVEL`] (0.1 %).
    pub detected: bool,
}

impl DistortionTest {
    /// One line for the summary.
    pub fn line(&self) -> String {
        format!(
            "nonlinear distortion: {} ({} of {} lines above the noise at 5 %, {:.1} expected by chance; binomial p = {:.2e}, detected below {:.0e})",
            if self.detected {
                "detected"
            } else {
                "not detected (insignificant against the noise)"
            },
            self.lines_distorted,
            self.lines,
            self.expected_by_chance,
            self.p_value,
            DETECTION_LEVEL
        )
    }
}

impl Bla {
    /// Estimates the BLA from a packed record `u[n] + i·y[n]` (A, m; one
    /// value a tick) laid out as `layout` says, using the realizations
    /// whose `use_realization` entry is true (all when it is empty).
    ///
    /// # Errors
    /// [`BlaError`]: fewer than 2 periods, no realization, a record shorter
    /// than the layout, a non-finite value in a measured period, an
    /// excited line without input.
    pub fn estimate(
        record: &[C64],
        layout: &Layout,
        use_realization: &[bool],
    ) -> Result<Self, BlaError> {
        let n = layout.period_ticks;
        let p_count = layout.periods;
        if p_count < 2 {
            return Err(BlaError::TooFewPeriods { periods: p_count });
        }
        if n < 2 || layout.lines.iter().any(|&k| k == 0 || 2 * k as usize >= n) {
            return Err(BlaError::Layout(format!(
                "lines must lie strictly between 0 and N/2 of a period of {n} ticks"
            )));
        }
        let used: Vec<usize> = (0..layout.realizations)
            .filter(|&m| use_realization.get(m).copied().unwrap_or(true))
            .collect();
        if used.is_empty() {
            return Err(BlaError::NoRealization {
                reason: format!("none of {} left to estimate from", layout.realizations),
            });
        }
        let needed = layout.period_start(*used.last().expect("one"), p_count);
        if record.len() < needed {
            return Err(BlaError::ShortRecord {
                ticks: record.len(),
                needed,
            });
        }
        let lines = &layout.lines;
        let l_count = lines.len();
        let mut planner = rustfft::FftPlanner::<f64>::new();
        let fft = planner.plan_fft_forward(n);
        let mut buf = vec![C64::new(0.0, 0.0); n];
        // Ĝ^[m] and σ̂²_n[m] per used realization, line by line.
        let mut g_m = vec![C64::new(0.0, 0.0); used.len() * l_count];
        let mut var_m = vec![0.0; used.len() * l_count];
        let mut g_p = vec![C64::new(0.0, 0.0); p_count * l_count];
        for (mi, &m) in used.iter().enumerate() {
            for p in 0..p_count {
                let start = layout.period_start(m, p);
                let slice = &record[start..start + n];
                if let Some(i) = slice.iter().position(|z| !z.re.is_finite()) {
                    return Err(not_finite("excitation_a", start + i, slice[i].re));
                }
                if let Some(i) = slice.iter().position(|z| !z.im.is_finite()) {
                    return Err(not_finite("position_m", start + i, slice[i].im));
                }
                buf.copy_from_slice(slice);
                fft.process(&mut buf);
                for (li, &k) in lines.iter().enumerate() {
                    let (z, zm) = (buf[k as usize], buf[n - k as usize].conj());
                    let u = (z + zm) * 0.5;
                    let y = (z - zm) * C64::new(0.0, -0.5);
                    if u.norm_sqr() == 0.0 {
                        return Err(BlaError::NoInput {
                            frequency_hz: k as f64 / layout.period_s(),
                            realization: m,
                            period: p,
                        });
                    }
                    g_p[p * l_count + li] = y / u;
                }
            }
            for li in 0..l_count {
                let mean =
                    (0..p_count).map(|p| g_p[p * l_count + li]).sum::<C64>() / p_count as f64;
                let ss: f64 = (0..p_count)
                    .map(|p| (g_p[p * l_count + li] - mean).norm_sqr())
                    .sum();
                g_m[mi * l_count + li] = mean;
                var_m[mi * l_count + li] = ss / (p_count * (p_count - 1)) as f64;
            }
        }
        let m_count = used.len();
        let mf = m_count as f64;
        let mut out = Self {
            frequency_hz: lines
                .iter()
                .map(|&k| k as f64 / layout.period_s())
                .collect(),
            response: Vec::with_capacity(l_count),
            sigma_bla_m_per_a: Vec::with_capacity(l_count),
            sigma_noise_m_per_a: Vec::with_capacity(l_count),
            sigma_nonlinear_m_per_a: Vec::with_capacity(l_count),
            distortion_p_value: Vec::with_capacity(l_count),
            realizations: m_count,
            periods: p_count,
            resolution_hz: 1.0 / layout.period_s(),
        };
        let (a, b) = (m_count.saturating_sub(1), m_count * (p_count - 1));
        for li in 0..l_count {
            let g = (0..m_count).map(|m| g_m[m * l_count + li]).sum::<C64>() / mf;
            let var_n = (0..m_count).map(|m| var_m[m * l_count + li]).sum::<f64>() / (mf * mf);
            let (var_bla, sigma_s, p) = if m_count >= 2 {
                let ss: f64 = (0..m_count)
                    .map(|m| (g_m[m * l_count + li] - g).norm_sqr())
                    .sum();
                let var_bla = ss / (mf * (mf - 1.0));
                let p = if var_n > 0.0 {
                    f_upper_tail(var_bla / var_n, a, b)
                } else if var_bla > 0.0 {
                    0.0
                } else {
                    1.0
                };
                (var_bla, (mf * (var_bla - var_n)).max(0.0).sqrt(), p)
            } else {
                (var_n, f64::NAN, f64::NAN)
            };
            out.response.push(g);
            out.sigma_bla_m_per_a.push(var_bla.sqrt());
            out.sigma_noise_m_per_a.push(var_n.sqrt());
            out.sigma_nonlinear_m_per_a.push(sigma_s);
            out.distortion_p_value.push(p);
        }
        Ok(out)
    }

    /// [`Self::estimate`] from separate input (A) and output (m) records.
    ///
    /// # Errors
    /// As [`Self::estimate`]; [`BlaError::ShortRecord`] also when `u` and
    /// `y` differ in length (the shorter counts).
    pub fn estimate_uy(
        u: &[f64],
        y: &[f64],
        layout: &Layout,
        use_realization: &[bool],
    ) -> Result<Self, BlaError> {
        let record: Vec<C64> = u.iter().zip(y).map(|(a, b)| C64::new(*a, *b)).collect();
        Self::estimate(&record, layout, use_realization)
    }

    /// The test for nonlinear distortion over every line (module docs);
    /// `None` with one realization.
    pub fn distortion_test(&self) -> Option<DistortionTest> {
        if self.realizations < 2 {
            return None;
        }
        let lines = self.distortion_p_value.len();
        let k = self
            .distortion_p_value
            .iter()
            .filter(|p| **p < LINE_LEVEL)
            .count();
        let p_value = binomial_upper_tail(lines, LINE_LEVEL, k);
        Some(DistortionTest {
            lines,
            lines_distorted: k,
            expected_by_chance: LINE_LEVEL * lines as f64,
            p_value,
            detected: p_value < DETECTION_LEVEL,
        })
    }

    /// The BLA as an [`Frf`] on its lines: magnitude, unwrapped phase,
    /// the signal-to-noise coherence `|Ĝ|² / (|Ĝ|² + σ̂²_BLA)`,
    /// `sigma_m_per_a` = `σ̂_BLA` (noise and distortion: what a fit
    /// weights with), `resolution_hz` = `1 / T_p` (each line is one DFT
    /// bin of a period, so every two lines are independent) and
    /// `sigma_dof` = [`Self::sigma_dof`].
    pub fn to_frf(&self) -> Frf {
        let mut phase_deg: Vec<f64> = self.response.iter().map(|g| g.arg().to_degrees()).collect();
        unwrap_deg(&mut phase_deg);
        Frf {
            frequency_hz: self.frequency_hz.clone(),
            magnitude_m_per_a: self.response.iter().map(|g| g.norm()).collect(),
            phase_deg,
            coherence: self
                .response
                .iter()
                .zip(&self.sigma_bla_m_per_a)
                .map(|(g, s)| {
                    let g2 = g.norm_sqr();
                    if g2 + s * s > 0.0 {
                        g2 / (g2 + s * s)
                    } else {
                        0.0
                    }
                })
                .collect(),
            sigma_m_per_a: self.sigma_bla_m_per_a.clone(),
            resolution_hz: vec![self.resolution_hz; self.frequency_hz.len()],
            sigma_dof: vec![self.sigma_dof(); self.frequency_hz.len()],
        }
    }

    /// Degrees of freedom of `σ̂²_BLA` (real, as of a χ²): `2(M − 1)`, the
    /// spread of M complex means; with one realization `2(P − 1)`, the
    /// spread of its P periods (module docs).
    pub fn sigma_dof(&self) -> f64 {
        if self.realizations >= 2 {
            2.0 * (self.realizations - 1) as f64
        } else {
            2.0 * (self.periods.max(1) - 1) as f64
        }
    }

    /// Median over the lines of `σ / |Ĝ|` for one of the σ columns.
    pub fn median_relative(&self, sigma: &[f64]) -> f64 {
        let mut r: Vec<f64> = sigma
            .iter()
            .zip(&self.response)
            .map(|(s, g)| s / g.norm())
            .filter(|x| x.is_finite())
            .collect();
        if r.is_empty() {
            return f64::NAN;
        }
        r.sort_by(f64::total_cmp);
        r[r.len() / 2]
    }

    /// The CSV header of [`Self::write_csv`].
    pub const CSV_HEADER: &'static str = "frequency_hz,magnitude_m_per_a,phase_deg,real_m_per_a,imag_m_per_a,sigma_bla_m_per_a,sigma_noise_m_per_a,sigma_nonlinear_m_per_a,distortion_p_value";

    /// Writes the BLA CSV ([`Self::CSV_HEADER`]: frequency (Hz), |Ĝ| (m/A),
    /// unwrapped phase (degrees), Re and Im of Ĝ (m/A), σ̂_BLA, σ̂_n, σ̂_S
    /// (m/A) and the line's distortion p-value; `NaN` where one
    /// realization leaves them undefined) through a temporary file renamed
    /// when complete ([`crate::outputs::write_atomically`]).
    ///
    /// # Errors
    /// I/O errors from creating, writing or renaming the file.
    pub fn write_csv(
        &self,
        path: &Path,
        existing: crate::outputs::Existing,
    ) -> std::io::Result<()> {
        crate::outputs::write_buffered_atomically(path, existing, |w| self.write_csv_to(w))
    }

    /// Writes the CSV rows (with the header) to `w`.
    ///
    /// # Errors
    /// The writer's.
    pub fn write_csv_to(&self, w: &mut impl Write) -> std::io::Result<()> {
        writeln!(w, "{}", Self::CSV_HEADER)?;
        let frf = self.to_frf();
        for i in 0..self.frequency_hz.len() {
            let g = self.response[i];
            writeln!(
                w,
                "{:.6},{:.6e},{:.3},{:.9e},{:.9e},{:.4e},{:.4e},{:.4e},{:.4e}",
                self.frequency_hz[i],
                frf.magnitude_m_per_a[i],
                frf.phase_deg[i],
                g.re,
                g.im,
                self.sigma_bla_m_per_a[i],
                self.sigma_noise_m_per_a[i],
                self.sigma_nonlinear_m_per_a[i],
                self.distortion_p_value[i]
            )?;
        }
        w.flush()
    }
}

fn not_finite(what: &'static str, tick: usize, value: f64) -> BlaError {
    BlaError::NotFinite { what, tick, value }
}

/// `P(F ≥ f)` for `F ~ F(2a, 2b)` with whole `a ≥ 1`, `b ≥ 1`:
/// `1 − I_x(a, b)` with `x = a f / (a f + b)`, and for whole parameters
/// `I_x(a, b) = P(B(a + b − 1, x) ≥ a)` (the incomplete beta function of
/// whole parameters as a binomial sum; Abramowitz & Stegun, *Handbook of
/// Mathematical Functions*, ch. 26), so `P(F ≥ f) = Σ_{j<a} C(n, j) x^j (1 − x)^{n−j}`,
/// `n = a + b − 1`: `a` terms, each in logarithms. 1 for `f ≤ 0`.
pub fn f_upper_tail(f: f64, a: usize, b: usize) -> f64 {
    if a == 0 || b == 0 || f.is_nan() {
        return f64::NAN;
    }
    if f <= 0.0 {
        return 1.0;
    }
    if f.is_infinite() {
        return 0.0;
    }
    let (af, bf) = (a as f64, b as f64);
    // x = a f / (a f + b), 1 − x = b / (a f + b), in logarithms.
    let ln_x = (af * f).ln() - (af * f + bf).ln();
    let ln_1mx = bf.ln() - (af * f + bf).ln();
    let n = a + b - 1;
    let mut ln_c = 0.0; // ln C(n, 0)
    let mut sum = 0.0;
    for j in 0..a {
        if j > 0 {
            ln_c += ((n - j + 1) as f64).ln() - (j as f64).ln();
        }
        sum += (ln_c + j as f64 * ln_x + (n - j) as f64 * ln_1mx).exp();
    }
    sum.min(1.0)
}

/// `P(B(n, q) ≥ k)` for the binomial distribution, summed in logarithms.
pub fn binomial_upper_tail(n: usize, q: f64, k: usize) -> f64 {
    if k == 0 {
        return 1.0;
    }
    if k > n {
        return 0.0;
    }
    let (ln_q, ln_1mq) = (q.ln(), (1.0 - q).ln());
    let mut ln_c = 0.0;
    let mut sum = 0.0;
    for j in 0..=n {
        if j > 0 {
            ln_c += ((n - j + 1) as f64).ln() - (j as f64).ln();
        }
        if j >= k {
            sum += (ln_c + j as f64 * ln_q + (n - j) as f64 * ln_1mq).exp();
        }
    }
    sum.min(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The F tail against closed forms: `F(2, 2b)`: `(1 + f/b)^(−b)`;
    /// `F(4, 2b)`: `(1 + f·2/b... )` via the two-term sum written out, and
    /// table values (the 5 % points of Fisher's F: F(2, 8) is
    /// 4.46, F(6, 24) at 5 % is 2.51).
    #[test]
    fn f_tail_against_closed_forms_and_tables() {
        for b in [1usize, 3, 8] {
            for f in [0.1, 1.0, 4.0] {
                let want = (1.0 + f / b as f64).powf(-(b as f64));
                assert!((f_upper_tail(f, 1, b) - want).abs() < 1e-14, "{b} {f}");
            }
        }
        // F(4, 2b): x = 2f/(2f+b); n = b + 1; terms j = 0, 1.
        let (f, b) = (1.7f64, 5usize);
        let x = 2.0 * f / (2.0 * f + b as f64);
        let want = (1.0 - x).powi(6) + 6.0 * x * (1.0 - x).powi(5);
        assert!((f_upper_tail(f, 2, b) - want).abs() < 1e-14);
        assert!((f_upper_tail(4.46, 1, 4) - 0.05).abs() < 5e-4);
        assert!((f_upper_tail(2.51, 3, 12) - 0.05).abs() < 5e-4);
        assert_eq!(f_upper_tail(0.0, 3, 4), 1.0);
    }

    /// The binomial tail by hand: `B(4, 0.5) ≥ 3` is 5/16.
    #[test]
    fn binomial_tail_by_hand() {
        assert!((binomial_upper_tail(4, 0.5, 3) - 5.0 / 16.0).abs() < 1e-15);
        assert_eq!(binomial_upper_tail(10, 0.05, 0), 1.0);
        // P(B(100, 0.05) ≥ 1) = 1 − 0.95^100.
        let want = 1.0 - 0.95f64.powi(100);
        assert!((binomial_upper_tail(100, 0.05, 1) - want).abs() < 1e-12);
    }

    fn layout(m: usize, p: usize) -> Layout {
        Layout {
            lead_in_ticks: 3,
            period_ticks: 64,
            transient_periods: 1,
            periods: p,
            realizations: m,
            lines: vec![1, 2, 5, 9, 20],
            tick_s: 1.0 / 64.0,
        }
    }

    /// A static gain with exact data: Ĝ is the gain, every σ 0, the
    /// record's errors name their input.
    #[test]
    fn exact_gain_and_errors() {
        let lay = layout(3, 2);
        let len = lay.needed_ticks() + 5;
        let u: Vec<f64> = (0..len)
            .map(|n| {
                let t = n as f64 / 64.0;
                (2.0 * std::f64::consts::PI * t).cos()
                    + (2.0 * std::f64::consts::PI * 2.0 * t + 0.3).cos()
                    + (2.0 * std::f64::consts::PI * 5.0 * t + 1.0).cos()
                    + (2.0 * std::f64::consts::PI * 9.0 * t + 2.0).cos()
                    + (2.0 * std::f64::consts::PI * 20.0 * t + 3.0).cos()
            })
            .collect();
        let y: Vec<f64> = u.iter().map(|x| -2.5 * x).collect();
        let b = Bla::estimate_uy(&u, &y, &lay, &[]).unwrap();
        for g in &b.response {
            assert!((g - C64::new(-2.5, 0.0)).norm() < 1e-12);
        }
        assert!(b.sigma_bla_m_per_a.iter().all(|s| *s < 1e-12));
        assert_eq!(b.frequency_hz, vec![1.0, 2.0, 5.0, 9.0, 20.0]);
        assert_eq!(b.resolution_hz, 1.0);
        let mut bad = y.clone();
        bad[lay.period_start(1, 1) + 4] = f64::NAN;
        let e = Bla::estimate_uy(&u, &bad, &lay, &[]).unwrap_err();
        assert!(e.to_string().contains("position_m"), "{e}");
        let e = Bla::estimate_uy(&u[..100], &y[..100], &lay, &[]).unwrap_err();
        assert!(matches!(e, BlaError::ShortRecord { .. }), "{e}");
        let e = Bla::estimate_uy(&u, &y, &layout(3, 1), &[]).unwrap_err();
        assert!(e.to_string().starts_with("multisine.periods"), "{e}");
        let e = Bla::estimate_uy(&u, &y, &lay, &[false, false, false]).unwrap_err();
        assert!(e.to_string().starts_with("multisine.realizations"), "{e}");
        let zero = vec![0.0; len];
        let e = Bla::estimate_uy(&zero, &y, &lay, &[]).unwrap_err();
        assert!(matches!(e, BlaError::NoInput { .. }), "{e}");
    }
}
