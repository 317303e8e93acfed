//! The run catalogue's query time (issue 30, part 3: "a 10 000-run
//! catalogue answers a filtered query in ≤ 0.2 s with DuckDB").
//!
//! Writes `BENCH_CATALOGUE_RUNS` (default 10 000) synthetic runs through
//! the library's own writer ([`bench::catalogue::file::write_rows`]) twice:
//! as the runs append them, one file per run in `catalogue/`, and as
//! `bench catalogue` compacts them, one `catalogue.parquet`. Then
//! `benches/catalogue_query.py` (DuckDB from Python: `$BENCH_PYTHON`, else
//! `python3`) times the README's DuckDB query over each, a fresh
//! connection per query, and a whole `python -c` process for the
//! compacted file.
//!
//! The runs: start times spread over the 365 days before now (the query
//! keeps the last 30), 60 % chirps and 40 % steps on three hosts,
//! operating points uniform over 0–10 % of L (the query keeps 3–5 mm),
//! asymmetries over ±10 %, 95 % ok, 3 % faulted, 1 % stopped, 1 % errors;
//! chirps with three fitted modes, steps with margins and step figures.
//!
//! First, what a run pays for its row: [`append_run`] (read the row from
//! the finished recording, write it atomically and synced) on the default
//! chirp's recording.
//!
//! `cargo bench --bench catalogue` (or with `BENCH_CATALOGUE_DIR=DIR` to
//! keep the files).

mod common;

use bench::catalogue::file::write_rows;
use bench::catalogue::CatalogueRow;
use bench::jobs::catalogue::append_run;
use rand::{Rng, SeedableRng};
use std::path::Path;
use std::process::Command;
use std::time::Instant;

/// A synthetic run, `i` of a catalogue ending at `now_us`.
fn row(rng: &mut rand_chacha::ChaCha8Rng, i: usize, now_us: i64) -> CatalogueRow {
    const DAY_US: f64 = 86_400e6;
    let l_m = 0.0475;
    let start = now_us - (rng.random::<f64>() * 365.0 * DAY_US) as i64;
    let chirp = rng.random::<f64>() < 0.6;
    let u: f64 = rng.random();
    let outcome = if u < 0.95 {
        "ok"
    } else if u < 0.98 {
        "fault"
    } else if u < 0.99 {
        "stopped"
    } else {
        "error"
    };
    let op = rng.random::<f64>() * 0.1 * l_m;
    let mut r = CatalogueRow {
        start_utc_us: Some(start),
        host: Some(format!("lab-{}", 1 + i % 3)),
        bench_name: Some("sr4dof-ch5".into()),
        config_sha256: Some(format!("{:064x}", rng.random::<u128>())),
        bench_version: Some("0.1.0".into()),
        job_kind: Some(if chirp { "chirp" } else { "control" }.into()),
        backend: Some("sim:sr4dof".into()),
        pacing: Some("virtual".into()),
        rate_hz: Some(5000.0),
        operating_point_m: Some(op),
        operating_point_fraction_of_l: Some(op / l_m),
        mass_asymmetry: Some(rng.random_range(-0.1..0.1)),
        seed: Some(rng.random()),
        duration_s: Some(if chirp { 65.5 } else { 4.0 }),
        outcome: Some(outcome.into()),
        fault_kind: (outcome == "fault").then(|| "position_limit".into()),
        recording: Some(format!(
            "/var/lib/bench/recordings/{}-{i:05}.mcap",
            if chirp { "chirp" } else { "control-fast" }
        )),
        ..CatalogueRow::default()
    };
    if outcome != "ok" {
        return r;
    }
    if chirp {
        let u = 81.0 + rng.random::<f64>();
        let v = u + 0.5 + 3.0 * rng.random::<f64>();
        r.fit_modes = Some(3);
        r.mode_frequency_hz = [Some(29.27), Some(u), Some(v), None];
        r.mode_damping_ratio = [Some(0.009), Some(0.004), Some(0.004), None];
        r.pair_u_frequency_hz = Some(u);
        r.pair_v_frequency_hz = Some(v);
        r.fit_trusted = Some(rng.random::<f64>() < 0.97);
        r.verdict_cmp_cnmp = Some(rng.random::<bool>());
        r.model_cmp_cnmp = r.verdict_cmp_cnmp;
        r.peak_position_m = Some(2.5e-4);
    } else {
        r.controller = Some("fast".into());
        r.loop_check_passed = Some(true);
        r.crossover_rad_s = Some(284.0 + rng.random::<f64>());
        r.phase_margin_deg = Some(37.0 + rng.random::<f64>());
        r.gain_margin_db = Some(6.8);
        r.modulus_margin = Some(0.455);
        r.step_m = Some(1e-5);
        r.rise_time_s = Some(0.0048);
        r.settling_time_s = Some(0.085);
        r.overshoot_pct = Some(0.0);
        r.steady_state_error_std_m = Some(43e-9);
        r.peak_command_a = Some(0.178);
    }
    r
}

