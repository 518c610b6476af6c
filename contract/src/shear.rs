//! Ellipticity and shear conventions (SPEC §1), stated once.
//!
//! * **Ellipticity** (paper eq. 1, "reduced-shear type"): for axis ratio
//!   β = b/a and position angle θ (counter-clockwise from +x),
//!   e = (1−β)/(1+β) e^{2iθ}.
//! * **Distortion** (moments type): χ = (1−β²)/(1+β²) e^{2iθ}
//!   = (Qxx − Qyy + 2i Qxy)/(Qxx + Qyy). The two are related by
//!   χ = 2e/(1+|e|²) and e = χ/(1 + sqrt(1−|χ|²)).
//! * **Shear** (paper eq. 8, Seitz & Schneider 1997): a source with
//!   ellipticity e_s appears with e = (e_s + g)/(1 + g* e_s).
//! * The sheared light profile is I'(x) = I(A x) with the area-preserving
//!   A = (1−|g|²)^(−1/2) [[1−g1, −g2], [−g2, 1+g1]]. Its second-moment
//!   tensor is Q' = A⁻¹ Q A⁻ᵀ (substitute u = A x in ∫ x xᵀ I(A x) d²x;
//!   det A = 1), and the ellipticity of Q' obeys eq. 8 exactly. Positive g1
//!   stretches along x, positive g2 along y = x.
//!
//! [`Moments::sheared`] (explicit matrix algebra) is the slow, obvious twin
//! of the closed form [`apply_shear`]; the tests compare them.

use num_complex::Complex64;

/// Ellipticity e = (1−β)/(1+β) e^{2iθ} of axis ratio `beta` at angle
/// `theta` (radians) — paper eq. 1.
pub fn ellipticity(beta: f64, theta: f64) -> Complex64 {
    Complex64::from_polar((1.0 - beta) / (1.0 + beta), 2.0 * theta)
}

/// Distortion χ = (1−β²)/(1+β²) e^{2iθ} of axis ratio `beta` at `theta`.
pub fn distortion(beta: f64, theta: f64) -> Complex64 {
    let b2 = beta * beta;
    Complex64::from_polar((1.0 - b2) / (1.0 + b2), 2.0 * theta)
}

/// Axis ratio β = (1−|e|)/(1+|e|) and angle θ ∈ [0, π) of an ellipticity.
pub fn axis_ratio_and_angle(e: Complex64) -> (f64, f64) {
    let m = e.norm();
    let theta = (0.5 * e.arg()).rem_euclid(std::f64::consts::PI);
    ((1.0 - m) / (1.0 + m), theta)
}

/// Distortion of an ellipticity: χ = 2e/(1+|e|²).
pub fn e_to_chi(e: Complex64) -> Complex64 {
    e * (2.0 / (1.0 + e.norm_sqr()))
}

/// Ellipticity of a distortion: e = χ/(1 + sqrt(1−|χ|²)).
pub fn chi_to_e(chi: Complex64) -> Complex64 {
    chi / (1.0 + (1.0 - chi.norm_sqr()).max(0.0).sqrt())
}

/// Paper eq. 8: the ellipticity of a source of intrinsic ellipticity `e`
/// seen through reduced shear `g`: (e + g)/(1 + g* e).
pub fn apply_shear(e: Complex64, g: Complex64) -> Complex64 {
    (e + g) / (1.0 + g.conj() * e)
}

/// The area-preserving shear matrix A with I'(x) = I(A x), row-major.
pub fn shear_matrix(g1: f64, g2: f64) -> [[f64; 2]; 2] {
    let s = 1.0 / (1.0 - g1 * g1 - g2 * g2).sqrt();
    [[s * (1.0 - g1), -s * g2], [-s * g2, s * (1.0 + g1)]]
}

/// The inverse A⁻¹ = (1−|g|²)^(−1/2) [[1+g1, g2], [g2, 1−g1]] of
/// [`shear_matrix`], row-major: it maps a profile's second-moment tensor to
/// the sheared one, Q' = A⁻¹ Q A⁻ᵀ (A⁻¹ is symmetric), and a round profile
/// of unit tensor to one of ellipticity g.
pub fn inverse_shear_matrix(g1: f64, g2: f64) -> [[f64; 2]; 2] {
    let n = (1.0 - g1 * g1 - g2 * g2).sqrt();
    [[(1.0 + g1) / n, g2 / n], [g2 / n, (1.0 - g1) / n]]
}

/// Where a point at offset `d` from the lensing centre (source plane)
/// appears through the constant reduced shear g: x = A⁻¹ d, with
/// A⁻¹ = (1−|g|²)^(−1/2) [[1+g1, g2], [g2, 1−g1]] the inverse of
/// [`shear_matrix`]. This is the mapping of positions that goes with the
/// sheared profiles I'(x) = I(A x): a pattern of points is stretched like
/// every galaxy (positive g1 along x), and areas are kept (κ = 0).
pub fn lens_offset(d: (f64, f64), g1: f64, g2: f64) -> (f64, f64) {
    let s = 1.0 / (1.0 - g1 * g1 - g2 * g2).sqrt();
    (
        s * ((1.0 + g1) * d.0 + g2 * d.1),
        s * (g2 * d.0 + (1.0 - g1) * d.1),
    )
}

