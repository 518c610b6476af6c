//! `stepsim serve`: the challenge's web server and scoring workers.

use std::path::PathBuf;

/// Arguments of `stepsim serve`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The challenge's state directory (`stepsim challenge init`).
    #[arg(long, value_name = "DIR")]
    state: PathBuf,
    /// Address to listen on.
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:8080")]
    listen: String,
    /// Scoring workers (one running job per team).
    #[arg(long, value_name = "N", default_value_t = 1)]
    workers: usize,
    /// Give up a scoring job after this many seconds.
    #[arg(long, value_name = "S", default_value_t = 600)]
    timeout_s: u64,
}

/// Serves until the process ends.
pub fn run(args: &Args) -> anyhow::Result<()> {
    stepsim_server::api::serve_blocking(
        args.state.clone(),
        &args.listen,
        args.workers,
        std::time::Duration::from_secs(args.timeout_s),
    )?;
    Ok(())
}
