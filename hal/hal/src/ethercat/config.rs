//! The `[backend.ethercat]` table ([`EthercatConfig`]): interface, device
//! profile, expected identity, PDO map, SM watchdog, scalings, and its
//! validation. Shared by the host backend and the virtual slave.

use crate::param::{positive, ParamError};
use serde::{Deserialize, Serialize};

/// The device profile behind the EtherCAT slave.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Profile {
    /// A CiA 402 servo drive in cyclic synchronous torque mode
    /// (0x6060 = 10), driving the voice coil's current.
    #[default]
    Cia402,
    /// Analog terminals: a 16-bit ADC channel reading the probe, a 16-bit
    /// DAC channel commanding the current amplifier, a digital output
    /// enabling it and (optional) a digital input with the amplifier's
    /// ready and fault lines.
    Analog,
}

impl Profile {
    /// Snake-case name (the config's spelling).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Cia402 => "cia402",
            Self::Analog => "analog",
        }
    }

    /// The product code of the virtual slave of this profile (and the
    /// default expected `product_id`).
    pub fn product_id(self) -> u32 {
        match self {
            Self::Cia402 => 0x0000_0402,
            Self::Analog => 0x0000_0A10,
        }
    }
}

/// One PDO mapping entry (ETG.1000.6 §5.6.7.4.7, objects 0x1600/0x1A00):
/// the object `index`:`subindex`, `bits` wide.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PdoEntry {
    /// Object index (e.g. 0x6040).
    pub index: u16,
    /// Object subindex (0 for the CiA 402 objects).
    #[serde(default)]
    pub subindex: u8,
    /// Width, bits: 8, 16 or 32.
    pub bits: u8,
}

impl PdoEntry {
    /// The mapping entry as written to 0x1600/0x1A00:
    /// `index << 16 | subindex << 8 | bits`.
    pub fn raw(self) -> u32 {
        u32::from(self.index) << 16 | u32::from(self.subindex) << 8 | u32::from(self.bits)
    }

    /// The entry of a raw mapping word.
    pub fn from_raw(raw: u32) -> Self {
        Self {
            index: (raw >> 16) as u16,
            subindex: (raw >> 8) as u8,
            bits: raw as u8,
        }
    }

    const fn new(index: u16, bits: u8) -> Self {
        Self {
            index,
            subindex: 0,
            bits,
        }
    }
}

/// CiA 402 controlword (0x6040, u16; RxPDO).
pub const CONTROLWORD: PdoEntry = PdoEntry::new(0x6040, 16);
/// CiA 402 target torque (0x6071, i16, ‰ of the motor rated current
/// 0x6075; RxPDO). A voice coil's force is proportional to its current, so
/// the drive's torque loop is its current loop.
pub const TARGET_TORQUE: PdoEntry = PdoEntry::new(0x6071, 16);
/// Manufacturer-specific target current (0x2071, i32, µA; RxPDO): the
/// same set point at 1 µA resolution.
pub const TARGET_CURRENT: PdoEntry = PdoEntry::new(0x2071, 32);
/// CiA 402 statusword (0x6041, u16; TxPDO).
pub const STATUSWORD: PdoEntry = PdoEntry::new(0x6041, 16);
/// CiA 402 position actual value (0x6064, i32, counts of
/// `position_lsb_m`; TxPDO): the probe's reading.
pub const POSITION_ACTUAL: PdoEntry = PdoEntry::new(0x6064, 32);
/// CiA 402 current actual value (0x6078, i16, ‰ of 0x6075; TxPDO).
pub const CURRENT_ACTUAL: PdoEntry = PdoEntry::new(0x6078, 16);
/// Manufacturer-specific current actual value (0x2078, i32, µA; TxPDO).
pub const CURRENT_ACTUAL_UA: PdoEntry = PdoEntry::new(0x2078, 32);

