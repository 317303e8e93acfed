//! `bench serve --metrics` at the process boundary (issue 30, part 1): a
//! daemon's `/metrics` scraped over HTTP after jobs, read by a parser of
//! the text format written here (not the code under test's), its figures
//! checked against what the test knows independently (ticks from each
//! job's duration × the config's rate, the recordings' sizes on disk, the
//! config hash from the recording's own config text, the wall time between
//! scrapes); a real Prometheus (Debian's `prometheus` package, which
//! `.ci/run` installs) scraping a running daemon and answering the
//! README's queries; the HTTP surface; slow scrapers; and bad `--metrics`
//! values, each refused naming the flag before anything is opened.

use crate::common;
use crate::daemon_fixtures;

use common::*;
use daemon_fixtures::*;
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

// ---------------------------------------------------------------------
// The text format (Prometheus exposition format 0.0.4), parsed here.
// ---------------------------------------------------------------------

/// One sample line.
#[derive(Debug, Clone)]
struct Sample {
    name: String,
    labels: BTreeMap<String, String>,
    value: f64,
}

/// A scrape, parsed and checked for the format's rules: every line a
/// `# HELP`, a `# TYPE` or a sample; every sample's family declared by a
/// `# TYPE` before it; names and label names of the allowed characters.
#[derive(Debug)]
struct Exposition {
    samples: Vec<Sample>,
    /// Family name → type.
    types: BTreeMap<String, String>,
}

fn is_name(s: &str, colon: bool) -> bool {
    let mut chars = s.chars();
    let ok_first = |c: char| c.is_ascii_alphabetic() || c == '_' || (colon && c == ':');
    chars.next().is_some_and(ok_first) && chars.all(|c| ok_first(c) || c.is_ascii_digit())
}

fn parse_value(s: &str) -> f64 {
    match s {
        "+Inf" => f64::INFINITY,
        "-Inf" => f64::NEG_INFINITY,
        "NaN" => f64::NAN,
        s => s
            .parse()
            .unwrap_or_else(|_| panic!("not a sample value: {s:?}")),
    }
}

/// `{k="v",…}` → labels, and the rest of the line after `}`.
fn parse_labels(s: &str) -> (BTreeMap<String, String>, &str) {
    let mut labels = BTreeMap::new();
    let mut rest = s.strip_prefix('{').unwrap();
    loop {
        rest = rest.trim_start_matches(',');
        if let Some(r) = rest.strip_prefix('}') {
            return (labels, r);
        }
        let eq = rest.find('=').expect("label without =");
        let key = &rest[..eq];
        assert!(is_name(key, false), "label name {key:?}");
        rest = rest[eq + 1..]
            .strip_prefix('"')
            .expect("label value unquoted");
        let mut value = String::new();
        let mut chars = rest.char_indices();
        let end = loop {
            let (i, c) = chars.next().expect("unterminated label value");
            match c {
                '\\' => match chars.next().expect("dangling escape").1 {
                    'n' => value.push('\n'),
                    c @ ('\\' | '"') => value.push(c),
                    c => panic!("bad escape \\{c}"),
                },
                '"' => break i,
                c => value.push(c),
            }
        };
        assert!(
            labels.insert(key.to_string(), value).is_none(),
            "label {key} twice"
        );
        rest = &rest[end + 1..];
    }
}

fn parse_exposition(text: &str) -> Exposition {
    let mut samples = Vec::new();
    let mut types = BTreeMap::new();
    for line in text.lines() {
        if line.is_empty() {
            continue;
        }
        if let Some(c) = line.strip_prefix("# ") {
            let mut parts = c.splitn(3, ' ');
            let (kind, name) = (parts.next().unwrap(), parts.next().unwrap_or(""));
            assert!(is_name(name, true), "{line}");
            if kind == "TYPE" {
                let t = parts.next().unwrap_or("");
                assert!(
                    ["counter", "gauge", "histogram", "summary", "untyped"].contains(&t),
                    "{line}"
                );
                assert!(
                    types.insert(name.to_string(), t.to_string()).is_none(),
                    "{line}"
                );
            } else {
                assert_eq!(kind, "HELP", "{line}");
            }
            continue;
        }
        let name_end = line.find(['{', ' ']).expect(line);
        let name = &line[..name_end];
        assert!(is_name(name, true), "{line}");
        let (labels, rest) = if line[name_end..].starts_with('{') {
            parse_labels(&line[name_end..])
        } else {
            (BTreeMap::new(), &line[name_end..])
        };
        let mut fields = rest.split_whitespace();
        let value = parse_value(fields.next().expect(line));
        assert!(fields.count() <= 1, "{line}");
        // Declared before its first sample.
        let family = [name, name.trim_end_matches("_bucket")]
            .into_iter()
            .chain(name.strip_suffix("_sum"))
            .chain(name.strip_suffix("_count"))
            .find(|f| types.contains_key(*f))
            .unwrap_or_else(|| panic!("no # TYPE before {line}"));
        if family != name {
            assert_eq!(types[family], "histogram", "{line}");
        }
        samples.push(Sample {
            name: name.to_string(),
            labels,
            value,
        });
    }
    Exposition { samples, types }
}

