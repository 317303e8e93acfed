//! The serial DAQ emulator: a [`DeviceCore`] behind a pseudo-terminal,
//! speaking the [`protocol`](crate::protocol) exactly as firmware would
//! (`bench emulate serial`).
//!
//! The emulator creates a pty pair, keeps both ends open (so the host may
//! come and go without the master side seeing hang-ups) and serves the slave
//! path to one host at a time (the host's `flock` enforces it). It ticks the
//! device on its own clock (absolute deadlines on `CLOCK_MONOTONIC`),
//! handling host frames between ticks. Samples stream from the first host
//! hello on. Injected [`LinkFault`]s act on the frames it sends.

use super::{DeviceCore, EmulatorStatus, LinkFault, ScheduledLinkFault};
use bench_hal::os::{monotonic_ns, sleep_until_ns};
use bench_hal::{Command, Sample};
use bench_protocol::serial::{
    self as protocol, flags, DeviceHello, DeviceMessage, Frame, FrameReader, HostMessage,
    WireSample, WireStatus, INVALID_POSITION, MAX_FRAME,
};
use bench_protocol::DeviceFault;
use rand::{Rng, SeedableRng};
use std::collections::VecDeque;
use std::os::fd::{AsRawFd, RawFd};
use std::sync::atomic::{AtomicBool, Ordering};

/// Emulator settings.
#[derive(Debug, Clone, PartialEq)]
pub struct SerialEmulatorOptions {
    /// Protocol version to announce (tests use another to check refusal).
    pub protocol_version: u16,
    /// Size of one probe count, m.
    pub position_lsb_m: f64,
    /// Link faults to inject.
    pub link_faults: Vec<ScheduledLinkFault>,
    /// Seed for the bit-flip positions.
    pub seed: u64,
    /// SCHED_FIFO priority for the emulator thread (`None`: normal).
    pub realtime_priority: Option<i32>,
    /// Lockstep (test mode): while enabled, the device takes its next
    /// sample only once the command answering the last one has arrived (or
    /// the watchdog time has passed), never earlier than its period. The
    /// plant then sees exactly the zero-order hold of the direct simulator
    /// whatever the scheduling, so link-path results can be compared with
    /// it on a machine without real-time guarantees.
    pub lockstep: bool,
    /// Current limits to announce in the hello instead of the device's
    /// own, `(peak, continuous)` A (tests of the host's refusal and of its
    /// limits winning; any value, NaN and 1e30 included). The device still
    /// clips at its own peak.
    pub announce_currents_a: Option<(f32, f32)>,
}

impl Default for SerialEmulatorOptions {
    fn default() -> Self {
        Self {
            protocol_version: protocol::VERSION,
            position_lsb_m: 1e-10,
            link_faults: Vec::new(),
            seed: 0,
            realtime_priority: None,
            lockstep: false,
            announce_currents_a: None,
        }
    }
}

/// A pseudo-terminal pair: the emulator uses the master, the host opens the
/// slave's path.
pub struct Pty {
    master: serialport::TTYPort,
    _slave: serialport::TTYPort,
    path: String,
}

impl std::fmt::Debug for Pty {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pty").field("path", &self.path).finish()
    }
}

impl Pty {
    /// Creates a pty pair in raw mode.
    ///
    /// # Errors
    /// The system's error if no pty can be allocated.
    pub fn open() -> Result<Self, serialport::Error> {
        let (master, slave) = serialport::TTYPort::pair()?;
        let path = serialport::SerialPort::name(&slave).ok_or_else(|| {
            serialport::Error::new(serialport::ErrorKind::Unknown, "pty has no name")
        })?;
        let fd = master.as_raw_fd();
        // Neither end may leak into child processes (a `bench` host started
        // by the emulator's process would keep the pty alive after a
        // disconnect).
        for f in [fd, slave.as_raw_fd()] {
            // SAFETY: valid fds; F_SETFD with FD_CLOEXEC.
            unsafe { libc::fcntl(f, libc::F_SETFD, libc::FD_CLOEXEC) };
        }
        // Non-blocking writes: with no host reading, frames are dropped
        // instead of stalling the device clock.
        // SAFETY: valid fd; F_GETFL/F_SETFL with plain flags.
        unsafe {
            let fl = libc::fcntl(fd, libc::F_GETFL);
            libc::fcntl(fd, libc::F_SETFL, fl | libc::O_NONBLOCK);
        }
        Ok(Self {
            master,
            _slave: slave,
            path,
        })
    }

