//! The figures written as files: their sizes, the atomic write, invalid
//! and degenerate inputs (the Bode, time-series and design figures), the
//! pair window rule, and where the design figure's worst loop lands in its
//! Nyquist panel. `plot_write_examples_to_tmp` writes example figures for
//! visual inspection.

use super::pair_zoom::pair_window;
use super::*;
use crate::ident::frf::PairVerdict;
use crate::outputs::Existing;
use nalgebra::Complex;
use std::f64::consts::PI;
use std::fs;
use std::path::Path;

/// Two-mode compliance `x/i` of a flexure stage in m/A: a main mode near
/// 71 Hz and a weaker one near 420 Hz, with an optional dead time.
fn stage_response(f: f64, delay_s: f64) -> (f64, f64) {
    let w = 2.0 * PI * f;
    let mode = |k: f64, m: f64, zeta: f64, gain: f64| {
        let c = 2.0 * zeta * (k * m).sqrt();
        let (re, im) = (k - m * w * w, c * w);
        let d = re * re + im * im;
        (gain * re / d, -gain * im / d)
    };
    let a = mode(2.0e4, 0.1, 0.02, 5.0);
    let b = mode(3.0e5, 0.043, 0.01, 0.6);
    let (re, im) = (a.0 + b.0, a.1 + b.1);
    let mag = re.hypot(im);
    let phase = im.atan2(re) - w * delay_s;
    (mag, phase.to_degrees())
}

fn unwrap_deg(p: &mut [f64]) {
    for i in 1..p.len() {
        while p[i] - p[i - 1] > 180.0 {
            p[i] -= 360.0;
        }
        while p[i] - p[i - 1] < -180.0 {
            p[i] += 360.0;
        }
    }
}

fn log_grid(n: usize, f0: f64, f1: f64) -> Vec<f64> {
    (0..n)
        .map(|i| f0 * (f1 / f0).powf(i as f64 / (n - 1) as f64))
        .collect()
}

struct Example {
    f: Vec<f64>,
    mag: Vec<f64>,
    phase: Vec<f64>,
    coh: Vec<f64>,
    fm: Vec<f64>,
    mag_m: Vec<f64>,
    phase_m: Vec<f64>,
}

fn example() -> Example {
    let f = log_grid(200, 1.0, 1000.0);
    let mut mag = Vec::new();
    let mut phase = Vec::new();
    let mut coh = Vec::new();
    for (i, &fi) in f.iter().enumerate() {
        let (m, p) = stage_response(fi, 2e-4);
        // Deterministic "measurement noise" growing with frequency.
        let noise = 0.08 * (fi / 1000.0).sqrt() * (i as f64 * 2.3).sin();
        mag.push(m * (1.0 + noise));
        phase.push(p + 10.0 * noise);
        let dip = (-((fi.ln() - 130f64.ln()) / 0.08).powi(2)).exp();
        coh.push((0.98 - 0.5 * (fi / 1000.0).powi(2) - 0.6 * dip).clamp(0.0, 1.0));
    }
    unwrap_deg(&mut phase);
    let fm = log_grid(600, 0.8, 1200.0);
    let (mut mag_m, mut phase_m): (Vec<f64>, Vec<f64>) =
        fm.iter().map(|&fi| stage_response(fi, 2e-4)).unzip();
    unwrap_deg(&mut phase_m);
    mag_m.iter_mut().for_each(|m| *m *= 1.05);
    Example {
        f,
        mag,
        phase,
        coh,
        fm,
        mag_m,
        phase_m,
    }
}

fn bode<'a>(e: &'a Example, markers: &'a [f64]) -> BodePlot<'a> {
    BodePlot {
        title: "X axis compliance, chirp 1–1000 Hz",
        magnitude_axis: super::MAGNITUDE_M_PER_A,
        measured: BodeSeries {
            label: "measured",
            frequency_hz: &e.f,
            magnitude: &e.mag,
            phase_deg: &e.phase,
        },
        coherence: &e.coh,
        model: Some(BodeSeries {
            label: "lumped model",
            frequency_hz: &e.fm,
            magnitude: &e.mag_m,
            phase_deg: &e.phase_m,
        }),
        markers_hz: markers,
        pair: None,
    }
}

