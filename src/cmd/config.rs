//! `stepsim config`: validate a config and print the resolved JSON.

use super::ConfigArgs;

/// Arguments of `stepsim config`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    config: ConfigArgs,
}

/// Prints the resolved config, or refuses it with the key and reason.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let plan = args.config.plan()?;
    println!("{}", plan.raw.to_json());
    eprintln!(
        "stepsim: {}: {} PSFs × {} shears = {} datasets of {} images each",
        args.config.config.display(),
        plan.raw.psfs.len(),
        plan.raw.shears.len(),
        plan.datasets.len(),
        plan.n_fields()
    );
    Ok(())
}
