//! Square 2-D complex FFTs (row-major, standard FFT order) on top of rustfft.
//!
//! Forward: X[k] = Σ x[j] e^{−2πi jk/n} per axis; inverse without the 1/n
//! factor (callers normalise).
//!
//! stepsim's own FFTs (`stepsim_numerics::fft`), or rustfft's scalar ones
//! (`FftPlannerScalar`) for a side with a prime factor above 5, not
//! rustfft's planner by CPU: its AVX and
//! SSE code round differently, and the optical PSF (and so every image
//! drawn with it) must have the same bits on every CPU.

use num_complex::Complex64;
use rustfft::{FftDirection, FftPlannerScalar};
use stepsim_numerics::fft_size::is_friendly;

/// In-place 2-D FFT of an `n × n` row-major array: `stepsim_numerics::fft`
/// (eight rows, then eight columns, at a time in vector lanes) where n has
/// no prime factor above 5, else rustfft's scalar FFTs along the rows, a
/// transpose, the rows again and a transpose back.
pub(crate) fn fft2(data: &mut [Complex64], n: usize, direction: FftDirection) {
    assert_eq!(data.len(), n * n, "fft2: data is not n×n");
    if is_friendly(n) {
        stepsim_numerics::fft::fft2(data, n, direction == FftDirection::Inverse);
        return;
    }
    let mut planner = FftPlannerScalar::new();
    let fft = planner.plan_fft(n, direction);
    fft.process(data);
    transpose(data, n);
    fft.process(data);
    transpose(data, n);
}

/// In-place transpose, by 16 × 16 blocks so that the rows touched stay in
/// cache (a 2048² grid is 64 MiB); the same swaps as the plain loop.
fn transpose(data: &mut [Complex64], n: usize) {
    const B: usize = 16;
    for r0 in (0..n).step_by(B) {
        for c0 in (r0..n).step_by(B) {
            for r in r0..(r0 + B).min(n) {
                for c in c0.max(r + 1)..(c0 + B).min(n) {
                    data.swap(r * n + c, c * n + r);
                }
            }
        }
    }
}

/// Signed frequency index of FFT bin `k` of an `n`-point transform.
pub(crate) fn signed(k: usize, n: usize) -> i64 {
    if k < n.div_ceil(2) {
        k as i64
    } else {
        k as i64 - n as i64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_a_direct_dft() {
        for n in [6, 7, 10] {
            matches_a_direct_dft_at(n);
        }
    }

    fn matches_a_direct_dft_at(n: usize) {
        let x: Vec<Complex64> = (0..n * n)
            .map(|i| Complex64::new((i as f64 * 0.37).sin(), (i as f64 * 0.11).cos()))
            .collect();
        let mut y = x.clone();
        fft2(&mut y, n, FftDirection::Forward);
        for (k1, k2) in [(0, 0), (1, 4), (5, 2), (3, 3)] {
            let mut want = Complex64::new(0.0, 0.0);
            for j1 in 0..n {
                for j2 in 0..n {
                    let ph = -2.0 * std::f64::consts::PI * ((j1 * k1 + j2 * k2) as f64) / n as f64;
                    want += x[j1 * n + j2] * Complex64::from_polar(1.0, ph);
                }
            }
            assert!((y[k1 * n + k2] - want).norm() < 1e-12, "n {n}");
        }
        fft2(&mut y, n, FftDirection::Inverse);
        let nn = (n * n) as f64;
        assert!(
            y.iter().zip(&x).all(|(a, b)| (a / nn - b).norm() < 1e-13),
            "n {n}"
        );
        assert_eq!(signed(3, 6), -3);
        // The blocked transpose on a side that is not a multiple of its block.
        let n = 37;
        let mut t: Vec<Complex64> = (0..n * n).map(|i| Complex64::new(i as f64, 0.0)).collect();
        transpose(&mut t, n);
        assert!((0..n * n).all(|i| t[i].re == ((i % n) * n + i / n) as f64));
        assert_eq!(signed(2, 6), 2);
        assert_eq!(signed(2, 5), 2);
        assert_eq!(signed(3, 5), -2);
    }
}
