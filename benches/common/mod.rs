//! What the benchmarks share: the shipped bench and the default chirp run
//! as `bench chirp --overwrite` does it.

use bench::config::BenchConfig;
use bench::jobs::chirp::{run_chirp, ChirpOptions, ChirpSummary};
use bench::outputs::{Existing, Origin, OutputPlan};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// The shipped Chapter 5 bench and its path.
pub fn shipped() -> (BenchConfig, PathBuf) {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    (BenchConfig::load(&p).unwrap(), p)
}

/// The default chirp on the simulator in virtual time, seed 1, its files
/// in `dir`.
pub fn default_chirp(dir: &Path) -> ChirpOptions {
    let (config, config_path) = shipped();
    ChirpOptions {
        config,
        config_path,
        out: dir.join("chirp.mcap"),
        frf_csv: dir.join("chirp.frf.csv"),
        plot: dir.join("chirp.bode.png"),
        bla_csv: None,
        realtime: false,
        pace: None,
        seed: 1,
        progress: false,
        backend: None,
        inject: None,
        catalogue: false,
    }
}

/// Runs `opts`, replacing its files from an earlier run.
pub fn run(opts: &ChirpOptions) -> ChirpSummary {
    let outputs = OutputPlan::new(Existing::Replace)
        .with_recording(&opts.out, Origin::Given)
        .with_output("frf_csv", &opts.frf_csv, Origin::Given)
        .with_output("plot", &opts.plot, Origin::Given);
    run_chirp(opts, outputs, Arc::new(AtomicBool::new(false)), None).unwrap()
}
