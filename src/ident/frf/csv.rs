//! The FRF CSV: writing it (atomically) and reading it back, seven columns
//! or the older six and four.

use super::*;

/// Fewest rows of an FRF CSV.
pub const MIN_CSV_POINTS: usize = 10;

/// The frequencies an FRF line may have, Hz: from a decade below the
/// lowest line any bench job measures (a multisine of the longest period,
/// 600 s: 1.7 mHz; a sweep starts at 0.01 Hz at the lowest) to the
/// Nyquist frequency of the fastest loop (`loop.rate_hz` ≤ 100 kHz). Each
/// command then refuses lines at or above its own loop's Nyquist
/// frequency.
pub const FREQUENCY_RANGE_HZ: (f64, f64) = (1e-4, 5e4);

/// The magnitudes an FRF line may have, m/A. Above: 10 times what any
/// bench the config's ranges allow can measure (the widest probe range,
/// 10 mm, over the least current a sweep plays, 0.1 mA at a profile scale
/// of 0.001: 1e5 m/A). Below: 1e-20 m/A is 2e-19 m at the largest coil
/// current (20 A), four decades under the finest displacement a probe
/// resolves with the longest averaging. Within these bounds every number
/// the fit and the design compute from the lines (|H|², the weights
/// 1/|H|, the normal equations of the fit, a controller's gain for a
/// crossover) stays far inside f64: at 1e196 m/A the fit's squares
/// underflowed and its solve failed.
pub const MAGNITUDE_RANGE_M_PER_A: (f64, f64) = (1e-20, 1e6);

