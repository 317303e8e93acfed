//! The CAN device emulator ([`run_emulator`]): a [`DeviceCore`] on a
//! SocketCAN socket, laid out by the same frame map as the host backend
//! ([`crate::can`]), as a CANopen-style node would run it
//! (`bench emulate can`).
//!
//! # Watchdog
//!
//! The device drops the current to 0 A, disables the amplifier and latches
//! [`DeviceFault::Watchdog`] when no valid command has arrived for
//! `[emulator] watchdog_ms` while enabled. The emulator checks it on every
//! sample tick (SYNC or timer) **and** from its own clock when ticks stop (a
//! host that dies stops sending SYNC too;
//! [`DeviceCore::check_watchdog`], the plant does not advance), so the
//! current is 0 within `watchdog_ms` + one period of the last valid command
//! in both modes. Only an enable edge clears the latch.
//!
//! # Emulator fault injection ([`LinkFault`])
//!
//! Bit flips: an error frame (protocol violation, CRC sequence) replaces the
//! data frame, as the bus CRC would have rejected it (the bit count does not
//! matter on CAN). Drop: the next N sample frames are not sent (the plant
//! and counter go on). Delay: every outgoing frame is held back. Stall: no
//! sampling, no sending, no command handling and no watchdog for the
//! duration, as on a hung microcontroller. Disconnect: a bus-off error frame,
//! then silence (received frames are ignored; the device's watchdog trips).
//! Error frames written by a program are delivered as error frames by a
//! virtual bus (`vcan`) and a socket pair, not by a physical bus: inject
//! faults on `vcan`.

use crate::emulator::{DeviceCore, EmulatorStatus, LinkFault, ScheduledLinkFault};
use bench_hal::can::socket::{can_option, errno, queue_full, try_recv, try_send, wait_fd, Rx};
use bench_hal::can::{seq_delta, CanConfig, CanError, CanSocket, SamplePayload};
use bench_hal::os::monotonic_ns;
use bench_hal::Command;
use bench_protocol::DeviceFault;
use socketcan::errors::{Location, ViolationTypes};
use socketcan::frame::CanErrorFrame;
use socketcan::{CanFrame, EmbeddedFrame, ErrorCause, Frame, Socket, SocketOptions};
use std::collections::VecDeque;
use std::os::fd::{AsRawFd, RawFd};
use std::sync::atomic::{AtomicBool, Ordering};

/// The emulator wakes at least this often to look at its stop flag.
const EMULATOR_POLL_NS: u64 = 10_000_000;

/// Link-fault state of the emulator.
#[derive(Debug, Default)]
struct Faults {
    drop_left: u32,
    flip_left: u32,
    delay_ns: u64,
    /// Outgoing frames are held until then (a `hold` fault), monotonic ns.
    hold_until_ns: u64,
    stall_until_ns: Option<u64>,
    disconnected: bool,
}

struct Emulator<'a> {
    fd: RawFd,
    cfg: &'a CanConfig,
    core: DeviceCore,
    status: &'a EmulatorStatus,
    sync_word: u32,
    command_word: u32,
    sample_id: u32,
    t0_ns: u64,
    last_tick_ns: u64,
    last_enable_bit: bool,
    last_sent_seq: Option<u64>,
    faults: Faults,
    /// Frames held back by a delay: (release time, frame).
    delayed: VecDeque<(u64, libc::can_frame)>,
}

