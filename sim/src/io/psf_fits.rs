//! PSF images on disk (`RUN/private/psf/<name>.fits`, `stepsim psf`).
//!
//! Primary HDU: the pixel-convolved PSF at the image pixel scale; extension
//! `OVERSAMPLED`: the same PSF (still convolved with the image pixel)
//! sampled `OVERSAMP` times finer. Both are BITPIX −64, centred on pixel
//! (n/2 + 1, n/2 + 1) (FITS), normalised to unit sum. Header keywords:
//! `PIXSCALE` (arcsec of this HDU's samples), `OVERSAMP`, `PSFNAME`, plus
//! the caller's measurements (FWHM, χ, seeing, amplitude).

use fitsio::FitsFile;
use fitsio::hdu::HduInfo;
use fitsio::images::{ImageDescription, ImageType};
use std::path::Path;
use stepsim_contract::io::fits::{Primary, create_fits, open_fits};
use stepsim_contract::io::{IoError, write_atomically};

/// A square PSF image.
#[derive(Debug, Clone, Copy)]
pub struct PsfImage<'a> {
    /// Row-major values.
    pub data: &'a [f64],
    /// Side.
    pub n: usize,
    /// Sample spacing (arcsec).
    pub scale_arcsec: f64,
}

/// A numeric header keyword: (name ≤ 8 chars, value, comment).
pub type Keyword = (String, f64, String);

/// Writes the two PSF images atomically.
pub fn write_psf_fits(
    path: &Path,
    name: &str,
    at_pixel: PsfImage<'_>,
    oversampled: PsfImage<'_>,
    oversample: usize,
    keywords: &[Keyword],
) -> Result<(), IoError> {
    for img in [&at_pixel, &oversampled] {
        if img.data.len() != img.n * img.n {
            return Err(IoError::format(
                path,
                format!(
                    "PSF image has {} values, expected {}²",
                    img.data.len(),
                    img.n
                ),
            ));
        }
    }
    write_atomically(path, |tmp| {
        let fe = |e: fitsio::errors::Error| IoError::fits(path, e);
        let desc = ImageDescription {
            data_type: ImageType::Double,
            dimensions: &[at_pixel.n, at_pixel.n],
        };
        let mut f = create_fits(
            tmp,
            Primary {
                image: Some(&desc),
                rice: false,
            },
        )?;
        let hdu = f.primary_hdu().map_err(fe)?;
        hdu.write_image(&mut f, at_pixel.data).map_err(fe)?;
        let common = |f: &mut FitsFile, hdu: &fitsio::hdu::FitsHdu, scale: f64| {
            hdu.write_key(f, "PSFNAME", (name, "PSF name from the config"))?;
            hdu.write_key(f, "PIXSCALE", (scale, "arcsec per sample"))?;
            hdu.write_key(
                f,
                "OVERSAMP",
                (oversample as i64, "samples per image pixel (ext 1)"),
            )?;
            for (k, v, c) in keywords {
                hdu.write_key(f, k, (*v, c.as_str()))?;
            }
            Ok::<(), fitsio::errors::Error>(())
        };
        common(&mut f, &hdu, at_pixel.scale_arcsec).map_err(fe)?;
        let desc = ImageDescription {
            data_type: ImageType::Double,
            dimensions: &[oversampled.n, oversampled.n],
        };
        let ext = f.create_image("OVERSAMPLED", &desc).map_err(fe)?;
        ext.write_image(&mut f, oversampled.data).map_err(fe)?;
        common(&mut f, &ext, oversampled.scale_arcsec).map_err(fe)?;
        stepsim_contract::io::fits::finish_fits(f, path)
    })
}

/// Smallest side in pixels of the pixel-scale PSF image written by default
/// (`stepsim psf` without `--size-px`, and the run's `private/psf/` files);
/// see [`renderer_side_px`].
pub const DEFAULT_SIZE_PX: usize = 128;

