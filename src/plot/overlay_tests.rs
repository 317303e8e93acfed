//! The overlay figures as files: their size (the legend's rows by the
//! documented layout), each trace in its colour where its data lies, the
//! faint points, the pair window's union rule, the Nyquist plane's equal
//! scales (an exact circle stays round), the palettes, and invalid data.

use super::palette::{FAINT_COLOR, MODEL_COLOR, OVERLAY_QUALITATIVE};
use super::*;
use crate::ident::frf::{unwrap_deg, Frf, PairVerdict, C64};
use crate::outputs::Existing;
use image::RgbImage;
use plotters::style::RGBColor;
use std::f64::consts::PI;

/// An FRF on `f` of the response `h` with coherence `coh`.
fn frf(f: &[f64], h: impl Fn(f64) -> C64, coh: impl Fn(f64) -> f64) -> Frf {
    let mut out = Frf::empty();
    for &x in f {
        let v = h(x);
        out.push_checked([
            x,
            v.norm(),
            v.arg().to_degrees(),
            coh(x),
            f64::NAN,
            f64::NAN,
            f64::NAN,
        ])
        .unwrap();
    }
    unwrap_deg(&mut out.phase_deg);
    out
}

fn log_grid(n: usize, f0: f64, f1: f64) -> Vec<f64> {
    (0..n)
        .map(|i| f0 * (f1 / f0).powf(i as f64 / (n - 1) as f64))
        .collect()
}

/// Two lightly damped modes at `a` and `b` Hz (compliance, m/A).
fn two_modes(a: f64, b: f64, sign: f64) -> impl Fn(f64) -> C64 {
    move |x: f64| {
        let mode = |fn_: f64, gain: f64| {
            let r = x / fn_;
            gain / C64::new(1.0 - r * r, 2.0 * 0.005 * r)
        };
        mode(a, 1e-6) + mode(b, sign * 0.5e-6)
    }
}

fn pair(lower_hz: f64, upper_hz: f64) -> PairVerdict {
    PairVerdict {
        lower_hz,
        upper_hz,
        band_hz: (0.8 * lower_hz, 1.2 * upper_hz),
        net_phase_deg: -360.0,
        net_phase_multiple_deg: -360.0,
        cmp_cnmp: true,
    }
}

fn near(p: [u8; 3], c: RGBColor, tol: i32) -> bool {
    (i32::from(p[0]) - i32::from(c.0)).abs() <= tol
        && (i32::from(p[1]) - i32::from(c.1)).abs() <= tol
        && (i32::from(p[2]) - i32::from(c.2)).abs() <= tol
}

/// A panel frame, edges inclusive.
#[derive(Debug, Clone, Copy)]
struct Frame {
    left: u32,
    right: u32,
    top: u32,
    bottom: u32,
}

