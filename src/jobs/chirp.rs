//! `bench chirp`: excite the stage with a chirp, record, estimate the FRF,
//! plot it beside the model and summarise the modes and the CMP-CNMP test.
//!
//! Threads: the real-time loop (`bench-rt`) drives the stage and pushes
//! records into a wait-free queue; the writer (`bench-writer`) drains it into
//! the MCAP file and keeps the input/output samples for identification; the
//! calling thread shows progress, then estimates, plots and summarises once
//! the loop has stopped.

use crate::config::BenchConfig;
use crate::error::RunError;
use crate::ident::bla::{Bla, DistortionTest};
use crate::ident::excitation::{Chirp, Excitation};
use crate::ident::frf::{Frf, PairVerdict, Resonance, Spectra};
use crate::ident::multisine::{Layout, Multisine};
use crate::jobs::session::{
    finish, open_recording, run_recorded, Kept, Recorded, Runner, SessionOptions, TimingSummary,
};
use crate::outputs::{Existing, Origin, OutputPlan};
use crate::plot::{bode_curve, write_bode_png, BodePlot, BodeSeries, PairZoom};
use crate::rt::backend::{self, BackendSpec};
use crate::rt::{Job, JobOutput};
use bench_hal::model::Sr4dof;
use bench_hal::sim::ZohPlant;
use bench_hal::Sample;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::sync::Arc;

/// Fewest points per decade of the model curve in the Bode plot.
pub const MODEL_POINTS_PER_DECADE: usize = 2000;

/// The chirp job: open loop, command = excitation (a sweep, or a
/// multisine read from its precomputed table).
#[derive(Debug, Clone)]
pub struct ChirpJob {
    excitation: Excitation,
    total_ticks: u64,
}

impl ChirpJob {
    /// Wraps a sweep ([`Chirp`]) or any [`Excitation`].
    pub fn new(excitation: impl Into<Excitation>) -> Self {
        let excitation = excitation.into();
        Self {
            total_ticks: excitation.total_ticks(),
            excitation,
        }
    }
}

impl Job for ChirpJob {
    /// Real-time safe: the sweep in closed form, the multisine by one
    /// table lookup.
    #[inline]
    fn tick(&mut self, tick: u64, _sample: &Sample) -> JobOutput {
        let e = self.excitation.value_a(tick);
        JobOutput {
            command_a: e,
            excitation_a: e,
            setpoint_m: f64::NAN,
            done: tick + 1 >= self.total_ticks,
        }
    }
}

/// The estimator a sweep's record is identified with: the configured one,
/// except that the LPM gives way to H1 when its local window
/// (`2n + 1` bins of the record) is wider than half the narrowest
/// half-power band `2ζf` of the config's modes in the band: the LPM
/// approximates the FRF by a polynomial over its window (Pintelon &
/// Schoukens 2012, §7.2), which a resonance narrower than the window
/// breaks (a short sweep: 13 bins of a 9.5 s record are 1.35 Hz against
/// the X mode's 0.53 Hz). Said on stderr; the CSV's `resolution_hz`
/// shows which estimate each line is.
fn lpm_or_h1(
    cfg: &BenchConfig,
    model: &Sr4dof,
    bin_hz: f64,
) -> (crate::config::IdentificationConfig, FrfEstimator) {
    let mut ident = cfg.identification;
    if ident.estimator != crate::config::Estimator::Lpm {
        return (ident, FrfEstimator::of(EstimatorName::H1));
    }
    let window_hz = (2 * ident.lpm_half_width_bins + 1) as f64 * bin_hz;
    let narrowest = model
        .modes()
        .iter()
        .map(|m| (m.frequency_hz(), 2.0 * m.zeta * m.frequency_hz()))
        .filter(|(f, _)| (cfg.chirp.f_start_hz..=cfg.chirp.f_end_hz).contains(f))
        .map(|(_, b)| b)
        .fold(f64::INFINITY, f64::min);
    if window_hz > 0.5 * narrowest {
        let note = format!(
            "the LPM's window ({window_hz:.3} Hz, {} bins of this record) is wider than half the narrowest half-power band of the config's modes ({narrowest:.3} Hz): the FRF is estimated with H1 (a longer sweep lets the LPM run)",
            2 * ident.lpm_half_width_bins + 1
        );
        tracing::warn!("{note}");
        ident.estimator = crate::config::Estimator::H1;
        let used = FrfEstimator {
            note: Some(note),
            ..FrfEstimator::of(EstimatorName::H1)
        };
        return (ident, used);
    }
    (ident, FrfEstimator::of(EstimatorName::Lpm))
}

/// The estimators a run's FRF can come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum EstimatorName {
    /// The local polynomial method.
    Lpm,
    /// H1 on smoothed spectra.
    H1,
    /// A multisine's best linear approximation.
    Bla,
}

impl EstimatorName {
    /// The measured curve's legend label in a Bode plot.
    pub fn plot_label(self) -> &'static str {
        match self {
            EstimatorName::Lpm => "measured (LPM)",
            EstimatorName::H1 => "measured (H1)",
            EstimatorName::Bla => "measured (BLA)",
        }
    }
}

impl FrfEstimator {
    /// `name`, without a note.
    fn of(name: EstimatorName) -> Self {
        Self { name, note: None }
    }
}

/// Which estimator made a run's FRF, and why when it is not the
/// configured one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct FrfEstimator {
    /// `"lpm"` (the local polynomial method), `"h1"` (smoothed spectra)
    /// or `"bla"` (a multisine's best linear approximation).
    pub name: EstimatorName,
    /// Why the estimator differs from `identification.estimator` (a sweep
    /// too short for the LPM's window); `null` when it does not.
    pub note: Option<String>,
}

