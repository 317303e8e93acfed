//! The plant's tests: the SR4DoF model against the thesis and the
//! simulated stage against the model, one test binary with a module per
//! subject.

#[path = "../common/params.rs"]
mod common;

mod model;
mod sim;
