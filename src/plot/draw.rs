//! Drawing curves and guides on a panel. Non-finite samples (and, on a log
//! axis, non-positive x) break a curve into runs instead of failing; runs
//! are clipped to the x range, time series are first reduced to the first,
//! lowest, highest and last sample of each pixel column (the same
//! picture), and lines are drawn segment by segment: plotters fills a wide
//! polyline as one polygon, which leaves holes where a dense trace turns
//! back on itself. Also the dashed guide lines and translucent shading.

use std::ops::Range;

use plotters::coord::ranged1d::Ranged;
use plotters::prelude::*;

use super::axes::Chart;
use super::style::LINE_WIDTH;
use super::BoxError;

/// `(x, y)` pairs of two columns (the shorter one sets the length).
pub(super) fn pairs(x: &[f64], y: &[f64]) -> Vec<(f64, f64)> {
    x.iter().copied().zip(y.iter().copied()).collect()
}

/// Splits `points` at invalid samples (non-finite, or non-positive x for a
/// log axis) and clips the runs to `x_range` (interpolating at the edges,
/// linearly in log x for a log axis). Returns the drawable runs.
pub(super) fn runs(
    points: &[(f64, f64)],
    x_range: &Range<f64>,
    log_x: bool,
) -> Vec<Vec<(f64, f64)>> {
    split_and_clip(points, x_range, None, log_x)
}

/// [`runs`] on linear axes, clipped to the box `x_range` × `y_range`: a
/// curve that leaves the box (a loop going to infinity) is cut at its edge.
pub(super) fn runs_in_box(
    points: &[(f64, f64)],
    x_range: &Range<f64>,
    y_range: &Range<f64>,
) -> Vec<Vec<(f64, f64)>> {
    split_and_clip(points, x_range, Some(y_range), false)
}

/// [`runs`], also clipped to `y_range` when given.
fn split_and_clip(
    points: &[(f64, f64)],
    x_range: &Range<f64>,
    y_range: Option<&Range<f64>>,
    log_x: bool,
) -> Vec<Vec<(f64, f64)>> {
    let mut out = Vec::new();
    let mut cur = Vec::new();
    for &(x, y) in points {
        if x.is_finite() && y.is_finite() && (!log_x || x > 0.0) {
            cur.push((x, y));
        } else if !cur.is_empty() {
            out.extend(clip(&std::mem::take(&mut cur), x_range, y_range, log_x));
        }
    }
    if !cur.is_empty() {
        out.extend(clip(&cur, x_range, y_range, log_x));
    }
    out
}

/// The part `(t0, t1)` of the segment from `a` to `a + d` (parameter 0 to
/// 1) inside `lo..=hi` (Liang–Barsky, one coordinate); `t0 > t1` when none.
fn clip_param(a: f64, d: f64, lo: f64, hi: f64, (t0, t1): (f64, f64)) -> (f64, f64) {
    if d == 0.0 {
        if a < lo || a > hi {
            (1.0, 0.0)
        } else {
            (t0, t1)
        }
    } else {
        let (ta, tb) = ((lo - a) / d, (hi - a) / d);
        (t0.max(ta.min(tb)), t1.min(ta.max(tb)))
    }
}

/// Clips a polyline of finite points to `x_range` (and `y_range`).
fn clip(
    seg: &[(f64, f64)],
    x_range: &Range<f64>,
    y_range: Option<&Range<f64>>,
    log_x: bool,
) -> Vec<Vec<(f64, f64)>> {
    let tx = |x: f64| if log_x { x.ln() } else { x };
    let untx = |x: f64| if log_x { x.exp() } else { x };
    let (lo, hi) = (tx(x_range.start), tx(x_range.end));
    let in_y = |y: f64| y_range.is_none_or(|r| y >= r.start && y <= r.end);
    if seg.len() == 1 {
        let x = tx(seg[0].0);
        return if x >= lo && x <= hi && in_y(seg[0].1) {
            vec![seg.to_vec()]
        } else {
            Vec::new()
        };
    }
    let mut out = Vec::new();
    let mut cur: Vec<(f64, f64)> = Vec::new();
    for w in seg.windows(2) {
        let (a, b) = (w[0], w[1]);
        let (xa, xb) = (tx(a.0), tx(b.0));
        let dx = xb - xa;
        let dy = b.1 - a.1;
        let mut t = clip_param(xa, dx, lo, hi, (0.0, 1.0));
        if let Some(r) = y_range {
            t = clip_param(a.1, dy, r.start, r.end, t);
        }
        let (t0, t1) = t;
        if t0 > t1 {
            if !cur.is_empty() {
                out.push(std::mem::take(&mut cur));
            }
            continue;
        }
        let at = |t: f64| {
            if t <= 0.0 {
                a
            } else if t >= 1.0 {
                b
            } else {
                (untx(xa + t * dx), a.1 + t * dy)
            }
        };
        let (p0, p1) = (at(t0), at(t1));
        if cur.last() != Some(&p0) {
            if !cur.is_empty() {
                out.push(std::mem::take(&mut cur));
            }
            cur.push(p0);
        }
        cur.push(p1);
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    out
}

/// Samples as held from each sample time to the next (zero-order hold):
/// `(t_k, v_k), (t_{k+1}, v_k), (t_{k+1}, v_{k+1}), …`. A non-finite value
/// breaks the line for its period.
pub(super) fn staircase(t: &[f64], v: &[f64]) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(2 * t.len());
    for k in 0..t.len().min(v.len()) {
        out.push((t[k], v[k]));
        if let Some(&next) = t.get(k + 1) {
            out.push((next, v[k]));
        }
    }
    out
}