/// Everything `bench chirp` needs, resolved from config and arguments.
#[derive(Debug, Clone)]
pub struct ChirpOptions {
    /// The validated bench config (command-line overrides applied).
    pub config: BenchConfig,
    /// Where the config came from (recorded).
    pub config_path: PathBuf,
    /// The MCAP recording.
    pub out: PathBuf,
    /// The FRF CSV.
    pub frf_csv: PathBuf,
    /// The Bode plot PNG.
    pub plot: PathBuf,
    /// The BLA CSV of a multisine (`chirp.kind = "multisine"`:
    /// [`Bla::CSV_HEADER`]); `None`: not written (a sweep ignores it).
    pub bla_csv: Option<PathBuf>,
    /// Real-time pacing instead of virtual time.
    pub realtime: bool,
    /// Virtual time paced at this factor of real time
    /// ([`crate::rt::Pacing::Paced`]); `None`: as fast as it goes. Not with
    /// `realtime`, not on hardware (refused, naming `pace`).
    pub pace: Option<f64>,
    /// Simulator noise seed.
    pub seed: u64,
    /// Show a progress bar (real-time mode, on a terminal).
    pub progress: bool,
    /// `--backend` (else `[backend]` of the config).
    pub backend: Option<BackendSpec>,
    /// A simulator fault to inject (local runs on the simulator only).
    pub inject: Option<bench_hal::sim::ScheduledFault>,
}

/// The model's view of the same bench, for comparison.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ModelSummary {
    /// Natural frequencies of the four modes, Hz.
    pub natural_frequencies_hz: Vec<f64>,
    /// Modal damping ratios, dimensionless.
    pub damping_ratios: Vec<f64>,
    /// Index (0-based) of the X rigid-body mode.
    pub rigid_body_mode: usize,
    /// Zeros of the damped model, `[re, im]` in Hz (s / 2π).
    pub zeros_hz: Vec<[f64; 2]>,
    /// Types of the undamped numerator roots (Chapter 3).
    pub zero_types: Vec<String>,
    /// Eq. (2-8) discriminant of the numerator cubic in `u = s²`, in the
    /// model's SI units (only its sign matters: negative ⇔ CMP-CNMP).
    pub cnmp_discriminant: f64,
    /// The damped model has complex right-half-plane zeros.
    pub cmp_cnmp: bool,
}

/// Result of `bench chirp` (printed, and as JSON with `--json`).
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ChirpSummary {
    /// The MCAP recording.
    pub recording: PathBuf,
    /// The FRF CSV.
    pub frf_csv: PathBuf,
    /// The Bode plot.
    pub plot: PathBuf,
    /// Backend that ran.
    pub backend: String,
    /// Noise seed.
    pub seed: u64,
    /// Operating point Y1o, m, and as a fraction of L.
    pub operating_point_m: f64,
    /// Y1o / L, dimensionless.
    pub operating_point_fraction_of_l: f64,
    /// Mass asymmetry Δm23 = m2/m3 − 1, dimensionless.
    pub mass_asymmetry: f64,
    /// Largest |x1| read during the run, m.
    pub peak_position_m: f64,
    /// The resonances of the measured FRF: the modes of the modal fit,
    /// each at its fitted natural frequency and damping ratio, with the
    /// measured |H| there and its height over the lower flanking minimum
    /// within ±5 %.
    pub resonances: Vec<Resonance>,
    /// The closely spaced pair (of the fit) and the net phase across it.
    pub closely_spaced_pair: Option<PairVerdict>,
    /// Verdict: CMP-CNMP zeros between the pair (`null` when the data
    /// cannot decide; `verdict.reason` says why).
    pub cmp_cnmp: Option<bool>,
    /// The automatic modal fit of the measured FRF (`bench fit`); absent
    /// when it could not be made (`verdict.reason` says why).
    pub fit: Option<crate::ident::modal_fit::ModalFit>,
    /// Both tests behind `cmp_cnmp` and how they combine.
    pub verdict: crate::ident::verdict::Verdict,
    /// The model of the configured bench.
    pub model: ModelSummary,
    /// The estimator that made the FRF (`null` in summaries of older
    /// versions).
    #[serde(default)]
    pub frf_estimator: Option<FrfEstimator>,
    /// Link counters of a hardware backend (CRC errors, sequence gaps,
    /// late samples, timeouts); absent on the simulator.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub link: Option<serde_json::Value>,
    /// Loop timing.
    pub timing: TimingSummary,
    /// The current limits in force and where each came from (`null` in
    /// summaries of older versions).
    #[serde(default)]
    pub current_limits: Option<crate::rt::supervisor::CurrentLimits>,
    /// The stalls the run saw and the FRF lines they cost.
    #[serde(default)]
    pub stalls: StallReport,
    /// The multisine and its best linear approximation
    /// (`chirp.kind = "multisine"`); absent for a sweep.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub multisine: Option<MultisineSummary>,
}

/// A multisine run: the signal played and what the best linear
/// approximation ([`crate::ident::bla`]) made of it.
#[derive(Debug, Clone, Serialize, Deserialize, schemars::JsonSchema)]
pub struct MultisineSummary {
    /// `random` or `schroeder`.
    pub phases: String,
    /// Period T_p, s (whole loop ticks).
    pub period_s: f64,
    /// Line spacing 1 / T_p, Hz.
    pub resolution_hz: f64,
    /// Excited lines, count.
    pub lines: usize,
    /// Lowest and highest excited line, Hz.
    pub band_hz: [f64; 2],
    /// Smallest and largest line amplitude, A.
    pub line_amplitude_a: [f64; 2],
    /// Peak / RMS of the played signal.
    pub crest_factor: f64,
    /// Measured periods per realization, P.
    pub periods: usize,
    /// Discarded periods at the start of each realization.
    pub transient_periods: usize,
    /// Realizations played, M.
    pub realizations: usize,
    /// Realizations in the estimate (stalls may leave some out).
    pub realizations_used: usize,
    /// What is left of the model's slowest modal transient, `e^{−ζω t}`,
    /// at the first measured period of a realization (`t` = the transient
    /// periods), dimensionless; a large value means more transient
    /// periods are needed (it shows as noise and distortion).
    pub model_transient_left: f64,
    /// Median over the lines of `σ̂_BLA / |Ĝ|` (the estimate's total
    /// relative 1σ), dimensionless.
    pub median_sigma_bla_rel: f64,
    /// Median of `σ̂_n / |Ĝ|` (its noise part), dimensionless.
    pub median_sigma_noise_rel: f64,
    /// Median of `σ̂_S / |Ĝ|` (one realization's nonlinear distortion;
    /// `null` with one realization), dimensionless.
    pub median_sigma_nonlinear_rel: Option<f64>,
    /// The test for nonlinear distortion above the noise (`null` with one
    /// realization: Schroeder phases cannot tell it).
    pub distortion: Option<DistortionTest>,
    /// The BLA CSV (per line: Ĝ, σ̂_BLA, σ̂_n, σ̂_S, p-value), if written.
    pub bla_csv: Option<PathBuf>,
}

