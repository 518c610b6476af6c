//! `public/README.md`: what participants are told. It states facts about the
//! data and the conventions, never a PSF name, shear, seed or run name.

use crate::io::image_fits::{Compression, SampleFormat};
use crate::run::plan::Plan;
use std::fmt::Write as _;

/// The participants' README of a run. `submission_format` is the paragraph
/// describing the submission format (see [`stepsim_contract::SUBMISSION_FORMAT_MD`]).
pub fn participants_readme(plan: &Plan, submission_format: &str) -> String {
    let ins = plan.instrument();
    let img = plan.geometry();
    let det = plan.detector();
    let n_per = plan.datasets()[0].fields.len() as u32 * if plan.rotated_pairs() { 2 } else { 1 };
    let magzero = ins.zp_eff() - 2.5 * ins.gain_e_per_adu.log10();
    let pixels = match (plan.output().format, plan.output().compression) {
        (SampleFormat::Float32, _) => "32-bit floats (BITPIX −32)".to_string(),
        (SampleFormat::Int32, Compression::None) => {
            "32-bit integers (BITPIX 32), ADU rounded to the nearest integer".to_string()
        }
        (SampleFormat::Int32, Compression::Rice) => "32-bit integers (BITPIX 32), ADU rounded to \
             the nearest integer, losslessly Rice tile-compressed (the image is in HDU 1; \
             `funpack` or any cfitsio/astropy reader opens it)"
            .to_string(),
    };
    let mut s = String::new();
    let _ = write!(
        s,
        "# Simulated weak-lensing images

This directory holds simulated ground-based images in the style of the Shear
TEsting Programme (STEP1, Heymans et al. 2006). Every image shows galaxies and
stars seen through a point-spread function (PSF) and sheared by a constant
reduced shear. Your task: measure the shear of every galaxy you detect and send
back a catalogue.

## What is here

- `manifest.json`: every image with its id, its dataset id, its file and the
  SHA-256 of the file; plus the instrument facts below. Check your download
  with `sha256sum`.
- `<dataset-id>/<image-id>.fits`: the images, {n_datasets} datasets of {n_per}
  {images} each. All images of one dataset share the same PSF and the same
  shear. Ids are opaque: they say nothing about the PSF or the shear.
- As in STEP1, the same galaxies appear in images of several datasets (only
  shear, PSF and noise differ), but nothing tells which images share them:
  every image has the same header.

## The images

- {width} × {height} pixels of {pixscale}″ (header `PIXSCALE`), I band.
- Pixel values in ADU; gain {gain} e⁻/ADU (`GAIN`). Pixels are {pixels}.
- The sky is **not** subtracted: about {sky_mag} mag/arcsec², i.e. about
  {sky_adu:.1} ADU per pixel; estimate it yourself.
- Noise: Poisson photon noise on sky and objects, plus Gaussian read noise of
  {ron} e⁻ rms (`RDNOISE`); an empty sky pixel has σ ≈ {sigma_adu:.2} ADU.
- Exposure {exposure} s (`EXPTIME`). Magnitudes (I, Vega):
  m = {magzero:.4} − 2.5 log10(total ADU) (`MAGZERO`), i.e.
  {zp} − 2.5 log10(electrons per second).
- Pixels at or above {saturation} ADU (`SATURATE`) are clipped (saturated).
- Stars (point sources) are in every image: use them to model the PSF.
- Every image carries the same TAN WCS (`CTYPE`, `CRVAL`, `CRPIX`, `CD`):
  north up, east left. Its reference point is a convention, the same for
  every image, not the image's own place on the sky.

## Conventions

- Pixel coordinates are FITS coordinates: the centre of the first pixel is
  (1.0, 1.0) and x runs along NAXIS1.
- Shear: reduced shear g = γ/(1−κ) with κ = 0; positive g1 stretches an
  image along x, positive g2 along the line y = x. Report, for every galaxy,
  your estimate γ̂ of the shear (not its ellipticity): averaged over many
  galaxies it should give the dataset's shear.
- Position angles are counter-clockwise from the +x axis.

{submission_format}",
        n_datasets = plan.datasets().len(),
        images = if n_per == 1 { "image" } else { "images" },
        width = img.width_px,
        height = img.height_px,
        pixscale = img.pixel_scale_arcsec,
        gain = ins.gain_e_per_adu,
        sky_mag = ins.sky_mag_arcsec2,
        sky_adu = det.sky_e_per_px / ins.gain_e_per_adu,
        ron = ins.read_noise_e,
        sigma_adu = det.sky_sigma_e() / ins.gain_e_per_adu,
        exposure = ins.exposure_s,
        zp = ins.zeropoint_mag,
        saturation = ins.saturation_adu,
    );
    if !s.ends_with('\n') {
        s.push('\n');
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn readme_states_the_facts_and_names_no_secret() {
        let plan = Plan::from_json(
            "{}",
            Path::new("t.json"),
            &["run.name=secretname", "run.seed=97531"],
        )
        .unwrap();
        let text = participants_readme(&plan, "SUBMIT-PARAGRAPH\n");
        for fact in [
            "4096 × 4096",
            "0.206″",
            "gain 4 e⁻/ADU",
            "5 e⁻ rms",
            "65535 ADU",
            "3600 s",
            "30 datasets of 64",
            "SUBMIT-PARAGRAPH",
            "(1.0, 1.0)",
            "every image has the same header",
        ] {
            assert!(text.contains(fact), "missing {fact:?}");
        }
        // Sky 80 174.6 e⁻ / 4 = 20 043.66 ADU; σ = sqrt(80 174.6 + 25) / 4 = 70.80 ADU.
        assert!(text.contains("about\n  20043.7 ADU"), "{text}");
        assert!(text.contains("σ ≈ 70.80 ADU"), "{text}");
        assert!(!text.contains("same sky position"), "{text}");
        for secret in [
            "secretname",
            "97531",
            "coma",
            "jitter",
            "defocus",
            "trefoil",
        ] {
            assert!(!text.contains(secret), "README names {secret}");
        }
    }

    #[test]
    fn one_image_a_dataset_is_said_in_the_singular() {
        let text = |n: &str| {
            let n_images = format!("image.n_images={n}");
            let plan = Plan::from_json(
                "{}",
                Path::new("t.json"),
                &[&n_images, "population.rotated_pairs=false"],
            )
            .unwrap();
            participants_readme(&plan, "")
        };
        assert!(
            text("1").contains("30 datasets of 1\n  image each"),
            "{}",
            text("1")
        );
        assert!(
            text("2").contains("30 datasets of 2\n  images each"),
            "{}",
            text("2")
        );
    }
}
