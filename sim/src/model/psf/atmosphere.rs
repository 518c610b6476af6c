//! Kolmogorov long-exposure atmospheric turbulence.
//!
//! MTF(f) = exp(−3.44 (λ f / r0)^(5/3)) (Fried 1966; Roddier 1981), with f in
//! cycles per arcsec and λ/r0 in arcsec. Its PSF has
//! FWHM = 0.976 λ/r0 (tested to 1 % in `psf::tests`).

/// The Kolmogorov long-exposure transfer function.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kolmogorov {
    /// λ/r0 in arcsec.
    pub lambda_over_r0_arcsec: f64,
}

/// FWHM of the Kolmogorov PSF in units of λ/r0.
pub const FWHM_OVER_LAMBDA_R0: f64 = 0.976;

impl Kolmogorov {
    /// The screen whose PSF alone has the given FWHM.
    pub fn from_fwhm(fwhm_arcsec: f64) -> Self {
        Self {
            lambda_over_r0_arcsec: fwhm_arcsec / FWHM_OVER_LAMBDA_R0,
        }
    }

    /// Seeing FWHM of the atmosphere alone (0.976 λ/r0).
    pub fn fwhm_arcsec(&self) -> f64 {
        FWHM_OVER_LAMBDA_R0 * self.lambda_over_r0_arcsec
    }

    /// MTF at radial frequency `f` (cycles per arcsec).
    pub fn mtf(&self, f: f64) -> f64 {
        (-3.44 * (self.lambda_over_r0_arcsec * f).powf(5.0 / 3.0)).exp()
    }

    /// The frequency beyond which the MTF is below `level`.
    pub fn cutoff(&self, level: f64) -> f64 {
        (-level.ln() / 3.44).powf(0.6) / self.lambda_over_r0_arcsec
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mtf_values() {
        let k = Kolmogorov {
            lambda_over_r0_arcsec: 0.8,
        };
        assert_eq!(k.mtf(0.0), 1.0);
        // λf/r0 = 1 → exp(−3.44).
        assert!((k.mtf(1.25) - (-3.44f64).exp()).abs() < 1e-12);
        assert!((k.mtf(k.cutoff(1e-12)) - 1e-12).abs() < 1e-20);
        assert!((Kolmogorov::from_fwhm(0.9).fwhm_arcsec() - 0.9).abs() < 1e-12);
    }
}
