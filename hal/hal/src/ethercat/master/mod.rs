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
use super::rack::RackLayout;
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

mod bringup;
mod exchange;
mod group;
mod link;

use bringup::step_in;
use group::{on_group, Running};
use link::{take_parts, Link, Parts, POOL};

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
    /// The deadline of one round trip in force when the counters were
    /// read, ns ([`EthercatStage::exchange_timeout_ns`]): a setting, not a
    /// counter.
    pub exchange_timeout_ns: u64,
}

/// The EtherCAT stage (host side): one CiA 402 drive in cyclic synchronous
/// torque mode, or analog terminals (one slave, or a rack of them:
/// `[[backend.ethercat.slaves]]`), brought up to SAFE-OP by
/// [`Stage::configure`] and to OP and OPERATION ENABLED (the enable
/// output) by [`Stage::enable`]; one process-data exchange per tick (see
/// the [module docs](super)).
pub struct EthercatStage {
    cfg: EthercatConfig,
    layout: ImageLayout,
    /// The rack's signals (`None`: the single device).
    rack: Option<RackLayout>,
    /// The group's working counter expected in SAFE-OP and in OP.
    wkc: (u16, u16),
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
        let rack = cfg.rack("backend.ethercat")?;
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
            rack,
            wkc: (1, 3),
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
        EthercatStats {
            exchange_timeout_ns: self.timeout_ns,
            ..self.stats
        }
    }

    /// Tells the stage how long the loop's supervisor tolerates going
    /// without a fresh sample, s (its stall bound; infinite: none): the
    /// default exchange deadline follows it
    /// ([`EthercatConfig::exchange_timeout_ns`]). Applies at once if
    /// configured, else at [`Stage::configure`]. Arithmetic only (no
    /// allocation, no call into the link): the daemon's loop calls it
    /// between jobs.
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
            name: match self.rack {
                Some(r) => format!(
                    "ethercat:{} analog rack of {} slaves",
                    self.cfg.interface, r.slaves
                ),
                None => format!(
                    "ethercat:{} {} 0x{:08X}:0x{:08X}",
                    self.cfg.interface,
                    self.cfg.profile.as_str(),
                    self.cfg.vendor_id,
                    self.cfg.expected_product_id()
                ),
            },
            clock: Clock::Host,
            period_ns,
            peak_current_a: self.cfg.peak_current_a,
            continuous_current_a: self.cfg.continuous_current_a,
            probe_range_m: self.cfg.probe_range_m,
            probe_lsb_m: if self.analog() {
                self.cfg.adc_full_scale_m / 32767.0
            } else {
                self.cfg.position_lsb_m
            },
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
                let g = step_in(&mut self.link, &self.cfg, g.into_op(md), deadline, step)?;
                self.group = Some(Running::Op(g));
            }
            Some(Running::SafeOpDc(g)) => {
                let g = step_in(&mut self.link, &self.cfg, g.into_op(md), deadline, step)?;
                self.group = Some(Running::OpDc(g));
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
