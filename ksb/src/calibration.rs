//! KSB+'s isotropic correction calibrated on the image's own PSF.
//!
//! P^γ = P^sh − P^sm (P^sh* / P^sm*) (paper eq. 15, half-traces) is exact
//! for a Gaussian PSF and not for PSFs with wings: through a PSF with 20 %
//! of its flux in a halo of σ 4 px, noise-free Gaussian galaxies of σ
//! 1.5–4 px come out with m = −0.077 … +0.015 (round ones −0.043 …
//! −0.025; `tests`), and the compact STEP1 PSFs give m_isolated ≈ −0.04 …
//! −0.07 (docs/baseline.md).
//!
//! The calibration measures what the correction misses on the image's own
//! PSF. Model galaxies are drawn through the image's PSF stack
//! ([`crate::metacal::stack_psf`], pixel included) in Fourier space, on a
//! 64² or [`SIDE`]² grid: a ladder of scales (from [`FIRST_SCALE`] r_g*
//! up by [`SIZE_STEP`]) in rows of intrinsic shape [`INTRINSIC`]. Each
//! model is measured unsheared and sheared by ±0.01 in g₁ and g₂, as the
//! pipeline measures a galaxy (windowed centroid and size, KSB integrals,
//! e_cor = e − P^sm p with p and P^sh*/P^sm* from the stack at the
//! model's r_g, γ̂ = e_cor / ½Tr P^γ), and its k is the response of that
//! estimator,
//!
//! k = ½ (∂γ̂₁/∂g₁ + ∂γ̂₂/∂g₂)  (central differences),
//!
//! 1 where KSB+ is exact (through a Gaussian PSF, round Gaussian models
//! give 1 to 1e-3).
//!
//! k depends on the galaxy's shape, so the image's galaxies choose the
//! mix of rows ([`PgammaCalibration::shape_index`],
//! [`PgammaCalibration::for_shapes`]), and every galaxy's P^γ is
//! multiplied by the mix's k at its [`size`]. What it does not correct:
//! a galaxy profile unlike the model's ([`CalibrationProfile`]), shapes
//! that differ between sizes, and noise.

use crate::centroid::{WindowSettings, windowed};
use crate::image::Image;
use crate::metacal::{Plans, PsfStack, freq};
use crate::moments::{KsbShape, ksb_integrals};
use crate::psf_model::PsfCorrection;
use crate::shear::{e_cor, pgamma};
use rustfft::num_complex::Complex64;
use std::f64::consts::PI;

/// Side of the grid the models are drawn on (pixels): holds the window of
/// a galaxy of r_g up to 15 px (4 r_g).
pub const SIDE: usize = 128;

/// The shear of the sheared models.
const STEP: f64 = 0.01;

/// Ratio of neighbouring model scales.
const SIZE_STEP: f64 = 1.15;

/// Convergence tolerance of the models' windowed centroids and sizes.
const MODEL_TOL: f64 = 1e-7;

/// The smallest model scale, in units of r_g*.
const FIRST_SCALE: f64 = 0.3;

/// Iterations of k(size) towards its fixed point (the first takes the
/// largest |R − 1| of the halo tests from 1e-3 to 2e-4, the second to
/// 1e-4; later ones wander at 1e-5).
const ITERATIONS: usize = 2;

/// The radial profile of the model galaxies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CalibrationProfile {
    /// exp(−r / h): transform (1 + 4π² h² |k|²)^(−3/2).
    Exponential,
    /// exp(−r² / 2σ²): transform exp(−2π² σ² |k|²).
    Gaussian,
}

impl CalibrationProfile {
    /// The transform at k (cycles per pixel) of the round profile of scale
    /// `s` given the intrinsic shape `g_int` and then sheared by `g`, with
    /// its value at k = 0 equal to 1.
    fn transform(self, s: f64, g_int: [f64; 2], g: [f64; 2], k: [f64; 2]) -> f64 {
        // I(x) = f(|A_int A x|) with SPEC §1's A (determinant 1) for each
        // shear (the lens acts on the intrinsic shape): the transform's
        // quadratic form is |(A_int A)⁻ᵀ k|² = |A_int⁻¹ A⁻¹ k|², with
        // A⁻¹ = (1 − |g|²)^(−½) [[1 + g₁, g₂], [g₂, 1 − g₁]].
        let inv = |g: [f64; 2], k: [f64; 2]| {
            let n = (1.0 - g[0] * g[0] - g[1] * g[1]).sqrt();
            [
                ((1.0 + g[0]) * k[0] + g[1] * k[1]) / n,
                (g[1] * k[0] + (1.0 - g[0]) * k[1]) / n,
            ]
        };
        let v = inv(g_int, inv(g, k));
        let q = s * s * (v[0] * v[0] + v[1] * v[1]);
        match self {
            CalibrationProfile::Exponential => {
                let x = 1.0 + 4.0 * PI * PI * q;
                1.0 / (x * x.sqrt())
            }
            CalibrationProfile::Gaussian => (-2.0 * PI * PI * q).exp(),
        }
    }
}

