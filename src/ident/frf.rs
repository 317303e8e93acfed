//! Frequency-response (FRF) estimation from a chirp record: H1 estimator
//! with magnitude-squared coherence on a log-spaced grid with
//! frequency-dependent resolution (in the spirit of MATLAB `spafdr`), plus
//! the resonance finder and the CMP-CNMP phase test of the summary.
//!
//! # Method
//! 1. The whole record (lead-in, sweep, ring-down tail) of input `u[n]` (A)
//!    and output `y[n]` (m, probe offset removed) is zero-padded to a fast
//!    length `N` and transformed once: both channels packed as one complex
//!    signal `u + i·y` and transformed in the record's own memory by a
//!    four-step FFT ([`crate::ident::fft`], `rustfft` for the short
//!    transforms), giving `U[k]`, `Y[k]` up to the band's top, bin spacing
//!    `Δf = f_s / N`. Because the excitation
//!    starts and ends at rest, the record holds the complete response and the
//!    full-record transform needs no time window.
//! 2. At each grid frequency `f` the cross- and auto-spectra are averaged
//!    over neighbouring bins with a Hann (cos²) weight `w_k` of half width
//!    `h(f) = max(ρ f / 2, n_min Δf / 2)`, ρ the relative resolution:
//!    ```text
//!    S_uu = Σ w_k |U_k|²,  S_yy = Σ w_k |Y_k|²,  S_yu = Σ w_k Y_k U_k*
//!    H1(f) = S_yu / S_uu                              (m/A)
//!    γ²(f) = |S_yu|² / (S_uu S_yy)                    (0 … 1)
//!    ```
//!    (Bendat & Piersol, *Random Data*, §9.2; frequency-smoothed spectra as
//!    in Ljung, *System Identification*, §6.4.) Noise on `y` leaves H1
//!    unbiased and lowers γ²; γ² = 1 for a noise-free linear system.
//! 3. The phase is unwrapped along the grid.
//!
//! The grid is log-spaced with `points_per_decade` points from the sweep's
//! start to its end frequency, so resolution and density both scale with `f`.

use crate::config::IdentificationConfig;
use crate::ident::fft::PackedSpectrum;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::io::Write;
use std::path::Path;

/// Complex number type used for spectra.
pub use super::C64;

/// The spectra of one record, ready to be averaged at any frequency up to
/// the one it was made for.
#[derive(Debug, Clone)]
pub struct Spectra {
    spectrum: PackedSpectrum,
    bin_hz: f64,
    relative_resolution: f64,
    min_bins: usize,
}

/// A smoothed estimate at one frequency.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// H1 = S_yu / S_uu, m/A.
    pub response: C64,
    /// Magnitude-squared coherence, 0 … 1.
    pub coherence: f64,
}

/// Smallest `n ≥ len` of the form 2^a 3^b 5^c (fast FFT sizes; the record
/// is zero-padded to it, so a record reserves this many ticks).
pub fn fast_len(len: usize) -> usize {
    let mut n = len.max(2);
    loop {
        let mut m = n;
        for p in [2, 3, 5] {
            while m.is_multiple_of(p) {
                m /= p;
            }
        }
        if m == 1 {
            return n;
        }
        n += 1;
    }
}

/// Half width of the smoothing window at `f`, Hz: `max(ρ f / 2, n_min Δf / 2)`.
fn half_width_hz(relative_resolution: f64, min_bins: usize, bin_hz: f64, f_hz: f64) -> f64 {
    (0.5 * relative_resolution * f_hz).max(0.5 * min_bins as f64 * bin_hz)
}

impl Spectra {
    /// Transforms the record, keeping every bin up to Nyquist. `u` (A) and
    /// `y` (m) are sampled at `rate_hz`.
    ///
    /// # Panics
    /// If `u` and `y` differ in length.
    pub fn new(u: &[f64], y: &[f64], rate_hz: f64, cfg: &IdentificationConfig) -> Self {
        assert_eq!(
            u.len(),
            y.len(),
            "input and output records differ in length"
        );
        let mut record = Vec::with_capacity(fast_len(u.len()));
        record.extend(u.iter().zip(y).map(|(a, b)| C64::new(*a, *b)));
        Self::from_record(record, rate_hz, cfg, f64::INFINITY)
    }

