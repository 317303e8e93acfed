//! The step and Bode figures, read back as images: their size (from the PNG
//! header, and the file decodes), and where the markers land.
//!
//! The references are independent of the plotting code: analytic step
//! responses (first order: 10 % at τ ln(10/9), 90 % at τ ln 10, ±2 % settled
//! at τ ln 50; second order: peak at π/ω_d, Ogata, *Modern Control
//! Engineering*, §5-3), the zoom-window and pair-window rules as documented
//! on `write_step_png` and `write_bode_png`, and the panel frames found in
//! the pixels (the long black horizontal lines). A marker is looked for in
//! the pixel column its time or frequency maps to inside the frame.

use bench::ident::frf::PairVerdict;
use bench::jobs::control::{step_analysis, StepAnalysis};
use bench::jobs::session::Collected;
use bench::outputs::Existing;
use bench::plot::{
    write_bode_png, write_step_png, BodePlot, BodeSeries, PairZoom, StepPlot, COMMAND_COLOR,
    FAINT_COLOR, MARKER_COLOR, MEASURED_COLOR, OVERSHOOT_COLOR, RISE_COLOR, SETTLE_COLOR,
};
use image::RgbImage;
use plotters::style::RGBColor;
use std::f64::consts::PI;
use std::path::Path;

/// Width and height from the PNG signature and IHDR chunk.
fn png_header_size(path: &Path) -> (u32, u32) {
    let bytes = std::fs::read(path).unwrap();
    assert!(bytes.len() > 24, "PNG too short");
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "not a PNG signature");
    assert_eq!(&bytes[12..16], b"IHDR");
    let w = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
    let h = u32::from_be_bytes(bytes[20..24].try_into().unwrap());
    (w, h)
}

/// Decodes the PNG, checking its header size against the decoded one.
fn load(path: &Path, size: (u32, u32)) -> RgbImage {
    assert_eq!(png_header_size(path), size);
    let img = image::open(path).expect("the PNG decodes").to_rgb8();
    assert_eq!(img.dimensions(), size);
    img
}

/// A panel frame: its edges in pixels (inclusive).
#[derive(Debug, Clone, Copy)]
struct Frame {
    left: u32,
    right: u32,
    top: u32,
    bottom: u32,
}

impl Frame {
    /// The column `v` maps to on a linear axis `lo..hi` over the frame.
    fn column(&self, v: f64, lo: f64, hi: f64) -> f64 {
        f64::from(self.left) + (v - lo) / (hi - lo) * f64::from(self.right - self.left)
    }
}

/// The frames of the panels, top to bottom: rows holding a black run of at
/// least half the width are frame edges (rows within 2 px count as one),
/// taken in pairs.
fn frames(img: &RgbImage) -> Vec<Frame> {
    let (w, h) = img.dimensions();
    let mut edges: Vec<(u32, u32, u32)> = Vec::new(); // (row, left, right)
    for y in 0..h {
        let (mut best, mut run_start, mut best_span) = (0, None, (0, 0));
        for x in 0..=w {
            let black = x < w && img.get_pixel(x, y).0 == [0, 0, 0];
            match (black, run_start) {
                (true, None) => run_start = Some(x),
                (false, Some(s)) => {
                    if x - s > best {
                        best = x - s;
                        best_span = (s, x - 1);
                    }
                    run_start = None;
                }
                _ => {}
            }
        }
        if best >= w / 2 && edges.last().is_none_or(|e| y > e.0 + 2) {
            edges.push((y, best_span.0, best_span.1));
        }
    }
    assert!(
        edges.len().is_multiple_of(2),
        "unpaired frame edges at {edges:?}"
    );
    edges
        .chunks(2)
        .map(|p| Frame {
            left: p[0].1,
            right: p[0].2,
            top: p[0].0,
            bottom: p[1].0,
        })
        .collect()
}

