//! Local jobs (`bench chirp`, `bench control`) run on a worker thread, so
//! that SIGINT/SIGTERM stay effective while the job is being prepared
//! (model, loop check, outputs): the main thread watches the stop flag
//! and the loop's tick count.

use super::status;
use bench::error::RunError;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

/// How long a job that has not reached its loop yet (no tick run) is given
/// after SIGINT/SIGTERM to get there or to return, before the run ends
/// with status 130 without it. Once the loop runs, the loop itself stops
/// the job safely (0 A, recording finished) and nothing is cut short.
const PREPARATION_STOP_GRACE: Duration = Duration::from_millis(200);

/// Runs `job` on a worker thread; `job` gets `stop` and the counter the
/// loop sets to its tick count. A SIGINT/SIGTERM (`stop`) while the loop has run no
/// tick ends the run with status 130 after [`PREPARATION_STOP_GRACE`]:
/// the preparation is abandoned with the process, nothing was enabled.
/// The test hook [`bench::daemon::testing::prepare_hang_hook`] runs first
/// on the worker.
///
/// # Errors
/// The exit status when the run was interrupted during its preparation,
/// or the worker panicked.
pub(super) fn run_job<T: Send + 'static>(
    stop: Arc<AtomicBool>,
    job: impl FnOnce(Arc<AtomicBool>, Arc<AtomicU64>) -> Result<T, RunError> + Send + 'static,
) -> Result<Result<T, RunError>, ExitCode> {
    let ticks = Arc::new(AtomicU64::new(0));
    let (tx, rx) = mpsc::channel();
    let (worker_stop, worker_ticks) = (Arc::clone(&stop), Arc::clone(&ticks));
    let spawned = std::thread::Builder::new()
        .name("bench-job".into())
        .spawn(move || {
            bench::daemon::testing::prepare_hang_hook();
            let _ = tx.send(job(worker_stop, worker_ticks));
        });
    if let Err(e) = spawned {
        errln!("error: cannot start the job thread: {e}");
        return Err(ExitCode::from(status::ERROR));
    }
    let mut stopped_at: Option<Instant> = None;
    loop {
        match rx.recv_timeout(Duration::from_millis(10)) {
            Ok(r) => return Ok(r),
            Err(mpsc::RecvTimeoutError::Disconnected) => {
                errln!("error: the job thread panicked");
                return Err(ExitCode::from(status::ERROR));
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
        }
        if stop.load(Ordering::Relaxed) {
            let at = *stopped_at.get_or_insert_with(Instant::now);
            if ticks.load(Ordering::Relaxed) == 0 && at.elapsed() >= PREPARATION_STOP_GRACE {
                errln!("error: interrupted while the job was being prepared; nothing was enabled, no recording");
                return Err(ExitCode::from(status::INTERRUPTED));
            }
        }
    }
}
