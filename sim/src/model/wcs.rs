//! TAN (gnomonic) world coordinate system of the images (FITS WCS paper II).
//!
//! Every image of a run has the same WCS: the reference pixel is the image
//! centre, the reference point is (`image.field_ra_deg`,
//! `image.field_dec_deg`) whatever the base field, north is +y and east is
//! −x (the usual sky orientation), and the scale is the pixel scale with no
//! rotation: CD = [[−s, 0], [0, s]] with s in degrees.
//!
//! One position for all, not one per base field: a run with held-out
//! datasets puts them on base fields of their own, so a per-field position
//! grouped the public images into exactly the public and the held-out
//! datasets (issue #23). With one WCS every public header is the same.

/// The geometry of every image of a run: size, pixel scale and the sky
/// position of its centre (made by the plan from the `image` section).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geometry {
    /// NAXIS1.
    pub width_px: u32,
    /// NAXIS2.
    pub height_px: u32,
    /// Pixel scale (arcsec).
    pub pixel_scale_arcsec: f64,
    /// Right ascension of the TAN WCS reference point (the image centre).
    pub ra_deg: f64,
    /// Declination of the TAN WCS reference point.
    pub dec_deg: f64,
}

impl Geometry {
    /// STEP1's images (4096², 0.206″) at the config's default position
    /// (150°, 2°).
    pub fn step1() -> Self {
        Self {
            width_px: 4096,
            height_px: 4096,
            pixel_scale_arcsec: 0.206,
            ra_deg: 150.0,
            dec_deg: 2.0,
        }
    }
}

/// A TAN WCS with a diagonal CD matrix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TanWcs {
    /// CRVAL1: right ascension of the reference point (deg).
    pub crval1: f64,
    /// CRVAL2: declination of the reference point (deg).
    pub crval2: f64,
    /// CRPIX1 (FITS pixels).
    pub crpix1: f64,
    /// CRPIX2.
    pub crpix2: f64,
    /// CD1_1 (deg per pixel, negative: east to the left).
    pub cd1_1: f64,
    /// CD2_2 (deg per pixel).
    pub cd2_2: f64,
}

impl TanWcs {
    /// The WCS of every image of geometry `image`.
    pub fn of_images(image: &Geometry) -> Self {
        let s = image.pixel_scale_arcsec / 3600.0;
        Self {
            crval1: image.ra_deg,
            crval2: image.dec_deg,
            crpix1: (f64::from(image.width_px) + 1.0) / 2.0,
            crpix2: (f64::from(image.height_px) + 1.0) / 2.0,
            cd1_1: -s,
            cd2_2: s,
        }
    }

    /// FITS pixel (x, y) to (ra, dec) in degrees.
    pub fn pixel_to_sky(&self, x: f64, y: f64) -> (f64, f64) {
        // Intermediate world coordinates (radians on the tangent plane).
        let xi = (self.cd1_1 * (x - self.crpix1)).to_radians();
        let eta = (self.cd2_2 * (y - self.crpix2)).to_radians();
        let (a0, d0) = (self.crval1.to_radians(), self.crval2.to_radians());
        let denom = d0.cos() - eta * d0.sin();
        let a = a0 + xi.atan2(denom);
        let d = (d0.sin() + eta * d0.cos()).atan2(xi.hypot(denom));
        (a.to_degrees().rem_euclid(360.0), d.to_degrees())
    }

    /// (ra, dec) in degrees to FITS pixel (x, y).
    pub fn sky_to_pixel(&self, ra: f64, dec: f64) -> (f64, f64) {
        let (a, d) = (ra.to_radians(), dec.to_radians());
        let (a0, d0) = (self.crval1.to_radians(), self.crval2.to_radians());
        let cos_c = d0.sin() * d.sin() + d0.cos() * d.cos() * (a - a0).cos();
        let xi = d.cos() * (a - a0).sin() / cos_c;
        let eta = (d0.cos() * d.sin() - d0.sin() * d.cos() * (a - a0).cos()) / cos_c;
        (
            xi.to_degrees() / self.cd1_1 + self.crpix1,
            eta.to_degrees() / self.cd2_2 + self.crpix2,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_pixel_maps_to_reference_point_and_round_trips() {
        let img = Geometry::step1();
        let w = TanWcs::of_images(&img);
        let (ra, dec) = w.pixel_to_sky(w.crpix1, w.crpix2);
        assert!((ra - w.crval1).abs() < 1e-12 && (dec - w.crval2).abs() < 1e-12);
        assert_eq!((w.crval1, w.crval2), (150.0, 2.0));
        assert_eq!((w.crpix1, w.crpix2), (2048.5, 2048.5));
        for (x, y) in [
            (1.0, 1.0),
            (4096.0, 1.0),
            (2000.5, 3999.25),
            (-50.0, 4200.0),
        ] {
            let (ra, dec) = w.pixel_to_sky(x, y);
            let (x2, y2) = w.sky_to_pixel(ra, dec);
            assert!(
                (x - x2).abs() < 1e-7 && (y - y2).abs() < 1e-7,
                "{x},{y} -> {x2},{y2}"
            );
        }
    }

    #[test]
    fn scale_and_orientation() {
        let w = TanWcs::of_images(&Geometry::step1());
        // One pixel north (+y) is 0.206″ of declination.
        let (_, d0) = w.pixel_to_sky(w.crpix1, w.crpix2);
        let (_, d1) = w.pixel_to_sky(w.crpix1, w.crpix2 + 1.0);
        assert!(((d1 - d0) * 3600.0 - 0.206).abs() < 1e-9);
        // One pixel to +x is west: RA decreases by 0.206″ / cos(dec).
        let (a0, _) = w.pixel_to_sky(w.crpix1, w.crpix2);
        let (a1, _) = w.pixel_to_sky(w.crpix1 + 1.0, w.crpix2);
        let want = -0.206 / 2f64.to_radians().cos();
        assert!(((a1 - a0) * 3600.0 - want).abs() < 1e-6);
    }
}
