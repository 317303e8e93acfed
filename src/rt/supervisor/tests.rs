use super::*;
use bench_hal::SampleFlags;

fn config() -> SupervisorConfig {
    SupervisorConfig {
        position_limit_m: 0.8e-3,
        peak_current_a: 9.98,
        max_missed_deadlines: 3,
        max_missed_samples: 3,
        max_position_step_m: 50e-6,
        max_late_commands: 10,
        continuous_current_a: 2.34,
        i2t_peak_duration_s: 1.0,
        period_s: 2e-4,
        reach: crate::rt::supervisor::ReachEnvelope::NONE,
        watchdog_s: None,
        probe: ProbeValidity::OFF,
    }
}

fn sup() -> Supervisor {
    let mut s = Supervisor::new(config());
    s.enabled();
    s.running();
    s
}

fn sample(x: f64, oor: bool) -> Sample {
    seq_sample(0, x, oor)
}

/// A silent link (reads that time out) is judged by time when the
/// device announced its watchdog: the watchdog between jobs and in open
/// loop, the job's stall bound while running in closed loop (here 10
/// periods, 2 ms), never by the count of timeouts; without a watchdog,
/// each timeout is a missing sample (K = 3).
#[test]
fn a_silent_link_is_judged_by_how_long_it_was_silent() {
    let timeout = |s: &mut Supervisor, silent_s: f64| {
        s.hal_error(HalCall::ReadSample, ErrorKind::Timeout, silent_s)
    };
    let watchdog = SupervisorConfig {
        watchdog_s: Some(50e-3),
        ..config()
    };
    // Idle (disabled): only the watchdog; many timeouts below it are fine.
    let mut s = Supervisor::new(watchdog);
    for i in 1..=9 {
        assert_eq!(
            timeout(&mut s, f64::from(i) * 5e-3),
            HalVerdict::SampleMissing { tripped: false }
        );
    }
    assert_eq!(
        timeout(&mut s, 50.1e-3),
        HalVerdict::SampleMissing { tripped: true }
    );
    assert_eq!(s.fault(), Some((FaultKind::Link, 50.1e-3)));
    assert_eq!(s.stall_bound().map(|b| b.1), Some(StallRule::Watchdog));
    // A sample ends the silence: the count starts again.
    let mut s = Supervisor::new(watchdog);
    timeout(&mut s, 40e-3);
    assert_eq!(s.check_sample(&seq_sample(1, 0.0, false)), None);
    assert_eq!(
        timeout(&mut s, 40e-3),
        HalVerdict::SampleMissing { tripped: false }
    );
    // Running under a closed loop's bound of 10 periods (2 ms).
    let mut s = Supervisor::new(watchdog);
    s.enabled();
    s.running();
    assert_eq!(
        timeout(&mut s, 2e-3),
        HalVerdict::SampleMissing { tripped: false }
    );
    assert_eq!(
        timeout(&mut s, 2.1e-3),
        HalVerdict::SampleMissing { tripped: true }
    );
    assert_eq!(
        s.stall_bound().map(|b| (b.0, b.1)),
        Some((2e-3, StallRule::Bound))
    );
    // Open loop (no bound): the watchdog.
    let mut s = Supervisor::new(SupervisorConfig {
        max_late_commands: u64::MAX,
        ..watchdog
    });
    s.enabled();
    s.running();
    assert_eq!(
        timeout(&mut s, 45e-3),
        HalVerdict::SampleMissing { tripped: false }
    );
    // No watchdog: the fourth timeout in a row is K + 1 missing samples.
    let mut s = sup();
    for _ in 0..3 {
        assert_eq!(
            timeout(&mut s, 1e-3),
            HalVerdict::SampleMissing { tripped: false }
        );
    }
    assert_eq!(
        timeout(&mut s, 1e-3),
        HalVerdict::SampleMissing { tripped: true }
    );
    assert_eq!(s.fault(), Some((FaultKind::Link, 4.0)));
}

fn seq_sample(seq: u64, x: f64, oor: bool) -> Sample {
    Sample {
        seq,
        device_time_ns: 0,
        position_m: x,
        measured_current_a: f64::NAN,
        flags: SampleFlags {
            out_of_range: oor,
            ..Default::default()
        },
    }
}

fn late_sample(seq: u64, late: bool) -> Sample {
    let mut s = seq_sample(seq, 0.0, false);
    s.flags.command_late = late;
    s
}

