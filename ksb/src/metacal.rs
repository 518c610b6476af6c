//! Metacalibration (Huff & Mandelbaum 2017; Sheldon & Huff 2017) on the
//! pipeline's detections: `stepsim measure --method metacal`.
//!
//! For each galaxy, with Î its stamp's Fourier transform (about its
//! windowed centroid c), P̂ the PSF's (a stack of the image's PSF stars,
//! pixel included) and Γ a round Gaussian slightly wider than the PSF, the
//! version sheared by g is
//!
//! Ĵ_g(k) = Î(M k) / P̂(M k) · Γ(k),  M = A⁻¹ = (1 − |g|²)^(−½) [[1 + g₁, g₂], [g₂, 1 − g₁]],
//!
//! the Fourier transform of (galaxy sheared as SPEC §1: I′(x) = I(A x))
//! convolved with Γ. Î(M k) and P̂(M k) are evaluated off the grid by their
//! Taylor series to second order in δk = (M − 1) k, whose terms are the
//! exact transforms of the stamp weighted by (x − c) and (x − c)²; with
//! |g| = 0.01 the third-order term is below 2e-4 of Î wherever Γ is above
//! 1e-3. Five versions are made (no shear, ±0.01 in g₁ and in g₂), each
//! measured the same way: windowed centroid and size ([`crate::centroid`],
//! a round adaptive Gaussian weight) and the KSB weighted ellipticity
//! e = q / T ([`crate::moments`]), and put to the selection's tests that
//! depend on the shear (a resolved neighbour, [`neighbour_peak`]; the
//! centroid's shift from the detection, [`VersionTests`]), so that the
//! selection response below sees them.
//!
//! The response of a dataset is R = R_γ + R_S, both 2 × 2 means over its
//! galaxies: R_γ,ij = ⟨(e_i(+g_j) − e_i(−g_j)) / 0.02⟩ over the galaxies
//! selected on the unsheared version, and the selection response
//! R_S,ij = (⟨e_i(0)⟩ over those selected on the +g_j version − the same
//! over −g_j) / 0.02. Each selected galaxy's row is R⁻¹ e(0), so that the
//! harness's mean of a dataset's rows is R⁻¹ ⟨e⟩, the estimate of g.
//!
//! Γ's σ is the smallest of 1.2, 1.3, … 3.0 × r_g* for which Γ(k) stays
//! below 1.5 |P̂(k)| on the grid (so that no frequency is amplified more
//! than 1.5× by the deconvolution, also where an aberrated PSF's transfer
//! function has zeros).

use crate::centroid::{WindowSettings, windowed};
use crate::flags;
use crate::image::Image;
use crate::moments::{PixelNoise, ksb_integrals};
use crate::params::KsbParams;
use crate::pipeline::MeasuredObject;
use rand::RngExt;
use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};
use std::f64::consts::PI;
use std::sync::Arc;
use stepsim_contract::seed::{SeedKey, Stream};
use stepsim_numerics::stats::weighted_median;

/// The shear of the sheared versions.
pub const STEP: f64 = 0.01;

/// The five versions: no shear, +g₁, −g₁, +g₂, −g₂.
pub const VERSIONS: [[f64; 2]; 5] = [
    [0.0, 0.0],
    [STEP, 0.0],
    [-STEP, 0.0],
    [0.0, STEP],
    [0.0, -STEP],
];

/// Side of the PSF stack (metacalibration's stamps, KSB+'s P^γ
/// calibration).
pub const PSF_SIDE: usize = 32;

/// Side of metadetection's PSF stack ([`stack_psf_wide`]).
pub const WIDE_PSF_SIDE: usize = 64;

/// A star whose stamp has another detection's disc within this many
/// pixels of its centre is left out of [`stack_psf_wide`]: its flux, the
/// sum of its pixels outside the discs, would miss part of its core.
pub const WIDE_STACK_CORE_PX: f64 = 8.0;

/// Stamp sides used for galaxies (the smallest that holds 8 r_g of the
/// reconvolved galaxy).
pub const STAMP_SIDES: [usize; 3] = [32, 48, 64];

/// One galaxy's five measurements.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct McMeasure {
    /// Weighted ellipticity e = q / T of each version.
    pub e: [[f64; 2]; 5],
    /// Windowed size r_g of each version (pixels).
    pub rg: [f64; 5],
    /// S/N of each version, the one its cut compares with `min_sn`: its
    /// weighted flux over σ √(Σ W²), σ the image's background noise
    /// (KSB's ν of the version with the image's noise; infinite without
    /// noise). A function of the version alone, so that R_S sees how the
    /// cut responds to the shear ([`measure_object`]).
    pub sn: [f64; 5],
    /// The version's centroid converged and its moments are defined.
    pub ok: [bool; 5],
    /// The version shows a second peak near the galaxy
    /// ([`neighbour_peak`]).
    pub blended: [bool; 5],
}

/// Transforms of one stamp: F and its first and second k-derivatives as
/// the transforms of the stamp weighted by (x − c) and (x − c)².
struct Transforms {
    side: usize,
    /// Î, Σ(x−c)I, Σ(y−c)I, Σ(x−c)²I, Σ(x−c)(y−c)I, Σ(y−c)²I, each side².
    f: [Vec<Complex64>; 6],
}

