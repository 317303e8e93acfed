//! The application behind the virtual slave's ESC: a CiA 402 servo drive
//! in cyclic synchronous torque mode (IEC 61800-7-201 = CiA 402-2) around
//! the emulated plant ([`DeviceCore`]), its object dictionary (CoE, ETG.1000.6
//! §5.6) and the SDO services the master uses (expedited upload and
//! download, abort).
//!
//! # Object dictionary
//!
//! | index:sub | type | access | meaning |
//! |---|---|---|---|
//! | 0x1000:00 | u32 | ro | device type 0x0002_0192 (CiA 402 servo) |
//! | 0x1018:01–04 | u32 | ro | vendor, product, revision, serial |
//! | 0x1600:00–08 | u8 / u32 | rw in PRE-OP | RxPDO mapping (host → drive) |
//! | 0x1A00:00–08 | u8 / u32 | rw in PRE-OP | TxPDO mapping (drive → host) |
//! | 0x1C12:00–01 | u8 / u16 | rw in PRE-OP | SM2 assignment (0x1600) |
//! | 0x1C13:00–01 | u8 / u16 | rw in PRE-OP | SM3 assignment (0x1A00) |
//! | 0x6040:00 | u16 | rw, Rx | controlword |
//! | 0x6041:00 | u16 | ro, Tx | statusword |
//! | 0x6060:00 | i8 | rw | modes of operation: only 10 (CST) is accepted |
//! | 0x6061:00 | i8 | ro | modes of operation display |
//! | 0x6064:00 | i32 | ro, Tx | position actual value, counts of `position_lsb_m` (the probe) |
//! | 0x6071:00 | i16 | rw, Rx | target torque, ‰ of 0x6075 |
//! | 0x6073:00 | u16 | ro | max current, ‰ of 0x6075 (the peak current) |
//! | 0x6075:00 | u32 | ro | motor rated current, mA (the continuous current) |
//! | 0x6078:00 | i16 | ro, Tx | current actual value, ‰ of 0x6075 |
//! | 0x2071:00 | i32 | rw, Rx | target current, µA (manufacturer-specific) |
//! | 0x2078:00 | i32 | ro, Tx | current actual value, µA (manufacturer-specific) |
//!
//! Mapping an object not marked Rx/Tx in that direction, or at another
//! width, is refused with abort 0x0604_0041; more than 8 entries or 32
//! bytes with 0x0604_0042.
//!
//! # The analog-terminal profile
//!
//! The same ESC with analog I/O instead of the drive (device type
//! 0x0000_0191), the amplifier behind the DAC:
//!
//! | index:sub | type | access | meaning |
//! |---|---|---|---|
//! | 0x7000:01 | i16 | Rx | DAC channel 1: ±32767 = ± `dac_full_scale_a` |
//! | 0x7010:01 | u8 | Rx | digital output, bit 0: amplifier enable (a rising edge enables and clears a latched fault) |
//! | 0x6000:11 | i16 | ro, Tx | ADC channel 1: ±32767 = ± `adc_full_scale_m` (saturated; 0 with the error bit) |
//! | 0x6000:01 | u16 | ro, Tx | ADC channel 1 status (EL31xx layout): bit 0 underrange, bit 1 overrange, bit 6 error (the probe has no valid reading) |
//! | 0x6020:01 | u8 | ro, Tx | digital input: bit 0 amplifier ready (enabled), bit 1 amplifier fault |
//!
//! plus 0x1018, 0x1600/0x1A00, 0x1C12/0x1C13 as above.

use super::sii::MBX_SIZE;
use crate::emulator::DeviceCore;
use bench_hal::ethercat::config::{EthercatConfig, PdoEntry, Profile, MAX_PDO_BYTES};
use bench_hal::ethercat::wire::cia402::*;
use bench_hal::ethercat::wire::{adc_status, le16};
use bench_hal::{Command, Sample};
use bench_protocol::DeviceFault;

