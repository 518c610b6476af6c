//! `stepsim config`: validate a config and print the resolved JSON (without a
//! seed when the config gives none: each `generate` draws its own).

use super::ConfigArgs;
use stepsim_sim::SeedOrigin;

/// Arguments of `stepsim config`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    config: ConfigArgs,
}

/// Prints the resolved config, or refuses it with the key and reason.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let plan = args.config.plan()?;
    println!("{}", plan.config_json_as_given());
    eprintln!(
        "stepsim: {}: {} PSFs × {} shears = {} datasets of {} base fields each",
        args.config.config.display(),
        plan.n_psfs(),
        plan.shears().len(),
        plan.datasets().len(),
        plan.datasets()[0].fields.len()
    );
    match plan.seed_origin() {
        SeedOrigin::Config => eprintln!(
            "stepsim: run.seed is given: a release made with it is only as blind as the seed is secret"
        ),
        SeedOrigin::Drawn => eprintln!(
            "stepsim: run.seed is not given: `generate` draws a secret one and records it only in RUN/private/config.json"
        ),
    }
    Ok(())
}
