//! End-to-end checks of `stepsim generate`: reproducibility at any thread
//! count and shard split, blindness of the public half, resume, Rice output
//! and refused configs.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Output;

use crate::common;
use common::{files, run, run_env, stderr};

/// 2 PSFs × 2 shears × 2 images of 128², with secrets that are easy to grep.
const CONFIG: &str = r#"{
  "run": {"name": "runNameSecret", "seed": 8675309},
  "image": {"width_px": 128, "height_px": 96, "n_images": 2, "margin_arcsec": 2.0},
  "psfs": [
    {"name": "psfAlphaSecret", "model": "gaussian", "fwhm_arcsec": 0.9},
    {"name": "psfBetaSecret", "model": "moffat", "beta": 3.5, "fwhm_arcsec": 0.85}
  ],
  "shears": [{"g1": 0.0173, "g2": -0.0231}, {"g1": 0.0419, "g2": 0.0067}]
}"#;

const SECRETS: &[&str] = &[
    "runNameSecret",
    "8675309",
    "psfAlphaSecret",
    "psfBetaSecret",
    "0.0173",
    "-0.0231",
    "0.0231",
    "0.0419",
    "0.0067",
    "moffat",
    "gaussian",
];

fn setup() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("c.json"), CONFIG).unwrap();
    dir
}

fn generate(dir: &Path, out: &str, extra: &[&str]) -> Output {
    let mut args = vec!["generate", "--config", "c.json", "--out", out];
    args.extend_from_slice(extra);
    let o = run(&args, dir);
    assert!(o.status.success(), "generate {extra:?} failed");
    o
}

/// The files that must be identical between runs: public/ and private/
/// except the PSF files (written by whichever shard built the PSF) and the
/// shards' done-markers.
fn release(run: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut f = files(&run.join("public"));
    for (k, v) in files(&run.join("private")) {
        if !k.starts_with("psf") && !k.starts_with("shards") {
            f.insert(Path::new("private").join(k), v);
        }
    }
    f
}

fn manifest(run: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(run.join("public/manifest.json")).unwrap()).unwrap()
}

/// Public file of each image, keyed by (dataset index, field, rotated), from
/// `private/datasets.json`.
fn image_files(run: &Path) -> BTreeMap<(usize, u64, bool), String> {
    let d: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("private/datasets.json")).unwrap()).unwrap();
    let mut out = BTreeMap::new();
    for (i, ds) in d["datasets"].as_array().unwrap().iter().enumerate() {
        let did = ds["dataset"].as_str().unwrap();
        for im in ds["images"].as_array().unwrap() {
            let key = (
                i,
                im["field"].as_u64().unwrap(),
                im["rotated"].as_bool().unwrap(),
            );
            let file = format!("{did}/{}.fits", im["image"].as_str().unwrap());
            out.insert(key, file);
        }
    }
    out
}