/// Signed frequency of FFT index `a` on a grid of `side`, cycles per pixel.
pub(crate) fn freq(a: usize, side: usize) -> f64 {
    let a = a as f64;
    let s = side as f64;
    if a < s / 2.0 { a / s } else { a / s - 1.0 }
}

/// The FFT plans of one side (forward and inverse).
#[derive(Clone)]
pub struct Plans {
    side: usize,
    fwd: Arc<dyn Fft<f64>>,
    inv: Arc<dyn Fft<f64>>,
}

impl Plans {
    /// Plans for a grid of `side`.
    pub fn new(side: usize) -> Self {
        let mut p = FftPlanner::new();
        Self {
            side,
            fwd: p.plan_fft_forward(side),
            inv: p.plan_fft_inverse(side),
        }
    }

    /// In-place 2-D transform of a row-major side × side array.
    pub(crate) fn fft2(&self, buf: &mut [Complex64], inverse: bool) {
        let s = self.side;
        let plan = if inverse { &self.inv } else { &self.fwd };
        for row in buf.chunks_exact_mut(s) {
            plan.process(row);
        }
        let mut col = vec![Complex64::new(0.0, 0.0); s];
        for x in 0..s {
            for y in 0..s {
                col[y] = buf[y * s + x];
            }
            plan.process(&mut col);
            for y in 0..s {
                buf[y * s + x] = col[y];
            }
        }
    }
}

/// The six transforms of `stamp` (row-major side × side, pixel (i, j) at
/// x = i, y = j) about the centre `c`, each multiplied by e^{2πi k·c} so
/// that they are sums of e^{−2πi k·(x − c)}.
fn transforms(stamp: &[f64], c: [f64; 2], plans: &Plans) -> Transforms {
    let s = plans.side;
    let weights: [fn(f64, f64) -> f64; 6] = [
        |_, _| 1.0,
        |dx, _| dx,
        |_, dy| dy,
        |dx, _| dx * dx,
        |dx, dy| dx * dy,
        |_, dy| dy * dy,
    ];
    let f = weights.map(|w| {
        let mut buf: Vec<Complex64> = (0..s * s)
            .map(|p| {
                let (i, j) = (p % s, p / s);
                Complex64::new(stamp[p] * w(i as f64 - c[0], j as f64 - c[1]), 0.0)
            })
            .collect();
        plans.fft2(&mut buf, false);
        about_centre(&mut buf, c, s, 1.0);
        buf
    });
    Transforms { side: s, f }
}

/// Multiplies a side² transform by `scale` e^{2πi k·c}, so that it sums
/// `scale` e^{−2πi k·(x − c)}: the transform about the centre `c`.
fn about_centre(buf: &mut [Complex64], c: [f64; 2], s: usize, scale: f64) {
    for b in 0..s {
        for a in 0..s {
            let ph = 2.0 * PI * (freq(a, s) * c[0] + freq(b, s) * c[1]);
            buf[b * s + a] *= Complex64::from_polar(scale, ph);
        }
    }
}

impl Transforms {
    /// The transform at M k for grid index (a, b), by its Taylor series to
    /// second order in δk = (M − 1) k.
    fn at_sheared(&self, p: usize, dk: [f64; 2]) -> Complex64 {
        let f = &self.f;
        let i = Complex64::new(0.0, 1.0);
        // ∂_j F = −2πi F_j, ∂_ij F = −4π² F_ij.
        let first = (f[1][p] * dk[0] + f[2][p] * dk[1]) * (-2.0 * PI * i);
        let second = (f[3][p] * (dk[0] * dk[0])
            + f[4][p] * (2.0 * dk[0] * dk[1])
            + f[5][p] * (dk[1] * dk[1]))
            * (-4.0 * PI * PI * 0.5);
        f[0][p] + first + second
    }
}

/// M − 1 for the shear g (M = A⁻¹ of SPEC §1).
fn m_minus_one(g: [f64; 2]) -> [[f64; 2]; 2] {
    let n = 1.0 / (1.0 - g[0] * g[0] - g[1] * g[1]).sqrt();
    [
        [n * (1.0 + g[0]) - 1.0, n * g[1]],
        [n * g[1], n * (1.0 - g[0]) - 1.0],
    ]
}

/// The image's PSF, as a normalised stack of its PSF stars.
#[derive(Debug, Clone, PartialEq)]
pub struct PsfStack {
    /// Side of the stack: [`PSF_SIDE`], or [`WIDE_PSF_SIDE`] for
    /// metadetection ([`stack_psf_wide`]).
    pub side: usize,
    /// Pixel values on a side² grid, the centre at index side / 2 in both
    /// axes; they sum to 1.
    pub pix: Vec<f64>,
    /// Number of stars stacked.
    pub n_stars: usize,
}

impl PsfStack {
    /// The stack on a side × side grid (side ≥ the stack's), its centre
    /// at index side / 2 in both axes, zero around it.
    pub fn on_grid(&self, side: usize) -> Vec<f64> {
        let mut grid = vec![0.0; side * side];
        let (h, o) = (self.side / 2, side / 2);
        for (j, row) in self.pix.chunks_exact(self.side).enumerate() {
            let start = (j + o - h) * side + o - h;
            grid[start..start + self.side].copy_from_slice(row);
        }
        grid
    }
}

