//! The local polynomial method (`src/ident/lpm.rs`) against independent
//! references, on records made by the simulator:
//!
//! - a noise-free record: the LPM FRF is the model's exact sampled (ZOH)
//!   response, `ZohPlant::frf` (what `bench chirp` draws as the model), to
//!   rounding away from the modes and within its stated polynomial bias at
//!   them;
//! - the shipped bench with its noise, through `bench chirp` (the FRF CSV is
//!   the LPM's), and a few random benches (seeded, masses and stiffnesses
//!   within ±25 %): the FRF and σ equal those of
//!   `tests/data/lpm_reference.py`, a from-scratch numpy LPM (integer bin
//!   offsets, LAPACK least squares and QR where the Rust code scales the
//!   columns and solves the normal equations by Cholesky);
//! - σ honesty, by Monte Carlo over noise seeds on one bench: the scatter of
//!   Ĝ about the noise-free estimate matches the reported σ as the theory of
//!   the module docs says (`|Ĝ − G|²/σ̂²` is F(2, 2q)), and H1's σ from the
//!   coherence measured the same way (right on average, but heavy-tailed:
//!   2σ covers less than a known σ would; the numbers are printed and the
//!   shortfall asserted as documented).
//!
//! Python is `$BENCH_PYTHON` when set, else `python3`, with numpy and
//! scipy; a missing interpreter or module is a failure with the command
//! that installs it, never a skip.

use crate::common;

use bench::config::{BenchConfig, Estimator};
use bench::ident::chirp::Chirp;
use bench::ident::frf::{fast_len, Frf, Spectra, C64};
use bench::ident::lpm::{self, LpmOptions};
use bench_hal::{Command, Stage};
use bench_plant::model::Sr4dof;
use bench_plant::sim::{SimParams, SimStage, ZohPlant};
use rand::{Rng, SeedableRng};
use serde::Deserialize;
use std::path::Path;

/// What the reference needs, for failure messages.
const INSTALL_HINT: &str = "the LPM reference tests/data/lpm_reference.py needs python3 with numpy and scipy: `pip install numpy scipy` (in a venv where pip refuses with externally-managed-environment, then set BENCH_PYTHON=<venv>/bin/python), or run .ci/run, which does that";

fn shipped(name: &str) -> BenchConfig {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("bench-config")
        .join(name);
    let c = BenchConfig::load(&p).unwrap();
    c.validate(&p).unwrap();
    c
}

fn period_s(cfg: &BenchConfig) -> f64 {
    cfg.loop_.period_ns() as f64 * 1e-9
}

/// The bench without probe noise, quantisation or force disturbance.
fn quiet(mut cfg: BenchConfig) -> BenchConfig {
    cfg.probe.noise_rms_m = 0.0;
    cfg.probe.quantization_m = 0.0;
    cfg.plant.disturbance = None;
    cfg
}

/// The record `bench chirp` identifies from, made the way its loop makes
/// it (read the sample, command the chirp's value, keep both): the
/// excitation + i · the probe reading, the lead-in's mean taken off the
/// reading.
fn simulate(cfg: &BenchConfig, seed: u64) -> Vec<C64> {
    let mut stage = SimStage::new(SimParams {
        plant: cfg.plant,
        actuator: cfg.actuator,
        probe: cfg.probe,
        mechanical_stop_m: cfg.stage.mechanical_stop_m,
        seed,
    })
    .unwrap();
    let chirp = Chirp::new(&cfg.chirp, cfg.excitation.kind, period_s(cfg));
    stage.configure(cfg.loop_.period_ns()).unwrap();
    stage.enable().unwrap();
    let n = chirp.total_ticks();
    let mut record = Vec::with_capacity(fast_len(n as usize));
    for tick in 0..n {
        let s = stage.read_sample().unwrap();
        assert!(!stage.at_stop(), "the simulated stage hit its stop");
        let u = chirp.value_a(tick);
        stage
            .write_command(Command {
                current_a: u,
                answers_seq: s.seq,
            })
            .unwrap();
        record.push(C64::new(u, s.position_m));
    }
    remove_offset(&mut record, chirp.lead_in_ticks() as usize);
    record
}