/// SDO abort codes (ETG.1000.6 Table 41).
pub mod abort {
    /// Client/server command specifier not valid.
    pub const COMMAND: u32 = 0x0504_0001;
    /// Attempt to write a read-only object.
    pub const READ_ONLY: u32 = 0x0601_0002;
    /// Object does not exist.
    pub const NO_OBJECT: u32 = 0x0602_0000;
    /// Object cannot be mapped to the PDO.
    pub const NOT_MAPPABLE: u32 = 0x0604_0041;
    /// Number and length of mapped objects exceed the PDO.
    pub const PDO_LENGTH: u32 = 0x0604_0042;
    /// Data type does not match (length).
    pub const LENGTH: u32 = 0x0607_0010;
    /// Subindex does not exist.
    pub const NO_SUBINDEX: u32 = 0x0609_0011;
    /// Value range exceeded.
    pub const RANGE: u32 = 0x0609_0030;
    /// Not in the present device state.
    pub const STATE: u32 = 0x0800_0022;
}

/// CiA 402 drive states (IEC 61800-7-201 Figure 17).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State402 {
    /// Switch on disabled.
    SwitchOnDisabled,
    /// Ready to switch on.
    ReadyToSwitchOn,
    /// Switched on.
    SwitchedOn,
    /// Operation enabled: current flows.
    OperationEnabled,
    /// Quick stop active (current 0).
    QuickStopActive,
    /// Fault (current 0), left by a fault reset.
    Fault,
}

impl State402 {
    /// The statusword of the state (bits 0–6, voltage and remote set).
    pub fn statusword(self) -> u16 {
        SW_REMOTE
            | match self {
                Self::SwitchOnDisabled => SW_SWITCH_ON_DISABLED,
                Self::ReadyToSwitchOn => SW_QUICK_STOP | SW_VOLTAGE_ENABLED | SW_READY,
                Self::SwitchedOn => SW_QUICK_STOP | SW_VOLTAGE_ENABLED | SW_READY | SW_SWITCHED_ON,
                Self::OperationEnabled => {
                    SW_QUICK_STOP
                        | SW_VOLTAGE_ENABLED
                        | SW_READY
                        | SW_SWITCHED_ON
                        | SW_OPERATION_ENABLED
                }
                Self::QuickStopActive => {
                    SW_VOLTAGE_ENABLED | SW_READY | SW_SWITCHED_ON | SW_OPERATION_ENABLED
                }
                Self::Fault => SW_FAULT,
            }
    }
}

const RX_MAPPABLE: [PdoEntry; 3] = [
    bench_hal::ethercat::config::CONTROLWORD,
    bench_hal::ethercat::config::TARGET_TORQUE,
    bench_hal::ethercat::config::TARGET_CURRENT,
];
const TX_MAPPABLE: [PdoEntry; 4] = [
    bench_hal::ethercat::config::STATUSWORD,
    bench_hal::ethercat::config::POSITION_ACTUAL,
    bench_hal::ethercat::config::CURRENT_ACTUAL,
    bench_hal::ethercat::config::CURRENT_ACTUAL_UA,
];
const RX_MAPPABLE_ANALOG: [PdoEntry; 2] = [
    bench_hal::ethercat::config::DAC_OUTPUT,
    bench_hal::ethercat::config::ENABLE_OUTPUT,
];
const TX_MAPPABLE_ANALOG: [PdoEntry; 3] = [
    bench_hal::ethercat::config::ADC_INPUT,
    bench_hal::ethercat::config::STATUS_INPUT,
    bench_hal::ethercat::config::ADC_STATUS,
];

/// A PDO mapping object (0x1600 or 0x1A00) and its assignment.
#[derive(Debug, Clone)]
struct Pdo {
    entries: [u32; 8],
    count: u8,
    assigned: bool,
}

impl Pdo {
    fn new(map: &[PdoEntry]) -> Self {
        let mut entries = [0u32; 8];
        for (e, m) in entries.iter_mut().zip(map) {
            *e = m.raw();
        }
        Self {
            entries,
            count: map.len() as u8,
            assigned: true,
        }
    }

    fn bytes(&self) -> usize {
        if !self.assigned {
            return 0;
        }
        self.entries[..usize::from(self.count)]
            .iter()
            .map(|e| usize::from(PdoEntry::from_raw(*e).bits / 8))
            .sum()
    }
}

