//! Outlier lines, as a link or an estimator that does not know about a
//! corrupted block gives them: `tests/cli/real_links.rs`' outlier
//! condition and the flagged fit of `benches/fit.rs`. Included with
//! `#[path = ".../common/outliers.rs"] mod outliers;`.

use bench::ident::frf::{Frf, C64};
use rand::{Rng, SeedableRng};

/// `frf` with 20 % of its lines, drawn at random (ChaCha8 seeded with
/// `seed`), multiplied by `1 + r e^{jφ}` (r uniform in [0.2, 1], φ uniform
/// in [−π, π)); their σ and coherence left as they were.
pub fn with_outliers(mut frf: Frf, seed: u64) -> Frf {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    for k in 0..frf.frequency_hz.len() {
        if rng.random_range(0.0..1.0) < 0.2 {
            let r: f64 = rng.random_range(0.2..1.0);
            let phi: f64 = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
            let h = C64::from_polar(frf.magnitude_m_per_a[k], frf.phase_deg[k].to_radians())
                * (C64::from_polar(r, phi) + 1.0);
            frf.magnitude_m_per_a[k] = h.norm();
            // Unwrapped as the estimator unwraps: the nearest turn to the
            // line's phase as it was.
            let was = frf.phase_deg[k];
            let p = h.arg().to_degrees();
            frf.phase_deg[k] = p + 360.0 * ((was - p) / 360.0).round();
        }
    }
    frf
}
