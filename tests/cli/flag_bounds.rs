//! Every numeric value a job takes from outside the config: the flags of
//! `bench chirp` and `bench control`, and the `chirp` / `control` request
//! parameters of the daemon (the same [`JobRequest`] types). Each is set to
//! NaN, ±inf, negative, zero, ±denormal, huge, just outside and just inside
//! its documented range, and garbage. The ranges are the documented ranges
//! of the config keys the values override (README, *Configuration
//! reference*, at the shipped `sr4dof-ch5.toml`), written here, not taken
//! from the code.
//!
//! - Requests (library level, as the daemon and the CLI apply them):
//!   refused naming the parameter, or accepted with the value on its key and
//!   inside its range.
//! - The binary: every value outside its range exits 2 naming the flag, and
//!   a sample inside runs (`--check-only` for control, a short sweep for
//!   chirp).

use crate::common;

use bench::config::BenchConfig;
use bench::jobs::request::{
    ChirpRequest, ControlRequest, JobRequest, LocalOverrides, OperatingPoint, RequestError,
};
use serde_json::json;
use std::path::Path;

fn ch5() -> BenchConfig {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    let c = BenchConfig::load(&p).unwrap();
    c.validate(&p).unwrap();
    c
}

/// A documented range `[lo, hi]` with open or closed ends; `abs`: of the
/// magnitude.
#[derive(Debug, Clone, Copy)]
struct Doc {
    lo: f64,
    lo_closed: bool,
    hi: f64,
    hi_closed: bool,
    abs: bool,
}

const fn doc(lo: f64, lo_closed: bool, hi: f64, hi_closed: bool) -> Doc {
    Doc {
        lo,
        lo_closed,
        hi,
        hi_closed,
        abs: false,
    }
}

impl Doc {
    fn contains(&self, v: f64) -> bool {
        let v = if self.abs { v.abs() } else { v };
        v.is_finite()
            && (if self.lo_closed {
                v >= self.lo
            } else {
                v > self.lo
            })
            && (if self.hi_closed {
                v <= self.hi
            } else {
                v < self.hi
            })
    }

    fn values(&self) -> Vec<f64> {
        let mut v = vec![
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            -1.0,
            -0.0,
            0.0,
            5e-324,
            -5e-324,
            1e-300,
            1.0,
            1e9,
            1e300,
            f64::MAX,
            -1e300,
        ];
        for b in [self.lo, self.hi] {
            v.extend([b.next_down(), b, b.next_up()]);
        }
        if self.abs {
            let neg: Vec<f64> = v.iter().map(|x| -x).collect();
            v.extend(neg);
        }
        v
    }
}

// The shipped Chapter 5 config: 5 kHz (Nyquist 2.5 kHz), peak 9.98 A,
// position limit 0.8 mm, beam 47.5 mm, chirp 0.1–500 Hz, step settle
// 0.2 s, smooth 0, window 3 s (a request's duration shrinks the window to
// at most half of it).
const AMPLITUDE: Doc = doc(1e-4, true, 9.98, true);
const F_START: Doc = doc(0.01, true, 500.0, false);
const F_END: Doc = doc(0.1, false, 2500.0, false);
const CHIRP_DURATION: Doc = doc(0.1, true, 600.0, true);
const STEP: Doc = Doc {
    abs: true,
    ..doc(1e-9, true, 0.8e-3, false)
};
const STEP_DURATION: Doc = doc(0.2, false, 3600.0, true);
/// 4 s − 0.2 s settle − 3 s window.
const SMOOTH: Doc = doc(0.0, true, 0.8, true);
const OPERATING_POINT_M: Doc = doc(-0.2 * 0.0475, true, 0.2 * 0.0475, true);
const OPERATING_POINT_PCT: Doc = doc(-20.0, true, 20.0, true);
/// README: −0.33 to 0.5 (the heavier secondary stage at most about 1.5
/// times the lighter); `--mass-asymmetry-pct` the same in %.
const MASS_ASYMMETRY: Doc = doc(-0.33, true, 0.5, true);
const MASS_ASYMMETRY_PCT: Doc = doc(-33.0, true, 50.0, true);

