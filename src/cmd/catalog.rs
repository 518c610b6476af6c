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
use anyhow::Context as _;
use std::path::{Path, PathBuf};
use stepsim_sim::config::{Plan, SeedOrigin};
use stepsim_sim::io::{skymaker, truth, write_bytes_atomically};
use stepsim_sim::population;
use stepsim_sim::truth::TruthRow;

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
    population::preflight(&plan)?;
    super::check_memory(
        "catalog",
        stepsim_sim::memory::catalog_estimate(&plan),
        "lower population.galaxies.mag_faint, population.stars.density_per_arcmin2, image.margin_arcsec or the image size",
    )?;
    let config_path = args.out.join("config.json");
    write_bytes_atomically(&config_path, plan.raw.to_json().as_bytes())?;
    if plan.seed_origin == SeedOrigin::Drawn {
        eprintln!(
            "stepsim: run.seed is not given: drew one from the operating system; it is recorded in {}",
            config_path.display()
        );
    }
    let mut n_gal = 0usize;
    let mut n_star = 0usize;
    for field in 0..plan.n_fields() {
        let rows =
            population::base_field(&plan, field).with_context(|| format!("base field {field}"))?;
        n_star += rows.iter().filter(|r| r.is_star()).count();
        n_gal += rows.iter().filter(|r| !r.is_star()).count();
        write_field(&plan, &args.out, field, false, &rows)?;
        if plan.raw.population.rotated_pairs {
            write_field(&plan, &args.out, field, true, &population::rotated(&rows))?;
        }
    }
    eprintln!(
        "stepsim: {} base fields: {} galaxies, {} stars ({:.1} galaxies per field) in {}",
        plan.n_fields(),
        n_gal,
        n_star,
        n_gal as f64 / f64::from(plan.n_fields().max(1)),
        args.out.display()
    );
    Ok(())
}

fn write_field(
    plan: &Plan,
    out: &Path,
    field: u32,
    rotated: bool,
    rows: &[TruthRow],
) -> anyhow::Result<()> {
    let stem = format!("field_{field:03}{}", if rotated { "_rot" } else { "" });
    let im = &plan.raw.image;
    let mut keywords = stepsim_sim::generate::pipeline::field_keywords(field, rotated);
    keywords.extend([
        (
            "PIXSCALE".to_string(),
            im.pixel_scale_arcsec,
            "arcsec per pixel".to_string(),
        ),
        (
            "NAXIS1IM".to_string(),
            f64::from(im.width_px),
            "image width".to_string(),
        ),
        (
            "NAXIS2IM".to_string(),
            f64::from(im.height_px),
            "image height".to_string(),
        ),
    ]);
    truth::write_truth_fits(&out.join(format!("{stem}.fits")), rows, &keywords)?;
    truth::write_truth_csv(&out.join(format!("{stem}.csv")), rows)?;
    skymaker::write_list(
        &out.join(format!("{stem}.list")),
        rows,
        &population::t_types(plan),
    )?;
    Ok(())
}
