//! Serial DAQ backend: a USB-serial (CDC-ACM) microcontroller speaking the
//! [`protocol`](bench_protocol::serial) (specified in `hal/protocol/PROTOCOL.md`).
//!
//! The port is opened with the `serialport` crate (raw mode, exclusive:
//! `TIOCEXCL` plus an exclusive `flock`, so a second `bench` on the same port
//! is refused as [`ErrorKind::Busy`], even as root). On the real-time tick
//! the backend then works on the raw file descriptor with `ppoll`/`read`/
//! `write` and fixed buffers, so reading and writing never allocate.
//!
//! The device owns the clock ([`Clock::Device`]): [`SerialStage::read_sample`]
//! returns the samples in order, one per call, waiting at most
//! `sample_timeout_periods` for the next one. Samples that arrive in a burst
//! (the USB or pty layer delayed them) are all returned, back to back, so
//! the loop catches up without losing any. The host keeps as many as the
//! device runs on one command before its watchdog stops it
//! ([`backlog_len`]: the announced `watchdog_ms` of samples, plus
//! [`BACKLOG`]), so a host that stalls for less than the device's watchdog
//! loses no sample: after the stall the loop answers them all, and the
//! supervisor judges the stall by the late commands the device flagged. If
//! more pile up, the oldest are dropped and counted as late; the supervisor
//! then sees the sequence gap.
//!
//! Errors on the tick and what the loop's link supervision makes of them:
//!
//! | condition | error kind | host reaction |
//! |---|---|---|
//! | no frame at all within the timeout | `Timeout` | silent link: judged by how long it has been silent (the device's watchdog, the job's stall bound, the reach of the held command) |
//! | only corrupt frames within the timeout | `Crc` | bad sample; K in a row → link fault |
//! | end of file, `POLLHUP`, `EIO` (unplugged, emulator gone) | `Link` | link fault at once |
//! | write failed or blocked beyond one period | `Link` | link fault at once |
//!
//! **A corrupt frame costs its own sample, never the next one.** A bit
//! error on a frame's `0x00` delimiter glues the following frame, intact,
//! to the corrupt one; the receiver then sees one bad frame where two
//! samples were sent, and K corrupt frames could show as a gap of K + 1
//! (the link fault), where K dropped frames show as a gap of K. So a
//! rejected frame is searched, from its end, for a valid frame
//! (`recover`): the intact frame glued to it is returned as if its
//! delimiter had been there (counted in [`SerialStats::recovered_frames`]).
//! Only complete suffixes that pass the CRC-32C are taken, so the search
//! never invents a frame (odds 2⁻³² per try, at most 63 tries); a frame
//! whose content is intact but whose own delimiter was hit is still lost
//! (it is the corrupt one).
//!
//! Layer rule: may use `os`, `param`.

use crate::os::monotonic_ns;
use crate::{Clock, Command, DeviceInfo, ErrorKind, LifecycleError, Sample, SampleFlags, Stage};
use bench_protocol::serial::{
    self as protocol, flags, DeviceHello, DeviceMessage, FrameError, HostMessage, WireSample,
    WireStatus, INVALID_POSITION, MAX_FRAME,
};
use std::os::fd::{AsRawFd, RawFd};
use std::time::Duration;

/// Samples queued on the host side beyond the device's watchdog time
/// ([`backlog_len`]); older ones are dropped beyond.
pub const BACKLOG: usize = 32;

/// Longest watchdog whose samples the host keeps, s (the device's watchdog
/// is at most 1 s: a dead host must not leave current flowing longer).
pub const BACKLOG_WATCHDOG_MAX_S: f64 = 1.0;

/// Samples the host queues at most for a device sampling every `period_ns`
/// with a watchdog of `watchdog_ms` (`u32::MAX`: not announced, taken as
/// [`BACKLOG_WATCHDOG_MAX_S`]): every sample of one watchdog time, plus
/// [`BACKLOG`]. Allocated at `configure`, never on the tick.
pub fn backlog_len(period_ns: u64, watchdog_ms: u32) -> usize {
    let watchdog_s = if watchdog_ms == u32::MAX {
        BACKLOG_WATCHDOG_MAX_S
    } else {
        (f64::from(watchdog_ms) * 1e-3).min(BACKLOG_WATCHDOG_MAX_S)
    };
    (watchdog_s * 1e9 / period_ns.max(1) as f64).ceil() as usize + BACKLOG
}