    /// Transforms a packed record `u[n] + i·y[n]` (A, m; sampled at
    /// `rate_hz`) in its own memory ([`crate::ident::fft`]): zero-padded to
    /// [`fast_len`] (within the reserved capacity if the caller reserved
    /// it), and only the bins that estimates up to `f_max_hz` read are kept.
    /// Peak memory: the record's 16 bytes a tick plus `O(√N)`.
    pub fn from_record(
        mut record: Vec<C64>,
        rate_hz: f64,
        cfg: &IdentificationConfig,
        f_max_hz: f64,
    ) -> Self {
        let n = fast_len(record.len());
        record.resize(n, C64::new(0.0, 0.0));
        let bin_hz = rate_hz / n as f64;
        let k_max = if f_max_hz.is_finite() {
            let top_hz =
                f_max_hz + half_width_hz(cfg.relative_resolution, cfg.min_bins, bin_hz, f_max_hz);
            (top_hz / bin_hz).ceil() as usize + 1
        } else {
            n / 2
        };
        Self {
            spectrum: PackedSpectrum::transform(record, k_max),
            bin_hz,
            relative_resolution: cfg.relative_resolution,
            min_bins: cfg.min_bins,
        }
    }

    /// DFT bin spacing, Hz.
    pub fn bin_hz(&self) -> f64 {
        self.bin_hz
    }

    /// Half width of the smoothing window at `f`, Hz.
    pub fn half_width_hz(&self, frequency_hz: f64) -> f64 {
        half_width_hz(
            self.relative_resolution,
            self.min_bins,
            self.bin_hz,
            frequency_hz,
        )
    }

    /// The smoothed H1 estimate and coherence at `frequency_hz` with the
    /// configured resolution.
    pub fn estimate(&self, frequency_hz: f64) -> Estimate {
        self.estimate_with(frequency_hz, self.half_width_hz(frequency_hz))
    }

    /// The smoothed estimate with an explicit half width, Hz.
    pub fn estimate_with(&self, frequency_hz: f64, half_width_hz: f64) -> Estimate {
        let lo = ((frequency_hz - half_width_hz) / self.bin_hz)
            .ceil()
            .max(0.0) as usize;
        let top = ((frequency_hz + half_width_hz) / self.bin_hz).floor() as usize;
        let nyquist = self.spectrum.fft_len() / 2;
        if top > self.spectrum.k_max() && self.spectrum.k_max() < nyquist {
            // Above the band the spectra were kept for.
            return Estimate {
                response: C64::new(f64::NAN, f64::NAN),
                coherence: 0.0,
            };
        }
        let hi = top.min(self.spectrum.k_max());
        let (mut suu, mut syy, mut syu) = (0.0, 0.0, C64::new(0.0, 0.0));
        for k in lo..=hi {
            let d = (k as f64 * self.bin_hz - frequency_hz) / half_width_hz;
            let w = (0.5 * PI * d).cos().powi(2);
            let (u, y) = self.spectrum.bin(k);
            suu += w * u.norm_sqr();
            syy += w * y.norm_sqr();
            syu += y * u.conj() * w;
        }
        if suu <= 0.0 {
            return Estimate {
                response: C64::new(f64::NAN, f64::NAN),
                coherence: 0.0,
            };
        }
        let coherence = if syy > 0.0 {
            (syu.norm_sqr() / (suu * syy)).min(1.0)
        } else {
            0.0
        };
        Estimate {
            response: syu / suu,
            coherence,
        }
    }
}

/// A measured frequency response on a grid.
#[derive(Debug, Clone, Serialize)]
pub struct Frf {
    /// Grid, Hz (ascending).
    pub frequency_hz: Vec<f64>,
    /// |H1|, m/A.
    pub magnitude_m_per_a: Vec<f64>,
    /// arg H1, degrees, unwrapped along the grid.
    pub phase_deg: Vec<f64>,
    /// γ², 0 … 1.
    pub coherence: Vec<f64>,
}

/// Log-spaced grid from `f_lo` to `f_hi` (Hz) with `per_decade` points per
/// decade, both ends included.
pub fn log_grid(f_lo: f64, f_hi: f64, per_decade: usize) -> Vec<f64> {
    let decades = (f_hi / f_lo).log10();
    let n = ((decades * per_decade as f64).ceil() as usize).max(1);
    (0..=n)
        .map(|i| f_lo * (f_hi / f_lo).powf(i as f64 / n as f64))
        .collect()
}

