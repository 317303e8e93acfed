//! The EtherCAT slave controller (ESC) of the virtual slave: its memory
//! (registers 0x0000–0x0FFF, process RAM 0x1000–0x1FFF), the datagram
//! commands on it (ETG.1000.4 §5.4: auto-increment, configured-address,
//! broadcast and logical addressing, read/write/read-write and
//! read-multiple-write, with their working-counter increments), the AL
//! state machine (ETG.1000.6 §5.3), SII EEPROM access (0x0500–0x050F),
//! the mailbox sync managers SM0/SM1 carrying CoE to the application (the CiA 402 drive), the
//! process-data sync managers SM2/SM3 mapped by FMMUs (0x0600..), the
//! SM watchdog (0x0400, 0x0420, 0x0440), and the distributed clock's
//! registers: receive times latched by a write to 0x0900, the system time
//! 0x0910 = local time + offset 0x0920, delay 0x0928, SYNC0 start 0x0990
//! and cycle 0x09A0 (stored; the drive cycles on the frame, see
//! [`super`]).

use super::sii::{MBX_IN_START, MBX_OUT_START, MBX_SIZE, PD_IN_START, PD_OUT_START};
use bench_hal::ethercat::wire::{al, cmd, le16, le32, reg, DATAGRAM_HEADER, WKC_LEN};

/// ESC memory size, bytes.
pub const MEM: usize = 0x2000;

/// Registers the master cannot write (restored after every write).
const READ_ONLY: [(usize, usize); 7] = [
    (0x0000, 0x0010),
    (0x0110, 0x0112),
    (0x0130, 0x0136),
    (0x0440, 0x0442),
    (0x0508, 0x0510),
    (0x0900, 0x0910),
    (0x0918, 0x0920),
];

/// A frame whose datagrams run past its end.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Malformed;

/// What one datagram did to the process data.
#[derive(Debug, Default, Clone, Copy)]
pub struct PdAccess {
    /// The outputs (SM2) were written while in OP.
    pub outputs_written: bool,
    /// The inputs (SM3) were read.
    pub inputs_read: bool,
}

/// The application behind an ESC (its PDI side): the CiA 402 drive
/// ([`super::drive::Drive`]) or a terminal of a rack
/// ([`super::rack::Terminal`]).
pub trait App {
    /// SM2 (outputs) length its PDO map needs, bytes.
    fn rx_bytes(&self) -> usize;
    /// SM3 (inputs) length its PDO map needs, bytes.
    fn tx_bytes(&self) -> usize;
    /// Serves one mailbox request (ETG.1000.6 §5.6); `false`: no answer.
    fn mailbox(&mut self, req: &[u8], resp: &mut [u8], preop: bool) -> bool;
    /// Writes its inputs (at SAFE-OP entry and after each cycle).
    fn write_inputs(&self, inputs: &mut [u8]);
    /// One SM-synchronous cycle: the outputs (`None` outside OP), then the
    /// inputs.
    fn cycle(&mut self, outputs: Option<&[u8]>, inputs: &mut [u8], now_ns: u64);
}

/// The ESC and the application behind it.
#[derive(Debug)]
pub struct Esc<A> {
    mem: Box<[u8; MEM]>,
    sii: Vec<u8>,
    /// The application (the drive, a terminal).
    pub app: A,
    /// The ESC has mailbox sync managers (SM0/SM1); without, INIT →
    /// PRE-OP does not check them (ETG.1000.6 §5.3.2).
    has_mailbox: bool,
    /// Port 1's receive time after port 0's, ns (0: port 1 closed).
    loop_delay_ns: u64,
    al_state: u8,
    /// The ESC's local clock at the frame being processed, ns.
    local_ns: u64,
}

