//! ethercrab's PDU loop on the caller's thread: the storage and its
//! parts (split once per process, pooled between stages), [`Link`] (the
//! raw socket and the TX/RX ends) and its [`Link::block_on`].

use super::*;

/// Frames in flight (ethercrab's PDU storage slots).
pub(super) const FRAMES: usize = 4;
/// Largest PDU payload of one frame, bytes.
pub(super) const PDU_DATA: usize = PduStorage::element_size(256);
/// The group's process image, bytes (both directions).
pub(super) const MAX_PDI: usize = 2 * MAX_PDO_BYTES;

static STORAGE: PduStorage<FRAMES, PDU_DATA> = PduStorage::new();

/// ethercrab's PDU loop parts: split once per process, handed back when a
/// stage is dropped so the next one reuses them.
pub(super) struct Parts {
    pub(super) tx: PduTx<'static>,
    pub(super) rx: PduRx<'static>,
    pub(super) pdu_loop: PduLoop<'static>,
}

pub(super) static POOL: Mutex<Option<Parts>> = Mutex::new(None);

pub(super) fn take_parts() -> Result<Parts, EthercatError> {
    let mut pool = POOL.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(p) = pool.take() {
        return Ok(p);
    }
    let (tx, rx, pdu_loop) = STORAGE.try_split().map_err(|()| EthercatError::Busy)?;
    Ok(Parts { tx, rx, pdu_loop })
}

/// The raw socket and ethercrab's TX/RX ends, driven on the caller's
/// thread.
pub(super) struct Link {
    pub(super) sock: RawSocket,
    /// Handed back to the pool on drop.
    pub(super) ends: Option<(PduTx<'static>, PduRx<'static>)>,
    pub(super) buf: [u8; 1600],
}

/// Why [`Link::block_on`] gave up.
#[derive(Debug)]
pub(super) enum Stall {
    Deadline,
    Io(std::io::Error),
}

impl Link {
    /// Polls `fut` to completion, sending the frames it queues and feeding
    /// back the answers, until `deadline_ns`; when nothing arrives it
    /// sleeps on the socket at most `step_ns` before polling again (the
    /// futures' own timers are polled, not woken). Dropping the future on
    /// the deadline releases its frame. Allocates nothing.
    pub(super) fn block_on<F: Future>(
        &mut self,
        fut: F,
        deadline_ns: u64,
        step_ns: u64,
    ) -> Result<F::Output, Stall> {
        let mut fut = pin!(fut);
        let mut cx = Context::from_waker(Waker::noop());
        let Some((tx, rx)) = self.ends.as_mut() else {
            return Err(Stall::Io(std::io::Error::from_raw_os_error(libc::EBADF)));
        };
        loop {
            if let Poll::Ready(v) = fut.as_mut().poll(&mut cx) {
                return Ok(v);
            }
            while let Some(frame) = tx.next_sendable_frame() {
                let sock = &self.sock;
                let mut os_err = None;
                let r = frame.send_blocking(|d| match sock.send(d) {
                    Ok(n) => Ok(n),
                    Err(e) => {
                        os_err = Some(e);
                        Err(ethercrab::error::Error::SendFrame)
                    }
                });
                if r.is_err() {
                    return Err(Stall::Io(
                        os_err.unwrap_or_else(|| std::io::Error::from_raw_os_error(libc::EIO)),
                    ));
                }
            }
            let mut got = false;
            while let Some(n) = self.sock.try_recv(&mut self.buf).map_err(Stall::Io)? {
                // Frames that are not answers to ours are ignored.
                let _ = rx.receive_frame(&self.buf[..n]);
                got = true;
            }
            if got {
                continue;
            }
            let now = monotonic_ns();
            if now >= deadline_ns {
                return Err(Stall::Deadline);
            }
            self.sock
                .wait(deadline_ns.min(now.saturating_add(step_ns)))
                .map_err(Stall::Io)?;
        }
    }
}
