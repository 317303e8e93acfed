//! The command line's standard output. A reader that goes away (`bench …
//! | head`) or a full disk must not panic the process in the middle of a
//! run, nor stop the work it prints about (a campaign goes on, its
//! recordings and journal are complete); nor may a standard error that
//! cannot be written (`errln!` ignores its failures). `outln!` (defined in `cli/mod.rs`) writes
//! to stdout and, on the first failed write, stops printing and remembers
//! the error, which [`status`] turns into the exit status once the command
//! is done.

use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::OnceLock;

static FAILED: AtomicBool = AtomicBool::new(false);
static ERROR: OnceLock<std::io::Error> = OnceLock::new();

/// Writes `args` to stdout (locked, so a line is never interleaved); after
/// a failed write, nothing more is written.
pub fn write(args: std::fmt::Arguments<'_>) {
    if FAILED.load(Ordering::Relaxed) {
        return;
    }
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_fmt(args).and_then(|()| out.flush()) {
        FAILED.store(true, Ordering::Relaxed);
        let _ = ERROR.set(e);
    }
}

/// Writes `args` to stderr, ignoring failures (`errln!`). `eprintln!`
/// panics when stderr cannot be written, and the panic's exit 101 would
/// hide the command's own status (a fault's 3) behind a full disk under a
/// log.
pub fn write_err(args: std::fmt::Arguments<'_>) {
    let _ = std::io::stderr().lock().write_fmt(args);
}

/// The exit status once the command is done, if stdout changes it: none
/// if stdout took everything or the command failed on its own (`success`
/// false: its status stands); otherwise 141 (128 + SIGPIPE, what a shell
/// shows for a process killed by it) for a reader that went away, and 1,
/// with the error on stderr, for any other failure.
pub fn status(success: bool) -> Option<u8> {
    let e = ERROR.get()?;
    if e.kind() == std::io::ErrorKind::BrokenPipe {
        return success.then_some(super::status::STDOUT_CLOSED);
    }
    errln!("error: standard output: {e}");
    success.then_some(super::status::ERROR)
}
