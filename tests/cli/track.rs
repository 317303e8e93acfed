//! `bench track` on the simulated Chapter 5 bench: a 10 Hz triangle
//! raster of ±5 µm with the fast controller.
//!
//! - With the bench's own model the feedforward alone reaches the noise
//!   floor; feedback alone leaves the error the model predicts (`S·r`,
//!   with the standstill noise added in quadrature).
//! - With a model 15 % off in mass and 14 % in bearing stiffness (a lab's
//!   nominal model) the feedforward does not, and learning does, trial by
//!   trial, without ever growing.
//! - Bad scans and options exit 2 naming the flag, with nothing written.

use crate::common;

use common::*;
use serde_json::Value;
use std::path::Path;

fn track(dir: &Path, extra: &[&str]) -> (std::process::Output, Value) {
    let out = path_in(dir, "run");
    let mut args = vec!["track", "--json", "--out", out.as_str()];
    args.extend_from_slice(extra);
    let o = run(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v = json_stdout(&o);
    (o, v)
}

/// The shipped bench's config with m1 +15 % and the bearings k4, k5
/// −14 %: a nominal model off the simulated bench, written in `dir`.
pub(crate) fn off_model(dir: &Path) -> std::path::PathBuf {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"),
    )
    .unwrap();
    let off = set_key(&text, "m1_kg", "0.46");
    let off = set_key(&off, "k4_n_per_m", "31.0e3");
    let off = set_key(&off, "k5_n_per_m", "31.0e3");
    let model = dir.join("off.toml");
    std::fs::write(&model, off).unwrap();
    model
}

fn rms(t: &Value) -> f64 {
    t["rms_error_m"].as_f64().unwrap()
}

/// Every trial's recording is complete (no `.part` left) and holds its
/// `/track/trial` report, the same as the summary's; `track.json` is the
/// summary printed.
fn check_files(dir: &Path, v: &Value) {
    // --periods 1, or the default 5.
    let periods = v["trials"][0]["rms_error_sigma_m"]
        .as_f64()
        .map_or(1, |_| 5);
    check_files_of(dir, v, periods);
}

/// [`check_files`] of a run of `periods` measured lines.
fn check_files_of(dir: &Path, v: &Value, periods: usize) {
    let run = dir.join("run");
    let on_disk: Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("track.json")).unwrap()).unwrap();
    assert_eq!(&on_disk, v);
    for t in v["trials"].as_array().unwrap() {
        let rec = Path::new(t["recording"].as_str().unwrap());
        assert!(rec.is_file(), "{rec:?}");
        let mut part = rec.as_os_str().to_owned();
        part.push(".part");
        assert!(!Path::new(&part).exists());
        let reports: Vec<Value> = mcap_messages(rec)
            .into_iter()
            .filter(|(topic, _, _)| topic == "/track/trial")
            .map(|(_, _, m)| m)
            .collect();
        assert_eq!(reports.len(), 1, "{rec:?}");
        assert_eq!(reports[0]["rms_error_m"], t["rms_error_m"]);
    }
    let csv = std::fs::read_to_string(run.join("feedforward.csv")).unwrap();
    let n = v["plan"]["period_ticks"].as_u64().unwrap() as usize;
    assert_eq!(csv.lines().count(), n + 3, "two comments, a header, a line");
    let png = image::open(run.join("track.png")).unwrap().to_rgb8();
    assert_eq!(png.dimensions(), (1400, 1500));
    // The noise floor's 1σ is that of an RMS of white noise over the
    // measured ticks, σ/√(2N), within a factor 2 (the loop colours it);
    // with one measured line there is no scatter: no σ (null).
    let floor = &v["trials"][0];
    for t in v["trials"].as_array().unwrap() {
        let Some(s) = t["rms_error_sigma_m"].as_f64() else {
            assert_eq!(periods, 1, "{t}");
            continue;
        };
        assert!(s > 0.0 && s < 0.2 * rms(t), "{t}");
        assert!(t["of_noise_floor_sigma"].as_f64().unwrap() > 0.0, "{t}");
    }
    if periods > 1 {
        let white = rms(floor) / (2.0 * (n * periods) as f64).sqrt();
        let sigma = floor["rms_error_sigma_m"].as_f64().unwrap();
        assert!((0.5..2.0).contains(&(sigma / white)), "{sigma} {white}");
        assert!(v["improvement_sigma"].as_f64().unwrap() > 0.0);
    }
}

/// The target on the shipped bench: feedforward (and learning)
/// ≥ 10× below feedback alone, within 2× of the noise floor. The noise
/// floor is the probe's 40 nm and the disturbance's answer; feedback
/// alone leaves `√((S·r)² + floor²)` as the model predicts it, within
/// 10 %.
#[test]
fn a_triangle_raster_reaches_the_noise_floor_on_the_shipped_bench() {
    let dir = tmp();
    let (_, v) = track(dir.path(), &[]);
    let floor = v["noise_floor_m"].as_f64().unwrap();
    assert!((35e-9..80e-9).contains(&floor), "{floor}");
    let trials = v["trials"].as_array().unwrap();
    assert_eq!(trials[0]["name"], "standstill");
    // The probe's 40 nm noise dithers its 30 nm code: the standstill is
    // the floor, above the quantisation's q/√12.
    let q = v["quantization_floor_m"].as_f64().unwrap();
    assert!((q / (30e-9 / 12f64.sqrt()) - 1.0).abs() < 1e-12, "{q}");
    assert_eq!(floor, rms(&trials[0]));
    assert_eq!(v["noise_floor_sigma_m"], trials[0]["rms_error_sigma_m"]);
    assert_eq!(trials[1]["name"], "feedback");
    assert_eq!(trials[2]["name"], "feedforward");
    let predicted = v["plan"]["predicted_feedback_rms_error_m"]
        .as_f64()
        .unwrap();
    let want = (predicted * predicted + floor * floor).sqrt();
    assert!(
        (rms(&trials[1]) / want - 1.0).abs() < 0.1,
        "{} {want}",
        rms(&trials[1])
    );
    let best = trials[2..].iter().map(rms).fold(f64::INFINITY, f64::min);
    assert!(rms(&trials[1]) / best >= 10.0, "{v}");
    assert!(best <= 2.0 * floor, "{best} {floor}");
    assert_eq!(v["stop"], "converged");
    // The default smoothing keeps the harmonics below the CNMP band
    // (10, 30, 50 Hz of a 10 Hz line), none in a band.
    assert_eq!(v["plan"]["harmonics"], 5);
    assert!((58.0..60.0).contains(&v["plan"]["scan"]["cutoff_hz"].as_f64().unwrap()));
    assert!(v["plan"]["harmonics_in_zero_bands"]
        .as_array()
        .unwrap()
        .is_empty());
    check_files(dir.path(), &v);
}

