//! The handlers: everything that knows HTTP. The state the handlers share
//! ([`AppState`]), the error answer ([`ApiError`]), the router and the
//! server; under it the JSON API by job ([`api`]), the participants' and
//! organisers' pages by page ([`pages`]), the token check and rate limit
//! ([`auth`]), the connection layer ([`net`]) and its limits ([`limits`]).
//!
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
//!                             a page for a browser (`pages::wants_html`)
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

pub mod api;
pub mod auth;
pub mod limits;
mod log;
pub mod net;
pub mod pages;

use crate::challenge::{Challenge, token_hash};
use crate::store::{Store, Team};
use axum::Router;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use limits::Limits;
use serde_json::json;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

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
    uploads: Mutex<std::collections::HashMap<i64, api::upload::TeamUploads>>,
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

pub(crate) type ApiResult = Result<Response, ApiError>;

/// The router of the API, with security headers on every answer.
pub fn router(state: AppState) -> Router {
    use tower_http::set_header::SetResponseHeaderLayer as H;
    let (pages, web) = pages::pages(&state);
    Router::new()
        .merge(api::routes())
        .merge(pages)
        .fallback(|| async { ApiError::not_found() })
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            net::guard_body,
        ))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            auth::rate_limit,
        ))
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            pages::html_errors,
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
            log::log_requests,
        ))
        .with_state(state)
}

/// True when the held-out scores are open.
pub(crate) async fn revealed(state: &AppState) -> Result<bool, ApiError> {
    Ok(state
        .store()
        .meta("revealed")
        .await
        .map_err(ApiError::internal)?
        .as_deref()
        == Some("true"))
}

/// Serves the API on `listen` with `workers` scoring workers of its own
/// (run with `worker`'s options) under `limits` until the process ends
/// ([`net::serve_with_limits`]); `/metrics` answers anyone when
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
    let result = net::serve_with_limits(listener, router(state), limits).await;
    if let Some(pool) = pool {
        let _ = tokio::task::spawn_blocking(move || pool.stop()).await;
    }
    result.map_err(|e| crate::ChallengeError::Run(format!("server stopped: {e}")))
}

/// `serve` on a runtime of its own (for the command line).
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
