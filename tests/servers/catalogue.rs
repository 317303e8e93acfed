//! The run catalogue (issue 30, part 3), at the process boundary:
//!
//! - every finished chirp and control run appends its row beside its
//!   recording, and each value matches an independent source: the
//!   `--json` summary the run printed, the flags given (seed, operating
//!   point), the clock around the run, the host's name, the SHA-256 of
//!   the config the recording holds (computed here);
//! - `bench catalogue` rebuilds the same rows from the recordings, and
//!   skips (naming them) files that are no finished recording;
//! - the README's DuckDB query and pandas one-liner, run by DuckDB and
//!   pandas from Python (`$BENCH_PYTHON`, else `python3`, as `.ci/run`
//!   installs them), answer over the folder of rows and over the
//!   compacted file;
//! - a catalogue that cannot be written never fails a run;
//! - bad flags of `bench catalogue` exit 2 naming the flag, and write
//!   nothing.

use crate::common;

use bench::catalogue::file::{read_rows, ReadRow};
use bench::catalogue::{Value as Cell, COLUMNS};
use common::{bench, json_stdout, tmp};
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// `bench ARGS` in `dir`, with `./recordings` absent there.
fn bench_in(dir: &Path, args: &[&str]) -> Output {
    bench()
        .current_dir(dir)
        .args(args)
        .output()
        .expect("bench runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// µs since the Unix epoch, now.
fn now_us() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_micros() as i64
}

/// One run of the fixture: its recording, the summary it printed, the
/// flags' values and the clock around it.
struct Run {
    recording: PathBuf,
    summary: Value,
    seed: u64,
    /// The operating point and asymmetry the flags set (m, fraction).
    point: (f64, f64),
    before_us: i64,
    after_us: i64,
    /// The exit status.
    code: i32,
}

/// The shipped Chapter 5 bench's beam length, m (README, *Configuration
/// reference*), and its default operating point and asymmetry.
const L_M: f64 = 0.0475;
const DEFAULT_POINT: (f64, f64) = (0.08 * L_M, 0.10);

struct Fixture {
    dir: tempfile::TempDir,
    runs: BTreeMap<&'static str, Run>,
}

/// The runs every test reads (made once): two chirps at two operating
/// points, a fast and a slow step, a step that faults, and a chirp stopped
/// by SIGINT.
fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let dir = tmp();
        let d = dir.path();
        let mut runs = BTreeMap::new();
        let mut run =
            |name: &'static str, args: &[&str], seed: u64, point: (f64, f64), code: i32| {
                let out = d.join(format!("{name}.mcap"));
                let mut a: Vec<String> = args.iter().map(|s| s.to_string()).collect();
                a.extend([
                    "--seed".into(),
                    seed.to_string(),
                    "--out".into(),
                    out.display().to_string(),
                    "--json".into(),
                ]);
                let a: Vec<&str> = a.iter().map(String::as_str).collect();
                let before_us = now_us();
                let o = bench_in(d, &a);
                let after_us = now_us();
                assert_eq!(o.status.code(), Some(code), "{name}: {}", stderr(&o));
                runs.insert(
                    name,
                    Run {
                        recording: out,
                        summary: json_stdout(&o),
                        seed,
                        point,
                        before_us,
                        after_us,
                        code,
                    },
                );
            };
        let sweep = ["chirp", "--duration-s", "4", "--f-start-hz", "5"];
        run("chirp-8pct", &sweep, 42, DEFAULT_POINT, 0);
        let mut low = sweep.to_vec();
        low.extend(["--operating-point-pct", "2", "--mass-asymmetry", "-0.1"]);
        run("chirp-2pct", &low, 43, (0.02 * L_M, -0.1), 0);
        run(
            "step-fast",
            &["control", "--fast", "--duration-s", "2"],
            7,
            DEFAULT_POINT,
            0,
        );
        run(
            "step-slow",
            &["control", "--slow", "--duration-s", "2"],
            8,
            DEFAULT_POINT,
            0,
        );
        run(
            "step-fault",
            &[
                "control",
                "--fast",
                "--duration-s",
                "2",
                "--inject-fault",
                "jump@1.0",
            ],
            9,
            DEFAULT_POINT,
            3,
        );
        // A chirp paced at real time, stopped by SIGINT once it runs.
        let out = d.join("chirp-stopped.mcap");
        let before_us = now_us();
        let child = bench()
            .current_dir(d)
            .args([
                "chirp",
                "--pace",
                "1",
                "--duration-s",
                "20",
                "--seed",
                "44",
                "--json",
                "--out",
            ])
            .arg(&out)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let part = d.join("chirp-stopped.mcap.part");
        wait_until_started(&part);
        std::thread::sleep(Duration::from_millis(1500));
        // SAFETY: a plain signal to the child we started.
        unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
        let o = child.wait_with_output().unwrap();
        assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
        runs.insert(
            "chirp-stopped",
            Run {
                recording: out,
                summary: json_stdout(&o),
                seed: 44,
                point: DEFAULT_POINT,
                before_us,
                after_us: now_us(),
                code: 130,
            },
        );
        Fixture { dir, runs }
    })
}

