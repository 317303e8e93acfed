//! Running `bench chirp` end to end: the outputs, the recording, the loop,
//! the estimate (a sweep's LPM or H1, a multisine's BLA) and its files.

use super::*;

/// What a multisine run keeps of its excitation once the job (and its
/// table) has moved to the loop.
#[derive(Debug, Clone)]
pub(super) struct MultisinePlan {
    pub(super) layout: Layout,
    pub(super) phases: &'static str,
    pub(super) crest_factor: f64,
    /// Smallest and largest line amplitude, A.
    pub(super) line_amplitude_a: [f64; 2],
    pub(super) band_hz: [f64; 2],
    pub(super) f_max_hz: f64,
    pub(super) peak_a: f64,
}

impl MultisinePlan {
    pub(super) fn of(m: &Multisine) -> Self {
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

    pub(super) fn summary(
        &self,
        bla: &Bla,
        model: &Sr4dof,
        bla_csv: Option<PathBuf>,
    ) -> MultisineSummary {
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
    // No output may be the config it reads (rule 6 of crate::outputs).
    outputs.add_input("config", &opts.config_path);
    outputs.check()?;
    let spec = BackendSpec::resolve(opts.backend.as_ref(), &opts.config);
    let (mut stage, info) = backend::open(
        &spec,
        &opts.config,
        &opts.config_path,
        opts.seed,
        opts.inject,
        // Open loop: no stall bound of its own, only the user's.
        opts.config.safety.max_overrun_s.unwrap_or(f64::INFINITY),
    )?;
    let mut runner = Runner::Local {
        stage: &mut stage,
        info: &info,
    };
    let result = run_chirp_with(&mut runner, !spec.is_sim(), opts, &mut outputs, stop, ticks);
    catalogued(opts, result)
}

/// `result` with the run's row appended to the catalogue (when
/// `opts.catalogue`): a summary reports it; an error whose recording was
/// finished appends it too. Never changes the outcome.
fn catalogued(
    opts: &ChirpOptions,
    result: Result<ChirpSummary, RunError>,
) -> Result<ChirpSummary, RunError> {
    if !opts.catalogue {
        return result;
    }
    match result {
        Ok(mut summary) => {
            summary.catalogue = Some(crate::jobs::catalogue::catalogue_run(&opts.out));
            Ok(summary)
        }
        Err(e) => {
            crate::jobs::catalogue::catalogue_ended_run(&e, &opts.out);
            Err(e)
        }
    }
}

/// The outputs of a chirp, none replaced (the daemon's jobs: their names
/// are derived from the recording's).
pub fn chirp_outputs(opts: &ChirpOptions) -> OutputPlan {
    let plan = OutputPlan::new(Existing::Refuse)
        .with_recording(&opts.out, Origin::Default)
        .with_output("frf_csv", &opts.frf_csv, Origin::Derived)
        .with_output("plot", &opts.plot, Origin::Derived);
    match &opts.bla_csv {
        Some(p) if !opts.config.excitation.kind.is_sweep() => {
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
    let result = run_chirp_with(runner, hardware, opts, &mut outputs, stop, ticks);
    catalogued(opts, result)
}

/// The excitation of `opts` at the device's period, checked before
/// anything is enabled: its ticks within the job's limit, and a sweep's
/// band wide enough for the LPM's local window on the record's bin
/// spacing (a multisine's FRF is the BLA on its own lines). A multisine's
/// table is computed here, before the loop starts.
fn checked_excitation(opts: &ChirpOptions, period_s: f64) -> Result<Excitation, RunError> {
    let cfg = &opts.config;
    let bad = |e: String| RunError::BadInput(format!("config {}: {e}", opts.config_path.display()));
    let excitation = Excitation::new(cfg, period_s, opts.seed)
        .map_err(|e| bad(format!("{e} (at the device's period of {period_s} s)")))?;
    let total_ticks = excitation.total_ticks();
    if total_ticks > crate::config::ranges::JOB_TICKS_MAX {
        return Err(bad(format!(
            "chirp.duration_s: lead_in_s + duration_s + tail_s is more than {} ticks at the device's period",
            crate::config::ranges::JOB_TICKS_MAX
        )));
    }
    let sweep = matches!(excitation, Excitation::Sweep(_));
    if sweep && cfg.identification.estimator == crate::config::Estimator::Lpm {
        let bin_hz = 1.0 / period_s / crate::ident::frf::fast_len(total_ticks as usize) as f64;
        crate::ident::lpm::check_band(
            bin_hz,
            cfg.chirp.f_start_hz,
            cfg.chirp.f_end_hz,
            &crate::ident::lpm::LpmOptions::from_config(&cfg.identification),
        )
        .map_err(|e| bad(e.to_string()))?;
    }
    Ok(excitation)
}

/// The recorded session of a chirp of `total_ticks`.
fn chirp_session<'a>(
    opts: &'a ChirpOptions,
    hardware: bool,
    total_ticks: u64,
    ticks: Option<&'a Arc<AtomicU64>>,
) -> SessionOptions<'a> {
    SessionOptions {
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
    }
}

/// Takes the probe offset (the lead-in's mean) off the record's position
/// in place; returns the largest |position| left, m.
fn remove_probe_offset(record: &mut [crate::ident::frf::C64], lead_in_ticks: u64) -> f64 {
    let lead = (lead_in_ticks as usize).min(record.len());
    let offset = if lead > 0 {
        record[..lead].iter().map(|z| z.im).sum::<f64>() / lead as f64
    } else {
        0.0
    };
    let mut peak_position_m = 0.0_f64;
    for z in record.iter_mut() {
        z.im -= offset;
        peak_position_m = peak_position_m.max(z.im.abs());
    }
    peak_position_m
}

/// The FRF CSV, and a multisine's BLA CSV when asked for.
fn write_estimates(
    opts: &ChirpOptions,
    existing: Existing,
    frf: &Frf,
    bla: Option<&Bla>,
) -> Result<(), RunError> {
    frf.write_csv(&opts.frf_csv, existing)
        .map_err(|e| RunError::Output {
            path: opts.frf_csv.clone(),
            reason: e.to_string(),
        })?;
    match (bla, &opts.bla_csv) {
        (Some(b), Some(path)) => b.write_csv(path, existing).map_err(|e| RunError::Output {
            path: path.clone(),
            reason: e.to_string(),
        }),
        _ => Ok(()),
    }
}

/// The chirp's Bode figure (`opts.plot`): the measured FRF with its
/// coherence, the model's curve, the resonances marked and the closely
/// spaced pair zoomed.
fn write_chirp_figure(
    opts: &ChirpOptions,
    existing: Existing,
    frf: &Frf,
    summary: &ChirpSummary,
    model: BodeSeries<'_>,
) -> Result<(), RunError> {
    let cfg = &opts.config;
    let markers: Vec<f64> = summary.resonances.iter().map(|r| r.frequency_hz).collect();
    let no_pair = PairZoom::reason_of(&summary.verdict.phase_test);
    let pair_zoom = PairZoom::of(&summary.verdict.phase_test, frf, &no_pair);
    let title = format!(
        "x1 / current, Y1o = {:.1} % of L, Δm23 = {:+.0} % (seed {})",
        100.0 * cfg.plant.operating_point_m / cfg.plant.beam.length_m,
        100.0 * cfg.plant.mass_asymmetry,
        opts.seed
    );
    write_bode_png(
        &opts.plot,
        existing,
        &BodePlot {
            title: &title,
            magnitude_axis: crate::plot::MAGNITUDE_M_PER_A,
            measured: BodeSeries::measured(
                frf,
                summary
                    .frf_estimator
                    .as_ref()
                    .map_or("measured", |e| e.name.plot_label()),
            ),
            coherence: &frf.coherence,
            model: Some(model),
            markers_hz: &markers,
            pair: Some(pair_zoom),
        },
    )
    .map_err(|e| RunError::Output {
        path: opts.plot.clone(),
        reason: e.to_string(),
    })
}

/// A sweep's FRF with the estimator of `identification.estimator` (LPM or
/// H1), the stalls' spans left out. A NaN sample faults the run before it
/// gets here; the check names it if not.
fn estimate_sweep(
    opts: &ChirpOptions,
    model: &Sr4dof,
    record: Vec<crate::ident::frf::C64>,
    stalls: &[(u64, f64)],
    chirp: &Chirp,
    period_s: f64,
) -> Result<(Frf, StallReport, FrfEstimator), RunError> {
    let cfg = &opts.config;
    let estimate_failed = |e: crate::ident::frf::FrfError| RunError::Output {
        path: opts.frf_csv.clone(),
        reason: format!("the FRF could not be estimated: {e}"),
    };
    crate::ident::frf::check_record(&record).map_err(estimate_failed)?;
    let spectra = Spectra::from_record(
        record,
        1.0 / period_s,
        &cfg.identification,
        cfg.chirp.f_end_hz,
    );
    let (ident, estimator) = lpm_or_h1(cfg, model, spectra.bin_hz());
    let frf = Frf::from_spectra(&spectra, cfg.chirp.f_start_hz, cfg.chirp.f_end_hz, &ident)
        .map_err(estimate_failed)?;
    let mut stall_report = StallReport::of(
        stalls,
        chirp,
        period_s,
        cfg.identification.relative_resolution,
    );
    let frf = stall_report.exclude(frf);
    Ok((frf, stall_report, estimator))
}

/// The model's curve for the plot, on a grid at least as dense as
/// MODEL_POINTS_PER_DECADE, so that its lightly damped peaks keep their
/// shape in the plot's pair zoom.
fn model_curve(cfg: &BenchConfig, zoh: &ZohPlant) -> (Vec<f64>, Vec<crate::ident::frf::C64>) {
    let f = crate::ident::frf::log_grid(
        cfg.chirp.f_start_hz,
        cfg.chirp.f_end_hz,
        cfg.identification
            .points_per_decade
            .max(MODEL_POINTS_PER_DECADE),
    );
    let h = f.iter().map(|&f| zoh.frf(f)).collect();
    (f, h)
}

/// The samples go to the disk while the FRF and the fit are computed: an
/// fsync of the part file now (any descriptor of a file syncs it) leaves
/// the one in `finish` only the tail, the summary and the index.
/// Durability is unchanged: `finish` still syncs before the rename, and
/// reports the errors.
fn sync_early(part: &std::path::Path) -> std::thread::JoinHandle<std::io::Result<()>> {
    let part = part.to_path_buf();
    std::thread::spawn(move || std::fs::File::open(part).and_then(|f| f.sync_data()))
}

pub(super) fn run_chirp_with(
    runner: &mut Runner<'_>,
    hardware: bool,
    opts: &ChirpOptions,
    outputs: &mut OutputPlan,
    stop: Arc<AtomicBool>,
    ticks: Option<&Arc<AtomicU64>>,
) -> Result<ChirpSummary, RunError> {
    let cfg = &opts.config;
    let info = &runner.info().clone();
    outputs.add_input("config", &opts.config_path);
    outputs.check()?;
    let model = Sr4dof::new(cfg.plant)
        .map_err(|e| RunError::BadInput(format!("config {}: {e}", opts.config_path.display())))?;
    let period_s = info.period_ns as f64 * 1e-9;
    let excitation = checked_excitation(opts, period_s)?;
    let total_ticks = excitation.total_ticks();
    let lead_in_ticks = excitation.lead_in_ticks();
    let (sweep, plan) = match &excitation {
        Excitation::Sweep(c) => (Some(*c), None),
        Excitation::Multisine(m) => (None, Some(MultisinePlan::of(m))),
    };
    crate::jobs::request::refuse_pace_on_hardware(opts.pace, hardware, &info.name)?;
    let session = chirp_session(opts, hardware, total_ticks, ticks);
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
    let early_sync = sync_early(recorder.part_path());

    // Identification, in the record's own memory (the FFT runs in the
    // packed record, 16 bytes a tick at the peak).
    let mut record = data.frf_record;
    let peak_position_m = remove_probe_offset(&mut record, lead_in_ticks);
    let (frf, stall_report, bla, frf_estimator) = match (sweep, &plan) {
        (Some(chirp), _) => {
            let (frf, stalls, estimator) =
                estimate_sweep(opts, &model, record, &stalls, &chirp, period_s)?;
            (frf, stalls, None, estimator)
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
    // The fit and the model's curve for the plot ([`model_curve`]) side by
    // side, and the FRF CSV written beside them.
    let (identified, ((model_f, model_h), csv)) = rayon::join(
        || identify(&frf, period_s, cfg.actuator.bandwidth_hz),
        || {
            let curve = model_curve(cfg, &zoh);
            let csv = write_estimates(opts, outputs.existing(), &frf, bla.as_ref());
            (curve, csv)
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
        catalogue: None,
    };
    let model_series = BodeSeries {
        label: "model (ZOH)",
        frequency_hz: &model_f,
        magnitude: &model_mag,
        phase_deg: &model_phase,
    };
    // The plot is rendered while the recording is finished (its tail, the
    // summary and the index written and synced, then renamed): a failed
    // plot still leaves the recording complete.
    let (plotted, finished) = rayon::join(
        || write_chirp_figure(opts, outputs.existing(), &frf, &summary, model_series),
        || -> Result<(), RunError> {
            recorder.write_frf(end_ns, &frf_record(&frf))?;
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

/// The columns of `frf` as the `/sysid/frf` message, borrowed.
fn frf_record(frf: &crate::ident::frf::Frf) -> crate::record::FrfRecord<'_> {
    crate::record::FrfRecord {
        frequency_hz: (&frf.frequency_hz[..]).into(),
        magnitude_m_per_a: (&frf.magnitude_m_per_a[..]).into(),
        phase_deg: (&frf.phase_deg[..]).into(),
        coherence: (&frf.coherence[..]).into(),
        sigma_m_per_a: (&frf.sigma_m_per_a[..]).into(),
        resolution_hz: (&frf.resolution_hz[..]).into(),
        sigma_dof: (&frf.sigma_dof[..]).into(),
    }
}
