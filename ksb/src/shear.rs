//! The KSB+ shear estimator, its noise, and the weights.
//!
//! With a galaxy's e, P^sm, P^sh at its r_g and the PSF model's p and
//! R = ½Tr P^sh* / ½Tr P^sm* at its position and r_g:
//!
//! * anisotropy correction (paper eq. 12): e_cor = e − P^sm p (full tensor);
//! * P^γ = ½Tr P^sh − R ½Tr P^sm (paper eq. 15, scalar half-trace form;
//!   KSB table "½Tr[P^γ]");
//! * γ̂ = e_cor / P^γ (paper eq. 16 with a scalar P^γ).
//!
//! Noise: σ_γ = σ_e / P^γ, with σ_e the pixel-noise error of e per
//! component (rms of the two, [`crate::moments`]). Weight (Hoekstra et al.
//! 2000, appendix A): w = 1 / (σ_int² + σ_γ²).
//!
//! Optionally ([`crate::params::PgammaMode::FitSize`]) P^γ is replaced by a
//! smooth fit against size: a cubic polynomial in t = ln(r_g / r_g*) fitted
//! to the good galaxies of the image by least squares with 3σ clipping
//! (as HH and MB fit ½Tr P^γ(r_g)), under the workspace's one clipping rule
//! ([`stepsim_numerics::fit`]: a clipped galaxy stays out).

use crate::linalg::{half_trace, mul_vec};
use crate::moments::KsbShape;
#[cfg(doc)]
use crate::params::SizeCut;
use crate::psf_model::PsfCorrection;
use stepsim_numerics::fit::{Clip, fit_clipped};

/// A galaxy's shear estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShearEstimate {
    /// PSF-anisotropy-corrected ellipticity e − P^sm p.
    pub e_cor: [f64; 2],
    /// ½Tr P^γ used.
    pub pgamma: f64,
    /// γ̂.
    pub gamma: [f64; 2],
    /// Noise σ of γ̂ per component.
    pub sigma_gamma: f64,
}

/// ½Tr P^γ of a galaxy.
pub fn pgamma(shape: &KsbShape, corr: &PsfCorrection) -> f64 {
    half_trace(&shape.psh) - corr.ratio * half_trace(&shape.psm)
}

/// The anisotropy-corrected ellipticity e − P^sm p.
pub fn e_cor(shape: &KsbShape, corr: &PsfCorrection) -> [f64; 2] {
    let sm = mul_vec(&shape.psm, corr.p);
    [shape.e[0] - sm[0], shape.e[1] - sm[1]]
}

/// The estimate with a given P^γ.
pub fn estimate_with(shape: &KsbShape, corr: &PsfCorrection, pgamma: f64) -> ShearEstimate {
    let e_cor = e_cor(shape, corr);
    let sigma_e = (0.5 * (shape.sigma_e[0].powi(2) + shape.sigma_e[1].powi(2))).sqrt();
    ShearEstimate {
        e_cor,
        pgamma,
        gamma: [e_cor[0] / pgamma, e_cor[1] / pgamma],
        sigma_gamma: sigma_e / pgamma.abs(),
    }
}

/// The estimate with the galaxy's own P^γ.
#[cfg(test)]
pub fn estimate(shape: &KsbShape, corr: &PsfCorrection) -> ShearEstimate {
    estimate_with(shape, corr, pgamma(shape, corr))
}

/// Weight w = 1 / (σ_int² + σ_γ²).
pub fn weight(sigma_gamma: f64, sigma_int: f64) -> f64 {
    1.0 / (sigma_int * sigma_int + sigma_gamma * sigma_gamma)
}

