//! Student's t distribution with ν (a positive integer) degrees of freedom:
//! density, CDF and quantile.
//!
//! The CDF is the finite series of Abramowitz & Stegun 26.7.3–26.7.4
//! (Zelen & Severo): with θ = atan(t/√ν), A(t|ν) = P(|T| ≤ t) is
//!
//! * ν odd: (2/π)[θ + sin θ (cos θ + (2/3) cos³θ + … +
//!   (2·4···(ν−3))/(1·3···(ν−2)) cos^{ν−2}θ)] (for ν = 1 only 2θ/π),
//! * ν even: sin θ [1 + (1/2) cos²θ + (1·3)/(2·4) cos⁴θ + … +
//!   (1·3···(ν−3))/(2·4···(ν−2)) cos^{ν−2}θ],
//!
//! and F(t) = ½ + ½ sign(t) A(|t| | ν): ν/2 terms, exact up to rounding.
//! The quantile is Newton's iteration on that CDF, kept inside a bracket
//! (bisection when a step would leave it), from the Cornish–Fisher start;
//! ν = 1 and ν = 2 have closed forms. [`t_quantile_slow`] is the
//! slow, obvious twin: bisection on the CDF found by integrating the
//! density numerically.

use crate::quad::simpson;
use crate::roots::Bisection;
use std::f64::consts::PI;

/// The density of Student's t with `nu` degrees of freedom,
/// Γ((ν+1)/2) / (√(νπ) Γ(ν/2)) (1 + t²/ν)^(−(ν+1)/2). NaN for ν = 0.
pub fn t_pdf(t: f64, nu: u32) -> f64 {
    if nu == 0 {
        return f64::NAN;
    }
    let n = f64::from(nu);
    let ln_norm = libm::lgamma(0.5 * (n + 1.0)) - libm::lgamma(0.5 * n) - 0.5 * (n * PI).ln();
    (ln_norm - 0.5 * (n + 1.0) * (t * t / n).ln_1p()).exp()
}

/// The CDF of Student's t with `nu` degrees of freedom (the series of the
/// module doc; O(ν) operations). NaN for ν = 0 or a NaN `t`.
pub fn t_cdf(t: f64, nu: u32) -> f64 {
    if nu == 0 || t.is_nan() {
        return f64::NAN;
    }
    if t.is_infinite() {
        return if t > 0.0 { 1.0 } else { 0.0 };
    }
    let n = f64::from(nu);
    let a = t.abs();
    let r = (n + a * a).sqrt();
    let (sin, cos2) = (a / r, n / (n + a * a));
    let abs_prob = if nu % 2 == 1 {
        let theta = a.atan2(n.sqrt());
        let mut sum = 0.0;
        if nu > 1 {
            // cos θ + (2/3) cos³θ + …: term k + 2 = term k · (k+1)/(k+2) · cos²θ.
            let mut term = cos2.sqrt();
            sum = term;
            let mut k = 1;
            while k + 2 < nu {
                term *= f64::from(k + 1) / f64::from(k + 2) * cos2;
                sum += term;
                k += 2;
            }
        }
        2.0 / PI * (theta + sin * sum)
    } else {
        // 1 + (1/2) cos²θ + …: term k + 2 = term k · (k+1)/(k+2) · cos²θ.
        let mut term = 1.0;
        let mut sum = 1.0;
        let mut k = 0;
        while k + 2 < nu {
            term *= f64::from(k + 1) / f64::from(k + 2) * cos2;
            sum += term;
            k += 2;
        }
        sin * sum
    };
    let half = 0.5 * abs_prob.min(1.0);
    if t >= 0.0 { 0.5 + half } else { 0.5 - half }
}

/// The `p` quantile of Student's t with `nu` degrees of freedom: the t with
/// [`t_cdf`]`(t, ν) = p`. NaN for ν = 0 or p outside (0, 1); ±∞ at p = 0, 1.
pub fn t_quantile(p: f64, nu: u32) -> f64 {
    if nu == 0 {
        return f64::NAN;
    }
    if let Some(q) = crate::stats::quantile_outside_open_unit(p) {
        return q;
    }
    if p < 0.5 {
        return -t_quantile(1.0 - p, nu);
    }
    if p == 0.5 {
        return 0.0;
    }
    match nu {
        1 => return (PI * (p - 0.5)).tan(),
        2 => {
            let a = 2.0 * p - 1.0;
            return a * (2.0 / (1.0 - a * a)).sqrt();
        }
        _ => {}
    }
    // Bracket [lo, hi] with F(lo) < p ≤ F(hi).
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    while t_cdf(hi, nu) < p {
        lo = hi;
        hi *= 2.0;
        if hi > 1e300 {
            return f64::INFINITY;
        }
    }
    // Cornish–Fisher start: z + (z³ + z)/(4ν) + (5z⁵ + 16z³ + 3z)/(96ν²).
    let z = crate::stats::normal_quantile(p);
    let n = f64::from(nu);
    let mut x = z
        + (z.powi(3) + z) / (4.0 * n)
        + (5.0 * z.powi(5) + 16.0 * z.powi(3) + 3.0 * z) / (96.0 * n * n);
    if !(lo < x && x < hi) {
        x = 0.5 * (lo + hi);
    }
    for _ in 0..200 {
        let f = t_cdf(x, nu) - p;
        if f < 0.0 {
            lo = x;
        } else {
            hi = x;
        }
        let step = f / t_pdf(x, nu);
        let next = x - step;
        let next = if lo < next && next < hi && step.is_finite() {
            next
        } else {
            0.5 * (lo + hi)
        };
        if (next - x).abs() <= 4.0 * f64::EPSILON * x.abs() || hi - lo <= f64::EPSILON * hi {
            return next;
        }
        x = next;
    }
    x
}