/// The pair zoom of the example: two made-up modes near 400 Hz.
fn example_pair() -> PairZoom<'static> {
    PairZoom::Resolved {
        pair: PairVerdict {
            lower_hz: 400.0,
            upper_hz: 430.0,
            band_hz: (150.0, 700.0),
            net_phase_deg: -350.0,
            net_phase_multiple_deg: -360.0,
            cmp_cnmp: true,
        },
        band_phase_deg: (-190.0, -540.0),
    }
}

/// Reads width and height from the PNG signature + IHDR chunk.
fn png_size(path: &Path) -> (u32, u32) {
    let bytes = fs::read(path).unwrap();
    assert!(bytes.len() > 24, "PNG too short");
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "not a PNG signature");
    assert_eq!(&bytes[12..16], b"IHDR");
    let w = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
    let h = u32::from_be_bytes(bytes[20..24].try_into().unwrap());
    (w, h)
}

fn dir_entries(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn plot_bode_writes_1400x1000_png() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bode.png");
    let e = example();
    write_bode_png(&path, Existing::Refuse, &bode(&e, &[70.9, 420.0])).unwrap();
    assert_eq!(png_size(&path), (1400, 1000));
    // Nothing but the final file is left behind.
    assert_eq!(dir_entries(dir.path()), vec!["bode.png".to_string()]);
}

#[test]
fn plot_bode_with_a_pair_zoom_is_1400x1650() {
    let dir = tempfile::tempdir().unwrap();
    let e = example();
    for (i, pair) in [
        example_pair(),
        PairZoom::Unresolved {
            reason: "only one resonance",
        },
    ]
    .into_iter()
    .enumerate()
    {
        let path = dir.path().join(format!("bode{i}.png"));
        let plot = BodePlot {
            pair: Some(pair),
            ..bode(&e, &[70.9, 400.0, 430.0])
        };
        write_bode_png(&path, Existing::Refuse, &plot).unwrap();
        assert_eq!(png_size(&path), (1400, 1650));
    }
}

#[test]
fn plot_bode_replaces_an_existing_file_only_with_overwrite() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bode.png");
    fs::write(&path, b"old").unwrap();
    let e = example();
    let err = write_bode_png(&path, Existing::Refuse, &bode(&e, &[])).unwrap_err();
    assert!(matches!(err, PlotError::Io { .. }), "{err:?}");
    assert_eq!(fs::read(&path).unwrap(), b"old");
    write_bode_png(&path, Existing::Replace, &bode(&e, &[])).unwrap();
    assert_eq!(png_size(&path), (1400, 1000));
    assert_eq!(dir_entries(dir.path()), vec!["bode.png".to_string()]);
}

#[test]
fn plot_bode_survives_nan_zero_and_negative_points() {
    let dir = tempfile::tempdir().unwrap();
    let e = example();
    let mut mag = e.mag.clone();
    let mut phase = e.phase.clone();
    let mut coh = e.coh.clone();
    let mut f = e.f.clone();
    mag[10] = 0.0;
    mag[11] = -1.0;
    mag[50] = f64::NAN;
    mag[120] = f64::INFINITY;
    phase[60] = f64::NAN;
    phase[61] = f64::NEG_INFINITY;
    coh[70] = f64::NAN;
    f[0] = 0.0; // DC bin: no place on a log axis
    f[199] = f64::NAN;
    let plot = BodePlot {
        title: "NaN and zero points",
        magnitude_axis: super::MAGNITUDE_M_PER_A,
        measured: BodeSeries {
            label: "measured",
            frequency_hz: &f,
            magnitude: &mag,
            phase_deg: &phase,
        },
        coherence: &coh,
        model: None,
        markers_hz: &[f64::NAN, -5.0, 1e9, 70.9],
        pair: None,
    };
    let path = dir.path().join("nan.png");
    write_bode_png(&path, Existing::Refuse, &plot).unwrap();
    assert_eq!(png_size(&path), (1400, 1000));
}

