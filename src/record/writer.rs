//! The MCAP writer: [`Recorder`] (channels, messages, the `.part` rule,
//! chunk flushing) and the writer thread ([`spawn_writer`]) that drains the
//! tick's queue into it. See the [module docs](crate::record) for topics and units.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::marker::PhantomData;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mcap::records::MessageHeader;
use schemars::JsonSchema;
use serde::Serialize;

use crate::error::RecordError;
use crate::outputs::part_path_for;
use crate::record::proto::{
    self, Envelope, EnvelopeBuilder, SampleBlock, BLOCK_TICKS, SCHEMA_ENVELOPE, SCHEMA_SAMPLE_BLOCK,
};
use crate::record::queue::QueueRoom;
use crate::record::schema_of;
use crate::record::topics::{
    EventKind, EventRecord, FaultKind, FoxgloveLog, Record, SupervisorState, TimingRecord,
};
use crate::record::{
    SCHEMA_EVENT, SCHEMA_FRF, SCHEMA_LOG, SCHEMA_TIMING, TOPIC_ENVELOPE, TOPIC_EVENT, TOPIC_FRF,
    TOPIC_LOG, TOPIC_SAMPLE, TOPIC_TIMING,
};

/// When [`spawn_writer`] closes and flushes a chunk: once `wall` of wall
/// time, or `loop_time` of log (loop) time, has passed since the last
/// flush, whichever comes first.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChunkPolicy {
    /// Wall-time deadline: bounds what a killed process loses.
    pub wall: Duration,
    /// Loop-time deadline: bounds a chunk's size (it is built in memory).
    pub loop_time: Duration,
}

impl ChunkPolicy {
    /// Real time: 50 ms of either (the two advance together), so a killed
    /// run loses at most the 50 ms plus what is queued.
    pub const REAL_TIME: Self = Self {
        wall: Duration::from_millis(50),
        loop_time: Duration::from_millis(50),
    };
    /// Virtual time: 50 ms of wall time, as in real time, or 1 s of loop
    /// time (5 000 ticks at 5 kHz, about 200 kB before compression). The
    /// default chirp's loop time runs about 3 000 times faster than the
    /// wall clock: 50 ms of loop time would close a chunk every 250 ticks,
    /// which costs the writer about a quarter more CPU and the file 17 %
    /// more bytes (`cargo bench --bench recorder`).
    pub const VIRTUAL_TIME: Self = Self {
        wall: Duration::from_millis(50),
        loop_time: Duration::from_secs(1),
    };
}

/// The writer looks at the wall clock once per this many records (a few
/// µs of writing): the chunk deadline is met to within that, and the clock
/// read stays off the per-record cost.
const WALL_CHECK_RECORDS: u64 = 32;

/// Size of the buffer between the mcap writer and the file, bytes.
const FILE_BUFFER_BYTES: usize = 64 * 1024;

/// Largest number of records taken from the queue in one batch by the writer
/// thread (slots are released to the producer after each batch).
const MAX_BATCH: usize = 1024;

/// A channel of one [`Recorder`] whose messages are `T` and whose schema
/// was generated from `T` (returned by [`Recorder::add_channel_for`],
/// written with [`Recorder::write`]).
pub struct Channel<T: ?Sized> {
    index: usize,
    message: PhantomData<fn(&T)>,
}

impl<T: ?Sized> Channel<T> {
    fn new(index: usize) -> Self {
        Self {
            index,
            message: PhantomData,
        }
    }
}

// Not derived: the derives would require `T: Clone` etc.
impl<T: ?Sized> Clone for Channel<T> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<T: ?Sized> Copy for Channel<T> {}

impl<T: ?Sized> std::fmt::Debug for Channel<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Channel")
            .field("index", &self.index)
            .field("message", &std::any::type_name::<T>())
            .finish()
    }
}

#[derive(Debug)]
struct ChannelState {
    /// MCAP channel id.
    id: u16,
    /// Sequence number of the next message on this channel.
    next_sequence: u32,
}

