//! Tracking error (jitter): the image smeared along one direction.
//!
//! Kernel: a 1-D Gaussian of standard deviation σ (arcsec) along the unit
//! vector (cos α, sin α), a delta across it. Transfer function
//! T(u, v) = exp(−2π² σ² (u cos α + v sin α)²), f in cycles per arcsec.

/// A 1-D Gaussian tracking-error kernel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Jitter {
    /// σ of the smear (arcsec).
    pub sigma_arcsec: f64,
    /// Direction of the smear from +x (radians).
    pub angle_rad: f64,
}

impl Jitter {
    /// T(u, v).
    pub fn transfer(&self, u: f64, v: f64) -> f64 {
        let k = u * self.angle_rad.cos() + v * self.angle_rad.sin();
        let s = std::f64::consts::PI * self.sigma_arcsec * k;
        (-2.0 * s * s).exp()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smears_only_along_its_direction() {
        let j = Jitter {
            sigma_arcsec: 0.15,
            angle_rad: 0.0,
        };
        assert_eq!(j.transfer(0.0, 3.0), 1.0);
        let want = (-2.0 * (std::f64::consts::PI * 0.15 * 2.0f64).powi(2)).exp();
        assert!((j.transfer(2.0, 5.0) - want).abs() < 1e-14);
        let r = Jitter {
            angle_rad: std::f64::consts::FRAC_PI_2,
            ..j
        };
        assert!((r.transfer(5.0, 2.0) - want).abs() < 1e-14);
    }
}
