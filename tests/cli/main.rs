//! The tests that run the `bench` process (the command line and the
//! daemon on its socket) and read what it writes: one test binary with a
//! module per command or subject.

mod analyze;
mod campaign;
mod campaign_hardware;
mod chirp;
mod cli;
#[path = "../common/mod.rs"]
mod common;
mod config_bounds;
mod config_mutation;
mod control;
mod corrupt_frames;
mod daemon;
mod daemon_cli;
#[path = "../common/daemon.rs"]
mod daemon_fixtures;
mod daemon_hostile;
mod daemon_jobs;
mod design_cli;
mod design_limit;
mod disk_full;
mod docs_reference;
mod export;
mod first_hour;
mod fit;
mod flag_bounds;
mod foxglove_layout;
mod hardware;
mod inject_at_zero;
mod limits;
mod logging;
mod lpm;
mod mode_count;
mod model_export;
mod multisine;
#[path = "../common/outliers.rs"]
mod outliers;
mod outputs;
mod pace;
mod plot_overlay;
mod readme_examples;
mod real_links;
mod recover;
mod schemas;
mod stalls;
mod test_command;
mod track;
mod track_daemon;
mod track_trajectory;
mod uncertainty;
mod update;
mod verify;
