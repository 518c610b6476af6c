//! `stepsim`: STEP-style weak-lensing image simulations and blind shear-challenge scoring.
//!
//! Exit codes: 0 success; 1 the input was refused (the message says which file,
//! line or key, and why); 2 usage error (from the argument parser).

mod block_cache;
mod cmd;
mod huge_pages;

#[global_allocator]
static ALLOCATOR: huge_pages::HugePageAlloc = huge_pages::HugePageAlloc;

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
    /// Print a Slurm submit script: generate, measure and score as job arrays.
    Slurm(cmd::slurm::Args),
    /// Run a served challenge: init, teams and tokens, reveal, export.
    Challenge(cmd::challenge::Args),
    /// Serve a challenge over HTTP (uploads, scoring queue, leaderboard).
    Serve(cmd::serve::Args),
    /// Score a challenge's queue without serving it (several hosts may run
    /// workers on one PostgreSQL store).
    Worker(cmd::worker::Args),
}

fn main() -> ExitCode {
    huge_pages::configure();
    let cli = Cli::parse();
    // The global pool (score, leaderboard, catalog, psf) honours
    // RAYON_NUM_THREADS; bound it as `--threads` is bounded.
    if let Some(n) = std::env::var("RAYON_NUM_THREADS")
        .ok()
        .and_then(|v| v.trim().parse::<usize>().ok())
    {
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(cmd::threads_of("RAYON_NUM_THREADS", n))
            .build_global();
    }
    let result = match cli.command {
        Command::Config(args) => cmd::config::run(&args),
        Command::Generate(args) => cmd::generate::run(&args),
        Command::Bench(args) => cmd::bench::run(&args),
        Command::Measure(args) => cmd::measure::run(&args),
        Command::Score(args) => cmd::score::run(&args),
        Command::Leaderboard(args) => cmd::leaderboard::run(&args),
        Command::Catalog(args) => cmd::catalog::run(&args),
        Command::Psf(args) => cmd::psf::run(&args),
        Command::Slurm(args) => cmd::slurm::run(&args),
        Command::Challenge(args) => cmd::challenge::run(&args),
        Command::Serve(args) => cmd::serve::run(&args),
        Command::Worker(args) => cmd::worker::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("stepsim: error: {}", chain_message(&e));
            ExitCode::from(1)
        }
    }
}

/// The error and its causes joined by ": ", leaving out a cause whose text
/// the message before it already contains (a wrapper that shows its source
/// would otherwise print it twice).
fn chain_message(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if text.is_empty() || out.contains(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::chain_message;
    use std::fmt;

    #[derive(Debug)]
    struct Inner;
    impl fmt::Display for Inner {
        fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str("cannot write /d/x.fits: the disk is full")
        }
    }
    impl std::error::Error for Inner {}

    /// A wrapper whose message shows its source, and which also returns it
    /// as `source()` (what thiserror does with a field named `source`).
    #[derive(Debug)]
    struct Wrapper {
        shows: bool,
        inner: Inner,
    }
    impl fmt::Display for Wrapper {
        fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            if self.shows {
                write!(f, "base field 3: {}", self.inner)
            } else {
                f.write_str("base field 3")
            }
        }
    }
    impl std::error::Error for Wrapper {
        fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
            Some(&self.inner)
        }
    }

    #[test]
    fn a_cause_already_in_the_message_is_printed_once() {
        for shows in [true, false] {
            let e = anyhow::Error::new(Wrapper {
                shows,
                inner: Inner,
            })
            .context("generating runs/a");
            assert_eq!(
                chain_message(&e),
                "generating runs/a: base field 3: cannot write /d/x.fits: the disk is full"
            );
        }
    }
}
