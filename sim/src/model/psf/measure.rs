//! Pictures and measurements of a PSF as a star would show it.
//!
//! * [`image`]: the pixel-convolved PSF on an `n × n` grid, through the same
//!   path as the renderer (`transfer` × pixel sinc, inverse FFT).
//! * [`fwhm_from_area`]: FWHM = 2 sqrt(A/π) from the area A above half
//!   maximum (SPEC §3), with a sub-sample boundary correction.
//! * [`report`]: everything `psf_report.json` holds.

use super::optical::sinc;
use super::{Psf, PsfError, StampGrid};
use crate::model::moments;
use num_complex::Complex64;
use rustfft::{FftDirection, FftPlannerScalar};
use serde::{Deserialize, Serialize};

/// The pixel-convolved PSF (square pixel of side `pixel_scale_arcsec`)
/// sampled every `pixel_scale_arcsec / oversample` on an `n × n` grid
/// (n even), centred on sample (n/2, n/2) (0-based; FITS pixel n/2 + 1).
/// Values are fractions of the flux and sum to 1 over the grid; light
/// beyond the grid wraps around (as in the renderer's stamps).
pub fn image(psf: &dyn Psf, n: usize, pixel_scale_arcsec: f64, oversample: usize) -> Vec<f64> {
    let h = pixel_scale_arcsec / oversample.max(1) as f64;
    let grid = StampGrid::new(n, h);
    let t = psf.transfer(grid);
    let nc = grid.n_cols();
    let mut half: Vec<Complex64> = Vec::with_capacity(n * nc);
    for row in 0..n {
        for col in 0..nc {
            let (u, v) = grid.frequency(row, col);
            let g = t[row * nc + col];
            let s = sinc(u * pixel_scale_arcsec) * sinc(v * pixel_scale_arcsec);
            let sign = if (row + col) % 2 == 1 { -1.0 } else { 1.0 };
            half.push(Complex64::new(f64::from(g.re), f64::from(g.im)) * (s * sign));
        }
    }
    inverse_half_plane(&half, n)
        .into_iter()
        .map(|v| v / (n * n) as f64)
        .collect()
}

/// Inverse 2-D FFT (no 1/n² factor) of a half-plane array (n rows of
/// n/2 + 1 columns) of a real image's transform; returns the real image.
/// rustfft's scalar FFTs, the same bits on every CPU (as `fft2`).
pub fn inverse_half_plane(half: &[Complex64], n: usize) -> Vec<f64> {
    let nc = n / 2 + 1;
    let mut planner = FftPlannerScalar::new();
    let fft = planner.plan_fft(n, FftDirection::Inverse);
    // Columns: inverse along v.
    let mut cols = vec![Complex64::new(0.0, 0.0); nc * n];
    for c in 0..nc {
        for r in 0..n {
            cols[c * n + r] = half[r * nc + c];
        }
    }
    fft.process(&mut cols);
    // Rows: rebuild the full row by Hermitian symmetry, inverse along u.
    let mut rows = vec![Complex64::new(0.0, 0.0); n * n];
    for y in 0..n {
        for c in 0..nc {
            rows[y * n + c] = cols[c * n + y];
        }
        for c in nc..n {
            rows[y * n + c] = cols[(n - c) * n + y].conj();
        }
    }
    fft.process(&mut rows);
    rows.iter().map(|v| v.re).collect()
}

/// FWHM (in units of the sample spacing) from the area above half maximum:
/// 2 sqrt(A/π). Samples near the half-maximum contour count the fraction
/// of their cell above it, from the local gradient (linear interpolation).
pub fn fwhm_from_area(img: &[f64], n: usize) -> f64 {
    2.0 * (area_above(img, n, 0.5) / std::f64::consts::PI).sqrt()
}

