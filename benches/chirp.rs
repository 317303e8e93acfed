//! End-to-end `bench chirp` in virtual time (loop + MCAP + FRF + plot) on
//! the default 0.1–500 Hz chirp, and the FRF estimation alone on a record of
//! the same length.

mod common;

use bench::ident::frf::{find_resonances, Frf, Spectra};
use criterion::{criterion_group, criterion_main, Criterion};
use std::time::Duration;

fn chirp(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let opts = common::default_chirp(dir.path());
    let cfg = &opts.config;
    let mut g = c.benchmark_group("chirp");
    g.sample_size(10).measurement_time(Duration::from_secs(20));
    g.bench_function("default_chirp_end_to_end", |b| {
        // Every iteration writes the same files: --overwrite.
        b.iter(|| common::run(&opts))
    });

    // A record of the default length (lead-in + 60 s sweep + tail at 5 kHz).
    let rate = cfg.loop_.rate_hz;
    let sweep_s = cfg.chirp.duration_s.expect("the shipped chirp is a sweep");
    let n = ((cfg.chirp.lead_in_s + sweep_s + cfg.chirp.tail_s) * rate) as usize;
    let u: Vec<f64> = (0..n).map(|k| (k as f64 * 0.37).sin()).collect();
    let y: Vec<f64> = (0..n)
        .map(|k| (k as f64 * 0.37 + 0.5).sin() * 1e-5)
        .collect();
    g.bench_function("frf_estimation_default_record", |b| {
        b.iter(|| {
            let s = Spectra::new(&u, &y, rate, &cfg.identification);
            let frf = Frf::estimate(
                &s,
                cfg.chirp.f_start_hz,
                cfg.chirp.f_end_hz,
                &cfg.identification,
            );
            find_resonances(&frf, &s, 3.0).len()
        })
    });
    g.finish();
}

criterion_group!(benches, chirp);
criterion_main!(benches);
