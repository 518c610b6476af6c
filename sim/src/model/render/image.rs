//! A whole image: every object's stamp added into one array.
//!
//! Reproducible by construction: stamps are rendered in parallel (each
//! stamp depends only on its row), batch by batch, and each batch is added
//! by one task while the next batch is drawn, in the **drawing order**
//! ([`drawing_order`]: galaxies before stars, each from the top row of the
//! image down, then by x, then in row order). Every pixel therefore sees
//! the same sequence of f32 additions whatever the thread count. Drawing
//! down the image rather than in the catalogue's (random) order keeps the
//! canvas rows a batch adds to in the cache (the galaxy stage of a STEP1
//! image took 7 % less time), and ends at the bottom rows, where the image
//! convolution starts (drawn upwards instead, the convolution took 8–11 %
//! longer: BENCHMARKS.md).
//!
//! With [`super::Method::Split`] (the default) the stamps hold object ⊗ L
//! and are added into a canvas with a margin; [`Canvas::finish`] convolves
//! it once with the rest of the PSF (see [`super::split`]). The convolution
//! works on disjoint output blocks, so it is reproducible too.

use super::{RenderError, Renderer, Stamp};
use rayon::prelude::*;
use stepsim_contract::truth::TruthRow;

/// Objects rendered per batch (bounds the memory held in stamps).
pub(crate) const BATCH: usize = 2048;

/// The noise-free, sky-free electron image of `rows`, row-major
/// (index (y − 1) · width + (x − 1) for FITS pixel (x, y)); objects partly
/// off the image are clipped. Rows that fail [`crate::model::profile::check_row`] are
/// skipped: call [`try_draw_image`] to have them refused instead.
pub fn draw_image(renderer: &Renderer, rows: &[TruthRow], width: u32, height: u32) -> Vec<f32> {
    let mut canvas = Canvas::new(renderer, width, height);
    canvas.add(rows);
    canvas.finish()
}

/// As [`draw_image`], but the first row that cannot be drawn is an error
/// naming its id, column and value.
pub fn try_draw_image(
    renderer: &Renderer,
    rows: &[TruthRow],
    width: u32,
    height: u32,
) -> Result<Vec<f32>, RenderError> {
    let mut canvas = Canvas::new(renderer, width, height);
    canvas.try_add(rows)?;
    Ok(canvas.finish())
}

/// An image being drawn: stamps are added (in any number of calls, e.g.
/// galaxies then stars), then [`Canvas::finish`] gives the image.
#[derive(Debug)]
pub struct Canvas<'a> {
    renderer: &'a Renderer,
    width: usize,
    height: usize,
    /// Pixels of margin on every side (0 for [`super::Method::Stamp`]).
    margin: usize,
    data: Vec<f32>,
}

impl<'a> Canvas<'a> {
    /// An empty `width × height` image for `renderer` (with the margin its
    /// method needs).
    pub fn new(renderer: &'a Renderer, width: u32, height: u32) -> Self {
        let margin = renderer.split().map_or(0, |s| s.margin_px());
        let (w, h) = (width as usize, height as usize);
        Canvas {
            renderer,
            width: w,
            height: h,
            margin,
            data: zeroed((w + 2 * margin) * (h + 2 * margin)),
        }
    }

    /// Adds `rows`, skipping rows that fail [`crate::model::profile::check_row`].
    pub fn add(&mut self, rows: &[TruthRow]) {
        self.add_rows(drawing_order(rows.iter()));
    }

    /// Adds `rows`, or refuses them all (nothing added) if one cannot be drawn.
    pub fn try_add(&mut self, rows: &[TruthRow]) -> Result<(), RenderError> {
        self.try_add_kind(rows, |_| true)
    }

    /// Adds the rows of `rows` that are stars (`stars` true) or galaxies,
    /// or refuses them all (nothing added) if one of those cannot be drawn.
    /// Adding the galaxies, then the stars, gives the same bytes as
    /// [`Canvas::try_add`] of all rows (the drawing order puts galaxies
    /// first).
    pub fn try_add_only(&mut self, rows: &[TruthRow], stars: bool) -> Result<(), RenderError> {
        self.try_add_kind(rows, |r| r.is_star() == stars)
    }

    fn try_add_kind(
        &mut self,
        rows: &[TruthRow],
        keep: impl Fn(&TruthRow) -> bool,
    ) -> Result<(), RenderError> {
        let kept = || rows.iter().filter(|r| keep(r));
        kept().try_for_each(crate::model::profile::check_row)?;
        self.add_rows(drawing_order(kept()));
        Ok(())
    }

