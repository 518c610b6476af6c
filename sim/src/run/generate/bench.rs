//! The pieces of `stepsim bench`: one image made stage by stage with each
//! stage timed (a benchmark, never a test assertion). Galaxies and stars are
//! added to the image separately so that their costs can be told apart, and
//! the image-level PSF convolution of the split method
//! ([`crate::model::render::split`]) is its own stage; the result is the model that
//! the noise stage uses. The image is made by the run's own pipeline
//! (`pipeline.rs`), so the benchmark times exactly what `generate`
//! does per image. Process CPU time is read from `/proc/self/stat` (clock
//! ticks, 10 ms) around each stage.

use super::pipeline::{Context, Lap, make_image};
use super::{GenerateError, Made, RunDir};
use crate::run::plan::Plan;
use std::path::Path;

pub use super::pipeline::{StageTimes, process_cpu_s};

/// Makes image `field` (not the rotated twin) of the dataset with PSF
/// `psf_index` and the last shear of the plan, exactly as `generate` makes
/// it (the same `pipeline::make_image`, the same noise key, truth table, checksums
/// and sidecar), into the run directory `scratch` (created; its files are
/// overwritten), and times every stage. The base field and the PSF are
/// drawn and built here, each once per call, and timed as `population_s`
/// and `psf_s`; a run draws a base field once for all its datasets and
/// builds each PSF once.
pub fn run_once(
    plan: &Plan,
    psf_index: usize,
    field: u32,
    scratch: &Path,
) -> Result<StageTimes, GenerateError> {
    let (w, h) = (plan.geometry().width_px, plan.geometry().height_px);
    let last_shear = plan.shears().len() - 1;
    let dataset = plan
        .datasets()
        .iter()
        .find(|d| d.psf == psf_index && d.shear == last_shear)
        .expect("every PSF has a dataset with every shear");
    let key = super::blinding_key(plan);
    let job = super::jobs(plan, &key)?
        .into_iter()
        .find(|j| j.field == field && !j.rotated && j.dataset == dataset.index)
        .expect("the field is in range");
    let run = RunDir::new(scratch);
    super::make_dataset_dirs(&run, std::slice::from_ref(&job))?;
    let mut t = StageTimes::default();
    let cpu_start = process_cpu_s();
    let mut lap = Lap::start(true);

    let base = crate::model::population::base_field(&plan.population(), field)
        .map_err(|source| GenerateError::Population { field, source })?;
    t.population_s = lap.lap().0;

    let det = plan.detector();
    let renderer = plan
        .renderer(psf_index)
        .map_err(|source| GenerateError::Psf {
            index: psf_index,
            name: plan.psf_name(psf_index).to_string(),
            source,
        })?;
    // The split method's image kernel belongs to the PSF stage too.
    if let Some(split) = renderer.split() {
        split.convolver(w as usize, h as usize);
    }
    t.psf_s = lap.lap().0;

    let config_sha256 = super::config_sha256(plan);
    let made = Made {
        config_sha256: &config_sha256,
    };
    let cx = Context {
        plan,
        run: &run,
        det: &det,
        made: &made,
    };
    make_image(&cx, &job, &base, &renderer, &mut lap, &mut t)?;
    t.total_cpu_s = process_cpu_s() - cpu_start;
    Ok(t)
}

/// Peak resident memory of this process in bytes (`VmHWM` of
/// `/proc/self/status`), when the system reports it.
pub fn peak_memory_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_small_image_runs_every_stage() {
        let plan = Plan::from_json(
            "{}",
            Path::new("t.json"),
            &[
                "image.width_px=64",
                "image.height_px=64",
                "image.n_images=1",
                // A written seed: with a drawn one this 64² image had no
                // star in one CI run, and the test failed by chance.
                "run.seed=7",
                "psfs=[{\"name\":\"a\",\"model\":\"gaussian\"},{\"name\":\"b\",\"model\":\"moffat\",\"beta\":3.5}]",
                "shears=[{\"g1\":0.0},{\"g1\":0.04,\"g2\":-0.02}]",
            ],
        )
        .unwrap();
        let dir = tempfile::tempdir().unwrap();
        let t = run_once(&plan, 1, 0, dir.path()).unwrap();
        assert!(t.n_galaxies > 0 && t.n_stars > 0);
        assert!(peak_memory_bytes().is_some_and(|b| b > 0));
        // The benchmark's image is the run's own image of that dataset,
        // byte for byte (same pipeline, same noise key, same files).
        let run = tempfile::tempdir().unwrap();
        let quiet = |_: super::super::Event| {};
        super::super::generate(&plan, run.path(), &Default::default(), &quiet).unwrap();
        let key = super::super::blinding_key(&plan);
        let last = plan.shears().len() - 1;
        let d = plan
            .datasets()
            .iter()
            .find(|d| d.psf == 1 && d.shear == last)
            .unwrap();
        let job = super::super::jobs(&plan, &key)
            .unwrap()
            .into_iter()
            .find(|j| j.field == 0 && !j.rotated && j.dataset == d.index)
            .unwrap();
        let (a, b) = (RunDir::new(dir.path()), RunDir::new(run.path()));
        for (x, y) in [
            (
                a.public().image(&job.dataset_id, &job.image_id),
                b.public().image(&job.dataset_id, &job.image_id),
            ),
            (
                a.private().truth(&job.image_id),
                b.private().truth(&job.image_id),
            ),
        ] {
            assert!(
                std::fs::read(&x).unwrap() == std::fs::read(&y).unwrap(),
                "{x:?}"
            );
        }
        let side = std::fs::read_to_string(a.private().sidecar(&job.image_id)).unwrap();
        assert_eq!(
            side,
            std::fs::read_to_string(b.private().sidecar(&job.image_id)).unwrap()
        );
    }
}
