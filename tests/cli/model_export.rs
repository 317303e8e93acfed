//! `bench fit --export-model` (issue 29): the fitted modal model as a
//! transfer function, zeros/poles/gain or state space, in JSON, a MATLAB
//! script or a python-control script, checked by loading every form and
//! format in python-control (`tests/data/model_export_check.py`, an
//! independent reader: it builds the system from the file alone) and
//! comparing its frequency response, with the exported delay and the
//! hold's sinc, against the measured FRF the fit was made from: the model
//! explains the FRF to its noise (RMS of |Ĥ − H|/σ about 1, as the fit's
//! own χ²/ν says) and its poles are the fitted modes.
//!
//! Python is `$BENCH_PYTHON` when set, else `python3`, with numpy and
//! python-control 0.10 (`.ci/run` installs them); missing is a failure with
//! the install command, never a skip.

use crate::common;

use common::{json_stdout, path_in, run, tmp};
use serde_json::Value;
use std::path::Path;
use std::process::Command;

const HINT: &str = "tests/data/model_export_check.py needs python3 with numpy and python-control 0.10: `pip install 'control>=0.10,<0.11'` (in a venv where pip refuses with externally-managed-environment; then set BENCH_PYTHON=<venv>/bin/python), or run .ci/run, which does that";

fn python() -> String {
    std::env::var("BENCH_PYTHON").unwrap_or_else(|_| "python3".into())
}

