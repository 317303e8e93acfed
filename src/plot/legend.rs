//! Text around the panels: the figure's title, legend strips above a
//! panel or a row of panels (outside the plotted area, so they never hide
//! a trace), labels above the frame at the x of a marker line (stacked in
//! rows so they do not overlap), and header lines above a section.

use plotters::coord::ranged1d::Ranged;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::axes::{plot_columns, Chart};
use super::style::{FONT, HEADER_SIZE, TITLE_SIZE};
use super::{Area, BoxError};

/// Legend text, px.
const LEGEND_SIZE: f64 = 17.0;
/// Marker labels, px.
const MARKER_LABEL_SIZE: f64 = 15.0;
/// Height of one row of a legend strip, px.
const LEGEND_ROW_H: u32 = 24;
/// Length of a legend entry's swatch, px.
const SWATCH_W: i32 = 30;

/// How a legend entry is drawn before its text.
#[derive(Debug, Clone, Copy)]
pub(super) enum Swatch {
    /// A solid line of this width.
    Line(RGBColor, u32),
    /// A dashed line.
    Dashed(RGBColor),
    /// A translucent patch.
    Fill(RGBColor, f64),
    /// Text only.
    Text,
}

/// One entry of a legend strip: a swatch and its text.
pub(super) struct Entry {
    text: String,
    swatch: Swatch,
}

/// The legend entry `text` drawn after `swatch`.
pub(super) fn entry(text: impl Into<String>, swatch: Swatch) -> Entry {
    Entry {
        text: text.into(),
        swatch,
    }
}

/// Legend text, left-aligned and vertically centred on its row.
fn legend_style() -> TextStyle<'static> {
    TextStyle::from((FONT, LEGEND_SIZE).into_font()).pos(Pos::new(HPos::Left, VPos::Center))
}

/// Lays `entries` out left to right in rows `width` px wide: the x offset
/// and row of each, and the number of rows.
fn legend_layout(
    area: &Area<'_>,
    entries: &[Entry],
    width: i32,
) -> Result<(Vec<(i32, usize)>, usize), BoxError> {
    let style = legend_style();
    let mut out = Vec::with_capacity(entries.len());
    let (mut x, mut row) = (0, 0);
    for e in entries {
        let (tw, _) = area.estimate_text_size(&e.text, &style)?;
        let sw = if matches!(e.swatch, Swatch::Text) {
            0
        } else {
            SWATCH_W + 6
        };
        let w = sw + i32::try_from(tw)?;
        if x > 0 && x + w > width {
            x = 0;
            row += 1;
        }
        out.push((x, row));
        x += w + 24;
    }
    let rows = if entries.is_empty() { 0 } else { row + 1 };
    Ok((out, rows))
}

/// Height of the legend strip of `entries` above a panel built on `area`.
pub(super) fn legend_height(area: &Area<'_>, entries: &[Entry]) -> Result<u32, BoxError> {
    let (l, r) = plot_columns(area);
    let (_, rows) = legend_layout(area, entries, r - l)?;
    Ok(u32::try_from(rows)? * LEGEND_ROW_H)
}

/// Draws `swatch` from (`x`, `y`) (absolute pixels, the middle of its row);
/// returns the x where its text starts.
fn draw_swatch(root: &Area<'_>, swatch: Swatch, x: i32, y: i32) -> Result<i32, BoxError> {
    let seg = vec![(x, y), (x + SWATCH_W, y)];
    match swatch {
        Swatch::Line(c, w) => root.draw(&PathElement::new(seg, c.stroke_width(w)))?,
        Swatch::Dashed(c) => {
            root.draw(&DashedPathElement::new(seg, 8, 5, c.stroke_width(2)))?;
        }
        Swatch::Fill(c, a) => root.draw(&Rectangle::new(
            [(x, y - 7), (x + SWATCH_W, y + 7)],
            c.mix(a).filled(),
        ))?,
        Swatch::Text => return Ok(x),
    }
    Ok(x + SWATCH_W + 6)
}

/// Draws the legend strip of `entries` with its top-left corner at
/// (`x0`, `y_top`) (absolute pixels), wrapping at `width`.
fn draw_legend(
    root: &Area<'_>,
    entries: &[Entry],
    x0: i32,
    width: i32,
    y_top: i32,
) -> Result<(), BoxError> {
    let (pos, _) = legend_layout(root, entries, width)?;
    let row_h = i32::try_from(LEGEND_ROW_H)?;
    for (e, (dx, row)) in entries.iter().zip(pos) {
        let x = x0 + dx;
        let y = y_top + i32::try_from(row)? * row_h + row_h / 2;
        let tx = draw_swatch(root, e.swatch, x, y)?;
        root.draw(&Text::new(e.text.clone(), (tx, y), legend_style()))?;
    }
    Ok(())
}

/// Draws the legend strip of `entries` at the top of the space reserved
/// above the frame of `chart` (built on `area`).
pub(super) fn panel_legend<X: Ranged<ValueType = f64>>(
    root: &Area<'_>,
    area: &Area<'_>,
    chart: &Chart<'_, '_, X>,
    entries: &[Entry],
) -> Result<(), BoxError> {
    let (xs, _) = chart.plotting_area().get_pixel_range();
    let (_, top) = area.get_base_pixel();
    draw_legend(root, entries, xs.start, xs.end - xs.start, top + 2)
}

