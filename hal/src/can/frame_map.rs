//! The CAN frame map: where each value sits in the SYNC, command and sample
//! frames ([`CommandMap`], [`SampleMap`], [`FieldSpec`]), their payloads,
//! counter arithmetic ([`seq_delta`]) and the `[backend.can]` table
//! ([`CanConfig`]) with its validation. Shared by the host backend and the
//! CAN emulator; see the [module docs](super) for the default map.

use super::CanError;
use crate::model::{positive, ParamError};
use crate::SampleFlags;
use serde::{Deserialize, Serialize};
use socketcan::{CanDataFrame, CanFilter, EmbeddedFrame, ExtendedId, StandardId};

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
/// Status bits 4–7 carry the latched fault code ([`DeviceFault::code`](crate::emulator::DeviceFault::code)).
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
    /// mapped, [`Sample::measured_current_a`](crate::Sample::measured_current_a) is NaN).
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
    /// Latched fault code ([`DeviceFault::code`](crate::emulator::DeviceFault::code), 0 for none).
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
    /// ([`Clock::Host`](crate::Clock::Host), default); false: the device samples on its own
    /// timer ([`Clock::Device`](crate::Clock::Device)).
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
    pub(crate) fn id_word(&self, id: u32) -> u32 {
        if self.extended {
            id | libc::CAN_EFF_FLAG
        } else {
            id
        }
    }

    /// A data frame with this id and data, as the kernel's struct.
    pub(crate) fn raw_frame(&self, id: u32, data: &[u8]) -> libc::can_frame {
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
    pub(crate) fn filter(&self, id: u32) -> CanFilter {
        let mask = if self.extended {
            libc::CAN_EFF_MASK
        } else {
            libc::CAN_SFF_MASK
        } | libc::CAN_EFF_FLAG
            | libc::CAN_RTR_FLAG;
        CanFilter::new(self.id_word(id), mask)
    }
}
