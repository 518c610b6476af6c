//! Square 2-D complex FFTs (row-major, standard FFT order) on top of rustfft.
//!
//! Forward: X[k] = Σ x[j] e^{−2πi jk/n} per axis; inverse without the 1/n
//! factor (callers normalise).

use num_complex::Complex64;
use rustfft::{FftDirection, FftPlanner};

/// In-place 2-D FFT of an `n × n` row-major array.
pub(crate) fn fft2(data: &mut [Complex64], n: usize, direction: FftDirection) {
    assert_eq!(data.len(), n * n, "fft2: data is not n×n");
    let mut planner = FftPlanner::new();
    let fft = planner.plan_fft(n, direction);
    fft.process(data);
    transpose(data, n);
    fft.process(data);
    transpose(data, n);
}

fn transpose(data: &mut [Complex64], n: usize) {
    for r in 0..n {
        for c in (r + 1)..n {
            data.swap(r * n + c, c * n + r);
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
        let n = 6;
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
            assert!((y[k1 * n + k2] - want).norm() < 1e-12);
        }
        assert_eq!(signed(3, 6), -3);
        assert_eq!(signed(2, 6), 2);
        assert_eq!(signed(2, 5), 2);
        assert_eq!(signed(3, 5), -2);
    }
}
