//! Test-only hooks. Nothing here is for operators; the README's test
//! section lists them.
//!
//! - [`PREPARE_HANG_ENV`]: with `BENCH_TEST_PREPARE_HANG=1` in its
//!   environment, every job preparation (a `bench serve` job, a local
//!   `bench chirp|control`) hangs for ever at its start, before anything
//!   is checked, opened or enabled. It stands in for a preparation that
//!   never returns (an eigenvalue iteration on an absurd model), so the
//!   tests can show that `stop`, `status` and signals stay effective
//!   whatever the maths does.
//! - [`ALLOCATE_JOB_ENV`]: with `BENCH_TEST_ALLOCATE_JOB=KIND` (a job
//!   kind, `analyze`…) in its environment, every `bench serve` job of that
//!   kind allocates (and writes) 16 MiB blocks without end at its start.
//!   It stands in for a job whose memory grows without bound (a file read
//!   to its end, an absurd grid), so the tests can show that the job's
//!   memory budget fails the job and not the daemon.

/// The environment variable of the preparation-hang hook (test only):
/// `1` makes job preparation hang for ever.
pub const PREPARE_HANG_ENV: &str = "BENCH_TEST_PREPARE_HANG";

/// Called once at the start of each job's preparation: hangs for ever
/// (sleeping, not spinning) when [`PREPARE_HANG_ENV`] is `1`, else returns
/// at once. Test only.
#[doc(hidden)]
pub fn prepare_hang_hook() {
    if std::env::var_os(PREPARE_HANG_ENV).is_some_and(|v| v == "1") {
        tracing::warn!("{PREPARE_HANG_ENV}=1: this job's preparation hangs for ever (test hook)");
        loop {
            std::thread::sleep(std::time::Duration::from_secs(3600));
        }
    }
}

/// The environment variable of the allocation hook (test only): a job
/// kind, whose daemon jobs then allocate without end.
pub const ALLOCATE_JOB_ENV: &str = "BENCH_TEST_ALLOCATE_JOB";

/// Called once at the start of each daemon job, with its kind: allocates
/// and writes 16 MiB blocks for ever (until the job's memory budget parks
/// the thread) when [`ALLOCATE_JOB_ENV`] names `kind`, else returns at
/// once. Test only.
#[doc(hidden)]
pub fn allocate_hook(kind: &str) {
    if std::env::var_os(ALLOCATE_JOB_ENV).is_some_and(|v| v == kind) {
        tracing::warn!("{ALLOCATE_JOB_ENV}={kind}: this job allocates without end (test hook)");
        let mut held: Vec<Vec<u8>> = Vec::new();
        loop {
            held.push(vec![1u8; 16 << 20]);
            std::hint::black_box(&held);
        }
    }
}