/// The intrinsic shapes |g_int| of the model rows (shear type; distortion
/// 0, 0.38, 0.69, 0.88): round, and pairs of orientations 90° apart.
const INTRINSIC: [f64; 4] = [0.0, 0.2, 0.4, 0.6];

/// The models of one image's PSF: k by size and intrinsic shape.
#[derive(Debug, Clone, PartialEq)]
pub struct PgammaCalibration {
    /// One row per intrinsic shape, by increasing |g_int|.
    rows: Vec<Row>,
}

/// k(size) of one image's galaxies ([`PgammaCalibration::for_shapes`]).
#[derive(Debug, Clone, PartialEq)]
pub struct SizeFactor {
    /// ln size of the round models, increasing.
    ln_rg: Vec<f64>,
    /// k at each.
    k: Vec<f64>,
}

impl SizeFactor {
    /// k at [`size`] `size`.
    fn at_size(&self, size: f64) -> f64 {
        lerp(&self.ln_rg, &self.k, size.ln())
    }

    /// k of a galaxy of windowed size `rg` and |e_cor| `e`: linear in the
    /// log of its [`size`], held at the ends; NaN for a NaN size or |e|.
    pub fn factor(&self, rg: f64, e: f64) -> f64 {
        let z = size(rg, e);
        if z.is_nan() {
            f64::NAN
        } else {
            self.at_size(z)
        }
    }
}

/// `values` (one per node) at `t`, linear between the increasing `nodes`
/// and held at the ends ([`bracket`]).
fn lerp(nodes: &[f64], values: &[f64], t: f64) -> f64 {
    lerp_by(nodes, t, |i| values[i])
}

/// [`lerp`] of the node values `value(i)`, evaluated only at the one or
/// two nodes it needs.
fn lerp_by(nodes: &[f64], t: f64, value: impl Fn(usize) -> f64) -> f64 {
    let (i, f) = bracket(nodes, t);
    let v0 = value(i);
    if f == 0.0 {
        v0
    } else {
        v0 + f * (value(i + 1) - v0)
    }
}

/// Where `t` falls on the increasing nodes `ln_rg`: (i, f) with t between
/// node i and i + 1 at fraction f; (0, 0) below the first node (and for
/// NaN), (last, 0) beyond the last.
fn bracket(ln_rg: &[f64], t: f64) -> (usize, f64) {
    let n = ln_rg.len();
    if t.is_nan() || t <= ln_rg[0] {
        return (0, 0.0);
    }
    if t >= ln_rg[n - 1] {
        return (n - 1, 0.0);
    }
    let i = ln_rg.partition_point(|&l| l <= t) - 1;
    (i, (t - ln_rg[i]) / (ln_rg[i + 1] - ln_rg[i]))
}

/// The models of one intrinsic shape, by increasing size.
#[derive(Debug, Clone, PartialEq)]
struct Row {
    /// ln [`size`] (ring mean), increasing.
    ln_rg: Vec<f64>,
    /// |e_cor| (ring mean) at g = 0.
    e: Vec<f64>,
    /// The ring at each size.
    rings: Vec<Vec<Member>>,
}

impl Row {
    /// |e_cor| at ln size `t`: linear in ln size, held at the ends.
    fn e_at(&self, t: f64) -> f64 {
        lerp(&self.ln_rg, &self.e, t)
    }

    /// The rings' response at ln size `t` with k(size) = `k` (linear in
    /// ln size between the rings, held at the ends).
    fn response_at(&self, t: f64, k: &dyn Fn(f64) -> f64) -> f64 {
        lerp_by(&self.ln_rg, t, |i| {
            ring_mean(&self.rings[i], |m| m.response(k))
        })
    }
}

/// One model's measurement: its windowed size, e_cor and ½Tr P^γ.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ModelShape {
    rg: f64,
    e_cor: [f64; 2],
    pgamma: f64,
}

impl ModelShape {
    /// Its [`size`].
    fn size(&self) -> f64 {
        size(self.rg, self.e_cor[0].hypot(self.e_cor[1]))
    }
}

