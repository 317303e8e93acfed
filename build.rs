//! Probes the build machine for what a test needs and the machine may lack,
//! so that a test that cannot run here is reported as ignored with its
//! reason (`cargo test` lists it), never passed without its assertions:
//!
//! - `cfg(bench_root)`: the build runs as root (effective uid 0), which the
//!   tests that mount a small tmpfs to fill a disk need
//!   (`tests/outputs.rs`).
//!
//! The probe runs when this file changes (`touch build.rs` after changing
//! the user that builds).

fn main() {
    println!("cargo::rustc-check-cfg=cfg(bench_root)");
    println!("cargo::rerun-if-changed=build.rs");
    let root = std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("Uid:"))
                .and_then(|l| l.split_whitespace().nth(2).map(|e| e == "0"))
        })
        .unwrap_or(false);
    if root {
        println!("cargo::rustc-cfg=bench_root");
    }
}
