//! The first hour of a new user (issue 17, items 1 and 4): the installed
//! binary, copied out of the build tree and run from an empty directory,
//! runs `bench chirp` and `bench control --fast` on the built-in Chapter 5
//! bench and writes its recordings where the README says (XDG base
//! directories, or `./recordings` when it exists); `bench config default`
//! prints a file `--config` takes; the completion script and man page
//! cover every command.
//!
//! The references are independent of the code under test: the shipped
//! `bench-config/sr4dof-ch5.toml` read from the source tree, the XDG Base
//! Directory specification's defaults, `bash -n` and `groff`/`man`.

use crate::common;

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The binary, copied into its own directory (as `cargo install` would
/// put it somewhere that is not the repository).
struct Installed {
    _dir: tempfile::TempDir,
    bin: PathBuf,
}

/// Copies the binary to a directory of its own. Under a lock that every
/// spawn of this file also takes: a copy still open for writing when
/// another test thread forks would leak into that child and make the
/// `exec` of the copy fail with ETXTBSY ("Text file busy").
fn install() -> Installed {
    let _g = SPAWN.lock().unwrap_or_else(|e| e.into_inner());
    let dir = common::tmp();
    let bin = dir.path().join("bench");
    std::fs::copy(env!("CARGO_BIN_EXE_bench"), &bin).expect("copy the binary");
    Installed { _dir: dir, bin }
}

static SPAWN: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// `c.output()` with the fork under [`SPAWN`].
fn output_locked(c: &mut Command) -> std::io::Result<Output> {
    let child = {
        let _g = SPAWN.lock().unwrap_or_else(|e| e.into_inner());
        c.stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()?
    };
    child.wait_with_output()
}

/// A user's world: an empty working directory, a home and a data home of
/// its own.
struct World {
    _root: tempfile::TempDir,
    cwd: PathBuf,
    home: PathBuf,
    data_home: PathBuf,
}

fn world() -> World {
    let root = common::tmp();
    let cwd = root.path().join("work");
    let home = root.path().join("home");
    let data_home = root.path().join("data");
    for d in [&cwd, &home] {
        std::fs::create_dir(d).unwrap();
    }
    World {
        _root: root,
        cwd,
        home,
        data_home,
    }
}

impl Installed {
    /// `bench args` in `w.cwd`, with `HOME` and (if `xdg`) `XDG_DATA_HOME`
    /// pointing into `w`, nothing else of the caller's environment that
    /// could lead it back to the repository.
    fn run(&self, w: &World, xdg: Option<&Path>, args: &[&str]) -> Output {
        let mut c = Command::new(&self.bin);
        c.current_dir(&w.cwd)
            .args(args)
            .env_clear()
            .env("PATH", std::env::var_os("PATH").unwrap_or_default())
            .env("HOME", &w.home);
        if let Some(x) = xdg {
            c.env("XDG_DATA_HOME", x);
        }
        output_locked(&mut c).expect("run the installed bench")
    }
}

fn ok(o: &Output, what: &str) {
    assert!(
        o.status.success(),
        "{what}: {:?}\nstdout:\n{}\nstderr:\n{}",
        o.status,
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

fn json(o: &Output) -> Value {
    common::json_stdout(o)
}

/// The `.mcap` files in `dir` (none if it does not exist).
fn recordings_in(dir: &Path) -> Vec<PathBuf> {
    if !dir.exists() {
        return Vec::new();
    }
    common::files_in(dir)
        .into_iter()
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect()
}

/// The `path` the recording's `bench.config` metadata names.
fn recorded_config_path(rec: &Path) -> String {
    let bytes = std::fs::read(rec).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("summary");
    let idx = summary
        .metadata_indexes
        .iter()
        .find(|m| m.name == "bench.config")
        .expect("bench.config metadata");
    mcap::read::metadata(&bytes, idx).unwrap().metadata["path"].clone()
}

#[test]
fn from_an_empty_directory_recordings_go_to_the_xdg_data_home() {
    let bench = install();
    let w = world();
    let want = w.data_home.join("bench").join("recordings");

    let o = bench.run(
        &w,
        Some(&w.data_home),
        &["chirp", "--duration-s", "2", "--json"],
    );
    ok(&o, "bench chirp");
    let s = json(&o);
    let rec = PathBuf::from(s["recording"].as_str().unwrap());
    assert!(rec.is_absolute(), "{rec:?}");
    assert_eq!(rec.parent().unwrap(), want, "summary: {s}");
    assert_eq!(recordings_in(&want), std::slice::from_ref(&rec));
    for p in ["frf_csv", "plot"] {
        let f = PathBuf::from(s[p].as_str().unwrap());
        assert!(
            f.is_absolute() && f.starts_with(&want) && f.is_file(),
            "{p}: {f:?}"
        );
    }
    assert_eq!(recorded_config_path(&rec), "built-in (sr4dof-ch5)");
    // The directory was made with the project's directory mode (rwxr-x---,
    // less what the umask takes).
    use std::os::unix::fs::PermissionsExt;
    let mode = std::fs::metadata(&want).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode & !0o750, 0, "{mode:o}");
    // Nothing in the working directory.
    assert_eq!(std::fs::read_dir(&w.cwd).unwrap().count(), 0);

    // The human summary names the same directory.
    let o = bench.run(&w, Some(&w.data_home), &["control", "--fast"]);
    ok(&o, "bench control --fast");
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains(&want.display().to_string()), "{out}");
    let recs = recordings_in(&want);
    assert_eq!(recs.len(), 2, "{recs:?}");
    assert!(recs.iter().any(|r| r
        .file_name()
        .unwrap()
        .to_string_lossy()
        .starts_with("control-fast-")));
}

#[test]
fn without_xdg_data_home_recordings_go_under_home_local_share() {
    let bench = install();
    let w = world();
    // The XDG spec: unset, empty or relative XDG_DATA_HOME all mean
    // $HOME/.local/share.
    let want = w.home.join(".local/share/bench/recordings");
    for (i, xdg) in [None, Some(""), Some("relative/data")]
        .into_iter()
        .enumerate()
    {
        let o = bench.run(
            &w,
            xdg.map(Path::new),
            &["chirp", "--duration-s", "0.5", "--json"],
        );
        ok(&o, &format!("XDG_DATA_HOME={xdg:?}"));
        let rec = PathBuf::from(json(&o)["recording"].as_str().unwrap().to_string());
        assert_eq!(rec.parent().unwrap(), want, "XDG_DATA_HOME={xdg:?}");
        assert_eq!(recordings_in(&want).len(), i + 1);
    }
    assert!(!w.cwd.join("relative").exists());
}

#[test]
fn a_recordings_directory_in_the_working_directory_wins() {
    let bench = install();
    let w = world();
    let local = w.cwd.join("recordings");
    std::fs::create_dir(&local).unwrap();
    let o = bench.run(
        &w,
        Some(&w.data_home),
        &["chirp", "--duration-s", "0.5", "--json"],
    );
    ok(&o, "bench chirp");
    let rec = PathBuf::from(json(&o)["recording"].as_str().unwrap().to_string());
    assert_eq!(rec.parent().unwrap(), local);
    assert_eq!(recordings_in(&local), [rec]);
    assert!(!w.data_home.exists(), "nothing under the data home");
    let o = bench.run(&w, Some(&w.data_home), &["control", "--fast", "--json"]);
    ok(&o, "bench control --fast");
    let rec = PathBuf::from(json(&o)["recording"].as_str().unwrap().to_string());
    assert_eq!(rec.parent().unwrap(), local);
}

#[test]
fn with_no_home_at_all_the_error_names_out_and_nothing_is_written() {
    let bench = install();
    let w = world();
    let o = output_locked(
        Command::new(&bench.bin)
            .current_dir(&w.cwd)
            .args(["chirp", "--duration-s", "0.5"])
            .env_clear(),
    )
    .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--out") && err.contains("HOME"), "{err}");
    assert_eq!(std::fs::read_dir(&w.cwd).unwrap().count(), 0);
    // With --out it runs.
    let o = output_locked(
        Command::new(&bench.bin)
            .current_dir(&w.cwd)
            .args(["chirp", "--duration-s", "0.5", "--out", "run.mcap"])
            .env_clear(),
    )
    .unwrap();
    ok(&o, "bench chirp --out run.mcap");
    assert!(w.cwd.join("run.mcap").is_file());
}

#[test]
fn config_default_prints_the_shipped_file_and_config_takes_it() {
    let bench = install();
    let w = world();
    let o = bench.run(&w, Some(&w.data_home), &["config", "default"]);
    ok(&o, "bench config default");
    let shipped =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"))
            .unwrap();
    assert_eq!(o.stdout, shipped);
    // `bench config default > my.toml`, edited, then `--config my.toml`.
    let text = String::from_utf8(o.stdout)
        .unwrap()
        .replace("mass_asymmetry = 0.10 ", "mass_asymmetry = -0.05");
    assert!(text.contains("mass_asymmetry = -0.05"));
    std::fs::write(w.cwd.join("my.toml"), text).unwrap();
    let o = bench.run(&w, Some(&w.data_home), &["config", "check", "my.toml"]);
    ok(&o, "bench config check my.toml");
    let o = bench.run(
        &w,
        Some(&w.data_home),
        &[
            "chirp",
            "--config",
            "my.toml",
            "--duration-s",
            "0.5",
            "--json",
        ],
    );
    ok(&o, "bench chirp --config my.toml");
    let s = json(&o);
    assert_eq!(s["mass_asymmetry"].as_f64(), Some(-0.05), "{s}");
    let rec = PathBuf::from(s["recording"].as_str().unwrap());
    assert_eq!(recorded_config_path(&rec), "my.toml");
    // A missing --config is still an error naming it, not the built-in.
    let o = bench.run(&w, Some(&w.data_home), &["chirp", "--config", "nope.toml"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("nope.toml"));
}

#[test]
fn control_check_only_creates_no_directory() {
    let bench = install();
    let w = world();
    let o = bench.run(
        &w,
        Some(&w.data_home),
        &["control", "--fast", "--check-only"],
    );
    ok(&o, "bench control --fast --check-only");
    assert!(!w.data_home.exists());
    assert_eq!(std::fs::read_dir(&w.cwd).unwrap().count(), 0);
}

/// The subcommands of `bench`, from its help (not from the clap tree the
/// generators read).
fn subcommands(bench: &Installed, w: &World) -> Vec<String> {
    let o = bench.run(w, None, &["--help"]);
    ok(&o, "bench --help");
    let help = String::from_utf8_lossy(&o.stdout).to_string();
    let cmds: Vec<String> = help
        .split("Commands:")
        .nth(1)
        .expect("a Commands: section")
        .lines()
        .skip(1) // the rest of the "Commands:" line
        .take_while(|l| !l.trim().is_empty())
        .filter_map(|l| l.split_whitespace().next().map(str::to_string))
        .filter(|c| c != "help")
        .collect();
    for c in [
        "chirp",
        "control",
        "emulate",
        "serve",
        "daemon",
        "recover",
        "config",
        "completions",
        "man",
    ] {
        assert!(cmds.iter().any(|x| x == c), "{c} not in {cmds:?}");
    }
    cmds
}

#[test]
#[cfg_attr(
    not(bench_has_bash),
    ignore = "checking the script with `bash -n` needs bash on PATH (`build.rs` probes it)"
)]
fn the_bash_completion_script_is_valid_and_knows_every_command() {
    let bench = install();
    let w = world();
    let cmds = subcommands(&bench, &w);
    let o = bench.run(&w, None, &["completions", "bash"]);
    ok(&o, "bench completions bash");
    let script = String::from_utf8(o.stdout).unwrap();
    for c in &cmds {
        assert!(script.contains(c.as_str()), "{c} missing from the script");
    }
    assert!(script.contains("--mass-asymmetry-pct"));
    assert!(
        script.contains("complete -F"),
        "registers a completion function"
    );
    let path = w.cwd.join("bench.bash");
    std::fs::write(&path, &script).unwrap();
    let o = output_locked(Command::new("bash").arg("-n").arg(&path)).expect("bash runs");
    assert!(
        o.status.success(),
        "bash -n: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    for shell in ["zsh", "fish", "elvish", "powershell"] {
        let o = bench.run(&w, None, &["completions", shell]);
        ok(&o, shell);
        let s = String::from_utf8_lossy(&o.stdout);
        assert!(s.contains("chirp") && s.contains("completions"), "{shell}");
    }
    let o = bench.run(&w, None, &["completions", "tcsh"]);
    assert_eq!(o.status.code(), Some(2));
}

