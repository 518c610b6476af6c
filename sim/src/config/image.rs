//! Image geometry, detector and telescope sections of the config.

use super::{Invalid, check_positive, check_range};
use serde::{Deserialize, Serialize};

/// Allowed `image.pixel_scale_arcsec`.
pub const PIXEL_SCALE_RANGE_ARCSEC: (f64, f64) = (0.03, 5.0);

/// `image`: geometry of every simulated image and the number of base fields.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RawImage {
    /// NAXIS1.
    pub width_px: u32,
    /// NAXIS2.
    pub height_px: u32,
    /// Pixel scale (STEP1: 0.206″).
    pub pixel_scale_arcsec: f64,
    /// Images per dataset = number of base fields (STEP1: 64).
    pub n_images: u32,
    /// Objects are placed over the image plus this margin on every side, so
    /// that objects near the edge are partly on the image.
    pub margin_arcsec: f64,
    /// Right ascension of the TAN WCS reference point of every image.
    pub field_ra_deg: f64,
    /// Declination of the TAN WCS reference point of every image.
    pub field_dec_deg: f64,
    /// Accepted (and range-checked) so that older configs still parse, but
    /// it has no effect since output version 3: every image has the same
    /// reference point ([`crate::wcs`]). It used to put base field k
    /// `k × field_spacing_deg` east of field 0, which told the held-out
    /// datasets from the public ones (issue #23).
    pub field_spacing_deg: f64,
}

impl Default for RawImage {
    fn default() -> Self {
        Self {
            width_px: 4096,
            height_px: 4096,
            pixel_scale_arcsec: 0.206,
            n_images: 64,
            margin_arcsec: 10.0,
            field_ra_deg: 150.0,
            field_dec_deg: 2.0,
            field_spacing_deg: 1.0,
        }
    }
}

impl RawImage {
    pub(crate) fn validate(&self) -> Result<(), Invalid> {
        for (k, v) in [
            ("image.width_px", self.width_px),
            ("image.height_px", self.height_px),
            ("image.n_images", self.n_images),
        ] {
            if v == 0 || v > 65_536 {
                return Err(Invalid::new(
                    k.into(),
                    format!("must be in [1, 65536], got {v}"),
                ));
            }
        }
        // 0.03″ (JWST-like sampling) to 5″ per pixel. Finer scales cost
        // memory as the square of 1/scale (measuring a PSF for its file takes
        // 2.8 GiB at 0.05″, 21 GiB at 0.01″) and no imager samples finer.
        check_range(
            "image.pixel_scale_arcsec",
            self.pixel_scale_arcsec,
            PIXEL_SCALE_RANGE_ARCSEC.0,
            PIXEL_SCALE_RANGE_ARCSEC.1,
        )?;
        check_range("image.margin_arcsec", self.margin_arcsec, 0.0, 600.0)?;
        check_range("image.field_ra_deg", self.field_ra_deg, 0.0, 360.0)?;
        check_range("image.field_dec_deg", self.field_dec_deg, -89.0, 89.0)?;
        check_range("image.field_spacing_deg", self.field_spacing_deg, 0.0, 10.0)?;
        Ok(())
    }

    /// Image area in arcmin².
    pub fn area_arcmin2(&self) -> f64 {
        let s = self.pixel_scale_arcsec / 60.0;
        f64::from(self.width_px) * f64::from(self.height_px) * s * s
    }
}

/// `instrument`: sky, exposure and detector (SPEC §4 defaults).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RawInstrument {
    /// Sky surface brightness, I band, Vega (STEP1: 19.2 mag arcsec⁻²).
    pub sky_mag_arcsec2: f64,
    /// Magnitude giving 1 e⁻/s.
    pub zeropoint_mag: f64,
    /// Exposure time.
    pub exposure_s: f64,
    /// Electrons per ADU.
    pub gain_e_per_adu: f64,
    /// Gaussian read noise, electrons rms.
    pub read_noise_e: f64,
    /// Pixel values are clipped here (ADU) and SATURATE is written.
    pub saturation_adu: f64,
}

