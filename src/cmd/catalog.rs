//! `stepsim catalog`: write the base fields (truth tables and SkyMaker
//! lists) without rendering any image.
//!
//! Output, in `--out DIR`:
//! * `config.json`: the resolved config (defaults and overrides applied),
//!   including the seed: when the config gives none, one is drawn from the
//!   operating system and recorded only there (rerun with
//!   `--config DIR/config.json` to reproduce the fields);
//! * per base field k: `field_kkk.fits` (truth table, EXTNAME `TRUTH`, the
//!   SPEC §5 columns, unsheared), `field_kkk.csv` (its CSV twin) and
//!   `field_kkk.list` (SkyMaker/Stuff list);
//! * with `population.rotated_pairs`: the 90°-rotated twins
//!   `field_kkk_rot.{fits,csv,list}`.
//!
//! Everything is validated (config, object counts, input lists) before the
//! first file is written; every file is written atomically.

use super::ConfigArgs;
use std::path::PathBuf;
use stepsim_sim::SeedOrigin;
use stepsim_sim::run::products;

/// Arguments of `stepsim catalog`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    config: ConfigArgs,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
}

/// Writes the base fields of the config.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let plan = args.config.plan()?;
    super::fits_path("--out", &args.out)?;
    // The population is refused (with its key) before the memory estimate.
    stepsim_sim::model::population::preflight(&plan.population())?;
    super::check_memory(
        "catalog",
        stepsim_sim::run::memory::catalog_estimate(&plan),
        "lower population.galaxies.mag_faint, population.stars.density_per_arcmin2, image.margin_arcsec or the image size",
    )?;
    let counts = products::write_catalog(&plan, &args.out)?;
    if plan.seed_origin() == SeedOrigin::Drawn {
        eprintln!(
            "stepsim: run.seed is not given: drew one from the operating system; it is recorded in {}",
            args.out.join("config.json").display()
        );
    }
    eprintln!(
        "stepsim: {} base fields: {} galaxies, {} stars ({:.1} galaxies per field) in {}",
        counts.fields,
        counts.galaxies,
        counts.stars,
        counts.galaxies as f64 / f64::from(counts.fields.max(1)),
        args.out.display()
    );
    Ok(())
}