/// One request field: its name (the daemon's param and, with `--` and
/// dashes, the flag), the config key it lands on, its range, and how to set
/// it.
struct Field {
    name: &'static str,
    key: &'static str,
    doc: Doc,
}

const CHIRP: [Field; 4] = [
    Field {
        name: "amplitude_a",
        key: "chirp.amplitude_a",
        doc: AMPLITUDE,
    },
    Field {
        name: "f_start_hz",
        key: "chirp.f_start_hz",
        doc: F_START,
    },
    Field {
        name: "f_end_hz",
        key: "chirp.f_end_hz",
        doc: F_END,
    },
    Field {
        name: "duration_s",
        key: "chirp.duration_s",
        doc: CHIRP_DURATION,
    },
];

const CONTROL: [Field; 3] = [
    Field {
        name: "step_m",
        key: "step.step_m",
        doc: STEP,
    },
    Field {
        name: "duration_s",
        key: "step.duration_s",
        doc: STEP_DURATION,
    },
    Field {
        name: "smooth_s",
        key: "step.smooth_s",
        doc: SMOOTH,
    },
];

fn chirp_request(name: &str, x: f64) -> ChirpRequest {
    let mut r = ChirpRequest::default();
    match name {
        "amplitude_a" => r.amplitude_a = Some(x),
        "f_start_hz" => r.f_start_hz = Some(x),
        "f_end_hz" => r.f_end_hz = Some(x),
        "duration_s" => r.duration_s = Some(x),
        _ => unreachable!("{name}"),
    }
    r
}

fn control_request(name: &str, x: f64) -> ControlRequest {
    let mut r = ControlRequest::new("fast");
    match name {
        "step_m" => r.step_m = Some(x),
        "duration_s" => r.duration_s = Some(x),
        "smooth_s" => r.smooth_s = Some(x),
        _ => unreachable!("{name}"),
    }
    r
}

fn value_of(c: &BenchConfig, key: &str) -> f64 {
    let v: toml::Value = toml::from_str(&c.to_toml()).unwrap();
    let mut cur = &v;
    for p in key.split('.') {
        cur = &cur[p];
    }
    cur.as_float().unwrap()
}

/// The rule for one applied request.
fn judge(f: &Field, x: f64, got: Result<BenchConfig, RequestError>) -> Result<(), String> {
    match got {
        Ok(c) if f.doc.contains(x) => {
            let v = value_of(&c, f.key);
            if v == x || (v == 0.0 && x == 0.0) {
                Ok(())
            } else {
                Err(format!("accepted {x:?} but {} = {v:?}", f.key))
            }
        }
        Ok(_) => Err(format!("{x:?} is outside {:?} but accepted", f.doc)),
        Err(e) => {
            let text = e.to_string();
            if text.contains(f.name) {
                Ok(())
            } else {
                Err(format!("{x:?} refused without naming {}: {text}", f.name))
            }
        }
    }
}

