//! Reading a recording that may be cut or damaged, one top-level record at
//! a time, every chunk checked on its own.
//!
//! A chunk is kept only whole: its framing (record length = header +
//! compressed size), its lz4 data, the CRC of its records (MCAP's
//! `uncompressed_crc`, checked before any record is used), the records
//! inside it (only schemas, channels and messages) and its header's log
//! times against its messages must all check out. A damaged chunk is
//! dropped entirely, and reading resumes at the next intact record: after
//! the damaged record when its length still leads there, else at the next
//! chunk that checks out (scanned for byte by byte; an intact chunk's CRC
//! makes a false match a 2⁻³² event) or at the first record before it from
//! which the record lengths lead to it exactly (the damaged chunk's message
//! index, a metadata record). Every intact chunk after the damage is kept.
//!
//! A record that runs past the end of the file with no intact chunk after
//! it is the **cut**: the chunk (or message index) being written when the
//! run was killed. That is the expected end of a `.part` file, not damage.
//! A damaged length in the very last record looks the same and is reported
//! as the cut.
//!
//! A chunk holds the definitions of the channels first used in it; chunk 0
//! of a `bench` recording holds those of every per-tick channel. When a
//! chunk with definitions is damaged, the messages of later chunks on those
//! channels can only be kept with the definitions rebuilt: that is done
//! when the recording was made by this very version of `bench` (the
//! `bench.run` metadata's `version`), whose recorder registers the same
//! channels in the same order (`writer::base_channels`); otherwise
//! those messages are reported lost ([`Salvage::orphaned`]).
//!
//! Pure over a byte slice (no I/O), after mcap's sans-io reader.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

use mcap::records::{op, MessageHeader, Metadata, Record};
use serde::Serialize;

/// Opcode and length prefix of every MCAP record, bytes.
const PREFIX_BYTES: usize = 9;

/// The largest record or decompressed chunk believed, bytes: a damaged
/// length must not make the reader allocate the machine's memory. A chunk
/// of `bench` (50 ms of samples, or the results at the end) holds well
/// under 10 MiB.
const RECORD_LIMIT_BYTES: usize = 256 << 20;

/// What a dropped region of the file held.
///
/// A chunk whose opcode alone was damaged is a chunk here, and dropped
/// like any other damaged chunk.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum RegionKind {
    /// A chunk (its opcode intact, or its body framed as a chunk, or a
    /// message index after it).
    Chunk,
    /// A message index: redundant (every reader rebuilds it from the
    /// messages), nothing is lost with it.
    MessageIndex,
    /// A metadata record (`bench.config`, `bench.run`).
    Metadata,
    /// Bytes that are no record the reader can name.
    Unreadable,
}

impl RegionKind {
    /// The kind in words (`chunk`, `message index`, …).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Chunk => "chunk",
            Self::MessageIndex => "message index",
            Self::Metadata => "metadata",
            Self::Unreadable => "unreadable bytes",
        }
    }
}

/// A damaged region of the file, dropped whole.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Dropped {
    /// What it held.
    pub kind: RegionKind,
    /// The chunk's index, counting every chunk of the file from 0 in file
    /// order, intact or not (chunk 0 of a `bench` recording holds the
    /// channel definitions); for a region that is no chunk, the index the
    /// next chunk has.
    pub chunk_index: u64,
    /// Where the region starts in the file, bytes from the file's start.
    pub offset_bytes: u64,
    /// Its length, bytes (up to where reading resumed).
    pub length_bytes: u64,
    /// Messages lost with it, count: from the message index records after
    /// a chunk when they survived; `None` when unknown.
    pub messages: Option<u64>,
    /// Log times of its messages, ns (first, last): from the chunk's
    /// header when that is plausible (within the log times kept), else
    /// the last message kept before it and the first kept after it
    /// (the lost messages lie between). `None` when unknown.
    pub log_time_ns: Option<(u64, u64)>,
    /// Why it was dropped (e.g. the CRC mismatch, the lz4 error).
    pub reason: String,
}