fn near(p: [u8; 3], c: RGBColor, tol: i32) -> bool {
    (i32::from(p[0]) - i32::from(c.0)).abs() <= tol
        && (i32::from(p[1]) - i32::from(c.1)).abs() <= tol
        && (i32::from(p[2]) - i32::from(c.2)).abs() <= tol
}

/// Pixels of colour `c` (±`tol` per channel) in each column strictly
/// inside `f`.
fn column_counts(img: &RgbImage, f: &Frame, c: RGBColor, tol: i32) -> Vec<(u32, usize)> {
    (f.left + 1..f.right)
        .map(|x| {
            let n = (f.top + 1..f.bottom)
                .filter(|&y| near(img.get_pixel(x, y).0, c, tol))
                .count();
            (x, n)
        })
        .collect()
}

/// Asserts that the columns with many pixels of colour `c` (a vertical
/// marker line) are all within `tol_px` of one of `expected`, and that each
/// expected column has one.
fn assert_markers_at(
    img: &RgbImage,
    f: &Frame,
    c: RGBColor,
    expected: &[f64],
    tol_px: f64,
    what: &str,
) {
    let min_count = ((f.bottom - f.top) / 4) as usize;
    let found: Vec<u32> = column_counts(img, f, c, 8)
        .into_iter()
        .filter(|&(_, n)| n >= min_count)
        .map(|(x, _)| x)
        .collect();
    assert!(
        !found.is_empty(),
        "{what}: no marker line of {c:?} in {f:?}"
    );
    for &x in &found {
        assert!(
            expected.iter().any(|e| (f64::from(x) - e).abs() <= tol_px),
            "{what}: marker column {x} is not near any of {expected:?} (found {found:?})"
        );
    }
    for e in expected {
        assert!(
            found.iter().any(|&x| (f64::from(x) - e).abs() <= tol_px),
            "{what}: nothing near column {e:.1} (found {found:?})"
        );
    }
}

const DT: f64 = 1e-4;
const SETTLE_S: f64 = 0.05;
const STEP_M: f64 = 10e-6;

/// A step record on `n` samples of `DT`: the response `r(s)` (fraction of
/// the step, `s` the time since the step) and a command that chatters by
/// ±0.1 A every sample on top of a slow value (what a noisy loop does).
fn record(n: usize, r: impl Fn(f64) -> f64) -> Collected {
    let mut d = Collected::default();
    for k in 0..n {
        let t = k as f64 * DT;
        let s = t - SETTLE_S;
        let on = s >= 0.0;
        d.t_s.push(t);
        d.setpoint_m.push(if on { STEP_M } else { 0.0 });
        d.position_m.push(if on { STEP_M * r(s) } else { 0.0 });
        let chatter = if k % 2 == 0 { 0.1 } else { -0.1 };
        d.current_command_a
            .push(if on { 0.05 + chatter } else { chatter });
    }
    d
}

fn write_step(dir: &Path, name: &str, d: &Collected, a: &StepAnalysis) -> std::path::PathBuf {
    let um = |v: &[f64]| v.iter().map(|x| x * 1e6).collect::<Vec<f64>>();
    let path = dir.join(name);
    write_step_png(
        &path,
        Existing::Refuse,
        &StepPlot {
            title: "synthetic step",
            t_s: &d.t_s,
            setpoint_um: &um(&d.setpoint_m),
            position_um: &um(&d.position_m),
            smoothed_um: &um(&a.smoothed_position_m),
            command_a: &d.current_command_a,
            metrics: &a.metrics,
            events: &a.events,
        },
    )
    .unwrap();
    path
}

/// The zoom window of `write_step_png` in ms since the step, by its
/// documented rule.
fn zoom_ms(rise_s: f64, settle_s: f64, record_end_s: f64) -> (f64, f64) {
    let post = (2.0 * settle_s)
        .max(4.0 * rise_s)
        .max(20.0 * DT)
        .min(record_end_s - SETTLE_S);
    let pre = (post / 10.0).clamp(2.0 * DT, SETTLE_S);
    (-pre * 1e3, post * 1e3)
}

