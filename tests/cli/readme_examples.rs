//! Every shell example of the README and the book, run (issue 29: "docs
//! that cannot go stale"; issue 42: one runner, transcript-style where
//! output is shown). The ```sh blocks and the `$ ` lines of the ```console
//! blocks ([`crate::common::doc_blocks`]) run in reading order by one
//! `bash` in a scratch directory, with `bench` on `PATH` and `HOME`,
//! `XDG_RUNTIME_DIR` and `XDG_DATA_HOME` inside the scratch directory;
//! every line must exit 0. A console block's lines after a `$ ` line are
//! what it prints: its standard output must be that text, line by line,
//! after [`normalise`] (what depends on the machine or the moment, the
//! absolute paths and UTC stamps of the files written and the loop's wall
//! time and latency figures, is `…` in both). A block that no longer
//! matches fails with both texts, so a sample is regenerated from the
//! binary, never edited by hand.
//!
//! A line runs as written, except where an example names a file the
//! reader already has (a placeholder): the test makes that file first, or
//! puts the real name in place of the example's (the table in
//! [`adapt`], each with its reason). Runs that last until stopped (the
//! live view, a daemon in the foreground, an event subscription) are
//! stopped after a few seconds and must have been running. The lines a
//! machine may not be able to run are their own tests, ignored with the
//! reason where it cannot: the CAN examples (a `vcan0` interface), the
//! EtherCAT examples (root, for network namespaces: skipped otherwise), the
//! latency soak (minutes, run by hand) and the `cargo` lines of the quick
//! start (what `.ci/run` itself runs).

use std::path::{Path, PathBuf};
use std::process::Command;

/// One command of the docs: where it is (`page:line`), its text, and for
/// a console block's `$ ` line the output shown after it.
#[derive(Debug, Clone)]
struct Example {
    at: String,
    line: String,
    shown: Option<String>,
}

/// The shell example lines of the README and the book, in reading order:
/// every non-comment line of a ```sh block, and every `$ ` line of a
/// ```console block with the lines after it (up to the next `$ ` line) as
/// its shown output. A console block must start with a `$ ` line.
fn examples() -> Vec<Example> {
    let mut out: Vec<Example> = Vec::new();
    for b in crate::common::doc_blocks() {
        match b.lang.as_str() {
            "sh" | "bash" => {
                for (at, l) in b.numbered_lines() {
                    let t = l.trim();
                    if !t.is_empty() && !t.starts_with('#') {
                        out.push(Example {
                            at,
                            line: l.to_string(),
                            shown: None,
                        });
                    }
                }
            }
            "console" => {
                let mut mine: Vec<Example> = Vec::new();
                for (at, l) in b.numbered_lines() {
                    if let Some(cmd) = l.strip_prefix("$ ") {
                        mine.push(Example {
                            at,
                            line: cmd.to_string(),
                            shown: Some(String::new()),
                        });
                    } else {
                        let e = mine.last_mut().unwrap_or_else(|| {
                            panic!("{at}: a console block starts with a `$ ` command line")
                        });
                        let shown = e.shown.get_or_insert_with(String::new);
                        shown.push_str(l);
                        shown.push('\n');
                    }
                }
                out.extend(mine);
            }
            _ => {}
        }
    }
    out
}

