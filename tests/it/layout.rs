//! The layout's rules hold (issue 26): every folder of the library (and
//! every top-level file) states in its header which other folders it may
//! use, in one line
//!
//! ```text
//! //! Layer rule: may use `config`, `record`.
//! ```
//!
//! (or `may use nothing of the crate.`), and this test reads every file's
//! `crate::…` paths (`use` lines, grouped `use crate::{a::X, b::Y}` and
//! paths written inline; comments and the `#[cfg(test)]` module at the end
//! of a file are not read) and fails on a path its folder's rule does not
//! allow, on a folder without a rule, and on any cycle among the rules (so
//! none among the imports). The binary (`src/main.rs`, `src/cli/`) is the
//! top: it may use all of the library and is not checked.
//!
//! The checker itself is tested on a made-up tree:
//! [`the_checker_catches_a_wrong_import_and_a_cycle`] gives it a file of
//! `rt` that imports `jobs` (which `rt`'s rule does not allow), and two
//! folders whose rules allow each other, and expects both to be reported.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Source files by path relative to `src/` (e.g. `rt/tick.rs`).
type Tree = BTreeMap<String, String>;

/// The folder (top-level module) a file belongs to: `rt/tick.rs` → `rt`,
/// `config.rs` → `config`.
fn folder(path: &str) -> String {
    let first = path.split('/').next().unwrap();
    first.trim_end_matches(".rs").to_string()
}

/// The file that holds a folder's rule: `rt/mod.rs`, or `config.rs`.
fn rule_file(tree: &Tree, folder: &str) -> Option<String> {
    [format!("{folder}/mod.rs"), format!("{folder}.rs")]
        .into_iter()
        .find(|p| tree.contains_key(p))
}

/// The folders a rule line allows, or `None` if the file has no rule.
fn parse_rule(src: &str) -> Option<BTreeSet<String>> {
    let line = src
        .lines()
        .take_while(|l| l.starts_with("//!") || l.trim().is_empty())
        .find(|l| l.starts_with("//! Layer rule:"))?;
    let rest = line.trim_start_matches("//! Layer rule:");
    Some(
        rest.split('`')
            .skip(1)
            .step_by(2)
            .map(str::to_string)
            .collect(),
    )
}

/// The code of a file that the rules apply to: comment lines dropped, and
/// everything from a `#[cfg(test)]` at the start of a line on.
fn code(src: &str) -> String {
    let mut out = String::new();
    for line in src.lines() {
        if line.starts_with("#[cfg(test)]") {
            break;
        }
        let t = line.trim_start();
        if t.starts_with("//") {
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

/// The first segments of every `crate::` path in `code`, with the
/// members of grouped paths (`crate::{a::X, b::{Y, Z}}` → `a`, `b`).
fn crate_paths(code: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut rest = code;
    while let Some(i) = rest.find("crate::") {
        let before = rest[..i].chars().last();
        rest = &rest[i + "crate::".len()..];
        // `bench_hal::crate::` cannot occur; a `$crate::` in a macro is
        // the macro's crate: skip it.
        if before == Some('$') {
            continue;
        }
        if let Some(group) = rest.strip_prefix('{') {
            // The balanced group's top-level members.
            let mut depth = 1;
            let mut end = 0;
            for (k, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' => {
                        depth -= 1;
                        if depth == 0 {
                            end = k;
                            break;
                        }
                    }
                    _ => {}
                }
            }
            let mut depth = 0;
            let mut member = String::new();
            for c in group[..end].chars().chain([',']) {
                match c {
                    '{' => depth += 1,
                    '}' => depth -= 1,
                    ',' if depth == 0 => {
                        let name: String = member
                            .trim()
                            .chars()
                            .take_while(|c| c.is_alphanumeric() || *c == '_')
                            .collect();
                        if !name.is_empty() && name != "self" {
                            out.insert(name);
                        }
                        member.clear();
                        continue;
                    }
                    _ => {}
                }
                member.push(c);
            }
        } else {
            let name: String = rest
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            if !name.is_empty() {
                out.insert(name);
            }
        }
    }
    out
}

/// Every broken rule of `tree`, one line each (empty: the layout holds).
fn check(tree: &Tree) -> Vec<String> {
    let mut problems = Vec::new();
    let folders: BTreeSet<String> = tree
        .keys()
        .map(|p| folder(p))
        .filter(|f| f != "lib" && f != "main" && f != "cli")
        .collect();
    let mut rules: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for f in &folders {
        let rule = rule_file(tree, f).and_then(|p| parse_rule(&tree[&p]));
        match rule {
            Some(r) => {
                for name in &r {
                    if !folders.contains(name) {
                        problems.push(format!(
                            "{f}: the rule names `{name}`, which is not a folder"
                        ));
                    }
                }
                rules.insert(f.clone(), r);
            }
            None => problems.push(format!(
                "{f}: no `//! Layer rule: may use …` line in its header ({})",
                rule_file(tree, f).unwrap_or_else(|| format!("{f}/mod.rs"))
            )),
        }
    }
    for (path, src) in tree {
        let f = folder(path);
        let Some(allowed) = rules.get(&f) else {
            continue;
        };
        for used in crate_paths(&code(src)) {
            if used != f && folders.contains(&used) && !allowed.contains(&used) {
                problems.push(format!(
                    "{path}: uses `crate::{used}`, which the rule of `{f}` does not allow (it may use {})",
                    if allowed.is_empty() {
                        "nothing of the crate".to_string()
                    } else {
                        allowed.iter().map(|a| format!("`{a}`")).collect::<Vec<_>>().join(", ")
                    }
                ));
            }
        }
    }
    // The rules must form no cycle (depth-first search, three colours).
    fn visit(
        f: &str,
        rules: &BTreeMap<String, BTreeSet<String>>,
        state: &mut BTreeMap<String, u8>,
        stack: &mut Vec<String>,
        problems: &mut Vec<String>,
    ) {
        state.insert(f.to_string(), 1);
        stack.push(f.to_string());
        for next in rules.get(f).into_iter().flatten() {
            match state.get(next.as_str()).copied().unwrap_or(0) {
                0 => visit(next, rules, state, stack, problems),
                1 => {
                    let at = stack.iter().position(|s| s == next).unwrap();
                    let mut cycle = stack[at..].to_vec();
                    cycle.push(next.clone());
                    problems.push(format!("cycle among the rules: {}", cycle.join(" → ")));
                }
                _ => {}
            }
        }
        stack.pop();
        state.insert(f.to_string(), 2);
    }
    let mut state = BTreeMap::new();
    for f in rules.keys() {
        if state.get(f.as_str()).copied().unwrap_or(0) == 0 {
            visit(f, &rules, &mut state, &mut Vec::new(), &mut problems);
        }
    }
    problems
}

fn read_tree(root: &Path) -> Tree {
    fn walk(dir: &Path, root: &Path, out: &mut Tree) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(&p, root, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
                out.insert(rel, std::fs::read_to_string(&p).unwrap());
            }
        }
    }
    let mut out = Tree::new();
    walk(root, root, &mut out);
    out
}