/// MCAP recorder (see the [module docs](crate::record) for topics, units, the `.part`
/// rule and chunking).
pub struct Recorder {
    /// `None` only after `finish` / during `drop`.
    writer: Option<mcap::Writer<BufWriter<File>>>,
    final_path: PathBuf,
    part_path: PathBuf,
    /// What the final rename does with an existing file.
    existing: crate::outputs::Existing,
    channels: Vec<ChannelState>,
    /// The live twin of each channel (same index), when a live view runs
    /// ([`crate::live`]).
    live: Vec<Option<crate::live::LiveChannel>>,
    /// `/bench/sample` (protobuf blocks), index into `channels`.
    sample: usize,
    /// `/bench/envelope` (protobuf), index into `channels`.
    envelope: usize,
    /// The block being filled (written when full and at every chunk flush).
    block: SampleBlock,
    /// The envelope bucket being filled.
    envelope_builder: EnvelopeBuilder,
    timing: Channel<TimingRecord>,
    event: Channel<EventRecord>,
    frf: Channel<FrfRecord<'static>>,
    log: Channel<FoxgloveLog>,
    /// Added to every log time: the run's start, ns since the Unix epoch
    /// (0 until set).
    time_origin_ns: u64,
    /// Reused serialization buffer (no allocation per message once warm).
    buf: Vec<u8>,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("final_path", &self.final_path)
            .field("part_path", &self.part_path)
            .field("channels", &self.channels.len())
            .field("open", &self.writer.is_some())
            .finish()
    }
}

/// Log time of a record, ns of loop time: `round(t_s × 1e9)`.
///
/// Saturating: negative or `NaN` times give 0, times beyond `u64::MAX` ns
/// (≈ 584 years) give `u64::MAX`.
pub fn log_time_ns(t_s: f64) -> u64 {
    // `as` from f64 to u64 saturates and maps NaN to 0.
    (t_s * 1e9).round() as u64
}

/// The identified frequency response current → position (`/sysid/frf`):
/// arrays of equal length, one entry per frequency line. Non-finite numbers
/// are written as null.
#[derive(Serialize, JsonSchema)]
struct FrfRecord<'a> {
    /// Frequency of each line, Hz.
    frequency_hz: &'a [f64],
    /// Magnitude of the position/current response, m/A.
    magnitude_m_per_a: &'a [f64],
    /// Phase of the position/current response, deg.
    phase_deg: &'a [f64],
    /// Magnitude-squared coherence, dimensionless (0 … 1).
    coherence: &'a [f64],
}

/// A channel every recording opens with ([`base_channel_specs`]).
struct ChannelSpec {
    topic: &'static str,
    message_encoding: &'static str,
    schema_name: &'static str,
    schema_encoding: &'static str,
    schema_data: Vec<u8>,
}

/// The channels [`Recorder::create_with`] registers, in its order (the
/// order gives their MCAP ids): `/bench/sample`, `/bench/envelope`
/// (protobuf), `/bench/timing`, `/bench/event`, `/sysid/frf`, `/bench/log`
/// (JSON, schemas from [`schema_of`]).
fn base_channel_specs() -> Result<[ChannelSpec; 6], RecordError> {
    let descriptor = proto::file_descriptor_set();
    let proto = |topic, schema_name| ChannelSpec {
        topic,
        message_encoding: "protobuf",
        schema_name,
        schema_encoding: "protobuf",
        schema_data: descriptor.clone(),
    };
    fn json<T: JsonSchema + ?Sized>(
        topic: &'static str,
        schema_name: &'static str,
    ) -> Result<ChannelSpec, RecordError> {
        Ok(ChannelSpec {
            topic,
            message_encoding: "json",
            schema_name,
            schema_encoding: "jsonschema",
            schema_data: serde_json::to_vec_pretty(&schema_of::<T>())?,
        })
    }
    Ok([
        proto(TOPIC_SAMPLE, SCHEMA_SAMPLE_BLOCK),
        proto(TOPIC_ENVELOPE, SCHEMA_ENVELOPE),
        json::<TimingRecord>(TOPIC_TIMING, SCHEMA_TIMING)?,
        json::<EventRecord>(TOPIC_EVENT, SCHEMA_EVENT)?,
        json::<FrfRecord<'static>>(TOPIC_FRF, SCHEMA_FRF)?,
        json::<FoxgloveLog>(TOPIC_LOG, SCHEMA_LOG)?,
    ])
}

