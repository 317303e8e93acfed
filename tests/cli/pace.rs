//! `--pace` and the request's `pace` (README, *Pacing virtual time:
//! `--pace`*): a paced run takes its loop time over the factor of wall
//! time and never less; pacing changes when ticks run, never what they
//! compute (the FRF and the step's metrics equal the unpaced run's, the
//! same seed); a late release is no fault (a 300 ms host stall in a paced
//! fast step finishes, the same stall in real time is the overruns fault);
//! bad values (generated mutations, and any pace with `--realtime` or on
//! hardware) exit 2 naming `--pace` with nothing written, and the daemon
//! refuses the same values with the same reasons, runs a paced job on the
//! simulator and is back in real time after it.
//!
//! The live view of a paced run is tested in `tests/servers/live.rs`.

use crate::common;
use crate::daemon_fixtures;

use common::*;
use daemon_fixtures::Daemon;
use rand::{Rng, SeedableRng};
use serde_json::{json, Value};
use std::path::Path;
use std::time::Instant;

/// Loop time of a run, s: its ticks at its rate.
fn loop_s(summary: &Value) -> f64 {
    let t = &summary["timing"];
    t["ticks"].as_f64().unwrap() / t["rate_hz"].as_f64().unwrap()
}

/// The wall time a paced run cannot beat, s: its last tick is due
/// `(ticks − 1)·period/factor` after its first.
fn paced_floor_s(summary: &Value) -> f64 {
    let t = &summary["timing"];
    (t["ticks"].as_f64().unwrap() - 1.0)
        / t["rate_hz"].as_f64().unwrap()
        / t["pace_factor"].as_f64().unwrap()
}

fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The wall-clock requirement: `--pace 10` on a run of 10 s of
/// loop time takes about a second, never less than 10 s / 10.
#[test]
fn pace_10_runs_a_10_s_run_in_about_a_second() {
    let _g = one_at_a_time();
    let dir = tmp();
    // Lead-in 0.5 s + sweep 9 s + tail 0.5 s: 10 s of loop time.
    let cfg = quiet_config(dir.path(), 0.5, "");
    let t0 = Instant::now();
    let o = bench()
        .args(["chirp", "--pace", "10", "--json", "--duration-s", "9"])
        .arg("--config")
        .arg(&cfg)
        .arg("--out")
        .arg(dir.path().join("run.mcap"))
        .output()
        .unwrap();
    let process_s = t0.elapsed().as_secs_f64();
    assert!(o.status.success(), "{}", stderr(&o));
    let s = json_stdout(&o);
    let t = &s["timing"];
    assert_eq!(t["mode"], "paced", "{t}");
    assert_eq!(t["pace_factor"], 10.0);
    // 20 µs of wall time a tick at 5 kHz: 50 ticks in a 1 ms batch.
    assert_eq!(t["pace_batch_ticks"], 50);
    assert!((loop_s(&s) - 10.0).abs() < 1e-3, "{}", loop_s(&s));
    let wall_s = t["wall_s"].as_f64().unwrap();
    eprintln!("--pace 10, 10 s of loop time: loop {wall_s:.3} s wall, process {process_s:.3} s");
    assert!(wall_s >= paced_floor_s(&s), "{wall_s} s: faster than paced");
    // About a second; generous for a loaded 2-core machine.
    assert!(wall_s < 3.0, "{wall_s} s for 1 s of paced time");
    assert!((1.0..10.0).contains(&process_s), "{process_s} s");
    // No wake-up counted as a deadline missed: virtual time has none.
    assert_eq!(t["overruns"], 0);
    assert_eq!(t["dropped_records"], 0);
}

