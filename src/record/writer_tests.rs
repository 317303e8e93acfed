//! Tests of the recorder and its writer thread.

use super::*;
use crate::record::reader::{decode_samples, read_messages_tolerant, read_samples_tolerant};
use crate::record::spawn_writer;
use crate::record::topics::SampleRecord;
use crate::vocab::{EventKind, FaultKind, SupervisorState};
use serde_json::{json, Value};
use std::sync::atomic::{AtomicBool, Ordering};

fn sample(tick: u64) -> SampleRecord {
    let t_s = tick as f64 * 200e-6;
    SampleRecord {
        tick,
        t_s,
        wake_s: t_s + 1e-5 * (tick % 3) as f64,
        current_command_a: 0.1 * (tick as f64).sin(),
        position_m: if tick % 7 == 3 {
            f64::NAN
        } else {
            1e-6 * tick as f64
        },
        excitation_a: if tick.is_multiple_of(2) {
            f64::NAN
        } else {
            0.05
        },
        setpoint_m: f64::NAN,
        state: SupervisorState::Running,
        out_of_range: tick.is_multiple_of(11),
    }
}

fn timing(tick: u64) -> TimingRecord {
    TimingRecord {
        tick,
        t_s: tick as f64 * 200e-6,
        ticks: 500,
        wake_latency_mean_ns: 1234.5,
        wake_latency_p50_ns: 1100.0,
        wake_latency_p99_ns: 5000.0,
        wake_latency_p999_ns: 8000.0,
        wake_latency_max_ns: 9000.0,
        compute_mean_ns: 800.25,
        compute_p50_ns: 750.0,
        compute_p99_ns: 2000.0,
        compute_p999_ns: 2500.0,
        compute_max_ns: f64::NAN,
        overruns: 1,
        dropped_records: 2,
    }
}

fn event(tick: u64, kind: EventKind, fault: Option<FaultKind>, value: f64) -> EventRecord {
    EventRecord {
        tick,
        t_s: tick as f64 * 200e-6,
        kind,
        state: SupervisorState::Faulted,
        fault,
        value,
    }
}

/// Equal, both NaN, or 1 ULP apart: the JSON text is the exact shortest
/// representation, but serde_json without its `float_roundtrip` feature
/// may parse it back 1 ULP off.
fn same_f64(a: f64, b: f64) -> bool {
    (a.is_nan() && b.is_nan())
        || a == b
        || (a.is_finite() && (a - b).abs() <= f64::EPSILON * a.abs().max(b.abs()))
}

/// `s` as the recording stores it: currents and positions in single
/// precision.
fn stored(s: &SampleRecord) -> SampleRecord {
    let single = |x: f64| f64::from(x as f32);
    SampleRecord {
        current_command_a: single(s.current_command_a),
        position_m: single(s.position_m),
        excitation_a: single(s.excitation_a),
        setpoint_m: single(s.setpoint_m),
        ..*s
    }
}

fn same_sample(a: &SampleRecord, b: &SampleRecord) -> bool {
    a.tick == b.tick
        && same_f64(a.t_s, b.t_s)
        && same_f64(a.current_command_a, b.current_command_a)
        && same_f64(a.position_m, b.position_m)
        && same_f64(a.excitation_a, b.excitation_a)
        && same_f64(a.setpoint_m, b.setpoint_m)
        && a.state == b.state
        && a.out_of_range == b.out_of_range
}

