//! EtherCAT on the wire (ETG.1000.4 §5): the Ethernet type, the frame and
//! datagram headers, the command codes, and the ESC registers both sides
//! use (ETG.1000.4 §6, Beckhoff ESC datasheet section II).

/// EtherType of EtherCAT frames (ETG.1000.4 §5.3).
pub const ETHERTYPE: u16 = 0x88A4;
/// Ethernet header length, bytes.
pub const ETH_HEADER: usize = 14;
/// EtherCAT frame header length (11-bit length, type 1 = PDUs), bytes.
pub const ECAT_HEADER: usize = 2;
/// Datagram header length (command, index, address, length, IRQ), bytes.
pub const DATAGRAM_HEADER: usize = 10;
/// Working counter length, bytes.
pub const WKC_LEN: usize = 2;

/// Datagram command codes (ETG.1000.4 Table 14).
pub mod cmd {
    /// No operation.
    pub const NOP: u8 = 0;
    /// Auto-increment physical read.
    pub const APRD: u8 = 1;
    /// Auto-increment physical write.
    pub const APWR: u8 = 2;
    /// Auto-increment physical read/write.
    pub const APRW: u8 = 3;
    /// Configured-address physical read.
    pub const FPRD: u8 = 4;
    /// Configured-address physical write.
    pub const FPWR: u8 = 5;
    /// Configured-address physical read/write.
    pub const FPRW: u8 = 6;
    /// Broadcast read.
    pub const BRD: u8 = 7;
    /// Broadcast write.
    pub const BWR: u8 = 8;
    /// Broadcast read/write.
    pub const BRW: u8 = 9;
    /// Logical read.
    pub const LRD: u8 = 10;
    /// Logical write.
    pub const LWR: u8 = 11;
    /// Logical read/write.
    pub const LRW: u8 = 12;
    /// Auto-increment read, multiple write.
    pub const ARMW: u8 = 13;
    /// Configured-address read, multiple write.
    pub const FRMW: u8 = 14;
}

/// ESC registers (ETG.1000.4 §6, ESC datasheet section II).
pub mod reg {
    /// ESC type (u8).
    pub const TYPE: u16 = 0x0000;
    /// FMMUs supported (u8).
    pub const FMMU_COUNT: u16 = 0x0004;
    /// SyncManagers supported (u8).
    pub const SM_COUNT: u16 = 0x0005;
    /// RAM size, KiB (u8).
    pub const RAM_SIZE: u16 = 0x0006;
    /// ESC features supported (u16): bit 2 distributed clocks.
    pub const FEATURES: u16 = 0x0008;
    /// Configured station address (u16).
    pub const STATION_ADDRESS: u16 = 0x0010;
    /// DL status (u16): bit 4 physical link on port 0, bit 9 communication
    /// on port 0.
    pub const DL_STATUS: u16 = 0x0110;
    /// AL control (u16): bits 0–3 requested state, bit 4 error acknowledge.
    pub const AL_CONTROL: u16 = 0x0120;
    /// AL status (u16): bits 0–3 state, bit 4 error.
    pub const AL_STATUS: u16 = 0x0130;
    /// AL status code (u16, ETG.1000.6 Table 11).
    pub const AL_STATUS_CODE: u16 = 0x0134;
    /// Watchdog divider (u16): one watchdog step is (divider + 2) × 40 ns.
    pub const WD_DIVIDER: u16 = 0x0400;
    /// SM watchdog time (u16, steps).
    pub const WD_TIME_PD: u16 = 0x0420;
    /// SM watchdog status (u16): bit 0 = 1 while not expired.
    pub const WD_STATUS_PD: u16 = 0x0440;
    /// SII access / owner (u16).
    pub const SII_CONFIG: u16 = 0x0500;
    /// SII control/status (u16): bit 6 read size (1: 8 bytes), bit 8 read,
    /// bit 9 write, bit 10 reload, bit 15 busy.
    pub const SII_CONTROL: u16 = 0x0502;
    /// SII word address (u32).
    pub const SII_ADDRESS: u16 = 0x0504;
    /// SII data (8 bytes).
    pub const SII_DATA: u16 = 0x0508;
    /// FMMU 0 (16 bytes each).
    pub const FMMU0: u16 = 0x0600;
    /// SyncManager 0 (8 bytes each: start, length, control, status,
    /// activate, PDI control).
    pub const SM0: u16 = 0x0800;
}

/// AL states (ETG.1000.6 §5.3.2).
pub mod al {
    /// INIT.
    pub const INIT: u8 = 0x01;
    /// PRE-OPERATIONAL.
    pub const PRE_OP: u8 = 0x02;
    /// BOOTSTRAP.
    pub const BOOT: u8 = 0x03;
    /// SAFE-OPERATIONAL.
    pub const SAFE_OP: u8 = 0x04;
    /// OPERATIONAL.
    pub const OP: u8 = 0x08;
    /// Error flag of the AL status.
    pub const ERROR: u8 = 0x10;
    /// AL status code: invalid requested state change.
    pub const CODE_INVALID_STATE_CHANGE: u16 = 0x0011;
    /// AL status code: unknown requested state.
    pub const CODE_UNKNOWN_STATE: u16 = 0x0012;
    /// AL status code: invalid mailbox configuration.
    pub const CODE_INVALID_MAILBOX: u16 = 0x0016;
    /// AL status code: invalid sync manager configuration.
    pub const CODE_INVALID_SM: u16 = 0x0017;
    /// AL status code: sync manager watchdog.
    pub const CODE_SM_WATCHDOG: u16 = 0x001B;
    /// AL status code: invalid output configuration.
    pub const CODE_INVALID_OUTPUTS: u16 = 0x001D;
    /// AL status code: invalid input configuration.
    pub const CODE_INVALID_INPUTS: u16 = 0x001E;

