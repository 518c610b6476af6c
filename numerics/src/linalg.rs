//! One dense linear solver: symmetric positive-definite systems (the normal
//! equations of every least-squares fit in the workspace) by Cholesky
//! decomposition, and the inverse of such a matrix (a fit's covariance).
//! Matrices are row-major `n × n` slices.

/// The Cholesky factor L (row-major, lower triangle) of `a` = L Lᵀ, or
/// `None` when a pivot is NaN or not above 1e-14 of its diagonal entry (not
/// positive definite to working precision).
fn cholesky(a: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut l = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..=i {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= l[i * n + k] * l[j * n + k];
            }
            if i == j {
                if s.is_nan() || s <= 1e-14 * a[i * n + i].abs() {
                    return None;
                }
                l[i * n + i] = s.sqrt();
            } else {
                l[i * n + j] = s / l[j * n + j];
            }
        }
    }
    Some(l)
}

/// Solves L Lᵀ x = b by forward then back substitution.
fn substitute(l: &[f64], b: &[f64]) -> Vec<f64> {
    let n = b.len();
    let mut y = vec![0.0; n];
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i * n + k] * y[k];
        }
        y[i] = s / l[i * n + i];
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let mut s = y[i];
        for k in i + 1..n {
            s -= l[k * n + i] * x[k];
        }
        x[i] = s / l[i * n + i];
    }
    x
}

/// Solves the symmetric positive-definite system `a x = b` (`a` row-major
/// `n × n`, `n` = `b.len()`) by Cholesky decomposition; `None` if `a` is
/// not positive definite (see the pivot rule of the module).
pub fn solve_spd(a: &[f64], b: &[f64]) -> Option<Vec<f64>> {
    let n = b.len();
    if a.len() != n * n {
        return None;
    }
    let l = cholesky(a, n)?;
    Some(substitute(&l, b))
}

/// Solves `a x = b` and also returns a⁻¹ (row-major), both from one
/// Cholesky decomposition; `None` if `a` is not positive definite.
pub fn solve_spd_with_inverse(a: &[f64], b: &[f64]) -> Option<(Vec<f64>, Vec<f64>)> {
    let n = b.len();
    if a.len() != n * n {
        return None;
    }
    let l = cholesky(a, n)?;
    let mut inv = vec![0.0; n * n];
    let mut e = vec![0.0; n];
    for col in 0..n {
        e.iter_mut()
            .enumerate()
            .for_each(|(i, v)| *v = f64::from(u8::from(i == col)));
        for (row, v) in substitute(&l, &e).into_iter().enumerate() {
            inv[row * n + col] = v;
        }
    }
    Some((substitute(&l, b), inv))
}

/// Determinant by cofactor expansion along the first row (O(n!): the slow
/// twin's building block, for small n).
fn determinant_by_cofactors(a: &[f64], n: usize) -> f64 {
    if n == 0 {
        return 1.0;
    }
    (0..n)
        .map(|col| {
            let minor: Vec<f64> = (1..n)
                .flat_map(|r| (0..n).filter(move |&c| c != col).map(move |c| (r, c)))
                .map(|(r, c)| a[r * n + c])
                .collect();
            let sign = if col % 2 == 0 { 1.0 } else { -1.0 };
            sign * a[col] * determinant_by_cofactors(&minor, n - 1)
        })
        .sum()
}

/// Slow reference for [`solve_spd`]: Cramer's rule, x_k = det(a with
/// column k replaced by b) / det(a); `None` when det(a) is zero.
pub fn solve_spd_slow(a: &[f64], b: &[f64]) -> Option<Vec<f64>> {
    let n = b.len();
    let det = determinant_by_cofactors(a, n);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    Some(
        (0..n)
            .map(|k| {
                let mut ak = a.to_vec();
                for r in 0..n {
                    ak[r * n + k] = b[r];
                }
                determinant_by_cofactors(&ak, n) / det
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_rng;
    use rand::RngExt;

    /// A random SPD matrix Mᵀ M + n I.
    fn spd(rng: &mut impl rand::Rng, n: usize) -> Vec<f64> {
        let m: Vec<f64> = (0..n * n).map(|_| rng.random::<f64>() - 0.5).collect();
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                a[i * n + j] = (0..n).map(|k| m[k * n + i] * m[k * n + j]).sum::<f64>()
                    + if i == j { 0.1 } else { 0.0 };
            }
        }
        a
    }

    #[test]
    fn cholesky_matches_cramer_and_inverts() {
        let mut rng = test_rng(1);
        for n in 1..=6 {
            for _ in 0..20 {
                let a = spd(&mut rng, n);
                let b: Vec<f64> = (0..n).map(|_| rng.random::<f64>() * 10.0 - 5.0).collect();
                let fast = solve_spd(&a, &b).unwrap();
                let slow = solve_spd_slow(&a, &b).unwrap();
                for (f, s) in fast.iter().zip(&slow) {
                    assert!((f - s).abs() < 1e-9 * (1.0 + s.abs()), "n {n}: {f} {s}");
                }
                let (x, inv) = solve_spd_with_inverse(&a, &b).unwrap();
                assert_eq!(x, fast);
                for i in 0..n {
                    for j in 0..n {
                        let p: f64 = (0..n).map(|k| a[i * n + k] * inv[k * n + j]).sum();
                        let want = if i == j { 1.0 } else { 0.0 };
                        assert!((p - want).abs() < 1e-9, "n {n}: A A⁻¹ [{i}][{j}] = {p}");
                    }
                }
            }
        }
    }

    #[test]
    fn known_system_and_refusals() {
        let a = [4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];
        let x_true = [1.0, -2.0, 0.25];
        let b: Vec<f64> = (0..3)
            .map(|i| (0..3).map(|k| a[i * 3 + k] * x_true[k]).sum())
            .collect();
        let x = solve_spd(&a, &b).unwrap();
        for k in 0..3 {
            assert!((x[k] - x_true[k]).abs() < 1e-12);
        }
        // Indefinite, singular, NaN and mis-sized systems are refused.
        assert!(solve_spd(&[1.0, 2.0, 2.0, 1.0], &[1.0, 1.0]).is_none());
        assert!(solve_spd(&[1.0, 1.0, 1.0, 1.0], &[1.0, 1.0]).is_none());
        assert!(solve_spd(&[f64::NAN], &[1.0]).is_none());
        assert!(solve_spd(&[1.0, 0.0, 0.0], &[1.0, 1.0]).is_none());
        assert_eq!(determinant_by_cofactors(&[2.0, 1.0, 1.0, 3.0], 2), 5.0);
        assert!(solve_spd_slow(&[1.0, 1.0, 1.0, 1.0], &[1.0, 1.0]).is_none());
    }
}
