//! Issue 28: numbers a researcher can trust, checked against the truth
//! that made the data.
//!
//! Random hidden benches around the Chapter 5 bench (the parallelogram
//! stiffness ±25 %, the mass asymmetry −12 … +12 %, both damping ratios,
//! the force constant ±20 %, the operating point 2–9 % of L; the masses
//! and X bearings known), each measured the way `bench chirp` measures it
//! (the shipped chirp played into the simulator with its probe noise and
//! quantisation, the configured FRF estimator), then fitted (`bench fit`)
//! and updated (`bench fit --update`, from the textbook stiffness
//! 24 E I / L³, no asymmetry, the shipped damping and force constant).
//! The seeds are fixed: the same benches every run.
//!
//! - **Coverage.** For every reported quantity — each fitted mode's
//!   frequency, damping ratio and modal constant against the hidden
//!   model's (frequency, damping, force constant × residue of Eq. 4-15),
//!   and the update's stiffness, Δm23 and force constant against the hidden
//!   values — the truth lies within the stated 2σ for ≥ 90 % and within 3σ
//!   for ≥ 98 % of the benches whose result is not flagged.
//! - **No silent wrong answer.** On ≥ 200 benches, no update is off by more
//!   than 5σ in any parameter without a flag on the fit or the update.

use bench::config::BenchConfig;
use bench::ident::bla::Bla;
use bench::ident::excitation::Excitation;
use bench::ident::frf::{fast_len, Frf, Spectra, C64};
use bench::ident::modal_fit::{fit, FrfData, ModalFit, Path as FitPath};
use bench::ident::update::{update_to_frf, Bench, Parameter, Update};
use bench_hal::{Command, Stage};
use bench_plant::model::Sr4dof;
use bench_plant::sim::{SimParams, SimStage};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use std::path::Path;
use std::sync::OnceLock;

/// Benches of the no-silent-failure test; the coverage test uses the
/// first [`COVERAGE_BENCHES`].
const BENCHES: usize = 200;
const COVERAGE_BENCHES: usize = 100;

pub(crate) fn ch5() -> BenchConfig {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    let c = BenchConfig::load(&p).unwrap();
    c.validate(&p).unwrap();
    c
}

pub(crate) fn period_s(cfg: &BenchConfig) -> f64 {
    cfg.loop_.period_ns() as f64 * 1e-9
}

/// The hidden bench of seed `seed`: the config it runs on.
pub(crate) fn hidden(base: &BenchConfig, seed: u64) -> BenchConfig {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(28_000 + seed);
    let mut c = base.clone();
    let p = &mut c.plant;
    p.parallelogram_stiffness_n_per_m =
        Some(p.parallelogram_stiffness_n_per_m.unwrap_or(8727.0) * rng.random_range(0.75..1.25));
    p.mass_asymmetry = rng.random_range(-0.12..0.12);
    p.operating_point_m = p.beam.length_m * rng.random_range(0.02..0.09);
    p.damping.zeta_rigid = rng.random_range(0.005..0.02);
    p.damping.zeta_csm = rng.random_range(0.002..0.008);
    c.actuator.force_constant_n_per_a *= rng.random_range(0.8..1.2);
    c
}

/// The FRF `bench chirp` estimates on `cfg`'s simulated bench (noise seed
/// `seed`): the excitation of `cfg` (its sweep, or its multisine with
/// phases from `seed`) played the way the loop plays it (read the sample,
/// command, keep both), the lead-in's mean taken off the reading; a
/// sweep's FRF by the configured estimator, a multisine's BLA.
pub(crate) fn measure(cfg: &BenchConfig, seed: u64) -> Frf {
    measure_with_holds(cfg, seed, &[])
}