fn remove_offset(record: &mut [C64], lead: usize) {
    let offset = record[..lead].iter().map(|z| z.im).sum::<f64>() / lead.max(1) as f64;
    for z in record {
        z.im -= offset;
    }
}

/// The spectra of `record` as `bench chirp` makes them.
fn spectra(cfg: &BenchConfig, record: Vec<C64>) -> Spectra {
    Spectra::from_record(
        record,
        1.0 / period_s(cfg),
        &cfg.identification,
        cfg.chirp.f_end_hz,
    )
}

/// The LPM and the H1 FRF of the configured band.
fn both(cfg: &BenchConfig, s: &Spectra) -> (Frf, Frf) {
    let (lo, hi) = (cfg.chirp.f_start_hz, cfg.chirp.f_end_hz);
    let l = lpm::estimate(
        s,
        lo,
        hi,
        cfg.identification.points_per_decade,
        &LpmOptions::from_config(&cfg.identification),
    )
    .unwrap();
    (l, Frf::estimate(s, lo, hi, &cfg.identification))
}

/// The reference's answer, one entry per frequency.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Reference {
    response_re: Vec<Option<f64>>,
    response_im: Vec<Option<f64>>,
    sigma_m_per_a: Vec<Option<f64>>,
    coherence: Vec<Option<f64>>,
    noise_variance_m2: Vec<Option<f64>>,
    half_width_bins: Vec<usize>,
}

impl Reference {
    fn response(&self, i: usize) -> C64 {
        let v = |x: Option<f64>| x.unwrap_or(f64::NAN);
        C64::new(v(self.response_re[i]), v(self.response_im[i]))
    }
}

