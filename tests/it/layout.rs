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
//!
//! The rules hold in every crate of the workspace ([`CRATES`]: the
//! application and the HAL's four crates), and the crate graph the book
//! draws is Cargo's ([`the_crate_graph_in_the_book_is_cargos`]).
//!
//! Within a folder the files are layered too (issue 43): no two files of
//! any crate import each other
//! ([`no_two_files_import_each_other`]; a module and its own child are one
//! unit). Run on the tree before the split of `ident/chirp.rs`,
//! `plot/measured.rs` and the EtherCAT config, it names the five circles
//! that `farm-studio look` counted.

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

/// The sources of every crate of the workspace: the application and the
/// HAL's crates (between crates Cargo keeps the layers; within each, its
/// folders' rules do).
const CRATES: [&str; 5] = [
    "src",
    "hal/protocol/src",
    "hal/hal/src",
    "hal/plant/src",
    "hal/devices/src",
];

#[test]
fn every_folder_keeps_its_layer_rule() {
    for dir in CRATES {
        let tree = read_tree(&Path::new(env!("CARGO_MANIFEST_DIR")).join(dir));
        assert!(tree.len() >= 4, "{dir}: {} files read", tree.len());
        let problems = check(&tree);
        assert!(problems.is_empty(), "{dir}: {problems:#?}");
    }
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

/// The module path of a file: `ident/frf/mod.rs` → `ident::frf`,
/// `ident/lpm.rs` → `ident::lpm`, `lib.rs` → the crate.
fn module_of(path: &str) -> Vec<String> {
    let mut parts: Vec<String> = path
        .trim_end_matches(".rs")
        .split('/')
        .map(String::from)
        .collect();
    if matches!(
        parts.last().map(String::as_str),
        Some("mod" | "lib" | "main")
    ) {
        parts.pop();
    }
    parts
}

/// The paths of a `use` tree: `a::{b, c::{d, e}}` → `a::b`, `a::c::d`,
/// `a::c::e` (an `as` rename dropped).
fn use_paths(tree: &str) -> Vec<String> {
    let tree = tree.trim();
    let Some(open) = tree.find('{') else {
        let plain = tree.split(" as ").next().unwrap_or(tree).trim();
        return vec![plain.to_string()];
    };
    let prefix = &tree[..open];
    let inner = &tree[open + 1..tree.rfind('}').unwrap_or(tree.len())];
    let (mut members, mut depth, mut member) = (Vec::new(), 0, String::new());
    for c in inner.chars().chain([',']) {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                if !member.trim().is_empty() {
                    members.push(std::mem::take(&mut member));
                }
                member.clear();
                continue;
            }
            _ => {}
        }
        member.push(c);
    }
    members
        .iter()
        .flat_map(|m| use_paths(m))
        .map(|m| format!("{prefix}{m}"))
        .collect()
}

/// Which files each file imports: its `use` paths and inline `crate::` /
/// `super::` paths, resolved to the file of the longest module prefix
/// they name. Not read: comments, the test module, re-exports (`pub use`:
/// a module's face, not a dependency of its code) and glob imports.
fn file_imports(tree: &Tree) -> BTreeMap<String, BTreeSet<String>> {
    let modules: BTreeMap<Vec<String>, String> =
        tree.keys().map(|p| (module_of(p), p.clone())).collect();
    let mut out = BTreeMap::new();
    for (path, src) in tree {
        let module = module_of(path);
        // Without comments, the test module and re-exports.
        let mut body = String::new();
        let mut statement = String::new();
        for line in code(src).lines() {
            let t = line.trim_start();
            if !statement.is_empty()
                || t.starts_with("pub use ")
                || (t.starts_with("pub(") && t.contains(" use "))
            {
                statement.push_str(line);
                if line.contains(';') {
                    statement.clear();
                }
                continue;
            }
            body.push_str(line);
            body.push('\n');
        }
        let children: BTreeSet<String> = body
            .lines()
            .filter_map(|l| {
                let t = l.trim_start();
                let t = t
                    .strip_prefix("pub(crate) ")
                    .or(t.strip_prefix("pub "))
                    .unwrap_or(t);
                t.strip_prefix("mod ")?
                    .strip_suffix(';')
                    .map(|m| m.trim().to_string())
            })
            .collect();
        let mut paths = Vec::new();
        // `use` statements start a line (a `use ` inside a string or a
        // longer word is not one) and end at their `;`.
        let mut statement: Option<String> = None;
        for line in body.lines() {
            let t = line.trim_start();
            let s = match statement.take() {
                Some(s) => s + " " + t,
                None if t.starts_with("use ") => t["use ".len()..].to_string(),
                None => continue,
            };
            match s.find(';') {
                Some(end) => paths.extend(use_paths(&s[..end])),
                None => statement = Some(s),
            }
        }
        for root in ["crate::", "super::"] {
            let mut rest = body.as_str();
            while let Some(i) = rest.find(root) {
                let before = rest[..i].chars().last();
                let tail = &rest[i..];
                rest = &rest[i + root.len()..];
                if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':' || c == '$') {
                    continue;
                }
                let p: String = tail
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':')
                    .collect();
                paths.push(p);
            }
        }
        let mut targets = BTreeSet::new();
        for p in paths {
            let mut segs: Vec<&str> = p
                .split("::")
                .map(str::trim)
                .filter(|s| !s.is_empty())
                .collect();
            if segs.last().is_none_or(|s| *s == "*") {
                continue;
            }
            let mut base = module.clone();
            match segs[0] {
                "crate" => {
                    base.clear();
                    segs.remove(0);
                }
                "super" => {
                    while segs.first() == Some(&"super") {
                        base.pop();
                        segs.remove(0);
                    }
                }
                "self" => {
                    segs.remove(0);
                }
                s if children.contains(s) => {}
                _ => continue,
            }
            let full: Vec<String> = base
                .into_iter()
                .chain(segs.iter().map(|s| s.to_string()))
                .collect();
            if let Some(target) = (1..=full.len()).rev().find_map(|k| modules.get(&full[..k])) {
                if target != path {
                    targets.insert(target.clone());
                }
            }
        }
        out.insert(path.clone(), targets);
    }
    out
}

