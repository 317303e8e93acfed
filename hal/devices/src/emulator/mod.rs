//! emulator: the device side of the wire, the DAQ firmware as a host sees
//! it. [`DeviceCore`] (plant, device clock, amplifier state, watchdog;
//! `core.rs`) is transport-free; [`serial`] serves it over a
//! pseudo-terminal in the frames of [`bench_protocol::serial`], [`can`]
//! over SocketCAN in the frame map of [`bench_protocol::can`]. From
//! `bench_hal::can` it uses the `[backend.can]` table, the socket
//! primitives and `CanError`; never the host backends
//! (`SerialStage`, `CanStage`).
//!
//! Layer rule: may use nothing of the crate.

pub mod can;
mod core;
pub mod serial;

pub use self::core::{DeviceCore, EmulatorStatus, LinkFault, ScheduledLinkFault};
