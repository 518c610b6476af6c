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
//! A run first claims its directory ([`claim`]: `private/config.json` is
//! created, never replaced) and refuses any file another run left there
//! ([`integrity`]). Images are made field by field (the base field is drawn
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
//! giving all of `public/` one time stamp ([`times`]).

pub mod bench;
pub mod claim;
pub mod integrity;
pub mod pipeline;
mod readme;
mod shard;
pub mod times;

pub use claim::{Claim, SeedUse};
pub use integrity::OUTPUT_VERSION;
pub use readme::participants_readme;
pub use shard::{AutoShardError, BadShard, SLURM_ARRAY_VARS, Shard};

use crate::model::noise::Detector;
use crate::model::render::Renderer;
use crate::run::blind::BlindingKey;
use crate::run::plan::Plan;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use stepsim_contract::digest::sha256_hex;
use stepsim_contract::io::{IoError, write_bytes_atomically};
use stepsim_contract::run_dir::{PublicDir, RunDir};
use stepsim_contract::run_layout::{
    DATASETS_FORMAT, DatasetEntry, DatasetImage, Datasets, InstrumentFacts, MANIFEST_FORMAT,
    Manifest, ManifestImage,
};
use stepsim_contract::seed::{SeedKey, Stream};
use stepsim_contract::truth::TruthRow;

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

/// The done-marker `private/shards/K-of-N.json` a shard writes when every
/// image it owns is written and verified.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShardMarker {
    /// [`SHARD_MARKER_FORMAT`].
    pub format: String,
    /// The shard, `K/N`.
    pub shard: String,
    /// SHA-256 of the run's `private/config.json`.
    pub config_sha256: String,
    /// [`OUTPUT_VERSION`] of the stepsim that made the files.
    pub output_version: u32,
    /// The images the shard owns, all finished and verified, sorted by id.
    pub images: Vec<String>,
}

/// `format` of a [`ShardMarker`].
pub const SHARD_MARKER_FORMAT: &str = "stepsim-shard-1";

/// One image of the run.
#[derive(Debug, Clone, PartialEq)]
pub struct Job {
    /// Position in the canonical order (for sharding).
    pub order: usize,
    /// Base field.
    pub field: u32,
    /// 90°-rotated twin of the base field.
    pub rotated: bool,
    /// Dataset index in [`Plan::datasets`].
    pub dataset: u32,
    /// Opaque dataset id.
    pub dataset_id: String,
    /// Opaque image id.
    pub image_id: String,
}

impl Job {
    /// Image path relative to `public/`.
    pub fn public_file(&self) -> String {
        PublicDir::image_file(&self.dataset_id, &self.image_id)
    }
    /// Key of the image's noise.
    pub fn noise_key(&self, run_seed: u64) -> SeedKey {
        SeedKey::image(run_seed, self.field, self.dataset, Stream::Noise)
            .with_index(u64::from(self.rotated))
    }
}

/// The blinding key of a run: from its seed and resolved config
/// ([`BlindingKey::for_run`] of [`claim::config_json`]).
pub fn blinding_key(plan: &Plan) -> BlindingKey {
    BlindingKey::for_run(plan.seed(), claim::config_json(plan).as_bytes())
}

/// SHA-256 of a run's `private/config.json` (recorded in every sidecar).
pub fn config_sha256(plan: &Plan) -> String {
    sha256_hex(claim::config_json(plan).as_bytes())
}

/// Every image of a plan in canonical order, with its opaque ids.
pub fn jobs(plan: &Plan, key: &BlindingKey) -> Result<Vec<Job>, GenerateError> {
    let rotations: &[bool] = if plan.rotated_pairs() {
        &[false, true]
    } else {
        &[false]
    };
    let dataset_ids: Vec<String> = plan
        .datasets()
        .iter()
        .map(|d| key.dataset_id(d.index))
        .collect();
    let mut out = Vec::new();
    for field in 0..plan.n_fields() {
        for &rotated in rotations {
            for d in plan.datasets().iter().filter(|d| d.fields.contains(&field)) {
                out.push(Job {
                    order: out.len(),
                    field,
                    rotated,
                    dataset: d.index,
                    dataset_id: dataset_ids[d.index as usize].clone(),
                    image_id: key.image_id(d.index, field, rotated),
                });
            }
        }
    }
    let mut seen = std::collections::HashSet::new();
    for id in dataset_ids.iter().chain(out.iter().map(|j| &j.image_id)) {
        if !seen.insert(id.as_str()) {
            return Err(GenerateError::IdCollision { id: id.clone() });
        }
    }
    Ok(out)
}

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
    /// [`OUTPUT_VERSION`] of the stepsim that made the files.
    pub output_version: u32,
}

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
    let paths = RunDir::new(out);
    // Everything that could fail before drawing is checked before writing.
    crate::model::population::preflight(&plan.population()).map_err(GenerateError::Preflight)?;
    let claim = claim::claim(plan, out)?;
    let plan = &claim.plan;
    let config_sha256 = config_sha256(plan);
    let key = blinding_key(plan);
    let all = jobs(plan, &key)?;
    refuse_foreign_or_undo_claim(plan, &paths, &key, &all, claim.created)?;
    let removed_tmp = stepsim_contract::io::remove_stale_temporaries(out);
    let work = find_pending(plan, &paths, &all, options.shard, &config_sha256)?;
    make_dataset_dirs(&paths, &all)?;
    let psfs = build_psfs(plan, &paths, &work, progress)?;
    let disk_estimate =
        crate::run::disk::generate_estimate(plan, Some(&solved_psfs(plan, &paths, &psfs)));
    if let Some(d) = &options.disk {
        crate::run::disk::check(
            &out.display().to_string(),
            disk_estimate.clone(),
            d.present_bytes,
            d.free.clone(),
        )
        .map_err(Box::new)?;
    }
    progress(Event::Start {
        pending: work.pending.len(),
        done: work.mine.len() - work.pending.len(),
    });
    let shared = || write_shared(plan, &paths, &key, &all, options, &psfs.renderers);
    make_images(
        plan,
        &paths,
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
    } = conclude(
        plan,
        &paths,
        &all,
        &work.mine,
        options.shard,
        &config_sha256,
    )?;
    let mut stray_tmp = Vec::new();
    find_tmp(out, &mut stray_tmp);
    stray_tmp.sort();
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