/// Largest |phase| of an FRF line, degrees (2778 turns): an unwrapped
/// phase grows by less than 180° per line, and no FRF a bench measures
/// comes near it; up to it an f64 holds the phase to 1e-10°, where
/// beyond 1e15° it cannot even tell a degree.
pub const MAX_ABS_PHASE_DEG: f64 = 1e6;

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
    /// `frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz,sigma_dof`
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
    /// `frequency_hz,magnitude_m_per_a,phase_deg,coherence,sigma_m_per_a,resolution_hz,sigma_dof`),
    /// or the 6-column one of earlier versions ([`CSV_HEADER_6`], without
    /// the last: σ's degrees of freedom are then NaN, not stated) or the
    /// 4-column one ([`CSV_HEADER_4`], without the last three: σ,
    /// resolution and degrees of freedom NaN, unknown), checking
    /// every field ([`Self::push_checked`]): frequencies in
    /// [`FREQUENCY_RANGE_HZ`] and ascending; magnitudes in
    /// [`MAGNITUDE_RANGE_M_PER_A`]; phases within ±[`MAX_ABS_PHASE_DEG`];
    /// coherence in 0 … 1; σ in 0 … the largest magnitude; resolution
    /// above 0 and at most the highest frequency; degrees of freedom at
    /// least 1 (or `inf`, a known variance); at least
    /// [`MIN_CSV_POINTS`] rows, at most [`MAX_CSV_POINTS`].
    ///
    /// # Errors
    /// The reason, naming the line (1-based, the header is line 1) and the
    /// column.
    pub fn read_csv(text: &str) -> Result<Self, String> {
        let mut lines = text.lines();
        let columns = match lines.next() {
            Some(h) if h.trim_end() == CSV_HEADER => 7,
            Some(h) if h.trim_end() == CSV_HEADER_6 => 6,
            Some(h) if h.trim_end() == CSV_HEADER_4 => 4,
            Some(h) => {
                return Err(format!(
                    "line 1: the header is {h:?}, not {CSV_HEADER} (the CSV bench chirp writes), \
                     {CSV_HEADER_6} or {CSV_HEADER_4} (those of earlier versions)"
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
            let mut v = [f64::NAN; 7];
            for (j, f) in fields.iter().enumerate() {
                v[j] = f.trim().parse::<f64>().map_err(|e| {
                    format!(
                        "line {n}: {}: {:?} is not a number ({e})",
                        CSV_COLUMNS[j],
                        f.trim()
                    )
                })?;
                // The degrees of freedom may be infinite (a known variance).
                if j >= 4 && !v[j].is_finite() && !(j == 6 && v[j] == f64::INFINITY) {
                    return Err(format!(
                        "line {n}: {}: {} is not finite (only the 4-column CSV leaves it unknown)",
                        CSV_COLUMNS[j],
                        show(v[j])
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
    /// coherence, sigma_m_per_a, resolution_hz, sigma_dof]` after checking it: the
    /// first four finite; frequency in [`FREQUENCY_RANGE_HZ`] and above the
    /// last one; magnitude in [`MAGNITUDE_RANGE_M_PER_A`]; |phase| at most
    /// [`MAX_ABS_PHASE_DEG`]; coherence in 0 … 1; σ NaN (unknown) or in 0 …
    /// the largest magnitude; resolution NaN (unknown) or above 0 and at
    /// most the highest frequency; degrees of freedom NaN (not stated),
    /// infinite (known) or at least 1. The one check of every FRF read
    /// (CSV, recording).
    ///
    /// # Errors
    /// The reason, naming the column and the range; nothing is appended.
    pub fn push_checked(&mut self, v: [f64; 7]) -> Result<(), String> {
        if let Some(j) = v[..4].iter().position(|x| !x.is_finite()) {
            return Err(format!("{}: {} is not finite", CSV_COLUMNS[j], show(v[j])));
        }
        let (f_lo, f_hi) = FREQUENCY_RANGE_HZ;
        if v[0] <= 0.0 {
            return Err(format!("frequency_hz: {} is not positive", show(v[0])));
        }
        if !(f_lo..=f_hi).contains(&v[0]) {
            return Err(format!(
                "frequency_hz: {} is outside {f_lo:e} … {f_hi:e} Hz (no bench measures a line \
                 there; docs/src/jobs/chirp.md, FRF CSV)",
                show(v[0])
            ));
        }
        if let Some(last) = self.frequency_hz.last().filter(|f| **f >= v[0]) {
            return Err(format!(
                "frequency_hz: {} does not ascend (the point before has {last})",
                v[0]
            ));
        }
        let (m_lo, m_hi) = MAGNITUDE_RANGE_M_PER_A;
        if v[1] <= 0.0 {
            return Err(format!("magnitude_m_per_a: {} is not positive", show(v[1])));
        }
        if !(m_lo..=m_hi).contains(&v[1]) {
            return Err(format!(
                "magnitude_m_per_a: {} is outside {m_lo:e} … {m_hi:e} m/A (no bench measures \
                 a response there; docs/src/jobs/chirp.md, FRF CSV)",
                show(v[1])
            ));
        }
        if v[2].abs() > MAX_ABS_PHASE_DEG {
            return Err(format!(
                "phase_deg: {} is beyond ±{MAX_ABS_PHASE_DEG:e}° (2778 turns; no FRF a bench \
                 measures unwraps that far; docs/src/jobs/chirp.md, FRF CSV)",
                show(v[2])
            ));
        }
        if !(0.0..=1.0).contains(&v[3]) {
            return Err(format!("coherence: {} is outside 0 … 1", show(v[3])));
        }
        if !(v[4].is_nan() || (0.0..=m_hi).contains(&v[4])) {
            return Err(format!(
                "sigma_m_per_a: {} is not a standard deviation of a response (0 … {m_hi:e} m/A)",
                show(v[4])
            ));
        }
        if !(v[5].is_nan() || (v[5] > 0.0 && v[5] <= f_hi)) {
            return Err(format!(
                "resolution_hz: {} is not a band width (above 0, at most {f_hi:e} Hz)",
                show(v[5])
            ));
        }
        if !(v[6].is_nan() || v[6] >= 1.0) {
            return Err(format!(
                "sigma_dof: {} is not the degrees of freedom of a variance estimate (at least 1, \
                 or inf for a known variance)",
                show(v[6])
            ));
        }
        self.frequency_hz.push(v[0]);
        self.magnitude_m_per_a.push(v[1]);
        self.phase_deg.push(v[2]);
        self.coherence.push(v[3]);
        self.sigma_m_per_a.push(v[4]);
        self.resolution_hz.push(v[5]);
        self.sigma_dof.push(v[6]);
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
                "{:.6},{:.6e},{:.3},{:.5},{:.6e},{:.6e},{}",
                self.frequency_hz[i],
                self.magnitude_m_per_a[i],
                self.phase_deg[i],
                self.coherence[i],
                self.sigma_m_per_a[i],
                self.resolution_hz[i],
                self.sigma_dof[i]
            )?;
        }
        w.flush()
    }
}

/// `v` in the shorter of its plain and exponent forms (`1e-300`, not 300
/// zeros; `0.5`, not `5e-1`), as the value in an error is quoted.
fn show(v: f64) -> String {
    let (plain, exp) = (format!("{v}"), format!("{v:e}"));
    if plain.len() <= exp.len() {
        plain
    } else {
        exp
    }
}
