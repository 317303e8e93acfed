//! The analog profile as a rack of separate terminals
//! (`[[backend.ethercat.slaves]]`, [`RackSlave`]): which slave of the
//! segment carries each signal, the identity expected of every slave, the
//! process-data map of each, and where the host finds each signal in the
//! group's process image ([`RackLayout`]).
//!
//! # Keys (one table per slave of the segment, the coupler counted)
//!
//! | key | type | meaning |
//! |---|---|---|
//! | `position` | integer | 0-based position on the segment (auto-increment order: 0 is the slave next to the master) |
//! | `vendor_id` | integer | expected vendor id (SII word 0x0008; Beckhoff: 0x2) |
//! | `product_id` | integer | expected product code (SII word 0x000A; EL3102: 0x0C1E3052) |
//! | `name` | string | optional, for messages (`"EL3102"`) |
//! | `rx_pdo` | array of `{index, subindex, bits}` | the terminal's outputs, in image order (default: its `dac` then `enable`) |
//! | `tx_pdo` | array of `{index, subindex, bits}` | the terminal's inputs, in image order (default: its `adc`, `status`, `fault`) |
//! | `adc` | `{index, subindex, bits = 16}` | the probe's ADC channel (i16, ±32767 = ± `adc_full_scale_m`), an entry of `tx_pdo` |
//! | `dac` | `{index, subindex, bits = 16}` | the amplifier's DAC channel (i16, ±32767 = ± `dac_full_scale_a`), an entry of `rx_pdo` |
//! | `enable` | `{index, subindex, bits}` | the amplifier's enable output, bit 0 of an entry of `rx_pdo` |
//! | `status` | `{index, subindex, bits}` | optional: the amplifier's ready line, bit 0 of an entry of `tx_pdo` (with 2 bits or more, bit 1 is its fault line) |
//! | `fault` | `{index, subindex, bits}` | optional: the amplifier's fault line, bit 0 of an entry of `tx_pdo`, when `status` is 1 bit wide |
//! | `adc_status` | `{index, subindex, bits = 16}` | optional: the ADC channel's status word (EL31xx: 0x6000:01..0x6000:10 as one 16-bit entry; bit 0 underrange, bit 1 overrange, bit 6 error), an entry of `tx_pdo`. An error makes the reading NaN (no valid reading: `probe_not_finite`), under- or overrange flags it out of range (`probe_out_of_range`) |
//! | `fixed_pdo` | bool | the terminal's PDO contents are fixed: no map written over CoE, its own assignment taken (default false) |
//!
//! An entry's `bits` is 1 to 32; index 0 is a gap (padding). The entries
//! of one slave and direction lie in its image back to back from bit 0
//! (ETG.1000.6 §5.6.7.4.7); each slave's image is whole bytes in the
//! group's image (the master places slaves byte-aligned).
//!
//! A slave with a CoE mailbox gets its map written over SDO in PRE-OP
//! (0x1C12/0x1C13 cleared, 0x1600/0x1A00 entries, count, assignment: the
//! single device's sequence), unless `fixed_pdo`; one without a mailbox
//! (EL1xxx, EL2xxx) keeps the fixed map of its SII. Either way the image
//! found must be the one configured (checked by its size at SAFE-OP).
//!
//! # Validation ([`EthercatConfig::rack`])
//!
//! Errors name `backend.ethercat.slaves[i].key`: positions 0 to n − 1 each
//! once (n at most [`MAX_RACK`]), `adc`, `dac` and `enable` each on exactly
//! one slave, `status` and `fault` on at most one (`fault` only beside a
//! 1-bit `status`), each signal an entry of its slave's map in its
//! direction at its width, entries 1 to 32 bits and not twice, each
//! slave's image at most [`MAX_PDO_BYTES`] per direction and the rack's
//! at most `2 × MAX_PDO_BYTES` in all; `profile = "analog"`, and the
//! single device's `rx_pdo`, `tx_pdo`, `product_id` unset.

use super::config::{EthercatConfig, PdoEntry, Profile, RackSlave, MAX_PDO_BYTES};
use crate::param::ParamError;

/// The most slaves of a rack (the host's group holds this many).
pub const MAX_RACK: usize = 8;

/// Where one signal lies: the slave's position and the bit offset in that
/// slave's image of the signal's direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SignalAt {
    /// Position of the slave on the segment.
    pub slave: usize,
    /// Bit offset in the slave's output or input image.
    pub bit: usize,
    /// Width, bits.
    pub bits: u8,
}

