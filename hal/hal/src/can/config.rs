//! The `[backend.can]` table ([`CanConfig`]) and the validation of a
//! frame map's keys: the host's side of the CAN frame map, whose layout
//! (fields, payloads, counters) is [`bench_protocol::can`], shared with the
//! CAN emulator. See the [module docs](super) for the default map.

use crate::param::{positive, ParamError};
use bench_protocol::can::{CommandMap, FieldSpec, SampleMap, CAN_DATA_BYTES, DEFAULT_SYNC_ID};
use serde::{Deserialize, Serialize};
use socketcan::{CanDataFrame, CanFilter, EmbeddedFrame, ExtendedId, StandardId};

/// Checks a field's width, placement and scale; keys are `key.offset_byte`,
/// `key.width_bits` and `key.scale`.
///
/// # Errors
/// The offending key with the reason.
pub fn validate_field(f: &FieldSpec, key: &str) -> Result<(), ParamError> {
    if !matches!(f.width_bits, 8 | 16 | 24 | 32) {
        return Err(ParamError::new(
            format!("{key}.width_bits"),
            format!("must be 8, 16, 24 or 32, got {}", f.width_bits),
        ));
    }
    let r = f.byte_range();
    if r.end > CAN_DATA_BYTES {
        return Err(ParamError::new(
            format!("{key}.offset_byte"),
            format!(
                "bytes {}..{} do not fit in the {CAN_DATA_BYTES} data bytes of a CAN frame",
                r.start, r.end
            ),
        ));
    }
    if !f.scale.is_finite() || f.scale == 0.0 {
        return Err(ParamError::new(
            format!("{key}.scale"),
            format!("must be finite and non-zero, got {}", f.scale),
        ));
    }
    Ok(())
}

fn validate_integer(f: &FieldSpec, key: &str) -> Result<(), ParamError> {
    validate_field(f, key)?;
    if f.signed {
        return Err(ParamError::new(
            format!("{key}.signed"),
            "an integer field (counter or bits) must be unsigned",
        ));
    }
    if f.scale != 1.0 {
        return Err(ParamError::new(
            format!("{key}.scale"),
            format!(
                "an integer field (counter or bits) has scale 1, got {}",
                f.scale
            ),
        ));
    }
    Ok(())
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

/// Checks a command map's fields, keys under `prefix` (e.g.
/// `backend.can.command`).
///
/// # Errors
/// The first offending key with the reason.
pub fn validate_command_map(m: &CommandMap, prefix: &str) -> Result<(), ParamError> {
    validate_field(&m.current, &format!("{prefix}.current"))?;
    validate_integer(&m.answers_seq, &format!("{prefix}.answers_seq"))?;
    validate_integer(&m.control, &format!("{prefix}.control"))?;
    check_overlap(
        prefix,
        &[
            ("current", &m.current),
            ("answers_seq", &m.answers_seq),
            ("control", &m.control),
        ],
    )
}

/// Checks a sample map's fields, keys under `prefix` (e.g.
/// `backend.can.sample`).
///
/// # Errors
/// The first offending key with the reason.
pub fn validate_sample_map(m: &SampleMap, prefix: &str) -> Result<(), ParamError> {
    validate_field(&m.position, &format!("{prefix}.position"))?;
    validate_integer(&m.seq, &format!("{prefix}.seq"))?;
    validate_integer(&m.status, &format!("{prefix}.status"))?;
    let mut fields = vec![
        ("position", &m.position),
        ("seq", &m.seq),
        ("status", &m.status),
    ];
    if let Some(c) = &m.measured_current {
        validate_field(c, &format!("{prefix}.measured_current"))?;
        fields.push(("measured_current", c));
    }
    check_overlap(prefix, &fields)
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
        validate_command_map(&self.command, &k("command"))?;
        validate_sample_map(&self.sample, &k("sample"))?;
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
    pub fn id_word(&self, id: u32) -> u32 {
        if self.extended {
            id | libc::CAN_EFF_FLAG
        } else {
            id
        }
    }

    /// A data frame with this id and data, as the kernel's struct.
    pub fn raw_frame(&self, id: u32, data: &[u8]) -> libc::can_frame {
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
    pub fn filter(&self, id: u32) -> CanFilter {
        let mask = if self.extended {
            libc::CAN_EFF_MASK
        } else {
            libc::CAN_SFF_MASK
        } | libc::CAN_EFF_FLAG
            | libc::CAN_RTR_FLAG;
        CanFilter::new(self.id_word(id), mask)
    }
}
