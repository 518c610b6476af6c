//! What a run accepts in its directory: its own files and nothing else.
//!
//! Every sidecar records what made it (the SHA-256 of the resolved config and
//! [`OUTPUT_VERSION`]); a sidecar made by anything else is refused by name.
//! So is any file under `public/`, `private/truth`, `private/model`,
//! `private/done`, `private/inputs` or `private/psf` (apart from the PSF store `private/psf/cache/`)
//! whose name is not one of this run's (a
//! leftover of another config, for instance after `private/config.json` was
//! deleted), and a `private/blinding.key` or `private/datasets.json` with
//! other content than this run's. Temporary files (`.<name>.<pid>.tmp`) are left to
//! [`stepsim_contract::io::remove_stale_temporaries`].

use super::{GenerateError, Job, RunDir, Sidecar};
use crate::run::plan::Plan;
use std::collections::HashSet;
use std::path::{Path, PathBuf};
use stepsim_contract::io::IoError;

/// Version of what `generate` writes: bumped whenever the bytes of a run's
/// files change on purpose, so that a rerun refuses the files of an older
/// stepsim instead of mixing them with new ones.
pub const OUTPUT_VERSION: u32 = 7;

/// Refuses, naming it, the first file or directory (in sorted order) that
/// does not belong to the run of `all`.
pub fn refuse_foreign_files(plan: &Plan, run: &RunDir, all: &[Job]) -> Result<(), GenerateError> {
    let (public, private) = (run.public(), run.private());
    let mut datasets: HashSet<PathBuf> = HashSet::new();
    let mut public_files: HashSet<PathBuf> = HashSet::new();
    let mut private_files: HashSet<PathBuf> = HashSet::new();
    for j in all {
        datasets.insert(public.dataset(&j.dataset_id));
        public_files.insert(public.image(&j.dataset_id, &j.image_id));
        private_files.insert(private.truth(&j.image_id));
        private_files.insert(private.model(&j.image_id));
        private_files.insert(private.sidecar(&j.image_id));
    }
    for entry in listing(public.path())? {
        if entry.is_dir() && datasets.contains(&entry) {
            for file in listing(&entry)? {
                if file.is_dir() || !public_files.contains(&file) {
                    return Err(foreign(&file));
                }
            }
        } else if entry.is_dir() || !(entry == public.readme() || entry == public.manifest()) {
            return Err(foreign(&entry));
        }
    }
    for dir in [private.truth_dir(), private.model_dir(), private.done_dir()] {
        for file in listing(&dir)? {
            if file.is_dir() || !private_files.contains(&file) {
                return Err(foreign(&file));
            }
        }
    }
    let psfs: HashSet<PathBuf> = plan
        .psf_names()
        .iter()
        .map(|name| private.psf(name))
        .collect();
    for file in listing(&private.psf_dir())? {
        // `cache/` is the run's PSF store: its files are checked when read
        // (crate::io::psf_store) and rebuilt when they do not check.
        let store = file == private.psf_cache() && file.is_dir();
        if !store && (file.is_dir() || !psfs.contains(&file)) {
            return Err(foreign(&file));
        }
    }
    let inputs: HashSet<PathBuf> = plan
        .run_inputs()
        .iter()
        .map(|i| private.input(&i.name))
        .collect();
    for file in listing(&private.inputs())? {
        if file.is_dir() || !inputs.contains(&file) {
            return Err(foreign(&file));
        }
    }
    Ok(())
}

/// Keeps the run's copies of its inputs ([`Plan::run_inputs`]) in
/// `RUN/private/`: writes those missing (atomically) and refuses
/// ([`GenerateError::InputChanged`]) a copy whose bytes differ from the
/// file the plan read, so that a run is never continued with other inputs
/// than it was made with.
pub fn keep_inputs(plan: &Plan, run: &RunDir) -> Result<(), GenerateError> {
    for input in plan.run_inputs() {
        let copy = run.private().input(&input.name);
        match std::fs::read(&copy) {
            Ok(bytes) if bytes == *input.bytes => {}
            Ok(_) => {
                return Err(GenerateError::InputChanged {
                    copy,
                    source_file: input.source.clone(),
                });
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                stepsim_contract::io::write_bytes_atomically(&copy, &input.bytes)?;
            }
            Err(e) => return Err(IoError::os(&copy, e).into()),
        }
    }
    Ok(())
}

/// Refuses, naming it, a file of `files` (path, content) that exists with
/// other content than this run's (e.g. the `blinding.key` of another run
/// whose `private/config.json` was deleted).
pub fn refuse_other_contents(files: &[(PathBuf, String)]) -> Result<(), GenerateError> {
    for (path, want) in files {
        match std::fs::read(path) {
            Ok(bytes) if bytes != want.as_bytes() => return Err(foreign(path)),
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(IoError::os(path, e).into()),
        }
    }
    Ok(())
}

fn foreign(path: &Path) -> GenerateError {
    GenerateError::ForeignFile { path: path.into() }
}

/// The entries of `dir`, sorted, without temporaries; empty when `dir` does
/// not exist.
fn listing(dir: &Path) -> Result<Vec<std::path::PathBuf>, IoError> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(IoError::os(dir, e)),
    };
    let mut out = Vec::new();
    for e in entries {
        let p = e.map_err(|e| IoError::os(dir, e))?.path();
        if stepsim_contract::io::temporary_owner(&p).is_none() {
            out.push(p);
        }
    }
    out.sort();
    Ok(out)
}

/// The sidecar of `job`: `None` when there is none; refused (naming the
/// file) when it cannot be read as a sidecar of this stepsim, or was made by
/// another config or output version.
pub fn read_sidecar(
    run: &RunDir,
    job: &Job,
    config_sha256: &str,
) -> Result<Option<Sidecar>, GenerateError> {
    let path = run.private().sidecar(&job.image_id);
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(IoError::os(&path, e).into()),
    };
    let side: Sidecar = serde_json::from_str(&text).map_err(|e| GenerateError::ForeignSidecar {
        path: path.clone(),
        why: format!("it is not a sidecar this stepsim can read ({e})"),
    })?;
    if side.output_version != OUTPUT_VERSION {
        return Err(GenerateError::ForeignSidecar {
            path,
            why: format!(
                "it was made by another version of stepsim (output version {}, this one writes {OUTPUT_VERSION})",
                side.output_version
            ),
        });
    }
    if side.config_sha256 != config_sha256 || side.image != job.image_id {
        return Err(GenerateError::ForeignSidecar {
            path,
            why: format!(
                "it was made by another config (config SHA-256 {}, this run's is {config_sha256})",
                side.config_sha256
            ),
        });
    }
    Ok(Some(side))
}
