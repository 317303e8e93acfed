//! A parameter that cannot describe a physical bench ([`ParamError`], the
//! key and the reason) and the range checks every config table uses:
//! [`positive`], [`non_negative`], [`within`].
//!
//! Layer rule: may use nothing of the crate.

/// A parameter that cannot describe a physical bench.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{key}: {reason}")]
pub struct ParamError {
    /// Dotted key of the offending value (e.g. `plant.m1_kg`).
    pub key: String,
    /// Why it is refused.
    pub reason: String,
}

impl ParamError {
    /// Builds an error for `key`.
    pub fn new(key: impl Into<String>, reason: impl Into<String>) -> Self {
        Self {
            key: key.into(),
            reason: reason.into(),
        }
    }
}

/// Checks that `value` is finite and > 0.
///
/// # Errors
/// [`ParamError`] naming `key`.
pub fn positive(key: &str, value: f64) -> Result<(), ParamError> {
    if !value.is_finite() {
        Err(ParamError::new(
            key,
            format!("must be a finite number, got {value}"),
        ))
    } else if value <= 0.0 {
        Err(ParamError::new(key, format!("must be > 0, got {value}")))
    } else {
        Ok(())
    }
}

/// Checks that `value` is finite and ≥ 0.
///
/// # Errors
/// [`ParamError`] naming `key`.
pub fn non_negative(key: &str, value: f64) -> Result<(), ParamError> {
    if !value.is_finite() {
        Err(ParamError::new(
            key,
            format!("must be a finite number, got {value}"),
        ))
    } else if value < 0.0 {
        Err(ParamError::new(key, format!("must be >= 0, got {value}")))
    } else {
        Ok(())
    }
}

/// Checks that `value` is finite and in `[lo, hi]` (`unit` for the
/// message), with `why` the documented reason for the range. `key` is
/// only formatted on failure (the map validates tens of thousands of
/// benches).
///
/// # Errors
/// [`ParamError`] naming `key`.
pub fn within(
    key: impl std::fmt::Display,
    value: f64,
    (lo, hi): (f64, f64),
    unit: &str,
    why: &str,
) -> Result<(), ParamError> {
    if !value.is_finite() {
        return Err(ParamError::new(
            key.to_string(),
            format!("must be a finite number, got {value}"),
        ));
    }
    if !(lo..=hi).contains(&value) {
        return Err(ParamError::new(
            key.to_string(),
            format!("{value:?} {unit} is outside [{lo:?}, {hi:?}] {unit}: {why}"),
        ));
    }
    Ok(())
}
