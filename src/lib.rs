//! `bench`: real-time loop, chirp identification, recording and plotting for
//! the SR4DoF flexure motion stage of the reference thesis.
//!
//! The hardware sits behind [`bench_hal::Stage`]; the simulated plant
//! ([`bench_hal::sim::SimStage`]) is the default backend.
#![warn(missing_docs)]

pub mod backend;
pub mod chirp;
pub mod client;
pub mod config;
pub mod control;
pub mod control_run;
pub mod daemon;
pub mod excitation;
pub mod loopcheck;
pub mod plot;
pub mod record;
pub mod records;
pub mod rt;
pub mod session;
pub mod supervisor;
pub mod sysid;
pub mod timing;
