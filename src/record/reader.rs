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
    /// Every intact top-level metadata record (`bench.config`,
    /// `bench.run`), in file order.
    pub metadata: Vec<mcap::records::Metadata>,
}

impl TolerantRead {
    /// The topics the messages are on, sorted, each once.
    pub fn topics(&self) -> Vec<&str> {
        let mut topics: Vec<&str> = self
            .messages
            .iter()
            .map(|m| m.channel.topic.as_str())
            .collect();
        topics.sort();
        topics.dedup();
        topics
    }

    /// The value of `key` in the first metadata record named `name`
    /// (`("bench.config", "toml")`: the run's resolved config).
    pub fn metadata_entry(&self, name: &str, key: &str) -> Option<&str> {
        self.metadata
            .iter()
            .find(|m| m.name == name)
            .and_then(|m| m.metadata.get(key))
            .map(String::as_str)
    }
}

/// Reads every message of a possibly cut or damaged MCAP (e.g. the `.part`
/// file left by a killed run) with [`super::salvage::salvage`]: every
/// message of every intact chunk, the chunks after a damaged one included.
pub fn read_messages_tolerant(bytes: &[u8]) -> TolerantRead {
    match super::salvage::salvage(bytes) {
        Ok(s) => TolerantRead {
            error: s.first_problem(),
            messages: s.messages,
            metadata: s.metadata,
        },
        Err(e) => TolerantRead {
            messages: Vec::new(),
            error: Some(e),
            metadata: Vec::new(),
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