impl Dropped {
    /// Whether data was lost with it: every kind but a message index.
    pub fn lost(&self) -> bool {
        self.kind != RegionKind::MessageIndex
    }
}

/// The end of a `.part` file: the record being written when the run was
/// killed, incomplete.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Cut {
    /// What it was, when its opcode says (a chunk, a message index, …).
    pub kind: RegionKind,
    /// The chunk's index when it was a chunk (as [`Dropped::chunk_index`]).
    pub chunk_index: u64,
    /// Where it starts, bytes from the file's start.
    pub offset_bytes: u64,
    /// The bytes of it in the file.
    pub length_bytes: u64,
    /// What is missing, in words.
    pub reason: String,
}

/// Messages whose channel definition was lost with a damaged chunk and
/// could not be rebuilt.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize, schemars::JsonSchema)]
pub struct Orphaned {
    /// The MCAP channel id the messages name.
    pub channel_id: u16,
    /// Messages on it dropped, count.
    pub messages: u64,
}

/// What [`salvage`] read.
#[derive(Debug, Default)]
pub struct Salvage {
    /// Every message of every intact chunk, in file order.
    pub messages: Vec<mcap::Message<'static>>,
    /// Every intact top-level metadata record, in file order.
    pub metadata: Vec<Metadata>,
    /// Intact chunks read, count.
    pub chunks: u64,
    /// Damaged regions dropped, in file order.
    pub dropped: Vec<Dropped>,
    /// The incomplete record at the end of the file, if any.
    pub cut: Option<Cut>,
    /// Messages of intact chunks dropped because their channel's definition
    /// was lost and could not be rebuilt, per channel.
    pub orphaned: Vec<Orphaned>,
    /// When channel definitions lost with a damaged chunk were rebuilt:
    /// which, and from what.
    pub rebuilt: Option<String>,
    /// Whether the data section ended with its `DataEnd` record (a finished
    /// recording); else the file ended (a `.part` file).
    pub data_end: bool,
}

impl Salvage {
    /// Whether anything that was written is missing besides the cut: a
    /// dropped chunk, metadata record or unreadable bytes, or messages
    /// whose channel could not be rebuilt. A damaged message index alone
    /// loses nothing.
    pub fn lost(&self) -> bool {
        self.dropped.iter().any(Dropped::lost) || !self.orphaned.is_empty()
    }

    /// The first thing that was not read, in words (a dropped region, else
    /// the cut), `None` when the file was read to its end.
    pub fn first_problem(&self) -> Option<String> {
        let dropped = self.dropped.first().map(|d| {
            format!(
                "{} {} at byte {} dropped: {}",
                d.kind.as_str(),
                d.chunk_index,
                d.offset_bytes,
                d.reason
            )
        });
        dropped.or_else(|| {
            self.cut
                .as_ref()
                .map(|c| format!("cut at byte {}: {}", c.offset_bytes, c.reason))
        })
    }
}

/// A message read, or one on a channel not (yet) defined.
enum Slot {
    Message(mcap::Message<'static>),
    Orphan {
        header: MessageHeader,
        data: Vec<u8>,
    },
}

/// The records of an intact chunk: schemas, channels and messages.
struct CheckedChunk {
    records: Vec<Record<'static>>,
}

/// Reads `bytes` (an MCAP file, complete or the `.part` of a killed run,
/// possibly damaged) as the [module docs](self) say.
///
/// # Errors
/// When `bytes` does not start with the MCAP magic.
pub fn salvage(bytes: &[u8]) -> Result<Salvage, String> {
    if !bytes.starts_with(mcap::MAGIC) {
        return Err("it does not start with the MCAP magic".into());
    }
    let mut r = Reader {
        bytes,
        out: Salvage::default(),
        slots: Vec::new(),
        schemas: HashMap::new(),
        channels: HashMap::new(),
        chunk_index: 0,
        counting: None,
        marks: Vec::new(),
    };
    r.run();
    Ok(r.finish())
}

struct Reader<'b> {
    bytes: &'b [u8],
    out: Salvage,
    slots: Vec<Slot>,
    schemas: HashMap<u16, Arc<mcap::Schema<'static>>>,
    channels: HashMap<u16, Arc<mcap::Channel<'static>>>,
    /// The index the next chunk gets.
    chunk_index: u64,
    /// The dropped chunk whose message index records are being counted.
    counting: Option<usize>,
    /// Per dropped region: its index in `out.dropped` and the number of
    /// messages read before it (where it lies among them).
    marks: Vec<(usize, usize)>,
}

