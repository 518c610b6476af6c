//! PSFs kept between the processes of a run (`RUN/private/psf/cache/`).
//!
//! An optical PSF costs 2.5 s to solve (seeing and aberration for the
//! target FWHM and χ, then the transfer function on the final grid); every
//! process of a run — a resumed one, each shard, `--finish` — would pay it
//! again. The first process that builds one stores what was expensive: the
//! solved [`Calibration`] and the band-limited transfer function as
//! [`OpticalPsf::new`] has recentred it (since format 3; before, the band
//! before the recentring, which every load then did again: three inverse
//! FFTs and phase ramps of the band, 2 % of a user's first image). A later
//! process loads it when the file checks and only samples it
//! ([`OpticalPsf::recentred`]), and gets the very same PSF (the sampling is
//! rerun on the loaded values, so the bytes of every image are those of a
//! process that built it: tests
//! `generate_reuses_stored_psfs_across_shards_byte_for_byte` and
//! `load_or_build_stores_reuses_and_rebuilds_the_same_psf`).
//!
//! File `<spec digest>.bin`: a text header, then the content.
//!
//! ```text
//! stepsim psf store 4            format version (FORMAT)
//! spec-sha256 <64 hex>           spec_digest: everything the PSF's bytes depend on
//! content-crc32 <8 hex>          CRC-32 (IEEE) of the content bytes
//! content-bytes <n>
//! <empty line>
//! <n content bytes, little-endian>
//! ```
//!
//! Content: seeing FWHM, λ/r0, amplitude, FWHM, |χ|, the recentring's
//! centroid shift x, y (7 × f64), the amplitude unit (u8: 0 waves, 1
//! arcsec), the aberration's name (u32 length + UTF-8), the grid side nc
//! (u64), the frequency spacing (f64) and the recentred band's nc² complex
//! values (re, im as f64), FFT order.
//!
//! A file is used only when its version, spec digest and content CRC all
//! check and the content parses to exactly its length; anything else (a
//! stale, truncated, tampered or foreign file) is rebuilt, never trusted,
//! and the file is rewritten atomically. Only optical PSFs are stored: the
//! other models build in milliseconds.
//!
//! **The user's store.** Besides the run's own store, a process looks in a
//! store of the user's ([`user_store_dir`]: `STEPSIM_PSF_STORE`, else
//! `$XDG_CACHE_HOME/stepsim/psf`, else `$HOME/.cache/stepsim/psf`;
//! `STEPSIM_PSF_STORE=off` turns it off), so that a new run of a PSF built
//! by any earlier run does not wait for it. A file found there is checked
//! as above and copied into the run's store (the run keeps its private
//! copy, as before); a PSF built here is written to both. The user's store
//! is a cache: a file there that fails a check is ignored and rewritten,
//! and a failure to write there is not an error (the run's own copy is
//! what the run needs). It outlives builds of stepsim, so [`FORMAT`] is
//! part of every digest and must be bumped whenever the solution of a PSF
//! changes: a test pins the solved PSF of one spec
//! (`the_solved_psf_is_pinned_so_a_solver_change_bumps_the_format`). The
//! checks (digest, content CRC) find damage, not forgery: the store is
//! trusted like the binary, so it is made private to the user (0700) and
//! must not be a directory others can write.

use crate::model::psf::optical::BandTransfer;
use crate::model::psf::{
    Calibration, OpticalPsf, OpticalRequest, Psf, PsfAccuracy, PsfError, PsfSpec,
};
use num_complex::{Complex32, Complex64};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use stepsim_contract::digest::sha256_hex;
use stepsim_contract::io::{IoError, write_bytes_atomically};

/// Version of the file format and of what it holds: bump it whenever the
/// solved PSF or this layout changes, so that older files are rebuilt.
pub const FORMAT: u32 = 4;

/// How a PSF of a process came to be.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Origin {
    /// Built here; the model is not stored (not optical: cheap to build).
    Built,
    /// Loaded from `file`, verified.
    Reused {
        /// The file it was loaded from.
        file: PathBuf,
    },
    /// Built here (no file yet) and stored in `file`.
    Stored {
        /// The file written.
        file: PathBuf,
    },
    /// Copied into the run's store (`file`) from the user's store (`from`),
    /// verified.
    Copied {
        /// The run's copy, written.
        file: PathBuf,
        /// The user's store file it came from.
        from: PathBuf,
    },
    /// `file` was there but unusable (`why`): rebuilt and stored again.
    Rebuilt {
        /// The file rewritten.
        file: PathBuf,
        /// Why it was not used (lower case, no full stop).
        why: String,
    },
}

impl std::fmt::Display for Origin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Origin::Built => write!(f, "built"),
            Origin::Reused { file } => write!(f, "reused from {}", file.display()),
            Origin::Stored { file } => write!(f, "built and stored in {}", file.display()),
            Origin::Copied { file, from } => {
                write!(f, "copied from {} to {}", from.display(), file.display())
            }
            Origin::Rebuilt { file, why } => {
                write!(f, "rebuilt ({} {why}) and stored again", file.display())
            }
        }
    }
}

