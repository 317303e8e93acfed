//! Every call into the operating system that timing depends on, in one
//! place: the clock (`CLOCK_MONOTONIC` time and absolute sleeps on it),
//! scheduling (SCHED_FIFO, CPU affinity, niceness), memory locking, waiting on a file descriptor
//! ([`poll_until`]) and the CPU wake-up latency request (`/dev/cpu_dma_latency`), and the free space
//! of a file system ([`available_bytes`]). The host backends,
//! the emulators and the bench's real-time loop, recorder and live view use
//! it; it depends on nothing else in the crate.
//!
//! `/dev/cpu_dma_latency` is the kernel's PM QoS request for CPU wake-up
//! latency (Documentation/power/pm_qos_interface.rst). Writing a 32-bit 0
//! asks every CPU to stay out of the deep idle states (C-states) whose exit
//! adds tens of µs to a timer wake-up; the request holds while the file
//! stays open and ends when it is closed. `cyclictest` (rt-tests) does the
//! same for its whole run, so a real-time run holds it for its whole run
//! too ([`CpuDmaLatency`], an RAII guard: closed when the loop ends, on
//! every path, fault and error included).
//!
//! Layer rule: may use nothing of the crate.

use std::fs::{File, OpenOptions};
use std::io::Write;

/// `CLOCK_MONOTONIC`, ns.
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: valid pointer; CLOCK_MONOTONIC always exists.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// Waits until `fd` reports one of `events` (`POLLIN`, `POLLOUT`) or an
/// error condition, or `CLOCK_MONOTONIC` reaches `deadline_ns` (absolute),
/// with `ppoll`; a signal resumes the wait with the time left. `Ok(None)`
/// on timeout, else the returned events (`revents`: also `POLLHUP`,
/// `POLLERR`, `POLLNVAL`, which the caller judges).
///
/// # Errors
/// The OS error of `ppoll` other than `EINTR`.
pub fn poll_until(
    fd: std::os::fd::RawFd,
    events: libc::c_short,
    deadline_ns: u64,
) -> std::io::Result<Option<libc::c_short>> {
    loop {
        let left = deadline_ns.saturating_sub(monotonic_ns());
        let ts = libc::timespec {
            tv_sec: (left / 1_000_000_000) as libc::time_t,
            tv_nsec: (left % 1_000_000_000) as libc::c_long,
        };
        let mut pfd = libc::pollfd {
            fd,
            events,
            revents: 0,
        };
        // SAFETY: one valid pollfd, a valid timespec, no signal mask.
        let r = unsafe { libc::ppoll(&mut pfd, 1, &ts, std::ptr::null()) };
        if r > 0 {
            return Ok(Some(pfd.revents));
        }
        if r == 0 {
            return Ok(None);
        }
        let e = std::io::Error::last_os_error();
        if e.raw_os_error() != Some(libc::EINTR) {
            return Err(e);
        }
    }
}

/// Sleeps until `CLOCK_MONOTONIC` reaches `deadline_ns` (absolute, so
/// periods do not drift). Returns at once if it has passed.
pub fn sleep_until_ns(deadline_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
    };
    loop {
        // SAFETY: valid timespec; EINTR returns early and we retry.
        let r = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if r != libc::EINTR {
            break;
        }
    }
}

/// Applies SCHED_FIFO, `mlockall` and CPU pinning to the calling thread.
/// Returns one warning line per thing that was not permitted.
pub fn make_realtime(priority: i32, cpu: Option<usize>) -> Vec<String> {
    let mut warnings = Vec::new();
    // SAFETY: plain libc calls on the current thread with valid arguments.
    unsafe {
        if libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) != 0 {
            warnings.push(format!(
                "mlockall failed ({}): page faults may add latency",
                std::io::Error::last_os_error()
            ));
        }
        let param = libc::sched_param {
            sched_priority: priority,
        };
        let r = libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param);
        if r != 0 {
            warnings.push(format!(
                "SCHED_FIFO priority {priority} not permitted ({}): running with normal scheduling, expect jitter",
                std::io::Error::from_raw_os_error(r)
            ));
        }
        if let Some(cpu) = cpu {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_SET(cpu, &mut set);
            if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) != 0 {
                warnings.push(format!(
                    "pinning to CPU {cpu} failed ({})",
                    std::io::Error::last_os_error()
                ));
            }
        }
    }
    warnings
}

