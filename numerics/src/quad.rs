//! Composite Simpson's rule: ∫ₐᵇ f ≈ h/3 [f(a) + 4 f(a+h) + 2 f(a+2h) +
//! … + 4 f(b−h) + f(b)] with h = (b − a)/n (exact for cubics; error of
//! order h⁴ f⁗).

/// ∫ₐᵇ f(x) dx by composite Simpson's rule with `n` intervals (`n` even and
/// at least 2; an odd `n` is raised by one). The sum runs f(a) + f(b)
/// first, then the interior points in order: callers' numbers depend on
/// that order to the last bit.
pub fn simpson(f: impl Fn(f64) -> f64, a: f64, b: f64, n: usize) -> f64 {
    let n = n.max(2).next_multiple_of(2);
    let h = (b - a) / n as f64;
    let mut s = f(a) + f(b);
    for i in 1..n {
        let w = if i % 2 == 1 { 4.0 } else { 2.0 };
        s += w * f(a + i as f64 * h);
    }
    s * h / 3.0
}

/// Slow reference for [`simpson`]: Richardson's combination
/// (4 T(h) − T(2h)) / 3 of two trapezoid sums computed separately, which is
/// Simpson's rule written another way.
pub fn simpson_slow(f: impl Fn(f64) -> f64, a: f64, b: f64, n: usize) -> f64 {
    let n = n.max(2).next_multiple_of(2);
    let trapezoid = |m: usize| {
        let h = (b - a) / m as f64;
        let inner: f64 = (1..m).map(|i| f(a + i as f64 * h)).sum();
        h * (0.5 * f(a) + inner + 0.5 * f(b))
    };
    (4.0 * trapezoid(n) - trapezoid(n / 2)) / 3.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn simpson_matches_the_trapezoid_combination() {
        for (a, b, n) in [
            (0.0, 1.0, 2),
            (-3.0, 2.5, 64),
            (1.0, 40.0, 1000),
            (2.0, -1.0, 10),
        ] {
            for f in [
                (|x: f64| (-x * x).exp()) as fn(f64) -> f64,
                |x: f64| x.sin() * x,
                |x: f64| 1.0 / (1.0 + x * x),
            ] {
                let (fast, slow) = (simpson(f, a, b, n), simpson_slow(f, a, b, n));
                assert!(
                    (fast - slow).abs() < 1e-13 * (1.0 + slow.abs()),
                    "{fast} {slow}"
                );
            }
        }
    }

    #[test]
    fn simpson_is_exact_for_cubics_and_converges_as_h4() {
        // ∫₀² (x³ − 2x + 1) dx = 4 − 4 + 2 = 2, exact with two intervals.
        assert!((simpson(|x| x * x * x - 2.0 * x + 1.0, 0.0, 2.0, 2) - 2.0).abs() < 1e-15);
        // An odd count is raised to the next even one.
        assert_eq!(
            simpson(f64::exp, 0.0, 1.0, 7),
            simpson(f64::exp, 0.0, 1.0, 8)
        );
        // ∫₀¹ eˣ = e − 1: halving h divides the error by 16.
        let err = |n| (simpson(f64::exp, 0.0, 1.0, n) - (std::f64::consts::E - 1.0)).abs();
        let ratio = err(8) / err(16);
        assert!((ratio - 16.0).abs() < 0.2, "{ratio}");
    }
}
