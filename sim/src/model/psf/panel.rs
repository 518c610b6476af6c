//! Pictures of PSFs side by side (like paper Fig. 1): a row of tiles, each
//! the central part of a PSF image scaled to its own peak, with contours at
//! given fractions of the peak. Returns an RGB buffer (top row first, so
//! +y is up as in a FITS viewer), each tile labelled with its name (drawn
//! with a real font when [`stepsim_figure::png`] writes the picture).

use stepsim_figure::picture::{Label, Picture};

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

/// One row of `count` square tiles of `2 half` samples each, every sample
/// enlarged to a `zoom × zoom` block, on a dark background with a 6-pixel
/// gap, one tile per name, the name written in its top-left corner;
/// `colour_of(t, i, j)` colours sample (i, j) of tile t, j counting up (the
/// picture is flipped so +y is up).
fn tile_row(
    names: &[&str],
    half: usize,
    zoom: usize,
    colour_of: impl Fn(usize, usize, usize) -> [u8; 3],
) -> Picture {
    let count = names.len();
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
    let size = (side as f64 / 12.0).clamp(9.0, 18.0);
    let labels = names
        .iter()
        .enumerate()
        .map(|(t, name)| Label {
            x: (gap + t * (side + gap)) as f64 + size / 3.0,
            y: gap as f64 + size * 1.2,
            size,
            text: (*name).to_owned(),
        })
        .collect();
    Picture {
        width,
        height,
        rgb,
        labels,
    }
}

/// Largest value of an image.
fn peak_of(img: &[f64]) -> f64 {
    img.iter().copied().fold(f64::NEG_INFINITY, f64::max)
}

