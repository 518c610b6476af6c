//! # stepsim-contract
//!
//! The on-disk contract of a stepsim run (SPEC §1 and §5,
//! `docs/run-layout.md`): what the simulator writes and the scorer, the
//! reference pipeline and the server read, in one small crate that links no
//! renderer, FFT or population model.
//!
//! * [`run_dir`]: the paths of a run directory ([`run_dir::RunDir`], and
//!   its halves [`run_dir::PublicDir`] and [`run_dir::PrivateDir`]).
//! * [`run_layout`]: `public/manifest.json` and `private/datasets.json`.
//! * [`truth`]: the truth table's row and column list (SPEC §5);
//!   [`io::truth`] reads and writes it (FITS, and the CSV twin).
//! * [`io`]: the I/O error naming the file, atomic writes
//!   ([`io::write_atomically`]), FITS files opened and created by their plain
//!   names with cfitsio statuses as sentences ([`io::fits`]), public images
//!   read back ([`io::image`]).
//! * [`shear`]: the ellipticity and shear conventions of SPEC §1 (the one
//!   home of the shear matrix).
//! * [`seed`]: keyed random streams; the key → seed mixing is frozen, as the
//!   bytes of every run and the blinding key depend on it.
//! * [`digest`]: SHA-256 as hex (manifest, sidecars, ids).
//! * [`SUBMISSION_FORMAT_MD`]: the submission format told to participants.
#![deny(missing_docs)]

pub mod digest;
pub mod io;
pub mod run_dir;
pub mod run_layout;
pub mod seed;
pub mod shear;
pub mod truth;

/// How to submit and what the score means, in Markdown (SPEC §6): shown by
/// `stepsim score --help` and written into the participants' README. The
/// one copy of this text.
pub const SUBMISSION_FORMAT_MD: &str = include_str!("submission_format.md");

/// Largest |e1| or |e2| a submission may carry (SPEC §6). A shear estimate
/// beyond it can only be a failed measurement; the scorer refuses it, which
/// keeps every sum of the metrics finite and every printed number short, and
/// the reference pipeline writes such an estimate as 0 with weight 0.
pub const MAX_ABS_SHEAR: f64 = 1e6;
