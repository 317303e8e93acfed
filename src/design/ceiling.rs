//! The limit of a design's own inputs: [`super::limit::performance_limit`]
//! on every coherent line of every input and on each input's fitted model
//! between and above them, with what binds it, for `bench design`'s
//! report.
//!
//! # The lines
//! Each input's coherent lines (the plant with the computation delay, as
//! the design judges it; every line within ±4 % of a fitted mode, and
//! elsewhere every n-th so that at most [`LINES_PER_INPUT`] remain, fewer
//! for many inputs, [`LINES_TOTAL`]) and,
//! from its modal fit ([`super::fitted`]) with
//! the same delay: a log grid of [`MODEL_LINES_PER_DECADE`] from the
//! input's lowest line to [`TOP_FRACTION`] of the Nyquist frequency,
//! keeping the points above the measured band and those in a gap of the
//! measurement wider than [`GAP_RATIO`]; and across each fitted mode,
//! and across the pole and the zero of each MMP pair that every input has
//! ([`light_pairs`], which the `limit` strategy may cancel), points
//! `ω + kζω/2`, `k = −8…8`, where no measured line lies within `ζω/4`.
//! Across the modes these points replaced seven across the half-power
//! band where it fell between two lines: the measured lines of a default
//! chirp are ~1.5 rad/s apart, and the v mode's peak (half-width 2 s⁻¹ at
//! 532 rad/s) fell between them, where the certificate's dense grid then
//! found |S| 1.48 that the climb's lines read as 1.27; over the README
//! chirp's seeds 1–8 the design reached 0.72 of the limit on average
//! before, 0.83 with them (and [`super::fixed_order::ABOVE_EDGE_DAMPING`]).
//! The `limit` strategy climbs on these lines and, a second time, on the
//! same lines without the points across the modes ([`ModelPoints`],
//! [`ClimbLines`]): the climb is local and takes another path there (the
//! 20-cell campaign of `benches/design-time.sh`: 0.79 of its limit
//! across the modes, 1.01 without).
//! (The same points across every lightly damped zero of the fits, not
//! only the pairs', made the climb stall on the shipped bench, 0.75 of its
//! limit against 0.87, and across each input's own pairs the 20-cell
//! campaign's, 255 rad/s against 303: the climb is local, and the
//! certificate's dense grid judges its result either way.)
//! At a measured line whose noise (its 1σ from the FRF, `sigma_m_per_a`)
//! cannot resolve the bound the weight sets on |S| there, the fit at the
//! same frequency stands in for it ([`super::limit::NOISE_RESOLUTION`]):
//! well below ω* the weight asks |S| ≈ ω/ω*, far under a line's relative
//! noise, and only a smooth model can decide it.
//!
//! # When there is no limit
//! The Youla form needs a stable plant. A fit whose mass line (`L/s²`) is
//! significant (above 3σ and more than [`MASS_LINE_SHARE_MAX`] of the
//! response at the lowest line) describes a free mass: the report says so
//! and the design goes on with the search alone. A cone program that
//! neither solves nor proves infeasibility leaves the limit uncomputed,
//! with the solver's status.

use super::fitted::FittedPlant;
use super::limit::{
    performance_limit, rhp_zero_bound_rad_s, Basis, BindingLine, LineNoise, Lines, LoopBounds,
    ZeroBound,
};
use super::loops::DesignFrf;
use crate::ident::C64;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Model points per decade between and above the measured lines.
pub const MODEL_LINES_PER_DECADE: f64 = 200.0;
/// The model's lines end at this fraction of the Nyquist frequency (the
/// independent reference's band, `tests/data/limit_reference.py`).
pub const TOP_FRACTION: f64 = 0.98;
/// A gap between two measured lines wider than this ratio gets model
/// points.
pub const GAP_RATIO: f64 = 1.02;
/// A pole and a zero damped less than this are lightly damped: an MMP
/// pair of them gets model points across it ([`light_pairs`]; a 2 %
/// half-power half-width: wider features are seen by the log grid and the
/// measured lines).
pub const LIGHT_DAMPING: f64 = 0.02;
/// Zeros of several fits closer than this fraction of their modulus are
/// one pole pair of Q's basis (5 %: a workspace's zeros move a few % from
/// cell to cell, and one pole pair serves them all).
pub const ZERO_MERGE: f64 = 0.05;
/// Most measured lines per input in the cone programs: every line within
/// ±4 % of a fitted mode, and every n-th elsewhere so that at most this
/// many remain (a default chirp's 400 lines per decade vary smoothly
/// between the resonances) …
pub const LINES_PER_INPUT: usize = 300;
/// … and at most this many over all inputs, down to
/// [`LINES_PER_INPUT_MIN`] an input (a workspace of 20 inputs: 150 each).
pub const LINES_TOTAL: usize = 3000;
/// The fewest lines an input keeps outside its modes' neighbourhoods.
pub const LINES_PER_INPUT_MIN: usize = 100;

/// The band edge's bound on |T| (|L| ≤ 0.24/(1 − 0.24) = −10.0 dB), in
/// the limit and in a design alike ([`ProgramLines::bounds`]).
pub const EDGE_T_MAX: f64 = 0.24;
/// The band edge starts at this fraction of the highest coherent line.
pub const EDGE_FRACTION: f64 = 0.9;

/// Largest share of a fit's response at its lowest line that a mass line
/// may have for the plant to count as stable (10 %).
pub const MASS_LINE_SHARE_MAX: f64 = 0.1;