const EMPTY_SAMPLE: WireSample = WireSample {
    seq: 0,
    time_us: 0,
    position: 0,
    current_a: 0.0,
    flags: 0,
};

/// Serial backend settings (the `[backend.serial]` table).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SerialConfig {
    /// Device path, e.g. `/dev/ttyACM0` (the `--backend serial:PATH` argument
    /// overrides it).
    pub path: String,
    /// Line rate, baud (ignored by USB CDC-ACM devices and pseudo-terminals).
    pub baud: u32,
    /// How long to wait for the device's hello and for enable/disable
    /// acknowledgements, ms (`bench` accepts 1 ms … 10 s).
    pub handshake_timeout_ms: f64,
    /// Longest wait for a sample on the tick, in sample periods (default 25:
    /// 5 ms at 5 kHz). Past it the read is a bad sample (`Timeout`); the
    /// host's link fault comes after `safety.max_missed_samples + 1` of them
    /// in a row. USB and pseudo-terminal layers deliver samples in bursts:
    /// on a loaded 2-core VM a pty held samples back for up to 5.4 ms.
    /// Range: 1 … 1000 periods; `bench` also holds it to at most 200 ms at
    /// the loop rate, and `(max_missed_samples + 1)` of them to at most 1 s.
    pub sample_timeout_periods: f64,
}

impl Default for SerialConfig {
    fn default() -> Self {
        Self {
            path: "/dev/ttyACM0".into(),
            baud: 921_600,
            handshake_timeout_ms: 500.0,
            sample_timeout_periods: 25.0,
        }
    }
}

impl SerialConfig {
    /// Checks every value, keys under `prefix`.
    ///
    /// # Errors
    /// The first offending key with the reason.
    pub fn validate(&self, prefix: &str) -> Result<(), crate::param::ParamError> {
        if self.path.is_empty() {
            return Err(crate::param::ParamError::new(
                format!("{prefix}.path"),
                "is empty",
            ));
        }
        crate::param::positive(
            &format!("{prefix}.handshake_timeout_ms"),
            self.handshake_timeout_ms,
        )?;
        if !(self.sample_timeout_periods >= 1.0 && self.sample_timeout_periods <= 1000.0) {
            return Err(crate::param::ParamError::new(
                format!("{prefix}.sample_timeout_periods"),
                format!(
                    "{} is outside 1 … 1000 periods",
                    self.sample_timeout_periods
                ),
            ));
        }
        Ok(())
    }
}

