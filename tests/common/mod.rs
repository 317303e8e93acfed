//! Shared helpers for the process-boundary tests: run the `bench` binary,
//! read its outputs, load the scipy reference (`tests/data/`).
#![allow(dead_code)]

pub mod docs;
pub mod emulator;
pub mod host_stall;
pub mod loop_reference;
#[path = "../../hal/devices/tests/common/watchdog.rs"]
mod watchdog;
#[allow(unused_imports)] // only the real-time job tests watch the machine
pub use docs::{doc_blocks, doc_pages, docs_text, DocBlock};
pub use host_stall::HostStallWatch;
#[allow(unused_imports)] // not every test file waits for a watchdog
pub use watchdog::{wait_for_watchdog_trip, WatchdogTrip};

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output};

/// The `bench` binary under test.
pub fn bench() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_bench"));
    c.current_dir(env!("CARGO_MANIFEST_DIR"));
    c
}

/// Runs `bench` with `args`, returns the output.
pub fn run(args: &[&str]) -> Output {
    bench().args(args).output().expect("cannot start bench")
}

/// A child process (a daemon, a server) that is killed and reaped when
/// dropped: at the end of its test, and on a failed assertion too, so a
/// test that panics leaves nothing running to load the machine or hold a
/// socket. Dereferences to the [`Child`]; [`Self::into_inner`] takes it
/// back (to wait for its output).
pub struct KillOnDrop(Option<Child>);

impl KillOnDrop {
    pub fn new(child: Child) -> Self {
        Self(Some(child))
    }

    /// The child, no longer killed when dropped.
    pub fn into_inner(mut self) -> Child {
        self.0.take().expect("a child until into_inner")
    }
}

impl std::ops::Deref for KillOnDrop {
    type Target = Child;
    fn deref(&self) -> &Child {
        self.0.as_ref().expect("a child until into_inner")
    }
}

impl std::ops::DerefMut for KillOnDrop {
    fn deref_mut(&mut self) -> &mut Child {
        self.0.as_mut().expect("a child until into_inner")
    }
}

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        if let Some(c) = self.0.as_mut() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// A fresh temporary directory.
pub fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().expect("tempdir")
}

/// `dir/name` as a `String`.
pub fn path_in(dir: &Path, name: &str) -> String {
    dir.join(name).display().to_string()
}

/// Parses the one JSON object `--json` prints.
pub fn json_stdout(out: &Output) -> Value {
    let s = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(s.trim()).unwrap_or_else(|e| {
        panic!(
            "stdout is not one JSON object ({e}):\n{s}\nstderr:\n{}",
            String::from_utf8_lossy(&out.stderr)
        )
    })
}

/// The scipy reference (`tests/data/sr4dof_reference.json`), one case.
pub fn reference(case: &str) -> Value {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/sr4dof_reference.json");
    let all: Value =
        serde_json::from_str(&std::fs::read_to_string(p).expect("reference data")).expect("json");
    all[case].clone()
}

/// `Vec<f64>` from a JSON array.
pub fn floats(v: &Value) -> Vec<f64> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

/// Rows of the FRF CSV: (frequency_hz, magnitude_m_per_a, phase_deg, coherence).
pub fn read_frf_csv(path: &Path) -> Vec<[f64; 4]> {
    read_frf_csv_full(path)
        .into_iter()
        .map(|v| [v[0], v[1], v[2], v[3]])
        .collect()
}

/// Rows of the FRF CSV, every column: (frequency_hz, magnitude_m_per_a,
/// phase_deg, coherence, sigma_m_per_a, resolution_hz, sigma_dof).
pub fn read_frf_csv_full(path: &Path) -> Vec<[f64; 7]> {
    let text = std::fs::read_to_string(path).expect("FRF CSV");
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some(
            "frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz,sigma_dof"
        )
    );
    lines
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().expect("number")).collect();
            assert_eq!(v.len(), 7, "{l}");
            [v[0], v[1], v[2], v[3], v[4], v[5], v[6]]
        })
        .collect()
}

