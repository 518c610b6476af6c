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
use crate::psf::{GaussianPsf, Psf};
use crate::seed::{SeedKey, Stream};
use crate::truth::{KIND_GALAXY, KIND_STAR, TruthRow};
use crate::wcs::TanWcs;
use rand::RngExt;
use rayon::prelude::*;
use std::path::Path;
use std::sync::Arc;

/// Error of the population module (stand-in: never produced).
#[derive(Debug, thiserror::Error)]
#[error("population: {0}")]
pub struct PopulationError(pub String);

/// Error of the PSF module (stand-in: never produced).
#[derive(Debug, thiserror::Error)]
#[error("psf: {0}")]
pub struct PsfError(pub String);

/// The unsheared base field `field`, shared by every dataset
/// (`population::base_field`).
pub fn base_field(plan: &Plan, field: u32) -> Result<Vec<TruthRow>, PopulationError> {
    let img = &plan.raw.image;
    let ins = &plan.raw.instrument;
    let wcs = TanWcs::for_field(img, field);
    let margin_px = img.margin_arcsec / img.pixel_scale_arcsec;
    let (w, h) = (f64::from(img.width_px), f64::from(img.height_px));
    let area_arcmin2 =
        (w + 2.0 * margin_px) * (h + 2.0 * margin_px) * img.pixel_scale_arcsec.powi(2) / 3600.0;
    let mut rows = Vec::new();
    for (stream, density, kind) in [
        (Stream::Galaxies, 30.0, KIND_GALAXY),
        (Stream::Stars, 5.0, KIND_STAR),
    ] {
        let mut rng = SeedKey::base(plan.seed(), field, stream).rng();
        let n = (area_arcmin2 * density).round().max(1.0) as usize;
        for _ in 0..n {
            let x = rng.random_range(0.5 - margin_px..w + 0.5 + margin_px);
            let y = rng.random_range(0.5 - margin_px..h + 0.5 + margin_px);
            let mag = rng.random_range(19.0..25.0);
            let (ra_deg, dec_deg) = wcs.pixel_to_sky(x, y);
            let mut r = TruthRow {
                id: rows.len() as i64 + 1,
                kind,
                hubble_type: -1,
                x,
                y,
                ra_deg,
                dec_deg,
                mag,
                flux_e: ins.mag_to_electrons(mag),
                ..Default::default()
            };
            if kind == KIND_GALAXY {
                let pa: f64 = rng.random_range(0.0..std::f64::consts::PI);
                let ba: f64 = rng.random_range(0.3..1.0);
                let e = (1.0 - ba) / (1.0 + ba);
                r.hubble_type = 3;
                r.z = rng.random_range(0.1..1.5);
                r.disk_h_arcsec = rng.random_range(0.1..0.6);
                r.disk_ba = ba;
                r.bulge_ba = 1.0;
                r.bulge_flat_q = 1.0;
                r.pa_deg = pa.to_degrees();
                r.disk_e1_int = e * (2.0 * pa).cos();
                r.disk_e2_int = e * (2.0 * pa).sin();
                r.e1_int = r.disk_e1_int;
                r.e2_int = r.disk_e2_int;
                r.disk_e1 = r.disk_e1_int;
                r.disk_e2 = r.disk_e2_int;
                r.e1 = r.e1_int;
                r.e2 = r.e2_int;
            }
            rows.push(r);
        }
    }
    Ok(rows)
}

/// The truth rows of a dataset with reduced shear (g1, g2)
/// (`population::sheared`). Stand-in: sets g1, g2 and applies eq. 8 to the
/// whole-galaxy ellipticity only.
pub fn sheared(rows: &[TruthRow], g1: f64, g2: f64) -> Vec<TruthRow> {
    rows.iter()
        .map(|r| {
            let mut s = *r;
            s.g1 = g1;
            s.g2 = g2;
            if r.kind == KIND_GALAXY {
                // e = (e_s + g) / (1 + g* e_s) in complex numbers.
                let (a, b) = (r.e1_int + g1, r.e2_int + g2);
                let (c, d) = (
                    1.0 + g1 * r.e1_int + g2 * r.e2_int,
                    g1 * r.e2_int - g2 * r.e1_int,
                );
                let den = c * c + d * d;
                s.e1 = (a * c + b * d) / den;
                s.e2 = (b * c - a * d) / den;
            }
            s
        })
        .collect()
}

/// The 90°-rotated twin of a base field (`population::rotated`).
pub fn rotated(rows: &[TruthRow]) -> Vec<TruthRow> {
    rows.iter()
        .map(|r| {
            let mut s = *r;
            if r.kind == KIND_GALAXY {
                s.pa_deg = (r.pa_deg + 90.0).rem_euclid(180.0);
                for v in [
                    &mut s.disk_e1_int,
                    &mut s.disk_e2_int,
                    &mut s.e1_int,
                    &mut s.e2_int,
                    &mut s.disk_e1,
                    &mut s.disk_e2,
                    &mut s.e1,
                    &mut s.e2,
                ] {
                    *v = -*v;
                }
            }
            s
        })
        .collect()
}

/// A calibrated PSF (`psf::build`). Stand-in: a round Gaussian of the
/// configured FWHM whatever the model.
pub fn build_psf(
    psf: &RawPsf,
    _telescope: &RawTelescope,
    _pixel_scale_arcsec: f64,
) -> Result<Arc<dyn Psf>, PsfError> {
    Ok(Arc::new(GaussianPsf::round(psf.fwhm_arcsec)))
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

/// Writes the PSF image file `private/psf/<name>.fits`
/// (`io::psf_fits::write_psf_fits`). Stand-in: one primary HDU holding a
/// unit-flux star drawn at image sampling on a 64² grid, centred on pixel
/// (33, 33).
pub fn write_psf_fits(
    path: &Path,
    psf: &Arc<dyn Psf>,
    _raw: &RawPsf,
    pixel_scale_arcsec: f64,
) -> Result<(), IoError> {
    let r = Renderer::new(psf.clone(), pixel_scale_arcsec, Accuracy, 1.0);
    let star = TruthRow {
        kind: KIND_STAR,
        x: 33.0,
        y: 33.0,
        flux_e: 1.0,
        ..Default::default()
    };
    let px = draw_image(&r, &[star], 64, 64);
    crate::io::write_atomically(path, |tmp| {
        let fe = |e: fitsio::errors::Error| IoError::fits(path, e);
        let desc = fitsio::images::ImageDescription {
            data_type: fitsio::images::ImageType::Float,
            dimensions: &[64, 64],
        };
        let mut f = fitsio::FitsFile::create(tmp)
            .with_custom_primary(&desc)
            .open()
            .map_err(fe)?;
        let hdu = f.primary_hdu().map_err(fe)?;
        hdu.write_image(&mut f, &px).map_err(fe)?;
        Ok(())
    })
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