#[test]
fn plot_bode_degenerate_inputs_do_not_panic() {
    let dir = tempfile::tempdir().unwrap();
    let one = [100.0];
    // (frequency, magnitude, phase, coherence)
    type Case = (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>);
    let cases: Vec<Case> = vec![
        // Single point.
        (vec![100.0], vec![1e-4], vec![-90.0], vec![0.9]),
        // All-equal values on a real grid.
        (
            log_grid(20, 1.0, 100.0),
            vec![1e-4; 20],
            vec![-90.0; 20],
            vec![1.0; 20],
        ),
        // All-equal frequencies.
        (vec![50.0; 5], vec![1e-3; 5], vec![0.0; 5], vec![0.5; 5]),
        // Nothing valid at all.
        (
            vec![f64::NAN; 3],
            vec![0.0; 3],
            vec![f64::NAN; 3],
            vec![f64::NAN; 3],
        ),
        // Empty.
        (vec![], vec![], vec![], vec![]),
        // Narrow range without a decade or 1-2-5 tick inside.
        (
            vec![101.0, 103.0, 107.0],
            vec![1e-4, 2e-4, 3e-4],
            vec![1.0, 2.0, 3.0],
            vec![1.0; 3],
        ),
    ];
    for (i, (f, m, p, c)) in cases.iter().enumerate() {
        let plot = BodePlot {
            title: "",
            magnitude_axis: super::MAGNITUDE_M_PER_A,
            measured: BodeSeries {
                label: "measured",
                frequency_hz: f,
                magnitude: m,
                phase_deg: p,
            },
            coherence: c,
            model: Some(BodeSeries {
                label: "model",
                frequency_hz: &one,
                magnitude: &[2e-4],
                phase_deg: &[-45.0],
            }),
            markers_hz: &one,
            pair: None,
        };
        let path = dir.path().join(format!("case{i}.png"));
        write_bode_png(&path, Existing::Refuse, &plot).unwrap_or_else(|e| panic!("case {i}: {e}"));
        assert_eq!(png_size(&path), (1400, 1000), "case {i}");
        // The same with a pair zoom, resolved or not.
        for (j, pair) in [example_pair(), PairZoom::Unresolved { reason: "none" }]
            .into_iter()
            .enumerate()
        {
            let plot = BodePlot {
                pair: Some(pair),
                ..plot
            };
            let path = dir.path().join(format!("case{i}-{j}.png"));
            write_bode_png(&path, Existing::Refuse, &plot)
                .unwrap_or_else(|e| panic!("case {i}-{j}: {e}"));
            assert_eq!(png_size(&path), (1400, 1650), "case {i}-{j}");
        }
    }
}

