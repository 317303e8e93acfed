//! `bench analyze` and `bench map` end to end: the answers against the
//! thesis, the files they write, and bad input refused with the flag named
//! and nothing written.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn bench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bench"))
}

fn config(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("bench-config")
        .join(name)
}

fn run(args: &[&str], dir: &Path) -> Output {
    bench()
        .args(args)
        .current_dir(dir)
        .output()
        .expect("bench runs")
}

fn json(out: &Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "exit {:?}\nstderr: {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("one JSON object")
}

/// Width and height from a PNG's IHDR chunk (and the file decodes).
fn png_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(
        &bytes[..8],
        b"\x89PNG\r\n\x1a\n",
        "{} is not a PNG",
        path.display()
    );
    let w = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
    let h = u32::from_be_bytes(bytes[20..24].try_into().unwrap());
    (w, h)
}

#[test]
fn analyze_reports_modes_sequence_zeros_and_the_three_mode_test() {
    let dir = tempfile::tempdir().unwrap();
    let ch2 = config("sr4dof-ch2.toml");
    let ch2 = ch2.to_str().unwrap();
    // Thesis Fig 2-4 (Chapter 2 bench): at Y1o = 5 % of L a 360° drop (CMP-CNMP)
    // with Δm23 = 5 %, none without asymmetry.
    let asym = json(&run(
        &[
            "analyze",
            "--config",
            ch2,
            "--operating-point-pct",
            "5",
            "--mass-asymmetry",
            "0.05",
            "--json",
            "--pole-zero-png",
            "pz.png",
            "--modes-png",
            "modes.png",
        ],
        dir.path(),
    ));
    assert_eq!(asym["cnmp"], true, "{asym:#}");
    let sym = json(&run(
        &[
            "analyze",
            "--config",
            ch2,
            "--operating-point-pct",
            "5",
            "--mass-asymmetry",
            "0",
            "--json",
            "--no-plot",
        ],
        dir.path(),
    ));
    assert_eq!(sym["cnmp"], false, "{sym:#}");
    // Modes: four, ascending, each with frequency, residue (signed, 1/kg)
    // and observability; the X rigid-body mode at 18.2 Hz (Table 2-2).
    let modes = asym["modes"].as_array().unwrap();
    assert_eq!(modes.len(), 4);
    let freqs: Vec<f64> = modes
        .iter()
        .map(|m| m["frequency_hz"].as_f64().unwrap())
        .collect();
    assert!(freqs.windows(2).all(|w| w[0] <= w[1]), "{freqs:?}");
    let r = modes.iter().find(|m| m["label"] == "R").expect("an R mode");
    assert!(
        (r["frequency_hz"].as_f64().unwrap() - 18.2).abs() < 0.2,
        "{r}"
    );
    assert!(
        r["residue"].as_f64().unwrap() > 0.0,
        "Assumption A3-6: the slowest mode in the path is positive: {r}"
    );
    for m in modes {
        for key in [
            "frequency_hz",
            "residue",
            "observable",
            "in_path",
            "sign",
            "modal_mass_kg",
        ] {
            assert!(!m[key].is_null(), "mode without {key}: {m}");
        }
    }
    // One mode is unobservable in x1 (thesis 4.4.2).
    assert_eq!(
        modes.iter().filter(|m| m["observable"] == false).count(),
        1,
        "{modes:?}"
    );
    // CMP-CNMP ⇔ [R]-[u]-[v] with alternating signs (Table 3-3), and the
    // three-mode verdict agrees here.
    assert_eq!(asym["sequence"], "[R]-[u]-[v]");
    assert_eq!(asym["alternating_signs"], true);
    assert_eq!(asym["three_mode"]["p4_1_cnmp"], true);
    let nmp: Vec<&serde_json::Value> = asym["zeros_undamped"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|z| z["re_rad_s"].as_f64().unwrap() > 0.0)
        .collect();
    assert_eq!(nmp.len(), 2, "a CNMP pair: {:#}", asym["zeros_undamped"]);
    assert!(nmp.iter().all(|z| z["kind"] == "CMP-CNMP"));
    assert_eq!(
        sym["zeros_undamped"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|z| z["kind"] != "MMP")
            .count(),
        0
    );
    // The PNGs, at the documented size, named in the summary.
    for key in ["pole_zero_png", "modes_png"] {
        let p = PathBuf::from(asym[key].as_str().unwrap());
        assert!(p.is_absolute(), "{key}: {}", p.display());
        assert_eq!(png_size(&p), (1400, 1000), "{key}");
    }
    assert!(sym["pole_zero_png"].is_null());
    // The human summary says the same.
    let text = run(
        &[
            "analyze",
            "--config",
            ch2,
            "--operating-point-pct",
            "5",
            "--mass-asymmetry",
            "0.05",
            "--no-plot",
        ],
        dir.path(),
    );
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(
        text.contains("[R]-[u]-[v]") && text.contains("CMP-CNMP"),
        "{text}"
    );
}

