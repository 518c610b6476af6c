//! `generate` with a `challenge` section: held-out base fields (with their
//! twins) appear only in datasets of their own, with drawn shears recorded
//! only in private/; public/ has the same shape as an ordinary run.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::Output;
use stepsim_contract::run_layout::Part;
use stepsim_sim::{Plan, holdout_fields, holdout_shear};

use crate::common;

fn stepsim(args: &[&str], dir: &Path) -> Output {
    common::run(args, dir)
}

/// 2 Gaussian PSFs × 2 shears on `n_images` tiny base fields.
fn config(n_images: u32, challenge: &str) -> String {
    format!(
        r#"{{
  "run": {{"seed": 2718}},
  "image": {{"width_px": 32, "height_px": 32, "n_images": {n_images}, "margin_arcsec": 1.0}},
  "population": {{"galaxies": {{"mag_faint": 23.0}}, "rotated_pairs": true}},
  "psfs": [{{"name": "a", "model": "gaussian", "fwhm_arcsec": 0.7}},
           {{"name": "b", "model": "gaussian", "fwhm_arcsec": 0.9}}],
  "shears": [{{"g1": 0.0}}, {{"g1": 0.05}}]{challenge}
}}"#
    )
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

/// FITS header keywords of a file's first HDU (names only, in order).
fn header_keys(path: &Path) -> Vec<String> {
    let bytes = std::fs::read(path).unwrap();
    let mut keys = Vec::new();
    for card in bytes.chunks(80) {
        let name = String::from_utf8_lossy(&card[..8]).trim().to_string();
        if name == "END" {
            break;
        }
        keys.push(name);
    }
    keys
}

#[test]
fn held_out_fields_get_datasets_and_shears_of_their_own() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let challenge = r#", "challenge": {"holdout_fields": 2, "holdout_g_max": 0.08}"#;
    std::fs::write(d.join("c.json"), config(4, challenge)).unwrap();
    let o = stepsim(&["generate", "--config", "c.json", "--out", "run"], d);
    assert!(o.status.success());
    let datasets = json(&d.join("run/private/datasets.json"));
    let datasets = datasets["datasets"].as_array().unwrap();
    assert_eq!(datasets.len(), 8, "2 PSFs × 2 shears, public and held out");
    let mut fields: BTreeMap<&str, BTreeSet<u64>> = BTreeMap::new();
    let mut held_shears = Vec::new();
    for (i, ds) in datasets.iter().enumerate() {
        let part = ds.get("part").and_then(|p| p.as_str()).unwrap_or("public");
        assert_eq!(part, if i < 4 { "public" } else { "holdout" }, "{ds}");
        let f: BTreeSet<u64> = ds["images"]
            .as_array()
            .unwrap()
            .iter()
            .map(|im| im["field"].as_u64().unwrap())
            .collect();
        assert_eq!(f.len(), 2, "two base fields per dataset");
        assert_eq!(ds["images"].as_array().unwrap().len(), 4, "with twins");
        let prev = fields.insert(part, f.clone());
        assert!(prev.is_none() || prev == Some(f), "one field set per part");
        let (g1, g2) = (ds["g1"].as_f64().unwrap(), ds["g2"].as_f64().unwrap());
        if i < 4 {
            assert_eq!((g1, g2), ([0.0, 0.05][i % 2], 0.0));
        } else {
            assert!(g1.hypot(g2) <= 0.08, "{g1} {g2}");
            held_shears.push((g1.to_bits(), g2.to_bits()));
        }
    }
    let (public, held) = (&fields["public"], &fields["holdout"]);
    assert!(public.is_disjoint(held));
    assert_eq!(public.union(held).count(), 4);
    held_shears.sort_unstable();
    held_shears.dedup();
    assert_eq!(held_shears.len(), 4, "each held-out dataset draws its own");
    // Truth headers carry the drawn shear.
    let manifest = json(&d.join("run/public/manifest.json"));
    let images = manifest["images"].as_array().unwrap();
    assert_eq!(images.len(), 32);
    // Public: every dataset holds as many images, every image has the same
    // size and the same header keywords; the README and the manifest say
    // nothing of a challenge.
    let mut per_dataset: BTreeMap<&str, usize> = BTreeMap::new();
    let mut sizes = BTreeSet::new();
    let mut keys = BTreeSet::new();
    for im in images {
        *per_dataset
            .entry(im["dataset"].as_str().unwrap())
            .or_default() += 1;
        let p = d.join("run/public").join(im["file"].as_str().unwrap());
        sizes.insert(std::fs::metadata(&p).unwrap().len());
        keys.insert(header_keys(&p));
    }
    assert_eq!(per_dataset.len(), 8);
    assert!(per_dataset.values().all(|&n| n == 4), "{per_dataset:?}");
    assert_eq!((sizes.len(), keys.len()), (1, 1));
    let public_text = [
        std::fs::read_to_string(d.join("run/public/README.md")).unwrap(),
        serde_json::to_string(&manifest).unwrap(),
    ]
    .concat()
    .to_lowercase();
    for word in ["held", "holdout", "\"part\""] {
        assert!(!public_text.contains(word), "public/ mentions {word:?}");
    }
    // A second run of the same config writes the same private split.
    let o = stepsim(&["generate", "--config", "c.json", "--out", "run2"], d);
    assert!(o.status.success());
    assert_eq!(
        std::fs::read(d.join("run/private/datasets.json")).unwrap(),
        std::fs::read(d.join("run2/private/datasets.json")).unwrap()
    );
}

