//! Reading recordings back, also the `.part` file of a killed run.

use crate::record::topics::SampleRecord;
use crate::record::{log_time_ns, TOPIC_SAMPLE};

/// What a tolerant read of a (possibly cut or damaged) recording returned.
#[derive(Debug)]
pub struct TolerantRead {
    /// Messages of every intact chunk, in file order (a damaged chunk is
    /// dropped whole, the intact chunks after it are kept: see
    /// [`super::salvage`]).
    pub messages: Vec<mcap::Message<'static>>,
    /// The first thing that was not read, in words (a dropped chunk, the
    /// chunk cut by a kill, or input that is no MCAP); `None` if the file
    /// was read to its end.
    pub error: Option<String>,
}

/// Reads every message of a possibly cut or damaged MCAP (e.g. the `.part`
/// file left by a killed run) with [`super::salvage::salvage`]: every
/// message of every intact chunk, the chunks after a damaged one included.
pub fn read_messages_tolerant(bytes: &[u8]) -> TolerantRead {
    match super::salvage::salvage(bytes) {
        Ok(s) => TolerantRead {
            error: s.first_problem(),
            messages: s.messages,
        },
        Err(e) => TolerantRead {
            messages: Vec::new(),
            error: Some(e),
        },
    }
}

/// Decodes a `/bench/sample` JSON payload back into a [`SampleRecord`]
/// (`null` → `NaN`). `None` if it does not parse.
pub fn decode_sample(data: &[u8]) -> Option<SampleRecord> {
    serde_json::from_slice(data).ok()
}

/// The ticks of one `/bench/sample` message with their log times (ns, as
/// recorded: the block's log time plus each tick's loop time since the
/// block's first): a protobuf `bench.SampleBlock` gives its ticks, a JSON
/// `bench.Sample` (recordings made before the blocks) one tick.
///
/// # Errors
/// Why the payload is neither (the encoding and the decoder's reason).
pub fn decode_samples(m: &mcap::Message<'_>) -> Result<Vec<(u64, SampleRecord)>, String> {
    match m.channel.message_encoding.as_str() {
        "protobuf" => {
            let records = crate::record::proto::decode_block(&m.data)?;
            let t0 = records.first().map_or(0, |r| log_time_ns(r.t_s));
            let origin = m.log_time.saturating_sub(t0);
            Ok(records
                .into_iter()
                .map(|r| (origin.saturating_add(log_time_ns(r.t_s)), r))
                .collect())
        }
        "json" => decode_sample(&m.data)
            .map(|r| vec![(m.log_time, r)])
            .ok_or_else(|| "not a bench.Sample JSON message".to_string()),
        other => Err(format!("unknown message encoding {other:?}")),
    }
}

/// The `/bench/sample` records of a possibly truncated recording (see
/// [`read_messages_tolerant`]), decoded back into [`SampleRecord`]s in file
/// order (JSON `null` → `NaN`), from the protobuf blocks or the JSON
/// messages of older recordings. Messages that fail to decode are skipped.
pub fn read_samples_tolerant(bytes: &[u8]) -> Vec<SampleRecord> {
    read_messages_tolerant(bytes)
        .messages
        .iter()
        .filter(|m| m.channel.topic == TOPIC_SAMPLE)
        .filter_map(|m| decode_samples(m).ok())
        .flatten()
        .map(|(_, r)| r)
        .collect()
}

/// The FRF and the bench config a `bench chirp` recording holds.
#[derive(Debug, Clone)]
pub struct RecordedFrf {
    /// `/sysid/frf` (the last one if several).
    pub frf: crate::ident::frf::Frf,
    /// The `toml` entry of the `bench.config` metadata record, if present.
    pub config_toml: Option<String>,
}

/// Reads the `/sysid/frf` message and the `bench.config` metadata of the
/// recording in `bytes` (complete, or the `.part` of a killed run).
///
/// # Errors
/// The reason: not a readable MCAP, no `/sysid/frf` channel (with the
/// topics it has), or a `/sysid/frf` payload that is not an FRF (naming
/// the field).
pub fn read_frf(bytes: &[u8]) -> Result<RecordedFrf, String> {
    #[derive(serde::Deserialize)]
    struct Payload {
        frequency_hz: Vec<f64>,
        magnitude_m_per_a: Vec<f64>,
        phase_deg: Vec<f64>,
        coherence: Vec<f64>,
    }
    let read = read_messages_tolerant(bytes);
    if read.messages.is_empty() {
        return Err(match read.error {
            Some(e) => format!("not a readable MCAP recording: {e}"),
            None => "no messages: an empty recording".into(),
        });
    }
    let Some(msg) = read
        .messages
        .iter()
        .rev()
        .find(|m| m.channel.topic == crate::record::TOPIC_FRF)
    else {
        let mut topics: Vec<&str> = read
            .messages
            .iter()
            .map(|m| m.channel.topic.as_str())
            .collect();
        topics.sort();
        topics.dedup();
        return Err(format!(
            "no {} channel (a bench chirp recording has one; this one has {})",
            crate::record::TOPIC_FRF,
            topics.join(", ")
        ));
    };
    let p: Payload = serde_json::from_slice(&msg.data).map_err(|e| {
        format!(
            "{}: the payload is not an FRF: {e}",
            crate::record::TOPIC_FRF
        )
    })?;
    let n = p.frequency_hz.len();
    for (name, len) in [
        ("magnitude_m_per_a", p.magnitude_m_per_a.len()),
        ("phase_deg", p.phase_deg.len()),
        ("coherence", p.coherence.len()),
    ] {
        if len != n {
            return Err(format!(
                "{}: {name} has {len} values for {n} frequencies",
                crate::record::TOPIC_FRF
            ));
        }
    }
    let mut frf = crate::ident::frf::Frf {
        frequency_hz: Vec::with_capacity(n),
        magnitude_m_per_a: Vec::with_capacity(n),
        phase_deg: Vec::with_capacity(n),
        coherence: Vec::with_capacity(n),
    };
    for k in 0..n {
        frf.push_checked([
            p.frequency_hz[k],
            p.magnitude_m_per_a[k],
            p.phase_deg[k],
            p.coherence[k],
        ])
        .map_err(|e| format!("{}: point {}: {e}", crate::record::TOPIC_FRF, k + 1))?;
    }
    if n < crate::ident::frf::MIN_CSV_POINTS {
        return Err(format!(
            "{}: {n} points; an FRF needs at least {}",
            crate::record::TOPIC_FRF,
            crate::ident::frf::MIN_CSV_POINTS
        ));
    }
    let config_toml = mcap::read::LinearReader::new_with_options(
        bytes,
        mcap::read::Options::IgnoreEndMagic.into(),
    )
    .ok()
    .and_then(|r| {
        r.filter_map(Result::ok).find_map(|rec| match rec {
            mcap::records::Record::Metadata(m) if m.name == "bench.config" => {
                m.metadata.get("toml").cloned()
            }
            _ => None,
        })
    });
    Ok(RecordedFrf { frf, config_toml })
}
