//! Bisection: the point where a monotone predicate turns from false to
//! true, narrowed by halving a bracket.

/// When to stop bisecting.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bisection {
    /// At most this many halvings.
    pub max_halvings: usize,
    /// Stop once hi − lo ≤ `relative_width` × hi (0: only the halvings
    /// count, to machine precision).
    pub relative_width: f64,
}

impl Bisection {
    /// Halve `max_halvings` times (or until the bracket stops shrinking).
    pub const fn halvings(max_halvings: usize) -> Self {
        Self {
            max_halvings,
            relative_width: 0.0,
        }
    }

    /// Halve until hi − lo ≤ `relative_width` × hi, at most 200 times.
    pub const fn to_relative_width(relative_width: f64) -> Self {
        Self {
            max_halvings: 200,
            relative_width,
        }
    }

    /// Narrows the bracket [`lo`, `hi`], in which `pred` is false at `lo`
    /// and true at `hi`, to the point where it turns: each step takes
    /// mid = (lo + hi)/2 and moves `hi` there when `pred(mid)` holds, `lo`
    /// otherwise. Returns the final (lo, hi); the width is checked before
    /// each halving.
    pub fn run(&self, mut lo: f64, mut hi: f64, mut pred: impl FnMut(f64) -> bool) -> (f64, f64) {
        for _ in 0..self.max_halvings {
            if hi - lo <= self.relative_width * hi {
                break;
            }
            let mid = 0.5 * (lo + hi);
            if pred(mid) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        (lo, hi)
    }
}

/// Slow reference for [`Bisection::run`]: the first of `steps` + 1 equally
/// spaced points of [`lo`, `hi`] at which `pred` holds (`hi` if none).
pub fn first_true_slow(lo: f64, hi: f64, steps: usize, pred: impl Fn(f64) -> bool) -> f64 {
    (0..=steps)
        .map(|i| lo + (hi - lo) * i as f64 / steps as f64)
        .find(|&x| pred(x))
        .unwrap_or(hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bisection_matches_a_fine_scan() {
        let steps = 1_000_000;
        for (lo, hi, root) in [(0.0, 1.0, 0.3), (-5.0, 7.0, 6.99), (1.0, 2.0, 1.000_001)] {
            let pred = |x: f64| x * x * x >= root * root * root;
            let (a, b) = Bisection::halvings(200).run(lo, hi, pred);
            let slow = first_true_slow(lo, hi, steps, pred);
            let grid = (hi - lo) / steps as f64;
            assert!(a <= b && !pred(a) && pred(b), "{a} {b}");
            assert!((b - slow).abs() <= grid, "{b} vs {slow}");
            assert!((b - root).abs() < 1e-14 * root.abs().max(1.0), "{b}");
        }
    }

    #[test]
    fn bisection_stops_at_the_relative_width() {
        let mut calls = 0;
        let (lo, hi) = Bisection::to_relative_width(1e-6).run(0.0, 1.0, |x| {
            calls += 1;
            x >= 0.5 + 1e-3
        });
        assert!(hi - lo <= 1e-6 * hi && hi - lo > 0.5e-6 * hi, "{lo} {hi}");
        // hi ends near 0.5: 2⁻ᵏ ≤ 0.5e-6 takes k = 21 halvings.
        assert_eq!(calls, 21);
        // A bracket already narrow enough is returned as it is.
        assert_eq!(
            Bisection::to_relative_width(0.5).run(1.0, 1.5, |_| true),
            (1.0, 1.5)
        );
        // Zero halvings: nothing is evaluated.
        assert_eq!(
            Bisection::halvings(0).run(0.0, 1.0, |_| unreachable!()),
            (0.0, 1.0)
        );
    }
}
