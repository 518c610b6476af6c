//! `stepsim serve`: the challenge's web server and scoring workers.

use std::path::PathBuf;
use std::time::Duration;
use stepsim_server::{
    DEFAULT_BODY_GRACE, DEFAULT_BODY_MIN_BYTES_PER_S, DEFAULT_BODY_STALL_TIMEOUT,
    DEFAULT_CHECK_BUDGET, DEFAULT_HEADER_TIMEOUT, DEFAULT_IDLE_TIMEOUT, DEFAULT_MAX_CONNECTIONS,
    DEFAULT_MAX_CONNECTIONS_PER_ADDR, DEFAULT_UPLOADS_AT_ONCE, DEFAULT_UPLOADS_PER_TEAM, Limits,
    StoreUrl, default_checks_at_once,
};

/// What `serve` and `worker` share: the store, and how a job is run.
#[derive(Debug, clap::Args)]
pub struct WorkerArgs {
    /// The store, when not the one the state directory names:
    /// postgres://USER@HOST:PORT/DATABASE or sqlite:PATH.
    #[arg(long, value_name = "URL")]
    store: Option<String>,
    /// Give up a scoring job after this many seconds.
    #[arg(long, value_name = "S", default_value_t = 600)]
    timeout_s: u64,
    /// A job's lease: a worker renews it every third of this while it
    /// scores; a job whose worker died is taken again once it runs out.
    #[arg(long, value_name = "S", default_value_t = stepsim_server::DEFAULT_LEASE_S,
          value_parser = clap::value_parser!(i64).range(3..=86_400))]
    lease_s: i64,
}

impl WorkerArgs {
    /// The worker's options; refuses a `--store` that is not a store
    /// address (read here, not by clap, whose refusal would repeat the
    /// value and a password in it).
    pub fn options(&self) -> anyhow::Result<stepsim_server::WorkerOptions> {
        let store = self
            .store
            .as_deref()
            .map(StoreUrl::parse)
            .transpose()
            .map_err(|e| anyhow::anyhow!(e))?;
        Ok(stepsim_server::WorkerOptions {
            timeout: Duration::from_secs(self.timeout_s),
            lease_s: self.lease_s,
            store,
        })
    }
}

/// Arguments of `stepsim serve` (the limits: docs/server.md, "Threat model").
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The challenge's state directory (`stepsim challenge init`).
    #[arg(long, value_name = "DIR")]
    state: PathBuf,
    /// Address to listen on.
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:8080")]
    listen: String,
    /// Scoring workers of this process (one running job per team); 0 when
    /// `stepsim worker` processes score the queue.
    #[arg(long, value_name = "N", default_value_t = 1)]
    workers: usize,
    #[command(flatten)]
    worker: WorkerArgs,
    /// Close a connection whose request headers take longer (from their first byte).
    #[arg(long, value_name = "S", default_value_t = DEFAULT_HEADER_TIMEOUT.as_secs())]
    header_timeout_s: u64,
    /// Close a connection with no request in flight and no traffic for this long.
    #[arg(long, value_name = "S", default_value_t = DEFAULT_IDLE_TIMEOUT.as_secs())]
    idle_timeout_s: u64,
    /// Cut off a request body that sends nothing for this long (408).
    #[arg(long, value_name = "S", default_value_t = DEFAULT_BODY_STALL_TIMEOUT.as_secs())]
    body_stall_s: u64,
    /// Cut off a request body slower than this on average after the first body-grace seconds.
    #[arg(long, value_name = "BYTES", default_value_t = DEFAULT_BODY_MIN_BYTES_PER_S)]
    body_min_bytes_per_s: u64,
    /// See --body-min-bytes-per-s.
    #[arg(long, value_name = "S", default_value_t = DEFAULT_BODY_GRACE.as_secs())]
    body_grace_s: u64,
    /// Connections open at once, all clients.
    #[arg(long, value_name = "N", default_value_t = DEFAULT_MAX_CONNECTIONS)]
    max_connections: usize,
    /// Connections open at once from one client address (raise it behind a proxy).
    #[arg(long, value_name = "N", default_value_t = DEFAULT_MAX_CONNECTIONS_PER_ADDR)]
    max_connections_per_addr: usize,
    /// Uploads of one team received or checked at once.
    #[arg(long, value_name = "N", default_value_t = DEFAULT_UPLOADS_PER_TEAM)]
    uploads_per_team: usize,
    /// Uploads received or checked at once, all teams.
    #[arg(long, value_name = "N", default_value_t = DEFAULT_UPLOADS_AT_ONCE)]
    uploads_at_once: usize,
    /// Format checks at once (default: one per core).
    #[arg(long, value_name = "N")]
    checks_at_once: Option<usize>,
    /// Wall-clock budget of one format check, its wait for a turn included.
    #[arg(long, value_name = "S", default_value_t = DEFAULT_CHECK_BUDGET.as_secs())]
    check_budget_s: u64,
    /// The log on standard error: `plain` (a line of text an event) or
    /// `json` (a JSON object a line).
    #[arg(long, value_name = "FORMAT", default_value = "plain", value_parser = ["plain", "json"])]
    log_format: String,
    /// Let anyone who reaches the server read `/metrics` (default: the
    /// organisers' token or signed-in session only).
    #[arg(long)]
    open_metrics: bool,
}

/// Serves until the process ends.
pub fn run(args: &Args) -> anyhow::Result<()> {
    stepsim_server::init_logging(
        stepsim_server::LogFormat::from_name(&args.log_format).unwrap_or_default(),
    );
    let limits = Limits {
        header_timeout: Duration::from_secs(args.header_timeout_s),
        idle_timeout: Duration::from_secs(args.idle_timeout_s),
        body_stall_timeout: Duration::from_secs(args.body_stall_s),
        body_min_bytes_per_s: args.body_min_bytes_per_s,
        body_grace: Duration::from_secs(args.body_grace_s),
        max_connections: args.max_connections,
        max_connections_per_addr: args.max_connections_per_addr,
        uploads_per_team: args.uploads_per_team,
        uploads_at_once: args.uploads_at_once,
        checks_at_once: args.checks_at_once.unwrap_or_else(default_checks_at_once),
        check_budget: Duration::from_secs(args.check_budget_s),
    };
    stepsim_server::serve_blocking(
        args.state.clone(),
        &args.listen,
        args.workers,
        args.worker.options()?,
        limits,
        args.open_metrics,
    )?;
    Ok(())
}
