//! Every preset in configs/ loads, validates and describes what its name says.

use std::path::Path;
use stepsim_sim::Plan;

fn load(name: &str) -> Plan {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("configs")
        .join(name);
    Plan::load(&path, &[]).unwrap_or_else(|e| panic!("{name}: {e}"))
}

#[test]
fn every_preset_validates() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "json") {
            Plan::load(&path, &[]).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            n += 1;
        }
    }
    assert!(n >= 2, "expected at least the two STEP1 presets, found {n}");
}

#[test]
fn the_step1_presets_carry_no_seed() {
    // A release is only as blind as its seed is secret: each run of a preset
    // draws its own.
    for name in ["step1.json", "step1-mini.json"] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("configs")
            .join(name);
        let json = std::fs::read_to_string(&path).unwrap();
        assert_eq!(Plan::seed_written_in(&json, &path), None, "{name}");
        assert_eq!(load(name).seed_origin(), stepsim_sim::SeedOrigin::Drawn);
    }
}

#[test]
fn step1_is_the_paper_design() {
    let p = load("step1.json");
    let im = p.geometry();
    assert_eq!((im.width_px, im.height_px, p.n_fields()), (4096, 4096, 64));
    assert_eq!(im.pixel_scale_arcsec, 0.206);
    assert_eq!(p.n_psfs(), 6);
    let g1: Vec<f64> = p.shears().iter().map(|s| s.g1).collect();
    assert_eq!(g1, [0.0, 0.005, 0.01, 0.05, 0.1]);
    assert!(p.shears().iter().all(|s| s.g2 == 0.0));
    assert_eq!(p.datasets().len(), 30);
    assert_eq!(p.instrument().sky_mag_arcsec2, 19.2);
    // STEP1 sheared shapes only: positions are not lensed (κ = 0).
    assert!(!p.lens_positions());
    assert!(!load("step1-mini.json").lens_positions());
}

#[test]
fn mini_has_the_same_datasets_on_small_images() {
    let full = load("step1.json");
    let mini = load("step1-mini.json");
    // The same PSF × shear design (the base fields differ in number).
    let design = |p: &stepsim_sim::Plan| {
        p.datasets()
            .iter()
            .map(|d| (d.index, d.psf, d.shear, d.part, d.g1, d.g2))
            .collect::<Vec<_>>()
    };
    assert_eq!(design(&mini), design(&full));
    let psfs = |p: &stepsim_sim::Plan| {
        p.psf_specs()
            .iter()
            .map(|s| (s.name.clone(), s.fwhm_arcsec, s.model.clone()))
            .collect::<Vec<_>>()
    };
    assert_eq!(psfs(&mini), psfs(&full));
    assert_eq!(
        (
            mini.geometry().width_px,
            mini.geometry().height_px,
            mini.n_fields()
        ),
        (1024, 1024, 2)
    );
}

#[test]
fn deep_lensed_is_the_benchmark_design_of_docs_metacal() {
    // docs/metacal.md, "A deep lensed scene whose twins turn the whole
    // field": its numbers were measured on this config, seed included.
    let p = load("deep-lensed.json");
    let im = p.geometry();
    assert_eq!((im.width_px, im.height_px, p.n_fields()), (4096, 4096, 64));
    assert_eq!(p.seed(), 2612071);
    assert!(p.lens_positions() && p.rotated_pairs());
    assert!(p.population().rotate_positions);
    let g: Vec<(f64, f64)> = p.shears().iter().map(|s| (s.g1, s.g2)).collect();
    assert_eq!(g, [(-0.04, -0.04), (0.04, 0.04)]);
    assert_eq!(p.n_psfs(), 1);
    assert_eq!(p.instrument().sky_mag_arcsec2, 24.2);
    assert_eq!(p.instrument().exposure_s, 1e6);
}
