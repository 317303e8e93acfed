//! `bench chirp`: excite the stage with a chirp, record, estimate the FRF,
//! plot it beside the model and summarise the modes and the CMP-CNMP test.
//!
//! Threads: the real-time loop (`bench-rt`) drives the stage and pushes
//! records into a wait-free queue; the writer (`bench-writer`) drains it into
//! the MCAP file and keeps the input/output samples for identification; the
//! calling thread shows progress, then estimates, plots and summarises once
//! the loop has stopped.

use crate::config::{BenchConfig, ExcitationKind};
use crate::error::RunError;
use crate::ident::bla::{Bla, DistortionTest};
use crate::ident::chirp::Chirp;
use crate::ident::excitation::Excitation;
use crate::ident::frf::{Frf, PairVerdict, Resonance, Spectra};
use crate::ident::multisine::{Layout, Multisine};
use crate::jobs::session::{
    finish, open_recording, run_recorded, Kept, Recorded, Runner, SessionOptions, TimingSummary,
};
use crate::outputs::{beside, Destination, Existing, Origin, OutputPlan};
use crate::plot::{bode_curve, write_bode_png, BodePlot, BodeSeries, PairZoom};
use crate::rt::backend::{self, BackendSpec};
use crate::rt::{Job, JobOutput};
use bench_hal::Sample;
use bench_plant::model::Sr4dof;
use bench_plant::sim::ZohPlant;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::sync::Arc;

mod identify;
mod run;
mod stall;
pub use identify::*;
pub use run::*;
pub use stall::*;

/// A chirp's outputs beside its recording `<stem>.mcap`: the one place
/// their names are made, for `bench chirp` (where `--frf-csv`, `--plot`
/// and `--bla-csv` may name others) and the daemon's jobs alike.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChirpOutputs {
    /// `<stem>.frf.csv`: the FRF.
    pub frf_csv: PathBuf,
    /// `<stem>.bode.png`: its Bode plot.
    pub plot: PathBuf,
    /// `<stem>.bla.csv`: a multisine's best linear approximation; `None`
    /// for a sweep.
    pub bla_csv: Option<PathBuf>,
}

impl ChirpOutputs {
    /// The suffixes, FRF CSV, Bode plot, BLA CSV.
    const SUFFIXES: [&'static str; 3] = [".frf.csv", ".bode.png", ".bla.csv"];

    /// The suffixes a recording's name must leave free
    /// ([`crate::outputs::claim_recording`]'s companions).
    pub fn companions(multisine: bool) -> &'static [&'static str] {
        if multisine {
            &Self::SUFFIXES
        } else {
            &Self::SUFFIXES[..2]
        }
    }

    /// The recording of a chirp playing `kind` and its outputs where
    /// `dest` puts them ([`Destination::recording`]; `--frf-csv`,
    /// `--plot`, `--bla-csv` beside it unless given), with the plan that
    /// checks them. The command line and the daemon both name a chirp's
    /// outputs here.
    ///
    /// # Errors
    /// [`RunError::BadOption`]: the recording's
    /// ([`Destination::recording`]), or `bla_csv` given for a sweep (which
    /// has no BLA).
    pub fn plan(
        dest: &Destination,
        kind: ExcitationKind,
    ) -> Result<(PathBuf, Self, OutputPlan), RunError> {
        let multisine = !kind.is_sweep();
        if !multisine && dest.given("bla_csv").is_some() {
            return Err(RunError::option(
                "bla_csv",
                "",
                format!(
                    "excitation.kind = \"{}\" plays a sweep, which has no BLA (excitation.kind = \"multisine\" or --excitation multisine has)",
                    kind.as_str()
                ),
            ));
        }
        let (out, plan) = dest.recording("chirp", Self::companions(multisine), true)?;
        let beside = Self::beside(&out, multisine);
        let (frf_csv, frf_origin) = dest.beside_recording("frf_csv", beside.frf_csv);
        let (plot, plot_origin) = dest.beside_recording("plot", beside.plot);
        let plan = plan
            .with_output("frf_csv", &frf_csv, frf_origin)
            .with_output("plot", &plot, plot_origin);
        let (bla_csv, plan) = match beside.bla_csv {
            Some(default) => {
                let (p, origin) = dest.beside_recording("bla_csv", default);
                let plan = plan.with_output("bla_csv", &p, origin);
                (Some(p), plan)
            }
            None => (None, plan),
        };
        let outputs = Self {
            frf_csv,
            plot,
            bla_csv,
        };
        Ok((out, outputs, plan))
    }

    /// The outputs beside the recording `out` ([`beside`]).
    pub fn beside(out: &std::path::Path, multisine: bool) -> Self {
        let [frf, plot, bla] = Self::SUFFIXES;
        Self {
            frf_csv: beside(out, frf),
            plot: beside(out, plot),
            bla_csv: multisine.then(|| beside(out, bla)),
        }
    }
}

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
    /// The BLA CSV of a multisine (`excitation.kind = "multisine"`:
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
    pub inject: Option<bench_plant::sim::ScheduledFault>,
    /// Append the run's row to the run catalogue beside its recording
    /// once the recording is finished ([`crate::jobs::catalogue`]): the
    /// CLI's and the daemon's runs; not a campaign's cells (the campaign
    /// keeps its own results).
    pub catalogue: bool,
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
    /// (`excitation.kind = "multisine"`); absent for a sweep.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub multisine: Option<MultisineSummary>,
    /// The run's row in the run catalogue, or why it was not written;
    /// absent when the run is not catalogued (a campaign's cells, and the
    /// summary recorded in the recording, which the row is read from).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub catalogue: Option<crate::jobs::catalogue::CatalogueEntry>,
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

#[cfg(test)]
mod tests;