/// A histogram read back: `(le, cumulative count)` in order, sum, count.
#[derive(Debug)]
struct Histogram {
    buckets: Vec<(f64, f64)>,
    sum: f64,
    count: f64,
}

impl Exposition {
    /// The samples of `name` whose labels include `labels`.
    fn all(&self, name: &str, labels: &[(&str, &str)]) -> Vec<&Sample> {
        self.samples
            .iter()
            .filter(|s| {
                s.name == name
                    && labels
                        .iter()
                        .all(|(k, v)| s.labels.get(*k).map(String::as_str) == Some(*v))
            })
            .collect()
    }

    /// The one sample of `name` with `labels`.
    fn get(&self, name: &str, labels: &[(&str, &str)]) -> f64 {
        let v = self.all(name, labels);
        assert_eq!(v.len(), 1, "{name} {labels:?}: {v:?}");
        v[0].value
    }

    /// The histogram `name`, checked: `le` increasing and ending at
    /// `+Inf`, counts cumulative, `+Inf` = `_count`, a sum that is a
    /// number.
    fn histogram(&self, name: &str) -> Histogram {
        assert_eq!(self.types[name], "histogram");
        let buckets: Vec<(f64, f64)> = self
            .all(&format!("{name}_bucket"), &[])
            .iter()
            .map(|s| (parse_value(&s.labels["le"]), s.value))
            .collect();
        let h = Histogram {
            sum: self.get(&format!("{name}_sum"), &[]),
            count: self.get(&format!("{name}_count"), &[]),
            buckets,
        };
        assert!(h.buckets.len() > 10, "{name}: {:?}", h.buckets);
        assert!(h
            .buckets
            .windows(2)
            .all(|w| w[0].0 < w[1].0 && w[0].1 <= w[1].1));
        assert_eq!(
            h.buckets.last().unwrap(),
            &(f64::INFINITY, h.count),
            "{name}"
        );
        assert!(h.sum.is_finite() && h.sum >= 0.0, "{name}: {h:?}");
        h
    }
}

// ---------------------------------------------------------------------
// HTTP, the daemon, the config.
// ---------------------------------------------------------------------

/// One HTTP/1.1 request (`Connection: close`): status, headers (lower-case
/// names), body.
fn http(
    addr: &str,
    method: &str,
    path: &str,
    accept: Option<&str>,
) -> (u16, BTreeMap<String, String>, String) {
    try_http(addr, method, path, accept)
        .unwrap_or_else(|e| panic!("{method} http://{addr}{path}: {e}"))
}

/// [`http`], failures returned.
fn try_http(
    addr: &str,
    method: &str,
    path: &str,
    accept: Option<&str>,
) -> Result<(u16, BTreeMap<String, String>, String), String> {
    let mut s = TcpStream::connect(addr).map_err(|e| e.to_string())?;
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let accept = accept.map_or(String::new(), |a| format!("Accept: {a}\r\n"));
    write!(
        s,
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\n{accept}Connection: close\r\n\r\n"
    )
    .map_err(|e| e.to_string())?;
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).map_err(|e| e.to_string())?;
    let raw = String::from_utf8(raw).map_err(|e| e.to_string())?;
    let (head, body) = raw
        .split_once("\r\n\r\n")
        .ok_or_else(|| format!("no complete header in {raw:?}"))?;
    let mut lines = head.lines();
    let status: u16 = lines
        .next()
        .and_then(|l| l.split(' ').nth(1))
        .and_then(|c| c.parse().ok())
        .ok_or_else(|| format!("no status line in {head:?}"))?;
    let headers = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    Ok((status, headers, body.to_string()))
}

/// `GET /metrics`, parsed.
fn scrape(addr: &str) -> Exposition {
    let (status, headers, body) = http(addr, "GET", "/metrics", None);
    assert_eq!(status, 200, "{body}");
    assert_eq!(
        headers["content-type"],
        "text/plain; version=0.0.4; charset=utf-8"
    );
    assert_eq!(
        headers["content-length"].parse::<usize>().unwrap(),
        body.len()
    );
    parse_exposition(&body)
}

