//! The galaxy and star renderer (Fourier space, one stamp per object).
//!
//! For each truth row the renderer chooses a stamp (side `n`, even,
//! 2^a 3^b 5^c), fills the half-plane frequency grid of that stamp with
//!
//! ```text
//! Σ_c F_c f̃_c(|L_cᵀ k|) · T_psf(k) · sinc(u p) sinc(v p) · e^{−2πi k·x₀}
//! ```
//!
//! (profile transforms, the component linear maps of size, flattening,
//! angle and shear, the PSF transfer function, the pixel response and the
//! sub-pixel position), and takes one inverse real 2-D FFT: the result is the
//! pixel-integrated, PSF-convolved image sampled at pixel centres, in
//! electrons. A star is the same with the galaxy factor replaced by its flux.
//!
//! Accuracy is governed by one struct, [`Accuracy`]; the slow real-space
//! twin is [`ReferenceRenderer`]; [`draw_image`] adds stamps into a full image
//! reproducibly. Measured accuracy and speed: `docs/rendering.md`,
//! `BENCHMARKS.md`.
//!
//! Pixel conventions: FITS (first pixel centre 1.0); a [`Stamp`]'s `x0`,
//! `y0` are the 0-based image-array indices of its first pixel, so stamp
//! pixel (i, j) is FITS pixel (x0 + 1 + i, y0 + 1 + j).

pub mod convolve;
mod image;
mod reference;
pub mod split;
pub mod stamp;

pub use image::{Canvas, draw_image, drawing_order, try_draw_image};
pub use reference::ReferenceRenderer;

use crate::model::profile::{Galaxy, ProfileKind, RadialProfile, RowError, check_row};
use crate::model::psf::{Psf, StampGrid};
use serde::{Deserialize, Serialize};
use stamp::{FftCache, Fill, StampEngine};
use std::sync::{Arc, OnceLock};
use std::time::Instant;
use stepsim_contract::truth::TruthRow;
use stepsim_numerics::fft_size::{fft_friendly, fft_friendly_below};

/// A truth row the renderer refuses.
pub type RenderError = RowError;

/// How whole images apply the PSF (the config's `render.method`).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Object ⊗ a narrow Gaussian per stamp, then one convolution of the
    /// image with the rest of the PSF.
    #[default]
    Split,
    /// Object ⊗ the whole PSF per stamp.
    Stamp,
}

/// The renderer's tolerances, in one place (GalSim `GSParams`-like): the
/// defaults of the `render` config section, from which the plan makes them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Accuracy {
    /// Largest fraction of an object's flux allowed outside its stamp
    /// (default 5e-3). Outside flux is folded back into the periodic stamp,
    /// not lost: the stamp always holds the whole flux.
    pub folding_threshold: f64,
    /// k-space cut (default 1e-4, config `render.maxk_threshold`): where the
    /// PSF ⊗ pixel transfer |T S| is below this, the product is set to zero
    /// (stars are never cut).
    /// Measured against the real-space twin: ≤ 1.3e-4 of the peak at 1e-4,
    /// ≤ 5e-4 at 1e-3 (docs/rendering.md).
    pub kvalue_threshold: f64,
    /// No stamp edge brighter than this many sky σ (default 0.1).
    pub edge_sky_sigma: f64,
    /// Largest stamp side in pixels (default 1024).
    pub max_stamp_px: usize,
    /// Smallest stamp side in pixels (16).
    pub min_stamp_px: usize,
    /// How whole images apply the PSF (config `render.method`): `split`
    /// (default) draws object ⊗ a narrow Gaussian per stamp and convolves
    /// the image once with the rest of the PSF ([`split`]); `stamp` draws
    /// each object with the whole PSF on its own stamp. Single-object
    /// drawing ([`Renderer::draw`]) always uses the whole PSF.
    pub method: Method,
}

impl Default for Accuracy {
    fn default() -> Self {
        Self {
            folding_threshold: 5e-3,
            kvalue_threshold: 1e-4,
            edge_sky_sigma: 0.1,
            max_stamp_px: 1024,
            min_stamp_px: 16,
            method: Method::Split,
        }
    }
}

/// One drawn object.
#[derive(Debug, Clone, PartialEq)]
pub struct Stamp {
    /// 0-based image-array column of the stamp's first pixel (FITS x − 1).
    pub x0: i64,
    /// 0-based image-array row of the stamp's first pixel (FITS y − 1).
    pub y0: i64,
    /// Columns.
    pub nx: usize,
    /// Rows.
    pub ny: usize,
    /// Electrons per pixel, row-major (index j · nx + i).
    pub data: Vec<f32>,
}

