//! [`CanError`]: the errors of the SocketCAN backend and emulator, and
//! their [`ErrorKind`]s.

use super::CAN_DATA_BYTES;
use crate::param::ParamError;
use crate::ErrorKind;
use bench_protocol::DeviceFault;
use socketcan::frame::CanErrorFrame;
use std::io;

/// Errors of the SocketCAN backend and emulator.
#[derive(Debug, thiserror::Error)]
pub enum CanError {
    /// The configuration is invalid.
    #[error("invalid CAN configuration: {0}")]
    Config(#[from] ParamError),
    /// The interface does not exist (or SocketCAN is unavailable).
    #[error("CAN interface `{interface}` not found ({source}); list interfaces with `ip link show type can` (or `type vcan`)")]
    NotFound {
        /// The interface name.
        interface: String,
        /// The OS error.
        source: io::Error,
    },
    /// A socket operation failed.
    #[error("CAN socket {op} failed: {source}")]
    Io {
        /// What was being done.
        op: &'static str,
        /// The OS error.
        source: io::Error,
    },
    /// No sample frame within the bounded wait.
    #[error("no sample frame within {waited_ns} ns")]
    Timeout {
        /// How long the read waited, ns.
        waited_ns: u64,
    },
    /// The configure-time link check got no sample.
    #[error("no sample frame 0x{sample_id:X} from node {node_id} on {interface} within {waited_ms} ms: is the device powered, on this bus, at this bit rate?")]
    NoDevice {
        /// The interface.
        interface: String,
        /// Node id.
        node_id: u8,
        /// Expected sample id.
        sample_id: u32,
        /// How long configure waited, ms.
        waited_ms: u64,
    },
    /// A bus-off error frame: the controller left the bus.
    #[error("CAN bus-off")]
    BusOff,
    /// Another error frame (protocol, CRC, ACK, transceiver, controller).
    #[error("CAN error frame: {}", describe_error_frame(.bits, .data))]
    ErrorFrame {
        /// Error class bits of the id word (`CAN_ERR_*`).
        bits: u32,
        /// The error frame's data bytes.
        data: [u8; CAN_DATA_BYTES],
    },
    /// A frame shorter than its map.
    #[error("{frame} frame carries {len} data bytes, the frame map needs {need}")]
    ShortFrame {
        /// `"command"` or `"sample"`.
        frame: &'static str,
        /// Bytes received.
        len: usize,
        /// Bytes the map needs.
        need: usize,
    },
    /// A datagram that is not a classic CAN frame.
    #[error("a {len}-byte datagram on the CAN socket is not a CAN frame")]
    BadDatagram {
        /// Its length, bytes.
        len: usize,
    },
    /// Used against the stage's lifecycle.
    #[error("CAN stage: {0}")]
    Lifecycle(#[from] crate::LifecycleError),
    /// An unusable sample period or timeout.
    #[error("sample period {period_ns} ns is unusable: {reason}")]
    Period {
        /// The requested period, ns.
        period_ns: u64,
        /// Why.
        reason: &'static str,
    },
    /// The device reports an amplifier fault (or did not enable).
    #[error("the device reports an amplifier fault ({})", fault_name(.code))]
    DeviceFault {
        /// The fault code from the status byte ([`DeviceFault::code`](bench_protocol::DeviceFault::code)).
        code: u8,
    },
    /// The transmit queue stayed full for the whole bounded wait.
    #[error("CAN transmit queue full (is the bus acknowledging frames?)")]
    TxFull,
}

fn fault_name(code: &u8) -> &'static str {
    DeviceFault::from_code(*code).map_or("unspecified", DeviceFault::as_str)
}

fn describe_error_frame(bits: &u32, data: &[u8; CAN_DATA_BYTES]) -> String {
    let bits = *bits;
    match CanErrorFrame::new_error(bits, data) {
        Ok(f) => format!("{} (class 0x{bits:X})", f.into_error()),
        Err(_) => format!("class 0x{bits:X}"),
    }
}

impl crate::Error for CanError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Config(_) | Self::Period { .. } => ErrorKind::Config,
            Self::NotFound { .. } => ErrorKind::NotFound,
            Self::Io { source, .. } => match source.raw_os_error() {
                Some(libc::ENODEV | libc::ENXIO) => ErrorKind::NotFound,
                Some(libc::EBUSY | libc::EADDRINUSE) => ErrorKind::Busy,
                _ => ErrorKind::Link,
            },
            Self::Timeout { .. } => ErrorKind::Timeout,
            Self::NoDevice { .. } | Self::BusOff | Self::TxFull => ErrorKind::Link,
            Self::ErrorFrame { .. } => ErrorKind::Crc,
            Self::ShortFrame { .. } | Self::BadDatagram { .. } => ErrorKind::Protocol,
            Self::Lifecycle(e) => crate::Error::kind(e),
            Self::DeviceFault { .. } => ErrorKind::AmplifierFault,
        }
    }
}

impl From<bench_protocol::can::ShortFrame> for CanError {
    fn from(e: bench_protocol::can::ShortFrame) -> Self {
        Self::ShortFrame {
            frame: e.frame,
            len: e.len,
            need: e.need,
        }
    }
}
