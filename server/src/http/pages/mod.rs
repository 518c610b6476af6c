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
//! goes through [`crate::http::api::upload`]'s one upload path.
//!
//! Here: what every page shares (templates, sessions, the header, forms
//! and cookies, errors as pages); one module per page below.

pub(crate) mod data;
mod entries;
mod errors;
mod format;
mod home;
mod leaderboard;
mod markdown;
mod organisers;
mod report;
mod signin;
mod tables;

pub(crate) use errors::html_errors;
pub use errors::wants_html;
pub use markdown::{escape, markdown_html};

use format::{cap_text, size_text, when};
pub(crate) use format::{fixed, interval_ends, signed};

use super::{ApiError, AppState};
use crate::challenge::token_hash;
use crate::store::Team;
use axum::Router;
use axum::extract::{Extension, Request};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use minijinja::Environment;
use serde::Serialize;
use serde_json::Value;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use stepsim_contract::digest::hex;

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

const STYLE_CSS: &str = include_str!("../../../templates/style.css");

/// The page templates, compiled into the binary.
const TEMPLATES: [(&str, &str); 9] = [
    ("base.html", include_str!("../../../templates/base.html")),
    ("index.html", include_str!("../../../templates/index.html")),
    ("data.html", include_str!("../../../templates/data.html")),
    (
        "signin.html",
        include_str!("../../../templates/signin.html"),
    ),
    (
        "entries.html",
        include_str!("../../../templates/entries.html"),
    ),
    (
        "leaderboard.html",
        include_str!("../../../templates/leaderboard.html"),
    ),
    (
        "report.html",
        include_str!("../../../templates/report.html"),
    ),
    (
        "message.html",
        include_str!("../../../templates/message.html"),
    ),
    (
        "organisers.html",
        include_str!("../../../templates/organisers.html"),
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

/// The pages' routes, merged into [`crate::http::router`], and what they
/// share: the router puts it in every request's extensions, so that
/// [`html_errors`] and [`data::data_index`] render pages too.
pub(crate) fn pages(state: &AppState) -> (Router<AppState>, Arc<Web>) {
    use tower_http::set_header::SetResponseHeaderLayer as H;
    let readme = state
        .settings()
        .truth_dir
        .parent()
        .map(|run| {
            stepsim_contract::run_dir::RunDir::new(run)
                .public()
                .readme()
        })
        .and_then(|p| std::fs::read_to_string(p).ok())
        .map(|t| markdown_html(&t));
    let web = Arc::new(Web {
        env: templates().map_err(|e| e.to_string()),
        readme_html: readme,
        sessions: Mutex::new(HashMap::new()),
    });
    let router = Router::new()
        .route("/", get(home::index))
        .route("/signin", get(signin::signin_page).post(signin::signin))
        .route("/signout", post(signin::signout))
        .route("/entries", get(entries::entries_page).post(entries::upload))
        .route("/entries/final", post(entries::choose_final))
        .route("/organisers", get(organisers::organisers_page))
        .route("/organisers/signin", post(organisers::organisers_signin))
        .route("/metrics", get(organisers::metrics))
        .route("/leaderboard", get(leaderboard::leaderboard_page))
        .route("/entries/{id}/report", get(report::report_page))
        .route("/entries/{id}/figures/{part}/{file}", get(report::figure))
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

// ---- small helpers ----------------------------------------------------

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
                crate::http::log::note_team(t.id);
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
