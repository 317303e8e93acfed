//! How long a move takes to settle: the time from the move's start after
//! which the error stays within a band (`±settle_band_m`) until the next
//! move, measured on the error averaged over the trial's lines.
//!
//! The probe's noise is broadband (the standstill error is tens of nm RMS
//! at 20 kHz), so a ±10 nm band judged on single ticks would never be met.
//! The error is therefore averaged over the measured lines (noise `/√P`)
//! and over a centred window of [`SETTLE_WINDOW_S`] (a moving average,
//! zero phase, wrapping round the periodic line): white noise falls by
//! `√(window ticks)` while the stage's motion, which the loop and the
//! modes keep below a few hundred hertz, passes (a 1 ms average keeps
//! 98.4 % of a 100 Hz sine). What noise is left is measured, from the
//! scatter between the lines, and reported beside the band: a band under
//! 4σ of it is flagged (over a dwell of some hundred independent
//! averages, noise alone reaches 3σ).

/// The centred moving average's length, s (module docs).
pub const SETTLE_WINDOW_S: f64 = 1e-3;

/// A settle band is trusted when it is at least this many σ of the
/// averaged error's noise (module docs).
pub const TRUSTED_BAND_SIGMAS: f64 = 4.0;

/// A trial's settling, from [`settle`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settle {
    /// The move-and-settle time: from each move's start to the first tick
    /// at which the reference has arrived and after which the averaged
    /// error stays within the band to the middle of the dwell, the larger
    /// of the two moves of a line, s (at least the move's duration);
    /// `None`: a move never settled.
    pub time_s: Option<f64>,
    /// The averaged error's noise, 1σ, m: the scatter between the lines
    /// of each tick's smoothed error over `√P`, RMS over the line; NaN
    /// with one line.
    pub noise_sigma_m: f64,
}

impl Settle {
    /// Whether a band of `±band_m` can be judged on this noise: at least
    /// [`TRUSTED_BAND_SIGMAS`] σ of it (false with one line).
    pub fn trusted(&self, band_m: f64) -> bool {
        band_m >= TRUSTED_BAND_SIGMAS * self.noise_sigma_m
    }
}

/// The centred moving average of one periodic line over `w` ticks (odd).
fn smooth(line: &[f64], w: usize) -> Vec<f64> {
    let n = line.len();
    let h = (w / 2) as isize;
    (0..n as isize)
        .map(|i| {
            (-h..=h)
                .map(|d| line[(i + d).rem_euclid(n as isize) as usize])
                .sum::<f64>()
                / (2 * h + 1) as f64
        })
        .collect()
}

/// The settling of a trial whose error is `error_m` (the measured ticks,
/// whole lines of `n` ticks first; a partial line is left out), the moves
/// starting at the ticks `starts` of each line (ascending), at `rate_hz`,
/// within `±band_m` (module docs), each move lasting `move_ticks`. A move
/// has settled when the error stays within the band from then to the
/// middle of the dwell after it: the dwell's second half is left out, as
/// a feedforward that inverts a non-minimum-phase plant acts ahead of the
/// next move (stable inversion's preview).
pub fn settle(
    error_m: &[f64],
    n: usize,
    starts: &[usize],
    move_ticks: usize,
    rate_hz: f64,
    band_m: f64,
) -> Settle {
    let w = ((SETTLE_WINDOW_S * rate_hz).round() as usize / 2) * 2 + 1;
    let lines: Vec<Vec<f64>> = error_m.chunks_exact(n).map(|l| smooth(l, w)).collect();
    let p = lines.len();
    if p == 0 {
        return Settle {
            time_s: None,
            noise_sigma_m: f64::NAN,
        };
    }
    let mean: Vec<f64> = (0..n)
        .map(|i| lines.iter().map(|l| l[i]).sum::<f64>() / p as f64)
        .collect();
    let noise_sigma_m = if p < 2 {
        f64::NAN
    } else {
        let var_mean: f64 = (0..n)
            .map(|i| {
                let v: f64 =
                    lines.iter().map(|l| (l[i] - mean[i]).powi(2)).sum::<f64>() / (p - 1) as f64;
                v / p as f64
            })
            .sum::<f64>()
            / n as f64;
        var_mean.sqrt()
    };
    let mut worst: Option<usize> = Some(0);
    for (j, &start) in starts.iter().enumerate() {
        let next = starts.get(j + 1).copied().unwrap_or(n + starts[0]);
        let end = start + move_ticks + next.saturating_sub(start + move_ticks) / 2;
        // The last tick of the window outside the band.
        let last_out = (start..end).rev().find(|&i| mean[i % n].abs() > band_m);
        // Settled once the reference has arrived and the error stays in.
        let t = match last_out {
            None => Some(move_ticks),
            Some(i) if i + 1 >= end => None,
            Some(i) => Some((i + 1 - start).max(move_ticks)),
        };
        worst = match (worst, t) {
            (Some(a), Some(b)) => Some(a.max(b)),
            _ => None,
        };
    }
    Settle {
        time_s: worst.map(|t| t as f64 / rate_hz),
        noise_sigma_m,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::splitmix::standard_normal;

    /// An error decaying as `e^{−t/τ}` from 1 µm after each of two moves
    /// per line, under white noise of 40 nm: the noise left is
    /// `40 nm/√(w·P)` and the error settles into ±10 nm where the clean
    /// decay crosses the band, `τ·ln(100)`, or later by as much as a 4σ
    /// excursion of that noise can hold it out (`τ·ln(b/(b − 4σ))`).
    #[test]
    fn an_exponential_settles_where_it_crosses_the_band() {
        let (rate, n, p, tau) = (20e3, 4000, 100, 5e-3);
        let clean: Vec<f64> = (0..n)
            .map(|i| {
                let t = (i % (n / 2)) as f64 / rate;
                1e-6 * (-t / tau).exp()
            })
            .collect();
        let e: Vec<f64> = (0..n * p)
            .map(|i| clean[i % n] + 40e-9 * standard_normal(i as u64 + 7))
            .collect();
        let s = settle(&e, n, &[0, n / 2], 0, rate, 10e-9);
        let w = 21.0;
        let noise = 40e-9 / (w * p as f64).sqrt();
        assert!((s.noise_sigma_m / noise - 1.0).abs() < 0.1, "{s:?} {noise}");
        let want = tau * 100f64.ln();
        let late = tau * (10e-9 / (10e-9 - 4.0 * noise)).ln();
        let t = s.time_s.unwrap();
        assert!(
            t > want - 0.5e-3 && t < want + late,
            "{t} against {want} + {late}"
        );
        // A band the error never enters within the line: not settled.
        assert_eq!(settle(&e, n, &[0, n / 2], 0, rate, 1e-12).time_s, None);
    }
}
