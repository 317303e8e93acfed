//! The CAN frame map: where each value sits in the SYNC, command and sample
//! frames ([`CommandMap`], [`SampleMap`], [`FieldSpec`]), their payloads
//! and counter arithmetic ([`seq_delta`]). Shared by the host backend
//! (`bench_hal::can`, which adds the `[backend.can]` table and the
//! validation of a map's keys) and the CAN emulator; the default map is
//! described in `bench_hal::can`. Fixed buffers only: no allocation.
//!
//! Layer rule: may use nothing of the crate.

use crate::SampleFlags;
use serde::{Deserialize, Serialize};

/// CANopen SYNC id.
pub const DEFAULT_SYNC_ID: u32 = 0x080;
/// CANopen RPDO1 base: the default command id is `0x200 + node_id`.
pub const RPDO1_BASE: u32 = 0x200;
/// CANopen TPDO1 base: the default sample id is `0x180 + node_id`.
pub const TPDO1_BASE: u32 = 0x180;

/// Status bit: the probe is out of range.
pub const STATUS_OUT_OF_RANGE: u64 = 1 << 0;
/// Status bit: the amplifier is enabled.
pub const STATUS_AMPLIFIER_ENABLED: u64 = 1 << 1;
/// Status bit: the amplifier reports a fault.
pub const STATUS_AMPLIFIER_FAULT: u64 = 1 << 2;
/// Status bit: the command in force did not answer the previous sample
/// (see [`SampleFlags::command_late`]).
pub const STATUS_COMMAND_LATE: u64 = 1 << 3;
/// Status bits 4–7 carry the latched fault code ([`DeviceFault::code`](crate::DeviceFault::code)).
pub const STATUS_FAULT_CODE_SHIFT: u32 = 4;
/// Control bit: enable request (the device enables on its rising edge).
pub const CONTROL_ENABLE: u64 = 1 << 0;

/// The data bytes of a classic CAN frame.
pub const CAN_DATA_BYTES: usize = 8;

/// Byte order of a field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Endian {
    /// Least significant byte first (CANopen).
    #[default]
    Little,
    /// Most significant byte first.
    Big,
}

fn default_scale() -> f64 {
    1.0
}

/// Where and how one value sits in a frame's data bytes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FieldSpec {
    /// First data byte, 0..=7.
    pub offset_byte: u8,
    /// Width, bits: 8, 16, 24 or 32.
    pub width_bits: u8,
    /// Two's complement (`true`) or unsigned.
    #[serde(default)]
    pub signed: bool,
    /// SI unit per LSB (A, m); 1 for integer fields. Negative flips the sign.
    #[serde(default = "default_scale")]
    pub scale: f64,
    /// Byte order.
    #[serde(default)]
    pub endian: Endian,
}

impl FieldSpec {
    /// A little-endian field.
    pub const fn le(offset_byte: u8, width_bits: u8, signed: bool, scale: f64) -> Self {
        Self {
            offset_byte,
            width_bits,
            signed,
            scale,
            endian: Endian::Little,
        }
    }

    /// The data bytes the field occupies (half-open).
    pub fn byte_range(&self) -> core::ops::Range<usize> {
        let o = self.offset_byte as usize;
        o..o + self.width_bits as usize / 8
    }

    fn mask(&self) -> u64 {
        (1u64 << self.width_bits) - 1
    }

    /// Smallest raw code a value encodes to (the code below it, for signed
    /// fields, is reserved for NaN).
    pub fn raw_min(&self) -> i64 {
        if self.signed {
            -(1i64 << (self.width_bits - 1)) + 1
        } else {
            0
        }
    }

    /// Largest raw code.
    pub fn raw_max(&self) -> i64 {
        if self.signed {
            (1i64 << (self.width_bits - 1)) - 1
        } else {
            (1i64 << self.width_bits) - 1
        }
    }

    fn write(&self, bits: u64, data: &mut [u8; CAN_DATA_BYTES]) {
        let n = self.width_bits as usize / 8;
        let o = self.offset_byte as usize;
        for i in 0..n {
            let b = (bits >> (8 * i)) as u8;
            match self.endian {
                Endian::Little => data[o + i] = b,
                Endian::Big => data[o + n - 1 - i] = b,
            }
        }
    }

    fn read(&self, data: &[u8; CAN_DATA_BYTES]) -> u64 {
        let n = self.width_bits as usize / 8;
        let o = self.offset_byte as usize;
        let mut bits = 0u64;
        for i in 0..n {
            let b = match self.endian {
                Endian::Little => data[o + i],
                Endian::Big => data[o + n - 1 - i],
            };
            bits |= u64::from(b) << (8 * i);
        }
        bits
    }

