//! `bench chirp`: excite the stage with a chirp, record, estimate the FRF,
//! plot it beside the model and summarise the modes and the CMP-CNMP test.
//!
//! Threads: the real-time loop (`bench-rt`) drives the stage and pushes
//! records into a wait-free queue; the writer (`bench-writer`) drains it into
//! the MCAP file and keeps the input/output samples for identification; the
//! calling thread shows progress, then estimates, plots and summarises once
//! the loop has stopped.

use crate::config::BenchConfig;
use crate::excitation::Chirp;
use crate::plot::{write_bode_png, BodePlot, BodeSeries};
use crate::record::{spawn_writer, Recorder, DEFAULT_CHUNK_INTERVAL};
use crate::records::Record;
use crate::rt::{self, Job, JobOutput, LoopOptions, LoopReport, Pacing, StopReason};
use crate::sysid::{closely_spaced_pair, find_resonances, Frf, PairVerdict, Resonance, Spectra};
use bench_hal::sim::{SimStage, ZohPlant};
use bench_hal::{Sample, Stage};
use serde::Serialize;
use serde_json::json;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Smallest peak prominence for a resonance, dB.
pub const MIN_PROMINENCE_DB: f64 = 3.0;

/// Capacity of the record queue, records (≈ 13 s at 5 kHz).
const QUEUE_CAPACITY: usize = 1 << 16;

/// The chirp job: open loop, command = excitation.
#[derive(Debug, Clone, Copy)]
pub struct ChirpJob {
    chirp: Chirp,
}

impl ChirpJob {
    /// Wraps a chirp.
    pub fn new(chirp: Chirp) -> Self {
        Self { chirp }
    }
}

impl Job for ChirpJob {
    #[inline]
    fn tick(&mut self, tick: u64, _sample: &Sample) -> JobOutput {
        let e = self.chirp.value_a(tick);
        JobOutput {
            command_a: e,
            excitation_a: e,
            setpoint_m: f64::NAN,
            done: tick + 1 >= self.chirp.total_ticks(),
        }
    }
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
    /// Real-time pacing instead of virtual time.
    pub realtime: bool,
    /// Simulator noise seed.
    pub seed: u64,
    /// Show a progress bar (real-time mode, on a terminal).
    pub progress: bool,
}

/// Loop timing in the summary.
#[derive(Debug, Clone, Serialize)]
pub struct TimingSummary {
    /// Ticks run.
    pub ticks: u64,
    /// Pacing: `virtual` or `realtime`.
    pub mode: &'static str,
    /// Loop rate, Hz.
    pub rate_hz: f64,
    /// Wake-up latency p99, µs (0 in virtual time).
    pub wake_latency_p99_us: f64,
    /// Largest wake-up latency, µs.
    pub wake_latency_max_us: f64,
    /// Mean compute time per tick, µs.
    pub compute_mean_us: f64,
    /// Compute time p99, µs.
    pub compute_p99_us: f64,
    /// Largest compute time, µs.
    pub compute_max_us: f64,
    /// Ticks that ended after the next deadline.
    pub overruns: u64,
    /// Records dropped because the writer fell behind.
    pub dropped_records: u64,
    /// Wall time of the loop, s.
    pub wall_s: f64,
    /// Real-time setup warnings.
    pub warnings: Vec<String>,
}

impl TimingSummary {
    fn new(r: &LoopReport, realtime: bool, rate_hz: f64, wall_s: f64) -> Self {
        let t = &r.timing;
        Self {
            ticks: r.ticks,
            mode: if realtime { "realtime" } else { "virtual" },
            rate_hz,
            wake_latency_p99_us: t.wake.quantile_ns(0.99) * 1e-3,
            wake_latency_max_us: t.wake.max_ns() * 1e-3,
            compute_mean_us: t.compute.mean_ns() * 1e-3,
            compute_p99_us: t.compute.quantile_ns(0.99) * 1e-3,
            compute_max_us: t.compute.max_ns() * 1e-3,
            overruns: t.overruns,
            dropped_records: r.dropped_records,
            wall_s,
            warnings: r.warnings.clone(),
        }
    }
}

