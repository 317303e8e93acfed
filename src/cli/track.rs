//! `bench track`: its flags and the printed trials.

use super::serve::via_daemon_then;
use super::{bad_input, emit, job_thread, load_config, refuse_local_only, run_failed_json};
use bench::error::RunError;
use bench::jobs::request::{parse_seed, JobRequest, SnapLimit, TrackRequest};
use bench::jobs::track::{run_track, TrackSummary};
use bench::jobs::track_request::TrackRunner;
use bench::rt::backend::BackendSpec;
use bench::track::{FeedforwardKind, ScanKind};
use clap::Args;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

#[derive(Debug, Args)]
#[command(
    mut_arg("out", |a| a.value_name("DIR").help("Output directory: one recording per trial, track.json, feedforward.csv [default: track-<controller>-<UTC time> in ./recordings if it exists, else in $XDG_DATA_HOME/bench/recordings]")),
)]
#[command(group(clap::ArgGroup::new("which").args(["slow", "fast", "controller"])))]
pub(super) struct TrackArgs {
    /// The slow controller of Eq. (6-6) (`[controller.slow]`).
    #[arg(long)]
    slow: bool,
    /// The fast controller of Eq. (6-7) (`[controller.fast]`) [the default].
    #[arg(long)]
    fast: bool,
    /// Any `[controller.NAME]` of the config.
    #[arg(long, value_name = "NAME")]
    controller: Option<String>,
    #[command(flatten)]
    config: super::ConfigFlag,
    /// The model the feedforward and the learning filter are computed on:
    /// a bench config whose [plant] is the bench as measured (`bench fit
    /// --update` writes one) [default: the [plant] of --config]. The loop,
    /// limits and backend stay --config's.
    #[arg(long, value_name = "FILE")]
    model: Option<std::path::PathBuf>,
    /// Replay a learned feedforward (the feedforward.csv of an earlier
    /// run) in place of the model-inverse one; learning goes on from it.
    /// Refused when it was learned with another loop rate, amplifier,
    /// controller, line or scan.
    #[arg(long, value_name = "FILE.csv")]
    feedforward: Option<std::path::PathBuf>,
    /// Learn with the process sensitivity PS measured on this loop: the
    /// recording of `bench control --verify` with the same controller,
    /// loop rate, amplifier, bench and kind of backend. L inverts the
    /// measured PS, and a harmonic is learned only where |1 − L·PS| stays
    /// below 1 at the measurement's 2σ (the convergence margin is
    /// reported) [default: the model's PS]. Refused when measured on
    /// another loop.
    #[arg(long, value_name = "FILE.mcap")]
    learning_ps: Option<std::path::PathBuf>,
    /// The scan: triangle (a raster line, smoothed below the cut-off),
    /// sine, move (point to point: up by the amplitude at the line's
    /// start, back at its middle, each with a 3rd- or 4th-order profile
    /// within the --max-* limits and a dwell after it), or csv (the line
    /// of --reference, played whole) [default: trajectory.scan of the
    /// config, else triangle].
    #[arg(long, value_name = "KIND")]
    scan: Option<ScanKind>,
    /// With --scan csv: the reference line, a CSV of one row per tick
    /// (header time_s,position_m; time_s = i / loop.rate_hz; position_m
    /// about the start position, m). Its rows make the line: the line rate
    /// is loop.rate_hz / rows. Range: at least 8 rows, finite positions
    /// within safety.position_limit_m, its predicted current within the
    /// actuator's peak and continuous currents.
    #[arg(long, value_name = "FILE.csv")]
    reference: Option<std::path::PathBuf>,
    /// Amplitude about the start position (a move's distance), m
    /// [default: 5e-6; with --scan csv, the reference's own, not to be
    /// given]. Range: above 0, the scan within safety.position_limit_m and
    /// its predicted current within the actuator's peak and continuous
    /// currents.
    #[arg(long, value_name = "M", allow_hyphen_values = true)]
    amplitude_m: Option<f64>,
    /// Lines per second, Hz [default: 10; with --scan csv, loop.rate_hz /
    /// the reference's rows, and given only to state it]. Range: a line of
    /// a whole number of ticks (at least 8), its fundamental below the
    /// band of the plant's lowest zero.
    #[arg(long, value_name = "HZ", allow_hyphen_values = true)]
    line_rate_hz: Option<f64>,
    /// Remove the scan's harmonics at or above this frequency, Hz
    /// [default: the lower edge of the lowest zero's band; for a move,
    /// whose reference is played whole, the feedforward's and learning's
    /// top, 4× the highest zero band's upper edge]. Range: above the line
    /// rate, at most the Nyquist frequency.
    #[arg(long, value_name = "HZ", allow_hyphen_values = true)]
    cutoff_hz: Option<f64>,
    /// The feedforward trial's feedforward: inverse (the model's inverse
    /// on every kept harmonic: stable inversion with a line of preview) or
    /// snap (position to snap feedforward, its gains the Taylor series of
    /// the model's 1/P at 0 Hz: right only well below the plant's lowest
    /// zero). Learning starts from it.
    #[arg(long, value_name = "KIND", default_value = "inverse")]
    feedforward_kind: FeedforwardKind,
    /// A move's peak velocity, m/s [default: trajectory.max_velocity_m_s
    /// of the config, else 1e-3]. Range: above 0, at most 2
    /// safety.position_limit_m × loop.rate_hz (the stroke in one tick);
    /// the move (the sum of its phases) at most a quarter of the line.
    #[arg(long, value_name = "M/S", allow_hyphen_values = true)]
    max_velocity_m_s: Option<f64>,
    /// A move's peak acceleration, m/s² [default: the config's
    /// trajectory.max_acceleration_m_s2, else 0.1]. Range: above 0, at
    /// most 2 safety.position_limit_m × loop.rate_hz².
    #[arg(long, value_name = "M/S2", allow_hyphen_values = true)]
    max_acceleration_m_s2: Option<f64>,
    /// A move's peak jerk, m/s³ [default: the config's
    /// trajectory.max_jerk_m_s3, else 40]. Range: above 0, at most 2
    /// safety.position_limit_m × loop.rate_hz³.
    #[arg(long, value_name = "M/S3", allow_hyphen_values = true)]
    max_jerk_m_s3: Option<f64>,
    /// A move's peak snap, m/s⁴: a 4th-order profile; `none`: a 3rd-order
    /// profile (the jerk steps) [default: the config's
    /// trajectory.max_snap_m_s4, else 2e4]. Range: above 0, at most 2
    /// safety.position_limit_m × loop.rate_hz⁴.
    #[arg(long, value_name = "M/S4", allow_hyphen_values = true, value_parser = SnapLimit::parse)]
    max_snap_m_s4: Option<SnapLimit>,
    /// The band a move settles into, ± m [default: the config's
    /// trajectory.settle_band_m, else 1e-8]. Range: above 0, below the
    /// move's distance.
    #[arg(long, value_name = "M", allow_hyphen_values = true)]
    settle_band_m: Option<f64>,
    /// Learning trials at most (after the standstill, feedback and
    /// feedforward trials). Range: 1 to 100.
    #[arg(
        long,
        value_name = "N",
        default_value_t = 10,
        allow_hyphen_values = true
    )]
    trials: u32,
    /// The learning gain α: the share of the last trial's error learned.
    /// Range: (0, 1].
    #[arg(
        long,
        value_name = "ALPHA",
        default_value_t = 0.7,
        allow_hyphen_values = true
    )]
    learning_gain: f64,
    /// Measured lines per trial (after the warm-up lines: five of the
    /// loop's slowest time constants, two at least). Range: 1 to
    /// 1000.
    #[arg(
        long,
        value_name = "N",
        default_value_t = 5,
        allow_hyphen_values = true
    )]
    periods: u32,
    #[command(flatten)]
    out: super::OutFlag,
    /// Pace the loop in real time.
    #[arg(long)]
    realtime: bool,
    /// Simulator noise seed [default: sim.seed].
    #[arg(long, value_name = "N", allow_hyphen_values = true, value_parser = parse_seed)]
    seed: Option<u64>,
    /// Backend: sim, serial:PATH, socketcan:IFACE or ethercat:IFACE
    /// [default: [backend] of the config]. Hardware always runs in real
    /// time.
    #[arg(long, value_name = "BACKEND")]
    backend: Option<BackendSpec>,
    /// Inject a simulator fault: KIND@T_S with KIND one of nan, frozen,
    /// drop (10 samples), jump (0.2 mm), out_of_range, dead, blind,
    /// stall:MS, and T_S the loop time from the first trial's start, s
    /// (the trials run back to back); e.g. nan@3.
    #[arg(long, value_name = "KIND@T_S")]
    inject_fault: Option<String>,
    #[command(flatten)]
    job: super::JobFlags,
    #[command(flatten)]
    outputs: super::OutputFlags,
}

