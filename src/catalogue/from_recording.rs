//! A finished recording's catalogue row, read through the recording's
//! index: the footer, the summary section, the two metadata records and
//! only the chunks that hold an event or a result (the first and the last
//! few of a run, whatever its length), so a 10-minute recording costs
//! about what a 1-second one does, and memory holds one chunk at a time.

use super::{finite, CatalogueRow, Outcome, MODE_COLUMNS};
use crate::input_file::{Kind, Problem};
use crate::record::topics::{EventKind, EventRecord};
use crate::record::TOPIC_EVENT;
use serde::Deserialize;
use serde_json::Value as Json;
use std::collections::BTreeMap;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

/// The chirp's summary channel.
const TOPIC_CHIRP_SUMMARY: &str = "/sysid/summary";
/// The control job's summary channel.
const TOPIC_CONTROL_SUMMARY: &str = "/control/summary";
/// The loop check, recorded before the loop starts.
const TOPIC_LOOP_CHECK: &str = "/control/loop_check";
/// The step metrics.
const TOPIC_STEP_METRICS: &str = "/control/metrics";

/// The channels a row reads.
const TOPICS: [&str; 5] = [
    TOPIC_EVENT,
    TOPIC_CHIRP_SUMMARY,
    TOPIC_CONTROL_SUMMARY,
    TOPIC_LOOP_CHECK,
    TOPIC_STEP_METRICS,
];

