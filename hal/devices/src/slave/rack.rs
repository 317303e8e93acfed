//! The virtual rack (`bench emulate ethercat IFACE` with
//! `[[backend.ethercat.slaves]]`, [`run_rack`]): a chain of ESCs on one
//! raw socket, one per configured slave, each with its own identity, SII
//! and process image ([`Terminal`]), the one plant ([`DeviceCore`])
//! behind them.
//!
//! # The segment
//!
//! Each frame's datagrams pass through ESC 0, 1, … in order, as on a
//! real segment (ETG.1000.4 §5.4): an auto-increment address (`APxx`)
//! addresses the slave it reaches at 0 and each slave increments it; a
//! configured address (`FPxx`) matches one slave; broadcasts (`BRD`,
//! `BWR`, `BRW`) are served by each; logical datagrams (`LRD`, `LWR`,
//! `LRW`) go through each slave's FMMUs. The working counter counts per
//! slave (+1 read, +2 write, +3 read-write; `LRW` +1 per slave whose
//! inputs are read, +2 per slave whose outputs are written). Slaves with
//! a slave behind them report a link on port 1 and latch its receive time
//! 1 µs per slave behind later than port 0 (the frame's loop), so the
//! master's distributed-clock delay measurement sees a line.
//!
//! # The terminals
//!
//! A slave carrying `adc` or `dac` is an analog terminal with a CoE
//! mailbox (its map written by the master, objects 0x1018, 0x1600,
//! 0x1A00, 0x1C12, 0x1C13; the entries it may map are those of its
//! configured map; with `fixed_pdo` none: its objects are read-only, as
//! on Beckhoff's analog terminals) and distributed clocks; the others (coupler, digital
//! I/O) have no mailbox and their configured map as fixed PDOs in the
//! SII. Each cycle (after a frame that read or wrote process data) the
//! DAC terminal's value commands the current, the enable output's rising
//! edge enables the amplifier (clearing a latched fault) and its 0
//! disables it, the plant advances one period, and the ADC terminal
//! latches the probe (±32767 = ± `adc_full_scale_m`), the status terminal
//! the amplifier's ready (bit 0 of `status`) and fault (bit 1 of a wider
//! `status`, or bit 0 of `fault`) lines. A terminal not in OP has no
//! valid outputs: the DAC's value is 0 A, the enable output 0.
//!
//! # SM watchdog
//!
//! Each terminal with outputs has its own (0x0400/0x0420, SM2's watchdog
//! bit from the SII). When the DAC terminal's expires its output goes to
//! 0 A and the amplifier latches the fault (as the EL4xxx with its
//! watchdog set to the default output value); when the enable terminal's
//! expires the enable drops (the EL2xxx's outputs go to 0); either goes to
//! SAFE-OP + ERROR with AL status code 0x001B.
//!
//! # Faults
//!
//! As the single device's ([`super::SlaveFault`]): `drop`, `wkc` and
//! `disconnect` act on the frame, `drive_fault` on the amplifier,
//! `dc_drift` on the slaves' clock, `leave_op` takes the DAC terminal to
//! SAFE-OP + ERROR, `leave_op:N` the terminal at position N.

use super::drive::{abort, want_size, Dictionary};
use super::esc::{App, Esc, Malformed, PdAccess};
use super::sii;
use super::{
    answer, find_datagram, intake, short_wkc, Faults, LocalClock, ScheduledSlaveFault, SlaveFault,
};
use crate::emulator::{DeviceCore, EmulatorStatus};
use bench_hal::ethercat::config::RackSlave;
use bench_hal::ethercat::config::{EthercatConfig, PdoEntry};
use bench_hal::ethercat::rack::MAX_RACK;
use bench_hal::ethercat::socket::RawSocket;
use bench_hal::ethercat::wire::{adc_status, al, cmd, get_bits, set_bits};
use bench_hal::ethercat::EthercatError;
use bench_hal::os::monotonic_ns;
use bench_hal::Command;
use bench_protocol::DeviceFault;
use std::sync::atomic::{AtomicBool, Ordering};

