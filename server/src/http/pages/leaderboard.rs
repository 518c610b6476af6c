//! The leaderboard page (`/leaderboard`).

use super::{ApiError, AppState, Shared, fixed, interval_ends, signed};
use crate::challenge::figures::HoldoutFigures;
use crate::challenge::leaderboard;
use crate::store::{Submission, Team};
use axum::extract::{Extension, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::Response;
use serde::Serialize;

/// A leaderboard row for the page.
#[derive(Debug, Serialize)]
pub(super) struct BoardRow {
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

/// Whether revealed, the teams and every entry: what the leaderboard is
/// made of ([`leaderboard::rows`]).
pub(super) async fn board(
    state: &AppState,
) -> Result<(bool, Vec<Team>, Vec<Submission>), ApiError> {
    let revealed = crate::http::revealed(state).await?;
    let store = state.store();
    Ok((
        revealed,
        store.teams().await.map_err(ApiError::internal)?,
        store.all_submissions().await.map_err(ApiError::internal)?,
    ))
}

pub(super) async fn leaderboard_page(
    State(state): State<AppState>,
    Extension(web): Shared,
    headers: HeaderMap,
) -> Response {
    let nav = web.nav(&state, &headers, "leaderboard").await;
    let (revealed, teams, subs) = match board(&state).await {
        Ok(b) => b,
        Err(e) => return web.error(&nav, &e),
    };
    let rows: Vec<BoardRow> = leaderboard::rows(&teams, &subs, revealed)
        .iter()
        .map(|r| {
            let public = r.public.as_ref();
            let holdout = r.holdout();
            BoardRow {
                rank: r.rank.map(|n| n as i64),
                team: r.team.name.clone(),
                role: r.team.role.name().to_string(),
                finals: r
                    .revealed
                    .as_ref()
                    .map(|v| {
                        v.finals
                            .iter()
                            .map(i64::to_string)
                            .collect::<Vec<_>>()
                            .join(", ")
                    })
                    .unwrap_or_default(),
                entries: r.entries as i64,
                entry: r.entry.id,
                m_mean: signed(public.and_then(|p| p.m_mean), 3),
                sigma_c: fixed(public.and_then(|p| p.sigma_c), 4),
                q_c: fixed(public.and_then(|p| p.q_c), 0),
                h_m_mean: signed(holdout.and_then(HoldoutFigures::m_mean), 4),
                h_sigma_c: fixed(holdout.and_then(HoldoutFigures::sigma_c), 5),
                h_q_c: fixed(holdout.and_then(HoldoutFigures::q_c), 1),
                h_q_c_ci: leaderboard::q_c_interval(r)
                    .and_then(|ci| interval_ends(ci, 1, fixed))
                    .map(|(lo, hi)| format!("{lo}–{hi}"))
                    .unwrap_or_else(|| "—".to_owned()),
                tied_above: r.revealed.as_ref().is_some_and(|v| v.tied_above),
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
