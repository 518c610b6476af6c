//! The run's directory before any image is made: another run's files
//! refused (a claim made just now undone), this shard's images verified to
//! find those left to make (a stale manifest removed), and the datasets'
//! directories created.

use super::shared::private_shared;
use super::sidecar::verify_files;
use super::{GenerateError, Job, Shard, Sidecar, integrity};
use crate::run::blind::BlindingKey;
use crate::run::plan::Plan;
use rayon::prelude::*;
use stepsim_contract::io::IoError;
use stepsim_contract::run_dir::RunDir;

/// Refuses files and shared contents another run left in the directory,
/// and keeps the run's copies of its inputs ([`integrity::keep_inputs`]); a
/// claim made just now is undone on failure.
pub(super) fn refuse_foreign_or_undo_claim(
    plan: &Plan,
    run: &RunDir,
    key: &BlindingKey,
    all: &[Job],
    claimed_now: bool,
) -> Result<(), GenerateError> {
    let checked = integrity::refuse_foreign_files(plan, run, all)
        .and_then(|()| integrity::refuse_other_contents(&private_shared(plan, run, key, all)))
        .and_then(|()| integrity::keep_inputs(plan, run));
    if checked.is_err() && claimed_now {
        let _ = std::fs::remove_file(run.private().config());
    }
    checked
}

/// This process's share of a run and what is left of it.
pub(super) struct Work<'a> {
    /// The images of this shard.
    pub(super) mine: Vec<&'a Job>,
    /// Those not found finished and verified.
    pub(super) pending: Vec<&'a Job>,
    /// True when a stale manifest was removed.
    pub(super) removed_manifest: bool,
}

/// Resume: reads every sidecar (refusing foreign ones), verifies this
/// shard's images against theirs (read only), and removes a manifest that
/// would list an image missing or damaged (other shards' images count as
/// finished when their sidecar and file exist).
pub(super) fn find_pending<'a>(
    plan: &Plan,
    run: &RunDir,
    all: &'a [Job],
    shard: Shard,
    config_sha256: &str,
) -> Result<Work<'a>, GenerateError> {
    let sides: Vec<Option<Sidecar>> = all
        .par_iter()
        .map(|j| integrity::read_sidecar(run, j, config_sha256))
        .collect::<Result<_, _>>()?;
    let want_model = plan.output().write_model;
    let mine: Vec<&Job> = all.iter().filter(|j| shard.owns(j.order)).collect();
    let done: Vec<bool> = mine
        .par_iter()
        .map(|j| {
            sides[j.order]
                .as_ref()
                .is_some_and(|s| verify_files(run, j, s, want_model))
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
            sides[j.order].is_none() || !run.public().image(&j.dataset_id, &j.image_id).is_file()
        });
    let manifest_path = run.public().manifest();
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

/// Creates `public/<dataset-id>/` for every dataset, in the order of the ids
/// (so that neither inode numbers nor creation order follow the datasets).
pub(super) fn make_dataset_dirs(run: &RunDir, all: &[Job]) -> Result<(), IoError> {
    let mut ids: Vec<&str> = all.iter().map(|j| j.dataset_id.as_str()).collect();
    ids.sort_unstable();
    ids.dedup();
    for id in ids {
        let dir = run.public().dataset(id);
        std::fs::create_dir_all(&dir).map_err(|e| IoError::os(&dir, e))?;
    }
    Ok(())
}
