//! `bench chirp` end to end on the simulated Chapter 5 bench, at the process
//! boundary, against the independent scipy reference in `tests/data/`.

use crate::common;

use common::*;
use serde_json::Value;
use std::path::Path;

/// Resonance frequencies reported in the summary, Hz.
fn resonances(summary: &Value) -> Vec<f64> {
    summary["resonances"]
        .as_array()
        .expect("resonances")
        .iter()
        .map(|r| r["frequency_hz"].as_f64().expect("frequency"))
        .collect()
}

/// Anti-resonance frequencies of the reference: |Im| of its finite zeros, Hz.
fn anti_resonances(reference: &Value) -> Vec<f64> {
    reference["zeros_hz"]
        .as_array()
        .unwrap()
        .iter()
        .map(|z| (z[0].as_f64().unwrap(), z[1].as_f64().unwrap()))
        .filter(|(re, im)| re.hypot(*im) < 1e4 && *im > 0.0)
        .map(|(_, im)| im)
        .collect()
}

/// Runs the default chirp with extra args into `dir`, returns the summary.
fn chirp(dir: &Path, extra: &[&str]) -> Value {
    let out = path_in(dir, "run.mcap");
    let mut args = vec!["chirp", "--json", "--out", &out];
    args.extend_from_slice(extra);
    let o = run(&args);
    assert!(
        o.status.success(),
        "bench chirp failed: {:?}\n{}",
        o.status,
        String::from_utf8_lossy(&o.stderr)
    );
    json_stdout(&o)
}

#[test]
fn frf_matches_the_model_and_finds_the_cnmp_pair() {
    let dir = tmp();
    let s = chirp(dir.path(), &[]);
    let reference = reference("ch5_plus10");
    let rows = read_frf_csv(&dir.path().join("run.frf.csv"));
    assert!(dir.path().join("run.bode.png").exists());
    assert!(dir.path().join("run.mcap").exists());
    assert!(!dir.path().join("run.mcap.part").exists());

    let rf = floats(&reference["frf"]["frequency_hz"]);
    let rmag = floats(&reference["frf"]["magnitude_m_per_a"]);
    let rph = floats(&reference["frf"]["phase_deg"]);
    let modes = floats(&reference["natural_frequencies_hz"]);
    let antis = anti_resonances(&reference);
    let near = |f: f64, set: &[f64]| set.iter().any(|g| (f / g - 1.0).abs() <= 0.03);

    let (mut db_err, mut ph_err) = (Vec::new(), Vec::new());
    let mut checked = 0;
    for [f, mag, ph, coh] in &rows {
        if !(1.0..=300.0).contains(f) {
            continue;
        }
        if !near(*f, &antis) {
            assert!(*coh > 0.95, "coherence {coh} at {f} Hz");
        }
        if near(*f, &modes) || near(*f, &antis) {
            continue;
        }
        checked += 1;
        let m = interp_log(&rf, &rmag, *f);
        let p = interp_log(&rf, &rph, *f);
        db_err.push((20.0 * (mag / m).log10()).abs());
        let d = (ph - p).rem_euclid(360.0);
        ph_err.push(d.min(360.0 - d));
    }
    assert!(checked > 500, "only {checked} points compared");
    let (mdb, mph) = (median(&db_err), median(&ph_err));
    eprintln!("median error over {checked} points: {mdb:.4} dB, {mph:.3} deg");
    assert!(mdb <= 0.5, "median magnitude error {mdb} dB");
    assert!(mph <= 3.0, "median phase error {mph}°");

    // The X rigid-body mode (mode 2 on this bench) and the closely spaced
    // pair, located within 0.5 %.
    let found = resonances(&s);
    for f_ref in [modes[1], modes[2], modes[3]] {
        let best = found
            .iter()
            .map(|f| (f / f_ref - 1.0).abs())
            .fold(f64::INFINITY, f64::min);
        assert!(
            best <= 0.005,
            "mode at {f_ref:.2} Hz: nearest found off by {:.3} %",
            best * 100.0
        );
    }

    // Fig 5-9: +10 %, 8 % shows the CMP-CNMP pattern, and so do the model's
    // zeros (scipy: a complex pair in the right half plane near 83.3 Hz).
    assert_eq!(s["cmp_cnmp"], Value::Bool(true), "{s}");
    let pair = &s["closely_spaced_pair"];
    assert!((pair["net_phase_multiple_deg"].as_f64().unwrap() + 360.0).abs() < 1e-9);
    let rhp_complex = reference["zeros_hz"].as_array().unwrap().iter().any(|z| {
        z[0].as_f64().unwrap() > 0.0
            && z[1].as_f64().unwrap().abs() > 1.0
            && z[0].as_f64().unwrap() < 1e4
    });
    assert!(rhp_complex);
    assert_eq!(s["model"]["cmp_cnmp"], Value::Bool(true));
}

