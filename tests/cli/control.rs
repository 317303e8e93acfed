//! `bench control` end to end on the simulated Chapter 5 bench.

use crate::common;

use common::*;
use serde_json::Value;
use std::path::Path;

const CH5: &str = "bench-config/sr4dof-ch5.toml";

fn shipped_ch5() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(CH5)).unwrap()
}

fn control(dir: &Path, extra: &[&str]) -> (std::process::Output, String) {
    let out = path_in(dir, "run.mcap");
    let mut args = vec!["control", "--json", "--out", out.as_str()];
    args.extend_from_slice(extra);
    let o = run(&args);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    (o, err)
}

fn metric(s: &Value, key: &str) -> f64 {
    s["metrics"][key]
        .as_f64()
        .unwrap_or_else(|| panic!("{key} missing in {s}"))
}

/// Both thesis controllers close a stable loop; the fast one settles
/// faster and, with the configured disturbance, holds position with a
/// smaller σ (thesis: 0.086 s vs 0.166 s, 0.050 µm vs 0.066 µm).
#[test]
fn slow_and_fast_steps() {
    let dir = tmp();
    let mut s = Vec::new();
    for c in ["--slow", "--fast"] {
        // A directory each: bench never replaces a recording.
        let sub = dir.path().join(&c[2..]);
        std::fs::create_dir(&sub).unwrap();
        let (o, err) = control(&sub, &[c]);
        assert!(o.status.success(), "{c}: {err}");
        s.push(json_stdout(&o));
    }
    let (slow, fast) = (&s[0], &s[1]);
    for v in [slow, fast] {
        assert_eq!(v["loop_check"]["closed_loop_stable"], Value::Bool(true));
        assert!(metric(v, "overshoot_pct") < 20.0);
        assert!(metric(v, "steady_state_error_mean_nm").abs() < 20.0);
    }
    let (ts, tf) = (
        metric(slow, "settling_time_s"),
        metric(fast, "settling_time_s"),
    );
    eprintln!("settling: slow {ts:.3} s, fast {tf:.3} s");
    assert!(tf < ts, "fast {tf} s is not faster than slow {ts} s");
    let (ss, sf) = (
        metric(slow, "steady_state_error_std_nm"),
        metric(fast, "steady_state_error_std_nm"),
    );
    eprintln!("steady-state σ: slow {ss:.1} nm, fast {sf:.1} nm");
    assert!(sf < ss, "fast σ {sf} nm is not below slow σ {ss} nm");
    assert!(slow["disturbance_rms_n"].as_f64().unwrap() > 0.0);
    // The thesis' figures without the amplifier lag (Figs 6-8, 6-10).
    let m = |v: &Value, k: &str| v["loop_check"]["model_without_amplifier_lag"][k].clone();
    let wc = |v: &Value| m(v, "crossovers_rad_s")[0].as_f64().unwrap();
    let pm = |v: &Value| m(v, "phase_margin_deg").as_f64().unwrap();
    assert!((wc(slow) - 18.7).abs() <= 1.0 && (pm(slow) - 73.0).abs() <= 3.0);
    assert!((wc(fast) - 285.0).abs() <= 5.0 && (pm(fast) - 42.0).abs() <= 3.0);
    // The recording holds the check, the metrics and setpoints.
    let msgs = mcap_messages(&dir.path().join("fast/run.mcap"));
    assert!(msgs.iter().any(|m| m.0 == "/control/loop_check"));
    let metrics = msgs.iter().find(|m| m.0 == "/control/metrics").unwrap();
    assert_eq!(metrics.2["settling_time_s"].as_f64(), Some(tf));
    let sample = msgs.iter().find(|m| m.0 == "/bench/sample").unwrap();
    assert!(sample.2["setpoint_m"].as_f64().is_some());
    assert!(dir.path().join("fast/run.step.png").exists());
}

#[test]
fn check_only_records_nothing() {
    let dir = tmp();
    let (o, err) = control(dir.path(), &["--fast", "--check-only"]);
    assert!(o.status.success(), "{err}");
    let s = json_stdout(&o);
    assert!(s["metrics"].is_null());
    assert!(files_in(dir.path()).is_empty());
    // The check reports the discretisation that runs and its error to
    // f_s/10 (issue: within 0.1 dB / 1°).
    let d = &s["loop_check"]["discretization"];
    assert_eq!(d["method"], "least_squares", "{d}");
    assert_eq!(d["up_to_hz"].as_f64(), Some(500.0));
    assert!(d["max_error_db"].as_f64().unwrap() <= 0.1, "{d}");
    assert!(d["max_error_deg"].as_f64().unwrap() <= 1.0, "{d}");
    let o = run(&["control", "--slow", "--check-only"]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("phase margin") && text.contains("passed"),
        "{text}"
    );
}

