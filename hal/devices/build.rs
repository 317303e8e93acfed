//! Probes the build machine for what a test needs and the machine may lack,
//! so that a test that cannot run here is reported as ignored with its
//! reason (`cargo test` lists it), never passed without its assertions:
//!
//! - `cfg(vcan0)`: a virtual CAN interface `vcan0` exists
//!   (`tests/devices/can.rs::round_trip_on_vcan0`).
//!
//! The probe runs when this file changes; after creating `vcan0`
//! (`ip link add vcan0 type vcan && ip link set up vcan0`), `touch
//! hal/devices/build.rs` to run it again.

fn main() {
    println!("cargo::rustc-check-cfg=cfg(vcan0)");
    println!("cargo::rerun-if-changed=build.rs");
    if std::path::Path::new("/sys/class/net/vcan0").exists() {
        println!("cargo::rustc-cfg=vcan0");
    }
}
