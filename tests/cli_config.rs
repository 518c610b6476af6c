//! End-to-end checks of `stepsim config`: exit codes and messages.

use crate::common;
use common::{ok, run_with, stderr, stepsim};

#[test]
fn resolved_config_is_printed_with_overrides() {
    let out = ok(run_with(
        stepsim()
            .args([
                "config",
                "--config",
                "configs/step1-mini.json",
                "--set",
                "image.n_images=3",
            ])
            .current_dir(env!("CARGO_MANIFEST_DIR")),
    ));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["image"]["n_images"], 3);
    assert_eq!(v["image"]["width_px"], 1024);
    // The preset has no seed: none is printed (each `generate` draws its own).
    assert!(v["run"].get("seed").is_none(), "{}", v["run"]);
    let e = stderr(&out);
    assert!(e.contains("run.seed is not given"), "{e}");
}

#[test]
fn bad_configs_exit_1_naming_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "unknown.json",
            "{\"image\": {\"n_imgs\": 2}}",
            "image.n_imgs",
        ),
        (
            "malformed.json",
            "{\n\"image\": {\n\"n_images\": 2,,\n}}",
            "line 3",
        ),
        (
            "negative.json",
            "{\"image\": {\"pixel_scale_arcsec\": -0.2}}",
            "image.pixel_scale_arcsec",
        ),
        (
            "emptyq.json",
            "{\"population\": {\"galaxies\": {\"flattening\": {\"min\": 0.8, \"max\": 0.5}}}}",
            "population.galaxies.flattening",
        ),
    ];
    for (name, text, needle) in cases {
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        let out = run_with(stepsim().args(["config", "--config"]).arg(&path));
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{name}: {err}");
        assert!(err.contains(needle), "{name}: expected {needle:?} in {err}");
        assert!(
            err.contains(name),
            "{name}: message should name the file: {err}"
        );
    }
}

#[test]
fn a_missing_file_is_named_once_with_the_os_reason_once() {
    let out = run_with(stepsim().args(["config", "--config", "/nonexistent/stepsim.json"]));
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("/nonexistent/stepsim.json"), "{err}");
    assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
}

#[test]
fn usage_errors_exit_2() {
    let out = run_with(stepsim().args(["config", "--no-such-flag"]));
    assert_eq!(out.status.code(), Some(2));
}