/// Every pair of files that import each other, other than a module and
/// its own child (a `mod.rs` dispatching to a child that uses its
/// parent's types is one unit), one line each.
fn two_file_circles(tree: &Tree) -> Vec<String> {
    let imports = file_imports(tree);
    let mut out = Vec::new();
    for (a, targets) in &imports {
        for b in targets {
            let (ma, mb) = (module_of(a), module_of(b));
            let parent_and_child = ma.len() + 1 == mb.len() && mb.starts_with(&ma)
                || mb.len() + 1 == ma.len() && ma.starts_with(&mb);
            if a < b && !parent_and_child && imports.get(b).is_some_and(|t| t.contains(a)) {
                out.push(format!("{a} and {b} import each other"));
            }
        }
    }
    out
}

/// No two files of the library or of `bench_hal` import each other
/// (issue 43): the order of the files within a folder is a layering too.
#[test]
fn no_two_files_import_each_other() {
    for dir in CRATES {
        let tree = read_tree(&Path::new(env!("CARGO_MANIFEST_DIR")).join(dir));
        assert!(tree.len() >= 4, "{dir}: {} files read", tree.len());
        let circles = two_file_circles(&tree);
        assert!(circles.is_empty(), "{dir}: {circles:#?}");
    }
}

/// The circle check on a made-up tree: a circle between siblings is
/// found, through a grouped `use`, an inline `crate::` path and a
/// `super::` path; a parent and its child, a re-export, a glob and the
/// test module are not circles.
#[test]
fn the_circle_check_finds_siblings_that_import_each_other() {
    let tree: Tree = [
        ("lib.rs", "pub mod ident;\n"),
        (
            "ident/mod.rs",
            "mod chirp;\nmod sweep;\nuse chirp::Chirp;\npub use sweep::*;\n",
        ),
        ("ident/chirp.rs", "use super::{C64, sweep::{Sweep, X}};\n"),
        (
            "ident/sweep.rs",
            "fn f() { crate::ident::chirp::Chirp::new(); }\n",
        ),
        (
            "plot/a.rs",
            "pub use crate::plot::b::B;\nuse super::c::*;\n",
        ),
        ("plot/b.rs", "use crate::plot::a::A;\n"),
        (
            "plot/c.rs",
            "//! crate::plot::d in a comment\n#[cfg(test)]\nmod tests { use crate::plot::d::D; }\n",
        ),
        ("plot/d.rs", "use super::c::C;\n"),
        ("plot/mod.rs", "mod a;\nmod b;\nmod c;\nmod d;\n"),
    ]
    .into_iter()
    .map(|(p, s)| (p.to_string(), s.to_string()))
    .collect();
    assert_eq!(
        two_file_circles(&tree),
        vec!["ident/chirp.rs and ident/sweep.rs import each other".to_string()]
    );
    let imports = file_imports(&tree);
    assert!(imports["ident/mod.rs"].contains("ident/chirp.rs"));
    assert!(imports["ident/chirp.rs"].contains("ident/mod.rs"));
}

