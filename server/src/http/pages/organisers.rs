//! The organisers' page (`/organisers`, its sign-in) and `/metrics`.

use super::entries::{EntryView, entry_view};
use super::signin::{signed_in, signin_fields};
use super::{
    ApiError, AppState, Nav, ORGANISER_SIGNIN_COOKIE, Shared, Web, random_hex, set_cookie,
};
use crate::store::Role;
use axum::extract::{Extension, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde_json::Value;

/// The organisers' page: with an organiser session, every team and entry
/// (statuses, rounded public feedback, final choices; no truth); without,
/// the password form.
pub(super) async fn organisers_page(
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
pub(super) async fn metrics(
    State(state): State<AppState>,
    Extension(web): Shared,
    headers: HeaderMap,
) -> Response {
    let session = matches!(web.session(&state, &headers).await, Some((s, None)) if s.organiser);
    let bearer = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| crate::http::auth::bearer_token(v.as_bytes()));
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
pub(super) async fn organisers_signin(
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
