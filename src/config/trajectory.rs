//! `[trajectory]`: the reference `bench track` follows (and the daemon's
//! `track` jobs) where its flags or a request's fields do not say. Every
//! key is optional; a flag or a field given wins over the key, the key
//! over the built-in default of `bench track --help`.

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// The periodic scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ScanKind {
    /// `A·sin(ωt)`.
    Sine,
    /// The triangle of a raster line, smoothed (`crate::track` docs).
    Triangle,
    /// A point-to-point move and back: up by the amplitude at the line's
    /// start, back at its middle, each with the planned profile and a
    /// dwell after it.
    Move,
    /// A line read from a CSV (`reference`): one position per tick,
    /// played whole.
    Csv,
}

impl std::str::FromStr for ScanKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "sine" => Ok(Self::Sine),
            "triangle" => Ok(Self::Triangle),
            "move" => Ok(Self::Move),
            "csv" => Ok(Self::Csv),
            _ => Err(format!("{s:?} is not a scan (sine, triangle, move or csv)")),
        }
    }
}

/// A move's snap limit: a number (m/s⁴, a 4th-order profile) or `"none"`
/// (a 3rd-order profile: the jerk steps).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SnapLimit {
    /// The peak snap, m/s⁴.
    Limit(f64),
    /// No snap limit: a 3rd-order profile.
    None,
}

impl SnapLimit {
    /// `--max-snap-m-s4`'s text: a number, or `none`.
    ///
    /// # Errors
    /// The reason, for text that is neither.
    pub fn parse(s: &str) -> Result<Self, String> {
        if s == "none" {
            return Ok(Self::None);
        }
        s.parse::<f64>()
            .map(Self::Limit)
            .map_err(|e| format!("{s:?} is neither a snap in m/s⁴ nor `none`: {e}"))
    }

    /// The limit, m/s⁴; `None` for a 3rd-order profile.
    pub fn limit(self) -> Option<f64> {
        match self {
            Self::Limit(v) => Some(v),
            Self::None => None,
        }
    }
}

impl Serialize for SnapLimit {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Self::None => s.serialize_str("none"),
            Self::Limit(x) => s.serialize_f64(*x),
        }
    }
}

impl<'de> Deserialize<'de> for SnapLimit {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let v = number_or_word(
            d,
            "none",
            "a peak snap in m/s⁴ (a number) or \"none\" (a 3rd-order profile)",
        )?;
        Ok(v.map_or(SnapLimit::None, SnapLimit::Limit))
    }
}

/// A number, or the one word `word` (`None`): the serde form of a value
/// that may be switched off (`max_snap_m_s4 = "none"`, a request's
/// `pace: "off"`). `expecting` says what the value is, for the error.
///
/// # Errors
/// Anything else, with `expecting`.
pub fn number_or_word<'de, D: serde::Deserializer<'de>>(
    d: D,
    word: &'static str,
    expecting: &'static str,
) -> Result<Option<f64>, D::Error> {
    struct V(&'static str, &'static str);
    impl serde::de::Visitor<'_> for V {
        type Value = Option<f64>;
        fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str(self.1)
        }
        fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<Option<f64>, E> {
            Ok(Some(v))
        }
        fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Option<f64>, E> {
            Ok(Some(v as f64))
        }
        fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Option<f64>, E> {
            Ok(Some(v as f64))
        }
        fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Option<f64>, E> {
            if v == self.0 {
                Ok(None)
            } else {
                Err(E::invalid_value(serde::de::Unexpected::Str(v), &self))
            }
        }
    }
    d.deserialize_any(V(word, expecting))
}

/// The largest meaningful limit of a move's derivative of `order` (1:
/// velocity, m/s; 2: acceleration, m/s²; 3: jerk, m/s³; 4: snap, m/s⁴):
/// `stroke_m · rate_hz^order`, the limit that crosses the whole stroke
/// within one tick of the loop. A faster limit cannot shape a move the
/// loop samples (a move lasts 2 ticks at least).
pub fn move_limit_max(order: i32, stroke_m: f64, rate_hz: f64) -> f64 {
    stroke_m * rate_hz.powi(order)
}

/// `[trajectory]` (module docs). Ranges, checked when the config loads
/// (the rest when `bench track` plans the scan on the model, naming the
/// key as `trajectory.KEY`): `amplitude_m` in (0, `safety.position_limit_m`);
/// `line_rate_hz` in (0, `loop.rate_hz`/8] (a line of 8 ticks at least);
/// `cutoff_hz` above the line rate, at most Nyquist; the move's limits
/// above 0 and at most [`move_limit_max`] of the stroke
/// (2 `safety.position_limit_m`); `settle_band_m` in (0, `safety.position_limit_m`);
/// `reference` given exactly with `scan = "csv"`, which takes neither
/// `amplitude_m` nor `line_rate_hz` (the file's rows make both).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrajectoryConfig {
    /// The scan.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scan: Option<ScanKind>,
    /// The line of a csv scan: a CSV of one row per tick (header
    /// `time_s,position_m`); a relative path is taken from the config
    /// file's directory.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<PathBuf>,
    /// Amplitude about the start position (a move's distance), m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub amplitude_m: Option<f64>,
    /// Lines per second, Hz.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub line_rate_hz: Option<f64>,
    /// The harmonics' cut-off, Hz.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cutoff_hz: Option<f64>,
    /// A move's peak velocity, m/s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_velocity_m_s: Option<f64>,
    /// A move's peak acceleration, m/s².
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_acceleration_m_s2: Option<f64>,
    /// A move's peak jerk, m/s³.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_jerk_m_s3: Option<f64>,
    /// A move's peak snap, m/s⁴, or `"none"` (a 3rd-order profile).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_snap_m_s4: Option<SnapLimit>,
    /// The band a move settles into, ± m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub settle_band_m: Option<f64>,
}