#[test]
fn plot_missing_directory_is_an_error_naming_the_path() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("no-such-dir").join("bode.png");
    let e = example();
    let err = write_bode_png(&path, Existing::Refuse, &bode(&e, &[])).unwrap_err();
    assert!(matches!(err, PlotError::Io { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(msg.contains(&path.display().to_string()), "{msg}");
    assert!(msg.contains("does not exist"), "{msg}");
    assert!(!path.exists());

    let err = write_time_png(&path, Existing::Refuse, "t", &[TimePanel::default()]).unwrap_err();
    assert!(err.to_string().contains(&path.display().to_string()));
}

#[test]
fn plot_mismatched_lengths_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.png");
    let e = example();
    let mut plot = bode(&e, &[]);
    plot.coherence = &e.coh[1..];
    let err = write_bode_png(&path, Existing::Refuse, &plot).unwrap_err();
    assert!(matches!(err, PlotError::InvalidData { .. }), "{err:?}");
    assert!(err.to_string().contains("coherence"));

    let mut plot = bode(&e, &[]);
    plot.model.as_mut().unwrap().phase_deg = &e.phase_m[..3];
    let err = write_bode_png(&path, Existing::Refuse, &plot).unwrap_err();
    assert!(err.to_string().contains("lumped model"), "{err}");

    let t = [0.0, 1.0];
    let panel = TimePanel {
        y_label: "y",
        series: vec![("s", &t[..], &t[..1])],
    };
    let err = write_time_png(&path, Existing::Refuse, "", &[panel]).unwrap_err();
    assert!(matches!(err, PlotError::InvalidData { .. }), "{err:?}");
    assert!(write_time_png(&path, Existing::Refuse, "", &[]).is_err());
    assert!(!path.exists());
}

fn step_example() -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
    let t: Vec<f64> = (0..2000).map(|i| i as f64 * 1e-4).collect();
    let r: Vec<f64> = t
        .iter()
        .map(|&t| if t >= 0.02 { 10.0 } else { 0.0 })
        .collect();
    let y: Vec<f64> = t
        .iter()
        .map(|&t| {
            if t < 0.02 {
                0.0
            } else {
                let s = t - 0.02;
                10.0 * (1.0 - (-s / 0.004).exp() * (2.0 * PI * 120.0 * s).cos())
            }
        })
        .collect();
    let u: Vec<f64> = y
        .iter()
        .zip(&r)
        .map(|(y, r)| 0.05 * (r - y) + 0.002 * r)
        .collect();
    (t, r, y, u)
}

#[test]
fn plot_time_writes_png() {
    let dir = tempfile::tempdir().unwrap();
    let (t, r, y, mut u) = step_example();
    u[500] = f64::NAN;
    let panels = [
        TimePanel {
            y_label: "Position [µm]",
            series: vec![("reference", &t[..], &r[..]), ("measured", &t[..], &y[..])],
        },
        TimePanel {
            y_label: "Current [A]",
            series: vec![("", &t[..], &u[..])],
        },
    ];
    let path = dir.path().join("step.png");
    write_time_png(&path, Existing::Refuse, "Closed-loop step", &panels).unwrap();
    assert_eq!(png_size(&path), (1400, 1000));

    // Many panels grow the figure; empty and constant panels are fine.
    let c = vec![3.0; t.len()];
    let mut many = vec![TimePanel::default(); 4];
    many.push(TimePanel {
        y_label: "const",
        series: vec![("c", &t[..], &c[..])],
    });
    write_time_png(&path, Existing::Replace, "", &many).unwrap();
    assert_eq!(png_size(&path), (1400, 1600));
}

#[test]
fn plot_pair_window() {
    let PairZoom::Resolved { pair, .. } = example_pair() else {
        unreachable!()
    };
    let w = pair_window(&pair, &(1.0..1000.0));
    assert_eq!(w, 370.0..460.0);
    // Cut to the measured band when the pair stays inside it.
    let w = pair_window(&pair, &(1.0..440.0));
    assert_eq!(w, 370.0..440.0);
    // A pair at the edge keeps its own window.
    let w = pair_window(&pair, &(1.0..420.0));
    assert_eq!(w, 370.0..460.0);
}

/// `L = k·e^(−sτ)/(s(s + 1))` on `omega` (rad/s): an integrator, a
/// first-order lag and a dead time, crossing −1 at `k ≈ 1/τ` for small τ.
fn integrator_loop(omega: &[f64], k: f64, delay_s: f64) -> Vec<Complex<f64>> {
    omega
        .iter()
        .map(|&w| {
            let s = Complex::new(0.0, w);
            k * (-s * delay_s).exp() / (s * (s + 1.0))
        })
        .collect()
}

/// Loops of four inputs (the last the worst) and a model, on 0.05–50 rad/s.
struct DesignExample {
    omega: Vec<f64>,
    gains: Vec<Vec<Complex<f64>>>,
    model_omega: Vec<f64>,
    model_gain: Vec<Complex<f64>>,
}