/// Analog terminal: DAC channel 1 (0x7000:01, i16, ±32767 = ±
/// `dac_full_scale_a`; RxPDO): the amplifier's current command.
pub const DAC_OUTPUT: PdoEntry = PdoEntry {
    index: 0x7000,
    subindex: 1,
    bits: 16,
};
/// Analog terminal: digital output (0x7010:01, u8, bit 0 = enable the
/// amplifier; RxPDO).
pub const ENABLE_OUTPUT: PdoEntry = PdoEntry {
    index: 0x7010,
    subindex: 1,
    bits: 8,
};
/// Analog terminal: ADC channel 1 value (0x6000:11, i16, ±32767 = ±
/// `adc_full_scale_m`; TxPDO): the probe.
pub const ADC_INPUT: PdoEntry = PdoEntry {
    index: 0x6000,
    subindex: 0x11,
    bits: 16,
};
/// Analog terminal: ADC channel 1 status (0x6000:01..0x6000:10 as one u16,
/// EL31xx layout: bit 0 underrange, bit 1 overrange, bit 6 error;
/// [`crate::ethercat::wire::adc_status`]; TxPDO, optional). An error makes
/// the reading NaN (no valid reading), under- or overrange flags it out of
/// range.
pub const ADC_STATUS: PdoEntry = PdoEntry {
    index: 0x6000,
    subindex: 0x01,
    bits: 16,
};
/// Analog terminal: digital input (0x6020:01, u8, bit 0 amplifier ready
/// (enabled), bit 1 amplifier fault; TxPDO, optional).
pub const STATUS_INPUT: PdoEntry = PdoEntry {
    index: 0x6020,
    subindex: 1,
    bits: 8,
};

/// The largest process image of one direction, bytes.
pub const MAX_PDO_BYTES: usize = 32;

fn default_interface() -> String {
    "eth0".into()
}

/// The EtherCAT backend's configuration (the `[backend.ethercat]` table).
/// Every key has a default: `interface = "eth0"` alone is complete.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EthercatConfig {
    /// Network interface the EtherCAT segment is on (`eth1`, a veth).
    #[serde(default = "default_interface")]
    pub interface: String,
    /// Device profile (`"cia402"`).
    pub profile: Profile,
    /// Expected vendor id (SII word 0x0008, object 0x1018:01); the slave
    /// found must carry it. Default: the virtual slave's, 0x00BE_C0DE.
    pub vendor_id: u32,
    /// Expected product code (SII word 0x000A, object 0x1018:02).
    /// Default: the profile's virtual slave ([`Profile::product_id`]).
    pub product_id: Option<u32>,
    /// RxPDO 0x1600 (host → drive), in order. Empty: the profile's default
    /// ([`EthercatConfig::rx_entries`]). Must hold the controlword and one
    /// target (0x6071 or 0x2071).
    pub rx_pdo: Vec<PdoEntry>,
    /// TxPDO 0x1A00 (drive → host), in order. Empty: the profile's
    /// default. Must hold the statusword and the position (0x6064).
    pub tx_pdo: Vec<PdoEntry>,
    /// SM watchdog time, ms (ESC registers 0x0400/0x0420, 100 µs base):
    /// with no process data for this long the drive drops the current to
    /// 0 A and latches a fault. Range [0.2, 1000] ms and at least two loop
    /// periods (checked by the bench config).
    pub watchdog_ms: f64,
    /// Bound on one process-data round trip, ms. A frame not back in
    /// time is lost: kind `Timeout`. One back later than the period but
    /// within this bound makes the tick late, which the supervisor's
    /// overrun rule judges. Default (unset): the loop's own stall
    /// tolerance, capped by the SM watchdog, at least one period
    /// ([`Self::exchange_timeout_ns`]); set, it overrides that. Range
    /// [0.01, `watchdog_ms`] ms: a frame later than the watchdog finds the
    /// drive already stopped on its own.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub exchange_timeout_ms: Option<f64>,
    /// Bound on the whole bring-up INIT → OP, ms (default 5000).
    pub bringup_timeout_ms: f64,
    /// Amplifier peak current, A (default 9.98, the thesis bench).
    pub peak_current_a: f64,
    /// Actuator continuous current, A (default 2.34); also the drive's
    /// motor rated current 0x6075 (mA) in the virtual slave.
    pub continuous_current_a: f64,
    /// Probe half range, m (default 1e-3).
    pub probe_range_m: f64,
    /// One count of the position actual value 0x6064, m (default 1e-10).
    pub position_lsb_m: f64,
    /// Distributed clocks (default true): the slave's SYNC0 at the loop
    /// period (0x0990/0x09A0 through ethercrab), its system time read in
    /// every process-data frame (`FRMW` 0x0910) and checked against the
    /// host's clock.
    pub distributed_clocks: bool,
    /// The largest rate error allowed between the distributed clock and the
    /// host's clock, ppm: within any one-second window the clocks' offset
    /// may move by at most this × 1 s (default 100 ppm: 100 µs, beyond any
    /// crystal's tolerance); more is a fault. Range [1, 10 000].
    pub dc_drift_max_ppm: f64,
    /// Analog profile: the position at ADC full scale (+32767 counts), m
    /// (default 1e-3: the probe's ±1 mm on the ADC's ±10 V, 30.5 nm per
    /// count). A reading at ±32767 is out of range.
    pub adc_full_scale_m: f64,
    /// Analog profile: the current at DAC full scale (+32767 counts), A
    /// (default 9.98: the amplifier's ±10 V input at its peak current,
    /// 0.30 mA per count).
    pub dac_full_scale_a: f64,
    /// Analog profile as a rack of separate terminals
    /// (`[[backend.ethercat.slaves]]`, one table per slave of the segment,
    /// the coupler counted): each slave's position, identity, map and the
    /// signals it carries ([`super::rack`]). Empty (the default): one slave
    /// carries all four signals.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub slaves: Vec<RackSlave>,
}