#[test]
fn negative_asymmetry_has_no_cnmp_zeros() {
    let dir = tmp();
    let s = chirp(dir.path(), &["--mass-asymmetry", "-0.10"]);
    let reference = reference("ch5_minus10");
    // scipy: every finite zero in the left half plane.
    assert!(reference["zeros_hz"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|z| z[1].as_f64().unwrap().abs() > 1.0)
        .all(|z| z[0].as_f64().unwrap() < 0.0));
    assert_eq!(s["model"]["cmp_cnmp"], Value::Bool(false));
    assert_eq!(s["cmp_cnmp"], Value::Bool(false), "{s}");
    // The pair is still found (84.7 / 88.8 Hz): the verdict is a measured
    // "no", not a missing pair.
    let pair = &s["closely_spaced_pair"];
    let modes = floats(&reference["natural_frequencies_hz"]);
    assert!(
        (pair["lower_hz"].as_f64().unwrap() / modes[2] - 1.0).abs() < 0.005,
        "{pair}"
    );
    assert!(
        (pair["upper_hz"].as_f64().unwrap() / modes[3] - 1.0).abs() < 0.005,
        "{pair}"
    );
    assert!(pair["net_phase_multiple_deg"].as_f64().unwrap() > -360.0);
}

#[test]
fn recording_reads_back_with_every_topic() {
    let dir = tmp();
    let s = chirp(dir.path(), &["--duration-s", "4", "--f-start-hz", "5"]);
    let path = dir.path().join("run.mcap");
    let msgs = mcap_messages(&path);
    let count = |t: &str| msgs.iter().filter(|m| m.0 == t).count();
    let ticks = s["timing"]["ticks"].as_u64().unwrap() as usize;
    assert_eq!(count("/bench/sample"), ticks);
    assert!(count("/bench/timing") >= 5);
    assert!(count("/bench/event") >= 4);
    assert_eq!(count("/sysid/frf"), 1);
    assert_eq!(count("/sysid/summary"), 1);
    // The run's start, host, version and config hash in the metadata.
    let bytes = std::fs::read(&path).unwrap();
    let summary = mcap::Summary::read(&bytes)
        .unwrap()
        .expect("summary section");
    let run_meta = |name: &str| {
        let idx = summary
            .metadata_indexes
            .iter()
            .find(|m| m.name == name)
            .unwrap_or_else(|| panic!("no {name} metadata"));
        mcap::read::metadata(&bytes, idx).unwrap().metadata
    };
    let run = run_meta("bench.run");
    let start_ns: u64 = run["start_time_unix_ns"].parse().unwrap();
    let now_ns = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64;
    assert!(
        start_ns <= now_ns && now_ns - start_ns < 600_000_000_000,
        "{run:?}"
    );
    assert!(run["start_time_utc"].ends_with('Z'), "{run:?}");
    assert_eq!(run["version"], env!("CARGO_PKG_VERSION"));
    assert!(run.contains_key("host"));
    let config = run_meta("bench.config");
    assert_eq!(run["config_sha256"], config["sha256"]);
    assert_eq!(run["config_sha256"].len(), 64);
    // Samples: consecutive ticks, log time = the run's start (Unix ns) +
    // tick × period.
    let samples: Vec<&(String, u64, Value)> =
        msgs.iter().filter(|m| m.0 == "/bench/sample").collect();
    for (k, (_, log_time, v)) in samples.iter().enumerate() {
        assert_eq!(v["tick"].as_u64(), Some(k as u64));
        assert_eq!(*log_time, start_ns + k as u64 * 200_000);
        for key in ["t_s", "current_command_a", "position_m", "excitation_a"] {
            assert!(v.get(key).is_some(), "sample lacks {key}");
        }
    }
    // The config is in the metadata, and it parses back.
    let meta_names: Vec<String> = summary
        .metadata_indexes
        .iter()
        .map(|m| m.name.clone())
        .collect();
    assert!(
        meta_names.contains(&"bench.config".to_string()),
        "{meta_names:?}"
    );
    let idx = summary
        .metadata_indexes
        .iter()
        .find(|m| m.name == "bench.config")
        .unwrap();
    let meta = mcap::read::metadata(&bytes, idx).unwrap();
    let toml = &meta.metadata["toml"];
    bench::config::BenchConfig::from_toml(toml, Path::new("recorded")).unwrap();
    // Every event again as a foxglove.Log line at the same time.
    let events: Vec<_> = msgs.iter().filter(|m| m.0 == "/bench/event").collect();
    let logs: Vec<_> = msgs.iter().filter(|m| m.0 == "/bench/log").collect();
    assert_eq!(events.len(), logs.len());
    for (e, l) in events.iter().zip(&logs) {
        assert_eq!(e.1, l.1);
        let ts = &l.2["timestamp"];
        let ns = ts["sec"].as_u64().unwrap() * 1_000_000_000 + ts["nsec"].as_u64().unwrap();
        assert_eq!(ns, l.1);
        assert!(l.2["message"]
            .as_str()
            .unwrap()
            .starts_with(e.2["kind"].as_str().unwrap()));
    }
    // Events: started, finished, stopped.
    let kinds: Vec<String> = msgs
        .iter()
        .filter(|m| m.0 == "/bench/event")
        .map(|m| m.2["kind"].as_str().unwrap().to_string())
        .collect();
    for k in [
        "loop_started",
        "job_started",
        "job_finished",
        "loop_stopped",
    ] {
        assert!(kinds.iter().any(|x| x == k), "{k} missing from {kinds:?}");
    }
}

