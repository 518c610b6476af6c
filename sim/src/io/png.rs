//! The one PNG encoder of the workspace: 8-bit greyscale, RGB or palette
//! images, every row with the "Up" filter, the zlib stream from
//! `miniz_oxide`. Enough for diagnostic pictures (the PSF panel) and the
//! harness plots.
//!
//! [`decode`] is the reference reader kept alongside: it checks every chunk
//! CRC and the zlib Adler-32 and undoes all five PNG row filters, so tests
//! can check that whatever [`encode`] and [`encode_indexed`] write reads
//! back to their input.

use super::{IoError, write_bytes_atomically};
use std::path::Path;

/// The PNG file signature.
const SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a];

/// PNG colour types of IHDR (8-bit samples only).
const GREY: u8 = 0;
const RGB: u8 = 2;
const INDEXED: u8 = 3;

/// CRC-32 (IEEE, reflected, as PNG uses), bit by bit.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xedb8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    let crc = crc32(&out[start..]);
    out.extend_from_slice(&crc.to_be_bytes());
}

/// Encodes `height` rows of `stride` bytes with colour type `colour`
/// (and, for palette images, its PLTE).
fn encode_rows(
    width: usize,
    height: usize,
    colour: u8,
    stride: usize,
    palette: Option<&[[u8; 3]]>,
    pixels: &[u8],
) -> Vec<u8> {
    assert_eq!(pixels.len(), stride * height, "pixel buffer size");
    let mut raw = Vec::with_capacity((stride + 1) * height);
    let mut prev = vec![0u8; stride];
    for row in pixels.chunks_exact(stride.max(1)).take(height) {
        raw.push(2); // filter: Up (difference from the row above)
        raw.extend(row.iter().zip(&prev).map(|(a, b)| a.wrapping_sub(*b)));
        prev.copy_from_slice(row);
    }
    if stride == 0 {
        raw.resize(height, 2);
    }
    let z = miniz_oxide::deflate::compress_to_vec_zlib(&raw, 8);
    let mut out = SIGNATURE.to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&(width as u32).to_be_bytes());
    ihdr.extend_from_slice(&(height as u32).to_be_bytes());
    ihdr.extend_from_slice(&[8, colour, 0, 0, 0]);
    chunk(&mut out, b"IHDR", &ihdr);
    if let Some(p) = palette {
        let plte: Vec<u8> = p.iter().flatten().copied().collect();
        chunk(&mut out, b"PLTE", &plte);
    }
    chunk(&mut out, b"IDAT", &z);
    chunk(&mut out, b"IEND", &[]);
    out
}

/// Encodes an image as PNG bytes. `channels` is 1 (grey) or 3 (RGB);
/// `pixels` is row-major, top row first, `width × height × channels` bytes.
///
/// # Panics
/// If `channels` is not 1 or 3 or `pixels` has the wrong length (a bug of
/// the caller, not bad input).
pub fn encode(width: usize, height: usize, channels: usize, pixels: &[u8]) -> Vec<u8> {
    assert!(channels == 1 || channels == 3);
    let colour = if channels == 1 { GREY } else { RGB };
    encode_rows(width, height, colour, width * channels, None, pixels)
}

/// Encodes a `width × height` image of indices into `palette` (at most 256
/// colours), row-major from the top.
///
/// # Panics
/// If `pix` is not `width × height` bytes or the palette has more than 256
/// entries (bugs of the caller).
pub fn encode_indexed(width: usize, height: usize, palette: &[[u8; 3]], pix: &[u8]) -> Vec<u8> {
    assert!(
        palette.len() <= 256,
        "a PNG palette holds at most 256 colours"
    );
    encode_rows(width, height, INDEXED, width, Some(palette), pix)
}

/// Writes a grey or RGB PNG ([`encode`]) atomically.
pub fn write_png(
    path: &Path,
    width: usize,
    height: usize,
    channels: usize,
    pixels: &[u8],
) -> Result<(), IoError> {
    write_bytes_atomically(path, &encode(width, height, channels, pixels))
}

/// A PNG read back by [`decode`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Decoded {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Bytes per pixel: 1 (grey or palette index) or 3 (RGB).
    pub channels: usize,
    /// Whether the pixels are indices into `palette` (colour type 3).
    pub indexed: bool,
    /// The PLTE entries (empty unless the image has one).
    pub palette: Vec<[u8; 3]>,
    /// Row-major samples, top row first, `width × height × channels` bytes.
    pub pixels: Vec<u8>,
}

/// The Paeth predictor of the PNG specification (filter type 4).
fn paeth(a: u8, b: u8, c: u8) -> u8 {
    let p = i16::from(a) + i16::from(b) - i16::from(c);
    let (pa, pb, pc) = (
        (p - i16::from(a)).abs(),
        (p - i16::from(b)).abs(),
        (p - i16::from(c)).abs(),
    );
    if pa <= pb && pa <= pc {
        a
    } else if pb <= pc {
        b
    } else {
        c
    }
}

