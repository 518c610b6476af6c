//! Files of a run: the I/O error that names the file, atomic writes, FITS
//! files opened and created by their plain names, truth tables and the
//! reading of public images.
//!
//! Every writer goes through [`write_atomically`]: the file is written under a
//! temporary name in the same directory and renamed into place only when
//! complete, so a killed run never leaves a truncated file under a final name.

pub mod fits;
pub mod image;
pub mod truth;

use std::path::{Path, PathBuf};

/// An I/O error naming the file.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// Operating-system error.
    // Named `error`, not `source`: the message already shows it, and a
    // `source` would make the CLI's error chain print it twice.
    #[error("{path}: {error}")]
    Os {
        /// The file.
        path: PathBuf,
        /// The error.
        error: std::io::Error,
    },
    /// cfitsio error, as a sentence that names the file
    /// ([`fits::status_sentence`]).
    #[error("{message}")]
    Fits {
        /// The file.
        path: PathBuf,
        /// The sentence (names the file).
        message: String,
    },
    /// The file's content is not what was expected.
    #[error("{path}: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong (names line and column where they exist).
        message: String,
    },
}

impl IoError {
    /// Wraps an OS error.
    pub fn os(path: &Path, source: std::io::Error) -> Self {
        Self::Os {
            path: path.into(),
            error: source,
        }
    }
    /// Wraps an error of the fitsio crate as a sentence naming the file
    /// (cfitsio statuses are translated, never shown as structs).
    pub fn fits(path: &Path, e: fitsio::errors::Error) -> Self {
        use fitsio::errors::Error;
        let p = path.display();
        let message = match e {
            Error::Fits(f) => fits::status_sentence(path, f.status),
            Error::ExistingFile(_) => format!("cannot create {p}: the file exists"),
            Error::Message(m) => format!("{p}: {m}"),
            Error::Index(i) => format!("{p}: {}", i.message),
            Error::Io(io) => format!("{p}: {io}"),
            other => format!("{p}: {other}"),
        };
        Self::Fits {
            path: path.into(),
            message,
        }
    }
    /// A cfitsio status as a sentence naming the file.
    pub fn fits_status(path: &Path, status: i32) -> Self {
        Self::Fits {
            path: path.into(),
            message: fits::status_sentence(path, status),
        }
    }
    /// A content error.
    pub fn format(path: &Path, message: impl Into<String>) -> Self {
        Self::Format {
            path: path.into(),
            message: message.into(),
        }
    }
}

/// The temporary name used while `path` is written: same directory, so the
/// final rename is atomic; ends in `.tmp` so that it is never mistaken for a
/// finished file. The process id keeps two concurrent writers apart.
pub fn temporary_name(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

/// The process id of the writer of a temporary file made by
/// [`temporary_name`] (`.<name>.<pid>.tmp`), or `None` if `path` is not one.
pub fn temporary_owner(path: &Path) -> Option<u32> {
    let name = path.file_name()?.to_str()?;
    let stem = name.strip_prefix('.')?.strip_suffix(".tmp")?;
    stem.rsplit_once('.')?.1.parse().ok()
}

/// Whether process `pid` is alive. Where that cannot be told (no `/proc`),
/// it is assumed alive, so that nothing another writer still needs is removed.
fn process_alive(pid: u32) -> bool {
    let proc = Path::new("/proc");
    !proc.join("self").exists() || proc.join(pid.to_string()).exists()
}

/// Removes, below `dir`, the temporary files of [`write_atomically`] whose
/// writer process is gone (a killed run); those of live writers (another
/// shard at work, this process) stay. Returns the removed paths, sorted.
pub fn remove_stale_temporaries(dir: &Path) -> Vec<PathBuf> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(&p, out);
            } else if temporary_owner(&p).is_some_and(|pid| !process_alive(pid))
                && std::fs::remove_file(&p).is_ok()
            {
                out.push(p);
            }
        }
    }
    let mut removed = Vec::new();
    walk(dir, &mut removed);
    removed.sort();
    removed
}

/// What already stands at a path about to be written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Target {
    /// Nothing, a regular file or a directory (or a link to one): the
    /// finished file is renamed into place.
    Renamed,
    /// A character device (`/dev/null`): the finished file is copied into
    /// it, never renamed over it.
    Device,
}

/// How `path` is written, or an error naming it when something other than
/// a regular file, a directory or a character device stands there (a
/// FIFO, a socket, a block device): renaming over it would replace it, and
/// writing into it could wait for a reader for ever.
fn target(path: &Path) -> Result<Target, IoError> {
    let Ok(meta) = std::fs::metadata(path) else {
        return Ok(Target::Renamed);
    };
    let kind = meta.file_type();
    if kind.is_file() || kind.is_dir() {
        return Ok(Target::Renamed);
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt as _;
        if kind.is_char_device() {
            return Ok(Target::Device);
        }
    }
    Err(IoError::format(
        path,
        "not a regular file, a directory or a character device (a FIFO, a socket or a block \
         device?): stepsim writes a finished file in place of its output, so it does not write \
         into this one; give a file name",
    ))
}

