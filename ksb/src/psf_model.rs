//! The PSF model: anisotropy p_μ and the stellar polarisability ratio across
//! the field, as functions of the weight scale r_g (KSB table rows "PSF: 2D
//! polynomial model" and "P^γ correction"; the CH / TS / HH choice of
//! measuring stars with the galaxy's r_g).
//!
//! For each scale r_k of a geometric ladder (ratio `scale_step`) covering
//! the galaxies' sizes, every PSF star is re-centred with a window of r_k
//! and measured at r_k:
//! * p = (P^sm*)⁻¹ e* (paper eq. 13, the full 2 × 2 inverse), and
//! * R = ½Tr P^sh* / ½Tr P^sm*, the scalar form of (P^sm*)⁻¹ P^sh* used in
//!   P^γ = P^sh − P^sm R (paper eq. 15 with half-traces).
//!
//! p₁, p₂ and R are each fitted by a polynomial in (x, y)
//! ([`crate::polynomial`]) with joint κσ clipping, order `psf_order`, lowered
//! to what the number of stars supports. A galaxy of size r_g takes the
//! models of the two neighbouring scales, interpolated linearly in ln r_g
//! (clamped at the ends of the ladder).

use crate::centroid::{WindowSettings, windowed};
use crate::image::Image;
use crate::linalg::{half_trace, inverse, mul_vec};
use crate::moments::{KsbShape, PixelNoise, ksb_integrals};
use crate::params::KsbParams;
use crate::polynomial::{FieldFrame, Poly2, fit_clipped};
use rayon::prelude::*;

/// The PSF correction at one position and scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PsfCorrection {
    /// Anisotropy p_μ.
    pub p: [f64; 2],
    /// ½Tr P^sh* / ½Tr P^sm*.
    pub ratio: f64,
}

impl PsfCorrection {
    /// The correction a star's KSB shape gives: p = (P^sm*)⁻¹ e* and
    /// R = ½Tr P^sh* / ½Tr P^sm*; `None` if P^sm* is singular.
    pub fn of_star(star: &KsbShape) -> Option<Self> {
        Some(Self {
            p: mul_vec(&inverse(&star.psm)?, star.e),
            ratio: half_trace(&star.psh) / half_trace(&star.psm),
        })
    }
}

/// The model at one weight scale.
#[derive(Debug, Clone, PartialEq)]
pub struct ScaleModel {
    /// The weight scale (pixels).
    pub rg: f64,
    /// Fits of p₁, p₂, R.
    pub fits: Vec<Poly2>,
    /// Stars kept after clipping.
    pub n_used: usize,
}

/// The PSF model of one image.
#[derive(Debug, Clone, PartialEq)]
pub struct PsfModel {
    /// Models by increasing scale.
    pub scales: Vec<ScaleModel>,
}

/// One star's measurement at one scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StarAtScale {
    /// Centre, array coordinates.
    pub x: f64,
    /// Centre, array coordinates.
    pub y: f64,
    /// p_μ.
    pub p: [f64; 2],
    /// ½Tr P^sh* / ½Tr P^sm*.
    pub ratio: f64,
}

/// Measures one star (from centre `(x, y)`) at scale `rg`.
pub fn star_at_scale(
    img: &Image,
    x: f64,
    y: f64,
    rg: f64,
    noise: Option<PixelNoise>,
    params: &KsbParams,
) -> Option<StarAtScale> {
    let s = WindowSettings {
        rg_min: rg,
        rg_max: rg,
        ..params.window_settings()
    };
    let c = windowed(img, x, y, rg, false, &s)?;
    if !c.converged || (c.x - x).hypot(c.y - y) > params.centroid_max_shift_px {
        return None;
    }
    let shape = ksb_integrals(img, c.x, c.y, rg, params.window_radius_rg * rg, noise).shape()?;
    let PsfCorrection { p, ratio } = PsfCorrection::of_star(&shape)?;
    (p[0].is_finite() && p[1].is_finite() && ratio.is_finite()).then_some(StarAtScale {
        x: c.x,
        y: c.y,
        p,
        ratio,
    })
}

