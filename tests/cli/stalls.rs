//! Faults with physical reasons (issue 25): a stall (the loop thread held
//! up, as a loaded host does) ends a closed loop exactly when it exceeds the
//! bound the loop check derived, never below it; open-loop identification
//! survives it, with the span left out of the FRF; a user's bound above the
//! loop's own is refused with both numbers. Over the serial emulator, a
//! link that holds its frames back (a USB hiccup, `hold:S`) is judged the
//! same way: by how long it was silent, against the device's watchdog in
//! open loop and the loop's bound in closed loop.

use crate::common;

use bench_devices::emulator::{LinkFault, ScheduledLinkFault};
use common::emulator::Emulator;
use common::{
    bench, fault_in_injected_stall, json_stdout, one_at_a_time, past_machine_stalls, path_in,
    quiet_config_edited, tmp, HostStallWatch,
};
use serde_json::Value;
use std::path::{Path, PathBuf};

fn config(dir: &Path, extra_safety: &str) -> PathBuf {
    quiet_config_edited(dir, 0.5, "", |t| {
        t.replace("\n[safety]\n", &format!("\n[safety]\n{extra_safety}"))
    })
}

/// The loop check's stall bound of `controller`, s, and its source.
fn stall_bound(cfg: &Path, controller: &str) -> (f64, String) {
    let out = bench()
        .args([
            "control",
            "--controller",
            controller,
            "--check-only",
            "--json",
            "--config",
        ])
        .arg(cfg)
        .output()
        .unwrap();
    let v = json_stdout(&out);
    let s = &v["loop_check"]["stall"];
    (
        s["bound_s"].as_f64().unwrap(),
        s["source"].as_str().unwrap().to_string(),
    )
}

fn control_with_stall(
    cfg: &Path,
    dir: &Path,
    controller: &str,
    stall_ms: f64,
) -> (Option<i32>, Value) {
    let rec = path_in(dir, &format!("{controller}-{stall_ms}.mcap"));
    let run = || {
        let out = bench()
            .args([
                "control",
                "--controller",
                controller,
                "--realtime",
                "--duration-s",
                "1.5",
                "--json",
            ])
            .args([
                "--inject-fault",
                &format!("stall:{stall_ms}@0.6"),
                // A run again after a machine stall replaces the first's.
                "--overwrite",
                "--out",
                &rec,
                "--config",
            ])
            .arg(cfg)
            .output()
            .unwrap();
        (out.status.code(), json_stdout(&out))
    };
    // The injected stall ends the run, if it does, when it ends.
    past_machine_stalls(run, |v| fault_in_injected_stall(v, 0.6, stall_ms * 1e-3))
}

/// Each controller's delay bound is its delay margin plus one period of
/// that crossover (fast: 2.3 + 22.1 ms; slow: 17.0 + 33.9 ms at the
/// 185 rad/s crossing). With the loop settled (a small held current, whose
/// reach never gets to the limit), a stall of a third of the bound runs
/// through; one of 2.5 times stops the run on `overruns`, with the stall,
/// the bound and where it came from in the message. (The bound is counted
/// in whole periods; the supervisor's unit test checks the edge, K periods
/// behind tolerated and K + 1 not.)
#[test]
fn a_closed_loop_stops_when_a_stall_exceeds_its_derived_bound() {
    let _g = one_at_a_time();
    let dir = tmp();
    let cfg = config(dir.path(), "");
    for controller in ["slow", "fast"] {
        let (bound_s, source) = stall_bound(&cfg, controller);
        assert!(source.starts_with("delay margin"), "{controller}: {source}");
        assert!(
            source.contains(&format!("controller {controller}")),
            "{source}"
        );
        assert!(bound_s > 10e-3 && bound_s < 0.1, "{controller}: {bound_s}");
        let (code, v) = control_with_stall(&cfg, dir.path(), controller, bound_s * 1e3 / 3.0);
        assert_eq!(
            code,
            Some(0),
            "{controller}: a stall of a third of the bound faulted: {v}"
        );
        let (code, v) = control_with_stall(&cfg, dir.path(), controller, bound_s * 1e3 * 2.5);
        assert_eq!(code, Some(3), "{controller}: {v}");
        assert_eq!(v["fault"]["kind"], "overruns", "{controller}: {v}");
        let msg = v["fault"]["message"].as_str().unwrap();
        assert!(
            msg.starts_with("stall ") && msg.contains(" ms > ") && msg.contains(&source),
            "{controller}: {msg}"
        );
        let stalled = v["fault"]["value"].as_f64().unwrap();
        assert!(stalled > bound_s, "{controller}: {stalled} s");
    }
}

