//! Exponential disk of unit scale length h = 1 and unit flux.
//!
//! Real space: f(r) = e^{−r} / (2π).
//! Enclosed flux: L(<r) = 1 − (1 + r) e^{−r}; half-light radius
//! r½ = 1.678346990 h (root of L = ½).
//! Second moment: ⟨r²⟩ = ∫ r² f dA = Γ(4) = 6 h², so Qxx = Qyy = 3 h².
//! Fourier space (k in cycles per h): f̃(k) = (1 + (2πk)²)^{−3/2}
//! (e.g. GalSim's `Exponential`; Freeman 1970 for the disk law).

use super::RadialProfile;
use std::f64::consts::PI;

/// The exponential profile (unit scale length, unit flux).
#[derive(Debug, Clone, Copy, Default)]
pub struct Exponential;

impl Exponential {
    /// Half-light radius in units of the scale length (b₁ of
    /// [`super::sersic::sersic_b`]; the population's disk sizes use it).
    pub const HALF_LIGHT_RADIUS: f64 = 1.678_346_990_016_661;

    /// ⟨r²⟩ / h² of the untruncated profile: Γ(4) = 6.
    pub const MEAN_R2: f64 = 6.0;

    /// f̃ as a function of t = k² (k in cycles per h): the form used in the
    /// Fourier loop, which has k² from a quadratic form.
    #[inline]
    pub fn transform_k2(t: f64) -> f64 {
        let q = 1.0 + 4.0 * PI * PI * t;
        1.0 / (q * q.sqrt())
    }
}

impl RadialProfile for Exponential {
    fn density(&self, r: f64) -> f64 {
        (-r).exp() / (2.0 * PI)
    }
    fn transform(&self, k: f64) -> f64 {
        Self::transform_k2(k * k)
    }
    fn enclosed(&self, r: f64) -> f64 {
        1.0 - (1.0 + r) * (-r).exp()
    }
    fn mean_r2(&self) -> f64 {
        Self::MEAN_R2
    }
    fn radius_density_below(&self, level: f64) -> f64 {
        // e^{−r} / 2π = level
        (-(2.0 * PI * level).ln()).max(0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Composite Simpson integral of f(r) 2πr dr on [0, r].
    fn simpson_enclosed(r: f64, n: usize) -> f64 {
        let g = |x: f64| Exponential.density(x) * 2.0 * PI * x;
        stepsim_numerics::quad::simpson(g, 0.0, r, n)
    }

    #[test]
    fn half_light_radius_encloses_half_the_flux() {
        // Independent numerical integral of the density, tolerance 1e-4
        // (measured: |L − ½| < 1e-12).
        let l = simpson_enclosed(Exponential::HALF_LIGHT_RADIUS, 2000);
        assert!((l - 0.5).abs() < 1e-4, "{l}");
        assert!((Exponential.enclosed(Exponential::HALF_LIGHT_RADIUS) - 0.5).abs() < 1e-12);
        let r = Exponential.radius_enclosing(0.5);
        assert!((r - Exponential::HALF_LIGHT_RADIUS).abs() < 1e-9, "{r}");
        // The density integrates to one.
        assert!((simpson_enclosed(60.0, 20000) - 1.0).abs() < 1e-10);
        // Closed-form density radius against the density itself.
        let r = Exponential.radius_density_below(1e-5);
        assert!((Exponential.density(r) / 1e-5 - 1.0).abs() < 1e-12);
    }

    #[test]
    fn transform_matches_direct_hankel_integral() {
        // f̃(k) = ∫ f(r) J0(2πkr) 2πr dr by Gauss–Legendre panels.
        for k in [0.0, 0.05, 0.2, 0.7, 2.0] {
            let direct = crate::model::profile::hankel_slow(|r| Exponential.density(r), k, 60.0);
            assert!((direct - Exponential.transform(k)).abs() < 1e-9, "k={k}");
        }
    }

    #[test]
    fn second_moment_is_six() {
        // ∫ r² f 2πr dr numerically.
        let n = 20000;
        let h = 80.0 / n as f64;
        let s: f64 = (0..n)
            .map(|i| {
                let r = (i as f64 + 0.5) * h;
                r * r * Exponential.density(r) * 2.0 * PI * r * h
            })
            .sum();
        assert!((s - Exponential.mean_r2()).abs() < 1e-5, "{s}");
    }
}
