//! Scoring end to end: read the truth set and the submission, match image
//! by image, compute the metrics, write the report. The stages are public so
//! that the benchmark can time them.

use crate::error::HarnessError;
use crate::read::submission::{Submission, read_submission_limited};
use crate::read::truth_set::{TruthSet, load_truth_set, run_submission_limit};
use crate::score::bootstrap::{DEFAULT_RESAMPLES, DEFAULT_SEED, bootstrap};
use crate::score::isolation::{Isolation, Plane};
use crate::score::metrics::{
    DISK_EDGES_ARCSEC, DatasetMeta, ImageStats, MAG_EDGES, binned_residuals, match_image,
    score_tables,
};
use crate::score::report::Report;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Default match radius (SPEC §7, the paper's 1″).
pub const DEFAULT_MATCH_RADIUS_ARCSEC: f64 = 1.0;

/// What to score and how.
#[derive(Debug, Clone)]
pub struct ScoreOptions {
    /// `RUN/private`.
    pub truth_dir: PathBuf,
    /// The submission file or directory.
    pub submission: PathBuf,
    /// Name in the report (default: the submission's file name).
    pub name: Option<String>,
    /// Match radius.
    pub match_radius_arcsec: f64,
    /// Score a partial submission.
    pub allow_missing_images: bool,
    /// Bootstrap resamples (0: no intervals).
    pub bootstrap_resamples: usize,
    /// Bootstrap seed.
    pub bootstrap_seed: u64,
    /// Largest submission read, in bytes, as stored and after gzip
    /// decompression (`None`: the run's own limit,
    /// [`crate::read::truth_set::run_submission_limit`]).
    pub max_submission_bytes: Option<u64>,
}

impl ScoreOptions {
    /// Options with the defaults of `stepsim score`.
    pub fn new(truth_dir: impl Into<PathBuf>, submission: impl Into<PathBuf>) -> Self {
        Self {
            truth_dir: truth_dir.into(),
            submission: submission.into(),
            name: None,
            match_radius_arcsec: DEFAULT_MATCH_RADIUS_ARCSEC,
            allow_missing_images: false,
            bootstrap_resamples: DEFAULT_RESAMPLES,
            bootstrap_seed: DEFAULT_SEED,
            max_submission_bytes: None,
        }
    }
}

/// Truth set and submission, read and checked.
#[derive(Debug, Clone)]
pub struct Prepared {
    /// The private half of the run.
    pub truth: TruthSet,
    /// The submission.
    pub submission: Submission,
    /// Warnings for the report.
    pub warnings: Vec<String>,
}

/// Stage 1: reads and checks the truth set and the submission, streamed
/// ([`read_submission_limited`]: the rows are spilled by image to a
/// temporary file, so memory holds no more than one table's buffer and the
/// files being read, whatever the catalogue's size). This is also the
/// server's format check.
pub fn prepare(opts: &ScoreOptions) -> Result<Prepared, HarnessError> {
    prepare_with(opts, read_submission_limited)
}

/// [`prepare`] reading the submission whole into memory
/// ([`crate::read::submission::read_submission_slow`]): the slow twin of the
/// streamed path, kept to test that both give the same report.
pub fn prepare_slow(opts: &ScoreOptions) -> Result<Prepared, HarnessError> {
    prepare_with(opts, crate::read::submission::read_submission_slow)
}

/// Reads a submission against an index within a byte limit.
type Reader =
    fn(&Path, &crate::read::truth_set::ImageIndex, u64) -> Result<Submission, HarnessError>;

fn prepare_with(opts: &ScoreOptions, read: Reader) -> Result<Prepared, HarnessError> {
    let r = opts.match_radius_arcsec;
    if !(r > 0.0 && r.is_finite()) {
        return Err(HarnessError::BadOption {
            name: "--match-radius-arcsec".into(),
            message: format!("{r} is not a positive number"),
        });
    }
    let truth = load_truth_set(&opts.truth_dir)?;
    let limit = match opts.max_submission_bytes {
        Some(n) => n,
        None => run_submission_limit(&truth)?,
    };
    let submission = read(&opts.submission, &truth.index, limit)?;
    let missing = submission.missing_images();
    let mut warnings = Vec::new();
    if !missing.is_empty() {
        if !opts.allow_missing_images {
            // Named by the smallest ids, not the first in `datasets.json`
            // order, which is private (issue #23).
            return Err(HarnessError::missing_images(
                &opts.submission,
                missing
                    .iter()
                    .map(|&i| truth.index.images[i].image.as_str()),
                truth.index.images.len(),
            ));
        }
        warnings.push(format!(
            "{} of {} images have no rows and are not scored",
            missing.len(),
            truth.index.images.len()
        ));
    }
    if !submission.ignored_columns.is_empty() {
        warnings.push(format!(
            "columns ignored: {}",
            submission.ignored_columns.join(", ")
        ));
    }
    Ok(Prepared {
        truth,
        submission,
        warnings,
    })
}

/// Stage 2: reads the truth table of every submitted image, matches its rows
/// and reduces it to [`ImageStats`] (in parallel, in image order; each
/// worker holds one image's rows and truth table at a time).
pub fn match_images(p: &Prepared, radius_arcsec: f64) -> Result<Vec<ImageStats>, HarnessError> {
    let which: Vec<usize> = (0..p.truth.index.images.len())
        .filter(|&i| p.submission.image_len(i) > 0)
        .collect();
    let radius_px = radius_arcsec / p.truth.index.pixel_scale_arcsec;
    let scale = p.truth.index.pixel_scale_arcsec;
    which
        .par_iter()
        .map(|&i| {
            let info = &p.truth.index.images[i];
            let plane = isolation_plane(&p.truth, info.dataset);
            let path = p.truth.truth_path(&info.image);
            let truth = crate::read::truth_set::read_scoring_columns(&path)?;
            let rows = p.submission.image_rows(i)?;
            Ok(match_image(
                info.dataset,
                info.field,
                &rows,
                &truth,
                radius_px,
                (p.truth.index.width_px, p.truth.index.height_px),
                Isolation::standard(scale, plane),
            ))
        })
        .collect()
}

/// Where dataset `d`'s isolated galaxies are classed: in the source plane
/// (its shear undone) when the run lensed its galaxies' positions, else in
/// the image plane (docs/scoring.md, "Isolated galaxies").
pub fn isolation_plane(truth: &TruthSet, d: usize) -> Plane {
    let ds = &truth.datasets.datasets[d];
    if truth.lensed_positions {
        Plane::Source {
            g1: ds.g1,
            g2: ds.g2,
        }
    } else {
        Plane::Image
    }
}

/// Stage 3: the metrics, the bootstrap and the report.
pub fn build_report(p: &Prepared, stats: &[ImageStats], opts: &ScoreOptions) -> Report {
    let meta = DatasetMeta::of_run(&p.truth.datasets);
    let area = p.truth.index.image_area_arcmin2();
    let scores = score_tables(&meta, stats, area);
    let mut summary = scores.summary;
    if opts.bootstrap_resamples > 0 {
        summary.bootstrap = Some(bootstrap(
            &meta,
            stats,
            area,
            opts.bootstrap_resamples,
            opts.bootstrap_seed,
        ));
    }
    let mut warnings = p.warnings.clone();
    let zero_w = stats.iter().filter(|s| s.sw <= 0.0).count();
    if zero_w > 0 {
        warnings.push(format!(
            "{zero_w} images have zero total weight and do not enter the shear means"
        ));
    }
    let name = opts.name.clone().unwrap_or_else(|| {
        opts.submission
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| opts.submission.display().to_string())
    });
    Report {
        submission: name,
        run: p.truth.run.clone(),
        match_radius_arcsec: opts.match_radius_arcsec,
        isolation_plane: crate::score::isolation::IsolationPlane::of_run(p.truth.lensed_positions),
        datasets: scores.datasets,
        psfs: scores.psfs,
        summary,
        by_magnitude: binned_residuals(&meta, stats, "mag", &MAG_EDGES, |s| &s.by_mag),
        by_disk_size: binned_residuals(&meta, stats, "disk_h_arcsec", &DISK_EDGES_ARCSEC, |s| {
            &s.by_disk
        }),
        warnings,
    }
}

