//! Detection: threshold the smoothed image, label 8-connected footprints by
//! flood fill, drop small or insignificant ones, and split footprints with
//! two or more well-separated peaks (simple deblending).
//!
//! A footprint is the set of connected pixels whose smoothed value exceeds
//! `detect_thresh` × σ_f, where σ_f is the noise of the smoothed image. Its
//! peaks are the local maxima (3 × 3) of the smoothed image above
//! `detect_peak_sn` × σ_f. Peaks are taken from the highest down; a peak is
//! kept as a separate object if, towards every peak already kept, it lies at
//! least `deblend_min_sep_px` away and the smoothed image dips on the
//! straight line between them below (1 − `deblend_min_dip`) × its own
//! height. Pixels of a split footprint go to the nearest kept peak. A split
//! source is marked blended when another peak of its footprint is closer
//! than `deblend_flag_px` (farther neighbours do not reach its weight window).

use crate::image::Image;
use crate::params::KsbParams;

/// One detected source.
#[derive(Debug, Clone, PartialEq)]
pub struct Detection {
    /// Peak of the smoothed image, array coordinates.
    pub x: f64,
    /// Peak of the smoothed image, array coordinates.
    pub y: f64,
    /// The smoothed image's peak to a fraction of a pixel: the vertex of a
    /// quadratic surface fitted to the 3 × 3 pixels about the peak pixel
    /// ([`subpixel_peak`]), array coordinates. The light's mode, against
    /// which a blend's windowed centroid shifts (`flags::SHIFTED`).
    pub peak: (f64, f64),
    /// Smoothed peak in units of σ_f.
    pub peak_sn: f64,
    /// Number of footprint pixels assigned to this source.
    pub area: usize,
    /// Split from a footprint with another source whose peak is closer
    /// than `deblend_flag_px`.
    pub blended: bool,
    /// The footprint touches the image border.
    pub touches_edge: bool,
    /// A pixel of the footprint is at or above the saturation level.
    pub saturated: bool,
    /// The sub-pixel peaks of the other sources split from its footprint
    /// (empty when it was not split).
    pub siblings: Vec<(f64, f64)>,
}

/// Detects sources. `filtered` is the background-subtracted image smoothed
/// by [`crate::filter::smooth`], `sigma_f` its noise; `raw` the image as read
/// (electrons, sky included) and `saturation_e` its saturation level.
pub fn detect(
    filtered: &Image,
    sigma_f: f64,
    raw: &Image,
    saturation_e: Option<f64>,
    params: &KsbParams,
) -> Vec<Detection> {
    let (w, h) = (filtered.width, filtered.height);
    let thresh = (params.detect_thresh * sigma_f) as f32;
    let peak_min = params.detect_peak_sn * sigma_f;
    let mut label = vec![false; w * h];
    let mut stack = Vec::new();
    let mut pixels: Vec<usize> = Vec::new();
    let mut out = Vec::new();
    for start in 0..w * h {
        if label[start] || filtered.data[start].is_nan() || filtered.data[start] <= thresh {
            continue;
        }
        // Flood fill the footprint.
        pixels.clear();
        stack.push(start);
        label[start] = true;
        while let Some(p) = stack.pop() {
            pixels.push(p);
            let (x, y) = ((p % w) as i64, (p / w) as i64);
            for dy in -1..=1i64 {
                for dx in -1..=1i64 {
                    let (nx, ny) = (x + dx, y + dy);
                    if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                        continue;
                    }
                    let q = ny as usize * w + nx as usize;
                    if !label[q] && filtered.data[q] > thresh {
                        label[q] = true;
                        stack.push(q);
                    }
                }
            }
        }
        if pixels.len() < params.detect_min_area {
            continue;
        }
        out.extend(split_footprint(
            filtered,
            sigma_f,
            raw,
            saturation_e,
            &pixels,
            peak_min,
            params,
        ));
    }
    out
}

