//! The SocketCAN backend ([`CanStage`]) and the CAN device emulator
//! ([`run_emulator`]), over the `socketcan` crate.
//!
//! The device is a CANopen-style node: no handshake, three frames, each laid
//! out by a configurable **frame map** (`[backend.can]`, [`CanConfig`]).
//!
//! # Default frame map (node `n`, default 1)
//!
//! All fields little-endian; byte ranges are half-open.
//!
//! | frame | id | bytes | width | type | scale | unit | key |
//! |---|---|---|---|---|---|---|---|
//! | SYNC (host → device) | `0x080` | — (DLC 0) | | | | | `sync_id` |
//! | command, RPDO1 (host → device) | `0x200 + n` | 0..4 | 32 | `i32` | 1e-6 | A | `command.current` |
//! | | | 4..6 | 16 | `u16` | 1 | sample seq (low bits) | `command.answers_seq` |
//! | | | 6..7 | 8 | `u8` | bit 0: enable | | `command.control` |
//! | sample, TPDO1 (device → host) | `0x180 + n` | 0..4 | 32 | `i32` | 1e-10 | m | `sample.position` |
//! | | | 4..6 | 16 | `u16` | 1 | sample counter | `sample.seq` |
//! | | | 6..7 | 8 | `u8` | status bits | | `sample.status` |
//! | | | — | | (optional) | | A | `sample.measured_current` |
//!
//! Frames are sent with the smallest DLC that holds every mapped field (7 for
//! the defaults); a received frame shorter than that is refused
//! ([`CanError::ShortFrame`], kind `Protocol`).
//!
//! * **Status byte**: bit 0 probe out of range, bit 1 amplifier enabled,
//!   bit 2 amplifier fault, bits 4–7 the latched fault code
//!   ([`DeviceFault::code`]: 1 watchdog, 2 bad command).
//! * **Control byte**: bit 0 enable request. The device **enables on the
//!   rising edge** of the bit (with 0 A, clearing a latched fault) and
//!   disables whenever it reads 0; a latched fault therefore survives
//!   commands that keep the bit set, and only a fresh 0 → 1 edge
//!   ([`Stage::enable`]) clears it, as with a CANopen fault reset.
//! * **Scaled fields** (`current`, `position`, `measured_current`):
//!   `raw = round(value / scale)`. Encoding **saturates** at the field's
//!   range: signed fields at `±(2^(w−1) − 1)`, unsigned at `[0, 2^w − 1]`.
//!   The most negative code of a signed field, `−2^(w−1)`, is reserved for
//!   "no value": NaN encodes to it and it decodes to NaN (an unsigned field
//!   encodes NaN as 0). So a 1e-6 A/LSB `i32` carries ±2147 A and a
//!   1e-10 m/LSB `i32` carries ±0.21 m.
//! * **Integer fields** (`answers_seq`, `seq`, `status`, `control`) must be
//!   unsigned with scale 1; counters wrap modulo `2^w`. The host unwraps the
//!   sample counter into the monotonic [`Sample::seq`] (consecutive from 0
//!   at the first sample read after [`Stage::configure`]; a jump is a gap,
//!   counted in [`CanStats`]), and maps [`Command::answers_seq`] back to
//!   the device's counter. With a `w`-bit counter, gaps of `2^(w−1)` samples
//!   or more cannot be told from stale frames.
//!
//! A field table given in the config replaces the default one whole:
//! `offset_byte` and `width_bits` (8, 16, 24 or 32) are required, `signed`
//! (false), `scale` (1) and `endian` (`"little"` | `"big"`) are optional.
//! [`CanConfig::validate`] refuses fields beyond the 8 data bytes, fields
//! overlapping within a frame, widths other than 8/16/24/32, zero or
//! non-finite scales, ids beyond 11 bits (29 with `extended = true`),
//! duplicate ids and node ids outside 1..=127, naming the key.
//!
//! # Clock
//!
//! * `sync_producer = true` (default): the host is the SYNC producer. Each
//!   [`Stage::read_sample`] sends one SYNC and waits (bounded) for the
//!   sample it triggers; the device samples **on SYNC**, so the host's
//!   deadlines pace the loop: [`Clock::Host`].
//! * `sync_producer = false`: the device samples on its own timer at the
//!   configured period and [`Stage::read_sample`] waits for the next sample
//!   frame: [`Clock::Device`]. The device's rate is set on the device
//!   (CANopen has no handshake); the host takes the requested period as the
//!   device's.
//!
//! In both modes `read_sample` first drains what is queued on the socket:
//! with SYNC, queued samples answer earlier SYNCs and are discarded as late;
//! without, the newest queued sample is returned at once (older ones count
//! as gaps), so a slow tick never leaves the loop behind the device.
//! The wait is bounded by `sample_timeout_ms` (default: two periods, at
//! least 1 ms) and ends in [`CanError::Timeout`].
//!
//! # Errors on the bus
//!
//! The host socket accepts every SocketCAN error class (error-frame mask
//! `CAN_ERR_MASK`) and, on a real CAN socket, only the sample id.
//!
//! * A **bus-off** error frame is a link fault: [`CanError::BusOff`], kind
//!   `Link`, latched until the next [`Stage::configure`].
//! * Any other error frame (protocol violation, CRC, transceiver, missing
//!   ACK, controller overflow/warning/passive, TX timeout) met while waiting
//!   for a sample makes that read fail with [`CanError::ErrorFrame`], kind
//!   `Crc`: a bad sample, which the loop's link supervision counts.
//!   Lost-arbitration, restart, error-counter and "back to error active"
//!   reports are counted only.
//! * Socket I/O errors are kind `Link` (`NotFound` for a missing interface).
//! * A sample reporting an amplifier fault while the host has the amplifier
//!   enabled fails the read with [`CanError::DeviceFault`], kind
//!   `AmplifierFault` (the device's watchdog or command check tripped).
//!
//! Counters are in [`CanStage::stats`]. `read_sample` and `write_command`
//! do not allocate or log; every wait is bounded (`ppoll` with a deadline,
//! non-blocking socket).
//!
//! # Watchdog
//!
//! The device drops the current to 0 A, disables the amplifier and latches
//! [`DeviceFault::Watchdog`] when no valid command has arrived for
//! `[emulator] watchdog_ms` while enabled. The emulator checks it on every
//! sample tick (SYNC or timer) **and** from its own clock when ticks stop (a
//! host that dies stops sending SYNC too;
//! [`DeviceCore::check_watchdog`], the plant does not advance), so the
//! current is 0 within `watchdog_ms` + one period of the last valid command
//! in both modes. Only an enable edge clears the latch.
//!
//! # Emulator fault injection ([`LinkFault`])
//!
//! Bit flips: an error frame (protocol violation, CRC sequence) replaces the
//! data frame, as the bus CRC would have rejected it (the bit count does not
//! matter on CAN). Drop: the next N sample frames are not sent (the plant
//! and counter go on). Delay: every outgoing frame is held back. Stall: no
//! sampling, no sending, no command handling and no watchdog for the
//! duration, as on a hung microcontroller. Disconnect: a bus-off error frame,
//! then silence (received frames are ignored; the device's watchdog trips).
//! Error frames written by a program are delivered as error frames by a
//! virtual bus (`vcan`) and a socket pair, not by a physical bus: inject
//! faults on `vcan`.