/// The channel definitions a recording of this build opens with, with the
/// MCAP schema and channel ids it gives them (registered in the same order
/// on an in-memory mcap writer, which numbers them as the recorder's does):
/// what [`super::salvage`] puts back when the chunk holding them was
/// damaged.
///
/// # Errors
/// [`RecordError::Json`] / [`RecordError::Mcap`] (not expected: the same
/// calls succeed for every recording).
pub(crate) fn base_channels() -> Result<Vec<mcap::Channel<'static>>, RecordError> {
    let mcap_err = |source| RecordError::Mcap {
        path: PathBuf::new(),
        source,
    };
    let mut w = mcap::WriteOptions::new()
        .create(io::Cursor::new(Vec::new()))
        .map_err(mcap_err)?;
    let mut out = Vec::with_capacity(6);
    for c in base_channel_specs()? {
        let schema_id = w
            .add_schema(c.schema_name, c.schema_encoding, &c.schema_data)
            .map_err(mcap_err)?;
        let id = w
            .add_channel(schema_id, c.topic, c.message_encoding, &BTreeMap::new())
            .map_err(mcap_err)?;
        out.push(mcap::Channel {
            id,
            topic: c.topic.to_string(),
            schema: Some(Arc::new(mcap::Schema {
                id: schema_id,
                name: c.schema_name.to_string(),
                encoding: c.schema_encoding.to_string(),
                data: c.schema_data.into(),
            })),
            message_encoding: c.message_encoding.to_string(),
            metadata: BTreeMap::new(),
        });
    }
    Ok(out)
}

impl Recorder {
    /// Creates the recording `<final_path>.part` (see the
    /// [module docs](crate::record)), writes the MCAP header and registers the
    /// channels `/bench/sample`, `/bench/timing`, `/bench/event` and
    /// `/sysid/frf`, then flushes so the schemas reach the OS at once.
    ///
    /// Chunks are lz4-compressed and closed only by
    /// [`flush_chunk`](Self::flush_chunk) (never by size). The `.part` file
    /// is created exclusively with mode [`FILE_MODE`](crate::outputs::FILE_MODE):
    /// an existing one (the partial recording of a killed run) is refused,
    /// and [`finish`](Self::finish) never replaces an existing
    /// `final_path` (see [`crate::outputs`]).
    ///
    /// # Errors
    /// [`RecordError::Create`] naming the `.part` path, its directory and the
    /// OS reason when the directory does not exist or is not writable, the
    /// `.part` file exists (or `final_path` has no file name);
    /// [`RecordError::Mcap`] if the header cannot be written.
    pub fn create(final_path: &Path) -> Result<Recorder, RecordError> {
        Self::create_with(final_path, crate::outputs::Existing::Refuse, None)
    }

