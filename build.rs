//! Probes the build machine for what a test needs and the machine may lack,
//! so that a test that cannot run here is reported as ignored with its
//! reason (`cargo test` lists it), never passed without its assertions:
//!
//! - `cfg(bench_root)`: the build runs as root (effective uid 0), which the
//!   tests that mount a small tmpfs to fill a disk need
//!   (`tests/cli/outputs.rs`).
//!
//! - `cfg(bench_has_bash)`, `cfg(bench_has_man)`: `bash`, and `groff` or
//!   `man`, are on `PATH` (`tests/cli/first_hour.rs`: the completion script
//!   checked with `bash -n`, the man page rendered).
//!
//! - `cfg(bench_has_vcan0)`: a virtual CAN interface `vcan0` exists
//!   (`tests/cli/readme_examples.rs`: the README's CAN examples).
//!
//! For the release profile it also has the linker compress the binary's
//! debug sections (its line tables), which halves the installed binary.
//!
//! The probe runs when this file changes (`touch build.rs` after changing
//! the user that builds or installing those programs).

fn on_path(program: &str) -> bool {
    std::env::var_os("PATH").is_some_and(|paths| {
        std::env::split_paths(&paths).any(|dir| {
            use std::os::unix::fs::PermissionsExt;
            std::fs::metadata(dir.join(program))
                .is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
        })
    })
}

fn main() {
    println!(
        "cargo::rustc-check-cfg=cfg(bench_root, bench_has_bash, bench_has_man, bench_has_vcan0)"
    );
    if std::path::Path::new("/sys/class/net/vcan0").exists() {
        println!("cargo::rustc-cfg=bench_has_vcan0");
    }
    if on_path("bash") {
        println!("cargo::rustc-cfg=bench_has_bash");
    }
    if on_path("groff") || on_path("man") {
        println!("cargo::rustc-cfg=bench_has_man");
    }
    println!("cargo::rerun-if-changed=build.rs");
    // The release binary's debug sections (the workspace's line tables,
    // the release profile's only debug information) compressed by the
    // linker (zlib, SHF_COMPRESSED: GNU ld and lld both write it): 83 MB
    // to about 45 MB, and a panic's backtrace still names file and line
    // (std's symbolizer decompresses them; `benches/sizes.sh`).
    if std::env::var("PROFILE").as_deref() == Ok("release") {
        println!("cargo::rustc-link-arg-bins=-Wl,--compress-debug-sections=zlib");
    }
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
