//! MCAP recorder: writes the records of the real-time tick (and the results
//! computed after the run) to an [MCAP](https://mcap.dev) file.
//!
//! [`topics`] holds the records the tick pushes (`Copy`, no heap data); the
//! writer ([`Recorder`], [`spawn_writer`]) serialises them on its own thread;
//! the reader ([`read_messages_tolerant`], [`read_samples_tolerant`]) reads
//! recordings back, also cut ones; [`schema_of`] generates each channel's
//! JSON Schema. [`queue`] is the wait-free queue from the tick to the writer.
//!
//! # Topics
//!
//! The per-tick channels are binary ([`proto`]): `/bench/sample` holds the
//! ticks in blocks and `/bench/envelope` their extremes per 5 ms for
//! plotting, both protobuf. Every other channel uses
//! `message_encoding = "json"` and a schema with
//! `encoding = "jsonschema"` whose data is a JSON Schema document. Each
//! record is written down once, as a Rust type: a message is the type's
//! `serde_json` form and the channel's schema is generated from the same
//! type ([`schema_of`]), so every field's `description` is its doc comment,
//! which states its unit. Non-finite floating-point values (`NaN`, `±inf`)
//! are written as JSON `null`, since JSON has no NaN; the schemas declare
//! every number as `["number", "null"]`.
//!
//! - `/bench/sample`, schema `bench.SampleBlock` (protobuf): up to
//!   [`proto::BLOCK_TICKS`] consecutive ticks per message as columns, read
//!   back as one [`SampleRecord`] per tick ([`read_samples_tolerant`],
//!   [`decode_samples`]). Recordings made before this held one JSON
//!   `bench.Sample` message per tick on the same topic; the readers take
//!   both.
//! - `/bench/envelope`, schema `bench.Envelope` (protobuf): per
//!   [`proto::ENVELOPE_PERIOD_S`] (5 ms) of loop time, the smallest and
//!   largest position and command ([`proto::Envelope`]).
//! - `/bench/timing`, schema `bench.Timing`: one [`TimingRecord`] per
//!   reporting window.
//! - `/bench/event`, schema `bench.Event`: one [`EventRecord`] per event;
//!   `kind`, `state` and `fault` are the [`EventKind::as_str`],
//!   [`SupervisorState::as_str`] and [`FaultKind::as_str`] names.
//! - `/sysid/frf`, schema `bench.Frf`: arrays of equal length, one entry per
//!   frequency line: `frequency_hz` (Hz), `magnitude_m_per_a` (m/A),
//!   `phase_deg` (deg), `coherence` (dimensionless, 0…1),
//!   `sigma_m_per_a` (m/A, the 1σ of the complex response) and
//!   `resolution_hz` (Hz, the band each line draws on; both absent in
//!   recordings of earlier versions); see [`Recorder::write_frf`].
//!
//! The jobs add their results (e.g. `/sysid/summary`, `/control/metrics`)
//! with [`Recorder::add_channel_for`], which registers the schema generated
//! from the message type, and write them with [`Recorder::write`].
//!
//! [`SampleRecord`]: topics::SampleRecord
//! [`TimingRecord`]: topics::TimingRecord
//! [`EventRecord`]: topics::EventRecord
//! [`EventKind::as_str`]: topics::EventKind::as_str
//! [`SupervisorState::as_str`]: topics::SupervisorState::as_str
//! [`FaultKind::as_str`]: topics::FaultKind::as_str
//!
//! # Time stamps
//!
//! Log time and publish time of every message are **nanoseconds since the
//! Unix epoch**: the run's start ([`Recorder::set_time_origin_ns`], the
//! `start_time_unix_ns` of the `bench.run` metadata) plus the record's loop
//! time, `round(t_s × 1e9)` (see [`log_time_ns`]), so Foxglove places a
//! recording at the moment it was made. The writers take loop time; the
//! recorder adds the origin. Recordings made before (origin 0) hold loop
//! time alone. Publish time equals log time. Sequence numbers count per
//! channel from 0.
//!
//! - `/bench/log`, schema `foxglove.Log`: every event again as a
//!   [`FoxgloveLog`](topics::FoxgloveLog) line, for Foxglove's Log panel.
//!
//! # The `.part` rule
//!
//! [`Recorder::create`] writes to a sibling file named `<final_path>.part`
//! (e.g. `run.mcap.part`). Only [`Recorder::finish`] completes the MCAP, fsyncs
//! it and renames it to `final_path`. A process killed (even with `SIGKILL`)
//! therefore leaves `run.mcap.part`, never a file that looks complete. A
//! [`Recorder`] dropped without `finish` (e.g. on an error path) still writes
//! the MCAP summary and footer so the `.part` file is a valid MCAP, but it is
//! **not** renamed: a failed run never looks complete.
//!
//! # Chunks and flushing
//!
//! Messages go into lz4-compressed chunks. Chunks are **not** closed by size:
//! a chunk is closed only by [`Recorder::flush_chunk`] (and by metadata writes
//! and `finish`). The chunk being built is held in memory (the mcap writer is
//! configured with `disable_seeking(true)`, i.e. buffered chunks), so the file
//! on disk only ever holds complete chunks plus, at worst, one chunk that was
//! cut while being written — readable up to the last complete chunk with
//! [`read_messages_tolerant`] / [`read_samples_tolerant`], which also keep
//! every intact chunk after a damaged one ([`salvage`]).
//!
//! The writer thread ([`spawn_writer`]) closes and flushes a chunk whenever
//! 50 ms of **wall** time has elapsed since the last flush, **or** the log
//! (loop) time of the written records has advanced by 50 ms in real time, by
//! 1 s in (faster than real time) virtual time ([`ChunkPolicy`]). A killed
//! run loses at most about 100 ms of wall time's records. Flushing hands the
//! bytes to the OS (survives a killed process); only `finish` fsyncs
//! (survives power loss).
//!
//! Layer rule: may use `error`, `input_file`, `live`, `outputs`, `vocab`.