/// A PDO map of a terminal: entries and whether it is assigned.
#[derive(Debug, Clone)]
struct Map {
    entries: Vec<PdoEntry>,
    assigned: bool,
    /// What may be mapped (the terminal's configured map).
    mappable: Vec<PdoEntry>,
}

impl Map {
    fn new(entries: Vec<PdoEntry>) -> Self {
        Self {
            mappable: entries.clone(),
            entries,
            assigned: true,
        }
    }

    fn bits(&self) -> usize {
        if self.assigned {
            self.entries.iter().map(|e| usize::from(e.bits)).sum()
        } else {
            0
        }
    }

    /// The bit offset of `e` in the image (`None`: not mapped).
    fn find(&self, e: PdoEntry) -> Option<usize> {
        if !self.assigned {
            return None;
        }
        let mut bit = 0;
        for m in &self.entries {
            if m.index == e.index && m.subindex == e.subindex {
                return Some(bit);
            }
            bit += usize::from(m.bits);
        }
        None
    }
}

/// One terminal of the rack: identity, map, the signals it carries.
#[derive(Debug)]
pub struct Terminal {
    slave: RackSlave,
    coe: bool,
    rx: Map,
    tx: Map,
}

impl Terminal {
    /// The terminal of a configured slave (CoE when it carries an analog
    /// channel; see the [module docs](self)).
    pub fn new(slave: &RackSlave) -> Self {
        Self {
            coe: slave.adc.is_some() || slave.dac.is_some(),
            rx: Map::new(slave.rx_entries()),
            tx: Map::new(slave.tx_entries()),
            slave: slave.clone(),
        }
    }
}

impl Dictionary for Terminal {
    fn sdo_upload(&self, index: u16, sub: u8) -> Result<(u32, u8), u32> {
        let map = |m: &Map| match sub {
            0 => Ok((m.entries.len() as u32, 1)),
            s if usize::from(s) <= m.entries.len() => Ok((m.entries[usize::from(s) - 1].raw(), 4)),
            _ => Err(abort::NO_SUBINDEX),
        };
        let assign = |m: &Map, which: u16| match sub {
            0 => Ok((u32::from(m.assigned), 1)),
            1 if m.assigned => Ok((u32::from(which), 2)),
            _ => Err(abort::NO_SUBINDEX),
        };
        match (index, sub) {
            (0x1000, 0) => Ok((0x0000_0191, 4)),
            (0x1018, 0) => Ok((4, 1)),
            (0x1018, 1) => Ok((self.slave.vendor_id, 4)),
            (0x1018, 2) => Ok((self.slave.product_id, 4)),
            (0x1018, 3) => Ok((0x0001_0000, 4)),
            (0x1018, 4) => Ok((1, 4)),
            (0x1600, _) => map(&self.rx),
            (0x1A00, _) => map(&self.tx),
            (0x1C12, _) => assign(&self.rx, 0x1600),
            (0x1C13, _) => assign(&self.tx, 0x1A00),
            (0x1000 | 0x1018, _) => Err(abort::NO_SUBINDEX),
            _ => Err(abort::NO_OBJECT),
        }
    }

