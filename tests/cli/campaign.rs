//! `bench campaign` on the simulator: a small grid run whole, the same grid
//! killed with SIGKILL at random moments and resumed each time (issue 15),
//! a changed campaign refused on resume, and bad input.

use bench::catalogue::file::read_rows;
use bench::catalogue::Value as Cell;
use rand::{Rng, SeedableRng};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

fn bench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bench"))
}

fn run(args: &[&str], cwd: &Path) -> Output {
    bench()
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("bench runs")
}

/// A 4 × 3 grid of 2 s chirps on the Chapter 5 bench, in `dir`.
fn small_campaign(dir: &Path) -> PathBuf {
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"),
        dir.join("sr4dof-ch5.toml"),
    )
    .unwrap();
    let p = dir.join("small.toml");
    std::fs::write(
        &p,
        r#"config = "sr4dof-ch5.toml"
seed = 15
[grid]
operating_point_pct = [1.0, 4.0, 7.0, 9.0]
mass_asymmetry = { from = -0.06, to = 0.06, step = 0.06 }
[chirp]
duration_s = 2.0
"#,
    )
    .unwrap();
    p
}

/// What a finished campaign measured: cells.csv, and per cell the journal's
/// FRF and summary checksums. (The MCAP files carry the wall-clock time
/// of the run in their metadata.)
fn results(dir: &Path) -> (String, BTreeMap<usize, Vec<String>>) {
    let csv = std::fs::read_to_string(dir.join("cells.csv")).unwrap();
    let mut sums = BTreeMap::new();
    let mut done_count: BTreeMap<usize, usize> = BTreeMap::new();
    for line in std::fs::read_to_string(dir.join("journal.jsonl"))
        .unwrap()
        .lines()
    {
        let json = line.rsplit_once('\t').unwrap().0;
        let v: Value = serde_json::from_str(json).unwrap();
        if v["entry"] == "done" {
            let cell = v["cell"].as_u64().unwrap() as usize;
            *done_count.entry(cell).or_default() += 1;
            let files: Vec<String> = v["files"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|f| {
                    let p = f["path"].as_str().unwrap();
                    p.ends_with("frf.csv")
                })
                .map(|f| f["sha256"].as_str().unwrap().to_string())
                .collect();
            sums.insert(cell, files);
        }
    }
    for (cell, n) in &done_count {
        assert_eq!(*n, 1, "cell {cell} was run to completion {n} times");
    }
    // One catalogue row a done cell, and none of a cell an interrupted
    // attempt left.
    let mut rows: Vec<String> = std::fs::read_dir(dir.join("catalogue"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    rows.sort();
    let want: Vec<String> = done_count
        .keys()
        .map(|c| format!("cell-{c:03}.parquet"))
        .collect();
    assert_eq!(rows, want, "{}", dir.display());
    (csv, sums)
}

#[test]
fn a_campaign_killed_at_random_moments_and_resumed_ends_as_an_uninterrupted_one() {
    let tmp = tempfile::tempdir().unwrap();
    let file = small_campaign(tmp.path());
    let file = file.to_str().unwrap();

    // Uninterrupted.
    let started = Instant::now();
    let out = run(
        &["campaign", "run", file, "--out", "whole", "--json"],
        tmp.path(),
    );
    let whole_s = started.elapsed();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(s["cells"], 12);
    assert_eq!(s["done"], 12);
    let reference = results(&tmp.path().join("whole"));
    assert_eq!(reference.1.len(), 12);

    // Killed with SIGKILL at 20 random moments in all, each time resumed
    // until it finishes; a campaign that finishes before the 20th kill is
    // compared and the next one started in a new directory.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(15);
    let mut kills = 0;
    let mut campaigns = 0;
    while kills < 20 {
        campaigns += 1;
        let name = format!("killed{campaigns}");
        let mut first = true;
        let mut attempts = 0;
        loop {
            attempts += 1;
            assert!(attempts < 500, "{name} never finished");
            let mut cmd = bench();
            if first {
                cmd.args(["campaign", "run", file, "--out", &name]);
            } else {
                cmd.args(["campaign", "resume", &name]);
            }
            first = false;
            let mut child = cmd
                .current_dir(tmp.path())
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap();
            if kills < 20 {
                let wait = rng.random_range(0.0..1.0) * whole_s.as_secs_f64() / 8.0;
                std::thread::sleep(Duration::from_secs_f64(wait));
                // SIGKILL: no handler runs, nothing is cleaned up.
                unsafe { libc::kill(child.id() as i32, libc::SIGKILL) };
            }
            let status = child.wait().unwrap();
            use std::os::unix::process::ExitStatusExt;
            if status.signal() == Some(libc::SIGKILL) {
                kills += 1;
                continue;
            }
            let mut err = String::new();
            use std::io::Read;
            child
                .stderr
                .take()
                .unwrap()
                .read_to_string(&mut err)
                .unwrap();
            assert!(
                status.success(),
                "{name}, attempt {attempts}: {status:?} {err}"
            );
            break;
        }
        let killed = results(&tmp.path().join(&name));
        assert_eq!(killed, reference, "{name}");
    }
}

#[test]
fn resuming_with_a_changed_campaign_or_config_is_refused_naming_what_changed() {
    let tmp = tempfile::tempdir().unwrap();
    let file = small_campaign(tmp.path());
    // A stopped campaign: one cell only, by a grid that is run whole, then
    // edited.
    let out = run(
        &["campaign", "run", file.to_str().unwrap(), "--out", "c"],
        tmp.path(),
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&file).unwrap();
    std::fs::write(&file, text.replace("duration_s = 2.0", "duration_s = 3.0")).unwrap();
    let out = run(
        &[
            "campaign",
            "resume",
            "c",
            "--campaign",
            file.to_str().unwrap(),
        ],
        tmp.path(),
    );
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("chirp.duration_s") && err.contains("--force"),
        "{err}"
    );
    // Editing the copy in the directory is caught the same way.
    let copy = tmp.path().join("c/bench.toml");
    let t = std::fs::read_to_string(&copy).unwrap();
    std::fs::write(&copy, t.replace("seed = 1", "seed = 2")).unwrap();
    let out = run(&["campaign", "resume", "c"], tmp.path());
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("config sim.seed"), "{err}");
    // Without the edit the original copy is accepted again.
    std::fs::write(&copy, t).unwrap();
    let out = run(&["campaign", "status", "c", "--json"], tmp.path());
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let s: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(s["done"], 12);
    // The original file changed: status says so, and goes on with the copy.
    assert!(String::from_utf8_lossy(&out.stderr).contains("changed since the campaign started"));
}