/// Why a recording gives no row.
#[derive(Debug, thiserror::Error)]
pub enum CatalogueError {
    /// The file cannot be read.
    #[error("{}: {source}", path.display())]
    Io {
        /// The recording.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// It is not a finished recording of `bench`.
    #[error("{}: {reason}", path.display())]
    Recording {
        /// The recording.
        path: PathBuf,
        /// Why, in words.
        reason: String,
    },
    /// The row file cannot be written.
    #[error("{}: {source}", path.display())]
    Write {
        /// The row file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
}

/// Magic at both ends of an MCAP file.
const MAGIC: &[u8] = b"\x89MCAP0\r\n";

/// `len` bytes of `file` at `offset`, which must lie within its `size`
/// bytes (an index pointing past the end is a damaged file, not a reason
/// to allocate what it says).
fn read_at(file: &std::fs::File, size: u64, offset: u64, len: u64) -> Result<Vec<u8>, String> {
    if offset.checked_add(len).is_none_or(|end| end > size) {
        return Err(format!(
            "its index points past its end ({len} bytes at byte {offset} of {size})"
        ));
    }
    let mut buf = vec![0; len as usize];
    file.read_exact_at(&mut buf, offset)
        .map_err(|e| e.to_string())?;
    Ok(buf)
}

/// The catalogue row of the finished recording at `path` (see the module
/// docs of [`super`] for every column's source); `recording` is the path
/// as given, made absolute. Memory: the summary section and one chunk at
/// a time.
///
/// # Errors
/// [`CatalogueError::Io`] when the file cannot be opened;
/// [`CatalogueError::Recording`] when it is not an MCAP file with a
/// summary section (an unfinished `.part`: `bench recover` it first), its
/// index or a chunk it needs is damaged, or it is not a recording of
/// `bench` (no `bench.run` metadata).
pub fn row_of_recording(path: &Path) -> Result<CatalogueRow, CatalogueError> {
    let io = |source| CatalogueError::Io {
        path: path.to_path_buf(),
        source,
    };
    let bad = |reason: String| CatalogueError::Recording {
        path: path.to_path_buf(),
        reason,
    };
    // A regular file within a recording's limit (crate::input_file); a
    // FIFO named *.mcap is refused, not waited on.
    let opened = match crate::input_file::open(path, Kind::Recording, "recordings") {
        Ok(o) => o,
        Err(e) => match e.problem {
            Problem::Open(source) | Problem::Read(source) => return Err(io(source)),
            _ => return Err(bad(e.reason())),
        },
    };
    let size = opened.len();
    let mut file = opened.into_file();
    let magic = MAGIC.len() as u64;
    if size < 2 * magic {
        return Err(bad(format!("{size} bytes: too short for an MCAP file")));
    }
    let (head, tail) = (
        read_at(&file, size, 0, magic).map_err(bad)?,
        read_at(&file, size, size - magic, magic).map_err(bad)?,
    );
    if head != MAGIC || tail != MAGIC {
        return Err(bad(
            "not a finished MCAP recording (no MCAP magic at its start and end; a killed run's .part needs `bench recover`)".into(),
        ));
    }
    // The summary section, as mcap's own `Summary::read` reads it, from
    // the file instead of a buffer of it.
    let summary = {
        use mcap::sans_io::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
        use std::io::{Read, Seek};
        let mut reader =
            SummaryReader::new_with_options(SummaryReaderOptions::default().with_file_size(size));
        while let Some(event) = reader.next_event() {
            match event.map_err(|e| bad(format!("its summary section: {e}")))? {
                SummaryReadEvent::ReadRequest(n) => {
                    let read = file.read(reader.insert(n)).map_err(io)?;
                    reader.notify_read(read);
                }
                SummaryReadEvent::SeekRequest(to) => {
                    let at = file.seek(to).map_err(io)?;
                    reader.notify_seeked(at);
                }
            }
        }
        reader.finish().ok_or_else(|| {
            bad("no summary section (not finished by bench; `bench recover` makes one)".into())
        })?
    };

    let mut metadata: BTreeMap<String, BTreeMap<String, String>> = BTreeMap::new();
    for index in &summary.metadata_indexes {
        if index.name != "bench.run" && index.name != "bench.config" {
            continue;
        }
        let buf = read_at(&file, size, index.offset, index.length).map_err(bad)?;
        let local = mcap::records::MetadataIndex {
            offset: 0,
            ..index.clone()
        };
        let m = mcap::read::metadata(&buf, &local)
            .map_err(|e| bad(format!("metadata {}: {e}", index.name)))?;
        metadata.insert(m.name, m.metadata);
    }
    let run = metadata
        .get("bench.run")
        .ok_or_else(|| bad("no bench.run metadata: not a recording of bench".into()))?;

    // The messages of the channels a row reads, from the chunks that hold
    // any, in file order.
    let wanted: BTreeMap<u16, &str> = summary
        .channels
        .iter()
        .filter_map(|(id, c)| TOPICS.iter().find(|t| **t == c.topic).map(|t| (*id, *t)))
        .collect();
    let mut messages: BTreeMap<&str, Vec<Json>> = BTreeMap::new();
    let mut chunks: Vec<&mcap::records::ChunkIndex> = summary
        .chunk_indexes
        .iter()
        .filter(|c| {
            // Without message indexes every chunk is read.
            c.message_index_offsets.is_empty()
                || c.message_index_offsets
                    .keys()
                    .any(|id| wanted.contains_key(id))
        })
        .collect();
    chunks.sort_by_key(|c| c.chunk_start_offset);
    for chunk in chunks {
        let at = chunk.chunk_start_offset;
        let damaged = |e: mcap::McapError| bad(format!("the chunk at byte {at}: {e}"));
        let buf = read_at(&file, size, at, chunk.chunk_length).map_err(bad)?;
        let local = mcap::records::ChunkIndex {
            chunk_start_offset: 0,
            ..chunk.clone()
        };
        for m in summary.stream_chunk(&buf, &local).map_err(damaged)? {
            let m = m.map_err(damaged)?;
            let Some(topic) = wanted.get(&m.channel.id) else {
                continue;
            };
            if m.channel.message_encoding != "json" {
                continue;
            }
            if let Ok(v) = serde_json::from_slice::<Json>(&m.data) {
                messages.entry(topic).or_default().push(v);
            }
        }
    }

    let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    Ok(row_of(
        run,
        metadata.get("bench.config"),
        &messages,
        abs.display().to_string(),
    ))
}

/// The row of one recording's metadata and messages (by topic).
fn row_of(
    run: &BTreeMap<String, String>,
    config: Option<&BTreeMap<String, String>>,
    messages: &BTreeMap<&str, Vec<Json>>,
    recording: String,
) -> CatalogueRow {
    let text = |k: &str| run.get(k).filter(|s| !s.is_empty()).cloned();
    let real = |k: &str| run.get(k).and_then(|s| s.parse::<f64>().ok());
    let on = |topic: &str| messages.get(topic).map_or(&[][..], Vec::as_slice);
    let mut row = CatalogueRow {
        start_utc_us: run
            .get("start_time_unix_ns")
            .and_then(|s| s.parse::<u64>().ok())
            .and_then(|ns| i64::try_from(ns / 1_000).ok()),
        host: text("host"),
        config_sha256: text("config_sha256")
            .or_else(|| config.and_then(|c| c.get("sha256").cloned())),
        bench_version: text("version"),
        job_kind: text("command"),
        backend: text("backend"),
        pacing: text("mode"),
        rate_hz: real("rate_hz"),
        seed: run.get("seed").and_then(|s| s.parse::<u64>().ok()),
        recording: Some(recording),
        ..CatalogueRow::default()
    };

    // The bench: the config's name and its plant's operating point.
    if let Some(c) = config {
        row.bench_name = c.get("path").map(|p| bench_name(p));
        if let Some(plant) = c
            .get("toml")
            .and_then(|t| t.parse::<toml::Table>().ok())
            .and_then(|t| t.get("plant").and_then(|p| p.as_table()).cloned())
        {
            let number = |v: Option<&toml::Value>| {
                v.and_then(|v| v.as_float().or_else(|| v.as_integer().map(|i| i as f64)))
            };
            row.operating_point_m = number(plant.get("operating_point_m"));
            row.mass_asymmetry = number(plant.get("mass_asymmetry"));
            let length_m = number(
                plant
                    .get("beam")
                    .and_then(|b| b.as_table())
                    .and_then(|b| b.get("length_m")),
            );
            row.operating_point_fraction_of_l = row
                .operating_point_m
                .zip(length_m)
                .and_then(|(y, l)| finite(y / l));
        }
    }

    // How it ended: the events first, then the job's own summary.
    // Read as the loop wrote them (`EventRecord`); a message that is not
    // one (a damaged payload) says nothing about how the run ended.
    let events: Vec<EventRecord> = on(TOPIC_EVENT)
        .iter()
        .filter_map(|e| EventRecord::deserialize(e).ok())
        .collect();
    let fault = events.iter().find(|e| e.kind == EventKind::Fault);
    let interrupted = events.iter().any(|e| e.kind == EventKind::Interrupted);
    let chirp = on(TOPIC_CHIRP_SUMMARY).last();
    let control = on(TOPIC_CONTROL_SUMMARY).last();
    let outcome = if let Some(e) = fault {
        row.fault_kind = e.fault.map(|f| f.as_str().to_string());
        Outcome::Fault
    } else if interrupted {
        Outcome::Stopped
    } else if chirp.is_some() || control.is_some() {
        Outcome::Ok
    } else {
        Outcome::Error
    };
    row.outcome = Some(outcome.as_str().to_string());
    // Unknown (null) when the loop never stopped: a killed run's recording
    // recovered by `bench recover`.
    row.duration_s = events
        .iter()
        .rev()
        .find(|e| e.kind == EventKind::LoopStopped)
        .and_then(|e| finite(e.t_s));

    if let Some(s) = chirp {
        chirp_results(&mut row, s);
    }
    if let Some(check) = on(TOPIC_LOOP_CHECK).last() {
        loop_check_results(&mut row, check);
    }
    if let Some(m) = on(TOPIC_STEP_METRICS).last() {
        step_results(&mut row, m);
    }
    if let Some(s) = control {
        row.verify_flagged = at(s, control_field::VERIFY_FLAGGED).and_then(Json::as_bool);
    }
    row
}

/// The fields a row reads in `/sysid/summary` (`bench.ChirpSummary`).
mod chirp_field {
    pub const PEAK_POSITION_M: &str = "/peak_position_m";
    pub const CMP_CNMP: &str = "/cmp_cnmp";
    pub const MODEL_CMP_CNMP: &str = "/model/cmp_cnmp";
    pub const FIT: &str = "/fit";
    pub const FIT_MODES: &str = "/fit/modes";
    pub const MODE_FREQUENCY_HZ: &str = "/fit/modes/*/frequency_hz";
    pub const MODE_DAMPING_RATIO: &str = "/fit/modes/*/damping_ratio";
    pub const MODE_LABEL: &str = "/fit/modes/*/label";
    pub const FIT_QUALITY: &str = "/fit/quality";
    pub const FIT_CHECKED: &str = "/fit/quality/checked";
    pub const FIT_FLAGS: &str = "/fit/quality/flags";
}

/// The fields a row reads in `/control/summary` (`bench.ControlSummary`).
mod control_field {
    pub const VERIFY_FLAGGED: &str = "/verify/result/flagged";
}

/// The fields a row reads in `/control/loop_check` (`bench.LoopCheck`).
mod check_field {
    pub const CONTROLLER: &str = "/controller";
    pub const FAILURES: &str = "/failures";
    pub const CROSSOVERS_RAD_S: &str = "/model/crossovers_rad_s";
    pub const PHASE_MARGIN_DEG: &str = "/model/phase_margin_deg";
    pub const GAIN_MARGIN_DB: &str = "/model/gain_margin_db";
    pub const SENSITIVITY_PEAK: &str = "/model/sensitivity_peak";
}

/// The fields a row reads in `/control/metrics` (`bench.StepMetrics`).
mod step_field {
    pub const STEP_M: &str = "/step_m";
    pub const RISE_TIME_S: &str = "/rise_time_s";
    pub const SETTLING_TIME_S: &str = "/settling_time_s";
    pub const OVERSHOOT_PCT: &str = "/overshoot_pct";
    pub const STEADY_STATE_ERROR_STD_NM: &str = "/steady_state_error_std_nm";
    pub const PEAK_COMMAND_A: &str = "/peak_command_a";
}

/// What a row reads of one job's result channel: its topic, the name of
/// the schema its writer records (the writing type's JSON Schema,
/// `bench.<Type>`), and every field read, as a JSON pointer (RFC 6901)
/// into a message, an array's elements written `*`.
///
/// The catalogue sits below the jobs (each run appends its row), so it
/// cannot name their result types; it reads their JSON field by field,
/// which keeps a NaN written as null, or a field an older version did not
/// write, one unknown column rather than a lost row. These are all the
/// fields it reads, and `schemas::recorded_messages_match_their_channel_schemas`
/// finds each in the schema the writer records, so a field renamed or
/// removed on the writing side fails that test instead of emptying a
/// column.
#[derive(Debug, Clone, Copy)]
pub struct ResultReads {
    /// The channel.
    pub topic: &'static str,
    /// Its schema's name, as recorded.
    pub schema: &'static str,
    /// The fields read (JSON pointers, `*` for every element).
    pub fields: &'static [&'static str],
}

/// Every field a row reads of the jobs' result channels.
pub const RESULT_READS: [ResultReads; 4] = {
    use check_field as k;
    use chirp_field as c;
    use step_field as m;
    [
        ResultReads {
            topic: TOPIC_CHIRP_SUMMARY,
            schema: "bench.ChirpSummary",
            fields: &[
                c::PEAK_POSITION_M,
                c::CMP_CNMP,
                c::MODEL_CMP_CNMP,
                c::FIT,
                c::FIT_MODES,
                c::MODE_FREQUENCY_HZ,
                c::MODE_DAMPING_RATIO,
                c::MODE_LABEL,
                c::FIT_QUALITY,
                c::FIT_CHECKED,
                c::FIT_FLAGS,
            ],
        },
        ResultReads {
            topic: TOPIC_CONTROL_SUMMARY,
            schema: "bench.ControlSummary",
            fields: &[control_field::VERIFY_FLAGGED],
        },
        ResultReads {
            topic: TOPIC_LOOP_CHECK,
            schema: "bench.LoopCheck",
            fields: &[
                k::CONTROLLER,
                k::FAILURES,
                k::CROSSOVERS_RAD_S,
                k::PHASE_MARGIN_DEG,
                k::GAIN_MARGIN_DB,
                k::SENSITIVITY_PEAK,
            ],
        },
        ResultReads {
            topic: TOPIC_STEP_METRICS,
            schema: "bench.StepMetrics",
            fields: &[
                m::STEP_M,
                m::RISE_TIME_S,
                m::SETTLING_TIME_S,
                m::OVERSHOOT_PCT,
                m::STEADY_STATE_ERROR_STD_NM,
                m::PEAK_COMMAND_A,
            ],
        },
    ]
};

/// The value at JSON `pointer` in `v`, `None` when absent or null.
fn at<'a>(v: &'a Json, pointer: &str) -> Option<&'a Json> {
    v.pointer(pointer).filter(|x| !x.is_null())
}