impl TrackArgs {
    fn controller(&self) -> String {
        if self.slow {
            "slow".to_string()
        } else {
            self.controller
                .clone()
                .unwrap_or_else(|| "fast".to_string())
        }
    }

    /// The request the flags make (paths absolute: the daemon's working
    /// directory is not this one's).
    fn request(&self) -> TrackRequest {
        let abs = |p: &Option<PathBuf>| p.as_deref().map(super::absolute_path);
        TrackRequest {
            controller: Some(self.controller()),
            model: abs(&self.model),
            feedforward: abs(&self.feedforward),
            learning_ps: abs(&self.learning_ps),
            scan: self.scan,
            reference: abs(&self.reference),
            amplitude_m: self.amplitude_m,
            line_rate_hz: self.line_rate_hz,
            cutoff_hz: self.cutoff_hz,
            feedforward_kind: Some(self.feedforward_kind),
            max_velocity_m_s: self.max_velocity_m_s,
            max_acceleration_m_s2: self.max_acceleration_m_s2,
            max_jerk_m_s3: self.max_jerk_m_s3,
            max_snap_m_s4: self.max_snap_m_s4,
            settle_band_m: self.settle_band_m,
            trials: Some(self.trials),
            learning_gain: Some(self.learning_gain),
            periods: Some(self.periods),
            seed: self.seed,
            inject_fault: self.inject_fault.clone(),
            pace: None,
        }
    }
}

