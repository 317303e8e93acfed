//! `bench fit` and the modal fit behind it (`bench::ident::modal_fit`,
//! `bench::ident::verdict`).
//!
//! The reference is independent of the fit: the 60 random benches of
//! `tests/data/analysis_reference.json` (masses and stiffnesses ±25 %,
//! operating point 0–10 % of L, asymmetry ±15 %), whose frequencies,
//! residues and typed zeros `tests/data/analysis_reference.py` computed
//! with scipy from the thesis' Eq. 2-5; the damping ratios are the
//! model's Rayleigh ones.

mod common;

use bench::config::BenchConfig;
use bench::ident::frf::log_grid;
use bench::ident::modal_fit::{fit, Path as FitPath};
use bench_hal::model::Sr4dof;
use bench_hal::sim::ZohPlant;
use rand::SeedableRng;
use serde::Deserialize;
use serde_json::Value;
use std::path::Path;
use std::process::Command;

#[derive(Deserialize)]
struct Params {
    m1_kg: f64,
    m2_kg: f64,
    m3_kg: f64,
    m4_kg: f64,
    m5_kg: f64,
    k4_n_per_m: f64,
    k5_n_per_m: f64,
    parallelogram_stiffness_n_per_m: f64,
    operating_point_m: f64,
    mass_asymmetry: f64,
    zeta_rigid: f64,
    zeta_csm: f64,
}

#[derive(Deserialize)]
struct Reference {
    params: Params,
    frequencies_hz: Vec<f64>,
    residues_per_kg: Vec<f64>,
    zeros_damped: Vec<(f64, f64, String)>,
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn bench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bench"))
}

/// Relative noise of the synthetic FRFs (0.1 % per point, complex).
const NOISE: f64 = 1e-3;

/// Fitted frequencies within 0.2 %, damping ratios within 15 %, the signs
/// of every mode whose peak stands above the noise, and the zero types of
/// the fitted model equal to scipy's (CMP-CNMP present or not) on the 60
/// random benches, from their exact sampled response with 0.1 % noise.
#[test]
fn random_plants_frequencies_damping_signs_and_zero_types() {
    let refs: Vec<Reference> = serde_json::from_str(
        &std::fs::read_to_string(root().join("tests/data/analysis_reference.json")).unwrap(),
    )
    .unwrap();
    let cfg = BenchConfig::load(&root().join("bench-config/sr4dof-ch5.toml")).unwrap();
    let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
    let path = FitPath {
        period_s,
        amplifier_bandwidth_hz: cfg.actuator.bandwidth_hz,
    };
    let kf = cfg.actuator.force_constant_n_per_a;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(13);
    let mut checked_modes = 0;
    let mut checked_zeros = 0;
    for (i, r) in refs.iter().enumerate() {
        let q = &r.params;
        let mut p = cfg.plant;
        p.m1_kg = q.m1_kg;
        p.m2_kg = q.m2_kg;
        p.m3_kg = q.m3_kg;
        p.m4_kg = q.m4_kg;
        p.m5_kg = q.m5_kg;
        p.k4_n_per_m = q.k4_n_per_m;
        p.k5_n_per_m = q.k5_n_per_m;
        p.parallelogram_stiffness_n_per_m = Some(q.parallelogram_stiffness_n_per_m);
        p.operating_point_m = q.operating_point_m;
        p.mass_asymmetry = q.mass_asymmetry;
        p.damping.zeta_rigid = q.zeta_rigid;
        p.damping.zeta_csm = q.zeta_csm;
        let model = Sr4dof::new(p).unwrap();
        let zoh = ZohPlant::new(&model, &cfg.actuator, period_s);
        let data = common::noisy_frf(&zoh, NOISE, &mut rng);
        let fitted = fit(&data, &path).unwrap();
        let zetas: Vec<f64> = model.modes().iter().map(|m| m.zeta).collect();
        let amax = r
            .residues_per_kg
            .iter()
            .fold(0.0_f64, |m, a| m.max(a.abs()));
        let mut all_found = true;
        for (k, (&fr, &alpha)) in r.frequencies_hz.iter().zip(&r.residues_per_kg).enumerate() {
            // The mode's peak over the rest of the response, relative.
            let w = 2.0 * std::f64::consts::PI * fr;
            let peak = (kf * alpha).abs() / (2.0 * zetas[k] * w * w);
            let rest = zoh.frf(fr).norm();
            let visible = peak > 20.0 * NOISE * rest;
            let in_path = alpha.abs() >= 1e-4 * amax;
            let found = fitted
                .modes
                .iter()
                .find(|m| (m.frequency_hz / fr - 1.0).abs() < 2e-3);
            if !visible {
                if in_path && found.is_none() {
                    all_found = false;
                }
                continue;
            }
            let m = found.unwrap_or_else(|| {
                panic!(
                    "bench {i}: mode {k} at {fr:.3} Hz not fitted within 0.2 %: {:?}",
                    fitted.modes
                )
            });
            assert!(
                (m.damping_ratio / zetas[k] - 1.0).abs() < 0.15,
                "bench {i}: mode {k} damping {} vs {}",
                m.damping_ratio,
                zetas[k]
            );
            assert_eq!(
                m.modal_constant.signum(),
                alpha.signum(),
                "bench {i}: mode {k} sign ({} vs residue {alpha})",
                m.modal_constant
            );
            checked_modes += 1;
        }
        if all_found {
            let reference_cnmp = r.zeros_damped.iter().any(|z| z.2 == "CMP-CNMP");
            assert_eq!(
                fitted.cmp_cnmp, reference_cnmp,
                "bench {i}: fitted zeros {:?} vs scipy {:?}",
                fitted.zeros, r.zeros_damped
            );
            assert_eq!(
                fitted.zeros.iter().filter(|z| z.kind == "RMP-RNMP").count(),
                r.zeros_damped.iter().filter(|z| z.2 == "RMP-RNMP").count(),
                "bench {i}: RMP-RNMP zeros {:?} vs scipy {:?}",
                fitted.zeros,
                r.zeros_damped
            );
            checked_zeros += 1;
        }
    }
    assert!(checked_modes >= 150, "{checked_modes} modes checked");
    assert!(
        checked_zeros >= 50,
        "{checked_zeros} benches' zeros checked"
    );
}

fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// A valid FRF CSV: the Chapter 5 bench's exact sampled response, in the
/// 4-column form of earlier versions.
fn valid_csv() -> String {
    valid_csv_with(false)
}

/// A valid FRF CSV, with `sigma_m_per_a` (0.1 % of |H|) and
/// `resolution_hz` (0.2 Hz) when `sigma`.
fn valid_csv_with(sigma: bool) -> String {
    let cfg = BenchConfig::load(&root().join("bench-config/sr4dof-ch5.toml")).unwrap();
    let model = Sr4dof::new(cfg.plant).unwrap();
    let zoh = ZohPlant::new(&model, &cfg.actuator, cfg.loop_.period_ns() as f64 * 1e-9);
    let mut s = String::from(if sigma {
        "frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz\n"
    } else {
        "frequency_hz,magnitude_m_per_a,phase_deg,coherence\n"
    });
    let mut last = 0.0;
    let mut off = 0.0;
    for f in log_grid(1.0, 400.0, 200) {
        let h = zoh.frf(f);
        let mut p = h.arg().to_degrees() + off;
        while p - last > 180.0 {
            p -= 360.0;
            off -= 360.0;
        }
        while p - last < -180.0 {
            p += 360.0;
            off += 360.0;
        }
        last = p;
        if sigma {
            s.push_str(&format!(
                "{f},{:e},{p},0.999,{:e},0.2\n",
                h.norm(),
                1e-3 * h.norm()
            ));
        } else {
            s.push_str(&format!("{f},{:e},{p},0.999\n", h.norm()));
        }
    }
    s
}