/// The limit as `bench design` reports it (JSON `limit`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct LimitReport {
    /// The largest performance bandwidth ω* any stabilising LTI
    /// controller reaches on these inputs with the same M, delay and
    /// amplifier, rad/s (`null`: not computed, see `not_computed`).
    pub performance_bandwidth_rad_s: Option<f64>,
    /// Its 1σ from the lines' noise and the fits' covariance, rad/s,
    /// first order through the cone program's dual (`null`: not known,
    /// e.g. a 4-column CSV, or not computed).
    #[serde(default)]
    pub performance_bandwidth_sigma_rad_s: Option<f64>,
    /// The search's upper end: no Q of the basis reaches it, rad/s.
    pub infeasible_above_rad_s: Option<f64>,
    /// Why no limit was computed (`null`: it was).
    pub not_computed: Option<String>,
    /// `M`, the largest |S| of the weight (`--s-max`).
    pub s_max: f64,
    /// Each right-half-plane zero of the fits (upper half plane) and the
    /// largest ω* it allows, `|1/M + ω*/z| ≤ 1`.
    pub rhp_zeros: Vec<ZeroBound>,
    /// Where `|W_P S|` is within 1 % of its largest value at the limit.
    pub binding: Vec<BindingLine>,
    /// What binds, in words.
    pub binds: String,
    /// The effort bound the limit and the design keep, `|K S|` ≤ this on
    /// every line, A/m: the peak current over the setpoint step
    /// ([`LoopBounds::effort_for_step`]).
    pub effort_max_a_per_m: f64,
    /// The band edge, rad/s: from here up `|T|` ≤ [`EDGE_T_MAX`] in the
    /// limit and the design; `null` where the limit was not computed.
    pub band_edge_rad_s: Option<f64>,
    /// Lines the cone programs held: measured (at most
    /// [`LINES_PER_INPUT`] an input), and from the fits.
    pub lines: [usize; 2],
    /// Measured lines too noisy to resolve the bound on |S| at the limit
    /// (2σ |W_P| > 0.5), where the fit stood in.
    pub fit_stood_in_lines: usize,
    /// Cone programs solved.
    pub solves: usize,
    /// Wall time, s.
    pub time_s: f64,
}

/// The fits' model lines of one input (module docs), at the loop period
/// `period_s` with the delay `delay_s`: `(ω, P)`.
fn model_lines(
    frf: &DesignFrf,
    plant: &FittedPlant,
    pairs: &[LightPair],
    (period_s, delay_s): (f64, f64),
    points: ModelPoints,
) -> (Vec<f64>, Vec<C64>) {
    let w = &frf.omega_rad_s;
    let (lo, hi) = (w[0], *w.last().expect("lines"));
    let top = TOP_FRACTION * PI / period_s;
    let mut grid: Vec<f64> = Vec::new();
    let decades = (top / lo).log10();
    let n = (decades * MODEL_LINES_PER_DECADE).ceil().max(1.0) as usize;
    let in_gap = |x: f64| {
        if x > hi {
            return true;
        }
        let i = w.partition_point(|v| *v < x);
        i > 0 && i < w.len() && w[i] / w[i - 1] > GAP_RATIO
    };
    for k in 0..=n {
        let x = lo * (top / lo).powf(k as f64 / n as f64);
        if x > lo && in_gap(x) {
            grid.push(x);
        }
    }
    // Across every fitted mode, and across the pole and the zero of each
    // MMP pair that the `limit` strategy's climb may cancel (those of
    // every input): points every half of the half-power half-width `ζω`
    // over ±4 of them, where no measured line lies within a quarter of it
    // (a resonance, and a cancellation's residue, are as narrow as that).
    let modes = plant
        .fit()
        .modes
        .iter()
        .map(|m| (2.0 * PI * m.frequency_hz, m.damping_ratio));
    let pair_roots = pairs.iter().flat_map(|p| [p.pole, p.zero]);
    let across = match points {
        ModelPoints::AcrossModes => modes.chain(pair_roots).collect(),
        ModelPoints::GapsOnly => Vec::new(),
    };
    for (wn, z) in across {
        let half_width = z * wn;
        let near_a_line = |x: f64| {
            let i = w.partition_point(|v| *v < x);
            [i.checked_sub(1), Some(i)]
                .into_iter()
                .flatten()
                .filter_map(|j| w.get(j))
                .any(|v| (v - x).abs() < 0.25 * half_width)
        };
        grid.extend(
            (-8..=8)
                .map(|k| wn + 0.5 * f64::from(k) * half_width)
                .filter(|x| *x > lo && *x < top && !near_a_line(*x)),
        );
    }
    grid.sort_by(f64::total_cmp);
    grid.dedup();
    let p = grid
        .iter()
        .map(|&x| plant.frf(x) * C64::from_polar(1.0, -x * delay_s))
        .collect();
    (grid, p)
}