    /// Name of a state for messages.
    pub fn name(state: u8) -> &'static str {
        match state & 0x0F {
            INIT => "INIT",
            PRE_OP => "PRE-OP",
            BOOT => "BOOT",
            SAFE_OP => "SAFE-OP",
            OP => "OP",
            _ => "unknown",
        }
    }
}

/// CiA 402 statusword bits and states (IEC 61800-7-201 §6.2, Table 30).
pub mod cia402 {
    /// Ready to switch on.
    pub const SW_READY: u16 = 1 << 0;
    /// Switched on.
    pub const SW_SWITCHED_ON: u16 = 1 << 1;
    /// Operation enabled.
    pub const SW_OPERATION_ENABLED: u16 = 1 << 2;
    /// Fault.
    pub const SW_FAULT: u16 = 1 << 3;
    /// Voltage enabled.
    pub const SW_VOLTAGE_ENABLED: u16 = 1 << 4;
    /// Quick stop (active low: 1 = not quick stopping).
    pub const SW_QUICK_STOP: u16 = 1 << 5;
    /// Switch on disabled.
    pub const SW_SWITCH_ON_DISABLED: u16 = 1 << 6;
    /// Remote.
    pub const SW_REMOTE: u16 = 1 << 9;
    /// The bits that give the state (mask 0x006F).
    pub const STATE_MASK: u16 = 0x006F;

    /// Controlword "shutdown" (0b0110): to READY TO SWITCH ON.
    pub const CW_SHUTDOWN: u16 = 0x0006;
    /// Controlword "switch on" (0b0111).
    pub const CW_SWITCH_ON: u16 = 0x0007;
    /// Controlword "enable operation" (0b1111).
    pub const CW_ENABLE_OPERATION: u16 = 0x000F;
    /// Controlword "disable voltage" (0b0000).
    pub const CW_DISABLE_VOLTAGE: u16 = 0x0000;
    /// Controlword "quick stop" (0b0010).
    pub const CW_QUICK_STOP: u16 = 0x0002;
    /// Controlword bit 7: fault reset (on its rising edge).
    pub const CW_FAULT_RESET: u16 = 0x0080;
    /// Modes of operation 0x6060: cyclic synchronous torque.
    pub const MODE_CST: i8 = 10;
}

/// The status word of an analog input channel (Beckhoff EL31xx, objects
/// 0x6000:01..0x6000:10 read as one u16: the terminals' documented layout).
pub mod adc_status {
    /// The input is below the measuring range (0x6000:01).
    pub const UNDERRANGE: u16 = 1 << 0;
    /// The input is above the measuring range (0x6000:02).
    pub const OVERRANGE: u16 = 1 << 1;
    /// The channel has no valid value: wire break, overload, converter
    /// error (0x6000:07).
    pub const ERROR: u16 = 1 << 6;

    /// The status a terminal reports for a reading `position_m` of a probe
    /// flagged out of range or not (`out_of_range`) at full scale
    /// `full_scale_m`: error when the reading is not a number, under- or
    /// overrange by its sign when out of range or beyond full scale.
    pub fn of(position_m: f64, out_of_range: bool, full_scale_m: f64) -> u16 {
        if !position_m.is_finite() {
            return ERROR;
        }
        if out_of_range || position_m.abs() >= full_scale_m {
            return if position_m < 0.0 {
                UNDERRANGE
            } else {
                OVERRANGE
            };
        }
        0
    }
}

/// Reads a little-endian u16 at `at`.
pub fn le16(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}

/// Reads a little-endian u32 at `at`.
pub fn le32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// `n` bits (≤ 32) of a process image `b` from bit `bit`, least
/// significant first (the image's bit order: bit 0 is the least
/// significant bit of byte 0). Bits beyond `b` read 0.
pub fn get_bits(b: &[u8], bit: usize, n: usize) -> u32 {
    let mut v = 0u32;
    for k in 0..n.min(32) {
        let at = bit + k;
        if b.get(at / 8).is_some_and(|x| x >> (at % 8) & 1 != 0) {
            v |= 1 << k;
        }
    }
    v
}

/// Writes the `n` low bits (≤ 32) of `v` into `b` from bit `bit`, the
/// other bits untouched; bits beyond `b` are dropped.
pub fn set_bits(b: &mut [u8], bit: usize, n: usize, v: u32) {
    for k in 0..n.min(32) {
        let at = bit + k;
        if let Some(x) = b.get_mut(at / 8) {
            if v >> k & 1 != 0 {
                *x |= 1 << (at % 8);
            } else {
                *x &= !(1 << (at % 8));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bits_go_in_and_out_at_their_offsets() {
        let mut b = [0u8; 4];
        set_bits(&mut b, 3, 16, 0xBEEF);
        assert_eq!(get_bits(&b, 3, 16), 0xBEEF);
        // 0xBEEF << 3 = 0x5F778: bytes 0x78, 0xF7, 0x05.
        assert_eq!(b, [0x78, 0xF7, 0x05, 0]);
        set_bits(&mut b, 3, 16, 0);
        assert_eq!(b, [0; 4]);
        // Past the end: read as 0, written nowhere.
        set_bits(&mut b, 30, 4, 0xF);
        assert_eq!(b, [0, 0, 0, 0xC0]);
        assert_eq!(get_bits(&b, 30, 4), 0x3);
    }
}