/// Side (pixels, even) of the PSF images written by default: the extent the
/// split renderer gives the PSF around every object, ±[`kernel_margin_px`]
/// (beyond it the PSF is below 1e-7 of its peak and holds < 1e-5 of the
/// flux), and at least [`DEFAULT_SIZE_PX`]. 328 for the STEP1 PSFs at
/// 0.206″ (±163 px); a 128² file missed 1.1e-3 of their flux.
///
/// [`kernel_margin_px`]: crate::model::render::split::kernel_margin_px
pub fn renderer_side_px(
    psf: &dyn crate::model::psf::Psf,
    pixel_scale_arcsec: f64,
    max_stamp_px: usize,
) -> usize {
    let m = crate::model::render::split::kernel_margin_px(psf, pixel_scale_arcsec, max_stamp_px);
    (2 * m + 2).max(DEFAULT_SIZE_PX)
}
/// Samples per pixel of the oversampled PSF image written by default.
pub const DEFAULT_OVERSAMPLE: usize = 4;

/// Draws `psf` at `side_px` pixels (and [`DEFAULT_OVERSAMPLE`] times
/// finer), measures it and writes the file `path` with the report in the
/// header: a run's `private/psf/<name>.fits`.
pub fn draw_and_write(
    path: &Path,
    psf: &dyn crate::model::psf::Psf,
    name: &str,
    pixel_scale_arcsec: f64,
    side_px: usize,
) -> Result<(), IoError> {
    let report = crate::model::psf::report(name, psf, pixel_scale_arcsec)
        .map_err(|e| IoError::format(path, e.to_string()))?;
    let drawn = crate::model::psf::draw_for_file(
        name,
        psf,
        pixel_scale_arcsec,
        side_px,
        DEFAULT_OVERSAMPLE,
        Some(report),
    );
    write_psf(path, &drawn)
}

/// Writes a drawn PSF ([`crate::model::psf::draw_for_file`]) to
/// `RUN/private/psf/<name>.fits` (or any path): the pixel-scale image in the
/// primary HDU, the fine one in `OVERSAMPLED`, with the report's FWHM, χ and
/// calibration in the headers when given. This is what `stepsim psf` and the
/// generate step write.
pub fn write_psf(path: &Path, drawn: &crate::model::psf::DrawnPsf) -> Result<(), IoError> {
    let (n, oversample, p) = (drawn.n, drawn.oversample, drawn.pixel_scale_arcsec);
    let mut keys: Vec<Keyword> = Vec::new();
    if let Some(r) = &drawn.report {
        keys.push((
            "FWHM".into(),
            r.fwhm_arcsec,
            "arcsec, area above half max".into(),
        ));
        keys.push(("CHI1".into(), r.chi1, "adaptive-moment distortion".into()));
        keys.push(("CHI2".into(), r.chi2, "adaptive-moment distortion".into()));
        if let (Some(s), Some(a)) = (r.seeing_fwhm_arcsec, r.amplitude) {
            keys.push(("SEEING".into(), s, "arcsec, atmosphere alone".into()));
            keys.push((
                "AMPLITUD".into(),
                a,
                r.amplitude_unit.clone().unwrap_or_default(),
            ));
        }
    }
    write_psf_fits(
        path,
        &drawn.name,
        PsfImage {
            data: &drawn.at_pixel,
            n,
            scale_arcsec: p,
        },
        PsfImage {
            data: &drawn.oversampled,
            n: n * oversample,
            scale_arcsec: p / oversample as f64,
        },
        oversample,
        &keys,
    )
}

/// Reads the primary image of a FITS file: (values row-major, nx, ny).
pub fn read_psf_fits(path: &Path) -> Result<(Vec<f64>, usize, usize), IoError> {
    read_image_hdu(path, None)
}

/// A PSF image as [`read_psf_fits`] returns it: row-major values, nx, ny.
pub type PsfValues = (Vec<f64>, usize, usize);

/// [`read_psf_fits`], also handing back the file's bytes (what a run keeps
/// a copy of). cfitsio reads the file by name, so the bytes are a second
/// read of it.
pub fn read_psf_fits_and_bytes(path: &Path) -> Result<(PsfValues, Vec<u8>), IoError> {
    let image = read_psf_fits(path)?;
    let bytes = std::fs::read(path).map_err(|e| IoError::os(path, e))?;
    Ok((image, bytes))
}

