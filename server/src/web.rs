//! The participants' pages (docs/server.md, "Pages"): HTML rendered on the
//! server from templates built into the binary (`server/templates/`,
//! minijinja, every value escaped), no JavaScript.
//!
//! ```text
//! GET  /                       the challenge: the run's README, the rules
//! GET  /signin, POST /signin   a team token -> a session cookie
//! POST /signout                ends the session
//! GET  /entries, POST /entries the team's entries, quota, the upload form
//! GET  /leaderboard            the board (the final one after reveal)
//! GET  /entries/{id}/report    after reveal: full reports, both parts
//! GET  /entries/{id}/figures/{public|holdout}/{fig}.png   after reveal
//! GET  /static/style.css       the stylesheet
//! ```
//!
//! A session is a random 256-bit id in an `HttpOnly; SameSite=Strict`
//! cookie; the server keeps only its SHA-256, with the team's token hash
//! (a revoked or rotated token ends its sessions) and the session's CSRF
//! token. Sessions live in memory: a restarted server signs everyone out.
//! Every form POST carries a CSRF token in a hidden field and must come
//! from the page's own origin (`Origin`, else `Referer`); the upload form
//! goes through [`crate::api`]'s one upload path.

mod markdown;
mod report;

pub use markdown::{escape, markdown_html};

use crate::api::{ApiError, AppState};
use crate::challenge::{hex, token_hash};
use crate::store::{Role, Team};
use axum::Router;
use axum::body::Body;
use axum::extract::{Extension, Path as UrlPath, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use minijinja::Environment;
use serde::Serialize;
use serde_json::Value;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use stepsim_harness::pipeline::{REPORT_FIGURES, REPORT_JSON};

/// The session cookie.
pub const SESSION_COOKIE: &str = "stepsim_session";
/// The sign-in form's CSRF cookie (double submit: cookie and hidden field).
pub const SIGNIN_COOKIE: &str = "stepsim_signin";
/// The organisers' sign-in form's CSRF cookie (on `/organisers`).
pub const ORGANISER_SIGNIN_COOKIE: &str = "stepsim_org_signin";
/// How long a session lasts.
pub const SESSION_S: i64 = 12 * 3600;
/// Sessions kept at most; past it the one closest to expiry goes.
pub const MAX_SESSIONS: usize = 10_000;
/// The pages' Content-Security-Policy: no script at all, styles and images
/// from the server only, forms posting only to it, no framing.
pub const PAGE_CSP: &str = "default-src 'none'; img-src 'self'; style-src 'self'; \
                            form-action 'self'; frame-ancestors 'none'; base-uri 'none'";
/// The pages' Referrer-Policy: a form post carries its `Origin` (browsers
/// send `Origin: null` under `no-referrer`), nothing goes to other sites.
pub const PAGE_REFERRER_POLICY: &str = "same-origin";
/// The largest sign-in or sign-out form body read.
const FORM_MAX_BYTES: usize = 16 * 1024;

const STYLE_CSS: &str = include_str!("../templates/style.css");

/// The page templates, compiled into the binary.
const TEMPLATES: [(&str, &str); 9] = [
    ("base.html", include_str!("../templates/base.html")),
    ("index.html", include_str!("../templates/index.html")),
    ("data.html", include_str!("../templates/data.html")),
    ("signin.html", include_str!("../templates/signin.html")),
    ("entries.html", include_str!("../templates/entries.html")),
    (
        "leaderboard.html",
        include_str!("../templates/leaderboard.html"),
    ),
    ("report.html", include_str!("../templates/report.html")),
    ("message.html", include_str!("../templates/message.html")),
    (
        "organisers.html",
        include_str!("../templates/organisers.html"),
    ),
];

/// The template environment (autoescape on for `.html`).
pub fn templates() -> Result<Environment<'static>, minijinja::Error> {
    let mut env = Environment::new();
    env.set_undefined_behavior(minijinja::UndefinedBehavior::Strict);
    for (name, source) in TEMPLATES {
        env.add_template(name, source)?;
    }
    Ok(env)
}

#[derive(Debug, Clone)]
struct Session {
    /// The team's token hash (empty for an organiser session).
    token_sha256: String,
    /// Signed in with the organiser password (no team).
    organiser: bool,
    csrf: String,
    expires_s: i64,
}

/// What the pages share besides [`AppState`].
pub(crate) struct Web {
    env: Result<Environment<'static>, String>,
    /// The run's `public/README.md` as HTML, read when the server starts.
    readme_html: Option<String>,
    /// SHA-256 of the session id -> session.
    sessions: Mutex<HashMap<String, Session>>,
}

type Shared = Extension<Arc<Web>>;

/// The pages' routes, merged into [`crate::api::router`], and what they
/// share: the router puts it in every request's extensions, so that
/// [`html_errors`] and [`data_index`] render pages too.
pub(crate) fn pages(state: &AppState) -> (Router<AppState>, Arc<Web>) {
    use tower_http::set_header::SetResponseHeaderLayer as H;
    let readme = state
        .settings()
        .truth_dir
        .parent()
        .map(|run| run.join("public").join("README.md"))
        .and_then(|p| std::fs::read_to_string(p).ok())
        .map(|t| markdown_html(&t));
    let web = Arc::new(Web {
        env: templates().map_err(|e| e.to_string()),
        readme_html: readme,
        sessions: Mutex::new(HashMap::new()),
    });
    let router = Router::new()
        .route("/", get(index))
        .route("/signin", get(signin_page).post(signin))
        .route("/signout", post(signout))
        .route("/entries", get(entries_page).post(upload))
        .route("/entries/final", post(choose_final))
        .route("/organisers", get(organisers_page))
        .route("/organisers/signin", post(organisers_signin))
        .route("/metrics", get(metrics))
        .route("/leaderboard", get(leaderboard_page))
        .route("/entries/{id}/report", get(report_page))
        .route("/entries/{id}/figures/{part}/{file}", get(figure))
        .route("/static/style.css", get(stylesheet))
        .layer(Extension(web.clone()))
        .layer(H::overriding(
            header::CONTENT_SECURITY_POLICY,
            HeaderValue::from_static(PAGE_CSP),
        ))
        .layer(H::overriding(
            header::REFERRER_POLICY,
            HeaderValue::from_static(PAGE_REFERRER_POLICY),
        ));
    (router, web)
}

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

// ---- small helpers ----------------------------------------------------

/// `v` with `dp` decimals, a true minus sign, `—` when missing.
pub(crate) fn fixed(v: Option<f64>, dp: usize) -> String {
    match v.filter(|v| v.is_finite()) {
        Some(v) => {
            let s = format!("{v:.dp$}");
            match s.strip_prefix('-') {
                // -0.000 reads as 0.000.
                Some(rest) if rest.chars().all(|c| c == '0' || c == '.') => rest.to_string(),
                Some(rest) => format!("−{rest}"),
                None => s,
            }
        }
        None => "—".into(),
    }
}

