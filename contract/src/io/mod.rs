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

/// Writes `path` atomically: `write` receives a temporary path to create; on
/// success it is renamed to `path`, on failure it is removed.
pub fn write_atomically<E>(path: &Path, write: impl FnOnce(&Path) -> Result<(), E>) -> Result<(), E>
where
    E: From<IoError>,
{
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| IoError::os(dir, e))?;
    }
    let tmp = temporary_name(path);
    let _ = std::fs::remove_file(&tmp);
    match write(&tmp) {
        Ok(()) => std::fs::rename(&tmp, path).map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            E::from(IoError::os(path, e))
        }),
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
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
