//! An entry's full report and its figures, after reveal
//! (`/entries/{id}/report`, `/entries/{id}/figures/...`).

use super::{ApiError, AppState, Shared, Web, tables, when};
use crate::challenge::leaderboard;
use axum::body::Body;
use axum::extract::{Extension, Path as UrlPath, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde_json::Value;
use stepsim_harness::{REPORT_FIGURES, REPORT_JSON};

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
    let (revealed, teams, subs) = super::leaderboard::board(state).await?;
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
    let ranked = leaderboard::rows(&teams, &subs, revealed)
        .iter()
        .any(|r| r.entry.id == id);
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
    let revealed = crate::http::revealed(state).await.ok()?;
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

pub(super) async fn report_page(
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
        let report: stepsim_harness::Report = match serde_json::from_str(&text) {
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
            "tables": tables::tables(&report),
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
pub(super) async fn figure(
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