/// What reading one record did.
enum Step {
    Next,
    DataEnd,
}

impl Reader<'_> {
    fn run(&mut self) {
        let bytes = self.bytes;
        let mut p = mcap::MAGIC.len();
        while p < bytes.len() {
            let rest = bytes.len() - p;
            if rest < PREFIX_BYTES {
                self.out.cut = Some(Cut {
                    kind: RegionKind::Unreadable,
                    chunk_index: self.chunk_index,
                    offset_bytes: p as u64,
                    length_bytes: rest as u64,
                    reason: format!("{rest} bytes of a record's 9-byte opcode and length"),
                });
                return;
            }
            let opcode = bytes[p];
            let end = record_end(bytes, p);
            let step = match end {
                Some(end) => self.read_record(opcode, &bytes[p..end], p),
                None => Err(format!(
                    "a record of {} bytes runs past the end of the file ({} bytes left)",
                    record_len(bytes, p),
                    rest - PREFIX_BYTES
                )),
            };
            match step {
                Ok(Step::Next) => p = end.expect("a record read has an end"),
                Ok(Step::DataEnd) => {
                    self.out.data_end = true;
                    return;
                }
                Err(reason) => match next_anchor(bytes, p + 1) {
                    None => match end {
                        None => {
                            self.out.cut = Some(Cut {
                                kind: kind_of_opcode(opcode),
                                chunk_index: self.chunk_index,
                                offset_bytes: p as u64,
                                length_bytes: rest as u64,
                                reason,
                            });
                            return;
                        }
                        Some(end) => {
                            self.drop_region(opcode, p, end, reason);
                            p = end;
                        }
                    },
                    Some(anchor) => {
                        let resume = match end {
                            Some(e) if e <= anchor && chains(bytes, e, anchor) => e,
                            _ => (p + 1..=anchor)
                                .find(|&q| chains(bytes, q, anchor))
                                .expect("the anchor chains to itself"),
                        };
                        self.drop_region(opcode, p, resume, reason);
                        p = resume;
                    }
                },
            }
        }
    }

    /// Reads the whole record `record` (prefix included) at `offset`.
    fn read_record(&mut self, opcode: u8, record: &[u8], offset: usize) -> Result<Step, String> {
        let body = &record[PREFIX_BYTES..];
        let counting = self.counting.take();
        match opcode {
            op::HEADER if offset == mcap::MAGIC.len() => {
                mcap::parse_record(opcode, body).map_err(|e| format!("header: {e}"))?;
            }
            op::CHUNK => {
                let chunk = check_chunk(record, true)?;
                self.take_chunk(chunk);
            }
            op::MESSAGE_INDEX => {
                let n = check_message_index(body)?;
                if let Some(i) = counting {
                    let d = &mut self.out.dropped[i];
                    d.messages = Some(d.messages.unwrap_or(0) + n);
                    self.counting = Some(i);
                }
            }
            op::METADATA => {
                let m = check_metadata(body)?;
                self.out.metadata.push(m);
            }
            op::DATA_END => return Ok(Step::DataEnd),
            other => {
                return Err(format!(
                    "a record with opcode {other:#04x}, which the data section of a recording does not hold here"
                ))
            }
        }
        Ok(Step::Next)
    }

    /// Keeps the schemas, channels and messages of an intact chunk.
    fn take_chunk(&mut self, chunk: CheckedChunk) {
        self.chunk_index += 1;
        self.out.chunks += 1;
        for record in chunk.records {
            match record {
                Record::Schema { header, data } => {
                    self.schemas.insert(
                        header.id,
                        Arc::new(mcap::Schema {
                            id: header.id,
                            name: header.name,
                            encoding: header.encoding,
                            data,
                        }),
                    );
                }
                Record::Channel(c) => {
                    // A channel whose schema was lost stays undefined: its
                    // messages wait for the rebuilt definitions.
                    let schema = match c.schema_id {
                        0 => None,
                        id => match self.schemas.get(&id) {
                            Some(s) => Some(Arc::clone(s)),
                            None => continue,
                        },
                    };
                    self.channels.insert(
                        c.id,
                        Arc::new(mcap::Channel {
                            id: c.id,
                            topic: c.topic,
                            schema,
                            message_encoding: c.message_encoding,
                            metadata: c.metadata,
                        }),
                    );
                }
                Record::Message { header, data } => {
                    self.slots
                        .push(match self.channels.get(&header.channel_id) {
                            Some(ch) => Slot::Message(mcap::Message {
                                channel: Arc::clone(ch),
                                sequence: header.sequence,
                                log_time: header.log_time,
                                publish_time: header.publish_time,
                                data,
                            }),
                            None => Slot::Orphan {
                                header,
                                data: data.into_owned(),
                            },
                        });
                }
                _ => unreachable!("check_chunk keeps schemas, channels and messages only"),
            }
        }
    }

    /// Records the damaged region `[start, end)` whose first byte is
    /// `opcode`.
    fn drop_region(&mut self, opcode: u8, start: usize, end: usize, reason: String) {
        let bytes = self.bytes;
        let followed_by_index =
            end + PREFIX_BYTES <= bytes.len() && bytes[end] == op::MESSAGE_INDEX;
        // A region that frames as a chunk but for its opcode, or that a
        // message index follows, was a chunk whose opcode was damaged.
        let kind = if chunk_header(&bytes[start..end]).is_some() {
            RegionKind::Chunk
        } else {
            match kind_of_opcode(opcode) {
                RegionKind::Unreadable if followed_by_index => RegionKind::Chunk,
                k => k,
            }
        };
        let log_time_ns = if kind == RegionKind::Chunk {
            chunk_header(&bytes[start..end]).map(|h| (h.message_start_time, h.message_end_time))
        } else {
            None
        };
        let reason = if kind == RegionKind::Chunk && opcode != op::CHUNK {
            format!("its opcode is {opcode:#04x}, not a chunk's 0x06 ({reason})")
        } else {
            reason
        };
        let chunk_index = self.chunk_index;
        if kind == RegionKind::Chunk {
            self.chunk_index += 1;
        }
        self.out.dropped.push(Dropped {
            kind,
            chunk_index,
            offset_bytes: start as u64,
            length_bytes: (end - start) as u64,
            messages: None,
            log_time_ns,
            reason,
        });
        self.counting =
            (kind == RegionKind::Chunk && followed_by_index).then_some(self.out.dropped.len() - 1);
        // Where in the messages kept this region lies (for the time span
        // from the neighbours).
        self.marks
            .push((self.out.dropped.len() - 1, self.slots.len()));
    }

    fn finish(mut self) -> Salvage {
        let mut out = std::mem::take(&mut self.out);
        self.time_spans(&mut out);
        // Rebuilt definitions for the messages whose channel was lost.
        let mut fallback = HashMap::new();
        if self.slots.iter().any(|s| matches!(s, Slot::Orphan { .. })) {
            if let Some((channels, note)) = rebuilt_channels(&out.metadata) {
                fallback = channels;
                out.rebuilt = Some(note);
            }
        }
        let mut orphaned: BTreeMap<u16, u64> = BTreeMap::new();
        let mut used_fallback = false;
        for slot in std::mem::take(&mut self.slots) {
            match slot {
                Slot::Message(m) => out.messages.push(m),
                Slot::Orphan { header, data } => match fallback.get(&header.channel_id) {
                    Some(ch) => {
                        used_fallback = true;
                        out.messages.push(mcap::Message {
                            channel: Arc::clone(ch),
                            sequence: header.sequence,
                            log_time: header.log_time,
                            publish_time: header.publish_time,
                            data: data.into(),
                        });
                    }
                    None => *orphaned.entry(header.channel_id).or_default() += 1,
                },
            }
        }
        if !used_fallback {
            out.rebuilt = None;
        }
        out.orphaned = orphaned
            .into_iter()
            .map(|(channel_id, messages)| Orphaned {
                channel_id,
                messages,
            })
            .collect();
        out
    }

    /// Each dropped chunk's log time span: its header's when that lies
    /// within the log times read, else the neighbours' in file order.
    fn time_spans(&self, out: &mut Salvage) {
        let log_time = |s: &Slot| match s {
            Slot::Message(m) => m.log_time,
            Slot::Orphan { header, .. } => header.log_time,
        };
        let lo = self.slots.iter().map(log_time).min();
        let hi = self.slots.iter().map(log_time).max();
        for &(i, at) in &self.marks {
            let d = &mut out.dropped[i];
            let plausible = d.log_time_ns.is_some_and(|(a, b)| {
                a <= b && lo.is_some_and(|lo| a >= lo) && hi.is_some_and(|hi| b <= hi)
            });
            if d.kind != RegionKind::Chunk {
                d.log_time_ns = None;
            } else if !plausible {
                let before = at
                    .checked_sub(1)
                    .and_then(|k| self.slots.get(k))
                    .map(log_time);
                let after = self.slots.get(at).map(log_time);
                d.log_time_ns = before.zip(after).filter(|(a, b)| a <= b);
            }
        }
    }
}

