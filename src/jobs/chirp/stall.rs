//! What a host stall does to an identification: the bias a held command
//! leaves at the swept line or the multisine's lines, and the bands a run
//! leaves out of its FRF because of it.

use super::*;

/// The largest relative bias, in power, a stall may leave at the swept
/// line before its band is left out of the FRF: 1e-4, a 1 % error of |H|.
pub const STALL_BIAS_MAX: f64 = 1e-4;

/// The relative bias in power a hold of `hold_s` leaves at the line the
/// sweep is at (`f_hz`, sweeping at `rate_hz_per_s`): the held sample
/// departs from the planned sine by up to `min(2π f t, 2)` of its
/// amplitude, an error pulse of energy `A² min(2π f h, 2)² h / 3`
/// (`h = hold_s`), spread over about `1/h` Hz, against the chirp's energy
/// density `A² / (2 df/dt)` there:
/// `(2/3) min(2π f h, 2)² h² (df/dt)`. Dimensionless.
pub fn held_excitation_bias(f_hz: f64, hold_s: f64, rate_hz_per_s: f64) -> f64 {
    let e = (2.0 * std::f64::consts::PI * f_hz * hold_s).min(2.0);
    2.0 / 3.0 * e * e * hold_s * hold_s * rate_hz_per_s.abs()
}

/// The stalls of an open-loop run (`/bench/event` `stall`: the loop
/// behind its deadlines, or the device on late commands) and what they
/// cost the FRF. A stall holds the last excitation sample while the sweep
/// is at `f(t)`, so the record no longer shows exactly what the plant
/// received there. A stall whose bias at the swept line
/// ([`held_excitation_bias`]) exceeds [`STALL_BIAS_MAX`] (1 % of |H|) has
/// its band left out: the FRF lines whose window (`resolution_hz`: the
/// LPM's local window or H1's smoothing window) meets the frequencies
/// swept during the stall, widened by twice
/// `identification.relative_resolution` on each side (from the FRF, its
/// CSV and fit), counted here. Shorter stalls are counted only: a VM's
/// ordinary one-period overruns bias no line by 1e-8.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct StallReport {
    /// Stalls seen, count.
    pub count: u64,
    /// The longest, s.
    pub longest_s: f64,
    /// All of them, s.
    pub total_s: f64,
    /// The sweep's frequency bands they biased by more than 1 %,
    /// `[f_lo, f_hi]` Hz (a stall in the lead-in or the tail biases none).
    pub bands_hz: Vec<[f64; 2]>,
    /// FRF lines left out, count.
    pub excluded_lines: u64,
    /// Multisine realizations left out of the BLA, count.
    #[serde(default)]
    pub excluded_realizations: u64,
}

/// The relative bias, in power, a hold of `hold_s` leaves at the weakest
/// line of a multisine: the held sample departs from the signal by at most
/// `e = min(2π f_max h, 2) · peak` (Bernstein's inequality bounds the
/// slope of a trigonometric polynomial of top frequency `f_max` by
/// `2π f_max · peak`), an error whose DFT over one period is at most
/// `e · h / T_s` against the line's `N A_min / 2`:
/// `(2 e h / (T_p A_min))²`. Dimensionless.
pub fn held_multisine_bias(
    hold_s: f64,
    f_max_hz: f64,
    peak_a: f64,
    min_line_a: f64,
    period_s: f64,
) -> f64 {
    let e = (2.0 * std::f64::consts::PI * f_max_hz * hold_s).min(2.0) * peak_a;
    (2.0 * e * hold_s / (period_s * min_line_a)).powi(2)
}

