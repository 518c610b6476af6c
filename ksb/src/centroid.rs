//! Windowed centroid and the size r_g (KSB table row "Galaxy size r_g").
//!
//! The centroid iterates like SExtractor's XWIN: with a round Gaussian
//! weight W of scale r_g about the current centre c,
//! c ← c + 2 Σ W I (x − c) / Σ W I. The factor 2 makes the step exact for a
//! Gaussian object of σ = r_g and contracting for any other size. At the
//! fixed point the weighted first moments vanish, which is the centre the
//! KSB formulae assume.
//!
//! The size iterates at the same time: r_g² ← Σ W I |θ − θ̄|² / Σ W I (both
//! axes together, i.e. twice the weighted second moment per axis). For a Gaussian of σ_o the weighted second moment per
//! axis is σ_o² r_g² / (σ_o² + r_g²), so the fixed point is r_g = σ_o (the
//! map contracts by 1/2 per step there): r_g is the σ of the Gaussian that
//! the object's light resembles, the scale at which a Gaussian filter of the
//! object's own width matches it (as *hfindpeaks*' optimal scale).

use crate::image::Image;
use crate::moments::window_moments;

/// Result of the windowed centroid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Windowed {
    /// Centre, array coordinates.
    pub x: f64,
    /// Centre, array coordinates.
    pub y: f64,
    /// Weight scale r_g at convergence (pixels).
    pub rg: f64,
    /// Both centre and size converged within the tolerance.
    pub converged: bool,
    /// r_g hit a bound of `[rg_min, rg_max]`.
    pub at_bound: bool,
    /// Number of iterations used.
    pub iterations: usize,
}

/// Settings of [`windowed`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindowSettings {
    /// Window radius in units of r_g.
    pub radius_rg: f64,
    /// Smallest r_g.
    pub rg_min: f64,
    /// Largest r_g.
    pub rg_max: f64,
    /// Convergence tolerance (pixels for the centre, relative for r_g).
    pub tol: f64,
    /// Most iterations.
    pub max_iter: usize,
}

/// Windowed centroid from `(x0, y0)` with the size adapted from `rg0`; if
/// `adapt_size` is false r_g stays at `rg0`. `None` if the weighted flux is
/// not positive (nothing there).
pub fn windowed(
    img: &Image,
    x0: f64,
    y0: f64,
    rg0: f64,
    adapt_size: bool,
    s: &WindowSettings,
) -> Option<Windowed> {
    let (mut x, mut y, mut rg) = (x0, y0, rg0.clamp(s.rg_min, s.rg_max));
    let mut at_bound = false;
    for it in 1..=s.max_iter {
        let m = window_moments(img, x, y, rg, s.radius_rg * rg);
        if m.s0.is_nan() || m.s0 <= 0.0 {
            return None;
        }
        let mut dx = 2.0 * m.first[0] / m.s0;
        let mut dy = 2.0 * m.first[1] / m.s0;
        let step = (dx * dx + dy * dy).sqrt();
        if step > rg {
            dx *= rg / step;
            dy *= rg / step;
        }
        let mut drel = 0.0;
        if adapt_size {
            // Second moment about the weighted mean, per axis, doubled.
            let mean2 = (m.first[0].powi(2) + m.first[1].powi(2)) / (m.s0 * m.s0);
            let r2 = m.trace / m.s0 - mean2;
            let new = if r2 > 0.0 { r2.sqrt() } else { s.rg_min };
            let clamped = new.clamp(s.rg_min, s.rg_max);
            at_bound = clamped != new;
            drel = (clamped - rg).abs() / rg;
            rg = clamped;
        }
        x += dx;
        y += dy;
        if !(x.is_finite() && y.is_finite()) {
            return None;
        }
        if (dx * dx + dy * dy).sqrt() < s.tol && drel < s.tol {
            return Some(Windowed {
                x,
                y,
                rg,
                converged: true,
                at_bound,
                iterations: it,
            });
        }
    }
    Some(Windowed {
        x,
        y,
        rg,
        converged: false,
        at_bound,
        iterations: s.max_iter,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{covariance, draw_gaussian_sampled};

    const S: WindowSettings = WindowSettings {
        radius_rg: 5.0,
        rg_min: 0.5,
        rg_max: 15.0,
        tol: 1e-6,
        max_iter: 200,
    };

    #[test]
    fn gaussian_centre_and_sigma_are_recovered() {
        // Noise-free sampled Gaussians: centre to 1e-4 px and r_g = σ to
        // 1e-4 relative (the f32 pixels and 5 r_g window limit it).
        for (x, y, sigma, e) in [
            (30.3, 29.8, 2.0, [0.0, 0.0]),
            (31.7, 28.2, 3.5, [0.3, -0.2]),
        ] {
            let mut img = Image::zeros(64, 64);
            draw_gaussian_sampled(&mut img, x, y, 1e4, &covariance(sigma, e));
            let w = windowed(&img, x.round() + 1.0, y.round() - 1.0, 1.0, true, &S).unwrap();
            assert!(w.converged);
            assert!((w.x - x).abs() < 1e-4 && (w.y - y).abs() < 1e-4, "{w:?}");
            if e == [0.0, 0.0] {
                assert!((w.rg / sigma - 1.0).abs() < 1e-4, "{w:?}");
            } else {
                // Elliptical: between the minor and major axis σ.
                let c = covariance(sigma, e);
                let (tr, det) = (c[0][0] + c[1][1], c[0][0] * c[1][1] - c[0][1] * c[0][1]);
                let lmax = 0.5 * tr + (0.25 * tr * tr - det).sqrt();
                let lmin = det / lmax;
                assert!(w.rg > lmin.sqrt() && w.rg < lmax.sqrt(), "{w:?}");
            }
        }
    }

    #[test]
    fn empty_sky_has_no_centroid() {
        let img = Image::zeros(20, 20);
        assert!(windowed(&img, 10.0, 10.0, 2.0, true, &S).is_none());
    }
}
