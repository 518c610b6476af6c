//! Pictures of PSFs side by side (like paper Fig. 1): a row of tiles, each
//! the central part of a PSF image scaled to its own peak, with contours at
//! given fractions of the peak. Returns an RGB buffer (top row first, so
//! +y is up as in a FITS viewer); [`crate::io::png`] writes it.

/// How pixel values map to grey.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Stretch {
    /// Linear from 0 to the peak.
    Linear,
    /// log10 from `floor` × peak to the peak.
    Log {
        /// Lowest level shown, as a fraction of the peak.
        floor: f64,
    },
}

/// Contour colours, cycled.
const COLOURS: [[u8; 3]; 5] = [
    [60, 120, 255],
    [40, 200, 200],
    [80, 220, 80],
    [255, 200, 40],
    [255, 60, 60],
];

/// An RGB picture.
#[derive(Debug, Clone, PartialEq)]
pub struct Picture {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// RGB bytes, top row first.
    pub rgb: Vec<u8>,
}

/// One row of `count` square tiles of `2 half` samples each, every sample
/// enlarged to a `zoom × zoom` block, on a dark background with a 6-pixel
/// gap; `colour_of(t, i, j)` colours sample (i, j) of tile t, j counting
/// up (the picture is flipped so +y is up).
fn tile_row(
    count: usize,
    half: usize,
    zoom: usize,
    colour_of: impl Fn(usize, usize, usize) -> [u8; 3],
) -> Picture {
    let side = 2 * half * zoom;
    let gap = 6;
    let width = count * side + (count + 1) * gap;
    let height = side + 2 * gap;
    let mut rgb = vec![30u8; width * height * 3];
    for t in 0..count {
        let x0 = gap + t * (side + gap);
        for j in 0..2 * half {
            for i in 0..2 * half {
                let colour = colour_of(t, i, j);
                for a in 0..zoom {
                    for b in 0..zoom {
                        let px = x0 + i * zoom + a;
                        // Flip: sample row j (y up) goes to picture row from the bottom.
                        let py = gap + side - 1 - (j * zoom + b);
                        let o = (py * width + px) * 3;
                        rgb[o..o + 3].copy_from_slice(&colour);
                    }
                }
            }
        }
    }
    label_tiles(&mut rgb, width, count, side, gap);
    Picture { width, height, rgb }
}

/// Largest value of an image.
fn peak_of(img: &[f64]) -> f64 {
    img.iter().copied().fold(f64::NEG_INFINITY, f64::max)
}

/// Lays out square images (`n × n`, row-major, centre at n/2) in one row.
/// Each tile shows the central `2 half` samples enlarged `zoom` times.
pub fn row(
    images: &[&[f64]],
    n: usize,
    half: usize,
    zoom: usize,
    stretch: Stretch,
    contours: &[f64],
) -> Picture {
    let half = half.min(n / 2);
    let peaks: Vec<f64> = images.iter().map(|img| peak_of(img)).collect();
    let c = n / 2;
    let at =
        |t: usize, i: usize, j: usize| images[t][(c - half + j) * n + (c - half + i)] / peaks[t];
    tile_row(images.len(), half, zoom, |t, i, j| {
        let v = at(t, i, j);
        let g = match stretch {
            Stretch::Linear => v.clamp(0.0, 1.0),
            Stretch::Log { floor } => {
                ((v.max(floor * 1e-3).log10() - floor.log10()) / -floor.log10()).clamp(0.0, 1.0)
            }
        };
        let mut colour = [(g * 255.0).round() as u8; 3];
        for (k, &lev) in contours.iter().enumerate() {
            let crosses = v >= lev
                && [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)]
                    .iter()
                    .any(|&(di, dj)| {
                        let (ii, jj) = (i as i64 + di, j as i64 + dj);
                        ii >= 0
                            && jj >= 0
                            && (ii as usize) < 2 * half
                            && (jj as usize) < 2 * half
                            && at(t, ii as usize, jj as usize) < lev
                    });
            if crosses {
                colour = COLOURS[k % COLOURS.len()];
            }
        }
        colour
    })
}

/// 3 × 5 bitmaps of the digits 0–9 (rows top to bottom, 3 bits each).
const DIGITS: [[u8; 5]; 10] = [
    [7, 5, 5, 5, 7],
    [2, 6, 2, 2, 7],
    [7, 1, 7, 4, 7],
    [7, 1, 7, 1, 7],
    [5, 5, 7, 1, 1],
    [7, 4, 7, 1, 7],
    [7, 4, 7, 5, 7],
    [7, 1, 1, 1, 1],
    [7, 5, 7, 5, 7],
    [7, 5, 7, 1, 7],
];

