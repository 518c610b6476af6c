//! The run layer: from a config file to the files of a run. The config as
//! written ([`config`]), the plan that resolves it ([`crate::Plan`]), the
//! estimates checked before any work ([`memory`], [`disk`]), the run itself
//! ([`generate`], with its opaque ids from [`blind`]) and what a plan makes
//! besides a run ([`products`]).
//!
//! It uses the models and the file formats of [`crate::io`]; neither uses it.

pub mod blind;
pub mod config;
pub mod disk;
pub mod generate;
pub mod memory;
pub(crate) mod plan;
pub mod products;
