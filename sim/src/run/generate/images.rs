//! The pending images made field by field, in lanes of the rayon pool,
//! each base field drawn once and shared by its images ([`pipeline`] makes
//! one image).

use super::{Event, GenerateError, Job, Made, Psfs, pipeline};
use crate::run::plan::Plan;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use stepsim_contract::io::IoError;
use stepsim_contract::run_dir::RunDir;
use stepsim_contract::truth::TruthRow;

/// Makes the pending images field by field: each base field (and its
/// rotated twin) is drawn once for all the datasets' images of the field.
/// Within a field, images are written in the order of their opaque ids
/// (keyed by the blinding secret), so that no write order follows the
/// datasets. `write_shared` runs once, after the first base field is drawn
/// (or at the end when nothing is pending).
pub(super) fn make_images(
    plan: &Plan,
    run: &RunDir,
    pending: &[&Job],
    psfs: &Psfs,
    config_sha256: &str,
    write_shared: impl Fn() -> Result<(), GenerateError>,
    progress: &(dyn Fn(Event) + Sync),
) -> Result<(), GenerateError> {
    let mut jobs: Vec<&Job> = pending.to_vec();
    jobs.sort_by(|a, b| (a.field, &a.image_id).cmp(&(b.field, &b.image_id)));
    let fields = FieldPopulations::new(plan, &jobs);
    // The first field is drawn before anything is written, so that a
    // population error leaves the run as it was.
    if let Some(first) = jobs.first() {
        fields.get(first.field).map_err(|e| {
            e.unwrap_or_else(|| {
                IoError::format(
                    run.private().path(),
                    "the population of the first field could not be drawn",
                )
                .into()
            })
        })?;
    }
    write_shared()?;
    let made = Made { config_sha256 };
    let cx = pipeline::Context {
        plan,
        run,
        det: &psfs.det,
        made: &made,
    };
    // One lane per thread; each lane takes the next image until none is
    // left and runs its images one after another, so at most `lanes` images
    // are in flight. (A thread waiting inside an image's parallel loop may
    // steal a lane that has not started yet, and run it to the end with the
    // waiting image kept; the count in flight stays at most `lanes`.) Unlike
    // fixed batches, a lane does not wait for the others: the serial parts
    // of an image (its files) overlap with the other lanes' parallel stages.
    let lanes = rayon::current_num_threads().clamp(1, jobs.len().max(1));
    let next = AtomicUsize::new(0);
    let made = AtomicUsize::new(0);
    let failed = Mutex::new(None::<GenerateError>);
    (0..lanes).into_par_iter().for_each(|_| {
        while failed.lock().is_ok_and(|f| f.is_none()) {
            let i = next.fetch_add(1, Ordering::Relaxed);
            let Some(job) = jobs.get(i) else { return };
            let done = (|| {
                // Draw the field `lanes` images ahead now if no lane has yet
                // (this lane stays busy; the others need not wait for it).
                if let Some(ahead) = jobs.get(i + lanes) {
                    fields.draw_ahead(ahead.field)?;
                }
                let population = fields.get(job.field)?;
                let rows = match (&population.twin, job.rotated) {
                    (Some(twin), true) => twin,
                    _ => &population.base,
                };
                let renderer = &psfs.renderers[&plan.datasets()[job.dataset as usize].psf];
                let mut lap = pipeline::Lap::start(false);
                let mut times = pipeline::StageTimes::default();
                pipeline::make_image(&cx, job, rows, renderer, &mut lap, &mut times)
                    .map_err(Some)?;
                fields.finished(job.field);
                made.fetch_add(1, Ordering::Relaxed);
                progress(Event::ImageWritten);
                Ok::<(), Option<GenerateError>>(())
            })();
            if let Err(e) = done {
                // `None`: a population another lane failed to draw; that
                // lane (or the first to see it) reports the error.
                if let (Some(e), Ok(mut f)) = (e, failed.lock()) {
                    f.get_or_insert(e);
                }
                return;
            }
        }
    });
    match failed.into_inner().unwrap_or_else(|p| p.into_inner()) {
        Some(e) => Err(e),
        // Every lane stopped without an error: every image must be made.
        None if made.into_inner() == jobs.len() => Ok(()),
        None => Err(IoError::format(
            run.public().path(),
            "an image worker stopped before its images were written; run generate again to finish them",
        )
        .into()),
    }
}

