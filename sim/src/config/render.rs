//! `render` and `output` sections.

use super::{Invalid, check_range};
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
    pub method: RenderMethod,
}

/// `render.method`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum RenderMethod {
    /// Object ⊗ a narrow Gaussian per stamp, then one convolution of the
    /// image with the rest of the PSF.
    #[default]
    Split,
    /// Object ⊗ the whole PSF per stamp.
    Stamp,
}

impl Default for RawRender {
    fn default() -> Self {
        Self {
            folding_threshold: 5e-3,
            maxk_threshold: 1e-4,
            edge_sky_sigma: 0.1,
            max_stamp_px: 1024,
            method: RenderMethod::Split,
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

/// Pixel type of the written images.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum SampleFormat {
    /// BITPIX −32.
    Float32,
    /// BITPIX 32 (ADU rounded to the nearest integer).
    Int32,
}

/// Compression of the written images.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Compression {
    /// Plain FITS.
    None,
    /// Lossless Rice tile compression (integer output only).
    Rice,
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
