//! # stepsim-harness
//!
//! Scores shear catalogues against the truth of a stepsim run, the way the
//! STEP1 paper did (section "Analysis"). Metrics are pure functions of tables;
//! reading and writing live at the edges.
#![deny(missing_docs)]