/// Replaces what depends on the machine or the moment by `…`.
fn normalise(text: &str) -> Vec<String> {
    text.lines()
        .map(|l| {
            let t = l.trim_end();
            // Files: `  recording   /any/path/chirp-<stamp>.mcap` etc.
            if let Some(i) = t.find('/') {
                let label = &t[..i];
                if [
                    "recording",
                    "FRF (CSV)",
                    "Bode plot",
                    "catalogue",
                    "plot",
                    "updated bench",
                ]
                .iter()
                .any(|k| label.trim() == *k)
                {
                    return format!("{label}…");
                }
            }
            // The loop's timing: wall time and latency vary by machine.
            if t.starts_with("loop:") {
                return t.split(',').next().unwrap_or(t).to_string() + ", …";
            }
            for label in ["  wake-up latency", "  compute"] {
                if t.starts_with(label) {
                    return format!("{label} …");
                }
            }
            t.to_string()
        })
        .collect()
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Which test runs a line.
#[derive(Debug, PartialEq)]
enum Runner {
    /// The main test.
    Main,
    /// Needs `vcan0`.
    Can,
    /// Needs root: network namespaces and a veth pair (EtherCAT).
    Ethercat,
    /// The latency soak.
    Soak,
    /// The quick start's `cargo` lines.
    Cargo,
}

fn runner(line: &str) -> Runner {
    if line.starts_with("cargo ") || line.starts_with("tests/run") {
        Runner::Cargo
    } else if line.contains("vcan0") {
        Runner::Can
    } else if line.contains(" ecm") || line.contains(" ecs") {
        Runner::Ethercat
    } else if line.contains("benches/latency-vs-cyclictest.sh") {
        Runner::Soak
    } else {
        Runner::Main
    }
}

/// Waits (≤ 10 s) until `$1` exists.
const WAIT_FOR: &str = "wait_for() { for _ in $(seq 100); do [ -e \"$1\" ] && [ -s \"$1\" -o -S \"$1\" ] && return 0; sleep 0.1; done; echo \"$1 never appeared\" >&2; return 1; }";

/// `line` stopped with SIGINT after `s` seconds (its exit status kept:
/// 130 when it was still running then).
fn until_stopped(s: u32, line: &str) -> String {
    format!(
        "timeout --preserve-status -s INT {s} bash -c {}",
        quote(line)
    )
}

/// Runs `line` for at most `s` seconds: it must still be running then
/// (stopped with SIGINT: exit 130) or have ended well.
fn stopped_after(s: u32, line: &str) -> String {
    format!("{} || [ $? -eq 130 ]", until_stopped(s, line))
}

/// The line as the test runs it: setup commands first where the example
/// names a file the reader already has, the example's placeholder names
/// replaced by the files the test made, runs that last until stopped
/// stopped. Returns `(setup, line)`.
fn adapt(line: &str, campaign_done: &mut bool) -> (Vec<String>, String) {
    let mut setup = Vec::new();
    let mut l = line.to_string();
    // `bench fit frf.csv` / `rec.mcap`: any chirp's CSV and recording.
    if l.contains("frf.csv") && l.starts_with("bench fit") || l.contains("rec.mcap") {
        setup.push("[ -e rec.mcap ] || bench chirp --out rec.mcap >/dev/null".into());
        if l.starts_with("bench fit frf.csv") {
            setup.push("cp rec.frf.csv frf.csv".into());
        }
    }
    // The start of an update: the reader's own bench file.
    if l.contains("--config start.toml") {
        setup.push("[ -e start.toml ] || bench config default > start.toml".into());
    }
    // `excitation.kind = "multisine"` in the reader's file, without the
    // sweep's keys (as the README's TOML shows).
    if l.contains("my-multisine.toml") {
        setup.push(
            r#"bench config default | sed -e 's/^kind = "exponential"/kind = "multisine"/' -e '/^\[chirp\]/,/^\[/{/^duration_s = /d;/^taper_s = /d}' > my-multisine.toml"#
                .into(),
        );
    }
    // The map examples read the campaign example's directory, which the
    // README makes later: the campaign's own line runs first.
    if l.starts_with("bench campaign run --out fig5-10") {
        if *campaign_done {
            // Ran before the map examples (as written).
            return (setup, "bench campaign status fig5-10 >/dev/null".into());
        }
        *campaign_done = true;
    } else if l.contains("fig5-10") && !*campaign_done {
        setup.push("bench campaign run --out fig5-10 >/dev/null".into());
        *campaign_done = true;
    }
    // The emulator's pty: its first line of output.
    if l.starts_with("bench emulate serial &") {
        return (
            vec![],
            "bench emulate serial > pty.txt & wait_for pty.txt".into(),
        );
    }
    l = l.replace("serial:/dev/pts/3", "serial:$(head -n1 pty.txt)");
    // A recording's name made of its start time: the one made here.
    l = l.replace(
        "recordings/chirp-20261122T101500Z.mcap",
        "$(ls recordings/chirp-*.mcap | head -n1)",
    );
    if l.contains(" run.mcap") {
        setup.push("[ -e run.mcap ] || cp rec.mcap run.mcap".into());
        // The export's own frf.csv, not the fit example's.
        setup.push("rm -f frf.csv".into());
    }
    // A system daemon's socket: this daemon's.
    l = l.replace("/run/bench/bench.sock", "$XDG_RUNTIME_DIR/bench.sock");
    // A daemon in the background: wait for its socket (the one it names).
    if l.starts_with("bench serve --socket") {
        let code = l.split(" #").next().unwrap_or("").trim_end().to_string();
        if code.ends_with('&') {
            let socket = code
                .split('"')
                .nth(1)
                .unwrap_or("$XDG_RUNTIME_DIR/bench.sock");
            l = format!("{code} wait_for \"{socket}\"");
        }
    }
    // A bench job through the daemon: in virtual time (`--pace off`, the
    // simulator's clock). What this test checks is that the line runs;
    // the daemon's real-time jobs are tests/cli/daemon.rs's subject, where
    // a host-stall watch tells this VM's own stalls (tens of ms, past the
    // loop's delay margin) from the loop's.
    if (l.starts_with("bench control ") || l.starts_with("bench chirp "))
        && l.contains("--daemon")
        && !l.contains("--pace")
    {
        let code = l.split(" #").next().unwrap_or("").trim_end();
        l = format!("{code} --pace off");
    }
    // An exit the example's comment announces (9: a flagged fit, the
    // figure written).
    if l.contains("(exit 9:") {
        return (setup, format!("{l}\n[ $? -eq 9 ]"));
    }
    // A real-time run on this machine: `--realtime`, or the host over the
    // emulator's link.
    if l.contains("--realtime") || l.contains("--backend serial:") {
        return (setup, in_realtime_turn(&l));
    }
    // Runs until stopped: the live view, a daemon in the foreground, an
    // event subscription.
    if l.contains("--live") {
        return (setup, stopped_after(4, &l));
    }
    if l.contains("\"cmd\":\"subscribe\"") {
        return (
            setup,
            format!("timeout 3 bash -c {} || [ $? -eq 124 ]", quote(&l)),
        );
    }
    (setup, l)
}

/// A real-time line as the test runs it. It takes the real-time turn of
/// the other tests (`common::one_at_a_time`'s lock file), and a fault of a
/// stalled host is tried once more: `link` or `link_latency` (no sample
/// within the bound) or `overruns` (the loop behind its deadlines beyond
/// the bound). With the default bench that bound is the loop's delay
/// margin plus one period of its crossover (about 24 ms), and this 2-core
/// VM stalls even SCHED_FIFO threads for up to ~70 ms while the other
/// tests load it (measured; `hardware.rs` and `stalls.rs` give their runs
/// room in the config instead). The fault is right on such a stall; the
/// example runs the default bench as written, so the test retries instead.
/// Any other failure, or a second stall fault, fails the example. A live
/// view runs until stopped (SIGINT after 4 s: exit 130). The command runs
/// without a trailing comment, which would swallow the rest.
fn in_realtime_turn(line: &str) -> String {
    let code = line.split(" #").next().unwrap_or("").trim_end();
    let lock = "flock \"$BENCH_REALTIME_LOCK\"";
    let (run, ok) = if code.contains("--live") {
        (
            format!("{lock} {}", until_stopped(4, code)),
            "[ $rc -eq 0 -o $rc -eq 130 ]",
        )
    } else {
        (format!("{lock} {code}"), "[ $rc -eq 0 ]")
    };
    format!(
        "{{ {run}; }} 2> rt-err.txt; rc=$?; cat rt-err.txt >&2; {ok} || \
         {{ grep -q '^error: safety fault: \\(link\\|link_latency\\|overruns\\) at tick' rt-err.txt \
         && echo 'a stall fault on a loaded machine: once more' >&2 && {{ {run}; rc=$?; {ok}; }}; }}"
    )
}

/// `s` single-quoted for bash.
fn quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}

