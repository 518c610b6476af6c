//! `stepsim challenge ...`: the organiser's commands on a challenge's state
//! directory (docs/server.md). They work while `stepsim serve` runs.

use std::path::PathBuf;
use stepsim_server::{Challenge, Role, StoreUrl};

/// Reads an RFC 3339 time for `--deadline`/`--at`.
fn rfc3339(text: &str) -> Result<i64, String> {
    stepsim_server::parse_rfc3339(text)
        .ok_or_else(|| format!("{text:?} is not an RFC 3339 time such as 2026-12-31T23:59:59Z"))
}

/// Reads a role for `team mark --role`.
fn role(text: &str) -> Result<Role, String> {
    Role::from_name(text)
        .ok_or_else(|| format!("{text:?} is not a role: organisers, baseline or participant"))
}

/// Arguments of `stepsim challenge`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
    /// The store, when not the one the state directory names:
    /// postgres://USER@HOST:PORT/DATABASE (for `init`: an empty database,
    /// named then in DIR/store.url) or sqlite:PATH (default:
    /// DIR/challenge.db).
    #[arg(long, value_name = "URL", global = true)]
    store: Option<String>,
}

#[derive(Debug, clap::Subcommand)]
enum Command {
    /// Create a challenge for a run (its held-out part is scored at reveal).
    Init {
        /// The run directory (`stepsim generate --out RUN`).
        #[arg(long, value_name = "RUN")]
        run: PathBuf,
        /// The challenge's state directory (created).
        #[arg(long, value_name = "DIR")]
        state: PathBuf,
        /// Scored submissions per team per rolling 24 hours.
        #[arg(long, value_name = "N", default_value_t = stepsim_server::DEFAULT_QUOTA)]
        quota: u32,
        /// Serve a run without held-out fields (its public score is final).
        #[arg(long)]
        no_holdout: bool,
        /// Uploads are refused from this time on (RFC 3339, e.g.
        /// 2026-12-31T23:59:59Z).
        #[arg(long, value_name = "TIME", value_parser = rfc3339)]
        deadline: Option<i64>,
        /// The challenge's name shown to participants (default: the run
        /// directory's name).
        #[arg(long, value_name = "TEXT")]
        name: Option<String>,
        /// Cap on one upload in bytes, as stored and after gzip
        /// decompression (default: the run's own limit, 256 bytes per truth
        /// object and 64 KiB per image, at least 256 MiB).
        #[arg(long, value_name = "BYTES")]
        max_upload_bytes: Option<u64>,
    },
    /// Set the deadline: uploads are refused from then on.
    Deadline {
        /// The challenge's state directory.
        #[arg(long, value_name = "DIR")]
        state: PathBuf,
        /// The deadline (RFC 3339, e.g. 2026-12-31T23:59:59Z).
        #[arg(long, value_name = "TIME", value_parser = rfc3339)]
        at: i64,
    },
    /// Freeze: no more uploads (final entries can still be chosen).
    Freeze {
        /// The challenge's state directory.
        #[arg(long, value_name = "DIR")]
        state: PathBuf,
    },
    /// Close: no more uploads and no more choices of final entries.
    Close {
        /// The challenge's state directory.
        #[arg(long, value_name = "DIR")]
        state: PathBuf,
    },
    /// Queue every scored entry again for this binary's scorer (old scores
    /// are kept; the newest is shown).
    Rescore {
        /// The challenge's state directory.
        #[arg(long, value_name = "DIR")]
        state: PathBuf,
    },
    /// Set the organiser password (read from the first line of stdin; only
    /// its Argon2id hash is stored).
    OrganiserPassword {
        /// The challenge's state directory.
        #[arg(long, value_name = "DIR")]
        state: PathBuf,
    },
    /// Teams and their tokens.
    Team {
        #[command(subcommand)]
        command: TeamCommand,
    },
    /// Write the leaderboard: FILE (JSON), FILE.csv and FILE.reports/ (one
    /// report.json per ranked entry, for `stepsim leaderboard`).
    Export {
        /// The challenge's state directory.
        #[arg(long, value_name = "DIR")]
        state: PathBuf,
        /// The JSON file to write.
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
    },
    /// Reveal: held-out scores and full reports open.
    Reveal {
        /// The challenge's state directory.
        #[arg(long, value_name = "DIR")]
        state: PathBuf,
    },
}