    fn add_rows(&mut self, rows: Vec<&TruthRow>) {
        let stamp_renderer = match self.renderer.split() {
            Some(s) => s.stamps(),
            None => self.renderer,
        };
        let m = self.margin;
        let (w, h) = (self.width + 2 * m, self.height + 2 * m);
        let shift = m as i64;
        let draw = |batch: &[&TruthRow]| -> Vec<Stamp> {
            batch
                .par_iter()
                .filter(|row| touches(stamp_renderer, row, w, h, shift))
                .filter_map(|row| stamp_renderer.try_draw(row).ok())
                .collect()
        };
        // Pipeline: batch k is added (serially, in drawing order) while
        // batch k + 1 is drawn.
        let data = &mut self.data;
        let mut pending: Vec<Stamp> = Vec::new();
        for batch in rows.chunks(BATCH) {
            let done = std::mem::take(&mut pending);
            let ((), next) = rayon::join(
                || {
                    for s in &done {
                        add_stamp(data, w, h, s, shift);
                    }
                },
                || draw(batch),
            );
            pending = next;
        }
        for s in &pending {
            add_stamp(data, w, h, s, shift);
        }
    }

    /// The finished image (`width × height`, row-major).
    pub fn finish(self) -> Vec<f32> {
        match self.renderer.split() {
            Some(s) => {
                s.convolver(self.width, self.height)
                    .apply(self.data, self.width, self.height)
            }
            None => self.data,
        }
    }
}

/// `rows` in the order they are drawn and added: galaxies before stars,
/// each by decreasing y, then increasing x, then in the given order (a
/// stable sort; a NaN position sorts first or last, and such a row is
/// skipped or refused anyway).
pub fn drawing_order<'r>(rows: impl Iterator<Item = &'r TruthRow>) -> Vec<&'r TruthRow> {
    let mut order: Vec<&TruthRow> = rows.collect();
    order.sort_by(|a, b| {
        (a.is_star().cmp(&b.is_star()))
            .then(b.y.total_cmp(&a.y))
            .then(a.x.total_cmp(&b.x))
    });
    order
}

/// `n` zeros, first touched in parallel: a fresh 4096² canvas is ~19 000
/// pages, and faulting them in from one thread cost ~0.1 s of the galaxy
/// stage (measured with 2 threads).
pub(crate) fn zeroed(n: usize) -> Vec<f32> {
    let mut v = Vec::with_capacity(n);
    v.par_extend(rayon::iter::repeat_n(0.0f32, n));
    v
}

/// Quick test whether an object's largest possible stamp reaches a canvas
/// of `w × h` pixels whose first pixel is image pixel (−shift, −shift).
fn touches(renderer: &Renderer, row: &TruthRow, w: usize, h: usize, shift: i64) -> bool {
    let half = renderer.accuracy().max_stamp_px as f64 / 2.0 + 1.0;
    let (x, y) = (row.x + shift as f64, row.y + shift as f64);
    x + half >= 0.5 && x - half <= w as f64 + 0.5 && y + half >= 0.5 && y - half <= h as f64 + 0.5
}

/// Adds the part of `s` (moved by `shift` pixels along both axes) that falls
/// on the `w × h` canvas.
/// Where the CPU runs AVX2 the same code runs built for it (eight f32 lanes
/// instead of four; the same additions, `stepsim_numerics::simd`).
fn add_stamp(canvas: &mut [f32], w: usize, h: usize, s: &Stamp, shift: i64) {
    #[cfg(target_arch = "x86_64")]
    if stepsim_numerics::simd::has_avx2() {
        // SAFETY: the CPU runs AVX2 (checked just above).
        return unsafe { add_stamp_avx2(canvas, w, h, s, shift) };
    }
    add_stamp_body(canvas, w, h, s, shift);
}

/// [`add_stamp_body`] built for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn add_stamp_avx2(canvas: &mut [f32], w: usize, h: usize, s: &Stamp, shift: i64) {
    add_stamp_body(canvas, w, h, s, shift);
}

#[inline(always)]
fn add_stamp_body(canvas: &mut [f32], w: usize, h: usize, s: &Stamp, shift: i64) {
    let (x0, y0) = (s.x0 + shift, s.y0 + shift);
    let j_lo = (-y0).max(0);
    let j_hi = (h as i64 - y0).min(s.ny as i64);
    if j_lo >= j_hi {
        return;
    }
    let i_lo = (-x0).max(0);
    let i_hi = (w as i64 - x0).min(s.nx as i64);
    if i_lo >= i_hi {
        return;
    }
    for j in j_lo..j_hi {
        let y = y0 + j;
        let dst_start = (y as usize) * w + (x0 + i_lo) as usize;
        let len = (i_hi - i_lo) as usize;
        let src_start = j as usize * s.nx + i_lo as usize;
        for (d, v) in canvas[dst_start..dst_start + len]
            .iter_mut()
            .zip(&s.data[src_start..src_start + len])
        {
            *d += *v;
        }
    }
}
