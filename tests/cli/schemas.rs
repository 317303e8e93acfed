//! Every message of a recorded chirp run (paced, `--pace 50`) and of
//! recorded control runs (one clean, one with a fault) on the simulator is
//! valid against its channel's schema, checked with independent
//! implementations: JSON channels against their JSON Schema
//! (`jsonschema`), the protobuf channels (`/bench/sample`
//! blocks, `/bench/envelope`) decoded against the recorded
//! `FileDescriptorSet` by `prost-reflect` (no unknown field, every enum
//! value defined, every column of a block as long as the block); every
//! field of every JSON schema has a description; and the validators do
//! reject wrong messages (a summary's pacing mode outside `virtual`, `paced`,
//! `realtime` among them).

use crate::common;

use common::*;
use serde_json::{json, Value};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// One channel of a recording: its schema and its messages (protobuf
/// channels: validated while read, `schema` null; sample blocks as one
/// JSON-shaped sample per tick).
struct Channel {
    schema_name: String,
    schema: Value,
    messages: Vec<Value>,
}

/// Decodes a protobuf message against the schema's own descriptor set
/// (prost-reflect, independent of the writer's prost structs) and checks
/// it: no unknown field, every enum value defined, and for a sample block
/// every repeated column as long as `t_s`.
fn check_protobuf(topic: &str, schema: &mcap::Schema, data: &[u8]) -> Result<(), String> {
    use prost_reflect::{DescriptorPool, DynamicMessage, Kind, Value as PV};
    let pool = DescriptorPool::decode(schema.data.as_ref())
        .map_err(|e| format!("{topic}: schema is not a FileDescriptorSet: {e}"))?;
    let desc = pool
        .get_message_by_name(&schema.name)
        .ok_or_else(|| format!("{topic}: no message {} in its schema", schema.name))?;
    let msg = DynamicMessage::decode(desc.clone(), data)
        .map_err(|e| format!("{topic}: not a {}: {e}", schema.name))?;
    if msg.unknown_fields().next().is_some() {
        return Err(format!("{topic}: unknown fields"));
    }
    let mut lengths = BTreeSet::new();
    for f in desc.fields() {
        let v = msg.get_field(&f);
        if let Kind::Enum(e) = f.kind() {
            let values: Vec<i32> = match v.as_ref() {
                PV::EnumNumber(n) => vec![*n],
                PV::List(l) => l.iter().filter_map(PV::as_enum_number).collect(),
                _ => vec![],
            };
            if let Some(n) = values.iter().find(|n| e.get_value(**n).is_none()) {
                return Err(format!("{topic}.{}: {n} is not a {}", f.name(), e.name()));
            }
        }
        if f.is_list() {
            lengths.insert(v.as_list().map_or(0, <[PV]>::len));
        }
    }
    if lengths.len() > 1 {
        return Err(format!("{topic}: columns of different lengths {lengths:?}"));
    }
    Ok(())
}