/// Why a PSF could not be had.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// Building it failed.
    #[error(transparent)]
    Psf(#[from] PsfError),
    /// Storing it failed.
    #[error(transparent)]
    Io(#[from] IoError),
}

/// True for the models kept in a store (optical ones).
pub fn is_stored(spec: &PsfSpec) -> bool {
    spec.is_optical()
}

/// Hex SHA-256 of everything the PSF's bytes depend on: the format version,
/// the PSF's entry as the config spells it ([`PsfSpec::entry_json`]: model,
/// FWHM, aberration, amplitude or target χ, angle, name), the telescope,
/// the pixel scale and the accuracy settings.
pub fn spec_digest(spec: &PsfSpec, accuracy: &PsfAccuracy) -> String {
    let text = format!(
        "stepsim psf store {FORMAT}\nentry {}\ntelescope {}\npixel_scale_arcsec {:?}\naccuracy {:?}\n",
        spec.entry_json(),
        serde_json::to_string(&spec.telescope).expect("the telescope serialises"),
        spec.pixel_scale_arcsec,
        accuracy,
    );
    sha256_hex(text.as_bytes())
}

/// The file of `spec` in the store directory `dir`.
pub fn file_for(dir: &Path, spec: &PsfSpec, accuracy: &PsfAccuracy) -> PathBuf {
    dir.join(format!("{}.bin", spec_digest(spec, accuracy)))
}

/// The environment variable naming the user's PSF store (a directory), or
/// `off` for none.
pub const USER_STORE_ENV: &str = "STEPSIM_PSF_STORE";

/// The user's PSF store: `STEPSIM_PSF_STORE` when set (`off` or empty: no
/// store), else `$XDG_CACHE_HOME/stepsim/psf` (an absolute
/// `XDG_CACHE_HOME`), else `$HOME/.cache/stepsim/psf`, else none.
pub fn user_store_dir() -> Option<PathBuf> {
    user_store_dir_from(|k| std::env::var_os(k))
}

/// [`user_store_dir`] with the environment read by `var`.
pub fn user_store_dir_from(var: impl Fn(&str) -> Option<std::ffi::OsString>) -> Option<PathBuf> {
    if let Some(v) = var(USER_STORE_ENV) {
        return (!v.is_empty() && v != "off").then(|| PathBuf::from(v));
    }
    let absolute = |v: std::ffi::OsString| {
        let p = PathBuf::from(v);
        p.is_absolute().then_some(p)
    };
    var("XDG_CACHE_HOME")
        .and_then(absolute)
        .or_else(|| var("HOME").and_then(absolute).map(|h| h.join(".cache")))
        .map(|c| c.join("stepsim").join("psf"))
}

/// A store file read and checked: its bytes and the PSF they hold.
type Stored = (Vec<u8>, BandTransfer, Calibration);

/// The stored PSF in `file`, or why not (`None`: no such file).
fn read_stored(file: &Path, digest: &str) -> Option<Result<Stored, String>> {
    match std::fs::read(file) {
        Ok(bytes) => Some(parse(&bytes, digest).map(|(band, cal)| (bytes, band, cal))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => Some(Err(format!("could not be read: {e}"))),
    }
}

/// Writes `bytes` to `path` in the user's store: the directory made
/// private to the user (0700) when it is created, the temporary file
/// created anew (never through an existing file or link of that name)
/// and private (0600), then renamed over `path`.
fn write_private(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    use std::os::unix::fs::{DirBuilderExt, OpenOptionsExt};
    if let Some(dir) = path.parent() {
        std::fs::DirBuilder::new()
            .recursive(true)
            .mode(0o700)
            .create(dir)?;
    }
    let tmp = stepsim_contract::io::temporary_name(path);
    let open = || {
        std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .mode(0o600)
            .open(&tmp)
    };
    let mut f = match open() {
        Ok(f) => f,
        // A temporary left by a process that died: removed (a link is
        // removed, not followed), then created anew.
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
            std::fs::remove_file(&tmp)?;
            open()?
        }
        Err(e) => return Err(e),
    };
    let written = f.write_all(bytes).and_then(|()| f.sync_all());
    drop(f);
    match written.and_then(|()| std::fs::rename(&tmp, path)) {
        Ok(()) => Ok(()),
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}

/// The PSF of `spec`: loaded from the store `dir` when its file checks,
/// otherwise built (and, for optical models, stored).
pub fn load_or_build(
    spec: &PsfSpec,
    accuracy: &PsfAccuracy,
    dir: &Path,
) -> Result<(Arc<dyn Psf>, Origin), StoreError> {
    load_or_build_shared(spec, accuracy, dir, None)
}

/// [`load_or_build`] with the user's store `user` as well: a PSF not in
/// the run's store `dir` is copied from `user` when its file there checks;
/// one built here is stored in both (a failure to write to `user` is
/// ignored: it is a cache).
pub fn load_or_build_shared(
    spec: &PsfSpec,
    accuracy: &PsfAccuracy,
    dir: &Path,
    user: Option<&Path>,
) -> Result<(Arc<dyn Psf>, Origin), StoreError> {
    let Some(request) = OpticalRequest::of(spec) else {
        return Ok((
            crate::model::psf::build_with(spec, accuracy)?,
            Origin::Built,
        ));
    };
    let digest = spec_digest(spec, accuracy);
    let name = format!("{digest}.bin");
    let file = dir.join(&name);
    let why = match read_stored(&file, &digest) {
        Some(Ok((_, band, cal))) => {
            let psf = Arc::new(OpticalPsf::recentred(band, cal));
            return Ok((psf, Origin::Reused { file }));
        }
        Some(Err(why)) => Some(why),
        None => None,
    };
    let shared = user.map(|u| u.join(&name));
    if let Some(from) = &shared
        && let Some(Ok((bytes, band, cal))) = read_stored(from, &digest)
    {
        write_bytes_atomically(&file, &bytes)?;
        let psf = Arc::new(OpticalPsf::recentred(band, cal));
        let from = from.clone();
        return Ok((psf, Origin::Copied { file, from }));
    }
    let (band, cal) = crate::model::psf::solve_optical(&request, accuracy)?;
    let psf = OpticalPsf::new(band, cal);
    let bytes = encode(psf.band(), psf.calibration_ref(), &digest);
    write_bytes_atomically(&file, &bytes)?;
    if let Some(from) = &shared {
        // A cache: a store that cannot be written costs the next run its
        // PSF build, nothing else.
        let _ = write_private(from, &bytes);
    }
    let psf = Arc::new(psf);
    let origin = match why {
        None => Origin::Stored { file },
        Some(why) => Origin::Rebuilt { file, why },
    };
    Ok((psf, origin))
}

/// The whole file of a PSF: header and content.
pub fn encode(band: &BandTransfer, cal: &Calibration, spec_digest: &str) -> Vec<u8> {
    let mut c = Vec::with_capacity(128 + band.t.len() * 16);
    for v in [
        cal.seeing_fwhm_arcsec,
        cal.lambda_over_r0_arcsec,
        cal.amplitude,
        cal.fwhm_arcsec,
        cal.chi_abs,
        cal.centroid_shift_arcsec.0,
        cal.centroid_shift_arcsec.1,
    ] {
        c.extend_from_slice(&v.to_le_bytes());
    }
    c.push(u8::from(cal.amplitude_unit == "arcsec"));
    c.extend_from_slice(&(cal.aberration.len() as u32).to_le_bytes());
    c.extend_from_slice(cal.aberration.as_bytes());
    c.extend_from_slice(&(band.nc as u64).to_le_bytes());
    c.extend_from_slice(&band.du.to_le_bytes());
    for z in &band.t {
        c.extend_from_slice(&z.re.to_le_bytes());
        c.extend_from_slice(&z.im.to_le_bytes());
    }
    frame(&format!("stepsim psf store {FORMAT}"), spec_digest, &c)
}

/// A store file: the header (`version` line, the spec digest, the
/// content's CRC-32 and length, an empty line), then `content`.
///
/// A CRC-32, not a SHA-256 (since store format 4, drawn-file format 4 and
/// transfer format 2, 2026-12-05): the check is for damage, not forgery
/// (the store is the user's, trusted like the binary), and checking a
/// first image's 23 MB of store files took 2 % of its CPU with SHA-256.
fn frame(version: &str, spec_digest: &str, content: &[u8]) -> Vec<u8> {
    let mut out = format!(
        "{version}\nspec-sha256 {spec_digest}\ncontent-crc32 {:08x}\ncontent-bytes {}\n\n",
        crc32fast::hash(content),
        content.len()
    )
    .into_bytes();
    out.extend_from_slice(content);
    out
}

/// The stored PSF of a file whose spec digest must be `want_spec`, or why
/// it cannot be used (lower case, no full stop).
pub fn parse(bytes: &[u8], want_spec: &str) -> Result<(BandTransfer, Calibration), String> {
    let content = unframe(
        bytes,
        &format!("stepsim psf store {FORMAT}"),
        FORMAT,
        want_spec,
    )?;
    decode(content).ok_or_else(|| "has content that does not parse".into())
}

/// The content of a store file written by [`frame`] with `version` (of
/// number `number`) for spec digest `want_spec`, or why it cannot be used.
fn unframe<'a>(
    bytes: &'a [u8],
    version: &str,
    number: u32,
    want_spec: &str,
) -> Result<&'a [u8], String> {
    let end = bytes
        .windows(2)
        .position(|w| w == b"\n\n")
        .filter(|&i| i < 4096)
        .ok_or("has no header (not a PSF store file)")?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "has a header that is not text")?;
    let content = &bytes[end + 2..];
    let lines: Vec<&str> = header.lines().collect();
    let [_, spec, crc, len] = lines[..] else {
        return Err("has a header of the wrong shape (not a PSF store file)".into());
    };
    if lines[0] != version {
        return Err(format!(
            "is of another format (`{}`, this stepsim reads version {number})",
            lines[0]
        ));
    }
    if spec.strip_prefix("spec-sha256 ") != Some(want_spec) {
        return Err("was made for another PSF spec (its spec digest differs)".into());
    }
    let n: usize = len
        .strip_prefix("content-bytes ")
        .and_then(|v| v.parse().ok())
        .ok_or("has no valid content length")?;
    if content.len() != n {
        return Err(format!(
            "is truncated or padded ({} content bytes, the header says {n})",
            content.len()
        ));
    }
    if crc.strip_prefix("content-crc32 ")
        != Some(format!("{:08x}", crc32fast::hash(content)).as_str())
    {
        return Err("has content that does not match its CRC-32 (damaged or edited)".into());
    }
    Ok(content)
}

