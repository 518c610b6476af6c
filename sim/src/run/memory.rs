//! The memory a command will need, estimated from the plan before any work
//! starts, so that a run too big for the machine is refused with a sentence
//! (instead of an allocation failure that aborts it half-made).
//!
//! The estimate is an upper bound built from what the code holds at its
//! peak (docs/config.md, "Memory"):
//!
//! * **images in flight**: one per worker thread. An image's peak is the
//!   larger of (canvas with the split method's margin; the convolved model
//!   is written into the canvas's own buffer) and (model + noisy pixels +
//!   an integer or model copy), all f32, plus the thread's convolution
//!   scratch (one FFT tile) and one band of output blocks;
//! * **population**: the expected objects of a base field (configured
//!   densities × placement area) as truth rows, held as the base field, its
//!   rotated twin and one sheared copy per image in flight, plus a batch of
//!   stamps;
//! * **PSFs**: per PSF its image-level convolution kernel on one FFT tile,
//!   plus the transient grids of building an optical PSF;
//! * **program**: code, allocator and thread stacks.
//!
//! The margin is taken at its largest (half of `render.max_stamp_px`), as
//! it is for the optical PSFs; for narrow PSFs the estimate is high.
//! Measured against peak RSS in BENCHMARKS.md.

use crate::io::image_fits::{Compression, SampleFormat};
use crate::model::psf::PsfSpec;
use crate::model::render::Method;
use crate::run::plan::Plan;
use std::fmt;
use stepsim_contract::truth::TruthRow;

/// Code, allocator arenas and thread stacks (measured: 7 MiB for a run that
/// stops at once; 32 MiB leaves room for the workers).
pub const PROGRAM_BYTES: u64 = 32 << 20;

/// Transient memory of building and calibrating one optical PSF (its pupil
/// and FFT grids; measured peak 158 MiB for one 1024² image with the coma
/// PSF against 72 MiB for a Gaussian PSF of a 2048² image).
pub const OPTICAL_BUILD_BYTES: u64 = 128 << 20;

/// Bytes per sample of the fine grid on which a PSF is measured
/// ([`crate::model::psf::report`]: transfer, half-plane spectrum, inverse FFT and
/// image; measured 2.76 GiB peak, 44 B per sample, for its 8192² grid at
/// 0.05″ per pixel; rounded up).
pub const REPORT_BYTES_PER_SAMPLE: f64 = 48.0;

/// Side of the fine grid [`crate::model::psf::report`] uses at a pixel scale.
pub fn report_grid_side(pixel_scale_arcsec: f64) -> usize {
    let h = pixel_scale_arcsec / crate::model::psf::FINE_OVERSAMPLE as f64;
    let want = (26.0 / h).ceil();
    if want.is_finite() && want < (1u64 << 40) as f64 {
        (want as usize).next_power_of_two().max(256)
    } else {
        usize::MAX
    }
}

/// Bytes of measuring one PSF at a pixel scale.
pub fn report_bytes(pixel_scale_arcsec: f64) -> f64 {
    let n = report_grid_side(pixel_scale_arcsec) as f64;
    REPORT_BYTES_PER_SAMPLE * n * n
}

/// Stamps held while a batch is drawn and the previous one added (two
/// batches of 2048 objects at a typical 32² f32 stamp of the split method).
pub const STAMP_BYTES: u64 = 2 * 2048 * 32 * 32 * 4;

/// One part of an estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct Part {
    /// What it is, for humans ("2 images of 4096 × 4096 px in flight").
    pub what: String,
    /// Bytes.
    pub bytes: u64,
}

/// The memory a command needs, by part.
#[derive(Debug, Clone, PartialEq)]
pub struct MemoryEstimate {
    /// The parts; their sum is [`MemoryEstimate::total_bytes`].
    pub parts: Vec<Part>,
}

impl MemoryEstimate {
    /// Sum of the parts.
    pub fn total_bytes(&self) -> u64 {
        self.parts
            .iter()
            .fold(0u64, |a, p| a.saturating_add(p.bytes))
    }
}

impl MemoryEstimate {
    /// The parts as `what: size; ...`.
    pub fn parts_text(&self) -> String {
        self.parts
            .iter()
            .filter(|p| p.bytes > 0)
            .map(|p| format!("{}: {}", p.what, human(p.bytes)))
            .collect::<Vec<_>>()
            .join("; ")
    }
}

impl fmt::Display for MemoryEstimate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "about {} ({})",
            human(self.total_bytes()),
            self.parts_text()
        )
    }
}

/// Bytes as GiB or MiB with one decimal.
pub fn human(bytes: u64) -> String {
    let b = bytes as f64;
    if b >= (1u64 << 30) as f64 {
        format!("{:.1} GiB", b / (1u64 << 30) as f64)
    } else {
        format!("{:.1} MiB", b / (1u64 << 20) as f64)
    }
}

