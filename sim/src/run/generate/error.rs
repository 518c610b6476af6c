//! Why a run failed: [`GenerateError`] and the sentence of an incomplete
//! run.

use super::Shard;
use std::path::{Path, PathBuf};
use stepsim_contract::io::IoError;

/// Why a run failed.
#[derive(Debug, thiserror::Error)]
pub enum GenerateError {
    /// Reading or writing a file failed.
    #[error(transparent)]
    Io(#[from] IoError),
    /// A truth row cannot be drawn (names the object, column and value).
    #[error("base field {field}: {source}")]
    Render {
        /// The base field.
        field: u32,
        /// The renderer's error.
        source: crate::model::render::RenderError,
    },
    /// The population cannot be made (checked before anything is written).
    #[error("population: {0}")]
    Preflight(crate::model::population::PopulationError),
    /// The population of a base field could not be made.
    #[error("base field {field}: {source}")]
    Population {
        /// The base field.
        field: u32,
        /// The population's error.
        source: crate::model::population::PopulationError,
    },
    /// A PSF could not be built.
    #[error("psfs.{index} ({name}): {source}")]
    Psf {
        /// Index in the config's `psfs`.
        index: usize,
        /// Its name.
        name: String,
        /// The PSF module's error.
        source: crate::model::psf::PsfError,
    },
    /// The run does not fit on its file system (checked again once the
    /// PSFs are solved, with their sizes).
    #[error("{0}; the solved PSFs are kept in private/psf/cache/ for the next attempt")]
    NoSpace(#[from] Box<crate::run::disk::NoSpace>),
    /// The output directory holds a run made from another config.
    #[error(
        "{path} holds a run made from a different config; use another --out, or delete the whole run directory"
    )]
    DifferentRun {
        /// The existing `private/config.json`.
        path: PathBuf,
    },
    /// A file in the run directory does not belong to this run.
    #[error(
        "{path} does not belong to this run (it was made by another config or another version of stepsim); use another --out, or delete the whole run directory"
    )]
    ForeignFile {
        /// The file or directory.
        path: PathBuf,
    },
    /// The copy of an input kept in `RUN/private/inputs/` differs from the
    /// file the config names now: the run was made with other bytes.
    #[error(
        "{copy} differs from {source_file}: the run was made with other bytes of this input than the config names now; restore the input the run was made with (the copy is it), or use another --out"
    )]
    InputChanged {
        /// The run's copy.
        copy: PathBuf,
        /// The file the config names.
        source_file: PathBuf,
    },
    /// A sidecar was made by another config or output version.
    #[error("{path} is refused: {why}; use another --out, or delete the whole run directory")]
    ForeignSidecar {
        /// The sidecar.
        path: PathBuf,
        /// Who made it.
        why: String,
    },
    /// `--finish` on a directory that holds no run.
    #[error("{path} does not exist: there is no run to finish here (run the shards first)")]
    NoRun {
        /// The missing `private/config.json`.
        path: PathBuf,
    },
    /// `--finish` found images missing or failing verification.
    #[error("{}", incomplete_message(.run, .missing, .total, .rerun, *.removed_manifest))]
    Incomplete {
        /// The run directory.
        run: PathBuf,
        /// The public files (relative to `public/`) of the images missing
        /// or failing verification, in canonical order.
        missing: Vec<String>,
        /// Images in the run.
        total: usize,
        /// The shards that own them (when the done-markers agree on N).
        rerun: Vec<Shard>,
        /// True when a `public/manifest.json` from before was removed.
        removed_manifest: bool,
    },
    /// Two opaque ids collided (practically impossible; change `run.seed`).
    #[error("opaque id {id} is not unique; choose another run.seed")]
    IdCollision {
        /// The id.
        id: String,
    },
}

fn incomplete_message(
    run: &Path,
    missing: &[String],
    total: &usize,
    rerun: &[Shard],
    removed_manifest: bool,
) -> String {
    const SHOWN: usize = 10;
    let mut list: Vec<&str> = missing.iter().take(SHOWN).map(String::as_str).collect();
    let more = missing.len().saturating_sub(SHOWN);
    let more = if more > 0 {
        format!(" and {more} more")
    } else {
        String::new()
    };
    list.dedup();
    let hint = if rerun.is_empty() {
        "rerun the shards that own them".to_string()
    } else {
        let names: Vec<String> = rerun.iter().map(Shard::to_string).collect();
        format!("rerun shard {}", names.join(", "))
    };
    let removed = if removed_manifest {
        "; the manifest written before was removed"
    } else {
        ""
    };
    format!(
        "{} of {total} images of {} are missing or fail verification ({}{more}); {hint}, then --finish again (nothing was written{removed})",
        missing.len(),
        run.display(),
        list.join(", ")
    )
}