impl Stamp {
    /// Sum of the pixels (electrons), in f64.
    pub fn sum(&self) -> f64 {
        self.data.iter().map(|&v| f64::from(v)).sum()
    }
}

/// Time spent in each stage of one [`Renderer::draw_timed`] call, in ns.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StageTimes {
    /// Row check, profile set-up and stamp sizing.
    pub setup_ns: u64,
    /// Filling the frequency grid.
    pub kspace_ns: u64,
    /// The inverse FFT and scaling.
    pub fft_ns: u64,
}

impl std::ops::AddAssign for StageTimes {
    fn add_assign(&mut self, o: Self) {
        self.setup_ns += o.setup_ns;
        self.kspace_ns += o.kspace_ns;
        self.fft_ns += o.fft_ns;
    }
}

/// Draws truth rows convolved with one PSF at one pixel scale.
#[derive(Debug)]
pub struct Renderer {
    psf: Arc<dyn Psf>,
    pixel_scale_arcsec: f64,
    accuracy: Accuracy,
    sky_sigma_e: f64,
    /// Fraction of a star's flux in its brightest pixel (centred star).
    psf_peak_fraction: f64,
    /// PSF radius enclosing 1 − folding/2 of its flux (arcsec).
    psf_fold_radius: f64,
    /// Unit-profile radii enclosing 1 − folding/2: [de Vaucouleurs, exponential].
    unit_fold_radius: [f64; 2],
    engine32: StampEngine<f32>,
    engine64: StampEngine<f64>,
    /// The factored PSF of whole images, built on first use.
    split: OnceLock<Box<split::Split>>,
}

impl Renderer {
    /// A renderer for `psf` at `pixel_scale_arcsec`; `sky_sigma_e` is the sky
    /// noise σ per pixel in electrons (for the edge criterion; 0 disables it).
    pub fn new(
        psf: Arc<dyn Psf>,
        pixel_scale_arcsec: f64,
        accuracy: Accuracy,
        sky_sigma_e: f64,
    ) -> Renderer {
        let psf_fold_radius = psf.radius_enclosing(1.0 - 0.5 * accuracy.folding_threshold);
        let engine32 = StampEngine::new(FftCache::default());
        let engine64 = StampEngine::new(FftCache::default());
        let mut r = Renderer {
            psf,
            pixel_scale_arcsec,
            accuracy,
            sky_sigma_e,
            psf_peak_fraction: 1.0,
            psf_fold_radius,
            unit_fold_radius: [
                crate::model::profile::DeVaucouleurs
                    .radius_enclosing(1.0 - 0.5 * accuracy.folding_threshold),
                crate::model::profile::Exponential
                    .radius_enclosing(1.0 - 0.5 * accuracy.folding_threshold),
            ],
            engine32,
            engine64,
            split: OnceLock::new(),
        };
        r.psf_peak_fraction = r.measure_psf_peak_fraction();
        r
    }

    /// The accuracy settings.
    pub fn accuracy(&self) -> &Accuracy {
        &self.accuracy
    }

    /// The pixel scale (arcsec).
    pub fn pixel_scale_arcsec(&self) -> f64 {
        self.pixel_scale_arcsec
    }

    /// The PSF.
    pub fn psf(&self) -> &Arc<dyn Psf> {
        &self.psf
    }

    /// The factored PSF that whole images use when the method is
    /// [`Method::Split`] (built on first call: one transfer function on the
    /// tile grid); `None` for [`Method::Stamp`].
    pub fn split(&self) -> Option<&split::Split> {
        (self.accuracy.method == Method::Split).then(|| {
            &**self.split.get_or_init(|| {
                Box::new(split::Split::new(
                    &self.psf,
                    self.pixel_scale_arcsec,
                    self.accuracy,
                    self.sky_sigma_e,
                ))
            })
        })
    }

    /// Fraction of a centred star's flux in its central pixel.
    pub fn psf_peak_fraction(&self) -> f64 {
        self.psf_peak_fraction
    }

