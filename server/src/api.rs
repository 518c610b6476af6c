//! The JSON API (docs/server.md, "API"):
//!
//! ```text
//! POST /api/submissions       Bearer token; the file as the body (raw, or
//!                             multipart field `file`) -> 202 {"id", "status"}
//! GET  /api/submissions       the caller's entries, newest first
//! GET  /api/submissions/{id}  one of the caller's entries (404 for others')
//! GET  /api/leaderboard       {"revealed", "rows": [{"rank", "team", "role", ...}]}
//! PUT  /api/final             Bearer token; {"entries": [id, ...]} (at most 2)
//! GET  /api/challenge         name, deadline, frozen/closed/revealed, rules
//! GET  /data/                 the public files: path, bytes, sha256 (manifest order);
//!                             a page for a browser (`web::wants_html`)
//! GET  /data/{path}           one public file listed there (nothing else)
//! GET  /data.tar              all of them as one tar archive, with SHA256SUMS
//! ```
//!
//! Errors are JSON `{"error": "..."}`: 401 without a valid token, 404 for
//! what does not exist or is another team's, 413 past the size cap, 422 for
//! an upload the harness refuses (its message, file paths replaced), 429
//! past the quota or the cap on refused uploads (with `reset`, also as
//! `Retry-After`), 403 for an upload when the challenge is frozen, closed or
//! past its deadline and for a choice of final entries once it is closed.

use crate::challenge::{
    Challenge, ChoiceError, Phase, QUOTA_WINDOW_S, choose_final_entries, final_entries_or_default,
    hex, parse_figures, rank_key, token_hash,
};
use crate::limits::Limits;
use crate::store::{Role, Store, Submission, Team};
use axum::Router;
use axum::body::Body;
use axum::extract::{FromRequest, Path as UrlPath, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, put};
use http_body_util::BodyExt;
use serde_json::{Value, json};
use sha2::{Digest, Sha256};
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use tokio::io::AsyncWriteExt;

/// What the handlers share.
#[derive(Clone)]
pub struct AppState {
    inner: Arc<Inner>,
}

struct Inner {
    dir: PathBuf,
    settings: crate::Settings,
    limits: Limits,
    store: Arc<dyn Store>,
    /// Live scoring workers, when the server runs its own (`None`: the
    /// caller scores the queue, as tests do).
    workers: Option<Arc<AtomicUsize>>,
    /// Uploads of each team being received or checked now.
    uploads: Mutex<std::collections::HashMap<i64, usize>>,
    /// Uploads being received or checked now, all teams.
    uploads_all: Arc<tokio::sync::Semaphore>,
    /// Format checks running now.
    checks: Arc<tokio::sync::Semaphore>,
    /// Times (s) of the recent requests of each token hash / client address.
    recent: Mutex<std::collections::HashMap<String, std::collections::VecDeque<i64>>>,
    /// The counters behind `/metrics` (shared with the server's workers).
    metrics: Arc<crate::observe::Metrics>,
    /// `/metrics` answers anyone (`serve --open-metrics`), not only the
    /// organisers.
    open_metrics: bool,
}

/// The window of the per-token and per-address rate limit.
pub const RATE_WINDOW_S: i64 = 60;

/// Tokens and addresses the rate limiter keeps before it drops the quiet ones.
const MAX_RATE_KEYS: usize = 10_000;

impl AppState {
    /// The state of a challenge (its own store connection), with the
    /// default [`Limits`] and no workers of its own (the caller scores the
    /// queue).
    pub fn new(ch: Challenge) -> Self {
        Self::with_limits(ch, Limits::default(), None)
    }

    /// The state of a challenge under `limits`; `workers` counts the live
    /// scoring workers ([`crate::worker::WorkerPool::live`]): while it is
    /// 0, uploads are refused with 503.
    pub fn with_limits(ch: Challenge, limits: Limits, workers: Option<Arc<AtomicUsize>>) -> Self {
        Self::build(ch, limits, workers, Arc::default(), false)
    }

    /// The state of a server running `pool`'s workers: uploads are refused
    /// while none is alive, `/metrics` counts their jobs, and answers
    /// anyone when `open_metrics`.
    pub fn serving(
        ch: Challenge,
        limits: Limits,
        pool: &crate::worker::WorkerPool,
        open_metrics: bool,
    ) -> Self {
        Self::build(ch, limits, Some(pool.live()), pool.metrics(), open_metrics)
    }

    fn build(
        ch: Challenge,
        limits: Limits,
        workers: Option<Arc<AtomicUsize>>,
        metrics: Arc<crate::observe::Metrics>,
        open_metrics: bool,
    ) -> Self {
        Self {
            inner: Arc::new(Inner {
                dir: ch.dir,
                settings: ch.settings,
                store: ch.store,
                workers,
                uploads: Mutex::new(std::collections::HashMap::new()),
                uploads_all: Arc::new(tokio::sync::Semaphore::new(limits.uploads_at_once.max(1))),
                checks: Arc::new(tokio::sync::Semaphore::new(limits.checks_at_once.max(1))),
                limits,
                recent: Mutex::new(std::collections::HashMap::new()),
                metrics,
                open_metrics,
            }),
        }
    }

    /// The server's counters (`/metrics`).
    pub fn metrics(&self) -> &crate::observe::Metrics {
        &self.inner.metrics
    }

    /// True when `/metrics` answers anyone (`serve --open-metrics`).
    pub fn open_metrics(&self) -> bool {
        self.inner.open_metrics
    }

