//! `bench`'s loop check against the independent python-control reference
//! (`tests/data/loop_reference.py`, through `tests/common/loop_reference.rs`),
//! in both directions, on the controllers that exist today: Eq. (6-6) and
//! (6-7) on the shipped Chapter 5 bench, the thesis' own figures, issue 27's
//! figures with half a sample of computation delay, and ten random benches.
//!
//! # Tolerances
//! Two comparisons, two sets:
//!
//! - **Same loop, two implementations** ([`SAME_LOOP`]): the tool's
//!   continuous margins (`LoopCheck::continuous`: `C(jω) k_f G(jω)`, no
//!   hold, no amplifier) against the reference's with the hold and the
//!   amplifier off. Both evaluate the same exact expression; they differ
//!   only in how a crossing is refined (the tool bisects the exact function,
//!   python-control's `stability_margins` runs `brentq` on a cubic spline
//!   through 20 001 grid points) and in how ‖S‖∞ is found (the tool takes
//!   the largest grid value, unrefined, which a resonance's sharp peak can
//!   exceed by 0.3 %, below). Crossovers to 10⁻⁵ (relative), phase margins
//!   to 0.01°, gain margins to 0.01 dB, ‖S‖∞ to 0.3 %.
//! - **The loop that runs** ([`RUNNING_LOOP`]): the tool's `model_margins`
//!   (the discrete controller that runs × the zero-order-hold sampled plant,
//!   `ZohPlant`) against the reference's continuous loop with the exact
//!   hold `(1 − e^{−sT})/(sT)`. The two loops differ by a relative error
//!   δ = |ΔL|/|L| with two sources:
//!   1. the controller: the shipped controllers run their `least_squares`
//!      discretisation, within 0.003 dB / 0.02° of the continuous design up
//!      to f_s/10 = 500 Hz (`docs/src/jobs/control.md`). The test measures
//!      δ_c = |C_d/C − 1| where the margins are read (each crossover, the
//!      gain margin's phase crossover, the ‖S‖∞ peak: at most 1.5·10⁻⁴
//!      here), asserts δ_c ≤ 5·10⁻³, and widens the tolerances below only
//!      where δ_c exceeds 1.1·10⁻³ (each bound as derived, with the same
//!      headroom). A least-squares fit to f_s/4, tried for issue 45, left
//!      Eq. (6-7) at δ_c = 4.9·10⁻³ and moved a random bench's crossover
//!      by 1.5 %: it is not what runs;
//!   2. the hold: the sampled plant is the continuous one with the exact
//!      hold plus its aliases at ω ± k·2π/T, which relative to it are about
//!      (ω/ω_s)³ (the plant falls as ω⁻² above its modes, the hold as ω⁻¹):
//!      below 10⁻⁴ up to 700 rad/s, the highest figure here.
//!
//!   With δ ≤ 1.2·10⁻³: a crossover moves by δ / |d ln|L| / d ln ω| ≤ 2δ
//!   (|L| falls at least 10 dB/decade through every crossover of these
//!   loops; a resonance's flanks are far steeper) → **0.3 %**; a phase
//!   margin by δ plus the phase slope times that move, the phase slope at
//!   most twice the log-magnitude slope (a second-order resonance's flanks:
//!   equal) → 3δ rad = 0.2° → **0.3°**; a gain margin likewise by 3δ
//!   neper = 0.03 dB → **0.05 dB**; ‖S‖∞ by S·|L|·δ ≤ 5δ = 0.6 % at the
//!   peaks here, plus up to 0.3 % by which the tool's unrefined grid
//!   maximum (20 001 log points, Δln ω = 6.1·10⁻⁴) falls below a
//!   resonance's sharp peak (½(Δln ω / 2ζ)² for ζ ≥ 0.004) → **1 %**.
//!   Phase margins are compared on the circle (a margin near ±180° may
//!   wrap). A controller discretised with Tustin (0.5 dB / 1.3° at
//!   500 Hz) would need tolerances a hundred times wider; the premise is
//!   asserted, not assumed.
//!
//! Issue 27's figures are compared to the digits the issue prints.

