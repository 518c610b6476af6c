//! The scoring queue's workers: each claims the oldest queued job of a team
//! that has none running, scores it with the harness (the library code of
//! `stepsim score`, restricted to a part: `stepsim_harness::part`), keeps
//! the reports per entry and records the result.

use crate::challenge::{Challenge, ChallengeError};
use crate::store::Submission;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;
use stepsim_harness::part::{Part, PublicFeedback, score_part};
use stepsim_harness::pipeline::ScoreOptions;
use stepsim_harness::write_outputs;

/// Recorded with every score: a scorer change shows in the database.
pub const SCORER_VERSION: &str = concat!("stepsim-harness ", env!("CARGO_PKG_VERSION"));

/// Default limit on one scoring job.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(600);

/// A harness message as a participant may see it: the server's paths (the
/// stored upload, the private run directory) replaced by neutral words.
pub fn participant_message(message: &str, upload: &Path, truth_dir: &Path) -> String {
    message
        .replace(&upload.display().to_string(), "the upload")
        .replace(&truth_dir.display().to_string(), "the run")
}

/// Scores entry `sub` of `ch`: the public part (feedback), and the held-out
/// part when the run has one; writes both reports under `entries/<id>/`.
/// Returns (public feedback JSON, held-out summary JSON) or the message.
pub fn score_entry(ch: &Challenge, sub: &Submission) -> Result<(String, Option<String>), String> {
    let upload = ch.upload_path(&sub.sha256);
    let truth = &ch.settings.truth_dir;
    let mut opts = ScoreOptions::new(truth, &upload);
    opts.name = Some(format!("entry {}", sub.id));
    let msg =
        |e: stepsim_harness::HarnessError| participant_message(&e.to_string(), &upload, truth);
    let public = score_part(&opts, Part::Public).map_err(msg)?;
    write_outputs(&ch.entry_dir(sub.id, Part::Public), &public, true).map_err(msg)?;
    let feedback =
        serde_json::to_string(&PublicFeedback::of_report(&public)).map_err(|e| e.to_string())?;
    let holdout = if ch.settings.holdout {
        // A failure on the held-out part must not show before reveal: a
        // refused entry would tell the participant something about the
        // held-out data. The entry is scored on its public part, and the
        // failure is kept as the held-out result (`{"error": …}`, opened
        // at reveal like any held-out figure).
        let held = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let report = score_part(&opts, Part::Holdout).map_err(msg)?;
            write_outputs(&ch.entry_dir(sub.id, Part::Holdout), &report, true).map_err(msg)?;
            serde_json::to_string(&report.summary).map_err(|e| e.to_string())
        }))
        .unwrap_or_else(|_| Err("the scorer failed on the held-out part".into()));
        Some(held.unwrap_or_else(|e| {
            eprintln!(
                "stepsim serve: entry {}: held-out part not scored: {e}",
                sub.id
            );
            serde_json::json!({ "error": e }).to_string()
        }))
    } else {
        None
    };
    Ok((feedback, holdout))
}

/// Runs one worker on the challenge in `dir` until `stop` is set: claims,
/// scores (in a thread of its own, given up after `timeout`), records.
pub fn run_worker(
    dir: &Path,
    stop: Arc<AtomicBool>,
    timeout: Duration,
) -> Result<(), ChallengeError> {
    let mut ch = Challenge::open(dir)?;
    while !stop.load(Ordering::Relaxed) {
        let Some(job) = ch.store.claim_job(crate::now_s())? else {
            std::thread::sleep(Duration::from_millis(200));
            continue;
        };
        let (tx, rx) = std::sync::mpsc::channel();
        let dir2 = dir.to_path_buf();
        let job2 = job.clone();
        std::thread::spawn(move || {
            let result = match Challenge::open(&dir2) {
                Ok(c) => std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    score_entry(&c, &job2)
                }))
                .unwrap_or_else(|_| Err("the scorer failed on this upload".into())),
                Err(e) => Err(e.to_string()),
            };
            let _ = tx.send(result);
        });
        let result = rx.recv_timeout(timeout).unwrap_or_else(|_| {
            Err(format!(
                "scoring took longer than {} s and was stopped",
                timeout.as_secs()
            ))
        });
        if let Err(e) = &result {
            eprintln!("stepsim serve: entry {} refused: {e}", job.id);
        }
        ch.store
            .finish_job(job.id, result, SCORER_VERSION, crate::now_s())?;
    }
    Ok(())
}