/// DC registers (ETG.1000.4 §6.8, ESC datasheet section II 0x0900..).
mod dc {
    /// Receive time port 0 (u32), latched by a write to it.
    pub const PORT0: usize = 0x0900;
    /// System time (u64): local time + offset.
    pub const SYSTEM_TIME: usize = 0x0910;
    /// Receive time of the processing unit (u64), latched with port 0.
    pub const RECEIVE_TIME_PU: usize = 0x0918;
    /// System time offset (u64).
    pub const OFFSET: usize = 0x0920;
}

impl<A: App> Esc<A> {
    /// An ESC in INIT with `sii` as EEPROM, with mailbox.
    pub fn new(sii: Vec<u8>, app: A) -> Self {
        Self::in_chain(sii, app, true, false, true)
    }

    /// An ESC in INIT at a place in a chain: `has_mailbox` (SM0/SM1),
    /// `downstream` (a slave follows on port 1: DL status link on port 1),
    /// `dc` (distributed clocks supported, ESC register 0x0008 bit 2).
    pub fn in_chain(sii: Vec<u8>, app: A, has_mailbox: bool, downstream: bool, dc: bool) -> Self {
        let mut mem = Box::new([0u8; MEM]);
        mem[reg::TYPE as usize] = 0x11;
        mem[reg::FMMU_COUNT as usize] = 4;
        mem[reg::SM_COUNT as usize] = 4;
        mem[reg::RAM_SIZE as usize] = 8;
        // Features: distributed clocks (bit 2), 64-bit (bit 3).
        mem[reg::FEATURES as usize] = if dc { 0x0C } else { 0 };
        // DL status: PDI operational, link and communication on port 0
        // (and port 1 when a slave follows).
        let dl: u16 = if downstream { 0x0A31 } else { 0x0211 };
        mem[0x0110..0x0112].copy_from_slice(&dl.to_le_bytes());
        mem[0x0400..0x0402].copy_from_slice(&2498u16.to_le_bytes());
        mem[0x0420..0x0422].copy_from_slice(&1000u16.to_le_bytes());
        mem[0x0440..0x0442].copy_from_slice(&1u16.to_le_bytes());
        mem[0x0502..0x0504].copy_from_slice(&0x0040u16.to_le_bytes());
        let mut esc = Self {
            mem,
            sii,
            app,
            has_mailbox,
            loop_delay_ns: 0,
            al_state: al::INIT,
            local_ns: 0,
        };
        esc.set_al(al::INIT, 0);
        esc
    }

    /// AL status register (state and error bit).
    pub fn al_status(&self) -> u8 {
        self.mem[reg::AL_STATUS as usize]
    }

    /// AL state (without the error bit).
    pub fn al_state(&self) -> u8 {
        self.al_state
    }

    fn set_al(&mut self, state: u8, code: u16) {
        self.al_state = state;
        let status = if code != 0 { state | al::ERROR } else { state };
        self.mem[reg::AL_STATUS as usize] = status;
        self.mem[reg::AL_STATUS as usize + 1] = 0;
        self.mem[0x0134..0x0136].copy_from_slice(&code.to_le_bytes());
    }

    /// Drops to `state` with error `code` (the application's reaction to a
    /// watchdog or an injected fault).
    pub fn error(&mut self, state: u8, code: u16) {
        self.set_al(state, code);
    }

    fn r16(&self, at: u16) -> u16 {
        le16(&self.mem[..], at as usize)
    }

    fn sm(&self, n: usize) -> (u16, u16, u8, bool) {
        let b = reg::SM0 as usize + 8 * n;
        (
            self.r16(b as u16),
            self.r16(b as u16 + 2),
            self.mem[b + 4],
            self.mem[b + 6] & 1 != 0,
        )
    }

    fn sm_status(&mut self, n: usize) -> &mut u8 {
        &mut self.mem[reg::SM0 as usize + 8 * n + 5]
    }