/// What the solved PSFs write: the side of each one's file (those this
/// process built) and the bytes of the run's store files.
fn solved_psfs(plan: &Plan, paths: &RunDir, psfs: &Psfs) -> crate::run::disk::SolvedPsfs {
    use crate::io::psf_store::{file_for, is_stored};
    let scale = plan.pixel_scale_arcsec();
    let max_stamp = plan.accuracy().max_stamp_px;
    let file_side_px = psfs
        .renderers
        .iter()
        .map(|(p, r)| {
            let side = crate::io::psf_fits::renderer_side_px(r.psf().as_ref(), scale, max_stamp);
            (*p, side)
        })
        .collect();
    let accuracy = crate::model::psf::PsfAccuracy::default();
    let files: std::collections::BTreeSet<PathBuf> = plan
        .psf_specs()
        .iter()
        .filter(|spec| is_stored(spec))
        .map(|spec| file_for(&paths.private().psf_cache(), spec, &accuracy))
        .collect();
    let store_bytes = files
        .iter()
        .filter_map(|f| std::fs::metadata(f).ok())
        .map(|m| m.len())
        .sum();
    crate::run::disk::SolvedPsfs {
        file_side_px,
        store_bytes,
    }
}

/// Refuses files and shared contents another run left in the directory,
/// and keeps the run's copies of its inputs ([`integrity::keep_inputs`]); a
/// claim made just now is undone on failure.
fn refuse_foreign_or_undo_claim(
    plan: &Plan,
    paths: &RunDir,
    key: &BlindingKey,
    all: &[Job],
    claimed_now: bool,
) -> Result<(), GenerateError> {
    let checked = integrity::refuse_foreign_files(plan, paths, all)
        .and_then(|()| integrity::refuse_other_contents(&private_shared(plan, paths, key, all)))
        .and_then(|()| integrity::keep_inputs(plan, paths));
    if checked.is_err() && claimed_now {
        let _ = std::fs::remove_file(paths.private().config());
    }
    checked
}

/// This process's share of a run and what is left of it.
struct Work<'a> {
    /// The images of this shard.
    mine: Vec<&'a Job>,
    /// Those not found finished and verified.
    pending: Vec<&'a Job>,
    /// True when a stale manifest was removed.
    removed_manifest: bool,
}

/// Resume: reads every sidecar (refusing foreign ones), verifies this
/// shard's images against theirs (read only), and removes a manifest that
/// would list an image missing or damaged (other shards' images count as
/// finished when their sidecar and file exist).
fn find_pending<'a>(
    plan: &Plan,
    paths: &RunDir,
    all: &'a [Job],
    shard: Shard,
    config_sha256: &str,
) -> Result<Work<'a>, GenerateError> {
    let sides: Vec<Option<Sidecar>> = all
        .par_iter()
        .map(|j| integrity::read_sidecar(paths, j, config_sha256))
        .collect::<Result<_, _>>()?;
    let want_model = plan.output().write_model;
    let mine: Vec<&Job> = all.iter().filter(|j| shard.owns(j.order)).collect();
    let done: Vec<bool> = mine
        .par_iter()
        .map(|j| {
            sides[j.order]
                .as_ref()
                .is_some_and(|s| verify_files(paths, j, s, want_model))
        })
        .collect();
    let pending: Vec<&Job> = mine
        .iter()
        .zip(&done)
        .filter(|(_, d)| !**d)
        .map(|(j, _)| *j)
        .collect();
    let unfinished = !pending.is_empty()
        || all.iter().any(|j| {
            sides[j.order].is_none() || !paths.public().image(&j.dataset_id, &j.image_id).is_file()
        });
    let manifest_path = paths.public().manifest();
    let removed_manifest = unfinished && manifest_path.exists();
    if removed_manifest {
        std::fs::remove_file(&manifest_path).map_err(|e| IoError::os(&manifest_path, e))?;
    }
    Ok(Work {
        mine,
        pending,
        removed_manifest,
    })
}

/// The PSFs of a process, each built once, and their renderers.
struct Psfs {
    /// Renderer (and so PSF) of each PSF index built.
    renderers: BTreeMap<usize, Renderer>,
    /// The detector of every image.
    det: Detector,
    /// How many were loaded from the run's store.
    reused: usize,
}

/// Builds the PSFs this process needs: those of its pending images, and
/// those whose `private/psf/` file is missing (`output.write_psf`).
fn build_psfs(
    plan: &Plan,
    paths: &RunDir,
    work: &Work,
    progress: &(dyn Fn(Event) + Sync),
) -> Result<Psfs, GenerateError> {
    let ds = plan.datasets();
    let mut needed: Vec<usize> = work
        .pending
        .iter()
        .map(|j| ds[j.dataset as usize].psf)
        .collect();
    if plan.output().write_psf {
        for j in &work.mine {
            let p = ds[j.dataset as usize].psf;
            if !paths.private().psf(plan.psf_name(p)).exists() {
                needed.push(p);
            }
        }
    }
    needed.sort_unstable();
    needed.dedup();
    let det = plan.detector();
    let mut out = Psfs {
        renderers: BTreeMap::new(),
        det,
        reused: 0,
    };
    progress(Event::PsfsStart {
        total: needed.len(),
    });
    for &p in &needed {
        let psf_err = |source| GenerateError::Psf {
            index: p,
            name: plan.psf_name(p).to_string(),
            source,
        };
        let (_, origin) =
            plan.psf_in_store(p, &paths.private().psf_cache())
                .map_err(|e| match e {
                    crate::io::psf_store::StoreError::Psf(source) => psf_err(source),
                    crate::io::psf_store::StoreError::Io(e) => GenerateError::Io(e),
                })?;
        let origin = origin.unwrap_or(crate::io::psf_store::Origin::Built);
        out.reused += usize::from(matches!(
            origin,
            crate::io::psf_store::Origin::Reused { .. }
                | crate::io::psf_store::Origin::Copied { .. }
        ));
        let renderer = plan.renderer(p).map_err(psf_err)?;
        out.renderers.insert(p, renderer);
        progress(Event::PsfBuilt {
            name: plan.psf_name(p).to_string(),
            done: out.renderers.len(),
            total: needed.len(),
            origin,
        });
    }
    Ok(out)
}