use crate::common;

use bench::config::BenchConfig;
use bench::control::loop_check::{check_loop, LoopCheck, Margins};
use bench::control::DiscreteController;
use bench::splitmix::{splitmix64, GAMMA};
use bench_plant::model::Sr4dof;
use common::loop_reference::{python_reference, Case, RefLoop, RefMargins, Requirements};
use std::path::Path;

/// Allowed differences between the tool's margins and the reference's.
#[derive(Debug, Clone, Copy)]
struct Tol {
    /// Relative, on every crossover frequency.
    crossover_rel: f64,
    /// Degrees, on every phase margin (on the circle).
    pm_deg: f64,
    /// dB, on the gain margin.
    gm_db: f64,
    /// Relative, on ‖S‖∞.
    s_rel: f64,
}

/// The same continuous loop in two implementations (module docs).
const SAME_LOOP: Tol = Tol {
    crossover_rel: 1e-5,
    pm_deg: 0.01,
    gm_db: 0.01,
    s_rel: 0.003,
};

/// The sampled loop that runs against the continuous loop with the exact
/// hold (module docs).
const RUNNING_LOOP: Tol = Tol {
    crossover_rel: 0.003,
    pm_deg: 0.3,
    gm_db: 0.05,
    s_rel: 0.01,
};

/// The largest controller δ at the margins' frequencies the running
/// loop's comparison accepts (0.04 dB / 0.23°): the tolerances derived
/// from it stay within four times [`RUNNING_LOOP`].
const CONTROLLER_DELTA_MAX: f64 = 5e-3;

fn shipped() -> BenchConfig {
    BenchConfig::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"))
        .expect("the shipped config")
}

fn period_s(cfg: &BenchConfig) -> f64 {
    cfg.loop_.period_ns() as f64 * 1e-9
}

/// The tool's loop check of `name` on `cfg` (model only).
fn tool(cfg: &BenchConfig, name: &str) -> LoopCheck {
    tool_with_link(cfg, name, 0)
}

/// The same with the link's pure delay of `periods` loop periods.
fn tool_with_link(cfg: &BenchConfig, name: &str, periods: u32) -> LoopCheck {
    let model = Sr4dof::new(cfg.plant).expect("a valid plant");
    let t = period_s(cfg);
    let ctrl = DiscreteController::new(&cfg.controller[name], t, cfg.actuator.peak_current_a);
    check_loop(cfg, &model, name, &ctrl, t, None, 0.0, periods)
}

/// The difference of two angles on the circle, degrees in [0, 180].
fn angle_diff(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(360.0);
    d.min(360.0 - d)
}

/// The largest differences seen, per figure (for the table's last line).
#[derive(Debug, Default)]
struct Worst {
    crossover_rel: f64,
    pm_deg: f64,
    gm_db: f64,
    s_rel: f64,
}

impl Worst {
    fn line(&self, what: &str) {
        eprintln!(
            "   largest differences, {what}: crossover {:.2e} (relative), phase margin {:.4}°, gain margin {:.4} dB, ‖S‖∞ {:.2e} (relative)",
            self.crossover_rel, self.pm_deg, self.gm_db, self.s_rel
        );
    }
}

