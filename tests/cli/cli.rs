//! Bad input, signals and kills at the process boundary.

use crate::common;

use common::*;
use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant};

const CH5: &str = "bench-config/sr4dof-ch5.toml";

fn shipped_ch5() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(CH5)).unwrap()
}

/// Runs `bench chirp` with `args` into an empty directory and checks: exit
/// 2, the message on stderr names `needle`, and nothing was left behind.
fn refused(extra: &[&str], config_text: Option<&str>, needle: &str) {
    let dir = tmp();
    let out_dir = dir.path().join("out");
    std::fs::create_dir(&out_dir).unwrap();
    let cfg = path_in(dir.path(), "bench.toml");
    std::fs::write(&cfg, config_text.unwrap_or(&shipped_ch5())).unwrap();
    let out = path_in(&out_dir, "run.mcap");
    let mut args = vec!["chirp", "--config", cfg.as_str(), "--out", out.as_str()];
    args.extend_from_slice(extra);
    let o = run(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(
        o.status.code(),
        Some(2),
        "{extra:?}: status {:?}, stderr: {err}",
        o.status
    );
    assert!(
        err.contains(needle),
        "{extra:?}: stderr lacks {needle:?}: {err}"
    );
    assert!(o.stdout.is_empty(), "nothing on stdout on error");
    assert!(
        files_in(&out_dir).is_empty(),
        "files left behind: {:?}",
        files_in(&out_dir)
    );
}

#[test]
fn missing_config() {
    let o = run(&["chirp", "--config", "/nonexistent/bench.toml"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("/nonexistent/bench.toml"));
}

#[test]
fn unparseable_config() {
    refused(&[], Some("this is [ not toml"), "bench.toml");
}

#[test]
fn unknown_key() {
    let text = shipped_ch5().replace("[plant]\n", "[plant]\nm6_kg = 0.1\n");
    refused(&[], Some(&text), "m6_kg");
}

#[test]
fn non_positive_mass_and_stiffness() {
    let text = shipped_ch5().replace("m1_kg = 0.4 ", "m1_kg = 0.0 ");
    refused(&[], Some(&text), "plant.m1_kg");
    let text = shipped_ch5().replace("k5_n_per_m = 36.0e3", "k5_n_per_m = -36.0e3");
    refused(&[], Some(&text), "plant.k5_n_per_m");
}

#[test]
fn nan_value() {
    let text = shipped_ch5().replace("k4_n_per_m = 36.0e3", "k4_n_per_m = nan");
    refused(&[], Some(&text), "plant.k4_n_per_m");
}

#[test]
fn f_end_at_or_above_nyquist() {
    refused(&["--f-end-hz", "2500"], None, "--f-end-hz");
    refused(&["--f-end-hz", "3000"], None, "Nyquist");
    let text = shipped_ch5().replace("f_end_hz = 500.0", "f_end_hz = 2600.0");
    refused(&[], Some(&text), "chirp.f_end_hz");
}

#[test]
fn amplitude_above_peak_current() {
    refused(&["--amplitude-a", "12"], None, "--amplitude-a");
    refused(&["--amplitude-a", "12"], None, "peak current");
}

#[test]
fn bad_arguments() {
    refused(&["--duration-s", "-3"], None, "--duration-s");
    refused(&["--seed", "abc"], None, "--seed");
    refused(
        &["--operating-point-pct", "30"],
        None,
        "--operating-point-pct",
    );
}

#[test]
fn unwritable_outputs() {
    let dir = tmp();
    let file = path_in(dir.path(), "a-file");
    std::fs::write(&file, "x").unwrap();
    for (flag, value) in [
        ("--out", "/nonexistent-dir/run.mcap".to_string()),
        ("--out", format!("{file}/run.mcap")),
        ("--frf-csv", "/nonexistent-dir/frf.csv".to_string()),
        ("--png", format!("{file}/bode.png")),
    ] {
        refused(&[flag, &value], None, flag);
    }
    refused(&["--out", "/tmp/not-an-mcap.txt"], None, ".mcap");
}

/// Waits until `part` holds at least one flushed sample; returns the
/// highest tick seen and when.
fn wait_for_samples(part: &Path, deadline: Duration) -> (u64, Instant) {
    let start = Instant::now();
    loop {
        if let Ok(bytes) = std::fs::read(part) {
            let s = bench::record::read_samples_tolerant(&bytes);
            if let Some(last) = s.last() {
                return (last.tick, Instant::now());
            }
        }
        assert!(
            start.elapsed() < deadline,
            "no samples in {} after {deadline:?}",
            part.display()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Starts a 30 s real-time chirp writing `dir/run.mcap`, stderr piped, on
/// the built-in bench with the timing bounds relaxed (`relax_timing_bounds`):
/// the other tests of this binary load both cores, and a stall of a few tens
/// of ms would end the run on the overrun fault before the signal these
/// tests are about.
fn spawn_realtime_chirp(dir: &Path) -> std::process::Child {
    let out = path_in(dir, "run.mcap");
    let config = dir.join("bench.toml");
    let built_in = bench().args(["config", "default"]).output().unwrap();
    assert!(built_in.status.success());
    std::fs::write(
        &config,
        relax_timing_bounds(&String::from_utf8(built_in.stdout).unwrap()),
    )
    .unwrap();
    bench()
        .args([
            "chirp",
            "--realtime",
            "--duration-s",
            "30",
            "--f-start-hz",
            "5",
            "--config",
        ])
        .arg(&config)
        .args(["--out", &out])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// README, *Recording reference* (durability): a real-time run killed with SIGKILL leaves a `.part` file whose
/// completed chunks read back, losing at most ~100 ms of samples.
#[test]
fn sigkill_in_realtime_loses_at_most_100_ms() {
    let _g = one_at_a_time();
    let dir = tmp();
    let mut child = spawn_realtime_chirp(dir.path());
    let part = dir.path().join("run.mcap.part");
    let (k0, t0) = wait_for_samples(&part, Duration::from_secs(20));
    std::thread::sleep(Duration::from_millis(1500));
    let waited = t0.elapsed().as_secs_f64();
    child.kill().unwrap(); // SIGKILL
    let o = child.wait_with_output().unwrap();
    assert!(
        !dir.path().join("run.mcap").exists(),
        "a killed run must not look complete; the run ended by itself first: {:?} {}",
        o.status,
        String::from_utf8_lossy(&o.stderr)
    );
    let bytes = std::fs::read(&part).unwrap();
    let samples = bench::record::read_samples_tolerant(&bytes);
    // Completed chunks read back, in order, without gaps.
    for (i, s) in samples.iter().enumerate() {
        assert_eq!(s.tick, i as u64);
    }
    // The loop ran in real time from tick k0 at t0 for `waited` seconds.
    let produced_at_least = k0 as f64 + waited * 5000.0;
    let recovered = samples.len() as f64;
    let lost_s = (produced_at_least - recovered) / 5000.0;
    eprintln!(
        "recovered {recovered} samples; lost at most {:.0} ms",
        lost_s * 1e3
    );
    assert!(lost_s <= 0.15, "lost {:.0} ms of samples", lost_s * 1e3);
}

/// SIGINT and SIGTERM stop the loop safely: exit 130, a finished recording
/// that ends with the interruption and the amplifier disabled.
#[test]
fn sigint_and_sigterm_finish_the_recording() {
    let _g = one_at_a_time();
    for sig in [libc::SIGINT, libc::SIGTERM] {
        let dir = tmp();
        let child = spawn_realtime_chirp(dir.path());
        wait_for_samples(&dir.path().join("run.mcap.part"), Duration::from_secs(20));
        // SAFETY: sending a signal to our own child.
        unsafe { libc::kill(child.id() as i32, sig) };
        let o = child.wait_with_output().unwrap();
        assert_eq!(
            o.status.code(),
            Some(130),
            "signal {sig}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(String::from_utf8_lossy(&o.stderr).contains("interrupted"));
        let path = dir.path().join("run.mcap");
        assert!(path.exists() && !dir.path().join("run.mcap.part").exists());
        let msgs = mcap_messages(&path); // strict reader: the file is complete
        let events: Vec<(String, String)> = msgs
            .iter()
            .filter(|m| m.0 == "/bench/event")
            .map(|m| {
                (
                    m.2["kind"].as_str().unwrap().into(),
                    m.2["state"].as_str().unwrap().into(),
                )
            })
            .collect();
        let i = events
            .iter()
            .position(|e| e.0 == "interrupted")
            .expect("interrupted event");
        assert!(events[i..].iter().any(|e| e.1 == "disabled"), "{events:?}");
        assert_eq!(events.last().unwrap().0, "loop_stopped");
    }
}

/// A fault on the stage (the chirp drives x1 past the software limit) ends
/// the run with the fault status, 0 A from the faulting tick and a finished
/// recording holding the fault.
#[test]
fn position_fault_stops_the_chirp() {
    let dir = tmp();
    let out = path_in(dir.path(), "run.mcap");
    // 0.5 A at the 29 Hz rigid-body mode without the amplitude profile.
    let text = shipped_ch5().replace("amplitude_profile = ", "# amplitude_profile = ");
    let cfg = path_in(dir.path(), "bench.toml");
    std::fs::write(&cfg, text).unwrap();
    let o = run(&["chirp", "--config", &cfg, "--out", &out]);
    assert_eq!(
        o.status.code(),
        Some(3),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(String::from_utf8_lossy(&o.stderr).contains("position_limit"));
    let msgs = mcap_messages(&dir.path().join("run.mcap"));
    let fault = msgs
        .iter()
        .find(|m| m.0 == "/bench/event" && m.2["kind"] == "fault")
        .expect("fault event");
    assert_eq!(fault.2["fault"], "position_limit");
    let fault_tick = fault.2["tick"].as_u64().unwrap();
    let samples: Vec<_> = msgs.iter().filter(|m| m.0 == "/bench/sample").collect();
    let at = samples
        .iter()
        .find(|m| m.2["tick"].as_u64() == Some(fault_tick))
        .unwrap();
    assert_eq!(at.2["current_command_a"].as_f64(), Some(0.0));
    assert_eq!(at.2["state"], "faulted");
    assert!(at.2["position_m"].as_f64().unwrap().abs() > 0.8e-3);
    assert_eq!(samples.last().unwrap().2["tick"].as_u64(), Some(fault_tick));
}

#[test]
fn help_lists_every_chirp_option() {
    let o = run(&["chirp", "--help"]);
    assert!(o.status.success());
    let help = String::from_utf8_lossy(&o.stdout);
    for flag in [
        "--config",
        "--out",
        "--frf-csv",
        "--png",
        "--overwrite",
        "--realtime",
        "--pace",
        "--live",
        "--seed",
        "--json",
        "--operating-point-m",
        "--operating-point-pct",
        "--mass-asymmetry",
        "--amplitude-a",
        "--f-start-hz",
        "--f-end-hz",
        "--duration-s",
        "--excitation",
        "--bla-csv",
    ] {
        assert!(help.contains(flag), "--help lacks {flag}");
    }
}

#[test]
fn help_lists_every_control_option() {
    let o = run(&["control", "--help"]);
    assert!(o.status.success());
    let help = String::from_utf8_lossy(&o.stdout);
    for flag in [
        "--slow",
        "--fast",
        "--controller",
        "--config",
        "--step-m",
        "--duration-s",
        "--smooth-s",
        "--out",
        "--png",
        "--overwrite",
        "--json",
        "--realtime",
        "--pace",
        "--live",
        "--check-only",
        "--frf",
        "--override-check",
        "--seed",
        "--inject-fault",
        "--verify",
        "--verify-amplitude-a",
        "--verify-duration-s",
    ] {
        assert!(help.contains(flag), "--help lacks {flag}");
    }
}

/// A reader that went away (`bench chirp | head`) or a full disk behind
/// stdout: no panic, the run's files complete, and the status says what
/// happened (141 = 128 + SIGPIPE for the closed pipe; 1 and the error on
/// stderr for /dev/full). Both the text and the `--json` printing.
#[test]
fn a_closed_or_full_stdout_ends_with_complete_files_and_a_status() {
    let dir = tmp();
    for (i, json) in [false, true].into_iter().enumerate() {
        for full in [false, true] {
            let out = dir.path().join(format!("run{i}{}.mcap", u8::from(full)));
            let mut cmd = bench();
            cmd.args(["chirp", "--duration-s", "2", "--f-start-hz", "20", "--out"])
                .arg(&out)
                .stderr(Stdio::piped());
            if json {
                cmd.arg("--json");
            }
            if full {
                cmd.stdout(std::fs::File::create("/dev/full").unwrap());
            } else {
                cmd.stdout(Stdio::piped());
            }
            let mut child = cmd.spawn().unwrap();
            // The reader goes away before anything is printed.
            drop(child.stdout.take());
            let o = child.wait_with_output().unwrap();
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(!err.contains("panicked"), "{err}");
            if full {
                assert_eq!(o.status.code(), Some(1), "{err}");
                assert!(err.contains("standard output"), "{err}");
            } else {
                assert_eq!(o.status.code(), Some(141), "{err}");
            }
            // The recording and its outputs were finished before printing.
            assert!(out.exists(), "no {}", out.display());
            assert!(!Path::new(&format!("{}.part", out.display())).exists());
            let samples = bench::record::read_samples_tolerant(&std::fs::read(&out).unwrap());
            assert!(samples.len() > 10_000, "{}", samples.len());
        }
    }
}

/// A standard error that cannot be written (`2>/dev/full`, a log on a full
/// disk) loses the messages, never the exit status: a fault still exits 3
/// with its recording finished, bad input 2, never 101 (the status of a
/// panic, which `eprintln!` and tracing's own error report raise on such a
/// stderr). With `RUST_LOG=debug` tracing writes there too, and an invalid
/// `RUST_LOG` takes the warning path.
#[test]
fn a_full_stderr_keeps_the_exit_status() {
    let dir = tmp();
    let fault_cfg = path_in(dir.path(), "fault.toml");
    // As in `position_fault_stops_the_chirp`: 0.5 A at the rigid-body mode.
    std::fs::write(
        &fault_cfg,
        shipped_ch5().replace("amplitude_profile = ", "# amplitude_profile = "),
    )
    .unwrap();
    let bad_cfg = path_in(dir.path(), "bad.toml");
    std::fs::write(&bad_cfg, "no_such_key = 1\n").unwrap();
    for (i, log) in ["", "debug", "no such filter ==="].into_iter().enumerate() {
        for (cfg, want) in [(&fault_cfg, 3), (&bad_cfg, 2)] {
            let out = dir.path().join(format!("run{i}-{want}.mcap"));
            let o = bench()
                .args(["chirp", "--config", cfg, "--out"])
                .arg(&out)
                .env("RUST_LOG", log)
                .stdout(Stdio::null())
                .stderr(std::fs::File::create("/dev/full").unwrap())
                .output()
                .unwrap();
            assert_eq!(
                o.status.code(),
                Some(want),
                "RUST_LOG={log:?}, {cfg}: status {:?}",
                o.status
            );
            if want == 3 {
                // The fault's recording is finished and holds the fault.
                let fault = mcap_messages(&out)
                    .into_iter()
                    .find(|m| m.0 == "/bench/event" && m.2["kind"] == "fault")
                    .expect("a fault event");
                assert_eq!(fault.2["fault"], "position_limit");
            } else {
                assert!(!out.exists());
            }
        }
    }
    // `bench control --inject-fault` (the fault latched by the loop itself).
    let out = dir.path().join("control.mcap");
    let o = bench()
        .args([
            "control",
            "--fast",
            "--duration-s",
            "2",
            "--inject-fault",
            "nan@1.0",
            "--out",
        ])
        .arg(&out)
        .env("RUST_LOG", "debug")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create("/dev/full").unwrap())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(3), "control: {:?}", o.status);
    assert!(out.exists());
}

/// Issue 25: the densest FRF grid the config allows (10 000 points per
/// decade, at a relative resolution of 0.2 %) is post-processed with
/// every grid point in the CSV and a fit (the modal fit thins it to 1 000
/// per decade; its time, 104 s before, is measured by
/// `benches/dense-grid-time.sh`, not asserted here: a loaded machine made
/// a timed assertion fail); and a SIGINT during that post-processing lets
/// it finish: exit 0, every output complete, a note saying so. The signal is sent when the CSV's
/// temporary file appears after the recording was created: the CSV is
/// written beside the fit.
#[test]
fn the_densest_grid_post_processes_every_point_and_an_interrupt_there_finishes_it() {
    let dir = tmp();
    let cfg = path_in(dir.path(), "dense.toml");
    let text = set_key(
        &set_key(&shipped_ch5(), "points_per_decade", "10000"),
        "relative_resolution",
        "0.002",
    );
    std::fs::write(&cfg, text).unwrap();
    let out = dir.path().join("run.mcap");
    let t0 = Instant::now();
    let mut child = bench()
        .args([
            "chirp",
            "--duration-s",
            "5",
            "--json",
            "--config",
            &cfg,
            "--out",
        ])
        .arg(&out)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let csv_tmp = || {
        files_in(dir.path()).iter().any(|p| {
            let n = p.file_name().unwrap().to_string_lossy().into_owned();
            n.starts_with(".run.frf.csv.") && n.ends_with(".tmp")
        })
    };
    // The outputs are checked before the run by creating (and removing) a
    // temporary file of the same pattern: only one seen once the recording
    // exists is the CSV being written.
    let part = dir.path().join("run.mcap.part");
    let mut recording = false;
    let mut signalled = false;
    // A bound on the wait for the CSV, not on the run's speed.
    while t0.elapsed() < Duration::from_secs(120) {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        recording = recording || part.exists();
        if recording && csv_tmp() {
            // SAFETY: sending a signal to our own child.
            unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
            signalled = true;
            break;
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        signalled,
        "the post-processing ended before its CSV was seen"
    );
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert!(err.contains("note: interrupted after the sweep"), "{err}");
    assert!(out.exists() && !dir.path().join("run.mcap.part").exists());
    let summary = json_stdout(&o);
    assert!(
        summary["fit"]["modes"]
            .as_array()
            .is_some_and(|m| !m.is_empty()),
        "{summary}"
    );
    // Every point of the grid: 10 000 per decade over 0.1-500 Hz.
    let rows = read_frf_csv(&dir.path().join("run.frf.csv")).len();
    let want = ((500.0f64 / 0.1).log10() * 10_000.0).ceil() as usize + 1;
    assert_eq!(rows, want);
}

/// `--config` with `--daemon` is refused (exit 2, naming the flag), never
/// silently dropped: the daemon runs the config it was started with. The
/// refusal comes before any socket is opened.
#[test]
fn config_with_daemon_is_refused_not_ignored() {
    let cfg = Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml");
    for cmd in [&["chirp"][..], &["control", "--fast"][..]] {
        let mut args = cmd.to_vec();
        args.extend([
            "--daemon",
            "/nonexistent.sock",
            "--config",
            cfg.to_str().unwrap(),
        ]);
        let o = run(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{cmd:?}: {err}");
        assert!(
            err.contains("--config") && err.contains("bench serve --config"),
            "{cmd:?}: {err}"
        );
    }
}

/// The subcommands a `--help` lists (its `Commands:` section), `help` left
/// out.
fn subcommands(help: &str) -> Vec<String> {
    help.lines()
        .skip_while(|l| l.trim() != "Commands:")
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .filter(|l| l.starts_with("  ") && !l.starts_with("   "))
        .filter_map(|l| l.split_whitespace().next().map(String::from))
        .filter(|c| c != "help")
        .collect()
}

/// The exit statuses a text names: `exit N`, `exits N`, `status N`, and
/// each `N …` item of an `Exit status: N …; M …. K …` paragraph.
fn codes_named(text: &str) -> Vec<u8> {
    let mut codes = Vec::new();
    let number = |w: &str| -> Option<u8> {
        let digits: String = w.chars().take_while(char::is_ascii_digit).collect();
        digits.parse().ok()
    };
    let words: Vec<&str> = text.split_whitespace().collect();
    for w in words.windows(2) {
        let word = w[0]
            .trim_matches(|c: char| !c.is_alphanumeric())
            .to_lowercase();
        if ["exit", "exits", "status"].contains(&word.as_str()) {
            codes.extend(number(w[1].trim_start_matches("**")));
        }
    }
    for (i, _) in text.match_indices("Exit status:") {
        let para = text[i + "Exit status:".len()..]
            .split("\n\n")
            .next()
            .unwrap_or("");
        for item in para.split(';').flat_map(|i| i.split(". ")) {
            codes.extend(number(item.trim()));
        }
    }
    codes
}

/// Every exit status the command line documents is one of the one table,
/// `bench::error::EXIT_STATUSES`, and for a command it lists: each
/// command's and subcommand's `--help` (`Exit status: N …; M …`, `exit
/// N`); `bench --help` lists the table; the README's *Exit status* table
/// has its codes in its order, each row holding the table's words and
/// naming only commands the table lists for it; and every `exit N` in the
/// README is one of its codes (issue 46: `bench recover --help` said 6
/// for lost data, where it exits 7).
#[test]
fn exit_statuses_follow_the_one_table() {
    use bench::error::EXIT_STATUSES;
    let allowed = |command: &str, code: u8| {
        EXIT_STATUSES
            .iter()
            .any(|s| s.code == code && (s.commands.is_empty() || s.commands.contains(&command)))
    };
    let help = |args: &[&str]| {
        let mut a = args.to_vec();
        a.push("--help");
        let o = run(&a);
        assert!(o.status.success(), "{a:?}");
        String::from_utf8(o.stdout).unwrap()
    };
    // `bench --help`: the table, generated from it.
    let top = help(&[]);
    for s in EXIT_STATUSES {
        assert!(
            top.contains(&format!("{:>3}  {}", s.code, s.meaning)),
            "bench --help lacks {} {}:\n{top}",
            s.code,
            s.meaning
        );
    }
    // Every command's and subcommand's --help.
    let mut checked = 0;
    for command in subcommands(&top) {
        let text = help(&[&command]);
        let mut texts = vec![(command.clone(), text.clone())];
        for sub in subcommands(&text) {
            texts.push((format!("{command} {sub}"), help(&[&command, &sub])));
        }
        for (name, text) in texts {
            for code in codes_named(&text) {
                checked += 1;
                assert!(
                    allowed(&command, code),
                    "bench {name} --help names exit status {code}, which the table does not give `bench {command}`:\n{text}"
                );
            }
        }
    }
    assert!(checked >= 30, "only {checked} statuses named in --help");
    let recover = help(&["recover"]);
    assert!(recover.contains("7 when data was lost"), "{recover}");
    // The README's table: the codes in order, the table's words, the
    // commands it lists.
    let readme = crate::common::docs_text();
    let at = readme
        .find("**What each means, in detail**")
        .expect("the README's exit status table");
    let rows: Vec<&str> = readme[at..]
        .lines()
        .skip_while(|l| !l.starts_with("| status |"))
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .collect();
    let codes: Vec<u8> = rows
        .iter()
        .map(|r| r.split('|').nth(1).unwrap().trim().parse().unwrap())
        .collect();
    let table: Vec<u8> = EXIT_STATUSES.iter().map(|s| s.code).collect();
    assert_eq!(codes, table, "the README's exit statuses");
    for (row, s) in rows.iter().zip(EXIT_STATUSES) {
        assert!(row.contains(s.meaning), "{row}\nlacks {:?}", s.meaning);
        if s.commands.is_empty() {
            continue;
        }
        let named: Vec<&str> = row
            .match_indices("`bench ")
            .filter_map(|(i, _)| row[i + 7..].split([' ', '`']).next())
            .collect();
        assert!(
            !named.is_empty() || row.contains("--daemon"),
            "{row}: names no command"
        );
        for c in named {
            assert!(s.commands.contains(&c), "{row}: names bench {c}");
        }
    }
    for code in codes_named(&readme) {
        assert!(
            table.contains(&code),
            "the README names exit status {code}, not in the table"
        );
    }
}

/// A FIFO at `path` (opening it for reading would wait for a writer).
fn mkfifo(path: &Path) {
    let c = std::ffi::CString::new(path.display().to_string()).unwrap();
    // SAFETY: a valid C string; mkfifo has no other precondition.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

/// Issue 46, items 3 and 4: every file argument of every command (the
/// seven the audit found read unbounded and hanging on a FIFO: `design`
/// inputs and `--config`, `fit`, `plot`, `campaign run`, `control --frf`
/// and `export`; and the others) given a FIFO with no writer or
/// `/dev/zero` is refused within 1 s, exit 2, the message naming the flag
/// (a positional argument: its value), the file and what it is, and
/// nothing is written.
#[test]
fn a_fifo_or_a_device_as_any_file_argument_is_refused_at_once() {
    let dir = tmp();
    let d = dir.path();
    small_frf_csv(d, "X.csv");
    // Each as a FIFO, and as a link to /dev/zero of the same name (the
    // name says what is read: `.mcap` a recording).
    for ext in ["csv", "mcap", "toml", "mcap.part"] {
        mkfifo(&d.join(format!("fifo.{ext}")));
        std::os::unix::fs::symlink("/dev/zero", d.join(format!("zero.{ext}"))).unwrap();
    }
    // (arguments with {F} for the file, the flag named, the FIFO's name,
    // what is read)
    let cases: &[(&str, &str, &str, &str)] = &[
        ("design {F}", "", "fifo.csv", "FRF CSVs"),
        ("design {F}", "", "fifo.mcap", "recordings"),
        (
            "design X.csv --config {F}",
            "--config",
            "fifo.toml",
            "configs",
        ),
        ("fit {F}", "", "fifo.csv", "FRF CSVs"),
        ("fit {F}", "", "fifo.mcap", "recordings"),
        ("fit X.csv --config {F}", "--config", "fifo.toml", "configs"),
        ("plot bode {F}", "", "fifo.csv", "FRF CSVs"),
        (
            "plot nyquist X.csv --config {F}",
            "--config",
            "fifo.toml",
            "configs",
        ),
        (
            "campaign run {F}",
            "campaign file",
            "fifo.toml",
            "campaign files",
        ),
        (
            "control --slow --check-only --frf {F}",
            "--frf",
            "fifo.csv",
            "FRF CSVs",
        ),
        (
            "control --slow --check-only --config {F}",
            "--config",
            "fifo.toml",
            "configs",
        ),
        ("chirp --config {F}", "--config", "fifo.toml", "configs"),
        ("export {F} --to csv", "", "fifo.mcap", "recordings"),
        (
            "export {F} --to csv --topic /sysid/frf",
            "",
            "fifo.mcap",
            "recordings",
        ),
        ("recover {F}", "PART", "fifo.mcap.part", "recordings"),
        ("analyze --config {F}", "--config", "fifo.toml", "configs"),
        ("map --config {F}", "--config", "fifo.toml", "configs"),
        (
            "map --measured {F}",
            "--measured",
            "fifo.csv",
            "measured map CSVs",
        ),
        ("config check {F}", "", "fifo.toml", "configs"),
    ];
    let before = files_in(d);
    let t0 = Instant::now();
    let mut runs = 0;
    for (args, flag, fifo, kind) in cases {
        let mut files = vec![
            (d.join(fifo).display().to_string(), "a FIFO"),
            (
                d.join(fifo.replace("fifo", "zero")).display().to_string(),
                "a character device",
            ),
        ];
        // The audit's own: /dev/zero itself, where no name says a
        // recording.
        if !fifo.contains("mcap") {
            files.push(("/dev/zero".to_string(), "a character device"));
        }
        for (file, what) in files {
            runs += 1;
            let args: Vec<&str> = args
                .split_whitespace()
                .map(|a| if a == "{F}" { file.as_str() } else { a })
                .collect();
            let (o, ended) = run_within(&args, d, Duration::from_secs(1));
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(ended, "{args:?} still running after 1 s: {err}");
            assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
            let named = format!("{flag} {file}: not a regular file ({what}); bench reads {kind} only from regular files");
            assert!(err.contains(named.trim_start()), "{args:?}: {err}");
            assert_eq!(files_in(d), before, "{args:?}: something was written");
        }
    }
    eprintln!("{runs} runs refused in {:?}", t0.elapsed());
}

/// Issue 46, item 3: a file larger than its kind's limit is refused before
/// it is read, naming its size and the limit (sparse files: nothing is
/// written to the disk).
#[test]
fn a_file_over_its_limit_is_refused_naming_the_limit() {
    let dir = tmp();
    let d = dir.path();
    small_frf_csv(d, "X.csv");
    let sparse = |name: &str, bytes: u64| {
        let p = d.join(name);
        std::fs::File::create(&p).unwrap().set_len(bytes).unwrap();
        p.display().to_string()
    };
    let csv = sparse("big.csv", (16 << 20) + 1);
    let toml = sparse("big.toml", (1 << 20) + 1);
    let mcap = sparse("big.mcap", (4u64 << 30) + 1);
    for (args, needle) in [
        (
            vec!["design", &csv],
            format!("{csv}: 16777217 bytes, larger than the 16 MiB bench reads as an FRF CSV"),
        ),
        (
            vec!["fit", &csv],
            format!("{csv}: 16777217 bytes, larger than the 16 MiB"),
        ),
        (
            vec!["plot", "bode", &csv],
            format!("{csv}: 16777217 bytes, larger than the 16 MiB"),
        ),
        (
            vec!["control", "--slow", "--check-only", "--frf", &csv],
            format!("--frf {csv}: 16777217 bytes"),
        ),
        (
            vec!["design", "X.csv", "--config", &toml],
            format!(
                "--config {toml}: 1048577 bytes, larger than the 1 MiB bench reads as a config"
            ),
        ),
        (
            vec!["chirp", "--config", &toml],
            format!("--config {toml}: 1048577 bytes, larger than the 1 MiB"),
        ),
        (
            vec!["fit", &mcap],
            format!("{mcap}: 4294967297 bytes, larger than the 4 GiB bench reads as a recording"),
        ),
        (
            vec!["export", &mcap, "--to", "csv"],
            format!("{mcap}: 4294967297 bytes, larger than the 4 GiB"),
        ),
    ] {
        let (o, ended) = run_within(&args, d, Duration::from_secs(1));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(ended && o.status.code() == Some(2), "{args:?}: {err}");
        assert!(err.contains(&needle), "{args:?}: {needle:?} not in {err}");
    }
}
