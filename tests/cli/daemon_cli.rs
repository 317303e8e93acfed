//! `bench daemon status|reset|enable|disable|stop|shutdown` against a real
//! `bench serve` on the simulator: what they print is checked against the
//! daemon's own `status` read through the socket, their exit statuses
//! against the README's table, and the socket errors (no daemon, a stale
//! socket, a directory, a file) by status and message.

use crate::common;
use crate::daemon_fixtures;

use common::*;
use daemon_fixtures::*;
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Output;
use std::time::{Duration, Instant};

/// The exit statuses of the README's table.
const FAULT: i32 = 3;
const BAD_INPUT: i32 = 2;
const REFUSED: i32 = 5;
const NO_DAEMON: i32 = 6;

/// Runs `bench daemon ARGS --socket SOCKET`.
fn daemon_cmd(socket: &Path, args: &[&str]) -> Output {
    let mut all = vec!["daemon"];
    all.extend(args);
    all.extend(["--socket", socket.to_str().unwrap()]);
    run(&all)
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).to_string()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).to_string()
}

/// The `key  value` lines of the human output: key and value are
/// separated by two spaces or more (the values are aligned); every line
/// has both, and no key is given twice.
fn fields(o: &Output) -> BTreeMap<String, String> {
    let text = stdout(o);
    let mut m = BTreeMap::new();
    for line in text.lines() {
        let (k, v) = line
            .split_once("  ")
            .unwrap_or_else(|| panic!("not a `key  value` line: {line:?} in\n{text}"));
        let prev = m.insert(k.trim().to_string(), v.trim().to_string());
        assert!(prev.is_none(), "{k:?} twice in\n{text}");
    }
    m
}

/// The aligned column: every value starts at the same character.
fn assert_aligned(o: &Output) {
    let text = stdout(o);
    let starts: Vec<usize> = text
        .lines()
        .map(|l| {
            let k = l.split_once("  ").unwrap().0;
            let rest = &l[k.len()..];
            k.chars().count() + rest.chars().take_while(|c| *c == ' ').count()
        })
        .collect();
    assert!(
        starts.windows(2).all(|w| w[0] == w[1]),
        "values not aligned: {starts:?}\n{text}"
    );
}

/// The daemon's `status` result, read through the socket.
fn status_json(d: &Daemon) -> Value {
    let r = d.client().call("status", json!({}));
    assert_eq!(r["ok"], true, "{r}");
    r["result"].clone()
}

/// What `bench daemon status` printed agrees with the daemon's JSON
/// `status` read before (`s0`) and after (`s1`) it: the state, the fault
/// (kind and cause), the job, the backend, the hold, the jobs run, the
/// last recording, and the position (µm) and current (A) to the printed
/// digits when they did not change between the readings.
fn assert_status_printed(o: &Output, s0: &Value, s1: &Value) {
    let f = fields(o);
    assert_aligned(o);
    for k in ["state", "backend", "hold"] {
        assert_eq!(s0[k], s1[k], "{k} changed during the test");
        assert_eq!(f[k], s0[k].as_str().unwrap(), "{k}: {f:?} vs {s0}");
    }
    assert_eq!(f["jobs run"], s0["jobs_run"].to_string(), "{f:?} vs {s0}");
    let rate: f64 = f["loop rate"].strip_suffix(" Hz").unwrap().parse().unwrap();
    assert_eq!(rate, s0["rate_hz"].as_f64().unwrap());
    match s0["fault"].as_object() {
        None => assert_eq!(f["fault"], "none"),
        Some(fault) => {
            let (kind, msg) = (
                fault["kind"].as_str().unwrap(),
                fault["message"].as_str().unwrap(),
            );
            assert!(
                f["fault"].contains(kind) && f["fault"].contains(msg),
                "{f:?} vs {s0}"
            );
        }
    }
    match s0["job"].as_object() {
        None => assert_eq!(f["job"], "none"),
        Some(job) => {
            assert!(
                f["job"].contains(job["kind"].as_str().unwrap())
                    && f["job"].contains(&job["id"].to_string()),
                "{f:?} vs {s0}"
            );
            assert_eq!(f["recording"], job["recording"].as_str().unwrap());
        }
    }
    assert_eq!(
        f["last recording"],
        s0["last_recording"].as_str().unwrap_or("none")
    );
}