/// What differs beyond `tol` between the tool's `m` and the reference's
/// `r`; the differences go into `worst`.
fn disagreements(what: &str, m: &Margins, r: &RefLoop, tol: Tol, worst: &mut Worst) -> Vec<String> {
    let mut v = Vec::new();
    if m.crossovers_rad_s.len() != r.crossovers_rad_s.len() {
        v.push(format!(
            "{what}: crossovers {:?} (tool) against {:?} (reference)",
            m.crossovers_rad_s, r.crossovers_rad_s
        ));
    } else {
        for i in 0..m.crossovers_rad_s.len() {
            let (wt, wr) = (m.crossovers_rad_s[i], r.crossovers_rad_s[i]);
            let d = (wt / wr - 1.0).abs();
            worst.crossover_rel = worst.crossover_rel.max(d);
            if d > tol.crossover_rel {
                v.push(format!(
                    "{what}: crossover {wt:.4} rad/s (tool) against {wr:.4} (reference)"
                ));
            }
            let (pt, pr) = (m.phase_margins_deg[i], r.phase_margins_deg[i]);
            let d = angle_diff(pt, pr);
            worst.pm_deg = worst.pm_deg.max(d);
            if d > tol.pm_deg {
                v.push(format!(
                    "{what}: phase margin {pt:.3}° (tool) against {pr:.3}° (reference) at {wr:.1} rad/s"
                ));
            }
        }
    }
    match (m.gain_margin_db, r.gain_margin_db) {
        (Some(gt), Some(gr)) => {
            worst.gm_db = worst.gm_db.max((gt - gr).abs());
            if (gt - gr).abs() > tol.gm_db {
                v.push(format!(
                    "{what}: gain margin {gt:.4} dB (tool) against {gr:.4} dB (reference)"
                ));
            }
        }
        (None, None) => {}
        _ => v.push(format!(
            "{what}: gain margin {:?} dB (tool) against {:?} dB (reference)",
            m.gain_margin_db, r.gain_margin_db
        )),
    }
    let d = (m.sensitivity_peak / r.sensitivity_peak - 1.0).abs();
    worst.s_rel = worst.s_rel.max(d);
    if d > tol.s_rel {
        v.push(format!(
            "{what}: ‖S‖∞ {:.4} (tool) against {:.4} (reference)",
            m.sensitivity_peak, r.sensitivity_peak
        ));
    }
    v
}

/// The controller's part of δ (module docs): the largest
/// `|C_d(e^{jωT})/C(jω) − 1|` of the controller that runs, at the
/// frequencies where `m`'s margins are read (every crossover, the gain
/// margin's phase crossover, the ‖S‖∞ peak).
fn controller_delta(cfg: &BenchConfig, name: &str, m: &Margins) -> f64 {
    let t = period_s(cfg);
    let c = &cfg.controller[name];
    let d = DiscreteController::new(c, t, f64::INFINITY);
    m.crossovers_rad_s
        .iter()
        .copied()
        .chain(m.gain_margin_at_rad_s)
        .chain([m.sensitivity_peak_at_rad_s])
        .filter(|w| w.is_finite() && *w > 0.0)
        .map(|w| (d.response(w, t) / c.response(w) - 1.0).norm())
        .fold(0.0, f64::max)
}

/// The [`RUNNING_LOOP`] premise, measured: the controller's δ at the
/// margins' frequencies is at most [`CONTROLLER_DELTA_MAX`], and the
/// tolerances follow from it (module docs: δ = δ_c + 10⁻⁴ for the hold;
/// crossover 2.5δ, phase margin 4.5δ rad, gain margin 5.7δ neper, ‖S‖∞
/// 5δ + 0.4 %), each at least its [`RUNNING_LOOP`] value.
fn premise(what: &str, cfg: &BenchConfig, name: &str, check: &LoopCheck) -> (Tol, Vec<String>) {
    let dc = controller_delta(cfg, name, &check.model);
    let d = dc + 1e-4;
    let tol = Tol {
        crossover_rel: RUNNING_LOOP.crossover_rel.max(2.5 * d),
        pm_deg: RUNNING_LOOP.pm_deg.max((4.5 * d).to_degrees()),
        gm_db: RUNNING_LOOP
            .gm_db
            .max(5.7 * d * 20.0 / std::f64::consts::LN_10),
        s_rel: RUNNING_LOOP.s_rel.max(5.0 * d + 0.004),
    };
    eprintln!(
        "   {what}: the controller that runs ({}) is within δ = {dc:.1e} of the design where the margins are read",
        check.discretization.method.as_str()
    );
    let problems = if dc > CONTROLLER_DELTA_MAX {
        vec![format!(
            "{what}: the discretisation that runs ({}) is δ = {dc:.2e} from the design where the margins are read, beyond the {CONTROLLER_DELTA_MAX} the tolerances assume",
            check.discretization.method.as_str()
        )]
    } else {
        Vec::new()
    };
    (tol, problems)
}