/// As [`fixed`], with a `+` on positive values (columns of signed numbers).
pub(crate) fn signed(v: Option<f64>, dp: usize) -> String {
    let s = fixed(v, dp);
    match v {
        Some(x) if x > 0.0 && !s.chars().all(|c| c == '0' || c == '.') => format!("+{s}"),
        _ => s,
    }
}

/// The ends of a 95 % interval as shown with `dp` decimals by `show`
/// ([`fixed`] or [`signed`]); `None` when they read the same: an interval
/// of no width at the precision shown (the bootstrap found no spread: one
/// base field, or resamples that all agree) says nothing of the
/// uncertainty, and is shown as "—" (the leaderboard and the report page).
pub(crate) fn interval_ends(
    ci: [f64; 2],
    dp: usize,
    show: fn(Option<f64>, usize) -> String,
) -> Option<(String, String)> {
    let (lo, hi) = (show(Some(ci[0]), dp), show(Some(ci[1]), dp));
    (lo != hi).then_some((lo, hi))
}

/// A time as `YYYY-MM-DD HH:MM UTC`.
fn when(t_s: i64) -> String {
    let t = crate::utc_text(t_s);
    format!("{} {} UTC", &t[..10], &t[11..16])
}

/// A byte count for people (`12.3 kB`).
fn size_text(bytes: i64) -> String {
    let b = bytes as f64;
    if b < 1e3 {
        format!("{bytes} B")
    } else if b < 1e6 {
        format!("{:.1} kB", b / 1e3)
    } else if b < 1e9 {
        format!("{:.1} MB", b / 1e6)
    } else {
        format!("{:.2} GB", b / 1e9)
    }
}

/// A size cap for people: whole MiB or KiB when it is one (`256 MiB`).
fn cap_text(bytes: u64) -> String {
    if bytes >= 1 << 20 && bytes % (1 << 20) == 0 {
        format!("{} MiB", bytes >> 20)
    } else if bytes >= 1 << 10 && bytes % (1 << 10) == 0 {
        format!("{} KiB", bytes >> 10)
    } else {
        format!("{bytes} bytes")
    }
}

fn random_hex() -> Result<String, ApiError> {
    let mut b = [0u8; 32];
    getrandom::fill(&mut b).map_err(ApiError::internal)?;
    Ok(hex(&b))
}

/// Equality of two secrets in time independent of where they differ.
fn same_secret(a: &str, b: &str) -> bool {
    a.len() == b.len()
        && a.bytes()
            .zip(b.bytes())
            .fold(0u8, |acc, (x, y)| acc | (x ^ y))
            == 0
}

/// The value of cookie `name`.
fn cookie(headers: &HeaderMap, name: &str) -> Option<String> {
    headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|kv| kv.trim().split_once('='))
        .find(|(k, _)| *k == name)
        .map(|(_, v)| v.to_string())
}

/// Whether a form post comes from this server's own pages: its `Origin`
/// (else its `Referer`) must be `http(s)://HOST` of the request. A request
/// carrying neither (not a browser) is left to the CSRF token.
pub fn same_origin(headers: &HeaderMap) -> bool {
    let host = headers.get(header::HOST).and_then(|v| v.to_str().ok());
    let ok = |origin: &str| {
        host.is_some_and(|h| origin == format!("http://{h}") || origin == format!("https://{h}"))
    };
    if let Some(o) = headers.get(header::ORIGIN) {
        return o.to_str().is_ok_and(ok);
    }
    if let Some(r) = headers.get(header::REFERER) {
        let Ok(r) = r.to_str() else { return false };
        let Some((scheme, rest)) = r.split_once("://") else {
            return false;
        };
        let authority = rest.split('/').next().unwrap_or("");
        return ok(&format!("{scheme}://{authority}"));
    }
    true
}

// ---- rendering --------------------------------------------------------

/// The signed-in team as the page header shows it.
#[derive(Debug, Serialize)]
struct Nav {
    /// The challenge's name (`challenge init --name`, or the run
    /// directory's name).
    challenge: String,
    team: Option<String>,
    /// Signed in with the organiser password.
    organiser: bool,
    csrf: String,
    page: &'static str,
}

impl Nav {
    async fn new(
        state: &AppState,
        session: Option<&Session>,
        team: Option<&Team>,
        page: &'static str,
    ) -> Self {
        let challenge = state
            .store()
            .meta("name")
            .await
            .ok()
            .flatten()
            .unwrap_or_else(|| "stepsim challenge".into());
        Nav {
            challenge,
            team: team.map(|t| t.name.clone()),
            organiser: session.is_some_and(|s| s.organiser),
            csrf: session.map(|s| s.csrf.clone()).unwrap_or_default(),
            page,
        }
    }
}

impl Web {
    fn render(&self, status: StatusCode, name: &str, ctx: Value) -> Response {
        self.render_value(status, name, minijinja::Value::from_serialize(&ctx))
    }