/// The size the calibration is indexed by: r_g (1 − |e|²)^¼, which a
/// shear changes only to second order where r_g changes to first (g e):
/// for unweighted moments it is det(Q)^¼, which a shear of determinant 1
/// keeps. Indexed by r_g itself, a galaxy's k would follow the shear and
/// add a response of its own (2 % for |e_s| = 0.4, σ 1.5 px through the
/// halo PSF of the tests).
pub fn size(rg: f64, e: f64) -> f64 {
    if e.is_nan() {
        return f64::NAN;
    }
    rg * (1.0 - (e * e).min(0.99)).sqrt().sqrt()
}

/// One grid the models are drawn on, with the PSF stack at its centre.
struct Grid {
    side: usize,
    plans: Plans,
    /// The PSF stack's transform.
    psf_t: Vec<Complex64>,
    /// The PSF stack itself (× 1e4).
    psf_img: Image,
}

impl Grid {
    fn new(psf: &PsfStack, side: usize) -> Self {
        let plans = Plans::new(side);
        let pix = psf.on_grid(side);
        let mut psf_t: Vec<Complex64> = pix.iter().map(|&v| Complex64::new(v, 0.0)).collect();
        plans.fft2(&mut psf_t, false);
        Self {
            side,
            plans,
            psf_t,
            psf_img: Image {
                width: side,
                height: side,
                data: pix.iter().map(|&v| (1e4 * v) as f32).collect(),
            },
        }
    }
}

/// The drawing and measuring of models through one PSF.
struct Bench {
    /// A small grid for most models and a large one ([`SIDE`]) for the
    /// rest.
    grids: [Grid; 2],
    profile: CalibrationProfile,
    /// The pipeline's window, converged tightly: the sheared models'
    /// sizes differ by 0.2 %, more than the pipeline's tolerance.
    win: WindowSettings,
}

impl Bench {
    fn new(psf: &PsfStack, profile: CalibrationProfile, win: &WindowSettings) -> Self {
        Self {
            grids: [Grid::new(psf, SIDE / 2), Grid::new(psf, SIDE)],
            profile,
            win: WindowSettings {
                tol: MODEL_TOL,
                max_iter: 1000,
                ..*win
            },
        }
    }

    /// The model of scale `s` and intrinsic shape `g_int` sheared by `g`,
    /// drawn on `grid`.
    fn draw(&self, grid: &Grid, s: f64, g_int: [f64; 2], g: [f64; 2]) -> Image {
        let n = grid.side;
        let mut buf: Vec<Complex64> = (0..n * n)
            .map(|p| {
                let k = [freq(p % n, n), freq(p / n, n)];
                grid.psf_t[p] * self.profile.transform(s, g_int, g, k)
            })
            .collect();
        grid.plans.fft2(&mut buf, true);
        let norm = (n * n) as f64;
        Image {
            width: n,
            height: n,
            data: buf.iter().map(|v| (1e4 * v.re / norm) as f32).collect(),
        }
    }

    /// The KSB shape of `img` at its windowed centroid, from the centre of
    /// its grid; r_g adapted from `rg0` when `adapt` is set.
    fn shape(&self, img: &Image, rg0: f64, adapt: bool) -> Option<KsbShape> {
        let c = (img.width / 2) as f64;
        let w = windowed(img, c, c, rg0, adapt, &self.win)?;
        if !w.converged || w.at_bound {
            return None;
        }
        let ints = ksb_integrals(img, w.x, w.y, w.rg, self.win.radius_rg * w.rg, None);
        if ints.clipped {
            return None;
        }
        ints.shape()
    }

    /// The model of scale `s` and intrinsic shape `g_int` sheared by `g`,
    /// measured on `grid`.
    fn measure(
        &self,
        grid: &Grid,
        s: f64,
        g_int: [f64; 2],
        g: [f64; 2],
        rg0: f64,
    ) -> Option<ModelShape> {
        let shape = self.shape(&self.draw(grid, s, g_int, g), rg0, true)?;
        let star = self.shape(&grid.psf_img, shape.sigma_w, false)?;
        let corr = PsfCorrection::of_star(&star)?;
        Some(ModelShape {
            rg: shape.sigma_w,
            e_cor: e_cor(&shape, &corr),
            pgamma: pgamma(&shape, &corr),
        })
    }

