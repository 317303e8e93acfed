//! Limits that hold (issue 25): the host's current limits always win over
//! what a device announces, the I²t protection cannot be configured off,
//! and the recording of every faulted or interrupted run ends at 0 A.

use crate::common;

use bench::config::BenchConfig;
use common::emulator::Emulator;
use common::{
    bench, json_stdout, mcap_messages, one_at_a_time, path_in, quiet_config_edited, set_key, tmp,
};
use rand::{Rng, SeedableRng};
use serde_json::Value;
use std::path::{Path, PathBuf};

fn shipped() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml")
}

/// The quiet Chapter 5 bench with the host's `[actuator]` current limits
/// set to `peak` and `continuous` (A).
fn host_config(dir: &Path, peak: &str, continuous: &str) -> PathBuf {
    quiet_config_edited(dir, 0.5, "", |t| {
        set_key(
            &set_key(t, "peak_current_a", peak),
            "continuous_current_a",
            continuous,
        )
    })
}

/// The `/bench/sample` messages of a recording, in order.
fn samples(rec: &Path) -> Vec<Value> {
    mcap_messages(rec)
        .into_iter()
        .filter(|(t, ..)| t == "/bench/sample")
        .map(|(.., v)| v)
        .collect()
}

fn largest_command_a(rec: &Path) -> f64 {
    samples(rec)
        .iter()
        .map(|s| s["current_command_a"].as_f64().unwrap_or(0.0).abs())
        .fold(0.0, f64::max)
}

/// The breach, reversed: a host config of 1 A peak / 0.5 A
/// continuous against a serial device that announces its 9.98 A. The
/// commanded current never exceeds 1 A, the I²t protection trips as it does
/// on the simulator with the same config, and the summary says which limit
/// applied and where it came from.
#[test]
fn a_serial_device_never_raises_the_host_limits() {
    let _g = one_at_a_time();
    let dir = tmp();
    let host = host_config(dir.path(), "1.0", "0.5");
    // The device runs the shipped bench: it announces 9.98 A / 2.34 A.
    let emu = Emulator::start_with(&shipped(), vec![], None, true);
    let mut kinds = Vec::new();
    for backend in [emu.backend(), "sim".to_string()] {
        let rec = path_in(dir.path(), &format!("{}.mcap", backend.len()));
        let out = bench()
            .args(["control", "--fast", "--config"])
            .arg(&host)
            .args([
                "--backend",
                &backend,
                "--step-m",
                "0.0005",
                "--duration-s",
                "2",
                "--json",
                "--out",
                &rec,
            ])
            .output()
            .unwrap();
        let v = json_stdout(&out);
        let limits = &v["current_limits"];
        assert_eq!(limits["peak_current_a"], 1.0, "{backend}: {v}");
        assert_eq!(limits["peak_from"], "host_config", "{backend}: {v}");
        assert_eq!(limits["continuous_current_a"], 0.5, "{backend}: {v}");
        let biggest = largest_command_a(Path::new(&rec));
        assert!(
            biggest <= 1.0,
            "{backend}: commanded {biggest} A with a 1 A host limit"
        );
        // Saturated at 1 A against a stiffness that 11 N cannot bend 500 µm,
        // it spends the I²t budget (1² − 0.5²) A² × 1 s in about a second.
        assert_eq!(out.status.code(), Some(3), "{backend}: {v}");
        kinds.push(v["fault"]["kind"].as_str().unwrap_or("").to_string());
        if backend.starts_with("serial") {
            let dev = limits["device_peak_current_a"].as_f64().unwrap();
            assert!((dev - 9.98).abs() < 1e-5, "{v}");
        }
    }
    assert_eq!(kinds, ["i2t", "i2t"], "serial and sim must stop alike");
}

