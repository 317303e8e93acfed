//! The SII EEPROM image of the virtual slave (ETG.1000.6 §5.4, ETG2010):
//! the information area (words 0x0000–0x003F) and the categories from word
//! 0x0040 (strings, general, FMMU, sync managers, end).

use bench_hal::ethercat::config::{EthercatConfig, PdoEntry};

/// Write mailbox (SM0, master → slave) start address in ESC memory.
pub const MBX_OUT_START: u16 = 0x1000;
/// Read mailbox (SM1, slave → master) start address.
pub const MBX_IN_START: u16 = 0x1080;
/// Mailbox size, bytes (both directions).
pub const MBX_SIZE: u16 = 128;
/// Output process data (SM2) start address.
pub const PD_OUT_START: u16 = 0x1100;
/// Input process data (SM3) start address.
pub const PD_IN_START: u16 = 0x1180;
/// Device name of the CiA 402 profile (SII strings).
pub const DEVICE_NAME: &str = "bench CiA402 CST drive";
/// Device name of the analog-terminal profile (SII strings).
pub const DEVICE_NAME_ANALOG: &str = "bench analog terminals";

fn push16(v: &mut Vec<u8>, x: u16) {
    v.extend_from_slice(&x.to_le_bytes());
}

fn push32(v: &mut Vec<u8>, x: u32) {
    v.extend_from_slice(&x.to_le_bytes());
}

/// CRC-8 of the first 14 bytes (ETG.1000.6 §5.4: polynomial x⁸+x²+x+1,
/// initial 0xFF).
fn crc8(bytes: &[u8]) -> u8 {
    const C: crc::Crc<u8> = crc::Crc::<u8>::new(&crc::Algorithm {
        width: 8,
        poly: 0x07,
        init: 0xFF,
        refin: false,
        refout: false,
        xorout: 0x00,
        check: 0x00, // not used by the computation
        residue: 0x00,
    });
    C.checksum(bytes)
}

fn category(v: &mut Vec<u8>, kind: u16, mut data: Vec<u8>) {
    if data.len() % 2 == 1 {
        data.push(0);
    }
    push16(v, kind);
    push16(v, (data.len() / 2) as u16);
    v.extend_from_slice(&data);
}

/// The EEPROM contents of the virtual slave with `vendor_id`/`product_id`.
pub fn image(cfg: &EthercatConfig, vendor_id: u32, product_id: u32) -> Vec<u8> {
    let name = match cfg.profile {
        bench_hal::ethercat::config::Profile::Cia402 => DEVICE_NAME,
        bench_hal::ethercat::config::Profile::Analog => DEVICE_NAME_ANALOG,
    };
    build(name, vendor_id, product_id, true, None)
}

/// The EEPROM contents of a terminal of a rack: with a CoE mailbox
/// (`coe`), or without one and then with its fixed PDOs in the TxPDO
/// (50) and RxPDO (51) categories (ETG2010 Table 14: the master sizes the
/// process data from them), `rx` assigned to SM2 and `tx` to SM3.
pub fn terminal_image(
    name: &str,
    vendor_id: u32,
    product_id: u32,
    coe: bool,
    rx: &[PdoEntry],
    tx: &[PdoEntry],
) -> Vec<u8> {
    build(name, vendor_id, product_id, coe, (!coe).then_some((rx, tx)))
}