/// Area (in cells) where the image exceeds `level` × its maximum.
pub fn area_above(img: &[f64], n: usize, level: f64) -> f64 {
    if n < 3 || img.len() != n * n {
        return 0.0;
    }
    let peak = img.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let cut = level * peak;
    let mut area = 0.0;
    for j in 1..n - 1 {
        for i in 1..n - 1 {
            let v = img[j * n + i];
            let gx = 0.5 * (img[j * n + i + 1] - img[j * n + i - 1]);
            let gy = 0.5 * (img[(j + 1) * n + i] - img[(j - 1) * n + i]);
            // Width of the cell across the contour, in value units.
            let w = gx.abs() + gy.abs();
            let d = v - cut;
            area += if d.abs() >= 0.5 * w || w == 0.0 {
                if d > 0.0 { 1.0 } else { 0.0 }
            } else {
                0.5 + d / w
            };
        }
    }
    area
}

/// Flux within `radius` (in samples) of the point (x0, y0) (0-based sample
/// coordinates), counting each sample by its centre.
pub fn encircled(img: &[f64], n: usize, x0: f64, y0: f64, radius: f64) -> f64 {
    let r2 = radius * radius;
    let mut s = 0.0;
    for j in 0..n {
        let dy = j as f64 - y0;
        for i in 0..n {
            let dx = i as f64 - x0;
            if dx * dx + dy * dy <= r2 {
                s += img[j * n + i];
            }
        }
    }
    s
}

/// What `stepsim psf` reports for one PSF (`psf_report.json`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct PsfReport {
    /// The PSF's name from the config.
    pub name: String,
    /// Pixel scale the PSF was measured at.
    pub pixel_scale_arcsec: f64,
    /// FWHM of the finely sampled pixel-convolved PSF, 2 sqrt(A/π).
    pub fwhm_arcsec: f64,
    /// Adaptive-moment distortion χ1 of the finely sampled pixel-convolved PSF.
    pub chi1: f64,
    /// Adaptive-moment distortion χ2.
    pub chi2: f64,
    /// |χ|.
    pub chi_abs: f64,
    /// χ1 measured on the PSF image at the pixel scale (as a star shows it).
    pub chi1_pixel: f64,
    /// χ2 at the pixel scale.
    pub chi2_pixel: f64,
    /// Adaptive-moment σ (determinant radius) in arcsec.
    pub sigma_arcsec: f64,
    /// Unweighted light centroid of the pixel-scale image minus its nominal
    /// centre, x, in pixels.
    pub centroid_x: f64,
    /// Same for y, in pixels.
    pub centroid_y: f64,
    /// Adaptive (weighted) centroid minus the nominal centre, x, pixels.
    pub centroid_adaptive_x: f64,
    /// Same for y.
    pub centroid_adaptive_y: f64,
    /// Seeing FWHM of the atmosphere alone (0.976 λ/r0), optical PSFs only.
    pub seeing_fwhm_arcsec: Option<f64>,
    /// λ/r0 in arcsec, optical PSFs only.
    pub lambda_over_r0_arcsec: Option<f64>,
    /// The aberration (`none`, `coma`, ...), optical PSFs only.
    pub aberration: Option<String>,
    /// Its amplitude: waves rms (Zernike) or the jitter σ in arcsec.
    pub amplitude: Option<f64>,
    /// Unit of `amplitude`: `waves` or `arcsec`.
    pub amplitude_unit: Option<String>,
    /// Diameter 2 sqrt(A/π) of the area above 90 % of the peak: the core width.
    pub core_diameter_arcsec: f64,
    /// Peak of the pixel-scale image as a fraction of the flux.
    pub peak_fraction: f64,
    /// Fraction of the flux within 1″ of the centroid.
    pub ee_1arcsec: f64,
    /// Fraction of the flux within 2″.
    pub ee_2arcsec: f64,
    /// Radius beyond which the PSF is everywhere fainter than 1e-5 of its
    /// peak (the reach of the diffraction spikes).
    pub radius_1e5_arcsec: f64,
}

/// Oversampling of the "finely sampled" PSF used for FWHM and χ.
pub const FINE_OVERSAMPLE: usize = 8;

