//! Background (sky) level and noise, SExtractor style: κσ-clipped
//! statistics in square meshes, a 3 × 3 median filter over the mesh grid,
//! and bilinear interpolation between mesh centres.
//!
//! Per mesh: clip at `κ` σ about the median until stable (at most 10
//! passes); the level is SExtractor's mode estimate 2.5 median − 1.5 mean
//! when the clipped distribution is only mildly skewed
//! ((mean − median)/σ < 0.3), else the median. The noise of the image is the
//! median of the meshes' clipped σ (the sky of a STEP image is uniform).

use crate::image::Image;
use rayon::prelude::*;
use stepsim_numerics::stats::median;

/// The background of an image.
#[derive(Debug, Clone, PartialEq)]
pub struct Background {
    /// Mesh side in pixels.
    pub mesh: usize,
    /// Meshes along x.
    pub nx: usize,
    /// Meshes along y.
    pub ny: usize,
    /// Level per mesh (after the median filter), row-major.
    pub levels: Vec<f64>,
    /// Noise σ of one pixel (electrons).
    pub rms: f64,
}

/// κσ-clipped (level, σ) of a sample, or `None` if it is empty. Reorders `v`.
pub fn clipped_stats(v: &mut [f32], kappa: f64) -> Option<(f64, f64)> {
    let mut n = v.len();
    if n == 0 {
        return None;
    }
    let (mut med, mut mean, mut sd) = (0.0, 0.0, 0.0);
    for _ in 0..10 {
        let s = &mut v[..n];
        let mid = n / 2;
        s.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
        med = f64::from(s[mid]);
        mean = s.iter().map(|&x| f64::from(x)).sum::<f64>() / n as f64;
        sd = (s
            .iter()
            .map(|&x| (f64::from(x) - mean).powi(2))
            .sum::<f64>()
            / n as f64)
            .sqrt();
        // Keep the values within κσ of the median at the front.
        let (lo, hi) = (med - kappa * sd, med + kappa * sd);
        let mut k = 0;
        for i in 0..n {
            let x = f64::from(s[i]);
            if x >= lo && x <= hi {
                s.swap(i, k);
                k += 1;
            }
        }
        if k == n || k < 3 {
            break;
        }
        n = k;
    }
    let level = if sd > 0.0 && (mean - med) / sd < 0.3 {
        2.5 * med - 1.5 * mean
    } else {
        med
    };
    Some((level, sd))
}

impl Background {
    /// Estimates the background of `img` with meshes of `mesh` pixels.
    pub fn estimate(img: &Image, mesh: usize, kappa: f64) -> Self {
        let nx = img.width.div_ceil(mesh).max(1);
        let ny = img.height.div_ceil(mesh).max(1);
        let stats: Vec<Option<(f64, f64)>> = (0..nx * ny)
            .into_par_iter()
            .map(|k| {
                let (mx, my) = (k % nx, k / nx);
                let mut v = Vec::with_capacity(mesh * mesh);
                for iy in my * mesh..((my + 1) * mesh).min(img.height) {
                    let row = &img.data[iy * img.width..(iy + 1) * img.width];
                    v.extend(
                        row[mx * mesh..((mx + 1) * mesh).min(img.width)]
                            .iter()
                            .filter(|x| x.is_finite()),
                    );
                }
                clipped_stats(&mut v, kappa)
            })
            .collect();
        let mut sds: Vec<f64> = stats.iter().flatten().map(|s| s.1).collect();
        let rms = median(&mut sds).unwrap_or(0.0);
        let all: Vec<f64> = stats.iter().flatten().map(|s| s.0).collect();
        let fallback = median(&mut all.clone()).unwrap_or(0.0);
        let raw: Vec<f64> = stats.iter().map(|s| s.map_or(fallback, |s| s.0)).collect();
        // 3 × 3 median filter of the mesh grid.
        let mut levels = vec![0.0; nx * ny];
        for my in 0..ny {
            for mx in 0..nx {
                let mut v = Vec::with_capacity(9);
                for j in my.saturating_sub(1)..=(my + 1).min(ny - 1) {
                    for i in mx.saturating_sub(1)..=(mx + 1).min(nx - 1) {
                        v.push(raw[j * nx + i]);
                    }
                }
                levels[my * nx + mx] = median(&mut v).unwrap_or(fallback);
            }
        }
        Self {
            mesh,
            nx,
            ny,
            levels,
            rms,
        }
    }

    /// The background at array coordinate (x, y): bilinear between mesh
    /// centres, constant beyond the outermost centres.
    pub fn level_at(&self, x: f64, y: f64) -> f64 {
        let (i0, i1, tx) = self.axis(x, self.nx);
        let (j0, j1, ty) = self.axis(y, self.ny);
        self.blend((i0, i1, tx), (j0, j1, ty))
    }

    /// Along one axis of `n` meshes: the two mesh centres that bracket array
    /// coordinate `c` and the weight of the second.
    fn axis(&self, c: f64, n: usize) -> (usize, usize, f64) {
        let f = ((c + 0.5) / self.mesh as f64 - 0.5).clamp(0.0, (n - 1) as f64);
        let i0 = f.floor() as usize;
        (i0, (i0 + 1).min(n - 1), f - i0 as f64)
    }

    /// The bilinear blend of the four mesh levels around a point.
    fn blend(&self, (i0, i1, tx): (usize, usize, f64), (j0, j1, ty): (usize, usize, f64)) -> f64 {
        let l = |i: usize, j: usize| self.levels[j * self.nx + i];
        (1.0 - ty) * ((1.0 - tx) * l(i0, j0) + tx * l(i1, j0))
            + ty * ((1.0 - tx) * l(i0, j1) + tx * l(i1, j1))
    }

