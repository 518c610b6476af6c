//! **STAND-INS.** Every call that `generate` and `bench` make into the
//! population, PSF and rendering modules goes through this one file, so that
//! the run could be built and tested before those modules existed.
//!
//! The bodies below are temporary stand-ins with the agreed signatures:
//!
//! * `population::base_field(plan, field)`, `population::sheared(rows, g1, g2)`,
//!   `population::rotated(rows)`;
//! * `psf::build(psf, telescope, pixel_scale_arcsec)` and
//!   `io::psf_fits::write_psf_fits(...)`;
//! * `render::{Accuracy::from_config, Renderer::new, draw_image}`.
//!
//! When the real modules are merged, replace the bodies (and the stand-in
//! types) by calls to / re-exports of the real ones; nothing else in
//! `generate` depends on what the stand-ins draw. They are deliberately
//! simple: a few objects per arcmin² at seeded random positions, a round
//! Gaussian PSF of the configured FWHM for every model, each object painted
//! as a round Gaussian sampled at pixel centres.

use crate::config::{Plan, RawPsf, RawRender, RawTelescope};
use crate::io::IoError;
use crate::psf::Psf;
use crate::truth::{KIND_GALAXY, TruthRow};
use rayon::prelude::*;
use std::path::Path;
use std::sync::Arc;

pub use crate::population::PopulationError;

pub use crate::psf::PsfError;

/// The unsheared base field `field`, shared by every dataset.
pub fn base_field(plan: &Plan, field: u32) -> Result<Vec<TruthRow>, PopulationError> {
    crate::population::base_field(plan, field)
}

/// The truth rows of a dataset with reduced shear (g1, g2).
pub fn sheared(rows: &[TruthRow], g1: f64, g2: f64) -> Vec<TruthRow> {
    crate::population::sheared(rows, g1, g2)
}

/// The 90°-rotated twin of a base field.
pub fn rotated(rows: &[TruthRow]) -> Vec<TruthRow> {
    crate::population::rotated(rows)
}

/// The calibrated PSF of one config entry (built once per process).
pub fn build_psf(
    psf: &RawPsf,
    telescope: &RawTelescope,
    pixel_scale_arcsec: f64,
) -> Result<Arc<dyn Psf>, PsfError> {
    crate::psf::build(psf, telescope, pixel_scale_arcsec)
}

/// Renderer accuracy (`render::Accuracy`). Stand-in: unused.
#[derive(Debug, Clone, Copy)]
pub struct Accuracy;

impl Accuracy {
    /// `render::Accuracy::from_config`.
    pub fn from_config(_render: &RawRender) -> Self {
        Self
    }
}

/// An image renderer for one PSF (`render::Renderer`).
#[derive(Debug)]
pub struct Renderer {
    psf_sigma_arcsec: f64,
    pixel_scale_arcsec: f64,
}

impl Renderer {
    /// `render::Renderer::new`.
    pub fn new(
        psf: Arc<dyn Psf>,
        pixel_scale_arcsec: f64,
        _accuracy: Accuracy,
        _sky_sigma_e: f64,
    ) -> Self {
        // For a round Gaussian, r(½) = σ sqrt(2 ln 2).
        let sigma = psf.radius_enclosing(0.5) / (2.0 * std::f64::consts::LN_2).sqrt();
        Self {
            psf_sigma_arcsec: sigma,
            pixel_scale_arcsec,
        }
    }
}

/// The renderer of one PSF, built from the config's `render` section.
pub fn renderer(
    psf: Arc<dyn Psf>,
    pixel_scale_arcsec: f64,
    render: &RawRender,
    sky_sigma_e: f64,
) -> Renderer {
    Renderer::new(
        psf,
        pixel_scale_arcsec,
        Accuracy::from_config(render),
        sky_sigma_e,
    )
}

