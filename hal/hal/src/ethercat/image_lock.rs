//! [`BorrowFlag`]: the lock of the process image that never waits.
//!
//! ethercrab keeps a group's process image behind a
//! `lock_api::RwLock<R, _>`, generic over the raw lock `R`; its default
//! (`ethercrab::DefaultLock`, a spin `RwLock` with `spin::Yield`) spins
//! and calls `sched_yield` when contended. The stage gives its group this
//! one instead: one atomic word used as a borrow flag, like a `RefCell`'s.
//! Only the loop thread touches the image (the stage is not `Sync`; the
//! tick copies the outputs in, runs `tx_rx`, copies the inputs out, each
//! borrow ending before the next begins), so an acquisition always
//! succeeds at once. If one ever found the image borrowed, that would be
//! a logic error in the stage: it panics naming the lock, never spins,
//! yields or parks.

use core::sync::atomic::{AtomicUsize, Ordering};
use lock_api::{GuardSend, RawRwLock};

/// The exclusive bit of the flag; below it, the number of shared borrows.
const EXCLUSIVE: usize = 1 << (usize::BITS - 1);

/// A `lock_api::RawRwLock` that never waits: shared or exclusive
/// acquisition succeeds at once or panics (see the [module docs](self)).
/// Real-time safe: one atomic read-modify-write per acquisition and one
/// per release, no system call.
#[derive(Debug)]
pub struct BorrowFlag(AtomicUsize);

impl BorrowFlag {
    /// The image was found borrowed: a logic error, said loudly.
    #[cold]
    #[track_caller]
    fn contended(what: &str, state: usize) -> ! {
        panic!(
            "the EtherCAT process image's BorrowFlag was asked for a {what} borrow while {}: \
             only the loop thread may touch the image, one borrow at a time (a logic error in the stage)",
            if state & EXCLUSIVE != 0 {
                "exclusively borrowed".to_string()
            } else {
                format!("{state} shared borrow(s) were held")
            }
        )
    }
}

// SAFETY: the flag gives an exclusive borrow only when no borrow is held
// (compare-exchange from 0) and a shared one only when no exclusive borrow
// is held (the increment is undone if the exclusive bit was set); Acquire
// on taking and Release on giving back order the image's accesses.
unsafe impl RawRwLock for BorrowFlag {
    #[allow(clippy::declare_interior_mutable_const)]
    const INIT: Self = Self(AtomicUsize::new(0));

    type GuardMarker = GuardSend;

    fn lock_shared(&self) {
        if !self.try_lock_shared() {
            Self::contended("shared", self.0.load(Ordering::Relaxed));
        }
    }

    fn try_lock_shared(&self) -> bool {
        let before = self.0.fetch_add(1, Ordering::Acquire);
        if before & EXCLUSIVE != 0 {
            self.0.fetch_sub(1, Ordering::Relaxed);
            return false;
        }
        true
    }

    unsafe fn unlock_shared(&self) {
        self.0.fetch_sub(1, Ordering::Release);
    }

    fn lock_exclusive(&self) {
        if !self.try_lock_exclusive() {
            Self::contended("exclusive", self.0.load(Ordering::Relaxed));
        }
    }

    fn try_lock_exclusive(&self) -> bool {
        self.0
            .compare_exchange(0, EXCLUSIVE, Ordering::Acquire, Ordering::Relaxed)
            .is_ok()
    }

    unsafe fn unlock_exclusive(&self) {
        self.0.store(0, Ordering::Release);
    }

    fn is_locked(&self) -> bool {
        self.0.load(Ordering::Relaxed) != 0
    }

    fn is_locked_exclusive(&self) -> bool {
        self.0.load(Ordering::Relaxed) & EXCLUSIVE != 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type Image = lock_api::RwLock<BorrowFlag, [u8; 4]>;

    #[test]
    fn borrows_in_turn_succeed_and_nest_only_when_shared() {
        let image = Image::new([0; 4]);
        image.write()[0] = 7;
        {
            let a = image.read();
            let b = image.read();
            assert_eq!(a[0] + b[0], 14);
            assert!(image.try_write().is_none());
        }
        image.write()[1] = 1;
        assert_eq!(*image.read(), [7, 1, 0, 0]);
        assert!(!image.is_locked());
    }

    #[test]
    fn a_borrow_of_a_borrowed_image_panics_at_once_naming_the_flag() {
        let image = Image::new([0; 4]);
        let _w = image.write();
        let err = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let _r = image.read();
        }))
        .unwrap_err();
        let msg = err.downcast_ref::<String>().unwrap();
        assert!(
            msg.contains("BorrowFlag") && msg.contains("exclusively borrowed"),
            "{msg}"
        );
        // A failed shared attempt leaves the exclusive borrow intact.
        assert!(image.is_locked_exclusive());
        let err = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let _w2 = image.write();
        }))
        .unwrap_err();
        assert!(err
            .downcast_ref::<String>()
            .unwrap()
            .contains("exclusive borrow"));
    }
}