    /// [`create`](Self::create) with the run's policy for existing files
    /// (`--overwrite`: an existing regular `.part` and `final_path` are
    /// replaced) and, for a default name claimed by
    /// [`claim_recording`](crate::outputs::claim_recording), its `.part`
    /// file already created and open (`claimed_part`).
    ///
    /// # Errors
    /// As [`create`](Self::create).
    pub fn create_with(
        final_path: &Path,
        existing: crate::outputs::Existing,
        claimed_part: Option<File>,
    ) -> Result<Recorder, RecordError> {
        let part_path = part_path_for(final_path);
        let dir = match final_path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        if final_path.file_name().is_none() {
            return Err(RecordError::Create {
                path: part_path,
                dir,
                source: io::Error::new(io::ErrorKind::InvalidInput, "path has no file name"),
            });
        }
        let file = match claimed_part {
            Some(f) => f,
            None => crate::outputs::create_part(&part_path, existing).map_err(|source| {
                RecordError::Create {
                    path: part_path.clone(),
                    dir: dir.clone(),
                    source,
                }
            })?,
        };
        let writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Lz4))
            .chunk_size(None)
            .disable_seeking(true)
            .profile("")
            .library(concat!("bench-", env!("CARGO_PKG_VERSION"), " (mcap-rs)"))
            .create(BufWriter::with_capacity(FILE_BUFFER_BYTES, file))
            .map_err(|source| RecordError::Mcap {
                path: part_path.clone(),
                source,
            })?;
        let mut rec = Recorder {
            writer: Some(writer),
            final_path: final_path.to_path_buf(),
            part_path,
            existing,
            channels: Vec::with_capacity(8),
            live: Vec::with_capacity(8),
            sample: 0,
            envelope: 0,
            block: SampleBlock::with_capacity(),
            envelope_builder: EnvelopeBuilder::default(),
            timing: Channel::new(0),
            event: Channel::new(0),
            frf: Channel::new(0),
            log: Channel::new(0),
            time_origin_ns: 0,
            buf: Vec::with_capacity(512),
        };
        let mut index = Vec::with_capacity(6);
        for c in base_channel_specs()? {
            index.push(rec.register(
                c.topic,
                c.message_encoding,
                c.schema_name,
                c.schema_encoding,
                &c.schema_data,
            )?);
        }
        let [sample, envelope, timing, event, frf, log] = index[..] else {
            unreachable!("six base channels");
        };
        rec.sample = sample;
        rec.envelope = envelope;
        rec.timing = Channel::new(timing);
        rec.event = Channel::new(event);
        rec.frf = Channel::new(frf);
        rec.log = Channel::new(log);
        rec.flush_chunk()?;
        Ok(rec)
    }

    /// The path the recording gets on [`finish`](Self::finish).
    pub fn final_path(&self) -> &Path {
        &self.final_path
    }

    /// The `.part` file being written (`<final_path>.part`).
    pub fn part_path(&self) -> &Path {
        &self.part_path
    }

    fn writer(&mut self) -> &mut mcap::Writer<BufWriter<File>> {
        self.writer
            .as_mut()
            .expect("Recorder used after finish (writer is only taken by finish/drop)")
    }

    fn mcap_err(&self, source: mcap::McapError) -> RecordError {
        RecordError::Mcap {
            path: self.part_path.clone(),
            source,
        }
    }

    /// Registers a JSON channel on `topic` whose messages are `T`, with a
    /// `jsonschema` schema named `schema_name` generated from `T` by
    /// [`schema_of`] (each field's doc comment, stating its unit, is its
    /// description). Registering the same topic and schema twice returns an
    /// equivalent channel.
    ///
    /// The channel record goes into the current chunk: it reaches the file
    /// with the next [`flush_chunk`](Self::flush_chunk).
    ///
    /// # Errors
    /// [`RecordError::Json`] / [`RecordError::Mcap`].
    pub fn add_channel_for<T: JsonSchema + ?Sized>(
        &mut self,
        topic: &str,
        schema_name: &str,
    ) -> Result<Channel<T>, RecordError> {
        let schema_data = serde_json::to_vec_pretty(&schema_of::<T>())?;
        self.register(topic, "json", schema_name, "jsonschema", &schema_data)
            .map(Channel::new)
    }

    /// Adds the schema and the channel to the MCAP and, when a live view
    /// runs, the channel's live twin; returns the channel's index. The same
    /// topic, encoding and schema registered again return the same index.
    fn register(
        &mut self,
        topic: &str,
        message_encoding: &str,
        schema_name: &str,
        schema_encoding: &str,
        schema_data: &[u8],
    ) -> Result<usize, RecordError> {
        let w = self.writer();
        let ids = w
            .add_schema(schema_name, schema_encoding, schema_data)
            .and_then(|sid| w.add_channel(sid, topic, message_encoding, &BTreeMap::new()));
        let id = ids.map_err(|e| self.mcap_err(e))?;
        if let Some(i) = self.channels.iter().position(|c| c.id == id) {
            return Ok(i);
        }
        self.channels.push(ChannelState {
            id,
            next_sequence: 0,
        });
        self.live.push(crate::live::LiveChannel::new(
            topic,
            message_encoding,
            schema_name,
            schema_encoding,
            schema_data,
        ));
        Ok(self.channels.len() - 1)
    }

    /// Writes `message` (its `serde_json` form; non-finite numbers become
    /// `null`) on `ch` at `log_time_ns` (nanoseconds of loop time; publish
    /// time = log time).
    ///
    /// # Errors
    /// [`RecordError::UnknownChannel`] for a channel of another recorder,
    /// [`RecordError::Json`], [`RecordError::Mcap`].
    pub fn write<T: Serialize + ?Sized>(
        &mut self,
        ch: Channel<T>,
        log_time_ns: u64,
        message: &T,
    ) -> Result<(), RecordError> {
        self.write_at(ch.index, log_time_ns, message)
    }

    /// Serialises `message` into `self.buf` and writes it as one message on
    /// channel `index` at `log_time` (ns of loop time; publish time = log
    /// time).
    fn write_at<T: Serialize + ?Sized>(
        &mut self,
        index: usize,
        log_time: u64,
        message: &T,
    ) -> Result<(), RecordError> {
        self.buf.clear();
        serde_json::to_writer(&mut self.buf, message)?;
        self.write_buf(index, log_time)
    }

    /// Encodes the protobuf `message` into `self.buf` and writes it on
    /// channel `index` at `log_time` (ns of loop time).
    fn write_proto<M: prost::Message>(
        &mut self,
        index: usize,
        log_time: u64,
        message: &M,
    ) -> Result<(), RecordError> {
        self.buf.clear();
        message
            .encode(&mut self.buf)
            .expect("a Vec grows to hold any message");
        self.write_buf(index, log_time)
    }

    /// Writes `self.buf` as one message on channel `index` at `log_time`
    /// (ns of loop time; publish time = log time).
    fn write_buf(&mut self, index: usize, log_time: u64) -> Result<(), RecordError> {
        let state = self
            .channels
            .get_mut(index)
            .ok_or(RecordError::UnknownChannel(index))?;
        let log_time = log_time.saturating_add(self.time_origin_ns);
        let header = MessageHeader {
            channel_id: state.id,
            sequence: state.next_sequence,
            log_time,
            publish_time: log_time,
        };
        state.next_sequence = state.next_sequence.wrapping_add(1);
        if let Some(Some(live)) = self.live.get(index) {
            live.log(&self.buf, log_time);
        }
        let w = self
            .writer
            .as_mut()
            .expect("Recorder used after finish (writer is only taken by finish/drop)");
        match w.write_to_known_channel(&header, &self.buf) {
            Ok(()) => Ok(()),
            Err(e) => Err(self.mcap_err(e)),
        }
    }

    /// Writes one record from the tick: a [`Record::Sample`] on
    /// `/bench/sample`, [`Record::Timing`] on `/bench/timing`,
    /// [`Record::Event`] on `/bench/event`, each at log time
    /// `round(t_s × 1e9)` ns of loop time. Non-finite numbers become `null`.
    ///
    /// # Errors
    /// [`RecordError::Json`] / [`RecordError::Mcap`].
    pub fn write_record(&mut self, r: &Record) -> Result<(), RecordError> {
        match r {
            Record::Sample(s) => {
                if !self.block.is_empty() && s.tick != self.block.next_tick() {
                    self.write_block()?;
                }
                self.block.push(s);
                if let Some(e) = self.envelope_builder.push(s) {
                    self.write_envelope(&e)?;
                }
                if self.block.len() >= BLOCK_TICKS {
                    self.write_block()?;
                }
                Ok(())
            }
            Record::Timing(t) => self.write(self.timing, log_time_ns(t.t_s), t),
            Record::Event(e) => {
                let t = log_time_ns(e.t_s);
                self.write(self.event, t, e)?;
                let line = FoxgloveLog::of_event(e, t.saturating_add(self.time_origin_ns));
                self.write(self.log, t, &line)
            }
        }
    }

    /// Writes the block in progress (if any) on `/bench/sample` at its
    /// first tick's log time and empties it.
    fn write_block(&mut self) -> Result<(), RecordError> {
        if self.block.is_empty() {
            return Ok(());
        }
        let block = std::mem::take(&mut self.block);
        let res = self.write_proto(self.sample, log_time_ns(block.t_s[0]), &block);
        self.block = block;
        self.block.clear();
        res
    }

    fn write_envelope(&mut self, e: &Envelope) -> Result<(), RecordError> {
        self.write_proto(self.envelope, log_time_ns(e.t_s), e)
    }

    /// Writes what is buffered for the binary channels: the block in
    /// progress and, with `end`, the last envelope bucket.
    fn write_pending(&mut self, end: bool) -> Result<(), RecordError> {
        self.write_block()?;
        if end {
            if let Some(e) = self.envelope_builder.finish() {
                self.write_envelope(&e)?;
            }
        }
        Ok(())
    }

    /// Sets the run's start, ns since the Unix epoch: every message's log
    /// time is this plus its loop time (see the [module docs](crate::record)).
    /// Set it before the first message.
    pub fn set_time_origin_ns(&mut self, unix_ns: u64) {
        self.time_origin_ns = unix_ns;
    }

    /// The run's start, ns since the Unix epoch (0: not set).
    pub fn time_origin_ns(&self) -> u64 {
        self.time_origin_ns
    }

    /// Writes the identified frequency response on `/sysid/frf` at
    /// `log_time_ns` (ns of loop time). Arrays: `frequency_hz` in Hz,
    /// `magnitude_m_per_a` in m/A, `phase_deg` in degrees, `coherence`
    /// dimensionless (0…1); non-finite entries become `null`.
    ///
    /// # Errors
    /// [`RecordError::FrfLength`] if the four slices differ in length;
    /// [`RecordError::Json`] / [`RecordError::Mcap`].
    pub fn write_frf(
        &mut self,
        log_time_ns: u64,
        frequency_hz: &[f64],
        magnitude_m_per_a: &[f64],
        phase_deg: &[f64],
        coherence: &[f64],
    ) -> Result<(), RecordError> {
        let n = frequency_hz.len();
        if magnitude_m_per_a.len() != n || phase_deg.len() != n || coherence.len() != n {
            return Err(RecordError::FrfLength {
                frequency: n,
                magnitude: magnitude_m_per_a.len(),
                phase: phase_deg.len(),
                coherence: coherence.len(),
            });
        }
        let frf = FrfRecord {
            frequency_hz,
            magnitude_m_per_a,
            phase_deg,
            coherence,
        };
        // The channel's type is `FrfRecord<'static>`; this one borrows.
        self.write_at(self.frf.index, log_time_ns, &frf)
    }

    /// Writes an MCAP Metadata record `name` with string `entries` (e.g.
    /// name `"bench.config"`, key `"toml"` = the resolved configuration).
    /// This closes the current chunk (an mcap rule) and flushes, so the
    /// metadata survives a killed process.
    ///
    /// # Errors
    /// [`RecordError::Mcap`].
    pub fn write_metadata(
        &mut self,
        name: &str,
        entries: &BTreeMap<String, String>,
    ) -> Result<(), RecordError> {
        let md = mcap::records::Metadata {
            name: name.to_owned(),
            metadata: entries.clone(),
        };
        let res = self.writer().write_metadata(&md);
        res.map_err(|e| self.mcap_err(e))?;
        self.flush_chunk()
    }

    /// Closes the current chunk, writes it out and flushes the file buffer so
    /// the bytes reach the OS (no fsync). Everything written before this call
    /// survives a killed process. A no-op apart from the buffer flush when no
    /// chunk is open.
    ///
    /// # Errors
    /// [`RecordError::Mcap`].
    pub fn flush_chunk(&mut self) -> Result<(), RecordError> {
        // The samples buffered in the block go into this chunk.
        self.write_pending(false)?;
        // mcap's `Writer::flush` = finish the chunk + `flush()` the
        // underlying writer, i.e. our BufWriter → write(2) to the file.
        let res = self.writer().flush();
        res.map_err(|e| self.mcap_err(e))
    }

    /// Completes the MCAP (summary section + footer), flushes, fsyncs the
    /// file, renames `<final_path>.part` to `final_path` without replacing
    /// an existing file unless the recorder was created with
    /// [`Existing::Replace`](crate::outputs::Existing::Replace)
    /// ([`outputs::commit`](crate::outputs::commit)), then fsyncs the
    /// directory (best effort) and returns `final_path`.
    ///
    /// On error the `.part` file is left in place and nothing is renamed.
    ///
    /// # Errors
    /// [`RecordError::Mcap`], [`RecordError::Io`], [`RecordError::Rename`].
    pub fn finish(mut self) -> Result<PathBuf, RecordError> {
        self.write_pending(true)?;
        let mut w = self
            .writer
            .take()
            .expect("Recorder writer present until finish");
        w.finish().map_err(|e| self.mcap_err(e))?;
        let io_err = |source| RecordError::Io {
            path: self.part_path.clone(),
            source,
        };
        let file = w
            .into_inner()
            .into_inner()
            .map_err(|e| io_err(e.into_error()))?;
        file.sync_all().map_err(io_err)?;
        drop(file);
        crate::outputs::commit(&self.part_path, &self.final_path, self.existing).map_err(
            |source| RecordError::Rename {
                from: self.part_path.clone(),
                to: self.final_path.clone(),
                source,
            },
        )?;
        sync_parent_dir(&self.final_path);
        Ok(self.final_path.clone())
    }
}