/// The frames in columns `x0..x1`: rows with a black run over half that
/// width are edges (rows within 2 px count as one), in pairs.
fn frames(img: &RgbImage, x0: u32, x1: u32) -> Vec<Frame> {
    let mut edges: Vec<(u32, u32, u32)> = Vec::new();
    for y in 0..img.height() {
        let (mut best, mut start, mut span) = (0, None, (0, 0));
        for x in x0..=x1 {
            let black = x < x1 && img.get_pixel(x, y).0 == [0, 0, 0];
            match (black, start) {
                (true, None) => start = Some(x),
                (false, Some(s)) => {
                    if x - s > best {
                        best = x - s;
                        span = (s, x - 1);
                    }
                    start = None;
                }
                _ => {}
            }
        }
        if best >= (x1 - x0) / 2 && edges.last().is_none_or(|e| y > e.0 + 2) {
            edges.push((y, span.0, span.1));
        }
    }
    assert!(
        edges.len().is_multiple_of(2),
        "unpaired frame edges {edges:?}"
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

/// Pixels of colour `c` (±`tol`) strictly inside `f`, in columns `cols`.
fn count_in(img: &RgbImage, f: &Frame, cols: std::ops::Range<u32>, c: RGBColor, tol: i32) -> usize {
    let cols = cols.start.max(f.left + 1)..cols.end.min(f.right);
    cols.map(|x| {
        (f.top + 1..f.bottom)
            .filter(|&y| near(img.get_pixel(x, y).0, c, tol))
            .count()
    })
    .sum()
}

/// The column of `hz` on a log axis `lo..hi` over `f`.
fn log_col(f: &Frame, hz: f64, lo: f64, hi: f64) -> u32 {
    let t = (hz / lo).ln() / (hi / lo).ln();
    (f64::from(f.left) + t * f64::from(f.right - f.left)).round() as u32
}

/// Three FRFs, two with a pair (100/110 Hz and 120/125 Hz), one with its
/// coherence at 0.2 above 500 Hz, and a model.
struct Three {
    frfs: Vec<Frf>,
    pairs: Vec<Option<PairVerdict>>,
    model_f: Vec<f64>,
    model_h: Vec<C64>,
}

fn three() -> Three {
    let f = log_grid(800, 10.0, 1000.0);
    let frfs = vec![
        frf(&f, two_modes(100.0, 110.0, -1.0), |_| 0.99),
        frf(&f, two_modes(120.0, 125.0, 1.0), |_| 0.99),
        frf(
            &f,
            |x| two_modes(200.0, 300.0, 1.0)(x) * 3.0,
            |x| if x > 500.0 { 0.2 } else { 0.99 },
        ),
    ];
    let model_f = log_grid(4000, 10.0, 1000.0);
    let model_h = model_f
        .iter()
        .map(|&x| two_modes(100.0, 110.0, -1.0)(x) * 0.5)
        .collect();
    Three {
        frfs,
        pairs: vec![Some(pair(100.0, 110.0)), Some(pair(120.0, 125.0)), None],
        model_f,
        model_h,
    }
}

const LEGENDS: [&str; 3] = ["first: CMP-CNMP", "second: CMP-CNMP", "third: undecided"];

fn traces<'a>(t: &'a Three, modes: &'a [f64]) -> Vec<OverlayTrace<'a>> {
    t.frfs
        .iter()
        .enumerate()
        .map(|(i, f)| OverlayTrace {
            legend: LEGENDS[i],
            legend_short: LEGENDS[i],
            frf: f,
            color: OVERLAY_QUALITATIVE[i],
            pair: t.pairs[i],
            modes_hz: modes,
        })
        .collect()
}

fn plot_of<'a>(t: &'a Three, traces: &'a [OverlayTrace<'a>]) -> OverlayPlot<'a> {
    OverlayPlot {
        title: "three",
        traces,
        colors_note: None,
        model: Some(OverlayModel {
            label: "model",
            frequency_hz: &t.model_f,
            response_m_per_a: &t.model_h,
        }),
    }
}

/// The pair window is the union of each pair's `lower − d … upper + d`,
/// `d = max(upper − lower, 1 % of lower)`: 90–120 Hz and 115–130 Hz give
/// 90–130 Hz; the band is every trace's.
#[test]
fn overlay_pair_window_is_the_union_of_the_pairs_windows() {
    let t = three();
    let tr = traces(&t, &[]);
    let plot = plot_of(&t, &tr);
    assert_eq!(plot.band_hz(), 10.0..1000.0);
    let w = plot.pair_zoom_hz().unwrap();
    assert!(
        (w.start - 90.0).abs() < 1e-9 && (w.end - 130.0).abs() < 1e-9,
        "{w:?}"
    );
    let none: Vec<OverlayTrace<'_>> = tr
        .iter()
        .map(|x| OverlayTrace { pair: None, ..*x })
        .collect();
    assert_eq!(plot_of(&t, &none).pair_zoom_hz(), None);
}

