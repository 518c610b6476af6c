//! The challenge page (`GET /`): the run's README and the rules.

use super::{ApiError, AppState, Shared, rules, when};
use axum::extract::{Extension, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::Response;

pub(super) async fn index(
    State(state): State<AppState>,
    Extension(web): Shared,
    headers: HeaderMap,
) -> Response {
    let nav = web.nav(&state, &headers, "index").await;
    let phase = match crate::challenge::Phase::read(state.store()).await {
        Ok(p) => p,
        Err(e) => return web.error(&nav, &ApiError::internal(e)),
    };
    let now = crate::now_s();
    // The README is HTML made by `markdown_html`, which escapes every
    // character of the text: it is marked safe, everything else is escaped.
    let readme = web
        .readme_html
        .clone()
        .map(minijinja::Value::from_safe_string);
    web.render_value(
        StatusCode::OK,
        "index.html",
        minijinja::context! {
            readme => readme,
            ..minijinja::Value::from_serialize(serde_json::json!({
                "nav": nav,
                "rules": rules(&state),
                "revealed": phase.revealed,
                "closed": phase.closed,
                "frozen": phase.frozen,
                "deadline": phase.deadline_s.map(when),
                "deadline_passed": phase.deadline_s.is_some_and(|d| now >= d),
                "uploads_open": phase.uploads_open(now),
                "max_final": crate::challenge::MAX_FINAL_ENTRIES,
            }))
        },
    )
}