impl Default for RawInstrument {
    fn default() -> Self {
        Self {
            sky_mag_arcsec2: 19.2,
            zeropoint_mag: 26.0,
            exposure_s: 3600.0,
            gain_e_per_adu: 4.0,
            read_noise_e: 5.0,
            saturation_adu: 65535.0,
        }
    }
}

impl RawInstrument {
    pub(crate) fn validate(&self) -> Result<(), Invalid> {
        check_range(
            "instrument.sky_mag_arcsec2",
            self.sky_mag_arcsec2,
            0.0,
            40.0,
        )?;
        check_range("instrument.zeropoint_mag", self.zeropoint_mag, 0.0, 50.0)?;
        // 1 ms to ~11.6 days; the sky must also stay below saturation
        // (checked with the pixel scale in `Plan::new`).
        check_range("instrument.exposure_s", self.exposure_s, 1e-3, 1e6)?;
        check_range(
            "instrument.gain_e_per_adu",
            self.gain_e_per_adu,
            0.01,
            1000.0,
        )?;
        check_range("instrument.read_noise_e", self.read_noise_e, 0.0, 1e4)?;
        // Up to the largest int32 (the integer output format).
        check_range(
            "instrument.saturation_adu",
            self.saturation_adu,
            1.0,
            2_147_483_647.0,
        )?;
        Ok(())
    }

    /// Effective zeropoint: m = zp_eff − 2.5 log10(electrons) (SPEC §1).
    pub fn zp_eff(&self) -> f64 {
        self.zeropoint_mag + 2.5 * self.exposure_s.log10()
    }

    /// Total electrons of a source of magnitude `mag`.
    pub fn mag_to_electrons(&self, mag: f64) -> f64 {
        10f64.powf(-0.4 * (mag - self.zp_eff()))
    }

    /// Magnitude of a source with `electrons` in total.
    pub fn electrons_to_mag(&self, electrons: f64) -> f64 {
        self.zp_eff() - 2.5 * electrons.log10()
    }
}

/// `telescope`: the pupil and wavelength of the optical PSF models
/// (SPEC §3 defaults: CFHT-like, as SkyMaker's).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct RawTelescope {
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

impl Default for RawTelescope {
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

impl RawTelescope {
    pub(crate) fn validate(&self) -> Result<(), Invalid> {
        check_positive("telescope.diameter_m", self.diameter_m)?;
        check_range(
            "telescope.obstruction_m",
            self.obstruction_m,
            0.0,
            self.diameter_m * 0.95,
        )?;
        if self.spider_arms > 16 {
            return Err(Invalid::new(
                "telescope.spider_arms".into(),
                format!("must be ≤ 16, got {}", self.spider_arms),
            ));
        }
        check_range(
            "telescope.spider_width_m",
            self.spider_width_m,
            0.0,
            self.diameter_m / 4.0,
        )?;
        check_range(
            "telescope.spider_angle_deg",
            self.spider_angle_deg,
            -360.0,
            360.0,
        )?;
        check_range("telescope.wavelength_um", self.wavelength_um, 0.1, 30.0)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn magnitudes_and_electrons_are_inverse() {
        let ins = RawInstrument::default();
        // zp_eff = 26 + 2.5 log10(3600) = 26 + 8.890756... = 34.890756...
        assert!((ins.zp_eff() - (26.0 + 2.5 * 3600f64.log10())).abs() < 1e-12);
        assert!((ins.zp_eff() - 34.890_756).abs() < 1e-6);
        // A 26th-magnitude source gives 1 e-/s, i.e. 3600 e- in 3600 s.
        assert!((ins.mag_to_electrons(26.0) - 3600.0).abs() < 1e-6);
        for m in [17.0, 20.5, 24.0, 27.3] {
            assert!((ins.electrons_to_mag(ins.mag_to_electrons(m)) - m).abs() < 1e-12);
        }
    }

    #[test]
    fn step1_area() {
        // 4096 × 0.206″ = 843.776″ = 14.0629′ on a side, 197.766 arcmin².
        let a = RawImage::default().area_arcmin2();
        assert!((a - 197.766_094).abs() < 1e-5, "{a}");
    }
}