/// N late commands in a row (N = the periods in
/// `max_command_latency_s`, 10 here) pass, N + 1 trip `link_latency`
/// with the time run on late commands; one on-time command resets the
/// count, and a gap of late samples counts its missing ticks.
#[test]
fn more_than_the_bound_of_late_commands_in_a_row_is_the_latency_fault() {
    let mut sv = sup();
    let mut seq = 0;
    for _ in 0..10 {
        assert_eq!(sv.check_sample(&late_sample(seq, true)), None);
        seq += 1;
    }
    // One in time: the count starts again.
    assert_eq!(sv.check_sample(&late_sample(seq, false)), None);
    seq += 1;
    for _ in 0..10 {
        assert_eq!(sv.check_sample(&late_sample(seq, true)), None);
        seq += 1;
    }
    assert_eq!(
        sv.check_sample(&late_sample(seq, true)),
        Some(FaultKind::LinkLatency)
    );
    let (kind, value) = sv.fault().unwrap();
    assert_eq!(kind, FaultKind::LinkLatency);
    assert!((value - 11.0 * 2e-4).abs() < 1e-12, "{value}");
    assert_eq!(sv.command(1.0), (0.0, None));
    // A gap of 2 between late samples counts 3 ticks late.
    let mut sv = sup();
    for seq in [0, 3, 6, 9] {
        assert_eq!(sv.check_sample(&late_sample(seq, true)), None);
    }
    assert_eq!(
        sv.check_sample(&late_sample(12, true)),
        Some(FaultKind::LinkLatency)
    );
}

#[test]
fn faults_latch_and_zero_the_command() {
    for (x, oor, kind) in [
        (f64::NAN, false, FaultKind::ProbeNotFinite),
        (f64::INFINITY, false, FaultKind::ProbeNotFinite),
        (1e-3, true, FaultKind::ProbeOutOfRange),
        (-0.81e-3, false, FaultKind::PositionLimit),
    ] {
        let mut s = sup();
        assert_eq!(s.command(1.0).0, 1.0);
        assert_eq!(s.check_sample(&sample(x, oor)), Some(kind));
        assert_eq!(s.state(), SupervisorState::Faulted);
        assert_eq!(s.command(1.0).0, 0.0);
        // Good samples do not clear it.
        assert_eq!(s.check_sample(&sample(0.0, false)), None);
        s.enabled();
        s.running();
        assert_eq!(s.state(), SupervisorState::Faulted);
        assert_eq!(s.command(1.0).0, 0.0);
        s.reset();
        assert_eq!(s.state(), SupervisorState::Disabled);
    }
}

#[test]
fn command_clipped_and_non_finite_trips() {
    let mut s = sup();
    assert_eq!(s.command(50.0).0, 9.98);
    assert_eq!(s.command(-50.0).0, -9.98);
    assert_eq!(
        s.command(f64::NAN),
        (0.0, Some(FaultKind::CommandNotFinite))
    );
    assert_eq!(s.state(), SupervisorState::Faulted);
}

#[test]
fn missing_and_stale_samples() {
    let mut s = sup();
    for k in 0..10 {
        assert_eq!(s.check_sample(&seq_sample(k, 0.0, false)), None);
    }
    // A gap of 3 is tolerated (max 3), then recovery resets the count.
    assert_eq!(s.check_sample(&seq_sample(13, 0.0, false)), None);
    assert_eq!(s.check_sample(&seq_sample(14, 0.0, false)), None);
    // The same sequence number four times: stale.
    for _ in 0..3 {
        assert_eq!(s.check_sample(&seq_sample(14, 0.0, false)), None);
    }
    assert_eq!(
        s.check_sample(&seq_sample(14, 0.0, false)),
        Some(FaultKind::StaleSample)
    );
    // A gap of 4 at once is the link fault.
    let mut s = sup();
    s.check_sample(&seq_sample(0, 0.0, false));
    assert_eq!(
        s.check_sample(&seq_sample(5, 0.0, false)),
        Some(FaultKind::Link)
    );
    assert_eq!(s.fault(), Some((FaultKind::Link, 4.0)));
}

#[test]
fn ticks_without_a_sample_and_the_gap_they_leave_count_once() {
    // Two timeouts, then the next sample shows the gap of the two it
    // missed: 2 missing, not 4, so K = 3 holds.
    let mut s = sup();
    s.check_sample(&seq_sample(0, 0.0, false));
    assert_eq!(s.sample_missing(), None);
    assert_eq!(s.sample_missing(), None);
    assert_eq!(s.check_sample(&seq_sample(3, 0.0, false)), None);
    assert_eq!(s.missing_samples(), 0);
    // Four in a row trip on the fourth.
    for _ in 0..3 {
        assert_eq!(s.sample_missing(), None);
    }
    assert_eq!(s.sample_missing(), Some(FaultKind::Link));
    assert_eq!(s.command(1.0), (0.0, None));
    // A disconnect trips at once (but a latched fault is not replaced).
    let mut s = sup();
    assert!(s.link_lost());
    assert_eq!(s.fault().map(|f| f.0), Some(FaultKind::Link));
}