/// Errors of the serial backend.
#[derive(Debug, thiserror::Error)]
pub enum SerialError {
    /// The device path does not exist.
    #[error("serial device {path} does not exist")]
    NotFound {
        /// The path.
        path: String,
    },
    /// Another process holds the port.
    #[error("serial device {path} is busy (held by another process)")]
    Busy {
        /// The path.
        path: String,
    },
    /// Opening or configuring the port failed.
    #[error("cannot open serial device {path}: {reason}")]
    Open {
        /// The path.
        path: String,
        /// The system's reason.
        reason: String,
    },
    /// The device did not answer the hello in time, or answered garbage.
    #[error("no protocol hello from {path} within {timeout_ms} ms ({bad_frames} bad frames): is it a bench DAQ?")]
    NoHello {
        /// The path.
        path: String,
        /// How long we waited.
        timeout_ms: f64,
        /// Corrupt frames seen meanwhile.
        bad_frames: u64,
    },
    /// The device speaks another protocol version.
    #[error("device on {path} speaks protocol version {device}, bench speaks version {host}")]
    Version {
        /// The path.
        path: String,
        /// The device's version.
        device: u16,
        /// Ours.
        host: u16,
    },
    /// The device samples at another rate than the loop asks for.
    #[error("device on {path} samples every {device_ns} ns ({:.1} Hz) but the loop asks for {requested_ns} ns ({:.1} Hz): set [loop] rate_hz to the device's rate", 1e9 / *device_ns as f64, 1e9 / *requested_ns as f64)]
    Rate {
        /// The path.
        path: String,
        /// Device period, ns.
        device_ns: u64,
        /// Requested period, ns.
        requested_ns: u64,
    },
    /// No acknowledgement of enable/disable in time.
    #[error("device did not acknowledge {what} within {timeout_ms} ms")]
    NoAck {
        /// `enable` or `disable`.
        what: &'static str,
        /// How long we waited.
        timeout_ms: f64,
    },
    /// The device refused to enable (a latched fault it could not clear).
    #[error("device refused to enable (fault code {fault})")]
    Refused {
        /// The device's fault code.
        fault: u8,
    },
    /// No sample within the timeout.
    #[error("no sample within {timeout_us} µs")]
    Timeout {
        /// The timeout, µs.
        timeout_us: u64,
    },
    /// Only corrupt frames within the timeout.
    #[error("only corrupt frames within the sample timeout (last: {0})")]
    Corrupt(FrameError),
    /// The link is gone (unplugged, peer closed).
    #[error("serial link lost: {0}")]
    Disconnected(&'static str),
    /// A lifecycle method in the wrong state (the port closed).
    #[error("serial stage: {0}")]
    State(&'static str),
    /// Used against the stage's lifecycle.
    #[error("serial stage: {0}")]
    Lifecycle(#[from] crate::LifecycleError),
    /// The device reports a latched fault while enabled.
    #[error("device reports a latched fault (code {code}: 1 watchdog, 2 bad command); its amplifier is off")]
    DeviceFault {
        /// The device's fault code (0 if no status came with it).
        code: u8,
    },
}

impl crate::Error for SerialError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::NotFound { .. } => ErrorKind::NotFound,
            Self::Busy { .. } => ErrorKind::Busy,
            Self::Open { .. } | Self::Disconnected(_) => ErrorKind::Link,
            Self::NoHello { .. } | Self::Version { .. } => ErrorKind::Protocol,
            Self::Rate { .. } => ErrorKind::Config,
            Self::NoAck { .. } | Self::Timeout { .. } => ErrorKind::Timeout,
            Self::Refused { .. } | Self::DeviceFault { .. } => ErrorKind::AmplifierFault,
            Self::Corrupt(_) => ErrorKind::Crc,
            Self::State(_) => ErrorKind::InvalidState,
            Self::Lifecycle(e) => crate::Error::kind(e),
        }
    }
}

/// Link counters of the serial backend.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct SerialStats {
    /// Samples returned to the loop.
    pub samples: u64,
    /// Frames that failed their CRC.
    pub crc_errors: u64,
    /// Frames that were not valid COBS, too short or too long, or did not
    /// decode.
    pub frame_errors: u64,
    /// Sequence gaps seen (each gap counts once).
    pub sequence_gaps: u64,
    /// Samples the device sent that never reached the loop (sum of gap
    /// sizes, late ones included).
    pub missed_samples: u64,
    /// Samples dropped because more than [`backlog_len`] were waiting (the
    /// host fell behind by more than the device's watchdog time).
    pub late_samples: u64,
    /// Most samples that were waiting at once.
    pub max_backlog: u64,
    /// Reads that timed out.
    pub timeouts: u64,
    /// Intact frames recovered from the end of a rejected one (a bit error
    /// on the delimiter between them had glued them together).
    pub recovered_frames: u64,
}

/// The serial DAQ stage.
pub struct SerialStage {
    cfg: SerialConfig,
    port: Option<serialport::TTYPort>,
    fd: RawFd,
    /// The bytes received since the last delimiter, the last [`MAX_FRAME`]
    /// of them (a ring): the frame being received, or the end of an
    /// over-long one.
    tail: [u8; MAX_FRAME],
    /// Bytes received since the last delimiter (may exceed [`MAX_FRAME`]).
    tail_len: usize,
    /// A message recovered from the end of the last rejected frame, not
    /// yet returned.
    recovered: Option<DeviceMessage>,
    rx: [u8; 512],
    rx_len: usize,
    rx_pos: usize,
    /// Received samples not yet returned, oldest first (ring).
    queue: Box<[WireSample]>,
    queue_head: usize,
    queue_len: usize,
    hello: Option<DeviceHello>,
    period_ns: u64,
    timeout_ns: u64,
    /// First device sequence number after configure (seq 0 for the loop).
    seq_base: Option<u64>,
    /// Unwrapped device sequence of the last sample returned.
    last_seq: Option<u64>,
    /// Device time of the first sample after configure, µs.
    time_base_us: Option<u64>,
    enabled: bool,
    stats: SerialStats,
    last_status: Option<WireStatus>,
}

