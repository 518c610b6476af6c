//! One image of a run, stage by stage: the code `generate` runs for every
//! image and `bench` times ([`super::bench`]). From the base field's rows
//! to the finished files:
//!
//! 1. rows of the dataset: sheared (and lensed) base field ([`dataset_rows`]);
//! 2. model: galaxies, stars, then the image-level PSF convolution
//!    ([`draw_model`]);
//! 3. pixels: sky, photon and read noise ([`crate::model::noise::realise`]) keyed
//!    by the job ([`super::Job::noise_key`]);
//! 4. files: the public image, the truth table ([`crate::io::truth_header::truth_keywords`]), the
//!    optional model, and last the sidecar with their SHA-256 (each file
//!    is built in memory and hashed as written: nothing is read back).
//!
//! Every stage's wall time goes to a [`StageTimes`] (and process CPU time
//! when asked for); generate discards them, bench prints them.

use super::{GenerateError, Job, Made, RunDir, Sidecar};
use crate::io::image_fits::{ImageHeader, SampleFormat, write_image_fits};
use crate::io::truth_header::truth_keywords;
use crate::model::noise::{self, Detector};
use crate::model::render::{Canvas, RenderError, Renderer};
use crate::run::plan::Plan;
use std::time::Instant;
use stepsim_contract::io::truth::write_truth_fits;
use stepsim_contract::io::write_bytes_atomically;
use stepsim_contract::truth::TruthRow;

/// Wall-clock seconds of each stage of one image, and what it held.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTimes {
    /// Base field (bench only: generate draws it once per field) and the
    /// dataset's shear.
    pub population_s: f64,
    /// Building (calibrating) the PSF and its renderer (bench only).
    pub psf_s: f64,
    /// Drawing the galaxies.
    pub galaxies_s: f64,
    /// Drawing the stars.
    pub stars_s: f64,
    /// Convolving the image with the PSF's wings (split method; 0 for the
    /// stamp method).
    pub convolve_s: f64,
    /// Sky, photon and read noise.
    pub noise_s: f64,
    /// Writing the public FITS image.
    pub write_s: f64,
    /// Writing the truth table.
    pub truth_s: f64,
    /// Writing the noise-free model (`output.write_model`).
    pub model_s: f64,
    /// SHA-256 of the files and the sidecar.
    pub checksum_s: f64,
    /// Galaxies in the dataset's rows.
    pub n_galaxies: usize,
    /// Stars in the dataset's rows.
    pub n_stars: usize,
    /// Process CPU seconds (all threads) of the galaxy stage.
    pub galaxies_cpu_s: f64,
    /// Process CPU seconds of the convolution stage.
    pub convolve_cpu_s: f64,
    /// Process CPU seconds of the noise stage.
    pub noise_cpu_s: f64,
    /// Process CPU seconds of the whole image.
    pub total_cpu_s: f64,
}

impl StageTimes {
    /// Total of the stages.
    pub fn total_s(&self) -> f64 {
        self.population_s
            + self.psf_s
            + self.galaxies_s
            + self.stars_s
            + self.convolve_s
            + self.noise_s
            + self.write_s
            + self.truth_s
            + self.model_s
            + self.checksum_s
    }
}

/// A stopwatch of wall time and (when `cpu`) process CPU time.
#[derive(Debug, Clone, Copy)]
pub struct Lap {
    wall: Instant,
    cpu_s: f64,
    with_cpu: bool,
}

impl Lap {
    /// Starts now; reads `/proc/self/stat` only when `with_cpu`.
    pub fn start(with_cpu: bool) -> Self {
        Self {
            wall: Instant::now(),
            cpu_s: if with_cpu { process_cpu_s() } else { 0.0 },
            with_cpu,
        }
    }

    /// (wall, CPU) seconds since the start or the last lap; restarts.
    pub fn lap(&mut self) -> (f64, f64) {
        let next = Self::start(self.with_cpu);
        let out = (
            (next.wall - self.wall).as_secs_f64(),
            next.cpu_s - self.cpu_s,
        );
        *self = next;
        out
    }
}

/// The rows of `job`'s dataset: its base field (`base`, already the
/// rotated twin when `job.rotated`) sheared by the dataset's shear, and
/// lensed too with `population.lens_positions`.
pub fn dataset_rows(plan: &Plan, job: &Job, base: &[TruthRow]) -> Vec<TruthRow> {
    let d = &plan.datasets()[job.dataset as usize];
    let rows = crate::model::population::sheared(base, d.g1, d.g2);
    if plan.lens_positions() {
        crate::model::population::lensed(&plan.population(), job.field, &rows, d.g1, d.g2)
    } else {
        rows
    }
}