    /// The five measurements of the model of scale `s` and intrinsic
    /// shape `g_int`: unsheared, then sheared by +g₁, −g₁, +g₂, −g₂. All
    /// five on the small grid when the window of r_g ≈ `rg0` fits in it
    /// with a quarter to spare, else (or when the small grid fails) on the
    /// large one.
    fn model(&self, s: f64, g_int: [f64; 2], rg0: f64) -> Option<Member> {
        let small = 1.25 * self.win.radius_rg * rg0 < (self.grids[0].side / 2) as f64;
        if small {
            if let Some(m) = self.model_on(&self.grids[0], s, g_int, rg0) {
                return Some(m);
            }
        }
        self.model_on(&self.grids[1], s, g_int, rg0)
    }

    /// [`Self::model`] on one grid.
    fn model_on(&self, grid: &Grid, s: f64, g_int: [f64; 2], rg0: f64) -> Option<Member> {
        let base = self.measure(grid, s, g_int, [0.0, 0.0], rg0)?;
        let mut sheared = Vec::with_capacity(4);
        for g in [[STEP, 0.0], [-STEP, 0.0], [0.0, STEP], [0.0, -STEP]] {
            let m = self.measure(grid, s, g_int, g, base.rg)?;
            if m.pgamma.is_nan() || m.pgamma <= 0.0 {
                return None;
            }
            sheared.push(m);
        }
        let sheared: [ModelShape; 4] = sheared.try_into().ok()?;
        (base.pgamma > 0.0).then_some(Member { base, sheared })
    }

    /// The models of scale `s` with intrinsic |g_int| = `e_int` at two
    /// orientations 90° apart, which cancels the PSF anisotropy's first
    /// order (one model when round; a round PSF's trace response does not
    /// depend on the orientation); `None` if one of them could not be
    /// measured.
    fn ring(&self, s: f64, e_int: f64, rg0: f64) -> Option<Vec<Member>> {
        let n = if e_int == 0.0 { 1 } else { 2 };
        (0..n)
            .map(|i| {
                let th = PI * i as f64 / n as f64;
                let g_int = [e_int * (2.0 * th).cos(), e_int * (2.0 * th).sin()];
                self.model(s, g_int, rg0)
            })
            .collect()
    }
}

/// One model's measurements.
#[derive(Debug, Clone, PartialEq)]
struct Member {
    base: ModelShape,
    sheared: [ModelShape; 4],
}

impl Member {
    /// The response ½ (∂γ̂₁/∂g₁ + ∂γ̂₂/∂g₂) of γ̂ = e_cor / (P^γ k(size)),
    /// each sheared version with its own P^γ and size (central
    /// differences).
    fn response(&self, k: &dyn Fn(f64) -> f64) -> f64 {
        let gamma = |m: &ModelShape, c: usize| m.e_cor[c] / (m.pgamma * k(m.size()));
        let [p1, m1, p2, m2] = &self.sheared;
        0.5 * ((gamma(p1, 0) - gamma(m1, 0)) + (gamma(p2, 1) - gamma(m2, 1))) / (2.0 * STEP)
    }
}

/// Rings' mean of `f` over their members.
fn ring_mean(ring: &[Member], f: impl Fn(&Member) -> f64) -> f64 {
    ring.iter().map(f).sum::<f64>() / ring.len() as f64
}

impl PgammaCalibration {
    /// The calibration for the PSF `psf`, with models from the PSF's own
    /// r_g* (`rg_star`) to `rg_max` (both windowed sizes, pixels);
    /// `None` if a row holds fewer than two models.
    pub fn new(
        psf: &PsfStack,
        rg_star: f64,
        rg_max: f64,
        profile: CalibrationProfile,
        win: &WindowSettings,
    ) -> Option<Self> {
        let bench = Bench::new(psf, profile, win);
        let rg_top = rg_max.min(0.9 * (SIDE / 2) as f64 / win.radius_rg);
        let mut rows = Vec::new();
        for e_int in INTRINSIC {
            let mut row = Row {
                ln_rg: Vec::new(),
                e: Vec::new(),
                rings: Vec::new(),
            };
            // Model scales from FIRST_SCALE r_g* up, until the models' r_g
            // passes the top: the smallest are measured at about r_g*. Each
            // model starts from the last one's r_g, one step larger.
            let mut s = FIRST_SCALE * rg_star;
            let mut rg0 = rg_star;
            while rg0 < rg_top && s < rg_top {
                match bench.ring(s, e_int, rg0) {
                    Some(ring) => {
                        let z = ring_mean(&ring, |m| m.base.size());
                        let k = ring_mean(&ring, |m| m.response(&|_| 1.0));
                        rg0 = ring_mean(&ring, |m| m.base.rg) * SIZE_STEP;
                        if row.ln_rg.last().is_none_or(|&l| z.ln() > l) && k > 0.0 {
                            row.ln_rg.push(z.ln());
                            row.e
                                .push(ring_mean(&ring, |m| m.base.e_cor[0].hypot(m.base.e_cor[1])));
                            row.rings.push(ring);
                        }
                    }
                    None => rg0 *= SIZE_STEP,
                }
                s *= SIZE_STEP;
            }
            // A row of fewer than two models is left out; without the
            // round row there is no calibration.
            if row.ln_rg.len() >= 2 {
                rows.push(row);
            } else if e_int == 0.0 {
                return None;
            }
        }
        Some(Self { rows })
    }

