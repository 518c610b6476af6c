//! Simulated images as FITS files (SPEC §4).
//!
//! * Pixels are ADU, row-major with index `(y − 1) · width + (x − 1)` for FITS
//!   pixel (x, y); x runs along NAXIS1.
//! * `float32` (default): BITPIX −32, the primary HDU holds the image.
//! * `int32`: BITPIX 32, ADU rounded to the nearest integer. With
//!   `compression = "rice"` the image is Rice tile-compressed by cfitsio
//!   (lossless for integers); it then sits in HDU 1 (a `ZIMAGE` binary table
//!   behind an empty primary), which every FITS reader opens transparently.
//! * Header: a TAN WCS (`CTYPEi`, `CRVALi`, `CRPIXi`, `CDi_j`, `CUNITi`,
//!   `RADESYS`, `EQUINOX`), `BUNIT = 'ADU'` and the instrument keywords
//!   `GAIN` (e⁻/ADU), `RDNOISE` (e⁻), `SATURATE` (ADU), `EXPTIME` (s),
//!   `MAGZERO` and `PIXSCALE` (arcsec). `MAGZERO` is the zeropoint of the
//!   image *in ADU*: m = MAGZERO − 2.5 log10(total ADU) =
//!   zeropoint_mag + 2.5 log10(exposure_s) − 2.5 log10(gain) (SExtractor's
//!   `MAG_ZEROPOINT` for this image).
//! * Nothing else: no PSF, shear, seed or other truth, and no `DATE` or any
//!   time-dependent keyword, so a rerun writes identical bytes.
//!
//! Files are written atomically ([`stepsim_contract::io::write_atomically`]).

use crate::model::noise::Instrument;
use crate::model::wcs::{Geometry, TanWcs};
use fitsio::FitsFile;
use fitsio::images::{ImageDescription, ImageType};
use serde::{Deserialize, Serialize};
use std::path::Path;
use stepsim_contract::io::IoError;
use stepsim_contract::io::fits::{Primary, fits_bytes, write_fits_hashed};
use stepsim_contract::io::write_atomically;

/// Pixel type of the written images (the config's `output.format`).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum SampleFormat {
    /// BITPIX −32.
    Float32,
    /// BITPIX 32 (ADU rounded to the nearest integer).
    Int32,
}

/// Compression of the written images (the config's `output.compression`).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Compression {
    /// Plain FITS.
    None,
    /// Lossless Rice tile compression (integer output only).
    Rice,
}

/// What goes into the header of an image besides its pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageHeader {
    /// The TAN WCS (the same for every image of a run: [`crate::model::wcs`]).
    pub wcs: TanWcs,
    /// GAIN, e⁻/ADU.
    pub gain_e_per_adu: f64,
    /// RDNOISE, e⁻.
    pub read_noise_e: f64,
    /// SATURATE, ADU.
    pub saturation_adu: f64,
    /// EXPTIME, s.
    pub exposure_s: f64,
    /// MAGZERO: magnitude of a source of 1 ADU in total.
    pub magzero_adu: f64,
    /// PIXSCALE, arcsec.
    pub pixel_scale_arcsec: f64,
}

impl ImageHeader {
    /// The header of every image of a run: one for all base fields,
    /// datasets and twins, so that no keyword groups the images.
    pub fn new(image: &Geometry, instrument: &Instrument) -> Self {
        Self {
            wcs: TanWcs::of_images(image),
            gain_e_per_adu: instrument.gain_e_per_adu,
            read_noise_e: instrument.read_noise_e,
            saturation_adu: instrument.saturation_adu,
            exposure_s: instrument.exposure_s,
            magzero_adu: instrument.zp_eff() - 2.5 * instrument.gain_e_per_adu.log10(),
            pixel_scale_arcsec: image.pixel_scale_arcsec,
        }
    }
}

/// The integer written for an ADU value in `int32` output: nearest integer,
/// clamped to the i32 range.
pub fn adu_to_i32(v: f32) -> i32 {
    let r = f64::from(v).round();
    r.clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
}