fn design_example() -> DesignExample {
    let omega = log_grid(400, 0.05, 50.0);
    let gains = [(0.6, 0.05), (0.8, 0.12), (1.0, 0.08), (1.5, 0.1)]
        .iter()
        .map(|&(k, delay_s)| integrator_loop(&omega, k, delay_s))
        .collect();
    let model_omega = log_grid(300, 0.02, 100.0);
    let model_gain = integrator_loop(&model_omega, 1.1, 0.1);
    DesignExample {
        omega,
        gains,
        model_omega,
        model_gain,
    }
}

fn design_loops(e: &DesignExample) -> Vec<DesignLoop<'_>> {
    let names = ["x1", "x2", "y1", "y2"];
    e.gains
        .iter()
        .zip(names)
        .enumerate()
        .map(|(i, (g, label))| DesignLoop {
            label,
            omega_rad_s: &e.omega,
            loop_gain: g,
            worst: i == 3,
        })
        .collect()
}

fn design_plot<'a>(e: &'a DesignExample, loops: &'a [DesignLoop<'a>]) -> DesignPlot<'a> {
    DesignPlot {
        title: "bench design: loops of 4 inputs",
        loops,
        model: Some(DesignLoop {
            label: "model",
            omega_rad_s: &e.model_omega,
            loop_gain: &e.model_gain,
            worst: false,
        }),
        sensitivity_peak_max: 2.0,
        phase_margin_min_deg: 30.0,
        crossover_rad_s: Some(1.2),
        sensitivity_bandwidth_rad_s: Some(0.6),
    }
}

#[test]
fn plot_design_writes_1400x1000_and_refuses_an_existing_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("design.png");
    let e = design_example();
    let loops = design_loops(&e);
    write_design_png(&path, Existing::Refuse, &design_plot(&e, &loops)).unwrap();
    assert_eq!(png_size(&path), (1400, 1000));
    assert_eq!(dir_entries(dir.path()), vec!["design.png".to_string()]);

    let before = fs::read(&path).unwrap();
    let err = write_design_png(&path, Existing::Refuse, &design_plot(&e, &loops)).unwrap_err();
    assert!(matches!(err, PlotError::Io { .. }), "{err:?}");
    assert_eq!(fs::read(&path).unwrap(), before);
    // Without a model, markers or other inputs, and with nothing at all.
    let plot = DesignPlot {
        model: None,
        crossover_rad_s: None,
        sensitivity_bandwidth_rad_s: Some(1e6),
        ..design_plot(&e, &loops[3..])
    };
    write_design_png(&path, Existing::Replace, &plot).unwrap();
    assert_eq!(png_size(&path), (1400, 1000));
    let empty = DesignPlot {
        model: None,
        ..design_plot(&e, &[])
    };
    write_design_png(&path, Existing::Replace, &empty).unwrap();
    assert_eq!(png_size(&path), (1400, 1000));
    assert_eq!(dir_entries(dir.path()), vec!["design.png".to_string()]);
}