pub(super) fn track(args: TrackArgs, stop: Arc<AtomicBool>) -> ExitCode {
    let request = args.request();
    if let Some(sock) = &args.job.daemon {
        let local_only = [
            (
                args.config.config.is_some(),
                "--config (the daemon runs the bench config it was started with: bench serve --config)",
            ),
            (args.out.out.is_some(), "--out"),
            (args.outputs.overwrite, "--overwrite"),
            (args.backend.is_some(), "--backend"),
            (
                args.realtime,
                "--realtime (the daemon's jobs run in real time unless bench serve --pace says otherwise)",
            ),
        ];
        if let Some(code) = refuse_local_only(
            &local_only,
            "run it locally, or let the daemon choose the directory",
        ) {
            return code;
        }
        return via_daemon_then(
            sock,
            &JobRequest::Track(request),
            args.job.json.json,
            print_track_summary,
            |_| None,
        );
    }
    let (cfg, config_path) = match load_config(args.config.config.as_deref()) {
        Ok(c) => c,
        Err(e) => return bad_input(e),
    };
    let controller = request.controller();
    let out_dir = match &args.out.out {
        Some(d) => d.clone(),
        None => match super::default_recordings(true, "--out") {
            Ok(d) => d.join(format!("track-{controller}-{}", bench::outputs::stamp())),
            Err(e) => return bad_input(e),
        },
    };
    // An error about a field the config's [trajectory] gave names it so.
    let (named_cfg, named_path) = (cfg.clone(), config_path.clone());
    let name_of = |key: &str| request.name_of(&named_cfg, &named_path, key, super::option_flag);
    let runner = TrackRunner {
        seed: cfg.sim.seed,
        config: (cfg, config_path),
        out_dir,
        backend: args.backend.clone(),
        realtime: args.realtime,
        pace: None,
        overwrite: args.outputs.overwrite,
    };
    let opts = match request.options(runner) {
        Ok(o) => o,
        Err(e) => return failed(&e, args.job.json.json, name_of),
    };
    let opts_named = opts.clone();
    let result = job_thread::run_job(stop, move |stop, _ticks| run_track(&opts, stop));
    let result = match result {
        Ok(r) => r,
        Err(code) => return code,
    };
    match result {
        Ok(summary) => match emit(&summary, args.job.json.json, print_track_summary) {
            Ok(()) => ExitCode::SUCCESS,
            Err(code) => code,
        },
        Err(e) => failed(&e, args.job.json.json, |key| {
            opts_named.name_of(key, super::option_flag)
        }),
    }
}

/// A run's error as every command prints it, a bad option named by
/// `name_of` (a flag, or a key of the config's `[trajectory]`).
fn failed(e: &RunError, json: bool, name_of: impl FnOnce(&str) -> String) -> ExitCode {
    match e {
        RunError::BadOption { key, .. } => {
            let key: &str = key;
            errln!(
                "error: {}",
                e.option_message(|_| name_of(key)).unwrap_or_default()
            );
            ExitCode::from(bench::error::exit::BAD_INPUT)
        }
        e => run_failed_json(e, json),
    }
}

