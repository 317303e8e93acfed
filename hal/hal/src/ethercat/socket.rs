//! The raw Ethernet socket both sides use: `AF_PACKET`/`SOCK_RAW` bound to
//! one interface and EtherType 0x88A4, non-blocking; waits go through
//! [`crate::os::poll_until`]. Sending and receiving do not allocate.

use super::wire::ETHERTYPE;
use super::EthercatError;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};

/// `sll_pkttype` of a frame this host sent (the kernel loops outgoing
/// frames back to packet sockets).
const PACKET_OUTGOING: u8 = 4;

/// A raw EtherCAT socket on one interface.
#[derive(Debug)]
pub struct RawSocket {
    fd: OwnedFd,
}

impl RawSocket {
    /// Opens `interface` for EtherCAT frames.
    ///
    /// # Errors
    /// [`EthercatError::NotFound`] when the interface does not exist,
    /// [`EthercatError::Permission`] without `CAP_NET_RAW`,
    /// [`EthercatError::Io`] otherwise.
    pub fn open(interface: &str) -> Result<Self, EthercatError> {
        let name = std::ffi::CString::new(interface).map_err(|_| EthercatError::NotFound {
            interface: interface.into(),
            source: io::Error::from_raw_os_error(libc::EINVAL),
        })?;
        let proto = i32::from(ETHERTYPE.to_be());
        // SAFETY: plain socket(2) call.
        let raw = unsafe {
            libc::socket(
                libc::AF_PACKET,
                libc::SOCK_RAW | libc::SOCK_NONBLOCK | libc::SOCK_CLOEXEC,
                proto,
            )
        };
        if raw < 0 {
            let source = io::Error::last_os_error();
            return Err(match source.raw_os_error() {
                Some(libc::EPERM | libc::EACCES) => EthercatError::Permission {
                    interface: interface.into(),
                    source,
                },
                _ => EthercatError::Io {
                    op: "socket(AF_PACKET)",
                    source,
                },
            });
        }
        // SAFETY: `raw` is a fresh descriptor we own.
        let fd = unsafe { OwnedFd::from_raw_fd(raw) };
        // SAFETY: valid NUL-terminated name.
        let ifindex = unsafe { libc::if_nametoindex(name.as_ptr()) };
        if ifindex == 0 {
            return Err(EthercatError::NotFound {
                interface: interface.into(),
                source: io::Error::last_os_error(),
            });
        }
        // SAFETY: sockaddr_ll is plain data; zeroed is valid.
        let mut sa: libc::sockaddr_ll = unsafe { std::mem::zeroed() };
        sa.sll_family = libc::AF_PACKET as u16;
        sa.sll_protocol = ETHERTYPE.to_be();
        sa.sll_ifindex = ifindex as i32;
        // SAFETY: valid sockaddr_ll of the given size.
        let r = unsafe {
            libc::bind(
                fd.as_raw_fd(),
                (&sa as *const libc::sockaddr_ll).cast(),
                std::mem::size_of::<libc::sockaddr_ll>() as libc::socklen_t,
            )
        };
        if r < 0 {
            let source = io::Error::last_os_error();
            return Err(match source.raw_os_error() {
                Some(libc::ENODEV | libc::ENXIO) => EthercatError::NotFound {
                    interface: interface.into(),
                    source,
                },
                Some(libc::EPERM | libc::EACCES) => EthercatError::Permission {
                    interface: interface.into(),
                    source,
                },
                _ => EthercatError::Io {
                    op: "bind(AF_PACKET)",
                    source,
                },
            });
        }
        Ok(Self { fd })
    }

    /// The descriptor (to wait on).
    pub fn fd(&self) -> RawFd {
        self.fd.as_raw_fd()
    }

    /// Sends one Ethernet frame (header included) without blocking.
    ///
    /// # Errors
    /// The OS error (`EAGAIN`/`ENOBUFS` when the queue is full).
    pub fn send(&self, frame: &[u8]) -> io::Result<usize> {
        loop {
            // SAFETY: `frame` is valid for its length.
            let n = unsafe {
                libc::send(
                    self.fd(),
                    frame.as_ptr().cast(),
                    frame.len(),
                    libc::MSG_DONTWAIT,
                )
            };
            if n >= 0 {
                return Ok(n as usize);
            }
            let e = io::Error::last_os_error();
            if e.raw_os_error() != Some(libc::EINTR) {
                return Err(e);
            }
        }
    }

    /// Receives one frame sent by another station into `buf` without
    /// blocking: its length, `Ok(None)` when none is queued. Frames this
    /// host sent (looped back by the kernel) are skipped.
    ///
    /// # Errors
    /// The OS error.
    pub fn try_recv(&self, buf: &mut [u8]) -> io::Result<Option<usize>> {
        loop {
            // SAFETY: sockaddr_ll is plain data.
            let mut sa: libc::sockaddr_ll = unsafe { std::mem::zeroed() };
            let mut len = std::mem::size_of::<libc::sockaddr_ll>() as libc::socklen_t;
            // SAFETY: valid buffer and address storage.
            let n = unsafe {
                libc::recvfrom(
                    self.fd(),
                    buf.as_mut_ptr().cast(),
                    buf.len(),
                    libc::MSG_DONTWAIT,
                    (&mut sa as *mut libc::sockaddr_ll).cast(),
                    &mut len,
                )
            };
            if n >= 0 {
                if sa.sll_pkttype == PACKET_OUTGOING {
                    continue;
                }
                return Ok(Some(n as usize));
            }
            let e = io::Error::last_os_error();
            match e.raw_os_error() {
                Some(libc::EINTR) => continue,
                Some(libc::EAGAIN) => return Ok(None),
                _ => return Err(e),
            }
        }
    }

    /// Waits until a frame may be readable or `deadline_ns`
    /// (`CLOCK_MONOTONIC`) passes; `Ok(false)` on timeout.
    ///
    /// # Errors
    /// The OS error of the wait.
    pub fn wait(&self, deadline_ns: u64) -> io::Result<bool> {
        Ok(crate::os::poll_until(self.fd(), libc::POLLIN, deadline_ns)?.is_some())
    }
}