/// The length field of the record at `p` (needs 9 bytes there).
fn record_len(bytes: &[u8], p: usize) -> u64 {
    u64::from_le_bytes(bytes[p + 1..p + PREFIX_BYTES].try_into().expect("8 bytes"))
}

/// The end of the record at `p`, if it lies within `bytes` (and within
/// [`RECORD_LIMIT_BYTES`]).
fn record_end(bytes: &[u8], p: usize) -> Option<usize> {
    let len = usize::try_from(record_len(bytes, p)).ok()?;
    if len > RECORD_LIMIT_BYTES {
        return None;
    }
    let end = p.checked_add(PREFIX_BYTES)?.checked_add(len)?;
    (end <= bytes.len()).then_some(end)
}

/// What a region whose first byte is `opcode` was.
fn kind_of_opcode(opcode: u8) -> RegionKind {
    match opcode {
        op::CHUNK => RegionKind::Chunk,
        op::MESSAGE_INDEX => RegionKind::MessageIndex,
        op::METADATA => RegionKind::Metadata,
        _ => RegionKind::Unreadable,
    }
}

/// The first chunk at or after `from` that checks out, CRC included
/// (a chunk without a CRC is not taken: nothing would tell it from chance).
fn next_anchor(bytes: &[u8], from: usize) -> Option<usize> {
    let mut q = from;
    while q + PREFIX_BYTES <= bytes.len() {
        let at = q + bytes[q..].iter().position(|&b| b == op::CHUNK)?;
        if let Some(end) = (at + PREFIX_BYTES <= bytes.len())
            .then(|| record_end(bytes, at))
            .flatten()
        {
            let record = &bytes[at..end];
            if chunk_header(record).is_some_and(|h| h.uncompressed_crc != 0)
                && check_chunk(record, false).is_ok()
            {
                return Some(at);
            }
        }
        q = at + 1;
    }
    None
}

