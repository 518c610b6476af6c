//! The JSON API, by job: a team's entries and its final choice
//! ([`entries`]), uploads ([`upload`]), the leaderboard ([`leaderboard`]),
//! the challenge's public state ([`state`]) and the run's public files
//! ([`data`]).

pub mod data;
pub mod entries;
pub mod leaderboard;
pub mod state;
pub mod upload;

use super::AppState;
use axum::Router;
use axum::routing::{get, put};

/// The routes of the API and of the public files.
pub(crate) fn routes() -> Router<AppState> {
    Router::new()
        .route(
            "/api/submissions",
            get(entries::list_submissions).post(upload::post_submission),
        )
        .route("/api/submissions/{id}", get(entries::get_submission))
        .route("/api/leaderboard", get(leaderboard::leaderboard))
        .route("/api/final", put(entries::put_final))
        .route("/api/challenge", get(state::challenge_state))
        .route("/data", get(super::pages::data::data_index))
        .route("/data/", get(super::pages::data::data_index))
        .route("/data.tar", get(data::archive))
        .route("/data/{*path}", get(data::download))
}
