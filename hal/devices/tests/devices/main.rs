//! The hal's tests: the plant model, the simulator, the wire protocol and
//! the serial, CAN and EtherCAT backends against their emulators, one test
//! binary with a module per subject.

#[path = "../common/mod.rs"]
mod common;

mod can;
mod device;
mod ethercat;
mod serial;
