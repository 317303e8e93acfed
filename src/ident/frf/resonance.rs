//! Resonances found in a measured FRF, and the phase test for CMP-CNMP
//! zeros across a closely spaced pair.

use super::*;

/// A resonance found in a measured FRF.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Resonance {
    /// Peak frequency, Hz (refined between grid points; in `bench chirp`'s
    /// summary the fitted natural frequency).
    pub frequency_hz: f64,
    /// Peak magnitude, m/A.
    pub magnitude_m_per_a: f64,
    /// Damping ratio: in `bench chirp`'s summary the modal fit's; from
    /// [`find_resonances`] the half-power (−3 dB) bandwidth,
    /// `ζ ≈ (f₊ − f₋) / (2 f_n)`, when both half-power points are found
    /// before a neighbouring feature.
    pub damping_ratio: Option<f64>,
    /// Peak height above the lower of the two flanking minima, dB.
    pub prominence_db: f64,
}

/// Smallest magnitude-squared coherence γ² at which an FRF point is taken
/// as data: a resonance must peak at or above it, and the Bode plot draws
/// the points below it faint (at γ² = 0.5 as much of the output power is
/// noise or nonlinearity as is explained by the input; Bendat & Piersol,
/// *Random Data*, §9.2.3).
pub const MIN_COHERENCE: f64 = 0.5;

/// Relative distance at which a lightly damped peak must have dropped by
/// [`SHARPNESS_DB`] on at least one side.
pub const SHARPNESS_SPAN: f64 = 0.03;
/// Drop required within ±[`SHARPNESS_SPAN`] of a peak, dB.
pub const SHARPNESS_DB: f64 = 3.0;

/// Finds lightly damped resonances: local maxima of |H| on the grid that
/// rise at least `min_prominence_db` above the higher of the two flanking
/// minima, have coherence ≥ [`MIN_COHERENCE`], and are sharp — |H| is at least
/// [`SHARPNESS_DB`] lower at `f·(1 ± SHARPNESS_SPAN)` on one side or the
/// other (a single mode passes this for ζ ≲ 0.03; the broad hump that
/// follows an anti-resonance does not). Each peak is then refined on a
/// quarter-bin sweep of the lightly smoothed estimate, and its damping is
/// estimated from the half-power bandwidth.
pub fn find_resonances(frf: &Frf, spectra: &Spectra, min_prominence_db: f64) -> Vec<Resonance> {
    let db: Vec<f64> = frf
        .magnitude_m_per_a
        .iter()
        .map(|m| {
            if *m > 0.0 {
                20.0 * m.log10()
            } else {
                f64::NEG_INFINITY
            }
        })
        .collect();
    let n = db.len();
    let mut out = Vec::new();
    for i in 1..n.saturating_sub(1) {
        if !(db[i] > db[i - 1] && db[i] >= db[i + 1]) || frf.coherence[i] < MIN_COHERENCE {
            continue;
        }
        // Flanking minima: walk down until the curve rises above the peak.
        let flank = |range: &mut dyn Iterator<Item = usize>| {
            let mut lowest = db[i];
            for j in range {
                if db[j] > db[i] {
                    break;
                }
                lowest = lowest.min(db[j]);
            }
            lowest
        };
        let left = flank(&mut (0..i).rev());
        let right = flank(&mut (i + 1..n));
        let prominence = db[i] - left.max(right);
        if prominence < min_prominence_db {
            continue;
        }
        let f = frf.frequency_hz[i];
        let db_at = |x: f64| {
            let j = frf.frequency_hz.partition_point(|g| *g < x).min(n - 1);
            db[j]
        };
        let drop = (db[i] - db_at(f * (1.0 - SHARPNESS_SPAN)))
            .max(db[i] - db_at(f * (1.0 + SHARPNESS_SPAN)));
        if drop < SHARPNESS_DB {
            continue;
        }
        out.push(refine_peak(frf, spectra, i, prominence));
    }
    out
}

pub(super) fn refine_peak(frf: &Frf, spectra: &Spectra, i: usize, prominence_db: f64) -> Resonance {
    let f = &frf.frequency_hz;
    let (lo, hi) = (f[i - 1], f[i + 1]);
    // Light smoothing (3 bins) so the peak is not flattened by the window.
    let hw = 1.5 * spectra.bin_hz();
    let mag = |x: f64| spectra.estimate_with(x, hw).response.norm();
    let step = spectra.bin_hz() / 4.0;
    let (mut best_f, mut best_m) = (f[i], mag(f[i]));
    let mut x = lo;
    while x <= hi {
        let m = mag(x);
        if m > best_m {
            best_m = m;
            best_f = x;
        }
        x += step;
    }
    // Parabolic interpolation of |H| in dB around the best sample.
    let (a, b, c) = (
        20.0 * mag(best_f - step).log10(),
        20.0 * best_m.log10(),
        20.0 * mag(best_f + step).log10(),
    );
    let denom = a - 2.0 * b + c;
    if denom < 0.0 {
        best_f += 0.5 * step * (a - c) / denom;
    }
    // Half-power points: walk out until |H| < peak/√2, stop at a rise.
    let target = best_m / 2f64.sqrt();
    let walk = |dir: f64| -> Option<f64> {
        let mut prev = best_m;
        let mut x = best_f;
        for _ in 0..20_000 {
            x += dir * step;
            let m = mag(x);
            if m < target {
                // Linear interpolation between the last two samples.
                let frac = (prev - target) / (prev - m);
                return Some(x - dir * step * (1.0 - frac));
            }
            if m > prev * 1.05 {
                return None;
            }
            prev = m;
        }
        None
    };
    let damping_ratio = match (walk(-1.0), walk(1.0)) {
        (Some(f1), Some(f2)) => Some((f2 - f1) / (2.0 * best_f)),
        _ => None,
    };
    Resonance {
        frequency_hz: best_f,
        magnitude_m_per_a: best_m,
        damping_ratio,
        prominence_db,
    }
}

/// The phase test for CMP-CNMP zeros across a closely spaced pair.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct PairVerdict {
    /// Lower mode of the pair, Hz.
    pub lower_hz: f64,
    /// Upper mode of the pair, Hz.
    pub upper_hz: f64,
    /// Band over which the net phase is taken, Hz.
    pub band_hz: (f64, f64),
    /// Net phase change over the band, degrees (unwrapped).
    pub net_phase_deg: f64,
    /// Net phase rounded to a multiple of 180°.
    pub net_phase_multiple_deg: f64,
    /// `true`: two poles and no net phase from the zeros between them —
    /// the −360° signature of CMP-CNMP zeros (thesis §2.2.2, Fig 5-9b).
    pub cmp_cnmp: bool,
}

pub use crate::analysis::modal::CLOSE_PAIR_RATIO;
