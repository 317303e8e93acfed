//! [`Excitation`], what `bench chirp` plays: the sweep of
//! [`crate::ident::chirp`] or the multisine of [`crate::ident::multisine`]
//! (`excitation.kind`).

use crate::ident::chirp::Chirp;
use crate::ident::multisine::{Multisine, MultisineError};

/// What `bench chirp` plays: a sweep ([`Chirp`]) or a multisine
/// ([`Multisine`], `excitation.kind = "multisine"`).
#[derive(Debug, Clone)]
#[allow(
    clippy::large_enum_variant,
    reason = "one per job, moved once into the loop; a box would add an indirection to every tick"
)]
pub enum Excitation {
    /// An exponential or linear sweep.
    Sweep(Chirp),
    /// A periodic multisine with its precomputed table.
    Multisine(Multisine),
}

impl Excitation {
    /// The excitation of `cfg` (`[chirp]`, and `[multisine]` or its
    /// defaults) for a loop of period `period_s` (s), random phases from
    /// `seed`. A multisine's table is computed here: call it before the
    /// loop starts.
    ///
    /// # Errors
    /// A multisine that cannot be built at this period
    /// ([`Multisine::new`]).
    pub fn new(
        cfg: &crate::config::BenchConfig,
        period_s: f64,
        seed: u64,
    ) -> Result<Self, MultisineError> {
        if cfg.excitation.kind.is_sweep() {
            Ok(Self::Sweep(Chirp::new(
                &cfg.chirp,
                cfg.excitation.kind,
                period_s,
            )))
        } else {
            let ms = cfg.multisine.unwrap_or_default();
            Ok(Self::Multisine(Multisine::new(
                &cfg.chirp, &ms, period_s, seed,
            )?))
        }
    }

    /// The record length of [`Self::new`]'s excitation, ticks, without
    /// computing a multisine's table.
    ///
    /// # Errors
    /// As [`Self::new`].
    pub fn total_ticks_of(
        cfg: &crate::config::BenchConfig,
        period_s: f64,
    ) -> Result<u64, MultisineError> {
        if cfg.excitation.kind.is_sweep() {
            Ok(Chirp::new(&cfg.chirp, cfg.excitation.kind, period_s).total_ticks())
        } else {
            Multisine::total_ticks_of(&cfg.chirp, &cfg.multisine.unwrap_or_default(), period_s)
        }
    }

    /// Total record length, ticks.
    pub fn total_ticks(&self) -> u64 {
        match self {
            Self::Sweep(c) => c.total_ticks(),
            Self::Multisine(m) => m.total_ticks(),
        }
    }

    /// Ticks of quiet lead-in.
    pub fn lead_in_ticks(&self) -> u64 {
        match self {
            Self::Sweep(c) => c.lead_in_ticks(),
            Self::Multisine(m) => m.lead_in_ticks(),
        }
    }

    /// Excitation current at `tick`, A. Real-time safe (a sweep in closed
    /// form, a multisine by a table lookup).
    #[inline]
    pub fn value_a(&self, tick: u64) -> f64 {
        match self {
            Self::Sweep(c) => c.value_a(tick),
            Self::Multisine(m) => m.value_a(tick),
        }
    }
}

impl From<Chirp> for Excitation {
    fn from(c: Chirp) -> Self {
        Self::Sweep(c)
    }
}

impl From<Multisine> for Excitation {
    fn from(m: Multisine) -> Self {
        Self::Multisine(m)
    }
}