/// fsync the directory holding `path` so the rename is durable (best effort;
/// not possible on every platform).
fn sync_parent_dir(path: &Path) {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
}

/// Dropping a [`Recorder`] without [`Recorder::finish`] (e.g. on an error
/// path) still completes the MCAP structure (summary, footer) in the `.part`
/// file and flushes it, but does **not** rename it: the `.part` suffix marks
/// the run as failed/incomplete. Errors are logged with `tracing`, not
/// returned.
impl Drop for Recorder {
    fn drop(&mut self) {
        if self.writer.is_some() {
            if let Err(e) = self.write_pending(true) {
                tracing::warn!(path = %self.part_path.display(), error = %e, "could not write the last samples");
            }
        }
        if let Some(mut w) = self.writer.take() {
            if let Err(e) = w.finish() {
                tracing::warn!(
                    path = %self.part_path.display(),
                    error = %e,
                    "could not complete the MCAP of an unfinished recording"
                );
            }
            let mut inner = w.into_inner();
            if let Err(e) = inner.flush() {
                tracing::warn!(path = %self.part_path.display(), error = %e, "flush failed");
            }
            tracing::warn!(
                path = %self.part_path.display(),
                "recording dropped without finish(); left as .part"
            );
        }
    }
}

/// Counters returned by the writer thread ([`spawn_writer`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WriterStats {
    /// Records popped from the queue and written, count.
    pub records_written: u64,
    /// Chunks closed and flushed by the thread, count.
    pub chunks_flushed: u64,
}

