//! The serial DAQ emulator (the code `bench emulate serial` runs) on a
//! pseudo-terminal, in the test process, for the tests that drive the
//! `bench` binary over the serial backend and watch the device's state.

use bench::config::BenchConfig;
use bench_devices::emulator::serial::{self as serial_emulator, Pty, SerialEmulatorOptions};
use bench_devices::emulator::{DeviceCore, EmulatorStatus, ScheduledLinkFault};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

/// A running emulator; stopped on drop.
pub struct Emulator {
    pub path: String,
    pub stop: Arc<AtomicBool>,
    pub status: Arc<EmulatorStatus>,
    pub period_ns: u64,
    pub watchdog_ns: u64,
    thread: Option<JoinHandle<std::io::Result<()>>>,
}

impl Emulator {
    /// The device of `config`, as `bench emulate serial --config` runs it.
    pub fn start(config: &Path, faults: Vec<ScheduledLinkFault>, version: Option<u16>) -> Self {
        Self::start_with(config, faults, version, false)
    }

    /// In lockstep mode (the comparisons with the direct simulator).
    pub fn lockstep(config: &Path) -> Self {
        Self::start_with(config, vec![], None, true)
    }

    pub fn start_with(
        config: &Path,
        faults: Vec<ScheduledLinkFault>,
        version: Option<u16>,
        lockstep: bool,
    ) -> Self {
        Self::start_announcing(config, faults, version, lockstep, None)
    }

    /// As [`Self::start_with`], announcing `announce` (peak, continuous
    /// current, A) in its hello instead of its config's.
    pub fn start_announcing(
        config: &Path,
        faults: Vec<ScheduledLinkFault>,
        version: Option<u16>,
        lockstep: bool,
        announce: Option<(f32, f32)>,
    ) -> Self {
        let cfg = BenchConfig::load(config).unwrap();
        let watchdog_ns = (cfg.emulator.watchdog_ms * 1e6) as u64;
        let core = DeviceCore::new(
            cfg.sim_params(cfg.sim.seed),
            cfg.loop_.period_ns(),
            watchdog_ns,
        )
        .unwrap();
        let pty = Pty::open().unwrap();
        let path = pty.path().to_string();
        let opts = SerialEmulatorOptions {
            protocol_version: version.unwrap_or(bench_protocol::serial::VERSION),
            position_lsb_m: cfg.emulator.position_lsb_m,
            link_faults: faults,
            seed: 1,
            realtime_priority: Some(cfg.emulator.priority),
            lockstep,
            announce_currents_a: announce,
        };
        let stop = Arc::new(AtomicBool::new(false));
        let status = Arc::new(EmulatorStatus::default());
        let (s, st) = (Arc::clone(&stop), Arc::clone(&status));
        let thread = std::thread::spawn(move || serial_emulator::run(pty, core, &opts, &s, &st));
        Self {
            path,
            stop,
            status,
            period_ns: cfg.loop_.period_ns(),
            watchdog_ns,
            thread: Some(thread),
        }
    }

    pub fn backend(&self) -> String {
        format!("serial:{}", self.path)
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