/// Stacks the stars at `stars` (array coordinates of their windowed
/// centroids) of the background-subtracted image `sub`: each star's stamp
/// is moved to the grid centre by its transform's phase (exact for a
/// band-limited image), divided by its flux, and the stack is the median of
/// the stars pixel by pixel (a neighbour in one star's stamp does not
/// enter), normalised to sum 1. `None` without a star whose PSF_SIDE²
/// stamp lies inside the image.
pub fn stack_psf(sub: &Image, stars: &[(f64, f64)]) -> Option<PsfStack> {
    stack_of_side(sub, stars, PSF_SIDE, None)
}

/// The stack of [`stack_psf`] on [`WIDE_PSF_SIDE`]² pixels, with two
/// changes. Each star's pixels within `others[i][2]` px of another
/// detection (`others[i]` = x, y, radius; one within 1 px of the star is
/// the star itself) are left out of that pixel's median and of the star's
/// flux (a star with such a disc within [`WIDE_STACK_CORE_PX`] of its
/// centre is left out), and a pixel left out of every star's takes the
/// mean of the stack's pixels at its distance from the centre (to 1 px):
/// a 64² stamp holds neighbours that a 32² one did not, and where the
/// stars share a layout of neighbours, as on a grid, the median does not
/// remove them.
/// The median is weighted by each star's flux squared (the inverse of the
/// variance of its normalised pixels where the sky's noise dominates), so
/// that light that is not the star's (what the background's mode leaves
/// of a deep scene's faint galaxies, a level b) enters as b / F of the
/// brightest stars, not of the median one: in the deep lensed scene's
/// images the plain median had 3.5 % of the stack's light in a pedestal
/// beyond 8 px (1–2·10⁻⁵ a pixel against the PSF's 2.6·10⁻⁶ at 26 px)
/// and its centre 4 % low; weighted, the stack's rings are within 6·10⁻⁶
/// of the image's PSF at its centre (peak 0.032; 2.6·10⁻⁵ through a
/// Gaussian PSF, peak 0.038) and 6·10⁻⁷ beyond 8 px (docs/metacal.md,
/// "The PSF stack's pedestal").
/// And the stack is multiplied by [`round_taper`], so that it holds the
/// PSF within a circle, not a square. Metadetection's versions are
/// deconvolved by it. The light a stack leaves out is deconvolved by
/// nothing, and a square leaves out more along its diagonals than along
/// its axes: a PSF model with a direction of its own, of the square's
/// symmetry, which biases e₁ (along the pixels) and e₂ (along their
/// diagonals) unequally (`pipeline` test
/// `metadetection_s_psf_stack_has_no_direction_of_its_own`: m₁ − m₂ =
/// +0.004 … +0.005 through the 32² square, within ±0.0013 through this).
pub fn stack_psf_wide(sub: &Image, stars: &[(f64, f64)], others: &[[f64; 3]]) -> Option<PsfStack> {
    stack_of_side(sub, stars, WIDE_PSF_SIDE, Some(others))
}

/// The weight of a stack of `side` at a distance `r` (px) from its
/// centre: 1 within `side`/2 − 8, 0 beyond `side`/2 − ½, a half cosine
/// between (a hard round cut would keep the square grid's pattern at its
/// edge).
pub fn round_taper(r: f64, side: usize) -> f64 {
    let (r1, r2) = (side as f64 / 2.0 - 8.0, side as f64 / 2.0 - 0.5);
    if r <= r1 {
        1.0
    } else if r >= r2 {
        0.0
    } else {
        0.5 * (1.0 + (PI * (r - r1) / (r2 - r1)).cos())
    }
}

