//! The host side: [`EthercatStage`], the EtherCAT [`Stage`] backend on
//! `ethercrab`, with its own single-thread driver of ethercrab's PDU loop
//! ([`Link::block_on`]): the future is polled, the frames it queues are
//! sent on the raw socket and the answers fed back, all on the calling
//! thread with a deadline. No TX/RX thread, no executor, no timer thread in
//! the cyclic exchange: ethercrab's PDU timeout is set to never
//! (`Duration::MAX`, so `async_io` registers no timer) and the deadline is
//! ours.
//!
//! No lock either. What the tick runs through ethercrab 0.7.1, read in its
//! source: `SubDeviceGroup::tx_rx` / `tx_rx_dc` take the process image's
//! write guard (here [`BorrowFlag`]: one atomic, never waits);
//! `PduLoop::alloc_frame` claims a storage slot by atomic
//! compare-exchange over at most twice the slots, no retry loop;
//! `wake_sender` and the frame future's waker are `atomic_waker`
//! (compare-exchange, no spin; the waker is `Waker::noop`);
//! `ReceiveFrameFut::poll` swaps the slot's atomic state and polls a
//! never-firing `async_io::Timer` (no reactor); `PduRx::receive_frame`
//! and `SendableFrame::send_blocking` are atomics and copies; `log`
//! macros read one atomic level (muted). Every `thread::yield_now` and
//! `futures_lite::yield_now` in ethercrab's PDU loop is in its tests; the
//! only other yields (`subdevice_group` ~1409/1624, `timer_factory` 142)
//! are in tests and in `loop_tick` for bring-up. The test
//! `the_ticks_make_no_futex_or_sched_yield_call` traces the loop thread.

use super::config::{EthercatConfig, ImageLayout, MAX_PDO_BYTES};
use super::image_lock::BorrowFlag;
use super::socket::RawSocket;
use super::wire::cia402::*;
use super::EthercatError;
use crate::os::monotonic_ns;
use crate::{Clock, Command, DeviceInfo, LifecycleError, Sample, SampleFlags, Stage};
use core::future::Future;
use core::pin::pin;
use core::task::{Context, Poll, Waker};
use ethercrab::subdevice_group::{DcConfiguration, HasDc, NoDc, Op, PreOp, SafeOp};
use ethercrab::{
    Command as EcCommand, MainDevice, MainDeviceConfig, PduLoop, PduRx, PduStorage, PduTx,
    RegisterAddress, SubDevice, SubDeviceGroup, SubDeviceGroupHandle, SubDeviceState, Timeouts,
};
use std::sync::Mutex;
use std::time::Duration;

/// Frames in flight (ethercrab's PDU storage slots).
const FRAMES: usize = 4;
/// Largest PDU payload of one frame, bytes.
const PDU_DATA: usize = PduStorage::element_size(256);
/// The group's process image, bytes (both directions).
const MAX_PDI: usize = 2 * MAX_PDO_BYTES;

static STORAGE: PduStorage<FRAMES, PDU_DATA> = PduStorage::new();

/// ethercrab's PDU loop parts: split once per process, handed back when a
/// stage is dropped so the next one reuses them.
struct Parts {
    tx: PduTx<'static>,
    rx: PduRx<'static>,
    pdu_loop: PduLoop<'static>,
}

static POOL: Mutex<Option<Parts>> = Mutex::new(None);

fn take_parts() -> Result<Parts, EthercatError> {
    let mut pool = POOL.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(p) = pool.take() {
        return Ok(p);
    }
    let (tx, rx, pdu_loop) = STORAGE.try_split().map_err(|()| EthercatError::Busy)?;
    Ok(Parts { tx, rx, pdu_loop })
}

/// The raw socket and ethercrab's TX/RX ends, driven on the caller's
/// thread.
struct Link {
    sock: RawSocket,
    /// Handed back to the pool on drop.
    ends: Option<(PduTx<'static>, PduRx<'static>)>,
    buf: [u8; 1600],
}

/// Why [`Link::block_on`] gave up.
#[derive(Debug)]
enum Stall {
    Deadline,
    Io(std::io::Error),
}

impl Link {
    /// Polls `fut` to completion, sending the frames it queues and feeding
    /// back the answers, until `deadline_ns`; when nothing arrives it
    /// sleeps on the socket at most `step_ns` before polling again (the
    /// futures' own timers are polled, not woken). Dropping the future on
    /// the deadline releases its frame. Allocates nothing.
    fn block_on<F: Future>(
        &mut self,
        fut: F,
        deadline_ns: u64,
        step_ns: u64,
    ) -> Result<F::Output, Stall> {
        let mut fut = pin!(fut);
        let mut cx = Context::from_waker(Waker::noop());
        let Some((tx, rx)) = self.ends.as_mut() else {
            return Err(Stall::Io(std::io::Error::from_raw_os_error(libc::EBADF)));
        };
        loop {
            if let Poll::Ready(v) = fut.as_mut().poll(&mut cx) {
                return Ok(v);
            }
            while let Some(frame) = tx.next_sendable_frame() {
                let sock = &self.sock;
                let mut os_err = None;
                let r = frame.send_blocking(|d| match sock.send(d) {
                    Ok(n) => Ok(n),
                    Err(e) => {
                        os_err = Some(e);
                        Err(ethercrab::error::Error::SendFrame)
                    }
                });
                if r.is_err() {
                    return Err(Stall::Io(
                        os_err.unwrap_or_else(|| std::io::Error::from_raw_os_error(libc::EIO)),
                    ));
                }
            }
            let mut got = false;
            while let Some(n) = self.sock.try_recv(&mut self.buf).map_err(Stall::Io)? {
                // Frames that are not answers to ours are ignored.
                let _ = rx.receive_frame(&self.buf[..n]);
                got = true;
            }
            if got {
                continue;
            }
            let now = monotonic_ns();
            if now >= deadline_ns {
                return Err(Stall::Deadline);
            }
            self.sock
                .wait(deadline_ns.min(now.saturating_add(step_ns)))
                .map_err(Stall::Io)?;
        }
    }
}