/// A scratch directory set up as a reader's: `bench` on `PATH`, a
/// `recordings/` directory (a checkout has one), the repository's
/// `bench-config/` and `benches/`.
fn scratch() -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let bin = dir.path().join("bin");
    for d in ["bin", "home", "run", "data", "work/recordings"] {
        std::fs::create_dir_all(dir.path().join(d)).unwrap();
    }
    std::os::unix::fs::symlink(env!("CARGO_BIN_EXE_bench"), bin.join("bench")).unwrap();
    let work = dir.path().join("work");
    for d in ["bench-config", "benches"] {
        std::os::unix::fs::symlink(root().join(d), work.join(d)).unwrap();
    }
    (dir, work)
}

/// Runs `lines` as one bash script in a scratch directory; panics naming
/// the first line that failed, with the tail of its output, or the first
/// shown output that is not what its command printed. Returns the
/// script's standard error.
fn run_lines(lines: &[Example]) -> String {
    let (dir, work) = scratch();
    let shown_dir = dir.path().join("shown");
    std::fs::create_dir(&shown_dir).unwrap();
    let mut script = String::from(
        "set -a -u -o pipefail\ntrap 'kill $(jobs -p) 2>/dev/null; wait 2>/dev/null' EXIT\n",
    );
    script.push_str(WAIT_FOR);
    script.push('\n');
    let mut campaign_done = false;
    for (k, e) in lines.iter().enumerate() {
        let (n, line) = (&e.at, &e.line);
        let (setup, l) = adapt(line, &mut campaign_done);
        // A shown output: the command's standard output, kept.
        let l = match e.shown {
            Some(_) => format!("{{ {l}\n}} > {}", shown_dir.join(k.to_string()).display()),
            None => l,
        };
        script.push_str(&format!(
            "echo {} >&2\n",
            quote(&format!("::: {n}: {line}"))
        ));
        for s in setup {
            script.push_str(&format!(
                "{s} || {{ echo {} >&2; exit 1; }}\n",
                quote(&format!("FAILED setup of {n}: {s}"))
            ));
        }
        script.push_str(&format!(
            "{l}\nrc=$?; [ $rc -eq 0 ] || {{ echo \"FAILED (exit $rc) {n}: \"{} >&2; exit 1; }}\n",
            quote(line)
        ));
    }
    let log = dir.path().join("log.txt");
    let out = Command::new("bash")
        .arg("-c")
        .arg(&script)
        .current_dir(&work)
        .env(
            "PATH",
            format!(
                "{}:{}",
                dir.path().join("bin").display(),
                std::env::var("PATH").unwrap_or_default()
            ),
        )
        .env("HOME", dir.path().join("home"))
        .env("XDG_RUNTIME_DIR", dir.path().join("run"))
        .env("XDG_DATA_HOME", dir.path().join("data"))
        .env(
            "BENCH_REALTIME_LOCK",
            Path::new(env!("CARGO_TARGET_TMPDIR")).join("realtime.lock"),
        )
        .env("EDITOR", "true")
        .env("MANPAGER", "cat")
        .env("PAGER", "cat")
        .env_remove("RUST_LOG")
        .env_remove("BENCH_LOG")
        .stdout(std::fs::File::create(&log).unwrap())
        .stderr(std::process::Stdio::piped())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    if !out.status.success() {
        let tail: Vec<&str> = err.lines().rev().take(40).collect();
        let tail: Vec<&str> = tail.into_iter().rev().collect();
        let stdout = std::fs::read_to_string(&log).unwrap_or_default();
        let stdout_tail: Vec<&str> = stdout.lines().rev().take(15).collect();
        panic!(
            "a README example failed:\n{}\n--- stdout (last lines, reversed) ---\n{}",
            tail.join("\n"),
            stdout_tail.join("\n")
        );
    }
    // Every line ran: its marker was printed (anywhere in a line: a
    // background example may have written a line without its end).
    let missing: Vec<&String> = lines
        .iter()
        .map(|e| &e.at)
        .filter(|n| !err.contains(&format!("::: {n}: ")))
        .collect();
    assert!(
        missing.is_empty(),
        "these lines did not run: {missing:?}\n{err}"
    );
    for (k, e) in lines.iter().enumerate() {
        let Some(shown) = &e.shown else { continue };
        let got = std::fs::read_to_string(shown_dir.join(k.to_string())).unwrap();
        assert_eq!(
            normalise(shown),
            normalise(&got),
            "{}: the output shown for `{}` is stale; the binary prints:\n{got}",
            e.at,
            e.line
        );
    }
    err.into_owned()
}