    fn sdo_download(
        &mut self,
        index: u16,
        sub: u8,
        value: u32,
        size: u8,
        preop: bool,
    ) -> Result<(), u32> {
        let want = |n: u8| want_size(size, n);
        match index {
            0x1600 | 0x1A00 | 0x1C12 | 0x1C13 if !preop => Err(abort::STATE),
            // Fixed PDO contents (and assignment): read-only.
            0x1600 | 0x1A00 | 0x1C12 | 0x1C13 if self.slave.fixed_pdo => Err(abort::READ_ONLY),
            0x1600 | 0x1A00 => {
                let m = if index == 0x1600 {
                    &mut self.rx
                } else {
                    &mut self.tx
                };
                match sub {
                    0 => {
                        want(1)?;
                        let n = value as usize;
                        if n > m.entries.len() {
                            return Err(abort::PDO_LENGTH);
                        }
                        m.entries.truncate(n);
                        Ok(())
                    }
                    1..=16 => {
                        want(4)?;
                        let e = PdoEntry::from_raw(value);
                        if !m.mappable.contains(&e) {
                            return Err(abort::NOT_MAPPABLE);
                        }
                        let at = usize::from(sub - 1);
                        if at > m.entries.len() {
                            return Err(abort::NO_SUBINDEX);
                        }
                        if at == m.entries.len() {
                            m.entries.push(e);
                        } else {
                            m.entries[at] = e;
                        }
                        Ok(())
                    }
                    _ => Err(abort::NO_SUBINDEX),
                }
            }
            0x1C12 | 0x1C13 => {
                let (m, which) = if index == 0x1C12 {
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
                        m.assigned = value == 1;
                        Ok(())
                    }
                    1 => {
                        want(2)?;
                        if value == which {
                            Ok(())
                        } else {
                            Err(abort::RANGE)
                        }
                    }
                    _ => Err(abort::NO_SUBINDEX),
                }
            }
            0x1000 | 0x1018 => Err(abort::READ_ONLY),
            _ => Err(abort::NO_OBJECT),
        }
    }
}

impl App for Terminal {
    fn rx_bytes(&self) -> usize {
        self.rx.bits().div_ceil(8)
    }
    fn tx_bytes(&self) -> usize {
        self.tx.bits().div_ceil(8)
    }
    fn mailbox(&mut self, req: &[u8], resp: &mut [u8], preop: bool) -> bool {
        self.coe && self.serve_mailbox(req, resp, preop)
    }
    /// The rack latches the inputs (the plant is shared).
    fn write_inputs(&self, _inputs: &mut [u8]) {}
    /// The rack runs the plant (shared by the terminals).
    fn cycle(&mut self, _outputs: Option<&[u8]>, _inputs: &mut [u8], _now_ns: u64) {}
}

/// The rack: its ESCs in position order and the plant.
struct Rack {
    escs: Vec<Esc<Terminal>>,
    core: DeviceCore,
    adc_full_scale_m: f64,
    dac_full_scale_a: f64,
    /// Positions of the terminals carrying each signal.
    adc: usize,
    dac: usize,
    enable: usize,
    status: Option<usize>,
    fault: Option<usize>,
    adc_status: Option<usize>,
    enable_bit: bool,
    position_m: f64,
    /// The ADC channel's status word of the last sample (EL31xx layout).
    adc_status_bits: u16,
}

impl Rack {
    /// The signal's value in its terminal's outputs (`None`: not in OP).
    fn output(&self, at: usize, e: Option<PdoEntry>) -> Option<u32> {
        let esc = &self.escs[at];
        let e = e?;
        let bit = esc.app.rx.find(e)?;
        esc.outputs().map(|o| get_bits(o, bit, usize::from(e.bits)))
    }

    /// One SM-synchronous cycle of the plant under the terminals' outputs.
    fn cycle(&mut self, now_ns: u64) {
        self.apply(now_ns);
        let s = self.core.tick(now_ns);
        self.position_m = s.position_m;
        self.adc_status_bits =
            adc_status::of(s.position_m, s.flags.out_of_range, self.adc_full_scale_m);
        self.latch();
    }

    /// The terminals' outputs applied to the amplifier (enable edge,
    /// current).
    fn apply(&mut self, now_ns: u64) {
        let dac = self
            .output(self.dac, self.escs[self.dac].app.slave.dac)
            .map_or(0, |v| i64::from(v as u16 as i16));
        let en = self
            .output(self.enable, self.escs[self.enable].app.slave.enable)
            .is_some_and(|v| v & 1 != 0);
        if en && !self.enable_bit {
            self.core.enable(now_ns);
        } else if !en && self.core.is_enabled() {
            self.core.disable();
        }
        self.enable_bit = en;
        if self.core.is_enabled() {
            let current_a = dac as f64 / 32767.0 * self.dac_full_scale_a;
            self.core.command(
                Command {
                    current_a,
                    answers_seq: 0,
                },
                now_ns,
            );
        }
    }