/// Reference reader of 8-bit, non-interlaced grey, RGB and palette PNGs
/// (what this module writes, with any row filters). Checks the signature,
/// every chunk CRC and the zlib Adler-32; `None` on anything else or any
/// error.
pub fn decode(png: &[u8]) -> Option<Decoded> {
    if png.get(..8)? != SIGNATURE {
        return None;
    }
    let (mut i, mut ihdr, mut palette, mut idat) = (8, None, Vec::new(), Vec::new());
    while i + 12 <= png.len() {
        let n = u32::from_be_bytes(png[i..i + 4].try_into().ok()?) as usize;
        let kind = png.get(i + 4..i + 8)?;
        let data = png.get(i + 8..i + 8 + n)?;
        let crc = u32::from_be_bytes(png.get(i + 8 + n..i + 12 + n)?.try_into().ok()?);
        if crc32(&png[i + 4..i + 8 + n]) != crc {
            return None;
        }
        match kind {
            b"IHDR" => ihdr = Some(data.get(..13)?.to_vec()),
            b"PLTE" => palette = data.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
            b"IDAT" => idat.extend_from_slice(data),
            _ => {}
        }
        i += 12 + n;
    }
    let h = ihdr?;
    let width = u32::from_be_bytes(h[0..4].try_into().ok()?) as usize;
    let height = u32::from_be_bytes(h[4..8].try_into().ok()?) as usize;
    let channels = match (h[8], h[9], h[12]) {
        (8, GREY | INDEXED, 0) => 1,
        (8, RGB, 0) => 3,
        _ => return None,
    };
    let raw = miniz_oxide::inflate::decompress_to_vec_zlib(&idat).ok()?;
    let stride = width.checked_mul(channels)?;
    if Some(raw.len()) != (stride + 1).checked_mul(height) {
        return None;
    }
    let mut pixels = vec![0u8; stride * height];
    for (y, row) in raw.chunks_exact(stride + 1).enumerate() {
        let (done, rest) = pixels.split_at_mut(y * stride);
        let prev = if y == 0 {
            None
        } else {
            Some(&done[(y - 1) * stride..])
        };
        let cur = &mut rest[..stride];
        for x in 0..stride {
            let a = if x >= channels { cur[x - channels] } else { 0 };
            let b = prev.map_or(0, |p| p[x]);
            let c = match prev {
                Some(p) if x >= channels => p[x - channels],
                _ => 0,
            };
            let predictor = match row[0] {
                0 => 0,
                1 => a,
                2 => b,
                3 => ((u16::from(a) + u16::from(b)) / 2) as u8,
                4 => paeth(a, b, c),
                _ => return None,
            };
            cur[x] = row[1 + x].wrapping_add(predictor);
        }
    }
    Some(Decoded {
        width,
        height,
        channels,
        indexed: h[9] == INDEXED,
        palette,
        pixels,
    })
}

