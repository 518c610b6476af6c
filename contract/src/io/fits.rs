//! Opening and creating FITS files by their plain names, and cfitsio's
//! status codes as sentences.
//!
//! cfitsio's ordinary open and create calls read a file name as its
//! *extended syntax*: `a[1].fits` selects an extension of `a`, `b(2)` names
//! a template, a leading `!` means "overwrite", `x.fits[compress R]` asks
//! for compression. A user's path is never meant that way, so every FITS
//! file of the workspace is opened with [`open_fits`] and created with
//! [`create_fits`], which call cfitsio's disk-file variants
//! (`fits_open_diskfile`, `fits_create_diskfile`): they take the whole
//! string literally as the name of a file on disk. Compression is asked for
//! through the API ([`Primary::rice`]), never through the name.

use super::IoError;
use fitsio::FitsFile;
use fitsio::images::ImageDescription;
use std::ffi::CString;
use std::path::Path;

impl std::fmt::Debug for Primary<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Primary")
            .field("image", &self.image.map(|d| d.dimensions))
            .field("rice", &self.rice)
            .finish()
    }
}

/// The primary HDU of a new file.
#[derive(Clone, Copy, Default)]
pub struct Primary<'a> {
    /// The primary image (`None`: an empty primary HDU).
    pub image: Option<&'a ImageDescription<'a>>,
    /// Rice tile compression: the image goes into a compressed extension
    /// behind an empty primary (integer images only).
    pub rice: bool,
}

fn c_path(path: &Path) -> Result<CString, IoError> {
    use std::os::unix::ffi::OsStrExt as _;
    CString::new(path.as_os_str().as_bytes())
        .map_err(|_| IoError::format(path, "the file name contains a NUL byte"))
}

/// Wraps a pointer cfitsio returned with status 0; closes it again if
/// fitsio cannot take it (e.g. a file name that is not UTF-8).
fn wrap(
    path: &Path,
    fptr: *mut fitsio::sys::fitsfile,
    mode: fitsio::FileOpenMode,
) -> Result<FitsFile, IoError> {
    // SAFETY: `fptr` was just returned by cfitsio with status 0.
    match unsafe { FitsFile::from_raw(fptr, mode) } {
        Ok(f) => Ok(f),
        Err(_) => {
            let mut status = 0;
            // SAFETY: as above; the pointer is not used afterwards.
            unsafe { fitsio::sys::ffclos(fptr, &mut status) };
            Err(IoError::format(
                path,
                "the file name is not valid UTF-8 (cfitsio files need UTF-8 names)",
            ))
        }
    }
}

/// Opens an existing FITS file read-only; `path` is a plain file name
/// (brackets, parentheses and a leading `!` are part of the name).
pub fn open_fits(path: &Path) -> Result<FitsFile, IoError> {
    let name = c_path(path)?;
    let mut fptr = std::ptr::null_mut();
    let mut status = 0;
    // SAFETY: `name` is a NUL-terminated string that outlives the call;
    // `fptr` and `status` are valid for writes.
    unsafe { fitsio::sys::ffdkopn(&mut fptr, name.as_ptr(), 0, &mut status) };
    if status != 0 {
        return Err(IoError::fits_status(path, status));
    }
    wrap(path, fptr, fitsio::FileOpenMode::READONLY)
}

/// Creates a new FITS file (refused if `path` exists) with the given primary
/// HDU; `path` is a plain file name. Like fitsio's `FitsFile::create`, a
/// primary image gets `EXTNAME = '_PRIMARY'` (callers delete it if unwanted).
pub fn create_fits(path: &Path, primary: Primary<'_>) -> Result<FitsFile, IoError> {
    let name = c_path(path)?;
    if std::fs::symlink_metadata(path).is_ok() {
        return Err(IoError::format(path, "cannot create: the file exists"));
    }
    let mut fptr = std::ptr::null_mut();
    let mut status = 0;
    // SAFETY: as in `open_fits`.
    unsafe { fitsio::sys::ffdkinit(&mut fptr, name.as_ptr(), &mut status) };
    if status != 0 {
        return Err(IoError::fits_status(path, status));
    }
    let mut f = wrap(path, fptr, fitsio::FileOpenMode::READWRITE)?;
    if primary.rice {
        let mut tiles = [0 as std::os::raw::c_long; 6];
        // SAFETY: `f` is an open file; `tiles` holds MAX_COMPRESS_DIM (6) values.
        unsafe {
            fitsio::sys::fits_set_compression_type(
                f.as_raw(),
                fitsio::sys::RICE_1 as i32,
                &mut status,
            );
            fitsio::sys::fits_set_tile_dim(f.as_raw(), 6, tiles.as_mut_ptr(), &mut status);
        }
        if status != 0 {
            return Err(IoError::fits_status(path, status));
        }
    }
    match primary.image {
        Some(desc) => {
            f.create_image("_PRIMARY", desc)
                .map_err(|e| IoError::fits(path, e))?;
        }
        None => {
            // SAFETY: `f` is an open, empty file; NAXIS 0 needs no axes.
            unsafe {
                fitsio::sys::ffphps(f.as_raw(), 8, 0, std::ptr::null_mut(), &mut status);
            }
            if status != 0 {
                return Err(IoError::fits_status(path, status));
            }
        }
    }
    Ok(f)
}

