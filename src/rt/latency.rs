//! `/dev/cpu_dma_latency`: the kernel's PM QoS request for CPU wake-up
//! latency (Documentation/power/pm_qos_interface.rst). Writing a 32-bit 0
//! asks every CPU to stay out of the deep idle states (C-states) whose exit
//! adds tens of µs to a timer wake-up; the request holds while the file
//! stays open and ends when it is closed. `cyclictest` (rt-tests) does the
//! same for its whole run, so a real-time run holds it for its whole run
//! too ([`CpuDmaLatency`], an RAII guard: closed when the loop ends, on
//! every path, fault and error included).

use std::fs::{File, OpenOptions};
use std::io::Write;

/// The PM QoS device.
pub const PATH: &str = "/dev/cpu_dma_latency";

/// Whether the run holds `/dev/cpu_dma_latency` at 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DmaLatency {
    /// Virtual time: not asked for.
    #[default]
    NotRequested,
    /// Held at 0 µs for the run.
    Held,
    /// Could not be opened or written; the OS error number.
    Unavailable {
        /// `errno` of the failed open or write.
        errno: i32,
    },
}

impl std::fmt::Display for DmaLatency {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::NotRequested => write!(f, "not requested (virtual time)"),
            Self::Held => write!(f, "held at 0 µs"),
            Self::Unavailable { errno } => write!(
                f,
                "unavailable ({})",
                std::io::Error::from_raw_os_error(*errno)
            ),
        }
    }
}

/// The open request: while it lives the CPUs stay out of deep idle states.
/// Dropping it closes the file, which ends the request.
#[derive(Debug)]
pub struct CpuDmaLatency {
    _file: File,
}

impl CpuDmaLatency {
    /// Opens [`PATH`] and writes 0 (a native-endian `s32`, as `cyclictest`
    /// does). Allocates (not on the tick).
    ///
    /// # Errors
    /// The open or write error: no such device (a container without it),
    /// or permission (the node is usually mode 0600, root only).
    pub fn hold() -> std::io::Result<Self> {
        let mut file = OpenOptions::new().write(true).open(PATH)?;
        file.write_all(&0i32.to_ne_bytes())?;
        Ok(Self { _file: file })
    }

    /// [`CpuDmaLatency::hold`], as the guard and what happened.
    pub fn try_hold() -> (Option<Self>, DmaLatency) {
        match Self::hold() {
            Ok(g) => (Some(g), DmaLatency::Held),
            Err(e) => (
                None,
                DmaLatency::Unavailable {
                    errno: e.raw_os_error().unwrap_or(libc::EIO),
                },
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Read;

    /// The kernel's current aggregate request, µs (reading the device gives
    /// it as an `s32`).
    fn current_us() -> Option<i32> {
        let mut b = [0u8; 4];
        File::open(PATH).ok()?.read_exact(&mut b).ok()?;
        Some(i32::from_ne_bytes(b))
    }

    #[test]
    fn held_reads_zero_and_the_status_says_why_not() {
        let (guard, status) = CpuDmaLatency::try_hold();
        match status {
            DmaLatency::Held => {
                assert!(guard.is_some());
                // While held, the kernel's aggregate target is 0 µs.
                if let Some(v) = current_us() {
                    assert_eq!(v, 0);
                }
                assert_eq!(status.to_string(), "held at 0 µs");
            }
            DmaLatency::Unavailable { errno } => {
                assert!(guard.is_none());
                let text = status.to_string();
                assert!(text.starts_with("unavailable ("), "{text}");
                assert!(text.contains(&format!("os error {errno}")), "{text}");
            }
            DmaLatency::NotRequested => panic!("try_hold always tries"),
        }
        assert_eq!(
            DmaLatency::NotRequested.to_string(),
            "not requested (virtual time)"
        );
    }
}
