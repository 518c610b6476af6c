//! The scoring queue's workers: each claims the oldest queued job of a team
//! that has none running, scores it with the harness (the library code of
//! `stepsim score`, restricted to a part: `stepsim_harness::score_prepared_part`), keeps
//! the reports per entry and records the result.

use crate::challenge::{Challenge, ChallengeError, Settings};
use crate::observe::Metrics;
use crate::store::Submission;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Duration;
use stepsim_contract::run_layout::Part;
use stepsim_harness::{PublicFeedback, ScoreOptions, prepare, score_prepared_part, write_outputs};

use crate::challenge::SCORER_VERSION;

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

/// True when the harness's error is the organisers' (the run's private
/// files: `datasets.json`, `config.json`), not the upload's: a participant
/// is then neither charged for it nor shown it.
pub fn organisers_fault(e: &stepsim_harness::HarnessError) -> bool {
    matches!(e, stepsim_harness::HarnessError::Truth { .. })
}

/// The message a participant sees for a fault of the organisers' side
/// (fixed: it depends on nothing private).
pub const ORGANISERS_FAULT: &str = "the server could not read its run to score this entry (the \
     organisers' side, not the upload; they are told): it can be scored again with `challenge \
     rescore`";

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
/// check of an upload (`http::api::upload::submit`) and the worker build them, so that a
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
    score_upload_unless(dir, settings, sub, &AtomicBool::new(false))
}

/// The message of a scoring given up because `cancel` was set (its worker
/// lost the job's lease, or ran out of time): nothing of it is written.
const CANCELLED: &str = "scoring given up";

/// [`score_upload`] that writes nothing once `cancel` is set (checked
/// before each report is written): a worker that lost the job's lease must
/// not write over the reports of the worker that holds it now.
pub fn score_upload_unless(
    dir: &Path,
    settings: &Settings,
    sub: &Submission,
    cancel: &AtomicBool,
) -> Result<(String, Option<String>), String> {
    let go_on = || {
        if cancel.load(Ordering::SeqCst) {
            Err(CANCELLED.to_string())
        } else {
            Ok(())
        }
    };
    let upload = dir.join("uploads").join(&sub.sha256);
    let entry_dir = |part: Part| {
        dir.join("entries")
            .join(sub.id.to_string())
            .join(part.name())
    };
    let truth = &settings.truth_dir;
    let mut opts = upload_options(settings, &upload);
    opts.name = Some(format!("entry {}", sub.id));
    let msg = |e: stepsim_harness::HarnessError| {
        if organisers_fault(&e) {
            tracing::error!(entry = sub.id, error = %e, "the run cannot be read");
            ORGANISERS_FAULT.to_string()
        } else {
            participant_message(&e.to_string(), &upload, truth)
        }
    };
    // The upload is read and checked once; both parts are scored from it.
    let prepared = prepare(&opts).map_err(msg)?;
    let public = score_prepared_part(&prepared, Part::Public, &opts).map_err(msg)?;
    go_on()?;
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
            go_on()?;
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

/// How long a job's lease lasts without renewal by default: a worker
/// renews it every third of this while it scores, so a worker killed
/// mid-scoring has its job taken again by another within this time.
pub const DEFAULT_LEASE_S: i64 = 60;

/// How a worker runs: its limit on one job, its lease, and its store when
/// not the one its state directory names.
#[derive(Debug, Clone)]
pub struct WorkerOptions {
    /// The limit on one scoring job.
    pub timeout: Duration,
    /// The lease of a job, in seconds (at least 3).
    pub lease_s: i64,
    /// The store (`None`: the state directory's).
    pub store: Option<crate::store::StoreUrl>,
}

impl Default for WorkerOptions {
    fn default() -> Self {
        Self {
            timeout: DEFAULT_TIMEOUT,
            lease_s: DEFAULT_LEASE_S,
            store: None,
        }
    }
}

/// Sleeps `d` in slices, returning early (false) once `stop` is set.
async fn nap(d: Duration, stop: &AtomicBool) -> bool {
    let end = tokio::time::Instant::now() + d;
    while tokio::time::Instant::now() < end {
        if stop.load(Ordering::Relaxed) {
            return false;
        }
        let left = end - tokio::time::Instant::now();
        tokio::time::sleep(Duration::from_millis(50).min(left)).await;
    }
    !stop.load(Ordering::Relaxed)
}

/// Runs one worker on the challenge in `dir` until `stop` is set (on a
/// runtime of its own): see `work`.
pub fn run_worker(
    dir: &Path,
    stop: Arc<AtomicBool>,
    timeout: Duration,
) -> Result<(), ChallengeError> {
    let opts = WorkerOptions {
        timeout,
        ..WorkerOptions::default()
    };
    let rt = runtime()?;
    rt.block_on(async {
        let ch = open_waiting(dir, &opts, &stop).await;
        if let Some(ch) = ch {
            work(
                &ch,
                &crate::store::worker_name(0),
                &stop,
                &opts,
                &Metrics::default(),
            )
            .await;
        }
        Ok(())
    })
}

fn runtime() -> Result<tokio::runtime::Runtime, ChallengeError> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| ChallengeError::Run(format!("cannot start a worker: {e}")))
}

