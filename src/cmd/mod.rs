//! One module per subcommand; each has `Args` (clap) and `run`.

pub mod bench;
pub mod catalog;
pub mod config;
pub mod generate;
pub mod leaderboard;
pub mod measure;
pub mod psf;
pub mod score;

use std::path::PathBuf;

/// Arguments shared by every command that reads a config.
#[derive(Debug, clap::Args)]
pub struct ConfigArgs {
    /// The JSON config file (see docs/config.md).
    #[arg(long, value_name = "FILE")]
    pub config: PathBuf,
    /// Override one config value: `--set image.n_images=4` (repeatable; the
    /// value is read as JSON when it parses, as a string otherwise).
    #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
    pub overrides: Vec<String>,
}

/// The resolved config as the user gave it: with the seed when the config
/// (or a `--set`) gave one, without it when [`Plan::new`] drew it.
///
/// [`Plan::new`]: stepsim_sim::config::Plan::new
pub fn as_given(plan: &stepsim_sim::config::Plan) -> stepsim_sim::config::RawConfig {
    let mut raw = plan.raw.clone();
    if plan.seed_origin == stepsim_sim::config::SeedOrigin::Drawn {
        raw.run.seed = None;
    }
    raw
}

impl ConfigArgs {
    /// Loads and validates the config with its overrides.
    pub fn plan(&self) -> anyhow::Result<stepsim_sim::config::Plan> {
        Ok(stepsim_sim::config::Plan::load(
            &self.config,
            &self.overrides,
        )?)
    }
}
