//! Issue 45, item 5: fits and verdicts on data as a real link gives it.
//! The shipped Chapter 5 bench (its own noise seeds) and random hidden
//! benches around it (`uncertainty.rs`'s draw: mass asymmetry of both
//! signs, so CMP-CNMP zeros or none), measured by the default chirp
//! (`uncertainty::measure`), fitted (`bench fit`) and judged (the verdict
//! of `bench chirp`), under three hostile conditions:
//!
//! - **noise**: the probe's white noise raised to 10 % of the RMS
//!   position the chirp makes on that bench (its noise-free record, the
//!   lead-in left out): 3.5–5.5 µm where the shipped probe has 40 nm, a
//!   median line 1.0–1.3 % of |H| in 1σ;
//! - **outlier lines**: 20 % of the lines, drawn at random, multiplied by
//!   `1 + r e^{jφ}` (r from 0.2 to 1, φ uniform), their stated σ and
//!   coherence left as they were (a corrupted block that the estimator
//!   does not know about);
//! - **dropped samples**: three 30 ms spans at random times during which
//!   the link delivers nothing and nothing tells the host: it reads the
//!   last sample that arrived, the stage keeps the last command.
//!
//! What must hold, on every fit: the verdict is the truth's (the hidden
//! model's zeros, Chapter 3) or `null` with a reason — never a confident
//! wrong verdict. With outlier lines or dropped samples, a fit that is
//! not flagged must also find the hidden model's in-path modes (each
//! within 1 %, one to one, none added): every such fit is flagged.
//!
//! At 10 % noise the pair (2–5 % apart) sinks under the noise on some
//! benches, and a fit that misses it is not flagged (its residual is
//! white and at the noise). What must hold there: every true in-path mode
//! a trusted fit missed is one the fit said it could miss — reported
//! undecided, in a fitted mode's unresolved band, or weaker than the
//! detection limit it states at that frequency
//! (`ModalFit::quality.detection_limit`) — and no trusted fit adds a
//! mode (one of 60 did, at 153 Hz, until a mode the data do not decide
//! was pruned). The verdicts are all `null` (no pair, or the phase
//! test's coherence and the residue test's confidence too low).

use super::mode_count::{judge, matching, true_modes};
use super::outliers::with_outliers;
use super::uncertainty::{ch5, hidden, measure, measure_with_holds, period_s, record_with_holds};
use bench::analysis::modal::modal_terms;
use bench::config::BenchConfig;
use bench::ident::frf::Frf;
use bench::ident::modal_fit::{fit, path_phase_deg, FrfData, Path as FitPath};
use bench::ident::verdict::{verdict, without_fit};
use bench_plant::model::Sr4dof;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

/// Benches per condition: the shipped bench's noise seeds, then hidden
/// benches.
const SHIPPED: u64 = 10;
const RANDOM: u64 = 50;
/// The noisy condition's probe noise against the chirp's RMS position.
const NOISE_TO_SIGNAL: f64 = 0.10;

#[derive(Clone, Copy, Debug)]
enum Condition {
    Noise,
    Outliers,
    Dropped,
}

fn measured(cfg: &BenchConfig, seed: u64, c: Condition) -> Frf {
    match c {
        Condition::Noise => {
            let mut c = cfg.clone();
            c.probe.noise_rms_m = 0.0;
            c.probe.quantization_m = 0.0;
            let (clean, excitation) = record_with_holds(&c, seed, &[]);
            let lead = excitation.lead_in_ticks() as usize;
            let y = &clean[lead..];
            let rms = (y.iter().map(|z| z.im * z.im).sum::<f64>() / y.len() as f64).sqrt();
            let mut c = cfg.clone();
            c.probe.noise_rms_m = NOISE_TO_SIGNAL * rms;

            measure(&c, seed)
        }
        Condition::Outliers => with_outliers(measure(cfg, seed), 45_500 + seed),
        Condition::Dropped => {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(45_700 + seed);
            let rate = 1.0 / period_s(cfg);
            let span = (0.030 * rate) as u64;
            // After the lead-in, over the sweep.
            let lead = (0.5 * rate) as u64;
            let end = ((0.5 + cfg.chirp.duration_s.unwrap_or(20.0)) * rate) as u64;
            let holds: Vec<(u64, u64)> = (0..3)
                .map(|_| (rng.random_range(lead..end - span), span))
                .collect();
            measure_with_holds(cfg, seed, &holds)
        }
    }
}