    /// The path the host opens (e.g. `/dev/pts/3`).
    pub fn path(&self) -> &str {
        &self.path
    }
}

struct Link {
    fd: RawFd,
    reader: FrameReader,
    delayed: VecDeque<(u64, [u8; MAX_FRAME], usize)>,
    delay_ns: u64,
    /// Outgoing frames are held until then (a `hold` fault), monotonic ns.
    hold_until_ns: u64,
    flip_bits: u32,
    flip_frames: u32,
    drop_frames: u32,
    rng: rand_chacha::ChaCha8Rng,
}

impl Link {
    fn write_now(&self, frame: &[u8]) {
        if self.fd < 0 {
            return; // disconnected
        }
        // SAFETY: valid fd and buffer. A full buffer (no host) drops it.
        unsafe { libc::write(self.fd, frame.as_ptr().cast(), frame.len()) };
    }

    fn send(&mut self, msg: &DeviceMessage, now: u64, droppable: bool) {
        if droppable && self.drop_frames > 0 {
            self.drop_frames -= 1;
            return;
        }
        let mut frame = [0u8; MAX_FRAME];
        let n = protocol::encode(msg, &mut frame);
        if self.flip_frames > 0 {
            self.flip_frames -= 1;
            for _ in 0..self.flip_bits {
                // Any bit of the frame, the delimiter included.
                let bit = self.rng.random_range(0..n * 8);
                frame[bit / 8] ^= 1 << (bit % 8);
            }
        }
        if self.delay_ns > 0 || now < self.hold_until_ns || !self.delayed.is_empty() {
            let at = (now + self.delay_ns).max(self.hold_until_ns);
            self.delayed.push_back((at, frame, n));
        } else {
            self.write_now(&frame[..n]);
        }
    }

    fn flush_due(&mut self, now: u64) {
        while let Some(&(at, frame, n)) = self.delayed.front() {
            if at > now {
                break;
            }
            self.write_now(&frame[..n]);
            self.delayed.pop_front();
        }
    }
}

fn status_msg(core: &DeviceCore, st: &EmulatorStatus) -> DeviceMessage {
    DeviceMessage::Status(WireStatus {
        enabled: core.is_enabled(),
        fault: core.fault().map_or(0, DeviceFault::code),
        bad_frames: st.bad_frames.load(Ordering::Relaxed) as u32,
        late_commands: st.late_commands.load(Ordering::Relaxed) as u32,
    })
}

