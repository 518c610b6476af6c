//! The readers: everything that comes from a file, checked at the edge.
//! Participant input is hostile: regular files only, size caps, no panics
//! on a malformed FITS file. Uses nothing of the crate but [`crate::error`].

pub mod fits_table;
pub mod input;
pub mod spill;
pub mod submission;
pub mod truth_set;