/// Sets SCHED_FIFO at `priority` for the calling thread. Returns whether
/// it was permitted (refused: the thread keeps normal scheduling).
pub fn set_fifo_priority(priority: i32) -> bool {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: plain call on the current thread with a valid parameter.
    unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) == 0 }
}

/// The SCHED_FIFO priority of the calling thread, `None` when it runs
/// under another policy (normal scheduling).
pub fn fifo_priority() -> Option<i32> {
    let mut policy = 0;
    let mut param = libc::sched_param { sched_priority: 0 };
    // SAFETY: plain call on the current thread with valid out-pointers.
    let r = unsafe { libc::pthread_getschedparam(libc::pthread_self(), &mut policy, &mut param) };
    (r == 0 && policy == libc::SCHED_FIFO).then_some(param.sched_priority)
}

/// Returns the calling thread to normal scheduling (SCHED_OTHER). Always
/// permitted (lowering needs no privilege); returns whether it took.
pub fn set_normal_scheduling() -> bool {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: plain call on the current thread with a valid parameter.
    unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_OTHER, &param) == 0 }
}

/// The CPUs online (at least 1).
pub fn online_cpus() -> usize {
    // SAFETY: sysconf has no preconditions.
    let n = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) };
    usize::try_from(n).unwrap_or(1).max(1)
}

/// Lowers the calling thread's priority (nice 10) and, on a machine with
/// more than one CPU, keeps it off `cpu` (the loop's). Best effort: a
/// refusal leaves the thread as it was.
pub fn keep_off_cpu(cpu: Option<usize>) {
    let online = online_cpus();
    // SAFETY: plain syscalls on the calling thread with valid arguments.
    unsafe {
        libc::setpriority(libc::PRIO_PROCESS, 0, 10);
        if let (Some(cpu), true) = (cpu, online > 1) {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            for c in (0..online).filter(|c| *c != cpu) {
                libc::CPU_SET(c, &mut set);
            }
            libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set);
        }
    }
}

/// The PM QoS device.
pub const CPU_DMA_LATENCY_PATH: &str = "/dev/cpu_dma_latency";

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
    /// Opens [`CPU_DMA_LATENCY_PATH`] and writes 0 (a native-endian `s32`, as `cyclictest`
    /// does). Allocates (not on the tick).
    ///
    /// # Errors
    /// The open or write error: no such device (a container without it),
    /// or permission (the node is usually mode 0600, root only).
    pub fn hold() -> std::io::Result<Self> {
        let mut file = OpenOptions::new().write(true).open(CPU_DMA_LATENCY_PATH)?;
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

/// Bytes an unprivileged process may still write on the file system that
/// holds `path` (`statvfs(3)`: `f_bavail × f_frsize`).
///
/// # Errors
/// The OS error: `path` does not exist, or is not valid for the call.
pub fn available_bytes(path: &std::path::Path) -> std::io::Result<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes())
        .map_err(|_| std::io::Error::new(std::io::ErrorKind::InvalidInput, "a NUL in the path"))?;
    // SAFETY: statvfs is plain old data; zeroed is a valid value.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `c` is a valid NUL-terminated path, `st` a valid out-pointer.
    if unsafe { libc::statvfs(c.as_ptr(), &mut st) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    #[allow(clippy::unnecessary_cast)]
    Ok((st.f_bavail as u64).saturating_mul(st.f_frsize as u64))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Read;

    /// The kernel's current aggregate request, µs (reading the device gives
    /// it as an `s32`).
    fn current_us() -> Option<i32> {
        let mut b = [0u8; 4];
        File::open(CPU_DMA_LATENCY_PATH)
            .ok()?
            .read_exact(&mut b)
            .ok()?;
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
