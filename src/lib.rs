//! `bench`: real-time loop, chirp identification, recording and plotting for
//! the SR4DoF flexure motion stage of the reference thesis.
//!
//! The hardware sits behind [`bench_hal::Stage`]; the simulated plant
//! ([`bench_plant::sim::SimStage`]) is the default backend. The folders, from
//! the tick outwards: [`rt`] (loop, supervisor, backends), [`ident`]
//! (excitation, FRF), [`control`] (controllers, loop check), [`record`]
//! (MCAP topics, writer, reader), [`jobs`] (chirp and step runs),
//! [`daemon`] (`bench serve` and its client), [`live`] (the Foxglove live
//! view). The command line lives in the binary (`src/cli`).
#![warn(missing_docs)]

pub mod analysis;
pub mod campaign;
pub mod catalogue;
pub mod config;
pub mod control;
pub mod daemon;
pub mod design;
pub mod error;
pub mod ident;
pub mod input_file;
pub mod job_memory;
pub mod jobs;
pub mod live;
pub mod outputs;
pub mod plot;
pub mod record;
pub mod rt;
pub mod splitmix;
pub mod track;
pub mod upload;
pub mod vocab;