    /// The live scoring workers of this server, when it runs its own.
    pub fn live_workers(&self) -> Option<usize> {
        self.inner
            .workers
            .as_ref()
            .map(|w| w.load(Ordering::SeqCst))
    }

    /// The server's limits.
    pub fn limits(&self) -> &Limits {
        &self.inner.limits
    }

    /// The store (shared; each call is one transaction of its own).
    pub fn store(&self) -> &dyn Store {
        self.inner.store.as_ref()
    }

    /// The store, shared (for a task that outlives a borrow).
    pub fn store_arc(&self) -> Arc<dyn Store> {
        self.inner.store.clone()
    }

    /// The challenge's state directory.
    pub fn dir(&self) -> &std::path::Path {
        &self.inner.dir
    }

    /// The challenge's settings.
    pub fn settings(&self) -> &crate::Settings {
        &self.inner.settings
    }

    /// The team of a bearer token (its text after `Bearer `), if it is a
    /// valid, unrevoked one.
    pub async fn team_of_token(
        &self,
        token: &str,
    ) -> Result<Option<Team>, crate::store::StoreError> {
        self.store().team_by_token(&token_hash(token)).await
    }
}

/// An error answer.
#[derive(Debug)]
pub struct ApiError {
    pub(crate) status: StatusCode,
    pub(crate) message: String,
    pub(crate) reset_s: Option<i64>,
}

impl ApiError {
    /// An answer with this status and `{"error": message}`.
    pub fn new(status: StatusCode, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
            reset_s: None,
        }
    }
    /// A 500 whose cause goes to the server's log only.
    pub fn internal(e: impl std::fmt::Display) -> Self {
        tracing::error!(error = %e, "internal error");
        Self::new(
            StatusCode::INTERNAL_SERVER_ERROR,
            "the server failed; the organisers can see why in its log",
        )
    }
    /// 404 `{"error": "not found"}`.
    pub fn not_found() -> Self {
        Self::new(StatusCode::NOT_FOUND, "not found")
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let mut body = json!({"error": self.message});
        let mut headers = HeaderMap::new();
        if let Some(t) = self.reset_s {
            body["reset"] = json!(crate::utc_text(t));
            let wait = (t - crate::now_s()).max(1);
            if let Ok(v) = HeaderValue::from_str(&wait.to_string()) {
                headers.insert(header::RETRY_AFTER, v);
            }
        }
        if self.status == StatusCode::UNAUTHORIZED {
            headers.insert(header::WWW_AUTHENTICATE, HeaderValue::from_static("Bearer"));
        }
        (self.status, headers, axum::Json(body)).into_response()
    }
}

type ApiResult = Result<Response, ApiError>;

/// The router of the API, with security headers on every answer.
pub fn router(state: AppState) -> Router {
    use tower_http::set_header::SetResponseHeaderLayer as H;
    let (pages, web) = crate::web::pages(&state);
    Router::new()
        .route(
            "/api/submissions",
            get(list_submissions).post(post_submission),
        )
        .route("/api/submissions/{id}", get(get_submission))
        .route("/api/leaderboard", get(leaderboard))
        .route("/api/final", put(put_final))
        .route("/api/challenge", get(challenge_state))
        .route("/data", get(crate::web::data_index))
        .route("/data/", get(crate::web::data_index))
        .route("/data.tar", get(crate::data::archive))
        .route("/data/{*path}", get(crate::data::download))
        .merge(pages)
        .fallback(|| async { ApiError::not_found() })
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            crate::net::guard_body,
        ))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            rate_limit,
        ))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            crate::web::html_errors,
        ))
        .layer(axum::Extension(web))
        .layer(axum::extract::DefaultBodyLimit::disable())
        .layer(H::overriding(
            header::X_CONTENT_TYPE_OPTIONS,
            HeaderValue::from_static("nosniff"),
        ))
        .layer(H::overriding(
            header::X_FRAME_OPTIONS,
            HeaderValue::from_static("DENY"),
        ))
        .layer(H::if_not_present(
            header::CONTENT_SECURITY_POLICY,
            HeaderValue::from_static("default-src 'none'; frame-ancestors 'none'"),
        ))
        .layer(H::if_not_present(
            header::REFERRER_POLICY,
            HeaderValue::from_static("no-referrer"),
        ))
        .layer(H::overriding(
            header::CACHE_CONTROL,
            HeaderValue::from_static("no-store"),
        ))
        .layer(axum::middleware::from_fn_with_state(
            state.inner.metrics.clone(),
            crate::observe::log_requests,
        ))
        .with_state(state)
}

