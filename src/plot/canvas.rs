//! What a figure is drawn on: an RGB bitmap (PNG) or an SVG document
//! (SVG, and PDF converted from it), behind one plotters backend so that
//! every figure draws once for every format ([`Canvas`]).

use std::error::Error as StdError;
use std::fmt;

use plotters::prelude::*;
use plotters_backend::{
    BackendColor, BackendCoord, BackendStyle, BackendTextStyle, DrawingErrorKind,
};

/// The formats a figure is written in, chosen by the file's extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// A PNG bitmap (any extension but the two below).
    Png,
    /// An SVG document (`.svg`): vector, text as text.
    Svg,
    /// A one-page PDF (`.pdf`): the SVG converted, text embedded in DejaVu
    /// Sans.
    Pdf,
}

impl Format {
    /// The format of `path` by its extension (case-insensitive): `.svg`,
    /// `.pdf`, else PNG.
    pub fn of(path: &std::path::Path) -> Self {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("svg") => Self::Svg,
            Some("pdf") => Self::Pdf,
            _ => Self::Png,
        }
    }
}

/// A bitmap or an SVG backend; draws by delegating each call.
pub enum Canvas<'a> {
    /// An RGB buffer.
    Bitmap(BitMapBackend<'a>),
    /// An SVG document in a string.
    Svg(SVGBackend<'a>),
}

/// A backend's error, as text.
#[derive(Debug)]
pub struct CanvasError(String);

impl fmt::Display for CanvasError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl StdError for CanvasError {}

type Drawn = Result<(), DrawingErrorKind<CanvasError>>;

fn conv<T, E: StdError + Send + Sync>(
    r: Result<T, DrawingErrorKind<E>>,
) -> Result<T, DrawingErrorKind<CanvasError>> {
    r.map_err(|e| match e {
        DrawingErrorKind::DrawingError(e) => {
            DrawingErrorKind::DrawingError(CanvasError(e.to_string()))
        }
        DrawingErrorKind::FontError(f) => DrawingErrorKind::FontError(f),
    })
}

/// Calls `$call` on whichever backend `$self` holds.
macro_rules! each {
    ($self:expr, $b:ident => $call:expr) => {
        match $self {
            Canvas::Bitmap($b) => conv($call),
            Canvas::Svg($b) => conv($call),
        }
    };
}

impl DrawingBackend for Canvas<'_> {
    type ErrorType = CanvasError;

    fn get_size(&self) -> (u32, u32) {
        match self {
            Canvas::Bitmap(b) => b.get_size(),
            Canvas::Svg(b) => b.get_size(),
        }
    }

    fn ensure_prepared(&mut self) -> Drawn {
        each!(self, b => b.ensure_prepared())
    }

    fn present(&mut self) -> Drawn {
        each!(self, b => b.present())
    }

    fn draw_pixel(&mut self, point: BackendCoord, color: BackendColor) -> Drawn {
        each!(self, b => b.draw_pixel(point, color))
    }

    fn draw_line<S: BackendStyle>(
        &mut self,
        from: BackendCoord,
        to: BackendCoord,
        style: &S,
    ) -> Drawn {
        each!(self, b => b.draw_line(from, to, style))
    }

    fn draw_rect<S: BackendStyle>(
        &mut self,
        upper_left: BackendCoord,
        bottom_right: BackendCoord,
        style: &S,
        fill: bool,
    ) -> Drawn {
        each!(self, b => b.draw_rect(upper_left, bottom_right, style, fill))
    }

    fn draw_path<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        path: I,
        style: &S,
    ) -> Drawn {
        each!(self, b => b.draw_path(path, style))
    }

    fn draw_circle<S: BackendStyle>(
        &mut self,
        center: BackendCoord,
        radius: u32,
        style: &S,
        fill: bool,
    ) -> Drawn {
        each!(self, b => b.draw_circle(center, radius, style, fill))
    }

    fn fill_polygon<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        vert: I,
        style: &S,
    ) -> Drawn {
        each!(self, b => b.fill_polygon(vert, style))
    }

    fn draw_text<T: BackendTextStyle>(
        &mut self,
        text: &str,
        style: &T,
        pos: BackendCoord,
    ) -> Drawn {
        each!(self, b => b.draw_text(text, style, pos))
    }

    fn estimate_text_size<T: BackendTextStyle>(
        &self,
        text: &str,
        style: &T,
    ) -> Result<(u32, u32), DrawingErrorKind<CanvasError>> {
        match self {
            Canvas::Bitmap(b) => conv(b.estimate_text_size(text, style)),
            Canvas::Svg(b) => conv(b.estimate_text_size(text, style)),
        }
    }

    fn blit_bitmap(&mut self, pos: BackendCoord, size: (u32, u32), src: &[u8]) -> Drawn {
        each!(self, b => b.blit_bitmap(pos, size, src))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn the_extension_chooses_the_format() {
        for (p, f) in [
            ("a.png", Format::Png),
            ("a.PNG", Format::Png),
            ("a", Format::Png),
            ("dir.svg/a.png", Format::Png),
            ("a.svg", Format::Svg),
            ("a.SVG", Format::Svg),
            ("a.pdf", Format::Pdf),
            ("x/y.Pdf", Format::Pdf),
        ] {
            assert_eq!(Format::of(Path::new(p)), f, "{p}");
        }
    }
}
