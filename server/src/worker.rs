//! The scoring queue's workers: each claims the oldest queued job of a team
//! that has none running, scores it with the harness (the library code of
//! `stepsim score`, restricted to a part: `stepsim_harness::part`), keeps
//! the reports per entry and records the result.

use crate::challenge::{Challenge, ChallengeError, Settings};
use crate::observe::Metrics;
use crate::store::Submission;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Duration;
use stepsim_harness::part::{Part, PublicFeedback, score_prepared_part};
use stepsim_harness::pipeline::{ScoreOptions, prepare};
use stepsim_harness::write_outputs;

/// Recorded with every score: a scorer change shows in the database.
pub const SCORER_VERSION: &str = concat!("stepsim-harness ", env!("CARGO_PKG_VERSION"));

/// Default limit on one scoring job.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(600);

/// A harness message as a participant may see it: the server's paths (the
/// stored upload, the private run directory) replaced by neutral words, and
/// advice meant for the command line ([`server_wording`]) replaced by what
/// to do with an upload.
pub fn participant_message(message: &str, upload: &Path, truth_dir: &Path) -> String {
    server_wording(
        &message
            .replace(&upload.display().to_string(), "the upload")
            .replace(&truth_dir.display().to_string(), "the run"),
    )
}

/// The harness's advice to pass `--allow-missing-images` (a flag of
/// `stepsim score`) as a participant of the server can act on it: the
/// server takes no flags and scores complete catalogues only. The rest of
/// the message (counts, the smallest missing ids, lines and columns) is
/// kept. A fixed replacement: it depends on nothing private. Also applied
/// to messages stored before it existed when they are shown.
pub fn server_wording(message: &str) -> String {
    message.replace(
        "; pass --allow-missing-images to score a partial submission",
        "; the server scores only catalogues with rows for every image of the release \
         (manifest.json on the data page lists them all): add the missing images' rows and \
         upload again",
    )
}

/// The harness's options for scoring (or format-checking) the upload at
/// `upload` against the challenge's run: the one place both the format
/// check of an upload (`api::submit`) and the worker build them, so that a
/// limit set here holds for both.
pub fn upload_options(settings: &Settings, upload: &Path) -> ScoreOptions {
    let mut opts = ScoreOptions::new(&settings.truth_dir, upload);
    opts.max_submission_bytes = Some(settings.max_upload_bytes);
    opts
}

/// Scores entry `sub` of `ch`: the public part (feedback), and the held-out
/// part when the run has one; writes both reports under `entries/<id>/`.
/// Returns (public feedback JSON, held-out summary JSON) or the message.
pub fn score_entry(ch: &Challenge, sub: &Submission) -> Result<(String, Option<String>), String> {
    score_upload(&ch.dir, &ch.settings, sub)
}

/// [`score_entry`] from the state directory and settings alone (no store:
/// a store that is locked cannot make a participant's entry fail).
pub fn score_upload(
    dir: &Path,
    settings: &Settings,
    sub: &Submission,
) -> Result<(String, Option<String>), String> {
    let upload = dir.join("uploads").join(&sub.sha256);
    let entry_dir = |part: Part| {
        dir.join("entries")
            .join(sub.id.to_string())
            .join(part.name())
    };
    let truth = &settings.truth_dir;
    let mut opts = upload_options(settings, &upload);
    opts.name = Some(format!("entry {}", sub.id));
    let msg =
        |e: stepsim_harness::HarnessError| participant_message(&e.to_string(), &upload, truth);
    // The upload is read and checked once; both parts are scored from it.
    let prepared = prepare(&opts).map_err(msg)?;
    let public = score_prepared_part(&prepared, Part::Public, &opts).map_err(msg)?;
    write_outputs(&entry_dir(Part::Public), &public, true).map_err(msg)?;
    let feedback =
        serde_json::to_string(&PublicFeedback::of_report(&public)).map_err(|e| e.to_string())?;
    let holdout = if settings.holdout {
        // A failure on the held-out part must not show before reveal: a
        // refused entry would tell the participant something about the
        // held-out data. The entry is scored on its public part, and the
        // failure is kept as the held-out result (`{"error": …}`, opened
        // at reveal like any held-out figure).
        let held = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let report = score_prepared_part(&prepared, Part::Holdout, &opts).map_err(msg)?;
            write_outputs(&entry_dir(Part::Holdout), &report, true).map_err(msg)?;
            serde_json::to_string(&report.summary).map_err(|e| e.to_string())
        }))
        .unwrap_or_else(|_| Err("the scorer failed on the held-out part".into()));
        Some(held.unwrap_or_else(|e| {
            tracing::warn!(entry = sub.id, error = %e, "held-out part not scored");
            serde_json::json!({ "error": e }).to_string()
        }))
    } else {
        None
    };
    Ok((feedback, holdout))
}

/// The first wait after a store error; it doubles up to [`MAX_BACKOFF`].
pub const FIRST_BACKOFF: Duration = Duration::from_millis(200);
/// The longest wait between two tries after store errors.
pub const MAX_BACKOFF: Duration = Duration::from_secs(5);

/// Sleeps `d` in slices, returning early (false) once `stop` is set.
fn nap(d: Duration, stop: &AtomicBool) -> bool {
    let end = std::time::Instant::now() + d;
    while std::time::Instant::now() < end {
        if stop.load(Ordering::Relaxed) {
            return false;
        }
        std::thread::sleep(Duration::from_millis(50).min(end - std::time::Instant::now()));
    }
    !stop.load(Ordering::Relaxed)
}