    fn render_value(&self, status: StatusCode, name: &str, ctx: minijinja::Value) -> Response {
        let html = self.env.as_ref().map_err(|e| e.clone()).and_then(|env| {
            env.get_template(name)
                .and_then(|t| t.render(&ctx))
                .map_err(|e| format!("{e:#}"))
        });
        match html {
            // The pages' own policies, also on pages answered outside the
            // pages' routes (errors, the data page).
            Ok(html) => (
                status,
                [
                    (header::CONTENT_TYPE, "text/html; charset=utf-8"),
                    (header::CONTENT_SECURITY_POLICY, PAGE_CSP),
                    (header::REFERRER_POLICY, PAGE_REFERRER_POLICY),
                ],
                html,
            )
                .into_response(),
            Err(e) => {
                tracing::error!(page = name, error = %e, "page failed");
                (
                    StatusCode::INTERNAL_SERVER_ERROR,
                    [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
                    "the page failed; the organisers can see why in the server's log",
                )
                    .into_response()
            }
        }
    }

    /// A page of one message (errors, refusals).
    fn message(&self, nav: &Nav, status: StatusCode, title: &str, text: &str) -> Response {
        self.render(
            status,
            "message.html",
            serde_json::json!({"nav": nav, "title": title, "text": text,
                               "code": status.as_u16()}),
        )
    }

    fn error(&self, nav: &Nav, e: &ApiError) -> Response {
        let title = match e.status {
            StatusCode::NOT_FOUND => "Not found",
            StatusCode::FORBIDDEN => "Refused",
            StatusCode::TOO_MANY_REQUESTS => "Too many requests",
            s if s.is_server_error() => "Server error",
            _ => "Refused",
        };
        self.message(nav, e.status, title, &e.message)
    }

    /// The session of a request: an organiser's (no team), or a team's
    /// whose token still works. Expired sessions and those of revoked or
    /// rotated tokens are dropped.
    async fn session(
        &self,
        state: &AppState,
        headers: &HeaderMap,
    ) -> Option<(Session, Option<Team>)> {
        let id = cookie(headers, SESSION_COOKIE)?;
        let key = token_hash(&id);
        let sessions = || {
            self.sessions
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
        };
        let s = sessions().get(&key)?.clone();
        let live = s.expires_s > crate::now_s();
        if live && s.organiser {
            return Some((s, None));
        }
        let team = match live {
            true => state
                .store()
                .team_by_token(&s.token_sha256)
                .await
                .ok()
                .flatten(),
            false => None,
        };
        match team {
            Some(t) => {
                crate::observe::note_team(t.id);
                Some((s, Some(t)))
            }
            None => {
                sessions().remove(&key);
                None
            }
        }
    }

    /// The session of a signed-in team, if any.
    async fn team_session(&self, state: &AppState, headers: &HeaderMap) -> Option<(Session, Team)> {
        match self.session(state, headers).await? {
            (s, Some(t)) => Some((s, t)),
            (_, None) => None,
        }
    }

    async fn nav(&self, state: &AppState, headers: &HeaderMap, page: &'static str) -> Nav {
        match self.session(state, headers).await {
            Some((s, t)) => Nav::new(state, Some(&s), t.as_ref(), page).await,
            None => Nav::new(state, None, None, page).await,
        }
    }

    /// Starts a session for a token's hash (empty with `organiser`);
    /// returns the cookie's value.
    fn start_session(&self, token_sha256: &str, organiser: bool) -> Result<String, ApiError> {
        let id = random_hex()?;
        let now = crate::now_s();
        let mut sessions = self
            .sessions
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        sessions.retain(|_, s| s.expires_s > now);
        if sessions.len() >= MAX_SESSIONS {
            let oldest = sessions
                .iter()
                .min_by_key(|(_, s)| s.expires_s)
                .map(|(k, _)| k.clone());
            if let Some(k) = oldest {
                sessions.remove(&k);
            }
        }
        sessions.insert(
            token_hash(&id),
            Session {
                token_sha256: token_sha256.to_string(),
                organiser,
                csrf: random_hex()?,
                expires_s: now + SESSION_S,
            },
        );
        Ok(id)
    }
}

fn redirect(to: &str) -> Response {
    (StatusCode::SEE_OTHER, [(header::LOCATION, to.to_string())]).into_response()
}

/// `Set-Cookie` for `name=value` on `path` for `max_age_s` (0 clears),
/// `Secure` when the page was reached over HTTPS.
fn set_cookie(name: &str, value: &str, path: &str, max_age_s: i64, secure: bool) -> String {
    format!(
        "{name}={value}; HttpOnly; SameSite=Strict; Path={path}; Max-Age={max_age_s}{}",
        if secure { "; Secure" } else { "" }
    )
}

fn over_https(headers: &HeaderMap) -> bool {
    headers
        .get(header::ORIGIN)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|o| o.starts_with("https://"))
}

/// A urlencoded form body (at most [`FORM_MAX_BYTES`]), its fields in order.
async fn form_pairs(req: Request) -> Result<Vec<(String, String)>, ApiError> {
    let bytes = axum::body::to_bytes(req.into_body(), FORM_MAX_BYTES)
        .await
        .map_err(|_| ApiError::new(StatusCode::BAD_REQUEST, "the form is too large"))?;
    serde_urlencoded::from_bytes::<Vec<(String, String)>>(&bytes)
        .map_err(|_| ApiError::new(StatusCode::BAD_REQUEST, "the form could not be read"))
}

/// A urlencoded form body as a map (the last of repeated names).
async fn form(req: Request) -> Result<HashMap<String, String>, ApiError> {
    Ok(form_pairs(req).await?.into_iter().collect())
}

fn csrf_refused() -> ApiError {
    ApiError::new(
        StatusCode::FORBIDDEN,
        "this form was not sent from this site's own page, or the page is out of date \
         (its security token is missing or wrong). Open the page again and resend the form.",
    )
}

fn origin_refused() -> ApiError {
    ApiError::new(
        StatusCode::FORBIDDEN,
        "this form was sent from another site (its Origin is not this server); it was refused.",
    )
}

fn rules(state: &AppState) -> Value {
    let s = state.settings();
    serde_json::json!({
        "quota": s.quota,
        "requests_per_minute": s.requests_per_minute,
        "max_upload": cap_text(s.max_upload_bytes),
        "max_upload_bytes": s.max_upload_bytes,
        "format_failure_cap": s.format_failure_cap,
        "holdout": s.holdout,
    })
}

// ---- handlers ---------------------------------------------------------

async fn stylesheet() -> Response {
    (
        [
            (header::CONTENT_TYPE, "text/css; charset=utf-8"),
            (header::CACHE_CONTROL, "public, max-age=3600"),
        ],
        STYLE_CSS,
    )
        .into_response()
}

/// `GET /data/` (and `/data`): for a browser ([`wants_html`]) the data
/// page — every public file with its size and SHA-256, the archive
/// (`/data.tar`) and a command that downloads and checks it; for anyone
/// else the JSON listing ([`crate::data::listing`]).
pub(crate) async fn data_index(
    State(state): State<AppState>,
    Extension(web): Shared,
    headers: HeaderMap,
) -> Response {
    if !wants_html(&headers) {
        return match crate::data::listing(State(state)).await {
            Ok(r) => r,
            Err(e) => e.into_response(),
        };
    }
    let nav = web.nav(&state, &headers, "data").await;
    let public = crate::data::public_dir(&state.settings().truth_dir);
    let listed = tokio::task::spawn_blocking(move || crate::data::public_files(&public)).await;
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
    let archive = crate::data::archive_len(&files);
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
            "sums": crate::data::SUMS_FILE,
            "dir": crate::data::ARCHIVE_DIR,
            "command": format!(
                "curl -fsS {scheme}://{host}/data.tar | tar -xf - && (cd {} && sha256sum -c {})",
                crate::data::ARCHIVE_DIR,
                crate::data::SUMS_FILE
            ),
        }),
    )
}