impl Default for EthercatConfig {
    fn default() -> Self {
        Self {
            interface: default_interface(),
            profile: Profile::Cia402,
            vendor_id: VIRTUAL_VENDOR_ID,
            product_id: None,
            rx_pdo: Vec::new(),
            tx_pdo: Vec::new(),
            watchdog_ms: 20.0,
            exchange_timeout_ms: None,
            bringup_timeout_ms: 5000.0,
            peak_current_a: 9.98,
            continuous_current_a: 2.34,
            probe_range_m: 1e-3,
            position_lsb_m: 1e-10,
            distributed_clocks: true,
            dc_drift_max_ppm: 100.0,
            adc_full_scale_m: 1e-3,
            dac_full_scale_a: 9.98,
            slaves: Vec::new(),
        }
    }
}

/// Vendor id of the virtual slave (`bench emulate ethercat`).
pub const VIRTUAL_VENDOR_ID: u32 = 0x00BE_C0DE;

/// Where the host finds each value in the process images (byte offsets).
/// In the analog profile the controlword is the enable output, the target
/// the DAC, the statusword the status input (`usize::MAX` when not mapped)
/// and the position the ADC.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImageLayout {
    /// Output image length, bytes.
    pub out_len: usize,
    /// Input image length, bytes.
    pub in_len: usize,
    /// Controlword offset.
    pub controlword: usize,
    /// Target: offset and whether it is 0x2071 (µA) rather than 0x6071 (‰).
    pub target: (usize, bool),
    /// Statusword offset.
    pub statusword: usize,
    /// Position actual offset.
    pub position: usize,
    /// Current actual: offset and whether it is 0x2078 (µA) rather than
    /// 0x6078 (‰), if mapped.
    pub current: Option<(usize, bool)>,
    /// The analog input's status word (0x6000:01, u16), if mapped: in a
    /// rack, where the host gathers the terminal's `adc_status`.
    pub adc_status: Option<usize>,
}

