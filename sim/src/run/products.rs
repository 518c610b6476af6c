//! What a plan makes besides a run: the PSF set of `stepsim psf` and the
//! base-field catalogue of `stepsim catalog`. The commands parse, call one
//! function of this module and print.

use crate::io::psf_fits::{self, renderer_side_px, write_psf};
use crate::io::skymaker;
use crate::model::population::{self, PopulationError};
use crate::model::psf::{self, PsfError, PsfReport, panel};
use crate::run::plan::Plan;
use rayon::prelude::*;
use std::path::Path;
use stepsim_contract::io::{IoError, truth, write_bytes_atomically};
use stepsim_contract::truth::TruthRow;
use stepsim_figure::png::write_picture;

/// Why a product could not be made.
#[derive(Debug, thiserror::Error)]
pub enum ProductError {
    /// A PSF could not be built or measured.
    #[error(transparent)]
    Psf(#[from] PsfError),
    /// A base field could not be drawn.
    #[error("base field {field}: {source}")]
    Population {
        /// The base field.
        field: u32,
        /// What went wrong.
        source: PopulationError,
    },
    /// The population is refused before anything is written.
    #[error(transparent)]
    Preflight(PopulationError),
    /// A file could not be written.
    #[error(transparent)]
    Io(#[from] IoError),
    /// The worker threads could not be started.
    #[error("cannot start {workers} worker threads: {message}")]
    Threads {
        /// How many were asked for.
        workers: usize,
        /// What the thread pool said.
        message: String,
    },
}

/// Options of [`write_psf_set`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PsfSetOptions {
    /// Side of the pixel-scale image; `None`: the extent the renderer gives
    /// each PSF ([`renderer_side_px`]).
    pub size_px: Option<usize>,
    /// Samples per pixel of the oversampled image.
    pub oversample: usize,
    /// PSFs built at the same time (each optical one holds ~200 MB).
    pub workers: usize,
}

/// Side of the largest PSF file image [`write_psf_set`] may write (for the
/// memory estimate before any work).
pub fn largest_psf_side_px(plan: &Plan, size_px: Option<usize>) -> usize {
    size_px.unwrap_or((plan.accuracy().max_stamp_px + 2).max(psf_fits::DEFAULT_SIZE_PX))
}

/// One PSF of the set, built, measured and drawn.
struct DonePsf {
    report: PsfReport,
    core: Vec<f64>,
    wing: Vec<f64>,
}

/// Builds every PSF of the plan and writes, in `out`: `<name>.fits` per PSF,
/// `psf_report.json` (`config_label` names the config in it),
/// `config.json` (the resolved config as given: a drawn seed is left out,
/// PSFs do not depend on it) and `psf_cores.png` (cores, differences to the
/// first PSF, wings). PSFs are built `workers` at a time on a rayon pool;
/// `on_built` is called (from a worker) with each report and the seconds
/// it took. Returns the reports in config order.
pub fn write_psf_set(
    plan: &Plan,
    out: &Path,
    config_label: &str,
    options: PsfSetOptions,
    on_built: &(dyn Fn(&PsfReport, f64) + Sync),
) -> Result<Vec<PsfReport>, ProductError> {
    let p = plan.pixel_scale_arcsec();
    let max_stamp_px = plan.accuracy().max_stamp_px;
    let one = |index: usize| -> Result<DonePsf, ProductError> {
        let start = std::time::Instant::now();
        let name = plan.psf_name(index);
        let built = plan.psf(index)?;
        let report = psf::report(name, built.as_ref(), p)?;
        on_built(&report, start.elapsed().as_secs_f64());
        let n = options
            .size_px
            .unwrap_or_else(|| renderer_side_px(built.as_ref(), p, max_stamp_px));
        let drawn = psf::draw_for_file(
            name,
            built.as_ref(),
            p,
            n,
            options.oversample,
            Some(report.clone()),
        );
        write_psf(&out.join(format!("{name}.fits")), &drawn)?;
        // Pictures: cores at p/8, wings at p/2.
        Ok(DonePsf {
            core: psf::image(built.as_ref(), 256, p, 8),
            wing: psf::image(built.as_ref(), 512, p, 2),
            report,
        })
    };
    let workers = options.workers.clamp(1, plan.n_psfs().max(1));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(workers)
        .build()
        .map_err(|e| ProductError::Threads {
            workers,
            message: e.to_string(),
        })?;
    // Collected in config order: the output does not depend on scheduling.
    let done: Vec<DonePsf> = pool.install(|| {
        (0..plan.n_psfs())
            .into_par_iter()
            .with_max_len(1)
            .map(one)
            .collect::<Result<_, _>>()
    })?;
    let reports: Vec<PsfReport> = done.iter().map(|d| d.report.clone()).collect();
    let json = serde_json::json!({
        "config": config_label,
        "pixel_scale_arcsec": p,
        "psfs": reports,
    });
    let text = serde_json::to_string_pretty(&json).expect("report serialises") + "\n";
    write_bytes_atomically(&out.join("psf_report.json"), text.as_bytes())?;
    let config = format!("{}\n", plan.config_json_as_given());
    write_bytes_atomically(&out.join("config.json"), config.as_bytes())?;
    let cores: Vec<&[f64]> = done.iter().map(|d| d.core.as_slice()).collect();
    let wings: Vec<&[f64]> = done.iter().map(|d| d.wing.as_slice()).collect();
    let picture = panel::psf_set(&cores, &wings, &plan.psf_names(), p);
    write_picture(&out.join("psf_cores.png"), &picture)?;
    Ok(reports)
}

/// Counts of a written catalogue.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CatalogCounts {
    /// Base fields written.
    pub fields: u32,
    /// Galaxies over all base fields (twins not counted).
    pub galaxies: usize,
    /// Stars over all base fields (twins not counted).
    pub stars: usize,
}

