//! The binary (protobuf) channels of a recording: `/bench/sample` in blocks
//! of ticks and `/bench/envelope`, the min/max per 5 ms for display.
//!
//! One JSON message per tick cost about 1 µs of writer CPU and 75 bytes on
//! disk per tick (issue 16). A block holds up to [`BLOCK_TICKS`] ticks as
//! packed columns, so the per-message costs (the MCAP record header, the
//! 16-byte message index entry, the serializer call) are paid once per
//! block, and each column compresses on its own (constant columns such as
//! the setpoint and the state take almost nothing). Blocks are closed when
//! full and at every chunk flush (every 50 ms, [`super::spawn_writer`]),
//! so a killed run still loses at most one chunk interval.
//!
//! Encoding: protobuf (proto3, packed repeated fields), schema encoding
//! `protobuf` (a serialized `google.protobuf.FileDescriptorSet` built by
//! [`file_descriptor_set`]), as the MCAP spec's well-known encodings list
//! it: Foxglove and Lichtblick decode it, and Python reads it with
//! `mcap-protobuf-support` or, faster, through `bench export`.
//!
//! Numbers: times (`t_s`, `wake_s`) are `double`, exactly the loop's values.
//! Currents and positions are `float` (IEEE single, 24-bit significand):
//! the rounding is at most 6·10⁻⁸ of the value, 0.06 nm at 1 mm and 30 nA
//! at 0.5 A, far below the capacitance probe's 40 nm noise (thesis
//! Chapter 5) and a 20-bit converter's step over ±1 mm (2 nm). `NaN` (no
//! reading, no excitation, open loop) is stored as `NaN`.

use crate::record::topics::{SampleRecord, SupervisorState};
use prost::Message as _;
use prost_types::field_descriptor_proto::{Label, Type};
use prost_types::{
    DescriptorProto, EnumDescriptorProto, EnumValueDescriptorProto, FieldDescriptorProto,
    FileDescriptorProto, FileDescriptorSet,
};

/// Most ticks in one `/bench/sample` block (51.2 ms at 5 kHz; blocks are
/// also closed at every chunk flush, every 50 ms).
pub const BLOCK_TICKS: usize = 256;

/// Length of one `/bench/envelope` bucket of loop time, s (200 Hz: 13 000
/// points over the default chirp, more than a plot shows, and 5 ms
/// resolution on a step that settles in 85 ms). Each envelope message costs
/// the writer about 1 µs (`benches/recorder.rs`): at 1 ms buckets the
/// envelope alone took 0.22 µs and 12 bytes per tick at 5 kHz.
pub const ENVELOPE_PERIOD_S: f64 = 5e-3;

/// The supervisor state as a protobuf enum (`bench.State`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, prost::Enumeration)]
#[repr(i32)]
pub enum State {
    /// Amplifier disabled, 0 A.
    Disabled = 0,
    /// Amplifier enabled, no job output applied yet.
    Enabled = 1,
    /// A job drives the command.
    Running = 2,
    /// A fault latched.
    Faulted = 3,
}

impl From<SupervisorState> for State {
    fn from(s: SupervisorState) -> Self {
        match s {
            SupervisorState::Disabled => Self::Disabled,
            SupervisorState::Enabled => Self::Enabled,
            SupervisorState::Running => Self::Running,
            SupervisorState::Faulted => Self::Faulted,
        }
    }
}

impl From<State> for SupervisorState {
    fn from(s: State) -> Self {
        match s {
            State::Disabled => Self::Disabled,
            State::Enabled => Self::Enabled,
            State::Running => Self::Running,
            State::Faulted => Self::Faulted,
        }
    }
}