/// [`stack_psf`] on `s`² pixels; with `others`, [`stack_psf_wide`]'s
/// neighbours left out, empty pixels filled and the round taper.
fn stack_of_side(
    sub: &Image,
    stars: &[(f64, f64)],
    s: usize,
    others: Option<&[[f64; 3]]>,
) -> Option<PsfStack> {
    let plans = Plans::new(s);
    let h = (s / 2) as f64;
    let norm = (s * s) as f64;
    let mut centred: Vec<Vec<f64>> = Vec::new();
    // Each star's weight in the pixels' medians: 1 in the plain stack,
    // flux² in the wide one.
    let mut weights: Vec<f64> = Vec::new();
    for &(x, y) in stars {
        let Some((stamp, c)) = cut(sub, x, y, s) else {
            continue;
        };
        let mut t = transforms_one(&stamp, c, &plans);
        let Some(others) = others else {
            let flux = t[0].re;
            if !(flux > 0.0 && flux.is_finite()) {
                continue;
            }
            // Centre at index s/2: multiply by e^{−2πi k·(s/2)} / flux.
            about_centre(&mut t, [-h, -h], s, 1.0 / flux);
            plans.fft2(&mut t, true);
            centred.push(t.iter().map(|v| v.re / norm).collect());
            weights.push(1.0);
            continue;
        };
        about_centre(&mut t, [-h, -h], s, 1.0);
        plans.fft2(&mut t, true);
        let mut star: Vec<f64> = t.iter().map(|v| v.re / norm).collect();
        // The centred pixel (i, j) lies at (x + i − h, y + j − h).
        let mut core_covered = false;
        for o in others {
            let (dx, dy) = (o[0] - x, o[1] - y);
            let reach = h + o[2];
            if dx.abs() > reach || dy.abs() > reach {
                continue;
            }
            let d = dx.hypot(dy);
            if d < 1.0 {
                continue;
            }
            if d - o[2] < WIDE_STACK_CORE_PX {
                core_covered = true;
                break;
            }
            for (p, v) in star.iter_mut().enumerate() {
                let (u, w) = ((p % s) as f64 - h - dx, (p / s) as f64 - h - dy);
                if u * u + w * w < o[2] * o[2] {
                    *v = f64::NAN;
                }
            }
        }
        if core_covered {
            continue;
        }
        let flux: f64 = star.iter().filter(|v| !v.is_nan()).sum();
        if !(flux > 0.0 && flux.is_finite()) {
            continue;
        }
        star.iter_mut().for_each(|v| *v /= flux);
        centred.push(star);
        weights.push(flux * flux);
    }
    if centred.is_empty() {
        return None;
    }
    // Equal weights make the weighted median the plain one, bit for bit
    // (`stepsim_numerics::stats` tests it).
    let mut column = Vec::with_capacity(centred.len());
    let mut pix: Vec<f64> = (0..s * s)
        .map(|p| {
            column.clear();
            column.extend(
                centred
                    .iter()
                    .zip(&weights)
                    .filter(|(star, _)| !star[p].is_nan())
                    .map(|(star, &w)| (star[p], w)),
            );
            weighted_median(&mut column).unwrap_or(f64::NAN)
        })
        .collect();
    if others.is_some() {
        // Each pixel's distance from the centre: at most h √2 < s.
        let radius: Vec<f64> = (0..s * s)
            .map(|p| ((p % s) as f64 - h).hypot((p / s) as f64 - h))
            .collect();
        let mut ring = vec![(0.0, 0usize); s];
        for (v, r) in pix.iter().zip(&radius) {
            if !v.is_nan() {
                let ring = &mut ring[*r as usize];
                ring.0 += v;
                ring.1 += 1;
            }
        }
        for (v, r) in pix.iter_mut().zip(&radius) {
            if v.is_nan() {
                let (sum, n) = ring[*r as usize];
                *v = if n > 0 { sum / n as f64 } else { 0.0 };
            }
            *v *= round_taper(*r, s);
        }
    }
    let total: f64 = pix.iter().sum();
    pix.iter_mut().for_each(|v| *v /= total);
    Some(PsfStack {
        side: s,
        pix,
        n_stars: centred.len(),
    })
}

/// Only the plain transform of a stamp about `c`.
fn transforms_one(stamp: &[f64], c: [f64; 2], plans: &Plans) -> Vec<Complex64> {
    let s = plans.side;
    let mut buf: Vec<Complex64> = stamp.iter().map(|&v| Complex64::new(v, 0.0)).collect();
    plans.fft2(&mut buf, false);
    about_centre(&mut buf, c, s, 1.0);
    buf
}

/// The side × side stamp of `img` around (x, y) and the centre in stamp
/// coordinates; `None` if it does not lie inside the image.
fn cut(img: &Image, x: f64, y: f64, side: usize) -> Option<(Vec<f64>, [f64; 2])> {
    let h = (side / 2) as i64;
    let (ix, iy) = (x.round() as i64, y.round() as i64);
    let (x0, y0) = (ix - h, iy - h);
    if x0 < 0
        || y0 < 0
        || x0 + side as i64 > img.width as i64
        || y0 + side as i64 > img.height as i64
    {
        return None;
    }
    let mut stamp = Vec::with_capacity(side * side);
    for j in 0..side {
        let row = (y0 as usize + j) * img.width + x0 as usize;
        stamp.extend(img.data[row..row + side].iter().map(|&v| f64::from(v)));
    }
    Some((stamp, [x - x0 as f64, y - y0 as f64]))
}

/// The PSF's transforms on one stamp grid, and the reconvolution.
pub struct Deconvolver {
    plans: Plans,
    psf: Transforms,
    /// Γ(k) on the grid.
    gamma: Vec<f64>,
    /// σ of Γ (pixels).
    pub sigma: f64,
    /// Per-pixel variance of a version made of white noise of variance 1:
    /// the mean of |Γ(k) / P̂(k)|² over the grid.
    noise_gain: f64,
}

impl Deconvolver {
    /// Prepares stamps of `side` for the PSF `psf` and a reconvolution of
    /// σ `sigma`.
    pub fn new(psf: &PsfStack, side: usize, sigma: f64) -> Self {
        let plans = Plans::new(side);
        let stamp = psf.on_grid(side);
        let o = side / 2;
        let c = [o as f64, o as f64];
        let psf = transforms(&stamp, c, &plans);
        let gamma = (0..side * side)
            .map(|p| {
                let k2 = freq(p % side, side).powi(2) + freq(p / side, side).powi(2);
                (-2.0 * PI * PI * sigma * sigma * k2).exp()
            })
            .collect::<Vec<f64>>();
        let noise_gain = gamma
            .iter()
            .zip(&psf.f[0])
            .map(|(g, p)| (g / p.norm()).powi(2))
            .sum::<f64>()
            / (side * side) as f64;
        Self {
            plans,
            psf,
            gamma,
            sigma,
            noise_gain,
        }
    }

    /// The largest Γ(k) / |P̂(k)| on the grid.
    pub fn max_amplification(&self) -> f64 {
        self.gamma
            .iter()
            .zip(&self.psf.f[0])
            .map(|(g, p)| g / p.norm())
            .fold(0.0, f64::max)
    }