/// Draws the legend strip of `entries` at the top of `area`, over the
/// columns a panel built on `area` would plot in (a strip for several
/// panels; its height is [`legend_height`]).
pub(super) fn area_legend(
    root: &Area<'_>,
    area: &Area<'_>,
    entries: &[Entry],
) -> Result<(), BoxError> {
    let (l, r) = plot_columns(area);
    let (_, top) = area.get_base_pixel();
    draw_legend(root, entries, l, r - l, top + 2)
}

/// A label placed above the frame of a panel, at the x of its marker.
pub(super) struct MarkerLabel {
    x: f64,
    text: String,
    color: RGBColor,
    row: usize,
}

/// A marker label in `color`, centred above its point.
pub(super) fn marker_style(color: RGBColor) -> TextStyle<'static> {
    let mut style = TextStyle::from((FONT, MARKER_LABEL_SIZE).into_font())
        .pos(Pos::new(HPos::Center, VPos::Bottom));
    style.color = color.to_backend_color();
    style
}

/// Assigns marker labels `(x, text, colour)` to rows so that labels in a
/// row do not overlap; `x_px` maps x to an (approximate) pixel column.
/// Returns the labels and the number of rows.
pub(super) fn layout_marker_labels(
    area: &Area<'_>,
    items: Vec<(f64, String, RGBColor)>,
    x_px: impl Fn(f64) -> i32,
) -> Result<(Vec<MarkerLabel>, usize), BoxError> {
    let mut sorted = items;
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut row_right_edges: Vec<i32> = Vec::new();
    let mut labels = Vec::new();
    for (x, text, color) in sorted {
        let (tw, _) = area.estimate_text_size(&text, &marker_style(color))?;
        let tw = i32::try_from(tw)?;
        let left = x_px(x) - tw / 2;
        let row = match row_right_edges.iter().position(|&r| left > r + 8) {
            Some(r) => r,
            None => {
                row_right_edges.push(i32::MIN);
                row_right_edges.len() - 1
            }
        };
        row_right_edges[row] = left + tw;
        labels.push(MarkerLabel {
            x,
            text,
            color,
            row,
        });
    }
    Ok((labels, row_right_edges.len()))
}

/// Height of one row of marker labels in pixels.
pub(super) fn marker_row_height() -> i32 {
    MARKER_LABEL_SIZE as i32 + 4
}

/// Draws the marker labels above the frame of `chart`, centred on the lines
/// (kept inside the plotting columns).
pub(super) fn draw_marker_labels<X: Ranged<ValueType = f64>>(
    root: &Area<'_>,
    chart: &Chart<'_, '_, X>,
    labels: &[MarkerLabel],
    y_top: f64,
) -> Result<(), BoxError> {
    let (xs, _) = chart.plotting_area().get_pixel_range();
    for l in labels {
        let style = marker_style(l.color);
        let (px, py) = chart.backend_coord(&(l.x, y_top));
        let (tw, _) = root.estimate_text_size(&l.text, &style)?;
        let half = i32::try_from(tw)? / 2 + 2;
        let x = px.clamp(xs.start + half, (xs.end - half).max(xs.start + half));
        let y = py - 4 - i32::try_from(l.row)? * marker_row_height();
        root.draw(&Text::new(l.text.clone(), (x, y), style))?;
    }
    Ok(())
}

/// The part of `area` below the figure's `title` (none when empty), with a
/// margin above.
pub(super) fn titled<'b>(area: &Area<'b>, title: &str) -> Result<Area<'b>, BoxError> {
    let outer = area.margin(8, 0, 0, 0);
    Ok(if title.is_empty() {
        outer
    } else {
        outer.titled(title, (FONT, TITLE_SIZE))?
    })
}

/// Draws lines of text left-aligned at the plot columns of `area`, from its
/// top.
pub(super) fn header_lines(
    root: &Area<'_>,
    area: &Area<'_>,
    lines: &[String],
) -> Result<(), BoxError> {
    let (left, _) = plot_columns(area);
    let (_, top) = area.get_base_pixel();
    let style =
        TextStyle::from((FONT, HEADER_SIZE).into_font()).pos(Pos::new(HPos::Left, VPos::Top));
    for (i, line) in lines.iter().enumerate() {
        let y = top + i32::try_from(i)? * (HEADER_SIZE as i32 + 8);
        root.draw(&Text::new(line.clone(), (left, y), style.clone()))?;
    }
    Ok(())
}

/// Height of `n` header lines, px.
pub(super) fn header_height(n: usize) -> u32 {
    u32::try_from(n).unwrap_or(0) * (HEADER_SIZE as u32 + 8) + 6
}

/// A legend of many entries in columns (the traces of an overlay), laid
/// out before the image exists ([`table_layout`]), so the figure can be
/// made as tall as its legend needs.
pub(super) struct Table {
    /// `(x offset, first row, text lines, swatch)` of each entry.
    cells: Vec<(i32, usize, Vec<String>, Swatch)>,
    /// Rows in all.
    rows: usize,
}

