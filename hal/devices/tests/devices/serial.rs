//! The serial backend against the serial emulator over a real
//! pseudo-terminal: handshake, round trip, watchdog, link faults, bad input.

use crate::common;

use bench_devices::emulator::serial::{self as serial_emulator, Pty, SerialEmulatorOptions};
use bench_devices::emulator::{DeviceCore, EmulatorStatus, LinkFault, ScheduledLinkFault};
use bench_hal::serial::{SerialConfig, SerialStage};
use bench_hal::{Command, Error as _, ErrorKind, Stage};
use bench_plant::sim::SimParams;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

const PERIOD_NS: u64 = 1_000_000; // 1 kHz: robust on a loaded 2-core machine
const WATCHDOG_NS: u64 = 20_000_000;

fn params() -> SimParams {
    common::ch5_bench(0.08, 0.0, 7)
}

struct Emulator {
    path: String,
    stop: Arc<AtomicBool>,
    status: Arc<EmulatorStatus>,
    thread: Option<JoinHandle<std::io::Result<()>>>,
}

impl Emulator {
    fn start(opts: SerialEmulatorOptions) -> Self {
        let pty = Pty::open().expect("pty");
        let path = pty.path().to_string();
        let core = DeviceCore::new(params(), PERIOD_NS, WATCHDOG_NS).unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let status = Arc::new(EmulatorStatus::default());
        let (s, st) = (Arc::clone(&stop), Arc::clone(&status));
        let thread = std::thread::spawn(move || serial_emulator::run(pty, core, &opts, &s, &st));
        Self {
            path,
            stop,
            status,
            thread: Some(thread),
        }
    }