impl MultisineSummary {
    /// Lines for the printed summary.
    pub fn lines(&self) -> Vec<String> {
        let mut v = vec![
            format!(
                "multisine: {} phases, {} lines {:.3}–{:.1} Hz (every {:.4} Hz at most), {} × ({} + {}) periods of {:.3} s, crest factor {:.2}, line amplitudes {:.2e}–{:.2e} A",
                self.phases,
                self.lines,
                self.band_hz[0],
                self.band_hz[1],
                self.resolution_hz,
                self.realizations,
                self.transient_periods,
                self.periods,
                self.period_s,
                self.crest_factor,
                self.line_amplitude_a[0],
                self.line_amplitude_a[1],
            ),
            format!(
                "BLA from {} of {} realizations: median relative 1σ {:.2e} (noise {:.2e}{})",
                self.realizations_used,
                self.realizations,
                self.median_sigma_bla_rel,
                self.median_sigma_noise_rel,
                match self.median_sigma_nonlinear_rel {
                    Some(x) => format!(", one realization's nonlinear distortion {x:.2e}"),
                    None => String::new(),
                }
            ),
        ];
        v.push(match &self.distortion {
            Some(t) => t.line(),
            None => "nonlinear distortion: not assessed (one realization: Schroeder phases cannot tell it from the response; use phases = \"random\")".into(),
        });
        if self.model_transient_left > 1e-3 {
            v.push(format!(
                "warning: {:.1e} of the model's slowest transient is left after {} transient period(s): raise multisine.transient_periods",
                self.model_transient_left, self.transient_periods
            ));
        }
        v
    }
}

/// The largest relative bias, in power, a stall may leave at the swept
/// line before its band is left out of the FRF: 1e-4, a 1 % error of |H|.
pub const STALL_BIAS_MAX: f64 = 1e-4;

/// The relative bias in power a hold of `hold_s` leaves at the line the
/// sweep is at (`f_hz`, sweeping at `rate_hz_per_s`): the held sample
/// departs from the planned sine by up to `min(2π f t, 2)` of its
/// amplitude, an error pulse of energy `A² min(2π f h, 2)² h / 3`
/// (`h = hold_s`), spread over about `1/h` Hz, against the chirp's energy
/// density `A² / (2 df/dt)` there:
/// `(2/3) min(2π f h, 2)² h² (df/dt)`. Dimensionless.
pub fn held_excitation_bias(f_hz: f64, hold_s: f64, rate_hz_per_s: f64) -> f64 {
    let e = (2.0 * std::f64::consts::PI * f_hz * hold_s).min(2.0);
    2.0 / 3.0 * e * e * hold_s * hold_s * rate_hz_per_s.abs()
}

/// The stalls of an open-loop run (`/bench/event` `stall`: the loop
/// behind its deadlines, or the device on late commands) and what they
/// cost the FRF. A stall holds the last excitation sample while the sweep
/// is at `f(t)`, so the record no longer shows exactly what the plant
/// received there. A stall whose bias at the swept line
/// ([`held_excitation_bias`]) exceeds [`STALL_BIAS_MAX`] (1 % of |H|) has
/// its band left out: the FRF lines whose window (`resolution_hz`: the
/// LPM's local window or H1's smoothing window) meets the frequencies
/// swept during the stall, widened by twice
/// `identification.relative_resolution` on each side (from the FRF, its
/// CSV and fit), counted here. Shorter stalls are counted only: a VM's
/// ordinary one-period overruns bias no line by 1e-8.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct StallReport {
    /// Stalls seen, count.
    pub count: u64,
    /// The longest, s.
    pub longest_s: f64,
    /// All of them, s.
    pub total_s: f64,
    /// The sweep's frequency bands they biased by more than 1 %,
    /// `[f_lo, f_hi]` Hz (a stall in the lead-in or the tail biases none).
    pub bands_hz: Vec<[f64; 2]>,
    /// FRF lines left out, count.
    pub excluded_lines: u64,
    /// Multisine realizations left out of the BLA, count.
    #[serde(default)]
    pub excluded_realizations: u64,
}

/// The relative bias, in power, a hold of `hold_s` leaves at the weakest
/// line of a multisine: the held sample departs from the signal by at most
/// `e = min(2π f_max h, 2) · peak` (Bernstein's inequality bounds the
/// slope of a trigonometric polynomial of top frequency `f_max` by
/// `2π f_max · peak`), an error whose DFT over one period is at most
/// `e · h / T_s` against the line's `N A_min / 2`:
/// `(2 e h / (T_p A_min))²`. Dimensionless.
pub fn held_multisine_bias(
    hold_s: f64,
    f_max_hz: f64,
    peak_a: f64,
    min_line_a: f64,
    period_s: f64,
) -> f64 {
    let e = (2.0 * std::f64::consts::PI * f_max_hz * hold_s).min(2.0) * peak_a;
    (2.0 * e * hold_s / (period_s * min_line_a)).powi(2)
}