impl std::fmt::Debug for SerialStage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SerialStage")
            .field("path", &self.cfg.path)
            .field("hello", &self.hello)
            .field("stats", &self.stats)
            .finish()
    }
}

/// What [`SerialStage::next_buffered`] yields.
enum Rx {
    /// A valid message.
    Message(DeviceMessage),
    /// A rejected frame: why, and its bytes as received (COBS-encoded; the
    /// last [`MAX_FRAME`] of them when it was too long), `len` of them.
    Rejected(FrameError, [u8; MAX_FRAME], usize),
}

/// The message of the longest proper suffix of `raw` (a rejected frame's
/// bytes, as received) that is a valid frame: where a bit error destroyed a
/// delimiter, the next frame sits intact at the end of the corrupt one.
/// Real-time: stack buffers only.
fn recover(raw: &[u8]) -> Option<DeviceMessage> {
    (1..raw.len()).find_map(|start| {
        let mut buf = [0u8; MAX_FRAME];
        let part = &mut buf[..raw.len() - start];
        part.copy_from_slice(&raw[start..]);
        protocol::decode::<DeviceMessage>(part).ok()
    })
}

/// What [`SerialStage::wait_for`] shows its filter.
enum Seen<'a> {
    /// A valid message.
    Message(DeviceMessage),
    /// A rejected frame, raw.
    Rejected(&'a mut [u8]),
}

impl SerialStage {
    /// Opens the port (exclusively). Nothing is sent until
    /// [`configure`](Stage::configure).
    ///
    /// # Errors
    /// `NotFound` if the path does not exist, `Busy` if another process
    /// holds it, `Link` if it cannot be opened or set to raw mode.
    pub fn open(cfg: &SerialConfig) -> Result<Self, SerialError> {
        let path = cfg.path.clone();
        if !std::path::Path::new(&path).exists() {
            return Err(SerialError::NotFound { path });
        }
        let port = serialport::new(&path, cfg.baud)
            .timeout(Duration::from_millis(100))
            .open_native()
            .map_err(|e| match e.kind() {
                serialport::ErrorKind::NoDevice => SerialError::Busy { path: path.clone() },
                serialport::ErrorKind::Io(std::io::ErrorKind::NotFound) => {
                    SerialError::NotFound { path: path.clone() }
                }
                _ => SerialError::Open {
                    path: path.clone(),
                    reason: e.to_string(),
                },
            })?;
        let fd = port.as_raw_fd();
        Ok(Self {
            cfg: cfg.clone(),
            port: Some(port),
            fd,
            tail: [0; MAX_FRAME],
            tail_len: 0,
            recovered: None,
            rx: [0; 512],
            rx_len: 0,
            rx_pos: 0,
            queue: vec![EMPTY_SAMPLE; BACKLOG].into_boxed_slice(),
            queue_head: 0,
            queue_len: 0,
            hello: None,
            period_ns: 0,
            timeout_ns: 0,
            seq_base: None,
            last_seq: None,
            time_base_us: None,
            enabled: false,
            stats: SerialStats::default(),
            last_status: None,
        })
    }

    /// Link counters so far.
    pub fn stats(&self) -> SerialStats {
        self.stats
    }

    /// The device's hello (after `configure`).
    pub fn device_hello(&self) -> Option<&DeviceHello> {
        self.hello.as_ref()
    }

    /// The last status the device reported.
    pub fn last_status(&self) -> Option<WireStatus> {
        self.last_status
    }