/// Bad pace values, written out and generated (seeded): above the range,
/// below it, negative, a valid value mangled, not numbers at all.
fn bad_paces() -> Vec<String> {
    let mut bad: Vec<String> = [
        "0", "-0", "0.0", "-1", "nan", "NaN", "inf", "-inf", "infinity", "1e309", "1e-400", "",
        " ", "abc", "fast", "1x", "10%", "0x10", "1,5", "½", "OFF", "off1", "--", "1 2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x9ace);
    for _ in 0..4 {
        // Above the range, below it, negative, and a valid value mangled.
        bad.push(format!("{}", rng.random_range(100.001..1e12)));
        bad.push(format!("{:e}", rng.random_range(1e-12..0.0099)));
        bad.push(format!("{}", -rng.random_range(0.01..100.0)));
        let ok = format!("{:.3}", rng.random_range(0.01..100.0));
        let at = rng.random_range(0..ok.len());
        let junk = ['a', 'e', '.', '-', '/', 'x'][rng.random_range(0..6)];
        let mut mangled = ok.clone();
        mangled.insert(at, junk);
        if mangled.parse::<f64>().is_err() {
            bad.push(mangled);
        }
        bad.push(format!("{ok}s"));
    }
    bad
}

/// Bad `--pace` values, written out and generated: each exits 2 naming
/// `--pace` with its reason, before anything is written; so does any pace
/// with `--realtime` (naming both) or on hardware.
#[test]
fn bad_pace_values_exit_2_naming_pace() {
    let dir = tmp();
    let bad = bad_paces();
    let out = dir.path().join("never.mcap");
    let outs = out.display().to_string();
    let exits_2 = |args: &[&str], names: &[&str]| {
        let o = run(args);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
        for n in names {
            assert!(e.contains(n), "{args:?}: no {n} in {e}");
        }
        assert!(!out.exists(), "{args:?} wrote {outs}");
    };
    for cmd in [&["chirp"][..], &["control", "--fast"][..]] {
        for v in &bad {
            let mut args = cmd.to_vec();
            args.extend(["--pace", v, "--duration-s", "1", "--out", &outs]);
            exits_2(&args, &["--pace"]);
        }
        // A valid pace with --realtime: both named.
        for v in ["1", "0.5", "10", "off"] {
            let mut args = cmd.to_vec();
            args.extend([
                "--realtime",
                "--pace",
                v,
                "--duration-s",
                "1",
                "--out",
                &outs,
            ]);
            exits_2(&args, &["--pace", "--realtime"]);
        }
        // On hardware, which runs in real time: refused before the device
        // is opened.
        let mut args = cmd.to_vec();
        args.extend([
            "--backend",
            "serial:/dev/bench-none",
            "--pace",
            "0.5",
            "--out",
            &outs,
        ]);
        exits_2(&args, &["--pace", "real time", "serial:/dev/bench-none"]);
    }
    // The reasons say what a pace is.
    let e = stderr(&run(&["chirp", "--pace", "0"]));
    assert!(e.contains("from 0.01 to 100") && e.contains("off"), "{e}");
}

/// Pacing decides when ticks run, not what they compute: a chirp paced at
/// 20× and the same chirp unpaced (same seed, the simulator's noise on)
/// give the same samples and the same FRF CSV, byte for byte.
#[test]
fn a_paced_chirp_gives_the_unpaced_chirps_frf() {
    let dir = tmp();
    let mut summaries = Vec::new();
    for pace in ["20", "off"] {
        let out = dir.path().join(format!("pace-{pace}.mcap"));
        let o = bench()
            .args(["chirp", "--pace", pace, "--seed", "7", "--json"])
            .args(["--duration-s", "3", "--f-start-hz", "5"])
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{pace}: {}", stderr(&o));
        summaries.push(json_stdout(&o));
    }
    assert_eq!(summaries[0]["timing"]["mode"], "paced");
    assert_eq!(summaries[0]["timing"]["pace_factor"], 20.0);
    assert_eq!(summaries[1]["timing"]["mode"], "virtual");
    assert!(summaries[1]["timing"].get("pace_factor").is_none());
    assert!(summaries[0]["timing"]["wall_s"].as_f64().unwrap() >= paced_floor_s(&summaries[0]));
    let read = |name: &str| std::fs::read(dir.path().join(name)).unwrap();
    assert_eq!(
        read("pace-20.frf.csv"),
        read("pace-off.frf.csv"),
        "the FRF CSVs differ"
    );
    let samples = |name: &str| {
        bench::record::read_samples_tolerant(&read(name))
            .into_iter()
            .map(|s| {
                (
                    s.tick,
                    s.position_m.to_bits(),
                    s.current_command_a.to_bits(),
                )
            })
            .collect::<Vec<_>>()
    };
    let paced = samples("pace-20.mcap");
    assert!(paced.len() > 10_000);
    assert_eq!(paced, samples("pace-off.mcap"));
    for key in ["peak_position_m", "fit", "verdict"] {
        assert_eq!(summaries[0][key], summaries[1][key], "{key}");
    }
}

/// A late release is no fault: the host stalls 300 ms in a paced fast
/// step (a bound of a few ms in real time); the step finishes, the lag
/// shows as wake-up latency, no stall is counted, and its metrics equal
/// the unpaced run's with the same stall. The same stall in real time is
/// the supervisor's overruns fault: safety is the supervisor's, pacing
/// only waits.
#[test]
fn a_host_stall_in_a_paced_step_is_no_fault() {
    let _g = one_at_a_time();
    let dir = tmp();
    let step = |pace: &[&str], name: &str| {
        bench()
            .args(["control", "--fast", "--json", "--duration-s", "2"])
            .args(["--inject-fault", "stall:300@0.5"])
            .args(pace)
            .arg("--out")
            .arg(dir.path().join(name))
            .output()
            .unwrap()
    };
    let paced = step(&["--pace", "4"], "paced.mcap");
    assert!(paced.status.success(), "{}", stderr(&paced));
    let paced = json_stdout(&paced);
    let t = &paced["timing"];
    assert_eq!(t["mode"], "paced");
    assert!(
        t["wake_latency_max_us"].as_f64().unwrap() >= 250e3,
        "the 300 ms lag is not in the wake-up latency: {t}"
    );
    assert_eq!(t["overruns"], 0);
    let events = mcap_messages(&dir.path().join("paced.mcap"));
    let kinds: Vec<&str> = events
        .iter()
        .filter(|(topic, ..)| topic == "/bench/event")
        .filter_map(|(.., v)| v["kind"].as_str())
        .collect();
    assert!(
        !kinds.contains(&"stall") && !kinds.contains(&"fault"),
        "{kinds:?}"
    );
    let unpaced = step(&["--pace", "off"], "unpaced.mcap");
    assert!(unpaced.status.success(), "{}", stderr(&unpaced));
    assert_eq!(paced["metrics"], json_stdout(&unpaced)["metrics"]);
    let realtime = step(&["--realtime"], "realtime.mcap");
    assert_eq!(realtime.status.code(), Some(3), "{}", stderr(&realtime));
    assert!(
        stderr(&realtime).contains("overruns"),
        "{}",
        stderr(&realtime)
    );
}

/// `--live` in virtual time without `--pace` paces at 1× and says so, with
/// how to run unpaced; `--pace off` does not.
#[test]
fn live_paces_at_real_time_by_default_and_says_so() {
    let _g = one_at_a_time();
    let dir = tmp();
    let cfg = quiet_config(dir.path(), 0.1, "");
    let chirp = |extra: &[&str], name: &str| {
        bench()
            .args([
                "chirp",
                "--json",
                "--duration-s",
                "0.5",
                "--live",
                "127.0.0.1:0",
            ])
            .args(extra)
            .arg("--config")
            .arg(&cfg)
            .arg("--out")
            .arg(dir.path().join(name))
            .output()
            .unwrap()
    };
    let o = chirp(&[], "default.mcap");
    assert!(o.status.success(), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("paced at 1× real time") && e.contains("--pace off"),
        "{e}"
    );
    let s = json_stdout(&o);
    assert_eq!(s["timing"]["mode"], "paced");
    assert_eq!(s["timing"]["pace_factor"], 1.0);
    assert!(s["timing"]["wall_s"].as_f64().unwrap() >= paced_floor_s(&s));
    let o = chirp(&["--pace", "off"], "off.mcap");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("paced at"), "{}", stderr(&o));
    assert_eq!(json_stdout(&o)["timing"]["mode"], "virtual");
}

