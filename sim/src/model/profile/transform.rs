//! Linear maps of the plane: size, flattening, rotation and shear.
//!
//! A component is a unit circular profile f carried to the sky by a linear
//! map L (unit-profile coordinates → arcsec offsets from the centre):
//! I(x) = F / |det L| · f(|L⁻¹ x|). Its transform is F · f̃(|Lᵀ k|), so only the
//! symmetric matrix L Lᵀ is needed in Fourier space, and its unweighted
//! second-moment tensor is Q = ⟨r²⟩/2 · L Lᵀ (per unit flux).
//!
//! Shear (SPEC §1): the sheared profile is I'(x) = I(A x) with the
//! area-preserving A = (1−|g|²)^{−1/2} [[1−g1, −g2], [−g2, 1+g1]], i.e. the
//! map becomes A⁻¹ L. Positive g1 stretches along x, positive g2 along y = x.
//! A sub-pixel shift by x₀ is the phase e^{−2πi k·x₀} (applied by the
//! renderer per stamp).

/// A 2 × 2 real matrix acting on column vectors (x, y).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinearMap {
    /// Row-major entries.
    pub m: [[f64; 2]; 2],
}

/// The shear matrix A(g) of SPEC §1 (det A = 1).
pub fn shear_matrix(g1: f64, g2: f64) -> LinearMap {
    LinearMap {
        m: stepsim_contract::shear::shear_matrix(g1, g2),
    }
}

impl LinearMap {
    /// The identity.
    pub const IDENTITY: Self = Self {
        m: [[1.0, 0.0], [0.0, 1.0]],
    };

    /// Counter-clockwise rotation by `theta` radians.
    pub fn rotation(theta: f64) -> Self {
        let (s, c) = theta.sin_cos();
        Self {
            m: [[c, -s], [s, c]],
        }
    }

    /// Scaling by `sx` along x and `sy` along y.
    pub fn diagonal(sx: f64, sy: f64) -> Self {
        Self {
            m: [[sx, 0.0], [0.0, sy]],
        }
    }

    /// The map of an elliptical component before shear: major axis `a`
    /// (arcsec) along position angle `theta` (radians CCW from +x), minor
    /// axis `ba · a`.
    pub fn ellipse(a: f64, ba: f64, theta: f64) -> Self {
        Self::rotation(theta).then_after(Self::diagonal(a, ba * a))
    }

    /// The matrix product `self · other` (apply `other` first).
    pub fn then_after(self, other: Self) -> Self {
        let (a, b) = (self.m, other.m);
        let mut m = [[0.0; 2]; 2];
        for (i, row) in m.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = a[i][0] * b[0][j] + a[i][1] * b[1][j];
            }
        }
        Self { m }
    }

    /// Determinant.
    pub fn det(&self) -> f64 {
        self.m[0][0] * self.m[1][1] - self.m[0][1] * self.m[1][0]
    }

    /// Inverse (the caller guarantees det ≠ 0).
    pub fn inverse(&self) -> Self {
        let d = self.det();
        Self {
            m: [
                [self.m[1][1] / d, -self.m[0][1] / d],
                [-self.m[1][0] / d, self.m[0][0] / d],
            ],
        }
    }

    /// Applies the map to (x, y).
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        (
            self.m[0][0] * x + self.m[0][1] * y,
            self.m[1][0] * x + self.m[1][1] * y,
        )
    }

    /// The symmetric matrix L Lᵀ as (xx, xy, yy).
    pub fn gram(&self) -> [f64; 3] {
        let m = &self.m;
        [
            m[0][0] * m[0][0] + m[0][1] * m[0][1],
            m[0][0] * m[1][0] + m[0][1] * m[1][1],
            m[1][0] * m[1][0] + m[1][1] * m[1][1],
        ]
    }

    /// Largest singular value: the longest semi-axis of the image of the
    /// unit circle.
    pub fn max_stretch(&self) -> f64 {
        let [a, b, c] = self.gram();
        let half_tr = 0.5 * (a + c);
        let disc = (0.25 * (a - c) * (a - c) + b * b).sqrt();
        (half_tr + disc).sqrt()
    }
}

/// The eq. 1 ellipticity e = χ / (1 + sqrt(1 − |χ|²)) of a second-moment
/// tensor (xx, xy, yy), with χ = (Qxx − Qyy, 2Qxy) / (Qxx + Qyy).
pub fn ellipticity_of_moments(q: [f64; 3]) -> (f64, f64) {
    let e = stepsim_contract::shear::Moments {
        xx: q[0],
        xy: q[1],
        yy: q[2],
    }
    .ellipticity();
    (e.re, e.im)
}

/// Paper eq. 8: e = (e_s + g) / (1 + g* e_s) in complex numbers.
pub fn shear_ellipticity(e: (f64, f64), g: (f64, f64)) -> (f64, f64) {
    use num_complex::Complex64;
    let out =
        stepsim_contract::shear::apply_shear(Complex64::new(e.0, e.1), Complex64::new(g.0, g.1));
    (out.re, out.im)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shear_matrix_is_area_preserving_and_stretches_along_x_for_positive_g1() {
        let a = shear_matrix(0.1, 0.05);
        assert!((a.det() - 1.0).abs() < 1e-14);
        // The sheared image of a circle, A⁻¹, is longer along x for g1 > 0.
        let l = shear_matrix(0.2, 0.0).inverse();
        let (x, _) = l.apply(1.0, 0.0);
        let (_, y) = l.apply(0.0, 1.0);
        assert!(x > 1.0 && y < 1.0);
    }

    #[test]
    fn ellipse_moments_give_eq1_ellipticity_and_shear_gives_eq8() {
        // Q ∝ L Lᵀ of an ellipse with β, θ has e = (1−β)/(1+β) e^{2iθ}.
        let (beta, theta): (f64, f64) = (0.4, 0.7);
        let l = LinearMap::ellipse(2.0, beta, theta);
        let e = ellipticity_of_moments(l.gram());
        let want = (1.0 - beta) / (1.0 + beta);
        assert!((e.0 - want * (2.0 * theta).cos()).abs() < 1e-14);
        assert!((e.1 - want * (2.0 * theta).sin()).abs() < 1e-14);
        // Sheared map A⁻¹ L obeys eq. 8 exactly.
        let g = (0.05, -0.03);
        let sheared = shear_matrix(g.0, g.1).inverse().then_after(l);
        let got = ellipticity_of_moments(sheared.gram());
        let want = shear_ellipticity(e, g);
        assert!((got.0 - want.0).abs() < 1e-14 && (got.1 - want.1).abs() < 1e-14);
        // Max stretch of the unsheared ellipse is the major axis.
        assert!((l.max_stretch() - 2.0).abs() < 1e-14);
    }
}