    /// Writes `value` (SI units) as `round(value / scale)`, saturated at
    /// [`raw_min`](Self::raw_min)..=[`raw_max`](Self::raw_max); NaN writes
    /// the reserved code of a signed field (0 for an unsigned one).
    pub fn encode(&self, value: f64, data: &mut [u8; CAN_DATA_BYTES]) {
        let raw = if value.is_nan() {
            if self.signed {
                -(1i64 << (self.width_bits - 1))
            } else {
                0
            }
        } else {
            // `as` saturates, and the clamp keeps the result in range.
            (libm::round(value / self.scale) as i64).clamp(self.raw_min(), self.raw_max())
        };
        self.write(raw as u64 & self.mask(), data);
    }

    /// Reads the field as a value in SI units (NaN for the reserved code of
    /// a signed field).
    pub fn decode(&self, data: &[u8; CAN_DATA_BYTES]) -> f64 {
        let bits = self.read(data);
        if self.signed {
            let shift = 64 - u32::from(self.width_bits);
            let raw = ((bits << shift) as i64) >> shift;
            if raw == -(1i64 << (self.width_bits - 1)) {
                f64::NAN
            } else {
                raw as f64 * self.scale
            }
        } else {
            bits as f64 * self.scale
        }
    }

    /// Writes the low `width_bits` of `bits` (counters wrap, no scaling).
    pub fn encode_bits(&self, bits: u64, data: &mut [u8; CAN_DATA_BYTES]) {
        self.write(bits & self.mask(), data);
    }

    /// Reads the field's raw bits.
    pub fn decode_bits(&self, data: &[u8; CAN_DATA_BYTES]) -> u64 {
        self.read(data)
    }
}

/// Signed difference `raw − prev_raw` of two `width_bits` counters, in
/// `[−2^(w−1), 2^(w−1))`: 1 for the next sample, `k > 1` after `k − 1` lost
/// ones, ≤ 0 for a repeated or stale one.
pub fn seq_delta(prev_raw: u64, raw: u64, width_bits: u8) -> i64 {
    let w = u32::from(width_bits);
    let d = raw.wrapping_sub(prev_raw) & ((1u64 << w) - 1);
    if d >= 1u64 << (w - 1) {
        d as i64 - (1i64 << w)
    } else {
        d as i64
    }
}

fn frame_len(fields: &[&FieldSpec]) -> usize {
    fields.iter().map(|f| f.byte_range().end).max().unwrap_or(0)
}

/// A frame shorter than its map: `len` bytes where the map needs `need`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ShortFrame {
    /// `"command"` or `"sample"`.
    pub frame: &'static str,
    /// Bytes received.
    pub len: usize,
    /// Bytes the map needs.
    pub need: usize,
}

impl core::fmt::Display for ShortFrame {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "{} frame of {} bytes, the map needs {}",
            self.frame, self.len, self.need
        )
    }
}

fn padded(data: &[u8], need: usize, frame: &'static str) -> Result<[u8; 8], ShortFrame> {
    if data.len() < need {
        return Err(ShortFrame {
            frame,
            len: data.len(),
            need,
        });
    }
    let mut d = [0u8; CAN_DATA_BYTES];
    let n = data.len().min(CAN_DATA_BYTES);
    d[..n].copy_from_slice(&data[..n]);
    Ok(d)
}

/// Layout of the command frame (RPDO1, host → device).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CommandMap {
    /// Frame id; default `0x200 + node_id`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<u32>,
    /// Current demand, A (default `i32` at byte 0, 1e-6 A/LSB).
    pub current: FieldSpec,
    /// Low bits of the sample counter this command answers (default `u16`
    /// at byte 4).
    pub answers_seq: FieldSpec,
    /// Control bits, bit 0 enable (default `u8` at byte 6).
    pub control: FieldSpec,
}

impl Default for CommandMap {
    fn default() -> Self {
        Self {
            id: None,
            current: FieldSpec::le(0, 32, true, 1e-6),
            answers_seq: FieldSpec::le(4, 16, false, 1.0),
            control: FieldSpec::le(6, 8, false, 1.0),
        }
    }
}

/// The values a command frame carries.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CommandPayload {
    /// Current demand, A.
    pub current_a: f64,
    /// Sample counter answered (device numbering; only the low bits travel).
    pub answers_seq: u64,
    /// Enable request (control bit 0).
    pub enable: bool,
}

impl CommandMap {
    /// The frame id for `node_id`.
    pub fn resolved_id(&self, node_id: u8) -> u32 {
        self.id.unwrap_or(RPDO1_BASE + u32::from(node_id))
    }

    /// Data length of the frame: the end of the last mapped byte.
    pub fn len(&self) -> usize {
        frame_len(&[&self.current, &self.answers_seq, &self.control])
    }

    /// Whether the map has no bytes (never, once validated).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Encodes a command: the data bytes (unused ones 0); send the first
    /// [`len`](Self::len). Saturates a current beyond the field's range.
    pub fn encode(&self, p: &CommandPayload) -> [u8; CAN_DATA_BYTES] {
        let mut d = [0u8; CAN_DATA_BYTES];
        self.current.encode(p.current_a, &mut d);
        self.answers_seq.encode_bits(p.answers_seq, &mut d);
        self.control
            .encode_bits(if p.enable { CONTROL_ENABLE } else { 0 }, &mut d);
        d
    }

