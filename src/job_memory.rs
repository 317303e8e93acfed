//! Memory budgets for the daemon's jobs that compute: a counting global
//! allocator ([`BudgetAllocator`], installed by the `bench` binary) and
//! the budget a thread allocates against ([`JobMemory`]). A leaf: it uses
//! only `std`.
//!
//! A thread cannot be killed and an allocation cannot fail cleanly in
//! Rust (a null from the allocator aborts the process, and an allocator
//! must not unwind), so a job that goes over its budget is **parked**: the
//! allocation that would take it over never happens, its thread sleeps for
//! ever inside the allocator, holding what it had (at most its budget plus
//! [`SMALL_SLACK_FRACTION`] of it), and [`JobMemory::over_budget`] tells
//! the daemon, which fails the job and frees its slot. What the job
//! allocated stays allocated until the daemon restarts; the daemon admits
//! a new job only while that, plus the new job's budget, fits in half its
//! memory limit ([`memory_limit_bytes`]).
//!
//! Only threads that [`JobMemory::enter`]ed a budget are counted; the
//! others (the loop, the socket, the owner) pay one thread-local read per
//! allocation. Memory freed on another thread than the one that allocated
//! it is credited to that other thread's budget (if any): a job's figure
//! is what its threads allocated less what they freed.
//!
//! Layer rule: may use nothing of the crate.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, Ordering};
use std::sync::Arc;

/// An allocation of at least this many bytes that would take a job over
/// its budget parks the job's thread at once. A smaller one is let
/// through until the job is [`SMALL_SLACK_FRACTION`] over: the
/// library code under a job (the standard library, logging) takes locks
/// around small allocations only, and a thread parked holding a lock the
/// daemon needs would wedge it.
pub const PARK_MIN_BYTES: usize = 64 * 1024;

/// How far over its budget small allocations may take a job before its
/// thread is parked anyway: this fraction of the budget.
pub const SMALL_SLACK_FRACTION: u64 = 8;

/// The share of the daemon's memory limit one job may allocate: a
/// quarter (the daemon's owner divides [`memory_limit_bytes`] by it).
pub const JOB_SHARE_DIVISOR: u64 = 4;

/// A budget and what its threads hold.
#[derive(Debug)]
struct Budget {
    /// Bytes allocated less bytes freed by the threads that entered it.
    live: AtomicI64,
    /// The budget, bytes.
    limit: i64,
    /// The size of the first allocation refused (0: none).
    refused: AtomicU64,
}

/// A job's memory budget, shared by the threads that [`enter`](Self::enter)
/// it. Cloning shares it.
#[derive(Debug, Clone)]
pub struct JobMemory(Arc<Budget>);

thread_local! {
    /// The budget of this thread (null: not counted). Const-initialised
    /// and without a destructor, so the allocator can read it at any time,
    /// thread teardown included, without allocating.
    static CURRENT: Cell<*const Budget> = const { Cell::new(std::ptr::null()) };
}

/// Set by the allocator's first call: [`BudgetAllocator`] is the global
/// allocator of this process.
static INSTALLED: AtomicBool = AtomicBool::new(false);

impl JobMemory {
    /// A budget of `limit_bytes`.
    pub fn new(limit_bytes: u64) -> Self {
        Self(Arc::new(Budget {
            live: AtomicI64::new(0),
            limit: i64::try_from(limit_bytes).unwrap_or(i64::MAX),
            refused: AtomicU64::new(0),
        }))
    }

    /// Counts this thread's allocations against the budget until the
    /// guard is dropped (on this thread). A thread counted already is
    /// moved to this budget.
    pub fn enter(&self) -> Entered {
        attach(self);
        Entered(std::marker::PhantomData)
    }

    /// The budget, bytes.
    pub fn limit_bytes(&self) -> u64 {
        self.0.limit as u64
    }

    /// What the budget's threads hold now, bytes (allocated less freed; 0
    /// when they freed more than they allocated).
    pub fn live_bytes(&self) -> u64 {
        self.0.live.load(Ordering::Relaxed).max(0) as u64
    }

    /// The size of the allocation that took the job over its budget, bytes
    /// (`None` while it is within it). Its thread is parked for ever, or
    /// will be at its next allocation of [`PARK_MIN_BYTES`] or more.
    pub fn over_budget(&self) -> Option<u64> {
        match self.0.refused.load(Ordering::Acquire) {
            0 => None,
            n => Some(n),
        }
    }

    /// The budget of this thread, if it entered one (for a thread it
    /// starts to [`enter`](Self::enter) too).
    pub fn current() -> Option<Self> {
        let p = CURRENT.with(Cell::get);
        if p.is_null() {
            return None;
        }
        // SAFETY: `p` came from `Arc::into_raw` in `attach` and this
        // thread holds that count until `detach`; one more count for the
        // clone returned.
        unsafe {
            Arc::increment_strong_count(p);
            Some(Self(Arc::from_raw(p)))
        }
    }

    /// Counts the calling thread against this budget until [`detach`] is
    /// called on it (for threads started by a pool, whose start and exit
    /// handlers cannot hold a guard).
    pub fn attach_thread(&self) {
        attach(self);
    }
}

/// Stops counting the calling thread (see [`JobMemory::attach_thread`]).
pub fn detach_thread() {
    detach();
}

/// Whether [`BudgetAllocator`] is this process's global allocator (it
/// has allocated once). Budgets count nothing without it.
pub fn installed() -> bool {
    INSTALLED.load(Ordering::Relaxed)
}

fn attach(m: &JobMemory) {
    detach();
    let p = Arc::into_raw(Arc::clone(&m.0));
    CURRENT.with(|c| c.set(p));
}

