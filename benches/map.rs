//! `bench map`'s computation (issue 14): the CNMP map of the Chapter 5
//! bench on a 200 × 200 grid of operating point (0 … 10 % of L) × mass
//! asymmetry (−10 … +10 %): per cell the model's eigen-decomposition,
//! residues, damped and undamped zeros and their types.
//!
//! Criterion measures the map on rayon's global pool (all cores) and on one
//! thread. Then the same computation in NumPy (`benches/map_numpy.py`, one
//! cell at a time and batched over all cells) is timed in the same run,
//! its CNMP cell counts are checked against ours, and the ratios are
//! printed. Without `python3` and numpy that comparison is skipped with
//! the reason.
//!
//!     cargo bench --bench map

use bench::analysis::map::{cnmp_map, linspace};
use bench::config::BenchConfig;
use bench_plant::model::Sr4dofParams;
use criterion::{black_box, Criterion};
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

const N: usize = 200;

fn grid() -> (Sr4dofParams, Vec<f64>, Vec<f64>) {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    let plant = BenchConfig::load(&p).expect("shipped config").plant;
    let ops = linspace(0.0, 0.10 * plant.beam.length_m, N);
    let dms = linspace(-0.10, 0.10, N);
    (plant, ops, dms)
}

fn one_thread_pool() -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a one-thread pool")
}

/// Median wall time of `runs` calls.
fn median_of(runs: usize, mut f: impl FnMut()) -> Duration {
    let mut t: Vec<Duration> = (0..runs)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed()
        })
        .collect();
    t.sort();
    t[runs / 2]
}

fn compare_with_numpy(all_cores: Duration, one_thread: Duration, counts: (usize, usize)) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/map_numpy.py");
    let out = Command::new("python3")
        .arg(&script)
        .arg(N.to_string())
        .output();
    let out = match out {
        Ok(o) if o.status.success() => o,
        Ok(o) => {
            println!(
                "NumPy comparison skipped: {} failed: {}",
                script.display(),
                String::from_utf8_lossy(&o.stderr).trim()
            );
            return;
        }
        Err(e) => {
            println!("NumPy comparison skipped: python3: {e}");
            return;
        }
    };
    let v: serde_json::Value =
        serde_json::from_slice(&out.stdout).expect("map_numpy.py prints one JSON line");
    let loop_s = v["loop_s"].as_f64().expect("loop_s");
    let batched_s = v["batched_s"].as_f64().expect("batched_s");
    let ours = [counts.0 as u64, counts.1 as u64];
    for key in ["loop_cnmp", "batched_cnmp"] {
        let theirs: Vec<u64> = v[key]
            .as_array()
            .expect(key)
            .iter()
            .map(|c| c.as_u64().expect("count"))
            .collect();
        assert_eq!(
            theirs, ours,
            "{key}: NumPy's CNMP cell counts (undamped, damped) differ from ours"
        );
    }
    let s = all_cores.as_secs_f64();
    let s1 = one_thread.as_secs_f64();
    println!(
        "map {N}x{N} ({} cells; CNMP undamped {}, damped {}; numpy {}):",
        N * N,
        counts.0,
        counts.1,
        v["numpy"].as_str().unwrap_or("?")
    );
    println!(
        "  bench, {} threads: {:8.1} ms",
        rayon::current_num_threads(),
        1e3 * s
    );
    println!("  bench, 1 thread:  {:8.1} ms", 1e3 * s1);
    println!(
        "  NumPy, cell by cell: {:8.1} ms  -> bench is {:.0}x faster ({:.0}x on one thread)",
        1e3 * loop_s,
        loop_s / s,
        loop_s / s1
    );
    println!(
        "  NumPy, batched:      {:8.1} ms  -> bench is {:.1}x faster ({:.1}x on one thread)",
        1e3 * batched_s,
        batched_s / s,
        batched_s / s1
    );
}

fn main() {
    let (base, ops, dms) = grid();
    let pool = one_thread_pool();
    let mut c = Criterion::default().configure_from_args();
    let mut g = c.benchmark_group("map");
    g.sample_size(20);
    g.bench_function("cnmp_map_200x200", |b| {
        b.iter(|| black_box(cnmp_map(&base, &ops, &dms).unwrap()))
    });
    g.bench_function("cnmp_map_200x200_one_thread", |b| {
        b.iter(|| pool.install(|| black_box(cnmp_map(&base, &ops, &dms).unwrap())))
    });
    g.finish();
    c.final_summary();

    let cells = cnmp_map(&base, &ops, &dms).unwrap();
    let counts = (
        cells.iter().filter(|c| c.cnmp).count(),
        cells.iter().filter(|c| c.cnmp_damped).count(),
    );
    let all = median_of(11, || {
        black_box(cnmp_map(&base, &ops, &dms).unwrap());
    });
    let one = median_of(5, || {
        pool.install(|| black_box(cnmp_map(&base, &ops, &dms).unwrap()));
    });
    compare_with_numpy(all, one, counts);
}