/// A first-order step: the rise markers at the 10 % and 90 % crossings and
/// the settling marker at the 2 % entry, where the analytic response puts
/// them in the zoom panel; no overshoot marker.
#[test]
fn step_plot_marks_rise_and_settling_where_the_response_has_them() {
    let tau = 0.01;
    let n = 6000;
    let d = record(n, |s| 1.0 - (-s / tau).exp());
    let a = step_analysis(&d, SETTLE_S, STEP_M, 0.2, DT);
    let dir = tempfile::tempdir().unwrap();
    let img = load(&write_step(dir.path(), "first.png", &d, &a), (1400, 1700));
    let f = frames(&img);
    assert_eq!(
        f.len(),
        5,
        "three overview panels and two zoom panels: {f:?}"
    );
    let zoom = f[3];

    let (t10, t90, ts) = (
        tau * (10.0f64 / 9.0).ln(),
        tau * 10f64.ln(),
        tau * 50f64.ln(),
    );
    // The window follows the metrics (rule as documented; they are checked
    // against τ ln 9 and τ ln 50 in jobs::control); the markers are placed by
    // the analytic response.
    let m = a.metrics;
    let (lo, hi) = zoom_ms(
        m.rise_time_s.unwrap(),
        m.settling_time_s.unwrap(),
        (n - 1) as f64 * DT,
    );
    let col = |s: f64| zoom.column(s * 1e3, lo, hi);
    // ±4 px: the metrics' 2 ms moving average and one-sample grid shift
    // crossings by well under 0.3 ms (4 px here).
    assert_markers_at(&img, &zoom, RISE_COLOR, &[col(t10), col(t90)], 4.0, "rise");
    assert_markers_at(&img, &zoom, SETTLE_COLOR, &[col(ts)], 4.0, "settling");
    let overshoot: usize = column_counts(&img, &zoom, OVERSHOOT_COLOR, 8)
        .iter()
        .map(|c| c.1)
        .sum();
    assert_eq!(overshoot, 0, "no overshoot marker without overshoot");
}

/// A second-order step (ζ = 0.3): the overshoot marker at the peak,
/// t_p = π/ω_d after the step.
#[test]
fn step_plot_marks_the_overshoot_at_the_peak() {
    let (wn, zeta) = (2.0 * PI * 20.0, 0.3);
    let wd = wn * (1.0f64 - zeta * zeta).sqrt();
    let n = 6000;
    let d = record(n, |s| {
        1.0 - (-zeta * wn * s).exp() * ((wd * s).cos() + zeta * wn / wd * (wd * s).sin())
    });
    let a = step_analysis(&d, SETTLE_S, STEP_M, 0.2, DT);
    let dir = tempfile::tempdir().unwrap();
    let img = load(&write_step(dir.path(), "second.png", &d, &a), (1400, 1700));
    let f = frames(&img);
    assert_eq!(f.len(), 5, "{f:?}");
    let zoom = f[3];
    // The window follows the metrics (rule as documented); the peak is
    // placed by the analytic response.
    let m = a.metrics;
    let (lo, hi) = zoom_ms(
        m.rise_time_s.unwrap(),
        m.settling_time_s.unwrap(),
        (n - 1) as f64 * DT,
    );
    let t_peak = PI / wd;
    assert_markers_at(
        &img,
        &zoom,
        OVERSHOOT_COLOR,
        &[zoom.column(t_peak * 1e3, lo, hi)],
        4.0,
        "overshoot",
    );
}