impl PsfModel {
    /// Builds the model from stars at `stars` (array coordinates) for
    /// weight scales from `rg_lo` to `rg_hi`. Scales with fewer than
    /// `psf_min_stars` usable stars are left out; `None` if none is left.
    pub fn build(
        img: &Image,
        stars: &[(f64, f64)],
        rg_lo: f64,
        rg_hi: f64,
        params: &KsbParams,
    ) -> Option<Self> {
        let n_scales = ((rg_hi / rg_lo).ln() / params.scale_step.ln())
            .ceil()
            .max(0.0) as usize
            + 1;
        let frame = FieldFrame::of_image(img.width, img.height);
        let scales: Vec<Option<ScaleModel>> = (0..n_scales)
            .into_par_iter()
            .map(|k| {
                let rg = rg_lo * params.scale_step.powi(k as i32);
                let m: Vec<StarAtScale> = stars
                    .iter()
                    .filter_map(|&(x, y)| star_at_scale(img, x, y, rg, None, params))
                    .collect();
                let xy: Vec<(f64, f64)> = m.iter().map(|s| (s.x, s.y)).collect();
                let vals = vec![
                    m.iter().map(|s| s.p[0]).collect(),
                    m.iter().map(|s| s.p[1]).collect(),
                    m.iter().map(|s| s.ratio).collect(),
                ];
                let (fits, keep) = fit_stars(frame, &xy, &vals, params)?;
                Some(ScaleModel {
                    rg,
                    fits,
                    n_used: keep.iter().filter(|k| **k).count(),
                })
            })
            .collect();
        let scales: Vec<ScaleModel> = scales.into_iter().flatten().collect();
        (!scales.is_empty()).then_some(Self { scales })
    }

    /// The correction at (x, y) for weight scale `rg`.
    pub fn at(&self, x: f64, y: f64, rg: f64) -> PsfCorrection {
        let eval = |s: &ScaleModel| PsfCorrection {
            p: [s.fits[0].eval(x, y), s.fits[1].eval(x, y)],
            ratio: s.fits[2].eval(x, y),
        };
        let n = self.scales.len();
        if n == 1 || rg <= self.scales[0].rg {
            return eval(&self.scales[0]);
        }
        if rg >= self.scales[n - 1].rg {
            return eval(&self.scales[n - 1]);
        }
        let k = self.scales.partition_point(|s| s.rg <= rg).clamp(1, n - 1);
        let (a, b) = (&self.scales[k - 1], &self.scales[k]);
        let t = (rg.ln() - a.rg.ln()) / (b.rg.ln() - a.rg.ln());
        let (ca, cb) = (eval(a), eval(b));
        PsfCorrection {
            p: [
                (1.0 - t) * ca.p[0] + t * cb.p[0],
                (1.0 - t) * ca.p[1] + t * cb.p[1],
            ],
            ratio: (1.0 - t) * ca.ratio + t * cb.ratio,
        }
    }

    /// Polynomial order used (at the first scale).
    pub fn order(&self) -> usize {
        self.scales.first().map_or(0, |s| s.fits[0].order)
    }
}

/// Polynomials across the field of the stars' `values` at `xy`, with the
/// PSF model's order, clipping and star counts (`psf_order`,
/// `psf_clip_sigma`, `psf_stars_per_term`, `psf_min_stars`).
fn fit_stars(
    frame: FieldFrame,
    xy: &[(f64, f64)],
    values: &[Vec<f64>],
    params: &KsbParams,
) -> Option<(Vec<Poly2>, Vec<bool>)> {
    fit_clipped(
        frame,
        xy,
        values,
        params.psf_order,
        params.psf_clip_sigma,
        params.psf_stars_per_term,
        params.psf_min_stars,
    )
}

/// The stars' own windowed ellipticity e* across the field (each star
/// measured with its own r_g, as the stellar locus sizes them): what the
/// PSF-corrected size cut takes out as the PSF's tensor
/// ([`crate::shear::psf_corrected_size`]). e₁* and e₂* are fitted as p and
/// R are ([`PsfModel::build`]): one polynomial each, joint κσ clipping, the
/// order lowered to what the stars support.
#[derive(Debug, Clone, PartialEq)]
pub struct StarShape {
    fits: Vec<Poly2>,
}

