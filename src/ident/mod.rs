//! Identification: the chirp excitation the loop plays, and the frequency
//! response estimated from a recorded run (the local polynomial method,
//! or H1 with coherence), with its 1σ per line.
//!
//! May use `bench_hal::model` (the lumped model, for comparison) and the
//! recording reader (an FRF from a recording, [`frf::read_frf`]); never the
//! loop or the daemon.
//!
//! Layer rule: may use `analysis`, `config`, `outputs`, `record`, `splitmix`.

/// A complex number of `f64` (spectra, frequency responses).
pub type C64 = nalgebra::Complex<f64>;

pub mod excitation;
pub mod fft;
pub mod frf;
pub mod lpm;
mod lsq;
pub mod modal_fit;
pub mod update;
pub mod verdict;