/// Lays out square images (`n × n`, row-major, centre at n/2) in one row.
/// Each tile shows the central `2 half` samples enlarged `zoom` times.
pub fn row(
    images: &[&[f64]],
    names: &[&str],
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
    tile_row(names, half, zoom, |t, i, j| {
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

/// How each image differs from a reference image (both scaled to unit
/// peak): red where brighter, blue where fainter, full colour at ±`scale`.
/// With the unaberrated PSF as reference this shows what each aberration
/// does at the same FWHM — the "+" of astigmatism, the three lobes of
/// trefoil, the flare of coma, the flat top of defocus — which the seeing
/// hides in the direct picture.
pub fn difference_row(
    images: &[&[f64]],
    names: &[&str],
    reference: &[f64],
    n: usize,
    half: usize,
    zoom: usize,
    scale: f64,
) -> Picture {
    let half = half.min(n / 2);
    let p0 = peak_of(reference);
    let peaks: Vec<f64> = images.iter().map(|img| peak_of(img)).collect();
    tile_row(names, half, zoom, |t, i, j| {
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

/// Stacks pictures vertically (narrower ones padded on the right), labels
/// kept in place.
pub fn stack(pictures: &[Picture]) -> Picture {
    let width = pictures.iter().map(|p| p.width).max().unwrap_or(0);
    let mut rgb = Vec::new();
    let mut labels = Vec::new();
    let mut height = 0;
    for p in pictures {
        for row in p.rgb.chunks_exact(p.width * 3) {
            rgb.extend_from_slice(row);
            rgb.resize(rgb.len() + (width - p.width) * 3, 30);
        }
        labels.extend(p.labels.iter().map(|l| Label {
            y: l.y + height as f64,
            ..l.clone()
        }));
        height += p.height;
    }
    Picture {
        width,
        height,
        rgb,
        labels,
    }
}

/// A strip of `height` dark pixels carrying one line of text (a caption
/// above a row of tiles), its font made smaller (not below 8 px) when the
/// line would not fit the width: DejaVu Sans averages under 0.6 em a
/// character (a long caption was cut off at the right edge).
pub fn caption(width: usize, height: usize, text: &str) -> Picture {
    let fit = (width as f64 - 12.0) / (CHAR_EM * text.chars().count().max(1) as f64);
    let size = (height as f64 * 0.6).min(fit).max(8.0);
    Picture {
        width,
        height,
        rgb: vec![30; width * height * 3],
        labels: vec![Label {
            x: 6.0,
            y: height as f64 * 0.75,
            size,
            text: text.to_owned(),
        }],
    }
}

/// The picture of a PSF set (`psf_cores.png`): the cores (±1.6″, linear,
/// contours at 3 %, 25 %, 90 % of the peak), each core minus the first
/// PSF's (both at unit peak; red brighter, blue fainter, full colour at
/// ±5 %), and the wings (±15″, log stretch down to 1e-6, contours at
/// 3e-5 … 0.25 of the peak), one column per PSF, with captions. `cores` are
/// 256² images at p/8 and `wings` 512² images at p/2
/// ([`crate::model::psf::image`]) for pixel scale `pixel_scale_arcsec` = p.
pub fn psf_set(
    cores: &[&[f64]],
    wings: &[&[f64]],
    names: &[&str],
    pixel_scale_arcsec: f64,
) -> Picture {
    let p = pixel_scale_arcsec;
    let half_core = (1.6 / (p / 8.0)).round() as usize;
    let half_wing = (15.0 / (p / 2.0)).round() as usize;
    let top = row(
        cores,
        names,
        256,
        half_core,
        2,
        Stretch::Linear,
        &[0.03, 0.25, 0.9],
    );
    let zoom = (top.width / (cores.len() * 2 * half_wing.min(256))).max(1);
    let bottom = row(
        wings,
        names,
        512,
        half_wing,
        zoom,
        Stretch::Log { floor: 1e-6 },
        &[3e-5, 3e-4, 3e-3, 0.03, 0.25],
    );
    let middle = difference_row(cores, names, cores[0], 256, half_core, 2, 0.05);
    let w = top.width;
    stack(&[
        caption(
            w,
            30,
            "cores ±1.6″, linear; contours at 3 %, 25 %, 90 % of the peak",
        ),
        top,
        caption(
            w,
            30,
            &format!(
                "core minus {}'s, both at unit peak: red brighter, blue fainter (±5 %)",
                names[0]
            ),
        ),
        middle,
        caption(
            w,
            30,
            "wings ±15″, log stretch to 1e-6; contours at 3e-5 … 0.25 of the peak",
        ),
        bottom,
    ])
}
/// Average advance of a DejaVu Sans character, in em (an upper estimate).
const CHAR_EM: f64 = 0.6;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_long_caption_is_set_smaller_to_fit_the_width() {
        let short = caption(600, 30, "cores");
        assert_eq!(short.labels[0].size, 18.0);
        let text = "core minus none's, both at unit peak: red brighter, blue fainter (±5 %)";
        let long = caption(600, 30, text);
        let size = long.labels[0].size;
        assert!(
            size < 18.0 && size * CHAR_EM * text.chars().count() as f64 <= 588.0,
            "{size}"
        );
    }

    #[test]
    fn tiles_contours_and_orientation() {
        // A 8×8 image with a bright pixel above-right of the centre.
        let n = 8;
        let mut img = vec![0.0; n * n];
        img[5 * n + 5] = 1.0;
        img[4 * n + 4] = 0.5;
        let p = row(
            &[&img, &img],
            &["a", "b"],
            n,
            4,
            1,
            Stretch::Linear,
            &[0.75],
        );
        assert_eq!(p.width, 2 * 8 + 3 * 6);
        assert_eq!(p.height, 8 + 12);
        // Sample (5, 5) is the contour (≥ 0.75 with darker neighbours):
        // picture x = 6 + 5, y = 6 + 8 − 1 − 5.
        let o = ((6 + 2) * p.width + 6 + 5) * 3;
        assert_eq!(&p.rgb[o..o + 3], &COLOURS[0]);
        // Sample (4, 4) is half grey.
        let o = ((6 + 3) * p.width + 6 + 4) * 3;
        assert_eq!(p.rgb[o], 128);
        // Each tile carries its name, at its own top-left corner.
        assert_eq!(p.labels.len(), 2);
        assert_eq!(p.labels[1].text, "b");
        assert!(p.labels[1].x > (6 + 8 + 6) as f64 && p.labels[1].x < (6 + 8 + 6 + 8) as f64);
        let s = stack(&[p.clone(), p]);
        // Stacking keeps the labels on their tiles.
        assert_eq!(s.labels.len(), 4);
        assert_eq!(s.labels[3].y, s.labels[1].y + 20.0);
        assert_eq!(s.height, 40);
        assert_eq!(s.rgb.len(), s.width * s.height * 3);
    }
}