/// All three stages.
pub fn score(opts: &ScoreOptions) -> Result<Report, HarnessError> {
    let p = prepare(opts)?;
    let stats = match_images(&p, opts.match_radius_arcsec)?;
    Ok(build_report(&p, &stats, opts))
}

/// [`score`] with the submission read whole ([`prepare_slow`]): the slow
/// twin, whose report the streamed one must equal.
pub fn score_slow(opts: &ScoreOptions) -> Result<Report, HarnessError> {
    let p = prepare_slow(opts)?;
    let stats = match_images(&p, opts.match_radius_arcsec)?;
    Ok(build_report(&p, &stats, opts))
}

/// File name of the JSON report.
pub const REPORT_JSON: &str = "report.json";
/// File name of the Markdown report.
pub const REPORT_MD: &str = "report.md";

/// Base names of the plots `score` writes, each as `.svg` and `.png`.
pub const REPORT_FIGURES: [&str; 4] = [
    "fig2_shear_response",
    "fig3_m_sigma_c",
    "fig4_mselc_muncontaminated",
    "fig5_residual_magnitude",
];

/// Every file [`write_outputs`] writes into `dir`, in the order written.
pub fn output_paths(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = REPORT_FIGURES
        .iter()
        .flat_map(|n| [dir.join(format!("{n}.svg")), dir.join(format!("{n}.png"))])
        .collect();
    v.push(dir.join(REPORT_MD));
    v.push(dir.join(REPORT_JSON));
    v
}

