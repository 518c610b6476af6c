//! The slow, obvious twin of the Fourier renderer: direct real-space
//! integration of galaxy ⊗ round Gaussian PSF over each pixel.
//!
//! Method, for a stamp of `nx × ny` pixels:
//! 1. Cut every pixel into `supersample²` square cells of side h = p / s and
//!    integrate the galaxy's surface brightness over each cell (2 × 2
//!    Gauss–Legendre points; cells within 3 h of the centre, where the
//!    de Vaucouleurs cusp lives, are split into 24 × 24 sub-cells first).
//!    The cell grid extends 6.5 σ beyond the stamp so that light from
//!    outside is convolved in.
//! 2. Convolve the cell fluxes with the Gaussian PSF, separably, each cell
//!    treated as a point mass at its centre and the kernel integrated
//!    exactly over the receiving cell (erf differences). Point masses equal
//!    to the cell fluxes sample I ⊗ box_h, i.e. the profile widened by the
//!    cell's variance h²/12 per axis, so the kernel's variance is
//!    σ² − h²/12: the O(h²) error cancels, leaving O(h⁴) (the measured
//!    error falls from ~1e-3 to ~1e-6 of the peak at 9 cells per pixel).
//! 3. Sum the cells of each pixel.
//!
//! Stars are a point: the pixel integral of the Gaussian is a product of
//! erf differences. With `psf_sigma_arcsec = None` the galaxy is integrated
//! over pixels without a PSF.
//!
//! No FFT, no periodicity, no Fourier transforms of profiles: an
//! independent check of [`super::Renderer`].

use crate::model::profile::{GL8, Galaxy, RowError};
use stepsim_contract::truth::TruthRow;
use stepsim_numerics::stats::normal_cdf;

/// The real-space reference renderer.
#[derive(Debug, Clone, Copy)]
pub struct ReferenceRenderer {
    /// Pixel scale (arcsec).
    pub pixel_scale_arcsec: f64,
    /// σ of the round Gaussian PSF (arcsec), or none.
    pub psf_sigma_arcsec: Option<f64>,
    /// Cells per pixel side (odd keeps a cell centred on each pixel centre).
    pub supersample: usize,
}

const GL2: [(f64, f64); 2] = [
    (-0.577_350_269_189_625_8, 1.0),
    (0.577_350_269_189_625_8, 1.0),
];

impl ReferenceRenderer {
    /// Draws `row` on the `nx × ny` pixels whose first pixel has 0-based
    /// image index (x0, y0); electrons per pixel, row-major.
    pub fn draw(
        &self,
        row: &TruthRow,
        x0: i64,
        y0: i64,
        nx: usize,
        ny: usize,
    ) -> Result<Vec<f64>, RowError> {
        let p = self.pixel_scale_arcsec;
        if row.is_star() {
            crate::model::profile::check_row(row)?;
            let sigma = self.psf_sigma_arcsec.unwrap_or(1e-9 * p);
            let axis = |first: i64, len: usize, c: f64| -> Vec<f64> {
                (0..len)
                    .map(|i| {
                        let centre = (first + 1 + i as i64) as f64; // FITS pixel
                        let lo = (centre - 0.5 - c) * p / sigma;
                        let hi = (centre + 0.5 - c) * p / sigma;
                        normal_cdf(hi) - normal_cdf(lo)
                    })
                    .collect()
            };
            let wx = axis(x0, nx, row.x);
            let wy = axis(y0, ny, row.y);
            return Ok((0..ny)
                .flat_map(|j| {
                    let wyj = wy[j];
                    wx.iter().map(move |&w| w * wyj * row.flux_e)
                })
                .collect());
        }
        let galaxy = Galaxy::from_row(row)?;
        let s = self.supersample.max(1);
        let h = p / s as f64;
        let margin = match self.psf_sigma_arcsec {
            Some(sig) => (6.5 * sig / h).ceil() as usize,
            None => 0,
        };
        let (fx, fy) = (nx * s + 2 * margin, ny * s + 2 * margin);
        // Centre of cell (a, b) in arcsec relative to the galaxy centre.
        let cx0 = ((x0 + 1) as f64 - 0.5 - row.x) * p - margin as f64 * h + 0.5 * h;
        let cy0 = ((y0 + 1) as f64 - 0.5 - row.y) * p - margin as f64 * h + 0.5 * h;
        let mut cells = vec![0.0; fx * fy];
        for b in 0..fy {
            let cy = cy0 + b as f64 * h;
            for a in 0..fx {
                let cx = cx0 + a as f64 * h;
                cells[b * fx + a] = if cx.hypot(cy) < 3.0 * h {
                    cell_integral_fine(&galaxy, cx, cy, h, 24)
                } else {
                    cell_integral(&galaxy, cx, cy, h)
                };
            }
        }
        let conv = match self.psf_sigma_arcsec {
            None => cells,
            Some(sig) => convolve_gaussian(&cells, fx, fy, margin, sig, h),
        };
        // conv has (fx − 2m) × (fy − 2m) = (nx s) × (ny s) cells.
        let (cx_n, _) = (nx * s, ny * s);
        let mut out = vec![0.0; nx * ny];
        for j in 0..ny {
            for i in 0..nx {
                let mut sum = 0.0;
                for bb in 0..s {
                    let r = (j * s + bb) * cx_n + i * s;
                    sum += conv[r..r + s].iter().sum::<f64>();
                }
                out[j * nx + i] = sum;
            }
        }
        Ok(out)
    }
}

