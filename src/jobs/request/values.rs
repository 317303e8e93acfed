//! The values of a request that come as text: a seed, a pace, a fault to
//! inject; each parsed and checked against its range.

use super::*;

/// Parses a simulator seed (`seed`, `--seed`): an integer in
/// `0..=2^64 − 1`, with a message that says so for anything else (a
/// negative number, a fraction, text).
///
/// # Errors
/// Why it does not parse (the caller names the field or flag).
pub fn parse_seed(s: &str) -> Result<u64, String> {
    s.trim().parse::<u64>().map_err(|_| {
        format!(
            "{s:?} is not a seed: an integer in 0..={} (2^64 - 1)",
            u64::MAX
        )
    })
}

/// The slowest pace, × real time: a hundredth (a 10 s sweep takes about
/// 17 minutes; a 10 kHz loop releases 100 ticks a second).
pub const PACE_MIN: f64 = 0.01;
/// The fastest pace, × real time. Past it a pace has nothing left to show
/// (a 10 s sweep passes in a tenth of a second) and comes near the
/// machine's own speed: the default chirp's loop runs 650–1 300× real time
/// unpaced on a 2-core VM (README, *Measured performance*), where a pace
/// would no longer pace; `off` runs as fast as it goes and says so.
pub const PACE_MAX: f64 = 100.0;

/// How a run on the simulator is paced against the wall clock (`--pace`,
/// the request's `pace`): in JSON a number (the factor) or `"off"`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pace {
    /// Virtual time as fast as it goes ([`crate::rt::Pacing::Virtual`]).
    Off,
    /// Virtual time at this factor of real time
    /// ([`crate::rt::Pacing::Paced`]): 1 real time, 0.1 ten times slower,
    /// 10 ten times faster. In [[`PACE_MIN`], [`PACE_MAX`]] once checked
    /// ([`check_pace`]).
    Factor(f64),
}

impl Pace {
    /// The factor of real time, `None` for [`Pace::Off`].
    pub fn factor(self) -> Option<f64> {
        match self {
            Self::Off => None,
            Self::Factor(f) => Some(f),
        }
    }
}

impl std::fmt::Display for Pace {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Off => f.write_str("off"),
            Self::Factor(x) => write!(f, "{x}"),
        }
    }
}

impl Serialize for Pace {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Self::Off => s.serialize_str("off"),
            Self::Factor(x) => s.serialize_f64(*x),
        }
    }
}

impl<'de> Deserialize<'de> for Pace {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let v = crate::config::number_or_word(
            d,
            "off",
            "a factor of real time (a number, 1: real time) or \"off\"",
        )?;
        Ok(v.map_or(Pace::Off, Pace::Factor))
    }
}

/// Why `factor` is not a pace, or the factor: in [[`PACE_MIN`],
/// [`PACE_MAX`]], finite. The one check of `--pace` and of a request's
/// `pace`.
///
/// # Errors
/// The reason, and what a pace is (the caller names the flag or field).
pub fn check_pace_factor(factor: f64) -> Result<f64, String> {
    let why = if factor.is_nan() {
        "not a number".to_string()
    } else if factor <= 0.0 {
        format!("{factor}× would stop time or run it backwards")
    } else if factor > PACE_MAX {
        format!(
            "{factor}× is faster than a pace can serve: past {PACE_MAX}× a live view shows nothing (a 10 s sweep passes in a tenth of a second) and the loop nears its unpaced speed (650–1 300× real time on a 2-core VM; give off to run as fast as it goes)"
        )
    } else if factor < PACE_MIN {
        format!("{factor}× is slower than a hundredth of real time (at {PACE_MIN}× a 10 s sweep already takes 17 minutes)")
    } else {
        return Ok(factor);
    };
    Err(format!(
        "{why}; a pace is a factor of real time from {PACE_MIN} to {PACE_MAX} (1: real time, 0.1: ten times slower, 10: ten times faster) or off (virtual time as fast as it goes)"
    ))
}