/// The number at `pointer` in `v`, `None` when absent, null or not finite.
fn num(v: &Json, pointer: &str) -> Option<f64> {
    at(v, pointer).and_then(Json::as_f64).and_then(finite)
}

/// An element's part of `ARRAY/*/FIELD`: `/FIELD`.
fn in_element(pointer: &'static str) -> &'static str {
    pointer.split_once("/*").map_or(pointer, |(_, field)| field)
}

/// The chirp's headline results: the fit's modes, the pair, the verdicts.
fn chirp_results(row: &mut CatalogueRow, s: &Json) {
    use chirp_field as c;
    row.peak_position_m = num(s, c::PEAK_POSITION_M);
    row.verdict_cmp_cnmp = at(s, c::CMP_CNMP).and_then(Json::as_bool);
    row.model_cmp_cnmp = at(s, c::MODEL_CMP_CNMP).and_then(Json::as_bool);
    if at(s, c::FIT).is_none() {
        return;
    }
    let mut modes: Vec<&Json> = at(s, c::FIT_MODES)
        .and_then(Json::as_array)
        .map(|m| m.iter().collect())
        .unwrap_or_default();
    let frequency = in_element(c::MODE_FREQUENCY_HZ);
    modes.sort_by(|a, b| {
        let f = |m: &Json| num(m, frequency).unwrap_or(f64::INFINITY);
        f(a).total_cmp(&f(b))
    });
    row.fit_modes = Some(modes.len() as i64);
    for (i, m) in modes.iter().take(MODE_COLUMNS).enumerate() {
        row.mode_frequency_hz[i] = num(m, frequency);
        row.mode_damping_ratio[i] = num(m, in_element(c::MODE_DAMPING_RATIO));
    }
    let labelled = |label: &str| {
        modes
            .iter()
            .find(|m| at(m, in_element(c::MODE_LABEL)).and_then(Json::as_str) == Some(label))
            .and_then(|m| num(m, frequency))
    };
    row.pair_u_frequency_hz = labelled("u");
    row.pair_v_frequency_hz = labelled("v");
    row.fit_trusted = s.pointer(c::FIT_QUALITY).map(|_| {
        at(s, c::FIT_CHECKED).and_then(Json::as_bool) == Some(true)
            && at(s, c::FIT_FLAGS)
                .and_then(Json::as_array)
                .is_some_and(Vec::is_empty)
    });
}

/// The loop check's margins (the model with the amplifier: what runs).
fn loop_check_results(row: &mut CatalogueRow, c: &Json) {
    use check_field as k;
    row.controller = at(c, k::CONTROLLER)
        .and_then(Json::as_str)
        .map(str::to_string);
    row.loop_check_passed = at(c, k::FAILURES)
        .and_then(Json::as_array)
        .map(Vec::is_empty);
    row.crossover_rad_s = at(c, k::CROSSOVERS_RAD_S)
        .and_then(Json::as_array)
        .and_then(|a| a.first())
        .and_then(Json::as_f64)
        .and_then(finite);
    row.phase_margin_deg = num(c, k::PHASE_MARGIN_DEG);
    row.gain_margin_db = num(c, k::GAIN_MARGIN_DB);
    row.modulus_margin = num(c, k::SENSITIVITY_PEAK).and_then(|s| finite(1.0 / s));
}

/// The step's figures.
fn step_results(row: &mut CatalogueRow, m: &Json) {
    use step_field as f;
    row.step_m = num(m, f::STEP_M);
    row.rise_time_s = num(m, f::RISE_TIME_S);
    row.settling_time_s = num(m, f::SETTLING_TIME_S);
    row.overshoot_pct = num(m, f::OVERSHOOT_PCT);
    row.steady_state_error_std_m = num(m, f::STEADY_STATE_ERROR_STD_NM).map(|nm| nm * 1e-9);
    row.peak_command_a = num(m, f::PEAK_COMMAND_A);
}

/// The bench's name from the config's recorded path: the file's stem
/// (`bench-config/sr4dof-ch5.toml` → `sr4dof-ch5`); the built-in bench,
/// recorded as `built-in (sr4dof-ch5)`, is the bench it copies.
fn bench_name(path: &str) -> String {
    if let Some(inner) = path
        .strip_prefix("built-in (")
        .and_then(|s| s.strip_suffix(')'))
    {
        return inner.to_string();
    }
    Path::new(path)
        .file_stem()
        .map_or_else(|| path.to_string(), |s| s.to_string_lossy().into_owned())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::topics::{FaultKind, SupervisorState};
    use serde_json::json;

    fn run_meta() -> BTreeMap<String, String> {
        [
            ("command", "chirp"),
            ("seed", "18446744073709551615"),
            ("start_time_unix_ns", "1795000000123456789"),
            ("rate_hz", "5000"),
            ("host", "lab-1"),
            ("config_sha256", "ab"),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
    }

    #[test]
    fn the_bench_name_is_the_config_files_stem() {
        assert_eq!(bench_name("bench-config/sr4dof-ch2.toml"), "sr4dof-ch2");
        assert_eq!(bench_name("built-in (sr4dof-ch5)"), "sr4dof-ch5");
        assert_eq!(bench_name("/etc/bench/lab"), "lab");
    }

    /// A `/bench/event` message as the loop writes it.
    fn event(kind: EventKind, t_s: f64, fault: Option<FaultKind>) -> Json {
        serde_json::to_value(EventRecord {
            tick: (t_s * 1e4) as u64,
            t_s,
            kind,
            state: SupervisorState::Disabled,
            fault,
            value: f64::NAN,
        })
        .unwrap()
    }

    #[test]
    fn a_fault_event_makes_a_fault_row_whatever_else_is_recorded() {
        let mut m: BTreeMap<&str, Vec<Json>> = BTreeMap::new();
        m.insert(
            TOPIC_EVENT,
            vec![
                event(EventKind::LoopStarted, 0.0, None),
                event(EventKind::Fault, 0.25, Some(FaultKind::PositionLimit)),
                event(EventKind::Fault, 0.3, Some(FaultKind::I2t)),
                event(EventKind::LoopStopped, 0.3002, None),
            ],
        );
        let row = row_of(&run_meta(), None, &m, "/r/x.mcap".into());
        assert_eq!(row.outcome.as_deref(), Some("fault"));
        assert_eq!(row.fault_kind.as_deref(), Some("position_limit"));
        assert_eq!(row.duration_s, Some(0.3002));
        assert_eq!(row.seed, Some(u64::MAX));
        assert_eq!(row.start_utc_us, Some(1_795_000_000_123_456));
    }

    #[test]
    fn without_a_summary_or_a_fault_a_run_is_an_error_and_interrupted_is_stopped() {
        let mut m: BTreeMap<&str, Vec<Json>> = BTreeMap::new();
        // A killed run, recovered: it never stopped its loop.
        m.insert(TOPIC_EVENT, vec![event(EventKind::JobStarted, 0.0, None)]);
        let row = row_of(&run_meta(), None, &m, String::new());
        assert_eq!(row.outcome.as_deref(), Some("error"));
        assert_eq!(row.duration_s, None);
        m.get_mut(TOPIC_EVENT)
            .unwrap()
            .push(event(EventKind::LoopStopped, 1.0, None));
        let row = row_of(&run_meta(), None, &m, String::new());
        assert_eq!(row.outcome.as_deref(), Some("error"));
        assert_eq!(row.duration_s, Some(1.0));
        m.get_mut(TOPIC_EVENT)
            .unwrap()
            .insert(0, event(EventKind::Interrupted, 0.5, None));
        let row = row_of(&run_meta(), None, &m, String::new());
        assert_eq!(row.outcome.as_deref(), Some("stopped"));
        assert_eq!(row.fault_kind, None);
        // A damaged event (not an event record) is no fault.
        m.get_mut(TOPIC_EVENT)
            .unwrap()
            .push(json!({"kind": "fault", "t_s": 0.7}));
        let row = row_of(&run_meta(), None, &m, String::new());
        assert_eq!(row.outcome.as_deref(), Some("stopped"));
    }

    #[test]
    fn modes_are_taken_by_frequency_and_the_pair_by_label() {
        let mut m: BTreeMap<&str, Vec<Json>> = BTreeMap::new();
        m.insert(
            TOPIC_CHIRP_SUMMARY,
            vec![json!({
                "cmp_cnmp": null,
                "model": {"cmp_cnmp": true},
                "fit": {
                    "modes": [
                        {"label": "v", "frequency_hz": 84.0, "damping_ratio": 0.004},
                        {"label": "R", "frequency_hz": 29.0, "damping_ratio": 0.009},
                        {"label": "u", "frequency_hz": 81.0, "damping_ratio": null},
                    ],
                    "quality": {"checked": true, "flags": ["split mode"]}
                }
            })],
        );
        let row = row_of(&run_meta(), None, &m, String::new());
        assert_eq!(row.outcome.as_deref(), Some("ok"));
        assert_eq!(row.fit_modes, Some(3));
        assert_eq!(
            row.mode_frequency_hz,
            [Some(29.0), Some(81.0), Some(84.0), None]
        );
        assert_eq!(
            row.mode_damping_ratio,
            [Some(0.009), None, Some(0.004), None]
        );
        assert_eq!(row.pair_u_frequency_hz, Some(81.0));
        assert_eq!(row.pair_v_frequency_hz, Some(84.0));
        assert_eq!(row.fit_trusted, Some(false));
        assert_eq!(row.verdict_cmp_cnmp, None);
        assert_eq!(row.model_cmp_cnmp, Some(true));
    }

    #[test]
    fn the_operating_point_comes_from_the_recorded_config() {
        let config: BTreeMap<String, String> = [
            ("path".to_string(), "bench-config/sr4dof-ch5.toml".to_string()),
            (
                "toml".to_string(),
                "[plant]\noperating_point_m = 0.0038\nmass_asymmetry = 0.1\nbeam = { length_m = 0.0475 }\n".to_string(),
            ),
        ]
        .into_iter()
        .collect();
        let row = row_of(&run_meta(), Some(&config), &BTreeMap::new(), String::new());
        assert_eq!(row.bench_name.as_deref(), Some("sr4dof-ch5"));
        assert_eq!(row.operating_point_m, Some(0.0038));
        assert_eq!(row.mass_asymmetry, Some(0.1));
        assert!((row.operating_point_fraction_of_l.unwrap() - 0.08).abs() < 1e-12);
    }
}