fn check(model: &Path, csv: &str) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/model_export_check.py");
    let out = Command::new(python())
        .arg(&script)
        .arg(model)
        .arg(csv)
        .output()
        .unwrap_or_else(|e| panic!("{}: {e}; {HINT}", python()));
    assert!(
        out.status.success(),
        "{} on {}: {}\n{HINT}",
        script.display(),
        model.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// A default chirp on the simulated Chapter 5 bench: its FRF CSV.
fn chirp(dir: &Path) -> String {
    let mcap = path_in(dir, "c.mcap");
    let o = run(&["chirp", "--out", &mcap, "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    json_stdout(&o)["frf_csv"].as_str().unwrap().to_string()
}

#[test]
fn every_form_and_format_loads_in_python_control_and_explains_the_frf() {
    let dir = tmp();
    let csv = chirp(dir.path());
    let mut fitted_hz: Option<Vec<f64>> = None;
    for form in ["tf", "zpk", "ss"] {
        for format in ["json", "matlab", "python"] {
            let ext = match format {
                "json" => "json",
                "matlab" => "m",
                _ => "py",
            };
            let model = dir.path().join(format!("g_{form}.{ext}"));
            let o = run(&[
                "fit",
                &csv,
                "--no-plot",
                "--json",
                "--export-model",
                form,
                "--model-format",
                format,
                "--model-out",
                model.to_str().unwrap(),
            ]);
            assert!(
                o.status.success(),
                "{form} {format}: {}",
                String::from_utf8_lossy(&o.stderr)
            );
            let s = json_stdout(&o);
            assert_eq!(s["model"].as_str(), model.to_str());
            let f: Vec<f64> = s["fit"]["modes"]
                .as_array()
                .unwrap()
                .iter()
                .map(|m| m["frequency_hz"].as_f64().unwrap())
                .collect();
            fitted_hz = Some(f);
            let chi2 = s["fit"]["quality"]["chi2_per_dof"].as_f64().unwrap();
            let r = check(&model, &csv);
            let rms = r["rms_normalised"].as_f64().unwrap();
            // The fit's χ²/ν is the mean of |ΔH|²/(σ²/2) per part over
            // independent lines; over all lines the RMS of |ΔH|/σ is
            // about √(χ²/ν): allow 1.5× (the floor ε|H| is not in σ).
            assert!(
                rms < 1.5 * chi2.sqrt().max(1.0),
                "{form} {format}: RMS |Ĥ − H|/σ = {rms} (fit χ²/ν {chi2}): {r}"
            );
            assert!(
                r["median_relative"].as_f64().unwrap() < 0.01,
                "{form} {format}: {r}"
            );
            // Its poles: the fitted modes (rad/s → Hz), plus the
            // amplifier's real pole and the lower residual's double
            // integrator (not in `pole_hz`, which lists the upper half).
            let poles: Vec<f64> = r["pole_hz"]
                .as_array()
                .unwrap()
                .iter()
                .map(|p| p.as_f64().unwrap())
                .collect();
            let fitted = fitted_hz.as_ref().unwrap();
            assert_eq!(poles.len(), fitted.len(), "{form} {format}: {r}");
            for (p, f) in poles.iter().zip(fitted) {
                assert!(
                    (p - f).abs() < 1e-6 * f,
                    "{form} {format}: pole {p} Hz, mode {f} Hz"
                );
            }
        }
    }
    // The thesis' bench: its in-path modes near 29.3, 81.2 and 84.7 Hz
    // (Table 5-1's calibrated bench, `bench analyze`).
    let f = fitted_hz.unwrap();
    assert_eq!(f.len(), 3, "{f:?}");
    for (got, want) in f.iter().zip([29.27, 81.16, 84.67]) {
        assert!((got - want).abs() < 0.01 * want, "{f:?}");
    }
}

#[test]
fn bad_export_requests_are_refused_naming_the_option_and_nothing_is_written() {
    let dir = tmp();
    let csv = chirp(dir.path());
    let listing = || {
        let mut v: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    };
    let before = listing();
    // Mutations of the flags: each refused with exit 2, the flag named.
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["--export-model", "bode"], "--export-model"),
        (vec!["--export-model", ""], "--export-model"),
        (vec!["--export-model", "TF "], "--export-model"),
        (vec!["--model-format", "json"], "--export-model"),
        (
            vec!["--export-model", "tf", "--model-format", "mat"],
            "--model-format",
        ),
        (vec!["--model-out", "x.json"], "--export-model"),
        (
            vec![
                "--export-model",
                "ss",
                "--model-out",
                "/nonexistent-dir/x.json",
            ],
            "--model-out",
        ),
    ];
    for (extra, named) in &cases {
        let mut args = vec!["fit", csv.as_str(), "--no-plot"];
        args.extend(extra.iter());
        let o = run(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {err}");
        assert!(err.contains(named), "{extra:?}: names {named}: {err}");
        assert_eq!(listing(), before, "{extra:?}: something was written");
    }
    // With natural frequencies there is no modal model.
    let o = run(&["fit", "--frequencies", "29,81,85", "--export-model", "tf"]);
    assert_eq!(o.status.code(), Some(2));
    // An existing model file is never replaced without --overwrite, and
    // the refusal comes before anything is written.
    let model = dir.path().join("keep.json");
    std::fs::write(&model, "mine").unwrap();
    let o = run(&[
        "fit",
        &csv,
        "--export-model",
        "zpk",
        "--model-out",
        model.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("--model-out"), "{err}");
    assert_eq!(std::fs::read_to_string(&model).unwrap(), "mine");
    assert!(
        !dir.path().join("c.fit.png").exists(),
        "the plot was written"
    );
    // The default file beside the input, an identifier for a script.
    let o = run(&[
        "fit",
        &csv,
        "--no-plot",
        "--export-model",
        "tf",
        "--model-format",
        "matlab",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(dir.path().join("c_frf_model.m").exists(), "{:?}", listing());
}

/// Issue 29, results that travel: a rerun of `bench fit` on the same input
/// replaces its own plot and model (derived outputs never block a rerun),
/// `--update` after a plain fit works, and an updated bench that exists
/// (which the user may have edited) is never replaced without
/// `--overwrite`.
#[test]
fn a_rerun_of_fit_on_the_same_input_works() {
    let dir = tmp();
    let csv = chirp(dir.path());
    let png = dir.path().join("c.frf.fit.png");
    let model = dir.path().join("c.frf.model.json");
    let ok = |args: &[&str]| {
        let o = run(args);
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    };
    ok(&["fit", &csv, "--export-model", "ss"]);
    assert!(png.exists() && model.exists());
    std::fs::write(&model, "stale").unwrap();
    std::fs::write(&png, "stale").unwrap();
    ok(&["fit", &csv, "--export-model", "ss"]);
    assert!(std::fs::read_to_string(&model).unwrap().contains("\"ss\""));
    assert_ne!(std::fs::read(&png).unwrap(), b"stale");
    ok(&["fit", &csv, "--update"]);
    let updated = dir.path().join("c.frf.updated.toml");
    assert!(updated.exists());
    std::fs::write(&updated, "# mine\n").unwrap();
    let o = run(&["fit", &csv, "--update"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--out") && err.contains("--overwrite"),
        "{err}"
    );
    assert_eq!(std::fs::read_to_string(&updated).unwrap(), "# mine\n");
}

/// Issue 29, the round trips a lab makes: a recording's FRF exported as
/// CSV, fitted and updated from, and the updated bench's controller checked
/// against the same exported FRF by `bench control --frf`; the updated
/// bench's margins on the measured FRF are the ones the recording's own
/// CSV gives.
#[test]
fn export_fit_update_and_control_frf_round_trip() {
    let dir = tmp();
    let csv = chirp(dir.path());
    let rec = path_in(dir.path(), "c.mcap");
    let exported = path_in(dir.path(), "exported.csv");
    let o = run(&[
        "export",
        &rec,
        "--to",
        "csv",
        "--topic",
        "/sysid/frf",
        "--out",
        &exported,
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let updated = path_in(dir.path(), "updated.toml");
    let o = run(&[
        "fit",
        &exported,
        "--update",
        "--no-plot",
        "--out",
        &updated,
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = json_stdout(&o);
    assert!(
        s["update"]["flags"].as_array().unwrap().is_empty(),
        "{}",
        s["update"]
    );
    let check = |frf: &str| {
        let o = run(&[
            "control",
            "--fast",
            "--config",
            &updated,
            "--frf",
            frf,
            "--check-only",
            "--json",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        json_stdout(&o)
    };
    let (a, b) = (check(&exported), check(&csv));
    let margins = |v: &Value| v["loop_check"]["measured"].clone();
    assert!(!margins(&a).is_null(), "no measured margins: {a}");
    assert_eq!(margins(&a), margins(&b));
}
