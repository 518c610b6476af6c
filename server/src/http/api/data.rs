//! The run's public data through the server (`GET /data/`, `GET
//! /data/{path}`): only the files of `RUN/public` that its manifest names
//! (`manifest.json` itself, `README.md` and each image's `file`), looked up
//! by exact name, so nothing else under the run — the private half, the
//! state directory, `../` paths — can be reached. No `Last-Modified`
//! header: file times could tell the order in which images were made; an
//! image's ETag is its SHA-256 from the manifest.
//!
//! `GET /data.tar` streams the whole release as one tar archive (POSIX
//! ustar, written here: `public/SHA256SUMS`, then every listed file under
//! `public/`), its length known before the first byte, every time stamp 0.

use crate::http::{ApiError, AppState};
use axum::body::Body;
use axum::extract::{Path as UrlPath, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde_json::{Value, json};
use sha2::{Digest, Sha256};
use std::path::PathBuf;
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
    truth_dir
        .parent()
        .map(|p| p.join("public"))
        .unwrap_or_else(|| PathBuf::from("public"))
}

fn sha256_of(path: &std::path::Path) -> std::io::Result<String> {
    let mut f = std::fs::File::open(path)?;
    let mut h = Sha256::new();
    std::io::copy(&mut f, &mut h)?;
    Ok(crate::hex(&h.finalize()))
}

