//! Errors of the harness. Every refusal names the file and, where it exists,
//! the line (or FITS row) and the column, so that a participant can fix the
//! submission without guessing.

use std::fmt;
use std::path::PathBuf;
use stepsim_contract::io::IoError;

/// How many missing image ids a [`HarnessError::MissingImages`] refusal
/// names.
pub const MISSING_IDS_SHOWN: usize = 5;

/// The ids of a missing-images refusal, `…` after them when more are
/// missing than shown.
fn show_ids(ids: &[String], n_missing: usize) -> String {
    let mut s = ids.join(", ");
    if n_missing > ids.len() {
        s.push_str(", …");
    }
    s
}

/// Characters of a name or value that a message quotes ([`show_text`]).
pub const SHOWN_CHARS: usize = 64;

/// A name or value as a message quotes it: at most [`SHOWN_CHARS`]
/// characters, then `…` and the length in bytes, so that a 100 MB field
/// makes a message of one line, not of 100 MB.
pub fn show_text(s: &str) -> String {
    match s.char_indices().nth(SHOWN_CHARS) {
        None => s.to_owned(),
        Some((cut, _)) => format!("{}… ({} bytes)", &s[..cut], s.len()),
    }
}

/// Formats a number shortly, as Rust does (`0.25`, `1e308`, `-3`) but in
/// scientific notation outside 10⁻⁴ ≤ |x| < 10¹⁵; `inf`, `-inf`, `NaN`
/// as such.
pub fn show_number(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || (1e-4..1e15).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// Where in a submission a problem sits.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    /// The file.
    pub path: PathBuf,
    /// 1-based line of a text file, or 1-based row of a FITS table.
    pub line: Option<u64>,
    /// `true` when `line` counts FITS table rows rather than text lines.
    pub is_row: bool,
    /// The column name, when one column is at fault.
    pub column: Option<String>,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.path.display())?;
        if let Some(l) = self.line {
            let what = if self.is_row { "row" } else { "line" };
            write!(f, ": {what} {l}")?;
        }
        if let Some(c) = &self.column {
            write!(f, ", column `{}`", show_text(c))?;
        }
        Ok(())
    }
}