/// Whether pixel `p` of `img` is a local maximum of its 3 × 3
/// neighbourhood (on a plateau, the first pixel in memory order).
pub(crate) fn is_local_max(img: &Image, p: usize) -> bool {
    let (w, h) = (img.width, img.height);
    let (x, y) = ((p % w) as i64, (p / w) as i64);
    let v = img.data[p];
    for dy in -1..=1i64 {
        for dx in -1..=1i64 {
            if dx == 0 && dy == 0 {
                continue;
            }
            let (nx, ny) = (x + dx, y + dy);
            if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                continue;
            }
            let q = ny as usize * w + nx as usize;
            // Ties: the first pixel in memory order of a plateau wins.
            let u = img.data[q];
            if u > v || (u == v && q < p) {
                return false;
            }
        }
    }
    true
}

/// The peak of `img` near its local maximum at pixel `p`, to a fraction of
/// a pixel: the vertex of the quadratic surface a + bx + cy + dx² + ey² +
/// gxy fitted (least squares) to the 3 × 3 pixels about `p`, at most ½ px
/// away per axis. The cross term matters: fitted one axis at a time, an
/// elongated peak tilted by 45° comes out up to half a pixel off, which a
/// cut on the centroid's shift from the peak would turn into a cut on e₂.
/// A pixel on the border, or a 3 × 3 patch that is not a maximum of a
/// concave surface, gives the pixel's centre.
pub fn subpixel_peak(img: &Image, p: usize) -> (f64, f64) {
    let (w, h) = (img.width, img.height);
    let (x, y) = (p % w, p / w);
    let centre = (x as f64, y as f64);
    if x == 0 || y == 0 || x + 1 >= w || y + 1 >= h {
        return centre;
    }
    // f[j][i] = img(x + i − 1, y + j − 1).
    let mut f = [[0.0f64; 3]; 3];
    for (j, row) in f.iter_mut().enumerate() {
        for (i, v) in row.iter_mut().enumerate() {
            *v = f64::from(img.data[(y + j - 1) * w + x + i - 1]);
        }
    }
    let col = |i: usize| f[0][i] + f[1][i] + f[2][i];
    let row = |j: usize| f[j][0] + f[j][1] + f[j][2];
    // The least-squares coefficients on the 3 × 3 stencil.
    let b = (col(2) - col(0)) / 6.0;
    let c = (row(2) - row(0)) / 6.0;
    let d = (col(0) + col(2) - 2.0 * col(1)) / 6.0;
    let e = (row(0) + row(2) - 2.0 * row(1)) / 6.0;
    let g = (f[2][2] - f[0][2] - f[2][0] + f[0][0]) / 4.0;
    // Gradient zero: [2d g; g 2e] (dx, dy) = −(b, c), a maximum when the
    // Hessian is negative definite.
    let det = 4.0 * d * e - g * g;
    if !(d < 0.0 && det > 0.0) {
        return centre;
    }
    let dx = (-2.0 * e * b + g * c) / det;
    let dy = (g * b - 2.0 * d * c) / det;
    if !(dx.is_finite() && dy.is_finite()) {
        return centre;
    }
    (
        x as f64 + dx.clamp(-0.5, 0.5),
        y as f64 + dy.clamp(-0.5, 0.5),
    )
}

/// Lowest smoothed value on the segment between two pixels (nearest-pixel
/// samples every 0.5 px).
fn min_on_line(img: &Image, a: (f64, f64), b: (f64, f64)) -> f64 {
    let d = ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt();
    let n = (2.0 * d).ceil().max(1.0) as usize;
    (0..=n)
        .map(|k| {
            let t = k as f64 / n as f64;
            let x = (a.0 + t * (b.0 - a.0)).round() as usize;
            let y = (a.1 + t * (b.1 - a.1)).round() as usize;
            f64::from(img.at(x, y))
        })
        .fold(f64::INFINITY, f64::min)
}