/// The limit of the inputs `frfs` (coherent lines, computation delay
/// applied) and their fits `plants` (same order) on their program lines
/// `set` (the [`program_lines`] of both with the fits' points across
/// every mode, [`ModelPoints::AcrossModes`]: the set a climb's first
/// climbs run on, [`ClimbLines::across_modes`]), for a loop of
/// `period_s` and `M = s_max`. Where a line's noise cannot resolve the
/// bound on |S| the fit stands in for it
/// ([`super::limit::NOISE_RESOLUTION`]). Never fails: what prevents a
/// limit is reported in `not_computed`.
pub fn bench_limit(
    frfs: &[DesignFrf],
    plants: &[FittedPlant],
    set: &ProgramLines,
    period_s: f64,
    s_max: f64,
    effort_max_a_per_m: f64,
) -> LimitReport {
    let t0 = std::time::Instant::now();
    let hz = |z: C64| z / (2.0 * PI);
    let zeros = fit_zeros(plants);
    let mut rhp_zeros: Vec<ZeroBound> = rhp_fit_zeros(plants, s_max)
        .iter()
        .filter_map(|z| {
            rhp_zero_bound_rad_s(*z, s_max).map(|b| ZeroBound {
                re_hz: hz(*z).re,
                im_hz: hz(*z).im,
                bound_rad_s: b,
            })
        })
        .collect();
    rhp_zeros.sort_by(|a, b| a.bound_rad_s.total_cmp(&b.bound_rad_s));
    let mut report = LimitReport {
        performance_bandwidth_rad_s: None,
        performance_bandwidth_sigma_rad_s: None,
        infeasible_above_rad_s: None,
        not_computed: None,
        s_max,
        rhp_zeros,
        binding: vec![],
        binds: String::new(),
        effort_max_a_per_m,
        band_edge_rad_s: None,
        lines: [0, 0],
        fit_stood_in_lines: 0,
        solves: 0,
        time_s: 0.0,
    };
    if let Some(why) = mass_line_refusal(frfs, plants) {
        report.not_computed = Some(format!("{why}; the design uses the search alone"));
        report.binds = "not computed".into();
        report.time_s = t0.elapsed().as_secs_f64();
        return report;
    }
    let lines = set.lines();
    report.lines = [
        set.measured.iter().map(|f| f.0.omega_rad_s.len()).sum(),
        set.models.iter().map(|m| m.1.len()).sum(),
    ];
    let basis = Basis::for_plant(&zeros, set.lowest_rad_s, period_s);
    // No controller passes the lowest zero bound (lines between the zeros
    // may let the search pass it by a little): the search starts there.
    let upper = report.rhp_zeros.first().map(|z| 1.05 * z.bound_rad_s);
    let bounds = set.bounds(effort_max_a_per_m);
    report.effort_max_a_per_m = effort_max_a_per_m;
    report.band_edge_rad_s = Some(bounds.band_edge_rad_s).filter(|w| w.is_finite());
    match performance_limit(&lines, basis, period_s, s_max, upper, bounds) {
        Ok(l) => {
            let w = l.performance_bandwidth_rad_s;
            report.performance_bandwidth_rad_s = Some(w);
            report.performance_bandwidth_sigma_rad_s = l.performance_bandwidth_sigma_rad_s;
            report.infeasible_above_rad_s = Some(l.infeasible_above_rad_s);
            report.solves = l.solves;
            report.fit_stood_in_lines = l.stand_in_lines;
            report.binds = what_binds(w, &report.rhp_zeros, &l, &bounds, period_s);
            report.binding = l.binding;
        }
        Err(e) => {
            report.not_computed = Some(format!("{e}; the design uses the search alone"));
            report.binds = "not computed".into();
        }
    }
    report.time_s = t0.elapsed().as_secs_f64();
    report
}

/// Every fit's zeros (rad/s, Im ≥ 0), once: zeros of several fits within
/// [`ZERO_MERGE`] of each other are one.
pub fn fit_zeros(plants: &[FittedPlant]) -> Vec<C64> {
    let mut zeros: Vec<C64> = Vec::new();
    for p in plants {
        for z in &p.fit().zeros {
            let s = C64::new(z.re_hz, z.im_hz.abs()) * (2.0 * PI);
            if s.is_finite() && !zeros.iter().any(|x| (x - s).norm() < ZERO_MERGE * s.norm()) {
                zeros.push(s);
            }
        }
    }
    zeros
}

/// The right-half-plane zeros of the fits `plants` (rad/s, Im ≥ 0); of
/// those of several fits within [`ZERO_MERGE`] of each other, the one
/// with the lowest bound at `M = s_max` ([`rhp_zero_bound_rad_s`]: the
/// one that holds a workspace's limit down). Apart from [`fit_zeros`],
/// which merges across the imaginary axis: a CMP-CNMP quartet's two
/// pairs (−2.3 ± 83.3j and +1.7 ± 83.3j Hz on the shipped bench at 8 % of
/// L) are 4.8 % apart, and there whichever came first stood for both (one
/// pole pair of Q serves them), so that the report listed no
/// right-half-plane zero.
pub fn rhp_fit_zeros(plants: &[FittedPlant], s_max: f64) -> Vec<C64> {
    let bound = |z: C64| rhp_zero_bound_rad_s(z, s_max).unwrap_or(f64::INFINITY);
    let mut zeros: Vec<C64> = Vec::new();
    for p in plants {
        for z in &p.fit().zeros {
            let s = C64::new(z.re_hz, z.im_hz.abs()) * (2.0 * PI);
            if !(s.is_finite() && s.re > 0.0) {
                continue;
            }
            match zeros
                .iter_mut()
                .find(|x| (**x - s).norm() < ZERO_MERGE * s.norm())
            {
                Some(x) if bound(s) < bound(*x) => *x = s,
                Some(_) => {}
                None => zeros.push(s),
            }
        }
    }
    zeros
}

/// A lightly damped pole of the fit and the left-half-plane zero next to
/// it (rad/s and ζ each): an MMP pair, which a controller may cancel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightPair {
    /// The mode: natural frequency (rad/s) and damping ratio.
    pub pole: (f64, f64),
    /// The zero: natural frequency (rad/s) and damping ratio.
    pub zero: (f64, f64),
}

