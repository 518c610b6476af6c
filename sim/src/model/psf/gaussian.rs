//! Elliptical Gaussian PSF.
//!
//! I(x) = F / (2π σ² ) exp(−|A x|² / (2σ²)) for the area-preserving shear
//! matrix A of ellipticity e (SPEC §1), so σ is the geometric-mean width and
//! FWHM = 2 sqrt(2 ln 2) σ along the geometric mean axis. Its transform is
//! T(k) = exp(−2π² σ² |A⁻ᵀ k|²) with k in cycles per arcsec.

use super::{Psf, StampGrid};
use num_complex::Complex32;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// An elliptical Gaussian PSF.
#[derive(Debug)]
pub struct GaussianPsf {
    sigma_arcsec: f64,
    /// Inverse-transpose of the shear matrix, for the transform.
    ainv_t: [[f64; 2]; 2],
    cache: Mutex<HashMap<StampGrid, Arc<Vec<Complex32>>>>,
}

impl GaussianPsf {
    /// A round Gaussian of the given FWHM.
    pub fn round(fwhm_arcsec: f64) -> Self {
        Self::elliptical(fwhm_arcsec, 0.0, 0.0)
    }

    /// An elliptical Gaussian: geometric-mean FWHM and eq. 1 ellipticity (e1, e2).
    pub fn elliptical(fwhm_arcsec: f64, e1: f64, e2: f64) -> Self {
        let sigma_arcsec = fwhm_arcsec / (2.0 * (2.0 * std::f64::consts::LN_2).sqrt());
        // A maps the elliptical image onto a circle: the shear matrix of g = e
        // (a circle sheared by g has ellipticity g, SPEC §1).
        let a = stepsim_contract::shear::shear_matrix(e1, e2);
        // det A = 1, A symmetric: A⁻ᵀ = A⁻¹ = [[a11, −a01], [−a10, a00]].
        let ainv_t = [[a[1][1], -a[0][1]], [-a[1][0], a[0][0]]];
        Self {
            sigma_arcsec,
            ainv_t,
            cache: Mutex::new(HashMap::new()),
        }
    }

    /// σ in arcsec (geometric mean).
    pub fn sigma_arcsec(&self) -> f64 {
        self.sigma_arcsec
    }

    /// T(u, v) at one frequency (cycles per arcsec).
    pub fn transfer_at(&self, u: f64, v: f64) -> f64 {
        let m = &self.ainv_t;
        let (ku, kv) = (m[0][0] * u + m[0][1] * v, m[1][0] * u + m[1][1] * v);
        let s = std::f64::consts::PI * self.sigma_arcsec;
        (-2.0 * s * s * (ku * ku + kv * kv)).exp()
    }
}

impl Psf for GaussianPsf {
    fn transfer(&self, grid: StampGrid) -> Arc<Vec<Complex32>> {
        let mut cache = self.cache.lock().expect("psf cache lock");
        cache
            .entry(grid)
            .or_insert_with(|| {
                let mut t = Vec::with_capacity(grid.n * grid.n_cols());
                for row in 0..grid.n {
                    for col in 0..grid.n_cols() {
                        let (u, v) = grid.frequency(row, col);
                        t.push(Complex32::new(self.transfer_at(u, v) as f32, 0.0));
                    }
                }
                Arc::new(t)
            })
            .clone()
    }

    fn radius_enclosing(&self, fraction: f64) -> f64 {
        // Round-equivalent: enclosed flux 1 − exp(−r²/2σ²); widen by the
        // major-axis stretch so the bound holds for the ellipse too.
        let f = fraction.clamp(0.0, 1.0 - 1e-15);
        let stretch = self.ainv_t[0][0].max(self.ainv_t[1][1]) + self.ainv_t[0][1].abs();
        self.sigma_arcsec * (-2.0 * (1.0 - f).ln()).sqrt() * stretch
    }

    fn radius_below(&self, level: f64) -> f64 {
        let stretch = self.ainv_t[0][0].max(self.ainv_t[1][1]) + self.ainv_t[0][1].abs();
        self.sigma_arcsec * (-2.0 * level.clamp(1e-300, 1.0).ln()).sqrt() * stretch
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_transfer_matches_closed_form_and_is_one_at_zero() {
        let p = GaussianPsf::round(0.9);
        let grid = StampGrid::new(32, 0.2);
        let t = p.transfer(grid);
        assert_eq!(t.len(), 32 * 17);
        assert!((t[0].re - 1.0).abs() < 1e-7);
        let s = 0.9 / 2.354_820_045_030_949;
        for (row, col) in [(0, 3), (5, 0), (31, 16), (17, 9)] {
            let (u, v) = grid.frequency(row, col);
            let want = (-2.0 * (std::f64::consts::PI * s).powi(2) * (u * u + v * v)).exp();
            assert!((f64::from(t[row * 17 + col].re) - want).abs() < 1e-7);
        }
        // Cached: the same Arc comes back.
        assert!(Arc::ptr_eq(&t, &p.transfer(grid)));
    }

    #[test]
    fn elliptical_transfer_is_narrower_along_the_stretched_axis() {
        // e1 > 0 stretches the image along x, so T falls faster along u.
        let p = GaussianPsf::elliptical(0.9, 0.2, 0.0);
        assert!(p.transfer_at(0.5, 0.0) < p.transfer_at(0.0, 0.5));
        let q = GaussianPsf::elliptical(0.9, 0.0, 0.2);
        // e2 > 0 stretches along y = x.
        assert!(q.transfer_at(0.4, 0.4) < q.transfer_at(0.4, -0.4));
    }
}
