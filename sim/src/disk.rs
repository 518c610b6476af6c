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
//!   sampling and one oversampled;
//! * **small files**: sidecars, manifest, datasets, config, README (4 KiB
//!   per image, 64 KiB for the run).

use crate::memory::{MemoryEstimate, Part};
use crate::plan::Plan;

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
    8 + 4 * crate::truth::INT_COLUMNS.len() as u64 + 8 * crate::truth::FLOAT_COLUMNS.len() as u64
}

/// What `stepsim generate` writes for the whole run, by file kind.
pub fn generate_estimate(plan: &Plan) -> MemoryEstimate {
    let img = &plan.image();
    let out = &plan.output();
    let n = images_in_run(plan);
    let pixels = u64::from(img.width_px) * u64::from(img.height_px);
    let image = fits_file_bytes(pixels.saturating_mul(4));
    let objects = crate::memory::objects_per_field(plan);
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
                    crate::config::SampleFormat::Float32 => "float32",
                    crate::config::SampleFormat::Int32 => "int32",
                },
                match out.compression {
                    crate::config::Compression::Rice => " (Rice, counted uncompressed)",
                    crate::config::Compression::None => "",
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
        use crate::io::psf_fits::{DEFAULT_OVERSAMPLE, DEFAULT_SIZE_PX};
        let side = DEFAULT_SIZE_PX as u64;
        let fine = side * DEFAULT_OVERSAMPLE as u64;
        let one = fits_file_bytes(8 * side * side) + fits_file_bytes(8 * fine * fine);
        let k = plan.psfs().len() as u64;
        parts.push(Part {
            what: format!("{k} PSF file{}", if k == 1 { "" } else { "s" }),
            bytes: one.saturating_mul(k),
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
    crate::memory::human(estimate.total_bytes()),
    estimate.parts_text(),
    crate::memory::human(*present_bytes),
    crate::memory::human(*free_bytes)
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
        let e = generate_estimate(&p);
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
        let rows = crate::memory::objects_per_field(&p).ceil() as u64;
        assert_eq!(
            e.parts[1].bytes,
            1920 * fits_file_bytes(rows * truth_row_bytes())
        );
        // Truth, PSFs and small files are a minor share of it.
        let rest = e.total_bytes() - images;
        assert!(rest > 0 && rest < images / 4, "{rest}");
        // write_model doubles the images.
        let m = generate_estimate(&plan(&text, &["run.seed=1", "output.write_model=true"]));
        assert_eq!(m.total_bytes() - e.total_bytes(), images);
        // Rotated twins double the images.
        let r = plan(&text, &["run.seed=1", "population.rotated_pairs=true"]);
        assert_eq!(generate_estimate(&r).parts[0].bytes, 2 * images);
    }

    #[test]
    fn check_refuses_only_what_does_not_fit_after_what_is_present() {
        let p = plan("{}", &["run.seed=1"]);
        let e = generate_estimate(&p);
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
