//! Axis ranges, tick positions and number formatting: pure functions of
//! the data, no drawing. The model-analysis figures (`pole_zero.rs`,
//! `modes.rs`, `map.rs`) take their ranges from [`span`] and leave the
//! ticks to plotters.

use std::ops::Range;

/// Range of the finite `values`, widened to at least `min_span` (centred) and
/// then padded by `pad_frac` of the span on both sides. All-equal data gets a
/// span relative to its magnitude (or 2 around zero). `fallback` is used when
/// there is no finite value.
pub(super) fn padded_range(
    values: &[f64],
    pad_frac: f64,
    min_span: f64,
    fallback: Range<f64>,
) -> Range<f64> {
    let (lo, hi) = values
        .iter()
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    if lo > hi {
        return fallback;
    }
    let mid = 0.5 * lo + 0.5 * hi;
    let mut span = hi - lo;
    let degenerate = mid.abs() * 1e-9;
    let min_span = if span <= degenerate && min_span <= degenerate {
        // Constant data without a configured minimum span.
        if mid == 0.0 {
            2.0
        } else {
            mid.abs() * 0.2
        }
    } else {
        min_span.max(degenerate)
    };
    let (mut lo, mut hi) = (lo, hi);
    if span < min_span {
        lo = mid - 0.5 * min_span;
        hi = mid + 0.5 * min_span;
        span = min_span;
    }
    let pad = span * pad_frac;
    let r = (lo - pad)..(hi + pad);
    if r.start.is_finite() && r.end.is_finite() && r.start < r.end {
        r
    } else {
        fallback
    }
}

/// Smallest and largest positive finite value, if any.
pub(super) fn positive_extent(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && *v > 0.0)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    (lo <= hi).then_some((lo, hi))
}

/// Log-axis range spanning the positive finite `freqs`. A single frequency
/// (or a span under 1 %) gets a factor of two either side.
pub(super) fn log_range(freqs: impl Iterator<Item = f64>) -> Range<f64> {
    let Some((lo, hi)) = positive_extent(freqs) else {
        return 1.0..1000.0;
    };
    if hi / lo < 1.01 {
        let r = (lo / 2.0)..(hi * 2.0);
        if r.start > 0.0 && r.end.is_finite() {
            return r;
        }
        return 1.0..1000.0;
    }
    lo..hi
}

/// Labelled (bold) and grid-only (light) tick positions for a log axis:
/// decades when the range spans at least two, otherwise 1-2-5 or 1..9 per
/// decade, and a linear fallback for very narrow ranges.
pub(super) fn log_ticks(r: &Range<f64>) -> (Vec<f64>, Vec<f64>) {
    let (lo, hi) = (r.start, r.end);
    let d0 = lo.log10().floor() as i32;
    let d1 = hi.log10().ceil() as i32;
    let gen = |mantissas: &[f64]| -> Vec<f64> {
        let mut v = Vec::new();
        for d in d0..=d1 {
            let p = 10f64.powi(d);
            for &m in mantissas {
                let x = m * p;
                if x >= lo * (1.0 - 1e-9) && x <= hi * (1.0 + 1e-9) {
                    v.push(x);
                }
            }
        }
        v
    };
    let all: Vec<f64> = (1..=9).map(f64::from).collect();
    let mut bold = gen(&[1.0]);
    if bold.len() > 12 {
        let step = bold.len().div_ceil(10);
        bold = bold.into_iter().step_by(step).collect();
    }
    if bold.len() < 3 {
        bold = gen(&[1.0, 2.0, 5.0]);
    }
    if bold.len() < 3 {
        bold = gen(&all);
    }
    if bold.len() < 2 {
        bold = linear_ticks(r, 6);
    }
    let light = if hi / lo > 3.0 && d1 - d0 <= 30 {
        gen(&all)
    } else {
        Vec::new()
    };
    (bold, light)
}

/// "Nice" 1-2-5 step ticks inside `r`, at most about `max_n` of them.
pub(super) fn linear_ticks(r: &Range<f64>, max_n: usize) -> Vec<f64> {
    let span = r.end - r.start;
    if !(span > 0.0 && span.is_finite()) || max_n == 0 {
        return vec![r.start];
    }
    let raw = span / max_n as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let first = (r.start / step).ceil();
    let last = (r.end / step).floor();
    if !(first.is_finite() && last.is_finite()) || last - first > 1000.0 {
        return vec![r.start, r.end];
    }
    let (first, last) = (first as i64, last as i64);
    (first..=last).map(|k| k as f64 * step).collect()
}

/// Ticks at the multiples of `step` inside `r`.
pub(super) fn ticks_every(r: &Range<f64>, step: f64) -> Vec<f64> {
    let (first, last) = (
        (r.start / step).ceil() as i64,
        (r.end / step).floor() as i64,
    );
    (first..=last).map(|k| k as f64 * step).collect()
}

