//! `stepsim worker`: scoring workers without a web server, on this host or
//! another that shares the challenge's state directory and database.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};

/// Set by SIGINT or SIGTERM.
static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_stop(_: libc::c_int) {
    // An atomic store: safe in a signal handler.
    STOP.store(true, Ordering::SeqCst);
}

/// Arguments of `stepsim worker`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The challenge's state directory (shared with the servers: uploads
    /// are read from it, reports written to it).
    #[arg(long, value_name = "DIR")]
    state: PathBuf,
    /// Scoring workers in this process (each scores one job at a time).
    #[arg(long, value_name = "N", default_value_t = 1)]
    threads: usize,
    #[command(flatten)]
    worker: super::serve::WorkerArgs,
    /// The log on standard error: `plain` or `json`.
    #[arg(long, value_name = "FORMAT", default_value = "plain", value_parser = ["plain", "json"])]
    log_format: String,
}

/// Scores the queue until the process is stopped (SIGINT or SIGTERM end
/// it after the jobs under way).
pub fn run(args: &Args) -> anyhow::Result<()> {
    stepsim_server::init_logging(
        stepsim_server::LogFormat::from_name(&args.log_format).unwrap_or_default(),
    );
    for sig in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: `on_stop` only stores to an atomic, which is
        // async-signal-safe; the handler stays valid for the process.
        unsafe {
            libc::signal(sig, on_stop as *const () as libc::sighandler_t);
        }
    }
    let opts = args.worker.options()?;
    // Opened once here so that a wrong directory or store is an error now,
    // not a retry loop.
    stepsim_server::block_on(stepsim_server::Challenge::open_with_store(
        &args.state,
        opts.store.as_ref(),
    ))??;
    let pool = stepsim_server::WorkerPool::start_with(&args.state, args.threads.max(1), opts);
    eprintln!(
        "stepsim worker: {} worker(s) scoring the queue of {}",
        args.threads.max(1),
        args.state.display()
    );
    while !STOP.load(Ordering::SeqCst) && pool.live().load(Ordering::SeqCst) > 0 {
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    pool.stop();
    Ok(())
}
