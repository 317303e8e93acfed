//! What the two overlay figures share ([`write_bode_overlay_png`] in
//! `bode_overlay.rs`, [`write_nyquist_png`] in `nyquist.rs`): the traces
//! and the model they draw ([`OverlayPlot`]), the checks of that data, the
//! legend of the traces (a table above the panels, as tall as it needs to
//! be: one row or two per trace, or columns for many) and the frequency
//! band and pair window they share.
//!
//! [`write_bode_overlay_png`]: super::write_bode_overlay_png
//! [`write_nyquist_png`]: super::write_nyquist_png

use std::ops::Range;
use std::path::Path;

use plotters::style::RGBColor;

use super::axes::{plot_columns, plot_columns_at};
use super::legend::{draw_table, table_layout, Swatch, Table};
use super::pair_zoom::pair_window;
use super::png::invalid;
use super::style::{ensure_font, LINE_WIDTH};
use super::ticks::{log_range, positive_extent};
use super::{Area, BoxError, PlotError};
use crate::ident::frf::{Frf, PairVerdict, C64, MIN_COHERENCE};

/// Most traces an overlay draws (the Fig 5-10 grid has 150 cells).
pub const MAX_OVERLAY_TRACES: usize = 200;

/// Traces up to which the legend has one column, each entry in full on up
/// to two rows; beyond, columns of one row per entry in the short form.
pub const FULL_LEGEND_MAX: usize = 12;
/// Rows an entry of a one-column legend may take.
const FULL_LEGEND_LINES: usize = 2;
/// Traces up to which a legend in columns has two of them (else three).
const TWO_COLUMNS_MAX: usize = 48;
/// Traces up to which the curves are [`LINE_WIDTH`] wide (else 1 px).
const WIDE_LINES_MAX: usize = 8;

/// One measured FRF of an overlay.
#[derive(Debug, Clone, Copy)]
pub struct OverlayTrace<'a> {
    /// Its legend entry in full: its name and verdict, with why.
    pub legend: &'a str,
    /// Its legend entry in short, for a legend in columns (more than 12
    /// traces); cut with `…` to its column.
    pub legend_short: &'a str,
    /// The FRF (m/A): its frequency, magnitude, phase and coherence
    /// columns, of equal lengths. Points below [`MIN_COHERENCE`] are drawn
    /// in [`faint`](super::faint) of `color`.
    pub frf: &'a Frf,
    /// The trace's colour ([`overlay_colors`](super::overlay_colors)).
    pub color: RGBColor,
    /// The closely spaced pair of its phase test, if one was resolved: its
    /// two modes are marked in the pair zoom, whose window spans every
    /// trace's pair.
    pub pair: Option<PairVerdict>,
    /// Its fitted modes in the path, Hz (dots on the Nyquist curves).
    pub modes_hz: &'a [f64],
}

/// The model drawn once (dashed) over the traces.
#[derive(Debug, Clone, Copy)]
pub struct OverlayModel<'a> {
    /// Its legend entry (what the model is: its bench, operating point).
    pub label: &'a str,
    /// Frequency grid, Hz; the model is clipped to the traces' band.
    pub frequency_hz: &'a [f64],
    /// `H(j2πf)`, m/A, one per frequency.
    pub response_m_per_a: &'a [C64],
}

/// Everything an overlay figure shows.
#[derive(Debug, Clone, Copy)]
pub struct OverlayPlot<'a> {
    /// Figure title (omitted when empty).
    pub title: &'a str,
    /// The FRFs, drawn in order (the last on top); 1 to
    /// [`MAX_OVERLAY_TRACES`].
    pub traces: &'a [OverlayTrace<'a>],
    /// What the colours mean (their order, for a sequential palette): a
    /// line of text above the traces' legend.
    pub colors_note: Option<&'a str>,
    /// The model, if drawn.
    pub model: Option<OverlayModel<'a>>,
}

impl OverlayPlot<'_> {
    /// The frequency axis of the figures, Hz: the traces' frequencies
    /// (the model's only when they have no usable band).
    pub fn band_hz(&self) -> Range<f64> {
        band(self)
    }

    /// The pair zoom's window, Hz: the union over the traces' resolved
    /// pairs of the Bode figure's window, `lower − d … upper + d`,
    /// `d = max(upper − lower, 1 % of lower)`, kept inside the band when
    /// the pair is; `None` when no trace resolved a pair.
    pub fn pair_zoom_hz(&self) -> Option<Range<f64>> {
        pairs_window(self, &band(self))
    }
}