/// The group, its process image behind [`BorrowFlag`] (never waits), not
/// ethercrab's default spin lock (which yields when contended).
type Group<S, D = NoDc> = SubDeviceGroup<2, MAX_PDI, BorrowFlag, S, D>;

/// `MainDevice::init`'s group filter: every slave into the one group.
fn the_group<'g>(
    g: &'g Group<PreOp>,
    _: &SubDevice,
) -> Result<&'g dyn SubDeviceGroupHandle, ethercrab::error::Error> {
    Ok(g)
}

/// The group in its AL state: SAFE-OP while disabled (inputs valid, the
/// outputs and the SM watchdog not in force), OP while enabled.
enum Running {
    SafeOp(Group<SafeOp>),
    Op(Group<Op>),
    /// With distributed clocks (SYNC0 at the loop period).
    SafeOpDc(Group<SafeOp, HasDc>),
    /// With distributed clocks.
    OpDc(Group<Op, HasDc>),
}

impl Running {
    fn is_op(&self) -> bool {
        matches!(self, Self::Op(_) | Self::OpDc(_))
    }
}

/// Applies `$body` to the group of any variant of a `Running`.
macro_rules! on_group {
    ($r:expr, $g:ident => $body:expr) => {
        match $r {
            Running::SafeOp($g) => $body,
            Running::Op($g) => $body,
            Running::SafeOpDc($g) => $body,
            Running::OpDc($g) => $body,
        }
    };
}

/// Link counters of an [`EthercatStage`] (since it was opened).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct EthercatStats {
    /// Process-data round trips completed.
    pub exchanges: u64,
    /// Frames not back within the exchange timeout.
    pub lost_frames: u64,
    /// Frames back with a wrong working counter.
    pub wkc_errors: u64,
    /// Exchanges that found the slave out of its expected AL state.
    pub state_errors: u64,
    /// Largest round trip, ns.
    pub max_round_trip_ns: u64,
    /// Largest change of the distributed clock's offset to the host's
    /// clock seen within a one-second window, ns (0 without DC).
    pub max_dc_offset_change_ns: u64,
}

/// The EtherCAT stage (host side): one CiA 402 drive in cyclic synchronous
/// torque mode, brought up to SAFE-OP by [`Stage::configure`] and to OP
/// and OPERATION ENABLED by [`Stage::enable`]; one process-data exchange
/// per tick (see the [module docs](super)).
pub struct EthercatStage {
    cfg: EthercatConfig,
    layout: ImageLayout,
    link: Link,
    md: Option<MainDevice<'static>>,
    group: Option<Running>,
    period_ns: u64,
    timeout_ns: u64,
    /// The loop's stall tolerance, ns (`None`: none given).
    stall_bound_ns: Option<u64>,
    configured: bool,
    enabled: bool,
    fresh: bool,
    seq: u64,
    out: [u8; MAX_PDO_BYTES],
    inp: [u8; MAX_PDO_BYTES],
    controlword: u16,
    rated_current_a: f64,
    /// The `log` level before the stage muted ethercrab (restored on drop).
    log_level: log::LevelFilter,
    /// DC offset to the host clock, bounds [a, b] ns, and when taken.
    dc_base: Option<(i128, i128, u64)>,
    stats: EthercatStats,
}

impl core::fmt::Debug for EthercatStage {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("EthercatStage")
            .field("interface", &self.cfg.interface)
            .field("configured", &self.configured)
            .field("enabled", &self.enabled)
            .field("stats", &self.stats)
            .finish()
    }
}

fn entry_i64(b: &[u8], at: usize, wide: bool) -> i64 {
    if wide {
        i64::from(i32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]))
    } else {
        i64::from(i16::from_le_bytes([b[at], b[at + 1]]))
    }
}

impl EthercatStage {
    /// Checks `cfg` and opens its interface (nothing is sent yet).
    ///
    /// # Errors
    /// `Config` for an invalid `cfg` (naming the key), `NotFound` for a
    /// missing interface, `Busy` without `CAP_NET_RAW` or when another
    /// EtherCAT master is open in this process.
    pub fn open(cfg: &EthercatConfig) -> Result<Self, EthercatError> {
        let layout = cfg.layout("backend.ethercat")?;
        cfg.validate("backend.ethercat")?;
        let sock = RawSocket::open(&cfg.interface)?;
        let parts = take_parts()?;
        // ethercrab reports through the `log` crate, also from the PDU
        // loop the tick drives (a late answer to an abandoned frame): the
        // tick must not log, and every failure comes back as an error
        // here. Muted while the stage is open.
        let log_level = log::max_level();
        log::set_max_level(log::LevelFilter::Off);
        let timeouts = Timeouts {
            // Never: the deadline of every exchange is ours (no timer).
            pdu: Duration::MAX,
            state_transition: Duration::from_secs_f64(cfg.bringup_timeout_ms * 1e-3),
            eeprom: Duration::from_millis(100),
            wait_loop_delay: Duration::ZERO,
            mailbox_echo: Duration::from_millis(200),
            mailbox_response: Duration::from_millis(1000),
        };
        let md = MainDevice::new(
            parts.pdu_loop,
            timeouts,
            MainDeviceConfig {
                dc_static_sync_iterations: if cfg.distributed_clocks { 100 } else { 0 },
                ..MainDeviceConfig::default()
            },
        );
        Ok(Self {
            cfg: cfg.clone(),
            layout,
            link: Link {
                sock,
                ends: Some((parts.tx, parts.rx)),
                buf: [0; 1600],
            },
            md: Some(md),
            group: None,
            period_ns: 0,
            timeout_ns: 0,
            stall_bound_ns: None,
            configured: false,
            enabled: false,
            fresh: false,
            seq: 0,
            out: [0; MAX_PDO_BYTES],
            inp: [0; MAX_PDO_BYTES],
            controlword: CW_DISABLE_VOLTAGE,
            rated_current_a: cfg.continuous_current_a,
            log_level,
            dc_base: None,
            stats: EthercatStats::default(),
        })
    }

