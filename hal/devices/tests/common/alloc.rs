//! The one counting allocator of the hal test binary (a binary has one
//! global allocator): every allocation is counted on its own thread
//! ([`allocations_here`]), and, on threads that switched [`COUNT_HERE`] on,
//! also in the process-wide [`ALLOCATIONS`] (a loop thread's count read by
//! the test's thread).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

struct Counting;

thread_local! {
    /// This thread's allocations since it started.
    static HERE: Cell<u64> = const { Cell::new(0) };
    /// Whether this thread's allocations also go to [`ALLOCATIONS`].
    pub static COUNT_HERE: Cell<bool> = const { Cell::new(false) };
}

/// Allocations of the threads that set [`COUNT_HERE`].
pub static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

fn count_one() {
    // `try_with`: thread-locals may be gone during thread teardown.
    let _ = HERE.try_with(|c| c.set(c.get() + 1));
    if COUNT_HERE.try_with(|c| c.get()).unwrap_or(false) {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
    }
}

// SAFETY: forwards to the system allocator; the counters are const
// thread-local `Cell`s and an atomic (no allocation, no destructor).
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count_one();
        // SAFETY: the caller's contract.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller's contract.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count_one();
        // SAFETY: the caller's contract.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// This thread's allocations so far.
pub fn allocations_here() -> u64 {
    HERE.with(|c| c.get())
}
