//! Tests of a whole run: its layout, resume, the disk estimate, and each
//! image as a pure function of its field, dataset and keys.

use super::*;
use crate::io::image_fits::{ImageHeader, SampleFormat, write_image_fits};
use crate::model::render::try_draw_image;
use stepsim_contract::digest::sha256_hex;
use stepsim_contract::run_layout::{Datasets, Manifest};
use stepsim_contract::seed::{SeedKey, Stream};

fn plan(overrides: &[&str]) -> Plan {
    let mut o: Vec<String> = [
        "run.seed=20060101",
        "image.width_px=96",
        "image.height_px=80",
        "image.n_images=2",
        "image.margin_arcsec=5",
        "psfs=[{\"name\":\"a\",\"model\":\"gaussian\"},{\"name\":\"b\",\"model\":\"gaussian\",\"fwhm_arcsec\":1.1}]",
        "shears=[{\"g1\":0.0},{\"g1\":0.04,\"g2\":-0.02}]",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    o.extend(overrides.iter().map(|s| s.to_string()));
    let o: Vec<&str> = o.iter().map(String::as_str).collect();
    Plan::from_json("{}", Path::new("t.json"), &o).unwrap()
}

#[test]
fn jobs_enumerate_fields_twins_and_datasets() {
    let p = plan(&["population.rotated_pairs=true"]);
    let key = blinding_key(&p);
    let js = jobs(&p, &key).unwrap();
    assert_eq!(js.len(), 2 * 2 * 4);
    assert_eq!((js[0].field, js[0].rotated, js[0].dataset), (0, false, 0));
    assert_eq!((js[5].field, js[5].rotated, js[5].dataset), (0, true, 1));
    assert_eq!((js[15].field, js[15].rotated, js[15].dataset), (1, true, 3));
    assert!(js.iter().enumerate().all(|(i, j)| j.order == i));
    // Dataset ids are shared by the images of a dataset only.
    assert_eq!(js[1].dataset_id, js[5].dataset_id);
    assert_ne!(js[1].dataset_id, js[2].dataset_id);
    // Twins get different noise.
    assert_ne!(js[0].noise_key(1).seed(), js[4].noise_key(1).seed());
}

#[test]
fn run_writes_layout_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let p = plan(&[]);
    let quiet = |_: Event| {};
    let s = generate(&p, dir.path(), &Options::default(), &quiet).unwrap();
    assert_eq!((s.total, s.written, s.skipped), (8, 8, 0));
    assert!(s.manifest_written && s.stray_tmp.is_empty());
    let run = RunDir::new(dir.path());
    let m: Manifest =
        serde_json::from_str(&std::fs::read_to_string(run.public().manifest()).unwrap()).unwrap();
    assert_eq!(m.images.len(), 8);
    for im in &m.images {
        let bytes = std::fs::read(run.public().file(&im.file)).unwrap();
        assert_eq!(sha256_hex(&bytes), im.sha256);
    }
    let d: Datasets =
        serde_json::from_str(&std::fs::read_to_string(run.private().datasets()).unwrap()).unwrap();
    assert_eq!(d.datasets[3].psf, "b");
    assert_eq!((d.datasets[3].g1, d.datasets[3].g2), (0.04, -0.02));
    // Truth rows carry the dataset's shear.
    let im = &d.datasets[3].images[1];
    let rows =
        stepsim_contract::io::truth::read_truth_fits(&run.private().truth(&im.image)).unwrap();
    assert!(!rows.is_empty() && rows.iter().all(|r| r.g1 == 0.04 && r.g2 == -0.02));
    // Second run: everything verified, nothing written.
    let s = generate(&p, dir.path(), &Options::default(), &quiet).unwrap();
    assert_eq!((s.written, s.skipped), (0, 8));
    // A different config into the same directory is refused.
    let other = plan(&["run.seed=5"]);
    let err = generate(&other, dir.path(), &Options::default(), &quiet).unwrap_err();
    assert!(matches!(err, GenerateError::DifferentRun { .. }), "{err}");
}