impl StallReport {
    /// The report of `stalls` (end tick, length s) on `chirp` at
    /// `period_s`, with the FRF's relative resolution `r`.
    pub fn of(stalls: &[(u64, f64)], chirp: &Chirp, period_s: f64, r: f64) -> Self {
        let mut rep = Self::default();
        let lead_s = chirp.lead_in_ticks() as f64 * period_s;
        let sweep_s = chirp.sweep_s();
        for &(tick, len_s) in stalls {
            if !(len_s.is_finite() && len_s > 0.0) {
                continue;
            }
            rep.count += 1;
            rep.longest_s = rep.longest_s.max(len_s);
            rep.total_s += len_s;
            // The held span in the sweep's time: it ends at `tick`.
            let t_end = tick as f64 * period_s - lead_s;
            let t_start = t_end - len_s - period_s;
            if t_end < 0.0 || t_start > sweep_s {
                continue;
            }
            // The bias the held excitation leaves at the swept line.
            let t_mid = (0.5 * (t_start + t_end)).clamp(0.0, sweep_s);
            let f_s = chirp.frequency_hz(t_mid);
            let bias =
                held_excitation_bias(f_s, len_s + period_s, chirp.sweep_rate_hz_per_s(t_mid));
            if bias <= STALL_BIAS_MAX {
                continue;
            }
            let f_lo = chirp.frequency_hz(t_start.max(0.0)) * (1.0 - 2.0 * r);
            let f_hi = chirp.frequency_hz(t_end.min(sweep_s)) * (1.0 + 2.0 * r);
            rep.bands_hz.push([f_lo, f_hi]);
        }
        rep
    }

    /// The report of `stalls` (end tick, length s) on a multisine of
    /// `plan` at `period_s`, and which realizations the BLA may use: a
    /// stall whose bias at the weakest line ([`held_multisine_bias`])
    /// exceeds [`STALL_BIAS_MAX`] leaves out the realization whose
    /// measured periods it meets (a stall in a transient period, the
    /// lead-in or the tail decays with the transient, or meets nothing).
    pub(super) fn of_multisine(
        stalls: &[(u64, f64)],
        plan: &MultisinePlan,
        period_s: f64,
    ) -> (Self, Vec<bool>) {
        let mut rep = Self::default();
        let layout = &plan.layout;
        let mut keep = vec![true; layout.realizations];
        for &(tick, len_s) in stalls {
            if !(len_s.is_finite() && len_s > 0.0) {
                continue;
            }
            rep.count += 1;
            rep.longest_s = rep.longest_s.max(len_s);
            rep.total_s += len_s;
            let hold_s = len_s + period_s;
            let bias = held_multisine_bias(
                hold_s,
                plan.f_max_hz,
                plan.peak_a,
                plan.line_amplitude_a[0],
                layout.period_s(),
            );
            if bias <= STALL_BIAS_MAX {
                continue;
            }
            let end = tick as usize;
            let start = end.saturating_sub((hold_s / period_s).ceil() as usize);
            for (m, k) in keep.iter_mut().enumerate() {
                let span = layout.measured(m);
                if start < span.end && end >= span.start {
                    *k = false;
                }
            }
        }
        rep.excluded_realizations = keep.iter().filter(|k| !**k).count() as u64;
        (rep, keep)
    }

    /// `frf` without the lines in the stalls' bands (counted).
    pub fn exclude(&mut self, frf: Frf) -> Frf {
        if self.bands_hz.is_empty() {
            return frf;
        }
        // A line goes when its window (`resolution_hz` wide, centred on it;
        // the line alone where unknown) meets a band.
        let keep: Vec<bool> = frf
            .frequency_hz
            .iter()
            .zip(&frf.resolution_hz)
            .map(|(f, r)| {
                let half = if r.is_finite() { 0.5 * r } else { 0.0 };
                !self
                    .bands_hz
                    .iter()
                    .any(|[lo, hi]| f + half >= *lo && f - half <= *hi)
            })
            .collect();
        self.excluded_lines = keep.iter().filter(|k| !**k).count() as u64;
        frf.select(|i| keep[i])
    }

    /// One line for the summary.
    pub fn line(&self) -> String {
        if self.count == 0 {
            return "stalls: none".to_string();
        }
        let bands: Vec<String> = self
            .bands_hz
            .iter()
            .map(|[a, b]| format!("{a:.2}–{b:.2} Hz"))
            .collect();
        let realizations = if self.excluded_realizations > 0 {
            format!(
                "; {} multisine realization(s) left out",
                self.excluded_realizations
            )
        } else {
            String::new()
        };
        format!(
            "stalls: {} (longest {:.1} ms, {:.1} ms in all); {} FRF lines left out{}{realizations}",
            self.count,
            self.longest_s * 1e3,
            self.total_s * 1e3,
            self.excluded_lines,
            if bands.is_empty() {
                String::new()
            } else {
                format!(" ({})", bands.join(", "))
            }
        )
    }
}
