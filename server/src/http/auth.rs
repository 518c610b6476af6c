//! Who is asking, and how often: the bearer token of the API and the
//! rate limit per token and per client address.

use super::{ApiError, AppState, MAX_RATE_KEYS, RATE_WINDOW_S};
use crate::challenge::token_hash;
use crate::store::Team;
use axum::extract::{Request, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};

/// Counts a request against its token's and its client address's limit
/// (`requests_per_minute` each, over the last [`RATE_WINDOW_S`] seconds);
/// 429 with the reset time past either. A forged token is counted too, so
/// guessing tokens is slowed like everything else.
pub(crate) async fn rate_limit(
    State(state): State<AppState>,
    req: Request,
    next: axum::middleware::Next,
) -> Response {
    // Public data downloads need no token and come in hundreds of files;
    // they are not counted (docs/server.md, "Rules").
    if req.uri().path().starts_with("/data/") {
        return next.run(req).await;
    }
    let mut keys = Vec::new();
    if let Some(info) = req
        .extensions()
        .get::<axum::extract::ConnectInfo<std::net::SocketAddr>>()
    {
        keys.push(format!("addr {}", info.0.ip()));
    }
    if let Some(v) = req.headers().get(header::AUTHORIZATION) {
        // The token itself is the key, however the header is spelt: a
        // malformed header (refused with 401 anyway) counts against the
        // token it carries, not a fresh key.
        let token = match bearer_token(v.as_bytes()) {
            Some(t) => t.to_string(),
            None => String::from_utf8_lossy(v.as_bytes())
                .split_ascii_whitespace()
                .last()
                .unwrap_or_default()
                .to_string(),
        };
        keys.push(format!("token {}", token_hash(&token)));
    }
    let limit = state.inner.settings.requests_per_minute as usize;
    let now = crate::now_s();
    let mut refused = None;
    {
        let mut recent = state
            .inner
            .recent
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        // Keys of clients quiet for a window are dropped once there are
        // many: random forged tokens must not grow the map for ever.
        if recent.len() > MAX_RATE_KEYS {
            recent.retain(|_, t| t.back().is_some_and(|&x| x > now - RATE_WINDOW_S));
        }
        for k in &keys {
            let Some(times) = recent.get_mut(k) else {
                continue;
            };
            while times.front().is_some_and(|&t| t <= now - RATE_WINDOW_S) {
                times.pop_front();
            }
            if times.len() >= limit {
                let reset = times.front().copied().unwrap_or(now) + RATE_WINDOW_S;
                refused = Some(refused.map_or(reset, |r: i64| r.max(reset)));
            }
        }
        if refused.is_none() {
            for k in &keys {
                recent.entry(k.clone()).or_default().push_back(now);
            }
        }
    }
    match refused {
        Some(reset) => ApiError {
            reset_s: Some(reset),
            ..ApiError::new(
                StatusCode::TOO_MANY_REQUESTS,
                format!(
                    "more than {limit} requests in a minute; the next is possible at {}",
                    crate::utc_text(reset)
                ),
            )
        }
        .into_response(),
        None => next.run(req).await,
    }
}

/// The token of an `Authorization` header value, read strictly: the scheme
/// `Bearer` (any case), one space, then a token of RFC 6750's `b64token`
/// characters (letters, digits, `-._~+/`, then `=` only) and nothing after
/// it. `None` for anything else (which is answered 401).
pub fn bearer_token(value: &[u8]) -> Option<&str> {
    let (scheme, token) = (value.get(..7)?, value.get(7..)?);
    if !scheme.eq_ignore_ascii_case(b"bearer ") || token.is_empty() {
        return None;
    }
    let body = token.len() - token.iter().rev().take_while(|&&c| c == b'=').count();
    let ok = body > 0
        && token[..body]
            .iter()
            .all(|&c| c.is_ascii_alphanumeric() || b"-._~+/".contains(&c));
    ok.then(|| std::str::from_utf8(token).ok()).flatten()
}

/// The team of a request's bearer token, or 401.
pub(crate) async fn auth(state: &AppState, headers: &HeaderMap) -> Result<Team, ApiError> {
    let unauthorized = || {
        ApiError::new(
            StatusCode::UNAUTHORIZED,
            "a valid token is needed: send `Authorization: Bearer TOKEN`",
        )
    };
    let token = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| bearer_token(v.as_bytes()))
        .ok_or_else(unauthorized)?;
    let team = state
        .store()
        .team_by_token(&token_hash(token))
        .await
        .map_err(ApiError::internal)?
        .ok_or_else(unauthorized)?;
    crate::http::log::note_team(team.id);
    Ok(team)
}