/// Makes the pending images field by field: each base field (and its
/// rotated twin) is drawn once for all the datasets' images of the field.
/// Within a field, images are written in the order of their opaque ids
/// (keyed by the blinding secret), so that no write order follows the
/// datasets. `write_shared` runs once, after the first base field is drawn
/// (or at the end when nothing is pending).
fn make_images(
    plan: &Plan,
    paths: &RunDir,
    pending: &[&Job],
    psfs: &Psfs,
    config_sha256: &str,
    write_shared: impl Fn() -> Result<(), GenerateError>,
    progress: &(dyn Fn(Event) + Sync),
) -> Result<(), GenerateError> {
    let mut jobs: Vec<&Job> = pending.to_vec();
    jobs.sort_by(|a, b| (a.field, &a.image_id).cmp(&(b.field, &b.image_id)));
    let fields = FieldPopulations::new(plan, &jobs);
    // The first field is drawn before anything is written, so that a
    // population error leaves the run as it was.
    if let Some(first) = jobs.first() {
        fields.get(first.field).map_err(|e| {
            e.unwrap_or_else(|| {
                IoError::format(
                    paths.private().path(),
                    "the population of the first field could not be drawn",
                )
                .into()
            })
        })?;
    }
    write_shared()?;
    let made = Made { config_sha256 };
    let cx = pipeline::Context {
        plan,
        paths,
        det: &psfs.det,
        made: &made,
    };
    // One lane per thread; each lane takes the next image until none is
    // left and runs its images one after another, so at most `lanes` images
    // are in flight. (A thread waiting inside an image's parallel loop may
    // steal a lane that has not started yet, and run it to the end with the
    // waiting image kept; the count in flight stays at most `lanes`.) Unlike
    // fixed batches, a lane does not wait for the others: the serial parts
    // of an image (its files) overlap with the other lanes' parallel stages.
    let lanes = rayon::current_num_threads().clamp(1, jobs.len().max(1));
    let next = AtomicUsize::new(0);
    let made = AtomicUsize::new(0);
    let failed = Mutex::new(None::<GenerateError>);
    (0..lanes).into_par_iter().for_each(|_| {
        while failed.lock().is_ok_and(|f| f.is_none()) {
            let i = next.fetch_add(1, Ordering::Relaxed);
            let Some(job) = jobs.get(i) else { return };
            let done = (|| {
                // Draw the field `lanes` images ahead now if no lane has yet
                // (this lane stays busy; the others need not wait for it).
                if let Some(ahead) = jobs.get(i + lanes) {
                    fields.draw_ahead(ahead.field)?;
                }
                let population = fields.get(job.field)?;
                let rows = match (&population.twin, job.rotated) {
                    (Some(twin), true) => twin,
                    _ => &population.base,
                };
                let renderer = &psfs.renderers[&plan.datasets()[job.dataset as usize].psf];
                let mut lap = pipeline::Lap::start(false);
                let mut times = pipeline::StageTimes::default();
                pipeline::make_image(&cx, job, rows, renderer, &mut lap, &mut times)
                    .map_err(Some)?;
                fields.finished(job.field);
                made.fetch_add(1, Ordering::Relaxed);
                progress(Event::ImageWritten);
                Ok::<(), Option<GenerateError>>(())
            })();
            if let Err(e) = done {
                // `None`: a population another lane failed to draw; that
                // lane (or the first to see it) reports the error.
                if let (Some(e), Ok(mut f)) = (e, failed.lock()) {
                    f.get_or_insert(e);
                }
                return;
            }
        }
    });
    match failed.into_inner().unwrap_or_else(|p| p.into_inner()) {
        Some(e) => Err(e),
        // Every lane stopped without an error: every image must be made.
        None if made.into_inner() == jobs.len() => Ok(()),
        None => Err(IoError::format(
            paths.public().path(),
            "an image worker stopped before its images were written; run generate again to finish them",
        )
        .into()),
    }
}

/// The base field (and its 90°-rotated twin when a pending image needs it)
/// of every field with pending images, shared by all of that field's images
/// and dropped after the last. Nothing here blocks a pool thread (which
/// could deadlock if drawing ever used the pool itself): a lane that needs a
/// population nobody has finished draws it (the draw is deterministic, so a
/// second copy is the same rows) and the first copy stored wins; a lane
/// drawing ahead skips a field another lane is already drawing.
struct FieldPopulations<'a> {
    plan: &'a Plan,
    fields: Mutex<BTreeMap<u32, FieldEntry>>,
}

struct FieldEntry {
    /// Images of the field still to make.
    remaining: usize,
    /// Whether one of them is a rotated twin.
    twin: bool,
    /// Whether a lane has started drawing the population.
    claimed: Arc<AtomicBool>,
    /// The population once drawn (`None`: drawing it failed).
    population: Arc<PopulationCell>,
}

/// A field's population once drawn (`None` inside: drawing it failed).
type PopulationCell = OnceLock<Option<Arc<Population>>>;

struct Population {
    base: Vec<TruthRow>,
    twin: Option<Vec<TruthRow>>,
}

impl<'a> FieldPopulations<'a> {
    fn new(plan: &'a Plan, jobs: &[&Job]) -> Self {
        let mut fields: BTreeMap<u32, FieldEntry> = BTreeMap::new();
        for j in jobs {
            let e = fields.entry(j.field).or_insert_with(|| FieldEntry {
                remaining: 0,
                twin: false,
                claimed: Arc::default(),
                population: Arc::default(),
            });
            e.remaining += 1;
            e.twin |= j.rotated;
        }
        Self {
            plan,
            fields: Mutex::new(fields),
        }
    }

    /// The entry of `field` (`None`: no image of it is pending).
    fn entry(&self, field: u32) -> Option<(Arc<AtomicBool>, Arc<PopulationCell>, bool)> {
        let fields = self.fields.lock().ok()?;
        let e = fields.get(&field)?;
        Some((e.claimed.clone(), e.population.clone(), e.twin))
    }