/// The crate graph in the book (`docs/src/architecture.md`, between the
/// `crate-graph` markers: `crate -> dep, dep`) is Cargo's: each crate of
/// the workspace with the workspace crates its `[dependencies]` name.
#[test]
fn the_crate_graph_in_the_book_is_cargos() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut cargo: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for manifest in [
        "Cargo.toml",
        "hal/protocol/Cargo.toml",
        "hal/hal/Cargo.toml",
        "hal/plant/Cargo.toml",
        "hal/devices/Cargo.toml",
    ] {
        let t: toml::Table = std::fs::read_to_string(root.join(manifest))
            .unwrap()
            .parse()
            .unwrap();
        let name = t["package"]["name"].as_str().unwrap().to_string();
        let deps = t
            .get("dependencies")
            .and_then(|d| d.as_table())
            .map(|d| {
                d.iter()
                    .filter(|(_, v)| v.get("path").is_some())
                    .map(|(k, _)| k.clone())
                    .collect()
            })
            .unwrap_or_default();
        cargo.insert(name, deps);
    }
    // Every member of the workspace is in the list above.
    let ws: toml::Table = std::fs::read_to_string(root.join("Cargo.toml"))
        .unwrap()
        .parse()
        .unwrap();
    let members = ws["workspace"]["members"].as_array().unwrap().len();
    assert_eq!(members, cargo.len(), "a workspace member is not checked");
    let book = std::fs::read_to_string(root.join("docs/src/architecture.md")).unwrap();
    let graph = book
        .split("<!-- crate-graph -->")
        .nth(1)
        .and_then(|s| s.split("<!-- crate-graph:end -->").next())
        .expect("architecture.md has the crate-graph markers");
    let mut written: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for line in graph.lines().filter(|l| l.contains("->")) {
        let (name, deps) = line.split_once("->").unwrap();
        let deps = deps
            .split(',')
            .map(str::trim)
            .filter(|d| !d.is_empty() && *d != "(none)")
            .map(String::from)
            .collect();
        written.insert(name.trim().to_string(), deps);
    }
    assert_eq!(
        written, cargo,
        "the book's crate graph (left) against Cargo's"
    );
}

/// `src` with comments and string, raw-string and character literals
/// blanked (newlines kept, so line numbers hold), so that its braces are
/// the code's.
fn blank_literals(src: &str) -> String {
    let c: Vec<char> = src.chars().collect();
    let mut out = String::with_capacity(src.len());
    let blank = |out: &mut String, s: &[char]| {
        out.extend(s.iter().map(|&ch| if ch == '\n' { '\n' } else { ' ' }));
    };
    let ident = |ch: char| ch.is_alphanumeric() || ch == '_';
    let mut i = 0;
    while i < c.len() {
        let rest = &c[i..];
        let end = if rest.starts_with(&['/', '/']) {
            rest.iter().position(|&ch| ch == '\n').unwrap_or(rest.len())
        } else if rest.starts_with(&['/', '*']) {
            rest.windows(2)
                .skip(2)
                .position(|w| w == ['*', '/'])
                .map_or(rest.len(), |p| p + 4)
        } else if (rest[0] == 'r' || rest.starts_with(&['b', 'r']))
            && (i == 0 || !ident(c[i - 1]))
            && {
                let k = if rest[0] == 'b' { 2 } else { 1 };
                let hashes = rest[k..].iter().take_while(|&&ch| ch == '#').count();
                rest.get(k + hashes) == Some(&'"')
            }
        {
            let k = if rest[0] == 'b' { 2 } else { 1 };
            let hashes = rest[k..].iter().take_while(|&&ch| ch == '#').count();
            let open = k + hashes + 1;
            (open..rest.len())
                .find(|&j| {
                    rest[j] == '"'
                        && rest[j + 1..]
                            .iter()
                            .take(hashes)
                            .filter(|&&h| h == '#')
                            .count()
                            == hashes
                })
                .map_or(rest.len(), |j| j + 1 + hashes)
        } else if rest[0] == '"' {
            let mut j = 1;
            while j < rest.len() && rest[j] != '"' {
                j += if rest[j] == '\\' { 2 } else { 1 };
            }
            (j + 1).min(rest.len())
        } else if rest[0] == '\'' && rest.get(1) == Some(&'\\') {
            rest[2..]
                .iter()
                .position(|&ch| ch == '\'')
                .map_or(rest.len(), |p| p + 3)
        } else if rest[0] == '\'' && rest.get(2) == Some(&'\'') {
            3
        } else {
            out.push(rest[0]);
            i += 1;
            continue;
        };
        blank(&mut out, &rest[..end]);
        i += end;
    }
    out
}

