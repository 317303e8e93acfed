//! The documentation a user reads (the README and the book), as pages and
//! as fenced blocks: the one parser every test that reads an example, a
//! sample output or a snippet out of the docs goes through.

use std::path::Path;

/// The documentation a user reads, as (path from the repository root,
/// text): `README.md`, then the book's chapters (`docs/src`) in the order
/// of its `SUMMARY.md`. Every chapter `SUMMARY.md` names must exist, and
/// every Markdown file under `docs/src` must be named in it.
pub fn doc_pages() -> Vec<(String, String)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let read = |rel: &str| {
        std::fs::read_to_string(root.join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
    };
    let mut pages = vec![("README.md".to_string(), read("README.md"))];
    let summary = read("docs/src/SUMMARY.md");
    let mut named = std::collections::BTreeSet::new();
    for line in summary.lines() {
        if let Some((_, rest)) = line.split_once("](") {
            let chapter = rest.split(')').next().unwrap();
            let rel = format!("docs/src/{chapter}");
            named.insert(rel.clone());
            pages.push((rel.clone(), read(&rel)));
        }
    }
    let mut on_disk = Vec::new();
    let mut dirs = vec![root.join("docs/src")];
    while let Some(d) = dirs.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                dirs.push(p);
            } else if p.extension().is_some_and(|x| x == "md") && !p.ends_with("SUMMARY.md") {
                on_disk.push(p.strip_prefix(root).unwrap().display().to_string());
            }
        }
    }
    for p in on_disk {
        assert!(named.contains(&p), "{p} is not in docs/src/SUMMARY.md");
    }
    pages
}

/// [`doc_pages`] as one text, each page after a blank line.
pub fn docs_text() -> String {
    doc_pages()
        .into_iter()
        .map(|(_, t)| t)
        .collect::<Vec<_>>()
        .join("\n")
}

/// A fenced code block of the docs.
#[derive(Debug, Clone)]
pub struct DocBlock {
    /// The page, from the repository root (`docs/src/daemon.md`).
    pub page: String,
    /// The 1-based line of the opening fence.
    pub line: usize,
    /// The fence's info string (`sh`, `console`, `text`, `toml`, …).
    pub lang: String,
    /// The `<!-- … -->` comment right before the fence (blank lines
    /// between allowed), without its delimiters and trimmed.
    pub marker: Option<String>,
    /// The last non-blank line before the fence (and before its marker):
    /// the sentence that introduces the block.
    pub intro: String,
    /// The block's text, one `\n` after each line.
    pub body: String,
}

impl DocBlock {
    /// The body's lines with their `page:line`.
    pub fn numbered_lines(&self) -> impl Iterator<Item = (String, &str)> {
        self.body
            .lines()
            .enumerate()
            .map(move |(i, l)| (format!("{}:{}", self.page, self.line + 1 + i), l))
    }
}

/// Every fenced block of [`doc_pages`], in reading order. An unclosed
/// fence fails, naming where it opened.
pub fn doc_blocks() -> Vec<DocBlock> {
    let mut out = Vec::new();
    for (page, text) in doc_pages() {
        let lines: Vec<&str> = text.lines().collect();
        let mut i = 0;
        while i < lines.len() {
            let Some(info) = lines[i].strip_prefix("```") else {
                i += 1;
                continue;
            };
            let open = i;
            let close = (open + 1..lines.len())
                .find(|&k| lines[k].trim_end() == "```")
                .unwrap_or_else(|| panic!("{page}:{}: the fence is not closed", open + 1));
            let mut before = (0..open).rev().filter(|&k| !lines[k].trim().is_empty());
            let mut marker = None;
            let mut intro = String::new();
            if let Some(k) = before.next() {
                let t = lines[k].trim();
                if let Some(m) = t.strip_prefix("<!--").and_then(|m| m.strip_suffix("-->")) {
                    marker = Some(m.trim().to_string());
                    intro = before
                        .next()
                        .map_or(String::new(), |k| lines[k].trim().to_string());
                } else {
                    intro = t.to_string();
                }
            }
            let body: String = lines[open + 1..close]
                .iter()
                .map(|l| format!("{l}\n"))
                .collect();
            out.push(DocBlock {
                page: page.clone(),
                line: open + 1,
                lang: info.trim().to_string(),
                marker,
                intro,
                body,
            });
            i = close + 1;
        }
    }
    out
}
