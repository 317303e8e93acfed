//! Waiting for a device emulator's watchdog: shared by the hal tests
//! (`hal/devices/tests/common`) and the process-boundary tests (`tests/common`
//! includes this file by path).

/// When a device emulator's watchdog dropped the current, read from its
/// [`EmulatorStatus`](bench_devices::emulator::EmulatorStatus): host
/// `CLOCK_MONOTONIC`, ns.
#[derive(Debug, Clone, Copy)]
pub struct WatchdogTrip {
    /// The last command (output write) the device took.
    pub last_command_ns: u64,
    /// When the device's thread tripped (0 A).
    pub trip_ns: u64,
    /// When the watchdog was due: the last command plus its time, in the
    /// device's schedule.
    pub deadline_ns: u64,
}

/// Waits (polling every millisecond) until the device behind `status`
/// has tripped its watchdog, at most `timeout`; panics naming the device
/// if it never does.
pub fn wait_for_watchdog_trip(
    status: &bench_devices::emulator::EmulatorStatus,
    timeout: std::time::Duration,
    device: &str,
) -> WatchdogTrip {
    use std::sync::atomic::Ordering;
    let t0 = std::time::Instant::now();
    while status.watchdog_trip_mono_ns.load(Ordering::Acquire) == 0 {
        assert!(
            t0.elapsed() < timeout,
            "the {device}'s watchdog never tripped within {timeout:?}"
        );
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    WatchdogTrip {
        last_command_ns: status.last_command_mono_ns.load(Ordering::Acquire),
        trip_ns: status.watchdog_trip_mono_ns.load(Ordering::Acquire),
        deadline_ns: status
            .watchdog_trip_deadline_mono_ns
            .load(Ordering::Acquire),
    }
}
