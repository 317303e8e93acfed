//! The FRF and the bench config a `bench chirp` recording holds.

use super::*;

/// The FRF and the bench config a `bench chirp` recording holds.
#[derive(Debug, Clone)]
pub struct RecordedFrf {
    /// `/sysid/frf` (the last one if several).
    pub frf: Frf,
    /// The `toml` entry of the `bench.config` metadata record (the
    /// resolved config), if present.
    pub config_toml: Option<String>,
    /// The `source` entry of the `bench.config` metadata record (the
    /// config file's text as given, comments and all, before the command
    /// line's overrides), if present.
    pub config_source: Option<String>,
}

/// Reads the `/sysid/frf` message and the `bench.config` metadata of the
/// recording in `bytes` (complete, or the `.part` of a killed run).
///
/// # Errors
/// The reason: not a readable MCAP, no `/sysid/frf` channel (with the
/// topics it has), or a `/sysid/frf` payload that is not an FRF (naming
/// the field).
pub fn read_frf(bytes: &[u8]) -> Result<RecordedFrf, String> {
    let read = crate::record::read_messages_tolerant(bytes);
    if read.messages.is_empty() {
        return Err(match read.error {
            Some(e) => format!("not a readable MCAP recording: {e}"),
            None => "no messages: an empty recording".into(),
        });
    }
    let Some(msg) = read
        .messages
        .iter()
        .rev()
        .find(|m| m.channel.topic == crate::record::TOPIC_FRF)
    else {
        let topics = read.topics();
        return Err(format!(
            "no {} channel (a bench chirp recording has one; this one has {})",
            crate::record::TOPIC_FRF,
            topics.join(", ")
        ));
    };
    let p: crate::record::FrfRecord = serde_json::from_slice(&msg.data).map_err(|e| {
        format!(
            "{}: the payload is not an FRF: {e}",
            crate::record::TOPIC_FRF
        )
    })?;
    let n = p.frequency_hz.len();
    if n > MAX_CSV_POINTS {
        return Err(format!(
            "{}: {}",
            crate::record::TOPIC_FRF,
            too_many_points("lines")
        ));
    }
    // A column absent (a recording made before it existed): unknown, or
    // for the degrees of freedom, not stated.
    let unknown = |v: std::borrow::Cow<'_, [f64]>| -> Vec<f64> {
        if v.is_empty() && n > 0 {
            vec![f64::NAN; n]
        } else {
            v.into_owned()
        }
    };
    let sigma = unknown(p.sigma_m_per_a);
    let resolution = unknown(p.resolution_hz);
    let dof = unknown(p.sigma_dof);
    for (name, len) in [
        ("magnitude_m_per_a", p.magnitude_m_per_a.len()),
        ("phase_deg", p.phase_deg.len()),
        ("coherence", p.coherence.len()),
        ("sigma_m_per_a", sigma.len()),
        ("resolution_hz", resolution.len()),
        ("sigma_dof", dof.len()),
    ] {
        if len != n {
            return Err(format!(
                "{}: {name} has {len} values for {n} frequencies",
                crate::record::TOPIC_FRF
            ));
        }
    }
    let mut frf = Frf::empty();
    for k in 0..n {
        frf.push_checked([
            p.frequency_hz[k],
            p.magnitude_m_per_a[k],
            p.phase_deg[k],
            p.coherence[k],
            sigma[k],
            resolution[k],
            dof[k],
        ])
        .map_err(|e| format!("{}: point {}: {e}", crate::record::TOPIC_FRF, k + 1))?;
    }
    if n < MIN_CSV_POINTS {
        return Err(format!(
            "{}: {n} points; an FRF needs at least {}",
            crate::record::TOPIC_FRF,
            MIN_CSV_POINTS
        ));
    }
    let config = mcap::read::LinearReader::new_with_options(
        bytes,
        mcap::read::Options::IgnoreEndMagic.into(),
    )
    .ok()
    .and_then(|r| {
        r.filter_map(Result::ok).find_map(|rec| match rec {
            mcap::records::Record::Metadata(m) if m.name == "bench.config" => Some(m.metadata),
            _ => None,
        })
    });
    Ok(RecordedFrf {
        frf,
        config_toml: config.as_ref().and_then(|m| m.get("toml").cloned()),
        config_source: config.and_then(|mut m| m.remove("source")),
    })
}