/// Where the host finds the rack's signals.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RackLayout {
    /// Slaves on the segment.
    pub slaves: usize,
    /// ADC (input, 16 bits).
    pub adc: SignalAt,
    /// DAC (output, 16 bits).
    pub dac: SignalAt,
    /// Enable (output, bit 0).
    pub enable: SignalAt,
    /// Ready line, and the fault line as bit 1 when 2 bits wide (input).
    pub status: Option<SignalAt>,
    /// Fault line (input, bit 0).
    pub fault: Option<SignalAt>,
    /// The ADC channel's status word (input, 16 bits).
    pub adc_status: Option<SignalAt>,
    /// Per position: output and input image bytes.
    pub image: [(usize, usize); MAX_RACK],
}

/// The signals by key, their direction (`true`: output) and width rule.
const SIGNALS: [(&str, bool); 6] = [
    ("adc", false),
    ("dac", true),
    ("enable", true),
    ("status", false),
    ("fault", false),
    ("adc_status", false),
];

fn signal(s: &RackSlave, name: &str) -> Option<PdoEntry> {
    match name {
        "adc" => s.adc,
        "dac" => s.dac,
        "enable" => s.enable,
        "status" => s.status,
        "adc_status" => s.adc_status,
        _ => s.fault,
    }
}

impl EthercatConfig {
    /// The slaves of the rack in position order (empty: the single
    /// device). Not real-time.
    pub fn rack_slaves(&self) -> Vec<&RackSlave> {
        let mut v: Vec<&RackSlave> = self.slaves.iter().collect();
        v.sort_by_key(|s| s.position);
        v
    }

    /// Every slave's `position` within the rack and taken once.
    fn check_positions(&self, prefix: &str) -> Result<(), ParamError> {
        let n = self.slaves.len();
        let mut at_position = [usize::MAX; MAX_RACK];
        for (i, s) in self.slaves.iter().enumerate() {
            let p = usize::from(s.position);
            let key = format!("{prefix}.slaves[{i}].position");
            if p >= n {
                return Err(ParamError::new(
                    key,
                    format!(
                        "position {p} is beyond the rack of {n} slaves (0 to {})",
                        n - 1
                    ),
                ));
            }
            if at_position[p] != usize::MAX {
                return Err(ParamError::new(
                    key,
                    format!("position {p} is also slaves[{}]'s", at_position[p]),
                ));
            }
            at_position[p] = i;
        }
        Ok(())
    }

