//! Every message of a recorded chirp run and of recorded control runs (one
//! clean, one with a fault) on the simulator is valid against its channel's
//! JSON Schema, checked with an independent validator (`jsonschema`); every
//! field of every schema has a description; and the validator does reject a
//! wrong message against the generated schemas.

mod common;

use common::*;
use serde_json::{json, Value};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// One channel of a recording: its schema and its messages.
struct Channel {
    schema_name: String,
    schema: Value,
    messages: Vec<Value>,
}

/// The channels of an MCAP recording by topic (strict read: the file must
/// be complete).
fn channels(path: &Path) -> BTreeMap<String, Channel> {
    let bytes = std::fs::read(path).expect("recording");
    let mut out: BTreeMap<String, Channel> = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).expect("mcap") {
        let m = m.expect("message");
        assert_eq!(m.channel.message_encoding, "json", "{}", m.channel.topic);
        let schema = m.channel.schema.as_ref().expect("channel has a schema");
        assert_eq!(schema.encoding, "jsonschema", "{}", m.channel.topic);
        let ch = out
            .entry(m.channel.topic.clone())
            .or_insert_with(|| Channel {
                schema_name: schema.name.clone(),
                schema: serde_json::from_slice(&schema.data).expect("schema is JSON"),
                messages: Vec::new(),
            });
        ch.messages
            .push(serde_json::from_slice(&m.data).expect("message is JSON"));
    }
    out
}

/// Every object property in `schema` (root, `$defs`, nested) has a
/// non-empty description; returns the paths of those that do not.
fn undescribed(schema: &Value, path: &str, missing: &mut Vec<String>) {
    match schema {
        Value::Object(o) => {
            if let Some(Value::Object(props)) = o.get("properties") {
                for (name, p) in props {
                    if p["description"].as_str().is_none_or(str::is_empty) {
                        missing.push(format!("{path}.{name}"));
                    }
                }
            }
            for (k, v) in o {
                undescribed(v, &format!("{path}/{k}"), missing);
            }
        }
        Value::Array(a) => {
            for (i, v) in a.iter().enumerate() {
                undescribed(v, &format!("{path}/{i}"), missing);
            }
        }
        _ => {}
    }
}