    /// The version of `stamp` (centre `c`) sheared by `g`, reconvolved:
    /// a side × side image with the galaxy at `c`.
    #[cfg(test)]
    pub fn version(&self, gal: &[f64], c: [f64; 2], g: [f64; 2]) -> Image {
        let t = transforms(gal, c, &self.plans);
        self.version_of(&t, c, g)
    }

    fn version_of(&self, t: &Transforms, c: [f64; 2], g: [f64; 2]) -> Image {
        let s = t.side;
        let d = m_minus_one(g);
        let mut buf = vec![Complex64::new(0.0, 0.0); s * s];
        for b in 0..s {
            for a in 0..s {
                let p = b * s + a;
                let gm = self.gamma[p];
                if gm < 1e-12 {
                    continue;
                }
                let k = [freq(a, s), freq(b, s)];
                let dk = [
                    d[0][0] * k[0] + d[0][1] * k[1],
                    d[1][0] * k[0] + d[1][1] * k[1],
                ];
                let ratio = t.at_sheared(p, dk) / self.psf.at_sheared(p, dk);
                let ph = -2.0 * PI * (k[0] * c[0] + k[1] * c[1]);
                buf[p] = ratio * gm * Complex64::from_polar(1.0, ph);
            }
        }
        self.plans.fft2(&mut buf, true);
        let norm = (s * s) as f64;
        Image {
            width: s,
            height: s,
            data: buf.iter().map(|v| (v.re / norm) as f32).collect(),
        }
    }

    /// The five measured versions of the galaxy at `pos` (array
    /// coordinates of its windowed centroid) of `sub` with windowed size
    /// `rg`, each version's centroid found from the detection's position
    /// `det`, and each put to `tests`; `None` if its stamp leaves the
    /// image.
    pub fn measure(
        &self,
        sub: &Image,
        pos: [f64; 2],
        det: [f64; 2],
        rg: f64,
        win: &WindowSettings,
        tests: &VersionTests,
    ) -> Option<McMeasure> {
        let [x, y] = pos;
        let (stamp, c) = cut(sub, x, y, self.plans.side)?;
        let t = transforms(&stamp, c, &self.plans);
        // Noise correction ("fixnoise", Sheldon & Huff 2017 §4.2): shearing
        // the deconvolved image shears its noise too, and the noise's
        // correlations respond to the shear. A white noise stamp of the
        // image's σ, rotated by 90°, made into each version and rotated
        // back, responds the opposite way; adding it cancels that response
        // (at √2 the noise), seeded by a digest of the stamp's pixels
        // ([`fixnoise`]).
        let side = self.plans.side;
        let noise_sigma = tests.noise_sigma;
        let noise = (noise_sigma > 0.0).then(|| {
            let n = fixnoise(&stamp, noise_sigma);
            let cr = rot90_point(c, side);
            (transforms(&rot90(&n, side), cr, &self.plans), cr)
        });
        let mut m = McMeasure {
            e: [[0.0; 2]; 5],
            rg: [0.0; 5],
            sn: [0.0; 5],
            ok: [false; 5],
            blended: [false; 5],
        };
        // The versions' noise: the image's, filtered, and the correction's.
        let sigma_v = noise_sigma * (2.0 * self.noise_gain).sqrt();
        // Each version's S/N is its weighted flux over the image's σ times
        // √(Σ W²) of its own window: decided on the version, as every cut
        // is. (Until 2026-12-06 it was the image's KSB ν scaled by the
        // version's weighted flux, which left out how the window's size
        // follows the shear: m −0.027 ± 0.010 at STEP1's noise on the
        // isolated-galaxy grid, −0.011 ± 0.009 now; docs/metacal.md.)
        let pixel_noise = (noise_sigma > 0.0).then_some(PixelNoise {
            background_var: noise_sigma * noise_sigma,
            poisson: false,
        });
        let rg0 = (rg * rg + self.sigma * self.sigma).sqrt();
        // The detection's position relative to the stamp's centre c.
        let rel = [det[0] - x, det[1] - y];
        for (v, g) in VERSIONS.iter().enumerate() {
            // Where the version's shear about c takes it: c + M rel.
            let mm = m_minus_one(*g);
            let start = [
                c[0] + rel[0] + mm[0][0] * rel[0] + mm[0][1] * rel[1],
                c[1] + rel[1] + mm[1][0] * rel[0] + mm[1][1] * rel[1],
            ];
            let mut img = self.version_of(&t, c, *g);
            if let Some((tn, cr)) = &noise {
                let nv = self.version_of(tn, *cr, *g);
                let back = rot270(&nv.data, side);
                for (a, b) in img.data.iter_mut().zip(back) {
                    *a += b;
                }
            }
            let Some(w) = windowed(&img, start[0], start[1], rg0, true, win) else {
                continue;
            };
            let ints = ksb_integrals(&img, w.x, w.y, w.rg, win.radius_rg * w.rg, pixel_noise);
            if ints.clipped || !(ints.s0 > 0.0 && ints.trace > 0.0) {
                continue;
            }
            m.e[v] = [ints.q[0] / ints.trace, ints.q[1] / ints.trace];
            m.rg[v] = w.rg;
            m.sn[v] = ints.sn();
            m.ok[v] = w.converged
                && !w.at_bound
                && (w.x - start[0]).hypot(w.y - start[1]) <= tests.max_shift;
            m.blended[v] = neighbour_peak(&img, w.x, w.y, tests.blend_radius, sigma_v);
        }
        Some(m)
    }
}