/// Runs one worker on the challenge in `dir` until `stop` is set: claims,
/// scores (in a thread of its own, given up after `timeout`), records.
///
/// A store error (the database locked by an organiser's `sqlite3` or a
/// backup for longer than the store's busy timeout, a full disk) never
/// ends the worker: it is logged and the call is tried again after a wait
/// that doubles from [`FIRST_BACKOFF`] to [`MAX_BACKOFF`]. A result that
/// cannot be recorded is kept and recorded once the store answers; the job
/// stays `scoring` meanwhile, so a server stopped then queues it again.
/// Returns once `stop` is set (the error type is kept for callers).
pub fn run_worker(
    dir: &Path,
    stop: Arc<AtomicBool>,
    timeout: Duration,
) -> Result<(), ChallengeError> {
    run_observed_worker(dir, stop, timeout, &Metrics::default())
}

/// [`run_worker`], counting each finished job in `metrics`.
pub fn run_observed_worker(
    dir: &Path,
    stop: Arc<AtomicBool>,
    timeout: Duration,
    metrics: &Metrics,
) -> Result<(), ChallengeError> {
    let mut backoff = FIRST_BACKOFF;
    let failed = |backoff: &mut Duration, what: &str, e: &dyn std::fmt::Display| -> bool {
        tracing::warn!(
            error = %e,
            retry_ms = backoff.as_millis() as u64,
            "worker: {what}; trying again"
        );
        let go_on = nap(*backoff, &stop);
        *backoff = (*backoff * 2).min(MAX_BACKOFF);
        go_on
    };
    let mut ch = loop {
        match Challenge::open(dir) {
            Ok(ch) => break ch,
            Err(e) => {
                if !failed(&mut backoff, "cannot open the challenge", &e) {
                    return Ok(());
                }
            }
        }
    };
    while !stop.load(Ordering::Relaxed) {
        let job = match ch.store.claim_job(crate::now_s()) {
            Ok(Some(job)) => job,
            Ok(None) => {
                std::thread::sleep(Duration::from_millis(200));
                continue;
            }
            Err(e) => {
                failed(&mut backoff, "cannot claim a job", &e);
                continue;
            }
        };
        backoff = FIRST_BACKOFF;
        tracing::info!(entry = job.id, team = job.team_id, "scoring started");
        let started = std::time::Instant::now();
        let (tx, rx) = std::sync::mpsc::channel();
        let (dir2, settings2, job2) = (dir.to_path_buf(), ch.settings.clone(), job.clone());
        std::thread::spawn(move || {
            let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                score_upload(&dir2, &settings2, &job2)
            }))
            .unwrap_or_else(|_| Err("the scorer failed on this upload".into()));
            let _ = tx.send(result);
        });
        let result = rx.recv_timeout(timeout).unwrap_or_else(|_| {
            Err(format!(
                "scoring took longer than {} s and was stopped",
                timeout.as_secs()
            ))
        });
        let seconds = started.elapsed().as_secs_f64();
        let outcome = if result.is_ok() { "scored" } else { "refused" };
        metrics.scoring(outcome, seconds);
        match &result {
            Ok(_) => tracing::info!(
                entry = job.id,
                team = job.team_id,
                seconds = %format_args!("{seconds:.2}"),
                "scoring ended: scored"
            ),
            Err(e) => tracing::info!(
                entry = job.id,
                team = job.team_id,
                seconds = %format_args!("{seconds:.2}"),
                reason = %crate::observe::first_line(e),
                "scoring ended: refused"
            ),
        }
        loop {
            match ch
                .store
                .finish_job(job.id, result.clone(), SCORER_VERSION, crate::now_s())
            {
                Ok(()) => break,
                Err(e) => {
                    let what = format!("cannot record entry {}", job.id);
                    if !failed(&mut backoff, &what, &e) {
                        // Left `scoring`: queued again when the server starts.
                        return Ok(());
                    }
                }
            }
        }
        backoff = FIRST_BACKOFF;
    }
    Ok(())
}

/// The scoring workers of a server: threads running [`run_worker`], and
/// how many of them are alive (an upload is refused with 503 when none is:
/// an accepted upload must be scored).
#[derive(Debug)]
pub struct WorkerPool {
    live: Arc<AtomicUsize>,
    metrics: Arc<Metrics>,
    stop: Arc<AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

/// Counts a worker thread as alive until it ends, also by a panic.
struct Alive(Arc<AtomicUsize>);

impl Drop for Alive {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

impl WorkerPool {
    /// Starts `n` workers (at least one) on the challenge in `dir`.
    pub fn start(dir: &Path, n: usize, timeout: Duration) -> Self {
        let live = Arc::new(AtomicUsize::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let metrics = Arc::new(Metrics::default());
        let threads = (0..n.max(1))
            .map(|_| {
                let (d, s, m) = (dir.to_path_buf(), stop.clone(), metrics.clone());
                live.fetch_add(1, Ordering::SeqCst);
                let alive = Alive(live.clone());
                std::thread::spawn(move || {
                    let _alive = alive;
                    if let Err(e) = run_observed_worker(&d, s, timeout, &m) {
                        tracing::error!(error = %e, "worker stopped");
                    }
                })
            })
            .collect();
        Self {
            live,
            metrics,
            stop,
            threads,
        }
    }

    /// The counters of this pool's jobs (and of the server that shares them).
    pub fn metrics(&self) -> Arc<Metrics> {
        self.metrics.clone()
    }

    /// The count of live workers, shared (what `AppState::with_workers` reads).
    pub fn live(&self) -> Arc<AtomicUsize> {
        self.live.clone()
    }

    /// Stops the workers and waits for them (each finishes its job first).
    pub fn stop(mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}
