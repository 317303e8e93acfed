//! `bench serve` through its socket, as a separate process: requests and
//! errors, jobs equal to local runs, one job at a time, stop, SIGTERM, the
//! unattended rule, latched faults, socket permissions, and 1000 status
//! requests during a real-time job.

use crate::common;
use crate::daemon_fixtures;

use common::*;
use daemon_fixtures::*;
use serde_json::{json, Value};
use std::io::{BufRead, BufReader};
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

#[test]
fn requests_errors_and_jobs_equal_to_local_runs() {
    let _g = one_at_a_time();
    let d = Daemon::start();
    // Owner-only socket.
    let mode = std::fs::metadata(&d.socket).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o600, "socket mode {mode:o}");
    let mut c = d.client();
    let s = c.call("status", json!({}));
    assert_eq!(s["ok"], true);
    assert_eq!(s["result"]["state"], "disabled");
    assert_eq!(s["result"]["backend"], "sim:sr4dof");
    // Malformed JSON, unknown commands, bad parameters: errors, and the
    // daemon keeps serving.
    c.send_raw("{not json");
    let r = c.response();
    assert_eq!(r["error"]["kind"], "bad_request", "{r}");
    c.send_raw(r#"{"id": 7}"#);
    assert_eq!(c.response()["error"]["kind"], "bad_request");
    assert_eq!(
        c.call("frobnicate", json!({}))["error"]["kind"],
        "unknown_command"
    );
    let r = c.call("chirp", json!({ "amplitude_a": "loud" }));
    assert_eq!(r["error"]["kind"], "bad_params", "{r}");
    assert!(r["error"]["message"]
        .as_str()
        .unwrap()
        .contains("amplitude_a"));
    let r = c.call("chirp", json!({ "f_end_hz": 1e5 }));
    assert_eq!(r["error"]["kind"], "bad_params", "{r}");
    assert!(
        r["error"]["message"].as_str().unwrap().contains("f_end_hz"),
        "{r}"
    );
    let r = c.call("control", json!({ "controller": "nope" }));
    assert_eq!(r["error"]["kind"], "bad_params", "{r}");
    assert_eq!(c.call("status", json!({}))["result"]["state"], "disabled");

    let cfg = d.config.display().to_string();
    // The fast step, both ways (first: after a chirp the lightly damped
    // modes ring for seconds, and a step on a ringing stage settles later).
    let o = run(&[
        "control",
        "--fast",
        "--daemon",
        &d.sock(),
        "--duration-s",
        "1.5",
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = json_stdout(&o);
    let out = path_in(d.dir.path(), "local-step.mcap");
    let o = run(&[
        "control",
        "--fast",
        "--config",
        &cfg,
        "--out",
        &out,
        "--duration-s",
        "1.5",
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let l = json_stdout(&o);
    for k in ["rise_time_s", "settling_time_s", "overshoot_pct"] {
        let (a, b) = (
            r["metrics"][k].as_f64().unwrap(),
            l["metrics"][k].as_f64().unwrap(),
        );
        // Within 2 %, or two ticks (0.4 ms) for the tick-quantised times.
        assert!(
            (a - b).abs() <= (0.02 * b.abs()).max(if k == "overshoot_pct" { 0.5 } else { 4e-4 }),
            "{k}: daemon {a}, local {b}"
        );
    }
    // A chirp through the socket (the CLI client) and locally, once the
    // step's ringing has died down (29 Hz mode: time constant 0.6 s).
    std::thread::sleep(Duration::from_secs(4));
    let args = ["--f-start-hz", "5", "--duration-s", "3", "--json"];
    let mut remote = vec!["chirp", "--daemon", d.socket.to_str().unwrap()];
    remote.extend(args);
    let o = run(&remote);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = json_stdout(&o);
    let out = path_in(d.dir.path(), "local.mcap");
    let mut local = vec!["chirp", "--config", &cfg, "--out", &out];
    local.extend(args);
    let o = run(&local);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let l = json_stdout(&o);
    // The two measured FRFs agree where both are coherent. (Compared as
    // measurements: the modal fit on top of them is a nonlinear search, and
    // a 3 s sweep after a step leaves it free to settle differently on
    // equal data.)
    let frf = |v: &Value| common::read_frf_csv(Path::new(v["frf_csv"].as_str().unwrap()));
    let (fr, fl) = (frf(&r), frf(&l));
    // The daemon runs in real time: a host stall leaves its span out of
    // that FRF (`stalls` in its summary), so the grids are matched by
    // frequency; every daemon line is a line of the local grid.
    let excluded = r["stalls"]["excluded_lines"].as_u64().unwrap() as usize;
    assert_eq!(fr.len() + excluded, fl.len(), "{}", r["stalls"]);
    let mut rel: Vec<f64> = fr
        .iter()
        .map(|a| {
            let b = fl
                .iter()
                .find(|b| b[0] == a[0])
                .unwrap_or_else(|| panic!("{} Hz not on the local grid", a[0]));
            (a, b)
        })
        .filter(|(a, b)| a[3] >= 0.9 && b[3] >= 0.9)
        .map(|(a, b)| (a[1] / b[1] - 1.0).abs())
        .collect();
    assert!(
        rel.len() > fr.len() / 2,
        "{} of {} points coherent",
        rel.len(),
        fr.len()
    );
    rel.sort_by(f64::total_cmp);
    let (median, p95) = (rel[rel.len() / 2], rel[rel.len() * 95 / 100]);
    assert!(
        median < 0.01 && p95 < 0.05,
        "|H| daemon/local − 1: median {median}, p95 {p95}"
    );
    // Its recording is under recordings/, finished.
    let rec = Path::new(r["recording"].as_str().unwrap()).to_path_buf();
    assert!(
        rec.starts_with(d.dir.path().join("rec")) && rec.exists(),
        "{rec:?}"
    );

    assert_eq!(c.call("status", json!({}))["result"]["jobs_run"], 2);
    // The rolling event log has the jobs.
    let log = std::fs::read_to_string(d.dir.path().join("rec/daemon-events.jsonl")).unwrap();
    assert!(log.contains("job_started") && log.contains("job_finished"));
}

/// The recording ends with the interruption, then the loop's teardown
/// (0 A, amplifier disabled: the `disabled` state) and the loop's end.
fn assert_stopped_at_zero_amps(rec: &Path) {
    let events: Vec<Value> = mcap_messages(rec)
        .into_iter()
        .filter(|m| m.0 == "/bench/event")
        .map(|m| m.2)
        .collect();
    let i = events
        .iter()
        .position(|e| e["kind"] == "interrupted")
        .expect("no interrupted event");
    let after: Vec<(&Value, &Value)> = events[i..]
        .iter()
        .map(|e| (&e["kind"], &e["state"]))
        .collect();
    assert!(
        after
            .iter()
            .any(|(k, s)| *k == "state_changed" && *s == "disabled"),
        "{after:?}"
    );
    assert_eq!(events.last().unwrap()["kind"], "loop_stopped");
}

#[test]
fn one_job_at_a_time_and_stop_leaves_zero_amps() {
    let _g = one_at_a_time();
    let d = Daemon::start();
    let mut a = d.client();
    let started = a.submit("chirp", json!({ "duration_s": 30, "f_start_hz": 2 }));
    let rec = PathBuf::from(started["recording"].as_str().unwrap());
    let mut b = d.client();
    let r = b.call("control", json!({ "controller": "fast" }));
    assert_eq!(r["error"]["kind"], "busy", "{r}");
    for cmd in ["enable", "disable", "reset"] {
        let r = b.call(cmd, json!({}));
        assert_eq!(r["error"]["kind"], "busy", "{cmd}: {r}");
    }
    let s = wait_state(&mut b, "running", Duration::from_secs(5));
    assert_eq!(s["job"]["kind"], "chirp");
    std::thread::sleep(Duration::from_millis(700));
    let s = b.call("status", json!({}))["result"].clone();
    assert!(s["job"]["ticks"].as_u64().unwrap() > 0, "{s}");
    assert_eq!(b.call("stop", json!({}))["ok"], true);
    // The submitter gets its answer: interrupted, recording finished.
    let r = a.response();
    assert_eq!(r["error"]["kind"], "interrupted", "{r}");
    assert!(rec.exists(), "{rec:?} not finished");
    assert_stopped_at_zero_amps(&rec);
    wait_state(&mut b, "disabled", Duration::from_secs(5));
}

#[test]
fn sigterm_mid_job_finishes_the_recording_and_removes_the_socket() {
    let _g = one_at_a_time();
    let d = Daemon::start();
    let mut a = d.client();
    let started = a.submit("chirp", json!({ "duration_s": 30, "f_start_hz": 2 }));
    let rec = PathBuf::from(started["recording"].as_str().unwrap());
    std::thread::sleep(Duration::from_millis(800));
    let mut d = d;
    // SAFETY: plain kill(2) on our child.
    unsafe { libc::kill(d.child.id() as i32, libc::SIGTERM) };
    let status = d.child.wait().unwrap();
    assert!(status.success(), "exit {status:?}");
    assert!(!d.socket.exists(), "socket left behind");
    assert!(rec.exists(), "recording not finished");
    assert_stopped_at_zero_amps(&rec);
    // The client got its interrupted answer before the daemon left.
    let r = a.response();
    assert_eq!(r["error"]["kind"], "interrupted", "{r}");
}

/// The detached control job runs in real time: a machine stall beyond
/// the loop's bound (the VM's vCPU not run for tens of ms, seen by
/// [`HostStallWatch`]) ends it on `overruns`, rightly. That attempt is
/// tried again (at most 3), as an operator would; a fault the machine
/// did not make fails at once.
#[test]
fn a_client_that_leaves_stops_its_job_unless_detached() {
    let _g = one_at_a_time();
    let mut seen = Vec::new();
    let (d, mut b) = loop {
        let d = Daemon::start();
        let watch = HostStallWatch::start(79);
        {
            let mut a = d.client();
            a.submit("chirp", json!({ "duration_s": 30, "f_start_hz": 2 }));
        } // disconnects
        let mut b = d.client();
        wait_state(&mut b, "disabled", Duration::from_secs(5));
        {
            let mut a = d.client();
            a.submit(
                "control",
                json!({ "controller": "fast", "duration_s": 1.5, "detach": true }),
            );
        }
        std::thread::sleep(Duration::from_millis(500));
        let s = b.call("status", json!({}))["result"].clone();
        let machine_ms = watch.stop() * 1e3;
        if s["state"] == "running" {
            break (d, b);
        }
        let by_machine = s["fault"]["kind"] == "overruns" && machine_ms >= 5.0;
        assert!(
            by_machine && seen.len() < 2,
            "the detached job is not running (machine late {machine_ms:.1} ms; retried: {seen:?}): {s}"
        );
        seen.push(format!(
            "{} with the machine late {machine_ms:.1} ms",
            s["fault"]
        ));
    };
    let s = wait_state(&mut b, "disabled", Duration::from_secs(20));
    assert_eq!(s["jobs_run"], 2);
    // `shutdown`: the daemon exits 0 and removes its socket.
    assert_eq!(b.call("shutdown", json!({}))["ok"], true);
    let mut d = d;
    let t0 = Instant::now();
    let status = loop {
        if let Some(st) = d.child.try_wait().unwrap() {
            break st;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "daemon did not shut down"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(status.success(), "{status:?}");
    assert!(!d.socket.exists());
}

#[test]
fn faults_latch_until_reset() {
    let _g = one_at_a_time();
    let d = Daemon::start();
    let mut c = d.client();
    // In virtual time: the latch is the subject, not the loop's timing
    // (in real time a machine stall beyond the loop's delay bound could
    // latch an overruns fault before the injected drop).
    let r = c.call(
        "control",
        json!({ "controller": "fast", "duration_s": 1.5, "inject_fault": "drop@0.3", "pace": "off" }),
    );
    assert_eq!(r["error"]["kind"], "fault", "{r}");
    let s = c.call("status", json!({}))["result"].clone();
    assert_eq!(s["state"], "faulted");
    assert_eq!(s["fault"]["kind"], "link", "{s}");
    assert!(s["fault"]["message"].as_str().unwrap().contains("link"));
    assert_eq!(c.call("enable", json!({}))["error"]["kind"], "faulted");
    assert_eq!(c.call("chirp", json!({}))["error"]["kind"], "faulted");
    assert_eq!(c.call("reset", json!({}))["ok"], true);
    assert_eq!(c.call("enable", json!({}))["ok"], true);
    assert_eq!(c.call("status", json!({}))["result"]["state"], "enabled");
    assert_eq!(c.call("disable", json!({}))["ok"], true);
    // The CLI client maps the fault to the fault exit status.
    let o = run(&[
        "control",
        "--fast",
        "--daemon",
        &d.sock(),
        "--duration-s",
        "1.5",
        "--inject-fault",
        "jump@0.3",
    ]);
    assert_eq!(
        o.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let o = run(&[
        "control",
        "--fast",
        "--daemon",
        &d.sock(),
        "--duration-s",
        "1.5",
    ]);
    assert_eq!(
        o.status.code(),
        Some(5),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// A daemon on the serial backend, against the emulator as a user runs it
/// (`bench emulate serial`) with `faults`; the emulator process is killed
/// when the pair is dropped.
struct SerialDaemon {
    daemon: Daemon,
    emulator: Child,
    _dir: tempfile::TempDir,
}

impl SerialDaemon {
    fn start(faults: &[&str]) -> Self {
        Self::start_edited(faults, |t| t.to_string())
    }

    /// The emulator and the daemon with their config passed through `edit`.
    fn start_edited(faults: &[&str], edit: impl Fn(&str) -> String) -> Self {
        let dir = tmp();
        let cfg = common::quiet_config_edited(dir.path(), 1.0, SERIAL_EXTRA, &edit);
        let (emulator, pty) = spawn_emulator(&cfg, faults);
        let daemon = Daemon::start_edited(
            &["--backend", &format!("serial:{pty}")],
            SERIAL_EXTRA,
            &edit,
            |_| {},
        );
        Self {
            daemon,
            emulator,
            _dir: dir,
        }
    }
}

impl Drop for SerialDaemon {
    fn drop(&mut self) {
        let _ = self.daemon.child.kill();
        let _ = self.daemon.child.wait();
        let _ = self.emulator.kill();
        let _ = self.emulator.wait();
    }
}

/// The serial emulator as a user runs it (`bench emulate serial`), with
/// link faults; returns the process and its pty path.
fn spawn_emulator(config: &Path, faults: &[&str]) -> (Child, String) {
    let mut cmd = bench();
    cmd.args(["emulate", "serial", "--config", config.to_str().unwrap()]);
    for f in faults {
        cmd.args(["--fault", f]);
    }
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    (child, line.trim().to_string())
}

/// The link limits of the hardware tests: this 2-core VM stalls even
/// SCHED_FIFO threads for tens of ms at times, so only injected faults
/// trip them.
const SERIAL_EXTRA: &str =
    "\n[backend.serial]\nsample_timeout_periods = 200.0\n\n[emulator]\nwatchdog_ms = 300.0\n";

/// A fault the loop latches between jobs: `status` reports it with its
/// cause, `enable` and jobs are refused until `reset`, then both work.
fn assert_latched_between_jobs(d: &Daemon, kind: &str, what: &str) {
    let mut c = d.client();
    let s = wait_state(&mut c, "faulted", Duration::from_secs(15));
    assert_eq!(s["fault"]["kind"], kind, "{what}: {s}");
    let msg = s["fault"]["message"].as_str().unwrap();
    assert!(
        msg.contains("between jobs") && msg.contains(kind),
        "{what}: {msg}"
    );
    assert!(s["job"].is_null(), "{what}: {s}");
    let e = c.call("enable", json!({}));
    assert_eq!(e["error"]["kind"], "faulted", "{what}: {e}");
    let e = c.call("chirp", json!({ "duration_s": 0.5 }));
    assert_eq!(e["error"]["kind"], "faulted", "{what}: {e}");
    let e = c.call(
        "control",
        json!({ "controller": "fast", "duration_s": 0.5 }),
    );
    assert_eq!(e["error"]["kind"], "faulted", "{what}: {e}");
    // Still faulted after the refusals.
    let s = c.call("status", json!({}))["result"].clone();
    assert_eq!(s["state"], "faulted", "{what}: {s}");
    assert_eq!(c.call("reset", json!({}))["ok"], true, "{what}");
}

/// Every simulator fault injected while no job runs latches in the one
/// supervisor of the daemon's loop, with its own fault name.
#[test]
fn sim_faults_between_jobs_latch_until_reset() {
    let _g = one_at_a_time();
    // (fault, its name, whether the cause persists after the reset)
    for (fault, kind, persists) in [
        ("nan@0.8", "probe_not_finite", true),
        ("frozen@0.8", "stale_sample", true),
        ("drop@0.8", "link", false),
        ("jump@0.8", "position_jump", false),
        ("out_of_range@0.8", "probe_out_of_range", true),
    ] {
        let d = Daemon::start_with(&["--inject-fault", fault], "");
        assert_latched_between_jobs(&d, kind, fault);
        let mut c = d.client();
        if persists {
            // The probe still reads NaN / frozen / out of range: the same
            // supervisor latches it again at once.
            let s = wait_state(&mut c, "faulted", Duration::from_secs(5));
            assert_eq!(s["fault"]["kind"], kind, "{fault} after reset: {s}");
        } else {
            // A one-off fault (a gap, a step in the reading) is gone after
            // the reset: the loop holds cleanly and a job runs.
            std::thread::sleep(Duration::from_millis(300));
            let s = c.call("status", json!({}))["result"].clone();
            assert_eq!(s["state"], "disabled", "{fault} after reset: {s}");
            let r = c.call(
                "control",
                json!({ "controller": "fast", "duration_s": 0.5, "pace": "off" }),
            );
            assert_eq!(r["ok"], true, "{fault}: {r}");
        }
    }
}

/// A host stall between jobs (the loop thread blocked 60 ms, 300
/// deadlines missed at 5 kHz) with the amplifier disabled at 0 A is
/// reported and never latched: there is nothing to protect. Jobs still run
/// afterwards, and a stall in the middle of the idle loop is not counted
/// against the next job.
#[test]
fn a_stall_between_jobs_never_latches() {
    let _g = one_at_a_time();
    let d = Daemon::start_with(&["--inject-fault", "stall:60@0.8"], "");
    let mut c = d.client();
    // Past the stall (0.8 s of loop time, then 60 ms).
    let t0 = std::time::Instant::now();
    while t0.elapsed() < Duration::from_secs(2) {
        let s = c.call("status", json!({}))["result"].clone();
        assert_ne!(s["state"], "faulted", "latched a stall between jobs: {s}");
        std::thread::sleep(Duration::from_millis(100));
    }
    let r = c.call("chirp", json!({ "duration_s": 0.5, "pace": "off" }));
    assert_eq!(r["ok"], true, "{r}");
}

/// A serial link silent for 30 ms between jobs (frames held back, as a
/// USB hiccup does), shorter than the device's 50 ms watchdog: nothing is
/// latched, and the next job runs.
#[test]
fn a_silent_serial_link_between_jobs_never_latches() {
    let _g = one_at_a_time();
    let s = SerialDaemon::start(&["hold:0.03@2"]);
    let mut c = s.daemon.client();
    let t0 = std::time::Instant::now();
    while t0.elapsed() < Duration::from_secs(3) {
        let st = c.call("status", json!({}))["result"].clone();
        assert_ne!(
            st["state"], "faulted",
            "latched a hiccup between jobs: {st}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let r = c.call_realtime("chirp", json!({ "duration_s": 0.5 }));
    assert_eq!(r["ok"], true, "{r}");
}

/// Link faults of the serial device between jobs (a hung device, a
/// disconnect, a burst of corrupt frames) latch the `link` fault.
#[test]
fn serial_link_faults_between_jobs_latch_until_reset() {
    let _g = one_at_a_time();
    for fault in ["stall:1.0@2", "disconnect@2", "bitflip:8x12@2"] {
        let s = SerialDaemon::start(&[fault]);
        assert_latched_between_jobs(&s.daemon, "link", fault);
    }
}

/// 20 consecutive control jobs over the serial emulator all start and end
/// cleanly (no backlog at hand-over), and each job's link counters are its
/// own, not the daemon's life.
#[test]
fn twenty_serial_daemon_jobs_start_cleanly() {
    let _g = one_at_a_time();
    // The gap fault is not under test here, the backlog count is: with the
    // shipped limit (3 samples) a 1.4 ms host stall at a job's first tick
    // faulted the job on CI (7 samples missing at tick 0). Here the limit is
    // 20 samples (4 ms; the largest the 40 ms sample timeout allows is 24),
    // far below the 300-400-sample backlog the regression left.
    let s = SerialDaemon::start_edited(&[], |t| common::set_key(t, "max_missed_samples", "20"));
    let mut c = s.daemon.client();
    for i in 0..20 {
        // Some time between jobs: the loop keeps reading the device.
        std::thread::sleep(Duration::from_millis(50 + 20 * (i % 5)));
        let r = c.call_realtime(
            "control",
            json!({ "controller": "fast", "duration_s": 0.5 }),
        );
        assert_eq!(r["ok"], true, "job {i}: {r}");
        let ticks = r["result"]["timing"]["ticks"].as_u64().unwrap();
        let samples = r["result"]["link"]["samples"].as_u64().unwrap();
        assert_eq!(ticks, 2500, "job {i}");
        assert!(
            (ticks..=ticks + 2).contains(&samples),
            "job {i}: {samples} samples counted for {ticks} ticks: {}",
            r["result"]["link"]
        );
        // Before the one loop, the backlog of the pause between jobs came
        // out as a gap of 300-400 samples at tick 1 (the 50-130 ms pause at
        // 5 kHz). Now only what scheduling stalls lose may be missing: a
        // sample or two on a quiet VM, 8 seen once with the whole test
        // suite running on both cores. The bound sits well below the
        // regression and well above the stalls (no timing assertion: the
        // backlog is a count of the pause's samples, not a latency).
        let missed = r["result"]["link"]["missed_samples"].as_u64().unwrap();
        assert!(missed < 100, "job {i}: {missed} samples missed: {r}");
    }
}

/// Enabled between jobs, the daemon holds 0 A, or, with `[daemon]
/// hold_controller`, holds the position with that controller (a non-zero
/// current against the probe noise and the disturbance of the shipped
/// bench, the stage within a micrometre); a job takes over from the hold
/// and ends disabled at 0 A.
#[test]
fn hold_between_jobs_is_zero_current_or_the_hold_controller() {
    let _g = one_at_a_time();
    let sample = |c: &mut Client| {
        let s = c.call("status", json!({}))["result"].clone();
        (
            s["command_a"].as_f64().unwrap(),
            s["position_m"].as_f64().unwrap_or(f64::NAN),
        )
    };
    // Zero current.
    let d = Daemon::start();
    let mut c = d.client();
    assert_eq!(
        c.call("status", json!({}))["result"]["hold"],
        "zero_current"
    );
    assert_eq!(c.call("enable", json!({}))["ok"], true);
    for _ in 0..20 {
        assert_eq!(sample(&mut c).0, 0.0);
        std::thread::sleep(Duration::from_millis(10));
    }
    drop(d);
    // The fast controller holds the position (shipped bench: disturbance
    // and probe noise on).
    let dir = tmp();
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o700)).unwrap();
    let text = relax_timing_bounds(
        &std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"),
        )
        .unwrap(),
    ) + "\n[daemon]\nhold_controller = \"fast\"\n";
    let config = dir.path().join("bench.toml");
    std::fs::write(&config, text).unwrap();
    let socket = dir.path().join("bench.sock");
    let mut child = spawn_serve(&config, &socket, &dir.path().join("rec"), &[]);
    let mut c = Client::new(&socket);
    let s = c.call("status", json!({}))["result"].clone();
    assert_eq!(s["hold"], "position (controller fast)", "{s}");
    // Disabled, the hold controller does not drive.
    assert_eq!(sample(&mut c).0, 0.0);
    assert_eq!(c.call("enable", json!({}))["ok"], true);
    let mut driven = 0;
    for _ in 0..40 {
        std::thread::sleep(Duration::from_millis(10));
        let (i, x) = sample(&mut c);
        if i != 0.0 {
            driven += 1;
        }
        assert!(i.abs() < 1.0, "hold current {i} A");
        assert!(x.abs() < 1e-6, "held at {x} m");
    }
    assert!(
        driven > 30,
        "the hold controller commanded 0 A {} times",
        40 - driven
    );
    // A job takes over and leaves the amplifier disabled at 0 A.
    let r = c.call(
        "control",
        json!({ "controller": "fast", "duration_s": 0.5, "pace": "off" }),
    );
    assert_eq!(r["ok"], true, "{r}");
    let s = c.call("status", json!({}))["result"].clone();
    assert_eq!(s["state"], "disabled", "{s}");
    assert_eq!(s["command_a"], 0.0, "{s}");
    // Enabled again, then disabled: the hold ends at 0 A.
    assert_eq!(c.call("enable", json!({}))["ok"], true);
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(c.call("disable", json!({}))["ok"], true);
    std::thread::sleep(Duration::from_millis(50));
    assert_eq!(sample(&mut c).0, 0.0);
    let _ = child.kill();
    let _ = child.wait();
}

/// A hold controller that fails the loop check keeps the daemon from
/// starting (exit 2, the key named).
#[test]
fn a_hold_controller_that_fails_the_loop_check_is_refused() {
    let dir = tmp();
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o700)).unwrap();
    // Ten times the fast controller's gain is unstable (Chapter 6).
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"),
    )
    .unwrap();
    let fast = text.find("[controller.fast]").unwrap();
    let gain = fast + text[fast..].find("\ngain = ").unwrap() + 1;
    let end = gain + text[gain..].find('\n').unwrap();
    let value: f64 = text[gain + 7..end]
        .split('#')
        .next()
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    let text = format!(
        "{}gain = {:e}{}\n[daemon]\nhold_controller = \"fast\"\n",
        &text[..gain],
        10.0 * value,
        &text[end..]
    );
    let config = dir.path().join("bench.toml");
    std::fs::write(&config, text).unwrap();
    let o = run(&[
        "serve",
        "--config",
        config.to_str().unwrap(),
        "--socket",
        dir.path().join("b.sock").to_str().unwrap(),
        "--recordings",
        dir.path().join("rec").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("daemon.hold_controller") && err.contains("loop check"),
        "{err}"
    );
}

/// Another user cannot reach the daemon: its socket is owner-only in a
/// private directory. Run as root, the client is started as uid 65534
/// (nobody).
#[test]
#[cfg_attr(
    not(bench_root),
    ignore = "needs root to start a client as another user (uid 65534)"
)]
fn another_user_cannot_reach_the_daemon() {
    use std::os::unix::process::CommandExt;
    let d = Daemon::start();
    let o = bench()
        .args(["control", "--fast", "--daemon", &d.sock()])
        .uid(65534)
        .gid(65534)
        .output()
        .expect("as root, bench runs as uid 65534");
    assert_eq!(
        o.status.code(),
        Some(2),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(String::from_utf8_lossy(&o.stderr).contains("ermission denied"));
}

#[test]
fn socket_access_and_stale_sockets() {
    let _g = one_at_a_time();
    let d = Daemon::start();
    // A second daemon on a live socket is refused.
    let o = run(&[
        "serve",
        "--config",
        &d.config.display().to_string(),
        "--socket",
        &d.sock(),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("another bench daemon"));
    // A world-writable directory is refused.
    let ww = tmp();
    std::fs::set_permissions(ww.path(), std::fs::Permissions::from_mode(0o777)).unwrap();
    let o = run(&[
        "serve",
        "--config",
        &d.config.display().to_string(),
        "--socket",
        &path_in(ww.path(), "b.sock"),
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("world-writable"));
    // SIGKILL leaves a stale socket; a restart replaces it.
    let socket = d.socket.clone();
    let config = d.config.clone();
    let dir = tmp();
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o700)).unwrap();
    let stale = dir.path().join("s.sock");
    {
        let _l = std::os::unix::net::UnixListener::bind(&stale).unwrap();
    } // closed, file left
    assert!(stale.exists());
    // (spawn_serve fails the test if the socket never answers.)
    let mut child = spawn_serve(
        &config,
        &stale,
        &dir.path().join("rec"),
        &["--socket-group", "root"],
    );
    let mode = std::fs::metadata(&stale).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o660, "with --socket-group: {mode:o}");
    let _ = child.kill();
    let _ = child.wait();
    drop(d);
    let _ = socket;
}

/// 1000 status requests from 10 clients during a real-time fast-loop job
/// leave the loop alone: the job ends without a fault. A stall the machine
/// made (a vCPU the host did not run, which a watch thread on every CPU
/// sees too) faults the job as it must, and the job is run again, at most
/// three times; a stall the watch did not see is the daemon's and fails
/// the test ([`retry_machine_stalls`]).
#[test]
fn thousand_status_requests_during_a_realtime_job() {
    let _g = one_at_a_time();
    let d = Daemon::start();
    let (r, took, machine_stalls) =
        retry_machine_stalls(&mut d.client(), |_| status_storm_during_a_job(&d));
    assert_eq!(r["ok"], true, "{r}");
    let overruns = r["result"]["timing"]["overruns"].as_u64().unwrap();
    eprintln!(
        "1000 status requests from 10 clients in {:.0} ms during the job; loop overruns: {overruns}; earlier attempts ended by the machine's stalls: {machine_stalls:?}",
        took.as_secs_f64() * 1e3
    );
    assert!(r["result"]["metrics"]["settling_time_s"].as_f64().is_some());
}

/// Submits a 4 s fast-loop job and sends 1000 status requests from 10
/// clients while it runs; the job's response and how long the requests took.
fn status_storm_during_a_job(d: &Daemon) -> (Value, Duration) {
    let mut a = d.client();
    a.submit("control", json!({ "controller": "fast", "duration_s": 4 }));
    let t0 = Instant::now();
    let threads: Vec<_> = (0..10)
        .map(|_| {
            let socket = d.socket.clone();
            std::thread::spawn(move || {
                let mut c = Client::new(&socket);
                let mut ok = 0;
                for _ in 0..100 {
                    if c.call("status", json!({}))["ok"] == true {
                        ok += 1;
                    }
                }
                ok
            })
        })
        .collect();
    let answered: u32 = threads.into_iter().map(|t| t.join().unwrap()).sum();
    let took = t0.elapsed();
    assert_eq!(answered, 1000);
    (a.response(), took)
}

/// A track job on the daemon's serial bench (the emulator on a pty): the
/// trials run one after the other on the daemon's loop, which holds 0 A
/// between them; the summary names the serial backend; the feedforward
/// and one learning trial take the raster's error ≥ 10× below feedback
/// alone; the daemon ends disabled, ready for the next job. The model is
/// off the bench ([`crate::track::off_model`]), so that the feedforward
/// leaves more than the noise floor and a learning trial runs.
#[test]
fn a_track_job_runs_on_the_daemons_serial_bench() {
    let _g = one_at_a_time();
    let s = SerialDaemon::start(&[]);
    let model = crate::track::off_model(s.daemon.dir.path());
    let mut c = s.daemon.client();
    let r = c.call_realtime("track", json!({ "trials": 1, "model": model }));
    assert_eq!(r["ok"], true, "{r}");
    let v = &r["result"];
    assert!(v["backend"].as_str().unwrap().starts_with("serial:"), "{v}");
    let trials = v["trials"].as_array().unwrap();
    assert_eq!(trials.len(), 4, "{v}");
    let rms = |i: usize| trials[i]["rms_error_m"].as_f64().unwrap();
    assert!(rms(3) < rms(2), "learning lowers the error: {v}");
    assert!(rms(1) / rms(3) >= 10.0, "{v}");
    for t in trials {
        assert!(Path::new(t["recording"].as_str().unwrap()).is_file(), "{t}");
    }
    assert_eq!(c.call("status", json!({}))["result"]["state"], "disabled");
}
