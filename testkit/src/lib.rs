//! # stepsim-testkit
//!
//! Test fixtures of the workspace, kept out of the libraries' APIs: a
//! dev-dependency of the harness, the reference pipeline, the server and
//! the binary's tests, examples and benchmarks, never a normal one.
//!
//! ```text
//! scene.rs       the reference pipeline's synthetic scenes: elliptical
//!                Gaussians drawn plainly, a STEP-like image of them, its
//!                public half written to disk
//! synthetic.rs   runs in memory with an exactly known answer (truth tables,
//!                datasets.json, submissions by a rule), written to disk as
//!                a challenge run when a test needs files
//! ```
//!
//! The harness's own unit tests compile `synthetic.rs` into the harness
//! (`#[path]` in `harness/src/lib.rs`), and ksb's compile `scene.rs` into
//! ksb (`ksb/src/lib.rs`): a dev-dependency would hand them the library's
//! types, not those of the crate under test.
#![deny(missing_docs)]

pub mod scene;
pub mod synthetic;
