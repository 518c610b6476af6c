//! `stepsim challenge ...`: the organiser's commands on a challenge's state
//! directory (docs/server.md). They work while `stepsim serve` runs.

use std::path::PathBuf;
use stepsim_server::Challenge;

/// Arguments of `stepsim challenge`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
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
        #[arg(long, value_name = "N", default_value_t = stepsim_server::challenge::DEFAULT_QUOTA)]
        quota: u32,
        /// Serve a run without held-out fields (its public score is final).
        #[arg(long)]
        no_holdout: bool,
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
}

/// Runs the command.
pub fn run(args: &Args) -> anyhow::Result<()> {
    match &args.command {
        Command::Init {
            run,
            state,
            quota,
            no_holdout,
        } => {
            let ch = Challenge::init(run, state, *quota, *no_holdout)?;
            eprintln!(
                "stepsim: challenge in {} for {} (quota {} per 24 h{})",
                state.display(),
                ch.settings.truth_dir.display(),
                ch.settings.quota,
                if ch.settings.holdout {
                    ", held-out part scored at reveal"
                } else {
                    ", no held-out part"
                }
            );
        }
        Command::Team { command } => match command {
            TeamCommand::Add { name, state } => {
                let token = Challenge::open(state)?.add_team(name)?;
                println!("team {name:?} added; its token (shown only now):");
                println!("{token}");
            }
            TeamCommand::Rotate { name, state } => {
                let token = Challenge::open(state)?.rotate_token(name)?;
                println!("team {name:?} has a new token (shown only now):");
                println!("{token}");
            }
            TeamCommand::Revoke { name, state } => {
                Challenge::open(state)?.revoke(name)?;
                eprintln!("stepsim: the token of team {name:?} is revoked");
            }
        },
        Command::Export { state, out } => {
            let e = Challenge::open(state)?.export(out)?;
            eprintln!(
                "stepsim: leaderboard written: {}, {} and {} reports",
                e.json.display(),
                e.csv.display(),
                e.reports.len()
            );
        }
        Command::Reveal { state } => {
            Challenge::open(state)?.reveal()?;
            eprintln!("stepsim: revealed: held-out scores are on the leaderboard");
        }
    }
    Ok(())
}