/// Whether the record lengths from `q` lead exactly to `anchor`, through
/// records a recording's data section holds (chunks, message indexes,
/// metadata).
fn chains(bytes: &[u8], mut q: usize, anchor: usize) -> bool {
    loop {
        if q == anchor {
            return true;
        }
        if q + PREFIX_BYTES > anchor
            || !matches!(bytes[q], op::CHUNK | op::MESSAGE_INDEX | op::METADATA)
        {
            return false;
        }
        match record_end(bytes, q) {
            Some(end) if end <= anchor => q = end,
            _ => return false,
        }
    }
}

/// The header of the chunk record `record` (prefix included), if it parses
/// and its length agrees with its compressed size exactly.
fn chunk_header(record: &[u8]) -> Option<mcap::records::ChunkHeader> {
    let body = record.get(PREFIX_BYTES..)?;
    match mcap::parse_record(op::CHUNK, body) {
        Ok(Record::Chunk { header, data }) => {
            let header_bytes = 8 + 8 + 8 + 4 + 4 + header.compression.len() + 8;
            (header_bytes + data.len() == body.len()).then_some(header)
        }
        _ => None,
    }
}

/// Checks the chunk record `record` (prefix included) whole: its framing,
/// its decompression and the CRC of its records before any is read (mcap's
/// `prevalidate_chunk_crcs`), the records inside (schemas, channels and
/// messages only) and its header's log times (the first and last of its
/// messages; 0 and 0 without messages). `keep`: return the records (else
/// only check).
fn check_chunk(record: &[u8], keep: bool) -> Result<CheckedChunk, String> {
    use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
    let header = chunk_header(record).ok_or_else(|| {
        let body = &record[PREFIX_BYTES..];
        match mcap::parse_record(op::CHUNK, body) {
            Err(e) => format!("its header does not parse: {e}"),
            Ok(_) => "its record length disagrees with its compressed size".to_string(),
        }
    })?;
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_start_magic(true)
            .with_skip_end_magic(true)
            .with_prevalidate_chunk_crcs(true)
            .with_record_length_limit(RECORD_LIMIT_BYTES),
    );
    let mut rest = record;
    let mut records = Vec::new();
    let mut times: Option<(u64, u64)> = None;
    while let Some(event) = reader.next_event() {
        match event.map_err(|e| match e {
            mcap::McapError::BadChunkCrc { saved, calculated } => format!(
                "CRC mismatch: its records hash to {calculated:08x}, its header says {saved:08x}"
            ),
            e => e.to_string(),
        })? {
            LinearReadEvent::ReadRequest(n) => {
                let n = n.min(rest.len());
                reader.insert(n).copy_from_slice(&rest[..n]);
                reader.notify_read(n);
                rest = &rest[n..];
            }
            LinearReadEvent::Record { opcode, data } => {
                let r = mcap::parse_record(opcode, data)
                    .map_err(|e| format!("a record inside does not parse: {e}"))?;
                match &r {
                    Record::Message { header, .. } => {
                        let t = header.log_time;
                        times = Some(times.map_or((t, t), |(a, b)| (a.min(t), b.max(t))));
                    }
                    Record::Schema { .. } | Record::Channel(_) => {}
                    other => {
                        return Err(format!(
                            "it holds a record with opcode {:#04x}",
                            other.opcode()
                        ))
                    }
                }
                if keep {
                    records.push(r.into_owned());
                }
            }
        }
    }
    let (first, last) = times.unwrap_or((0, 0));
    if (header.message_start_time, header.message_end_time) != (first, last) {
        return Err(format!(
            "its header's log times {}..{} ns disagree with its messages' {first}..{last} ns",
            header.message_start_time, header.message_end_time
        ));
    }
    Ok(CheckedChunk { records })
}