    fn send(&mut self, msg: &HostMessage) -> Result<(), SerialError> {
        let mut frame = [0u8; MAX_FRAME];
        let n = protocol::encode(msg, &mut frame);
        let deadline = monotonic_ns() + self.timeout_ns.max(1_000_000);
        let mut off = 0;
        while off < n {
            // SAFETY: fd is open for the port's lifetime; the slice is valid.
            let r = unsafe { libc::write(self.fd, frame[off..n].as_ptr().cast(), n - off) };
            if r > 0 {
                off += r as usize;
                continue;
            }
            let err = std::io::Error::last_os_error().raw_os_error();
            match err {
                Some(libc::EINTR) => continue,
                Some(libc::EAGAIN) if monotonic_ns() < deadline => {
                    self.poll(libc::POLLOUT, deadline)?;
                }
                Some(libc::EAGAIN) => return Err(SerialError::Disconnected("write blocked")),
                _ => return Err(SerialError::Disconnected("write failed")),
            }
        }
        Ok(())
    }

    /// Waits for `events` on the fd until `deadline` (monotonic ns).
    /// `Ok(true)` ready, `Ok(false)` timed out.
    fn poll(&self, events: libc::c_short, deadline: u64) -> Result<bool, SerialError> {
        loop {
            let revents = match crate::os::poll_until(self.fd, events, deadline) {
                Err(_) => return Err(SerialError::Disconnected("poll failed")),
                Ok(None) => return Ok(false),
                Ok(Some(r)) => r,
            };
            if revents & events != 0 {
                return Ok(true);
            }
            if revents & (libc::POLLHUP | libc::POLLERR | libc::POLLNVAL) != 0 {
                return Err(SerialError::Disconnected("device hung up"));
            }
        }
    }

    /// Reads what is available into the receive buffer (after the fd was
    /// reported readable). `Err` on end of file or an I/O error.
    fn fill(&mut self) -> Result<(), SerialError> {
        self.rx_pos = 0;
        self.rx_len = 0;
        loop {
            // SAFETY: fd is open; rx is a valid writable buffer.
            let r = unsafe { libc::read(self.fd, self.rx.as_mut_ptr().cast(), self.rx.len()) };
            if r > 0 {
                self.rx_len = r as usize;
                return Ok(());
            }
            if r == 0 {
                return Err(SerialError::Disconnected("end of file"));
            }
            match std::io::Error::last_os_error().raw_os_error() {
                Some(libc::EINTR) => continue,
                Some(libc::EAGAIN) => return Ok(()),
                _ => return Err(SerialError::Disconnected("read failed (device gone)")),
            }
        }
    }

    /// The next complete frame in the receive buffer: a valid device
    /// message, or a rejected frame (counted). After a rejected frame, the
    /// intact frame a corrupted delimiter glued to its end, if any
    /// (`recover`), comes next. Real-time: fixed buffers.
    fn next_buffered(&mut self) -> Option<Rx> {
        if let Some(m) = self.recovered.take() {
            return Some(Rx::Message(m));
        }
        while self.rx_pos < self.rx_len {
            let b = self.rx[self.rx_pos];
            self.rx_pos += 1;
            if b != 0 {
                self.tail[self.tail_len % MAX_FRAME] = b;
                self.tail_len += 1;
                continue;
            }
            let len = std::mem::take(&mut self.tail_len);
            if len == 0 {
                continue;
            }
            let n = len.min(MAX_FRAME);
            let mut raw = [0u8; MAX_FRAME];
            for (i, r) in raw[..n].iter_mut().enumerate() {
                *r = self.tail[(len - n + i) % MAX_FRAME];
            }
            let err = if len > MAX_FRAME {
                FrameError::TooLong
            } else {
                let mut frame = raw;
                match protocol::decode::<DeviceMessage>(&mut frame[..n]) {
                    Ok(m) => return Some(Rx::Message(m)),
                    Err(e) => e,
                }
            };
            self.count_bad(err);
            self.recovered = recover(&raw[..n]);
            if self.recovered.is_some() {
                self.stats.recovered_frames += 1;
            }
            return Some(Rx::Rejected(err, raw, n));
        }
        None
    }