/// The printed position (µm) and current (A) are the daemon's reading to
/// the printed digits, when the reading did not change between `s0` and
/// `s1`; no number before the first reading (`null`: JSON has no NaN).
/// `Err` says which differs: the stage rings for seconds after a job and
/// its reading is quantised, so two equal readings around the printed one
/// do not prove it stood still in between (the caller reads again).
fn reading_printed(o: &Output, s0: &Value, s1: &Value) -> Result<(), String> {
    let f = fields(o);
    let check = |printed: &str, unit: &str, key: &str, scale: f64, digit: f64| {
        let number = printed
            .strip_suffix(unit)
            .and_then(|x| x.trim().parse::<f64>().ok());
        match (s0[key].as_f64(), s1[key].as_f64()) {
            (Some(a), Some(b)) if a == b => {
                let x = number.unwrap_or_else(|| panic!("{key}: {printed:?} is not a {unit}"));
                if (x - a * scale).abs() > digit {
                    return Err(format!("{key}: printed {x} {unit}, the daemon said {a}"));
                }
            }
            (None, None) => assert!(number.is_none(), "{key}: {printed:?}, no reading yet"),
            _ => {}
        }
        Ok(())
    };
    check(&f["position"], "µm", "position_m", 1e6, 1e-3)?;
    check(&f["command"], "A", "command_a", 1.0, 1e-4)
}

/// `status` printed and exited as the daemon's state says: 0 healthy, the
/// fault status when a fault is latched; `--json` is the daemon's answer.
fn check_status(d: &Daemon) -> Value {
    // The reading to the printed digits: read again while the stage still
    // moves (20 tries over 2 s); a wrong printout fails every try.
    let mut attempt = 0;
    let (s0, want) = loop {
        let s0 = status_json(d);
        let o = daemon_cmd(&d.socket, &["status"]);
        let s1 = status_json(d);
        let want = if s0["fault"].is_null() { 0 } else { FAULT };
        assert_eq!(o.status.code(), Some(want), "{s0}\n{}", stderr(&o));
        assert_status_printed(&o, &s0, &s1);
        match reading_printed(&o, &s0, &s1) {
            Ok(()) => break (s0, want),
            Err(e) if attempt >= 19 => panic!("{e} (20 tries)"),
            Err(_) => {
                attempt += 1;
                std::thread::sleep(std::time::Duration::from_millis(100));
            }
        }
    };
    // --json: the daemon's result itself (less what moves by the tick).
    let o = daemon_cmd(&d.socket, &["status", "--json"]);
    assert_eq!(o.status.code(), Some(want), "{}", stderr(&o));
    let mut printed = json_stdout(&o);
    let mut s = status_json(d);
    for v in [&mut printed, &mut s] {
        for k in ["position_m", "command_a"] {
            v.as_object_mut().unwrap().remove(k);
        }
        if let Some(j) = v["job"].as_object_mut() {
            j.remove("ticks");
        }
    }
    assert_eq!(printed, s);
    s0
}

