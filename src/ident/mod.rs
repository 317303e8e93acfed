//! Identification: the chirp excitation the loop plays, and the frequency
//! response (H1 estimator, coherence) estimated from a recorded run.
//!
//! May use `bench_hal::model` (the lumped model, for comparison); never the
//! loop, the recorder or the daemon.

pub mod excitation;
pub mod fft;
pub mod frf;
mod lsq;
pub mod modal_fit;
pub mod update;
pub mod verdict;