impl StallReport {
    /// The report of `stalls` (end tick, length s) on `chirp` at
    /// `period_s`, with the FRF's relative resolution `r`.
    pub fn of(stalls: &[(u64, f64)], chirp: &Chirp, period_s: f64, r: f64) -> Self {
        let mut rep = Self::default();
        let lead_s = chirp.lead_in_ticks() as f64 * period_s;
        let sweep_s = chirp.sweep_s();
        for &(tick, len_s) in stalls {
            if !(len_s.is_finite() && len_s > 0.0) {
                continue;
            }
            rep.count += 1;
            rep.longest_s = rep.longest_s.max(len_s);
            rep.total_s += len_s;
            // The held span in the sweep's time: it ends at `tick`.
            let t_end = tick as f64 * period_s - lead_s;
            let t_start = t_end - len_s - period_s;
            if t_end < 0.0 || t_start > sweep_s {
                continue;
            }
            // The bias the held excitation leaves at the swept line.
            let t_mid = (0.5 * (t_start + t_end)).clamp(0.0, sweep_s);
            let f_s = chirp.frequency_hz(t_mid);
            let bias =
                held_excitation_bias(f_s, len_s + period_s, chirp.sweep_rate_hz_per_s(t_mid));
            if bias <= STALL_BIAS_MAX {
                continue;
            }
            let f_lo = chirp.frequency_hz(t_start.max(0.0)) * (1.0 - 2.0 * r);
            let f_hi = chirp.frequency_hz(t_end.min(sweep_s)) * (1.0 + 2.0 * r);
            rep.bands_hz.push([f_lo, f_hi]);
        }
        rep
    }

    /// The report of `stalls` (end tick, length s) on a multisine of
    /// `plan` at `period_s`, and which realizations the BLA may use: a
    /// stall whose bias at the weakest line ([`held_multisine_bias`])
    /// exceeds [`STALL_BIAS_MAX`] leaves out the realization whose
    /// measured periods it meets (a stall in a transient period, the
    /// lead-in or the tail decays with the transient, or meets nothing).
    fn of_multisine(
        stalls: &[(u64, f64)],
        plan: &MultisinePlan,
        period_s: f64,
    ) -> (Self, Vec<bool>) {
        let mut rep = Self::default();
        let layout = &plan.layout;
        let mut keep = vec![true; layout.realizations];
        for &(tick, len_s) in stalls {
            if !(len_s.is_finite() && len_s > 0.0) {
                continue;
            }
            rep.count += 1;
            rep.longest_s = rep.longest_s.max(len_s);
            rep.total_s += len_s;
            let hold_s = len_s + period_s;
            let bias = held_multisine_bias(
                hold_s,
                plan.f_max_hz,
                plan.peak_a,
                plan.line_amplitude_a[0],
                layout.period_s(),
            );
            if bias <= STALL_BIAS_MAX {
                continue;
            }
            let end = tick as usize;
            let start = end.saturating_sub((hold_s / period_s).ceil() as usize);
            for (m, k) in keep.iter_mut().enumerate() {
                let span = layout.measured(m);
                if start < span.end && end >= span.start {
                    *k = false;
                }
            }
        }
        rep.excluded_realizations = keep.iter().filter(|k| !**k).count() as u64;
        (rep, keep)
    }

    /// `frf` without the lines in the stalls' bands (counted).
    pub fn exclude(&mut self, frf: Frf) -> Frf {
        if self.bands_hz.is_empty() {
            return frf;
        }
        // A line goes when its window (`resolution_hz` wide, centred on it;
        // the line alone where unknown) meets a band.
        let keep: Vec<bool> = frf
            .frequency_hz
            .iter()
            .zip(&frf.resolution_hz)
            .map(|(f, r)| {
                let half = if r.is_finite() { 0.5 * r } else { 0.0 };
                !self
                    .bands_hz
                    .iter()
                    .any(|[lo, hi]| f + half >= *lo && f - half <= *hi)
            })
            .collect();
        self.excluded_lines = keep.iter().filter(|k| !**k).count() as u64;
        frf.select(|i| keep[i])
    }

    /// One line for the summary.
    pub fn line(&self) -> String {
        if self.count == 0 {
            return "stalls: none".to_string();
        }
        let bands: Vec<String> = self
            .bands_hz
            .iter()
            .map(|[a, b]| format!("{a:.2}–{b:.2} Hz"))
            .collect();
        let realizations = if self.excluded_realizations > 0 {
            format!(
                "; {} multisine realization(s) left out",
                self.excluded_realizations
            )
        } else {
            String::new()
        };
        format!(
            "stalls: {} (longest {:.1} ms, {:.1} ms in all); {} FRF lines left out{}{realizations}",
            self.count,
            self.longest_s * 1e3,
            self.total_s * 1e3,
            self.excluded_lines,
            if bands.is_empty() {
                String::new()
            } else {
                format!(" ({})", bands.join(", "))
            }
        )
    }
}

/// What a multisine run keeps of its excitation once the job (and its
/// table) has moved to the loop.
#[derive(Debug, Clone)]
struct MultisinePlan {
    layout: Layout,
    phases: &'static str,
    crest_factor: f64,
    /// Smallest and largest line amplitude, A.
    line_amplitude_a: [f64; 2],
    band_hz: [f64; 2],
    f_max_hz: f64,
    peak_a: f64,
}

impl MultisinePlan {
    fn of(m: &Multisine) -> Self {
        let a = m.amplitudes_a();
        let f = m.frequency_hz();
        let peak_a = (0..m.realizations())
            .flat_map(|r| m.period_a(r).iter())
            .fold(0.0_f64, |p, x| p.max(x.abs()));
        Self {
            layout: m.layout(),
            phases: m.phases().as_str(),
            crest_factor: m.crest_factor(),
            line_amplitude_a: [
                a.iter().copied().fold(f64::INFINITY, f64::min),
                a.iter().copied().fold(0.0, f64::max),
            ],
            band_hz: [f[0], f[f.len() - 1]],
            f_max_hz: f[f.len() - 1],
            peak_a,
        }
    }