/// Unwraps a phase sequence in degrees (jumps > 180° folded by 360°).
pub fn unwrap_deg(phase_deg: &mut [f64]) {
    let mut offset = 0.0;
    for i in 1..phase_deg.len() {
        let prev = phase_deg[i - 1];
        let mut cur = phase_deg[i] + offset;
        while cur - prev > 180.0 {
            cur -= 360.0;
            offset -= 360.0;
        }
        while cur - prev < -180.0 {
            cur += 360.0;
            offset += 360.0;
        }
        phase_deg[i] = cur;
    }
}

impl Frf {
    /// The unwrapped phase, degrees, at the first grid point at or above
    /// `frequency_hz` (the last one above the grid; NaN for an empty grid):
    /// the phase the verdict's phase test takes at the edges of its band.
    pub fn phase_at_deg(&self, frequency_hz: f64) -> f64 {
        let grid = &self.frequency_hz;
        if grid.is_empty() {
            return f64::NAN;
        }
        let i = grid
            .partition_point(|g| *g < frequency_hz)
            .min(grid.len() - 1);
        self.phase_deg[i]
    }

    /// Estimates the FRF on the log grid `f_lo … f_hi` (Hz).
    pub fn estimate(spectra: &Spectra, f_lo: f64, f_hi: f64, cfg: &IdentificationConfig) -> Self {
        let frequency_hz = log_grid(f_lo, f_hi, cfg.points_per_decade);
        let est: Vec<Estimate> = frequency_hz.iter().map(|&f| spectra.estimate(f)).collect();
        let mut phase_deg: Vec<f64> = est.iter().map(|e| e.response.arg().to_degrees()).collect();
        unwrap_deg(&mut phase_deg);
        Self {
            magnitude_m_per_a: est.iter().map(|e| e.response.norm()).collect(),
            coherence: est.iter().map(|e| e.coherence).collect(),
            phase_deg,
            frequency_hz,
        }
    }