/// The tests each version of a galaxy is put to besides its
/// measurement ([`Deconvolver::measure`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VersionTests {
    /// σ of the image's background noise (0: none, and no noise
    /// correction).
    pub noise_sigma: f64,
    /// A second peak within this of the centroid makes the version
    /// blended ([`neighbour_peak`]).
    pub blend_radius: f64,
    /// The version's windowed centroid may move at most this far from
    /// the detection's position (the detection's `CENTROID` test).
    pub max_shift: f64,
}

impl VersionTests {
    /// The tests of `params` with the background σ `noise_sigma`.
    pub fn new(params: &KsbParams, noise_sigma: f64) -> Self {
        Self {
            noise_sigma,
            blend_radius: params.close_pair_px,
            max_shift: params.centroid_max_shift_px,
        }
    }
}

/// Significance (in the version's pixel σ) a second peak and the dip
/// between it and the galaxy's peak need to count ([`neighbour_peak`]).
const PEAK_NSIGMA: f64 = 4.0;

/// Whether `img` shows, within `radius` of (x, y), two local maxima (each
/// above its 8 neighbours and above [`PEAK_NSIGMA`] σ) with a dip of at
/// least [`PEAK_NSIGMA`] σ below the lower one on the segment between
/// them: a neighbour the version resolves. Metacalibration decides this
/// on every version, so that which galaxies count as blended responds to
/// the shear as the image would, and the selection response sees it
/// (what detecting on each version, metadetection, does for the whole
/// detection). Without noise (`sigma` 0) any dip counts.
pub fn neighbour_peak(img: &Image, x: f64, y: f64, radius: f64, sigma: f64) -> bool {
    let (w, h) = (img.width as i64, img.height as i64);
    let at = |i: i64, j: i64| f64::from(img.data[(j * w + i) as usize]);
    let floor = PEAK_NSIGMA * sigma;
    let mut peaks: Vec<(f64, f64, f64)> = Vec::new();
    let (i0, i1) = (
        ((x - radius).floor() as i64).max(1),
        ((x + radius).ceil() as i64).min(w - 2),
    );
    let (j0, j1) = (
        ((y - radius).floor() as i64).max(1),
        ((y + radius).ceil() as i64).min(h - 2),
    );
    for j in j0..=j1 {
        for i in i0..=i1 {
            let (dx, dy) = (i as f64 - x, j as f64 - y);
            if dx * dx + dy * dy > radius * radius {
                continue;
            }
            let v = at(i, j);
            if v <= floor {
                continue;
            }
            if crate::segment::is_local_max(img, (j * w + i) as usize) {
                peaks.push((dx * dx + dy * dy, i as f64, j as f64));
            }
        }
    }
    if peaks.len() < 2 {
        return false;
    }
    peaks.sort_by(|a, b| a.0.total_cmp(&b.0));
    let own = peaks[0];
    let sample = |px: f64, py: f64| -> f64 {
        let (fx, fy) = (px.floor(), py.floor());
        let (tx, ty) = (px - fx, py - fy);
        let (ix, iy) = (fx as i64, fy as i64);
        (1.0 - ty) * ((1.0 - tx) * at(ix, iy) + tx * at(ix + 1, iy))
            + ty * ((1.0 - tx) * at(ix, iy + 1) + tx * at(ix + 1, iy + 1))
    };
    peaks[1..].iter().any(|p| {
        let low = at(own.1 as i64, own.2 as i64).min(at(p.1 as i64, p.2 as i64));
        let d = (p.1 - own.1).hypot(p.2 - own.2);
        let steps = (2.0 * d).ceil() as usize;
        let dip = (1..steps)
            .map(|s| {
                let t = s as f64 / steps as f64;
                sample(own.1 + t * (p.1 - own.1), own.2 + t * (p.2 - own.2))
            })
            .fold(f64::INFINITY, f64::min);
        dip < low - floor.max(f64::EPSILON * low.abs())
    })
}

/// The run seed of the noise-correction stamps.
const FIXNOISE_SEED: u64 = 0x6d65_7461_6361_6c00;

/// The noise-correction stamp of `stamp`: white Gaussian noise of σ
/// `sigma`, one value per pixel, seeded by a digest of the stamp's pixels.
/// So it is the same at any thread count and for every version of one
/// galaxy, and independent between any two stamps that differ, also
/// between galaxies cut at the same pixel of different images (a twin, the
/// same base field at another shear, a grid of postage stamps). Seeded by
/// the position alone (before 2026-12-06), every galaxy at one position
/// shared one noise stamp, and on a grid of fixed positions its
/// contribution did not average out: c₂ −3e-4 at ten times STEP1's S/N
/// (docs/metacal.md, "Isolated galaxies"). It cannot be keyed by (run
/// seed, field, dataset) as the simulation's draws are: a participant's
/// images are blind, and the measurement knows neither. The cost: two runs
/// of the same galaxies and noise at ±g no longer share the correction,
/// so their paired difference holds its noise (m's error at STEP1's noise
/// on the grid: 0.0175 against 0.0116).
fn fixnoise(stamp: &[f64], sigma: f64) -> Vec<f64> {
    let digest = stamp.iter().fold(stamp.len() as u64, |h, v| {
        stepsim_contract::seed::splitmix64(h ^ v.to_bits())
    });
    let mut rng = SeedKey::base(FIXNOISE_SEED, 0, Stream::Noise)
        .with_index(digest)
        .rng();
    (0..stamp.len())
        .map(|_| sigma * rng.sample::<f64, _>(rand_distr::StandardNormal))
        .collect()
}

