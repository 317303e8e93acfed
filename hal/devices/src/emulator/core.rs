//! The device side of an emulated DAQ: the simulated plant as a
//! microcontroller would run it, with its own clock and a watchdog.
//!
//! Both emulators (serial over a pseudo-terminal, SocketCAN) wrap one
//! [`DeviceCore`]; they differ only in how samples and commands travel. The
//! core is transport-free and time is passed in, so its rules are unit
//! tested without a link:
//!
//! * **The device owns the clock.** [`DeviceCore::tick`] is called on the
//!   device's sample timer (period `period_ns`). It advances the plant by one
//!   period with the latest accepted command held (zero-order hold) and
//!   returns the new sample, sequence numbers consecutive from 0.
//! * **Latest command wins.** [`DeviceCore::command`] stores a demand for the
//!   coming period; it is applied from the next tick on.
//! * **Watchdog.** While enabled, if no valid command has arrived for
//!   `watchdog_ns`, the next tick drops the current to 0 A, disables the
//!   amplifier and latches [`DeviceFault::Watchdog`]. Only
//!   [`DeviceCore::enable`] clears the latch. Worst-case detection time is
//!   `watchdog_ns + period_ns` after the last valid command.

use bench_hal::{Command, DeviceInfo, Sample, Stage};
use bench_plant::sim::{ScheduledFault, SimError, SimParams, SimStage};
use bench_protocol::DeviceFault;

/// The emulated device: plant, clock, amplifier state and watchdog.
#[derive(Debug, Clone)]
pub struct DeviceCore {
    stage: SimStage,
    info: DeviceInfo,
    watchdog_ns: u64,
    enabled: bool,
    fault: Option<DeviceFault>,
    /// Device time of the last valid command (or of the enable), ns.
    last_command_ns: u64,
    demand_a: f64,
    last_seq: u64,
    /// Sequence number (low bits, `seq_mask`) the last accepted command
    /// answered; the enable counts as an answer to the sample before it.
    answered_seq: Option<u64>,
    /// The bits of the sequence number a command carries.
    seq_mask: u64,
}

impl DeviceCore {
    /// A device running `params` at `period_ns` with a `watchdog_ns`
    /// watchdog. Disabled at 0 A.
    ///
    /// # Errors
    /// The simulator's parameter or period errors.
    pub fn new(params: SimParams, period_ns: u64, watchdog_ns: u64) -> Result<Self, SimError> {
        let mut stage = SimStage::new(params)?;
        let info = stage.configure(period_ns)?;
        Ok(Self {
            stage,
            info,
            watchdog_ns,
            enabled: false,
            fault: None,
            last_command_ns: 0,
            demand_a: 0.0,
            last_seq: 0,
            answered_seq: None,
            seq_mask: u64::from(u32::MAX),
        })
    }

    /// What the device reports in its handshake.
    pub fn info(&self) -> &DeviceInfo {
        &self.info
    }

    /// Sample period, ns.
    pub fn period_ns(&self) -> u64 {
        self.info.period_ns
    }

    /// Watchdog time, ns.
    pub fn watchdog_ns(&self) -> u64 {
        self.watchdog_ns
    }

    /// Commands carry the low `bits` of the sample sequence number they
    /// answer (32 on the serial link, the mapped width on CAN).
    pub fn set_answer_bits(&mut self, bits: u32) {
        self.seq_mask = if bits >= 64 {
            u64::MAX
        } else {
            (1u64 << bits) - 1
        };
    }

    /// Schedules a plant-side fault (NaN, frozen, jump, …) at device time.
    pub fn inject(&mut self, fault: ScheduledFault) {
        self.stage.inject(fault);
    }

    /// Enables the amplifier at 0 A and clears a latched fault. The watchdog
    /// starts counting from `now_ns`.
    pub fn enable(&mut self, now_ns: u64) {
        self.fault = None;
        self.demand_a = 0.0;
        self.enabled = self.stage.enable().is_ok();
        self.last_command_ns = now_ns;
        self.answered_seq = Some(self.last_seq & self.seq_mask);
    }

    /// 0 A, amplifier disabled. Does not clear a latched fault.
    pub fn disable(&mut self) {
        self.enabled = false;
        self.demand_a = 0.0;
        let _ = self.stage.disable();
    }

