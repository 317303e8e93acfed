//! The pair zoom of the Bode figure ([`PairZoom`]): magnitude and phase
//! on a linear frequency axis around the closely spaced pair, with the
//! phase at the band edges and the net phase and CMP-CNMP verdict written
//! above; or, when no pair was resolved, a framed panel saying why.

use std::ops::Range;

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::axes::{frame, linear_axis, mesh, panel_chart, plot_columns, X_LABEL_AREA};
use super::draw::{draw_runs, hline, runs, vline};
use super::legend::{
    draw_marker_labels, entry, header_height, header_lines, layout_marker_labels, legend_height,
    marker_row_height, panel_legend, Swatch,
};
use super::measured::{draw_measured, BodeCurves};
use super::palette::{BAND_END_COLOR, BAND_START_COLOR, MARKER_COLOR, MEASURED_COLOR, MODEL_COLOR};
use super::style::{FONT, HEADER_SIZE, LINE_WIDTH};
use super::ticks::{fmt_sig, linear_ticks, padded_range, phase_ticks, tick_formatter};
use super::{Area, BoxError};
use crate::ident::frf::PairVerdict;

/// The zoom on the closely spaced pair of a Bode figure.
#[derive(Debug, Clone, Copy)]
pub enum PairZoom<'a> {
    /// The pair the FRF analysis found
    /// ([`phase_test`](crate::ident::verdict::phase_test)).
    Resolved {
        /// Its modes, band, net phase and verdict.
        pair: PairVerdict,
        /// The measured phase at the two edges of `pair.band_hz`, degrees:
        /// the values whose difference is `pair.net_phase_deg`
        /// ([`Frf::phase_at_deg`](crate::ident::frf::Frf::phase_at_deg)).
        band_phase_deg: (f64, f64),
    },
    /// No pair was resolved; the panel shows why.
    Unresolved {
        /// The reason, e.g. from
        /// the phase test's reason ([`crate::ident::verdict::PhaseTest`]).
        reason: &'a str,
    },
}

impl<'a> PairZoom<'a> {
    /// The zoom for `test`'s pair on the measured `frf`, or, when it found
    /// none, the panel with `reason` (e.g. [`PairZoom::reason_of`]).
    pub fn of(
        test: &crate::ident::verdict::PhaseTest,
        frf: &crate::ident::frf::Frf,
        reason: &'a str,
    ) -> Self {
        match &test.pair {
            Some(p) => PairZoom::Resolved {
                pair: *p,
                band_phase_deg: (frf.phase_at_deg(p.band_hz.0), frf.phase_at_deg(p.band_hz.1)),
            },
            None => PairZoom::Unresolved { reason },
        }
    }

    /// Why `test` resolved no pair, for the panel.
    pub fn reason_of(test: &crate::ident::verdict::PhaseTest) -> String {
        test.reason
            .clone()
            .unwrap_or_else(|| "no closely spaced pair was fitted".to_string())
    }
}

/// The linear frequency window of the pair zoom (see
/// [`write_bode_png`](super::write_bode_png)), kept inside `x_range` when
/// the pair is.
pub(super) fn pair_window(pair: &PairVerdict, x_range: &Range<f64>) -> Range<f64> {
    let (lo, hi) = (
        pair.lower_hz.min(pair.upper_hz),
        pair.lower_hz.max(pair.upper_hz),
    );
    let d = (hi - lo).max(0.01 * lo.abs());
    let w = (lo - d)..(hi + d);
    let clipped = w.start.max(x_range.start)..w.end.min(x_range.end);
    if clipped.start < lo && clipped.end > hi {
        clipped
    } else if w.start < w.end && w.start.is_finite() && w.end.is_finite() {
        w
    } else {
        x_range.clone()
    }
}

/// Text of the CMP-CNMP verdict, as the summary prints it.
fn verdict_text(pair: &PairVerdict) -> &'static str {
    if pair.cmp_cnmp {
        "CMP-CNMP zeros: the pair shows the net −360° phase drop"
    } else {
        "no CMP-CNMP zeros: the zeros between the modes give back phase"
    }
}