    /// The rack's layout (`None`: no `slaves`, the single device); see
    /// the [module docs](super::rack) for the rules.
    ///
    /// # Errors
    /// [`ParamError`] naming `prefix.slaves[i].key` (or `prefix.slaves`,
    /// `prefix.profile`, `prefix.rx_pdo` …) and the reason.
    pub fn rack(&self, prefix: &str) -> Result<Option<RackLayout>, ParamError> {
        let n = self.slaves.len();
        if n == 0 {
            return Ok(None);
        }
        let err = |key: String, why: String| Err(ParamError::new(key, why));
        if self.profile != Profile::Analog {
            return err(
                format!("{prefix}.slaves"),
                "a rack of terminals is the analog profile: set profile = \"analog\"".into(),
            );
        }
        for (key, set) in [
            ("rx_pdo", !self.rx_pdo.is_empty()),
            ("tx_pdo", !self.tx_pdo.is_empty()),
            ("product_id", self.product_id.is_some()),
        ] {
            if set {
                return err(
                    format!("{prefix}.{key}"),
                    "is the single device's; with [[backend.ethercat.slaves]] each slave has its own"
                        .into(),
                );
            }
        }
        if n > MAX_RACK {
            return err(
                format!("{prefix}.slaves"),
                format!("{n} slaves, at most {MAX_RACK}"),
            );
        }
        self.check_positions(prefix)?;
        let mut image = [(0usize, 0usize); MAX_RACK];
        let mut found: [Option<(usize, SignalAt)>; 6] = [None; 6];
        for (i, s) in self.slaves.iter().enumerate() {
            let sk = format!("{prefix}.slaves[{i}]");
            check_pdo_maps(s, &sk)?;
            let (rx, tx) = (s.rx_entries(), s.tx_entries());
            image[usize::from(s.position)] = s.image_bytes();
            for (k, (name, output)) in SIGNALS.iter().enumerate() {
                let Some(e) = signal(s, name) else { continue };
                let key = format!("{sk}.{name}");
                if let Some((j, _)) = found[k] {
                    return err(
                        key,
                        format!(
                            "`{name}` is also on slaves[{j}] (each signal on exactly one slave)"
                        ),
                    );
                }
                let wide = matches!(*name, "adc" | "dac" | "adc_status");
                if wide && e.bits != 16 {
                    return err(
                        key,
                        format!("the {name} channel is 16 bits, not {}", e.bits),
                    );
                }
                if !(1..=32).contains(&e.bits) {
                    return err(key, format!("bits must be 1 to 32, got {}", e.bits));
                }
                let (map, dir) = if *output {
                    (&rx, "rx_pdo")
                } else {
                    (&tx, "tx_pdo")
                };
                let mut bit = 0usize;
                let mut hit = None;
                for m in map.iter() {
                    if m.index == e.index && m.subindex == e.subindex && m.index != 0 {
                        hit = Some((bit, m.bits));
                        break;
                    }
                    bit += usize::from(m.bits);
                }
                let Some((bit, bits)) = hit else {
                    return err(
                        key,
                        format!(
                            "0x{:04X}:{:02X} is not an entry of {sk}.{dir} (the {} of this terminal)",
                            e.index,
                            e.subindex,
                            if *output { "outputs" } else { "inputs" }
                        ),
                    );
                };
                if bits != e.bits {
                    return err(
                        key,
                        format!(
                            "0x{:04X}:{:02X} is {bits} bits wide in {sk}.{dir}, not {}",
                            e.index, e.subindex, e.bits
                        ),
                    );
                }
                found[k] = Some((
                    i,
                    SignalAt {
                        slave: usize::from(s.position),
                        bit,
                        bits,
                    },
                ));
            }
        }
        for name in ["adc", "dac", "enable"] {
            let k = SIGNALS.iter().position(|(s, _)| *s == name).unwrap_or(0);
            if found[k].is_none() {
                return err(
                    format!("{prefix}.slaves"),
                    format!("no slave carries the `{name}` (each of adc, dac, enable on exactly one slave)"),
                );
            }
        }
        if let Some((j, _)) = found[4] {
            let ok = found[3].is_some_and(|(_, s)| s.bits == 1);
            if !ok {
                return err(
                    format!("{prefix}.slaves[{j}].fault"),
                    "a fault line needs a 1-bit `status` (the ready line) on a slave; a wider `status` carries the fault as its bit 1".into(),
                );
            }
        }
        let total: usize = image.iter().map(|(o, i)| o + i).sum();
        if total > 2 * MAX_PDO_BYTES {
            return err(
                format!("{prefix}.slaves"),
                format!(
                    "the rack's image is {total} bytes, at most {}",
                    2 * MAX_PDO_BYTES
                ),
            );
        }
        let get = |k: usize| found[k].map(|(_, s)| s);
        let (Some(adc), Some(dac), Some(enable)) = (get(0), get(1), get(2)) else {
            return err(format!("{prefix}.slaves"), "a signal is missing".into());
        };
        Ok(Some(RackLayout {
            slaves: n,
            adc,
            dac,
            enable,
            status: get(3),
            fault: get(4),
            adc_status: get(5),
            image,
        }))
    }
}

/// A slave's own PDO maps: each entry 1 to 32 bits and mapped once, each
/// image within [`MAX_PDO_BYTES`]; `sk` names the slave in errors.
fn check_pdo_maps(s: &RackSlave, sk: &str) -> Result<(), ParamError> {
    for (dir, entries) in [("rx_pdo", s.rx_entries()), ("tx_pdo", s.tx_entries())] {
        let mut bits = 0usize;
        for (j, e) in entries.iter().enumerate() {
            if !(1..=32).contains(&e.bits) {
                return Err(ParamError::new(
                    format!("{sk}.{dir}[{j}]"),
                    format!("bits must be 1 to 32, got {}", e.bits),
                ));
            }
            if e.index != 0
                && entries[..j]
                    .iter()
                    .any(|p| p.index == e.index && p.subindex == e.subindex)
            {
                return Err(ParamError::new(
                    format!("{sk}.{dir}[{j}]"),
                    format!("0x{:04X}:{:02X} is mapped twice", e.index, e.subindex),
                ));
            }
            bits += usize::from(e.bits);
        }
        if bits.div_ceil(8) > MAX_PDO_BYTES {
            return Err(ParamError::new(
                format!("{sk}.{dir}"),
                format!("the image is longer than {MAX_PDO_BYTES} bytes"),
            ));
        }
    }
    Ok(())
}

