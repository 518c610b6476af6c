//! The JSON API (docs/server.md, "API"):
//!
//! ```text
//! POST /api/submissions       Bearer token; the file as the body (raw, or
//!                             multipart field `file`) -> 202 {"id", "status"}
//! GET  /api/submissions       the caller's entries, newest first
//! GET  /api/submissions/{id}  one of the caller's entries (404 for others')
//! GET  /api/leaderboard       {"revealed", "rows": [{"team", ...}]}
//! ```
//!
//! Errors are JSON `{"error": "..."}`: 401 without a valid token, 404 for
//! what does not exist or is another team's, 413 past the size cap, 422 for
//! an upload the harness refuses (its message, file paths replaced), 429
//! past the quota or the cap on refused uploads (with `reset`, also as
//! `Retry-After`).

use crate::challenge::{Challenge, QUOTA_WINDOW_S, hex, token_hash};
use crate::store::{Store, Submission, Team};
use axum::Router;
use axum::body::Body;
use axum::extract::{FromRequest, Path as UrlPath, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use http_body_util::BodyExt;
use serde_json::{Value, json};
use sha2::{Digest, Sha256};
use std::path::PathBuf;
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
    store: Mutex<Box<dyn Store>>,
    /// Times (s) of the recent requests of each token hash / client address.
    recent: Mutex<std::collections::HashMap<String, std::collections::VecDeque<i64>>>,
}

/// The window of the per-token and per-address rate limit.
pub const RATE_WINDOW_S: i64 = 60;

impl AppState {
    /// The state of a challenge (its own store connection).
    pub fn new(ch: Challenge) -> Self {
        Self {
            inner: Arc::new(Inner {
                dir: ch.dir,
                settings: ch.settings,
                store: Mutex::new(ch.store),
                recent: Mutex::new(std::collections::HashMap::new()),
            }),
        }
    }

    pub(crate) fn store(&self) -> std::sync::MutexGuard<'_, Box<dyn Store>> {
        self.inner
            .store
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// The challenge's settings.
    pub(crate) fn settings(&self) -> &crate::Settings {
        &self.inner.settings
    }

    /// The challenge's state directory.
    pub(crate) fn dir(&self) -> &std::path::Path {
        &self.inner.dir
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
    pub(crate) fn new(status: StatusCode, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
            reset_s: None,
        }
    }
    pub(crate) fn internal(e: impl std::fmt::Display) -> Self {
        eprintln!("stepsim serve: internal error: {e}");
        Self::new(
            StatusCode::INTERNAL_SERVER_ERROR,
            "the server failed; the organisers can see why in its log",
        )
    }
    pub(crate) fn not_found() -> Self {
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
    Router::new()
        .route(
            "/api/submissions",
            get(list_submissions).post(post_submission),
        )
        .route("/api/submissions/{id}", get(get_submission))
        .route("/api/leaderboard", get(leaderboard))
        .merge(crate::web::routes(&state))
        .fallback(|| async { ApiError::not_found() })
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            rate_limit,
        ))
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
    let mut keys = Vec::new();
    if let Some(info) = req
        .extensions()
        .get::<axum::extract::ConnectInfo<std::net::SocketAddr>>()
    {
        keys.push(format!("addr {}", info.0.ip()));
    }
    if let Some(v) = req
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
    {
        keys.push(format!("token {}", token_hash(v)));
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
        for k in &keys {
            let times = recent.entry(k.clone()).or_default();
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

/// The team of a request's bearer token, or 401.
fn auth(state: &AppState, headers: &HeaderMap) -> Result<Team, ApiError> {
    let unauthorized = || {
        ApiError::new(
            StatusCode::UNAUTHORIZED,
            "a valid token is needed: send `Authorization: Bearer TOKEN`",
        )
    };
    let value = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .ok_or_else(unauthorized)?;
    let token = value
        .strip_prefix("Bearer ")
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .ok_or_else(unauthorized)?;
    state
        .store()
        .team_by_token(&token_hash(token))
        .map_err(ApiError::internal)?
        .ok_or_else(unauthorized)
}

/// One entry as its team sees it.
fn entry_json(s: &Submission, revealed: bool) -> Value {
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
    });
    if let Some(e) = &s.error {
        v["error"] = json!(e);
    }
    if s.status == "scored" {
        v["public"] = parse(&s.public_json).unwrap_or(Value::Null);
        if revealed && s.holdout_json.is_some() {
            v["holdout"] = parse(&s.holdout_json).unwrap_or(Value::Null);
        }
    }
    v
}