/// Opens the challenge, trying again (with the backoff of [`work`]) while
/// it cannot; `None` once `stop` is set.
async fn open_waiting(dir: &Path, opts: &WorkerOptions, stop: &AtomicBool) -> Option<Challenge> {
    let mut backoff = FIRST_BACKOFF;
    loop {
        match Challenge::open_with_store(dir, opts.store.as_ref()).await {
            Ok(ch) => return Some(ch),
            Err(e) => {
                tracing::warn!(
                    error = %e,
                    retry_ms = backoff.as_millis() as u64,
                    "worker: cannot open the challenge; trying again"
                );
                if !nap(backoff, stop).await {
                    return None;
                }
                backoff = (backoff * 2).min(MAX_BACKOFF);
            }
        }
    }
}

/// Runs worker `name` on `ch` until `stop` is set: claims a job with a
/// lease, scores it (in a thread of its own, given up after the timeout)
/// while renewing the lease every third of it, and records the result,
/// counting each job in `metrics`.
///
/// A store error (the database locked or unreachable, a full disk) never
/// ends the worker: it is logged and the call is tried again after a wait
/// that doubles from [`FIRST_BACKOFF`] to [`MAX_BACKOFF`]. A result that
/// cannot be recorded is kept and recorded once the store answers, while
/// the worker still holds the lease; once the lease is lost (it ran out,
/// and another worker took the job), the result is dropped: the other
/// worker's counts, so every entry is scored once. A job under way when
/// `stop` is set is finished first.
pub async fn work(
    ch: &Challenge,
    name: &str,
    stop: &AtomicBool,
    opts: &WorkerOptions,
    metrics: &Metrics,
) {
    let lease = crate::store::Lease {
        worker: name.to_string(),
        seconds: opts.lease_s.max(3),
    };
    let renew_every = Duration::from_secs((lease.seconds / 3).max(1) as u64);
    let mut backoff = FIRST_BACKOFF;
    while !stop.load(Ordering::Relaxed) {
        let job = match ch.store.claim_job(&lease, crate::now_s()).await {
            Ok(Some(job)) => job,
            Ok(None) => {
                nap(Duration::from_millis(200), stop).await;
                continue;
            }
            Err(e) => {
                tracing::warn!(error = %e, retry_ms = backoff.as_millis() as u64,
                    "worker: cannot claim a job; trying again");
                nap(backoff, stop).await;
                backoff = (backoff * 2).min(MAX_BACKOFF);
                continue;
            }
        };
        backoff = FIRST_BACKOFF;
        tracing::info!(
            entry = job.id,
            team = job.team_id,
            worker = name,
            "scoring started"
        );
        let started = std::time::Instant::now();
        let (tx, mut rx) = tokio::sync::oneshot::channel();
        let (dir2, settings2, job2) = (ch.dir.clone(), ch.settings.clone(), job.clone());
        let cancel = Arc::new(AtomicBool::new(false));
        let cancel2 = cancel.clone();
        std::thread::spawn(move || {
            let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                score_upload_unless(&dir2, &settings2, &job2, &cancel2)
            }))
            .unwrap_or_else(|_| Err("the scorer failed on this upload".into()));
            let _ = tx.send(result);
        });
        let deadline = tokio::time::Instant::now() + opts.timeout;
        let mut held = true;
        let result = loop {
            let tick = tokio::time::sleep(renew_every);
            tokio::select! {
                r = &mut rx => {
                    break r.unwrap_or_else(|_| Err("the scorer failed on this upload".into()));
                }
                _ = tokio::time::sleep_until(deadline) => {
                    cancel.store(true, Ordering::SeqCst);
                    break Err(format!(
                        "scoring took longer than {} s and was stopped",
                        opts.timeout.as_secs()
                    ));
                }
                _ = tick => {
                    match ch.store.renew_lease(job.id, &lease, crate::now_s()).await {
                        Ok(true) => {}
                        Ok(false) => {
                            held = false;
                            break Err("lease lost".into());
                        }
                        Err(e) => tracing::warn!(entry = job.id, error = %e,
                            "worker: cannot renew the lease; trying again"),
                    }
                }
            }
        };
        if !held {
            tracing::warn!(
                entry = job.id,
                worker = name,
                "scoring abandoned: the lease ran out and another worker took the job"
            );
            // It writes nothing more; waited for (up to the job's limit)
            // so that abandoned scorings never pile up beside new jobs.
            cancel.store(true, Ordering::SeqCst);
            let _ = tokio::time::timeout_at(deadline, &mut rx).await;
            continue;
        }
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
                .finish_job(job.id, name, result.clone(), SCORER_VERSION, crate::now_s())
                .await
            {
                Ok(true) => break,
                Ok(false) => {
                    tracing::warn!(
                        entry = job.id,
                        worker = name,
                        "result dropped: the lease ran out and another worker took the job"
                    );
                    break;
                }
                Err(e) if stop.load(Ordering::Relaxed) => {
                    // Stopping: the job stays `scoring` under a lease that
                    // runs out, and another worker takes it then.
                    tracing::warn!(entry = job.id, error = %e,
                        "worker: stopping without recording the entry");
                    return;
                }
                Err(e) => {
                    tracing::warn!(entry = job.id, error = %e,
                        retry_ms = backoff.as_millis() as u64,
                        "worker: cannot record the entry; trying again");
                    // Kept under the lease meanwhile: renewed, so that no
                    // other worker scores the entry again.
                    let _ = ch.store.renew_lease(job.id, &lease, crate::now_s()).await;
                    tokio::time::sleep(backoff).await;
                    backoff = (backoff * 2).min(MAX_BACKOFF);
                }
            }
        }
        backoff = FIRST_BACKOFF;
    }
}

