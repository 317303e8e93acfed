//! Identification: the excitation the loop plays (a chirp, or a periodic
//! multisine), and the frequency response estimated from a recorded run
//! with its 1σ per line (the local polynomial method, or H1 with
//! coherence, from a chirp; the best linear approximation with its noise
//! and nonlinear distortion from a multisine).
//!
//! May use `bench_plant::model` (the lumped model, for comparison) and the
//! recording reader (an FRF from a recording, [`frf::read_frf`]); never the
//! loop or the daemon.
//!
//! Layer rule: may use `analysis`, `config`, `outputs`, `record`, `splitmix`.

/// A complex number of `f64` (spectra, frequency responses).
pub type C64 = nalgebra::Complex<f64>;

pub mod bla;
pub mod chirp;
pub mod excitation;
pub mod export;
pub mod fft;
pub mod frf;
pub mod lpm;
mod lsq;
pub mod modal_fit;
pub mod multisine;
pub mod update;
pub mod verdict;