/// The frames a backend exchanges inside `enable` and `disable` (the CiA
/// 402 state machine over EtherCAT) are not samples the link lost: the
/// sequence starts again after each, while the same gap anywhere else is
/// the `link` fault (K = 3 here).
#[test]
fn a_sequence_jump_across_enable_or_disable_is_no_gap() {
    let mut s = Supervisor::new(config());
    assert_eq!(s.check_sample(&seq_sample(0, 0.0, false)), None);
    // Eight frames of the enable's state machine.
    s.enabled();
    assert_eq!(s.check_sample(&seq_sample(9, 0.0, false)), None);
    s.running();
    assert_eq!(s.check_sample(&seq_sample(10, 0.0, false)), None);
    // The disable's frames.
    s.disabled();
    assert_eq!(s.check_sample(&seq_sample(16, 0.0, false)), None);
    s.enabled();
    assert_eq!(s.check_sample(&seq_sample(30, 0.0, false)), None);
    assert_eq!(s.missing_samples(), 0);
    // The same jump while running: more than K missing.
    s.running();
    assert_eq!(
        s.check_sample(&seq_sample(38, 0.0, false)),
        Some(FaultKind::Link)
    );
    assert_eq!(s.fault(), Some((FaultKind::Link, 7.0)));
}

/// "More than K" means the same for corrupt and dropped frames: K of
/// either are tolerated, K + 1 trip, at any K; a bad read and the gap
/// it leaves count once.
#[test]
fn k_corrupt_frames_count_as_k_dropped_ones() {
    use bench_hal::ErrorKind as E;
    for k in [0u32, 1, 2, 3, 7, 50] {
        let sup_k = || {
            let mut s = Supervisor::new(SupervisorConfig {
                max_missed_samples: k,
                ..config()
            });
            s.enabled();
            s.running();
            assert_eq!(s.check_sample(&seq_sample(0, 0.0, false)), None);
            s
        };
        let n = u64::from(k);
        // Dropped: a gap of K is tolerated, K + 1 trips (value K + 1).
        let mut s = sup_k();
        assert_eq!(
            s.check_sample(&seq_sample(n + 1, 0.0, false)),
            None,
            "k={k}"
        );
        assert_eq!(s.state(), SupervisorState::Running);
        let mut s = sup_k();
        assert_eq!(
            s.check_sample(&seq_sample(n + 2, 0.0, false)),
            Some(FaultKind::Link),
            "k={k}"
        );
        assert_eq!(s.fault(), Some((FaultKind::Link, (n + 1) as f64)));
        // Corrupt (or timed out), each read a tick without a sample,
        // then the gap they leave: K and the gap of K are K, not 2K.
        for kind in [E::Crc, E::Timeout] {
            for bad_reads in 0..=n {
                let mut s = sup_k();
                for _ in 0..bad_reads {
                    assert_eq!(
                        s.hal_error(HalCall::ReadSample, kind, f64::NAN),
                        HalVerdict::SampleMissing { tripped: false },
                        "k={k}"
                    );
                }
                assert_eq!(
                    s.check_sample(&seq_sample(n + 1, 0.0, false)),
                    None,
                    "k={k}, {bad_reads} bad reads then a gap of {k}"
                );
                assert_eq!(s.missing_samples(), 0);
                // The count starts again: K more are tolerated.
                for _ in 0..n {
                    s.hal_error(HalCall::ReadSample, kind, f64::NAN);
                }
                assert_eq!(s.check_sample(&seq_sample(2 * n + 2, 0.0, false)), None);
                assert_eq!(s.state(), SupervisorState::Running, "k={k}");
            }
            // K + 1 bad reads trip on the last one.
            let mut s = sup_k();
            for i in 0..=n {
                assert_eq!(
                    s.hal_error(HalCall::ReadSample, kind, f64::NAN),
                    HalVerdict::SampleMissing { tripped: i == n },
                    "k={k}, read {i}"
                );
            }
            assert_eq!(s.fault(), Some((FaultKind::Link, (n + 1) as f64)));
            // K bad reads, then a gap of K + 1: the sample that shows
            // the (K + 1)th missing one trips.
            let mut s = sup_k();
            for _ in 0..n {
                s.hal_error(HalCall::ReadSample, kind, f64::NAN);
            }
            assert_eq!(
                s.check_sample(&seq_sample(n + 2, 0.0, false)),
                Some(FaultKind::Link),
                "k={k}"
            );
            assert_eq!(s.fault(), Some((FaultKind::Link, (n + 1) as f64)));
        }
    }
}