/// The daemon takes the same `pace`: checked as `--pace` is (the same
/// reason for the same value), refused on hardware; on the simulator a
/// paced job runs paced, an unpaced one unpaced, and the next job without
/// `pace` is back in the loop's real time.
#[test]
fn the_daemon_takes_the_same_pace() {
    let _g = one_at_a_time();
    let d = Daemon::start();
    let sock = d.sock();
    let o = run(&[
        "chirp",
        "--daemon",
        &sock,
        "--json",
        "--duration-s",
        "1.5",
        "--pace",
        "10",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = json_stdout(&o);
    assert_eq!(s["timing"]["mode"], "paced", "{}", s["timing"]);
    assert_eq!(s["timing"]["pace_factor"], 10.0);
    assert!(s["timing"]["wall_s"].as_f64().unwrap() >= paced_floor_s(&s));
    let o = run(&[
        "control",
        "--daemon",
        &sock,
        "--fast",
        "--json",
        "--duration-s",
        "0.5",
        "--pace",
        "off",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(json_stdout(&o)["timing"]["mode"], "virtual");
    let o = run(&[
        "control",
        "--daemon",
        &sock,
        "--fast",
        "--json",
        "--duration-s",
        "0.5",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = json_stdout(&o);
    assert_eq!(s["timing"]["mode"], "realtime");
    assert!(loop_s(&s) >= 0.5);
    let mut c = d.client();
    assert_eq!(c.call("status", json!({}))["result"]["state"], "disabled");
    // The same reasons as the CLI's, value for value.
    for v in ["0", "-1", "1e9", "101", "0.001", "-0.5"] {
        let cli = stderr(&run(&["chirp", "--pace", v]));
        let reason = cli
            .lines()
            .find_map(|l| l.split_once("': ").map(|(_, r)| r.to_string()))
            .unwrap_or_else(|| panic!("no reason in {cli}"));
        let n: f64 = v.parse().unwrap();
        for cmd in ["chirp", "control"] {
            let params = match cmd {
                "chirp" => json!({"pace": n, "duration_s": 1}),
                _ => json!({"controller": "fast", "pace": n}),
            };
            let r = c.call(cmd, params);
            assert_eq!(r["ok"], false, "{cmd} pace {v}: {r}");
            assert_eq!(r["error"]["kind"], "bad_params", "{r}");
            let m = r["error"]["message"].as_str().unwrap();
            assert!(m.starts_with("params.pace"), "{m}");
            assert!(m.contains(&reason), "{m}\nis not the CLI's\n{reason}");
        }
    }
    // Neither a number nor "off".
    for v in [
        json!("fast"),
        json!("1"),
        json!("OFF"),
        json!(true),
        json!([1]),
    ] {
        let r = c.call("chirp", json!({"pace": v}));
        assert_eq!(r["ok"], false, "{v}: {r}");
        assert_eq!(r["error"]["kind"], "bad_params", "{r}");
        assert!(
            r["error"]["message"].as_str().unwrap().contains("pace"),
            "{r}"
        );
    }
    assert_eq!(c.call("status", json!({}))["result"]["jobs_run"], 3);
}

/// On a daemon whose bench is hardware (the serial device emulator), a
/// `pace` is refused: hardware runs in real time.
#[test]
fn a_hardware_daemon_refuses_a_pace() {
    let _g = one_at_a_time();
    let emu = common::emulator::Emulator::start(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"),
        vec![],
        None,
    );
    let backend = emu.backend();
    let d = Daemon::start_with(&["--backend", &backend], "");
    let mut c = d.client();
    for (cmd, params) in [
        ("chirp", json!({"pace": 1})),
        ("control", json!({"controller": "fast", "pace": "off"})),
    ] {
        let r = c.call(cmd, params);
        assert_eq!(r["ok"], false, "{r}");
        assert_eq!(r["error"]["kind"], "bad_params", "{r}");
        let m = r["error"]["message"].as_str().unwrap();
        assert!(
            m.starts_with("params.pace") && m.contains("real time") && m.contains(&backend),
            "{m}"
        );
    }
    let o = run(&["chirp", "--daemon", &d.sock(), "--pace", "1"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("pace"), "{}", stderr(&o));
}

/// `bench serve --pace`: a simulator daemon gives its pace to every job
/// whose request names none (a 20 s chirp in virtual time, unpaced, at
/// the simulator's speed: far under its 20 s of loop time), a request's
/// own `pace` wins (a 0.5 s step at 1×: at least its loop time), and
/// `status` shows it. Bad values ([`bad_paces`]) exit 2 naming `--pace`
/// before a socket exists; on hardware `--pace` is refused with the
/// reason before the device is opened.
#[test]
fn a_daemon_started_with_a_pace_gives_it_to_every_job_that_names_none() {
    let _g = one_at_a_time();
    let d = Daemon::start_with(&["--pace", "off"], "");
    let mut c = d.client();
    assert_eq!(c.call("status", json!({}))["result"]["pace"], "off");
    let t0 = Instant::now();
    let o = run(&[
        "chirp",
        "--daemon",
        &d.sock(),
        "--json",
        "--duration-s",
        "20",
    ]);
    let wall_s = t0.elapsed().as_secs_f64();
    assert!(o.status.success(), "{}", stderr(&o));
    let s = json_stdout(&o);
    assert_eq!(s["timing"]["mode"], "virtual", "{s}");
    assert!(loop_s(&s) >= 20.0, "{s}");
    assert!(wall_s < 20.0, "a 20 s chirp took {wall_s} s of wall time");
    let o = run(&[
        "control",
        "--daemon",
        &d.sock(),
        "--fast",
        "--json",
        "--duration-s",
        "0.5",
        "--pace",
        "1",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = json_stdout(&o);
    assert_eq!(s["timing"]["pace_factor"], 1.0, "{s}");
    assert!(paced_floor_s(&s) >= 0.49, "{s}");
    assert_eq!(c.call("status", json!({}))["result"]["jobs_run"], 2);

    let dir = tmp();
    for v in &bad_paces() {
        let sock = dir.path().join("x.sock");
        let o = run(&["serve", "--socket", sock.to_str().unwrap(), "--pace", v]);
        assert_eq!(o.status.code(), Some(2), "--pace {v:?}: {}", stderr(&o));
        assert!(stderr(&o).contains("--pace"), "{v:?}: {}", stderr(&o));
        assert!(!sock.exists(), "--pace {v:?}: a socket was made");
    }

    // On hardware: refused before the device is opened (there is none).
    let sock = dir.path().join("hw.sock");
    let o = run(&[
        "serve",
        "--socket",
        sock.to_str().unwrap(),
        "--backend",
        "serial:/dev/bench-none",
        "--pace",
        "off",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("--pace") && e.contains("real time"), "{e}");
    assert!(!sock.exists());
}
