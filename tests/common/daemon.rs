//! The daemon fixtures of the socket tests (`tests/cli/daemon.rs`,
//! `tests/cli/daemon_hostile.rs`): start `bench serve` on a private socket, a
//! JSON-lines client, waiting for a state. Included with
//! `#[path = "common/daemon.rs"] mod daemon_fixtures;` beside `mod common;`.
#![allow(dead_code)]

use crate::common::{bench, tmp, KillOnDrop};
use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::fs::PermissionsExt;
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Starts `bench serve` and waits until its socket answers. The daemon is
/// killed when the returned guard drops (a failed assertion too).
pub fn spawn_serve(config: &Path, socket: &Path, recordings: &Path, extra: &[&str]) -> KillOnDrop {
    spawn_serve_with(config, socket, recordings, extra, |_| {})
}

/// [`spawn_serve`], with the command adjusted by `adjust` (environment,
/// resource limits) before it starts.
pub fn spawn_serve_with(
    config: &Path,
    socket: &Path,
    recordings: &Path,
    extra: &[&str],
    adjust: impl FnOnce(&mut Command),
) -> KillOnDrop {
    let mut cmd = bench();
    // Its stderr is a pipe the tests do not read: warnings only, so a long
    // test never fills it (tests/cli/logging.rs reads the default `info`).
    cmd.env("RUST_LOG", "warn");
    adjust(&mut cmd);
    let child = KillOnDrop::new(
        cmd.args([
            "serve",
            "--config",
            config.to_str().unwrap(),
            "--socket",
            socket.to_str().unwrap(),
            "--recordings",
            recordings.to_str().unwrap(),
        ])
        .args(extra)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap(),
    );
    let t0 = Instant::now();
    while UnixStream::connect(socket).is_err() {
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "daemon on {socket:?} did not come up"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    child
}

/// A daemon on a private socket and config, killed when dropped (its
/// `child` first, then its directory removed).
pub struct Daemon {
    pub child: KillOnDrop,
    pub socket: PathBuf,
    pub dir: tempfile::TempDir,
    pub config: PathBuf,
}

impl Daemon {
    pub fn start() -> Self {
        Self::start_with(&[], "")
    }

    /// With extra `bench serve` arguments and extra config text.
    pub fn start_with(extra: &[&str], config_extra: &str) -> Self {
        Self::start_adjusted(extra, config_extra, |_| {})
    }

    /// As [`Self::start_with`], the command adjusted by `adjust` first.
    pub fn start_adjusted(
        extra: &[&str],
        config_extra: &str,
        adjust: impl FnOnce(&mut Command),
    ) -> Self {
        Self::start_edited(extra, config_extra, |t| t.to_string(), adjust)
    }

    /// As [`Self::start_adjusted`], the config text passed through `edit`
    /// (see [`crate::common::quiet_config_edited`]).
    pub fn start_edited(
        extra: &[&str],
        config_extra: &str,
        edit: impl FnOnce(&str) -> String,
        adjust: impl FnOnce(&mut Command),
    ) -> Self {
        let dir = tmp();
        std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o700)).unwrap();
        let config = crate::common::quiet_config_edited(dir.path(), 1.0, config_extra, edit);
        let socket = dir.path().join("bench.sock");
        let child = spawn_serve_with(&config, &socket, &dir.path().join("rec"), extra, adjust);
        Self {
            child,
            socket,
            dir,
            config,
        }
    }

    pub fn client(&self) -> Client {
        Client::new(&self.socket)
    }

    pub fn sock(&self) -> String {
        self.socket.display().to_string()
    }
}

pub struct Client {
    pub w: UnixStream,
    pub r: BufReader<UnixStream>,
    pub next: u64,
}

impl Client {
    pub fn new(socket: &Path) -> Self {
        let w = UnixStream::connect(socket).unwrap();
        let r = BufReader::new(w.try_clone().unwrap());
        Self { w, r, next: 100 }
    }

    pub fn send_raw(&mut self, line: &str) {
        self.w.write_all(format!("{line}\n").as_bytes()).unwrap();
    }

    pub fn line(&mut self) -> Value {
        let mut l = String::new();
        assert!(
            self.r.read_line(&mut l).unwrap() > 0,
            "daemon closed the connection"
        );
        serde_json::from_str(&l).unwrap()
    }

    /// The next response (skipping events).
    pub fn response(&mut self) -> Value {
        loop {
            let v = self.line();
            if v.get("event").is_none() {
                return v;
            }
        }
    }

    pub fn call(&mut self, cmd: &str, params: Value) -> Value {
        self.next += 1;
        self.send_raw(&json!({ "id": self.next, "cmd": cmd, "params": params }).to_string());
        let r = self.response();
        assert_eq!(r["id"], json!(self.next), "{r}");
        r
    }

    /// [`Self::call`] for a real-time closed-loop job whose timing is not
    /// the test's subject, through [`retry_machine_stalls`].
    pub fn call_realtime(&mut self, cmd: &str, params: Value) -> Value {
        retry_machine_stalls(self, |c| (c.call(cmd, params.clone()), ())).0
    }

    /// Submits a job without waiting for its end; returns the job id from
    /// the `job_started` event.
    pub fn submit(&mut self, cmd: &str, params: Value) -> Value {
        self.next += 1;
        self.send_raw(&json!({ "id": self.next, "cmd": cmd, "params": params }).to_string());
        loop {
            let v = self.line();
            if v["event"] == "job_started" {
                return v;
            }
            assert!(v.get("event").is_some(), "job refused: {v}");
        }
    }
}

pub fn wait_state(c: &mut Client, state: &str, timeout: Duration) -> Value {
    let t0 = Instant::now();
    loop {
        let s = c.call("status", json!({}));
        if s["result"]["state"] == state {
            return s["result"].clone();
        }
        assert!(t0.elapsed() < timeout, "state stayed {}", s["result"]);
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Runs `job` (a real-time closed-loop job through the daemon `client`
/// talks to: its response, and what else the test wants) while a
/// [`HostStallWatch`] runs on every CPU. A job that faults on a stall the
/// machine made (the host not running the vCPU: the watch saw at least
/// half of it) is reset through `client` and run again, at most three
/// times; a stall the watch did not see fails the test, the daemon
/// stalled its own loop. Returns the first response that is not such a
/// fault, what `job` gave with it, and the machine's stalls before it.
///
/// [`HostStallWatch`]: crate::common::HostStallWatch
pub fn retry_machine_stalls<T>(
    client: &mut Client,
    mut job: impl FnMut(&mut Client) -> (Value, T),
) -> (Value, T, Vec<String>) {
    let mut seen = Vec::new();
    for _ in 0..3 {
        // One below the shipped config's loop priority (80).
        let watch = crate::common::HostStallWatch::start(79);
        let (r, extra) = job(client);
        let machine_s = watch.stop();
        // A stall fault's value is the stall, s.
        let fault = &r["error"]["summary"]["fault"];
        if r["ok"] == true || fault["kind"] != "overruns" {
            return (r, extra, seen);
        }
        seen.push(crate::common::machine_made(fault, machine_s, &r));
        // Faults latch: clear it for the next attempt.
        assert_eq!(client.call("reset", json!({}))["ok"], true);
    }
    panic!("three jobs in a row ended by the machine's own stalls ({seen:?}): this machine cannot hold the loop's delay margin");
}