    fn measure_psf_peak_fraction(&self) -> f64 {
        let r = self.psf.radius_enclosing(0.999);
        let want = (2.0 * r / self.pixel_scale_arcsec).ceil();
        let cap = self.accuracy.max_stamp_px.max(32);
        // `as usize` saturates (NaN → 0), so a degenerate PSF cannot overflow.
        let want = if want.is_finite() { want as usize } else { cap };
        let n = fft_friendly(want.min(cap) + 8).clamp(32, fft_friendly(cap));
        let row = TruthRow {
            kind: stepsim_contract::truth::KIND_STAR,
            flux_e: 1.0,
            x: 1.0,
            y: 1.0,
            hubble_type: -1,
            ..TruthRow::default()
        };
        let (_, _, data) = self
            .draw_f64_with_side(&row, n)
            .expect("a unit star is valid");
        data.iter().copied().fold(0.0, f64::max)
    }

    /// Stamp side (pixels) for a row: the smallest FFT-friendly even side
    /// whose half-width covers (a) the radius outside which at most
    /// `folding_threshold` of the flux lies (union bound: galaxy radius for
    /// half of it plus PSF radius for the other half), and (b) the radius
    /// beyond which the object is fainter than `edge_sky_sigma` × sky σ per
    /// pixel (galaxy profile radius plus the PSF folding radius, or the PSF
    /// wings of the whole flux, e.g. diffraction spikes of bright stars);
    /// clamped to [`Accuracy::min_stamp_px`, `Accuracy::max_stamp_px`].
    pub fn stamp_side(&self, row: &TruthRow) -> Result<usize, RenderError> {
        Ok(self.side_of(row, galaxy_of(row)?.as_ref()))
    }

    /// [`Self::stamp_side`] of a checked row and its galaxy (`None` for a
    /// star).
    fn side_of(&self, row: &TruthRow, galaxy: Option<&Galaxy>) -> usize {
        let p = self.pixel_scale_arcsec;
        let acc = &self.accuracy;
        let edge_e = acc.edge_sky_sigma * self.sky_sigma_e;
        let mut radius = self.psf_fold_radius;
        let flux = row.flux_e;
        if edge_e > 0.0 && flux * self.psf_peak_fraction > edge_e {
            let level = edge_e / (2.0 * flux * self.psf_peak_fraction);
            radius = radius.max(self.psf.radius_below(level));
        }
        if let Some(g) = galaxy {
            let n_comp = g.components.len() as f64;
            for c in &g.components {
                // Share the galaxy's half of the folding budget equally
                // between components: component c may leave out a fraction
                // f / (2 n w_c) of its own flux (w_c its share of the total).
                let share = c.flux_e / flux;
                let allowed = (acc.folding_threshold / (2.0 * n_comp * share)).min(0.5);
                let unit = if g.components.len() > 1 {
                    unit_radius_outside(c.kind, allowed)
                } else {
                    match c.kind {
                        ProfileKind::DeVaucouleurs => self.unit_fold_radius[0],
                        ProfileKind::Exponential => self.unit_fold_radius[1],
                    }
                };
                let r_fold = unit * c.map.max_stretch();
                radius = radius.max(r_fold + self.psf_fold_radius);
                if edge_e > 0.0 {
                    let level = edge_e / (2.0 * p * p);
                    let r_edge = c.radius_density_below(level);
                    if r_edge > 0.0 {
                        radius = radius.max(r_edge + self.psf_fold_radius);
                    }
                }
            }
        }
        let want = (2.0 * radius / p).ceil().min(1e6) as usize + 4;
        let max = fft_friendly_below(acc.max_stamp_px.max(acc.min_stamp_px));
        fft_friendly(want.max(acc.min_stamp_px)).min(max)
    }

    /// Draws one object (electrons, noise-free). A row that fails
    /// [`check_row`] gives an empty stamp (`nx = ny = 0`); use
    /// [`Self::try_draw`] to get the reason.
    pub fn draw(&self, row: &TruthRow) -> Stamp {
        self.try_draw(row).unwrap_or(Stamp {
            x0: 0,
            y0: 0,
            nx: 0,
            ny: 0,
            data: Vec::new(),
        })
    }

    /// Draws one object, or says why the row cannot be drawn.
    pub fn try_draw(&self, row: &TruthRow) -> Result<Stamp, RenderError> {
        Ok(self.draw_inner(row, None, false)?.0)
    }

    /// Draws one object and reports the time of each stage (for benchmarks).
    pub fn draw_timed(&self, row: &TruthRow) -> Result<(Stamp, StageTimes), RenderError> {
        self.draw_inner(row, None, true)
    }