/// Runs `tests/data/lpm_reference.py` on `record` (padded to `n_fft`
/// samples, bins up to `k_max`) at `frequencies_hz`.
///
/// # Panics
/// When python, numpy or scipy are missing ([`INSTALL_HINT`]), or the
/// script fails: a test failure, never a skip.
fn python_lpm(
    record: &[C64],
    rate_hz: f64,
    k_max: usize,
    opts: &LpmOptions,
    frequencies_hz: &[f64],
) -> Reference {
    let dir = tempfile::tempdir().unwrap();
    let bytes = |f: fn(&C64) -> f64| -> Vec<u8> {
        record.iter().flat_map(|z| f(z).to_le_bytes()).collect()
    };
    let (u_file, y_file) = (dir.path().join("u.f64"), dir.path().join("y.f64"));
    std::fs::write(&u_file, bytes(|z| z.re)).unwrap();
    std::fs::write(&y_file, bytes(|z| z.im)).unwrap();
    let input = dir.path().join("in.json");
    let output = dir.path().join("out.json");
    std::fs::write(
        &input,
        serde_json::to_vec(&serde_json::json!({
            "rate_hz": rate_hz,
            "n_fft": fast_len(record.len()),
            "k_max": k_max,
            "half_width_bins": opts.half_width_bins,
            "degree": opts.degree,
            "relative_resolution": opts.relative_resolution,
            "frequencies_hz": frequencies_hz,
            "u_file": u_file,
            "y_file": y_file,
        }))
        .unwrap(),
    )
    .unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/lpm_reference.py");
    let py = common::loop_reference::python();
    let out = std::process::Command::new(&py)
        .arg(&script)
        .arg(&input)
        .arg(&output)
        .output()
        .unwrap_or_else(|e| panic!("cannot run `{py}` ({e}): {INSTALL_HINT}"));
    assert!(
        out.status.success(),
        "`{py} {}` failed ({}):\n{}\n{INSTALL_HINT}",
        script.display(),
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let r: Reference = serde_json::from_slice(&std::fs::read(&output).unwrap())
        .expect("the reference's output parses");
    assert_eq!(r.response_re.len(), frequencies_hz.len());
    r
}

/// Rust's LPM (`frf`) against the reference on the same record, at every
/// line: the response within `tol_g` relative, σ within `tol_s` relative,
/// the coherence within 1e-6; the worst relative errors returned.
fn compare(frf: &Frf, bin_hz: f64, r: &Reference, tol_g: f64, tol_s: f64) -> (f64, f64) {
    let (mut worst_g, mut worst_s) = (0.0f64, 0.0f64);
    for i in 0..frf.frequency_hz.len() {
        let f = frf.frequency_hz[i];
        let window = (2 * r.half_width_bins[i] + 1) as f64 * bin_hz;
        assert!((frf.resolution_hz[i] / window - 1.0).abs() < 1e-9, "{f} Hz");
        let g = r.response(i);
        let eg = (frf.response(i) - g).norm() / g.norm();
        let rs = r.sigma_m_per_a[i].expect("σ");
        let es = (frf.sigma_m_per_a[i] / rs - 1.0).abs();
        let ec = (frf.coherence[i] - r.coherence[i].expect("γ²")).abs();
        assert!(
            eg <= tol_g,
            "{f:.3} Hz: Ĝ {} vs the reference's {g}: {eg:.2e}",
            frf.response(i)
        );
        assert!(
            es <= tol_s,
            "{f:.3} Hz: σ {} vs the reference's {rs}: {es:.2e}",
            frf.sigma_m_per_a[i]
        );
        assert!(ec <= 1e-6, "{f:.3} Hz: coherence differs by {ec:.2e}");
        assert!(r.noise_variance_m2[i].expect("σ²_V") >= 0.0);
        worst_g = worst_g.max(eg);
        worst_s = worst_s.max(es);
    }
    (worst_g, worst_s)
}

/// (a) No noise: the LPM of the shipped bench's default chirp record is
/// the model's exact ZOH response. Away from the modes (further than
/// 25 % from every natural frequency) to rounding: relative error
/// ≤ 1e-7 (measured: median 5e-10, the residue of the ring-down the 5 s
/// tail leaves and of the transform's rounding). Nearer, the local
/// quadratic misses the resonance's cubic and higher terms, evaluated at
/// the grid's fractional offset from the nearest bin: up to 1e-4 on the
/// skirts, and ≤ 6e-3 within ±2 % of a mode (measured 4.0e-3 at 84.47 Hz,
/// the upper mode of the pair, ζ = 0.004, where the window, 0.4 % of f =
/// 0.34 Hz, is half the half-power band; 1.2e-3 at the 29.3 Hz peak, ζ =
/// 0.009, where the 13-bin window is 38 % of it). Without noise σ is that
/// misfit, and it covers the bias at every line:
/// `|Ĝ − G| ≤ σ + 1e-7 |G|` (measured: at most 0.88 σ). H1, for
/// comparison, is biased by 2.9 % at the peaks (its window, as wide,
/// averages across them), more than 5 times the LPM.
#[test]
fn a_noise_free_record_gives_the_exact_zoh_response() {
    let cfg = quiet(shipped("sr4dof-ch5.toml"));
    let model = Sr4dof::new(cfg.plant).unwrap();
    let zoh = ZohPlant::new(&model, &cfg.actuator, period_s(&cfg));
    let modes: Vec<f64> = model.modes().iter().map(|m| m.frequency_hz()).collect();
    let near = |f: f64, within: f64| modes.iter().any(|m| (f / m - 1.0).abs() <= within);
    let s = spectra(&cfg, simulate(&cfg, 1));
    let (l, h) = both(&cfg, &s);
    let (mut away, mut at, mut h1, mut covered) = (Vec::new(), 0.0f64, 0.0f64, 0.0f64);
    let mut at_hz = 0.0;
    for i in 0..l.frequency_hz.len() {
        let f = l.frequency_hz[i];
        let g = zoh.frf(f);
        let err = (l.response(i) - g).norm();
        let e = err / g.norm();
        assert!(
            err <= l.sigma_m_per_a[i] + 1e-7 * g.norm(),
            "{f:.3} Hz: |Ĝ − G| {err:.2e} above σ {:.2e}",
            l.sigma_m_per_a[i]
        );
        if l.sigma_m_per_a[i] > 1e-7 * g.norm() {
            covered = covered.max(err / l.sigma_m_per_a[i]);
        }
        if !near(f, 0.25) {
            assert!(e <= 1e-7, "{f:.3} Hz: relative error {e:.2e}");
            away.push(e);
        }
        if near(f, 0.02) {
            if e > at {
                at_hz = f;
            }
            at = at.max(e);
            h1 = h1.max((h.response(i) - g).norm() / g.norm());
        }
        let half = ((0.004 * f / (2.0 * s.bin_hz())).floor() as usize).max(6);
        assert!((l.resolution_hz[i] - (2 * half + 1) as f64 * s.bin_hz()).abs() < 1e-9);
    }
    eprintln!(
        "noise-free LPM vs ZOH: median {:.1e} away from the modes, worst {at:.1e} at them \
         ({at_hz:.2} Hz; H1 worst {h1:.1e} there); |Ĝ − G| at most {covered:.2} σ where σ is \
         above rounding",
        common::median(&away)
    );
    assert!(away.len() > 900, "{} lines", away.len());
    assert!(at <= 6e-3, "{at}");
    assert!(h1 > 5.0 * at, "H1 {h1} vs LPM {at}");
}

/// (b) The shipped (built-in) bench with its noise, through `bench chirp`:
/// the FRF CSV is the LPM of the recorded samples (the default estimator),
/// to the CSV's printed digits; and that LPM equals the python
/// reference's to 1e-8 (response, relative), 1e-6 (σ, relative) and 1e-6
/// (coherence). (Measured: about 1e-11 and 1e-9; the two differ in the
/// FFT, the polynomial basis and the least-squares solver, so rounding
/// is all they share.)
#[test]
fn the_shipped_bench_agrees_with_the_python_reference() {
    let dir = common::tmp();
    let out = common::path_in(dir.path(), "run.mcap");
    let o = common::run(&["chirp", "--json", "--out", &out]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cfg = shipped("sr4dof-ch5.toml");
    assert_eq!(cfg.identification.estimator, Estimator::Lpm);
    let samples = bench::record::read_samples_tolerant(&std::fs::read(&out).unwrap());
    let mut record: Vec<C64> = samples
        .iter()
        .map(|s| C64::new(s.excitation_a, s.position_m))
        .collect();
    let chirp = Chirp::new(&cfg.chirp, cfg.excitation.kind, period_s(&cfg));
    assert_eq!(record.len() as u64, chirp.total_ticks());
    remove_offset(&mut record, chirp.lead_in_ticks() as usize);
    let rate_hz = 1.0 / period_s(&cfg);
    let s = spectra(&cfg, record.clone());
    let (frf, _) = both(&cfg, &s);
    // The CSV bench chirp wrote is this LPM, of the record in f64; the
    // recording keeps its samples in f32 (rounding of 6e-8 relative, far
    // below the probe noise), so the two differ by a small part of σ, plus
    // the CSV's printed digits (7 of the magnitude; 0.001° of the phase,
    // 8.7e-6 of |G|).
    let rows = common::read_frf_csv_full(&dir.path().join("run.frf.csv"));
    assert_eq!(rows.len(), frf.frequency_hz.len());
    let mut worst = [0.0f64; 4];
    for (i, r) in rows.iter().enumerate() {
        let sigma = frf.sigma_m_per_a[i];
        let g = C64::from_polar(r[1], r[2].to_radians());
        let printed = 1e-5 * frf.magnitude_m_per_a[i];
        let d = [
            (r[0] / frf.frequency_hz[i] - 1.0).abs(),
            ((g - frf.response(i)).norm() - printed).max(0.0) / sigma,
            (r[4] / sigma - 1.0).abs(),
            (r[3] - frf.coherence[i]).abs(),
        ];
        assert!(
            d[0] < 1e-5 && (r[5] / frf.resolution_hz[i] - 1.0).abs() < 1e-6,
            "{r:?}"
        );
        assert!(d[1] < 0.05 && d[2] < 1e-3 && d[3] < 1e-3, "{r:?}: {d:?}");
        for j in 0..4 {
            worst[j] = worst[j].max(d[j]);
        }
    }
    assert!((rows[0][5] / (13.0 * s.bin_hz()) - 1.0).abs() < 1e-6);
    assert!((rows.last().unwrap()[5] / (0.004 * 500.0) - 1.0).abs() < 0.02);
    eprintln!(
        "the CSV vs the LPM of the recorded (f32) samples: |ΔĜ| ≤ {:.1e} σ (+ the printed \
         digits), σ within {:.1e}, γ² within {:.1e}",
        worst[1], worst[2], worst[3]
    );
    let reference = python_lpm(
        &record,
        rate_hz,
        s.k_max(),
        &LpmOptions::from_config(&cfg.identification),
        &frf.frequency_hz,
    );
    let (g, sg) = compare(&frf, s.bin_hz(), &reference, 1e-8, 1e-6);
    eprintln!("shipped bench: Rust vs python LPM: Ĝ {g:.1e}, σ {sg:.1e} (relative, worst line)");
}

/// (c) Three random benches (seed 28: masses, bearing and parallelogram
/// stiffnesses each scaled by a factor in [0.75, 1.25]), a 20 s sweep at
/// 0.05 A with the probe's noise and quantisation: Rust's LPM equals the
/// python reference's, as in (b), with the window and degree varied too.
#[test]
fn random_benches_agree_with_the_python_reference() {
    let base = shipped("sr4dof-ch5.toml");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(28);
    for (case, opts) in [(4, 2), (6, 2), (8, 3)].into_iter().enumerate() {
        let mut cfg = base.clone();
        let mut scale = || rng.random_range(0.75..=1.25);
        let p = &mut cfg.plant;
        p.m1_kg *= scale();
        p.m2_kg *= scale();
        p.m3_kg *= scale();
        p.m4_kg *= scale();
        p.m5_kg *= scale();
        p.k4_n_per_m *= scale();
        p.k5_n_per_m *= scale();
        let k = p.parallelogram_stiffness_n_per_m.unwrap() * scale();
        p.parallelogram_stiffness_n_per_m = Some(k);
        cfg.chirp.duration_s = Some(20.0);
        cfg.chirp.amplitude_a = 0.05;
        cfg.chirp.amplitude_profile.clear();
        cfg.identification.lpm_half_width_bins = opts.0;
        cfg.identification.lpm_degree = opts.1;
        let record = simulate(&cfg, 100 + case as u64);
        let s = spectra(&cfg, record.clone());
        let (frf, _) = both(&cfg, &s);
        let lpm_opts = LpmOptions::from_config(&cfg.identification);
        let reference = python_lpm(
            &record,
            1.0 / period_s(&cfg),
            s.k_max(),
            &lpm_opts,
            &frf.frequency_hz,
        );
        let (g, sg) = compare(&frf, s.bin_hz(), &reference, 1e-8, 1e-6);
        eprintln!(
            "random bench {case} (n {}, R {}): Rust vs python LPM: Ĝ {g:.1e}, σ {sg:.1e}",
            opts.0, opts.1
        );
    }
}

/// The scatter of `Ĝ` about a reference over lines × seeds, against the
/// reported σ.
struct Scatter {
    /// Mean of `|Ĝ − G|² / σ²` over lines × seeds.
    mean_ratio: f64,
    /// Fraction with `|Ĝ − G| ≤ 2σ`.
    within_2_sigma: f64,
    /// Per line, `Σ_seeds |Ĝ − G|² / Σ_seeds σ²` (the variance the line
    /// shows over the variance it reports), averaged over the lines.
    variance_ratio: f64,
    /// What the theory says of `mean_ratio` (`q/(q − 1)`) and
    /// `within_2_sigma` (`1 − (1 + 4/q)^(−q)`), averaged over the samples
    /// with each line's `q` (NaN: no `q`, H1).
    expected_mean_ratio: f64,
    expected_within_2_sigma: f64,
    /// Lines × seeds.
    count: usize,
}

/// One sample: `(|ΔG|², σ², q)`.
type Sample = (f64, f64, f64);

/// Accumulates, per line, the squared deviations and the reported
/// variances.
#[derive(Default)]
struct Lines {
    lines: Vec<Vec<Sample>>,
}

impl Lines {
    /// Line `line` of one seed: its deviation, its σ, its degrees of
    /// freedom (NaN: none stated).
    fn add(&mut self, line: usize, deviation: C64, sigma: f64, q: f64) {
        if self.lines.len() <= line {
            self.lines.resize(line + 1, Vec::new());
        }
        self.lines[line].push((deviation.norm_sqr(), sigma * sigma, q));
    }

    fn scatter(&self) -> Scatter {
        self.scatter_of(|_| true)
    }

    /// The scatter of the lines `keep` picks (by index).
    fn scatter_of(&self, keep: impl Fn(usize) -> bool) -> Scatter {
        let kept: Vec<&Vec<Sample>> = self
            .lines
            .iter()
            .enumerate()
            .filter(|(i, _)| keep(*i))
            .map(|(_, l)| l)
            .collect();
        let all: Vec<&Sample> = kept.iter().copied().flatten().collect();
        let n = all.len() as f64;
        let mean = |f: &dyn Fn(&Sample) -> f64| all.iter().map(|s| f(s)).sum::<f64>() / n;
        let per_line: Vec<f64> = kept
            .iter()
            .filter(|l| !l.is_empty())
            .map(|l| l.iter().map(|p| p.0).sum::<f64>() / l.iter().map(|p| p.1).sum::<f64>())
            .collect();
        Scatter {
            mean_ratio: mean(&|s| s.0 / s.1),
            within_2_sigma: mean(&|s| f64::from(u8::from(s.0 <= 4.0 * s.1))),
            variance_ratio: per_line.iter().sum::<f64>() / per_line.len() as f64,
            expected_mean_ratio: mean(&|s| s.2 / (s.2 - 1.0)),
            expected_within_2_sigma: mean(&|s| 1.0 - (1.0 + 4.0 / s.2).powf(-s.2)),
            count: all.len(),
        }
    }
}

impl std::fmt::Display for Scatter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "mean |ΔG|²/σ² {:.3} (theory {:.3}), within 2σ {:.4} (theory {:.4}), per-line \
             variance / σ² {:.3} ({} lines × seeds)",
            self.mean_ratio,
            self.expected_mean_ratio,
            self.within_2_sigma,
            self.expected_within_2_sigma,
            self.variance_ratio,
            self.count
        )
    }
}

