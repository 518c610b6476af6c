//! The space the whole run writes, estimated once its PSFs are solved (their
//! files' sides and the store's bytes) and checked before the first image
//! is written.

use super::{GenerateError, Options, Psfs};
use crate::run::memory::MemoryEstimate;
use crate::run::plan::Plan;
use std::path::{Path, PathBuf};
use stepsim_contract::run_dir::RunDir;

/// What the whole run writes ([`crate::run::disk::generate_estimate`] with
/// the solved PSFs), checked against `options.disk` when given.
pub(super) fn check_space(
    plan: &Plan,
    run: &RunDir,
    psfs: &Psfs,
    options: &Options,
    out: &Path,
) -> Result<MemoryEstimate, GenerateError> {
    let disk_estimate =
        crate::run::disk::generate_estimate(plan, Some(&solved_psfs(plan, run, psfs)));
    if let Some(d) = &options.disk {
        crate::run::disk::check(
            &out.display().to_string(),
            disk_estimate.clone(),
            d.present_bytes,
            d.free.clone(),
        )
        .map_err(Box::new)?;
    }
    Ok(disk_estimate)
}

/// What the solved PSFs write: the side of each one's file (those this
/// process built) and the bytes of the run's store files.
fn solved_psfs(plan: &Plan, run: &RunDir, psfs: &Psfs) -> crate::run::disk::SolvedPsfs {
    use crate::io::psf_store::{file_for, is_stored};
    let scale = plan.pixel_scale_arcsec();
    let max_stamp = plan.accuracy().max_stamp_px;
    let file_side_px = psfs
        .renderers
        .iter()
        .map(|(p, r)| {
            let side = crate::io::psf_fits::renderer_side_px(r.psf().as_ref(), scale, max_stamp);
            (*p, side)
        })
        .collect();
    let accuracy = crate::model::psf::PsfAccuracy::default();
    let files: std::collections::BTreeSet<PathBuf> = plan
        .psf_specs()
        .iter()
        .filter(|spec| is_stored(spec))
        .map(|spec| file_for(&run.private().psf_cache(), spec, &accuracy))
        .collect();
    let store_bytes = files
        .iter()
        .filter_map(|f| std::fs::metadata(f).ok())
        .map(|m| m.len())
        .sum();
    crate::run::disk::SolvedPsfs {
        file_side_px,
        store_bytes,
    }
}