/// The per-run rows of `dir/catalogue/`, by recording.
fn rows_in_folder(dir: &Path) -> BTreeMap<String, ReadRow> {
    let mut out = BTreeMap::new();
    for e in std::fs::read_dir(dir.join("catalogue")).unwrap() {
        let p = e.unwrap().path();
        let rows = read_rows(&p).unwrap();
        assert_eq!(rows.len(), 1, "{}: one row per run file", p.display());
        let row = rows.into_iter().next().unwrap();
        out.insert(text(&row, "recording").unwrap(), row);
    }
    out
}

fn text(row: &ReadRow, col: &str) -> Option<String> {
    match &row[col] {
        Cell::Text(t) => t.clone(),
        other => panic!("{col}: {other:?} is not text"),
    }
}
fn real(row: &ReadRow, col: &str) -> Option<f64> {
    match &row[col] {
        Cell::Real(x) => *x,
        other => panic!("{col}: {other:?} is not a real"),
    }
}
fn flag(row: &ReadRow, col: &str) -> Option<bool> {
    match &row[col] {
        Cell::Flag(x) => *x,
        other => panic!("{col}: {other:?} is not a flag"),
    }
}

/// `a` and `b` equal to 1e-12 relative (JSON and Parquet both keep the
/// double; the tolerance only spares a last-digit print).
fn close(a: Option<f64>, b: Option<f64>, what: &str) {
    match (a, b) {
        (Some(a), Some(b)) => assert!(
            (a - b).abs() <= 1e-12 * a.abs().max(b.abs()),
            "{what}: {a} != {b}"
        ),
        (a, b) => assert_eq!(a, b, "{what}"),
    }
}

fn json_f64(v: &Value) -> Option<f64> {
    v.as_f64()
}

/// The host's name, as the kernel reports it.
fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .unwrap()
        .trim()
        .to_string()
}

