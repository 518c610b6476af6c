//! `stepsim generate`: a whole blind data release (SPEC §5, `docs/run-layout.md`).
//!
//! The run is a list of images in canonical order — for each base field k,
//! for the field and (with `population.rotated_pairs`) its 90°-rotated twin,
//! for each dataset d (PSF × shear) — and every image is a pure function of
//! (config, k, rotated, d):
//!
//! 1. truth rows = `sheared(base_field(k) [rotated], g1(d), g2(d))`;
//! 2. model = `draw_image(renderer of PSF(d), rows)` (electrons, no sky);
//! 3. pixels = [`crate::model::noise::realise`] with key
//!    `SeedKey::image(seed, k, d, Noise).with_index(rotated)`;
//! 4. `public/<dataset-id>/<image-id>.fits`, `private/truth/<image-id>.fits`,
//!    optionally `private/model/<image-id>.fits`, and last the sidecar
//!    `private/done/<image-id>.json` holding the files' SHA-256 and what made
//!    them (config SHA-256, [`OUTPUT_VERSION`]).
//!
//! A run first claims its directory (`claim.rs`: `private/config.json` is
//! created, never replaced) and refuses any file another run left there
//! (`integrity.rs`). Images are made field by field (the base field is drawn
//! once and shared by the datasets), within a field in the order of their
//! opaque ids, in parallel over the images of a field and within each image.
//! A rerun skips every image whose sidecar matches the files on disk
//! (resume), and `--shard K/N` makes only image j with j mod N = K − 1.
//!
//! Completion is explicit. A whole run (no shard, or N = 1) writes
//! `public/manifest.json` itself. A shard (N > 1) never does, even when it
//! happens to finish last: it ends by writing its done-marker
//! `private/shards/K-of-N.json` ([`ShardMarker`]), and [`finish`] (run once
//! after every shard) verifies every image against its sidecar and writes the
//! manifest, or refuses listing the images missing. A process that finds an
//! image unfinished first removes a stale manifest. Every process ends by
//! giving all of `public/` one time stamp (`times.rs`).

pub mod bench;
mod claim;
mod conclude;
mod error;
mod finish;
mod images;
mod integrity;
mod jobs;
mod pipeline;
mod prepare;
mod psfs;
mod readme;
mod shard;
mod shared;
mod sidecar;
mod space;
mod times;

pub use claim::{Claim, SeedUse};
pub use conclude::{SHARD_MARKER_FORMAT, ShardMarker};
pub use error::GenerateError;
pub use finish::{Finished, finish};
pub use integrity::OUTPUT_VERSION;
pub use jobs::{Job, blinding_key, config_sha256, jobs};
pub use readme::participants_readme;
pub use shard::{AutoShardError, BadShard, SLURM_ARRAY_VARS, Shard};
pub use shared::{datasets_json, instrument_facts};
pub use sidecar::{Sidecar, verify};

use crate::run::plan::Plan;
use conclude::{Concluded, conclude, stray_temporaries};
use images::make_images;
use prepare::{find_pending, make_dataset_dirs, refuse_foreign_or_undo_claim};
use psfs::{Psfs, build_psfs};
use shared::write_shared;
use sidecar::Made;
use space::check_space;
use std::path::{Path, PathBuf};
use stepsim_contract::run_dir::RunDir;

/// Options of a run besides the config.
#[derive(Debug, Clone, Default)]
pub struct Options {
    /// Which share of the images to make.
    pub shard: Shard,
    /// The submission-format paragraph of the participants' README
    /// (default [`stepsim_contract::SUBMISSION_FORMAT_MD`]).
    pub submission_format: Option<String>,
    /// The space the run is checked against once its PSFs are solved,
    /// before the first image is written (`None`: not checked).
    pub disk: Option<crate::run::disk::DiskSpace>,
}

/// What the run reports while it works (for a progress bar).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// Work starts: `pending` images to make, `done` already verified.
    Start {
        /// Images this process will make.
        pending: usize,
        /// Images of this shard found finished and verified.
        done: usize,
    },
    /// PSFs are about to be built: `total` of them.
    PsfsStart {
        /// PSFs this process builds.
        total: usize,
    },
    /// One PSF is ready (`done` of `total`): built, or reused from the
    /// run's store (`origin`).
    PsfBuilt {
        /// Its name in the config.
        name: String,
        /// PSFs ready so far.
        done: usize,
        /// PSFs this process needs.
        total: usize,
        /// How it came: built, reused from `private/psf/cache/`, stored
        /// there, or rebuilt because the stored file was unusable.
        origin: crate::io::psf_store::Origin,
    },
    /// One image was written.
    ImageWritten,
}