    /// Accepts a command received at `now_ns`. A non-finite demand, or a
    /// non-zero one while disabled or faulted, is refused: 0 A, disabled,
    /// fault latched ([`DeviceFault::BadCommand`]); returns `false`.
    /// A zero demand while disabled is accepted and does nothing (the host
    /// keeps the watchdog fed while idle).
    pub fn command(&mut self, command: Command, now_ns: u64) -> bool {
        let i = command.current_a;
        if !i.is_finite() || (!self.enabled && i != 0.0) {
            if self.enabled || !i.is_finite() {
                self.fault.get_or_insert(DeviceFault::BadCommand);
            }
            self.disable();
            return false;
        }
        self.last_command_ns = now_ns;
        self.answered_seq = Some(command.answers_seq & self.seq_mask);
        if self.enabled {
            let peak = self.info.peak_current_a;
            self.demand_a = i.clamp(-peak, peak);
        }
        true
    }

    /// Trips `fault` now: 0 A, amplifier disabled, fault latched until the
    /// next [`enable`](Self::enable). For rules kept outside the core (the
    /// SM watchdog of an EtherCAT slave controller, an injected drive
    /// fault).
    pub fn trip(&mut self, fault: DeviceFault) {
        self.fault = Some(fault);
        self.disable();
    }

    /// Applies the watchdog rule at device time `now_ns` without advancing
    /// the plant (for a device whose sample ticks stopped, e.g. a SYNC-driven
    /// one whose host died). Returns `true` if this call tripped it.
    pub fn check_watchdog(&mut self, now_ns: u64) -> bool {
        if self.enabled && now_ns.saturating_sub(self.last_command_ns) > self.watchdog_ns {
            self.fault = Some(DeviceFault::Watchdog);
            self.disable();
            return true;
        }
        false
    }

    /// One sample-timer tick at device time `now_ns`: watchdog check, then
    /// the plant advances one period under the held demand and is sampled.
    /// The sample says whether the command in force answered the previous
    /// sample ([`SampleFlags::command_late`](crate::SampleFlags::command_late)).
    pub fn tick(&mut self, now_ns: u64) -> Sample {
        self.check_watchdog(now_ns);
        let _ = self.stage.write_command(Command {
            current_a: if self.enabled { self.demand_a } else { 0.0 },
            answers_seq: self.last_seq,
        });
        let mut s = self
            .stage
            .read_sample()
            .expect("a configured simulator always samples");
        s.flags.amplifier_enabled = self.enabled;
        s.flags.amplifier_fault = self.fault.is_some();
        s.flags.command_late =
            self.enabled && self.answered_seq != Some(self.last_seq & self.seq_mask);
        self.last_seq = s.seq;
        s
    }

    /// The current the device is commanding now, A (0 when disabled).
    pub fn commanded_current_a(&self) -> f64 {
        if self.enabled {
            self.demand_a
        } else {
            0.0
        }
    }

    /// Amplifier enabled.
    pub fn is_enabled(&self) -> bool {
        self.enabled
    }

    /// The latched fault, if any.
    pub fn fault(&self) -> Option<DeviceFault> {
        self.fault
    }

    /// Device time of the last valid command, ns.
    pub fn last_command_ns(&self) -> u64 {
        self.last_command_ns
    }
}

/// A link-level fault an emulator can inject (on top of the plant-side
/// [`FaultInjection`](crate::sim::FaultInjection)s of the simulator).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LinkFault {
    /// Flip this many random bits in each of the next `frames` outgoing
    /// frames (serial: the CRC must reject them; CAN: the bus CRC would, so
    /// the emulator sends an error frame instead of the data frame).
    BitFlips {
        /// Bits flipped per frame.
        bits: u32,
        /// Frames affected.
        frames: u32,
    },
    /// Do not send the next `frames` sample frames (the plant keeps moving,
    /// the sequence number keeps counting).
    Drop {
        /// Frames dropped.
        frames: u32,
    },
    /// Hold every outgoing frame back by this long from then on, s.
    Delay {
        /// Added latency, s.
        delay_s: f64,
    },
    /// Hold every outgoing frame back for this long, once, then send them
    /// together (a USB or driver hiccup): the device keeps sampling, and
    /// its watchdog keeps running on the commands that do not come, s.
    Hold {
        /// Length of the hold, s.
        duration_s: f64,
    },
    /// Stop sampling and sending for this long (the device hangs), s. The
    /// watchdog does not run while stalled, as on a hung microcontroller.
    Stall {
        /// Length of the stall, s.
        duration_s: f64,
    },
    /// Drop the link for good (serial: close the pseudo-terminal; CAN:
    /// report bus-off and go silent).
    Disconnect,
}