/// Counts a request against its token's and its client address's limit
/// (`requests_per_minute` each, over the last [`RATE_WINDOW_S`] seconds);
/// 429 with the reset time past either. A forged token is counted too, so
/// guessing tokens is slowed like everything else.
async fn rate_limit(
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
async fn auth(state: &AppState, headers: &HeaderMap) -> Result<Team, ApiError> {
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
    crate::observe::note_team(team.id);
    Ok(team)
}

/// One entry as its team sees it: `id`, `status`, `created`, `sha256`,
/// `bytes`, `final`, `error` (refused), `public` and `scorer_version`
/// (once scored; a re-scored entry shows its newest score), `holdout`
/// (after reveal).
pub fn entry_json(s: &Submission, revealed: bool) -> Value {
    let parse = |t: &Option<String>| {
        t.as_deref()
            .and_then(|t| serde_json::from_str::<Value>(t).ok())
    };
    let mut v = json!({
        "id": s.id,
        "status": s.status,
        "created": crate::utc_text(s.created_s),
        "sha256": s.sha256,
        "bytes": s.bytes,
        "final": s.final_choice,
    });
    if let Some(e) = &s.error {
        v["error"] = json!(crate::worker::server_wording(e));
    }
    if s.has_score() {
        v["public"] = parse(&s.public_json).unwrap_or(Value::Null);
        v["scorer_version"] = json!(s.scorer_version);
        if revealed && s.holdout_json.is_some() {
            v["holdout"] = parse(&s.holdout_json).unwrap_or(Value::Null);
        }
    }
    v
}

pub(crate) async fn revealed(state: &AppState) -> Result<bool, ApiError> {
    Ok(state
        .store()
        .meta("revealed")
        .await
        .map_err(ApiError::internal)?
        .as_deref()
        == Some("true"))
}

async fn list_submissions(State(state): State<AppState>, headers: HeaderMap) -> ApiResult {
    let team = auth(&state, &headers).await?;
    let revealed = revealed(&state).await?;
    let subs = state
        .store()
        .submissions_of(team.id)
        .await
        .map_err(ApiError::internal)?;
    let quota = quota_status(&state, team.id).await?;
    let refused = refusal_status(&state, team.id).await?;
    let refs: Vec<&Submission> = subs.iter().collect();
    let counted: Vec<i64> = final_entries_or_default(&refs)
        .iter()
        .map(|s| s.id)
        .collect();
    let chosen = subs.iter().any(|s| s.final_choice);
    let entries: Vec<Value> = subs
        .iter()
        .map(|s| {
            let mut v = entry_json(s, revealed);
            v["final"] = json!(counted.contains(&s.id));
            v
        })
        .collect();
    Ok(axum::Json(json!({
        "team": team.name,
        "role": team.role.name(),
        "quota": quota,
        "final": counted,
        "final_chosen": chosen,
        "submissions": entries,
        "refused_uploads": refused,
    }))
    .into_response())
}

/// `PUT /api/final` with `{"entries": [id, ...]}`: the team's final entries
/// (at most two of its scored entries; `[]` goes back to the default).
async fn put_final(State(state): State<AppState>, req: Request) -> ApiResult {
    let team = auth(&state, req.headers()).await?;
    let bad = |why: String| {
        ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!("the body must be JSON {{\"entries\": [id, ...]}}: {why}"),
        )
    };
    let bytes = axum::body::to_bytes(req.into_body(), 64 * 1024)
        .await
        .map_err(|e| bad(format!("cannot read it ({e})")))?;
    let v: Value = serde_json::from_slice(&bytes).map_err(|e| bad(format!("not JSON ({e})")))?;
    let list = v
        .get("entries")
        .and_then(Value::as_array)
        .ok_or_else(|| bad("no list `entries`".into()))?;
    let ids = list
        .iter()
        .map(|x| {
            x.as_i64()
                .ok_or_else(|| bad(format!("{x} is not an entry id")))
        })
        .collect::<Result<Vec<i64>, ApiError>>()?;
    let result = choose_final_entries(state.store(), team.id, &ids).await;
    match result {
        Ok(ids) => Ok(axum::Json(json!({"final": ids})).into_response()),
        Err(ChoiceError::Store(e)) => Err(ApiError::internal(e)),
        Err(ChoiceError::NotFound(_)) => Err(ApiError::not_found()),
        Err(e @ ChoiceError::Closed) => Err(ApiError::new(StatusCode::FORBIDDEN, e.to_string())),
        Err(e) => Err(ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            e.to_string(),
        )),
    }
}

/// The public state of the challenge as JSON (`GET /api/challenge`).
pub async fn challenge_json(
    state: &AppState,
    now_s: i64,
) -> Result<Value, crate::store::StoreError> {
    let store = state.store();
    let phase = Phase::read(store).await?;
    let name = store
        .meta("name")
        .await?
        .unwrap_or_else(|| "stepsim challenge".into());
    let s = state.settings();
    Ok(json!({
        "name": name,
        "deadline": phase.deadline_s.map(crate::utc_text),
        "frozen": phase.frozen,
        "closed": phase.closed,
        "revealed": phase.revealed,
        "uploads_open": phase.uploads_open(now_s),
        "rules": {
            "quota": s.quota,
            "quota_window_hours": QUOTA_WINDOW_S / 3600,
            "refused_uploads_cap": s.format_failure_cap,
            "max_upload_bytes": s.max_upload_bytes,
            "requests_per_minute": s.requests_per_minute,
            "max_final_entries": crate::challenge::MAX_FINAL_ENTRIES,
            "feedback_decimals": stepsim_harness::part::FEEDBACK_DECIMALS
                .iter()
                .map(|(k, d)| (k.to_string(), json!(d)))
                .collect::<serde_json::Map<String, Value>>(),
        },
    }))
}

async fn challenge_state(State(state): State<AppState>) -> ApiResult {
    let v = challenge_json(&state, crate::now_s())
        .await
        .map_err(ApiError::internal)?;
    Ok(axum::Json(v).into_response())
}