/// Linear interpolation of `y(x)` in log x; `x` ascending.
pub fn interp_log(x: &[f64], y: &[f64], at: f64) -> f64 {
    let i = x.partition_point(|v| *v < at).clamp(1, x.len() - 1);
    let (x0, x1) = (x[i - 1].ln(), x[i].ln());
    let t = (at.ln() - x0) / (x1 - x0);
    y[i - 1] + t * (y[i] - y[i - 1])
}

/// Median of a slice (sorted copy).
pub fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[s.len() / 2]
}

/// Files in `dir` (names).
pub fn files_in(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .expect("read_dir")
        .map(|e| e.expect("entry").path())
        .collect();
    v.sort();
    v
}

/// A faulted run's recording at `path`: its fault event (`case` names the
/// run in messages) and the peak |current command| before the fault's
/// tick, A; asserts 0 A commanded from that tick on.
#[allow(dead_code)]
pub fn fault_and_peak_before(path: &Path, case: &str) -> (Value, f64) {
    let msgs = mcap_messages(path);
    let ev = msgs
        .iter()
        .find(|m| m.0 == "/bench/event" && m.2["kind"] == "fault")
        .unwrap_or_else(|| panic!("{case}: no fault event"))
        .2
        .clone();
    let tick = ev["tick"].as_u64().unwrap();
    let mut peak_a: f64 = 0.0;
    for s in msgs.iter().filter(|m| m.0 == "/bench/sample").map(|m| &m.2) {
        let i = s["current_command_a"].as_f64().unwrap();
        if s["tick"].as_u64().unwrap() < tick {
            peak_a = peak_a.max(i.abs());
        } else {
            assert_eq!(i, 0.0, "{case}: {s}");
        }
    }
    (ev, peak_a)
}

/// All messages of an MCAP file by topic: (topic, log_time, JSON value).
pub fn mcap_messages(path: &Path) -> Vec<(String, u64, Value)> {
    let bytes = std::fs::read(path).expect("recording");
    mcap::MessageStream::new(&bytes)
        .expect("mcap")
        .flat_map(|m| {
            let m = m.expect("message");
            if m.channel.message_encoding == "json" {
                let v: Value = serde_json::from_slice(&m.data).expect("json payload");
                return vec![(m.channel.topic.clone(), m.log_time, v)];
            }
            // Protobuf: the sample blocks as one JSON-shaped sample per
            // tick (as recordings before the blocks held them), the
            // envelope as its fields.
            match m.channel.topic.as_str() {
                "/bench/sample" => bench::record::decode_samples(&m)
                    .expect("a sample block")
                    .into_iter()
                    .map(|(t, s)| {
                        let v = serde_json::to_value(s).unwrap();
                        (m.channel.topic.clone(), t, v)
                    })
                    .collect(),
                "/bench/envelope" => {
                    let e = <bench::record::proto::Envelope as prost::Message>::decode(&m.data[..])
                        .expect("an envelope");
                    let v = serde_json::to_value(e).unwrap();
                    vec![(m.channel.topic.clone(), m.log_time, v)]
                }
                other => panic!("unexpected protobuf channel {other}"),
            }
        })
        .collect()
}

static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Held by a real-time test while it runs ([`one_at_a_time`]).
pub struct RealTimeTurn {
    _file: std::fs::File,
    _guard: std::sync::MutexGuard<'static, ()>,
}

/// Serialises the real-time tests (they would disturb each other on a
/// 2-core machine): those of this test binary (a mutex), and those of the
/// other test binaries that `tests/run` runs at the same time (an
/// exclusive `flock` on `realtime.lock` in cargo's shared temporary
/// directory, released when the returned turn is dropped or the process
/// ends).
pub fn one_at_a_time() -> RealTimeTurn {
    let guard = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let path = Path::new(env!("CARGO_TARGET_TMPDIR")).join("realtime.lock");
    let file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    use std::os::fd::AsRawFd;
    // SAFETY: a plain call on an open descriptor this function owns.
    while unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX) } != 0 {
        let e = std::io::Error::last_os_error();
        assert_eq!(
            e.kind(),
            std::io::ErrorKind::Interrupted,
            "flock {}: {e}",
            path.display()
        );
    }
    RealTimeTurn {
        _file: file,
        _guard: guard,
    }
}

