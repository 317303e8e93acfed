//! The library's integration tests: the loop, identification, design and
//! the layout, called as a library (no `bench` process), one test binary
//! (one link of the crate graph) with a module per subject.

#[path = "../common/mod.rs"]
mod common;
#[path = "../common/daemon.rs"]
mod daemon_fixtures;

mod alloc;
mod analysis_reference;
mod bla_statistics;
mod design;
mod layout;
mod loop_reference;
mod overrun_key;
mod plots;
mod shared_flags;
mod track_reference;