/// A device that announces less than the host lowers the limit in force,
/// and the summary names the device as its source.
#[test]
fn a_device_that_announces_less_lowers_the_limit() {
    let _g = one_at_a_time();
    let dir = tmp();
    let host = host_config(dir.path(), "9.98", "2.34");
    let emu = Emulator::start_announcing(&shipped(), vec![], None, true, Some((0.8, 0.3)));
    let rec = path_in(dir.path(), "low.mcap");
    let out = bench()
        .args(["control", "--fast", "--config"])
        .arg(&host)
        .args([
            "--backend",
            &emu.backend(),
            "--step-m",
            "0.0005",
            "--duration-s",
            "1",
            "--json",
            "--out",
            &rec,
        ])
        .output()
        .unwrap();
    let v = json_stdout(&out);
    assert_eq!(v["current_limits"]["peak_from"], "device", "{v}");
    assert_eq!(v["current_limits"]["continuous_from"], "device", "{v}");
    let biggest = largest_command_a(Path::new(&rec));
    assert!(
        biggest <= f64::from(0.8f32),
        "commanded {biggest} A, the device allows 0.8 A"
    );
}

/// Announcements outside the physical ranges (NaN, infinities, 1e30 A,
/// zero, negative, continuous above peak, above 20 A), fixed and generated,
/// are refused at the handshake naming the values: exit 2, the amplifier
/// never enabled, no recording left.
#[test]
fn announcements_outside_the_physical_ranges_are_refused_at_the_handshake() {
    let _g = one_at_a_time();
    let dir = tmp();
    let host = host_config(dir.path(), "9.98", "2.34");
    let mut cases: Vec<(f32, f32)> = vec![
        (f32::NAN, 2.34),
        (9.98, f32::NAN),
        (1e30, 2.34),
        (9.98, 1e30),
        (f32::INFINITY, 2.34),
        (-1.0, 2.34),
        (0.0, 0.0),
        (9.98, 20.0),
        (25.0, 2.0),
        (-f32::MAX, -1.0),
    ];
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(25);
    while cases.len() < 16 {
        let p: f32 = rng.random_range(-50.0..50.0);
        let c: f32 = rng.random_range(-50.0..50.0);
        let ok = p > 0.0 && p <= 20.0 && c > 0.0 && c <= p;
        if !ok {
            cases.push((p, c));
        }
    }
    for (p, c) in cases {
        let emu = Emulator::start_announcing(&shipped(), vec![], None, false, Some((p, c)));
        let rec = dir
            .path()
            .join(format!("refused-{}.mcap", p.to_bits() ^ c.to_bits()));
        let out = bench()
            .args(["chirp", "--config"])
            .arg(&host)
            .args(["--backend", &emu.backend(), "--duration-s", "0.5", "--out"])
            .arg(&rec)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "({p}, {c}): {err}");
        assert!(
            err.contains("--backend") && err.contains("announced"),
            "({p}, {c}): {err}"
        );
        assert!(err.contains("nothing was enabled"), "({p}, {c}): {err}");
        assert!(
            !emu.status
                .enabled
                .load(std::sync::atomic::Ordering::Relaxed),
            "({p}, {c}): enabled"
        );
        assert!(!rec.exists(), "({p}, {c}): a recording was left");
        let part = rec.with_extension("mcap.part");
        assert!(!part.exists(), "({p}, {c}): a part file was left");
    }
}

/// Generated current ratings: a config is accepted exactly when the peak
/// is within the coil's rating and the continuous rating within the coil's
/// and at most peak / 1.25, so every accepted config has an I²t budget of
/// at least 0.56 I_cont² t_peak; a refusal names the key it refuses.
#[test]
fn no_config_switches_the_thermal_protection_off() {
    let text = std::fs::read_to_string(shipped()).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2025);
    let (mut accepted, mut refused) = (0, 0);
    let mut pairs: Vec<(f64, f64)> = vec![
        (9.98, 9.98),
        (2.34, 2.34),
        (20.0, 20.0),
        (1.0, 0.9),
        (1.25, 1.0),
        (9.98, 2.34),
    ];
    for _ in 0..400 {
        pairs.push((rng.random_range(0.01..12.0), rng.random_range(0.01..12.0)));
    }
    for (peak, cont) in pairs {
        let t = set_key(
            &set_key(&text, "peak_current_a", &format!("{peak:?}")),
            "continuous_current_a",
            &format!("{cont:?}"),
        );
        let p = Path::new("mutated.toml");
        let r = BenchConfig::from_toml(&t, p).and_then(|c| c.validate(p).map(|()| c));
        let legal = peak <= 9.98 && cont <= 2.34 && cont * 1.25 <= peak * (1.0 + 1e-9);
        match r {
            Ok(c) => {
                assert!(legal, "accepted peak {peak} A, continuous {cont} A");
                let a = &c.actuator;
                let budget = (a.peak_current_a.powi(2) - a.continuous_current_a.powi(2))
                    * c.safety.i2t_peak_duration_s;
                assert!(
                    budget
                        >= 0.56
                            * a.continuous_current_a.powi(2)
                            * c.safety.i2t_peak_duration_s
                            * (1.0 - 1e-6),
                    "budget {budget}"
                );
                accepted += 1;
            }
            Err(e) => {
                assert!(
                    !legal,
                    "refused legal peak {peak} A, continuous {cont} A: {e}"
                );
                let e = e.to_string();
                assert!(
                    e.contains("actuator.peak_current_a")
                        || e.contains("actuator.continuous_current_a"),
                    "{e}"
                );
                refused += 1;
            }
        }
    }
    assert!(
        accepted > 20 && refused > 20,
        "{accepted} accepted, {refused} refused"
    );
}