/// Refuses, unless `force`, when any of the files `score` writes into `dir`
/// already exists (or is a link, even a broken one), naming the first.
pub fn check_outputs_free(dir: &Path, force: bool) -> Result<(), HarnessError> {
    if force {
        return Ok(());
    }
    match output_paths(dir)
        .into_iter()
        .find(|p| std::fs::symlink_metadata(p).is_ok())
    {
        Some(path) => Err(HarnessError::ReportExists { path }),
        None => Ok(()),
    }
}

/// Writes `DIR/report.json`, `DIR/report.md` and the plots
/// ([`output_paths`]), each atomically (the JSON last). Refuses when any of
/// them exists unless `force` ([`check_outputs_free`]). Returns the paths
/// written.
pub fn write_outputs(
    dir: &Path,
    report: &Report,
    force: bool,
) -> Result<Vec<PathBuf>, HarnessError> {
    check_outputs_free(dir, force)?;
    let json_path = dir.join(REPORT_JSON);
    let mut files: Vec<(PathBuf, Vec<u8>)> = Vec::new();
    for (name, fig) in crate::report::plots::report_figures(report) {
        files.push((dir.join(format!("{name}.svg")), fig.to_svg().into_bytes()));
        let png = dir.join(format!("{name}.png"));
        let bytes = fig.to_png().map_err(|e| HarnessError::Report {
            path: png.clone(),
            message: e.to_string(),
        })?;
        files.push((png, bytes));
    }
    files.push((
        dir.join(REPORT_MD),
        crate::report::markdown::report_markdown(report).into_bytes(),
    ));
    let mut json = serde_json::to_string_pretty(report).unwrap_or_default();
    json.push('\n');
    files.push((json_path, json.into_bytes()));
    let mut written = Vec::new();
    for (path, bytes) in files {
        stepsim_contract::io::write_bytes_atomically(&path, &bytes)?;
        written.push(path);
    }
    Ok(written)
}