async fn index(
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

async fn signin_page(
    State(state): State<AppState>,
    Extension(web): Shared,
    headers: HeaderMap,
) -> Response {
    let nav = web.nav(&state, &headers, "signin").await;
    signin_form(&web, &nav, StatusCode::OK, None)
}

/// The sign-in form with a fresh double-submit CSRF token.
fn signin_form(web: &Web, nav: &Nav, status: StatusCode, error: Option<&str>) -> Response {
    let token = match random_hex() {
        Ok(t) => t,
        Err(e) => return web.error(nav, &e),
    };
    let mut resp = web.render(
        status,
        "signin.html",
        serde_json::json!({"nav": nav, "csrf": token, "error": error}),
    );
    if let Ok(v) = HeaderValue::from_str(&set_cookie(SIGNIN_COOKIE, &token, "/signin", 3600, false))
    {
        resp.headers_mut().insert(header::SET_COOKIE, v);
    }
    resp
}

async fn signin(State(state): State<AppState>, Extension(web): Shared, req: Request) -> Response {
    let headers = req.headers().clone();
    let nav = web.nav(&state, &headers, "signin").await;
    let fields = match signin_fields(&web, &nav, &headers, req, SIGNIN_COOKIE).await {
        Ok(f) => f,
        Err(page) => return page,
    };
    let token = fields.get("token").map(|t| t.trim()).unwrap_or("");
    let hash = token_hash(token);
    let team = match state.store().team_by_token(&hash).await {
        Ok(t) => t,
        Err(e) => return web.error(&nav, &ApiError::internal(e)),
    };
    if token.is_empty() || team.is_none() {
        return signin_form(
            &web,
            &nav,
            StatusCode::UNAUTHORIZED,
            Some("this token is not valid (mistyped, revoked or replaced): ask the organisers"),
        );
    }
    signed_in(&web, &nav, &headers, &hash, false)
}

/// The checks of a sign-in form (same origin, the double-submit token of
/// its cookie `signin_cookie`) and its fields; the refusal page otherwise.
async fn signin_fields(
    web: &Web,
    nav: &Nav,
    headers: &HeaderMap,
    req: Request,
    signin_cookie: &str,
) -> Result<HashMap<String, String>, Response> {
    if !same_origin(headers) {
        return Err(web.error(nav, &origin_refused()));
    }
    let fields = form(req).await.map_err(|e| web.error(nav, &e))?;
    let sent = fields.get("csrf").map(String::as_str).unwrap_or("");
    let kept = cookie(headers, signin_cookie).unwrap_or_default();
    if sent.is_empty() || !same_secret(sent, &kept) {
        return Err(web.error(nav, &csrf_refused()));
    }
    Ok(fields)
}

/// A new session (a team's, or the organisers' when `organiser`): its
/// cookie set, the sign-in form's cookie cleared, and a redirect to the
/// page it opens.
fn signed_in(
    web: &Web,
    nav: &Nav,
    headers: &HeaderMap,
    token_sha256: &str,
    organiser: bool,
) -> Response {
    let (to, signin_cookie, signin_path) = if organiser {
        ("/organisers", ORGANISER_SIGNIN_COOKIE, "/organisers")
    } else {
        ("/entries", SIGNIN_COOKIE, "/signin")
    };
    let id = match web.start_session(token_sha256, organiser) {
        Ok(id) => id,
        Err(e) => return web.error(nav, &e),
    };
    let secure = over_https(headers);
    let mut resp = redirect(to);
    for c in [
        set_cookie(SESSION_COOKIE, &id, "/", SESSION_S, secure),
        set_cookie(signin_cookie, "", signin_path, 0, secure),
    ] {
        if let Ok(v) = HeaderValue::from_str(&c) {
            resp.headers_mut().append(header::SET_COOKIE, v);
        }
    }
    resp
}

/// The organisers' page: with an organiser session, every team and entry
/// (statuses, rounded public feedback, final choices; no truth); without,
/// the password form.
async fn organisers_page(
    State(state): State<AppState>,
    Extension(web): Shared,
    headers: HeaderMap,
) -> Response {
    let session = web.session(&state, &headers).await;
    let nav = web.nav(&state, &headers, "organisers").await;
    match session {
        Some((s, None)) if s.organiser => organisers_list(&state, &web, &nav).await,
        _ => organisers_form(&web, &nav, StatusCode::OK, None),
    }
}

fn organisers_form(web: &Web, nav: &Nav, status: StatusCode, error: Option<&str>) -> Response {
    let token = match random_hex() {
        Ok(t) => t,
        Err(e) => return web.error(nav, &e),
    };
    let mut resp = web.render(
        status,
        "organisers.html",
        serde_json::json!({"nav": nav, "signed_in": false, "csrf": token, "error": error}),
    );
    let c = set_cookie(ORGANISER_SIGNIN_COOKIE, &token, "/organisers", 3600, false);
    if let Ok(v) = HeaderValue::from_str(&c) {
        resp.headers_mut().insert(header::SET_COOKIE, v);
    }
    resp
}

/// `GET /metrics`: the server's counters in the Prometheus text format
/// ([`crate::observe::Metrics::render`]), for the organisers (the token of
/// a team marked `organisers`, or the organisers' signed-in session), or
/// for anyone under `serve --open-metrics`; 401 otherwise.
async fn metrics(
    State(state): State<AppState>,
    Extension(web): Shared,
    headers: HeaderMap,
) -> Response {
    let session = matches!(web.session(&state, &headers).await, Some((s, None)) if s.organiser);
    let bearer = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| crate::api::bearer_token(v.as_bytes()));
    let token = match bearer {
        Some(t) => state
            .team_of_token(t)
            .await
            .ok()
            .flatten()
            .is_some_and(|t| t.role == Role::Organisers),
        None => false,
    };
    if !(state.open_metrics() || session || token) {
        return ApiError::new(
            StatusCode::UNAUTHORIZED,
            "the metrics are the organisers': send the token of a team marked `organisers`, \
             or sign in on /organisers",
        )
        .into_response();
    }
    let counts = state.store().queue_counts().await;
    match counts {
        Ok(c) => (
            [(
                header::CONTENT_TYPE,
                "text/plain; version=0.0.4; charset=utf-8",
            )],
            state.metrics().render(c, state.live_workers()),
        )
            .into_response(),
        Err(e) => ApiError::internal(e).into_response(),
    }
}

/// How many refused uploads the organisers' page lists at most.
const ORGANISER_REFUSALS_SHOWN: usize = 200;