/// Each trace in its colour on the magnitude panel and, for the two with
/// a pair, in the zoom; the third's points above 500 Hz (coherence 0.2)
/// only faint; the model drawn; each pair's modes marked ▼ at the top of
/// the zoom where its frequencies map; the height is the Bode figure's
/// 1650 px plus a 24 px legend row per trace and 8 px.
#[test]
fn overlay_bode_draws_each_trace_in_its_colour() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bode.png");
    let t = three();
    let tr = traces(&t, &[]);
    write_bode_overlay_png(&path, Existing::Refuse, &plot_of(&t, &tr)).unwrap();
    let img = image::open(&path).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (1400, 1650 + 3 * 24 + 8));
    let fr = frames(&img, 0, 1400);
    assert_eq!(fr.len(), 5, "magnitude, phase, coherence, zoom ×2: {fr:?}");
    let mag = fr[0];
    let all = 0..1400;
    for (i, c) in OVERLAY_QUALITATIVE[..3].iter().enumerate() {
        assert!(count_in(&img, &mag, all.clone(), *c, 6) > 100, "trace {i}");
    }
    assert!(
        count_in(&img, &mag, all.clone(), MODEL_COLOR, 6) > 50,
        "model"
    );
    // Above 500 Hz the third trace is faint only.
    let (lo, hi) = (log_col(&mag, 520.0, 10.0, 1000.0), mag.right);
    let third = OVERLAY_QUALITATIVE[2];
    assert_eq!(count_in(&img, &mag, lo..hi, third, 30), 0);
    assert!(count_in(&img, &mag, lo..hi, faint(third), 6) > 50);
    // The zoom: the two traces with a pair, and their ▼ at the top.
    let zoom = fr[3];
    for c in &OVERLAY_QUALITATIVE[..2] {
        assert!(count_in(&img, &zoom, all.clone(), *c, 6) > 100);
    }
    let col = |hz: f64| {
        (f64::from(zoom.left) + (hz - 90.0) / 40.0 * f64::from(zoom.right - zoom.left)).round()
            as u32
    };
    for (hz, c) in [
        (100.0, OVERLAY_QUALITATIVE[0]),
        (110.0, OVERLAY_QUALITATIVE[0]),
        (120.0, OVERLAY_QUALITATIVE[1]),
        (125.0, OVERLAY_QUALITATIVE[1]),
    ] {
        let x = col(hz);
        let marked = (zoom.top + 2..zoom.top + 8)
            .filter(|&y| near(img.get_pixel(x, y).0, c, 6))
            .count();
        assert!(marked >= 4, "no ▼ of {c:?} at {hz} Hz (column {x})");
    }
}

/// The Nyquist plane has equal scales: an exact circle (coherence 0.2,
/// so drawn faint, with no arrow) has a square bounding box, and spans
/// most of the panel.
#[test]
fn overlay_nyquist_keeps_a_circle_round() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nyquist.png");
    let f = log_grid(600, 1.0, 100.0);
    let n = f.len();
    let centre = C64::new(2e-3, -1e-3);
    let h: Vec<C64> = (0..n)
        .map(|i| centre + C64::from_polar(1e-3, -2.0 * PI * 0.97 * i as f64 / (n - 1) as f64))
        .collect();
    let mut fr = Frf::empty();
    for (x, v) in f.iter().zip(&h) {
        fr.push_checked([
            *x,
            v.norm(),
            v.arg().to_degrees(),
            0.2,
            f64::NAN,
            f64::NAN,
            f64::NAN,
        ])
        .unwrap();
    }
    unwrap_deg(&mut fr.phase_deg);
    let traces = [OverlayTrace {
        legend: "circle",
        legend_short: "circle",
        frf: &fr,
        color: OVERLAY_QUALITATIVE[0],
        pair: None,
        modes_hz: &[],
    }];
    let plot = OverlayPlot {
        title: "",
        traces: &traces,
        colors_note: None,
        model: None,
    };
    write_nyquist_png(&path, Existing::Refuse, &plot).unwrap();
    let img = image::open(&path).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (1400, 860 + 24 + 8));
    let fr = frames(&img, 0, 700);
    assert_eq!(fr.len(), 1, "{fr:?}");
    let p = fr[0];
    let mut xs = Vec::new();
    let mut ys = Vec::new();
    for y in p.top + 2..p.bottom - 1 {
        for x in p.left + 2..p.right - 1 {
            let px = img.get_pixel(x, y).0;
            assert!(
                !near(px, OVERLAY_QUALITATIVE[0], 30),
                "a solid pixel at ({x}, {y})"
            );
            if near(px, FAINT_COLOR, 6) {
                xs.push(x);
                ys.push(y);
            }
        }
    }
    let w = f64::from(xs.iter().max().unwrap() - xs.iter().min().unwrap());
    let hgt = f64::from(ys.iter().max().unwrap() - ys.iter().min().unwrap());
    assert!((w - hgt).abs() <= 3.0, "{w} × {hgt} px");
    assert!(w > 0.8 * f64::from(p.right - p.left), "{w} px");
}