    fn summary(&self, bla: &Bla, model: &Sr4dof, bla_csv: Option<PathBuf>) -> MultisineSummary {
        let l = &self.layout;
        // The slowest modal decay rate ζω of the model, 1/s.
        let slowest = model
            .modes()
            .iter()
            .map(|md| md.zeta * 2.0 * std::f64::consts::PI * md.frequency_hz())
            .filter(|r| r.is_finite() && *r > 0.0)
            .fold(f64::INFINITY, f64::min);
        let t = l.transient_periods as f64 * l.period_s();
        let test = bla.distortion_test();
        MultisineSummary {
            phases: self.phases.to_string(),
            period_s: l.period_s(),
            resolution_hz: bla.resolution_hz,
            lines: l.lines.len(),
            band_hz: self.band_hz,
            line_amplitude_a: self.line_amplitude_a,
            crest_factor: self.crest_factor,
            periods: l.periods,
            transient_periods: l.transient_periods,
            realizations: l.realizations,
            realizations_used: bla.realizations,
            model_transient_left: if slowest.is_finite() {
                (-slowest * t).exp()
            } else {
                1.0
            },
            median_sigma_bla_rel: bla.median_relative(&bla.sigma_bla_m_per_a),
            median_sigma_noise_rel: bla.median_relative(&bla.sigma_noise_m_per_a),
            median_sigma_nonlinear_rel: test
                .is_some()
                .then(|| bla.median_relative(&bla.sigma_nonlinear_m_per_a)),
            distortion: test,
            bla_csv,
        }
    }
}

fn model_summary(m: &Sr4dof) -> ModelSummary {
    let two_pi = 2.0 * std::f64::consts::PI;
    ModelSummary {
        natural_frequencies_hz: m.modes().iter().map(|md| md.frequency_hz()).collect(),
        damping_ratios: m.modes().iter().map(|md| md.zeta).collect(),
        rigid_body_mode: m.rigid_body_mode(),
        zeros_hz: m
            .zeros()
            .iter()
            .map(|z| [z.re / two_pi, z.im / two_pi])
            .collect(),
        zero_types: m
            .undamped_zeros()
            .iter()
            .map(|z| z.kind.as_str().to_string())
            .collect::<Vec<_>>(),
        cnmp_discriminant: m.cnmp_discriminant(),
        cmp_cnmp: m.has_cnmp_zeros(),
    }
}

/// What the modal fit and the verdict make of a measured FRF.
#[derive(Debug, Clone)]
pub struct Identified {
    /// The fit (`None` if it could not be made).
    pub fit: Option<crate::ident::modal_fit::ModalFit>,
    /// The verdict.
    pub verdict: crate::ident::verdict::Verdict,
    /// The fitted modes as resonances.
    pub resonances: Vec<Resonance>,
    /// The path outside the mechanics the fit assumed.
    pub path: crate::ident::modal_fit::Path,
}

/// Fits `frf` ([`crate::ident::modal_fit::fit`]) for a loop of period
/// `period_s` and an amplifier of bandwidth `amplifier_bandwidth_hz`, and
/// gives the verdict ([`crate::ident::verdict`]).
pub fn identify(frf: &Frf, period_s: f64, amplifier_bandwidth_hz: f64) -> Identified {
    use crate::ident::modal_fit::{self, FrfData, Path};
    use crate::ident::verdict;
    let path = Path {
        period_s,
        amplifier_bandwidth_hz,
    };
    match modal_fit::fit(&FrfData::from_frf(frf), &path) {
        Ok(fit) => {
            let v = verdict::verdict(frf, &fit, |f| modal_fit::path_phase_deg(&fit, &path, f));
            let resonances = fit
                .modes
                .iter()
                .filter(|m| m.in_path)
                .map(|m| as_resonance(frf, m.frequency_hz, m.damping_ratio))
                .collect();
            Identified {
                fit: Some(fit),
                verdict: v,
                resonances,
                path,
            }
        }
        Err(e) => Identified {
            fit: None,
            verdict: verdict::without_fit(&e.to_string()),
            resonances: Vec::new(),
            path,
        },
    }
}

/// A fitted mode as a [`Resonance`]: measured |H| at the grid point
/// nearest `frequency_hz`, prominence over the lower of the minima within
/// ±5 % on each side.
fn as_resonance(frf: &Frf, frequency_hz: f64, damping_ratio: f64) -> Resonance {
    let g = &frf.frequency_hz;
    let m = &frf.magnitude_m_per_a;
    let k = g.partition_point(|f| *f < frequency_hz).min(g.len() - 1);
    let lo = g.partition_point(|f| *f < frequency_hz / 1.05);
    let hi = g.partition_point(|f| *f <= frequency_hz * 1.05).max(k + 1);
    let left = m[lo..=k].iter().fold(f64::INFINITY, |a, b| a.min(*b));
    let right = m[k..hi].iter().fold(f64::INFINITY, |a, b| a.min(*b));
    Resonance {
        frequency_hz,
        magnitude_m_per_a: m[k],
        damping_ratio: Some(damping_ratio),
        prominence_db: 20.0 * (m[k] / left.min(right)).log10(),
    }
}