/// A daemon with `--metrics`, its metrics address read from its stderr
/// (which a thread keeps draining).
struct Metered {
    d: Daemon,
    /// `IP:PORT` to connect to.
    addr: String,
    /// The URL it printed.
    url: String,
}

impl Metered {
    /// `bench serve --metrics METRICS` with the test config, its chirp
    /// shortened to 1 s.
    fn start(metrics: &str) -> Self {
        let mut d = Daemon::start_edited(
            &["--metrics", metrics],
            "",
            |t| t.replace("duration_s = 60.0", "duration_s = 1.0"),
            |_| {},
        );
        let stderr = d.child.stderr.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines() {
                let Ok(line) = line else { break };
                let _ = tx.send(line);
            }
        });
        let url = loop {
            let line = rx
                .recv_timeout(Duration::from_secs(10))
                .expect("bench serve did not print its metrics address");
            if let Some(u) = line.strip_prefix("bench serve: metrics on ") {
                break u.to_string();
            }
        };
        let hostport = url
            .strip_prefix("http://")
            .and_then(|u| u.strip_suffix("/metrics"))
            .unwrap_or_else(|| panic!("{url}"));
        let port = hostport.rsplit_once(':').unwrap().1;
        let addr = format!("127.0.0.1:{port}");
        Self { d, addr, url }
    }
}

/// The config file's `[loop] rate_hz` and `[chirp]` lead-in, sweep and
/// tail, s.
fn config_figures(config: &Path) -> (f64, f64, f64, f64) {
    let t: toml::Table = toml::from_str(&std::fs::read_to_string(config).unwrap()).unwrap();
    let f = |table: &str, key: &str| t[table][key].as_float().unwrap();
    (
        f("loop", "rate_hz"),
        f("chirp", "lead_in_s"),
        f("chirp", "duration_s"),
        f("chirp", "tail_s"),
    )
}

fn job_ticks(e: &Exposition) -> f64 {
    e.get("bench_loop_ticks_total", &[("phase", "job")])
}

fn all_ticks(e: &Exposition) -> f64 {
    job_ticks(e) + e.get("bench_loop_ticks_total", &[("phase", "hold")])
}

/// The loop's series of one scrape agree with each other: both
/// histograms count every tick the loop ran.
fn check_loop_series(e: &Exposition) {
    let wake = e.histogram("bench_loop_wakeup_latency_seconds");
    let compute = e.histogram("bench_loop_compute_seconds");
    assert_eq!(wake.count, compute.count);
    assert_eq!(wake.count, all_ticks(e));
    assert!(e.get("bench_loop_overruns_total", &[]) <= wake.count);
    // A period is 200 µs: the median tick wakes and computes within it.
    for h in [&wake, &compute] {
        let median = h.buckets.iter().find(|b| b.1 >= h.count / 2.0).unwrap().0;
        assert!(median <= 200e-6, "{h:?}");
    }
}

/// Sum of the sizes of the `.mcap` files in `dir`, bytes.
fn mcap_bytes(dir: &Path) -> u64 {
    files_in(dir)
        .iter()
        .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
        .map(|p| std::fs::metadata(p).unwrap().len())
        .sum()
}

/// The `bench.config` metadata of a recording.
fn recorded_config(rec: &Path) -> BTreeMap<String, String> {
    let bytes = std::fs::read(rec).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let idx = summary
        .metadata_indexes
        .iter()
        .find(|m| m.name == "bench.config")
        .unwrap();
    mcap::read::metadata(&bytes, idx).unwrap().metadata
}