/// The legend's rows: up to 12 traces one each (two when the entry wraps),
/// the colours' note one; more traces in two columns up to 48.
#[test]
fn overlay_legend_rows_set_the_height() {
    let dir = tempfile::tempdir().unwrap();
    let t = three();
    let f = &t.frfs[0];
    let long = "a long verdict ".repeat(20);
    let make = |n: usize, legend: &'static str| -> Vec<OverlayTrace<'_>> {
        (0..n)
            .map(|i| OverlayTrace {
                legend,
                legend_short: "short",
                frf: f,
                color: viridis(i as f64 / n as f64),
                pair: None,
                modes_hz: &[],
            })
            .collect()
    };
    let long: &'static str = Box::leak(long.into_boxed_str());
    // Words wider than a line: each cut to it.
    let word: &'static str = Box::leak("x".repeat(300).into_boxed_str());
    let words: &'static str = Box::leak(format!("{word} {word} {word}").into_boxed_str());
    for (k, (n, legend, note, rows)) in [
        (1, "one", None, 1),
        (1, long, None, 2),
        (1, word, None, 1),
        (1, words, None, 2),
        (12, "one", Some("colours"), 13),
        (20, "one", None, 10),
        (20, "one", Some("colours"), 11),
        (60, "one", None, 20),
    ]
    .into_iter()
    .enumerate()
    {
        let traces = make(n, legend);
        let plot = OverlayPlot {
            title: "",
            traces: &traces,
            colors_note: note,
            model: None,
        };
        let path = dir.path().join(format!("{k}.png"));
        write_bode_overlay_png(&path, Existing::Refuse, &plot).unwrap();
        let img = image::open(&path).unwrap();
        assert_eq!(
            (img.width(), img.height()),
            (1400, 1650 + rows * 24 + 8),
            "{n} traces, {rows} rows"
        );
    }
}

/// No trace, too many, columns of unequal lengths: refused naming the
/// problem, nothing written.
#[test]
fn overlay_invalid_data_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let t = three();
    let mut short = t.frfs[0].clone();
    short.coherence.pop();
    let ok = traces(&t, &[]);
    let bad_len = [OverlayTrace {
        frf: &short,
        ..ok[0]
    }];
    let many: Vec<OverlayTrace<'_>> = (0..MAX_OVERLAY_TRACES + 1).map(|_| ok[0]).collect();
    let h1 = [C64::new(1.0, 0.0)];
    for (traces, model, what) in [
        (&[][..], None, "0 traces"),
        (&many[..], None, "201 traces"),
        (&bad_len[..], None, "coherences"),
        (
            &ok[..],
            Some(OverlayModel {
                label: "m",
                frequency_hz: &[1.0, 2.0],
                response_m_per_a: &h1,
            }),
            "model",
        ),
    ] {
        let plot = OverlayPlot {
            title: "",
            traces,
            colors_note: None,
            model,
        };
        for nyquist in [false, true] {
            let path = dir.path().join("x.png");
            let e = if nyquist {
                write_nyquist_png(&path, Existing::Refuse, &plot)
            } else {
                write_bode_overlay_png(&path, Existing::Refuse, &plot)
            }
            .unwrap_err();
            assert!(
                matches!(&e, PlotError::InvalidData { reason, .. } if reason.contains(what)),
                "{what}: {e}"
            );
            assert!(!path.exists());
        }
    }
}

/// The palettes: the faint colour of the measured blue is the Bode
/// figure's; viridis passes through matplotlib's published values (at 0,
/// 0.1, …; `python3 -c "import matplotlib; print(matplotlib.colormaps
/// ['viridis'](0.5))"`); the colours of an overlay are all different.
#[test]
fn overlay_palettes() {
    assert_eq!(faint(MEASURED_COLOR), FAINT_COLOR);
    let at = |t: f64| viridis(t / 0.85);
    assert_eq!(at(0.0), RGBColor(0x44, 0x01, 0x54));
    assert_eq!(at(0.5), RGBColor(0x21, 0x91, 0x8c));
    assert_eq!(at(0.8), RGBColor(0x7a, 0xd1, 0x51));
    assert_eq!(viridis(2.0), at(0.85));
    for (palette, n) in [
        (OverlayPalette::Qualitative, 8),
        (OverlayPalette::Sequential, 2),
        (OverlayPalette::Sequential, 150),
    ] {
        let c = overlay_colors(palette, n);
        assert_eq!(c.len(), n);
        for i in 0..n {
            for j in 0..i {
                assert_ne!(c[i], c[j], "{palette:?} {n}: {i} and {j}");
            }
            assert_ne!(c[i], MODEL_COLOR);
        }
    }
}