    /// Draws the population of `field` and stores it unless another copy
    /// was stored first. `Err` carries this draw's own error.
    fn draw(&self, field: u32, twin: bool, cell: &PopulationCell) -> Result<(), GenerateError> {
        match crate::model::population::base_field(&self.plan.population(), field) {
            Ok(base) => {
                let twin = twin.then(|| crate::model::population::rotated(&base));
                let _ = cell.set(Some(Arc::new(Population { base, twin })));
                Ok(())
            }
            Err(source) => {
                let _ = cell.set(None);
                Err(GenerateError::Population { field, source })
            }
        }
    }

    /// The population of `field`, drawn now if no lane has finished drawing
    /// it. `Err(None)`: it could not be drawn and a lane that drew it
    /// reports why.
    fn get(&self, field: u32) -> Result<Arc<Population>, Option<GenerateError>> {
        let (claimed, cell, twin) = self.entry(field).ok_or(None)?;
        if cell.get().is_none() {
            claimed.store(true, Ordering::Relaxed);
            self.draw(field, twin, &cell).map_err(Some)?;
        }
        match cell.get() {
            Some(Some(p)) => Ok(p.clone()),
            _ => Err(None),
        }
    }

    /// Draws the population of `field` if no lane has started to. A field
    /// whose images are all made has nothing to draw.
    fn draw_ahead(&self, field: u32) -> Result<(), Option<GenerateError>> {
        let Some((claimed, cell, twin)) = self.entry(field) else {
            return Ok(());
        };
        if claimed.swap(true, Ordering::Relaxed) {
            return Ok(());
        }
        self.draw(field, twin, &cell).map_err(Some)
    }

    /// One image of `field` is made; after its last, the population goes.
    fn finished(&self, field: u32) {
        if let Ok(mut fields) = self.fields.lock()
            && let Some(e) = fields.get_mut(&field)
        {
            e.remaining -= 1;
            if e.remaining == 0 {
                fields.remove(&field);
            }
        }
    }
}

/// What [`conclude`] did.
struct Concluded {
    /// Images of the run finished (sidecar and public file present).
    finished: usize,
    /// Whether this process wrote `public/manifest.json`.
    manifest_written: bool,
    /// The shard's done-marker, for a shard of several.
    marker: Option<PathBuf>,
}

/// Completion: a shard of several writes its done-marker, a whole run its
/// manifest when every image is finished; then `public/` gets the run's time
/// stamp.
fn conclude(
    plan: &Plan,
    paths: &RunDir,
    all: &[Job],
    mine: &[&Job],
    shard: Shard,
    config_sha256: &str,
) -> Result<Concluded, GenerateError> {
    let out = if shard.n > 1 {
        let marker = write_marker(paths, shard, mine, config_sha256)?;
        Concluded {
            finished: count_finished(paths, all, config_sha256)?,
            manifest_written: false,
            marker: Some(marker),
        }
    } else {
        write_manifest_if_complete(plan, paths, all, config_sha256)?
    };
    times::normalise(
        paths.public().path(),
        times::run_instant(&paths.private().config())?,
    )?;
    Ok(out)
}

/// Writes the done-marker of `shard` (atomically) and returns its path.
fn write_marker(
    paths: &RunDir,
    shard: Shard,
    mine: &[&Job],
    config_sha256: &str,
) -> Result<PathBuf, GenerateError> {
    let mut images: Vec<String> = mine.iter().map(|j| j.image_id.clone()).collect();
    images.sort();
    let marker = ShardMarker {
        format: SHARD_MARKER_FORMAT.into(),
        shard: shard.to_string(),
        config_sha256: config_sha256.into(),
        output_version: OUTPUT_VERSION,
        images,
    };
    let path = paths.private().shard_marker(shard.k, shard.n);
    let text = serde_json::to_string_pretty(&marker).expect("marker serialises") + "\n";
    write_bytes_atomically(&path, text.as_bytes())?;
    Ok(path)
}

/// Images of the run whose sidecar and public file are present.
fn count_finished(
    paths: &RunDir,
    all: &[Job],
    config_sha256: &str,
) -> Result<usize, GenerateError> {
    let mut n = 0;
    for j in all {
        if integrity::read_sidecar(paths, j, config_sha256)?.is_some()
            && paths.public().image(&j.dataset_id, &j.image_id).is_file()
        {
            n += 1;
        }
    }
    Ok(n)
}

/// What [`finish`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct Finished {
    /// How the seed was chosen (adopted, for a config without `run.seed`).
    pub seed: SeedUse,
    /// Images in the run, all verified.
    pub total: usize,
    /// Done-markers found under `private/shards` (file names, sorted).
    pub markers: Vec<String>,
}

/// Finishes a run made in shards: verifies every image (sidecar of this
/// run, every file with its recorded SHA-256, as a resume does), then writes
/// `public/manifest.json` and gives `public/` the run's time stamp. When an
/// image is missing or fails verification nothing is written and the images
/// are listed ([`GenerateError::Incomplete`]), with the shards to rerun when
/// the done-markers name one shard count. Parallel in the current rayon pool.
///
/// Whenever it fails after joining the run (an image missing or altered, a
/// foreign file, an unreadable sidecar), a `public/manifest.json` already
/// there (from an earlier `--finish` or whole run) is removed: it would
/// claim a run that is no longer what it says. A config that is not the
/// run's is refused before, and touches nothing.
pub fn finish(plan: &Plan, out: &Path) -> Result<Finished, GenerateError> {
    let paths = RunDir::new(out);
    if !paths.private().config().is_file() {
        return Err(GenerateError::NoRun {
            path: paths.private().config(),
        });
    }
    let claim = claim::claim(plan, out)?;
    match finish_claimed(&claim, &paths, out) {
        Ok(f) => Ok(f),
        Err(e) => {
            let manifest = paths.public().manifest();
            let removed = match std::fs::remove_file(&manifest) {
                Ok(()) => true,
                Err(r) if r.kind() == std::io::ErrorKind::NotFound => false,
                Err(r) => return Err(IoError::os(&manifest, r).into()),
            };
            Err(match e {
                GenerateError::Incomplete {
                    run,
                    missing,
                    total,
                    rerun,
                    ..
                } => GenerateError::Incomplete {
                    run,
                    missing,
                    total,
                    rerun,
                    removed_manifest: removed,
                },
                e => e,
            })
        }
    }
}