#[test]
fn every_folder_keeps_its_layer_rule() {
    let tree = read_tree(&Path::new(env!("CARGO_MANIFEST_DIR")).join("src"));
    assert!(tree.len() > 50, "{} files read", tree.len());
    let problems = check(&tree);
    assert!(problems.is_empty(), "{problems:#?}");
}

#[test]
fn the_checker_catches_a_wrong_import_and_a_cycle() {
    let tree: Tree = [
        ("lib.rs", "pub mod rt;\n"),
        (
            "rt/mod.rs",
            "//! The loop.\n//!\n//! Layer rule: may use `record`.\n\nmod tick;\n",
        ),
        (
            "rt/tick.rs",
            "use crate::record::Queue;\nuse crate::{jobs::Job, record::topics::Record};\n\n#[cfg(test)]\nmod tests {\n    use crate::daemon::X;\n}\n",
        ),
        ("record/mod.rs", "//! Layer rule: may use nothing of the crate.\n"),
        ("jobs/mod.rs", "//! Layer rule: may use `rt`, `daemon`.\n"),
        ("daemon/mod.rs", "//! Layer rule: may use `jobs`.\n// crate::rt in a comment\n"),
        ("plot.rs", "//! Plots, no rule.\n"),
    ]
    .into_iter()
    .map(|(p, s)| (p.to_string(), s.to_string()))
    .collect();
    let problems = check(&tree);
    let has = |s: &str| problems.iter().any(|p| p.contains(s));
    assert!(
        has("rt/tick.rs: uses `crate::jobs`, which the rule of `rt` does not allow (it may use `record`)"),
        "{problems:#?}"
    );
    assert!(
        has("cycle among the rules: daemon → jobs → daemon"),
        "{problems:#?}"
    );
    assert!(has("plot: no `//! Layer rule"), "{problems:#?}");
    // The test module and the comment are not read.
    assert!(
        !has("crate::daemon`, which the rule of `rt`"),
        "{problems:#?}"
    );
    assert!(!has("daemon/mod.rs: uses `crate::rt`"), "{problems:#?}");
    assert_eq!(problems.len(), 3, "{problems:#?}");
    // Grouped paths give each member.
    assert_eq!(
        crate_paths("use crate::{a::X, b::{Y, Z}, c};\nlet v = crate::d::f();"),
        ["a", "b", "c", "d"].map(String::from).into_iter().collect()
    );
}