/// A probe whose code (300 nm) is far wider than its noise (none): a
/// still reading stays on one code, so the standstill's RMS error (a few
/// tens of nm of the loop hunting between two codes) is no floor for a
/// scan, which crosses codes and leaves about the uniform quantisation
/// error, `q/√12` = 86.6 nm (Widrow & Kollár, *Quantization Noise*,
/// 2008). The noise floor is that, exactly and without a σ, and the
/// feedforward trial converges on it (against the standstill it read 5×
/// "the floor", and learning ran its whole budget for nothing).
#[test]
fn a_coarse_probes_noise_floor_is_its_quantisation() {
    let dir = tmp();
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"),
    )
    .unwrap();
    let text = set_key(&text, "noise_rms_m", "0.0");
    let text = set_key(&text, "quantization_m", "300e-9");
    let cfg = dir.path().join("coarse.toml");
    std::fs::write(&cfg, text).unwrap();
    let (_, v) = track(dir.path(), &["--config", cfg.to_str().unwrap()]);
    let want = 300e-9 / 12f64.sqrt();
    for key in ["quantization_floor_m", "noise_floor_m"] {
        let got = v[key].as_f64().unwrap();
        assert!((got / want - 1.0).abs() < 1e-12, "{key}: {got} {want}");
    }
    assert_eq!(v["noise_floor_sigma_m"], 0.0);
    let trials = v["trials"].as_array().unwrap();
    assert!(rms(&trials[0]) < 0.5 * want, "one code: {}", trials[0]);
    let ff = &trials[2];
    assert_eq!(ff["name"], "feedforward");
    let of = ff["of_noise_floor"].as_f64().unwrap();
    assert!((0.8..1.5).contains(&of), "{ff}");
    assert!((of - rms(ff) / want).abs() < 1e-9 * of, "{ff}");
    assert_eq!(v["stop"], "converged", "{v}");
    assert_eq!(v["best_trial"], "feedforward");
    // The text names the floor's source as the book shows it
    // (docs/src/jobs/track.md, *The noise floor*).
    let out = path_in(dir.path(), "text");
    let o = run(&["track", "--config", cfg.to_str().unwrap(), "--out", &out]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    let line = text
        .lines()
        .find(|l| l.starts_with("  noise floor"))
        .unwrap_or_else(|| panic!("no noise floor line:\n{text}"));
    let shown: Vec<String> = doc_blocks()
        .into_iter()
        .filter(|b| b.lang == "text" && b.body.starts_with("  noise floor"))
        .map(|b| b.body.trim_end().to_string())
        .collect();
    assert_eq!(shown, [line], "the book's sample is stale");
}

/// With a nominal model off the bench (masses +15 %, bearings −14 %) the
/// feedforward leaves several times the noise floor; learning brings the
/// error down every trial and converges within the budget of 10, ≥ 10×
/// below feedback alone, without a trial growing.
#[test]
fn learning_corrects_a_model_that_is_off() {
    let dir = tmp();
    let model = off_model(dir.path());
    let (_, v) = track(dir.path(), &["--model", model.to_str().unwrap()]);
    let floor = v["noise_floor_m"].as_f64().unwrap();
    let trials = v["trials"].as_array().unwrap();
    let ff = rms(&trials[2]);
    assert!(ff > 2.0 * floor, "the model is off: {ff} {floor}");
    let learning: Vec<f64> = trials[3..].iter().map(rms).collect();
    assert!(!learning.is_empty() && learning.len() <= 10, "{v}");
    let mut last = ff;
    for e in &learning {
        assert!(*e < last, "{learning:?}");
        last = *e;
    }
    assert_eq!(v["stop"], "converged");
    assert!(last <= 1.5 * floor);
    assert!(rms(&trials[1]) / last >= 10.0);
    assert_eq!(v["plan"]["model"], model.to_str().unwrap());
    check_files(dir.path(), &v);
}

/// `bench track` of a 10 µm move and back at 1 line/s, 200 lines, one
/// learning trial, with the feedforward `kind`.
fn ten_micron_move(dir: &Path, kind: &str) -> Value {
    let args = [
        "--scan",
        "move",
        "--amplitude-m",
        "10e-6",
        "--line-rate-hz",
        "1",
        "--periods",
        "200",
        "--trials",
        "1",
        "--feedforward-kind",
        kind,
    ];
    track(dir, &args).1
}

/// A 10 µm move and back at 1 line/s with the default fourth-order
/// limits (v 1 mm/s, a 0.1 m/s², j 40 m/s³, s 2·10⁴ m/s⁴), 200 lines
/// averaged. The profile is the one worked out by hand from Lambrechts
/// et al.'s rule: `t_s = j/s` = 2 ms, the jerk phase to `a/j` = 2.5 ms,
/// the acceleration phase cut by the distance at 8 ms (`w₃² + 4.5 ms·w₃
/// = d/a`), the velocity box `d/v̂` = 12.5 ms: 25 ms in all. With the
/// bench's own model the stable inversion tracks the move within ±10 nm
/// throughout, so it settles as the reference arrives; feedback alone on
/// the same profile takes more than 3× as long (issue 44's target).
#[test]
fn a_move_settles_three_times_sooner_with_the_feedforward() {
    let dir = tmp();
    let v = ten_micron_move(dir.path(), "inverse");
    let plan = &v["plan"];
    let widths: Vec<f64> = plan["move_profile"]["widths_s"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w.as_f64().unwrap())
        .collect();
    for (w, e) in widths.iter().zip([2e-3, 2.5e-3, 8e-3, 12.5e-3]) {
        assert!((w - e).abs() < 1e-9, "{widths:?}");
    }
    let band = plan["settle_band_m"].as_f64().unwrap();
    assert_eq!(band, 10e-9);
    let trials = v["trials"].as_array().unwrap();
    let settle = |i: usize| trials[i]["settle_time_s"].as_f64();
    assert!(settle(0).is_none(), "the standstill has no move");
    let (fb, ff) = (settle(1).unwrap(), settle(2).unwrap());
    let tick = 1.0 / 5000.0;
    assert!((ff - 25e-3).abs() <= tick, "feedforward {ff} s");
    assert!(fb > 3.0 * ff, "feedback {fb} s, feedforward {ff} s");
    let speedup = v["settle_speedup"].as_f64().unwrap();
    assert!((speedup - fb / ff).abs() < 1e-9);
    for t in &trials[1..] {
        let noise = t["settle_noise_sigma_m"].as_f64().unwrap();
        assert!(4.0 * noise < band, "{t}");
        assert_eq!(t["settle_trusted"], true, "{t}");
    }
    check_files_of(dir.path(), &v, 200);
    // The snap feedforward: 1/P's Taylor series at 0 Hz, which diverges
    // at the plant's lowest zero (the MMP pair at 22.6 Hz). It tracks the
    // move to the noise floor in RMS, but its error around 22.6 Hz and
    // above keeps the move out of ±10 nm long after the inverse's.
    let dir = tmp();
    let s = ten_micron_move(dir.path(), "snap");
    assert_eq!(s["plan"]["feedforward_kind"], "snap");
    let c2 = s["plan"]["derivative_gains"]["gains"][2].as_f64().unwrap();
    assert!(c2 > 0.0, "a mass: {c2}");
    let t = &s["trials"][2];
    assert!(rms(t) < 1.5 * rms(&s["trials"][0]), "{t}");
    let snap_settle = t["settle_time_s"].as_f64().unwrap();
    assert!(
        snap_settle > 2.0 * ff,
        "snap {snap_settle} s, inverse {ff} s"
    );
}