/// Runs the device until `stop` is raised or a `Disconnect` fault closes
/// the link. `status` is updated every tick.
///
/// # Errors
/// An I/O error on the pty other than a full buffer.
pub fn run(
    pty: Pty,
    core: DeviceCore,
    opts: &SerialEmulatorOptions,
    stop: &AtomicBool,
    status: &EmulatorStatus,
) -> std::io::Result<()> {
    if let Some(priority) = opts.realtime_priority {
        // Refused: normal scheduling.
        bench_hal::os::set_fifo_priority(priority);
    }
    let info = core.info().clone();
    let hello = DeviceHello {
        version: opts.protocol_version,
        period_ns: info.period_ns as u32,
        watchdog_ms: (core.watchdog_ns() / 1_000_000) as u32,
        peak_current_a: opts
            .announce_currents_a
            .map_or(info.peak_current_a as f32, |a| a.0),
        continuous_current_a: opts
            .announce_currents_a
            .map_or(info.continuous_current_a as f32, |a| a.1),
        probe_range_m: info.probe_range_m as f32,
        position_lsb_m: opts.position_lsb_m as f32,
    };
    let lsb = f64::from(hello.position_lsb_m);
    let pty = Some(pty);
    let link = Link {
        fd: pty.as_ref().map_or(-1, |p| p.master.as_raw_fd()),
        reader: FrameReader::new(),
        delayed: VecDeque::new(),
        delay_ns: 0,
        hold_until_ns: 0,
        flip_bits: 0,
        flip_frames: 0,
        drop_frames: 0,
        rng: rand_chacha::ChaCha8Rng::seed_from_u64(opts.seed),
    };
    let mut faults = opts.link_faults.clone();
    faults.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
    let faults: VecDeque<_> = faults.into();

    let period = core.period_ns();
    let start = monotonic_ns();
    let mut emu = Emulator {
        core,
        opts,
        status,
        pty,
        link,
        hello,
        lsb,
        faults,
        start,
        next: start + period,
        session: false,
        last_sent_seq: 0,
        stalled_until: 0,
        answered: true,
        last_tick_ns: start,
    };
    let mut rx = [0u8; 512];
    while !stop.load(Ordering::Relaxed) {
        emu.serve_host(&mut rx);
        let now = monotonic_ns();
        if !opts.lockstep {
            status
                .max_tick_lateness_ns
                .fetch_max(now.saturating_sub(emu.next), Ordering::Relaxed);
        }
        emu.inject_faults(now);
        if now >= emu.stalled_until {
            emu.tick(now);
        }
        if emu.pty.is_some() {
            emu.link.flush_due(now);
        }
        emu.next = next_deadline(emu.next + period, period, status, !opts.lockstep);
    }
    Ok(())
}

/// The running emulator of [`run`]: the device, the link to the host
/// (with the faults still to inject), the session and the device's clock.
struct Emulator<'a> {
    core: DeviceCore,
    opts: &'a SerialEmulatorOptions,
    status: &'a EmulatorStatus,
    /// The pty (`None` once a `Disconnect` fault pulled the cable).
    pty: Option<Pty>,
    link: Link,
    /// The device's answer to a host hello.
    hello: DeviceHello,
    /// Size of one probe count as announced, m.
    lsb: f64,
    /// Link faults not injected yet, by time.
    faults: VecDeque<ScheduledLinkFault>,
    /// The device's time origin, monotonic ns.
    start: u64,
    /// The next tick's deadline, monotonic ns.
    next: u64,
    /// A host said hello (samples stream).
    session: bool,
    /// Sequence number of the last sample sent (a command answering
    /// another one is late).
    last_sent_seq: u32,
    /// A `Stall` fault hangs the device until then, monotonic ns.
    stalled_until: u64,
    /// Lockstep: the command answering the last sample has arrived.
    answered: bool,
    /// When the device last ticked, monotonic ns (in lockstep, the answer
    /// is awaited at most the watchdog time from then).
    last_tick_ns: u64,
}