/// Closes a file being written, reporting what its final flush met (a full
/// disk often shows only here; dropping a `FitsFile` would ignore it).
/// Writers call this last, before the atomic rename.
pub fn finish_fits(mut f: FitsFile, path: &Path) -> Result<(), IoError> {
    let mut status = 0;
    // SAFETY: the pointer is the open file of `f`; it is closed here exactly
    // once and `f` is forgotten so that its destructor does not close it again.
    unsafe {
        fitsio::sys::ffclos(f.as_raw(), &mut status);
    }
    std::mem::forget(f);
    if status != 0 {
        return Err(IoError::fits_status(path, status));
    }
    Ok(())
}

/// What a cfitsio status means, as the end of a sentence about `path`
/// (lower case, no full stop). Unknown statuses give cfitsio's own text.
pub fn status_sentence(path: &Path, status: i32) -> String {
    let p = path.display();
    let what = match status {
        104 => return format!("cannot open {p}: no such file, or it is not readable"),
        105 => {
            return format!(
                "cannot create {p}: its directory is missing or not writable, or the file exists"
            );
        }
        106 => return format!("cannot write {p}: the disk is full or the file is not writable"),
        107 => "the file ends too early (truncated, or not a FITS file)",
        108 => return format!("cannot read {p}: read error"),
        111 => "an array is too big for cfitsio",
        112 => return format!("cannot write {p}: the file is read-only"),
        113 => "out of memory",
        116 => "seek error (the file is damaged or truncated)",
        202 => "a required header keyword is missing",
        204 | 209 | 211..=216 => "a header keyword has an invalid value",
        207 | 205 => "a header card holds an illegal character or an unterminated string",
        210 => "the header has no END card (truncated, or not a FITS file)",
        219 => "a column is missing",
        220..=225 | 251 | 252 => "not a FITS file (its header does not start as FITS requires)",
        226 | 227 | 235 => "the HDU is not a table",
        233 => "the HDU is not an image",
        237 => "a column name matches more than one column",
        253..=255 => "the header or data padding is corrupt",
        261..=263 => "a table column has an invalid or unsupported format (TFORM/TDIM)",
        301 => "the HDU does not exist",
        302 => "the column does not exist",
        307 | 308 => "a row or element number is out of range",
        412 => "a value overflows the column's data type",
        413 | 414 => "the tile-compressed data are corrupt",
        _ => return format!("{p}: {} (cfitsio status {status})", cfitsio_text(status)),
    };
    format!("{p}: {what} (cfitsio status {status})")
}

/// cfitsio's own short text for a status.
fn cfitsio_text(status: i32) -> String {
    let mut buf = [0 as std::os::raw::c_char; 31];
    // SAFETY: ffgerr writes at most 30 characters plus NUL into `buf`.
    unsafe { fitsio::sys::ffgerr(status, buf.as_mut_ptr()) };
    // SAFETY: `buf` is NUL-terminated by ffgerr (and zeroed beforehand).
    let text = unsafe { std::ffi::CStr::from_ptr(buf.as_ptr()) };
    text.to_string_lossy().trim().to_lowercase()
}

#[cfg(test)]
mod tests {
    use super::*;
    use fitsio::images::ImageType;

