//! `bench campaign` on hardware (the serial DAQ emulator on a
//! pseudo-terminal): the operator is told what to change before each cell,
//! nothing reaches the device before the answer, and skip / redo / stop
//! are journaled and resumable.

use crate::common;
use crate::daemon_fixtures;

use common::emulator::Emulator;
use std::io::{Read, Write};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

const PROMPT: &str = "[Enter] run";

/// Stderr of a child, collected on a thread.
struct Collected(Arc<Mutex<String>>);

impl Collected {
    fn of(child: &mut Child) -> Self {
        let buf = Arc::new(Mutex::new(String::new()));
        let b = Arc::clone(&buf);
        let mut err = child.stderr.take().unwrap();
        std::thread::spawn(move || {
            let mut chunk = [0u8; 4096];
            while let Ok(n) = err.read(&mut chunk) {
                if n == 0 {
                    break;
                }
                b.lock()
                    .unwrap()
                    .push_str(&String::from_utf8_lossy(&chunk[..n]));
            }
        });
        Self(buf)
    }

    /// Waits until the text holds `n` prompts; returns the text.
    fn prompts(&self, n: usize) -> String {
        let start = Instant::now();
        loop {
            let t = self.0.lock().unwrap().clone();
            if t.matches(PROMPT).count() >= n {
                return t;
            }
            assert!(
                start.elapsed() < Duration::from_secs(120),
                "no prompt {n}:\n{t}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    fn text(&self) -> String {
        self.0.lock().unwrap().clone()
    }
}

/// `bench ARGS` in `cwd` with stdin, stdout and stderr piped.
fn spawn(args: &[&str], cwd: &Path) -> Child {
    Command::new(env!("CARGO_BIN_EXE_bench"))
        .args(args)
        .current_dir(cwd)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

fn campaign_file(dir: &Path) -> std::path::PathBuf {
    // The shipped bench with the link-latency and overrun bounds of the
    // shared test config (a loaded 2-core VM stalls the host at times), 20
    // missed samples (4 ms at 5 kHz) before the link fault, and a 300 ms
    // device watchdog (a silent link is judged by it: an emulator starved
    // for 50 ms under a full test run faulted a cell): this test is about
    // the operator's flow, not the link's bounds.
    common::quiet_config_edited(dir, 0.3, "\n[emulator]\nwatchdog_ms = 300.0\n", |t| {
        common::set_key(t, "max_missed_samples", "20")
    });
    let p = dir.join("hw.toml");
    std::fs::write(
        &p,
        r#"config = "bench.toml"
seed = 3
mass_increment_kg = 0.0005
[grid]
operating_point_pct = [2.0, 6.0]
mass_asymmetry = [-0.0166666666666667, 0.0166666666666667]
[chirp]
duration_s = 0.5
taper_s = 0.1
lead_in_s = 0.2
tail_s = 0.3
"#,
    )
    .unwrap();
    p
}

#[test]
fn the_operator_is_told_each_change_and_nothing_moves_before_the_answer() {
    let tmp = tempfile::tempdir().unwrap();
    let file = campaign_file(tmp.path());
    let cfg = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    let emu = Emulator::start(&cfg, vec![], None);
    let backend = emu.backend();
    let mut child = spawn(
        &[
            "campaign",
            "run",
            file.to_str().unwrap(),
            "--out",
            "hw",
            "--backend",
            &backend,
        ],
        tmp.path(),
    );
    let err = Collected::of(&mut child);
    let mut stdin = child.stdin.take().unwrap();

    // First cell (serpentine: Δm23 = −1.67 %, 2 % of L): absolute setup.
    let t = err.prompts(1);
    let l_mm = 47.5;
    assert!(t.contains(&format!("{:.3} mm", 0.02 * l_mm)), "{t}");
    assert!(t.contains("0 on stage 2, 2 on stage 3"), "{t}");
    std::thread::sleep(Duration::from_millis(300));
    // Nothing reached the device before the answer.
    assert!(!emu.status.host_connected.load(Ordering::SeqCst), "{t}");
    assert!(!emu.status.enabled.load(Ordering::SeqCst));
    assert_eq!(emu.status.commands_received.load(Ordering::SeqCst), 0);
    stdin.write_all(b"\n").unwrap();

    // Second cell: 6 % of L, same masses: the move is stated.
    let t = err.prompts(2);
    let second = t.rsplit("cell 2 of 4").next().unwrap();
    assert!(
        second.contains(&format!("move {:+.3} mm", 0.04 * l_mm)),
        "{second}"
    );
    assert!(second.contains("(unchanged)"), "{second}");
    // Between cells the amplifier is disabled at 0 A.
    assert!(!emu.status.enabled.load(Ordering::SeqCst));
    assert_eq!(emu.status.commanded_current_a(), 0.0);
    stdin.write_all(b"s\n").unwrap();

    // Third cell: Δm23 = +1.67 %: remove 2 from stage 3, add 2 to stage 2.
    let t = err.prompts(3);
    let third = t.rsplit("cell 3 of 4").next().unwrap();
    assert!(
        third.contains("2 on stage 2 (add 2), 0 on stage 3 (remove 2)"),
        "{third}"
    );
    // The README's sample prompt is one the operator was shown.
    let sample = crate::common::doc_blocks()
        .into_iter()
        .find(|b| b.lang == "text" && b.body.starts_with("cell 3 of 4"))
        .expect("the README's prompt sample")
        .body;
    let shown = err.text();
    for line in sample.lines() {
        assert!(
            shown.contains(line.trim_end()),
            "the README's prompt line is not what the operator is shown:\n{line}\nshown:\n{shown}"
        );
    }
    // Redo the previous (skipped) cell: it is asked again.
    stdin.write_all(b"r\n").unwrap();
    let t = err.prompts(4);
    let again = t.rsplit(PROMPT).nth(1).unwrap();
    assert!(again.contains("(grid cell 1)"), "{again}");
    stdin.write_all(b"q\n").unwrap();
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "{}", err.text());

    // One cell done, one skipped; resume runs the other two.
    let journal = std::fs::read_to_string(tmp.path().join("hw/journal.jsonl")).unwrap();
    assert_eq!(journal.matches("\"entry\":\"done\"").count(), 1);
    assert_eq!(journal.matches("\"entry\":\"skipped\"").count(), 1);
    let mut child = spawn(
        &["campaign", "resume", "hw", "--backend", &backend, "--json"],
        tmp.path(),
    );
    let err = Collected::of(&mut child);
    child.stdin.take().unwrap().write_all(b"\n\n").unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "{}", err.text());
    let s: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(s["done"], 3, "{s}");
    assert_eq!(s["skipped"], 1, "{s}");
    assert_eq!(s["pending"], 0, "{s}");
    // The achieved asymmetry (whole masses) is what the model is taken at.
    let achieved = s["results"][0]["achieved_mass_asymmetry"].as_f64();
    assert!(
        achieved.is_none() || (achieved.unwrap() - (0.06 / 0.061 - 1.0)).abs() < 1e-12,
        "{s}"
    );
    assert!(!emu.status.enabled.load(Ordering::SeqCst));
}

#[test]
fn with_daemon_each_cell_is_a_daemon_job_after_the_operator_answers() {
    let tmp = tempfile::tempdir().unwrap();
    let file = campaign_file(tmp.path());
    // The daemon serves the same quiet bench (its config, its simulator).
    let socket = tmp.path().join("bench.sock");
    let recordings = tmp.path().join("daemon-recordings");
    std::fs::create_dir(&recordings).unwrap();
    // Killed on drop, also when an assertion fails.
    let _serve =
        daemon_fixtures::spawn_serve(&tmp.path().join("bench.toml"), &socket, &recordings, &[]);
    let text = std::fs::read_to_string(&file).unwrap();
    std::fs::write(
        &file,
        text.replace(
            "operating_point_pct = [2.0, 6.0]",
            "operating_point_pct = [6.0]",
        ),
    )
    .unwrap();
    let mut child = spawn(
        &[
            "campaign",
            "run",
            file.to_str().unwrap(),
            "--out",
            "d",
            "--json",
            "--cells-on-daemon",
            socket.to_str().unwrap(),
        ],
        tmp.path(),
    );
    let err = Collected::of(&mut child);
    let mut stdin = child.stdin.take().unwrap();
    err.prompts(1);
    // No job before the answer.
    std::thread::sleep(Duration::from_millis(200));
    let chirps = || {
        std::fs::read_dir(&recordings)
            .unwrap()
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with("chirp"))
            .collect::<Vec<_>>()
    };
    assert!(chirps().is_empty(), "{:?}", chirps());
    stdin.write_all(b"\n").unwrap();
    err.prompts(2);
    stdin.write_all(b"\n").unwrap();
    drop(stdin);
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "{}", err.text());
    let s: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(s["done"], 2, "{s}");
    // The journal names the daemon's recordings (absolute), checksummed.
    let journal = std::fs::read_to_string(tmp.path().join("d/journal.jsonl")).unwrap();
    let rec = recordings.canonicalize().unwrap();
    assert_eq!(
        journal
            .matches(&format!("\"path\":\"{}", rec.display()))
            .count(),
        2,
        "{journal}"
    );
    for cell in ["cells/000", "cells/001"] {
        assert!(tmp.path().join("d").join(cell).join("frf.csv").is_file());
    }
}
