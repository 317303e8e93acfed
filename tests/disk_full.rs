//! A recording that fails is a fault (issue 12, item 2): a full disk stops
//! the run at 0 A within 100 ms of the failed write, with the exit status
//! of a fault, and nothing looks complete (no final `.mcap`, only the
//! `.part`).
//!
//! The disk is a 1 MiB tmpfs mounted for the test (we run as root here);
//! where mounting is not permitted, the same failure is injected with a
//! file size limit (`RLIMIT_FSIZE`, `SIGXFSZ` ignored: writes beyond it fail
//! with `EFBIG`), which the test says on stderr.

mod common;

use common::emulator::Emulator;
use common::*;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// Size of the small disk, bytes.
const DISK_BYTES: u64 = 1 << 20;

/// Where the recording goes, and how the disk fills.
enum Disk {
    /// A tmpfs of [`DISK_BYTES`] mounted at the path (unmounted on drop).
    Tmpfs(PathBuf),
    /// A plain directory; the `bench` process gets `RLIMIT_FSIZE`.
    Limit(PathBuf),
}

impl Disk {
    fn new(dir: &Path) -> Self {
        let at = dir.join("disk");
        std::fs::create_dir(&at).unwrap();
        let ok = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={DISK_BYTES}")])
            .arg("tmpfs")
            .arg(&at)
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        if ok {
            Self::Tmpfs(at)
        } else {
            eprintln!("mounting a tmpfs is not permitted here: injecting the write error with RLIMIT_FSIZE");
            Self::Limit(at)
        }
    }

    fn dir(&self) -> &Path {
        match self {
            Self::Tmpfs(p) | Self::Limit(p) => p,
        }
    }

    /// `bench` with the file size limit when there is no tmpfs.
    fn bench(&self) -> Command {
        let mut c = bench();
        if let Self::Limit(_) = self {
            // SAFETY: only async-signal-safe calls between fork and exec.
            unsafe {
                c.pre_exec(|| {
                    libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
                    let l = libc::rlimit {
                        rlim_cur: DISK_BYTES,
                        rlim_max: DISK_BYTES,
                    };
                    if libc::setrlimit(libc::RLIMIT_FSIZE, &l) != 0 {
                        return Err(std::io::Error::last_os_error());
                    }
                    Ok(())
                });
            }
        }
        c
    }

    /// The disk is full: no block left (tmpfs), or `file` at the limit.
    fn full(&self, file: &Path) -> bool {
        match self {
            Self::Tmpfs(p) => {
                let c = std::ffi::CString::new(p.as_os_str().as_encoded_bytes()).unwrap();
                // SAFETY: valid C string and out-pointer.
                let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
                unsafe { libc::statvfs(c.as_ptr(), &mut st) == 0 && st.f_bavail == 0 }
            }
            Self::Limit(_) => std::fs::metadata(file).is_ok_and(|m| m.len() >= DISK_BYTES),
        }
    }
}

impl Drop for Disk {
    fn drop(&mut self) {
        if let Self::Tmpfs(p) = self {
            let _ = Command::new("umount").arg("-l").arg(p).status();
        }
    }
}

fn assert_fault_left_part(out: &std::process::Output, rec: &Path) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "exit status of a fault: {err}");
    assert!(
        err.contains("safety fault: recording"),
        "names the recording fault: {err}"
    );
    assert!(
        err.contains("No space left on device") || err.contains("File too large"),
        "says why: {err}"
    );
    assert!(!rec.exists(), "nothing looks complete");
    let part = PathBuf::from(format!("{}.part", rec.display()));
    assert!(part.exists(), "the incomplete recording is kept as .part");
    assert!(err.contains(&part.display().to_string()), "{err}");
}

#[test]
fn a_full_disk_stops_a_real_time_chirp_at_zero_amps_within_100_ms() {
    let _g = one_at_a_time();
    let dir = tmp();
    let cfg = quiet_config(
        dir.path(),
        2.0,
        "\n[backend.serial]\nsample_timeout_periods = 200.0\n\n[emulator]\nwatchdog_ms = 300.0\n",
    );
    let emu = Emulator::start(&cfg, vec![], None);
    let disk = Disk::new(dir.path());
    let rec = disk.dir().join("run.mcap");
    let part = PathBuf::from(format!("{}.part", rec.display()));
    let child = disk
        .bench()
        .args(["chirp", "--realtime", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(&rec)
        .args(["--frf-csv", &path_in(dir.path(), "frf.csv")])
        .args(["--plot", &path_in(dir.path(), "bode.png")])
        .args(["--backend", &emu.backend()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Watch the disk and the device: when did the disk fill, when did the
    // current stop, was current flowing before.
    let t0 = Instant::now();
    let mut flowing = false;
    let mut full_at = None;
    let mut zero_at = None;
    while t0.elapsed() < Duration::from_secs(60) {
        let now = Instant::now();
        let enabled = emu.status.enabled.load(Ordering::Acquire);
        let current_a = emu.status.commanded_current_a();
        match full_at {
            None => {
                flowing |= enabled && current_a != 0.0;
                if disk.full(&part) {
                    full_at = Some(now);
                }
            }
            Some(_) => {
                if !enabled && current_a == 0.0 {
                    zero_at = Some(now);
                    break;
                }
            }
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    let out = child.wait_with_output().unwrap();
    assert!(flowing, "the chirp drove the stage before the disk filled");
    let full_at = full_at.expect("the disk never filled");
    let zero_at = zero_at.expect("the current never stopped");
    let dt = zero_at - full_at;
    assert!(
        dt <= Duration::from_millis(100),
        "0 A and disabled only {:.1} ms after the disk filled",
        dt.as_secs_f64() * 1e3
    );
    assert_fault_left_part(&out, &rec);
    // Stays at 0 A.
    assert_eq!(emu.status.commanded_current_a(), 0.0);
    assert!(!emu.status.enabled.load(Ordering::Acquire));
}

#[test]
fn a_full_disk_is_a_fault_in_virtual_time_too() {
    let _g = one_at_a_time();
    let dir = tmp();
    let disk = Disk::new(dir.path());
    for args in [
        vec!["chirp"],
        vec!["control", "--fast", "--duration-s", "30"],
    ] {
        let rec = disk.dir().join(format!("{}.mcap", args[0]));
        let out = disk
            .bench()
            .args(&args)
            .arg("--out")
            .arg(&rec)
            .args(["--plot", &path_in(dir.path(), &format!("{}.png", args[0]))])
            .output()
            .unwrap();
        assert_fault_left_part(&out, &rec);
        let part = PathBuf::from(format!("{}.part", rec.display()));
        std::fs::remove_file(part).unwrap();
    }
}
