//! The outputs of a score: `report.md`, the figures and the leaderboard of
//! many reports. Uses the report types of [`crate::score`] and, for the
//! leaderboard's reports, the bounded reads of [`crate::read`].

pub mod leaderboard;
pub mod markdown;
pub mod plots;