    /// The inputs: ADC, ready and fault lines.
    fn latch(&mut self) {
        let counts = (self.position_m / self.adc_full_scale_m * 32767.0)
            .round()
            .clamp(-32767.0, 32767.0) as i16;
        let ready = u32::from(self.core.is_enabled());
        let fault = u32::from(self.core.fault().is_some());
        let mut put = |at: usize, which: fn(&RackSlave) -> Option<PdoEntry>, v: u32| {
            let esc = &mut self.escs[at];
            let Some(e) = which(&esc.app.slave) else {
                return;
            };
            if let Some(bit) = esc.app.tx.find(e) {
                set_bits(esc.inputs_mut(), bit, usize::from(e.bits), v);
            }
        };
        put(self.adc, |s| s.adc, u32::from(counts as u16));
        if let Some(s) = self.status {
            // A wide status carries the fault line as bit 1.
            put(s, |s| s.status, ready | fault << 1);
        }
        if let Some(f) = self.fault {
            put(f, |s| s.fault, fault);
        }
        if let Some(a) = self.adc_status {
            put(a, |s| s.adc_status, u32::from(self.adc_status_bits));
        }
    }
}

/// One frame's datagrams (`pdus`, after the EtherCAT header) through ESC
/// 0, 1, … in order, as on a segment (see the [module docs](self)); what
/// each did to its process data in `pd` (by position). A malformed frame
/// stops at the first ESC ([`Malformed`]: no answer).
///
/// # Errors
/// [`Malformed`] for datagrams that run past the frame.
pub fn through_chain<A: App>(
    escs: &mut [Esc<A>],
    pdus: &mut [u8],
    local_ns: u64,
    pd: &mut [PdAccess],
) -> Result<(), Malformed> {
    for (esc, pd) in escs.iter_mut().zip(pd.iter_mut()) {
        esc.process(pdus, pd, local_ns)?;
    }
    Ok(())
}