/// [`finish`] once the run is joined.
fn finish_claimed(
    claim: &claim::Claim,
    paths: &RunDir,
    out: &Path,
) -> Result<Finished, GenerateError> {
    let plan = &claim.plan;
    let config_sha256 = config_sha256(plan);
    let key = blinding_key(plan);
    let all = jobs(plan, &key)?;
    integrity::refuse_foreign_files(plan, paths, &all)?;
    integrity::refuse_other_contents(&private_shared(plan, paths, &key, &all))?;
    integrity::keep_inputs(plan, paths)?;
    let want_model = plan.output().write_model;
    let ok: Vec<bool> = all
        .par_iter()
        .map(|j| verify(paths, j, want_model, &config_sha256))
        .collect::<Result<_, _>>()?;
    let markers = marker_names(paths)?;
    let missing: Vec<&Job> = all.iter().filter(|j| !ok[j.order]).collect();
    let readme = paths.public().readme();
    if missing.is_empty() && !readme.is_file() {
        return Err(IoError::format(
            &readme,
            "missing: no shard finished writing the shared files; rerun any shard",
        )
        .into());
    }
    if !missing.is_empty() {
        let counts: std::collections::BTreeSet<u32> = markers
            .iter()
            .filter_map(|m| m.strip_suffix(".json")?.split_once("-of-")?.1.parse().ok())
            .collect();
        let rerun: Vec<Shard> = match counts.iter().collect::<Vec<_>>()[..] {
            [&n] => {
                let mut ks: Vec<u32> = missing
                    .iter()
                    .map(|j| (j.order % n as usize) as u32 + 1)
                    .collect();
                ks.sort_unstable();
                ks.dedup();
                ks.into_iter().map(|k| Shard { k, n }).collect()
            }
            _ => Vec::new(),
        };
        return Err(GenerateError::Incomplete {
            run: out.into(),
            missing: missing.iter().map(|j| j.public_file()).collect(),
            total: all.len(),
            rerun,
            removed_manifest: false,
        });
    }
    let done = write_manifest_if_complete(plan, paths, &all, &config_sha256)?;
    debug_assert!(done.manifest_written);
    times::normalise(
        paths.public().path(),
        times::run_instant(&paths.private().config())?,
    )?;
    Ok(Finished {
        seed: claim.seed,
        total: all.len(),
        markers,
    })
}

/// The done-markers' file names under `private/shards`, sorted.
fn marker_names(paths: &RunDir) -> Result<Vec<String>, IoError> {
    let dir = paths.private().shards_dir();
    let entries = match std::fs::read_dir(&dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(IoError::os(&dir, e)),
    };
    let mut out = Vec::new();
    for e in entries {
        let name = e.map_err(|e| IoError::os(&dir, e))?.file_name();
        let name = name.to_string_lossy().into_owned();
        if name.ends_with(".json") && !name.starts_with('.') {
            out.push(name);
        }
    }
    out.sort();
    Ok(out)
}

/// What made an image's files (recorded in its sidecar).
pub(crate) struct Made<'a> {
    pub(crate) config_sha256: &'a str,
}

/// Creates `public/<dataset-id>/` for every dataset, in the order of the ids
/// (so that neither inode numbers nor creation order follow the datasets).
fn make_dataset_dirs(paths: &RunDir, all: &[Job]) -> Result<(), IoError> {
    let mut ids: Vec<&str> = all.iter().map(|j| j.dataset_id.as_str()).collect();
    ids.sort_unstable();
    ids.dedup();
    for id in ids {
        let dir = paths.public().dataset(id);
        std::fs::create_dir_all(&dir).map_err(|e| IoError::os(&dir, e))?;
    }
    Ok(())
}

/// True when the image's sidecar is this run's and every file it lists is on
/// disk with the recorded SHA-256 (a foreign sidecar is an error: see
/// [`integrity::read_sidecar`]).
pub fn verify(
    paths: &RunDir,
    job: &Job,
    want_model: bool,
    config_sha256: &str,
) -> Result<bool, GenerateError> {
    Ok(integrity::read_sidecar(paths, job, config_sha256)?
        .is_some_and(|side| verify_files(paths, job, &side, want_model)))
}

/// True when every file `side` lists is on disk with the recorded SHA-256.
fn verify_files(paths: &RunDir, job: &Job, side: &Sidecar, want_model: bool) -> bool {
    let same = |path: &Path, want: &str| std::fs::read(path).is_ok_and(|b| sha256_hex(&b) == want);
    side.image == job.image_id
        && side.file == job.public_file()
        && same(
            &paths.public().image(&job.dataset_id, &job.image_id),
            &side.sha256,
        )
        && same(&paths.private().truth(&job.image_id), &side.truth_sha256)
        && match (&side.model_sha256, want_model) {
            (Some(m), true) => same(&paths.private().model(&job.image_id), m),
            (None, false) => true,
            _ => false,
        }
}

/// The files every shard writes identically: datasets, blinding key,
/// participants' README, and the PSFs this process built (the resolved config
/// was written first, by [`claim::claim`]).
fn write_shared(
    plan: &Plan,
    paths: &RunDir,
    key: &BlindingKey,
    all: &[Job],
    options: &Options,
    renderers: &BTreeMap<usize, Renderer>,
) -> Result<(), GenerateError> {
    for (path, bytes) in private_shared(plan, paths, key, all) {
        write_bytes_atomically(&path, bytes.as_bytes())?;
    }
    let para = options
        .submission_format
        .as_deref()
        .unwrap_or(stepsim_contract::SUBMISSION_FORMAT_MD);
    write_bytes_atomically(
        &paths.public().readme(),
        participants_readme(plan, para).as_bytes(),
    )?;
    if plan.output().write_psf {
        for (p, renderer) in renderers {
            let name = plan.psf_name(*p);
            write_psf_file(
                &paths.private().psf(name),
                renderer.psf(),
                name,
                plan.pixel_scale_arcsec(),
                plan.accuracy().max_stamp_px,
            )?;
        }
    }
    Ok(())
}

