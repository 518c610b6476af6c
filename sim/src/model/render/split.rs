//! The PSF factored for whole images: T = L · (T / L).
//!
//! A physical PSF (optics with spiders plus Kolmogorov seeing) has wings:
//! 99.5 % of its flux needs a 6.2″ radius, against 1.24″ for a Gaussian of
//! the same FWHM. Drawn per object, every stamp must hold those wings, which
//! makes the median galaxy stamp 120 px instead of 36 px. The wings are the
//! same for every object of an image, so they are better applied once.
//!
//! The transfer function is factored exactly, T(k) = L(k) · K(k), with a
//! narrow round Gaussian L(k) = exp(−2π² σ_L² |k|²):
//!
//! 1. each object is drawn on a small stamp as object ⊗ L ⊗ pixel (the
//!    ordinary [`Renderer`] with L as its PSF, stamps sized for L);
//! 2. the stamps are added into a *canvas*: the image plus a margin as wide
//!    as the PSF;
//! 3. the canvas is convolved once with K = T / L by overlap-save FFTs
//!    ([`Convolver`]).
//!
//! The factorisation is exact: on every frequency the product is
//! object × T × pixel, as when each object is drawn with the whole PSF. The
//! two ways differ only in what the grids leave out: a stamp now has to
//! hold object ⊗ L (the folding threshold applies to it), and the kernel is
//! represented on the tile grid within ±`margin` pixels. The PSF's wings
//! reach ±`margin` pixels from every object, far beyond what a per-object
//! stamp could afford (diffraction spikes of every star included).
//! Measured against whole-PSF stamps: ≤ 7.2e-5 of an object's peak
//! (docs/rendering.md).
//!
//! σ_L is the widest Gaussian (up to [`MAX_SIGMA_PX`] pixels) with
//! L ≥ |T| on the tile grids, so |K| ≤ 1: the convolution never amplifies
//! anything, in particular not the small errors of the stamps (their
//! k-space cut and wrapped tails). Both the Nyquist row and column of K are
//! zero (T is ≲ 1e-6 there); the stamps hold their Nyquist cells, where L is
//! still 4.6e-3 (render/stamp.rs).

use super::convolve::Convolver;
use super::{Accuracy, Method, Renderer};
use crate::model::psf::{GaussianPsf, Psf, StampGrid};
use num_complex::Complex32;
use std::collections::HashMap;
use std::f64::consts::PI;
use std::sync::{Arc, Mutex};
use stepsim_numerics::fft_size::fft_friendly;

/// Largest σ of the per-stamp Gaussian L, in pixels. Wider L would smooth
/// the stamps more but make them larger; one pixel adds 0.7″ to a stamp's
/// radius at the default folding threshold.
pub const MAX_SIGMA_PX: f64 = 1.0;

/// The kernel's margin reaches where the PSF is below this fraction of its
/// peak (and holds all but 1e-5 of its flux), within the largest stamp.
pub const MARGIN_LEVEL: f64 = 1e-7;

/// The per-image half of a factored PSF.
#[derive(Debug)]
pub struct Split {
    psf: Arc<dyn Psf>,
    /// L: the Gaussian of the stamps, and the divisor of the kernel.
    l: Arc<GaussianPsf>,
    stamps: Renderer,
    margin: usize,
    pixel_scale_arcsec: f64,
    convolvers: Mutex<HashMap<usize, Arc<Convolver>>>,
}

impl Split {
    /// Factors `psf` for images of pixel scale `pixel_scale_arcsec`.
    pub fn new(
        psf: &Arc<dyn Psf>,
        pixel_scale_arcsec: f64,
        accuracy: Accuracy,
        sky_sigma_e: f64,
    ) -> Split {
        let p = pixel_scale_arcsec;
        let margin = kernel_margin_px(psf.as_ref(), p, accuracy.max_stamp_px);
        // σ_L: the bound on the smallest and the largest tile grid images
        // use, less 5% for the frequencies between grid points when the cap
        // does not bind (a test checks |T / L| ≤ 1 on the tiles of a 4096²
        // and a 64² image).
        let bound = [tile_side(margin, 0), tile_side(margin, usize::MAX)]
            .into_iter()
            .map(|n| {
                let grid = StampGrid::new(n, p);
                prefilter_sigma_px(&psf.transfer(grid), grid)
            })
            .fold(f64::INFINITY, f64::min);
        let sigma_px = (0.95 * bound).min(MAX_SIGMA_PX);
        let fwhm = sigma_px * p * 2.0 * (2.0 * std::f64::consts::LN_2).sqrt();
        let l = Arc::new(GaussianPsf::round(fwhm));
        let stamps = Renderer::new(
            l.clone(),
            p,
            Accuracy {
                method: Method::Stamp,
                ..accuracy
            },
            sky_sigma_e,
        );
        Split {
            psf: psf.clone(),
            l,
            stamps,
            margin,
            pixel_scale_arcsec: p,
            convolvers: Mutex::new(HashMap::new()),
        }
    }

