//! One run per directory: `generate` claims its directory before any work,
//! refuses by name every file another config (or another stepsim) made,
//! never leaves a manifest listing a missing image, and `score` refuses ids
//! of another run.

use std::path::Path;
use std::process::Output;

use crate::common;
use common::{files, ok, run, stderr};

fn generate(dir: &Path, config: &str, out: &str, extra: &[&str]) -> Output {
    let mut args = vec!["generate", "--config", config, "--out", out];
    args.extend_from_slice(extra);
    run(&args, dir)
}

/// 2 PSFs × 2 shears × 2 small images.
const X: &str = r#"{
  "run": {"name": "x", "seed": 77},
  "image": {"width_px": 48, "height_px": 40, "n_images": 2, "margin_arcsec": 1.0},
  "population": {"galaxies": {"mag_faint": 23.0}},
  "psfs": [{"name": "a", "model": "gaussian"}, {"name": "b", "model": "gaussian", "fwhm_arcsec": 1.1}],
  "shears": [{"g1": 0.0}, {"g1": 0.04}]
}"#;

/// X with other shears (and the same seed).
fn y_config() -> String {
    X.replace(r#"{"g1": 0.04}"#, r#"{"g1": 0.02}"#)
}

fn setup() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("x.json"), X).unwrap();
    std::fs::write(dir.path().join("y.json"), y_config()).unwrap();
    dir
}

#[test]
fn a_directory_holds_one_run_even_without_its_config() {
    let dir = setup();
    let d = dir.path();
    ok(generate(d, "x.json", "run", &[]));
    let before = files(&d.join("run"));
    // Another config into the same directory: refused, naming the config.
    let o = generate(d, "y.json", "run", &[]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains("run/private/config.json") && e.contains("different config"),
        "{e}"
    );
    assert!(files(&d.join("run")) == before);
    // Without private/config.json the other config is still refused, naming
    // a file of the first run; nothing is mixed in.
    std::fs::remove_file(d.join("run/private/config.json")).unwrap();
    let o = generate(d, "y.json", "run", &[]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("does not belong to this run"), "{e}");
    // The refused run leaves the directory as it found it (its claim undone).
    let mut expected = before.clone();
    expected.remove(Path::new("private/config.json"));
    assert!(files(&d.join("run")) == expected);
    // Even with only the shared private files left, the other run is told.
    let only = d.join("only");
    ok(generate(d, "x.json", "only", &[]));
    for sub in ["public", "private/truth", "private/done", "private/psf"] {
        std::fs::remove_dir_all(only.join(sub)).unwrap();
    }
    std::fs::remove_file(only.join("private/config.json")).unwrap();
    let o = generate(d, "y.json", "only", &[]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains("only/private/blinding.key") && e.contains("does not belong"),
        "{e}"
    );
    // With its own config back the first run is whole again.
    let e = stderr(&ok(generate(d, "x.json", "run", &[])));
    assert!(e.contains("0 images written, 8 already"), "{e}");
    assert!(files(&d.join("run")) == before);
}

#[test]
fn a_sidecar_of_another_config_or_version_is_refused_by_name() {
    let dir = setup();
    let d = dir.path();
    ok(generate(d, "x.json", "run", &[]));
    let done = d.join("run/private/done");
    let side = std::fs::read_dir(&done)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let text = std::fs::read_to_string(&side).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(
        v["output_version"],
        stepsim_sim::run::generate::OUTPUT_VERSION
    );
    let sha = v["config_sha256"].as_str().unwrap().to_string();
    assert_eq!(
        sha,
        stepsim_contract::digest::sha256_hex(
            &std::fs::read(d.join("run/private/config.json")).unwrap()
        )
    );
    let name = side.file_name().unwrap().to_string_lossy().into_owned();
    for (changed, why) in [
        (
            text.replace(&sha, &"0".repeat(64)),
            "made by another config",
        ),
        (
            text.replace(
                &format!(
                    "\"output_version\": {}",
                    stepsim_sim::run::generate::OUTPUT_VERSION
                ),
                "\"output_version\": 1",
            ),
            "made by another version of stepsim",
        ),
        (
            text.replace(&format!(",\n  \"config_sha256\": \"{sha}\""), ""),
            "not a sidecar this stepsim can read",
        ),
    ] {
        assert_ne!(changed, text);
        std::fs::write(&side, &changed).unwrap();
        let before = files(&d.join("run"));
        let o = generate(d, "x.json", "run", &[]);
        assert_eq!(o.status.code(), Some(1), "{why}");
        let e = stderr(&o);
        assert!(e.contains(&name) && e.contains(why), "{why}: {e}");
        assert!(files(&d.join("run")) == before, "{why}: nothing touched");
    }
    std::fs::write(&side, &text).unwrap();
    ok(generate(d, "x.json", "run", &[]));
}

