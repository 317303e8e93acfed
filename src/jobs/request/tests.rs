use super::*;
use serde_json::json;
use std::path::Path;

fn ch5() -> BenchConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    let cfg = BenchConfig::load(&path).unwrap();
    cfg.validate(&path).unwrap();
    cfg
}

type Expect = fn(&mut BenchConfig);

/// `pace` in JSON: a number or "off", checked as `--pace` is; it
/// writes nothing into the config.
#[test]
fn pace_reads_a_number_or_off_and_is_checked_as_the_flag() {
    let r: ChirpRequest = serde_json::from_value(json!({"pace": 0.5})).unwrap();
    assert_eq!(r.pace, Some(Pace::Factor(0.5)));
    assert_eq!(check_pace(r.pace), Ok(Some(Pace::Factor(0.5))));
    let r: ControlRequest =
        serde_json::from_value(json!({"controller": "fast", "pace": "off"})).unwrap();
    assert_eq!(r.pace, Some(Pace::Off));
    assert_eq!(serde_json::to_value(&r).unwrap()["pace"], json!("off"));
    let r: ChirpRequest = serde_json::from_value(json!({"pace": 2})).unwrap();
    assert_eq!(serde_json::to_value(&r).unwrap()["pace"], json!(2.0));
    for bad in [
        json!("fast"),
        json!("1"),
        json!(true),
        json!([1]),
        json!({}),
    ] {
        assert!(serde_json::from_value::<ChirpRequest>(json!({ "pace": bad })).is_err());
    }
    for f in [0.0, -1.0, 1e-3, 100.5, 1e300, f64::INFINITY, f64::NAN] {
        let e = check_pace(Some(Pace::Factor(f))).unwrap_err();
        let RequestError::Field { field, reason, .. } = &e else {
            panic!("{e:?}")
        };
        assert_eq!(*field, "pace");
        // The flag's reason, word for word.
        assert_eq!(Err(reason.clone()), check_pace_factor(f));
    }
    for (given, want) in [
        ("off", Pace::Off),
        ("1", Pace::Factor(1.0)),
        (" 0.01 ", Pace::Factor(0.01)),
        ("100", Pace::Factor(100.0)),
    ] {
        assert_eq!(parse_pace(given), Ok(want), "{given}");
    }
    let mut got = ch5();
    ChirpRequest {
        pace: Some(Pace::Factor(3.0)),
        ..Default::default()
    }
    .apply(&mut got)
    .unwrap();
    assert_eq!(got, ch5());
}

/// Each field lands on its config key and nowhere else.
#[test]
fn chirp_fields_land_on_their_keys() {
    let cases: [(ChirpRequest, Expect); 5] = [
        (
            ChirpRequest {
                amplitude_a: Some(0.25),
                ..Default::default()
            },
            |c| c.chirp.amplitude_a = 0.25,
        ),
        (
            ChirpRequest {
                f_start_hz: Some(5.0),
                ..Default::default()
            },
            |c| c.chirp.f_start_hz = 5.0,
        ),
        (
            ChirpRequest {
                f_end_hz: Some(400.0),
                ..Default::default()
            },
            |c| c.chirp.f_end_hz = 400.0,
        ),
        // A long sweep keeps the fades; a short one shrinks them.
        (
            ChirpRequest {
                duration_s: Some(20.0),
                ..Default::default()
            },
            |c| c.chirp.duration_s = Some(20.0),
        ),
        (
            ChirpRequest {
                duration_s: Some(1.0),
                ..Default::default()
            },
            |c| {
                c.chirp.duration_s = Some(1.0);
                c.chirp.taper_s = Some(0.25);
            },
        ),
    ];
    for (request, expect) in cases {
        let mut got = ch5();
        request.apply(&mut got).unwrap();
        let mut want = ch5();
        expect(&mut want);
        assert_eq!(got, want, "{request:?}");
    }
    // The seed is not a config value.
    let mut got = ch5();
    ChirpRequest {
        seed: Some(42),
        ..Default::default()
    }
    .apply(&mut got)
    .unwrap();
    assert_eq!(got, ch5());
}