/// The fits' MMP pairs: each left-half-plane zero damped less than
/// [`LIGHT_DAMPING`] with the nearest lightly damped mode within
/// [`ZERO_MERGE`] of it, each mode at most once; with several fits, the
/// first fit's pairs that every other fit has within [`ZERO_MERGE`], their
/// damping widened to cover the spread (the cancellation must hold on every
/// input). Right-half-plane zeros are never paired: a controller pole
/// there would be unstable.
pub fn light_pairs(plants: &[FittedPlant]) -> Vec<LightPair> {
    let pairs_of = |p: &FittedPlant| -> Vec<LightPair> {
        let mut used = vec![false; p.fit().modes.len()];
        let mut out: Vec<LightPair> = Vec::new();
        for z in &p.fit().zeros {
            let s = C64::new(z.re_hz, z.im_hz.abs()) * (2.0 * PI);
            let (wz, zz) = (s.norm(), -s.re / s.norm());
            // A zero listed with its conjugate is one.
            let listed = out.iter().any(|q| (q.zero.0 / wz - 1.0).abs() < 1e-9);
            if listed || !(wz.is_finite() && zz > 0.0 && zz < LIGHT_DAMPING) {
                continue;
            }
            let near = p
                .fit()
                .modes
                .iter()
                .enumerate()
                .filter(|(i, m)| {
                    !used[*i]
                        && m.damping_ratio > 0.0
                        && m.damping_ratio < LIGHT_DAMPING
                        && (2.0 * PI * m.frequency_hz / wz - 1.0).abs() < ZERO_MERGE
                })
                .min_by(|a, b| {
                    (a.1.frequency_hz - wz / (2.0 * PI))
                        .abs()
                        .total_cmp(&(b.1.frequency_hz - wz / (2.0 * PI)).abs())
                });
            if let Some((i, m)) = near {
                used[i] = true;
                out.push(LightPair {
                    pole: (2.0 * PI * m.frequency_hz, m.damping_ratio),
                    zero: (wz, zz),
                });
            }
        }
        out
    };
    let Some((first, rest)) = plants.split_first() else {
        return vec![];
    };
    let close = |a: (f64, f64), b: (f64, f64)| (a.0 / b.0 - 1.0).abs() < ZERO_MERGE;
    let others: Vec<Vec<LightPair>> = rest.iter().map(pairs_of).collect();
    pairs_of(first)
        .into_iter()
        .filter_map(|mut p| {
            for other in &others {
                let q = other
                    .iter()
                    .find(|q| close(p.pole, q.pole) && close(p.zero, q.zero))?;
                // A spread of δω covered by ζ ≥ δω/ω.
                p.pole.1 = p.pole.1.max((q.pole.0 - p.pole.0).abs() / p.pole.0);
                p.zero.1 = p.zero.1.max((q.zero.0 - p.zero.0).abs() / p.zero.0);
            }
            Some(p)
        })
        .collect()
}

/// Why the Youla form does not apply to these fits: the first whose mass
/// line (`L/s²`) is significant and more than [`MASS_LINE_SHARE_MAX`] of
/// its response at its lowest line (a free mass, not a stable plant).
pub fn mass_line_refusal(frfs: &[DesignFrf], plants: &[FittedPlant]) -> Option<String> {
    frfs.iter().zip(plants).find_map(|(f, p)| {
        let share = p.mass_line_share(f.omega_rad_s[0]);
        (share > MASS_LINE_SHARE_MAX).then(|| {
            format!(
                "the fit of {} has a mass line (L/s², {:.0} % of the response at its lowest line {:.2} Hz): a free mass is not a stable plant, and the Youla form needs one",
                f.label,
                100.0 * share,
                f.omega_rad_s[0] / (2.0 * PI)
            )
        })
    })
}

/// The lines of the limit's and a design's cone programs (see the module
/// docs), owned: each input's coherent lines thinned, with their 1σ and
/// the fit at each, and each fit's lines between and above them.
#[derive(Debug, Clone)]
pub struct ProgramLines {
    /// Per input: its thinned lines, their relative 1σ (NaN: unknown)
    /// and the fit at the same lines (m/A, the computation delay applied).
    pub measured: Vec<(DesignFrf, Vec<f64>, Vec<C64>)>,
    /// Per input: its fit's label, lines (rad/s) and response (m/A).
    pub models: Vec<(String, Vec<f64>, Vec<C64>)>,
    /// Per input: the fit's 1σ relative to its magnitude on the input's
    /// thinned lines, then on the fit's own lines (the fit's covariance;
    /// NaN: unknown), as `measured` and `models` hold them.
    pub fit_sigma: Vec<(Vec<f64>, Vec<f64>)>,
    /// The MMP pairs every fit has ([`light_pairs`]): the model lines
    /// sample them, and the `limit` strategy climbs each start with them
    /// cancelled too.
    pub pairs: Vec<LightPair>,
    /// The lowest measured line over the inputs, rad/s.
    pub lowest_rad_s: f64,
}

/// Where a fit's points go besides the measured lines (see the module
/// docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelPoints {
    /// In the measurement's gaps and above its band, and across every
    /// fitted mode and MMP pair: the limit's, and a climb's first set.
    AcrossModes,
    /// In the gaps and above the band only: a climb's second set (the
    /// climb is local, and its path on these lines is another; the
    /// certificate's dense grid of the fits judges the result either
    /// way).
    GapsOnly,
}

/// The two sets of lines a climb runs on, the same but for the fits'
/// points ([`ModelPoints`]): the `limit` strategy climbs each start on
/// both, and the certificate picks.
#[derive(Debug, Clone)]
pub struct ClimbLines {
    /// With the points across every mode ([`ModelPoints::AcrossModes`]).
    pub across_modes: ProgramLines,
    /// With the gaps' and above-band points only ([`ModelPoints::GapsOnly`]).
    pub gaps_only: ProgramLines,
}

impl ClimbLines {
    /// Both sets of [`program_lines`].
    pub fn new(
        frfs: &[DesignFrf],
        relative_sigma: &[Vec<f64>],
        plants: &[FittedPlant],
        period_and_delay_s: (f64, f64),
    ) -> Self {
        let set = |points| program_lines(frfs, relative_sigma, plants, period_and_delay_s, points);
        Self {
            across_modes: set(ModelPoints::AcrossModes),
            gaps_only: set(ModelPoints::GapsOnly),
        }
    }

    /// The set of `points`.
    pub fn of(&self, points: ModelPoints) -> &ProgramLines {
        match points {
            ModelPoints::AcrossModes => &self.across_modes,
            ModelPoints::GapsOnly => &self.gaps_only,
        }
    }
}

