//! `bench serve` against hostile or broken clients (issue 12, items 10 and
//! 12): over-long lines, a client that pipelines and never reads, file
//! descriptor exhaustion, too many clients, invalid UTF-8, duplicate keys,
//! ids echoed byte for byte, mutated request lines, and a job whose
//! preparation hangs (`BENCH_TEST_PREPARE_HANG=1`, a test-only hook).
//!
//! Memory is the daemon's resident set (`VmRSS` of `/proc/PID/status`),
//! CPU its `utime + stime` (`/proc/PID/stat`). Bounds are functional
//! (what the old code broke by orders of magnitude), not benchmarks.

use crate::common;
use crate::daemon_fixtures;

use common::*;
use daemon_fixtures::*;
use proptest::prelude::*;
use proptest::test_runner::{Config as PropConfig, TestCaseError, TestRunner};
use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::UnixStream;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::time::{Duration, Instant};

/// `bench::daemon::MAX_LINE_BYTES`.
const MAX_LINE: usize = bench::daemon::MAX_LINE_BYTES;

/// The daemon's resident set, KiB.
fn rss_kib(pid: u32) -> u64 {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("proc status");
    s.lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .expect("VmRSS")
}

/// The daemon's CPU time so far (user + system), s.
fn cpu_s(pid: u32) -> f64 {
    let s = std::fs::read_to_string(format!("/proc/{pid}/stat")).expect("proc stat");
    // Fields after the command name: state is field 3, utime 14, stime 15.
    let rest = &s[s.rfind(')').expect("comm") + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: u64 = f[11].parse::<u64>().unwrap() + f[12].parse::<u64>().unwrap();
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
    ticks as f64 / hz
}

/// One `status` round trip on `c`, with its duration.
fn timed_status(c: &mut Client) -> Duration {
    let t0 = Instant::now();
    let r = c.call("status", json!({}));
    assert_eq!(r["ok"], true, "{r}");
    t0.elapsed()
}

/// Reads what the daemon sends until it closes (or errors, or `timeout`
/// passes); returns the lines.
fn drain(s: &UnixStream, timeout: Duration) -> Vec<String> {
    s.set_read_timeout(Some(timeout)).unwrap();
    let mut r = BufReader::new(s.try_clone().unwrap());
    let mut lines = Vec::new();
    loop {
        let mut l = String::new();
        match r.read_line(&mut l) {
            Ok(0) | Err(_) => return lines,
            Ok(_) => lines.push(l),
        }
    }
}

#[test]
fn over_long_lines_are_refused_without_buffering_them() {
    let _g = one_at_a_time();
    let d = Daemon::start();
    let pid = d.child.id();
    let mut other = d.client();
    timed_status(&mut other);
    let base = rss_kib(pid);
    // 8 MiB without a newline: answered `bad_request` naming the limit (or
    // cut off), never read to the end.
    let s = UnixStream::connect(&d.socket).unwrap();
    let writer = {
        let mut w = s.try_clone().unwrap();
        std::thread::spawn(move || {
            let chunk = vec![b'x'; 1 << 20];
            let mut sent = 0usize;
            for _ in 0..8 {
                match w.write_all(&chunk) {
                    Ok(()) => sent += chunk.len(),
                    Err(_) => break,
                }
            }
            sent
        })
    };
    let lines = drain(&s, Duration::from_secs(10));
    let sent = writer.join().unwrap();
    if let Some(l) = lines.first() {
        let v: Value = serde_json::from_str(l).unwrap();
        assert_eq!(v["error"]["kind"], "bad_request", "{v}");
        let msg = v["error"]["message"].as_str().unwrap();
        assert!(msg.contains(&MAX_LINE.to_string()), "{msg}");
    }
    assert!(sent < 8 << 20, "the daemon read all 8 MiB of one line");
    // 1 GiB streamed: the daemon stops reading after the limit; the client
    // gets an error long before it has sent it all.
    let mut s = UnixStream::connect(&d.socket).unwrap();
    let chunk = vec![b'{'; 1 << 20];
    let mut sent = 0usize;
    for _ in 0..1024 {
        match s.write_all(&chunk) {
            Ok(()) => sent += chunk.len(),
            Err(_) => break,
        }
    }
    assert!(sent < 64 << 20, "{sent} bytes of one line accepted");
    drop(s);
    // Memory: a few buffers, not the lines.
    let grown = rss_kib(pid).saturating_sub(base);
    eprintln!("RSS grew by {grown} KiB after an 8 MiB and a 1 GiB line");
    assert!(
        grown < 4 * (MAX_LINE as u64 / 1024) + 4096,
        "RSS grew by {grown} KiB"
    );
    // Other clients are served, new ones too.
    assert!(timed_status(&mut other) < Duration::from_millis(500));
    assert!(timed_status(&mut d.client()) < Duration::from_millis(500));
    // A line at the limit is still read (and refused as JSON only).
    let mut c = d.client();
    c.send_raw(&" ".repeat(MAX_LINE - 2).replacen(' ', "x", 1));
    assert_eq!(c.response()["error"]["kind"], "bad_request");
    assert!(timed_status(&mut c) < Duration::from_millis(500));
}

#[test]
fn a_client_that_pipelines_and_never_reads_is_disconnected() {
    let _g = one_at_a_time();
    let d = Daemon::start();
    let pid = d.child.id();
    let mut other = d.client();
    timed_status(&mut other);
    let base = rss_kib(pid);
    let mut p = UnixStream::connect(&d.socket).unwrap();
    let writer = std::thread::spawn(move || {
        let line = b"{\"id\":1,\"cmd\":\"status\"}\n";
        let batch: Vec<u8> = line.repeat(1000);
        let mut sent = 0usize;
        for _ in 0..500 {
            if p.write_all(&batch).is_err() {
                return (sent, true);
            }
            sent += 1000;
        }
        (sent, false)
    });
    // Meanwhile another client's status stays fast.
    let mut worst = Duration::ZERO;
    while !writer.is_finished() {
        worst = worst.max(timed_status(&mut other));
        std::thread::sleep(Duration::from_millis(5));
    }
    let (sent, cut) = writer.join().unwrap();
    eprintln!("pipelining client cut after {sent} requests; worst other status {worst:?}");
    assert!(
        cut,
        "all {sent} requests were taken from a client that never reads"
    );
    assert!(worst < Duration::from_millis(500), "status took {worst:?}");
    let grown = rss_kib(pid).saturating_sub(base);
    eprintln!("RSS grew by {grown} KiB");
    let pending_kib = bench::daemon::MAX_PENDING_BYTES as u64 / 1024;
    assert!(grown < 4 * pending_kib + 4096, "RSS grew by {grown} KiB");
    assert!(timed_status(&mut d.client()) < Duration::from_millis(500));
}

/// Connects and asks `status`; `true` when answered `ok`.
fn status_on_new_connection(socket: &Path) -> Option<UnixStream> {
    let s = UnixStream::connect(socket).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(3))).unwrap();
    (&s).write_all(b"{\"id\":1,\"cmd\":\"status\"}\n").ok()?;
    let mut l = String::new();
    BufReader::new(&s).read_line(&mut l).ok()?;
    let v: Value = serde_json::from_str(&l).ok()?;
    (v["ok"] == true).then_some(s)
}