async fn organisers_list(state: &AppState, web: &Web, nav: &Nav) -> Response {
    // The newest refusals only, and the per-team counts from the
    // database: a crowd of teams each at its daily cap must not make this
    // page read every refusal while it holds the store.
    let (teams, subs, counts, failures, per_team) = {
        let store = state.store();
        match (
            store.teams().await,
            store.all_submissions().await,
            store.queue_counts().await,
            store.format_failures(None, ORGANISER_REFUSALS_SHOWN).await,
            store.format_failure_counts().await,
        ) {
            (Ok(t), Ok(s), Ok(c), Ok(f), Ok(n)) => (t, s, c, f, n),
            (Err(e), ..)
            | (_, Err(e), ..)
            | (_, _, Err(e), ..)
            | (.., Err(e), _)
            | (.., Err(e)) => {
                return web.error(nav, &ApiError::internal(e));
            }
        }
    };
    let refused_uploads = |team_id: i64| {
        per_team
            .iter()
            .find(|(t, _)| *t == team_id)
            .map_or(0, |(_, n)| *n as usize)
    };
    let team_name = |id: i64| {
        teams
            .iter()
            .find(|t| t.id == id)
            .map_or("", |t| t.name.as_str())
    };
    let mut team_rows = Vec::new();
    let mut counted: Vec<i64> = Vec::new();
    for t in &teams {
        let own: Vec<&crate::store::Submission> =
            subs.iter().filter(|s| s.team_id == t.id).collect();
        let finals: Vec<i64> = crate::challenge::final_entries_or_default(&own)
            .iter()
            .map(|s| s.id)
            .collect();
        counted.extend(&finals);
        let chosen = own.iter().any(|s| s.final_choice);
        team_rows.push(serde_json::json!({
            "name": t.name,
            "role": t.role.name(),
            "revoked": t.revoked,
            "entries": own.len(),
            "scored": own.iter().filter(|s| s.has_score()).count(),
            "refused": own.iter().filter(|s| s.status == "refused").count()
                + refused_uploads(t.id),
            "finals": if finals.is_empty() {
                "—".to_string()
            } else {
                let ids: Vec<String> = finals.iter().map(i64::to_string).collect();
                format!("{}{}", ids.join(", "), if chosen { "" } else { " (default)" })
            },
        }));
    }
    let mut entries: Vec<Value> = subs
        .iter()
        .rev()
        .map(|s| {
            let mut v = serde_json::to_value(EntryView {
                counted: counted.contains(&s.id),
                ..entry_view(s, false)
            })
            .unwrap_or(Value::Null);
            v["team"] = serde_json::json!(team_name(s.team_id));
            v["final"] = serde_json::json!(counted.contains(&s.id));
            v
        })
        .collect();
    entries.truncate(1000);
    let refusals: Vec<Value> = failures
        .iter()
        .map(|f| {
            serde_json::json!({
                "created": crate::utc_text(f.created_s),
                "team": team_name(f.team_id),
                "error": f.error,
            })
        })
        .collect();
    let queue = serde_json::json!({
        "queued": counts.queued,
        "scoring": counts.scoring,
        "scored": counts.scored,
        "refused": counts.refused,
        "format_refusals": counts.format_refusals,
        "workers": state.live_workers(),
    });
    web.render(
        StatusCode::OK,
        "organisers.html",
        serde_json::json!({
            "nav": nav, "signed_in": true, "teams": team_rows, "entries": entries,
            "queue": queue, "refusals": refusals,
            "refusals_shown": ORGANISER_REFUSALS_SHOWN,
        }),
    )
}

/// `POST /organisers/signin`: the organiser password (its Argon2id hash,
/// [`crate::challenge::verify_organiser_password`]) → an organiser session.
async fn organisers_signin(
    State(state): State<AppState>,
    Extension(web): Shared,
    req: Request,
) -> Response {
    let headers = req.headers().clone();
    let nav = web.nav(&state, &headers, "organisers").await;
    let fields = match signin_fields(&web, &nav, &headers, req, ORGANISER_SIGNIN_COOKIE).await {
        Ok(f) => f,
        Err(page) => return page,
    };
    let password = fields.get("password").map(String::as_str).unwrap_or("");
    // The stored hash is read under the store's lock; the slow Argon2
    // check runs without it, off the async threads.
    let phc = state
        .store()
        .meta(crate::challenge::ORGANISER_PASSWORD_KEY)
        .await
        .ok()
        .flatten();
    let ok = match (password.is_empty(), phc) {
        (false, Some(phc)) => {
            let password = password.to_owned();
            tokio::task::spawn_blocking(move || crate::challenge::verify_phc(&phc, &password))
                .await
                .unwrap_or(false)
        }
        _ => false,
    };
    if !ok {
        return organisers_form(
            &web,
            &nav,
            StatusCode::UNAUTHORIZED,
            Some(
                "this is not the organiser password (or none is set: `stepsim challenge organiser-password`)",
            ),
        );
    }
    signed_in(&web, &nav, &headers, "", true)
}

async fn signout(State(state): State<AppState>, Extension(web): Shared, req: Request) -> Response {
    let headers = req.headers().clone();
    let nav = web.nav(&state, &headers, "signout").await;
    if !same_origin(&headers) {
        return web.error(&nav, &origin_refused());
    }
    let Some((session, _)) = web.session(&state, &headers).await else {
        return redirect("/");
    };
    let fields = match form(req).await {
        Ok(f) => f,
        Err(e) => return web.error(&nav, &e),
    };
    if !same_secret(
        fields.get("csrf").map(String::as_str).unwrap_or(""),
        &session.csrf,
    ) {
        return web.error(&nav, &csrf_refused());
    }
    if let Some(id) = cookie(&headers, SESSION_COOKIE) {
        web.sessions
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .remove(&token_hash(&id));
    }
    let mut resp = redirect("/");
    if let Ok(v) = HeaderValue::from_str(&set_cookie(SESSION_COOKIE, "", "/", 0, false)) {
        resp.headers_mut().insert(header::SET_COOKIE, v);
    }
    resp
}

/// An entry as its team's page shows it.
#[derive(Debug, Serialize)]
struct EntryView {
    id: i64,
    status: String,
    created: String,
    bytes: String,
    bytes_exact: i64,
    sha256: String,
    sha_prefix: String,
    error: Option<String>,
    m_mean: String,
    sigma_c: String,
    q_c: String,
    pct_stars: String,
    pct_false: String,
    report: bool,
    /// It has a score to show (scored, or queued again for a re-score).
    scored: bool,
    /// It counts at reveal (chosen, or the default best public entry).
    counted: bool,
    /// The team chose it.
    chosen: bool,
}

fn entry_view(s: &crate::store::Submission, revealed: bool) -> EntryView {
    let public: Value = s
        .public_json
        .as_deref()
        .and_then(|t| serde_json::from_str(t).ok())
        .unwrap_or(Value::Null);
    let n = |k: &str| public.get(k).and_then(Value::as_f64);
    EntryView {
        id: s.id,
        status: s.status.clone(),
        created: when(s.created_s),
        bytes: size_text(s.bytes),
        bytes_exact: s.bytes,
        sha256: s.sha256.clone(),
        sha_prefix: s.sha256.chars().take(12).collect(),
        error: s.error.as_deref().map(crate::worker::server_wording),
        m_mean: signed(n("m_mean"), 3),
        sigma_c: fixed(n("sigma_c"), 4),
        q_c: fixed(n("q_c"), 0),
        pct_stars: fixed(n("pct_stars"), 1),
        pct_false: fixed(n("pct_false"), 1),
        report: revealed && s.has_score(),
        scored: s.has_score(),
        counted: false,
        chosen: s.final_choice,
    }
}

/// A note above the entries (the last upload's outcome).
#[derive(Debug, Serialize)]
struct Notice {
    ok: bool,
    text: String,
}