/// A symmetric 2×2 second-moment tensor Q (arcsec², or any squared unit),
/// Q = ∫ x xᵀ I(x) d²x / ∫ I d²x about the centroid.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Moments {
    /// Qxx.
    pub xx: f64,
    /// Qxy.
    pub xy: f64,
    /// Qyy.
    pub yy: f64,
}

impl Moments {
    /// The tensor of an elliptical component whose second moment along its
    /// major axis is `sigma2_major`, with axis ratio `beta` and major axis at
    /// `theta` (radians): R(θ) diag(σ², β²σ²) R(θ)ᵀ.
    pub fn of_ellipse(sigma2_major: f64, beta: f64, theta: f64) -> Self {
        let (s, c) = theta.sin_cos();
        let a2 = sigma2_major;
        let b2 = beta * beta * sigma2_major;
        Self {
            xx: a2 * c * c + b2 * s * s,
            xy: (a2 - b2) * c * s,
            yy: a2 * s * s + b2 * c * c,
        }
    }

    /// Trace Qxx + Qyy.
    pub fn trace(&self) -> f64 {
        self.xx + self.yy
    }

    /// Distortion χ = (Qxx − Qyy + 2i Qxy)/(Qxx + Qyy).
    pub fn distortion(&self) -> Complex64 {
        Complex64::new(self.xx - self.yy, 2.0 * self.xy) / self.trace()
    }

    /// Eigenvalues (λmax, λmin).
    pub fn eigenvalues(&self) -> (f64, f64) {
        let h = 0.5 * (self.xx + self.yy);
        let d = (0.25 * (self.xx - self.yy).powi(2) + self.xy * self.xy).sqrt();
        (h + d, (h - d).max(0.0))
    }

    /// Ellipticity (eq. 1) from the eigen-axis ratio β = sqrt(λmin/λmax) and
    /// the angle of the major eigenvector, θ = ½ atan2(2Qxy, Qxx − Qyy).
    /// Computed from the eigen-decomposition on purpose (not from χ), so
    /// that it is an independent check of the closed forms.
    pub fn ellipticity(&self) -> Complex64 {
        let (lmax, lmin) = self.eigenvalues();
        if lmax <= 0.0 {
            return Complex64::new(0.0, 0.0);
        }
        let beta = (lmin / lmax).sqrt();
        let theta = 0.5 * (2.0 * self.xy).atan2(self.xx - self.yy);
        ellipticity(beta, theta)
    }

    /// The tensor of the profile sheared by A(g): Q' = A⁻¹ Q A⁻ᵀ.
    pub fn sheared(&self, g1: f64, g2: f64) -> Self {
        let a = shear_matrix(g1, g2);
        // det A = 1, so A⁻¹ = [[a11, −a01], [−a10, a00]].
        let inv = [[a[1][1], -a[0][1]], [-a[1][0], a[0][0]]];
        let q = [[self.xx, self.xy], [self.xy, self.yy]];
        let mut t = [[0.0; 2]; 2];
        for i in 0..2 {
            for j in 0..2 {
                t[i][j] = (0..2).map(|k| inv[i][k] * q[k][j]).sum();
            }
        }
        let mut r = [[0.0; 2]; 2];
        for i in 0..2 {
            for j in 0..2 {
                r[i][j] = (0..2).map(|k| t[i][k] * inv[j][k]).sum();
            }
        }
        Self {
            xx: r[0][0],
            xy: 0.5 * (r[0][1] + r[1][0]),
            yy: r[1][1],
        }
    }