/// Parses a pace (`--pace`): `off`, or a factor of real time checked by
/// [`check_pace_factor`].
///
/// # Errors
/// Why it is not a pace (the caller names the flag).
pub fn parse_pace(s: &str) -> Result<Pace, String> {
    let t = s.trim();
    if t == "off" {
        return Ok(Pace::Off);
    }
    let factor: f64 = t.parse().map_err(|_| {
        format!(
            "{s:?} is not a number; a pace is a factor of real time from {PACE_MIN} to {PACE_MAX} (1: real time, 0.1: ten times slower, 10: ten times faster) or off"
        )
    })?;
    check_pace_factor(factor).map(Pace::Factor)
}

/// A request's `pace`, checked as `--pace` is ([`check_pace_factor`]).
///
/// # Errors
/// [`RequestError::Field`] naming `pace`.
pub fn check_pace(pace: Option<Pace>) -> Result<Option<Pace>, RequestError> {
    match pace {
        Some(Pace::Factor(f)) => {
            check_pace_factor(f)
                .map(|f| Some(Pace::Factor(f)))
                .map_err(|reason| RequestError::Field {
                    field: "pace",
                    value: f.to_string(),
                    reason,
                })
        }
        other => Ok(other),
    }
}

/// Why a pace is refused on a hardware backend (`backend` as named, e.g.
/// `serial:/dev/ttyUSB0`): hardware runs in real time.
pub fn pace_on_hardware(backend: &str) -> String {
    format!(
        "the {backend} backend runs in real time, always: a physical plant moves at its own pace, so the loop keeps its deadlines and cannot run slower or faster than the wall clock; a pace applies to the simulator (backend sim)"
    )
}

/// A pace on a hardware backend (`hardware`, named `backend`), refused as
/// the option `pace` ([`pace_on_hardware`]); any pace on a simulator, and
/// none anywhere, passes.
///
/// # Errors
/// [`crate::error::RunError::BadOption`] for `pace` when both are given.
pub fn refuse_pace_on_hardware(
    pace: Option<impl ToString>,
    hardware: bool,
    backend: &str,
) -> Result<(), crate::error::RunError> {
    match pace {
        Some(p) if hardware => Err(crate::error::RunError::option(
            "pace",
            p,
            pace_on_hardware(backend),
        )),
        _ => Ok(()),
    }
}

/// Parses a simulator fault `KIND@T_S`: KIND one of nan, frozen, drop (10
/// samples), jump (0.2 mm), out_of_range, dead (reads 0 m, no noise),
/// blind (reads its noise, not the stage), or `stall:MS` (the host stalls
/// once for MS milliseconds, 0 < MS ≤ 10 000); T_S the loop time, s.
///
/// # Errors
/// Why it does not parse (the caller names the field or flag).
pub fn parse_fault(s: &str) -> Result<ScheduledFault, String> {
    let (kind, at) = s
        .split_once('@')
        .ok_or_else(|| "expected KIND@T_S, e.g. nan@1.5".to_string())?;
    let at_s: f64 = at
        .parse()
        .ok()
        .filter(|t: &f64| t.is_finite() && *t >= 0.0)
        .ok_or_else(|| format!("time {at:?} is not a non-negative number of seconds"))?;
    let kind = match kind {
        "nan" => FaultInjection::Nan,
        "frozen" => FaultInjection::Frozen,
        "drop" => FaultInjection::Drop(10),
        "jump" => FaultInjection::Jump(0.2e-3),
        "out_of_range" => FaultInjection::OutOfRange,
        "dead" => FaultInjection::Dead,
        "blind" => FaultInjection::Blind,
        other => {
            match other.strip_prefix("stall:") {
                Some(ms) => {
                    let ms: f64 = ms
                    .parse()
                    .ok()
                    .filter(|m: &f64| m.is_finite() && *m > 0.0 && *m <= 10_000.0)
                    .ok_or_else(|| {
                        format!("stall {ms:?} is not a duration in ms in (0, 10000], e.g. stall:30@1.5")
                    })?;
                    FaultInjection::Stall(ms * 1e-3)
                }
                None => {
                    return Err(format!(
                        "unknown kind {other:?} (nan, frozen, drop, jump, out_of_range, dead, blind, stall:MS)"
                    ))
                }
            }
        }
    };
    Ok(ScheduledFault { at_s, kind })
}
