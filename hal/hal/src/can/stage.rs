//! The host side: [`CanStage`], the SocketCAN [`Stage`] backend, and its
//! link counters ([`CanStats`]).

use super::socket::{can_option, open_socket, send_until, try_recv, wait_fd, Rx};
use super::{
    seq_delta, CanConfig, CanError, CanSocket, CommandPayload, SamplePayload, CAN_DATA_BYTES,
};
use crate::os::monotonic_ns;
use crate::{Clock, Command, DeviceInfo, LifecycleError, Sample, Stage};
use bench_protocol::DeviceFault;
use socketcan::{CanFrame, EmbeddedFrame, Frame, Socket, SocketOptions};
use std::io;
use std::os::fd::{AsRawFd, RawFd};

const LINK_WAIT_MIN_NS: u64 = 100_000_000;

/// Whether an error frame's classes make the read that meets it bad.
/// Lost arbitration, controller restart, error counters and a controller
/// report of only "back to error active" are informational.
fn error_frame_is_bad(bits: u32, data: &[u8]) -> bool {
    let informational =
        libc::CAN_ERR_LOSTARB | libc::CAN_ERR_RESTARTED | libc::CAN_ERR_CNT | libc::CAN_ERR_CRTL;
    if bits & !informational != 0 {
        return true;
    }
    bits & libc::CAN_ERR_CRTL != 0 && data[1] & !(libc::CAN_ERR_CRTL_ACTIVE as u8) != 0
}

/// Link counters of a [`CanStage`] (since it was created).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct CanStats {
    /// Samples returned by `read_sample`.
    pub samples: u64,
    /// Command frames sent.
    pub commands_sent: u64,
    /// SYNC frames sent.
    pub syncs_sent: u64,
    /// Error frames received (all classes).
    pub error_frames: u64,
    /// Bus-off reports.
    pub bus_off: u64,
    /// Reads that timed out.
    pub timeouts: u64,
    /// Sequence gaps seen (a jump of the counter by more than one).
    pub seq_gaps: u64,
    /// Samples missing in those gaps.
    pub lost_samples: u64,
    /// Samples discarded as late (answering an earlier SYNC) or stale.
    pub late_samples: u64,
    /// Frames refused: wrong size or shorter than the map.
    pub bad_frames: u64,
}

/// What one received frame means to the host.
enum Event {
    Sample(SamplePayload),
    BusOff,
    Bad(CanError),
    Ignore,
}

/// The SocketCAN stage (host side).
#[derive(Debug)]
pub struct CanStage {
    sock: CanSocket,
    cfg: CanConfig,
    sample_word: u32,
    sync_frame: libc::can_frame,
    kernel_filters: bool,
    period_ns: u64,
    timeout_ns: u64,
    configured: bool,
    enabled: bool,
    bus_off: bool,
    /// Device counter (raw) of the sample numbered 0.
    base_raw: u64,
    last_raw: Option<u64>,
    seq: u64,
    last_fault_code: u8,
    stats: CanStats,
}

impl CanStage {
    /// Opens `cfg.interface` with the error-frame mask and a sample-id
    /// filter.
    ///
    /// # Errors
    /// `Config` for an invalid `cfg`, `NotFound` for a missing interface,
    /// `Link` for other socket errors.
    pub fn open(cfg: &CanConfig) -> Result<Self, CanError> {
        cfg.validate("backend.can")?;
        let sock = open_socket(&cfg.interface)?;
        let stage = Self::from_socket(sock, cfg)?;
        if !stage.kernel_filters {
            return Err(CanError::Io {
                op: "setsockopt(CAN_RAW_FILTER)",
                source: io::Error::from_raw_os_error(libc::ENOPROTOOPT),
            });
        }
        Ok(stage)
    }