/// `text` (a bench config) with the two optional stall bounds, where it
/// sets them, at their largest, 0.1 s: `max_command_latency_s` and
/// `max_overrun_s`. The shipped configs set neither (the bounds are derived
/// per job from the loop), so this changes only configs that do. Only the
/// tests of those rules tighten them.
pub fn relax_timing_bounds(text: &str) -> String {
    let text = set_key(text, "max_command_latency_s", "0.1");
    set_key(&text, "max_overrun_s", "0.1")
}

/// `text` (a bench config) with the value of every line that sets `key`
/// replaced by `value` (TOML text).
pub fn set_key(text: &str, key: &str, value: &str) -> String {
    let prefix = format!("{key} =");
    text.lines()
        .map(|l| {
            if l.starts_with(&prefix) {
                format!("{key} = {value}")
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// The Chapter 5 bench (`sr4dof-ch5.toml`) without probe noise and
/// disturbance, with a `tail_s` chirp tail and the link latency bound at
/// its largest (0.1 s), plus `extra` TOML appended;
/// written to `dir/bench.toml`. Two runs then see the same plant response
/// and differ only by what is under test.
pub fn quiet_config(dir: &Path, tail_s: f64, extra: &str) -> PathBuf {
    quiet_config_edited(dir, tail_s, extra, |t| t.to_string())
}

/// As [`quiet_config`], the text passed through `edit` before `extra` is
/// appended.
pub fn quiet_config_edited(
    dir: &Path,
    tail_s: f64,
    extra: &str,
    edit: impl FnOnce(&str) -> String,
) -> PathBuf {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"),
    )
    .expect("shipped config");
    let text: String = text
        .lines()
        .filter(|l| !l.starts_with("disturbance ="))
        .map(|l| {
            if l.starts_with("noise_rms_m =") {
                "noise_rms_m = 0.0".to_string()
            } else if l.starts_with("tail_s =") {
                format!("tail_s = {tail_s:?}")
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    let text = edit(&relax_timing_bounds(&text)) + extra;
    let p = dir.join("bench.toml");
    std::fs::write(&p, text).expect("write config");
    p
}

/// The exact sampled response of `zoh` on the chirp's grid (0.1–500 Hz,
/// 400 points per decade) with complex Gaussian noise of relative RMS
/// `noise` per point, and the coherence that noise implies.
pub fn noisy_frf(
    zoh: &bench_plant::sim::ZohPlant,
    noise: f64,
    rng: &mut impl rand::Rng,
) -> bench::ident::modal_fit::FrfData {
    use bench::ident::frf::C64;
    let mut normal = || {
        let u1: f64 = rng.random_range(f64::EPSILON..1.0);
        let u2: f64 = rng.random_range(0.0..1.0);
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    };
    let f = bench::ident::frf::log_grid(0.1, 500.0, 400);
    let h: Vec<C64> = f
        .iter()
        .map(|&f| {
            let e = C64::new(normal(), normal()) * (noise / 2f64.sqrt());
            zoh.frf(f) * (C64::new(1.0, 0.0) + e)
        })
        .collect();
    // Each line's own noise, independent of the others' (resolution 0).
    let sigma = h.iter().map(|h| noise * h.norm()).collect();
    bench::ident::modal_fit::FrfData {
        response: h,
        coherence: vec![1.0 / (1.0 + noise * noise); f.len()],
        sigma_m_per_a: sigma,
        resolution_hz: vec![0.0; f.len()],
        sigma_dof: vec![f64::INFINITY; f.len()],
        frequency_hz: f,
    }
}

/// A small FRF CSV (`bench chirp`'s six columns, 20 lines from 10 to
/// 200 Hz) at `dir/name`: enough for every reader of an FRF to take it, for
/// the tests of what happens before any fit (the input and output checks).
pub fn small_frf_csv(dir: &Path, name: &str) -> PathBuf {
    let mut text = String::from(
        "frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz\n",
    );
    for i in 1..=20 {
        let f = 10.0 * f64::from(i);
        let mag = 1e-5 / (1.0 + (f / 50.0).powi(2));
        text.push_str(&format!(
            "{f},{mag:e},{},0.99,{:e},0.5\n",
            -0.5 * f,
            mag * 1e-3
        ));
    }
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// Runs `bench` with `args` in `cwd`, killed after `limit`: the output,
/// and whether it ended by itself within the limit.
pub fn run_within(args: &[&str], cwd: &Path, limit: std::time::Duration) -> (Output, bool) {
    use std::process::Stdio;
    let mut child = bench()
        .current_dir(cwd)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("cannot start bench");
    let t0 = std::time::Instant::now();
    let ended = loop {
        if child.try_wait().expect("wait").is_some() {
            break true;
        }
        if t0.elapsed() > limit {
            let _ = child.kill();
            break false;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    };
    (child.wait_with_output().expect("output"), ended)
}

/// A real-time `bench` process run by `job` (its exit code and JSON
/// summary), run again, at most three times, when it ended on an
/// `overruns` fault that is not the test's subject (`subject` false on the
/// summary) and that the machine made: the host-stall watch (one SCHED_FIFO
/// thread per CPU, one below the shipped loop's priority 80) saw its own
/// threads late by at least half the stall. A stall the watch did not see
/// fails the test with both figures: then the process stalled its loop.
pub fn past_machine_stalls(
    mut job: impl FnMut() -> (Option<i32>, Value),
    subject: impl Fn(&Value) -> bool,
) -> (Option<i32>, Value) {
    let mut seen = Vec::new();
    for _ in 0..3 {
        let watch = HostStallWatch::start(79);
        let (code, v) = job();
        let machine_s = watch.stop();
        if v["fault"]["kind"] != "overruns" || subject(&v) {
            return (code, v);
        }
        seen.push(machine_made(&v["fault"], machine_s, &v));
    }
    panic!("three runs in a row ended by the machine's own stalls ({seen:?}): this machine cannot hold the loop's delay margin");
}

/// The overruns `fault` (its value is the stall, s) of `what` judged
/// against the host-stall watch's `machine_s`: a panic unless the machine
/// was late by at least half the stall; otherwise both figures, for the
/// message of the retry that gives up.
pub fn machine_made(fault: &Value, machine_s: f64, what: &Value) -> String {
    let stall_s = fault["value"].as_f64().unwrap_or(f64::INFINITY);
    assert!(
        machine_s >= 0.5 * stall_s,
        "the loop stalled {:.1} ms where the machine's own real-time threads were at most {:.1} ms late: the code under test stalled it: {what}",
        stall_s * 1e3,
        machine_s * 1e3
    );
    format!(
        "loop {:.1} ms, machine {:.1} ms",
        stall_s * 1e3,
        machine_s * 1e3
    )
}

/// Whether the summary `v` of a run ended on a fault at a tick (at the
/// run's own `timing.rate_hz`) from `at_s` to the end of a stall of
/// `stall_s` injected there, plus 10 ms for the loop to judge it: the
/// fault is that stall, not one the machine made elsewhere.
pub fn fault_in_injected_stall(v: &Value, at_s: f64, stall_s: f64) -> bool {
    let rate_hz = v["timing"]["rate_hz"].as_f64().unwrap_or(f64::NAN);
    v["fault"]["tick"]
        .as_f64()
        .map(|t| t / rate_hz)
        .is_some_and(|t| t >= at_s && t <= at_s + stall_s + 0.01)
}
