//! PNG pictures of the workspace, made with well-kept crates: the `png`
//! codec for raster pictures (the PSF panel), and `resvg` for figures drawn
//! as SVG (the harness plots), rasterised **with their text** by the
//! DejaVu Sans font that the `dejavu` crate bundles, so that no system font
//! is needed and the PNG shows exactly what the SVG shows.
//!
//! Text on a raster picture ([`Picture`]'s labels) is drawn the same way: the
//! labels become a small SVG of text, rasterised and laid over the pixels.

use crate::picture::{Picture, xml_escape};
use std::path::Path;
use std::sync::{Arc, OnceLock};
use stepsim_contract::io::{IoError, write_bytes_atomically};

/// The family name of the bundled font; SVG `font-family="sans-serif"`
/// resolves to it.
pub const FONT_FAMILY: &str = "DejaVu Sans";

/// An SVG that cannot be rasterised (a bug of its writer, not user input).
#[derive(Debug, thiserror::Error)]
pub enum SvgError {
    /// The SVG text does not parse.
    #[error("the figure's SVG does not parse: {0}")]
    Parse(String),
    /// Its size is zero or too large for a picture.
    #[error("the figure's size {width}×{height} px cannot be rasterised")]
    Size {
        /// Width in pixels.
        width: f32,
        /// Height in pixels.
        height: f32,
    },
    /// The PNG encoder failed.
    #[error("cannot encode the PNG: {0}")]
    Encode(String),
}

/// The font database: the bundled DejaVu Sans family (regular, bold,
/// oblique), loaded once per process.
fn fonts() -> Arc<resvg::usvg::fontdb::Database> {
    static DB: OnceLock<Arc<resvg::usvg::fontdb::Database>> = OnceLock::new();
    DB.get_or_init(|| {
        let mut db = resvg::usvg::fontdb::Database::new();
        for face in [
            dejavu::sans::regular(),
            dejavu::sans::bold(),
            dejavu::sans::oblique(),
            dejavu::sans::bold_oblique(),
        ] {
            db.load_font_data(face.to_vec());
        }
        db.set_sans_serif_family(FONT_FAMILY);
        Arc::new(db)
    })
    .clone()
}

/// Rasterises an SVG document at its own size: premultiplied RGBA pixels,
/// top row first.
fn rasterise(svg: &str) -> Result<resvg::tiny_skia::Pixmap, SvgError> {
    let options = resvg::usvg::Options {
        font_family: FONT_FAMILY.into(),
        fontdb: fonts(),
        ..Default::default()
    };
    let tree =
        resvg::usvg::Tree::from_str(svg, &options).map_err(|e| SvgError::Parse(e.to_string()))?;
    let size = tree.size();
    let (w, h) = (size.width().ceil(), size.height().ceil());
    let mut pixmap = resvg::tiny_skia::Pixmap::new(w as u32, h as u32).ok_or(SvgError::Size {
        width: w,
        height: h,
    })?;
    resvg::render(
        &tree,
        resvg::tiny_skia::Transform::identity(),
        &mut pixmap.as_mut(),
    );
    Ok(pixmap)
}

/// Rasterises an SVG figure, text included, and encodes it as PNG (RGBA).
pub fn svg_to_png(svg: &str) -> Result<Vec<u8>, SvgError> {
    rasterise(svg)?
        .encode_png()
        .map_err(|e| SvgError::Encode(e.to_string()))
}

/// The pixels of a picture with its labels drawn over them (white text
/// with a dark outline, legible on any background).
pub fn flatten(picture: &Picture) -> Result<Vec<u8>, SvgError> {
    let mut rgb = picture.rgb.clone();
    if picture.labels.is_empty() {
        return Ok(rgb);
    }
    let mut svg = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{}\" height=\"{}\" font-family=\"sans-serif\">",
        picture.width, picture.height
    );
    for l in &picture.labels {
        svg.push_str(&format!(
            "<text x=\"{:.1}\" y=\"{:.1}\" font-size=\"{:.1}\" fill=\"white\" stroke=\"black\" stroke-width=\"{:.1}\" paint-order=\"stroke\">{}</text>",
            l.x,
            l.y,
            l.size,
            (l.size / 6.0).max(1.0),
            xml_escape(&l.text)
        ));
    }
    svg.push_str("</svg>");
    let overlay = rasterise(&svg)?;
    // Premultiplied source over opaque destination: d = s + d (1 − a).
    for (d, s) in rgb.chunks_exact_mut(3).zip(overlay.data().chunks_exact(4)) {
        let keep = 255 - u16::from(s[3]);
        for c in 0..3 {
            let v = u16::from(s[c]) + (u16::from(d[c]) * keep + 127) / 255;
            d[c] = v.min(255) as u8;
        }
    }
    Ok(rgb)
}

/// A picture, labels drawn, as PNG bytes (RGB).
pub fn picture_to_png(picture: &Picture) -> Result<Vec<u8>, SvgError> {
    encode_rgb(picture.width, picture.height, &flatten(picture)?)
}

/// Encodes `width × height` RGB pixels (top row first) as PNG.
pub fn encode_rgb(width: usize, height: usize, rgb: &[u8]) -> Result<Vec<u8>, SvgError> {
    let mut out = Vec::new();
    let enc_err = |e: png::EncodingError| SvgError::Encode(e.to_string());
    let mut enc = png::Encoder::new(&mut out, width as u32, height as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().map_err(enc_err)?;
    w.write_image_data(rgb).map_err(enc_err)?;
    w.finish().map_err(enc_err)?;
    Ok(out)
}

/// Writes a picture, labels drawn, as a PNG file (atomically).
pub fn write_picture(path: &Path, picture: &Picture) -> Result<(), IoError> {
    let bytes = picture_to_png(picture).map_err(|e| IoError::format(path, e.to_string()))?;
    write_bytes_atomically(path, &bytes)
}

/// A PNG read back by [`decode`]: 8-bit RGBA, top row first.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Decoded {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// RGBA bytes, `width × height × 4`, not premultiplied.
    pub rgba: Vec<u8>,
}