impl LinkFault {
    /// Parses `bitflip:BITS[xFRAMES]`, `drop:FRAMES`, `delay:SECONDS`,
    /// `hold:SECONDS`, `stall:SECONDS`, `disconnect`.
    ///
    /// # Errors
    /// A message naming the part that does not parse.
    pub fn parse(s: &str) -> Result<Self, String> {
        let (name, arg) = s.split_once(':').unwrap_or((s, ""));
        let num = |what: &str| -> Result<f64, String> {
            arg.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite() && *v >= 0.0)
                .ok_or_else(|| format!("{name}: {what} `{arg}` is not a non-negative number"))
        };
        match name {
            "bitflip" => {
                let (bits, frames) = arg.split_once('x').unwrap_or((arg, "1"));
                let bits = bits
                    .parse::<u32>()
                    .ok()
                    .filter(|b| *b > 0)
                    .ok_or_else(|| format!("bitflip: bit count `{bits}` is not a positive integer"))?;
                let frames = frames
                    .parse::<u32>()
                    .map_err(|_| format!("bitflip: frame count `{frames}` is not an integer"))?;
                Ok(Self::BitFlips { bits, frames })
            }
            "drop" => Ok(Self::Drop {
                frames: arg
                    .parse()
                    .map_err(|_| format!("drop: frame count `{arg}` is not an integer"))?,
            }),
            "delay" => Ok(Self::Delay {
                delay_s: num("delay")?,
            }),
            "hold" => Ok(Self::Hold {
                duration_s: num("duration")?,
            }),
            "stall" => Ok(Self::Stall {
                duration_s: num("duration")?,
            }),
            "disconnect" if arg.is_empty() => Ok(Self::Disconnect),
            _ => Err(format!(
                "unknown link fault `{s}` (expected bitflip:BITS[xFRAMES], drop:FRAMES, delay:S, hold:S, stall:S or disconnect)"
            )),
        }
    }
}

/// A link fault scheduled at device time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScheduledLinkFault {
    /// Device time (since the emulator started) at which it starts, s.
    pub at_s: f64,
    /// What happens.
    pub kind: LinkFault,
}

/// What an emulator publishes about itself, lock-free, for tests and the
/// status line (`Arc` it and read from any thread).
#[derive(Debug, Default)]
pub struct EmulatorStatus {
    /// Commanded current, A, as `f64::to_bits`.
    commanded_current_bits: std::sync::atomic::AtomicU64,
    /// Amplifier enabled.
    pub enabled: std::sync::atomic::AtomicBool,
    /// Latched fault code ([`DeviceFault::code`], 0 for none).
    pub fault_code: std::sync::atomic::AtomicU8,
    /// Monotonic time of the last valid command, ns (`CLOCK_MONOTONIC`).
    pub last_command_mono_ns: std::sync::atomic::AtomicU64,
    /// Monotonic time at which the current was last dropped to 0 by the
    /// watchdog, ns (0 if never).
    pub watchdog_trip_mono_ns: std::sync::atomic::AtomicU64,
    /// Scheduled time (deadline) of the device tick at which the watchdog
    /// tripped, ns (`CLOCK_MONOTONIC`): the device-time statement of the
    /// trip, free of the host OS's scheduling delay.
    pub watchdog_trip_deadline_mono_ns: std::sync::atomic::AtomicU64,
    /// Samples sent.
    pub samples_sent: std::sync::atomic::AtomicU64,
    /// Valid commands received.
    pub commands_received: std::sync::atomic::AtomicU64,
    /// Frames received that failed their check (CRC, decoding).
    pub bad_frames: std::sync::atomic::AtomicU64,
    /// Commands that arrived after the period they were meant for.
    pub late_commands: std::sync::atomic::AtomicU64,
    /// A host has said hello (serial) since the emulator started.
    pub host_connected: std::sync::atomic::AtomicBool,
    /// Largest lateness of a device tick behind its deadline, ns (the
    /// emulator's own timing jitter), a skipped tick's included.
    pub max_tick_lateness_ns: std::sync::atomic::AtomicU64,
}

impl EmulatorStatus {
    /// Commanded current, A.
    pub fn commanded_current_a(&self) -> f64 {
        f64::from_bits(
            self.commanded_current_bits
                .load(std::sync::atomic::Ordering::Acquire),
        )
    }

    /// Publishes the device's state.
    pub fn publish(&self, d: &DeviceCore) {
        use std::sync::atomic::Ordering::Release;
        self.commanded_current_bits
            .store(d.commanded_current_a().to_bits(), Release);
        self.enabled.store(d.is_enabled(), Release);
        self.fault_code
            .store(d.fault().map_or(0, DeviceFault::code), Release);
    }
}
