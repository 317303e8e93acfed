//! `bench track` as a daemon job (`bench track --daemon`, the socket's
//! `track`): the same plan and, trial by trial, the same errors as the
//! local run on the same bench; its trials in `track-<UTC>-job<N>/` of
//! the daemon's recordings directory, every one finished; a fault in a
//! learning trial latched by the daemon's one supervisor with every
//! recording kept; and a request the CLI refuses refused with `bad_params`
//! naming the parameter, nothing written.

use crate::common;
use crate::daemon_fixtures;

use common::*;
use daemon_fixtures::*;
use serde_json::{json, Value};
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};

/// `bench serve` on the shipped bench (its probe noise and disturbance: a
/// noise floor to learn down to), its jobs in virtual time.
fn shipped_daemon() -> Daemon {
    let dir = tmp();
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o700)).unwrap();
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    let socket = dir.path().join("bench.sock");
    let child = spawn_serve(
        &config,
        &socket,
        &dir.path().join("rec"),
        &["--pace", "off"],
    );
    Daemon {
        child,
        socket,
        dir,
        config,
    }
}

/// The directories the daemon made in its recordings directory.
fn track_dirs(d: &Daemon) -> Vec<PathBuf> {
    let rec = d.dir.path().join("rec");
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(&rec)
        .map(|r| {
            r.map(|e| e.unwrap().path())
                .filter(|p| {
                    p.is_dir()
                        && p.file_name()
                            .unwrap()
                            .to_string_lossy()
                            .starts_with("track-")
                })
                .collect()
        })
        .unwrap_or_default();
    dirs.sort();
    dirs
}

fn rms(t: &Value) -> (f64, f64) {
    (
        t["rms_error_m"].as_f64().unwrap(),
        t["rms_error_sigma_m"].as_f64().unwrap(),
    )
}