    /// The link counters.
    pub fn stats(&self) -> EthercatStats {
        self.stats
    }

    /// Tells the stage how long the loop's supervisor tolerates going
    /// without a fresh sample, s (its stall bound; infinite: none): the
    /// default exchange deadline follows it
    /// ([`EthercatConfig::exchange_timeout_ns`]). Applies at once if
    /// configured, else at [`Stage::configure`]. Not real-time: call it
    /// before the loop runs.
    pub fn set_stall_bound_s(&mut self, stall_bound_s: f64) {
        self.stall_bound_ns = (stall_bound_s.is_finite() && stall_bound_s >= 0.0)
            .then_some((stall_bound_s * 1e9) as u64);
        if self.period_ns > 0 {
            self.timeout_ns = self
                .cfg
                .exchange_timeout_ns(self.period_ns, self.stall_bound_ns);
        }
    }

    /// The deadline of one process-data exchange in force, ns (0 before
    /// [`Stage::configure`]).
    pub fn exchange_timeout_ns(&self) -> u64 {
        self.timeout_ns
    }

    /// The configuration in force.
    pub fn config(&self) -> &EthercatConfig {
        &self.cfg
    }

    /// The statusword of the latest exchange (analog profile: the status
    /// input, 0 when not mapped).
    pub fn statusword(&self) -> u16 {
        let at = self.layout.statusword;
        if self.analog() {
            return if at == usize::MAX {
                0
            } else {
                u16::from(self.inp[at])
            };
        }
        u16::from_le_bytes([self.inp[at], self.inp[at + 1]])
    }

    fn analog(&self) -> bool {
        self.cfg.profile == super::config::Profile::Analog
    }

    /// The amplifier is enabled and not faulted, as its status says
    /// (analog without a status input: as commanded).
    fn status_ok(&self) -> bool {
        let sw = self.statusword();
        if self.analog() {
            self.layout.statusword == usize::MAX || sw & 0x03 == 0x01
        } else {
            sw & SW_FAULT == 0 && sw & STATE_MASK == 0x27
        }
    }

