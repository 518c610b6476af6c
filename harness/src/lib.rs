//! # stepsim-harness
//!
//! Scores shear catalogues against the truth of a stepsim run, the way the
//! STEP1 paper did (section "Analysis"). Metrics are pure functions of tables;
//! reading and writing live at the edges.
//!
//! ```text
//! submission.rs  read + check a submission (text, CSV, FITS, directory)
//! input.rs       bounded reads of regular files, gzip within a cap
//! fits_table.rs  a submission's FITS table via raw cfitsio; error sentences
//! truth_set.rs   RUN/private: datasets.json, truth/<image>.fits
//! matching.rs    nearest truth object within the radius (grid + brute force)
//! isolation.rs   which galaxies have no bright neighbour (sweep + brute force)
//! metrics.rs     per-image sums -> per-dataset, per-PSF, summary, bins
//! fit.rs         weighted least squares, means with errors
//! bootstrap.rs   intervals from resampled base fields
//! pipeline.rs    the stages end to end, writing the outputs
//! part.rs        one part of a challenge run; the public feedback
//! report.rs      report.json types      markdown.rs  report.md
//! plots.rs       Figs 2-5 as SVG + PNG  leaderboard.rs  ranking reports
//! ```
//!
//! Units: positions in FITS pixels (first pixel centre 1.0), the match radius
//! in arcsec at the edge (pixels inside), shears dimensionless.
#![deny(missing_docs)]

pub mod bootstrap;
pub mod combine;
pub mod error;
pub mod fit;
pub mod fits_table;
pub mod input;
pub mod isolation;
pub mod leaderboard;
pub mod markdown;
pub mod matching;
pub mod metrics;
pub mod part;
pub mod pipeline;
pub mod plots;
pub mod report;
pub mod spill;
pub mod submission;
pub mod synthetic;
pub mod truth_set;

pub use error::HarnessError;
pub use pipeline::{ScoreOptions, score, write_outputs};
pub use report::Report;

/// How to submit and what the score means, in Markdown (the one copy lives
/// in `stepsim-contract`).
pub use stepsim_contract::SUBMISSION_FORMAT_MD;