/// The base field (and its 90°-rotated twin when a pending image needs it)
/// of every field with pending images, shared by all of that field's images
/// and dropped after the last. Nothing here blocks a pool thread (which
/// could deadlock if drawing ever used the pool itself): a lane that needs a
/// population nobody has finished draws it (the draw is deterministic, so a
/// second copy is the same rows) and the first copy stored wins; a lane
/// drawing ahead skips a field another lane is already drawing.
struct FieldPopulations<'a> {
    plan: &'a Plan,
    fields: Mutex<BTreeMap<u32, FieldEntry>>,
}

struct FieldEntry {
    /// Images of the field still to make.
    remaining: usize,
    /// Whether one of them is a rotated twin.
    twin: bool,
    /// Whether a lane has started drawing the population.
    claimed: Arc<AtomicBool>,
    /// The population once drawn (`None`: drawing it failed).
    population: Arc<PopulationCell>,
}

/// A field's population once drawn (`None` inside: drawing it failed).
type PopulationCell = OnceLock<Option<Arc<Population>>>;

struct Population {
    base: Vec<TruthRow>,
    twin: Option<Vec<TruthRow>>,
}

impl<'a> FieldPopulations<'a> {
    fn new(plan: &'a Plan, jobs: &[&Job]) -> Self {
        let mut fields: BTreeMap<u32, FieldEntry> = BTreeMap::new();
        for j in jobs {
            let e = fields.entry(j.field).or_insert_with(|| FieldEntry {
                remaining: 0,
                twin: false,
                claimed: Arc::default(),
                population: Arc::default(),
            });
            e.remaining += 1;
            e.twin |= j.rotated;
        }
        Self {
            plan,
            fields: Mutex::new(fields),
        }
    }

    /// The entry of `field` (`None`: no image of it is pending).
    fn entry(&self, field: u32) -> Option<(Arc<AtomicBool>, Arc<PopulationCell>, bool)> {
        let fields = self.fields.lock().ok()?;
        let e = fields.get(&field)?;
        Some((e.claimed.clone(), e.population.clone(), e.twin))
    }

    /// Draws the population of `field` and stores it unless another copy
    /// was stored first. `Err` carries this draw's own error.
    fn draw(&self, field: u32, twin: bool, cell: &PopulationCell) -> Result<(), GenerateError> {
        let spec = self.plan.population();
        match crate::model::population::base_field(&spec, field) {
            Ok(base) => {
                let twin = twin.then(|| crate::model::population::twin(&spec, &base));
                let _ = cell.set(Some(Arc::new(Population { base, twin })));
                Ok(())
            }
            Err(source) => {
                let _ = cell.set(None);
                Err(GenerateError::Population { field, source })
            }
        }
    }

    /// The population of `field`, drawn now if no lane has finished drawing
    /// it. `Err(None)`: it could not be drawn and a lane that drew it
    /// reports why.
    fn get(&self, field: u32) -> Result<Arc<Population>, Option<GenerateError>> {
        let (claimed, cell, twin) = self.entry(field).ok_or(None)?;
        if cell.get().is_none() {
            claimed.store(true, Ordering::Relaxed);
            self.draw(field, twin, &cell).map_err(Some)?;
        }
        match cell.get() {
            Some(Some(p)) => Ok(p.clone()),
            _ => Err(None),
        }
    }

    /// Draws the population of `field` if no lane has started to. A field
    /// whose images are all made has nothing to draw.
    fn draw_ahead(&self, field: u32) -> Result<(), Option<GenerateError>> {
        let Some((claimed, cell, twin)) = self.entry(field) else {
            return Ok(());
        };
        if claimed.swap(true, Ordering::Relaxed) {
            return Ok(());
        }
        self.draw(field, twin, &cell).map_err(Some)
    }

    /// One image of `field` is made; after its last, the population goes.
    fn finished(&self, field: u32) {
        if let Ok(mut fields) = self.fields.lock()
            && let Some(e) = fields.get_mut(&field)
        {
            e.remaining -= 1;
            if e.remaining == 0 {
                fields.remove(&field);
            }
        }
    }
}
