//! Recordings to object storage (issue 30, part 2) against a real
//! S3-compatible server: moto in server mode (from PyPI, installed by
//! `.ci/run` into the venv of `$BENCH_PYTHON`), started by each test with
//! its authentication on (`INITIAL_NO_AUTH_ACTION_COUNT=3`: every request
//! after the setup's three IAM calls must be signed with the key the setup
//! made, so wrong credentials are refused as AWS refuses them).
//!
//! What the store holds is read with boto3 (`tests/data/s3_store.py`), not
//! with the `object_store` crate `bench` uses, and checked against the
//! local files' SHA-256 computed here. The store "going away" is a TCP
//! proxy between `bench` and moto, run by the test: taken down, it resets
//! every connection and refuses new ones, as a network outage does; it
//! also counts the bytes sent to the store (no second upload) and can slow
//! them (an upload still in flight when the store goes away).

use crate::common;
use crate::daemon_fixtures;

use common::{bench, json_stdout, tmp, KillOnDrop};
use serde_json::{json, Value};
use sha2::{Digest, Sha256};
use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

const PY_HINT: &str = "the upload tests need python3 with moto[server], boto3 and pyarrow: `pip install 'moto[server]' boto3 pyarrow` (in a venv, then set BENCH_PYTHON=<venv>/bin/python), or run .ci/run, which installs them";

fn python() -> String {
    std::env::var("BENCH_PYTHON")
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "python3".to_string())
}

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/s3_store.py")
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A moto S3 server with authentication on, its bucket `lab-bench` and
/// the one access key it accepts.
struct Moto {
    child: Child,
    port: u16,
    id: String,
    secret: String,
}

impl Moto {
    fn start() -> Self {
        let port = free_port();
        let child = Command::new(python())
            .args([
                "-m",
                "moto.server",
                "-H",
                "127.0.0.1",
                "-p",
                &port.to_string(),
            ])
            .env("INITIAL_NO_AUTH_ACTION_COUNT", "3")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start moto with {}: {e}; {PY_HINT}", python()));
        let mut m = Self {
            child,
            port,
            id: String::new(),
            secret: String::new(),
        };
        let t0 = Instant::now();
        while TcpStream::connect(("127.0.0.1", port)).is_err() {
            if let Ok(Some(status)) = m.child.try_wait() {
                panic!("moto exited ({status}); {PY_HINT}");
            }
            assert!(
                t0.elapsed() < Duration::from_secs(30),
                "moto did not come up"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        let o = Command::new(python())
            .arg(script())
            .args(["setup", &m.endpoint()])
            .output()
            .unwrap();
        assert!(o.status.success(), "setup: {}\n{PY_HINT}", stderr(&o));
        let k: Value = serde_json::from_slice(&o.stdout).unwrap();
        m.id = k["id"].as_str().unwrap().into();
        m.secret = k["secret"].as_str().unwrap().into();
        m
    }

    fn endpoint(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    fn addr(&self) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], self.port))
    }

    /// Every object under `prefix`, read with boto3.
    fn objects(&self, prefix: &str) -> serde_json::Map<String, Value> {
        let o = Command::new(python())
            .arg(script())
            .args(["objects", &self.endpoint(), "lab-bench", prefix])
            .env("AWS_ACCESS_KEY_ID", &self.id)
            .env("AWS_SECRET_ACCESS_KEY", &self.secret)
            .output()
            .unwrap();
        assert!(o.status.success(), "objects: {}", stderr(&o));
        match serde_json::from_slice(&o.stdout).unwrap() {
            Value::Object(m) => m,
            v => panic!("{v}"),
        }
    }
}

impl Drop for Moto {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A TCP proxy to `upstream` that the test can take down (every
/// connection reset, new ones refused) and bring back; it counts the
/// bytes sent upstream and, with `rate_bytes_per_s`, paces them.
struct Proxy {
    addr: SocketAddr,
    up: Arc<AtomicBool>,
    sent: Arc<AtomicU64>,
    conns: Arc<Mutex<Vec<TcpStream>>>,
}

impl Proxy {
    fn start(upstream: SocketAddr, rate_bytes_per_s: Option<f64>) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let up = Arc::new(AtomicBool::new(true));
        let sent = Arc::new(AtomicU64::new(0));
        let conns = Arc::new(Mutex::new(Vec::new()));
        {
            let (up, sent, conns) = (Arc::clone(&up), Arc::clone(&sent), Arc::clone(&conns));
            std::thread::spawn(move || {
                for client in listener.incoming() {
                    let Ok(client) = client else { continue };
                    if !up.load(Ordering::SeqCst) {
                        let _ = client.shutdown(Shutdown::Both);
                        continue;
                    }
                    let Ok(server) = TcpStream::connect(upstream) else {
                        continue;
                    };
                    {
                        let mut c = conns.lock().unwrap();
                        c.push(client.try_clone().unwrap());
                        c.push(server.try_clone().unwrap());
                    }
                    let (c2, s2) = (client.try_clone().unwrap(), server.try_clone().unwrap());
                    let sent = Arc::clone(&sent);
                    std::thread::spawn(move || pump(client, server, Some(&sent), rate_bytes_per_s));
                    std::thread::spawn(move || pump(s2, c2, None, None));
                }
            });
        }
        Self {
            addr,
            up,
            sent,
            conns,
        }
    }

    fn endpoint(&self) -> String {
        format!("http://{}", self.addr)
    }

    fn down(&self) {
        self.up.store(false, Ordering::SeqCst);
        for c in self.conns.lock().unwrap().drain(..) {
            let _ = c.shutdown(Shutdown::Both);
        }
    }

    fn up(&self) {
        self.up.store(true, Ordering::SeqCst);
    }

    fn sent(&self) -> u64 {
        self.sent.load(Ordering::SeqCst)
    }
}

fn pump(mut from: TcpStream, mut to: TcpStream, count: Option<&AtomicU64>, rate: Option<f64>) {
    let mut buf = [0u8; 16 * 1024];
    loop {
        let n = match from.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        if let Some(r) = rate {
            std::thread::sleep(Duration::from_secs_f64(n as f64 / r));
        }
        if to.write_all(&buf[..n]).is_err() {
            break;
        }
        if let Some(c) = count {
            c.fetch_add(n as u64, Ordering::SeqCst);
        }
    }
    let _ = to.shutdown(Shutdown::Write);
}

/// A store that takes every connection and never answers on it (the
/// audit's hostile case, issue 46 item 7): a TCP listener whose thread
/// accepts each connection and holds it open without reading or writing.
/// It counts the connections taken (the store was reached, not refused).
struct SilentStore {
    addr: SocketAddr,
    accepted: Arc<AtomicU64>,
}

impl SilentStore {
    fn start() -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let accepted = Arc::new(AtomicU64::new(0));
        let count = Arc::clone(&accepted);
        std::thread::spawn(move || {
            let mut held = Vec::new();
            for c in listener.incoming().flatten() {
                count.fetch_add(1, Ordering::SeqCst);
                held.push(c);
            }
        });
        Self { addr, accepted }
    }

