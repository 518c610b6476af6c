//! A whole public run directory: read `manifest.json`, measure every image
//! in parallel, write one submission (SPEC §6) sorted by image id, then y,
//! then x. The output is the same whatever the thread count: images are
//! independent and every per-image step is deterministic.

use crate::error::KsbError;
use crate::io::{read_fits_image, read_manifest, write_submission};
use crate::params::KsbParams;
use crate::pipeline::{ImageInfo, ImageMeasurement, measure_image};
use rayon::prelude::*;
use std::path::Path;

/// Summary of one measured image.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageSummary {
    /// Public image id.
    pub image: String,
    /// Rows written.
    pub n_objects: usize,
    /// Rows with positive weight.
    pub n_weighted: usize,
    /// PSF stars.
    pub n_stars: usize,
    /// r_g* (pixels), if a locus was found.
    pub rg_star_px: Option<f64>,
    /// PSF model order, if any.
    pub psf_order: Option<usize>,
}

/// Measures `public_dir` (holding `manifest.json`) with `threads` threads
/// (0: rayon's default) and writes the submission to `out`.
pub fn measure_run(
    public_dir: &Path,
    out: &Path,
    threads: usize,
    params: &KsbParams,
) -> Result<Vec<ImageSummary>, KsbError> {
    params.validate()?;
    let manifest_path = public_dir.join("manifest.json");
    let manifest = read_manifest(&manifest_path)?;
    let inst = &manifest.instrument;
    let gain = inst.gain_e_per_adu;
    let info = ImageInfo {
        zeropoint_eff_mag: inst.zeropoint_mag + 2.5 * inst.exposure_s.max(1e-30).log10(),
        saturation_e: (inst.saturation_adu > 0.0).then_some((inst.saturation_adu - 0.5) * gain),
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| KsbError::Threads {
            threads,
            message: e.to_string(),
        })?;
    let mut images: Vec<&stepsim_sim::run_layout::ManifestImage> = manifest.images.iter().collect();
    images.sort_by(|a, b| a.image.cmp(&b.image));
    let results: Vec<Result<ImageMeasurement, KsbError>> = pool.install(|| {
        images
            .par_iter()
            .map(|im| {
                let path = public_dir.join(&im.file);
                let img = read_fits_image(&path)?;
                if img.width != inst.width_px as usize || img.height != inst.height_px as usize {
                    return Err(KsbError::Image {
                        path,
                        message: format!(
                            "image is {} × {}, the manifest says {} × {}",
                            img.width, img.height, inst.width_px, inst.height_px
                        ),
                    });
                }
                measure_image(&img.scaled(gain as f32), &info, params)
            })
            .collect()
    });
    let mut measured = Vec::with_capacity(results.len());
    for r in results {
        measured.push(r?);
    }
    write_submission(
        out,
        images
            .iter()
            .zip(&measured)
            .flat_map(|(im, m)| m.objects.iter().map(move |o| (im.image.as_str(), o))),
    )?;
    Ok(images
        .iter()
        .zip(&measured)
        .map(|(im, m)| ImageSummary {
            image: im.image.clone(),
            n_objects: m.objects.len(),
            n_weighted: m.objects.iter().filter(|o| o.weight > 0.0).count(),
            n_stars: m.n_stars,
            rg_star_px: m.locus.map(|l| l.rg_star),
            psf_order: m.psf_order,
        })
        .collect())
}
