//! Bring-up (INIT → PRE-OP → PDO map, mode, SM watchdog → SAFE-OP) and the
//! way back to SAFE-OP, with the helpers that name the step or the key
//! of a failure.

use super::group::{the_group, Group};
use super::link::Stall;
use super::*;
use crate::ethercat::rack::MAX_RACK;

impl EthercatStage {
    /// INIT → PRE-OP → (PDO map, mode, watchdog) → SAFE-OP.
    pub(super) fn bring_up(&mut self, period_ns: u64) -> Result<Running, EthercatError> {
        let start = monotonic_ns();
        let deadline = start + (self.cfg.bringup_timeout_ms * 1e6) as u64;
        let analog = self.analog();
        let images = self.images();
        let mut b = Bringup {
            link: &mut self.link,
            cfg: &self.cfg,
            md: self
                .md
                .as_ref()
                .expect("the main device lives as long as the stage"),
            rack: self.rack,
            deadline,
        };
        // 1. Is anyone there? A broadcast read comes back only through a
        //    slave.
        b.probe(start)?;
        // 2. INIT → PRE-OP: addresses, SII, mailboxes.
        let group = b.pre_op()?;
        // 3. Identity of each slave; 4. the PDO map of each over CoE.
        b.check_identities(&group)?;
        b.map_pdos(&group)?;
        if !analog {
            sdo_in(
                b.link,
                b.cfg,
                &group,
                b.md,
                0,
                (0x6060, 0),
                Sdo::I8(MODE_CST),
                "backend.ethercat.profile".into(),
                deadline,
            )?;
        }
        if !analog && (!self.layout.target.1 || matches!(self.layout.current, Some((_, false)))) {
            // Torque / current in ‰ of the motor rated current 0x6075 (mA).
            self.rated_current_a = b.rated_current_a(&group)?;
        }
        b.set_sm_watchdogs(&group, &images)?;
        // 5. PRE-OP → SAFE-OP: FMMUs and SMs from the map read back; with
        //    distributed clocks, SYNC0 at the loop period first.
        let running = b.safe_op(group, period_ns)?;
        // Each slave's image as configured; the working counters of the
        // group's LRW (ETG.1000.4 §5.4.3.4: +1 per slave whose inputs are
        // read, +2 per slave whose outputs are written).
        b.check_images(&running, &images)?;
        let reads = images.iter().filter(|(_, i)| *i > 0).count() as u16;
        let writes = images.iter().filter(|(o, _)| *o > 0).count() as u16;
        self.wkc = (reads, reads + 2 * writes);
        Ok(running)
    }

    /// Each slave's image bytes (outputs, inputs) by position, as
    /// configured.
    pub(super) fn images(&self) -> Vec<(usize, usize)> {
        match self.rack {
            Some(r) => r.image[..r.slaves].to_vec(),
            None => vec![(self.layout.out_len, self.layout.in_len)],
        }
    }

    /// Acknowledges a slave error and requests SAFE-OP (AL control
    /// 0x0014: ETG.1000.6 §5.3.2, an error must be acknowledged before the
    /// slave goes up again), then waits for SAFE-OP.
    pub(super) fn back_to_safe_op(&mut self) -> Result<(), EthercatError> {
        let md = self
            .md
            .as_ref()
            .expect("the main device lives as long as the stage");
        let deadline = monotonic_ns() + (self.cfg.bringup_timeout_ms * 1e6) as u64;
        let step = "acknowledging the slave's AL status";
        let n = self.images().len();
        for position in 0..n {
            let sd = match self.group.as_ref() {
                Some(r) => on_group!(r, g => g
                    .subdevice(md, position)
                    .map(|sd| sd.configured_address())),
                None => return Ok(()),
            }
            .map_err(|e| bringup_err(&self.cfg, step, e))?;
            step_in(
                &mut self.link,
                &self.cfg,
                EcCommand::fpwr(sd, RegisterAddress::AlControl.into()).send(md, 0x0014u16),
                deadline,
                step,
            )?;
        }
        let step = "bringing the slave back to SAFE-OP";
        let (link, cfg) = (&mut self.link, &self.cfg);
        match self.group.take() {
            Some(Running::Op(g)) => {
                let g = step_in(link, cfg, g.into_safe_op(md), deadline, step)?;
                self.group = Some(Running::SafeOp(g));
            }
            Some(Running::OpDc(g)) => {
                let g = step_in(link, cfg, g.into_safe_op(md), deadline, step)?;
                self.group = Some(Running::SafeOpDc(g));
            }
            other => self.group = other,
        }
        Ok(())
    }
}