#[test]
fn bad_campaign_input_exits_2_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let file = small_campaign(tmp.path());
    let f = file.to_str().unwrap();
    let base = std::fs::read_to_string(&file).unwrap();
    let cases: Vec<(String, &str)> = vec![
        (
            base.replace("[1.0, 4.0, 7.0, 9.0]", "[]"),
            "grid.operating_point_pct",
        ),
        (
            base.replace("[1.0, 4.0, 7.0, 9.0]", "[1.0, 4.0, 1.0]"),
            "duplicates",
        ),
        (
            base.replace("[1.0, 4.0, 7.0, 9.0]", "[1.0, 25.0]"),
            "grid.operating_point_pct[1]",
        ),
        (
            base.replace("to = 0.06", "to = -0.5"),
            "grid.mass_asymmetry.to",
        ),
        (base.replace("seed = 15", "seed = 15\nbogus = 2"), "bogus"),
        (
            base.replace("duration_s = 2.0", "duration_s = 0.0"),
            "chirp.duration_s",
        ),
        // The excitation's overrides: a kind no excitation has, and the
        // old spelling beside the new one.
        (
            format!("{base}\n[excitation]\nkind = \"sine\"\n"),
            "excitation.kind",
        ),
        (
            base.replace("duration_s = 2.0", "duration_s = 2.0\nkind = \"linear\"")
                + "\n[excitation]\nkind = \"linear\"\n",
            "chirp.kind: is the old spelling of excitation.kind",
        ),
    ];
    for (i, (text, needle)) in cases.iter().enumerate() {
        let p = tmp.path().join(format!("bad{i}.toml"));
        std::fs::write(&p, text).unwrap();
        let out_dir = format!("out{i}");
        let out = run(
            &["campaign", "run", p.to_str().unwrap(), "--out", &out_dir],
            tmp.path(),
        );
        assert_eq!(out.status.code(), Some(2), "case {i}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(needle), "case {i}: {err}");
        assert!(
            !tmp.path().join(&out_dir).exists(),
            "case {i} wrote {out_dir}"
        );
    }
    // A non-empty output directory is never written into.
    std::fs::create_dir(tmp.path().join("full")).unwrap();
    std::fs::write(tmp.path().join("full/keep.txt"), "x").unwrap();
    let out = run(&["campaign", "run", f, "--out", "full"], tmp.path());
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("not empty"));
    assert_eq!(
        std::fs::read_dir(tmp.path().join("full")).unwrap().count(),
        1
    );
    // Not a campaign.
    let out = run(&["campaign", "resume", "full"], tmp.path());
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("not a bench campaign directory"));
    let out = run(&["campaign", "status", "nowhere"], tmp.path());
    assert_eq!(out.status.code(), Some(2));
    let out = run(
        &["campaign", "run", "missing.toml", "--out", "m"],
        tmp.path(),
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("missing.toml"));
    let out = run(
        &["campaign", "run", f, "--out", "t", "--threads", "0"],
        tmp.path(),
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--threads"));
    assert!(!tmp.path().join("t").exists());
    // `--submit`, the old spelling of --daemon, with or without a socket:
    // refused, saying what it is now; nothing submitted, nothing written.
    for extra in [&["--submit"][..], &["--submit", "nowhere.sock"][..]] {
        let out = run(&[&["campaign", "run", f][..], extra].concat(), tmp.path());
        assert_eq!(out.status.code(), Some(2));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("--submit is now --daemon"), "{err}");
        assert!(err.contains("--cells-on-daemon"), "{err}");
    }
}