pub(crate) fn revealed(state: &AppState) -> Result<bool, ApiError> {
    Ok(state
        .store()
        .meta("revealed")
        .map_err(ApiError::internal)?
        .as_deref()
        == Some("true"))
}

async fn list_submissions(State(state): State<AppState>, headers: HeaderMap) -> ApiResult {
    let team = auth(&state, &headers)?;
    let revealed = revealed(&state)?;
    let subs = state
        .store()
        .submissions_of(team.id)
        .map_err(ApiError::internal)?;
    let quota = quota_status(&state, team.id)?;
    let entries: Vec<Value> = subs.iter().map(|s| entry_json(s, revealed)).collect();
    Ok(
        axum::Json(json!({"team": team.name, "quota": quota, "submissions": entries}))
            .into_response(),
    )
}

async fn get_submission(
    State(state): State<AppState>,
    headers: HeaderMap,
    UrlPath(id): UrlPath<String>,
) -> ApiResult {
    let team = auth(&state, &headers)?;
    let id: i64 = id.parse().map_err(|_| ApiError::not_found())?;
    let sub = state
        .store()
        .submission(id)
        .map_err(ApiError::internal)?
        .filter(|s| s.team_id == team.id)
        .ok_or_else(ApiError::not_found)?;
    let revealed = revealed(&state)?;
    Ok(axum::Json(entry_json(&sub, revealed)).into_response())
}

/// The quota of a team now: used, limit and when the oldest use expires.
pub(crate) fn quota_status(state: &AppState, team_id: i64) -> Result<Value, ApiError> {
    let now = crate::now_s();
    let used = state
        .store()
        .accepted_since(team_id, now - QUOTA_WINDOW_S)
        .map_err(ApiError::internal)?;
    let limit = state.inner.settings.quota;
    let mut v = json!({"used": used.len(), "limit": limit, "window_hours": 24});
    if let Some(first) = used.first() {
        v["reset"] = json!(crate::utc_text(first + QUOTA_WINDOW_S));
    }
    Ok(v)
}

async fn leaderboard(State(state): State<AppState>) -> ApiResult {
    let revealed = revealed(&state)?;
    let (teams, subs) = {
        let store = state.store();
        (
            store.teams().map_err(ApiError::internal)?,
            store.all_submissions().map_err(ApiError::internal)?,
        )
    };
    let rows = leaderboard_rows(&teams, &subs, revealed);
    Ok(axum::Json(json!({"revealed": revealed, "rows": rows})).into_response())
}

fn number(v: &Value, key: &str) -> Option<f64> {
    v.get(key).and_then(Value::as_f64)
}

