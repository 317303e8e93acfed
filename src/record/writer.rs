//! The MCAP writer: [`Recorder`] (channels, messages, the `.part` rule,
//! chunk flushing). The writer thread that drains the tick's queue into it
//! is [`super::drain`]. See the [module docs](crate::record) for topics and units.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::marker::PhantomData;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use mcap::records::MessageHeader;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};
use std::borrow::Cow;

use crate::error::RecordError;
use crate::outputs::part_path_for;
use crate::record::proto::{
    self, Envelope, EnvelopeBuilder, SampleBlock, BLOCK_TICKS, SCHEMA_ENVELOPE, SCHEMA_SAMPLE_BLOCK,
};
use crate::record::schema_of;
use crate::record::topics::{EventRecord, FoxgloveLog, Record, TimingRecord};
use crate::record::{
    SCHEMA_EVENT, SCHEMA_FRF, SCHEMA_LOG, SCHEMA_TIMING, TOPIC_ENVELOPE, TOPIC_EVENT, TOPIC_FRF,
    TOPIC_LOG, TOPIC_SAMPLE, TOPIC_TIMING,
};

/// When [`crate::record::spawn_writer`] closes and flushes a chunk: once `wall` of wall
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

/// Size of the buffer between the mcap writer and the file, bytes.
const FILE_BUFFER_BYTES: usize = 64 * 1024;

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
/// arrays of equal length, one entry per frequency line. The one type of
/// the channel, written ([`Recorder::write_frf`], borrowing the FRF's
/// columns) and read (`crate::ident::frf::read_frf`, owning them).
/// Non-finite numbers are written as null and read back as NaN, except
/// in `sigma_dof`, whose null is infinite (a known variance). A column
/// added after the first recordings (`sigma_m_per_a`, `resolution_hz`,
/// `sigma_dof`) reads as empty when absent.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct FrfRecord<'a> {
    /// Frequency of each line, Hz.
    #[serde(deserialize_with = "null_as_nan")]
    pub frequency_hz: Cow<'a, [f64]>,
    /// Magnitude of the position/current response, m/A.
    #[serde(deserialize_with = "null_as_nan")]
    pub magnitude_m_per_a: Cow<'a, [f64]>,
    /// Phase of the position/current response, deg.
    #[serde(deserialize_with = "null_as_nan")]
    pub phase_deg: Cow<'a, [f64]>,
    /// Magnitude-squared coherence (H1), or its signal-to-noise form
    /// (LPM), dimensionless (0 … 1).
    #[serde(deserialize_with = "null_as_nan")]
    pub coherence: Cow<'a, [f64]>,
    /// 1σ of the complex response, sqrt(E|Ĥ − H|²), m/A (absent in
    /// recordings made before it existed: unknown).
    #[serde(default, deserialize_with = "null_as_nan")]
    pub sigma_m_per_a: Cow<'a, [f64]>,
    /// Width of the band of DFT bins each line's estimate draws on, Hz
    /// (absent in recordings made before it existed: unknown).
    #[serde(default, deserialize_with = "null_as_nan")]
    pub resolution_hz: Cow<'a, [f64]>,
    /// Degrees of freedom of the variance behind `sigma_m_per_a`
    /// ([`crate::ident::frf::Frf::sigma_dof`]; null: known; absent in
    /// recordings made before it existed: not stated).
    #[serde(default, deserialize_with = "null_as_infinity")]
    pub sigma_dof: Cow<'a, [f64]>,
}

/// A JSON array of numbers and nulls, the nulls as `null_value`.
fn nulls_as<'de, D: serde::Deserializer<'de>>(
    d: D,
    null_value: f64,
) -> Result<Cow<'static, [f64]>, D::Error> {
    let v: Vec<Option<f64>> = Deserialize::deserialize(d)?;
    Ok(Cow::Owned(
        v.into_iter().map(|x| x.unwrap_or(null_value)).collect(),
    ))
}

fn null_as_nan<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Cow<'static, [f64]>, D::Error> {
    nulls_as(d, f64::NAN)
}

fn null_as_infinity<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<Cow<'static, [f64]>, D::Error> {
    nulls_as(d, f64::INFINITY)
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

    /// Writes the identified frequency response `frf` on `/sysid/frf` at
    /// `log_time_ns` (ns of loop time). Arrays: `frequency_hz` in Hz,
    /// `magnitude_m_per_a` in m/A, `phase_deg` in degrees, `coherence`
    /// dimensionless (0…1), `sigma_m_per_a` in m/A, `resolution_hz` in Hz,
    /// `sigma_dof` dimensionless; non-finite entries become `null`.
    ///
    /// # Errors
    /// [`RecordError::FrfLength`] if the seven slices differ in length;
    /// [`RecordError::Json`] / [`RecordError::Mcap`].
    pub fn write_frf(&mut self, log_time_ns: u64, frf: &FrfRecord<'_>) -> Result<(), RecordError> {
        let n = frf.frequency_hz.len();
        let lengths = [
            frf.magnitude_m_per_a.len(),
            frf.phase_deg.len(),
            frf.coherence.len(),
            frf.sigma_m_per_a.len(),
            frf.resolution_hz.len(),
            frf.sigma_dof.len(),
        ];
        if lengths.iter().any(|l| *l != n) {
            return Err(RecordError::FrfLength {
                frequency: n,
                magnitude: lengths[0],
                phase: lengths[1],
                coherence: lengths[2],
                sigma: lengths[3],
                resolution: lengths[4],
                dof: lengths[5],
            });
        }
        self.write_at(self.frf.index, log_time_ns, frf)
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

#[cfg(test)]
#[path = "writer_tests.rs"]
mod tests;
