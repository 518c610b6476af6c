//! The disk space `stepsim generate` will write, estimated from the plan
//! before any work starts, so that a run too big for its file system is
//! refused with the figures instead of failing half-made (docs/config.md,
//! "Disk").
//!
//! The estimate is the whole run (every shard writes into one directory),
//! by file kind, each rounded up to FITS's 2880-byte blocks:
//!
//! * **images**: width × height × 4 bytes (float32 or int32) per image.
//!   Rice-compressed int32 images are counted uncompressed: the ratio
//!   depends on the noise (measured 0.29 for the mini preset, README), and
//!   the check must not pass a run that then fills the disk;
//! * **truth**: the expected objects of a base field, one table row each
//!   (`id` 8 bytes, the other integer columns 4, the float columns 8);
//! * **model** (`output.write_model`): one float32 image per image;
//! * **PSFs** (`output.write_psf`): per PSF a float64 image at pixel
//!   sampling and one oversampled, in one file. Their side is the extent
//!   the renderer gives the PSF ([`renderer_side_px`]), known only once the
//!   PSF is solved: before that it is counted at its least,
//!   [`DEFAULT_SIZE_PX`] (0.14 of the STEP1 PSFs' 328 px files), and
//!   `generate` checks the space again with the solved sides before it
//!   writes the first image;
//! * **PSF store** (`private/psf/cache/`): the solved PSFs, counted from
//!   their files once solved (nothing before: their size, like the files',
//!   follows from the solution);
//! * **small files**: sidecars, manifest, datasets, config, README (4 KiB
//!   per image, 64 KiB for the run).

use crate::io::psf_fits::{DEFAULT_OVERSAMPLE, DEFAULT_SIZE_PX};
use crate::run::memory::{MemoryEstimate, Part};
use crate::run::plan::Plan;
use std::collections::BTreeMap;

#[cfg(doc)]
use crate::io::psf_fits::renderer_side_px;

/// FITS files grow in blocks of this many bytes.
pub const FITS_BLOCK_BYTES: u64 = 2880;

/// Header blocks counted per FITS file (primary header, extension header).
pub const FITS_HEADER_BLOCKS: u64 = 3;

/// Small files per image (sidecar, directory entries).
pub const SMALL_BYTES_PER_IMAGE: u64 = 4096;

/// Small files of the run (manifest, datasets, config, README, key).
pub const SMALL_BYTES_PER_RUN: u64 = 64 << 10;

/// Bytes of one FITS file holding `data_bytes` of data.
pub fn fits_file_bytes(data_bytes: u64) -> u64 {
    let blocks = data_bytes.div_ceil(FITS_BLOCK_BYTES);
    (blocks.saturating_add(FITS_HEADER_BLOCKS)).saturating_mul(FITS_BLOCK_BYTES)
}

/// Images the run makes (every field, its rotated twin if any, every
/// dataset).
pub fn images_in_run(plan: &Plan) -> u64 {
    plan.n_images_in_run()
}

/// Bytes of one truth table row.
pub fn truth_row_bytes() -> u64 {
    8 + 4 * stepsim_contract::truth::INT_COLUMNS.len() as u64
        + 8 * stepsim_contract::truth::FLOAT_COLUMNS.len() as u64
}

/// What the solved PSFs of a run write, measured once they are solved.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SolvedPsfs {
    /// Side (pixels) of the pixel-scale image of each PSF file, by PSF
    /// index ([`renderer_side_px`]); a PSF not listed is counted at
    /// [`DEFAULT_SIZE_PX`].
    pub file_side_px: BTreeMap<usize, usize>,
    /// Bytes of the run's PSF store files.
    pub store_bytes: u64,
}

/// Bytes of one PSF file: the float64 image of `side` px and the one
/// oversampled [`DEFAULT_OVERSAMPLE`] times, in two HDUs.
pub fn psf_file_bytes(side: usize) -> u64 {
    let side = side as u64;
    let fine = side.saturating_mul(DEFAULT_OVERSAMPLE as u64);
    let blocks = |n: u64| {
        n.saturating_mul(n)
            .saturating_mul(8)
            .div_ceil(FITS_BLOCK_BYTES)
    };
    (blocks(side) + blocks(fine) + FITS_HEADER_BLOCKS).saturating_mul(FITS_BLOCK_BYTES)
}