/// What the pair zoom labels: the measured and model curves and the
/// magnitude axis (the Bode figure's).
pub(super) struct ZoomLabels<'a> {
    /// The measured curve's label.
    pub(super) measured: &'a str,
    /// The model curve's label (`None`: no model).
    pub(super) model: Option<&'a str>,
    /// The magnitude axis' label, with its unit.
    pub(super) magnitude_axis: &'a str,
}

/// The pair zoom on `area` (see [`write_bode_png`](super::write_bode_png)):
/// the header lines, then magnitude and phase over `window`.
pub(super) fn draw_pair_zoom(
    root: &Area<'_>,
    area: &Area<'_>,
    names: &ZoomLabels<'_>,
    c: &BodeCurves,
    pair: &PairVerdict,
    band_phase_deg: (f64, f64),
    window: &Range<f64>,
) -> Result<(), BoxError> {
    let area = area.margin(14, 0, 0, 0);
    let lines = [
        format!(
            "Closely spaced pair: {:.2} Hz and {:.2} Hz (zoom {}–{} Hz, shaded above)",
            pair.lower_hz,
            pair.upper_hz,
            fmt_sig(window.start, 4),
            fmt_sig(window.end, 4)
        ),
        format!(
            "Net phase over {:.1}–{:.1} Hz: {:.0}° (≈ {:.0}°) → {}",
            pair.band_hz.0,
            pair.band_hz.1,
            pair.net_phase_deg,
            pair.net_phase_multiple_deg,
            verdict_text(pair)
        ),
    ];
    let (head, panels) = area.split_vertically(header_height(lines.len()));
    header_lines(root, &head, &lines)?;

    let x_ticks = linear_ticks(window, 10);
    let x_fmt = tick_formatter(&x_ticks);
    let no_fmt = |_: &f64| String::new();
    let db_vals = BodeCurves::y_values(&c.meas_db, &c.good, &c.model_db, window);
    let mut phase_vals = BodeCurves::y_values(&c.meas_phase, &c.good, &c.model_phase, window);
    phase_vals.extend([band_phase_deg.0, band_phase_deg.1]);
    let db_range = padded_range(&db_vals, 0.08, 10.0, -100.0..0.0);
    let phase_range = padded_range(&phase_vals, 0.08, 45.0, -180.0..0.0);
    let modes = [pair.lower_hz, pair.upper_hz];

    let (px0, px1) = plot_columns(&panels);
    let span = window.end - window.start;
    let items = modes
        .iter()
        .map(|&f| (f, format!("{} Hz", fmt_sig(f, 4)), MARKER_COLOR))
        .collect();
    let (labels, rows) = layout_marker_labels(&panels, items, |f| {
        px0 + (f64::from(px1 - px0) * (f - window.start) / span) as i32
    })?;
    let mut mag_entries = vec![entry(
        format!("{}, a dot per grid point", names.measured),
        Swatch::Line(MEASURED_COLOR, LINE_WIDTH),
    )];
    if let Some(m) = names.model {
        mag_entries.push(entry(m, Swatch::Dashed(MODEL_COLOR)));
    }
    mag_entries.push(entry("modes of the pair", Swatch::Dashed(MARKER_COLOR)));
    let mag_top = legend_height(&panels, &mag_entries)?
        + 6
        + u32::try_from(rows)? * u32::try_from(marker_row_height())?;
    let phase_entries = [
        entry(
            format!(
                "φ({:.1} Hz) = {:.0}° (band start)",
                pair.band_hz.0, band_phase_deg.0
            ),
            Swatch::Dashed(BAND_START_COLOR),
        ),
        entry(
            format!(
                "φ({:.1} Hz) = {:.0}° (band end)",
                pair.band_hz.1, band_phase_deg.1
            ),
            Swatch::Dashed(BAND_END_COLOR),
        ),
        // The net phase of the summary, and how it follows from the two
        // values above: their difference less the known path's
        // (delay, hold, amplifier; `phase_test`).
        {
            let raw = band_phase_deg.1 - band_phase_deg.0;
            entry(
                format!(
                    "net phase {:.0}° = {:.0}° − {:.0}° of the path (delay, hold, amplifier)",
                    pair.net_phase_deg,
                    raw,
                    raw - pair.net_phase_deg
                ),
                Swatch::Text,
            )
        },
    ];
    let phase_top = legend_height(&panels, &phase_entries)? + 6;
    let (_, h) = panels.dim_in_pixel();
    let plot_h = f64::from(h.saturating_sub(X_LABEL_AREA + mag_top + phase_top + 10));
    let (mag_area, phase_area) = panels.split_vertically((plot_h * 0.5) as u32 + mag_top);

    {
        let y_ticks = linear_ticks(&db_range, 6);
        let y_fmt = tick_formatter(&y_ticks);
        let x = linear_axis(window, x_ticks.clone());
        let mut chart = panel_chart(&mag_area, x, &db_range, y_ticks, mag_top, false)?;
        mesh(&mut chart, None, names.magnitude_axis, &no_fmt, &y_fmt)?;
        for &f in &modes {
            vline(&mut chart, f, &db_range, MARKER_COLOR, 1)?;
        }
        draw_measured(&mut chart, &c.meas_db, &c.good, window, false, true)?;
        if names.model.is_some() {
            draw_runs(
                &mut chart,
                &runs(&c.model_db, window, false),
                MODEL_COLOR,
                true,
            )?;
        }
        frame(&chart)?;
        panel_legend(root, &mag_area, &chart, &mag_entries)?;
        draw_marker_labels(root, &chart, &labels, db_range.end)?;
    }
    {
        let y_ticks = phase_ticks(&phase_range);
        let y_fmt = tick_formatter(&y_ticks);
        let x = linear_axis(window, x_ticks.clone());
        let mut chart = panel_chart(&phase_area, x, &phase_range, y_ticks, phase_top, true)?;
        mesh(
            &mut chart,
            Some("Frequency [Hz]"),
            "Phase [°]",
            &x_fmt,
            &y_fmt,
        )?;
        for &f in &modes {
            vline(&mut chart, f, &phase_range, MARKER_COLOR, 1)?;
        }
        hline(&mut chart, band_phase_deg.0, window, BAND_START_COLOR)?;
        hline(&mut chart, band_phase_deg.1, window, BAND_END_COLOR)?;
        draw_measured(&mut chart, &c.meas_phase, &c.good, window, false, true)?;
        if names.model.is_some() {
            draw_runs(
                &mut chart,
                &runs(&c.model_phase, window, false),
                MODEL_COLOR,
                true,
            )?;
        }
        frame(&chart)?;
        panel_legend(root, &phase_area, &chart, &phase_entries)?;
    }
    Ok(())
}

