//! The telescope pupil: a disk with a central obstruction and spider arms.
//!
//! Coordinates in metres on the pupil, x and y in the same orientation as the
//! sky axes of the image (no inversion). Spider arm k runs from the centre
//! outward at angle α₀ + 2πk/N from +x and blocks a strip of the given width
//! (the arms of a 4-arm spider form two perpendicular bars).
//!
//! Sampled transmission is **anti-aliased**: each cell of the grid holds the
//! fraction of its area that is open, estimated with `supersample²`
//! sub-points on cells that an edge crosses (cells far from every edge are 0
//! or 1 exactly).

use super::Telescope;

/// A pupil geometry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pupil {
    /// Outer diameter (m).
    pub diameter_m: f64,
    /// Central obstruction diameter (m).
    pub obstruction_m: f64,
    /// Number of spider arms.
    pub arms: u32,
    /// Width of each arm (m).
    pub arm_width_m: f64,
    /// Angle of the first arm from +x (radians).
    pub arm_angle_rad: f64,
}

impl Pupil {
    /// The pupil of telescope `t`.
    pub fn from_telescope(t: &Telescope) -> Self {
        Self {
            diameter_m: t.diameter_m,
            obstruction_m: t.obstruction_m,
            arms: t.spider_arms,
            arm_width_m: t.spider_width_m,
            arm_angle_rad: t.spider_angle_deg.to_radians(),
        }
    }

    /// Whether the point (x, y) (metres) is open.
    pub fn is_open(&self, x: f64, y: f64) -> bool {
        let r2 = x * x + y * y;
        let (ro, ri) = (0.5 * self.diameter_m, 0.5 * self.obstruction_m);
        if r2 > ro * ro || r2 < ri * ri {
            return false;
        }
        self.arm_distance(x, y) >= 0.5 * self.arm_width_m
    }

    /// Distance from (x, y) to the nearest arm's centre line (∞ without arms).
    fn arm_distance(&self, x: f64, y: f64) -> f64 {
        let mut d = f64::INFINITY;
        for k in 0..self.arms {
            let a =
                self.arm_angle_rad + std::f64::consts::TAU * f64::from(k) / f64::from(self.arms);
            let (c, s) = (a.cos(), a.sin());
            let along = x * c + y * s;
            let across = (-x * s + y * c).abs();
            let dist = if along >= 0.0 { across } else { x.hypot(y) };
            d = d.min(dist);
        }
        d
    }

    /// Open fraction of each cell of an `n × n` grid of spacing `dx_m`,
    /// row-major, with the pupil centre at the centre of cell (n/2, n/2).
    pub fn sample(&self, n: usize, dx_m: f64, supersample: usize) -> Vec<f64> {
        let ss = supersample.max(1);
        let (ro, ri) = (0.5 * self.diameter_m, 0.5 * self.obstruction_m);
        let half_diag = dx_m * std::f64::consts::FRAC_1_SQRT_2;
        let c = (n / 2) as f64;
        let mut out = vec![0.0; n * n];
        for j in 0..n {
            let y = (j as f64 - c) * dx_m;
            for i in 0..n {
                let x = (i as f64 - c) * dx_m;
                let r = x.hypot(y);
                if r - half_diag > ro || r + half_diag < ri {
                    continue;
                }
                let clear = r + half_diag < ro
                    && r - half_diag > ri
                    && self.arm_distance(x, y) - half_diag > 0.5 * self.arm_width_m;
                out[j * n + i] = if clear {
                    1.0
                } else {
                    let mut k = 0usize;
                    for b in 0..ss {
                        let yy = y + ((b as f64 + 0.5) / ss as f64 - 0.5) * dx_m;
                        for a in 0..ss {
                            let xx = x + ((a as f64 + 0.5) / ss as f64 - 0.5) * dx_m;
                            k += usize::from(self.is_open(xx, yy));
                        }
                    }
                    k as f64 / (ss * ss) as f64
                };
            }
        }
        out
    }

    /// Open area (m²) from geometry: annulus minus the arms' strips between
    /// the obstruction and the rim (neglecting the w²-order corners where
    /// arms meet the circles and each other).
    pub fn open_area_m2(&self) -> f64 {
        let annulus =
            std::f64::consts::PI / 4.0 * (self.diameter_m.powi(2) - self.obstruction_m.powi(2));
        annulus
            - f64::from(self.arms) * self.arm_width_m * 0.5 * (self.diameter_m - self.obstruction_m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sampled_area_matches_geometry() {
        let p = Pupil::from_telescope(&Telescope::default());
        let dx = 3.6 / 500.0;
        let t = p.sample(512, dx, 8);
        let area: f64 = t.iter().sum::<f64>() * dx * dx;
        let want = p.open_area_m2();
        assert!((area / want - 1.0).abs() < 2e-4, "{area} vs {want}");
        // Anti-aliased: some cells are partially open.
        assert!(t.iter().any(|&v| v > 0.1 && v < 0.9));
        // Arms along +x and +y block the centre lines.
        assert!(!p.is_open(1.2, 0.0) && !p.is_open(0.0, -1.2));
        assert!(p.is_open(1.2, 0.05) && !p.is_open(0.3, 0.3) && !p.is_open(1.9, 0.0));
    }

    #[test]
    fn three_arms_are_rays_not_bars() {
        let p = Pupil {
            arms: 3,
            ..Pupil::from_telescope(&Telescope::default())
        };
        assert!(!p.is_open(1.2, 0.0));
        assert!(p.is_open(-1.2, 0.0));
    }
}