/// Checks a message index record's body; its entries, count.
fn check_message_index(body: &[u8]) -> Result<u64, String> {
    match mcap::parse_record(op::MESSAGE_INDEX, body) {
        Ok(Record::MessageIndex(m)) if 2 + 4 + 16 * m.records.len() == body.len() => {
            Ok(m.records.len() as u64)
        }
        Ok(_) => Err("message index: its length disagrees with its entries".into()),
        Err(e) => Err(format!("message index: {e}")),
    }
}

/// Checks a metadata record's body (it parses, and its length is exactly
/// what it holds).
fn check_metadata(body: &[u8]) -> Result<Metadata, String> {
    match mcap::parse_record(op::METADATA, body) {
        Ok(Record::Metadata(m)) => {
            let map: usize = m
                .metadata
                .iter()
                .map(|(k, v)| 4 + k.len() + 4 + v.len())
                .sum();
            if 4 + m.name.len() + 4 + map == body.len() {
                Ok(m)
            } else {
                Err(format!(
                    "metadata {:?}: its length disagrees with what it holds",
                    m.name
                ))
            }
        }
        Ok(_) => Err("metadata: not a metadata record".into()),
        Err(e) => Err(format!("metadata: {e}")),
    }
}

/// The channel definitions `bench` registers when it creates a recording,
/// by MCAP channel id, when the recording was made by this version (the
/// `bench.run` metadata's `version`): they are the ones lost with a damaged
/// chunk 0. With a note saying so.
fn rebuilt_channels(
    metadata: &[Metadata],
) -> Option<(HashMap<u16, Arc<mcap::Channel<'static>>>, String)> {
    let ours = env!("CARGO_PKG_VERSION");
    let version = metadata
        .iter()
        .find(|m| m.name == "bench.run")
        .and_then(|m| m.metadata.get("version"))?;
    if version != ours {
        return None;
    }
    let channels = super::writer::base_channels().ok()?;
    let topics: Vec<&str> = channels.iter().map(|c| c.topic.as_str()).collect();
    let note = format!(
        "the definitions of {} were lost with a damaged chunk and rebuilt from bench {ours}, the version that made the recording",
        topics.join(", ")
    );
    Some((
        channels.into_iter().map(|c| (c.id, Arc::new(c))).collect(),
        note,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::topics::{Record as Tick, SampleRecord, SupervisorState};
    use crate::record::Recorder;

    fn sample(tick: u64) -> SampleRecord {
        let t_s = tick as f64 * 200e-6;
        SampleRecord {
            tick,
            t_s,
            wake_s: t_s,
            current_command_a: 0.1 * (tick as f64).sin(),
            position_m: 1e-6 * tick as f64,
            excitation_a: f64::NAN,
            setpoint_m: f64::NAN,
            state: SupervisorState::Running,
            out_of_range: false,
        }
    }

    /// A `.part` file of `chunks` chunks of samples after chunk 0 (the
    /// channel definitions), with a `bench.run` of `version`; the byte
    /// range of every chunk record, found by walking the records.
    fn part(chunks: u64, version: &str) -> (Vec<u8>, Vec<(usize, usize)>) {
        let dir = tempfile::tempdir().unwrap();
        let mut rec = Recorder::create(&dir.path().join("r.mcap")).unwrap();
        rec.write_metadata(
            "bench.run",
            &BTreeMap::from([("version".to_string(), version.to_string())]),
        )
        .unwrap();
        for c in 0..chunks {
            for t in 0..600 {
                rec.write_record(&Tick::Sample(sample(c * 600 + t)))
                    .unwrap();
            }
            rec.flush_chunk().unwrap();
        }
        let bytes = std::fs::read(rec.part_path()).unwrap();
        drop(rec);
        let mut ranges = Vec::new();
        let mut p = mcap::MAGIC.len();
        while p < bytes.len() {
            let end = record_end(&bytes, p).unwrap();
            if bytes[p] == op::CHUNK {
                ranges.push((p, end));
            }
            p = end;
        }
        (bytes, ranges)
    }

    fn ticks(s: &Salvage) -> Vec<u64> {
        s.messages
            .iter()
            .filter(|m| m.channel.topic == crate::record::TOPIC_SAMPLE)
            .flat_map(|m| crate::record::decode_samples(m).unwrap())
            .map(|(_, r)| r.tick)
            .collect()
    }

    #[test]
    fn an_intact_file_reads_whole() {
        let (bytes, ranges) = part(4, "x");
        let s = salvage(&bytes).unwrap();
        assert_eq!(s.chunks, ranges.len() as u64);
        assert!(s.dropped.is_empty() && s.cut.is_none() && !s.lost());
        assert_eq!(ticks(&s), (0..2400).collect::<Vec<_>>());
        assert_eq!(s.metadata.len(), 1);
    }

    /// Every bit of a chunk's first 120 bytes (header and the start of its
    /// data) and every 97th byte after: that chunk alone is dropped, the
    /// others kept. Or, where the flip does not change what the chunk
    /// decompresses to (lz4 takes a few damaged bytes for the same output,
    /// e.g. a match offset of 0 copying the zeros the buffer already
    /// holds), it is kept whole, its records' CRC intact.
    #[test]
    fn a_flipped_bit_anywhere_in_a_chunk_drops_that_chunk_only() {
        let (bytes, ranges) = part(4, "x");
        let k = 2; // ticks 600..1200
        let (start, end) = ranges[k];
        let want: Vec<u64> = (0..600).chain(1200..2400).collect();
        let positions = (start..start + 120).chain((start + 120..end).step_by(97));
        let mut unchanged = 0;
        for pos in positions {
            for bit in 0..8 {
                let mut b = bytes.clone();
                b[pos] ^= 1 << bit;
                let s = salvage(&b).unwrap();
                let at = format!("byte {} bit {bit}", pos - start);
                if s.dropped.is_empty() {
                    let records = |b: &[u8]| {
                        check_chunk(&b[start..end], true)
                            .unwrap()
                            .records
                            .into_iter()
                            .map(|r| format!("{r:?}"))
                            .collect::<Vec<_>>()
                    };
                    assert_eq!(records(&b), records(&bytes), "{at}");
                    assert_eq!(ticks(&s), (0..2400).collect::<Vec<_>>(), "{at}");
                    unchanged += 1;
                    continue;
                }
                assert_eq!(s.dropped.len(), 1, "{at}: {:?}", s.dropped);
                assert_eq!(s.dropped[0].kind, RegionKind::Chunk, "{at}");
                assert_eq!(s.dropped[0].chunk_index, k as u64, "{at}");
                assert_eq!(s.dropped[0].offset_bytes, start as u64, "{at}");
                assert!(s.lost() && s.cut.is_none(), "{at}");
                assert_eq!(ticks(&s), want, "{at}");
            }
        }
        assert!(unchanged <= 8, "{unchanged} flips left the chunk unchanged");
    }

    /// A cut anywhere in the last chunk: named, not a loss.
    #[test]
    fn a_cut_last_chunk_is_no_loss() {
        let (bytes, ranges) = part(3, "x");
        let (start, end) = ranges[ranges.len() - 1];
        for cut in start + 1..end {
            let s = salvage(&bytes[..cut]).unwrap();
            let c = s.cut.as_ref().unwrap_or_else(|| panic!("cut {cut}"));
            assert_eq!(c.offset_bytes, start as u64);
            assert!(!s.lost() && s.dropped.is_empty(), "cut {cut}");
            assert_eq!(ticks(&s), (0..1200).collect::<Vec<_>>());
        }
    }

    /// Chunk 0 (the channel definitions) damaged: rebuilt when this version
    /// made the recording, else every later message is orphaned.
    #[test]
    fn a_damaged_chunk_0_is_rebuilt_for_this_version_only() {
        let ours = env!("CARGO_PKG_VERSION");
        for (version, rebuilt) in [(ours, true), ("0.0.0-another", false)] {
            let (mut bytes, ranges) = part(2, version);
            bytes[ranges[0].0 + 80] ^= 4;
            let s = salvage(&bytes).unwrap();
            assert_eq!(s.dropped[0].chunk_index, 0);
            assert!(s.lost());
            if rebuilt {
                assert!(s.rebuilt.is_some() && s.orphaned.is_empty());
                assert_eq!(ticks(&s), (0..1200).collect::<Vec<_>>());
            } else {
                assert!(s.rebuilt.is_none() && s.messages.is_empty());
                assert!(!s.orphaned.is_empty());
            }
        }
    }

    /// The rebuilt definitions are the ones a recording holds, ids included.
    #[test]
    fn base_channels_match_a_recording() {
        let (bytes, _) = part(1, "x");
        let s = salvage(&bytes).unwrap();
        let base = super::super::writer::base_channels().unwrap();
        for c in base {
            let m = s.messages.iter().find(|m| m.channel.topic == c.topic);
            if let Some(m) = m {
                assert_eq!(*m.channel, c, "{}", c.topic);
            }
        }
        assert!(s
            .messages
            .iter()
            .any(|m| m.channel.topic == crate::record::TOPIC_SAMPLE));
    }
}