/// [`measure`] with the link dropping samples unseen: over each
/// `(first_tick, ticks)` span the host keeps reading the last sample that
/// arrived and the stage keeps the last command it received (a serial
/// link's stall that no sequence number reveals).
pub(crate) fn measure_with_holds(cfg: &BenchConfig, seed: u64, holds: &[(u64, u64)]) -> Frf {
    let (record, excitation) = record_with_holds(cfg, seed, holds);
    if let Excitation::Multisine(ms) = &excitation {
        return Bla::estimate(&record, &ms.layout(), &[]).unwrap().to_frf();
    }
    let spectra = Spectra::from_record(
        record,
        1.0 / period_s(cfg),
        &cfg.identification,
        cfg.chirp.f_end_hz,
    );
    Frf::from_spectra(
        &spectra,
        cfg.chirp.f_start_hz,
        cfg.chirp.f_end_hz,
        &cfg.identification,
    )
    .unwrap()
}

/// The record [`measure_with_holds`] estimates from: (command A, reading
/// m) per tick, the lead-in's mean taken off the reading; and the
/// excitation played.
pub(crate) fn record_with_holds(
    cfg: &BenchConfig,
    seed: u64,
    holds: &[(u64, u64)],
) -> (Vec<C64>, Excitation) {
    let mut stage = SimStage::new(SimParams {
        plant: cfg.plant,
        actuator: cfg.actuator,
        probe: cfg.probe,
        mechanical_stop_m: cfg.stage.mechanical_stop_m,
        seed,
    })
    .unwrap();
    let excitation = Excitation::new(cfg, period_s(cfg), seed).unwrap();
    stage.configure(cfg.loop_.period_ns()).unwrap();
    stage.enable().unwrap();
    let n = excitation.total_ticks();
    let mut record = Vec::with_capacity(fast_len(n as usize));
    let (mut last_u, mut last_y) = (0.0, 0.0);
    for tick in 0..n {
        let s = stage.read_sample().unwrap();
        let held = holds
            .iter()
            .any(|&(first, len)| (first..first + len).contains(&tick));
        let (u, y) = if held {
            (last_u, last_y)
        } else {
            (excitation.value_a(tick), s.position_m)
        };
        stage
            .write_command(Command {
                current_a: u,
                answers_seq: s.seq,
            })
            .unwrap();
        (last_u, last_y) = (u, y);
        record.push(C64::new(excitation.value_a(tick), y));
    }
    let lead = (excitation.lead_in_ticks() as usize).max(1);
    let offset = record[..lead].iter().map(|z| z.im).sum::<f64>() / lead as f64;
    for z in &mut record {
        z.im -= offset;
    }
    (record, excitation)
}

/// One bench's truth and results.
struct Run {
    seed: u64,
    truth: BenchConfig,
    fit: Option<ModalFit>,
    update: Option<Update>,
}

fn run(base: &BenchConfig, seed: u64) -> Run {
    let truth = hidden(base, seed);
    let frf = measure(&truth, seed + 1);
    let data = FrfData::from_frf(&frf);
    let path = FitPath {
        period_s: period_s(base),
        amplifier_bandwidth_hz: base.actuator.bandwidth_hz,
    };
    let fitted = fit(&data, &path).ok();
    let mut start = base.plant;
    start.parallelogram_stiffness_n_per_m = None; // 24 E I / L³
    start.mass_asymmetry = 0.0;
    start.operating_point_m = truth.plant.operating_point_m;
    let start = Bench {
        plant: start,
        force_constant_n_per_a: base.actuator.force_constant_n_per_a,
    };
    let update = update_to_frf(
        &start,
        &Parameter::FRF_DEFAULT,
        &data,
        &path,
        fitted.as_ref(),
    )
    .ok();
    Run {
        seed,
        truth,
        fit: fitted,
        update,
    }
}

/// Every bench's run, computed once for both tests.
fn runs() -> &'static [Run] {
    static RUNS: OnceLock<Vec<Run>> = OnceLock::new();
    RUNS.get_or_init(|| {
        let base = ch5();
        (0..BENCHES as u64)
            .into_par_iter()
            .map(|s| run(&base, s))
            .collect()
    })
}

