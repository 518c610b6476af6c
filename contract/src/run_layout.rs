//! The JSON documents of a run directory (SPEC §5); see `docs/run-layout.md`.
//!
//! ```text
//! RUN/public/manifest.json      Manifest   (no truth in it)
//! RUN/private/datasets.json     Datasets   (dataset id -> PSF, shear, images)
//! RUN/private/config.json       the resolved RawConfig
//! RUN/private/truth/<image>.fits
//! ```
//!
//! Their paths, and every other path of a run: [`crate::run_dir`].

use serde::{Deserialize, Serialize};

/// Format tag of `manifest.json`.
pub const MANIFEST_FORMAT: &str = "stepsim-manifest-1";
/// Format tag of `datasets.json`.
pub const DATASETS_FORMAT: &str = "stepsim-datasets-1";

/// Facts about the instrument that participants need (public).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct InstrumentFacts {
    /// NAXIS1 of every image.
    pub width_px: u32,
    /// NAXIS2 of every image.
    pub height_px: u32,
    /// Pixel scale.
    pub pixel_scale_arcsec: f64,
    /// Electrons per ADU.
    pub gain_e_per_adu: f64,
    /// Read noise in electrons.
    pub read_noise_e: f64,
    /// Saturation level in ADU.
    pub saturation_adu: f64,
    /// Exposure time.
    pub exposure_s: f64,
    /// Magnitude giving 1 e⁻/s.
    pub zeropoint_mag: f64,
}

/// One public image.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ManifestImage {
    /// Opaque image id.
    pub image: String,
    /// Opaque dataset id.
    pub dataset: String,
    /// Path relative to `public/`.
    pub file: String,
    /// Hex SHA-256 of the file.
    pub sha256: String,
}

/// `public/manifest.json`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// [`MANIFEST_FORMAT`].
    pub format: String,
    /// Instrument facts.
    pub instrument: InstrumentFacts,
    /// Every image, sorted by dataset id then image id.
    pub images: Vec<ManifestImage>,
}

/// One image of a dataset (private).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DatasetImage {
    /// Opaque image id.
    pub image: String,
    /// Base field index (0-based); image k of every dataset shares field k.
    pub field: u32,
    /// True for the 90°-rotated twin of the base field.
    #[serde(default)]
    pub rotated: bool,
}

/// Which part of a challenge run a dataset belongs to.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Hash, Default)]
#[serde(rename_all = "snake_case")]
pub enum Part {
    /// Scored with feedback before reveal (the configured design).
    #[default]
    Public,
    /// Scored only at reveal (base fields and shears of its own).
    Holdout,
}

impl Part {
    /// True for [`Part::Public`] (`datasets.json` leaves the default out).
    pub fn is_public(&self) -> bool {
        *self == Part::Public
    }

    /// The name used in files and on the command line.
    pub fn name(&self) -> &'static str {
        match self {
            Part::Public => "public",
            Part::Holdout => "holdout",
        }
    }
}

/// One dataset (private).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DatasetEntry {
    /// Opaque dataset id.
    pub dataset: String,
    /// PSF index in the config (0..6 for STEP1, the paper's PSF ID).
    pub psf_id: u32,
    /// PSF name.
    pub psf: String,
    /// Applied g1.
    pub g1: f64,
    /// Applied g2.
    pub g2: f64,
    /// Its images.
    pub images: Vec<DatasetImage>,
    /// Which part of a challenge run it belongs to (absent: public, as in
    /// every run made without a `challenge` section).
    #[serde(default, skip_serializing_if = "Part::is_public")]
    pub part: Part,
}

/// `private/datasets.json`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Datasets {
    /// [`DATASETS_FORMAT`].
    pub format: String,
    /// NAXIS1.
    pub width_px: u32,
    /// NAXIS2.
    pub height_px: u32,
    /// Pixel scale.
    pub pixel_scale_arcsec: f64,
    /// Every dataset, PSF-major then shear.
    pub datasets: Vec<DatasetEntry>,
}