#[test]
fn the_shipped_fig_5_10_campaign_is_the_thesis_grid() {
    let tmp = tempfile::tempdir().unwrap();
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/campaign-fig5-10.toml");
    // Loaded (and validated) by status of a fresh directory made from it;
    // here through the library for the grid itself.
    let c = bench::campaign::file::Campaign::load(&shipped).unwrap();
    assert_eq!(c.operating_points_m.len(), 15);
    assert_eq!(c.mass_asymmetries.len(), 10);
    let l = c.config.plant.beam.length_m;
    assert!((c.operating_points_m[0] / l - 0.006).abs() < 1e-12);
    assert!((c.operating_points_m[14] / l - 0.090).abs() < 1e-12);
    assert!((c.mass_asymmetries[0] + 0.08).abs() < 1e-12);
    assert!((c.mass_asymmetries[9] - 0.10).abs() < 1e-12);
    drop(tmp);
}

/// Every numeric key of the shipped campaign file, found by walking its
/// tables, set to hostile values (NaN, ±inf, negative, zero, denormal,
/// huge, the wrong type) and deleted, and an unknown key added to every
/// table: each mutation is refused naming its key, or accepted with the
/// value inside the range the README documents.
#[test]
fn mutations_of_every_campaign_key_are_refused_by_name_or_in_range() {
    use toml::{Table, Value};
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/campaign-fig5-10.toml");
    let text = std::fs::read_to_string(&shipped).unwrap();
    let table: Table = text.parse().unwrap();
    // Dotted paths of the numeric leaves.
    fn leaves(prefix: &str, t: &Table, out: &mut Vec<String>) {
        for (k, v) in t {
            let key = if prefix.is_empty() {
                k.clone()
            } else {
                format!("{prefix}.{k}")
            };
            match v {
                Value::Table(t) => leaves(&key, t, out),
                Value::Float(_) | Value::Integer(_) => out.push(key),
                _ => {}
            }
        }
    }
    let mut keys = Vec::new();
    leaves("", &table, &mut keys);
    assert!(keys.len() >= 10, "{keys:?}");
    let l = 0.0475;
    // The README's ranges, for an accepted value.
    let in_range = |key: &str, v: f64, c: &bench::campaign::file::Campaign| -> bool {
        match key {
            "seed" => v >= 0.0,
            "settle_s" => (0.0..=600.0).contains(&v),
            "mass_increment_kg" => (1e-5..=0.1).contains(&v),
            k if k.starts_with("grid.operating_point_pct") => c
                .operating_points_m
                .iter()
                .all(|op| op.abs() <= 0.2 * l + 1e-15),
            k if k.starts_with("grid.mass_asymmetry") => {
                c.mass_asymmetries.iter().all(|d| (-0.33..=0.5).contains(d))
            }
            "chirp.duration_s" => c
                .config
                .chirp
                .duration_s
                .is_some_and(|d| (0.1..=600.0).contains(&d)),
            other => panic!("no documented range for {other}"),
        }
    };
    let set = |t: &mut Table, key: &str, v: Option<Value>| {
        let parts: Vec<&str> = key.split('.').collect();
        let mut cur = t;
        for p in &parts[..parts.len() - 1] {
            cur = cur.get_mut(*p).unwrap().as_table_mut().unwrap();
        }
        match v {
            Some(v) => {
                cur.insert(parts[parts.len() - 1].to_string(), v);
            }
            None => {
                cur.remove(parts[parts.len() - 1]);
            }
        }
    };
    let hostile: Vec<Value> = vec![
        Value::Float(f64::NAN),
        Value::Float(f64::INFINITY),
        Value::Float(f64::NEG_INFINITY),
        Value::Float(-1.0),
        Value::Float(0.0),
        Value::Float(-0.0),
        Value::Float(5e-324),
        Value::Float(1e300),
        Value::Float(-1e300),
        Value::Integer(-1),
        Value::Integer(i64::MAX),
        Value::Float(0.5),
        Value::Float(2.0),
        Value::Float(1e-6),
        Value::String("1.0".into()),
        Value::Boolean(true),
        Value::Array(vec![]),
    ];
    let mut mutations = 0;
    for key in &keys {
        let mut cases: Vec<Option<Value>> = hostile.iter().cloned().map(Some).collect();
        cases.push(None);
        for v in cases {
            let mut t = table.clone();
            set(&mut t, key, v.clone());
            let mutated = toml::to_string(&t).unwrap();
            mutations += 1;
            match bench::campaign::file::Campaign::from_text(&shipped, mutated.clone()) {
                Err(e) => {
                    let msg = e.to_string();
                    let last = key.rsplit('.').next().unwrap();
                    assert!(
                        msg.contains(key.as_str()) || msg.contains(last),
                        "{key} = {v:?}: the refusal does not name it: {msg}"
                    );
                }
                Ok(c) => {
                    let given = match &v {
                        Some(Value::Float(f)) => Some(*f),
                        Some(Value::Integer(i)) => Some(*i as f64),
                        _ => None,
                    };
                    if let Some(x) = given {
                        assert!(in_range(key, x, &c), "{key} = {x} accepted out of range");
                    }
                    assert!(c.cells().len() <= 10_000);
                }
            }
        }
    }
    // An unknown key in every table.
    for table_key in ["", "grid", "chirp"] {
        let mut t = table.clone();
        let target = if table_key.is_empty() {
            &mut t
        } else {
            t.get_mut(table_key).unwrap().as_table_mut().unwrap()
        };
        target.insert("not_a_key".into(), Value::Integer(1));
        let e = bench::campaign::file::Campaign::from_text(&shipped, toml::to_string(&t).unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("not_a_key"), "[{table_key}]: {e}");
        mutations += 1;
    }
    assert!(mutations > 150, "{mutations}");
}