/// A run that does not fit.
#[derive(Debug, thiserror::Error)]
#[error(
    "{command} needs about {} of memory ({}), but only {} is available ({source_of_available}); {hint}",
    human(estimate.total_bytes()),
    estimate.parts_text(),
    human(*available_bytes)
)]
pub struct TooBig {
    /// The command (`generate`, `bench`, ...).
    pub command: String,
    /// The estimate.
    pub estimate: MemoryEstimate,
    /// What is available.
    pub available_bytes: u64,
    /// Where that number comes from.
    pub source_of_available: String,
    /// What to lower.
    pub hint: String,
}

/// Refuses `estimate` when it exceeds `available_bytes` (nothing is
/// refused when the available memory is unknown).
pub fn check(
    command: &str,
    estimate: MemoryEstimate,
    available: Option<(u64, String)>,
    hint: &str,
) -> Result<MemoryEstimate, TooBig> {
    match available {
        Some((bytes, source)) if estimate.total_bytes() > bytes => Err(TooBig {
            command: command.into(),
            estimate,
            available_bytes: bytes,
            source_of_available: source,
            hint: hint.into(),
        }),
        _ => Ok(estimate),
    }
}

/// What to lower when `generate` or `bench` does not fit.
pub const RUN_HINT: &str = "lower image.width_px and image.height_px, population.galaxies.mag_faint, population.stars.density_per_arcmin2, image.margin_arcsec or --threads";

fn f32_bytes(px: f64) -> f64 {
    4.0 * px
}

/// Margin (pixels) the split method's canvas can carry: at most half the
/// largest stamp (what the optical PSFs reach).
fn margin_px(plan: &Plan) -> f64 {
    match plan.accuracy().method {
        Method::Split => (plan.accuracy().max_stamp_px / 2).max(4) as f64,
        Method::Stamp => 0.0,
    }
}

/// Side of the convolution tile for a margin `m` and image side `side`
/// (as `render::split` chooses it, before rounding to an FFT size).
fn tile_px(m: f64, side: f64) -> f64 {
    (8.0 * m).max(256.0).min(side + 2.0 * m).max(2.0 * m + 64.0)
}

/// Peak bytes of one image of the plan in flight (one worker).
pub fn image_bytes(plan: &Plan) -> f64 {
    let (w, h) = (
        f64::from(plan.geometry().width_px),
        f64::from(plan.geometry().height_px),
    );
    let m = margin_px(plan);
    let px = w * h;
    let canvas = f32_bytes((w + 2.0 * m) * (h + 2.0 * m));
    let out = &plan.output();
    let copies =
        2.0 + f64::from(u8::from(
            out.format == SampleFormat::Int32 || out.compression == Compression::Rice,
        )) + f64::from(u8::from(out.write_model));
    // The convolution writes the model into the canvas's buffer
    // (`Convolver::apply`), so drawing holds the canvas alone; finishing
    // keeps that buffer (its capacity is the canvas's, at most 1.56 × px
    // with the largest margin), within the two image-sized copies counted.
    let drawing = canvas;
    let finishing = copies * f32_bytes(px);
    let scratch = if m > 0.0 {
        let n = tile_px(m, w.max(h));
        // Complex f32 half-plane tile, plus one band of output blocks.
        8.0 * n * (n / 2.0 + 1.0) + f32_bytes((n - 2.0 * m).max(1.0) * w)
    } else {
        0.0
    };
    drawing.max(finishing) + scratch
}

/// Expected objects (galaxies + stars) of one base field: the galaxies
/// drawn less those outside the magnitude range
/// ([`crate::model::population::kept_fraction`]), and the stars.
pub fn objects_per_field(plan: &Plan) -> f64 {
    let area = plan.placement_area().area_arcmin2;
    let galaxies = if plan.reads_skymaker_lists() {
        // A list's size is its own (read by the plan).
        0.0
    } else {
        crate::model::population::model(&plan.population()).density_per_arcmin2()
            * crate::model::population::kept_fraction(&plan.population())
    };
    (galaxies + plan.stars().density_per_arcmin2) * area
}

/// Bytes of the population: base field, twin, one sheared copy per image
/// in flight, and the stamps being drawn.
pub fn population_bytes(plan: &Plan, images_in_flight: usize) -> f64 {
    let row = std::mem::size_of::<TruthRow>() as f64;
    let copies = 1.0 + f64::from(u8::from(plan.rotated_pairs())) + images_in_flight as f64;
    objects_per_field(plan) * row * copies + STAMP_BYTES as f64
}