/// The LPM's and H1's scatter over `seeds` noise seeds of `cfg`'s chirp,
/// lines in `band_hz`, about the estimates of the noise-free record (the
/// same window, the same bias: the variance alone is judged); and the
/// LPM's and H1's about the model's exact response (bias included); over
/// all those lines, and over those within ±2 % of a mode.
fn scatter(cfg: &BenchConfig, seeds: u64, band_hz: (f64, f64)) -> ([Scatter; 4], [Scatter; 4]) {
    let q = quiet(cfg.clone());
    let (l0, h0) = both(&q, &spectra(&q, simulate(&q, 1)));
    let model = Sr4dof::new(cfg.plant).unwrap();
    let zoh = ZohPlant::new(&model, &cfg.actuator, period_s(cfg));
    let truth: Vec<C64> = l0.frequency_hz.iter().map(|&f| zoh.frf(f)).collect();
    let modes: Vec<f64> = model.modes().iter().map(|m| m.frequency_hz()).collect();
    let at_mode = |i: usize| {
        let f = l0.frequency_hz[i];
        modes.iter().any(|m| (f / m - 1.0).abs() <= 0.02)
    };
    let unknowns = 2.0 * (cfg.identification.lpm_degree as f64 + 1.0);
    let [mut lpm, mut h1, mut lpm_truth, mut h1_truth] = std::array::from_fn(|_| Lines::default());
    for seed in 1..=seeds {
        let s = spectra(cfg, simulate(cfg, seed));
        let (l, h) = both(cfg, &s);
        for (i, g) in truth.iter().enumerate() {
            if (band_hz.0..=band_hz.1).contains(&l.frequency_hz[i]) {
                let dof = (l.resolution_hz[i] / s.bin_hz()).round() - unknowns;
                lpm.add(i, l.response(i) - l0.response(i), l.sigma_m_per_a[i], dof);
                lpm_truth.add(i, l.response(i) - g, l.sigma_m_per_a[i], dof);
                h1_truth.add(i, h.response(i) - g, h.sigma_m_per_a[i], f64::NAN);
                h1.add(
                    i,
                    h.response(i) - h0.response(i),
                    h.sigma_m_per_a[i],
                    f64::NAN,
                );
            }
        }
    }
    let lines = [lpm, h1, lpm_truth, h1_truth];
    (
        std::array::from_fn(|k| lines[k].scatter()),
        std::array::from_fn(|k| lines[k].scatter_of(at_mode)),
    )
}

