//! The figures' type and line style: the embedded font (registered with
//! plotters once, so no system font libraries are needed), the text sizes
//! and the line width. Colours are in [`super::palette`]; legend strips,
//! marker labels and header lines in [`super::legend`].
//!
//! The model-analysis figures (pole-zero map, decomposed modes, CNMP map,
//! veering) use plotters' own captions and series-label boxes instead of
//! the legend strips, in their own sizes (the `ANALYSIS_` items).

use std::sync::OnceLock;

use plotters::style::{FontStyle, IntoFont, TextStyle};

use super::PlotError;

/// The family name the embedded font is registered under.
pub(super) const FONT: &str = "sans-serif";
/// DejaVu Sans, embedded.
pub(super) static FONT_BYTES: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

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

/// Size of every model-analysis figure, px.
pub(super) const ANALYSIS_SIZE: (u32, u32) = (1400, 1000);
/// Title of a model-analysis figure, px.
pub(super) const ANALYSIS_TITLE_SIZE: u32 = 26;
/// The reference size of a model-analysis figure's other text, px: its
/// panel captions, axis descriptions, tick and series labels are drawn at
/// it or a few px off it (+2, −2, −4), figure by figure.
pub(super) const ANALYSIS_LABEL_SIZE: u32 = 18;

/// The embedded font at `size` px, for the model-analysis figures.
pub(super) fn analysis_font(size: u32) -> TextStyle<'static> {
    (FONT, size).into_font().into()
}
