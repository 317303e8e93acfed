//! `bench-plant`: the flexure stage the `bench` loop runs when there is no
//! bench. [`model`] is the SR4DoF lumped model of the thesis (Chapter 2,
//! Eq. 2-5: masses, flexure stiffnesses, Rayleigh damping, operating
//! point, mass asymmetry) with its modes, residues and zeros; [`sim`] is
//! the simulated stage ([`sim::SimStage`], a [`bench_hal::Stage`] like any
//! backend, not a test double) that runs the model discretised exactly
//! (zero-order hold) at the loop period, with the amplifier's and the
//! probe's limits and noise.
//!
//! Analytic and light: it depends on the HAL's trait and errors only
//! (`bench-hal` without its host backends), so a change to the model
//! builds and tests on its own (`cargo test -p bench-plant`).
#![warn(missing_docs)]

pub mod model;
pub mod sim;