/// [`ProgramLines`] of `frfs` (the computation delay `delay_s` applied)
/// and their fits `plants` at the loop period `period_s`, the fits'
/// points placed as `points` says.
pub fn program_lines(
    frfs: &[DesignFrf],
    relative_sigma: &[Vec<f64>],
    plants: &[FittedPlant],
    (period_s, delay_s): (f64, f64),
    points: ModelPoints,
) -> ProgramLines {
    let pairs = light_pairs(plants);
    let models: Vec<(String, Vec<f64>, Vec<C64>)> = frfs
        .iter()
        .zip(plants)
        .map(|(f, p)| {
            let (w, h) = model_lines(f, p, &pairs, (period_s, delay_s), points);
            (format!("the fit of {}", f.label), w, h)
        })
        .collect();
    // Each input's lines thinned ([`LINES_PER_INPUT`]), with their noise
    // and the fit at each, to stand in where the line is noisy.
    let thinned: Vec<(DesignFrf, Vec<f64>, Vec<C64>)> = frfs
        .iter()
        .zip(plants)
        .zip(relative_sigma)
        .map(|((f, p), sigma)| {
            let n = f.omega_rad_s.len();
            let per_input = (LINES_TOTAL / frfs.len()).clamp(LINES_PER_INPUT_MIN, LINES_PER_INPUT);
            let every = n.div_ceil(per_input).max(1);
            let modes: Vec<f64> = p
                .fit()
                .modes
                .iter()
                .map(|m| 2.0 * PI * m.frequency_hz)
                .collect();
            let keep: Vec<usize> = (0..n)
                .filter(|&k| {
                    let w = f.omega_rad_s[k];
                    k % every == 0
                        || k + 1 == n
                        || modes.iter().any(|r| (w / r - 1.0).abs() <= 0.04)
                })
                .collect();
            let d = DesignFrf {
                label: f.label.clone(),
                omega_rad_s: keep.iter().map(|&k| f.omega_rad_s[k]).collect(),
                plant_m_per_a: keep.iter().map(|&k| f.plant_m_per_a[k]).collect(),
                lines_total: f.lines_total,
            };
            let s = keep
                .iter()
                .map(|&k| sigma.get(k).copied().unwrap_or(f64::NAN))
                .collect();
            let m = d
                .omega_rad_s
                .iter()
                .map(|&w| p.frf(w) * C64::from_polar(1.0, -w * delay_s))
                .collect();
            (d, s, m)
        })
        .collect();
    let lowest_rad_s = frfs
        .iter()
        .map(|f| f.omega_rad_s[0])
        .fold(f64::INFINITY, f64::min);
    let fit_sigma = thinned
        .iter()
        .zip(&models)
        .zip(plants)
        .map(|(((d, _, _), (_, w, _)), p)| {
            let at = |w: &[f64]| w.iter().map(|w| p.frf_relative_sigma(*w)).collect();
            (at(&d.omega_rad_s), at(w))
        })
        .collect();
    ProgramLines {
        measured: thinned,
        fit_sigma,
        models,
        pairs,
        lowest_rad_s,
    }
}

impl ProgramLines {
    /// The lowest of the inputs' highest coherent lines, rad/s (where the
    /// measurement of the narrowest input ends: the thinning keeps every
    /// input's last line).
    pub fn top_coherent_rad_s(&self) -> f64 {
        self.measured
            .iter()
            .filter_map(|m| m.0.omega_rad_s.last().copied())
            .fold(f64::INFINITY, f64::min)
    }

    /// The bounds the limit and a design keep on these lines: the effort
    /// `|K S| ≤ effort_max_a_per_m` (A/m, [`LoopBounds::effort_for_step`])
    /// and `|T| ≤` [`EDGE_T_MAX`] from [`EDGE_FRACTION`] of the lowest of
    /// the inputs' highest coherent lines up (|L| ≤ −10 dB where the
    /// measurement ends: no loop relies on the plant above it).
    pub fn bounds(&self, effort_max_a_per_m: f64) -> LoopBounds {
        LoopBounds {
            effort_max_a_per_m,
            band_edge_rad_s: EDGE_FRACTION * self.top_coherent_rad_s(),
            band_edge_t_max: EDGE_T_MAX,
        }
    }

    /// The lines as the cone program takes them: each input's, then each
    /// fit's.
    pub fn lines(&self) -> Vec<Lines<'_>> {
        let mut lines: Vec<Lines<'_>> = self
            .measured
            .iter()
            .zip(&self.fit_sigma)
            .map(|((f, sigma, m), (fs, _))| Lines {
                label: &f.label,
                omega_rad_s: &f.omega_rad_s,
                plant_m_per_a: &f.plant_m_per_a,
                relative_sigma: sigma,
                correlated: false,
                noise: Some(LineNoise {
                    model_m_per_a: m,
                    model_relative_sigma: fs,
                }),
            })
            .collect();
        lines.extend(
            self.models
                .iter()
                .zip(&self.fit_sigma)
                .filter(|(m, _)| !m.1.is_empty())
                .map(|((l, w, h), (_, fs))| Lines {
                    label: l,
                    omega_rad_s: w,
                    plant_m_per_a: h,
                    relative_sigma: fs,
                    correlated: true,
                    noise: None,
                }),
        );
        lines
    }
}