async fn get_submission(
    State(state): State<AppState>,
    headers: HeaderMap,
    UrlPath(id): UrlPath<String>,
) -> ApiResult {
    let team = auth(&state, &headers).await?;
    let id: i64 = id.parse().map_err(|_| ApiError::not_found())?;
    let sub = state
        .store()
        .submission(id)
        .await
        .map_err(ApiError::internal)?
        .filter(|s| s.team_id == team.id)
        .ok_or_else(ApiError::not_found)?;
    let revealed = revealed(&state).await?;
    Ok(axum::Json(entry_json(&sub, revealed)).into_response())
}

/// The quota of a team now: used, limit and when the oldest use expires.
pub(crate) async fn quota_status(state: &AppState, team_id: i64) -> Result<Value, ApiError> {
    let now = crate::now_s();
    let used = state
        .store()
        .accepted_since(team_id, now - QUOTA_WINDOW_S)
        .await
        .map_err(ApiError::internal)?;
    let limit = state.inner.settings.quota;
    let mut v = json!({"used": used.len(), "limit": limit, "window_hours": 24});
    if let Some(first) = used.first() {
        v["reset"] = json!(crate::utc_text(first + QUOTA_WINDOW_S));
    }
    Ok(v)
}

/// How many of a team's refused uploads the team is shown (newest first).
pub const REFUSALS_SHOWN: usize = 50;

/// The uploads of a team the format check refused (never entries): `used`
/// (in the last 24 hours, counted against `limit`, the refusal cap),
/// `window_hours`, `reset` (when the oldest counted one leaves the window,
/// if any) and `recent`, the newest [`REFUSALS_SHOWN`] with `created` and
/// `error` (the message the team was sent).
pub(crate) async fn refusal_status(state: &AppState, team_id: i64) -> Result<Value, ApiError> {
    let now = crate::now_s();
    let (used, recent) = {
        let store = state.store();
        (
            store
                .format_failures_since(team_id, now - QUOTA_WINDOW_S)
                .await
                .map_err(ApiError::internal)?,
            store
                .format_failures(Some(team_id), REFUSALS_SHOWN)
                .await
                .map_err(ApiError::internal)?,
        )
    };
    let recent: Vec<Value> = recent
        .iter()
        .map(|f| {
            json!({"created": crate::utc_text(f.created_s),
                   "error": crate::worker::server_wording(&f.error)})
        })
        .collect();
    let mut v = json!({
        "used": used.len(),
        "limit": state.inner.settings.format_failure_cap,
        "window_hours": QUOTA_WINDOW_S / 3600,
        "recent": recent,
    });
    if let Some(first) = used.first() {
        v["reset"] = json!(crate::utc_text(first + QUOTA_WINDOW_S));
    }
    Ok(v)
}

async fn leaderboard(State(state): State<AppState>) -> ApiResult {
    let revealed = revealed(&state).await?;
    let (teams, subs) = {
        let store = state.store();
        (
            store.teams().await.map_err(ApiError::internal)?,
            store.all_submissions().await.map_err(ApiError::internal)?,
        )
    };
    let rows = leaderboard_rows(&teams, &subs, revealed);
    Ok(axum::Json(json!({"revealed": revealed, "rows": rows})).into_response())
}

/// The leaderboard. Before reveal: each team's best scored entry by
/// public Q_c (ties by |⟨m⟩|, then the earlier entry:
/// [`crate::challenge::best_public`], the entry the team's own view counts
/// by default), ranked by it. After reveal: of each team's final entries
/// (those it chose, or its best public one), the one with the best held-out
/// Q_c (ties by |⟨m⟩|, then the earlier entry), ranked by it,
/// with `finals` (the ids that counted) and `holdout`. Every row has `rank`,
/// `team`, `role`, `entries` (how many scored), `entry` and `public`.
/// Participants are ranked 1, 2, ...; the organisers' and the baseline's
/// rows are placed where their figures put them with `rank: null`. After
/// reveal each row also has `tied_above`: true when its held-out Q_c
/// interval ([`q_c_interval`]) overlaps that of the row above it (the
/// board does not rank the two apart).
pub fn leaderboard_rows(teams: &[Team], subs: &[Submission], revealed: bool) -> Vec<Value> {
    let mut rows: Vec<(Value, (f64, f64), i64)> = Vec::new();
    for team in teams {
        let own: Vec<&Submission> = subs
            .iter()
            .filter(|s| s.team_id == team.id && s.has_score())
            .collect();
        let Some(best) = crate::challenge::best_public(&own) else {
            continue;
        };
        let public = parse_figures(best.public_json.as_deref());
        let mut row = json!({
            "team": team.name,
            "role": team.role.name(),
            "entries": own.len(),
            "entry": best.id,
            "public": public,
        });
        let mut key = rank_key(&public);
        let mut entry = best.id;
        if revealed {
            let finals = final_entries_or_default(&own);
            let mut pick: Option<(&Submission, Value, (f64, f64))> = None;
            for s in &finals {
                let h = parse_figures(s.holdout_json.as_deref());
                let k = rank_key(&h);
                if pick
                    .as_ref()
                    .is_none_or(|p| k.partial_cmp(&p.2) == Some(std::cmp::Ordering::Less))
                {
                    pick = Some((s, h, k));
                }
            }
            if let Some((s, h, k)) = pick {
                row["entry"] = json!(s.id);
                row["public"] = parse_figures(s.public_json.as_deref());
                row["holdout"] = h;
                key = k;
                entry = s.id;
            }
            row["finals"] = json!(finals.iter().map(|s| s.id).collect::<Vec<_>>());
        }
        rows.push((row, key, entry));
    }
    rows.sort_by(|a, b| {
        a.1.partial_cmp(&b.1)
            .unwrap_or(std::cmp::Ordering::Equal)
            .then(a.2.cmp(&b.2))
    });
    let mut rank = 0;
    let mut above: Option<[f64; 2]> = None;
    rows.into_iter()
        .map(|(mut r, _, _)| {
            if r["role"] == Role::Participant.name() {
                rank += 1;
                r["rank"] = json!(rank);
            } else {
                r["rank"] = Value::Null;
            }
            if revealed {
                // Rows whose held-out Q_c intervals (95 %, bootstrap over
                // base fields) overlap are not ranked apart by this board.
                let ci = q_c_interval(&r["holdout"]);
                let tied =
                    matches!((above, ci), (Some(a), Some(b)) if a[0] <= b[1] && b[0] <= a[1]);
                r["tied_above"] = json!(tied);
                above = ci;
            }
            r
        })
        .collect()
}

