//! The virtual EtherCAT slave (`bench emulate ethercat IFACE`,
//! [`run_slave`]): a slave controller ([`esc`]) with SII EEPROM
//! ([`sii`]) and a CiA 402 drive ([`drive`]) around the emulated plant
//! ([`DeviceCore`]), answering EtherCAT frames on a raw socket.
//!
//! # Timing: SM-synchronous
//!
//! The drive runs in SM-synchronous mode (ETG.1020 §6, 0x1C32:01 = 1):
//! every frame that exchanges the process data (the master's `LRW`)
//! triggers one drive cycle, **after** the frame has been answered: the
//! outputs just written are applied, the plant advances one loop period
//! under them, and the new inputs are latched for the next frame. A frame
//! therefore returns the inputs of the cycle before: the process data add
//! one loop period of delay between the command and the position it
//! causes, on top of the simulator's zero-order hold.
//!
//! # SM watchdog
//!
//! The SM2 (outputs) watchdog of the ESC (registers 0x0400 divider, 0x0420
//! time, 0x0440 status; the watchdog bit 0x40 of the SM2 control byte from
//! the SII) restarts on every write of the outputs in OP; it runs only in
//! OP, from the first output write after each entry to OP. When it expires
//! (checked on the emulator's own clock, so also when frames stop) the
//! drive drops the current to 0 A and latches a fault (statusword bit 3,
//! [`DeviceFault::Watchdog`]), 0x0440 bit 0 clears and the slave goes to
//! SAFE-OP + ERROR with AL status code 0x001B. The current is 0 within the
//! watchdog time plus the emulator's wake-up latency of the last output
//! write.
//!
//! # Fault injection ([`SlaveFault`])
//!
//! Times count from the slave's first entry to OP: `drop:N` answers none
//! of the next N process-data frames (lost frames), `wkc:N` answers N with
//! the working counter one short, `leave_op` drops to SAFE-OP + ERROR
//! (outputs no longer valid: the drive disables), `drive_fault` latches a
//! drive fault (0 A, statusword bit 3), `disconnect` stops answering for
//! good (the SM watchdog then trips), `dc_drift:PPM` makes the slave's
//! local clock (the distributed clocks' reference) run PPM fast.
//!
//! What the slave shares with the host's master (the `[backend.ethercat]`
//! table, the wire constants, the raw socket, `EthercatError`) is
//! `bench_hal::ethercat`'s.
//!
//! Layer rule: may use `emulator`.
pub mod drive;
pub mod esc;
pub mod rack;
pub mod sii;

use self::drive::Drive;
use self::esc::{Esc, PdAccess};
use crate::emulator::{DeviceCore, EmulatorStatus};
use bench_hal::ethercat::config::EthercatConfig;
use bench_hal::ethercat::socket::RawSocket;
use bench_hal::ethercat::wire::{al, cmd, ECAT_HEADER, ETHERTYPE, ETH_HEADER};
use bench_hal::ethercat::EthercatError;
use bench_hal::os::monotonic_ns;
use bench_protocol::DeviceFault;
use std::sync::atomic::{AtomicBool, Ordering};

/// The slave wakes at least this often to look at its stop flag.
const POLL_NS: u64 = 10_000_000;

/// A fault the virtual slave can inject.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SlaveFault {
    /// Answer none of the next `frames` process-data frames.
    Drop {
        /// Frames lost.
        frames: u32,
    },
    /// Answer the next `frames` process-data frames with a working counter
    /// one short.
    WrongWkc {
        /// Frames affected.
        frames: u32,
    },
    /// Leave OP (SAFE-OP + ERROR, AL status code 0x0001); in a rack, the
    /// DAC terminal.
    LeaveOp,
    /// In a rack: the terminal at `position` leaves OP (`leave_op:N`;
    /// the single device: as [`Self::LeaveOp`]).
    LeaveOpAt {
        /// Position on the segment.
        position: u16,
    },
    /// The drive faults (statusword bit 3, 0 A).
    DriveFault,
    /// Stop answering for good.
    Disconnect,
    /// The slave's local clock (the DC reference) runs `ppm` parts per
    /// million fast from then on.
    DcDrift {
        /// Rate error, ppm.
        ppm: f64,
    },
}