/// SHA-256 (hex) of the resolved config a recording holds (`bench.config`
/// `toml`), computed here.
fn recorded_config_sha256(recording: &Path) -> String {
    use sha2::Digest;
    let bytes = std::fs::read(recording).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let index = summary
        .metadata_indexes
        .iter()
        .find(|m| m.name == "bench.config")
        .unwrap();
    let m = mcap::read::metadata(&bytes, index).unwrap();
    let digest = sha2::Sha256::digest(m.metadata["toml"].as_bytes());
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

/// Every run appended one row, in `catalogue/` beside its recording, and
/// each value is the one an independent source gives.
#[test]
fn every_run_appends_a_row_that_matches_its_summary_and_its_flags() {
    let f = fixture();
    let rows = rows_in_folder(f.dir.path());
    assert_eq!(rows.len(), f.runs.len(), "{:?}", rows.keys());
    for (name, run) in &f.runs {
        let abs = std::path::absolute(&run.recording).unwrap();
        let row = rows
            .get(&abs.display().to_string())
            .unwrap_or_else(|| panic!("{name}: no row for {}", abs.display()));
        let s = &run.summary;
        // The row file the summary names (a successful run's summary, and
        // the `--json` of one that ended on a fault or was stopped).
        {
            let want = f
                .dir
                .path()
                .join("catalogue")
                .join(format!("{name}.parquet"));
            assert_eq!(
                s["catalogue"],
                json!({ "row": want.display().to_string() }),
                "{name}"
            );
        }
        // When, where, what.
        let Cell::TimestampUtc(Some(start)) = row["start_utc"] else {
            panic!("{name}: no start_utc")
        };
        assert!(
            (run.before_us..=run.after_us).contains(&start),
            "{name}: start {start} outside the run [{}, {}]",
            run.before_us,
            run.after_us
        );
        assert_eq!(text(row, "host"), Some(hostname()), "{name}");
        assert_eq!(
            text(row, "bench_name").as_deref(),
            Some("sr4dof-ch5"),
            "{name}"
        );
        assert_eq!(
            text(row, "config_sha256"),
            Some(recorded_config_sha256(&run.recording)),
            "{name}"
        );
        assert_eq!(
            text(row, "bench_version").as_deref(),
            Some(env!("CARGO_PKG_VERSION"))
        );
        let kind = if name.starts_with("chirp") {
            "chirp"
        } else {
            "control"
        };
        assert_eq!(text(row, "job_kind").as_deref(), Some(kind), "{name}");
        assert_eq!(
            text(row, "backend").as_deref(),
            Some("sim:sr4dof"),
            "{name}"
        );
        assert_eq!(row["seed"], Cell::Unsigned(Some(run.seed)), "{name}");
        close(real(row, "operating_point_m"), Some(run.point.0), name);
        close(real(row, "mass_asymmetry"), Some(run.point.1), name);
        close(
            real(row, "operating_point_fraction_of_l"),
            Some(run.point.0 / L_M),
            name,
        );
        // How it ended, and how long its loop ran.
        let (outcome, fault) = match run.code {
            0 => ("ok", None),
            3 => ("fault", s["fault"]["kind"].as_str().map(str::to_string)),
            130 => ("stopped", None),
            c => panic!("{name}: exit {c}"),
        };
        assert_eq!(text(row, "outcome").as_deref(), Some(outcome), "{name}");
        assert_eq!(text(row, "fault_kind"), fault, "{name}");
        if let Some(t) = s.get("timing").filter(|t| !t.is_null()) {
            let loop_s = t["ticks"].as_f64().unwrap() / t["rate_hz"].as_f64().unwrap();
            close(real(row, "duration_s"), Some(loop_s), name);
        } else if run.code == 130 {
            // Stopped: the tick the summary names, plus the one after it.
            let d = real(row, "duration_s").unwrap();
            let tick = s["tick"].as_f64().unwrap();
            assert!(
                (d * 5000.0 - (tick + 1.0)).abs() < 1.5,
                "{name}: {d} s, tick {tick}"
            );
        }
        if kind == "chirp" {
            chirp_columns(name, row, s);
        } else {
            control_columns(name, row, s);
        }
    }
}

fn chirp_columns(name: &str, row: &ReadRow, s: &Value) {
    for c in ["controller", "step_m", "phase_margin_deg", "rise_time_s"] {
        assert!(row[c].is_null(), "{name}: {c} on a chirp");
    }
    if s.get("fit").is_none() {
        // Stopped: no results.
        assert_eq!(row["fit_modes"], Cell::Count(None), "{name}");
        assert!(real(row, "mode1_frequency_hz").is_none());
        return;
    }
    let modes = s["fit"]["modes"].as_array().unwrap();
    assert_eq!(
        row["fit_modes"],
        Cell::Count(Some(modes.len() as i64)),
        "{name}"
    );
    assert!(
        !modes.is_empty(),
        "{name}: a 4 s chirp from 5 Hz finds modes"
    );
    let mut freqs: Vec<(f64, f64)> = modes
        .iter()
        .map(|m| {
            (
                m["frequency_hz"].as_f64().unwrap(),
                m["damping_ratio"].as_f64().unwrap(),
            )
        })
        .collect();
    freqs.sort_by(|a, b| a.0.total_cmp(&b.0));
    for i in 0..4 {
        close(
            real(row, &format!("mode{}_frequency_hz", i + 1)),
            freqs.get(i).map(|f| f.0),
            name,
        );
        close(
            real(row, &format!("mode{}_damping_ratio", i + 1)),
            freqs.get(i).map(|f| f.1),
            name,
        );
    }
    for (label, col) in [("u", "pair_u_frequency_hz"), ("v", "pair_v_frequency_hz")] {
        let want = modes
            .iter()
            .find(|m| m["label"] == label)
            .and_then(|m| json_f64(&m["frequency_hz"]));
        close(real(row, col), want, name);
    }
    assert_eq!(
        flag(row, "verdict_cmp_cnmp"),
        s["cmp_cnmp"].as_bool(),
        "{name}"
    );
    assert_eq!(
        flag(row, "model_cmp_cnmp"),
        s["model"]["cmp_cnmp"].as_bool(),
        "{name}"
    );
    let q = &s["fit"]["quality"];
    let trusted = q["checked"] == true && q["flags"].as_array().unwrap().is_empty();
    assert_eq!(flag(row, "fit_trusted"), Some(trusted), "{name}");
    close(
        real(row, "peak_position_m"),
        json_f64(&s["peak_position_m"]),
        name,
    );
}

fn control_columns(name: &str, row: &ReadRow, s: &Value) {
    for c in ["fit_modes", "mode1_frequency_hz", "verdict_cmp_cnmp"] {
        assert!(row[c].is_null(), "{name}: {c} on a step");
    }
    let controller = if name.contains("slow") {
        "slow"
    } else {
        "fast"
    };
    assert_eq!(
        text(row, "controller").as_deref(),
        Some(controller),
        "{name}"
    );
    // The fault's summary has no loop check: its margins are the ones the
    // fast step's summary reports (same controller, same bench).
    let check = match s.get("loop_check") {
        Some(c) => c.clone(),
        None => fixture().runs["step-fast"].summary["loop_check"].clone(),
    };
    let m = &check["model"];
    assert_eq!(flag(row, "loop_check_passed"), Some(true), "{name}");
    close(
        real(row, "crossover_rad_s"),
        json_f64(&m["crossovers_rad_s"][0]),
        name,
    );
    close(
        real(row, "phase_margin_deg"),
        json_f64(&m["phase_margin_deg"]),
        name,
    );
    close(
        real(row, "gain_margin_db"),
        json_f64(&m["gain_margin_db"]),
        name,
    );
    close(
        real(row, "modulus_margin"),
        json_f64(&m["sensitivity_peak"]).map(|s| 1.0 / s),
        name,
    );
    let Some(metrics) = s.get("metrics") else {
        for c in ["step_m", "rise_time_s", "settling_time_s", "peak_command_a"] {
            assert!(row[c].is_null(), "{name}: {c} without a step's end");
        }
        return;
    };
    close(real(row, "step_m"), json_f64(&metrics["step_m"]), name);
    close(
        real(row, "rise_time_s"),
        json_f64(&metrics["rise_time_s"]),
        name,
    );
    close(
        real(row, "settling_time_s"),
        json_f64(&metrics["settling_time_s"]),
        name,
    );
    close(
        real(row, "overshoot_pct"),
        json_f64(&metrics["overshoot_pct"]),
        name,
    );
    close(
        real(row, "steady_state_error_std_m"),
        json_f64(&metrics["steady_state_error_std_nm"]).map(|nm| nm * 1e-9),
        name,
    );
    close(
        real(row, "peak_command_a"),
        json_f64(&metrics["peak_command_a"]),
        name,
    );
    assert_eq!(flag(row, "verify_flagged"), None, "{name}: no --verify");
}

/// `bench catalogue` gives the rows the runs appended, sorted by start
/// time; files that are no finished recording are skipped, each named
/// with its reason, and counted; `.part` files and subdirectories are not
/// read; an existing catalogue needs `--overwrite`.
#[test]
fn the_rebuild_gives_the_same_rows_and_skips_what_is_no_recording() {
    let f = fixture();
    // A copy of the recordings, with what is not one beside them.
    let dir = tmp();
    let d = dir.path();
    for run in f.runs.values() {
        std::fs::copy(&run.recording, d.join(run.recording.file_name().unwrap())).unwrap();
    }
    let good = &f.runs["chirp-8pct"].recording;
    let bytes = std::fs::read(good).unwrap();
    std::fs::write(d.join("cut.mcap"), &bytes[..bytes.len() / 2]).unwrap();
    let mut flipped = bytes.clone();
    let n = flipped.len();
    // The summary section's bytes near the end: a damaged index.
    for b in &mut flipped[n - 300..n - 60] {
        *b ^= 0x5a;
    }
    std::fs::write(d.join("damaged.mcap"), &flipped).unwrap();
    std::fs::write(d.join("notes.mcap"), "not a recording\n").unwrap();
    std::fs::write(d.join("running.mcap.part"), &bytes[..1000]).unwrap();
    std::fs::create_dir(d.join("old.mcap")).unwrap();

    let o = bench_in(d, &["catalogue", "--recordings", ".", "--json"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let s = json_stdout(&o);
    let err = stderr(&o);
    let skipped: Vec<&str> = s["skipped"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| k["recording"].as_str().unwrap())
        .collect();
    let abs = |name: &str| {
        std::path::absolute(d.join(name))
            .unwrap()
            .display()
            .to_string()
    };
    assert_eq!(
        skipped,
        [abs("cut.mcap"), abs("damaged.mcap"), abs("notes.mcap")],
        "{s}"
    );
    for name in ["cut.mcap", "damaged.mcap", "notes.mcap"] {
        assert!(err.contains(name), "stderr names {name}: {err}");
    }
    assert!(!err.contains("running.mcap.part"), "{err}");
    assert_eq!(s["rows"], f.runs.len(), "{s}");
    assert_eq!(
        s["outcomes"],
        json!({"ok": 4, "fault": 1, "stopped": 1}),
        "{s}"
    );
    let out = d.join("catalogue.parquet");
    assert_eq!(s["catalogue"], abs("catalogue.parquet"));
    let rebuilt = read_rows(&out).unwrap();
    // Sorted by start time.
    let starts: Vec<&Cell> = rebuilt.iter().map(|r| &r["start_utc"]).collect();
    let mut sorted = starts.clone();
    sorted.sort_by_key(|c| match c {
        Cell::TimestampUtc(t) => *t,
        _ => None,
    });
    assert_eq!(starts, sorted);
    // The same rows as the runs appended, but for the recording's place.
    let appended = rows_in_folder(f.dir.path());
    assert_eq!(rebuilt.len(), appended.len());
    for row in &rebuilt {
        let rec = text(row, "recording").unwrap();
        let name = Path::new(&rec).file_name().unwrap().to_str().unwrap();
        let original = f.dir.path().join(name);
        let mut want = appended[&std::path::absolute(&original)
            .unwrap()
            .display()
            .to_string()]
            .clone();
        want.insert("recording".into(), Cell::Text(Some(rec.clone())));
        assert_eq!(row, &want, "{name}");
        assert_eq!(row.len(), COLUMNS.len());
    }
    // Again: refused without --overwrite, naming --out; replaced with it.
    let o = bench_in(d, &["catalogue", "--recordings", "."]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("--out") && stderr(&o).contains("--overwrite"),
        "{}",
        stderr(&o)
    );
    let o = bench_in(d, &["catalogue", "--recordings", ".", "--overwrite"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let out_text = String::from_utf8_lossy(&o.stdout);
    assert!(
        out_text.contains("6 runs (1 fault, 4 ok, 1 stopped)"),
        "{out_text}"
    );
    assert_eq!(read_rows(&out).unwrap(), rebuilt);
    // Recordings kept in a bucket: the rows name their objects.
    let o = bench_in(
        d,
        &[
            "catalogue",
            "--recordings",
            ".",
            "--out",
            "urls.parquet",
            "--recording-url",
            "s3://lab-bench/recordings/",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let urls = read_rows(&d.join("urls.parquet")).unwrap();
    assert_eq!(urls.len(), rebuilt.len());
    for (u, r) in urls.iter().zip(&rebuilt) {
        let local = text(r, "recording").unwrap();
        let name = Path::new(&local).file_name().unwrap().to_str().unwrap();
        assert_eq!(
            text(u, "recording"),
            Some(format!("s3://lab-bench/recordings/{name}"))
        );
        let mut u = u.clone();
        u.insert("recording".into(), r["recording"].clone());
        assert_eq!(&u, r);
    }
}

/// The interpreter of the Python checks: `$BENCH_PYTHON`, else `python3`.
fn python() -> String {
    std::env::var("BENCH_PYTHON")
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "python3".to_string())
}

const PY_HINT: &str = "the catalogue's DuckDB and pandas checks need python3 with duckdb, pandas and pyarrow: `pip install duckdb pandas pyarrow` (in a venv where pip refuses with externally-managed-environment, then set BENCH_PYTHON=<venv>/bin/python), or run .ci/run, which installs them";

/// Runs `script` (which prints one JSON value) with the Python of
/// [`python`]; a missing module is a failure naming `.ci/run`.
fn run_python(script: &str) -> Value {
    let o = Command::new(python())
        .args(["-c", script])
        .output()
        .unwrap_or_else(|e| panic!("cannot run {}: {e}; {PY_HINT}", python()));
    let err = stderr(&o);
    assert!(!err.contains("ModuleNotFoundError"), "{err}\n{PY_HINT}");
    assert!(
        o.status.success(),
        "python failed:\n{err}\nscript:\n{script}"
    );
    serde_json::from_slice(&o.stdout)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&o.stdout)))
}

/// The code block (```LANG) after the README's marker
/// `<!-- catalogue example: NAME -->`.
fn readme_block(name: &str) -> String {
    let marker = format!("catalogue example: {name}");
    let b = crate::common::doc_blocks()
        .into_iter()
        .find(|b| b.marker.as_deref() == Some(marker.as_str()))
        .unwrap_or_else(|| panic!("the docs have no block marked <!-- {marker} -->"));
    b.body.trim_end_matches('\n').to_string()
}

/// The README's DuckDB query, run by DuckDB over the folder of per-run
/// rows and over the compacted catalogue, gives the chirps it asks for
/// (done, operating point 3 to 5 mm, started in the last 30 days), with
/// the closely spaced pair their summaries report; the pandas one-liner
/// gives the control runs.
#[test]
fn the_readme_duckdb_query_and_pandas_one_liner_answer_over_the_catalogue() {
    let f = fixture();
    let d = f.dir.path();
    let o = bench_in(
        d,
        &[
            "catalogue",
            "--recordings",
            ".",
            "--out",
            "compacted.parquet",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));

    let query = readme_block("duckdb");
    assert!(
        query.contains("'recordings/catalogue/*.parquet'"),
        "{query}"
    );
    let folder = query.replace(
        "recordings/catalogue/*.parquet",
        &format!("{}/catalogue/*.parquet", d.display()),
    );
    let compacted = query.replace(
        "recordings/catalogue/*.parquet",
        &d.join("compacted.parquet").display().to_string(),
    );
    let script = format!(
        r#"
import json, duckdb
def run(q):
    rel = duckdb.sql(q)
    return [dict(zip(rel.columns, [str(v) if v is not None and not isinstance(v, (int, float, bool)) else v for v in r])) for r in rel.fetchall()]
print(json.dumps({{"folder": run({folder:?}), "compacted": run({compacted:?})}}))
"#
    );
    let v = run_python(&script);
    // What the query asks, from the runs' own summaries and flags.
    let mut want: Vec<(&str, &Run)> = f
        .runs
        .iter()
        .filter(|(n, r)| {
            n.starts_with("chirp") && r.code == 0 && (0.003..=0.005).contains(&r.point.0)
        })
        .map(|(n, r)| (*n, r))
        .collect();
    want.sort_by_key(|(_, r)| r.before_us);
    assert_eq!(want.len(), 1, "the fixture has one chirp at 8 % of L");
    for key in ["folder", "compacted"] {
        let rows = v[key].as_array().unwrap();
        assert_eq!(rows.len(), want.len(), "{key}: {v}");
        for (row, (name, run)) in rows.iter().zip(&want) {
            let rec = std::path::absolute(&run.recording).unwrap();
            assert_eq!(row["recording"], rec.display().to_string(), "{key} {name}");
            let modes = run.summary["fit"]["modes"].as_array().unwrap();
            for (label, col) in [("u", "pair_u_frequency_hz"), ("v", "pair_v_frequency_hz")] {
                let want = modes
                    .iter()
                    .find(|m| m["label"] == label)
                    .map(|m| m["frequency_hz"].clone())
                    .unwrap_or(Value::Null);
                assert_eq!(row[col], want, "{key} {name} {col}");
            }
            assert_eq!(
                row["verdict_cmp_cnmp"], run.summary["cmp_cnmp"],
                "{key} {name}"
            );
        }
    }

    let pandas = readme_block("pandas").replace(
        "\"recordings/catalogue\"",
        &format!("{:?}", d.join("catalogue").display().to_string()),
    );
    let script = format!(
        "{pandas}\nimport json\nprint(json.dumps({{'recording': sorted(runs['recording']), 'controller': sorted(runs['controller']), 'columns': list(runs.columns)}}))\n"
    );
    let v = run_python(&script);
    let mut controls: Vec<String> = f
        .runs
        .iter()
        .filter(|(n, _)| n.starts_with("step"))
        .map(|(_, r)| {
            std::path::absolute(&r.recording)
                .unwrap()
                .display()
                .to_string()
        })
        .collect();
    controls.sort();
    assert_eq!(v["recording"], json!(controls), "{v}");
    assert_eq!(v["controller"], json!(["fast", "fast", "slow"]), "{v}");
    let names: Vec<&str> = COLUMNS.iter().map(|c| c.name).collect();
    assert_eq!(v["columns"], json!(names), "{v}");
}

/// The README's column table lists every column, in order, with its type.
#[test]
fn the_readme_documents_every_column() {
    let readme = crate::common::docs_text();
    let at = readme
        .find("<!-- catalogue columns -->")
        .expect("the README's column table");
    let table: Vec<(String, String)> = readme[at..]
        .lines()
        .skip(1)
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .skip(2)
        .map(|l| {
            let cells: Vec<&str> = l.split('|').map(str::trim).collect();
            (cells[1].trim_matches('`').to_string(), cells[2].to_string())
        })
        .collect();
    let want: Vec<(String, String)> = COLUMNS
        .iter()
        .map(|c| (c.name.to_string(), c.column_type.name().to_string()))
        .collect();
    assert_eq!(table, want);
}

/// A catalogue that cannot be written (its directory's name taken by a
/// file) is a warning: the run exits 0 with its recording and says why in
/// its summary and on stderr; the rebuild still catalogues the run.
#[test]
fn a_catalogue_that_cannot_be_written_never_fails_the_run() {
    let dir = tmp();
    let d = dir.path();
    std::fs::write(d.join("catalogue"), "in the way\n").unwrap();
    let o = bench_in(
        d,
        &[
            "control",
            "--fast",
            "--duration-s",
            "1",
            "--out",
            "run.mcap",
            "--json",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let s = json_stdout(&o);
    assert!(s["metrics"].is_object(), "{s}");
    assert_eq!(s["catalogue"]["row"], Value::Null, "{s}");
    let w = s["catalogue"]["warning"].as_str().unwrap();
    assert!(w.contains("catalogue"), "{w}");
    assert!(
        stderr(&o).contains("catalogue row was not written"),
        "{}",
        stderr(&o)
    );
    assert!(d.join("run.mcap").is_file());
    // The human summary says it too.
    let o = bench_in(
        d,
        &[
            "control",
            "--fast",
            "--duration-s",
            "1",
            "--out",
            "run2.mcap",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("catalogue   not written:"));
    let o = bench_in(d, &["catalogue", "--recordings", ".", "--json"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert_eq!(json_stdout(&o)["rows"], 2);
}

/// Bad flags of `bench catalogue`, generated: every one exits 2, names its
/// flag and the reason, and leaves no file behind.
#[test]
fn bad_catalogue_flags_exit_2_naming_the_flag_and_write_nothing() {
    let f = fixture();
    let dir = tmp();
    let d = dir.path();
    let recs = f.dir.path().display().to_string();
    std::fs::write(d.join("exists.parquet"), "old\n").unwrap();
    std::fs::write(d.join("plain-file"), "x\n").unwrap();
    std::fs::create_dir(d.join("sub.parquet")).unwrap();
    std::os::unix::fs::symlink(d.join("exists.parquet"), d.join("link.parquet")).unwrap();
    let before = common::files_in(d);
    let p = |name: &str| d.join(name).display().to_string();
    // (args, the flag named, a word of the reason)
    let mut cases: Vec<(Vec<String>, &str, &str)> = Vec::new();
    for (dir_value, reason) in [
        (p("missing"), "does not exist"),
        (p("plain-file"), "not a directory"),
        (p("missing/deeper"), "does not exist"),
        // The parser refuses an empty value.
        (String::new(), "value"),
    ] {
        cases.push((
            vec![
                "--recordings".into(),
                dir_value,
                "--out".into(),
                p("new.parquet"),
            ],
            "--recordings",
            reason,
        ));
    }
    for (out, extra, reason) in [
        (p("exists.parquet"), None, "--overwrite"),
        (p("sub.parquet"), Some("--overwrite"), "directory"),
        (p("link.parquet"), Some("--overwrite"), "symbolic link"),
        (p("new.csv"), None, ".parquet"),
        (p("new"), None, ".parquet"),
        (p("missing/new.parquet"), None, "directory"),
        (format!("{}/", p("new.parquet")), None, "not a file path"),
        ("/dev/null".into(), Some("--overwrite"), "parquet"),
        (String::new(), None, "value"),
    ] {
        let mut a = vec!["--recordings".into(), recs.clone(), "--out".into(), out];
        a.extend(extra.map(String::from));
        cases.push((a, "--out", reason));
    }
    for url in [
        "lab-bench/recordings",
        "s3://",
        "3s://b",
        "s3://a b",
        "://b",
    ] {
        cases.push((
            vec![
                "--recordings".into(),
                recs.clone(),
                "--out".into(),
                p("new.parquet"),
                "--recording-url".into(),
                url.into(),
            ],
            "--recording-url",
            "URL",
        ));
    }
    // The parser's own refusals name the flag too.
    cases.push((vec!["--recordings".into()], "--recordings", "value"));
    cases.push((vec!["--out".into()], "--out", "value"));
    cases.push((
        vec!["--recording".into(), recs.clone()],
        "--recording",
        "unexpected",
    ));
    for (args, flag, reason) in &cases {
        let mut a = vec!["catalogue".to_string()];
        a.extend(args.iter().cloned());
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        let o = bench_in(d, &a);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{a:?}: {err}");
        assert!(err.contains(flag), "{a:?}: names {flag}: {err}");
        assert!(err.contains(reason), "{a:?}: says {reason:?}: {err}");
        assert_eq!(common::files_in(d), before, "{a:?} left a file");
        assert_eq!(
            std::fs::read_to_string(d.join("exists.parquet")).unwrap(),
            "old\n"
        );
    }
    // A relative --recordings that does not exist is named as given.
    let o = bench_in(d, &["catalogue", "--recordings", "nowhere"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("--recordings nowhere: does not exist"),
        "{}",
        stderr(&o)
    );
}

use crate::daemon_fixtures;

/// The daemon's chirp and control jobs append their rows in its
/// recordings directory (each matching the job's result), and its
/// `catalogue` job (`bench catalogue --daemon`) gives the rows a local
/// `bench catalogue` gives over the same directory; its parameters are
/// checked as the flags are.
#[test]
fn the_daemons_jobs_append_rows_and_its_catalogue_job_is_the_local_one() {
    let d = daemon_fixtures::Daemon::start();
    let mut c = d.client();
    let step = c.call(
        "control",
        json!({"controller": "fast", "duration_s": 1, "seed": 5, "pace": "off"}),
    );
    assert_eq!(step["ok"], true, "{step}");
    let chirp = c.call(
        "chirp",
        json!({"duration_s": 2, "f_start_hz": 5, "seed": 6, "pace": "off"}),
    );
    assert_eq!(chirp["ok"], true, "{chirp}");
    let recordings = d.dir.path().join("rec");
    for (job, seed) in [(&step["result"], 5), (&chirp["result"], 6)] {
        let rec = PathBuf::from(job["recording"].as_str().unwrap());
        assert_eq!(rec.parent().unwrap(), recordings);
        let row_file = PathBuf::from(job["catalogue"]["row"].as_str().unwrap());
        assert_eq!(row_file, bench::catalogue::row_path(&rec));
        let rows = read_rows(&row_file).unwrap();
        assert_eq!(rows.len(), 1);
        let row = &rows[0];
        assert_eq!(text(row, "recording"), Some(rec.display().to_string()));
        assert_eq!(text(row, "outcome").as_deref(), Some("ok"));
        assert_eq!(row["seed"], Cell::Unsigned(Some(seed)));
        let t = &job["timing"];
        close(
            real(row, "duration_s"),
            Some(t["ticks"].as_f64().unwrap() / t["rate_hz"].as_f64().unwrap()),
            "daemon job",
        );
    }
    close(
        real(
            &read_rows(&bench::catalogue::row_path(Path::new(
                step["result"]["recording"].as_str().unwrap(),
            )))
            .unwrap()[0],
            "phase_margin_deg",
        ),
        step["result"]["loop_check"]["model"]["phase_margin_deg"].as_f64(),
        "daemon step",
    );

    // The daemon's catalogue job, through the CLI, against a local one.
    let here = tmp();
    let o = bench_in(here.path(), &["catalogue", "--daemon", &d.sock(), "--json"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let remote = json_stdout(&o);
    let remote_file = PathBuf::from(remote["catalogue"].as_str().unwrap());
    assert_eq!(remote_file.parent().unwrap(), recordings);
    let name = remote_file.file_name().unwrap().to_str().unwrap();
    assert!(
        name.starts_with("catalogue-") && name.ends_with("-job3.parquet"),
        "{name}"
    );
    let local_file = here.path().join("local.parquet");
    let o = bench_in(
        here.path(),
        &[
            "catalogue",
            "--recordings",
            recordings.to_str().unwrap(),
            "--out",
            local_file.to_str().unwrap(),
            "--json",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let local = json_stdout(&o);
    assert_eq!(remote["rows"], 2);
    for key in ["rows", "outcomes", "skipped", "recordings"] {
        assert_eq!(remote[key], local[key], "{key}");
    }
    assert_eq!(
        read_rows(&remote_file).unwrap(),
        read_rows(&local_file).unwrap()
    );

    // Its parameters, checked as the flags are.
    let r = c.call("catalogue", json!({"recordings": "rec"}));
    assert_eq!(r["error"]["kind"], "bad_params", "{r}");
    assert!(
        r["error"]["message"]
            .as_str()
            .unwrap()
            .starts_with("params.recordings"),
        "{r}"
    );
    let missing = d.dir.path().join("missing");
    let r = c.call("catalogue", json!({"recordings": missing}));
    assert_eq!(r["error"]["kind"], "bad_params", "{r}");
    let m = r["error"]["message"].as_str().unwrap();
    assert!(
        m.starts_with("params.recordings") && m.contains("does not exist"),
        "{r}"
    );
    let r = c.call(
        "catalogue",
        json!({"recording_url": "lab-bench/recordings"}),
    );
    assert_eq!(r["error"]["kind"], "bad_params", "{r}");
    let m = r["error"]["message"].as_str().unwrap();
    assert!(
        m.starts_with("params.recording_url") && m.contains("URL"),
        "{r}"
    );
    let r = c.call("catalogue", json!({"out": "x.parquet"}));
    assert_eq!(r["error"]["kind"], "bad_params", "{r}");
    assert!(
        r["error"]["message"].as_str().unwrap().contains("out"),
        "{r}"
    );
    for flag in ["--out", "--overwrite"] {
        let mut args = vec!["catalogue", "--daemon", d.socket.to_str().unwrap(), flag];
        if flag == "--out" {
            args.push("x.parquet");
        }
        let o = bench_in(here.path(), &args);
        assert_eq!(o.status.code(), Some(2), "{flag}: {}", stderr(&o));
        assert!(stderr(&o).contains(flag), "{}", stderr(&o));
    }

    // A daemon job that ends on a fault: the client's --json is the local
    // run's (outcome, fault, recording), with the row the daemon wrote.
    let o = bench_in(
        here.path(),
        &[
            "control",
            "--daemon",
            &d.sock(),
            "--fast",
            "--duration-s",
            "2",
            "--inject-fault",
            "jump@1.0",
            "--pace",
            "off",
            "--json",
        ],
    );
    assert_eq!(o.status.code(), Some(3), "{}", stderr(&o));
    let s = json_stdout(&o);
    assert_eq!(s["outcome"], "fault", "{s}");
    assert!(s["fault"]["kind"].is_string(), "{s}");
    let rec = PathBuf::from(s["recording"].as_str().unwrap());
    assert_eq!(rec.parent().unwrap(), recordings, "{s}");
    let row_file = PathBuf::from(s["catalogue"]["row"].as_str().unwrap());
    assert_eq!(row_file, bench::catalogue::row_path(&rec), "{s}");
    let rows = read_rows(&row_file).unwrap();
    assert_eq!(rows.len(), 1);
    assert_eq!(text(&rows[0], "outcome").as_deref(), Some("fault"));
    assert_eq!(
        text(&rows[0], "fault_kind"),
        s["fault"]["kind"].as_str().map(str::to_string)
    );
    assert_eq!(text(&rows[0], "recording"), Some(rec.display().to_string()));
}

/// A killed run appends no row (its recording never finished); once
/// `bench recover` has made its `.part` a recording, the rebuild gives it
/// an `error` row with no duration (its loop never stopped), and the
/// start, seed and operating point it recorded.
#[test]
fn a_killed_runs_recovered_recording_is_an_error_row_without_a_duration() {
    let dir = tmp();
    let d = dir.path();
    let before_us = now_us();
    let mut child = bench()
        .current_dir(d)
        .args([
            "chirp",
            "--pace",
            "1",
            "--duration-s",
            "20",
            "--seed",
            "45",
            "--out",
            "killed.mcap",
        ])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let part = d.join("killed.mcap.part");
    wait_until_started(&part);
    std::thread::sleep(Duration::from_millis(1000));
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(!d.join("catalogue").exists(), "a killed run appends no row");
    let o = bench_in(
        d,
        &["recover", "killed.mcap.part", "--out", "recovered.mcap"],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    std::fs::remove_file(&part).unwrap();
    let o = bench_in(d, &["catalogue", "--recordings", ".", "--json"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let s = json_stdout(&o);
    assert_eq!(s["rows"], 1, "{s}");
    assert_eq!(s["outcomes"], json!({"error": 1}), "{s}");
    let rows = read_rows(&d.join("catalogue.parquet")).unwrap();
    let row = &rows[0];
    assert_eq!(row["duration_s"], Cell::Real(None));
    assert_eq!(row["seed"], Cell::Unsigned(Some(45)));
    assert_eq!(row["fault_kind"], Cell::Text(None));
    close(
        real(row, "operating_point_m"),
        Some(DEFAULT_POINT.0),
        "recovered",
    );
    let Cell::TimestampUtc(Some(start)) = row["start_utc"] else {
        panic!("no start")
    };
    assert!(start >= before_us && start <= now_us());
    assert_eq!(
        text(row, "recording"),
        Some(
            std::path::absolute(d.join("recovered.mcap"))
                .unwrap()
                .display()
                .to_string()
        )
    );
}

/// Waits (at most 20 s) until the paced chirp has claimed its recording
/// `part` (the `.part` file exists).
fn wait_until_started(part: &Path) {
    let t0 = Instant::now();
    while !part.exists() {
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "the paced chirp never started"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}
