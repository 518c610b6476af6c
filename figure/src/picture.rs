//! A raster picture with text to lay over it: the value the PSF panel
//! (`stepsim_sim::model::psf::panel`) makes and [`crate::png`] writes. Text is kept
//! as labels, not pixels, so that it is drawn with a real font at the end.

/// A line of text on a raster picture.
#[derive(Debug, Clone, PartialEq)]
pub struct Label {
    /// Left end of the text's baseline, pixels from the left.
    pub x: f64,
    /// The baseline, pixels from the top.
    pub y: f64,
    /// Font size in pixels.
    pub size: f64,
    /// The text (plain; escaped when drawn).
    pub text: String,
}

/// An RGB picture with text to lay over it.
#[derive(Debug, Clone, PartialEq)]
pub struct Picture {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// RGB bytes, top row first.
    pub rgb: Vec<u8>,
    /// Text drawn in white over the pixels.
    pub labels: Vec<Label>,
}

/// Escapes text for SVG character data and attribute values.
pub fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}