#[test]
fn control_fields_land_on_their_keys() {
    let with = |f: fn(&mut ControlRequest)| {
        let mut r = ControlRequest::new("fast");
        f(&mut r);
        r
    };
    let cases: [(ControlRequest, Expect); 5] = [
        (with(|r| r.step_m = Some(-5e-6)), |c| c.step.step_m = -5e-6),
        (with(|r| r.duration_s = Some(8.0)), |c| {
            c.step.duration_s = 8.0
        }),
        (with(|r| r.duration_s = Some(1.5)), |c| {
            c.step.duration_s = 1.5;
            c.step.steady_state_window_s = 0.75;
        }),
        (with(|r| r.smooth_s = Some(0.05)), |c| {
            c.step.smooth_s = 0.05
        }),
        // Not config values.
        (
            with(|r| {
                r.seed = Some(7);
                r.override_check = true;
            }),
            |_| {},
        ),
    ];
    for (request, expect) in cases {
        let mut got = ch5();
        assert_eq!(request.apply(&mut got).unwrap(), None);
        let mut want = ch5();
        expect(&mut want);
        assert_eq!(got, want, "{request:?}");
    }
    let mut got = ch5();
    let fault = with(|r| r.inject_fault = Some("jump@0.3".into()))
        .apply(&mut got)
        .unwrap();
    assert_eq!(
        fault,
        Some(ScheduledFault {
            at_s: 0.3,
            kind: FaultInjection::Jump(0.2e-3)
        })
    );
    assert_eq!(got, ch5());
}

/// `verify`: the defaults (10 % of `chirp.amplitude_a`, 10 s), the
/// values given, their ranges, and neither without `verify`.
#[test]
fn verify_settings() {
    let cfg = ch5();
    let mut r = ControlRequest::new("fast");
    assert_eq!(r.verify_settings(&cfg).unwrap(), None);
    r.verify = true;
    assert_eq!(
        r.verify_settings(&cfg).unwrap(),
        Some(VerifySettings {
            amplitude_a: 0.05,
            duration_s: 10.0
        })
    );
    r.verify_amplitude_a = Some(0.2);
    r.verify_duration_s = Some(3.0);
    assert_eq!(
        r.verify_settings(&cfg).unwrap(),
        Some(VerifySettings {
            amplitude_a: 0.2,
            duration_s: 3.0
        })
    );
    let field = |r: &ControlRequest| match r.apply(&mut ch5()) {
        Err(RequestError::Field { field, .. }) => field,
        other => panic!("{r:?}: {other:?}"),
    };
    for a in [f64::NAN, -1.0, 0.0, 9.9e-5, 9.981, f64::INFINITY] {
        let mut bad = r.clone();
        bad.verify_amplitude_a = Some(a);
        assert_eq!(field(&bad), "verify_amplitude_a", "{a}");
    }
    for d in [f64::NAN, 0.0, 0.099, 600.1, -5.0] {
        let mut bad = r.clone();
        bad.verify_duration_s = Some(d);
        assert_eq!(field(&bad), "verify_duration_s", "{d}");
    }
    // A run beyond the job's tick budget: 600 s at 100 kHz.
    let mut fast_loop = ch5();
    fast_loop.loop_.rate_hz = 100_000.0;
    let mut long = r.clone();
    long.verify_duration_s = Some(600.0);
    assert!(matches!(
        long.verify_settings(&fast_loop),
        Err(RequestError::Field {
            field: "verify_duration_s",
            ..
        })
    ));
    r.verify = false;
    assert_eq!(field(&r), "verify_amplitude_a");
    // The wire form carries them; absent, they stay out.
    let wire = serde_json::to_value(JobRequest::Control(ControlRequest::new("fast"))).unwrap();
    assert_eq!(
        wire,
        json!({ "cmd": "control", "params": { "controller": "fast", "override_check": false } })
    );
    let v: ControlRequest = serde_json::from_value(
        json!({ "controller": "fast", "verify": true, "verify_amplitude_a": 0.1 }),
    )
    .unwrap();
    assert!(v.verify && v.verify_amplitude_a == Some(0.1));
}