#[test]
fn hal_errors_map_to_one_rule() {
    use bench_hal::ErrorKind as K;
    // Timeouts and corrupt frames on a read are missing samples: K = 3
    // tolerated, the fourth trips the link fault.
    for kind in [K::Timeout, K::Crc] {
        let mut s = sup();
        for _ in 0..3 {
            assert_eq!(
                s.hal_error(HalCall::ReadSample, kind, f64::NAN),
                HalVerdict::SampleMissing { tripped: false }
            );
        }
        assert_eq!(
            s.hal_error(HalCall::ReadSample, kind, f64::NAN),
            HalVerdict::SampleMissing { tripped: true }
        );
        assert_eq!(s.fault(), Some((FaultKind::Link, 4.0)));
    }
    // A lost link on a read is the link fault at once.
    let mut s = sup();
    assert_eq!(
        s.hal_error(HalCall::ReadSample, K::Link, f64::NAN),
        HalVerdict::Fault {
            kind: FaultKind::Link,
            tripped: true
        }
    );
    // Everything else is a HAL fault, whatever the call; the first
    // fault stays latched.
    for (call, kind) in [
        (HalCall::ReadSample, K::Protocol),
        (HalCall::ReadSample, K::AmplifierFault),
        (HalCall::WriteCommand, K::Link),
        (HalCall::WriteCommand, K::Timeout),
        (HalCall::Enable, K::AmplifierFault),
    ] {
        let mut s = sup();
        assert_eq!(
            s.hal_error(call, kind, 1.5),
            HalVerdict::Fault {
                kind: FaultKind::Hal,
                tripped: true
            },
            "{call:?} {kind:?}"
        );
        assert_eq!(s.fault(), Some((FaultKind::Hal, 1.5)));
        assert_eq!(
            s.hal_error(HalCall::ReadSample, K::Link, f64::NAN),
            HalVerdict::Fault {
                kind: FaultKind::Link,
                tripped: false
            }
        );
        assert_eq!(s.fault(), Some((FaultKind::Hal, 1.5)));
    }
}

#[test]
fn position_jump() {
    let mut s = sup();
    assert_eq!(s.check_sample(&seq_sample(0, 0.0, false)), None);
    assert_eq!(s.check_sample(&seq_sample(1, 40e-6, false)), None);
    assert_eq!(
        s.check_sample(&seq_sample(2, 100e-6, false)),
        Some(FaultKind::PositionJump)
    );
}

/// I²t: the peak current is allowed for 1 s from cold, the continuous
/// current for ever (analytic budget (9.98² − 2.34²) A² · 1 s).
#[test]
fn i2t_budget() {
    let mut s = sup();
    for _ in 0..100_000 {
        assert_eq!(s.command(2.34).1, None);
    }
    assert_eq!(s.i2t_a2s(), 0.0);
    let mut ticks = 0;
    while s.command(9.98).1.is_none() {
        ticks += 1;
        assert!(ticks < 10_000);
    }
    // 1 s at 5 kHz.
    assert!((4999..=5001).contains(&ticks), "{ticks}");
    assert_eq!(s.state(), SupervisorState::Faulted);
    assert_eq!(s.command(1.0).0, 0.0);
}

#[test]
fn overruns_in_a_row() {
    let mut s = sup();
    // 3 deadlines may be missed in a row; the fourth trips.
    assert_eq!(s.check_overrun(2), None);
    assert_eq!(s.check_overrun(1), None);
    assert_eq!(s.check_overrun(0), None);
    assert_eq!(s.missed_deadlines(), 0);
    assert_eq!(s.check_overrun(1), None);
    assert_eq!(s.check_overrun(2), None);
    assert_eq!(s.check_overrun(1), Some(FaultKind::Overruns));
    // The value is how long the loop was behind: 4 periods of 200 µs.
    let (_, behind_s) = s.fault().unwrap();
    assert!((behind_s - 4.0 * 2e-4).abs() < 1e-12, "{behind_s}");
}

/// The supervisor at `rate_hz` with the shipped bound of 2 ms, the
/// missed deadlines converted as the config does.
fn sup_at(rate_hz: f64) -> Supervisor {
    let period_s = 1.0 / rate_hz;
    let mut s = Supervisor::new(SupervisorConfig {
        max_missed_deadlines: whole_periods(2e-3, period_s),
        period_s,
        ..config()
    });
    s.enabled();
    s.running();
    s
}

