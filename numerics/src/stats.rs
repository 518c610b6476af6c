//! Small statistics shared by every crate of the workspace: the median, the
//! normal CDF (used to draw the population) and the one-sample
//! Kolmogorov–Smirnov test (used to validate it), each with its slow twin.

/// Median of a sample, reordering it (sorted); the mean of the two middle
/// values for an even count; `None` when empty. NaNs sort after +∞
/// ([`f64::total_cmp`]).
pub fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

/// Weighted median of (value, weight) pairs (weights positive and finite),
/// reordering them (sorted by value): the value at which the weights,
/// summed in increasing order of value, first reach half their total; the
/// mean of that value and the next when they reach exactly half, so that
/// equal weights give [`median`]. `None` when empty.
pub fn weighted_median(v: &mut [(f64, f64)]) -> Option<f64> {
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let half = 0.5 * v.iter().map(|p| p.1).sum::<f64>();
    let mut below = 0.0;
    for (k, &(x, w)) in v.iter().enumerate() {
        below += w;
        if below == half && k + 1 < v.len() {
            return Some(0.5 * (x + v[k + 1].0));
        }
        if below >= half {
            return Some(x);
        }
    }
    v.last().map(|p| p.0)
}

/// Slow reference for [`weighted_median`]: the sample value x whose weight
/// strictly below it is less than half the total and whose weight at or
/// below it is more than half; or, where the weight at or below a value is
/// exactly half, the mean of it and the smallest value above it. Found by
/// summing over every sample for every sample (O(n²), no sorting).
pub fn weighted_median_slow(v: &[(f64, f64)]) -> Option<f64> {
    let half = 0.5 * v.iter().map(|p| p.1).sum::<f64>();
    let weight =
        |keep: &dyn Fn(f64) -> bool| -> f64 { v.iter().filter(|p| keep(p.0)).map(|p| p.1).sum() };
    for &(x, _) in v {
        let (below, at_or_below) = (weight(&|y| y < x), weight(&|y| y <= x));
        if at_or_below == half {
            let next = v
                .iter()
                .map(|p| p.0)
                .filter(|&y| y > x)
                .fold(f64::INFINITY, f64::min);
            if next.is_finite() {
                return Some(0.5 * (x + next));
            }
        }
        if below < half && at_or_below >= half {
            return Some(x);
        }
    }
    None
}

/// Complementary error function (the `libm` crate's, accurate to about
/// one unit in the last place).
pub fn erfc(x: f64) -> f64 {
    libm::erfc(x)
}

/// Slow reference for [`erfc`]: 1 − erf(x) with erf from its Maclaurin
/// series 2/√π Σ (−1)ⁿ x²ⁿ⁺¹ / (n! (2n + 1)), summed until the terms stop
/// mattering (|x| ≤ 3; the terms grow to about 10³ there, so the result
/// loses about three digits: good to 1e-12 absolute).
pub fn erfc_slow(x: f64) -> f64 {
    let mut term = x; // (−1)ⁿ x²ⁿ⁺¹ / n!
    let mut sum = x;
    let mut n = 0.0;
    while term.abs() > 1e-17 * sum.abs().max(1e-300) || n < 3.0 {
        n += 1.0;
        term *= -x * x / n;
        sum += term / (2.0 * n + 1.0);
    }
    1.0 - 2.0 / std::f64::consts::PI.sqrt() * sum
}

/// Standard normal CDF Φ(x) = erfc(−x/√2)/2.
pub fn normal_cdf(x: f64) -> f64 {
    0.5 * erfc(-x / std::f64::consts::SQRT_2)
}

/// The quantile of a distribution on the whole real line at a `p` that is
/// not inside (0, 1): NaN outside [0, 1], −∞ at 0, +∞ at 1; `None` for p in
/// (0, 1), which the distribution's own quantile answers.
pub(crate) fn quantile_outside_open_unit(p: f64) -> Option<f64> {
    if !(0.0..=1.0).contains(&p) {
        Some(f64::NAN)
    } else if p == 0.0 {
        Some(f64::NEG_INFINITY)
    } else if p == 1.0 {
        Some(f64::INFINITY)
    } else {
        None
    }
}

/// The standard normal quantile Φ⁻¹(p): bisection ([`crate::roots::Bisection`],
/// to machine precision) of [`normal_cdf`] on [−40, 40]. NaN for p outside
/// [0, 1]; ±∞ at p = 0, 1.
pub fn normal_quantile(p: f64) -> f64 {
    if let Some(q) = quantile_outside_open_unit(p) {
        return q;
    }
    let (lo, hi) = crate::roots::Bisection::halvings(200).run(-40.0, 40.0, |x| normal_cdf(x) >= p);
    0.5 * (lo + hi)
}