/// `/bench/sample`, schema `bench.SampleBlock`: consecutive ticks
/// `first_tick, first_tick + 1, …` as columns of equal length (one entry
/// per tick). The message's log time is its first tick's.
#[derive(Clone, PartialEq, prost::Message, serde::Serialize)]
pub struct SampleBlock {
    /// Tick index of the first entry, ticks (0-based since the loop started).
    #[prost(uint64, tag = "1")]
    pub first_tick: u64,
    /// Loop time of each tick, s (as [`SampleRecord::t_s`]).
    #[prost(double, repeated, tag = "2")]
    pub t_s: Vec<f64>,
    /// When each tick woke, s (as [`SampleRecord::wake_s`]).
    #[prost(double, repeated, tag = "3")]
    pub wake_s: Vec<f64>,
    /// Current commanded to the amplifier, A (after limits).
    #[prost(float, repeated, tag = "4")]
    pub current_command_a: Vec<f32>,
    /// Probe reading, m (`NaN`: none).
    #[prost(float, repeated, tag = "5")]
    pub position_m: Vec<f32>,
    /// Excitation part of the command, A (`NaN`: none runs).
    #[prost(float, repeated, tag = "6")]
    pub excitation_a: Vec<f32>,
    /// Position setpoint, m (`NaN`: open loop).
    #[prost(float, repeated, tag = "7")]
    pub setpoint_m: Vec<f32>,
    /// Supervisor state at the end of each tick.
    #[prost(enumeration = "State", repeated, tag = "8")]
    #[serde(serialize_with = "state_names")]
    pub state: Vec<i32>,
    /// Probe reported out of range.
    #[prost(bool, repeated, tag = "9")]
    pub out_of_range: Vec<bool>,
}

impl SampleBlock {
    /// An empty block with room for [`BLOCK_TICKS`] ticks (allocated once;
    /// [`clear`](Self::clear) keeps the room).
    pub fn with_capacity() -> Self {
        Self {
            first_tick: 0,
            t_s: Vec::with_capacity(BLOCK_TICKS),
            wake_s: Vec::with_capacity(BLOCK_TICKS),
            current_command_a: Vec::with_capacity(BLOCK_TICKS),
            position_m: Vec::with_capacity(BLOCK_TICKS),
            excitation_a: Vec::with_capacity(BLOCK_TICKS),
            setpoint_m: Vec::with_capacity(BLOCK_TICKS),
            state: Vec::with_capacity(BLOCK_TICKS),
            out_of_range: Vec::with_capacity(BLOCK_TICKS),
        }
    }

    /// Ticks held.
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    /// No tick held.
    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// Empties the block, keeping its room.
    pub fn clear(&mut self) {
        self.t_s.clear();
        self.wake_s.clear();
        self.current_command_a.clear();
        self.position_m.clear();
        self.excitation_a.clear();
        self.setpoint_m.clear();
        self.state.clear();
        self.out_of_range.clear();
    }

    /// Appends one tick. The caller keeps ticks consecutive (a tick that
    /// does not follow the last one starts a new block).
    pub fn push(&mut self, s: &SampleRecord) {
        if self.is_empty() {
            self.first_tick = s.tick;
        }
        self.t_s.push(s.t_s);
        self.wake_s.push(s.wake_s);
        self.current_command_a.push(s.current_command_a as f32);
        self.position_m.push(s.position_m as f32);
        self.excitation_a.push(s.excitation_a as f32);
        self.setpoint_m.push(s.setpoint_m as f32);
        self.state.push(State::from(s.state) as i32);
        self.out_of_range.push(s.out_of_range);
    }

    /// The tick the next pushed sample must have to join this block.
    pub fn next_tick(&self) -> u64 {
        self.first_tick + self.len() as u64
    }

