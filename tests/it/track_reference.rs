//! `bench track`'s learning against the independent reference
//! `tests/data/ilc_reference.py` (python-control, the SR4DoF model of
//! `make_reference.py`): the monotonic-convergence factor
//! `|1 − α·PS/PS_model|` of every learned harmonic, and the RMS tracking
//! error of the feedforward trial and of each learning trial after it, for
//! a model 15 % off the plant in mass and 14 % in bearing stiffness.
//!
//! `bench`'s side runs the trials as the loop runs them, tick by tick in
//! the time domain (the zero-order-hold plant of the simulator, noise-free,
//! the discrete controller, [`TrackJob`]), and learns with
//! [`Learning::update`] from each trial's measured lines, as `bench track`
//! does. They agree within 1e-3 (2026-11-29); the test asks 1 % (the issue: 10 %).

use crate::common::loop_reference::{python, INSTALL_HINT};
use bench::config::BenchConfig;
use bench::control::verify::ModelLoop;
use bench::control::DiscreteController;
use bench::ident::C64;
use bench::rt::Job;
use bench::track::{model_inverse, Harmonics, Learning, Scan, ScanKind, TrackJob};
use bench_hal::Sample;
use bench_plant::model::Sr4dof;
use bench_plant::sim::ZohPlant;
use nalgebra::SVector;
use serde_json::{json, Value};
use std::path::Path;
use std::process::Command;

fn ch5() -> BenchConfig {
    BenchConfig::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"))
        .unwrap()
}

const LINES: u64 = 8;
const MEASURED: usize = 4;

/// One trial in the time domain, noise-free: the mean measured line of
/// the error (the last `MEASURED` full lines before the fade-out).
fn trial(plant: &ZohPlant, ctrl: DiscreteController, r: &[f64], f: &[f64]) -> Vec<f64> {
    let n = r.len();
    let mut job = TrackJob::new(ctrl, r.to_vec(), f.to_vec(), LINES);
    let mut x = SVector::<f64, 9>::zeros();
    let e: Vec<f64> = (0..job.total_ticks())
        .map(|k| {
            let y = x[0];
            let s = Sample {
                seq: k,
                device_time_ns: 0,
                position_m: y,
                measured_current_a: f64::NAN,
                flags: Default::default(),
            };
            let out = job.tick(k, &s);
            plant.step(&mut x, out.command_a, 0.0);
            out.setpoint_m - y
        })
        .collect();
    let end = LINES as usize * n;
    (0..n)
        .map(|i| (1..=MEASURED).map(|p| e[end - p * n + i]).sum::<f64>() / MEASURED as f64)
        .collect()
}

fn rms(x: &[f64]) -> f64 {
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

fn reference(case: &Value) -> Value {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("case.json");
    std::fs::write(&input, serde_json::to_vec(case).unwrap()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/ilc_reference.py");
    let py = python();
    let out = Command::new(&py)
        .arg(&script)
        .arg(&input)
        .output()
        .unwrap_or_else(|e| panic!("cannot run `{py}` ({e}): {INSTALL_HINT}"));
    assert!(
        out.status.success(),
        "{}\n{INSTALL_HINT}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn learning_converges_as_python_control_predicts() {
    let cfg = ch5();
    let mut model_params = cfg.plant;
    model_params.m1_kg *= 1.15;
    model_params.k4_n_per_m = 31.0e3;
    model_params.k5_n_per_m = 31.0e3;
    let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
    let truth = ZohPlant::new(&Sr4dof::new(cfg.plant).unwrap(), &cfg.actuator, period_s);
    let model = ZohPlant::new(&Sr4dof::new(model_params).unwrap(), &cfg.actuator, period_s);
    let ctrl = DiscreteController::new(&cfg.controller["fast"], period_s, 1e3);
    let (line_hz, alpha, trials) = (10.0, 0.5, 5usize);
    let scan = Scan {
        kind: ScanKind::Triangle,
        move_limits: None,
        amplitude_m: 5e-6,
        line_rate_hz: line_hz,
        cutoff_hz: 58.0,
        reference_csv: None,
        reference: None,
    };
    let n = (cfg.loop_.rate_hz / line_hz).round() as usize;
    let k_max = scan.k_max();
    fn on<'a>(p: &'a ZohPlant, ctrl: &'a DiscreteController) -> ModelLoop<'a> {
        ModelLoop {
            plant: p,
            ctrl,
            link_delay_periods: 0,
        }
    }
    let r = scan.harmonics(n);
    let learning = Learning::new(&on(&model, &ctrl), alpha, k_max, line_hz);
    let ps_true: Vec<C64> = (0..=k_max)
        .map(|k| on(&truth, &ctrl).process_sensitivity(k as f64 * line_hz))
        .collect();
    let contraction = learning.contraction(&ps_true);

    let r_t = r.synthesize();
    let feedback = rms(&trial(&truth, ctrl, &r_t, &vec![0.0; n]));
    let mut f = model_inverse(&r, &on(&model, &ctrl), line_hz);
    let mut got = Vec::new();
    for _ in 0..=trials {
        let e = trial(&truth, ctrl, &r_t, &f.synthesize());
        got.push(rms(&e));
        f = learning.update(&f, &Harmonics::analyze(&e, k_max));
    }

    let want = reference(&json!({
        "true_plant": cfg.plant,
        "model_plant": model_params,
        "actuator": cfg.actuator,
        "controller": cfg.controller["fast"],
        "rate_hz": cfg.loop_.rate_hz,
        "line_rate_hz": line_hz,
        "amplitude_m": 5e-6,
        "cutoff_hz": 58.0,
        "learning_gain": alpha,
        "trials": trials,
    }));
    let near = |a: f64, b: f64| (a / b - 1.0).abs() < 0.01;
    let want_c: Vec<f64> = want["contraction"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(want_c.len(), contraction.len());
    for (k, (a, b)) in contraction.iter().zip(&want_c).enumerate() {
        assert!(near(*a, *b), "harmonic {}: {a} against {b}", k + 1);
        assert!(*a < 1.0, "harmonic {}: {a} does not contract", k + 1);
    }
    let want_fb = want["feedback_rms_m"].as_f64().unwrap();
    assert!(
        near(feedback, want_fb),
        "feedback {feedback} against {want_fb}"
    );
    let want_rms: Vec<f64> = want["rms_m"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    eprintln!("feedback {feedback:.4e} (python {want_fb:.4e}); trials {got:?}; python {want_rms:?}; contraction {contraction:.3?} (python {want_c:.3?})");
    for (j, (a, b)) in got.iter().zip(&want_rms).enumerate() {
        assert!(near(*a, *b), "trial {j}: {a} against {b}");
    }
    // It converged: the last trial is a small part of the first.
    assert!(got[trials] < 0.1 * got[0], "{got:?}");
}