/// The scoring workers of a process: tasks running `work` on a thread
/// and runtime of their own, and how many of them are alive (an upload is
/// refused with 503 when none is: an accepted upload must be scored).
#[derive(Debug)]
pub struct WorkerPool {
    live: Arc<AtomicUsize>,
    metrics: Arc<Metrics>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// Counts a worker as alive until it ends, also by a panic.
struct Alive(Arc<AtomicUsize>);

impl Drop for Alive {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

impl WorkerPool {
    /// Starts `n` workers (at least one) on the challenge in `dir`.
    pub fn start(dir: &Path, n: usize, timeout: Duration) -> Self {
        Self::start_with(
            dir,
            n,
            WorkerOptions {
                timeout,
                ..WorkerOptions::default()
            },
        )
    }

    /// Starts `n` workers (at least one) on the challenge in `dir` with
    /// `opts`.
    pub fn start_with(dir: &Path, n: usize, opts: WorkerOptions) -> Self {
        let n = n.max(1);
        let live = Arc::new(AtomicUsize::new(n));
        let stop = Arc::new(AtomicBool::new(false));
        let metrics = Arc::new(Metrics::default());
        let (d, s, m, l) = (
            dir.to_path_buf(),
            stop.clone(),
            metrics.clone(),
            live.clone(),
        );
        let thread = std::thread::spawn(move || {
            let alive: Vec<Alive> = (0..n).map(|_| Alive(l.clone())).collect();
            let rt = match runtime() {
                Ok(rt) => rt,
                Err(e) => {
                    tracing::error!(error = %e, "workers stopped");
                    return;
                }
            };
            rt.block_on(async move {
                let Some(ch) = open_waiting(&d, &opts, &s).await else {
                    return;
                };
                let ch = Arc::new(ch);
                let mut tasks = tokio::task::JoinSet::new();
                for (i, a) in alive.into_iter().enumerate() {
                    let (ch, s, m, opts) = (ch.clone(), s.clone(), m.clone(), opts.clone());
                    tasks.spawn(async move {
                        let _alive = a;
                        let name = crate::store::worker_name(i);
                        work(&ch, &name, &s, &opts, &m).await;
                    });
                }
                while tasks.join_next().await.is_some() {}
            });
        });
        Self {
            live,
            metrics,
            stop,
            thread: Some(thread),
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
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