impl Emulator<'_> {
    /// The host's turn between two ticks: waits for bytes on the pty,
    /// deframes and decodes them (bad frames counted), answers each
    /// message and publishes the device's state. A stalled device reads
    /// nothing; without a pty it sleeps until the tick.
    fn serve_host(&mut self, rx: &mut [u8; 512]) {
        // Serve the host until the next tick (in lockstep, also until the
        // answer to the last sample, at most the watchdog time).
        loop {
            let now = monotonic_ns();
            let waiting = self.opts.lockstep
                && self.session
                && self.core.is_enabled()
                && !self.answered
                && now < self.last_tick_ns + self.core.watchdog_ns();
            if now >= self.next && !waiting {
                break;
            }
            let until = if now >= self.next {
                self.last_tick_ns + self.core.watchdog_ns()
            } else {
                self.next
            };
            if self.pty.is_none() {
                sleep_until_ns(until);
                continue;
            }
            let left = until - now;
            let ts = libc::timespec {
                tv_sec: (left / 1_000_000_000) as libc::time_t,
                tv_nsec: (left % 1_000_000_000) as libc::c_long,
            };
            let mut pfd = libc::pollfd {
                fd: self.link.fd,
                events: libc::POLLIN,
                revents: 0,
            };
            // SAFETY: one valid pollfd and timespec.
            let r = unsafe { libc::ppoll(&mut pfd, 1, &ts, std::ptr::null()) };
            if r <= 0 || pfd.revents & libc::POLLIN == 0 {
                if r > 0 {
                    // Hang-up without data: wait out the period.
                    sleep_until_ns(until);
                }
                continue;
            }
            // SAFETY: valid fd and buffer.
            let n = unsafe { libc::read(self.link.fd, rx.as_mut_ptr().cast(), rx.len()) };
            if n <= 0 {
                continue;
            }
            let now = monotonic_ns();
            if now < self.stalled_until {
                continue; // a hung device reads nothing
            }
            let t_dev = now - self.start;
            for &b in &rx[..n as usize] {
                let msg = match self.link.reader.push(b) {
                    None => continue,
                    Some(Frame::TooLong) => {
                        self.status.bad_frames.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                    Some(Frame::Bytes(f)) => match protocol::decode::<HostMessage>(f) {
                        Ok(m) => m,
                        Err(_) => {
                            self.status.bad_frames.fetch_add(1, Ordering::Relaxed);
                            continue;
                        }
                    },
                };
                self.answer(msg, now, t_dev);
            }
            self.status.publish(&self.core);
        }
    }

    /// Acts on one host message as the firmware does, at `now` (monotonic
    /// ns; `t_dev` on the device's clock): a hello opens the session
    /// (device disabled, hello sent back), enable / disable / status
    /// requests are answered with the status, a command drives the device
    /// (a late one counted; the status sent when it faults the device).
    fn answer(&mut self, msg: HostMessage, now: u64, t_dev: u64) {
        let (core, status, link) = (&mut self.core, self.status, &mut self.link);
        match msg {
            HostMessage::Hello { .. } => {
                core.disable();
                self.session = true;
                status.host_connected.store(true, Ordering::Relaxed);
                link.send(&DeviceMessage::Hello(self.hello), now, false);
            }
            HostMessage::Enable => {
                core.enable(t_dev);
                self.answered = true;
                status.last_command_mono_ns.store(now, Ordering::Relaxed);
                link.send(&status_msg(core, status), now, false);
            }
            HostMessage::Disable => {
                core.disable();
                link.send(&status_msg(core, status), now, false);
            }
            HostMessage::StatusRequest => {
                link.send(&status_msg(core, status), now, false);
            }
            HostMessage::Command {
                answers_seq,
                current_a,
            } => {
                if answers_seq != self.last_sent_seq && current_a != 0.0 {
                    status.late_commands.fetch_add(1, Ordering::Relaxed);
                }
                if answers_seq == self.last_sent_seq {
                    self.answered = true;
                }
                let had_fault = core.fault().is_some();
                if core.command(
                    Command {
                        current_a: current_a.into(),
                        answers_seq: answers_seq.into(),
                    },
                    t_dev,
                ) {
                    status.commands_received.fetch_add(1, Ordering::Relaxed);
                    status.last_command_mono_ns.store(now, Ordering::Relaxed);
                } else if !had_fault && core.fault().is_some() {
                    link.send(&status_msg(core, status), now, false);
                }
            }
        }
    }

    /// Injects the link faults due by `now` (monotonic ns): bit flips,
    /// dropped, delayed or held frames act on the frames sent from now on,
    /// a stall hangs the device, a disconnect closes the pty.
    fn inject_faults(&mut self, now: u64) {
        let link = &mut self.link;
        let t_s = (now - self.start) as f64 * 1e-9;
        while self.faults.front().is_some_and(|f| f.at_s <= t_s) {
            let f = self.faults.pop_front().expect("checked");
            match f.kind {
                LinkFault::BitFlips { bits, frames } => {
                    link.flip_bits = bits;
                    link.flip_frames = frames;
                }
                LinkFault::Drop { frames } => link.drop_frames = frames,
                LinkFault::Delay { delay_s } => link.delay_ns = (delay_s * 1e9) as u64,
                LinkFault::Hold { duration_s } => {
                    link.hold_until_ns = now + (duration_s * 1e9) as u64;
                }
                LinkFault::Stall { duration_s } => {
                    self.stalled_until = now + (duration_s * 1e9) as u64;
                }
                LinkFault::Disconnect => {
                    // The cable is pulled; the device itself keeps running
                    // (and its watchdog with it).
                    self.pty.take();
                    link.fd = -1;
                    self.session = false;
                    self.status.host_connected.store(false, Ordering::Relaxed);
                }
            }
        }
    }

    /// The device's tick at `now` (monotonic ns), on its timer's time: the
    /// plant steps, a watchdog trip is stamped (and its status sent to the
    /// host), the status is published and, in a session, the sample sent.
    fn tick(&mut self, now: u64) {
        let (core, status, link) = (&mut self.core, self.status, &mut self.link);
        self.last_tick_ns = now;
        self.answered = false;
        let was_enabled = core.is_enabled();
        // Device time is the timer's: the tick's scheduled time.
        let s = core.tick(self.next.min(now) - self.start);
        if was_enabled && !core.is_enabled() && core.fault() == Some(DeviceFault::Watchdog) {
            // The device's state (0 A) is published before the trip
            // stamps: whoever sees the stamp sees the current dropped.
            status.publish(core);
            status
                .watchdog_trip_deadline_mono_ns
                .store(self.next, Ordering::Release);
            status.watchdog_trip_mono_ns.store(now, Ordering::Release);
            if self.session {
                link.send(&status_msg(core, status), now, false);
            }
        }
        status.publish(core);
        if self.session {
            self.last_sent_seq = s.seq as u32;
            link.send(&DeviceMessage::Sample(wire_sample(&s, self.lsb)), now, true);
            status.samples_sent.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// A sample as framed on the wire: the position in probe counts of `lsb`
/// m (clamped to the i32 range, [`INVALID_POSITION`] when not finite), the
/// device time in µs, the flags as their bits.
fn wire_sample(s: &Sample, lsb: f64) -> WireSample {
    let position = if s.position_m.is_finite() {
        (s.position_m / lsb)
            .round()
            .clamp(f64::from(i32::MIN + 1), f64::from(i32::MAX)) as i32
    } else {
        INVALID_POSITION
    };
    let mut fl = 0;
    if s.flags.out_of_range {
        fl |= flags::OUT_OF_RANGE;
    }
    if s.flags.amplifier_enabled {
        fl |= flags::AMPLIFIER_ENABLED;
    }
    if s.flags.amplifier_fault {
        fl |= flags::FAULT;
    }
    if s.flags.command_late {
        fl |= flags::COMMAND_LATE;
    }
    WireSample {
        seq: s.seq as u32,
        time_us: s.device_time_ns / 1000,
        position,
        current_a: s.measured_current_a as f32,
        flags: fl,
    }
}

/// The deadline of the tick after the one due at `next`: `next` itself,
/// or, when the thread fell more than a period behind (preempted), the
/// first period boundary ahead, the missed ticks skipped as a timer
/// interrupt that was masked would skip them. A skipped tick was late by
/// how far behind the thread fell (a watchdog trip it would have made
/// comes that much later): kept in `status.max_tick_lateness_ns` when
/// `jitter` (a lockstep device waits for its host on purpose).
fn next_deadline(next: u64, period: u64, status: &EmulatorStatus, jitter: bool) -> u64 {
    let now = monotonic_ns();
    if now <= next + period {
        return next;
    }
    if jitter {
        status
            .max_tick_lateness_ns
            .fetch_max(now - next, Ordering::Relaxed);
    }
    now - (now - next) % period + period
}