/// Measures a PSF at a pixel scale.
pub fn report(name: &str, psf: &dyn Psf, pixel_scale_arcsec: f64) -> Result<PsfReport, PsfError> {
    let p = pixel_scale_arcsec;
    let h = p / FINE_OVERSAMPLE as f64;
    // Fine grid wide enough (≥ 26″) that the 2″ encircled energy is not
    // polluted by wrapped wings.
    let nf = ((26.0 / h).ceil() as usize).next_power_of_two().max(256);
    let fine = image(psf, nf, p, FINE_OVERSAMPLE);
    let m = moments::adaptive(&fine, nf, nf, 0.4 / h).map_err(|source| PsfError::Moments {
        name: name.into(),
        source,
    })?;
    let (chi1, chi2) = m.chi();
    let fwhm = fwhm_from_area(&fine, nf) * h;
    let core = 2.0 * (area_above(&fine, nf, 0.9) / std::f64::consts::PI).sqrt() * h;
    let (cx, cy) = (m.x - 1.0, m.y - 1.0);
    let ee1 = encircled(&fine, nf, cx, cy, 1.0 / h);
    let ee2 = encircled(&fine, nf, cx, cy, 2.0 / h);
    // At the pixel scale.
    let n = 64;
    let px = image(psf, n, p, 1);
    let u = moments::unweighted(&px, n, n).map_err(|source| PsfError::Moments {
        name: name.into(),
        source,
    })?;
    let a = moments::adaptive(&px, n, n, 0.4 / p).map_err(|source| PsfError::Moments {
        name: name.into(),
        source,
    })?;
    let centre = (n / 2) as f64 + 1.0;
    let cal = psf.calibration();
    Ok(PsfReport {
        name: name.into(),
        pixel_scale_arcsec: p,
        fwhm_arcsec: fwhm,
        chi1,
        chi2,
        chi_abs: chi1.hypot(chi2),
        chi1_pixel: a.chi().0,
        chi2_pixel: a.chi().1,
        sigma_arcsec: m.sigma() * h,
        centroid_x: u.x - centre,
        centroid_y: u.y - centre,
        centroid_adaptive_x: a.x - centre,
        centroid_adaptive_y: a.y - centre,
        seeing_fwhm_arcsec: cal.as_ref().map(|c| c.seeing_fwhm_arcsec),
        lambda_over_r0_arcsec: cal.as_ref().map(|c| c.lambda_over_r0_arcsec),
        aberration: cal.as_ref().map(|c| c.aberration.clone()),
        amplitude: cal.as_ref().map(|c| c.amplitude),
        amplitude_unit: cal.as_ref().map(|c| c.amplitude_unit.to_string()),
        core_diameter_arcsec: core,
        peak_fraction: px.iter().copied().fold(0.0, f64::max),
        ee_1arcsec: ee1,
        ee_2arcsec: ee2,
        radius_1e5_arcsec: psf.radius_below(1e-5),
    })
}

/// Radius (in samples) at which the image, walked outward from sample
/// (n/2, n/2) along direction `angle_rad`, first drops below `level` × its
/// maximum; bilinear interpolation, steps of 0.05 samples. For showing the
/// shape of a core: an "+"-shaped core reaches further along its arms.
pub fn contour_radius(img: &[f64], n: usize, level: f64, angle_rad: f64) -> f64 {
    let peak = img.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let cut = level * peak;
    let c = (n / 2) as f64;
    let (dx, dy) = (angle_rad.cos(), angle_rad.sin());
    let at = |x: f64, y: f64| {
        let (i, j) = (x.floor(), y.floor());
        let (fx, fy) = (x - i, y - j);
        let (i, j) = (i as usize, j as usize);
        let v = |a: usize, b: usize| img[b * n + a];
        (1.0 - fx) * (1.0 - fy) * v(i, j)
            + fx * (1.0 - fy) * v(i + 1, j)
            + (1.0 - fx) * fy * v(i, j + 1)
            + fx * fy * v(i + 1, j + 1)
    };
    let mut r = 0.0;
    let mut prev = at(c, c);
    while r < c - 2.0 {
        let next_r = r + 0.05;
        let v = at(c + next_r * dx, c + next_r * dy);
        if v < cut {
            return r + 0.05 * (prev - cut) / (prev - v);
        }
        prev = v;
        r = next_r;
    }
    r
}