impl SlaveFault {
    /// Parses `drop:FRAMES`, `wkc:FRAMES`, `leave_op`, `leave_op:POSITION`, `drive_fault`,
    /// `disconnect`, `dc_drift:PPM`.
    ///
    /// # Errors
    /// A message naming what does not parse.
    pub fn parse(s: &str) -> Result<Self, String> {
        let (name, arg) = s.split_once(':').unwrap_or((s, ""));
        let frames = || {
            arg.parse::<u32>()
                .ok()
                .filter(|n| *n > 0)
                .ok_or_else(|| format!("{name}: frame count `{arg}` is not a positive integer"))
        };
        match name {
            "drop" => Ok(Self::Drop { frames: frames()? }),
            "wkc" => Ok(Self::WrongWkc { frames: frames()? }),
            "leave_op" if arg.is_empty() => Ok(Self::LeaveOp),
            "leave_op" => Ok(Self::LeaveOpAt {
                position: arg
                    .parse::<u16>()
                    .map_err(|_| format!("leave_op: position `{arg}` is not a slave position"))?,
            }),
            "drive_fault" if arg.is_empty() => Ok(Self::DriveFault),
            "disconnect" if arg.is_empty() => Ok(Self::Disconnect),
            "dc_drift" => Ok(Self::DcDrift {
                ppm: arg
                    .parse::<f64>()
                    .ok()
                    .filter(|p| p.is_finite() && p.abs() <= 1e6)
                    .ok_or_else(|| format!("dc_drift: `{arg}` is not a rate error in ppm"))?,
            }),
            _ => Err(format!(
                "unknown EtherCAT slave fault `{s}` (expected drop:FRAMES, wkc:FRAMES, leave_op[:POSITION], drive_fault, disconnect or dc_drift:PPM)"
            )),
        }
    }
}

/// A slave fault at a time after the slave first entered OP.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScheduledSlaveFault {
    /// Seconds after the first entry to OP.
    pub at_s: f64,
    /// What happens.
    pub kind: SlaveFault,
}

/// What the virtual slave says about itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlaveIdentity {
    /// Vendor id (SII, 0x1018:01).
    pub vendor_id: u32,
    /// Product code (SII, 0x1018:02).
    pub product_id: u32,
}

#[derive(Debug, Default)]
struct Faults {
    drop_left: u32,
    wkc_left: u32,
    disconnected: bool,
}