    /// INIT → PRE-OP → (PDO map, mode, watchdog) → SAFE-OP.
    fn bring_up(&mut self, period_ns: u64) -> Result<Running, EthercatError> {
        let start = monotonic_ns();
        let deadline = start + (self.cfg.bringup_timeout_ms * 1e6) as u64;
        // 1. Is anyone there? A broadcast read comes back only through a
        //    slave.
        let probe_ns = 500_000_000u64.min(deadline - start);
        let md = self
            .md
            .as_ref()
            .expect("the main device lives as long as the stage");
        let probe = EcCommand::brd(RegisterAddress::Type.into())
            .ignore_wkc()
            .receive::<u8>(md);
        match self.link.block_on(probe, start + probe_ns, 1_000_000) {
            Ok(Ok(_)) => {}
            Ok(Err(e)) => return Err(bringup_err(&self.cfg, "probing the segment", e)),
            Err(Stall::Io(source)) => {
                return Err(EthercatError::Io {
                    op: "send/recv",
                    source,
                })
            }
            Err(Stall::Deadline) => {
                return Err(EthercatError::NoSlave {
                    interface: self.cfg.interface.clone(),
                    waited_ms: probe_ns / 1_000_000,
                })
            }
        }
        // 2. INIT → PRE-OP: addresses, SII, mailboxes.
        let group: Group<PreOp> = run_in(
            &mut self.link,
            &self.cfg,
            md.init::<2, _>(
                ethercrab::std::ethercat_now,
                Group::<PreOp>::default(),
                the_group,
            ),
            deadline,
            "bringing the slave to PRE-OP",
        )?
        .map_err(|e| bringup_err(&self.cfg, "bringing the slave to PRE-OP", e))?;
        let n = md.num_subdevices();
        if n != 1 {
            return Err(EthercatError::SlaveCount {
                interface: self.cfg.interface.clone(),
                found: n as u16,
            });
        }
        // 3. Identity.
        let id = group
            .subdevice(md, 0)
            .map_err(|e| bringup_err(&self.cfg, "reading the identity", e))?
            .identity();
        if id.vendor_id != self.cfg.vendor_id {
            return Err(EthercatError::Identity {
                key: "backend.ethercat.vendor_id",
                interface: self.cfg.interface.clone(),
                what: "vendor id",
                found: id.vendor_id,
                expected: self.cfg.vendor_id,
            });
        }
        if id.product_id != self.cfg.expected_product_id() {
            return Err(EthercatError::Identity {
                key: "backend.ethercat.product_id",
                interface: self.cfg.interface.clone(),
                what: "product code",
                found: id.product_id,
                expected: self.cfg.expected_product_id(),
            });
        }
        // 4. PDO map, mode, SM watchdog (PRE-OP, over CoE).
        for (dir, assign, pdo, entries) in [
            ("rx_pdo", 0x1C12u16, 0x1600u16, self.cfg.rx_entries()),
            ("tx_pdo", 0x1C13, 0x1A00, self.cfg.tx_entries()),
        ] {
            let key = |i: Option<usize>| match i {
                Some(i) => format!("backend.ethercat.{dir}[{i}]"),
                None => format!("backend.ethercat.{dir}"),
            };
            sdo_in(
                &mut self.link,
                &self.cfg,
                &group,
                md,
                assign,
                0,
                0u8,
                key(None),
                deadline,
            )?;
            sdo_in(
                &mut self.link,
                &self.cfg,
                &group,
                md,
                pdo,
                0,
                0u8,
                key(None),
                deadline,
            )?;
            for (i, e) in entries.iter().enumerate() {
                sdo_in(
                    &mut self.link,
                    &self.cfg,
                    &group,
                    md,
                    pdo,
                    i as u8 + 1,
                    e.raw(),
                    key(Some(i)),
                    deadline,
                )?;
            }
            sdo_in(
                &mut self.link,
                &self.cfg,
                &group,
                md,
                pdo,
                0,
                entries.len() as u8,
                key(None),
                deadline,
            )?;
            sdo_in(
                &mut self.link,
                &self.cfg,
                &group,
                md,
                assign,
                1,
                pdo,
                key(None),
                deadline,
            )?;
            sdo_in(
                &mut self.link,
                &self.cfg,
                &group,
                md,
                assign,
                0,
                1u8,
                key(None),
                deadline,
            )?;
        }
        if !self.analog() {
            sdo_in(
                &mut self.link,
                &self.cfg,
                &group,
                md,
                0x6060,
                0,
                MODE_CST,
                "backend.ethercat.profile".into(),
                deadline,
            )?;
        }
        if !self.analog()
            && (!self.layout.target.1 || matches!(self.layout.current, Some((_, false))))
        {
            // Torque / current in ‰ of the motor rated current 0x6075 (mA).
            let sd = group
                .subdevice(md, 0)
                .map_err(|e| bringup_err(&self.cfg, "reading 0x6075", e))?;
            let ma: u32 = run_in(
                &mut self.link,
                &self.cfg,
                sd.sdo_read(0x6075, 0),
                deadline,
                "reading the motor rated current 0x6075",
            )?
            .map_err(|e| bringup_err(&self.cfg, "reading the motor rated current 0x6075", e))?;
            if ma == 0 {
                return Err(EthercatError::Bringup {
                    interface: self.cfg.interface.clone(),
                    step: "reading the motor rated current 0x6075",
                    reason: "the drive reports 0 mA".into(),
                });
            }
            self.rated_current_a = f64::from(ma) * 1e-3;
        }
        // SM watchdog: 100 µs steps ((2498 + 2) × 40 ns).
        let steps = (self.cfg.watchdog_ms * 10.0).round().clamp(1.0, 65535.0) as u16;
        {
            let sd = group
                .subdevice(md, 0)
                .map_err(|e| bringup_err(&self.cfg, "setting the SM watchdog", e))?;
            run_in(
                &mut self.link,
                &self.cfg,
                sd.register_write(0x0400u16, 2498u16),
                deadline,
                "setting the SM watchdog",
            )?
            .map_err(|e| bringup_err(&self.cfg, "setting the SM watchdog divider 0x0400", e))?;
            run_in(
                &mut self.link,
                &self.cfg,
                sd.register_write(0x0420u16, steps),
                deadline,
                "setting the SM watchdog",
            )?
            .map_err(|e| {
                bringup_err(
                    &self.cfg,
                    "setting the SM watchdog time 0x0420 (backend.ethercat.watchdog_ms)",
                    e,
                )
            })?;
        }
        // 5. PRE-OP → SAFE-OP: FMMUs and SMs from the map read back; with
        //    distributed clocks, SYNC0 at the loop period first.
        let step = "bringing the slave to SAFE-OP (the slave checks SM2/SM3 against its PDO map)";
        let running = if self.cfg.distributed_clocks {
            let mut group = group;
            for mut sd in group.iter_mut(md) {
                sd.set_dc_sync(ethercrab::DcSync::Sync0);
            }
            let dc = DcConfiguration {
                start_delay: Duration::from_millis(10),
                sync0_period: Duration::from_nanos(period_ns),
                sync0_shift: Duration::ZERO,
            };
            let sync = "configuring distributed-clock SYNC0 at the loop period";
            // FMMUs and SMs first (the PDI), then SYNC0.
            let group = run_in(
                &mut self.link,
                &self.cfg,
                group.into_pre_op_pdi(md),
                deadline,
                step,
            )?
            .map_err(|e| bringup_err(&self.cfg, step, e))?;
            let g = run_in(
                &mut self.link,
                &self.cfg,
                group.configure_dc_sync(md, dc),
                deadline,
                sync,
            )?
            .map_err(|e| bringup_err(&self.cfg, sync, e))?;
            let g = run_in(
                &mut self.link,
                &self.cfg,
                g.into_safe_op(md),
                deadline,
                step,
            )?
            .map_err(|e| bringup_err(&self.cfg, step, e))?;
            Running::SafeOpDc(g)
        } else {
            let g = run_in(
                &mut self.link,
                &self.cfg,
                group.into_safe_op(md),
                deadline,
                step,
            )?
            .map_err(|e| bringup_err(&self.cfg, step, e))?;
            Running::SafeOp(g)
        };
        let sizes = on_group!(&running, g => g
        .subdevice(md, 0)
        .map(|sd| {
            let io = sd.io_raw();
            (io.outputs().len(), io.inputs().len())
        }))
        .map_err(|e| bringup_err(&self.cfg, "reading the process image", e))?;
        if sizes != (self.layout.out_len, self.layout.in_len) {
            return Err(EthercatError::Bringup {
                interface: self.cfg.interface.clone(),
                step: "checking the process image",
                reason: format!(
                    "the slave maps {} output and {} input bytes, the config {} and {}",
                    sizes.0, sizes.1, self.layout.out_len, self.layout.in_len
                ),
            });
        }
        Ok(running)
    }