use crate::device::{
    monotonic_ns, sleep_until_ns, DeviceCore, DeviceFault, EmulatorStatus, LinkFault,
    ScheduledLinkFault,
};
use crate::model::{positive, ParamError};
use crate::{Clock, Command, DeviceInfo, ErrorKind, Sample, SampleFlags, Stage};
use serde::{Deserialize, Serialize};
use socketcan::errors::{Location, ViolationTypes};
use socketcan::frame::{can_frame_default, CanErrorFrame};
pub use socketcan::CanSocket;
use socketcan::{
    CanDataFrame, CanFilter, CanFrame, EmbeddedFrame, ErrorCause, ExtendedId, Frame, Socket,
    SocketOptions, StandardId,
};
use std::collections::VecDeque;
use std::io;
use std::os::fd::{AsRawFd, RawFd};
use std::sync::atomic::{AtomicBool, Ordering};

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
/// Status bits 4–7 carry the latched fault code ([`DeviceFault::code`]).
pub const STATUS_FAULT_CODE_SHIFT: u32 = 4;
/// Control bit: enable request (the device enables on its rising edge).
pub const CONTROL_ENABLE: u64 = 1 << 0;

/// The data bytes of a classic CAN frame.
pub const CAN_DATA_BYTES: usize = 8;