/// The two images of a PSF file (`RUN/private/psf/<name>.fits`, `stepsim
/// psf`), drawn: the pixel-convolved PSF at the image pixel scale on an
/// `n × n` grid and `oversample` times finer on `(n·oversample)²`, with the
/// measured report for the headers. [`crate::io::psf_fits::write_psf`]
/// writes it.
#[derive(Debug, Clone, PartialEq)]
pub struct DrawnPsf {
    /// The PSF's name from the config.
    pub name: String,
    /// Image pixel scale (arcsec).
    pub pixel_scale_arcsec: f64,
    /// Side of the pixel-scale image.
    pub n: usize,
    /// The pixel-scale image, row-major, unit sum.
    pub at_pixel: Vec<f64>,
    /// Samples per pixel of the fine image.
    pub oversample: usize,
    /// The fine image (side `n · oversample`), row-major, unit sum.
    pub oversampled: Vec<f64>,
    /// FWHM, χ and calibration for the header, when measured.
    pub report: Option<PsfReport>,
}

/// Draws both images of `psf`'s file (see [`DrawnPsf`]).
pub fn draw_for_file(
    name: &str,
    psf: &dyn Psf,
    pixel_scale_arcsec: f64,
    n: usize,
    oversample: usize,
    report: Option<PsfReport>,
) -> DrawnPsf {
    DrawnPsf {
        name: name.into(),
        pixel_scale_arcsec,
        n,
        at_pixel: image(psf, n, pixel_scale_arcsec, 1),
        oversample,
        oversampled: image(psf, n * oversample, pixel_scale_arcsec, oversample),
        report,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::psf::GaussianPsf;

    #[test]
    fn gaussian_image_and_fwhm() {
        // A round Gaussian without pixel blur at tiny pixels: FWHM measured
        // from the area must equal the input.
        let g = GaussianPsf::round(0.9);
        let p = 0.01;
        let n = 256;
        let img = image(&g, n, p, 1);
        let s: f64 = img.iter().sum();
        assert!((s - 1.0).abs() < 1e-6, "{s}");
        let f = fwhm_from_area(&img, n) * p;
        assert!((f - 0.9).abs() < 1e-3, "{f}");
        // Centre at (n/2, n/2): the peak sample.
        let k = img
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .unwrap()
            .0;
        assert_eq!((k % n, k / n), (n / 2, n / 2));
        // Encircled energy of a Gaussian: 1 − exp(−r²/2σ²).
        let sig = 0.9 / 2.354_820_045 / p;
        let ee = encircled(&img, n, 128.0, 128.0, sig);
        assert!((ee - (1.0 - (-0.5f64).exp())).abs() < 5e-3, "{ee}");
    }

    #[test]
    fn pixel_image_of_a_gaussian_matches_direct_integration() {
        // Slow twin: integrate the Gaussian over each pixel numerically.
        // FWHM 0.9″ at 0.2″ pixels: T × sinc at the grid's Nyquist frequency
        // is 1e-8, so the FFT route has no aliasing to speak of.
        let g = GaussianPsf::round(0.9);
        let (n, p) = (32, 0.2);
        let img = image(&g, n, p, 1);
        let sig = 0.9 / 2.354_820_045_030_949;
        for (i, j) in [(16, 16), (17, 16), (18, 19), (12, 16)] {
            let (x0, y0) = ((i as f64 - 16.0) * p, (j as f64 - 16.0) * p);
            let m = 40;
            let mut s = 0.0;
            for a in 0..m {
                for b in 0..m {
                    let x = x0 + ((a as f64 + 0.5) / m as f64 - 0.5) * p;
                    let y = y0 + ((b as f64 + 0.5) / m as f64 - 0.5) * p;
                    s += (-(x * x + y * y) / (2.0 * sig * sig)).exp();
                }
            }
            s *= (p / m as f64).powi(2) / (2.0 * std::f64::consts::PI * sig * sig);
            assert!(
                (img[j * n + i] - s).abs() < 1e-6,
                "({i},{j}) {} vs {s}",
                img[j * n + i]
            );
        }
    }
}