    /// One process-data round trip: the outputs `self.out` go out, the
    /// inputs come back into `self.inp`; working counter, AL state and
    /// the drive's fault bit are checked. Real-time safe: no allocation,
    /// no lock (the image's [`BorrowFlag`] is one atomic that never
    /// waits), the wait bounded by the exchange timeout.
    fn exchange(&mut self) -> Result<(), EthercatError> {
        let md = self
            .md
            .as_ref()
            .expect("the main device lives as long as the stage");
        let (out_len, in_len) = (self.layout.out_len, self.layout.in_len);
        let Some(group) = self.group.as_ref() else {
            return Err(LifecycleError::NotConfigured.into());
        };
        let op = group.is_op();
        if op {
            on_group!(group, g => if let Ok(sd) = g.subdevice(md, 0) {
                sd.outputs_raw_mut()[..out_len].copy_from_slice(&self.out[..out_len]);
            });
        }
        let start = monotonic_ns();
        let deadline = start + self.timeout_ns;
        // (working counter, AL state of the slave, DC system time).
        let result = match group {
            Running::SafeOp(g) => self
                .link
                .block_on(g.tx_rx(md), deadline, u64::MAX)
                .map(|r| r.map(|r| (r.working_counter, r.subdevice_states.first().copied(), None))),
            Running::Op(g) => self
                .link
                .block_on(g.tx_rx(md), deadline, u64::MAX)
                .map(|r| r.map(|r| (r.working_counter, r.subdevice_states.first().copied(), None))),
            Running::SafeOpDc(g) => {
                self.link
                    .block_on(g.tx_rx_dc(md), deadline, u64::MAX)
                    .map(|r| {
                        r.map(|r| {
                            let t = Some(r.extra.dc_system_time);
                            (r.working_counter, r.subdevice_states.first().copied(), t)
                        })
                    })
            }
            Running::OpDc(g) => self
                .link
                .block_on(g.tx_rx_dc(md), deadline, u64::MAX)
                .map(|r| {
                    r.map(|r| {
                        let t = Some(r.extra.dc_system_time);
                        (r.working_counter, r.subdevice_states.first().copied(), t)
                    })
                }),
        };
        let end = monotonic_ns();
        on_group!(group, g => if let Ok(sd) = g.subdevice(md, 0) {
            self.inp[..in_len].copy_from_slice(&sd.inputs_raw()[..in_len]);
        });
        let rt = end - start;
        let (working_counter, state, dc_time) = match result {
            Ok(Ok(r)) => r,
            Ok(Err(e)) => return Err(EthercatError::Exchange(e)),
            Err(Stall::Deadline) => {
                self.stats.lost_frames += 1;
                return Err(EthercatError::Timeout { waited_ns: rt });
            }
            Err(Stall::Io(source)) => {
                return Err(EthercatError::Io {
                    op: "send/recv",
                    source,
                })
            }
        };
        self.stats.max_round_trip_ns = self.stats.max_round_trip_ns.max(rt);
        let want = if op {
            SubDeviceState::Op
        } else {
            SubDeviceState::SafeOp
        };
        let state = state.unwrap_or(SubDeviceState::None);
        if state != want {
            self.stats.state_errors += 1;
            return Err(EthercatError::NotOp {
                state: u8::from(state),
            });
        }
        // Inputs read +1, outputs written +2 (ETG.1000.4 §5.4.3.4).
        let expected = if op { 3 } else { 1 };
        if working_counter != expected {
            self.stats.wkc_errors += 1;
            return Err(EthercatError::WorkingCounter {
                expected,
                got: working_counter,
            });
        }
        if let Some(t) = dc_time {
            self.check_dc(t, start, end)?;
        }
        self.stats.exchanges += 1;
        self.seq += 1;
        self.fresh = true;
        if self.enabled && !self.status_ok() {
            self.enabled = false;
            return Err(EthercatError::DriveFault {
                statusword: self.statusword(),
            });
        }
        Ok(())
    }

