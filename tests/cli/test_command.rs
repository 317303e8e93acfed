//! The README's test command, `tests/run`, on a machine that lacks what it
//! needs: it names what is missing and how to get it, and exits 1 before
//! any test runs. The machine is faked by `PATH`: a directory holding only
//! the few programs the script itself uses (and a fake `cargo` that
//! records that it ran).

use crate::common::tmp;
use std::path::Path;
use std::process::{Command, Output};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// A `PATH` directory with `programs` linked from the machine's, and a
/// fake `cargo` that writes `cargo ran` to `marker`.
fn machine(dir: &Path, programs: &[&str], marker: &Path) -> String {
    let bin = dir.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    for p in programs {
        let found = ["/usr/bin", "/bin", "/usr/sbin", "/sbin"]
            .iter()
            .map(|d| Path::new(d).join(p))
            .find(|p| p.exists())
            .unwrap_or_else(|| panic!("{p} is not on this machine"));
        std::os::unix::fs::symlink(found, bin.join(p)).unwrap();
    }
    bin.display().to_string() + &format!("#{}", marker.display())
}

fn run_tests_run(path_and_marker: &str, env: &[(&str, &str)]) -> Output {
    let (path, marker) = path_and_marker.split_once('#').unwrap();
    let fake_cargo = Path::new(path).join("cargo");
    if !fake_cargo.exists() && env.iter().any(|(k, _)| *k == "FAKE_CARGO") {
        std::fs::write(
            &fake_cargo,
            format!("#!/bin/bash\necho cargo ran > {marker}\n"),
        )
        .unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&fake_cargo, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    let mut c = Command::new("/bin/bash");
    c.arg(root().join("tests/run"))
        .env_clear()
        .env("PATH", path)
        .env("HOME", Path::new(path).parent().unwrap());
    for (k, v) in env {
        if *k != "FAKE_CARGO" {
            c.env(k, v);
        }
    }
    c.output().unwrap()
}

#[test]
fn without_cargo_it_says_to_install_a_rust_toolchain() {
    let dir = tmp();
    let marker = dir.path().join("ran");
    let p = machine(dir.path(), &["dirname"], &marker);
    let o = run_tests_run(&p, &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("no cargo on PATH") && err.contains("rustup.rs"),
        "{err}"
    );
}

#[test]
fn a_missing_program_is_named_with_its_package_and_no_test_runs() {
    let dir = tmp();
    let marker = dir.path().join("ran");
    let p = machine(dir.path(), &["dirname", "id"], &marker);
    // Told not to install: socat, the first the tests need, is named with
    // the package that has it and the command that installs it.
    let o = run_tests_run(&p, &[("FAKE_CARGO", "1"), ("BENCH_NO_INSTALL", "1")]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("missing socat") && err.contains("apt-get install socat"),
        "{err}"
    );
    assert!(!marker.exists(), "cargo ran although socat is missing");
    // Allowed to install, but with no apt-get on this machine: said so.
    let o = run_tests_run(&p, &[("FAKE_CARGO", "1")]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("no apt-get to install it with"), "{err}");
    assert!(!marker.exists(), "cargo ran although socat is missing");
}

#[test]
fn not_root_and_no_sudo_is_said_with_the_command_to_run() {
    let dir = tmp();
    let marker = dir.path().join("ran");
    let p = machine(dir.path(), &["dirname"], &marker);
    let bin = Path::new(p.split_once('#').unwrap().0);
    // A user's machine: `id -u` says 1000, apt-get exists, sudo does not.
    for (name, body) in [("id", "echo 1000"), ("apt-get", "exit 0")] {
        let f = bin.join(name);
        std::fs::write(&f, format!("#!/bin/bash\n{body}\n")).unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&f, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    let o = run_tests_run(&p, &[("FAKE_CARGO", "1")]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("not root and no password-less sudo")
            && err.contains("sudo apt-get install socat"),
        "{err}"
    );
    assert!(!marker.exists(), "cargo ran although socat is missing");
}
