//! Second moments of images: plain (unweighted) and adaptive
//! (elliptical-Gaussian-weighted, HSM `FindAdaptiveMom` style).
//!
//! Coordinates are FITS pixels of the image passed in: the centre of the
//! first pixel is (1.0, 1.0), x runs along a row (NAXIS1). Images are
//! row-major, `nx` columns by `ny` rows. Moments are in pixel² units.
//!
//! The distortion of a moment tensor Q is χ = (Qxx − Qyy, 2Qxy)/(Qxx + Qyy)
//! (SPEC §1).
//!
//! **Adaptive moments.** The weight is the elliptical Gaussian
//! W(x) = exp(−½ (x−c)ᵀ M⁻¹ (x−c)); the centroid c and the matrix M are
//! iterated until c is the W-weighted centroid and M equals twice the
//! W-weighted covariance of the image. For an elliptical Gaussian image of
//! covariance C the fixed point is M = C exactly (the product of two
//! Gaussians has covariance (C⁻¹ + M⁻¹)⁻¹ = C/2), so χ of a Gaussian is
//! recovered exactly; this is the definition used by HSM (Hirata & Seljak
//! 2003, Bernstein & Jarvis 2002).

/// Centroid and second moments of an image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Moments {
    /// Sum of the pixel values (for adaptive moments: the weighted sum Σ W I).
    pub flux: f64,
    /// Centroid x (FITS pixels).
    pub x: f64,
    /// Centroid y (FITS pixels).
    pub y: f64,
    /// ⟨dx²⟩ (pixels²).
    pub qxx: f64,
    /// ⟨dy²⟩ (pixels²).
    pub qyy: f64,
    /// ⟨dx dy⟩ (pixels²).
    pub qxy: f64,
}

impl Moments {
    /// Distortion χ = (Qxx − Qyy, 2Qxy)/(Qxx + Qyy).
    pub fn chi(&self) -> (f64, f64) {
        let t = self.qxx + self.qyy;
        ((self.qxx - self.qyy) / t, 2.0 * self.qxy / t)
    }

    /// |χ|.
    pub fn chi_abs(&self) -> f64 {
        let (a, b) = self.chi();
        a.hypot(b)
    }

    /// Determinant radius σ = (Qxx Qyy − Qxy²)^(1/4) in pixels.
    pub fn sigma(&self) -> f64 {
        (self.qxx * self.qyy - self.qxy * self.qxy).sqrt().sqrt()
    }
}

/// Why adaptive moments could not be measured.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MomentsError {
    /// The (weighted) flux is not positive.
    #[error("moments: non-positive flux {0}")]
    NonPositiveFlux(f64),
    /// The image is not `nx × ny`.
    #[error("moments: image has {len} values, expected {nx}×{ny}")]
    Shape {
        /// Values given.
        len: usize,
        /// Columns.
        nx: usize,
        /// Rows.
        ny: usize,
    },
    /// The weight matrix stopped being positive definite.
    #[error("moments: weight matrix not positive definite after {0} iterations")]
    NotPositiveDefinite(usize),
    /// The iteration did not converge.
    #[error("moments: no convergence after {0} iterations")]
    NoConvergence(usize),
}

/// Plain first and second moments of the whole image (no weight).
pub fn unweighted(image: &[f64], nx: usize, ny: usize) -> Result<Moments, MomentsError> {
    if image.len() != nx * ny {
        return Err(MomentsError::Shape {
            len: image.len(),
            nx,
            ny,
        });
    }
    let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for (j, row) in image.chunks_exact(nx).enumerate() {
        for (i, &v) in row.iter().enumerate() {
            s += v;
            sx += v * (i as f64 + 1.0);
            sy += v * (j as f64 + 1.0);
        }
    }
    if s.is_nan() || s <= 0.0 {
        return Err(MomentsError::NonPositiveFlux(s));
    }
    let (x, y) = (sx / s, sy / s);
    let (mut xx, mut yy, mut xy) = (0.0, 0.0, 0.0);
    for (j, row) in image.chunks_exact(nx).enumerate() {
        let dy = j as f64 + 1.0 - y;
        for (i, &v) in row.iter().enumerate() {
            let dx = i as f64 + 1.0 - x;
            xx += v * dx * dx;
            yy += v * dy * dy;
            xy += v * dx * dy;
        }
    }
    Ok(Moments {
        flux: s,
        x,
        y,
        qxx: xx / s,
        qyy: yy / s,
        qxy: xy / s,
    })
}