/// Writes `path` atomically: `write` receives a temporary path to create; on
/// success it is renamed to `path`, on failure it is removed.
///
/// Where `path` is a character device (`--out /dev/null`), the temporary
/// file is made in the system's temporary directory and copied into the
/// device, which stays what it was (renamed over, `/dev/null` would have
/// become a regular file). A FIFO, a socket or a block device is refused
/// before anything is written.
pub fn write_atomically<E>(path: &Path, write: impl FnOnce(&Path) -> Result<(), E>) -> Result<(), E>
where
    E: From<IoError>,
{
    let target = target(path)?;
    let tmp = match target {
        Target::Renamed => {
            if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir).map_err(|e| IoError::os(dir, e))?;
            }
            temporary_name(path)
        }
        Target::Device => {
            let name = temporary_name(path);
            std::env::temp_dir().join(name.file_name().unwrap_or_default())
        }
    };
    let _ = std::fs::remove_file(&tmp);
    let done = write(&tmp).and_then(|()| match target {
        Target::Renamed => std::fs::rename(&tmp, path).map_err(|e| E::from(IoError::os(path, e))),
        Target::Device => copy_into(&tmp, path).map_err(E::from),
    });
    if done.is_err() || target == Target::Device {
        let _ = std::fs::remove_file(&tmp);
    }
    done
}

/// Copies the file `from` into the existing `device`.
fn copy_into(from: &Path, device: &Path) -> Result<(), IoError> {
    let mut src = std::fs::File::open(from).map_err(|e| IoError::os(from, e))?;
    let mut dst = std::fs::OpenOptions::new()
        .write(true)
        .open(device)
        .map_err(|e| IoError::os(device, e))?;
    std::io::copy(&mut src, &mut dst).map_err(|e| IoError::os(device, e))?;
    Ok(())
}

/// Writes bytes atomically.
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    write_atomically(path, |tmp| {
        std::fs::write(tmp, bytes).map_err(|e| IoError::os(tmp, e))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_write_leaves_nothing_behind() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a/b.txt");
        let r: Result<(), IoError> = write_atomically(&path, |tmp| {
            std::fs::write(tmp, b"half").unwrap();
            Err(IoError::format(tmp, "boom"))
        });
        assert!(r.is_err());
        assert!(!path.exists());
        assert_eq!(std::fs::read_dir(dir.path().join("a")).unwrap().count(), 0);
        write_bytes_atomically(&path, b"whole").unwrap();
        assert_eq!(
            temporary_owner(&temporary_name(&path)),
            Some(std::process::id())
        );
        assert_eq!(temporary_owner(&path), None);
        assert_eq!(std::fs::read(&path).unwrap(), b"whole");
        assert_eq!(std::fs::read_dir(dir.path().join("a")).unwrap().count(), 1);
    }

    #[cfg(unix)]
    #[test]
    fn a_device_is_written_into_and_a_fifo_refused_never_replaced() {
        use std::os::unix::fs::FileTypeExt as _;
        // `--out /dev/null`: the bytes go into the device, which stays a
        // character device (renamed over, it became a regular file, and
        // every later `> /dev/null` on the machine filled it).
        let null = Path::new("/dev/null");
        write_bytes_atomically(null, b"into the device").unwrap();
        let r: Result<(), IoError> = write_atomically(null, |tmp| {
            assert!(tmp.starts_with(std::env::temp_dir()), "{}", tmp.display());
            std::fs::write(tmp, b"x").map_err(|e| IoError::os(tmp, e))
        });
        r.unwrap();
        let meta = std::fs::metadata(null).unwrap();
        assert!(meta.file_type().is_char_device());
        assert_eq!(std::fs::read(null).unwrap(), b"");
        assert!(!temporary_name(null).exists());
        let tmp_left = std::env::temp_dir().join(temporary_name(null).file_name().unwrap());
        assert!(!tmp_left.exists());
        // A FIFO is refused before anything is written, and stays.
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("pipe");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(made.success());
        let mut called = false;
        let r: Result<(), IoError> = write_atomically(&fifo, |_| {
            called = true;
            Ok(())
        });
        let e = r.unwrap_err().to_string();
        assert!(!called);
        assert!(
            e.contains("pipe") && e.contains("not a regular file"),
            "{e}"
        );
        assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn only_temporaries_of_dead_writers_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let sub = dir.path().join("d");
        std::fs::create_dir_all(&sub).unwrap();
        // A pid that cannot be alive (beyond Linux's pid_max of 2^22).
        let dead = sub.join(".img.fits.4194305.tmp");
        let live = temporary_name(&sub.join("img2.fits")); // this process
        let other = sub.join("notes.tmp"); // not ours: never touched
        let done = sub.join("img.fits");
        for p in [&dead, &live, &other, &done] {
            std::fs::write(p, b"x").unwrap();
        }
        assert_eq!(remove_stale_temporaries(dir.path()), vec![dead.clone()]);
        assert!(!dead.exists() && live.exists() && other.exists() && done.exists());
    }
}