/// Slow reference for [`t_quantile`] (p in (0, 1), ν ≥ 1): bisection
/// ([`Bisection`], to a relative width of 1e-10) of ½ + ∫₀ᵗ [`t_pdf`] = p, the integral by
/// composite Simpson ([`simpson`], 20 000 intervals) of the density; the
/// upper end of the bracket is doubled from 1 until the integral exceeds
/// p. Good to about 1e-8 relative for p ≤ 0.999.
pub fn t_quantile_slow(p: f64, nu: u32) -> f64 {
    if p < 0.5 {
        return -t_quantile_slow(1.0 - p, nu);
    }
    let cdf = |t: f64| 0.5 + simpson(|x| t_pdf(x, nu), 0.0, t, 20_000);
    let mut hi = 1.0;
    while cdf(hi) < p {
        hi *= 2.0;
    }
    let (lo, hi) = Bisection::to_relative_width(1e-10).run(0.0, hi, |t| cdf(t) >= p);
    0.5 * (lo + hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantile_matches_its_slow_twin() {
        for nu in [1, 2, 3, 4, 5, 7, 8, 10, 15, 30, 63, 100] {
            for p in [
                0.05, 0.16, 0.5, 0.6, 0.75, 0.84, 0.9, 0.95, 0.975, 0.99, 0.995,
            ] {
                let (fast, slow) = (t_quantile(p, nu), t_quantile_slow(p, nu));
                assert!(
                    (fast - slow).abs() <= 2e-8 * slow.abs().max(1.0),
                    "ν {nu}, p {p}: {fast} vs {slow}"
                );
                // The quantile inverts the CDF.
                assert!((t_cdf(fast, nu) - p).abs() < 1e-13, "ν {nu}, p {p}");
            }
        }
    }

    #[test]
    fn quantile_matches_table_values() {
        // Two-sided 95 % and 99 % points, one-sided 95 % and 90 % (any
        // table of Student's t, e.g. Abramowitz & Stegun table 26.10).
        for (p, nu, want) in [
            (0.975, 1, 12.7062),
            (0.975, 2, 4.3027),
            (0.975, 3, 3.1824),
            (0.975, 5, 2.5706),
            (0.975, 7, 2.3646),
            (0.975, 10, 2.2281),
            (0.975, 30, 2.0423),
            (0.975, 120, 1.9799),
            (0.995, 5, 4.0321),
            (0.995, 7, 3.4995),
            (0.95, 10, 1.8125),
            (0.9, 7, 1.4149),
        ] {
            let got = t_quantile(p, nu);
            assert!(
                (got - want).abs() < 6e-5,
                "t_({p}, {nu}) = {got}, table {want}"
            );
        }
        // The ±1σ point of 7 degrees of freedom, p = Φ(1) = 0.841345, and
        // p = 0.84 (1.076713 and 1.070287 by an independent Simpson
        // integration of the density in Python).
        let p1 = crate::stats::normal_cdf(1.0);
        assert!(
            (t_quantile(p1, 7) - 1.076_713).abs() < 1e-6,
            "{}",
            t_quantile(p1, 7)
        );
        assert!((t_quantile(0.84, 7) - 1.070_287).abs() < 1e-6);
        // Large ν tends to the normal quantile.
        let z = crate::stats::normal_quantile(0.975);
        assert!((t_quantile(0.975, 100_000) - z).abs() < 1e-4);
        // Symmetry, the median, the ends and nonsense.
        assert_eq!(t_quantile(0.025, 7), -t_quantile(0.975, 7));
        assert_eq!(t_quantile(0.5, 7), 0.0);
        assert_eq!(t_quantile(1.0, 3), f64::INFINITY);
        assert!(t_quantile(0.9, 0).is_nan() && t_quantile(1.5, 3).is_nan());
        assert!(t_quantile(f64::NAN, 3).is_nan());
    }

    #[test]
    fn cdf_has_the_closed_forms_of_small_nu() {
        for i in -40..=40 {
            let t = f64::from(i) * 0.25;
            // ν = 1: Cauchy; ν = 3: ½ + (1/π)[t/(√3(1 + t²/3)) + atan(t/√3)].
            let c1 = 0.5 + t.atan() / PI;
            assert!((t_cdf(t, 1) - c1).abs() < 1e-15, "t {t}");
            let s3 = 3f64.sqrt();
            let c3 = 0.5 + (t / (s3 * (1.0 + t * t / 3.0)) + (t / s3).atan()) / PI;
            assert!((t_cdf(t, 3) - c3).abs() < 1e-15, "t {t}");
            let c2 = 0.5 + t / (2.0 * (2.0 + t * t).sqrt());
            assert!((t_cdf(t, 2) - c2).abs() < 1e-15, "t {t}");
        }
        assert_eq!(t_cdf(f64::INFINITY, 4), 1.0);
        assert!(t_cdf(1.0, 0).is_nan());
    }
}
