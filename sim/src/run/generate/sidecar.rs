//! The sidecar `private/done/<image-id>.json` that marks an image finished,
//! and the verification of an image's files against it.

use super::{GenerateError, Job, integrity};
use serde::{Deserialize, Serialize};
use std::path::Path;
use stepsim_contract::digest::sha256_hex;
use stepsim_contract::run_dir::RunDir;

/// The sidecar `private/done/<image-id>.json`, written after an image's
/// files: it marks the image finished and lets a rerun verify it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sidecar {
    /// Opaque image id.
    pub image: String,
    /// Opaque dataset id.
    pub dataset: String,
    /// Image path relative to `public/`.
    pub file: String,
    /// SHA-256 of the public image.
    pub sha256: String,
    /// SHA-256 of `private/truth/<image-id>.fits`.
    pub truth_sha256: String,
    /// SHA-256 of `private/model/<image-id>.fits`, when written.
    #[serde(default)]
    pub model_sha256: Option<String>,
    /// SHA-256 of the run's `private/config.json` (what made the files).
    pub config_sha256: String,
    /// [`super::OUTPUT_VERSION`] of the stepsim that made the files.
    pub output_version: u32,
}

/// What made an image's files (recorded in its sidecar).
pub(crate) struct Made<'a> {
    pub(crate) config_sha256: &'a str,
}

/// True when the image's sidecar is this run's and every file it lists is on
/// disk with the recorded SHA-256 (a foreign sidecar is an error: see
/// `integrity::read_sidecar`).
pub fn verify(
    run: &RunDir,
    job: &Job,
    want_model: bool,
    config_sha256: &str,
) -> Result<bool, GenerateError> {
    Ok(integrity::read_sidecar(run, job, config_sha256)?
        .is_some_and(|side| verify_files(run, job, &side, want_model)))
}

/// True when every file `side` lists is on disk with the recorded SHA-256.
pub(super) fn verify_files(run: &RunDir, job: &Job, side: &Sidecar, want_model: bool) -> bool {
    let same = |path: &Path, want: &str| std::fs::read(path).is_ok_and(|b| sha256_hex(&b) == want);
    side.image == job.image_id
        && side.file == job.public_file()
        && same(
            &run.public().image(&job.dataset_id, &job.image_id),
            &side.sha256,
        )
        && same(&run.private().truth(&job.image_id), &side.truth_sha256)
        && match (&side.model_sha256, want_model) {
            (Some(m), true) => same(&run.private().model(&job.image_id), m),
            (None, false) => true,
            _ => false,
        }
}
