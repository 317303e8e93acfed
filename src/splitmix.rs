//! SplitMix64 (Steele, Lea & Flood, "Fast splittable pseudorandom number
//! generators", OOPSLA 2014): the one mixing function behind the
//! campaign's per-cell seeds and the residue test's fixed draws, where a
//! stream must be reproducible from a `u64` without a generator's state.
//!
//! Layer rule: may use nothing of the crate.

/// The SplitMix64 output for state `z`: `z + γ` (γ = 0x9e37_79b9_7f4a_7c15,
/// the golden-ratio increment) through the two xor-shift-multiply rounds.
/// A stream is `splitmix64(s)`, `splitmix64(s + γ)`, `splitmix64(s + 2γ)`, …
pub fn splitmix64(z: u64) -> u64 {
    let mut z = z.wrapping_add(GAMMA);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The golden-ratio increment γ of a SplitMix64 stream.
pub const GAMMA: u64 = 0x9e37_79b9_7f4a_7c15;

/// The `i`-th standard normal draw of the SplitMix64 stream seeded 0, by
/// Box–Muller from its uniforms `2i` and `2i + 1` (each `(x >> 11 + ½)/2⁵³`
/// of an output, in (0, 1)): reproducible draws for tests that sample
/// noise, without a generator's state.
pub fn standard_normal(i: u64) -> f64 {
    let u = |k: u64| ((splitmix64(k.wrapping_mul(GAMMA)) >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
    (-2.0 * u(2 * i).ln()).sqrt() * (2.0 * std::f64::consts::PI * u(2 * i + 1)).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The reference outputs of the C implementation (Vigna,
    /// `splitmix64.c`, seed 1234567): 6457827717110365317,
    /// 3203168211198807973, 9817491932198370423.
    #[test]
    fn matches_the_reference_stream() {
        let mut s: u64 = 1_234_567;
        let mut next = || {
            let x = splitmix64(s);
            s = s.wrapping_add(GAMMA);
            x
        };
        assert_eq!(next(), 6_457_827_717_110_365_317);
        assert_eq!(next(), 3_203_168_211_198_807_973);
        assert_eq!(next(), 9_817_491_932_198_370_423);
    }
}