/// Version of the transfer files kept in the user's store
/// ([`provide_transfers`]): bump it whenever a PSF's transfer on a grid
/// changes for a given spec (the chirp-z transform, the sampling, FORMAT's
/// PSF itself), so that older files are computed again.
pub const TRANSFER_FORMAT: u32 = 2;

/// Hex SHA-256 naming the transfer file of the PSF of `spec_digest`
/// ([`spec_digest`]) on an `n`-pixel grid.
pub fn transfer_digest(spec_digest: &str, n: usize) -> String {
    sha256_hex(
        format!("stepsim psf transfer {TRANSFER_FORMAT}\npsf {spec_digest}\nn {n}\n").as_bytes(),
    )
}

/// Hands `psf` (of spec `spec` at `accuracy`) its transfer on each of
/// `grids` from the user's store `user` when a file there checks
/// (`<transfer digest>.t.bin`: the frame the other store files have, then n · (n/2 + 1)
/// complex values as little-endian f32 pairs, the grid's row-major order);
/// any other grid's is computed here and kept there (a cache: a failure to
/// keep it is ignored). Only optical PSFs, whose transfer on a large grid
/// is a chirp-z transform of their samples (about 0.03 s on the 1350-pixel
/// tile of a 4096² image); the run's own store does not keep them (each
/// process computes what the user's store lacks). Returns how many came
/// from the store.
pub fn provide_transfers(
    psf: &dyn Psf,
    spec: &PsfSpec,
    accuracy: &PsfAccuracy,
    grids: &[crate::model::psf::StampGrid],
    user: Option<&Path>,
) -> usize {
    let (Some(user), Some(_)) = (user, OpticalRequest::of(spec)) else {
        return 0;
    };
    let spec = spec_digest(spec, accuracy);
    let version = format!("stepsim psf transfer {TRANSFER_FORMAT}");
    let mut found = 0;
    for &grid in grids {
        let digest = transfer_digest(&spec, grid.n);
        let file = user.join(format!("{digest}.t.bin"));
        let len = grid.n * grid.n_cols();
        let stored = std::fs::read(&file).ok().and_then(|bytes| {
            let content = unframe(&bytes, &version, TRANSFER_FORMAT, &digest).ok()?;
            (content.len() == len * 8).then(|| {
                content
                    .chunks_exact(8)
                    .map(|z| {
                        let re = f32::from_le_bytes(z[..4].try_into().expect("4 bytes"));
                        let im = f32::from_le_bytes(z[4..].try_into().expect("4 bytes"));
                        Complex32::new(re, im)
                    })
                    .collect::<Vec<_>>()
            })
        });
        match stored {
            Some(t) => {
                psf.provide_transfer(grid, Arc::new(t));
                found += 1;
            }
            None => {
                let t = psf.transfer(grid);
                let mut content = Vec::with_capacity(t.len() * 8);
                for z in t.iter() {
                    content.extend_from_slice(&z.re.to_le_bytes());
                    content.extend_from_slice(&z.im.to_le_bytes());
                }
                let _ = write_private(&file, &frame(&version, &digest, &content));
            }
        }
    }
    found
}

