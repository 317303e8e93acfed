//! `bench-devices`: the virtual devices, the other side of every wire the
//! `bench` host speaks, each running the simulated plant
//! ([`bench_plant::sim`]) as a DAQ's firmware or a drive would:
//!
//! * [`emulator`]: the serial DAQ (over a pseudo-terminal) and the CAN DAQ
//!   (over SocketCAN) around one transport-free device core
//!   ([`emulator::DeviceCore`]: device clock, amplifier state, watchdog,
//!   link-fault injection);
//! * [`slave`]: the virtual EtherCAT slaves (a CiA 402 drive, an analog
//!   rack of terminals) on a raw socket, with their slave controller and
//!   SII EEPROM.
//!
//! Used by the tests of the host backends and by `bench emulate`; never by
//! a host backend.
#![warn(missing_docs)]

pub mod emulator;
pub mod slave;