/// The noise-free model of `rows` in electrons: the galaxies, then the
/// stars, then the image-level convolution of the split method. Stamps are
/// added in the drawing order ([`crate::model::render::drawing_order`]:
/// galaxies first) whatever the split, so the bytes equal those of
/// [`crate::model::render::try_draw_image`].
pub fn draw_model(
    renderer: &Renderer,
    rows: &[TruthRow],
    width: u32,
    height: u32,
    lap: &mut Lap,
    t: &mut StageTimes,
) -> Result<Vec<f32>, RenderError> {
    t.n_galaxies = rows.iter().filter(|r| !r.is_star()).count();
    t.n_stars = rows.len() - t.n_galaxies;
    let mut canvas = Canvas::new(renderer, width, height);
    canvas.try_add_only(rows, false)?;
    (t.galaxies_s, t.galaxies_cpu_s) = lap.lap();
    canvas.try_add_only(rows, true)?;
    t.stars_s = lap.lap().0;
    let model = canvas.finish();
    (t.convolve_s, t.convolve_cpu_s) = lap.lap();
    Ok(model)
}

/// What every image of a run shares.
pub(crate) struct Context<'a> {
    pub plan: &'a Plan,
    pub run: &'a RunDir,
    pub det: &'a Detector,
    pub made: &'a Made<'a>,
}

/// Makes one image and its private files (the sidecar last), timing each
/// stage into `t` (whose `population_s` it adds the shear to).
pub(crate) fn make_image(
    cx: &Context,
    job: &Job,
    base: &[TruthRow],
    renderer: &Renderer,
    lap: &mut Lap,
    t: &mut StageTimes,
) -> Result<(), GenerateError> {
    let (plan, run, det) = (cx.plan, cx.run, cx.det);
    let d = &plan.datasets()[job.dataset as usize];
    let (w, h) = (plan.geometry().width_px, plan.geometry().height_px);
    let output = plan.output();
    let rows = dataset_rows(plan, job, base);
    t.population_s += lap.lap().0;

    let render_err = |source| GenerateError::Render {
        field: job.field,
        source,
    };
    let model = draw_model(renderer, &rows, w, h, lap, t).map_err(render_err)?;

    let noise_key = output.noise.then(|| job.noise_key(plan.seed()));
    // The model becomes the pixels in place unless it is written too.
    let (pixels, model) = if output.write_model {
        (
            noise::realise(&model, w as usize, det, noise_key),
            Some(model),
        )
    } else {
        let mut pixels = model;
        noise::realise_in_place(&mut pixels, w as usize, det, noise_key);
        (pixels, None)
    };
    (t.noise_s, t.noise_cpu_s) = lap.lap();

    let header = ImageHeader::new(&plan.geometry(), plan.instrument());
    let image_path = run.public().image(&job.dataset_id, &job.image_id);
    let format = (output.format, output.compression);
    let image_sha256 = write_image_fits(&image_path, &pixels, w, h, &header, format.0, format.1)?;
    drop(pixels);
    t.write_s = lap.lap().0;

    let truth_path = run.private().truth(&job.image_id);
    let keywords = truth_keywords(job.field, job.rotated, d.psf, d.g1, d.g2);
    let truth_sha256 = write_truth_fits(&truth_path, &rows, &keywords)?;
    t.truth_s = lap.lap().0;

    let model_sha256 = if let Some(model) = &model {
        let adu: Vec<f32> = model
            .iter()
            .map(|&m| (f64::from(m) / det.gain_e_per_adu) as f32)
            .collect();
        let path = run.private().model(&job.image_id);
        let none = crate::io::image_fits::Compression::None;
        let sha = write_image_fits(&path, &adu, w, h, &header, SampleFormat::Float32, none)?;
        t.model_s = lap.lap().0;
        Some(sha)
    } else {
        None
    };
    drop(model);

    let side = Sidecar {
        image: job.image_id.clone(),
        dataset: job.dataset_id.clone(),
        file: job.public_file(),
        sha256: image_sha256,
        truth_sha256,
        model_sha256,
        config_sha256: cx.made.config_sha256.to_string(),
        output_version: super::OUTPUT_VERSION,
    };
    let text = serde_json::to_string_pretty(&side).expect("sidecar serialises") + "\n";
    write_bytes_atomically(&run.private().sidecar(&job.image_id), text.as_bytes())?;
    t.checksum_s = lap.lap().0;
    Ok(())
}

/// User + system CPU seconds of this process so far (all threads), from
/// `/proc/self/stat` at 100 ticks per second (Linux's USER_HZ); 0 where the
/// file is missing.
pub fn process_cpu_s() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    // Fields after the parenthesised command name; utime and stime are
    // fields 14 and 15 of the whole line.
    let Some(rest) = stat.rfind(')').map(|i| &stat[i + 1..]) else {
        return 0.0;
    };
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| fields.get(i).and_then(|v| v.parse::<f64>().ok());
    match (tick(11), tick(12)) {
        (Some(u), Some(s)) => (u + s) / 100.0,
        _ => 0.0,
    }
}