/// The model's view of the same bench, for comparison.
#[derive(Debug, Clone, Serialize)]
pub struct ModelSummary {
    /// Natural frequencies of the four modes, Hz.
    pub natural_frequencies_hz: Vec<f64>,
    /// Modal damping ratios.
    pub damping_ratios: Vec<f64>,
    /// Index (0-based) of the X rigid-body mode.
    pub rigid_body_mode: usize,
    /// Zeros of the damped model, `[re, im]` in Hz (s / 2π).
    pub zeros_hz: Vec<[f64; 2]>,
    /// Types of the undamped numerator roots (Chapter 3).
    pub zero_types: Vec<&'static str>,
    /// Eq. (2-8) discriminant (negative ⇔ CMP-CNMP).
    pub cnmp_discriminant: f64,
    /// The damped model has complex right-half-plane zeros.
    pub cmp_cnmp: bool,
}

/// Result of `bench chirp` (printed, and as JSON with `--json`).
#[derive(Debug, Clone, Serialize)]
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
    /// Y1o / L.
    pub operating_point_fraction_of_l: f64,
    /// Δm23.
    pub mass_asymmetry: f64,
    /// Largest |x1| read during the run, m.
    pub peak_position_m: f64,
    /// Resonances found in the measured FRF.
    pub resonances: Vec<Resonance>,
    /// The closely spaced pair and its phase test.
    pub closely_spaced_pair: Option<PairVerdict>,
    /// Verdict: the measured phase shows the CMP-CNMP −360° signature
    /// (`None` when no closely spaced pair was resolved).
    pub cmp_cnmp: Option<bool>,
    /// The model of the configured bench.
    pub model: ModelSummary,
    /// Loop timing.
    pub timing: TimingSummary,
}

/// Why a chirp run did not produce a summary.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// Bad input detected before anything was enabled (exit 2).
    #[error("{0}")]
    BadInput(String),
    /// The supervisor latched a fault (exit 3). The recording was finished.
    #[error("safety fault: {kind} at tick {tick} (value {value:e}); 0 A, amplifier disabled; recording {recording}")]
    Fault {
        /// Fault name.
        kind: &'static str,
        /// Offending value.
        value: f64,
        /// Tick.
        tick: u64,
        /// The finished recording.
        recording: String,
    },
    /// The HAL failed (exit 4). The recording was finished.
    #[error(
        "hardware error at tick {tick}: {message}; 0 A, amplifier disabled; recording {recording}"
    )]
    Hal {
        /// Backend message.
        message: String,
        /// Tick.
        tick: u64,
        /// The finished recording.
        recording: String,
    },
    /// Stopped by SIGINT/SIGTERM (exit 130). The recording was finished.
    #[error("interrupted at tick {tick}: 0 A, amplifier disabled; recording {recording} finished")]
    Interrupted {
        /// Tick.
        tick: u64,
        /// The finished recording.
        recording: String,
    },
    /// Anything else (exit 1).
    #[error(transparent)]
    Other(#[from] anyhow::Error),
}

/// Checks that `path` can be created: its directory exists and is writable.
/// Creates and removes a probe file beside it; leaves nothing behind.
///
/// # Errors
/// [`RunError::BadInput`] naming `arg` and the path.
pub fn check_writable(path: &Path, arg: &str) -> Result<(), RunError> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    if path.file_name().is_none() {
        return Err(RunError::BadInput(format!(
            "{arg} {}: not a file path",
            path.display()
        )));
    }
    if !dir.is_dir() {
        return Err(RunError::BadInput(format!(
            "{arg} {}: directory {} does not exist",
            path.display(),
            dir.display()
        )));
    }
    if path.is_dir() {
        return Err(RunError::BadInput(format!(
            "{arg} {}: is a directory",
            path.display()
        )));
    }
    let probe = dir.join(format!(".bench-write-check-{}", std::process::id()));
    match std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
    {
        Ok(_) => {
            let _ = std::fs::remove_file(&probe);
            Ok(())
        }
        Err(e) => Err(RunError::BadInput(format!(
            "{arg} {}: cannot write in {}: {e}",
            path.display(),
            dir.display()
        ))),
    }
}