#[derive(Debug, clap::Subcommand)]
enum TeamCommand {
    /// Add a team; its token is printed once, as the last line.
    Add {
        /// The team's name (shown on the leaderboard).
        name: String,
        /// The challenge's state directory.
        #[arg(long, value_name = "DIR")]
        state: PathBuf,
    },
    /// Give a team a new token (printed as the last line); the old one stops.
    Rotate {
        /// The team's name.
        name: String,
        /// The challenge's state directory.
        #[arg(long, value_name = "DIR")]
        state: PathBuf,
    },
    /// Revoke a team's token.
    Revoke {
        /// The team's name.
        name: String,
        /// The challenge's state directory.
        #[arg(long, value_name = "DIR")]
        state: PathBuf,
    },
    /// Mark a team as the organisers' or the baseline (shown, never
    /// ranked), or as participants (ranked; the default).
    Mark {
        /// The team's name.
        name: String,
        /// organisers, baseline or participant.
        #[arg(long, value_name = "ROLE", value_parser = role)]
        role: Role,
        /// The challenge's state directory.
        #[arg(long, value_name = "DIR")]
        state: PathBuf,
    },
}

/// Runs the command.
pub fn run(args: &Args) -> anyhow::Result<()> {
    stepsim_server::block_on(run_async(args))?
}

async fn run_async(args: &Args) -> anyhow::Result<()> {
    // Read here, not by clap, whose refusal would repeat the value (and a
    // password in it).
    let store = args
        .store
        .as_deref()
        .map(StoreUrl::parse)
        .transpose()
        .map_err(|e| anyhow::anyhow!(e))?;
    let store = store.as_ref();
    let open = async |state: &std::path::Path| Challenge::open_with_store(state, store).await;
    match &args.command {
        Command::Init {
            run,
            state,
            quota,
            no_holdout,
            deadline,
            name,
            max_upload_bytes,
        } => {
            if let Some(n) = name {
                let n = n.trim();
                if n.is_empty() || n.chars().count() > 200 || n.chars().any(char::is_control) {
                    anyhow::bail!(
                        "--name: a challenge name must be 1 to 200 characters without control characters"
                    );
                }
            }
            let mut ch = Challenge::init_with_store(run, state, *quota, *no_holdout, store).await?;
            if let Some(n) = name {
                ch.set_name(n).await?;
            }
            if deadline.is_some() {
                ch.set_deadline(*deadline).await?;
            }
            if let Some(b) = max_upload_bytes {
                ch.set_max_upload_bytes(*b).await?;
            }
            eprintln!(
                "stepsim: challenge in {} for {} (quota {} per 24 h, uploads up to {}{})",
                state.display(),
                ch.settings.truth_dir.display(),
                ch.settings.quota,
                stepsim_harness::show_bytes(ch.settings.max_upload_bytes),
                if ch.settings.holdout {
                    ", held-out part scored at reveal"
                } else {
                    ", no held-out part"
                }
            );
        }
        Command::Team { command } => match command {
            TeamCommand::Add { name, state } => {
                let token = open(state).await?.add_team(name).await?;
                println!("team {name:?} added; its token (shown only now):");
                println!("{token}");
            }
            TeamCommand::Rotate { name, state } => {
                let token = open(state).await?.rotate_token(name).await?;
                println!("team {name:?} has a new token (shown only now):");
                println!("{token}");
            }
            TeamCommand::Revoke { name, state } => {
                open(state).await?.revoke(name).await?;
                eprintln!("stepsim: the token of team {name:?} is revoked");
            }
            TeamCommand::Mark { name, role, state } => {
                open(state).await?.set_role(name, *role).await?;
                eprintln!("stepsim: team {name:?} is marked {}", role.name());
            }
        },
        Command::Export { state, out } => {
            let e = open(state).await?.export(out).await?;
            eprintln!(
                "stepsim: leaderboard written: {}, {} and {} reports",
                e.json.display(),
                e.csv.display(),
                e.reports.len()
            );
        }
        Command::Reveal { state } => {
            open(state).await?.reveal().await?;
            eprintln!("stepsim: revealed (and closed): held-out scores are on the leaderboard");
        }
        Command::Deadline { state, at } => {
            open(state).await?.set_deadline(Some(*at)).await?;
            eprintln!(
                "stepsim: uploads are refused from {}",
                stepsim_server::utc_text(*at)
            );
        }
        Command::Freeze { state } => {
            open(state).await?.freeze().await?;
            eprintln!("stepsim: frozen: no more uploads; final entries can still be chosen");
        }
        Command::Close { state } => {
            open(state).await?.close().await?;
            eprintln!("stepsim: closed: no more uploads or choices of final entries");
        }
        Command::Rescore { state } => {
            let n = open(state).await?.rescore().await?;
            eprintln!(
                "stepsim: {n} scored entries queued again for {}",
                stepsim_server::SCORER_VERSION
            );
        }
        Command::OrganiserPassword { state } => {
            let ch = open(state).await?;
            let mut line = String::new();
            std::io::stdin()
                .read_line(&mut line)
                .map_err(|e| anyhow::anyhow!("cannot read the password from stdin: {e}"))?;
            let password = line.trim_end_matches(['\n', '\r']);
            ch.set_organiser_password(password).await?;
            eprintln!("stepsim: the organiser password is set (only its hash is stored)");
        }
    }
    Ok(())
}