/// The Beckhoff rack of the docs: EK1100 coupler, EL3102 ADC, EL4132 DAC,
/// EL2002 digital outputs, EL1002 digital inputs (vendor 0x2; product
/// codes from Beckhoff's ESI files), with the terminals' own maps; the
/// analog terminals' PDO contents fixed (`fixed_pdo`), as Beckhoff's are.
pub fn beckhoff_example() -> Vec<RackSlave> {
    let e = |index: u16, subindex: u8, bits: u8| PdoEntry {
        index,
        subindex,
        bits,
    };
    let slave = |position, product_id, name: &str| RackSlave {
        position,
        vendor_id: 0x2,
        product_id,
        name: name.into(),
        ..RackSlave::default()
    };
    // EL3102: per channel 0x6000:01..0x6000:10 status bits (16 bits in
    // all, written here as one entry: `adc_status`) then 0x6000:11 the
    // value.
    let adc = RackSlave {
        tx_pdo: vec![
            e(0x6000, 0x01, 16),
            e(0x6000, 0x11, 16),
            e(0, 0, 16),
            e(0x6010, 0x11, 16),
        ],
        adc: Some(e(0x6000, 0x11, 16)),
        adc_status: Some(e(0x6000, 0x01, 16)),
        fixed_pdo: true,
        ..slave(1, 0x0C1E_3052, "EL3102")
    };
    let dac = RackSlave {
        rx_pdo: vec![e(0x7000, 0x01, 16), e(0x7010, 0x01, 16)],
        dac: Some(e(0x7000, 0x01, 16)),
        fixed_pdo: true,
        ..slave(2, 0x1024_3052, "EL4132")
    };
    let out = RackSlave {
        rx_pdo: vec![e(0x7000, 0x01, 1), e(0x7010, 0x01, 1)],
        enable: Some(e(0x7000, 0x01, 1)),
        ..slave(3, 0x07D2_3052, "EL2002")
    };
    let inp = RackSlave {
        tx_pdo: vec![e(0x6000, 0x01, 1), e(0x6010, 0x01, 1)],
        status: Some(e(0x6000, 0x01, 1)),
        fault: Some(e(0x6010, 0x01, 1)),
        ..slave(4, 0x03EA_3052, "EL1002")
    };
    vec![slave(0, 0x044C_2C52, "EK1100"), adc, dac, out, inp]
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: &str = "backend.ethercat";

    fn map_mut<'a>(s: &'a mut RackSlave, dir: &str) -> &'a mut Vec<PdoEntry> {
        if dir == "rx_pdo" {
            &mut s.rx_pdo
        } else {
            &mut s.tx_pdo
        }
    }

    fn rack(slaves: Vec<RackSlave>) -> EthercatConfig {
        EthercatConfig {
            profile: Profile::Analog,
            slaves,
            ..EthercatConfig::default()
        }
    }

    /// The Beckhoff rack lays out as its terminals' maps say: the EL3102's
    /// first value after 16 status bits, each terminal's image whole bytes.
    #[test]
    fn the_beckhoff_rack_lays_out_from_the_terminals_maps() {
        let c = rack(beckhoff_example());
        c.validate(P).unwrap();
        let l = c.rack(P).unwrap().unwrap();
        assert_eq!(l.slaves, 5);
        let at = |slave, bit, bits| SignalAt { slave, bit, bits };
        assert_eq!(l.adc, at(1, 16, 16));
        assert_eq!(l.dac, at(2, 0, 16));
        assert_eq!(l.enable, at(3, 0, 1));
        assert_eq!(l.status, Some(at(4, 0, 1)));
        assert_eq!(l.fault, Some(at(4, 1, 1)));
        assert_eq!(&l.image[..5], &[(0, 0), (0, 8), (4, 0), (1, 0), (0, 1)]);
        // Listed in any order: the position decides.
        let mut shuffled = beckhoff_example();
        shuffled.reverse();
        let r = rack(shuffled);
        assert_eq!(r.rack(P).unwrap().unwrap().adc, at(1, 16, 16));
        assert_eq!(r.rack_slaves()[2].name, "EL4132");
        // The single device is untouched.
        assert_eq!(EthercatConfig::default().rack(P).unwrap(), None);
    }

    /// Generated bad racks: every slave's position out of range and on
    /// every other's, every signal removed, copied onto every other slave,
    /// at another width and at an entry not in the map, every map entry
    /// at 0 and 33 bits and mapped twice; each refused naming its key.
    #[test]
    fn mutations_of_the_rack_are_refused_naming_the_key() {
        let base = beckhoff_example();
        let n = base.len();
        let mut cases: Vec<(Vec<RackSlave>, Vec<String>)> = Vec::new();
        let key = |i: usize, k: &str| format!("{P}.slaves[{i}].{k}");
        for i in 0..n {
            let mut s = base.clone();
            s[i].position = n as u16;
            cases.push((s, vec![key(i, "position")]));
            for j in (0..n).filter(|j| *j != i) {
                let mut s = base.clone();
                s[i].position = base[j].position;
                cases.push((s, vec![key(i.max(j), "position")]));
            }
            for (k, (name, _)) in SIGNALS.iter().enumerate() {
                let Some(e) = signal(&base[i], name) else {
                    continue;
                };
                let set = |s: &mut RackSlave, v: Option<PdoEntry>| match k {
                    0 => s.adc = v,
                    1 => s.dac = v,
                    2 => s.enable = v,
                    3 => s.status = v,
                    4 => s.fault = v,
                    _ => s.adc_status = v,
                };
                // Removed.
                let mut s = base.clone();
                set(&mut s[i], None);
                let want = match *name {
                    "status" => key(i, "fault"),
                    "fault" | "adc_status" => {
                        // Without a fault line or the ADC's status word
                        // the rack is whole.
                        assert!(rack(s.clone()).validate(P).is_ok());
                        continue;
                    }
                    _ => format!("{P}.slaves"),
                };
                cases.push((s, vec![want]));
                // On another slave too.
                for j in (0..n).filter(|j| *j != i) {
                    let mut s = base.clone();
                    set(&mut s[j], Some(e));
                    cases.push((s, vec![key(i, name), key(j, name)]));
                }
                // Another width; an entry not in the map.
                for bits in [8u8, 2, 0, 33] {
                    if bits == e.bits {
                        continue;
                    }
                    let mut s = base.clone();
                    set(&mut s[i], Some(PdoEntry { bits, ..e }));
                    cases.push((s, vec![key(i, name)]));
                }
                let mut s = base.clone();
                set(
                    &mut s[i],
                    Some(PdoEntry {
                        subindex: 0x7F,
                        ..e
                    }),
                );
                cases.push((s, vec![key(i, name)]));
            }
            for dir in ["rx_pdo", "tx_pdo"] {
                let len = map_mut(&mut base[i].clone(), dir).len();
                for j in 0..len {
                    for bits in [0u8, 33] {
                        let mut s = base.clone();
                        map_mut(&mut s[i], dir)[j].bits = bits;
                        cases.push((s, vec![format!("{P}.slaves[{i}].{dir}[{j}]")]));
                    }
                    let mut s = base.clone();
                    let e = map_mut(&mut s[i], dir)[j];
                    if e.index != 0 {
                        map_mut(&mut s[i], dir).push(e);
                        cases.push((s, vec![format!("{P}.slaves[{i}].{dir}[{len}]")]));
                    }
                }
            }
        }
        // Whole-rack mutations.
        let mut c = rack(base.clone());
        c.profile = Profile::Cia402;
        assert_eq!(c.validate(P).unwrap_err().key, format!("{P}.slaves"));
        for (k, f) in [
            (
                "rx_pdo",
                (|c: &mut EthercatConfig| c.rx_pdo = vec![crate::ethercat::config::DAC_OUTPUT])
                    as fn(&mut EthercatConfig),
            ),
            ("tx_pdo", |c| {
                c.tx_pdo = vec![crate::ethercat::config::ADC_INPUT]
            }),
            ("product_id", |c| c.product_id = Some(0x0A10)),
        ] {
            let mut c = rack(base.clone());
            f(&mut c);
            assert_eq!(c.validate(P).unwrap_err().key, format!("{P}.{k}"));
        }
        let mut big = base.clone();
        for p in n..=MAX_RACK {
            big.push(RackSlave {
                position: p as u16,
                ..base[0].clone()
            });
        }
        cases.push((big, vec![format!("{P}.slaves")]));
        let mut wide = base.clone();
        wide[4].tx_pdo = vec![PdoEntry {
            index: 0x6000,
            subindex: 1,
            bits: 2,
        }];
        wide[4].status = Some(wide[4].tx_pdo[0]);
        cases.push((wide, vec![key(4, "fault")]));
        assert!(cases.len() > 80, "only {} mutations", cases.len());
        for (slaves, keys) in &cases {
            let e = rack(slaves.clone())
                .validate(P)
                .expect_err(&format!("accepted: {slaves:?}"));
            assert!(
                keys.contains(&e.key),
                "refused as {} ({}), expected one of {keys:?}",
                e.key,
                e.reason
            );
        }
    }
}
