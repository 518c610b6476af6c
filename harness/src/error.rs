//! Errors of the harness. Every refusal names the file and, where it exists,
//! the line (or FITS row) and the column, so that a participant can fix the
//! submission without guessing.

use std::fmt;
use std::path::PathBuf;
use stepsim_contract::io::IoError;

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
            write!(f, ", column `{c}`")?;
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
    #[error(
        "{path}: {n_missing} of {n_total} images have no rows (first missing: {first}); \
         pass --allow-missing-images to score a partial submission"
    )]
    MissingImages {
        /// The submission.
        path: PathBuf,
        /// How many images have no rows.
        n_missing: usize,
        /// How many images the run has.
        n_total: usize,
        /// The first missing image id.
        first: String,
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
    }
}
