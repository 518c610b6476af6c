//! Moffat PSF (Moffat 1969), for tests and quick runs.
//!
//! I(r) ∝ (1 + (r/α)²)^(−β) for r < r_trunc (0 beyond), with
//! FWHM = 2α sqrt(2^(1/β) − 1). The FWHM is that of the profile itself
//! (the renderer adds the pixel). It is represented by point samples every
//! min(FWHM/16, pixel/4) out to the truncation radius, or to where the
//! profile falls below 1e-7 of its peak (at most 1024 samples a side), and
//! handed to [`SampledPsf`]; the untruncated Moffat's transform at the
//! sampling's Nyquist frequency is below e^{−50}, so nothing aliases.

use super::sampled::SampledPsf;

/// The Moffat scale radius α for a FWHM and β.
pub fn alpha(fwhm_arcsec: f64, beta: f64) -> f64 {
    fwhm_arcsec / (2.0 * (2f64.powf(1.0 / beta) - 1.0).sqrt())
}

/// Profile value relative to the centre.
pub fn profile(r: f64, alpha: f64, beta: f64) -> f64 {
    (1.0 + (r / alpha).powi(2)).powf(-beta)
}

/// A sampled Moffat PSF.
pub fn moffat(fwhm_arcsec: f64, beta: f64, trunc_fwhm: f64, pixel_scale_arcsec: f64) -> SampledPsf {
    let a = alpha(fwhm_arcsec, beta);
    let s = (fwhm_arcsec / 16.0).min(pixel_scale_arcsec / 4.0);
    let r_far = a * (1e7f64.powf(1.0 / beta) - 1.0).sqrt();
    let r_max = if trunc_fwhm > 0.0 {
        trunc_fwhm * fwhm_arcsec
    } else {
        r_far
    };
    let n = ((2.0 * r_max / s).ceil() as usize + 2).div_ceil(2) * 2;
    let n = n.clamp(16, 1024);
    let c = (n / 2) as f64;
    let mut v = vec![0.0; n * n];
    for j in 0..n {
        for i in 0..n {
            let r = ((i as f64 - c) * s).hypot((j as f64 - c) * s);
            if trunc_fwhm <= 0.0 || r < r_max {
                v[j * n + i] = profile(r, a, beta);
            }
        }
    }
    SampledPsf::new(v, n, s, (0.0, 0.0)).expect("Moffat has flux")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::psf::Psf;
    use crate::model::psf::measure::fwhm_from_area;

    #[test]
    fn fwhm_and_normalisation() {
        for (beta, trunc) in [(3.5, 0.0), (2.5, 4.0)] {
            let p = moffat(0.9, beta, trunc, 0.2);
            let f = fwhm_from_area(p.values(), p.n()) * p.spacing_arcsec();
            assert!((f - 0.9).abs() < 2e-3, "β {beta}: {f}");
            let s: f64 = p.values().iter().sum();
            assert!((s - 1.0).abs() < 1e-12);
            // T(0) = 1 and T falls with frequency.
            let t = p.transfer(crate::model::psf::StampGrid::new(32, 0.2));
            assert!((t[0].re - 1.0).abs() < 1e-6);
            assert!(t[5].re < t[1].re);
        }
        // Half maximum exactly at FWHM/2.
        let a = alpha(0.9, 3.0);
        assert!((profile(0.45, a, 3.0) - 0.5).abs() < 1e-12);
    }
}
