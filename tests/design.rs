//! `bench design` as a library: designs on the shipped Chapter 5 bench.

use bench::config::BenchConfig;
use bench::design::loops::figures;
use bench::design::modes::PlantModes;
use bench::design::search::Requirements;
use bench::design::{certify, design, prepare, DesignSpec, InputFrf, Strategy, UNIT_PER_METRE};
use bench::ident::frf::{log_grid, Frf};
use bench::ident::modal_fit::Path as FitPath;
use bench_hal::model::Sr4dof;
use bench_hal::sim::ZohPlant;
use std::path::Path;
use std::time::Instant;

fn config() -> BenchConfig {
    BenchConfig::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"))
        .unwrap()
}

/// The model's FRF on the default chirp's grid (0.1–500 Hz, 400 lines per
/// decade), coherence 1.
fn model_frf(cfg: &BenchConfig) -> Frf {
    let model = Sr4dof::new(cfg.plant).unwrap();
    let t = cfg.loop_.period_ns() as f64 * 1e-9;
    let p = ZohPlant::new(&model, &cfg.actuator, t);
    let f = log_grid(0.1, 500.0, 400);
    let h: Vec<_> = f.iter().map(|&f| p.frf(f)).collect();
    let mut phase: Vec<f64> = h.iter().map(|h| h.arg().to_degrees()).collect();
    bench::ident::frf::unwrap_deg(&mut phase);
    Frf {
        magnitude_m_per_a: h.iter().map(|h| h.norm()).collect(),
        phase_deg: phase,
        coherence: vec![1.0; f.len()],
        frequency_hz: f,
    }
}

#[test]
fn fast_design_on_the_chapter_5_model() {
    let cfg = config();
    let t = cfg.loop_.period_ns() as f64 * 1e-9;
    let inputs = vec![InputFrf {
        label: "model".into(),
        frf: model_frf(&cfg),
    }];
    let spec = DesignSpec {
        strategy: Strategy::Auto,
        requirements: Requirements {
            phase_margin_min_deg: 40.0,
            gain_margin_min_db: 6.0,
            sensitivity_peak_max: 2.0,
        },
        computation_delay_s: t,
    };
    let path = FitPath {
        period_s: t,
        amplifier_bandwidth_hz: cfg.actuator.bandwidth_hz,
    };
    let t0 = Instant::now();
    let modes = PlantModes::identify(&inputs, path).unwrap();
    let (frfs, _) = prepare(
        &inputs,
        spec.computation_delay_s,
        Some(modes.first_resonance_rad_s),
    )
    .unwrap();
    let d = design(&frfs, &modes, &spec, t, cfg.actuator.peak_current_a).unwrap();
    eprintln!("design time {:.2} s", t0.elapsed().as_secs_f64());
    eprintln!("{}", d.why);
    for a in &d.attempts {
        let e = &a.evaluation;
        eprintln!(
            "{}: feasible {} ω_B {:.1} rad/s, crossovers {:?}, PMs {:?}, GM {:?}, S {:.3}, binding {:?}\n{:#?}",
            a.strategy,
            e.feasible(),
            e.sensitivity_bandwidth_min_rad_s,
            e.figures[0].crossovers_rad_s,
            e.figures[0].phase_margins_deg,
            e.figures[0].gain_margin_db,
            e.figures[0].sensitivity_peak,
            e.binding,
            e.controller
        );
    }
    // Eq. (6-7) on the same loop.
    let problem = bench::design::search::Problem::new(
        frfs.iter().collect(),
        spec.requirements,
        UNIT_PER_METRE,
    );
    let thesis = certify(
        &problem,
        cfg.controller["fast"].clone(),
        t,
        cfg.actuator.peak_current_a,
    );
    let f = &thesis.figures[0];
    eprintln!(
        "Eq. 6-7: ω_B {:.1}, crossovers {:?}, PMs {:?}, S {:.3}",
        thesis.sensitivity_bandwidth_min_rad_s,
        f.crossovers_rad_s,
        f.phase_margins_deg,
        f.sensitivity_peak
    );
    let _ = figures;
    assert!(d.chosen.evaluation.feasible());
}
