//! The leaderboard: one row per team with a scored entry, ranked.
//!
//! Before reveal each team's best scored entry by public Q_c (ties by
//! |⟨m⟩|, then the earlier entry: [`best_public`], the entry the team's own
//! view counts by default), ranked by it. After reveal, of each team's final
//! entries ([`final_entries_or_default`]), the one with the best held-out
//! Q_c (ties by |⟨m⟩|, then the earlier entry), ranked by it. Participants
//! are ranked 1, 2, ...; the organisers' and the baseline's rows are placed
//! where their figures put them, unranked. After reveal a row is "tied
//! above" when its held-out Q_c interval overlaps that of the row above it
//! (the board does not rank the two apart).

use super::figures::{
    HoldoutFigures, PublicFigures, holdout_rank_key, public_of_text, public_rank_key, stored_json,
};
use super::finals::{best_public, final_entries_or_default};
use crate::store::{Role, Submission, Team};
use serde_json::{Value, json};

/// One row of the leaderboard.
#[derive(Debug, Clone, PartialEq)]
pub struct Row<'a> {
    /// 1, 2, ... for participants; `None` for the organisers' and the
    /// baseline's rows (never ranked).
    pub rank: Option<usize>,
    /// The team.
    pub team: &'a Team,
    /// How many of its entries are scored.
    pub entries: usize,
    /// The entry whose figures the row shows (and ranks by).
    pub entry: &'a Submission,
    /// That entry's public feedback.
    pub public: Option<PublicFigures>,
    /// After reveal: what counts there (`None` before).
    pub revealed: Option<RevealedRow>,
}

/// What a row shows after reveal.
#[derive(Debug, Clone, PartialEq)]
pub struct RevealedRow {
    /// The team's final entries (those that counted), by id.
    pub finals: Vec<i64>,
    /// The held-out result of the row's entry.
    pub holdout: Option<HoldoutFigures>,
    /// Its held-out Q_c interval overlaps that of the row above.
    pub tied_above: bool,
}

impl Row<'_> {
    /// The held-out result shown (after reveal).
    pub fn holdout(&self) -> Option<&HoldoutFigures> {
        self.revealed.as_ref().and_then(|r| r.holdout.as_ref())
    }

    /// The row as the API sends it (`GET /api/leaderboard`, the export):
    /// `rank` (`null` when unranked), `team`, `role`, `entries`, `entry` and
    /// `public`; after reveal also `finals`, `holdout` and `tied_above`.
    /// The figures are the stored JSON as the worker wrote it.
    pub fn json(&self) -> Value {
        let mut v = json!({
            "rank": self.rank,
            "team": self.team.name,
            "role": self.team.role.name(),
            "entries": self.entries,
            "entry": self.entry.id,
            "public": stored_json(self.entry.public_json.as_deref()),
        });
        if let Some(r) = &self.revealed {
            v["finals"] = json!(r.finals);
            v["holdout"] = stored_json(self.entry.holdout_json.as_deref());
            v["tied_above"] = json!(r.tied_above);
        }
        v
    }
}

/// The leaderboard of `teams` from their entries `subs`, ranked (see the
/// module's documentation).
pub fn rows<'a>(teams: &'a [Team], subs: &'a [Submission], revealed: bool) -> Vec<Row<'a>> {
    let mut rows: Vec<(Row<'a>, (f64, f64))> = Vec::new();
    for team in teams {
        let own: Vec<&Submission> = subs
            .iter()
            .filter(|s| s.team_id == team.id && s.has_score())
            .collect();
        let Some(best) = best_public(&own) else {
            continue;
        };
        let public = public_of_text(best.public_json.as_deref());
        let mut key = public_rank_key(public.as_ref());
        let mut row = Row {
            rank: None,
            team,
            entries: own.len(),
            entry: best,
            public,
            revealed: None,
        };
        if revealed {
            let finals = final_entries_or_default(&own);
            // `finals` is never empty here (the team has a scored entry),
            // so one of them is picked.
            let mut pick: Option<(&Submission, Option<HoldoutFigures>, (f64, f64))> = None;
            for s in &finals {
                let h = HoldoutFigures::of_text(s.holdout_json.as_deref());
                let k = holdout_rank_key(h.as_ref());
                if pick
                    .as_ref()
                    .is_none_or(|p| k.partial_cmp(&p.2) == Some(std::cmp::Ordering::Less))
                {
                    pick = Some((s, h, k));
                }
            }
            let mut holdout = None;
            if let Some((s, h, k)) = pick {
                row.entry = s;
                row.public = public_of_text(s.public_json.as_deref());
                holdout = h;
                key = k;
            }
            row.revealed = Some(RevealedRow {
                finals: finals.iter().map(|s| s.id).collect(),
                holdout,
                tied_above: false,
            });
        }
        rows.push((row, key));
    }
    rows.sort_by(|a, b| {
        a.1.partial_cmp(&b.1)
            .unwrap_or(std::cmp::Ordering::Equal)
            .then(a.0.entry.id.cmp(&b.0.entry.id))
    });
    let mut rank = 0;
    let mut above: Option<[f64; 2]> = None;
    rows.into_iter()
        .map(|(mut r, _)| {
            if r.team.role == Role::Participant {
                rank += 1;
                r.rank = Some(rank);
            }
            let ci = r.holdout().and_then(HoldoutFigures::q_c_interval);
            if let Some(rv) = &mut r.revealed {
                // Rows whose held-out Q_c intervals (95 %, bootstrap over
                // base fields) overlap are not ranked apart by this board.
                rv.tied_above =
                    matches!((above, ci), (Some(a), Some(b)) if a[0] <= b[1] && b[0] <= a[1]);
                above = ci;
            }
            r
        })
        .collect()
}

/// The 95 % bootstrap interval of Q_c of a row's held-out result, when it
/// has one.
pub fn q_c_interval(row: &Row<'_>) -> Option<[f64; 2]> {
    row.holdout().and_then(HoldoutFigures::q_c_interval)
}