/// Bytes of the regular files under `dir`.
fn bytes_under(dir: &Path) -> u64 {
    let mut n = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let e = e.unwrap();
        let m = e.metadata().unwrap();
        n += if m.is_dir() {
            bytes_under(&e.path())
        } else {
            m.len()
        };
    }
    n
}

/// "1.03 MB" → bytes.
fn parse_size(s: &str) -> f64 {
    let (v, unit) = s.trim().split_once(' ').unwrap();
    let scale = match unit {
        "kB" => 1e3,
        "MB" => 1e6,
        "GB" => 1e9,
        u => panic!("unit {u}"),
    };
    v.parse::<f64>().unwrap() * scale
}

/// The disk line a run prints first: (bytes a cell, keep).
fn disk_line(stderr: &str) -> (f64, String) {
    let line = stderr
        .lines()
        .find(|l| l.starts_with("disk: about "))
        .unwrap_or_else(|| panic!("no disk line: {stderr}"));
    let per_cell = line.split(" for ").nth(1).unwrap();
    let per_cell = per_cell
        .split('(')
        .nth(1)
        .unwrap()
        .split(" a cell")
        .next()
        .unwrap();
    let keep = line
        .split("keep = ")
        .nth(1)
        .unwrap()
        .split(')')
        .next()
        .unwrap();
    assert!(line.contains("free there"), "{line}");
    (parse_size(per_cell), keep.to_string())
}

