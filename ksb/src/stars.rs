//! Star–galaxy separation in the size–magnitude plane (KSB table: stars
//! "selected from a magnitude-size plot"; here automatically).
//!
//! Stars all have the PSF's size r_g*, galaxies are larger and spread out;
//! among bright, clean objects the stars form the narrowest, densest
//! branch. The locus is found as:
//!
//! 1. candidates: clean objects (no flag of [`crate::flags::NOT_FOR_PSF`])
//!    with S/N ≥ `star_min_sn`;
//! 2. the peak of the *narrow excess* of ln r_g among them: a Gaussian
//!    kernel density of width h = `locus_bandwidth` minus one of width 5h
//!    (both normalised), on a grid of h/4. The broad density of galaxies
//!    cancels in the difference, the narrow stellar branch does not, so a
//!    crowd of galaxies does not pull the peak as much. Stars are the
//!    smallest objects, so the locus is the smallest-size local maximum of
//!    that excess reaching 30 % of its highest maximum (a pile of compact
//!    bright galaxies just above the stars can be as dense as the locus);
//! 3. r_g* = the median of candidates within 2 bandwidths of the mode, and
//!    the locus half-width = max(`locus_nsigma` × 1.4826 MAD,
//!    `locus_min_halfwidth`) in ln r_g of those. If fewer than
//!    `locus_min_concentration` of the candidates within 6 bandwidths of
//!    the peak lie within 2 bandwidths, the peak is a broad clump of
//!    galaxies, not stars, and there is no locus.
//!
//! An object is a star when |ln r_g − ln r_g*| ≤ half-width and its S/N is at
//! least `star_class_min_sn` (fainter objects' sizes are too noisy to tell).
//! Stars used for the PSF model are the clean candidates of step 1 on the
//! locus.

use crate::params::KsbParams;

/// The stellar locus.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Locus {
    /// Size of the stars, r_g* (pixels).
    pub rg_star: f64,
    /// Half-width in ln r_g.
    pub half_width: f64,
    /// Number of candidates on the locus.
    pub n_stars: usize,
}

/// What the classifier needs of one object.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SizeMag {
    /// r_g in pixels.
    pub rg: f64,
    /// Gaussian-weighted S/N.
    pub sn: f64,
    /// Free of disqualifying flags.
    pub clean: bool,
}

impl Locus {
    /// Whether `o` lies on the locus and is bright enough to be called a star.
    pub fn is_star(&self, o: &SizeMag, params: &KsbParams) -> bool {
        o.sn >= params.star_class_min_sn && (o.rg.ln() - self.rg_star.ln()).abs() <= self.half_width
    }

    /// Whether `o` is a star good enough for the PSF model.
    pub fn is_psf_star(&self, o: &SizeMag, params: &KsbParams) -> bool {
        o.clean && o.sn >= params.star_min_sn && self.is_star(o, params)
    }
}

