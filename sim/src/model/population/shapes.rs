//! Galaxy shapes (SPEC §2, paper section "STEP Simulation Data").
//!
//! * Intrinsic bulge flattening q ~ N(mean 0.65, σ 0.18) truncated to
//!   [0.3, 1] by resampling (Sandage, Freeman & Stokes 1970, as in the paper;
//!   Stuff itself only clips at 1).
//! * Inclination i: uniform in angle on [0, i_max] (`flat`, Stuff and STEP1)
//!   or isotropic, cos i uniform on [cos i_max, 1].
//! * Apparent axis ratios: bulge β = sqrt(q² sin² i + cos² i) (oblate
//!   spheroid seen at inclination i), thin disk β = cos i.
//! * One position angle θ uniform in [0, π), shared by bulge and disk.

use super::{Flattening, InclinationLaw};
use rand::RngExt;
use rand_distr::StandardNormal;
use std::f64::consts::PI;
use stepsim_contract::seed::SimRng;
use stepsim_numerics::stats::normal_cdf;

/// The shape of one galaxy, before shear.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shape {
    /// Intrinsic bulge flattening q.
    pub q: f64,
    /// Inclination (radians).
    pub incl: f64,
    /// Apparent bulge axis ratio.
    pub bulge_ba: f64,
    /// Apparent disk axis ratio.
    pub disk_ba: f64,
    /// Position angle θ ∈ [0, π) (radians).
    pub theta: f64,
}

/// The shape laws of the config.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShapeLaw {
    /// Bulge flattening law.
    pub flattening: (f64, f64, f64, f64),
    /// Inclination law.
    pub inclination: InclinationLaw,
    /// Largest inclination (radians).
    pub max_incl: f64,
}

impl ShapeLaw {
    /// From the config (`population.galaxies`).
    pub fn new(f: &Flattening, law: InclinationLaw, max_incl_deg: f64) -> Self {
        Self {
            flattening: (f.mean, f.sigma, f.min, f.max),
            inclination: law,
            max_incl: max_incl_deg.to_radians(),
        }
    }

    /// Draws q by resampling the normal until it falls in [min, max]
    /// (the config guarantees an acceptance rate ≥ 1e-3).
    pub fn draw_q(&self, rng: &mut SimRng) -> f64 {
        let (mean, sigma, lo, hi) = self.flattening;
        loop {
            let n: f64 = rng.sample(StandardNormal);
            let q = mean + sigma * n;
            if (lo..=hi).contains(&q) {
                return q;
            }
        }
    }

    /// CDF of the truncated normal law of q.
    pub fn q_cdf(&self, q: f64) -> f64 {
        let (mean, sigma, lo, hi) = self.flattening;
        let f = |x: f64| normal_cdf((x - mean) / sigma);
        ((f(q.clamp(lo, hi)) - f(lo)) / (f(hi) - f(lo))).clamp(0.0, 1.0)
    }

    /// Draws an inclination (radians).
    pub fn draw_incl(&self, rng: &mut SimRng) -> f64 {
        let u: f64 = rng.random();
        match self.inclination {
            InclinationLaw::Flat => u * self.max_incl,
            InclinationLaw::Isotropic => {
                let c0 = self.max_incl.cos();
                (1.0 - u * (1.0 - c0)).clamp(-1.0, 1.0).acos()
            }
        }
    }

    /// CDF of the inclination law.
    pub fn incl_cdf(&self, i: f64) -> f64 {
        let i = i.clamp(0.0, self.max_incl);
        match self.inclination {
            InclinationLaw::Flat => {
                if self.max_incl > 0.0 {
                    i / self.max_incl
                } else {
                    1.0
                }
            }
            InclinationLaw::Isotropic => {
                let c0 = self.max_incl.cos();
                if c0 < 1.0 {
                    (1.0 - i.cos()) / (1.0 - c0)
                } else {
                    1.0
                }
            }
        }
    }

    /// Draws a whole shape, always in the order q, i, θ.
    pub fn draw(&self, rng: &mut SimRng) -> Shape {
        let q = self.draw_q(rng);
        let incl = self.draw_incl(rng);
        let theta = rng.random::<f64>() * PI;
        Shape {
            q,
            incl,
            bulge_ba: bulge_axis_ratio(q, incl),
            disk_ba: disk_axis_ratio(incl),
            theta,
        }
    }
}

/// Apparent axis ratio of an oblate spheroid of flattening q at inclination
/// i: β = sqrt(q² sin² i + cos² i).
pub fn bulge_axis_ratio(q: f64, incl: f64) -> f64 {
    let (s, c) = incl.sin_cos();
    (q * q * s * s + c * c).sqrt()
}