impl Decoded {
    /// The RGBA of pixel (x, y) (y from the top).
    pub fn pixel(&self, x: usize, y: usize) -> [u8; 4] {
        let o = (y * self.width + x) * 4;
        [
            self.rgba[o],
            self.rgba[o + 1],
            self.rgba[o + 2],
            self.rgba[o + 3],
        ]
    }
}

/// Reads PNG bytes of any 8-bit colour type (for tests and checks): `None`
/// if they are not a PNG, or larger than 64 Mpixel.
pub fn decode(bytes: &[u8]) -> Option<Decoded> {
    let limits = png::Limits { bytes: 256 << 20 };
    let mut dec = png::Decoder::new_with_limits(std::io::Cursor::new(bytes), limits);
    dec.set_transformations(png::Transformations::EXPAND);
    let mut reader = dec.read_info().ok()?;
    let mut buf = vec![0; reader.output_buffer_size()?];
    let info = reader.next_frame(&mut buf).ok()?;
    if info.bit_depth != png::BitDepth::Eight {
        return None;
    }
    let px = (info.width as usize) * (info.height as usize);
    let rgba: Vec<u8> = match info.color_type {
        png::ColorType::Rgba => buf[..px * 4].to_vec(),
        png::ColorType::Rgb => buf[..px * 3]
            .chunks_exact(3)
            .flat_map(|c| [c[0], c[1], c[2], 255])
            .collect(),
        png::ColorType::Grayscale => buf[..px].iter().flat_map(|&g| [g, g, g, 255]).collect(),
        png::ColorType::GrayscaleAlpha => buf[..px * 2]
            .chunks_exact(2)
            .flat_map(|c| [c[0], c[0], c[0], c[1]])
            .collect(),
        png::ColorType::Indexed => return None,
    };
    Some(Decoded {
        width: info.width as usize,
        height: info.height as usize,
        rgba,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::picture::Label;

    /// Dark pixels (all channels < 128, opaque) in a rectangle.
    fn dark(d: &Decoded, x0: usize, y0: usize, x1: usize, y1: usize) -> usize {
        (y0..y1)
            .flat_map(|y| (x0..x1).map(move |x| (x, y)))
            .filter(|&(x, y)| {
                let p = d.pixel(x, y);
                p[3] > 200 && p[0] < 128 && p[1] < 128 && p[2] < 128
            })
            .count()
    }

    #[test]
    fn svg_text_is_drawn_with_the_bundled_font() {
        let frame = |text: &str| {
            format!(
                "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"200\" height=\"40\" font-family=\"sans-serif\">\
                 <rect width=\"200\" height=\"40\" fill=\"white\"/>\
                 <text x=\"10\" y=\"28\" font-size=\"20\">{text}</text></svg>"
            )
        };
        let with = decode(&svg_to_png(&frame("m = 0.01")).unwrap()).unwrap();
        let without = decode(&svg_to_png(&frame("")).unwrap()).unwrap();
        assert_eq!((with.width, with.height), (200, 40));
        assert_eq!(dark(&without, 0, 0, 200, 40), 0);
        // Eight glyphs at 20 px: a few hundred dark pixels, all where the
        // text stands (x from 10, baseline 28, ascent ≈ 15 px).
        let inside = dark(&with, 8, 10, 120, 32);
        assert!(inside > 150, "{inside} dark pixels");
        assert_eq!(dark(&with, 0, 0, 200, 40), inside);
    }

    #[test]
    fn a_bad_svg_is_an_error_not_a_panic() {
        assert!(matches!(svg_to_png("<svg"), Err(SvgError::Parse(_))));
        let empty = "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"0\" height=\"0\"/>";
        assert!(svg_to_png(empty).is_err());
    }

    #[test]
    fn labels_are_laid_over_the_pixels_and_the_rest_is_kept() {
        let (w, h) = (120, 30);
        let rgb: Vec<u8> = (0..w * h).flat_map(|i| [(i % 251) as u8, 40, 90]).collect();
        let mut pic = Picture {
            width: w,
            height: h,
            rgb: rgb.clone(),
            labels: vec![],
        };
        let plain = decode(&picture_to_png(&pic).unwrap()).unwrap();
        assert_eq!(plain.width, w);
        let back: Vec<u8> = plain
            .rgba
            .chunks_exact(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect();
        assert_eq!(back, rgb, "RGB round trip");
        pic.labels.push(Label {
            x: 4.0,
            y: 20.0,
            size: 16.0,
            text: "coma <1>".into(),
        });
        let labelled = flatten(&pic).unwrap();
        let white = labelled
            .chunks_exact(3)
            .filter(|p| p.iter().all(|&c| c > 230))
            .count();
        assert!(white > 40, "{white} white text pixels");
        // Pixels right of the text are untouched.
        for y in 0..h {
            for x in 100..w {
                let o = (y * w + x) * 3;
                assert_eq!(labelled[o..o + 3], rgb[o..o + 3]);
            }
        }
    }

    #[test]
    fn garbage_is_not_a_png() {
        assert!(decode(b"not a png").is_none());
        assert!(decode(&[]).is_none());
    }
}