/// What `stepsim generate` writes for the whole run, by file kind: before
/// the PSFs are solved (`solved` `None`, PSF files counted at their least,
/// the store not at all) or after.
pub fn generate_estimate(plan: &Plan, solved: Option<&SolvedPsfs>) -> MemoryEstimate {
    let img = &plan.geometry();
    let out = &plan.output();
    let n = images_in_run(plan);
    let pixels = u64::from(img.width_px) * u64::from(img.height_px);
    let image = fits_file_bytes(pixels.saturating_mul(4));
    let objects = crate::run::memory::objects_per_field(plan);
    let rows = if objects.is_finite() && objects >= 0.0 {
        objects.ceil() as u64
    } else {
        u64::MAX
    };
    let truth = fits_file_bytes(rows.saturating_mul(truth_row_bytes()));
    let mut parts = vec![
        Part {
            what: format!(
                "{n} image{} of {} × {} px, {}{}",
                if n == 1 { "" } else { "s" },
                img.width_px,
                img.height_px,
                match out.format {
                    crate::io::image_fits::SampleFormat::Float32 => "float32",
                    crate::io::image_fits::SampleFormat::Int32 => "int32",
                },
                match out.compression {
                    crate::io::image_fits::Compression::Rice => " (Rice, counted uncompressed)",
                    crate::io::image_fits::Compression::None => "",
                }
            ),
            bytes: image.saturating_mul(n),
        },
        Part {
            what: format!("{n} truth tables (about {rows} rows each)"),
            bytes: truth.saturating_mul(n),
        },
    ];
    if out.write_model {
        parts.push(Part {
            what: format!("{n} model images"),
            bytes: image.saturating_mul(n),
        });
    }
    if out.write_psf {
        let k = plan.n_psfs();
        let known = BTreeMap::new();
        let sides = solved.map_or(&known, |s| &s.file_side_px);
        let side = |p: usize| sides.get(&p).copied().unwrap_or(DEFAULT_SIZE_PX);
        let bytes = (0..k).map(|p| psf_file_bytes(side(p))).sum::<u64>();
        let (lo, hi) = (0..k)
            .map(side)
            .fold((usize::MAX, 0), |(lo, hi), s| (lo.min(s), hi.max(s)));
        let span = if lo == hi {
            format!("{lo}")
        } else {
            format!("{lo}–{hi}")
        };
        let plural = if k == 1 { "" } else { "s" };
        parts.push(Part {
            what: if solved.is_some() {
                format!("{k} PSF file{plural} ({span} px, and {DEFAULT_OVERSAMPLE}× finer)")
            } else {
                format!("{k} PSF file{plural} (at least {span} px each until solved)")
            },
            bytes,
        });
    }
    if let Some(s) = solved.filter(|s| s.store_bytes > 0) {
        parts.push(Part {
            what: "the solved PSFs (private/psf/cache/)".into(),
            bytes: s.store_bytes,
        });
    }
    parts.push(Part {
        what: "sidecars, manifest and other small files".into(),
        bytes: SMALL_BYTES_PER_IMAGE
            .saturating_mul(n)
            .saturating_add(SMALL_BYTES_PER_RUN),
    });
    MemoryEstimate { parts }
}

/// A run that does not fit on its file system.
#[derive(Debug, thiserror::Error)]
#[error(
    "generate would write about {} ({}) to {place}, of which {} is already there, but only {} is free ({source_of_free}); lower image.n_images, image.width_px and image.height_px, use output.format \"int32\" with output.compression \"rice\", or free some space",
    crate::run::memory::human(estimate.total_bytes()),
    estimate.parts_text(),
    crate::run::memory::human(*present_bytes),
    crate::run::memory::human(*free_bytes)
)]
pub struct NoSpace {
    /// The run directory.
    pub place: String,
    /// What the whole run writes.
    pub estimate: MemoryEstimate,
    /// Bytes of files already under the run directory (a resumed run).
    pub present_bytes: u64,
    /// Free bytes on its file system.
    pub free_bytes: u64,
    /// Where that number comes from.
    pub source_of_free: String,
}