/// Bytes of the files under `dir` whose path passes `keep`.
fn bytes_where(dir: &Path, keep: &dyn Fn(&Path) -> bool) -> u64 {
    let mut total = 0;
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let path = e.path();
        if path.is_dir() {
            total += bytes_where(&path, keep);
        } else if keep(&path) {
            total += e.metadata().unwrap().len();
        }
    }
    total
}

#[test]
fn the_disk_estimate_matches_what_a_run_writes() {
    // An optical PSF (solved, stored, written at the renderer's side)
    // and a Gaussian one, float32 images.
    let dir = tempfile::tempdir().unwrap();
    let p = plan(&[
        "image.width_px=256",
        "image.height_px=256",
        "psfs=[{\"name\":\"o\",\"model\":\"optical\",\"aberration\":\"none\",\"fwhm_arcsec\":0.9},{\"name\":\"g\",\"model\":\"gaussian\"}]",
    ]);
    let before = crate::run::disk::generate_estimate(&p, None);
    let s = generate(&p, dir.path(), &Options::default(), &|_: Event| {}).unwrap();
    let after = &s.disk_estimate;
    let part = |e: &crate::run::memory::MemoryEstimate, what: &str| {
        e.parts
            .iter()
            .find(|x| x.what.contains(what))
            .map_or(0, |x| x.bytes)
    };
    let root = dir.path();
    let run = RunDir::new(root);
    let under = |sub: &Path, ext: &str| {
        bytes_where(sub, &|f| {
            f.extension().is_some_and(|x| x == ext) && !f.starts_with(run.private().psf_cache())
        })
    };
    let block = crate::run::disk::FITS_BLOCK_BYTES;
    // Images: at most three header blocks more than written, each.
    let images = under(run.public().path(), "fits");
    let est = part(after, "images of");
    assert!(
        est >= images && est - images <= 3 * block * 8,
        "{est} {images}"
    );
    // PSF files: the solved side, at most one block more per file; the
    // optical one's side (> 128) was counted at 128 before solving.
    let psf_files = under(&run.private().psf_dir(), "fits");
    let est = part(after, "PSF file");
    assert!(
        est >= psf_files && est - psf_files <= 2 * block,
        "{est} {psf_files}"
    );
    assert!(part(&before, "PSF file") < psf_files / 2);
    assert!(
        after
            .parts
            .iter()
            .any(|x| x.what.starts_with("2 PSF files (128–"))
    );
    // The store: its files, exactly; unknown before solving.
    let store = bytes_where(&run.private().psf_cache(), &|_| true);
    assert!(store > 0);
    assert_eq!(part(after, "private/psf/cache"), store);
    assert_eq!(part(&before, "private/psf/cache"), 0);
    // Truth: the expected rows of a field; what was written has the
    // rows drawn (Poisson), so it lies within 5σ of the estimate.
    let truth = under(&run.private().truth_dir(), "fits");
    let est = part(after, "truth tables") as f64;
    let expected = crate::run::memory::objects_per_field(&p);
    let rel = 5.0 / expected.sqrt();
    assert!(expected > 20.0, "{expected}");
    assert!(
        (truth as f64 / est - 1.0).abs() < rel,
        "truth {truth} against {est} ({expected} objects)"
    );
    // Everything else fits in the small files' share.
    let all = bytes_where(root, &|_| true);
    let rest = all - images - psf_files - store - truth;
    assert!(rest <= part(after, "small files"), "{rest}");
    // And the whole: within the truth tables' spread.
    let total = after.total_bytes() as f64;
    assert!((all as f64 / total - 1.0).abs() < 0.1, "{all} {total}");
}