/// Phase ticks at multiples of 15, 45, 90, 180, 360, ... degrees.
pub(super) fn phase_ticks(r: &Range<f64>) -> Vec<f64> {
    let span = r.end - r.start;
    let mut step = 15.0;
    for s in [15.0, 45.0, 90.0, 180.0] {
        step = s;
        if span / s <= 8.0 {
            break;
        }
    }
    while span / step > 8.0 {
        step *= 2.0;
    }
    let first = (r.start / step).ceil() as i64;
    let last = (r.end / step).floor() as i64;
    let ticks: Vec<f64> = (first..=last).map(|k| k as f64 * step).collect();
    if ticks.len() < 2 {
        linear_ticks(r, 6)
    } else {
        ticks
    }
}

/// Formatter for the given ticks: fixed-point with as many decimals as the
/// tick spacing needs, or, for very large/small values, scientific notation
/// with one exponent shared by all ticks (e.g. `0.8e-5`, `1.0e-5`).
pub(super) fn tick_formatter(ticks: &[f64]) -> impl Fn(&f64) -> String {
    let step = ticks
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .fold(f64::INFINITY, f64::min);
    let step = if step.is_finite() && step > 0.0 {
        step
    } else {
        ticks.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1.0)
    };
    let max_abs = ticks.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let scientific = max_abs >= 1e6 || step < 1e-3;
    let step_exp = step.log10().floor();
    let decimals = (-step_exp).clamp(0.0, 12.0) as usize;
    let exp = if max_abs > 0.0 {
        max_abs.log10().floor()
    } else {
        0.0
    };
    let sci_decimals = (exp - step_exp).clamp(0.0, 12.0) as usize;
    move |v: &f64| {
        let v = *v;
        let is_zero = v.abs() < step * 1e-6;
        match (scientific, is_zero) {
            (true, true) => "0".to_string(),
            (true, false) => format!("{:.sci_decimals$}e{exp}", v / 10f64.powf(exp)),
            (false, true) => format!("{:.decimals$}", 0.0),
            (false, false) => format!("{v:.decimals$}"),
        }
    }
}

/// Formats an axis tick value with up to six significant digits, trimming
/// trailing zeros (e.g. `0.2`, `50`, `1000`).
pub(super) fn fmt_tick(v: f64) -> String {
    fmt_sig(v, 6)
}

/// Formats `v` with `sig` significant digits, trimming trailing zeros.
pub(super) fn fmt_sig(v: f64, sig: i32) -> String {
    if v == 0.0 || !v.is_finite() {
        return if v.is_finite() {
            "0".to_string()
        } else {
            v.to_string()
        };
    }
    let decimals = (sig - 1 - v.abs().log10().floor() as i32).clamp(0, 15) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// The range of the model-analysis figures: the extent of the finite
/// `values`, at least `min_span` wide, widened by `pad` of that width in
/// all (half each side) around its middle; `-1..1` without a finite value.
pub(super) fn span(values: impl Iterator<Item = f64>, pad: f64, min_span: f64) -> Range<f64> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return -1.0..1.0;
    }
    let s = (hi - lo).max(min_span);
    let mid = 0.5 * (lo + hi);
    (mid - 0.5 * s * (1.0 + pad))..(mid + 0.5 * s * (1.0 + pad))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plot_tick_helpers() {
        assert_eq!(log_ticks(&(1.0..1000.0)).0, vec![1.0, 10.0, 100.0, 1000.0]);
        let (bold, _) = log_ticks(&(20.0..80.0));
        assert_eq!(bold.len(), 7, "{bold:?}");
        let (bold, _) = log_ticks(&(5.0..300.0));
        assert_eq!(bold, vec![5.0, 10.0, 20.0, 50.0, 100.0, 200.0]);
        assert!(!log_ticks(&(101.0..107.0)).0.is_empty());
        assert_eq!(
            phase_ticks(&(-200.0..10.0)),
            vec![-180.0, -135.0, -90.0, -45.0, 0.0]
        );
        assert_eq!(fmt_tick(0.30000000000000004), "0.3");
        assert_eq!(fmt_tick(1000.0), "1000");
        assert_eq!(fmt_sig(70.9, 4), "70.9");
        assert_eq!(fmt_sig(1234.56, 4), "1235");
        let r = padded_range(&[5.0, 5.0], 0.0, 0.0, 0.0..1.0);
        assert!(r.start < 5.0 && r.end > 5.0);
        let r = padded_range(&[0.0], 0.05, 0.0, 0.0..1.0);
        assert!(r.start < 0.0 && r.end > 0.0);
        let f = tick_formatter(&[0.0, 0.2, 0.4]);
        assert_eq!(f(&0.4), "0.4");
        let f = tick_formatter(&[0.0, 5e-6, 1e-5]);
        assert_eq!(f(&5e-6), "0.5e-5");
        assert_eq!(f(&1e-5), "1.0e-5");
        assert_eq!(f(&0.0), "0");
    }
}
