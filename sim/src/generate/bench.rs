//! The pieces of `stepsim bench`: one image made stage by stage with each
//! stage timed (a benchmark, never a test assertion). Galaxies and stars are
//! added to the image separately so that their costs can be told apart, and
//! the image-level PSF convolution of the split method
//! ([`crate::render::split`]) is its own stage; the result is the model that
//! the noise stage uses. Process CPU time is read from `/proc/self/stat`
//! (clock ticks, 10 ms) around each stage.

use super::GenerateError;
use crate::io::image_fits::{ImageHeader, write_image_fits};
use crate::noise;
use crate::plan::Plan;
use crate::render::{Canvas, Renderer};
use crate::seed::{SeedKey, Stream};
use std::path::Path;
use std::time::Instant;

/// Wall-clock seconds of each stage of one image, and what it held.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTimes {
    /// Base field and shear.
    pub population_s: f64,
    /// Building (calibrating) the PSF and its renderer.
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
    /// Writing the FITS file.
    pub write_s: f64,
    /// Galaxies in the base field.
    pub n_galaxies: usize,
    /// Stars in the base field.
    pub n_stars: usize,
    /// Process CPU seconds (all threads) of the galaxy stage.
    pub galaxies_cpu_s: f64,
    /// Process CPU seconds of the convolution stage.
    pub convolve_cpu_s: f64,
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
    }
}

/// Makes image `field` of the dataset with PSF `psf_index` and the last
/// shear of the plan, writing it to `scratch` (overwritten), and times every
/// stage.
pub fn run_once(
    plan: &Plan,
    psf_index: usize,
    field: u32,
    scratch: &Path,
) -> Result<StageTimes, GenerateError> {
    let (w, h) = (plan.image().width_px, plan.image().height_px);
    let pixel_scale = plan.pixel_scale_arcsec();
    let shear = plan.shears().last().expect("validated plan has shears");
    let mut t = StageTimes::default();
    let cpu_start = process_cpu_s();

    let clock = Instant::now();
    let base = crate::population::base_field(plan, field)
        .map_err(|source| GenerateError::Population { field, source })?;
    let rows = crate::population::sheared(&base, shear.g1, shear.g2);
    let (galaxies, stars): (Vec<_>, Vec<_>) = rows.into_iter().partition(|r| !r.is_star());
    t.population_s = clock.elapsed().as_secs_f64();
    t.n_galaxies = galaxies.len();
    t.n_stars = stars.len();

    let clock = Instant::now();
    let det = plan.detector();
    let psf =
        crate::psf::build(&plan.psf_spec(psf_index)).map_err(|source| GenerateError::Psf {
            index: psf_index,
            name: plan.psfs()[psf_index].name.clone(),
            source,
        })?;
    let renderer = Renderer::new(psf, pixel_scale, plan.accuracy(), det.sky_sigma_e());
    // The split method's image kernel belongs to the PSF stage too.
    if let Some(split) = renderer.split() {
        split.convolver(w as usize, h as usize);
    }
    t.psf_s = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let cpu = process_cpu_s();
    let mut canvas = Canvas::new(&renderer, w, h);
    canvas
        .try_add(&galaxies)
        .map_err(|source| GenerateError::Render { field, source })?;
    t.galaxies_s = clock.elapsed().as_secs_f64();
    t.galaxies_cpu_s = process_cpu_s() - cpu;

    let clock = Instant::now();
    canvas
        .try_add(&stars)
        .map_err(|source| GenerateError::Render { field, source })?;
    t.stars_s = clock.elapsed().as_secs_f64();

    let clock = Instant::now();
    let cpu = process_cpu_s();
    let model = canvas.finish();
    t.convolve_s = clock.elapsed().as_secs_f64();
    t.convolve_cpu_s = process_cpu_s() - cpu;

    let clock = Instant::now();
    let key = SeedKey::image(plan.seed(), field, 0, Stream::Noise);
    let pixels = noise::realise(&model, w as usize, &det, Some(key));
    t.noise_s = clock.elapsed().as_secs_f64();
    drop(model);

    let clock = Instant::now();
    let header = ImageHeader::new(plan.image(), plan.instrument(), field);
    write_image_fits(
        scratch,
        &pixels,
        w,
        h,
        &header,
        plan.output().format,
        plan.output().compression,
    )?;
    t.write_s = clock.elapsed().as_secs_f64();
    t.total_cpu_s = process_cpu_s() - cpu_start;
    Ok(t)
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
        let raw = crate::config::RawConfig::parse(
            "{}",
            Path::new("t.json"),
            &[
                "image.width_px=64".into(),
                "image.height_px=64".into(),
                "image.n_images=1".into(),
            ],
        )
        .unwrap();
        let plan = Plan::new(raw, Path::new("t.json")).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.fits");
        let t = run_once(&plan, 1, 0, &path).unwrap();
        assert!(t.n_galaxies > 0 && t.n_stars > 0);
        assert!(t.total_s() >= t.noise_s);
        let img = crate::io::image_fits::read_image_fits(&path).unwrap();
        assert_eq!(img.pixels.len(), 64 * 64);
        assert!(peak_memory_bytes().is_some_and(|b| b > 0));
        assert!(t.total_cpu_s >= 0.0 && t.convolve_s > 0.0);
    }
}
