//! Weighted least-squares polynomial fits, y = Σ_k a_k x^k, and means with
//! errors: the numerical kernels of the metrics.
//!
//! Errors on the parameters: when every point has a positive finite error
//! σ_i, weights are 1/σ_i² and the covariance is (AᵀWA)⁻¹ (the errors given
//! are taken at face value, no χ² rescaling). When some σ_i is zero or
//! unknown (for example a single image per dataset, or synthetic data
//! without noise), the fit is unweighted and the covariance is
//! s²(AᵀA)⁻¹ with s² = RSS/(n − p) (no error when n = p).
//! [`fit_line_closed_form`] is the textbook straight-line fit that tests the
//! general solver.

/// Result of a polynomial fit.
#[derive(Debug, Clone, PartialEq)]
pub struct PolyFit {
    /// Coefficients a_0 (constant), a_1 (slope), a_2, ...
    pub coef: Vec<f64>,
    /// 1σ errors of the coefficients (`None` when not determined).
    pub err: Vec<Option<f64>>,
}

/// Fits y = Σ_{k<p} a_k x^k by weighted least squares with per-point errors
/// `sigma` (see the module doc for the error rule). `None` when there are
/// fewer points than parameters or the design is singular.
pub fn fit_poly(x: &[f64], y: &[f64], sigma: &[Option<f64>], p: usize) -> Option<PolyFit> {
    let n = x.len();
    if n < p || p == 0 || y.len() != n || sigma.len() != n {
        return None;
    }
    let weighted = sigma
        .iter()
        .all(|s| matches!(s, Some(v) if *v > 0.0 && v.is_finite()));
    let w: Vec<f64> = sigma
        .iter()
        .map(|s| {
            if weighted {
                1.0 / s.unwrap_or(1.0).powi(2)
            } else {
                1.0
            }
        })
        .collect();
    let mut m = vec![vec![0.0; p]; p];
    let mut b = vec![0.0; p];
    for i in 0..n {
        let pw: Vec<f64> = (0..p).map(|k| x[i].powi(k as i32)).collect();
        for r in 0..p {
            b[r] += w[i] * pw[r] * y[i];
            for c in 0..p {
                m[r][c] += w[i] * pw[r] * pw[c];
            }
        }
    }
    let flat: Vec<f64> = m.concat();
    let (coef, inv) = stepsim_numerics::linalg::solve_spd_with_inverse(&flat, &b)?;
    let s2 = if weighted {
        Some(1.0)
    } else if n > p {
        let rss: f64 = (0..n)
            .map(|i| {
                let f: f64 = (0..p).map(|k| coef[k] * x[i].powi(k as i32)).sum();
                (y[i] - f).powi(2)
            })
            .sum();
        Some(rss / (n - p) as f64)
    } else {
        None
    };
    let err = (0..p)
        .map(|k| s2.map(|s2| (s2 * inv[k * p + k]).max(0.0).sqrt()))
        .collect();
    Some(PolyFit { coef, err })
}

/// Reference: the closed-form weighted straight-line fit y = a + b x
/// (Numerical Recipes §15.2). Returns (a, b, σ_a, σ_b) with weights 1/σ².
pub fn fit_line_closed_form(x: &[f64], y: &[f64], sigma: &[f64]) -> (f64, f64, f64, f64) {
    let (mut s, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for i in 0..x.len() {
        let w = 1.0 / (sigma[i] * sigma[i]);
        s += w;
        sx += w * x[i];
        sy += w * y[i];
        sxx += w * x[i] * x[i];
        sxy += w * x[i] * y[i];
    }
    let delta = s * sxx - sx * sx;
    let a = (sxx * sy - sx * sxy) / delta;
    let b = (s * sxy - sx * sy) / delta;
    (a, b, (sxx / delta).sqrt(), (s / delta).sqrt())
}

/// Mean of `v` and its error, the standard deviation (n − 1) over √n
/// (`None` for fewer than two values). `None` mean for an empty slice.
pub fn mean_and_error(v: &[f64]) -> (Option<f64>, Option<f64>) {
    let n = v.len();
    if n == 0 {
        return (None, None);
    }
    let mean = v.iter().sum::<f64>() / n as f64;
    if n < 2 {
        return (Some(mean), None);
    }
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    (Some(mean), Some((var / n as f64).sqrt()))
}

/// Population standard deviation (divide by n) of `v`; `None` when empty.
pub fn population_std(v: &[f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    Some((v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weighted_line_matches_the_closed_form() {
        let x = [0.0, 0.005, 0.01, 0.05, 0.1];
        let y = [0.0011, -0.0003, 0.0004, -0.002, -0.0041];
        let s = [0.001, 0.0012, 0.0009, 0.0015, 0.002];
        let f = fit_poly(&x, &y, &s.map(Some), 2).unwrap();
        let (a, b, sa, sb) = fit_line_closed_form(&x, &y, &s);
        assert!((f.coef[0] - a).abs() < 1e-15, "{} {a}", f.coef[0]);
        assert!((f.coef[1] - b).abs() < 1e-12);
        assert!((f.err[0].unwrap() - sa).abs() < 1e-15);
        assert!((f.err[1].unwrap() - sb).abs() < 1e-12);
    }

    #[test]
    fn exact_quadratic_is_recovered_and_unweighted_errors_vanish() {
        let x = [0.0, 0.005, 0.01, 0.05, 0.1];
        let y: Vec<f64> = x.iter().map(|x| 0.002 - 0.03 * x + 0.7 * x * x).collect();
        let f = fit_poly(&x, &y, &[None; 5], 3).unwrap();
        assert!((f.coef[0] - 0.002).abs() < 1e-12);
        assert!((f.coef[1] + 0.03).abs() < 1e-10);
        assert!((f.coef[2] - 0.7).abs() < 1e-8);
        assert!(f.err[2].unwrap() < 1e-8);
        // Fewer points than parameters: no fit.
        assert!(fit_poly(&x[..2], &y[..2], &[None; 2], 3).is_none());
        // All x equal: the slope is undetermined.
        assert!(fit_poly(&[0.1; 3], &[1.0, 2.0, 3.0], &[None; 3], 2).is_none());
        // Weights spanning 40 decades still give the exact line.
        let yl: Vec<f64> = x.iter().map(|x| 0.5 + 2.0 * x).collect();
        let s = [
            Some(1e-19),
            Some(1e-9),
            Some(1e-10),
            Some(1e-3),
            Some(1e-12),
        ];
        let f = fit_poly(&x, &yl, &s, 2).unwrap();
        assert!(
            (f.coef[0] - 0.5).abs() < 1e-12 && (f.coef[1] - 2.0).abs() < 1e-9,
            "{f:?}"
        );
        // n = p: exact, errors unknown.
        let f = fit_poly(&x[..3], &y[..3], &[None; 3], 3).unwrap();
        assert_eq!(f.err, vec![None, None, None]);
    }

    #[test]
    fn mean_error_and_population_std() {
        let (m, e) = mean_and_error(&[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(m, Some(2.5));
        // sample std = sqrt(5/3); / sqrt(4)
        assert!((e.unwrap() - (5.0f64 / 3.0).sqrt() / 2.0).abs() < 1e-15);
        assert_eq!(mean_and_error(&[3.0]), (Some(3.0), None));
        assert_eq!(population_std(&[1.0, 3.0]), Some(1.0));
    }
}