#[test]
fn out_of_file_descriptors_the_daemon_backs_off_and_keeps_serving() {
    let _g = one_at_a_time();
    let d = Daemon::start_adjusted(&[], "", |cmd| {
        // SAFETY: only setrlimit between fork and exec.
        unsafe {
            cmd.pre_exec(|| {
                let lim = libc::rlimit {
                    rlim_cur: 40,
                    rlim_max: 40,
                };
                if libc::setrlimit(libc::RLIMIT_NOFILE, &lim) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
    });
    let pid = d.child.id();
    let t_start = Instant::now();
    let mut first = d.client();
    timed_status(&mut first);
    // Clients until the daemon has no descriptor left.
    let mut held = Vec::new();
    let refused = loop {
        match status_on_new_connection(&d.socket) {
            Some(s) => held.push(s),
            None => break true,
        }
        if held.len() > 100 {
            break false;
        }
    };
    assert!(refused, "100 clients with 40 descriptors");
    eprintln!("limit reached after {:?}", t_start.elapsed());
    eprintln!("{} clients served at the descriptor limit", held.len());
    // Clients waiting in the backlog while no descriptor is free: the old
    // accept loop spun at 100 % CPU on EMFILE.
    let waiting: Vec<UnixStream> = (0..20)
        .filter_map(|_| UnixStream::connect(&d.socket).ok())
        .collect();
    std::thread::sleep(Duration::from_millis(200));
    let c0 = cpu_s(pid);
    std::thread::sleep(Duration::from_secs(1));
    let cpu = cpu_s(pid) - c0;
    eprintln!("daemon CPU at the descriptor limit: {cpu:.2} s in 1 s");
    // (The old accept loop took 0.6 s of the 1 s here with 4 builds
    // sharing the 2 cores; the daemon at rest takes under 0.1 s.)
    assert!(cpu < 0.3, "the daemon spins: {cpu:.2} s of CPU in 1 s");
    // The connected clients are still served.
    assert!(timed_status(&mut first) < Duration::from_millis(500));
    assert!(status_on_new_connection(&d.socket).is_none());
    eprintln!("spin checked after {:?}", t_start.elapsed());
    // Descriptors free again: new clients are served.
    drop(waiting);
    held.truncate(held.len().saturating_sub(5));
    let t0 = Instant::now();
    while status_on_new_connection(&d.socket).is_none() {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "no new client after descriptors were freed"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(timed_status(&mut first) < Duration::from_millis(500));
}

#[test]
fn at_most_max_clients_at_once() {
    let _g = one_at_a_time();
    let d = Daemon::start();
    let max = bench::daemon::MAX_CLIENTS;
    let mut held: Vec<UnixStream> = (0..max)
        .map(|i| {
            status_on_new_connection(&d.socket)
                .unwrap_or_else(|| panic!("client {i} of {max} refused"))
        })
        .collect();
    let s = UnixStream::connect(&d.socket).unwrap();
    let lines = drain(&s, Duration::from_secs(5));
    assert_eq!(lines.len(), 1, "{lines:?}");
    let v: Value = serde_json::from_str(&lines[0]).unwrap();
    assert_eq!(v["error"]["kind"], "busy", "{v}");
    assert!(v["error"]["message"]
        .as_str()
        .unwrap()
        .contains("too many clients"));
    held.pop();
    let t0 = Instant::now();
    while status_on_new_connection(&d.socket).is_none() {
        assert!(t0.elapsed() < Duration::from_secs(5), "slot not freed");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn invalid_utf8_and_duplicate_keys_are_bad_requests() {
    let _g = one_at_a_time();
    let d = Daemon::start();
    let mut c = d.client();
    c.w.write_all(b"{\"id\":1,\"cmd\":\"stat\xffus\"}\n")
        .unwrap();
    let r = c.response();
    assert_eq!(r["error"]["kind"], "bad_request", "{r}");
    assert!(r["error"]["message"].as_str().unwrap().contains("UTF-8"));
    for (line, key) in [
        (r#"{"id":2,"cmd":"status","cmd":"shutdown"}"#, "cmd"),
        (r#"{"id":3,"id":4,"cmd":"status"}"#, "id"),
        (
            r#"{"id":5,"cmd":"control","params":{"controller":"fast","controller":"slow"}}"#,
            "controller",
        ),
        (
            r#"{"id":6,"cmd":"chirp","params":{"duration_s":1,"seed":{"a":1,"b":[{"c":1,"\u0063":2}]}}}"#,
            "c",
        ),
        (r#"{"id":{"k":1,"k":1},"cmd":"status"}"#, "k"),
    ] {
        c.send_raw(line);
        let r = c.response();
        assert_eq!(r["error"]["kind"], "bad_request", "{line}: {r}");
        let msg = r["error"]["message"].as_str().unwrap();
        assert!(
            msg.contains(&format!("duplicate key \"{key}\"")),
            "{line}: {msg}"
        );
    }
    // The id of a request refused for a duplicate elsewhere is echoed.
    c.send_raw(r#"{"id":"dup","cmd":"status","params":{"x":1,"x":2}}"#);
    assert_eq!(c.response()["id"], "dup");
    // Nothing ran, the daemon is where it was.
    let s = c.call("status", json!({}))["result"].clone();
    assert_eq!(s["state"], "disabled");
    assert_eq!(s["jobs_run"], 0);
}

/// JSON ids: big integers, out-of-range and odd floats, strings with
/// escapes and unicode, nested arrays and objects of them (unique keys).
fn id_text() -> impl Strategy<Value = String> {
    let leaf = prop_oneof![
        "-?[1-9][0-9]{0,40}",
        Just("18446744073709551616".to_string()),
        Just("-9223372036854775809".to_string()),
        Just("1e400".to_string()),
        Just("-0.0".to_string()),
        Just("0".to_string()),
        "-?[0-9]\\.[0-9]{1,20}[eE][+-]?[0-9]{1,4}",
        Just("true".to_string()),
        Just("null".to_string()),
        // Strings: escapes, unicode (raw and escaped), surrogate pairs.
        prop::collection::vec(
            prop_oneof![
                "[a-zA-Z0-9 ]{1,4}",
                Just("\\\"".to_string()),
                Just("\\\\".to_string()),
                Just("\\n\\t\\/".to_string()),
                Just("\\u00e9".to_string()),
                Just("\\ud83d\\ude00".to_string()),
                Just("é€😀".to_string()),
            ],
            0..6
        )
        .prop_map(|parts| format!("\"{}\"", parts.concat())),
    ];
    leaf.prop_recursive(3, 24, 4, |inner| {
        prop_oneof![
            prop::collection::vec(inner.clone(), 0..4).prop_map(|v| format!("[{}]", v.join(", "))),
            prop::collection::vec(inner, 0..4).prop_map(|v| {
                let fields: Vec<String> = v
                    .iter()
                    .enumerate()
                    .map(|(i, x)| format!("\"k{i}\" : {x}"))
                    .collect();
                format!("{{{}}}", fields.join(","))
            }),
        ]
    })
}

#[test]
fn ids_are_echoed_byte_for_byte() {
    let _g = one_at_a_time();
    let d = Daemon::start();
    // (TestRunner::run takes a `Fn`.)
    let c = std::cell::RefCell::new(d.client());
    let mut runner = TestRunner::new(PropConfig {
        cases: 300,
        failure_persistence: None,
        ..PropConfig::default()
    });
    runner
        .run(&id_text(), |id| {
            let mut c = c.borrow_mut();
            for cmd in ["status", "no_such_command"] {
                c.send_raw(&format!("{{\"id\": {id} ,\"cmd\":\"{cmd}\"}}"));
                let mut line = String::new();
                c.r.read_line(&mut line).unwrap();
                let want = format!("{{\"id\":{id},");
                prop_assert!(line.starts_with(&want), "sent id {id}, got {line}");
            }
            Ok(())
        })
        .unwrap();
    // The CLI client's integer id still matches.
    assert_eq!(c.borrow_mut().call("status", json!({}))["ok"], true);
}

/// Request lines the mutations start from (short jobs, never `shutdown`).
const SEEDS: &[&str] = &[
    r#"{"id":1,"cmd":"status"}"#,
    r#"{"id":"a","cmd":"stop","params":{}}"#,
    r#"{"id":2,"cmd":"chirp","params":{"duration_s":0.2,"amplitude_a":0.1,"f_start_hz":5,"f_end_hz":50,"seed":3}}"#,
    r#"{"id":3,"cmd":"control","params":{"controller":"fast","duration_s":0.2,"step_m":1e-6,"smooth_s":0.01,"seed":1,"override_check":false,"detach":false}}"#,
    r#"{"id":[4],"cmd":"control","params":{"controller":"slow","duration_s":0.2,"inject_fault":"nan@0.1"}}"#,
    r#"{"id":7,"cmd":"track","params":{"trials":1,"periods":1,"seed":2,"pace":"off"}}"#,
    r#"{"id":5,"cmd":"disable"}"#,
    r#"{"id":6,"cmd":"reset"}"#,
];

/// Values of the wrong type (or out of any range) for a parameter.
const WRONG: &[&str] = &[
    "\"x\"",
    "[]",
    "{}",
    "null",
    "true",
    "-1",
    "1e400",
    "-1e400",
    "18446744073709551616",
    "1e-320",
    "\"\\u0000\"",
    "[[[[[[[[1]]]]]]]]",
];

#[derive(Debug, Clone)]
enum Mutation {
    Truncate(prop::sample::Index),
    Flip(prop::sample::Index, u8),
    Nul(prop::sample::Index),
    Huge(prop::sample::Index),
    /// Replaces the value after the n-th `:` by a wrong one.
    WrongType(prop::sample::Index, prop::sample::Index),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        any::<prop::sample::Index>().prop_map(Mutation::Truncate),
        (any::<prop::sample::Index>(), 1u8..=255).prop_map(|(i, b)| Mutation::Flip(i, b)),
        any::<prop::sample::Index>().prop_map(Mutation::Nul),
        any::<prop::sample::Index>().prop_map(Mutation::Huge),
        (any::<prop::sample::Index>(), any::<prop::sample::Index>())
            .prop_map(|(i, w)| Mutation::WrongType(i, w)),
    ]
}

fn mutate(seed: &str, ms: &[Mutation]) -> Vec<u8> {
    let mut b = seed.as_bytes().to_vec();
    for m in ms {
        if b.is_empty() {
            break;
        }
        match m {
            Mutation::Truncate(i) => b.truncate(i.index(b.len())),
            Mutation::Flip(i, x) => {
                let i = i.index(b.len());
                b[i] ^= x;
            }
            Mutation::Nul(i) => {
                let i = i.index(b.len() + 1);
                b.insert(i, 0);
            }
            Mutation::Huge(i) => {
                let i = i.index(b.len() + 1);
                let huge = format!("9{}e99999", "9".repeat(400));
                b.splice(i..i, huge.bytes());
            }
            Mutation::WrongType(i, w) => {
                let colons: Vec<usize> = b
                    .iter()
                    .enumerate()
                    .filter(|(_, c)| **c == b':')
                    .map(|(k, _)| k)
                    .collect();
                if colons.is_empty() {
                    continue;
                }
                let at = colons[i.index(colons.len())] + 1;
                let end = b[at..]
                    .iter()
                    .position(|c| *c == b',' || *c == b'}')
                    .map_or(b.len(), |e| at + e);
                let wrong = WRONG[w.index(WRONG.len())];
                b.splice(at..end, wrong.bytes());
            }
        }
    }
    // One request per line.
    for c in &mut b {
        if *c == b'\n' {
            *c = b' ';
        }
    }
    b
}

#[test]
fn mutated_requests_get_an_answer_or_a_close_and_never_kill_the_daemon() {
    let _g = one_at_a_time();
    let d = Daemon::start();
    let watcher = std::cell::RefCell::new(d.client());
    let mut runner = TestRunner::new(PropConfig {
        cases: 400,
        failure_persistence: None,
        ..PropConfig::default()
    });
    let answered = std::cell::Cell::new(0u32);
    let closed = std::cell::Cell::new(0u32);
    let strategy = (
        prop::sample::select(SEEDS),
        prop::collection::vec(mutation(), 1..4),
    );
    runner
        .run(&strategy, |(seed, ms)| {
            let line = mutate(seed, &ms);
            if line.iter().all(u8::is_ascii_whitespace) {
                // A blank line is skipped by the daemon: no answer due.
                return Ok(());
            }
            let s = UnixStream::connect(&d.socket)
                .map_err(|e| TestCaseError::fail(format!("connect: {e}")))?;
            s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
            let mut w = s.try_clone().unwrap();
            w.write_all(&line).unwrap();
            w.write_all(b"\n").unwrap();
            let mut r = BufReader::new(s);
            // The answer: the first line that is not an event. A job that
            // started is stopped (its answer then comes).
            loop {
                let mut l = String::new();
                match r.read_line(&mut l) {
                    Ok(0) | Err(_) => {
                        eprintln!("closed after: {}", String::from_utf8_lossy(&line));
                        closed.set(closed.get() + 1);
                        break;
                    }
                    Ok(_) => {}
                }
                // Raw values: an echoed id such as 1e400 is no `f64`.
                let v: std::collections::BTreeMap<String, Box<serde_json::value::RawValue>> =
                    serde_json::from_str(&l).map_err(|e| {
                        TestCaseError::fail(format!("not JSON from the daemon ({e}): {l}"))
                    })?;
                let event = v.get("event").map(|e| e.get());
                if event == Some("\"job_started\"") {
                    w.write_all(b"{\"cmd\":\"stop\"}\n").unwrap();
                    // The stop's own answer comes first; skip it.
                    let mut l = String::new();
                    let _ = r.read_line(&mut l);
                }
                if event.is_none() {
                    prop_assert!(v.contains_key("ok") && v.contains_key("id"), "{}", l);
                    answered.set(answered.get() + 1);
                    break;
                }
            }
            // The daemon is alive and answers others.
            let st = watcher.borrow_mut().call("status", json!({}));
            prop_assert_eq!(&st["ok"], &json!(true), "{}", st);
            Ok(())
        })
        .unwrap();
    eprintln!(
        "{} mutated requests answered, {} connections closed",
        answered.get(),
        closed.get()
    );
    let mut d = d;
    assert!(d.child.try_wait().unwrap().is_none(), "the daemon died");
}

/// A daemon whose every job preparation hangs (the test-only hook).
fn hanging_daemon() -> Daemon {
    Daemon::start_adjusted(&[], "", |cmd| {
        cmd.env(bench::daemon::testing::PREPARE_HANG_ENV, "1");
    })
}

#[test]
fn a_hanging_preparation_leaves_status_stop_and_sigterm_effective() {
    let _g = one_at_a_time();
    let d = hanging_daemon();
    let mut b = d.client();
    assert_eq!(b.call("enable", json!({}))["ok"], true);
    let mut a = d.client();
    let started = a.submit("control", json!({ "controller": "fast" }));
    let rec = Path::new(started["recording"].as_str().unwrap()).to_path_buf();
    std::thread::sleep(Duration::from_millis(300));
    // status answers (fast) while the preparation hangs: the stage holds
    // 0 A, the job has run no tick.
    assert!(timed_status(&mut b) < Duration::from_millis(500));
    let s = b.call("status", json!({}))["result"].clone();
    assert_eq!(s["state"], "running", "{s}");
    assert_eq!(s["job"]["ticks"], 0, "{s}");
    assert_eq!(s["command_a"], 0.0, "{s}");
    // A second job is busy; stop ends the hung one.
    assert_eq!(
        b.call("chirp", json!({}))["error"]["kind"],
        "busy",
        "one job at a time"
    );
    assert_eq!(b.call("stop", json!({}))["ok"], true);
    let t0 = Instant::now();
    let r = a.response();
    assert!(t0.elapsed() < Duration::from_secs(1), "{:?}", t0.elapsed());
    assert_eq!(r["error"]["kind"], "interrupted", "{r}");
    // Back between jobs: disabled (a job ends disabled), 0 A, no
    // recording, nothing counted as run.
    let s = wait_state(&mut b, "disabled", Duration::from_secs(2));
    assert_eq!(s["command_a"], 0.0, "{s}");
    assert!(s["job"].is_null(), "{s}");
    assert!(!rec.exists(), "{rec:?}");
    // Another job hangs too; SIGTERM ends the daemon within 1 s anyway.
    let started = a.submit("chirp", json!({ "duration_s": 1 }));
    assert!(started["job"].as_u64().is_some());
    std::thread::sleep(Duration::from_millis(300));
    let s = b.call("status", json!({}))["result"].clone();
    assert_eq!(s["command_a"], 0.0, "{s}");
    let mut d = d;
    let t0 = Instant::now();
    // SAFETY: plain kill(2) on our child.
    unsafe { libc::kill(d.child.id() as i32, libc::SIGTERM) };
    let status = loop {
        if let Some(st) = d.child.try_wait().unwrap() {
            break st;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(1),
            "the daemon did not exit within 1 s of SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(5));
    };
    eprintln!("exited {:?} after SIGTERM", t0.elapsed());
    assert!(status.success(), "{status:?}");
    assert!(!d.socket.exists(), "socket left behind");
    // The submitter got its answer before the daemon left.
    let r = a.response();
    assert_eq!(r["error"]["kind"], "interrupted", "{r}");
    let mut err = String::new();
    d.child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn a_local_run_interrupted_while_preparing_exits_130_at_once() {
    let _g = one_at_a_time();
    let dir = tmp();
    let cfg = quiet_config(dir.path(), 1.0, "");
    let out = dir.path().join("step.mcap");
    let mut child = bench()
        .args([
            "control",
            "--fast",
            "--config",
            cfg.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .env(bench::daemon::testing::PREPARE_HANG_ENV, "1")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(700));
    assert!(child.try_wait().unwrap().is_none(), "the hook did not hang");
    let t0 = Instant::now();
    // SAFETY: plain kill(2) on our child.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let status = loop {
        if let Some(st) = child.try_wait().unwrap() {
            break st;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(1),
            "no exit within 1 s of SIGINT"
        );
        std::thread::sleep(Duration::from_millis(5));
    };
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    assert_eq!(status.code(), Some(130), "{err}");
    assert!(err.contains("nothing was enabled"), "{err}");
    assert!(
        files_in(dir.path()).iter().all(|p| p == &cfg),
        "{:?}",
        files_in(dir.path())
    );
}

/// SIGTERMs the daemon and waits for it to exit, at most `bound`; the
/// time it took, and the exit status.
fn sigterm_within(d: &mut Daemon, bound: Duration) -> (Duration, std::process::ExitStatus) {
    let t0 = Instant::now();
    // SAFETY: plain kill(2) on our child.
    unsafe { libc::kill(d.child.id() as i32, libc::SIGTERM) };
    loop {
        if let Some(st) = d.child.try_wait().unwrap() {
            return (t0.elapsed(), st);
        }
        assert!(
            t0.elapsed() < bound,
            "the daemon did not exit within {bound:?} of SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// The audit's wedged job (issue 46, item 4): a `design` job whose
/// thread never returns (it read a FIFO; the preparation-hang hook stands
/// in for the read, as FIFOs are refused at open now) held the only job
/// slot: `stop` was acknowledged and nothing stopped, chirp and control
/// got `busy`, SIGTERM did not end the daemon within 15 s. Now the job is
/// abandoned `JOB_STOP_TIMEOUT_MS` after `stop`, its slot freed, the
/// amplifier disabled at 0 A, and SIGTERM ends the daemon within
/// `SHUTDOWN_BOUND_MS` with another such job running.
#[test]
fn a_job_that_does_not_answer_stop_is_abandoned_and_sigterm_ends_the_daemon_in_2_s() {
    let _g = one_at_a_time();
    let timeout = Duration::from_millis(bench::daemon::JOB_STOP_TIMEOUT_MS);
    // What a job that answers `stop` takes: a real-time chirp's loop ends
    // within a tick, then its recording is finished (tail, summary, index,
    // synced, renamed). The timeout is ten times that here.
    {
        let d = Daemon::start();
        let mut c = d.client();
        c.submit("chirp", json!({ "duration_s": 5 }));
        std::thread::sleep(Duration::from_millis(400));
        assert_eq!(d.client().call("stop", json!({}))["ok"], true);
        let t0 = Instant::now();
        let r = c.response();
        let took = t0.elapsed();
        eprintln!("a chirp answered its stop, recording finished, in {took:?}");
        assert_eq!(r["error"]["kind"], "interrupted", "{r}");
        let rec = r["error"]["summary"]["recording"].as_str().unwrap();
        assert!(Path::new(rec).is_file(), "{r}");
        assert!(took < timeout / 4, "{took:?}");
    }
    let mut d = hanging_daemon();
    let input = d.dir.path().join("measured.frf.csv");
    std::fs::write(
        &input,
        "frequency_hz,magnitude_m_per_a,phase_deg,coherence\n1,1e-6,0,1\n",
    )
    .unwrap();
    let design = json!({ "inputs": [input], "no_plot": true });
    let mut b = d.client();
    assert_eq!(b.call("enable", json!({}))["ok"], true);
    let mut a = d.client();
    a.w.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let started = a.submit("design", design.clone());
    let id = started["job"].as_u64().unwrap();
    std::thread::sleep(Duration::from_millis(200));
    let s = b.call("status", json!({}))["result"].clone();
    assert_eq!(s["state"], "running", "{s}");
    assert_eq!(s["job"]["kind"], "design", "{s}");
    assert_eq!(b.call("chirp", json!({}))["error"]["kind"], "busy");
    // `stop`: the job is abandoned JOB_STOP_TIMEOUT_MS later.
    assert_eq!(b.call("stop", json!({}))["result"]["stopping"], id);
    let t0 = Instant::now();
    let r = a.response();
    let waited = t0.elapsed();
    eprintln!("stopped job answered after {waited:?}: {r}");
    assert_eq!(r["error"]["kind"], "interrupted", "{r}");
    assert!(
        r["error"]["message"]
            .as_str()
            .unwrap()
            .contains("abandoned"),
        "{r}"
    );
    assert!(
        waited >= timeout - Duration::from_millis(50)
            && waited < timeout + Duration::from_millis(500),
        "{waited:?}"
    );
    // Its slot is free; the stage was left at 0 A, disabled (it was
    // enabled); the job is listed as abandoned.
    let s = wait_state(&mut b, "disabled", Duration::from_secs(1));
    assert_eq!(s["command_a"], 0.0, "{s}");
    assert!(s["job"].is_null(), "{s}");
    assert_eq!(s["abandoned_jobs"][0]["id"], id, "{s}");
    assert_eq!(s["abandoned_jobs"][0]["kind"], "design", "{s}");
    let chirp = b.submit("chirp", json!({ "duration_s": 1 }));
    assert!(chirp["job"].as_u64().is_some(), "{chirp}");
    assert_eq!(b.call("stop", json!({}))["ok"], true);
    assert_eq!(b.response()["error"]["kind"], "interrupted");
    // Another wedged job, not stopped: SIGTERM ends the daemon within the
    // bound all the same, and the job's client gets its answer first.
    a.submit("design", design);
    std::thread::sleep(Duration::from_millis(200));
    let bound = Duration::from_millis(bench::daemon::SHUTDOWN_BOUND_MS);
    let (took, status) = sigterm_within(&mut d, bound);
    eprintln!("exited {took:?} after SIGTERM with a wedged job");
    assert!(status.success(), "{status:?}");
    assert!(!d.socket.exists(), "socket left behind");
    let r = a.response();
    assert_eq!(r["error"]["kind"], "interrupted", "{r}");
}

/// A memory cgroup the test makes (cgroup v2, or v1's memory controller)
/// with a limit, removed on drop (once its processes are gone).
struct MemoryCgroup {
    dir: std::path::PathBuf,
    v2: bool,
}

impl MemoryCgroup {
    /// A new group limited to `limit_bytes`, or why there can be none here.
    fn new(limit_bytes: u64) -> Result<Self, String> {
        let name = format!("bench-test-{}", std::process::id());
        let write =
            |p: &Path, v: &str| std::fs::write(p, v).map_err(|e| format!("{}: {e}", p.display()));
        let v2_root = Path::new("/sys/fs/cgroup");
        let controllers = std::fs::read_to_string(v2_root.join("cgroup.controllers"));
        let (dir, v2) = if controllers.is_ok_and(|c| c.split_whitespace().any(|c| c == "memory")) {
            // A child of the root, which may hold processes and children.
            let _ = write(&v2_root.join("cgroup.subtree_control"), "+memory");
            (v2_root.join(&name), true)
        } else {
            let own = std::fs::read_to_string("/proc/self/cgroup").map_err(|e| e.to_string())?;
            let path = own
                .lines()
                .find_map(|l| {
                    let mut f = l.splitn(3, ':');
                    let (_, c, p) = (f.next()?, f.next()?, f.next()?);
                    c.split(',').any(|c| c == "memory").then(|| p.to_string())
                })
                .ok_or("no cgroup v2 memory controller and no v1 memory hierarchy")?;
            let root = Path::new("/sys/fs/cgroup/memory").join(path.trim_start_matches('/'));
            (root.join(&name), false)
        };
        std::fs::create_dir(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        let g = Self { dir, v2 };
        let file = if v2 {
            "memory.max"
        } else {
            "memory.limit_in_bytes"
        };
        write(&g.dir.join(file), &limit_bytes.to_string())?;
        if v2 {
            let _ = write(&g.dir.join("memory.swap.max"), "0");
        }
        Ok(g)
    }

    fn add(&self, pid: u32) {
        std::fs::write(self.dir.join("cgroup.procs"), pid.to_string()).unwrap();
    }

    /// The most the group has held, bytes.
    fn peak_bytes(&self) -> u64 {
        let f = if self.v2 {
            "memory.peak"
        } else {
            "memory.max_usage_in_bytes"
        };
        std::fs::read_to_string(self.dir.join(f))
            .ok()
            .and_then(|s| s.trim().parse().ok())
            .unwrap_or(0)
    }
}

impl Drop for MemoryCgroup {
    fn drop(&mut self) {
        for _ in 0..100 {
            if std::fs::remove_dir(&self.dir).is_ok() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// The audit's `{"cmd":"design","params":{"inputs":["/dev/zero"]}}`
/// (issue 46, item 4): it read until memory ran out, and in a 3 GiB
/// memory cgroup the daemon was OOM-killed while enabled and holding the
/// stage. Here, in a 512 MiB cgroup, each job that computes has a budget
/// of a quarter of that: the request fails (over its budget, or refused
/// as not a regular file) and the daemon lives, the stage at 0 A,
/// disabled. The allocation hook (`BENCH_TEST_ALLOCATE_JOB=analyze`)
/// stands in for any job whose memory grows without bound: each fails on
/// its budget, until what the parked jobs hold leaves no room for another
/// (`busy`); a bench job still runs, and SIGTERM still ends the daemon.
#[test]
fn a_job_over_its_memory_budget_fails_and_the_daemon_lives_in_a_memory_cgroup() {
    let _g = one_at_a_time();
    let limit: u64 = 512 << 20;
    let cg = match MemoryCgroup::new(limit) {
        Ok(g) => g,
        Err(why) => {
            eprintln!("SKIPPED: no memory cgroup can be made here: {why}");
            return;
        }
    };
    let mut d = Daemon::start_adjusted(&[], "", |cmd| {
        cmd.env(bench::daemon::testing::ALLOCATE_JOB_ENV, "analyze");
    });
    cg.add(d.child.id());
    let mut b = d.client();
    assert_eq!(b.call("enable", json!({}))["ok"], true);
    let mut a = d.client();
    a.w.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    let t0 = Instant::now();
    let r = a.call(
        "design",
        json!({ "inputs": ["/dev/zero"], "no_plot": true }),
    );
    eprintln!("/dev/zero design answered after {:?}: {r}", t0.elapsed());
    // Refused before any job starts: not a regular file (the bounded
    // reads, item 3); the budget below is the second line of defence.
    assert_eq!(r["ok"], false, "{r}");
    assert_eq!(r["error"]["kind"], "bad_params", "{r}");
    assert!(
        r["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("/dev/zero") && m.contains("not a regular file")),
        "{r}"
    );
    assert!(d.child.try_wait().unwrap().is_none(), "the daemon died");
    let s = b.call("status", json!({}))["result"].clone();
    assert_eq!(s["command_a"], 0.0, "{s}");
    // Jobs that grow without bound: each fails on its budget, until the
    // memory the parked ones hold leaves no room (busy).
    let mut busy = None;
    for _ in 0..4 {
        assert_eq!(b.call("enable", json!({}))["ok"], true);
        let t0 = Instant::now();
        let r = a.call("analyze", json!({ "no_plots": true }));
        eprintln!("allocating job answered after {:?}: {r}", t0.elapsed());
        assert_eq!(r["ok"], false, "{r}");
        assert!(d.child.try_wait().unwrap().is_none(), "the daemon died");
        let message = r["error"]["message"].as_str().unwrap().to_string();
        if r["error"]["kind"] == "busy" {
            busy = Some(message);
            break;
        }
        assert_eq!(r["error"]["kind"], "error", "{r}");
        assert!(message.contains("memory budget of 128 MiB"), "{message}");
        let s = wait_state(&mut b, "disabled", Duration::from_secs(1));
        assert_eq!(s["command_a"], 0.0, "{s}");
    }
    let busy = busy.expect("the abandoned jobs' memory never refused a job");
    assert!(busy.contains("abandoned job(s) still hold"), "{busy}");
    let s = b.call("status", json!({}))["result"].clone();
    let held: u64 = s["abandoned_jobs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j["memory_bytes"].as_u64().unwrap())
        .sum();
    eprintln!(
        "abandoned jobs hold {} MiB; the cgroup's peak {} MiB of {} MiB",
        held >> 20,
        cg.peak_bytes() >> 20,
        limit >> 20
    );
    assert!(held <= limit / 2 + (16 << 20), "{s}");
    // A bench job still runs.
    let r = a.call("chirp", json!({ "duration_s": 0.5, "pace": "off" }));
    assert_eq!(r["ok"], true, "{r}");
    let bound = Duration::from_millis(bench::daemon::SHUTDOWN_BOUND_MS);
    let (took, status) = sigterm_within(&mut d, bound);
    eprintln!("exited {took:?} after SIGTERM with parked jobs");
    assert!(status.success(), "{status:?}");
}