/// Adaptive moments (see the module docs). `sigma_guess_px` starts the
/// weight; the start centroid is the brightest pixel. The returned moments
/// are the converged weight matrix M (so χ is the adaptive distortion) and
/// the weighted centroid; `flux` is Σ W I.
pub fn adaptive(
    image: &[f64],
    nx: usize,
    ny: usize,
    sigma_guess_px: f64,
) -> Result<Moments, MomentsError> {
    if image.len() != nx * ny {
        return Err(MomentsError::Shape {
            len: image.len(),
            nx,
            ny,
        });
    }
    let peak =
        image.iter().enumerate().fold(
            (0, f64::NEG_INFINITY),
            |b, (i, &v)| if v > b.1 { (i, v) } else { b },
        );
    let start = ((peak.0 % nx) as f64 + 1.0, (peak.0 / nx) as f64 + 1.0);
    adaptive_from(image, nx, ny, start, sigma_guess_px)
}

/// [`adaptive`] with the iteration started at `start` (FITS pixels of the
/// image) instead of the brightest pixel: measures the object there when a
/// brighter neighbour shares the image.
pub fn adaptive_from(
    image: &[f64],
    nx: usize,
    ny: usize,
    start: (f64, f64),
    sigma_guess_px: f64,
) -> Result<Moments, MomentsError> {
    if image.len() != nx * ny {
        return Err(MomentsError::Shape {
            len: image.len(),
            nx,
            ny,
        });
    }
    let (mut cx, mut cy) = (start.0 - 1.0, start.1 - 1.0);
    let s2 = sigma_guess_px.max(0.5).powi(2);
    let (mut mxx, mut myy, mut mxy) = (s2, s2, 0.0);
    const MAX_ITER: usize = 500;
    for it in 0..MAX_ITER {
        let det = mxx * myy - mxy * mxy;
        if !(det > 0.0 && mxx > 0.0) {
            return Err(MomentsError::NotPositiveDefinite(it));
        }
        let (ixx, iyy, ixy) = (myy / det, mxx / det, -mxy / det);
        // Bounding box: the weight is below e^{-32} beyond 8σ along each axis.
        let (hx, hy) = (8.0 * mxx.sqrt(), 8.0 * myy.sqrt());
        let i0 = ((cx - hx).floor().max(0.0)) as usize;
        let i1 = ((cx + hx).ceil().min(nx as f64 - 1.0)).max(0.0) as usize;
        let j0 = ((cy - hy).floor().max(0.0)) as usize;
        let j1 = ((cy + hy).ceil().min(ny as f64 - 1.0)).max(0.0) as usize;
        let (mut s, mut sx, mut sy, mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for j in j0..=j1 {
            let dy = j as f64 - cy;
            let row = &image[j * nx..(j + 1) * nx];
            for (i, &v) in row.iter().enumerate().take(i1 + 1).skip(i0) {
                let dx = i as f64 - cx;
                let rho2 = ixx * dx * dx + iyy * dy * dy + 2.0 * ixy * dx * dy;
                if rho2 > 64.0 {
                    continue;
                }
                let w = v * (-0.5 * rho2).exp();
                s += w;
                sx += w * dx;
                sy += w * dy;
                sxx += w * dx * dx;
                syy += w * dy * dy;
                sxy += w * dx * dy;
            }
        }
        if s.is_nan() || s <= 0.0 {
            return Err(MomentsError::NonPositiveFlux(s));
        }
        let (ddx, ddy) = (sx / s, sy / s);
        // Covariance about the new centroid.
        let nxx = 2.0 * (sxx / s - ddx * ddx);
        let nyy = 2.0 * (syy / s - ddy * ddy);
        let nxy = 2.0 * (sxy / s - ddx * ddy);
        cx += ddx;
        cy += ddy;
        let change = (nxx - mxx).abs() + (nyy - myy).abs() + (nxy - mxy).abs();
        let scale = nxx + nyy;
        mxx = nxx;
        myy = nyy;
        mxy = nxy;
        if !scale.is_finite() {
            return Err(MomentsError::NotPositiveDefinite(it));
        }
        if change < 1e-12 * scale && ddx.abs() + ddy.abs() < 1e-10 {
            return Ok(Moments {
                flux: s,
                x: cx + 1.0,
                y: cy + 1.0,
                qxx: mxx,
                qyy: myy,
                qxy: mxy,
            });
        }
    }
    Err(MomentsError::NoConvergence(MAX_ITER))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An elliptical Gaussian of covariance given by (σ, χ1, χ2) at (x0, y0)
    /// (FITS pixels), point-sampled.
    pub(crate) fn gaussian(n: usize, x0: f64, y0: f64, sigma: f64, chi: (f64, f64)) -> Vec<f64> {
        // C = σ² / sqrt(1 − |χ|²) [[1 + χ1, χ2], [χ2, 1 − χ1]] has det σ⁴.
        let f = sigma * sigma / (1.0 - chi.0 * chi.0 - chi.1 * chi.1).sqrt();
        let (cxx, cyy, cxy) = (f * (1.0 + chi.0), f * (1.0 - chi.0), f * chi.1);
        let det = cxx * cyy - cxy * cxy;
        let mut img = vec![0.0; n * n];
        for j in 0..n {
            for i in 0..n {
                let dx = i as f64 + 1.0 - x0;
                let dy = j as f64 + 1.0 - y0;
                let r2 = (cyy * dx * dx + cxx * dy * dy - 2.0 * cxy * dx * dy) / det;
                img[j * n + i] = 1000.0 * (-0.5 * r2).exp();
            }
        }
        img
    }

    #[test]
    fn adaptive_from_measures_the_object_at_its_start() {
        // A faint round Gaussian at (20, 20) and one 10× brighter at (60, 60):
        // from the brightest pixel the bright one is measured; started at
        // the faint one, the faint one.
        let faint = gaussian(80, 20.0, 20.0, 2.5, (0.2, 0.0));
        let bright = gaussian(80, 60.0, 60.0, 3.0, (0.0, 0.0));
        let img: Vec<f64> = faint
            .iter()
            .zip(&bright)
            .map(|(a, b)| a + 10.0 * b)
            .collect();
        let m = adaptive(&img, 80, 80, 2.0).unwrap();
        assert!((m.x - 60.0).abs() < 1e-3, "{m:?}");
        let f = adaptive_from(&img, 80, 80, (20.4, 19.6), 2.0).unwrap();
        assert!(
            (f.x - 20.0).abs() < 1e-3 && (f.y - 20.0).abs() < 1e-3,
            "{f:?}"
        );
        assert!((f.chi().0 - 0.2).abs() < 1e-5, "{:?}", f.chi());
        // Started at the brightest pixel it is `adaptive`.
        assert_eq!(adaptive_from(&img, 80, 80, (60.0, 60.0), 2.0).unwrap(), m);
    }

    #[test]
    fn adaptive_recovers_chi_of_elliptical_gaussians_to_1e5() {
        for &(sigma, chi, x0, y0) in &[
            (3.0, (0.0, 0.0), 40.3, 41.7),
            (4.0, (0.3, -0.1), 40.0, 40.5),
            (2.5, (-0.05, 0.2), 39.2, 42.9),
            (5.0, (0.6, 0.3), 41.1, 40.0),
        ] {
            let img = gaussian(80, x0, y0, sigma, chi);
            let m = adaptive(&img, 80, 80, 2.0).unwrap();
            let (c1, c2) = m.chi();
            assert!((c1 - chi.0).abs() < 1e-5, "{c1} vs {}", chi.0);
            assert!((c2 - chi.1).abs() < 1e-5, "{c2} vs {}", chi.1);
            assert!((m.x - x0).abs() < 1e-5 && (m.y - y0).abs() < 1e-5);
            assert!((m.sigma() - sigma).abs() < 1e-5 * sigma, "{}", m.sigma());
            // Unweighted moments of a Gaussian give the same tensor.
            let u = unweighted(&img, 80, 80).unwrap();
            assert!((u.chi().0 - chi.0).abs() < 1e-5 && (u.chi().1 - chi.1).abs() < 1e-5);
            assert!((u.qxx - m.qxx).abs() < 1e-5 * m.qxx);
        }
    }

    #[test]
    fn adaptive_differs_from_unweighted_on_a_two_component_image() {
        // A core plus a faint, wide, offset halo: the weight down-weights the
        // halo, so adaptive χ is smaller than unweighted χ.
        let mut img = gaussian(96, 48.0, 48.0, 3.0, (0.0, 0.0));
        let halo = gaussian(96, 48.0, 48.0, 10.0, (0.5, 0.0));
        for (a, b) in img.iter_mut().zip(&halo) {
            *a += 0.05 * b;
        }
        let a = adaptive(&img, 96, 96, 3.0).unwrap().chi_abs();
        let u = unweighted(&img, 96, 96).unwrap().chi_abs();
        assert!(a > 1e-3 && a < 0.5 * u, "adaptive {a}, unweighted {u}");
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        assert!(matches!(
            adaptive(&[0.0; 16], 4, 4, 1.0),
            Err(MomentsError::NonPositiveFlux(_))
        ));
        assert!(matches!(
            unweighted(&[1.0; 15], 4, 4),
            Err(MomentsError::Shape { .. })
        ));
        assert!(adaptive(&[f64::NAN; 16], 4, 4, 1.0).is_err());
    }
}
