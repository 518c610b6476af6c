//! # stepsim-ksb
//!
//! The reference shear pipeline behind `stepsim measure`: a SExtractor-like
//! source detection, automatic star–galaxy separation in the size–magnitude
//! plane, and the KSB+ shear estimator (Kaiser, Squires & Broadhurst 1995;
//! Luppino & Kaiser 1997; Hoekstra et al. 1998) as described in the STEP1
//! paper (Heymans et al. 2006, section 3.1 and appendix A). `docs/ksb.md`
//! says which choice this implementation makes for every row of the paper's
//! KSB table.
//!
//! ## Units and coordinates
//! * Inside the crate, pixel positions are **array coordinates**: the centre
//!   of pixel `(ix, iy)` (0-based, `ix` along NAXIS1) is `(ix, iy)`. At the
//!   edges (the submission, [`pipeline::MeasuredObject`]) positions are FITS
//!   pixels: array coordinate + 1.
//! * Pixel values are **electrons** (ADU × gain), sky still in them when read;
//!   sizes and weight scales are in pixels; magnitudes are on the image's
//!   zeropoint system (SPEC §1).
//! * Ellipticities measured from moments are of the *distortion* type,
//!   χ = (Q11 − Q22, 2 Q12) / (Q11 + Q22) (paper eq. 11); shear estimates are
//!   reduced-shear type.
//!
//! ## Pipeline (one image)
//! [`background`] → [`filter`] → [`segment`] (detection, deblending) →
//! [`centroid`] (windowed centroid and size r_g) → [`stars`] (stellar locus)
//! → [`moments`] (KSB moments and polarisabilities) → [`psf_model`]
//! (p_μ and P^sh*/P^sm* across the field, per weight scale) → [`shear`]
//! (estimator, weights, cuts, [`flags`]). [`pipeline`] strings them together;
//! [`run`] reads a public run directory and writes a submission.
//!
//! With [`params::Method::Metacal`] the shear estimate is metacalibration
//! ([`metacal`]) instead of [`shear`]; detection, stars and cuts on the
//! detection are shared.
//!
//! Every fast routine `f` has a slow, obvious twin `f_slow` in the same
//! module, used by the tests.
#![deny(missing_docs)]

pub mod background;
pub mod centroid;
pub mod draw;
pub mod error;
pub mod filter;
pub mod flags;
pub mod image;
pub mod io;
pub mod linalg;
pub mod metacal;
pub mod moments;
pub mod params;
pub mod pipeline;
pub mod polynomial;
pub mod psf_model;
pub mod run;
pub mod segment;
pub mod shear;
pub mod stars;

pub use error::KsbError;
pub use image::Image;
pub use params::KsbParams;
pub use pipeline::{MeasuredObject, measure_image};