    /// The ticks as records (`f32` columns widened back to `f64`).
    ///
    /// # Errors
    /// The first column whose length differs from `t_s`, or an unknown
    /// state value.
    pub fn records(&self) -> Result<Vec<SampleRecord>, String> {
        let n = self.t_s.len();
        for (name, len) in [
            ("wake_s", self.wake_s.len()),
            ("current_command_a", self.current_command_a.len()),
            ("position_m", self.position_m.len()),
            ("excitation_a", self.excitation_a.len()),
            ("setpoint_m", self.setpoint_m.len()),
            ("state", self.state.len()),
            ("out_of_range", self.out_of_range.len()),
        ] {
            if len != n {
                return Err(format!("column {name} has {len} entries, t_s has {n}"));
            }
        }
        (0..n)
            .map(|i| {
                let state = State::try_from(self.state[i])
                    .map_err(|_| format!("state {} is not a bench.State", self.state[i]))?;
                Ok(SampleRecord {
                    tick: self.first_tick + i as u64,
                    t_s: self.t_s[i],
                    wake_s: self.wake_s[i],
                    current_command_a: f64::from(self.current_command_a[i]),
                    position_m: f64::from(self.position_m[i]),
                    excitation_a: f64::from(self.excitation_a[i]),
                    setpoint_m: f64::from(self.setpoint_m[i]),
                    state: state.into(),
                    out_of_range: self.out_of_range[i],
                })
            })
            .collect()
    }
}

/// `/bench/envelope`, schema `bench.Envelope`: the samples of one
/// [`ENVELOPE_PERIOD_S`] bucket of loop time reduced to their extremes,
/// for plotting a whole run against time (Foxglove's Plot panel:
/// `/bench/envelope.position_max_m` and `.position_min_m`). The message's
/// log time is its first tick's. Extremes ignore `NaN`; a bucket without a
/// reading has `NaN` extremes.
#[derive(Clone, PartialEq, prost::Message, serde::Serialize)]
pub struct Envelope {
    /// Tick index of the bucket's first tick.
    #[prost(uint64, tag = "1")]
    pub first_tick: u64,
    /// Ticks in the bucket.
    #[prost(uint32, tag = "2")]
    pub ticks: u32,
    /// Loop time of the bucket's first tick, s.
    #[prost(double, tag = "3")]
    pub t_s: f64,
    /// Smallest probe reading, m.
    #[prost(float, tag = "4")]
    pub position_min_m: f32,
    /// Largest probe reading, m.
    #[prost(float, tag = "5")]
    pub position_max_m: f32,
    /// Smallest commanded current, A.
    #[prost(float, tag = "6")]
    pub current_command_min_a: f32,
    /// Largest commanded current, A.
    #[prost(float, tag = "7")]
    pub current_command_max_a: f32,
    /// Position setpoint at the bucket's last tick, m (`NaN`: open loop).
    #[prost(float, tag = "8")]
    pub setpoint_m: f32,
    /// Supervisor state at the bucket's last tick.
    #[prost(enumeration = "State", tag = "9")]
    #[serde(serialize_with = "state_name")]
    pub state: i32,
}

/// The [`SupervisorState::as_str`] name of a `bench.State` value
/// (`"unknown"` for a value outside the enum).
fn name_of(v: i32) -> &'static str {
    State::try_from(v).map_or("unknown", |s| SupervisorState::from(s).as_str())
}

fn state_name<S: serde::Serializer>(v: &i32, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(name_of(*v))
}

fn state_names<S: serde::Serializer>(v: &[i32], s: S) -> Result<S::Ok, S::Error> {
    s.collect_seq(v.iter().map(|x| name_of(*x)))
}

/// Builds [`Envelope`]s from consecutive samples.
#[derive(Debug, Default)]
pub struct EnvelopeBuilder {
    current: Option<(i64, Envelope)>,
}