/// Writes `private/psf/<name>.fits`: the pixel-scale image and the
/// oversampled one, with the measured report in the header (the same file
/// `stepsim psf` writes, at its default sizes: the extent the renderer
/// gives the PSF).
fn write_psf_file(
    path: &Path,
    psf: &Arc<dyn crate::model::psf::Psf>,
    name: &str,
    pixel_scale_arcsec: f64,
    max_stamp_px: usize,
) -> Result<(), IoError> {
    use crate::io::psf_fits::{DEFAULT_OVERSAMPLE, renderer_side_px, write_psf};
    let report = crate::model::psf::report(name, psf.as_ref(), pixel_scale_arcsec)
        .map_err(|e| IoError::format(path, e.to_string()))?;
    let drawn = crate::model::psf::draw_for_file(
        name,
        psf.as_ref(),
        pixel_scale_arcsec,
        renderer_side_px(psf.as_ref(), pixel_scale_arcsec, max_stamp_px),
        DEFAULT_OVERSAMPLE,
        Some(report),
    );
    write_psf(path, &drawn)
}

/// The private files every process of a run writes identically:
/// `blinding.key` and `datasets.json` (path, content).
fn private_shared(
    plan: &Plan,
    paths: &RunDir,
    key: &BlindingKey,
    all: &[Job],
) -> [(PathBuf, String); 2] {
    let datasets = datasets_json(plan, all);
    [
        (
            paths.private().blinding_key(),
            format!("{}\n", key.to_hex()),
        ),
        (
            paths.private().datasets(),
            serde_json::to_string_pretty(&datasets).expect("datasets serialise") + "\n",
        ),
    ]
}

/// `private/datasets.json` of a run.
pub fn datasets_json(plan: &Plan, all: &[Job]) -> Datasets {
    let img = &plan.geometry();
    Datasets {
        format: DATASETS_FORMAT.into(),
        width_px: img.width_px,
        height_px: img.height_px,
        pixel_scale_arcsec: img.pixel_scale_arcsec,
        datasets: plan
            .datasets()
            .iter()
            .map(|d| {
                let images: Vec<&Job> = all.iter().filter(|j| j.dataset == d.index).collect();
                DatasetEntry {
                    dataset: images
                        .first()
                        .map(|j| j.dataset_id.clone())
                        .unwrap_or_default(),
                    psf_id: d.psf as u32,
                    psf: plan.psf_name(d.psf).to_string(),
                    g1: d.g1,
                    g2: d.g2,
                    images: images
                        .iter()
                        .map(|j| DatasetImage {
                            image: j.image_id.clone(),
                            field: j.field,
                            rotated: j.rotated,
                        })
                        .collect(),
                    part: d.part,
                }
            })
            .collect(),
    }
}

/// The public instrument facts of a plan.
pub fn instrument_facts(plan: &Plan) -> InstrumentFacts {
    let (img, ins) = (&plan.geometry(), &plan.instrument());
    InstrumentFacts {
        width_px: img.width_px,
        height_px: img.height_px,
        pixel_scale_arcsec: img.pixel_scale_arcsec,
        gain_e_per_adu: ins.gain_e_per_adu,
        read_noise_e: ins.read_noise_e,
        saturation_adu: ins.saturation_adu,
        exposure_s: ins.exposure_s,
        zeropoint_mag: ins.zeropoint_mag,
    }
}

/// Writes `public/manifest.json` from the sidecars when every image of the
/// run has one. Returns (images finished, manifest written).
fn write_manifest_if_complete(
    plan: &Plan,
    paths: &RunDir,
    all: &[Job],
    config_sha256: &str,
) -> Result<Concluded, GenerateError> {
    let mut sides: Vec<Option<Sidecar>> = Vec::with_capacity(all.len());
    for j in all {
        let side = integrity::read_sidecar(paths, j, config_sha256)?;
        sides.push(side.filter(|_| paths.public().image(&j.dataset_id, &j.image_id).is_file()));
    }
    let finished = sides.iter().filter(|s| s.is_some()).count();
    let mut out = Concluded {
        finished,
        manifest_written: false,
        marker: None,
    };
    if finished < all.len() {
        return Ok(out);
    }
    let mut images: Vec<ManifestImage> = sides
        .into_iter()
        .flatten()
        .map(|s| ManifestImage {
            image: s.image,
            dataset: s.dataset,
            file: s.file,
            sha256: s.sha256,
        })
        .collect();
    images.sort_by(|a, b| (&a.dataset, &a.image).cmp(&(&b.dataset, &b.image)));
    let manifest = Manifest {
        format: MANIFEST_FORMAT.into(),
        instrument: instrument_facts(plan),
        images,
    };
    let text = serde_json::to_string_pretty(&manifest).expect("manifest serialises") + "\n";
    write_bytes_atomically(&paths.public().manifest(), text.as_bytes())?;
    out.manifest_written = true;
    Ok(out)
}

