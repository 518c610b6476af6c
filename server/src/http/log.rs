//! The log line of each request: method, path, status, milliseconds and
//! the team's id (`-` before one is known); its counters are
//! [`crate::observe::Metrics`].

use crate::observe::{Metrics, log_text};
use axum::extract::Request;
use axum::middleware::Next;
use axum::response::Response;
use std::time::Instant;

tokio::task_local! {
    /// The team of the request being answered on this task, once known.
    static TEAM: std::cell::Cell<Option<i64>>;
}

/// Records the team of the request being answered (called where a token
/// or a session is checked), for its log line.
pub(crate) fn note_team(team_id: i64) {
    let _ = TEAM.try_with(|t| t.set(Some(team_id)));
}

/// The middleware that logs a line per request and counts it.
pub(crate) async fn log_requests(
    axum::extract::State(metrics): axum::extract::State<std::sync::Arc<Metrics>>,
    req: Request,
    next: Next,
) -> Response {
    let start = Instant::now();
    let method = req.method().clone();
    // The path is the client's: clipped and escaped (a 60 KB path of
    // look-alike spaces must not become a 60 KB line of forged fields).
    let path = log_text(req.uri().path(), 200);
    let (response, team) = TEAM
        .scope(std::cell::Cell::new(None), async move {
            let r = next.run(req).await;
            (r, TEAM.with(std::cell::Cell::get))
        })
        .await;
    let status = response.status().as_u16();
    metrics.request(status);
    let ms = start.elapsed().as_secs_f64() * 1e3;
    let team = team.map_or_else(|| "-".to_string(), |t| t.to_string());
    tracing::info!(%method, %path, status, ms = %format_args!("{ms:.1}"), team = %team, "request");
    response
}