fn detach() {
    let p = CURRENT.with(|c| c.replace(std::ptr::null()));
    if !p.is_null() {
        // SAFETY: the count `attach` took with `Arc::into_raw`.
        drop(unsafe { Arc::from_raw(p) });
    }
}

/// A thread counted against a [`JobMemory`] until this is dropped.
#[must_use = "the thread is counted until the guard is dropped"]
pub struct Entered(std::marker::PhantomData<*const ()>);

impl Drop for Entered {
    fn drop(&mut self) {
        detach();
    }
}

/// The global allocator of the `bench` binary: the system allocator,
/// counting the allocations of threads that entered a [`JobMemory`]
/// against it, and parking such a thread instead of letting it go over
/// (see the module). Real-time safe as the system allocator is (one
/// thread-local read and, on a counted thread, one atomic add more); the
/// loop's tick allocates nothing anyway.
#[derive(Debug, Default)]
pub struct BudgetAllocator;

/// Charges `size` bytes to the calling thread's budget, parking the
/// thread instead when it would go over (see the module).
#[inline]
fn charge(size: usize) {
    let p = CURRENT.with(Cell::get);
    if p.is_null() {
        return;
    }
    // SAFETY: `attach` keeps the budget alive while this thread points at
    // it.
    let b = unsafe { &*p };
    let size = i64::try_from(size).unwrap_or(i64::MAX);
    let live = b
        .live
        .fetch_add(size, Ordering::Relaxed)
        .saturating_add(size);
    if live <= b.limit {
        return;
    }
    let _ = b
        .refused
        .compare_exchange(0, size.max(1) as u64, Ordering::AcqRel, Ordering::Relaxed);
    let slack = b.limit / SMALL_SLACK_FRACTION as i64;
    if size as usize >= PARK_MIN_BYTES || live > b.limit.saturating_add(slack) {
        b.live.fetch_sub(size, Ordering::Relaxed);
        // Sleeping allocates nothing; this thread never returns.
        loop {
            std::thread::sleep(std::time::Duration::from_secs(3600));
        }
    }
}

#[inline]
fn credit(size: usize) {
    let p = CURRENT.with(Cell::get);
    if !p.is_null() {
        // SAFETY: as in `charge`.
        let b = unsafe { &*p };
        b.live
            .fetch_sub(i64::try_from(size).unwrap_or(i64::MAX), Ordering::Relaxed);
    }
}

// SAFETY: every block comes from `System` with the caller's layout and
// goes back to it with the same; the counting neither allocates nor
// unwinds (a thread over its budget sleeps instead of returning).
unsafe impl GlobalAlloc for BudgetAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if !INSTALLED.load(Ordering::Relaxed) {
            INSTALLED.store(true, Ordering::Relaxed);
        }
        charge(layout.size());
        // SAFETY: the caller's contract, passed on.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        charge(layout.size());
        // SAFETY: the caller's contract, passed on.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        credit(layout.size());
        // SAFETY: the caller's contract, passed on.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let old = layout.size();
        if new_size > old {
            charge(new_size - old);
        }
        // SAFETY: the caller's contract, passed on.
        let q = unsafe { System.realloc(ptr, layout, new_size) };
        if new_size < old && !q.is_null() {
            credit(old - new_size);
        }
        q
    }
}

/// The memory this process may use, bytes: the smaller of the machine's
/// (`MemTotal` of `/proc/meminfo`) and the limit of every memory cgroup
/// it is in, up to the root (cgroup v2 `memory.max`, v1
/// `memory.limit_in_bytes`). Read each time (the process may be moved
/// into a cgroup while it runs); `u64::MAX` when nothing can be read.
pub fn memory_limit_bytes() -> u64 {
    let mut limit = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("MemTotal:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        })
        .map_or(u64::MAX, |kib| kib.saturating_mul(1024));
    let Ok(groups) = std::fs::read_to_string("/proc/self/cgroup") else {
        return limit;
    };
    for line in groups.lines() {
        // `ID:CONTROLLERS:PATH`: v2 is `0::PATH`, v1 memory `N:memory:PATH`.
        let mut f = line.splitn(3, ':');
        let (Some(_), Some(controllers), Some(path)) = (f.next(), f.next(), f.next()) else {
            continue;
        };
        let (root, file) = if controllers.is_empty() {
            ("/sys/fs/cgroup", "memory.max")
        } else if controllers.split(',').any(|c| c == "memory") {
            ("/sys/fs/cgroup/memory", "memory.limit_in_bytes")
        } else {
            continue;
        };
        let mut dir = std::path::PathBuf::from(root);
        dir.push(path.trim_start_matches('/'));
        loop {
            if let Some(v) = std::fs::read_to_string(dir.join(file))
                .ok()
                .and_then(|s| s.trim().parse::<u64>().ok())
            {
                limit = limit.min(v);
            }
            if dir.as_os_str().len() <= root.len() || !dir.pop() {
                break;
            }
        }
    }
    limit
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_limit_is_at_most_the_machines() {
        let l = memory_limit_bytes();
        assert!(l > 16 << 20, "{l}");
    }

    #[test]
    fn a_budget_is_shared_by_clones_and_left_on_drop() {
        let m = JobMemory::new(1 << 30);
        assert!(JobMemory::current().is_none());
        {
            let _g = m.enter();
            let c = JobMemory::current().expect("entered");
            assert!(Arc::ptr_eq(&c.0, &m.0));
        }
        assert!(JobMemory::current().is_none());
        assert_eq!(m.over_budget(), None);
    }
}