/// Writes the base fields of the plan without rendering, in `out`:
/// `config.json` (the resolved config, seed included), and per base field k
/// `field_kkk.{fits,csv,list}` (truth table, its CSV twin, SkyMaker list),
/// plus `field_kkk_rot.*` with `population.rotated_pairs`. The population
/// is checked ([`population::preflight`]) before the first file is written.
pub fn write_catalog(plan: &Plan, out: &Path) -> Result<CatalogCounts, ProductError> {
    let spec = plan.population();
    population::preflight(&spec).map_err(ProductError::Preflight)?;
    write_bytes_atomically(&out.join("config.json"), plan.config_json().as_bytes())?;
    let mut counts = CatalogCounts {
        fields: plan.n_fields(),
        galaxies: 0,
        stars: 0,
    };
    let t_types = population::t_types(&spec);
    for field in 0..plan.n_fields() {
        let rows = population::base_field(&spec, field)
            .map_err(|source| ProductError::Population { field, source })?;
        counts.stars += rows.iter().filter(|r| r.is_star()).count();
        counts.galaxies += rows.iter().filter(|r| !r.is_star()).count();
        write_field(plan, out, field, false, &rows, &t_types)?;
        if plan.rotated_pairs() {
            let twin = population::twin(&spec, &rows);
            write_field(plan, out, field, true, &twin, &t_types)?;
        }
    }
    Ok(counts)
}

fn write_field(
    plan: &Plan,
    out: &Path,
    field: u32,
    rotated: bool,
    rows: &[TruthRow],
    t_types: &[f64],
) -> Result<(), IoError> {
    let stem = format!("field_{field:03}{}", if rotated { "_rot" } else { "" });
    let im = plan.geometry();
    let keyword = |k: &str, v: f64, c: &str| (k.to_string(), v, c.to_string());
    let mut keywords = crate::io::truth_header::field_keywords(field, rotated);
    keywords.extend([
        keyword("PIXSCALE", im.pixel_scale_arcsec, "arcsec per pixel"),
        keyword("NAXIS1IM", f64::from(im.width_px), "image width"),
        keyword("NAXIS2IM", f64::from(im.height_px), "image height"),
    ]);
    truth::write_truth_fits(&out.join(format!("{stem}.fits")), rows, &keywords)?;
    truth::write_truth_csv(&out.join(format!("{stem}.csv")), rows)?;
    skymaker::write_list(&out.join(format!("{stem}.list")), rows, t_types)
}