/// One tick stalled `stall_s` at `rate_hz`: it ends `stall_s` after
/// its deadline, so it misses ⌊stall / period⌋ deadlines, then the loop
/// is on time again. Returns whether the overrun rule tripped.
fn one_stall_trips(rate_hz: f64, stall_s: f64) -> bool {
    let mut s = sup_at(rate_hz);
    let missed = (stall_s * rate_hz).floor() as u64;
    let tripped = [0, 0, missed, 0, 0]
        .into_iter()
        .any(|m| s.check_overrun(m).is_some());
    assert_eq!(tripped, s.fault().is_some());
    tripped
}

/// A loop that ends every tick a little more than a period late for
/// `late_s` in all: one deadline missed per tick. Returns whether the
/// rule tripped.
fn slow_ticks_trip(rate_hz: f64, late_s: f64) -> bool {
    let mut s = sup_at(rate_hz);
    let ticks = (late_s * rate_hz).round() as u64;
    (0..ticks).any(|_| s.check_overrun(1).is_some())
}

#[test]
fn the_same_stall_is_judged_the_same_at_5_10_and_20_khz() {
    for rate_hz in [5e3, 10e3, 20e3] {
        // Behind schedule longer than 2 ms: the fault, at every rate.
        for stall_s in [2.5e-3, 3e-3, 50e-3] {
            assert!(
                one_stall_trips(rate_hz, stall_s),
                "{rate_hz} Hz {stall_s} s"
            );
            assert!(
                slow_ticks_trip(rate_hz, stall_s),
                "{rate_hz} Hz {stall_s} s"
            );
        }
        // Up to 2 ms: tolerated, at every rate (at 20 kHz 1.5 ms is 30
        // missed deadlines, which M = 5 ticks used to fault on).
        for stall_s in [0.3e-3, 1.5e-3, 1.9e-3] {
            assert!(
                !one_stall_trips(rate_hz, stall_s),
                "{rate_hz} Hz {stall_s} s"
            );
            assert!(
                !slow_ticks_trip(rate_hz, stall_s),
                "{rate_hz} Hz {stall_s} s"
            );
        }
    }
}

#[test]
fn whole_periods_of_a_bound() {
    // 2 ms is 10 periods at 5 kHz despite 2e-3 / 2e-4 rounding below.
    assert_eq!(whole_periods(2e-3, 2e-4), 10);
    assert_eq!(whole_periods(2e-3, 1e-4), 20);
    assert_eq!(whole_periods(2e-3, 5e-5), 40);
    assert_eq!(whole_periods(2e-3, 1e-2), 0);
    assert_eq!(whole_periods(0.1, 1.0 / 3.0), 0);
}

/// The reach rule judges how long one command stayed in force, the bound
/// rule the deadlines missed in a row. On the shipped bench (5 kHz) with
/// 3.2 A held at x1 = 0, the reach is a few ms (`time_to_reach_s`):
/// - a loop that ends every tick one deadline late for twice that time
///   refreshes the command every other period: below the bound (here 200
///   periods, 40 ms) it runs on;
/// - one stall of 1.5 times the reach trips at once, on the reach, with
///   that stall as its value.
#[test]
fn the_reach_judges_one_held_command_not_a_streak_of_late_ticks() {
    let bench = crate::config::BenchConfig::builtin().unwrap();
    let period_s = 2e-4;
    let fresh = || {
        let mut s = Supervisor::new(SupervisorConfig {
            max_missed_deadlines: 200,
            reach: bench.reach_envelope(period_s),
            ..config()
        });
        s.enabled();
        s.running();
        assert_eq!(s.command(3.2), (3.2, None));
        s
    };
    let mut s = fresh();
    let reach_s = s.reach_time_s();
    assert!(reach_s > 1e-3 && reach_s < 20e-3, "{reach_s}");
    let late_ticks = (2.0 * reach_s / period_s).ceil() as u64;
    assert!(late_ticks < 200);
    for _ in 0..late_ticks {
        assert_eq!(s.check_overrun(1), None);
        assert_eq!(s.command(3.2), (3.2, None));
    }
    assert_eq!(s.missed_deadlines(), late_ticks);

    let mut s = fresh();
    let stall = (1.5 * reach_s / period_s).ceil() as u64;
    assert_eq!(s.check_overrun(stall), Some(FaultKind::Overruns));
    let (_, value_s) = s.fault().unwrap();
    assert!(
        (value_s - stall as f64 * period_s).abs() < 1e-12,
        "{value_s}"
    );
}