/// The 95 % bootstrap interval of Q_c in a part's summary figures, when
/// the report has one.
pub fn q_c_interval(figures: &Value) -> Option<[f64; 2]> {
    let ci = figures.get("bootstrap")?.get("q_c")?.as_array()?;
    match (ci.first()?.as_f64(), ci.get(1)?.as_f64()) {
        (Some(lo), Some(hi)) if lo.is_finite() && hi.is_finite() => Some([lo, hi]),
        _ => None,
    }
}

/// The small form fields sent before a multipart upload's `file` (name,
/// value), as [`submit`]'s check sees them; empty for a raw body.
pub(crate) type FormFields = [(String, String)];

/// At most this many fields, of at most [`FIELD_MAX_BYTES`] each, may come
/// before a multipart upload's `file`.
const MAX_FIELDS: usize = 16;
const FIELD_MAX_BYTES: usize = 1024;

/// Streams the upload (raw body or multipart field `file`) into a temporary
/// file under `uploads/`, capped at `max` bytes; returns (path, SHA-256, size).
/// `check` sees the fields sent before `file` (nothing for a raw body) and
/// may refuse before a byte of the file is kept.
async fn receive(
    state: &AppState,
    req: Request,
    max: u64,
    check: impl FnOnce(&FormFields) -> Result<(), ApiError>,
) -> Result<(PathBuf, String, u64), ApiError> {
    let mut check = Some(check);
    let cut = req
        .extensions()
        .get::<crate::net::BodyCut>()
        .map(|c| c.0.clone());
    let limits = state.inner.limits.clone();
    // A body error: 408 when the body guard cut it off, else 400.
    let broke = |text: String| {
        if cut.as_ref().is_some_and(|c| c.load(Ordering::SeqCst)) {
            ApiError::new(
                StatusCode::REQUEST_TIMEOUT,
                format!(
                    "the upload arrived too slowly and was cut off: nothing for {} s, or less \
                     than {} bytes per second on average after the first {} s",
                    limits.body_stall_timeout.as_secs(),
                    limits.body_min_bytes_per_s,
                    limits.body_grace.as_secs()
                ),
            )
        } else {
            ApiError::new(StatusCode::BAD_REQUEST, text)
        }
    };
    let too_big = || {
        ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("the upload is larger than the limit of {max} bytes"),
        )
    };
    if let Some(len) = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
    {
        // A multipart body carries a little framing beyond the file.
        if len > max + 64 * 1024 {
            return Err(too_big());
        }
    }
    let mut nonce = [0u8; 12];
    getrandom::fill(&mut nonce).map_err(ApiError::internal)?;
    let tmp = state
        .inner
        .dir
        .join("uploads")
        .join(format!(".{}.tmp", hex(&nonce)));
    let mut file = tokio::fs::File::create(&tmp)
        .await
        .map_err(ApiError::internal)?;
    let result: Result<(String, u64), ApiError> = async {
        let mut hasher = Sha256::new();
        let mut size: u64 = 0;
        let mut sink = async |chunk: &[u8]| -> Result<(), ApiError> {
            size += chunk.len() as u64;
            if size > max {
                return Err(too_big());
            }
            hasher.update(chunk);
            file.write_all(chunk).await.map_err(ApiError::internal)
        };
        let multipart = req
            .headers()
            .get(header::CONTENT_TYPE)
            .and_then(|v| v.to_str().ok())
            .is_some_and(|v| v.starts_with("multipart/form-data"));
        if multipart {
            let mut mp = axum::extract::Multipart::from_request(req, state)
                .await
                .map_err(|e| broke(e.body_text()))?;
            let mut found = false;
            let mut fields: Vec<(String, String)> = Vec::new();
            while let Some(mut field) = mp.next_field().await.map_err(|e| broke(e.body_text()))? {
                if found {
                    continue;
                }
                if field.name() != Some("file") {
                    // Read in chunks, capped: a huge field is refused, never buffered.
                    if fields.len() >= MAX_FIELDS {
                        return Err(ApiError::new(
                            StatusCode::BAD_REQUEST,
                            "the multipart form has too many or too large fields before `file`",
                        ));
                    }
                    let name = field.name().unwrap_or_default().to_string();
                    let mut value = Vec::new();
                    while let Some(chunk) = field.chunk().await.map_err(|e| broke(e.body_text()))? {
                        value.extend_from_slice(&chunk);
                        if value.len() > FIELD_MAX_BYTES {
                            return Err(ApiError::new(
                                StatusCode::BAD_REQUEST,
                                "the multipart form has too many or too large fields before `file`",
                            ));
                        }
                    }
                    fields.push((name, String::from_utf8_lossy(&value).into_owned()));
                    continue;
                }
                found = true;
                if let Some(c) = check.take() {
                    c(&fields)?;
                }
                while let Some(chunk) = field.chunk().await.map_err(|e| broke(e.body_text()))? {
                    sink(chunk.as_ref()).await?;
                }
            }
            if !found {
                return Err(ApiError::new(
                    StatusCode::BAD_REQUEST,
                    "the multipart form has no field `file`",
                ));
            }
        } else {
            if let Some(c) = check.take() {
                c(&[])?;
            }
            let mut body: Body = req.into_body();
            while let Some(frame) = body.frame().await {
                let frame = frame.map_err(|e| broke(format!("the upload broke off: {e}")))?;
                if let Some(data) = frame.data_ref() {
                    sink(data.as_ref()).await?;
                }
            }
        }
        file.sync_all().await.map_err(ApiError::internal)?;
        Ok((hex(&hasher.finalize()), size))
    }
    .await;
    match result {
        Ok((sha, size)) => Ok((tmp, sha, size)),
        Err(e) => {
            let _ = tokio::fs::remove_file(&tmp).await;
            Err(e)
        }
    }
}