fn record_log_time(r: &Record) -> u64 {
    log_time_ns(match r {
        Record::Sample(s) => s.t_s,
        Record::Timing(t) => t.t_s,
        Record::Event(e) => e.t_s,
    })
}

/// Starts the writer thread (named `bench-writer`): it pops every record from
/// `consumer`, writes it with [`Recorder::write_record`], then calls
/// `on_record` on it (e.g. to collect samples for identification). After
/// each batch it tells `room` how full the queue still is
/// ([`QueueRoom::made_room`]): a virtual-time loop parked on the full queue
/// is woken once half of it is free.
///
/// **Chunks reach the disk on a wall-clock deadline.** It closes and
/// flushes a chunk ([`Recorder::flush_chunk`], a `write(2)` to the file)
/// whenever `chunks.wall` of wall time has passed since the last flush, or
/// the log time (loop time, ns) of the written records has advanced by
/// `chunks.loop_time` ([`ChunkPolicy`]); the wall deadline is checked every
/// [`WALL_CHECK_RECORDS`] records (a few µs), so a writer that is behind
/// still flushes on time. With 50 ms of wall time, a killed process loses
/// at most that plus what sits in the queue (a few ms when the writer keeps
/// up), under the 100 ms the README promises. When the queue is empty it sleeps
/// ~1 ms. `priority`: in real-time runs the thread takes `SCHED_FIFO` at
/// this priority (one below the loop's), so a loaded machine does not starve
/// it; without the permission it runs normally (best effort, no error).
///
/// It exits once `done` is set (or the producer was dropped) **and** the
/// queue is empty — the queue is drained fully — flushes the last chunk, and
/// returns the recorder, **not finished**, so the caller can add e.g.
/// `/sysid/frf` and then call [`Recorder::finish`].
///
/// **On a write error** (e.g. `ENOSPC`) the thread tries to write a
/// `fault`/`recording` event (it may fail too), drops the recorder (leaving
/// the `.part` file, see [`Recorder`]'s `Drop`) and returns the error at
/// once. Dropping its consumer abandons the queue: the loop sees that on its
/// next tick ([`crate::rt::Emitter::recording_lost`]) and stops on the
/// `recording` fault (0 A, disabled); a loop parked on `room` is woken.
///
/// # Panics
/// If the OS cannot spawn a thread.
pub fn spawn_writer<F>(
    mut consumer: rtrb::Consumer<Record>,
    room: Arc<QueueRoom>,
    mut recorder: Recorder,
    done: Arc<AtomicBool>,
    chunks: ChunkPolicy,
    priority: Option<i32>,
    mut on_record: F,
) -> JoinHandle<Result<(Recorder, WriterStats), RecordError>>
where
    F: FnMut(&Record) + Send + 'static,
{
    std::thread::Builder::new()
        .name("bench-writer".into())
        .spawn(move || {
            if let Some(p) = priority {
                // The loop's own setup (mlockall is process-wide: again is
                // a no-op); not permitted, the writer runs normally.
                for w in bench_hal::os::make_realtime(p, None) {
                    tracing::debug!("bench-writer: {w}");
                }
            }
            let mut last: Option<(u64, f64)> = None;
            let result = write_queue(
                &mut consumer,
                &room,
                &mut recorder,
                &done,
                chunks,
                &mut on_record,
                &mut last,
            );
            match result {
                Ok(stats) => Ok((recorder, stats)),
                Err(e) => {
                    let (tick, t_s) = last.unwrap_or((0, 0.0));
                    let _ = recorder.write_record(&Record::Event(EventRecord {
                        tick,
                        t_s,
                        kind: EventKind::Fault,
                        state: SupervisorState::Faulted,
                        fault: Some(FaultKind::Recording),
                        value: f64::NAN,
                    }));
                    drop(recorder);
                    drop(consumer);
                    // A loop parked on the full queue sees it abandoned now.
                    room.release();
                    Err(e)
                }
            }
        })
        .expect("cannot spawn the bench-writer thread")
}

