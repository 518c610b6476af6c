//! The model layer: what a run simulates, as values. Light profiles, the
//! population, the PSFs, the renderer, the noise, the images' WCS and the
//! moments that check them.
//!
//! The models take typed specs ([`psf::PsfSpec`],
//! [`population::PopulationSpec`], [`wcs::Geometry`], [`noise::Instrument`],
//! [`render::Accuracy`]) that the plan builds from the validated config;
//! they know no config, no plan and no file (`sim/tests/module_graph.rs`).

pub mod moments;
pub mod noise;
pub mod population;
pub mod profile;
pub mod psf;
pub mod render;
pub mod wcs;
