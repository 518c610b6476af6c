//! A PSF read from a FITS image (primary HDU).
//!
//! The image is taken as point samples of the PSF's surface brightness
//! **without** the pixel response (the renderer applies its own pixel), at
//! the `pixel_scale_arcsec` given in the config. It is normalised to unit
//! sum, padded with zeros to a square of even side, and recentred on its
//! light centroid. Frequencies above the file's Nyquist frequency are zero.

use super::PsfError;
use super::sampled::SampledPsf;

/// Builds a [`SampledPsf`] from an `nx × ny` image (row-major).
pub fn from_image(
    name: &str,
    path: &str,
    values: &[f64],
    nx: usize,
    ny: usize,
    pixel_scale_arcsec: f64,
) -> Result<SampledPsf, PsfError> {
    let bad = |message: String| PsfError::BadImage {
        name: name.into(),
        path: path.into(),
        message,
    };
    if nx == 0 || ny == 0 || values.len() != nx * ny {
        return Err(bad(format!(
            "image is {nx}×{ny} with {} values",
            values.len()
        )));
    }
    if let Some(k) = values.iter().position(|v| !v.is_finite()) {
        return Err(bad(format!(
            "pixel ({}, {}) is not finite",
            k % nx + 1,
            k / nx + 1
        )));
    }
    let sum: f64 = values.iter().sum();
    if sum <= 0.0 {
        return Err(bad(format!("pixel sum is {sum}, must be > 0")));
    }
    let n = nx.max(ny).div_ceil(2) * 2;
    // Place the image so that its centre pixel ((nx−1)/2 rounded up) lands on n/2.
    let (ox, oy) = (n / 2 - nx / 2, n / 2 - ny / 2);
    let mut sq = vec![0.0; n * n];
    for j in 0..ny {
        for i in 0..nx {
            sq[(j + oy) * n + i + ox] = values[j * nx + i];
        }
    }
    let c = SampledPsf::grid_centroid(&sq, n, pixel_scale_arcsec);
    SampledPsf::new(sq, n, pixel_scale_arcsec, c).ok_or_else(|| bad("no usable flux".into()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::psf::{GaussianPsf, Psf, StampGrid};

    #[test]
    fn gaussian_image_gives_the_gaussian_transfer_and_is_recentred() {
        // A well-sampled Gaussian (σ = 4 samples, > 6σ from every edge),
        // off-centre, odd-sized.
        let (nx, ny, s, sig) = (61, 57, 0.05, 0.2);
        let mut v = vec![0.0; nx * ny];
        for j in 0..ny {
            for i in 0..nx {
                let (x, y) = ((i as f64 - 30.3) * s, (j as f64 - 27.6) * s);
                v[j * nx + i] = (-(x * x + y * y) / (2.0 * sig * sig)).exp();
            }
        }
        let p = from_image("f", "f.fits", &v, nx, ny, s).unwrap();
        let g = GaussianPsf::round(sig * 2.354_820_045_030_949);
        let grid = StampGrid::new(32, 0.2);
        let (a, b) = (p.transfer(grid), g.transfer(grid));
        for (x, y) in a.iter().zip(b.iter()) {
            // Recentred: no phase left; magnitudes agree.
            assert!(
                (x.re - y.re).abs() < 1e-5 && x.im.abs() < 1e-5,
                "{x} vs {y}"
            );
        }
    }

    #[test]
    fn bad_images_are_refused_with_the_reason() {
        let e = from_image("f", "x.fits", &[1.0, f64::NAN, 0.0, 0.0], 2, 2, 0.1).unwrap_err();
        assert!(e.to_string().contains("pixel (2, 1) is not finite"), "{e}");
        let e = from_image("f", "x.fits", &[0.0; 4], 2, 2, 0.1).unwrap_err();
        assert!(e.to_string().contains("x.fits"), "{e}");
    }
}
