//! `stepsim bench`: time one full image stage by stage (a benchmark; the
//! numbers go to BENCHMARKS.md, never into a test).

use anyhow::{Context as _, bail};
use std::path::{Path, PathBuf};
use stepsim_numerics::stats::median;
use stepsim_sim::run::generate::bench::{StageTimes, peak_memory_bytes, run_once};
use stepsim_sim::{Plan, SeedOrigin};

/// Arguments of `stepsim bench`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Config file (default: the built-in STEP1 preset, one 4096² image).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Override one config value (repeatable), as for `generate`.
    #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
    overrides: Vec<String>,
    /// Name of the PSF to use.
    #[arg(long, value_name = "NAME", default_value = "coma")]
    psf: String,
    /// Base field to draw.
    #[arg(long, value_name = "K", default_value_t = 0)]
    field: u32,
    /// Repeats; the median of each stage is reported.
    #[arg(long, value_name = "N", default_value_t = 3)]
    repeats: usize,
    /// Worker threads (0: one per core; at most 1024, and at most 4 per
    /// core are used).
    #[arg(long, value_name = "N", default_value_t = 0, value_parser = super::threads_arg)]
    threads: usize,
    /// Directory for the scratch run (default: the system temp dir); it is
    /// removed afterwards.
    #[arg(long, value_name = "DIR")]
    scratch: Option<PathBuf>,
    /// Render the objects of this SkyMaker list (as `stepsim catalog`
    /// writes it) instead of a drawn population: the same as
    /// `--set 'population.source={"skymaker_list":{"path":"FILE"}}'`, for
    /// comparing with another renderer on the same objects.
    #[arg(long, value_name = "FILE")]
    list: Option<PathBuf>,
}

/// Master seed of a benchmark whose config gives none, so that runs draw
/// the same scene and their timings compare.
pub const BENCH_SEED: u64 = 20060101;

/// The plan to time: `config` (or the built-in STEP1 preset) with
/// `overrides`; without a `run.seed` the seed is [`BENCH_SEED`], not a
/// fresh one.
fn bench_plan(config: Option<&Path>, overrides: &[String]) -> anyhow::Result<Plan> {
    let plan = match config {
        Some(path) => Plan::load(path, overrides)?,
        None => {
            let source = Path::new("<built-in STEP1 preset>");
            let overrides: Vec<&str> = overrides.iter().map(String::as_str).collect();
            Plan::from_json("{}", source, &overrides)?
        }
    };
    Ok(match plan.seed_origin() {
        SeedOrigin::Drawn => plan.with_seed(BENCH_SEED),
        SeedOrigin::Config => plan,
    })
}