impl Table {
    /// This table with `below` under it.
    pub(super) fn above(mut self, below: Table) -> Table {
        let shift = self.rows;
        self.cells.extend(
            below
                .cells
                .into_iter()
                .map(|(x, row, lines, swatch)| (x, row + shift, lines, swatch)),
        );
        self.rows += below.rows;
        self
    }

    /// Height of the table, px.
    pub(super) fn height(&self) -> u32 {
        u32::try_from(self.rows).unwrap_or(u32::MAX) * LEGEND_ROW_H
    }
}

/// Width of `text` in the legend's font, px.
fn legend_text_width(text: &str) -> Result<i32, BoxError> {
    let (w, _) = (FONT, LEGEND_SIZE).into_font().box_size(text)?;
    Ok(i32::try_from(w)?)
}

/// `text` cut to fit in `width` px, with `…` where it was cut.
fn truncated(text: &str, width: i32) -> Result<String, BoxError> {
    if legend_text_width(text)? <= width {
        return Ok(text.to_string());
    }
    let chars: Vec<char> = text.chars().collect();
    // The longest prefix that fits with the ellipsis (binary search).
    let (mut lo, mut hi) = (0, chars.len());
    while lo < hi {
        let mid = (lo + hi).div_ceil(2);
        let s: String = chars[..mid].iter().collect::<String>() + "…";
        if legend_text_width(&s)? <= width {
            lo = mid;
        } else {
            hi = mid - 1;
        }
    }
    Ok(chars[..lo]
        .iter()
        .collect::<String>()
        .trim_end()
        .to_string()
        + "…")
}

/// `text` broken at spaces into lines of at most `width` px, at most
/// `max_lines` of them (the last cut with `…` when the text goes on).
fn wrapped(text: &str, width: i32, max_lines: usize) -> Result<Vec<String>, BoxError> {
    let mut lines: Vec<String> = Vec::new();
    let mut cur = String::new();
    let words: Vec<&str> = text.split(' ').collect();
    for (i, w) in words.iter().enumerate() {
        let candidate = if cur.is_empty() {
            (*w).to_string()
        } else {
            format!("{cur} {w}")
        };
        if cur.is_empty() || legend_text_width(&candidate)? <= width {
            cur = candidate;
            continue;
        }
        if lines.len() + 1 == max_lines.max(1) {
            // The last line allowed: the rest of the text, cut to fit.
            let rest = format!("{cur} {}", words[i..].join(" "));
            lines.push(truncated(&rest, width)?);
            return Ok(lines);
        }
        // A single word wider than a line is cut.
        lines.push(truncated(&std::mem::take(&mut cur), width)?);
        cur = (*w).to_string();
    }
    lines.push(truncated(&cur, width)?);
    Ok(lines)
}

/// Lays `entries` (text, swatch) out in `columns` columns over `width` px,
/// filled top to bottom, then left to right: with one column each entry
/// wraps onto at most `max_lines` rows; with more, each takes one row, cut
/// to its column with `…`.
pub(super) fn table_layout(
    entries: &[(String, Swatch)],
    width: i32,
    columns: usize,
    max_lines: usize,
) -> Result<Table, BoxError> {
    let columns = columns.clamp(1, entries.len().max(1));
    let col_w = width / i32::try_from(columns)?;
    let text_w = |s: &Swatch| {
        col_w
            - 12
            - if matches!(s, Swatch::Text) {
                0
            } else {
                SWATCH_W + 6
            }
    };
    let mut cells = Vec::with_capacity(entries.len());
    if columns == 1 {
        let mut row = 0;
        for (text, swatch) in entries {
            let lines = wrapped(text, text_w(swatch), max_lines)?;
            let n = lines.len();
            cells.push((0, row, lines, *swatch));
            row += n;
        }
        return Ok(Table { cells, rows: row });
    }
    let rows = entries.len().div_ceil(columns);
    for (i, (text, swatch)) in entries.iter().enumerate() {
        let (col, row) = (i / rows, i % rows);
        let line = truncated(text, text_w(swatch))?;
        cells.push((i32::try_from(col)? * col_w, row, vec![line], *swatch));
    }
    Ok(Table { cells, rows })
}

/// Draws `table` with its top-left corner at (`x0`, `y_top`) (absolute
/// pixels): each entry's swatch on its first row, its lines after it.
pub(super) fn draw_table(
    root: &Area<'_>,
    table: &Table,
    x0: i32,
    y_top: i32,
) -> Result<(), BoxError> {
    let row_h = i32::try_from(LEGEND_ROW_H)?;
    for (dx, row, lines, swatch) in &table.cells {
        let x = x0 + dx;
        let y = y_top + i32::try_from(*row)? * row_h + row_h / 2;
        let tx = draw_swatch(root, *swatch, x, y)?;
        for (k, line) in lines.iter().enumerate() {
            let ly = y + i32::try_from(k)? * row_h;
            root.draw(&Text::new(line.clone(), (tx, ly), legend_style()))?;
        }
    }
    Ok(())
}