/// Runs the virtual rack of `cfg.slaves` on `sock` until `stop` is raised
/// (see the [module docs](self)): the plant of `core` (no watchdog of its
/// own: the terminals' SM watchdogs act), the faults of `faults`, the
/// state published in `status` as [`super::run_slave`] does
/// (`commands_received`, `last_command_mono_ns`: the DAC terminal's output
/// writes in OP; `watchdog_trip_*`: the first SM watchdog of the DAC or
/// enable terminal that expires). Leaves the amplifier disabled.
///
/// # Errors
/// `Config` when `cfg` holds no valid rack; `Link` when the socket fails.
pub fn run_rack(
    sock: &RawSocket,
    cfg: &EthercatConfig,
    core: DeviceCore,
    faults: &[ScheduledSlaveFault],
    stop: &AtomicBool,
    status: &EmulatorStatus,
) -> Result<(), EthercatError> {
    let Some(layout) = cfg.rack("backend.ethercat")? else {
        return Err(EthercatError::Config(bench_hal::param::ParamError::new(
            "backend.ethercat.slaves",
            "the virtual rack needs [[backend.ethercat.slaves]]",
        )));
    };
    let slaves = cfg.rack_slaves();
    let n = slaves.len();
    let escs = chain_of(&slaves);
    let mut rack = Rack {
        escs,
        core,
        adc_full_scale_m: cfg.adc_full_scale_m,
        dac_full_scale_a: cfg.dac_full_scale_a,
        adc: layout.adc.slave,
        dac: layout.dac.slave,
        enable: layout.enable.slave,
        status: layout.status.map(|s| s.slave),
        fault: layout.fault.map(|s| s.slave),
        adc_status: layout.adc_status.map(|s| s.slave),
        adc_status_bits: 0,
        enable_bit: false,
        position_m: 0.0,
    };
    let mut schedule = faults.to_vec();
    schedule.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
    let mut f = Faults::default();
    let mut next_fault = 0;
    let mut buf = [0u8; 1600];
    let t0 = monotonic_ns();
    let mut op_since: Option<u64> = None;
    let mut last_out: [Option<u64>; MAX_RACK] = [None; MAX_RACK];
    let mut clock = LocalClock::new(t0);
    status.publish(&rack.core);
    let io = |source| EthercatError::Io {
        op: "slave socket",
        source,
    };
    while !stop.load(Ordering::Acquire) {
        let now = monotonic_ns();
        if let Some(op0) = op_since {
            while let Some(s) = schedule.get(next_fault) {
                if ((now - op0) as f64) * 1e-9 < s.at_s {
                    break;
                }
                match s.kind {
                    SlaveFault::Drop { frames } => f.drop_left += frames,
                    SlaveFault::WrongWkc { frames } => f.wkc_left += frames,
                    SlaveFault::LeaveOp | SlaveFault::LeaveOpAt { .. } => {
                        let p = match s.kind {
                            SlaveFault::LeaveOpAt { position } => usize::from(position),
                            _ => rack.dac,
                        };
                        if let Some(esc) = rack.escs.get_mut(p) {
                            esc.error(al::SAFE_OP, 0x0001);
                        }
                        // Its outputs are no longer valid, at once.
                        rack.apply(now - t0);
                        rack.latch();
                    }
                    SlaveFault::DriveFault => rack.core.trip(DeviceFault::Amplifier),
                    SlaveFault::Disconnect => f.disconnected = true,
                    SlaveFault::DcDrift { ppm } => clock.drift(now, ppm),
                }
                status.publish(&rack.core);
                next_fault += 1;
            }
        }
        // The SM watchdogs, on the slaves' own clock.
        let mut wake = rack.expire_watchdogs(&mut last_out[..n], now, status);
        if let (Some(op0), Some(s)) = (op_since, schedule.get(next_fault)) {
            wake = wake.min(op0 + (s.at_s * 1e9) as u64);
        }
        if !sock.wait(wake.max(now)).map_err(io)? {
            continue;
        }
        while let Some(len) = sock.try_recv(&mut buf).map_err(io)? {
            let now = monotonic_ns();
            if f.disconnected {
                continue;
            }
            let frame = &mut buf[..len];
            let Some(pdus) = intake(frame, status) else {
                continue;
            };
            let lrw = find_datagram(&frame[pdus.clone()], cmd::LRW);
            if lrw.is_some() && f.drop_left > 0 {
                f.drop_left -= 1;
                continue;
            }
            // Through ESC 0, 1, … in order.
            let mut pd = [PdAccess::default(); MAX_RACK];
            let start = pdus.start;
            if through_chain(&mut rack.escs, &mut frame[pdus], clock.at(now), &mut pd).is_err() {
                status.bad_frames.fetch_add(1, Ordering::Relaxed);
                continue;
            }
            let mut touched = false;
            let mut dac_written = false;
            for (p, (esc, pd)) in rack.escs.iter_mut().zip(pd).enumerate() {
                if esc.al_state() != al::OP {
                    // Out of OP the watchdog does not run; back in OP the
                    // first output write arms it again (as the single
                    // device's, `run_slave`).
                    last_out[p] = None;
                }
                if pd.outputs_written {
                    last_out[p] = Some(now);
                    esc.set_watchdog_expired(false);
                    dac_written |= p == rack.dac;
                }
                touched |= pd.outputs_written || pd.inputs_read;
            }
            if let (Some(w), true) = (lrw, f.wkc_left > 0) {
                f.wkc_left -= 1;
                short_wkc(frame, start + w);
            }
            answer(sock, frame).map_err(io)?;
            if op_since.is_none() && rack.escs.iter().any(|e| e.al_state() == al::OP) {
                op_since = Some(now);
            }
            if dac_written {
                status.last_command_mono_ns.store(now, Ordering::Release);
                status.commands_received.fetch_add(1, Ordering::Relaxed);
                status.host_connected.store(true, Ordering::Release);
            }
            if touched {
                rack.cycle(now - t0);
                status.samples_sent.fetch_add(1, Ordering::Relaxed);
            } else {
                rack.latch();
            }
            status.publish(&rack.core);
        }
    }
    rack.core.disable();
    status.publish(&rack.core);
    Ok(())
}