mod drain;
pub mod export;
pub mod proto;
pub mod queue;
mod reader;
pub mod recover;
pub mod salvage;
mod schema;
pub mod topics;
mod writer;

pub use crate::error::RecordError;
pub use crate::outputs::{part_path_for, PART_SUFFIX};
pub use drain::{spawn_writer, WriterStats};
pub use reader::{
    decode_sample, decode_samples, read_messages_tolerant, read_samples_tolerant, TolerantRead,
};
pub use schema::{nan_if_null, schema_of};
pub use writer::{log_time_ns, Channel, ChunkPolicy, FrfRecord, Recorder};

/// Topic of the per-tick samples.
pub const TOPIC_SAMPLE: &str = "/bench/sample";
/// Topic of the per-5 ms extremes of the samples, for display.
pub const TOPIC_ENVELOPE: &str = "/bench/envelope";
/// Topic of the loop-timing windows.
pub const TOPIC_TIMING: &str = "/bench/timing";
/// Topic of the events.
pub const TOPIC_EVENT: &str = "/bench/event";
/// Topic of the identified frequency response.
pub const TOPIC_FRF: &str = "/sysid/frf";
/// Topic of the events as Foxglove log lines.
pub const TOPIC_LOG: &str = "/bench/log";

/// Schema name of [`TOPIC_SAMPLE`] in recordings made before the
/// protobuf blocks (one JSON message per tick); now
/// [`proto::SCHEMA_SAMPLE_BLOCK`].
pub const SCHEMA_SAMPLE: &str = "bench.Sample";
/// Schema name of [`TOPIC_TIMING`].
pub const SCHEMA_TIMING: &str = "bench.Timing";
/// Schema name of [`TOPIC_EVENT`].
pub const SCHEMA_EVENT: &str = "bench.Event";
/// Schema name of [`TOPIC_FRF`].
pub const SCHEMA_FRF: &str = "bench.Frf";
/// Schema name of [`TOPIC_LOG`]: Foxglove's well-known log schema.
pub const SCHEMA_LOG: &str = "foxglove.Log";