/// `a` (side × side, pixel (i, j) at index j·side + i) rotated by 90°
/// counter-clockwise about the stamp's centre: (i, j) → (side − 1 − j, i).
fn rot90<T: Copy>(a: &[T], side: usize) -> Vec<T> {
    let mut out = a.to_vec();
    for j in 0..side {
        for i in 0..side {
            out[i * side + (side - 1 - j)] = a[j * side + i];
        }
    }
    out
}

/// The inverse of [`rot90`], as f32 pixels to add.
fn rot270(a: &[f32], side: usize) -> Vec<f32> {
    let mut out = a.to_vec();
    for j in 0..side {
        for i in 0..side {
            out[j * side + i] = a[i * side + (side - 1 - j)];
        }
    }
    out
}

/// Where [`rot90`] takes the point `c`.
fn rot90_point(c: [f64; 2], side: usize) -> [f64; 2] {
    [(side - 1) as f64 - c[1], c[0]]
}

/// What metacalibration needs of one image: the deconvolvers of each stamp
/// side for its PSF stack.
pub struct ImageMetacal {
    /// One per [`STAMP_SIDES`].
    decs: Vec<Deconvolver>,
    /// σ of the reconvolution (pixels).
    pub sigma: f64,
}

impl ImageMetacal {
    /// From the PSF stars at `stars` of `sub` and the stellar size
    /// `rg_star`; `None` without a star to stack.
    pub fn new(sub: &Image, stars: &[(f64, f64)], rg_star: f64) -> Option<Self> {
        let psf = stack_psf(sub, stars)?;
        let sigma = reconvolution_sigma(&psf, rg_star);
        Some(Self {
            decs: STAMP_SIDES
                .iter()
                .map(|&side| Deconvolver::new(&psf, side, sigma))
                .collect(),
            sigma,
        })
    }
}

/// Measures the galaxy row `o` (detection flags `det_flags`, detected at
/// `det`, array coordinates) by metacalibration: its five versions and
/// their cuts, its flags for the unsheared version. `e1`, `e2` and the
/// weight stay 0 until [`apply_response`].
pub fn measure_object(
    mut o: MeasuredObject,
    det_flags: u32,
    det: [f64; 2],
    sub: &Image,
    mc: Option<&ImageMetacal>,
    params: &KsbParams,
    noise_sigma: f64,
) -> MeasuredObject {
    o.flags = det_flags;
    o.pgamma = f64::NAN;
    let Some(mc) = mc else {
        o.flags |= flags::NO_PSF;
        return o;
    };
    let Some(side) = stamp_side(o.rg_px, mc.sigma) else {
        o.flags |= flags::LARGE;
        return o;
    };
    let k = STAMP_SIDES
        .iter()
        .position(|&s| s == side)
        .expect("a stamp side");
    let win = params.window_settings();
    let tests = VersionTests::new(params, noise_sigma);
    let Some(m) = mc.decs[k].measure(sub, [o.x - 1.0, o.y - 1.0], det, o.rg_px, &win, &tests)
    else {
        o.flags |= flags::EDGE;
        return o;
    };
    let min_rg = params.metacal_size_min_factor * mc.sigma;
    // Blending and the centroid's shift are decided on each version
    // ([`neighbour_peak`], [`VersionTests::max_shift`]), not by the
    // detection, so that R_S sees how they respond to the shear.
    let others = det_flags & !(flags::BLENDED | flags::CENTROID);
    o.flags = others;
    if m.blended[0] {
        o.flags |= flags::BLENDED;
    }
    let pass = |v: usize| {
        others == 0 && !m.blended[v] && m.ok[v] && m.sn[v] >= params.min_sn && m.rg[v] > min_rg
    };
    let selected = [pass(0), pass(1), pass(2), pass(3), pass(4)];
    if !m.ok[0] {
        o.flags |= flags::CENTROID;
    } else if m.rg[0] <= min_rg {
        o.flags |= flags::SMALL;
    }
    // The row's ν is its unsheared version's S/N, the one its cut compares
    // (0 when the version could not be measured, as for KSB+).
    o.sn = m.sn[0];
    if m.sn[0] < params.min_sn {
        o.flags |= flags::LOW_SN;
    }
    // A guard: every cut above sets its flag, so this only catches a size
    // or S/N that is NaN.
    if o.flags == 0 && !selected[0] {
        o.flags |= flags::MOMENTS;
    }
    o.metacal = Some((m, selected));
    o
}

/// Sets `e1`, `e2` (R⁻¹ e of the unsheared version) and the weight (1 for
/// a galaxy selected on the unsheared version, 0 otherwise) of the rows
/// `objs`, which share one response: a dataset's (a run) or an image's
/// ([`crate::pipeline::measure_image`]). Without a response every row is
/// flagged NO_PSF. Returns R.
pub fn apply_response<'a>(
    objs: impl Iterator<Item = &'a mut MeasuredObject>,
) -> Option<[[f64; 2]; 2]> {
    let mut rows: Vec<&mut MeasuredObject> = objs.filter(|o| o.metacal.is_some()).collect();
    let ms: Vec<(McMeasure, [bool; 5])> = rows.iter().filter_map(|o| o.metacal).collect();
    let r = response(&ms);
    set_rows(rows.iter_mut().map(|o| &mut **o), r);
    r
}

