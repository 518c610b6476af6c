//! # stepsim-figure
//!
//! stepsim's pictures as PNG, shared by the simulator (the PSF panel) and the
//! harness (the score figures), so that the scorer draws its figures without
//! linking the simulator:
//!
//! * [`picture`]: a raster picture with text labels.
//! * [`png`]: SVG figures rasterised with their text by `resvg` and the
//!   bundled DejaVu Sans font; pictures with their labels; a PNG decoder for
//!   tests and checks.
#![deny(missing_docs)]

pub mod picture;
pub mod png;
