//! The scan against its analytic shape, and the feedforward and the
//! learning law of the frequency domain against a simulation of the loop in
//! the time domain (the zero-order-hold plant stepped tick by tick with the
//! controller and [`TrackJob`] as the loop runs them).

use super::*;
use crate::config::BenchConfig;
use bench_plant::model::Sr4dof;
use bench_plant::sim::ZohPlant;
use nalgebra::SVector;

fn ch5() -> BenchConfig {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    BenchConfig::load(&path).unwrap()
}

struct Bench {
    plant: ZohPlant,
    ctrl: DiscreteController,
    period_s: f64,
    zeros: Vec<crate::analysis::modal::TypedZero>,
}

fn bench() -> Bench {
    let cfg = ch5();
    let model = Sr4dof::new(cfg.plant).unwrap();
    let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
    Bench {
        plant: ZohPlant::new(&model, &cfg.actuator, period_s),
        ctrl: DiscreteController::new(&cfg.controller["fast"], period_s, 1e3),
        period_s,
        zeros: crate::analysis::modal::damped_zeros(&model),
    }
}

impl Bench {
    fn model(&self) -> ModelLoop<'_> {
        ModelLoop {
            plant: &self.plant,
            ctrl: &self.ctrl,
            link_delay_periods: 0,
        }
    }

    /// The loop in the time domain, noise-free: the reading of tick `k`
    /// answers the commands before it (as the simulator's stage does).
    /// Returns the error `setpoint − reading` of every tick.
    fn run(&self, mut job: TrackJob) -> Vec<f64> {
        let mut x = SVector::<f64, 9>::zeros();
        (0..job.total_ticks())
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
                self.plant.step(&mut x, out.command_a, 0.0);
                out.setpoint_m - y
            })
            .collect()
    }
}

/// The mean period of `e` over its last `m` whole periods of `n` ticks
/// at full amplitude (before the job's fade-out and hold, two periods).
fn last_periods(e: &[f64], n: usize, m: usize) -> Vec<f64> {
    let start = e.len() - (m + 2) * n;
    (0..n)
        .map(|i| (0..m).map(|p| e[start + p * n + i]).sum::<f64>() / m as f64)
        .collect()
}