/// The drive: CiA 402 state machine, object dictionary, plant.
#[derive(Debug)]
pub struct Drive {
    pub(super) core: DeviceCore,
    profile: Profile,
    adc_full_scale_m: f64,
    dac_full_scale_a: f64,
    enable_bit: bool,
    state: State402,
    controlword: u16,
    mode: i8,
    rx: Pdo,
    tx: Pdo,
    vendor_id: u32,
    product_id: u32,
    rated_current_a: f64,
    peak_current_a: f64,
    position_lsb_m: f64,
    last: Option<Sample>,
    demand_a: f64,
}

fn entry_value(bytes: &[u8], at: usize, bits: u8) -> i64 {
    match bits {
        8 => i64::from(bytes[at] as i8),
        16 => i64::from(le16(bytes, at) as i16),
        _ => i64::from(bench_hal::ethercat::wire::le32(bytes, at) as i32),
    }
}

impl Drive {
    /// A drive around `core`, its PDO map the defaults of `cfg`.
    pub fn new(core: DeviceCore, cfg: &EthercatConfig, vendor_id: u32, product_id: u32) -> Self {
        // The device's own defaults (not the host's map).
        let defaults = EthercatConfig {
            profile: cfg.profile,
            ..EthercatConfig::default()
        };
        Self {
            core,
            profile: cfg.profile,
            adc_full_scale_m: cfg.adc_full_scale_m,
            dac_full_scale_a: cfg.dac_full_scale_a,
            enable_bit: false,
            state: State402::SwitchOnDisabled,
            controlword: 0,
            mode: 0,
            rx: Pdo::new(&defaults.rx_entries()),
            tx: Pdo::new(&defaults.tx_entries()),
            vendor_id,
            product_id,
            rated_current_a: cfg.continuous_current_a,
            peak_current_a: cfg.peak_current_a,
            position_lsb_m: cfg.position_lsb_m,
            last: None,
            demand_a: 0.0,
        }
    }

    /// SM2 (outputs) length the PDO map needs, bytes.
    pub fn rx_bytes(&self) -> usize {
        self.rx.bytes()
    }

    /// SM3 (inputs) length the PDO map needs, bytes.
    pub fn tx_bytes(&self) -> usize {
        self.tx.bytes()
    }

    /// CiA 402 state.
    pub fn state(&self) -> State402 {
        self.state
    }

    /// Statusword now.
    pub fn statusword(&self) -> u16 {
        self.state.statusword()
    }

    fn leave_enabled(&mut self) {
        if self.state == State402::OperationEnabled {
            self.core.disable();
        }
    }

    /// The drive faults (watchdog, injected amplifier fault): 0 A at
    /// once, fault latched, state FAULT.
    pub fn fault(&mut self, fault: DeviceFault) {
        self.core.trip(fault);
        self.state = State402::Fault;
        self.demand_a = 0.0;
    }

    /// The outputs are no longer valid (the slave left OP): the drive
    /// disables as on a "disable voltage".
    pub fn outputs_invalid(&mut self, now_ns: u64) {
        self.apply_controlword(CW_DISABLE_VOLTAGE, now_ns);
        self.demand_a = 0.0;
    }

    /// 0 A, disabled, without a fault (the emulator stops).
    pub fn fault_free_disable(&mut self) {
        self.core.disable();
        if self.state != State402::Fault {
            self.state = State402::SwitchOnDisabled;
        }
    }

    /// Applies a controlword (IEC 61800-7-201 Table 27) at device time
    /// `now_ns`.
    fn apply_controlword(&mut self, cw: u16, now_ns: u64) {
        let rising_reset = cw & CW_FAULT_RESET != 0 && self.controlword & CW_FAULT_RESET == 0;
        self.controlword = cw;
        use State402::*;
        if self.state == Fault {
            if rising_reset {
                self.state = SwitchOnDisabled;
            }
            return;
        }
        if cw & CW_FAULT_RESET != 0 {
            return;
        }
        let next = if cw & 0x0002 == 0 {
            // Disable voltage.
            SwitchOnDisabled
        } else if cw & 0x0004 == 0 {
            // Quick stop.
            match self.state {
                OperationEnabled => QuickStopActive,
                _ => SwitchOnDisabled,
            }
        } else if cw & 0x0001 == 0 {
            // Shutdown.
            match self.state {
                SwitchOnDisabled | SwitchedOn | OperationEnabled | ReadyToSwitchOn => {
                    ReadyToSwitchOn
                }
                s => s,
            }
        } else if cw & 0x0008 == 0 {
            // Switch on / disable operation.
            match self.state {
                ReadyToSwitchOn | OperationEnabled | SwitchedOn => SwitchedOn,
                s => s,
            }
        } else {
            // Enable operation (only in CST).
            match self.state {
                SwitchedOn | OperationEnabled if self.mode == MODE_CST => OperationEnabled,
                ReadyToSwitchOn => SwitchedOn,
                s => s,
            }
        };
        let next = if self.state == QuickStopActive && next == QuickStopActive {
            // The quick stop is done at once (the current is 0).
            SwitchOnDisabled
        } else {
            next
        };
        if next != OperationEnabled {
            self.leave_enabled();
        } else if self.state != OperationEnabled {
            self.core.enable(now_ns);
        }
        self.state = next;
    }