/// Writes an image atomically and returns the SHA-256 (hex) of the file's
/// bytes, hashed as written: uncompressed float32 images streamed to disk,
/// the others built by cfitsio in memory ([`write_image_fits_slow`]).
/// `pixels_adu` has `width × height` values.
pub fn write_image_fits(
    path: &Path,
    pixels_adu: &[f32],
    width: u32,
    height: u32,
    header: &ImageHeader,
    format: SampleFormat,
    compression: Compression,
) -> Result<String, IoError> {
    let n = width as usize * height as usize;
    if pixels_adu.len() != n {
        return Err(IoError::format(
            path,
            format!(
                "image has {} pixels, expected {width} × {height} = {n}",
                pixels_adu.len()
            ),
        ));
    }
    if compression == Compression::Rice && format == SampleFormat::Float32 {
        return Err(IoError::format(
            path,
            "rice compression is only offered for int32 output",
        ));
    }
    if format == SampleFormat::Float32 && compression == Compression::None {
        return write_float32_streamed(path, pixels_adu, width, height, header);
    }
    write_image_fits_slow(path, pixels_adu, width, height, header, format, compression)
}

/// [`write_image_fits`] with the whole file built by cfitsio in memory: the
/// way int32 and Rice-compressed images are written, and the slow twin of
/// the streamed float32 writer (tested byte for byte).
pub fn write_image_fits_slow(
    path: &Path,
    pixels_adu: &[f32],
    width: u32,
    height: u32,
    header: &ImageHeader,
    format: SampleFormat,
    compression: Compression,
) -> Result<String, IoError> {
    let dims = [height as usize, width as usize];
    let desc = ImageDescription {
        data_type: match format {
            SampleFormat::Float32 => ImageType::Float,
            SampleFormat::Int32 => ImageType::Long,
        },
        dimensions: &dims,
    };
    let primary = Primary {
        image: Some(&desc),
        rice: compression == Compression::Rice,
    };
    write_fits_hashed(path, primary, |f| {
        let fe = |e: fitsio::errors::Error| IoError::fits(path, e);
        // The image is the last HDU: the primary, or HDU 1 behind an empty
        // primary when cfitsio tile-compresses it.
        let last = f.num_hdus().map_err(fe)? - 1;
        let hdu = f.hdu(last).map_err(fe)?;
        match format {
            SampleFormat::Float32 => hdu.write_image(f, pixels_adu).map_err(fe)?,
            SampleFormat::Int32 => {
                let ints: Vec<i32> = pixels_adu.iter().map(|&v| adu_to_i32(v)).collect();
                hdu.write_image(f, &ints).map_err(fe)?
            }
        }
        write_keywords(f, &hdu, header, path)
    })
}