/// Version of the drawn PSF files (`RUN/private/psf/<name>.fits`) kept in
/// the user's store: bump it whenever the bytes of such a file change for a
/// given PSF (its drawing, its report, the FITS writer), so that older
/// files are drawn again. A test pins one file's bytes
/// (`the_drawn_psf_file_is_pinned_so_a_change_bumps_its_format`).
pub const FILE_FORMAT: u32 = 4;

/// Hex SHA-256 naming the drawn file of the PSF of `spec_digest`
/// ([`spec_digest`]) at `side_px` pixels with `oversample`.
pub fn file_digest(spec_digest: &str, side_px: usize, oversample: usize) -> String {
    sha256_hex(
        format!(
            "stepsim psf file {FILE_FORMAT}\npsf {spec_digest}\nside_px {side_px}\noversample {oversample}\n"
        )
        .as_bytes(),
    )
}

/// Writes a PSF's drawn file `path` (drawing and measuring it took 13 % of
/// a one-image run's CPU in a profile, docs/psf.md): copied
/// from the user's store `user` when a file there of digest `digest`
/// ([`file_digest`]) checks, otherwise written by `draw` and then kept
/// there (a cache: a failure to keep it is ignored). True when copied.
pub fn write_drawn_file(
    path: &Path,
    digest: &str,
    user: Option<&Path>,
    draw: impl FnOnce(&Path) -> Result<(), IoError>,
) -> Result<bool, IoError> {
    let version = format!("stepsim psf file {FILE_FORMAT}");
    let stored = user.map(|u| u.join(format!("{digest}.fits.bin")));
    if let Some(from) = &stored
        && let Ok(bytes) = std::fs::read(from)
        && let Ok(content) = unframe(&bytes, &version, FILE_FORMAT, digest)
    {
        write_bytes_atomically(path, content)?;
        return Ok(true);
    }
    draw(path)?;
    if let Some(to) = &stored
        && let Ok(content) = std::fs::read(path)
    {
        let _ = write_private(to, &frame(&version, digest, &content));
    }
    Ok(false)
}

