//! # stepsim-harness
//!
//! Scores shear catalogues against the truth of a stepsim run, the way the
//! STEP1 paper did (section "Analysis"). Metrics are pure functions of tables;
//! reading and writing live at the edges.
//!
//! ```text
//! read/       the edges that read: submissions (text, CSV, FITS, per-image
//!             directories) with bounded reads, gzip within a cap, FITS
//!             tables via raw cfitsio, rows spilled to disk by image, and
//!             RUN/private (datasets.json, truth/<image>.fits)
//! score/      pure functions of tables: matching (grid + brute force),
//!             isolation (sweep + brute force), the fits, the SPEC §7
//!             metrics, bootstrap intervals, the report.json types
//! report/     the outputs: report.md, Figs 2-5 as SVG + PNG, leaderboards
//! pipeline.rs the stages end to end, writing the outputs
//! part.rs     one part of a challenge run; the public feedback
//! combine.rs  one report from the reports of runs holding some PSFs each
//! error.rs    HarnessError, the one error type
//! ```
//!
//! The layers depend downward only (read ← score ← report ← pipeline, part,
//! combine; `tests/module_graph.rs` checks it). The modules are private:
//! what users call is re-exported here, each item under one name.
//!
//! Units: positions in FITS pixels (first pixel centre 1.0), the match radius
//! in arcsec at the edge (pixels inside), shears dimensionless.
#![deny(missing_docs)]

mod combine;
mod error;
mod part;
mod pipeline;
mod read;
mod report;
mod score;

// The unit tests use the synthetic runs of `stepsim-testkit` with this
// crate's own types: its source is compiled in, and names this crate as
// `stepsim_harness` as it does from outside.
#[cfg(test)]
extern crate self as stepsim_harness;
#[cfg(test)]
#[allow(dead_code)]
#[path = "../../testkit/src/synthetic.rs"]
mod synthetic;

pub use error::{HarnessError, Location, MISSING_IDS_SHOWN};

// Reading.
pub use read::input::{
    InputError, MAX_GZIP_MEMBERS, MAX_REPORT_BYTES, MAX_SUBMISSION_BYTES, show_bytes,
};
pub use read::spill::DEFAULT_BUFFER_ROWS;
pub use read::submission::{
    FileRows, MAX_COLUMNS, MAX_LINE_BYTES, SubRow, Submission, parse_file, parse_file_limited,
    read_submission, read_submission_limited, read_submission_slow, read_submission_spilled,
};
pub use read::truth_set::{
    ImageIndex, ImageInfo, SCORING_COLUMNS, SUBMISSION_BYTES_PER_IMAGE,
    SUBMISSION_BYTES_PER_TRUTH_ROW, TruthSet, lensed_positions, load_truth_set, population_switch,
    run_identity, run_submission_limit,
};

// Scoring.
pub use score::bootstrap::{
    DEFAULT_RESAMPLES, bootstrap, intervals, percentile_interval, resample_summaries,
};
pub use score::fit::{PolyFit, fit_line_closed_form};
pub use score::isolation::{
    ISOLATION_FLUX_FRACTION, ISOLATION_RADIUS_ARCSEC, Isolation, IsolationPlane, Plane, isolated,
    isolated_slow,
};
pub use score::matching::{Matches, match_nearest, match_nearest_slow};
pub use score::metrics::{
    BinAcc, CHANCE_LATTICE, DISK_EDGES_ARCSEC, DatasetMeta, FitModel, ImageStats, MAG_EDGES,
    MIN_SHEARS_QUADRATIC, ModelWhy, Q_SIGNIFICANCE, Response, Scores, ValErr, binned_residuals,
    chance_matches, chance_matches_slow, fit_response, image_stats, match_image, score_tables,
    score_tables_with,
};
pub use score::report::{
    BinReport, Binned, BootstrapCi, DatasetReport, FitChoice, FitKind, PsfReport, Report, Summary,
};

// Reports.
pub use report::leaderboard::{
    Entry, LEADERBOARD_FORMAT, Leaderboard, check_comparable, leaderboard_markdown, rank,
    read_report,
};
pub use report::markdown::{FEW_BASE_FIELDS, distinct_resamples};
pub use report::plots::fig3;

// The stages end to end.
pub use combine::combine_files;
pub use part::{
    FEEDBACK_DECIMALS, PublicFeedback, has_holdout, round_to, score_part, score_prepared_part,
};
pub use pipeline::{
    DEFAULT_MATCH_RADIUS_ARCSEC, Prepared, REPORT_FIGURES, REPORT_JSON, ScoreOptions, build_report,
    check_outputs_free, match_images, output_paths, prepare, prepare_slow, score, score_slow,
    write_outputs,
};