#[test]
fn plot_design_rejects_bad_loops_naming_them() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("design.png");
    let e = design_example();
    let check = |plot: &DesignPlot<'_>, words: &[&str]| {
        let err = write_design_png(&path, Existing::Refuse, plot).unwrap_err();
        assert!(matches!(err, PlotError::InvalidData { .. }), "{err:?}");
        let msg = err.to_string();
        for w in words {
            assert!(msg.contains(w), "{msg:?} lacks {w:?}");
        }
        assert!(!path.exists());
    };
    // Mismatched lengths.
    let mut loops = design_loops(&e);
    loops[1].loop_gain = &e.gains[1][1..];
    check(
        &design_plot(&e, &loops),
        &["\"x2\"", "400 frequencies", "399"],
    );
    // A NaN loop gain.
    let mut g = e.gains[2].clone();
    g[17].im = f64::NAN;
    let mut loops = design_loops(&e);
    loops[2].loop_gain = &g;
    check(&design_plot(&e, &loops), &["\"y1\"", "loop gain 17", "NaN"]);
    // Frequencies not ascending, or not positive.
    let mut w = e.omega.clone();
    w.swap(5, 6);
    let mut loops = design_loops(&e);
    loops[0].omega_rad_s = &w;
    check(&design_plot(&e, &loops), &["\"x1\"", "not ascending at 6"]);
    let mut w = e.omega.clone();
    w[0] = 0.0;
    loops[0].omega_rad_s = &w;
    check(&design_plot(&e, &loops), &["\"x1\"", "frequency 0 is 0"]);
    // The model is named as such.
    let loops = design_loops(&e);
    let mut plot = design_plot(&e, &loops);
    plot.model.as_mut().unwrap().loop_gain = &e.model_gain[..3];
    check(&plot, &["model loop \"model\""]);
    // The limits and markers.
    let plot = DesignPlot {
        sensitivity_peak_max: 0.0,
        ..design_plot(&e, &loops)
    };
    check(&plot, &["sensitivity_peak_max"]);
    let plot = DesignPlot {
        phase_margin_min_deg: f64::NAN,
        ..design_plot(&e, &loops)
    };
    check(&plot, &["phase_margin_min_deg"]);
    let plot = DesignPlot {
        crossover_rad_s: Some(-1.0),
        ..design_plot(&e, &loops)
    };
    check(&plot, &["crossover_rad_s"]);
}

/// Pixel `p` is colour `c` within `tol` per channel.
fn near(p: [u8; 3], c: plotters::style::RGBColor, tol: i32) -> bool {
    (i32::from(p[0]) - i32::from(c.0)).abs() <= tol
        && (i32::from(p[1]) - i32::from(c.1)).abs() <= tol
        && (i32::from(p[2]) - i32::from(c.2)).abs() <= tol
}

/// The worst loop `L = 1/(s(s + 1))` lands where it should in the Nyquist
/// panel: the panel's frame is found in the pixels (the black rows in the
/// left column), mapped by the documented rule (equal scales, centred on
/// −1, showing at least [−3, 1] × [−2, 2]), and the worst loop's colour is
/// found near the analytic curve (`L(j1) = −0.5 − 0.5j`, `L(j0.5) = −0.8 −
/// 1.6j`, `L(j2) = −0.2 − 0.1j`) and nowhere else inside the frame.
#[test]
fn plot_design_worst_loop_lands_on_its_nyquist_curve() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nyquist.png");
    let omega = log_grid(600, 0.05, 50.0);
    let worst = integrator_loop(&omega, 1.0, 0.0);
    let other = integrator_loop(&omega, 0.5, 0.2);
    let loops = [
        DesignLoop {
            label: "other",
            omega_rad_s: &omega,
            loop_gain: &other,
            worst: false,
        },
        DesignLoop {
            label: "worst",
            omega_rad_s: &omega,
            loop_gain: &worst,
            worst: true,
        },
    ];
    let plot = DesignPlot {
        title: "",
        loops: &loops,
        model: None,
        sensitivity_peak_max: 2.0,
        phase_margin_min_deg: 30.0,
        crossover_rad_s: Some(0.79),
        sensitivity_bandwidth_rad_s: None,
    };
    write_design_png(&path, Existing::Refuse, &plot).unwrap();
    let img = image::open(&path).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (1400, 1000));

    // The Nyquist frame: rows with a black run over 300 px left of x = 700.
    let mut rows = Vec::new();
    for y in 0..img.height() {
        let (mut run, mut best) = (0u32, (0u32, 0u32));
        for x in 0..700 {
            if img.get_pixel(x, y).0 == [0, 0, 0] {
                run += 1;
                if run > best.1 - best.0 {
                    best = (x + 1 - run, x + 1);
                }
            } else {
                run = 0;
            }
        }
        if best.1 - best.0 > 300 {
            rows.push((y, best));
        }
    }
    let (top, (left, right)) = rows.first().copied().expect("a Nyquist frame");
    let (bottom, _) = *rows.last().unwrap();
    let (w, h) = (f64::from(right - left), f64::from(bottom - top));
    assert!(h > 300.0 && w > 300.0, "{rows:?}");
    let px_per_unit = (w / 4.0).min(h / 4.0);
    let (cx, cy) = (f64::from(left + right) / 2.0, f64::from(top + bottom) / 2.0);
    let to_px = |re: f64, im: f64| (cx + (re + 1.0) * px_per_unit, cy - im * px_per_unit);

    let is_worst = |x: u32, y: u32| near(img.get_pixel(x, y).0, WORST_LOOP_COLOR, 8);
    let found_near = |(px, py): (f64, f64), r: i64| {
        (-r..=r)
            .any(|dx| (-r..=r).any(|dy| is_worst((px as i64 + dx) as u32, (py as i64 + dy) as u32)))
    };
    for (re, im) in [(-0.5, -0.5), (-0.8, -1.6), (-0.2, -0.1)] {
        assert!(
            found_near(to_px(re, im), 3),
            "no worst-loop pixel near L = {re} {im}j"
        );
    }
    // Every worst-coloured pixel inside the frame is on the curve (the
    // negative frequencies, the mirror image, are not drawn).
    let curve: Vec<(f64, f64)> = log_grid(4000, 0.05, 50.0)
        .iter()
        .map(|&w| {
            let l = integrator_loop(&[w], 1.0, 0.0)[0];
            to_px(l.re, l.im)
        })
        .collect();
    let mut count = 0;
    for y in top + 2..bottom - 1 {
        for x in left + 2..right - 1 {
            if is_worst(x, y) {
                count += 1;
                let d = curve
                    .iter()
                    .map(|&(px, py)| (px - f64::from(x)).hypot(py - f64::from(y)))
                    .fold(f64::INFINITY, f64::min);
                assert!(
                    d < 4.0,
                    "worst-loop pixel ({x}, {y}) is {d:.1} px off the curve"
                );
            }
        }
    }
    assert!(count > 500, "only {count} worst-loop pixels");
    assert!(
        !found_near(to_px(-0.5, 0.5), 6),
        "the mirror image is drawn"
    );
}