/// The size the `SMALL` cut compares with `size_min_factor` × r_g* under
/// [`SizeCut::PsfCorrected`]: the r_g of the round object whose
/// PSF-corrected area equals this one's.
///
/// r_g alone follows the shear to first order in g·e: the PSF adds to both
/// axes of a sheared galaxy, so a galaxy stretched along the shear grows and
/// one stretched across it shrinks, and a cut on r_g keeps more of the first
/// (docs/baseline.md, "The size cut's selection"). For a Gaussian of axes
/// a ≥ b (σ's) the windowed r_g is √(ab) and the weighted e is
/// (a − b)/(a + b), so its second moments are the tensor
/// M = r_g²/(1 − e²) [[1 + e² + 2e₁, 2e₂], [2e₂, 1 + e² − 2e₁]] (trace
/// 2 r_g² (1 + e²)/(1 − e²), determinant r_g⁴). The star's (r_g*, e*) give
/// the PSF's tensor P the same way, and the galaxy's own moments are M − P,
/// whose determinant a shear (determinant 1) keeps. An elliptical PSF must
/// be taken out as the tensor it is: with e* left out, a galaxy lying across
/// the PSF's anisotropy keeps more of its area than one aligned with it, and
/// the cut selects on the PSF's direction (c₁ −0.006 with the jitter PSF on
/// isolated galaxies, docs/baseline.md). The result is √(√det(M − P) +
/// r_g*²): r_g itself for a round object of r_g ≥ r_g* through a round PSF.
/// An object whose M − P is not positive definite (smaller than the PSF
/// along some axis), or with |e| ≥ 1, or a PSF with |e*| ≥ 1, gets r_g*,
/// below any cut; a NaN input gives NaN.
pub fn psf_corrected_size(rg: f64, e: [f64; 2], rg_star: f64, e_star: [f64; 2]) -> f64 {
    if [rg, e[0], e[1], rg_star, e_star[0], e_star[1]]
        .iter()
        .any(|v| v.is_nan())
    {
        return f64::NAN;
    }
    let det = match (moment_tensor(rg, e), moment_tensor(rg_star, e_star)) {
        (Some(m), Some(p)) => {
            let det = (m[0] - p[0]) * (m[1] - p[1]) - (m[2] - p[2]).powi(2);
            // Positive definite: a positive determinant and diagonal.
            if m[0] - p[0] > 0.0 { det } else { 0.0 }
        }
        _ => 0.0,
    };
    (det.max(0.0).sqrt() + rg_star * rg_star).sqrt()
}

/// (M₁₁, M₂₂, M₁₂) of the Gaussian whose windowed r_g and e these are
/// ([`psf_corrected_size`]); `None` for |e| ≥ 1 (a line).
fn moment_tensor(rg: f64, e: [f64; 2]) -> Option<[f64; 3]> {
    let e2 = e[0] * e[0] + e[1] * e[1];
    if e2 >= 1.0 {
        return None;
    }
    let s = rg * rg / (1.0 - e2);
    Some([
        s * (1.0 + e2 + 2.0 * e[0]),
        s * (1.0 + e2 - 2.0 * e[0]),
        s * 2.0 * e[1],
    ])
}

/// A fit of P^γ against t = ln(r_g / r_g*).
#[derive(Debug, Clone, PartialEq)]
pub struct PgammaFit {
    /// r_g* of the image.
    pub rg_star: f64,
    /// Polynomial coefficients in t, constant first.
    pub coef: Vec<f64>,
    /// Range of t covered by the data (evaluation is clamped to it).
    pub t_range: (f64, f64),
}

impl PgammaFit {
    /// Fits (r_g, P^γ) pairs; `None` with fewer than 20 points.
    pub fn fit(points: &[(f64, f64)], rg_star: f64) -> Option<Self> {
        if points.len() < 20 {
            return None;
        }
        let ts: Vec<f64> = points.iter().map(|p| (p.0 / rg_star).ln()).collect();
        let t_range = (
            ts.iter().copied().fold(f64::INFINITY, f64::min),
            ts.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        );
        let degree = if points.len() >= 60 { 3 } else { 1 };
        let values: Vec<f64> = points.iter().map(|p| p.1).collect();
        let powers = |i: usize, m: usize, out: &mut Vec<f64>| {
            out.clear();
            out.extend((0..m).map(|k| ts[i].powi(k as i32)));
        };
        let clip = Clip {
            kappa: 3.0,
            max_passes: 10,
            min_points: 20,
        };
        let fit = fit_clipped(&[&values], powers, |_| degree + 1, clip)?;
        let coef = fit.coef.into_iter().next()?;
        Some(Self {
            rg_star,
            coef,
            t_range,
        })
    }