/// (d) σ is honest: over noise seeds on the Chapter 5 bench, the scatter
/// of Ĝ about the noise-free record's estimate (the same window and bias:
/// the variance alone is judged), and about the model's exact response
/// (the bias included), against the σ each noisy record reports. With `q`
/// degrees of freedom at a line (`2n + 1 − 2(R + 1)`, n of that line's
/// window) the theory of `src/ident/lpm.rs` says: within 2σ
/// `1 − (1 + 4/q)^(−q)` (q = 7: 0.958); the mean of `|ΔG|²/σ̂²`
/// `q/(q − 1)` (σ̂ is itself estimated); the variance each line shows over
/// the σ̂² it reports (its mean over the seeds) 1. The expected values are
/// averaged over the lines' q.
///
/// On the shipped chirp (60 s sweep; the window 13 bins = 0.2 Hz up to
/// 46 Hz, 0.4 % of f above), 60 seeds, lines 1–400 Hz. Asserted: coverage
/// within 0.01 of theory, mean ratio within 0.05, variance ratio 1 ± 0.05
/// (the spread of each over ~60 000 samples, neighbouring lines sharing
/// bins, is a few 1e-3 and 1e-2); the same about the model. Measured:
/// 0.965 (theory 0.964), 1.106 (1.125), 0.986; about the model 0.965,
/// 1.109, 0.989.
///
/// On a short record (a 4 s sweep 2–500 Hz at 0.05 A, 5 s tail: Δf =
/// 0.105 Hz, the window 1.4 Hz, wider than the half-power band of every
/// mode), 100 seeds, lines 4–400 Hz: at the modes the local polynomials
/// cannot follow G, and the misfit enters σ̂ (the noise-free record's σ is
/// that misfit): σ̂ is conservative there, never optimistic. Asserted:
/// coverage at least theory − 0.01 (also about the model), mean ratio at
/// most theory + 0.05. Measured: 0.962 (theory 0.958), 1.105 (1.166);
/// about the model 0.962; within ±2 % of a mode 0.991.
///
/// H1's σ from the coherence, judged the same way, is right on average
/// (variance ratio 0.92 on the shipped chirp, 0.98 on the short record)
/// but is itself an estimate from the few bins of the Hann window, with
/// no stated degrees of freedom, so `|ΔH|/σ` has heavier tails than a
/// known σ gives: 0.951 and 0.928 within 2σ where a known σ covers
/// `1 − e^{−4}` = 0.982 (and nothing says what it should be, since `n_d`
/// runs from 3 bins at 1 Hz to hundreds at 400 Hz); mean ratio 1.14 and
/// 1.32. Near the modes its σ is inflated instead (the coherence drops
/// where G varies across the window even without noise): variance ratio
/// 0.38 within ±2 % of a mode. Asserted as documented: H1 covers less
/// than 0.97 over all lines.
#[test]
fn sigma_is_honest_over_noise_seeds() {
    let cfg = shipped("sr4dof-ch5.toml");
    let ([l, h, t, ht], [_, _, tm, htm]) = scatter(&cfg, 60, (1.0, 400.0));
    eprintln!(
        "shipped chirp:\n  LPM: {l}\n  H1:  {h}\n  about the model: LPM {t}\n  H1 {ht}\n  \
         about the model within 2 % of a mode: LPM {tm}\n  H1 {htm}"
    );
    // Against the model itself, the bias included: as honest.
    assert!(
        (t.within_2_sigma - t.expected_within_2_sigma).abs() <= 0.01,
        "LPM: {t}"
    );
    assert!(
        (t.mean_ratio - t.expected_mean_ratio).abs() <= 0.05,
        "LPM: {t}"
    );
    assert!(
        (l.within_2_sigma - l.expected_within_2_sigma).abs() <= 0.01,
        "LPM: {l}"
    );
    assert!(
        (l.mean_ratio - l.expected_mean_ratio).abs() <= 0.05,
        "LPM: {l}"
    );
    assert!((l.variance_ratio - 1.0).abs() <= 0.05, "LPM: {l}");
    // H1: right on average per line, but heavy-tailed (documented).
    assert!(h.within_2_sigma < 0.97, "H1: {h}");
    assert!((h.variance_ratio - 1.0).abs() <= 0.15, "H1: {h}");

    let mut short = cfg.clone();
    short.chirp.duration_s = Some(4.0);
    short.chirp.taper_s = Some(0.1);
    short.chirp.f_start_hz = 2.0;
    short.chirp.amplitude_a = 0.05;
    short.chirp.amplitude_profile.clear();
    let ([l, h, t, ht], [_, _, tm, htm]) = scatter(&short, 100, (4.0, 400.0));
    eprintln!(
        "short record:\n  LPM: {l}\n  H1:  {h}\n  about the model: LPM {t}\n  H1 {ht}\n  \
         about the model within 2 % of a mode: LPM {tm}\n  H1 {htm}"
    );
    assert!(
        t.within_2_sigma >= t.expected_within_2_sigma - 0.01,
        "LPM: {t}"
    );
    assert!(
        l.within_2_sigma >= l.expected_within_2_sigma - 0.01,
        "LPM: {l}"
    );
    assert!(l.mean_ratio <= l.expected_mean_ratio + 0.05, "LPM: {l}");
    assert!(h.within_2_sigma < 0.97, "H1: {h}");
}