async fn entries_response(
    state: &AppState,
    web: &Web,
    nav: &Nav,
    team: &Team,
    status: StatusCode,
    notice: Option<Notice>,
) -> Response {
    let result = async {
        let revealed = crate::api::revealed(state).await?;
        let subs = state
            .store()
            .submissions_of(team.id)
            .await
            .map_err(ApiError::internal)?;
        let quota = crate::api::quota_status(state, team.id).await?;
        let page_time = |v: &Value| {
            v.as_str()
                .filter(|t| t.len() >= 16)
                .map(|t| format!("{} {} UTC", &t[..10], &t[11..16]))
        };
        let reset = page_time(&quota["reset"]);
        let refused = crate::api::refusal_status(state, team.id).await?;
        let refusals: Vec<Value> = refused["recent"]
            .as_array()
            .into_iter()
            .flatten()
            .map(|f| serde_json::json!({"created": page_time(&f["created"]), "error": f["error"]}))
            .collect();
        let refs: Vec<&crate::store::Submission> = subs.iter().collect();
        let counted: Vec<i64> = crate::challenge::final_entries_or_default(&refs)
            .iter()
            .map(|s| s.id)
            .collect();
        let entries: Vec<EntryView> = subs
            .iter()
            .map(|s| EntryView {
                counted: counted.contains(&s.id),
                ..entry_view(s, revealed)
            })
            .collect();
        let phase = crate::challenge::Phase::read(state.store())
            .await
            .map_err(ApiError::internal)?;
        Ok(serde_json::json!({
            "nav": nav,
            "team": team.name,
            "entries": entries,
            "quota": {"used": quota["used"], "limit": quota["limit"], "reset": reset},
            "refused": {
                "used": refused["used"],
                "limit": refused["limit"],
                "reset": page_time(&refused["reset"]),
                "recent": refusals,
                "shown": crate::api::REFUSALS_SHOWN,
            },
            "rules": rules(state),
            "revealed": revealed,
            "notice": notice,
            "pending": subs.iter().any(|s| s.status == "queued" || s.status == "scoring"),
            "final": {
                "chosen": subs.iter().any(|s| s.final_choice),
                "counted": counted,
                "max": crate::challenge::MAX_FINAL_ENTRIES,
                "open": !phase.closed,
            },
            "uploads_open": phase.uploads_open(crate::now_s()),
            "upload_refusal": phase.upload_refusal(crate::now_s()),
        }))
    }
    .await;
    let result: Result<Value, ApiError> = result;
    match result {
        Ok(ctx) => web.render(status, "entries.html", ctx),
        Err(e) => web.error(nav, &e),
    }
}

async fn entries_page(
    State(state): State<AppState>,
    Extension(web): Shared,
    headers: HeaderMap,
    uri: axum::http::Uri,
) -> Response {
    let Some((session, team)) = web.team_session(&state, &headers).await else {
        return redirect("/signin");
    };
    let nav = Nav::new(&state, Some(&session), Some(&team), "entries").await;
    let query: HashMap<String, String> = uri
        .query()
        .and_then(|q| serde_urlencoded::from_str::<Vec<(String, String)>>(q).ok())
        .map(|v| v.into_iter().collect())
        .unwrap_or_default();
    let chosen = query.get("final").map(|ids| Notice {
        ok: true,
        text: if ids.is_empty() {
            "No final entry chosen: your best public entry counts at reveal.".into()
        } else {
            format!("Final entries saved: {ids}.")
        },
    });
    let notice = query
        .get("uploaded")
        .and_then(|id| id.parse::<i64>().ok())
        .map(|id| Notice {
            ok: true,
            text: if query.contains_key("duplicate") {
                format!("You uploaded these bytes before: entry {id}; nothing was counted.")
            } else {
                format!(
                    "Entry {id} passed the format check and is queued for scoring; \
                     this page shows its status."
                )
            },
        });
    entries_response(&state, &web, &nav, &team, StatusCode::OK, notice.or(chosen)).await
}

/// The signed-in team of a form POST, with its page context, once the
/// request passed the same-origin check; the refusal page otherwise
/// (`what` names the action in the sign-in message).
async fn posting_team(
    web: &Web,
    state: &AppState,
    headers: &HeaderMap,
    what: &str,
) -> Result<(Session, Team, Nav), Box<Response>> {
    let Some((session, team)) = web.team_session(state, headers).await else {
        let nav = web.nav(state, headers, "entries").await;
        return Err(Box::new(web.message(
            &nav,
            StatusCode::FORBIDDEN,
            "Sign in first",
            &format!("{what} needs a signed-in team: sign in with your team's token."),
        )));
    };
    let nav = Nav::new(state, Some(&session), Some(&team), "entries").await;
    if !same_origin(headers) {
        return Err(Box::new(web.error(&nav, &origin_refused())));
    }
    Ok((session, team, nav))
}

/// The final-entries form (`POST /entries/final`, checkboxes `final`):
/// [`crate::challenge::choose_final_entries`], the path of `PUT /api/final`.
async fn choose_final(
    State(state): State<AppState>,
    Extension(web): Shared,
    req: Request,
) -> Response {
    let headers = req.headers().clone();
    let (session, team, nav) =
        match posting_team(&web, &state, &headers, "choosing final entries").await {
            Ok(t) => t,
            Err(page) => return *page,
        };
    let fields = match form_pairs(req).await {
        Ok(f) => f,
        Err(e) => return web.error(&nav, &e),
    };
    let sent = fields
        .iter()
        .find(|(k, _)| k == "csrf")
        .map_or("", |(_, v)| v.as_str());
    if !same_secret(sent, &session.csrf) {
        return web.error(&nav, &csrf_refused());
    }
    let ids: Vec<i64> = fields
        .iter()
        .filter(|(k, _)| k == "final")
        .filter_map(|(_, v)| v.parse().ok())
        .collect();
    let result = crate::challenge::choose_final_entries(state.store(), team.id, &ids).await;
    use crate::challenge::ChoiceError;
    let e = match result {
        Ok(ids) => {
            let list: Vec<String> = ids.iter().map(i64::to_string).collect();
            return redirect(&format!("/entries?final={}", list.join(",")));
        }
        Err(ChoiceError::Store(e)) => ApiError::internal(e),
        Err(ChoiceError::NotFound(_)) => ApiError::not_found(),
        Err(e @ ChoiceError::Closed) => ApiError::new(StatusCode::FORBIDDEN, e.to_string()),
        Err(e) => ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, e.to_string()),
    };
    entries_response(
        &state,
        &web,
        &nav,
        &team,
        e.status,
        Some(Notice {
            ok: false,
            text: e.message,
        }),
    )
    .await
}

