//! The run's public data through the server (`GET /data/`, `GET
//! /data/{path}`): only the files of `RUN/public` that its manifest names
//! (`manifest.json` itself, `README.md` and each image's `file`), looked up
//! by exact name, so nothing else under the run — the private half, the
//! state directory, `../` paths — can be reached. No `Last-Modified`
//! header: file times could tell the order in which images were made; an
//! image's ETag is its SHA-256 from the manifest.
//!
//! `GET /data.tar` streams the whole release as one tar archive (its
//! layout: [`crate::challenge::public_data`]), its length known before the
//! first byte.

use crate::challenge::public_data::{
    ARCHIVE_DIR, BLOCK, PublicFile, SUMS_FILE, archive_len, padded, public_dir, public_files,
    sha256sums, tar_header,
};
use crate::http::{ApiError, AppState};
use axum::body::Body;
use axum::extract::{Path as UrlPath, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde_json::{Value, json};
use std::path::PathBuf;

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