/// `bench fit` on a valid CSV: exit 0, JSON with the modes (frequency,
/// damping ratio, signed modal constant and their 1σ), the verdict, a PNG.
#[test]
fn fit_cli_on_a_csv() {
    let dir = tempfile::tempdir().unwrap();
    let csv = write(dir.path(), "frf.csv", &valid_csv());
    let out = bench()
        .args(["fit", csv.to_str().unwrap(), "--json"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    let modes = v["modes"].as_array().unwrap();
    assert!(modes.len() >= 3, "{v}");
    for m in modes {
        for k in [
            "frequency_hz",
            "frequency_sigma_hz",
            "damping_ratio",
            "damping_ratio_sigma",
            "modal_constant",
            "modal_constant_sigma",
            "sign",
        ] {
            assert!(m[k].is_number(), "{k} in {m}");
        }
    }
    // The shipped bench (8 % of L, Δm23 = +10 %): the verdict is its model's.
    let cfg = BenchConfig::load(&root().join("bench-config/sr4dof-ch5.toml")).unwrap();
    let model = Sr4dof::new(cfg.plant).unwrap();
    assert_eq!(
        v["verdict"]["cmp_cnmp"],
        Value::Bool(bench::analysis::modal::model_cnmp_damped(&model)),
        "{v}"
    );
    let png = dir.path().join("frf.fit.png");
    assert!(std::fs::metadata(&png).unwrap().len() > 10_000);
}

/// Bad FRFs: exit 2 naming the file and the line or field, no PNG.
/// Generated: every data line of a valid CSV (both forms: 6 columns, and
/// the 4 of earlier versions) broken in each column in several ways, plus
/// the header, too few points and recordings without an FRF.
#[test]
fn bad_frf_inputs_exit_2_naming_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let mut cases: Vec<(String, String, String)> = Vec::new(); // (text, must contain, what)
    for with_sigma in [false, true] {
        broken_lines(&valid_csv_with(with_sigma), &mut cases);
    }
    // The 6-column form read fine (the 4-column one is fit_cli_on_a_csv's).
    let six = write(dir.path(), "six.csv", &valid_csv_with(true));
    let out = bench()
        .args(["fit", six.to_str().unwrap(), "--no-plot"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let good = valid_csv();
    let lines: Vec<&str> = good.lines().collect();
    let run = |name: &str, text: &str| {
        let p = write(dir.path(), name, text);
        let out = bench()
            .args(["fit", p.to_str().unwrap(), "--no-plot"])
            .output()
            .unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
            p,
        )
    };
    cases.push((
        good.replacen("coherence", "gamma2", 1),
        "line 1".into(),
        "wrong header".into(),
    ));
    cases.push((
        lines[..6].join("\n"),
        "at least".into(),
        "too few points".into(),
    ));
    cases.push((String::new(), "empty".into(), "empty file".into()));
    for (k, (text, needle, what)) in cases.iter().enumerate() {
        let (code, err, p) = run(&format!("bad{k}.csv"), text);
        assert_eq!(code, Some(2), "{what}: {err}");
        assert!(err.contains(p.to_str().unwrap()), "{what}: {err}");
        assert!(err.contains(needle.as_str()), "{what}: {err}");
    }
    assert!(cases.len() > 200, "{} cases", cases.len());
    recordings_without_an_frf(dir.path(), &run);
}

/// Every 37th data line of the CSV `good` broken in each of its columns
/// in several ways, a repeated frequency, an extra field: (text, what the
/// error must contain, what was broken).
fn broken_lines(good: &str, cases: &mut Vec<(String, String, String)>) {
    let lines: Vec<&str> = good.lines().collect();
    let columns: Vec<&str> = lines[0].split(',').collect();
    for li in (1..lines.len()).step_by(37) {
        for (c, col) in columns.iter().enumerate() {
            let bad_values: &[&str] = match c {
                0 => &["NaN", "-1", "0", "x", "", "inf"],
                1 => &["NaN", "-1e-6", "0", "x", ""],
                2 => &["NaN", "inf", "x", ""],
                3 => &["NaN", "-0.1", "1.5", "x", ""],
                // sigma_m_per_a: unknown (NaN) only in the 4-column form.
                4 => &["NaN", "-1e-9", "inf", "x", ""],
                _ => &["NaN", "0", "-0.1", "inf", "x", ""],
            };
            for bad in bad_values {
                let mut l: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
                let mut f: Vec<String> = l[li].split(',').map(String::from).collect();
                f[c] = bad.to_string();
                l[li] = f.join(",");
                cases.push((
                    l.join("\n"),
                    format!("line {}", li + 1),
                    format!("{col}={bad:?}"),
                ));
            }
        }
        // Non-monotonic: this line's frequency equal to the previous one's.
        if li > 1 {
            let mut l: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
            let prev = l[li - 1].split(',').next().unwrap().to_string();
            let rest: Vec<String> = l[li].split(',').skip(1).map(String::from).collect();
            l[li] = format!("{prev},{}", rest.join(","));
            cases.push((
                l.join("\n"),
                format!("line {}", li + 1),
                "repeated frequency".into(),
            ));
        }
        // A missing or an extra field.
        let mut l: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
        l[li] = format!("{},1", l[li]);
        cases.push((
            l.join("\n"),
            format!("line {}", li + 1),
            "extra field".into(),
        ));
    }
}

/// What `bench fit` on a file made: exit status, stderr, the file.
type Outcome = (Option<i32>, String, std::path::PathBuf);

/// A file that is not a recording, and recordings without an FRF, given
/// to `run`: exit 2 naming the file.
fn recordings_without_an_frf(dir: &Path, run: &dyn Fn(&str, &str) -> Outcome) {
    // A file that is not a recording, and a recording without /sysid/frf.
    let (code, err, _) = run("junk.mcap", "not an mcap");
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("junk.mcap"), "{err}");
    let rec = dir.join("nofrf.mcap");
    {
        let mut w = mcap::Writer::new(std::io::BufWriter::new(
            std::fs::File::create(&rec).unwrap(),
        ))
        .unwrap();
        let ch = w
            .add_channel(
                0,
                "/bench/sample",
                "json",
                &std::collections::BTreeMap::new(),
            )
            .unwrap();
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: ch,
                sequence: 0,
                log_time: 1,
                publish_time: 1,
            },
            b"{}",
        )
        .unwrap();
        w.finish().unwrap();
    }
    let out = bench()
        .args(["fit", rec.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("nofrf.mcap") && err.contains("/sysid/frf"),
        "{err}"
    );
    // No plot left by any refusal.
    assert!(std::fs::read_dir(dir).unwrap().all(|e| !e
        .unwrap()
        .file_name()
        .to_string_lossy()
        .ends_with(".png")));
}

