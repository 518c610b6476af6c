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
//!   edges (the submission, [`MeasuredObject`]) positions are FITS
//!   pixels: array coordinate + 1.
//! * Pixel values are **electrons** (ADU × gain), sky still in them when read;
//!   sizes and weight scales are in pixels; magnitudes are on the image's
//!   zeropoint system (SPEC §1).
//! * Ellipticities measured from moments are of the *distortion* type,
//!   χ = (Q11 − Q22, 2 Q12) / (Q11 + Q22) (paper eq. 11); shear estimates are
//!   reduced-shear type.
//!
//! ## Pipeline (one image)
//!
//! ```text
//! background.rs   SExtractor-style mesh background and its rms
//! filter.rs       the matched filter of detection
//! segment.rs      detection and deblending
//! centroid.rs     windowed centroid and size r_g
//! stars.rs        the stellar locus in the size–magnitude plane
//! moments.rs      KSB moments and polarisabilities
//! psf_model.rs    p_μ and P^sh*/P^sm* across the field, per weight scale
//! shear.rs        the estimator, weights and cuts (flags.rs: the flag bits)
//! calibration.rs  P^γ calibrated on the image's own PSF with model galaxies
//! metacal.rs      metacalibration, the other estimator (Method::Metacal)
//! metadetect.rs   metacalibration of the whole image, detection included
//!                 (Method::Metadetect)
//! pipeline.rs     the stages strung together for one image
//! run.rs          a public run directory in, a submission out (shards too)
//! io.rs           FITS images, manifest, submission text
//! params.rs       KsbParams, every setting with its default
//! ```
//!
//! With [`Method::Metacal`] the shear estimate is metacalibration instead
//! of KSB+; detection, stars and cuts on the detection are shared. With
//! [`Method::Metadetect`] the detection too is made on each sheared
//! version of the whole image.
//!
//! The modules are private: what users call is re-exported here, each item
//! under one name. Synthetic test scenes live in `stepsim-testkit`
//! (`scene`), which ksb's own unit tests compile in by `#[path]`.
//!
//! Every fast routine `f` has a slow, obvious twin `f_slow` in the same
//! module, used by the tests.
#![deny(missing_docs)]

mod background;
mod calibration;
mod centroid;
mod error;
mod filter;
mod flags;
mod image;
mod io;
mod linalg;
mod metacal;
mod metadetect;
mod moments;
mod params;
mod pipeline;
mod polynomial;
mod psf_model;
mod run;
mod segment;
mod shear;
mod stars;

// The unit tests draw their scenes with `stepsim-testkit`'s scene.rs and
// this crate's own types: its source is compiled in, and names this crate
// as `stepsim_ksb` as it does from outside.
#[cfg(test)]
extern crate self as stepsim_ksb;
#[cfg(test)]
#[allow(dead_code)]
#[path = "../../testkit/src/scene.rs"]
mod scene;

pub use calibration::CalibrationProfile;
pub use error::KsbError;
pub use image::Image;
pub use io::{read_manifest, write_fits_image};
pub use linalg::Mat2;
pub use params::{KsbParams, Method, PgammaMode, SizeCut};
pub use pipeline::{ImageInfo, ImageMeasurement, KsbDetails, MeasuredObject, measure_image};
pub use run::{
    DatasetResponse, ImageSummary, Progress, join_parts, measure_run, measure_run_with_details,
    measure_shard, part_path, parts_count, rows_path,
};