/// What the steps of [`EthercatStage::bring_up`] share: the link they
/// drive, the config their errors name, the main device, the rack
/// (`None`: the single device) and the deadline of the whole bring-up.
struct Bringup<'a> {
    link: &'a mut Link,
    cfg: &'a EthercatConfig,
    md: &'a MainDevice<'static>,
    rack: Option<RackLayout>,
    deadline: u64,
}

impl Bringup<'_> {
    /// Probes the segment with a broadcast read of the ESC type register
    /// (working counter ignored), for at most 0.5 s of the bring-up's
    /// time: `NoSlave` when nothing comes back.
    fn probe(&mut self, start: u64) -> Result<(), EthercatError> {
        let probe_ns = 500_000_000u64.min(self.deadline - start);
        let probe = EcCommand::brd(RegisterAddress::Type.into())
            .ignore_wkc()
            .receive::<u8>(self.md);
        match self.link.block_on(probe, start + probe_ns, 1_000_000) {
            Ok(Ok(_)) => {}
            Ok(Err(e)) => return Err(bringup_err(self.cfg, "probing the segment", e)),
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
        Ok(())
    }

    /// INIT → PRE-OP: ethercrab assigns the station addresses, reads each
    /// slave's SII (EEPROM) and sets up the mailboxes, every slave in the
    /// one group; then the slaves found are counted against the config
    /// (one, or the rack's).
    fn pre_op(&mut self) -> Result<Group<PreOp>, EthercatError> {
        let md = self.md;
        let group: Group<PreOp> = step_in(
            self.link,
            self.cfg,
            md.init::<MAX_RACK, _>(
                ethercrab::std::ethercat_now,
                Group::<PreOp>::default(),
                the_group,
            ),
            self.deadline,
            "bringing the slave to PRE-OP",
        )?;
        let n = md.num_subdevices();
        let expected = self.rack.map_or(1, |r| r.slaves);
        if n != expected {
            return Err(EthercatError::SlaveCount {
                interface: self.cfg.interface.clone(),
                found: n as u16,
                expected: expected as u16,
            });
        }
        Ok(group)
    }

    /// Checks the identity (vendor id, product code, as read from the SII)
    /// of each configured slave against the config; `Identity` names the
    /// key of the first mismatch.
    fn check_identities(&self, group: &Group<PreOp>) -> Result<(), EthercatError> {
        let (cfg, md) = (self.cfg, self.md);
        let mut idents = Vec::new();
        if self.rack.is_some() {
            for (i, s) in cfg.slaves.iter().enumerate() {
                let key = format!("backend.ethercat.slaves[{i}]");
                idents.push((usize::from(s.position), s.vendor_id, s.product_id, key));
            }
        } else {
            let key = "backend.ethercat".to_string();
            idents.push((0, cfg.vendor_id, cfg.expected_product_id(), key));
        }
        for (position, vendor_id, product_id, key) in idents {
            let id = group
                .subdevice(md, position)
                .map_err(|e| bringup_err(self.cfg, "reading the identity", e))?
                .identity();
            for (what, k, found, want) in [
                ("vendor id", "vendor_id", id.vendor_id, vendor_id),
                ("product code", "product_id", id.product_id, product_id),
            ] {
                if found != want {
                    return Err(EthercatError::Identity {
                        key: format!("{key}.{k}"),
                        position: position as u16,
                        interface: self.cfg.interface.clone(),
                        what,
                        found,
                        expected: want,
                    });
                }
            }
        }
        Ok(())
    }

    /// Writes the PDO map (RxPDO 0x1600 assigned in 0x1C12, TxPDO 0x1A00
    /// in 0x1C13) of each slave that is not fixed over CoE, in PRE-OP: the
    /// single device's, or each rack slave's that has a CoE mailbox and
    /// entries to map. An abort names the entry's key.
    fn map_pdos(&mut self, group: &Group<PreOp>) -> Result<(), EthercatError> {
        let cfg = self.cfg;
        let mut maps = Vec::new();
        if self.rack.is_some() {
            for (i, s) in cfg.slaves.iter().enumerate() {
                let key = format!("backend.ethercat.slaves[{i}]");
                if !s.fixed_pdo {
                    maps.push((usize::from(s.position), key, s.rx_entries(), s.tx_entries()));
                }
            }
        } else {
            let key = "backend.ethercat".to_string();
            maps.push((0, key, cfg.rx_entries(), cfg.tx_entries()));
        }
        for (position, key, rx, tx) in maps {
            // A slave without a CoE mailbox keeps its fixed map (SII word
            // 0x001C: mailbox protocols, bit 2 CoE; 0x001B: its send
            // mailbox size, as ethercrab decides).
            if self.rack.is_some() && !self.has_coe_mailbox(group, position)? {
                continue;
            }
            for (dir, assign, pdo, entries) in [
                ("rx_pdo", 0x1C12u16, 0x1600u16, rx),
                ("tx_pdo", 0x1C13, 0x1A00, tx),
            ] {
                if entries.is_empty() && self.rack.is_some() {
                    continue;
                }
                let key = |i: Option<usize>| match i {
                    Some(i) => format!("{key}.{dir}[{i}]"),
                    None => format!("{key}.{dir}"),
                };
                // Clear the assignment and the map, write the entries,
                // their count, then assign the PDO (the CoE mapping
                // sequence).
                let mut writes = vec![(assign, 0, Sdo::U8(0), None), (pdo, 0, Sdo::U8(0), None)];
                for (i, e) in entries.iter().enumerate() {
                    writes.push((pdo, i as u8 + 1, Sdo::U32(e.raw()), Some(i)));
                }
                writes.extend([
                    (pdo, 0, Sdo::U8(entries.len() as u8), None),
                    (assign, 1, Sdo::U16(pdo), None),
                    (assign, 0, Sdo::U8(1), None),
                ]);
                for (index, subindex, value, i) in writes {
                    sdo_in(
                        self.link,
                        self.cfg,
                        group,
                        self.md,
                        position,
                        (index, subindex),
                        value,
                        key(i),
                        self.deadline,
                    )?;
                }
            }
        }
        Ok(())
    }

    /// Whether the slave at `position` has a CoE mailbox, read from its
    /// SII (EEPROM): CoE among its mailbox protocols (word 0x001C, bit 2)
    /// and a send mailbox (word 0x001B, its size, not 0).
    fn has_coe_mailbox(
        &mut self,
        group: &Group<PreOp>,
        position: usize,
    ) -> Result<bool, EthercatError> {
        let md = self.md;
        let sd = group
            .subdevice(md, position)
            .map_err(|e| bringup_err(self.cfg, "reading the SII", e))?;
        let step = "reading the SII mailbox protocols (word 0x001C)";
        let protocols: u16 = step_in(
            self.link,
            self.cfg,
            sd.eeprom_read(md, 0x001C),
            self.deadline,
            step,
        )?;
        let send: u16 = step_in(
            self.link,
            self.cfg,
            sd.eeprom_read(md, 0x001B),
            self.deadline,
            step,
        )?;
        Ok(protocols & 0x0004 != 0 && send != 0)
    }

    /// The drive's motor rated current, A, read over CoE (0x6075, mA) in
    /// PRE-OP; 0 mA is refused.
    fn rated_current_a(&mut self, group: &Group<PreOp>) -> Result<f64, EthercatError> {
        let sd = group
            .subdevice(self.md, 0)
            .map_err(|e| bringup_err(self.cfg, "reading 0x6075", e))?;
        let ma: u32 = step_in(
            self.link,
            self.cfg,
            sd.sdo_read(0x6075, 0),
            self.deadline,
            "reading the motor rated current 0x6075",
        )?;
        if ma == 0 {
            return Err(EthercatError::Bringup {
                interface: self.cfg.interface.clone(),
                step: "reading the motor rated current 0x6075",
                reason: "the drive reports 0 mA".into(),
            });
        }
        Ok(f64::from(ma) * 1e-3)
    }

    /// Sets the sync manager watchdog of each slave with outputs
    /// (`images`, by position) to `backend.ethercat.watchdog_ms`: the
    /// divider 0x0400, then the time 0x0420. In force from OP on.
    fn set_sm_watchdogs(
        &mut self,
        group: &Group<PreOp>,
        images: &[(usize, usize)],
    ) -> Result<(), EthercatError> {
        // SM watchdog: 100 µs steps ((2498 + 2) × 40 ns).
        let steps = (self.cfg.watchdog_ms * 10.0).round().clamp(1.0, 65535.0) as u16;
        for (position, _) in images.iter().enumerate().filter(|(_, (o, _))| *o > 0) {
            let sd = group
                .subdevice(self.md, position)
                .map_err(|e| bringup_err(self.cfg, "setting the SM watchdog", e))?;
            run_in(
                self.link,
                self.cfg,
                sd.register_write(0x0400u16, 2498u16),
                self.deadline,
                "setting the SM watchdog",
            )?
            .map_err(|e| bringup_err(self.cfg, "setting the SM watchdog divider 0x0400", e))?;
            run_in(
                self.link,
                self.cfg,
                sd.register_write(0x0420u16, steps),
                self.deadline,
                "setting the SM watchdog",
            )?
            .map_err(|e| {
                bringup_err(
                    self.cfg,
                    "setting the SM watchdog time 0x0420 (backend.ethercat.watchdog_ms)",
                    e,
                )
            })?;
        }
        Ok(())
    }

    /// PRE-OP → SAFE-OP: the FMMUs and SMs from the PDO map read back;
    /// with distributed clocks, the process data image first, then SYNC0
    /// at the loop period (`period_ns`), then SAFE-OP.
    fn safe_op(&mut self, group: Group<PreOp>, period_ns: u64) -> Result<Running, EthercatError> {
        let (md, deadline) = (self.md, self.deadline);
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
            let group = step_in(
                self.link,
                self.cfg,
                group.into_pre_op_pdi(md),
                deadline,
                step,
            )?;
            let g = step_in(
                self.link,
                self.cfg,
                group.configure_dc_sync(md, dc),
                deadline,
                sync,
            )?;
            let g = step_in(self.link, self.cfg, g.into_safe_op(md), deadline, step)?;
            Running::SafeOpDc(g)
        } else {
            let g = step_in(self.link, self.cfg, group.into_safe_op(md), deadline, step)?;
            Running::SafeOp(g)
        };
        Ok(running)
    }

    /// Checks each slave's process image in SAFE-OP (output and input
    /// bytes, as the SMs were set up from its PDO map) against `images`,
    /// the one configured.
    fn check_images(
        &self,
        running: &Running,
        images: &[(usize, usize)],
    ) -> Result<(), EthercatError> {
        let md = self.md;
        for (position, want) in images.iter().enumerate() {
            let sizes = on_group!(running, g => g
            .subdevice(md, position)
            .map(|sd| {
                let io = sd.io_raw();
                (io.outputs().len(), io.inputs().len())
            }))
            .map_err(|e| bringup_err(self.cfg, "reading the process image", e))?;
            if sizes != *want {
                return Err(EthercatError::Bringup {
                    interface: self.cfg.interface.clone(),
                    step: "checking the process image",
                    reason: format!(
                        "the slave at position {position} maps {} output and {} input bytes, the config {} and {}{}",
                        sizes.0,
                        sizes.1,
                        want.0,
                        want.1,
                        if self.rack.is_some() {
                            " (its map in [[backend.ethercat.slaves]])"
                        } else {
                            ""
                        }
                    ),
                });
            }
        }
        Ok(())
    }
}