    /// SM watchdog time, ns (0: off): the SM2 control's watchdog bit, the
    /// divider (0x0400) and the time (0x0420).
    pub fn watchdog_ns(&self) -> u64 {
        let (_, _, control, _) = self.sm(2);
        if control & 0x40 == 0 {
            return 0;
        }
        let step_ns = (u64::from(self.r16(reg::WD_DIVIDER)) + 2) * 40;
        u64::from(self.r16(reg::WD_TIME_PD)) * step_ns
    }

    /// Records the watchdog's state (0x0440 bit 0: 1 running, 0 expired).
    pub fn set_watchdog_expired(&mut self, expired: bool) {
        self.mem[0x0440] = u8::from(!expired);
    }

    /// The output image (SM2) and input image (SM3) lengths configured.
    fn pd_lengths(&self) -> (usize, usize) {
        (self.sm(2).1 as usize, self.sm(3).1 as usize)
    }

    /// The output image (SM2) while in OP (outputs valid), else `None`.
    pub fn outputs(&self) -> Option<&[u8]> {
        let o = PD_OUT_START as usize;
        let n = self.pd_lengths().0.min(64);
        (self.al_state == al::OP).then(|| &self.mem[o..o + n])
    }

    /// The input image (SM3), for the application to latch its inputs.
    pub fn inputs_mut(&mut self) -> &mut [u8] {
        let i = PD_IN_START as usize;
        let n = self.pd_lengths().1.min(64);
        &mut self.mem[i..i + n]
    }

    /// Sets the receive time of port 1 to `delay_ns` after port 0's at
    /// every latch: the frame's loop through the slaves behind this one
    /// (ETG.1000.4 §6.8; 0 at the end of the chain).
    pub fn set_loop_delay_ns(&mut self, delay_ns: u64) {
        self.loop_delay_ns = delay_ns;
    }

    /// Runs one drive cycle on the process images (after an exchange).
    pub fn cycle(&mut self, now_ns: u64) {
        let (out_len, in_len) = self.pd_lengths();
        let o = PD_OUT_START as usize;
        let i = PD_IN_START as usize;
        let mut outputs = [0u8; 64];
        let out_len = out_len.min(64);
        outputs[..out_len].copy_from_slice(&self.mem[o..o + out_len]);
        let in_len = in_len.min(64);
        let op = self.al_state == al::OP;
        self.app.cycle(
            op.then_some(&outputs[..out_len]),
            &mut self.mem[i..i + in_len],
            now_ns,
        );
    }

    /// The AL control register was written.
    fn al_control(&mut self) {
        let ctl = self.mem[reg::AL_CONTROL as usize];
        let req = ctl & 0x0F;
        let ack = ctl & 0x10 != 0;
        // The acknowledge is taken once.
        self.mem[reg::AL_CONTROL as usize] = req;
        let status = self.al_status();
        if status & al::ERROR != 0 && !ack && req >= self.al_state {
            // An error must be acknowledged before going up.
            return;
        }
        let cur = self.al_state;
        let code = match req {
            al::INIT => 0,
            al::PRE_OP => {
                if cur == al::INIT && self.has_mailbox && !self.mailbox_ok() {
                    al::CODE_INVALID_MAILBOX
                } else {
                    0
                }
            }
            al::SAFE_OP => {
                if cur == al::INIT {
                    al::CODE_INVALID_STATE_CHANGE
                } else if cur == al::PRE_OP {
                    self.pd_check()
                } else {
                    0
                }
            }
            al::OP => {
                if cur == al::SAFE_OP || cur == al::OP {
                    0
                } else {
                    al::CODE_INVALID_STATE_CHANGE
                }
            }
            al::BOOT => al::CODE_INVALID_STATE_CHANGE,
            _ => al::CODE_UNKNOWN_STATE,
        };
        if code != 0 {
            self.set_al(cur, code);
            return;
        }
        if req < al::SAFE_OP || req == al::BOOT {
            // Outputs are no longer valid: the drive disables.
            for n in 0..4 {
                *self.sm_status(n) &= !0x08;
            }
        }
        self.set_al(req, 0);
        if req == al::SAFE_OP {
            // Inputs are valid from SAFE-OP on.
            let i = PD_IN_START as usize;
            let n = (self.sm(3).1 as usize).min(64);
            self.app.write_inputs(&mut self.mem[i..i + n]);
        }
    }

