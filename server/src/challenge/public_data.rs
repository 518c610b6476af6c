//! The run's public data as the challenge hands it out: only the files of
//! `RUN/public` that its manifest names (`manifest.json` itself,
//! `README.md` and each image's `file`), with their sizes and SHA-256, and
//! the layout of the one tar archive of them all (POSIX ustar:
//! `public/SHA256SUMS`, then every listed file under `public/`, every time
//! stamp 0). Serving them is the handlers' (`http::api::data`).

use sha2::{Digest, Sha256};
use std::path::PathBuf;
use stepsim_contract::run_dir::{PublicDir, RunDir};
use stepsim_contract::run_layout::Manifest;

/// One file participants may download.
#[derive(Debug, Clone, PartialEq)]
pub struct PublicFile {
    /// Path relative to `RUN/public` (as the manifest names it).
    pub path: String,
    /// SHA-256 from the manifest (images), or of the file (manifest, README).
    pub sha256: String,
    /// Its size on disk.
    pub bytes: u64,
}

/// The public directory of the served run (`RUN/public`, beside the
/// `RUN/private` the challenge was made from).
pub fn public_dir(truth_dir: &std::path::Path) -> PathBuf {
    let run = truth_dir.parent().unwrap_or(std::path::Path::new(""));
    RunDir::new(run).public().path().to_path_buf()
}

fn sha256_of(path: &std::path::Path) -> std::io::Result<String> {
    let mut f = std::fs::File::open(path)?;
    let mut h = Sha256::new();
    std::io::copy(&mut f, &mut h)?;
    Ok(stepsim_contract::digest::hex(&h.finalize()))
}

/// The files of the run's public part in the manifest's order:
/// `manifest.json`, `README.md` (when there is one), then every image.
/// Refuses (message naming the file) a run without a readable manifest.
pub fn public_files(public: &std::path::Path) -> Result<Vec<PublicFile>, String> {
    let public = PublicDir::new(public);
    let mpath = public.manifest();
    let text = std::fs::read_to_string(&mpath)
        .map_err(|e| format!("{}: cannot read: {e}", mpath.display()))?;
    let manifest: Manifest = serde_json::from_str(&text)
        .map_err(|e| format!("{}: not a manifest: {e}", mpath.display()))?;
    let size = |p: &str| std::fs::metadata(public.file(p)).map(|m| m.len());
    let mut files = vec![PublicFile {
        path: PublicDir::MANIFEST.into(),
        sha256: stepsim_contract::digest::hex(&Sha256::digest(text.as_bytes())),
        bytes: text.len() as u64,
    }];
    if let Ok(bytes) = size(PublicDir::README) {
        let sha = sha256_of(&public.readme())
            .map_err(|e| format!("{}: {e}", public.readme().display()))?;
        files.push(PublicFile {
            path: PublicDir::README.into(),
            sha256: sha,
            bytes,
        });
    }
    for im in manifest.images {
        // Only plain relative names below `public/` (a damaged manifest
        // cannot point outside it).
        let plain = std::path::Path::new(&im.file)
            .components()
            .all(|c| matches!(c, std::path::Component::Normal(_)));
        if !plain || im.file.contains('\\') {
            return Err(format!(
                "{}: image {}: file {:?} is not a plain path inside public/",
                mpath.display(),
                im.image,
                im.file
            ));
        }
        let bytes =
            size(&im.file).map_err(|e| format!("{}: {e}", public.file(&im.file).display()))?;
        files.push(PublicFile {
            path: im.file,
            sha256: im.sha256,
            bytes,
        });
    }
    Ok(files)
}

/// The name of the checksum file at the head of the archive (the format
/// `sha256sum -c` reads: `HASH  PATH` a line).
pub const SUMS_FILE: &str = "SHA256SUMS";
/// The directory the archive unpacks into.
pub const ARCHIVE_DIR: &str = "public";
/// A tar block.
pub const BLOCK: u64 = 512;

/// `SHA256SUMS` of the listed files, in their order.
pub fn sha256sums(files: &[PublicFile]) -> String {
    files
        .iter()
        .map(|f| format!("{}  {}\n", f.sha256, f.path))
        .collect()
}