/// The keywords of an image HDU after its structural ones (`EXTNAME`, which
/// fitsio adds, removed again).
fn write_keywords(
    f: &mut FitsFile,
    hdu: &fitsio::hdu::FitsHdu,
    header: &ImageHeader,
    path: &Path,
) -> Result<(), IoError> {
    let fe = |e: fitsio::errors::Error| IoError::fits(path, e);
    // fitsio names the new HDU `_PRIMARY`; that is not a FITS keyword
    // anyone needs, so remove it again.
    delete_key(f, "EXTNAME").map_err(|e| IoError::format(path, e))?;
    let w = &header.wcs;
    let s = |f: &mut FitsFile, k: &str, v: &str, c: &str| hdu.write_key(f, k, (v, c));
    let d = |f: &mut FitsFile, k: &str, v: f64, c: &str| write_f64(f, k, v, c);
    s(f, "BUNIT", "ADU", "pixel unit").map_err(fe)?;
    s(f, "CTYPE1", "RA---TAN", "gnomonic projection").map_err(fe)?;
    s(f, "CTYPE2", "DEC--TAN", "gnomonic projection").map_err(fe)?;
    s(f, "CUNIT1", "deg", "").map_err(fe)?;
    s(f, "CUNIT2", "deg", "").map_err(fe)?;
    s(f, "RADESYS", "ICRS", "").map_err(fe)?;
    d(f, "EQUINOX", 2000.0, "").map_err(fe)?;
    d(f, "CRVAL1", w.crval1, "[deg] RA of reference point").map_err(fe)?;
    d(f, "CRVAL2", w.crval2, "[deg] Dec of reference point").map_err(fe)?;
    d(f, "CRPIX1", w.crpix1, "reference pixel x").map_err(fe)?;
    d(f, "CRPIX2", w.crpix2, "reference pixel y").map_err(fe)?;
    d(f, "CD1_1", w.cd1_1, "[deg/pixel]").map_err(fe)?;
    d(f, "CD1_2", 0.0, "[deg/pixel]").map_err(fe)?;
    d(f, "CD2_1", 0.0, "[deg/pixel]").map_err(fe)?;
    d(f, "CD2_2", w.cd2_2, "[deg/pixel]").map_err(fe)?;
    d(f, "GAIN", header.gain_e_per_adu, "[e-/ADU]").map_err(fe)?;
    d(f, "RDNOISE", header.read_noise_e, "[e-] read noise").map_err(fe)?;
    d(f, "SATURATE", header.saturation_adu, "[ADU] clip level").map_err(fe)?;
    d(f, "EXPTIME", header.exposure_s, "[s] exposure").map_err(fe)?;
    d(
        f,
        "MAGZERO",
        header.magzero_adu,
        "m = MAGZERO - 2.5 log10(ADU total)",
    )
    .map_err(fe)?;
    d(f, "PIXSCALE", header.pixel_scale_arcsec, "[arcsec/pixel]").map_err(fe)?;
    Ok(())
}

/// FITS block size: headers and data units are padded to whole blocks.
const BLOCK: usize = 2880;

/// An uncompressed float32 image written without building the file in
/// memory: the same bytes as [`write_image_fits_slow`] (tested), hashed
/// as they are written.
///
/// cfitsio builds the header: the same keywords for a 1 × 1 image, whose
/// `NAXIS1` and `NAXIS2` values are then replaced by the true ones (an
/// integer card's value is right-justified in columns 11–30, the comment
/// does not depend on it). The data follow in slices of 256 kB: big-endian
/// IEEE floats, as cfitsio writes them, then zeros to a whole block. In
/// memory the file took a 67 MB buffer for a 4096² image that cfitsio first
/// zero-filled and then copied the data into.
fn write_float32_streamed(
    path: &Path,
    pixels_adu: &[f32],
    width: u32,
    height: u32,
    header: &ImageHeader,
) -> Result<String, IoError> {
    use sha2::{Digest, Sha256};
    use std::io::Write as _;
    let head = float32_header(path, width, height, header)?;
    let mut sha = Sha256::new();
    write_atomically(path, |tmp| {
        let os = |e| IoError::os(tmp, e);
        let mut file = std::fs::File::create(tmp).map_err(os)?;
        sha.update(&head);
        file.write_all(&head).map_err(os)?;
        let mut bytes = Vec::new();
        for chunk in pixels_adu.chunks(1 << 16) {
            bytes.resize(chunk.len() * 4, 0);
            for (b, v) in bytes.chunks_exact_mut(4).zip(chunk) {
                b.copy_from_slice(&v.to_be_bytes());
            }
            sha.update(&bytes);
            file.write_all(&bytes).map_err(os)?;
        }
        let pad = vec![0u8; (BLOCK - pixels_adu.len() * 4 % BLOCK) % BLOCK];
        sha.update(&pad);
        file.write_all(&pad).map_err(os)?;
        file.flush().map_err(os)
    })?;
    Ok(stepsim_contract::digest::hex(&sha.finalize()))
}

