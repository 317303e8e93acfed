//! The messages of TOML syntax and type errors, naming the key path.

/// The message of a TOML error in `text`, the key it is about first: the
/// parser names a line, and the key only when it is on that line, so the
/// full key path comes first, array elements by index
/// (`chirp.amplitude_profile[1][1]: TOML parse error at line 86, …`),
/// also for an element on a line of its own. Without a key (a syntax
/// error), the parser's message alone.
pub fn toml_error_message(text: &str, e: &toml::de::Error) -> String {
    let message = e.to_string().trim_end().to_string();
    match e.span().and_then(|span| key_path_at(text, span)) {
        Some(key) => format!("{key}: {message}"),
        None => message,
    }
}

/// The dotted key path of the innermost key or value of `text` whose span
/// holds `span` (a parse error's): tables and inline tables by name, array
/// elements and arrays of tables by index (`controller.fast.real_poles_rad_s[1]`,
/// `chirp.amplitude_profile[1][1]`). `None` for text that is no TOML
/// document (a syntax error) or a span outside every key.
pub(in crate::config) fn key_path_at(text: &str, span: std::ops::Range<usize>) -> Option<String> {
    use toml_edit::{Item, Table, Value};
    /// The best (shortest containing) span so far, and its path.
    type Best = Option<(usize, String)>;
    fn consider(
        at: Option<std::ops::Range<usize>>,
        span: &std::ops::Range<usize>,
        path: &str,
        best: &mut Best,
    ) {
        if let Some(at) = at {
            let holds = at.start <= span.start && span.end <= at.end;
            if holds && best.as_ref().is_none_or(|(len, _)| at.len() <= *len) {
                *best = Some((at.len(), path.to_string()));
            }
        }
    }
    fn join(path: &str, key: &str) -> String {
        if path.is_empty() {
            key.to_string()
        } else {
            format!("{path}.{key}")
        }
    }
    fn value(v: &Value, path: &str, span: &std::ops::Range<usize>, best: &mut Best) {
        consider(v.span(), span, path, best);
        match v {
            Value::Array(a) => {
                for (i, x) in a.iter().enumerate() {
                    value(x, &format!("{path}[{i}]"), span, best);
                }
            }
            Value::InlineTable(t) => {
                for (k, x) in t.iter() {
                    let p = join(path, k);
                    consider(t.key(k).and_then(toml_edit::Key::span), span, &p, best);
                    value(x, &p, span, best);
                }
            }
            _ => {}
        }
    }
    fn item(it: &Item, path: &str, span: &std::ops::Range<usize>, best: &mut Best) {
        match it {
            Item::Value(v) => value(v, path, span, best),
            Item::Table(t) => table(t, path, span, best),
            Item::ArrayOfTables(a) => {
                for (i, t) in a.iter().enumerate() {
                    table(t, &format!("{path}[{i}]"), span, best);
                }
            }
            Item::None => {}
        }
    }
    fn table(t: &Table, path: &str, span: &std::ops::Range<usize>, best: &mut Best) {
        if !path.is_empty() {
            consider(t.span(), span, path, best);
        }
        for (k, it) in t.iter() {
            let p = join(path, k);
            consider(t.key(k).and_then(toml_edit::Key::span), span, &p, best);
            item(it, &p, span, best);
        }
    }
    let doc = toml_edit::ImDocument::parse(text).ok()?;
    let mut best = None;
    table(doc.as_table(), "", &span, &mut best);
    best.map(|(_, path)| path)
}