/// Bytes `n` takes in a tar archive, padded to whole blocks.
pub fn padded(n: u64) -> u64 {
    n.div_ceil(BLOCK) * BLOCK
}

/// The length of the archive of `files` (`GET /data.tar`): a header and the padded contents
/// of `SHA256SUMS` and of each file, then two zero blocks.
pub fn archive_len(files: &[PublicFile]) -> u64 {
    let sums = sha256sums(files).len() as u64;
    files.iter().map(|f| BLOCK + padded(f.bytes)).sum::<u64>() + BLOCK + padded(sums) + 2 * BLOCK
}

/// The ustar header of a regular file `name` of `size` bytes: mode 0644,
/// owner 0, time stamp 0. A name over 100 bytes is split at a `/` into
/// the 155-byte prefix and the name; one that does not fit is refused.
pub fn tar_header(name: &str, size: u64) -> Result<[u8; 512], String> {
    let mut h = [0u8; 512];
    let (prefix, short) = if name.len() <= 100 {
        ("", name)
    } else {
        name.char_indices()
            .filter(|&(i, c)| c == '/' && i <= 155 && name.len() - i - 1 <= 100)
            .map(|(i, _)| (&name[..i], &name[i + 1..]))
            .next()
            .ok_or_else(|| format!("{name}: too long a path for a tar archive"))?
    };
    if size >= 1 << 33 {
        return Err(format!(
            "{name}: {size} bytes is too large for a ustar header"
        ));
    }
    let put = |h: &mut [u8; 512], at: usize, bytes: &[u8]| {
        h[at..at + bytes.len()].copy_from_slice(bytes);
    };
    put(&mut h, 0, short.as_bytes());
    put(&mut h, 100, b"0000644\0");
    put(&mut h, 108, b"0000000\0");
    put(&mut h, 116, b"0000000\0");
    put(&mut h, 124, format!("{size:011o}\0").as_bytes());
    put(&mut h, 136, b"00000000000\0");
    put(&mut h, 148, b"        ");
    h[156] = b'0';
    put(&mut h, 257, b"ustar\0");
    put(&mut h, 263, b"00");
    put(&mut h, 345, prefix.as_bytes());
    let sum: u32 = h.iter().map(|&b| u32::from(b)).sum();
    put(&mut h, 148, format!("{sum:06o}\0 ").as_bytes());
    Ok(h)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tar_headers_are_ustar_with_their_checksum() {
        let h = tar_header("public/a/b.fits", 1000).unwrap();
        assert_eq!(&h[..15], b"public/a/b.fits");
        assert_eq!(&h[124..136], b"00000001750\0");
        assert_eq!(&h[257..263], b"ustar\0");
        // The checksum: the sum of the bytes with its own field as spaces.
        let mut blank = h;
        blank[148..156].copy_from_slice(b"        ");
        let sum: u32 = blank.iter().map(|&b| u32::from(b)).sum();
        assert_eq!(&h[148..156], format!("{sum:06o}\0 ").as_bytes());
        // A long path goes into the prefix, split at a `/`.
        let long = format!("public/{}/{}.fits", "d".repeat(90), "i".repeat(60));
        let h = tar_header(&long, 1).unwrap();
        assert_eq!(
            &h[345..345 + 97],
            format!("public/{}", "d".repeat(90)).as_bytes()
        );
        assert_eq!(&h[..65], format!("{}.fits", "i".repeat(60)).as_bytes());
        assert!(tar_header(&"x".repeat(300), 1).is_err());
        assert!(tar_header("a", 1 << 33).is_err());
    }

    #[test]
    fn the_archive_length_counts_headers_padding_and_the_end() {
        let f = |bytes| PublicFile {
            path: "a".into(),
            sha256: "0".repeat(64),
            bytes,
        };
        let files = [f(0), f(1), f(512)];
        // SHA256SUMS: 3 lines of 64 + 2 + 1 + 1 bytes = 204, one block.
        assert_eq!(
            archive_len(&files),
            (1 + 1) * 512 + 512 + (512 + 512) + (512 + 512) + 1024
        );
    }
}
