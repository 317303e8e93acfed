//! Closed-loop costs: per-tick compute of the fast controller (Eq. 6-7)
//! plus the supervisor, with its p50/p99 from a histogram of single ticks,
//! what the metrics tap of `bench serve --metrics` adds to a tick, and a
//! whole closed-loop step in virtual time (simulated seconds per wall
//! second).

use bench::config::BenchConfig;
use bench::control::DiscreteController;
use bench::jobs::control::{run_control, ControlJob, ControlOptions};
use bench::outputs::{Existing, Origin, OutputPlan};
use bench::rt::supervisor::Supervisor;
use bench::rt::timing::Histogram;
use bench::rt::Job;
use bench_hal::{Sample, SampleFlags};
use criterion::{black_box, criterion_group, criterion_main, Criterion};
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};

fn config() -> (BenchConfig, std::path::PathBuf) {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    (BenchConfig::load(&p).unwrap(), p)
}

fn sample(k: u64) -> Sample {
    Sample {
        seq: k,
        device_time_ns: k * 200_000,
        position_m: 1e-6 * ((k % 97) as f64 * 0.01).sin(),
        measured_current_a: f64::NAN,
        flags: SampleFlags::default(),
    }
}

fn control(c: &mut Criterion) {
    let (cfg, path) = config();
    let info = bench_hal::DeviceInfo {
        name: "bench".into(),
        clock: bench_hal::Clock::Host,
        period_ns: cfg.loop_.period_ns(),
        peak_current_a: cfg.actuator.peak_current_a,
        continuous_current_a: cfg.actuator.continuous_current_a,
        probe_range_m: cfg.probe.range_m,
        probe_lsb_m: 0.0,
        watchdog_s: None,
    };
    let ctrl = DiscreteController::new(&cfg.controller["fast"], 2e-4, info.peak_current_a);
    let mut job = ControlJob::new(ctrl, 1e-5, 10, 0, u64::MAX);
    let mut sup = Supervisor::new(cfg.supervisor(&info));
    sup.enabled();
    sup.running();

    // p50/p99 of single ticks (Instant overhead included, ~20 ns).
    let mut h = Histogram::default();
    for k in 0..1_000_000u64 {
        let s = sample(k);
        let t0 = Instant::now();
        sup.check_sample(&s);
        let out = job.tick(k, &s);
        black_box(sup.command(out.command_a));
        h.record(t0.elapsed().as_nanos() as u64);
    }
    println!(
        "control/fast_tick_single: p50 {:.0} ns, p99 {:.0} ns, max {:.0} ns (HDR histogram, ≤ 1 % above, 1e6 ticks)",
        h.quantile_ns(0.5),
        h.quantile_ns(0.99),
        h.max_ns()
    );

    let mut g = c.benchmark_group("control");
    let mut k = 0u64;
    g.bench_function("fast_controller_plus_supervisor_tick", |b| {
        b.iter(|| {
            k += 1;
            let s = sample(k);
            sup.check_sample(&s);
            let out = job.tick(k, &s);
            sup.command(out.command_a)
        })
    });

    // The probe-validity rules' share of the supervisor's sample check:
    // the same check with the rules on (the shipped bench's settings) and
    // off; the difference is their cost per tick (issue 46: ≤ 50 ns). The
    // reading follows the quasi-static model at 0.1 A with the probe's
    // noise-sized wiggle, so neither rule trips and both run in full.
    let mut on_cfg = cfg.supervisor(&info);
    on_cfg.probe = cfg.probe_validity(&info, info.continuous_current_a);
    assert!(on_cfg.probe.plausibility.is_some() && on_cfg.probe.frozen_samples < 100);
    let mut off_cfg = on_cfg;
    off_cfg.probe = bench::rt::supervisor::ProbeValidity::OFF;
    for (name, sc) in [
        ("probe_validity_on", on_cfg),
        ("probe_validity_off", off_cfg),
    ] {
        let mut sup = Supervisor::new(sc);
        sup.enabled();
        sup.running();
        let mut k = 0u64;
        g.bench_function(name, |b| {
            b.iter(|| {
                k += 1;
                let mut s = sample(k);
                s.position_m = 15.44e-6 + 4e-8 * ((k % 89) as f64 * 0.7).sin();
                black_box(sup.check_sample(black_box(&s)));
                sup.command(black_box(0.1))
            })
        });
        assert!(sup.fault().is_none(), "{name}: {:?}", sup.fault());
    }

    // The metrics tap's work on a real-time tick: two bucket searches, the
    // counters, and an offer (a 700-byte push) every 500 ticks; the reader
    // drains the queue as the daemon's metrics thread does.
    let (mut tap, mut counts) = bench::rt::tap::loop_tap(200_000);
    let mut k = 0u64;
    g.bench_function("metrics_tap_tick", |b| {
        b.iter(|| {
            k += 1;
            tap.timed(
                black_box(5_000 + (k * 7919) % 40_000),
                black_box(1_800),
                false,
            );
            if tap.ticked(true, false) {
                tap.offer(None);
                while counts.pop().is_ok() {}
            }
        })
    });

    let dir = tempfile::tempdir().unwrap();
    let opts = ControlOptions {
        config: cfg.clone(),
        config_path: path,
        controller: "fast".into(),
        check_only: false,
        frf: None,
        override_check: false,
        out: dir.path().join("run.mcap"),
        plot: dir.path().join("run.step.png"),
        realtime: false,
        pace: None,
        seed: 1,
        progress: false,
        inject: None,
        backend: None,
        verify: None,
        catalogue: false,
    };
    g.sample_size(10).measurement_time(Duration::from_secs(15));
    g.bench_function("closed_loop_step_4s_virtual", |b| {
        // Every iteration writes the same files: --overwrite.
        let outputs = || {
            OutputPlan::new(Existing::Replace)
                .with_recording(&opts.out, Origin::Given)
                .with_output("plot", &opts.plot, Origin::Given)
        };
        b.iter(|| run_control(&opts, outputs(), Arc::new(AtomicBool::new(false)), None).unwrap())
    });
    g.finish();
}

criterion_group!(benches, control);
criterion_main!(benches);
