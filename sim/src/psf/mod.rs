//! PSF models (SPEC §3).
//!
//! A PSF is an immutable value implementing [`Psf`]. The renderer works in
//! Fourier space per stamp, so the central operation is
//! [`Psf::transfer`]: the PSF's transfer function sampled on the frequency
//! grid of an `n × n` stamp. Implementations cache it per `(n, pixel scale)`.
//!
//! Units: arcsec on the sky, frequencies in cycles per arcsec.

mod gaussian;

pub use gaussian::GaussianPsf;

use num_complex::Complex32;
use std::sync::Arc;

/// Frequency grid of an `n × n` stamp with pixel scale `pixel_scale_arcsec`,
/// in the half-plane layout of a real 2-D FFT: `n` rows (v index) of
/// `n / 2 + 1` columns (u index), row-major. Column `i` is
/// u = i / (n·p); row `j` is v = j / (n·p) for j ≤ n/2 and (j − n) / (n·p)
/// above. `n` is even.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct StampGrid {
    /// Stamp side in pixels (even).
    pub n: usize,
    /// Pixel scale in micro-arcsec (an integer so that the grid can key a cache).
    pub pixel_scale_uas: u64,
}

impl StampGrid {
    /// A grid for an `n`-pixel stamp of the given pixel scale.
    pub fn new(n: usize, pixel_scale_arcsec: f64) -> Self {
        assert!(n >= 2 && n % 2 == 0, "stamp side must be even, got {n}");
        Self {
            n,
            pixel_scale_uas: (pixel_scale_arcsec * 1e6).round() as u64,
        }
    }
    /// Pixel scale in arcsec.
    pub fn pixel_scale_arcsec(&self) -> f64 {
        self.pixel_scale_uas as f64 * 1e-6
    }
    /// Number of columns of the half plane.
    pub fn n_cols(&self) -> usize {
        self.n / 2 + 1
    }
    /// Frequency spacing in cycles per arcsec.
    pub fn dk(&self) -> f64 {
        1.0 / (self.n as f64 * self.pixel_scale_arcsec())
    }
    /// (u, v) in cycles per arcsec of half-plane cell (`row`, `col`).
    pub fn frequency(&self, row: usize, col: usize) -> (f64, f64) {
        let dk = self.dk();
        let j = if row <= self.n / 2 {
            row as f64
        } else {
            row as f64 - self.n as f64
        };
        (col as f64 * dk, j * dk)
    }
}

/// A point-spread function: optics, atmosphere and anything else except the
/// pixel response, which the renderer applies.
pub trait Psf: Send + Sync + std::fmt::Debug {
    /// Transfer function T(u, v) = ∫ PSF(x) e^{−2πi(ux+vy)} dx, with T(0) = 1,
    /// on the half-plane grid of `grid`. Cached by the implementation.
    fn transfer(&self, grid: StampGrid) -> Arc<Vec<Complex32>>;

    /// Radius (arcsec) of the circle about the centroid that holds `fraction`
    /// of the flux; used to size stamps.
    fn radius_enclosing(&self, fraction: f64) -> f64;

    /// Fraction of the flux beyond radius `r_arcsec` at which the surface
    /// brightness relative to the peak drops below `level` (for the edge
    /// criterion of bright stars): the radius beyond which the PSF is fainter
    /// than `level` × peak everywhere.
    fn radius_below(&self, level: f64) -> f64;
}