/// Bytes of the PSFs: each one's image-level kernel on one tile (split
/// method), plus the transient grids of building an optical PSF.
pub fn psf_bytes(plan: &Plan, psfs: &[usize]) -> f64 {
    let m = margin_px(plan);
    let side = f64::from(plan.geometry().width_px.max(plan.geometry().height_px));
    let kernel = if m > 0.0 {
        let n = tile_px(m, side);
        8.0 * n * (n / 2.0 + 1.0)
    } else {
        0.0
    };
    let optical = psfs
        .iter()
        .any(|&i| plan.psf_specs().get(i).is_some_and(PsfSpec::is_optical));
    // Building an optical PSF and measuring a PSF for its file are
    // transients, one at a time.
    let build = if optical {
        OPTICAL_BUILD_BYTES as f64
    } else {
        0.0
    };
    kernel * psfs.len() as f64 + build.max(report_bytes(plan.geometry().pixel_scale_arcsec))
}

fn to_bytes(x: f64) -> u64 {
    if x.is_finite() && x < u64::MAX as f64 {
        x.ceil() as u64
    } else {
        u64::MAX
    }
}

/// `stepsim generate` with `threads` workers: every PSF of the plan, one
/// image per worker in flight.
pub fn generate_estimate(plan: &Plan, threads: usize) -> MemoryEstimate {
    // Images are made field by field, at most one per worker.
    let per_field = plan.datasets().len() * (1 + usize::from(plan.rotated_pairs()));
    let t = threads.max(1).min(per_field.max(1));
    let all: Vec<usize> = (0..plan.n_psfs()).collect();
    run_estimate(plan, t, &all)
}

/// `stepsim bench` with `threads` workers: one PSF, one image (drawn with
/// every worker).
pub fn bench_estimate(plan: &Plan, psf: usize) -> MemoryEstimate {
    run_estimate(plan, 1, &[psf])
}

fn run_estimate(plan: &Plan, images: usize, psfs: &[usize]) -> MemoryEstimate {
    let img = &plan.geometry();
    MemoryEstimate {
        parts: vec![
            Part {
                what: format!(
                    "{images} image{} of {} × {} px in flight",
                    if images == 1 { "" } else { "s" },
                    img.width_px,
                    img.height_px
                ),
                bytes: to_bytes(images as f64 * image_bytes(plan)),
            },
            Part {
                what: format!(
                    "population ({:.0} objects per field)",
                    objects_per_field(plan)
                ),
                bytes: to_bytes(population_bytes(plan, images)),
            },
            Part {
                what: format!(
                    "{} PSF{}",
                    psfs.len(),
                    if psfs.len() == 1 { "" } else { "s" }
                ),
                bytes: to_bytes(psf_bytes(plan, psfs)),
            },
            Part {
                what: "program".into(),
                bytes: PROGRAM_BYTES,
            },
        ],
    }
}

/// `stepsim catalog`: one base field and its twin at a time.
pub fn catalog_estimate(plan: &Plan) -> MemoryEstimate {
    MemoryEstimate {
        parts: vec![
            Part {
                what: format!(
                    "population ({:.0} objects per field)",
                    objects_per_field(plan)
                ),
                // Rows, twin, and their CSV / list text (about 3 rows' worth).
                bytes: to_bytes(
                    objects_per_field(plan) * std::mem::size_of::<TruthRow>() as f64 * 4.0,
                ),
            },
            Part {
                what: "program".into(),
                bytes: PROGRAM_BYTES,
            },
        ],
    }
}

/// `stepsim psf` with `workers` PSFs built at a time, images of `size_px`²
/// at `oversample` samples per pixel: per worker, the build and the
/// oversampled image (f64) with its FFT grid (complex f64).
pub fn psf_estimate(
    plan: &Plan,
    size_px: usize,
    oversample: usize,
    workers: usize,
) -> MemoryEstimate {
    let fine = (size_px * oversample) as f64;
    let optical = plan.psf_specs().iter().any(PsfSpec::is_optical);
    let build = if optical {
        OPTICAL_BUILD_BYTES as f64
    } else {
        0.0
    };
    let per =
        fine * fine * (8.0 + 16.0) + build.max(report_bytes(plan.geometry().pixel_scale_arcsec));
    MemoryEstimate {
        parts: vec![
            Part {
                what: format!(
                    "{workers} PSF{} of {}² samples at a time",
                    if workers == 1 { "" } else { "s" },
                    size_px * oversample
                ),
                bytes: to_bytes(workers.max(1) as f64 * per),
            },
            Part {
                what: "program".into(),
                bytes: PROGRAM_BYTES,
            },
        ],
    }
}

/// Bytes per pixel of one image being measured by the KSB+ pipeline (the
/// image, its background-subtracted and smoothed copies, the segmentation
/// map and per-object work): measured 16 B/px per extra image in flight on
/// 1024² and 2048² images (BENCHMARKS.md), doubled for a bound.
pub const MEASURE_BYTES_PER_PX: f64 = 32.0;