/// Reduces a polyline whose x does not decrease to the first, lowest,
/// highest and last point of each of `columns` equal slices of `x_range`
/// (one per pixel column): the same picture with at most four points per
/// column.
pub(super) fn decimate(
    pts: &[(f64, f64)],
    x_range: &Range<f64>,
    columns: usize,
) -> Vec<(f64, f64)> {
    let span = x_range.end - x_range.start;
    if pts.len() <= 4 * columns.max(1) || span.is_nan() || span <= 0.0 {
        return pts.to_vec();
    }
    let col = |x: f64| ((x - x_range.start) / span * columns as f64).floor() as i64;
    let mut out = Vec::with_capacity(4 * columns + 4);
    let mut i = 0;
    while i < pts.len() {
        let c = col(pts[i].0);
        let (mut lo, mut hi, mut j) = (i, i, i);
        while j < pts.len() && col(pts[j].0) == c {
            if pts[j].1 < pts[lo].1 {
                lo = j;
            }
            if pts[j].1 > pts[hi].1 {
                hi = j;
            }
            j += 1;
        }
        let mut keep = [i, lo, hi, j - 1];
        keep.sort_unstable();
        let mut last = usize::MAX;
        for k in keep {
            if k != last {
                out.push(pts[k]);
                last = k;
            }
        }
        i = j;
    }
    out
}

/// Draws a polyline segment by segment (a single point as a dot). A wide
/// polyline drawn in one piece is filled by plotters as one polygon, which
/// leaves holes where the trace turns back on itself.
pub(super) fn draw_polyline<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    pts: &[(f64, f64)],
    color: RGBColor,
    width: u32,
) -> Result<(), BoxError> {
    match pts.len() {
        0 => {}
        1 => {
            chart.draw_series(std::iter::once(Circle::new(pts[0], 3, color.filled())))?;
        }
        _ => {
            let style = color.stroke_width(width);
            chart.draw_series(
                pts.windows(2)
                    .map(|w| PathElement::new(vec![w[0], w[1]], style)),
            )?;
        }
    }
    Ok(())
}

/// Draws `pts` (linear x) split at invalid points, clipped to `x_range` and
/// decimated to the panel's pixel columns.
pub(super) fn draw_trace<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    pts: &[(f64, f64)],
    x_range: &Range<f64>,
    color: RGBColor,
    width: u32,
) -> Result<(), BoxError> {
    let (xs, _) = chart.plotting_area().get_pixel_range();
    let columns = usize::try_from(xs.end - xs.start).unwrap_or(1).max(1);
    for run in runs(pts, x_range, false) {
        draw_polyline(chart, &decimate(&run, x_range, columns), color, width)?;
    }
    Ok(())
}

/// Draws the runs of a curve, dashed or solid.
pub(super) fn draw_runs<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    runs: &[Vec<(f64, f64)>],
    color: RGBColor,
    dashed: bool,
) -> Result<(), BoxError> {
    for run in runs {
        if dashed && run.len() > 1 {
            let style = color.stroke_width(LINE_WIDTH);
            chart.draw_series(DashedLineSeries::new(run.iter().copied(), 10, 6, style))?;
        } else {
            draw_polyline(chart, run, color, LINE_WIDTH)?;
        }
    }
    Ok(())
}

/// A vertical dashed line across `y_range` at `x`.
pub(super) fn vline<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    x: f64,
    y_range: &Range<f64>,
    color: RGBColor,
    width: u32,
) -> Result<(), BoxError> {
    chart.draw_series(DashedLineSeries::new(
        [(x, y_range.start), (x, y_range.end)],
        8,
        5,
        color.stroke_width(width),
    ))?;
    Ok(())
}

