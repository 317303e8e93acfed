//! What the machine itself does to a real-time thread: one SCHED_FIFO
//! thread pinned to each CPU, waking on absolute 2 ms deadlines, records
//! the longest it woke late. A test of a real-time job uses it to tell a
//! stall the machine made (a virtual machine whose vCPU the host did not
//! run: measured here at 20–120 ms every few tens of seconds, at any
//! load, on both vCPUs of the CI machine) from one the code under test
//! made, which the watch does not see.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

/// The watch's period, ns: coarse enough to add no load worth naming,
/// fine enough to see a stall of a few ms.
const PERIOD_NS: u64 = 2_000_000;

/// One watch thread per online CPU (see the module doc); [`Self::stop`]
/// gives the longest lateness any of them saw.
pub struct HostStallWatch {
    stop: Arc<AtomicBool>,
    worst_ns: Arc<AtomicU64>,
    threads: Vec<JoinHandle<()>>,
}

impl HostStallWatch {
    /// Starts the watch at SCHED_FIFO `priority` (one below the loop's, so
    /// the loop is never delayed by it; without permission the threads run
    /// normally and see more).
    pub fn start(priority: i32) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let worst_ns = Arc::new(AtomicU64::new(0));
        let threads = (0..bench_hal::os::online_cpus())
            .map(|cpu| {
                let (stop, worst_ns) = (stop.clone(), worst_ns.clone());
                std::thread::spawn(move || {
                    // SAFETY: a zeroed cpu_set_t is valid; plain calls on
                    // the current thread.
                    unsafe {
                        let mut set: libc::cpu_set_t = std::mem::zeroed();
                        libc::CPU_SET(cpu, &mut set);
                        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set);
                    }
                    bench_hal::os::set_fifo_priority(priority);
                    let mut deadline = bench_hal::os::monotonic_ns();
                    while !stop.load(Ordering::Relaxed) {
                        deadline += PERIOD_NS;
                        bench_hal::os::sleep_until_ns(deadline);
                        let now = bench_hal::os::monotonic_ns();
                        worst_ns.fetch_max(now.saturating_sub(deadline), Ordering::Relaxed);
                        // After a stall, the next deadline from now (no
                        // burst of catch-up wakes).
                        deadline = deadline.max(now);
                    }
                })
            })
            .collect();
        Self {
            stop,
            worst_ns,
            threads,
        }
    }

    /// Stops the watch; the longest lateness it saw, s.
    pub fn stop(self) -> f64 {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads {
            let _ = t.join();
        }
        self.worst_ns.load(Ordering::Relaxed) as f64 * 1e-9
    }
}