/// Every function with a body in the code of `src` (before a
/// `#[cfg(test)]` at the start of a line): its name and its length in
/// lines, from `fn` to its closing brace (closures and nested functions
/// counted in it).
fn function_lengths(src: &str) -> Vec<(String, usize)> {
    let code = match src.find("\n#[cfg(test)]") {
        Some(k) => &src[..k],
        None => src,
    };
    let s = blank_literals(code);
    let b = s.as_bytes();
    let mut out = Vec::new();
    let mut from = 0;
    while let Some(k) = s[from..].find("fn ") {
        let at = from + k;
        from = at + 3;
        if at > 0 && (b[at - 1].is_ascii_alphanumeric() || b[at - 1] == b'_') {
            continue;
        }
        let name: String = s[at + 3..]
            .trim_start()
            .chars()
            .take_while(|ch| ch.is_alphanumeric() || *ch == '_')
            .collect();
        if name.is_empty() {
            continue;
        }
        // The body: the first `{` before any `;` (a declaration has none).
        let Some(open) = s[at..].find(['{', ';']) else {
            continue;
        };
        if b[at + open] == b';' {
            continue;
        }
        let mut depth = 0usize;
        let mut close = None;
        for (j, ch) in s[at + open..].char_indices() {
            match ch {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        close = Some(at + open + j);
                        break;
                    }
                }
                _ => {}
            }
        }
        let Some(close) = close else { continue };
        let lines = s[at..=close].matches('\n').count() + 1;
        out.push((name, lines));
    }
    out
}

/// Functions over [`LONGEST_FUNCTION_LINES`] allowed to stay while they
/// are split, each only shrinking: (path, function, lines). Issue 43 split
/// the last of them on 2026-11-29, so the list is empty and any function
/// over the limit fails; one added here must shrink until it leaves.
const LONG_FUNCTIONS: &[(&str, &str, usize)] = &[];

/// The longest function a file of the workspace may have (issue 43).
const LONGEST_FUNCTION_LINES: usize = 150;

/// No function of the workspace's non-test code grows beyond
/// [`LONGEST_FUNCTION_LINES`] lines, and the ones already longer
/// ([`LONG_FUNCTIONS`]) do not grow; one that shrank below the limit must
/// leave the list.
#[test]
fn no_function_grows_beyond_150_lines() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut problems = Vec::new();
    let mut seen = BTreeSet::new();
    for dir in CRATES {
        for (path, src) in read_tree(&root.join(dir)) {
            if path.ends_with("tests.rs") {
                continue;
            }
            let path = format!("{dir}/{path}");
            for (name, lines) in function_lengths(&src) {
                if lines <= LONGEST_FUNCTION_LINES {
                    continue;
                }
                let listed = LONG_FUNCTIONS
                    .iter()
                    .find(|(p, f, _)| *p == path && *f == name);
                if listed.is_some() {
                    seen.insert((path.clone(), name.clone()));
                }
                match listed {
                    Some((_, _, was)) if lines <= *was => {}
                    Some((_, _, was)) => problems.push(format!(
                        "{path}: fn {name} grew to {lines} lines from {was}: split it"
                    )),
                    None => problems.push(format!(
                        "{path}: fn {name} has {lines} lines, more than {LONGEST_FUNCTION_LINES}: split it"
                    )),
                }
            }
        }
    }
    for (p, f, _) in LONG_FUNCTIONS {
        if !seen.contains(&(p.to_string(), f.to_string())) {
            problems.push(format!(
                "{p}: fn {f} is no longer over {LONGEST_FUNCTION_LINES} lines: remove it from LONG_FUNCTIONS"
            ));
        }
    }
    assert!(problems.is_empty(), "{problems:#?}");
}

/// The function-length reader on made-up code: braces in strings, raw
/// strings, characters and comments do not count, lifetimes are not
/// characters, declarations without a body are skipped, and the test
/// module is not read.
#[test]
fn the_function_lengths_are_read_past_literals_and_comments() {
    let src = r##"
fn short<'a>(x: &'a str) -> char {
    let _ = "}}}";
    let _ = r#"{"#;
    // }
    /* { */
    '{'
}
trait T {
    fn declared(&self);
}
fn three() {
    let c = '\'';
}
#[cfg(test)]
mod tests {
    fn hidden() {}
}
"##;
    assert_eq!(
        function_lengths(src),
        vec![("short".to_string(), 7), ("three".to_string(), 3)]
    );
}