/// The rack's ESCs in chain order, each with its terminal's SII image and
/// its share of the loop delay (1 µs per slave behind it).
fn chain_of(slaves: &[&RackSlave]) -> Vec<Esc<Terminal>> {
    let n = slaves.len();
    let mut escs = Vec::with_capacity(n);
    for (p, s) in slaves.iter().enumerate() {
        let t = Terminal::new(s);
        let coe = t.coe;
        let name = if s.name.is_empty() {
            "bench terminal"
        } else {
            &s.name
        };
        let image = sii::terminal_image(
            name,
            s.vendor_id,
            s.product_id,
            coe,
            &s.rx_entries(),
            &s.tx_entries(),
        );
        let mut esc = Esc::in_chain(image, t, coe, p + 1 < n, coe);
        esc.set_loop_delay_ns(1000 * (n - 1 - p) as u64);
        escs.push(esc);
    }
    escs
}

impl Rack {
    /// Expires the SM watchdog of every slave in OP whose last output
    /// write (`last_out`, by position) is older than its watchdog time, as
    /// the terminal would: it drops to SAFE-OP, the DAC terminal trips the
    /// amplifier, the enable terminal disables it. Returns the next time
    /// a watchdog can expire (or the next poll).
    fn expire_watchdogs(
        &mut self,
        last_out: &mut [Option<u64>],
        now: u64,
        status: &EmulatorStatus,
    ) -> u64 {
        let mut wake = now + super::POLL_NS;
        for (p, last_p) in last_out.iter_mut().enumerate() {
            let wd = self.escs[p].watchdog_ns();
            let Some(last) = *last_p else { continue };
            if wd == 0 {
                continue;
            }
            if self.escs[p].al_state() == al::OP && now > last + wd {
                let esc = &mut self.escs[p];
                esc.set_watchdog_expired(true);
                esc.error(al::SAFE_OP, al::CODE_SM_WATCHDOG);
                let carries = p == self.dac || p == self.enable;
                if p == self.dac {
                    self.core.trip(DeviceFault::Watchdog);
                }
                if p == self.enable {
                    self.core.disable();
                    self.enable_bit = false;
                }
                self.latch();
                if carries && status.watchdog_trip_mono_ns.load(Ordering::Acquire) < last {
                    status
                        .watchdog_trip_deadline_mono_ns
                        .store(last + wd, Ordering::Release);
                    status.watchdog_trip_mono_ns.store(now, Ordering::Release);
                    status.host_connected.store(false, Ordering::Release);
                }
                status.publish(&self.core);
                *last_p = None;
            } else {
                wake = wake.min(last + wd + 1);
            }
        }
        wake
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One datagram: command, address (ADP, ADO), data; `more` another
    /// follows (ETG.1000.4 §5.4.1.2: 10-byte header, data, 2-byte WKC).
    fn datagram(f: &mut Vec<u8>, command: u8, adp: u16, ado: u16, data: &[u8], more: bool) {
        f.extend_from_slice(&[command, 0]);
        f.extend_from_slice(&adp.to_le_bytes());
        f.extend_from_slice(&ado.to_le_bytes());
        let len = data.len() as u16 | if more { 0x8000 } else { 0 };
        f.extend_from_slice(&len.to_le_bytes());
        f.extend_from_slice(&[0, 0]);
        f.extend_from_slice(data);
        f.extend_from_slice(&[0, 0]);
    }

    /// (ADP, data, WKC) of the `k`-th datagram of a frame.
    fn answer(f: &[u8], k: usize) -> (u16, Vec<u8>, u16) {
        let mut at = 0;
        for _ in 0..k {
            let len = usize::from(u16::from_le_bytes([f[at + 6], f[at + 7]]) & 0x07FF);
            at += 10 + len + 2;
        }
        let len = usize::from(u16::from_le_bytes([f[at + 6], f[at + 7]]) & 0x07FF);
        let d = f[at + 10..at + 10 + len].to_vec();
        let w = u16::from_le_bytes([f[at + 10 + len], f[at + 11 + len]]);
        (u16::from_le_bytes([f[at + 2], f[at + 3]]), d, w)
    }

    /// The chain as ETG.1000.4 §5.4 has it: a broadcast read is answered by
    /// each slave (WKC 5), an auto-increment address reaches the slave
    /// where it counts up to 0 (−2: the third) and comes back incremented
    /// by each, a configured address matches one slave, and a broadcast
    /// write counts each slave once.
    #[test]
    fn a_frame_passes_the_slaves_in_order_with_their_working_counters() {
        let rack = bench_hal::ethercat::rack::beckhoff_example();
        let mut escs: Vec<Esc<Terminal>> = rack
            .iter()
            .enumerate()
            .map(|(p, s)| {
                let t = Terminal::new(s);
                let coe = t.coe;
                let sii = sii::terminal_image(&s.name, 2, s.product_id, coe, &[], &[]);
                Esc::in_chain(sii, t, coe, p + 1 < rack.len(), coe)
            })
            .collect();
        let n = escs.len() as u16;
        let mut f = Vec::new();
        // BRD of the ESC type; APWR of station address 0x1003 to the third
        // slave (ADP −2); BWR of 0 to 0x0120 (AL control: INIT).
        datagram(&mut f, cmd::BRD, 0, 0x0000, &[0], true);
        datagram(
            &mut f,
            cmd::APWR,
            0u16.wrapping_sub(2),
            0x0010,
            &0x1003u16.to_le_bytes(),
            true,
        );
        datagram(&mut f, cmd::BWR, 0, 0x0120, &[1, 0], false);
        let mut pd = [PdAccess::default(); MAX_RACK];
        through_chain(&mut escs, &mut f, 0, &mut pd).unwrap();
        assert_eq!(answer(&f, 0), (n, vec![0x11], n));
        assert_eq!(answer(&f, 1).0, 0u16.wrapping_sub(2).wrapping_add(n));
        assert_eq!(answer(&f, 1).2, 1);
        assert_eq!(answer(&f, 2).2, n);
        // FPRD of the station address: only the third slave answers.
        let mut f = Vec::new();
        datagram(&mut f, cmd::FPRD, 0x1003, 0x0010, &[0, 0], false);
        through_chain(&mut escs, &mut f, 0, &mut pd).unwrap();
        assert_eq!(answer(&f, 0), (0x1003, 0x1003u16.to_le_bytes().to_vec(), 1));
        // APRD of the DL status: the last slave has no link on port 1,
        // the others do (port 1 bit 5).
        for p in 0..n {
            let mut f = Vec::new();
            datagram(
                &mut f,
                cmd::APRD,
                0u16.wrapping_sub(p),
                0x0110,
                &[0, 0],
                false,
            );
            through_chain(&mut escs, &mut f, 0, &mut pd).unwrap();
            let (_, d, w) = answer(&f, 0);
            assert_eq!(w, 1);
            assert_eq!(d[0] & 0x20 != 0, p + 1 < n, "slave {p}");
        }
        // A frame cut short is no answer.
        let mut f = Vec::new();
        datagram(&mut f, cmd::BRD, 0, 0, &[0; 4], false);
        f.truncate(f.len() - 3);
        assert!(through_chain(&mut escs, &mut f, 0, &mut pd).is_err());
    }
}