/// Sets the rows `objs` from their response `r` (metacal's and
/// metadetection's): each row with versions gets R⁻¹ e(0) and, when
/// selected on its unsheared version and unflagged, weight 1; without a
/// response it is flagged NO_PSF. Rows without versions are left alone.
pub fn set_rows<'a>(objs: impl Iterator<Item = &'a mut MeasuredObject>, r: Option<[[f64; 2]; 2]>) {
    set_rows_about(objs, r, [0.0; 2]);
}

/// [`set_rows`] for rows measured on a version sheared by −`g0`
/// (metadetection's `unshear`): each row gets g0 + R⁻¹ e, the shear it
/// estimates in the image as given.
pub fn set_rows_about<'a>(
    objs: impl Iterator<Item = &'a mut MeasuredObject>,
    r: Option<[[f64; 2]; 2]>,
    g0: [f64; 2],
) {
    for o in objs {
        let Some((m, sel)) = o.metacal else { continue };
        let Some(r) = r else {
            o.flags |= flags::NO_PSF;
            o.weight = 0.0;
            continue;
        };
        let mut g = apply_inverse(&r, m.e[0]);
        if g0 != [0.0; 2] {
            g = [g0[0] + g[0], g0[1] + g[1]];
        }
        if !(g[0].is_finite() && g[1].is_finite()) {
            o.flags |= flags::MOMENTS;
            continue;
        }
        if g[0].abs().max(g[1].abs()) <= stepsim_contract::MAX_ABS_SHEAR {
            o.e1 = g[0];
            o.e2 = g[1];
        }
        if sel[0] && o.flags == 0 {
            o.weight = 1.0;
        }
    }
}

/// The stamp side for a galaxy of windowed size `rg` reconvolved with σ
/// `sigma`, `None` if even the largest is too small.
pub fn stamp_side(rg: f64, sigma: f64) -> Option<usize> {
    let need = 8.0 * (rg * rg + sigma * sigma).sqrt();
    STAMP_SIDES.iter().copied().find(|&s| s as f64 >= need)
}

/// σ of Γ for the PSF `psf` with stellar size `rg_star`: the smallest of
/// 1.2, 1.3, … 3.0 × `rg_star` whose Γ stays below 1.5 |P̂| on the largest
/// stamp grid (the last one tried otherwise).
pub fn reconvolution_sigma(psf: &PsfStack, rg_star: f64) -> f64 {
    let side = *STAMP_SIDES.last().expect("sides");
    let mut sigma = 0.0;
    for step in 12..=30 {
        sigma = rg_star * f64::from(step) / 10.0;
        if Deconvolver::new(psf, side, sigma).max_amplification() <= 1.5 {
            break;
        }
    }
    sigma
}

/// The two parts of a dataset's response, (R_γ, R_S), from its galaxies'
/// measurements and their selection on each version (`selected[v]`);
/// `None` without a galaxy selected on every version.
pub fn response_parts(objs: &[(McMeasure, [bool; 5])]) -> Option<[[[f64; 2]; 2]; 2]> {
    let mut rg = [[0.0; 2]; 2];
    let mut rs = [[0.0; 2]; 2];
    let sel0: Vec<&McMeasure> = objs.iter().filter(|o| o.1[0]).map(|o| &o.0).collect();
    if sel0.is_empty() {
        return None;
    }
    let n0 = sel0.len() as f64;
    for j in 0..2 {
        for i in 0..2 {
            rg[i][j] = sel0
                .iter()
                .map(|m| (m.e[1 + 2 * j][i] - m.e[2 + 2 * j][i]) / (2.0 * STEP))
                .sum::<f64>()
                / n0;
            let mean_on = |v: usize| -> Option<f64> {
                let (s, n) = objs
                    .iter()
                    .filter(|o| o.1[v])
                    .fold((0.0, 0usize), |(s, n), o| (s + o.0.e[0][i], n + 1));
                (n > 0).then(|| s / n as f64)
            };
            rs[i][j] = (mean_on(1 + 2 * j)? - mean_on(2 + 2 * j)?) / (2.0 * STEP);
        }
    }
    Some([rg, rs])
}

/// A dataset's response R = R_γ + R_S ([`response_parts`]); `None`
/// without a galaxy selected on every version or with a singular R.
pub fn response(objs: &[(McMeasure, [bool; 5])]) -> Option<[[f64; 2]; 2]> {
    let [rg, rs] = response_parts(objs)?;
    let r = [
        [rg[0][0] + rs[0][0], rg[0][1] + rs[0][1]],
        [rg[1][0] + rs[1][0], rg[1][1] + rs[1][1]],
    ];
    let det = r[0][0] * r[1][1] - r[0][1] * r[1][0];
    (det.is_finite() && det.abs() > 1e-6).then_some(r)
}

/// R⁻¹ e.
pub fn apply_inverse(r: &[[f64; 2]; 2], e: [f64; 2]) -> [f64; 2] {
    let det = r[0][0] * r[1][1] - r[0][1] * r[1][0];
    [
        (r[1][1] * e[0] - r[0][1] * e[1]) / det,
        (-r[1][0] * e[0] + r[0][0] * e[1]) / det,
    ]
}

#[cfg(test)]
mod tests;