/// The header of a float32 image of `width × height` pixels with
/// `header`'s keywords, as cfitsio writes it (whole blocks, ending in `END`).
fn float32_header(
    path: &Path,
    width: u32,
    height: u32,
    header: &ImageHeader,
) -> Result<Vec<u8>, IoError> {
    let desc = ImageDescription {
        data_type: ImageType::Float,
        dimensions: &[1, 1],
    };
    let primary = Primary {
        image: Some(&desc),
        rice: false,
    };
    let file = fits_bytes(path, primary, |f| {
        let hdu = f.hdu(0).map_err(|e| IoError::fits(path, e))?;
        write_keywords(f, &hdu, header, path)
    })?;
    let bytes = file.as_slice();
    let cards = bytes.len().saturating_sub(BLOCK) / 80;
    let end = (0..cards)
        .find(|&i| bytes[i * 80..(i + 1) * 80].starts_with(b"END "))
        .ok_or_else(|| IoError::format(path, "cfitsio wrote a header without END"))?;
    let mut head = bytes[..(end + 1) * 80].to_vec();
    head.resize(head.len().div_ceil(BLOCK) * BLOCK, b' ');
    for (key, value) in [("NAXIS1", width), ("NAXIS2", height)] {
        let card = (0..=end)
            .find(|&i| head[i * 80..i * 80 + 8] == *format!("{key:<8}").as_bytes())
            .ok_or_else(|| IoError::format(path, format!("cfitsio wrote no {key} card")))?;
        head[card * 80 + 10..card * 80 + 30].copy_from_slice(format!("{value:>20}").as_bytes());
    }
    Ok(head)
}

/// The shortest text of `value` that reads back exactly, as a FITS real
/// (mantissa with a decimal point, exponent with `E`).
pub fn fits_real(value: f64) -> String {
    let text = format!("{value:?}");
    let (mantissa, exponent) = match text.split_once('e') {
        Some((m, e)) => (m.to_string(), Some(e.to_string())),
        None => (text, None),
    };
    let mantissa = if mantissa.contains('.') {
        mantissa
    } else {
        format!("{mantissa}.0")
    };
    match exponent {
        Some(e) => format!("{mantissa}E{e}"),
        None => mantissa,
    }
}

/// Writes a double keyword as a fixed-format card with the shortest exact
/// text of the value (cfitsio's own writer keeps 15 digits, or 17 with
/// noise such as 0.20599999999999999).
fn write_f64(f: &mut FitsFile, key: &str, value: f64, comment: &str) -> fitsio::errors::Result<()> {
    let mut card = format!("{key:<8}= {:>20}", fits_real(value));
    if !comment.is_empty() {
        card.push_str(" / ");
        card.push_str(comment);
    }
    card.truncate(80);
    let c_card = std::ffi::CString::new(card)?;
    let mut status = 0;
    // SAFETY: `f` is an open, writable cfitsio file; ffprec appends one
    // 80-character card to the current HDU's header and only reads `c_card`.
    unsafe {
        fitsio::sys::ffprec(f.as_raw(), c_card.as_ptr(), &mut status);
    }
    if status == 0 {
        Ok(())
    } else {
        Err(fitsio::errors::Error::Message(format!(
            "cannot write keyword {key}: cfitsio status {status}"
        )))
    }
}