#[test]
fn finish_refuses_listing_the_missing_images_and_a_rerun_shard_completes() {
    let dir = setup();
    let d = dir.path();
    generate(d, "whole", &[]);
    generate(d, "sh", &["--shard", "1/2"]);
    let o = run(
        &["generate", "--config", "c.json", "--out", "sh", "--finish"],
        d,
    );
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("4 of 8 images"), "{e}");
    assert!(e.contains("rerun shard 2/2"), "{e}");
    // Every missing image is listed: the ones of shard 2 (odd j).
    let files = image_files(&d.join("whole"));
    let listed = e.matches("missing or unverified: public/").count();
    assert_eq!(listed, 4, "{e}");
    assert!(files.values().filter(|f| e.contains(f.as_str())).count() == 4);
    // Nothing written: no manifest.
    assert!(!d.join("sh/public/manifest.json").exists());
    // A damaged image of shard 1 is caught by --finish, by its checksum.
    generate(d, "sh", &["--shard", "2/2"]);
    let first = files[&(0, 0, false)].clone();
    let path = d.join("sh/public").join(&first);
    let good = std::fs::read(&path).unwrap();
    let mut bad = good.clone();
    *bad.last_mut().unwrap() ^= 1;
    std::fs::write(&path, &bad).unwrap();
    let o = run(
        &["generate", "--config", "c.json", "--out", "sh", "--finish"],
        d,
    );
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("1 of 8 images") && e.contains(&first), "{e}");
    assert!(e.contains("rerun shard 1/2"), "{e}");
    assert!(!d.join("sh/public/manifest.json").exists());
    // Shard 1 rerun alone makes that image again; --finish then completes.
    generate(d, "sh", &["--shard", "1/2"]);
    generate(d, "sh", &["--finish"]);
    assert_eq!(
        std::fs::read(d.join("sh/public/manifest.json")).unwrap(),
        std::fs::read(d.join("whole/public/manifest.json")).unwrap()
    );
    assert_eq!(release(&d.join("sh")), release(&d.join("whole")));
    // --finish of a directory without a run, and with --shard: refused.
    let o = run(
        &[
            "generate", "--config", "c.json", "--out", "none", "--finish",
        ],
        d,
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("no run to finish"), "{}", stderr(&o));
    assert!(!d.join("none").exists());
    let o = run(
        &[
            "generate", "--config", "c.json", "--out", "sh", "--finish", "--shard", "1/2",
        ],
        d,
    );
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn a_finish_that_fails_removes_the_manifest_written_before() {
    // Issue #23: a run finished once, then one image altered: --finish
    // refused it but left the old manifest, which still claimed a run that
    // is no longer what it says (its checksum of that image is wrong).
    let dir = setup();
    let d = dir.path();
    generate(d, "sh", &["--shard", "1/2"]);
    generate(d, "sh", &["--shard", "2/2"]);
    generate(d, "sh", &["--finish"]);
    let manifest_path = d.join("sh/public/manifest.json");
    assert!(manifest_path.is_file());
    let file = image_files(&d.join("sh"))[&(1, 1, false)].clone();
    let path = d.join("sh/public").join(&file);
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[3000] ^= 0x40;
    std::fs::write(&path, &bytes).unwrap();
    let o = run(
        &["generate", "--config", "c.json", "--out", "sh", "--finish"],
        d,
    );
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("1 of 8 images") && e.contains(&file), "{e}");
    assert!(e.contains("the manifest written before was removed"), "{e}");
    assert!(!manifest_path.exists(), "a stale manifest is left");
    // Refused again: nothing to remove, and it does not say so.
    let o = run(
        &["generate", "--config", "c.json", "--out", "sh", "--finish"],
        d,
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(!stderr(&o).contains("was removed"), "{}", stderr(&o));
    // A whole run finished, then a truth table removed: --finish fails on
    // it and removes the manifest too.
    generate(d, "whole", &[]);
    assert!(d.join("whole/public/manifest.json").is_file());
    let truth = d.join("whole/private/truth").join(
        Path::new(&image_files(&d.join("whole"))[&(0, 0, false)])
            .file_name()
            .unwrap(),
    );
    std::fs::remove_file(&truth).unwrap();
    let o = run(
        &[
            "generate", "--config", "c.json", "--out", "whole", "--finish",
        ],
        d,
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(!d.join("whole/public/manifest.json").exists());
    // Another config is not the run's: refused before, the manifest stays.
    generate(d, "other", &[]);
    let o = run(
        &[
            "generate",
            "--config",
            "c.json",
            "--out",
            "other",
            "--finish",
            "--set",
            "run.seed=1",
        ],
        d,
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(d.join("other/public/manifest.json").is_file());
    // The image made again, --finish writes the manifest again.
    generate(d, "sh", &["--shard", "2/2"]);
    generate(d, "sh", &["--shard", "1/2"]);
    generate(d, "sh", &["--finish"]);
    assert!(manifest_path.is_file());
}

#[test]
fn shard_auto_outside_a_slurm_array_is_a_usage_error_and_inside_one_works() {
    let dir = setup();
    let d = dir.path();
    let o = common::run_with(
        common::stepsim()
            .args([
                "generate", "--config", "c.json", "--out", "a", "--shard", "auto",
            ])
            .current_dir(d)
            .env_remove("SLURM_ARRAY_TASK_ID")
            .env_remove("SLURM_ARRAY_TASK_COUNT")
            .env_remove("SLURM_ARRAY_TASK_MIN"),
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("SLURM_ARRAY_TASK_ID is not set"),
        "{}",
        stderr(&o)
    );
    assert!(!d.join("a").exists());
    // Array 0-1: task 1 is shard 2/2.
    let o = common::run_with(
        common::stepsim()
            .args([
                "generate", "--config", "c.json", "--out", "a", "--shard", "auto",
            ])
            .current_dir(d)
            .env("SLURM_ARRAY_TASK_ID", "1")
            .env("SLURM_ARRAY_TASK_COUNT", "2")
            .env("SLURM_ARRAY_TASK_MIN", "0"),
    );
    common::ok(o);
    assert!(d.join("a/private/shards/2-of-2.json").is_file());
}

#[test]
fn threads_and_shards_write_identical_bytes() {
    let dir = setup();
    let d = dir.path();
    generate(d, "t1", &["--threads", "1"]);
    generate(d, "t2", &["--threads", "2"]);
    // Shards in the order 3, 1, 2: none writes the manifest, each leaves its
    // done-marker naming the images it owns; --finish writes the manifest.
    for k in [3, 1, 2] {
        let o = generate(d, "sh", &["--shard", &format!("{k}/3"), "--threads", "2"]);
        assert!(
            !d.join("sh/public/manifest.json").exists(),
            "after shard {k}/3"
        );
        assert!(stderr(&o).contains("--finish"), "{}", stderr(&o));
        let marker: serde_json::Value = serde_json::from_slice(
            &std::fs::read(d.join(format!("sh/private/shards/{k}-of-3.json"))).unwrap(),
        )
        .unwrap();
        assert_eq!(marker["shard"], format!("{k}/3"));
        // 8 images: shard 1 owns j = 0, 3, 6; shard 2 j = 1, 4, 7; shard 3 j = 2, 5.
        let owned = if k == 3 { 2 } else { 3 };
        assert_eq!(marker["images"].as_array().unwrap().len(), owned);
    }
    let o = generate(d, "sh", &["--finish"]);
    assert!(stderr(&o).contains("all 8 images"), "{}", stderr(&o));
    // A whole run writes no marker.
    assert!(!d.join("t1/private/shards").exists());
    let a = release(&d.join("t1"));
    // 8 images + 8 truth tables + 8 sidecars + manifest, README, config,
    // datasets, blinding key.
    assert_eq!(a.len(), 8 * 3 + 5, "{:?}", a.keys().collect::<Vec<_>>());
    let images: Vec<_> = a
        .keys()
        .filter(|k| {
            k.to_string_lossy().starts_with('d') && k.extension().is_some_and(|e| e == "fits")
        })
        .collect();
    assert_eq!(images.len(), 8);
    for (name, other) in [
        ("threads 2", release(&d.join("t2"))),
        ("shards", release(&d.join("sh"))),
    ] {
        assert_eq!(
            a.keys().collect::<Vec<_>>(),
            other.keys().collect::<Vec<_>>(),
            "{name}"
        );
        for (k, v) in &a {
            assert!(other[k] == *v, "{name}: {} differs", k.display());
        }
    }
    // The manifest lists every image with the SHA-256 of its bytes.
    let m = manifest(&d.join("t1"));
    let list = m["images"].as_array().unwrap();
    assert_eq!(list.len(), 8);
    for im in list {
        let file = im["file"].as_str().unwrap();
        let bytes = &a[Path::new(file)];
        assert_eq!(
            stepsim_contract::digest::sha256_hex(bytes),
            im["sha256"].as_str().unwrap()
        );
    }
    // The images are noisy sky-level images of the right size with objects.
    let img = stepsim_contract::io::image::read_image_fits(
        &d.join("t1/public").join(list[0]["file"].as_str().unwrap()),
    )
    .unwrap();
    assert_eq!((img.width, img.height), (128, 96));
    let sky_adu = 80_174.626 / 4.0;
    let mut sorted = img.pixels.clone();
    sorted.sort_by(f32::total_cmp);
    let median = f64::from(sorted[sorted.len() / 2]);
    assert!((median / sky_adu - 1.0).abs() < 0.01, "median {median}");
}

#[test]
fn public_half_reveals_no_secret() {
    let dir = setup();
    let d = dir.path();
    generate(d, "run", &[]);
    let public = files(&d.join("run/public"));
    assert!(public.len() >= 10);
    for (path, bytes) in &public {
        let name = path.to_string_lossy();
        let text = String::from_utf8_lossy(bytes);
        for s in SECRETS {
            assert!(!name.contains(s), "{s} in file name {name}");
            assert!(!text.contains(s), "{s} in {name}");
        }
        // A public FITS header names neither a PSF nor a shear.
        if name.ends_with(".fits") {
            let header = &text[..2880];
            for k in ["PSF", "SHEAR", "G1 ", "G2 ", "SEED"] {
                assert!(!header.contains(k), "{k} in header of {name}");
            }
        }
    }
    // The private half does hold them (so that the check above can fail).
    let private = files(&d.join("run/private"));
    let all: String = private
        .iter()
        .filter(|(k, _)| k.extension().is_some_and(|e| e == "json"))
        .map(|(_, v)| String::from_utf8_lossy(v).into_owned())
        .collect();
    for s in [
        "runNameSecret",
        "8675309",
        "psfAlphaSecret",
        "0.0173",
        "-0.0231",
    ] {
        assert!(all.contains(s), "{s} missing from private/");
    }
}

#[test]
fn resume_rewrites_only_missing_or_damaged_images() {
    let dir = setup();
    let d = dir.path();
    generate(d, "ref", &[]);
    generate(d, "run", &[]);
    let before = release(&d.join("run"));
    let m = manifest(&d.join("run"));
    let list = m["images"].as_array().unwrap();
    let file = |i: usize| d.join("run/public").join(list[i]["file"].as_str().unwrap());
    // Every public file carries the run's one time stamp, so a rewrite is
    // told by the inode (a rename puts a new one in place).
    let inode = |p: &Path| std::os::unix::fs::MetadataExt::ino(&std::fs::metadata(p).unwrap());
    let untouched = file(7);
    let untouched_inode = inode(&untouched);
    let rewritten_inode = inode(&file(2));
    // Image 0: deleted, but its complete bytes left under a temporary name.
    let tmp = file(0).with_file_name(format!(
        ".{}.4194305.tmp",
        file(0).file_name().unwrap().to_string_lossy()
    ));
    std::fs::rename(file(0), &tmp).unwrap();
    // Image 1: truncated under its final name.
    let bytes = std::fs::read(file(1)).unwrap();
    std::fs::write(file(1), &bytes[..bytes.len() / 2]).unwrap();
    // Image 2: one pixel changed.
    let mut bytes = std::fs::read(file(2)).unwrap();
    let n = bytes.len();
    bytes[n - 100] ^= 1;
    std::fs::write(file(2), &bytes).unwrap();
    let o = generate(d, "run", &["--threads", "2"]);
    let err = stderr(&o);
    assert!(
        err.contains("3 images written, 5 already finished and verified"),
        "{err}"
    );
    // The dead writer's temporary (pid 4194305, above pid_max) is removed, never taken as finished.
    assert!(
        err.contains("removed") && err.contains(".4194305.tmp"),
        "{err}"
    );
    assert!(!tmp.exists());
    assert_eq!(inode(&untouched), untouched_inode);
    assert_ne!(inode(&file(2)), rewritten_inode);
    assert!(release(&d.join("run")) == before);
    assert!(release(&d.join("ref")) == before);
    // Nothing left to do.
    let o = generate(d, "run", &[]);
    assert!(
        stderr(&o).contains("0 images written, 8 already"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn rice_int32_output_is_the_float_image_rounded_exactly() {
    let dir = setup();
    let d = dir.path();
    generate(d, "f", &[]);
    generate(
        d,
        "r",
        &[
            "--set",
            "output.format=int32",
            "--set",
            "output.compression=rice",
        ],
    );
    // Same seed, same noise: the Rice image is the float image rounded to
    // integers, read back exactly. The configs differ, so the ids do: the
    // images are paired by dataset, field and twin.
    let (lf, lr) = (image_files(&d.join("f")), image_files(&d.join("r")));
    assert_eq!(lf.len(), 8);
    assert_eq!(lf.keys().collect::<Vec<_>>(), lr.keys().collect::<Vec<_>>());
    for (k, a) in &lf {
        let b = &lr[k];
        assert_ne!(a, b, "ids are unique to a run");
        let fa = d.join("f/public").join(a);
        let fb = d.join("r/public").join(b);
        let x = stepsim_contract::io::image::read_image_fits(&fa).unwrap();
        let y = stepsim_contract::io::image::read_image_fits(&fb).unwrap();
        assert_eq!(x.pixels.len(), y.pixels.len());
        for (p, q) in x.pixels.iter().zip(&y.pixels) {
            assert_eq!(stepsim_sim::io::image_fits::adu_to_i32(*p) as f32, *q);
        }
        assert!(std::fs::metadata(&fb).unwrap().len() < std::fs::metadata(&fa).unwrap().len());
    }
}

#[test]
fn refused_input_exits_1_and_writes_nothing() {
    let dir = setup();
    let d = dir.path();
    std::fs::write(d.join("bad.json"), r#"{"image": {"widht_px": 64}}"#).unwrap();
    // Each command line is split at spaces (no argument holds one).
    let cases = [
        ("generate --config bad.json --out x", "image.widht_px"),
        (
            "generate --config c.json --out x --set image.width_px=0",
            "image.width_px",
        ),
        (
            "generate --config c.json --out x --set output.compression=rice",
            "output.compression",
        ),
        ("generate --config missing.json --out x", "missing.json"),
    ];
    let run = |line: &str| run(&line.split(' ').collect::<Vec<_>>(), d);
    for (line, needle) in cases {
        let o = run(line);
        assert_eq!(o.status.code(), Some(1), "{line}");
        assert!(stderr(&o).contains(needle), "{line}: {}", stderr(&o));
        assert!(!d.join("x").exists(), "{line} wrote something");
    }
    // Usage errors exit 2.
    let o = run("generate --config c.json --out x --shard 4/3");
    assert_eq!(o.status.code(), Some(2));
    assert!(!d.join("x").exists());
    // A run directory made from another config is refused, untouched.
    generate(d, "y", &[]);
    let before = files(&d.join("y"));
    let o = run("generate --config c.json --out y --set run.seed=1");
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("different config"), "{}", stderr(&o));
    assert!(files(&d.join("y")) == before);
}

#[test]
fn killed_run_leaves_no_truncated_file_and_resumes_identically() {
    let dir = setup();
    let d = dir.path();
    let big = [
        "--set",
        "image.width_px=512",
        "--set",
        "image.height_px=512",
        "--set",
        "image.n_images=3",
    ];
    generate(d, "ref", &big);
    let mut args = vec!["generate", "--config", "c.json", "--out", "run"];
    args.extend_from_slice(&big);
    let mut child = common::stepsim()
        .args(&args)
        .current_dir(d)
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // Kill it while it works (wherever it is: the checks hold at any moment).
    while !d.join("run/private/truth").exists() {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    std::thread::sleep(std::time::Duration::from_millis(30));
    let _ = child.kill();
    child.wait().unwrap();
    // Every file under a final name is complete.
    for (path, _) in files(&d.join("run/public")) {
        let name = path.to_string_lossy().into_owned();
        if name.ends_with(".fits") && !name.contains("/.") {
            let img =
                stepsim_contract::io::image::read_image_fits(&d.join("run/public").join(&path))
                    .unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(img.pixels.len(), 512 * 512);
        }
    }
    generate(d, "run", &big);
    let (a, b) = (release(&d.join("ref")), release(&d.join("run")));
    assert_eq!(a.len(), 12 * 3 + 5);
    assert!(a == b, "resumed run differs from a straight run");
}

#[test]
fn off_a_terminal_progress_is_logged_and_an_unsharded_run_names_no_shard() {
    let dir = setup();
    let d = dir.path();
    let o = generate(d, "run", &["--threads", "1"]);
    let err = stderr(&o);
    let lines: Vec<&str> = err.lines().collect();
    // What it is doing, before and while it does it, in order.
    let at = |needle: &str| {
        lines
            .iter()
            .position(|l| l.contains(needle))
            .unwrap_or_else(|| panic!("no {needle:?} in {err}"))
    };
    let psfs = at("stepsim: building 2 PSFs");
    let first = at("stepsim: built PSF 1/2 (psfAlphaSecret)");
    let second = at("stepsim: built PSF 2/2 (psfBetaSecret)");
    let making = at("stepsim: making 8 images");
    let one = at("stepsim: 1/8 images written (12%)");
    let all = at("stepsim: 8/8 images written (100%)");
    assert!(psfs < first && first < second && second < making && making < one && one < all);
    // One line per image here (a tenth of 8 rounds up to 1).
    assert_eq!(err.matches("/8 images written").count(), 8, "{err}");
    assert!(
        err.contains("stepsim: 8 images written, 0 already finished and verified (8 in the run)"),
        "{err}"
    );
    assert!(!err.contains("shard"), "{err}");
    // A sharded run still names its shard.
    let o = generate(d, "run2", &["--shard", "1/2"]);
    assert!(
        stderr(&o).contains("stepsim: shard 1/2: 4 images written"),
        "{}",
        stderr(&o)
    );
}

/// One optical PSF (2.5 s to solve), 1 shear × 2 images of 128 × 96.
const OPTICAL: &str = r#"{
  "run": {"seed": 4242},
  "image": {"width_px": 128, "height_px": 96, "n_images": 2, "margin_arcsec": 2.0},
  "psfs": [{"name": "coma", "model": "optical", "aberration": "coma",
            "target_chi": 0.04, "fwhm_arcsec": 0.9}],
  "shears": [{"g1": 0.02, "g2": -0.01}]
}"#;

#[test]
fn generate_reuses_stored_psfs_across_shards_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("c.json"), OPTICAL).unwrap();
    let store = |run: &str| -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(d.join(run).join("private/psf/cache"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        v.sort();
        v
    };
    // One process: builds the PSF and stores it.
    let o = generate(d, "one", &[]);
    assert!(
        stderr(&o).contains("stepsim: built PSF 1/1 (coma), stored in "),
        "{}",
        stderr(&o)
    );
    let one_store = store("one");
    assert_eq!(one_store.len(), 1, "{one_store:?}");
    let stored = std::fs::read(&one_store[0]).unwrap();
    let header = format!(
        "stepsim psf store {}\nspec-sha256 ",
        stepsim_sim::io::psf_store::FORMAT
    );
    assert!(stored.starts_with(header.as_bytes()));
    // Two shards: the first builds and stores, the second reuses.
    let o = generate(d, "two", &["--shard", "1/2"]);
    assert!(
        stderr(&o).contains("built PSF 1/1 (coma), stored in "),
        "{}",
        stderr(&o)
    );
    let o = generate(d, "two", &["--shard", "2/2"]);
    let err = stderr(&o);
    assert!(
        err.contains("stepsim: reused PSF 1/1 (coma) from "),
        "{err}"
    );
    assert!(err.contains("private/psf/cache/"), "{err}");
    assert!(!err.contains("built PSF"), "{err}");
    generate(d, "two", &["--finish"]);
    assert!(
        release(&d.join("one")) == release(&d.join("two")),
        "reuse changed the run"
    );
    // The store's file is the same whichever process wrote it.
    assert_eq!(store("two").len(), 1);
    assert_eq!(std::fs::read(&store("two")[0]).unwrap(), stored);
    assert!(
        files(&d.join("two/public"))
            .keys()
            .all(|k| !k.starts_with("psf"))
    );

    // Damaged, then foreign (another spec's digest in its header): each is
    // rebuilt with one line saying why, rewritten, and the run is the same.
    let file = store("two")[0].clone();
    let mut foreign = stored.clone();
    let at = header.len();
    foreign[at] = if foreign[at] == b'0' { b'1' } else { b'0' };
    for (bad, why) in [
        (stored[..stored.len() - 100].to_vec(), "is truncated"),
        (foreign, "was made for another PSF spec"),
    ] {
        std::fs::write(&file, bad).unwrap();
        std::fs::remove_dir_all(d.join("two/private/done")).unwrap();
        let o = generate(d, "two", &[]);
        let err = stderr(&o);
        let line = err
            .lines()
            .find(|l| l.contains("rebuilt PSF 1/1 (coma)"))
            .unwrap_or_else(|| panic!("no rebuild line in {err}"));
        assert!(
            line.contains(why) && line.contains("stored again"),
            "{line}"
        );
        assert_eq!(err.matches("PSF 1/1").count(), 1, "{err}");
        assert_eq!(std::fs::read(&file).unwrap(), stored);
        assert!(release(&d.join("one")) == release(&d.join("two")));
    }
}

#[test]
fn a_run_that_fits_only_before_its_psfs_are_solved_is_refused_before_any_image() {
    // Before solving, the PSF file is counted at 128 px; solved, it is
    // the renderer's side (several times that) and its store file is
    // counted too: a disk between the two refuses after the solve, before
    // any image, keeping the solved PSF for the next attempt.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("c.json"), OPTICAL).unwrap();
    let plan = stepsim_sim::Plan::load(&d.join("c.json"), &[]).unwrap();
    let before = stepsim_sim::run::disk::generate_estimate(&plan, None).total_bytes();
    let limit = (before + (1 << 20)).to_string();
    let args = ["generate", "--config", "c.json", "--out", "r"];
    let o = run_env(&args, d, &[("STEPSIM_DISK_LIMIT_BYTES", &limit)]);
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    assert!(
        err.contains("stepsim: built PSF 1/1 (coma), stored in "),
        "{err}"
    );
    assert!(err.contains("1 PSF file ("), "{err}");
    assert!(
        err.contains("the solved PSFs (private/psf/cache/): "),
        "{err}"
    );
    assert!(
        err.contains("kept in private/psf/cache/ for the next attempt"),
        "{err}"
    );
    assert!(!err.contains("until solved"), "{err}");
    assert!(
        files(&d.join("r/public"))
            .keys()
            .all(|k| !k.to_string_lossy().ends_with(".fits")),
        "an image was written"
    );
    // With the space, the next attempt reuses the solved PSF.
    let o = generate(d, "r", &[]);
    let err = stderr(&o);
    assert!(
        err.contains("stepsim: reused PSF 1/1 (coma) from "),
        "{err}"
    );
    assert!(manifest(&d.join("r"))["images"].as_array().unwrap().len() == 2);
}

#[test]
fn a_new_run_copies_the_psf_another_run_built_from_the_users_store() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("c.json"), OPTICAL).unwrap();
    let user = d.join("user-store");
    let env = [("STEPSIM_PSF_STORE", user.to_str().unwrap())];
    let gen_ = |out: &str| {
        let o = run_env(&["generate", "--config", "c.json", "--out", out], d, &env);
        assert!(o.status.success(), "{}", stderr(&o));
        stderr(&o)
    };
    // The first run builds the PSF and stores it in its run and the user's store.
    let err = gen_("first");
    assert!(
        err.contains("stepsim: built PSF 1/1 (coma), stored in "),
        "{err}"
    );
    // It keeps the solved PSF, the drawn PSF file (`.fits.bin`) and the
    // PSF's transfers on the image convolution's tile grids (`.t.bin`).
    let (drawn, rest): (Vec<PathBuf>, Vec<PathBuf>) = std::fs::read_dir(&user)
        .unwrap()
        .map(|e| e.unwrap().path())
        .partition(|p| p.to_string_lossy().ends_with(".fits.bin"));
    let (transfers, shared): (Vec<PathBuf>, Vec<PathBuf>) = rest
        .into_iter()
        .partition(|p| p.to_string_lossy().ends_with(".t.bin"));
    assert_eq!((shared.len(), drawn.len()), (1, 1), "{shared:?} {drawn:?}");
    assert!(
        (1..=3).contains(&transfers.len()),
        "{transfers:?}: a transfer per tile grid"
    );
    let run_copy = d
        .join("first/private/psf/cache")
        .join(shared[0].file_name().unwrap());
    assert_eq!(
        std::fs::read(&shared[0]).unwrap(),
        std::fs::read(&run_copy).unwrap()
    );
    // A second run, elsewhere, builds nothing: it copies the PSF into its own
    // store, and its release is the first's byte for byte.
    let err = gen_("second");
    assert!(
        err.contains("stepsim: reused PSF 1/1 (coma) from the user's store "),
        "{err}"
    );
    assert!(!err.contains("built PSF"), "{err}");
    let copy = d
        .join("second/private/psf/cache")
        .join(shared[0].file_name().unwrap());
    assert_eq!(
        std::fs::read(&copy).unwrap(),
        std::fs::read(&shared[0]).unwrap()
    );
    assert!(release(&d.join("first")) == release(&d.join("second")));
    // Its PSF file was copied from the user's store, not drawn: the first
    // run's byte for byte.
    let psf_file = |run: &str| std::fs::read(d.join(run).join("private/psf/coma.fits")).unwrap();
    assert_eq!(psf_file("first"), psf_file("second"));
    let stored = std::fs::read(&drawn[0]).unwrap();
    assert!(stored.ends_with(&psf_file("first")));
    // A damaged file in the user's store is not trusted: the PSF is built
    // again, the file rewritten, the release the same.
    let good = std::fs::read(&shared[0]).unwrap();
    std::fs::write(&shared[0], &good[..good.len() / 3]).unwrap();
    let err = gen_("third");
    assert!(
        err.contains("stepsim: built PSF 1/1 (coma), stored in "),
        "{err}"
    );
    assert_eq!(std::fs::read(&shared[0]).unwrap(), good);
    assert!(release(&d.join("first")) == release(&d.join("third")));
    // Turned off, the user's store is not read (its good file is there,
    // and the PSF is built all the same) nor written (the file is as it was).
    let before = std::fs::metadata(&shared[0]).unwrap().modified().unwrap();
    let o = run_env(
        &["generate", "--config", "c.json", "--out", "fourth"],
        d,
        &[("STEPSIM_PSF_STORE", "off")],
    );
    assert!(
        stderr(&o).contains("built PSF 1/1 (coma), stored in "),
        "{}",
        stderr(&o)
    );
    assert!(!stderr(&o).contains("user's store"), "{}", stderr(&o));
    assert_eq!(
        std::fs::read_dir(&user).unwrap().count(),
        2 + transfers.len()
    );
    assert_eq!(
        std::fs::metadata(&shared[0]).unwrap().modified().unwrap(),
        before
    );
    // And its PSF file was drawn, the same as the copies.
    assert_eq!(psf_file("first"), psf_file("fourth"));
}

#[test]
fn huge_pages_and_the_block_cache_on_and_off_write_identical_bytes() {
    // 2048² images: the canvas, model and FITS buffers are 16 MiB, so the
    // allocator advises them when asked (src/huge_pages.rs; "1" here), and
    // `measure` keeps them
    // for the next image (src/block_cache.rs); the bytes must not care.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let config = r#"{
      "run": {"seed": 424242},
      "image": {"width_px": 2048, "height_px": 2048, "n_images": 2},
      "psfs": [{"name": "p", "model": "moffat", "beta": 3.5, "fwhm_arcsec": 0.85}],
      "shears": [{"g1": 0.02, "g2": -0.01}]
    }"#;
    std::fs::write(d.join("c.json"), config).unwrap();
    for (out, value) in [("on", "1"), ("off", "0")] {
        let env = [
            ("STEPSIM_HUGE_PAGES", value),
            ("STEPSIM_BLOCK_CACHE", value),
        ];
        let o = common::run_env(&["generate", "--config", "c.json", "--out", out], d, &env);
        assert!(o.status.success(), "{out}: {}", stderr(&o));
        let sub = format!("{out}.txt");
        let args = [
            "measure",
            "--run",
            "on/public",
            "--out",
            &sub,
            "--threads",
            "2",
        ];
        let o = common::run_env(&args, d, &env);
        assert!(o.status.success(), "{out}: {}", stderr(&o));
    }
    let (on, off) = (release(&d.join("on")), release(&d.join("off")));
    // Two images: each with its truth table and sidecar, and five shared files.
    assert_eq!(on.len(), 2 * 3 + 5, "{:?}", on.keys().collect::<Vec<_>>());
    assert_eq!(on, off);
    let (a, b) = (
        std::fs::read(d.join("on.txt")).unwrap(),
        std::fs::read(d.join("off.txt")).unwrap(),
    );
    assert!(a.len() > 10_000 && a == b, "the submissions differ");
}

/// A Gaussian PSF image of σ = 0.2″ sampled at 0.05″ (49²), as a FITS file.
fn write_gaussian_psf(path: &Path) {
    let n = 49;
    let mut v = vec![0.0; n * n];
    for j in 0..n {
        for i in 0..n {
            let (x, y) = ((i as f64 - 24.0) * 0.05, (j as f64 - 24.0) * 0.05);
            v[j * n + i] = (-(x * x + y * y) / (2.0 * 0.2f64.powi(2))).exp();
        }
    }
    let image = stepsim_sim::io::psf_fits::PsfImage {
        data: &v,
        n,
        scale_arcsec: 0.05,
    };
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    stepsim_sim::io::psf_fits::write_psf_fits(path, "g", image, image, 1, &[]).unwrap();
}

#[test]
fn the_private_config_reproduces_a_run_with_relative_inputs_from_anywhere() {
    // Issue #23: a config naming a SkyMaker list and a FITS PSF by paths
    // relative to itself. Its private copy lives in RUN/private, where those
    // paths led nowhere ("looking for run/private/first/field_000.list"), so
    // the documented reproduction failed.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cfg = d.join("cfg");
    std::fs::create_dir_all(&cfg).unwrap();
    std::fs::write(
        cfg.join("base.json"),
        r#"{"run": {"seed": 5}, "image": {"width_px": 64, "height_px": 48, "n_images": 2, "margin_arcsec": 1.0},
            "population": {"galaxies": {"mag_faint": 23.5}}}"#,
    )
    .unwrap();
    common::run_ok(
        &["catalog", "--config", "cfg/base.json", "--out", "cfg/first"],
        d,
    );
    write_gaussian_psf(&cfg.join("psfs/g.fits"));
    std::fs::write(
        cfg.join("c.json"),
        r#"{
  "run": {"seed": 424242},
  "image": {"width_px": 64, "height_px": 48, "n_images": 2, "margin_arcsec": 1.0},
  "population": {"source": {"skymaker_list": {"path": "first/field_00{field}.list"}}},
  "psfs": [
    {"name": "file", "model": "fits", "path": "psfs/g.fits", "pixel_scale_arcsec": 0.05},
    {"name": "gauss", "model": "gaussian", "fwhm_arcsec": 0.8}
  ],
  "shears": [{"g1": 0.0}, {"g1": 0.04, "g2": 0.01}]
}"#,
    )
    .unwrap();
    common::run_ok(&["generate", "--config", "cfg/c.json", "--out", "run"], d);
    // Reproduced from another working directory, into another directory:
    // the same bytes in public/ and private/ (PSF store aside).
    let elsewhere = d.join("elsewhere/deeper");
    std::fs::create_dir_all(&elsewhere).unwrap();
    common::run_ok(
        &[
            "generate",
            "--config",
            "../../run/private/config.json",
            "--out",
            "../run2",
        ],
        &elsewhere,
    );
    let (a, b) = (release(&d.join("run")), release(&d.join("elsewhere/run2")));
    // public: 8 images, README, manifest; private: config, datasets, key,
    // 8 truth tables, 8 sidecars, 3 copies of inputs.
    assert_eq!(a.len(), 8 + 2 + 3 + 8 * 2 + 3, "{:?}", a.keys());
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (k, v) in &a {
        assert!(b[k] == *v, "{} differs", k.display());
    }
    // The private config names the run's copies, relative to itself; the
    // copies are the inputs' bytes.
    let private = d.join("run/private");
    let config: serde_json::Value =
        serde_json::from_slice(&std::fs::read(private.join("config.json")).unwrap()).unwrap();
    assert_eq!(
        config["population"]["source"]["skymaker_list"]["path"],
        "inputs/list_{field}.list"
    );
    assert_eq!(config["psfs"][0]["path"], "inputs/psf_0.fits");
    for (copy, input) in [
        ("inputs/list_0.list", "cfg/first/field_000.list"),
        ("inputs/list_1.list", "cfg/first/field_001.list"),
        ("inputs/psf_0.fits", "cfg/psfs/g.fits"),
    ] {
        assert!(
            std::fs::read(private.join(copy)).unwrap() == std::fs::read(d.join(input)).unwrap(),
            "{copy}"
        );
    }
    // The original inputs moved away: the run is continued from its private
    // config alone, and from the original config the run is refused when an
    // input's bytes changed since (the copy pins them).
    std::fs::rename(&cfg, d.join("gone")).unwrap();
    let o = common::run_ok(
        &[
            "generate",
            "--config",
            "run/private/config.json",
            "--out",
            "run",
        ],
        d,
    );
    assert!(
        stderr(&o).contains("0 images written, 8 already"),
        "{}",
        stderr(&o)
    );
    std::fs::rename(d.join("gone"), &cfg).unwrap();
    let list = cfg.join("first/field_001.list");
    let mut text = std::fs::read_to_string(&list).unwrap();
    text.push_str("# one more line\n");
    std::fs::write(&list, text).unwrap();
    let o = run(&["generate", "--config", "cfg/c.json", "--out", "run"], d);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains("inputs/list_1.list")
            && e.contains("field_001.list")
            && e.contains("other bytes"),
        "{e}"
    );
}
