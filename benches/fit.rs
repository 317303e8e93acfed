//! `bench fit`'s modal fit (issue 13) on the default chirp's FRF: the
//! Chapter 5 bench as shipped (8 % of L, Δm23 = +10 %), its exact sampled
//! response on the chirp's grid (0.1–500 Hz, 400 points per decade) with
//! 0.5 % complex noise per point and the matching coherence (the simulated
//! 60 s chirp leaves an RMS relative error of about 0.8 %). Also the
//! verdict (the fit plus the phase test and 400 residue-test draws), and
//! the model update (`bench fit --update`) of the same FRF from the
//! Fig 5-11 start (the bench configured symmetric, textbook stiffness, the
//! five default parameters free), given the modal fit. And the fit on the
//! same FRF with a fifth of its lines corrupted by `real_links`' outlier
//! condition (`tests/common/outliers.rs`: each multiplied by
//! `1 + r e^{jφ}`, r from 0.2 to 1, φ uniform, σ and coherence left as
//! they were): a fit that ends flagged after pruning the modes the
//! corruption made it try (the slowest fits the tests meet). Eight draws, each timed once and all eight together.
//!
//!     cargo bench --bench fit

use bench::config::BenchConfig;
use bench::ident::frf::{log_grid, unwrap_deg, Frf, C64};
use bench::ident::modal_fit::{fit, FrfData, Path as FitPath};
use bench::ident::update::{update_to_frf, Bench, Parameter};
use bench_plant::model::Sr4dof;
use bench_plant::sim::ZohPlant;
use criterion::{black_box, Criterion};
use rand::{Rng, SeedableRng};
use std::path::Path;

#[path = "../tests/common/outliers.rs"]
mod outliers;

fn ch5() -> BenchConfig {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    BenchConfig::load(&p).expect("shipped config")
}

fn default_chirp_frf() -> (Frf, FitPath) {
    let cfg = ch5();
    let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
    let zoh = ZohPlant::new(&Sr4dof::new(cfg.plant).unwrap(), &cfg.actuator, period_s);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let noise = 5e-3;
    let f = log_grid(
        cfg.chirp.f_start_hz,
        cfg.chirp.f_end_hz,
        cfg.identification.points_per_decade,
    );
    let h: Vec<C64> = f
        .iter()
        .map(|&f| {
            let e =
                C64::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)) * (noise * 1.22);
            zoh.frf(f) * (C64::new(1.0, 0.0) + e)
        })
        .collect();
    let mut phase: Vec<f64> = h.iter().map(|h| h.arg().to_degrees()).collect();
    unwrap_deg(&mut phase);
    let frf = Frf {
        magnitude_m_per_a: h.iter().map(|h| h.norm()).collect(),
        phase_deg: phase,
        coherence: vec![1.0 / (1.0 + noise * noise); f.len()],
        // E|e|² = (2/3)(1.22 noise)² ≈ noise²; independent lines.
        sigma_m_per_a: h.iter().map(|h| h.norm() * noise).collect(),
        resolution_hz: vec![f64::NAN; f.len()],
        // A known variance.
        sigma_dof: vec![f64::INFINITY; f.len()],
        frequency_hz: f,
    };
    let path = FitPath {
        period_s,
        amplifier_bandwidth_hz: cfg.actuator.bandwidth_hz,
    };
    (frf, path)
}

/// Draws of [`outliers::with_outliers`] timed together.
const CORRUPTED_DRAWS: u64 = 8;

fn main() {
    let (frf, path) = default_chirp_frf();
    let data = FrfData::from_frf(&frf);
    let mut c = Criterion::default().sample_size(20).configure_from_args();
    c.bench_function("modal fit, default chirp FRF (1476 points)", |b| {
        b.iter(|| fit(black_box(&data), &path).unwrap())
    });
    // Eight draws of the corruption: the pruning's cost depends on which
    // modes a draw makes the fit try.
    let corrupted: Vec<FrfData> = (1..=CORRUPTED_DRAWS)
        .map(|seed| FrfData::from_frf(&outliers::with_outliers(frf.clone(), seed)))
        .collect();
    for (seed, d) in corrupted.iter().enumerate() {
        let t = std::time::Instant::now();
        let f = fit(d, &path).unwrap();
        println!(
            "a fifth of the lines corrupted, draw {}: {} modes, {} quality flags, {:.2} s",
            seed + 1,
            f.modes.len(),
            f.quality.flags.len(),
            t.elapsed().as_secs_f64()
        );
    }
    // Seconds an iteration: ten samples, not twenty.
    let mut g = c.benchmark_group("flagged fit");
    g.sample_size(10);
    g.bench_function(
        "modal fit, default chirp FRF, a fifth of the lines corrupted (8 draws)",
        |b| {
            b.iter(|| {
                for d in &corrupted {
                    fit(black_box(d), &path).unwrap();
                }
            })
        },
    );
    g.finish();
    c.bench_function("fit + verdict, default chirp FRF", |b| {
        b.iter(|| {
            bench::jobs::chirp::identify(
                black_box(&frf),
                path.period_s,
                path.amplifier_bandwidth_hz,
            )
        })
    });
    let f = fit(&data, &path).unwrap();
    let cfg = ch5();
    let mut plant = cfg.plant;
    plant.mass_asymmetry = 0.0;
    plant.parallelogram_stiffness_n_per_m = None;
    let start = Bench {
        plant,
        force_constant_n_per_a: cfg.actuator.force_constant_n_per_a,
    };
    c.bench_function("model update, default chirp FRF (5 parameters)", |b| {
        b.iter(|| {
            update_to_frf(
                black_box(&start),
                &Parameter::FRF_DEFAULT,
                &data,
                &path,
                Some(&f),
            )
            .unwrap()
        })
    });
    let u = update_to_frf(&start, &Parameter::FRF_DEFAULT, &data, &path, Some(&f)).unwrap();
    println!(
        "updated: {:?}",
        u.parameters
            .iter()
            .map(|p| (p.name.clone(), p.value))
            .collect::<Vec<_>>()
    );
    println!(
        "modes: {:?}, sequence {}, CMP-CNMP {}",
        f.modes
            .iter()
            .map(|m| (m.label.clone(), m.frequency_hz))
            .collect::<Vec<_>>(),
        f.dominant_sequence,
        f.cmp_cnmp
    );
    c.final_summary();
}