fn sha256_hex(text: &str) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(text.as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

// ---------------------------------------------------------------------
// The tests.
// ---------------------------------------------------------------------

/// Jobs on a daemon with `--metrics 0` (a bare port: loopback, the OS's
/// choice): every figure is what the test expects from what it ran.
#[test]
fn a_scrape_counts_the_loop_s_ticks_jobs_faults_and_recordings() {
    let _g = one_at_a_time();
    let m = Metered::start("0");
    assert!(m.url.starts_with("http://127.0.0.1:"), "{}", m.url);
    let (rate_hz, lead_in_s, sweep_s, tail_s) = config_figures(&m.d.config);
    let rec_dir = m.d.dir.path().join("rec");
    let mut c = m.d.client();

    // The hold's first ticks reach the metrics within 0.1 s.
    let t0 = Instant::now();
    let s0 = loop {
        let e = scrape(&m.addr);
        if all_ticks(&e) > 0.0 {
            break e;
        }
        assert!(t0.elapsed() < Duration::from_secs(2), "no tick counted");
        std::thread::sleep(Duration::from_millis(50));
    };
    let t0 = Instant::now();
    check_loop_series(&s0);
    assert_eq!(job_ticks(&s0), 0.0);
    assert_eq!(s0.get("bench_recorder_bytes_total", &[]), 0.0);
    assert_eq!(
        s0.get("bench_supervisor_state", &[("state", "disabled")]),
        1.0
    );
    // No job yet: no jobs_total series at all.
    assert!(s0.all("bench_jobs_total", &[]).is_empty());
    // Every fault kind, from 0.
    for k in bench::vocab::FaultKind::ALL {
        assert_eq!(s0.get("bench_faults_total", &[("kind", k.as_str())]), 0.0);
    }
    assert_eq!(
        s0.all("bench_faults_total", &[]).len(),
        bench::vocab::FaultKind::ALL.len()
    );
    // The simulator has no link: no link series.
    assert!(s0
        .samples
        .iter()
        .all(|s| !s.name.starts_with("bench_link_")));

    // Each job runs past the machine's own stalls (a VM not running the
    // loop's vCPU ends a job with an overruns fault, as it must): such an
    // attempt is reset and run again, and counted below as what it was.
    // `before` is the scrape just before the attempt that counts.
    let mut stalled = BTreeMap::<&str, f64>::new();
    let mut run = |c: &mut Client, kind: &'static str, params: Value| {
        let (r, before, seen) = retry_machine_stalls(c, |c| {
            let before = scrape(&m.addr);
            (c.call(kind, params.clone()), before)
        });
        *stalled.entry(kind).or_default() += seen.len() as f64;
        (r, before)
    };

    // A closed-loop step of 1 s: exactly 1 s × rate job ticks.
    let (r, before) = run(
        &mut c,
        "control",
        json!({ "controller": "fast", "duration_s": 1.0 }),
    );
    assert_eq!(r["ok"], true, "{r}");
    let s1 = scrape(&m.addr);
    check_loop_series(&s1);
    assert_eq!(job_ticks(&s1) - job_ticks(&before), (1.0 * rate_hz).round());
    assert_eq!(
        s1.get(
            "bench_jobs_total",
            &[("kind", "control"), ("outcome", "ok")]
        ),
        1.0
    );
    assert_eq!(s1.get("bench_recorder_queue_fill_ratio", &[]), 0.0);

    // A chirp: lead-in + sweep + tail, × rate.
    let (r, before) = run(&mut c, "chirp", json!({}));
    assert_eq!(r["ok"], true, "{r}");
    let s2 = scrape(&m.addr);
    check_loop_series(&s2);
    assert_eq!(
        job_ticks(&s2) - job_ticks(&before),
        ((lead_in_s + sweep_s + tail_s) * rate_hz).round()
    );
    assert_eq!(
        s2.get("bench_jobs_total", &[("kind", "chirp"), ("outcome", "ok")]),
        1.0
    );
    // The chirp ran the daemon's config unchanged: its recording's config
    // text hashes to the daemon's config hash.
    let rec = PathBuf::from(r["result"]["recording"].as_str().unwrap());
    let recorded = recorded_config(&rec);
    let info = s2.all("bench_build_info", &[]);
    assert_eq!(info.len(), 1);
    assert_eq!(info[0].value, 1.0);
    assert_eq!(info[0].labels["config_hash"], sha256_hex(&recorded["toml"]));
    assert_eq!(info[0].labels["version"], env!("CARGO_PKG_VERSION"));
    assert_eq!(info[0].labels["backend"], "sim:sr4dof");

    // A fault in a job: counted by kind, the state faulted.
    let (r, _) = run(
        &mut c,
        "control",
        json!({ "controller": "fast", "duration_s": 1.5, "inject_fault": "drop@0.3" }),
    );
    assert_eq!(r["error"]["kind"], "fault", "{r}");
    assert_eq!(r["error"]["summary"]["fault"]["kind"], "link", "{r}");
    let machine_stalls: f64 = stalled.values().sum();
    let s3 = scrape(&m.addr);
    check_loop_series(&s3);
    for k in bench::vocab::FaultKind::ALL {
        let want = match k.as_str() {
            "link" => 1.0,
            "overruns" => machine_stalls,
            _ => 0.0,
        };
        assert_eq!(s3.get("bench_faults_total", &[("kind", k.as_str())]), want);
    }
    for kind in ["control", "chirp"] {
        let ended_by_the_drop = f64::from(u8::from(kind == "control"));
        assert_eq!(
            s3.all("bench_jobs_total", &[("kind", kind), ("outcome", "fault")])
                .iter()
                .map(|x| x.value)
                .sum::<f64>(),
            ended_by_the_drop + stalled.get(kind).copied().unwrap_or(0.0),
            "{kind}"
        );
    }
    let states: Vec<(String, f64)> = s3
        .all("bench_supervisor_state", &[])
        .iter()
        .map(|s| (s.labels["state"].clone(), s.value))
        .collect();
    assert_eq!(states.len(), 4, "{states:?}");
    for (state, v) in &states {
        assert_eq!(*v, f64::from(u8::from(state == "faulted")), "{states:?}");
    }
    // Three recordings (and one per stalled attempt), every byte of them
    // counted.
    assert_eq!(
        files_in(&rec_dir)
            .iter()
            .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
            .count() as f64,
        3.0 + machine_stalls
    );
    assert_eq!(
        s3.get("bench_recorder_bytes_total", &[]),
        mcap_bytes(&rec_dir) as f64
    );

    assert_eq!(c.call("reset", json!({}))["ok"], true);
    let s4 = scrape(&m.addr);
    let t4 = t0.elapsed().as_secs_f64();
    check_loop_series(&s4);
    assert_eq!(
        s4.get("bench_supervisor_state", &[("state", "disabled")]),
        1.0
    );
    assert_eq!(
        s4.get("bench_supervisor_state", &[("state", "faulted")]),
        0.0
    );
    // The loop ran all along at its rate, every tick counted: never more
    // than the wall time allows (each scrape sees the loop as it was up to
    // 0.1 s before), and not far fewer (a stalled VM skips deadlines).
    let ticks = all_ticks(&s4) - all_ticks(&s0);
    assert!(ticks <= rate_hz * (t4 + 0.2), "{ticks} ticks in {t4:.2} s");
    assert!(ticks >= 0.5 * rate_hz * t4, "{ticks} ticks in {t4:.2} s");
    // Counters never go back.
    for (a, b) in [(&s0, &s1), (&s1, &s2), (&s2, &s3), (&s3, &s4)] {
        for name in [
            "bench_loop_overruns_total",
            "bench_recorder_bytes_total",
            "bench_loop_wakeup_latency_seconds_count",
        ] {
            assert!(b.get(name, &[]) >= a.get(name, &[]), "{name}");
        }
    }
}