/// Checks `plot`: 1 to [`MAX_OVERLAY_TRACES`] traces, each FRF's columns
/// and the model's of equal lengths.
pub(super) fn check(path: &Path, plot: &OverlayPlot<'_>) -> Result<(), PlotError> {
    let n = plot.traces.len();
    if n == 0 || n > MAX_OVERLAY_TRACES {
        return Err(invalid(
            path,
            format!("{n} traces; an overlay draws 1 to {MAX_OVERLAY_TRACES}"),
        ));
    }
    for (i, t) in plot.traces.iter().enumerate() {
        let f = t.frf;
        let len = f.frequency_hz.len();
        if f.magnitude_m_per_a.len() != len || f.phase_deg.len() != len || f.coherence.len() != len
        {
            return Err(invalid(
                path,
                format!(
                    "trace {} ({:?}): {len} frequencies, {} magnitudes, {} phases, {} coherences",
                    i + 1,
                    t.legend,
                    f.magnitude_m_per_a.len(),
                    f.phase_deg.len(),
                    f.coherence.len()
                ),
            ));
        }
    }
    if let Some(m) = &plot.model {
        if m.frequency_hz.len() != m.response_m_per_a.len() {
            return Err(invalid(
                path,
                format!(
                    "model: {} frequencies but {} responses",
                    m.frequency_hz.len(),
                    m.response_m_per_a.len()
                ),
            ));
        }
    }
    Ok(())
}

/// Width of the traces' curves, px.
pub(super) fn trace_width(plot: &OverlayPlot<'_>) -> u32 {
    if plot.traces.len() <= WIDE_LINES_MAX {
        LINE_WIDTH
    } else {
        1
    }
}

/// Whether `frf`'s point `i` is of good coherence (NaN is not).
pub(super) fn good(frf: &Frf) -> Vec<bool> {
    frf.coherence.iter().map(|&c| c >= MIN_COHERENCE).collect()
}

/// The frequency band of the overlay: the traces' frequencies (the model
/// widens it only when they have no usable band).
pub(super) fn band(plot: &OverlayPlot<'_>) -> Range<f64> {
    let all = || {
        plot.traces
            .iter()
            .flat_map(|t| t.frf.frequency_hz.iter().copied())
    };
    match positive_extent(all()) {
        Some((lo, hi)) if hi / lo >= 1.01 => lo..hi,
        _ => log_range(
            all().chain(
                plot.model
                    .iter()
                    .flat_map(|m| m.frequency_hz.iter().copied()),
            ),
        ),
    }
}

/// The pair zoom's window: the union of every resolved pair's window
/// (the Bode figure's rule, [`pair_window`]); `None` when no trace
/// resolved a pair.
pub(super) fn pairs_window(plot: &OverlayPlot<'_>, x_range: &Range<f64>) -> Option<Range<f64>> {
    plot.traces
        .iter()
        .filter_map(|t| t.pair.as_ref())
        .map(|p| pair_window(p, x_range))
        .reduce(|a, b| a.start.min(b.start)..a.end.max(b.end))
}

/// How many traces resolved a pair.
pub(super) fn resolved(plot: &OverlayPlot<'_>) -> usize {
    plot.traces.iter().filter(|t| t.pair.is_some()).count()
}

/// The traces' legend laid out for a figure `width` px wide (the text
/// sizes need the font): the colours' note, then one entry per trace in
/// its colour. Errors name `path`.
pub(super) fn trace_table(
    path: &Path,
    plot: &OverlayPlot<'_>,
    width: u32,
) -> Result<Table, PlotError> {
    ensure_font()?;
    let n = plot.traces.len();
    let full = n <= FULL_LEGEND_MAX;
    let mut entries: Vec<(String, Swatch)> = Vec::with_capacity(n + 1);
    let w = trace_width(plot).max(3);
    entries.extend(plot.traces.iter().map(|t| {
        let text = if full { t.legend } else { t.legend_short };
        (text.to_string(), Swatch::Line(t.color, w))
    }));
    let columns = if full {
        1
    } else if n <= TWO_COLUMNS_MAX {
        2
    } else {
        3
    };
    let cols = plot_columns_at(0, width);
    let draw_err = |e: BoxError| PlotError::Draw {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let mut table =
        table_layout(&entries, cols.1 - cols.0, columns, FULL_LEGEND_LINES).map_err(draw_err)?;
    if let Some(note) = plot.colors_note {
        let head = table_layout(&[(note.to_string(), Swatch::Text)], cols.1 - cols.0, 1, 1)
            .map_err(draw_err)?;
        table = head.above(table);
    }
    Ok(table)
}

/// Draws the traces' legend `table` at the top of `area`, over its plot
/// columns.
pub(super) fn draw_trace_table(
    root: &Area<'_>,
    area: &Area<'_>,
    table: &Table,
) -> Result<(), BoxError> {
    let (left, _) = plot_columns(area);
    let (_, top) = area.get_base_pixel();
    draw_table(root, table, left, top + 4)
}