    /// Wraps an open socket (tests pass one end of a `UnixDatagram` pair).
    /// The error-frame mask and the sample-id filter are set when the
    /// socket is a CAN_RAW socket, skipped otherwise
    /// ([`kernel_filters`](Self::kernel_filters)).
    ///
    /// # Errors
    /// `Config` for an invalid `cfg`, `Link` for socket errors.
    pub fn from_socket(sock: CanSocket, cfg: &CanConfig) -> Result<Self, CanError> {
        cfg.validate("backend.can")?;
        sock.set_nonblocking(true).map_err(|source| CanError::Io {
            op: "set_nonblocking",
            source,
        })?;
        let errors = can_option(
            sock.set_error_filter_accept_all(),
            "setsockopt(CAN_RAW_ERR_FILTER)",
        )?;
        let ids = can_option(
            sock.set_filters(&[cfg.filter(cfg.sample_id())]),
            "setsockopt(CAN_RAW_FILTER)",
        )?;
        Ok(Self {
            sample_word: cfg.id_word(cfg.sample_id()),
            sync_frame: cfg.raw_frame(cfg.sync_id, &[]),
            kernel_filters: errors && ids,
            cfg: cfg.clone(),
            sock,
            period_ns: 0,
            timeout_ns: 0,
            configured: false,
            enabled: false,
            bus_off: false,
            base_raw: 0,
            last_raw: None,
            seq: 0,
            last_fault_code: 0,
            stats: CanStats::default(),
        })
    }

    /// The link counters.
    pub fn stats(&self) -> CanStats {
        self.stats
    }

    /// The configuration in force.
    pub fn config(&self) -> &CanConfig {
        &self.cfg
    }

    /// Whether the error-frame mask and id filter are set in the kernel
    /// (false on a non-CAN test socket).
    pub fn kernel_filters(&self) -> bool {
        self.kernel_filters
    }

    /// The fault the device reported in its latest sample, if any.
    pub fn device_fault(&self) -> Option<DeviceFault> {
        DeviceFault::from_code(self.last_fault_code)
    }

    fn fd(&self) -> RawFd {
        self.sock.as_raw_fd()
    }

    fn classify(&mut self, rx: Rx) -> Event {
        match rx {
            Rx::Bad(len) => {
                self.stats.bad_frames += 1;
                Event::Bad(CanError::BadDatagram { len })
            }
            Rx::Frame(CanFrame::Error(f)) => {
                self.stats.error_frames += 1;
                let bits = f.error_bits();
                if bits & libc::CAN_ERR_BUSOFF != 0 {
                    self.stats.bus_off += 1;
                    Event::BusOff
                } else {
                    let mut data = [0u8; CAN_DATA_BYTES];
                    let d = f.data();
                    let n = d.len().min(CAN_DATA_BYTES);
                    data[..n].copy_from_slice(&d[..n]);
                    if error_frame_is_bad(bits, &data) {
                        Event::Bad(CanError::ErrorFrame { bits, data })
                    } else {
                        Event::Ignore
                    }
                }
            }
            Rx::Frame(CanFrame::Data(f)) if f.id_word() == self.sample_word => {
                match self.cfg.sample.decode(f.data()) {
                    Ok(p) => Event::Sample(p),
                    Err(e) => {
                        self.stats.bad_frames += 1;
                        Event::Bad(e.into())
                    }
                }
            }
            Rx::Frame(_) => Event::Ignore,
        }
    }

    /// Numbers a received sample; `None` if it is stale (older than the
    /// last one).
    fn accept(&mut self, p: &SamplePayload) -> Option<Sample> {
        let w = self.cfg.sample.seq.width_bits;
        match self.last_raw {
            None => {
                self.base_raw = p.seq;
                self.seq = 0;
            }
            Some(last) => {
                let d = seq_delta(last, p.seq, w);
                if d < 0 {
                    self.stats.late_samples += 1;
                    return None;
                }
                if d > 1 {
                    self.stats.seq_gaps += 1;
                    self.stats.lost_samples += d as u64 - 1;
                }
                self.seq += d as u64;
            }
        }
        self.last_raw = Some(p.seq);
        self.last_fault_code = p.fault_code;
        Some(Sample {
            seq: self.seq,
            device_time_ns: self.seq.saturating_mul(self.period_ns),
            position_m: p.position_m,
            measured_current_a: p.measured_current_a,
            flags: p.flags,
        })
    }

