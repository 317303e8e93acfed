//! Issue 45, item 2: a fit never invents a mode. The default chirp's and
//! the default multisine's FRFs of the shipped Chapter 5 bench (its own
//! noise seeds) and of random hidden benches around it (as
//! `uncertainty.rs` draws them, and with every mass m1–m5 drawn within
//! ±15 % as well: the fit knows no mass, so the modes move and the pair's
//! spacing changes, [`hidden_masses`]) are fitted (`bench fit`); the fit must
//! find exactly the hidden model's modes in the actuator-to-probe path
//! (each within 1 % in frequency, one to one, none added; a mode outside
//! the path, whose residue is under `RESIDUE_RATIO` of the largest, may be
//! found or not) on ≥ 98 % of
//! them. A true mode the fit reports as undecided (`UndecidedMode`) counts
//! as found: the data could not decide it, and the fit said so. The seeds
//! are fixed: the same benches every run. A wrong fit must be flagged.

use super::uncertainty::{ch5, hidden, measure, period_s};
use bench::analysis::modal::modal_terms;
use bench::config::{BenchConfig, ExcitationKind};
use bench::ident::modal_fit::{fit, FrfData, ModalFit, Path as FitPath};
use bench_plant::model::Sr4dof;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

/// Seeds of the shipped bench, and random benches, per excitation.
const SHIPPED: u64 = 40;
const RANDOM: u64 = 160;

/// The hidden model's modes inside the excited band, Hz: those in the
/// actuator-to-probe path (a modal residue at least `RESIDUE_RATIO` of the
/// largest), which the fit must find, and the others, which it may.
pub(crate) fn true_modes(cfg: &BenchConfig) -> (Vec<f64>, Vec<f64>) {
    let model = Sr4dof::new(cfg.plant).unwrap();
    let band = cfg.chirp.f_start_hz..=cfg.chirp.f_end_hz;
    let (path, weak): (Vec<_>, Vec<_>) = modal_terms(&model)
        .into_iter()
        .filter(|t| band.contains(&t.frequency_hz))
        .partition(|t| t.in_path);
    let hz = |v: Vec<bench::analysis::modal::ModalTerm>| v.iter().map(|t| t.frequency_hz).collect();
    (hz(path), hz(weak))
}

/// [`hidden`] with the five masses drawn within ±15 % of the shipped ones
/// (their own stream: the rest of the bench is `hidden`'s).
pub(crate) fn hidden_masses(base: &BenchConfig, seed: u64) -> BenchConfig {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(45_500 + seed);
    let mut c = hidden(base, seed);
    let p = &mut c.plant;
    for m in [
        &mut p.m1_kg,
        &mut p.m2_kg,
        &mut p.m3_kg,
        &mut p.m4_kg,
        &mut p.m5_kg,
    ] {
        *m *= rng.random_range(0.85..1.15);
    }
    c
}

fn multisine(cfg: &BenchConfig) -> BenchConfig {
    let mut c = cfg.clone();
    c.excitation.kind = ExcitationKind::Multisine;
    c.chirp.duration_s = None;
    c.chirp.taper_s = None;
    c
}

/// The true modes (indices into `truth`) that no fitted mode of `found`
/// matches, and the fitted modes (indices into `found`) that match no
/// true mode (nor a `weak` one): one to one, each true mode taking the
/// nearest fitted mode not yet taken within 1 % (one fitted mode between
/// a close pair is one).
pub(crate) fn matching(truth: &[f64], weak: &[f64], found: &[f64]) -> (Vec<usize>, Vec<usize>) {
    let mut taken = vec![false; found.len()];
    let mut missed = Vec::new();
    for (j, &t) in truth.iter().enumerate() {
        let best = (0..found.len())
            .filter(|&i| !taken[i] && (found[i] / t).ln().abs() < 0.01)
            .min_by(|&a, &b| {
                (found[a] / t)
                    .ln()
                    .abs()
                    .total_cmp(&(found[b] / t).ln().abs())
            });
        match best {
            Some(i) => taken[i] = true,
            None => missed.push(j),
        }
    }
    let invented = (0..found.len())
        .filter(|&i| !taken[i] && !weak.iter().any(|t| (found[i] / t).ln().abs() < 0.01))
        .collect();
    (missed, invented)
}

