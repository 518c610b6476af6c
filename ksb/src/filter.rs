//! Gaussian smoothing for detection. The kernel is a normalised Gaussian of
//! σ pixels truncated at 4σ, applied separably (rows then columns). At the
//! image border the kernel is renormalised over the pixels that exist.

use crate::image::Image;
use rayon::prelude::*;

/// The normalised 1-D kernel (odd length, centre in the middle).
pub fn kernel_1d(sigma: f64) -> Vec<f64> {
    let r = (4.0 * sigma).ceil().max(1.0) as i64;
    let k: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f64 = k.iter().sum();
    k.into_iter().map(|v| v / s).collect()
}

/// Noise σ of the smoothed image of white noise of σ = 1 away from the
/// border: sqrt(Σ k₂ᴅ²) = Σ k₁ᴅ².
pub fn noise_factor(sigma: f64) -> f64 {
    kernel_1d(sigma).iter().map(|v| v * v).sum()
}

fn convolve_line(src: &[f32], dst: &mut [f32], stride_src: usize, n: usize, k: &[f64]) {
    let r = (k.len() / 2) as i64;
    for i in 0..n as i64 {
        let (mut s, mut wsum) = (0.0, 0.0);
        for (j, kv) in k.iter().enumerate() {
            let p = i + j as i64 - r;
            if p >= 0 && p < n as i64 {
                s += kv * f64::from(src[p as usize * stride_src]);
                wsum += kv;
            }
        }
        dst[i as usize] = (s / wsum) as f32;
    }
}

/// Smooths `img` with a Gaussian of `sigma` pixels (fast, separable).
pub fn smooth(img: &Image, sigma: f64) -> Image {
    let k = kernel_1d(sigma);
    let (w, h) = (img.width, img.height);
    let mut rows = Image::zeros(w, h);
    rows.data
        .par_chunks_mut(w)
        .zip(img.data.par_chunks(w))
        .for_each(|(dst, src)| convolve_line(src, dst, 1, w, &k));
    // Columns: transpose in blocks of 64 columns for locality.
    let mut out = Image::zeros(w, h);
    let block = 64;
    let cols: Vec<Vec<f32>> = (0..w.div_ceil(block))
        .into_par_iter()
        .map(|b| {
            let (c0, c1) = (b * block, ((b + 1) * block).min(w));
            let mut res = vec![0.0f32; (c1 - c0) * h];
            let mut col = vec![0.0f32; h];
            let mut tmp = vec![0.0f32; h];
            for c in c0..c1 {
                for (iy, v) in col.iter_mut().enumerate() {
                    *v = rows.data[iy * w + c];
                }
                convolve_line(&col, &mut tmp, 1, h, &k);
                res[(c - c0) * h..(c - c0 + 1) * h].copy_from_slice(&tmp);
            }
            res
        })
        .collect();
    for (b, res) in cols.iter().enumerate() {
        let c0 = b * block;
        let nc = res.len() / h;
        for dc in 0..nc {
            for iy in 0..h {
                out.data[iy * w + c0 + dc] = res[dc * h + iy];
            }
        }
    }
    out
}

/// Reference twin of [`smooth`]: the direct 2-D convolution with the
/// product kernel, renormalised over existing pixels separately per axis
/// exactly as the separable version does.
pub fn smooth_reference(img: &Image, sigma: f64) -> Image {
    let k = kernel_1d(sigma);
    let r = (k.len() / 2) as i64;
    let (w, h) = (img.width as i64, img.height as i64);
    let mut out = Image::zeros(img.width, img.height);
    for y in 0..h {
        for x in 0..w {
            let (mut s, mut wx, mut wy) = (0.0, 0.0, 0.0);
            for (j, ky) in k.iter().enumerate() {
                let py = y + j as i64 - r;
                if py < 0 || py >= h {
                    continue;
                }
                wy += ky;
                for (i, kx) in k.iter().enumerate() {
                    let px = x + i as i64 - r;
                    if px < 0 || px >= w {
                        continue;
                    }
                    s += ky * kx * f64::from(img.at(px as usize, py as usize));
                }
            }
            for (i, kx) in k.iter().enumerate() {
                let px = x + i as i64 - r;
                if px >= 0 && px < w {
                    wx += kx;
                }
            }
            *out.at_mut(x as usize, y as usize) = (s / (wx * wy)) as f32;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;
    use stepsim_sim::seed::{SeedKey, Stream};

    #[test]
    fn separable_smoothing_equals_direct_convolution() {
        let mut img = Image::zeros(150, 70);
        let mut rng = SeedKey::base(2, 0, Stream::Test).rng();
        for v in &mut img.data {
            *v = rng.random_range(-1.0f32..1.0);
        }
        let a = smooth(&img, 1.5);
        let b = smooth_reference(&img, 1.5);
        let worst = a
            .data
            .iter()
            .zip(&b.data)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-6, "{worst}");
    }

    #[test]
    fn noise_factor_is_the_smoothed_white_noise_sigma() {
        let mut img = Image::zeros(300, 300);
        let mut rng = SeedKey::base(4, 0, Stream::Test).rng();
        for v in &mut img.data {
            *v = rng.sample::<f64, _>(rand_distr::StandardNormal) as f32;
        }
        let s = smooth(&img, 1.5);
        let inner: Vec<f64> = (20..280)
            .flat_map(|y| (20..280).map(move |x| (x, y)))
            .map(|(x, y)| f64::from(s.at(x, y)))
            .collect();
        let sd = (inner.iter().map(|v| v * v).sum::<f64>() / inner.len() as f64).sqrt();
        // 67 600 correlated samples (~1 independent per 28 px²): ±2 %.
        assert!(
            (sd / noise_factor(1.5) - 1.0).abs() < 0.03,
            "{sd} vs {}",
            noise_factor(1.5)
        );
    }
}
