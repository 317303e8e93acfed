//! `bench-hal`: the hardware abstraction between the `bench` real-time loop
//! and a flexure stage driven by a voice-coil **current amplifier** and read
//! by a **position probe**.
//!
//! The loop sees one trait, [`Stage`], with an explicit lifecycle (after
//! ros2_control's hardware interface):
//!
//! ```text
//!  configure(period_ns) ──► enable() ──► { read_sample(); write_command() }* ──► disable()
//!   link up, probe          amplifier      one pair per loop tick               0 A, amplifier
//!   readable, 0 A           enabled                                             disabled
//! ```
//!
//! The host backends live in this crate, each behind its cargo feature
//! (all on by default): [`serial`] ([`serial::SerialStage`]), [`can`]
//! ([`can::CanStage`]) and [`ethercat`] ([`ethercat::EthercatStage`], on
//! `ethercrab`). The simulated plant is the `bench-plant` crate
//! (`bench_plant::sim::SimStage`, a backend like these, not a test double:
//! the lumped SR4DoF model of the thesis discretised exactly at the loop
//! period); the device side of every wire (the serial and CAN emulators,
//! the virtual EtherCAT slaves) is `bench-devices`; what travels on the
//! wire (frames, the CAN map's layout, fault codes) is the `no_std`
//! `bench-protocol`.
//!
//! The trait fits both **host-clocked** backends (the loop sleeps until an
//! absolute deadline, then reads the latest sample: the simulator, an analog
//! card) and **device-clocked** ones (the DAQ samples on its own timer and
//! [`Stage::read_sample`] blocks, with a bounded timeout, until the next
//! sample arrives: a USB-serial microcontroller, a CAN module). The backend
//! says which in [`DeviceInfo::clock`].
//!
//! # Layout
//!
//! * The crate root: the [`Stage`] trait, its data and error kinds.
//! * [`param`]: a parameter's error ([`param::ParamError`]) and the range
//!   checks of every config table.
//! * [`os`]: every OS call timing needs (`CLOCK_MONOTONIC` time and
//!   absolute sleeps, scheduling, memory locking, CPU wake-up latency).
//! * Host backends: [`serial`], [`can`] (with the `[backend.can]` table
//!   and the socket primitives the CAN emulator shares) and [`ethercat`]
//!   (with the EtherCAT wire format and socket the virtual slaves share).
#![warn(missing_docs)]

#[cfg(feature = "can")]
pub mod can;
#[cfg(feature = "ethercat")]
pub mod ethercat;
pub mod os;
pub mod param;
#[cfg(feature = "serial")]
pub mod serial;

use core::fmt;

/// Classes of HAL failure, in the words of the bench rather than of a device
/// (after `embedded_hal::digital::ErrorKind`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum ErrorKind {
    /// No sample or acknowledgement within the backend's bounded timeout.
    Timeout,
    /// A value outside what the device can represent or accepts
    /// (e.g. a current above the amplifier's peak rating).
    OutOfRange,
    /// A frame failed its integrity check.
    Crc,
    /// The amplifier reported a fault (over-temperature, over-current, …).
    AmplifierFault,
    /// The link to the device is down or unusable (disconnect, bus-off).
    Link,
    /// The device speaks another protocol or version.
    Protocol,
    /// A lifecycle method was called in the wrong state
    /// (e.g. a non-zero command while the amplifier is disabled).
    InvalidState,
    /// The backend's configuration is invalid.
    Config,
    /// The device is held by another process.
    Busy,
    /// The device does not exist.
    NotFound,
    /// Anything else.
    Other,
}

/// A HAL error: any backend error type, with a [`kind`](Error::kind) the loop
/// can act on without knowing the backend.
pub trait Error: fmt::Debug + fmt::Display + Send + Sync + 'static {
    /// The class of this error.
    fn kind(&self) -> ErrorKind;
}

/// How the loop is paced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Clock {
    /// The host paces the loop: it waits for its own deadline, then
    /// [`Stage::read_sample`] returns the latest sample without waiting.
    Host,
    /// The device samples on its own timer at `rate_hz`;
    /// [`Stage::read_sample`] blocks (bounded) until the next sample.
    Device {
        /// Device sample rate, Hz.
        rate_hz: f64,
    },
}

/// What a configured backend reports about itself.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceInfo {
    /// Human-readable backend and device name (recorded in MCAP metadata).
    pub name: String,
    /// Who paces the loop.
    pub clock: Clock,
    /// Sample period actually in force, ns (may differ from the request for
    /// device-clocked backends).
    pub period_ns: u64,
    /// Largest current the amplifier delivers, A (commands beyond are
    /// clipped by the amplifier).
    pub peak_current_a: f64,
    /// Current the actuator can carry continuously, A (I²t rating).
    pub continuous_current_a: f64,
    /// The probe reads positions in `[-probe_range_m, +probe_range_m]`.
    pub probe_range_m: f64,
    /// The reading's count on the link, m: the step between two readings
    /// the link can carry (serial: the hello's `position_lsb_m`; CAN: the
    /// position field's scale; EtherCAT: the ADC's full scale / 32767 or
    /// the drive's `position_lsb_m`); 0 when the link carries the value
    /// itself (the simulator, whose own quantisation is
    /// `probe.quantization_m`). With the probe's noise it says how long a
    /// live probe can read one value ([`Sample::position_m`] bit-identical).
    pub probe_lsb_m: f64,
    /// The device's own watchdog, s, when it announces one: with no valid
    /// command for this long while enabled, the device drops the current to
    /// 0 A and latches a fault (serial: the hello's `watchdog_ms`). `None`:
    /// not announced (simulator, CAN). The host judges a silent link by it:
    /// a device heard from within its watchdog time is not dead.
    pub watchdog_s: Option<f64>,
}

