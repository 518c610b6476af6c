//! `stepsim generate`: make the blind data release of a config (SPEC §5).

use super::ConfigArgs;
use anyhow::Context as _;
use std::path::PathBuf;
use stepsim_contract::run_dir::RunDir;
use stepsim_sim::SeedOrigin;
use stepsim_sim::run::generate::{self, Event, Options, SeedUse, Shard};
use stepsim_sim::run::memory;

/// Arguments of `stepsim generate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    config: ConfigArgs,
    /// The run directory (public/ and private/ are made inside it).
    #[arg(long, value_name = "RUN")]
    out: PathBuf,
    /// Worker threads (0: one per core; at most 1024, and at most 4 per
    /// core are used). The output does not depend on it.
    #[arg(long, value_name = "N", default_value_t = 0, value_parser = super::threads_arg)]
    threads: usize,
    /// Make only share K of N of the images (1 ≤ K ≤ N), or `auto`: K and
    /// N of this Slurm array task (SLURM_ARRAY_TASK_ID, _COUNT, _MIN). A
    /// shard leaves private/shards/K-of-N.json; the manifest is written by
    /// `--finish` once every shard has run.
    #[arg(long, value_name = "K/N|auto", value_parser = super::shard_arg, conflicts_with = "finish")]
    shard: Option<Shard>,
    /// Finish a run made in shards: verify every image (sidecar and
    /// checksums) and write public/manifest.json; refused, listing the
    /// missing images, when one is missing (nothing is written then).
    #[arg(long)]
    finish: bool,
}

/// Runs (or resumes) the generation.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let plan = args.config.plan()?;
    super::fits_path("--out", &args.out)?;
    if plan.seed_origin() == SeedOrigin::Config {
        eprintln!(
            "stepsim: warning: run.seed is given ({}): this release is only as blind as that seed is secret; leave run.seed out for a real challenge (a secret seed is then drawn and recorded only in RUN/private/config.json)",
            plan.source().display()
        );
    }
    let threads = super::threads(args.threads);
    if args.finish {
        return finish(args, &plan, threads);
    }
    super::check_memory(
        "generate",
        memory::generate_estimate(&plan, threads),
        memory::RUN_HINT,
    )?;
    let disk = super::check_disk(&plan, &args.out)?;
    let pool = super::thread_pool(threads)?;
    let progress = super::progress::Progress::new();
    let on_event = |e: Event| progress.event(e);
    let options = Options {
        shard: args.shard.unwrap_or_default(),
        submission_format: Some(stepsim_contract::SUBMISSION_FORMAT_MD.to_string()),
        disk: Some(disk),
    };
    let summary = pool
        .install(|| generate::generate(&plan, &args.out, &options, &on_event))
        .with_context(|| format!("generating {}", args.out.display()))?;
    progress.finish();
    let config_path = RunDir::new(&args.out).private().config();
    match summary.seed {
        SeedUse::Given => {}
        SeedUse::Drawn => eprintln!(
            "stepsim: drew a secret seed from the operating system; it is recorded only in {} (keep private/ secret; rerun with --config {} to reproduce the run)",
            config_path.display(),
            config_path.display()
        ),
        SeedUse::Adopted => eprintln!(
            "stepsim: continuing the run in {} with its seed (from {})",
            args.out.display(),
            config_path.display()
        ),
    }
    if summary.removed_manifest {
        eprintln!(
            "stepsim: removed the manifest of {}: not every image is finished",
            args.out.display()
        );
    }
    if options.shard == Shard::ALL {
        eprintln!(
            "stepsim: {} written, {} already finished and verified ({} in the run)",
            super::progress::images(summary.written),
            summary.skipped,
            summary.total
        );
    } else {
        eprintln!(
            "stepsim: shard {}: {} written, {} already finished and verified ({} in this shard, {} in the run)",
            options.shard,
            super::progress::images(summary.written),
            summary.skipped,
            summary.in_shard,
            summary.total
        );
    }
    if let Some(marker) = &summary.marker {
        eprintln!(
            "stepsim: shard {} finished; wrote {} ({} of {} images of the run finished); when every shard has run: stepsim generate --config {} --out {} --finish",
            options.shard,
            marker.display(),
            summary.finished,
            summary.total,
            args.config.config.display(),
            args.out.display()
        );
    } else if summary.manifest_written {
        eprintln!(
            "stepsim: all {} images finished; wrote {}",
            summary.total,
            RunDir::new(&args.out).public().manifest().display()
        );
    } else {
        eprintln!(
            "stepsim: {} of {} images finished; the manifest is written once the other shards have run",
            summary.finished, summary.total
        );
    }
    for p in &summary.removed_tmp {
        eprintln!("stepsim: removed {} (left by a killed run)", p.display());
    }
    for p in &summary.stray_tmp {
        eprintln!(
            "stepsim: warning: leftover temporary file {} (another shard at work, or not stepsim's); it is never taken for a finished file",
            p.display()
        );
    }
    Ok(())
}

/// `--finish`: verify every image and write the manifest.
fn finish(args: &Args, plan: &stepsim_sim::Plan, threads: usize) -> anyhow::Result<()> {
    let pool = super::thread_pool(threads)?;
    match pool.install(|| generate::finish(plan, &args.out)) {
        Ok(f) => {
            eprintln!(
                "stepsim: all {} images of {} verified ({} done-markers: {}); wrote {}",
                f.total,
                args.out.display(),
                f.markers.len(),
                f.markers.join(" "),
                RunDir::new(&args.out).public().manifest().display()
            );
            Ok(())
        }
        Err(generate::GenerateError::Incomplete {
            run,
            missing,
            total,
            rerun,
            removed_manifest,
        }) => {
            for file in &missing {
                eprintln!("stepsim: missing or unverified: public/{file}");
            }
            Err(generate::GenerateError::Incomplete {
                run,
                missing,
                total,
                rerun,
                removed_manifest,
            })
            .with_context(|| format!("finishing {}", args.out.display()))
        }
        Err(e) => Err(e).with_context(|| format!("finishing {}", args.out.display())),
    }
}
