//! The files every shard writes identically: `datasets.json`, the blinding
//! key, the participants' README and the PSF files; and the public
//! instrument facts of the manifest.

use super::{GenerateError, Job, Options, participants_readme};
use crate::model::render::Renderer;
use crate::run::blind::BlindingKey;
use crate::run::plan::Plan;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use stepsim_contract::io::{IoError, write_bytes_atomically};
use stepsim_contract::run_dir::RunDir;
use stepsim_contract::run_layout::{
    DATASETS_FORMAT, DatasetEntry, DatasetImage, Datasets, InstrumentFacts,
};

/// The files every shard writes identically: datasets, blinding key,
/// participants' README, and the PSFs this process built (the resolved config
/// was written first, by [`claim::claim`]).
pub(super) fn write_shared(
    plan: &Plan,
    run: &RunDir,
    key: &BlindingKey,
    all: &[Job],
    options: &Options,
    renderers: &BTreeMap<usize, Renderer>,
) -> Result<(), GenerateError> {
    for (path, bytes) in private_shared(plan, run, key, all) {
        write_bytes_atomically(&path, bytes.as_bytes())?;
    }
    let para = options
        .submission_format
        .as_deref()
        .unwrap_or(stepsim_contract::SUBMISSION_FORMAT_MD);
    write_bytes_atomically(
        &run.public().readme(),
        participants_readme(plan, para).as_bytes(),
    )?;
    if plan.output().write_psf {
        let user = crate::io::psf_store::user_store_dir();
        for (p, renderer) in renderers {
            let name = plan.psf_name(*p);
            let spec = plan.psf_spec(*p);
            write_psf_file(
                &run.private().psf(name),
                renderer.psf(),
                name,
                plan.pixel_scale_arcsec(),
                plan.accuracy().max_stamp_px,
                // Only the stored (optical) PSFs: the others draw in
                // milliseconds.
                user.as_deref()
                    .filter(|_| crate::io::psf_store::is_stored(&spec))
                    .map(|u| {
                        let accuracy = crate::model::psf::PsfAccuracy::default();
                        (u, crate::io::psf_store::spec_digest(&spec, &accuracy))
                    }),
            )?;
        }
    }
    Ok(())
}

/// Writes `private/psf/<name>.fits`: the pixel-scale image and the
/// oversampled one, with the measured report in the header (the same file
/// `stepsim psf` writes, at its default sizes: the extent the renderer
/// gives the PSF).
///
/// With `user` (the user's PSF store and the PSF's spec digest) the file is
/// copied from the store when it holds it, and kept there when drawn
/// ([`crate::io::psf_store::write_drawn_file`]).
fn write_psf_file(
    path: &Path,
    psf: &Arc<dyn crate::model::psf::Psf>,
    name: &str,
    pixel_scale_arcsec: f64,
    max_stamp_px: usize,
    user: Option<(&Path, String)>,
) -> Result<(), IoError> {
    use crate::io::psf_fits::{DEFAULT_OVERSAMPLE, draw_and_write, renderer_side_px};
    use crate::io::psf_store::{file_digest, write_drawn_file};
    let side = renderer_side_px(psf.as_ref(), pixel_scale_arcsec, max_stamp_px);
    let draw = |path: &Path| draw_and_write(path, psf.as_ref(), name, pixel_scale_arcsec, side);
    match user {
        Some((dir, spec)) => {
            let digest = file_digest(&spec, side, DEFAULT_OVERSAMPLE);
            write_drawn_file(path, &digest, Some(dir), draw).map(|_| ())
        }
        None => draw(path),
    }
}

/// The private files every process of a run writes identically:
/// `blinding.key` and `datasets.json` (path, content).
pub(super) fn private_shared(
    plan: &Plan,
    run: &RunDir,
    key: &BlindingKey,
    all: &[Job],
) -> [(PathBuf, String); 2] {
    let datasets = datasets_json(plan, all);
    [
        (run.private().blinding_key(), format!("{}\n", key.to_hex())),
        (
            run.private().datasets(),
            serde_json::to_string_pretty(&datasets).expect("datasets serialise") + "\n",
        ),
    ]
}

/// `private/datasets.json` of a run.
pub fn datasets_json(plan: &Plan, all: &[Job]) -> Datasets {
    let img = &plan.geometry();
    Datasets {
        format: DATASETS_FORMAT.into(),
        width_px: img.width_px,
        height_px: img.height_px,
        pixel_scale_arcsec: img.pixel_scale_arcsec,
        datasets: plan
            .datasets()
            .iter()
            .map(|d| {
                let images: Vec<&Job> = all.iter().filter(|j| j.dataset == d.index).collect();
                DatasetEntry {
                    dataset: images
                        .first()
                        .map(|j| j.dataset_id.clone())
                        .unwrap_or_default(),
                    psf_id: d.psf as u32,
                    psf: plan.psf_name(d.psf).to_string(),
                    g1: d.g1,
                    g2: d.g2,
                    images: images
                        .iter()
                        .map(|j| DatasetImage {
                            image: j.image_id.clone(),
                            field: j.field,
                            rotated: j.rotated,
                        })
                        .collect(),
                    part: d.part,
                }
            })
            .collect(),
    }
}

/// The public instrument facts of a plan.
pub fn instrument_facts(plan: &Plan) -> InstrumentFacts {
    let (img, ins) = (&plan.geometry(), &plan.instrument());
    InstrumentFacts {
        width_px: img.width_px,
        height_px: img.height_px,
        pixel_scale_arcsec: img.pixel_scale_arcsec,
        gain_e_per_adu: ins.gain_e_per_adu,
        read_noise_e: ins.read_noise_e,
        saturation_adu: ins.saturation_adu,
        exposure_s: ins.exposure_s,
        zeropoint_mag: ins.zeropoint_mag,
    }
}