impl Emulator<'_> {
    fn dev(&self, mono_ns: u64) -> u64 {
        mono_ns.saturating_sub(self.t0_ns)
    }

    fn publish(&self) {
        self.status.publish(&self.core);
    }

    /// Sends now (a full queue or absent peer drops the frame).
    fn send_now(&self, frame: &libc::can_frame) -> Result<bool, CanError> {
        match try_send(self.fd, frame) {
            Ok(()) => Ok(true),
            Err(e)
                if queue_full(&e) || matches!(errno(&e), libc::ECONNREFUSED | libc::ENOTCONN) =>
            {
                Ok(false)
            }
            Err(source) => Err(CanError::Io { op: "send", source }),
        }
    }

    /// Sends through the delay line.
    fn emit(&mut self, frame: libc::can_frame, now: u64) -> Result<bool, CanError> {
        if self.faults.delay_ns > 0 || now < self.faults.hold_until_ns || !self.delayed.is_empty() {
            let t = self
                .delayed
                .back()
                .map_or(0, |(t, _)| *t)
                .max(now + self.faults.delay_ns)
                .max(self.faults.hold_until_ns);
            self.delayed.push_back((t, frame));
            Ok(true)
        } else {
            self.send_now(&frame)
        }
    }

    fn apply(&mut self, fault: LinkFault, now: u64) -> Result<(), CanError> {
        match fault {
            LinkFault::BitFlips { frames, .. } => self.faults.flip_left += frames,
            LinkFault::Drop { frames } => self.faults.drop_left += frames,
            LinkFault::Delay { delay_s } => self.faults.delay_ns = (delay_s * 1e9) as u64,
            LinkFault::Hold { duration_s } => {
                self.faults.hold_until_ns = now + (duration_s * 1e9) as u64;
            }
            LinkFault::Stall { duration_s } => {
                self.faults.stall_until_ns = Some(now + (duration_s * 1e9) as u64);
            }
            LinkFault::Disconnect => {
                let f: CanErrorFrame = ErrorCause::BusOff.into();
                self.send_now(f.as_ref())?;
                self.faults.disconnected = true;
                self.delayed.clear();
                self.status.host_connected.store(false, Ordering::Release);
            }
        }
        Ok(())
    }

    /// One sample tick at `now`.
    fn tick(&mut self, now: u64) -> Result<(), CanError> {
        let was_enabled = self.core.is_enabled();
        let s = self.core.tick(self.dev(now));
        self.last_tick_ns = now;
        if was_enabled && !self.core.is_enabled() {
            // State (0 A) first, then the trip stamp: whoever sees the
            // stamp sees the current dropped.
            self.publish();
            self.status
                .watchdog_trip_mono_ns
                .store(now, Ordering::Release);
            self.status.host_connected.store(false, Ordering::Release);
        }
        self.publish();
        if self.faults.disconnected {
            return Ok(());
        }
        if self.faults.drop_left > 0 {
            self.faults.drop_left -= 1;
            return Ok(());
        }
        let frame = if self.faults.flip_left > 0 {
            self.faults.flip_left -= 1;
            // The bus CRC rejects a corrupted frame: receivers see an error.
            let f: CanErrorFrame = ErrorCause::Protocol {
                types: ViolationTypes::BIT,
                location: Location::CrcSequence,
            }
            .into();
            *f.as_ref()
        } else {
            let p = SamplePayload {
                position_m: s.position_m,
                seq: s.seq,
                flags: s.flags,
                fault_code: self.core.fault().map_or(0, DeviceFault::code),
                measured_current_a: s.measured_current_a,
            };
            let data = self.cfg.sample.encode(&p);
            self.last_sent_seq = Some(s.seq);
            self.cfg
                .raw_frame(self.sample_id, &data[..self.cfg.sample.len()])
        };
        if self.emit(frame, now)? {
            self.status.samples_sent.fetch_add(1, Ordering::Relaxed);
        }
        Ok(())
    }

    /// The emulator's main loop (see [`run_emulator`]).
    fn run(
        &mut self,
        schedule: &[ScheduledLinkFault],
        stop: &AtomicBool,
        period: u64,
        watchdog: u64,
    ) -> Result<(), CanError> {
        let sync = self.cfg.sync_producer;
        let mut next_fault = 0;
        let mut next_tick = self.t0_ns + period;
        while !stop.load(Ordering::Acquire) {
            let now = monotonic_ns();
            while let Some(f) = schedule.get(next_fault) {
                if (self.dev(now) as f64) * 1e-9 < f.at_s {
                    break;
                }
                self.apply(f.kind, now)?;
                next_fault += 1;
            }
            if let Some(until) = self.faults.stall_until_ns {
                if now >= until {
                    self.faults.stall_until_ns = None;
                    // A hung device does not catch up: the timer restarts.
                    next_tick = now + period;
                    self.last_tick_ns = now;
                }
            }
            let stalled = self.faults.stall_until_ns.is_some();
            while let Some(&(t, frame)) = self.delayed.front() {
                if t > now {
                    break;
                }
                self.delayed.pop_front();
                self.send_now(&frame)?;
            }
            if !sync && !stalled && now >= next_tick {
                self.tick(now)?;
                while next_tick <= now {
                    next_tick += period;
                }
            }
            // The watchdog from the device's own clock, when ticks stopped
            // (SYNC mode with a dead host, or a disconnected link).
            if !stalled
                && self.core.is_enabled()
                && self.dev(now).saturating_sub(self.core.last_command_ns()) > watchdog
                && now.saturating_sub(self.last_tick_ns) >= period
                && self.core.check_watchdog(self.dev(now))
            {
                self.publish();
                self.status
                    .watchdog_trip_mono_ns
                    .store(now, Ordering::Release);
                self.status.host_connected.store(false, Ordering::Release);
                self.publish();
            }
            // Sleep until the next thing to do, or a frame.
            let mut wake = now + EMULATOR_POLL_NS;
            if let Some(until) = self.faults.stall_until_ns {
                wake = wake.min(until);
            } else {
                if !sync {
                    wake = wake.min(next_tick);
                }
                if self.core.is_enabled() {
                    let expiry = self.t0_ns + self.core.last_command_ns() + watchdog + 1;
                    wake = wake.min(expiry.max(self.last_tick_ns + period));
                }
            }
            if let Some(&(t, _)) = self.delayed.front() {
                wake = wake.min(t);
            }
            if let Some(f) = schedule.get(next_fault) {
                wake = wake.min(self.t0_ns + (f.at_s * 1e9) as u64);
            }
            let ready = wait_fd(self.fd, libc::POLLIN, wake.max(now))
                .map_err(|source| CanError::Io { op: "poll", source })?;
            if !ready {
                continue;
            }
            if let Some(rx) =
                try_recv(self.fd).map_err(|source| CanError::Io { op: "recv", source })?
            {
                self.on_frame(rx, monotonic_ns())?;
            }
        }
        Ok(())
    }

    fn on_frame(&mut self, rx: Rx, now: u64) -> Result<(), CanError> {
        if self.faults.disconnected || self.faults.stall_until_ns.is_some() {
            return Ok(());
        }
        let f = match rx {
            Rx::Frame(CanFrame::Data(f)) => f,
            Rx::Bad(_) => {
                self.status.bad_frames.fetch_add(1, Ordering::Relaxed);
                return Ok(());
            }
            Rx::Frame(_) => return Ok(()),
        };
        let word = f.id_word();
        if word == self.sync_word {
            self.status.host_connected.store(true, Ordering::Release);
            if self.cfg.sync_producer {
                self.tick(now)?;
            }
        } else if word == self.command_word {
            let c = match self.cfg.command.decode(f.data()) {
                Ok(c) => c,
                Err(_) => {
                    self.status.bad_frames.fetch_add(1, Ordering::Relaxed);
                    return Ok(());
                }
            };
            self.status.host_connected.store(true, Ordering::Release);
            let dev = self.dev(now);
            if c.enable && !self.last_enable_bit {
                self.core.enable(dev);
            } else if !c.enable && self.core.is_enabled() {
                self.core.disable();
            }
            self.last_enable_bit = c.enable;
            let accepted = self.core.command(
                Command {
                    current_a: c.current_a,
                    answers_seq: c.answers_seq,
                },
                dev,
            );
            if accepted {
                self.status
                    .last_command_mono_ns
                    .store(now, Ordering::Release);
                self.status
                    .commands_received
                    .fetch_add(1, Ordering::Relaxed);
                let w = self.cfg.command.answers_seq.width_bits;
                if let Some(last) = self.last_sent_seq {
                    if c.enable && seq_delta(last, c.answers_seq, w) < 0 {
                        self.status.late_commands.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
            self.publish();
        }
        Ok(())
    }
}

/// Runs the emulated device on `sock` until `stop` is raised: the plant in
/// `core` sampled on SYNC (`cfg.sync_producer`) or on its own timer at
/// `core.period_ns()`, commands from the command frame, the watchdog of
/// `core` (checked on every tick and from the emulator's clock when ticks
/// stop), the link faults of `faults` at their device times, and the
/// device's state published in `status`. Leaves the device disabled.
///
/// In `status`, `last_command_mono_ns` is the arrival of the last accepted
/// command, `watchdog_trip_mono_ns` the moment the watchdog dropped the
/// current, `host_connected` whether a SYNC or command frame arrived since
/// the start or the last trip, `bad_frames` counts command frames shorter
/// than the map and datagrams that are not CAN frames, and
/// `late_commands` counts enabled commands answering an older sample than
/// the last one sent.
///
/// Build `core` with the device's watchdog time (`[emulator] watchdog_ms`). The socket gets an id filter for
/// the SYNC and command ids when it is a CAN_RAW socket.
///
/// # Errors
/// `Config` for an invalid `cfg`; `Link` when the socket fails.
pub fn run_emulator(
    sock: CanSocket,
    cfg: &CanConfig,
    mut core: DeviceCore,
    faults: &[ScheduledLinkFault],
    stop: &AtomicBool,
    status: &EmulatorStatus,
) -> Result<(), CanError> {
    cfg.validate("backend.can")?;
    sock.set_nonblocking(true).map_err(|source| CanError::Io {
        op: "set_nonblocking",
        source,
    })?;
    can_option(
        sock.set_filters(&[cfg.filter(cfg.sync_id), cfg.filter(cfg.command_id())]),
        "setsockopt(CAN_RAW_FILTER)",
    )?;
    can_option(
        sock.set_error_filter_drop_all(),
        "setsockopt(CAN_RAW_ERR_FILTER)",
    )?;
    let mut schedule: Vec<ScheduledLinkFault> = faults.to_vec();
    schedule.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
    core.set_answer_bits(u32::from(cfg.command.answers_seq.width_bits));
    let period = core.period_ns();
    let watchdog = core.watchdog_ns();
    let t0 = monotonic_ns();
    let mut em = Emulator {
        fd: sock.as_raw_fd(),
        cfg,
        core,
        status,
        sync_word: cfg.id_word(cfg.sync_id),
        command_word: cfg.id_word(cfg.command_id()),
        sample_id: cfg.sample_id(),
        t0_ns: t0,
        last_tick_ns: t0,
        last_enable_bit: false,
        last_sent_seq: None,
        faults: Faults::default(),
        delayed: VecDeque::new(),
    };
    em.publish();
    let result = em.run(&schedule, stop, period, watchdog);
    em.core.disable();
    em.publish();
    result
}
