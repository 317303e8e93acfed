//! The emulated device core: watchdog, command checks, fault-injection
//! parsing.

use crate::common;

use bench_devices::emulator::{DeviceCore, LinkFault};
use bench_hal::Command;
use bench_plant::sim::SimParams;
use bench_protocol::DeviceFault;

fn params() -> SimParams {
    common::ch5_bench(0.08, 0.0, 1)
}

const PERIOD: u64 = 200_000;

#[test]
fn watchdog_drops_current_within_its_time_plus_one_period() {
    let wd = 5_000_000;
    let mut d = DeviceCore::new(params(), PERIOD, wd).unwrap();
    d.enable(0);
    let mut t = 0;
    let mut last_cmd = 0;
    // Fed for 10 ms.
    while t < 10_000_000 {
        t += PERIOD;
        d.tick(t);
        assert!(d.command(
            Command {
                current_a: 0.3,
                answers_seq: 0
            },
            t
        ));
        last_cmd = t;
    }
    assert_eq!(d.commanded_current_a(), 0.3);
    // Host goes quiet.
    let mut tripped_at = None;
    while t < 40_000_000 {
        t += PERIOD;
        let s = d.tick(t);
        if d.commanded_current_a() == 0.0 && tripped_at.is_none() {
            tripped_at = Some(t);
            assert!(s.flags.amplifier_fault && !s.flags.amplifier_enabled);
        }
    }
    let tripped_at = tripped_at.expect("watchdog never tripped");
    assert!(tripped_at - last_cmd > wd);
    assert!(tripped_at - last_cmd <= wd + PERIOD);
    // Latched: commands do not bring the current back.
    assert!(!d.command(
        Command {
            current_a: 0.3,
            answers_seq: 0
        },
        t
    ));
    assert_eq!(d.fault(), Some(DeviceFault::Watchdog));
    assert_eq!(d.commanded_current_a(), 0.0);
    // Re-enable clears it.
    d.enable(t);
    assert_eq!(d.fault(), None);
}

#[test]
fn link_faults_parse() {
    assert_eq!(
        LinkFault::parse("bitflip:2x10"),
        Ok(LinkFault::BitFlips {
            bits: 2,
            frames: 10
        })
    );
    assert_eq!(
        LinkFault::parse("drop:5"),
        Ok(LinkFault::Drop { frames: 5 })
    );
    assert_eq!(
        LinkFault::parse("stall:0.5"),
        Ok(LinkFault::Stall { duration_s: 0.5 })
    );
    assert_eq!(LinkFault::parse("disconnect"), Ok(LinkFault::Disconnect));
    assert!(LinkFault::parse("stall:-1").unwrap_err().contains("stall"));
    assert!(LinkFault::parse("melt").unwrap_err().contains("unknown"));
}

#[test]
fn non_finite_command_latches_bad_command() {
    let mut d = DeviceCore::new(params(), PERIOD, 5_000_000).unwrap();
    d.enable(0);
    assert!(!d.command(
        Command {
            current_a: f64::NAN,
            answers_seq: 0
        },
        0
    ));
    assert_eq!(d.fault(), Some(DeviceFault::BadCommand));
    assert!(!d.is_enabled());
}

#[test]
fn check_watchdog_trips_without_advancing_the_plant() {
    let mut d = DeviceCore::new(params(), PERIOD, 1_000_000).unwrap();
    d.enable(0);
    let s0 = d.tick(PERIOD);
    assert!(!d.check_watchdog(1_000_000));
    assert!(d.check_watchdog(1_000_001));
    assert_eq!(d.fault(), Some(DeviceFault::Watchdog));
    assert_eq!(d.commanded_current_a(), 0.0);
    // The plant did not move on: the next tick is the next sample.
    assert_eq!(d.tick(2 * PERIOD).seq, s0.seq + 1);
}
