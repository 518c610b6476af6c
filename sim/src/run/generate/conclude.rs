//! The end of a process's share: a shard of several writes its done-marker
//! ([`ShardMarker`]), a whole run its manifest once every image is finished;
//! then `public/` gets the run's time stamp.

use super::{
    GenerateError, Job, OUTPUT_VERSION, Shard, Sidecar, instrument_facts, integrity, times,
};
use crate::run::plan::Plan;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use stepsim_contract::io::write_bytes_atomically;
use stepsim_contract::run_dir::RunDir;
use stepsim_contract::run_layout::{MANIFEST_FORMAT, Manifest, ManifestImage};

/// What [`conclude`] did.
pub(super) struct Concluded {
    /// Images of the run finished (sidecar and public file present).
    pub(super) finished: usize,
    /// Whether this process wrote `public/manifest.json`.
    pub(super) manifest_written: bool,
    /// The shard's done-marker, for a shard of several.
    pub(super) marker: Option<PathBuf>,
}

/// Completion: a shard of several writes its done-marker, a whole run its
/// manifest when every image is finished; then `public/` gets the run's time
/// stamp.
pub(super) fn conclude(
    plan: &Plan,
    run: &RunDir,
    all: &[Job],
    mine: &[&Job],
    shard: Shard,
    config_sha256: &str,
) -> Result<Concluded, GenerateError> {
    let out = if shard.n > 1 {
        let marker = write_marker(run, shard, mine, config_sha256)?;
        Concluded {
            finished: count_finished(run, all, config_sha256)?,
            manifest_written: false,
            marker: Some(marker),
        }
    } else {
        write_manifest_if_complete(plan, run, all, config_sha256)?
    };
    times::normalise(
        run.public().path(),
        times::run_instant(&run.private().config())?,
    )?;
    Ok(out)
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

/// Writes the done-marker of `shard` (atomically) and returns its path.
fn write_marker(
    run: &RunDir,
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
    let path = run.private().shard_marker(shard.k, shard.n);
    let text = serde_json::to_string_pretty(&marker).expect("marker serialises") + "\n";
    write_bytes_atomically(&path, text.as_bytes())?;
    Ok(path)
}

/// Images of the run whose sidecar and public file are present.
fn count_finished(run: &RunDir, all: &[Job], config_sha256: &str) -> Result<usize, GenerateError> {
    let mut n = 0;
    for j in all {
        if integrity::read_sidecar(run, j, config_sha256)?.is_some()
            && run.public().image(&j.dataset_id, &j.image_id).is_file()
        {
            n += 1;
        }
    }
    Ok(n)
}

/// Writes `public/manifest.json` from the sidecars when every image of the
/// run has one. Returns (images finished, manifest written).
pub(super) fn write_manifest_if_complete(
    plan: &Plan,
    run: &RunDir,
    all: &[Job],
    config_sha256: &str,
) -> Result<Concluded, GenerateError> {
    let mut sides: Vec<Option<Sidecar>> = Vec::with_capacity(all.len());
    for j in all {
        let side = integrity::read_sidecar(run, j, config_sha256)?;
        sides.push(side.filter(|_| run.public().image(&j.dataset_id, &j.image_id).is_file()));
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
    write_bytes_atomically(&run.public().manifest(), text.as_bytes())?;
    out.manifest_written = true;
    Ok(out)
}

/// Temporary files (`*.tmp`) under `dir`, sorted.
pub(super) fn stray_temporaries(dir: &Path) -> Vec<PathBuf> {
    let mut stray_tmp = Vec::new();
    find_tmp(dir, &mut stray_tmp);
    stray_tmp.sort();
    stray_tmp
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