    /// One SM-synchronous cycle at device time `now_ns`: the outputs the
    /// master wrote (`None` in SAFE-OP: outputs not valid, held at a
    /// disable), then the plant advances one period and the inputs are
    /// written to `inputs`.
    pub fn cycle(&mut self, outputs: Option<&[u8]>, inputs: &mut [u8], now_ns: u64) {
        if self.profile == Profile::Analog {
            return self.analog_cycle(outputs, inputs, now_ns);
        }
        let mut cw = CW_DISABLE_VOLTAGE;
        let mut target_a = 0.0;
        if let Some(out) = outputs {
            let mut at = 0;
            for raw in &self.rx.entries[..usize::from(self.rx.count)] {
                let e = PdoEntry::from_raw(*raw);
                if at + usize::from(e.bits / 8) > out.len() {
                    break;
                }
                let v = entry_value(out, at, e.bits);
                match e.index {
                    0x6040 => cw = v as u16,
                    0x6071 => target_a = v as f64 * 1e-3 * self.rated_current_a,
                    0x2071 => target_a = v as f64 * 1e-6,
                    _ => {}
                }
                at += usize::from(e.bits / 8);
            }
        }
        self.apply_controlword(cw, now_ns);
        if self.state == State402::OperationEnabled {
            self.demand_a = target_a;
            let seq = self.last.map_or(0, |s| s.seq);
            self.core.command(
                Command {
                    current_a: target_a,
                    answers_seq: seq,
                },
                now_ns,
            );
        } else {
            self.demand_a = 0.0;
        }
        let s = self.core.tick(now_ns);
        if !s.position_m.is_finite() && self.core.fault().is_none() {
            // The drive's feedback failed: a servo drive faults on it
            // (position actual value not valid), dropping the current.
            self.core.trip(DeviceFault::Sensor);
        }
        if self.core.fault().is_some() && self.state == State402::OperationEnabled {
            self.state = State402::Fault;
        }
        self.last = Some(s);
        self.write_inputs(inputs);
    }

    /// The analog terminals' cycle: the enable output's rising edge enables
    /// the amplifier (clearing a latched fault), its 0 disables it; the DAC
    /// value is the current while enabled; then the plant advances and the
    /// ADC and the status input are latched.
    fn analog_cycle(&mut self, outputs: Option<&[u8]>, inputs: &mut [u8], now_ns: u64) {
        let mut dac = 0i64;
        let mut en = false;
        if let Some(out) = outputs {
            let mut at = 0;
            for raw in &self.rx.entries[..usize::from(self.rx.count)] {
                let e = PdoEntry::from_raw(*raw);
                if at + usize::from(e.bits / 8) > out.len() {
                    break;
                }
                let v = entry_value(out, at, e.bits);
                match e.index {
                    0x7000 => dac = v,
                    0x7010 => en = v & 1 != 0,
                    _ => {}
                }
                at += usize::from(e.bits / 8);
            }
        }
        if en && !self.enable_bit {
            self.core.enable(now_ns);
        } else if !en && self.core.is_enabled() {
            self.core.disable();
        }
        self.enable_bit = en;
        let current_a = dac as f64 / 32767.0 * self.dac_full_scale_a;
        self.demand_a = if self.core.is_enabled() {
            current_a
        } else {
            0.0
        };
        if self.core.is_enabled() {
            let seq = self.last.map_or(0, |s| s.seq);
            self.core.command(
                Command {
                    current_a,
                    answers_seq: seq,
                },
                now_ns,
            );
        }
        let s = self.core.tick(now_ns);
        self.last = Some(s);
        self.write_inputs(inputs);
    }