fn sample_stream(path: &Path) -> Vec<(u64, u64, u64)> {
    mcap_messages(path)
        .into_iter()
        .filter(|m| m.0 == "/bench/sample")
        .map(|m| {
            (
                m.2["tick"].as_u64().unwrap(),
                m.2["position_m"].as_f64().unwrap().to_bits(),
                m.2["current_command_a"].as_f64().unwrap().to_bits(),
            )
        })
        .collect()
}

#[test]
fn same_seed_gives_bit_identical_samples() {
    let dir = tmp();
    let args = ["--duration-s", "2", "--f-start-hz", "5", "--seed", "42"];
    let run_into = |name: &str, seed: &str| {
        let out = path_in(dir.path(), name);
        let mut a = vec!["chirp", "--json", "--out", out.as_str()];
        a.extend_from_slice(&args[..4]);
        a.extend_from_slice(&["--seed", seed]);
        let o = run(&a);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        sample_stream(&dir.path().join(name))
    };
    let a = run_into("a.mcap", "42");
    let b = run_into("b.mcap", "42");
    let c = run_into("c.mcap", "43");
    assert_eq!(a.len(), b.len());
    assert!(a == b, "same seed, different samples");
    assert!(a != c, "different seeds gave the same noise");
}

/// A sweep too short for the LPM's window (13 bins of a 4.4 s record are
/// 3 Hz, wider than half the X mode's 0.52 Hz half-power band) is
/// estimated with H1 and says so; the default 60 s sweep (13 bins =
/// 0.2 Hz) runs the configured LPM, with no note.
#[test]
fn a_sweep_too_short_for_the_lpm_says_it_used_h1() {
    let dir = tmp();
    let run_json = |name: &str, extra: &[&str]| {
        let out = path_in(dir.path(), name);
        let mut args = vec!["chirp", "--json", "--out", out.as_str()];
        args.extend(extra);
        let o = run(&args);
        assert!(
            o.status.success() || o.status.code() == Some(9),
            "{}",
            String::from_utf8_lossy(&o.stderr)
        );
        (
            json_stdout(&o),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let (short, err) = run_json("short.mcap", &["--duration-s", "4"]);
    assert_eq!(short["frf_estimator"]["name"], "h1", "{short}");
    let note = short["frf_estimator"]["note"].as_str().unwrap();
    assert!(note.contains("LPM's window"), "{note}");
    assert!(err.contains("H1"), "a warning on stderr: {err}");
    let (long, _) = run_json("long.mcap", &[]);
    assert_eq!(long["frf_estimator"]["name"], "lpm", "{long}");
    assert!(long["frf_estimator"]["note"].is_null());
}
