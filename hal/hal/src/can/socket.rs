//! Socket primitives: non-blocking, no allocation, deadlines on
//! `CLOCK_MONOTONIC` ([`crate::os`]). Used by the host stage and by the
//! CAN emulator.

use super::CanError;
use crate::os::{monotonic_ns, sleep_until_ns};
use socketcan::frame::can_frame_default;
use socketcan::{CanFrame, CanSocket, Socket};
use std::io;
use std::os::fd::RawFd;

/// One datagram read from the socket.
pub enum Rx {
    /// A classic CAN frame (data, remote or error).
    Frame(CanFrame),
    /// A datagram of the wrong size (not a classic CAN frame).
    Bad(usize),
}

/// The OS error number of `e` (0 when it carries none).
pub fn errno(e: &io::Error) -> i32 {
    e.raw_os_error().unwrap_or(0)
}

/// Waits until the socket is readable (`POLLIN`) or writable (`POLLOUT`),
/// or `deadline_ns` passes. `Ok(false)` on timeout.
pub fn wait_fd(fd: RawFd, events: libc::c_short, deadline_ns: u64) -> io::Result<bool> {
    Ok(crate::os::poll_until(fd, events, deadline_ns)?.is_some())
}

/// Reads one datagram without blocking; `Ok(None)` when none is queued.
pub fn try_recv(fd: RawFd) -> io::Result<Option<Rx>> {
    let mut frame = can_frame_default();
    let size = std::mem::size_of::<libc::can_frame>();
    loop {
        // SAFETY: `frame` is a plain C struct of `size` bytes.
        let n = unsafe {
            libc::recv(
                fd,
                (&mut frame as *mut libc::can_frame).cast(),
                size,
                libc::MSG_DONTWAIT,
            )
        };
        if n >= 0 {
            let n = n as usize;
            return Ok(Some(if n == size {
                Rx::Frame(CanFrame::from(frame))
            } else {
                Rx::Bad(n)
            }));
        }
        let e = io::Error::last_os_error();
        match errno(&e) {
            libc::EINTR => continue,
            libc::EAGAIN => return Ok(None),
            _ => return Err(e),
        }
    }
}

/// Sends one frame without blocking.
pub fn try_send(fd: RawFd, frame: &libc::can_frame) -> io::Result<()> {
    let size = std::mem::size_of::<libc::can_frame>();
    loop {
        // SAFETY: `frame` is a fully initialised C struct of `size` bytes.
        let n = unsafe {
            libc::send(
                fd,
                (frame as *const libc::can_frame).cast(),
                size,
                libc::MSG_DONTWAIT | libc::MSG_NOSIGNAL,
            )
        };
        if n >= 0 {
            return Ok(());
        }
        let e = io::Error::last_os_error();
        if errno(&e) != libc::EINTR {
            return Err(e);
        }
    }
}

/// Whether `e` says the transmit queue is full (`EAGAIN`, `ENOBUFS`).
pub fn queue_full(e: &io::Error) -> bool {
    matches!(errno(e), libc::EAGAIN | libc::ENOBUFS)
}

/// Sends one frame, retrying while the transmit queue is full until
/// `deadline_ns`.
pub fn send_until(fd: RawFd, frame: &libc::can_frame, deadline_ns: u64) -> Result<(), CanError> {
    loop {
        match try_send(fd, frame) {
            Ok(()) => return Ok(()),
            Err(e) if queue_full(&e) => {
                let now = monotonic_ns();
                if now >= deadline_ns {
                    return Err(CanError::TxFull);
                }
                // ENOBUFS is not pollable: short sleeps.
                sleep_until_ns(deadline_ns.min(now + 100_000));
            }
            Err(source) => return Err(CanError::Io { op: "send", source }),
        }
    }
}

/// Sets a socket option that only a real CAN_RAW socket has. On another
/// socket (a Unix datagram pair in tests) the option does not exist and is
/// skipped: `Ok(false)`.
pub fn can_option(r: io::Result<()>, op: &'static str) -> Result<bool, CanError> {
    match r {
        Ok(()) => Ok(true),
        Err(e) if matches!(errno(&e), libc::ENOPROTOOPT | libc::EOPNOTSUPP) => Ok(false),
        Err(source) => Err(CanError::Io { op, source }),
    }
}

/// Opens a raw CAN socket on `interface` (for
/// the CAN emulator, `bench_devices::emulator::can::run_emulator`; the stage
/// opens its own with [`CanStage::open`](super::CanStage::open)).
///
/// # Errors
/// `NotFound` naming the interface when it does not exist (or the kernel
/// has no SocketCAN), `Link` for other socket errors.
pub fn open_socket(interface: &str) -> Result<CanSocket, CanError> {
    CanSocket::open(interface).map_err(|source| match errno(&source) {
        libc::ENODEV | libc::ENXIO | libc::EAFNOSUPPORT | libc::EPROTONOSUPPORT => {
            CanError::NotFound {
                interface: interface.into(),
                source,
            }
        }
        _ => CanError::Io { op: "open", source },
    })
}