/// Runs `bench chirp` end to end on the backend of `opts`, writing the
/// outputs of `outputs` (the paths of `opts`; see [`crate::outputs`]), which
/// are checked before the backend is opened.
///
/// `stop` is raised by SIGINT/SIGTERM; `ticks`, if given, follows the
/// loop's tick count (progress, and the CLI's preparation watch).
///
/// # Errors
/// See [`RunError`]; on every error after the loop started the recording is
/// finished and the amplifier left disabled.
pub fn run_chirp(
    opts: &ChirpOptions,
    mut outputs: OutputPlan,
    stop: Arc<AtomicBool>,
    ticks: Option<&Arc<AtomicU64>>,
) -> Result<ChirpSummary, RunError> {
    outputs.check()?;
    let spec = BackendSpec::resolve(opts.backend.as_ref(), &opts.config);
    let (mut stage, info) = backend::open(
        &spec,
        &opts.config,
        &opts.config_path,
        opts.seed,
        opts.inject,
    )?;
    let mut runner = Runner::Local {
        stage: &mut stage,
        info: &info,
    };
    run_chirp_with(&mut runner, !spec.is_sim(), opts, &mut outputs, stop, ticks)
}

/// The outputs of a chirp, none replaced (the daemon's jobs: their names
/// are derived from the recording's).
pub fn chirp_outputs(opts: &ChirpOptions) -> OutputPlan {
    let plan = OutputPlan::new(Existing::Refuse)
        .with_recording(&opts.out, Origin::Default)
        .with_output("frf_csv", &opts.frf_csv, Origin::Derived)
        .with_output("plot", &opts.plot, Origin::Derived);
    match &opts.bla_csv {
        Some(p) if !opts.config.chirp.kind.is_sweep() => {
            plan.with_output("bla_csv", p, Origin::Derived)
        }
        _ => plan,
    }
}

/// Runs the chirp on `runner` (a configured stage, which it leaves
/// configured, disabled at 0 A; or the daemon's loop), with the outputs of
/// [`chirp_outputs`]. `hardware` forces real-time pacing; `ticks`, if
/// given, follows the loop's tick count (progress).
///
/// # Errors
/// As [`run_chirp`].
pub fn run_chirp_on(
    runner: &mut Runner<'_>,
    hardware: bool,
    opts: &ChirpOptions,
    stop: Arc<AtomicBool>,
    ticks: Option<&Arc<AtomicU64>>,
) -> Result<ChirpSummary, RunError> {
    let mut outputs = chirp_outputs(opts);
    run_chirp_with(runner, hardware, opts, &mut outputs, stop, ticks)
}