/// What a run did.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// How the seed was chosen (given, drawn now, or adopted from the run
    /// found in the directory).
    pub seed: SeedUse,
    /// True when a stale `public/manifest.json` was removed (an image of the
    /// run was unfinished or damaged).
    pub removed_manifest: bool,
    /// Images in the whole run.
    pub total: usize,
    /// Images of this shard.
    pub in_shard: usize,
    /// Images written by this process.
    pub written: usize,
    /// Images of this shard found finished and verified (skipped).
    pub skipped: usize,
    /// Images of the whole run finished (sidecar present) at the end.
    pub finished: usize,
    /// True when `public/manifest.json` was written (a whole run, every
    /// image finished; a shard of several never writes it).
    pub manifest_written: bool,
    /// The done-marker this shard wrote (shards of N > 1 only).
    pub marker: Option<PathBuf>,
    /// Temporary files of killed writers removed at the start.
    pub removed_tmp: Vec<PathBuf>,
    /// PSFs this process loaded from the run's store
    /// (`private/psf/cache/`) instead of building them.
    pub psfs_reused: usize,
    /// PSFs this process built (stored or not; rebuilt ones included).
    pub psfs_built: usize,
    /// Temporary files (`*.tmp`) still under the run directory at the end:
    /// being written by another shard right now, or not ours.
    pub stray_tmp: Vec<PathBuf>,
    /// What the whole run writes ([`crate::run::disk::generate_estimate`]), with
    /// the sides of the PSFs this process solved and the store's files.
    pub disk_estimate: crate::run::memory::MemoryEstimate,
}

/// Makes (this shard's share of) the run described by `plan` in `out`.
/// Parallel in the current rayon pool; `progress` is told what happens.
///
/// Order of work: preflight (nothing written), claim `private/config.json`
/// (adopting the existing run's seed when `plan`'s was drawn), refuse foreign
/// files and sidecars, verify this shard's images, remove a stale manifest,
/// create the dataset directories in the order of their ids, then build the
/// PSFs and make the pending images.
pub fn generate(
    plan: &Plan,
    out: &Path,
    options: &Options,
    progress: &(dyn Fn(Event) + Sync),
) -> Result<Summary, GenerateError> {
    let run = RunDir::new(out);
    // Everything that could fail before drawing is checked before writing.
    crate::model::population::preflight(&plan.population()).map_err(GenerateError::Preflight)?;
    let claim = claim::claim(plan, out)?;
    let plan = &claim.plan;
    let config_sha256 = config_sha256(plan);
    let key = blinding_key(plan);
    let all = jobs(plan, &key)?;
    refuse_foreign_or_undo_claim(plan, &run, &key, &all, claim.created)?;
    let removed_tmp = stepsim_contract::io::remove_stale_temporaries(out);
    let work = find_pending(plan, &run, &all, options.shard, &config_sha256)?;
    make_dataset_dirs(&run, &all)?;
    let psfs = build_psfs(plan, &run, &work, progress)?;
    let disk_estimate = check_space(plan, &run, &psfs, options, out)?;
    progress(Event::Start {
        pending: work.pending.len(),
        done: work.mine.len() - work.pending.len(),
    });
    let shared = || write_shared(plan, &run, &key, &all, options, &psfs.renderers);
    make_images(
        plan,
        &run,
        &work.pending,
        &psfs,
        &config_sha256,
        shared,
        progress,
    )?;
    let Concluded {
        finished,
        manifest_written,
        marker,
    } = conclude(plan, &run, &all, &work.mine, options.shard, &config_sha256)?;
    let stray_tmp = stray_temporaries(out);
    Ok(Summary {
        seed: claim.seed,
        removed_manifest: work.removed_manifest,
        total: all.len(),
        in_shard: work.mine.len(),
        written: work.pending.len(),
        skipped: work.mine.len() - work.pending.len(),
        finished,
        manifest_written,
        marker,
        removed_tmp,
        stray_tmp,
        psfs_reused: psfs.reused,
        psfs_built: psfs.renderers.len() - psfs.reused,
        disk_estimate,
    })
}

#[cfg(test)]
mod tests;