impl EnvelopeBuilder {
    /// Adds one sample; returns the finished bucket when `s` starts a new
    /// one.
    pub fn push(&mut self, s: &SampleRecord) -> Option<Envelope> {
        // The nudge keeps a tick at a bucket's start (t = k × 5 ms, computed
        // as tick × period with rounding) in that bucket.
        let bucket = (s.t_s / ENVELOPE_PERIOD_S + 1e-6).floor() as i64;
        let done = match &self.current {
            Some((b, _)) if *b == bucket => None,
            _ => self.current.take().map(|c| c.1),
        };
        let (_, e) = self.current.get_or_insert((
            bucket,
            Envelope {
                first_tick: s.tick,
                ticks: 0,
                t_s: s.t_s,
                position_min_m: f32::NAN,
                position_max_m: f32::NAN,
                current_command_min_a: f32::NAN,
                current_command_max_a: f32::NAN,
                setpoint_m: f32::NAN,
                state: 0,
            },
        ));
        let p = s.position_m as f32;
        let c = s.current_command_a as f32;
        // f32::min/max return the other operand when one is NaN.
        e.position_min_m = e.position_min_m.min(p);
        e.position_max_m = e.position_max_m.max(p);
        e.current_command_min_a = e.current_command_min_a.min(c);
        e.current_command_max_a = e.current_command_max_a.max(c);
        e.setpoint_m = s.setpoint_m as f32;
        e.state = State::from(s.state) as i32;
        e.ticks += 1;
        done
    }

    /// The bucket in progress, if any (at the end of a run).
    pub fn finish(&mut self) -> Option<Envelope> {
        self.current.take().map(|c| c.1)
    }
}

/// Schema name of the `/bench/sample` blocks.
pub const SCHEMA_SAMPLE_BLOCK: &str = "bench.SampleBlock";
/// Schema name of `/bench/envelope`.
pub const SCHEMA_ENVELOPE: &str = "bench.Envelope";

fn field(name: &str, number: i32, ty: Type, repeated: bool) -> FieldDescriptorProto {
    FieldDescriptorProto {
        name: Some(name.into()),
        number: Some(number),
        label: Some(if repeated {
            Label::Repeated
        } else {
            Label::Optional
        } as i32),
        r#type: Some(ty as i32),
        type_name: (ty == Type::Enum).then(|| ".bench.State".into()),
        json_name: Some(name.into()),
        ..Default::default()
    }
}

/// The `bench.proto` file descriptor: messages `bench.SampleBlock` and
/// `bench.Envelope`, enum `bench.State` (field names, numbers and types as
/// the structs above; `tests/cli/schemas.rs` decodes recorded messages with it).
pub fn file_descriptor() -> FileDescriptorProto {
    use Type::*;
    let sample = DescriptorProto {
        name: Some("SampleBlock".into()),
        field: vec![
            field("first_tick", 1, Uint64, false),
            field("t_s", 2, Double, true),
            field("wake_s", 3, Double, true),
            field("current_command_a", 4, Float, true),
            field("position_m", 5, Float, true),
            field("excitation_a", 6, Float, true),
            field("setpoint_m", 7, Float, true),
            field("state", 8, Enum, true),
            field("out_of_range", 9, Bool, true),
        ],
        ..Default::default()
    };
    let envelope = DescriptorProto {
        name: Some("Envelope".into()),
        field: vec![
            field("first_tick", 1, Uint64, false),
            field("ticks", 2, Uint32, false),
            field("t_s", 3, Double, false),
            field("position_min_m", 4, Float, false),
            field("position_max_m", 5, Float, false),
            field("current_command_min_a", 6, Float, false),
            field("current_command_max_a", 7, Float, false),
            field("setpoint_m", 8, Float, false),
            field("state", 9, Enum, false),
        ],
        ..Default::default()
    };
    let state = EnumDescriptorProto {
        name: Some("State".into()),
        value: SupervisorState::ALL
            .iter()
            .map(|s| EnumValueDescriptorProto {
                name: Some(s.as_str().to_uppercase()),
                number: Some(State::from(*s) as i32),
                options: None,
            })
            .collect(),
        ..Default::default()
    };
    FileDescriptorProto {
        name: Some("bench.proto".into()),
        package: Some("bench".into()),
        message_type: vec![sample, envelope],
        enum_type: vec![state],
        syntax: Some("proto3".into()),
        ..Default::default()
    }
}

/// The MCAP schema data of both protobuf channels: the serialized
/// `FileDescriptorSet` holding [`file_descriptor`].
pub fn file_descriptor_set() -> Vec<u8> {
    FileDescriptorSet {
        file: vec![file_descriptor()],
    }
    .encode_to_vec()
}