/// The Chapter 5 config with `edits` (`key`, TOML value) applied, written
/// to `dir/name`.
fn edited_config(dir: &Path, name: &str, edits: &[(&str, &str)]) -> String {
    let mut text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("bench-config/sr4dof-ch5.toml"),
    )
    .unwrap();
    for (key, value) in edits {
        assert!(
            text.lines().any(|l| l.starts_with(&format!("{key} ="))),
            "{key}"
        );
        text = common::set_key(&text, key, value);
    }
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.display().to_string()
}

/// `identification.estimator` other than "lpm" or "h1" is refused naming
/// the key. A chirp whose record is too short for the LPM's window (1.1 s:
/// bins of 0.9 Hz, none of them in 10–10.5 Hz) is refused before anything
/// is enabled: exit 2, the reason naming the key, no recording. With
/// `estimator = "h1"` a short chirp runs, and its CSV carries H1's σ
/// (finite, positive) and resolution, the Hann window's full width
/// `max(relative_resolution · f, min_bins · Δf)` (README).
#[test]
fn the_estimator_key_and_a_record_too_short_for_the_window() {
    let dir = common::tmp();
    let h2 = edited_config(dir.path(), "h2.toml", &[("estimator", "\"h2\"")]);
    let o = common::run(&["config", "check", &h2]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("identification.estimator") && err.contains("h2"),
        "{err}"
    );
    let short = edited_config(
        dir.path(),
        "short.toml",
        &[("taper_s", "0.1"), ("lead_in_s", "0.1"), ("tail_s", "0.5")],
    );
    let out = common::path_in(dir.path(), "short.mcap");
    let o = common::run(&[
        "chirp",
        "--config",
        &short,
        "--out",
        &out,
        "--duration-s",
        "0.5",
        "--f-start-hz",
        "10",
        "--f-end-hz",
        "10.5",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("too short for the LPM's local window")
            && err.contains("identification.lpm_half_width_bins = 6")
            && err.contains("short.toml"),
        "{err}"
    );
    assert!(!Path::new(&out).exists() && !Path::new(&format!("{out}.part")).exists());

    let h1 = edited_config(dir.path(), "h1.toml", &[("estimator", "\"h1\"")]);
    let out = common::path_in(dir.path(), "h1.mcap");
    let o = common::run(&[
        "chirp",
        "--config",
        &h1,
        "--out",
        &out,
        "--duration-s",
        "4",
        "--f-start-hz",
        "5",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rows = common::read_frf_csv_full(&dir.path().join("h1.frf.csv"));
    let ticks = ((0.5 + 4.0 + 5.0) * 5000.0_f64).round() as usize;
    let bin_hz = 5000.0 / fast_len(ticks) as f64;
    for r in &rows {
        let width = (0.004 * r[0]).max(5.0 * bin_hz);
        assert!((r[5] / width - 1.0).abs() < 1e-6, "{r:?}");
        assert!(r[4].is_finite() && r[4] > 0.0, "{r:?}");
    }
}