fn nm(m: f64) -> String {
    if m.is_finite() {
        format!("{:.1} nm", m * 1e9)
    } else {
        "n/a".to_string()
    }
}

fn print_track_summary(s: &TrackSummary) {
    let p = &s.plan;
    outln!(
        "bench track --controller {} on {} (seed {}): {}, {} ticks a line, harmonics below {:.1} Hz (the {} kept)",
        s.controller,
        s.backend,
        s.seed,
        p.scan.describe(),
        p.period_ticks,
        p.scan.cutoff_hz,
        p.harmonics
    );
    if let (Some(m), Some(band)) = (&p.move_profile, p.settle_band_m) {
        let pk = m.peaks();
        outln!(
            "  move: {:.2} µm in {:.2} ms (peaks {:.3e} m/s, {:.3e} m/s², {:.3e} m/s³{}), settling into ±{:.1} nm",
            m.distance_m * 1e6,
            m.duration_s() * 1e3,
            pk[0],
            pk[1],
            pk[2],
            if pk[3].is_finite() { format!(", {:.3e} m/s⁴", pk[3]) } else { String::new() },
            band * 1e9
        );
        if let Some(c) = p.move_in_zero_bands_m {
            let flag = if c > band { "warning: " } else { "" };
            outln!(
                "  {flag}{:.2} nm of the move lies in the right-half-plane zeros' bands (no loop tracks it, only the feedforward)",
                c * 1e9
            );
        }
        if let Some(l) = &p.smoother_move {
            let d = bench::track::MoveProfile::plan(m.distance_m, l).duration_s();
            outln!(
                "  smoother: {} (a move of {:.2} ms) keeps it within the band",
                l.flags(),
                d * 1e3
            );
        }
    }
    for b in &p.zero_bands {
        outln!(
            "  {} zero at {:.1} Hz closes {:.1}–{:.1} Hz",
            b.kind,
            b.zero_hz,
            b.low_hz,
            b.high_hz
        );
    }
    for (k, f) in &p.harmonics_removed {
        outln!("  smoothing removed harmonic {k} ({f:.1} Hz): it lies in a zero's band");
    }
    let in_bands = if p.move_profile.is_some() {
        &[][..]
    } else {
        &p.harmonics_in_zero_bands[..]
    };
    let fix = if p.scan.played_whole() {
        "only the feedforward does; smooth the reference to remove it"
    } else {
        "the default cut-off removes it"
    };
    for (k, f) in in_bands {
        outln!(
            "  warning: harmonic {k} ({f:.1} Hz) lies in a zero's band: no loop tracks it; {fix}"
        );
    }
    outln!("  model: the [plant] of {}", p.model.display());
    if let Some(g) = &p.derivative_gains {
        let c = g.gains;
        outln!(
            "  snap feedforward (1/P's Taylor series, fitted {:.2}–{:.2} Hz): {:.4e} A/m, {:.4e} A·s/m, {:.4e} A·s²/m, {:.4e} A·s³/m, {:.4e} A·s⁴/m",
            g.fitted_hz.0,
            g.fitted_hz.1,
            c[0],
            c[1],
            c[2],
            c[3],
            c[4]
        );
    }
    print_learning_checks(p);
    outln!(
        "  predicted: feedback alone {} RMS error; with the feedforward {:.2} A peak, {:.2} A RMS; learning contracts the error by {:.3} a trial (α {})",
        nm(p.predicted_feedback_rms_error_m),
        p.predicted_peak_current_a,
        p.predicted_rms_current_a,
        p.model_contraction,
        p.learning_gain
    );
    if let Some(still) = s.trials.first() {
        if s.floor_is_quantization() {
            outln!(
                "  noise floor {}: the reading's quantisation q/√12, above the standstill's {} (a still reading stays on one code; a scan crosses them)",
                nm(s.noise_floor_m),
                nm(still.rms_error_m)
            );
        } else {
            outln!(
                "  noise floor {} ± {}: the standstill's RMS error (the reading's quantisation q/√12 is {})",
                nm(s.noise_floor_m),
                nm(s.noise_floor_sigma_m),
                nm(s.quantization_floor_m)
            );
        }
    }
    for t in &s.trials {
        outln!(
            "  {:<12} RMS error {:>10} ± {:>6} ({:>6.2} ± {:.2}× the noise floor), peak {:>10}, feedforward {:.3} A RMS",
            t.name,
            nm(t.rms_error_m),
            nm(t.rms_error_sigma_m),
            t.of_noise_floor,
            t.of_noise_floor_sigma,
            nm(t.peak_error_m),
            t.feedforward_rms_a
        );
        if let (Some(noise), Some(band)) = (t.settle_noise_sigma_m, p.settle_band_m) {
            let time = t
                .settle_time_s
                .map_or("not settled before the next move".to_string(), |v| {
                    format!("settles in {:.2} ms", v * 1e3)
                });
            let flag = if t.settle_trusted == Some(true) {
                ""
            } else {
                " (untrusted: the band is under 4σ of the averaged error's noise: more --periods)"
            };
            outln!(
                "  {:<12} {time} (±{:.1} nm; averaged error's noise {} 1σ){flag}",
                "",
                band * 1e9,
                nm(noise)
            );
        }
    }
    if let Some(x) = s.settle_speedup {
        outln!("  the move settles {x:.1}× sooner with the feedforward than with feedback alone");
    }
    if let (Some(best), Some(imp), Some(stop)) = (&s.best_trial, s.improvement, &s.stop) {
        let sigma = s.improvement_sigma.unwrap_or(f64::NAN);
        outln!(
            "  best: {best}, {imp:.1} ± {sigma:.1}× lower RMS error than feedback alone; learning stopped: {stop}"
        );
    }
    outln!("  (± 1σ from the scatter between the measured lines; n/a with one line)");
    if let Some(csv) = &s.feedforward_csv {
        outln!("  feedforward: {}", csv.display());
    }
}