/// Writes each tile's index (0, 1, ...) in white in its top-left corner,
/// when tiles are at least 64 pixels wide.
fn label_tiles(rgb: &mut [u8], width: usize, tiles: usize, side: usize, gap: usize) {
    if side < 64 {
        return;
    }
    let s = (side / 64).max(1);
    for t in 0..tiles {
        let digits: Vec<usize> = t
            .to_string()
            .bytes()
            .map(|b| usize::from(b - b'0'))
            .collect();
        for (k, &d) in digits.iter().enumerate() {
            let x0 = gap + t * (side + gap) + 2 * s + k * 4 * s;
            let y0 = gap + 2 * s;
            for (r, bits) in DIGITS[d].iter().enumerate() {
                for c in 0..3 {
                    if bits >> (2 - c) & 1 == 1 {
                        for dy in 0..s {
                            for dx in 0..s {
                                let o = ((y0 + r * s + dy) * width + x0 + c * s + dx) * 3;
                                rgb[o..o + 3].copy_from_slice(&[255, 255, 255]);
                            }
                        }
                    }
                }
            }
        }
    }
}

/// How each image differs from a reference image (both scaled to unit
/// peak): red where brighter, blue where fainter, full colour at ±`scale`.
/// With the unaberrated PSF as reference this shows what each aberration
/// does at the same FWHM — the "+" of astigmatism, the three lobes of
/// trefoil, the flare of coma, the flat top of defocus — which the seeing
/// hides in the direct picture.
pub fn difference_row(
    images: &[&[f64]],
    reference: &[f64],
    n: usize,
    half: usize,
    zoom: usize,
    scale: f64,
) -> Picture {
    let half = half.min(n / 2);
    let p0 = peak_of(reference);
    let peaks: Vec<f64> = images.iter().map(|img| peak_of(img)).collect();
    tile_row(images.len(), half, zoom, |t, i, j| {
        let k = (n / 2 - half + j) * n + (n / 2 - half + i);
        let r = (images[t][k] / peaks[t] - reference[k] / p0) / scale;
        let a = (r.abs().min(1.0) * 255.0).round() as u8;
        if r >= 0.0 {
            [a, a / 4, 0]
        } else {
            [0, a / 2, a]
        }
    })
}

/// Stacks pictures of equal width vertically.
pub fn stack(pictures: &[Picture]) -> Picture {
    let width = pictures.iter().map(|p| p.width).max().unwrap_or(0);
    let mut rgb = Vec::new();
    let mut height = 0;
    for p in pictures {
        for row in p.rgb.chunks_exact(p.width * 3) {
            rgb.extend_from_slice(row);
            rgb.resize(rgb.len() + (width - p.width) * 3, 30);
        }
        height += p.height;
    }
    Picture { width, height, rgb }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_contours_and_orientation() {
        // A 8×8 image with a bright pixel above-right of the centre.
        let n = 8;
        let mut img = vec![0.0; n * n];
        img[5 * n + 5] = 1.0;
        img[4 * n + 4] = 0.5;
        let p = row(&[&img, &img], n, 4, 1, Stretch::Linear, &[0.75]);
        assert_eq!(p.width, 2 * 8 + 3 * 6);
        assert_eq!(p.height, 8 + 12);
        // Sample (5, 5) is the contour (≥ 0.75 with darker neighbours):
        // picture x = 6 + 5, y = 6 + 8 − 1 − 5.
        let o = ((6 + 2) * p.width + 6 + 5) * 3;
        assert_eq!(&p.rgb[o..o + 3], &COLOURS[0]);
        // Sample (4, 4) is half grey.
        let o = ((6 + 3) * p.width + 6 + 4) * 3;
        assert_eq!(p.rgb[o], 128);
        let s = stack(&[p.clone(), p]);
        // Tiles of 64 pixels or more carry their index: "1" on the second.
        let big = vec![0.0; 64 * 64];
        let q = row(&[&big, &big], 64, 32, 1, Stretch::Linear, &[]);
        let white = |x: usize, y: usize| q.rgb[(y * q.width + x) * 3] == 255;
        // Digit 1, top row: only the middle column lit (x0 = 6 + 70 + 2).
        assert!(white(78 + 1, 8) && !white(78, 8) && !white(78 + 2, 8));
        assert!(!white(78 + 1, 40));
        assert_eq!(s.height, 40);
        assert_eq!(s.rgb.len(), s.width * s.height * 3);
    }
}
