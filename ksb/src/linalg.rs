//! 2 × 2 tensors (the normal equations of the fits are solved by
//! `stepsim_numerics::linalg`).

/// A 2 × 2 matrix, `m[row][col]`.
pub type Mat2 = [[f64; 2]; 2];

/// Half the trace.
pub fn half_trace(m: &Mat2) -> f64 {
    0.5 * (m[0][0] + m[1][1])
}

/// The inverse, or `None` if the determinant is not a normal positive or
/// negative number relative to the entries.
pub fn inverse(m: &Mat2) -> Option<Mat2> {
    let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
    let scale = m.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
    if !det.is_finite() || scale == 0.0 || det.abs() < 1e-12 * scale * scale {
        return None;
    }
    Some([
        [m[1][1] / det, -m[0][1] / det],
        [-m[1][0] / det, m[0][0] / det],
    ])
}

/// Matrix times vector.
pub fn mul_vec(m: &Mat2, v: [f64; 2]) -> [f64; 2] {
    [
        m[0][0] * v[0] + m[0][1] * v[1],
        m[1][0] * v[0] + m[1][1] * v[1],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The identity.
    const IDENTITY: Mat2 = [[1.0, 0.0], [0.0, 1.0]];

    /// Matrix product.
    fn mul(a: &Mat2, b: &Mat2) -> Mat2 {
        let mut c = [[0.0; 2]; 2];
        for (i, row) in c.iter_mut().enumerate() {
            for (j, cij) in row.iter_mut().enumerate() {
                *cij = a[i][0] * b[0][j] + a[i][1] * b[1][j];
            }
        }
        c
    }

    #[test]
    fn inverse_inverts() {
        let m = [[2.0, 0.3], [-0.1, 1.5]];
        let p = mul(&m, &inverse(&m).unwrap());
        for (i, row) in p.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                assert!((v - IDENTITY[i][j]).abs() < 1e-14);
            }
        }
        assert!(inverse(&[[1.0, 2.0], [2.0, 4.0]]).is_none());
    }
}