fn list(v: &[f64], digits: usize) -> String {
    let s: Vec<String> = v.iter().map(|x| format!("{x:.digits$}")).collect();
    s.join(" ")
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("none".to_string(), |x| format!("{x:.digits$}"))
}

/// One block of the table: the tool's margins beside the reference's.
fn table(case: &str, rows: &[(&str, Option<&Margins>, Option<&RefLoop>)]) {
    eprintln!("── {case}");
    eprintln!(
        "   {:<28} {:<26} {:<22} {:>8} {:>8} {:>8}",
        "", "crossovers rad/s", "phase margins °", "GM dB", "‖S‖∞", "ω_B"
    );
    for (what, m, r) in rows {
        if let Some(m) = m {
            eprintln!(
                "   {:<28} {:<26} {:<22} {:>8} {:>8.4} {:>8}",
                what,
                list(&m.crossovers_rad_s, 2),
                list(&m.phase_margins_deg, 2),
                opt(m.gain_margin_db, 3),
                m.sensitivity_peak,
                "-"
            );
        }
        if let Some(r) = r {
            eprintln!(
                "   {:<28} {:<26} {:<22} {:>8} {:>8.4} {:>8}",
                what,
                list(&r.crossovers_rad_s, 2),
                list(&r.phase_margins_deg, 2),
                opt(r.gain_margin_db, 3),
                r.sensitivity_peak,
                opt(r.sensitivity_bandwidth_rad_s, 1)
            );
        }
    }
}

fn stability_line(case: &str, tool: Option<&LoopCheck>, r: &RefMargins) {
    let verdict = |s: bool| if s { "stable" } else { "UNSTABLE" };
    let tool = tool.map_or("not run".to_string(), |c| {
        format!(
            "{} (|z| {:.6})",
            verdict(c.closed_loop_stable),
            c.largest_pole_magnitude
        )
    });
    eprintln!(
        "   stability {case}: tool {tool}; reference Padé {} (order {}, max Re {:.3} rad/s), sampled {} (|z| {})",
        verdict(r.stable_continuous_pade),
        r.pade_order,
        r.largest_real_part_rad_s,
        r.stable_discrete.map_or("not run", verdict),
        opt(r.largest_pole_magnitude, 6)
    );
}

