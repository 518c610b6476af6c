//! The run's public data through the server (`GET /data/`, `GET
//! /data/{path}`): only the files of `RUN/public` that its manifest names
//! (`manifest.json` itself, `README.md` and each image's `file`), looked up
//! by exact name, so nothing else under the run — the private half, the
//! state directory, `../` paths — can be reached. No `Last-Modified`
//! header: file times could tell the order in which images were made; an
//! image's ETag is its SHA-256 from the manifest.

use crate::api::{ApiError, AppState};
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
    Ok(crate::challenge::hex(&h.finalize()))
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
        sha256: crate::challenge::hex(&Sha256::digest(text.as_bytes())),
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