    fn mailbox_ok(&self) -> bool {
        let (s0, l0, _, e0) = self.sm(0);
        let (s1, l1, _, e1) = self.sm(1);
        e0 && e1 && s0 == MBX_OUT_START && l0 == MBX_SIZE && s1 == MBX_IN_START && l1 == MBX_SIZE
    }

    /// PRE-OP → SAFE-OP: SM2/SM3 must match the PDO map.
    fn pd_check(&self) -> u16 {
        let (s2, l2, _, e2) = self.sm(2);
        let (s3, l3, _, e3) = self.sm(3);
        let rx = self.app.rx_bytes();
        let tx = self.app.tx_bytes();
        // A direction without process data needs no sync manager.
        if usize::from(l2) != rx || (rx > 0 && (s2 != PD_OUT_START || !e2)) {
            al::CODE_INVALID_OUTPUTS
        } else if usize::from(l3) != tx || (tx > 0 && (s3 != PD_IN_START || !e3)) {
            al::CODE_INVALID_INPUTS
        } else {
            0
        }
    }

    /// The SII control register was written.
    fn sii_control(&mut self) {
        let ctl = self.r16(reg::SII_CONTROL);
        if ctl & 0x0100 != 0 {
            let word = le32(&self.mem[..], reg::SII_ADDRESS as usize) as usize;
            for k in 0..8 {
                self.mem[reg::SII_DATA as usize + k] =
                    self.sii.get(word * 2 + k).copied().unwrap_or(0xFF);
            }
        }
        // Idle, 8-byte reads, no errors (writes and reloads are not
        // supported: the command-error bit reports them).
        let mut status = 0x0040u16;
        if ctl & 0x0600 != 0 {
            status |= 0x2000;
        }
        self.mem[0x0502..0x0504].copy_from_slice(&status.to_le_bytes());
    }

    /// The write mailbox was filled: serve the request.
    fn mailbox_request(&mut self) {
        let o = MBX_OUT_START as usize;
        let i = MBX_IN_START as usize;
        let n = MBX_SIZE as usize;
        let mut req = [0u8; 128];
        req[..n].copy_from_slice(&self.mem[o..o + n]);
        let mut resp = [0u8; 128];
        let preop = self.al_state == al::PRE_OP;
        if self.app.mailbox(&req[..n], &mut resp[..n], preop) {
            self.mem[i..i + n].copy_from_slice(&resp[..n]);
            *self.sm_status(1) |= 0x08;
        }
        *self.sm_status(0) &= !0x08;
    }

    fn phys_ok(ado: usize, len: usize) -> bool {
        ado + len <= MEM
    }

    /// Physical read into `data` (OR for broadcast).
    fn read(&mut self, ado: usize, data: &mut [u8], or: bool) -> bool {
        if !Self::phys_ok(ado, data.len()) {
            return false;
        }
        if ado < dc::SYSTEM_TIME + 8 && ado + data.len() > dc::SYSTEM_TIME {
            let offset = u64::from_le_bytes(
                self.mem[dc::OFFSET..dc::OFFSET + 8]
                    .try_into()
                    .unwrap_or([0; 8]),
            );
            let t = self.local_ns.wrapping_add(offset);
            self.mem[dc::SYSTEM_TIME..dc::SYSTEM_TIME + 8].copy_from_slice(&t.to_le_bytes());
        }
        let src = &self.mem[ado..ado + data.len()];
        if or {
            for (d, s) in data.iter_mut().zip(src) {
                *d |= *s;
            }
        } else {
            data.copy_from_slice(src);
        }
        // Reading the last byte of the read mailbox empties it.
        let last = usize::from(MBX_IN_START + MBX_SIZE - 1);
        if (ado..ado + data.len()).contains(&last) {
            *self.sm_status(1) &= !0x08;
        }
        true
    }