impl StarShape {
    /// Fits the stars `(x, y, e*)` (array coordinates) of an image of
    /// `width` × `height`; `None` with fewer than `psf_min_stars`.
    pub fn fit(
        stars: &[(f64, f64, [f64; 2])],
        width: usize,
        height: usize,
        params: &KsbParams,
    ) -> Option<Self> {
        let xy: Vec<(f64, f64)> = stars.iter().map(|s| (s.0, s.1)).collect();
        let vals = vec![
            stars.iter().map(|s| s.2[0]).collect(),
            stars.iter().map(|s| s.2[1]).collect(),
        ];
        let (fits, _) = fit_stars(FieldFrame::of_image(width, height), &xy, &vals, params)?;
        Some(Self { fits })
    }

    /// e* at (x, y).
    pub fn at(&self, x: f64, y: f64) -> [f64; 2] {
        [self.fits[0].eval(x, y), self.fits[1].eval(x, y)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::moments::gaussian_integrals;
    use crate::scene::{covariance, draw_gaussian_sampled};

    #[test]
    fn the_star_shapes_follow_a_linear_field() {
        // 40 stars whose e* changes linearly across a 2000 × 1000 image
        // (e₁* with x, e₂* with y): the fit gives it back at other places,
        // so x and y are not swapped and the frame is the image's.
        let truth = |x: f64, y: f64| [0.01 + 2e-5 * x, -0.02 + 3e-5 * y];
        let stars: Vec<(f64, f64, [f64; 2])> = (0..40)
            .map(|k| {
                let (x, y) = (37.0 + (k % 8) as f64 * 250.0, 61.0 + (k / 8) as f64 * 210.0);
                (x, y, truth(x, y))
            })
            .collect();
        let fit = StarShape::fit(&stars, 2000, 1000, &KsbParams::default()).unwrap();
        for (x, y) in [(100.0, 900.0), (1900.0, 50.0), (1000.0, 500.0)] {
            let (got, want) = (fit.at(x, y), truth(x, y));
            assert!(
                (got[0] - want[0]).abs() < 1e-9 && (got[1] - want[1]).abs() < 1e-9,
                "({x}, {y}): {got:?} against {want:?}"
            );
        }
        assert!(StarShape::fit(&stars[..2], 2000, 1000, &KsbParams::default()).is_none());
    }

    #[test]
    fn uniform_gaussian_psf_model_matches_the_analytic_star() {
        // 20 identical Gaussian stars on a 250² image: the model at every
        // position equals the analytic p and R of that Gaussian at the
        // requested scale (tolerance 1e-6; 1e-3 between ladder scales where
        // the linear interpolation in ln r_g is the limit).
        let cov = covariance(1.9, [0.06, -0.03]);
        let mut img = crate::image::Image::zeros(250, 250);
        let mut stars = Vec::new();
        for k in 0..20 {
            let (x, y) = (
                25.0 + (k % 5) as f64 * 50.0 + 0.3,
                30.0 + (k / 5) as f64 * 60.0 - 0.2,
            );
            draw_gaussian_sampled(&mut img, x, y, 1e5, &cov);
            stars.push((x.round(), y.round()));
        }
        let params = KsbParams {
            window_radius_rg: 6.0,
            centroid_tol_px: 1e-7,
            ..KsbParams::default()
        };
        let model = PsfModel::build(&img, &stars, 1.8, 4.0, &params).unwrap();
        assert_eq!(model.order(), 2);
        for s in &model.scales {
            let a = gaussian_integrals(1.0, &cov, s.rg).shape().unwrap();
            let p = mul_vec(&inverse(&a.psm).unwrap(), a.e);
            let c = model.at(100.0, 100.0, s.rg);
            assert!(
                (c.p[0] - p[0]).abs() < 1e-6 && (c.p[1] - p[1]).abs() < 1e-6,
                "{c:?} {p:?}"
            );
            let r = half_trace(&a.psh) / half_trace(&a.psm);
            assert!((c.ratio / r - 1.0).abs() < 1e-6);
        }
        let rg = 2.5;
        let a = gaussian_integrals(1.0, &cov, rg).shape().unwrap();
        let p = mul_vec(&inverse(&a.psm).unwrap(), a.e);
        let c = model.at(20.0, 180.0, rg);
        assert!((c.p[0] / p[0] - 1.0).abs() < 1e-3, "{c:?} {p:?}");
    }
}