#[test]
fn concurrent_runs_of_different_configs_cannot_both_succeed() {
    let dir = setup();
    let d = dir.path();
    for round in 0..3 {
        let out = format!("run{round}");
        let spawn = |config: &str| {
            common::stepsim()
                .args(["generate", "--config", config, "--out", &out])
                .current_dir(d)
                .stderr(std::process::Stdio::piped())
                .spawn()
                .unwrap()
        };
        let (a, b) = (spawn("x.json"), spawn("y.json"));
        let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
        let codes = [a.status.code(), b.status.code()];
        assert!(
            codes == [Some(0), Some(1)] || codes == [Some(1), Some(0)],
            "round {round}: {codes:?}"
        );
        let loser = if a.status.success() { &b } else { &a };
        assert!(
            stderr(loser).contains("different config"),
            "{}",
            stderr(loser)
        );
        // The winner's run is whole: its rerun verifies every image.
        let winner = if a.status.success() {
            "x.json"
        } else {
            "y.json"
        };
        let e = stderr(&ok(generate(d, winner, &out, &[])));
        assert!(e.contains("0 images written, 8 already"), "{e}");
    }
}

#[test]
fn a_manifest_never_lists_a_missing_image() {
    let dir = setup();
    let d = dir.path();
    ok(generate(d, "x.json", "run", &[]));
    let manifest_path = d.join("run/public/manifest.json");
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&manifest_path).unwrap()).unwrap();
    // Image j of the canonical order belongs to shard j mod 2 + 1: find one
    // of shard 1 through datasets.json (field 0, dataset 0 is j = 0).
    let datasets: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("run/private/datasets.json")).unwrap())
            .unwrap();
    let ds0 = &datasets["datasets"][0];
    let file = format!(
        "{}/{}.fits",
        ds0["dataset"].as_str().unwrap(),
        ds0["images"][0]["image"].as_str().unwrap()
    );
    assert!(
        manifest["images"]
            .as_array()
            .unwrap()
            .iter()
            .any(|i| i["file"] == file.as_str())
    );
    let image = d.join("run/public").join(&file);
    let bytes = std::fs::read(&image).unwrap();
    std::fs::remove_file(&image).unwrap();
    // Shard 2 does not own it: it makes nothing but removes the manifest.
    let e = stderr(&ok(generate(d, "x.json", "run", &["--shard", "2/2"])));
    assert!(e.contains("removed the manifest"), "{e}");
    assert!(!manifest_path.exists());
    assert!(!image.exists());
    // The whole run makes it again, and the manifest comes back.
    let e = stderr(&ok(generate(d, "x.json", "run", &[])));
    assert!(e.contains("1 image written, 7 already"), "{e}");
    assert!(std::fs::read(&image).unwrap() == bytes);
    let again: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&manifest_path).unwrap()).unwrap();
    assert_eq!(again, manifest);
}

#[test]
fn an_unwritable_output_is_refused_before_any_work() {
    let dir = setup();
    let d = dir.path();
    // A directory cannot be made below a regular file (root or not).
    std::fs::write(d.join("plain"), "x").unwrap();
    // The claim of private/config.json comes before any work: no PSF is
    // built (a missing PSF file is refused even earlier, when the config is
    // loaded: see the tests in sim/src/run/plan.rs).
    let o = generate(d, "x.json", "plain/run", &[]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("plain/run/private"), "{e}");
    assert!(!e.contains("PSF"), "{e}");
    assert_eq!(std::fs::read(d.join("plain")).unwrap(), b"x");
}

#[test]
fn score_refuses_ids_of_another_run() {
    let dir = setup();
    let d = dir.path();
    ok(generate(d, "x.json", "x", &[]));
    ok(generate(d, "y.json", "y", &[]));
    // A submission for run x (one row per image), scored against run y,
    // whose seed is the same: no id is shared.
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("x/public/manifest.json")).unwrap()).unwrap();
    let mut sub = String::from("# image x y e1 e2 weight\n");
    let images = m["images"].as_array().unwrap();
    for im in images {
        sub.push_str(&format!("{} 10 10 0 0 1\n", im["image"].as_str().unwrap()));
    }
    std::fs::write(d.join("sub.txt"), &sub).unwrap();
    let y: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("y/public/manifest.json")).unwrap()).unwrap();
    for (a, b) in images.iter().zip(y["images"].as_array().unwrap()) {
        assert_ne!(a["image"], b["image"]);
        assert_ne!(a["dataset"], b["dataset"]);
    }
    let o = run(
        &[
            "score",
            "--truth",
            "y/private",
            "--submission",
            "sub.txt",
            "--out",
            "scored",
        ],
        d,
    );
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    let first = images[0]["image"].as_str().unwrap();
    assert!(
        e.contains("sub.txt") && e.contains("unknown image id") && e.contains(first),
        "{e}"
    );
    assert!(!d.join("scored").exists());
}