/// Request parameters with every value, applied as the daemon applies
/// them: refused naming the parameter (the daemon answers `bad_request`
/// with that text), or accepted inside the range.
#[test]
fn every_request_parameter_is_refused_naming_it_or_lands_in_range() {
    let mut failures = Vec::new();
    let mut n = 0;
    for f in &CHIRP {
        for x in f.doc.values() {
            n += 1;
            let mut c = ch5();
            let got = chirp_request(f.name, x).apply(&mut c).map(|()| c);
            if let Err(why) = judge(f, x, got) {
                failures.push(format!("chirp {} = {x:?}: {why}", f.name));
            }
        }
    }
    for f in &CONTROL {
        for x in f.doc.values() {
            n += 1;
            let mut c = ch5();
            let got = control_request(f.name, x).apply(&mut c).map(|_| c);
            if let Err(why) = judge(f, x, got) {
                failures.push(format!("control {} = {x:?}: {why}", f.name));
            }
        }
    }
    // The local-only overrides of `bench chirp` (the daemon takes none).
    for (name, key, d) in [
        (
            "operating_point_m",
            "plant.operating_point_m",
            OPERATING_POINT_M,
        ),
        (
            "operating_point_pct",
            "plant.operating_point_m",
            OPERATING_POINT_PCT,
        ),
        ("mass_asymmetry", "plant.mass_asymmetry", MASS_ASYMMETRY),
    ] {
        for x in d.values() {
            // A percentage of L is rounded on the way to metres: an ulp
            // beyond ±20 % may land on the bound.
            if name == "operating_point_pct" && !d.contains(x) && near_a_bound(&d, x) {
                continue;
            }
            n += 1;
            let mut c = ch5();
            let o = match name {
                "operating_point_m" => LocalOverrides {
                    operating_point: Some(OperatingPoint::Metres(x)),
                    ..Default::default()
                },
                "operating_point_pct" => LocalOverrides {
                    operating_point: Some(OperatingPoint::PercentOfBeamLength(x)),
                    ..Default::default()
                },
                _ => LocalOverrides {
                    mass_asymmetry: Some(x),
                    ..Default::default()
                },
            };
            o.apply(&mut c);
            let got = ChirpRequest::default().apply(&mut c);
            let last = key.rsplit('.').next().unwrap();
            match got {
                Ok(()) if d.contains(x) => {}
                Ok(()) => failures.push(format!("{name} = {x:?}: outside {d:?} but accepted")),
                Err(e) if e.to_string().contains(last) => {}
                Err(e) => failures.push(format!("{name} = {x:?}: refused without {key}: {e}")),
            }
        }
    }
    assert!(n > 150, "only {n}");
    assert!(
        failures.is_empty(),
        "{} of {n}:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

/// The daemon's wire form: numbers JSON can carry are judged as above;
/// wrong types, negative or fractional seeds and unknown params do not
/// parse into a job.
#[test]
fn request_parameters_from_json() {
    let mut failures = Vec::new();
    for (cmd, fields) in [("chirp", &CHIRP[..]), ("control", &CONTROL[..])] {
        for f in fields {
            for x in f.doc.values().into_iter().filter(|x| x.is_finite()) {
                let mut params = json!({ f.name: x });
                if cmd == "control" {
                    params["controller"] = json!("fast");
                }
                let job: JobRequest =
                    serde_json::from_value(json!({ "cmd": cmd, "params": params }))
                        .unwrap_or_else(|e| panic!("{cmd} {} = {x}: {e}", f.name));
                let mut c = ch5();
                let got = match &job {
                    JobRequest::Chirp(r) => r.apply(&mut c).map(|()| c),
                    JobRequest::Control(r) => r.apply(&mut c).map(|_| c),
                    other => panic!("{cmd} parsed as {}", other.kind()),
                };
                if let Err(why) = judge(f, x, got) {
                    failures.push(format!("{cmd} {} = {x:?}: {why}", f.name));
                }
            }
            for bad in [json!("1.0"), json!(true), json!([1.0]), json!({})] {
                let mut params = json!({ f.name: bad });
                if cmd == "control" {
                    params["controller"] = json!("fast");
                }
                if serde_json::from_value::<JobRequest>(json!({ "cmd": cmd, "params": params }))
                    .is_ok()
                {
                    failures.push(format!("{cmd} {} = {bad}: parsed", f.name));
                }
            }
        }
        for seed in [json!(-1), json!(1.5), json!("7"), json!(1e300)] {
            let mut params = json!({ "seed": seed });
            if cmd == "control" {
                params["controller"] = json!("fast");
            }
            if serde_json::from_value::<JobRequest>(json!({ "cmd": cmd, "params": params })).is_ok()
            {
                failures.push(format!("{cmd} seed = {seed}: parsed"));
            }
        }
        for seed in [0u64, u64::MAX] {
            let mut params = json!({ "seed": seed });
            if cmd == "control" {
                params["controller"] = json!("fast");
            }
            assert!(
                serde_json::from_value::<JobRequest>(json!({ "cmd": cmd, "params": params }))
                    .is_ok(),
                "{cmd} seed {seed}"
            );
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// `bench control --verify`'s two values, which set no config key (the
/// verify's chirp is `[chirp]` with its own amplitude and duration):
/// README, *`--verify`*: the amplitude in [0.1 mA, actuator.peak_current_a]
/// (9.98 A shipped), the sweep in [0.1 s, 600 s]. Every value is refused
/// naming its parameter, or taken as given; the same from the daemon's
/// JSON. (Whether the limits leave room for an amplitude is judged on the
/// model before enable: `tests/cli/verify.rs`.)
#[test]
fn verify_parameters_are_refused_naming_them_or_taken_as_given() {
    const VERIFY_AMPLITUDE: Doc = doc(1e-4, true, 9.98, true);
    const VERIFY_DURATION: Doc = doc(0.1, true, 600.0, true);
    let mut failures = Vec::new();
    let mut n = 0;
    for (name, d) in [
        ("verify_amplitude_a", VERIFY_AMPLITUDE),
        ("verify_duration_s", VERIFY_DURATION),
    ] {
        for x in d.values() {
            n += 1;
            let mut r = ControlRequest::new("fast");
            r.verify = true;
            if name == "verify_amplitude_a" {
                r.verify_amplitude_a = Some(x);
            } else {
                r.verify_duration_s = Some(x);
            }
            let mut c = ch5();
            let applied = r.apply(&mut c).and_then(|_| r.verify_settings(&c));
            match applied {
                Ok(Some(v)) if d.contains(x) => {
                    let got = if name == "verify_amplitude_a" {
                        v.amplitude_a
                    } else {
                        v.duration_s
                    };
                    if got != x {
                        failures.push(format!("{name} = {x:?}: taken as {got:?}"));
                    }
                }
                Ok(_) => failures.push(format!("{name} = {x:?}: outside {d:?} but accepted")),
                Err(e) if e.to_string().contains(name) => {}
                Err(e) => failures.push(format!("{name} = {x:?}: refused without naming it: {e}")),
            }
            if x.is_finite() {
                let job: JobRequest = serde_json::from_value(json!({
                    "cmd": "control",
                    "params": { "controller": "fast", "verify": true, name: x }
                }))
                .unwrap();
                let JobRequest::Control(req) = job else {
                    panic!("not a control job")
                };
                assert_eq!(req, r, "{name} = {x:?}: the wire form differs");
            }
        }
    }
    assert!(n > 30, "only {n}");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// A bad `chirp.taper_s` or `step.steady_state_window_s` in the config is
/// not hidden by a request's duration (which shrinks them when valid).
#[test]
fn a_request_duration_does_not_mask_an_invalid_config() {
    for taper in [f64::NAN, -1.0, 1e300, 31.0] {
        let mut c = ch5();
        c.chirp.taper_s = Some(taper);
        let e = chirp_request("duration_s", 1.0)
            .apply(&mut c)
            .unwrap_err()
            .to_string();
        assert!(e.contains("chirp.taper_s"), "{taper}: {e}");
    }
    for window in [f64::NAN, -1.0, 0.0, 1e300, 3.9] {
        let mut c = ch5();
        c.step.steady_state_window_s = window;
        let e = control_request("duration_s", 1.0)
            .apply(&mut c)
            .unwrap_err()
            .to_string();
        assert!(e.contains("step.steady_state_window_s"), "{window}: {e}");
    }
}

/// Within rounding of an end of the range.
fn near_a_bound(d: &Doc, x: f64) -> bool {
    [d.lo, d.hi]
        .iter()
        .any(|b| (x - b).abs() <= 1e-12 * b.abs().max(x.abs()))
}

fn flag(name: &str) -> String {
    format!("--{}", name.replace('_', "-"))
}

/// The text the binary gets for a value (clap parses Rust's float syntax).
fn arg(x: f64) -> String {
    if x.is_nan() {
        "nan".into()
    } else {
        format!("{x:e}")
    }
}

/// Every out-of-range value of every numeric flag exits 2 naming the flag;
/// the binary is the same parse and the same request as above.
#[test]
fn the_binary_refuses_every_out_of_range_flag_with_exit_2() {
    let dir = common::tmp();
    let out = dir.path().join("x.mcap").display().to_string();
    let mut failures = Vec::new();
    let mut n = 0;
    // Refused with exit 2, naming the flag or the config key it overrides
    // (a refusal for another key's bound names this one in its reason).
    let mut check = |args: Vec<String>, flag: &str, key: &str| {
        n += 1;
        let a: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = common::run(&a);
        let err = String::from_utf8_lossy(&o.stderr);
        if o.status.code() != Some(2) || !(err.contains(flag) || err.contains(key)) {
            failures.push(format!(
                "{}: exit {:?}: {err}",
                args.join(" "),
                o.status.code()
            ));
        }
    };
    let chirp_flags: Vec<(&str, &str, Doc)> = CHIRP
        .iter()
        .map(|f| (f.name, f.key, f.doc))
        .chain([
            (
                "operating_point_m",
                "plant.operating_point_m",
                OPERATING_POINT_M,
            ),
            (
                "operating_point_pct",
                "plant.operating_point_m",
                OPERATING_POINT_PCT,
            ),
            ("mass_asymmetry", "plant.mass_asymmetry", MASS_ASYMMETRY),
            (
                "mass_asymmetry_pct",
                "plant.mass_asymmetry",
                MASS_ASYMMETRY_PCT,
            ),
        ])
        .collect();
    for (name, key, d) in chirp_flags {
        for x in d.values().into_iter().filter(|x| !d.contains(*x)) {
            if name == "operating_point_pct" && near_a_bound(&d, x) {
                continue;
            }
            check(
                vec![
                    "chirp".into(),
                    flag(name),
                    arg(x),
                    "--out".into(),
                    out.clone(),
                ],
                &flag(name),
                key,
            );
        }
        for junk in ["abc", "", "1,5", "0x10"] {
            check(
                vec![
                    "chirp".into(),
                    flag(name),
                    junk.into(),
                    "--out".into(),
                    out.clone(),
                ],
                &flag(name),
                key,
            );
        }
    }
    for f in &CONTROL {
        for x in f.doc.values().into_iter().filter(|x| !f.doc.contains(*x)) {
            check(
                vec![
                    "control".into(),
                    "--fast".into(),
                    "--check-only".into(),
                    flag(f.name),
                    arg(x),
                ],
                &flag(f.name),
                f.key,
            );
        }
        for junk in ["abc", "", "1,5"] {
            check(
                vec![
                    "control".into(),
                    "--fast".into(),
                    "--check-only".into(),
                    flag(f.name),
                    junk.into(),
                ],
                &flag(f.name),
                f.key,
            );
        }
    }
    // A seed is 0..=2^64 - 1: the message says so.
    for cmd in ["chirp", "control"] {
        for bad in ["-1", "1.5", "18446744073709551616", "abc", "-0x1"] {
            let mut args = vec![cmd.to_string()];
            if cmd == "control" {
                args.extend(["--fast".into(), "--check-only".into()]);
            }
            args.extend(["--seed".into(), bad.into()]);
            n += 1;
            let a: Vec<&str> = args.iter().map(String::as_str).collect();
            let o = common::run(&a);
            let err = String::from_utf8_lossy(&o.stderr);
            if o.status.code() != Some(2)
                || !err.contains("--seed")
                || !err.contains("18446744073709551615")
            {
                failures.push(format!("{}: {err}", args.join(" ")));
            }
        }
    }
    assert!(n > 120, "only {n}");
    assert!(
        failures.is_empty(),
        "{} of {n}:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

/// A sample of values inside the ranges runs, negative ones as plain
/// `--flag -x` (issue 12, item 15).
#[test]
fn the_binary_takes_values_inside_the_ranges_including_negative_ones() {
    let dir = common::tmp();
    for args in [
        vec!["--step-m", "-1e-5"],
        vec!["--step-m", "-0.000799"],
        vec!["--step-m", "1e-9"],
        vec!["--smooth-s", "0.8", "--seed", "18446744073709551615"],
        vec!["--duration-s", "3600", "--seed", "0"],
    ] {
        let mut a = vec!["control", "--fast", "--check-only", "--json"];
        a.extend(&args);
        let o = common::run(&a);
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    for (i, args) in [
        vec!["--mass-asymmetry", "-0.1", "--seed", "18446744073709551615"],
        vec!["--mass-asymmetry", "0.5"],
        vec!["--mass-asymmetry-pct", "-33"],
        vec!["--mass-asymmetry-pct", "10"],
        vec!["--operating-point-pct", "-5"],
        vec!["--operating-point-m", "-2e-3", "--amplitude-a", "1e-4"],
        vec!["--f-start-hz", "0.01", "--f-end-hz", "2499"],
    ]
    .into_iter()
    .enumerate()
    {
        let out = dir.path().join(format!("c{i}.mcap")).display().to_string();
        let mut a = vec!["chirp", "--duration-s", "0.1", "--json", "--out", &out];
        a.extend(&args);
        let o = common::run(&a);
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
}

/// A value in the wrong unit (issue 17, item 5): a mass asymmetry in
/// percent given as a fraction, an operating point in mm given as metres.
/// Refused (exit 2) naming the flag, with the hint in the intended unit;
/// `--mass-asymmetry-pct` runs the same sweep as the fraction; the two
/// mass-asymmetry flags exclude each other.
#[test]
fn values_in_the_wrong_unit_are_refused_with_a_hint() {
    let dir = common::tmp();
    let out = dir.path().join("c.mcap").display().to_string();
    for (args, want) in [
        (
            ["--mass-asymmetry", "10"],
            vec!["--mass-asymmetry", "0.10 = 10 %", "give 0.1"],
        ),
        (
            ["--mass-asymmetry", "-8"],
            vec!["--mass-asymmetry", "0.10 = 10 %", "give -0.08"],
        ),
        (
            ["--operating-point-m", "3"],
            vec!["--operating-point-m", "3 mm = 0.003 m"],
        ),
        (
            ["--operating-point-m", "-8"],
            vec!["--operating-point-m", "-8 mm = -0.008 m"],
        ),
        (
            ["--mass-asymmetry-pct", "1000"],
            vec!["--mass-asymmetry-pct 1000", "-33 % to 50 %"],
        ),
        (
            ["--operating-point-pct", "21"],
            vec!["--operating-point-pct 21", "20 %"],
        ),
    ] {
        let mut a = vec!["chirp", "--duration-s", "0.1", "--out", &out];
        a.extend(args);
        let o = common::run(&a);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        for w in want {
            assert!(err.contains(w), "{args:?}: no {w:?} in {err}");
        }
        assert!(!dir.path().join("c.mcap").exists());
    }
    // Out of range but not a unit slip: no hint that would mislead.
    for args in [
        ["--mass-asymmetry", "0.9"],
        ["--mass-asymmetry", "60"],
        ["--operating-point-m", "50"],
        ["--operating-point-m", "1000"],
    ] {
        let mut a = vec!["chirp", "--duration-s", "0.1", "--out", &out];
        a.extend(args);
        let o = common::run(&a);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            !err.contains("0.10 = 10 %") && !err.contains(" mm = "),
            "{args:?}: {err}"
        );
    }
    let o = common::run(&[
        "chirp",
        "--mass-asymmetry",
        "0.1",
        "--mass-asymmetry-pct",
        "10",
        "--out",
        &out,
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--mass-asymmetry-pct") && err.contains("cannot be used with"),
        "{err}"
    );
    // The percent flag is the fraction: the same Δm23 in the summary.
    let o = common::run(&[
        "chirp",
        "--duration-s",
        "0.1",
        "--json",
        "--out",
        &out,
        "--mass-asymmetry-pct",
        "-8",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = common::json_stdout(&o);
    assert!(
        (s["mass_asymmetry"].as_f64().unwrap() + 0.08).abs() < 1e-15,
        "{s}"
    );
}