    #[test]
    fn names_with_extended_syntax_are_plain_files() {
        let dir = tempfile::tempdir().unwrap();
        let sub = dir.path().join("run[x]");
        std::fs::create_dir(&sub).unwrap();
        for name in ["a[1].fits", "b(2)", "!c", "d.fits[compress R]", "e+1"] {
            let path = sub.join(name);
            let desc = ImageDescription {
                data_type: ImageType::Float,
                dimensions: &[2, 3],
            };
            {
                let mut f = create_fits(
                    &path,
                    Primary {
                        image: Some(&desc),
                        rice: false,
                    },
                )
                .unwrap();
                let hdu = f.primary_hdu().unwrap();
                hdu.write_image(&mut f, &[1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0])
                    .unwrap();
            }
            assert!(path.is_file(), "{name} was not created under its name");
            let mut f = open_fits(&path).unwrap();
            let hdu = f.primary_hdu().unwrap();
            let v: Vec<f32> = hdu.read_image(&mut f).unwrap();
            assert_eq!(v, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0], "{name}");
        }
        // Nothing else was made: no `c` from `!c`, no `d.fits`, no `a`.
        let mut names: Vec<String> = std::fs::read_dir(&sub)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(
            names,
            ["!c", "a[1].fits", "b(2)", "d.fits[compress R]", "e+1"]
        );
        // Creating over an existing file is refused, and leaves it alone.
        let err = create_fits(&sub.join("!c"), Primary::default())
            .err()
            .unwrap();
        assert!(err.to_string().contains("exists"), "{err}");
        assert!(open_fits(&sub.join("!c")).is_ok());
    }

    #[test]
    fn rice_primary_writes_a_compressed_extension() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r[1].fits");
        let desc = ImageDescription {
            data_type: ImageType::Long,
            dimensions: &[3, 4],
        };
        let data: Vec<i32> = (0..12).map(|k| 1000 + 7 * k).collect();
        {
            let mut f = create_fits(
                &path,
                Primary {
                    image: Some(&desc),
                    rice: true,
                },
            )
            .unwrap();
            assert_eq!(f.num_hdus().unwrap(), 2);
            let hdu = f.hdu(1).unwrap();
            hdu.write_image(&mut f, &data).unwrap();
        }
        let mut f = open_fits(&path).unwrap();
        let hdu = f.hdu(1).unwrap();
        let zcmp: String = hdu.read_key(&mut f, "ZCMPTYPE").unwrap();
        assert_eq!(zcmp, "RICE_1");
        let back: Vec<i32> = hdu.read_image(&mut f).unwrap();
        assert_eq!(back, data);
    }

    #[test]
    fn statuses_become_sentences_naming_the_file() {
        let p = Path::new("/full/disk/img.fits");
        assert_eq!(
            status_sentence(p, 106),
            "cannot write /full/disk/img.fits: the disk is full or the file is not writable"
        );
        assert_eq!(
            status_sentence(p, 104),
            "cannot open /full/disk/img.fits: no such file, or it is not readable"
        );
        assert_eq!(
            status_sentence(p, 252),
            "/full/disk/img.fits: not a FITS file (its header does not start as FITS requires) (cfitsio status 252)"
        );
        // An untranslated status still names the file, with cfitsio's text.
        let other = status_sentence(p, 125);
        assert!(
            other.starts_with("/full/disk/img.fits: ") && other.ends_with("(cfitsio status 125)"),
            "{other}"
        );
        // The IoError made from a fitsio error carries the sentence only.
        let e = fitsio::errors::Error::Fits(fitsio::errors::FitsError {
            status: 106,
            message: "error writing to FITS file".into(),
        });
        let msg = IoError::fits(p, e).to_string();
        assert_eq!(
            msg,
            "cannot write /full/disk/img.fits: the disk is full or the file is not writable"
        );
        assert!(
            !msg.contains("FitsError") && !msg.contains("status:"),
            "{msg}"
        );
    }

    #[test]
    fn a_missing_or_foreign_file_is_a_sentence() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("nope[2].fits");
        let msg = open_fits(&missing).err().unwrap().to_string();
        assert!(
            msg.starts_with("cannot open ") && msg.contains("nope[2].fits"),
            "{msg}"
        );
        let junk = dir.path().join("junk.fits");
        std::fs::write(&junk, vec![b'x'; 2880]).unwrap();
        let msg = open_fits(&junk).err().unwrap().to_string();
        assert!(
            msg.contains("junk.fits") && msg.contains("not a FITS file"),
            "{msg}"
        );
        let dirless = dir.path().join("no/such/dir.fits");
        let msg = create_fits(&dirless, Primary::default())
            .err()
            .unwrap()
            .to_string();
        assert!(
            msg.starts_with("cannot create ") && msg.contains("dir.fits"),
            "{msg}"
        );
    }
}