    /// Decodes a command frame's data.
    ///
    /// # Errors
    /// [`ShortFrame`] if `data` is shorter than [`len`](Self::len).
    pub fn decode(&self, data: &[u8]) -> Result<CommandPayload, ShortFrame> {
        let d = padded(data, self.len(), "command")?;
        Ok(CommandPayload {
            current_a: self.current.decode(&d),
            answers_seq: self.answers_seq.decode_bits(&d),
            enable: self.control.decode_bits(&d) & CONTROL_ENABLE != 0,
        })
    }
}

/// Layout of the sample frame (TPDO1, device → host).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SampleMap {
    /// Frame id; default `0x180 + node_id`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<u32>,
    /// Probe reading, m (default `i32` at byte 0, 1e-10 m/LSB).
    pub position: FieldSpec,
    /// Sample counter (default `u16` at byte 4).
    pub seq: FieldSpec,
    /// Status bits (default `u8` at byte 6; see the module docs).
    pub status: FieldSpec,
    /// Measured amplifier current, A, if the device sends it (default: not
    /// mapped, `Sample::measured_current_a` is NaN).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measured_current: Option<FieldSpec>,
}

impl Default for SampleMap {
    fn default() -> Self {
        Self {
            id: None,
            position: FieldSpec::le(0, 32, true, 1e-10),
            seq: FieldSpec::le(4, 16, false, 1.0),
            status: FieldSpec::le(6, 8, false, 1.0),
            measured_current: None,
        }
    }
}

/// The values a sample frame carries.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SamplePayload {
    /// Probe reading, m.
    pub position_m: f64,
    /// Sample counter (device numbering; only the low bits travel).
    pub seq: u64,
    /// Status flags.
    pub flags: SampleFlags,
    /// Latched fault code ([`DeviceFault::code`](crate::DeviceFault::code), 0 for none).
    pub fault_code: u8,
    /// Measured current, A (NaN when not mapped).
    pub measured_current_a: f64,
}

impl SampleMap {
    /// The frame id for `node_id`.
    pub fn resolved_id(&self, node_id: u8) -> u32 {
        self.id.unwrap_or(TPDO1_BASE + u32::from(node_id))
    }

    /// Data length of the frame: the end of the last mapped byte.
    pub fn len(&self) -> usize {
        match &self.measured_current {
            Some(m) => frame_len(&[&self.position, &self.seq, &self.status, m]),
            None => frame_len(&[&self.position, &self.seq, &self.status]),
        }
    }

    /// Whether the map has no bytes (never, once validated).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Encodes a sample: the data bytes (unused ones 0); send the first
    /// [`len`](Self::len). Saturates a position beyond the field's range.
    pub fn encode(&self, p: &SamplePayload) -> [u8; CAN_DATA_BYTES] {
        let mut d = [0u8; CAN_DATA_BYTES];
        self.position.encode(p.position_m, &mut d);
        self.seq.encode_bits(p.seq, &mut d);
        let f = p.flags;
        let mut status = u64::from(p.fault_code & 0x0F) << STATUS_FAULT_CODE_SHIFT;
        if f.out_of_range {
            status |= STATUS_OUT_OF_RANGE;
        }
        if f.amplifier_enabled {
            status |= STATUS_AMPLIFIER_ENABLED;
        }
        if f.amplifier_fault {
            status |= STATUS_AMPLIFIER_FAULT;
        }
        if f.command_late {
            status |= STATUS_COMMAND_LATE;
        }
        self.status.encode_bits(status, &mut d);
        if let Some(m) = &self.measured_current {
            m.encode(p.measured_current_a, &mut d);
        }
        d
    }

    /// Decodes a sample frame's data.
    ///
    /// # Errors
    /// [`ShortFrame`] if `data` is shorter than [`len`](Self::len).
    pub fn decode(&self, data: &[u8]) -> Result<SamplePayload, ShortFrame> {
        let d = padded(data, self.len(), "sample")?;
        let status = self.status.decode_bits(&d);
        Ok(SamplePayload {
            position_m: self.position.decode(&d),
            seq: self.seq.decode_bits(&d),
            flags: SampleFlags {
                out_of_range: status & STATUS_OUT_OF_RANGE != 0,
                amplifier_enabled: status & STATUS_AMPLIFIER_ENABLED != 0,
                amplifier_fault: status & STATUS_AMPLIFIER_FAULT != 0,
                command_late: status & STATUS_COMMAND_LATE != 0,
            },
            fault_code: ((status >> STATUS_FAULT_CODE_SHIFT) & 0x0F) as u8,
            measured_current_a: self
                .measured_current
                .as_ref()
                .map_or(f64::NAN, |m| m.decode(&d)),
        })
    }
}