    /// `self + w · other` (flux-weighted sums of components).
    pub fn add_weighted(&self, w: f64, other: &Self) -> Self {
        Self {
            xx: self.xx + w * other.xx,
            xy: self.xy + w * other.xy,
            yy: self.yy + w * other.yy,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::seed::{SeedKey, Stream};
    use rand::RngExt;
    use std::f64::consts::PI;

    #[test]
    fn lensed_offsets_undo_the_shear_matrix() {
        for (g1, g2) in [(0.1, 0.0), (0.0, 0.05), (-0.03, 0.07)] {
            let a = shear_matrix(g1, g2);
            for d in [(1.0, 0.0), (0.0, 1.0), (3.0, -2.0)] {
                let x = lens_offset(d, g1, g2);
                let back = (a[0][0] * x.0 + a[0][1] * x.1, a[1][0] * x.0 + a[1][1] * x.1);
                assert!((back.0 - d.0).abs() < 1e-14 && (back.1 - d.1).abs() < 1e-14);
            }
        }
        // Positive g1 stretches along x and squeezes along y.
        let x = lens_offset((1.0, 1.0), 0.1, 0.0);
        assert!(x.0 > 1.09 && x.1 < 0.91, "{x:?}");
    }

    #[test]
    fn inverse_shear_matrix_inverts_the_shear_matrix_and_shears_tensors() {
        let mul = |x: [[f64; 2]; 2], y: [[f64; 2]; 2]| {
            [
                [
                    x[0][0] * y[0][0] + x[0][1] * y[1][0],
                    x[0][0] * y[0][1] + x[0][1] * y[1][1],
                ],
                [
                    x[1][0] * y[0][0] + x[1][1] * y[1][0],
                    x[1][0] * y[0][1] + x[1][1] * y[1][1],
                ],
            ]
        };
        for (g1, g2) in [(0.1, 0.0), (0.0, 0.05), (-0.03, 0.07), (0.4, -0.3)] {
            let inv = inverse_shear_matrix(g1, g2);
            let one = mul(shear_matrix(g1, g2), inv);
            for (got, want) in one.iter().flatten().zip([1.0, 0.0, 0.0, 1.0]) {
                assert!((got - want).abs() < 1e-14, "{g1} {g2}: {one:?}");
            }
            // A⁻¹ Q A⁻ᵀ (A⁻¹ is symmetric) is the tensor of `Moments::sheared`.
            let q = Moments::of_ellipse(2.0, 0.6, 0.4);
            let r = mul(mul(inv, [[q.xx, q.xy], [q.xy, q.yy]]), inv);
            let s = q.sheared(g1, g2);
            for (got, want) in r.iter().flatten().zip([s.xx, s.xy, s.xy, s.yy]) {
                assert!((got - want).abs() < 1e-13, "{g1} {g2}: {r:?} vs {s:?}");
            }
        }
    }

    #[test]
    fn eq1_and_distortion_by_hand() {
        // β = 0.5, θ = 0: e = 1/3, χ = 0.75/1.25 = 0.6.
        let e = ellipticity(0.5, 0.0);
        assert!((e.re - 1.0 / 3.0).abs() < 1e-15 && e.im.abs() < 1e-15);
        let chi = distortion(0.5, 0.0);
        assert!((chi.re - 0.6).abs() < 1e-15);
        // θ = 45°: all in the second component.
        let e = ellipticity(0.5, PI / 4.0);
        assert!(e.re.abs() < 1e-15 && (e.im - 1.0 / 3.0).abs() < 1e-15);
        assert!((e_to_chi(ellipticity(0.5, 0.3)) - distortion(0.5, 0.3)).norm() < 1e-15);
        assert!((chi_to_e(distortion(0.2, 1.3)) - ellipticity(0.2, 1.3)).norm() < 1e-15);
        let (b, t) = axis_ratio_and_angle(ellipticity(0.3, 2.9));
        assert!((b - 0.3).abs() < 1e-14 && (t - 2.9).abs() < 1e-13);
    }

    #[test]
    fn positive_g1_stretches_along_x_and_g2_along_the_diagonal() {
        let round = Moments::of_ellipse(1.0, 1.0, 0.0);
        let s = round.sheared(0.1, 0.0);
        assert!(s.xx > s.yy && s.xy.abs() < 1e-15);
        // Area preserving: det Q unchanged.
        assert!((s.xx * s.yy - s.xy * s.xy - 1.0).abs() < 1e-14);
        let s = round.sheared(0.0, 0.1);
        assert!(s.xy > 0.0 && (s.xx - s.yy).abs() < 1e-15);
        // A circle sheared by g has ellipticity exactly g.
        let e = round.sheared(0.03, -0.07).ellipticity();
        assert!((e - Complex64::new(0.03, -0.07)).norm() < 1e-14);
    }

    #[test]
    fn tensor_ellipticity_matches_eq1() {
        let mut rng = SeedKey::base(1, 0, Stream::Test).rng();
        for _ in 0..2000 {
            let beta = rng.random_range(0.05..1.0);
            let theta = rng.random_range(0.0..PI);
            let sigma2 = rng.random_range(0.01..4.0);
            let q = Moments::of_ellipse(sigma2, beta, theta);
            assert!((q.ellipticity() - ellipticity(beta, theta)).norm() < 1e-12);
            assert!((q.distortion() - distortion(beta, theta)).norm() < 1e-12);
        }
    }

    #[test]
    fn sheared_tensor_obeys_eq8_for_thousands_of_random_cases() {
        let mut rng = SeedKey::base(2, 0, Stream::Test).rng();
        let mut worst = 0.0f64;
        for _ in 0..5000 {
            let beta = rng.random_range(0.02..1.0);
            let theta = rng.random_range(0.0..PI);
            let gm = rng.random_range(0.0..0.6);
            let ga = rng.random_range(0.0..2.0 * PI);
            let g = Complex64::from_polar(gm, ga);
            let q = Moments::of_ellipse(rng.random_range(0.01..4.0), beta, theta);
            let slow = q.sheared(g.re, g.im).ellipticity();
            let fast = apply_shear(ellipticity(beta, theta), g);
            worst = worst.max((slow - fast).norm());
        }
        assert!(worst < 1e-12, "worst |Δe| = {worst:e}");
    }

    #[test]
    fn shearing_back_undoes_a_shear() {
        let e = ellipticity(0.4, 0.7);
        let g = Complex64::new(0.05, -0.02);
        let back = apply_shear(apply_shear(e, g), -g);
        assert!((back - e).norm() < 1e-14);
    }
}
