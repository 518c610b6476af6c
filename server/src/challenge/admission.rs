//! The rules that admit an upload: the phase, the quota of accepted
//! entries and the cap on refused uploads, each over the last
//! [`QUOTA_WINDOW_S`]; and what a team is shown of where it stands.
//! Pure functions of the settings and the times the store recorded (the
//! handlers turn a [`Refusal`] into an answer).

use super::phase::Phase;
use super::{QUOTA_WINDOW_S, Settings};
use crate::store::{FormatFailure, Ledger, Store, StoreError};

/// Which rule refuses an upload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RefusalKind {
    /// The challenge is closed, frozen or past its deadline (HTTP 403).
    Phase,
    /// The team's quota of accepted entries is used (HTTP 429).
    Quota,
    /// The team's cap on refused uploads is reached (HTTP 429).
    RefusalCap,
}

/// Why an upload is refused: the rule, the message for the team, and when
/// the next upload is possible (if that is known).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refusal {
    /// The rule.
    pub kind: RefusalKind,
    /// The message for the team.
    pub message: String,
    /// When the next upload is possible (Unix seconds).
    pub reset_s: Option<i64>,
}

/// The refusal when a team's quota or refusal cap is used, given the times
/// of its accepted entries and refused uploads in the window (oldest
/// first) and `in_flight` others of its uploads still arriving.
pub fn limits(s: &Settings, used: &[i64], failed: &[i64], in_flight: usize) -> Option<Refusal> {
    let quota = s.quota as usize;
    if used.len() + in_flight >= quota {
        // The slot that frees first: the oldest counted upload leaving the
        // window, unless uploads still arriving hold the quota.
        let k = used.len() + in_flight - quota;
        let reset = used.get(k).map(|t| t + QUOTA_WINDOW_S);
        let counting = if in_flight > 0 {
            format!(", counting {in_flight} upload(s) of your team still arriving or being checked")
        } else {
            String::new()
        };
        let message = match reset {
            Some(r) => format!(
                "the quota of {} scored submissions per 24 hours is used{counting}; the next is \
                 possible at {}",
                s.quota,
                crate::utc_text(r)
            ),
            None => format!(
                "the quota of {} scored submissions per 24 hours is used{counting}",
                s.quota
            ),
        };
        return Some(Refusal {
            kind: RefusalKind::Quota,
            message,
            reset_s: reset,
        });
    }
    if failed.len() >= s.format_failure_cap as usize {
        let reset = failed[failed.len() - s.format_failure_cap as usize] + QUOTA_WINDOW_S;
        return Some(Refusal {
            kind: RefusalKind::RefusalCap,
            message: format!(
                "{} refused uploads in 24 hours: check your files with `stepsim score` on a \
                 run of your own; the next upload is possible at {}",
                s.format_failure_cap,
                crate::utc_text(reset)
            ),
            reset_s: Some(reset),
        });
    }
    None
}

/// Why an upload is refused at `now_s` on `ledger` (the phase, then the
/// quota and the refusal cap counting no upload in flight), if it is: the
/// rule of the store's admission, and its answer when the store declines.
pub fn admission_refusal(s: &Settings, ledger: &Ledger, now_s: i64) -> Option<Refusal> {
    if let Some(why) = Phase::of_meta(&ledger.meta).upload_refusal(now_s) {
        return Some(Refusal {
            kind: RefusalKind::Phase,
            message: why,
            reset_s: None,
        });
    }
    limits(s, &ledger.accepted, &ledger.refused, 0)
}

/// A team's quota now.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct QuotaStatus {
    /// Entries accepted in the window.
    pub used: usize,
    /// The quota.
    pub limit: u32,
    /// When the oldest counted entry leaves the window, if any.
    pub reset_s: Option<i64>,
}

/// How many of a team's refused uploads the team is shown (newest first).
pub const REFUSALS_SHOWN: usize = 50;

/// A team's uploads refused by the format check (never entries).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RefusalStatus {
    /// Refused uploads in the window (counted against `limit`).
    pub used: usize,
    /// The cap on refused uploads.
    pub limit: u32,
    /// When the oldest counted one leaves the window, if any.
    pub reset_s: Option<i64>,
    /// The newest [`REFUSALS_SHOWN`], newest first.
    pub recent: Vec<FormatFailure>,
}

/// The quota of team `team_id` at `now_s`.
pub async fn quota_status(
    store: &dyn Store,
    s: &Settings,
    team_id: i64,
    now_s: i64,
) -> Result<QuotaStatus, StoreError> {
    let used = store
        .accepted_since(team_id, now_s - QUOTA_WINDOW_S)
        .await?;
    Ok(QuotaStatus {
        used: used.len(),
        limit: s.quota,
        reset_s: used.first().map(|first| first + QUOTA_WINDOW_S),
    })
}

/// The refused uploads of team `team_id` at `now_s`.
pub async fn refusal_status(
    store: &dyn Store,
    s: &Settings,
    team_id: i64,
    now_s: i64,
) -> Result<RefusalStatus, StoreError> {
    let used = store
        .format_failures_since(team_id, now_s - QUOTA_WINDOW_S)
        .await?;
    let recent = store.format_failures(Some(team_id), REFUSALS_SHOWN).await?;
    Ok(RefusalStatus {
        used: used.len(),
        limit: s.format_failure_cap,
        reset_s: used.first().map(|first| first + QUOTA_WINDOW_S),
        recent,
    })
}
