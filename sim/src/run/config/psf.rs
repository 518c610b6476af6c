//! `psfs` section: one entry per PSF model (SPEC §3).

use super::{Invalid, check_positive, check_range};
use crate::model::psf::Aberration;
use serde::{Deserialize, Serialize};

/// One PSF model, tagged by `model`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, tag = "model", rename_all = "snake_case")]
pub enum RawPsfModel {
    /// Telescope optics + aberration + Kolmogorov seeing + pixel.
    Optical {
        /// The aberration.
        aberration: Aberration,
        /// Aberration amplitude in waves (rms over the unobstructed pupil,
        /// Noll-normalised Zernike), or for `jitter` the σ in arcsec of the
        /// 1-D Gaussian smear. When absent and `target_chi` is given, it is
        /// solved for; when both are absent a documented default is used
        /// (`psf::default_amplitude`, docs/psf.md).
        #[serde(default)]
        amplitude: Option<f64>,
        /// Target adaptive-moment distortion |χ| of the pixel-convolved PSF.
        #[serde(default)]
        target_chi: Option<f64>,
        /// Orientation of the aberration: the Zernike pattern is rotated
        /// counter-clockwise by this angle, or the jitter smear runs at it
        /// (degrees from +x).
        #[serde(default)]
        angle_deg: f64,
    },
    /// Elliptical Gaussian (tests and quick runs).
    Gaussian {
        /// Ellipticity component e1 (eq. 1 convention).
        #[serde(default)]
        e1: f64,
        /// Ellipticity component e2.
        #[serde(default)]
        e2: f64,
    },
    /// Moffat profile.
    Moffat {
        /// Moffat β.
        beta: f64,
        /// Truncation radius in units of the FWHM (0 for none).
        #[serde(default)]
        trunc_fwhm: f64,
    },
    /// A PSF image read from a FITS file (primary HDU).
    Fits {
        /// Path to the file.
        path: String,
        /// Pixel scale of the image.
        pixel_scale_arcsec: f64,
    },
}

/// One entry of `psfs`. (Unknown keys are refused by the flattened, tagged
/// [`RawPsfModel`]: serde's `deny_unknown_fields` cannot sit beside `flatten`.)
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct RawPsf {
    /// Name (private: never written to the public half).
    pub name: String,
    /// Target FWHM of the pixel-convolved PSF (STEP1: 0.9″). For optical
    /// PSFs the seeing is solved for; Gaussian and Moffat take it directly.
    #[serde(default = "default_fwhm")]
    pub fwhm_arcsec: f64,
    /// The model.
    #[serde(flatten)]
    pub model: RawPsfModel,
}

fn default_fwhm() -> f64 {
    0.9
}

impl RawPsf {
    /// The six STEP1 PSFs of SPEC §3 / paper Table 3.
    pub fn step1_set() -> Vec<Self> {
        crate::model::psf::STEP1_PSFS
            .iter()
            .map(|&(name, aberration, target_chi)| RawPsf {
                name: name.into(),
                fwhm_arcsec: 0.9,
                model: RawPsfModel::Optical {
                    aberration,
                    amplitude: None,
                    target_chi,
                    angle_deg: 0.0,
                },
            })
            .collect()
    }

    pub(crate) fn validate(&self) -> Result<(), Invalid> {
        if self.name.is_empty()
            || !self
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        {
            return Err(Invalid::new(
                "name".into(),
                format!("must be non-empty [A-Za-z0-9_-], got {:?}", self.name),
            ));
        }
        check_range("fwhm_arcsec", self.fwhm_arcsec, 0.01, 30.0)?;
        match &self.model {
            RawPsfModel::Optical {
                amplitude,
                target_chi,
                ..
            } => {
                if let Some(a) = amplitude {
                    check_range("amplitude", *a, -100.0, 100.0)?;
                }
                if let Some(c) = target_chi {
                    check_range("target_chi", *c, 0.0, 0.9)?;
                }
            }
            RawPsfModel::Gaussian { e1, e2 } => {
                if e1.hypot(*e2) >= 1.0 || !e1.is_finite() || !e2.is_finite() {
                    return Err(Invalid::new(
                        "e1".into(),
                        format!("|e| must be < 1, got ({e1}, {e2})"),
                    ));
                }
            }
            RawPsfModel::Moffat { beta, trunc_fwhm } => {
                check_range("beta", *beta, 1.1, 100.0)?;
                check_range("trunc_fwhm", *trunc_fwhm, 0.0, 1000.0)?;
            }
            RawPsfModel::Fits {
                path,
                pixel_scale_arcsec,
            } => {
                if path.is_empty() {
                    return Err(Invalid::new("path".into(), "empty path".into()));
                }
                check_positive("pixel_scale_arcsec", *pixel_scale_arcsec)?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use crate::run::config::RawConfig;
    use std::path::Path;

    #[test]
    fn unknown_psf_keys_and_models_are_refused() {
        let ok = r#"{"psfs": [{"name": "g", "model": "gaussian", "e1": 0.1}]}"#;
        let raw = RawConfig::parse(ok, Path::new("t.json"), &[]).unwrap();
        assert_eq!(raw.psfs[0].fwhm_arcsec, 0.9);
        for bad in [
            r#"{"psfs": [{"name": "g", "model": "gaussian", "e3": 0.1}]}"#,
            r#"{"psfs": [{"name": "g", "model": "lorentz"}]}"#,
            r#"{"psfs": [{"name": "g"}]}"#,
        ] {
            let err = RawConfig::parse(bad, Path::new("t.json"), &[])
                .unwrap_err()
                .to_string();
            assert!(err.contains("psfs[0]"), "{err}");
        }
    }
}