/// The upload form: [`crate::api::submit`], the path of `POST
/// /api/submissions`, with the session's CSRF token checked before the
/// file is kept.
async fn upload(State(state): State<AppState>, Extension(web): Shared, req: Request) -> Response {
    let headers = req.headers().clone();
    let (session, team, nav) =
        match posting_team(&web, &state, &headers, "uploading from the page").await {
            Ok(t) => t,
            Err(page) => return *page,
        };
    let expected = session.csrf.clone();
    let check = move |fields: &crate::api::FormFields| {
        let sent = fields
            .iter()
            .find(|(k, _)| k == "csrf")
            .map_or("", |(_, v)| v.as_str());
        if same_secret(sent, &expected) {
            Ok(())
        } else {
            Err(csrf_refused())
        }
    };
    match crate::api::submit(&state, &team, req, check).await {
        Ok(a) if a.duplicate => redirect(&format!("/entries?uploaded={}&duplicate=1", a.id)),
        Ok(a) => redirect(&format!("/entries?uploaded={}", a.id)),
        Err(e) if e.status == StatusCode::FORBIDDEN => web.error(&nav, &e),
        Err(e) => {
            let mut text = e.message.clone();
            if let Some(t) = e.reset_s {
                text = format!("{text} (resets {})", when(t));
            }
            entries_response(
                &state,
                &web,
                &nav,
                &team,
                e.status,
                Some(Notice { ok: false, text }),
            )
            .await
        }
    }
}

/// A leaderboard row for the page.
#[derive(Debug, Serialize)]
struct BoardRow {
    /// `None` for the organisers' and the baseline's rows (never ranked).
    rank: Option<i64>,
    team: String,
    role: String,
    /// After reveal: the team's final entries (those that counted).
    finals: String,
    entries: i64,
    entry: i64,
    m_mean: String,
    sigma_c: String,
    q_c: String,
    h_m_mean: String,
    h_sigma_c: String,
    h_q_c: String,
    /// After reveal: the held-out Q_c's 95 % interval (`lo–hi`).
    h_q_c_ci: String,
    /// After reveal: its interval overlaps the row above's.
    tied_above: bool,
}

/// The leaderboard rows (as the API ranks them) and whether revealed.
async fn board(state: &AppState) -> Result<(bool, Vec<Value>), ApiError> {
    let revealed = crate::api::revealed(state).await?;
    let (teams, subs) = {
        let store = state.store();
        (
            store.teams().await.map_err(ApiError::internal)?,
            store.all_submissions().await.map_err(ApiError::internal)?,
        )
    };
    Ok((
        revealed,
        crate::api::leaderboard_rows(&teams, &subs, revealed),
    ))
}

async fn leaderboard_page(
    State(state): State<AppState>,
    Extension(web): Shared,
    headers: HeaderMap,
) -> Response {
    let nav = web.nav(&state, &headers, "leaderboard").await;
    let (revealed, rows) = match board(&state).await {
        Ok(b) => b,
        Err(e) => return web.error(&nav, &e),
    };
    let rows: Vec<BoardRow> = rows
        .iter()
        .map(|r| {
            let n = |part: &str, k: &str| r[part].get(k).and_then(Value::as_f64);
            BoardRow {
                rank: r["rank"].as_i64(),
                team: r["team"].as_str().unwrap_or("").to_string(),
                role: r["role"].as_str().unwrap_or("participant").to_string(),
                finals: r["finals"]
                    .as_array()
                    .map(|a| {
                        a.iter()
                            .filter_map(Value::as_i64)
                            .map(|i| i.to_string())
                            .collect::<Vec<_>>()
                            .join(", ")
                    })
                    .unwrap_or_default(),
                entries: r["entries"].as_i64().unwrap_or(0),
                entry: r["entry"].as_i64().unwrap_or(0),
                m_mean: signed(n("public", "m_mean"), 3),
                sigma_c: fixed(n("public", "sigma_c"), 4),
                q_c: fixed(n("public", "q_c"), 0),
                h_m_mean: signed(n("holdout", "m_mean"), 4),
                h_sigma_c: fixed(n("holdout", "sigma_c"), 5),
                h_q_c: fixed(n("holdout", "q_c"), 1),
                h_q_c_ci: crate::api::q_c_interval(&r["holdout"])
                    .and_then(|ci| interval_ends(ci, 1, fixed))
                    .map(|(lo, hi)| format!("{lo}–{hi}"))
                    .unwrap_or_else(|| "—".to_owned()),
                tied_above: r["tied_above"].as_bool().unwrap_or(false),
            }
        })
        .collect();
    web.render(
        StatusCode::OK,
        "leaderboard.html",
        serde_json::json!({"nav": nav, "rows": rows, "revealed": revealed,
                           "holdout": state.settings().holdout}),
    )
}

/// The entry whose report or figures a request may see: after reveal, a
/// scored entry that is on the final board, or one of the signed-in
/// team's own. Anything else is "not found", as for no entry at all.
async fn visible_entry(
    state: &AppState,
    web: &Web,
    headers: &HeaderMap,
    id: &str,
) -> Result<crate::store::Submission, ApiError> {
    let id: i64 = id.parse().map_err(|_| ApiError::not_found())?;
    let (revealed, rows) = board(state).await?;
    if !revealed {
        return Err(ApiError::not_found());
    }
    let sub = state
        .store()
        .submission(id)
        .await
        .map_err(ApiError::internal)?
        .filter(|s| s.has_score())
        .ok_or_else(ApiError::not_found)?;
    let ranked = rows.iter().any(|r| r["entry"].as_i64() == Some(id));
    let own = web
        .team_session(state, headers)
        .await
        .is_some_and(|(_, t)| t.id == sub.team_id);
    if ranked || own {
        Ok(sub)
    } else {
        Err(ApiError::not_found())
    }
}

/// Why the signed-in team's own entry `id` has no report to show (before
/// reveal: when it opens), or `None` when it is not the team's entry: for
/// another team's entry the answer stays the "not found" of an entry that
/// does not exist.
async fn own_entry_without_report(
    state: &AppState,
    web: &Web,
    headers: &HeaderMap,
    id: &str,
) -> Option<String> {
    let id: i64 = id.parse().ok()?;
    let (_, team) = web.team_session(state, headers).await?;
    let sub = state
        .store()
        .submission(id)
        .await
        .ok()
        .flatten()
        .filter(|s| s.team_id == team.id)?;
    let revealed = crate::api::revealed(state).await.ok()?;
    Some(if !revealed {
        format!(
            "The full report of entry {id} (both parts: the summary with its intervals, the fits \
             per PSF, the per-dataset table and the figures) opens at reveal, when the organisers \
             open the held-out scores after the challenge closes. Until then \"Our entries\" \
             shows its rounded public feedback."
        )
    } else {
        format!(
            "Entry {id} has no report: it is {} (only a scored entry has one).",
            sub.status
        )
    })
}

/// The parts whose reports an entry has: `(url name, title, ranked)`.
const PARTS: [(&str, &str); 2] = [
    ("holdout", "Held-out part (ranked at reveal)"),
    ("public", "Public part"),
];

