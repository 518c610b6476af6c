//! End-to-end checks of `stepsim catalog`: outputs, reproducibility,
//! refusals.

use std::path::{Path, PathBuf};
use std::process::Output;
use stepsim_contract::io::truth;
use stepsim_sim::io::skymaker;

use crate::common;
use common::{run_with, stepsim};

/// `stepsim catalog --config CFG --out OUT ARGS`.
fn catalog(args: &[&str], cfg: &Path, out: &Path) -> Output {
    run_with(
        stepsim()
            .arg("catalog")
            .arg("--config")
            .arg(cfg)
            .arg("--out")
            .arg(out)
            .args(args),
    )
}

fn mini() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/step1-mini.json")
}

fn files(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn mini_preset_writes_truth_tables_and_lists() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cat");
    let o = catalog(&[], &mini(), &out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        files(&out),
        [
            "config.json",
            "field_000.csv",
            "field_000.fits",
            "field_000.list",
            "field_001.csv",
            "field_001.fits",
            "field_001.list"
        ]
    );
    let cfg: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("config.json")).unwrap()).unwrap();
    assert_eq!(cfg["image"]["width_px"], 1024);
    assert_eq!(cfg["population"]["galaxies"]["mag_faint"], 26.0);
    for f in 0..2 {
        let rows = truth::read_truth_fits(&out.join(format!("field_{f:03}.fits"))).unwrap();
        // 1024² of 0.206″ plus 10″ margins ≈ 14.4 arcmin²: ~2600 galaxies
        // (≈ 180 per arcmin² to I = 26) and ~140 stars.
        let stars = rows.iter().filter(|r| r.is_star()).count();
        let gals = rows.len() - stars;
        assert!((2000..3300).contains(&gals), "{gals} galaxies");
        assert!((90..200).contains(&stars), "{stars} stars");
        assert!(rows.iter().all(|r| r.g1 == 0.0 && r.g2 == 0.0));
        let list = skymaker::read_list(&out.join(format!("field_{f:03}.list"))).unwrap();
        assert_eq!(list.len(), rows.len());
        let csv = std::fs::read_to_string(out.join(format!("field_{f:03}.csv"))).unwrap();
        assert_eq!(csv.lines().count(), rows.len() + 1);
    }
}

#[test]
fn same_seed_same_bytes_other_seed_other_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b, c) = (
        dir.path().join("a"),
        dir.path().join("b"),
        dir.path().join("c"),
    );
    for (out, extra) in [
        (&a, vec!["--set", "run.seed=20060101"]),
        (&b, vec!["--set", "run.seed=20060101"]),
        (&c, vec!["--set", "run.seed=5"]),
    ] {
        let o = catalog(&extra, &mini(), out);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    for name in files(&a) {
        let (x, y, z) = (
            std::fs::read(a.join(&name)).unwrap(),
            std::fs::read(b.join(&name)).unwrap(),
            std::fs::read(c.join(&name)).unwrap(),
        );
        assert!(x == y, "{name} differs between identical runs");
        if name != "config.json" {
            assert!(x != z, "{name} identical for different seeds");
        }
    }
}

#[test]
fn without_a_seed_each_run_draws_one_and_records_it() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b, c) = (
        dir.path().join("a"),
        dir.path().join("b"),
        dir.path().join("c"),
    );
    let one = ["--set", "image.n_images=1"];
    for out in [&a, &b] {
        let o = catalog(&one, &mini(), out);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success() && e.contains("drew one"), "{e}");
    }
    let field = |d: &Path| std::fs::read(d.join("field_000.fits")).unwrap();
    assert!(field(&a) != field(&b), "two draws, two populations");
    // The recorded seed reproduces the fields.
    let cfg: serde_json::Value =
        serde_json::from_slice(&std::fs::read(a.join("config.json")).unwrap()).unwrap();
    assert!(cfg["run"]["seed"].is_u64());
    let o = catalog(&[], &a.join("config.json"), &c);
    assert!(o.status.success());
    assert!(field(&a) == field(&c));
}

#[test]
fn rotated_pairs_write_twins() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cat");
    let o = catalog(
        &[
            "--set",
            "population.rotated_pairs=true",
            "--set",
            "image.n_images=1",
        ],
        &mini(),
        &out,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let a = truth::read_truth_fits(&out.join("field_000.fits")).unwrap();
    let b = truth::read_truth_fits(&out.join("field_000_rot.fits")).unwrap();
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!((x.id, x.x, x.y, x.mag), (y.id, y.x, y.y, y.mag));
        assert!((x.e1_int + y.e1_int).abs() < 1e-12 && (x.e2_int + y.e2_int).abs() < 1e-12);
    }
    assert!(out.join("field_000_rot.list").exists() && out.join("field_000_rot.csv").exists());
}

#[test]
fn skymaker_lists_are_read_back_as_the_source() {
    let dir = tempfile::tempdir().unwrap();
    let first = dir.path().join("first");
    assert!(catalog(&[], &mini(), &first).status.success());
    let cfg = dir.path().join("list.json");
    std::fs::write(
        &cfg,
        r#"{"image": {"width_px": 1024, "height_px": 1024, "n_images": 2},
            "population": {"source": {"skymaker_list": {"path": "first/field_{field:03}.list"}}}}"#
            .replace("{field:03}", "00{field}"),
    )
    .unwrap();
    let second = dir.path().join("second");
    let o = catalog(&[], &cfg, &second);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in ["field_000.list", "field_001.list"] {
        assert_eq!(
            std::fs::read(first.join(f)).unwrap(),
            std::fs::read(second.join(f)).unwrap(),
            "{f}"
        );
    }
}

#[test]
fn bad_configs_exit_1_naming_the_problem_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "unknown.json",
            r#"{"population": {"galaxies": {"mag_faintt": 25}}}"#,
            "population.galaxies.mag_faintt",
        ),
        (
            "malformed.json",
            "{\n\"population\": {\n\"rotated_pairs\": true,,\n}}",
            "line 3",
        ),
        (
            "negative.json",
            r#"{"population": {"galaxies": {"sizes": {"disk_re_star_kpc_h": -3.85}}}}"#,
            "population.galaxies.sizes.disk_re_star_kpc_h",
        ),
        (
            "emptyq.json",
            r#"{"population": {"galaxies": {"flattening": {"min": 0.9, "max": 0.4}}}}"#,
            "population.galaxies.flattening",
        ),
        (
            "types.json",
            r#"{"population": {"galaxies": {"types": []}}}"#,
            "population.galaxies.types",
        ),
        (
            "list.json",
            r#"{"population": {"source": {"skymaker_list": {"path": "bad.list"}}}}"#,
            "line 2",
        ),
        (
            "huge.json",
            r#"{"image": {"width_px": 65536, "height_px": 65536}}"#,
            "population.galaxies.mag_faint",
        ),
    ];
    std::fs::write(dir.path().join("bad.list"), "100 1 2 20\n200 1 2 22 0.5\n").unwrap();
    for (name, text, needle) in cases {
        let cfg = dir.path().join(name);
        std::fs::write(&cfg, text).unwrap();
        let out = dir.path().join(format!("out-{name}"));
        let o = catalog(&[], &cfg, &out);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{name}: {err}");
        assert!(err.contains(needle), "{name}: expected {needle:?} in {err}");
        assert!(!out.exists(), "{name}: output directory was created");
    }
    // A bad --set override is refused the same way.
    let out = dir.path().join("out-set");
    let o = catalog(&["--set", "population.stars.slope=x"], &mini(), &out);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("population.stars.slope"));
    assert!(!out.exists());
}
