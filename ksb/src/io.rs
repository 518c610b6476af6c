//! Files: the public manifest, FITS images, and the submission table.

use crate::error::KsbError;
use crate::image::Image;
use crate::pipeline::MeasuredObject;
use std::fmt::Write as _;
use std::path::Path;
use stepsim_contract::io::fits::{Primary, create_fits, finish_fits};
use stepsim_contract::io::image::read_image_fits;
use stepsim_contract::io::{IoError, write_atomically};
use stepsim_contract::run_layout::{MANIFEST_FORMAT, Manifest};

/// Reads and checks `manifest.json`.
pub fn read_manifest(path: &Path) -> Result<Manifest, KsbError> {
    let text = std::fs::read_to_string(path).map_err(|e| IoError::os(path, e))?;
    let m: Manifest = serde_json::from_str(&text).map_err(|e| KsbError::Manifest {
        path: path.into(),
        message: format!("line {}, column {}: {e}", e.line(), e.column()),
    })?;
    if m.format != MANIFEST_FORMAT {
        return Err(KsbError::Manifest {
            path: path.into(),
            message: format!("format is {:?}, expected {MANIFEST_FORMAT:?}", m.format),
        });
    }
    let i = &m.instrument;
    if !(i.gain_e_per_adu > 0.0 && i.gain_e_per_adu.is_finite()) {
        return Err(KsbError::Manifest {
            path: path.into(),
            message: format!(
                "instrument.gain_e_per_adu = {} must be > 0",
                i.gain_e_per_adu
            ),
        });
    }
    Ok(m)
}

/// Reads the first HDU with 2-D image data (a primary image, or an image
/// extension such as a tile-compressed one) as f32, in the file's units
/// (the simulator's reader, [`read_image_fits`], as an [`Image`]).
pub fn read_fits_image(path: &Path) -> Result<Image, KsbError> {
    if !path.is_file() {
        return Err(KsbError::Io(IoError::os(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        )));
    }
    let f = read_image_fits(path)?;
    let (w, h) = (f.width as usize, f.height as usize);
    Image::from_vec(w, h, f.pixels).ok_or_else(|| KsbError::Image {
        path: path.into(),
        message: format!("pixel count does not match {w} × {h}"),
    })
}

/// Writes `img` as a BITPIX −32 primary image, atomically (for tests,
/// benchmarks and synthetic data; the simulator has its own writer).
pub fn write_fits_image(path: &Path, img: &Image) -> Result<(), KsbError> {
    use fitsio::images::{ImageDescription, ImageType};
    write_atomically(path, |tmp| -> Result<(), KsbError> {
        let fe = |e: fitsio::errors::Error| KsbError::Io(IoError::fits(path, e));
        let desc = ImageDescription {
            data_type: ImageType::Float,
            dimensions: &[img.height, img.width],
        };
        let mut f = create_fits(
            tmp,
            Primary {
                image: Some(&desc),
                rice: false,
            },
        )?;
        let hdu = f.primary_hdu().map_err(fe)?;
        hdu.write_image(&mut f, &img.data).map_err(fe)?;
        finish_fits(f, path)?;
        Ok(())
    })
}

/// Column header line of a submission (SPEC §6).
pub const SUBMISSION_HEADER: &str = "# image x y e1 e2 weight flags";

/// Formats a submission: the header line, then one line per object (for
/// the tests, as [`write_submission`]).
#[cfg(test)]
pub fn format_submission<'a>(
    rows: impl IntoIterator<Item = (&'a str, &'a MeasuredObject)>,
) -> String {
    let mut s = String::new();
    s.push_str(SUBMISSION_HEADER);
    s.push('\n');
    for (image, o) in rows {
        push_row(&mut s, image, o);
    }
    s
}

/// Appends the submission line of `o` on image `image` to `s`.
pub fn push_row(s: &mut String, image: &str, o: &MeasuredObject) {
    let _ = writeln!(
        s,
        "{image} {:.3} {:.3} {:.6} {:.6} {:.6} {}",
        o.x, o.y, o.e1, o.e2, o.weight, o.flags
    );
}

/// Column header line of the details table (`stepsim measure --details`):
/// the submission's columns, then the pipeline's own quantities.
pub const DETAILS_HEADER: &str = "# image x y e1 e2 weight flags r_g_px nu mag pgamma k e_cor1 e_cor2 \
     sigma_gamma e1_0 e2_0 e1_1p e2_1p e1_1m e2_1m e1_2p e2_2p e1_2m e2_2m mc_selected";