/// Writes `/tmp/bode-example.png`, `/tmp/bode-pair-example.png`,
/// `/tmp/time-example.png` and `/tmp/design-example.png` for visual
/// inspection:
/// `cargo test --lib plot -- --ignored`.
#[test]
#[ignore]
fn plot_write_examples_to_tmp() {
    let e = example();
    write_bode_png(
        Path::new("/tmp/bode-example.png"),
        Existing::Replace,
        &bode(&e, &[70.9, 420.0]),
    )
    .unwrap();
    write_bode_png(
        Path::new("/tmp/bode-pair-example.png"),
        Existing::Replace,
        &BodePlot {
            pair: Some(example_pair()),
            ..bode(&e, &[70.9, 400.0, 430.0])
        },
    )
    .unwrap();
    let (t, r, y, u) = step_example();
    let panels = [
        TimePanel {
            y_label: "Position [µm]",
            series: vec![("reference", &t[..], &r[..]), ("measured", &t[..], &y[..])],
        },
        TimePanel {
            y_label: "Current [A]",
            series: vec![("coil current", &t[..], &u[..])],
        },
    ];
    write_time_png(
        Path::new("/tmp/time-example.png"),
        Existing::Replace,
        "Closed-loop step, X axis",
        &panels,
    )
    .unwrap();
    let e = design_example();
    let loops = design_loops(&e);
    write_design_png(
        Path::new("/tmp/design-example.png"),
        Existing::Replace,
        &design_plot(&e, &loops),
    )
    .unwrap();
}