fn flagged(r: &Run) -> bool {
    r.fit.as_ref().is_none_or(|f| !f.trusted())
        || r.update.as_ref().is_none_or(|u| !u.flags.is_empty())
}

/// `(estimate − truth) / σ` of each updated parameter checked.
fn update_errors(r: &Run) -> Vec<(&'static str, f64)> {
    let Some(u) = &r.update else {
        return Vec::new();
    };
    let t = &r.truth;
    let value = |p: Parameter| {
        let q = u.parameters.iter().find(|q| q.name == p.name()).unwrap();
        (q.value, q.sigma.unwrap_or(f64::NAN))
    };
    [
        (
            "stiffness",
            Parameter::ParallelogramStiffness,
            t.plant.parallelogram_stiffness_n_per_m.unwrap(),
        ),
        (
            "mass asymmetry",
            Parameter::MassAsymmetry,
            t.plant.mass_asymmetry,
        ),
        (
            "force constant",
            Parameter::ForceConstant,
            t.actuator.force_constant_n_per_a,
        ),
    ]
    .into_iter()
    .map(|(name, p, truth)| {
        let (v, s) = value(p);
        (name, (v - truth) / s)
    })
    .collect()
}

/// `(estimate − truth) / σ` of each fitted mode's frequency, damping and
/// modal constant, against the hidden model's mode nearest in frequency.
fn fit_errors(r: &Run) -> Vec<(&'static str, f64)> {
    let Some(f) = &r.fit else { return Vec::new() };
    let model = Sr4dof::new(r.truth.plant).unwrap();
    let terms = bench::analysis::modal::modal_terms(&model);
    let kf = r.truth.actuator.force_constant_n_per_a;
    let mut out = Vec::new();
    for m in &f.modes {
        let Some(t) = terms.iter().min_by(|a, b| {
            (a.frequency_hz / m.frequency_hz)
                .ln()
                .abs()
                .total_cmp(&(b.frequency_hz / m.frequency_hz).ln().abs())
        }) else {
            continue;
        };
        out.push((
            "frequency",
            (m.frequency_hz - t.frequency_hz) / m.frequency_sigma_hz,
        ));
        out.push((
            "damping",
            (m.damping_ratio - t.damping_ratio) / m.damping_ratio_sigma,
        ));
        out.push((
            "modal constant",
            (m.modal_constant - t.residue_per_kg * kf) / m.modal_constant_sigma,
        ));
    }
    out
}

#[test]
fn stated_uncertainties_cover_the_truth() {
    let runs = &runs()[..COVERAGE_BENCHES];
    let trusted: Vec<&Run> = runs.iter().filter(|r| !flagged(r)).collect();
    if std::env::var_os("BENCH_SHOW_FLAGS").is_some() {
        for r in runs.iter().filter(|r| flagged(r)) {
            let f = r.fit.as_ref().map(|f| f.quality.flags.clone());
            let u = r.update.as_ref().map(|u| u.flags.clone());
            let p = &r.truth.plant;
            eprintln!(
                "seed {}: stiffness {:?} asym {} op {} zr {} zc {} kf {}: fit {f:?} update {u:?}",
                r.seed,
                p.parallelogram_stiffness_n_per_m,
                p.mass_asymmetry,
                p.operating_point_m,
                p.damping.zeta_rigid,
                p.damping.zeta_csm,
                r.truth.actuator.force_constant_n_per_a
            );
        }
    }
    assert!(
        trusted.len() * 10 >= runs.len() * 9,
        "only {} of {} benches unflagged",
        trusted.len(),
        runs.len()
    );
    if std::env::var_os("BENCH_SHOW_FLAGS").is_some() {
        let c: Vec<String> = trusted
            .iter()
            .take(20)
            .filter_map(|r| r.fit.as_ref()?.quality.chi2_per_dof)
            .map(|c| format!("{c:.2}"))
            .collect();
        eprintln!("χ²/ν of the first fits: {}", c.join(" "));
    }
    let mut table = std::collections::BTreeMap::<&str, Vec<f64>>::new();
    for r in &trusted {
        for (name, z) in fit_errors(r).into_iter().chain(update_errors(r)) {
            table.entry(name).or_default().push(z);
        }
    }
    let mut report = String::new();
    let mut bad = Vec::new();
    for (name, z) in &table {
        let n = z.len() as f64;
        let within = |k: f64| z.iter().filter(|z| z.abs() <= k).count() as f64 / n;
        let worst = z.iter().fold(0.0_f64, |m, z| m.max(z.abs()));
        report += &format!(
            "{name:<15} n {:>4}  within 2σ {:5.1} %  within 3σ {:5.1} %  worst {worst:.1}σ\n",
            z.len(),
            100.0 * within(2.0),
            100.0 * within(3.0)
        );
        if within(2.0) < 0.9 || within(3.0) < 0.98 {
            bad.push(*name);
        }
    }
    eprintln!("{report}");
    assert!(
        bad.is_empty(),
        "coverage below 90 % / 98 % for {bad:?}:\n{report}"
    );
}