/// Runs the benchmark and prints a table.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let mut overrides = args.overrides.clone();
    if let Some(list) = &args.list {
        overrides.push(list_override(list)?);
    }
    let plan = bench_plan(args.config.as_deref(), &overrides)?;
    let Some(psf_index) = plan.psf_names().iter().position(|p| *p == args.psf) else {
        let names = plan.psf_names();
        bail!(
            "--psf {}: no such PSF in the config (have: {})",
            args.psf,
            names.join(", ")
        );
    };
    if args.repeats == 0 {
        bail!("--repeats must be at least 1");
    }
    if args.field >= plan.n_fields() {
        bail!(
            "--field {} out of range (the config has {} base fields)",
            args.field,
            plan.n_fields()
        );
    }
    let threads = super::threads(args.threads);
    super::check_memory(
        "bench",
        stepsim_sim::run::memory::bench_estimate(&plan, psf_index),
        stepsim_sim::run::memory::RUN_HINT,
    )?;
    let pool = super::thread_pool(threads)?;
    let dir = args.scratch.clone().unwrap_or_else(std::env::temp_dir);
    let scratch = dir.join(format!("stepsim-bench-{}", std::process::id()));
    let mut runs: Vec<StageTimes> = Vec::new();
    for i in 0..args.repeats {
        let t = pool.install(|| run_once(&plan, psf_index, args.field, &scratch));
        let _ = std::fs::remove_dir_all(&scratch);
        let t = t.with_context(|| format!("repeat {}", i + 1))?;
        eprintln!(
            "stepsim bench: repeat {} of {}: {:.3} s",
            i + 1,
            args.repeats,
            t.total_s()
        );
        runs.push(t);
    }
    type Stage = fn(&StageTimes) -> f64;
    let stage = |f: Stage| -> (f64, f64, f64) {
        let mut v: Vec<f64> = runs.iter().map(f).collect();
        let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        (median(&mut v).unwrap_or(f64::NAN), lo, hi)
    };
    let img = &plan.geometry();
    println!(
        "image {} × {} px, seed {}, PSF {}, {} galaxies, {} stars, {} repeats, {} threads",
        img.width_px,
        img.height_px,
        plan.seed(),
        args.psf,
        runs[0].n_galaxies,
        runs[0].n_stars,
        args.repeats,
        pool.current_num_threads()
    );
    println!("| stage | median s | min s | max s |");
    println!("|---|---|---|---|");
    let rows: [(&str, Stage); 12] = [
        ("population (base field + shear)", |t| t.population_s),
        ("psf", |t| t.psf_s),
        ("galaxies", |t| t.galaxies_s),
        ("stars", |t| t.stars_s),
        ("convolve (PSF wings, split method)", |t| t.convolve_s),
        ("noise", |t| t.noise_s),
        ("write image", |t| t.write_s),
        ("truth table", |t| t.truth_s),
        ("model file", |t| t.model_s),
        ("checksums + sidecar", |t| t.checksum_s),
        ("total", |t| t.total_s()),
        ("total without population and psf", |t| {
            t.total_s() - t.population_s - t.psf_s
        }),
    ];
    for (name, f) in rows {
        let (m, lo, hi) = stage(f);
        println!("| {name} | {m:.3} | {lo:.3} | {hi:.3} |");
    }
    let (gal, _, _) = stage(|t| t.galaxies_s);
    println!(
        "µs wall per galaxy (galaxy stage wall time / galaxies): {:.1}",
        gal * 1e6 / runs[0].n_galaxies.max(1) as f64
    );
    let n_gal = runs[0].n_galaxies.max(1) as f64;
    let (gal_cpu, _, _) = stage(|t| t.galaxies_cpu_s);
    let (conv_cpu, _, _) = stage(|t| t.convolve_cpu_s);
    let (total_cpu, _, _) = stage(|t| t.total_cpu_s);
    println!(
        "µs CPU per galaxy: galaxy stage {:.1}; with the image convolution {:.1}; whole image {:.1} (CPU {:.2} s)",
        gal_cpu * 1e6 / n_gal,
        (gal_cpu + conv_cpu) * 1e6 / n_gal,
        total_cpu * 1e6 / n_gal,
        total_cpu
    );
    let (noise_cpu, _, _) = stage(|t| t.noise_cpu_s);
    println!("noise CPU s: {noise_cpu:.3}");
    match peak_memory_bytes() {
        Some(b) => println!("peak memory (VmHWM): {:.1} MiB", b as f64 / 1048576.0),
        None => println!("peak memory (VmHWM): unavailable"),
    }
    Ok(())
}

/// The `--set` that makes the population the SkyMaker list `path` (made
/// absolute, so that it does not depend on the config's directory).
fn list_override(path: &Path) -> anyhow::Result<String> {
    let abs = std::path::absolute(path)
        .with_context(|| format!("--list {}: cannot resolve the path", path.display()))?;
    let Some(text) = abs.to_str() else {
        bail!("--list {}: the path is not valid UTF-8", path.display());
    };
    let json = serde_json::json!({ "skymaker_list": { "path": text } });
    Ok(format!("population.source={json}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_benchmark_without_a_seed_uses_the_fixed_one() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = dir.path().join("c.json");
        std::fs::write(&cfg, "{}").unwrap();
        for config in [None, Some(cfg.as_path())] {
            assert_eq!(bench_plan(config, &[]).unwrap().seed(), BENCH_SEED);
            let given = bench_plan(config, &["run.seed=7".into()]).unwrap();
            assert_eq!(given.seed(), 7);
        }
    }

    #[test]
    fn a_list_becomes_the_population_source() {
        let dir = tempfile::tempdir().unwrap();
        let list = dir.path().join("f.list");
        std::fs::write(&list, "100 10.0 12.0 20.0\n").unwrap();
        let set = list_override(&list).unwrap();
        let plan = bench_plan(None, &[set, "image.n_images=1".into()]).unwrap();
        let rows = stepsim_sim::model::population::base_field(&plan.population(), 0).unwrap();
        assert_eq!(rows.len(), 1);
        assert!(rows[0].is_star() && (rows[0].x, rows[0].y) == (10.0, 12.0));
    }
}
