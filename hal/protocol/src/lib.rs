//! `bench-protocol`: what travels on the wire between the `bench` host and
//! a DAQ, and what a DAQ's firmware links: the serial frames
//! ([`serial`], specified byte by byte in `hal/protocol/PROTOCOL.md`), the
//! CAN frame map's layout ([`can`]), the sample's status bits
//! ([`SampleFlags`]) and the latched fault codes ([`DeviceFault`]).
//!
//! `#![no_std]` and without allocation: every encoder and decoder works
//! on fixed buffers, so the host runs them on the real-time tick and a
//! microcontroller links them as they are.
#![cfg_attr(not(test), no_std)]
#![warn(missing_docs)]

pub mod can;
mod fault;
pub mod serial;

pub use fault::DeviceFault;

/// Status bits carried with a sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SampleFlags {
    /// The probe is beyond its range; `position_m` is not trustworthy.
    pub out_of_range: bool,
    /// The amplifier is enabled.
    pub amplifier_enabled: bool,
    /// The amplifier reports a fault.
    pub amplifier_fault: bool,
    /// The command in force over the period that ended at this sample did
    /// not answer the previous sample: it arrived late, or none arrived (the
    /// device ran on an older one). Set only while the amplifier is enabled;
    /// backends that cannot tell report `false`. Many in a row mean a link
    /// whose latency exceeds a period (`link_latency` fault).
    pub command_late: bool,
}
