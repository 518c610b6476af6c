//! `stepsim psf`: build every PSF of a config, write its images, a JSON
//! report and pictures of the cores and wings (like paper Fig. 1).
//!
//! Writes, in `--out DIR`:
//! * `<name>.fits`: the pixel-convolved PSF at the image pixel scale
//!   (primary HDU) and `--oversample` times finer (extension `OVERSAMPLED`);
//! * `config.json`: the resolved config the PSFs were built from (without a
//!   seed when the config gives none: PSFs do not depend on it);
//! * `psf_report.json`: `{"pixel_scale_arcsec": p, "psfs": [report, ...]}`
//!   with each PSF's FWHM, χ1, χ2, centroid, seeing and amplitude;
//! * `psf_cores.png`: the cores (±1.6″, linear, contours at 3 %, 25 %, 90 %
//!   of the peak), each core minus the first PSF's (both at unit peak;
//!   red brighter, blue fainter, full colour at ±5 % of the peak), and the
//!   wings (±15″, log stretch down to 1e-6,
//!   contours at 0.003 %, 0.03 %, 0.3 %, 3 %, 25 %), one column per PSF in
//!   config order.

use super::ConfigArgs;
use std::path::PathBuf;
use stepsim_sim::io::psf_fits;
use stepsim_sim::run::products::{self, PsfSetOptions};

/// Arguments of `stepsim psf`.
#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    config: ConfigArgs,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Side of the PSF image at the pixel scale, in pixels (even, 16 to 4096;
    /// default: the extent the renderer gives each PSF, at least 128).
    #[arg(long, value_name = "PX", value_parser = even_size)]
    size_px: Option<u32>,
    /// Samples per pixel of the oversampled image (1 to 16).
    #[arg(long, default_value_t = psf_fits::DEFAULT_OVERSAMPLE as u32, value_name = "N",
          value_parser = clap::value_parser!(u32).range(1..=16))]
    oversample: u32,
}

/// Parses `--size-px`: an even number in [16, 4096].
fn even_size(s: &str) -> Result<u32, String> {
    let n: u32 = s.parse().map_err(|e| format!("{e}"))?;
    if (16..=4096).contains(&n) && n % 2 == 0 {
        Ok(n)
    } else {
        Err(format!("must be even and in [16, 4096], got {n}"))
    }
}

/// Builds, measures and writes every PSF of the config.
pub fn run(args: &Args) -> anyhow::Result<()> {
    let plan = args.config.plan()?;
    super::fits_path("--out", &args.out)?;
    let size_px = args.size_px.map(|n| n as usize);
    let options = PsfSetOptions {
        size_px,
        oversample: args.oversample as usize,
        // At most two at a time: each optical PSF holds ~200 MB of grids.
        workers: super::available_cores().min(2),
    };
    super::check_memory(
        "psf",
        stepsim_sim::run::memory::psf_estimate(
            &plan,
            products::largest_psf_side_px(&plan, size_px),
            options.oversample,
            options.workers.min(plan.n_psfs()),
        ),
        "lower --size-px or --oversample",
    )?;
    let reports = products::write_psf_set(
        &plan,
        &args.out,
        &args.config.config.display().to_string(),
        options,
        &|r, seconds| {
            eprintln!(
                "stepsim: psf {}: FWHM {:.4}″, |χ| {:.4} (χ1 {:+.4}, χ2 {:+.4}) [{seconds:.1} s]",
                r.name, r.fwhm_arcsec, r.chi_abs, r.chi1, r.chi2,
            )
        },
    )?;
    eprintln!(
        "stepsim: wrote {} PSFs, psf_report.json and psf_cores.png to {}",
        reports.len(),
        args.out.display()
    );
    Ok(())
}