    /// The image-level convolution with T / L for a `width × height` image
    /// (tiles of about 8 margins, smaller for small images; built once per
    /// tile side and cached).
    pub fn convolver(&self, width: usize, height: usize) -> Arc<Convolver> {
        let n = tile_side(self.margin, width.max(height));
        let mut map = self.convolvers.lock().expect("convolver cache");
        map.entry(n)
            .or_insert_with(|| {
                let grid = StampGrid::new(n, self.pixel_scale_arcsec);
                let kernel = divide_by_gaussian(&self.psf.transfer(grid), grid, &self.l);
                Arc::new(Convolver::new(n, self.margin, &kernel))
            })
            .clone()
    }

    /// The renderer of the per-object stamps (object ⊗ L ⊗ pixel).
    pub fn stamps(&self) -> &Renderer {
        &self.stamps
    }

    /// σ of L (arcsec).
    pub fn sigma_l_arcsec(&self) -> f64 {
        self.l.sigma_arcsec()
    }

    /// Canvas margin in pixels.
    pub fn margin_px(&self) -> usize {
        self.margin
    }
}

/// The grids on which a split renderer of `psf` asks for its transfer when
/// it draws images of longest side `image_side`: the smallest and the
/// largest tile (the prefilter's bound, [`Split::new`]) and the image's
/// tile ([`Split::convolver`]); none for the stamp method, whose stamps ask
/// for many small grids instead. What a PSF store keeps for the first
/// image of a process (the largest grid's chirp-z transform was 3 % of a
/// user's first image).
pub fn transfer_grids(
    psf: &dyn Psf,
    pixel_scale_arcsec: f64,
    accuracy: &Accuracy,
    image_side: usize,
) -> Vec<StampGrid> {
    if accuracy.method != Method::Split {
        return Vec::new();
    }
    let margin = kernel_margin_px(psf, pixel_scale_arcsec, accuracy.max_stamp_px);
    let mut sides = vec![
        tile_side(margin, 0),
        tile_side(margin, usize::MAX),
        tile_side(margin, image_side),
    ];
    sides.sort_unstable();
    sides.dedup();
    sides
        .into_iter()
        .map(|n| StampGrid::new(n, pixel_scale_arcsec))
        .collect()
}

/// How far (pixels) the image kernel reaches from every object: the radius
/// beyond which `psf` is below [`MARGIN_LEVEL`] of its peak or that holds all
/// but 1e-5 of its flux, whichever is larger, plus 2 pixels, capped at half
/// of `max_stamp_px` (`render.max_stamp_px`). The PSF files of a run are
/// written to this extent (`io::psf_fits::renderer_side_px`).
pub fn kernel_margin_px(psf: &dyn Psf, pixel_scale_arcsec: f64, max_stamp_px: usize) -> usize {
    let r = psf
        .radius_below(MARGIN_LEVEL)
        .max(psf.radius_enclosing(1.0 - 1e-5));
    let cap = (max_stamp_px / 2).max(4);
    let want = if r.is_finite() {
        (r / pixel_scale_arcsec).ceil().min(1e6) as usize + 2
    } else {
        cap
    };
    want.clamp(4, cap)
}

/// Tile side for `margin` and images of longest side `image_side`: about 8
/// margins (measured fastest on a 4096² image: 0.14 s against 0.18 s at 4
/// and 0.41 s at 3 margins), but no larger than the canvas needs.
fn tile_side(margin: usize, image_side: usize) -> usize {
    let want = (8 * margin).max(256);
    let canvas = image_side.saturating_add(2 * margin);
    fft_friendly(want.min(canvas).max(2 * margin + 64))
}

/// The largest σ (pixels) with exp(−2π² σ² |k|²) ≥ |T(k)| on every cell of
/// `grid` except the Nyquist row and column (0 if |T| ≥ 1 somewhere).
pub fn prefilter_sigma_px(t: &[Complex32], grid: StampGrid) -> f64 {
    // A cell lowers the bound only if −ln a / (2π² k²) < best, that is if
    // a > exp(−best 2π² k²) = e_u · e_v (k² = ku² + kv²). Cells below
    // that (all but the few near the band's edge, once `best` is small)
    // are passed over without their logarithm; the factors are those of a
    // gate g ≥ best, updated when best has fallen well below it, and the
    // test keeps a relative margin of 1e-9 (far above the rounding of the
    // factors' product), so every cell that could give the minimum is
    // evaluated exactly as in [`prefilter_sigma_px_slow`]: the same bits.
    let (n, nc) = (grid.n, grid.n_cols());
    let c = 2.0 * PI * PI;
    let ku = |col: usize| col as f64 / n as f64;
    let kv = |row: usize| if row <= n / 2 { row } else { n - row } as f64 / n as f64;
    let factors = |g: f64| -> Vec<f64> {
        (0..nc)
            .map(|col| (-g * c * ku(col) * ku(col)).exp())
            .collect()
    };
    let mut best = f64::INFINITY;
    let mut gate = f64::INFINITY;
    let mut eu = factors(gate);
    for row in 0..n {
        if row == n / 2 {
            continue;
        }
        let ev = (-gate * c * kv(row) * kv(row)).exp() * (1.0 - 1e-9);
        for col in 0..nc - 1 {
            if row == 0 && col == 0 {
                continue;
            }
            let a = f64::from(t[row * nc + col].norm());
            if a <= 0.0 || a < eu[col] * ev {
                continue;
            }
            let k2 = ku(col) * ku(col) + kv(row) * kv(row);
            let bound = (-a.ln()).max(0.0) / (2.0 * PI * PI * k2);
            best = best.min(bound);
        }
        if best < 0.9 * gate {
            gate = best;
            eu = factors(gate);
        }
    }
    best.sqrt()
}