    /// The distributed clock against the host's: the slave's system time
    /// `t` was read while the frame passed it, between `sent` and `back`
    /// (host `CLOCK_MONOTONIC`), so its offset to the host clock lies in
    /// [t − back, t − sent] whatever the round trip. Within each one-second
    /// window that offset may move by at most `dc_drift_max_ppm` × 1 s
    /// beyond those bounds; more is [`EthercatError::DcDrift`].
    fn check_dc(&mut self, t: u64, sent: u64, back: u64) -> Result<(), EthercatError> {
        let a = i128::from(t) - i128::from(back);
        let b = i128::from(t) - i128::from(sent);
        let bound = (self.cfg.dc_drift_max_ppm * 1e3) as i128;
        match self.dc_base {
            Some((a0, b0, since)) => {
                let moved = if a > b0 {
                    a - b0
                } else if b < a0 {
                    a0 - b
                } else {
                    0
                };
                self.stats.max_dc_offset_change_ns =
                    self.stats.max_dc_offset_change_ns.max(moved as u64);
                if moved > bound {
                    self.dc_base = None;
                    return Err(EthercatError::DcDrift {
                        moved_ns: moved as u64,
                        within_ns: sent - since,
                    });
                }
                if sent - since > 1_000_000_000 {
                    self.dc_base = Some((a, b, sent));
                }
            }
            None => self.dc_base = Some((a, b, sent)),
        }
        Ok(())
    }

    fn set_outputs(&mut self, controlword: u16, current_a: f64) {
        self.controlword = controlword;
        let l = self.layout;
        let (at, micro) = l.target;
        if self.analog() {
            // Enable output bit 0; DAC ±32767 = ± dac_full_scale_a.
            self.out[l.controlword] = u8::from(controlword & 1 != 0);
            let v = (current_a / self.cfg.dac_full_scale_a * 32767.0)
                .round()
                .clamp(-32767.0, 32767.0) as i16;
            self.out[at..at + 2].copy_from_slice(&v.to_le_bytes());
            return;
        }
        self.out[l.controlword..l.controlword + 2].copy_from_slice(&controlword.to_le_bytes());
        if micro {
            let v = (current_a * 1e6).round().clamp(-2.0e9, 2.0e9) as i32;
            self.out[at..at + 4].copy_from_slice(&v.to_le_bytes());
        } else {
            let v = (current_a / self.rated_current_a * 1e3)
                .round()
                .clamp(-32767.0, 32767.0) as i16;
            self.out[at..at + 2].copy_from_slice(&v.to_le_bytes());
        }
    }

    fn sample(&self) -> Sample {
        let l = self.layout;
        let sw = self.statusword();
        let (position_m, out_of_range, enabled, fault) = if self.analog() {
            let v = entry_i64(&self.inp, l.position, false);
            let known = l.statusword != usize::MAX;
            (
                v as f64 / 32767.0 * self.cfg.adc_full_scale_m,
                v.abs() >= 32767,
                if known { sw & 1 != 0 } else { self.enabled },
                known && sw & 2 != 0,
            )
        } else {
            let x = entry_i64(&self.inp, l.position, true) as f64 * self.cfg.position_lsb_m;
            (
                x,
                x.abs() > self.cfg.probe_range_m,
                sw & STATE_MASK == 0x27,
                sw & SW_FAULT != 0,
            )
        };
        let measured_current_a = match l.current {
            Some((at, true)) => entry_i64(&self.inp, at, true) as f64 * 1e-6,
            Some((at, false)) => {
                entry_i64(&self.inp, at, false) as f64 * 1e-3 * self.rated_current_a
            }
            None => f64::NAN,
        };
        Sample {
            seq: self.seq - 1,
            device_time_ns: (self.seq - 1).saturating_mul(self.period_ns),
            position_m,
            measured_current_a,
            flags: SampleFlags {
                out_of_range,
                amplifier_enabled: enabled,
                amplifier_fault: fault,
                command_late: false,
            },
        }
    }

    /// Runs exchanges with `controlword` until the statusword satisfies
    /// `done` or `deadline_ns`.
    fn drive_to(
        &mut self,
        controlword: u16,
        done: impl Fn(u16) -> bool,
        deadline_ns: u64,
    ) -> Result<bool, EthercatError> {
        loop {
            self.set_outputs(controlword, 0.0);
            match self.exchange() {
                Ok(()) => {}
                Err(EthercatError::Timeout { .. }) if monotonic_ns() < deadline_ns => continue,
                Err(e) => return Err(e),
            }
            if done(self.statusword()) {
                return Ok(true);
            }
            if monotonic_ns() >= deadline_ns {
                return Ok(false);
            }
        }
    }

    /// Acknowledges a slave error and requests SAFE-OP (AL control
    /// 0x0014: ETG.1000.6 §5.3.2, an error must be acknowledged before the
    /// slave goes up again), then waits for SAFE-OP.
    fn back_to_safe_op(&mut self) -> Result<(), EthercatError> {
        let md = self
            .md
            .as_ref()
            .expect("the main device lives as long as the stage");
        let deadline = monotonic_ns() + (self.cfg.bringup_timeout_ms * 1e6) as u64;
        let step = "acknowledging the slave's AL status";
        let sd = match self.group.as_ref() {
            Some(r) => on_group!(r, g => g.subdevice(md, 0).map(|sd| sd.configured_address())),
            None => return Ok(()),
        }
        .map_err(|e| bringup_err(&self.cfg, step, e))?;
        run_in(
            &mut self.link,
            &self.cfg,
            EcCommand::fpwr(sd, RegisterAddress::AlControl.into()).send(md, 0x0014u16),
            deadline,
            step,
        )?
        .map_err(|e| bringup_err(&self.cfg, step, e))?;
        let step = "bringing the slave back to SAFE-OP";
        match self.group.take() {
            Some(Running::Op(g)) => {
                let g = run_in(
                    &mut self.link,
                    &self.cfg,
                    g.into_safe_op(md),
                    deadline,
                    step,
                )?
                .map_err(|e| bringup_err(&self.cfg, step, e))?;
                self.group = Some(Running::SafeOp(g));
            }
            Some(Running::OpDc(g)) => {
                let g = run_in(
                    &mut self.link,
                    &self.cfg,
                    g.into_safe_op(md),
                    deadline,
                    step,
                )?
                .map_err(|e| bringup_err(&self.cfg, step, e))?;
                self.group = Some(Running::SafeOpDc(g));
            }
            other => self.group = other,
        }
        Ok(())
    }
}

