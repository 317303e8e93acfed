//! `[trajectory]` in the bench config: the reference `bench track` (and
//! the daemon's `track` job) follows where the flags or the request's
//! fields do not say. The scan a config describes plans exactly as the
//! same scan given by flags; a flag wins over the key; a relative
//! `reference` is the config file's directory's; a key out of its range
//! is refused when the config loads, one the model refuses when the scan
//! is planned, both naming `trajectory.KEY` (never a flag the user did not
//! give), exit 2 and nothing written.

use crate::common;
use crate::daemon_fixtures;

use common::*;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

/// The shipped config with `table` appended, as `name` in `dir`.
fn with_trajectory(dir: &Path, name: &str, table: &str) -> PathBuf {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"),
    )
    .unwrap();
    let p = dir.join(name);
    std::fs::write(&p, format!("{text}\n[trajectory]\n{table}")).unwrap();
    p
}

fn track(args: &[&str]) -> std::process::Output {
    let mut all = vec!["track", "--json", "--trials", "1", "--periods", "2"];
    all.extend_from_slice(args);
    run(&all)
}

fn ok(o: &std::process::Output) -> Value {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    json_stdout(o)
}

/// The plan without the model's path (the configs differ by name).
fn plan(v: &Value) -> Value {
    let mut p = v["plan"].clone();
    p.as_object_mut().unwrap().remove("model");
    p
}

#[test]
fn a_trajectory_in_the_config_plans_as_its_flags_do() {
    let dir = tmp();
    let d = dir.path();
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    let shipped = shipped.to_str().unwrap();
    // A sine of ±3 µm at 5 lines/s, cut at 40 Hz.
    let cfg = with_trajectory(
        d,
        "sine.toml",
        "scan = \"sine\"\namplitude_m = 3.0e-6\nline_rate_hz = 5.0\ncutoff_hz = 40.0\n",
    );
    let from_config = ok(&track(&[
        "--config",
        cfg.to_str().unwrap(),
        "--out",
        &path_in(d, "a"),
    ]));
    let from_flags = ok(&track(&[
        "--config",
        shipped,
        "--out",
        &path_in(d, "b"),
        "--scan",
        "sine",
        "--amplitude-m",
        "3e-6",
        "--line-rate-hz",
        "5",
        "--cutoff-hz",
        "40",
    ]));
    assert_eq!(plan(&from_config), plan(&from_flags));
    assert_eq!(from_config["plan"]["scan"]["kind"], "sine");
    assert_eq!(from_config["plan"]["scan"]["amplitude_m"], 3e-6);
    assert_eq!(from_config["plan"]["scan"]["line_rate_hz"], 5.0);
    // A flag wins over the key; the keys it leaves stand.
    let v = ok(&track(&[
        "--config",
        cfg.to_str().unwrap(),
        "--out",
        &path_in(d, "c"),
        "--amplitude-m",
        "2e-6",
    ]));
    assert_eq!(v["plan"]["scan"]["amplitude_m"], 2e-6);
    assert_eq!(v["plan"]["scan"]["line_rate_hz"], 5.0);
    // A move's limits and its settle band from the config.
    let mv = with_trajectory(
        d,
        "move.toml",
        "scan = \"move\"\namplitude_m = 10.0e-6\nline_rate_hz = 1.0\nmax_velocity_m_s = 5.0e-4\nmax_snap_m_s4 = \"none\"\nsettle_band_m = 20.0e-9\n",
    );
    let v = ok(&track(&[
        "--config",
        mv.to_str().unwrap(),
        "--out",
        &path_in(d, "m"),
    ]));
    let limits = &v["plan"]["scan"]["move_limits"];
    assert_eq!(limits["velocity_m_s"], 5e-4, "{v}");
    assert_eq!(limits["acceleration_m_s2"], 0.1, "{v}");
    assert_eq!(limits["snap_m_s4"], Value::Null, "{v}");
    assert_eq!(v["plan"]["settle_band_m"], 20e-9);
    // A csv line beside the config, named relative to it, run from
    // elsewhere: its rows make the line (500 rows: 10 lines/s).
    let sub = d.join("bench");
    std::fs::create_dir(&sub).unwrap();
    let mut text = String::from("time_s,position_m\n");
    for i in 0..500 {
        let t = i as f64 / 5000.0;
        let x = 2e-6 * (2.0 * std::f64::consts::PI * 10.0 * t).sin();
        text.push_str(&format!("{t:e},{x:e}\n"));
    }
    std::fs::write(sub.join("line.csv"), text).unwrap();
    let csv_cfg = with_trajectory(
        &sub,
        "csv.toml",
        "scan = \"csv\"\nreference = \"line.csv\"\n",
    );
    let v = ok(&track(&[
        "--config",
        csv_cfg.to_str().unwrap(),
        "--out",
        &path_in(d, "csv"),
    ]));
    assert_eq!(v["plan"]["scan"]["kind"], "csv");
    assert_eq!(v["plan"]["scan"]["line_rate_hz"], 10.0);
    assert_eq!(
        Path::new(v["plan"]["scan"]["reference_csv"].as_str().unwrap()),
        sub.join("line.csv")
    );
    // `--scan triangle` leaves the config's csv line out.
    let v = ok(&track(&[
        "--config",
        csv_cfg.to_str().unwrap(),
        "--out",
        &path_in(d, "tri"),
        "--scan",
        "triangle",
    ]));
    assert_eq!(v["plan"]["scan"]["kind"], "triangle");
    assert_eq!(v["plan"]["scan"]["amplitude_m"], 5e-6);

    // The daemon's track job follows its config's [trajectory] too.
    let socket = d.join("bench.sock");
    let child = daemon_fixtures::spawn_serve(&cfg, &socket, &d.join("rec"), &["--pace", "off"]);
    let daemon = daemon_fixtures::Daemon {
        child,
        socket,
        dir: tmp(),
        config: cfg.clone(),
    };
    let r = daemon
        .client()
        .call("track", json!({ "trials": 1, "periods": 2 }));
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(plan(&r["result"]), plan(&from_config));
}