fn build(
    name: &str,
    vendor_id: u32,
    product_id: u32,
    mailbox: bool,
    fixed: Option<(&[PdoEntry], &[PdoEntry])>,
) -> Vec<u8> {
    let mut v = Vec::with_capacity(512);
    // 0x0000: PDI control, PDI configuration, SYNC impulse length, PDI
    // configuration 2, configured station alias, reserved (4 bytes).
    for w in [0x0005u16, 0x0000, 0x0000, 0x0000, 0x0000, 0x0000, 0x0000] {
        push16(&mut v, w);
    }
    let crc = crc8(&v[..14]);
    push16(&mut v, u16::from(crc));
    // 0x0008: identity.
    push32(&mut v, vendor_id);
    push32(&mut v, product_id);
    push32(&mut v, 0x0001_0000); // revision
    push32(&mut v, 0x0000_0001); // serial
                                 // 0x0010..0x0017: bootstrap mailbox (unused), reserved.
    v.resize(0x18 * 2, 0);
    // 0x0018: standard mailbox: receive offset/size, send offset/size,
    // protocols (0x0004: CoE).
    let words = if mailbox {
        [MBX_OUT_START, MBX_SIZE, MBX_IN_START, MBX_SIZE, 0x0004]
    } else {
        [0; 5]
    };
    for w in words {
        push16(&mut v, w);
    }
    v.resize(0x3E * 2, 0);
    // 0x003E: size in kbit − 1 (4 kbit), 0x003F: version 1.
    push16(&mut v, 3);
    push16(&mut v, 1);
    // Categories.
    let mut strings = vec![1u8, name.len() as u8];
    strings.extend_from_slice(name.as_bytes());
    category(&mut v, 10, strings);
    // General (ETG.1000.6 Table 21): group, image, order, name string
    // indices; reserved; CoE details (SDO, PDO assign, PDO config:
    // 0x0D); FoE, EoE; SoE, DS402, sysman; flags; e-bus current; pad to 32
    // bytes.
    let coe_details = if mailbox { 0x0D } else { 0 };
    let mut general = vec![0u8, 0, 0, 1, 0, coe_details, 0, 0, 0, 1, 0, 0];
    general.resize(32, 0);
    category(&mut v, 30, general);
    // FMMU usage: 1 outputs, 2 inputs, 3 SM status.
    category(&mut v, 40, vec![0x01, 0x02, 0x03, 0xFF]);
    // Sync managers: start, length, control, reserved, enable, type.
    let mut sm = Vec::new();
    // Without a mailbox SM0/SM1 are unused (type 0), so the process data
    // stay on SM2/SM3.
    let (mbx_enable, mbx_out, mbx_in) = if mailbox { (1, 1, 2) } else { (0, 0, 0) };
    for (start, len, control, enable, kind) in [
        (MBX_OUT_START, MBX_SIZE, 0x26u8, mbx_enable, mbx_out),
        (MBX_IN_START, MBX_SIZE, 0x22, mbx_enable, mbx_in),
        (PD_OUT_START, 0, 0x64, 1, 3u8),
        (PD_IN_START, 0, 0x20, 1, 4),
    ] {
        let len = if mailbox || kind > 2 { len } else { 0 };
        push16(&mut sm, start);
        push16(&mut sm, len);
        sm.extend_from_slice(&[control, 0, enable, kind]);
    }
    category(&mut v, 41, sm);
    // Fixed PDOs (ETG2010 Table 14): 0x1A00 on SM3 (TxPDO, 50), 0x1600
    // on SM2 (RxPDO, 51); entry: index, subindex, name, data type, bit
    // length, flags.
    if let Some((rx, tx)) = fixed {
        for (kind, pdo, sm_index, entries) in [(50u16, 0x1A00u16, 3u8, tx), (51, 0x1600, 2, rx)] {
            if entries.is_empty() {
                continue;
            }
            let mut d = Vec::new();
            push16(&mut d, pdo);
            d.extend_from_slice(&[entries.len() as u8, sm_index, 0, 0]);
            push16(&mut d, 0);
            for e in entries {
                push16(&mut d, e.index);
                let data_type = if e.bits == 1 { 0x01 } else { 0x00 };
                d.extend_from_slice(&[e.subindex, 0, data_type, e.bits]);
                push16(&mut d, 0);
            }
            category(&mut v, kind, d);
        }
    }
    push16(&mut v, 0xFFFF);
    push16(&mut v, 0);
    v.resize(512, 0xFF);
    v
}