    /// The next sample, waiting at most `timeout_ns` (see the module docs).
    fn next_sample(&mut self, timeout_ns: u64) -> Result<Sample, CanError> {
        if self.bus_off {
            return Err(CanError::BusOff);
        }
        let fd = self.fd();
        let sync = self.cfg.sync_producer;
        // 1. What is queued already.
        let mut newest: Option<SamplePayload> = None;
        let mut pending: Option<CanError> = None;
        while let Some(rx) = try_recv(fd).map_err(|source| CanError::Io { op: "recv", source })? {
            match self.classify(rx) {
                Event::Sample(p) => {
                    if sync {
                        self.stats.late_samples += 1;
                    } else {
                        newest = Some(p);
                        pending = None;
                    }
                }
                Event::BusOff => {
                    self.bus_off = true;
                    return Err(CanError::BusOff);
                }
                Event::Bad(e) => {
                    if !sync {
                        newest = None;
                        pending = Some(e);
                    }
                }
                Event::Ignore => {}
            }
        }
        if let Some(e) = pending {
            return Err(e);
        }
        if let Some(p) = newest {
            if let Some(s) = self.accept(&p) {
                return Ok(s);
            }
        }
        // 2. Trigger (SYNC) and wait.
        let start = monotonic_ns();
        let deadline = start + timeout_ns;
        if sync {
            send_until(fd, &self.sync_frame, deadline)?;
            self.stats.syncs_sent += 1;
        }
        loop {
            let ready = wait_fd(fd, libc::POLLIN, deadline)
                .map_err(|source| CanError::Io { op: "poll", source })?;
            if !ready {
                self.stats.timeouts += 1;
                return Err(CanError::Timeout {
                    waited_ns: monotonic_ns() - start,
                });
            }
            let Some(rx) = try_recv(fd).map_err(|source| CanError::Io { op: "recv", source })?
            else {
                continue;
            };
            match self.classify(rx) {
                Event::Sample(p) => {
                    if let Some(s) = self.accept(&p) {
                        return Ok(s);
                    }
                }
                Event::BusOff => {
                    self.bus_off = true;
                    return Err(CanError::BusOff);
                }
                Event::Bad(e) => return Err(e),
                Event::Ignore => {}
            }
        }
    }

    fn send_command(
        &mut self,
        current_a: f64,
        answers_seq: u64,
        enable: bool,
    ) -> Result<(), CanError> {
        let p = CommandPayload {
            current_a,
            answers_seq: self.base_raw.wrapping_add(answers_seq),
            enable,
        };
        let data = self.cfg.command.encode(&p);
        let frame = self
            .cfg
            .raw_frame(self.cfg.command_id(), &data[..self.cfg.command.len()]);
        let timeout = if self.timeout_ns > 0 {
            self.timeout_ns
        } else {
            self.cfg.sample_timeout_ns(1_000_000)
        };
        send_until(self.fd(), &frame, monotonic_ns() + timeout)?;
        self.stats.commands_sent += 1;
        Ok(())
    }

    /// A bounded wait for non-real-time steps (configure, enable).
    fn setup_wait_ns(&self) -> u64 {
        (10 * self.timeout_ns).max(LINK_WAIT_MIN_NS)
    }
}

impl Stage for CanStage {
    type Error = CanError;

