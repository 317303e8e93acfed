//! [`EthercatError`]: the errors of the EtherCAT backend and virtual slave,
//! and their [`ErrorKind`]s.

use crate::param::ParamError;
use crate::ErrorKind;
use std::io;

/// Errors of the EtherCAT backend and virtual slave.
#[derive(Debug, thiserror::Error)]
pub enum EthercatError {
    /// The configuration is invalid.
    #[error("invalid EtherCAT configuration: {0}")]
    Config(#[from] ParamError),
    /// The interface does not exist.
    #[error(
        "network interface `{interface}` not found ({source}); list interfaces with `ip link`"
    )]
    NotFound {
        /// The interface name.
        interface: String,
        /// The OS error.
        source: io::Error,
    },
    /// No right to open a raw socket.
    #[error("no permission to open a raw socket on `{interface}` ({source}): EtherCAT needs CAP_NET_RAW (run as root or `setcap cap_net_raw,cap_net_admin=eip` the binary)")]
    Permission {
        /// The interface name.
        interface: String,
        /// The OS error.
        source: io::Error,
    },
    /// A socket operation failed.
    #[error("EtherCAT socket {op} failed: {source}")]
    Io {
        /// What was being done.
        op: &'static str,
        /// The OS error.
        source: io::Error,
    },
    /// No frame came back: nothing on the segment answers.
    #[error("no EtherCAT slave found on `{interface}`: no frame came back within {waited_ms} ms (is the slave powered and cabled to this port?)")]
    NoSlave {
        /// The interface.
        interface: String,
        /// How long the master waited, ms.
        waited_ms: u64,
    },
    /// The segment holds another number of slaves than configured (one,
    /// or the rack's `[[backend.ethercat.slaves]]`).
    #[error("{found} EtherCAT slaves answered on `{interface}`; the config expects {expected} (backend.ethercat.slaves)")]
    SlaveCount {
        /// The interface.
        interface: String,
        /// Slaves counted (working counter of a broadcast read).
        found: u16,
        /// Slaves configured.
        expected: u16,
    },
    /// The slave found is not the one configured.
    #[error("{key}: the slave at position {position} on `{interface}` has {what} 0x{found:08X}, the config expects 0x{expected:08X}")]
    Identity {
        /// The config key (`backend.ethercat.vendor_id`/`product_id`, or
        /// `backend.ethercat.slaves[i].vendor_id`/`product_id`).
        key: String,
        /// The slave's position on the segment (0: next to the master).
        position: u16,
        /// The interface.
        interface: String,
        /// `"vendor id"` or `"product code"`.
        what: &'static str,
        /// From the slave's SII.
        found: u32,
        /// From the config.
        expected: u32,
    },
    /// The slave refused an SDO download (its abort code, ETG.1000.6
    /// Table 41).
    #[error("{key}: the slave refused 0x{index:04X}:{subindex:02X} = 0x{value:X} ({reason})")]
    Refused {
        /// The config key the value comes from.
        key: String,
        /// Object index.
        index: u16,
        /// Object subindex.
        subindex: u8,
        /// The value written.
        value: u32,
        /// The abort, as the master reports it.
        reason: String,
    },
    /// A bring-up step failed.
    #[error("EtherCAT bring-up on `{interface}` failed while {step}: {reason}")]
    Bringup {
        /// The interface.
        interface: String,
        /// The step.
        step: &'static str,
        /// What went wrong.
        reason: String,
    },
    /// The bring-up did not finish in `bringup_timeout_ms`.
    #[error("EtherCAT bring-up on `{interface}` did not finish within {waited_ms} ms (step: {step}; backend.ethercat.bringup_timeout_ms)")]
    BringupTimeout {
        /// The interface.
        interface: String,
        /// The step that was running.
        step: &'static str,
        /// The bound, ms.
        waited_ms: u64,
    },
    /// Another EtherCAT master runs in this process.
    #[error("an EtherCAT master is already open in this process")]
    Busy,
    /// A process-data frame did not come back in time (lost frame).
    #[error("process-data frame lost: no answer within {waited_ns} ns")]
    Timeout {
        /// How long the exchange waited, ns.
        waited_ns: u64,
    },
    /// The process-data frame came back with a wrong working counter.
    #[error("working counter {got}, expected {expected} (the slave did not read and write its process data)")]
    WorkingCounter {
        /// Expected: 3 for a slave in OP (inputs read +1, outputs written +2).
        expected: u16,
        /// Received.
        got: u16,
    },
    /// The slave is not in the AL state the stage expects (OP while
    /// enabled, SAFE-OP otherwise), read in the same frame.
    #[error("the slave left its AL state: it is in {}", super::wire::al::name(*.state))]
    NotOp {
        /// AL state (AL status register 0x0130, bits 0–3).
        state: u8,
    },
    /// The distributed clock drifted from the host's clock beyond
    /// `dc_drift_max_ppm`.
    #[error("the distributed clock moved {} µs against the host's clock within {:.3} s (backend.ethercat.dc_drift_max_ppm)", *.moved_ns as f64 * 1e-3, *.within_ns as f64 * 1e-9)]
    DcDrift {
        /// Offset change beyond the round-trip bounds, ns.
        moved_ns: u64,
        /// Over this long, ns.
        within_ns: u64,
    },
    /// The drive reports a fault (statusword bit 3), or did not enable.
    #[error("the drive reports a fault (statusword 0x{statusword:04X})")]
    DriveFault {
        /// Statusword 0x6041.
        statusword: u16,
    },
    /// The frame's EtherCAT content failed (master stack error).
    #[error("EtherCAT process data: {0}")]
    Exchange(ethercrab::error::Error),
    /// Used against the stage's lifecycle.
    #[error("EtherCAT stage: {0}")]
    Lifecycle(#[from] crate::LifecycleError),
    /// An unusable sample period.
    #[error("sample period {period_ns} ns is unusable: {reason}")]
    Period {
        /// The requested period, ns.
        period_ns: u64,
        /// Why.
        reason: &'static str,
    },
}

impl crate::Error for EthercatError {
    fn kind(&self) -> ErrorKind {
        match self {
            Self::Config(_) | Self::Period { .. } => ErrorKind::Config,
            Self::NotFound { .. } => ErrorKind::NotFound,
            Self::Permission { .. } | Self::Busy => ErrorKind::Busy,
            Self::Io { source, .. } => match source.raw_os_error() {
                Some(libc::ENODEV | libc::ENXIO) => ErrorKind::NotFound,
                _ => ErrorKind::Link,
            },
            Self::NoSlave { .. }
            | Self::SlaveCount { .. }
            | Self::BringupTimeout { .. }
            | Self::Bringup { .. }
            | Self::WorkingCounter { .. }
            | Self::NotOp { .. }
            | Self::DcDrift { .. }
            | Self::Exchange(_) => ErrorKind::Link,
            Self::Identity { .. } | Self::Refused { .. } => ErrorKind::Protocol,
            Self::Timeout { .. } => ErrorKind::Timeout,
            Self::DriveFault { .. } => ErrorKind::AmplifierFault,
            Self::Lifecycle(e) => crate::Error::kind(e),
        }
    }
}
