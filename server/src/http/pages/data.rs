//! The data page (`GET /data/`).

use super::{ApiError, AppState, Shared, size_text, wants_html};
use axum::extract::{Extension, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde_json::Value;

/// `GET /data/` (and `/data`): for a browser ([`wants_html`]) the data
/// page — every public file with its size and SHA-256, the archive
/// (`/data.tar`) and a command that downloads and checks it; for anyone
/// else the JSON listing ([`crate::http::api::data::listing`]).
pub(crate) async fn data_index(
    State(state): State<AppState>,
    Extension(web): Shared,
    headers: HeaderMap,
) -> Response {
    if !wants_html(&headers) {
        return match crate::http::api::data::listing(State(state)).await {
            Ok(r) => r,
            Err(e) => e.into_response(),
        };
    }
    let nav = web.nav(&state, &headers, "data").await;
    let public = crate::challenge::public_data::public_dir(&state.settings().truth_dir);
    let listed =
        tokio::task::spawn_blocking(move || crate::challenge::public_data::public_files(&public))
            .await;
    let files = match listed {
        Ok(Ok(f)) => f,
        Ok(Err(e)) => {
            tracing::error!(error = %e, "public data");
            return web.message(
                &nav,
                StatusCode::NOT_FOUND,
                "Data",
                "the public data is not served here; the organisers hand it out",
            );
        }
        Err(e) => return web.error(&nav, &ApiError::internal(e)),
    };
    // The command names this server as the browser reached it; a Host
    // that is not a plain host[:port] is not repeated.
    let host = headers
        .get(header::HOST)
        .and_then(|v| v.to_str().ok())
        .filter(|h| {
            !h.is_empty()
                && h.chars()
                    .all(|c| c.is_ascii_alphanumeric() || ".-:[]".contains(c))
        })
        .unwrap_or("SERVER");
    let scheme = match headers
        .get("x-forwarded-proto")
        .and_then(|v| v.to_str().ok())
    {
        Some("https") => "https",
        _ => "http",
    };
    let total: u64 = files.iter().map(|f| f.bytes).sum();
    let archive = crate::challenge::public_data::archive_len(&files);
    let rows: Vec<Value> = files
        .iter()
        .map(|f| {
            serde_json::json!({"path": f.path, "bytes": size_text(f.bytes as i64),
                               "bytes_exact": f.bytes, "sha256": f.sha256})
        })
        .collect();
    web.render(
        StatusCode::OK,
        "data.html",
        serde_json::json!({
            "nav": nav,
            "files": rows,
            "count": files.len(),
            "total": size_text(total as i64),
            "archive": size_text(archive as i64),
            "archive_exact": archive,
            "sums": crate::challenge::public_data::SUMS_FILE,
            "dir": crate::challenge::public_data::ARCHIVE_DIR,
            "command": format!(
                "curl -fsS {scheme}://{host}/data.tar | tar -xf - && (cd {} && sha256sum -c {})",
                crate::challenge::public_data::ARCHIVE_DIR,
                crate::challenge::public_data::SUMS_FILE
            ),
        }),
    )
}