#[test]
fn lens_positions_moves_the_galaxies_of_each_dataset() {
    // Datasets 0 (g = 0) and 1 (g = (0.04, −0.02)) of field 0: in the
    // truth tables, every galaxy of dataset 1 sits at the lensed position
    // of the same galaxy in dataset 0; stars do not move.
    let dir = tempfile::tempdir().unwrap();
    let p = plan(&["population.lens_positions=true", "image.n_images=1"]);
    generate(&p, dir.path(), &Options::default(), &|_: Event| {}).unwrap();
    let run = RunDir::new(dir.path());
    let d: Datasets =
        serde_json::from_str(&std::fs::read_to_string(run.private().datasets()).unwrap()).unwrap();
    let truth = |k: usize| {
        stepsim_contract::io::truth::read_truth_fits(
            &run.private().truth(&d.datasets[k].images[0].image),
        )
        .unwrap()
    };
    let (flat, lensed) = (truth(0), truth(1));
    let (cx, cy) = p.lensing_centre();
    let mut moved = 0;
    for r in &lensed {
        let Some(f) = flat.iter().find(|f| f.id == r.id) else {
            continue;
        };
        let want = if r.is_star() {
            (f.x, f.y)
        } else {
            let (dx, dy) = stepsim_contract::shear::lens_offset((f.x - cx, f.y - cy), 0.04, -0.02);
            (cx + dx, cy + dy)
        };
        assert!(
            (r.x - want.0).abs() < 1e-9 && (r.y - want.1).abs() < 1e-9,
            "{r:?}"
        );
        moved += usize::from(!r.is_star() && (r.x, r.y) != (f.x, f.y));
    }
    assert!(moved > 0);
}

#[test]
fn noise_free_image_is_model_plus_sky_and_model_is_verified() {
    let dir = tempfile::tempdir().unwrap();
    let p = plan(&["output.noise=false", "output.write_model=true"]);
    let quiet = |_: Event| {};
    generate(&p, dir.path(), &Options::default(), &quiet).unwrap();
    let key = blinding_key(&p);
    let js = jobs(&p, &key).unwrap();
    let run = RunDir::new(dir.path());
    let det = p.detector();
    let sky_adu = det.sky_e_per_px / det.gain_e_per_adu;
    for j in &js {
        let img = stepsim_contract::io::image::read_image_fits(
            &run.public().image(&j.dataset_id, &j.image_id),
        )
        .unwrap();
        let model = stepsim_contract::io::image::read_image_fits(&run.private().model(&j.image_id))
            .unwrap();
        assert!(model.pixels.iter().any(|&m| m > 1.0), "model has objects");
        for (a, m) in img.pixels.iter().zip(&model.pixels) {
            // float32 rounding at 2e4 ADU: ulp 0.002
            assert!((f64::from(a - m) - sky_adu).abs() < 0.01, "{a} - {m}");
        }
        let side = integrity::read_sidecar(&run, j, &config_sha256(&p))
            .unwrap()
            .unwrap();
        assert!(side.model_sha256.is_some());
        assert_eq!(side.output_version, OUTPUT_VERSION);
        assert!(verify(&run, j, true, &config_sha256(&p)).unwrap());
    }
    // A damaged model makes its image pending again.
    std::fs::write(run.private().model(&js[3].image_id), b"junk").unwrap();
    assert!(!verify(&run, &js[3], true, &config_sha256(&p)).unwrap());
    let s = generate(&p, dir.path(), &Options::default(), &quiet).unwrap();
    assert_eq!((s.written, s.skipped), (1, 7));
}