/// `--keep` stores what it says per cell, the estimate printed before the
/// run is within its ±10 % of the bytes the cells wrote, and a design
/// over cells that keep no FRF is refused before anything runs.
#[test]
fn keep_stores_what_it_says_and_the_disk_estimate_holds() {
    let tmp = tempfile::tempdir().unwrap();
    let file = small_campaign(tmp.path());
    let file = file.to_str().unwrap();
    let expect: [(&str, &[&str]); 3] = [
        (
            "recording",
            &["bode.png", "chirp.mcap", "frf.csv", "summary.json"],
        ),
        ("frf", &["frf.csv", "summary.json"]),
        ("summary", &["summary.json"]),
    ];
    for (keep, files) in expect {
        let out = run(
            &[
                "campaign",
                "run",
                file,
                "--out",
                keep,
                "--keep",
                keep,
                "--threads",
                "2",
            ],
            tmp.path(),
        );
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{keep}: {err}");
        let (estimate, said) = disk_line(&err);
        assert_eq!(said, keep);
        let dir = tmp.path().join(keep);
        let mut total = 0;
        for cell in 0..12 {
            let cdir = dir.join(format!("cells/{cell:03}"));
            let mut names: Vec<String> = std::fs::read_dir(&cdir)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            names.sort();
            assert_eq!(names, files, "{keep}: cell {cell}");
            total += bytes_under(&cdir);
            let s: Value =
                serde_json::from_slice(&std::fs::read(cdir.join("summary.json")).unwrap()).unwrap();
            // The verdict is there whatever is kept; the files not kept
            // are named as such.
            assert!(s["verdict"].is_object(), "{s}");
            if keep != "recording" {
                assert_eq!(s["kept"], keep);
                assert!(s["recording"].is_null());
            }
            // The cell's row in the campaign's catalogue, whatever is
            // kept: the cell's point, seed and fit, and its recording
            // when kept.
            let row_file = dir.join(format!("catalogue/cell-{cell:03}.parquet"));
            total += std::fs::metadata(&row_file).unwrap().len();
            assert_eq!(
                s["catalogue"]["row"].as_str(),
                Some(std::path::absolute(&row_file).unwrap().to_str().unwrap()),
                "{s}"
            );
            let rows = read_rows(&row_file).unwrap();
            assert_eq!(rows.len(), 1);
            let row = &rows[0];
            assert_eq!(row["job_kind"], Cell::Text(Some("chirp".into())));
            assert_eq!(row["outcome"], Cell::Text(Some("ok".into())));
            assert_eq!(row["seed"], Cell::Unsigned(s["seed"].as_u64()));
            for key in ["operating_point_m", "mass_asymmetry"] {
                let Cell::Real(Some(x)) = row[key] else {
                    panic!("{key}: {:?}", row[key])
                };
                assert!((x - s[key].as_f64().unwrap()).abs() < 1e-15, "{key}");
            }
            assert_eq!(
                row["fit_modes"],
                Cell::Count(s["fit"]["modes"].as_array().map(|m| m.len() as i64)),
                "{s}"
            );
            let rec = std::path::absolute(cdir.join("chirp.mcap")).unwrap();
            assert_eq!(
                row["recording"],
                Cell::Text((keep == "recording").then(|| rec.display().to_string())),
                "{keep}"
            );
        }
        let measured = total as f64 / 12.0;
        assert!(
            (measured / estimate - 1.0).abs() < 0.10,
            "{keep}: {measured} B a cell measured, {estimate} B estimated"
        );
        // cells.csv names only the kept files, and status is clean.
        let csv = std::fs::read_to_string(dir.join("cells.csv")).unwrap();
        let row: Vec<&str> = csv.lines().nth(1).unwrap().split(',').collect();
        assert_eq!(!row[9].is_empty(), keep == "recording", "{csv}");
        assert_eq!(!row[10].is_empty(), keep != "summary", "{csv}");
        let st = run(&["campaign", "status", keep], tmp.path());
        assert!(
            st.status.success(),
            "{}",
            String::from_utf8_lossy(&st.stderr)
        );
    }
    // `bench catalogue` over the three campaigns: every cell once, the
    // kept recordings' rows rebuilt from them, the others carried from
    // the campaigns' catalogue folders; the same rows as the cells wrote.
    let all = tmp.path().join("all.parquet");
    let out = run(
        &[
            "catalogue",
            "--recordings",
            tmp.path().to_str().unwrap(),
            "--out",
            all.to_str().unwrap(),
            "--json",
        ],
        tmp.path(),
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(summary["rows"], 36, "{summary}");
    assert_eq!(summary["carried"], 24, "{summary}");
    assert_eq!(summary["skipped"], serde_json::json!([]), "{summary}");
    let as_text = |rows: Vec<bench::catalogue::file::ReadRow>| {
        let mut v: Vec<String> = rows.iter().map(|r| format!("{r:?}")).collect();
        v.sort();
        v
    };
    let mut cells = Vec::new();
    for keep in ["recording", "frf", "summary"] {
        for cell in 0..12 {
            let f = tmp
                .path()
                .join(format!("{keep}/catalogue/cell-{cell:03}.parquet"));
            cells.extend(read_rows(&f).unwrap());
        }
    }
    assert_eq!(as_text(read_rows(&all).unwrap()), as_text(cells));
    // The README's recursive glob finds every cell's row with DuckDB.
    let python = std::env::var("BENCH_PYTHON").unwrap_or_else(|_| "python3".into());
    let o = Command::new(python)
        .args([
            "-c",
            "import sys, duckdb; print(duckdb.sql(f\"SELECT count(*) FROM read_parquet('{sys.argv[1]}/**/catalogue/*.parquet') WHERE job_kind = 'chirp'\").fetchall()[0][0])",
        ])
        .arg(tmp.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(String::from_utf8_lossy(&o.stdout).trim(), "36");

    // The campaign's copy records the choice.
    let copy = std::fs::read_to_string(tmp.path().join("frf/campaign.toml")).unwrap();
    assert!(copy.contains("keep = \"frf\""), "{copy}");
    // A design needs the FRFs.
    let out = run(
        &[
            "campaign", "run", file, "--out", "nodesign", "--keep", "summary", "--design", "slow",
        ],
        tmp.path(),
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--keep summary"));
    assert!(!tmp.path().join("nodesign").exists());
    let out = run(&["design", "summary"], tmp.path());
    assert_eq!(out.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("kept its FRF"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Bad values are refused naming the flag.
    for bad in ["", "all", "FRF", "recording,frf", "none"] {
        let out = run(
            &["campaign", "run", file, "--out", "bad", "--keep", bad],
            tmp.path(),
        );
        assert_eq!(out.status.code(), Some(2), "{bad}");
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("--keep"),
            "{bad}"
        );
        assert!(!tmp.path().join("bad").exists());
    }
}

/// The shipped campaign is built in: `bench campaign default` prints it,
/// and `bench campaign run` without a file runs it from an empty
/// directory (stopped after a few cells here: 150 cells of 60 s chirps);
/// a resume goes on with what it keeps.
#[test]
fn the_builtin_campaign_runs_from_an_empty_directory() {
    let tmp = tempfile::tempdir().unwrap();
    let out = run(&["campaign", "default"], tmp.path());
    assert!(out.status.success());
    let shipped = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/campaign-fig5-10.toml"),
    )
    .unwrap();
    assert_eq!(String::from_utf8_lossy(&out.stdout), shipped);
    let done = |dir: &Path| -> usize {
        std::fs::read_to_string(dir.join("journal.jsonl"))
            .map(|j| {
                j.lines()
                    .filter(|l| l.contains("\"entry\":\"done\""))
                    .count()
            })
            .unwrap_or(0)
    };
    let dir = tmp.path().join("fig");
    for (round, args) in [
        (
            1,
            vec![
                "campaign",
                "run",
                "--out",
                "fig",
                "--keep",
                "frf",
                "--threads",
                "1",
            ],
        ),
        (2, vec!["campaign", "resume", "fig", "--threads", "1"]),
    ] {
        let mut child = bench()
            .args(&args)
            .current_dir(tmp.path())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let t0 = Instant::now();
        while done(&dir) < 2 * round {
            assert!(t0.elapsed() < Duration::from_secs(300), "no cells done");
            std::thread::sleep(Duration::from_millis(50));
        }
        unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
        let status = child.wait().unwrap();
        let mut err = String::new();
        use std::io::Read;
        child
            .stderr
            .take()
            .unwrap()
            .read_to_string(&mut err)
            .unwrap();
        assert_eq!(status.code(), Some(130), "{err}");
        let (_, keep) = disk_line(&err);
        assert_eq!(keep, "frf");
        assert!(
            err.contains(if round == 1 {
                "for 150 cells"
            } else {
                "cells ("
            }),
            "{err}"
        );
    }
    // Every done cell, before and after the resume, kept the FRF only.
    for e in std::fs::read_dir(dir.join("cells")).unwrap() {
        let cdir = e.unwrap().path();
        if cdir.join("summary.json").exists() {
            assert!(cdir.join("frf.csv").exists());
            assert!(!cdir.join("chirp.mcap").exists(), "{}", cdir.display());
        }
    }
    let origin = std::fs::read_to_string(dir.join("origin.json")).unwrap();
    assert!(
        origin.contains("\"built-in (campaign-fig5-10)\""),
        "{origin}"
    );
    let st = run(&["campaign", "status", "fig"], tmp.path());
    assert!(
        st.status.success(),
        "{}",
        String::from_utf8_lossy(&st.stderr)
    );
}