/// The book's DuckDB query (docs/src/fleet/catalogue.md) (the block after its marker).
fn readme_query() -> String {
    let readme = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/src/fleet/catalogue.md"),
    )
    .unwrap();
    let marker = "<!-- catalogue example: duckdb -->";
    let rest = &readme[readme.find(marker).expect("the book's query") + marker.len()..];
    let body = &rest[rest.find("```").unwrap()..];
    let body = &body[body.find('\n').unwrap() + 1..];
    body[..body.find("\n```").unwrap()].to_string()
}

/// The cost of a run's row on the default chirp's recording.
fn append_cost() {
    let dir = tempfile::tempdir().unwrap();
    let opts = common::default_chirp(dir.path());
    common::run(&opts);
    let size = std::fs::metadata(&opts.out).unwrap().len();
    let mut times: Vec<f64> = (0..20)
        .map(|_| {
            let t0 = Instant::now();
            append_run(&opts.out).unwrap();
            t0.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    println!(
        "a run's row (append_run) on the default chirp's recording ({:.1} MB): median {:.2} ms, min {:.2} ms, max {:.2} ms over 20",
        size as f64 / 1e6,
        1e3 * times[10],
        1e3 * times[0],
        1e3 * times[19]
    );
}

fn main() {
    append_cost();
    let n: usize = std::env::var("BENCH_CATALOGUE_RUNS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10_000);
    let keep = std::env::var_os("BENCH_CATALOGUE_DIR").map(std::path::PathBuf::from);
    let tmp = tempfile::tempdir().unwrap();
    let dir = keep.unwrap_or_else(|| tmp.path().to_path_buf());
    let per_run = dir.join("catalogue");
    std::fs::create_dir_all(&per_run).unwrap();
    let now_us = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_micros() as i64;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(30);
    let rows: Vec<CatalogueRow> = (0..n).map(|i| row(&mut rng, i, now_us)).collect();

    // As the runs append them: one file each (written plainly here; a run
    // writes its file atomically and synced).
    let t0 = Instant::now();
    let mut per_run_bytes = 0;
    for (i, r) in rows.iter().enumerate() {
        let p = per_run.join(format!("run-{i:05}.parquet"));
        write_rows(std::slice::from_ref(r), std::fs::File::create(&p).unwrap()).unwrap();
        per_run_bytes += std::fs::metadata(&p).unwrap().len();
    }
    let per_run_s = t0.elapsed().as_secs_f64();
    // As `bench catalogue` compacts them, sorted by start time.
    let mut sorted = rows.clone();
    sorted.sort_by_key(|r| r.start_utc_us);
    let compacted = dir.join("catalogue.parquet");
    let t0 = Instant::now();
    write_rows(&sorted, std::fs::File::create(&compacted).unwrap()).unwrap();
    let compacted_s = t0.elapsed().as_secs_f64();
    let compacted_bytes = std::fs::metadata(&compacted).unwrap().len();
    println!(
        "{n} runs: per-run files {:.1} MB written in {per_run_s:.2} s ({:.2} ms each), compacted {:.2} MB in {:.1} ms",
        per_run_bytes as f64 / 1e6,
        1e3 * per_run_s / n as f64,
        compacted_bytes as f64 / 1e6,
        1e3 * compacted_s
    );

    let query = dir.join("query.sql");
    std::fs::write(&query, readme_query()).unwrap();
    let python = std::env::var("BENCH_PYTHON")
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "python3".into());
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/catalogue_query.py");
    let status = Command::new(&python)
        .arg(&script)
        .arg(&dir)
        .arg(&query)
        .status()
        .unwrap_or_else(|e| panic!("cannot run {python}: {e} (pip install duckdb, or .ci/run)"));
    assert!(status.success(), "{} failed", script.display());
}