/// `stepsim measure` on images of `width × height` px, `images` of them,
/// with `threads` workers (one image per worker in flight).
pub fn measure_estimate(width: u32, height: u32, images: usize, threads: usize) -> MemoryEstimate {
    let t = threads.max(1).min(images.max(1));
    let px = f64::from(width) * f64::from(height);
    MemoryEstimate {
        parts: vec![
            Part {
                what: format!(
                    "{t} image{} of {width} × {height} px in flight",
                    if t == 1 { "" } else { "s" }
                ),
                bytes: to_bytes(t as f64 * px * MEASURE_BYTES_PER_PX),
            },
            Part {
                what: "program".into(),
                bytes: PROGRAM_BYTES,
            },
        ],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn plan(overrides: &[&str]) -> Plan {
        Plan::from_json("{}", Path::new("t.json"), overrides).unwrap()
    }

    #[test]
    fn image_bytes_follow_the_documented_formula() {
        // 4096² with the default 512-px margin: drawing = canvas 5120² f32
        // (the model is written into it); finishing = 2 × 4096² f32 (float
        // output), the larger; the tile is min(8 m, 4096 + 2 m) = 4096 →
        // 4096 × 2049 complex f32, plus a band of (4096 − 1024) × 4096 f32.
        let p = plan(&[]);
        let want = 4.0 * 2.0 * 4096.0 * 4096.0 + 8.0 * 4096.0 * 2049.0 + 4.0 * 3072.0 * 4096.0;
        assert_eq!(image_bytes(&p), want);
        // int32 output adds one image-sized copy to the finishing step:
        // 3 × 4096² f32.
        let q = plan(&["output.format=\"int32\""]);
        let scratch = 8.0 * 4096.0 * 2049.0 + 4.0 * 3072.0 * 4096.0;
        assert_eq!(image_bytes(&q), 3.0 * 4.0 * 4096.0 * 4096.0 + scratch);
        // Without the split method: no canvas margin, no convolution.
        let s = plan(&["render.method=\"stamp\""]);
        assert_eq!(image_bytes(&s), 4.0 * 2.0 * 4096.0 * 4096.0);
    }

    #[test]
    fn estimates_grow_with_threads_and_refuse_what_cannot_fit() {
        let p = plan(&[
            "image.width_px=65536",
            "image.height_px=65536",
            "population.galaxies.mag_faint=19",
        ]);
        let one = generate_estimate(&p, 1).total_bytes();
        let two = generate_estimate(&p, 2).total_bytes();
        // One 65536² image needs more than 2 × 16 GiB (model and noisy
        // pixels, plus the convolution's scratch).
        assert!(one > 32 << 30, "{}", human(one));
        assert!(two > one + (32 << 30), "{} vs {}", human(two), human(one));
        let err = check(
            "generate",
            generate_estimate(&p, 2),
            Some((24 << 30, "MemAvailable in /proc/meminfo".into())),
            RUN_HINT,
        )
        .unwrap_err()
        .to_string();
        assert!(err.starts_with("generate needs about "), "{err}");
        assert!(
            err.contains("2 images of 65536 × 65536 px in flight"),
            "{err}"
        );
        assert!(
            err.contains("only 24.0 GiB is available (MemAvailable"),
            "{err}"
        );
        assert!(err.contains("image.width_px"), "{err}");
        // The STEP1 preset with 2 threads: about 1.1 GiB (measured peak of
        // 6 optical PSFs, 4096² images, 2 threads: 597 MiB).
        let step1 = generate_estimate(&plan(&[]), 2).total_bytes();
        assert!((597 << 20..2 << 30).contains(&step1), "{}", human(step1));
        assert!(check("generate", generate_estimate(&plan(&[]), 2), None, RUN_HINT).is_ok());
    }

    #[test]
    fn measure_estimate_counts_images_in_flight() {
        // 2 threads on 2048² images: 2 × 2048² × 32 B + the program.
        let e = measure_estimate(2048, 2048, 10, 2);
        assert_eq!(e.total_bytes(), 2 * 2048 * 2048 * 32 + PROGRAM_BYTES);
        // Never more images in flight than there are images.
        assert_eq!(
            measure_estimate(2048, 2048, 1, 8),
            measure_estimate(2048, 2048, 1, 1)
        );
    }

    #[test]
    fn population_counts_follow_densities_and_area() {
        let p = plan(&[
            "population.stars.density_per_arcmin2=100",
            "population.galaxies.mag_faint=17.0001",
        ]);
        let area = p.placement_area().area_arcmin2;
        let n = objects_per_field(&p);
        assert!(
            (n - 100.0 * area).abs() < 0.01 * n,
            "{n} vs {}",
            100.0 * area
        );
    }
}
