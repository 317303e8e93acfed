//! `bench design` from one default chirp's CSV alone (no `--config`), on
//! the shipped bench and two held-out benches (issue 41): the design is
//! predicted and certified on the bench's own fitted model, the
//! performance limit it reports is within 10 % of the independent
//! reference computed on the true plant (`tests/data/limit_reference.py`:
//! cvxpy and Clarabel on the plant built from scratch with scipy; stored
//! in `limit_reference.json` for the cases of `limit_cases.json`), and
//! the designed controller, judged on the true plant, is stable, meets the
//! margins it was designed for, and has the ω* the report gives, under
//! the limit, and at least 0.8 of it (the `limit` strategy; the thesis'
//! families reach 0.51, 0.07 and 0.16 of it on these benches); the same
//! loops recomputed by python-control (`tests/data/loop_reference.py`)
//! are stable and have the ‖S‖∞, phase margin and ω_B bench reads.

use crate::common;

use common::*;
use serde_json::Value;

fn data(name: &str) -> Value {
    let p = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/");
    serde_json::from_str(&std::fs::read_to_string(format!("{p}{name}")).unwrap()).unwrap()
}

/// The built-in bench's config with the case's plant.
fn case_toml(c: &Value) -> String {
    let mut doc: toml_edit::DocumentMut = bench::config::BUILTIN_CONFIG_TOML.parse().unwrap();
    let f = |k: &str| c[k].as_f64().unwrap();
    let plant = doc["plant"].as_table_mut().unwrap();
    for (i, key) in ["m1_kg", "m2_kg", "m3_kg", "m4_kg", "m5_kg"]
        .iter()
        .enumerate()
    {
        plant[key] = toml_edit::value(c["m_kg"][i].as_f64().unwrap());
    }
    plant["k4_n_per_m"] = toml_edit::value(f("k4_n_per_m"));
    plant["k5_n_per_m"] = toml_edit::value(f("k5_n_per_m"));
    plant["parallelogram_stiffness_n_per_m"] = toml_edit::value(f("kp_n_per_m"));
    plant["operating_point_m"] = toml_edit::value(f("y1o_fraction_of_l") * 0.0475);
    plant["mass_asymmetry"] = toml_edit::value(f("mass_asymmetry"));
    doc.to_string()
}