/// The command is drawn without gaps: in the overview (20 samples a pixel
/// column, chattering every sample) and in the zoom, every column between
/// the first and last sample holds the command, as one unbroken vertical
/// stretch.
#[test]
fn step_plot_draws_the_command_without_gaps() {
    let d = record(6000, |s| 1.0 - (-s / 0.01).exp());
    let a = step_analysis(&d, SETTLE_S, STEP_M, 0.2, DT);
    let dir = tempfile::tempdir().unwrap();
    let img = load(&write_step(dir.path(), "cmd.png", &d, &a), (1400, 1700));
    let f = frames(&img);
    // Green dominates: the command, anti-aliased edges included.
    let is_cmd = |p: [u8; 3]| {
        let (r, g, b) = (i32::from(p[0]), i32::from(p[1]), i32::from(p[2]));
        g > r + 30 && g > b + 30
    };
    assert!(is_cmd([COMMAND_COLOR.0, COMMAND_COLOR.1, COMMAND_COLOR.2]));
    for (which, frame) in [("overview", f[1]), ("zoom", f[4])] {
        let mut covered = 0;
        for x in frame.left + 3..frame.right - 2 {
            let rows: Vec<u32> = (frame.top + 1..frame.bottom)
                .filter(|&y| is_cmd(img.get_pixel(x, y).0))
                .collect();
            assert!(!rows.is_empty(), "{which}: no command in column {x}");
            let gaps: Vec<_> = rows.windows(2).filter(|w| w[1] - w[0] > 2).collect();
            assert!(gaps.is_empty(), "{which}: column {x} has gaps {gaps:?}");
            covered += 1;
        }
        assert!(covered > 1000, "{which}: {covered} columns");
    }
}

/// A smooth FRF on 10 Hz–1 kHz with one point at 500 Hz lifted by 120 dB
/// at coherence 0.02: the point is drawn faint, never in the measured
/// colour, and does not stretch the magnitude axis.
#[test]
fn bode_plot_draws_low_coherence_points_faint() {
    let n = 301;
    let f: Vec<f64> = (0..n)
        .map(|i| 10.0 * 100f64.powf(i as f64 / (n - 1) as f64))
        .collect();
    let spike = f.iter().position(|&x| x >= 500.0).unwrap();
    let mut mag: Vec<f64> = f.iter().map(|x| 1e-2 / (x * x)).collect();
    mag[spike] *= 1e6;
    let phase = vec![-180.0; n];
    let mut coh = vec![0.99; n];
    coh[spike] = 0.02;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("coh.png");
    let plot = BodePlot {
        title: "low coherence",
        magnitude_axis: bench::plot::MAGNITUDE_M_PER_A,
        measured: BodeSeries {
            label: "measured",
            frequency_hz: &f,
            magnitude: &mag,
            phase_deg: &phase,
        },
        coherence: &coh,
        model: None,
        markers_hz: &[],
        pair: None,
    };
    write_bode_png(&path, Existing::Refuse, &plot).unwrap();
    let img = load(&path, (1400, 1000));
    let fr = frames(&img);
    assert_eq!(fr.len(), 3, "magnitude, phase, coherence: {fr:?}");
    let magf = fr[0];
    let col = |hz: f64| magf.column(hz.log10(), 1.0, 3.0).round() as u32;
    let x = col(f[spike]);
    let count = |c: RGBColor, tol: i32, x0: u32, x1: u32| -> usize {
        column_counts(&img, &magf, c, tol)
            .iter()
            .filter(|(cx, _)| (x0..=x1).contains(cx))
            .map(|c| c.1)
            .sum()
    };
    // Grid points are 4.2 px apart here: the faint lines to the point and
    // back cross the columns around it, the measured ones stop a point
    // before.
    assert_eq!(
        count(MEASURED_COLOR, 40, x - 2, x + 2),
        0,
        "the low-coherence point is drawn in the measured colour"
    );
    assert!(
        count(FAINT_COLOR, 12, x - 4, x + 4) > 20,
        "the point is drawn faint"
    );
    // Elsewhere the curve is in the measured colour.
    assert!(count(MEASURED_COLOR, 40, col(100.0) - 1, col(100.0) + 1) > 0);
    // The axis is set by the good points (80 dB), not stretched to the
    // point 120 dB up: their curve reaches from near the top of the frame
    // to near its bottom.
    let rows: Vec<u32> = (magf.top + 1..magf.bottom)
        .filter(|&y| {
            (magf.left + 1..magf.right).any(|x| near(img.get_pixel(x, y).0, MEASURED_COLOR, 40))
        })
        .collect();
    let height = f64::from(magf.bottom - magf.top);
    let spread = f64::from(rows.last().unwrap() - rows.first().unwrap());
    assert!(spread > 0.75 * height, "{spread} of {height} px");
}

