//! The FRF CSV: writing it (atomically) and reading it back, six columns or
//! the older four.

use super::*;

/// Fewest rows of an FRF CSV.
pub const MIN_CSV_POINTS: usize = 10;

/// Most lines of an FRF (a CSV's data rows, a recording's `/sysid/frf`):
/// 100 000. The densest grid `bench` estimates is
/// `identification.points_per_decade` ≤ 10 000 over at most 6.7 decades
/// (0.01 Hz to the 50 kHz Nyquist frequency of a 100 kHz loop), 67 000
/// lines; a default chirp's has about 1 500, a real chirp's a few hundred
/// to a few thousand. A file with more is not a measurement of this
/// bench, and is refused before it is parsed whole (the fit and the
/// design would spend minutes on it).
pub const MAX_CSV_POINTS: usize = 100_000;

/// The refusal of an FRF of more than [`MAX_CSV_POINTS`] lines.
pub(crate) fn too_many_points(what: &str) -> String {
    format!(
        "more than {MAX_CSV_POINTS} {what}: the densest FRF bench estimates has 67 000 \
         (10 000 points a decade from 0.01 Hz to 50 kHz); not an FRF of this bench"
    )
}

impl Frf {
    /// Writes the CSV
    /// `frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz`
    /// ([`CSV_HEADER`]) to `path` through a temporary file renamed when complete
    /// ([`outputs::write_atomically`](crate::outputs::write_atomically)):
    /// a failed write leaves nothing under `path`, and an existing `path`
    /// is replaced only with [`Existing::Replace`](crate::outputs::Existing::Replace).
    ///
    /// # Errors
    /// I/O errors from creating, writing or renaming the file.
    pub fn write_csv(
        &self,
        path: &Path,
        existing: crate::outputs::Existing,
    ) -> std::io::Result<()> {
        crate::outputs::write_buffered_atomically(path, existing, |w| self.write_csv_to(w))
    }

    /// Reads the CSV `bench chirp` writes ([`CSV_HEADER`]:
    /// `frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz`),
    /// or the 4-column one of earlier versions ([`CSV_HEADER_4`], without
    /// the last two: σ and resolution are then NaN, unknown), checking
    /// every field: frequencies positive, finite and ascending; magnitudes
    /// positive and finite; phases finite; coherence in 0 … 1; σ finite and
    /// ≥ 0; resolution finite and > 0; at least [`MIN_CSV_POINTS`] rows,
    /// at most [`MAX_CSV_POINTS`].
    ///
    /// # Errors
    /// The reason, naming the line (1-based, the header is line 1) and the
    /// column.
    pub fn read_csv(text: &str) -> Result<Self, String> {
        let mut lines = text.lines();
        let columns = match lines.next() {
            Some(h) if h.trim_end() == CSV_HEADER => 6,
            Some(h) if h.trim_end() == CSV_HEADER_4 => 4,
            Some(h) => {
                return Err(format!(
                    "line 1: the header is {h:?}, not {CSV_HEADER} (the CSV bench chirp writes) \
                     or {CSV_HEADER_4} (that of earlier versions)"
                ))
            }
            None => {
                return Err(format!(
                    "the file is empty (expected the header {CSV_HEADER})"
                ))
            }
        };
        let mut frf = Self::empty();
        for (i, line) in lines.enumerate() {
            let n = i + 2;
            if line.trim().is_empty() {
                continue;
            }
            if frf.frequency_hz.len() == MAX_CSV_POINTS {
                return Err(format!("line {n}: {}", too_many_points("data lines")));
            }
            let fields: Vec<&str> = line.split(',').collect();
            if fields.len() != columns {
                return Err(format!(
                    "line {n}: {} fields, expected {columns} ({})",
                    fields.len(),
                    CSV_COLUMNS[..columns].join(",")
                ));
            }
            let mut v = [f64::NAN; 6];
            for (j, f) in fields.iter().enumerate() {
                v[j] = f.trim().parse::<f64>().map_err(|e| {
                    format!(
                        "line {n}: {}: {:?} is not a number ({e})",
                        CSV_COLUMNS[j],
                        f.trim()
                    )
                })?;
                if j >= 4 && !v[j].is_finite() {
                    return Err(format!(
                        "line {n}: {}: {} is not finite (only the 4-column CSV leaves it unknown)",
                        CSV_COLUMNS[j], v[j]
                    ));
                }
            }
            frf.push_checked(v).map_err(|e| format!("line {n}: {e}"))?;
        }
        if frf.frequency_hz.len() < MIN_CSV_POINTS {
            return Err(format!(
                "{} data lines; an FRF needs at least {MIN_CSV_POINTS}",
                frf.frequency_hz.len()
            ));
        }
        Ok(frf)
    }

    /// Appends the point `[frequency_hz, magnitude_m_per_a, phase_deg,
    /// coherence, sigma_m_per_a, resolution_hz]` after checking it: the
    /// first four finite, frequency positive and above the last one,
    /// magnitude positive, coherence in 0 … 1; σ NaN (unknown) or finite
    /// and ≥ 0; resolution NaN (unknown) or finite and > 0.
    ///
    /// # Errors
    /// The reason, naming the column; nothing is appended.
    pub fn push_checked(&mut self, v: [f64; 6]) -> Result<(), String> {
        if let Some(j) = v[..4].iter().position(|x| !x.is_finite()) {
            return Err(format!("{}: {} is not finite", CSV_COLUMNS[j], v[j]));
        }
        if v[0] <= 0.0 {
            return Err(format!("frequency_hz: {} is not positive", v[0]));
        }
        if let Some(last) = self.frequency_hz.last().filter(|f| **f >= v[0]) {
            return Err(format!(
                "frequency_hz: {} does not ascend (the point before has {last})",
                v[0]
            ));
        }
        if v[1] <= 0.0 {
            return Err(format!("magnitude_m_per_a: {} is not positive", v[1]));
        }
        if !(0.0..=1.0).contains(&v[3]) {
            return Err(format!("coherence: {} is outside 0 … 1", v[3]));
        }
        if !(v[4].is_nan() || (v[4].is_finite() && v[4] >= 0.0)) {
            return Err(format!(
                "sigma_m_per_a: {} is not a standard deviation (finite, ≥ 0)",
                v[4]
            ));
        }
        if !(v[5].is_nan() || (v[5].is_finite() && v[5] > 0.0)) {
            return Err(format!(
                "resolution_hz: {} is not a band width (finite, > 0)",
                v[5]
            ));
        }
        self.frequency_hz.push(v[0]);
        self.magnitude_m_per_a.push(v[1]);
        self.phase_deg.push(v[2]);
        self.coherence.push(v[3]);
        self.sigma_m_per_a.push(v[4]);
        self.resolution_hz.push(v[5]);
        Ok(())
    }

    /// Writes the CSV rows (with the header [`CSV_HEADER`]) to `w`.
    ///
    /// # Errors
    /// The writer's.
    pub fn write_csv_to(&self, w: &mut impl Write) -> std::io::Result<()> {
        writeln!(w, "{CSV_HEADER}")?;
        for i in 0..self.frequency_hz.len() {
            writeln!(
                w,
                "{:.6},{:.6e},{:.3},{:.5},{:.6e},{:.6e}",
                self.frequency_hz[i],
                self.magnitude_m_per_a[i],
                self.phase_deg[i],
                self.coherence[i],
                self.sigma_m_per_a[i],
                self.resolution_hz[i]
            )?;
        }
        w.flush()
    }
}