fn by_topic(msgs: &[mcap::Message<'static>]) -> BTreeMap<String, Vec<Value>> {
    let mut out: BTreeMap<String, Vec<Value>> = BTreeMap::new();
    for m in msgs.iter().filter(|m| m.channel.message_encoding == "json") {
        out.entry(m.channel.topic.clone())
            .or_default()
            .push(serde_json::from_slice(&m.data).expect("message is JSON"));
    }
    out
}

/// A job's result, for the generic channel API.
#[derive(Serialize, JsonSchema)]
struct Metrics {
    /// RMS error, m.
    rms_m: f64,
}

/// With the run's start set, every log time (and the log line's
/// timestamp) is that start plus the loop time.
#[test]
fn log_times_are_unix_time_from_the_origin() {
    let dir = tempfile::tempdir().unwrap();
    let mut rec = Recorder::create(&dir.path().join("run.mcap")).unwrap();
    let origin = 1_795_000_000_123_456_789;
    rec.set_time_origin_ns(origin);
    rec.write_record(&Record::Sample(sample(5))).unwrap();
    rec.write_record(&Record::Event(event(
        5,
        EventKind::JobStarted,
        None,
        f64::NAN,
    )))
    .unwrap();
    let path = rec.finish().unwrap();
    let bytes = std::fs::read(path).unwrap();
    let msgs = read_messages_tolerant(&bytes).messages;
    // The event, its log line, the sample's block and its envelope.
    assert_eq!(msgs.len(), 4);
    for m in &msgs {
        assert_eq!(m.log_time, origin + 1_000_000, "{}", m.channel.topic);
    }
    let line = msgs.iter().find(|m| m.channel.topic == TOPIC_LOG).unwrap();
    let log: Value = serde_json::from_slice(&line.data).unwrap();
    assert_eq!(log["timestamp"]["sec"], json!(1_795_000_000));
    assert_eq!(log["timestamp"]["nsec"], json!(124_456_789));
}

#[test]
fn record_roundtrip_full_file() {
    let dir = tempfile::tempdir().unwrap();
    let final_path = dir.path().join("run.mcap");
    let mut rec = Recorder::create(&final_path).unwrap();
    assert_eq!(rec.part_path(), dir.path().join("run.mcap.part"));
    assert!(rec.part_path().exists());
    assert!(!final_path.exists());

    let mut config = BTreeMap::new();
    config.insert("toml".to_string(), "[loop]\nrate_hz = 5000\n".to_string());
    config.insert("version".to_string(), "1".to_string());
    rec.write_metadata("bench.config", &config).unwrap();

    rec.write_record(&Record::Event(event(
        0,
        EventKind::LoopStarted,
        None,
        f64::NAN,
    )))
    .unwrap();
    for tick in 0..1000 {
        rec.write_record(&Record::Sample(sample(tick))).unwrap();
        if tick % 500 == 499 {
            rec.write_record(&Record::Timing(timing(tick))).unwrap();
            rec.flush_chunk().unwrap();
        }
    }
    rec.write_record(&Record::Event(event(
        999,
        EventKind::Fault,
        Some(FaultKind::PositionLimit),
        1.5e-3,
    )))
    .unwrap();
    let freq = [1.0, 2.0, 4.0];
    let mag = [1e-3, 2e-3, f64::NAN];
    let phase = [-10.0, -20.0, -180.0];
    let coh = [0.99, 0.95, 0.5];
    let sigma = [1e-5, 2e-5, f64::NAN];
    let resolution = [0.1, 0.1, 0.2];
    let dof = [6.0, 6.0, f64::INFINITY];
    let lines = FrfRecord {
        frequency_hz: (&freq[..]).into(),
        magnitude_m_per_a: (&mag[..]).into(),
        phase_deg: (&phase[..]).into(),
        coherence: (&coh[..]).into(),
        sigma_m_per_a: (&sigma[..]).into(),
        resolution_hz: (&resolution[..]).into(),
        sigma_dof: (&dof[..]).into(),
    };
    rec.write_frf(log_time_ns(0.2), &lines).unwrap();
    // Extra channel through the generic API.
    let ch = rec
        .add_channel_for::<Metrics>("/bench/metrics", "bench.Metrics")
        .unwrap();
    rec.write(ch, 42, &Metrics { rms_m: 1e-7 }).unwrap();
    rec.write(ch, 43, &Metrics { rms_m: f64::NAN }).unwrap();
    assert!(matches!(
        rec.write_frf(
            0,
            &FrfRecord {
                magnitude_m_per_a: (&mag[..2]).into(),
                ..lines.clone()
            }
        ),
        Err(RecordError::FrfLength { magnitude: 2, .. })
    ));
    assert!(matches!(
        rec.write_frf(
            0,
            &FrfRecord {
                sigma_m_per_a: (&sigma[..1]).into(),
                ..lines.clone()
            }
        ),
        Err(RecordError::FrfLength { sigma: 1, .. })
    ));

    let out = rec.finish().unwrap();
    assert_eq!(out, final_path);
    assert!(final_path.exists());
    assert!(!part_path_for(&final_path).exists(), ".part must be gone");

    let bytes = std::fs::read(&final_path).unwrap();
    // Strict reader (checks end magic, CRCs) must accept the file.
    let msgs: Vec<_> = mcap::MessageStream::new(&bytes)
        .unwrap()
        .collect::<Result<_, _>>()
        .unwrap();
    let topics = by_topic(&msgs);
    assert!(!topics.contains_key(TOPIC_SAMPLE), "samples are protobuf");
    assert_eq!(topics[TOPIC_TIMING].len(), 2);
    assert_eq!(topics[TOPIC_EVENT].len(), 2);
    assert_eq!(topics[TOPIC_FRF].len(), 1);
    assert_eq!(topics["/bench/metrics"].len(), 2);

    // Encodings, schema names, schemas with unit descriptions.
    for m in msgs
        .iter()
        .filter(|m| ![TOPIC_SAMPLE, TOPIC_ENVELOPE].contains(&m.channel.topic.as_str()))
    {
        assert_eq!(m.channel.message_encoding, "json");
        let schema = m.channel.schema.as_ref().unwrap();
        assert_eq!(schema.encoding, "jsonschema");
    }
    let stored_schema = |topic: &str| {
        let m = msgs.iter().find(|m| m.channel.topic == topic).unwrap();
        let s = m.channel.schema.as_ref().unwrap();
        (
            s.name.clone(),
            serde_json::from_slice::<Value>(&s.data).unwrap(),
        )
    };
    for (topic, name, generated) in [
        (TOPIC_TIMING, SCHEMA_TIMING, schema_of::<TimingRecord>()),
        (TOPIC_EVENT, SCHEMA_EVENT, schema_of::<EventRecord>()),
        (TOPIC_FRF, SCHEMA_FRF, schema_of::<FrfRecord>()),
        ("/bench/metrics", "bench.Metrics", schema_of::<Metrics>()),
    ] {
        let (n, s) = stored_schema(topic);
        assert_eq!(n, name);
        assert_eq!(s, generated, "{topic}");
        let props = s["properties"].as_object().unwrap();
        assert!(!props.is_empty());
        for (field, p) in props {
            assert!(
                p["description"].as_str().is_some_and(|d| !d.is_empty()),
                "{topic}.{field} lacks a description"
            );
        }
        // Every emitted field is in the schema, and every field of the
        // schema is emitted.
        let first = topics[topic][0].as_object().unwrap();
        assert_eq!(
            first.keys().collect::<Vec<_>>(),
            props.keys().collect::<Vec<_>>(),
            "{topic}"
        );
    }
    assert!(topics["/bench/metrics"][1]["rms_m"].is_null());

    // The samples: protobuf blocks, closed when full (256 ticks) and
    // at each chunk flush (after ticks 499 and 999).
    let blocks: Vec<&mcap::Message> = msgs
        .iter()
        .filter(|m| m.channel.topic == TOPIC_SAMPLE)
        .collect();
    assert_eq!(blocks.len(), 4);
    let schema = blocks[0].channel.schema.as_ref().unwrap();
    assert_eq!(
        (
            schema.name.as_str(),
            schema.encoding.as_str(),
            blocks[0].channel.message_encoding.as_str()
        ),
        (SCHEMA_SAMPLE_BLOCK, "protobuf", "protobuf")
    );
    let mut next = 0u64;
    for (i, (m, first)) in blocks.iter().zip([0u64, 256, 500, 756]).enumerate() {
        assert_eq!(m.sequence, i as u32);
        assert_eq!(m.log_time, log_time_ns(first as f64 * 200e-6));
        assert_eq!(m.publish_time, m.log_time);
        for (log_time, got) in decode_samples(m).unwrap() {
            assert_eq!(got.tick, next);
            assert!(
                same_sample(&got, &stored(&sample(next))),
                "sample {next}: {got:?}"
            );
            assert_eq!(log_time, log_time_ns(next as f64 * 200e-6));
            next += 1;
        }
    }
    assert_eq!(next, 1000);
    let all = read_samples_tolerant(&bytes);
    assert_eq!(all.len(), 1000);
    let s3 = all[3];
    assert!(s3.position_m.is_nan() && s3.setpoint_m.is_nan());
    assert_eq!(s3.excitation_a, f64::from(0.05_f32));
    assert_eq!(s3.state, SupervisorState::Running);
    // The envelope: one message per 5 ms (25 ticks).
    let env: Vec<proto::Envelope> = msgs
        .iter()
        .filter(|m| m.channel.topic == TOPIC_ENVELOPE)
        .map(|m| prost::Message::decode(&m.data[..]).unwrap())
        .collect();
    assert_eq!(env.len(), 40);
    assert!(env.iter().all(|e| e.ticks == 25));
    let t0 = &topics[TOPIC_TIMING][0];
    assert_eq!(t0["tick"], json!(499));
    assert_eq!(t0["ticks"], json!(500));
    assert_eq!(t0["wake_latency_mean_ns"], json!(1234.5));
    assert!(t0["compute_max_ns"].is_null());
    assert_eq!(t0["dropped_records"], json!(2));
    let e = &topics[TOPIC_EVENT];
    assert_eq!(e[0]["kind"], json!("loop_started"));
    assert!(e[0]["fault"].is_null());
    assert!(e[0]["value"].is_null());
    assert_eq!(e[1]["kind"], json!("fault"));
    assert_eq!(e[1]["fault"], json!("position_limit"));
    assert_eq!(e[1]["state"], json!("faulted"));
    assert_eq!(e[1]["value"], json!(1.5e-3));
    // The events again as foxglove.Log lines: info, then error.
    let log = &topics[TOPIC_LOG];
    assert_eq!(log.len(), 2);
    assert_eq!(log[0]["level"], json!(2));
    assert_eq!(log[1]["level"], json!(4));
    let text = log[1]["message"].as_str().unwrap();
    assert!(
        text.starts_with("fault: position_limit (value 0.0015)"),
        "{text}"
    );
    let f = &topics[TOPIC_FRF][0];
    assert_eq!(f["frequency_hz"], json!([1.0, 2.0, 4.0]));
    assert_eq!(f["magnitude_m_per_a"], json!([1e-3, 2e-3, null]));
    assert_eq!(f["coherence"], json!([0.99, 0.95, 0.5]));
    assert_eq!(f["sigma_m_per_a"], json!([1e-5, 2e-5, null]));
    assert_eq!(f["resolution_hz"], json!([0.1, 0.1, 0.2]));
    assert_eq!(f["sigma_dof"], json!([6.0, 6.0, null]));
    let frf_msg = msgs.iter().find(|m| m.channel.topic == TOPIC_FRF).unwrap();
    assert_eq!(frf_msg.log_time, 200_000_000);

    // Summary: statistics and metadata.
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let stats = summary.stats.as_ref().unwrap();
    // Sample blocks, envelope, timing, events, FRF, metrics, and the
    // events again on /bench/log.
    assert_eq!(stats.message_count, 4 + 40 + 2 + 2 + 1 + 2 + 2);
    assert_eq!(stats.metadata_count, 1);
    assert_eq!(summary.metadata_indexes.len(), 1);
    assert_eq!(summary.metadata_indexes[0].name, "bench.config");
    let md = mcap::read::metadata(&bytes, &summary.metadata_indexes[0]).unwrap();
    assert_eq!(md.name, "bench.config");
    assert_eq!(md.metadata, config);
    assert!(summary.chunk_indexes.iter().all(|c| c.compression == "lz4"));
}

#[test]
fn record_create_in_missing_directory_fails_with_path() {
    let dir = tempfile::tempdir().unwrap();
    let final_path = dir.path().join("no-such-dir").join("run.mcap");
    let err = Recorder::create(&final_path).unwrap_err();
    assert!(matches!(err, RecordError::Create { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(msg.contains("no-such-dir"), "{msg}");
    assert!(msg.contains("run.mcap.part"), "{msg}");
    let os = io::Error::from(io::ErrorKind::NotFound).to_string();
    assert!(
        msg.contains("No such file or directory") || msg.contains(&os),
        "{msg}"
    );
}

#[test]
fn record_drop_without_finish_leaves_part() {
    let dir = tempfile::tempdir().unwrap();
    let final_path = dir.path().join("run.mcap");
    {
        let mut rec = Recorder::create(&final_path).unwrap();
        for tick in 0..10 {
            rec.write_record(&Record::Sample(sample(tick))).unwrap();
        }
        // dropped here, e.g. on an error path
    }
    assert!(!final_path.exists());
    let part = part_path_for(&final_path);
    assert!(part.exists());
    // Drop still completed the MCAP structure: strict reading works.
    let bytes = std::fs::read(&part).unwrap();
    let n = mcap::MessageStream::new(&bytes)
        .unwrap()
        .collect::<Result<Vec<_>, _>>()
        .unwrap()
        .len();
    // One block of the 10 ticks and one 5 ms envelope bucket.
    assert_eq!(n, 2);
    assert_eq!(read_samples_tolerant(&bytes).len(), 10);
    assert!(mcap::Summary::read(&bytes).unwrap().is_some());
}

#[test]
fn record_truncated_file_readable_up_to_last_flush() {
    let dir = tempfile::tempdir().unwrap();
    let final_path = dir.path().join("run.mcap");
    let mut rec = Recorder::create(&final_path).unwrap();
    let part = rec.part_path().to_path_buf();

    // Right after create, the schemas/channels are already on disk.
    let bytes0 = std::fs::read(&part).unwrap();
    let r0 = read_messages_tolerant(&bytes0);
    assert!(r0.messages.is_empty());
    assert!(r0.error.is_none(), "{:?}", r0.error);

    let mut tick = 0;
    let mut snapshots = Vec::new(); // (bytes on disk, samples flushed so far)
    for _batch in 0..5 {
        for _ in 0..300 {
            rec.write_record(&Record::Sample(sample(tick))).unwrap();
            tick += 1;
        }
        rec.flush_chunk().unwrap();
        snapshots.push((std::fs::read(&part).unwrap(), tick));
    }
    // Written but not flushed: must not be on disk, must not matter.
    for _ in 0..123 {
        rec.write_record(&Record::Sample(sample(tick))).unwrap();
        tick += 1;
    }
    let unflushed = std::fs::read(&part).unwrap();
    assert_eq!(unflushed, snapshots.last().unwrap().0);

    for (bytes, flushed) in &snapshots {
        // Cleanly cut after a flush ("SIGKILL" right after flush_chunk).
        let samples = read_samples_tolerant(bytes);
        assert_eq!(samples.len() as u64, *flushed);
        for (i, s) in samples.iter().enumerate() {
            assert!(same_sample(s, &stored(&sample(i as u64))));
        }
        let r = read_messages_tolerant(bytes);
        assert!(r.error.is_none(), "{:?}", r.error);

        // The strict linear reader yields the same messages, then an
        // UnexpectedEof error (no end magic / footer).
        let mut ok = 0;
        let mut err = None;
        for m in mcap::MessageStream::new(bytes).unwrap() {
            match m {
                Ok(m) if m.channel.topic == TOPIC_SAMPLE => {
                    ok += decode_samples(&m).unwrap().len() as u64
                }
                Ok(_) => {}
                Err(e) => {
                    err = Some(e);
                    break;
                }
            }
        }
        assert_eq!(ok, *flushed);
        assert!(
            matches!(err, Some(mcap::McapError::UnexpectedEof)),
            "{err:?}"
        );
        // No summary in a killed file.
        assert!(
            mcap::Summary::read(bytes).is_err() || mcap::Summary::read(bytes).unwrap().is_none()
        );
    }

    // Killed while a chunk was being written: cut inside the last chunk.
    let (prev, prev_flushed) = &snapshots[snapshots.len() - 2];
    let (last, last_flushed) = &snapshots[snapshots.len() - 1];
    for cut in [
        prev.len() + 1,
        prev.len() + 9,
        prev.len() + 40,
        (prev.len() + last.len()) / 2,
        last.len() - 1,
    ] {
        let r = read_messages_tolerant(&last[..cut]);
        let n = r
            .messages
            .iter()
            .filter(|m| m.channel.topic == TOPIC_SAMPLE)
            .map(|m| decode_samples(m).unwrap().len() as u64)
            .sum::<u64>();
        assert!(n >= *prev_flushed && n <= *last_flushed, "cut {cut}: {n}");
        // Every cut is reported, also one right after a chunk's 9-byte
        // opcode+length prefix (which mcap's linear reader takes for a
        // clean end).
        assert!(r.error.is_some(), "cut {cut}: a cut chunk must be reported");
    }
    drop(rec);
}

#[test]
fn record_writer_thread_drains_and_flushes() {
    let dir = tempfile::tempdir().unwrap();
    let final_path = dir.path().join("run.mcap");
    let rec = Recorder::create(&final_path).unwrap();
    let (mut prod, cons) = rtrb::RingBuffer::<Record>::new(4096);
    let done = Arc::new(AtomicBool::new(false));
    let seen = Arc::new(std::sync::Mutex::new(Vec::new()));
    let seen2 = Arc::clone(&seen);
    let h = spawn_writer(
        cons,
        Default::default(),
        rec,
        Arc::clone(&done),
        ChunkPolicy::REAL_TIME,
        None,
        move |r| {
            if let Record::Sample(s) = r {
                seen2.lock().unwrap().push(s.tick);
            }
        },
    );
    assert_eq!(h.thread().name(), Some("bench-writer"));
    // 5000 samples = 1 s of loop time at 5 kHz, pushed much faster than
    // real time: log-time flushing must give ~10 chunks.
    let n = 5000u64;
    // The ring may be full at any push, the last one included (the
    // writer drains at its own pace): wait for room.
    let mut push_waiting = |mut r: Record| {
        while let Err(rtrb::PushError::Full(back)) = prod.push(r) {
            r = back;
            std::thread::yield_now();
        }
    };
    for tick in 0..n {
        push_waiting(Record::Sample(sample(tick)));
    }
    push_waiting(Record::Event(event(
        n,
        EventKind::LoopStopped,
        None,
        f64::NAN,
    )));
    done.store(true, Ordering::Release);
    let (rec, stats) = h.join().unwrap().unwrap();
    assert_eq!(stats.records_written, n + 1);
    assert!(stats.chunks_flushed >= 10, "{stats:?}");
    assert_eq!(*seen.lock().unwrap(), (0..n).collect::<Vec<_>>());

    // Flushed on return: the .part already holds everything.
    let bytes = std::fs::read(rec.part_path()).unwrap();
    assert_eq!(read_samples_tolerant(&bytes).len() as u64, n);

    let path = rec.finish().unwrap();
    let bytes = std::fs::read(path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    assert_eq!(read_samples_tolerant(&bytes).len() as u64, n);
    assert_eq!(
        summary.stats.unwrap().message_count,
        read_messages_tolerant(&bytes).messages.len() as u64
    );
    // ≤ 100 ms of loop time per chunk (+ one tick of slack).
    for c in &summary.chunk_indexes {
        assert!(
            c.message_end_time - c.message_start_time <= 100_000_000 + 200_000,
            "{c:?}"
        );
    }
}

#[test]
fn record_log_time_rounding() {
    assert_eq!(log_time_ns(0.0), 0);
    assert_eq!(log_time_ns(1.5), 1_500_000_000);
    assert_eq!(log_time_ns(200e-6 * 3.0), 600_000);
    assert_eq!(log_time_ns(-1.0), 0);
    assert_eq!(log_time_ns(f64::NAN), 0);
}

/// The FRF channel's one type round-trips through its JSON: a NaN (here a
/// magnitude) comes back NaN, an infinite `sigma_dof` (a known variance)
/// infinite, and a message of a recording made before the σ columns
/// existed reads with them empty.
#[test]
fn the_frf_record_reads_back_what_it_wrote() {
    let nan_mag = [1e-3, f64::NAN];
    let two = [1.0, 2.0];
    let dof = [6.0, f64::INFINITY];
    let written = FrfRecord {
        frequency_hz: (&two[..]).into(),
        magnitude_m_per_a: (&nan_mag[..]).into(),
        phase_deg: (&two[..]).into(),
        coherence: (&two[..]).into(),
        sigma_m_per_a: (&two[..]).into(),
        resolution_hz: (&two[..]).into(),
        sigma_dof: (&dof[..]).into(),
    };
    let json = serde_json::to_string(&written).unwrap();
    assert!(
        json.contains("\"magnitude_m_per_a\":[0.001,null]"),
        "{json}"
    );
    let back: FrfRecord = serde_json::from_str(&json).unwrap();
    assert!(back.magnitude_m_per_a[1].is_nan());
    assert_eq!(back.sigma_dof[1], f64::INFINITY);
    assert_eq!(back.frequency_hz, written.frequency_hz);
    let legacy: FrfRecord = serde_json::from_str(
        r#"{"frequency_hz":[1.0],"magnitude_m_per_a":[1e-3],"phase_deg":[0.0],"coherence":[1.0]}"#,
    )
    .unwrap();
    assert!(legacy.sigma_m_per_a.is_empty() && legacy.sigma_dof.is_empty());
}