/// The pair zoom when no pair was resolved: a framed panel saying why.
pub(super) fn draw_no_pair(root: &Area<'_>, area: &Area<'_>, reason: &str) -> Result<(), BoxError> {
    let area = area.margin(14, 0, 0, 0);
    let lines = ["Closely spaced pair: not resolved; CMP-CNMP verdict undetermined".to_string()];
    let (head, rest) = area.split_vertically(header_height(lines.len()));
    header_lines(root, &head, &lines)?;
    let (left, right) = plot_columns(&rest);
    let (_, top) = rest.get_base_pixel();
    let (_, h) = rest.dim_in_pixel();
    let bottom = top + i32::try_from(h.saturating_sub(X_LABEL_AREA + 10))?;
    root.draw(&Rectangle::new(
        [(left, top), (right, bottom)],
        BLACK.stroke_width(1),
    ))?;
    let style =
        TextStyle::from((FONT, HEADER_SIZE).into_font()).pos(Pos::new(HPos::Center, VPos::Center));
    let mid = (left + right) / 2;
    let y = (top + bottom) / 2;
    root.draw(&Text::new(
        "No closely spaced pair was resolved:".to_string(),
        (mid, y - 16),
        style.clone(),
    ))?;
    root.draw(&Text::new(reason.to_string(), (mid, y + 16), style))?;
    Ok(())
}