fn run_chirp_with(
    runner: &mut Runner<'_>,
    hardware: bool,
    opts: &ChirpOptions,
    outputs: &mut OutputPlan,
    stop: Arc<AtomicBool>,
    ticks: Option<&Arc<AtomicU64>>,
) -> Result<ChirpSummary, RunError> {
    let cfg = &opts.config;
    let info = &runner.info().clone();
    outputs.check()?;
    let model = Sr4dof::new(cfg.plant)
        .map_err(|e| RunError::BadInput(format!("config {}: {e}", opts.config_path.display())))?;
    let period_s = info.period_ns as f64 * 1e-9;
    let rate_hz = 1.0 / period_s;
    // A multisine's table is computed here, before the loop starts.
    let excitation = Excitation::new(cfg, period_s, opts.seed).map_err(|e| {
        RunError::BadInput(format!(
            "config {}: {e} (at the device's period of {period_s} s)",
            opts.config_path.display()
        ))
    })?;
    let total_ticks = excitation.total_ticks();
    if total_ticks > crate::config::ranges::JOB_TICKS_MAX {
        return Err(RunError::BadInput(format!(
            "config {}: chirp.duration_s: lead_in_s + duration_s + tail_s is more than {} ticks at the device's period",
            opts.config_path.display(),
            crate::config::ranges::JOB_TICKS_MAX
        )));
    }
    let lead_in_ticks = excitation.lead_in_ticks();
    let (sweep, plan) = match &excitation {
        Excitation::Sweep(c) => (Some(*c), None),
        Excitation::Multisine(m) => (None, Some(MultisinePlan::of(m))),
    };
    // The LPM's local window must fit in the band: checked on the record's
    // bin spacing before anything is enabled (a sweep's; a multisine's
    // FRF is the BLA on its own lines).
    if sweep.is_some() && cfg.identification.estimator == crate::config::Estimator::Lpm {
        let bin_hz = rate_hz / crate::ident::frf::fast_len(total_ticks as usize) as f64;
        crate::ident::lpm::check_band(
            bin_hz,
            cfg.chirp.f_start_hz,
            cfg.chirp.f_end_hz,
            &crate::ident::lpm::LpmOptions::from_config(&cfg.identification),
        )
        .map_err(|e| RunError::BadInput(format!("config {}: {e}", opts.config_path.display())))?;
    }

    if let (Some(f), true) = (opts.pace, hardware) {
        return Err(RunError::option(
            "pace",
            f,
            crate::jobs::request::pace_on_hardware(&info.name),
        ));
    }
    let session = SessionOptions {
        command: "chirp",
        config_path: &opts.config_path,
        out: &opts.out,
        // Hardware runs in real time whatever the flag says.
        realtime: opts.realtime || hardware,
        pace: opts.pace,
        progress: opts.progress,
        seed: opts.seed,
        max_ticks: total_ticks,
        keep: Kept::CHIRP,
        ticks,
        // Open loop: a stall distorts the record, it endangers nothing; it
        // is recorded and its span left out of the FRF.
        stall: None,
        stall_source: "",
    };
    let recorder = open_recording(&session, cfg, info, outputs)?;
    let run = run_recorded(
        runner,
        ChirpJob::new(excitation),
        cfg,
        recorder,
        &session,
        stop,
    )?;
    let Recorded {
        mut recorder,
        data,
        timing,
        end_ns,
        link: run_link,
        current_limits,
        stalls,
    } = run;
    // The samples go to the disk while the FRF and the fit are computed: an
    // fsync of the part file now (any descriptor of a file syncs it) leaves
    // the one in `finish` only the tail, the summary and the index.
    // Durability is unchanged: `finish` still syncs before the rename, and
    // reports the errors.
    let early_sync = {
        let part = recorder.part_path().to_path_buf();
        std::thread::spawn(move || std::fs::File::open(part).and_then(|f| f.sync_data()))
    };

    // Identification, in the record's own memory: the probe offset (the
    // lead-in's mean) comes off the position in place, and the FFT runs in
    // the packed record (16 bytes a tick at the peak).
    let mut record = data.frf_record;
    let lead = (lead_in_ticks as usize).min(record.len());
    let offset = if lead > 0 {
        record[..lead].iter().map(|z| z.im).sum::<f64>() / lead as f64
    } else {
        0.0
    };
    let mut peak_position_m = 0.0_f64;
    for z in &mut record {
        z.im -= offset;
        peak_position_m = peak_position_m.max(z.im.abs());
    }
    // With the estimator of `identification.estimator` (a NaN sample
    // faults the run before it gets here; the check names it if not).
    let estimate_failed = |e: crate::ident::frf::FrfError| RunError::Output {
        path: opts.frf_csv.clone(),
        reason: format!("the FRF could not be estimated: {e}"),
    };
    let (frf, stall_report, bla, frf_estimator) = match (sweep, &plan) {
        (Some(chirp), _) => {
            crate::ident::frf::check_record(&record).map_err(estimate_failed)?;
            let spectra =
                Spectra::from_record(record, rate_hz, &cfg.identification, cfg.chirp.f_end_hz);
            let (ident, estimator) = lpm_or_h1(cfg, &model, spectra.bin_hz());
            let frf = Frf::from_spectra(&spectra, cfg.chirp.f_start_hz, cfg.chirp.f_end_hz, &ident)
                .map_err(estimate_failed)?;
            let mut stall_report = StallReport::of(
                &stalls,
                &chirp,
                period_s,
                cfg.identification.relative_resolution,
            );
            let frf = stall_report.exclude(frf);
            (frf, stall_report, None, estimator)
        }
        (None, Some(plan)) => {
            let (stall_report, keep) = StallReport::of_multisine(&stalls, plan, period_s);
            let bla = match Bla::estimate(&record, &plan.layout, &keep) {
                Ok(b) => b,
                Err(e) => {
                    // The run is recorded: finish it, then say why there
                    // is no estimate.
                    let _ = early_sync.join();
                    let recording = finish(recorder)?;
                    return Err(RunError::Output {
                        path: opts.frf_csv.clone(),
                        reason: format!(
                            "no best linear approximation: {e}; {}; recording {recording} finished",
                            stall_report.line()
                        ),
                    });
                }
            };
            drop(record);
            let estimator = FrfEstimator::of(EstimatorName::Bla);
            (bla.to_frf(), stall_report, Some(bla), estimator)
        }
        (None, None) => unreachable!("an excitation is a sweep or a multisine"),
    };
    if stall_report.count > 0 {
        tracing::warn!("{}", stall_report.line());
    }
    let zoh = ZohPlant::new(&model, &cfg.actuator, period_s);
    // The fit and the model's curve for the plot, side by side. The model
    // is drawn on a grid at least as dense as MODEL_POINTS_PER_DECADE, so
    // its lightly damped peaks keep their shape in the plot's pair zoom.
    // ... and the FRF CSV is written beside them.
    let (identified, ((model_f, model_h), csv)) = rayon::join(
        || identify(&frf, period_s, cfg.actuator.bandwidth_hz),
        || {
            let f = crate::ident::frf::log_grid(
                cfg.chirp.f_start_hz,
                cfg.chirp.f_end_hz,
                cfg.identification
                    .points_per_decade
                    .max(MODEL_POINTS_PER_DECADE),
            );
            let h: Vec<_> = f.iter().map(|&f| zoh.frf(f)).collect();
            let csv = frf
                .write_csv(&opts.frf_csv, outputs.existing())
                .map_err(|e| RunError::Output {
                    path: opts.frf_csv.clone(),
                    reason: e.to_string(),
                })
                .and_then(|()| match (&bla, &opts.bla_csv) {
                    (Some(b), Some(path)) => {
                        b.write_csv(path, outputs.existing())
                            .map_err(|e| RunError::Output {
                                path: path.clone(),
                                reason: e.to_string(),
                            })
                    }
                    _ => Ok(()),
                });
            ((f, h), csv)
        },
    );
    csv?;

    let (model_mag, model_phase) = bode_curve(&model_h, frf.phase_deg.first().copied());

    let summary = ChirpSummary {
        recording: opts.out.clone(),
        frf_csv: opts.frf_csv.clone(),
        plot: opts.plot.clone(),
        backend: info.name.clone(),
        seed: opts.seed,
        operating_point_m: cfg.plant.operating_point_m,
        operating_point_fraction_of_l: cfg.plant.operating_point_m / cfg.plant.beam.length_m,
        mass_asymmetry: cfg.plant.mass_asymmetry,
        cmp_cnmp: identified.verdict.cmp_cnmp,
        peak_position_m,
        resonances: identified.resonances,
        closely_spaced_pair: identified.verdict.phase_test.pair,
        fit: identified.fit,
        verdict: identified.verdict,
        model: model_summary(&model),
        frf_estimator: Some(frf_estimator),
        link: run_link,
        timing,
        current_limits: Some(current_limits),
        stalls: stall_report,
        multisine: plan
            .as_ref()
            .zip(bla.as_ref())
            .map(|(plan, bla)| plan.summary(bla, &model, opts.bla_csv.clone())),
    };
    let markers: Vec<f64> = summary.resonances.iter().map(|r| r.frequency_hz).collect();
    let no_pair = PairZoom::reason_of(&summary.verdict.phase_test);
    let pair_zoom = PairZoom::of(&summary.verdict.phase_test, &frf, &no_pair);
    let title = format!(
        "x1 / current, Y1o = {:.1} % of L, Δm23 = {:+.0} % (seed {})",
        100.0 * cfg.plant.operating_point_m / cfg.plant.beam.length_m,
        100.0 * cfg.plant.mass_asymmetry,
        opts.seed
    );
    // The plot is rendered while the recording is finished (its tail, the
    // summary and the index written and synced, then renamed): a failed
    // plot still leaves the recording complete.
    let (plotted, finished) = rayon::join(
        || {
            write_bode_png(
                &opts.plot,
                outputs.existing(),
                &BodePlot {
                    title: &title,
                    magnitude_axis: crate::plot::MAGNITUDE_M_PER_A,
                    measured: BodeSeries::measured(
                        &frf,
                        summary
                            .frf_estimator
                            .as_ref()
                            .map_or("measured", |e| e.name.plot_label()),
                    ),
                    coherence: &frf.coherence,
                    model: Some(BodeSeries {
                        label: "model (ZOH)",
                        frequency_hz: &model_f,
                        magnitude: &model_mag,
                        phase_deg: &model_phase,
                    }),
                    markers_hz: &markers,
                    pair: Some(pair_zoom),
                },
            )
            .map_err(|e| RunError::Output {
                path: opts.plot.clone(),
                reason: e.to_string(),
            })
        },
        || -> Result<(), RunError> {
            recorder.write_frf(
                end_ns,
                &crate::record::FrfRecord {
                    frequency_hz: &frf.frequency_hz,
                    magnitude_m_per_a: &frf.magnitude_m_per_a,
                    phase_deg: &frf.phase_deg,
                    coherence: &frf.coherence,
                    sigma_m_per_a: &frf.sigma_m_per_a,
                    resolution_hz: &frf.resolution_hz,
                },
            )?;
            let ch =
                recorder.add_channel_for::<ChirpSummary>("/sysid/summary", "bench.ChirpSummary")?;
            recorder.write(ch, end_ns, &summary)?;
            let _ = early_sync.join();
            finish(recorder)?;
            Ok(())
        },
    );
    finished?;
    plotted?;
    Ok(summary)
}

