//! `safety.max_overrun_s` replaced the tick count
//! `safety.max_consecutive_overruns`: a config that still has the old key is
//! refused naming it, with a hint naming the new one.

use bench::config::{BenchConfig, ConfigError};
use std::path::Path;

fn ch5_text() -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    std::fs::read_to_string(path).unwrap()
}

#[test]
fn the_old_overrun_count_is_refused_with_the_new_key_as_hint() {
    let text = ch5_text();
    assert!(text.contains("\n[safety]\n"));
    let old = text.replace("\n[safety]\n", "\n[safety]\nmax_consecutive_overruns = 5\n");
    let p = Path::new("old.toml");
    match BenchConfig::from_toml(&old, p).and_then(|c| c.validate(p)) {
        Err(ConfigError::Invalid { key, reason, .. }) => {
            assert_eq!(key, "safety.max_consecutive_overruns");
            assert!(reason.contains("safety.max_overrun_s"), "{reason}");
        }
        Err(e) => panic!("{e}"),
        Ok(()) => panic!("accepted"),
    }
}

fn info(period_ns: u64) -> bench_hal::DeviceInfo {
    bench_hal::DeviceInfo {
        name: "test".into(),
        clock: bench_hal::Clock::Host,
        period_ns,
        peak_current_a: 9.98,
        continuous_current_a: 2.34,
        probe_range_m: 1e-3,
        probe_lsb_m: 0.0,
        watchdog_s: None,
    }
}

/// The shipped config sets no stall bound of its own: the loop's applies
/// (closed loop), none in open loop.
#[test]
fn without_the_key_no_constant_bounds_a_stall() {
    let cfg = BenchConfig::from_toml(&ch5_text(), Path::new("ch5.toml")).unwrap();
    assert_eq!(cfg.safety.max_overrun_s, None);
    assert_eq!(cfg.safety.max_command_latency_s, None);
    let s = cfg.supervisor(&info(200_000));
    assert_eq!(s.max_missed_deadlines, u64::MAX);
    assert_eq!(s.max_late_commands, u64::MAX);
}

#[test]
fn the_overrun_bound_is_whole_periods_at_each_rate() {
    let text = ch5_text().replace("\n[safety]\n", "\n[safety]\nmax_overrun_s = 0.01\n");
    let cfg = BenchConfig::from_toml(&text, Path::new("ch5.toml")).unwrap();
    assert_eq!(cfg.safety.max_overrun_s, Some(10e-3));
    for (period_ns, periods) in [(200_000, 50), (100_000, 100), (50_000, 200)] {
        assert_eq!(
            cfg.supervisor(&info(period_ns)).max_missed_deadlines,
            periods
        );
    }
}