    /// Draws one object on a stamp of side `n` (even; for tests and
    /// studies of the stamp size).
    pub fn draw_with_side(&self, row: &TruthRow, n: usize) -> Result<Stamp, RenderError> {
        Ok(self.draw_inner(row, Some(n), false)?.0)
    }

    /// The same drawing in double precision throughout (slower; used by the
    /// moment tests): returns (x0, y0, data) of an `n × n` stamp.
    pub fn draw_f64_with_side(
        &self,
        row: &TruthRow,
        n: usize,
    ) -> Result<(i64, i64, Vec<f64>), RenderError> {
        let fill = self.fill_for(row, n)?;
        let grid = StampGrid::new(fill.n, self.pixel_scale_arcsec);
        let t = self.psf.transfer(grid);
        let data = self.engine64.render(&fill, &t, None);
        Ok((fill.x0, fill.y0, data))
    }

    fn fill_for(&self, row: &TruthRow, n: usize) -> Result<Fill, RenderError> {
        let components = galaxy_of(row)?.map(|g| g.components);
        Ok(self.fill_of(row, n, components))
    }

    /// The [`Fill`] of a checked row on a stamp of side `n` (made even),
    /// with its galaxy's components (`None` for a star).
    fn fill_of(
        &self,
        row: &TruthRow,
        n: usize,
        components: Option<Vec<crate::model::profile::Component>>,
    ) -> Fill {
        let n = n.max(2) + n % 2;
        let components = components.unwrap_or_default();
        // Nearest pixel to the centre sits at stamp index n/2.
        let ix = (row.x + 0.5).floor() as i64; // FITS pixel
        let iy = (row.y + 0.5).floor() as i64;
        let x0 = ix - 1 - (n / 2) as i64;
        let y0 = iy - 1 - (n / 2) as i64;
        Fill {
            n,
            pixel_scale_arcsec: self.pixel_scale_arcsec,
            dx_px: row.x - (x0 + 1) as f64,
            dy_px: row.y - (y0 + 1) as f64,
            star_flux_e: if row.is_star() { row.flux_e } else { 0.0 },
            components,
            cut: if row.is_star() {
                0.0
            } else {
                self.accuracy.kvalue_threshold
            },
            x0,
            y0,
        }
    }

    fn draw_inner(
        &self,
        row: &TruthRow,
        side: Option<usize>,
        timed: bool,
    ) -> Result<(Stamp, StageTimes), RenderError> {
        let t0 = timed.then(Instant::now);
        let galaxy = galaxy_of(row)?;
        let n = match side {
            Some(n) => n,
            None => self.side_of(row, galaxy.as_ref()),
        };
        let fill = self.fill_of(row, n, galaxy.map(|g| g.components));
        let grid = StampGrid::new(fill.n, self.pixel_scale_arcsec);
        let t = self.psf.transfer(grid);
        let mut times = StageTimes::default();
        if let Some(t0) = t0 {
            times.setup_ns = t0.elapsed().as_nanos() as u64;
        }
        let data = self.engine32.render(&fill, &t, timed.then_some(&mut times));
        Ok((
            Stamp {
                x0: fill.x0,
                y0: fill.y0,
                nx: fill.n,
                ny: fill.n,
                data,
            },
            times,
        ))
    }
}

/// The galaxy of a row that passes [`check_row`] (`None` for a star), or
/// why the row cannot be drawn ([`Galaxy::from_row`] checks the row
/// itself).
fn galaxy_of(row: &TruthRow) -> Result<Option<Galaxy>, RenderError> {
    if row.is_star() {
        check_row(row)?;
        return Ok(None);
    }
    Ok(Some(Galaxy::from_row(row)?))
}

/// Unit-profile radius outside which a fraction `outside` of the flux lies
/// (bisection to 1e-6 relative; the closed-form enclosed flux of each law).
fn unit_radius_outside(kind: ProfileKind, outside: f64) -> f64 {
    let p = kind.profile();
    let target = 1.0 - outside;
    let (mut lo, mut hi) = (0.0, 1.0);
    while p.enclosed(hi) < target && hi < 1e9 {
        lo = hi;
        hi *= 2.0;
    }
    stepsim_numerics::roots::Bisection::to_relative_width(1e-6)
        .run(lo, hi, |r| p.enclosed(r) >= target)
        .1
}

#[cfg(test)]
mod tests;