/// Slow reference for [`normal_cdf`]: composite Simpson integration
/// ([`crate::quad::simpson`]) of the density from −10 to `x` with 20 000
/// intervals.
pub fn normal_cdf_slow(x: f64) -> f64 {
    let lo = -10.0f64;
    if x <= lo {
        return 0.0;
    }
    let pdf = |t: f64| (-0.5 * t * t).exp() / (2.0 * std::f64::consts::PI).sqrt();
    crate::quad::simpson(pdf, lo, x, 20_000)
}

/// Slow reference for [`median`]: the value (or the mean of the two values)
/// with as many samples below as above, found by counting for every sample
/// (O(n²), no sorting).
pub fn median_slow(v: &[f64]) -> Option<f64> {
    let n = v.len();
    // The k-th smallest (0-based): a value with fewer than k + 1 samples
    // below it and at least k + 1 at or below it.
    let kth = |k: usize| {
        v.iter().copied().find(|&x| {
            let below = v.iter().filter(|&&y| y.total_cmp(&x).is_lt()).count();
            let at_or_below = v.iter().filter(|&&y| y.total_cmp(&x).is_le()).count();
            below <= k && k < at_or_below
        })
    };
    match n {
        0 => None,
        _ if n % 2 == 1 => kth(n / 2),
        _ => Some(0.5 * (kth(n / 2 - 1)? + kth(n / 2)?)),
    }
}

/// One-sample Kolmogorov–Smirnov statistic D = sup |F_n(x) − F(x)| of
/// `samples` (any order; sorted internally) against the CDF `cdf`.
pub fn ks_statistic(samples: &[f64], cdf: impl Fn(f64) -> f64) -> f64 {
    let mut xs = samples.to_vec();
    xs.sort_by(f64::total_cmp);
    let n = xs.len() as f64;
    let mut d = 0.0f64;
    for (i, &x) in xs.iter().enumerate() {
        let f = cdf(x);
        d = d.max(f - i as f64 / n).max((i + 1) as f64 / n - f);
    }
    d
}

/// Slow reference for [`ks_statistic`]: at every sample point counts the
/// samples ≤ x and < x directly (O(n²)).
pub fn ks_statistic_slow(samples: &[f64], cdf: impl Fn(f64) -> f64) -> f64 {
    let n = samples.len() as f64;
    samples
        .iter()
        .map(|&x| {
            let le = samples.iter().filter(|&&y| y <= x).count() as f64 / n;
            let lt = samples.iter().filter(|&&y| y < x).count() as f64 / n;
            (le - cdf(x)).abs().max((cdf(x) - lt).abs())
        })
        .fold(0.0, f64::max)
}

/// Asymptotic p-value of a KS statistic `d` from `n` samples:
/// Q_KS(λ) = 2 Σ_{k≥1} (−1)^{k−1} exp(−2k²λ²) with
/// λ = (√n + 0.12 + 0.11/√n) d (Stephens 1970; *Numerical Recipes* §14.3).
pub fn ks_p_value(d: f64, n: usize) -> f64 {
    let sn = (n as f64).sqrt();
    let lambda = (sn + 0.12 + 0.11 / sn) * d;
    kolmogorov_q(lambda)
}

