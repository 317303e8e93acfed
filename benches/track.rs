//! `bench track` between two trials: the trial's analysis (the measured
//! error, its mean line, its harmonics and their 1σ between lines) and the
//! learning update (significant harmonics only) with the
//! next trial's feedforward table, for a 1 s trial at 20 kHz (issue 44:
//! ≤ 1 s). Two lines: 10 Hz (2 000 ticks, 5 harmonics) and 1 Hz (20 000
//! ticks, the Chapter 5 bench's 58 harmonics below its CNMP band).

use bench::config::BenchConfig;
use bench::control::verify::ModelLoop;
use bench::control::DiscreteController;
use bench::jobs::track::{harmonic_sigma, measured_error};
use bench::track::{Harmonics, Learning, Scan, ScanKind};
use bench_plant::model::Sr4dof;
use bench_plant::sim::ZohPlant;
use criterion::{black_box, criterion_group, criterion_main, Criterion};
use std::path::Path;

fn track(c: &mut Criterion) {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    let cfg = BenchConfig::load(&p).unwrap();
    let rate_hz = 20_000.0;
    let period_s = 1.0 / rate_hz;
    let plant = ZohPlant::new(&Sr4dof::new(cfg.plant).unwrap(), &cfg.actuator, period_s);
    let ctrl = DiscreteController::new(&cfg.controller["fast"], period_s, 10.0);
    let model = ModelLoop {
        plant: &plant,
        ctrl: &ctrl,
        link_delay_periods: 0,
    };
    for line_hz in [10.0, 1.0] {
        let n = (rate_hz / line_hz) as usize;
        let scan = Scan {
            kind: ScanKind::Triangle,
            move_limits: None,
            amplitude_m: 5e-6,
            line_rate_hz: line_hz,
            cutoff_hz: 58.9,
            reference_csv: None,
            reference: None,
        };
        let k_max = scan.k_max();
        let learning = Learning::new(&model, 0.7, k_max, line_hz);
        let r = scan.harmonics(n);
        let r_t = r.synthesize();
        let ticks = rate_hz as usize;
        let setpoint: Vec<f64> = (0..ticks).map(|i| r_t[i % n]).collect();
        let position: Vec<f64> = setpoint
            .iter()
            .enumerate()
            .map(|(i, s)| s * 0.9 + 1e-8 * ((i * 7919) % 101) as f64)
            .collect();
        let f = Harmonics::zeros(k_max, n);
        c.bench_function(
            &format!("track: 1 s trial at 20 kHz, {line_hz} Hz line, analysis + update"),
            |b| {
                b.iter(|| {
                    let warm_up = if n < ticks { n } else { 0 };
                    let m = measured_error(&setpoint, &position, n, warm_up);
                    let sigma = harmonic_sigma(&m.error_m, n, k_max);
                    let e = Harmonics::analyze(&m.mean_line_m, k_max);
                    let next = learning.update_significant(&f, &e, &sigma);
                    black_box(next.synthesize())
                })
            },
        );
    }
}

criterion_group!(benches, track);
criterion_main!(benches);
