//! The tick: one process-data exchange ([`EthercatStage::exchange`]),
//! the distributed-clock check, the outputs and the sample.

use super::group::Cycle;
use super::link::Stall;
use super::*;
use crate::ethercat::rack::SignalAt;
use crate::ethercat::wire::{adc_status, get_bits, set_bits};

impl EthercatStage {
    /// One process-data round trip: the outputs `self.out` go out, the
    /// inputs come back into `self.inp`; working counter, AL state and
    /// the drive's fault bit are checked. Real-time safe: no allocation,
    /// no lock (the image's [`BorrowFlag`] is one atomic that never
    /// waits), the wait bounded by the exchange timeout.
    pub(super) fn exchange(&mut self) -> Result<(), EthercatError> {
        let md = self
            .md
            .as_ref()
            .expect("the main device lives as long as the stage");
        let (out_len, in_len) = (self.layout.out_len, self.layout.in_len);
        let Some(group) = self.group.as_ref() else {
            return Err(LifecycleError::NotConfigured.into());
        };
        let op = group.is_op();
        if let (true, Some(r)) = (op, self.rack) {
            // Scattered to the terminals: the DAC's i16, the enable bit.
            let l = self.layout;
            let dac = u32::from(u16::from_le_bytes([
                self.out[l.target.0],
                self.out[l.target.0 + 1],
            ]));
            let en = u32::from(self.out[l.controlword] & 1);
            for (at, v) in [(r.dac, dac), (r.enable, en)] {
                on_group!(group, g => if let Ok(sd) = g.subdevice(md, at.slave) {
                    set_bits(&mut sd.outputs_raw_mut(), at.bit, usize::from(at.bits.min(16)), v);
                });
            }
        } else if op {
            on_group!(group, g => if let Ok(sd) = g.subdevice(md, 0) {
                sd.outputs_raw_mut()[..out_len].copy_from_slice(&self.out[..out_len]);
            });
        }
        let start = monotonic_ns();
        let deadline = start + self.timeout_ns;
        // (working counter, AL state of the slave, DC system time).
        let result = on_group!(group, g => self.link.block_on(g.cycle(md), deadline, u64::MAX));
        let end = monotonic_ns();
        if let Some(r) = self.rack {
            // Gathered from the terminals: the ADC's i16, the ready and
            // fault lines as the single device's status bits 0 and 1.
            let l = self.layout;
            let bits = |at: SignalAt, n: usize| {
                on_group!(group, g => g
                    .subdevice(md, at.slave)
                    .map_or(0, |sd| get_bits(&sd.inputs_raw(), at.bit, n)))
            };
            let adc = bits(r.adc, 16) as u16;
            self.inp[l.position..l.position + 2].copy_from_slice(&adc.to_le_bytes());
            if let (Some(st), Some(at)) = (r.adc_status, l.adc_status) {
                let v = bits(st, 16) as u16;
                self.inp[at..at + 2].copy_from_slice(&v.to_le_bytes());
            }
            if let Some(st) = r.status {
                let wide = st.bits >= 2;
                let mut v = bits(st, if wide { 2 } else { 1 });
                if let Some(f) = r.fault {
                    v |= bits(f, 1) << 1;
                }
                self.inp[l.statusword] = v as u8;
            }
        } else {
            on_group!(group, g => if let Ok(sd) = g.subdevice(md, 0) {
                self.inp[..in_len].copy_from_slice(&sd.inputs_raw()[..in_len]);
            });
        }
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
        // Per slave: inputs read +1, outputs written +2 (ETG.1000.4
        // §5.4.3.4); the group's sum (found at bring-up).
        let expected = if op { self.wkc.1 } else { self.wkc.0 };
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
    pub(super) fn check_dc(&mut self, t: u64, sent: u64, back: u64) -> Result<(), EthercatError> {
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

    pub(super) fn set_outputs(&mut self, controlword: u16, current_a: f64) {
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

    pub(super) fn sample(&self) -> Sample {
        let l = self.layout;
        let sw = self.statusword();
        let (position_m, out_of_range, enabled, fault) = if self.analog() {
            let v = entry_i64(&self.inp, l.position, false);
            let known = l.statusword != usize::MAX;
            // The channel's status word, if mapped: an error is no valid
            // reading (NaN, as the serial and CAN links report one), under-
            // or overrange is out of range.
            let st = l
                .adc_status
                .map_or(0, |at| u16::from_le_bytes([self.inp[at], self.inp[at + 1]]));
            let x = if st & adc_status::ERROR != 0 {
                f64::NAN
            } else {
                v as f64 / 32767.0 * self.cfg.adc_full_scale_m
            };
            (
                x,
                v.abs() >= 32767 || st & (adc_status::UNDERRANGE | adc_status::OVERRANGE) != 0,
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
    pub(super) fn drive_to(
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
}
