//! `render` and `output` sections.

use super::{Invalid, check_range};
use crate::io::image_fits::{Compression, SampleFormat};
use crate::model::render::{Accuracy, Method};
use serde::{Deserialize, Serialize};

/// `render`: accuracy of the stamp renderer (GalSim GSParams-like). The
/// values are documented in `docs/rendering.md`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RawRender {
    /// Largest fraction of an object's flux allowed outside its stamp
    /// (GalSim's folding threshold; default 5e-3).
    pub folding_threshold: f64,
    /// k-space cut (default 1e-4): where the PSF ⊗ pixel transfer function is
    /// below this amplitude (relative to k = 0), galaxy transforms are not
    /// evaluated (GalSim's maxk_threshold in spirit). 1e-4 keeps rendering
    /// errors below ~1.3e-4 of the peak; 1e-3 is ~15% faster with errors up
    /// to ~5e-4 of the peak (docs/rendering.md).
    pub maxk_threshold: f64,
    /// No stamp edge may be brighter than this fraction of the sky noise σ.
    pub edge_sky_sigma: f64,
    /// Largest stamp side in pixels (bright stars).
    pub max_stamp_px: u32,
    /// How whole images apply the PSF: `split` (default; exact factoring,
    /// PSF wings applied once per image) or `stamp` (each object with the
    /// whole PSF on its own stamp). See docs/rendering.md.
    pub method: Method,
}

impl Default for RawRender {
    /// The renderer's own defaults ([`Accuracy::default`]).
    fn default() -> Self {
        let a = Accuracy::default();
        Self {
            folding_threshold: a.folding_threshold,
            maxk_threshold: a.kvalue_threshold,
            edge_sky_sigma: a.edge_sky_sigma,
            max_stamp_px: a.max_stamp_px as u32,
            method: a.method,
        }
    }
}

impl RawRender {
    pub(crate) fn validate(&self) -> Result<(), Invalid> {
        check_range(
            "render.folding_threshold",
            self.folding_threshold,
            1e-8,
            0.1,
        )?;
        check_range("render.maxk_threshold", self.maxk_threshold, 1e-8, 0.1)?;
        check_range("render.edge_sky_sigma", self.edge_sky_sigma, 1e-4, 10.0)?;
        if !(16..=8192).contains(&self.max_stamp_px) {
            return Err(Invalid::new(
                "render.max_stamp_px".into(),
                format!("must be in [16, 8192], got {}", self.max_stamp_px),
            ));
        }
        Ok(())
    }
}

/// `output`: what `generate` writes.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RawOutput {
    /// Add photon and read noise (false gives noise-free images with sky).
    pub noise: bool,
    /// Also write the noise-free model beside each noisy image (private half).
    pub write_model: bool,
    /// Write the PSF images into the private half.
    pub write_psf: bool,
    /// Pixel type.
    pub format: SampleFormat,
    /// Compression.
    pub compression: Compression,
}

impl Default for RawOutput {
    fn default() -> Self {
        Self {
            noise: true,
            write_model: false,
            write_psf: true,
            format: SampleFormat::Float32,
            compression: Compression::None,
        }
    }
}

impl RawOutput {
    pub(crate) fn validate(&self) -> Result<(), Invalid> {
        if self.compression == Compression::Rice && self.format == SampleFormat::Float32 {
            return Err(Invalid::new(
                "output.compression".into(),
                "rice compression is lossless only for integer output: set output.format to \"int32\"".into(),
            ));
        }
        Ok(())
    }
}
