//! Signing in with a team token, and signing out (`/signin`,
//! `/signout`).

use super::{
    ApiError, AppState, Nav, ORGANISER_SIGNIN_COOKIE, SESSION_COOKIE, SESSION_S, SIGNIN_COOKIE,
    Shared, Web, cookie, csrf_refused, form, origin_refused, over_https, random_hex, redirect,
    same_origin, same_secret, set_cookie,
};
use crate::challenge::token_hash;
use axum::extract::{Extension, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::Response;
use std::collections::HashMap;

pub(super) async fn signin_page(
    State(state): State<AppState>,
    Extension(web): Shared,
    headers: HeaderMap,
) -> Response {
    let nav = web.nav(&state, &headers, "signin").await;
    signin_form(&web, &nav, StatusCode::OK, None)
}

/// The sign-in form with a fresh double-submit CSRF token.
pub(super) fn signin_form(
    web: &Web,
    nav: &Nav,
    status: StatusCode,
    error: Option<&str>,
) -> Response {
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

pub(super) async fn signin(
    State(state): State<AppState>,
    Extension(web): Shared,
    req: Request,
) -> Response {
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
pub(super) async fn signin_fields(
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
pub(super) fn signed_in(
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

pub(super) async fn signout(
    State(state): State<AppState>,
    Extension(web): Shared,
    req: Request,
) -> Response {
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
