//! # stepsim-sim
//!
//! The simulator behind `stepsim`: a Stuff-style galaxy and star population,
//! the STEP1 PSF models, a Fourier-space stamp renderer, noise and FITS output.
//!
//! ## Units (one system inside)
//! * Angles on the sky: **arcsec** (positions on the image: FITS pixels,
//!   first pixel centre at 1.0; x along NAXIS1).
//! * Position angles: **radians** in code, counter-clockwise from +x; degrees
//!   only in files (`_deg` columns).
//! * Fluxes: **electrons** over the exposure; ADU only when writing pixels.
//! * Frequencies: cycles per arcsec.
//! * Ellipticity: the reduced-shear type e = (1−β)/(1+β) e^{2iθ} (paper eq. 1)
//!   unless a name says `chi` (distortion).
//!
//! ## Invariants
//! * The numerical core does no file I/O: everything on disk goes through
//!   [`io`].
//! * Every random draw comes from a generator keyed by
//!   (run seed, base field, dataset, purpose) — see [`seed`].
//! * Objects are immutable values.
#![deny(missing_docs)]

pub mod blind;
pub mod config;
pub mod disk;
pub mod generate;
pub mod io;
pub mod memory;
pub mod moments;
pub mod noise;
pub mod plan;
pub mod population;
pub mod products;
pub mod profile;
pub mod psf;
pub mod render;
/// The shared statistics, now in `stepsim-numerics` (re-exported while
/// sim's own modules still name them `crate::stats`).
pub use stepsim_numerics::stats;
pub mod wcs;

// The on-disk contract and the pictures live in their own crates, so that
// the scorer and the reference pipeline read a run without linking the
// simulator; they are re-exported under their old paths.
pub use stepsim_contract::{run_layout, seed, shear, truth};
pub use stepsim_figure::picture;