    /// Sends a disable (0 A, enable bit clear), then waits (bounded) for one
    /// sample to check that the device answers. Returns the configured
    /// ratings and the clock (see the module docs).
    fn configure(&mut self, period_ns: u64) -> Result<DeviceInfo, CanError> {
        if !(10_000..=1_000_000_000).contains(&period_ns) {
            return Err(CanError::Period {
                period_ns,
                reason: "must be between 10 µs and 1 s",
            });
        }
        let timeout_ns = self.cfg.sample_timeout_ns(period_ns);
        if !self.cfg.sync_producer && timeout_ns <= period_ns {
            return Err(CanError::Period {
                period_ns,
                reason: "backend.can.sample_timeout_ms must exceed the period when the device clocks the loop",
            });
        }
        self.configured = false;
        self.enabled = false;
        self.bus_off = false;
        self.period_ns = period_ns;
        self.timeout_ns = timeout_ns;
        self.last_raw = None;
        self.base_raw = 0;
        self.seq = 0;
        self.last_fault_code = 0;
        self.send_command(0.0, 0, false)?;
        let wait = self.setup_wait_ns();
        let deadline = monotonic_ns() + wait;
        loop {
            match self.next_sample(self.timeout_ns) {
                Ok(_) => break,
                Err(CanError::BusOff) => return Err(CanError::BusOff),
                Err(e @ CanError::Io { .. }) => return Err(e),
                Err(_) if monotonic_ns() < deadline => {}
                Err(_) => {
                    return Err(CanError::NoDevice {
                        interface: self.cfg.interface.clone(),
                        node_id: self.cfg.node_id,
                        sample_id: self.cfg.sample_id(),
                        waited_ms: wait / 1_000_000,
                    })
                }
            }
        }
        self.configured = true;
        Ok(DeviceInfo {
            name: format!("socketcan:{} node {}", self.cfg.interface, self.cfg.node_id),
            clock: if self.cfg.sync_producer {
                Clock::Host
            } else {
                Clock::Device {
                    rate_hz: 1e9 / period_ns as f64,
                }
            },
            period_ns,
            peak_current_a: self.cfg.peak_current_a,
            continuous_current_a: self.cfg.continuous_current_a,
            probe_range_m: self.cfg.probe_range_m,
            probe_lsb_m: self.cfg.sample.position.scale.abs(),
            watchdog_s: None,
        })
    }

    /// Sends an enable edge (bit 0 then 1, 0 A) and waits (bounded) for a
    /// sample showing the amplifier enabled.
    ///
    /// # Errors
    /// `AmplifierFault` ([`CanError::DeviceFault`]) if no sample shows it
    /// enabled in time.
    fn enable(&mut self) -> Result<(), CanError> {
        if !self.configured {
            return Err(LifecycleError::NotConfigured.into());
        }
        if self.bus_off {
            return Err(CanError::BusOff);
        }
        self.send_command(0.0, self.seq, false)?;
        self.send_command(0.0, self.seq, true)?;
        let deadline = monotonic_ns() + self.setup_wait_ns();
        loop {
            match self.next_sample(self.timeout_ns) {
                Ok(s) if s.flags.amplifier_enabled && !s.flags.amplifier_fault => {
                    self.enabled = true;
                    return Ok(());
                }
                Ok(s) => {
                    // Keep the watchdog fed while the device comes up.
                    self.send_command(0.0, s.seq, true)?;
                }
                Err(CanError::BusOff) => return Err(CanError::BusOff),
                Err(e @ CanError::Io { .. }) => return Err(e),
                Err(_) => {}
            }
            if monotonic_ns() >= deadline {
                let _ = self.send_command(0.0, self.seq, false);
                return Err(CanError::DeviceFault {
                    code: self.last_fault_code,
                });
            }
        }
    }

    fn read_sample(&mut self) -> Result<Sample, CanError> {
        if !self.configured {
            return Err(LifecycleError::NotConfigured.into());
        }
        let s = self.next_sample(self.timeout_ns)?;
        self.stats.samples += 1;
        if self.enabled && s.flags.amplifier_fault {
            self.enabled = false;
            return Err(CanError::DeviceFault {
                code: self.last_fault_code,
            });
        }
        Ok(s)
    }

    fn write_command(&mut self, command: Command) -> Result<(), CanError> {
        let i = command.current_a;
        if let Err(e) = LifecycleError::check_command(self.configured, self.enabled, i) {
            if matches!(e, LifecycleError::NotFinite { .. }) {
                let _ = self.send_command(0.0, command.answers_seq, self.enabled);
            }
            return Err(e.into());
        }
        if self.bus_off {
            return Err(CanError::BusOff);
        }
        self.send_command(i, command.answers_seq, self.enabled)
    }

    /// Sends 0 A with the enable bit clear (bounded wait for the transmit
    /// queue). Works in any state, idempotent.
    fn disable(&mut self) -> Result<(), CanError> {
        self.enabled = false;
        self.send_command(0.0, self.seq, false)
    }
}

impl Drop for CanStage {
    fn drop(&mut self) {
        let _ = self.disable();
    }
}