#[test]
fn local_overrides_land_on_their_keys() {
    let mut got = ch5();
    LocalOverrides {
        operating_point: Some(OperatingPoint::PercentOfBeamLength(5.0)),
        mass_asymmetry: Some(0.05),
        excitation: Some(ExcitationKind::Linear),
    }
    .apply(&mut got);
    let mut want = ch5();
    want.plant.operating_point_m = 0.05 * want.plant.beam.length_m;
    want.plant.mass_asymmetry = 0.05;
    want.excitation.kind = ExcitationKind::Linear;
    assert_eq!(got, want);
    LocalOverrides {
        operating_point: Some(OperatingPoint::Metres(1e-3)),
        ..Default::default()
    }
    .apply(&mut got);
    assert_eq!(got.plant.operating_point_m, 1e-3);
}

/// A bad value is refused naming the config key it set.
#[test]
fn bad_values_name_the_key() {
    let chirp = |f: fn(&mut ChirpRequest)| {
        let mut r = ChirpRequest::default();
        f(&mut r);
        r.apply(&mut ch5()).unwrap_err()
    };
    let invalid =
        |key: &str, e: &RequestError| matches!(e, RequestError::Invalid { key: k, .. } if k == key);
    for (e, key) in [
        (chirp(|r| r.amplitude_a = Some(12.0)), "chirp.amplitude_a"),
        (chirp(|r| r.f_start_hz = Some(f64::NAN)), "chirp.f_start_hz"),
        (chirp(|r| r.f_end_hz = Some(2500.0)), "chirp.f_end_hz"),
        (chirp(|r| r.duration_s = Some(-3.0)), "chirp.duration_s"),
    ] {
        assert!(invalid(key, &e), "{key}: {e}");
        assert!(e.to_string().starts_with(key), "{e}");
    }
    let control = |f: fn(&mut ControlRequest)| {
        let mut r = ControlRequest::new("slow");
        f(&mut r);
        r.apply(&mut ch5()).unwrap_err()
    };
    for (e, key) in [
        (control(|r| r.step_m = Some(1e-3)), "step.step_m"),
        (control(|r| r.duration_s = Some(0.1)), "step.duration_s"),
        (control(|r| r.smooth_s = Some(-1.0)), "step.smooth_s"),
    ] {
        assert!(invalid(key, &e), "{key}: {e}");
    }
    let e = control(|r| r.controller = "nope".into());
    assert!(
        matches!(&e, RequestError::Field { field: "controller", value, reason }
            if value == "nope" && reason.contains("fast, slow")),
        "{e}"
    );
    let e = control(|r| r.inject_fault = Some("smoke@1".into()));
    assert!(
        matches!(&e, RequestError::Field { field: "inject_fault", reason, .. }
            if reason.contains("unknown kind")),
        "{e}"
    );
    for bad in ["nan", "nan@-1", "nan@x"] {
        assert!(parse_fault(bad).is_err(), "{bad}");
    }
}

#[test]
fn unknown_fields_are_refused() {
    let e = serde_json::from_value::<ChirpRequest>(json!({ "amplitude": 0.1 })).unwrap_err();
    assert!(e.to_string().contains("amplitude"), "{e}");
    let e =
        serde_json::from_value::<ControlRequest>(json!({ "controller": "fast", "detach": true }))
            .unwrap_err();
    assert!(e.to_string().contains("detach"), "{e}");
    let e = serde_json::from_value::<JobRequest>(
        json!({ "cmd": "control", "params": { "controller": "fast", "step": 1e-6 } }),
    )
    .unwrap_err();
    assert!(e.to_string().contains("step"), "{e}");
}

/// The daemon's wire form: `cmd` and `params`; absent fields stay out.
#[test]
fn wire_form() {
    let chirp = JobRequest::Chirp(ChirpRequest {
        duration_s: Some(3.0),
        ..Default::default()
    });
    let v = serde_json::to_value(&chirp).unwrap();
    assert_eq!(
        v,
        json!({ "cmd": "chirp", "params": { "duration_s": 3.0 } })
    );
    assert_eq!(serde_json::from_value::<JobRequest>(v).unwrap(), chirp);
    let control: ControlRequest =
        serde_json::from_value(json!({ "controller": "fast", "seed": null })).unwrap();
    assert_eq!(control, ControlRequest::new("fast"));
    assert_eq!(JobRequest::Control(control).kind(), "control");
}