/// The last recorded sample of every faulted run shows 0 A in the faulted
/// state: a fault of the sample (NaN, a jump, out of range, frozen, a gap)
/// and a stall beyond the loop's bound (the overruns fault, where the
/// faulting tick's command had been sent before the stop).
#[test]
fn the_last_sample_of_a_faulted_run_is_zero_amperes() {
    let _g = one_at_a_time();
    let dir = tmp();
    let host = host_config(dir.path(), "9.98", "2.34");
    for (fault, kind, realtime) in [
        ("nan@0.5", "probe_not_finite", false),
        ("jump@0.5", "position_jump", false),
        ("out_of_range@0.5", "probe_out_of_range", false),
        ("frozen@0.5", "stale_sample", false),
        ("drop@0.5", "link", false),
        ("stall:80@0.5", "overruns", true),
    ] {
        let rec = dir.path().join(format!("{kind}.mcap"));
        let mut cmd = bench();
        cmd.args(["control", "--fast", "--config"])
            .arg(&host)
            .args([
                "--inject-fault",
                fault,
                "--duration-s",
                "1.5",
                "--json",
                "--out",
            ])
            .arg(&rec);
        if realtime {
            cmd.arg("--realtime");
        }
        let out = cmd.output().unwrap();
        assert_eq!(
            out.status.code(),
            Some(3),
            "{fault}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        // --json prints the run's summary with the fault on stdout.
        let v = json_stdout(&out);
        assert_eq!(v["outcome"], "fault", "{fault}: {v}");
        assert_eq!(v["fault"]["kind"], kind, "{fault}: {v}");
        assert!(
            v["current_limits"]["peak_current_a"].is_number(),
            "{fault}: {v}"
        );
        let s = samples(&rec);
        let last = s.last().unwrap();
        assert_eq!(last["current_command_a"], 0.0, "{fault}: {last}");
        assert_eq!(last["state"], "faulted", "{fault}: {last}");
        // The loop ran and drove current before the fault.
        assert!(
            s.iter()
                .any(|x| x["current_command_a"].as_f64().unwrap_or(0.0) != 0.0),
            "{fault}"
        );
    }
}

/// SIGINT in the middle of a real-time chirp: exit 130, the recording
/// complete, and its last sample at 0 A (the stop came after the last
/// tick's command was sent: one more sample shows the teardown).
#[test]
fn the_last_sample_of_an_interrupted_run_is_zero_amperes() {
    let _g = one_at_a_time();
    let dir = tmp();
    let host = host_config(dir.path(), "9.98", "2.34");
    let rec = dir.path().join("int.mcap");
    let child = bench()
        .args(["chirp", "--realtime", "--duration-s", "20", "--config"])
        .arg(&host)
        .arg("--out")
        .arg(&rec)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(2500));
    // SAFETY: kill(2) on our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let out = child.wait_with_output().unwrap();
    assert_eq!(
        out.status.code(),
        Some(130),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s = samples(&rec);
    let last = s.last().unwrap();
    assert_eq!(last["current_command_a"], 0.0, "{last}");
    assert_ne!(last["state"], "running", "{last}");
    // The chirp was driving current when it was stopped.
    assert!(s.len() > 5000);
    assert!(s[s.len() - 50..s.len() - 1]
        .iter()
        .any(|x| x["current_command_a"].as_f64().unwrap_or(0.0) != 0.0));
}
