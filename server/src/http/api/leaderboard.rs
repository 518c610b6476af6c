//! The leaderboard as JSON (`GET /api/leaderboard`): the rows of
//! [`crate::challenge::leaderboard`], their figures as stored.

use crate::challenge::leaderboard::{self, Row};
use crate::http::{ApiError, ApiResult, AppState, revealed};
use axum::extract::State;
use axum::response::IntoResponse;
use serde_json::{Value, json};

pub(crate) async fn leaderboard(State(state): State<AppState>) -> ApiResult {
    let revealed = revealed(&state).await?;
    let (teams, subs) = {
        let store = state.store();
        (
            store.teams().await.map_err(ApiError::internal)?,
            store.all_submissions().await.map_err(ApiError::internal)?,
        )
    };
    let rows: Vec<Value> = leaderboard::rows(&teams, &subs, revealed)
        .iter()
        .map(Row::json)
        .collect();
    Ok(axum::Json(json!({"revealed": revealed, "rows": rows})).into_response())
}