/// A stage used against its lifecycle (the same rule for every backend):
/// before `configure`, a non-zero current while the amplifier is disabled,
/// or a current that is not a number. [`LifecycleError::check_command`]
/// is the one check every `write_command` makes first.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum LifecycleError {
    /// `read_sample`, `write_command` or `enable` before `configure`.
    #[error("the stage is not configured")]
    NotConfigured,
    /// Non-zero current demanded while the amplifier is disabled.
    #[error("{current_a} A demanded while the amplifier is disabled")]
    NotEnabled {
        /// The demand, A.
        current_a: f64,
    },
    /// A current demand that is not finite.
    #[error("current demand is not finite ({current_a})")]
    NotFinite {
        /// The demand, A.
        current_a: f64,
    },
}

impl LifecycleError {
    /// The lifecycle check of a command of `current_a` on a stage that is
    /// (or is not) `configured` and `enabled`: a backend that gets
    /// `NotFinite` sends 0 A before returning it.
    ///
    /// # Errors
    /// The first rule broken, in the order above.
    pub fn check_command(configured: bool, enabled: bool, current_a: f64) -> Result<(), Self> {
        if !configured {
            Err(Self::NotConfigured)
        } else if !current_a.is_finite() {
            Err(Self::NotFinite { current_a })
        } else if !enabled && current_a != 0.0 {
            Err(Self::NotEnabled { current_a })
        } else {
            Ok(())
        }
    }
}

impl Error for LifecycleError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::NotConfigured | Self::NotEnabled { .. } => ErrorKind::InvalidState,
            Self::NotFinite { .. } => ErrorKind::OutOfRange,
        }
    }
}

/// One probe sample. Plain data, `Copy`: reading one never allocates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Sample sequence number, consecutive from 0 after `configure`. A gap
    /// means samples were lost.
    pub seq: u64,
    /// Device time of the sample, ns since `configure`.
    pub device_time_ns: u64,
    /// Probe reading, m. Saturated at the probe range when out of range.
    pub position_m: f64,
    /// Amplifier output current if the device measures it, A; `NaN` if not.
    pub measured_current_a: f64,
    /// Status flags.
    pub flags: SampleFlags,
}

pub use bench_protocol::SampleFlags;

/// One command to the amplifier.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    /// Current demand, A.
    pub current_a: f64,
    /// Sequence number of the sample this command answers (device-clocked
    /// backends use it to measure latency and detect a stale host).
    pub answers_seq: u64,
}

/// The loop's view of a stage: one current-controlled actuator and one
/// position probe.
///
/// Real-time safety: [`read_sample`](Stage::read_sample) and
/// [`write_command`](Stage::write_command) are called on the real-time tick.
/// Implementations must not allocate, lock contended mutexes or log in them;
/// blocking is allowed only for device I/O and must be bounded by a timeout.
/// The other methods run outside the tick.
///
/// Safety contract: [`disable`](Stage::disable) must drive the current to
/// 0 A and disable the amplifier from any state, including after an error,
/// and be idempotent. Dropping a backend must leave the amplifier disabled.
pub trait Stage {
    /// The backend's error type.
    type Error: Error;

    /// Brings the link up at the requested sample period and makes the probe
    /// readable, amplifier disabled (0 A). Not real-time.
    ///
    /// # Errors
    /// `Config` for an unusable period, `NotFound`/`Busy`/`Link`/`Protocol`
    /// when the device cannot be reached.
    fn configure(&mut self, period_ns: u64) -> Result<DeviceInfo, Self::Error>;

    /// Enables the amplifier at 0 A. Not real-time.
    ///
    /// # Errors
    /// `InvalidState` if not configured; `AmplifierFault` if it refuses.
    fn enable(&mut self) -> Result<(), Self::Error>;

    /// Reads the next sample. Real-time safe.
    ///
    /// # Errors
    /// `Timeout` when no sample arrives in time, `Link`/`Crc` on link faults,
    /// `InvalidState` if not configured.
    fn read_sample(&mut self) -> Result<Sample, Self::Error>;

    /// Sends the current demand for the coming period. Real-time safe.
    ///
    /// # Errors
    /// `InvalidState` for a non-zero demand while the amplifier is disabled,
    /// `OutOfRange` for a non-finite demand, `Link` on link faults.
    fn write_command(&mut self, command: Command) -> Result<(), Self::Error>;

    /// Commands 0 A and disables the amplifier. Works from any state and is
    /// idempotent. Not real-time (but bounded).
    ///
    /// # Errors
    /// `Link` if the device could not be told; the backend must still have
    /// done everything it can locally.
    fn disable(&mut self) -> Result<(), Self::Error>;

    /// The safe stop, in one place: commands 0 A (answering
    /// `answers_seq`), then disables the amplifier. The disable runs even
    /// when the 0 A command fails (a link that is gone), and its result is
    /// returned. Real-time safe when `write_command` and `disable` are.
    ///
    /// # Errors
    /// As [`disable`](Stage::disable).
    fn zero_and_disable(&mut self, answers_seq: u64) -> Result<(), Self::Error> {
        let _ = self.write_command(Command {
            current_a: 0.0,
            answers_seq,
        });
        self.disable()
    }
}
