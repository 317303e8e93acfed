//! Simulated plant throughput: exact-ZOH steps of the 9-state SR4DoF +
//! amplifier model, bare and through the HAL (probe noise, quantisation,
//! stop), as a tick would drive it.

use bench::config::BenchConfig;
use bench_hal::{Command, Stage};
use bench_plant::sim::{SimStage, ZohPlant};
use criterion::{black_box, criterion_group, criterion_main, Criterion, Throughput};
use nalgebra::SVector;
use std::path::Path;

fn config() -> BenchConfig {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    BenchConfig::load(&p).unwrap()
}

fn plant(c: &mut Criterion) {
    let cfg = config();
    let mut stage = SimStage::new(cfg.sim_params(1)).unwrap();
    let info = stage.configure(cfg.loop_.period_ns()).unwrap();
    let zoh = ZohPlant::new(stage.model(), &cfg.actuator, info.period_ns as f64 * 1e-9);
    let mut g = c.benchmark_group("plant");
    g.throughput(Throughput::Elements(1000));
    g.bench_function("zoh_step_x1000", |b| {
        let mut x = SVector::<f64, 9>::zeros();
        b.iter(|| {
            for k in 0..1000 {
                zoh.step(&mut x, black_box(if k % 2 == 0 { 0.1 } else { -0.1 }), 0.0);
            }
            black_box(x[0])
        })
    });
    stage.enable().unwrap();
    g.bench_function("hal_read_write_x1000", |b| {
        b.iter(|| {
            for k in 0..1000u64 {
                let s = stage.read_sample().unwrap();
                stage
                    .write_command(Command {
                        current_a: if k % 2 == 0 { 0.1 } else { -0.1 },
                        answers_seq: s.seq,
                    })
                    .unwrap();
            }
        })
    });
    g.finish();
}

criterion_group!(benches, plant);
criterion_main!(benches);
