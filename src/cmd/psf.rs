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
use anyhow::Context;
use std::path::PathBuf;
use stepsim_sim::io::png::write_picture;
use stepsim_sim::io::psf_fits::{self, write_psf};
use stepsim_sim::psf::{self, panel};

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
    let p = plan.raw.image.pixel_scale_arcsec;
    let os = args.oversample as usize;
    let max_stamp_px = plan.raw.render.max_stamp_px as usize;
    // One PSF per work item, at most two at a time (each holds ~200 MB of
    // 2048² grids); results are gathered in config order, so the output does
    // not depend on scheduling.
    struct Done {
        report: psf::PsfReport,
        core: Vec<f64>,
        wing: Vec<f64>,
    }
    let psfs = &plan.raw.psfs;
    let next = std::sync::atomic::AtomicUsize::new(0);
    let workers = super::available_cores().min(2).min(psfs.len());
    // The file side is known per PSF once it is built; bound it from above.
    let n_max = args
        .size_px
        .map_or((max_stamp_px + 2).max(psf_fits::DEFAULT_SIZE_PX), |n| {
            n as usize
        });
    super::check_memory(
        "psf",
        stepsim_sim::memory::psf_estimate(&plan, n_max, os, workers),
        "lower --size-px or --oversample",
    )?;
    let one = |raw: &stepsim_sim::config::RawPsf| -> anyhow::Result<Done> {
        let start = std::time::Instant::now();
        let built = psf::build(raw, &plan.raw.telescope, p)?;
        let report = psf::report(&raw.name, built.as_ref(), p)?;
        eprintln!(
            "stepsim: psf {}: FWHM {:.4}″, |χ| {:.4} (χ1 {:+.4}, χ2 {:+.4}) [{:.1} s]",
            raw.name,
            report.fwhm_arcsec,
            report.chi_abs,
            report.chi1,
            report.chi2,
            start.elapsed().as_secs_f64()
        );
        let path = args.out.join(format!("{}.fits", raw.name));
        let n = args.size_px.map_or_else(
            || psf_fits::renderer_side_px(built.as_ref(), p, max_stamp_px),
            |n| n as usize,
        );
        write_psf(&path, &raw.name, built.as_ref(), p, n, os, Some(&report))?;
        // Pictures: cores at p/8, wings at p/2.
        Ok(Done {
            core: psf::image(built.as_ref(), 256, p, 8),
            wing: psf::image(built.as_ref(), 512, p, 2),
            report,
        })
    };
    let mut results: Vec<Option<anyhow::Result<Done>>> = (0..psfs.len()).map(|_| None).collect();
    std::thread::scope(|scope| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(|| {
                    let mut mine = Vec::new();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        if i >= psfs.len() {
                            return mine;
                        }
                        mine.push((i, one(&psfs[i])));
                    }
                })
            })
            .collect();
        for h in handles {
            for (i, r) in h.join().expect("psf worker panicked") {
                results[i] = Some(r);
            }
        }
    });
    let mut reports = Vec::new();
    let (mut cores, mut wings) = (Vec::new(), Vec::new());
    for r in results {
        let done = r.expect("every PSF was processed")?;
        reports.push(done.report);
        cores.push(done.core);
        wings.push(done.wing);
    }
    let json = serde_json::json!({
        "config": args.config.config.display().to_string(),
        "pixel_scale_arcsec": p,
        "psfs": reports,
    });
    let text = serde_json::to_string_pretty(&json)? + "\n";
    stepsim_sim::io::write_bytes_atomically(&args.out.join("psf_report.json"), text.as_bytes())?;
    // PSFs do not depend on the seed: a drawn one is not recorded.
    let config = format!("{}\n", super::as_given(&plan).to_json());
    stepsim_sim::io::write_bytes_atomically(&args.out.join("config.json"), config.as_bytes())?;
    let core_refs: Vec<&[f64]> = cores.iter().map(Vec::as_slice).collect();
    let wing_refs: Vec<&[f64]> = wings.iter().map(Vec::as_slice).collect();
    let half_core = (1.6 / (p / 8.0)).round() as usize;
    let half_wing = (15.0 / (p / 2.0)).round() as usize;
    let names: Vec<&str> = plan.raw.psfs.iter().map(|r| r.name.as_str()).collect();
    let top = panel::row(
        &core_refs,
        &names,
        256,
        half_core,
        2,
        panel::Stretch::Linear,
        &[0.03, 0.25, 0.9],
    );
    let zoom = (top.width / (core_refs.len() * 2 * half_wing.min(256))).max(1);
    let bottom = panel::row(
        &wing_refs,
        &names,
        512,
        half_wing,
        zoom,
        panel::Stretch::Log { floor: 1e-6 },
        &[3e-5, 3e-4, 3e-3, 0.03, 0.25],
    );
    let middle = panel::difference_row(&core_refs, &names, core_refs[0], 256, half_core, 2, 0.05);
    let w = top.width;
    let pic = panel::stack(&[
        panel::caption(
            w,
            30,
            "cores ±1.6″, linear; contours at 3 %, 25 %, 90 % of the peak",
        ),
        top,
        panel::caption(
            w,
            30,
            &format!(
                "core minus {}'s, both at unit peak: red brighter, blue fainter (±5 %)",
                names[0]
            ),
        ),
        middle,
        panel::caption(
            w,
            30,
            "wings ±15″, log stretch to 1e-6; contours at 3e-5 … 0.25 of the peak",
        ),
        bottom,
    ]);
    let png = args.out.join("psf_cores.png");
    write_picture(&png, &pic).with_context(|| "writing the PSF panel")?;
    eprintln!(
        "stepsim: wrote {} PSFs, psf_report.json and psf_cores.png to {}",
        reports.len(),
        args.out.display()
    );
    Ok(())
}
