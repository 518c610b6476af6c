//! The organiser's export of the leaderboard: JSON, CSV and the ranked
//! entries' reports.

use super::{Challenge, ChallengeError, leaderboard};
use std::path::{Path, PathBuf};

/// What [`Challenge::export`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct Export {
    /// The leaderboard as JSON (`{"revealed", "part", "rows"}`).
    pub json: PathBuf,
    /// The same rows as CSV.
    pub csv: PathBuf,
    /// One `report.json` per ranked row (`stepsim leaderboard DIR/*.json`
    /// ranks them again).
    pub reports: Vec<PathBuf>,
}

/// The CSV columns of an export (rows of the leaderboard).
pub const EXPORT_CSV_COLUMNS: [&str; 9] = [
    "rank", "team", "entry", "part", "m_mean", "sigma_c", "q_c", "report", "role",
];

/// A text field of the CSV export: neutralised when a spreadsheet would
/// read it as a formula (it starts with `=`, `+`, `-`, `@`, a tab or a
/// carriage return: a `'` goes first, as OWASP advises for CSV injection),
/// then quoted when it holds a comma, quote or line break.
pub fn csv_field(s: &str) -> String {
    let s = if s.starts_with(['=', '+', '-', '@', '\t', '\r']) {
        format!("'{s}")
    } else {
        s.to_string()
    };
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s
    }
}

impl Challenge {
    /// Writes the leaderboard to `out` (JSON), `out` with extension `csv`,
    /// and each ranked entry's report of the part it is ranked on (held-out
    /// after reveal, public before) into the directory `out` with extension
    /// `reports`, named `RANK-entryID.json` (`organisers-entryID.json`,
    /// `baseline-entryID.json` for unranked rows). Every file is written
    /// atomically.
    pub async fn export(&self, out: &Path) -> Result<Export, ChallengeError> {
        use stepsim_contract::io::write_bytes_atomically;
        let revealed = self.revealed().await?;
        let part = if revealed && self.settings.holdout {
            stepsim_contract::run_layout::Part::Holdout
        } else {
            stepsim_contract::run_layout::Part::Public
        };
        let teams = self.store.teams().await?;
        let subs = self.store.all_submissions().await?;
        let board = leaderboard::rows(&teams, &subs, revealed);
        let mut rows = Vec::with_capacity(board.len());
        let reports_dir = out.with_extension("reports");
        let io = |p: &Path, e: String| ChallengeError::State {
            path: p.to_path_buf(),
            message: e,
        };
        std::fs::create_dir_all(&reports_dir).map_err(|e| io(&reports_dir, e.to_string()))?;
        let mut reports = Vec::new();
        let mut csv = EXPORT_CSV_COLUMNS.join(",");
        csv.push('\n');
        for r in &board {
            let mut row = r.json();
            let id = r.entry.id;
            // Unranked rows (organisers, baseline): an empty rank, and the
            // role in the report's name.
            let rank = r.rank;
            let role = r.team.role.name().to_string();
            let label = rank.map_or_else(|| role.clone(), |r| r.to_string());
            let src = self.entry_dir(id, part).join("report.json");
            let dst = reports_dir.join(format!("{label}-entry{id}.json"));
            let bytes = std::fs::read(&src).map_err(|e| io(&src, e.to_string()))?;
            write_bytes_atomically(&dst, &bytes).map_err(|e| io(&dst, e.to_string()))?;
            let name = dst
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            let figures = if part == stepsim_contract::run_layout::Part::Holdout {
                &row["holdout"]
            } else {
                &row["public"]
            };
            // Each figure as the stored JSON writes it (the row's JSON
            // above), so that the CSV and the JSON agree to the digit.
            let num = |k: &str| figures.get(k).map(|v| v.to_string()).unwrap_or_default();
            let fields = [
                rank.map(|r| r.to_string()).unwrap_or_default(),
                csv_field(&r.team.name),
                id.to_string(),
                part.name().to_string(),
                num("m_mean"),
                num("sigma_c"),
                num("q_c"),
                csv_field(&format!(
                    "{}/{name}",
                    reports_dir
                        .file_name()
                        .map(|n| n.to_string_lossy().into_owned())
                        .unwrap_or_default()
                )),
                role,
            ];
            csv.push_str(&fields.join(","));
            csv.push('\n');
            row["report"] = serde_json::json!(name);
            rows.push(row);
            reports.push(dst);
        }
        let doc = serde_json::json!({"revealed": revealed, "part": part.name(), "rows": rows});
        let mut json = serde_json::to_string_pretty(&doc).map_err(|e| io(out, e.to_string()))?;
        json.push('\n');
        write_bytes_atomically(out, json.as_bytes()).map_err(|e| io(out, e.to_string()))?;
        let csv_path = out.with_extension("csv");
        write_bytes_atomically(&csv_path, csv.as_bytes())
            .map_err(|e| io(&csv_path, e.to_string()))?;
        Ok(Export {
            json: out.to_path_buf(),
            csv: csv_path,
            reports,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::csv_field;

    #[test]
    fn csv_fields_that_a_spreadsheet_would_run_are_neutralised() {
        assert_eq!(
            csv_field("=HYPERLINK(\"http://x\",\"a\")"),
            "\"'=HYPERLINK(\"\"http://x\"\",\"\"a\"\")\""
        );
        for (t, want) in [
            ("+1", "'+1"),
            ("-1+2", "'-1+2"),
            ("@SUM(A1)", "'@SUM(A1)"),
            ("\tx", "'\tx"),
            ("\rx", "\"'\rx\""),
            ("Lensing Group A", "Lensing Group A"),
            ("a=b", "a=b"),
            ("a,b", "\"a,b\""),
        ] {
            assert_eq!(csv_field(t), want, "{t:?}");
        }
    }
}
