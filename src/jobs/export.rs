//! `bench export` as a job: a recording's channel as a table
//! ([`crate::record::export`]), except that the FRF channel exported as CSV
//! is written in the FRF CSV format of `bench chirp`
//! (`frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz,sigma_dof`,
//! [`crate::ident::frf::Frf::write_csv_to`]), the one `bench fit`,
//! `bench design` and `bench control --frf` read: an exported FRF travels
//! to the other commands as it is. Parquet keeps the generic table
//! (`log_time_ns` and the fields, one row per line).

use crate::ident::frf::read_frf;
use crate::outputs::{write_atomically, Existing};
use crate::record::export::{export, ExportError, ExportFormat};
use crate::record::TOPIC_FRF;
use std::path::Path;

/// Exports `topic` of `recording` to `out` in `format` (see the module
/// docs); returns the rows written.
///
/// # Errors
/// [`ExportError`]: an unreadable recording or FRF payload, no such topic,
/// or an output that cannot be written.
pub fn export_topic(
    recording: &Path,
    topic: &str,
    format: ExportFormat,
    out: &Path,
    existing: Existing,
) -> Result<usize, ExportError> {
    if topic != TOPIC_FRF || format != ExportFormat::Csv {
        return export(recording, topic, format, out, existing);
    }
    let bytes = crate::record::export::read_recording(recording)?;
    // No FRF channel: the generic error, with the topics the recording has.
    let frf = match read_frf(&bytes) {
        Ok(r) => r.frf,
        Err(_) => return export(recording, topic, format, out, existing),
    };
    write_atomically(out, existing, |f| frf.write_csv_to(f)).map_err(|source| {
        ExportError::Output {
            path: out.to_path_buf(),
            source,
        }
    })?;
    Ok(frf.frequency_hz.len())
}