    /// Fitted P^γ at size `rg`.
    pub fn eval(&self, rg: f64) -> f64 {
        let t = (rg / self.rg_star)
            .ln()
            .clamp(self.t_range.0, self.t_range.1);
        self.coef
            .iter()
            .enumerate()
            .map(|(i, c)| c * t.powi(i as i32))
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;
    use crate::moments::ksb_integrals;
    use crate::scene::{convolve, covariance, draw_gaussian_integrated, shear_covariance};

    /// Draws one pixel-integrated, noise-free Gaussian at (32.3, 31.8) of a
    /// 64² stamp and measures its KSB shape at its windowed r_g.
    fn measure(cov: &crate::linalg::Mat2, rg: Option<f64>) -> KsbShape {
        let mut img = Image::zeros(64, 64);
        draw_gaussian_integrated(&mut img, 32.3, 31.8, 1e4, cov);
        let s = crate::centroid::WindowSettings {
            radius_rg: 5.0,
            rg_min: 0.5,
            rg_max: 15.0,
            tol: 1e-8,
            max_iter: 300,
        };
        let c = crate::centroid::windowed(&img, 32.0, 32.0, rg.unwrap_or(2.0), rg.is_none(), &s)
            .unwrap();
        ksb_integrals(&img, c.x, c.y, c.rg, 5.0 * c.rg, None)
            .shape()
            .unwrap()
    }

    /// Ring-averaged γ̂ − g of noise-free galaxies of σ `sigma` and
    /// intrinsic |e_s| = `es` at 8 position angles, sheared by `g`, through
    /// the PSF of covariance `psf`; stars (the PSF alone) measured at each
    /// galaxy's r_g.
    fn ring_error(psf: &crate::linalg::Mat2, sigma: f64, es: f64, g: [f64; 2]) -> [f64; 2] {
        let n = 8;
        let mut err = [0.0; 2];
        for k in 0..n {
            let th = std::f64::consts::PI * k as f64 / n as f64;
            let e = [es * (2.0 * th).cos(), es * (2.0 * th).sin()];
            let gal = convolve(&shear_covariance(&covariance(sigma, e), g), psf);
            let shape = measure(&gal, None);
            let star = measure(psf, Some(shape.sigma_w));
            let corr = PsfCorrection::of_star(&star).unwrap();
            let est = estimate(&shape, &corr);
            for c in 0..2 {
                err[c] += (est.gamma[c] - g[c]) / n as f64;
            }
        }
        err
    }

    #[test]
    fn ksb_recovers_a_known_shear_through_an_anisotropic_gaussian_psf() {
        // Noise-free Gaussian galaxies sheared by g, convolved with an
        // elliptical Gaussian PSF (FWHM 4.37 px = 0.9″ at 0.206″/px,
        // e* = (0.05, −0.03)), integrated over pixels. Requirement: the
        // ring-averaged γ̂ equals g within 1e-3 per component.
        // Measured (docs/ksb.md): round sources ≤ 2.3e-4 for σ ≥ 2 px
        // (6e-4 at σ = 1 px); |e_s| = 0.2 rings ≤ 7e-4 for σ ≥ 2.5 px — the
        // KSB approximation grows with ellipticity and PSF/galaxy size.
        let psf = covariance(4.37 / 2.3548, [0.05, -0.03]);
        for g in [[0.05, 0.0], [-0.02, 0.04], [0.0, 0.0]] {
            for (sigma, es) in [(1.5, 0.0), (2.0, 0.0), (3.5, 0.0), (2.5, 0.2), (3.5, 0.2)] {
                let err = ring_error(&psf, sigma, es, g);
                assert!(
                    err[0].abs() < 1e-3 && err[1].abs() < 1e-3,
                    "σ {sigma}, |e_s| {es}, g {g:?}: ⟨γ̂⟩ − g = {err:?}"
                );
            }
        }
        // Round PSF, round sources: KSB is exact up to pixelisation (2e-5).
        let round = covariance(4.37 / 2.3548, [0.0, 0.0]);
        let err = ring_error(&round, 2.0, 0.0, [0.05, 0.02]);
        assert!(err[0].abs() < 1e-4 && err[1].abs() < 1e-4, "{err:?}");
    }

    #[test]
    fn the_psf_corrected_size_does_not_follow_the_shear() {
        // Elliptical Gaussians (geometric-mean σ 1.5 px, |e_s| 0.4, eq. 1)
        // through a round Gaussian PSF of FWHM 4.37 px, sheared by ±0.05
        // along and across their major axis: r_g moves at first order in
        // g·e (the SMALL cut's selection bias), the PSF-corrected size
        // must not.
        let psf = covariance(4.37 / 2.3548, [0.0, 0.0]);
        let star = measure(&psf, None);
        let rg_star = star.sigma_w;
        // The pixel adds 1/12 px² to σ².
        let sigma_pix = ((4.37_f64 / 2.3548).powi(2) + 1.0 / 12.0).sqrt();
        assert!((rg_star - sigma_pix).abs() < 1e-3, "{rg_star}");
        for th in [0.0_f64, 0.3, 1.1] {
            let e = [0.4 * (2.0 * th).cos(), 0.4 * (2.0 * th).sin()];
            let along = [0.05 * (2.0 * th).cos(), 0.05 * (2.0 * th).sin()];
            let size_of = |g: [f64; 2]| {
                let s = measure(
                    &convolve(&shear_covariance(&covariance(1.5, e), g), &psf),
                    None,
                );
                (
                    s.sigma_w,
                    psf_corrected_size(s.sigma_w, s.e, rg_star, [0.0; 2]),
                )
            };
            let (rg_up, size_up) = size_of(along);
            let (rg_down, size_down) = size_of([-along[0], -along[1]]);
            let (rg_0, size_0) = size_of([0.0, 0.0]);
            let moved = (rg_up - rg_down) / rg_0;
            let kept = (size_up - size_down) / size_0;
            assert!(moved > 5e-3, "θ {th}: r_g moved {moved}");
            // Measured: r_g 1.9 %, the size 4e-6 … 5e-6.
            assert!(kept.abs() < 2e-5, "θ {th}: size moved {kept} (r_g {moved})");
        }
        // A round object's size is its r_g; a line's is r_g*.
        let round = [0.0; 2];
        assert!((psf_corrected_size(2.7, round, 1.9, round) - 2.7).abs() < 1e-12);
        assert_eq!(psf_corrected_size(2.7, [0.8, 0.7], 1.9, round), 1.9);
        assert!(psf_corrected_size(f64::NAN, round, 1.9, round).is_nan());
        assert!(psf_corrected_size(2.7, [f64::NAN, 0.0], 1.9, round).is_nan());
        assert!(psf_corrected_size(2.7, round, 1.9, [0.1, f64::NAN]).is_nan());
        // Smaller than the PSF: r_g* (M − P negative definite has a
        // positive determinant too).
        assert_eq!(psf_corrected_size(0.8, round, 1.86, round), 1.86);
        assert_eq!(psf_corrected_size(1.8, [0.3, 0.0], 1.86, round), 1.86);
    }

    #[test]
    fn the_psf_corrected_size_takes_out_an_elliptical_psf() {
        // One elliptical Gaussian galaxy (σ 1.5 px, |e_s| 0.3, eq. 1) turned
        // to eight position angles and drawn through an elliptical Gaussian
        // PSF (FWHM 4.37 px, e 0.08 along x, then at 45°): its own area does
        // not depend on how it lies against the PSF, so the PSF-corrected
        // size with the star's e* must not either, and must be the galaxy's
        // own √(√det C + r_g*²); with e* taken as 0 it follows the angle
        // (the SMALL cut's additive selection).
        for psf_e in [[0.08, 0.0], [0.0, 0.08]] {
            let psf = covariance(4.37 / 2.3548, psf_e);
            let star = measure(&psf, None);
            let (rg_star, e_star) = (star.sigma_w, star.e);
            assert!(e_star[0].hypot(e_star[1]) > 0.03, "{e_star:?}");
            let mut with_e = Vec::new();
            let mut without = Vec::new();
            for k in 0..8 {
                let th = std::f64::consts::PI * k as f64 / 8.0;
                let e = [0.3 * (2.0 * th).cos(), 0.3 * (2.0 * th).sin()];
                let galaxy = covariance(1.5, e);
                let s = measure(&convolve(&galaxy, &psf), None);
                with_e.push(psf_corrected_size(s.sigma_w, s.e, rg_star, e_star));
                without.push(psf_corrected_size(s.sigma_w, s.e, rg_star, [0.0; 2]));
            }
            let spread = |v: &[f64]| {
                let (lo, hi) = v
                    .iter()
                    .fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
                (hi - lo) / lo
            };
            // Measured: 6.7 % without e*, 3.4e-6 with it; the galaxy's own
            // size to 2.5e-5.
            assert!(spread(&without) > 0.02, "without e*: {without:?}");
            assert!(spread(&with_e) < 2e-5, "with e*: {with_e:?}");
            let own = (1.5_f64.powi(2) + rg_star * rg_star).sqrt();
            for v in &with_e {
                assert!((v / own - 1.0).abs() < 1e-4, "{v} against {own}");
            }
        }
    }

    #[test]
    fn pgamma_fit_follows_a_smooth_relation_and_ignores_outliers() {
        let rg_star = 2.0;
        let truth = |rg: f64| 0.9 - 0.6 * (rg_star / rg).powi(2);
        let mut pts = Vec::new();
        for k in 0..100 {
            let rg = 2.2 + 0.05 * k as f64;
            let noise = 0.01 * ((k * 7 % 11) as f64 - 5.0) / 5.0;
            pts.push((rg, truth(rg) + noise + if k % 25 == 0 { 1.0 } else { 0.0 }));
        }
        let f = PgammaFit::fit(&pts, rg_star).unwrap();
        for rg in [2.3, 3.5, 6.0] {
            assert!(
                (f.eval(rg) - truth(rg)).abs() < 0.01,
                "{rg}: {}",
                f.eval(rg)
            );
        }
        // Clamped beyond the data.
        assert_eq!(f.eval(100.0), f.eval(2.2 + 0.05 * 99.0));
        assert!(PgammaFit::fit(&pts[..10], rg_star).is_none());
        assert!((weight(0.4, 0.3) - 4.0).abs() < 1e-12);
    }
}
