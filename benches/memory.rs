//! Heap held per tick by the default chirp (issue 16: at most 20 bytes a
//! tick for the FRF).
//!
//! A counting global allocator tracks the bytes live and their peak. Two
//! figures, each the peak above what was live before, divided by the
//! record's ticks:
//! - **FRF**: the record as the writer collects it (reserved up front,
//!   packed excitation + i·position, 16 bytes a tick), the transform in its
//!   memory, the kept band and the estimate on the grid;
//! - **whole run**: `run_chirp` end to end in virtual time (loop, queue,
//!   recorder, FRF, modal fit, plot).
//!
//! Run with `cargo bench --bench memory`; the figures are deterministic
//! (allocation sizes, not times).

mod common;

use bench::ident::chirp::Chirp;
use bench::ident::frf::{fast_len, Frf, Spectra, C64};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

fn grew(n: usize) {
    let now = LIVE.fetch_add(n, Ordering::Relaxed) + n;
    PEAK.fetch_max(now, Ordering::Relaxed);
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        grew(l.size());
        unsafe { System.alloc(l) }
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        grew(l.size());
        unsafe { System.alloc_zeroed(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        LIVE.fetch_sub(l.size(), Ordering::Relaxed);
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        // Counted as the allocator sees it: old and new both live while a
        // moving realloc copies (a shrink in place frees without a peak).
        if new > l.size() {
            grew(new - l.size());
        } else {
            LIVE.fetch_sub(l.size() - new, Ordering::Relaxed);
        }
        unsafe { System.realloc(p, l, new) }
    }
}

#[global_allocator]
static A: Counting = Counting;

/// Peak bytes above the live bytes at the start, while `f` runs.
fn peak_of<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let out = f();
    (out, PEAK.load(Ordering::Relaxed) - base)
}

fn main() {
    let (config, _) = common::shipped();
    let period_s = 1.0 / config.loop_.rate_hz;
    let chirp = Chirp::new(&config.chirp, config.excitation.kind, period_s);
    let n = chirp.total_ticks() as usize;

    // The FRF: a record with the default chirp's excitation and a response
    // of the same length (the figures do not depend on the values).
    let ((), frf_peak) = peak_of(|| {
        let mut record: Vec<C64> = Vec::with_capacity(fast_len(n));
        for k in 0..n {
            let u = chirp.value_a(k as u64);
            record.push(C64::new(u, 1e-6 * u + 1e-9 * (k as f64).sin()));
        }
        let spectra = Spectra::from_record(
            record,
            config.loop_.rate_hz,
            &config.identification,
            config.chirp.f_end_hz,
        );
        let frf = Frf::estimate(
            &spectra,
            config.chirp.f_start_hz,
            config.chirp.f_end_hz,
            &config.identification,
        );
        std::hint::black_box(frf);
    });

    let dir = tempfile::tempdir().unwrap();
    let opts = common::default_chirp(dir.path());
    let (summary, run_peak) = peak_of(|| common::run(&opts));
    assert_eq!(summary.timing.ticks as usize, n, "the run's ticks");

    let per = |b: usize| b as f64 / n as f64;
    println!("default chirp, {n} ticks (FFT length {})", fast_len(n));
    println!(
        "FRF (record, transform, band, grid): peak {:.2} MB = {:.1} B/tick (target <= 20)",
        frf_peak as f64 / 1e6,
        per(frf_peak)
    );
    println!(
        "whole run (loop, recorder, FRF, fit, plot): peak {:.2} MB = {:.1} B/tick",
        run_peak as f64 / 1e6,
        per(run_peak)
    );
}