/// Renders roff with `groff -k -man -Tutf8` or `man -l -`; `None` when
/// neither is installed.
fn render_roff(roff: &[u8]) -> Option<String> {
    use std::io::Write;
    use std::process::Stdio;
    for (prog, args) in [
        // -k: through preconv, as man(1) does (the page is UTF-8: Δ, µ, −).
        ("groff", &["-k", "-man", "-Tutf8", "-ww"][..]),
        ("man", &["-l", "-"][..]),
    ] {
        let spawned = {
            let _g = SPAWN.lock().unwrap_or_else(|e| e.into_inner());
            Command::new(prog)
                .args(args)
                .env("MANPAGER", "cat")
                .env("PAGER", "cat")
                .env("MANWIDTH", "200")
                .stdin(Stdio::piped())
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
        };
        let Ok(mut child) = spawned else {
            continue;
        };
        child.stdin.take().unwrap().write_all(roff).unwrap();
        let o = child.wait_with_output().unwrap();
        assert!(
            o.status.success(),
            "{prog}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!err.contains("warning"), "{prog}: {err}");
        return Some(String::from_utf8_lossy(&o.stdout).to_string());
    }
    None
}

#[test]
#[cfg_attr(
    not(bench_has_man),
    ignore = "rendering the page needs groff or man on PATH (`build.rs` probes them)"
)]
fn the_man_page_renders_and_mentions_every_command() {
    let bench = install();
    let w = world();
    let cmds = subcommands(&bench, &w);
    let o = bench.run(&w, None, &["man"]);
    ok(&o, "bench man");
    let roff = o.stdout;
    let text = String::from_utf8_lossy(&roff);
    assert!(text.starts_with(".ie") || text.contains(".TH"), "roff");
    match render_roff(&roff) {
        Some(page) => {
            // Rendering may hyphenate or embolden: compare plain words.
            // Drop grotty's overstrikes ("c\bc" bold, "_\bc" underline).
            let mut plain_chars: Vec<char> = Vec::new();
            for c in page.chars() {
                if c == '\u{8}' {
                    plain_chars.pop();
                } else {
                    plain_chars.push(c);
                }
            }
            let plain: String = plain_chars
                .into_iter()
                .filter(|c| !c.is_control() || *c == '\n')
                // groff -Tutf8 draws "-" as a hyphen or minus sign.
                .map(|c| {
                    if matches!(c, '\u{2010}' | '\u{2212}') {
                        '-'
                    } else {
                        c
                    }
                })
                .collect();
            for c in &cmds {
                assert!(
                    plain.contains(&format!("bench {c}")) || plain.contains(&format!("bench-{c}")),
                    "{c} not in the rendered page:\n{plain}"
                );
            }
            assert!(
                plain.contains("--mass-asymmetry-pct"),
                "options of the commands"
            );
        }
        None => panic!("neither groff nor man ran, although build.rs found one"),
    }
    for c in &cmds {
        assert!(text.contains(&format!("BENCH {}", c.to_uppercase())), "{c}");
    }
    // One command's page, and one page per command.
    let o = bench.run(&w, None, &["man", "chirp"]);
    ok(&o, "bench man chirp");
    assert!(String::from_utf8_lossy(&o.stdout).contains("mass\\-asymmetry\\-pct"));
    let o = bench.run(&w, None, &["man", "nope"]);
    assert_eq!(o.status.code(), Some(2));
    let o = bench.run(&w, None, &["man", "--out", "pages"]);
    ok(&o, "bench man --out pages");
    for c in &cmds {
        let p = w.cwd.join("pages").join(format!("bench-{c}.1"));
        assert!(p.is_file(), "{p:?}");
    }
    assert!(w.cwd.join("pages/bench.1").is_file());
    assert!(w.cwd.join("pages/bench-emulate-serial.1").is_file());
}