    /// Writes the inputs of the latest sample and state (also before the
    /// first cycle).
    pub fn write_inputs(&self, inputs: &mut [u8]) {
        let sw = self.statusword();
        let (pos, cur) = self.last.map_or((0.0, 0.0), |s| {
            (s.position_m, self.core.commanded_current_a())
        });
        let adc_status = self.last.map_or(0, |s| {
            adc_status::of(s.position_m, s.flags.out_of_range, self.adc_full_scale_m)
        });
        let mut at = 0;
        for raw in &self.tx.entries[..usize::from(self.tx.count)] {
            let e = PdoEntry::from_raw(*raw);
            let n = usize::from(e.bits / 8);
            if at + n > inputs.len() {
                break;
            }
            let v: i64 = match e.index {
                0x6041 => i64::from(sw),
                0x6064 => (pos / self.position_lsb_m)
                    .round()
                    .clamp(f64::from(i32::MIN), f64::from(i32::MAX))
                    as i64,
                0x6078 => (cur / self.rated_current_a * 1e3)
                    .round()
                    .clamp(-32767.0, 32767.0) as i64,
                0x2078 => (cur * 1e6).round().clamp(-2e9, 2e9) as i64,
                0x6000 if e.subindex == 0x01 => i64::from(adc_status),
                0x6000 => (pos / self.adc_full_scale_m * 32767.0)
                    .round()
                    .clamp(-32767.0, 32767.0) as i64,
                0x6020 => {
                    i64::from(self.core.is_enabled()) | i64::from(self.core.fault().is_some()) << 1
                }
                _ => 0,
            };
            inputs[at..at + n].copy_from_slice(&v.to_le_bytes()[..n]);
            at += n;
        }
    }

    /// The current the drive commands now, A.
    pub fn current_a(&self) -> f64 {
        self.core.commanded_current_a()
    }

    /// The communication objects both profiles have.
    fn upload_common(&self, index: u16, sub: u8) -> Result<(u32, u8), u32> {
        let pdo = |p: &Pdo| match sub {
            0 => Ok((u32::from(p.count), 1)),
            1..=8 => Ok((p.entries[usize::from(sub - 1)], 4)),
            _ => Err(abort::NO_SUBINDEX),
        };
        let assign = |p: &Pdo, which: u16| match sub {
            0 => Ok((u32::from(p.assigned), 1)),
            1 => Ok((u32::from(which), 2)),
            _ => Err(abort::NO_SUBINDEX),
        };
        match index {
            0x1018 => match sub {
                0 => Ok((4, 1)),
                1 => Ok((self.vendor_id, 4)),
                2 => Ok((self.product_id, 4)),
                3 => Ok((0x0001_0000, 4)),
                4 => Ok((1, 4)),
                _ => Err(abort::NO_SUBINDEX),
            },
            0x1600 => pdo(&self.rx),
            0x1A00 => pdo(&self.tx),
            0x1C12 => assign(&self.rx, 0x1600),
            0x1C13 => assign(&self.tx, 0x1A00),
            _ => Err(abort::NO_OBJECT),
        }
    }

