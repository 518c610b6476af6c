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
//! ## Layers
//! * [`model`]: profiles, population, PSFs, renderer, noise, WCS, moments;
//!   values in, values out.
//! * [`io`]: the simulator's file formats (images, PSF files and store,
//!   SkyMaker lists, truth header keywords); uses the models, not the run.
//! * [`run`]: the config, the [`Plan`] that resolves it, the memory and
//!   disk estimates, `generate` and the other products of a plan.
//!
//! ## Invariants
//! * The numerical core does no file I/O: everything on disk goes through
//!   [`io`].
//! * Every random draw comes from a generator keyed by
//!   (run seed, base field, dataset, purpose) — see
//!   [`stepsim_contract::seed`].
//! * Objects are immutable values.
#![deny(missing_docs)]

pub mod io;
pub mod model;
pub mod run;

pub use run::plan::{
    Dataset, Output, Plan, PlanError, RunInput, SeedOrigin, Shear, holdout_fields, holdout_shear,
    list_path,
};