/// Runs the virtual slave on `sock` until `stop` is raised (see the
/// module docs): the plant of `core` (build it with no watchdog of its
/// own, e.g. `u64::MAX / 4`: the SM watchdog is the ESC's), the PDO map
/// defaults and scalings of `cfg`, the identity `id`, the faults of
/// `faults`, and the state published in `status` (`last_command_mono_ns`:
/// the last output write in OP; `watchdog_trip_deadline_mono_ns`: that
/// write plus the watchdog time; `samples_sent`: process-data frames
/// answered; `commands_received`: output writes in OP; `bad_frames`:
/// malformed frames). Leaves the drive disabled.
///
/// # Errors
/// `Link` when the socket fails.
pub fn run_slave(
    sock: &RawSocket,
    cfg: &EthercatConfig,
    core: DeviceCore,
    id: SlaveIdentity,
    faults: &[ScheduledSlaveFault],
    stop: &AtomicBool,
    status: &EmulatorStatus,
) -> Result<(), EthercatError> {
    let mut schedule = faults.to_vec();
    schedule.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
    let mut esc = Esc::new(
        sii::image(cfg, id.vendor_id, id.product_id),
        Drive::new(core, cfg, id.vendor_id, id.product_id),
    );
    let mut f = Faults::default();
    let mut next_fault = 0;
    let mut buf = [0u8; 1600];
    let t0 = monotonic_ns();
    let mut op_since: Option<u64> = None;
    let mut last_pd_ns: Option<u64> = None;
    let mut clock = LocalClock::new(t0);
    status.publish(&esc.app.core);
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
                        esc.error(al::SAFE_OP, 0x0001);
                        esc.app.outputs_invalid(now - t0);
                    }
                    SlaveFault::DriveFault => esc.app.fault(DeviceFault::Amplifier),
                    SlaveFault::Disconnect => f.disconnected = true,
                    SlaveFault::DcDrift { ppm } => clock.drift(now, ppm),
                }
                status.publish(&esc.app.core);
                next_fault += 1;
            }
        }
        // The SM watchdog, on the slave's own clock.
        let wd = esc.watchdog_ns();
        if let Some(last) = last_pd_ns {
            if wd > 0 && esc.al_state() == al::OP && now > last + wd {
                esc.app.fault(DeviceFault::Watchdog);
                esc.set_watchdog_expired(true);
                esc.error(al::SAFE_OP, al::CODE_SM_WATCHDOG);
                status.publish(&esc.app.core);
                status
                    .watchdog_trip_deadline_mono_ns
                    .store(last + wd, Ordering::Release);
                status.watchdog_trip_mono_ns.store(now, Ordering::Release);
                status.host_connected.store(false, Ordering::Release);
                last_pd_ns = None;
            }
        }
        let mut wake = now + POLL_NS;
        if let (Some(last), true) = (last_pd_ns, wd > 0) {
            wake = wake.min(last + wd + 1);
        }
        if let (Some(op0), Some(s)) = (op_since, schedule.get(next_fault)) {
            wake = wake.min(op0 + (s.at_s * 1e9) as u64);
        }
        if !sock.wait(wake.max(now)).map_err(io)? {
            continue;
        }
        while let Some(n) = sock.try_recv(&mut buf).map_err(io)? {
            let now = monotonic_ns();
            if f.disconnected {
                continue;
            }
            let frame = &mut buf[..n];
            let Some(pdus) = intake(frame, status) else {
                continue;
            };
            let lrw = find_datagram(&frame[pdus.clone()], cmd::LRW);
            if lrw.is_some() && f.drop_left > 0 {
                f.drop_left -= 1;
                continue;
            }
            let mut pd = PdAccess::default();
            if esc
                .process(&mut frame[pdus.clone()], &mut pd, clock.at(now))
                .is_err()
            {
                status.bad_frames.fetch_add(1, Ordering::Relaxed);
                continue;
            }
            if let (Some(w), true) = (lrw, f.wkc_left > 0) {
                f.wkc_left -= 1;
                short_wkc(frame, pdus.start + w);
            }
            answer(sock, frame).map_err(io)?;
            if esc.al_state() == al::OP && op_since.is_none() {
                op_since = Some(now);
            }
            if esc.al_state() != al::OP {
                // Out of OP the outputs are not written and the watchdog
                // does not run; back in OP it is armed again by the first
                // output write, as on the first entry (a host that
                // disabled between two jobs and enables again).
                last_pd_ns = None;
            }
            if pd.outputs_written {
                last_pd_ns = Some(now);
                status.last_command_mono_ns.store(now, Ordering::Release);
                status.commands_received.fetch_add(1, Ordering::Relaxed);
                status.host_connected.store(true, Ordering::Release);
                esc.set_watchdog_expired(false);
            }
            if pd.outputs_written || pd.inputs_read {
                esc.cycle(now - t0);
                status.samples_sent.fetch_add(1, Ordering::Relaxed);
            }
            status.publish(&esc.app.core);
        }
    }
    esc.app.fault_free_disable();
    status.publish(&esc.app.core);
    Ok(())
}

