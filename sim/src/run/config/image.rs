//! Image geometry, detector and telescope sections of the config (the
//! `instrument` and `telescope` types are the models' own: [`Instrument`],
//! [`Telescope`]; their range checks are here).

use super::{Invalid, check_positive, check_range};
use crate::model::noise::Instrument;
use crate::model::psf::Telescope;
use crate::model::wcs::Geometry;
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
    /// reference point ([`crate::model::wcs`]). It used to put base field k
    /// `k × field_spacing_deg` east of field 0, which told the held-out
    /// datasets from the public ones (issue #23).
    pub field_spacing_deg: f64,
}

impl Default for RawImage {
    /// STEP1's images ([`Geometry::step1`]), 64 base fields.
    fn default() -> Self {
        let g = Geometry::step1();
        Self {
            width_px: g.width_px,
            height_px: g.height_px,
            pixel_scale_arcsec: g.pixel_scale_arcsec,
            n_images: 64,
            margin_arcsec: 10.0,
            field_ra_deg: g.ra_deg,
            field_dec_deg: g.dec_deg,
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

/// Range checks of the `instrument` section.
pub(crate) fn validate_instrument(ins: &Instrument) -> Result<(), Invalid> {
    check_range("instrument.sky_mag_arcsec2", ins.sky_mag_arcsec2, 0.0, 40.0)?;
    check_range("instrument.zeropoint_mag", ins.zeropoint_mag, 0.0, 50.0)?;
    // 1 ms to ~11.6 days; the sky must also stay below saturation
    // (checked with the pixel scale in `Plan::new`).
    check_range("instrument.exposure_s", ins.exposure_s, 1e-3, 1e6)?;
    check_range(
        "instrument.gain_e_per_adu",
        ins.gain_e_per_adu,
        0.01,
        1000.0,
    )?;
    check_range("instrument.read_noise_e", ins.read_noise_e, 0.0, 1e4)?;
    // Up to the largest int32 (the integer output format).
    check_range(
        "instrument.saturation_adu",
        ins.saturation_adu,
        1.0,
        2_147_483_647.0,
    )?;
    Ok(())
}

/// Range checks of the `telescope` section.
pub(crate) fn validate_telescope(tel: &Telescope) -> Result<(), Invalid> {
    check_positive("telescope.diameter_m", tel.diameter_m)?;
    check_range(
        "telescope.obstruction_m",
        tel.obstruction_m,
        0.0,
        tel.diameter_m * 0.95,
    )?;
    if tel.spider_arms > 16 {
        return Err(Invalid::new(
            "telescope.spider_arms".into(),
            format!("must be ≤ 16, got {}", tel.spider_arms),
        ));
    }
    check_range(
        "telescope.spider_width_m",
        tel.spider_width_m,
        0.0,
        tel.diameter_m / 4.0,
    )?;
    check_range(
        "telescope.spider_angle_deg",
        tel.spider_angle_deg,
        -360.0,
        360.0,
    )?;
    check_range("telescope.wavelength_um", tel.wavelength_um, 0.1, 30.0)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn magnitudes_and_electrons_are_inverse() {
        let ins = Instrument::default();
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