/// The pair zoom spans `lower − d … upper + d`, `d = upper − lower`, on a
/// linear axis, with the two modes marked where they lie; without a pair the
/// section is still drawn (a framed message).
#[test]
fn bode_plot_zooms_on_the_pair() {
    // Two lightly damped modes at 100 and 110 Hz.
    let n = 800;
    let f: Vec<f64> = (0..n)
        .map(|i| 10.0 * 100f64.powf(i as f64 / (n - 1) as f64))
        .collect();
    let h = |x: f64| {
        let mode = |fn_: f64, gain: f64| {
            let r = x / fn_;
            let (re, im) = (1.0 - r * r, 2.0 * 0.005 * r);
            let d = re * re + im * im;
            (gain * re / d, -gain * im / d)
        };
        let (a, b) = (mode(100.0, 1e-6), mode(110.0, -0.5e-6));
        (a.0 + b.0, a.1 + b.1)
    };
    let mag: Vec<f64> = f.iter().map(|&x| h(x).0.hypot(h(x).1)).collect();
    let phase: Vec<f64> = f
        .iter()
        .map(|&x| h(x).1.atan2(h(x).0).to_degrees())
        .collect();
    let coh = vec![0.99; n];
    let pair = PairVerdict {
        lower_hz: 100.0,
        upper_hz: 110.0,
        band_hz: (60.0, 300.0),
        net_phase_deg: -360.0,
        net_phase_multiple_deg: -360.0,
        cmp_cnmp: true,
    };
    let dir = tempfile::tempdir().unwrap();
    let base = BodePlot {
        title: "pair",
        magnitude_axis: bench::plot::MAGNITUDE_M_PER_A,
        measured: BodeSeries {
            label: "measured",
            frequency_hz: &f,
            magnitude: &mag,
            phase_deg: &phase,
        },
        coherence: &coh,
        model: None,
        markers_hz: &[100.0, 110.0],
        pair: Some(PairZoom::Resolved {
            pair,
            band_phase_deg: (0.0, -360.0),
        }),
    };
    let path = dir.path().join("pair.png");
    write_bode_png(&path, Existing::Refuse, &base).unwrap();
    let img = load(&path, (1400, 1650));
    let fr = frames(&img);
    assert_eq!(fr.len(), 5, "three main panels and two zoom panels: {fr:?}");
    for (i, zoom) in [fr[3], fr[4]].into_iter().enumerate() {
        let expected = [
            zoom.column(100.0, 90.0, 120.0),
            zoom.column(110.0, 90.0, 120.0),
        ];
        assert_markers_at(
            &img,
            &zoom,
            MARKER_COLOR,
            &expected,
            3.0,
            &format!("zoom panel {i}"),
        );
    }

    let path = dir.path().join("nopair.png");
    let plot = BodePlot {
        pair: Some(PairZoom::Unresolved {
            reason: "only one resonance was found (100.00 Hz)",
        }),
        ..base
    };
    write_bode_png(&path, Existing::Refuse, &plot).unwrap();
    let img = load(&path, (1400, 1650));
    let fr = frames(&img);
    assert_eq!(fr.len(), 4, "three main panels and the message box: {fr:?}");
    // The box holds text (dark pixels) and no curve.
    let b = fr[3];
    let dark = (b.top + 1..b.bottom)
        .flat_map(|y| (b.left + 1..b.right).map(move |x| (x, y)))
        .filter(|&(x, y)| img.get_pixel(x, y).0.iter().all(|&c| c < 100))
        .count();
    assert!(dark > 100, "{dark} dark pixels in the message box");
    assert_eq!(
        column_counts(&img, &b, MEASURED_COLOR, 40)
            .iter()
            .map(|c| c.1)
            .sum::<usize>(),
        0
    );
}