#[test]
fn status_reset_stop_and_shutdown_against_a_daemon() {
    let _g = one_at_a_time();
    let mut d = Daemon::start();
    let mut c = d.client();
    // Idle: healthy, exit 0.
    let s = check_status(&d);
    assert_eq!(s["state"], "disabled", "{s}");

    // Enable and disable between jobs.
    let o = daemon_cmd(&d.socket, &["enable"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        fields(&o)["state"],
        status_json(&d)["state"].as_str().unwrap()
    );
    assert_eq!(status_json(&d)["state"], "enabled");
    let o = daemon_cmd(&d.socket, &["disable", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(json_stdout(&o)["state"], status_json(&d)["state"]);
    assert_eq!(status_json(&d)["state"], "disabled");

    // A job that faults latches the fault.
    let r = c.call(
        "control",
        json!({ "controller": "fast", "duration_s": 1.5, "inject_fault": "drop@0.3", "pace": "off" }),
    );
    assert_eq!(r["error"]["kind"], "fault", "{r}");
    let s = check_status(&d);
    assert_eq!(s["state"], "faulted", "{s}");
    // `enable` is refused: the daemon's own message, exit 5; still faulted.
    let refusal = c.call("enable", json!({}));
    assert_eq!(refusal["error"]["kind"], "faulted", "{refusal}");
    let o = daemon_cmd(&d.socket, &["enable"]);
    assert_eq!(o.status.code(), Some(REFUSED), "{}", stderr(&o));
    assert!(
        stderr(&o).contains(refusal["error"]["message"].as_str().unwrap()),
        "{}",
        stderr(&o)
    );
    assert_eq!(status_json(&d)["state"], "faulted");
    // The script's idiom: status fails, reset answers it.
    let o = daemon_cmd(&d.socket, &["reset"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = status_json(&d);
    assert!(s["fault"].is_null(), "{s}");
    assert_eq!(fields(&o)["state"], s["state"].as_str().unwrap());
    let s = check_status(&d);
    assert_eq!(s["state"], "disabled", "{s}");

    // `stop` with no job: nothing to do, exit 0, nothing changes.
    let before = status_json(&d);
    let o = daemon_cmd(&d.socket, &["stop", "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(json_stdout(&o), c.call("stop", json!({}))["result"]);
    let after = status_json(&d);
    assert_eq!(
        (&before["state"], &before["jobs_run"], &before["job"]),
        (&after["state"], &after["jobs_run"], &after["job"])
    );

    // A running job: status shows it (exit 0); reset is refused with the
    // daemon's message (exit 5); stop returns once the job has ended.
    let mut a = d.client();
    let started = a.submit("chirp", json!({ "duration_s": 30, "f_start_hz": 2 }));
    wait_state(&mut c, "running", Duration::from_secs(10));
    let s = check_status(&d);
    assert_eq!(s["job"]["id"], started["job"], "{s}");
    let refusal = c.call("reset", json!({}));
    assert_eq!(refusal["error"]["kind"], "busy", "{refusal}");
    let o = daemon_cmd(&d.socket, &["reset"]);
    assert_eq!(o.status.code(), Some(REFUSED), "{}", stderr(&o));
    assert!(
        stderr(&o).contains(refusal["error"]["message"].as_str().unwrap()),
        "{}",
        stderr(&o)
    );
    let o = daemon_cmd(&d.socket, &["stop"]);
    assert!(o.status.success(), "{}", stderr(&o));
    // Returned only once the job was over.
    let s = status_json(&d);
    assert!(s["job"].is_null(), "{s}");
    assert_ne!(s["state"], "running", "{s}");
    assert_eq!(fields(&o)["state"], s["state"].as_str().unwrap());
    assert!(fields(&o)["stopped"].contains(&started["job"].to_string()));
    let r = a.response();
    assert_eq!(r["error"]["kind"], "interrupted", "{r}");

    // Shutdown: returns once the socket is gone; the daemon exits 0.
    let o = daemon_cmd(&d.socket, &["shutdown"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!d.socket.exists(), "the socket is still there");
    let t0 = Instant::now();
    let st = loop {
        if let Some(st) = d.child.try_wait().unwrap() {
            break st;
        }
        assert!(t0.elapsed() < Duration::from_secs(10), "daemon still up");
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(st.success(), "{st}");
    // Now nothing answers there.
    let o = daemon_cmd(&d.socket, &["status"]);
    assert_eq!(o.status.code(), Some(NO_DAEMON), "{}", stderr(&o));
}

/// A daemon whose fault latches between jobs (`--inject-fault`): `status`
/// exits with the fault status until `reset`.
#[test]
fn a_fault_between_jobs_then_reset() {
    let _g = one_at_a_time();
    let d = Daemon::start_with(&["--inject-fault", "jump@0.5"], "");
    let mut c = d.client();
    wait_state(&mut c, "faulted", Duration::from_secs(15));
    let s = check_status(&d);
    assert_eq!(s["fault"]["kind"], "position_jump", "{s}");
    let o = run(&[
        "daemon",
        "--socket",
        d.socket.to_str().unwrap(),
        "reset",
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(json_stdout(&o)["state"], status_json(&d)["state"]);
    let s = check_status(&d);
    assert!(s["fault"].is_null(), "{s}");
}

#[test]
fn no_daemon_and_paths_that_are_not_sockets() {
    let dir = tmp();
    // Nothing there: exit 6, the message names the socket, for every
    // command.
    let none = dir.path().join("none.sock");
    for cmd in ["status", "reset", "enable", "disable", "stop", "shutdown"] {
        let o = daemon_cmd(&none, &[cmd]);
        assert_eq!(o.status.code(), Some(NO_DAEMON), "{cmd}: {}", stderr(&o));
        let err = stderr(&o);
        assert!(
            err.contains(none.to_str().unwrap()) && err.contains("no daemon"),
            "{cmd}: {err}"
        );
        assert!(o.stdout.is_empty(), "{cmd}: {}", stdout(&o));
    }
    // A stale socket (its daemon gone): exit 6, and it is left alone.
    let stale = dir.path().join("stale.sock");
    drop(std::os::unix::net::UnixListener::bind(&stale).unwrap());
    let o = daemon_cmd(&stale, &["status"]);
    assert_eq!(o.status.code(), Some(NO_DAEMON), "{}", stderr(&o));
    assert!(
        stderr(&o).contains(stale.to_str().unwrap()),
        "{}",
        stderr(&o)
    );
    assert!(stale.exists());
    // A directory and a plain file: bad input naming --socket; the file is
    // untouched.
    let file = dir.path().join("notes.txt");
    std::fs::write(&file, "keep me").unwrap();
    for (path, what) in [(dir.path(), "directory"), (file.as_path(), "not a socket")] {
        let o = daemon_cmd(path, &["reset"]);
        assert_eq!(o.status.code(), Some(BAD_INPUT), "{path:?}: {}", stderr(&o));
        let err = stderr(&o);
        assert!(
            err.contains(&format!("--socket {}", path.display())) && err.contains(what),
            "{err}"
        );
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "keep me");
    // An empty path is bad input too.
    let o = run(&["daemon", "status", "--socket", ""]);
    assert_eq!(o.status.code(), Some(BAD_INPUT), "{}", stderr(&o));
    assert!(stderr(&o).contains("--socket"), "{}", stderr(&o));
    // Without --socket: the default rule of `bench serve`,
    // $XDG_RUNTIME_DIR/bench.sock.
    let o = bench()
        .env("XDG_RUNTIME_DIR", dir.path())
        .args(["daemon", "status"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(NO_DAEMON), "{}", stderr(&o));
    assert!(
        stderr(&o).contains(dir.path().join("bench.sock").to_str().unwrap()),
        "{}",
        stderr(&o)
    );
}

/// The default socket reaches a daemon `bench serve` started without
/// `--socket` (the same rule on both sides).
#[test]
fn the_default_socket_is_the_servers() {
    let _g = one_at_a_time();
    let dir = tmp();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o700)).unwrap();
    let config = quiet_config(dir.path(), 1.0, "");
    let mut serve = bench();
    let _serve = KillOnDrop::new(
        serve
            .env("XDG_RUNTIME_DIR", dir.path())
            .env("RUST_LOG", "warn")
            .args([
                "serve",
                "--config",
                config.to_str().unwrap(),
                "--recordings",
                dir.path().join("rec").to_str().unwrap(),
            ])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap(),
    );
    let socket = dir.path().join("bench.sock");
    let t0 = Instant::now();
    while std::os::unix::net::UnixStream::connect(&socket).is_err() {
        assert!(t0.elapsed() < Duration::from_secs(20), "no daemon came up");
        std::thread::sleep(Duration::from_millis(20));
    }
    let o = bench()
        .env("XDG_RUNTIME_DIR", dir.path())
        .args(["daemon", "status", "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let mut c = Client::new(&socket);
    let s = c.call("status", json!({}))["result"].clone();
    assert_eq!(json_stdout(&o)["backend"], s["backend"]);
    assert_eq!(json_stdout(&o)["state"], s["state"]);
}

#[test]
fn the_man_page_and_help_give_the_exit_statuses() {
    let o = run(&["man", "daemon"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let page = stdout(&o);
    assert!(page.contains(".TH bench-daemon"), "{page}");
    for sub in ["status", "reset", "enable", "disable", "stop", "shutdown"] {
        assert!(page.contains(&format!("bench\\-daemon\\-{sub}")), "{sub}");
        let o = run(&["daemon", sub, "--help"]);
        assert!(o.status.success(), "{}", stderr(&o));
        let help = stdout(&o);
        assert!(help.contains("Exit status: 0 "), "{sub}: {help}");
        assert!(
            help.contains(&format!("{NO_DAEMON} no daemon")),
            "{sub}: {help}"
        );
    }
    let help = stdout(&run(&["daemon", "status", "--help"]));
    assert!(
        help.contains(&format!("{FAULT} a fault is latched")),
        "{help}"
    );
    let help = stdout(&run(&["daemon", "reset", "--help"]));
    assert!(help.contains(&format!("{REFUSED} refused")), "{help}");
    let o = run(&["man", "daemon", "status"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("Exit status"));
}
