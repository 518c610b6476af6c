//! A whole image: every object's stamp added into one array.
//!
//! Reproducible by construction: stamps are rendered in parallel (each
//! stamp depends only on its row), then added in **row order** — the image
//! is cut into bands of rows, bands are filled in parallel, and within a
//! band the stamps are added in the order of `rows`. Every pixel therefore
//! sees the same sequence of f32 additions whatever the thread count.

use super::{RenderError, Renderer, Stamp};
use crate::truth::TruthRow;
use rayon::prelude::*;

/// Objects rendered per batch (bounds the memory held in stamps).
const BATCH: usize = 2048;
/// Image rows per band when adding stamps.
const BAND: usize = 32;

/// The noise-free, sky-free electron image of `rows`, row-major
/// (index (y − 1) · width + (x − 1) for FITS pixel (x, y)); objects partly
/// off the image are clipped. Rows that fail [`super::check_row`] are
/// skipped: call [`try_draw_image`] to have them refused instead.
pub fn draw_image(renderer: &Renderer, rows: &[TruthRow], width: u32, height: u32) -> Vec<f32> {
    render(renderer, rows, width, height, false).expect("lenient rendering never fails")
}

/// As [`draw_image`], but the first row that cannot be drawn is an error
/// naming its id, column and value.
pub fn try_draw_image(
    renderer: &Renderer,
    rows: &[TruthRow],
    width: u32,
    height: u32,
) -> Result<Vec<f32>, RenderError> {
    render(renderer, rows, width, height, true)
}

fn render(
    renderer: &Renderer,
    rows: &[TruthRow],
    width: u32,
    height: u32,
    strict: bool,
) -> Result<Vec<f32>, RenderError> {
    let (w, h) = (width as usize, height as usize);
    if strict {
        rows.iter().try_for_each(super::check_row)?;
    }
    let mut image = vec![0.0f32; w * h];
    for batch in rows.chunks(BATCH) {
        let stamps: Vec<Stamp> = batch
            .par_iter()
            .filter(|row| touches(renderer, row, w, h))
            .filter_map(|row| renderer.try_draw(row).ok())
            .collect();
        image
            .par_chunks_mut(BAND * w.max(1))
            .enumerate()
            .for_each(|(band, pixels)| {
                let y_lo = (band * BAND) as i64;
                let y_hi = y_lo + (pixels.len() / w.max(1)) as i64;
                for s in &stamps {
                    add_stamp(pixels, w, y_lo, y_hi, s);
                }
            });
    }
    Ok(image)
}

/// Quick test whether an object's largest possible stamp reaches the image.
fn touches(renderer: &Renderer, row: &TruthRow, w: usize, h: usize) -> bool {
    let half = renderer.accuracy().max_stamp_px as f64 / 2.0 + 1.0;
    row.x + half >= 0.5
        && row.x - half <= w as f64 + 0.5
        && row.y + half >= 0.5
        && row.y - half <= h as f64 + 0.5
}

/// Adds the part of `s` that falls on image rows [y_lo, y_hi) into `band`.
fn add_stamp(band: &mut [f32], w: usize, y_lo: i64, y_hi: i64, s: &Stamp) {
    let j_lo = (y_lo - s.y0).max(0);
    let j_hi = (y_hi - s.y0).min(s.ny as i64);
    if j_lo >= j_hi {
        return;
    }
    let i_lo = (-s.x0).max(0);
    let i_hi = (w as i64 - s.x0).min(s.nx as i64);
    if i_lo >= i_hi {
        return;
    }
    for j in j_lo..j_hi {
        let y = s.y0 + j;
        let dst_start = ((y - y_lo) as usize) * w + (s.x0 + i_lo) as usize;
        let len = (i_hi - i_lo) as usize;
        let src_start = j as usize * s.nx + i_lo as usize;
        for (d, v) in band[dst_start..dst_start + len]
            .iter_mut()
            .zip(&s.data[src_start..src_start + len])
        {
            *d += *v;
        }
    }
}