    /// SDO upload of `index`:`sub`: value and its size in bytes.
    fn upload(&self, index: u16, sub: u8) -> Result<(u32, u8), u32> {
        let pdo = |p: &Pdo| match sub {
            0 => Ok((u32::from(p.count), 1)),
            1..=8 => Ok((p.entries[usize::from(sub - 1)], 4)),
            _ => Err(abort::NO_SUBINDEX),
        };
        let assign = |p: &Pdo, which: u16| match sub {
            0 => Ok((u32::from(p.assigned), 1)),
            1 => Ok((u32::from(which), 2)),
            _ => Err(abort::NO_SUBINDEX),
        };
        let one = |v: u32, size: u8| {
            if sub == 0 {
                Ok((v, size))
            } else {
                Err(abort::NO_SUBINDEX)
            }
        };
        let cur = self.current_a();
        if self.profile == Profile::Analog {
            return match index {
                0x1000 => one(0x0000_0191, 4),
                0x1018 | 0x1600 | 0x1A00 | 0x1C12 | 0x1C13 => self.upload_common(index, sub),
                0x7000 if sub == 1 => Ok((
                    ((self.demand_a / self.dac_full_scale_a * 32767.0).round() as i16) as u16
                        as u32,
                    2,
                )),
                0x7010 if sub == 1 => Ok((u32::from(self.enable_bit), 1)),
                0x6000 if sub == 0x01 => Ok((
                    u32::from(self.last.map_or(0, |s| {
                        adc_status::of(s.position_m, s.flags.out_of_range, self.adc_full_scale_m)
                    })),
                    2,
                )),
                0x6000 if sub == 0x11 => Ok((
                    (self.last.map_or(0.0, |s| s.position_m) / self.adc_full_scale_m * 32767.0)
                        .round()
                        .clamp(-32767.0, 32767.0) as i16 as u16 as u32,
                    2,
                )),
                0x6020 if sub == 1 => Ok((
                    u32::from(self.core.is_enabled()) | u32::from(self.core.fault().is_some()) << 1,
                    1,
                )),
                0x7000 | 0x7010 | 0x6000 | 0x6020 => Err(abort::NO_SUBINDEX),
                _ => Err(abort::NO_OBJECT),
            };
        }
        match index {
            0x1000 => one(0x0002_0192, 4),
            0x1018 => match sub {
                0 => Ok((4, 1)),
                1 => Ok((self.vendor_id, 4)),
                2 => Ok((self.product_id, 4)),
                3 => Ok((0x0001_0000, 4)),
                4 => Ok((1, 4)),
                _ => Err(abort::NO_SUBINDEX),
            },
            0x1600 => pdo(&self.rx),
            0x1A00 => pdo(&self.tx),
            0x1C12 => assign(&self.rx, 0x1600),
            0x1C13 => assign(&self.tx, 0x1A00),
            0x6040 => one(u32::from(self.controlword), 2),
            0x6041 => one(u32::from(self.statusword()), 2),
            0x6060 => one(u32::from(self.mode as u8), 1),
            0x6061 => one(u32::from(self.mode as u8), 1),
            0x6064 => one(
                self.last
                    .map_or(0, |s| (s.position_m / self.position_lsb_m).round() as i32)
                    as u32,
                4,
            ),
            0x6071 => one(
                ((self.demand_a / self.rated_current_a * 1e3).round() as i16) as u16 as u32,
                2,
            ),
            0x6073 => one(
                (self.peak_current_a / self.rated_current_a * 1e3).round() as u32 & 0xFFFF,
                2,
            ),
            0x6075 => one((self.rated_current_a * 1e3).round() as u32, 4),
            0x6078 => one(
                ((cur / self.rated_current_a * 1e3).round() as i16) as u16 as u32,
                2,
            ),
            0x2071 => one((self.demand_a * 1e6).round() as i32 as u32, 4),
            0x2078 => one((cur * 1e6).round() as i32 as u32, 4),
            _ => Err(abort::NO_OBJECT),
        }
    }

