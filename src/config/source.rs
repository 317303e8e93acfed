//! A resolved config written back in the layout of the file it came from.
//!
//! A recording holds the resolved config (`bench.config` metadata `toml`:
//! the file with the command line's overrides applied, every key written
//! out, no comments) and the text of the file as given (`source`).
//! [`in_source_layout`] merges them: the given text, its comments, key
//! order and blank lines kept, with only the values the resolved config
//! differs in replaced (or added, at the end of their table). `bench fit
//! --update` starts from it, so the updated bench reads like the file the
//! lab wrote.

use std::path::Path;

use toml_edit::{DocumentMut, Item, Table};

use super::BenchConfig;

/// `source` (a bench config's text as given) with the values of
/// `resolved` (the same config after overrides, as [`BenchConfig::to_toml`]
/// writes it) where the two differ; comments and layout of `source` kept.
///
/// # Errors
/// The reason when `source` or `resolved` is not a bench config, or when
/// the merged text does not load to the resolved config (the caller then
/// falls back to `resolved` as it is).
pub fn in_source_layout(source: &str, resolved: &str) -> Result<String, String> {
    let here = Path::new("source");
    let given = BenchConfig::from_toml(source, here).map_err(|e| e.to_string())?;
    let want = BenchConfig::from_toml(resolved, here).map_err(|e| e.to_string())?;
    let canonical = |c: &BenchConfig| -> Result<toml::Table, String> {
        toml::from_str(&c.to_toml()).map_err(|e: toml::de::Error| e.to_string())
    };
    let (have, want_t) = (canonical(&given)?, canonical(&want)?);
    let mut doc: DocumentMut = source
        .parse()
        .map_err(|e: toml_edit::TomlError| e.to_string())?;
    let resolved_doc: DocumentMut = want
        .to_toml()
        .parse()
        .map_err(|e: toml_edit::TomlError| e.to_string())?;
    patch(doc.as_table_mut(), resolved_doc.as_table(), &have, &want_t);
    let merged = doc.to_string();
    let back = BenchConfig::from_toml(&merged, here).map_err(|e| e.to_string())?;
    if canonical(&back)? != want_t {
        return Err("the merged text does not load to the resolved config".into());
    }
    Ok(merged)
}

/// Sets in `doc` every leaf of `resolved` whose canonical value in `want`
/// differs from `have` (the source's canonical values), recursing into
/// tables.
fn patch(doc: &mut Table, resolved: &Table, have: &toml::Table, want: &toml::Table) {
    for (key, item) in resolved.iter() {
        let Some(w) = want.get(key) else { continue };
        let h = have.get(key);
        if h == Some(w) {
            continue;
        }
        match (item, w, h) {
            (Item::Table(sub), toml::Value::Table(wt), h) => {
                let empty = toml::Table::new();
                let ht = match h {
                    Some(toml::Value::Table(t)) => t,
                    _ => &empty,
                };
                let entry = doc.entry(key).or_insert_with(|| Item::Table(Table::new()));
                match entry {
                    Item::Table(t) => patch(t, sub, ht, wt),
                    // An inline table or a dotted key in the source:
                    // replaced whole.
                    other => *other = Item::Table(sub.clone()),
                }
            }
            _ => match doc.get_mut(key) {
                Some(Item::Value(v)) => {
                    let decor = v.decor().clone();
                    if let Some(new) = item.as_value() {
                        *v = new.clone();
                        *v.decor_mut() = decor;
                    } else {
                        doc[key] = item.clone();
                    }
                }
                _ => {
                    doc[key] = item.clone();
                }
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn comments_are_kept_and_overrides_applied() {
        let source = crate::config::BUILTIN_CONFIG_TOML;
        let mut cfg = BenchConfig::from_toml(source, Path::new("x")).unwrap();
        cfg.plant.mass_asymmetry = -0.02;
        let merged = in_source_layout(source, &cfg.to_toml()).unwrap();
        let back = BenchConfig::from_toml(&merged, Path::new("x")).unwrap();
        assert_eq!(back.plant.mass_asymmetry, -0.02);
        let comments = |t: &str| {
            t.lines()
                .filter(|l| l.trim_start().starts_with('#'))
                .count()
        };
        assert_eq!(comments(&merged), comments(source));
        // One line changed.
        let changed = merged
            .lines()
            .zip(source.lines())
            .filter(|(a, b)| a != b)
            .count();
        assert_eq!(changed, 1, "{merged}");
        assert_eq!(merged.lines().count(), source.lines().count());
    }

    #[test]
    fn unchanged_config_gives_the_source_back() {
        let source = crate::config::BUILTIN_CONFIG_TOML;
        let cfg = BenchConfig::from_toml(source, Path::new("x")).unwrap();
        assert_eq!(in_source_layout(source, &cfg.to_toml()).unwrap(), source);
    }

    #[test]
    fn not_a_config_is_an_error() {
        assert!(in_source_layout("not = [toml", "").is_err());
    }
}
