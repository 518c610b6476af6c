//! `stepsim leaderboard`: several reports ranked in one table (paper
//! Table 5 layout). Ranking: Q_c descending (larger is better); reports
//! without Q_c last; ties by |⟨m⟩| then by name.

use crate::error::HarnessError;
use crate::markdown::{TABLE5_HEADER, table5_cells};
use crate::report::{Report, Summary};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Format tag of `leaderboard.json`.
pub const LEADERBOARD_FORMAT: &str = "stepsim-leaderboard-1";

/// One ranked submission.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Entry {
    /// 1-based rank.
    pub rank: usize,
    /// Submission name.
    pub submission: String,
    /// The report file.
    pub report: PathBuf,
    /// Its summary.
    pub summary: Summary,
}

/// The leaderboard.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Leaderboard {
    /// [`LEADERBOARD_FORMAT`].
    pub format: String,
    /// Best first.
    pub entries: Vec<Entry>,
}

/// Reads one `report.json`.
pub fn read_report(path: &Path) -> Result<Report, HarnessError> {
    let text = std::fs::read_to_string(path).map_err(|e| HarnessError::Report {
        path: path.into(),
        message: format!("cannot read: {e}"),
    })?;
    serde_json::from_str(&text).map_err(|e| HarnessError::Report {
        path: path.into(),
        message: format!("not a stepsim report: {e}"),
    })
}

/// Ranks reports (pure).
pub fn rank(reports: &[(PathBuf, Report)]) -> Leaderboard {
    let mut order: Vec<usize> = (0..reports.len()).collect();
    let key = |i: usize| {
        let s = &reports[i].1.summary;
        (
            s.q_c.filter(|q| q.is_finite()),
            s.m_mean.map_or(f64::INFINITY, f64::abs),
        )
    };
    order.sort_by(|&a, &b| {
        let (qa, ma) = key(a);
        let (qb, mb) = key(b);
        match (qa, qb) {
            (Some(x), Some(y)) => y.total_cmp(&x),
            (Some(_), None) => std::cmp::Ordering::Less,
            (None, Some(_)) => std::cmp::Ordering::Greater,
            (None, None) => std::cmp::Ordering::Equal,
        }
        .then(ma.total_cmp(&mb))
        .then(reports[a].1.submission.cmp(&reports[b].1.submission))
    });
    Leaderboard {
        format: LEADERBOARD_FORMAT.into(),
        entries: order
            .iter()
            .enumerate()
            .map(|(k, &i)| Entry {
                rank: k + 1,
                submission: reports[i].1.submission.clone(),
                report: reports[i].0.clone(),
                summary: reports[i].1.summary.clone(),
            })
            .collect(),
    }
}

/// The leaderboard as Markdown (Table 5 layout with a rank column).
pub fn leaderboard_markdown(reports: &[(PathBuf, Report)], board: &Leaderboard) -> String {
    let mut o =
        String::from("# Leaderboard\n\nRanked by Q_c (larger is better); see docs/scoring.md.\n\n");
    let _ = writeln!(o, "| rank | submission {TABLE5_HEADER}");
    let _ = writeln!(o, "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for e in &board.entries {
        let r = reports
            .iter()
            .find(|(p, r)| *p == e.report && r.submission == e.submission)
            .map(|x| &x.1);
        if let Some(r) = r {
            let _ = writeln!(o, "| {} | {} {}", e.rank, e.submission, table5_cells(r));
        }
    }
    o
}
