//! Identification: the chirp excitation the loop plays, and the frequency
//! response (H1 estimator, coherence) estimated from a recorded run.
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
mod lsq;
pub mod modal_fit;
pub mod update;
pub mod verdict;