/// Finds the stellar locus, or `None` if there are fewer than
/// `psf_min_stars` candidates on it.
pub fn find_locus(objects: &[SizeMag], params: &KsbParams) -> Option<Locus> {
    let ln: Vec<f64> = objects
        .iter()
        .filter(|o| {
            o.clean
                && o.sn >= params.star_min_sn
                && o.rg > 1.05 * params.rg_min_px
                && o.rg.is_finite()
        })
        .map(|o| o.rg.ln())
        .collect();
    if ln.len() < params.psf_min_stars {
        return None;
    }
    let h = params.locus_bandwidth;
    let lo = ln.iter().copied().fold(f64::INFINITY, f64::min) - 2.0 * h;
    let hi = ln.iter().copied().fold(f64::NEG_INFINITY, f64::max) + 2.0 * h;
    let step = h / 4.0;
    let n = ((hi - lo) / step).ceil() as usize + 1;
    let score: Vec<f64> = (0..n)
        .map(|k| {
            let t = lo + k as f64 * step;
            let narrow: f64 = ln
                .iter()
                .map(|v| (-0.5 * ((v - t) / h).powi(2)).exp())
                .sum();
            let broad: f64 = ln
                .iter()
                .map(|v| (-0.5 * ((v - t) / (5.0 * h)).powi(2)).exp())
                .sum();
            narrow - broad / 5.0
        })
        .collect();
    let top = score.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let first_peak = (0..n).find(|&k| {
        let left = if k > 0 {
            score[k - 1]
        } else {
            f64::NEG_INFINITY
        };
        let right = if k + 1 < n {
            score[k + 1]
        } else {
            f64::NEG_INFINITY
        };
        score[k] >= 0.3 * top && score[k] >= left && score[k] >= right
    })?;
    let best = (score[first_peak], lo + first_peak as f64 * step);
    let mode = best.1;
    let mut near: Vec<f64> = ln
        .iter()
        .copied()
        .filter(|v| (v - mode).abs() <= 2.0 * h)
        .collect();
    let centre = stepsim_sim::stats::median(&mut near)?;
    let mut dev: Vec<f64> = near.iter().map(|v| (v - centre).abs()).collect();
    let mad = stepsim_sim::stats::median(&mut dev)?;
    // Stars scatter in size only by measurement noise: most candidates
    // within ±6h of a stellar peak lie within ±2h (a flat distribution
    // puts a third there). A broad "locus" is a clump of galaxies.
    let wide = ln.iter().filter(|v| (*v - mode).abs() <= 6.0 * h).count();
    if (near.len() as f64) < params.locus_min_concentration * wide as f64 {
        return None;
    }
    let half_width = (params.locus_nsigma * 1.4826 * mad).max(params.locus_min_halfwidth);
    let n_stars = ln
        .iter()
        .filter(|v| (*v - centre).abs() <= half_width)
        .count();
    (n_stars >= params.psf_min_stars).then_some(Locus {
        rg_star: centre.exp(),
        half_width,
        n_stars,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::draw::uniform;
    use rand::RngExt;
    use stepsim_sim::seed::{SeedKey, Stream};

    #[test]
    fn injected_stellar_locus_is_found_and_separated() {
        // 60 stars at r_g* = 2.0 px with size noise 1 % × (50 / S/N), S/N
        // from 20 to 2000; 400 galaxies with ln r_g uniform in
        // [ln 2.3, ln 8] and S/N from 10 to 500, some compact ones near the
        // locus at low S/N. Expected: r_g* within 1 %, every bright star
        // (S/N ≥ 50) a PSF star, no galaxy larger than 1.1 r_g* taken.
        let params = KsbParams::default();
        let mut rng = SeedKey::base(11, 0, Stream::Test).rng();
        let mut objs = Vec::new();
        let mut is_star = Vec::new();
        for _ in 0..60 {
            let sn = 10f64.powf(uniform(&mut rng, 20f64.log10(), 2000f64.log10()));
            let n: f64 = rng.sample(rand_distr::StandardNormal);
            objs.push(SizeMag {
                rg: 2.0 * (1.0 + 0.01 * 50.0 / sn * n),
                sn,
                clean: true,
            });
            is_star.push(true);
        }
        for _ in 0..400 {
            let sn = 10f64.powf(uniform(&mut rng, 1.0, 500f64.log10()));
            let rg = uniform(&mut rng, 2.3f64.ln(), 8f64.ln()).exp();
            objs.push(SizeMag {
                rg,
                sn,
                clean: rng.random::<f64>() > 0.1,
            });
            is_star.push(false);
        }
        let locus = find_locus(&objs, &params).unwrap();
        assert!((locus.rg_star / 2.0 - 1.0).abs() < 0.01, "{locus:?}");
        for (o, s) in objs.iter().zip(&is_star) {
            if *s && o.sn >= params.star_min_sn {
                assert!(locus.is_psf_star(o, &params), "{o:?} {locus:?}");
            }
            if !*s && o.rg > 1.1 * 2.0 {
                assert!(!locus.is_star(o, &params), "{o:?} {locus:?}");
            }
        }
    }

    #[test]
    fn a_broad_clump_of_galaxies_is_not_a_locus() {
        // 200 bright objects with ln r_g uniform over ±0.3 about ln 2.3 and
        // no stars: about 1/3 of those within ±6h lie within ±2h (< 0.5).
        let params = KsbParams::default();
        let objs: Vec<SizeMag> = (0..200)
            .map(|k| SizeMag {
                rg: 2.3 * (0.6 * (k as f64 / 199.0 - 0.5)).exp(),
                sn: 100.0,
                clean: true,
            })
            .collect();
        assert!(find_locus(&objs, &params).is_none());
    }

    #[test]
    fn too_few_candidates_give_no_locus() {
        let params = KsbParams::default();
        let objs = [SizeMag {
            rg: 2.0,
            sn: 100.0,
            clean: true,
        }; 2];
        assert!(find_locus(&objs, &params).is_none());
    }
}