/// One expedited SDO download during bring-up; an abort names `key`.
#[allow(clippy::too_many_arguments)]
fn sdo_in<T: ethercrab::EtherCrabWireWrite + Copy + Into<i64>>(
    link: &mut Link,
    cfg: &EthercatConfig,
    group: &Group<PreOp>,
    md: &MainDevice<'static>,
    index: u16,
    subindex: u8,
    value: T,
    key: String,
    deadline: u64,
) -> Result<(), EthercatError> {
    let step = "writing the object dictionary";
    let sd = group
        .subdevice(md, 0)
        .map_err(|e| bringup_err(cfg, step, e))?;
    match run_in(
        link,
        cfg,
        sd.sdo_write(index, subindex, value),
        deadline,
        step,
    )? {
        Ok(()) => Ok(()),
        Err(e) => Err(EthercatError::Refused {
            key,
            index,
            subindex,
            value: value.into() as u32,
            reason: e.to_string(),
        }),
    }
}

fn bringup_err(
    cfg: &EthercatConfig,
    step: &'static str,
    e: ethercrab::error::Error,
) -> EthercatError {
    EthercatError::Bringup {
        interface: cfg.interface.clone(),
        step,
        reason: e.to_string(),
    }
}

/// Runs a bring-up future to completion within `deadline_ns`.
fn run_in<F: Future>(
    link: &mut Link,
    cfg: &EthercatConfig,
    fut: F,
    deadline_ns: u64,
    step: &'static str,
) -> Result<F::Output, EthercatError> {
    match link.block_on(fut, deadline_ns, 1_000_000) {
        Ok(v) => Ok(v),
        Err(Stall::Io(source)) => Err(EthercatError::Io {
            op: "send/recv",
            source,
        }),
        Err(Stall::Deadline) => Err(EthercatError::BringupTimeout {
            interface: cfg.interface.clone(),
            step,
            waited_ms: cfg.bringup_timeout_ms as u64,
        }),
    }
}

impl Stage for EthercatStage {
    type Error = EthercatError;

    /// Brings the slave INIT → PRE-OP (identity checked, PDO map, mode CST,
    /// SM watchdog written over CoE) → SAFE-OP, and reads one sample.
    /// The drive stays disabled (controlword "disable voltage"), 0 A.
    fn configure(&mut self, period_ns: u64) -> Result<DeviceInfo, EthercatError> {
        if !(20_000..=1_000_000_000).contains(&period_ns) {
            return Err(EthercatError::Period {
                period_ns,
                reason: "must be between 20 µs and 1 s",
            });
        }
        let wd_ns = (self.cfg.watchdog_ms * 1e6) as u64;
        if wd_ns < 2 * period_ns {
            return Err(EthercatError::Period {
                period_ns,
                reason: "backend.ethercat.watchdog_ms must be at least two loop periods",
            });
        }
        self.configured = false;
        self.enabled = false;
        self.period_ns = period_ns;
        self.timeout_ns = self.cfg.exchange_timeout_ns(period_ns, self.stall_bound_ns);
        if self.group.is_some() {
            self.back_to_safe_op()?;
        } else {
            let g = self.bring_up(period_ns)?;
            self.group = Some(g);
        }
        self.seq = 0;
        self.dc_base = None;
        self.set_outputs(CW_DISABLE_VOLTAGE, 0.0);
        let deadline = monotonic_ns() + (self.cfg.bringup_timeout_ms * 1e6) as u64;
        loop {
            match self.exchange() {
                Ok(()) => break,
                Err(EthercatError::Timeout { .. }) if monotonic_ns() < deadline => {}
                Err(e) => return Err(e),
            }
        }
        self.configured = true;
        Ok(DeviceInfo {
            name: format!(
                "ethercat:{} {} 0x{:08X}:0x{:08X}",
                self.cfg.interface,
                self.cfg.profile.as_str(),
                self.cfg.vendor_id,
                self.cfg.expected_product_id()
            ),
            clock: Clock::Host,
            period_ns,
            peak_current_a: self.cfg.peak_current_a,
            continuous_current_a: self.cfg.continuous_current_a,
            probe_range_m: self.cfg.probe_range_m,
            watchdog_s: Some(self.cfg.watchdog_ms * 1e-3),
        })
    }

