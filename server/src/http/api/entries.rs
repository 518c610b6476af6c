//! A team's own entries (`GET /api/submissions`, `GET
//! /api/submissions/{id}`) and its choice of final entries (`PUT
//! /api/final`).

use crate::challenge::QUOTA_WINDOW_S;
use crate::challenge::admission::{self, QuotaStatus, RefusalStatus};
use crate::challenge::figures::stored_json;
use crate::challenge::{ChoiceError, choose_final_entries, final_entries_or_default};
use crate::http::auth::auth;
use crate::http::{ApiError, ApiResult, AppState, revealed};
use crate::store::Submission;
use axum::extract::{Path as UrlPath, Request, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::IntoResponse;
use serde_json::{Value, json};

/// One entry as its team sees it: `id`, `status`, `created`, `sha256`,
/// `bytes`, `final`, `error` (refused), `public` and `scorer_version`
/// (once scored; a re-scored entry shows its newest score), `holdout`
/// (after reveal).
pub fn entry_json(s: &Submission, revealed: bool) -> Value {
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
        v["public"] = stored_json(s.public_json.as_deref());
        v["scorer_version"] = json!(s.scorer_version);
        if revealed && s.holdout_json.is_some() {
            v["holdout"] = stored_json(s.holdout_json.as_deref());
        }
    }
    v
}

pub(crate) async fn list_submissions(
    State(state): State<AppState>,
    headers: HeaderMap,
) -> ApiResult {
    let team = auth(&state, &headers).await?;
    let revealed = revealed(&state).await?;
    let subs = state
        .store()
        .submissions_of(team.id)
        .await
        .map_err(ApiError::internal)?;
    let quota = quota_json(&quota_status(&state, team.id).await?);
    let refused = refusal_json(&refusal_status(&state, team.id).await?);
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
pub(crate) async fn put_final(State(state): State<AppState>, req: Request) -> ApiResult {
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

pub(crate) async fn get_submission(
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
pub(crate) async fn quota_status(state: &AppState, team_id: i64) -> Result<QuotaStatus, ApiError> {
    admission::quota_status(state.store(), state.settings(), team_id, crate::now_s())
        .await
        .map_err(ApiError::internal)
}

/// A quota as the API sends it: `used`, `limit`, `window_hours` and
/// `reset` (when the oldest use leaves the window, if any).
fn quota_json(q: &QuotaStatus) -> Value {
    let mut v = json!({"used": q.used, "limit": q.limit, "window_hours": 24});
    if let Some(reset) = q.reset_s {
        v["reset"] = json!(crate::utc_text(reset));
    }
    v
}

/// The uploads of a team the format check refused (never entries).
pub(crate) async fn refusal_status(
    state: &AppState,
    team_id: i64,
) -> Result<RefusalStatus, ApiError> {
    admission::refusal_status(state.store(), state.settings(), team_id, crate::now_s())
        .await
        .map_err(ApiError::internal)
}

/// Refused uploads as the API sends them: `used` (in the last 24 hours,
/// counted against `limit`, the refusal cap), `window_hours`, `reset`
/// (when the oldest counted one leaves the window, if any) and `recent`,
/// the newest [`admission::REFUSALS_SHOWN`] with `created` and `error`
/// (the message the team was sent).
fn refusal_json(r: &RefusalStatus) -> Value {
    let recent: Vec<Value> = r
        .recent
        .iter()
        .map(|f| {
            json!({"created": crate::utc_text(f.created_s),
                   "error": crate::worker::server_wording(&f.error)})
        })
        .collect();
    let mut v = json!({
        "used": r.used,
        "limit": r.limit,
        "window_hours": QUOTA_WINDOW_S / 3600,
        "recent": recent,
    });
    if let Some(reset) = r.reset_s {
        v["reset"] = json!(crate::utc_text(reset));
    }
    v
}
