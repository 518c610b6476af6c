//! Claiming a run directory, and refusing what another run left in it.
//!
//! `private/config.json` (the resolved config) is the first file a run
//! writes, and it is created, never replaced: written under a temporary name,
//! then hard-linked to its final name, which fails when the name exists. So
//! it is never half-written, and of two processes starting different configs
//! in one directory at the same moment exactly one claims it; the other finds
//! the file, compares, and is refused naming it. Writing it first also finds
//! an unwritable `--out` before any work.
//!
//! A config without a seed adopts the seed of the run it finds when the rest
//! of the resolved config is identical (a resume, or a shard started later);
//! the seed it drew is then dropped.

use super::GenerateError;
use crate::run::plan::{Plan, SeedOrigin};
use std::path::{Path, PathBuf};
use stepsim_contract::io::IoError;
use stepsim_contract::run_dir::RunDir;

/// How the run's seed was chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SeedUse {
    /// Given in the config (`run.seed`).
    Given,
    /// Drawn from the operating system by this process: a new run.
    Drawn,
    /// The config gave none; the existing run's `private/config.json` did.
    Adopted,
}

/// The outcome of `claim` (a run claiming its directory).
#[derive(Debug, Clone)]
pub struct Claim {
    /// The plan of the run (with an adopted seed where there was one).
    pub plan: Plan,
    /// The bytes of `private/config.json`.
    pub config_json: String,
    /// How the seed was chosen.
    pub seed: SeedUse,
    /// True when this process created `private/config.json`.
    pub created: bool,
}

/// The resolved config as written to `private/config.json`
/// ([`Plan::run_config_json`]: input paths name the run's copies).
pub fn config_json(plan: &Plan) -> String {
    format!("{}\n", plan.run_config_json())
}

/// Claims `out` for `plan`, or joins the run already there if it has the
/// same config (adopting its seed when `plan`'s was drawn).
pub fn claim(plan: &Plan, out: &Path) -> Result<Claim, GenerateError> {
    let path = RunDir::new(out).private().config();
    let mine = config_json(plan);
    let created = create_new(&path, mine.as_bytes())?;
    let given = match plan.seed_origin() {
        SeedOrigin::Config => SeedUse::Given,
        SeedOrigin::Drawn => SeedUse::Drawn,
    };
    if created {
        return Ok(Claim {
            plan: plan.clone(),
            config_json: mine,
            seed: given,
            created,
        });
    }
    let existing = std::fs::read_to_string(&path).map_err(|e| IoError::os(&path, e))?;
    if existing == mine {
        return Ok(Claim {
            plan: plan.clone(),
            config_json: mine,
            seed: given,
            created,
        });
    }
    let different = || GenerateError::DifferentRun { path: path.clone() };
    if plan.seed_origin() != SeedOrigin::Drawn {
        return Err(different());
    }
    let Some(seed) = Plan::seed_written_in(&existing, &path) else {
        return Err(different());
    };
    let adopted = plan.with_seed(seed);
    let again = config_json(&adopted);
    if again != existing {
        return Err(different());
    }
    Ok(Claim {
        plan: adopted,
        config_json: again,
        seed: SeedUse::Adopted,
        created,
    })
}

/// Creates `path` with `bytes` unless it exists: the bytes go to a temporary
/// file that is then hard-linked to `path` (atomic; fails if `path` exists).
/// Returns whether this call created it.
pub fn create_new(path: &Path, bytes: &[u8]) -> Result<bool, IoError> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| IoError::os(dir, e))?;
    }
    let tmp = unique_temporary(path);
    std::fs::write(&tmp, bytes).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        IoError::os(path, e)
    })?;
    let linked = std::fs::hard_link(&tmp, path);
    let _ = std::fs::remove_file(&tmp);
    match linked {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(false),
        Err(e) => Err(IoError::os(path, e)),
    }
}