/// What binds the limit `w` (rad/s), in words: a right-half-plane zero
/// whose own bound is within 25 % of it, else the lines where `|W_P S|`
/// reaches 1, named by where they lie.
fn what_binds(
    w: f64,
    zeros: &[ZeroBound],
    limit: &super::limit::Limit,
    bounds: &LoopBounds,
    period_s: f64,
) -> String {
    let nyquist = PI / period_s;
    let binding = &limit.binding;
    let mut parts = Vec::new();
    if let Some(z) = zeros.first().filter(|z| z.bound_rad_s <= 1.25 * w) {
        parts.push(format!(
            "the right-half-plane zero pair {:.2} ± {:.2}j Hz (S = 1 there for every controller: ω* ≤ {:.0} rad/s on its own)",
            z.re_hz, z.im_hz, z.bound_rad_s
        ));
    }
    if let Some(at) = limit.effort_binds_at_rad_s {
        parts.push(format!(
            "the peak current (|K S| = {:.2} A/µm at {:.0} Hz: a setpoint step's edge takes the coil's peak current)",
            1e-6 * bounds.effort_max_a_per_m,
            at / (2.0 * PI)
        ));
    }
    if let Some(at) = limit.band_edge_binds_at_rad_s {
        parts.push(format!(
            "the band edge (|T| = {:.2} at {:.0} Hz: the loop may not rely on the plant above {:.0} Hz, where the measurement ends)",
            bounds.band_edge_t_max,
            at / (2.0 * PI),
            bounds.band_edge_rad_s / (2.0 * PI)
        ));
    }
    let high: Vec<&BindingLine> = binding
        .iter()
        .filter(|b| b.omega_rad_s > 0.25 * nyquist)
        .collect();
    if !high.is_empty() {
        parts.push(format!(
            "the delay and the amplifier (|W_P S| = 1 at {:.0} Hz, {:.0} % of the Nyquist frequency, where the loop's phase lag grows with frequency)",
            high[0].omega_rad_s / (2.0 * PI),
            100.0 * high[0].omega_rad_s / nyquist
        ));
    }
    let low: Vec<String> = binding
        .iter()
        .filter(|b| b.omega_rad_s <= 0.25 * nyquist)
        .take(3)
        .map(|b| format!("{:.1} Hz of {}", b.omega_rad_s / (2.0 * PI), b.input))
        .collect();
    if !low.is_empty() {
        parts.push(format!("the lines at {}", low.join(", ")));
    }
    parts.join("; ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::design::fitted::test_support::{fit, mode};
    use crate::ident::modal_fit::Path;

    const T: f64 = 2e-4;

    fn path() -> Path {
        Path {
            period_s: T,
            amplifier_bandwidth_hz: 1000.0,
        }
    }

    /// A bench of two modes measured exactly on 300 lines from 0.5 to
    /// 400 Hz, with the computation delay of one period.
    fn measured(f: &crate::ident::modal_fit::ModalFit) -> (DesignFrf, FittedPlant) {
        let plant = FittedPlant::new(f, path());
        let omega: Vec<f64> = (0..300)
            .map(|k| 2.0 * PI * 0.5 * (800.0f64).powf(k as f64 / 299.0))
            .collect();
        let p = omega
            .iter()
            .map(|&w| plant.frf(w) * C64::from_polar(1.0, -w * T))
            .collect();
        (
            DesignFrf {
                label: "bench.frf.csv".into(),
                omega_rad_s: omega,
                plant_m_per_a: p,
                lines_total: 300,
            },
            plant,
        )
    }

    /// [`bench_limit`] of one exactly measured input `frf` and its fit
    /// `plant` at the period and delay `T`, M = 2, on the lines of both
    /// with the relative 1σ `sigma` (one per line) and the effort bound
    /// `effort_a_per_m`.
    fn limit_of(
        frf: &DesignFrf,
        plant: &FittedPlant,
        sigma: Vec<f64>,
        effort_a_per_m: f64,
    ) -> LimitReport {
        let (frfs, plants) = (std::slice::from_ref(frf), std::slice::from_ref(plant));
        let set = program_lines(frfs, &[sigma], plants, (T, T), ModelPoints::AcrossModes);
        bench_limit(frfs, plants, &set, T, 2.0, effort_a_per_m)
    }

    /// The limit of a two-mode bench (25 and 80 Hz) measured exactly
    /// ([`measured`]), with its lines' relative 1σ `sigma` (one value for
    /// all 300) and the effort bound `effort_a_per_m`; the plant too.
    fn two_mode_limit(sigma: f64, effort_a_per_m: f64) -> (LimitReport, FittedPlant) {
        let f = fit(
            vec![mode(25.0, 0.01, 10.0), mode(80.0, 0.004, 3.0)],
            0.0,
            0.5 * T,
        );
        let (frf, plant) = measured(&f);
        let r = limit_of(&frf, &plant, vec![sigma; 300], effort_a_per_m);
        (r, plant)
    }

    /// A fit with a significant mass line (L/s²) is a free mass: no limit,
    /// and the report says why, naming the input; without it the limit is
    /// computed, and a right-half-plane zero the fit lists is reported with
    /// its maximum-modulus bound (Skogestad & Postlethwaite Eq. 5.49).
    #[test]
    fn a_free_mass_has_no_limit_and_each_listed_rhp_zero_has_its_bound() {
        let mut f = fit(
            vec![mode(25.0, 0.01, 10.0), mode(80.0, 0.004, -3.0)],
            0.0,
            0.5 * T,
        );
        f.lower_residual = 2.0;
        f.lower_residual_sigma = 0.01;
        let (frf, plant) = measured(&f);
        let sigma = vec![f64::NAN; 300];
        let r = limit_of(&frf, &plant, sigma.clone(), f64::INFINITY);
        assert_eq!(r.performance_bandwidth_rad_s, None);
        let why = r.not_computed.unwrap();
        assert!(
            why.contains("mass line") && why.contains("bench.frf.csv"),
            "{why}"
        );

        let mut f = fit(
            vec![mode(25.0, 0.01, 10.0), mode(80.0, 0.004, -3.0)],
            0.0,
            0.5 * T,
        );
        let z = C64::new(2.0, 83.0);
        f.zeros = vec![zero_at(z)];
        let (frf, plant) = measured(&f);
        let r = limit_of(&frf, &plant, sigma.clone(), f64::INFINITY);
        let bound = super::super::limit::rhp_zero_bound_rad_s(z * (2.0 * PI), 2.0).unwrap();
        assert_eq!(r.rhp_zeros.len(), 1);
        assert!((r.rhp_zeros[0].bound_rad_s - bound).abs() < 1e-9 * bound);
        let w = r.performance_bandwidth_rad_s.expect("a limit");
        assert!(w > 0.0, "{r:?}");
        // These two modes have no RHP zero of their own: the listed pair
        // only places Q's poles, and the lines decide.
        assert!(r.lines[1] > 0, "no fitted lines above the band: {r:?}");
    }

    /// The effort bound holds the limit's Q on every line and lowers the
    /// limit when it binds, and the report says so; with a bound far
    /// above what the limit needs it changes nothing.
    #[test]
    fn the_peak_current_bounds_the_limit_when_it_binds() {
        let run = |effort: f64| two_mode_limit(0.0, effort).0;
        let (free, plant) = two_mode_limit(0.0, f64::INFINITY);
        let w_free = free.performance_bandwidth_rad_s.unwrap();
        let loose = run(1e12);
        let w_loose = loose.performance_bandwidth_rad_s.unwrap();
        assert!(
            (w_loose / w_free - 1.0).abs() < 0.02,
            "{w_loose} vs {w_free}"
        );
        assert!(!loose.binds.contains("peak current"), "{}", loose.binds);
        // |K S| at the free limit's crossover is about 1/|P| there: a
        // tenth of the plant's inverse at the free limit binds.
        let p_at = plant.frf(w_free).norm();
        let tight = run(0.1 / p_at);
        let w_tight = tight.performance_bandwidth_rad_s.unwrap();
        assert!(w_tight < 0.9 * w_free, "{w_tight} vs {w_free}");
        assert!(tight.binds.contains("peak current"), "{}", tight.binds);
        assert_eq!(tight.effort_max_a_per_m, 0.1 / p_at);
    }

    /// Where the lines' noise is larger than the bound the weight sets on
    /// |S| (the lowest lines, |S| ≈ ω/ω*), the fit stands in; noise-free
    /// lines never need it.
    #[test]
    fn noisy_low_lines_are_replaced_by_the_fit() {
        let run = |sigma: f64| two_mode_limit(sigma, f64::INFINITY).0;
        let (q, n) = (run(0.0), run(1e-2));
        assert_eq!(q.fit_stood_in_lines, 0);
        assert!(n.fit_stood_in_lines > 0, "{n:?}");
        // The lines are exact here, so the fit standing in for them
        // changes the limit by no more than the search's tolerance.
        let (a, b) = (
            q.performance_bandwidth_rad_s.unwrap(),
            n.performance_bandwidth_rad_s.unwrap(),
        );
        assert!((a / b - 1.0).abs() < 0.02, "{a} vs {b}");
    }

    /// The zeros of `A₁/(s² + 2ζ₁ω₁s + ω₁²) + A₂/(s² + 2ζ₂ω₂s + ω₂²)`
    /// (the numerator's roots, analytic), Hz, Im > 0.
    fn two_mode_zero_hz(m: [(f64, f64, f64); 2]) -> C64 {
        let [(f1, z1, a1), (f2, z2, a2)] = m;
        let (w1, w2) = (2.0 * PI * f1, 2.0 * PI * f2);
        let a = a1 + a2;
        let b = 2.0 * (a1 * z2 * w2 + a2 * z1 * w1);
        let c = a1 * w2 * w2 + a2 * w1 * w1;
        let disc = C64::new(b * b - 4.0 * a * c, 0.0).sqrt();
        let s = (-b + disc) / (2.0 * a);
        let s = if s.im < 0.0 { s.conj() } else { s };
        s / (2.0 * PI)
    }

    /// Modes at 25 Hz (ζ 1 %) and 80 Hz (ζ 0.4 %) with the zero the two
    /// make (an MMP pair with the 80 Hz mode), measured exactly: the
    /// input, its fit, and the zero (Hz, s/2π).
    fn mmp_pair_bench() -> (DesignFrf, FittedPlant, C64) {
        let m = [(25.0, 0.01, 10.0), (80.0, 0.004, 1.0)];
        let mut f = fit(
            m.iter().map(|&(h, z, a)| mode(h, z, a)).collect(),
            0.0,
            0.5 * T,
        );
        let zero = two_mode_zero_hz(m);
        f.zeros = vec![zero_at(zero)];
        let (frf, plant) = measured(&f);
        (frf, plant, zero)
    }

    /// An MMP pair narrower than the measured lines' spacing (ζ = 0.4 %:
    /// a half-power half-width of 0.32 Hz at 80 Hz and of 0.31 Hz at its
    /// zero near 76.6 Hz, where the lines are 1.7 Hz apart) is sampled by
    /// the fit's lines: the largest |P| over the program's lines is the
    /// fit's peak, the smallest its dip, each within 0.3 dB (a point
    /// within a quarter of the half-width: 0.26 dB; found on a grid of
    /// 10⁻⁵ relative spacing). Without the pair's points the dip was
    /// 0.71 dB off (the peak, which the modes' seven points cover, 0.03).
    #[test]
    fn the_programs_lines_see_an_mmp_pair_between_lines() {
        let (frf, plant, zero) = mmp_pair_bench();
        assert!(zero.re < 0.0 && zero.im > 76.0 && zero.im < 77.0, "{zero}");
        let set = program_lines(
            std::slice::from_ref(&frf),
            &[vec![f64::NAN; 300]],
            std::slice::from_ref(&plant),
            (T, T),
            ModelPoints::AcrossModes,
        );
        let seen: Vec<(f64, f64)> = set.measured[0]
            .0
            .omega_rad_s
            .iter()
            .zip(&set.measured[0].0.plant_m_per_a)
            .chain(set.models[0].1.iter().zip(&set.models[0].2))
            .map(|(w, p)| (*w, p.norm()))
            .collect();
        let db = |x: f64| 20.0 * x.log10();
        for (centre_hz, peak) in [(80.0, true), (zero.norm(), false)] {
            let w0 = 2.0 * PI * centre_hz;
            let (lo, hi) = (0.97 * w0, 1.03 * w0);
            let fine =
                (0..=6000).map(|k| plant.frf(lo * (hi / lo).powf(f64::from(k) / 6000.0)).norm());
            let on_lines = seen
                .iter()
                .filter(|(w, _)| *w >= lo && *w <= hi)
                .map(|(_, p)| *p);
            let (truth, sampled) = if peak {
                (fine.fold(0.0, f64::max), on_lines.fold(0.0, f64::max))
            } else {
                (
                    fine.fold(f64::INFINITY, f64::min),
                    on_lines.fold(f64::INFINITY, f64::min),
                )
            };
            let off = (db(sampled) - db(truth)).abs();
            assert!(
                off <= 0.3,
                "{} at {centre_hz:.2} Hz: {off:.2} dB off on the program's lines",
                if peak { "peak" } else { "dip" }
            );
        }
    }

    /// The climb's two sets of lines ([`ClimbLines`]) hold the same
    /// measured lines and MMP pairs; the gaps-only set's fit points are
    /// the across-modes set's less those across the modes: within ±4
    /// half-widths of the 80 Hz mode (ζ = 0.4 %, 0.32 Hz) the across-modes
    /// set has at least 8 more.
    #[test]
    fn the_two_sets_differ_only_by_the_points_across_the_modes() {
        let (frf, plant, _) = mmp_pair_bench();
        let sets = ClimbLines::new(
            std::slice::from_ref(&frf),
            &[vec![f64::NAN; 300]],
            std::slice::from_ref(&plant),
            (T, T),
        );
        let (across, gaps) = (
            sets.of(ModelPoints::AcrossModes),
            sets.of(ModelPoints::GapsOnly),
        );
        assert_eq!(
            across.measured[0].0.omega_rad_s,
            gaps.measured[0].0.omega_rad_s
        );
        assert_eq!(across.pairs, gaps.pairs);
        assert!(!across.pairs.is_empty());
        let half_width = 0.004 * 2.0 * PI * 80.0;
        let near = |w: &[f64]| {
            w.iter()
                .filter(|x| (**x - 2.0 * PI * 80.0).abs() <= 4.0 * half_width)
                .count()
        };
        // The gaps' own log-grid points (the lines are 2.1 % apart there,
        // wider than GAP_RATIO) are in both; the modes' are not.
        let (a, g) = (near(&across.models[0].1), near(&gaps.models[0].1));
        assert!(
            a >= g + 8,
            "across the modes {a} points near 80 Hz, gaps only {g}"
        );
        assert!(gaps.models[0]
            .1
            .iter()
            .all(|w| across.models[0].1.contains(w)));
        assert!(gaps.models[0].1.len() < across.models[0].1.len());
    }

    /// A fitted zero at `hz` (s/2π); its type is not read here.
    fn zero_at(hz: C64) -> crate::ident::modal_fit::FittedZero {
        crate::ident::modal_fit::FittedZero {
            re_hz: hz.re,
            im_hz: hz.im,
            kind: String::new(),
        }
    }

    /// Each lightly damped left-half-plane zero is paired with its mode
    /// (held-out b's pairs: 74.05/75.55 Hz and 83.60/82.53 Hz); a
    /// right-half-plane zero, a well damped zero and a zero with no mode
    /// within 5 % are not; a zero listed with its conjugate is one. With
    /// two fits, a pair both have is kept with its damping widened to the
    /// spread (1 % apart: ζ ≥ 0.01), one only the first has is not.
    #[test]
    fn mmp_pairs_are_the_lightly_damped_lhp_zeros_with_their_modes() {
        let modes = || {
            vec![
                mode(29.6, 0.009, 5.4),
                mode(74.05, 0.0042, -0.23),
                mode(83.6, 0.0039, 0.13),
            ]
        };
        let hz = |wn: f64, zeta: f64| C64::new(-zeta * wn, wn * (1.0 - zeta * zeta).sqrt());
        let mut f = fit(modes(), 0.0, 0.5 * T);
        f.zeros = vec![
            zero_at(hz(75.55, 0.0041)),
            zero_at(hz(75.55, 0.0041).conj()),
            zero_at(hz(82.53, 0.0039)),
            zero_at(C64::new(1.7, 40.0)),
            zero_at(hz(120.0, 0.003)),
            zero_at(hz(30.0, 0.2)),
        ];
        let p = FittedPlant::new(&f, path());
        let pairs = light_pairs(std::slice::from_ref(&p));
        assert_eq!(pairs.len(), 2, "{pairs:?}");
        let close = |a: f64, b: f64| (a / b - 1.0).abs() < 1e-9;
        let w = |f: f64| 2.0 * PI * f;
        let mut pairs = pairs;
        pairs.sort_by(|a, b| a.pole.0.total_cmp(&b.pole.0));
        assert!(close(pairs[0].pole.0, w(74.05)) && close(pairs[0].zero.0, w(75.55)));
        assert!(close(pairs[1].pole.0, w(83.6)) && close(pairs[1].zero.0, w(82.53)));
        assert!(close(pairs[0].zero.1, 0.0041) && close(pairs[1].pole.1, 0.0039));

        let mut g = fit(modes(), 0.0, 0.5 * T);
        for m in &mut g.modes {
            m.frequency_hz *= 1.01;
        }
        g.zeros = vec![zero_at(hz(75.55 * 1.01, 0.0041))];
        let q = FittedPlant::new(&g, path());
        let both = light_pairs(&[p, q]);
        assert_eq!(both.len(), 1, "{both:?}");
        assert!(close(both[0].pole.0, w(74.05)));
        assert!(
            both[0].pole.1 >= 0.0099 && both[0].zero.1 >= 0.0099,
            "{both:?}"
        );
    }
}