/// `s` percent-encoded for a URL query (everything but the unreserved).
fn url_encode(s: &str) -> String {
    s.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'.' | b'_' | b'~' => {
                (b as char).to_string()
            }
            b => format!("%{b:02X}"),
        })
        .collect()
}

/// Prometheus' `/api/v1/query` for `q`: the result vector.
fn promql(web: &str, q: &str) -> Vec<Value> {
    let (status, _, body) = http(
        web,
        "GET",
        &format!("/api/v1/query?query={}", url_encode(q)),
        None,
    );
    let v: Value = serde_json::from_str(&body).unwrap_or_else(|e| panic!("{e}: {body}"));
    assert_eq!(status, 200, "{q}: {v}");
    assert_eq!(v["status"], "success", "{q}: {v}");
    assert_eq!(v["data"]["resultType"], "vector", "{q}: {v}");
    v["data"]["result"].as_array().unwrap().clone()
}

/// The one value of `q`'s result.
fn promql_value(web: &str, q: &str) -> f64 {
    let r = promql(web, q);
    assert_eq!(r.len(), 1, "{q}: {r:?}");
    r[0]["value"][1].as_str().unwrap().parse().unwrap()
}

/// Polls `q` until its one value is `want` (≤ `timeout`).
fn wait_for_value(web: &str, q: &str, want: f64, timeout: Duration) {
    let t0 = Instant::now();
    loop {
        let r = promql(web, q);
        if r.len() == 1 && r[0]["value"][1].as_str() == Some(&want.to_string()) {
            return;
        }
        assert!(t0.elapsed() < timeout, "{q} never became {want}: {r:?}");
        std::thread::sleep(Duration::from_millis(250));
    }
}

/// The README's fenced blocks of `lang`.
fn readme_blocks(lang: &str) -> Vec<String> {
    crate::common::doc_blocks()
        .into_iter()
        .filter(|b| b.lang == lang)
        .map(|b| b.body)
        .collect()
}

