//! `--finish`: a run made in shards verified whole, its manifest written.

use super::conclude::write_manifest_if_complete;
use super::shared::private_shared;
use super::{
    GenerateError, Job, SeedUse, Shard, blinding_key, claim, config_sha256, integrity, jobs, times,
    verify,
};
use crate::run::plan::Plan;
use rayon::prelude::*;
use std::path::Path;
use stepsim_contract::io::IoError;
use stepsim_contract::run_dir::RunDir;

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
    let run = RunDir::new(out);
    if !run.private().config().is_file() {
        return Err(GenerateError::NoRun {
            path: run.private().config(),
        });
    }
    let claim = claim::claim(plan, out)?;
    match finish_claimed(&claim, &run, out) {
        Ok(f) => Ok(f),
        Err(e) => {
            let manifest = run.public().manifest();
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
    run: &RunDir,
    out: &Path,
) -> Result<Finished, GenerateError> {
    let plan = &claim.plan;
    let config_sha256 = config_sha256(plan);
    let key = blinding_key(plan);
    let all = jobs(plan, &key)?;
    integrity::refuse_foreign_files(plan, run, &all)?;
    integrity::refuse_other_contents(&private_shared(plan, run, &key, &all))?;
    integrity::keep_inputs(plan, run)?;
    let want_model = plan.output().write_model;
    let ok: Vec<bool> = all
        .par_iter()
        .map(|j| verify(run, j, want_model, &config_sha256))
        .collect::<Result<_, _>>()?;
    let markers = marker_names(run)?;
    let missing: Vec<&Job> = all.iter().filter(|j| !ok[j.order]).collect();
    let readme = run.public().readme();
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
    let done = write_manifest_if_complete(plan, run, &all, &config_sha256)?;
    debug_assert!(done.manifest_written);
    times::normalise(
        run.public().path(),
        times::run_instant(&run.private().config())?,
    )?;
    Ok(Finished {
        seed: claim.seed,
        total: all.len(),
        markers,
    })
}

/// The done-markers' file names under `private/shards`, sorted.
fn marker_names(run: &RunDir) -> Result<Vec<String>, IoError> {
    let dir = run.private().shards_dir();
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