/// Issue 29: the map marks the configured bench with a cross in the map's
/// red, on top of everything else: the same map with the bench given has
/// clearly more red pixels than without it (the crossing line is red in
/// both).
#[test]
fn the_map_marks_the_configured_bench() {
    use crate::analysis::map::MapCell;
    let dir = tempfile::tempdir().unwrap();
    let l = 0.0475;
    let ops: Vec<f64> = (1..=10).map(|i| i as f64 * 0.01 * l).collect();
    let dms: Vec<f64> = (-4..=5).map(|i| i as f64 * 0.02).collect();
    let cells: Vec<MapCell> = ops
        .iter()
        .flat_map(|&op| {
            dms.iter().map(move |&dm| MapCell {
                operating_point_m: op,
                mass_asymmetry: dm,
                cnmp: dm > 0.0 && op > 0.05 * l,
                cnmp_damped: dm > 0.0 && op > 0.06 * l,
                discriminant: 0.0,
            })
        })
        .collect();
    let red = |configured: Option<(f64, f64)>, name: &str| {
        let path = dir.path().join(name);
        write_map_png(
            &path,
            Existing::Replace,
            "map",
            l,
            &ops,
            &dms,
            &cells,
            Some(0.0767 * l),
            &[],
            configured,
        )
        .unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        img.pixels()
            .filter(|p| p.0[0] > 170 && p.0[1] < 70 && p.0[2] < 70)
            .count()
    };
    let (without, with) = (red(None, "a.png"), red(Some((0.03 * l, -0.04)), "b.png"));
    assert!(
        with > without + 100,
        "red pixels {with} with the bench, {without} without"
    );
}

/// `.svg` and `.pdf` give vector figures of the same drawing: an SVG of
/// the PNG's size whose text is text (the verdict line searchable), that
/// usvg parses; a one-page PDF of that size in points (× 0.75) with the
/// font embedded. A failed write leaves nothing.
#[test]
fn plot_vector_formats_by_extension() {
    use svg2pdf::usvg;
    let dir = tempfile::tempdir().unwrap();
    let e = example();
    let plot = BodePlot {
        pair: Some(example_pair()),
        ..bode(&e, &[70.9, 400.0, 430.0])
    };
    let svg_path = dir.path().join("bode.svg");
    write_bode_png(&svg_path, Existing::Refuse, &plot).unwrap();
    let svg = fs::read_to_string(&svg_path).unwrap();
    assert!(
        svg.starts_with("<svg width=\"1400\" height=\"1650\""),
        "{}",
        &svg[..80]
    );
    assert!(svg.contains("<text"), "no text elements");
    assert!(svg.contains("Coherence"), "the panel titles are text");
    let tree = usvg::Tree::from_str(&svg, &usvg::Options::default()).unwrap();
    assert_eq!(
        (tree.size().width(), tree.size().height()),
        (1400.0, 1650.0)
    );

    let pdf_path = dir.path().join("bode.PDF");
    write_bode_png(&pdf_path, Existing::Refuse, &plot).unwrap();
    let pdf = fs::read(&pdf_path).unwrap();
    assert!(pdf.starts_with(b"%PDF-"));
    let text = String::from_utf8_lossy(&pdf);
    assert_eq!(
        text.matches("/Type /Page\n").count()
            + text.matches("/Type /Page/").count()
            + text.matches("/Type /Page ").count(),
        1,
        "one page"
    );
    assert!(
        text.contains("/MediaBox [0 0 1050 1237.5]"),
        "1400 × 1650 px at 96 dpi"
    );
    assert!(text.contains("/FontFile2"), "the font is embedded");
    assert!(text.contains("DejaVu"), "in DejaVu Sans");
    // The PNG of the same plot is still a PNG.
    let png = dir.path().join("bode.png");
    write_bode_png(&png, Existing::Refuse, &plot).unwrap();
    assert_eq!(png_size(&png), (1400, 1650));
    // A vector figure into a missing directory writes nothing.
    let missing = dir.path().join("nope/bode.pdf");
    assert!(matches!(
        write_bode_png(&missing, Existing::Refuse, &plot),
        Err(PlotError::Io { .. })
    ));
    let mut names = dir_entries(dir.path());
    names.sort();
    assert_eq!(names, ["bode.PDF", "bode.png", "bode.svg"]);
}
