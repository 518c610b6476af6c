//! Scoring as pure functions of tables: matching, isolation, the fits, the
//! SPEC §7 metrics and their bootstrap intervals, and the `report.json`
//! types they fill. Reads the rows [`crate::read`] made; writes nothing.

pub mod bootstrap;
pub mod fit;
pub mod isolation;
pub mod matching;
pub mod metrics;
pub mod report;
