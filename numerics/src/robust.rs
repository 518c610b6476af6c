//! Robust width: MAD-σ, the median absolute deviation scaled to the σ of a
//! normal distribution.

use crate::stats::{median, median_slow};

/// σ of a normal distribution per median absolute deviation:
/// 1 / Φ⁻¹(3/4) = 1.4826 (to the four decimals the workspace has always used).
pub const MAD_TO_SIGMA: f64 = 1.4826;

/// 1.4826 × the median of |d| over `deviations` (residuals of a fit, or
/// values minus their centre: the caller chooses the centre); `None` when
/// there are none.
pub fn mad_sigma(deviations: impl IntoIterator<Item = f64>) -> Option<f64> {
    let mut abs: Vec<f64> = deviations.into_iter().map(f64::abs).collect();
    Some(MAD_TO_SIGMA * median(&mut abs)?)
}

/// Slow reference for [`mad_sigma`]: the same with the counting median.
pub fn mad_sigma_slow(deviations: &[f64]) -> Option<f64> {
    let abs: Vec<f64> = deviations.iter().map(|d| d.abs()).collect();
    Some(MAD_TO_SIGMA * median_slow(&abs)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng;
    use rand::RngExt;

    #[test]
    fn mad_sigma_matches_counting_and_a_normal_sample() {
        let mut rng = test_rng(9);
        for n in 0..30 {
            let d: Vec<f64> = (0..n).map(|_| rng.random::<f64>() * 4.0 - 2.0).collect();
            assert_eq!(mad_sigma(d.iter().copied()), mad_sigma_slow(&d));
        }
        assert_eq!(mad_sigma([]), None);
        // MAD of {−3, 1, 2} is 2.
        assert_eq!(mad_sigma([-3.0, 1.0, 2.0]), Some(2.0 * 1.4826));
        // A normal sample of σ = 2 (Box–Muller) gives σ back within 3 %.
        let d: Vec<f64> = (0..20_000)
            .map(|_| {
                let (u, v): (f64, f64) = (rng.random(), rng.random());
                2.0 * (-2.0 * (1.0 - u).ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
            })
            .collect();
        let s = mad_sigma(d).unwrap();
        assert!((s / 2.0 - 1.0).abs() < 0.03, "{s}");
    }
}
