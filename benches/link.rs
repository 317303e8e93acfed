//! The serial link over a pseudo-terminal, host ↔ emulator (same process,
//! separate threads, the emulator at SCHED_FIFO when permitted):
//!
//! 1. round-trip latency host → emulator → host: a status request answered
//!    by a status frame (p50 / p99 / max, µs);
//! 2. the loop rates the serial path sustains: for each rate, 2 s of the
//!    host answering every sample ([`SerialStage`] read + write), counting
//!    sequence gaps and timeouts on the host and late commands (answer
//!    after the next sample) on the device.
//!
//! `cargo bench --bench link`. Not criterion: these are distributions and
//! counts, printed as a table.

use bench_devices::emulator::serial::{self as serial_emulator, Pty, SerialEmulatorOptions};
use bench_devices::emulator::{DeviceCore, EmulatorStatus};
use bench_hal::serial::{SerialConfig, SerialStage};
use bench_hal::{Command, Stage};
use bench_protocol::serial::{
    self as protocol, DeviceMessage, Frame, FrameReader, HostMessage, MAX_FRAME,
};
use std::io::{Read, Write};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn start(
    period_ns: u64,
) -> (
    String,
    Arc<AtomicBool>,
    Arc<EmulatorStatus>,
    std::thread::JoinHandle<()>,
) {
    let cfg = bench::config::BenchConfig::load(Path::new("bench-config/sr4dof-ch5.toml")).unwrap();
    let core = DeviceCore::new(cfg.sim_params(1), period_ns, 50_000_000).unwrap();
    let pty = Pty::open().unwrap();
    let path = pty.path().to_string();
    let stop = Arc::new(AtomicBool::new(false));
    let status = Arc::new(EmulatorStatus::default());
    let (s, st) = (Arc::clone(&stop), Arc::clone(&status));
    let opts = SerialEmulatorOptions {
        realtime_priority: Some(70),
        ..Default::default()
    };
    let t = std::thread::spawn(move || {
        let _ = serial_emulator::run(pty, core, &opts, &s, &st);
    });
    (path, stop, status, t)
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

fn round_trip() {
    let (path, stop, _st, t) = start(1_000_000);
    let mut port = serialport::new(&path, 921_600)
        .timeout(Duration::from_secs(1))
        .open_native()
        .unwrap();
    let mut frame = [0u8; MAX_FRAME];
    let n = protocol::encode(&HostMessage::StatusRequest, &mut frame);
    let mut reader = FrameReader::new();
    let mut buf = [0u8; 256];
    let mut rtt_us = Vec::new();
    for _ in 0..5000 {
        let t0 = Instant::now();
        port.write_all(&frame[..n]).unwrap();
        'wait: loop {
            let k = port.read(&mut buf).unwrap();
            for &b in &buf[..k] {
                if let Some(Frame::Bytes(f)) = reader.push(b) {
                    if let Ok(DeviceMessage::Status(_)) = protocol::decode::<DeviceMessage>(f) {
                        break 'wait;
                    }
                }
            }
        }
        rtt_us.push(t0.elapsed().as_secs_f64() * 1e6);
    }
    stop.store(true, Ordering::Relaxed);
    t.join().unwrap();
    rtt_us.sort_by(f64::total_cmp);
    println!(
        "round trip host → emulator → host over the pty, {} requests: p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs",
        rtt_us.len(),
        quantile(&rtt_us, 0.5),
        quantile(&rtt_us, 0.99),
        rtt_us.last().unwrap()
    );
}

fn sustained(rate_hz: f64) {
    let period_ns = (1e9 / rate_hz).round() as u64;
    let (path, stop, status, t) = start(period_ns);
    let mut stage = SerialStage::open(&SerialConfig {
        path,
        ..Default::default()
    })
    .unwrap();
    stage.configure(period_ns).unwrap();
    stage.enable().unwrap();
    let late0 = status.late_commands.load(Ordering::Relaxed);
    let ticks = (2.0 * rate_hz) as u64;
    let mut errors = 0;
    for _ in 0..ticks {
        match stage.read_sample() {
            Ok(s) => {
                let _ = stage.write_command(Command {
                    current_a: 0.01,
                    answers_seq: s.seq,
                });
            }
            Err(_) => errors += 1,
        }
    }
    let _ = stage.disable();
    let late = status.late_commands.load(Ordering::Relaxed) - late0;
    let st = stage.stats();
    drop(stage);
    stop.store(true, Ordering::Relaxed);
    t.join().unwrap();
    println!(
        "{rate_hz:>7.0} Hz: {ticks} samples, sequence gaps {}, missed {}, timeouts {errors}, largest backlog {}, late commands {late} ({:.2} %)",
        st.sequence_gaps,
        st.missed_samples,
        st.max_backlog,
        100.0 * late as f64 / ticks as f64
    );
}

fn main() {
    // The host side as `bench` runs it: SCHED_FIFO 80 and mlockall (when
    // permitted); the emulator thread at 70.
    for w in bench_hal::os::make_realtime(80, None) {
        println!("warning: {w}");
    }
    round_trip();
    for rate in [1000.0, 2000.0, 5000.0, 10_000.0, 20_000.0] {
        sustained(rate);
    }
}
