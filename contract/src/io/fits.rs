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
    let f = wrap(path, fptr, fitsio::FileOpenMode::READWRITE)?;
    init_primary(f, path, primary)
}

/// Gives a new, empty file `f` its primary HDU (and the compression asked
/// for); `path` names it in errors.
fn init_primary(mut f: FitsFile, path: &Path, primary: Primary<'_>) -> Result<FitsFile, IoError> {
    let mut status = 0;
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

/// Writes a FITS file built by `fill` atomically to `path` and returns the
/// SHA-256 (lower-case hex) of its bytes: the file is built in memory by
/// cfitsio (`fits_create_memfile`), closed, hashed and written with one
/// [`write_bytes_atomically`](super::write_bytes_atomically) — the same bytes
/// [`create_fits`] + [`finish_fits`] put on disk (test
/// `memory_files_are_the_disk_files_byte_for_byte`), without reading the
/// file back to hash it. `primary` is as in [`create_fits`]; `path` names
/// the file in errors.
pub fn write_fits_hashed(
    path: &Path,
    primary: Primary<'_>,
    fill: impl FnOnce(&mut FitsFile) -> Result<(), IoError>,
) -> Result<String, IoError> {
    let bytes = fits_bytes(path, primary, fill)?;
    super::write_bytes_atomically(path, bytes.as_slice())?;
    Ok(crate::digest::sha256_hex(bytes.as_slice()))
}

/// The bytes of a FITS file built in memory by `fill` (see
/// [`write_fits_hashed`]).
pub fn fits_bytes(
    path: &Path,
    primary: Primary<'_>,
    fill: impl FnOnce(&mut FitsFile) -> Result<(), IoError>,
) -> Result<MemoryFile, IoError> {
    // cfitsio keeps the addresses of the pointer and the size and updates
    // both as the file grows, so they live in a box that does not move.
    let mut mem = Box::new(MemoryFile {
        ptr: std::ptr::null_mut(),
        len: 0,
    });
    let mut fptr = std::ptr::null_mut();
    let mut status = 0;
    // SAFETY: `mem.ptr` and `mem.len` outlive the file (closed below or by
    // the error path before `mem` is dropped); `grow` is a realloc that
    // accepts a null pointer.
    unsafe {
        fitsio::sys::ffimem(
            &mut fptr,
            &mut mem.ptr,
            &mut mem.len,
            0,
            Some(grow),
            &mut status,
        )
    };
    if status != 0 {
        return Err(IoError::fits_status(path, status));
    }
    let f = wrap(path, fptr, fitsio::FileOpenMode::READWRITE)?;
    let mut f = init_primary(f, path, primary)?;
    let filled = fill(&mut f);
    // Closed in every case, so that cfitsio no longer holds `mem`'s addresses.
    let closed = finish_fits(f, path);
    filled?;
    closed?;
    Ok(*mem)
}

/// The bytes of a FITS file built in memory ([`fits_bytes`]).
pub struct MemoryFile {
    ptr: *mut std::os::raw::c_void,
    len: usize,
}

impl MemoryFile {
    /// The file's bytes.
    pub fn as_slice(&self) -> &[u8] {
        if self.ptr.is_null() {
            return &[];
        }
        // SAFETY: `ptr` holds at least `len` bytes written by cfitsio
        // (`grow` never hands out less than asked for).
        unsafe { std::slice::from_raw_parts(self.ptr as *const u8, self.len) }
    }
}

impl Drop for MemoryFile {
    fn drop(&mut self) {
        // SAFETY: `ptr` is null or came from `grow`, and is freed once.
        unsafe { release(self.ptr) }
    }
}

impl std::fmt::Debug for MemoryFile {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "MemoryFile({} bytes)", self.len)
    }
}

/// Bytes before each block `grow` hands out: its capacity.
const HEADER: usize = 16;

fn block_layout(capacity: usize) -> Option<std::alloc::Layout> {
    std::alloc::Layout::from_size_align(capacity.checked_add(HEADER)?, HEADER).ok()
}