/// [`decode`] for palette images: `(width, height, indices)`; `None` if the
/// PNG is unreadable or not a palette image.
pub fn decode_indexed(png: &[u8]) -> Option<(usize, usize, Vec<u8>)> {
    let d = decode(png)?;
    d.indexed.then_some((d.width, d.height, d.pixels))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::seed::SimRng;
    use rand::{RngExt, SeedableRng};

    /// Adler-32 of zlib, written out to check the stream's trailer.
    fn adler32(bytes: &[u8]) -> u32 {
        let (mut a, mut b) = (1u32, 0u32);
        for &x in bytes {
            a = (a + u32::from(x)) % 65521;
            b = (b + a) % 65521;
        }
        (b << 16) | a
    }

    #[test]
    fn checksums_match_their_published_check_values() {
        assert_eq!(crc32(b"123456789"), 0xcbf4_3926);
        assert_eq!(crc32(b"IEND"), 0xae42_6082);
        assert_eq!(adler32(b"Wikipedia"), 0x11e6_0398);
    }

    #[test]
    fn checksums_and_layout() {
        let png = encode(2, 1, 1, &[0, 255]);
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
        assert_eq!(&png[12..16], b"IHDR");
        assert_eq!(
            &png[png.len() - 12..],
            &[0, 0, 0, 0, b'I', b'E', b'N', b'D', 0xae, 0x42, 0x60, 0x82]
        );
        // The zlib stream decodes to the filtered rows and ends with their
        // Adler-32; two rows show the Up filter.
        let png = encode(2, 2, 1, &[0, 255, 10, 5]);
        let idat_len = u32::from_be_bytes(png[33..37].try_into().unwrap()) as usize;
        assert_eq!(&png[37..41], b"IDAT");
        let z = &png[41..41 + idat_len];
        let raw = miniz_oxide::inflate::decompress_to_vec_zlib(z).unwrap();
        assert_eq!(raw, vec![2, 0, 255, 2, 10, 6]);
        assert_eq!(&z[z.len() - 4..], &adler32(&raw).to_be_bytes());
    }

    #[test]
    fn every_kind_of_image_round_trips_through_the_reference_reader() {
        let mut rng = SimRng::seed_from_u64(3);
        for case in 0..40 {
            let (w, h) = (rng.random_range(1..70), rng.random_range(1..50));
            let channels = [1, 3, 1][case % 3];
            let k = rng.random_range(1..=256u32);
            let runny = case % 2 == 0;
            let n = w * h * channels;
            let mut v: Vec<u8> = Vec::with_capacity(n);
            while v.len() < n {
                let b = rng.random_range(0..k) as u8;
                let r = if runny { rng.random_range(1..400) } else { 1 };
                v.extend(std::iter::repeat_n(b, r.min(n - v.len())));
            }
            let (png, palette) = if case % 3 == 2 {
                let pal: Vec<[u8; 3]> = (0..k).map(|i| [i as u8, 7, 255 - i as u8]).collect();
                (encode_indexed(w, h, &pal, &v), pal)
            } else {
                (encode(w, h, channels, &v), Vec::new())
            };
            let d = decode(&png).unwrap();
            assert_eq!((d.width, d.height, d.channels), (w, h, channels));
            assert_eq!(d.palette, palette);
            assert_eq!(d.pixels, v, "case {case}");
            assert_eq!(decode_indexed(&png).is_some(), case % 3 == 2);
        }
    }

    #[test]
    fn the_reader_undoes_all_five_row_filters() {
        // A 3 × 2 RGB image written by hand: an unfiltered first row, then a
        // second row with filter None, Sub, Up, Average or Paeth, checked
        // against values worked out on paper.
        let first = [11, 21, 31, 15, 25, 35, 15, 26, 37];
        let cases: [([u8; 10], [u8; 9]); 5] = [
            (
                [0, 10, 20, 30, 40, 50, 60, 70, 80, 90],
                [10, 20, 30, 40, 50, 60, 70, 80, 90],
            ),
            (
                [1, 10, 20, 30, 5, 5, 5, 1, 2, 3],
                [10, 20, 30, 15, 25, 35, 16, 27, 38],
            ),
            (
                [2, 1, 1, 1, 0, 0, 0, 255, 255, 255],
                [12, 22, 32, 15, 25, 35, 14, 25, 36],
            ),
            // Average of left and up: (0 + 11) / 2 + 4 = 9, (9 + 15) / 2 + 5 = 17, …
            (
                [3, 4, 4, 4, 5, 5, 5, 6, 6, 6],
                [9, 14, 19, 17, 24, 32, 22, 31, 40],
            ),
            // Paeth picks up, up, left across the row: 11 + 1, 15 + 1, 16 + 1, …
            (
                [4, 1, 2, 3, 1, 2, 3, 1, 2, 3],
                [12, 23, 34, 16, 27, 38, 17, 29, 41],
            ),
        ];
        for (filter, (row, want)) in cases.iter().enumerate() {
            let raw = [&[0][..], &first, row].concat();
            let mut png = SIGNATURE.to_vec();
            let mut ihdr = 3u32.to_be_bytes().to_vec();
            ihdr.extend_from_slice(&2u32.to_be_bytes());
            ihdr.extend_from_slice(&[8, RGB, 0, 0, 0]);
            chunk(&mut png, b"IHDR", &ihdr);
            chunk(
                &mut png,
                b"IDAT",
                &miniz_oxide::deflate::compress_to_vec_zlib(&raw, 6),
            );
            chunk(&mut png, b"IEND", &[]);
            let d = decode(&png).unwrap();
            assert_eq!(d.pixels[..9], first);
            assert_eq!(d.pixels[9..], *want, "filter {filter}");
        }
        assert_eq!(paeth(10, 20, 15), 15);
        assert_eq!(paeth(10, 20, 5), 20);
        assert_eq!(paeth(10, 20, 30), 10);
    }

    #[test]
    fn flat_images_compress_and_corruption_is_caught() {
        let (w, h) = (300, 250);
        let pix: Vec<u8> = (0..w * h)
            .map(|i| ((i % w) / 37 + (i / w) / 50) as u8 % 8)
            .collect();
        let png = encode_indexed(w, h, &[[0, 0, 0]; 8], &pix);
        let (dw, dh, dp) = decode_indexed(&png).unwrap();
        assert_eq!((dw, dh), (w, h));
        assert_eq!(dp, pix);
        assert!(png.len() < pix.len() / 20, "{} bytes", png.len());
        let mut bad = png.clone();
        bad[40] ^= 1;
        assert!(decode_indexed(&bad).is_none(), "a flipped bit is caught");
        // Absurd dimensions (with a valid CRC) are refused, not a panic.
        let mut huge = png.clone();
        huge[16..24].copy_from_slice(&[0xff; 8]);
        huge[25] = RGB; // 3 bytes per pixel: the row count × stride overflows

        let crc = crc32(&huge[12..29]);
        huge[29..33].copy_from_slice(&crc.to_be_bytes());
        assert!(decode(&huge).is_none());
        assert!(decode(&png[..png.len() / 2]).is_none(), "truncated");
    }
}
