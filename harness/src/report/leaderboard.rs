//! `stepsim leaderboard`: several reports ranked in one table (paper
//! Table 5 layout). Ranking: Q_c descending (larger is better); reports
//! without Q_c last; ties by |⟨m⟩| then by name. Only reports of one run
//! and one match radius are ranked together ([`check_comparable`]).

use crate::error::HarnessError;
use crate::error::show_number;
use crate::read::input::{MAX_REPORT_BYTES, read_regular_file};
use crate::report::markdown::{TABLE5_COLUMNS, escape, table, table5_cells};
use crate::score::report::{Report, Summary};
use serde::Serialize;
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

/// Reads one `report.json` (a regular file of at most
/// [`MAX_REPORT_BYTES`]). A report without the run identity `run` (written
/// before it existed) is refused with a sentence asking to score again.
pub fn read_report(path: &Path) -> Result<Report, HarnessError> {
    let refuse = |message: String| HarnessError::Report {
        path: path.into(),
        message,
    };
    let bytes = read_regular_file(path, MAX_REPORT_BYTES).map_err(|e| refuse(e.to_string()))?;
    let value: serde_json::Value = serde_json::from_slice(&bytes)
        .map_err(|e| refuse(format!("not a stepsim report (not JSON: {e})")))?;
    if value.is_object() && value.get("submission").is_some() && value.get("run").is_none() {
        return Err(refuse(
            "this report has no `run` key (the run's identity): it was written by an \
             earlier stepsim; score the submission again to rank it"
                .into(),
        ));
    }
    serde_json::from_value(value).map_err(|e| refuse(format!("not a stepsim report: {e}")))
}

/// Refuses a set of reports that cannot be ranked together, naming both
/// files: the same file given twice, reports of different runs (`run`),
/// match radii or isolation planes, two reports with the same submission
/// name.
pub fn check_comparable(reports: &[(PathBuf, Report)]) -> Result<(), HarnessError> {
    let canonical: Vec<PathBuf> = reports
        .iter()
        .map(|(p, _)| std::fs::canonicalize(p).unwrap_or_else(|_| p.clone()))
        .collect();
    for (j, (pj, rj)) in reports.iter().enumerate() {
        for (i, (pi, ri)) in reports[..j].iter().enumerate() {
            let refuse = |message: String| HarnessError::Report {
                path: pj.clone(),
                message,
            };
            let other = pi.display();
            if canonical[i] == canonical[j] {
                return Err(refuse(format!("given twice (also as {other})")));
            }
            if ri.run != rj.run {
                return Err(refuse(format!(
                    "scored against another run than {other} (run `{}`, there `{}`); a \
                     leaderboard ranks the submissions of one run",
                    rj.run, ri.run
                )));
            }
            if ri.match_radius_arcsec.to_bits() != rj.match_radius_arcsec.to_bits() {
                return Err(refuse(format!(
                    "matched within {} arcsec, {other} within {} arcsec; a leaderboard \
                     compares one match radius",
                    show_number(rj.match_radius_arcsec),
                    show_number(ri.match_radius_arcsec)
                )));
            }
            if ri.isolation_plane != rj.isolation_plane {
                return Err(refuse(format!(
                    "classes its isolated galaxies in the {} plane, {other} in the {} plane \
                     (scored before and after the harness classed a lensed run's in the source \
                     plane); score both again with one stepsim",
                    rj.isolation_plane.name(),
                    ri.isolation_plane.name()
                )));
            }
            if ri.submission == rj.submission {
                return Err(refuse(format!(
                    "submission `{}` is also the name in {other}; score one of them again \
                     with another --name",
                    rj.submission
                )));
            }
        }
    }
    Ok(())
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
    let header: Vec<&str> = ["rank", "submission"]
        .into_iter()
        .chain(TABLE5_COLUMNS)
        .collect();
    let rows = board.entries.iter().filter_map(|e| {
        let r = reports
            .iter()
            .find(|(p, r)| *p == e.report && r.submission == e.submission)?;
        Some(
            [e.rank.to_string(), escape(&e.submission)]
                .into_iter()
                .chain(table5_cells(&r.1))
                .collect::<Vec<_>>(),
        )
    });
    table(&mut o, &header, "rlrrrrrrrr", rows);
    o
}