/// The writer thread's loop (see [`spawn_writer`]). `last` is the tick and
/// loop time of the newest record written.
fn write_queue<F: FnMut(&Record)>(
    consumer: &mut rtrb::Consumer<Record>,
    room: &QueueRoom,
    recorder: &mut Recorder,
    done: &AtomicBool,
    chunks: ChunkPolicy,
    on_record: &mut F,
    last: &mut Option<(u64, f64)>,
) -> Result<WriterStats, RecordError> {
    let interval_ns = u64::try_from(chunks.loop_time.as_nanos()).unwrap_or(u64::MAX);
    let chunk_interval = chunks.wall;
    let mut stats = WriterStats::default();
    let mut last_flush_wall = Instant::now();
    // Log time of the last record written before the previous flush (or of
    // the first record ever).
    let mut last_flush_log: Option<u64> = None;
    // Log time of the newest record written.
    let mut last_written_log: Option<u64> = None;
    let mut dirty = false;
    loop {
        // Read `done` before looking at the queue: if it was set, every
        // record pushed before it is visible to the `slots()` below.
        let finishing = done.load(Ordering::Acquire) || consumer.is_abandoned();
        let n = consumer.slots().min(MAX_BATCH);
        if n > 0 {
            let chunk = consumer
                .read_chunk(n)
                .expect("slots() said these are available");
            let (a, b) = chunk.as_slices();
            for r in a.iter().chain(b) {
                recorder.write_record(r)?;
                on_record(r);
                stats.records_written += 1;
                dirty = true;
                *last = Some(record_tick_time(r));
                let t = record_log_time(r);
                last_written_log = Some(t);
                let base = *last_flush_log.get_or_insert(t);
                if t.saturating_sub(base) >= interval_ns
                    || (stats.records_written.is_multiple_of(WALL_CHECK_RECORDS)
                        && last_flush_wall.elapsed() >= chunk_interval)
                {
                    recorder.flush_chunk()?;
                    stats.chunks_flushed += 1;
                    dirty = false;
                    last_flush_log = Some(t);
                    last_flush_wall = Instant::now();
                }
            }
            chunk.commit_all();
            room.made_room(consumer.slots(), consumer.buffer().capacity());
        }
        if dirty && last_flush_wall.elapsed() >= chunk_interval {
            recorder.flush_chunk()?;
            stats.chunks_flushed += 1;
            dirty = false;
            last_flush_wall = Instant::now();
            last_flush_log = last_written_log;
        }
        if n == 0 {
            if finishing {
                break;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    if dirty {
        recorder.flush_chunk()?;
        stats.chunks_flushed += 1;
    }
    Ok(stats)
}

fn record_tick_time(r: &Record) -> (u64, f64) {
    match r {
        Record::Sample(s) => (s.tick, s.t_s),
        Record::Timing(t) => (t.tick, t.t_s),
        Record::Event(e) => (e.tick, e.t_s),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::record::reader::{decode_samples, read_messages_tolerant, read_samples_tolerant};
    use crate::record::topics::SampleRecord;
    use serde_json::{json, Value};

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
        rec.write_frf(log_time_ns(0.2), &freq, &mag, &phase, &coh)
            .unwrap();
        // Extra channel through the generic API.
        let ch = rec
            .add_channel_for::<Metrics>("/bench/metrics", "bench.Metrics")
            .unwrap();
        rec.write(ch, 42, &Metrics { rms_m: 1e-7 }).unwrap();
        rec.write(ch, 43, &Metrics { rms_m: f64::NAN }).unwrap();
        assert!(matches!(
            rec.write_frf(0, &freq, &mag[..2], &phase, &coh),
            Err(RecordError::FrfLength { magnitude: 2, .. })
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
                mcap::Summary::read(bytes).is_err()
                    || mcap::Summary::read(bytes).unwrap().is_none()
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
        let mut pushed = 0;
        while pushed < n {
            if prod.push(Record::Sample(sample(pushed))).is_ok() {
                pushed += 1;
            } else {
                std::thread::yield_now();
            }
        }
        prod.push(Record::Event(event(
            n,
            EventKind::LoopStopped,
            None,
            f64::NAN,
        )))
        .unwrap();
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
}
