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
    /// Build the config's PSFs: FITS images, psf_report.json, a picture.
    Psf(cmd::psf::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Config(args) => cmd::config::run(&args),
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