    /// Physical write of `data`, with the registers' side effects.
    fn write(&mut self, ado: usize, data: &[u8]) -> bool {
        if !Self::phys_ok(ado, data.len()) {
            return false;
        }
        let mut saved = [[0u8; 16]; READ_ONLY.len()];
        for (s, (a, b)) in saved.iter_mut().zip(READ_ONLY) {
            s[..b - a].copy_from_slice(&self.mem[a..b]);
        }
        let mut sm_status = [0u8; 4];
        for (n, s) in sm_status.iter_mut().enumerate() {
            *s = *self.sm_status(n);
        }
        self.mem[ado..ado + data.len()].copy_from_slice(data);
        for (s, (a, b)) in saved.iter().zip(READ_ONLY) {
            self.mem[a..b].copy_from_slice(&s[..b - a]);
        }
        for (n, s) in sm_status.iter().enumerate() {
            *self.sm_status(n) = *s;
        }
        let range = ado..ado + data.len();
        let touches = |a: u16| range.contains(&usize::from(a));
        if range.contains(&dc::PORT0) {
            // A write to receive time port 0 latches the local time of
            // the frame (one port: the others stay 0).
            let t = self.local_ns;
            self.mem[dc::PORT0..dc::PORT0 + 16].fill(0);
            self.mem[dc::PORT0..dc::PORT0 + 4].copy_from_slice(&(t as u32).to_le_bytes());
            if self.loop_delay_ns > 0 {
                let t1 = t + self.loop_delay_ns;
                self.mem[dc::PORT0 + 4..dc::PORT0 + 8].copy_from_slice(&(t1 as u32).to_le_bytes());
            }
            self.mem[dc::RECEIVE_TIME_PU..dc::RECEIVE_TIME_PU + 8]
                .copy_from_slice(&t.to_le_bytes());
        }
        if touches(reg::AL_CONTROL) {
            self.al_control();
        }
        if touches(reg::SII_CONTROL) || touches(reg::SII_CONTROL + 1) {
            self.sii_control();
        }
        if self.has_mailbox && touches(MBX_OUT_START + MBX_SIZE - 1) && self.al_state != al::INIT {
            *self.sm_status(0) |= 0x08;
            self.mailbox_request();
        }
        true
    }

    /// Logical access through the FMMUs: returns the working-counter
    /// increment (+1 read, +2 write) and what touched the process data.
    fn logical(&mut self, command: u8, addr: u32, data: &mut [u8], pd: &mut PdAccess) -> u16 {
        if self.al_state < al::SAFE_OP || self.al_state == al::BOOT {
            return 0;
        }
        let reads = matches!(command, cmd::LRD | cmd::LRW);
        let writes = matches!(command, cmd::LWR | cmd::LRW) && self.al_state == al::OP;
        let (mut r, mut w) = (false, false);
        for f in 0..usize::from(self.mem[reg::FMMU_COUNT as usize]) {
            let b = reg::FMMU0 as usize + 16 * f;
            let m = &self.mem[b..b + 16];
            if m[12] & 1 == 0 {
                continue;
            }
            let log = le32(m, 0);
            let len = u32::from(le16(m, 4));
            let phys = u32::from(le16(m, 8));
            let kind = m[11];
            let lo = addr.max(log);
            let hi = (addr + data.len() as u32).min(log + len);
            if lo >= hi {
                continue;
            }
            let d = (lo - addr) as usize..(hi - addr) as usize;
            let p = (phys + lo - log) as usize..(phys + hi - log) as usize;
            if p.end > MEM {
                continue;
            }
            if kind & 1 != 0 && reads {
                data[d.clone()].copy_from_slice(&self.mem[p.clone()]);
                r = true;
                if p.start >= PD_IN_START as usize {
                    pd.inputs_read = true;
                }
            }
            if kind & 2 != 0 && writes {
                self.mem[p.clone()].copy_from_slice(&data[d]);
                w = true;
                if p.start >= PD_OUT_START as usize && p.start < PD_IN_START as usize {
                    pd.outputs_written = true;
                }
            }
        }
        u16::from(r) + 2 * u16::from(w)
    }