    /// SDO download of `value` (`size` bytes) to `index`:`sub` in AL state
    /// `al_state`.
    fn download(
        &mut self,
        index: u16,
        sub: u8,
        value: u32,
        size: u8,
        preop: bool,
    ) -> Result<(), u32> {
        let want = |n: u8| want_size(size, n);
        match (index, sub) {
            (0x1600 | 0x1A00, _) => {
                if !preop {
                    return Err(abort::STATE);
                }
                let rx = index == 0x1600;
                let analog = self.profile == Profile::Analog;
                let mappable: &[PdoEntry] = match (rx, analog) {
                    (true, false) => &RX_MAPPABLE,
                    (false, false) => &TX_MAPPABLE,
                    (true, true) => &RX_MAPPABLE_ANALOG,
                    (false, true) => &TX_MAPPABLE_ANALOG,
                };
                let p = if rx { &mut self.rx } else { &mut self.tx };
                match sub {
                    0 => {
                        want(1)?;
                        let n = value as usize;
                        if n > 8 {
                            return Err(abort::PDO_LENGTH);
                        }
                        let bytes: usize = p.entries[..n]
                            .iter()
                            .map(|e| usize::from(PdoEntry::from_raw(*e).bits / 8))
                            .sum();
                        if bytes > MAX_PDO_BYTES || p.entries[..n].contains(&0) {
                            return Err(abort::PDO_LENGTH);
                        }
                        p.count = n as u8;
                        Ok(())
                    }
                    1..=8 => {
                        want(4)?;
                        if p.count != 0 {
                            return Err(abort::STATE);
                        }
                        let e = PdoEntry::from_raw(value);
                        if !mappable.contains(&e) {
                            return Err(abort::NOT_MAPPABLE);
                        }
                        p.entries[usize::from(sub - 1)] = value;
                        Ok(())
                    }
                    _ => Err(abort::NO_SUBINDEX),
                }
            }
            (0x1C12 | 0x1C13, _) => {
                if !preop {
                    return Err(abort::STATE);
                }
                let (p, which) = if index == 0x1C12 {
                    (&mut self.rx, 0x1600)
                } else {
                    (&mut self.tx, 0x1A00)
                };
                match sub {
                    0 => {
                        want(1)?;
                        if value > 1 {
                            return Err(abort::PDO_LENGTH);
                        }
                        p.assigned = value == 1;
                        Ok(())
                    }
                    1 => {
                        want(2)?;
                        if value != which {
                            return Err(abort::RANGE);
                        }
                        Ok(())
                    }
                    _ => Err(abort::NO_SUBINDEX),
                }
            }
            (0x6000 | 0x6020, _) if self.profile == Profile::Analog => Err(abort::READ_ONLY),
            (0x7000 | 0x7010, _) if self.profile == Profile::Analog => Err(abort::STATE),
            (_, _) if self.profile == Profile::Analog => Err(abort::NO_OBJECT),
            (0x6060, 0) => {
                want(1)?;
                if value as u8 as i8 != MODE_CST {
                    return Err(abort::RANGE);
                }
                self.mode = value as u8 as i8;
                Ok(())
            }
            (0x6040, 0) => {
                want(2)?;
                self.controlword = value as u16;
                Ok(())
            }
            (0x1000 | 0x1018 | 0x6041 | 0x6061 | 0x6064 | 0x6073 | 0x6075 | 0x6078 | 0x2078, _) => {
                Err(abort::READ_ONLY)
            }
            (0x6071 | 0x2071, 0) => Err(abort::STATE),
            _ => match self.upload(index, sub) {
                Ok(_) => Err(abort::READ_ONLY),
                Err(e) => Err(e),
            },
        }
    }
}

/// An object dictionary served over CoE SDO ([`serve_sdo`]): the drive's,
/// an analog terminal's.
pub(super) trait Dictionary {
    /// Upload of `index`:`sub`: the value and its size, bytes; else the
    /// abort code.
    fn sdo_upload(&self, index: u16, sub: u8) -> Result<(u32, u8), u32>;

    /// Expedited download of `value` (`size` bytes) to `index`:`sub`, in
    /// PRE-OP when `preop`; else the abort code.
    fn sdo_download(
        &mut self,
        index: u16,
        sub: u8,
        value: u32,
        size: u8,
        preop: bool,
    ) -> Result<(), u32>;

    /// Serves one CoE mailbox request `req` (mailbox header included);
    /// writes the response mailbox to `resp` (all of it, [`MBX_SIZE`]
    /// bytes). Returns `false` when the request is not CoE SDO (no
    /// response).
    fn serve_mailbox(&mut self, req: &[u8], resp: &mut [u8], preop: bool) -> bool {
        serve_sdo(req, resp, |r| match r {
            SdoRequest::Upload { index, sub } => self.sdo_upload(index, sub),
            SdoRequest::Download {
                index,
                sub,
                value,
                size,
            } => self
                .sdo_download(index, sub, value, size, preop)
                .map(|()| (0, 0)),
        })
    }
}

/// A download's size check: `size` bytes where the object has `n`
/// (abort 0x06070010 otherwise).
pub(super) fn want_size(size: u8, n: u8) -> Result<(), u32> {
    if size == n {
        Ok(())
    } else {
        Err(abort::LENGTH)
    }
}

