//! `stepsim`: STEP-style weak-lensing image simulations and blind shear-challenge scoring.
//!
//! Exit codes: 0 success; 1 the input was refused (the message says which file,
//! line or key, and why); 2 usage error (from the argument parser).

mod cmd;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// STEP-style weak-lensing image simulations and blind shear-challenge scoring.
#[derive(Debug, Parser)]
#[command(name = "stepsim", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Validate a config and print it fully resolved (defaults, overrides).
    Config(cmd::config::Args),
    /// Make the blind data release: images, truth, manifest (resumable, shardable).
    Generate(cmd::generate::Args),
    /// Time one full image stage by stage (population, PSF, galaxies, stars, noise, write).
    Bench(cmd::bench::Args),
    /// Measure shears of a public run with the KSB+ reference pipeline.
    Measure(cmd::measure::Args),
    /// Score a shear catalogue against a run's truth (report.json, report.md, plots).
    Score(cmd::score::Args),
    /// Rank several score reports in one table.
    Leaderboard(cmd::leaderboard::Args),
    /// Write the base fields (truth tables and SkyMaker lists), no images.
    Catalog(cmd::catalog::Args),
    /// Build the config's PSFs: FITS images, psf_report.json, a picture.
    Psf(cmd::psf::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Config(args) => cmd::config::run(&args),
        Command::Generate(args) => cmd::generate::run(&args),
        Command::Bench(args) => cmd::bench::run(&args),
        Command::Measure(args) => cmd::measure::run(&args),
        Command::Score(args) => cmd::score::run(&args),
        Command::Leaderboard(args) => cmd::leaderboard::run(&args),
        Command::Catalog(args) => cmd::catalog::run(&args),
        Command::Psf(args) => cmd::psf::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("stepsim: error: {e:#}");
            ExitCode::from(1)
        }
    }
}