/// With a model 15 % off the bench, the daemon's run and the local one
/// plan the same scan and learn the same way: each trial's RMS error
/// within 4σ of their difference (the two runs see different noise: the
/// daemon's loop holds between trials) plus 3 %, the same trials, both
/// converged. The daemon's directory holds every trial, finished, and the
/// summary it answered.
#[test]
fn a_track_job_on_the_daemon_learns_as_the_local_run_does() {
    let d = shipped_daemon();
    let model = crate::track::off_model(d.dir.path());
    let model_s = model.to_str().unwrap();
    let o = run(&[
        "track",
        "--daemon",
        &d.sock(),
        "--model",
        model_s,
        "--trials",
        "3",
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = json_stdout(&o);
    let out = path_in(d.dir.path(), "local");
    let cfg = d.config.to_str().unwrap();
    let o = run(&[
        "track", "--config", cfg, "--out", &out, "--model", model_s, "--trials", "3", "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let l = json_stdout(&o);
    assert_eq!(r["plan"], l["plan"]);
    assert_eq!(r["stop"], "converged", "{r}");
    assert_eq!(r["stop"], l["stop"]);
    assert_eq!(r["best_trial"], l["best_trial"]);
    let (rt, lt) = (
        r["trials"].as_array().unwrap(),
        l["trials"].as_array().unwrap(),
    );
    assert_eq!(rt.len(), lt.len(), "{r}\n{l}");
    for (a, b) in rt.iter().zip(lt) {
        assert_eq!(a["name"], b["name"]);
        let ((ra, sa), (rb, sb)) = (rms(a), rms(b));
        assert!(
            (ra - rb).abs() <= 4.0 * sa.hypot(sb) + 0.03 * rb,
            "{}: daemon {ra:e} ± {sa:e}, local {rb:e} ± {sb:e}",
            a["name"]
        );
    }
    // Its directory: every trial finished, the summary answered on disk.
    let dirs = track_dirs(&d);
    assert_eq!(dirs.len(), 1, "{dirs:?}");
    let dir = &dirs[0];
    assert!(dir
        .file_name()
        .unwrap()
        .to_string_lossy()
        .ends_with("-job1"));
    let on_disk: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("track.json")).unwrap()).unwrap();
    assert_eq!(on_disk, r);
    for t in rt {
        let rec = Path::new(t["recording"].as_str().unwrap());
        assert_eq!(rec.parent().unwrap(), dir.as_path());
        assert!(rec.is_file(), "{rec:?}");
        assert!(!mcap_messages(rec).is_empty(), "{rec:?}");
    }
    assert!(dir.join("feedforward.csv").is_file());
    assert!(dir.join("track.png").is_file());
    let leftovers: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".part") || n.ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    assert_eq!(
        d.client().call("status", json!({}))["result"]["state"],
        "disabled"
    );
}

/// A learning trial that faults on the daemon: the job's answer is the
/// fault, the daemon latches it (its one supervisor), the trials before
/// and the faulted one are finished recordings, and the summary on disk
/// stops at `fault` keeping the feedforward. After a reset the daemon runs
/// again. Requests the CLI refuses are `bad_params` naming the parameter,
/// and nothing is written for them.
#[test]
fn a_fault_on_the_daemon_keeps_every_trial_and_bad_requests_write_nothing() {
    let d = shipped_daemon();
    let model = crate::track::off_model(d.dir.path());
    let model_s = model.to_str().unwrap();
    let mut c = d.client();
    let bad: Vec<(Value, &str)> = vec![
        (json!({ "amplitude_m": 1.0 }), "params.amplitude_m"),
        (json!({ "amplitude_m": -1e-6 }), "params.amplitude_m"),
        (json!({ "line_rate_hz": 400.0 }), "params.line_rate_hz"),
        (json!({ "trials": 0 }), "params.trials"),
        (json!({ "periods": 100000 }), "params.periods"),
        (json!({ "learning_gain": 1.5 }), "params.learning_gain"),
        (json!({ "scan": "csv" }), "params.reference"),
        (json!({ "scan": "spiral" }), "params.scan"),
        (json!({ "reference": "/no/such.csv" }), "params.reference"),
        (
            json!({ "scan": "csv", "reference": "/no/such.csv" }),
            "params.reference",
        ),
        (json!({ "model": "off.toml" }), "params.model"),
        (json!({ "model": "/no/such.toml" }), "params.model"),
        (json!({ "learning_ps": "rel.mcap" }), "params.learning_ps"),
        (
            json!({ "feedforward": "/no/such.csv" }),
            "params.feedforward",
        ),
        (json!({ "max_snap_m_s4": "loud" }), "params.max_snap_m_s4"),
        (json!({ "inject_fault": "smoke@1" }), "params.inject_fault"),
        (json!({ "controller": "nope" }), "params.controller"),
        (json!({ "pace": 0 }), "params.pace"),
        (json!({ "out": "/tmp" }), "unknown field `out`"),
    ];
    for (params, names) in &bad {
        let r = c.call("track", params.clone());
        assert_eq!(r["error"]["kind"], "bad_params", "{params}: {r}");
        let m = r["error"]["message"].as_str().unwrap();
        assert!(m.contains(names), "{params}: {m}");
    }
    assert!(track_dirs(&d).is_empty(), "{:?}", track_dirs(&d));
    assert_eq!(c.call("status", json!({}))["result"]["state"], "disabled");

    // A fault in the first learning trial (a 0.2 mm step in the reading,
    // gone after a reset; the first three trials of the
    // shipped scan last (warm-up + 5 + 2) lines of 0.1 s each; the holds
    // between them on the daemon add a little).
    let plan = c.call("track", json!({ "model": model_s, "trials": 1 }));
    assert_eq!(plan["ok"], true, "{plan}");
    let lines = plan["result"]["plan"]["warm_up_periods"].as_u64().unwrap() + 5 + 2;
    let at = format!("jump@{}", 3.0 * lines as f64 / 10.0 + 0.5);
    let r = c.call("track", json!({ "model": model_s, "inject_fault": at }));
    assert_eq!(r["ok"], false, "{r}");
    let m = r["error"]["message"].as_str().unwrap();
    assert!(m.contains("position_jump"), "{m}");
    let status = c.call("status", json!({}))["result"].clone();
    assert_eq!(status["state"], "faulted", "{status}");
    let dirs = track_dirs(&d);
    assert_eq!(dirs.len(), 2, "{dirs:?}");
    crate::track::faulted_in_learning_1(&dirs[1]);
    // Refused while faulted; runs again after a reset (the step was a
    // one-off).
    let r = c.call("track", json!({ "trials": 1, "periods": 1 }));
    assert_eq!(r["ok"], false, "{r}");
    assert_eq!(c.call("reset", json!({}))["ok"], true);
    let r = c.call("track", json!({ "trials": 1, "periods": 1 }));
    assert_eq!(r["ok"], true, "{r}");
}