/// A value for an expedited SDO download.
#[derive(Debug, Clone, Copy)]
pub(super) enum Sdo {
    I8(i8),
    U8(u8),
    U16(u16),
    U32(u32),
}

impl Sdo {
    /// The value as the abort message shows it.
    fn raw(self) -> u32 {
        match self {
            Self::I8(v) => v as u32,
            Self::U8(v) => v.into(),
            Self::U16(v) => v.into(),
            Self::U32(v) => v,
        }
    }
}

/// One expedited SDO download during bring-up; an abort names `key`.
#[allow(clippy::too_many_arguments)]
pub(super) fn sdo_in(
    link: &mut Link,
    cfg: &EthercatConfig,
    group: &Group<PreOp>,
    md: &MainDevice<'static>,
    position: usize,
    (index, subindex): (u16, u8),
    value: Sdo,
    key: String,
    deadline: u64,
) -> Result<(), EthercatError> {
    let step = "writing the object dictionary";
    let sd = group
        .subdevice(md, position)
        .map_err(|e| bringup_err(cfg, step, e))?;
    let r = match value {
        Sdo::I8(v) => run_in(link, cfg, sd.sdo_write(index, subindex, v), deadline, step)?,
        Sdo::U8(v) => run_in(link, cfg, sd.sdo_write(index, subindex, v), deadline, step)?,
        Sdo::U16(v) => run_in(link, cfg, sd.sdo_write(index, subindex, v), deadline, step)?,
        Sdo::U32(v) => run_in(link, cfg, sd.sdo_write(index, subindex, v), deadline, step)?,
    };
    r.map_err(|e| EthercatError::Refused {
        key,
        index,
        subindex,
        value: value.raw(),
        reason: e.to_string(),
    })
}

pub(super) fn bringup_err(
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

/// Runs a bring-up step's future within `deadline_ns`; its error names
/// `step`.
pub(super) fn step_in<T, F: Future<Output = Result<T, ethercrab::error::Error>>>(
    link: &mut Link,
    cfg: &EthercatConfig,
    fut: F,
    deadline_ns: u64,
    step: &'static str,
) -> Result<T, EthercatError> {
    run_in(link, cfg, fut, deadline_ns, step)?.map_err(|e| bringup_err(cfg, step, e))
}

/// Runs a bring-up future to completion within `deadline_ns`.
pub(super) fn run_in<F: Future>(
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
