//! A team's final entries: those it chose, or by default its best public
//! one; the one rule of which entries count at reveal.

use super::figures::{public_of_text, public_rank_key};
use super::phase::Phase;
use crate::store::{Store, StoreError, Submission};

/// Why a choice of final entries is refused.
#[derive(Debug, thiserror::Error)]
pub enum ChoiceError {
    /// The challenge is closed (HTTP 403).
    #[error("the challenge is closed: final entries can no longer be chosen")]
    Closed,
    /// More than [`MAX_FINAL_ENTRIES`] (HTTP 422).
    #[error("at most {MAX_FINAL_ENTRIES} final entries can be chosen; {0} were given")]
    TooMany(usize),
    /// No entry of the team has this id (HTTP 404, as for another team's).
    #[error("entry {0} not found")]
    NotFound(i64),
    /// The entry has no score (HTTP 422).
    #[error("entry {0} is not scored; only scored entries can be final")]
    NotScored(i64),
    /// The store failed (HTTP 500).
    #[error(transparent)]
    Store(#[from] StoreError),
}

/// How many final entries a team may choose.
pub const MAX_FINAL_ENTRIES: usize = 2;

/// Checks and records a team's choice of final entries (up to
/// [`MAX_FINAL_ENTRIES`] of its own scored entries; an empty list goes
/// back to the default, its best public entry). Repeated ids count once.
/// Returns the chosen ids, sorted. Allowed while frozen, refused once
/// closed. Nothing changes when it is refused.
pub async fn choose_final_entries(
    store: &dyn Store,
    team_id: i64,
    ids: &[i64],
) -> Result<Vec<i64>, ChoiceError> {
    if Phase::read(store).await?.closed {
        return Err(ChoiceError::Closed);
    }
    let mut ids = ids.to_vec();
    ids.sort_unstable();
    ids.dedup();
    if ids.len() > MAX_FINAL_ENTRIES {
        return Err(ChoiceError::TooMany(ids.len()));
    }
    for &id in &ids {
        let sub = store
            .submission(id)
            .await?
            .filter(|s| s.team_id == team_id)
            .ok_or(ChoiceError::NotFound(id))?;
        if !sub.has_score() {
            return Err(ChoiceError::NotScored(id));
        }
    }
    // Closed since the check above (by another host): the transaction
    // that sets them reads `closed` again.
    if !store.set_final_entries(team_id, &ids).await? {
        return Err(ChoiceError::Closed);
    }
    Ok(ids)
}

/// A team's best entry by public feedback (the earlier entry, the smaller
/// id, on ties), among those with a score, whatever the order of `subs`:
/// the team's own view lists its entries newest first and the board oldest
/// first, and both must name the same entry (issue #27).
pub fn best_public<'a>(subs: &[&'a Submission]) -> Option<&'a Submission> {
    let mut best: Option<(&Submission, (f64, f64))> = None;
    for s in subs.iter().filter(|s| s.has_score()) {
        let k = public_rank_key(public_of_text(s.public_json.as_deref()).as_ref());
        let better = best.is_none_or(|(b, bk)| match k.partial_cmp(&bk) {
            Some(std::cmp::Ordering::Less) => true,
            Some(std::cmp::Ordering::Equal) => s.id < b.id,
            _ => false,
        });
        if better {
            best = Some((s, k));
        }
    }
    best.map(|b| b.0)
}

/// The entries of one team that count at reveal: those it chose (with a
/// score), or, when it chose none, its best public entry ([`best_public`]).
/// `subs` are the team's entries, in any order; the answer is in the order
/// of their ids.
pub fn final_entries_or_default<'a>(subs: &[&'a Submission]) -> Vec<&'a Submission> {
    let mut chosen: Vec<&Submission> = subs
        .iter()
        .copied()
        .filter(|s| s.final_choice && s.has_score())
        .collect();
    chosen.sort_by_key(|s| s.id);
    if chosen.is_empty() {
        best_public(subs).into_iter().collect()
    } else {
        chosen
    }
}