impl Dictionary for Drive {
    fn sdo_upload(&self, index: u16, sub: u8) -> Result<(u32, u8), u32> {
        self.upload(index, sub)
    }
    fn sdo_download(
        &mut self,
        index: u16,
        sub: u8,
        value: u32,
        size: u8,
        preop: bool,
    ) -> Result<(), u32> {
        self.download(index, sub, value, size, preop)
    }
}

/// One SDO request of a CoE mailbox (ETG.1000.6 §5.6).
#[derive(Debug, Clone, Copy)]
pub(super) enum SdoRequest {
    /// Upload (read) of `index`:`sub`.
    Upload {
        /// Object index.
        index: u16,
        /// Subindex.
        sub: u8,
    },
    /// Expedited download (write) of `value`, `size` bytes.
    Download {
        /// Object index.
        index: u16,
        /// Subindex.
        sub: u8,
        /// The value.
        value: u32,
        /// Its size, bytes.
        size: u8,
    },
}

/// Serves one CoE mailbox request `req` (mailbox header included) with
/// `handle` (an upload answers the value and its size in bytes; an error
/// is the abort code) and writes the response mailbox to `resp` (all of
/// it, [`MBX_SIZE`] bytes). Returns `false` when the request is not CoE
/// SDO (no response). Expedited transfers only; complete access is
/// refused (ETG.1000.6 §5.6).
pub(super) fn serve_sdo(
    req: &[u8],
    resp: &mut [u8],
    mut handle: impl FnMut(SdoRequest) -> Result<(u32, u8), u32>,
) -> bool {
    if req.len() < 16 || resp.len() < usize::from(MBX_SIZE) {
        return false;
    }
    let mbx_type = req[5] & 0x0F;
    let counter = req[5] & 0x70;
    let service = le16(req, 6) >> 12;
    if mbx_type != 3 || service != 2 {
        return false;
    }
    let sdo = req[8];
    let index = le16(req, 9);
    let sub = req[11];
    let data = bench_hal::ethercat::wire::le32(req, 12);
    let command = sdo >> 5;
    let complete_access = sdo & 0x10 != 0;
    let result: Result<(u8, u32), u32> = if complete_access {
        Err(abort::COMMAND)
    } else {
        match command {
            // Upload request.
            2 => handle(SdoRequest::Upload { index, sub })
                .map(|(v, size)| (0x40 | ((4 - size) << 2) | 0x03, v)),
            // Download request, expedited.
            1 if sdo & 0x02 != 0 => {
                let size = if sdo & 0x01 != 0 {
                    4 - ((sdo >> 2) & 0x03)
                } else {
                    4
                };
                let mask = if size == 4 {
                    u32::MAX
                } else {
                    (1u32 << (8 * size)) - 1
                };
                handle(SdoRequest::Download {
                    index,
                    sub,
                    value: data & mask,
                    size,
                })
                .map(|_| (0x60, 0))
            }
            _ => Err(abort::COMMAND),
        }
    };
    let (head, payload) = match result {
        Ok(x) => x,
        Err(code) => (0x80, code),
    };
    resp[..usize::from(MBX_SIZE)].fill(0);
    resp[0..2].copy_from_slice(&10u16.to_le_bytes());
    resp[5] = 0x03 | counter;
    resp[6..8].copy_from_slice(&(3u16 << 12).to_le_bytes());
    resp[8] = head;
    resp[9..11].copy_from_slice(&index.to_le_bytes());
    resp[11] = sub;
    resp[12..16].copy_from_slice(&payload.to_le_bytes());
    true
}

impl super::esc::App for Drive {
    fn rx_bytes(&self) -> usize {
        Drive::rx_bytes(self)
    }
    fn tx_bytes(&self) -> usize {
        Drive::tx_bytes(self)
    }
    fn mailbox(&mut self, req: &[u8], resp: &mut [u8], preop: bool) -> bool {
        self.serve_mailbox(req, resp, preop)
    }
    fn write_inputs(&self, inputs: &mut [u8]) {
        Drive::write_inputs(self, inputs)
    }
    fn cycle(&mut self, outputs: Option<&[u8]>, inputs: &mut [u8], now_ns: u64) {
        Drive::cycle(self, outputs, inputs, now_ns)
    }
}