/// [`prefilter_sigma_px`]'s slow, obvious twin: every cell's bound, the
/// least of them.
#[cfg_attr(not(test), allow(dead_code))]
fn prefilter_sigma_px_slow(t: &[Complex32], grid: StampGrid) -> f64 {
    let (n, nc) = (grid.n, grid.n_cols());
    let mut best = f64::INFINITY;
    for row in 0..n {
        if row == n / 2 {
            continue;
        }
        for col in 0..nc - 1 {
            if row == 0 && col == 0 {
                continue;
            }
            let a = f64::from(t[row * nc + col].norm());
            if a <= 0.0 {
                continue;
            }
            // k in cycles per pixel.
            let ku = col as f64 / n as f64;
            let kv = if row <= n / 2 { row } else { n - row } as f64 / n as f64;
            let k2 = ku * ku + kv * kv;
            let bound = (-a.ln()).max(0.0) / (2.0 * PI * PI * k2);
            best = best.min(bound);
        }
    }
    best.sqrt()
}

/// T / L on `grid`, zero on the Nyquist row and column; L is the very
/// Gaussian the stamps are drawn with (evaluated in f64).
fn divide_by_gaussian(t: &[Complex32], grid: StampGrid, l: &GaussianPsf) -> Vec<Complex32> {
    let (n, nc) = (grid.n, grid.n_cols());
    let mut out = vec![Complex32::new(0.0, 0.0); t.len()];
    for row in 0..n {
        if row == n / 2 {
            continue;
        }
        for col in 0..nc - 1 {
            let (u, v) = grid.frequency(row, col);
            let inv_l = 1.0 / l.transfer_at(u, v);
            let k = t[row * nc + col];
            out[row * nc + col] = Complex32::new(
                (f64::from(k.re) * inv_l) as f32,
                (f64::from(k.im) * inv_l) as f32,
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::psf::{PsfAccuracy, PsfModel, PsfSpec, Telescope};
    use rand::{RngExt, SeedableRng};
    use stepsim_contract::seed::SimRng;

    #[test]
    fn the_prefilter_bound_passes_over_cells_and_gives_the_same_bits() {
        let coma = PsfSpec::new(
            "coma",
            0.9,
            PsfModel::Optical {
                aberration: crate::model::psf::Aberration::Coma,
                amplitude: None,
                target_chi: Some(0.04),
                angle_deg: 0.0,
            },
            Telescope::default(),
            0.206,
        );
        let acc = PsfAccuracy {
            pupil_grid: 512,
            calibration_grid: 512,
            ..PsfAccuracy::default()
        };
        let optical = crate::model::psf::build_with(&coma, &acc).unwrap();
        let gaussian = Arc::new(GaussianPsf::round(0.9));
        let mut checked = 0;
        for psf in [optical.as_ref(), gaussian.as_ref() as &dyn Psf] {
            for n in [64, 256, 400, 1350] {
                let grid = StampGrid::new(n, 0.206);
                let t = psf.transfer(grid);
                let (fast, slow) = (
                    prefilter_sigma_px(&t, grid),
                    prefilter_sigma_px_slow(&t, grid),
                );
                assert_eq!(fast.to_bits(), slow.to_bits(), "n {n}: {fast} vs {slow}");
                assert!(fast > 0.0 && fast.is_finite(), "{fast}");
                checked += 1;
            }
        }
        // Noise-like transfers (a bound set anywhere, often), and one that
        // reaches 1 (bound 0).
        let grid = StampGrid::new(96, 0.206);
        let mut rng = SimRng::seed_from_u64(12345);
        for round in 0..20 {
            let t: Vec<Complex32> = (0..grid.n * grid.n_cols())
                .map(|_| {
                    let u: f64 = rng.random();
                    Complex32::new((u.powi(round % 5 + 1) * 0.9) as f32, 0.0)
                })
                .collect();
            let (fast, slow) = (
                prefilter_sigma_px(&t, grid),
                prefilter_sigma_px_slow(&t, grid),
            );
            assert_eq!(fast.to_bits(), slow.to_bits(), "round {round}");
            checked += 1;
        }
        let mut one = vec![Complex32::new(0.01, 0.0); grid.n * grid.n_cols()];
        one[5 * grid.n_cols() + 7] = Complex32::new(1.0, 0.0);
        assert_eq!(prefilter_sigma_px(&one, grid), 0.0);
        assert_eq!(prefilter_sigma_px_slow(&one, grid), 0.0);
        assert_eq!(checked, 28);
    }
}