fn decode(c: &[u8]) -> Option<(BandTransfer, Calibration)> {
    let mut at = 0usize;
    let mut take = |n: usize| -> Option<&[u8]> {
        let s = c.get(at..at.checked_add(n)?)?;
        at += n;
        Some(s)
    };
    let mut f = [0.0f64; 7];
    for v in &mut f {
        *v = f64::from_le_bytes(take(8)?.try_into().ok()?);
    }
    let unit = match take(1)?[0] {
        0 => "waves",
        1 => "arcsec",
        _ => return None,
    };
    let name_len = u32::from_le_bytes(take(4)?.try_into().ok()?) as usize;
    let aberration = std::str::from_utf8(take(name_len)?).ok()?.to_string();
    let nc = usize::try_from(u64::from_le_bytes(take(8)?.try_into().ok()?)).ok()?;
    let du = f64::from_le_bytes(take(8)?.try_into().ok()?);
    let count = nc.checked_mul(nc)?;
    let values = take(count.checked_mul(16)?)?;
    if at != c.len() || nc == 0 || !du.is_finite() || du <= 0.0 {
        return None;
    }
    let t = values
        .chunks_exact(16)
        .map(|z| {
            let re = f64::from_le_bytes(z[..8].try_into().expect("8 bytes"));
            let im = f64::from_le_bytes(z[8..].try_into().expect("8 bytes"));
            Complex64::new(re, im)
        })
        .collect();
    let cal = Calibration {
        seeing_fwhm_arcsec: f[0],
        lambda_over_r0_arcsec: f[1],
        aberration,
        amplitude: f[2],
        amplitude_unit: unit,
        fwhm_arcsec: f[3],
        chi_abs: f[4],
        centroid_shift_arcsec: (f[5], f[6]),
    };
    Some((BandTransfer { nc, du, t }, cal))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::psf::{Aberration, PsfModel, Telescope};

    fn spec(target_chi: f64) -> PsfSpec {
        let model = PsfModel::Optical {
            aberration: Aberration::Coma,
            amplitude: None,
            target_chi: Some(target_chi),
            angle_deg: 0.0,
        };
        PsfSpec::new("coma", 0.9, model, Telescope::default(), 0.206)
    }

    fn small() -> PsfAccuracy {
        PsfAccuracy {
            pupil_grid: 512,
            calibration_grid: 512,
            ..PsfAccuracy::default()
        }
    }

    fn sample_psf() -> (BandTransfer, Calibration) {
        let nc = 4;
        let t = (0..nc * nc)
            .map(|k| Complex64::new(1.0 / (1.0 + k as f64), -0.25 * k as f64))
            .collect();
        let cal = Calibration {
            seeing_fwhm_arcsec: 0.82,
            lambda_over_r0_arcsec: 0.84,
            aberration: "coma".into(),
            amplitude: 0.291,
            amplitude_unit: "waves",
            fwhm_arcsec: 0.9002,
            chi_abs: 0.0399,
            centroid_shift_arcsec: (0.01, -0.02),
        };
        (BandTransfer { nc, du: 0.125, t }, cal)
    }

    #[test]
    fn a_stored_psf_reads_back_exactly_and_nothing_else_is_trusted() {
        let (band, cal) = sample_psf();
        let d = "ab".repeat(32);
        let bytes = encode(&band, &cal, &d);
        let (b2, c2) = parse(&bytes, &d).unwrap();
        assert_eq!((b2.nc, b2.du, &b2.t), (band.nc, band.du, &band.t));
        assert_eq!(c2, cal);
        // Another spec, a truncation, one flipped bit of the content or of
        // the header, another version, junk: each refused with its reason.
        let why = parse(&bytes, &"cd".repeat(32)).unwrap_err();
        assert!(why.contains("another PSF spec"), "{why}");
        let why = parse(&bytes[..bytes.len() - 1], &d).unwrap_err();
        assert!(why.contains("truncated"), "{why}");
        let mut bad = bytes.clone();
        let last = bad.len() - 3;
        bad[last] ^= 1;
        let why = parse(&bad, &d).unwrap_err();
        assert!(why.contains("does not match its CRC-32"), "{why}");
        let other =
            String::from_utf8_lossy(&bytes[..20]).replace(&format!("store {FORMAT}"), "store 9");
        let mut old = other.into_bytes();
        old.extend_from_slice(&bytes[20..]);
        let why = parse(&old, &d).unwrap_err();
        assert!(why.contains("another format"), "{why}");
        assert!(parse(b"SIMPLE  = T", &d).unwrap_err().contains("no header"));
    }

    #[test]
    fn the_spec_digest_changes_with_everything_the_psf_depends_on() {
        let acc = PsfAccuracy::default();
        let base = spec_digest(&spec(0.04), &acc);
        assert_eq!(base, spec_digest(&spec(0.04), &acc));
        assert_ne!(base, spec_digest(&spec(0.05), &acc));
        let mut s = spec(0.04);
        s.pixel_scale_arcsec = 0.2;
        assert_ne!(base, spec_digest(&s, &acc));
        let mut s = spec(0.04);
        s.telescope.diameter_m = 4.0;
        assert_ne!(base, spec_digest(&s, &acc));
        assert_ne!(base, spec_digest(&spec(0.04), &small()));
    }

    #[test]
    fn the_solved_psf_is_pinned_so_a_solver_change_bumps_the_format() {
        // The user's store outlives builds: a solver whose result changes
        // must bump FORMAT (so that no new build reuses an old solution)
        // and record the new content hash here.
        let (s, acc) = (spec(0.04), small());
        let request = OpticalRequest::of(&s).unwrap();
        let (band, cal) = crate::model::psf::solve_optical(&request, &acc).unwrap();
        let psf = OpticalPsf::new(band, cal);
        let file = encode(psf.band(), psf.calibration_ref(), &spec_digest(&s, &acc));
        let at = file.windows(2).position(|w| w == b"\n\n").unwrap();
        let content = sha256_hex(&file[at + 2..]);
        assert_eq!(
            (FORMAT, content.as_str()),
            (4, PINNED_CONTENT_SHA256),
            "the solved PSF changed: bump FORMAT and record the new hash"
        );
    }

    #[test]
    fn the_drawn_psf_file_is_pinned_so_a_change_bumps_its_format() {
        // A drawn PSF file kept in the user's store outlives builds: a
        // change of its bytes (drawing, report, writer) must bump
        // FILE_FORMAT and record the new hash here. Drawn twice: the same
        // bytes.
        let (s, acc) = (spec(0.04), small());
        let request = OpticalRequest::of(&s).unwrap();
        let (band, cal) = crate::model::psf::solve_optical(&request, &acc).unwrap();
        let psf = OpticalPsf::new(band, cal);
        let tmp = tempfile::tempdir().unwrap();
        let draw = |name: &str| {
            let path = tmp.path().join(name);
            crate::io::psf_fits::draw_and_write(&path, &psf, "coma", 0.206, 64).unwrap();
            sha256_hex(&std::fs::read(path).unwrap())
        };
        let first = draw("a.fits");
        assert_eq!(first, draw("b.fits"), "drawn twice, different bytes");
        assert_eq!(
            (FILE_FORMAT, first.as_str()),
            (4, PINNED_FILE_SHA256),
            "the drawn PSF file changed: bump FILE_FORMAT and record the new hash"
        );
    }

    /// SHA-256 of the 64-pixel file of the coma PSF of
    /// `the_drawn_psf_file_is_pinned_so_a_change_bumps_its_format`.
    const PINNED_FILE_SHA256: &str =
        "229b012b44fb6d00dad5a82106294efc58b9e3a708c0e282c5c8b8163e9eec23";

    #[test]
    fn a_drawn_file_is_kept_in_the_users_store_and_copied_from_it() {
        let tmp = tempfile::tempdir().unwrap();
        let store = tmp.path().join("store");
        let digest = file_digest(&"ab".repeat(32), 64, 4);
        let drawn = std::cell::Cell::new(0);
        let draw = |path: &Path| {
            drawn.set(drawn.get() + 1);
            write_bytes_atomically(path, b"SIMPLE = the drawn file")
        };
        let run = |name: &str, user: Option<&Path>| {
            let path = tmp.path().join("run").join(name);
            let copied = write_drawn_file(&path, &digest, user, draw).unwrap();
            (copied, std::fs::read(path).unwrap())
        };
        // No store: drawn each time, nothing kept.
        assert_eq!(
            run("a.fits", None),
            (false, b"SIMPLE = the drawn file".to_vec())
        );
        assert!(!store.exists());
        // The first run with a store draws and keeps; the next copies.
        assert!(!run("b.fits", Some(&store)).0);
        assert_eq!(drawn.get(), 2);
        assert_eq!(
            run("c.fits", Some(&store)),
            (true, b"SIMPLE = the drawn file".to_vec())
        );
        assert_eq!(drawn.get(), 2);
        // Another file's digest is not this file.
        let other = file_digest(&"ab".repeat(32), 65, 4);
        assert_ne!(other, digest);
        // A damaged store file is drawn again and rewritten.
        let kept = store.join(format!("{digest}.fits.bin"));
        let mut bytes = std::fs::read(&kept).unwrap();
        *bytes.last_mut().unwrap() ^= 1;
        std::fs::write(&kept, &bytes).unwrap();
        assert!(!run("d.fits", Some(&store)).0);
        assert_eq!(drawn.get(), 3);
        assert_eq!(
            run("e.fits", Some(&store)),
            (true, b"SIMPLE = the drawn file".to_vec())
        );
    }

    /// SHA-256 of the content of the coma PSF of `spec(0.04)` at `small()`
    /// accuracy, as FORMATs 3 and 4 keep it (the band recentred; 4 checks it
    /// by a CRC-32 instead of a SHA-256; FORMAT 2 kept it before the
    /// recentring, content 7562b30f…; FFTs with the same bits on every CPU
    /// since 2026-12-05; FORMAT 1 used its FFTs by CPU).
    const PINNED_CONTENT_SHA256: &str =
        "cb38ac9e55832e52f9ed745fbb178cab74430d7e3ffbee3f7cc93955fb878c21";

    #[test]
    #[cfg(unix)]
    fn the_users_store_is_private_and_never_written_through_a_link() {
        use std::os::unix::fs::PermissionsExt;
        let tmp = tempfile::tempdir().unwrap();
        let store = tmp.path().join("new/store");
        let file = store.join("x.bin");
        write_private(&file, b"one").unwrap();
        let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode(&store), 0o700);
        assert_eq!(mode(&file), 0o600);
        // A link planted at the temporary's name is replaced, not followed.
        let victim = tmp.path().join("victim");
        std::fs::write(&victim, b"keep").unwrap();
        std::os::unix::fs::symlink(&victim, stepsim_contract::io::temporary_name(&file)).unwrap();
        write_private(&file, b"two").unwrap();
        assert_eq!(std::fs::read(&victim).unwrap(), b"keep");
        assert_eq!(std::fs::read(&file).unwrap(), b"two");
    }

    #[test]
    fn the_users_store_is_found_where_the_environment_says() {
        use std::ffi::OsString;
        let env = |pairs: &[(&str, &str)]| {
            let m: std::collections::HashMap<String, OsString> = pairs
                .iter()
                .map(|(k, v)| (k.to_string(), OsString::from(v)))
                .collect();
            move |k: &str| m.get(k).cloned()
        };
        let home = [("HOME", "/home/ann")];
        assert_eq!(
            user_store_dir_from(env(&home)),
            Some(PathBuf::from("/home/ann/.cache/stepsim/psf"))
        );
        assert_eq!(
            user_store_dir_from(env(&[("HOME", "/home/ann"), ("XDG_CACHE_HOME", "/c")])),
            Some(PathBuf::from("/c/stepsim/psf"))
        );
        // A relative XDG_CACHE_HOME is ignored, as the XDG rules say.
        assert_eq!(
            user_store_dir_from(env(&[("HOME", "/home/ann"), ("XDG_CACHE_HOME", "c")])),
            Some(PathBuf::from("/home/ann/.cache/stepsim/psf"))
        );
        assert_eq!(
            user_store_dir_from(env(&[("HOME", "/h"), ("STEPSIM_PSF_STORE", "/s")])),
            Some(PathBuf::from("/s"))
        );
        for off in ["off", ""] {
            assert_eq!(
                user_store_dir_from(env(&[("HOME", "/h"), ("STEPSIM_PSF_STORE", off)])),
                None
            );
        }
        assert_eq!(user_store_dir_from(env(&[])), None);
    }

    #[test]
    fn a_psf_built_once_is_copied_from_the_users_store_and_is_the_same() {
        let (a, b, c, user) = (
            tempfile::tempdir().unwrap(),
            tempfile::tempdir().unwrap(),
            tempfile::tempdir().unwrap(),
            tempfile::tempdir().unwrap(),
        );
        let u = user.path().join("nested/store");
        let (s, acc) = (spec(0.04), small());
        let (first, o1) = load_or_build_shared(&s, &acc, a.path(), Some(&u)).unwrap();
        let (fa, fu) = (file_for(a.path(), &s, &acc), file_for(&u, &s, &acc));
        assert_eq!(o1, Origin::Stored { file: fa.clone() });
        let bytes = std::fs::read(&fa).unwrap();
        assert_eq!(std::fs::read(&fu).unwrap(), bytes);
        let (second, o2) = load_or_build_shared(&s, &acc, b.path(), Some(&u)).unwrap();
        let fb = file_for(b.path(), &s, &acc);
        assert_eq!(
            o2,
            Origin::Copied {
                file: fb.clone(),
                from: fu.clone()
            }
        );
        assert_eq!(std::fs::read(&fb).unwrap(), bytes);
        let grid = crate::model::psf::StampGrid::new(48, 0.206);
        assert_eq!(*second.transfer(grid), *first.transfer(grid));
        assert_eq!(second.calibration(), first.calibration());
        // The run's own copy comes first (the user's is not read again).
        std::fs::write(&fu, b"junk").unwrap();
        let (_, o3) = load_or_build_shared(&s, &acc, b.path(), Some(&u)).unwrap();
        assert_eq!(o3, Origin::Reused { file: fb });
        // A damaged user's file is built over and rewritten.
        let (_, o4) = load_or_build_shared(&s, &acc, c.path(), Some(&u)).unwrap();
        assert_eq!(
            o4,
            Origin::Stored {
                file: file_for(c.path(), &s, &acc)
            }
        );
        assert_eq!(std::fs::read(&fu).unwrap(), bytes);
        // A user's store that cannot be written is no error.
        let blocked = user.path().join("a-file");
        std::fs::write(&blocked, b"x").unwrap();
        let d = tempfile::tempdir().unwrap();
        let (_, o5) = load_or_build_shared(&s, &acc, d.path(), Some(&blocked.join("sub"))).unwrap();
        assert!(matches!(o5, Origin::Stored { .. }), "{o5:?}");
    }

    #[test]
    fn transfers_are_kept_in_the_users_store_and_handed_back_the_same() {
        let (s, acc) = (spec(0.04), small());
        let (dir, user) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
        let u = user.path().join("store");
        let grids = [
            crate::model::psf::StampGrid::new(64, 0.206),
            crate::model::psf::StampGrid::new(90, 0.206),
        ];
        let fresh = || load_or_build(&s, &acc, dir.path()).unwrap().0;
        // Computed and kept the first time; handed back the next.
        let first = fresh();
        assert_eq!(
            provide_transfers(first.as_ref(), &s, &acc, &grids, Some(&u)),
            0
        );
        let second = fresh();
        assert_eq!(
            provide_transfers(second.as_ref(), &s, &acc, &grids, Some(&u)),
            2
        );
        let third = fresh();
        for g in grids {
            // `second` holds the stored copies, `third` computes its own.
            assert_eq!(*second.transfer(g), *third.transfer(g));
            assert_eq!(*second.transfer(g), *first.transfer(g));
        }
        // A damaged file is not used (and is written again); no store, a
        // model that is not optical: nothing read or written.
        let file = u.join(format!(
            "{}.t.bin",
            transfer_digest(&spec_digest(&s, &acc), 90)
        ));
        let good = std::fs::read(&file).unwrap();
        let mut bad = good.clone();
        let last = bad.len() - 5;
        bad[last] ^= 4;
        std::fs::write(&file, &bad).unwrap();
        let fourth = fresh();
        assert_eq!(
            provide_transfers(fourth.as_ref(), &s, &acc, &grids, Some(&u)),
            1
        );
        assert_eq!(std::fs::read(&file).unwrap(), good);
        assert_eq!(*fourth.transfer(grids[1]), *third.transfer(grids[1]));
        assert_eq!(
            provide_transfers(fresh().as_ref(), &s, &acc, &grids, None),
            0
        );
        let gaussian = PsfModel::Gaussian { e1: 0.0, e2: 0.0 };
        let g = PsfSpec::new("g", 0.9, gaussian, Telescope::default(), 0.206);
        let other = tempfile::tempdir().unwrap();
        let gpsf = crate::model::psf::build_with(&g, &acc).unwrap();
        assert_eq!(
            provide_transfers(gpsf.as_ref(), &g, &acc, &grids, Some(other.path())),
            0
        );
        assert_eq!(std::fs::read_dir(other.path()).unwrap().count(), 0);
        // A transfer of the wrong length is not taken.
        let psf = fresh();
        psf.provide_transfer(grids[0], Arc::new(vec![Complex32::new(9.0, 9.0); 3]));
        assert_eq!(*psf.transfer(grids[0]), *third.transfer(grids[0]));
    }

    #[test]
    fn load_or_build_stores_reuses_and_rebuilds_the_same_psf() {
        let dir = tempfile::tempdir().unwrap();
        let (s, acc) = (spec(0.04), small());
        let (built, o1) = load_or_build(&s, &acc, dir.path()).unwrap();
        let file = file_for(dir.path(), &s, &acc);
        assert_eq!(o1, Origin::Stored { file: file.clone() });
        let (again, o2) = load_or_build(&s, &acc, dir.path()).unwrap();
        assert_eq!(o2, Origin::Reused { file: file.clone() });
        // The very same PSF as building it directly (and as the first).
        let direct = crate::model::psf::build_with(&s, &acc).unwrap();
        let grid = crate::model::psf::StampGrid::new(48, 0.206);
        let t = direct.transfer(grid);
        assert_eq!(*built.transfer(grid), *t);
        assert_eq!(*again.transfer(grid), *t);
        assert_eq!(again.calibration(), direct.calibration());
        // A damaged file is rebuilt (saying why) and rewritten whole.
        let good = std::fs::read(&file).unwrap();
        std::fs::write(&file, &good[..good.len() / 2]).unwrap();
        let (fixed, o3) = load_or_build(&s, &acc, dir.path()).unwrap();
        assert!(
            matches!(&o3, Origin::Rebuilt { why, .. } if why.contains("truncated")),
            "{o3:?}"
        );
        assert_eq!(*fixed.transfer(grid), *t);
        assert_eq!(std::fs::read(&file).unwrap(), good);
        // Another config's file under this name is not used.
        let other = spec(0.05);
        let (_, _) = load_or_build(&other, &acc, dir.path()).unwrap();
        std::fs::copy(file_for(dir.path(), &other, &acc), &file).unwrap();
        let (_, o4) = load_or_build(&s, &acc, dir.path()).unwrap();
        assert!(
            matches!(&o4, Origin::Rebuilt { why, .. } if why.contains("another PSF spec")),
            "{o4:?}"
        );
        // Non-optical models are built, never stored.
        let gaussian = PsfModel::Gaussian { e1: 0.0, e2: 0.0 };
        let g = PsfSpec::new("g", 0.9, gaussian, Telescope::default(), 0.206);
        assert!(!is_stored(&g) && is_stored(&s));
        assert_eq!(
            load_or_build(&g, &acc, dir.path()).unwrap().1,
            Origin::Built
        );
    }
}