/// The README's one-line stderr samples (```text blocks of one line
/// starting with one of `starts`), each with what depends on the machine
/// (the free space) cut off.
fn stderr_samples(starts: &[&str]) -> Vec<String> {
    crate::common::doc_blocks()
        .into_iter()
        .filter(|b| b.lang == "text" && b.body.lines().count() == 1)
        .map(|b| b.body.trim_end().to_string())
        .filter(|l| starts.iter().any(|s| l.starts_with(s)))
        .map(|l| machine_free(&l))
        .collect()
}

/// `line` without its `; … free there` tail (the machine's free space).
fn machine_free(line: &str) -> String {
    line.split("; ")
        .filter(|p| !p.ends_with("free there"))
        .collect::<Vec<_>>()
        .join("; ")
}

/// Every example a reader can run on this machine.
#[test]
#[cfg_attr(
    not(all(bench_has_bash, bench_has_man)),
    ignore = "needs bash and man on PATH"
)]
fn every_readme_example_runs() {
    let lines: Vec<Example> = examples()
        .into_iter()
        .filter(|e| runner(&e.line) == Runner::Main)
        .collect();
    assert!(
        lines.len() > 50,
        "{} lines: the README lost its examples?",
        lines.len()
    );
    // The quick start's summary is shown as a transcript.
    assert!(
        lines
            .iter()
            .any(|e| e.line == "bench chirp"
                && e.shown.as_ref().is_some_and(|s| s.lines().count() > 20)),
        "the getting-started transcript of `bench chirp` is gone"
    );
    let err = run_lines(&lines);
    // The README's stderr samples are what the examples printed: the
    // campaign's disk estimate, the live view's pacing note.
    let samples = stderr_samples(&["disk: about", "note: --live without"]);
    assert_eq!(samples.len(), 2, "{samples:?}");
    let printed: Vec<String> = err.lines().map(machine_free).collect();
    for s in samples {
        assert!(
            printed.contains(&s),
            "the README's sample is not what the binary prints:\n  {s}\nprinted:\n{}",
            printed
                .iter()
                .filter(|l| l.starts_with(&s[..10]))
                .cloned()
                .collect::<Vec<_>>()
                .join("\n")
        );
    }
}

