//! The figures' type and line style: the embedded font (registered with
//! plotters once, so no system font libraries are needed), the text sizes
//! and the line width. Colours are in [`super::palette`]; legend strips,
//! marker labels and header lines in [`super::legend`].

use std::sync::OnceLock;

use plotters::style::FontStyle;

use super::PlotError;

/// The family name the embedded font is registered under.
pub(crate) const FONT: &str = "sans-serif";
/// DejaVu Sans, embedded.
static FONT_BYTES: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

/// Registers the embedded font with plotters (once per process).
///
/// # Errors
/// [`PlotError::Font`] if plotters refuses it.
pub(super) fn ensure_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, FONT_BYTES).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(PlotError::Font)
    }
}

/// Figure title, px.
pub(super) const TITLE_SIZE: f64 = 28.0;
/// Header lines above a section (the pair zoom's), px.
pub(super) const HEADER_SIZE: f64 = 20.0;
/// Axis descriptions, px.
pub(super) const DESC_SIZE: f64 = 20.0;
/// Tick labels, px.
pub(super) const TICK_SIZE: f64 = 17.0;
/// Width of a curve, px.
pub(super) const LINE_WIDTH: u32 = 2;