    /// SAFE-OP → OP, then the CiA 402 sequence at 0 A: fault reset (if
    /// faulted), shutdown, switch on, enable operation, each awaited in the
    /// statusword (bounded).
    ///
    /// # Errors
    /// `AmplifierFault` ([`EthercatError::DriveFault`]) if the drive does
    /// not reach OPERATION ENABLED; the drive is then told "disable
    /// voltage" and the slave returned to SAFE-OP.
    fn enable(&mut self) -> Result<(), EthercatError> {
        if !self.configured {
            return Err(LifecycleError::NotConfigured.into());
        }
        // The outputs in force when OP starts: 0 A, disabled.
        self.set_outputs(CW_DISABLE_VOLTAGE, 0.0);
        let md = self
            .md
            .as_ref()
            .expect("the main device lives as long as the stage");
        let deadline = monotonic_ns() + (self.cfg.bringup_timeout_ms * 1e6) as u64;
        let step = "bringing the slave to OP";
        match self.group.take() {
            Some(Running::SafeOp(g)) => {
                match run_in(&mut self.link, &self.cfg, g.into_op(md), deadline, step) {
                    Ok(Ok(g)) => self.group = Some(Running::Op(g)),
                    Ok(Err(e)) => return Err(bringup_err(&self.cfg, step, e)),
                    Err(e) => return Err(e),
                }
            }
            Some(Running::SafeOpDc(g)) => {
                match run_in(&mut self.link, &self.cfg, g.into_op(md), deadline, step) {
                    Ok(Ok(g)) => self.group = Some(Running::OpDc(g)),
                    Ok(Err(e)) => return Err(bringup_err(&self.cfg, step, e)),
                    Err(e) => return Err(e),
                }
            }
            other => self.group = other,
        }
        let deadline = monotonic_ns() + 500_000_000;
        let analog = self.analog();
        let ok = (|| -> Result<bool, EthercatError> {
            if analog {
                // The enable output's rising edge (it clears a latched
                // fault); the status input, if mapped, must say ready.
                self.drive_to(0, |_| true, deadline)?;
                let known = self.layout.statusword != usize::MAX;
                return self.drive_to(1, |st| !known || st & 0x03 == 0x01, deadline);
            }
            if self.statusword() & SW_FAULT != 0 {
                self.drive_to(CW_DISABLE_VOLTAGE, |_| true, deadline)?;
                if !self.drive_to(CW_FAULT_RESET, |sw| sw & SW_FAULT == 0, deadline)? {
                    return Ok(false);
                }
            }
            Ok(
                self.drive_to(CW_SHUTDOWN, |sw| sw & STATE_MASK == 0x21, deadline)?
                    && self.drive_to(CW_SWITCH_ON, |sw| sw & STATE_MASK == 0x23, deadline)?
                    && self.drive_to(
                        CW_ENABLE_OPERATION,
                        |sw| sw & STATE_MASK == 0x27,
                        deadline,
                    )?,
            )
        })();
        match ok {
            Ok(true) => {
                self.enabled = true;
                Ok(())
            }
            Ok(false) => {
                let sw = self.statusword();
                let _ = self.disable();
                Err(EthercatError::DriveFault { statusword: sw })
            }
            Err(e) => {
                let _ = self.disable();
                Err(e)
            }
        }
    }

    /// The sample of the latest exchange; if no exchange happened since the
    /// last read, one now (with the outputs held).
    fn read_sample(&mut self) -> Result<Sample, EthercatError> {
        if !self.configured {
            return Err(LifecycleError::NotConfigured.into());
        }
        if !self.fresh {
            self.exchange()?;
        }
        self.fresh = false;
        let s = self.sample();
        Ok(s)
    }

    /// Sets the target and exchanges the process data: the one round trip
    /// of the tick. The drive applies the target in its next cycle.
    fn write_command(&mut self, command: Command) -> Result<(), EthercatError> {
        let i = command.current_a;
        if let Err(e) = LifecycleError::check_command(self.configured, self.enabled, i) {
            if matches!(e, LifecycleError::NotFinite { .. }) && self.configured {
                let cw = self.controlword;
                self.set_outputs(cw, 0.0);
                let _ = self.exchange();
            }
            return Err(e.into());
        }
        let cw = if self.enabled {
            CW_ENABLE_OPERATION
        } else {
            CW_DISABLE_VOLTAGE
        };
        let peak = self.cfg.peak_current_a;
        self.set_outputs(cw, i.clamp(-peak, peak));
        self.exchange()
    }

    /// The drive's quick stop at 0 A (controlword 0x02: OPERATION ENABLED
    /// → QUICK STOP ACTIVE, the current to 0 at once), then "disable
    /// voltage" (→ SWITCH ON DISABLED), one exchange each, then the slave
    /// back to SAFE-OP (outputs no longer in force). Idempotent; bounded
    /// (each exchange at most max(`exchange_timeout_ms`, 10 ms)).
    fn disable(&mut self) -> Result<(), EthercatError> {
        self.enabled = false;
        if self.group.is_none() {
            return Ok(());
        }
        let r = if self.group.as_ref().is_some_and(Running::is_op) {
            let saved = self.timeout_ns;
            self.timeout_ns = self.timeout_ns.max(10_000_000);
            let mut r = Ok(());
            for cw in [CW_QUICK_STOP, CW_DISABLE_VOLTAGE] {
                self.set_outputs(cw, 0.0);
                if let Err(e) = self.exchange() {
                    r = Err(e);
                }
            }
            self.timeout_ns = saved;
            r
        } else {
            self.set_outputs(CW_DISABLE_VOLTAGE, 0.0);
            Ok(())
        };
        let s = self.back_to_safe_op();
        r.and(s)
    }
}

impl Drop for EthercatStage {
    fn drop(&mut self) {
        let _ = self.disable();
        // The group goes first; then the PDU loop and its ends are handed
        // back for the next stage of this process.
        self.group = None;
        if let (Some(md), Some((tx, rx))) = (self.md.take(), self.link.ends.take()) {
            // SAFETY: every group and future borrowing `md` is gone.
            let pdu_loop = unsafe { md.release() };
            let mut pool = POOL.lock().unwrap_or_else(|e| e.into_inner());
            *pool = Some(Parts { tx, rx, pdu_loop });
        }
        log::set_max_level(self.log_level);
    }
}