fn delete_key(f: &mut FitsFile, key: &str) -> Result<(), String> {
    let c_key = std::ffi::CString::new(key).map_err(|e| e.to_string())?;
    let mut status = 0;
    // SAFETY: `f` is an open, writable cfitsio file whose current HDU is the
    // image just created; ffdkey only edits that header.
    unsafe {
        fitsio::sys::ffdkey(f.as_raw(), c_key.as_ptr(), &mut status);
    }
    if status == 0 {
        Ok(())
    } else {
        Err(format!("cannot delete {key}: cfitsio status {status}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stepsim_contract::io::image::read_image_fits;

    fn header() -> ImageHeader {
        let img = Geometry {
            width_px: 40,
            height_px: 30,
            ..Geometry::step1()
        };
        ImageHeader::new(&img, &Instrument::default())
    }

    fn pixels() -> Vec<f32> {
        (0..1200)
            .map(|i| 20_000.0 + ((i * 7919) % 1000) as f32 * 0.37 - 150.0)
            .collect()
    }

    fn key_f64(path: &Path, hdu: usize, key: &str) -> f64 {
        let mut f = FitsFile::open(path).unwrap();
        let h = f.hdu(hdu).unwrap();
        h.read_key(&mut f, key).unwrap()
    }

    #[test]
    fn streamed_float32_files_are_cfitsios_byte_for_byte() {
        let dir = tempfile::tempdir().unwrap();
        let h = header();
        // One pixel; sizes whose data end inside a block and on its edge
        // (720 × 4 bytes = one block); an axis of 7 digits; odd values
        // (negative zero, subnormal, huge, NaN).
        for (w, ht) in [
            (1, 1),
            (7, 3),
            (720, 1),
            (40, 30),
            (1_000_003, 2),
            (333, 257),
        ] {
            let n = w as usize * ht as usize;
            let mut px: Vec<f32> = (0..n)
                .map(|i| 20_000.0 + ((i * 7919) % 1000) as f32 * 0.37 - 150.0)
                .collect();
            for (k, v) in [-0.0, 1e-40, 3e38, f32::NAN].into_iter().enumerate() {
                if k < n {
                    px[k * n / 4] = v;
                }
            }
            let (a, b) = (dir.path().join("a.fits"), dir.path().join("b.fits"));
            let none = Compression::None;
            let sha_a = write_image_fits(&a, &px, w, ht, &h, SampleFormat::Float32, none).unwrap();
            let sha_b =
                write_image_fits_slow(&b, &px, w, ht, &h, SampleFormat::Float32, none).unwrap();
            let (bytes_a, bytes_b) = (std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
            assert_eq!(bytes_a.len(), bytes_b.len(), "{w} × {ht}");
            assert!(bytes_a == bytes_b, "{w} × {ht}: the bytes differ");
            assert_eq!(sha_a, sha_b);
            assert_eq!(sha_a, stepsim_contract::digest::sha256_hex(&bytes_a));
            assert_eq!(bytes_a.len() % BLOCK, 0);
            std::fs::remove_file(&a).unwrap();
            std::fs::remove_file(&b).unwrap();
        }
    }

    #[test]
    fn float32_round_trip_is_exact_and_header_is_complete() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.fits");
        let px = pixels();
        let h = header();
        write_image_fits(
            &path,
            &px,
            40,
            30,
            &h,
            SampleFormat::Float32,
            Compression::None,
        )
        .unwrap();
        let back = read_image_fits(&path).unwrap();
        assert_eq!((back.width, back.height), (40, 30));
        assert_eq!(back.pixels, px);
        assert_eq!(key_f64(&path, 0, "GAIN"), 4.0);
        assert_eq!(key_f64(&path, 0, "RDNOISE"), 5.0);
        assert_eq!(key_f64(&path, 0, "SATURATE"), 65535.0);
        assert_eq!(key_f64(&path, 0, "EXPTIME"), 3600.0);
        assert_eq!(key_f64(&path, 0, "PIXSCALE"), 0.206);
        assert_eq!(key_f64(&path, 0, "CRPIX1"), 20.5);
        assert_eq!(key_f64(&path, 0, "CRPIX2"), 15.5);
        assert_eq!(key_f64(&path, 0, "CD1_1"), -0.206 / 3600.0);
        assert_eq!(key_f64(&path, 0, "CRVAL1"), h.wcs.crval1);
        // MAGZERO = 26 + 2.5 log10(3600) − 2.5 log10(4) = 33.385606
        assert!((key_f64(&path, 0, "MAGZERO") - 33.385_606).abs() < 1e-6);
        // The raw header: BITPIX −32, WCS types, no time, no EXTNAME.
        let bytes = std::fs::read(&path).unwrap();
        let head = String::from_utf8_lossy(&bytes[..2880]);
        assert!(head.contains("BITPIX  =                  -32"), "{head}");
        assert!(head.contains("'RA---TAN'") && head.contains("'DEC--TAN'"));
        assert!(
            head.contains("PIXSCALE=                0.206 / [arcsec/pixel]"),
            "{head}"
        );
        for banned in ["DATE", "EXTNAME", "CHECKSUM"] {
            assert!(!head.contains(banned), "{banned} in header");
        }
    }

    #[test]
    fn empty_2d_images_are_skipped() {
        use fitsio::images::{ImageDescription, ImageType};
        let dir = tempfile::tempdir().unwrap();
        // A 0 × 5 primary image, then (in the second file) a 3 × 2 extension.
        let write = |name: &str, with_sci: bool| {
            let path = dir.path().join(name);
            let mut f = FitsFile::create(&path)
                .with_custom_primary(&ImageDescription {
                    data_type: ImageType::Float,
                    dimensions: &[0, 5],
                })
                .open()
                .unwrap();
            if with_sci {
                let desc = ImageDescription {
                    data_type: ImageType::Float,
                    dimensions: &[2, 3],
                };
                let hdu = f.create_image("SCI", &desc).unwrap();
                hdu.write_image(&mut f, &[1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0])
                    .unwrap();
            }
            path
        };
        let e = read_image_fits(&write("e.fits", false))
            .unwrap_err()
            .to_string();
        assert!(e.contains("e.fits") && e.contains("no 2-D image"), "{e}");
        let img = read_image_fits(&write("s.fits", true)).unwrap();
        assert_eq!((img.width, img.height), (3, 2));
        assert_eq!(img.pixels, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
    }

    #[test]
    fn rice_int32_round_trip_is_exact_and_smaller() {
        let dir = tempfile::tempdir().unwrap();
        let px: Vec<f32> = (0..256 * 256)
            .map(|i: i64| (20_000 + (i * 48_271 % 97) - 48) as f32)
            .collect();
        let h = header();
        let rice = dir.path().join("r.fits");
        let plain = dir.path().join("p.fits");
        for (path, c) in [(&rice, Compression::Rice), (&plain, Compression::None)] {
            write_image_fits(path, &px, 256, 256, &h, SampleFormat::Int32, c).unwrap();
            let back = read_image_fits(path).unwrap();
            assert_eq!((back.width, back.height), (256, 256));
            assert_eq!(back.pixels, px);
        }
        let (r, p) = (
            std::fs::metadata(&rice).unwrap().len(),
            std::fs::metadata(&plain).unwrap().len(),
        );
        assert!(r < p / 2, "rice {r} bytes vs plain {p}");
        assert_eq!(key_f64(&rice, 1, "GAIN"), 4.0);
        // Identical bytes on rewrite (nothing time-dependent in the file).
        let first = std::fs::read(&rice).unwrap();
        write_image_fits(
            &rice,
            &px,
            256,
            256,
            &h,
            SampleFormat::Int32,
            Compression::Rice,
        )
        .unwrap();
        assert_eq!(std::fs::read(&rice).unwrap(), first);
        assert!(!String::from_utf8_lossy(&first).contains("DATE"));
    }

    #[test]
    fn reals_are_shortest_exact_fits_text() {
        assert_eq!(fits_real(0.206), "0.206");
        assert_eq!(fits_real(4.0), "4.0");
        assert_eq!(fits_real(-5.722222222222222e-5), "-5.722222222222222E-5");
        assert_eq!(fits_real(1e-5), "1.0E-5");
        assert_eq!(fits_real(1e300), "1.0E300");
        for v in [0.1, 1.0 / 3.0, -2.5e-12, 150.0 + 3.0 / 0.9993908270190958] {
            assert_eq!(fits_real(v).replace('E', "e").parse::<f64>().unwrap(), v);
        }
    }

    #[test]
    fn int32_rounds_to_nearest() {
        assert_eq!(adu_to_i32(2.4), 2);
        assert_eq!(adu_to_i32(2.6), 3);
        assert_eq!(adu_to_i32(-2.6), -3);
        assert_eq!(adu_to_i32(1e12), i32::MAX);
    }

    #[test]
    fn bad_input_writes_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.fits");
        let err = write_image_fits(
            &path,
            &[1.0; 10],
            4,
            4,
            &header(),
            SampleFormat::Float32,
            Compression::None,
        )
        .unwrap_err();
        assert!(err.to_string().contains("x.fits"), "{err}");
        assert!(
            write_image_fits(
                &path,
                &[1.0; 16],
                4,
                4,
                &header(),
                SampleFormat::Float32,
                Compression::Rice
            )
            .is_err()
        );
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }
}
