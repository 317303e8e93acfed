//! Logs follow the ecosystem (issue 17, item 4): `RUST_LOG` (with
//! `BENCH_LOG` as an alias), the daemon logs each job's start and end with
//! its recording path at its default level (`info`), a job that ends on a
//! fault and a fault between jobs name the fault, and nothing writes
//! colour codes into a pipe.

use crate::daemon_fixtures;

use daemon_fixtures::{wait_state, Daemon};
use serde_json::json;
use std::io::Read;
use std::time::Duration;

/// Runs one short control job on a daemon started with `env` (and
/// `RUST_LOG`/`BENCH_LOG` otherwise unset), stops it, returns its stderr
/// and the job's recording.
fn daemon_log(env: &[(&str, &str)]) -> (String, String) {
    let d = Daemon::start_adjusted(&[], "", |c| {
        c.env_remove("RUST_LOG").env_remove("BENCH_LOG");
        for (k, v) in env {
            c.env(k, v);
        }
    });
    let mut c = d.client();
    let r = c.call(
        "control",
        json!({"controller": "fast", "duration_s": 0.4, "pace": "off"}),
    );
    assert_eq!(r["ok"], json!(true), "{r}");
    let recording = r["result"]["recording"].as_str().unwrap().to_string();
    let mut d = d;
    // SAFETY: signalling our own child.
    unsafe { libc::kill(d.child.id() as i32, libc::SIGTERM) };
    let t0 = std::time::Instant::now();
    while d.child.try_wait().unwrap().is_none() {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "daemon did not exit"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let mut err = String::new();
    d.child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    (err, recording)
}

#[test]
fn the_daemon_logs_each_job_with_its_recording_and_no_colour_into_a_pipe() {
    let (err, recording) = daemon_log(&[]);
    assert!(!err.contains('\u{1b}'), "escape codes in a pipe:\n{err}");
    let started = err
        .lines()
        .find(|l| l.contains("job started"))
        .unwrap_or_else(|| panic!("no 'job started' line:\n{err}"));
    assert!(started.contains(&recording), "{started}");
    assert!(
        started.contains("kind=\"control\"") || started.contains("kind=control"),
        "{started}"
    );
    let finished = err
        .lines()
        .find(|l| l.contains("job finished"))
        .unwrap_or_else(|| panic!("no 'job finished' line:\n{err}"));
    assert!(finished.contains(&recording), "{finished}");
}

#[test]
fn rust_log_and_its_alias_bench_log_set_the_level() {
    // RUST_LOG=warn hides the job lines; BENCH_LOG alone does too; RUST_LOG
    // wins over BENCH_LOG.
    for env in [
        vec![("RUST_LOG", "warn")],
        vec![("BENCH_LOG", "warn")],
        vec![("RUST_LOG", "warn"), ("BENCH_LOG", "info")],
    ] {
        let (err, _) = daemon_log(&env);
        assert!(!err.contains("job started"), "{env:?}:\n{err}");
    }
    let (err, _) = daemon_log(&[("RUST_LOG", "info"), ("BENCH_LOG", "warn")]);
    assert!(err.contains("job started"), "RUST_LOG wins:\n{err}");
}

/// SIGTERMs the daemon and returns its stderr.
fn stop_and_read_stderr(mut d: Daemon) -> String {
    // SAFETY: signalling our own child.
    unsafe { libc::kill(d.child.id() as i32, libc::SIGTERM) };
    let t0 = std::time::Instant::now();
    while d.child.try_wait().unwrap().is_none() {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "daemon did not exit"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let mut err = String::new();
    d.child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    err
}

/// A job that ends on a fault is logged with the fault's supervisor name
/// and the job's recording (absolute); a fault between jobs is logged with
/// its name too. No escape codes in the pipe.
#[test]
fn faults_are_logged_with_their_name_and_the_recording() {
    let d = Daemon::start_adjusted(&[], "", |c| {
        c.env_remove("RUST_LOG").env_remove("BENCH_LOG");
    });
    let mut c = d.client();
    // The probe reads NaN 0.3 s into the job: the `probe_not_finite` fault
    // (the supervisor's name, as `status` reports it).
    let r = c.call(
        "control",
        json!({"controller": "fast", "duration_s": 1.0, "inject_fault": "nan@0.3", "pace": "off"}),
    );
    assert_eq!(r["error"]["kind"], json!("fault"), "{r}");
    let s = wait_state(&mut c, "faulted", Duration::from_secs(5));
    let fault = s["fault"]["kind"].as_str().unwrap().to_string();
    assert_eq!(fault, "probe_not_finite", "{s}");
    let recording = s["last_recording"].as_str().unwrap().to_string();
    assert!(
        std::path::Path::new(&recording).is_absolute(),
        "{recording}"
    );
    // Reset: the probe still reads NaN (an injected NaN lasts), so the
    // fault latches again at once, between jobs.
    assert_eq!(c.call("reset", json!({}))["ok"], json!(true));
    let s = wait_state(&mut c, "faulted", Duration::from_secs(10));
    assert!(
        s["fault"]["message"]
            .as_str()
            .unwrap()
            .contains("between jobs"),
        "{s}"
    );
    drop(c);
    let err = stop_and_read_stderr(d);
    assert!(!err.contains('\u{1b}'), "escape codes in a pipe:\n{err}");
    let ended = err
        .lines()
        // (A job the machine's own stall ended first, and was run again,
        // has its own line.)
        .find(|l| l.contains("job ended on a fault") && l.contains(&fault))
        .unwrap_or_else(|| panic!("no 'job ended on a fault' line naming {fault}:\n{err}"));
    assert!(ended.contains("ERROR"), "{ended}");
    assert!(ended.contains(&recording), "{ended}");
    let between = err
        .lines()
        .find(|l| l.contains("no job was running"))
        .unwrap_or_else(|| panic!("no fault-between-jobs line:\n{err}"));
    assert!(
        between.contains("ERROR") && between.contains("between jobs") && between.contains(&fault),
        "{between}"
    );
    assert!(
        between.contains(&recording),
        "the last recording: {between}"
    );
    assert!(
        err.lines()
            .any(|l| l.contains("reset") && l.contains(&fault)),
        "no reset line:\n{err}"
    );
}