/// Eq. (6-6) and (6-7) on the shipped Chapter 5 bench at 5 kHz with the
/// 1 kHz amplifier: the loop the tool checks agrees with python-control's
/// continuous loop with the exact hold ([`RUNNING_LOOP`]); the tool's
/// continuous margins agree with the reference's without hold and
/// amplifier ([`SAME_LOOP`]), and those reproduce the thesis' §6.2.1
/// figures (slow 18 rad/s / 70°, fast 287 rad/s / 42°) to 5 % and 3°: the
/// model is the Chapter 5 bench with the calibrated parallelogram
/// stiffness (README, *Calibration*), and the thesis reads its figures off
/// the Bode plots of Figs 6-8 and 6-10.
#[test]
fn chapter_5_controllers_agree_with_python_control() {
    let cfg = shipped();
    let names = ["slow", "fast"];
    let mut cases = Vec::new();
    for name in names {
        let c = &cfg.controller[name];
        cases.push(Case::new(name, &cfg, c, 0.0).with_discrete_margins());
        cases.push(Case::new(format!("{name} (thesis)"), &cfg, c, 0.0).thesis());
    }
    let refs = python_reference(&cases);
    let mut problems = Vec::new();
    let (mut running, mut same) = (Worst::default(), Worst::default());
    for (i, name) in names.iter().enumerate() {
        let (run, thesis) = (&refs[2 * i], &refs[2 * i + 1]);
        let check = tool(&cfg, name);
        let continuous = check.continuous.as_ref().expect("a config controller");
        table(
            &format!(
                "Eq. ({}) on the shipped bench, 5 kHz, 1 kHz amplifier",
                ["6-6", "6-7"][i]
            ),
            &[
                ("tool: sampled loop", Some(&check.model), None),
                ("reference: exact hold", None, Some(&run.margins)),
                ("reference: sampled, Tustin", None, run.discrete.as_ref()),
                ("tool: continuous (thesis)", Some(continuous), None),
                ("reference: continuous", None, Some(&thesis.margins)),
            ],
        );
        stability_line(name, Some(&check), run);
        let (tol, p) = premise(name, &cfg, name, &check);
        problems.extend(p);
        problems.extend(disagreements(
            name,
            &check.model,
            &run.margins,
            tol,
            &mut running,
        ));
        problems.extend(disagreements(
            &format!("{name} (thesis)"),
            continuous,
            &thesis.margins,
            SAME_LOOP,
            &mut same,
        ));
        if !(check.closed_loop_stable && run.stable() && thesis.stable()) {
            problems.push(format!("{name}: a stability verdict is not 'stable'"));
        }
        // The thesis' own figures (§6.2.1).
        let (wc, pm) = [(18.0, 70.0), (287.0, 42.0)][i];
        let (w, p) = (
            thesis.margins.crossovers_rad_s[0],
            thesis.margins.phase_margins_deg[0],
        );
        eprintln!("   thesis §6.2.1: {wc} rad/s / {pm}°; reference {w:.2} rad/s / {p:.2}°");
        if (w / wc - 1.0).abs() > 0.05 || (p - pm).abs() > 3.0 {
            problems.push(format!(
                "{name}: the reference's continuous loop {w:.2} rad/s / {p:.2}° is not the thesis' {wc} rad/s / {pm}°"
            ));
        }
    }
    running.line("the loop that runs (tool sampled, reference exact hold)");
    same.line("the continuous loop (tool, reference)");
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// Issue 27: "with the zero-order hold, the 1 kHz amplifier and half a
/// sample of computation delay, the thesis' Eq. 6-7 has ω_B ≈ 217 rad/s,
/// one crossing at 284 rad/s, phase margin 36° and ‖S‖∞ 2.28": the
/// reference reproduces each to the digits printed.
#[test]
fn issue_27_figures_of_eq_6_7_with_half_a_sample_of_delay() {
    let cfg = shipped();
    let t = period_s(&cfg);
    let r = &python_reference(&[Case::new(
        "fast, τ = T/2",
        &cfg,
        &cfg.controller["fast"],
        t / 2.0,
    )])[0];
    let m = &r.margins;
    table(
        "Eq. (6-7), hold, amplifier, τ = T/2",
        &[("reference", None, Some(m))],
    );
    eprintln!("   issue 27:                    284                        36                              2.28      217");
    stability_line("fast, τ = T/2", None, r);
    assert!(r.stable(), "{r:?}");
    assert_eq!(m.crossovers_rad_s.len(), 1, "one crossing: {m:?}");
    assert!((m.crossovers_rad_s[0] - 284.0).abs() < 0.5, "{m:?}");
    assert!((m.phase_margins_deg[0] - 36.0).abs() < 0.5, "{m:?}");
    assert!((m.sensitivity_peak - 2.28).abs() < 0.005, "{m:?}");
    let wb = m
        .sensitivity_bandwidth_rad_s
        .expect("a sensitivity bandwidth");
    assert!((wb - 217.0).abs() < 0.5, "ω_B {wb}");
    // And the verdict helper reads it as the issue does: below its 40° and
    // above its ‖S‖∞ of 2.
    let v = r.violations(&Requirements::issue_27());
    assert_eq!(v.len(), 2, "{v:?}");
}

/// Uniform in [lo, hi) from a SplitMix64 stream.
fn uniform(state: &mut u64, lo: f64, hi: f64) -> f64 {
    let x = splitmix64(*state);
    *state = state.wrapping_add(GAMMA);
    lo + (hi - lo) * ((x >> 11) as f64 / (1u64 << 53) as f64)
}

/// Ten random benches (masses and stiffnesses ±20 %, operating point 0–9 %
/// of L, asymmetry ±12 %, seeded), Eq. (6-6) and Eq. (6-7) on each: the
/// tool's and the reference's stability verdicts are the same, and the
/// margins agree within [`RUNNING_LOOP`] (those of the unstable loops too).
#[test]
fn random_benches_agree_with_python_control() {
    let base = shipped();
    let mut state = 27u64;
    let mut benches = Vec::new();
    for _ in 0..10 {
        let mut cfg = base.clone();
        let p = &mut cfg.plant;
        for m in [
            &mut p.m1_kg,
            &mut p.m2_kg,
            &mut p.m3_kg,
            &mut p.m4_kg,
            &mut p.m5_kg,
        ] {
            *m *= uniform(&mut state, 0.8, 1.2);
        }
        p.k4_n_per_m *= uniform(&mut state, 0.8, 1.2);
        p.k5_n_per_m *= uniform(&mut state, 0.8, 1.2);
        let kp = p
            .parallelogram_stiffness_n_per_m
            .unwrap_or_else(|| p.beam.parallelogram_stiffness_n_per_m());
        p.parallelogram_stiffness_n_per_m = Some(kp * uniform(&mut state, 0.8, 1.2));
        p.operating_point_m = uniform(&mut state, 0.0, 0.09) * p.beam.length_m;
        p.mass_asymmetry = uniform(&mut state, -0.12, 0.12);
        benches.push(cfg);
    }
    let mut cases = Vec::new();
    for (i, cfg) in benches.iter().enumerate() {
        for name in ["slow", "fast"] {
            cases.push(Case::new(
                format!("bench {i} {name}"),
                cfg,
                &cfg.controller[name],
                0.0,
            ));
        }
    }
    let refs = python_reference(&cases);
    let mut problems = Vec::new();
    let mut unstable = 0;
    let mut worst = Worst::default();
    for (k, r) in refs.iter().enumerate() {
        let cfg = &benches[k / 2];
        let name = ["slow", "fast"][k % 2];
        let check = tool(cfg, name);
        let p = &cfg.plant;
        table(
            &format!(
                "{}: Y1o {:.1} % of L, Δm23 {:+.1} %",
                r.name,
                100.0 * p.operating_point_m / p.beam.length_m,
                100.0 * p.mass_asymmetry
            ),
            &[
                ("tool: sampled loop", Some(&check.model), None),
                ("reference: exact hold", None, Some(&r.margins)),
            ],
        );
        stability_line(&r.name, Some(&check), r);
        let verdicts = [
            check.closed_loop_stable,
            r.stable_continuous_pade,
            r.stable_discrete.expect("with the hold"),
        ];
        if verdicts.iter().any(|v| *v != verdicts[0]) {
            problems.push(format!(
                "{}: stability verdicts differ (tool, Padé, sampled): {verdicts:?}",
                r.name
            ));
        } else if !verdicts[0] {
            unstable += 1;
        }
        // The margins of an unstable loop are figures of L(jω) all the
        // same: compared too.
        let (tol, p) = premise(&r.name, cfg, name, &check);
        problems.extend(p);
        problems.extend(disagreements(
            &r.name,
            &check.model,
            &r.margins,
            tol,
            &mut worst,
        ));
    }
    eprintln!(
        "{unstable} of {} loops unstable by every verdict",
        refs.len()
    );
    worst.line("the loop that runs (tool sampled, reference exact hold)");
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// Both directions of the stability verdict: Eq. (6-6) on the shipped
/// bench with its gain raised to 0.5 dB below its gain margin is stable,
/// and 0.5 dB above it unstable, for the tool and the reference alike
/// (the margin being the reference's); ten times Eq. (6-7)'s gain is
/// unstable for both.
#[test]
fn stability_verdicts_agree_across_the_gain_margin() {
    let cfg = shipped();
    let slow = &cfg.controller["slow"];
    let gm = python_reference(&[Case::new("slow", &cfg, slow, 0.0)])[0]
        .margins
        .gain_margin_db
        .expect("a gain margin");
    let mut loops = Vec::new();
    for (db, stable) in [(gm - 0.5, true), (gm + 0.5, false)] {
        let mut c = slow.clone();
        c.gain *= 10f64.powf(db / 20.0);
        loops.push((format!("slow × {db:+.2} dB"), "slow", c, stable));
    }
    let mut fast = cfg.controller["fast"].clone();
    fast.gain *= 10.0;
    loops.push(("fast × 10".to_string(), "fast", fast, false));
    let cases: Vec<Case> = loops
        .iter()
        .map(|(n, _, c, _)| Case::new(n.clone(), &cfg, c, 0.0))
        .collect();
    let refs = python_reference(&cases);
    for ((n, name, c, stable), r) in loops.iter().zip(&refs) {
        let mut cfg = cfg.clone();
        cfg.controller.insert(name.to_string(), c.clone());
        let check = tool(&cfg, name);
        stability_line(n, Some(&check), r);
        assert_eq!(check.closed_loop_stable, *stable, "{n}: tool");
        assert_eq!(r.stable_continuous_pade, *stable, "{n}: reference, Padé");
        assert_eq!(r.stable_discrete, Some(*stable), "{n}: reference, sampled");
    }
}

/// A controller `bench design` wrote for a random bench (corners up to
/// 0.8 × Nyquist, seven crossovers; `tests/data/designed-near-nyquist.toml`):
/// the loop check's closed-loop poles agree with python-control's sampled
/// loop (the same largest |z| to 1e-4) and say stable, as the simulator's
/// step does. Before the closed-loop matrix was balanced, the unbalanced
/// QR iteration found |z| = 1.65 and refused the controller.
#[test]
fn a_designed_controller_near_nyquist_is_judged_as_python_control_judges_it() {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/designed-near-nyquist.toml");
    let cfg = BenchConfig::load(&p).unwrap();
    let check = tool(&cfg, "designed");
    let c = &cfg.controller["designed"];
    let r = &python_reference(&[Case::new("designed", &cfg, c, 0.0).with_discrete_margins()])[0];
    eprintln!(
        "tool |z| {:.6} stable {}; python-control |z| {:?} stable {:?}",
        check.largest_pole_magnitude,
        check.closed_loop_stable,
        r.largest_pole_magnitude,
        r.stable_discrete
    );
    assert!(check.closed_loop_stable, "{:?}", check.failures);
    assert_eq!(r.stable_discrete, Some(true));
    let z = r.largest_pole_magnitude.unwrap();
    assert!(
        (check.largest_pole_magnitude - z).abs() < 1e-4,
        "{} against {z}",
        check.largest_pole_magnitude
    );
}

/// The loop on EtherCAT (issue 31): one period of the link's pure delay
/// in the loop. Eq. (6-6), Eq. (6-7), and Eq. (6-7) with its gain ×1.1,
/// each with d = 1: the tool's margins agree with python-control's
/// continuous loop times `e^{−sT}` ([`RUNNING_LOOP`]; on the unit circle
/// `z^{−1}` is `e^{−jωT}` exactly, so the tolerances are unchanged), its
/// stability verdict with the reference's sampled loop times a discrete
/// `z^{−1}` and the largest |z| with it to 1e-3 (the reference's
/// controller is Tustin, the tool's `least_squares`; the largest pole is
/// the slow plant mode, which both place alike). And the verdict the tool
/// gives the ×1.1 controller, the reference gives it too: ‖S‖∞ within
/// `safety.max_sensitivity_peak` without the delay, beyond it with.
#[test]
fn the_link_delay_agrees_with_python_control() {
    let base = shipped();
    let max_s = base.safety.max_sensitivity_peak;
    let mut hot = base.controller["fast"].clone();
    hot.gain *= 1.1;
    let loops = [
        ("slow", base.controller["slow"].clone()),
        ("fast", base.controller["fast"].clone()),
        ("fast × 1.1", hot),
    ];
    let mut cases = Vec::new();
    for (n, c) in &loops {
        cases.push(
            Case::new(*n, &base, c, 0.0)
                .with_link_delay(1)
                .with_discrete_margins(),
        );
        cases.push(Case::new(format!("{n}, no link"), &base, c, 0.0));
    }
    let refs = python_reference(&cases);
    let mut problems = Vec::new();
    let mut worst = Worst::default();
    for (i, (n, c)) in loops.iter().enumerate() {
        let (with, without) = (&refs[2 * i], &refs[2 * i + 1]);
        let mut cfg = base.clone();
        let name = if i == 0 { "slow" } else { "fast" };
        cfg.controller.insert(name.to_string(), c.clone());
        let check = tool_with_link(&cfg, name, 1);
        let plain = tool(&cfg, name);
        table(
            &format!("{n}, the link's delay of one period (200 µs)"),
            &[
                ("tool: sampled loop × z⁻¹", Some(&check.model), None),
                ("reference: exact hold × e^{−sT}", None, Some(&with.margins)),
                ("reference: sampled × z⁻¹", None, with.discrete.as_ref()),
                ("tool: without the link", Some(&plain.model), None),
                ("reference: without the link", None, Some(&without.margins)),
            ],
        );
        stability_line(n, Some(&check), with);
        let (tol, p) = premise(n, &cfg, name, &check);
        problems.extend(p);
        problems.extend(disagreements(
            n,
            &check.model,
            &with.margins,
            tol,
            &mut worst,
        ));
        if Some(check.closed_loop_stable) != with.stable_discrete {
            problems.push(format!(
                "{n}: stability verdicts differ with the link's delay"
            ));
        }
        let z = with.largest_pole_magnitude.expect("with the hold");
        if (check.largest_pole_magnitude - z).abs() > 1e-3 {
            problems.push(format!(
                "{n}: largest |z| {} (tool) against {z} (reference)",
                check.largest_pole_magnitude
            ));
        }
        // The reference's verdict on ‖S‖∞ is the tool's, both ways.
        for (what, tool_s, ref_s) in [
            (
                "with the link",
                check.model.sensitivity_peak,
                with.margins.sensitivity_peak,
            ),
            (
                "without",
                plain.model.sensitivity_peak,
                without.margins.sensitivity_peak,
            ),
        ] {
            if (tool_s > max_s) != (ref_s > max_s) {
                problems.push(format!(
                    "{n} {what}: ‖S‖∞ {tool_s:.3} (tool) and {ref_s:.3} (reference) on two sides of {max_s}"
                ));
            }
        }
        if i == 2 {
            if !plain.passed() || check.passed() {
                problems.push(format!(
                    "{n}: expected to pass without the link and be refused with it: {:?} / {:?}",
                    plain.failures, check.failures
                ));
            }
            if !(without.margins.sensitivity_peak <= max_s && with.margins.sensitivity_peak > max_s)
            {
                problems.push(format!(
                    "{n}: the reference's ‖S‖∞ {:.3} → {:.3} does not cross {max_s}",
                    without.margins.sensitivity_peak, with.margins.sensitivity_peak
                ));
            }
        } else if !check.passed() {
            problems.push(format!("{n}: refused with the link: {:?}", check.failures));
        }
    }
    worst.line("with the link's delay (tool sampled × z⁻¹, reference exact hold × e^{−sT})");
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
