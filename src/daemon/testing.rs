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