fn model_summary(stage: &SimStage) -> ModelSummary {
    let m = stage.model();
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
            .map(|z| z.kind.as_str())
            .collect::<Vec<_>>(),
        cnmp_discriminant: m.cnmp_discriminant(),
        cmp_cnmp: m.has_cnmp_zeros(),
    }
}

/// Input and output samples kept by the writer for identification.
#[derive(Debug, Default)]
struct Collected {
    excitation_a: Vec<f64>,
    position_m: Vec<f64>,
}

/// Runs `bench chirp` end to end on the simulated bench.
///
/// `stop` is raised by SIGINT/SIGTERM.
///
/// # Errors
/// See [`RunError`]; on every error after the loop started the recording is
/// finished and the amplifier left disabled.
pub fn run_chirp(opts: &ChirpOptions, stop: Arc<AtomicBool>) -> Result<ChirpSummary, RunError> {
    let cfg = &opts.config;
    check_writable(&opts.out, "--out")?;
    check_writable(&opts.frf_csv, "--frf-csv")?;
    check_writable(&opts.plot, "--plot")?;

    let mut stage = SimStage::new(cfg.sim_params(opts.seed))
        .map_err(|e| RunError::BadInput(format!("config {}: {e}", opts.config_path.display())))?;
    let period_ns = cfg.loop_.period_ns();
    let info = stage
        .configure(period_ns)
        .map_err(|e| RunError::BadInput(format!("loop.rate_hz: {e}")))?;
    let period_s = info.period_ns as f64 * 1e-9;
    let rate_hz = 1.0 / period_s;
    let chirp = Chirp::new(&cfg.chirp, period_s);
    let total_ticks = chirp.total_ticks();

    let mut recorder =
        Recorder::create(&opts.out).map_err(|e| RunError::BadInput(format!("--out: {e}")))?;
    let mut meta = BTreeMap::new();
    meta.insert("toml".to_string(), cfg.to_toml());
    meta.insert("path".to_string(), opts.config_path.display().to_string());
    recorder
        .write_metadata("bench.config", &meta)
        .map_err(anyhow::Error::from)?;
    let mut run_meta = BTreeMap::new();
    run_meta.insert("command".to_string(), "chirp".to_string());
    run_meta.insert("backend".to_string(), info.name.clone());
    run_meta.insert("seed".to_string(), opts.seed.to_string());
    run_meta.insert(
        "mode".to_string(),
        if opts.realtime { "realtime" } else { "virtual" }.to_string(),
    );
    run_meta.insert("rate_hz".to_string(), rate_hz.to_string());
    run_meta.insert("version".to_string(), env!("CARGO_PKG_VERSION").to_string());
    run_meta.insert(
        "log_time_unit".to_string(),
        "ns of loop time (tick × period)".to_string(),
    );
    recorder
        .write_metadata("bench.run", &run_meta)
        .map_err(anyhow::Error::from)?;

    let (mut producer, consumer) = rtrb::RingBuffer::<Record>::new(QUEUE_CAPACITY);
    let collected = Arc::new(Mutex::new(Collected {
        excitation_a: Vec::with_capacity(total_ticks as usize),
        position_m: Vec::with_capacity(total_ticks as usize),
    }));
    let sink = Arc::clone(&collected);
    let writer_done = Arc::new(AtomicBool::new(false));
    // Runs on the writer thread (never the real-time one).
    let writer = spawn_writer(
        consumer,
        recorder,
        Arc::clone(&writer_done),
        DEFAULT_CHUNK_INTERVAL,
        move |r| {
            if let Record::Sample(s) = r {
                let mut c = sink.lock().expect("collector poisoned");
                c.excitation_a.push(s.excitation_a);
                c.position_m.push(s.position_m);
            }
        },
    );

    let loop_opts = LoopOptions {
        period_ns: info.period_ns,
        pacing: if opts.realtime {
            Pacing::RealTime {
                priority: cfg.loop_.priority,
                cpu: cfg.loop_.cpu,
            }
        } else {
            Pacing::Virtual
        },
        timing_interval_ticks: ((cfg.loop_.timing_interval_s / period_s).round() as u64).max(1),
        safety: cfg.supervisor(&info),
        max_ticks: total_ticks,
    };
    let progress = Arc::new(AtomicU64::new(0));
    let clock = info.clock;
    let rt_progress = Arc::clone(&progress);
    let rt_stop = Arc::clone(&stop);
    let wall = Instant::now();
    let rt_thread = std::thread::Builder::new()
        .name("bench-rt".into())
        .spawn(move || {
            let mut job = ChirpJob::new(chirp);
            let report = rt::run(
                &mut stage,
                &mut job,
                &loop_opts,
                clock,
                &mut producer,
                &rt_stop,
                &rt_progress,
            );
            (stage, report)
        })
        .map_err(|e| anyhow::anyhow!("cannot spawn the real-time thread: {e}"))?;

    if opts.realtime && opts.progress {
        let bar = indicatif::ProgressBar::new(total_ticks);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{spinner} chirp [{bar:40}] {percent:>3}% {elapsed_precise} / ~{duration_precise}",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        while !rt_thread.is_finished() {
            bar.set_position(progress.load(Ordering::Relaxed));
            std::thread::sleep(Duration::from_millis(100));
        }
        bar.finish_and_clear();
    }
    let (stage, report) = rt_thread
        .join()
        .map_err(|_| anyhow::anyhow!("the real-time thread panicked"))?;
    let wall_s = wall.elapsed().as_secs_f64();
    writer_done.store(true, Ordering::Release);
    let (mut recorder, _stats) = writer
        .join()
        .map_err(|_| anyhow::anyhow!("the writer thread panicked"))?
        .map_err(anyhow::Error::from)?;
    let timing = TimingSummary::new(&report, opts.realtime, rate_hz, wall_s);
    for w in &timing.warnings {
        tracing::warn!("{w}");
    }

    let end_ns = crate::record::log_time_ns(report.ticks as f64 * period_s);
    match report.stop {
        StopReason::Finished => {}
        StopReason::Fault { kind, value, tick } => {
            let recording = finish(recorder)?;
            return Err(RunError::Fault {
                kind: kind.as_str(),
                value,
                tick,
                recording,
            });
        }
        StopReason::Hal { message, tick } => {
            let recording = finish(recorder)?;
            return Err(RunError::Hal {
                message,
                tick,
                recording,
            });
        }
        StopReason::Interrupted { tick } => {
            let recording = finish(recorder)?;
            return Err(RunError::Interrupted { tick, recording });
        }
        StopReason::TickLimit => {
            let recording = finish(recorder)?;
            return Err(RunError::Other(anyhow::anyhow!(
                "the chirp did not finish within its tick budget; recording {recording}"
            )));
        }
    }

    // Identification.
    let data = std::mem::take(&mut *collected.lock().expect("collector poisoned"));
    let lead = (chirp.lead_in_ticks() as usize).min(data.position_m.len());
    let offset = if lead > 0 {
        data.position_m[..lead].iter().sum::<f64>() / lead as f64
    } else {
        0.0
    };
    let y: Vec<f64> = data.position_m.iter().map(|v| v - offset).collect();
    let spectra = Spectra::new(&data.excitation_a, &y, rate_hz, &cfg.identification);
    let frf = Frf::estimate(
        &spectra,
        cfg.chirp.f_start_hz,
        cfg.chirp.f_end_hz,
        &cfg.identification,
    );
    let resonances = find_resonances(&frf, &spectra, MIN_PROMINENCE_DB);
    let pair = closely_spaced_pair(&frf, &resonances);

    let zoh = ZohPlant::new(stage.model(), &cfg.actuator, period_s);
    let model_h: Vec<_> = frf.frequency_hz.iter().map(|&f| zoh.frf(f)).collect();
    let model_mag: Vec<f64> = model_h.iter().map(|h| h.norm()).collect();
    let mut model_phase: Vec<f64> = model_h.iter().map(|h| h.arg().to_degrees()).collect();
    crate::sysid::unwrap_deg(&mut model_phase);
    // Align the model's unwrapped phase with the measurement's branch at the
    // first grid point (both start near 0° or −180°).
    if let (Some(m0), Some(p0)) = (model_phase.first().copied(), frf.phase_deg.first().copied()) {
        let shift = ((p0 - m0) / 360.0).round() * 360.0;
        model_phase.iter_mut().for_each(|p| *p += shift);
    }

    recorder
        .write_frf(
            end_ns,
            &frf.frequency_hz,
            &frf.magnitude_m_per_a,
            &frf.phase_deg,
            &frf.coherence,
        )
        .map_err(anyhow::Error::from)?;
    frf.write_csv(&opts.frf_csv)
        .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", opts.frf_csv.display()))?;
    let markers: Vec<f64> = resonances.iter().map(|r| r.frequency_hz).collect();
    let title = format!(
        "x1 / current, Y1o = {:.1} % of L, Δm23 = {:+.0} % (seed {})",
        100.0 * cfg.plant.operating_point_m / cfg.plant.beam.length_m,
        100.0 * cfg.plant.mass_asymmetry,
        opts.seed
    );
    write_bode_png(
        &opts.plot,
        &BodePlot {
            title: &title,
            measured: BodeSeries {
                label: "measured (H1)",
                frequency_hz: &frf.frequency_hz,
                magnitude: &frf.magnitude_m_per_a,
                phase_deg: &frf.phase_deg,
            },
            coherence: &frf.coherence,
            model: Some(BodeSeries {
                label: "model (ZOH)",
                frequency_hz: &frf.frequency_hz,
                magnitude: &model_mag,
                phase_deg: &model_phase,
            }),
            markers_hz: &markers,
        },
    )
    .map_err(|e| anyhow::anyhow!("{e}"))?;

    let summary = ChirpSummary {
        recording: opts.out.clone(),
        frf_csv: opts.frf_csv.clone(),
        plot: opts.plot.clone(),
        backend: info.name.clone(),
        seed: opts.seed,
        operating_point_m: cfg.plant.operating_point_m,
        operating_point_fraction_of_l: cfg.plant.operating_point_m / cfg.plant.beam.length_m,
        mass_asymmetry: cfg.plant.mass_asymmetry,
        cmp_cnmp: pair.map(|p| p.cmp_cnmp),
        peak_position_m: y.iter().fold(0.0, |m: f64, v| m.max(v.abs())),
        resonances,
        closely_spaced_pair: pair,
        model: model_summary(&stage),
        timing,
    };
    let ch = recorder
        .add_json_channel(
            "/sysid/summary",
            "bench.ChirpSummary",
            &json!({
                "type": "object",
                "description": "Summary of a bench chirp run: resonances (Hz, m/A), CMP-CNMP phase test (deg), model comparison and loop timing (µs)."
            }),
        )
        .map_err(anyhow::Error::from)?;
    recorder
        .write_json(
            ch,
            end_ns,
            &serde_json::to_value(&summary).map_err(anyhow::Error::from)?,
        )
        .map_err(anyhow::Error::from)?;
    finish(recorder)?;
    Ok(summary)
}

fn finish(recorder: Recorder) -> Result<String, RunError> {
    let path = recorder.finish().map_err(anyhow::Error::from)?;
    Ok(path.display().to_string())
}
