//! emulator: the device side of the wire, the DAQ firmware as a host sees
//! it. [`DeviceCore`] (plant, device clock, amplifier state, watchdog;
//! `core.rs`) is transport-free; [`serial`] serves it over a
//! pseudo-terminal in the [`protocol`](crate::protocol), [`can`] over
//! SocketCAN in the frame map of [`crate::can`]. May use the crate root,
//! `model`, `sim`, `protocol`, `clock`, and from `can` only the frame map,
//! the socket primitives and `CanError`; never the host backends
//! (`serial::SerialStage`, `can::CanStage`).

pub mod can;
mod core;
pub mod serial;

pub use self::core::{DeviceCore, DeviceFault, EmulatorStatus, LinkFault, ScheduledLinkFault};
