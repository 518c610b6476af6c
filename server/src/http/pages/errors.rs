//! Errors as pages for browsers, and how a request says it is a browser.

use super::{ApiError, AppState, Shared};
use axum::extract::{Extension, Request, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::Response;
use serde_json::Value;

/// Whether a request asks for a page rather than JSON: its `Accept` names
/// `text/html` (or `text/*`) with a weight above 0 and at least that of
/// JSON (`application/json`, `application/*`, `*/*`). Browsers send
/// `text/html,…,*/*;q=0.8`; curl sends `*/*`, which is JSON.
pub fn wants_html(headers: &HeaderMap) -> bool {
    let (mut html, mut json) = (0.0_f64, 0.0_f64);
    for accept in headers.get_all(header::ACCEPT) {
        let Ok(accept) = accept.to_str() else {
            continue;
        };
        for range in accept.split(',') {
            let mut parts = range.split(';');
            let kind = parts.next().unwrap_or("").trim().to_ascii_lowercase();
            let q = parts
                .filter_map(|p| p.trim().strip_prefix("q="))
                .find_map(|q| q.trim().parse::<f64>().ok())
                .unwrap_or(1.0);
            match kind.as_str() {
                "text/html" | "text/*" => html = html.max(q),
                "application/json" | "application/*" | "*/*" => json = json.max(q),
                _ => {}
            }
        }
    }
    html > 0.0 && html >= json
}

/// Errors as pages for browsers: an error answer in JSON (`{"error": …}`:
/// the unknown routes' 404, a missing data file, the rate limit's 429, …)
/// to a request that [`wants_html`] outside `/api/` is rendered as the
/// message page, with the same status and `Retry-After`. API clients and
/// anything under `/api/` keep the JSON.
pub(crate) async fn html_errors(
    State(state): State<AppState>,
    Extension(web): Shared,
    req: Request,
    next: axum::middleware::Next,
) -> Response {
    let path = req.uri().path().to_owned();
    let page = !(path == "/api" || path.starts_with("/api/")) && wants_html(req.headers());
    let headers = req.headers().clone();
    let resp = next.run(req).await;
    let json = resp
        .headers()
        .get(header::CONTENT_TYPE)
        .is_some_and(|v| v.as_bytes().starts_with(b"application/json"));
    let status = resp.status();
    if !page || !json || !(status.is_client_error() || status.is_server_error()) {
        return resp;
    }
    let (parts, body) = resp.into_parts();
    let message = axum::body::to_bytes(body, 64 * 1024)
        .await
        .ok()
        .and_then(|b| serde_json::from_slice::<Value>(&b).ok())
        .and_then(|v| v["error"].as_str().map(str::to_owned))
        .unwrap_or_else(|| status.canonical_reason().unwrap_or("error").to_owned());
    let nav = web.nav(&state, &headers, "error").await;
    let text = if status == StatusCode::NOT_FOUND && message == "not found" {
        // The path is not repeated: a crafted link must not put words of
        // its own on the server's page.
        "There is no page at this address. The challenge, its data and the leaderboard are \
         linked from the challenge page."
            .to_owned()
    } else {
        message
    };
    let mut out = web.error(&nav, &ApiError::new(status, text));
    for name in [header::RETRY_AFTER, header::WWW_AUTHENTICATE] {
        if let Some(v) = parts.headers.get(&name) {
            out.headers_mut().insert(name, v.clone());
        }
    }
    out
}