/// A controller whose loop is unstable on the model is refused before
/// enable: exit 2, the failing figure in the message, nothing recorded.
#[test]
fn unstable_controller_is_refused() {
    let dir = tmp();
    let cfg = path_in(dir.path(), "bench.toml");
    std::fs::write(
        &cfg,
        shipped_ch5().replace("gain = 51110.0", "gain = 511100.0"),
    )
    .unwrap();
    let out_dir = dir.path().join("out");
    std::fs::create_dir(&out_dir).unwrap();
    let out = path_in(&out_dir, "run.mcap");
    let o = run(&["control", "--fast", "--config", &cfg, "--out", &out]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("unstable") && err.contains("largest pole"),
        "{err}"
    );
    assert!(files_in(&out_dir).is_empty());
    let o = run(&["control", "--fast", "--config", &cfg, "--check-only"]);
    assert_eq!(o.status.code(), Some(2));
    // The override runs it on the simulator: the supervisor catches it.
    let o = run(&[
        "control",
        "--fast",
        "--config",
        &cfg,
        "--out",
        &out,
        "--override-check",
        "--duration-s",
        "2",
    ]);
    assert_eq!(
        o.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Every injected fault: 0 A from the faulting tick on, faulted until the
/// end (no reset), the fault in the recording, the fault exit status.
#[test]
fn injected_faults_latch_with_zero_current() {
    for (kind, fault) in [
        ("nan", "probe_not_finite"),
        ("frozen", "stale_sample"),
        ("drop", "link"),
        ("jump", "position_jump"),
        ("out_of_range", "probe_out_of_range"),
    ] {
        let dir = tmp();
        let spec = format!("{kind}@1.0");
        let (o, err) = control(
            dir.path(),
            &["--fast", "--duration-s", "2", "--inject-fault", &spec],
        );
        assert_eq!(o.status.code(), Some(3), "{kind}: {err}");
        assert!(err.contains(fault), "{kind}: {err}");
        let msgs = mcap_messages(&dir.path().join("run.mcap"));
        let ev = msgs
            .iter()
            .find(|m| m.0 == "/bench/event" && m.2["kind"] == "fault")
            .unwrap_or_else(|| panic!("{kind}: no fault event"));
        assert_eq!(ev.2["fault"], fault, "{kind}");
        let tick = ev.2["tick"].as_u64().unwrap();
        assert!(
            (4990..=5010).contains(&tick),
            "{kind}: fault at tick {tick}"
        );
        let samples: Vec<&Value> = msgs
            .iter()
            .filter(|m| m.0 == "/bench/sample")
            .map(|m| &m.2)
            .collect();
        let after: Vec<&&Value> = samples
            .iter()
            .filter(|s| s["tick"].as_u64().unwrap() >= tick)
            .collect();
        assert!(!after.is_empty());
        for s in after {
            assert_eq!(s["current_command_a"].as_f64(), Some(0.0), "{kind}: {s}");
            assert_eq!(s["state"], "faulted", "{kind}");
        }
        // Before the fault the loop was running with current flowing.
        assert!(samples[..tick as usize]
            .iter()
            .any(|s| s["current_command_a"].as_f64().unwrap() != 0.0));
        // The last state change keeps it faulted (latched, no reset).
        let last_state = msgs.iter().rev().find(|m| m.0 == "/bench/event").unwrap();
        assert_eq!(last_state.2["state"], "faulted", "{kind}");
    }
}

#[test]
fn bad_controller_input() {
    let dir = tmp();
    let o = run(&["control", "--controller", "nope", "--check-only"]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("nope") && err.contains("fast") && err.contains("slow"),
        "{err}"
    );
    let cases = [
        (
            "zeta = 0.7 }]   # 179/2",
            "zeta = -0.7 }]   # 179/2",
            "controller.slow.complex_poles[0].zeta",
        ),
        (
            "omega_rad_s = 175.0",
            "omega_rad_s = 0.0",
            "controller.fast.complex_zeros[0].omega_rad_s",
        ),
        (
            "real_zeros_rad_s = [88.7]",
            "real_zeros_rad_s = [88.7, 1.0, 2.0, 3.0]",
            "improper",
        ),
        ("gain = 0.12 ", "gain = 0.0 ", "controller.slow.gain"),
        (
            "discretization = \"least_squares\"   # within",
            "discretization = \"matched_zoh\"   # within",
            "controller.fast.discretization",
        ),
    ];
    for (from, to, needle) in cases {
        let text = shipped_ch5();
        assert!(text.contains(from), "fixture drifted: {from}");
        let cfg = path_in(dir.path(), "bench.toml");
        std::fs::write(&cfg, text.replace(from, to)).unwrap();
        let o = run(&["control", "--fast", "--config", &cfg, "--check-only"]);
        assert_eq!(o.status.code(), Some(2), "{needle}");
        assert!(
            String::from_utf8_lossy(&o.stderr).contains(needle),
            "{needle}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    let o = run(&["control", "--fast", "--step-m", "1e-3", "--check-only"]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--step-m") && err.contains("position limit"),
        "{err}"
    );
    let o = run(&["control", "--fast", "--inject-fault", "smoke@1"]);
    assert_eq!(o.status.code(), Some(2));
    let o = run(&["control"]);
    assert_eq!(
        o.status.code(),
        Some(2),
        "one of --slow/--fast/--controller is required"
    );
}

/// With `--frf`, the margins are also computed on a measured response; on
/// the simulator they agree with the model's.
#[test]
fn margins_on_a_measured_frf() {
    let dir = tmp();
    let out = path_in(dir.path(), "c.mcap");
    let o = run(&["chirp", "--out", &out]);
    assert!(o.status.success());
    let csv = path_in(dir.path(), "c.frf.csv");
    let (o, err) = control(dir.path(), &["--fast", "--check-only", "--frf", &csv]);
    assert!(o.status.success(), "{err}");
    let s = json_stdout(&o);
    let model = s["loop_check"]["model"]["crossovers_rad_s"][0]
        .as_f64()
        .unwrap();
    let meas = s["loop_check"]["measured"]["crossovers_rad_s"][0]
        .as_f64()
        .unwrap();
    assert!((meas / model - 1.0).abs() < 0.02, "{meas} vs {model}");
    let pm_model = s["loop_check"]["model"]["phase_margin_deg"]
        .as_f64()
        .unwrap();
    let pm_meas = s["loop_check"]["measured"]["phase_margin_deg"]
        .as_f64()
        .unwrap();
    assert!((pm_meas - pm_model).abs() < 2.0, "{pm_meas} vs {pm_model}");
    let bad = path_in(dir.path(), "bad.csv");
    std::fs::write(&bad, "not,a,frf\n").unwrap();
    let o = run(&["control", "--fast", "--check-only", "--frf", &bad]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--frf"));
}

/// With the calibrated stiffness of the shipped bench (README,
/// *Calibration*) and no noise, quantisation or disturbance, the Chapter 6
/// steps reproduce the thesis (§6.2, Figs 6-8 to 6-11): 2 % settling
/// 0.0858 s (fast, Eq. 6-7) and 0.1663 s (slow, Eq. 6-6) within 10 %, and
/// the continuous phase margins, computed as the thesis computed them (no
/// hold, no amplifier), 42° and 70° within 3°.
#[test]
fn noise_free_steps_reproduce_chapter_6() {
    let dir = tmp();
    let cfg = quiet_config_edited(dir.path(), 5.0, "", |t| set_key(t, "quantization_m", "0.0"));
    let cfg = cfg.to_str().unwrap();
    for (flag, settling_s, pm_deg) in [("--fast", 0.0858, 42.0), ("--slow", 0.1663, 70.0)] {
        let sub = dir.path().join(&flag[2..]);
        std::fs::create_dir(&sub).unwrap();
        let (o, err) = control(&sub, &[flag, "--config", cfg]);
        assert!(o.status.success(), "{flag}: {err}");
        let s = json_stdout(&o);
        let ts = metric(&s, "settling_time_s");
        assert!(
            (ts / settling_s - 1.0).abs() <= 0.1,
            "{flag}: settling {ts} s vs the thesis' {settling_s} s"
        );
        let pm = s["loop_check"]["continuous"]["phase_margin_deg"]
            .as_f64()
            .unwrap();
        assert!(
            (pm - pm_deg).abs() <= 3.0,
            "{flag}: continuous phase margin {pm}° vs the thesis' {pm_deg}°"
        );
        eprintln!("{flag}: settling {ts} s, continuous PM {pm:.1}°");
    }
}

/// A dead probe under closed loop (issue 46, finding 1): the probe reads
/// 0 m without noise (`dead`: what an analog input shows of dead probe
/// electronics), or its own noise without the stage (`blind`: the target
/// came loose), from before the step on, so each controller winds its
/// integrator up against a reading that never comes. The supervisor stops
/// it at 0 A, naming the reason, before the current reaches the coil's
/// continuous rating (2.34 A on the Chapter 5 bench): `probe_frozen` within
/// the number of bit-identical readings the probe's noise makes plausible
/// (29 at σ 40 nm, q 30 nm: p = q / (σ √(2π)) = 0.299, ⌈ln 1e-15 / ln p⌉),
/// `probe_implausible` once the quasi-static motion predicted from the
/// model's compliance reaches that of a quarter of the rating. Without
/// probe noise the frozen rule cannot decide and plausibility catches
/// the dead probe as well.
#[test]
fn a_dead_probe_stops_before_the_continuous_rating() {
    let dir = tmp();
    let noiseless = {
        let text = set_key(&shipped_ch5(), "noise_rms_m", "0.0");
        let p = dir.path().join("noiseless.toml");
        std::fs::write(&p, text).unwrap();
        p.to_string_lossy().into_owned()
    };
    let ch5 = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(CH5)
        .to_string_lossy()
        .into_owned();
    let continuous_a = 2.34;
    for (config, kind, fault) in [
        (&ch5, "dead", "probe_frozen"),
        (&ch5, "blind", "probe_implausible"),
        (&noiseless, "dead", "probe_implausible"),
    ] {
        for c in ["--fast", "--slow"] {
            let case = format!("{kind} {c} {config}");
            let sub = dir.path().join(format!("{kind}{c}{}", config.len()));
            std::fs::create_dir(&sub).unwrap();
            let (o, err) = control(
                &sub,
                &[
                    c,
                    "--config",
                    config,
                    "--duration-s",
                    "3",
                    "--inject-fault",
                    &format!("{kind}@0.1"),
                ],
            );
            assert_eq!(o.status.code(), Some(3), "{case}: {err}");
            assert!(err.contains(fault), "{case}: {err}");
            let (ev, peak_a) = fault_and_peak_before(&sub.join("run.mcap"), &case);
            assert_eq!(ev["fault"], fault, "{case}");
            let tick = ev["tick"].as_u64().unwrap();
            assert!(
                peak_a < continuous_a,
                "{case}: {peak_a} A before the fault at tick {tick}"
            );
            if fault == "probe_frozen" {
                // 0.1 s at 5 kHz, then 29 identical readings (the first
                // dead one counts as the first of them).
                assert!((500..=500 + 29).contains(&tick), "{case}: tick {tick}");
            }
        }
    }
}

/// Every bench config shipped in `bench-config/` runs its default chirp
/// (whole, as shipped) and both controllers (a 1 s step each): exit 0, no
/// fault, and the chirp's peak |x1| at most half the position limit (the
/// sweep's peak at resonance inside the stroke with margin). A campaign
/// file there runs the bench it names, which is one of these (issue 46:
/// the Chapter 2 bench's chirp tripped the position limit, exit 3, and it
/// had no controller).
#[test]
fn every_shipped_bench_runs_its_default_chirp_and_both_controllers() {
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config");
    let mut benches = Vec::new();
    let mut campaigns = Vec::new();
    for p in files_in(&shipped) {
        if p.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let text = std::fs::read_to_string(&p).unwrap();
        let table: toml::Table = text.parse().unwrap();
        if table.contains_key("grid") {
            campaigns.push((p, table));
        } else {
            benches.push(p);
        }
    }
    assert!(benches.len() >= 2, "{benches:?}");
    for (p, table) in &campaigns {
        let bench = table["config"].as_str().unwrap();
        assert!(
            benches.contains(&shipped.join(bench)),
            "{}: its bench {bench} is not a shipped bench config",
            p.display()
        );
    }
    let dir = tmp();
    for (i, cfg) in benches.iter().enumerate() {
        let name = cfg.display().to_string();
        let limit_m = bench::config::BenchConfig::load(cfg)
            .unwrap()
            .safety
            .position_limit_m;
        let out = path_in(dir.path(), &format!("chirp{i}.mcap"));
        let o = run(&["chirp", "--config", &name, "--out", &out, "--json"]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{name}: chirp {:?}: {err}", o.status);
        let s = json_stdout(&o);
        let peak = s["peak_position_m"].as_f64().unwrap();
        assert!(
            peak <= 0.5 * limit_m,
            "{name}: the chirp peaks at {peak} m, more than half the position limit {limit_m} m"
        );
        for c in ["--slow", "--fast"] {
            let out = path_in(dir.path(), &format!("control{i}{c}.mcap"));
            let o = run(&[
                "control",
                c,
                "--config",
                &name,
                "--duration-s",
                "1",
                "--out",
                &out,
                "--json",
            ]);
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(
                o.status.success(),
                "{name}: control {c} {:?}: {err}",
                o.status
            );
            let s = json_stdout(&o);
            assert!(s["fault"].is_null(), "{name}: control {c}: {s}");
            assert_eq!(s["loop_check"]["closed_loop_stable"], Value::Bool(true));
        }
    }
}