    /// Writes the CSV `frequency_hz,magnitude_m_per_a,phase_deg,coherence`
    /// to `path` through a temporary file renamed when complete
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
        crate::outputs::write_atomically(path, existing, |f| {
            let mut w = std::io::BufWriter::new(f);
            self.write_csv_to(&mut w)?;
            w.flush()
        })
    }

    /// Reads the CSV `bench chirp` writes
    /// (`frequency_hz,magnitude_m_per_a,phase_deg,coherence`), checking
    /// every field: frequencies positive, finite and ascending; magnitudes
    /// positive and finite; phases finite; coherence in 0 … 1; at least
    /// [`MIN_CSV_POINTS`] rows.
    ///
    /// # Errors
    /// The reason, naming the line (1-based, the header is line 1) and the
    /// column.
    pub fn read_csv(text: &str) -> Result<Self, String> {
        const HEADER: &str = "frequency_hz,magnitude_m_per_a,phase_deg,coherence";
        const COLUMNS: [&str; 4] = [
            "frequency_hz",
            "magnitude_m_per_a",
            "phase_deg",
            "coherence",
        ];
        let mut lines = text.lines();
        match lines.next() {
            Some(h) if h.trim_end() == HEADER => {}
            Some(h) => {
                return Err(format!(
                    "line 1: the header is {h:?}, not {HEADER} (the CSV bench chirp writes)"
                ))
            }
            None => return Err("the file is empty (expected the header {HEADER})".into()),
        }
        let mut frf = Self {
            frequency_hz: Vec::new(),
            magnitude_m_per_a: Vec::new(),
            phase_deg: Vec::new(),
            coherence: Vec::new(),
        };
        for (i, line) in lines.enumerate() {
            let n = i + 2;
            if line.trim().is_empty() {
                continue;
            }
            let fields: Vec<&str> = line.split(',').collect();
            if fields.len() != 4 {
                return Err(format!(
                    "line {n}: {} fields, expected 4 ({HEADER})",
                    fields.len()
                ));
            }
            let mut v = [0.0; 4];
            for (j, f) in fields.iter().enumerate() {
                v[j] = f.trim().parse::<f64>().map_err(|e| {
                    format!(
                        "line {n}: {}: {:?} is not a number ({e})",
                        COLUMNS[j],
                        f.trim()
                    )
                })?;
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
    /// coherence]` after checking it: all finite, frequency positive and
    /// above the last one, magnitude positive, coherence in 0 … 1.
    ///
    /// # Errors
    /// The reason, naming the column; nothing is appended.
    pub fn push_checked(&mut self, v: [f64; 4]) -> Result<(), String> {
        const COLUMNS: [&str; 4] = [
            "frequency_hz",
            "magnitude_m_per_a",
            "phase_deg",
            "coherence",
        ];
        if let Some(j) = v.iter().position(|x| !x.is_finite()) {
            return Err(format!("{}: {} is not finite", COLUMNS[j], v[j]));
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
        self.frequency_hz.push(v[0]);
        self.magnitude_m_per_a.push(v[1]);
        self.phase_deg.push(v[2]);
        self.coherence.push(v[3]);
        Ok(())
    }

    /// Writes the CSV rows (with the header) to `w`.
    ///
    /// # Errors
    /// The writer's.
    pub fn write_csv_to(&self, w: &mut impl Write) -> std::io::Result<()> {
        writeln!(w, "frequency_hz,magnitude_m_per_a,phase_deg,coherence")?;
        for i in 0..self.frequency_hz.len() {
            writeln!(
                w,
                "{:.6},{:.6e},{:.3},{:.5}",
                self.frequency_hz[i],
                self.magnitude_m_per_a[i],
                self.phase_deg[i],
                self.coherence[i]
            )?;
        }
        w.flush()
    }
}

/// Fewest rows of an FRF CSV.
pub const MIN_CSV_POINTS: usize = 10;

/// A resonance found in a measured FRF.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct Resonance {
    /// Peak frequency, Hz (refined between grid points; in `bench chirp`'s
    /// summary the fitted natural frequency).
    pub frequency_hz: f64,
    /// Peak magnitude, m/A.
    pub magnitude_m_per_a: f64,
    /// Damping ratio: in `bench chirp`'s summary the modal fit's; from
    /// [`find_resonances`] the half-power (−3 dB) bandwidth,
    /// `ζ ≈ (f₊ − f₋) / (2 f_n)`, when both half-power points are found
    /// before a neighbouring feature.
    pub damping_ratio: Option<f64>,
    /// Peak height above the lower of the two flanking minima, dB.
    pub prominence_db: f64,
}

/// Smallest magnitude-squared coherence γ² at which an FRF point is taken
/// as data: a resonance must peak at or above it, and the Bode plot draws
/// the points below it faint (at γ² = 0.5 as much of the output power is
/// noise or nonlinearity as is explained by the input; Bendat & Piersol,
/// *Random Data*, §9.2.3).
pub const MIN_COHERENCE: f64 = 0.5;

/// Relative distance at which a lightly damped peak must have dropped by
/// [`SHARPNESS_DB`] on at least one side.
pub const SHARPNESS_SPAN: f64 = 0.03;
/// Drop required within ±[`SHARPNESS_SPAN`] of a peak, dB.
pub const SHARPNESS_DB: f64 = 3.0;

/// Finds lightly damped resonances: local maxima of |H| on the grid that
/// rise at least `min_prominence_db` above the higher of the two flanking
/// minima, have coherence ≥ [`MIN_COHERENCE`], and are sharp — |H| is at least
/// [`SHARPNESS_DB`] lower at `f·(1 ± SHARPNESS_SPAN)` on one side or the
/// other (a single mode passes this for ζ ≲ 0.03; the broad hump that
/// follows an anti-resonance does not). Each peak is then refined on a
/// quarter-bin sweep of the lightly smoothed estimate, and its damping is
/// estimated from the half-power bandwidth.
pub fn find_resonances(frf: &Frf, spectra: &Spectra, min_prominence_db: f64) -> Vec<Resonance> {
    let db: Vec<f64> = frf
        .magnitude_m_per_a
        .iter()
        .map(|m| {
            if *m > 0.0 {
                20.0 * m.log10()
            } else {
                f64::NEG_INFINITY
            }
        })
        .collect();
    let n = db.len();
    let mut out = Vec::new();
    for i in 1..n.saturating_sub(1) {
        if !(db[i] > db[i - 1] && db[i] >= db[i + 1]) || frf.coherence[i] < MIN_COHERENCE {
            continue;
        }
        // Flanking minima: walk down until the curve rises above the peak.
        let flank = |range: &mut dyn Iterator<Item = usize>| {
            let mut lowest = db[i];
            for j in range {
                if db[j] > db[i] {
                    break;
                }
                lowest = lowest.min(db[j]);
            }
            lowest
        };
        let left = flank(&mut (0..i).rev());
        let right = flank(&mut (i + 1..n));
        let prominence = db[i] - left.max(right);
        if prominence < min_prominence_db {
            continue;
        }
        let f = frf.frequency_hz[i];
        let db_at = |x: f64| {
            let j = frf.frequency_hz.partition_point(|g| *g < x).min(n - 1);
            db[j]
        };
        let drop = (db[i] - db_at(f * (1.0 - SHARPNESS_SPAN)))
            .max(db[i] - db_at(f * (1.0 + SHARPNESS_SPAN)));
        if drop < SHARPNESS_DB {
            continue;
        }
        out.push(refine_peak(frf, spectra, i, prominence));
    }
    out
}

fn refine_peak(frf: &Frf, spectra: &Spectra, i: usize, prominence_db: f64) -> Resonance {
    let f = &frf.frequency_hz;
    let (lo, hi) = (f[i - 1], f[i + 1]);
    // Light smoothing (3 bins) so the peak is not flattened by the window.
    let hw = 1.5 * spectra.bin_hz();
    let mag = |x: f64| spectra.estimate_with(x, hw).response.norm();
    let step = spectra.bin_hz() / 4.0;
    let (mut best_f, mut best_m) = (f[i], mag(f[i]));
    let mut x = lo;
    while x <= hi {
        let m = mag(x);
        if m > best_m {
            best_m = m;
            best_f = x;
        }
        x += step;
    }
    // Parabolic interpolation of |H| in dB around the best sample.
    let (a, b, c) = (
        20.0 * mag(best_f - step).log10(),
        20.0 * best_m.log10(),
        20.0 * mag(best_f + step).log10(),
    );
    let denom = a - 2.0 * b + c;
    if denom < 0.0 {
        best_f += 0.5 * step * (a - c) / denom;
    }
    // Half-power points: walk out until |H| < peak/√2, stop at a rise.
    let target = best_m / 2f64.sqrt();
    let walk = |dir: f64| -> Option<f64> {
        let mut prev = best_m;
        let mut x = best_f;
        for _ in 0..20_000 {
            x += dir * step;
            let m = mag(x);
            if m < target {
                // Linear interpolation between the last two samples.
                let frac = (prev - target) / (prev - m);
                return Some(x - dir * step * (1.0 - frac));
            }
            if m > prev * 1.05 {
                return None;
            }
            prev = m;
        }
        None
    };
    let damping_ratio = match (walk(-1.0), walk(1.0)) {
        (Some(f1), Some(f2)) => Some((f2 - f1) / (2.0 * best_f)),
        _ => None,
    };
    Resonance {
        frequency_hz: best_f,
        magnitude_m_per_a: best_m,
        damping_ratio,
        prominence_db,
    }
}

/// The phase test for CMP-CNMP zeros across a closely spaced pair.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct PairVerdict {
    /// Lower mode of the pair, Hz.
    pub lower_hz: f64,
    /// Upper mode of the pair, Hz.
    pub upper_hz: f64,
    /// Band over which the net phase is taken, Hz.
    pub band_hz: (f64, f64),
    /// Net phase change over the band, degrees (unwrapped).
    pub net_phase_deg: f64,
    /// Net phase rounded to a multiple of 180°.
    pub net_phase_multiple_deg: f64,
    /// `true`: two poles and no net phase from the zeros between them —
    /// the −360° signature of CMP-CNMP zeros (thesis §2.2.2, Fig 5-9b).
    pub cmp_cnmp: bool,
}

/// Largest ratio between two adjacent resonances for them to count as a
/// closely spaced pair.
pub const CLOSE_PAIR_RATIO: f64 = 1.25;

/// The FRF and the bench config a `bench chirp` recording holds.
#[derive(Debug, Clone)]
pub struct RecordedFrf {
    /// `/sysid/frf` (the last one if several).
    pub frf: Frf,
    /// The `toml` entry of the `bench.config` metadata record, if present.
    pub config_toml: Option<String>,
}

/// Reads the `/sysid/frf` message and the `bench.config` metadata of the
/// recording in `bytes` (complete, or the `.part` of a killed run).
///
/// # Errors
/// The reason: not a readable MCAP, no `/sysid/frf` channel (with the
/// topics it has), or a `/sysid/frf` payload that is not an FRF (naming
/// the field).
pub fn read_frf(bytes: &[u8]) -> Result<RecordedFrf, String> {
    #[derive(serde::Deserialize)]
    struct Payload {
        frequency_hz: Vec<f64>,
        magnitude_m_per_a: Vec<f64>,
        phase_deg: Vec<f64>,
        coherence: Vec<f64>,
    }
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
    let p: Payload = serde_json::from_slice(&msg.data).map_err(|e| {
        format!(
            "{}: the payload is not an FRF: {e}",
            crate::record::TOPIC_FRF
        )
    })?;
    let n = p.frequency_hz.len();
    for (name, len) in [
        ("magnitude_m_per_a", p.magnitude_m_per_a.len()),
        ("phase_deg", p.phase_deg.len()),
        ("coherence", p.coherence.len()),
    ] {
        if len != n {
            return Err(format!(
                "{}: {name} has {len} values for {n} frequencies",
                crate::record::TOPIC_FRF
            ));
        }
    }
    let mut frf = Frf {
        frequency_hz: Vec::with_capacity(n),
        magnitude_m_per_a: Vec::with_capacity(n),
        phase_deg: Vec::with_capacity(n),
        coherence: Vec::with_capacity(n),
    };
    for k in 0..n {
        frf.push_checked([
            p.frequency_hz[k],
            p.magnitude_m_per_a[k],
            p.phase_deg[k],
            p.coherence[k],
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
    let config_toml = mcap::read::LinearReader::new_with_options(
        bytes,
        mcap::read::Options::IgnoreEndMagic.into(),
    )
    .ok()
    .and_then(|r| {
        r.filter_map(Result::ok).find_map(|rec| match rec {
            mcap::records::Record::Metadata(m) if m.name == "bench.config" => {
                m.metadata.get("toml").cloned()
            }
            _ => None,
        })
    });
    Ok(RecordedFrf { frf, config_toml })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A second-order system driven by white noise: the estimate matches the
    /// analytic FRF (independent reference) and coherence tracks the SNR.
    #[test]
    fn h1_of_a_known_filter() {
        use rand::{Rng, SeedableRng};
        let fs = 1000.0;
        let n = 200_000;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let u: Vec<f64> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
        // y[n] = u[n] − 0.5 u[n−1]: H(e^{jω}) = 1 − 0.5 e^{−jω}.
        let y: Vec<f64> = (0..n)
            .map(|k| u[k] - if k > 0 { 0.5 * u[k - 1] } else { 0.0 })
            .collect();
        let cfg = IdentificationConfig {
            points_per_decade: 50,
            relative_resolution: 0.05,
            min_bins: 31,
        };
        let s = Spectra::new(&u, &y, fs, &cfg);
        let frf = Frf::estimate(&s, 1.0, 400.0, &cfg);
        for (i, f) in frf.frequency_hz.iter().enumerate() {
            let w = 2.0 * PI * f / fs;
            let h = C64::new(1.0 - 0.5 * w.cos(), 0.5 * w.sin());
            assert!(
                (frf.magnitude_m_per_a[i] / h.norm() - 1.0).abs() < 0.02,
                "{f} Hz"
            );
            let dphi = frf.phase_deg[i] - h.arg().to_degrees();
            assert!(dphi.abs() < 1.0, "{f} Hz phase {dphi}");
            assert!(frf.coherence[i] > 0.999);
        }
        // With output noise of equal power, γ² ≈ |H|²/(|H|²+σ²/σu²).
        let ynoisy: Vec<f64> = y.iter().map(|v| v + rng.random_range(-1.0..1.0)).collect();
        let s = Spectra::new(&u, &ynoisy, fs, &cfg);
        let e = s.estimate(250.0);
        let h2 = C64::new(1.0 - 0.5 * (PI / 2.0).cos(), 0.5 * (PI / 2.0).sin()).norm_sqr();
        let expected = h2 / (h2 + 1.0);
        assert!(
            (e.coherence - expected).abs() < 0.05,
            "{} vs {expected}",
            e.coherence
        );
    }

    #[test]
    fn unwrap_and_grid() {
        let mut p = vec![170.0, -170.0, -10.0, 175.0, -175.0];
        unwrap_deg(&mut p);
        // Each step takes the representative nearest the previous value.
        assert_eq!(p, vec![170.0, 190.0, 350.0, 175.0, 185.0]);
        let g = log_grid(1.0, 1000.0, 10);
        assert_eq!(g.len(), 31);
        assert!((g[10] - 10.0).abs() < 1e-9 && (g[30] - 1000.0).abs() < 1e-9);
        assert_eq!(fast_len(7), 8);
        assert_eq!(fast_len(121), 125);
    }
}