/// cfitsio's realloc for memory files. cfitsio grows a memory file one
/// 2880-byte block at a time; this keeps a capacity that at least doubles
/// (stored just before the block), so a 67 MB image costs a few dozen
/// copies rather than thousands, while cfitsio's size stays exact.
unsafe extern "C" fn grow(p: *mut std::os::raw::c_void, size: usize) -> *mut std::os::raw::c_void {
    use std::alloc::{alloc, realloc};
    if p.is_null() {
        let capacity = size.max(1 << 16);
        let Some(layout) = block_layout(capacity) else {
            return std::ptr::null_mut();
        };
        // SAFETY: the layout has a non-zero size.
        let base = unsafe { alloc(layout) };
        if base.is_null() {
            return std::ptr::null_mut();
        }
        // SAFETY: the block starts with HEADER bytes for the capacity.
        unsafe {
            (base as *mut usize).write(capacity);
            return base.add(HEADER) as _;
        }
    }
    // SAFETY: `p` came from this function, HEADER bytes after its block's start.
    let base = unsafe { (p as *mut u8).sub(HEADER) };
    let capacity = unsafe { (base as *const usize).read() };
    if size <= capacity {
        return p;
    }
    let wanted = size.max(capacity.saturating_mul(2));
    let (Some(old), Some(_)) = (block_layout(capacity), block_layout(wanted)) else {
        return std::ptr::null_mut();
    };
    // SAFETY: `base` was allocated with `old`; the new size is valid.
    let moved = unsafe { realloc(base, old, wanted + HEADER) };
    if moved.is_null() {
        return std::ptr::null_mut();
    }
    // SAFETY: as for a new block.
    unsafe {
        (moved as *mut usize).write(wanted);
        moved.add(HEADER) as _
    }
}

/// Frees a block of [`grow`] (null: nothing).
unsafe fn release(p: *mut std::os::raw::c_void) {
    if p.is_null() {
        return;
    }
    // SAFETY: as in `grow`.
    unsafe {
        let base = (p as *mut u8).sub(HEADER);
        let capacity = (base as *const usize).read();
        if let Some(layout) = block_layout(capacity) {
            std::alloc::dealloc(base, layout);
        }
    }
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
    fn memory_files_are_the_disk_files_byte_for_byte() {
        let dir = tempfile::tempdir().unwrap();
        // Big enough that the memory file grows many times (cfitsio asks
        // for 2880 more bytes at a time; `grow` starts at 64 KiB and
        // doubles), plain and Rice-compressed, keys written after the data.
        let (w, h) = (300, 211);
        let data: Vec<i32> = (0..w * h).map(|k| (k as i32 * 7919) % 100_003).collect();
        for rice in [false, true] {
            let dims = [h, w];
            let desc = ImageDescription {
                data_type: ImageType::Long,
                dimensions: &dims,
            };
            let primary = Primary {
                image: Some(&desc),
                rice,
            };
            let fill = |f: &mut FitsFile| -> Result<(), IoError> {
                let last = f.num_hdus().unwrap() - 1;
                let hdu = f.hdu(last).unwrap();
                hdu.write_image(f, &data).unwrap();
                for k in 0..40 {
                    hdu.write_key(f, &format!("KEY{k}"), (k as f64, "a comment"))
                        .unwrap();
                }
                Ok(())
            };
            let disk = dir.path().join(format!("disk-{rice}.fits"));
            let mut f = create_fits(&disk, primary).unwrap();
            fill(&mut f).unwrap();
            finish_fits(f, &disk).unwrap();
            let mem = dir.path().join(format!("mem-{rice}.fits"));
            let sha = write_fits_hashed(&mem, primary, fill).unwrap();
            let (a, b) = (std::fs::read(&disk).unwrap(), std::fs::read(&mem).unwrap());
            assert!(a.len() > 2880 * if rice { 2 } else { 80 }, "{}", a.len());
            assert!(a == b, "rice {rice}: {} vs {} bytes", a.len(), b.len());
            assert_eq!(sha, crate::digest::sha256_hex(&a));
        }
        // A failing fill leaves no file and reports its error.
        let path = dir.path().join("never.fits");
        let err = write_fits_hashed(&path, Primary::default(), |_| {
            Err(IoError::format(Path::new("x"), "boom"))
        })
        .unwrap_err();
        assert_eq!(err.to_string(), "x: boom");
        assert!(!path.exists());
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