fn find_tmp(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            find_tmp(&p, out);
        } else if p.extension().is_some_and(|x| x == "tmp") {
            out.push(p);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::image_fits::{ImageHeader, SampleFormat, write_image_fits};
    use crate::model::render::try_draw_image;

    fn plan(overrides: &[&str]) -> Plan {
        let mut o: Vec<String> = [
            "run.seed=20060101",
            "image.width_px=96",
            "image.height_px=80",
            "image.n_images=2",
            "image.margin_arcsec=5",
            "psfs=[{\"name\":\"a\",\"model\":\"gaussian\"},{\"name\":\"b\",\"model\":\"gaussian\",\"fwhm_arcsec\":1.1}]",
            "shears=[{\"g1\":0.0},{\"g1\":0.04,\"g2\":-0.02}]",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        o.extend(overrides.iter().map(|s| s.to_string()));
        let o: Vec<&str> = o.iter().map(String::as_str).collect();
        Plan::from_json("{}", Path::new("t.json"), &o).unwrap()
    }

    #[test]
    fn jobs_enumerate_fields_twins_and_datasets() {
        let p = plan(&["population.rotated_pairs=true"]);
        let key = blinding_key(&p);
        let js = jobs(&p, &key).unwrap();
        assert_eq!(js.len(), 2 * 2 * 4);
        assert_eq!((js[0].field, js[0].rotated, js[0].dataset), (0, false, 0));
        assert_eq!((js[5].field, js[5].rotated, js[5].dataset), (0, true, 1));
        assert_eq!((js[15].field, js[15].rotated, js[15].dataset), (1, true, 3));
        assert!(js.iter().enumerate().all(|(i, j)| j.order == i));
        // Dataset ids are shared by the images of a dataset only.
        assert_eq!(js[1].dataset_id, js[5].dataset_id);
        assert_ne!(js[1].dataset_id, js[2].dataset_id);
        // Twins get different noise.
        assert_ne!(js[0].noise_key(1).seed(), js[4].noise_key(1).seed());
    }

    #[test]
    fn run_writes_layout_and_resumes() {
        let dir = tempfile::tempdir().unwrap();
        let p = plan(&[]);
        let quiet = |_: Event| {};
        let s = generate(&p, dir.path(), &Options::default(), &quiet).unwrap();
        assert_eq!((s.total, s.written, s.skipped), (8, 8, 0));
        assert!(s.manifest_written && s.stray_tmp.is_empty());
        let run = RunDir::new(dir.path());
        let m: Manifest =
            serde_json::from_str(&std::fs::read_to_string(run.public().manifest()).unwrap())
                .unwrap();
        assert_eq!(m.images.len(), 8);
        for im in &m.images {
            let bytes = std::fs::read(run.public().file(&im.file)).unwrap();
            assert_eq!(sha256_hex(&bytes), im.sha256);
        }
        let d: Datasets =
            serde_json::from_str(&std::fs::read_to_string(run.private().datasets()).unwrap())
                .unwrap();
        assert_eq!(d.datasets[3].psf, "b");
        assert_eq!((d.datasets[3].g1, d.datasets[3].g2), (0.04, -0.02));
        // Truth rows carry the dataset's shear.
        let im = &d.datasets[3].images[1];
        let rows =
            stepsim_contract::io::truth::read_truth_fits(&run.private().truth(&im.image)).unwrap();
        assert!(!rows.is_empty() && rows.iter().all(|r| r.g1 == 0.04 && r.g2 == -0.02));
        // Second run: everything verified, nothing written.
        let s = generate(&p, dir.path(), &Options::default(), &quiet).unwrap();
        assert_eq!((s.written, s.skipped), (0, 8));
        // A different config into the same directory is refused.
        let other = plan(&["run.seed=5"]);
        let err = generate(&other, dir.path(), &Options::default(), &quiet).unwrap_err();
        assert!(matches!(err, GenerateError::DifferentRun { .. }), "{err}");
    }

    /// Bytes of the files under `dir` whose path passes `keep`.
    fn bytes_where(dir: &Path, keep: &dyn Fn(&Path) -> bool) -> u64 {
        let mut total = 0;
        for e in std::fs::read_dir(dir).unwrap().flatten() {
            let path = e.path();
            if path.is_dir() {
                total += bytes_where(&path, keep);
            } else if keep(&path) {
                total += e.metadata().unwrap().len();
            }
        }
        total
    }

    #[test]
    fn the_disk_estimate_matches_what_a_run_writes() {
        // An optical PSF (solved, stored, written at the renderer's side)
        // and a Gaussian one, float32 images.
        let dir = tempfile::tempdir().unwrap();
        let p = plan(&[
            "image.width_px=256",
            "image.height_px=256",
            "psfs=[{\"name\":\"o\",\"model\":\"optical\",\"aberration\":\"none\",\"fwhm_arcsec\":0.9},{\"name\":\"g\",\"model\":\"gaussian\"}]",
        ]);
        let before = crate::run::disk::generate_estimate(&p, None);
        let s = generate(&p, dir.path(), &Options::default(), &|_: Event| {}).unwrap();
        let after = &s.disk_estimate;
        let part = |e: &crate::run::memory::MemoryEstimate, what: &str| {
            e.parts
                .iter()
                .find(|x| x.what.contains(what))
                .map_or(0, |x| x.bytes)
        };
        let root = dir.path();
        let run = RunDir::new(root);
        let under = |sub: &Path, ext: &str| {
            bytes_where(sub, &|f| {
                f.extension().is_some_and(|x| x == ext) && !f.starts_with(run.private().psf_cache())
            })
        };
        let block = crate::run::disk::FITS_BLOCK_BYTES;
        // Images: at most three header blocks more than written, each.
        let images = under(run.public().path(), "fits");
        let est = part(after, "images of");
        assert!(
            est >= images && est - images <= 3 * block * 8,
            "{est} {images}"
        );
        // PSF files: the solved side, at most one block more per file; the
        // optical one's side (> 128) was counted at 128 before solving.
        let psf_files = under(&run.private().psf_dir(), "fits");
        let est = part(after, "PSF file");
        assert!(
            est >= psf_files && est - psf_files <= 2 * block,
            "{est} {psf_files}"
        );
        assert!(part(&before, "PSF file") < psf_files / 2);
        assert!(
            after
                .parts
                .iter()
                .any(|x| x.what.starts_with("2 PSF files (128–"))
        );
        // The store: its files, exactly; unknown before solving.
        let store = bytes_where(&run.private().psf_cache(), &|_| true);
        assert!(store > 0);
        assert_eq!(part(after, "private/psf/cache"), store);
        assert_eq!(part(&before, "private/psf/cache"), 0);
        // Truth: the expected rows of a field; what was written has the
        // rows drawn (Poisson), so it lies within 5σ of the estimate.
        let truth = under(&run.private().truth_dir(), "fits");
        let est = part(after, "truth tables") as f64;
        let expected = crate::run::memory::objects_per_field(&p);
        let rel = 5.0 / expected.sqrt();
        assert!(expected > 20.0, "{expected}");
        assert!(
            (truth as f64 / est - 1.0).abs() < rel,
            "truth {truth} against {est} ({expected} objects)"
        );
        // Everything else fits in the small files' share.
        let all = bytes_where(root, &|_| true);
        let rest = all - images - psf_files - store - truth;
        assert!(rest <= part(after, "small files"), "{rest}");
        // And the whole: within the truth tables' spread.
        let total = after.total_bytes() as f64;
        assert!((all as f64 / total - 1.0).abs() < 0.1, "{all} {total}");
    }

    #[test]
    fn lens_positions_moves_the_galaxies_of_each_dataset() {
        // Datasets 0 (g = 0) and 1 (g = (0.04, −0.02)) of field 0: in the
        // truth tables, every galaxy of dataset 1 sits at the lensed position
        // of the same galaxy in dataset 0; stars do not move.
        let dir = tempfile::tempdir().unwrap();
        let p = plan(&["population.lens_positions=true", "image.n_images=1"]);
        generate(&p, dir.path(), &Options::default(), &|_: Event| {}).unwrap();
        let run = RunDir::new(dir.path());
        let d: Datasets =
            serde_json::from_str(&std::fs::read_to_string(run.private().datasets()).unwrap())
                .unwrap();
        let truth = |k: usize| {
            stepsim_contract::io::truth::read_truth_fits(
                &run.private().truth(&d.datasets[k].images[0].image),
            )
            .unwrap()
        };
        let (flat, lensed) = (truth(0), truth(1));
        let (cx, cy) = p.lensing_centre();
        let mut moved = 0;
        for r in &lensed {
            let Some(f) = flat.iter().find(|f| f.id == r.id) else {
                continue;
            };
            let want = if r.is_star() {
                (f.x, f.y)
            } else {
                let (dx, dy) =
                    stepsim_contract::shear::lens_offset((f.x - cx, f.y - cy), 0.04, -0.02);
                (cx + dx, cy + dy)
            };
            assert!(
                (r.x - want.0).abs() < 1e-9 && (r.y - want.1).abs() < 1e-9,
                "{r:?}"
            );
            moved += usize::from(!r.is_star() && (r.x, r.y) != (f.x, f.y));
        }
        assert!(moved > 0);
    }

    #[test]
    fn noise_free_image_is_model_plus_sky_and_model_is_verified() {
        let dir = tempfile::tempdir().unwrap();
        let p = plan(&["output.noise=false", "output.write_model=true"]);
        let quiet = |_: Event| {};
        generate(&p, dir.path(), &Options::default(), &quiet).unwrap();
        let key = blinding_key(&p);
        let js = jobs(&p, &key).unwrap();
        let paths = RunDir::new(dir.path());
        let det = p.detector();
        let sky_adu = det.sky_e_per_px / det.gain_e_per_adu;
        for j in &js {
            let img = stepsim_contract::io::image::read_image_fits(
                &paths.public().image(&j.dataset_id, &j.image_id),
            )
            .unwrap();
            let model =
                stepsim_contract::io::image::read_image_fits(&paths.private().model(&j.image_id))
                    .unwrap();
            assert!(model.pixels.iter().any(|&m| m > 1.0), "model has objects");
            for (a, m) in img.pixels.iter().zip(&model.pixels) {
                // float32 rounding at 2e4 ADU: ulp 0.002
                assert!((f64::from(a - m) - sky_adu).abs() < 0.01, "{a} - {m}");
            }
            let side = integrity::read_sidecar(&paths, j, &config_sha256(&p))
                .unwrap()
                .unwrap();
            assert!(side.model_sha256.is_some());
            assert_eq!(side.output_version, OUTPUT_VERSION);
            assert!(verify(&paths, j, true, &config_sha256(&p)).unwrap());
        }
        // A damaged model makes its image pending again.
        std::fs::write(paths.private().model(&js[3].image_id), b"junk").unwrap();
        assert!(!verify(&paths, &js[3], true, &config_sha256(&p)).unwrap());
        let s = generate(&p, dir.path(), &Options::default(), &quiet).unwrap();
        assert_eq!((s.written, s.skipped), (1, 7));
    }

    #[test]
    fn an_image_is_its_field_sheared_drawn_and_noised_with_its_own_key() {
        // Rebuild one image of the run by hand from the documented recipe and
        // compare bytes: base field k (rotated twin), the dataset's shear and
        // PSF, noise key (seed, k, dataset, Noise) with sub-stream 1.
        let dir = tempfile::tempdir().unwrap();
        let p = plan(&["population.rotated_pairs=true"]);
        let quiet = |_: Event| {};
        generate(&p, dir.path(), &Options::default(), &quiet).unwrap();
        let key = blinding_key(&p);
        let job = jobs(&p, &key)
            .unwrap()
            .into_iter()
            .find(|j| j.field == 1 && j.rotated && j.dataset == 3)
            .unwrap();
        let d = &p.datasets()[3];
        assert_eq!((d.psf, d.g1, d.g2), (1, 0.04, -0.02));
        let rows = crate::model::population::sheared(
            &crate::model::population::rotated(
                &crate::model::population::base_field(&p.population(), 1).unwrap(),
            ),
            d.g1,
            d.g2,
        );
        let det = p.detector();
        let r = p.renderer(1).unwrap();
        let (w, h) = (p.geometry().width_px, p.geometry().height_px);
        let model = try_draw_image(&r, &rows, w, h).unwrap();
        let noise_key = SeedKey::image(p.seed(), 1, 3, Stream::Noise).with_index(1);
        let pixels = crate::model::noise::realise_slow(&model, w as usize, &det, Some(noise_key));
        let by_hand = dir.path().join("by_hand.fits");
        write_image_fits(
            &by_hand,
            &pixels,
            w,
            h,
            &ImageHeader::new(&p.geometry(), p.instrument()),
            SampleFormat::Float32,
            crate::io::image_fits::Compression::None,
        )
        .unwrap();
        let paths = RunDir::new(dir.path());
        assert!(
            std::fs::read(&by_hand).unwrap()
                == std::fs::read(paths.public().image(&job.dataset_id, &job.image_id)).unwrap()
        );
        let truth =
            stepsim_contract::io::truth::read_truth_fits(&paths.private().truth(&job.image_id))
                .unwrap();
        assert_eq!(truth, rows);
    }
}
