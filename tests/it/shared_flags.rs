//! The command line's shared flags are declared once (issue 43, item 2):
//! `--config`, `--out`, `--png`, `--no-plot`, `--json`, `--daemon` and
//! `--overwrite` are each one field of one flag struct in `src/cli/mod.rs`
//! (`ConfigFlag`, `OutFlag`, `PngFlag`, `NoPlotFlag`, `JsonFlag`,
//! `JobFlags`, `OutputFlags`), which every command flattens
//! (`#[command(flatten)]`); a command says what its `--out` or `--png` is
//! with `mut_arg`, never by declaring the flag again.
//!
//! The test reads every file of `src/cli/`: a field with one of those
//! names whose nearest attribute is an `#[arg(…)]` declares the flag, and
//! only the flag structs may. Two other flags share a name and mean
//! something else, and are named here with the reason ([`OTHER_MEANING`]).
//! The reader is tested on made-up code
//! ([`the_reader_finds_a_second_declaration`]).

use std::path::Path;

/// The shared flags, as their fields are named.
const SHARED: [&str; 7] = [
    "config",
    "out",
    "png",
    "no_plot",
    "json",
    "daemon",
    "overwrite",
];

/// Fields that share a name with a shared flag and are no job's flag:
/// (file, field, why).
const OTHER_MEANING: &[(&str, &str, &str)] = &[
    (
        "docs.rs",
        "out",
        "`bench docs man --out DIR`: the directory of the manual pages, no job's output",
    ),
    (
        "daemon_cmd.rs",
        "json",
        "`bench daemon --json`: the daemon's answer unchanged, a global flag of the client",
    ),
];

/// The shared-flag fields `src` declares with `#[arg(…)]`: (field, line).
fn declarations(src: &str) -> Vec<(String, usize)> {
    let lines: Vec<&str> = src.lines().collect();
    let mut found = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let t = line.trim();
        let t = t
            .strip_prefix("pub(super) ")
            .or_else(|| t.strip_prefix("pub "))
            .unwrap_or(t);
        let Some((name, _)) = t.split_once(':') else {
            continue;
        };
        if !SHARED.contains(&name) || !t.ends_with(',') {
            continue;
        }
        // The nearest line above that is neither blank nor a doc comment:
        // the end of the field's attribute, if it has one.
        let above = lines[..i]
            .iter()
            .rev()
            .map(|l| l.trim())
            .find(|l| !l.is_empty() && !l.starts_with("///"));
        let Some(above) = above else {
            continue;
        };
        let is_attribute = above.starts_with("#[") || above == ")]";
        if is_attribute && above != "#[command(flatten)]" {
            found.push((name.to_string(), i + 1));
        }
    }
    found
}

/// Every shared flag is declared once, in `src/cli/mod.rs`; every other
/// file of the command line flattens it.
#[test]
fn every_shared_flag_is_declared_once() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/cli");
    let mut at_home = Vec::new();
    let mut problems = Vec::new();
    for entry in std::fs::read_dir(&dir).expect("src/cli") {
        let path = entry.expect("entry").path();
        let file = path.file_name().unwrap().to_string_lossy().to_string();
        let src = std::fs::read_to_string(&path).expect("read");
        for (name, line) in declarations(&src) {
            if file == "mod.rs" {
                at_home.push(name);
            } else if !OTHER_MEANING
                .iter()
                .any(|(f, n, _)| *f == file && *n == name)
            {
                problems.push(format!(
                    "src/cli/{file}:{line}: --{} is declared again: flatten its struct from src/cli/mod.rs (and mut_arg its help)",
                    name.replace('_', "-")
                ));
            }
        }
    }
    at_home.sort();
    let mut want: Vec<String> = SHARED.iter().map(|s| s.to_string()).collect();
    want.sort();
    assert_eq!(
        at_home, want,
        "src/cli/mod.rs declares each shared flag once"
    );
    assert!(problems.is_empty(), "{problems:#?}");
}

/// The reader on made-up code: a flattened flag and a function parameter
/// are no declarations; an `#[arg]` field is, with or without a doc
/// comment and over several attribute lines.
#[test]
fn the_reader_finds_a_second_declaration() {
    let src = r#"
struct A {
    #[command(flatten)]
    config: super::ConfigFlag,
    /// Where.
    #[arg(long)]
    out: Option<PathBuf>,
    #[arg(
        long,
        value_name = "FILE"
    )]
    pub(super) png: Option<PathBuf>,
    /// A flag of another name.
    #[arg(long)]
    seed: u64,
}
fn go(
    stop: bool,
    json: bool,
) {}
"#;
    let names: Vec<String> = declarations(src).into_iter().map(|(n, _)| n).collect();
    assert_eq!(names, ["out", "png"]);
}