impl EthercatConfig {
    /// The default configuration on `interface`.
    pub fn on(interface: &str) -> Self {
        Self {
            interface: interface.into(),
            ..Self::default()
        }
    }

    /// The product code expected.
    pub fn expected_product_id(&self) -> u32 {
        self.product_id.unwrap_or(self.profile.product_id())
    }

    /// RxPDO entries in force.
    pub fn rx_entries(&self) -> Vec<PdoEntry> {
        match (self.rx_pdo.is_empty(), self.profile) {
            (false, _) => self.rx_pdo.clone(),
            (true, Profile::Cia402) => vec![CONTROLWORD, TARGET_CURRENT],
            (true, Profile::Analog) => vec![DAC_OUTPUT, ENABLE_OUTPUT],
        }
    }

    /// TxPDO entries in force.
    pub fn tx_entries(&self) -> Vec<PdoEntry> {
        match (self.tx_pdo.is_empty(), self.profile) {
            (false, _) => self.tx_pdo.clone(),
            (true, Profile::Cia402) => vec![STATUSWORD, POSITION_ACTUAL, CURRENT_ACTUAL_UA],
            (true, Profile::Analog) => vec![ADC_INPUT, STATUS_INPUT, ADC_STATUS],
        }
    }

    /// The host's known objects of a direction: entry and name.
    fn known(&self, rx: bool) -> &'static [(PdoEntry, &'static str)] {
        match (self.profile, rx) {
            (Profile::Cia402, true) => &[
                (CONTROLWORD, "controlword"),
                (TARGET_TORQUE, "target torque"),
                (TARGET_CURRENT, "target current"),
            ],
            (Profile::Cia402, false) => &[
                (STATUSWORD, "statusword"),
                (POSITION_ACTUAL, "position actual"),
                (CURRENT_ACTUAL, "current actual"),
                (CURRENT_ACTUAL_UA, "current actual (µA)"),
            ],
            (Profile::Analog, true) => {
                &[(DAC_OUTPUT, "DAC output"), (ENABLE_OUTPUT, "enable output")]
            }
            (Profile::Analog, false) => &[
                (ADC_INPUT, "ADC input"),
                (STATUS_INPUT, "status input"),
                (ADC_STATUS, "ADC status"),
            ],
        }
    }

    /// The bound on one round trip at `period_ns`, ns, for a loop whose
    /// supervisor tolerates `stall_bound_ns` without a fresh sample
    /// (`None`: no bound, as in open-loop identification).
    ///
    /// `exchange_timeout_ms` when set; else `max(period, min(stall bound,
    /// watchdog))`. Why: while the tick waits for its frame the loop gets
    /// no fresh sample, so the wait is a stall; a frame late by less than
    /// the stall bound is a late tick the supervisor's overrun rule judges
    /// (and tolerates), and one later than that would be a fault whatever
    /// it brings, so waiting longer is pointless. Past the SM watchdog
    /// (`watchdog_ms`) the drive has dropped the current on its own. A
    /// bound below one period would cut round trips that are on time.
    pub fn exchange_timeout_ns(&self, period_ns: u64, stall_bound_ns: Option<u64>) -> u64 {
        match self.exchange_timeout_ms {
            Some(ms) => (ms * 1e6) as u64,
            None => {
                let watchdog_ns = (self.watchdog_ms * 1e6) as u64;
                stall_bound_ns
                    .unwrap_or(u64::MAX)
                    .min(watchdog_ns)
                    .max(period_ns)
            }
        }
    }

    /// Checks every key; errors name `prefix.key`.
    ///
    /// # Errors
    /// [`ParamError`] naming the first bad key.
    pub fn validate(&self, prefix: &str) -> Result<(), ParamError> {
        if self.interface.is_empty() || self.interface.len() >= libc::IF_NAMESIZE {
            return Err(ParamError::new(
                format!("{prefix}.interface"),
                format!(
                    "`{}` is not an interface name (1 to {} bytes)",
                    self.interface,
                    libc::IF_NAMESIZE - 1
                ),
            ));
        }
        if !(self.watchdog_ms.is_finite() && (0.2..=1000.0).contains(&self.watchdog_ms)) {
            return Err(ParamError::new(
                format!("{prefix}.watchdog_ms"),
                format!(
                    "must be in [0.2, 1000] ms (the SM watchdog counts 100 µs steps, and a dead host must not leave current flowing longer than 1 s), got {}",
                    self.watchdog_ms
                ),
            ));
        }
        if let Some(ms) = self.exchange_timeout_ms {
            if !(ms.is_finite() && (0.01..=self.watchdog_ms).contains(&ms)) {
                return Err(ParamError::new(
                    format!("{prefix}.exchange_timeout_ms"),
                    format!(
                        "must be in [0.01, {}] ms (up to {prefix}.watchdog_ms: a frame later than the SM watchdog finds the drive already stopped), got {ms}",
                        self.watchdog_ms
                    ),
                ));
            }
        }
        if !(self.bringup_timeout_ms.is_finite()
            && (100.0..=60_000.0).contains(&self.bringup_timeout_ms))
        {
            return Err(ParamError::new(
                format!("{prefix}.bringup_timeout_ms"),
                format!(
                    "must be in [100, 60000] ms, got {}",
                    self.bringup_timeout_ms
                ),
            ));
        }
        positive(&format!("{prefix}.peak_current_a"), self.peak_current_a)?;
        positive(
            &format!("{prefix}.continuous_current_a"),
            self.continuous_current_a,
        )?;
        positive(&format!("{prefix}.probe_range_m"), self.probe_range_m)?;
        positive(&format!("{prefix}.position_lsb_m"), self.position_lsb_m)?;
        if !(self.dc_drift_max_ppm.is_finite() && (1.0..=10_000.0).contains(&self.dc_drift_max_ppm))
        {
            return Err(ParamError::new(
                format!("{prefix}.dc_drift_max_ppm"),
                format!("must be in [1, 10000] ppm, got {}", self.dc_drift_max_ppm),
            ));
        }
        positive(&format!("{prefix}.adc_full_scale_m"), self.adc_full_scale_m)?;
        positive(&format!("{prefix}.dac_full_scale_a"), self.dac_full_scale_a)?;
        if self.profile == Profile::Analog && self.dac_full_scale_a < self.peak_current_a {
            return Err(ParamError::new(
                format!("{prefix}.dac_full_scale_a"),
                format!(
                    "{} A at full scale cannot command the peak current {} A",
                    self.dac_full_scale_a, self.peak_current_a
                ),
            ));
        }
        if self.probe_range_m / self.position_lsb_m > f64::from(i32::MAX) {
            return Err(ParamError::new(
                format!("{prefix}.position_lsb_m"),
                format!(
                    "{} m counts do not carry the probe range ±{} m in the 32-bit 0x6064",
                    self.position_lsb_m, self.probe_range_m
                ),
            ));
        }
        self.rack(prefix)?;
        self.layout(prefix).map(|_| ())
    }

    /// Where the host finds its values in the images of the PDO map in
    /// force. Entries the host does not know are carried (the drive may
    /// use them) and left 0.
    ///
    /// # Errors
    /// [`ParamError`] naming `prefix.rx_pdo[i]`/`prefix.tx_pdo[i]` for a
    /// width other than 8/16/32, a duplicate, a known object at the wrong
    /// width, an image beyond [`MAX_PDO_BYTES`], or a missing controlword,
    /// target, statusword or position.
    pub fn layout(&self, prefix: &str) -> Result<ImageLayout, ParamError> {
        let mut l = ImageLayout {
            out_len: 0,
            in_len: 0,
            controlword: usize::MAX,
            target: (usize::MAX, false),
            statusword: usize::MAX,
            position: usize::MAX,
            current: None,
            adc_status: None,
        };
        for (dir, entries) in [("rx_pdo", self.rx_entries()), ("tx_pdo", self.tx_entries())] {
            let mut offset = 0usize;
            for (i, e) in entries.iter().enumerate() {
                let key = format!("{prefix}.{dir}[{i}]");
                if !matches!(e.bits, 8 | 16 | 32) {
                    return Err(ParamError::new(
                        key,
                        format!("bits must be 8, 16 or 32, got {}", e.bits),
                    ));
                }
                if entries[..i]
                    .iter()
                    .any(|p| p.index == e.index && p.subindex == e.subindex)
                {
                    return Err(ParamError::new(
                        key,
                        format!("0x{:04X}:{:02X} is mapped twice", e.index, e.subindex),
                    ));
                }
                let known = self.known(dir == "rx_pdo");
                if let Some((k, name)) = known
                    .iter()
                    .find(|(k, _)| k.index == e.index && k.subindex == e.subindex)
                {
                    if k.bits != e.bits {
                        return Err(ParamError::new(
                            key,
                            format!(
                                "0x{:04X} ({name}) is {} bits wide, not {}",
                                e.index, k.bits, e.bits
                            ),
                        ));
                    }
                    match (dir, e.index) {
                        ("rx_pdo", 0x6040 | 0x7010) => l.controlword = offset,
                        ("rx_pdo", 0x7000) => l.target = (offset, false),
                        ("tx_pdo", 0x6020) => l.statusword = offset,
                        ("tx_pdo", 0x6000) if e.subindex == ADC_STATUS.subindex => {
                            l.adc_status = Some(offset)
                        }
                        ("tx_pdo", 0x6000) => l.position = offset,
                        ("rx_pdo", 0x6071 | 0x2071) => {
                            if l.target.0 != usize::MAX {
                                return Err(ParamError::new(
                                    key,
                                    "a second target (0x6071 and 0x2071 are alternatives)",
                                ));
                            }
                            l.target = (offset, e.index == 0x2071);
                        }
                        ("tx_pdo", 0x6041) => l.statusword = offset,
                        ("tx_pdo", 0x6064) => l.position = offset,
                        ("tx_pdo", 0x6078 | 0x2078) => {
                            if l.current.is_some() {
                                return Err(ParamError::new(
                                    key,
                                    "a second current actual (0x6078 and 0x2078 are alternatives)",
                                ));
                            }
                            l.current = Some((offset, e.index == 0x2078));
                        }
                        _ => {}
                    }
                }
                offset += usize::from(e.bits / 8);
                if offset > MAX_PDO_BYTES {
                    return Err(ParamError::new(
                        key,
                        format!("the PDO is longer than {MAX_PDO_BYTES} bytes"),
                    ));
                }
            }
            if dir == "rx_pdo" {
                l.out_len = offset;
            } else {
                l.in_len = offset;
            }
        }
        let missing = |dir: &str, what: &str| {
            ParamError::new(format!("{prefix}.{dir}"), format!("the map has no {what}"))
        };
        let analog = self.profile == Profile::Analog;
        if l.controlword == usize::MAX {
            return Err(missing(
                "rx_pdo",
                if analog {
                    "enable output 0x7010:01"
                } else {
                    "controlword 0x6040"
                },
            ));
        }
        if l.target.0 == usize::MAX {
            return Err(missing(
                "rx_pdo",
                if analog {
                    "DAC output 0x7000:01"
                } else {
                    "target (0x6071 target torque or 0x2071 target current)"
                },
            ));
        }
        if l.statusword == usize::MAX && !analog {
            return Err(missing("tx_pdo", "statusword 0x6041"));
        }
        if l.position == usize::MAX {
            return Err(missing(
                "tx_pdo",
                if analog {
                    "ADC input 0x6000:11"
                } else {
                    "position actual 0x6064"
                },
            ));
        }
        if !self.slaves.is_empty() {
            // A rack: the host's scratch image is the single analog
            // device's (DAC, enable; ADC, status), gathered from and
            // scattered to the terminals; without a status line, none.
            if self.slaves.iter().all(|s| s.status.is_none()) {
                l.statusword = usize::MAX;
            }
            if self.slaves.iter().all(|s| s.adc_status.is_none()) {
                l.adc_status = None;
            }
        }
        Ok(l)
    }
}

