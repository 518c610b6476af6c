//! Low-order 2-D polynomials across the field, fitted by least squares with
//! κσ clipping (KSB table row "PSF: 2D polynomial model").
//!
//! A polynomial of order n is Σ_{i+j ≤ n} c_ij u^i v^j in normalised
//! coordinates u = (x − x₀)/s, v = (y − y₀)/s (s = half the larger image
//! side), so the normal equations stay well conditioned.

use stepsim_numerics::fit::Clip;

/// Number of coefficients of an order-`n` polynomial in two variables.
pub fn n_terms(order: usize) -> usize {
    (order + 1) * (order + 2) / 2
}

/// Normalisation of field coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldFrame {
    /// Centre x.
    pub x0: f64,
    /// Centre y.
    pub y0: f64,
    /// Scale.
    pub scale: f64,
}

impl FieldFrame {
    /// The frame of a `width × height` image (array coordinates).
    pub fn of_image(width: usize, height: usize) -> Self {
        Self {
            x0: 0.5 * (width as f64 - 1.0),
            y0: 0.5 * (height as f64 - 1.0),
            scale: 0.5 * width.max(height).max(2) as f64,
        }
    }

    fn basis(&self, order: usize, x: f64, y: f64, out: &mut Vec<f64>) {
        out.clear();
        let (u, v) = ((x - self.x0) / self.scale, (y - self.y0) / self.scale);
        for total in 0..=order {
            for j in 0..=total {
                out.push(u.powi((total - j) as i32) * v.powi(j as i32));
            }
        }
    }
}

/// A fitted polynomial.
#[derive(Debug, Clone, PartialEq)]
pub struct Poly2 {
    /// Order.
    pub order: usize,
    /// Coordinate frame.
    pub frame: FieldFrame,
    /// Coefficients in the order of [`FieldFrame`]'s basis (by total degree,
    /// then by the power of v).
    pub coef: Vec<f64>,
}

impl Poly2 {
    /// Value at (x, y).
    pub fn eval(&self, x: f64, y: f64) -> f64 {
        let mut b = Vec::with_capacity(self.coef.len());
        self.frame.basis(self.order, x, y, &mut b);
        b.iter().zip(&self.coef).map(|(a, c)| a * c).sum()
    }
}

/// Least-squares fit of several quantities at the same points, with joint
/// κσ clipping under the workspace's one rule
/// ([`stepsim_numerics::fit`]: a point is dropped for good when any
/// quantity's residual exceeds κ robust σ (1.4826 × median absolute
/// residual) of that quantity; at most 10 passes). The order is lowered
/// until there are `per_term` kept points per coefficient. Returns the fits
/// and the kept mask, or `None` with fewer than `min_points` points.
pub fn fit_clipped(
    frame: FieldFrame,
    xy: &[(f64, f64)],
    values: &[Vec<f64>],
    max_order: usize,
    kappa: f64,
    per_term: f64,
    min_points: usize,
) -> Option<(Vec<Poly2>, Vec<bool>)> {
    let order_of = |terms: usize| (0..).find(|&o| n_terms(o) >= terms).unwrap_or(0);
    let terms_for = |kept: usize| {
        let mut order = max_order;
        while order > 0 && (kept as f64) < per_term * n_terms(order) as f64 {
            order -= 1;
        }
        n_terms(order)
    };
    let basis = |i: usize, terms: usize, out: &mut Vec<f64>| {
        frame.basis(order_of(terms), xy[i].0, xy[i].1, out);
    };
    let values: Vec<&[f64]> = values.iter().map(Vec::as_slice).collect();
    let clip = Clip {
        kappa,
        max_passes: 10,
        min_points,
    };
    let fit = stepsim_numerics::fit::fit_clipped(&values, basis, terms_for, clip)?;
    let order = order_of(fit.terms);
    let fits = fit
        .coef
        .into_iter()
        .map(|coef| Poly2 { order, frame, coef })
        .collect();
    Some((fits, fit.keep))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_quadratic_and_rejects_outliers() {
        let frame = FieldFrame::of_image(1000, 800);
        let truth = |x: f64, y: f64| 0.02 + 1e-5 * x - 2e-5 * y + 3e-8 * x * y - 1e-8 * x * x;
        let mut xy = Vec::new();
        let mut v = Vec::new();
        for k in 0..60 {
            let (x, y) = ((k * 37 % 1000) as f64, (k * 91 % 800) as f64);
            xy.push((x, y));
            // Deterministic small "noise" of ±1e-4, three gross outliers.
            let n = if k % 2 == 0 { 1e-4 } else { -1e-4 };
            v.push(truth(x, y) + n + if k % 20 == 3 { 0.05 } else { 0.0 });
        }
        let (fits, keep) = fit_clipped(frame, &xy, &[v], 2, 3.0, 3.0, 3).unwrap();
        assert_eq!(fits[0].order, 2);
        assert_eq!(keep.iter().filter(|k| !**k).count(), 3);
        for &(x, y) in &[(0.0, 0.0), (500.0, 400.0), (999.0, 799.0)] {
            assert!((fits[0].eval(x, y) - truth(x, y)).abs() < 1e-4, "{x},{y}");
        }
    }

    #[test]
    fn order_drops_with_few_points() {
        let frame = FieldFrame::of_image(100, 100);
        let xy = vec![
            (10.0, 10.0),
            (90.0, 20.0),
            (50.0, 80.0),
            (20.0, 60.0),
            (70.0, 70.0),
        ];
        let v = vec![xy.iter().map(|p| 1.0 + 0.01 * p.0).collect::<Vec<_>>()];
        // 5 points, 3 per term: order 0 (1 term) only; order 1 needs 9.
        let (fits, _) = fit_clipped(frame, &xy, &v, 2, 3.0, 3.0, 3).unwrap();
        assert_eq!(fits[0].order, 0);
        assert!((fits[0].eval(0.0, 0.0) - 1.0 - 0.01 * 48.0).abs() < 0.3);
        // Exact with enough points per term for order 1.
        let (fits, _) = fit_clipped(frame, &xy, &v, 2, 3.0, 1.5, 3).unwrap();
        assert_eq!(fits[0].order, 1);
        assert!((fits[0].eval(33.0, 5.0) - 1.33).abs() < 1e-10);
    }
}