const LINK_WAIT_MIN_NS: u64 = 100_000_000;
/// The emulator wakes at least this often to look at its stop flag.
const EMULATOR_POLL_NS: u64 = 10_000_000;

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
    pub fn byte_range(&self) -> std::ops::Range<usize> {
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

    /// Checks width, placement and scale; keys are `key.offset_byte`,
    /// `key.width_bits` and `key.scale`.
    ///
    /// # Errors
    /// The offending key with the reason.
    pub fn validate(&self, key: &str) -> Result<(), ParamError> {
        if !matches!(self.width_bits, 8 | 16 | 24 | 32) {
            return Err(ParamError::new(
                format!("{key}.width_bits"),
                format!("must be 8, 16, 24 or 32, got {}", self.width_bits),
            ));
        }
        let r = self.byte_range();
        if r.end > CAN_DATA_BYTES {
            return Err(ParamError::new(
                format!("{key}.offset_byte"),
                format!(
                    "bytes {}..{} do not fit in the {CAN_DATA_BYTES} data bytes of a CAN frame",
                    r.start, r.end
                ),
            ));
        }
        if !self.scale.is_finite() || self.scale == 0.0 {
            return Err(ParamError::new(
                format!("{key}.scale"),
                format!("must be finite and non-zero, got {}", self.scale),
            ));
        }
        Ok(())
    }

    fn validate_integer(&self, key: &str) -> Result<(), ParamError> {
        self.validate(key)?;
        if self.signed {
            return Err(ParamError::new(
                format!("{key}.signed"),
                "an integer field (counter or bits) must be unsigned",
            ));
        }
        if self.scale != 1.0 {
            return Err(ParamError::new(
                format!("{key}.scale"),
                format!(
                    "an integer field (counter or bits) has scale 1, got {}",
                    self.scale
                ),
            ));
        }
        Ok(())
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
            ((value / self.scale).round() as i64).clamp(self.raw_min(), self.raw_max())
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

fn check_overlap(prefix: &str, fields: &[(&str, &FieldSpec)]) -> Result<(), ParamError> {
    for (j, (kj, fj)) in fields.iter().enumerate() {
        for (ki, fi) in &fields[..j] {
            let (a, b) = (fi.byte_range(), fj.byte_range());
            if a.start < b.end && b.start < a.end {
                return Err(ParamError::new(
                    format!("{prefix}.{kj}"),
                    format!(
                        "bytes {}..{} overlap {prefix}.{ki} (bytes {}..{})",
                        b.start, b.end, a.start, a.end
                    ),
                ));
            }
        }
    }
    Ok(())
}

fn frame_len(fields: &[&FieldSpec]) -> usize {
    fields.iter().map(|f| f.byte_range().end).max().unwrap_or(0)
}

fn padded(data: &[u8], need: usize, frame: &'static str) -> Result<[u8; 8], CanError> {
    if data.len() < need {
        return Err(CanError::ShortFrame {
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

    /// Checks the fields, keys under `prefix` (e.g. `backend.can.command`).
    ///
    /// # Errors
    /// The first offending key with the reason.
    pub fn validate(&self, prefix: &str) -> Result<(), ParamError> {
        self.current.validate(&format!("{prefix}.current"))?;
        self.answers_seq
            .validate_integer(&format!("{prefix}.answers_seq"))?;
        self.control
            .validate_integer(&format!("{prefix}.control"))?;
        check_overlap(
            prefix,
            &[
                ("current", &self.current),
                ("answers_seq", &self.answers_seq),
                ("control", &self.control),
            ],
        )
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
    /// [`CanError::ShortFrame`] if `data` is shorter than [`len`](Self::len).
    pub fn decode(&self, data: &[u8]) -> Result<CommandPayload, CanError> {
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
    /// mapped, [`Sample::measured_current_a`] is NaN).
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
    /// Latched fault code ([`DeviceFault::code`], 0 for none).
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

    /// Checks the fields, keys under `prefix` (e.g. `backend.can.sample`).
    ///
    /// # Errors
    /// The first offending key with the reason.
    pub fn validate(&self, prefix: &str) -> Result<(), ParamError> {
        self.position.validate(&format!("{prefix}.position"))?;
        self.seq.validate_integer(&format!("{prefix}.seq"))?;
        self.status.validate_integer(&format!("{prefix}.status"))?;
        let mut fields = vec![
            ("position", &self.position),
            ("seq", &self.seq),
            ("status", &self.status),
        ];
        if let Some(m) = &self.measured_current {
            m.validate(&format!("{prefix}.measured_current"))?;
            fields.push(("measured_current", m));
        }
        check_overlap(prefix, &fields)
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
        self.status.encode_bits(status, &mut d);
        if let Some(m) = &self.measured_current {
            m.encode(p.measured_current_a, &mut d);
        }
        d
    }

    /// Decodes a sample frame's data.
    ///
    /// # Errors
    /// [`CanError::ShortFrame`] if `data` is shorter than [`len`](Self::len).
    pub fn decode(&self, data: &[u8]) -> Result<SamplePayload, CanError> {
        let d = padded(data, self.len(), "sample")?;
        let status = self.status.decode_bits(&d);
        Ok(SamplePayload {
            position_m: self.position.decode(&d),
            seq: self.seq.decode_bits(&d),
            flags: SampleFlags {
                out_of_range: status & STATUS_OUT_OF_RANGE != 0,
                amplifier_enabled: status & STATUS_AMPLIFIER_ENABLED != 0,
                amplifier_fault: status & STATUS_AMPLIFIER_FAULT != 0,
            },
            fault_code: ((status >> STATUS_FAULT_CODE_SHIFT) & 0x0F) as u8,
            measured_current_a: self
                .measured_current
                .as_ref()
                .map_or(f64::NAN, |m| m.decode(&d)),
        })
    }
}

fn default_interface() -> String {
    "can0".into()
}

/// The SocketCAN backend's configuration (the `[backend.can]` table). Every
/// key has a default: `interface = "can0"` alone is a complete table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CanConfig {
    /// CAN network interface (`can0`, `vcan0`).
    #[serde(default = "default_interface")]
    pub interface: String,
    /// CANopen node id of the device, 1..=127 (default 1).
    pub node_id: u8,
    /// All ids are 29-bit extended ids (default false: 11-bit).
    pub extended: bool,
    /// SYNC id (default 0x080).
    pub sync_id: u32,
    /// The host sends SYNC every tick and the device samples on it
    /// ([`Clock::Host`], default); false: the device samples on its own
    /// timer ([`Clock::Device`]).
    pub sync_producer: bool,
    /// Bound on the wait for a sample, ms (default: two periods, at least
    /// 1 ms).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sample_timeout_ms: Option<f64>,
    /// Amplifier peak current, A (CANopen has no handshake; default 9.98,
    /// the thesis bench).
    pub peak_current_a: f64,
    /// Actuator continuous current, A (default 2.34).
    pub continuous_current_a: f64,
    /// Probe half range, m (default 1e-3).
    pub probe_range_m: f64,
    /// Command frame layout.
    pub command: CommandMap,
    /// Sample frame layout.
    pub sample: SampleMap,
}

impl Default for CanConfig {
    fn default() -> Self {
        Self {
            interface: default_interface(),
            node_id: 1,
            extended: false,
            sync_id: DEFAULT_SYNC_ID,
            sync_producer: true,
            sample_timeout_ms: None,
            peak_current_a: 9.98,
            continuous_current_a: 2.34,
            probe_range_m: 1e-3,
            command: CommandMap::default(),
            sample: SampleMap::default(),
        }
    }
}

impl CanConfig {
    /// The default configuration on `interface`.
    pub fn on(interface: &str) -> Self {
        Self {
            interface: interface.into(),
            ..Self::default()
        }
    }

    /// Command frame id.
    pub fn command_id(&self) -> u32 {
        self.command.resolved_id(self.node_id)
    }

    /// Sample frame id.
    pub fn sample_id(&self) -> u32 {
        self.sample.resolved_id(self.node_id)
    }

    /// Bound on the wait for a sample at `period_ns`, ns.
    pub fn sample_timeout_ns(&self, period_ns: u64) -> u64 {
        match self.sample_timeout_ms {
            Some(ms) => (ms * 1e6).round() as u64,
            None => (2 * period_ns).max(1_000_000),
        }
    }

    /// Checks everything, keys under `prefix` (the CLI passes
    /// `"backend.can"`).
    ///
    /// # Errors
    /// The first offending key with the reason (overlaps and duplicate ids
    /// name both keys).
    pub fn validate(&self, prefix: &str) -> Result<(), ParamError> {
        let k = |name: &str| format!("{prefix}.{name}");
        if self.interface.is_empty() {
            return Err(ParamError::new(k("interface"), "must not be empty"));
        }
        if !(1..=127).contains(&self.node_id) {
            return Err(ParamError::new(
                k("node_id"),
                format!("must be 1..=127, got {}", self.node_id),
            ));
        }
        if let Some(t) = self.sample_timeout_ms {
            positive(&k("sample_timeout_ms"), t)?;
        }
        positive(&k("peak_current_a"), self.peak_current_a)?;
        positive(&k("continuous_current_a"), self.continuous_current_a)?;
        if self.continuous_current_a > self.peak_current_a {
            return Err(ParamError::new(
                k("continuous_current_a"),
                format!(
                    "{} A is above peak_current_a = {} A",
                    self.continuous_current_a, self.peak_current_a
                ),
            ));
        }
        positive(&k("probe_range_m"), self.probe_range_m)?;
        self.command.validate(&k("command"))?;
        self.sample.validate(&k("sample"))?;
        let max = if self.extended { 0x1FFF_FFFF } else { 0x7FF };
        let ids = [
            (k("sync_id"), self.sync_id),
            (k("command.id"), self.command_id()),
            (k("sample.id"), self.sample_id()),
        ];
        for (j, (kj, idj)) in ids.iter().enumerate() {
            if *idj > max {
                return Err(ParamError::new(
                    kj.clone(),
                    format!(
                        "0x{idj:X} is not a {} CAN id (max 0x{max:X}){}",
                        if self.extended { "29-bit" } else { "11-bit" },
                        if self.extended {
                            ""
                        } else {
                            "; set extended = true for 29-bit ids"
                        }
                    ),
                ));
            }
            for (ki, idi) in &ids[..j] {
                if idi == idj {
                    return Err(ParamError::new(
                        kj.clone(),
                        format!("0x{idj:X} is also {ki}: ids must be distinct"),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The SocketCAN id word (with the EFF flag for extended ids).
    fn id_word(&self, id: u32) -> u32 {
        if self.extended {
            id | libc::CAN_EFF_FLAG
        } else {
            id
        }
    }

    /// A data frame with this id and data, as the kernel's struct.
    fn raw_frame(&self, id: u32, data: &[u8]) -> libc::can_frame {
        let frame = if self.extended {
            ExtendedId::new(id).and_then(|i| CanDataFrame::new(i, data))
        } else {
            StandardId::new(id as u16).and_then(|i| CanDataFrame::new(i, data))
        };
        *frame
            .expect("a validated id and at most 8 data bytes make a frame")
            .as_ref()
    }

    /// A kernel filter passing exactly `id` (data frames, this id format).
    fn filter(&self, id: u32) -> CanFilter {
        let mask = if self.extended {
            libc::CAN_EFF_MASK
        } else {
            libc::CAN_SFF_MASK
        } | libc::CAN_EFF_FLAG
            | libc::CAN_RTR_FLAG;
        CanFilter::new(self.id_word(id), mask)
    }
}

/// Errors of the SocketCAN backend and emulator.
#[derive(Debug, thiserror::Error)]
pub enum CanError {
    /// The configuration is invalid.
    #[error("invalid CAN configuration: {0}")]
    Config(#[from] ParamError),
    /// The interface does not exist (or SocketCAN is unavailable).
    #[error("CAN interface `{interface}` not found ({source}); list interfaces with `ip link show type can` (or `type vcan`)")]
    NotFound {
        /// The interface name.
        interface: String,
        /// The OS error.
        source: io::Error,
    },
    /// A socket operation failed.
    #[error("CAN socket {op} failed: {source}")]
    Io {
        /// What was being done.
        op: &'static str,
        /// The OS error.
        source: io::Error,
    },
    /// No sample frame within the bounded wait.
    #[error("no sample frame within {waited_ns} ns")]
    Timeout {
        /// How long the read waited, ns.
        waited_ns: u64,
    },
    /// The configure-time link check got no sample.
    #[error("no sample frame 0x{sample_id:X} from node {node_id} on {interface} within {waited_ms} ms: is the device powered, on this bus, at this bit rate?")]
    NoDevice {
        /// The interface.
        interface: String,
        /// Node id.
        node_id: u8,
        /// Expected sample id.
        sample_id: u32,
        /// How long configure waited, ms.
        waited_ms: u64,
    },
    /// A bus-off error frame: the controller left the bus.
    #[error("CAN bus-off")]
    BusOff,
    /// Another error frame (protocol, CRC, ACK, transceiver, controller).
    #[error("CAN error frame: {}", describe_error_frame(.bits, .data))]
    ErrorFrame {
        /// Error class bits of the id word (`CAN_ERR_*`).
        bits: u32,
        /// The error frame's data bytes.
        data: [u8; CAN_DATA_BYTES],
    },
    /// A frame shorter than its map.
    #[error("{frame} frame carries {len} data bytes, the frame map needs {need}")]
    ShortFrame {
        /// `"command"` or `"sample"`.
        frame: &'static str,
        /// Bytes received.
        len: usize,
        /// Bytes the map needs.
        need: usize,
    },
    /// A datagram that is not a classic CAN frame.
    #[error("a {len}-byte datagram on the CAN socket is not a CAN frame")]
    BadDatagram {
        /// Its length, bytes.
        len: usize,
    },
    /// Used before `configure`.
    #[error("the CAN stage is not configured")]
    NotConfigured,
    /// Non-zero current while the amplifier is disabled.
    #[error("{current_a} A demanded while the amplifier is disabled")]
    NotEnabled {
        /// The demand, A.
        current_a: f64,
    },
    /// A non-finite current demand.
    #[error("current demand is not finite ({current_a})")]
    NotFinite {
        /// The demand.
        current_a: f64,
    },
    /// An unusable sample period or timeout.
    #[error("sample period {period_ns} ns is unusable: {reason}")]
    Period {
        /// The requested period, ns.
        period_ns: u64,
        /// Why.
        reason: &'static str,
    },
    /// The device reports an amplifier fault (or did not enable).
    #[error("the device reports an amplifier fault ({})", fault_name(.code))]
    DeviceFault {
        /// The fault code from the status byte ([`DeviceFault::code`]).
        code: u8,
    },
    /// The transmit queue stayed full for the whole bounded wait.
    #[error("CAN transmit queue full (is the bus acknowledging frames?)")]
    TxFull,
}

fn fault_name(code: &u8) -> &'static str {
    DeviceFault::from_code(*code).map_or("unspecified", DeviceFault::as_str)
}

fn describe_error_frame(bits: &u32, data: &[u8; CAN_DATA_BYTES]) -> String {
    let bits = *bits;
    match CanErrorFrame::new_error(bits, data) {
        Ok(f) => format!("{} (class 0x{bits:X})", f.into_error()),
        Err(_) => format!("class 0x{bits:X}"),
    }
}

impl crate::Error for CanError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Config(_) | Self::Period { .. } => ErrorKind::Config,
            Self::NotFound { .. } => ErrorKind::NotFound,
            Self::Io { source, .. } => match source.raw_os_error() {
                Some(libc::ENODEV | libc::ENXIO) => ErrorKind::NotFound,
                Some(libc::EBUSY | libc::EADDRINUSE) => ErrorKind::Busy,
                _ => ErrorKind::Link,
            },
            Self::Timeout { .. } => ErrorKind::Timeout,
            Self::NoDevice { .. } | Self::BusOff | Self::TxFull => ErrorKind::Link,
            Self::ErrorFrame { .. } => ErrorKind::Crc,
            Self::ShortFrame { .. } | Self::BadDatagram { .. } => ErrorKind::Protocol,
            Self::NotConfigured | Self::NotEnabled { .. } => ErrorKind::InvalidState,
            Self::NotFinite { .. } => ErrorKind::OutOfRange,
            Self::DeviceFault { .. } => ErrorKind::AmplifierFault,
        }
    }
}

// ---------------------------------------------------------------------------
// Socket primitives: non-blocking, no allocation, deadlines on
// CLOCK_MONOTONIC.

/// One datagram read from the socket.
enum Rx {
    Frame(CanFrame),
    /// A datagram of the wrong size (not a classic CAN frame).
    Bad(usize),
}

fn errno(e: &io::Error) -> i32 {
    e.raw_os_error().unwrap_or(0)
}

/// Waits until the socket is readable (`POLLIN`) or writable (`POLLOUT`),
/// or `deadline_ns` passes. `Ok(false)` on timeout.
fn wait_fd(fd: RawFd, events: libc::c_short, deadline_ns: u64) -> io::Result<bool> {
    loop {
        let now = monotonic_ns();
        let left = deadline_ns.saturating_sub(now);
        let ts = libc::timespec {
            tv_sec: (left / 1_000_000_000) as libc::time_t,
            tv_nsec: (left % 1_000_000_000) as libc::c_long,
        };
        let mut pfd = libc::pollfd {
            fd,
            events,
            revents: 0,
        };
        // SAFETY: one valid pollfd, a valid timespec, no signal mask.
        let r = unsafe { libc::ppoll(&mut pfd, 1, &ts, std::ptr::null()) };
        if r > 0 {
            return Ok(true);
        }
        if r == 0 {
            return Ok(false);
        }
        let e = io::Error::last_os_error();
        if errno(&e) != libc::EINTR {
            return Err(e);
        }
    }
}

/// Reads one datagram without blocking; `Ok(None)` when none is queued.
fn try_recv(fd: RawFd) -> io::Result<Option<Rx>> {
    let mut frame = can_frame_default();
    let size = std::mem::size_of::<libc::can_frame>();
    loop {
        // SAFETY: `frame` is a plain C struct of `size` bytes.
        let n = unsafe {
            libc::recv(
                fd,
                (&mut frame as *mut libc::can_frame).cast(),
                size,
                libc::MSG_DONTWAIT,
            )
        };
        if n >= 0 {
            let n = n as usize;
            return Ok(Some(if n == size {
                Rx::Frame(CanFrame::from(frame))
            } else {
                Rx::Bad(n)
            }));
        }
        let e = io::Error::last_os_error();
        match errno(&e) {
            libc::EINTR => continue,
            libc::EAGAIN => return Ok(None),
            _ => return Err(e),
        }
    }
}

/// Sends one frame without blocking.
fn try_send(fd: RawFd, frame: &libc::can_frame) -> io::Result<()> {
    let size = std::mem::size_of::<libc::can_frame>();
    loop {
        // SAFETY: `frame` is a fully initialised C struct of `size` bytes.
        let n = unsafe {
            libc::send(
                fd,
                (frame as *const libc::can_frame).cast(),
                size,
                libc::MSG_DONTWAIT | libc::MSG_NOSIGNAL,
            )
        };
        if n >= 0 {
            return Ok(());
        }
        let e = io::Error::last_os_error();
        if errno(&e) != libc::EINTR {
            return Err(e);
        }
    }
}

fn queue_full(e: &io::Error) -> bool {
    matches!(errno(e), libc::EAGAIN | libc::ENOBUFS)
}

/// Sends one frame, retrying while the transmit queue is full until
/// `deadline_ns`.
fn send_until(fd: RawFd, frame: &libc::can_frame, deadline_ns: u64) -> Result<(), CanError> {
    loop {
        match try_send(fd, frame) {
            Ok(()) => return Ok(()),
            Err(e) if queue_full(&e) => {
                let now = monotonic_ns();
                if now >= deadline_ns {
                    return Err(CanError::TxFull);
                }
                // ENOBUFS is not pollable: short sleeps.
                sleep_until_ns(deadline_ns.min(now + 100_000));
            }
            Err(source) => return Err(CanError::Io { op: "send", source }),
        }
    }
}

/// Sets a socket option that only a real CAN_RAW socket has. On another
/// socket (a Unix datagram pair in tests) the option does not exist and is
/// skipped: `Ok(false)`.
fn can_option(r: io::Result<()>, op: &'static str) -> Result<bool, CanError> {
    match r {
        Ok(()) => Ok(true),
        Err(e) if matches!(errno(&e), libc::ENOPROTOOPT | libc::EOPNOTSUPP) => Ok(false),
        Err(source) => Err(CanError::Io { op, source }),
    }
}

/// Whether an error frame's classes make the read that meets it bad.
/// Lost arbitration, controller restart, error counters and a controller
/// report of only "back to error active" are informational.
fn error_frame_is_bad(bits: u32, data: &[u8]) -> bool {
    let informational =
        libc::CAN_ERR_LOSTARB | libc::CAN_ERR_RESTARTED | libc::CAN_ERR_CNT | libc::CAN_ERR_CRTL;
    if bits & !informational != 0 {
        return true;
    }
    bits & libc::CAN_ERR_CRTL != 0 && data[1] & !(libc::CAN_ERR_CRTL_ACTIVE as u8) != 0
}

// ---------------------------------------------------------------------------
// Host side.

/// Opens a raw CAN socket on `interface` (for [`run_emulator`]; the stage
/// opens its own with [`CanStage::open`]).
///
/// # Errors
/// `NotFound` naming the interface when it does not exist (or the kernel
/// has no SocketCAN), `Link` for other socket errors.
pub fn open_socket(interface: &str) -> Result<CanSocket, CanError> {
    CanSocket::open(interface).map_err(|source| match errno(&source) {
        libc::ENODEV | libc::ENXIO | libc::EAFNOSUPPORT | libc::EPROTONOSUPPORT => {
            CanError::NotFound {
                interface: interface.into(),
                source,
            }
        }
        _ => CanError::Io { op: "open", source },
    })
}

/// Link counters of a [`CanStage`] (since it was created).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct CanStats {
    /// Samples returned by `read_sample`.
    pub samples: u64,
    /// Command frames sent.
    pub commands_sent: u64,
    /// SYNC frames sent.
    pub syncs_sent: u64,
    /// Error frames received (all classes).
    pub error_frames: u64,
    /// Bus-off reports.
    pub bus_off: u64,
    /// Reads that timed out.
    pub timeouts: u64,
    /// Sequence gaps seen (a jump of the counter by more than one).
    pub seq_gaps: u64,
    /// Samples missing in those gaps.
    pub lost_samples: u64,
    /// Samples discarded as late (answering an earlier SYNC) or stale.
    pub late_samples: u64,
    /// Frames refused: wrong size or shorter than the map.
    pub bad_frames: u64,
}

/// What one received frame means to the host.
enum Event {
    Sample(SamplePayload),
    BusOff,
    Bad(CanError),
    Ignore,
}

/// The SocketCAN stage (host side).
#[derive(Debug)]
pub struct CanStage {
    sock: CanSocket,
    cfg: CanConfig,
    sample_word: u32,
    sync_frame: libc::can_frame,
    kernel_filters: bool,
    period_ns: u64,
    timeout_ns: u64,
    configured: bool,
    enabled: bool,
    bus_off: bool,
    /// Device counter (raw) of the sample numbered 0.
    base_raw: u64,
    last_raw: Option<u64>,
    seq: u64,
    last_fault_code: u8,
    stats: CanStats,
}

impl CanStage {
    /// Opens `cfg.interface` with the error-frame mask and a sample-id
    /// filter.
    ///
    /// # Errors
    /// `Config` for an invalid `cfg`, `NotFound` for a missing interface,
    /// `Link` for other socket errors.
    pub fn open(cfg: &CanConfig) -> Result<Self, CanError> {
        cfg.validate("backend.can")?;
        let sock = open_socket(&cfg.interface)?;
        let stage = Self::from_socket(sock, cfg)?;
        if !stage.kernel_filters {
            return Err(CanError::Io {
                op: "setsockopt(CAN_RAW_FILTER)",
                source: io::Error::from_raw_os_error(libc::ENOPROTOOPT),
            });
        }
        Ok(stage)
    }

    /// Wraps an open socket (tests pass one end of a `UnixDatagram` pair).
    /// The error-frame mask and the sample-id filter are set when the
    /// socket is a CAN_RAW socket, skipped otherwise
    /// ([`kernel_filters`](Self::kernel_filters)).
    ///
    /// # Errors
    /// `Config` for an invalid `cfg`, `Link` for socket errors.
    pub fn from_socket(sock: CanSocket, cfg: &CanConfig) -> Result<Self, CanError> {
        cfg.validate("backend.can")?;
        sock.set_nonblocking(true).map_err(|source| CanError::Io {
            op: "set_nonblocking",
            source,
        })?;
        let errors = can_option(
            sock.set_error_filter_accept_all(),
            "setsockopt(CAN_RAW_ERR_FILTER)",
        )?;
        let ids = can_option(
            sock.set_filters(&[cfg.filter(cfg.sample_id())]),
            "setsockopt(CAN_RAW_FILTER)",
        )?;
        Ok(Self {
            sample_word: cfg.id_word(cfg.sample_id()),
            sync_frame: cfg.raw_frame(cfg.sync_id, &[]),
            kernel_filters: errors && ids,
            cfg: cfg.clone(),
            sock,
            period_ns: 0,
            timeout_ns: 0,
            configured: false,
            enabled: false,
            bus_off: false,
            base_raw: 0,
            last_raw: None,
            seq: 0,
            last_fault_code: 0,
            stats: CanStats::default(),
        })
    }

    /// The link counters.
    pub fn stats(&self) -> CanStats {
        self.stats
    }

    /// The configuration in force.
    pub fn config(&self) -> &CanConfig {
        &self.cfg
    }

    /// Whether the error-frame mask and id filter are set in the kernel
    /// (false on a non-CAN test socket).
    pub fn kernel_filters(&self) -> bool {
        self.kernel_filters
    }

    /// The fault the device reported in its latest sample, if any.
    pub fn device_fault(&self) -> Option<DeviceFault> {
        DeviceFault::from_code(self.last_fault_code)
    }

    fn fd(&self) -> RawFd {
        self.sock.as_raw_fd()
    }

    fn classify(&mut self, rx: Rx) -> Event {
        match rx {
            Rx::Bad(len) => {
                self.stats.bad_frames += 1;
                Event::Bad(CanError::BadDatagram { len })
            }
            Rx::Frame(CanFrame::Error(f)) => {
                self.stats.error_frames += 1;
                let bits = f.error_bits();
                if bits & libc::CAN_ERR_BUSOFF != 0 {
                    self.stats.bus_off += 1;
                    Event::BusOff
                } else {
                    let mut data = [0u8; CAN_DATA_BYTES];
                    let d = f.data();
                    let n = d.len().min(CAN_DATA_BYTES);
                    data[..n].copy_from_slice(&d[..n]);
                    if error_frame_is_bad(bits, &data) {
                        Event::Bad(CanError::ErrorFrame { bits, data })
                    } else {
                        Event::Ignore
                    }
                }
            }
            Rx::Frame(CanFrame::Data(f)) if f.id_word() == self.sample_word => {
                match self.cfg.sample.decode(f.data()) {
                    Ok(p) => Event::Sample(p),
                    Err(e) => {
                        self.stats.bad_frames += 1;
                        Event::Bad(e)
                    }
                }
            }
            Rx::Frame(_) => Event::Ignore,
        }
    }

    /// Numbers a received sample; `None` if it is stale (older than the
    /// last one).
    fn accept(&mut self, p: &SamplePayload) -> Option<Sample> {
        let w = self.cfg.sample.seq.width_bits;
        match self.last_raw {
            None => {
                self.base_raw = p.seq;
                self.seq = 0;
            }
            Some(last) => {
                let d = seq_delta(last, p.seq, w);
                if d < 0 {
                    self.stats.late_samples += 1;
                    return None;
                }
                if d > 1 {
                    self.stats.seq_gaps += 1;
                    self.stats.lost_samples += d as u64 - 1;
                }
                self.seq += d as u64;
            }
        }
        self.last_raw = Some(p.seq);
        self.last_fault_code = p.fault_code;
        Some(Sample {
            seq: self.seq,
            device_time_ns: self.seq.saturating_mul(self.period_ns),
            position_m: p.position_m,
            measured_current_a: p.measured_current_a,
            flags: p.flags,
        })
    }

    /// The next sample, waiting at most `timeout_ns` (see the module docs).
    fn next_sample(&mut self, timeout_ns: u64) -> Result<Sample, CanError> {
        if self.bus_off {
            return Err(CanError::BusOff);
        }
        let fd = self.fd();
        let sync = self.cfg.sync_producer;
        // 1. What is queued already.
        let mut newest: Option<SamplePayload> = None;
        let mut pending: Option<CanError> = None;
        while let Some(rx) = try_recv(fd).map_err(|source| CanError::Io { op: "recv", source })? {
            match self.classify(rx) {
                Event::Sample(p) => {
                    if sync {
                        self.stats.late_samples += 1;
                    } else {
                        newest = Some(p);
                        pending = None;
                    }
                }
                Event::BusOff => {
                    self.bus_off = true;
                    return Err(CanError::BusOff);
                }
                Event::Bad(e) => {
                    if !sync {
                        newest = None;
                        pending = Some(e);
                    }
                }
                Event::Ignore => {}
            }
        }
        if let Some(e) = pending {
            return Err(e);
        }
        if let Some(p) = newest {
            if let Some(s) = self.accept(&p) {
                return Ok(s);
            }
        }
        // 2. Trigger (SYNC) and wait.
        let start = monotonic_ns();
        let deadline = start + timeout_ns;
        if sync {
            send_until(fd, &self.sync_frame, deadline)?;
            self.stats.syncs_sent += 1;
        }
        loop {
            let ready = wait_fd(fd, libc::POLLIN, deadline)
                .map_err(|source| CanError::Io { op: "poll", source })?;
            if !ready {
                self.stats.timeouts += 1;
                return Err(CanError::Timeout {
                    waited_ns: monotonic_ns() - start,
                });
            }
            let Some(rx) = try_recv(fd).map_err(|source| CanError::Io { op: "recv", source })?
            else {
                continue;
            };
            match self.classify(rx) {
                Event::Sample(p) => {
                    if let Some(s) = self.accept(&p) {
                        return Ok(s);
                    }
                }
                Event::BusOff => {
                    self.bus_off = true;
                    return Err(CanError::BusOff);
                }
                Event::Bad(e) => return Err(e),
                Event::Ignore => {}
            }
        }
    }

    fn send_command(
        &mut self,
        current_a: f64,
        answers_seq: u64,
        enable: bool,
    ) -> Result<(), CanError> {
        let p = CommandPayload {
            current_a,
            answers_seq: self.base_raw.wrapping_add(answers_seq),
            enable,
        };
        let data = self.cfg.command.encode(&p);
        let frame = self
            .cfg
            .raw_frame(self.cfg.command_id(), &data[..self.cfg.command.len()]);
        let timeout = if self.timeout_ns > 0 {
            self.timeout_ns
        } else {
            self.cfg.sample_timeout_ns(1_000_000)
        };
        send_until(self.fd(), &frame, monotonic_ns() + timeout)?;
        self.stats.commands_sent += 1;
        Ok(())
    }

    /// A bounded wait for non-real-time steps (configure, enable).
    fn setup_wait_ns(&self) -> u64 {
        (10 * self.timeout_ns).max(LINK_WAIT_MIN_NS)
    }
}

impl Stage for CanStage {
    type Error = CanError;

    /// Sends a disable (0 A, enable bit clear), then waits (bounded) for one
    /// sample to check that the device answers. Returns the configured
    /// ratings and the clock (see the module docs).
    fn configure(&mut self, period_ns: u64) -> Result<DeviceInfo, CanError> {
        if !(10_000..=1_000_000_000).contains(&period_ns) {
            return Err(CanError::Period {
                period_ns,
                reason: "must be between 10 µs and 1 s",
            });
        }
        let timeout_ns = self.cfg.sample_timeout_ns(period_ns);
        if !self.cfg.sync_producer && timeout_ns <= period_ns {
            return Err(CanError::Period {
                period_ns,
                reason: "backend.can.sample_timeout_ms must exceed the period when the device clocks the loop",
            });
        }
        self.configured = false;
        self.enabled = false;
        self.bus_off = false;
        self.period_ns = period_ns;
        self.timeout_ns = timeout_ns;
        self.last_raw = None;
        self.base_raw = 0;
        self.seq = 0;
        self.last_fault_code = 0;
        self.send_command(0.0, 0, false)?;
        let wait = self.setup_wait_ns();
        let deadline = monotonic_ns() + wait;
        loop {
            match self.next_sample(self.timeout_ns) {
                Ok(_) => break,
                Err(CanError::BusOff) => return Err(CanError::BusOff),
                Err(e @ CanError::Io { .. }) => return Err(e),
                Err(_) if monotonic_ns() < deadline => {}
                Err(_) => {
                    return Err(CanError::NoDevice {
                        interface: self.cfg.interface.clone(),
                        node_id: self.cfg.node_id,
                        sample_id: self.cfg.sample_id(),
                        waited_ms: wait / 1_000_000,
                    })
                }
            }
        }
        self.configured = true;
        Ok(DeviceInfo {
            name: format!("socketcan:{} node {}", self.cfg.interface, self.cfg.node_id),
            clock: if self.cfg.sync_producer {
                Clock::Host
            } else {
                Clock::Device {
                    rate_hz: 1e9 / period_ns as f64,
                }
            },
            period_ns,
            peak_current_a: self.cfg.peak_current_a,
            continuous_current_a: self.cfg.continuous_current_a,
            probe_range_m: self.cfg.probe_range_m,
        })
    }

    /// Sends an enable edge (bit 0 then 1, 0 A) and waits (bounded) for a
    /// sample showing the amplifier enabled.
    ///
    /// # Errors
    /// `AmplifierFault` ([`CanError::DeviceFault`]) if no sample shows it
    /// enabled in time.
    fn enable(&mut self) -> Result<(), CanError> {
        if !self.configured {
            return Err(CanError::NotConfigured);
        }
        if self.bus_off {
            return Err(CanError::BusOff);
        }
        self.send_command(0.0, self.seq, false)?;
        self.send_command(0.0, self.seq, true)?;
        let deadline = monotonic_ns() + self.setup_wait_ns();
        loop {
            match self.next_sample(self.timeout_ns) {
                Ok(s) if s.flags.amplifier_enabled && !s.flags.amplifier_fault => {
                    self.enabled = true;
                    return Ok(());
                }
                Ok(s) => {
                    // Keep the watchdog fed while the device comes up.
                    self.send_command(0.0, s.seq, true)?;
                }
                Err(CanError::BusOff) => return Err(CanError::BusOff),
                Err(e @ CanError::Io { .. }) => return Err(e),
                Err(_) => {}
            }
            if monotonic_ns() >= deadline {
                let _ = self.send_command(0.0, self.seq, false);
                return Err(CanError::DeviceFault {
                    code: self.last_fault_code,
                });
            }
        }
    }

    fn read_sample(&mut self) -> Result<Sample, CanError> {
        if !self.configured {
            return Err(CanError::NotConfigured);
        }
        let s = self.next_sample(self.timeout_ns)?;
        self.stats.samples += 1;
        if self.enabled && s.flags.amplifier_fault {
            self.enabled = false;
            return Err(CanError::DeviceFault {
                code: self.last_fault_code,
            });
        }
        Ok(s)
    }

    fn write_command(&mut self, command: Command) -> Result<(), CanError> {
        if !self.configured {
            return Err(CanError::NotConfigured);
        }
        let i = command.current_a;
        if !i.is_finite() {
            let _ = self.send_command(0.0, command.answers_seq, self.enabled);
            return Err(CanError::NotFinite { current_a: i });
        }
        if !self.enabled && i != 0.0 {
            return Err(CanError::NotEnabled { current_a: i });
        }
        if self.bus_off {
            return Err(CanError::BusOff);
        }
        self.send_command(i, command.answers_seq, self.enabled)
    }

    /// Sends 0 A with the enable bit clear (bounded wait for the transmit
    /// queue). Works in any state, idempotent.
    fn disable(&mut self) -> Result<(), CanError> {
        self.enabled = false;
        self.send_command(0.0, self.seq, false)
    }
}

impl Drop for CanStage {
    fn drop(&mut self) {
        let _ = self.disable();
    }
}

// ---------------------------------------------------------------------------
// Device side.

/// Link-fault state of the emulator.
#[derive(Debug, Default)]
struct Faults {
    drop_left: u32,
    flip_left: u32,
    delay_ns: u64,
    stall_until_ns: Option<u64>,
    disconnected: bool,
}

struct Emulator<'a> {
    fd: RawFd,
    cfg: &'a CanConfig,
    core: DeviceCore,
    status: &'a EmulatorStatus,
    sync_word: u32,
    command_word: u32,
    sample_id: u32,
    t0_ns: u64,
    last_tick_ns: u64,
    last_enable_bit: bool,
    last_sent_seq: Option<u64>,
    faults: Faults,
    /// Frames held back by a delay: (release time, frame).
    delayed: VecDeque<(u64, libc::can_frame)>,
}

impl Emulator<'_> {
    fn dev(&self, mono_ns: u64) -> u64 {
        mono_ns.saturating_sub(self.t0_ns)
    }

    fn publish(&self) {
        self.status.publish(&self.core);
    }

    /// Sends now (a full queue or absent peer drops the frame).
    fn send_now(&self, frame: &libc::can_frame) -> Result<bool, CanError> {
        match try_send(self.fd, frame) {
            Ok(()) => Ok(true),
            Err(e)
                if queue_full(&e) || matches!(errno(&e), libc::ECONNREFUSED | libc::ENOTCONN) =>
            {
                Ok(false)
            }
            Err(source) => Err(CanError::Io { op: "send", source }),
        }
    }

    /// Sends through the delay line.
    fn emit(&mut self, frame: libc::can_frame, now: u64) -> Result<bool, CanError> {
        if self.faults.delay_ns > 0 {
            let t = self
                .delayed
                .back()
                .map_or(0, |(t, _)| *t)
                .max(now + self.faults.delay_ns);
            self.delayed.push_back((t, frame));
            Ok(true)
        } else {
            self.send_now(&frame)
        }
    }

    fn apply(&mut self, fault: LinkFault, now: u64) -> Result<(), CanError> {
        match fault {
            LinkFault::BitFlips { frames, .. } => self.faults.flip_left += frames,
            LinkFault::Drop { frames } => self.faults.drop_left += frames,
            LinkFault::Delay { delay_s } => self.faults.delay_ns = (delay_s * 1e9) as u64,
            LinkFault::Stall { duration_s } => {
                self.faults.stall_until_ns = Some(now + (duration_s * 1e9) as u64);
            }
            LinkFault::Disconnect => {
                let f: CanErrorFrame = ErrorCause::BusOff.into();
                self.send_now(f.as_ref())?;
                self.faults.disconnected = true;
                self.delayed.clear();
                self.status.host_connected.store(false, Ordering::Release);
            }
        }
        Ok(())
    }

    /// One sample tick at `now`.
    fn tick(&mut self, now: u64) -> Result<(), CanError> {
        let was_enabled = self.core.is_enabled();
        let s = self.core.tick(self.dev(now));
        self.last_tick_ns = now;
        if was_enabled && !self.core.is_enabled() {
            self.status
                .watchdog_trip_mono_ns
                .store(now, Ordering::Release);
            self.status.host_connected.store(false, Ordering::Release);
        }
        self.publish();
        if self.faults.disconnected {
            return Ok(());
        }
        if self.faults.drop_left > 0 {
            self.faults.drop_left -= 1;
            return Ok(());
        }
        let frame = if self.faults.flip_left > 0 {
            self.faults.flip_left -= 1;
            // The bus CRC rejects a corrupted frame: receivers see an error.
            let f: CanErrorFrame = ErrorCause::Protocol {
                types: ViolationTypes::BIT,
                location: Location::CrcSequence,
            }
            .into();
            *f.as_ref()
        } else {
            let p = SamplePayload {
                position_m: s.position_m,
                seq: s.seq,
                flags: s.flags,
                fault_code: self.core.fault().map_or(0, DeviceFault::code),
                measured_current_a: s.measured_current_a,
            };
            let data = self.cfg.sample.encode(&p);
            self.last_sent_seq = Some(s.seq);
            self.cfg
                .raw_frame(self.sample_id, &data[..self.cfg.sample.len()])
        };
        if self.emit(frame, now)? {
            self.status.samples_sent.fetch_add(1, Ordering::Relaxed);
        }
        Ok(())
    }

    /// The emulator's main loop (see [`run_emulator`]).
    fn run(
        &mut self,
        schedule: &[ScheduledLinkFault],
        stop: &AtomicBool,
        period: u64,
        watchdog: u64,
    ) -> Result<(), CanError> {
        let sync = self.cfg.sync_producer;
        let mut next_fault = 0;
        let mut next_tick = self.t0_ns + period;
        while !stop.load(Ordering::Acquire) {
            let now = monotonic_ns();
            while let Some(f) = schedule.get(next_fault) {
                if (self.dev(now) as f64) * 1e-9 < f.at_s {
                    break;
                }
                self.apply(f.kind, now)?;
                next_fault += 1;
            }
            if let Some(until) = self.faults.stall_until_ns {
                if now >= until {
                    self.faults.stall_until_ns = None;
                    // A hung device does not catch up: the timer restarts.
                    next_tick = now + period;
                    self.last_tick_ns = now;
                }
            }
            let stalled = self.faults.stall_until_ns.is_some();
            while let Some(&(t, frame)) = self.delayed.front() {
                if t > now {
                    break;
                }
                self.delayed.pop_front();
                self.send_now(&frame)?;
            }
            if !sync && !stalled && now >= next_tick {
                self.tick(now)?;
                while next_tick <= now {
                    next_tick += period;
                }
            }
            // The watchdog from the device's own clock, when ticks stopped
            // (SYNC mode with a dead host, or a disconnected link).
            if !stalled
                && self.core.is_enabled()
                && self.dev(now).saturating_sub(self.core.last_command_ns()) > watchdog
                && now.saturating_sub(self.last_tick_ns) >= period
                && self.core.check_watchdog(self.dev(now))
            {
                self.status
                    .watchdog_trip_mono_ns
                    .store(now, Ordering::Release);
                self.status.host_connected.store(false, Ordering::Release);
                self.publish();
            }
            // Sleep until the next thing to do, or a frame.
            let mut wake = now + EMULATOR_POLL_NS;
            if let Some(until) = self.faults.stall_until_ns {
                wake = wake.min(until);
            } else {
                if !sync {
                    wake = wake.min(next_tick);
                }
                if self.core.is_enabled() {
                    let expiry = self.t0_ns + self.core.last_command_ns() + watchdog + 1;
                    wake = wake.min(expiry.max(self.last_tick_ns + period));
                }
            }
            if let Some(&(t, _)) = self.delayed.front() {
                wake = wake.min(t);
            }
            if let Some(f) = schedule.get(next_fault) {
                wake = wake.min(self.t0_ns + (f.at_s * 1e9) as u64);
            }
            let ready = wait_fd(self.fd, libc::POLLIN, wake.max(now))
                .map_err(|source| CanError::Io { op: "poll", source })?;
            if !ready {
                continue;
            }
            if let Some(rx) =
                try_recv(self.fd).map_err(|source| CanError::Io { op: "recv", source })?
            {
                self.on_frame(rx, monotonic_ns())?;
            }
        }
        Ok(())
    }

    fn on_frame(&mut self, rx: Rx, now: u64) -> Result<(), CanError> {
        if self.faults.disconnected || self.faults.stall_until_ns.is_some() {
            return Ok(());
        }
        let f = match rx {
            Rx::Frame(CanFrame::Data(f)) => f,
            Rx::Bad(_) => {
                self.status.bad_frames.fetch_add(1, Ordering::Relaxed);
                return Ok(());
            }
            Rx::Frame(_) => return Ok(()),
        };
        let word = f.id_word();
        if word == self.sync_word {
            self.status.host_connected.store(true, Ordering::Release);
            if self.cfg.sync_producer {
                self.tick(now)?;
            }
        } else if word == self.command_word {
            let c = match self.cfg.command.decode(f.data()) {
                Ok(c) => c,
                Err(_) => {
                    self.status.bad_frames.fetch_add(1, Ordering::Relaxed);
                    return Ok(());
                }
            };
            self.status.host_connected.store(true, Ordering::Release);
            let dev = self.dev(now);
            if c.enable && !self.last_enable_bit {
                self.core.enable(dev);
            } else if !c.enable && self.core.is_enabled() {
                self.core.disable();
            }
            self.last_enable_bit = c.enable;
            let accepted = self.core.command(
                Command {
                    current_a: c.current_a,
                    answers_seq: c.answers_seq,
                },
                dev,
            );
            if accepted {
                self.status
                    .last_command_mono_ns
                    .store(now, Ordering::Release);
                self.status
                    .commands_received
                    .fetch_add(1, Ordering::Relaxed);
                let w = self.cfg.command.answers_seq.width_bits;
                if let Some(last) = self.last_sent_seq {
                    if c.enable && seq_delta(last, c.answers_seq, w) < 0 {
                        self.status.late_commands.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
            self.publish();
        }
        Ok(())
    }
}

/// Runs the emulated device on `sock` until `stop` is raised: the plant in
/// `core` sampled on SYNC (`cfg.sync_producer`) or on its own timer at
/// `core.period_ns()`, commands from the command frame, the watchdog of
/// `core` (checked on every tick and from the emulator's clock when ticks
/// stop), the link faults of `faults` at their device times, and the
/// device's state published in `status`. Leaves the device disabled.
///
/// In `status`, `last_command_mono_ns` is the arrival of the last accepted
/// command, `watchdog_trip_mono_ns` the moment the watchdog dropped the
/// current, `host_connected` whether a SYNC or command frame arrived since
/// the start or the last trip, `bad_frames` counts command frames shorter
/// than the map and datagrams that are not CAN frames, and
/// `late_commands` counts enabled commands answering an older sample than
/// the last one sent.
///
/// Build `core` with the device's watchdog time (`[emulator] watchdog_ms`). The socket gets an id filter for
/// the SYNC and command ids when it is a CAN_RAW socket.
///
/// # Errors
/// `Config` for an invalid `cfg`; `Link` when the socket fails.
pub fn run_emulator(
    sock: CanSocket,
    cfg: &CanConfig,
    core: DeviceCore,
    faults: &[ScheduledLinkFault],
    stop: &AtomicBool,
    status: &EmulatorStatus,
) -> Result<(), CanError> {
    cfg.validate("backend.can")?;
    sock.set_nonblocking(true).map_err(|source| CanError::Io {
        op: "set_nonblocking",
        source,
    })?;
    can_option(
        sock.set_filters(&[cfg.filter(cfg.sync_id), cfg.filter(cfg.command_id())]),
        "setsockopt(CAN_RAW_FILTER)",
    )?;
    can_option(
        sock.set_error_filter_drop_all(),
        "setsockopt(CAN_RAW_ERR_FILTER)",
    )?;
    let mut schedule: Vec<ScheduledLinkFault> = faults.to_vec();
    schedule.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
    let period = core.period_ns();
    let watchdog = core.watchdog_ns();
    let t0 = monotonic_ns();
    let mut em = Emulator {
        fd: sock.as_raw_fd(),
        cfg,
        core,
        status,
        sync_word: cfg.id_word(cfg.sync_id),
        command_word: cfg.id_word(cfg.command_id()),
        sample_id: cfg.sample_id(),
        t0_ns: t0,
        last_tick_ns: t0,
        last_enable_bit: false,
        last_sent_seq: None,
        faults: Faults::default(),
        delayed: VecDeque::new(),
    };
    em.publish();
    let result = em.run(&schedule, stop, period, watchdog);
    em.core.disable();
    em.publish();
    result
}