    /// Generous sample timeout: the test threads are not real-time and
    /// share two cores with the rest of the test suite.
    fn config(&self) -> SerialConfig {
        SerialConfig {
            path: self.path.clone(),
            sample_timeout_periods: 20.0,
            ..SerialConfig::default()
        }
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

fn wait_until(timeout: Duration, mut f: impl FnMut() -> bool) -> bool {
    let t0 = Instant::now();
    while t0.elapsed() < timeout {
        if f() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    false
}

#[test]
fn round_trip_moves_the_stage_and_disable_leaves_zero_amps() {
    let _rig = common::one_rig_at_a_time();
    let emu = Emulator::start(SerialEmulatorOptions::default());
    let mut stage = SerialStage::open(&emu.config()).unwrap();
    let info = stage.configure(PERIOD_NS).unwrap();
    assert_eq!(info.period_ns, PERIOD_NS);
    assert_eq!(info.peak_current_a as f32, 9.98f32);
    assert!(
        matches!(info.clock, bench_hal::Clock::Device { rate_hz } if (rate_hz - 1000.0).abs() < 1e-9)
    );
    stage.enable().unwrap();
    let mut last_seq = None;
    let mut x_end = 0.0;
    // 0.2 A for 50 ms: x1 moves positive (force along +X); the rigid-body
    // mode is at 29 Hz, so it is still on its first swing.
    for _ in 0..50 {
        let s = stage.read_sample().unwrap();
        if let Some(l) = last_seq {
            assert!(s.seq > l);
        }
        last_seq = Some(s.seq);
        x_end = s.position_m;
        stage
            .write_command(Command {
                current_a: 0.2,
                answers_seq: s.seq,
            })
            .unwrap();
    }
    assert!(x_end > 1e-7, "x1 = {x_end} m after 50 ms at 0.2 A");
    assert!((emu.status.commanded_current_a() - 0.2).abs() < 1e-6);
    stage.disable().unwrap();
    assert!(wait_until(Duration::from_secs(1), || emu
        .status
        .commanded_current_a()
        == 0.0
        && !emu.status.enabled.load(Ordering::Relaxed)));
    assert_eq!(emu.status.fault_code.load(Ordering::Relaxed), 0);
    let st = stage.stats();
    assert_eq!(st.crc_errors, 0);
}

#[test]
fn quiet_host_trips_the_watchdog_within_its_time_plus_one_period() {
    let _rig = common::one_rig_at_a_time();
    let emu = Emulator::start(SerialEmulatorOptions::default());
    let mut stage = SerialStage::open(&emu.config()).unwrap();
    stage.configure(PERIOD_NS).unwrap();
    stage.enable().unwrap();
    for _ in 0..20 {
        let s = stage.read_sample().unwrap();
        stage
            .write_command(Command {
                current_a: 0.1,
                answers_seq: s.seq,
            })
            .unwrap();
    }
    // The host goes quiet (no disable, no commands).
    let common::WatchdogTrip {
        last_command_ns: last,
        trip_ns: trip,
        deadline_ns: deadline,
    } = common::wait_for_watchdog_trip(&emu.status, Duration::from_secs(2), "serial device");
    // In device time (the scheduled time of the tick that tripped): never
    // before the watchdog time, and within it plus one period, plus the
    // ticks the emulator's thread skipped if the VM preempted it then (as a
    // device whose timer interrupt was masked would trip late).
    let dt = deadline.saturating_sub(last);
    let skipped_ns = emu.status.max_tick_lateness_ns.load(Ordering::Relaxed);
    let skipped_ns = skipped_ns.div_ceil(PERIOD_NS) * PERIOD_NS;
    assert!(
        dt + PERIOD_NS > WATCHDOG_NS && dt <= WATCHDOG_NS + PERIOD_NS + skipped_ns,
        "tripped at the tick {dt} ns after the last command ({skipped_ns} ns of ticks skipped)"
    );
    // In wall time, plus whatever the VM's scheduler adds (stalls of tens of
    // ms happen on a shared 2-core VM).
    assert!(
        trip - last <= WATCHDOG_NS + PERIOD_NS + 100_000_000,
        "tripped {} ns after the last command",
        trip - last
    );
    assert_eq!(emu.status.commanded_current_a(), 0.0);
    // The host hears of it from the first sample after the trip (after the
    // ones still queued from before): a device fault.
    let e = (0..1000)
        .find_map(|_| stage.read_sample().err())
        .expect("no device fault reported");
    assert_eq!(e.kind(), ErrorKind::AmplifierFault, "{e}");
    // Latched: commands do not bring the current back.
    let _ = stage.write_command(Command {
        current_a: 0.1,
        answers_seq: 0,
    });
    std::thread::sleep(Duration::from_millis(20));
    assert_eq!(emu.status.commanded_current_a(), 0.0);
    assert_eq!(emu.status.fault_code.load(Ordering::Relaxed), 1);
}

#[test]
fn another_protocol_version_is_refused() {
    let _rig = common::one_rig_at_a_time();
    let emu = Emulator::start(SerialEmulatorOptions {
        protocol_version: 2,
        ..Default::default()
    });
    let mut stage = SerialStage::open(&emu.config()).unwrap();
    let e = stage.configure(PERIOD_NS).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Protocol);
    assert!(e.to_string().contains("version 2"), "{e}");
    assert!(!emu.status.enabled.load(Ordering::Relaxed));
}

#[test]
fn another_rate_is_refused_with_both_rates() {
    let _rig = common::one_rig_at_a_time();
    let emu = Emulator::start(SerialEmulatorOptions::default());
    let mut stage = SerialStage::open(&emu.config()).unwrap();
    let e = stage.configure(200_000).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Config);
    let msg = e.to_string();
    assert!(
        msg.contains("1000.0 Hz") && msg.contains("5000.0 Hz"),
        "{msg}"
    );
}

#[test]
fn a_busy_port_and_a_missing_path_are_refused() {
    let _rig = common::one_rig_at_a_time();
    let emu = Emulator::start(SerialEmulatorOptions::default());
    let _first = SerialStage::open(&emu.config()).unwrap();
    let e = SerialStage::open(&emu.config()).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Busy, "{e}");
    let e = SerialStage::open(&SerialConfig {
        path: "/dev/does-not-exist-bench".into(),
        ..SerialConfig::default()
    })
    .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::NotFound);
    assert!(e.to_string().contains("/dev/does-not-exist-bench"));
}

#[test]
fn a_silent_peer_is_not_a_device() {
    let _rig = common::one_rig_at_a_time();
    // A pty with nobody on the other side answers nothing.
    let pty = Pty::open().unwrap();
    let mut stage = SerialStage::open(&SerialConfig {
        path: pty.path().into(),
        handshake_timeout_ms: 100.0,
        ..SerialConfig::default()
    })
    .unwrap();
    let e = stage.configure(PERIOD_NS).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Protocol);
    assert!(e.to_string().contains("no protocol hello"), "{e}");
}

/// Runs the host at the device's pace until `n` reads failed, returning the
/// failures' kinds.
fn run_until_errors(stage: &mut SerialStage, n: usize, limit: usize) -> Vec<ErrorKind> {
    let mut errors = Vec::new();
    for _ in 0..limit {
        match stage.read_sample() {
            Ok(s) => {
                let _ = stage.write_command(Command {
                    current_a: 0.0,
                    answers_seq: s.seq,
                });
            }
            Err(e) => {
                errors.push(e.kind());
                if errors.len() >= n || e.kind() == ErrorKind::Link {
                    break;
                }
            }
        }
    }
    errors
}