/// One slave of the rack (`[[backend.ethercat.slaves]]`; its keys and
/// their validation: [`super::rack`]).
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RackSlave {
    /// 0-based position on the segment, the coupler counted.
    pub position: u16,
    /// Expected vendor id (SII word 0x0008).
    pub vendor_id: u32,
    /// Expected product code (SII word 0x000A).
    pub product_id: u32,
    /// A name for messages (`"EL4132"`).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub name: String,
    /// The terminal's outputs in image order (empty: `dac`, `enable`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rx_pdo: Vec<PdoEntry>,
    /// The terminal's inputs in image order (empty: `adc`, `status`,
    /// `fault`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tx_pdo: Vec<PdoEntry>,
    /// The probe's ADC channel (16 bits, input).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adc: Option<PdoEntry>,
    /// The amplifier's DAC channel (16 bits, output).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dac: Option<PdoEntry>,
    /// The amplifier's enable (bit 0, output).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub enable: Option<PdoEntry>,
    /// The amplifier's ready line (bit 0; bit 1 its fault line when 2
    /// bits or wider; input).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub status: Option<PdoEntry>,
    /// The amplifier's fault line (bit 0, input), beside a 1-bit `status`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fault: Option<PdoEntry>,
    /// The probe's ADC channel status word (16 bits, input; EL31xx layout:
    /// bit 0 underrange, bit 1 overrange, bit 6 error).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adc_status: Option<PdoEntry>,
    /// The terminal's PDO contents are fixed (Beckhoff's analog terminals:
    /// one PDO per channel, 0x1600/0x1601, 0x1A00/0x1A02, not writable):
    /// the host writes no map over CoE and takes the terminal's own
    /// assignment, which must lay out as `rx_pdo`/`tx_pdo` (checked by
    /// size). Default false: a slave with a CoE mailbox gets its map
    /// written.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub fixed_pdo: bool,
}