    /// `img` minus the background: [`Background::level_at`] at every pixel,
    /// with each column's and each row's bracket computed once (the same
    /// arithmetic, so the same bits as [`Background::subtract_slow`]).
    pub fn subtract(&self, img: &Image) -> Image {
        self.subtract_owned(img.clone())
    }

    /// [`Background::subtract`] in the pixels of `img` itself (no second
    /// image): the same arithmetic, the same bits.
    pub fn subtract_owned(&self, img: Image) -> Image {
        let w = img.width;
        let columns: Vec<_> = (0..w).map(|ix| self.axis(ix as f64, self.nx)).collect();
        let mut out = img;
        out.data
            .par_chunks_mut(w)
            .enumerate()
            .for_each(|(iy, row)| {
                let r = self.axis(iy as f64, self.ny);
                for (v, &c) in row.iter_mut().zip(&columns) {
                    *v = (f64::from(*v) - self.blend(c, r)) as f32;
                }
            });
        out
    }

    /// The slow, obvious twin of [`Background::subtract`]: `level_at` for
    /// every pixel.
    #[cfg_attr(
        not(test),
        expect(dead_code, reason = "a slow twin, the reference of a unit test")
    )]
    pub fn subtract_slow(&self, img: &Image) -> Image {
        let mut out = img.clone();
        for iy in 0..img.height {
            for ix in 0..img.width {
                let v = out.at_mut(ix, iy);
                *v = (f64::from(*v) - self.level_at(ix as f64, iy as f64)) as f32;
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{add_sky_and_noise, covariance, draw_gaussian_sampled};
    use stepsim_contract::seed::{SeedKey, Stream};

    #[test]
    fn recovers_sky_and_noise_under_sources() {
        // Sky 1000 e⁻, read noise 10 e⁻: σ = sqrt(1100) = 33.17 e⁻. With 40
        // bright sources, the level is within 0.05 σ and σ within 2 %.
        let mut img = Image::zeros(256, 256);
        for k in 0..40 {
            let (x, y) = (10.0 + (k % 8) as f64 * 30.0, 15.0 + (k / 8) as f64 * 45.0);
            draw_gaussian_sampled(&mut img, x, y, 5e4, &covariance(2.0, [0.1, 0.0]));
        }
        add_sky_and_noise(&mut img, 1000.0, 10.0, SeedKey::base(1, 0, Stream::Test));
        let bg = Background::estimate(&img, 64, 3.0);
        let sigma = 1100f64.sqrt();
        assert!((bg.rms / sigma - 1.0).abs() < 0.02, "rms {}", bg.rms);
        for &(x, y) in &[(10.0, 10.0), (128.0, 128.0), (250.0, 30.0)] {
            let l = bg.level_at(x, y);
            assert!((l - 1000.0).abs() < 0.05 * sigma, "level {l} at {x},{y}");
        }
    }

    #[test]
    fn a_sky_gradient_is_interpolated() {
        // A plane sky 500 + 0.5 x + 0.25 y: mesh levels are the plane at the
        // mesh centres (the 3 × 3 median of a plane is its centre value away
        // from the border), so bilinear interpolation is exact between
        // interior centres; 0.5 e⁻ allows for the median of an even-sized
        // mesh (the upper middle value, ≤ one 0.25–0.5 e⁻ step off).
        let mut img = Image::zeros(256, 192);
        for iy in 0..192 {
            for ix in 0..256 {
                *img.at_mut(ix, iy) = (500.0 + 0.5 * ix as f64 + 0.25 * iy as f64) as f32;
            }
        }
        let bg = Background::estimate(&img, 32, 3.0);
        for &(x, y) in &[(60.0, 60.0), (100.3, 77.7), (200.0, 140.0)] {
            let truth = 500.0 + 0.5 * x + 0.25 * y;
            assert!(
                (bg.level_at(x, y) - truth).abs() < 0.5,
                "{x},{y}: {}",
                bg.level_at(x, y)
            );
        }
    }

    #[test]
    fn subtract_matches_its_twin_bit_for_bit() {
        // A noisy sky with a gradient and sources, meshes that do not divide
        // the image (partial meshes at the right and bottom edges).
        let (w, h) = (203, 157);
        let mut img = Image::zeros(w, h);
        for iy in 0..h {
            for ix in 0..w {
                *img.at_mut(ix, iy) = (300.0 + 0.7 * ix as f64 - 0.4 * iy as f64) as f32;
            }
        }
        for k in 0..12 {
            let (x, y) = (12.0 + (k % 4) as f64 * 50.0, 20.0 + (k / 4) as f64 * 50.0);
            draw_gaussian_sampled(&mut img, x, y, 2e4, &covariance(1.5, [0.2, -0.1]));
        }
        add_sky_and_noise(&mut img, 100.0, 5.0, SeedKey::base(2, 0, Stream::Test));
        let bg = Background::estimate(&img, 48, 3.0);
        assert!(bg.nx == 5 && bg.ny == 4);
        let (fast, slow) = (bg.subtract(&img), bg.subtract_slow(&img));
        let owned = bg.subtract_owned(img.clone());
        assert!(
            fast.data
                .iter()
                .zip(&slow.data)
                .zip(&owned.data)
                .all(|((a, b), c)| a.to_bits() == b.to_bits() && c.to_bits() == b.to_bits())
        );
        // And it did subtract: the corner pixel lost about its level.
        let l = bg.level_at(0.0, 0.0);
        assert!((f64::from(img.data[0] - fast.data[0]) - l).abs() < 1e-3 * l);
    }
}