    /// The fractional row index u of a galaxy of windowed size `rg` and
    /// |e_cor| `e`: between rows j and j + 1 when e lies between their
    /// |e_cor| at this size (linear), 0 below the round row, the last row
    /// beyond it.
    pub fn shape_index(&self, rg: f64, e: f64) -> f64 {
        let t = size(rg, e).ln();
        let es: Vec<f64> = self.rows.iter().map(|r| r.e_at(t)).collect();
        if e.is_nan() || e <= es[0] {
            return 0.0;
        }
        for (j, w) in es.windows(2).enumerate() {
            if e < w[1] && w[1] > w[0] {
                return j as f64 + (e - w[0]) / (w[1] - w[0]);
            }
        }
        (es.len() - 1) as f64
    }

    /// The rows' weights in a population whose galaxies have the
    /// fractional row indices `shapes`: the mean of each row's share under
    /// linear interpolation between rows. No shapes: the round row alone.
    pub fn row_weights(&self, shapes: &[f64]) -> Vec<f64> {
        let last = self.rows.len() - 1;
        let mut w = vec![0.0; self.rows.len()];
        if shapes.is_empty() {
            w[0] = 1.0;
            return w;
        }
        for &u in shapes {
            let u = if u.is_nan() {
                0.0
            } else {
                u.clamp(0.0, last as f64)
            };
            let j = (u.floor() as usize).min(last.saturating_sub(1));
            let f = u - j as f64;
            w[j] += 1.0 - f;
            w[(j + 1).min(last)] += f;
        }
        w.iter_mut().for_each(|v| *v /= shapes.len() as f64);
        w
    }

    /// k(size) for a population of galaxies whose intrinsic shapes are the
    /// fractional row indices `shapes` (the same at every size), at the
    /// round row's sizes. A galaxy's k depends on its size, which the
    /// shear changes a little, so k is moved towards the fixed point where
    /// the population's response of γ̂ = e_cor / (P^γ k(size)) is 1 at every
    /// size, each sheared model with k at its own size: from the rows'
    /// plain k, k ← k R (all sizes at once) [`ITERATIONS`] times. If a
    /// response is not finite and positive, the plain k.
    pub fn for_shapes(&self, shapes: &[f64]) -> SizeFactor {
        let w = self.row_weights(shapes);
        let nodes = self.rows[0].ln_rg.clone();
        let mix = |f: &dyn Fn(&Row) -> f64| -> f64 {
            self.rows
                .iter()
                .zip(&w)
                .filter(|(_, w)| **w > 0.0)
                .map(|(r, w)| w * f(r))
                .sum()
        };
        // The plain k: each row's response with k = 1.
        let plain = SizeFactor {
            k: nodes
                .iter()
                .map(|&t| mix(&|r| r.response_at(t, &|_| 1.0)))
                .collect(),
            ln_rg: nodes.clone(),
        };
        let mut f = plain.clone();
        for _ in 0..ITERATIONS {
            let r: Vec<f64> = nodes
                .iter()
                .map(|&t| mix(&|row| row.response_at(t, &|size| f.at_size(size))))
                .collect();
            if !r.iter().all(|r| r.is_finite() && *r > 0.0) {
                return plain;
            }
            f.k.iter_mut().zip(&r).for_each(|(k, r)| *k *= r);
        }
        f
    }

    /// Each row's models (size, |e_cor|, k), by increasing size.
    #[cfg(test)]
    pub fn table(&self) -> Vec<Vec<[f64; 3]>> {
        self.rows
            .iter()
            .map(|r| {
                (0..r.ln_rg.len())
                    .map(|i| {
                        let k = ring_mean(&r.rings[i], |m| m.response(&|_| 1.0));
                        [r.ln_rg[i].exp(), r.e[i], k]
                    })
                    .collect()
            })
            .collect()
    }
}

#[cfg(test)]
mod tests;