#[test]
fn a_design_from_a_csv_alone_reports_the_benchs_limit_and_holds_on_the_true_plant() {
    let dir = tmp();
    let cases = data("limit_cases.json");
    let refs = data("limit_reference.json");
    // The designed loops on the true plants, for python-control after the
    // loop: (case, bench's ‖S‖∞, least phase margin, ω_B there).
    let mut checks: Vec<(common::loop_reference::Case, f64, f64, f64)> = Vec::new();
    for (c, r) in cases["cases"]
        .as_array()
        .unwrap()
        .iter()
        .zip(refs["cases"].as_array().unwrap())
    {
        let name = c["name"].as_str().unwrap();
        assert_eq!(c["name"], r["name"]);
        let truth_toml = path_in(dir.path(), &format!("{name}.toml"));
        std::fs::write(&truth_toml, case_toml(c)).unwrap();
        let mcap = path_in(dir.path(), &format!("{name}.mcap"));
        let o = run(&["chirp", "--config", &truth_toml, "--out", &mcap, "--json"]);
        assert!(
            o.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let csv = json_stdout(&o)["frf_csv"].as_str().unwrap().to_string();
        let out = path_in(dir.path(), &format!("{name}.designed.toml"));
        let o = run(&["design", &csv, "--out", &out, "--no-plot", "--json"]);
        assert!(
            o.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let s = json_stdout(&o);
        // The bench's own model, named.
        let model = s["model"]["model"].as_str().unwrap();
        assert!(model.starts_with("the fit of "), "{name}: {model}");
        // How far what runs is from the design up to f_s/4 is stated
        // (issue 45), or what runs is the design (made in discrete time,
        // the `limit` strategy).
        let d = &s["discretization"];
        if d.is_null() {
            assert_eq!(s["strategy"], "limit", "{name}");
            assert_eq!(s["controller"]["discretization"], "bilinear", "{name}");
        } else {
            for key in ["wide_max_error_db", "wide_max_error_deg", "wide_up_to_hz"] {
                assert!(d[key].as_f64().is_some_and(f64::is_finite), "{name}: {d}");
            }
        }
        // The limit from the measurement against the reference on the
        // true plant.
        let want = r["limit_rad_s"].as_f64().unwrap();
        let got = s["limit"]["performance_bandwidth_rad_s"]
            .as_f64()
            .unwrap_or_else(|| panic!("{name}: no limit: {}", s["limit"]));
        assert!(
            (got / want - 1.0).abs() <= 0.10,
            "{name}: limit {got:.1} rad/s from the CSV, {want:.1} on the true plant"
        );
        // Where the reference's limit without the design's bounds is well
        // above the one with them, a bound holds it, and the report says
        // which (the peak current for the step, or the band edge).
        let free = r["limit_without_bounds_rad_s"].as_f64().unwrap();
        let binds = s["limit"]["binds"].as_str().unwrap();
        if free > 1.2 * want {
            assert!(
                binds.contains("peak current") || binds.contains("band edge"),
                "{name}: limit {want:.1} with the bounds, {free:.1} without: {binds}"
            );
        }
        // Each right-half-plane zero the fit reports is one of the true
        // mechanics', its bound within 3 % of the reference's, and a
        // bench whose true mechanics have one (the shipped bench's CMP-CNMP
        // pair) gets it reported: its default chirp's fit finds it (the
        // verdict agrees). Until 2026-11-27 the report dropped it: the
        // fit's left-half-plane pair of the quartet, 4.8 % away, stood
        // for both.
        let zs = s["limit"]["rhp_zeros"].as_array().unwrap();
        let want_z = r["rhp_zero_bounds"].as_array().unwrap();
        assert_eq!(
            zs.is_empty(),
            want_z.is_empty(),
            "{name}: right-half-plane zeros reported {zs:?}, in the true mechanics {want_z:?}"
        );
        for z in zs {
            let a = z["bound_rad_s"].as_f64().unwrap();
            assert!(
                want_z
                    .iter()
                    .any(|w| (a / w["bound_rad_s"].as_f64().unwrap() - 1.0).abs() < 0.03),
                "{name}: zero bound {a} is none of {want_z:?}"
            );
        }
        // The designed controller on the true plant: the loop to Nyquist.
        let truth = bench::config::BenchConfig::load(std::path::Path::new(&truth_toml)).unwrap();
        let designed = bench::config::BenchConfig::load(std::path::Path::new(&out)).unwrap();
        let (reach, check) = on_true_plant(name, &truth, &designed.controller["designed"]);
        eprintln!(
            "{name}: {} ω* {reach:.1} rad/s on the true plant ({:.2} of the reference limit {want:.1}; reported {:.1} of {got:.1}), design {:.2} s",
            s["strategy"],
            reach / want,
            s["performance_bandwidth_rad_s"].as_f64().unwrap_or(f64::NAN),
            s["design_time_s"].as_f64().unwrap_or(f64::NAN)
        );
        checks.push(check);
        // The limit strategy reaches 0.8 of the limit on the true plant
        // (issue 41, item 4; the thesis' families reached 0.51, 0.07 and
        // 0.16 of the limit without the bounds on these benches, and from
        // the CSV alone most designs fell back to the slow loop, ω_B
        // 13–15 rad/s). The limit and the design keep the same bounds:
        // the peak current for the setpoint step and |T| at the band
        // edge. Held-out b (MMP pairs at 74/75.5 and 82.5/83.6 Hz, ζ 0.4 %)
        // reached only 0.69 while the climb wrote its polynomials in z⁻¹
        // alone; in 1 − z⁻¹ it gets past 0.9.
        assert_eq!(s["strategy"], "limit", "{name}: {}", s["why"]);
        let families = s["strategies"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|a| a["strategy"] != "limit" && a["meets_margins"] == true)
            .filter_map(|a| a["performance_bandwidth_rad_s"].as_f64())
            .fold(0.0, f64::max);
        assert!(
            reach >= 0.8 * want,
            "{name}: ω* {reach:.1} rad/s on the true plant, {:.2} of the limit {want:.1}",
            reach / want
        );
        // The climb starts from the best of them and keeps only what
        // gains: above it on the true plant too.
        assert!(
            reach > families,
            "{name}: ω* {reach:.1} rad/s, the families' {families:.1}"
        );
        // No controller passes the limit: the design's ω* on the true plant
        // stays under the reference's (2 %: the reference's own bisection
        // and its lines), and the ω* reported from the measurement is the
        // true plant's within 5 %.
        assert!(
            reach <= 1.02 * want,
            "{name}: ω* {reach} above the limit {want}"
        );
        let reported = s["performance_bandwidth_rad_s"].as_f64().unwrap();
        assert!(
            (reported / reach - 1.0).abs() < 0.05,
            "{name}: ω* reported {reported}, on the true plant {reach}"
        );
    }
    check_by_python_control(&checks);
}

/// A workspace (issue 41, item 5): a campaign of the shipped bench over
/// the thesis' 6.2.2 range (0–8 % of L in steps of 2 %, +10 % asymmetry),
/// then `bench design` on the campaign's directory, no `--config`. The one
/// controller, judged on every cell's true plant, is stable, meets the
/// margins (python-control agrees), stays under every cell's own limit as
/// the independent reference computes it on the true plants
/// (`limit_reference.json`, `workspaces`; no controller passes that), and
/// its least ω* over the cells is at least 0.8 of the workspace's limit
/// there (one Q for every cell's true plant: the same problem with all
/// cells' constraints); the workspace's limit `bench` reports from the
/// measurements is the reference's within 10 %. Before the `limit`
/// strategy started a workspace's climb from its most demanding input's
/// own design, the controller reached 0.72 of it (its climbs from the
/// workspace's fast design stalled at 293 rad/s).
#[test]
fn one_controller_for_a_campaign_holds_on_every_cell_s_true_plant() {
    let dir = tmp();
    let cases = data("limit_cases.json");
    let refs = data("limit_reference.json");
    let ws = &cases["workspaces"][0];
    let r = &refs["workspaces"][0];
    assert_eq!(ws["name"], r["name"]);
    let base = cases["cases"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == ws["base"])
        .unwrap();
    let fractions: Vec<f64> = ws["y1o_fraction_of_l"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f.as_f64().unwrap())
        .collect();
    let asymmetry = ws["mass_asymmetry"].as_f64().unwrap();
    // The campaign: the base bench, its cells at the workspace's points.
    let mut cell = base.clone();
    cell["mass_asymmetry"] = asymmetry.into();
    std::fs::write(dir.path().join("bench.toml"), case_toml(&cell)).unwrap();
    let pcts: Vec<String> = fractions.iter().map(|f| format!("{}", 100.0 * f)).collect();
    let campaign = path_in(dir.path(), "ws.toml");
    std::fs::write(
        &campaign,
        format!(
            "config = \"bench.toml\"\nseed = 41\n[grid]\noperating_point_pct = [{}]\nmass_asymmetry = [{asymmetry}]\n",
            pcts.join(", ")
        ),
    )
    .unwrap();
    let cells = path_in(dir.path(), "ws");
    let o = run(&["campaign", "run", &campaign, "--out", &cells, "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = path_in(dir.path(), "ws.designed.toml");
    let o = run(&["design", &cells, "--out", &out, "--no-plot", "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = json_stdout(&o);
    assert_eq!(s["inputs"].as_array().unwrap().len(), fractions.len());
    let model = s["model"]["model"].as_str().unwrap();
    assert!(model.starts_with("the fit"), "{model}");
    // The cells at 6 and 8 % of L have the CMP-CNMP pair (their fits'
    // 5 % apart): the report names the 8 % cell's, whose bound is the
    // lower (448 rad/s where the 6 % cell's is 456).
    let zs = s["limit"]["rhp_zeros"].as_array().unwrap();
    let bound_8 = refs["cases"][0]["rhp_zero_bounds"][0]["bound_rad_s"]
        .as_f64()
        .unwrap();
    assert!(
        zs.iter()
            .any(|z| (z["bound_rad_s"].as_f64().unwrap() / bound_8 - 1.0).abs() < 0.01),
        "the workspace's right-half-plane zeros {zs:?}, the 8 % cell's bound {bound_8:.1}"
    );
    let want = r["limit_rad_s"].as_f64().unwrap();
    let got = s["limit"]["performance_bandwidth_rad_s"].as_f64().unwrap();
    eprintln!(
        "workspace: {} ω* {:.1} rad/s reported, limit {got:.1} from the CSVs, {want:.1} on the true plants, design {:.2} s",
        s["strategy"],
        s["performance_bandwidth_rad_s"].as_f64().unwrap_or(f64::NAN),
        s["design_time_s"].as_f64().unwrap_or(f64::NAN)
    );
    assert!(
        (got / want - 1.0).abs() <= 0.10,
        "the workspace's limit {got:.1} rad/s from the CSVs, {want:.1} on the true plants"
    );
    let designed = bench::config::BenchConfig::load(std::path::Path::new(&out)).unwrap();
    let ctrl = &designed.controller["designed"];
    let mut checks = Vec::new();
    let mut least = f64::INFINITY;
    for (f, own) in fractions.iter().zip(r["cells"].as_array().unwrap()) {
        assert_eq!(own["y1o_fraction_of_l"].as_f64(), Some(*f));
        let mut c = cell.clone();
        c["y1o_fraction_of_l"] = (*f).into();
        let path = dir.path().join(format!("truth-{f}.toml"));
        std::fs::write(&path, case_toml(&c)).unwrap();
        let truth = bench::config::BenchConfig::load(&path).unwrap();
        let name = format!("{:.0} % of L", 100.0 * f);
        let (reach, check) = on_true_plant(&name, &truth, ctrl);
        let own_limit = own["limit_rad_s"].as_f64().unwrap();
        eprintln!(
            "{name}: ω* {reach:.1} rad/s, {:.2} of the workspace's limit {want:.1}, {:.2} of the cell's own {own_limit:.1}",
            reach / want,
            reach / own_limit
        );
        assert!(
            reach <= 1.02 * own_limit,
            "{name}: ω* {reach:.1} above the cell's own limit {own_limit:.1}"
        );
        least = least.min(reach);
        checks.push(check);
    }
    assert_eq!(s["strategy"], "limit", "{}", s["why"]);
    assert!(
        least >= 0.8 * want,
        "the least ω* over the cells' true plants {least:.1} rad/s, {:.2} of the workspace's limit {want:.1}",
        least / want
    );
    check_by_python_control(&checks);
}

/// The designed controller `ctrl` on the true plant of `truth`, the loop
/// to Nyquist: stable, ‖S‖∞ ≤ M = 2 (5 %), the least phase margin ≥ 38°
/// and the gain margin ≥ 5.5 dB (the design's 40° and 6 dB, less the
/// reading's tolerance). Returns its ω* (rad/s, M = 2) and the case for
/// [`check_by_python_control`] with bench's ‖S‖∞, least phase margin and
/// ω_B.
fn on_true_plant(
    name: &str,
    truth: &bench::config::BenchConfig,
    ctrl: &bench::control::ControllerConfig,
) -> (f64, (common::loop_reference::Case, f64, f64, f64)) {
    let t = 1.0 / truth.loop_.rate_hz;
    let p = bench::design::predict::predict(truth, ctrl, t).unwrap();
    let (w, l) = bench::design::predict::model_loop(truth, ctrl, t).unwrap();
    let s_abs: Vec<f64> = l.iter().map(|l| 1.0 / (l + 1.0).norm()).collect();
    let reach =
        bench::design::limit::loop_performance_bandwidth_rad_s(&w, &s_abs, 2.0).unwrap_or(0.0);
    let f = &p.figures;
    eprintln!(
        "{name}: on the true plant ω* {reach:.1} rad/s, ‖S‖∞ {:.3}, PM {:?}°, GM {:?} dB; crossovers {:?} rad/s, phase margins {:?}°",
        f.margins.sensitivity_peak,
        f.phase_margin_min_deg,
        f.margins.gain_margin_db,
        f.margins.crossovers_rad_s,
        f.margins.phase_margins_deg
    );
    assert_eq!(
        f.rhp_closed_loop_poles, 0,
        "{name}: unstable on the true plant"
    );
    assert!(
        f.margins.sensitivity_peak <= 2.0 * 1.05,
        "{name}: ‖S‖∞ {}",
        f.margins.sensitivity_peak
    );
    assert!(f.phase_margin_min_deg.unwrap() >= 38.0, "{name}: {f:?}");
    assert!(
        f.margins.gain_margin_db.is_none_or(|g| g >= 5.5),
        "{name}: {f:?}"
    );
    let check = (
        common::loop_reference::Case::new(name, truth, ctrl, t).with_discrete_margins(),
        f.margins.sensitivity_peak,
        f.phase_margin_min_deg.unwrap_or(f64::NAN),
        f.sensitivity_bandwidth_rad_s.unwrap_or(f64::NAN),
    );
    (reach, check)
}

/// The designed loops on the true plants, recomputed by python-control
/// from scratch (`tests/data/loop_reference.py`: the SR4DoF model of
/// make_reference.py with the amplifier sampled by zero-order hold, one
/// period of delay, the controller by python-control's Tustin, which is
/// the `bilinear` map the design writes for): stable, ‖S‖∞ within the
/// margin, and the figures bench reads on the true plant (`checks`: the
/// case, bench's ‖S‖∞, least phase margin and ω_B) within 1 % (0.5° of
/// phase). The sampled loop, not the continuous one: the controller is
/// designed in discrete time, and on held-out a its continuous form,
/// 0.03 % off in frequency at 628 rad/s, crosses |L| = 1 twice more beside
/// a cancelled pair (PM 59°).
fn check_by_python_control(checks: &[(common::loop_reference::Case, f64, f64, f64)]) {
    let cases: Vec<_> = checks.iter().map(|c| c.0.clone()).collect();
    for (r, (case, peak, pm, wb)) in common::loop_reference::python_reference(&cases)
        .iter()
        .zip(checks)
    {
        let m = r.discrete.as_ref().expect("the sampled loop's margins");
        // Each crossover's margin in (0°, 360°], as bench takes it: a
        // crossover whose phase lies past −180° the other way round
        // (python-control's −117.5°) is 242.5° from it.
        let ref_pm = m
            .phase_margins_deg
            .iter()
            .map(|p| {
                let w = p.rem_euclid(360.0);
                if w == 0.0 {
                    360.0
                } else {
                    w
                }
            })
            .fold(f64::INFINITY, f64::min);
        eprintln!(
            "{}: python-control ‖S‖∞ {:.3} (bench {peak:.3}), least PM {ref_pm:.1}° ({pm:.1}°), ω_B {:?} ({wb:.1}) rad/s, largest pole |z| {:?}",
            case.name, m.sensitivity_peak, m.sensitivity_bandwidth_rad_s, r.largest_pole_magnitude
        );
        eprintln!(
            "{}: python-control's crossovers {:?} rad/s, phase margins {:?}°",
            case.name, m.crossovers_rad_s, m.phase_margins_deg
        );
        assert_eq!(r.stable_discrete, Some(true), "{}: {r:?}", case.name);
        assert!(r.stable_continuous_pade, "{}: {r:?}", case.name);
        assert!(m.sensitivity_peak <= 2.0 * 1.05, "{}: {r:?}", case.name);
        assert!(
            (m.sensitivity_peak / peak - 1.0).abs() < 0.01,
            "{}: {r:?}",
            case.name
        );
        assert!(
            ref_pm >= 38.0 && (ref_pm - pm).abs() < 0.5,
            "{}: {r:?}",
            case.name
        );
        let ref_wb = m.sensitivity_bandwidth_rad_s.expect("ω_B");
        assert!((ref_wb / wb - 1.0).abs() < 0.01, "{}: {r:?}", case.name);
    }
}

/// `--model config` predicts on the config's lumped model and says so;
/// the default names the fit.
#[test]
fn the_report_names_the_model_it_predicts_on() {
    let dir = tmp();
    let mcap = path_in(dir.path(), "c.mcap");
    let o = run(&["chirp", "--out", &mcap, "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = json_stdout(&o)["frf_csv"].as_str().unwrap().to_string();
    for (flag, words) in [
        ("fit", "the fit of "),
        ("config", "the config's model (built-in"),
    ] {
        let out = path_in(dir.path(), &format!("{flag}.toml"));
        let o = run(&[
            "design",
            &csv,
            "--model",
            flag,
            "--out",
            &out,
            "--no-plot",
            "--json",
        ]);
        assert!(
            o.status.success(),
            "{flag}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let s = json_stdout(&o);
        let m = s["model"]["model"].as_str().unwrap();
        assert!(m.starts_with(words), "{flag}: {m}");
        // The text report names it too.
        let o = run(&[
            "design",
            &csv,
            "--model",
            flag,
            "--out",
            &out,
            "--no-plot",
            "--overwrite",
        ]);
        let text = String::from_utf8_lossy(&o.stdout);
        assert!(text.contains(&format!("model: {m}")), "{flag}: {text}");
        assert!(text.contains("of the limit"), "{text}");
    }
    let o = run(&["design", &csv, "--model", "truth", "--no-plot"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--model"));
}

/// The README's main job, `bench chirp` then `bench design` on the
/// recording: the design climbs from the thesis' fast design (its gain
/// backed off until it meets the climb's band edge; from the slow design
/// the climb stalled at 0.59 of the limit) and reaches at least 0.8 of
/// the shipped bench's limit as the independent reference computes it on
/// the true plant (`limit_reference.json`, `ch5`).
#[test]
fn the_readme_main_job_designs_near_the_limit_from_the_recording() {
    let dir = tmp();
    let mcap = path_in(dir.path(), "first.mcap");
    let o = run(&["chirp", "--out", &mcap, "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = path_in(dir.path(), "first.designed.toml");
    let o = run(&["design", &mcap, "--out", &out, "--no-plot", "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = json_stdout(&o);
    let refs = data("limit_reference.json");
    let r = &refs["cases"][0];
    assert_eq!(r["name"], "ch5");
    let want = r["limit_rad_s"].as_f64().unwrap();
    let w = s["performance_bandwidth_rad_s"].as_f64().unwrap();
    eprintln!(
        "README main job: {} ω* {w:.1} rad/s, {:.2} of the reference limit {want:.1}",
        s["strategy"],
        w / want
    );
    assert_eq!(s["strategy"], "limit", "{}", s["why"]);
    assert!(w >= 0.8 * want, "ω* {w} of {want}: {}", s["why"]);
}

/// Issue 41, item 4, measured by hand (ignored: eight chirps and designs,
/// ~2 min): the README's main job (`bench chirp --seed N`, then `bench
/// design` on the recording) for seeds 1–8 of the shipped bench, each
/// design's ω* on the true plant (the built-in bench the simulator runs)
/// as a fraction of the reference limit (`limit_reference.json`, `ch5`).
/// Prints one line per seed and the least and mean; asserts that every
/// design is stable and meets its margins on the true plant
/// ([`on_true_plant`]) and reaches 0.8 of the limit there (issue 41's
/// target; 0.832–0.923 on 2026-11-29, with the Student-t fit and the
/// best climb climbed again). Run:
/// `cargo test --test cli readme_chirp_seeds -- --ignored --nocapture`.
#[test]
#[ignore]
fn readme_chirp_seeds_reach_of_the_limit() {
    let refs = data("limit_reference.json");
    let r = &refs["cases"][0];
    assert_eq!(r["name"], "ch5");
    let want = r["limit_rad_s"].as_f64().unwrap();
    let truth = bench::config::BenchConfig::builtin().unwrap();
    let dir = tmp();
    let mut reach = Vec::new();
    for seed in 1..=8 {
        let mcap = path_in(dir.path(), &format!("seed{seed}.mcap"));
        let o = run(&[
            "chirp",
            "--seed",
            &seed.to_string(),
            "--out",
            &mcap,
            "--json",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let out = path_in(dir.path(), &format!("seed{seed}.designed.toml"));
        let o = run(&["design", &mcap, "--out", &out, "--no-plot", "--json"]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let s = json_stdout(&o);
        let designed = bench::config::BenchConfig::load(std::path::Path::new(&out)).unwrap();
        let (w, _) = on_true_plant(
            &format!("seed {seed}"),
            &truth,
            &designed.controller["designed"],
        );
        eprintln!(
            "seed {seed}: {} ω* {w:.1} rad/s on the true plant, {:.3} of the reference limit {want:.1}; design {:.2} s",
            s["strategy"],
            w / want,
            s["design_time_s"].as_f64().unwrap_or(f64::NAN)
        );
        reach.push(w / want);
    }
    let least = reach.iter().copied().fold(f64::INFINITY, f64::min);
    let mean = reach.iter().sum::<f64>() / reach.len() as f64;
    eprintln!("seeds 1–8: least {least:.3}, mean {mean:.3} of the limit");
    assert!(
        least >= 0.8,
        "a seed's design reaches {least:.3} of the limit on the true plant: {reach:?}"
    );
}