/// The channels of an MCAP recording by topic (strict read: the file must
/// be complete).
fn channels(path: &Path) -> BTreeMap<String, Channel> {
    let bytes = std::fs::read(path).expect("recording");
    let mut out: BTreeMap<String, Channel> = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).expect("mcap") {
        let m = m.expect("message");
        let schema = m.channel.schema.as_ref().expect("channel has a schema");
        if m.channel.message_encoding == "protobuf" {
            assert_eq!(schema.encoding, "protobuf", "{}", m.channel.topic);
            check_protobuf(&m.channel.topic, schema, &m.data).unwrap();
            let ch = out
                .entry(m.channel.topic.clone())
                .or_insert_with(|| Channel {
                    schema_name: schema.name.clone(),
                    schema: Value::Null,
                    messages: Vec::new(),
                });
            if m.channel.topic == "/bench/sample" {
                for (_, s) in bench::record::decode_samples(&m).unwrap() {
                    ch.messages.push(serde_json::to_value(s).unwrap());
                }
            } else {
                ch.messages.push(Value::Null);
            }
            continue;
        }
        assert_eq!(m.channel.message_encoding, "json", "{}", m.channel.topic);
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
    for (topic, ch) in chans.iter().filter(|c| !c.1.schema.is_null()) {
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

/// A JSON pointer's segments (`*`: every element of an array).
fn segments(pointer: &str) -> Vec<&str> {
    pointer.split('/').skip(1).collect()
}

/// `schema` with its `$ref` followed (within `root`).
fn resolved<'a>(root: &'a Value, schema: &'a Value) -> &'a Value {
    match schema.get("$ref").and_then(Value::as_str) {
        Some(r) => resolved(
            root,
            root.pointer(r.trim_start_matches('#'))
                .unwrap_or_else(|| panic!("$ref {r} does not resolve")),
        ),
        None => schema,
    }
}

/// Whether the JSON Schema `schema` (its references resolved in `root`)
/// describes the field at `segments`: an object's property by name, `*`
/// an array's items; through `anyOf`, `oneOf` and `allOf` (an `Option` is
/// `anyOf [T, null]`).
fn schema_has(root: &Value, schema: &Value, segments: &[&str]) -> bool {
    let schema = resolved(root, schema);
    let Some((first, rest)) = segments.split_first() else {
        return true;
    };
    let through = ["anyOf", "oneOf", "allOf"].iter().any(|k| {
        schema
            .get(*k)
            .and_then(Value::as_array)
            .is_some_and(|bs| bs.iter().any(|b| schema_has(root, b, segments)))
    });
    let next = if *first == "*" {
        schema.get("items")
    } else {
        schema.get("properties").and_then(|p| p.get(*first))
    };
    through || next.is_some_and(|n| schema_has(root, n, rest))
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
    let control_path = control.clone();
    let faulted = dir.path().join("faulted.mcap");
    let p = |f: &Path| f.display().to_string();
    let (chirp_s, control_s, faulted_s) = (p(&chirp), p(&control), p(&faulted));
    // Paced (its summary's timing says so).
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
            "--pace",
            "50",
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
    // With --verify: /control/verify (its arrays and the summary's
    // `verify`). Whether a 2 s sweep agrees with the prediction is not
    // what is tested here: 0 or 8, the recording is complete either way.
    let verified = dir.path().join("verified.mcap");
    let o = run(&[
        "control",
        "--fast",
        "--json",
        "--out",
        &p(&verified),
        "--duration-s",
        "1",
        "--verify",
        "--verify-duration-s",
        "2",
    ]);
    assert!(
        matches!(o.status.code(), Some(0 | 8)),
        "{}",
        String::from_utf8_lossy(&o.stderr)
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

    // A multisine: the summary's `multisine` (the BLA and its test).
    let multisine = dir.path().join("multisine.mcap");
    bench_exits(
        &[
            "chirp",
            "--json",
            "--out",
            &p(&multisine),
            "--excitation",
            "multisine",
            "--f-start-hz",
            "5",
        ],
        0,
    );

    let chirp = validate_recording(&chirp);
    let chirp_topics = [
        ("/bench/sample", "bench.SampleBlock"),
        ("/bench/envelope", "bench.Envelope"),
        ("/bench/timing", "bench.Timing"),
        ("/bench/event", "bench.Event"),
        ("/sysid/frf", "bench.Frf"),
        ("/sysid/summary", "bench.ChirpSummary"),
    ];
    assert_topics(&chirp, &chirp_topics);
    // The pacing in the summary: a paced run says `paced`, its factor and
    // its batch; the schema knows three modes and nothing else.
    let cs = &chirp["/sysid/summary"];
    let paced = &cs.messages[0];
    assert_eq!(paced["timing"]["mode"], "paced", "{}", paced["timing"]);
    assert_eq!(paced["timing"]["pace_factor"], 50.0);
    assert_eq!(paced["timing"]["pace_batch_ticks"], 250);
    let valid_cs = |x: &Value| jsonschema::validator_for(&cs.schema).unwrap().is_valid(x);
    assert!(valid_cs(paced));
    for (pointer, wrong) in [
        ("/timing/mode", json!("fast")),
        ("/timing/mode", json!("Paced")),
        ("/timing/mode", json!(1)),
        ("/timing/pace_factor", json!("50")),
        ("/timing/pace_batch_ticks", json!(-1)),
        ("/timing/pace_batch_ticks", json!(2.5)),
    ] {
        assert!(
            !valid_cs(&replaced(paced, pointer, wrong.clone())),
            "{pointer} = {wrong} accepted"
        );
    }
    for mode in ["virtual", "realtime"] {
        let mut other = replaced(paced, "/timing/mode", json!(mode));
        let t = other["timing"].as_object_mut().unwrap();
        t.remove("pace_factor");
        t.remove("pace_batch_ticks");
        assert!(valid_cs(&other), "{mode}");
    }
    let multisine = validate_recording(&multisine);
    assert_topics(&multisine, &chirp_topics);
    let ms = &multisine["/sysid/summary"];
    let summary = &ms.messages[0];
    assert!(
        summary["multisine"]["distortion"]["lines"]
            .as_u64()
            .unwrap()
            >= 10
    );
    let valid_ms = |x: &Value| jsonschema::validator_for(&ms.schema).unwrap().is_valid(x);
    assert!(valid_ms(summary));
    assert!(!valid_ms(&replaced(
        summary,
        "/multisine/distortion/detected",
        json!("no")
    )));
    assert!(!valid_ms(&replaced(
        summary,
        "/multisine/band_hz",
        json!([1.0])
    )));
    let control = validate_recording(&control);
    assert_topics(
        &control,
        &[
            ("/bench/sample", "bench.SampleBlock"),
            ("/bench/envelope", "bench.Envelope"),
            ("/bench/event", "bench.Event"),
            ("/control/loop_check", "bench.LoopCheck"),
            ("/control/metrics", "bench.StepMetrics"),
            ("/control/summary", "bench.ControlSummary"),
        ],
    );
    let verified = validate_recording(&verified);
    assert_topics(
        &verified,
        &[
            ("/bench/sample", "bench.SampleBlock"),
            ("/control/loop_check", "bench.LoopCheck"),
            ("/control/metrics", "bench.StepMetrics"),
            ("/control/verify", "bench.VerifyMessage"),
            ("/control/summary", "bench.ControlSummary"),
        ],
    );
    // Every field the catalogue reads of the jobs' results
    // (`bench::catalogue::RESULT_READS`) is in the schema its writer
    // records: a field renamed or removed there fails here, not as an
    // empty catalogue column.
    for reads in bench::catalogue::RESULT_READS {
        let ch = [&chirp, &verified]
            .into_iter()
            .find_map(|c| c.get(reads.topic))
            .unwrap_or_else(|| panic!("no {} recorded", reads.topic));
        assert_eq!(ch.schema_name, reads.schema, "{}", reads.topic);
        for field in reads.fields {
            assert!(
                schema_has(&ch.schema, &ch.schema, &segments(field)),
                "the catalogue reads {field} of {}, which its schema {} does not have",
                reads.topic,
                reads.schema
            );
        }
    }
    // ... and the check can fail.
    let cs = &chirp["/sysid/summary"].schema;
    for absent in [
        "/peak_position_mm",
        "/fit/modes/frequency_hz",
        "/fit/modes/*/freq",
    ] {
        assert!(!schema_has(cs, cs, &segments(absent)), "{absent}");
    }
    let v = &verified["/control/verify"];
    let keys_of =
        |v: &Value| -> BTreeSet<String> { v.as_object().unwrap().keys().cloned().collect() };
    assert_eq!(
        keys_of(&v.messages[0]),
        BTreeSet::from_iter(
            "verify frequency_hz s_magnitude s_phase_deg s_coherence t_magnitude t_phase_deg \
             t_coherence ps_magnitude_m_per_a ps_phase_deg ps_coherence ps_sigma_m_per_a used \
             model_s_magnitude model_s_phase_deg"
                .split(' ')
                .map(String::from)
        )
    );
    let valid_v = |x: &Value| jsonschema::validator_for(&v.schema).unwrap().is_valid(x);
    assert!(!valid_v(&replaced(
        &v.messages[0],
        "/verify/result/flagged",
        json!("no")
    )));
    assert!(!valid_v(&replaced(&v.messages[0], "/used/0", json!(1.0))));
    let faulted = validate_recording(&faulted);
    assert_topics(
        &faulted,
        &[
            ("/bench/sample", "bench.SampleBlock"),
            ("/bench/envelope", "bench.Envelope"),
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
        names(
            "frequency_hz magnitude_m_per_a phase_deg coherence sigma_m_per_a resolution_hz \
             sigma_dof"
        )
    );
    assert_eq!(
        keys(&control["/control/metrics"].messages[0]),
        names(
            "step_m rise_time_s settling_time_s settling_margin overshoot_pct \
             steady_state_error_mean_nm steady_state_error_std_nm steady_state_window_s \
             peak_command_a"
        )
    );

    // The validators reject wrong messages against the generated schemas.
    let valid = |schema: &Value, v: &Value| jsonschema::validator_for(schema).unwrap().is_valid(v);
    let timing_schema = &control["/bench/timing"].schema;
    let timing = &control["/bench/timing"].messages[0];
    assert!(valid(timing_schema, timing));
    assert!(valid(
        timing_schema,
        &replaced(timing, "/wake_latency_max_ns", Value::Null)
    ));
    for (pointer, wrong) in [
        ("/wake_latency_max_ns", json!("1e3")),
        ("/tick", json!(-1)),
        ("/tick", json!(0.5)),
        ("/overruns", json!(false)),
    ] {
        assert!(
            !valid(timing_schema, &replaced(timing, pointer, wrong.clone())),
            "{pointer} = {wrong} accepted"
        );
    }
    let mut no_tick = timing.clone();
    no_tick.as_object_mut().unwrap().remove("tick");
    assert!(
        !valid(timing_schema, &no_tick),
        "a timing window without tick accepted"
    );
    // Protobuf: a block with an undefined state, a ragged block, a field
    // of the wrong wire type and an unknown field are refused.
    let schema = mcap::Schema {
        id: 1,
        name: "bench.SampleBlock".into(),
        encoding: "protobuf".into(),
        data: bench::record::proto::file_descriptor_set().into(),
    };
    let block = |edit: &dyn Fn(&mut bench::record::proto::SampleBlock)| {
        let mut b = bench::record::proto::SampleBlock::with_capacity();
        let s = bench::record::read_samples_tolerant(&std::fs::read(&control_path).unwrap());
        for r in &s[..10] {
            b.push(r);
        }
        edit(&mut b);
        prost::Message::encode_to_vec(&b)
    };
    check_protobuf("/bench/sample", &schema, &block(&|_| {})).unwrap();
    assert!(check_protobuf("/bench/sample", &schema, &block(&|b| b.state[3] = 7)).is_err());
    assert!(check_protobuf(
        "/bench/sample",
        &schema,
        &block(&|b| {
            b.position_m.pop();
        })
    )
    .is_err());
    let mut wrong_wire = block(&|_| {});
    wrong_wire.extend([0x10, 0x01]); // field 2 (t_s, packed doubles) as a varint
    assert!(check_protobuf("/bench/sample", &schema, &wrong_wire).is_err());
    let mut unknown = block(&|_| {});
    unknown.extend([0xa0, 0x01, 0x01]); // field 20, varint
    assert!(check_protobuf("/bench/sample", &schema, &unknown).is_err());
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
    for pointer in ["/sigma_m_per_a/0", "/resolution_hz/0", "/sigma_dof/0"] {
        assert!(
            !valid(
                &frf.schema,
                &replaced(&frf.messages[0], pointer, json!("1e-6"))
            ),
            "{pointer} as a string accepted"
        );
    }
}
