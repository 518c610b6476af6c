//! Stars (SPEC §2; paper section "STEP Simulation Data"): point sources
//! whose differential counts obey d log10 N / dm = s (0.3) between a bright
//! and a faint limit (17, 25), normalised to a density per arcmin² over that
//! range (10).
//!
//! With N(<m) ∝ 10^(s m), the magnitude of a star is drawn by inverting the
//! cumulative counts: m = log10(10^(s m_b) + u (10^(s m_f) − 10^(s m_b))) / s
//! (uniform in m when s = 0).

use super::StarSpec;
use rand::RngExt;
use stepsim_contract::seed::SimRng;

/// Draws one star magnitude.
pub fn draw_mag(stars: &StarSpec, rng: &mut SimRng) -> f64 {
    let u: f64 = rng.random();
    mag_quantile(stars, u)
}

/// The magnitude with a fraction `u` of the stars brighter than it.
pub fn mag_quantile(stars: &StarSpec, u: f64) -> f64 {
    let (mb, mf, s) = (stars.mag_bright, stars.mag_faint, stars.slope);
    if s.abs() < 1e-12 || mf <= mb {
        return mb + u * (mf - mb);
    }
    // Work relative to the bright limit to avoid overflow: 10^(s (m − m_b)).
    let span = 10f64.powf(s * (mf - mb)) - 1.0;
    let m = mb + (1.0 + u * span).log10() / s;
    m.clamp(mb, mf)
}

/// Fraction of the stars brighter than `m` (the CDF of [`draw_mag`]).
pub fn mag_cdf(stars: &StarSpec, m: f64) -> f64 {
    let (mb, mf, s) = (stars.mag_bright, stars.mag_faint, stars.slope);
    let m = m.clamp(mb, mf);
    if s.abs() < 1e-12 || mf <= mb {
        return if mf > mb { (m - mb) / (mf - mb) } else { 1.0 };
    }
    (10f64.powf(s * (m - mb)) - 1.0) / (10f64.powf(s * (mf - mb)) - 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::population::tests::count_slope;
    use stepsim_contract::seed::{SeedKey, Stream};
    use stepsim_numerics::stats::{ks_p_value, ks_statistic};

    #[test]
    fn star_counts_have_slope_0_3() {
        let stars = StarSpec::default();
        let mut rng = SeedKey::base(21, 0, Stream::Test).rng();
        let mags: Vec<f64> = (0..100_000).map(|_| draw_mag(&stars, &mut rng)).collect();
        assert!(mags.iter().all(|&m| (17.0..=25.0).contains(&m)));
        let slope = count_slope(&mags, 17.0, 25.0);
        assert!((slope - 0.3).abs() < 0.02, "slope {slope}");
        let d = ks_statistic(&mags, |m| mag_cdf(&stars, m));
        assert!(ks_p_value(d, mags.len()) > 1e-3, "D = {d}");
        // Quantile and CDF are inverse.
        for u in [0.0, 0.1, 0.5, 0.93, 1.0] {
            assert!((mag_cdf(&stars, mag_quantile(&stars, u)) - u).abs() < 1e-12);
        }
    }

    #[test]
    fn flat_counts_when_slope_is_zero() {
        let stars = StarSpec {
            slope: 0.0,
            ..StarSpec::default()
        };
        assert!((mag_quantile(&stars, 0.5) - 21.0).abs() < 1e-12);
        assert!((mag_cdf(&stars, 19.0) - 0.25).abs() < 1e-12);
    }
}