/// Refuses with 429 when a team has used its quota of accepted uploads
/// (counting `in_flight` other uploads of it still arriving or being
/// checked), or its cap on refused ones, in the last 24 hours.
async fn check_limits(state: &AppState, team_id: i64, in_flight: usize) -> Result<(), ApiError> {
    let since = crate::now_s() - QUOTA_WINDOW_S;
    let store = state.store();
    let accepted = store
        .accepted_since(team_id, since)
        .await
        .map_err(ApiError::internal)?;
    let refused = store
        .format_failures_since(team_id, since)
        .await
        .map_err(ApiError::internal)?;
    match limits(&state.inner.settings, &accepted, &refused, in_flight) {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// The answer when a team's quota or refusal cap is used, given the times
/// of its accepted entries and refused uploads in the window (oldest
/// first) and `in_flight` others of its uploads still arriving.
fn limits(s: &crate::Settings, used: &[i64], failed: &[i64], in_flight: usize) -> Option<ApiError> {
    let quota = s.quota as usize;
    if used.len() + in_flight >= quota {
        // The slot that frees first: the oldest counted upload leaving the
        // window, unless uploads still arriving hold the quota.
        let k = used.len() + in_flight - quota;
        let reset = used.get(k).map(|t| t + QUOTA_WINDOW_S);
        let counting = if in_flight > 0 {
            format!(", counting {in_flight} upload(s) of your team still arriving or being checked")
        } else {
            String::new()
        };
        let message = match reset {
            Some(r) => format!(
                "the quota of {} scored submissions per 24 hours is used{counting}; the next is \
                 possible at {}",
                s.quota,
                crate::utc_text(r)
            ),
            None => format!(
                "the quota of {} scored submissions per 24 hours is used{counting}",
                s.quota
            ),
        };
        return Some(ApiError {
            reset_s: reset,
            ..ApiError::new(StatusCode::TOO_MANY_REQUESTS, message)
        });
    }
    if failed.len() >= s.format_failure_cap as usize {
        let reset = failed[failed.len() - s.format_failure_cap as usize] + QUOTA_WINDOW_S;
        return Some(ApiError {
            reset_s: Some(reset),
            ..ApiError::new(
                StatusCode::TOO_MANY_REQUESTS,
                format!(
                    "{} refused uploads in 24 hours: check your files with `stepsim score` on a \
                     run of your own; the next upload is possible at {}",
                    s.format_failure_cap,
                    crate::utc_text(reset)
                ),
            )
        });
    }
    None
}

/// Why an upload is refused at `now_s` on `ledger` (the phase, then the
/// quota and the refusal cap counting no upload in flight), if it is: the
/// rule of the store's admission, and its answer when the store declines.
fn admission_refusal(
    s: &crate::Settings,
    ledger: &crate::store::Ledger,
    now_s: i64,
) -> Option<ApiError> {
    if let Some(why) = Phase::of_meta(&ledger.meta).upload_refusal(now_s) {
        return Some(ApiError::new(StatusCode::FORBIDDEN, why));
    }
    limits(s, &ledger.accepted, &ledger.refused, 0)
}

/// An upload of one team counted as in flight (being received or
/// checked) until it is dropped; holds a turn of all uploads at once.
struct UploadSlot {
    state: AppState,
    team_id: i64,
    _all: tokio::sync::OwnedSemaphorePermit,
}

impl UploadSlot {
    /// Takes a slot for `team_id`: 429 when the team has
    /// `uploads_per_team` in flight, 503 when the server has
    /// `uploads_at_once`. Returns it with the count of the team's other
    /// uploads in flight.
    fn take(state: &AppState, team_id: i64) -> Result<(Self, usize), ApiError> {
        let l = &state.inner.limits;
        let mut map = state
            .inner
            .uploads
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let n = map.get(&team_id).copied().unwrap_or(0);
        if n >= l.uploads_per_team.max(1) {
            return Err(ApiError::new(
                StatusCode::TOO_MANY_REQUESTS,
                format!(
                    "{n} upload(s) of your team are still arriving or being checked; at most {} \
                     at once: send the next when it is answered",
                    l.uploads_per_team.max(1)
                ),
            ));
        }
        let all = state
            .inner
            .uploads_all
            .clone()
            .try_acquire_owned()
            .map_err(|_| ApiError {
                reset_s: Some(crate::now_s() + 60),
                ..ApiError::new(
                    StatusCode::SERVICE_UNAVAILABLE,
                    format!(
                        "the server is receiving {} uploads already; send yours again in a minute \
                         (nothing was counted)",
                        l.uploads_at_once.max(1)
                    ),
                )
            })?;
        map.insert(team_id, n + 1);
        Ok((
            Self {
                state: state.clone(),
                team_id,
                _all: all,
            },
            n,
        ))
    }
}

impl Drop for UploadSlot {
    fn drop(&mut self) {
        let mut map = self
            .state
            .inner
            .uploads
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(n) = map.get_mut(&self.team_id) {
            *n = n.saturating_sub(1);
            if *n == 0 {
                map.remove(&self.team_id);
            }
        }
    }
}

/// The harness's format check of the upload at `tmp`, at most
/// `checks_at_once` at a time, within `check_budget` of wall-clock time
/// (its wait for a turn included). `Ok(Err(message))` is the harness's
/// refusal; `Err` is the server's (the budget, 503), not the participant's.
async fn format_check(
    state: &AppState,
    tmp: &std::path::Path,
) -> Result<Result<(), String>, ApiError> {
    let l = &state.inner.limits;
    let settings = state.inner.settings.clone();
    let checks = state.inner.checks.clone();
    let tmp2 = tmp.to_path_buf();
    let run = async move {
        let permit = checks.acquire_owned().await.map_err(ApiError::internal)?;
        // The harness call cannot be stopped: past the budget it goes on
        // (holding its turn, so checks at once stay bounded) and its
        // result is dropped.
        tokio::task::spawn_blocking(move || {
            let _turn = permit;
            let opts = crate::worker::upload_options(&settings, &tmp2);
            stepsim_harness::pipeline::prepare(&opts)
                .map(drop)
                .map_err(|e| {
                    crate::worker::participant_message(&e.to_string(), &tmp2, &settings.truth_dir)
                })
        })
        .await
        .map_err(ApiError::internal)
    };
    match tokio::time::timeout(l.check_budget, run).await {
        Ok(r) => r,
        Err(_) => Err(ApiError {
            reset_s: Some(crate::now_s() + 60),
            ..ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                format!(
                    "the server could not check the upload within {} s (it is busy); it was not \
                     kept and not counted against your team: send it again later",
                    l.check_budget.as_secs()
                ),
            )
        }),
    }
}

async fn post_submission(State(state): State<AppState>, req: Request) -> ApiResult {
    let team = auth(&state, req.headers()).await?;
    let accepted = submit(&state, &team, req, |_| Ok(())).await?;
    Ok(if accepted.duplicate {
        (
            StatusCode::OK,
            axum::Json(json!({"id": accepted.id, "status": accepted.status, "duplicate": true})),
        )
    } else {
        (
            StatusCode::ACCEPTED,
            axum::Json(json!({"id": accepted.id, "status": "queued"})),
        )
    }
    .into_response())
}

/// What [`submit`] made of an upload.
#[derive(Debug)]
pub(crate) struct Accepted {
    /// The entry's id.
    pub(crate) id: i64,
    /// Its status now (`queued` for a new one).
    pub(crate) status: String,
    /// True when the team had uploaded these bytes before (that entry).
    pub(crate) duplicate: bool,
}

/// An upload of `team` (raw body or multipart field `file`): the limits,
/// the streamed copy with its SHA-256, the harness's format check, the
/// duplicate check, the immutable file and the queue. The one path of both
/// `POST /api/submissions` and the page's upload form; `check` sees the
/// form's fields before the file (the form's CSRF token).
pub(crate) async fn submit(
    state: &AppState,
    team: &Team,
    req: Request,
    check: impl FnOnce(&FormFields) -> Result<(), ApiError>,
) -> Result<Accepted, ApiError> {
    let result = receive_and_queue(state, team, req, check).await;
    let status = match &result {
        Ok(a) if a.duplicate => {
            tracing::info!(
                team = team.id,
                entry = a.id,
                "upload: a duplicate of an entry"
            );
            StatusCode::OK
        }
        Ok(a) => {
            tracing::info!(team = team.id, entry = a.id, "upload accepted and queued");
            StatusCode::ACCEPTED
        }
        Err(e) => {
            tracing::info!(
                team = team.id,
                status = e.status.as_u16(),
                reason = %crate::observe::first_line(&e.message),
                "upload refused"
            );
            e.status
        }
    };
    state.metrics().upload(status.as_u16());
    result
}

/// [`submit`]'s work, before it is logged and counted.
async fn receive_and_queue(
    state: &AppState,
    team: &Team,
    req: Request,
    check: impl FnOnce(&FormFields) -> Result<(), ApiError>,
) -> Result<Accepted, ApiError> {
    if state.live_workers() == Some(0) {
        tracing::error!("no scoring worker runs; uploads are refused");
        return Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "the scoring queue is not running, so uploads are not accepted; nothing was \
             counted. The organisers have been told by the server's log",
        ));
    }
    let phase = Phase::read(state.store())
        .await
        .map_err(ApiError::internal)?;
    if let Some(why) = phase.upload_refusal(crate::now_s()) {
        return Err(ApiError::new(StatusCode::FORBIDDEN, why));
    }
    // Before a byte of the body is read: a turn among the team's and all
    // uploads at once, and the quota counting the team's uploads in flight.
    let (_slot, in_flight) = UploadSlot::take(state, team.id)?;
    check_limits(state, team.id, in_flight).await?;
    let max = state.inner.settings.max_upload_bytes;
    let (tmp, sha, size) = receive(state, req, max, check).await?;
    // The format check: the harness reads the whole upload against every
    // image of the run, as `stepsim score` does.
    let check = match format_check(state, &tmp).await {
        Ok(c) => c,
        Err(e) => {
            let _ = tokio::fs::remove_file(&tmp).await;
            return Err(e);
        }
    };
    if let Err(message) = check {
        let _ = tokio::fs::remove_file(&tmp).await;
        state
            .store()
            .add_format_failure(team.id, &message, crate::now_s())
            .await
            .map_err(ApiError::internal)?;
        return Err(ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, message));
    }
    // The phase, the duplicate check, the quota and the insert again, in
    // one transaction of the store that holds the team: the phase may have
    // changed during a slow upload (a body sent until after the deadline
    // or the reveal), and parallel uploads of one team, on any host, must
    // not all pass the quota. Only accepted entries count here: the uploads
    // that were in flight when this one took its slot have been counted
    // before its body was read, and those that finished since are in the
    // store (counting them again refused the second of two parallel
    // uploads under a quota of 2).
    let refuse = |e: ApiError| {
        let _ = std::fs::remove_file(&tmp);
        e
    };
    let final_path = state.inner.dir.join("uploads").join(&sha);
    // The file goes in place first (named by its hash: the same bytes are
    // the same file), so that no worker of any host finds an entry without
    // its upload.
    if final_path.exists() {
        let _ = std::fs::remove_file(&tmp);
    } else {
        std::fs::rename(&tmp, &final_path).map_err(|e| refuse(ApiError::internal(e)))?;
        if let Ok(d) = std::fs::File::open(state.inner.dir.join("uploads")) {
            let _ = d.sync_all();
        }
    }
    let now = crate::now_s();
    let settings = state.inner.settings.clone();
    let rule: crate::store::Rule =
        Arc::new(move |l| admission_refusal(&settings, l, now).is_none());
    let admitted = state
        .store()
        .admit(team.id, &sha, size as i64, now, now - QUOTA_WINDOW_S, rule)
        .await
        .map_err(ApiError::internal)?;
    match admitted {
        crate::store::Admission::Inserted(id) => Ok(Accepted {
            id,
            status: "queued".into(),
            duplicate: false,
        }),
        crate::store::Admission::Duplicate(id, status) => Ok(Accepted {
            id,
            status,
            duplicate: true,
        }),
        // The file stays: it is named by its hash, and an entry of this or
        // another team may hold the same bytes.
        crate::store::Admission::Declined(ledger) => Err(admission_refusal(
            &state.inner.settings,
            &ledger,
            now,
        )
        .unwrap_or_else(|| ApiError::internal("the admission was declined without a reason"))),
    }
}