/// The median line's relative 1σ.
fn median_relative_sigma(frf: &Frf) -> f64 {
    let mut r: Vec<f64> = frf
        .sigma_m_per_a
        .iter()
        .zip(&frf.magnitude_m_per_a)
        .map(|(s, m)| s / m)
        .filter(|v| v.is_finite())
        .collect();
    r.sort_by(f64::total_cmp);
    r[r.len() / 2]
}

/// One bench under one condition: (a confident wrong verdict, a trusted
/// fit that is wrong, the fit flagged, the verdict null), each with why.
struct Outcome {
    wrong_verdict: Option<String>,
    wrong_trusted_fit: Option<String>,
    flagged: bool,
    undecided: bool,
    relative_sigma: f64,
    /// True modes a trusted fit missed without saying so: not reported
    /// undecided, outside the unresolved bands, and at or above the
    /// detection limit it states (or where it states none).
    missed_above_limit: Vec<String>,
    /// True modes a trusted fit missed and said it could: reported
    /// undecided, in an unresolved band, or below its stated limit.
    missed_within_limit: Vec<String>,
    /// Modes a trusted fit added: fitted where no true mode is.
    invented: Vec<String>,
}

fn one(name: &str, cfg: &BenchConfig, seed: u64, c: Condition) -> Outcome {
    let frf = measured(cfg, seed, c);
    let path = FitPath {
        period_s: period_s(cfg),
        amplifier_bandwidth_hz: cfg.actuator.bandwidth_hz,
    };
    let (modes, weak) = true_modes(cfg);
    let cnmp = Sr4dof::new(cfg.plant).unwrap().has_cnmp_zeros();
    let f = fit(&FrfData::from_frf(&frf), &path);
    let v = match &f {
        Ok(f) => verdict(&frf, f, |hz| path_phase_deg(f, &path, hz)),
        Err(e) => without_fit(&e.to_string()),
    };
    let wrong_verdict = v.cmp_cnmp.filter(|&said| said != cnmp).map(|said| {
        format!(
            "{c:?}, {name}: verdict {said} where the truth is {cnmp} ({})",
            v.reason.clone().unwrap_or_default()
        )
    });
    let (flagged, wrong_trusted_fit) = match &f {
        Err(_) => (true, None),
        Ok(f) if !f.trusted() => (true, None),
        Ok(f) => (
            false,
            judge(&modes, &weak, Some(f)).map(|why| format!("{c:?}, {name}: {why}")),
        ),
    };
    // Every true mode a trusted fit missed, against the limit it states.
    let mut missed_above_limit = Vec::new();
    let mut missed_within_limit = Vec::new();
    let mut invented = Vec::new();
    if let Some(f) = f.as_ref().ok().filter(|f| f.trusted()) {
        let found: Vec<f64> = f.modes.iter().map(|m| m.frequency_hz).collect();
        let (missed, added) = matching(&modes, &weak, &found);
        for i in added {
            invented.push(format!(
                "{c:?}, {name}: a mode at {:.2} Hz where the truth has none ({modes:.2?} Hz)",
                found[i]
            ));
        }
        let terms = modal_terms(&Sr4dof::new(cfg.plant).unwrap());
        let kf = cfg.actuator.force_constant_n_per_a;
        for i in missed {
            let t = terms
                .iter()
                .min_by(|a, b| {
                    (a.frequency_hz / modes[i])
                        .ln()
                        .abs()
                        .total_cmp(&(b.frequency_hz / modes[i]).ln().abs())
                })
                .expect("a true mode");
            let a = (t.residue_per_kg * kf).abs();
            let ft = t.frequency_hz;
            let d = f.quality.detection_limit.as_ref();
            let limit = d.and_then(|d| d.at(ft).map(|l| (l, d.damping_at(ft))));
            let undecided = f
                .quality
                .undecided_modes
                .iter()
                .any(|u| (u.frequency_hz / ft).ln().abs() < 0.01);
            let unresolved = d.is_some_and(|d| d.unresolved(ft));
            let what = format!(
                "{c:?}, {name}: true mode {ft:.2} Hz (ζ {:.4}) |A| {a:.3e}: {}",
                t.damping_ratio,
                match (undecided, unresolved, limit) {
                    (true, _, _) => "reported undecided".to_string(),
                    (_, true, _) => "in a fitted mode's unresolved band".to_string(),
                    (_, _, Some((l, z))) => format!("stated limit {l:.3e} (ζ {z:.4})"),
                    _ => "no limit stated".to_string(),
                },
            );
            match limit {
                _ if undecided || unresolved => missed_within_limit.push(what),
                Some((l, _)) if a <= l => missed_within_limit.push(what),
                _ => missed_above_limit.push(what),
            }
        }
    }
    Outcome {
        wrong_verdict,
        wrong_trusted_fit,
        flagged,
        undecided: v.cmp_cnmp.is_none(),
        relative_sigma: median_relative_sigma(&frf),
        missed_above_limit,
        missed_within_limit,
        invented,
    }
}