/// Reads a 2-D image HDU (`None`: the primary, else by EXTNAME).
pub fn read_image_hdu(
    path: &Path,
    extname: Option<&str>,
) -> Result<(Vec<f64>, usize, usize), IoError> {
    let fe = |e: fitsio::errors::Error| IoError::fits(path, e);
    if !path.exists() {
        return Err(IoError::os(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        ));
    }
    let mut f = open_fits(path)?;
    let hdu = match extname {
        None => f.primary_hdu().map_err(fe)?,
        Some(name) => f.hdu(name).map_err(fe)?,
    };
    let (ny, nx) = match &hdu.info {
        HduInfo::ImageInfo { shape, .. } if shape.len() == 2 => (shape[0], shape[1]),
        HduInfo::ImageInfo { shape, .. } => {
            return Err(IoError::format(
                path,
                format!(
                    "primary HDU is {}-dimensional, expected a 2-D image",
                    shape.len()
                ),
            ));
        }
        _ => return Err(IoError::format(path, "primary HDU is not an image")),
    };
    let data: Vec<f64> = hdu.read_image(&mut f).map_err(fe)?;
    Ok((data, nx, ny))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_missing_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("psf/p.fits");
        let a: Vec<f64> = (0..16).map(f64::from).collect();
        let b: Vec<f64> = (0..64).map(|i| f64::from(i) * 0.5).collect();
        write_psf_fits(
            &path,
            "p",
            PsfImage {
                data: &a,
                n: 4,
                scale_arcsec: 0.2,
            },
            PsfImage {
                data: &b,
                n: 8,
                scale_arcsec: 0.1,
            },
            2,
            &[("FWHM".into(), 0.9, "arcsec".into())],
        )
        .unwrap();
        let (v, nx, ny) = read_psf_fits(&path).unwrap();
        assert_eq!((nx, ny), (4, 4));
        assert_eq!(v, a);
        let (w, nx, _) = read_image_hdu(&path, Some("OVERSAMPLED")).unwrap();
        assert_eq!((nx, w), (8, b.clone()));
        let err = read_psf_fits(&dir.path().join("nope.fits")).unwrap_err();
        assert!(err.to_string().contains("nope.fits"), "{err}");
        // Nothing else left in the directory.
        assert_eq!(
            std::fs::read_dir(dir.path().join("psf")).unwrap().count(),
            1
        );
    }

    #[test]
    fn psf_files_cover_the_renderer_extent() {
        // STEP1 PSF 0 at 0.206″: the file reaches ±163 px like the image
        // kernel; 1.1e-3 of the flux lies outside the central 128² (what the
        // old 128² file left out), and the outer border holds almost nothing
        // (no wrapped wings).
        let p = 0.206;
        let psf = crate::model::psf::build(&crate::model::psf::PsfSpec::step1(0, p)).unwrap();
        let n = renderer_side_px(psf.as_ref(), p, 1024);
        assert_eq!(n, 328);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("none.fits");
        write_psf(
            &path,
            &crate::model::psf::draw_for_file("none", psf.as_ref(), p, n, 1, None),
        )
        .unwrap();
        let (v, nx, ny) = read_psf_fits(&path).unwrap();
        assert_eq!((nx, ny), (328, 328));
        let total: f64 = v.iter().sum();
        let (lo, hi) = (n / 2 - 64, n / 2 + 64);
        let mut core = 0.0;
        let mut border = 0.0;
        for (k, &x) in v.iter().enumerate() {
            let (i, j) = (k % n, k / n);
            if (lo..hi).contains(&i) && (lo..hi).contains(&j) {
                core += x;
            }
            if i < 2 || j < 2 || i >= n - 2 || j >= n - 2 {
                border += x;
            }
        }
        let outside = total - core;
        eprintln!("sum {total}, outside the central 128²: {outside:.3e}, border {border:.2e}");
        assert!((total - 1.0).abs() < 1e-9, "{total}");
        assert!(outside > 9e-4 && outside < 1.3e-3, "{outside}");
        assert!(border.abs() < 1e-6, "{border}");
        // A Gaussian needs no more than the smallest default side.
        let g = crate::model::psf::GaussianPsf::round(0.9);
        assert_eq!(renderer_side_px(&g, p, 1024), DEFAULT_SIZE_PX);
    }
}