/// Validates every message of every channel of `path` against the
/// channel's schema; returns the channels for further checks.
fn validate_recording(path: &Path) -> BTreeMap<String, Channel> {
    let chans = channels(path);
    assert!(!chans.is_empty(), "{}: no messages", path.display());
    let mut failures = Vec::new();
    for (topic, ch) in &chans {
        let validator = jsonschema::validator_for(&ch.schema)
            .unwrap_or_else(|e| panic!("{topic}: schema {} invalid: {e}", ch.schema_name));
        let mut missing = Vec::new();
        undescribed(&ch.schema, &ch.schema_name, &mut missing);
        assert!(missing.is_empty(), "{topic}: no description: {missing:?}");
        for (i, msg) in ch.messages.iter().enumerate() {
            for e in validator.iter_errors(msg) {
                failures.push(format!("{topic} message {i}: {e} at {}", e.instance_path()));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{}: {} invalid messages, first: {:#?}",
        path.display(),
        failures.len(),
        &failures[..failures.len().min(10)]
    );
    chans
}

/// Runs `bench` with `args`, expecting exit status `code`.
fn bench_exits(args: &[&str], code: i32) {
    let o = run(args);
    assert_eq!(
        o.status.code(),
        Some(code),
        "bench {args:?}:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The topics and schema names a run must record.
fn assert_topics(chans: &BTreeMap<String, Channel>, expected: &[(&str, &str)]) {
    for (topic, schema_name) in expected {
        let ch = chans
            .get(*topic)
            .unwrap_or_else(|| panic!("no {topic}; got {:?}", chans.keys()));
        assert_eq!(ch.schema_name, *schema_name, "{topic}");
    }
}

/// `value` with the part at JSON `pointer` set to `new`.
fn replaced(value: &Value, pointer: &str, new: Value) -> Value {
    let mut v = value.clone();
    *v.pointer_mut(pointer)
        .unwrap_or_else(|| panic!("no {pointer} in {value}")) = new;
    v
}

#[test]
fn recorded_messages_match_their_channel_schemas() {
    let dir = tmp();
    let chirp = dir.path().join("chirp.mcap");
    let control = dir.path().join("control.mcap");
    let faulted = dir.path().join("faulted.mcap");
    let p = |f: &Path| f.display().to_string();
    let (chirp_s, control_s, faulted_s) = (p(&chirp), p(&control), p(&faulted));
    bench_exits(
        &[
            "chirp",
            "--json",
            "--out",
            &chirp_s,
            "--duration-s",
            "2",
            "--f-start-hz",
            "5",
        ],
        0,
    );
    bench_exits(
        &[
            "control",
            "--fast",
            "--json",
            "--out",
            &control_s,
            "--duration-s",
            "1.5",
        ],
        0,
    );
    // A fault: the probe reads NaN (recorded as null), the fault event.
    bench_exits(
        &[
            "control",
            "--fast",
            "--json",
            "--out",
            &faulted_s,
            "--duration-s",
            "1",
            "--inject-fault",
            "nan@0.5",
        ],
        3,
    );

    let chirp = validate_recording(&chirp);
    assert_topics(
        &chirp,
        &[
            ("/bench/sample", "bench.Sample"),
            ("/bench/timing", "bench.Timing"),
            ("/bench/event", "bench.Event"),
            ("/sysid/frf", "bench.Frf"),
            ("/sysid/summary", "bench.ChirpSummary"),
        ],
    );
    let control = validate_recording(&control);
    assert_topics(
        &control,
        &[
            ("/bench/sample", "bench.Sample"),
            ("/bench/event", "bench.Event"),
            ("/control/loop_check", "bench.LoopCheck"),
            ("/control/metrics", "bench.StepMetrics"),
            ("/control/summary", "bench.ControlSummary"),
        ],
    );
    let faulted = validate_recording(&faulted);
    assert_topics(
        &faulted,
        &[
            ("/bench/sample", "bench.Sample"),
            ("/bench/event", "bench.Event"),
            ("/control/loop_check", "bench.LoopCheck"),
        ],
    );

    // The fault run exercised the null (non-finite) and fault paths.
    let samples = &faulted["/bench/sample"].messages;
    assert!(samples.iter().any(|s| s["position_m"].is_null()));
    let events = &faulted["/bench/event"].messages;
    assert!(events.iter().any(|e| e["fault"] == "probe_not_finite"));

    // Recordings keep their fields (the README's recording reference).
    let keys = |v: &Value| -> BTreeSet<String> { v.as_object().unwrap().keys().cloned().collect() };
    let names = |s: &str| -> BTreeSet<String> { s.split(' ').map(String::from).collect() };
    assert_eq!(
        keys(&samples[0]),
        names(
            "tick t_s wake_s current_command_a position_m excitation_a setpoint_m state \
             out_of_range"
        )
    );
    assert_eq!(
        keys(&chirp["/bench/timing"].messages[0]),
        names(
            "tick t_s ticks wake_latency_mean_ns wake_latency_p50_ns wake_latency_p99_ns \
             wake_latency_p999_ns wake_latency_max_ns compute_mean_ns compute_p50_ns \
             compute_p99_ns compute_p999_ns compute_max_ns overruns dropped_records"
        )
    );
    assert_eq!(keys(&events[0]), names("tick t_s kind state fault value"));
    assert_eq!(
        keys(&chirp["/sysid/frf"].messages[0]),
        names("frequency_hz magnitude_m_per_a phase_deg coherence")
    );
    assert_eq!(
        keys(&control["/control/metrics"].messages[0]),
        names(
            "step_m rise_time_s settling_time_s overshoot_pct steady_state_error_mean_nm \
             steady_state_error_std_nm steady_state_window_s peak_command_a"
        )
    );

    // The validator rejects wrong messages against the generated schemas.
    let sample_schema = &control["/bench/sample"].schema;
    let sample = &control["/bench/sample"].messages[0];
    let valid = |schema: &Value, v: &Value| jsonschema::validator_for(schema).unwrap().is_valid(v);
    assert!(valid(sample_schema, sample));
    assert!(valid(
        sample_schema,
        &replaced(sample, "/position_m", Value::Null)
    ));
    for (pointer, wrong) in [
        ("/position_m", json!("1e-6")),
        ("/tick", json!(-1)),
        ("/tick", json!(0.5)),
        ("/state", json!("sleeping")),
        ("/out_of_range", json!(0)),
    ] {
        assert!(
            !valid(sample_schema, &replaced(sample, pointer, wrong.clone())),
            "{pointer} = {wrong} accepted"
        );
    }
    let mut no_tick = sample.clone();
    no_tick.as_object_mut().unwrap().remove("tick");
    assert!(
        !valid(sample_schema, &no_tick),
        "a sample without tick accepted"
    );
    let event_schema = &faulted["/bench/event"].schema;
    assert!(!valid(
        event_schema,
        &replaced(&events[0], "/fault", json!("gremlins"))
    ));
    let summary = &control["/control/summary"];
    let s = &summary.messages[0];
    assert!(!valid(
        &summary.schema,
        &replaced(s, "/metrics/overshoot_pct", json!("big"))
    ));
    assert!(!valid(
        &summary.schema,
        &replaced(s, "/loop_check/discretization/method", json!("euler"))
    ));
    let frf = &chirp["/sysid/frf"];
    assert!(!valid(
        &frf.schema,
        &replaced(&frf.messages[0], "/coherence/0", json!(true))
    ));
}