#[test]
fn link_faults_surface_as_their_kinds() {
    let _rig = common::one_rig_at_a_time();
    // Stall: timeouts.
    let emu = Emulator::start(SerialEmulatorOptions {
        link_faults: vec![ScheduledLinkFault {
            at_s: 0.3,
            kind: LinkFault::Stall { duration_s: 0.5 },
        }],
        ..Default::default()
    });
    let mut stage = SerialStage::open(&emu.config()).unwrap();
    stage.configure(PERIOD_NS).unwrap();
    stage.enable().unwrap();
    let errs = run_until_errors(&mut stage, 3, 5000);
    assert_eq!(errs, vec![ErrorKind::Timeout; 3]);
    drop(stage);
    drop(emu);

    // Bit flips: CRC failures, counted.
    let emu = Emulator::start(SerialEmulatorOptions {
        link_faults: vec![ScheduledLinkFault {
            at_s: 0.3,
            kind: LinkFault::BitFlips {
                bits: 1,
                frames: 1000,
            },
        }],
        ..Default::default()
    });
    let mut stage = SerialStage::open(&emu.config()).unwrap();
    stage.configure(PERIOD_NS).unwrap();
    stage.enable().unwrap();
    let errs = run_until_errors(&mut stage, 3, 5000);
    assert_eq!(errs.len(), 3);
    assert!(
        errs.iter()
            .all(|k| *k == ErrorKind::Crc || *k == ErrorKind::Timeout),
        "{errs:?}"
    );
    assert!(
        stage.stats().crc_errors + stage.stats().frame_errors >= 3,
        "{errs:?} {:?}",
        stage.stats()
    );
    drop(stage);
    drop(emu);

    // Drop: a sequence gap of that size.
    let emu = Emulator::start(SerialEmulatorOptions {
        link_faults: vec![ScheduledLinkFault {
            at_s: 0.3,
            kind: LinkFault::Drop { frames: 10 },
        }],
        ..Default::default()
    });
    let mut stage = SerialStage::open(&emu.config()).unwrap();
    stage.configure(PERIOD_NS).unwrap();
    stage.enable().unwrap();
    let mut gap = 0;
    let mut last = None;
    for _ in 0..800 {
        match stage.read_sample() {
            Ok(s) => {
                if let Some(l) = last {
                    gap = gap.max(s.seq - l - 1);
                }
                last = Some(s.seq);
                let _ = stage.write_command(Command {
                    current_a: 0.0,
                    answers_seq: s.seq,
                });
            }
            Err(e) => assert_eq!(e.kind(), ErrorKind::Timeout),
        }
    }
    assert!(gap >= 10, "largest gap {gap}");
    assert!(stage.stats().missed_samples >= 10);
    drop(stage);
    drop(emu);

    // Delay: samples still come, in order, later (no errors).
    let emu = Emulator::start(SerialEmulatorOptions {
        link_faults: vec![ScheduledLinkFault {
            at_s: 0.0,
            kind: LinkFault::Delay { delay_s: 0.01 },
        }],
        ..Default::default()
    });
    let mut stage = SerialStage::open(&emu.config()).unwrap();
    stage.configure(PERIOD_NS).unwrap();
    stage.enable().unwrap();
    let mut last = None;
    for _ in 0..200 {
        let s = stage.read_sample().unwrap();
        if let Some(l) = last {
            assert_eq!(s.seq, l + 1);
        }
        last = Some(s.seq);
        stage
            .write_command(Command {
                current_a: 0.01,
                answers_seq: s.seq,
            })
            .unwrap();
    }
    // The commands answer samples 10 ms old: the device counts them late.
    let late = emu.status.late_commands.load(Ordering::Relaxed);
    assert!(late >= 150, "{late} late commands of 200");
    drop(stage);
    drop(emu);

    // Disconnect: a link error at once.
    let emu = Emulator::start(SerialEmulatorOptions {
        link_faults: vec![ScheduledLinkFault {
            at_s: 0.3,
            kind: LinkFault::Disconnect,
        }],
        ..Default::default()
    });
    let mut stage = SerialStage::open(&emu.config()).unwrap();
    stage.configure(PERIOD_NS).unwrap();
    stage.enable().unwrap();
    let errs = run_until_errors(&mut stage, 100, 5000);
    assert_eq!(errs.last(), Some(&ErrorKind::Link), "{errs:?}");
    // Disable still returns (best effort) and does not hang.
    let _ = stage.disable();
}