/// The space of a run's file system when `generate` starts, against which
/// the whole run is checked before any work and again once its PSFs are
/// solved.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DiskSpace {
    /// Bytes of files already under the run directory (a resumed run).
    pub present_bytes: u64,
    /// Free bytes and where that number comes from (`None`: unknown, and
    /// nothing is refused).
    pub free: Option<(u64, String)>,
}

/// Refuses `estimate` when what is still to write (the estimate less the
/// bytes already present) exceeds `free` (nothing is refused when the free
/// space is unknown).
pub fn check(
    place: &str,
    estimate: MemoryEstimate,
    present_bytes: u64,
    free: Option<(u64, String)>,
) -> Result<MemoryEstimate, NoSpace> {
    match free {
        Some((free_bytes, source))
            if estimate.total_bytes().saturating_sub(present_bytes) > free_bytes =>
        {
            Err(NoSpace {
                place: place.into(),
                estimate,
                present_bytes,
                free_bytes,
                source_of_free: source,
            })
        }
        _ => Ok(estimate),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn plan(json: &str, overrides: &[&str]) -> Plan {
        Plan::from_json(json, Path::new("t.json"), overrides).unwrap()
    }

    #[test]
    fn fits_files_round_up_to_blocks_with_headers() {
        assert_eq!(fits_file_bytes(0), 3 * 2880);
        assert_eq!(fits_file_bytes(1), 4 * 2880);
        assert_eq!(fits_file_bytes(2880), 4 * 2880);
        assert_eq!(fits_file_bytes(2881), 5 * 2880);
    }

    #[test]
    fn the_step1_preset_needs_about_129_gb_of_float32_images() {
        let text = std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/step1.json"),
        )
        .unwrap();
        let p = plan(&text, &["run.seed=1"]);
        // 6 PSFs × 5 shears × 64 base fields (no rotated twins).
        assert_eq!(images_in_run(&p), 6 * 5 * 64);
        let e = generate_estimate(&p, None);
        let images = e.parts[0].bytes;
        // 4096² float32 = 64 MiB of data + 3 header blocks, rounded to 2880.
        let one = (4096u64 * 4096 * 4).div_ceil(2880) * 2880 + 3 * 2880;
        assert_eq!(images, one * 1920);
        assert!((128.0e9..130.0e9).contains(&(images as f64)), "{images}");
        assert!(
            e.parts[0]
                .what
                .starts_with("1920 images of 4096 × 4096 px, float32")
        );
        // Truth tables: one row per expected object of a base field.
        let rows = crate::run::memory::objects_per_field(&p).ceil() as u64;
        assert_eq!(
            e.parts[1].bytes,
            1920 * fits_file_bytes(rows * truth_row_bytes())
        );
        // Truth, PSFs and small files are a minor share of it.
        let rest = e.total_bytes() - images;
        assert!(rest > 0 && rest < images / 4, "{rest}");
        // write_model doubles the images.
        let m = generate_estimate(
            &plan(&text, &["run.seed=1", "output.write_model=true"]),
            None,
        );
        assert_eq!(m.total_bytes() - e.total_bytes(), images);
        // Rotated twins double the images.
        let r = plan(&text, &["run.seed=1", "population.rotated_pairs=true"]);
        assert_eq!(generate_estimate(&r, None).parts[0].bytes, 2 * images);
    }

    #[test]
    fn check_refuses_only_what_does_not_fit_after_what_is_present() {
        let p = plan("{}", &["run.seed=1"]);
        let e = generate_estimate(&p, None);
        let t = e.total_bytes();
        assert!(check("r", e.clone(), 0, Some((t, "x".into()))).is_ok());
        assert!(check("r", e.clone(), 0, None).is_ok());
        assert!(check("r", e.clone(), 10, Some((t - 10, "x".into()))).is_ok());
        let err = check("runs/r", e, 0, Some((t - 1, "F=1".into()))).unwrap_err();
        let msg = err.to_string();
        assert!(msg.starts_with("generate would write about "), "{msg}");
        assert!(
            msg.contains("to runs/r, of which 0.0 MiB is already there"),
            "{msg}"
        );
        assert!(msg.contains("is free (F=1)"), "{msg}");
        assert!(msg.contains("truth tables"), "{msg}");
    }
}