    fn enqueue(&mut self, s: WireSample) {
        let cap = self.queue.len();
        if self.queue_len == cap {
            self.queue_head = (self.queue_head + 1) % cap;
            self.queue_len -= 1;
            self.stats.late_samples += 1;
        }
        self.queue[(self.queue_head + self.queue_len) % cap] = s;
        self.queue_len += 1;
        self.stats.max_backlog = self.stats.max_backlog.max(self.queue_len as u64);
    }

    fn count_bad(&mut self, e: FrameError) {
        if e == FrameError::Crc {
            self.stats.crc_errors += 1;
        } else {
            self.stats.frame_errors += 1;
        }
    }

    /// Waits (until `deadline`) for a message accepted by `want`, consuming
    /// what comes before. `want` also sees each rejected frame's raw bytes
    /// (COBS-encoded, as received). Not real-time.
    fn wait_for<T>(
        &mut self,
        deadline: u64,
        mut want: impl FnMut(Seen<'_>) -> Option<T>,
    ) -> Result<Option<T>, SerialError> {
        loop {
            while let Some(rx) = self.next_buffered() {
                let got = match rx {
                    Rx::Message(m) => {
                        if let DeviceMessage::Status(s) = m {
                            self.last_status = Some(s);
                        }
                        want(Seen::Message(m))
                    }
                    Rx::Rejected(FrameError::TooLong, ..) => None,
                    Rx::Rejected(_, mut raw, len) => want(Seen::Rejected(&mut raw[..len])),
                };
                if got.is_some() {
                    return Ok(got);
                }
            }
            if !self.poll(libc::POLLIN, deadline)? {
                return Ok(None);
            }
            self.fill()?;
        }
    }

    fn handshake_deadline(&self) -> u64 {
        monotonic_ns() + (self.cfg.handshake_timeout_ms * 1e6) as u64
    }

    fn request_status(
        &mut self,
        msg: HostMessage,
        what: &'static str,
    ) -> Result<WireStatus, SerialError> {
        if self.port.is_none() || self.hello.is_none() {
            return Err(LifecycleError::NotConfigured.into());
        }
        self.send(&msg)?;
        let deadline = self.handshake_deadline();
        let got = self.wait_for(deadline, |m| match m {
            Seen::Message(DeviceMessage::Status(s)) => Some(s),
            _ => None,
        })?;
        got.ok_or(SerialError::NoAck {
            what,
            timeout_ms: self.cfg.handshake_timeout_ms,
        })
    }
}

impl Stage for SerialStage {
    type Error = SerialError;

    /// Flushes the input, sends the hello and waits for the device's; checks
    /// the version and the rate.
    fn configure(&mut self, period_ns: u64) -> Result<DeviceInfo, SerialError> {
        let Some(port) = self.port.as_mut() else {
            return Err(SerialError::State("port closed"));
        };
        let _ = serialport::SerialPort::clear(port, serialport::ClearBuffer::Input);
        self.tail_len = 0;
        self.recovered = None;
        self.rx_len = 0;
        self.rx_pos = 0;
        self.queue_len = 0;
        self.hello = None;
        self.timeout_ns = period_ns;
        self.send(&HostMessage::Hello {
            version: protocol::VERSION,
        })?;
        let deadline = self.handshake_deadline();
        let got = self.wait_for(deadline, |m| match m {
            Seen::Message(DeviceMessage::Hello(h)) => Some(Ok(h)),
            // A CRC-valid frame that does not decode: maybe another
            // version's hello.
            Seen::Rejected(raw) => protocol::peek_hello_version(raw).map(Err),
            Seen::Message(_) => None,
        })?;
        let path = self.cfg.path.clone();
        let hello = match got {
            None => {
                return Err(SerialError::NoHello {
                    path,
                    timeout_ms: self.cfg.handshake_timeout_ms,
                    bad_frames: self.stats.crc_errors + self.stats.frame_errors,
                })
            }
            Some(Err(v)) | Some(Ok(DeviceHello { version: v, .. })) if v != protocol::VERSION => {
                return Err(SerialError::Version {
                    path,
                    device: v,
                    host: protocol::VERSION,
                })
            }
            Some(Ok(h)) => h,
            Some(Err(_)) => unreachable!("a matching version decodes"),
        };
        if u64::from(hello.period_ns) != period_ns {
            return Err(SerialError::Rate {
                path,
                device_ns: hello.period_ns.into(),
                requested_ns: period_ns,
            });
        }
        self.hello = Some(hello);
        self.period_ns = period_ns;
        let cap = backlog_len(period_ns, hello.watchdog_ms);
        if self.queue.len() != cap {
            self.queue = vec![EMPTY_SAMPLE; cap].into_boxed_slice();
        }
        self.queue_head = 0;
        self.queue_len = 0;
        self.timeout_ns = (period_ns as f64 * self.cfg.sample_timeout_periods) as u64;
        self.seq_base = None;
        self.last_seq = None;
        self.time_base_us = None;
        self.enabled = false;
        Ok(DeviceInfo {
            name: format!("serial:{path} (protocol v{})", hello.version),
            clock: Clock::Device {
                rate_hz: 1e9 / period_ns as f64,
            },
            period_ns,
            peak_current_a: hello.peak_current_a.into(),
            continuous_current_a: hello.continuous_current_a.into(),
            probe_range_m: hello.probe_range_m.into(),
            probe_lsb_m: f64::from(hello.position_lsb_m).abs(),
            watchdog_s: (hello.watchdog_ms != u32::MAX)
                .then(|| f64::from(hello.watchdog_ms) * 1e-3),
        })
    }