/// The learning filter's check against a measured PS: each harmonic's
/// contraction bound at 2σ, the measured and the model's, and the margin.
fn print_learning_checks(p: &bench::jobs::track::TrackPlan) {
    let Some(ps) = &p.learning_ps else {
        return;
    };
    outln!(
        "  learning filter: L = α/PS measured in {} (|1 − L·PS| at 2σ; the model's L beside it)",
        ps.display()
    );
    let bound = |b: Option<f64>| b.map_or("n/a".to_string(), |b| format!("{b:.3}"));
    let why = |c: &bench::track::measured::HarmonicCheck| match (c.learned, c.contraction_bound) {
        (true, _) => "learned",
        (false, None) => "not learned: no coherent measured line",
        (false, Some(b)) if b >= 1.0 => "not learned: the measurement cannot vouch for it",
        (false, Some(_)) => "not learned: in a zero's band",
    };
    // Every harmonic of a short scan; of a long one, the learned harmonics
    // with the largest bounds and a count of the rest by reason.
    let mut shown: Vec<&bench::track::measured::HarmonicCheck> = p.learning_checks.iter().collect();
    if shown.len() > 12 {
        shown.retain(|c| c.learned);
        shown.sort_by(|a, b| {
            b.contraction_bound
                .partial_cmp(&a.contraction_bound)
                .unwrap_or(std::cmp::Ordering::Equal)
        });
        shown.truncate(5);
        shown.sort_by_key(|c| c.harmonic);
    }
    for c in &shown {
        outln!(
            "    harmonic {:>3} ({:>7.1} Hz): measured {}, model's L {}: {}",
            c.harmonic,
            c.frequency_hz,
            bound(c.contraction_bound),
            bound(c.model_contraction_bound),
            why(c)
        );
    }
    if shown.len() < p.learning_checks.len() {
        let mut counts = std::collections::BTreeMap::new();
        for c in &p.learning_checks {
            *counts.entry(why(c)).or_insert(0usize) += 1;
        }
        let list: Vec<String> = counts.iter().map(|(w, n)| format!("{n} {w}")).collect();
        outln!(
            "    (the {} learned with the largest bounds of {} harmonics: {})",
            shown.len(),
            p.learning_checks.len(),
            list.join(", ")
        );
    }
    match (p.convergence_margin, p.convergence_margin_at_hz) {
        (Some(m), Some(f)) => outln!(
            "  convergence margin {m:.3} at 2σ (set at {f:.1} Hz): every learned harmonic's error contracts each trial"
        ),
        _ => outln!("  warning: no harmonic is learned: the measurement vouches for none"),
    }
}
