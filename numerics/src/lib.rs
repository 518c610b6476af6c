//! # stepsim-numerics
//!
//! The small numerical tools every stepsim crate shares, one copy each and
//! each with a slow, obvious twin that a test compares it with:
//!
//! | module | tool | slow twin |
//! | --- | --- | --- |
//! | [`stats`] | median, erfc, normal CDF and quantile, Kolmogorov–Smirnov test | counting median, Maclaurin erfc, integrated density, O(n²) KS |
//! | [`student_t`] | Student's t density, CDF (Abramowitz & Stegun 26.7.3–4 series) and quantile (bracketed Newton) | bisection on the numerically integrated density |
//! | [`quad`] | composite Simpson's rule | Richardson's combination of two trapezoid sums |
//! | [`roots`] | bisection of a monotone predicate | a scan of a fine grid |
//! | [`robust`] | MAD-σ (1.4826 × median absolute deviation) | the counting median |
//! | [`linalg`] | symmetric positive-definite solve and inverse (Cholesky) | Cramer's rule with cofactor determinants |
//! | [`fit`] | linear least squares with κσ clipping (one rule) | the same rule written plainly with the slow twins |
//! | [`fft`] | FFTs of eight sequences at once, complex and real, the same bits on every CPU | the direct sum in f64 |
//! | [`fft_size`] | FFT lengths with no prime factor above 5 | trial division |
//! | [`simd`] | whether the CPU runs the AVX2 build of a hot loop | (each loop's own twin) |
//!
//! The crate depends on no other stepsim crate (only `libm`), so that the
//! simulator, the scorer and the reference pipeline can all use it without
//! linking one another.
#![deny(missing_docs)]

pub mod fft;
pub mod fft_size;
pub mod fit;
pub mod linalg;
pub mod quad;
pub mod robust;
pub mod roots;
pub mod simd;
pub mod stats;
pub mod student_t;

/// A generator with a fixed seed for the crate's own tests.
#[cfg(test)]
pub(crate) fn test_rng(seed: u64) -> rand_xoshiro::Xoshiro256PlusPlus {
    use rand::SeedableRng;
    rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed)
}