/// Runs the shipped Fig 5-10 campaign (150 cells on the simulated Chapter
/// 5 bench) with `chirp_duration_s`, returns `campaign status --json`.
fn fig_5_10(chirp_duration_s: f64) -> Value {
    let dir = tempfile::tempdir().unwrap();
    let shipped =
        std::fs::read_to_string(root().join("bench-config/campaign-fig5-10.toml")).unwrap();
    let config = root().join("bench-config/sr4dof-ch5.toml");
    let text: String = shipped
        .lines()
        .map(|l| {
            if l.starts_with("config =") {
                format!("config = {:?}", config.display().to_string())
            } else if l.starts_with("duration_s =") {
                format!("duration_s = {chirp_duration_s:?}")
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    let file = write(dir.path(), "campaign.toml", &text);
    let out = dir.path().join("run");
    let run = bench()
        .args([
            "campaign",
            "run",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let status = bench()
        .args(["campaign", "status", out.to_str().unwrap(), "--json"])
        .output()
        .unwrap();
    serde_json::from_slice(&status.stdout).unwrap()
}

/// Thesis Fig 5-10 on the simulator, the default 60 s sweep: the measured
/// verdict decided in at least 145 of the 150 cells, and in every decided
/// cell equal to the model's zeros (the campaign's `model_cnmp`, from the
/// model of the cell's achieved bench).
#[test]
fn fig_5_10_grid_is_decided_and_right() {
    let s = fig_5_10(60.0);
    assert_eq!(s["done"], 150, "{s}");
    let decided = s["decided"].as_u64().unwrap();
    assert!(decided >= 145, "{decided} decided: {}", s["results"]);
    assert_eq!(
        s["agree"].as_u64().unwrap(),
        decided,
        "{}",
        s["disagreements"]
    );
    for r in s["results"].as_array().unwrap() {
        if r["verdict"].is_null() {
            assert!(r["reason"].as_str().is_some_and(|t| !t.is_empty()), "{r}");
        }
    }
}

/// The same grid with 5 s sweeps (noisier, coarser): every verdict is
/// right or `null` with its reason, never wrong.
#[test]
fn short_sweeps_are_never_wrong() {
    let s = fig_5_10(5.0);
    assert_eq!(s["done"], 150, "{s}");
    assert_eq!(s["agree"], s["decided"], "{}", s["disagreements"]);
    assert!(s["disagreements"].as_array().unwrap().is_empty(), "{s}");
    for r in s["results"].as_array().unwrap() {
        if r["verdict"].is_null() {
            assert!(r["reason"].as_str().is_some_and(|t| !t.is_empty()), "{r}");
        }
    }
}
