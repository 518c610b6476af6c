//! `stepsim score`: score a submission against a run's truth (SPEC §6, §7).

use std::path::PathBuf;
use stepsim_harness::{DEFAULT_MATCH_RADIUS_ARCSEC, ScoreOptions};

/// Arguments of `stepsim score`.
#[derive(Debug, clap::Args)]
#[command(after_long_help = stepsim_contract::SUBMISSION_FORMAT_MD)]
pub struct Args {
    /// The private half of the run (`RUN/private`: datasets.json, truth/).
    #[arg(long, value_name = "DIR", required_unless_present = "combine")]
    truth: Option<PathBuf>,
    /// The submission: a table (whitespace with `#` header, CSV, FITS) or a
    /// directory of per-image tables `<image-id>.<ext>`.
    #[arg(long, value_name = "PATH", required_unless_present = "combine")]
    submission: Option<PathBuf>,
    /// Instead of scoring: combine the reports (report directories or
    /// report.json files) of runs that each hold some of the PSFs into one
    /// report, its summary recomputed over all their PSFs (no bootstrap
    /// intervals; docs/scoring.md).
    #[arg(long, value_name = "REPORT", num_args = 2.., conflicts_with_all = ["truth", "submission", "allow_missing_images", "match_radius_arcsec", "bootstrap_resamples"])]
    combine: Vec<PathBuf>,
    /// Where to write report.json, report.md and the plots.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Name of the submission in the report (default: its file name).
    #[arg(long)]
    name: Option<String>,
    /// Match radius between submitted and true positions.
    #[arg(long, value_name = "ARCSEC", default_value_t = DEFAULT_MATCH_RADIUS_ARCSEC,
          value_parser = positive_arcsec)]
    match_radius_arcsec: f64,
    /// Score a submission that lacks some images (they are left out).
    #[arg(long)]
    allow_missing_images: bool,
    /// Bootstrap resamples of the base fields for the intervals; 0 leaves
    /// the intervals out (a faster score, e.g. while developing a method).
    #[arg(long, value_name = "N", default_value_t = stepsim_harness::DEFAULT_RESAMPLES)]
    bootstrap_resamples: usize,
    /// Largest submission read, in bytes, as stored and after gzip
    /// decompression (the sum over a directory's files). Default: the run's
    /// own limit, 256 bytes per truth object and 64 KiB per image, at least
    /// 256 MiB (docs/scoring.md).
    #[arg(long, value_name = "N", conflicts_with = "combine")]
    max_submission_bytes: Option<u64>,
    /// Overwrite the files of an earlier report in --out.
    #[arg(long)]
    force: bool,
}

/// Scores and writes the report.
pub fn run(args: &Args) -> anyhow::Result<()> {
    stepsim_harness::check_outputs_free(&args.out, args.force)?;
    let report = match (&args.truth, &args.submission) {
        (Some(truth), Some(submission)) if args.combine.is_empty() => {
            super::fits_path("--truth", truth)?;
            super::fits_path("--submission", submission)?;
            let mut opts = ScoreOptions::new(truth, submission);
            opts.name = args.name.clone();
            opts.match_radius_arcsec = args.match_radius_arcsec;
            opts.allow_missing_images = args.allow_missing_images;
            opts.bootstrap_resamples = args.bootstrap_resamples;
            opts.max_submission_bytes = args.max_submission_bytes;
            stepsim_harness::score(&opts)?
        }
        _ => stepsim_harness::combine_files(&args.combine, args.name.as_deref())?,
    };
    stepsim_harness::write_outputs(&args.out, &report, args.force)?;
    for w in &report.warnings {
        eprintln!("stepsim: warning: {w}");
    }
    let s = &report.summary;
    let f = |v: Option<f64>| v.map_or("—".to_owned(), |x| format!("{x:.4}"));
    eprintln!(
        "stepsim: {}: <m> = {}, sigma_c = {}, <q> = {}, Q_c = {}; report in {}",
        report.submission,
        f(s.m_mean),
        f(s.sigma_c),
        f(s.q_mean),
        f(s.q_c),
        args.out.display()
    );
    Ok(())
}

/// A usage check (exit 2): the match radius must be a finite number > 0.
fn positive_arcsec(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        Ok(v) => Err(format!("must be a positive number of arcsec, got {v}")),
        Err(e) => Err(e.to_string()),
    }
}