    fn enable(&mut self) -> Result<(), SerialError> {
        let s = self.request_status(HostMessage::Enable, "enable")?;
        if !s.enabled {
            return Err(SerialError::Refused { fault: s.fault });
        }
        self.enabled = true;
        // Samples that came in meanwhile stay queued: the loop answers them
        // in order and catches up within a few ticks (a device in lockstep
        // waits for those answers).
        Ok(())
    }

    /// Real-time: fixed buffers, `ppoll`/`read` only.
    fn read_sample(&mut self) -> Result<Sample, SerialError> {
        let Some(hello) = self.hello else {
            return Err(LifecycleError::NotConfigured.into());
        };
        let deadline = monotonic_ns() + self.timeout_ns;
        let mut last_bad = None;
        loop {
            while let Some(rx) = self.next_buffered() {
                match rx {
                    Rx::Message(DeviceMessage::Sample(s)) => self.enqueue(s),
                    Rx::Message(DeviceMessage::Status(s)) => self.last_status = Some(s),
                    Rx::Message(DeviceMessage::Hello(_)) => {}
                    Rx::Rejected(e, ..) => last_bad = Some(e),
                }
            }
            if self.queue_len > 0 {
                break;
            }
            if !self.poll(libc::POLLIN, deadline)? {
                break;
            }
            self.fill()?;
        }
        if self.queue_len == 0 {
            self.stats.timeouts += 1;
            return Err(match last_bad {
                Some(e) => SerialError::Corrupt(e),
                None => SerialError::Timeout {
                    timeout_us: self.timeout_ns / 1000,
                },
            });
        }
        let w = self.queue[self.queue_head];
        self.queue_head = (self.queue_head + 1) % self.queue.len();
        self.queue_len -= 1;
        if self.enabled && w.flags & flags::FAULT != 0 {
            // The device latched a fault (its watchdog, a refused command)
            // while we drive it: nothing we command reaches the coil.
            self.enabled = false;
            return Err(SerialError::DeviceFault {
                code: self.last_status.map_or(0, |s| s.fault),
            });
        }
        // Unwrap the 32-bit sequence against the last one.
        let seq = match self.last_seq {
            None => u64::from(w.seq),
            Some(last) => {
                let delta = w.seq.wrapping_sub(last as u32);
                last + u64::from(delta)
            }
        };
        if let Some(last) = self.last_seq {
            if seq > last + 1 {
                self.stats.sequence_gaps += 1;
                self.stats.missed_samples += seq - last - 1;
            }
        }
        self.last_seq = Some(seq);
        let base = *self.seq_base.get_or_insert(seq);
        let time_base = *self.time_base_us.get_or_insert(w.time_us);
        self.stats.samples += 1;
        Ok(Sample {
            seq: seq - base,
            device_time_ns: w.time_us.saturating_sub(time_base).saturating_mul(1000),
            position_m: if w.position == INVALID_POSITION {
                f64::NAN
            } else {
                f64::from(w.position) * f64::from(hello.position_lsb_m)
            },
            measured_current_a: w.current_a.into(),
            flags: SampleFlags {
                out_of_range: w.flags & flags::OUT_OF_RANGE != 0,
                amplifier_enabled: w.flags & flags::AMPLIFIER_ENABLED != 0,
                amplifier_fault: w.flags & flags::FAULT != 0,
                command_late: w.flags & flags::COMMAND_LATE != 0,
            },
        })
    }

