//! The chirp-z transform: a discrete Fourier sum at any frequency spacing,
//! by three FFTs instead of one product per sample and frequency.
//!
//! For samples x_0 … x_{m−1} it gives X_q = Σ_i x_i e^{−2πi α q i} for the
//! integers q = q0 … q0 + k − 1 and any real α. With 2 q i = q² + i² −
//! (q − i)² the sum becomes a convolution (Bluestein's identity):
//! X_q = e^{−πiαq²} Σ_i (x_i e^{−πiαi²}) e^{πiα(q − i)²},
//! which one forward and one inverse FFT of length L ≥ m + k − 1 compute
//! (the chirp's own FFT is made once per transform). The cost is
//! O(L log L) per vector instead of O(m k); the result agrees with the
//! direct sum to rounding (about 1e-14 of Σ |x_i| at the sizes used here;
//! tested against [`direct`]).
//!
//! The FFTs are rustfft's scalar ones (`FftPlannerScalar`), not the
//! planner that picks AVX or SSE code by CPU: those give other roundings,
//! and a PSF's transfer, hence the images, must be the same bytes on any
//! x86-64 machine (docs/config.md, "Vector instructions"). At the sizes
//! used here (a 4096² image's tile grid) the whole transfer costs about
//! 0.05 s per PSF.

use num_complex::Complex64;
use rustfft::{Fft, FftPlannerScalar};
use std::f64::consts::PI;
use std::sync::Arc;
use stepsim_numerics::fft_size::fft_friendly;

/// One chirp-z transform: the sample count, the frequencies and α fixed.
pub(crate) struct Czt {
    m: usize,
    k: usize,
    /// e^{−πiαi²}, i < m.
    pre: Vec<Complex64>,
    /// e^{−πiαq²} / L, q = q0 … q0 + k − 1 (the inverse FFT's 1/L folded in).
    post: Vec<Complex64>,
    /// FFT of the chirp e^{πiα(q0 + t)²}, t = −(m − 1) … k − 1, wrapped.
    chirp_hat: Vec<Complex64>,
    forward: Arc<dyn Fft<f64>>,
    inverse: Arc<dyn Fft<f64>>,
}

/// e^{iπ a t²} with a t² reduced modulo 2 first (t an integer, so t² is
/// exact in f64 for |t| < 2^26).
fn chirp(a: f64, t: i64) -> Complex64 {
    let t2 = (t * t) as f64;
    Complex64::from_polar(1.0, PI * (a * t2).rem_euclid(2.0))
}

impl Czt {
    /// The transform of `m` samples to the `k` frequencies q0 … q0 + k − 1
    /// (in units of α cycles per sample).
    pub(crate) fn new(m: usize, alpha: f64, q0: i64, k: usize) -> Self {
        assert!(m > 0 && k > 0, "empty chirp-z transform");
        let l = fft_friendly(m + k - 1);
        let mut planner = FftPlannerScalar::new();
        let forward = planner.plan_fft_forward(l);
        let inverse = planner.plan_fft_inverse(l);
        let pre = (0..m as i64).map(|i| chirp(-alpha, i)).collect();
        let post = (0..k as i64)
            .map(|c| chirp(-alpha, q0 + c) / l as f64)
            .collect();
        let mut chirp_hat = vec![Complex64::new(0.0, 0.0); l];
        for t in -(m as i64 - 1)..k as i64 {
            chirp_hat[t.rem_euclid(l as i64) as usize] = chirp(alpha, q0 + t);
        }
        forward.process(&mut chirp_hat);
        Self {
            m,
            k,
            pre,
            post,
            chirp_hat,
            forward,
            inverse,
        }
    }

    /// Length of the work buffer [`Self::apply`] wants.
    pub(crate) fn work_len(&self) -> usize {
        self.chirp_hat.len()
    }

    /// X_q of the `m` samples `x(i)` into `out` (length k); `work` holds
    /// [`Self::work_len`] values (its contents are overwritten).
    pub(crate) fn apply(
        &self,
        x: impl Fn(usize) -> Complex64,
        out: &mut [Complex64],
        work: &mut [Complex64],
    ) {
        assert_eq!(out.len(), self.k, "chirp-z output length");
        assert_eq!(work.len(), self.chirp_hat.len(), "chirp-z work length");
        for (i, w) in work.iter_mut().enumerate() {
            *w = if i < self.m {
                x(i) * self.pre[i]
            } else {
                Complex64::new(0.0, 0.0)
            };
        }
        self.forward.process(work);
        for (w, h) in work.iter_mut().zip(&self.chirp_hat) {
            *w *= h;
        }
        self.inverse.process(work);
        for ((o, w), p) in out.iter_mut().zip(work.iter()).zip(&self.post) {
            *o = w * p;
        }
    }
}

/// [`Czt`]'s slow, obvious twin: the sum itself, term by term.
#[cfg(test)]
pub(crate) fn direct(x: &[Complex64], alpha: f64, q0: i64, k: usize) -> Vec<Complex64> {
    (0..k as i64)
        .map(|c| {
            x.iter()
                .enumerate()
                .map(|(i, &v)| {
                    let turns = (alpha * (q0 + c) as f64 * i as f64).rem_euclid(1.0);
                    v * Complex64::from_polar(1.0, -2.0 * PI * turns)
                })
                .sum()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_the_direct_sum() {
        // Spacings that are and are not simple fractions, frequency ranges
        // that start below, at and above zero, more and fewer frequencies
        // than samples.
        for &(m, alpha, q0, k) in &[
            (1usize, 0.3, 0i64, 1usize),
            (7, 0.25, 0, 4),
            (24, 0.013_717, -11, 23),
            (416, 0.000_181_3, 0, 676),
            (416, 0.000_181_3, -674, 1350),
            (100, 0.37, 5, 9),
        ] {
            let x: Vec<Complex64> = (0..m)
                .map(|i| {
                    let f = i as f64;
                    Complex64::new((0.3 * f).sin() + 1.5, (0.11 * f * f).cos() * 0.2)
                })
                .collect();
            let want = direct(&x, alpha, q0, k);
            let czt = Czt::new(m, alpha, q0, k);
            let mut got = vec![Complex64::new(0.0, 0.0); k];
            let mut work = vec![Complex64::new(0.0, 0.0); czt.work_len()];
            czt.apply(|i| x[i], &mut got, &mut work);
            let scale: f64 = x.iter().map(|v| v.norm()).sum();
            let worst = got
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).norm())
                .fold(0.0, f64::max);
            assert!(
                worst < 1e-13 * scale,
                "m {m}, α {alpha}, q0 {q0}, k {k}: worst {worst:e} of Σ|x| {scale}"
            );
        }
    }
}