impl RackSlave {
    /// The outputs in force: `rx_pdo`, or the slave's output signals.
    pub fn rx_entries(&self) -> Vec<PdoEntry> {
        if self.rx_pdo.is_empty() {
            [self.dac, self.enable].into_iter().flatten().collect()
        } else {
            self.rx_pdo.clone()
        }
    }

    /// The inputs in force: `tx_pdo`, or the slave's input signals.
    pub fn tx_entries(&self) -> Vec<PdoEntry> {
        if self.tx_pdo.is_empty() {
            [self.adc_status, self.adc, self.status, self.fault]
                .into_iter()
                .flatten()
                .collect()
        } else {
            self.tx_pdo.clone()
        }
    }

    /// Image bytes (outputs, inputs).
    pub fn image_bytes(&self) -> (usize, usize) {
        let bytes = |e: &[PdoEntry]| {
            e.iter()
                .map(|e| usize::from(e.bits))
                .sum::<usize>()
                .div_ceil(8)
        };
        (bytes(&self.rx_entries()), bytes(&self.tx_entries()))
    }

    /// `name` or `slave at position N`, for messages.
    pub fn label(&self) -> String {
        if self.name.is_empty() {
            format!("slave at position {}", self.position)
        } else {
            format!("{} at position {}", self.name, self.position)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_map_lays_out_and_bad_maps_name_the_entry() {
        let c = EthercatConfig::default();
        let l = c.layout("backend.ethercat").unwrap();
        assert_eq!((l.out_len, l.in_len), (6, 10));
        assert_eq!((l.controlword, l.target), (0, (2, true)));
        assert_eq!(
            (l.statusword, l.position, l.current),
            (0, 2, Some((6, true)))
        );
        let mut c = EthercatConfig {
            rx_pdo: vec![CONTROLWORD, PdoEntry::new(0x6071, 32)],
            ..EthercatConfig::default()
        };
        let e = c.validate("backend.ethercat").unwrap_err();
        assert_eq!(e.key, "backend.ethercat.rx_pdo[1]");
        c.rx_pdo = vec![CONTROLWORD];
        assert_eq!(
            c.validate("backend.ethercat").unwrap_err().key,
            "backend.ethercat.rx_pdo"
        );
        c.rx_pdo = vec![CONTROLWORD, TARGET_TORQUE, PdoEntry::new(0x6072, 16)];
        let l = c.layout("k").unwrap();
        assert_eq!((l.out_len, l.target), (6, (2, false)));
        let c = EthercatConfig {
            watchdog_ms: 0.0,
            ..EthercatConfig::default()
        };
        assert_eq!(
            c.validate("backend.ethercat").unwrap_err().key,
            "backend.ethercat.watchdog_ms"
        );
        assert_eq!(PdoEntry::from_raw(CONTROLWORD.raw()), CONTROLWORD);
        // The analog profile: DAC (i16) + enable (u8) out; ADC (i16) +
        // status (u8) + the ADC's status word (u16) in.
        let a = EthercatConfig {
            profile: Profile::Analog,
            ..EthercatConfig::default()
        };
        let l = a.layout("k").unwrap();
        assert_eq!((l.out_len, l.in_len), (3, 5));
        assert_eq!(l.adc_status, Some(3));
        assert_eq!(
            (l.target, l.controlword, l.position, l.statusword),
            ((0, false), 2, 0, 2)
        );
        assert_eq!(a.expected_product_id(), 0x0A10);
        let a = EthercatConfig {
            profile: Profile::Analog,
            dac_full_scale_a: 5.0,
            ..EthercatConfig::default()
        };
        assert_eq!(
            a.validate("backend.ethercat").unwrap_err().key,
            "backend.ethercat.dac_full_scale_a"
        );
        let d = EthercatConfig {
            dc_drift_max_ppm: 0.5,
            ..EthercatConfig::default()
        };
        assert_eq!(
            d.validate("backend.ethercat").unwrap_err().key,
            "backend.ethercat.dc_drift_max_ppm"
        );
        // The default round-trip bound follows the loop's stall bound,
        // capped by the SM watchdog (20 ms), at least a period.
        let c = EthercatConfig::default();
        assert_eq!(c.exchange_timeout_ns(200_000, Some(3_000_000)), 3_000_000);
        assert_eq!(c.exchange_timeout_ns(200_000, Some(24_200_000)), 20_000_000);
        assert_eq!(c.exchange_timeout_ns(200_000, None), 20_000_000);
        assert_eq!(c.exchange_timeout_ns(200_000, Some(100_000)), 200_000);
        assert_eq!(
            c.exchange_timeout_ns(30_000_000, Some(3_000_000)),
            30_000_000
        );
        // An explicit key overrides it; out of range it is refused.
        let c = EthercatConfig {
            exchange_timeout_ms: Some(7.5),
            ..EthercatConfig::default()
        };
        assert_eq!(c.exchange_timeout_ns(200_000, Some(3_000_000)), 7_500_000);
        for bad in [0.001, 20.5, f64::NAN] {
            let c = EthercatConfig {
                exchange_timeout_ms: Some(bad),
                ..EthercatConfig::default()
            };
            let e = c.validate("backend.ethercat").unwrap_err();
            assert_eq!(e.key, "backend.ethercat.exchange_timeout_ms", "{bad}");
        }
        assert_eq!(CONTROLWORD.raw(), 0x6040_0010);
    }
}
