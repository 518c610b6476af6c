//! End-to-end checks of `stepsim psf`: outputs, report keys, refusals.
//! (The six calibrated STEP1 PSFs are tested in the library,
//! `stepsim_sim::model::psf::tests`; here a small config keeps the run short.)

use std::path::Path;
use std::process::Output;
use stepsim_sim::Plan;
use stepsim_sim::io::psf_fits::{read_image_hdu, read_psf_fits};

use crate::common;
use common::run;

/// Writes `config` to `dir/c.json` and runs `stepsim psf` on it into
/// `dir/out`, with `extra` arguments.
fn run_psf(dir: &Path, config: &str, extra: &[&str]) -> Output {
    let cfg = dir.join("c.json");
    std::fs::write(&cfg, config).unwrap();
    let out_dir = dir.join("out");
    let mut args = vec![
        "psf",
        "--config",
        cfg.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    run(&args, dir)
}

/// `psf_report.json` of a run of [`run_psf`] in `dir`, which must have
/// succeeded.
fn report_of(dir: &Path, out: &Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&std::fs::read(dir.join("out/psf_report.json")).unwrap()).unwrap()
}

const CONFIG: &str = r#"{
  "psfs": [
    {"name": "none", "model": "optical", "aberration": "none"},
    {"name": "gauss", "model": "gaussian", "e1": 0.05},
    {"name": "moffat", "model": "moffat", "beta": 3.5}
  ]
}"#;

#[test]
fn writes_images_report_and_picture() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("out");
    let out = run_psf(
        dir.path(),
        CONFIG,
        &["--size-px", "64", "--oversample", "3"],
    );
    let report = report_of(dir.path(), &out);
    assert_eq!(report["pixel_scale_arcsec"], 0.206);
    // The resolved config is written beside the outputs (and reads back).
    let resolved = std::fs::read_to_string(out_dir.join("config.json")).unwrap();
    let plan = Plan::from_json(&resolved, &out_dir.join("config.json"), &[]).unwrap();
    assert_eq!(plan.n_psfs(), 3);
    let psfs = report["psfs"].as_array().unwrap();
    assert_eq!(psfs.len(), 3);
    for key in [
        "name",
        "fwhm_arcsec",
        "chi1",
        "chi2",
        "centroid_x",
        "centroid_y",
        "seeing_fwhm_arcsec",
        "amplitude",
        "ee_1arcsec",
        "ee_2arcsec",
    ] {
        assert!(psfs[0].get(key).is_some(), "missing {key}");
    }
    // The optical PSF is calibrated to 0.9″; the Gaussian's FWHM is that of
    // the profile, so with the pixel it is wider; its χ follows e1.
    let f0 = psfs[0]["fwhm_arcsec"].as_f64().unwrap();
    assert!((f0 - 0.9).abs() < 0.02, "{f0}");
    assert!(psfs[0]["seeing_fwhm_arcsec"].as_f64().unwrap() < 0.9);
    assert!(psfs[1]["seeing_fwhm_arcsec"].is_null());
    let chi1 = psfs[1]["chi1"].as_f64().unwrap();
    assert!(chi1 > 0.08 && chi1 < 0.1, "{chi1}");
    // FITS: primary at the pixel scale, OVERSAMPLED 3× finer, unit sums.
    for name in ["none", "gauss", "moffat"] {
        let path = out_dir.join(format!("{name}.fits"));
        let (v, nx, ny) = read_psf_fits(&path).unwrap();
        assert_eq!((nx, ny), (64, 64));
        assert!((v.iter().sum::<f64>() - 1.0).abs() < 1e-6);
        let (w, nx, _) = read_image_hdu(&path, Some("OVERSAMPLED")).unwrap();
        assert_eq!(nx, 192);
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-6);
        // Peak on the centre pixel (FITS 33, 33).
        let k = v
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .unwrap()
            .0;
        assert_eq!((k % 64, k / 64), (32, 32));
    }
    let png = std::fs::read(out_dir.join("psf_cores.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    // Nothing half-written left behind.
    assert!(
        std::fs::read_dir(&out_dir).unwrap().all(|e| !e
            .unwrap()
            .file_name()
            .to_string_lossy()
            .ends_with(".tmp"))
    );
}

#[test]
fn a_fits_psf_round_trips_through_the_config() {
    // Write a Gaussian PSF file, then use it as a `fits` model.
    let dir = tempfile::tempdir().unwrap();
    let n = 48;
    let mut v = vec![0.0; n * n];
    for j in 0..n {
        for i in 0..n {
            let (x, y) = ((i as f64 - 24.0) * 0.05, (j as f64 - 24.0) * 0.05);
            v[j * n + i] = (-(x * x + y * y) / (2.0 * 0.2f64.powi(2))).exp();
        }
    }
    let psf_path = dir.path().join("g.fits");
    stepsim_sim::io::psf_fits::write_psf_fits(
        &psf_path,
        "g",
        stepsim_sim::io::psf_fits::PsfImage {
            data: &v,
            n,
            scale_arcsec: 0.05,
        },
        stepsim_sim::io::psf_fits::PsfImage {
            data: &v,
            n,
            scale_arcsec: 0.05,
        },
        1,
        &[],
    )
    .unwrap();
    let text = format!(
        r#"{{"psfs": [{{"name": "f", "model": "fits", "path": {:?}, "pixel_scale_arcsec": 0.05}}]}}"#,
        psf_path.to_str().unwrap()
    );
    let report = report_of(dir.path(), &run_psf(dir.path(), &text, &[]));
    // σ = 0.2″ → FWHM 0.471″ before the 0.206″ pixel; with it, wider.
    let f = report["psfs"][0]["fwhm_arcsec"].as_f64().unwrap();
    assert!(f > 0.471 && f < 0.55, "{f}");
    assert!(report["psfs"][0]["chi1"].as_f64().unwrap().abs() < 1e-4);
}

#[test]
fn refusals_exit_1_and_usage_errors_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    // A missing PSF file is named.
    let out = run_psf(
        dir.path(),
        r#"{"psfs": [{"name": "f", "model": "fits", "path": "/nonexistent/p.fits", "pixel_scale_arcsec": 0.1}]}"#,
        &[],
    );
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("/nonexistent/p.fits"), "{err}");
    // An unreachable calibration is refused with the PSF's name.
    let blurry = r#"{"psfs": [{"name": "blurry", "model": "optical", "aberration": "defocus", "amplitude": 3.0}]}"#;
    let out = run_psf(dir.path(), blurry, &[]);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("psf blurry") && err.contains("fwhm_arcsec"),
        "{err}"
    );
    assert!(!dir.path().join("out/psf_report.json").exists());
    // Usage errors.
    for bad in [
        &["--size-px", "15"][..],
        &["--oversample", "0"],
        &["--size-px", "abc"],
    ] {
        assert_eq!(
            run_psf(dir.path(), blurry, bad).status.code(),
            Some(2),
            "{bad:?}"
        );
    }
}