fn rms(x: &[f64]) -> f64 {
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

#[test]
fn the_sine_scan_is_the_sine() {
    let scan = Scan {
        kind: ScanKind::Sine,
        move_limits: None,
        amplitude_m: 5e-6,
        line_rate_hz: 10.0,
        cutoff_hz: 50.0,
        reference_csv: None,
        reference: None,
    };
    let x = scan.harmonics(500).synthesize();
    for (i, v) in x.iter().enumerate() {
        let want = 5e-6 * (2.0 * PI * i as f64 / 500.0).sin();
        assert!((v - want).abs() < 1e-15, "{i}: {v} {want}");
    }
}

/// With a far cut-off the smoothed triangle is the triangle within
/// Lanczos' smoothing (a corner rounded over about one period of the
/// cut-off); it keeps no harmonic at or above the cut-off, and the
/// analysis of its samples gives back its harmonics.
#[test]
fn the_triangle_scan_is_the_triangle_below_its_cut_off() {
    let a = 5e-6;
    let n = 2000;
    let scan = Scan {
        kind: ScanKind::Triangle,
        move_limits: None,
        amplitude_m: a,
        line_rate_hz: 10.0,
        cutoff_hz: 2000.0,
        reference_csv: None,
        reference: None,
    };
    let h = scan.harmonics(n);
    assert_eq!(h.coef.len() - 1, 199);
    let x = h.synthesize();
    // The exact triangle: 0 at the start, rising to A at a quarter period.
    let tri = |t: f64| {
        let p = t.rem_euclid(1.0);
        if p < 0.25 {
            4.0 * a * p
        } else if p < 0.75 {
            a * (2.0 - 4.0 * p)
        } else {
            a * (4.0 * p - 4.0)
        }
    };
    let worst = x
        .iter()
        .enumerate()
        .map(|(i, v)| (v - tri(i as f64 / n as f64)).abs())
        .fold(0.0, f64::max);
    // Corner rounding: the slope 4A per period times about 1/k_c periods.
    assert!(worst < 4.0 * a / 200.0, "{worst}");
    assert!(worst > 0.0);
    let back = Harmonics::analyze(&x, 199);
    for (k, (c, d)) in back.coef.iter().zip(&h.coef).enumerate() {
        assert!((c - d).norm() < 1e-18, "{k}");
    }
    let coarse = Scan {
        cutoff_hz: 55.0,
        ..scan.clone()
    };
    assert_eq!(coarse.k_max(), 5);
    let one = Scan {
        cutoff_hz: 50.0,
        ..scan
    };
    assert_eq!(one.k_max(), 4, "50 Hz itself is cut");
}

/// The Chapter 5 bench's CNMP pair (thesis: ≈ 83 Hz) closes a band of
/// about 59–102 Hz; a 10 Hz triangle's 70 Hz and 90 Hz harmonics fall in
/// it, its 50 Hz one does not.
#[test]
fn the_cnmp_pair_of_chapter_5_closes_its_band() {
    let b = bench();
    let bands = ZeroBand::of(&b.zeros);
    let cnmp: Vec<&ZeroBand> = bands.iter().filter(|z| z.kind == "CMP-CNMP").collect();
    assert_eq!(cnmp.len(), 1, "{bands:?}");
    let z = cnmp[0];
    assert!((80.0..87.0).contains(&z.zero_hz), "{z:?}");
    assert!(
        z.contains(70.0) && z.contains(90.0) && !z.contains(50.0),
        "{z:?}"
    );
    // At the band's edges the pair's factor |1 − ω²/|z|²| is ½.
    for f in [z.low_hz, z.high_hz] {
        let factor = (1.0 - (f / z.zero_hz).powi(2)).abs();
        assert!((factor - 0.5).abs() < 1e-12, "{factor}");
    }
}

/// The model-inverse feedforward, played by the job around the
/// time-domain loop, leaves of a 10 Hz triangle's tracking error less
/// than 1e-4 of what feedback alone leaves after eight periods (what is
/// left is the fade-in's transient in the lightly damped modes) (the frequency-domain algebra
/// `e = S(r − Pf)` checked against the loop stepped tick by tick).
#[test]
fn the_model_inverse_tracks_the_scan_on_the_model() {
    let b = bench();
    let n = (0.1 / b.period_s).round() as usize;
    let scan = Scan {
        kind: ScanKind::Triangle,
        move_limits: None,
        amplitude_m: 5e-6,
        line_rate_hz: 10.0,
        cutoff_hz: 55.0,
        reference_csv: None,
        reference: None,
    };
    let r = scan.harmonics(n);
    let f = model_inverse(&r, &b.model(), scan.line_rate_hz);
    let total = 8;
    let alone = b.run(TrackJob::new(b.ctrl, r.synthesize(), vec![0.0; n], total));
    let with = b.run(TrackJob::new(b.ctrl, r.synthesize(), f.synthesize(), total));
    let e_alone = last_periods(&alone, n, 2);
    let e_with = last_periods(&with, n, 2);
    // Feedback alone: the error is S·r, predicted harmonic by harmonic.
    let (_, e_pred) = predict(&r, &Harmonics::zeros(r.coef.len() - 1, n), &b.model(), 10.0);
    let pred = e_pred.synthesize();
    let dev = e_alone
        .iter()
        .zip(&pred)
        .map(|(a, p)| (a - p).abs())
        .fold(0.0, f64::max);
    assert!(dev < 1e-3 * rms(&pred), "{dev} of {}", rms(&pred));
    assert!(rms(&e_alone) > 1e-8, "{}", rms(&e_alone));
    assert!(
        rms(&e_with) < 1e-4 * rms(&e_alone),
        "{} {}",
        rms(&e_with),
        rms(&e_alone)
    );
}

/// Each learning trial multiplies a learned harmonic's error by
/// `1 − α·PS/PS_model`: on the model itself by `1 − α`. Starting from no
/// feedforward, trial `j`'s error is `(1 − α)^j` of the first one's, in
/// the time-domain loop.
#[test]
fn learning_contracts_by_one_minus_the_gain_on_the_model() {
    let b = bench();
    let n = (0.1 / b.period_s).round() as usize;
    let scan = Scan {
        kind: ScanKind::Triangle,
        move_limits: None,
        amplitude_m: 5e-6,
        line_rate_hz: 10.0,
        cutoff_hz: 55.0,
        reference_csv: None,
        reference: None,
    };
    let r = scan.harmonics(n);
    let k_max = r.coef.len() - 1;
    let alpha = 0.6;
    let learning = Learning::new(&b.model(), alpha, k_max, 10.0);
    let ps: Vec<C64> = learning.ps_model.clone();
    for c in learning.contraction(&ps) {
        assert!((c - (1.0 - alpha)).abs() < 1e-12, "{c}");
    }
    let mut f = Harmonics::zeros(k_max, n);
    let mut first = 0.0;
    for j in 0..4 {
        let e = b.run(TrackJob::new(
            b.ctrl,
            r.synthesize(),
            f.synthesize(),
            8 * n as u64,
        ));
        let e = Harmonics::analyze(&last_periods(&e, n, 2), k_max);
        let size = e.coef[1..].iter().map(|c| c.norm_sqr()).sum::<f64>().sqrt();
        if j == 0 {
            first = size;
        } else {
            let want = first * (1.0 - alpha).powi(j);
            assert!((size / want - 1.0).abs() < 1e-3, "trial {j}: {size} {want}");
        }
        f = learning.update(&f, &e);
    }
}

/// The job plays both tables from the first finite reading, faded in over
/// the first period, then periodic to the end of its lines, faded out over
/// one period and held at the start for one more; it ends there.
#[test]
fn the_job_plays_its_tables_periodically_between_its_fades() {
    let b = bench();
    let r: Vec<f64> = (0..10).map(|i| i as f64 * 1e-7).collect();
    let f: Vec<f64> = (0..10).map(|i| i as f64 * 1e-2).collect();
    let mut job = TrackJob::new(b.ctrl, r.clone(), f.clone(), 3);
    assert_eq!(job.total_ticks(), 50);
    for k in 0..50u64 {
        let s = Sample {
            seq: k,
            device_time_ns: 0,
            position_m: if k == 0 { f64::NAN } else { 2e-6 },
            measured_current_a: f64::NAN,
            flags: Default::default(),
        };
        let out = job.tick(k, &s);
        let i = (k % 10) as usize;
        let w = match k {
            0..10 => 0.5 * (1.0 - (PI * k as f64 / 10.0).cos()),
            10..30 => 1.0,
            30..40 => 0.5 * (1.0 + (PI * (k - 30) as f64 / 10.0).cos()),
            _ => 0.0,
        };
        assert_eq!(out.excitation_a, w * f[i], "{k}");
        let start = if k == 0 { 0.0 } else { 2e-6 };
        assert!((out.setpoint_m - start - w * r[i]).abs() < 1e-18, "{k}");
        assert_eq!(out.done, k == 49);
    }
}

/// What the learning leaves alone: on the Chapter 5 bench at 10 lines/s
/// the harmonics inside a zero's band (20 Hz in the MMP pair's 16.0–27.6
/// Hz; 60–100 Hz in the CNMP pair's 58.9–102.0 Hz), and any harmonic whose
/// error is within 2σ of its noise.
#[test]
fn learning_leaves_out_the_zero_bands_and_the_noise() {
    let b = bench();
    let model = b.model();
    let bands = ZeroBand::of(&b.zeros);
    let mut learning = Learning::new(&model, 0.5, 12, 10.0);
    let out = learning.leave_out_bands(&bands, 10.0);
    assert_eq!(out, vec![2, 6, 7, 8, 9, 10]);
    assert!(learning.learns(1) && learning.learns(3) && learning.learns(11));
    assert!(!learning.learns(0) && !learning.learns(2));
    let n = 500;
    let f = Harmonics::zeros(12, n);
    let mut e = Harmonics::zeros(12, n);
    e.coef[1] = C64::new(3e-9, 0.0);
    e.coef[3] = C64::new(0.0, 1.9e-9);
    let sigma = vec![1e-9; 13];
    let next = learning.update_significant(&f, &e, &sigma);
    assert!(next.coef[1].norm() > 0.0, "3σ is learned");
    assert_eq!(next.coef[3], f.coef[3], "1.9σ is noise");
    // One line: no σ, everything learned.
    let next = learning.update_significant(&f, &e, &[f64::NAN; 13]);
    assert!(next.coef[3].norm() > 0.0);
}

/// A 10 µm move and back (the default limits, 25 ms) at 1 line/s in the
/// noise-free time-domain loop: with the model's inverse up to 408 Hz
/// (inside the CNMP band too: stable inversion, a line of preview) the
/// error stays within ±10 nm throughout, where feedback alone leaves
/// micrometres.
#[test]
fn the_inverse_carries_a_move_through_the_zeros_band() {
    let b = bench();
    let n = (1.0 / b.period_s).round() as usize;
    let scan = Scan {
        kind: ScanKind::Move,
        move_limits: Some(MoveLimits {
            velocity_m_s: 1e-3,
            acceleration_m_s2: 0.1,
            jerk_m_s3: 40.0,
            snap_m_s4: Some(2e4),
        }),
        amplitude_m: 10e-6,
        line_rate_hz: 1.0,
        cutoff_hz: 408.0,
        reference_csv: None,
        reference: None,
    };
    let table = scan.table(n);
    assert_eq!(table[0], 0.0);
    assert!((table[n / 4] - 10e-6).abs() < 1e-15);
    let r = scan.harmonics(n);
    let f = model_inverse(&r, &b.model(), 1.0);
    let alone = b.run(TrackJob::new(b.ctrl, table.clone(), vec![0.0; n], 4));
    let with = b.run(TrackJob::new(b.ctrl, table, f.synthesize(), 4));
    let peak = |e: &[f64]| e.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let (a, w) = (last_periods(&alone, n, 2), last_periods(&with, n, 2));
    assert!(peak(&a) > 1e-6, "{}", peak(&a));
    assert!(peak(&w) < 10e-9, "{}", peak(&w));
}

/// The derivatives' gains are the Taylor series of the model's `1/P` at
/// 0 Hz: `c₀` is `1/P` at a millihertz, and the polynomial matches `1/P`
/// on its fit band within 0.1 %.
#[test]
fn the_snap_gains_are_the_inverse_plants_series() {
    let b = bench();
    let m = b.model();
    let g = DerivativeGains::fit(&m, 22.6);
    let dc = (1.0 / m.plant(1e-3)).re;
    assert!((g.gains[0] / dc - 1.0).abs() < 1e-4, "{g:?} {dc}");
    assert!(g.gains[2] > 0.0, "a mass: {g:?}");
    for f in [0.3, 1.0, 3.0, 6.0] {
        let poly = g.at(f);
        let inv = 1.0 / m.plant(f);
        assert!(
            (poly - inv).norm() < 1e-3 * inv.norm(),
            "{f} Hz: {poly} {inv}"
        );
    }
}

/// The law on a measured PS: where the measurement is the loop's own PS
/// (the model's, sampled on a 400-a-decade grid) with a 1σ of `s·|PS|`,
/// `L_k` inverts it (`1 − L·PS = 1 − α` within the interpolation's
/// error), the bound is `(1 − α) + 2α·s`, and a harmonic is learned only
/// where that is below 1 and a coherent line brackets it: a relative 1σ
/// of 0.6 (bound 1.14 at α 0.7) or an incoherent line leaves it alone.
#[test]
fn the_measured_law_inverts_the_measurement_and_learns_only_what_it_vouches_for() {
    use super::measured::{learning, margin, MeasuredPs};
    let b = bench();
    let model = b.model();
    let f = crate::ident::frf::log_grid(1.0, 1000.0, 400);
    let ps: Vec<C64> = f.iter().map(|&f| model.process_sensitivity(f)).collect();
    let rel = |f: f64| if (38.0..42.0).contains(&f) { 0.6 } else { 0.01 };
    let mut m = MeasuredPs {
        sigma_m_per_a: f.iter().zip(&ps).map(|(&f, p)| rel(f) * p.norm()).collect(),
        counts: vec![true; f.len()],
        frequency_hz: f.clone(),
        ps,
    };
    let i = f.partition_point(|&x| x < 30.0);
    m.counts[i] = false;
    let alpha = 0.7;
    let (law, checks) = learning(&m, &model, alpha, 5, 10.0);
    for c in &checks {
        let f_hz = c.frequency_hz;
        let k = c.harmonic;
        let true_ps = model.process_sensitivity(f_hz);
        match k {
            3 => assert!(!c.learned && c.contraction_bound.is_none() && !law.learns(3)),
            4 => {
                let bound = c.contraction_bound.unwrap();
                assert!(
                    (bound - (1.0 - alpha + 2.0 * alpha * 0.6)).abs() < 1e-2,
                    "{bound}"
                );
                assert!(!c.learned && !law.learns(4));
            }
            _ => {
                assert!(c.learned && law.learns(k), "{c:?}");
                let contraction = (C64::new(1.0, 0.0) - law.l[k] * true_ps).norm();
                assert!(
                    (contraction - (1.0 - alpha)).abs() < 2e-3,
                    "{k}: {contraction}"
                );
                let bound = c.contraction_bound.unwrap();
                assert!(
                    (bound - (1.0 - alpha + 2.0 * alpha * 0.01)).abs() < 1e-3,
                    "{bound}"
                );
            }
        }
    }
    let (mg, at) = margin(&checks).unwrap();
    assert!(
        (mg - (alpha - 2.0 * alpha * 0.01)).abs() < 1e-3,
        "{mg} at {at}"
    );
}

/// A CSV scan read back from JSON has no line (the JSON leaves it out): it
/// stands still rather than recursing between its table and its
/// harmonics.
#[test]
fn a_csv_scan_without_its_line_stands_still() {
    let scan = Scan {
        kind: ScanKind::Csv,
        move_limits: None,
        amplitude_m: 5e-6,
        line_rate_hz: 10.0,
        cutoff_hz: 55.0,
        reference_csv: Some("line.csv".into()),
        reference: None,
    };
    let back: Scan = serde_json::from_str(&serde_json::to_string(&scan).unwrap()).unwrap();
    assert_eq!(back.table(500), vec![0.0; 500]);
    assert!(back.harmonics(500).coef.iter().all(|c| c.norm() == 0.0));
}