#[test]
fn the_turned_twin_at_minus_g_is_the_field_at_g_turned() {
    // With `rotate_positions` the twin is the field turned by 90°: drawn
    // with shear −g it is the field drawn with +g, turned ((x, y) →
    // (W + 1 − y, x) in FITS pixels), up to the drawing's rounding.
    let p = plan(&[
        "image.width_px=128",
        "image.height_px=128",
        "population.rotated_pairs=true",
        "population.rotate_positions=true",
        "population.lens_positions=true",
        "shears=[{\"g1\":0.04,\"g2\":-0.02},{\"g1\":-0.04,\"g2\":0.02}]",
    ]);
    let key = blinding_key(&p);
    let all = jobs(&p, &key).unwrap();
    let job = |dataset: u32, rotated: bool| {
        all.iter()
            .find(|j| j.field == 0 && j.rotated == rotated && j.dataset == dataset)
            .unwrap()
    };
    // Datasets 0 and 1: PSF a (round) with +g and −g.
    let pop = p.population();
    let base = crate::model::population::base_field(&pop, 0).unwrap();
    let turned = crate::model::population::twin(&pop, &base);
    let r = p.renderer(0).unwrap();
    let draw =
        |rows: &[stepsim_contract::truth::TruthRow]| try_draw_image(&r, rows, 128, 128).unwrap();
    let field = draw(&pipeline::dataset_rows(&p, job(0, false), &base));
    let twin = draw(&pipeline::dataset_rows(&p, job(1, true), &turned));
    let peak = field.iter().fold(0f32, |m, &v| m.max(v));
    assert!(peak > 0.0);
    let w = 128;
    let mut worst = 0f32;
    for y in 0..w {
        for x in 0..w {
            // 0-based: field (x, y) lands at (w − 1 − y, x).
            let d = (field[y * w + x] - twin[x * w + (w - 1 - y)]).abs();
            worst = worst.max(d);
        }
    }
    assert!(worst < 1e-4 * peak, "{worst} of {peak}");
    // Not the same image unturned.
    let unturned = field
        .iter()
        .zip(&twin)
        .fold(0f32, |m, (a, b)| m.max((a - b).abs()));
    assert!(unturned > 0.1 * peak);
}

#[test]
fn an_image_is_its_field_sheared_drawn_and_noised_with_its_own_key() {
    // Rebuild one image of the run by hand from the documented recipe and
    // compare bytes: base field k (rotated twin), the dataset's shear and
    // PSF, noise key (seed, k, dataset, Noise) with sub-stream 1.
    let dir = tempfile::tempdir().unwrap();
    let p = plan(&["population.rotated_pairs=true"]);
    let quiet = |_: Event| {};
    generate(&p, dir.path(), &Options::default(), &quiet).unwrap();
    let key = blinding_key(&p);
    let job = jobs(&p, &key)
        .unwrap()
        .into_iter()
        .find(|j| j.field == 1 && j.rotated && j.dataset == 3)
        .unwrap();
    let d = &p.datasets()[3];
    assert_eq!((d.psf, d.g1, d.g2), (1, 0.04, -0.02));
    let rows = crate::model::population::sheared(
        &crate::model::population::rotated(
            &crate::model::population::base_field(&p.population(), 1).unwrap(),
        ),
        d.g1,
        d.g2,
    );
    let det = p.detector();
    let r = p.renderer(1).unwrap();
    let (w, h) = (p.geometry().width_px, p.geometry().height_px);
    let model = try_draw_image(&r, &rows, w, h).unwrap();
    let noise_key = SeedKey::image(p.seed(), 1, 3, Stream::Noise).with_index(1);
    let pixels = crate::model::noise::realise_slow(&model, w as usize, &det, Some(noise_key));
    let by_hand = dir.path().join("by_hand.fits");
    write_image_fits(
        &by_hand,
        &pixels,
        w,
        h,
        &ImageHeader::new(&p.geometry(), p.instrument()),
        SampleFormat::Float32,
        crate::io::image_fits::Compression::None,
    )
    .unwrap();
    let run = RunDir::new(dir.path());
    assert!(
        std::fs::read(&by_hand).unwrap()
            == std::fs::read(run.public().image(&job.dataset_id, &job.image_id)).unwrap()
    );
    let truth =
        stepsim_contract::io::truth::read_truth_fits(&run.private().truth(&job.image_id)).unwrap();
    assert_eq!(truth, rows);
}