fn cell_integral(g: &Galaxy, cx: f64, cy: f64, h: f64) -> f64 {
    let mut s = 0.0;
    for &(xa, wa) in &GL2 {
        for &(ya, wb) in &GL2 {
            s += wa * wb * g.density(cx + 0.5 * h * xa, cy + 0.5 * h * ya);
        }
    }
    s * 0.25 * h * h
}

fn cell_integral_fine(g: &Galaxy, cx: f64, cy: f64, h: f64, k: usize) -> f64 {
    let hh = h / k as f64;
    let mut s = 0.0;
    for b in 0..k {
        for a in 0..k {
            let x = cx - 0.5 * h + (a as f64 + 0.5) * hh;
            let y = cy - 0.5 * h + (b as f64 + 0.5) * hh;
            // 8-point rule for the innermost sub-cells around the cusp.
            if x.hypot(y) < 1.5 * hh {
                let mut t = 0.0;
                for &(xa, wa) in &GL8 {
                    for &(ya, wb) in &GL8 {
                        t += wa * wb * g.density(x + 0.5 * hh * xa, y + 0.5 * hh * ya);
                    }
                }
                s += t * 0.25 * hh * hh;
            } else {
                s += cell_integral(g, x, y, hh);
            }
        }
    }
    s
}

/// Separable convolution of point masses at cell centres with a Gaussian
/// of variance σ² − h²/12 (see the module docs), integrated over each receiving cell; returns the
/// inner (fx − 2m) × (fy − 2m) cells.
fn convolve_gaussian(
    cells: &[f64],
    fx: usize,
    fy: usize,
    m: usize,
    sigma: f64,
    h: f64,
) -> Vec<f64> {
    let sig = (sigma * sigma - h * h / 12.0).max(1e-30).sqrt();
    let w: Vec<f64> = (0..=2 * m)
        .map(|k| {
            let d = (k as f64 - m as f64) * h;
            normal_cdf((d + 0.5 * h) / sig) - normal_cdf((d - 0.5 * h) / sig)
        })
        .collect();
    let ox = fx - 2 * m;
    let oy = fy - 2 * m;
    // Along x: every row, inner columns.
    let mut tmp = vec![0.0; ox * fy];
    for b in 0..fy {
        let src = &cells[b * fx..(b + 1) * fx];
        for a in 0..ox {
            tmp[b * ox + a] = src[a..a + 2 * m + 1]
                .iter()
                .zip(&w)
                .map(|(c, k)| c * k)
                .sum();
        }
    }
    // Along y.
    let mut out = vec![0.0; ox * oy];
    for (k, &wk) in w.iter().enumerate() {
        for b in 0..oy {
            let src = &tmp[(b + k) * ox..(b + k + 1) * ox];
            let dst = &mut out[b * ox..(b + 1) * ox];
            for (d, s) in dst.iter_mut().zip(src) {
                *d += wk * s;
            }
        }
    }
    out
}
