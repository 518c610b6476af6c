//! One time stamp for the whole public half.
//!
//! File times would otherwise tell the order in which images were written,
//! and that order follows the datasets. Every process of a run therefore ends
//! by giving every file and directory of `public/` the same modification and
//! access time: the instant the run was claimed, read from the modification
//! time of `private/config.json` (created once, never rewritten) and rounded
//! down to a whole second, so that shards and resumes agree. Setting the
//! times also sets each entry's change time (ctime, which cannot be chosen)
//! to "now", in the order the entries are visited: sorted by path, that is by
//! the opaque dataset and image ids, an order keyed by the blinding secret.

use std::fs::{File, FileTimes};
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use stepsim_contract::io::IoError;

/// The instant of a run: the modification time of its `private/config.json`,
/// rounded down to a whole second.
pub fn run_instant(config_json: &Path) -> Result<SystemTime, IoError> {
    let t = std::fs::metadata(config_json)
        .and_then(|m| m.modified())
        .map_err(|e| IoError::os(config_json, e))?;
    let s = t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
    Ok(UNIX_EPOCH + Duration::from_secs(s))
}

/// Every file and directory below `root` (and `root` itself, last), sorted
/// by path; temporaries of writers at work (`*.tmp`) are left out.
pub fn entries(root: &Path) -> Result<Vec<PathBuf>, IoError> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) -> Result<(), IoError> {
        for e in std::fs::read_dir(dir).map_err(|e| IoError::os(dir, e))? {
            let p = e.map_err(|e| IoError::os(dir, e))?.path();
            if stepsim_contract::io::temporary_owner(&p).is_some() {
                continue;
            }
            if p.is_dir() {
                walk(&p, out)?;
            }
            out.push(p);
        }
        Ok(())
    }
    let mut out = Vec::new();
    walk(root, &mut out)?;
    out.sort();
    out.push(root.into());
    Ok(out)
}

/// Gives every entry of `public` (see [`entries`]) modification and access
/// time `instant`, in sorted order. Nothing to do when `public` is missing.
pub fn normalise(public: &Path, instant: SystemTime) -> Result<(), IoError> {
    if !public.is_dir() {
        return Ok(());
    }
    let times = FileTimes::new().set_accessed(instant).set_modified(instant);
    for p in entries(public)? {
        match File::open(&p).and_then(|f| f.set_times(times)) {
            Ok(()) => {}
            // Removed meanwhile by another process of the run (a manifest
            // found stale): nothing to stamp.
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(IoError::os(&p, e)),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_entry_gets_the_instant_and_temporaries_are_left_alone() {
        let dir = tempfile::tempdir().unwrap();
        let public = dir.path().join("public");
        std::fs::create_dir_all(public.join("db")).unwrap();
        std::fs::create_dir_all(public.join("da")).unwrap();
        for f in ["da/i2.fits", "da/i1.fits", "db/i3.fits", "README.md"] {
            std::fs::write(public.join(f), f).unwrap();
        }
        let tmp = public.join("db/.i4.fits.4194305.tmp");
        std::fs::write(&tmp, "x").unwrap();
        let rel: Vec<String> = entries(&public)
            .unwrap()
            .iter()
            .map(|p| p.strip_prefix(dir.path()).unwrap().display().to_string())
            .collect();
        assert_eq!(
            rel,
            [
                "public/README.md",
                "public/da",
                "public/da/i1.fits",
                "public/da/i2.fits",
                "public/db",
                "public/db/i3.fits",
                "public",
            ]
        );
        let instant = UNIX_EPOCH + Duration::from_secs(1_700_000_000);
        // Listed before: reading a directory afterwards would set its atime.
        let all = entries(&public).unwrap();
        normalise(&public, instant).unwrap();
        for p in all {
            let m = std::fs::metadata(&p).unwrap();
            assert_eq!(m.modified().unwrap(), instant, "{}", p.display());
            assert_eq!(m.accessed().unwrap(), instant, "{}", p.display());
        }
        assert_ne!(
            std::fs::metadata(&tmp).unwrap().modified().unwrap(),
            instant
        );
        // The instant of a run: its config's mtime, to the second.
        let cfg = dir.path().join("config.json");
        std::fs::write(&cfg, "{}").unwrap();
        File::options()
            .write(true)
            .open(&cfg)
            .unwrap()
            .set_modified(instant + Duration::from_millis(700))
            .unwrap();
        assert_eq!(run_instant(&cfg).unwrap(), instant);
    }
}