/// The CAN examples: the emulator and a chirp over `vcan0`.
#[test]
#[cfg_attr(
    not(bench_has_vcan0),
    ignore = "no vcan0 here: ip link add vcan0 type vcan && ip link set up vcan0, then touch build.rs"
)]
fn readme_can_examples_run() {
    let lines: Vec<Example> = examples()
        .into_iter()
        .filter(|e| runner(&e.line) == Runner::Can)
        .map(|mut e| {
            // The emulator runs in the background for the chirp.
            if e.line.starts_with("bench emulate can") {
                e.line = "bench emulate can --iface vcan0 & sleep 1".to_string();
            }
            e
        })
        .collect();
    assert_eq!(lines.len(), 2);
    run_lines(&lines);
}

/// The EtherCAT examples: two namespaces, a veth pair, the virtual slave
/// and a short chirp (root only; `tests/servers/ethercat.rs` runs the same and
/// more). The namespaces get names of this run.
#[test]
fn readme_ethercat_examples_run() {
    // SAFETY: no preconditions.
    if unsafe { libc::geteuid() } != 0 {
        eprintln!("SKIPPED: not root (network namespaces, veth, raw sockets)");
        return;
    }
    let id = std::process::id();
    let lines: Vec<Example> = examples()
        .into_iter()
        .filter(|e| runner(&e.line) == Runner::Ethercat)
        .map(|mut e| {
            let l = e
                .line
                .replace("ecm ", &format!("ecm{id} "))
                .replace("ecs ", &format!("ecs{id} "));
            let l = if l.ends_with(" ecs") {
                format!("{l}{id}")
            } else {
                l
            };
            // The slave runs in the background for the chirp.
            e.line = if l.ends_with('&') {
                format!("{l} sleep 1")
            } else {
                l
            };
            e
        })
        .collect();
    assert_eq!(lines.len(), 6, "{lines:?}");
    run_lines(&lines);
}

/// The latency soak against cyclictest (minutes of SCHED_FIFO load).
#[test]
#[ignore = "the latency soak takes minutes of real-time load: run by hand (cargo test --test cli -- --ignored readme_latency_soak_runs)"]
fn readme_latency_soak_runs() {
    let lines: Vec<Example> = examples()
        .into_iter()
        .filter(|e| runner(&e.line) == Runner::Soak)
        .map(|mut e| {
            e.line = e.line.replace("sudo ", "");
            e
        })
        .collect();
    assert_eq!(lines.len(), 2);
    run_lines(&lines);
}

/// The quick start's lines are what `.ci/run` runs on a fresh clone
/// (`tests/run` is this test run itself); here they are only checked to
/// be the commands `.ci/run` uses.
#[test]
fn readme_cargo_lines_are_what_ci_runs() {
    let ci = std::fs::read_to_string(root().join(".ci/run")).unwrap();
    let cargo: Vec<String> = examples()
        .into_iter()
        .filter(|e| runner(&e.line) == Runner::Cargo)
        .map(|e| e.line)
        .collect();
    assert!(cargo.iter().any(|l| l == "tests/run"), "{cargo:?}");
    assert!(cargo.iter().any(|l| l == "cargo run -- chirp"), "{cargo:?}");
    assert!(
        ci.lines().any(|l| l.trim() == "tests/run"),
        "the README's test command is not what .ci/run runs"
    );
    assert!(
        ci.contains("bench=\"${CARGO_TARGET_DIR:-target}/debug/bench\"") && ci.contains("\"$bench\" chirp\n"),
        "the README's main command (cargo run -- chirp: target/debug/bench chirp) is not what .ci/run runs"
    );
    for l in &cargo {
        assert!(
            l == "tests/run"
                || l.starts_with("cargo run -- ")
                || l.starts_with("cargo build --release")
                || l.starts_with("cargo install --locked --path ."),
            "an unexpected cargo line in the docs: {l}"
        );
    }
}