/// Decodes a `/bench/sample` block payload into its records.
///
/// # Errors
/// Why the payload is not a `bench.SampleBlock`.
pub fn decode_block(data: &[u8]) -> Result<Vec<SampleRecord>, String> {
    SampleBlock::decode(data)
        .map_err(|e| format!("not a bench.SampleBlock: {e}"))?
        .records()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(tick: u64) -> SampleRecord {
        SampleRecord {
            tick,
            t_s: tick as f64 * 2e-4,
            wake_s: tick as f64 * 2e-4 + 1.7e-5,
            current_command_a: 0.123_456_789 * tick as f64,
            position_m: if tick == 3 {
                f64::NAN
            } else {
                1e-4 + 1e-9 * tick as f64
            },
            excitation_a: f64::NAN,
            setpoint_m: 5e-5,
            state: if tick > 4 {
                SupervisorState::Faulted
            } else {
                SupervisorState::Running
            },
            out_of_range: tick == 2,
        }
    }

    #[test]
    fn block_round_trips_within_single_precision() {
        let mut b = SampleBlock::with_capacity();
        for k in 10..20 {
            b.push(&rec(k));
        }
        let back = decode_block(&b.encode_to_vec()).unwrap();
        assert_eq!(back.len(), 10);
        for (k, r) in (10..20).zip(&back) {
            let want = rec(k);
            assert_eq!(r.tick, k);
            assert_eq!(r.t_s, want.t_s);
            assert_eq!(r.wake_s, want.wake_s);
            for (got, want) in [
                (r.current_command_a, want.current_command_a),
                (r.position_m, want.position_m),
                (r.setpoint_m, want.setpoint_m),
            ] {
                // IEEE single: relative rounding at most 2^-24.
                assert!(
                    (got - want).abs() <= want.abs() * 2f64.powi(-24),
                    "{got} {want}"
                );
            }
            assert!(r.excitation_a.is_nan());
            assert_eq!(r.state, want.state);
            assert_eq!(r.out_of_range, want.out_of_range);
        }
    }

    #[test]
    fn ragged_or_garbage_blocks_are_refused() {
        let mut b = SampleBlock::with_capacity();
        b.push(&rec(1));
        b.push(&rec(2));
        b.position_m.pop();
        let e = decode_block(&b.encode_to_vec()).unwrap_err();
        assert!(e.contains("position_m"), "{e}");
        assert!(decode_block(&[0xff, 0xff, 0xff]).is_err());
        let mut b = SampleBlock::with_capacity();
        b.push(&rec(1));
        b.state[0] = 9;
        assert!(decode_block(&b.encode_to_vec())
            .unwrap_err()
            .contains("state"));
    }

    #[test]
    fn envelope_holds_the_extremes_of_each_bucket() {
        // 1 kHz: five ticks per 5 ms bucket; position a ramp with one NaN.
        let mut env = EnvelopeBuilder::default();
        let mut out = Vec::new();
        for k in 0..23u64 {
            let mut s = rec(k);
            s.t_s = k as f64 * 1e-3;
            s.position_m = if k == 7 { f64::NAN } else { k as f64 * 1e-6 };
            s.current_command_a = -(k as f64) * 0.01;
            out.extend(env.push(&s));
        }
        out.extend(env.finish());
        assert_eq!(out.len(), 5);
        assert_eq!(
            out.iter().map(|e| e.ticks).collect::<Vec<_>>(),
            [5, 5, 5, 5, 3]
        );
        let e = &out[1]; // ticks 5..=9, tick 7 without a reading
        assert_eq!(e.first_tick, 5);
        assert_eq!(e.position_min_m, 5e-6_f32);
        assert_eq!(e.position_max_m, 9e-6_f32);
        assert_eq!(e.current_command_min_a, -0.09_f32);
        assert_eq!(e.current_command_max_a, -0.05_f32);
        assert_eq!(e.state, State::Faulted as i32);
    }
}