/// Appends the details line of `o` (docs/ksb.md, "The details table"):
/// its submission line's seven columns, then r_g (pixels), ν, the
/// magnitude, ½Tr P^γ as used (k included), the calibration's k, e_cor
/// and σ_γ; then, with metacalibration, the raw ellipticity of each of
/// the five versions ([`crate::metacal::VERSIONS`]' order: no shear, +g₁,
/// −g₁, +g₂, −g₂) and which versions pass the cuts (bit v for version v),
/// so that a subset's own response can be computed; `nan` where the
/// pipeline did not compute one (KSB+'s parts under metacal, metacal's
/// under KSB+, no PSF model, no moments; the mask is then 0).
pub fn push_details_row(s: &mut String, image: &str, o: &MeasuredObject) {
    let (e_cor, k, sigma) = o.ksb.map_or(([f64::NAN; 2], f64::NAN, f64::NAN), |d| {
        (d.e_cor, d.k, d.sigma_gamma)
    });
    let nan = |v: f64, digits: usize| {
        if v.is_finite() {
            format!("{v:.digits$}")
        } else {
            "nan".to_string()
        }
    };
    let _ = write!(
        s,
        "{image} {:.3} {:.3} {:.6} {:.6} {:.6} {} {} {} {} {} {} {} {} {}",
        o.x,
        o.y,
        o.e1,
        o.e2,
        o.weight,
        o.flags,
        nan(o.rg_px, 4),
        nan(o.sn, 2),
        nan(o.mag, 3),
        nan(o.pgamma, 6),
        nan(k, 6),
        nan(e_cor[0], 6),
        nan(e_cor[1], 6),
        nan(sigma, 6),
    );
    let (versions, selected) = o.metacal.map_or(([[f64::NAN; 2]; 5], 0u32), |(m, sel)| {
        let mask = (0..5).filter(|&v| sel[v]).map(|v| 1u32 << v).sum();
        (m.e, mask)
    });
    for e in versions {
        let _ = write!(s, " {} {}", nan(e[0], 6), nan(e[1], 6));
    }
    let _ = writeln!(s, " {selected}");
}

/// Writes a submission atomically (for the tests: a run writes its rows
/// by [`push_row`]).
#[cfg(test)]
pub fn write_submission<'a>(
    path: &Path,
    rows: impl IntoIterator<Item = (&'a str, &'a MeasuredObject)>,
) -> Result<(), KsbError> {
    let text = format_submission(rows);
    write_atomically(path, |tmp| -> Result<(), KsbError> {
        std::fs::write(tmp, text.as_bytes()).map_err(|e| IoError::os(tmp, e))?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use fitsio::FitsFile;

    #[test]
    fn fits_images_round_trip_plain_and_rice_compressed() {
        use fitsio::images::{ImageDescription, ImageType};
        let dir = tempfile::tempdir().unwrap();
        let data: Vec<f32> = (0..12 * 7).map(|k| k as f32 * 1.5).collect();
        let plain = dir.path().join("a.fits");
        {
            let mut f = FitsFile::create(&plain)
                .with_custom_primary(&ImageDescription {
                    data_type: ImageType::Float,
                    dimensions: &[7, 12],
                })
                .open()
                .unwrap();
            let hdu = f.primary_hdu().unwrap();
            hdu.write_image(&mut f, &data).unwrap();
        }
        let img = read_fits_image(&plain).unwrap();
        assert_eq!((img.width, img.height), (12, 7));
        assert_eq!(img.at(3, 2), data[2 * 12 + 3]);
        // Rice-compressed int32 in an image extension.
        let rice = dir.path().join("b.fits");
        let ints: Vec<i32> = (0..12 * 7).map(|k| 1000 + k).collect();
        {
            let name = format!("{}[compress R]", rice.display());
            let mut f = FitsFile::create(&name).open().unwrap();
            let hdu = f
                .create_image(
                    "SCI",
                    &ImageDescription {
                        data_type: ImageType::Long,
                        dimensions: &[7, 12],
                    },
                )
                .unwrap();
            hdu.write_image(&mut f, &ints).unwrap();
        }
        let img = read_fits_image(&rice).unwrap();
        assert_eq!((img.width, img.height), (12, 7));
        assert_eq!(img.at(5, 6), (1000 + 6 * 12 + 5) as f32);
        // Missing and non-image files are refused naming the file.
        let e = read_fits_image(&dir.path().join("none.fits"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("none.fits"), "{e}");
        std::fs::write(dir.path().join("junk.fits"), b"not fits").unwrap();
        let e = read_fits_image(&dir.path().join("junk.fits"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("junk.fits"), "{e}");
    }

    #[test]
    fn submission_has_the_spec_header_and_one_line_per_object() {
        let o = MeasuredObject {
            x: 10.5,
            y: 20.25,
            e1: 0.0123456,
            e2: -0.5,
            weight: 7.5,
            flags: 0,
            rg_px: 2.0,
            sn: 30.0,
            mag: 22.0,
            pgamma: 0.5,
            metacal: None,
            ksb: None,
        };
        let s = format_submission([
            ("img1", &o),
            (
                "img1",
                &MeasuredObject {
                    flags: 5,
                    weight: 0.0,
                    ..o
                },
            ),
        ]);
        let lines: Vec<&str> = s.lines().collect();
        assert_eq!(lines[0], "# image x y e1 e2 weight flags");
        assert_eq!(lines[1], "img1 10.500 20.250 0.012346 -0.500000 7.500000 0");
        assert_eq!(lines[2], "img1 10.500 20.250 0.012346 -0.500000 0.000000 5");
    }
}