async fn report_page(
    State(state): State<AppState>,
    Extension(web): Shared,
    headers: HeaderMap,
    UrlPath(id): UrlPath<String>,
) -> Response {
    let nav = web.nav(&state, &headers, "report").await;
    let sub = match visible_entry(&state, &web, &headers, &id).await {
        Ok(s) => s,
        Err(e) => {
            return match own_entry_without_report(&state, &web, &headers, &id).await {
                Some(text) => web.message(&nav, e.status, "Report not open", &text),
                None => web.error(&nav, &e),
            };
        }
    };
    let team = state
        .store()
        .teams()
        .await
        .ok()
        .and_then(|ts| ts.into_iter().find(|t| t.id == sub.team_id))
        .map(|t| t.name)
        .unwrap_or_default();
    let mut parts = Vec::new();
    for (name, title) in PARTS {
        let dir = state
            .dir()
            .join("entries")
            .join(sub.id.to_string())
            .join(name);
        let Ok(text) = std::fs::read_to_string(dir.join(REPORT_JSON)) else {
            continue;
        };
        let report: stepsim_harness::report::Report = match serde_json::from_str(&text) {
            Ok(r) => r,
            Err(e) => {
                return web.error(
                    &nav,
                    &ApiError::internal(format!("{}: {e}", dir.join(REPORT_JSON).display())),
                );
            }
        };
        let figures: Vec<Value> = REPORT_FIGURES
            .iter()
            .filter(|f| dir.join(format!("{f}.png")).is_file())
            .map(|f| serde_json::json!({"file": format!("{f}.png"), "caption": figure_caption(f)}))
            .collect();
        parts.push(serde_json::json!({
            "name": name,
            "title": title,
            "tables": report::tables(&report),
            "figures": figures,
        }));
    }
    web.render(
        StatusCode::OK,
        "report.html",
        serde_json::json!({"nav": nav, "id": sub.id, "team": team,
                           "created": when(sub.created_s), "parts": parts}),
    )
}

fn figure_caption(name: &str) -> &'static str {
    match name {
        "fig2_shear_response" => {
            "Shear response: measured minus true shear against true shear, per PSF"
        }
        "fig3_m_sigma_c" => "⟨m⟩ against σc: one point, this entry (the shaded band: |⟨m⟩| < 7 %)",
        "fig4_mselc_muncontaminated" => "Selection bias against the uncontaminated m",
        "fig5_residual_magnitude" => "Shear residual against true magnitude",
        _ => "",
    }
}

/// One of the report's PNG figures, after reveal, for a visible entry,
/// only the named plot files, only when the file exists.
async fn figure(
    State(state): State<AppState>,
    Extension(web): Shared,
    headers: HeaderMap,
    UrlPath((id, part, file)): UrlPath<(String, String, String)>,
) -> Response {
    let nav = web.nav(&state, &headers, "report").await;
    let not_found = || web.error(&nav, &ApiError::not_found());
    let sub = match visible_entry(&state, &web, &headers, &id).await {
        Ok(s) => s,
        Err(e) => return web.error(&nav, &e),
    };
    let Some((part, _)) = PARTS.iter().find(|(p, _)| *p == part) else {
        return not_found();
    };
    if !REPORT_FIGURES.iter().any(|f| format!("{f}.png") == file) {
        return not_found();
    }
    let path = state
        .dir()
        .join("entries")
        .join(sub.id.to_string())
        .join(part)
        .join(&file);
    match tokio::fs::read(&path).await {
        Ok(bytes) => ([(header::CONTENT_TYPE, "image/png")], Body::from(bytes)).into_response(),
        Err(_) => not_found(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_templates_compile() {
        let env = templates().unwrap();
        for (name, _) in TEMPLATES {
            assert!(env.get_template(name).is_ok(), "{name}");
        }
    }

    #[test]
    fn numbers_read_well() {
        assert_eq!(fixed(Some(-0.01234), 3), "−0.012");
        assert_eq!(fixed(Some(-0.0001), 3), "0.000");
        assert_eq!(fixed(None, 3), "—");
        assert_eq!(fixed(Some(f64::NAN), 3), "—");
        assert_eq!(signed(Some(0.0123), 3), "+0.012");
        assert_eq!(signed(Some(0.00001), 3), "0.000");
        assert_eq!(size_text(999), "999 B");
        assert_eq!(size_text(12_345), "12.3 kB");
        assert_eq!(cap_text(256 << 20), "256 MiB");
        assert_eq!(cap_text(1000), "1000 bytes");
        assert_eq!(when(0), "1970-01-01 00:00 UTC");
    }

    #[test]
    fn browsers_get_pages_and_scripts_json() {
        let accept = |v: &'static str| {
            let mut h = HeaderMap::new();
            h.insert(header::ACCEPT, HeaderValue::from_static(v));
            wants_html(&h)
        };
        // Chromium's and Firefox's Accept for a page.
        assert!(accept(
            "text/html,application/xhtml+xml,application/xml;q=0.9,image/avif,\
             image/webp,image/apng,*/*;q=0.8,application/signed-exchange;v=b3;q=0.7"
        ));
        assert!(accept(
            "text/html,application/xhtml+xml,application/xml;q=0.9,*/*;q=0.8"
        ));
        // curl, scripts, JSON clients; HTML refused or weighed below JSON.
        assert!(!accept("*/*"));
        assert!(!accept("application/json"));
        assert!(!accept("text/html;q=0, */*"));
        assert!(!accept("application/json, text/html;q=0.5"));
        assert!(!wants_html(&HeaderMap::new()));
    }

    #[test]
    fn origins_and_cookies() {
        let mut h = HeaderMap::new();
        h.insert(header::HOST, HeaderValue::from_static("example.org:8080"));
        assert!(same_origin(&h), "no Origin, no Referer: the token decides");
        h.insert(
            header::ORIGIN,
            HeaderValue::from_static("http://example.org:8080"),
        );
        assert!(same_origin(&h));
        h.insert(
            header::ORIGIN,
            HeaderValue::from_static("http://evil.example"),
        );
        assert!(!same_origin(&h));
        h.insert(header::ORIGIN, HeaderValue::from_static("null"));
        assert!(!same_origin(&h));
        h.remove(header::ORIGIN);
        h.insert(
            header::REFERER,
            HeaderValue::from_static("https://example.org:8080/entries"),
        );
        assert!(same_origin(&h));
        h.insert(
            header::REFERER,
            HeaderValue::from_static("https://example.org:8080.evil/x"),
        );
        assert!(!same_origin(&h));
        h.insert(
            header::COOKIE,
            HeaderValue::from_static("a=1; stepsim_session=abc; b=2"),
        );
        assert_eq!(cookie(&h, SESSION_COOKIE).as_deref(), Some("abc"));
        assert_eq!(cookie(&h, "c"), None);
        assert!(same_secret("abc", "abc") && !same_secret("abc", "abd") && !same_secret("a", "ab"));
    }
}