/// Noise-free, sky-free image in electrons, row-major, index
/// (y−1)·width + (x−1) (`render::draw_image`). Stand-in: round Gaussians of
/// σ² = σ_psf² + disk_h², sampled at pixel centres within 6σ; parallel over
/// bands of rows, each band summing objects in row order (deterministic).
pub fn draw_image(renderer: &Renderer, rows: &[TruthRow], width: u32, height: u32) -> Vec<f32> {
    let (w, h) = (width as usize, height as usize);
    let p = renderer.pixel_scale_arcsec;
    let mut img = vec![0f32; w * h];
    const BAND: usize = 32;
    img.par_chunks_mut(BAND * w)
        .enumerate()
        .for_each(|(band, dst)| {
            let y0 = band * BAND; // 0-based first row of the band
            let y1 = y0 + dst.len() / w;
            for r in rows {
                let size = if r.kind == KIND_GALAXY {
                    r.disk_h_arcsec
                } else {
                    0.0
                };
                let s = (renderer.psf_sigma_arcsec.powi(2) + size * size).sqrt() / p;
                let reach = 6.0 * s;
                // FITS pixel y = row + 1.
                let lo_y = ((r.y - 1.0 - reach).ceil().max(y0 as f64)) as usize;
                let hi_y = (r.y - 1.0 + reach).floor().min(y1 as f64 - 1.0);
                if hi_y < lo_y as f64 || r.x + reach < 1.0 || r.x - reach > w as f64 {
                    continue;
                }
                let lo_x = (r.x - 1.0 - reach).ceil().max(0.0) as usize;
                let hi_x = (r.x - 1.0 + reach).floor().min(w as f64 - 1.0) as usize;
                let norm = r.flux_e / (2.0 * std::f64::consts::PI * s * s);
                for row in lo_y..=hi_y as usize {
                    let dy = row as f64 + 1.0 - r.y;
                    let line = &mut dst[(row - y0) * w..(row - y0 + 1) * w];
                    for (col, v) in line.iter_mut().enumerate().take(hi_x + 1).skip(lo_x) {
                        let dx = col as f64 + 1.0 - r.x;
                        *v += (norm * (-(dx * dx + dy * dy) / (2.0 * s * s)).exp()) as f32;
                    }
                }
            }
        });
    img
}

/// Writes the PSF image file `private/psf/<name>.fits`: the pixel-scale
/// image and the oversampled one, with the measured report in the header
/// (the same file `stepsim psf` writes).
pub fn write_psf_fits(
    path: &Path,
    psf: &Arc<dyn Psf>,
    raw: &RawPsf,
    pixel_scale_arcsec: f64,
) -> Result<(), IoError> {
    use crate::io::psf_fits::{DEFAULT_OVERSAMPLE, DEFAULT_SIZE_PX, write_psf};
    let report = crate::psf::report(&raw.name, psf.as_ref(), pixel_scale_arcsec)
        .map_err(|e| IoError::format(path, e.to_string()))?;
    write_psf(
        path,
        &raw.name,
        psf.as_ref(),
        pixel_scale_arcsec,
        DEFAULT_SIZE_PX,
        DEFAULT_OVERSAMPLE,
        Some(&report),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stand_in_draws_the_flux_of_an_object_well_inside() {
        let psf = build_psf(&RawPsf::step1_set()[0], &RawTelescope::default(), 0.2).unwrap();
        let r = renderer(psf, 0.2, &RawRender::default(), 1.0);
        let obj = TruthRow {
            kind: KIND_GALAXY,
            x: 40.3,
            y: 47.8,
            flux_e: 1000.0,
            disk_h_arcsec: 0.3,
            ..Default::default()
        };
        let img = draw_image(&r, &[obj], 80, 100);
        let sum: f64 = img.iter().map(|&v| f64::from(v)).sum();
        assert!((sum - 1000.0).abs() < 0.1, "{sum}");
        // The peak is at the pixel nearest the position.
        let imax = img
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .unwrap()
            .0;
        assert_eq!((imax % 80 + 1, imax / 80 + 1), (40, 48));
    }
}
