//! The updated bench as TOML, in the start file's own layout.

use super::*;

/// The start bench's TOML text with the free parameters set to their
/// updated values: comments, layout and every other key kept, each
/// changed key commented with its start value and 1σ, and `header`
/// (comment lines, each starting with `#`) put on top.
///
/// # Errors
/// The start text does not parse as TOML, or a table the keys belong in
/// is missing.
pub fn updated_toml(start_toml: &str, update: &Update, header: &str) -> Result<String, String> {
    let mut doc: toml_edit::DocumentMut = start_toml
        .parse()
        .map_err(|e: toml_edit::TomlError| format!("the start config: {e}"))?;
    for p in update.parameters.iter().filter(|p| p.free) {
        let mut path: Vec<&str> = p.key.split('.').collect();
        let last = path.pop().unwrap_or_default();
        let mut item = doc.as_item_mut();
        for part in &path {
            item = item
                .get_mut(part)
                .ok_or_else(|| format!("the start config has no {part} table for {}", p.key))?;
        }
        let table = item
            .as_table_like_mut()
            .ok_or_else(|| format!("the start config: {} is not a table", path.join(".")))?;
        let sigma = p
            .sigma
            .map_or("not estimable".into(), |s| format!("{s:.3e}"));
        let mut value = toml_edit::Value::from(p.value);
        // Inline-table members keep no comments; top-level keys do.
        if path.len() == 1 {
            value.decor_mut().set_suffix(format!(
                "  # updated by bench fit: 1 sigma {sigma}, start {}",
                p.start
            ));
        }
        match table.get_mut(last) {
            Some(existing) => {
                if let Some(old) = existing.as_value() {
                    if path.len() > 1 {
                        *value.decor_mut() = old.decor().clone();
                    } else if let Some(prefix) = old.decor().prefix() {
                        value.decor_mut().set_prefix(prefix.clone());
                    }
                }
                *existing = toml_edit::Item::Value(value);
            }
            None => {
                table.insert(last, toml_edit::Item::Value(value));
            }
        }
    }
    // The X bearings scale together: k5 follows k4 in the start's ratio.
    let bearings = update
        .parameters
        .iter()
        .any(|p| p.free && p.name == Parameter::BearingStiffness.name());
    if let (true, Some(b)) = (bearings, &update.bench) {
        if let Some(plant) = doc.get_mut("plant").and_then(|t| t.as_table_like_mut()) {
            let prefix = plant
                .get("k5_n_per_m")
                .and_then(|v| v.as_value())
                .and_then(|v| v.decor().prefix().cloned());
            let mut value = toml_edit::Value::from(b.plant.k5_n_per_m);
            if let Some(prefix) = prefix {
                value.decor_mut().set_prefix(prefix);
            }
            value.decor_mut().set_suffix(format!(
                "  # updated by bench fit with k4_n_per_m (their ratio kept), start {}",
                plant
                    .get("k5_n_per_m")
                    .and_then(|v| v.as_value())
                    .and_then(toml_edit::Value::as_float)
                    .map_or(String::new(), |v| v.to_string())
            ));
            plant.insert("k5_n_per_m", toml_edit::Item::Value(value));
        }
    }
    Ok(format!("{header}{doc}"))
}