#[test]
fn no_update_is_off_by_more_than_5_sigma_without_a_flag() {
    let runs = runs();
    assert_eq!(runs.len(), BENCHES);
    let mut silent = Vec::new();
    let mut flagged_count = 0;
    for r in runs {
        if flagged(r) {
            flagged_count += 1;
            continue;
        }
        for (name, z) in update_errors(r) {
            // NaN (no 1σ) counts as off.
            if z.is_nan() || z.abs() > 5.0 {
                silent.push(format!("seed {}: {name} off by {z:.1}σ", r.seed));
            }
        }
    }
    eprintln!(
        "{} benches, {flagged_count} flagged, {} silently off by more than 5σ",
        runs.len(),
        silent.len()
    );
    assert!(silent.is_empty(), "{silent:#?}");
}

/// The silent-wrong-update case kept in `tests/data/split-modes.toml`
/// (hidden bench seed 17 of this file, noise seed 18): measured as
/// `bench chirp` measures it, the fit splits a mode into two cancelling
/// halves; that is flagged, so the verdict does not decide from it, and
/// the update from it is flagged too. Through the binary: `bench chirp`
/// then `bench fit --update` exits 9 with the flag and writes no updated
/// bench.
#[test]
fn the_split_case_of_tests_data_is_flagged() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/split-modes.toml");
    let cfg = BenchConfig::load(&path).unwrap();
    cfg.validate(&path).unwrap();
    let base = ch5();
    let hidden17 = hidden(&base, 17);
    assert_eq!(cfg.plant, hidden17.plant, "the file is hidden bench 17");
    let r = run(&base, 17);
    let f = r.fit.as_ref().unwrap();
    assert!(
        f.quality
            .flags
            .iter()
            .any(|x| x.contains("one mode split in two")),
        "{:?}",
        f.quality
    );
    assert!(!r.update.as_ref().unwrap().flags.is_empty());

    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("split.mcap");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_bench"))
        .args(["chirp", "--config"])
        .arg(&path)
        .arg("--out")
        .arg(&rec)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_bench"))
        .arg("fit")
        .arg(&rec)
        .args(["--update", "--no-plot"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    eprintln!("{stdout}");
    if stdout.contains("one mode split in two") {
        assert_eq!(out.status.code(), Some(9), "{stdout}");
        assert!(!dir.path().join("split.updated.toml").exists());
    } else {
        // The loop's own record may differ from this file's by the
        // command's timing; then the fit must not be silently wrong.
        assert!(
            out.status.code() == Some(9) || !stdout.contains("FLAGGED"),
            "{stdout}"
        );
    }
}
