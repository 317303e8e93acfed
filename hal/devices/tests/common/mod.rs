//! What the device tests share: one rig at a time, the counting
//! allocator, the watchdog wait, the host's stalls, and the thesis'
//! parameter sets (the plant's tests' own, `hal/plant/tests/common`).
#![allow(dead_code)]

pub mod alloc;
/// The machine's own stalls, told from the code's: one file for the HAL's
/// tests and the application's.
#[path = "../../../../tests/common/host_stall.rs"]
pub mod host_stall;
/// The Table 2-1 mechanism and the Chapter 5 bench.
#[path = "../../../plant/tests/common/params.rs"]
mod params;
mod watchdog;

/// One rig at a time in this process (the serial, CAN and EtherCAT
/// emulators with their hosts): their timing checks should not compete
/// for the two cores with another rig (two serial emulator tests beside
/// each other and the servers lane missed their device-time bounds by
/// 3 ms, one in each of two CI runs), and one EtherCAT master per
/// process.
pub fn one_rig_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static RIG: std::sync::Mutex<()> = std::sync::Mutex::new(());
    RIG.lock().unwrap_or_else(|e| e.into_inner())
}
#[allow(unused_imports)] // not every test file waits for a watchdog
pub use watchdog::{wait_for_watchdog_trip, WatchdogTrip};

pub use params::*;
