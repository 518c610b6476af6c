//! What a PSF is built from: the model and its targets ([`PsfModel`]), the
//! telescope ([`Telescope`]), the image pixel scale and, for a `fits` model,
//! the image the plan read ([`PsfSpec`]).
//!
//! These are the model's own types: the plan makes them from the config's
//! `psfs` and `telescope` sections (`crate::run::plan::Plan::psf_spec`). The
//! types the config spells exactly as the model does ([`Telescope`],
//! [`Aberration`]) carry their serde derives here and the config imports
//! them (ARCHITECTURE.md, "Configs in two layers").

use super::PsfFileImage;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// The optical aberration of an `optical` PSF.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Aberration {
    /// No aberration (PSF 0).
    None,
    /// Coma, Zernike Z7 (PSF 1).
    Coma,
    /// Tracking error: the optical PSF smeared along a line (PSF 2).
    Jitter,
    /// Defocus, Zernike Z4 (PSF 3).
    Defocus,
    /// Astigmatism, Zernike Z5/Z6 (PSF 4).
    Astigmatism,
    /// Trefoil, Zernike Z9/Z10 (PSF 5).
    Trefoil,
    /// Primary spherical aberration, Zernike Z11.
    Spherical,
}

/// The pupil and wavelength of the optical PSF models (SPEC §3 defaults:
/// CFHT-like, as SkyMaker's); the config's `telescope` section.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Telescope {
    /// Primary mirror diameter.
    pub diameter_m: f64,
    /// Central obstruction diameter.
    pub obstruction_m: f64,
    /// Number of spider arms (0 for none).
    pub spider_arms: u32,
    /// Thickness of each arm.
    pub spider_width_m: f64,
    /// Angle of the first arm from the +x axis.
    pub spider_angle_deg: f64,
    /// Central wavelength.
    pub wavelength_um: f64,
}

impl Default for Telescope {
    fn default() -> Self {
        Self {
            diameter_m: 3.6,
            obstruction_m: 1.0,
            spider_arms: 4,
            spider_width_m: 0.02,
            spider_angle_deg: 0.0,
            wavelength_um: 0.8,
        }
    }
}

/// One PSF model with its parameters. Serialised as the config spells a
/// `psfs` entry's model (tag `model`): that text keys the PSF store
/// (`crate::io::psf_store::spec_digest`).
#[derive(Debug, Clone, Serialize, PartialEq)]
#[serde(tag = "model", rename_all = "snake_case")]
pub enum PsfModel {
    /// Telescope optics + aberration + Kolmogorov seeing + pixel.
    Optical {
        /// The aberration.
        aberration: Aberration,
        /// Aberration amplitude in waves (or, for jitter, the smear σ in
        /// arcsec); `None`: solved for `target_chi`, or a documented
        /// default ([`super::default_amplitude`]).
        amplitude: Option<f64>,
        /// Target adaptive-moment distortion |χ| of the pixel-convolved PSF.
        target_chi: Option<f64>,
        /// Orientation of the aberration (degrees from +x).
        angle_deg: f64,
    },
    /// Elliptical Gaussian.
    Gaussian {
        /// Ellipticity component e1 (eq. 1 convention).
        e1: f64,
        /// Ellipticity component e2.
        e2: f64,
    },
    /// Moffat profile.
    Moffat {
        /// Moffat β.
        beta: f64,
        /// Truncation radius in units of the FWHM (0 for none).
        trunc_fwhm: f64,
    },
    /// A PSF image (the plan reads the file: [`PsfSpec::image`]).
    Fits {
        /// The file's name as the config gives it (in messages only).
        path: String,
        /// Pixel scale of the image.
        pixel_scale_arcsec: f64,
    },
}

/// Everything one PSF is built from: its name, target FWHM and model, the
/// telescope, the image pixel scale and, for a `fits` model, the image the
/// plan read (`crate::run::plan::Plan::psf_spec` hands these out).
#[derive(Debug, Clone, PartialEq)]
pub struct PsfSpec {
    /// Name (in messages and file names; private).
    pub name: String,
    /// Target FWHM of the pixel-convolved PSF (arcsec).
    pub fwhm_arcsec: f64,
    /// The model.
    pub model: PsfModel,
    /// The telescope (optical PSFs).
    pub telescope: Telescope,
    /// Pixel scale the PSF is calibrated for (arcsec).
    pub pixel_scale_arcsec: f64,
    /// The file's image for a `fits` model (`None` for the others).
    pub image: Option<Arc<PsfFileImage>>,
}

impl PsfSpec {
    /// The spec of a model that needs no file (every model but `fits`).
    pub fn new(
        name: &str,
        fwhm_arcsec: f64,
        model: PsfModel,
        telescope: Telescope,
        pixel_scale_arcsec: f64,
    ) -> Self {
        Self {
            name: name.into(),
            fwhm_arcsec,
            model,
            telescope,
            pixel_scale_arcsec,
            image: None,
        }
    }

    /// STEP1 PSF `index` ([`STEP1_PSFS`]) with the default telescope.
    ///
    /// # Panics
    /// When `index` ≥ 6.
    pub fn step1(index: usize, pixel_scale_arcsec: f64) -> Self {
        let (name, aberration, target_chi) = STEP1_PSFS[index];
        let model = PsfModel::Optical {
            aberration,
            amplitude: None,
            target_chi,
            angle_deg: 0.0,
        };
        Self::new(name, 0.9, model, Telescope::default(), pixel_scale_arcsec)
    }

    /// Whether the model is `optical` (the expensive, stored kind).
    pub fn is_optical(&self) -> bool {
        matches!(self.model, PsfModel::Optical { .. })
    }

    /// The model and targets as the config spells the PSF's entry
    /// (`{"name", "fwhm_arcsec", "model", ...}`): what identifies the PSF
    /// in the store's key.
    pub fn entry_json(&self) -> String {
        #[derive(Serialize)]
        struct Entry<'a> {
            name: &'a str,
            fwhm_arcsec: f64,
            #[serde(flatten)]
            model: &'a PsfModel,
        }
        serde_json::to_string(&Entry {
            name: &self.name,
            fwhm_arcsec: self.fwhm_arcsec,
            model: &self.model,
        })
        .expect("a PSF entry serialises")
    }
}

/// The six STEP1 PSFs of SPEC §3 / paper Table 3 as (name, aberration,
/// target χ): FWHM 0.9″, angle 0, amplitude solved or defaulted.
pub const STEP1_PSFS: [(&str, Aberration, Option<f64>); 6] = [
    ("none", Aberration::None, None),
    ("coma", Aberration::Coma, Some(0.040)),
    ("jitter", Aberration::Jitter, Some(0.080)),
    ("defocus", Aberration::Defocus, None),
    ("astigmatism", Aberration::Astigmatism, None),
    ("trefoil", Aberration::Trefoil, None),
];