#[cfg(test)]
mod stall_tests {
    use super::*;

    /// The multisine's bias bound by hand, and the realization a stall
    /// leaves out: a 30 ms hold in realization 1's measured periods drops
    /// it, the same in a transient period or one period's hold drops none.
    #[test]
    fn a_long_stall_leaves_its_realization_out() {
        // e = min(2π · 500 · 0.03, 2) · 0.5 A = 1 A;
        // (2 · 1 · 0.03 / (2 · 1e-3))² = 30² = 900.
        let b = held_multisine_bias(0.03, 500.0, 0.5, 1e-3, 2.0);
        assert!((b - 900.0).abs() < 1e-9, "{b}");
        // One 0.2 ms period at 500 Hz: (2 · 0.628 · 0.5 · 2e-4 / 2e-3)² = 3.9e-3.
        let e = 2.0 * std::f64::consts::PI * 500.0 * 2e-4;
        let by_hand = (2.0 * e * 0.5 * 2e-4 / (2.0 * 1e-3)).powi(2);
        assert!((held_multisine_bias(2e-4, 500.0, 0.5, 1e-3, 2.0) - by_hand).abs() < 1e-15);
        let plan = MultisinePlan {
            layout: Layout {
                lead_in_ticks: 100,
                period_ticks: 1000,
                transient_periods: 1,
                periods: 2,
                realizations: 3,
                lines: vec![1, 2, 3],
                tick_s: 1e-3,
            },
            phases: "random",
            crest_factor: 3.0,
            line_amplitude_a: [0.05, 0.1],
            band_hz: [1.0, 3.0],
            f_max_hz: 3.0,
            peak_a: 0.5,
        };
        // Realization 1 measures ticks 100 + 4000 … 100 + 6000.
        let (rep, keep) = StallReport::of_multisine(&[(4_600, 0.03)], &plan, 1e-3);
        assert_eq!(keep, vec![true, false, true]);
        assert_eq!(rep.excluded_realizations, 1);
        assert!(rep.line().contains("1 multisine realization(s) left out"));
        // In realization 1's transient period (3100 … 4100, the hold
        // 31 ticks before 4050): none.
        let (_, keep) = StallReport::of_multisine(&[(4_050, 0.03)], &plan, 1e-3);
        assert_eq!(keep, vec![true; 3]);
        // A one-tick overrun: its bias is far below 1e-4.
        let (rep, keep) = StallReport::of_multisine(&[(4_600, 1e-3)], &plan, 1e-3);
        assert_eq!((rep.count, keep), (1, vec![true; 3]));
    }

    /// The bias formula's figures: a one-period hold (0.2 ms) at 100 Hz in
    /// a 20 s sweep of 0.1–500 Hz is 1.8e-8; 30 ms at 7.07 Hz in a 4 s
    /// sweep is 1.6e-2 (a 12 % error of |H|), worked by hand from
    /// `(2/3)(2π f h)² h² df/dt`.
    #[test]
    fn held_excitation_bias_by_hand() {
        let k20 = (5000f64).ln() / 20.0;
        let b = held_excitation_bias(100.0, 2e-4, 100.0 * k20);
        let by_hand =
            2.0 / 3.0 * (2.0 * std::f64::consts::PI * 100.0 * 2e-4f64).powi(2) * 4e-8 * 100.0 * k20;
        assert!((b / by_hand - 1.0).abs() < 1e-12 && b < 2e-8, "{b}");
        let f = 0.1 * 5000f64.sqrt();
        let b = held_excitation_bias(f, 0.03, f * (5000f64).ln() / 4.0);
        assert!((b - 1.605e-2).abs() < 0.001e-2, "{b}");
        // The error saturates at twice the amplitude: a hold of many periods.
        let long = held_excitation_bias(100.0, 1.0, 1.0);
        assert!((long - 2.0 / 3.0 * 4.0).abs() < 1e-12);
    }
}