#[test]
fn a_run_without_the_section_keeps_its_files_as_before() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("c.json"), config(2, "")).unwrap();
    let o = stepsim(&["generate", "--config", "c.json", "--out", "run"], d);
    assert!(o.status.success());
    let config = std::fs::read_to_string(d.join("run/private/config.json")).unwrap();
    let datasets = std::fs::read_to_string(d.join("run/private/datasets.json")).unwrap();
    assert!(!config.contains("challenge"), "{config}");
    assert!(!datasets.contains("\"part\""), "{datasets}");
    assert_eq!(
        json(&d.join("run/public/manifest.json"))["images"]
            .as_array()
            .unwrap()
            .len(),
        16
    );
}

#[test]
fn bad_challenge_sections_are_refused_by_key() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (challenge, key, says) in [
        (
            r#", "challenge": {"holdout_fields": 1}"#,
            "challenge.holdout_fields",
            "half of image.n_images (4), got 1",
        ),
        (
            r#", "challenge": {"holdout_fields": 4}"#,
            "challenge.holdout_fields",
            "got 4",
        ),
        (
            r#", "challenge": {"holdout_fields": 2, "holdout_g_max": 1.5}"#,
            "challenge.holdout_g_max",
            "got 1.5",
        ),
        (
            r#", "challenge": {"holdout_fields": 2, "holdout_g_max": 0}"#,
            "challenge.holdout_g_max",
            "got 0",
        ),
        (
            r#", "challenge": {"holdout_field": 2}"#,
            "challenge.holdout_field",
            "unknown field",
        ),
        (
            r#", "challenge": [2, 0.1]"#,
            "challenge",
            "expected a JSON object",
        ),
        (
            r#", "challenge": {"holdout_fields": -2}"#,
            "challenge.holdout_fields",
            "invalid value",
        ),
    ] {
        std::fs::write(d.join("c.json"), config(4, challenge)).unwrap();
        let o = stepsim(&["generate", "--config", "c.json", "--out", "run"], d);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{challenge}: {err}");
        assert!(err.contains(&format!("`{key}`")), "{challenge}: {err}");
        assert!(err.contains(says), "{challenge}: {err}");
        assert!(!d.join("run").exists(), "{challenge}: nothing written");
    }
}

#[test]
fn held_out_shears_fill_the_disc_uniformly() {
    // Uniform in the disc: |g| ≤ g_max, ⟨|g|²⟩ = g_max²/2, ⟨g⟩ = 0, and
    // a quarter of the draws inside radius g_max/2.
    let n = 20_000;
    let g_max = 0.1;
    let draws: Vec<(f64, f64)> = (0..n).map(|i| holdout_shear(77, i, g_max)).collect();
    assert!(draws.iter().all(|(a, b)| a.hypot(*b) <= g_max));
    let r2 = draws.iter().map(|(a, b)| a * a + b * b).sum::<f64>() / f64::from(n);
    assert!((r2 / (g_max * g_max) - 0.5).abs() < 0.01, "{r2}");
    let inner = draws
        .iter()
        .filter(|(a, b)| a.hypot(*b) < g_max / 2.0)
        .count();
    assert!((inner as f64 / f64::from(n) - 0.25).abs() < 0.01, "{inner}");
    let m1 = draws.iter().map(|d| d.0).sum::<f64>() / f64::from(n);
    let m2 = draws.iter().map(|d| d.1).sum::<f64>() / f64::from(n);
    assert!(m1.abs() < 0.002 && m2.abs() < 0.002, "{m1} {m2}");
    // Keyed: the same (seed, index) gives the same shear, another seed not.
    assert_eq!(holdout_shear(77, 5, g_max), draws[5]);
    assert_ne!(holdout_shear(78, 5, g_max), draws[5]);
}

#[test]
fn held_out_fields_are_chosen_by_key_not_by_position() {
    // Over many seeds every field is held out about half of the time,
    // and the choice depends on the seed.
    let mut count = [0u32; 8];
    for seed in 0..400 {
        let held = holdout_fields(seed, 8, 4);
        assert_eq!(held.len(), 4);
        assert!(held.windows(2).all(|w| w[0] < w[1]));
        for f in held {
            count[f as usize] += 1;
        }
    }
    assert!(count.iter().all(|&c| (150..250).contains(&c)), "{count:?}");
    assert_ne!(holdout_fields(1, 8, 4), holdout_fields(2, 8, 4));
}

#[test]
fn a_plan_splits_fields_and_adopting_a_seed_redraws_the_split() {
    let json =
        r#"{"image": {"n_images": 6}, "challenge": {"holdout_fields": 3}, "run": {"seed": 5}}"#;
    let plan = Plan::from_json(json, Path::new("t.json"), &[]).unwrap();
    assert_eq!(plan.datasets().len(), 60);
    assert_eq!(plan.n_images_in_run(), 60 * 3, "no twins by default");
    let held = &plan.datasets()[30];
    assert_eq!(
        (held.part, held.index, held.psf, held.shear),
        (Part::Holdout, 30, 0, 0)
    );
    assert_eq!(held.fields, holdout_fields(5, 6, 3));
    assert_eq!((held.g1, held.g2), holdout_shear(5, 30, 0.1));
    assert!(
        plan.datasets()[..30]
            .iter()
            .all(|d| d.part == Part::Public && d.fields.len() == 3)
    );
    let other = plan.with_seed(6);
    assert_eq!(other.datasets()[30].fields, holdout_fields(6, 6, 3));
    assert_eq!(
        (other.datasets()[30].g1, other.datasets()[30].g2),
        holdout_shear(6, 30, 0.1)
    );
}