    /// Real-time: one frame written from a stack buffer.
    fn write_command(&mut self, command: Command) -> Result<(), SerialError> {
        let i = command.current_a;
        if let Err(e) = LifecycleError::check_command(self.hello.is_some(), self.enabled, i) {
            if matches!(e, LifecycleError::NotFinite { .. }) {
                let _ = self.send(&HostMessage::Command {
                    answers_seq: 0,
                    current_a: 0.0,
                });
            }
            return Err(e.into());
        }
        let device_seq = command.answers_seq + self.seq_base.unwrap_or(0);
        self.send(&HostMessage::Command {
            answers_seq: device_seq as u32,
            current_a: i as f32,
        })
    }

    fn disable(&mut self) -> Result<(), SerialError> {
        self.enabled = false;
        if self.port.is_none() || self.hello.is_none() {
            return Ok(());
        }
        let _ = self.send(&HostMessage::Command {
            answers_seq: 0,
            current_a: 0.0,
        });
        let s = self.request_status(HostMessage::Disable, "disable")?;
        if s.enabled {
            return Err(SerialError::NoAck {
                what: "disable",
                timeout_ms: self.cfg.handshake_timeout_ms,
            });
        }
        Ok(())
    }
}

impl Drop for SerialStage {
    fn drop(&mut self) {
        if self.hello.is_some() {
            let _ = self.send(&HostMessage::Disable);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_frame(seq: u32) -> ([u8; MAX_FRAME], usize) {
        let mut f = [0u8; MAX_FRAME];
        let n = protocol::encode(
            &DeviceMessage::Sample(WireSample {
                seq,
                time_us: 1_000_000 + u64::from(seq) * 200,
                position: -12_345,
                current_a: 0.5,
                flags: 0,
            }),
            &mut f,
        );
        (f, n)
    }

    /// A frame whose delimiter was flipped, glued to the next: the next one
    /// comes back, whole, from the end; the glued-on frame itself does not
    /// (it is the corrupt one), nor does anything from a lone corrupt frame.
    #[test]
    fn the_frame_after_a_corrupted_delimiter_is_recovered() {
        let (a, na) = sample_frame(7);
        let (b, nb) = sample_frame(8);
        for bit in 0..8 {
            for flip_content in [None, Some(3), Some(na - 2)] {
                // The bytes between two delimiters as received: frame 7
                // (maybe also hit inside), its delimiter turned non-zero,
                // frame 8 without its delimiter.
                let mut raw = Vec::new();
                raw.extend_from_slice(&a[..na - 1]);
                if let Some(i) = flip_content {
                    raw[i] ^= 0x10;
                }
                raw.push(1 << bit);
                raw.extend_from_slice(&b[..nb - 1]);
                let Some(DeviceMessage::Sample(s)) = recover(&raw) else {
                    panic!("not recovered: bit {bit}, {flip_content:?}");
                };
                assert_eq!(s.seq, 8);
            }
        }
        // A lone corrupt frame (any one bit) yields nothing.
        for bit in 0..(na - 1) * 8 {
            let mut raw = a[..na - 1].to_vec();
            raw[bit / 8] ^= 1 << (bit % 8);
            if raw.contains(&0) {
                continue; // the flip made a delimiter: two frames
            }
            assert_eq!(recover(&raw), None, "bit {bit}");
        }
    }
}
