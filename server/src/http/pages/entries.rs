//! The team's entries page (`/entries`): its entries and quota, the upload
//! form and the choice of final entries.

use super::{
    ApiError, AppState, Nav, Session, Shared, Web, csrf_refused, fixed, form_pairs, origin_refused,
    redirect, rules, same_origin, same_secret, signed, size_text, when,
};
use crate::challenge::admission::REFUSALS_SHOWN;
use crate::challenge::figures::public_of_text;
use crate::http::api;
use crate::http::api::upload::FormFields;
use crate::store::Team;
use axum::extract::{Extension, Request, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::Response;
use serde::Serialize;
use serde_json::Value;
use std::collections::HashMap;

/// An entry as its team's page shows it.
#[derive(Debug, Serialize)]
pub(super) struct EntryView {
    pub(super) id: i64,
    pub(super) status: String,
    pub(super) created: String,
    pub(super) bytes: String,
    pub(super) bytes_exact: i64,
    pub(super) sha256: String,
    pub(super) sha_prefix: String,
    pub(super) error: Option<String>,
    pub(super) m_mean: String,
    pub(super) sigma_c: String,
    pub(super) q_c: String,
    pub(super) pct_stars: String,
    pub(super) pct_false: String,
    pub(super) report: bool,
    /// It has a score to show (scored, or queued again for a re-score).
    pub(super) scored: bool,
    /// It counts at reveal (chosen, or the default best public entry).
    pub(super) counted: bool,
    /// The team chose it.
    pub(super) chosen: bool,
}

pub(super) fn entry_view(s: &crate::store::Submission, revealed: bool) -> EntryView {
    let public = public_of_text(s.public_json.as_deref());
    let public = public.as_ref();
    EntryView {
        id: s.id,
        status: s.status.clone(),
        created: when(s.created_s),
        bytes: size_text(s.bytes),
        bytes_exact: s.bytes,
        sha256: s.sha256.clone(),
        sha_prefix: s.sha256.chars().take(12).collect(),
        error: s.error.as_deref().map(crate::worker::server_wording),
        m_mean: signed(public.and_then(|p| p.m_mean), 3),
        sigma_c: fixed(public.and_then(|p| p.sigma_c), 4),
        q_c: fixed(public.and_then(|p| p.q_c), 0),
        pct_stars: fixed(public.and_then(|p| p.pct_stars), 1),
        pct_false: fixed(public.and_then(|p| p.pct_false), 1),
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
        let revealed = crate::http::revealed(state).await?;
        let subs = state
            .store()
            .submissions_of(team.id)
            .await
            .map_err(ApiError::internal)?;
        let quota = api::entries::quota_status(state, team.id).await?;
        let page_time = |t_s: i64| {
            let t = crate::utc_text(t_s);
            (t.len() >= 16).then(|| format!("{} {} UTC", &t[..10], &t[11..16]))
        };
        let refused = api::entries::refusal_status(state, team.id).await?;
        let refusals: Vec<Value> = refused
            .recent
            .iter()
            .map(|f| {
                serde_json::json!({"created": page_time(f.created_s),
                                   "error": crate::worker::server_wording(&f.error)})
            })
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
            "quota": {"used": quota.used, "limit": quota.limit,
                      "reset": quota.reset_s.and_then(page_time)},
            "refused": {
                "used": refused.used,
                "limit": refused.limit,
                "reset": refused.reset_s.and_then(page_time),
                "recent": refusals,
                "shown": REFUSALS_SHOWN,
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

pub(super) async fn entries_page(
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

/// The form's `csrf` field (the first of that name; missing counts as
/// empty) checked against the session's token `expected`: the refusal
/// [`csrf_refused`] when they differ. Both forms of this page post it.
fn check_csrf(fields: &FormFields, expected: &str) -> Result<(), ApiError> {
    let sent = fields
        .iter()
        .find(|(k, _)| k == "csrf")
        .map_or("", |(_, v)| v.as_str());
    if same_secret(sent, expected) {
        Ok(())
    } else {
        Err(csrf_refused())
    }
}

/// The final-entries form (`POST /entries/final`, checkboxes `final`):
/// [`crate::challenge::choose_final_entries`], the path of `PUT /api/final`.
pub(super) async fn choose_final(
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
    if let Err(e) = check_csrf(&fields, &session.csrf) {
        return web.error(&nav, &e);
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

/// The upload form: [`crate::http::api::upload::submit`], the path of `POST
/// /api/submissions`, with the session's CSRF token checked before the
/// file is kept.
pub(super) async fn upload(
    State(state): State<AppState>,
    Extension(web): Shared,
    req: Request,
) -> Response {
    let headers = req.headers().clone();
    let (session, team, nav) =
        match posting_team(&web, &state, &headers, "uploading from the page").await {
            Ok(t) => t,
            Err(page) => return *page,
        };
    let expected = session.csrf.clone();
    let check = move |fields: &FormFields| check_csrf(fields, &expected);
    match crate::http::api::upload::submit(&state, &team, req, check).await {
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
