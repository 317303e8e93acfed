//! End-to-end `bench chirp` in virtual time (loop + MCAP + FRF + plot) on
//! the default 0.1–500 Hz chirp, and the FRF estimation alone on a record of
//! the same length: H1 with the resonance finder (as before), then the two
//! estimators side by side, transform included (`frf_h1_default_record`,
//! `frf_lpm_default_record`) and the lines alone, from the same spectra
//! (`lines_h1`, `lines_lpm`).

mod common;

use bench::ident::frf::{find_resonances, Frf, Spectra};
use bench::ident::lpm::{self, LpmOptions};
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
    let id = &cfg.identification;
    let (f_lo, f_hi) = (cfg.chirp.f_start_hz, cfg.chirp.f_end_hz);
    let opts = LpmOptions::from_config(id);
    g.bench_function("frf_h1_default_record", |b| {
        b.iter(|| {
            let s = Spectra::new(&u, &y, rate, id);
            Frf::estimate(&s, f_lo, f_hi, id).frequency_hz.len()
        })
    });
    g.bench_function("frf_lpm_default_record", |b| {
        b.iter(|| {
            let s = Spectra::new(&u, &y, rate, id);
            lpm::estimate(&s, f_lo, f_hi, id.points_per_decade, &opts)
                .unwrap()
                .frequency_hz
                .len()
        })
    });
    let s = Spectra::new(&u, &y, rate, id);
    g.bench_function("lines_h1", |b| {
        b.iter(|| Frf::estimate(&s, f_lo, f_hi, id).frequency_hz.len())
    });
    g.bench_function("lines_lpm", |b| {
        b.iter(|| {
            lpm::estimate(&s, f_lo, f_hi, id.points_per_decade, &opts)
                .unwrap()
                .frequency_hz
                .len()
        })
    });
    g.finish();
}

criterion_group!(benches, chirp);
criterion_main!(benches);