/// The Kolmogorov survival function Q_KS(λ).
pub fn kolmogorov_q(lambda: f64) -> f64 {
    if lambda < 0.2 {
        return 1.0;
    }
    let mut sum = 0.0;
    let mut sign = 1.0;
    for k in 1..=100 {
        let term = (-2.0 * (k * k) as f64 * lambda * lambda).exp();
        sum += sign * term;
        if term < 1e-16 {
            break;
        }
        sign = -sign;
    }
    (2.0 * sum).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng;
    use rand::RngExt;

    #[test]
    fn erfc_matches_its_series_and_known_values() {
        let mut x = -3.0;
        while x <= 3.0 {
            let (fast, slow) = (erfc(x), erfc_slow(x));
            assert!((fast - slow).abs() < 1e-12, "x {x}: {fast} vs {slow}");
            x += 0.0625;
        }
        // erfc(0) = 1, erfc(1) = 0.157299207050285..., erfc(−∞) = 2.
        assert_eq!(erfc(0.0), 1.0);
        assert!((erfc(1.0) - 0.157_299_207_050_285_13).abs() < 1e-16);
        assert!((erfc(5.0) - 1.537_459_794_428_034_8e-12).abs() < 1e-26);
        assert_eq!(erfc(f64::NEG_INFINITY), 2.0);
    }

    #[test]
    fn median_of_odd_even_and_empty_samples() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(median(&mut [-1.5]), Some(-1.5));
        assert_eq!(median(&mut []), None);
        let mut v = [5.0, f64::INFINITY, -2.0];
        assert_eq!(median(&mut v), Some(5.0));
        assert_eq!(v, [-2.0, 5.0, f64::INFINITY], "left sorted");
    }

    #[test]
    fn median_matches_counting() {
        let mut rng = test_rng(5);
        for n in 0..40 {
            // Few distinct values: ties at the middle.
            let v: Vec<f64> = (0..n)
                .map(|_| f64::from(rng.random_range(0..7u8)))
                .collect();
            assert_eq!(median(&mut v.clone()), median_slow(&v), "{v:?}");
            let v: Vec<f64> = (0..n).map(|_| rng.random::<f64>() - 0.5).collect();
            assert_eq!(median(&mut v.clone()), median_slow(&v), "{v:?}");
        }
    }

    #[test]
    fn weighted_median_matches_summing_and_the_median_for_equal_weights() {
        assert_eq!(weighted_median(&mut []), None);
        assert_eq!(weighted_median_slow(&[]), None);
        // A heavy sample is the median however many light ones lie on one
        // side of it.
        let mut v = [(5.0, 10.0), (1.0, 1.0), (2.0, 1.0), (3.0, 1.0)];
        assert_eq!(weighted_median(&mut v), Some(5.0));
        assert_eq!(weighted_median(&mut [(1.0, 1.0), (2.0, 3.0)]), Some(2.0));
        assert_eq!(weighted_median(&mut [(1.0, 2.0), (2.0, 2.0)]), Some(1.5));
        let mut rng = test_rng(6);
        for n in 0..40 {
            // Integer weights sum exactly, so "exactly half" happens; few
            // distinct values make ties.
            let v: Vec<(f64, f64)> = (0..n)
                .map(|_| {
                    (
                        f64::from(rng.random_range(0..7u8)),
                        f64::from(rng.random_range(1..5u8)),
                    )
                })
                .collect();
            assert_eq!(
                weighted_median(&mut v.clone()),
                weighted_median_slow(&v),
                "{v:?}"
            );
            let v: Vec<(f64, f64)> = (0..n)
                .map(|_| (rng.random::<f64>() - 0.5, rng.random::<f64>() + 0.01))
                .collect();
            assert_eq!(
                weighted_median(&mut v.clone()),
                weighted_median_slow(&v),
                "{v:?}"
            );
            let mut values: Vec<f64> = v.iter().map(|p| p.0).collect();
            let mut equal: Vec<(f64, f64)> = values.iter().map(|&x| (x, 1.0)).collect();
            assert_eq!(weighted_median(&mut equal), median(&mut values), "{v:?}");
        }
    }

    #[test]
    fn normal_cdf_matches_integration_and_known_values() {
        for i in -60..=60 {
            let x = i as f64 * 0.1;
            let (fast, slow) = (normal_cdf(x), normal_cdf_slow(x));
            assert!((fast - slow).abs() < 2e-7, "x={x}: {fast} vs {slow}");
        }
        assert!((normal_cdf(1.959_963_985) - 0.975).abs() < 1e-7);
        assert!((normal_cdf(0.0) - 0.5).abs() < 1e-7);
    }

    #[test]
    fn normal_quantile_inverts_the_cdf() {
        assert!((normal_quantile(0.975) - 1.959_963_984_540_054).abs() < 1e-12);
        assert!((normal_quantile(0.841_344_746_068_542_9) - 1.0).abs() < 1e-12);
        assert!((normal_quantile(0.16) + 0.994_457_883_209_753).abs() < 1e-12);
        assert!(normal_quantile(0.5).abs() < 1e-15);
        assert!(normal_quantile(-0.1).is_nan() && normal_quantile(f64::NAN).is_nan());
        assert_eq!(normal_quantile(1.0), f64::INFINITY);
    }

    #[test]
    fn ks_statistic_matches_brute_force() {
        let mut rng = test_rng(3);
        let xs: Vec<f64> = (0..500).map(|_| rng.random::<f64>().powi(2)).collect();
        let cdf = |x: f64| x.clamp(0.0, 1.0);
        let (a, b) = (ks_statistic(&xs, cdf), ks_statistic_slow(&xs, cdf));
        assert!((a - b).abs() < 1e-15, "{a} {b}");
        // x² of a uniform is far from uniform: D is large.
        assert!(a > 0.2);
    }

    #[test]
    fn kolmogorov_critical_values() {
        // Classical asymptotic critical values of λ: 1.224 (10 %),
        // 1.358 (5 %), 1.628 (1 %).
        assert!((kolmogorov_q(1.224) - 0.10).abs() < 1e-3);
        assert!((kolmogorov_q(1.358) - 0.05).abs() < 1e-3);
        assert!((kolmogorov_q(1.628) - 0.01).abs() < 1e-3);
        assert_eq!(kolmogorov_q(0.0), 1.0);
    }

    #[test]
    fn ks_accepts_the_true_law_and_rejects_a_wrong_one() {
        let mut rng = test_rng(4);
        let xs: Vec<f64> = (0..20_000).map(|_| rng.random::<f64>()).collect();
        let p = ks_p_value(ks_statistic(&xs, |x| x.clamp(0.0, 1.0)), xs.len());
        assert!(p > 0.01, "p = {p}");
        let p = ks_p_value(ks_statistic(&xs, |x| x.clamp(0.0, 1.0).powf(1.2)), xs.len());
        assert!(p < 1e-6, "p = {p}");
    }
}