    fn endpoint(&self) -> String {
        format!("http://{}", self.addr)
    }

    fn accepted(&self) -> u64 {
        self.accepted.load(Ordering::SeqCst)
    }
}

/// A store that answers late: each connection is held `delay`, then
/// relayed to `upstream`.
fn late_store(upstream: SocketAddr, delay: Duration) -> SocketAddr {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    std::thread::spawn(move || {
        for client in listener.incoming().flatten() {
            std::thread::spawn(move || {
                std::thread::sleep(delay);
                let Ok(server) = TcpStream::connect(upstream) else {
                    return;
                };
                let (c2, s2) = (client.try_clone().unwrap(), server.try_clone().unwrap());
                std::thread::spawn(move || pump(s2, c2, None, None));
                pump(client, server, None, None);
            });
        }
    });
    addr
}

/// Sends SIGTERM to the daemon and waits for its exit, at most
/// `SHUTDOWN_BOUND_MS` (its documented bound) and 1 s for the process to
/// leave; returns its exit status and stderr.
fn sigterm(mut d: KillOnDrop) -> (std::process::ExitStatus, String) {
    // SAFETY: plain kill(2) on our child.
    unsafe { libc::kill(d.id() as i32, libc::SIGTERM) };
    let t0 = Instant::now();
    let bound = Duration::from_millis(bench::daemon::SHUTDOWN_BOUND_MS + 1000);
    while d.try_wait().unwrap().is_none() {
        if t0.elapsed() > bound {
            let _ = d.kill();
            panic!("the daemon did not end within {bound:?} of SIGTERM");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let o = d.into_inner().wait_with_output().unwrap();
    (o.status, stderr(&o))
}

/// The `AWS_*` environment of a store at `endpoint` with this key.
fn aws_env(cmd: &mut Command, endpoint: &str, id: &str, secret: &str) {
    for v in [
        "AWS_REGION",
        "AWS_DEFAULT_REGION",
        "AWS_SESSION_TOKEN",
        "AWS_PROFILE",
    ] {
        cmd.env_remove(v);
    }
    cmd.env("AWS_ENDPOINT", endpoint)
        .env("AWS_ALLOW_HTTP", "true")
        .env("AWS_ACCESS_KEY_ID", id)
        .env("AWS_SECRET_ACCESS_KEY", secret);
}

fn sha256_of(path: &Path) -> String {
    Sha256::digest(std::fs::read(path).unwrap())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// A finished chirp recording `dir/NAME.mcap` (with its FRF CSV, Bode plot
/// and catalogue row), unpaced on the simulator.
fn recording(dir: &Path, name: &str, duration_s: &str) -> PathBuf {
    let out = dir.join(format!("{name}.mcap"));
    let o = bench()
        .current_dir(dir)
        .args(["chirp", "--duration-s", duration_s, "--seed", "3", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    out
}

fn upload(moto_endpoint: &str, m: &Moto, args: &[&str]) -> Output {
    let mut c = bench();
    aws_env(&mut c, moto_endpoint, &m.id, &m.secret);
    c.arg("upload").args(args).output().unwrap()
}

/// The local files of recording `rec` that go up, by name (the recording
/// and every `STEM.*` beside it).
fn companions(rec: &Path) -> Vec<PathBuf> {
    let stem = rec.file_stem().unwrap().to_str().unwrap().to_string();
    let mut v: Vec<PathBuf> = std::fs::read_dir(rec.parent().unwrap())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            p.is_file()
                && p.file_name()
                    .unwrap()
                    .to_str()
                    .unwrap()
                    .starts_with(&format!("{stem}."))
        })
        .collect();
    v.sort();
    v
}

/// Every companion of `rec` is an object under `prefix` with the same
/// size and SHA-256, and its catalogue row is there with the recording's
/// object URL; nothing else is under `prefix`.
fn assert_uploaded(objects: &serde_json::Map<String, Value>, prefix: &str, rec: &Path) {
    let files = companions(rec);
    let stem = rec.file_stem().unwrap().to_str().unwrap();
    for f in &files {
        let key = format!("{prefix}/{}", f.file_name().unwrap().to_str().unwrap());
        let o = objects
            .get(&key)
            .unwrap_or_else(|| panic!("{key} not in the store: {objects:?}"));
        assert_eq!(
            o["size"],
            json!(std::fs::metadata(f).unwrap().len()),
            "{key}"
        );
        assert_eq!(o["sha256"], json!(sha256_of(f)), "{key}");
    }
    let row = format!("{prefix}/catalogue/{stem}.parquet");
    assert_eq!(
        objects[&row]["recording"],
        json!(format!("s3://lab-bench/{prefix}/{stem}.mcap")),
        "{row}"
    );
    assert_eq!(objects.len(), files.len() + 1, "{objects:?}");
}

#[test]
fn bench_upload_confirms_every_file_by_checksum_and_never_uploads_twice() {
    let m = Moto::start();
    let proxy = Proxy::start(m.addr(), None);
    let dir = tmp();
    let rec = recording(dir.path(), "run", "2");
    let o = upload(
        &proxy.endpoint(),
        &m,
        &["--to", "s3://lab-bench/bench3/", "--json"],
    );
    // No recording given: clap refuses.
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let o = upload(
        &proxy.endpoint(),
        &m,
        &[
            "--to",
            "s3://lab-bench/bench3/",
            "--json",
            rec.to_str().unwrap(),
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let s = json_stdout(&o);
    let confirmed = s["confirmed"].as_array().unwrap();
    assert_eq!(confirmed.len(), companions(&rec).len() + 1, "{s}");
    assert!(confirmed.iter().all(|t| t["uploaded"] == true), "{s}");
    let first = m.objects("bench3/");
    assert_uploaded(&first, "bench3", &rec);
    // The local copies are kept.
    assert!(companions(&rec).len() >= 3);

    // Again: everything is found in the store (read back, same SHA-256)
    // and nothing is sent again: far fewer bytes than the recording.
    std::thread::sleep(Duration::from_millis(1100));
    let before = proxy.sent();
    let o = upload(
        &proxy.endpoint(),
        &m,
        &[
            "--to",
            "s3://lab-bench/bench3",
            "--json",
            rec.to_str().unwrap(),
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let s = json_stdout(&o);
    assert!(
        s["confirmed"]
            .as_array()
            .unwrap()
            .iter()
            .all(|t| t["uploaded"] == false),
        "{s}"
    );
    let sent = proxy.sent() - before;
    let size = std::fs::metadata(&rec).unwrap().len();
    assert!(
        sent < size / 20,
        "{sent} bytes sent again ({size} B recording)"
    );
    let second = m.objects("bench3/");
    for (k, v) in &first {
        assert_eq!(
            second[k]["last_modified"], v["last_modified"],
            "{k} was written again"
        );
    }

    // A directory (a NAS): the same files, byte for byte.
    let nas = tmp();
    let o = bench()
        .args(["upload", "--to"])
        .arg(format!("file://{}", nas.path().display()))
        .arg(&rec)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    for f in companions(&rec) {
        let there = nas.path().join(f.file_name().unwrap());
        assert_eq!(
            std::fs::read(&there).unwrap(),
            std::fs::read(&f).unwrap(),
            "{there:?}"
        );
    }
    let row = nas.path().join("catalogue/run.parquet");
    let rows = bench::catalogue::file::read_rows(&row).unwrap();
    assert_eq!(
        rows[0]["recording"],
        bench::catalogue::Value::Text(Some(format!("file://{}/run.mcap", nas.path().display())))
    );
}

/// An https endpoint: moto behind socat, which terminates TLS with a
/// certificate for 127.0.0.1 signed by a test CA (`s3_store.py
/// selfsigned`). `bench upload` speaks TLS through rustls on *ring*, the
/// one crypto provider compiled in, and trusts the system's roots, which
/// `SSL_CERT_FILE` names: with the test CA there, every file is confirmed
/// by checksum; with the system's own roots only, the certificate is
/// refused at once (exit 2 naming `--to` and the trust, not a store that
/// is away) and nothing is uploaded.
#[test]
fn an_https_store_is_reached_over_tls_and_an_untrusted_certificate_refused() {
    let m = Moto::start();
    let certs = tmp();
    let o = Command::new(python())
        .arg(script())
        .arg("selfsigned")
        .arg(certs.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "selfsigned: {}\n{PY_HINT}", stderr(&o));
    let port = free_port();
    let pem = |name: &str| certs.path().join(name).to_str().unwrap().to_string();
    let mut socat = Command::new("socat")
        .arg(format!(
            "OPENSSL-LISTEN:{port},bind=127.0.0.1,reuseaddr,fork,cert={},key={},verify=0",
            pem("cert.pem"),
            pem("key.pem")
        ))
        .arg(format!("TCP:127.0.0.1:{}", m.port))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("socat (tests/run installs it)");
    let t0 = Instant::now();
    while TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(socat.try_wait().unwrap().is_none(), "socat exited");
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "socat did not listen"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let dir = tmp();
    let rec = recording(dir.path(), "tls", "1");
    let https = format!("https://127.0.0.1:{port}");
    let run = |ca: Option<&str>, prefix: &str| {
        let mut c = bench();
        aws_env(&mut c, &https, &m.id, &m.secret);
        c.env_remove("AWS_ALLOW_HTTP").env_remove("SSL_CERT_DIR");
        match ca {
            Some(f) => c.env("SSL_CERT_FILE", f),
            None => c.env_remove("SSL_CERT_FILE"),
        };
        c.args(["upload", "--retry-for", "0", "--to"])
            .arg(format!("s3://lab-bench/{prefix}"))
            .arg(&rec)
            .output()
            .unwrap()
    };
    let o = run(None, "untrusted");
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("--to") && e.contains("certificate is not trusted"),
        "{e}"
    );
    assert!(m.objects("untrusted").is_empty());
    let o = run(Some(&pem("ca.pem")), "tls");
    assert!(o.status.success(), "{}", stderr(&o));
    assert_uploaded(&m.objects("tls"), "tls", &rec);
    let _ = socat.kill();
    let _ = socat.wait();
}

#[test]
fn a_multipart_upload_survives_the_store_going_away_in_the_middle() {
    let m = Moto::start();
    // 3 MB/s to the store: the ~13 MB recording takes ~4 s to go up.
    let proxy = Proxy::start(m.addr(), Some(3e6));
    let dir = tmp();
    let rec = recording(dir.path(), "long", "150");
    let size = std::fs::metadata(&rec).unwrap().len();
    assert!(
        size > bench::upload::MULTIPART_THRESHOLD_BYTES,
        "{size} B: not a multipart upload"
    );
    let mut c = bench();
    aws_env(&mut c, &proxy.endpoint(), &m.id, &m.secret);
    let child = KillOnDrop::new(
        c.args([
            "upload",
            "--to",
            "s3://lab-bench/big",
            "--retry-for",
            "120",
            "--json",
        ])
        .arg(&rec)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap(),
    );
    // Mid-upload: more than one part's worth sent, less than the file.
    let t0 = Instant::now();
    while proxy.sent() < bench::upload::PART_BYTES as u64 + 1_000_000 {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "the upload did not start"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(proxy.sent() < size, "the upload ended before the outage");
    proxy.down();
    assert!(
        m.objects("big/").is_empty(),
        "an object appeared before its upload completed"
    );
    std::thread::sleep(Duration::from_secs(3));
    proxy.up();
    let o = child.into_inner().wait_with_output().unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert!(err.contains("again in"), "no retry was needed:\n{err}");
    assert_uploaded(&m.objects("big/"), "big", &rec);
}

/// The daemon's metrics, from the address it printed on stderr.
fn scrape(d: &mut Child) -> String {
    use std::io::BufRead;
    let err = d.stderr.as_mut().unwrap();
    let mut r = std::io::BufReader::new(err);
    let mut line = String::new();
    let url = loop {
        line.clear();
        assert!(r.read_line(&mut line).unwrap() > 0, "no metrics address");
        if let Some(u) = line.trim().strip_prefix("bench serve: metrics on http://") {
            break u.to_string();
        }
    };
    let (addr, path) = url.split_once('/').unwrap();
    let mut s = TcpStream::connect(addr).unwrap();
    write!(s, "GET /{path} HTTP/1.0\r\nHost: {addr}\r\n\r\n").unwrap();
    let mut text = String::new();
    s.read_to_string(&mut text).unwrap();
    text
}

fn journal_lines(recordings: &Path) -> Vec<Value> {
    std::fs::read_to_string(recordings.join("upload-journal.jsonl"))
        .unwrap_or_default()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

#[test]
fn the_daemon_uploads_after_an_outage_and_a_kill_from_its_journal_once() {
    let m = Moto::start();
    let proxy = Proxy::start(m.addr(), None);
    let dir = tmp();
    let config = common::quiet_config(dir.path(), 1.0, "");
    let socket = dir.path().join("bench.sock");
    let recordings = dir.path().join("rec");
    let serve = || {
        daemon_fixtures::spawn_serve_with(
            &config,
            &socket,
            &recordings,
            &[
                "--upload",
                "s3://lab-bench/daemon",
                "--metrics",
                "127.0.0.1:0",
            ],
            |c| aws_env(c, &proxy.endpoint(), &m.id, &m.secret),
        )
    };
    let mut d = serve();
    // The store goes away; a job runs and ends well all the same.
    proxy.down();
    let mut c = daemon_fixtures::Client::new(&socket);
    let r = c.call(
        "chirp",
        json!({"duration_s": 2, "f_start_hz": 5, "seed": 6, "pace": "off"}),
    );
    assert_eq!(r["ok"], true, "{r}");
    let rec = PathBuf::from(r["result"]["recording"].as_str().unwrap());
    let summary: Value =
        serde_json::from_str(&std::fs::read_to_string(rec.with_extension("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary, r["result"], "the summary beside the recording");
    std::thread::sleep(Duration::from_millis(1500));
    let queued: Vec<Value> = journal_lines(&recordings)
        .into_iter()
        .filter(|l| l["op"] == "queued")
        .collect();
    assert_eq!(queued.len(), companions(&rec).len() + 1, "{queued:?}");
    assert!(m.objects("daemon/").is_empty());
    // Killed while the store is away.
    d.kill().unwrap();
    d.wait().unwrap();
    proxy.up();
    let _ = std::fs::remove_file(&socket);
    let mut d = serve();
    let t0 = Instant::now();
    loop {
        let confirmed = journal_lines(&recordings)
            .iter()
            .filter(|l| l["op"] == "confirmed")
            .count();
        if confirmed == queued.len() {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "{confirmed} of {} confirmed",
            queued.len()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    let objects = m.objects("daemon/");
    assert_uploaded(&objects, "daemon", &rec);
    readme_bucket_query(&m, &rec);
    // The event log says so: the failures while the store was away, each
    // confirmation after.
    let log = std::fs::read_to_string(recordings.join("daemon-events.jsonl")).unwrap();
    let events: Vec<Value> = log
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect();
    let count = |kind: &str| events.iter().filter(|e| e["event"] == kind).count();
    assert!(count("upload_failed") >= 1, "{log}");
    assert_eq!(count("upload_confirmed"), queued.len(), "{log}");
    // The metrics count them: every file confirmed, none pending.
    let text = scrape(&mut d);
    assert!(
        text.contains(&format!(
            "bench_uploads_total{{outcome=\"confirmed\"}} {}",
            queued.len()
        )) && text.contains("bench_upload_pending 0"),
        "{text}"
    );
    // Restarted once more: nothing pending, nothing sent again.
    d.kill().unwrap();
    d.wait().unwrap();
    let _ = std::fs::remove_file(&socket);
    let lines = journal_lines(&recordings).len();
    let before = proxy.sent();
    let mut d = serve();
    std::thread::sleep(Duration::from_secs(3));
    d.kill().unwrap();
    d.wait().unwrap();
    let sent = proxy.sent() - before;
    assert!(
        sent < 10_000,
        "{sent} bytes sent after a restart with nothing pending"
    );
    assert_eq!(journal_lines(&recordings).len(), lines);
    assert_eq!(m.objects("daemon/"), objects);
}

/// The README's bucket query (`<!-- upload example: bucket-query -->`),
/// over the daemon's uploads under `daemon/`: the chirp's row, with its
/// object's URL, and one ok run.
fn readme_bucket_query(m: &Moto, rec: &Path) {
    let block = crate::common::doc_blocks()
        .into_iter()
        .find(|b| b.marker.as_deref() == Some("upload example: bucket-query") && b.lang == "python")
        .expect("the README's bucket query")
        .body;
    let script = format!(
        "{}\nimport json\nprint(json.dumps({{\"recordings\": list(runs.recording), \"ok\": int(per_host.runs.sum())}}))\n",
        block.replace("lab-bench/recordings/bench3/", "lab-bench/daemon/")
    );
    let mut c = Command::new(python());
    aws_env(&mut c, &m.endpoint(), &m.id, &m.secret);
    let o = c.args(["-c", &script]).output().unwrap();
    assert!(o.status.success(), "{}\n{script}", stderr(&o));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    let name = rec.file_name().unwrap().to_str().unwrap();
    assert_eq!(
        v,
        json!({"recordings": [format!("s3://lab-bench/daemon/{name}")], "ok": 1}),
        "{script}"
    );
}

#[test]
fn bad_stores_and_bad_files_exit_2_naming_the_flag_and_upload_nothing() {
    let m = Moto::start();
    let dir = tmp();
    let rec = recording(dir.path(), "ok", "1");
    let r = rec.to_str().unwrap();
    let ep = m.endpoint();
    let run = |env: &dyn Fn(&mut Command), args: &[&str]| {
        let mut c = bench();
        aws_env(&mut c, &ep, &m.id, &m.secret);
        env(&mut c);
        c.arg("upload").args(args).output().unwrap()
    };
    let none = |_: &mut Command| {};
    type Case<'a> = (
        &'a str,
        Box<dyn Fn(&mut Command)>,
        Vec<&'a str>,
        i32,
        &'a str,
        &'a str,
    );
    let part = dir.path().join("ok.mcap.part");
    std::fs::copy(&rec, &part).unwrap();
    let truncated = dir.path().join("cut.mcap");
    let bytes = std::fs::read(&rec).unwrap();
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    let csv = dir.path().join("ok.frf.csv");
    let spaced = dir.path().join("my run é.mcap");
    std::fs::copy(&rec, &spaced).unwrap();
    let cases: Vec<Case> = vec![
        (
            "wrong secret",
            Box::new(|c| {
                c.env("AWS_SECRET_ACCESS_KEY", "not-the-secret");
            }),
            vec!["--to", "s3://lab-bench/x", r],
            2,
            "--to",
            "credentials",
        ),
        (
            "unknown key",
            Box::new(|c| {
                c.env("AWS_ACCESS_KEY_ID", "AKIAUNKNOWN0000000000");
            }),
            vec!["--to", "s3://lab-bench/x", r],
            2,
            "--to",
            "credentials",
        ),
        (
            "no credentials",
            Box::new(|c| {
                c.env_remove("AWS_ACCESS_KEY_ID");
            }),
            vec!["--to", "s3://lab-bench/x", r],
            2,
            "--to",
            "AWS_ACCESS_KEY_ID",
        ),
        (
            "missing bucket",
            Box::new(none),
            vec!["--to", "s3://no-such-bucket/x", r],
            2,
            "--to",
            "does not exist",
        ),
        (
            "http not allowed",
            Box::new(|c| {
                c.env_remove("AWS_ALLOW_HTTP");
            }),
            vec!["--to", "s3://lab-bench/x", r],
            2,
            "--to",
            "AWS_ALLOW_HTTP",
        ),
        (
            "unreachable",
            Box::new(|c| {
                c.env("AWS_ENDPOINT", format!("http://127.0.0.1:{}", free_port()));
            }),
            vec!["--to", "s3://lab-bench/x", "--retry-for", "0", r],
            1,
            "--to",
            "not confirmed",
        ),
        (
            "a .part",
            Box::new(none),
            vec!["--to", "s3://lab-bench/x", part.to_str().unwrap()],
            2,
            "RECORDING",
            ".part",
        ),
        (
            "a truncated recording",
            Box::new(none),
            vec!["--to", "s3://lab-bench/x", truncated.to_str().unwrap()],
            2,
            "RECORDING",
            "not a finished MCAP recording",
        ),
        (
            "a CSV",
            Box::new(none),
            vec!["--to", "s3://lab-bench/x", csv.to_str().unwrap()],
            2,
            "RECORDING",
            "ends in .mcap",
        ),
        (
            "a missing file",
            Box::new(none),
            vec!["--to", "s3://lab-bench/x", "/nonexistent/a.mcap"],
            2,
            "RECORDING",
            "No such file",
        ),
        (
            "a space in the name",
            Box::new(none),
            vec!["--to", "s3://lab-bench/x", spaced.to_str().unwrap()],
            2,
            "RECORDING",
            "rename it",
        ),
        (
            "negative retry",
            Box::new(none),
            vec!["--to", "s3://lab-bench/x", "--retry-for", "-1", r],
            2,
            "--retry-for",
            "out of range",
        ),
        (
            "NaN retry",
            Box::new(none),
            vec!["--to", "s3://lab-bench/x", "--retry-for", "NaN", r],
            2,
            "--retry-for",
            "out of range",
        ),
        (
            "a year of retries",
            Box::new(none),
            vec!["--to", "s3://lab-bench/x", "--retry-for", "3.2e7", r],
            2,
            "--retry-for",
            "out of range",
        ),
        (
            "a store timeout too short",
            Box::new(none),
            vec!["--to", "s3://lab-bench/x", "--store-timeout", "0.4", r],
            2,
            "--store-timeout",
            "out of range",
        ),
        (
            "a store timeout too long",
            Box::new(none),
            vec!["--to", "s3://lab-bench/x", "--store-timeout", "301", r],
            2,
            "--store-timeout",
            "out of range",
        ),
        (
            "a NaN store timeout",
            Box::new(none),
            vec!["--to", "s3://lab-bench/x", "--store-timeout", "NaN", r],
            2,
            "--store-timeout",
            "out of range",
        ),
    ];
    for (what, env, args, code, flag, reason) in &cases {
        let o = run(env.as_ref(), args);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(*code), "{what}: {err}");
        assert!(err.contains(flag), "{what}: {err}");
        assert!(err.contains(reason), "{what}: {err}");
    }
    assert!(m.objects("").is_empty(), "{:?}", m.objects(""));

    // The daemon: a store that refuses stops it before it opens the bench
    // (no socket); one that does not answer only delays the uploads.
    let config = common::quiet_config(dir.path(), 1.0, "");
    let socket = dir.path().join("bench.sock");
    for (what, env, url, reason) in [
        (
            "wrong secret",
            ("AWS_SECRET_ACCESS_KEY", "nope".to_string()),
            "s3://lab-bench/d",
            "credentials",
        ),
        (
            "missing bucket",
            ("AWS_REGION", "us-east-1".to_string()),
            "s3://no-such-bucket/d",
            "does not exist",
        ),
    ] {
        let mut c = bench();
        aws_env(&mut c, &ep, &m.id, &m.secret);
        c.env(env.0, &env.1);
        let o = c
            .args(["serve", "--config", config.to_str().unwrap(), "--socket"])
            .arg(&socket)
            .arg("--recordings")
            .arg(dir.path().join("rec"))
            .args(["--upload", url])
            .output()
            .unwrap();
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{what}: {err}");
        assert!(
            err.contains("--upload") && err.contains(reason),
            "{what}: {err}"
        );
        assert!(!socket.exists(), "{what}: the daemon opened its socket");
    }
    // --store-timeout out of its range, or without --upload.
    for (what, args, reason) in [
        (
            "too short",
            vec!["--upload", "s3://lab-bench/d", "--store-timeout", "0.4"],
            "out of range",
        ),
        (
            "infinite",
            vec!["--upload", "s3://lab-bench/d", "--store-timeout", "inf"],
            "out of range",
        ),
        ("without --upload", vec!["--store-timeout", "5"], "--upload"),
    ] {
        let mut c = bench();
        aws_env(&mut c, &ep, &m.id, &m.secret);
        let o = c
            .args(["serve", "--config", config.to_str().unwrap(), "--socket"])
            .arg(&socket)
            .arg("--recordings")
            .arg(dir.path().join("rec"))
            .args(&args)
            .output()
            .unwrap();
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{what}: {err}");
        assert!(
            err.contains("--store-timeout") && err.contains(reason),
            "{what}: {err}"
        );
        assert!(!socket.exists(), "{what}: the daemon opened its socket");
    }
    // A store that refuses after the probe's grace (its answer held 2 s,
    // STORE_PROBE_GRACE_MS being 1 s): the daemon has opened the bench by
    // then and runs on, the refusal on stderr and in `status`.
    let late = late_store(m.addr(), Duration::from_secs(2));
    let mut d = daemon_fixtures::spawn_serve_with(
        &config,
        &socket,
        &dir.path().join("rec"),
        &["--upload", "s3://lab-bench/d"],
        |c| aws_env(c, &format!("http://{late}"), &m.id, "not-the-secret"),
    );
    let t0 = Instant::now();
    let store = loop {
        let store = store_status(&socket);
        if store["state"] != "probing" {
            break store;
        }
        assert!(t0.elapsed() < Duration::from_secs(20), "{store}");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert_eq!(store["state"], "refused", "{store}");
    assert!(
        store["reason"]
            .as_str()
            .is_some_and(|r| r.contains("credentials")),
        "{store}"
    );
    let mut client = daemon_fixtures::Client::new(&socket);
    let r = client.call(
        "control",
        json!({"controller": "fast", "duration_s": 1, "seed": 5, "pace": "off"}),
    );
    assert_eq!(r["ok"], true, "the daemon did not run on: {r}");
    assert!(d.try_wait().unwrap().is_none(), "the daemon ended");
    let (status, err) = sigterm(d);
    assert!(status.success(), "{status:?}: {err}");
    assert!(
        err.contains("error: --upload s3://lab-bench/d") && err.contains("credentials"),
        "{err}"
    );
    let queued = journal_lines(&dir.path().join("rec"))
        .iter()
        .filter(|l| l["op"] == "queued")
        .count();
    assert!(queued > 0, "the run's files were not queued");
    std::fs::remove_file(dir.path().join("rec").join("upload-journal.jsonl")).unwrap();
    // A journal with a bad line in its middle: refused, naming the line.
    let rec_dir = dir.path().join("rec");
    std::fs::create_dir_all(&rec_dir).unwrap();
    let journal = rec_dir.join("upload-journal.jsonl");
    std::fs::write(&journal, "{\"op\":\"queued\"}\n{}\n").unwrap();
    let mut c = bench();
    aws_env(&mut c, &ep, &m.id, &m.secret);
    let o = c
        .args(["serve", "--config", config.to_str().unwrap(), "--socket"])
        .arg(&socket)
        .arg("--recordings")
        .arg(&rec_dir)
        .args(["--upload", "s3://lab-bench/d"])
        .output()
        .unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("--upload") && err.contains("line 1"), "{err}");
    assert!(!socket.exists());
    std::fs::remove_file(&journal).unwrap();
    let unreachable = format!("http://127.0.0.1:{}", free_port());
    let mut d = daemon_fixtures::spawn_serve_with(
        &config,
        &socket,
        &dir.path().join("rec"),
        &["--upload", "s3://lab-bench/d"],
        |c| aws_env(c, &unreachable, &m.id, &m.secret),
    );
    let mut client = daemon_fixtures::Client::new(&socket);
    let r = client.call(
        "control",
        json!({"controller": "fast", "duration_s": 1, "seed": 5, "pace": "off"}),
    );
    assert_eq!(r["ok"], true, "a failed upload failed the run: {r}");
    d.kill().unwrap();
    let o = d.into_inner().wait_with_output().unwrap();
    let err = stderr(&o);
    assert!(
        err.contains("--upload s3://lab-bench/d") && err.contains("did not answer"),
        "{err}"
    );
}

/// Store URLs made bad on purpose from good ones, each by one mutation
/// that a valid URL cannot have (seeded: the same cases every run).
fn bad_urls(n: usize) -> Vec<String> {
    let mut state = 0x9e37_79b9_7f4a_7c15_u64;
    let mut next = |k: usize| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state % k as u64) as usize
    };
    let good = [
        "s3://lab-bench/recordings/bench3",
        "s3://lab.bench-2/x",
        "s3://abc",
    ];
    let mut out = Vec::new();
    while out.len() < n {
        let g = good[next(good.len())];
        let (scheme, rest) = g.split_once("://").unwrap();
        let (bucket, prefix) = rest.split_once('/').map_or((rest, ""), |(b, p)| (b, p));
        let tail = if prefix.is_empty() {
            String::new()
        } else {
            format!("/{prefix}")
        };
        let bad_char = ["A", "_", " ", "?", "#", "\t", "é", "%", "!", "*"][next(10)];
        let pos = next(bucket.len() + 1);
        let url = match next(9) {
            // A character a bucket name cannot hold.
            0 => format!(
                "{scheme}://{}{bad_char}{}{tail}",
                &bucket[..pos],
                &bucket[pos..]
            ),
            // Too short or too long a bucket.
            1 => format!("{scheme}://{}{tail}", &bucket[..next(3)]),
            2 => format!("{scheme}://{}{tail}", "a".repeat(64 + next(40))),
            // Starts or ends with a dot or dash, or holds "..".
            3 => format!("{scheme}://{}{bucket}{tail}", [".", "-"][next(2)]),
            4 => format!("{scheme}://{bucket}..x{tail}"),
            // An empty, `.` or `..` segment in the prefix.
            5 => format!("{scheme}://{bucket}/{}/p", ["", ".", ".."][next(3)]),
            // Another scheme, none, or no `://`.
            6 => format!(
                "{}://{rest}",
                ["gs", "http", "https", "S3", "s4", "az", "ftp", ""][next(8)]
            ),
            7 => rest.to_string(),
            // A directory that is relative, missing or a file.
            _ => [
                "file://relative/dir".to_string(),
                format!("file:///nonexistent-{}/x", next(1000)),
                "file:///etc/hostname".to_string(),
                "file:///tmp/../etc".to_string(),
            ][next(4)]
            .clone(),
        };
        out.push(url);
    }
    out
}

#[test]
fn generated_bad_store_urls_exit_2_naming_the_flag() {
    let dir = tmp();
    let rec = recording(dir.path(), "ok", "1");
    for url in bad_urls(60) {
        let o = bench()
            .args(["upload", "--to", &url])
            .arg(&rec)
            .env("AWS_ACCESS_KEY_ID", "a")
            .env("AWS_SECRET_ACCESS_KEY", "b")
            .output()
            .unwrap();
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{url:?}: {err}");
        assert!(err.contains("--to"), "{url:?}: {err}");
    }
    let config = common::quiet_config(dir.path(), 1.0, "");
    let socket = dir.path().join("bench.sock");
    for url in bad_urls(72).into_iter().skip(60) {
        let o = bench()
            .args(["serve", "--config", config.to_str().unwrap(), "--socket"])
            .arg(&socket)
            .arg("--recordings")
            .arg(dir.path().join("rec"))
            .args(["--upload", &url])
            .output()
            .unwrap();
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{url:?}: {err}");
        assert!(err.contains("--upload"), "{url:?}: {err}");
        assert!(!socket.exists());
    }
}

/// A small campaign (2 cells, 1 s chirps) in `dir/NAME` keeping `keep`.
fn campaign(dir: &Path, name: &str, keep: &str) -> PathBuf {
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"),
        dir.join("sr4dof-ch5.toml"),
    )
    .unwrap();
    let file = dir.join("two.toml");
    std::fs::write(
        &file,
        "config = \"sr4dof-ch5.toml\"\nseed = 4\n[grid]\noperating_point_pct = [4.0, 8.0]\nmass_asymmetry = [0.1]\n[chirp]\nduration_s = 1.0\n",
    )
    .unwrap();
    let o = bench()
        .current_dir(dir)
        .args([
            "campaign",
            "run",
            "two.toml",
            "--threads",
            "1",
            "--out",
            name,
            "--keep",
            keep,
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    dir.join(name)
}

/// The regular files below `dir`, relative, hidden ones left out.
fn files_below(dir: &Path, rel: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir.join(rel)).unwrap() {
        let e = e.unwrap();
        let n = e.file_name();
        if n.to_str().unwrap().starts_with('.') {
            continue;
        }
        if e.file_type().unwrap().is_dir() {
            files_below(dir, &rel.join(&n), out);
        } else {
            out.push(rel.join(&n));
        }
    }
}

/// Every file of campaign `dir` is an object `PREFIX/NAME/RELATIVE PATH`
/// with its size and SHA-256, but the rows of cells whose recordings went
/// up, which name the recording's object; nothing else is under
/// `PREFIX/NAME/`.
fn assert_campaign_uploaded(objects: &serde_json::Map<String, Value>, prefix: &str, dir: &Path) {
    assert_dir_uploaded(objects, prefix, dir, 2);
}

/// Every file below `dir` is in the store under `PREFIX/DIR/`, byte for
/// byte, `rows` of them a campaign cell's catalogue row.
fn assert_dir_uploaded(
    objects: &serde_json::Map<String, Value>,
    prefix: &str,
    dir: &Path,
    want_rows: usize,
) {
    let name = dir.file_name().unwrap().to_str().unwrap();
    let mut files = Vec::new();
    files_below(dir, Path::new(""), &mut files);
    let mine: Vec<&String> = objects
        .keys()
        .filter(|k| k.starts_with(&format!("{prefix}/{name}/")))
        .collect();
    assert_eq!(mine.len(), files.len(), "{mine:?} vs {files:?}");
    let mut rows = 0;
    for rel in &files {
        let rel_s = rel.to_str().unwrap();
        let key = format!("{prefix}/{name}/{rel_s}");
        let o = &objects
            .get(&key)
            .unwrap_or_else(|| panic!("{key} not in the store: {objects:?}"));
        if let Some(cell) = rel_s
            .strip_prefix("catalogue/cell-")
            .and_then(|r| r.strip_suffix(".parquet"))
        {
            rows += 1;
            let rec = dir.join(format!("cells/{cell}/chirp.mcap"));
            if rec.is_file() {
                assert_eq!(
                    o["recording"],
                    json!(format!(
                        "s3://lab-bench/{prefix}/{name}/cells/{cell}/chirp.mcap"
                    )),
                    "{key}"
                );
                continue;
            }
            assert_eq!(o["recording"], Value::Null, "{key}");
        }
        let f = dir.join(rel);
        assert_eq!(
            o["size"],
            json!(std::fs::metadata(&f).unwrap().len()),
            "{key}"
        );
        assert_eq!(o["sha256"], json!(sha256_of(&f)), "{key}");
    }
    assert_eq!(rows, want_rows, "{files:?}");
}

/// A campaign directory goes up whole with `bench upload` (the cells'
/// rows naming their recordings' objects, or null when not kept), and a
/// daemon with `--upload` uploads the campaign jobs it ran, and a track
/// job's directory.
#[test]
fn campaigns_go_up_whole_from_the_cli_and_the_daemon() {
    let m = Moto::start();
    let dir = tmp();
    let kept = campaign(dir.path(), "kept", "recording");
    let small = campaign(dir.path(), "small", "summary");
    let o = upload(
        &m.endpoint(),
        &m,
        &[
            "--to",
            "s3://lab-bench/camp",
            "--json",
            kept.to_str().unwrap(),
            small.to_str().unwrap(),
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let objects = m.objects("camp/");
    assert_campaign_uploaded(&objects, "camp", &kept);
    assert_campaign_uploaded(&objects, "camp", &small);
    // A directory that is no campaign is refused, naming it; nothing goes up.
    let o = upload(
        &m.endpoint(),
        &m,
        &["--to", "s3://lab-bench/none", dir.path().to_str().unwrap()],
    );
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("not a campaign directory"),
        "{}",
        stderr(&o)
    );
    assert!(m.objects("none/").is_empty());

    // The daemon's campaign job.
    let config = common::quiet_config(dir.path(), 1.0, "");
    let socket = dir.path().join("bench.sock");
    let recordings = dir.path().join("rec");
    let mut d = daemon_fixtures::spawn_serve_with(
        &config,
        &socket,
        &recordings,
        &["--upload", "s3://lab-bench/daemon"],
        |c| aws_env(c, &m.endpoint(), &m.id, &m.secret),
    );
    let mut c = daemon_fixtures::Client::new(&socket);
    let r = c.call(
        "campaign",
        json!({"file": dir.path().join("two.toml"), "threads": 1, "keep": "frf"}),
    );
    assert_eq!(r["ok"], true, "{r}");
    let cdir = PathBuf::from(r["result"]["dir"].as_str().unwrap());
    let mut files = Vec::new();
    files_below(&cdir, Path::new(""), &mut files);
    // A track job's directory goes up whole too (its trials, track.json,
    // the feedforward and the figure).
    let r = c.call("track", json!({"trials": 1, "periods": 1, "pace": "off"}));
    assert_eq!(r["ok"], true, "{r}");
    let tdir = PathBuf::from(r["result"]["trials"][0]["recording"].as_str().unwrap())
        .parent()
        .unwrap()
        .to_path_buf();
    files_below(&tdir, Path::new(""), &mut files);
    let t0 = Instant::now();
    while journal_lines(&recordings)
        .iter()
        .filter(|l| l["op"] == "confirmed")
        .count()
        < files.len()
    {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "{:?}",
            journal_lines(&recordings)
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    d.kill().unwrap();
    d.wait().unwrap();
    assert_campaign_uploaded(&m.objects("daemon/"), "daemon", &cdir);
    assert_dir_uploaded(&m.objects("daemon/"), "daemon", &tdir, 0);
}

/// The `store` of the daemon's `status`, over a connection of its own.
fn store_status(socket: &Path) -> Value {
    let mut c = daemon_fixtures::Client::new(socket);
    let r = c.call("status", json!({}));
    assert_eq!(r["ok"], true, "{r}");
    r["result"]["store"].clone()
}

/// Issue 46, item 7: a store that takes connections and never answers
/// does not hold the daemon's socket. The daemon waits for the store's
/// probe at most `STORE_PROBE_GRACE_MS` (1 s), then opens the bench and
/// its socket while the probe goes on; `status` shows the store
/// `probing`, then `unreachable` once the probe's request has had its
/// `--store-timeout`; a job runs meanwhile and its files stay queued in
/// the journal; SIGTERM ends the daemon as usual. Before the fix the
/// probe ran before the socket was opened: 120 s without an answer (10 s
/// with the default `--store-timeout`).
#[test]
fn a_silent_store_does_not_hold_the_daemons_socket_and_status_shows_its_probe() {
    let silent = SilentStore::start();
    let dir = tmp();
    let config = common::quiet_config(dir.path(), 1.0, "");
    // The socket must answer within the probe's grace and what the
    // daemon's own start takes: the process, the config, the simulator,
    // the socket (30–60 ms on this 2-core VM with a compiler running
    // beside it: answered 1.03–1.06 s after the spawn); 0.5 s of margin
    // for that.
    let grace = Duration::from_millis(bench::daemon::STORE_PROBE_GRACE_MS);
    let answer_bound = grace + Duration::from_millis(500);
    let serve = |name: &str, extra: &[&str]| {
        let socket = dir.path().join(format!("{name}.sock"));
        let recordings = dir.path().join(name);
        let mut args = vec!["--upload", "s3://lab-bench/silent"];
        args.extend_from_slice(extra);
        let t0 = Instant::now();
        let d = daemon_fixtures::spawn_serve_with(&config, &socket, &recordings, &args, |c| {
            aws_env(c, &silent.endpoint(), "AKIAEXAMPLE000000000", "not-checked");
        });
        let store = store_status(&socket);
        let answered = t0.elapsed();
        eprintln!("{name}: the socket answered `status` {answered:?} after the spawn");
        assert!(
            answered <= answer_bound,
            "{name}: the socket answered after {answered:?} (bound {answer_bound:?})"
        );
        (d, socket, recordings, store, t0)
    };

    // The default --store-timeout (documented: at most 10 s): the socket
    // answers well before it, the store still being probed.
    let (d, socket, _, store, _) = serve("default", &[]);
    assert_eq!(store["url"], "s3://lab-bench/silent", "{store}");
    assert_eq!(store["state"], "probing", "{store}");
    let timeout_s = store["timeout_s"].as_f64().unwrap();
    assert!(timeout_s > 0.0 && timeout_s <= 10.0, "{store}");
    assert!(silent.accepted() >= 1, "the probe never reached the store");
    // `bench daemon status` shows it.
    let o = bench()
        .args(["daemon", "status", "--socket"])
        .arg(&socket)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        out.lines()
            .any(|l| l.starts_with("upload store") && l.contains("s3://lab-bench/silent probing")),
        "{out}"
    );
    // SIGTERM while the probe still waits for the store.
    let (status, err) = sigterm(d);
    assert!(status.success(), "{status:?}: {err}");
    assert!(!socket.exists(), "socket left behind");

    // A short --store-timeout: probing, then unreachable once the probe
    // has had its timeout, the daemon serving jobs all along.
    let timeout = Duration::from_secs(2);
    let (d, socket, recordings, store, t0) = serve("short", &["--store-timeout", "2"]);
    assert_eq!(store["state"], "probing", "{store}");
    assert_eq!(store["timeout_s"], 2.0, "{store}");
    let mut c = daemon_fixtures::Client::new(&socket);
    let r = c.call(
        "chirp",
        json!({"duration_s": 1, "f_start_hz": 5, "seed": 6, "pace": "off"}),
    );
    assert_eq!(r["ok"], true, "{r}");
    let rec = PathBuf::from(r["result"]["recording"].as_str().unwrap());
    let queued = journal_lines(&recordings)
        .iter()
        .filter(|l| l["op"] == "queued")
        .count();
    assert_eq!(queued, companions(&rec).len() + 1, "{rec:?}");
    // The probe started before the grace, so within a timeout of the
    // spawn; a margin of 1 s for the process's start and the polling.
    let unreachable_bound = timeout + Duration::from_secs(1);
    let store = loop {
        let store = store_status(&socket);
        if store["state"] != "probing" {
            break store;
        }
        assert!(
            t0.elapsed() <= unreachable_bound,
            "still probing {:?} after the spawn: {store}",
            t0.elapsed()
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    eprintln!("short: unreachable {:?} after the spawn", t0.elapsed());
    assert_eq!(store["state"], "unreachable", "{store}");
    assert!(
        store["reason"].as_str().is_some_and(|r| !r.is_empty()),
        "{store}"
    );
    // Still serving, the recording still queued, never confirmed.
    assert_eq!(c.call("status", json!({}))["ok"], true);
    assert!(journal_lines(&recordings)
        .iter()
        .all(|l| l["op"] == "queued"));
    let (status, err) = sigterm(d);
    assert!(status.success(), "{status:?}: {err}");
    assert!(
        err.contains("--upload s3://lab-bench/silent") && err.contains("did not answer"),
        "{err}"
    );
    assert!(rec.is_file());
}

/// Issue 46, item 7: `bench upload --retry-for N` against a store that
/// takes connections and never answers returns within N plus one
/// `--store-timeout` (its probe counts as a try; no request waits longer
/// than the timeout), plus 2 s for the process (start, the recording's
/// check and SHA-256), exit 1 naming `--to`, the recording untouched.
/// Before the fix: 240 s for `--retry-for 5` (a 120 s request timeout).
/// The documented default `--store-timeout` is at most 10 s, for
/// `bench upload` and `bench serve` alike.
#[test]
fn bench_upload_to_a_silent_store_returns_within_retry_for_plus_one_timeout() {
    let silent = SilentStore::start();
    let dir = tmp();
    let rec = recording(dir.path(), "held", "1");
    let before = sha256_of(&rec);
    let (retry_for_s, timeout_s) = (2.0, 1.0);
    let mut c = bench();
    aws_env(
        &mut c,
        &silent.endpoint(),
        "AKIAEXAMPLE000000000",
        "not-checked",
    );
    let t0 = Instant::now();
    let o = c
        .args(["upload", "--to", "s3://lab-bench/silent", "--json"])
        .args(["--retry-for", &retry_for_s.to_string()])
        .args(["--store-timeout", &timeout_s.to_string()])
        .arg(&rec)
        .output()
        .unwrap();
    let took = t0.elapsed();
    eprintln!("bench upload --retry-for {retry_for_s} --store-timeout {timeout_s}: {took:?}");
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--to") && err.contains("not confirmed"),
        "{err}"
    );
    let bound = Duration::from_secs_f64(retry_for_s + timeout_s + 2.0);
    assert!(took <= bound, "took {took:?} (bound {bound:?})");
    assert!(silent.accepted() >= 1, "the store was never reached");
    let summary = json_stdout(&o);
    assert!(
        summary["confirmed"].as_array().unwrap().is_empty(),
        "{summary}"
    );
    assert_eq!(
        summary["failed"].as_array().unwrap().len(),
        companions(&rec).len() + 1,
        "{summary}"
    );
    assert_eq!(sha256_of(&rec), before, "the recording changed");

    // The documented defaults.
    for cmd in ["upload", "serve"] {
        let o = bench().args([cmd, "--help"]).output().unwrap();
        let help = String::from_utf8_lossy(&o.stdout).into_owned();
        let at = help
            .find("--store-timeout")
            .unwrap_or_else(|| panic!("bench {cmd} --help: no --store-timeout\n{help}"));
        let rest = &help[at..];
        let default: f64 = rest[rest.find("[default: ").unwrap() + 10..]
            .split(']')
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert!(default > 0.0 && default <= 10.0, "bench {cmd}: {default}");
    }
}