/// Everything that can go wrong while scoring.
#[derive(Debug, thiserror::Error)]
pub enum HarnessError {
    /// The submission is refused (bad content); names file, line and column.
    #[error("{at}: {message}")]
    Submission {
        /// Where.
        at: Location,
        /// What is wrong, lower-case.
        message: String,
    },
    /// The truth directory is unusable.
    #[error("{path}: {message}")]
    Truth {
        /// The file or directory.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A file `score` or `leaderboard` writes already exists and `--force`
    /// was not given.
    #[error("{path}: already exists; pass --force to overwrite it")]
    ReportExists {
        /// The existing file.
        path: PathBuf,
    },
    /// The submission lacks images and `--allow-missing-images` was not given.
    /// The ids shown are the smallest missing ones in byte order, never the
    /// first in the run's (private) order: see [`HarnessError::missing_images`].
    #[error(
        "{path}: {n_missing} of {n_total} images have no rows (missing, smallest ids first: \
         {}); pass --allow-missing-images to score a partial submission",
        show_ids(smallest, *n_missing)
    )]
    MissingImages {
        /// The submission.
        path: PathBuf,
        /// How many images have no rows.
        n_missing: usize,
        /// How many images the run has.
        n_total: usize,
        /// The [`MISSING_IDS_SHOWN`] smallest missing image ids, in byte
        /// order (fewer when fewer are missing).
        smallest: Vec<String>,
    },
    /// A report given to the leaderboard cannot be read.
    #[error("{path}: {message}")]
    Report {
        /// The report.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An option has an unusable value.
    #[error("{name}: {message}")]
    BadOption {
        /// The option, e.g. `--match-radius-arcsec`.
        name: String,
        /// What is wrong.
        message: String,
    },
    /// File input or output failed.
    #[error(transparent)]
    Io(#[from] IoError),
}

impl HarnessError {
    /// A submission error at `path`, `line`, `column`.
    pub fn submission(
        path: impl Into<PathBuf>,
        line: Option<u64>,
        column: Option<&str>,
        message: impl Into<String>,
    ) -> Self {
        Self::Submission {
            at: Location {
                path: path.into(),
                line,
                is_row: false,
                column: column.map(str::to_owned),
            },
            message: message.into(),
        }
    }

    /// A submission error at one row of a FITS table.
    pub fn submission_row(
        path: impl Into<PathBuf>,
        row: u64,
        column: Option<&str>,
        message: impl Into<String>,
    ) -> Self {
        Self::Submission {
            at: Location {
                path: path.into(),
                line: Some(row),
                is_row: true,
                column: column.map(str::to_owned),
            },
            message: message.into(),
        }
    }

    /// The refusal of a submission in which the images `missing` have no
    /// rows, out of `n_total`. It names the [`MISSING_IDS_SHOWN`] smallest
    /// missing ids in byte order: the message depends on the set of missing
    /// ids only, never on the order of `missing` (which follows the private
    /// order of `datasets.json`: PSF, shear, part).
    pub fn missing_images<'a>(
        path: impl Into<PathBuf>,
        missing: impl IntoIterator<Item = &'a str>,
        n_total: usize,
    ) -> Self {
        let mut ids: Vec<&str> = missing.into_iter().collect();
        let n_missing = ids.len();
        ids.sort_unstable();
        ids.dedup();
        ids.truncate(MISSING_IDS_SHOWN);
        Self::MissingImages {
            path: path.into(),
            n_missing,
            n_total,
            smallest: ids.into_iter().map(str::to_owned).collect(),
        }
    }

    /// A truth-directory error.
    pub fn truth(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Truth {
            path: path.into(),
            message: message.into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_file_line_and_column() {
        let e =
            HarnessError::submission("sub.txt", Some(12), Some("e1"), "value `nan` is not finite");
        assert_eq!(
            e.to_string(),
            "sub.txt: line 12, column `e1`: value `nan` is not finite"
        );
        let e = HarnessError::submission_row("s.fits", 3, None, "duplicate");
        assert_eq!(e.to_string(), "s.fits: row 3: duplicate");
        let long = "a".repeat(100_000);
        let e = HarnessError::submission("s.txt", Some(1), Some(&long), "column named twice");
        assert_eq!(
            e.to_string(),
            format!(
                "s.txt: line 1, column `{}… (100000 bytes)`: column named twice",
                "a".repeat(SHOWN_CHARS)
            )
        );
    }

    #[test]
    fn quoted_text_is_cut_at_a_character_boundary() {
        assert_eq!(show_text("imA"), "imA");
        let exact = "é".repeat(SHOWN_CHARS);
        assert_eq!(show_text(&exact), exact);
        let long = "é".repeat(SHOWN_CHARS + 1);
        assert_eq!(
            show_text(&long),
            format!(
                "{}… ({} bytes)",
                "é".repeat(SHOWN_CHARS),
                2 * (SHOWN_CHARS + 1)
            )
        );
    }

    #[test]
    fn missing_images_names_the_smallest_ids_whatever_their_order() {
        let ids = ["i7", "i3", "i9", "i1", "i5", "i2", "i8"];
        let a = HarnessError::missing_images("s.txt", ids, 60).to_string();
        let mut rev = ids;
        rev.reverse();
        let b = HarnessError::missing_images("s.txt", rev, 60).to_string();
        assert_eq!(a, b);
        assert_eq!(
            a,
            "s.txt: 7 of 60 images have no rows (missing, smallest ids first: i1, i2, i3, \
             i5, i7, …); pass --allow-missing-images to score a partial submission"
        );
        let one = HarnessError::missing_images("s.txt", ["h9"], 2).to_string();
        assert!(one.contains("1 of 2 images have no rows (missing, smallest ids first: h9);"));
    }
}