/// Apparent axis ratio of an infinitely thin disk: β = cos i.
pub fn disk_axis_ratio(incl: f64) -> f64 {
    incl.cos()
}

/// Intrinsic flattening from the apparent bulge axis ratio and the
/// inclination (inverse of [`bulge_axis_ratio`]); `None` when i ≈ 0 (every
/// q looks round face-on).
pub fn flattening_from_axis_ratio(bulge_ba: f64, incl: f64) -> Option<f64> {
    let (s, c) = incl.sin_cos();
    if s < 1e-6 {
        return None;
    }
    Some(
        ((bulge_ba * bulge_ba - c * c) / (s * s))
            .max(0.0)
            .sqrt()
            .min(1.0),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use stepsim_contract::seed::{SeedKey, Stream};
    use stepsim_numerics::stats::{ks_p_value, ks_statistic};

    fn law(incl: InclinationLaw) -> ShapeLaw {
        ShapeLaw::new(&Flattening::default(), incl, 85.0)
    }

    fn draws(law: &ShapeLaw, seed: u64, n: usize) -> Vec<Shape> {
        let mut rng = SeedKey::base(seed, 0, Stream::Test).rng();
        (0..n).map(|_| law.draw(&mut rng)).collect()
    }

    #[test]
    fn q_follows_the_truncated_normal() {
        let l = law(InclinationLaw::Flat);
        let s = draws(&l, 11, 100_000);
        let q: Vec<f64> = s.iter().map(|s| s.q).collect();
        assert!(q.iter().all(|&q| (0.3..=1.0).contains(&q)));
        let d = ks_statistic(&q, |x| l.q_cdf(x));
        let p = ks_p_value(d, q.len());
        assert!(p > 1e-3, "D = {d}, p = {p}");
        // Not the untruncated normal, nor a clipped one.
        let d = ks_statistic(&q, |x| normal_cdf((x - 0.65) / 0.18));
        assert!(ks_p_value(d, q.len()) < 1e-6, "D = {d}");
        // The truncated mean is below 0.65 by a computable amount: the
        // truncation is nearly symmetric about 0.65 (0.35 below, 0.35 above).
        let mean = q.iter().sum::<f64>() / q.len() as f64;
        assert!((mean - 0.65).abs() < 0.003, "{mean}");
    }

    #[test]
    fn inclination_follows_both_laws() {
        for (incl, seed) in [(InclinationLaw::Flat, 12), (InclinationLaw::Isotropic, 13)] {
            let l = law(incl);
            let s = draws(&l, seed, 100_000);
            let i: Vec<f64> = s.iter().map(|s| s.incl).collect();
            assert!(i.iter().all(|&i| (0.0..=85f64.to_radians()).contains(&i)));
            let d = ks_statistic(&i, |x| l.incl_cdf(x));
            let p = ks_p_value(d, i.len());
            assert!(p > 1e-3, "{incl:?}: D = {d}, p = {p}");
            // And the other law is rejected.
            let other = law(match incl {
                InclinationLaw::Flat => InclinationLaw::Isotropic,
                InclinationLaw::Isotropic => InclinationLaw::Flat,
            });
            let d = ks_statistic(&i, |x| other.incl_cdf(x));
            assert!(ks_p_value(d, i.len()) < 1e-6, "{incl:?}: D = {d}");
        }
    }

    #[test]
    fn position_angle_is_uniform() {
        let s = draws(&law(InclinationLaw::Flat), 14, 100_000);
        let t: Vec<f64> = s.iter().map(|s| s.theta).collect();
        assert!(t.iter().all(|&t| (0.0..PI).contains(&t)));
        let d = ks_statistic(&t, |x| (x / PI).clamp(0.0, 1.0));
        let p = ks_p_value(d, t.len());
        assert!(p > 1e-3, "D = {d}, p = {p}");
    }

    #[test]
    fn axis_ratio_formulas_hold_per_object() {
        for s in draws(&law(InclinationLaw::Isotropic), 15, 10_000) {
            let (si, ci) = s.incl.sin_cos();
            assert_eq!(s.disk_ba, ci);
            assert!((s.bulge_ba.powi(2) - (s.q * s.q * si * si + ci * ci)).abs() < 1e-15);
            // The bulge is never flatter than its intrinsic q nor than the disk.
            assert!(s.bulge_ba >= s.q - 1e-15 && s.bulge_ba >= s.disk_ba - 1e-15);
            if si > 0.01 {
                let q = flattening_from_axis_ratio(s.bulge_ba, s.incl).unwrap();
                assert!((q - s.q).abs() < 1e-9, "{q} vs {}", s.q);
            }
        }
        assert!(flattening_from_axis_ratio(1.0, 0.0).is_none());
    }
}