/// The leaderboard: each team's best scored entry by public Q_c (ties by
/// |⟨m⟩|, then by the earlier entry). Before reveal the rows carry the
/// public feedback only, ranked by it; after, the held-out summary of that
/// entry too, ranked by held-out Q_c.
pub fn leaderboard_rows(teams: &[Team], subs: &[Submission], revealed: bool) -> Vec<Value> {
    let key = |v: &Value| {
        (
            -number(v, "q_c").unwrap_or(f64::NEG_INFINITY),
            number(v, "m_mean").map_or(f64::INFINITY, f64::abs),
        )
    };
    let mut rows: Vec<(Value, (f64, f64))> = Vec::new();
    for team in teams {
        let mut best: Option<(&Submission, Value)> = None;
        let mut n = 0;
        for s in subs
            .iter()
            .filter(|s| s.team_id == team.id && s.status == "scored")
        {
            n += 1;
            let Some(p) = s
                .public_json
                .as_deref()
                .and_then(|t| serde_json::from_str::<Value>(t).ok())
            else {
                continue;
            };
            let better = match &best {
                None => true,
                Some((_, b)) => key(&p).partial_cmp(&key(b)) == Some(std::cmp::Ordering::Less),
            };
            if better {
                best = Some((s, p));
            }
        }
        let Some((s, public)) = best else { continue };
        let mut k = key(&public);
        let mut row = json!({"team": team.name, "entries": n, "entry": s.id, "public": public});
        if revealed {
            let h = s
                .holdout_json
                .as_deref()
                .and_then(|t| serde_json::from_str::<Value>(t).ok())
                .unwrap_or(Value::Null);
            k = key(&h);
            row["holdout"] = h;
        }
        rows.push((row, k));
    }
    rows.sort_by(|a, b| a.1.partial_cmp(&b.1).unwrap_or(std::cmp::Ordering::Equal));
    rows.into_iter()
        .enumerate()
        .map(|(i, (mut r, _))| {
            r["rank"] = json!(i + 1);
            r
        })
        .collect()
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
                .map_err(|e| ApiError::new(StatusCode::BAD_REQUEST, e.body_text()))?;
            let mut found = false;
            let mut fields: Vec<(String, String)> = Vec::new();
            while let Some(mut field) = mp
                .next_field()
                .await
                .map_err(|e| ApiError::new(StatusCode::BAD_REQUEST, e.body_text()))?
            {
                if found {
                    continue;
                }
                if field.name() != Some("file") {
                    // Read in chunks, capped: a huge field is refused, never buffered.
                    let name = field.name().unwrap_or_default().to_string();
                    let mut value = Vec::new();
                    while let Some(chunk) = field
                        .chunk()
                        .await
                        .map_err(|e| ApiError::new(StatusCode::BAD_REQUEST, e.body_text()))?
                    {
                        value.extend_from_slice(&chunk);
                        if fields.len() >= MAX_FIELDS || value.len() > FIELD_MAX_BYTES {
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
                while let Some(chunk) = field
                    .chunk()
                    .await
                    .map_err(|e| ApiError::new(StatusCode::BAD_REQUEST, e.body_text()))?
                {
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
                let frame = frame.map_err(|e| {
                    ApiError::new(
                        StatusCode::BAD_REQUEST,
                        format!("the upload broke off: {e}"),
                    )
                })?;
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

/// Refuses with 429 when a team has used its quota of accepted uploads, or
/// its cap on refused ones, in the last 24 hours.
fn check_limits(state: &AppState, team_id: i64) -> Result<(), ApiError> {
    let now = crate::now_s();
    let since = now - QUOTA_WINDOW_S;
    let s = &state.inner.settings;
    let store = state.store();
    let used = store
        .accepted_since(team_id, since)
        .map_err(ApiError::internal)?;
    if used.len() >= s.quota as usize {
        let reset = used[used.len() - s.quota as usize] + QUOTA_WINDOW_S;
        return Err(ApiError {
            reset_s: Some(reset),
            ..ApiError::new(
                StatusCode::TOO_MANY_REQUESTS,
                format!(
                    "the quota of {} scored submissions per 24 hours is used; the next is possible at {}",
                    s.quota,
                    crate::utc_text(reset)
                ),
            )
        });
    }
    let failed = store
        .format_failures_since(team_id, since)
        .map_err(ApiError::internal)?;
    if failed.len() >= s.format_failure_cap as usize {
        let reset = failed[failed.len() - s.format_failure_cap as usize] + QUOTA_WINDOW_S;
        return Err(ApiError {
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
    Ok(())
}

async fn post_submission(State(state): State<AppState>, req: Request) -> ApiResult {
    let team = auth(&state, req.headers())?;
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
    check_limits(state, team.id)?;
    let max = state.inner.settings.max_upload_bytes;
    let (tmp, sha, size) = receive(state, req, max, check).await?;
    // The format check: the harness reads the whole upload against every
    // image of the run, as `stepsim score` does.
    let truth = state.inner.settings.truth_dir.clone();
    let tmp2 = tmp.clone();
    let check = tokio::task::spawn_blocking(move || {
        let opts = stepsim_harness::pipeline::ScoreOptions::new(&truth, &tmp2);
        stepsim_harness::pipeline::prepare(&opts)
            .map(drop)
            .map_err(|e| crate::worker::participant_message(&e.to_string(), &tmp2, &truth))
    })
    .await
    .map_err(ApiError::internal)?;
    if let Err(message) = check {
        let _ = tokio::fs::remove_file(&tmp).await;
        state
            .store()
            .add_format_failure(team.id, &message, crate::now_s())
            .map_err(ApiError::internal)?;
        return Err(ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, message));
    }
    let dup = state
        .store()
        .find_duplicate(team.id, &sha)
        .map_err(ApiError::internal)?;
    if let Some(id) = dup {
        let _ = tokio::fs::remove_file(&tmp).await;
        let s = state.store().submission(id).map_err(ApiError::internal)?;
        let status = s.map(|s| s.status).unwrap_or_default();
        return Ok(Accepted {
            id,
            status,
            duplicate: true,
        });
    }
    let final_path = state.inner.dir.join("uploads").join(&sha);
    if final_path.exists() {
        let _ = tokio::fs::remove_file(&tmp).await;
    } else {
        tokio::fs::rename(&tmp, &final_path)
            .await
            .map_err(ApiError::internal)?;
        if let Ok(d) = std::fs::File::open(state.inner.dir.join("uploads")) {
            let _ = d.sync_all();
        }
    }
    let id = state
        .store()
        .insert_submission(team.id, &sha, size as i64, crate::now_s())
        .map_err(ApiError::internal)?;
    Ok(Accepted {
        id,
        status: "queued".into(),
        duplicate: false,
    })
}

/// Serves the API on `listen` with `workers` scoring workers until the
/// process ends. Jobs left `scoring` by a stopped server are queued again.
pub async fn serve(
    dir: PathBuf,
    listen: &str,
    workers: usize,
    timeout: std::time::Duration,
) -> Result<(), crate::ChallengeError> {
    let mut ch = Challenge::open(&dir)?;
    let n = ch.store.requeue_interrupted()?;
    if n > 0 {
        eprintln!("stepsim serve: {n} interrupted scoring jobs queued again");
    }
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    for _ in 0..workers.max(1) {
        let (d, s) = (dir.clone(), stop.clone());
        std::thread::spawn(move || {
            if let Err(e) = crate::worker::run_worker(&d, s, timeout) {
                eprintln!("stepsim serve: worker stopped: {e}");
            }
        });
    }
    let listener = tokio::net::TcpListener::bind(listen)
        .await
        .map_err(|e| crate::ChallengeError::Run(format!("cannot listen on {listen}: {e}")))?;
    let addr = listener
        .local_addr()
        .map_err(|e| crate::ChallengeError::Run(e.to_string()))?;
    eprintln!("stepsim serve: listening on http://{addr}");
    axum::serve(
        listener,
        router(AppState::new(ch)).into_make_service_with_connect_info::<std::net::SocketAddr>(),
    )
    .await
    .map_err(|e| crate::ChallengeError::Run(format!("server stopped: {e}")))
}

/// [`serve`] on a runtime of its own (for the command line).
pub fn serve_blocking(
    dir: PathBuf,
    listen: &str,
    workers: usize,
    timeout: std::time::Duration,
) -> Result<(), crate::ChallengeError> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| crate::ChallengeError::Run(format!("cannot start the server: {e}")))?;
    rt.block_on(serve(dir, listen, workers, timeout))
}