#[test]
fn map_matches_the_thesis_and_writes_its_csv_and_png() {
    let dir = tempfile::tempdir().unwrap();
    let ch2 = config("sr4dof-ch2.toml");
    let measured = dir.path().join("measured.csv");
    // A measured CMP-CNMP verdict at negative asymmetry contradicts the model
    // (thesis 2.2.3: m2 < m3 is free of CNMP zeros); one undecided row.
    std::fs::write(
        &measured,
        "operating_point_m,mass_asymmetry,verdict,recording\n0.001,-0.05,true,a.mcap\n0.001,0.05,,b.mcap\n",
    )
    .unwrap();
    let out = json(&run(
        &[
            "map",
            "--config",
            ch2.to_str().unwrap(),
            "--operating-points",
            "21",
            "--mass-asymmetries",
            "11",
            "--csv",
            "cells.csv",
            "--png",
            "map.png",
            "--measured",
            measured.to_str().unwrap(),
            "--json",
        ],
        dir.path(),
    ));
    let csv = std::fs::read_to_string(dir.path().join("cells.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("operating_point_m,mass_asymmetry,cnmp,cnmp_damped")
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 21 * 11);
    let mut positive_cnmp = 0;
    for r in &rows {
        let dm: f64 = r[1].parse().unwrap();
        if dm < 0.0 {
            assert_eq!(r[2], "false", "CNMP at negative asymmetry: {r:?}");
        } else if r[2] == "true" {
            positive_cnmp += 1;
        }
    }
    assert!(positive_cnmp > 0, "no CNMP cell at positive asymmetry");
    // Mode crossing of the symmetric Chapter 2 stage near 6.6 % of L (2.3).
    let beam = out["beam_length_m"].as_f64().unwrap();
    let crossing = out["crossing_operating_point_m"].as_f64().unwrap() / beam;
    assert!((crossing - 0.066).abs() < 0.01, "crossing at {crossing}");
    assert_eq!(out["measured"], 1);
    assert_eq!(out["measured_undecided"], 1);
    assert_eq!(
        out["disagreements"].as_array().unwrap().len(),
        1,
        "{:#}",
        out["disagreements"]
    );
    assert_eq!(png_size(&dir.path().join("map.png")), (1400, 1000));
    // Veering: a crossing for Δm23 = 0, a gap otherwise.
    let v = json(&run(
        &[
            "map",
            "--config",
            ch2.to_str().unwrap(),
            "--veering",
            "--veering-asymmetries",
            "0,0.05",
            "--png",
            "veer.png",
            "--json",
        ],
        dir.path(),
    ));
    let curves = v["curves"].as_array().unwrap();
    assert!(curves[0]["closest_gap_hz"].as_f64().unwrap() < 0.05);
    assert!(curves[1]["closest_gap_hz"].as_f64().unwrap() > 0.1);
    assert_eq!(png_size(&dir.path().join("veer.png")), (1400, 1000));
}

/// Bad values for every grid flag, generated: each exits 2, names the flag,
/// and writes nothing.
#[test]
fn bad_map_and_analyze_flags_are_refused_naming_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let ch5 = config("sr4dof-ch5.toml");
    let ch5 = ch5.to_str().unwrap();
    let bad_numbers = ["nan", "inf", "-inf", "-1", "1e300", "21", "1000", "-0.5"];
    let mut cases: Vec<(Vec<String>, &str)> = Vec::new();
    for v in bad_numbers {
        for flag in ["--operating-point-from-pct", "--operating-point-to-pct"] {
            // 0 … 20 % of L is the model's range; "21", "1000", "1e300" are
            // beyond it, "-1", "-0.5" below, nan/inf not numbers.
            cases.push((vec![flag.into(), v.into()], flag));
        }
    }
    // Fractions: −0.33 … 0.5 is the model's range.
    for v in ["nan", "inf", "-1", "-0.4", "0.6", "10", "1e9"] {
        for flag in ["--mass-asymmetry-from", "--mass-asymmetry-to"] {
            let mut args = vec![flag.to_string(), v.to_string()];
            // Keep the other end of the range valid and in order.
            if flag.ends_with("from") {
                args.extend(["--mass-asymmetry-to".into(), "0.5".into()]);
            } else {
                args.extend(["--mass-asymmetry-from".into(), "-0.33".into()]);
            }
            cases.push((args, flag));
        }
    }
    for v in ["0", "1", "402", "100000"] {
        cases.push((
            vec!["--operating-points".into(), v.into()],
            "--operating-points",
        ));
        cases.push((
            vec!["--mass-asymmetries".into(), v.into()],
            "--mass-asymmetries",
        ));
    }
    cases.push((
        vec![
            "--operating-point-from-pct".into(),
            "5".into(),
            "--operating-point-to-pct".into(),
            "5".into(),
        ],
        "--operating-point-to-pct",
    ));
    cases.push((
        vec![
            "--veering".into(),
            "--veering-asymmetries".into(),
            "12".into(),
        ],
        "--veering-asymmetries",
    ));
    cases.push((
        vec![
            "--veering".into(),
            "--localisation-at-pct".into(),
            "50".into(),
        ],
        "--localisation-at-pct",
    ));
    // Too many curves or points: each flag has a count range too.
    cases.push((
        vec![
            "--veering".into(),
            "--veering-asymmetries".into(),
            "0,0.01,0.02,0.03,0.04,0.05,0.06".into(),
        ],
        "--veering-asymmetries",
    ));
    let many: Vec<String> = (0..21).map(|i| (f64::from(i) * 0.5).to_string()).collect();
    cases.push((
        vec![
            "--veering".into(),
            "--localisation-at-pct".into(),
            many.join(","),
        ],
        "--localisation-at-pct",
    ));
    for (args, flag) in &cases {
        let mut full: Vec<&str> = vec!["map", "--config", ch5, "--png", "m.png", "--csv", "c.csv"];
        full.extend(args.iter().map(String::as_str));
        let out = run(&full, dir.path());
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            err.contains(flag),
            "{args:?}: the error does not name {flag}: {err}"
        );
        assert!(
            !dir.path().join("m.png").exists() && !dir.path().join("c.csv").exists(),
            "{args:?} wrote a file"
        );
    }
    // analyze: the plant flags.
    for (args, flag) in [
        (vec!["--mass-asymmetry", "12"], "--mass-asymmetry"),
        (vec!["--mass-asymmetry", "0.6"], "--mass-asymmetry"),
        (vec!["--mass-asymmetry-pct", "60"], "--mass-asymmetry-pct"),
        (vec!["--mass-asymmetry", "nan"], "--mass-asymmetry"),
        (vec!["--operating-point-pct", "30"], "--operating-point-pct"),
        (vec!["--operating-point-m", "3"], "--operating-point-m"),
    ] {
        let mut full = vec![
            "analyze",
            "--config",
            ch5,
            "--pole-zero-png",
            "p.png",
            "--modes-png",
            "q.png",
        ];
        full.extend(args.iter());
        let out = run(&full, dir.path());
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(flag), "{args:?}: {err}");
        assert!(!dir.path().join("p.png").exists());
    }
    // A measured CSV with a bad row names the file and the line.
    let bad = dir.path().join("bad.csv");
    for body in [
        "operating_point_m,mass_asymmetry,verdict\n0.001,0.05,maybe\n",
        "operating_point_m,mass_asymmetry,verdict\n3,0.05,true\n",
        "operating_point_m,mass_asymmetry,verdict\n0.001,5,true\n",
        "operating_point_m,mass_asymmetry,verdict\nx,0.05,true\n",
        "op,dm,verdict\n0.001,0.05,true\n",
        "",
    ] {
        std::fs::write(&bad, body).unwrap();
        let out = run(
            &[
                "map",
                "--config",
                ch5,
                "--png",
                "m.png",
                "--measured",
                bad.to_str().unwrap(),
            ],
            dir.path(),
        );
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{body:?}: {err}");
        assert!(
            err.contains("--measured") && err.contains("bad.csv"),
            "{body:?}: {err}"
        );
        assert!(!dir.path().join("m.png").exists());
    }
}