fn survey(c: Condition) {
    let base = ch5();
    let benches: Vec<(String, BenchConfig, u64)> = (0..SHIPPED)
        .map(|s| (format!("shipped, noise seed {s}"), base.clone(), 47_000 + s))
        .chain((0..RANDOM).map(|s| {
            (
                format!("hidden bench {}", 700 + s),
                hidden(&base, 700 + s),
                48_000 + s,
            )
        }))
        .collect();
    let out: Vec<Outcome> = benches
        .par_iter()
        .map(|(name, cfg, seed)| one(name, cfg, *seed, c))
        .collect();
    let n = out.len();
    let wrong: Vec<&String> = out
        .iter()
        .filter_map(|o| o.wrong_verdict.as_ref())
        .collect();
    let bad_fits: Vec<&String> = out
        .iter()
        .filter_map(|o| o.wrong_trusted_fit.as_ref())
        .collect();
    let flagged = out.iter().filter(|o| o.flagged).count();
    let undecided = out.iter().filter(|o| o.undecided).count();
    let mut rs: Vec<f64> = out.iter().map(|o| o.relative_sigma).collect();
    rs.sort_by(f64::total_cmp);
    eprintln!(
        "{c:?}: {n} fits; verdict right {}, undecided {undecided}, wrong {}; fits flagged {flagged}, unflagged and wrong {}; median line's relative 1σ {:.3}–{:.3}",
        n - undecided - wrong.len(),
        wrong.len(),
        bad_fits.len(),
        rs[0],
        rs[n - 1]
    );
    for w in wrong.iter().chain(&bad_fits) {
        eprintln!("  {w}");
    }
    let within: Vec<&String> = out.iter().flat_map(|o| &o.missed_within_limit).collect();
    let above: Vec<&String> = out.iter().flat_map(|o| &o.missed_above_limit).collect();
    eprintln!(
        "{c:?}: true modes missed by trusted fits: {} that the fit said it could miss (undecided, unresolved, below its detection limit), {} that it did not",
        within.len(),
        above.len()
    );
    for w in within.iter().chain(&above) {
        eprintln!("  {w}");
    }
    let invented: Vec<&String> = out.iter().flat_map(|o| &o.invented).collect();
    assert!(wrong.is_empty(), "{wrong:#?}");
    assert!(above.is_empty(), "missed without saying so: {above:#?}");
    assert!(
        invented.is_empty(),
        "invented by a trusted fit: {invented:#?}"
    );
    if !matches!(c, Condition::Noise) {
        assert!(bad_fits.is_empty(), "{bad_fits:#?}");
    }
}

#[test]
fn at_ten_percent_noise_no_verdict_is_confidently_wrong() {
    survey(Condition::Noise);
}

#[test]
fn with_a_fifth_of_the_lines_corrupted_no_verdict_is_confidently_wrong() {
    survey(Condition::Outliers);
}

#[test]
fn with_samples_dropped_unseen_no_verdict_is_confidently_wrong() {
    survey(Condition::Dropped);
}
