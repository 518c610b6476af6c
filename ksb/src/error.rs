//! Errors of the pipeline. Objects that cannot be measured never raise an
//! error: they get a named flag ([`crate::flags`]). Errors are for input that
//! cannot be used at all (missing manifest, unreadable image, bad parameters).

use std::path::PathBuf;

/// Everything that makes `measure` refuse its input.
#[derive(Debug, thiserror::Error)]
pub enum KsbError {
    /// A part of a sharded measure is missing or belongs to another run.
    #[error("{path}: {message}")]
    Part {
        /// The part (or its directory).
        path: std::path::PathBuf,
        /// What is wrong and what to do.
        message: String,
    },
    /// File-level I/O problem (names the file).
    #[error(transparent)]
    Io(#[from] stepsim_contract::io::IoError),
    /// The manifest does not parse or does not describe the images.
    #[error("{path}: {message}")]
    Manifest {
        /// The manifest file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An image has no usable 2-D image data, or the wrong shape.
    #[error("{path}: {message}")]
    Image {
        /// The image file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A parameter is out of its allowed range.
    #[error("invalid parameter {name} = {value}: {reason}")]
    Param {
        /// Parameter name.
        name: &'static str,
        /// Its value.
        value: f64,
        /// The allowed range.
        reason: &'static str,
    },
    /// Two parameters that cannot be used together.
    #[error("invalid parameters: {message}")]
    Combination {
        /// Which, and what to do.
        message: &'static str,
    },
    /// The thread pool could not be built.
    #[error("cannot start {threads} threads: {message}")]
    Threads {
        /// Requested thread count.
        threads: usize,
        /// What rayon said.
        message: String,
    },
}
