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
    assert!(text.contains("\nmax_overrun_s = "));
    let old = text.replace("\nmax_overrun_s = ", "\nmax_consecutive_overruns = 5\n#");
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

#[test]
fn the_overrun_bound_is_whole_periods_at_each_rate() {
    let text = ch5_text();
    let cfg = BenchConfig::from_toml(&text, Path::new("ch5.toml")).unwrap();
    assert_eq!(cfg.safety.max_overrun_s, 10e-3);
    for (period_ns, periods) in [(200_000, 50), (100_000, 100), (50_000, 200)] {
        let info = bench_hal::DeviceInfo {
            name: "test".into(),
            clock: bench_hal::Clock::Host,
            period_ns,
            peak_current_a: 9.98,
            continuous_current_a: 2.34,
            probe_range_m: 1e-3,
        };
        assert_eq!(cfg.supervisor(&info).max_missed_deadlines, periods);
    }
}
