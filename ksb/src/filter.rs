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
    // Short lines only: every output renormalised.
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

/// One output of the line convolution near an end, renormalised over the
/// samples that exist.
fn edge_value(src: &[f32], i: usize, k: &[f64]) -> f32 {
    let r = (k.len() / 2) as i64;
    let (mut s, mut wsum) = (0.0, 0.0);
    for (j, kv) in k.iter().enumerate() {
        let p = i as i64 + j as i64 - r;
        if p >= 0 && p < src.len() as i64 {
            s += kv * f64::from(src[p as usize]);
            wsum += kv;
        }
    }
    (s / wsum) as f32
}

/// Smooths `img` with a Gaussian of `sigma` pixels (fast, separable): rows
/// pass with an unchecked interior loop, then the column pass as weighted
/// sums of whole rows (cache friendly). Parallel over rows; the result does
/// not depend on the thread count.
pub fn smooth(img: &Image, sigma: f64) -> Image {
    let k = kernel_1d(sigma);
    let kf: Vec<f32> = k.iter().map(|&v| v as f32).collect();
    let r = k.len() / 2;
    let (w, h) = (img.width, img.height);
    let mut rows = Image::zeros(w, h);
    rows.data
        .par_chunks_mut(w)
        .zip(img.data.par_chunks(w))
        .for_each(|(dst, src)| {
            if w <= 2 * r {
                convolve_line(src, dst, 1, w, &k);
                return;
            }
            for i in (0..r).chain(w - r..w) {
                dst[i] = edge_value(src, i, &k);
            }
            for i in r..w - r {
                let win = &src[i - r..=i + r];
                let mut s = 0.0f32;
                for (a, b) in win.iter().zip(&kf) {
                    s += a * b;
                }
                dst[i] = s;
            }
        });
    let mut out = Image::zeros(w, h);
    out.data.par_chunks_mut(w).enumerate().for_each(|(y, dst)| {
        let mut wsum = 0.0f64;
        let mut acc = vec![0.0f32; w];
        for (j, &kj) in k.iter().enumerate() {
            let py = y as i64 + j as i64 - r as i64;
            if py < 0 || py >= h as i64 {
                continue;
            }
            wsum += kj;
            let kj = kj as f32;
            let src = &rows.data[py as usize * w..(py as usize + 1) * w];
            for (a, s) in acc.iter_mut().zip(src) {
                *a += kj * s;
            }
        }
        let norm = (1.0 / wsum) as f32;
        for (d, a) in dst.iter_mut().zip(&acc) {
            *d = a * norm;
        }
    });
    out
}

/// Reference twin of [`smooth`]: the direct 2-D convolution with the
/// product kernel, renormalised over existing pixels separately per axis
/// exactly as the separable version does.
#[cfg_attr(
    not(test),
    expect(dead_code, reason = "a slow twin, the reference of a unit test")
)]
pub fn smooth_slow(img: &Image, sigma: f64) -> Image {
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
    use stepsim_contract::seed::{SeedKey, Stream};

    #[test]
    fn separable_smoothing_equals_direct_convolution() {
        let mut img = Image::zeros(150, 70);
        let mut rng = SeedKey::base(2, 0, Stream::Test).rng();
        for v in &mut img.data {
            *v = rng.random_range(-1.0f32..1.0);
        }
        let a = smooth(&img, 1.5);
        let b = smooth_slow(&img, 1.5);
        let worst = a
            .data
            .iter()
            .zip(&b.data)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-6, "{worst}");
        // Lines shorter than the kernel: every output renormalised.
        let small = Image::from_vec(9, 5, (0..45).map(|v| v as f32).collect()).unwrap();
        let (a, b) = (smooth(&small, 1.5), smooth_slow(&small, 1.5));
        for (x, y) in a.data.iter().zip(&b.data) {
            assert!((x - y).abs() < 1e-5, "{x} vs {y}");
        }
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