/// Where the datagrams of `frame` lie (ETG.1000.4 §5.3: the Ethernet
/// header, the 2-byte EtherCAT header with length and type 1, then the
/// datagrams), shared by the single device and the rack. `None` for a
/// frame not to answer: not EtherCAT, already through a slave (ours), or
/// cut short or of another type (counted in `status.bad_frames`).
fn intake(frame: &[u8], status: &EmulatorStatus) -> Option<std::ops::Range<usize>> {
    let n = frame.len();
    if n < ETH_HEADER + ECAT_HEADER
        || u16::from_be_bytes([frame[12], frame[13]]) != ETHERTYPE
        || frame[6] & 0x02 != 0
    {
        return None;
    }
    let h = u16::from_le_bytes([frame[14], frame[15]]);
    let len = usize::from(h & 0x07FF);
    let start = ETH_HEADER + ECAT_HEADER;
    if h >> 12 != 1 || start + len > n {
        status.bad_frames.fetch_add(1, Ordering::Relaxed);
        return None;
    }
    Some(start..start + len)
}

/// One short of the working counter at `at` in `frame` (the `wkc:N`
/// fault).
fn short_wkc(frame: &mut [u8], at: usize) {
    let wkc = u16::from_le_bytes([frame[at], frame[at + 1]]).wrapping_sub(1);
    frame[at..at + 2].copy_from_slice(&wkc.to_le_bytes());
}

/// Sends the processed `frame` back: the first slave sets the locally
/// administered bit of the source address (what masters use to tell
/// answers apart); a full socket buffer drops the answer as a lost frame.
fn answer(sock: &RawSocket, frame: &mut [u8]) -> std::io::Result<()> {
    frame[6] |= 0x02;
    match sock.send(frame) {
        Ok(_) => Ok(()),
        Err(e) if matches!(e.raw_os_error(), Some(libc::EAGAIN | libc::ENOBUFS)) => Ok(()),
        Err(e) => Err(e),
    }
}

/// The slave's local clock (the distributed clocks' reference): the
/// monotonic and local times at the last rate change, and the rate.
#[derive(Debug, Clone, Copy)]
struct LocalClock {
    at_mono_ns: u64,
    at_local_ns: u64,
    rate: f64,
}

impl LocalClock {
    fn new(t0_ns: u64) -> Self {
        Self {
            at_mono_ns: t0_ns,
            at_local_ns: 0,
            rate: 1.0,
        }
    }

    /// The local time at monotonic time `now_ns`, ns.
    fn at(&self, now_ns: u64) -> u64 {
        self.at_local_ns + ((now_ns - self.at_mono_ns) as f64 * self.rate) as u64
    }

    /// From `now_ns` on, `ppm` parts per million fast (`dc_drift:PPM`).
    fn drift(&mut self, now_ns: u64, ppm: f64) {
        *self = Self {
            at_mono_ns: now_ns,
            at_local_ns: self.at(now_ns),
            rate: 1.0 + ppm * 1e-6,
        };
    }
}

/// The offset of the working counter of the first datagram with command
/// `command` in a frame's datagrams, if any.
fn find_datagram(pdus: &[u8], command: u8) -> Option<usize> {
    use bench_hal::ethercat::wire::{DATAGRAM_HEADER, WKC_LEN};
    let mut at = 0;
    while at + DATAGRAM_HEADER + WKC_LEN <= pdus.len() {
        let lenf = u16::from_le_bytes([pdus[at + 6], pdus[at + 7]]);
        let len = usize::from(lenf & 0x07FF);
        let wkc = at + DATAGRAM_HEADER + len;
        if wkc + WKC_LEN > pdus.len() {
            return None;
        }
        if pdus[at] == command {
            return Some(wkc);
        }
        if lenf & 0x8000 == 0 {
            return None;
        }
        at = wkc + WKC_LEN;
    }
    None
}