fn split_footprint(
    filtered: &Image,
    sigma_f: f64,
    raw: &Image,
    saturation_e: Option<f64>,
    pixels: &[usize],
    peak_min: f64,
    params: &KsbParams,
) -> Vec<Detection> {
    let w = filtered.width;
    let mut peaks: Vec<(f64, usize)> = pixels
        .iter()
        .filter(|&&p| f64::from(filtered.data[p]) >= peak_min && is_local_max(filtered, p))
        .map(|&p| (f64::from(filtered.data[p]), p))
        .collect();
    if peaks.is_empty() {
        return Vec::new();
    }
    peaks.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let xy = |p: usize| ((p % w) as f64, (p / w) as f64);
    let mut kept: Vec<(f64, usize)> = vec![peaks[0]];
    for &(hgt, p) in &peaks[1..] {
        if kept.len() >= params.deblend_max_peaks {
            break;
        }
        let separate = kept.iter().all(|&(_, k)| {
            let (a, b) = (xy(p), xy(k));
            let d = ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt();
            d >= params.deblend_min_sep_px
                && min_on_line(filtered, a, b) <= (1.0 - params.deblend_min_dip) * hgt
        });
        if separate {
            kept.push((hgt, p));
        }
    }
    let blended = kept.len() > 1;
    let mut dets: Vec<Detection> = kept
        .iter()
        .map(|&(hgt, p)| {
            let (x, y) = xy(p);
            let nearest = kept
                .iter()
                .filter(|&&(_, q)| q != p)
                .map(|&(_, q)| {
                    let (qx, qy) = xy(q);
                    (qx - x).hypot(qy - y)
                })
                .fold(f64::INFINITY, f64::min);
            Detection {
                x,
                y,
                peak: subpixel_peak(filtered, p),
                peak_sn: hgt / sigma_f,
                area: 0,
                blended: nearest < params.deblend_flag_px,
                touches_edge: false,
                saturated: false,
                siblings: Vec::new(),
            }
        })
        .collect();
    if blended {
        let peaks: Vec<(f64, f64)> = dets.iter().map(|d| d.peak).collect();
        for (i, d) in dets.iter_mut().enumerate() {
            d.siblings = peaks
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, &p)| p)
                .collect();
        }
    }
    for &p in pixels {
        let (x, y) = xy(p);
        let k = if blended {
            dets.iter()
                .enumerate()
                .map(|(i, d)| (i, (d.x - x).powi(2) + (d.y - y).powi(2)))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map_or(0, |m| m.0)
        } else {
            0
        };
        let d = &mut dets[k];
        d.area += 1;
        if x == 0.0 || y == 0.0 || x as usize == w - 1 || y as usize == filtered.height - 1 {
            d.touches_edge = true;
        }
        if let Some(s) = saturation_e {
            if f64::from(raw.data[p]) >= s {
                d.saturated = true;
            }
        }
    }
    dets
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{covariance, draw_gaussian_sampled};

    #[test]
    fn the_subpixel_peak_is_the_vertex_of_a_paraboloid() {
        // On a quadratic surface the fit is exact: the vertex of a tilted
        // elliptical paraboloid at (12.3, 7.8) comes back to rounding.
        let mut img = Image::zeros(20, 16);
        for iy in 0..16 {
            for ix in 0..20 {
                let (dx, dy) = (ix as f64 - 12.3, iy as f64 - 7.8);
                *img.at_mut(ix, iy) = (500.0 - dx * dx - 2.0 * dy * dy - 1.2 * dx * dy) as f32;
            }
        }
        let (x, y) = subpixel_peak(&img, 8 * 20 + 12);
        assert!((x - 12.3).abs() < 1e-4 && (y - 7.8).abs() < 1e-4, "{x} {y}");
        // Gaussians of σ = 3 px (a point source through the 0.9″ PSF and
        // the detection filter has σ ≈ 2.4 px), round and elongated
        // (|e| = 0.3, axis ratio 0.54) in 12 orientations, off the pixel
        // centre by up to half a pixel: within 0.04 px (0.026 measured)
        // whatever their orientation. Fitted one axis at a time, the
        // diagonal ones came out about 0.4 px off.
        let mut worst = 0.0f64;
        for k in 0..13 {
            let (e, a) = if k == 12 {
                (0.0, 0.0)
            } else {
                (0.3, k as f64 * std::f64::consts::PI / 12.0)
            };
            for (cx, cy) in [(14.4, 15.2), (14.5, 14.6), (15.3, 15.45), (15.0, 15.0)] {
                let mut g = Image::zeros(30, 30);
                draw_gaussian_sampled(
                    &mut g,
                    cx,
                    cy,
                    1000.0,
                    &covariance(3.0, [e * a.cos(), e * a.sin()]),
                );
                let p = (0..g.data.len()).fold(0, |b, q| if g.data[q] > g.data[b] { q } else { b });
                let (x, y) = subpixel_peak(&g, p);
                worst = worst.max((x - cx).hypot(y - cy));
            }
        }
        assert!(worst < 0.04, "worst offset {worst}");
        // At the border, or on a flat top, the pixel's centre.
        let mut g = Image::zeros(30, 30);
        draw_gaussian_sampled(&mut g, 0.3, 15.2, 1000.0, &covariance(2.0, [0.0, 0.0]));
        assert_eq!(subpixel_peak(&g, 15 * 30), (0.0, 15.0));
        let flat = Image::zeros(5, 5);
        assert_eq!(subpixel_peak(&flat, 2 * 5 + 2), (2.0, 2.0));
    }

    #[test]
    fn two_close_peaks_are_split_and_one_elongated_source_is_not() {
        let p = KsbParams::default();
        let mut img = Image::zeros(80, 60);
        // Two round sources 9 px apart: the dip between them is deep.
        draw_gaussian_sampled(&mut img, 30.0, 30.0, 1000.0, &covariance(1.8, [0.0, 0.0]));
        draw_gaussian_sampled(&mut img, 39.0, 31.0, 600.0, &covariance(1.8, [0.0, 0.0]));
        // An elongated single source: one peak.
        // Two sources 40 px apart joined by a faint bridge: split, not blended.
        draw_gaussian_sampled(&mut img, 10.0, 50.0, 1000.0, &covariance(1.8, [0.0, 0.0]));
        draw_gaussian_sampled(&mut img, 50.0, 50.0, 1000.0, &covariance(1.8, [0.0, 0.0]));
        for x in 10..=50 {
            *img.at_mut(x, 50) += 3.0;
        }
        draw_gaussian_sampled(&mut img, 60.0, 15.0, 1000.0, &covariance(2.5, [0.5, 0.0]));
        let d = detect(&img, 1.0, &img, Some(40.0), &p);
        assert_eq!(d.len(), 5, "{d:?}");
        let blended: Vec<_> = d.iter().filter(|d| d.blended).collect();
        assert_eq!(blended.len(), 2);
        assert!(
            blended
                .iter()
                .any(|d| (d.x - 30.0).abs() <= 1.0 && (d.y - 30.0).abs() <= 1.0)
        );
        assert!(
            blended
                .iter()
                .any(|d| (d.x - 39.0).abs() <= 1.0 && (d.y - 31.0).abs() <= 1.0)
        );
        let single = d.iter().find(|d| !d.blended && d.y == 15.0).unwrap();
        assert_eq!(d.iter().filter(|d| d.y == 50.0 && !d.blended).count(), 2);
        assert_eq!((single.x, single.y), (60.0, 15.0));
        // Peak of the 1000 e⁻ round source is 1000/(2π 1.8²) = 49 > 40: saturated.
        assert!(d.iter().any(|d| d.saturated && d.x == 30.0 && d.y == 30.0));
        assert!(!single.saturated);
    }
}
