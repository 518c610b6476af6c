//! The challenge's public state (`GET /api/challenge`): its name, phase
//! and rules.

use crate::challenge::{MAX_FINAL_ENTRIES, Phase, QUOTA_WINDOW_S};
use crate::http::{ApiError, ApiResult, AppState};
use axum::extract::State;
use axum::response::IntoResponse;
use serde_json::{Value, json};

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
            "max_final_entries": MAX_FINAL_ENTRIES,
            "feedback_decimals": stepsim_harness::FEEDBACK_DECIMALS
                .iter()
                .map(|(k, d)| (k.to_string(), json!(d)))
                .collect::<serde_json::Map<String, Value>>(),
        },
    }))
}

pub(crate) async fn challenge_state(State(state): State<AppState>) -> ApiResult {
    let v = challenge_json(&state, crate::now_s())
        .await
        .map_err(ApiError::internal)?;
    Ok(axum::Json(v).into_response())
}