/// What one fit found against the truth: `None` when it found exactly
/// the true modes (a true mode it reports as undecided, within 1 %, counts
/// as found: the fit said the data cannot decide it), else why not.
pub(crate) fn judge(truth: &[f64], weak: &[f64], fit: Option<&ModalFit>) -> Option<String> {
    let Some(f) = fit else {
        return Some("no fit".into());
    };
    let found: Vec<f64> = f.modes.iter().map(|m| m.frequency_hz).collect();
    let undecided: Vec<f64> = f
        .quality
        .undecided_modes
        .iter()
        .map(|m| m.frequency_hz)
        .collect();
    let (missed, invented) = matching(truth, weak, &found);
    let missed: Vec<f64> = missed.iter().map(|&i| truth[i]).collect();
    let invented = invented.len();
    let said = missed
        .iter()
        .all(|t| undecided.iter().any(|g| (g / t).ln().abs() < 0.01));
    (invented > 0 || !said).then(|| {
        format!(
            "truth {truth:.2?} Hz, fitted {found:.2?} Hz, undecided {undecided:.2?} Hz{}",
            if f.trusted() { "" } else { " (flagged)" }
        )
    })
}

/// A fit that went wrong: why, and whether it was trusted.
type Wrong = (String, bool);

/// The fits that went wrong (why, and whether the fit was trusted), and
/// the undecided modes reported that are no true mode.
fn survey(kind: &str) -> (Vec<Wrong>, Vec<String>) {
    let base = ch5();
    let base = if kind == "multisine" {
        multisine(&base)
    } else {
        base
    };
    let path = FitPath {
        period_s: period_s(&base),
        amplifier_bandwidth_hz: base.actuator.bandwidth_hz,
    };
    let benches: Vec<(String, BenchConfig, u64)> = (0..SHIPPED)
        .map(|s| (format!("shipped, noise seed {s}"), base.clone(), 45_000 + s))
        .chain((0..RANDOM).map(|s| {
            (
                format!("hidden bench {}", 450 + s),
                hidden_masses(&base, 450 + s),
                46_000 + s,
            )
        }))
        .collect();
    let results: Vec<(Option<Wrong>, Vec<String>)> = benches
        .par_iter()
        .map(|(name, cfg, seed)| {
            let frf = measure(cfg, *seed);
            let f = fit(&FrfData::from_frf(&frf), &path).ok();
            let (truth, weak) = true_modes(cfg);
            let spurious = f
                .iter()
                .flat_map(|f| &f.quality.undecided_modes)
                .filter(|m| {
                    !truth
                        .iter()
                        .chain(&weak)
                        .any(|t| (m.frequency_hz / t).ln().abs() < 0.01)
                })
                .map(|m| format!("{kind}, {name}: {}", m.line()))
                .collect();
            let trusted = f.as_ref().is_some_and(ModalFit::trusted);
            let wrong = judge(&truth, &weak, f.as_ref())
                .map(|why| (format!("{kind}, {name}: {why}"), trusted));
            (wrong, spurious)
        })
        .collect();
    (
        results.iter().filter_map(|r| r.0.clone()).collect(),
        results.into_iter().flat_map(|r| r.1).collect(),
    )
}

/// At least 98 % of the fits right, and none wrong without a flag; at
/// most 10 % report an undecided mode that is no true mode (the report's
/// level is crossed by the path model's error and the heavy tails of few
/// realizations: see `UndecidedMode`).
fn check(kind: &str) {
    let (wrong, spurious) = survey(kind);
    let confident: Vec<&String> = wrong.iter().filter(|w| w.1).map(|w| &w.0).collect();
    let wrong: Vec<String> = wrong.iter().map(|w| w.0.clone()).collect();
    let n = (SHIPPED + RANDOM) as usize;
    eprintln!(
        "{kind}: {} of {n} fits found exactly the true modes; {} reported an undecided mode that is none",
        n - wrong.len(),
        spurious.len()
    );
    for w in wrong.iter().chain(&spurious) {
        eprintln!("  {w}");
    }
    assert!(wrong.len() * 50 <= n, "{wrong:#?}");
    assert!(spurious.len() * 10 <= n, "{spurious:#?}");
    assert!(
        confident.is_empty(),
        "wrong and not flagged: {confident:#?}"
    );
}

#[test]
fn the_default_chirp_s_fit_finds_exactly_the_true_modes() {
    check("chirp");
}

#[test]
fn the_default_multisine_s_fit_finds_exactly_the_true_modes() {
    check("multisine");
}
