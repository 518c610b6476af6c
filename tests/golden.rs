//! Golden outputs: what pins the bytes of a release.
//!
//! * `tests/data/golden/draws.txt`: the first draws of every distribution the
//!   simulator samples, from fixed seed keys. An update of `rand`,
//!   `rand_distr` or `rand_xoshiro` that changes a sampler changes every
//!   release made with a given seed; this file says so at once.
//! * `tests/data/golden/run.txt`: the SHA-256 of every file of a small run
//!   (`tests/data/golden/config.json`: an optical and a Moffat PSF, two
//!   shears, two base fields with their rotated twins) — images, truth
//!   tables, PSF files, manifest and datasets.
//!
//! When a change alters output on purpose, re-bless with
//! `STEPSIM_BLESS=1 cargo test --test integration golden::` and say so in
//! CHANGELOG.md; never re-bless to make a failure go away without knowing
//! why.

use rand::RngExt;
use rand_distr::{Distribution, Normal, Poisson, StandardNormal};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use stepsim_contract::seed::{SeedKey, Stream};

use crate::common;
use common::files;

fn golden(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/golden")
        .join(name)
}

/// Compares `actual` with the golden file, or rewrites it under
/// `STEPSIM_BLESS=1`.
fn check(name: &str, actual: &str) {
    let path = golden(name);
    if std::env::var_os("STEPSIM_BLESS").is_some() {
        std::fs::write(&path, actual).unwrap();
        eprintln!("blessed {}", path.display());
        return;
    }
    let want = std::fs::read_to_string(&path).unwrap_or_default();
    if want != actual {
        let diff: Vec<String> = want
            .lines()
            .zip(actual.lines())
            .filter(|(a, b)| a != b)
            .take(8)
            .map(|(a, b)| format!("  golden: {a}\n  now:    {b}"))
            .collect();
        panic!(
            "{} differs from what the code makes now ({} vs {} lines):\n{}\n\
             If the change is deliberate, re-bless with STEPSIM_BLESS=1 and add a CHANGELOG line.",
            path.display(),
            want.lines().count(),
            actual.lines().count(),
            diff.join("\n")
        );
    }
}

#[test]
fn first_draws_of_every_distribution_are_pinned() {
    let key = |i: u64| SeedKey::image(20261201, 3, 7, Stream::Test).with_index(i);
    let mut out = String::new();
    let mut line = |name: &str, values: Vec<String>| {
        out.push_str(&format!("{name} {}\n", values.join(" ")));
    };
    line("seed", (0..4).map(|i| key(i).seed().to_string()).collect());
    let mut rng = key(0).rng();
    line(
        "u64",
        (0..4).map(|_| rng.random::<u64>().to_string()).collect(),
    );
    let mut rng = key(1).rng();
    line(
        "f64",
        (0..4)
            .map(|_| format!("{:?}", rng.random::<f64>()))
            .collect(),
    );
    let mut rng = key(2).rng();
    line(
        "range",
        (0..4)
            .map(|_| format!("{:?}", rng.random_range(-2.5..7.0)))
            .collect(),
    );
    let mut rng = key(3).rng();
    line(
        "standard_normal",
        (0..4)
            .map(|_| format!("{:?}", rng.sample::<f64, _>(StandardNormal)))
            .collect(),
    );
    let mut rng = key(4).rng();
    let normal = Normal::new(1.5, 5.0).unwrap();
    line(
        "normal",
        (0..4)
            .map(|_| format!("{:?}", normal.sample(&mut rng)))
            .collect(),
    );
    // Poisson at a faint pixel, a STEP1 sky level and a bright core.
    for lambda in [0.7, 12.0, 80_000.0, 3.0e6] {
        let mut rng = key(5).rng();
        let p = Poisson::new(lambda).unwrap();
        line(
            &format!("poisson({lambda})"),
            (0..4)
                .map(|_| format!("{:?}", p.sample(&mut rng)))
                .collect(),
        );
    }
    check("draws.txt", &out);
}

/// SHA-256 of the files of the golden run that matter (images, truth
/// tables, PSF files, manifest, datasets), made with `envs` set.
fn golden_run_hashes(envs: &[(&str, &str)]) -> String {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let mut cmd = common::stepsim();
    cmd.arg("generate")
        .arg("--config")
        .arg(golden("config.json"))
        .arg("--out")
        .arg(&run)
        .args(["--threads", "2"]);
    for (k, v) in envs {
        cmd.env(k, v);
    }
    common::ok(common::run_with(&mut cmd));
    let hashes: BTreeMap<String, String> = files(&run)
        .into_iter()
        .map(|(rel, bytes)| {
            (
                rel.to_string_lossy().into_owned(),
                stepsim_contract::digest::sha256_hex(&bytes),
            )
        })
        .collect();
    // What the run writes about itself (sidecars, the resolved config, the
    // key) follows from the rest; the bytes that matter are listed.
    hashes
        .iter()
        .filter(|(rel, _)| {
            rel.ends_with(".fits")
                || rel.ends_with("manifest.json")
                || rel.ends_with("datasets.json")
        })
        .map(|(rel, h)| format!("{h}  {rel}\n"))
        .collect()
}

#[test]
fn a_small_run_has_the_pinned_bytes() {
    let text = golden_run_hashes(&[]);
    assert!(
        text.lines().count() >= 2 * 2 * 2 * 2 * 2,
        "images and truth of 16 images"
    );
    check("run.txt", &text);
}

#[test]
fn the_plain_build_writes_the_same_bytes_as_the_vector_build() {
    // `STEPSIM_SIMD=0` runs the plain x86-64 build of every hot loop (the
    // stamps' Fourier grids and FFTs, the image convolution, the adding of
    // stamps, the noise) where the CPU would run the AVX2 build: a CPU
    // without AVX2 must write the same bytes (issue #25's rule). On a CPU
    // without AVX2 both runs take the plain build and the test still holds.
    let vector = golden_run_hashes(&[]);
    let plain = golden_run_hashes(&[("STEPSIM_SIMD", "0")]);
    assert!(vector.lines().count() >= 32);
    let differ: Vec<_> = vector
        .lines()
        .zip(plain.lines())
        .filter(|(a, b)| a != b)
        .map(|(a, _)| a.to_string())
        .collect();
    assert!(differ.is_empty(), "files that differ: {differ:?}");
}