/// Every bad value of every numeric flag, each alone: exit 2, the flag
/// named, nothing written (the output directory is never made).
#[test]
fn bad_scans_exit_2_naming_the_flag_and_write_nothing() {
    let dir = tmp();
    let nan = "NaN";
    let cases: Vec<(&str, Vec<&str>)> = vec![
        // Beyond the position limit, beyond the peak current, no length.
        (
            "--amplitude-m",
            vec!["0", "-5e-6", nan, "inf", "-inf", "1e-3", "1", "8e-4"],
        ),
        // Not a whole number of ticks, in the MMP band (16–27.6 Hz), in
        // and above the CNMP band, at Nyquist, none.
        (
            "--line-rate-hz",
            vec![
                "0", "-10", nan, "inf", "7", "20", "80", "500", "2500", "3e9",
            ],
        ),
        (
            "--cutoff-hz",
            vec!["5", "10", "0", "-50", nan, "inf", "2501", "1e12"],
        ),
        (
            "--learning-gain",
            vec!["0", "-0.5", "1.5", nan, "inf", "1e-400"],
        ),
        ("--trials", vec!["0", "101", "-1", "1.5", "x"]),
        ("--periods", vec!["0", "1001", "-3", "x"]),
        ("--scan", vec!["square", "", "TRIANGLE"]),
        (
            "--feedforward-kind",
            vec!["x", "", "INVERSE", "acceleration"],
        ),
    ];
    for (flag, values) in cases {
        for value in values {
            let out = path_in(dir.path(), "never");
            let o = run(&["track", "--out", &out, flag, value]);
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{flag} {value}: {err}");
            assert!(err.contains(flag), "{flag} {value}: {err}");
            assert!(!Path::new(&out).exists(), "{flag} {value}");
        }
    }
    // A move's limits and band, each alone: none, negative, not a number,
    // beyond what crosses the stroke (1.6 mm) within one tick (0.2 ms:
    // 8 m/s, 4e4 m/s², 2e8 m/s³, 1e12 m/s⁴); a band beyond the move; a
    // line too short for the move and its dwell.
    let move_cases: Vec<(&str, Vec<&str>)> = vec![
        ("--max-velocity-m-s", vec!["0", "-1e-3", nan, "inf", "8.1"]),
        (
            "--max-acceleration-m-s2",
            vec!["0", "-0.1", nan, "inf", "4.1e4"],
        ),
        ("--max-jerk-m-s3", vec!["0", "-40", nan, "-inf", "2.1e8"]),
        (
            "--max-snap-m-s4",
            vec!["0", "-2e4", nan, "inf", "x", "", "1.1e12"],
        ),
        ("--settle-band-m", vec!["0", "-1e-8", nan, "1e-5", "inf"]),
        // The default 5 µm move lasts 19.3 ms: a line of 1/(4·19.3 ms)
        // = 12.9 lines/s at most.
        ("--line-rate-hz", vec!["15.625", "25", "50"]),
    ];
    for (flag, values) in move_cases {
        for value in values {
            let out = path_in(dir.path(), "never");
            let o = run(&["track", "--scan", "move", "--out", &out, flag, value]);
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{flag} {value}: {err}");
            assert!(err.contains(flag), "{flag} {value}: {err}");
            assert!(!Path::new(&out).exists(), "{flag} {value}");
        }
    }
    let out = path_in(dir.path(), "never");
    let o = run(&["track", "--out", &out, "--model", "/nonexistent.toml"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--model"));
    let o = run(&["track", "--out", &out, "--controller", "nosuch"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--controller"));
    assert!(!Path::new(&out).exists());
}

/// A second run into the same directory is refused before anything is
/// enabled, and replaces the first with `--overwrite`.
#[test]
fn a_second_run_refuses_the_first_ones_files() {
    let dir = tmp();
    let (_, first) = track(dir.path(), &["--periods", "1"]);
    let out = path_in(dir.path(), "run");
    let o = run(&["track", "--out", &out, "--periods", "1"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("trial-00-standstill.mcap"));
    let again: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("run/track.json")).unwrap())
            .unwrap();
    assert_eq!(again, first);
    let (_, v) = track(dir.path(), &["--periods", "1", "--overwrite"]);
    check_files(dir.path(), &v);
}

/// A learned feedforward replays: started from it, the run's first scan
/// trial is as good as the learning trial it came from (within 10 %, the
/// noise differing), and learning goes on from there. A table learned
/// for another line, controller or scan, every mutation of its text that
/// breaks it, and one whose feedforward needs more current than the coil
/// may carry (predicted on the model) are refused with exit 2 naming
/// `--feedforward`, nothing written.
#[test]
fn a_learned_feedforward_replays_and_a_foreign_one_is_refused() {
    let dir = tmp();
    let model = off_model(dir.path());
    let model = model.to_str().unwrap().to_string();
    let (_, first) = track(dir.path(), &["--model", &model, "--trials", "1"]);
    let learned = rms(&first["trials"][3]);
    let csv = dir.path().join("run/feedforward.csv");
    let csv_s = csv.to_str().unwrap().to_string();
    let again = dir.path().join("again");
    let o = run(&[
        "track",
        "--json",
        "--out",
        again.to_str().unwrap(),
        "--model",
        &model,
        "--feedforward",
        &csv_s,
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v = json_stdout(&o);
    assert_eq!(v["trials"][2]["name"], "replayed");
    let replayed = rms(&v["trials"][2]);
    assert!(
        (replayed / learned - 1.0).abs() < 0.1,
        "{replayed} {learned}"
    );
    assert!(again.join("trial-02-replayed.mcap").is_file());

    let refused = |args: &[&str], what: &str| {
        let out = path_in(dir.path(), "never");
        let mut all = vec!["track", "--out", out.as_str(), "--model", &model];
        all.extend_from_slice(args);
        let o = run(&all);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{what}: {err}");
        assert!(err.contains("--feedforward"), "{what}: {err}");
        assert!(!Path::new(&out).exists(), "{what}");
    };
    refused(
        &["--feedforward", &csv_s, "--line-rate-hz", "12.5"],
        "another line",
    );
    refused(&["--feedforward", &csv_s, "--slow"], "another controller");
    refused(
        &["--feedforward", &csv_s, "--amplitude-m", "4e-6"],
        "another scan",
    );
    // Generated mutations of the table's text.
    let good = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = good.lines().collect();
    let mut mutants: Vec<(String, String)> = vec![
        ("empty".into(), String::new()),
        ("no identity".into(), lines[2..].join("\n")),
        (
            "no header".into(),
            [&lines[..2], &lines[3..]].concat().join("\n"),
        ),
        ("a line short".into(), lines[..lines.len() - 1].join("\n")),
        (
            "a line more".into(),
            format!("{good}{},0.1,0,0\n", lines.len() - 3),
        ),
        (
            "another rate".into(),
            good.replacen("\"rate_hz\":5000.0", "\"rate_hz\":4000.0", 1),
        ),
        (
            "another amplifier".into(),
            good.replacen("\"bandwidth_hz\":", "\"bandwidth_hz\":1", 1),
        ),
    ];
    // Every line parses and matches, but the feedforward needs more current
    // than the coil may carry.
    let scaled: Vec<String> = lines
        .iter()
        .enumerate()
        .map(|(i, l)| {
            if i < 3 {
                return l.to_string();
            }
            let mut c: Vec<String> = l.split(',').map(str::to_string).collect();
            c[3] = format!("{:e}", c[3].parse::<f64>().unwrap() * 500.0);
            c.join(",")
        })
        .collect();
    mutants.push(("500× the current".into(), scaled.join("\n")));
    for i in [3, 100, lines.len() - 1] {
        let cols: Vec<&str> = lines[i].split(',').collect();
        for (what, col, value) in [
            ("NaN feedforward", 3, "NaN"),
            ("inf feedforward", 3, "inf"),
            ("garbage", 3, "0x1p3"),
            ("tick out of order", 0, "7"),
            ("another reference", 2, "1e-3"),
        ] {
            let mut c = cols.clone();
            c[col] = value;
            let mut l = lines.clone();
            let row = c.join(",");
            l[i] = &row;
            mutants.push((format!("{what} at line {i}"), l.join("\n")));
        }
    }
    for (what, text) in mutants {
        let p = dir.path().join("mutant.csv");
        std::fs::write(&p, text).unwrap();
        refused(&["--feedforward", p.to_str().unwrap()], &what);
    }
}

/// The CSV of one line of `x(t)` at the built-in bench's 5 kHz: `rows`
/// rows, `time_s = i/5000`.
fn reference_csv(path: &Path, rows: usize, x: impl Fn(f64) -> f64) {
    let mut text = String::from("# a reference line\ntime_s,position_m\n");
    for i in 0..rows {
        let t = i as f64 / 5000.0;
        text.push_str(&format!("{t:.9},{:e}\n", x(t)));
    }
    std::fs::write(path, text).unwrap();
}

/// `--scan csv`: a reference read from a CSV is the scan it describes. The
/// ±5 µm sine at 10 lines/s written as 500 rows tracks as `--scan sine`
/// does: the same predicted feedback error, and the same trial errors on
/// the same seed (the reference is the same signal; the CSV's rounding is
/// 1e-13 of it). The line played is the CSV's, row for row (the learned
/// table's reference column), and that table replays only for that line.
/// Bad references and flag combinations exit 2 naming the flag, nothing
/// written.
#[test]
fn a_reference_from_a_csv_tracks_as_the_scan_it_describes() {
    let dir = tmp();
    let sine = |t: f64| 5e-6 * (2.0 * std::f64::consts::PI * 10.0 * t).sin();
    let csv = dir.path().join("sine.csv");
    reference_csv(&csv, 500, sine);
    let csv_s = csv.to_str().unwrap().to_string();
    let (_, v) = track(
        dir.path(),
        &["--scan", "csv", "--reference", &csv_s, "--trials", "1"],
    );
    let plan = &v["plan"];
    assert_eq!(plan["scan"]["kind"], "csv");
    assert_eq!(plan["scan"]["line_rate_hz"], 10.0);
    assert_eq!(plan["period_ticks"], 500);
    assert!((plan["scan"]["amplitude_m"].as_f64().unwrap() / 5e-6 - 1.0).abs() < 1e-6);
    let other = dir.path().join("sine-run");
    let o = run(&[
        "track",
        "--json",
        "--out",
        other.to_str().unwrap(),
        "--scan",
        "sine",
        "--trials",
        "1",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let w = json_stdout(&o);
    let rel = |a: f64, b: f64| (a / b - 1.0).abs();
    let key = "predicted_feedback_rms_error_m";
    assert!(
        rel(
            plan[key].as_f64().unwrap(),
            w["plan"][key].as_f64().unwrap()
        ) < 1e-6
    );
    for i in 0..3 {
        let (a, b) = (rms(&v["trials"][i]), rms(&w["trials"][i]));
        assert!(rel(a, b) < 1e-3, "trial {i}: {a} {b}");
    }
    // The line played is the CSV's.
    let table = std::fs::read_to_string(dir.path().join("run/feedforward.csv")).unwrap();
    let rows: Vec<f64> = table
        .lines()
        .skip(3)
        .map(|l| l.split(',').nth(2).unwrap().parse().unwrap())
        .collect();
    assert_eq!(rows.len(), 500);
    for (i, r) in rows.iter().enumerate() {
        assert!((r - sine(i as f64 / 5000.0)).abs() < 1e-15, "tick {i}");
    }
    check_files(dir.path(), &v);
    let learned = dir.path().join("run/feedforward.csv");
    let learned_s = learned.to_str().unwrap().to_string();
    let again = path_in(dir.path(), "again");
    let o = run(&[
        "track",
        "--out",
        &again,
        "--scan",
        "csv",
        "--reference",
        &csv_s,
        "--feedforward",
        &learned_s,
        "--trials",
        "1",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let refused = |args: &[&str], flag: &str, what: &str| {
        let out = path_in(dir.path(), "never");
        let mut all = vec!["track", "--out", out.as_str(), "--trials", "1"];
        all.extend_from_slice(args);
        let o = run(&all);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{what}: {err}");
        assert!(err.contains(flag), "{what}: {err}");
        assert!(!Path::new(&out).exists(), "{what}");
    };
    let half = dir.path().join("half.csv");
    reference_csv(&half, 500, |t| 0.5 * sine(t));
    let half_s = half.to_str().unwrap().to_string();
    refused(
        &[
            "--scan",
            "csv",
            "--reference",
            &half_s,
            "--feedforward",
            &learned_s,
        ],
        "--feedforward",
        "another line's table",
    );
    refused(&["--scan", "csv"], "--reference", "csv without a reference");
    refused(
        &["--reference", &csv_s],
        "--reference",
        "a reference with a triangle",
    );
    refused(
        &[
            "--scan",
            "csv",
            "--reference",
            &csv_s,
            "--amplitude-m",
            "5e-6",
        ],
        "--amplitude-m",
        "an amplitude with a csv",
    );
    refused(
        &[
            "--scan",
            "csv",
            "--reference",
            &csv_s,
            "--line-rate-hz",
            "12.5",
        ],
        "--line-rate-hz",
        "another line rate",
    );
    // Lines the plan refuses: beyond the stroke, a fundamental in the
    // zeros' band (20 rows: 250 Hz), fewer than 8 rows.
    let mut cases: Vec<(String, String, &str)> = Vec::new();
    let mut write = |name: &str, rows: usize, x: &dyn Fn(f64) -> f64, flag: &'static str| {
        let p = dir.path().join(name);
        reference_csv(&p, rows, x);
        cases.push((name.to_string(), p.to_str().unwrap().to_string(), flag));
    };
    write("beyond-stroke.csv", 500, &|t| 1e3 * sine(t), "--reference");
    write("too-fast.csv", 20, &sine, "--line-rate-hz");
    write("seven.csv", 7, &sine, "--reference");
    write("still.csv", 500, &|_| 0.0, "--reference");
    // Generated mutations of the good table's text.
    let good = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = good.lines().collect();
    let mut mutants: Vec<(String, String)> = vec![
        ("empty".into(), String::new()),
        (
            "no header".into(),
            [&lines[..1], &lines[2..]].concat().join("\n"),
        ),
        (
            "another header".into(),
            good.replacen("time_s,position_m", "t,x", 1),
        ),
        (
            "three columns".into(),
            good.replacen("time_s,position_m", "time_s,position_m,v", 1),
        ),
    ];
    for i in [2, 200, lines.len() - 1] {
        let cols: Vec<&str> = lines[i].split(',').collect();
        for (what, col, value) in [
            ("NaN position", 1, "NaN"),
            ("inf position", 1, "inf"),
            ("garbage", 1, "0x1p3"),
            ("a time off its tick", 0, "0.5"),
            ("no time", 0, ""),
        ] {
            let mut c = cols.clone();
            c[col] = value;
            let row = c.join(",");
            let mut l = lines.clone();
            l[i] = &row;
            mutants.push((format!("{what} at line {i}"), l.join("\n")));
        }
        // The last row missing is a shorter line, not a bad one.
        if i + 1 < lines.len() {
            let mut l = lines.clone();
            l.remove(i);
            mutants.push((format!("line {i} missing"), l.join("\n")));
        }
    }
    for (n, (what, text)) in mutants.into_iter().enumerate() {
        let name = format!("mutant-{n}.csv");
        let p = dir.path().join(&name);
        std::fs::write(&p, text).unwrap();
        cases.push((what, p.to_str().unwrap().to_string(), "--reference"));
    }
    for (what, path, flag) in &cases {
        refused(&["--scan", "csv", "--reference", path], flag, what);
    }
}

/// `--learning-ps`: the learning filter from the PS that `bench control
/// --verify` measured on the shipped bench (the fast loop, simulated), for
/// a model 15 % off. Each learned harmonic's measured PS is the true loop's
/// (the analytic `P/(1 + CP)` of the simulated plant, its ZOH, amplifier
/// and discrete controller) within 3σ + 1 %, and the contraction bound at
/// 2σ that the plan reports covers the true contraction `|1 − α·PS/P̂S|`
/// (which is `1 − α` within the measurement's error); learning converges.
/// A PS of another controller, a recording without a verify, and
/// generated mutations of the recording are refused, exit 2, nothing run.
#[test]
fn learning_from_the_measured_ps_holds_its_bound_and_a_foreign_one_is_refused() {
    use bench::control::verify::ModelLoop;
    use bench::control::DiscreteController;
    use bench_plant::model::Sr4dof;
    use bench_plant::sim::ZohPlant;
    let dir = tmp();
    let model = off_model(dir.path());
    let model = model.to_str().unwrap().to_string();
    let verified = path_in(dir.path(), "verify.mcap");
    let o = run(&["control", "--fast", "--verify", "--out", &verified]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (_, v) = track(dir.path(), &["--model", &model, "--learning-ps", &verified]);
    let plan = &v["plan"];
    assert_eq!(plan["learning_filter"], "measured");
    assert_eq!(plan["learning_ps"], verified.as_str());
    // The true loop, independent of the measurement.
    let cfg = bench::config::BenchConfig::from_toml(
        bench::config::BUILTIN_CONFIG_TOML,
        Path::new("builtin"),
    )
    .unwrap();
    let period_s = cfg.loop_.period_ns() as f64 * 1e-9;
    let truth = Sr4dof::new(cfg.plant).unwrap();
    let zoh = ZohPlant::new(&truth, &cfg.actuator, period_s);
    let ctrl = DiscreteController::new(
        &cfg.controller["fast"],
        period_s,
        cfg.actuator.peak_current_a,
    );
    let ml = ModelLoop {
        plant: &zoh,
        ctrl: &ctrl,
        link_delay_periods: 0,
    };
    let alpha = plan["learning_gain"].as_f64().unwrap();
    let checks = plan["learning_checks"].as_array().unwrap();
    assert_eq!(checks.len(), 5, "{plan}");
    let mut worst: f64 = 0.0;
    for c in checks {
        let f = c["frequency_hz"].as_f64().unwrap();
        let ps_true = ml.process_sensitivity(f);
        let m = c["measured_ps_magnitude_m_per_a"].as_f64().unwrap();
        let ph = c["measured_ps_phase_deg"].as_f64().unwrap().to_radians();
        let sigma = c["measured_ps_sigma_m_per_a"].as_f64().unwrap();
        let ps = bench::ident::C64::from_polar(m, ph);
        assert!(
            (ps - ps_true).norm() <= 3.0 * sigma + 0.01 * ps_true.norm(),
            "{f} Hz: measured {ps} ± {sigma}, true {ps_true}"
        );
        let bound = c["contraction_bound"].as_f64().unwrap();
        let true_contraction = (bench::ident::C64::new(1.0, 0.0) - ps_true * alpha / ps).norm();
        assert!(
            true_contraction <= bound,
            "{f} Hz: {true_contraction} > {bound}"
        );
        assert!(
            (true_contraction - (1.0 - alpha)).abs() < 0.03,
            "{f} Hz: {true_contraction}"
        );
        if c["learned"] == true {
            assert!(bound < 1.0);
            worst = worst.max(bound);
        }
    }
    let margin = plan["convergence_margin"].as_f64().unwrap();
    assert!(
        (margin - (1.0 - worst)).abs() < 1e-12 && margin > 0.5,
        "{margin}"
    );
    assert_eq!(v["stop"], "converged", "{v}");
    check_files(dir.path(), &v);
    // The text report says what was learned and the margin.
    let text_run = path_in(dir.path(), "text");
    let o = run(&[
        "track",
        "--out",
        &text_run,
        "--model",
        &model,
        "--learning-ps",
        &verified,
        "--trials",
        "1",
    ]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{text}");
    assert!(
        text.contains("learning filter: L = α/PS measured")
            && text.contains(&format!("convergence margin {margin:.3} at 2σ"))
            && text.contains("harmonic   2 (   20.0 Hz)")
            && text.contains("not learned: in a zero's band"),
        "{text}"
    );

    // Refused: exit 2 naming the flag, nothing run or written.
    let refused = |extra: &[&str], path: &str, what: &str| {
        let out = path_in(dir.path(), "never");
        let mut all = vec![
            "track",
            "--out",
            out.as_str(),
            "--model",
            &model,
            "--learning-ps",
            path,
        ];
        all.extend_from_slice(extra);
        let o = run(&all);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{what}: {err}");
        assert!(err.contains("--learning-ps"), "{what}: {err}");
        assert!(!Path::new(&out).exists(), "{what}");
        err.to_string()
    };
    let err = refused(&["--slow"], &verified, "another controller");
    assert!(err.contains("controller"), "{err}");
    let err = refused(
        &["--backend", "serial:/dev/bench-none"],
        &verified,
        "another backend",
    );
    assert!(err.contains("the backend sim (this run: serial)"), "{err}");
    let step = path_in(dir.path(), "step.mcap");
    assert!(run(&["control", "--fast", "--out", &step]).status.success());
    let err = refused(&[], &step, "no verify");
    assert!(err.contains("/control/verify"), "{err}");
    let missing = path_in(dir.path(), "missing.mcap");
    refused(&[], &missing, "missing");
    // Generated mutations of the recording: cut short, bytes flipped, the
    // verify's PS columns renamed or shortened in place.
    let good = std::fs::read(&verified).unwrap();
    let mut mutants: Vec<(String, Vec<u8>)> = vec![("empty".into(), Vec::new())];
    for frac in [0.01, 0.3, 0.6] {
        mutants.push((
            format!("cut at {frac}"),
            good[..(good.len() as f64 * frac) as usize].to_vec(),
        ));
    }
    for (from, to) in [
        (
            &b"\"ps_sigma_m_per_a\":["[..],
            &b"\"ps_sigma_m_per_b\":["[..],
        ),
        (
            &b"\"ps_magnitude_m_per_a\":["[..],
            &b"\"ps_magnitude_m_per_b\":["[..],
        ),
        (
            &b"\"controller\":\"fast\""[..],
            &b"\"controller\":\"slow\""[..],
        ),
    ] {
        if let Some(i) = good.windows(from.len()).rposition(|w| w == from) {
            let mut m = good.clone();
            m[i..i + to.len()].copy_from_slice(to);
            mutants.push((String::from_utf8_lossy(to).into_owned(), m));
        }
    }
    assert!(
        mutants.len() >= 6,
        "the recording's fields are where the test looks"
    );
    for (what, bytes) in mutants {
        let p = dir.path().join("mutant.mcap");
        std::fs::write(&p, bytes).unwrap();
        refused(&[], p.to_str().unwrap(), &what);
    }
}

/// The learning judges the next trial's current from the last trial's
/// measured command, not from the model alone: with a model 15 % off and a
/// ±0.4 mm scan, the model predicts the feedforward trial's command
/// 10 % low, while each learning trial's command is predicted within 3 %
/// of what the coil then carries. With `actuator.continuous_current_a`
/// lowered to 1.15 A, below what learning would need (≈ 1.22 A), learning
/// stops before its first trial (`limit`), the feedforward trial's table
/// is kept, and the warning names the key and the current.
#[test]
fn learning_stops_before_a_trial_beyond_the_coils_rating() {
    let dir = tmp();
    let model = off_model(dir.path());
    let model = model.to_str().unwrap();
    let (_, v) = track(
        dir.path(),
        &["--model", model, "--amplitude-m", "4e-4", "--trials", "2"],
    );
    let trials = v["trials"].as_array().unwrap();
    let command = |t: &Value| t["command_rms_a"].as_f64().unwrap();
    let predicted = |t: &Value| t["predicted_command_rms_a"].as_f64().unwrap();
    let ff = &trials[2];
    assert!(predicted(ff) / command(ff) < 0.95, "the model is off: {ff}");
    for t in &trials[3..] {
        assert!((predicted(t) / command(t) - 1.0).abs() < 0.03, "{t}");
    }
    assert!(command(&trials[3]) > 1.15, "{}", trials[3]);

    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"),
    )
    .unwrap();
    let low = dir.path().join("low.toml");
    std::fs::write(&low, set_key(&text, "continuous_current_a", "1.15")).unwrap();
    let out = path_in(dir.path(), "low");
    let o = run(&[
        "track",
        "--json",
        "--config",
        low.to_str().unwrap(),
        "--model",
        model,
        "--amplitude-m",
        "4e-4",
        "--out",
        &out,
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v = json_stdout(&o);
    assert_eq!(v["stop"], "limit");
    assert_eq!(v["trials"].as_array().unwrap().len(), 3, "{v}");
    assert_eq!(v["best_trial"], "feedforward");
    assert!(Path::new(&out).join("feedforward.csv").is_file());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("actuator.continuous_current_a 1.15 A") && err.contains("A RMS"),
        "{err}"
    );
    assert!(!Path::new(&out).join("trial-03-learning-1.mcap").exists());
}

/// A learning trial that faults (a NaN reading injected 0.3 s into the
/// first learning trial, after the three trials before it, each of its
/// warm-up, 5 measured lines and 2 to end) ends the run with the fault's
/// exit status: every recording, the faulted one too, is complete,
/// `track.json` and `track.png` hold the trials before it, and the best
/// feedforward learned so far is kept (`stop`: `fault`).
#[test]
fn a_trial_that_faults_stops_the_learning_and_keeps_everything() {
    let dir = tmp();
    let model = off_model(dir.path());
    let (_, first) = track(
        dir.path(),
        &["--model", model.to_str().unwrap(), "--trials", "1"],
    );
    let lines = first["plan"]["warm_up_periods"].as_u64().unwrap() + 5 + 2;
    let at = format!("nan@{}", 3.0 * lines as f64 / 10.0 + 0.3);
    let out = path_in(dir.path(), "faulted");
    let o = run(&[
        "track",
        "--out",
        &out,
        "--model",
        model.to_str().unwrap(),
        "--inject-fault",
        &at,
    ]);
    assert_eq!(o.status.code(), Some(3), "{o:?}");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("safety fault: probe_not_finite"), "{err}");
    assert!(err.contains("trial-03-learning-1.mcap"), "{err}");
    let v = faulted_in_learning_1(Path::new(&out));
    assert_eq!(v["best_trial"], "feedforward");
    // A fault of no known kind is refused before anything runs.
    let o = run(&[
        "track",
        "--out",
        &path_in(dir.path(), "hw"),
        "--inject-fault",
        "smoke@1",
    ]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--inject-fault smoke@1"));
    assert!(!dir.path().join("hw").exists());
}

/// The directory of a run whose first learning trial faulted: its
/// summary stops at `fault` after the three trials before, and those and
/// the faulted one are finished recordings (none after it); the
/// feedforward learned before and the figure are written. The summary.
pub(crate) fn faulted_in_learning_1(dir: &Path) -> Value {
    let v: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("track.json")).unwrap()).unwrap();
    assert_eq!(v["stop"], "fault", "{v}");
    assert_eq!(v["trials"].as_array().unwrap().len(), 3);
    for name in [
        "trial-00-standstill.mcap",
        "trial-01-feedback.mcap",
        "trial-02-feedforward.mcap",
        "trial-03-learning-1.mcap",
    ] {
        let rec = dir.join(name);
        assert!(rec.is_file(), "{rec:?}");
        assert!(!dir.join(format!("{name}.part")).exists());
        assert!(!mcap_messages(&rec).is_empty(), "{rec:?}");
    }
    assert!(!dir.join("trial-04-learning-2.mcap").exists());
    assert!(dir.join("feedforward.csv").is_file());
    assert!(dir.join("track.png").is_file());
    v
}

/// Issue 44's target on five benches that differ from the shipped one,
/// measured by hand (ignored: five chirps, designs, verifies and ten
/// learning runs, ~3 min): each bench (masses and bearing stiffnesses
/// ±15 %, operating point 2–8.5 % of L, mass asymmetry ±12 %, drawn from
/// SplitMix64) is measured with `bench chirp`, its controller designed
/// from the CSV alone (`bench design`), its loop measured with `bench
/// control --verify`, and the ±5 µm raster learned with that controller
/// on a model 3 % off the bench (m1 +3 %, bearings −3 %: `track` takes a
/// config's [plant]): once with `L` from the model's PS (printed), once
/// from the measured PS (`--learning-ps`, asserted). Both residue sign
/// patterns must be among the five; on every bench learning must converge
/// (within 1.5× the noise floor) and never grow two trials in a row.
/// Prints one line per run.
///
/// Met (2026-11-30, this VM): all five converge with either `L`, at
/// 1.34–1.46× the floor and 4.1–4.6× below feedback alone, in 0–2 learning
/// trials with the measured PS and 0–4 with the model's. Before the
/// warm-up lasted five of the loop's slowest time constants (two lines
/// then; 31–60 lines now at these loops' 0.6–1.2 s), three or four
/// converged: what was left of the fade-in's transient differed from line
/// to line, learning could not remove it, and on bench 0 it grew trial by
/// trial. Run:
#[test]
#[ignore]
fn five_random_benches_learn_with_their_designed_controllers() {
    let dir = tmp();
    let draw = |i: u64, lo: f64, hi: f64| {
        let u = (bench::splitmix::splitmix64(i.wrapping_mul(bench::splitmix::GAMMA)) >> 11) as f64
            / (1u64 << 53) as f64;
        lo + (hi - lo) * u
    };
    let (mut patterns, mut failed) = (Vec::new(), Vec::new());
    for b in 0..5u64 {
        let mut doc: toml_edit::DocumentMut = bench::config::BUILTIN_CONFIG_TOML.parse().unwrap();
        let plant = doc["plant"].as_table_mut().unwrap();
        let mut k = 100 * b;
        let mut scale = |key: &str| {
            let v = plant[key].as_float().unwrap();
            k += 1;
            plant[key] = toml_edit::value(v * draw(k, 0.85, 1.15));
        };
        for key in [
            "m1_kg",
            "m2_kg",
            "m3_kg",
            "m4_kg",
            "m5_kg",
            "k4_n_per_m",
            "k5_n_per_m",
        ] {
            scale(key);
        }
        plant["operating_point_m"] = toml_edit::value(draw(k + 1, 0.02, 0.085) * 0.0475);
        let sign = if b % 2 == 0 { 1.0 } else { -1.0 };
        plant["mass_asymmetry"] = toml_edit::value(sign * draw(k + 2, 0.04, 0.12));
        let truth = dir.path().join(format!("bench{b}.toml"));
        std::fs::write(&truth, doc.to_string()).unwrap();
        let truth_s = truth.to_str().unwrap();
        let mcap = path_in(dir.path(), &format!("bench{b}.mcap"));
        let o = run(&["chirp", "--config", truth_s, "--out", &mcap, "--json"]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let csv = json_stdout(&o)["frf_csv"].as_str().unwrap().to_string();
        // The lab's model of its bench, off it as a fit is: m1 +10 %, the
        // bearings −10 % (`track` takes a config's [plant] as its model).
        let mut off = doc.clone();
        for (key, f) in [("m1_kg", 1.03), ("k4_n_per_m", 0.97), ("k5_n_per_m", 0.97)] {
            let v = off["plant"][key].as_float().unwrap();
            off["plant"][key] = toml_edit::value(v * f);
        }
        let fitted = dir.path().join(format!("bench{b}.model.toml"));
        std::fs::write(&fitted, off.to_string()).unwrap();
        let fitted = fitted.to_str().unwrap().to_string();
        let designed = path_in(dir.path(), &format!("bench{b}.designed.toml"));
        let o = run(&["design", &csv, "--out", &designed, "--no-plot", "--json"]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let d = json_stdout(&o);
        let name = d["name"].as_str().unwrap().to_string();
        let pattern = d["modes"]["inputs"][0]["pair_signs"]
            .as_str()
            .unwrap()
            .to_string();
        // The designed controller on the true bench.
        let designed_doc: toml_edit::DocumentMut =
            std::fs::read_to_string(&designed).unwrap().parse().unwrap();
        doc["controller"][name.as_str()] = designed_doc["controller"][name.as_str()].clone();
        let run_cfg = dir.path().join(format!("bench{b}.run.toml"));
        std::fs::write(&run_cfg, doc.to_string()).unwrap();
        // The loop measured on the bench: the verify's PS for the learning.
        let verified = path_in(dir.path(), &format!("bench{b}.verify.mcap"));
        let o = run(&[
            "control",
            "--config",
            run_cfg.to_str().unwrap(),
            "--controller",
            &name,
            "--verify",
            "--out",
            &verified,
        ]);
        assert!(
            matches!(o.status.code(), Some(0 | 8)),
            "bench {b}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        for learning_ps in [None, Some(verified.as_str())] {
            let out = path_in(
                dir.path(),
                &format!(
                    "track{b}-{}",
                    if learning_ps.is_some() { "ps" } else { "model" }
                ),
            );
            let mut args = vec![
                "track",
                "--json",
                "--config",
                run_cfg.to_str().unwrap(),
                "--controller",
                &name,
                "--model",
                &fitted,
                "--out",
                &out,
            ];
            if let Some(p) = learning_ps {
                args.extend(["--learning-ps", p]);
            }
            let o = run(&args);
            assert!(
                o.status.success(),
                "bench {b}: {}",
                String::from_utf8_lossy(&o.stderr)
            );
            let v = json_stdout(&o);
            let trials = v["trials"].as_array().unwrap();
            let errors: Vec<f64> = trials.iter().map(rms).collect();
            eprintln!(
                "bench {b} ({pattern}, {} ω* {:.0} rad/s), L from the {}: floor {:.1} nm, feedback {:.1} nm, feedforward {:.1} nm, learning {:?} nm, stop {}, {:.1}× below feedback; convergence margin {}",
                d["strategy"],
                d["performance_bandwidth_rad_s"].as_f64().unwrap_or(f64::NAN),
                v["plan"]["learning_filter"],
                errors[0] * 1e9,
                errors[1] * 1e9,
                errors[2] * 1e9,
                errors[3..].iter().map(|e| (e * 1e10).round() / 10.0).collect::<Vec<_>>(),
                v["stop"],
                v["improvement"].as_f64().unwrap(),
                v["plan"]["convergence_margin"]
            );
            // The target is met with the measured PS; the model's is printed
            // beside it.
            if learning_ps.is_none() {
                continue;
            }
            if v["stop"] != "converged" {
                failed.push(format!("bench {b}: stop {}", v["stop"]));
            }
            if errors[2..].windows(3).any(|w| w[2] > w[1] && w[1] > w[0]) {
                failed.push(format!("bench {b} grew: {errors:?}"));
            }
        }
        patterns.push(pattern);
    }
    assert!(failed.is_empty(), "{failed:?}");
    assert!(
        patterns.iter().any(|p| p == "alternating")
            && patterns.iter().any(|p| p == "non-alternating"),
        "{patterns:?}"
    );
}

/// Issue 44, item 2: the feedforward from the bench's fitted model. The
/// bench is the shipped one with the stage 15 % heavier and the X
/// bearings 14 % softer than its nominal file. One default chirp of it,
/// `bench fit --update` from the nominal file with the stage's mass and
/// the bearings free (the force constant held), gives both within 3σ +
/// 0.1 % of the bench's own values (the independent reference: the file
/// the simulator runs). With that fitted model the feedforward trial is
/// within the convergence band of the noise floor at once, with both
/// feedforward kinds; with the nominal model it leaves more than 3× it.
#[test]
fn the_fitted_model_carries_the_feedforward_to_the_noise_floor() {
    let dir = tmp();
    let d = dir.path();
    let bench = off_model(d);
    let bench_s = bench.to_str().unwrap();
    let nominal = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    let nominal_s = nominal.to_str().unwrap();
    let chirp = path_in(d, "chirp.mcap");
    let o = run(&["chirp", "--config", bench_s, "--out", &chirp, "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = json_stdout(&o)["frf_csv"].as_str().unwrap().to_string();
    let fitted = path_in(d, "fitted.toml");
    let o = run(&[
        "fit",
        &csv,
        "--config",
        nominal_s,
        "--update",
        "--free",
        "parallelogram_stiffness_n_per_m,mass_asymmetry,zeta_rigid,zeta_csm,m1_kg,k4_n_per_m",
        "--out",
        &fitted,
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let update = json_stdout(&o)["update"].clone();
    let truth = bench::config::BenchConfig::load(&bench).unwrap().plant;
    for (name, want) in [("m1_kg", truth.m1_kg), ("k4_n_per_m", truth.k4_n_per_m)] {
        let p = update["parameters"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["name"] == name)
            .unwrap_or_else(|| panic!("no {name} in {update}"));
        let (v, s) = (p["value"].as_f64().unwrap(), p["sigma"].as_f64().unwrap());
        assert!(
            (v - want).abs() <= 3.0 * s + 1e-3 * want,
            "{name}: {v} ± {s}, the bench's {want}"
        );
    }
    let written = bench::config::BenchConfig::load(Path::new(&fitted)).unwrap();
    assert!((written.plant.k5_n_per_m / truth.k5_n_per_m - 1.0).abs() < 1e-3);
    let ff = |model: &str, kind: &str, out: &str| -> f64 {
        let (_, v) = track(
            d,
            &[
                "--config",
                bench_s,
                "--model",
                model,
                "--feedforward-kind",
                kind,
                "--trials",
                "1",
                "--overwrite",
            ],
        );
        std::fs::rename(d.join("run"), d.join(out)).unwrap();
        v["trials"][2]["of_noise_floor"].as_f64().unwrap()
    };
    for kind in ["inverse", "snap"] {
        let x = ff(&fitted, kind, &format!("fitted-{kind}"));
        assert!(x < 1.5, "{kind} from the fitted model: {x}× the floor");
    }
    let x = ff(nominal_s, "inverse", "nominal");
    assert!(x > 3.0, "from the nominal model: {x}× the floor");
}