/// A horizontal dashed line across `x_range` at `y`.
pub(super) fn hline<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    y: f64,
    x_range: &Range<f64>,
    color: RGBColor,
) -> Result<(), BoxError> {
    chart.draw_series(DashedLineSeries::new(
        [(x_range.start, y), (x_range.end, y)],
        8,
        5,
        color.stroke_width(LINE_WIDTH),
    ))?;
    Ok(())
}

/// A translucent band from `x` to `x` and `y` to `y` (any order).
pub(super) fn shade<X: Ranged<ValueType = f64>>(
    chart: &mut Chart<'_, '_, X>,
    x: (f64, f64),
    y: (f64, f64),
    color: RGBColor,
    alpha: f64,
) -> Result<(), BoxError> {
    let (x0, x1) = (x.0.min(x.1), x.0.max(x.1));
    let (y0, y1) = (y.0.min(y.1), y.0.max(y.1));
    chart.draw_series(std::iter::once(Rectangle::new(
        [(x0, y1), (x1, y0)],
        color.mix(alpha).filled(),
    )))?;
    Ok(())
}

/// The values of `pts` whose x lies in `x_range`.
pub(super) fn values_in<'p>(
    pts: &'p [(f64, f64)],
    x_range: &Range<f64>,
) -> impl Iterator<Item = f64> + 'p {
    let r = x_range.clone();
    pts.iter()
        .filter(move |p| p.0 >= r.start && p.0 <= r.end && p.1.is_finite())
        .map(|p| p.1)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first, lowest, highest and last point of each column survive,
    /// in order; short series are left alone.
    #[test]
    fn plot_decimate_keeps_the_envelope_in_order() {
        let pts: Vec<(f64, f64)> = (0..1000)
            .map(|i| {
                (
                    f64::from(i) * 0.001,
                    if i == 503 { 9.0 } else { f64::from(i % 7) },
                )
            })
            .collect();
        let d = decimate(&pts, &(0.0..1.0), 10);
        assert!(d.len() <= 40, "{}", d.len());
        assert!(d.windows(2).all(|w| w[0].0 <= w[1].0), "order kept");
        assert_eq!(d.first(), pts.first());
        assert_eq!(d.last(), pts.last());
        assert!(d.contains(&(0.503, 9.0)), "the spike survives");
        // Each column keeps its own minimum (0) and maximum (6 or the spike).
        for c in 0..10 {
            let col: Vec<f64> = d
                .iter()
                .filter(|p| (p.0 * 10.0).floor() as i32 == c)
                .map(|p| p.1)
                .collect();
            assert!(col.contains(&0.0), "column {c}: {col:?}");
            assert!(col.iter().any(|&v| v >= 6.0), "column {c}: {col:?}");
        }
        assert_eq!(decimate(&pts[..30], &(0.0..1.0), 10), pts[..30].to_vec());
    }

    /// A curve through the box is cut at its edges; one that leaves and
    /// comes back is two runs.
    #[test]
    fn plot_runs_in_box_cut_at_the_edges() {
        let b = -1.0..1.0;
        let r = runs_in_box(&[(-10.0, -10.0), (10.0, 10.0)], &b, &b);
        assert_eq!(r, vec![vec![(-1.0, -1.0), (1.0, 1.0)]]);
        let pts = [
            (0.0, 0.0),
            (0.0, 4.0),
            (0.5, 0.5),
            (f64::NAN, 0.0),
            (0.2, 0.2),
        ];
        let r = runs_in_box(&pts, &b, &b);
        assert_eq!(r.len(), 3, "{r:?}");
        assert_eq!(r[0], vec![(0.0, 0.0), (0.0, 1.0)]);
        // Back in where y = 1: t = 3/3.5 along (0, 4) → (0.5, 0.5).
        assert!((r[1][0].0 - 3.0 / 7.0).abs() < 1e-12 && r[1][0].1 == 1.0);
        assert_eq!(&r[1][1..], &[(0.5, 0.5)]);
        assert_eq!(r[2], vec![(0.2, 0.2)]);
        assert!(runs_in_box(&[(5.0, 0.0), (5.0, 1.0)], &b, &b).is_empty());
    }

    #[test]
    fn plot_staircase_holds_each_sample_until_the_next() {
        let t = [0.0, 1.0, 2.0, 3.0];
        let v = [5.0, 6.0, f64::NAN, 8.0];
        let s = staircase(&t, &v);
        assert_eq!(&s[..4], &[(0.0, 5.0), (1.0, 5.0), (1.0, 6.0), (2.0, 6.0)]);
        assert!(s[4].1.is_nan() && s[5].1.is_nan());
        assert_eq!(s[6], (3.0, 8.0));
        assert_eq!(s.len(), 7);
        // The NaN period breaks the line into two runs.
        assert_eq!(runs(&s, &(0.0..3.0), false).len(), 2);
    }
}