/// An open-loop chirp that loses 30 ms to a stall finishes: the stall is
/// reported with its length, and the FRF lines swept while it held the
/// excitation are left out of the FRF (and its CSV).
#[test]
fn an_open_loop_chirp_survives_a_stall_and_leaves_its_span_out() {
    let _g = one_at_a_time();
    let dir = tmp();
    let cfg = config(dir.path(), "");
    let rec = path_in(dir.path(), "chirp.mcap");
    let out = bench()
        .args([
            "chirp",
            "--realtime",
            "--duration-s",
            "4",
            "--json",
            "--inject-fault",
            "stall:30@2.5",
        ])
        .args(["--out", &rec, "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v = json_stdout(&out);
    let st = &v["stalls"];
    assert!(st["count"].as_u64().unwrap() >= 1, "{st}");
    assert!(st["longest_s"].as_f64().unwrap() >= 0.029, "{st}");
    let excluded = st["excluded_lines"].as_u64().unwrap();
    assert!(excluded > 0, "{st}");
    // The sweep (0.1 → 500 Hz in 4 s, after the 0.5 s lead-in) is at
    // 0.1 · 5000^(2 / 4) = 7.07 Hz when the stall hits at 2.5 s.
    let f = 0.1 * 5000f64.powf(2.0 / 4.0);
    let hit = st["bands_hz"]
        .as_array()
        .unwrap()
        .iter()
        .any(|b| b[0].as_f64().unwrap() <= f * 1.01 && b[1].as_f64().unwrap() >= f * 0.99);
    assert!(hit, "no band at {f} Hz: {st}");
    let csv = common::read_frf_csv(Path::new(&v["frf_csv"].as_str().unwrap()));
    assert!(
        !csv.iter().any(|r| (r[0] / f - 1.0).abs() < 0.001),
        "the CSV keeps the stalled line at {f} Hz"
    );
}

/// `safety.max_overrun_s` and `safety.max_command_latency_s` may tighten
/// the loop's bound, never loosen it: above it, the loop check refuses the
/// controller with both numbers (exit 2, nothing enabled); below it, the
/// key is the bound in force.
#[test]
fn a_user_bound_above_the_loops_own_is_refused_with_both_numbers() {
    let dir = tmp();
    let plain = config(dir.path(), "");
    let (fast_s, _) = stall_bound(&plain, "fast");
    for key in ["max_overrun_s", "max_command_latency_s"] {
        let d = tmp();
        let cfg = config(d.path(), &format!("{key} = 0.05\n"));
        let out = bench()
            .args(["control", "--fast", "--config"])
            .arg(&cfg)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{key}: {err}");
        let want = format!("safety.{key} = 50.0 ms is above the {:.1} ms", fast_s * 1e3);
        assert!(err.contains(&want), "{key}: {err}");
        let d = tmp();
        let cfg = config(d.path(), &format!("{key} = 0.001\n"));
        let (bound, source) = stall_bound(&cfg, "fast");
        assert_eq!(bound, 0.001, "{key}");
        assert!(source.starts_with(&format!("safety.{key}")), "{source}");
    }
}

/// The serial soak of issue 25: `BENCH_SOAK_RUNS` (default 20) default
/// chirps (65 s each) over the serial emulator in real time, on this
/// machine as it is. Every run must finish; the stalls (late-command runs)
/// each saw are printed. Run by hand (22 minutes):
/// `cargo test --release --test cli -- --ignored --nocapture stalls::`.
#[test]
#[ignore]
fn soak_default_chirps_over_the_serial_emulator() {
    let _g = one_at_a_time();
    let dir = tmp();
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    let runs: usize = std::env::var("BENCH_SOAK_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20);
    let mut failed = Vec::new();
    for run in 0..runs {
        let emu = common::emulator::Emulator::start(&shipped, vec![], None);
        let rec = path_in(dir.path(), &format!("serial{run}.mcap"));
        let out = bench()
            .args([
                "chirp",
                "--json",
                "--backend",
                &emu.backend(),
                "--out",
                &rec,
            ])
            .output()
            .unwrap();
        let v: Value = serde_json::from_slice(&out.stdout).unwrap_or(Value::Null);
        eprintln!(
            "run {run}: exit {:?}, stalls {} (longest {:.2} ms, {} FRF lines left out), link {}",
            out.status.code(),
            v["stalls"]["count"],
            v["stalls"]["longest_s"].as_f64().unwrap_or(0.0) * 1e3,
            v["stalls"]["excluded_lines"],
            v["link"]
        );
        if !out.status.success() {
            failed.push(format!(
                "run {run}: {}",
                String::from_utf8_lossy(&out.stderr)
            ));
        }
    }
    assert!(failed.is_empty(), "{failed:#?}");
}

/// The travel rule: a stall right after a 500 µm step, while the fast
/// controller drives near the peak current (8.6 A, 1.8 ms after the step),
/// is shorter than the delay
/// bound (24.4 ms) but long enough for that current to carry x1 to the
/// 800 µm limit (the model's reach: about 6 ms from the start): it stops
/// the run, and the message names the held current and the reach. The same
/// stall before the step (the loop holding its start, a few mA) runs
/// through.
#[test]
fn a_stall_on_a_large_held_current_stops_on_the_reach() {
    let _g = one_at_a_time();
    let dir = tmp();
    let cfg = config(dir.path(), "");
    const STALL_MS: f64 = 15.0;
    let run = |at: &str| {
        let rec = path_in(dir.path(), &format!("reach{at}.mcap"));
        let out = bench()
            .args([
                "control",
                "--fast",
                "--realtime",
                "--duration-s",
                "1",
                "--step-m",
                "0.0005",
                "--json",
            ])
            .args([
                "--inject-fault",
                &format!("stall:{STALL_MS}@{at}"),
                // A run again after a machine stall replaces the first's.
                "--overwrite",
                "--out",
                &rec,
                "--config",
            ])
            .arg(&cfg)
            .output()
            .unwrap();
        (out.status.code(), json_stdout(&out))
    };
    let run = |at: &str| {
        let at_s: f64 = at.parse().unwrap();
        past_machine_stalls(
            || run(at),
            |v| fault_in_injected_stall(v, at_s, STALL_MS * 1e-3),
        )
    };
    // settle_s = 0.2 s: the step is at 0.2 s, the command near its peak
    // 1.8 ms later.
    let (code, v) = run("0.2018");
    assert_eq!(code, Some(3), "{v}");
    assert_eq!(v["fault"]["kind"], "overruns", "{v}");
    let msg = v["fault"]["message"].as_str().unwrap();
    assert!(
        msg.contains("could carry x1 to the 800.0 µm position limit"),
        "{msg}"
    );
    let held: f64 = msg
        .split("the held ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|a| a.parse().ok())
        .unwrap_or_else(|| panic!("{msg}"));
    assert!(held > 5.0, "{msg}");
    let (code, v) = run("0.1");
    assert_eq!(code, Some(0), "{v}");
}

/// `bench` over the serial emulator, which holds its frames back for
/// `hold_ms` once, `at_s` after it started: `args` after the backend.
fn serial_with_hold(cfg: &Path, hold_ms: f64, at_s: f64, args: &[&str]) -> (Option<i32>, Value) {
    let emu = Emulator::start(
        cfg,
        vec![ScheduledLinkFault {
            at_s,
            kind: LinkFault::Hold {
                duration_s: hold_ms * 1e-3,
            },
        }],
        None,
    );
    let out = bench()
        .args(args)
        .args(["--json", "--backend", &emu.backend(), "--config"])
        .arg(cfg)
        .output()
        .unwrap();
    (out.status.code(), json_stdout(&out))
}

/// A serial link that goes silent for 5, 25 or 40 ms (the device keeps
/// sampling, its frames arrive late, together) during an open-loop chirp
/// (3 s after the emulator started: the chirp has started by then, even on
/// a loaded machine):
/// shorter than the device's 50 ms watchdog, so the link is not dead and
/// the chirp finishes, with the stall (the device running on late
/// commands) reported at its length. The host keeps every sample of the
/// silence (its queue holds a watchdog's worth), so none is missing.
///
/// The device's watchdog counts the hold plus the link's round trip and
/// whatever the machine adds: a run that ends on the watchdog while the
/// host-stall watch saw the machine late by the margin left (watchdog −
/// hold) is the machine's, and is run again (at most three times); one the
/// watch did not explain fails.
#[test]
fn an_open_loop_chirp_rides_out_a_silent_serial_link() {
    let _g = one_at_a_time();
    let dir = tmp();
    let cfg = config(dir.path(), "");
    let watchdog_ms = bench::config::BenchConfig::load(&cfg)
        .unwrap()
        .emulator
        .watchdog_ms;
    assert_eq!(watchdog_ms, 50.0);
    for hold_ms in [5.0, 25.0, 40.0] {
        let rec = path_in(dir.path(), &format!("hold{hold_ms}.mcap"));
        let mut seen = Vec::new();
        let (code, v, machine_ms) = loop {
            let watch = HostStallWatch::start(79);
            let (code, v) = serial_with_hold(
                &cfg,
                hold_ms,
                3.0,
                &["chirp", "--duration-s", "6", "--out", &rec],
            );
            let machine_ms = watch.stop() * 1e3;
            // The device's watchdog tripped, or the host's supervisor saw
            // the link silent past that same watchdog (a link fault).
            let says_watchdog = |m: &Value| m.as_str().is_some_and(|m| m.contains("watchdog"));
            let on_watchdog = (v["outcome"] == "hal" && says_watchdog(&v["hal"]["message"]))
                || (v["fault"]["kind"] == "link" && says_watchdog(&v["fault"]["message"]));
            if !(on_watchdog && machine_ms >= watchdog_ms - hold_ms && seen.len() < 2) {
                break (code, v, machine_ms);
            }
            seen.push(format!("machine late {machine_ms:.1} ms"));
        };
        assert_eq!(code, Some(0), "hold {hold_ms} ms (retried: {seen:?}): {v}");
        // The host sees the silence from its last frame before to its
        // first after: shorter than the hold by as much as the machine
        // delayed the host's reading of the frames before it (the watch).
        let longest = v["stalls"]["longest_s"].as_f64().unwrap();
        assert!(
            longest >= (0.9 * hold_ms - machine_ms) * 1e-3,
            "hold {hold_ms} ms: longest stall {longest} s (machine late {machine_ms:.1} ms): {}",
            v["stalls"]
        );
        assert_eq!(v["link"]["missed_samples"], 0, "hold {hold_ms} ms: {v}");
    }
}

/// The same silence in closed loop: the fast controller's bound (delay
/// margin + one crossover period, 24.4 ms) decides. A third of it runs
/// through; 1.6 times it stops the step on `link`, the message giving the
/// silence, the bound and where it came from (the silence is judged at
/// each sample timeout, 5 ms here, so the stop comes within one timeout
/// after the bound).
#[test]
fn a_closed_loop_stops_when_the_serial_link_is_silent_beyond_its_bound() {
    let _g = one_at_a_time();
    let dir = tmp();
    let cfg = config(dir.path(), "");
    let (bound_s, source) = stall_bound(&cfg, "fast");
    let step = |hold_ms: f64| {
        let rec = path_in(dir.path(), &format!("step{hold_ms}.mcap"));
        serial_with_hold(
            &cfg,
            hold_ms,
            1.0,
            &["control", "--fast", "--duration-s", "2", "--out", &rec],
        )
    };
    let (code, v) = step(bound_s * 1e3 / 3.0);
    assert_eq!(code, Some(0), "a third of the bound faulted: {v}");
    let (code, v) = step(bound_s * 1e3 * 1.6);
    assert_eq!(code, Some(3), "{v}");
    assert_eq!(v["fault"]["kind"], "link", "{v}");
    let msg = v["fault"]["message"].as_str().unwrap();
    assert!(
        msg.starts_with("no sample for ") && msg.contains(&source),
        "{msg}"
    );
    let silent_s = v["fault"]["value"].as_f64().unwrap();
    assert!(
        silent_s > bound_s && silent_s < bound_s + 0.015,
        "{silent_s} s against {bound_s} s"
    );
}

/// A device that stays silent longer than its own watchdog (it hangs for
/// 80 ms) is a dead link, even in open loop: the chirp stops on `link`,
/// naming the watchdog.
#[test]
fn a_serial_device_silent_beyond_its_watchdog_ends_the_chirp() {
    let _g = one_at_a_time();
    let dir = tmp();
    let cfg = config(dir.path(), "");
    let emu = Emulator::start(
        &cfg,
        vec![ScheduledLinkFault {
            at_s: 2.0,
            kind: LinkFault::Stall { duration_s: 0.08 },
        }],
        None,
    );
    let rec = path_in(dir.path(), "hung.mcap");
    let out = bench()
        .args(["chirp", "--duration-s", "4", "--json", "--out", &rec])
        .args(["--backend", &emu.backend(), "--config"])
        .arg(&cfg)
        .output()
        .unwrap();
    let v = json_stdout(&out);
    assert_eq!(out.status.code(), Some(3), "{v}");
    assert_eq!(v["fault"]["kind"], "link", "{v}");
    let msg = v["fault"]["message"].as_str().unwrap();
    assert!(msg.contains("> 50.0 ms (the device's watchdog"), "{msg}");
}
