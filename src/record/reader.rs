//! Reading recordings back, also the `.part` file of a killed run.

use crate::record::topics::SampleRecord;
use crate::record::TOPIC_SAMPLE;

/// What a tolerant read of a (possibly truncated) recording returned.
#[derive(Debug)]
pub struct TolerantRead {
    /// Messages read, in file order, up to the first error.
    pub messages: Vec<mcap::Message<'static>>,
    /// The error that stopped reading (e.g. unexpected end of file in a chunk
    /// cut by a kill), `None` if the data ended cleanly. Note: the mcap
    /// reader also reports a clean end when the file was cut exactly after a
    /// chunk's 9-byte opcode+length prefix, so `None` does not prove that the
    /// recording was not killed — use the `.part` name / summary for that.
    pub error: Option<mcap::McapError>,
}

/// Reads every message of a possibly truncated MCAP (e.g. the `.part` file
/// left by a killed run): linear read with
/// [`mcap::read::Options::IgnoreEndMagic`], keeping messages until the first
/// error. All messages of chunks that were completely written are returned.
pub fn read_messages_tolerant(bytes: &[u8]) -> TolerantRead {
    let mut messages = Vec::new();
    let stream = match mcap::MessageStream::new_with_options(
        bytes,
        mcap::read::Options::IgnoreEndMagic.into(),
    ) {
        Ok(s) => s,
        Err(e) => {
            return TolerantRead {
                messages,
                error: Some(e),
            }
        }
    };
    for m in stream {
        match m {
            Ok(m) => messages.push(m),
            Err(e) => {
                return TolerantRead {
                    messages,
                    error: Some(e),
                }
            }
        }
    }
    TolerantRead {
        messages,
        error: None,
    }
}

/// Decodes a `/bench/sample` JSON payload back into a [`SampleRecord`]
/// (`null` → `NaN`). `None` if it does not parse.
pub fn decode_sample(data: &[u8]) -> Option<SampleRecord> {
    serde_json::from_slice(data).ok()
}

/// The `/bench/sample` records of a possibly truncated recording (see
/// [`read_messages_tolerant`]), decoded back into [`SampleRecord`]s in file
/// order (`null` → `NaN`). Messages that fail to decode are skipped.
pub fn read_samples_tolerant(bytes: &[u8]) -> Vec<SampleRecord> {
    read_messages_tolerant(bytes)
        .messages
        .iter()
        .filter(|m| m.channel.topic == TOPIC_SAMPLE)
        .filter_map(|m| decode_sample(&m.data))
        .collect()
}
