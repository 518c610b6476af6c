//! The PSFs a process needs, each built once (or reused from the run's
//! store), with their renderers.

use super::prepare::Work;
use super::{Event, GenerateError};
use crate::model::noise::Detector;
use crate::model::render::Renderer;
use crate::run::plan::Plan;
use std::collections::BTreeMap;
use stepsim_contract::run_dir::RunDir;

/// The PSFs of a process, each built once, and their renderers.
pub(super) struct Psfs {
    /// Renderer (and so PSF) of each PSF index built.
    pub(super) renderers: BTreeMap<usize, Renderer>,
    /// The detector of every image.
    pub(super) det: Detector,
    /// How many were loaded from the run's store.
    pub(super) reused: usize,
}

/// Builds the PSFs this process needs: those of its pending images, and
/// those whose `private/psf/` file is missing (`output.write_psf`).
pub(super) fn build_psfs(
    plan: &Plan,
    run: &RunDir,
    work: &Work,
    progress: &(dyn Fn(Event) + Sync),
) -> Result<Psfs, GenerateError> {
    let ds = plan.datasets();
    let mut needed: Vec<usize> = work
        .pending
        .iter()
        .map(|j| ds[j.dataset as usize].psf)
        .collect();
    if plan.output().write_psf {
        for j in &work.mine {
            let p = ds[j.dataset as usize].psf;
            if !run.private().psf(plan.psf_name(p)).exists() {
                needed.push(p);
            }
        }
    }
    needed.sort_unstable();
    needed.dedup();
    let det = plan.detector();
    let mut out = Psfs {
        renderers: BTreeMap::new(),
        det,
        reused: 0,
    };
    progress(Event::PsfsStart {
        total: needed.len(),
    });
    for &p in &needed {
        let psf_err = |source| GenerateError::Psf {
            index: p,
            name: plan.psf_name(p).to_string(),
            source,
        };
        let (_, origin) =
            plan.psf_in_store(p, &run.private().psf_cache())
                .map_err(|e| match e {
                    crate::io::psf_store::StoreError::Psf(source) => psf_err(source),
                    crate::io::psf_store::StoreError::Io(e) => GenerateError::Io(e),
                })?;
        let origin = origin.unwrap_or(crate::io::psf_store::Origin::Built);
        out.reused += usize::from(matches!(
            origin,
            crate::io::psf_store::Origin::Reused { .. }
                | crate::io::psf_store::Origin::Copied { .. }
        ));
        let renderer = plan.renderer(p).map_err(psf_err)?;
        out.renderers.insert(p, renderer);
        progress(Event::PsfBuilt {
            name: plan.psf_name(p).to_string(),
            done: out.renderers.len(),
            total: needed.len(),
            origin,
        });
    }
    Ok(out)
}