    /// Processes the datagrams of one EtherCAT frame payload (after the
    /// 2-byte EtherCAT header) in place: data read, addresses incremented,
    /// working counters. [`Malformed`] for a frame cut short.
    /// `local_ns` is the ESC's local clock when the frame passes (the DC
    /// registers' time base).
    pub fn process(
        &mut self,
        pdus: &mut [u8],
        pd: &mut PdAccess,
        local_ns: u64,
    ) -> Result<(), Malformed> {
        self.local_ns = local_ns;
        let mut at = 0;
        loop {
            if at + DATAGRAM_HEADER + WKC_LEN > pdus.len() {
                return Err(Malformed);
            }
            let command = pdus[at];
            let adp = le16(pdus, at + 2);
            let ado = le16(pdus, at + 4) as usize;
            let laddr = le32(pdus, at + 2);
            let lenf = le16(pdus, at + 6);
            let len = usize::from(lenf & 0x07FF);
            let more = lenf & 0x8000 != 0;
            let d0 = at + DATAGRAM_HEADER;
            if d0 + len + WKC_LEN > pdus.len() {
                return Err(Malformed);
            }
            let mut wkc = le16(pdus, d0 + len);
            let station = self.r16(reg::STATION_ADDRESS);
            let (head, rest) = pdus.split_at_mut(d0);
            let data = &mut rest[..len];
            let mut inc = 0u16;
            match command {
                cmd::NOP => {}
                cmd::APRD | cmd::APWR | cmd::APRW | cmd::ARMW => {
                    if adp == 0 {
                        inc = self.physical(command, ado, data);
                    } else if command == cmd::ARMW && self.write(ado, data) {
                        inc = 1;
                    }
                    head[at + 2..at + 4].copy_from_slice(&adp.wrapping_add(1).to_le_bytes());
                }
                cmd::FPRD | cmd::FPWR | cmd::FPRW | cmd::FRMW => {
                    if adp == station {
                        inc = self.physical(command, ado, data);
                    } else if command == cmd::FRMW && self.write(ado, data) {
                        inc = 1;
                    }
                }
                cmd::BRD | cmd::BWR | cmd::BRW => {
                    inc = self.physical(command, ado, data);
                    head[at + 2..at + 4].copy_from_slice(&adp.wrapping_add(1).to_le_bytes());
                }
                cmd::LRD | cmd::LWR | cmd::LRW => {
                    inc = self.logical(command, laddr, data, pd);
                }
                _ => {}
            }
            wkc = wkc.wrapping_add(inc);
            rest[len..len + 2].copy_from_slice(&wkc.to_le_bytes());
            at = d0 + len + WKC_LEN;
            if !more {
                return Ok(());
            }
        }
    }

    fn physical(&mut self, command: u8, ado: usize, data: &mut [u8]) -> u16 {
        match command {
            cmd::APRD | cmd::FPRD | cmd::ARMW | cmd::FRMW => u16::from(self.read(ado, data, false)),
            cmd::BRD => u16::from(self.read(ado, data, true)),
            cmd::APWR | cmd::FPWR | cmd::BWR => u16::from(self.write(ado, data)),
            cmd::APRW | cmd::FPRW | cmd::BRW => {
                let mut old = [0u8; 2048];
                let n = data.len();
                if !self.read(ado, &mut old[..n], command == cmd::BRW) {
                    return 0;
                }
                self.write(ado, data);
                data.copy_from_slice(&old[..n]);
                3
            }
            _ => 0,
        }
    }
}