/// The files of the run's public part in the manifest's order:
/// `manifest.json`, `README.md` (when there is one), then every image.
/// Refuses (message naming the file) a run without a readable manifest.
pub fn public_files(public: &std::path::Path) -> Result<Vec<PublicFile>, String> {
    let mpath = public.join("manifest.json");
    let text = std::fs::read_to_string(&mpath)
        .map_err(|e| format!("{}: cannot read: {e}", mpath.display()))?;
    let manifest: Manifest = serde_json::from_str(&text)
        .map_err(|e| format!("{}: not a manifest: {e}", mpath.display()))?;
    let size = |p: &str| std::fs::metadata(public.join(p)).map(|m| m.len());
    let mut files = vec![PublicFile {
        path: "manifest.json".into(),
        sha256: crate::hex(&Sha256::digest(text.as_bytes())),
        bytes: text.len() as u64,
    }];
    if let Ok(bytes) = size("README.md") {
        let sha = sha256_of(&public.join("README.md"))
            .map_err(|e| format!("{}: {e}", public.join("README.md").display()))?;
        files.push(PublicFile {
            path: "README.md".into(),
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
            size(&im.file).map_err(|e| format!("{}: {e}", public.join(&im.file).display()))?;
        files.push(PublicFile {
            path: im.file,
            sha256: im.sha256,
            bytes,
        });
    }
    Ok(files)
}

fn files_of(state: &AppState) -> Result<(PathBuf, Vec<PublicFile>), ApiError> {
    let public = public_dir(&state.settings().truth_dir);
    let files = public_files(&public).map_err(|e| {
        tracing::error!(error = %e, "public data");
        ApiError::new(
            StatusCode::NOT_FOUND,
            "the public data is not served here; the organisers hand it out",
        )
    })?;
    Ok((public, files))
}

/// `GET /data/`: `{"files": [{"path", "bytes", "sha256"}, ...]}` in the
/// manifest's order.
pub async fn listing(State(state): State<AppState>) -> Result<Response, ApiError> {
    let (_, files) = tokio::task::spawn_blocking(move || files_of(&state))
        .await
        .map_err(ApiError::internal)??;
    let list: Vec<Value> = files
        .iter()
        .map(|f| json!({"path": f.path, "bytes": f.bytes, "sha256": f.sha256}))
        .collect();
    Ok(axum::Json(json!({"files": list})).into_response())
}

/// `GET /data/{path}`: one listed file, streamed; 404 for anything else.
pub async fn download(
    State(state): State<AppState>,
    UrlPath(path): UrlPath<String>,
) -> Result<Response, ApiError> {
    if path
        .split('/')
        .any(|c| c.is_empty() || c == "." || c == "..")
    {
        return Err(ApiError::new(StatusCode::NOT_FOUND, "not found"));
    }
    let (public, files) = tokio::task::spawn_blocking(move || files_of(&state))
        .await
        .map_err(ApiError::internal)??;
    let Some(f) = files.into_iter().find(|f| f.path == path) else {
        return Err(ApiError::new(StatusCode::NOT_FOUND, "not found"));
    };
    let file = tokio::fs::File::open(public.join(&f.path))
        .await
        .map_err(ApiError::internal)?;
    let stream = futures_util::stream::unfold(file, |mut file| async move {
        use tokio::io::AsyncReadExt;
        let mut buf = vec![0u8; 256 * 1024];
        match file.read(&mut buf).await {
            Ok(0) => None,
            Ok(n) => {
                buf.truncate(n);
                Some((Ok::<_, std::io::Error>(axum::body::Bytes::from(buf)), file))
            }
            Err(e) => Some((Err(e), file)),
        }
    });
    let kind = if f.path.ends_with(".json") {
        "application/json"
    } else if f.path.ends_with(".md") {
        "text/markdown; charset=utf-8"
    } else {
        "application/octet-stream"
    };
    let mut resp = Body::from_stream(stream).into_response();
    let h = resp.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(kind));
    if let Ok(v) = HeaderValue::from_str(&f.bytes.to_string()) {
        h.insert(header::CONTENT_LENGTH, v);
    }
    if let Ok(v) = HeaderValue::from_str(&format!("\"{}\"", f.sha256)) {
        h.insert(header::ETAG, v);
    }
    Ok(resp)
}

/// The name of the checksum file at the head of the archive (the format
/// `sha256sum -c` reads: `HASH  PATH` a line).
pub const SUMS_FILE: &str = "SHA256SUMS";
/// The directory the archive unpacks into.
pub const ARCHIVE_DIR: &str = "public";
const BLOCK: u64 = 512;

/// `SHA256SUMS` of the listed files, in their order.
pub fn sha256sums(files: &[PublicFile]) -> String {
    files
        .iter()
        .map(|f| format!("{}  {}\n", f.sha256, f.path))
        .collect()
}

/// Bytes `n` takes in a tar archive, padded to whole blocks.
fn padded(n: u64) -> u64 {
    n.div_ceil(BLOCK) * BLOCK
}

/// The length of [`archive`]'s answer: a header and the padded contents
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

/// What the archive stream still has to send.
struct TarStream {
    public: PathBuf,
    files: std::collections::VecDeque<PublicFile>,
    /// The file being sent: its handle, the bytes still to send, the
    /// padding after them.
    current: Option<(tokio::fs::File, u64, u64)>,
    /// The two zero blocks at the end are sent.
    ended: bool,
}

impl TarStream {
    /// The next chunk of the archive; `None` at its end.
    async fn next_chunk(&mut self) -> Option<std::io::Result<axum::body::Bytes>> {
        use tokio::io::AsyncReadExt;
        if let Some((file, left, pad)) = &mut self.current {
            if *left > 0 {
                let mut buf = vec![0u8; (*left).min(256 * 1024) as usize];
                return match file.read(&mut buf).await {
                    Ok(0) => {
                        self.ended = true;
                        self.files.clear();
                        self.current = None;
                        Some(Err(std::io::Error::new(
                            std::io::ErrorKind::UnexpectedEof,
                            "a public file is shorter than when it was listed",
                        )))
                    }
                    Ok(n) => {
                        *left -= n as u64;
                        buf.truncate(n);
                        Some(Ok(buf.into()))
                    }
                    Err(e) => {
                        self.ended = true;
                        self.files.clear();
                        self.current = None;
                        Some(Err(e))
                    }
                };
            }
            let pad = *pad as usize;
            self.current = None;
            if pad > 0 {
                return Some(Ok(vec![0u8; pad].into()));
            }
        }
        if let Some(f) = self.files.pop_front() {
            let name = format!("{ARCHIVE_DIR}/{}", f.path);
            let opened = match tar_header(&name, f.bytes) {
                Ok(h) => tokio::fs::File::open(self.public.join(&f.path))
                    .await
                    .map(|file| (h, file)),
                Err(e) => Err(std::io::Error::new(std::io::ErrorKind::InvalidData, e)),
            };
            return match opened {
                Ok((h, file)) => {
                    self.current = Some((file, f.bytes, padded(f.bytes) - f.bytes));
                    Some(Ok(h.to_vec().into()))
                }
                Err(e) => {
                    self.ended = true;
                    self.files.clear();
                    Some(Err(e))
                }
            };
        }
        if self.ended {
            return None;
        }
        self.ended = true;
        Some(Ok(vec![0u8; 2 * BLOCK as usize].into()))
    }
}

/// `GET /data.tar`: the whole release as one tar archive, streamed (one
/// file open at a time, 256 KiB read at a time), with `Content-Length`:
/// `public/SHA256SUMS` ([`sha256sums`]), then every file of [`listing`]
/// in its order under `public/`. Unpack and check with `tar -xf data.tar
/// && (cd public && sha256sum -c SHA256SUMS)`.
pub async fn archive(State(state): State<AppState>) -> Result<Response, ApiError> {
    let (public, files) = tokio::task::spawn_blocking(move || files_of(&state))
        .await
        .map_err(ApiError::internal)??;
    let sums = sha256sums(&files);
    let len = archive_len(&files);
    let mut head = tar_header(&format!("{ARCHIVE_DIR}/{SUMS_FILE}"), sums.len() as u64)
        .map_err(ApiError::internal)?
        .to_vec();
    head.extend_from_slice(sums.as_bytes());
    head.resize(BLOCK as usize + padded(sums.len() as u64) as usize, 0);
    for f in &files {
        tar_header(&format!("{ARCHIVE_DIR}/{}", f.path), f.bytes).map_err(ApiError::internal)?;
    }
    let stream = TarStream {
        public,
        files: files.into(),
        current: None,
        ended: false,
    };
    let first = futures_util::stream::once(async move {
        Ok::<_, std::io::Error>(axum::body::Bytes::from(head))
    });
    let rest = futures_util::stream::unfold(stream, |mut s| async move {
        s.next_chunk().await.map(|c| (c, s))
    });
    use futures_util::StreamExt;
    let mut resp = Body::from_stream(first.chain(rest)).into_response();
    let h = resp.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/x-tar"),
    );
    h.insert(
        header::CONTENT_DISPOSITION,
        HeaderValue::from_static("attachment; filename=\"data.tar\""),
    );
    if let Ok(v) = HeaderValue::from_str(&len.to_string()) {
        h.insert(header::CONTENT_LENGTH, v);
    }
    Ok(resp)
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