/// A free TCP port on loopback (bound, then released).
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A real Prometheus with the README's scrape config (every second)
/// against a running daemon: the target is up, and its HTTP API answers
/// for the series, the p99 wake-up latency and both of the README's
/// Grafana queries. `promtool check metrics` finds nothing to say about
/// the exposition.
#[test]
fn a_real_prometheus_scrapes_the_daemon_and_answers_the_readme_s_queries() {
    let prometheus = std::env::split_paths(&std::env::var_os("PATH").unwrap_or_default())
        .map(|d| d.join("prometheus"))
        .find(|p| p.is_file())
        .unwrap_or_else(|| {
            panic!(
                "no `prometheus` on PATH: this test runs a real Prometheus (Debian's \
                 `prometheus` package); .ci/run installs it (apt-get install prometheus)"
            )
        });
    let promtool = prometheus.with_file_name("promtool");
    let _g = one_at_a_time();
    let m = Metered::start("127.0.0.1:0");
    let dir = tmp();

    // promtool's lint of the exposition: no complaint.
    let (_, _, body) = http(&m.addr, "GET", "/metrics", None);
    let mut lint = Command::new(&promtool)
        .args(["check", "metrics"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    lint.stdin
        .take()
        .unwrap()
        .write_all(body.as_bytes())
        .unwrap();
    let lint = lint.wait_with_output().unwrap();
    assert!(
        lint.status.success() && lint.stdout.is_empty() && lint.stderr.is_empty(),
        "promtool check metrics: {}{}",
        String::from_utf8_lossy(&lint.stdout),
        String::from_utf8_lossy(&lint.stderr)
    );

    // The README's scrape config, pointed at this daemon.
    let yaml = readme_blocks("yaml")
        .into_iter()
        .find(|b| b.contains("scrape_configs"))
        .expect("the README's Prometheus scrape config");
    assert!(yaml.contains("127.0.0.1:9464"), "{yaml}");
    assert!(yaml.contains("scrape_interval: 1s"), "{yaml}");
    let config = dir.path().join("prometheus.yml");
    std::fs::write(&config, yaml.replace("127.0.0.1:9464", &m.addr)).unwrap();
    let web = format!("127.0.0.1:{}", free_port());
    let log = dir.path().join("prometheus.log");
    let prom = KillOnDrop::new(
        Command::new(&prometheus)
            .arg(format!("--config.file={}", config.display()))
            .arg(format!(
                "--storage.tsdb.path={}",
                dir.path().join("data").display()
            ))
            .arg(format!("--web.listen-address={web}"))
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap(),
    );
    let t0 = Instant::now();
    loop {
        if TcpStream::connect(&web).is_ok() && http(&web, "GET", "/-/ready", None).0 == 200 {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "Prometheus did not come up: {}",
            std::fs::read_to_string(&log).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    wait_for_value(&web, "up{job=\"bench\"}", 1.0, Duration::from_secs(30));

    // Both jobs run past the machine's own stalls: an attempt the VM ended
    // with an overruns fault is reset, run again and counted below.
    let mut c = m.d.client();
    let (r, _, seen_ok) = retry_machine_stalls(&mut c, |c| {
        let params = json!({ "controller": "fast", "duration_s": 1.0 });
        (c.call("control", params), ())
    });
    assert_eq!(r["ok"], true, "{r}");
    let (r, _, seen_drop) = retry_machine_stalls(&mut c, |c| {
        let params = json!({ "controller": "fast", "duration_s": 1.5, "inject_fault": "drop@0.3" });
        (c.call("control", params), ())
    });
    assert_eq!(r["error"]["summary"]["fault"]["kind"], "link", "{r}");
    let machine_stalls = (seen_ok.len() + seen_drop.len()) as f64;
    // Scraped after both jobs (every second).
    let q = "bench_jobs_total{kind=\"control\",outcome=\"fault\"}";
    wait_for_value(&web, q, 1.0 + machine_stalls, Duration::from_secs(30));

    // The target: up, scraped without error.
    let (_, _, targets) = http(&web, "GET", "/api/v1/targets", None);
    let targets: Value = serde_json::from_str(&targets).unwrap();
    let active = &targets["data"]["activeTargets"];
    assert_eq!(active.as_array().unwrap().len(), 1, "{targets}");
    assert_eq!(active[0]["health"], "up", "{targets}");
    assert_eq!(active[0]["lastError"], "", "{targets}");

    assert_eq!(
        promql_value(&web, "bench_jobs_total{kind=\"control\",outcome=\"ok\"}"),
        1.0
    );
    assert_eq!(promql_value(&web, "bench_faults_total{kind=\"link\"}"), 1.0);
    assert_eq!(
        promql_value(
            &web,
            "sum(bench_faults_total) - sum(bench_faults_total{kind=~\"link|overruns\"})"
        ),
        0.0
    );
    assert_eq!(
        promql_value(&web, "bench_faults_total{kind=\"overruns\"}"),
        machine_stalls
    );
    assert_eq!(
        promql_value(&web, "bench_supervisor_state{state=\"faulted\"}"),
        1.0
    );
    let info = promql(&web, "bench_build_info");
    assert_eq!(info.len(), 1, "{info:?}");
    let hash = info[0]["metric"]["config_hash"].as_str().unwrap();
    assert!(hash.len() == 64 && hash.bytes().all(|b| b.is_ascii_hexdigit()));
    assert_eq!(info[0]["metric"]["version"], env!("CARGO_PKG_VERSION"));
    // Ticks at the loop's rate (jobs and hold), over the last 5 s of
    // scrapes.
    // Scraped every second: polled (≤ 30 s) until the 5 s window holds
    // the loop after the jobs (the fault's job and the switch to hold take
    // ticks out of it), in place of a fixed wait.
    let (rate_hz, ..) = config_figures(&m.d.config);
    let t0 = Instant::now();
    loop {
        let r = promql(&web, "sum(rate(bench_loop_ticks_total[5s]))");
        let rate: f64 = r
            .first()
            .and_then(|s| s["value"][1].as_str())
            .and_then(|v| v.parse().ok())
            .unwrap_or(f64::NAN);
        if rate > 0.5 * rate_hz && rate < 1.1 * rate_hz {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "{rate} ticks/s for 30 s, the config says {rate_hz} Hz"
        );
        std::thread::sleep(Duration::from_millis(250));
    }
    let p99 = promql_value(
        &web,
        "histogram_quantile(0.99, rate(bench_loop_wakeup_latency_seconds_bucket[1m]))",
    );
    assert!(p99 > 0.0 && p99 < 0.1, "p99 wake-up latency {p99} s");

    // The README's Grafana queries: each answers, with numbers.
    let queries = readme_blocks("promql");
    assert_eq!(queries.len(), 2, "{queries:?}");
    for q in queries {
        let r = promql(&web, q.trim());
        assert!(!r.is_empty(), "{q}: no result");
        for s in &r {
            let v: f64 = s["value"][1].as_str().unwrap().parse().unwrap();
            assert!(v.is_finite(), "{q}: {s}");
        }
    }
    drop(prom);
}

/// The HTTP surface, on an explicitly named address of every interface
/// (accepted because it is written out): `/metrics` in both formats,
/// `HEAD`, 404 elsewhere, 405 for other methods.
#[test]
fn metrics_only_at_slash_metrics_in_either_text_format() {
    let _g = one_at_a_time();
    let m = Metered::start("0.0.0.0:0");
    assert!(m.url.starts_with("http://0.0.0.0:"), "{}", m.url);
    let e = scrape(&m.addr);
    check_loop_series(&e);
    let (status, headers, body) = http(
        &m.addr,
        "GET",
        "/metrics",
        Some("application/openmetrics-text;version=1.0.0,text/plain;version=0.0.4;q=0.5"),
    );
    assert_eq!(status, 200);
    assert!(
        headers["content-type"].starts_with("application/openmetrics-text; version=1.0.0"),
        "{headers:?}"
    );
    assert!(body.ends_with("# EOF\n"), "{body}");
    assert!(body.contains("# UNIT bench_loop_wakeup_latency_seconds seconds"));
    assert!(body.contains("# TYPE bench_build info"));
    let (status, headers, body) = http(&m.addr, "HEAD", "/metrics", None);
    assert_eq!(status, 200);
    assert!(body.is_empty());
    assert!(headers["content-length"].parse::<usize>().unwrap() > 1000);
    for path in ["/", "/metric", "/metrics/", "/api/v1/query", "/debug"] {
        let (status, _, body) = http(&m.addr, "GET", path, None);
        assert_eq!(status, 404, "{path}: {body}");
    }
    for method in ["POST", "PUT", "DELETE"] {
        let (status, headers, _) = http(&m.addr, method, "/metrics", None);
        assert_eq!(status, 405, "{method}");
        assert_eq!(headers["allow"], "GET, HEAD");
    }
}

/// Scrapers that never finish a request, or never read, hold only their
/// own connections: the daemon answers `status` at once, a job runs its
/// ticks, and every tick is still counted; once they are gone, a scrape
/// answers again. The job runs in real time: a machine stall beyond the
/// loop's bound (seen by [`HostStallWatch`]) ends it on `overruns`,
/// rightly, and that attempt is tried again (at most 3); any other fault
/// fails at once.
#[test]
fn slow_scrapers_never_reach_the_loop_or_the_jobs() {
    let _g = one_at_a_time();
    let mut seen = Vec::new();
    let (m, rate_hz, before, stuck) = loop {
        let m = Metered::start("0");
        let (rate_hz, ..) = config_figures(&m.d.config);
        let before = scrape(&m.addr);
        // Every connection the server takes, each stuck half-way through a
        // header, and more beyond (closed by the server).
        let stuck: Vec<TcpStream> = (0..bench::daemon::metrics::MAX_SCRAPERS + 4)
            .map(|_| {
                let mut s = TcpStream::connect(&m.addr).unwrap();
                s.write_all(b"GET /metrics HTTP/1.1\r\nHost: x\r\n")
                    .unwrap();
                s
            })
            .collect();
        let mut c = m.d.client();
        let t = Instant::now();
        let s = c.call("status", json!({}));
        assert_eq!(s["ok"], true);
        assert!(t.elapsed() < Duration::from_secs(1), "{:?}", t.elapsed());
        let watch = common::HostStallWatch::start(79);
        let r = c.call(
            "control",
            json!({ "controller": "fast", "duration_s": 1.0 }),
        );
        let machine_ms = watch.stop() * 1e3;
        if r["ok"] == true {
            break (m, rate_hz, before, stuck);
        }
        let fault = c.call("status", json!({}))["result"]["fault"].clone();
        assert!(
            fault["kind"] == "overruns" && machine_ms >= 5.0 && seen.len() < 2,
            "the job failed (machine late {machine_ms:.1} ms; retried: {seen:?}): {r}, fault {fault}"
        );
        seen.push(format!("{fault} with the machine late {machine_ms:.1} ms"));
    };
    drop(stuck);
    // The server frees the slots as the stuck connections close.
    let t0 = Instant::now();
    while try_http(&m.addr, "GET", "/metrics", None).map(|r| r.0) != Ok(200) {
        assert!(t0.elapsed() < Duration::from_secs(15), "no scrape answered");
        std::thread::sleep(Duration::from_millis(200));
    }
    let after = scrape(&m.addr);
    check_loop_series(&after);
    assert_eq!(
        job_ticks(&after) - job_ticks(&before),
        (1.0 * rate_hz).round()
    );
}

/// `bench serve --metrics VALUE` with `VALUE` refused: exit 2, the message
/// names `--metrics`, and nothing was started (no socket, no recordings
/// directory).
fn assert_refused(value: &str, why: &str) {
    let dir = tmp();
    let socket = dir.path().join("bench.sock");
    let rec = dir.path().join("rec");
    let t = Instant::now();
    let out = bench()
        .env("RUST_LOG", "warn")
        .args(["serve", "--socket"])
        .arg(&socket)
        .arg("--recordings")
        .arg(&rec)
        .args(["--metrics", value])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{value:?}: {err}");
    assert!(err.contains("--metrics"), "{value:?}: {err}");
    assert!(err.contains(why), "{value:?}: wanted {why:?} in {err}");
    assert!(
        !socket.exists() && !rec.exists(),
        "{value:?}: something was started"
    );
    assert!(t.elapsed() < Duration::from_secs(10));
}

/// Generated bad values: empty, no port, ports out of range or not
/// numbers, host names (loopback or not, never looked up), what is not an
/// address at all.
#[test]
fn bad_metrics_values_are_refused_naming_the_flag() {
    assert_refused("", "empty");
    for host in ["127.0.0.1", "0.0.0.0", "localhost", "[::1]", "::1", "::"] {
        assert_refused(host, "no port");
    }
    for host in ["127.0.0.1", "0.0.0.0", "localhost", "[::1]"] {
        assert_refused(&format!("{host}:"), "no port");
        for port in ["65536", "70000", "99999999999"] {
            assert_refused(&format!("{host}:{port}"), "outside 0 … 65535");
        }
        for port in ["http", "9x", "-1", "+1", "0x10"] {
            assert_refused(&format!("{host}:{port}"), "not a number");
        }
    }
    for port in ["65536", "70000"] {
        assert_refused(port, "outside 0 … 65535");
    }
    for host in [
        "bench.lab",
        "example.org",
        "localhost.localdomain",
        "ip6-localhost",
    ] {
        assert_refused(&format!("{host}:9464"), "host name");
    }
    for garbage in [
        "1.2.3.4.5:9464",
        "256.1.1.1:9464",
        "http://127.0.0.1:9464",
        "a b:1",
    ] {
        assert_refused(garbage, "not an IP address");
    }
    assert_refused(":9464", "no address before the port");
    assert_refused("garbage", "not an address");
}

/// An address in use, or one of no interface of this machine: refused
/// naming `--metrics` and the OS's reason, before the socket or the bench
/// is opened.
#[test]
fn an_address_in_use_stops_the_daemon_before_it_opens_the_bench() {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    assert_refused(&addr, "in use");
    assert_refused(&addr.replace("127.0.0.1", "localhost"), "in use");
    // TEST-NET-1 (RFC 5737): an explicit address, accepted as such, but
    // not this machine's.
    assert_refused("192.0.2.5:9464", "cannot listen there");
}