/// Serves the API on `listen` with `workers` scoring workers of its own
/// (run with `worker`'s options) under `limits` until the process ends
/// ([`crate::net::serve_with_limits`]); `/metrics` answers anyone when
/// `open_metrics`, else the organisers. With no workers of its own, the
/// queue is scored by `stepsim worker` processes (on this host or others).
/// A job left `scoring` by a stopped server or worker is taken again once
/// its lease runs out.
pub async fn serve(
    dir: PathBuf,
    listen: &str,
    workers: usize,
    worker: crate::worker::WorkerOptions,
    limits: Limits,
    open_metrics: bool,
) -> Result<(), crate::ChallengeError> {
    let ch = Challenge::open_with_store(&dir, worker.store.as_ref()).await?;
    let pool = (workers > 0).then(|| crate::worker::WorkerPool::start_with(&dir, workers, worker));
    let listener = tokio::net::TcpListener::bind(listen)
        .await
        .map_err(|e| crate::ChallengeError::Run(format!("cannot listen on {listen}: {e}")))?;
    let addr = listener
        .local_addr()
        .map_err(|e| crate::ChallengeError::Run(e.to_string()))?;
    eprintln!("stepsim serve: listening on http://{addr}");
    let state = match &pool {
        Some(pool) => AppState::serving(ch, limits.clone(), pool, open_metrics),
        None => AppState::build(ch, limits.clone(), None, Arc::default(), open_metrics),
    };
    let result = crate::net::serve_with_limits(listener, router(state), limits).await;
    if let Some(pool) = pool {
        let _ = tokio::task::spawn_blocking(move || pool.stop()).await;
    }
    result.map_err(|e| crate::ChallengeError::Run(format!("server stopped: {e}")))
}

/// [`serve`] on a runtime of its own (for the command line).
pub fn serve_blocking(
    dir: PathBuf,
    listen: &str,
    workers: usize,
    worker: crate::worker::WorkerOptions,
    limits: Limits,
    open_metrics: bool,
) -> Result<(), crate::ChallengeError> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| crate::ChallengeError::Run(format!("cannot start the server: {e}")))?;
    rt.block_on(serve(dir, listen, workers, worker, limits, open_metrics))
}