/// Keys out of their ranges are refused as the config loads, naming the
/// key; a key the model refuses (a line rate in the MMP zero's band, a
/// move too long for its line) is refused when the scan is planned,
/// naming `trajectory.KEY` and the file, not a flag; exit 2, nothing
/// written. Through the daemon, the same refusal names the key too.
#[test]
fn bad_trajectory_keys_are_refused_naming_them() {
    let dir = tmp();
    let d = dir.path();
    let cases: &[(&str, &str)] = &[
        ("amplitude_m = 1.0\n", "trajectory.amplitude_m"),
        ("amplitude_m = -1e-6\n", "trajectory.amplitude_m"),
        ("amplitude_m = nan\n", "trajectory.amplitude_m"),
        ("line_rate_hz = 0.0\n", "trajectory.line_rate_hz"),
        ("line_rate_hz = 1000.0\n", "trajectory.line_rate_hz"),
        ("cutoff_hz = 3000.0\n", "trajectory.cutoff_hz"),
        (
            "line_rate_hz = 10.0\ncutoff_hz = 5.0\n",
            "trajectory.cutoff_hz",
        ),
        ("max_jerk_m_s3 = inf\n", "trajectory.max_jerk_m_s3"),
        // Faster than crossing the 1.6 mm stroke within a 0.2 ms tick.
        ("max_velocity_m_s = 8.1\n", "trajectory.max_velocity_m_s"),
        ("max_snap_m_s4 = 1.1e12\n", "trajectory.max_snap_m_s4"),
        ("max_snap_m_s4 = \"loud\"\n", "max_snap_m_s4"),
        ("settle_band_m = 0.0\n", "trajectory.settle_band_m"),
        ("scan = \"spiral\"\n", "scan"),
        ("scan = \"csv\"\n", "trajectory.reference"),
        ("reference = \"line.csv\"\n", "trajectory.reference"),
        (
            "scan = \"csv\"\nreference = \"line.csv\"\namplitude_m = 1e-6\n",
            "trajectory.amplitude_m",
        ),
        ("speed = 1.0\n", "speed"),
        // Planned on the model.
        ("line_rate_hz = 20.0\n", "trajectory.line_rate_hz of"),
        (
            "scan = \"move\"\nline_rate_hz = 10.0\nmax_velocity_m_s = 1e-5\n",
            "trajectory.line_rate_hz of",
        ),
        (
            "scan = \"csv\"\nreference = \"none.csv\"\n",
            "trajectory.reference of",
        ),
    ];
    for (i, (table, names)) in cases.iter().enumerate() {
        let cfg = with_trajectory(d, &format!("bad{i}.toml"), table);
        let out = d.join(format!("out{i}"));
        let o = track(&[
            "--config",
            cfg.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{table}: {err}");
        assert!(err.contains(names), "{table}: {err}");
        assert!(
            !err.contains("--line-rate-hz") && !err.contains("--reference"),
            "{table}: {err}"
        );
        assert!(!out.exists(), "{table}: wrote {out:?}");
    }
    // Any key of the config, not only the trajectory's, is checked before
    // the run (track once ran on a config it had not checked), and so is
    // the --model's.
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"),
    )
    .unwrap();
    let key = text
        .lines()
        .find(|l| l.starts_with("position_limit_m"))
        .unwrap();
    let bad = d.join("bad-limit.toml");
    std::fs::write(&bad, text.replace(key, "position_limit_m = -1.0")).unwrap();
    for args in [
        vec!["--config", bad.to_str().unwrap()],
        vec!["--model", bad.to_str().unwrap()],
    ] {
        let out = d.join("limit-out");
        let mut all = args.clone();
        all.extend(["--out", out.to_str().unwrap()]);
        let o = track(&all);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains("safety.position_limit_m"), "{args:?}: {err}");
        assert!(!out.exists());
    }
    // The daemon names the key of its config as well.
    let cfg = with_trajectory(d, "daemon.toml", "line_rate_hz = 20.0\n");
    let socket = d.join("bench.sock");
    let child = daemon_fixtures::spawn_serve(&cfg, &socket, &d.join("rec"), &["--pace", "off"]);
    let daemon = daemon_fixtures::Daemon {
        child,
        socket,
        dir: tmp(),
        config: cfg.clone(),
    };
    let mut c = daemon.client();
    let r = c.call("track", json!({}));
    assert_eq!(r["error"]["kind"], "bad_params", "{r}");
    let m = r["error"]["message"].as_str().unwrap();
    assert!(m.contains("trajectory.line_rate_hz of"), "{m}");
    // A request's own field is named as the request's.
    let r = c.call("track", json!({ "line_rate_hz": 20.0 }));
    let m = r["error"]["message"].as_str().unwrap();
    assert!(m.contains("params.line_rate_hz"), "{m}");
}