/// A temporary name for `path` unique to this process and call: the form of
/// [`stepsim_contract::io::temporary_name`] (`.<name>.<n>.<pid>.tmp`, so a killed
/// writer's file is cleaned up the same way), with a counter so that threads
/// of one process do not share it.
fn unique_temporary(path: &Path) -> PathBuf {
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(0);
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.claim{n}.{}.tmp", std::process::id()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::{Arc, Barrier};

    fn plan(overrides: &[&str]) -> Plan {
        Plan::from_json("{}", Path::new("t.json"), overrides).unwrap()
    }

    #[test]
    fn of_threads_claiming_one_directory_with_different_configs_one_wins() {
        for round in 0..5 {
            let dir = tempfile::tempdir().unwrap();
            let n = 8;
            let barrier = Arc::new(Barrier::new(n));
            let results: Vec<Result<Claim, GenerateError>> = std::thread::scope(|s| {
                let handles: Vec<_> = (0..n)
                    .map(|i| {
                        let (barrier, out) = (barrier.clone(), dir.path());
                        s.spawn(move || {
                            let p = plan(&[&format!("run.seed={i}")]);
                            barrier.wait();
                            claim(&p, out)
                        })
                    })
                    .collect();
                handles.into_iter().map(|h| h.join().unwrap()).collect()
            });
            let winners: Vec<&Claim> = results.iter().filter_map(|r| r.as_ref().ok()).collect();
            assert_eq!(winners.len(), 1, "round {round}");
            assert!(winners[0].created);
            for r in &results {
                if let Err(e) = r {
                    assert!(matches!(e, GenerateError::DifferentRun { .. }), "{e}");
                }
            }
            // The file is the winner's, whole; no temporary is left.
            let run = RunDir::new(dir.path());
            let text = std::fs::read_to_string(run.private().config()).unwrap();
            assert_eq!(text, winners[0].config_json);
            let left: Vec<_> = std::fs::read_dir(run.private().path())
                .unwrap()
                .map(|e| e.unwrap().file_name())
                .collect();
            assert_eq!(left, ["config.json"]);
        }
    }

    #[test]
    fn seedless_shards_started_at_the_same_moment_agree_on_one_seed() {
        // N shards of a config without run.seed each draw a seed; one claims
        // the directory and every other adopts its seed.
        for round in 0..5 {
            let dir = tempfile::tempdir().unwrap();
            let n = 8;
            let barrier = Arc::new(Barrier::new(n));
            let claims: Vec<Claim> = std::thread::scope(|s| {
                let handles: Vec<_> = (0..n)
                    .map(|_| {
                        let (barrier, out) = (barrier.clone(), dir.path());
                        s.spawn(move || {
                            let p = plan(&[]);
                            barrier.wait();
                            claim(&p, out).unwrap()
                        })
                    })
                    .collect();
                handles.into_iter().map(|h| h.join().unwrap()).collect()
            });
            let created: Vec<&Claim> = claims.iter().filter(|c| c.created).collect();
            assert_eq!(created.len(), 1, "round {round}");
            assert_eq!(created[0].seed, SeedUse::Drawn);
            let seed = created[0].plan.seed();
            for c in &claims {
                assert_eq!(c.plan.seed(), seed, "round {round}");
                assert_eq!(c.config_json, created[0].config_json);
                if !c.created {
                    assert_eq!(c.seed, SeedUse::Adopted);
                }
            }
        }
    }

    #[test]
    fn a_drawn_seed_gives_way_to_the_run_found_and_a_given_one_does_not() {
        let dir = tempfile::tempdir().unwrap();
        let first = plan(&[]);
        let c = claim(&first, dir.path()).unwrap();
        assert_eq!((c.seed, c.created), (SeedUse::Drawn, true));
        // The same seedless config again: a new draw, the run's seed adopted.
        let again = plan(&[]);
        assert_ne!(again.seed(), first.seed());
        let c = claim(&again, dir.path()).unwrap();
        assert_eq!((c.seed, c.created), (SeedUse::Adopted, false));
        assert_eq!(c.plan.seed(), first.seed());
        assert_eq!(c.config_json, config_json(&first));
        // The recorded seed given explicitly: the same run.
        let given = plan(&[&format!("run.seed={}", first.seed())]);
        assert_eq!(claim(&given, dir.path()).unwrap().seed, SeedUse::Given);
        // Another given seed, or another config without a seed: refused.
        let other = plan(&[&format!("run.seed={}", first.seed() ^ 1)]);
        assert!(matches!(
            claim(&other, dir.path()),
            Err(GenerateError::DifferentRun { .. })
        ));
        let other = plan(&["image.n_images=3"]);
        assert!(matches!(
            claim(&other, dir.path()),
            Err(GenerateError::DifferentRun { .. })
        ));
    }
}
