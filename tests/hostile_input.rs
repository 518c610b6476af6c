//! Hostile and absurd input to the simulator's commands: each is refused
//! with a sentence naming the key, file or value (exit 1; usage errors
//! exit 2), writes nothing, and never panics or aborts.

use std::path::Path;
use std::process::{Command, Output};

/// 1 Gaussian PSF × 2 shears × 2 images of 256², enough objects to measure.
const TINY: &str = r#"{
  "run": {"seed": 99},
  "image": {"width_px": 256, "height_px": 256, "n_images": 2, "margin_arcsec": 2.0},
  "psfs": [{"name": "g", "model": "gaussian"}],
  "shears": [{"g1": 0.0}, {"g1": 0.05}],
  "population": {"galaxies": {"mag_faint": 24.0}}
}"#;

fn stepsim(args: &[&str], dir: &Path, env: &[(&str, &str)]) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_stepsim"));
    c.args(args).current_dir(dir).env("CI", "1");
    for (k, v) in env {
        c.env(k, v);
    }
    let out = c.output().unwrap();
    eprintln!("{}", String::from_utf8_lossy(&out.stderr));
    out
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Names of the entries of `dir`, sorted.
fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn configs_that_are_not_objects_are_refused_with_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "array.json",
            "[{}, {}, {}]",
            "the config (line 1): expected a JSON object {...}, found an array",
        ),
        (
            "nested.json",
            "{\n  \"image\": [64, 64, 0.2, 1]\n}",
            "key `image` (line 2): expected a JSON object {...}, found an array",
        ),
        (
            "psf.json",
            "{\"psfs\": [[\"g\", \"gaussian\"]]}",
            "key `psfs.0`: expected a JSON object {...}, found an array",
        ),
        (
            "number.json",
            "7",
            "the config (line 1): expected a JSON object {...}, found a number",
        ),
    ];
    for (name, text, needle) in cases {
        std::fs::write(dir.path().join(name), text).unwrap();
        let o = stepsim(&["config", "--config", name], dir.path(), &[]);
        assert_eq!(o.status.code(), Some(1), "{name}");
        let e = stderr(&o);
        assert!(e.contains(&format!("{name}: {needle}")), "{name}: {e}");
    }
    // An override that turns a section into an array is refused too.
    std::fs::write(dir.path().join("c.json"), TINY).unwrap();
    let o = stepsim(
        &[
            "config",
            "--config",
            "c.json",
            "--set",
            "instrument=[1,2,3]",
        ],
        dir.path(),
        &[],
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("--set: key `instrument`: expected a JSON object"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn absurd_instrument_and_geometry_values_name_key_and_range() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("c.json"), TINY).unwrap();
    let cases = [
        (
            "instrument.exposure_s=1e300",
            "key `instrument.exposure_s`: must be in [0.001, 1000000], got 1e300",
        ),
        (
            "image.pixel_scale_arcsec=1e-9",
            "key `image.pixel_scale_arcsec`: must be in [0.03, 5], got 1e-9",
        ),
        (
            "instrument.gain_e_per_adu=1e-12",
            "key `instrument.gain_e_per_adu`: must be in [0.01, 1000]",
        ),
        (
            "instrument.saturation_adu=1e300",
            "key `instrument.saturation_adu`: must be in [1, 2147483647]",
        ),
        (
            "population.galaxies.mag_faint=39",
            "key `population.galaxies.mag_faint`: must be in [17, 32], got 39",
        ),
        (
            "population.stars.density_per_arcmin2=99999",
            "key `population.stars.density_per_arcmin2`: must be in [0, 10000]",
        ),
        // In range one by one, but the sky alone saturates every pixel.
        (
            "instrument.exposure_s=1e6",
            "key `instrument`: the sky alone gives",
        ),
    ];
    for (set, needle) in cases {
        let o = stepsim(
            &[
                "generate", "--config", "c.json", "--out", "run", "--set", set,
            ],
            dir.path(),
            &[],
        );
        assert_eq!(o.status.code(), Some(1), "{set}");
        let e = stderr(&o);
        assert!(e.contains(needle), "{set}: {e}");
        assert!(!dir.path().join("run").exists(), "{set} wrote a run");
    }
}

#[test]
fn a_run_too_big_for_memory_is_refused_before_anything_is_written() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("c.json"), TINY).unwrap();
    let big = [
        "--set",
        "image.width_px=65536",
        "--set",
        "image.height_px=65536",
        "--set",
        "population.galaxies.mag_faint=19",
    ];
    let limit = [("STEPSIM_MEMORY_LIMIT_BYTES", "8589934592")];
    let mut args = vec![
        "generate",
        "--config",
        "c.json",
        "--out",
        "run",
        "--threads",
        "2",
    ];
    args.extend_from_slice(&big);
    let o = stepsim(&args, dir.path(), &limit);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains("generate needs about ")
            && e.contains("2 images of 65536 × 65536 px in flight")
            && e.contains("only 8.0 GiB is available (STEPSIM_MEMORY_LIMIT_BYTES=8589934592)")
            && e.contains("lower image.width_px"),
        "{e}"
    );
    assert_eq!(listing(dir.path()), ["c.json"]);
    // bench draws one such image: refused as well.
    let mut args = vec![
        "bench",
        "--config",
        "c.json",
        "--psf",
        "g",
        "--repeats",
        "1",
    ];
    args.extend_from_slice(&big);
    let o = stepsim(&args, dir.path(), &limit);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("bench needs about "), "{}", stderr(&o));
    // psf with a huge oversampled image.
    let o = stepsim(
        &[
            "psf",
            "--config",
            "c.json",
            "--out",
            "p",
            "--size-px",
            "4096",
            "--oversample",
            "16",
        ],
        dir.path(),
        &limit,
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("psf needs about "), "{}", stderr(&o));
    assert_eq!(listing(dir.path()), ["c.json"]);
    // A limit that is not a number is refused, not ignored.
    let o = stepsim(
        &["generate", "--config", "c.json", "--out", "run"],
        dir.path(),
        &[("STEPSIM_MEMORY_LIMIT_BYTES", "8G")],
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("STEPSIM_MEMORY_LIMIT_BYTES=8G: not a number of bytes"),
        "{}",
        stderr(&o)
    );
    assert_eq!(listing(dir.path()), ["c.json"]);
}

#[test]
fn thread_counts_beyond_the_documented_range_are_usage_errors() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("c.json"), TINY).unwrap();
    for args in [
        vec![
            "generate",
            "--config",
            "c.json",
            "--out",
            "run",
            "--threads",
            "100000",
        ],
        vec![
            "generate",
            "--config",
            "c.json",
            "--out",
            "run",
            "--threads",
            "1025",
        ],
        vec![
            "bench",
            "--config",
            "c.json",
            "--psf",
            "g",
            "--threads",
            "3000",
        ],
        vec![
            "measure",
            "--run",
            "run/public",
            "--out",
            "s.txt",
            "--threads",
            "5000",
        ],
    ] {
        let o = stepsim(&args, dir.path(), &[]);
        assert_eq!(o.status.code(), Some(2), "{args:?}");
        assert!(stderr(&o).contains("more than 1024"), "{}", stderr(&o));
    }
    assert_eq!(listing(dir.path()), ["c.json"]);
    // Within the range but beyond 4 per core: capped, with a note.
    let o = stepsim(
        &[
            "generate",
            "--config",
            "c.json",
            "--out",
            "run",
            "--threads",
            "1024",
            "--set",
            "shears=[{\"g1\":0}]",
            "--set",
            "image.n_images=1",
        ],
        dir.path(),
        &[],
    );
    assert!(o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("stepsim: note: --threads 1024 is more than 4 per core") && e.contains("using "),
        "{e}"
    );
}

#[test]
fn extended_syntax_names_are_plain_paths_for_generate_measure_and_score() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("c.json"), TINY).unwrap();
    let o = stepsim(
        &[
            "generate",
            "--config",
            "c.json",
            "--out",
            "run[x]",
            "--threads",
            "2",
        ],
        d,
        &[],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    // Nothing but the config and the run in the working directory.
    assert_eq!(listing(d), ["c.json", "run[x]"]);
    assert!(d.join("run[x]/public/manifest.json").is_file());
    for out in ["a[1].fits", "b(2)", "!c"] {
        let o = stepsim(
            &[
                "measure",
                "--run",
                "run[x]/public",
                "--out",
                out,
                "--threads",
                "2",
            ],
            d,
            &[],
        );
        assert!(o.status.success(), "{out}: {}", stderr(&o));
        let text = std::fs::read_to_string(d.join(out)).unwrap();
        assert!(text.starts_with("# image x y e1 e2"), "{out}");
        assert!(
            text.lines().count() > 5,
            "{out}: {} lines",
            text.lines().count()
        );
    }
    assert_eq!(listing(d), ["!c", "a[1].fits", "b(2)", "c.json", "run[x]"]);
    for (sub, out) in [("b(2)", "s[1]"), ("!c", "!t(2)")] {
        let o = stepsim(
            &[
                "score",
                "--truth",
                "run[x]/private",
                "--submission",
                sub,
                "--out",
                out,
            ],
            d,
            // The global pool's thread count is bounded too (100000 hung).
            &[("RAYON_NUM_THREADS", "100000")],
        );
        assert!(o.status.success(), "{sub}: {}", stderr(&o));
        assert!(
            stderr(&o).contains("stepsim: note: RAYON_NUM_THREADS 100000 is more than 4 per core"),
            "{}",
            stderr(&o)
        );
        let report: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(d.join(out).join("report.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(report["datasets"].as_array().unwrap().len(), 2, "{sub}");
    }
    assert_eq!(
        listing(d),
        [
            "!c",
            "!t(2)",
            "a[1].fits",
            "b(2)",
            "c.json",
            "run[x]",
            "s[1]"
        ]
    );
}

#[test]
fn paths_that_are_not_utf8_are_refused_before_anything_is_written() {
    use std::os::unix::ffi::OsStrExt as _;
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("c.json"), TINY).unwrap();
    let bad = std::ffi::OsStr::from_bytes(b"r\xffn");
    let o = Command::new(env!("CARGO_BIN_EXE_stepsim"))
        .args(["generate", "--config", "c.json", "--out"])
        .arg(bad)
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("--out r\u{fffd}n: the path is not valid UTF-8"),
        "{}",
        stderr(&o)
    );
    assert_eq!(listing(dir.path()), ["c.json"]);
}

/// Gated: `STEPSIM_FULL_DISK_DIR` names an empty directory on a small file
/// system (e.g. `mount -t tmpfs -o size=4m tmpfs DIR`); the test fills it to
/// 1 MiB of free space and checks that `generate` stops with a sentence and
/// leaves no partial file.
#[test]
fn a_full_disk_is_a_sentence_and_leaves_no_partial_file() {
    let Some(root) = std::env::var_os("STEPSIM_FULL_DISK_DIR") else {
        eprintln!("STEPSIM_FULL_DISK_DIR not set: the full-disk run is skipped");
        return;
    };
    let root = Path::new(&root);
    let work = tempfile::tempdir().unwrap();
    std::fs::write(work.path().join("c.json"), TINY).unwrap();
    // Fill the file system with 256 KiB files, then free 1 MiB.
    let fill = root.join("fill");
    std::fs::create_dir_all(&fill).unwrap();
    let chunk = vec![7u8; 256 << 10];
    let mut n = 0;
    while std::fs::write(fill.join(n.to_string()), &chunk).is_ok() {
        n += 1;
    }
    let _ = std::fs::remove_file(fill.join(n.to_string()));
    for k in 1..=4 {
        std::fs::remove_file(fill.join((n - k).to_string())).unwrap();
    }
    let run = root.join("run");
    let o = stepsim(
        &[
            "generate",
            "--config",
            "c.json",
            "--out",
            run.to_str().unwrap(),
            "--threads",
            "1",
        ],
        work.path(),
        &[],
    );
    std::fs::remove_dir_all(&fill).unwrap();
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains("cannot write ") && e.contains(": the disk is full or the file is not writable"),
        "{e}"
    );
    assert!(!e.contains("FitsError") && !e.contains("status:"), "{e}");
    // No temporary and no FITS file without its sidecar remains.
    fn walk(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(&p, out);
            } else {
                out.push(p);
            }
        }
    }
    let mut files = Vec::new();
    walk(&run, &mut files);
    assert!(
        files.iter().all(|p| !p.to_string_lossy().ends_with(".tmp")),
        "{files:?}"
    );
    for p in files
        .iter()
        .filter(|p| p.starts_with(run.join("public")) && p.extension().is_some_and(|x| x == "fits"))
    {
        let id = p.file_stem().unwrap().to_string_lossy().into_owned();
        assert!(
            run.join(format!("private/done/{id}.json")).is_file(),
            "{p:?} has no sidecar"
        );
    }
    std::fs::remove_dir_all(&run).unwrap();
}

#[test]
fn a_run_too_big_for_the_disk_is_refused_before_anything_is_written() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("c.json"), TINY).unwrap();
    let o = stepsim(
        &["generate", "--config", "c.json", "--out", "run"],
        dir.path(),
        &[("STEPSIM_DISK_LIMIT_BYTES", "100000")],
    );
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains("generate would write about ")
            && e.contains("truth tables")
            && e.contains("to run, of which 0.0 MiB is already there")
            && e.contains("only 0.1 MiB is free (STEPSIM_DISK_LIMIT_BYTES=100000)")
            && e.contains("output.compression \"rice\""),
        "{e}"
    );
    assert_eq!(listing(dir.path()), ["c.json"]);
    // A limit that is not a number is refused, not ignored.
    let o = stepsim(
        &["generate", "--config", "c.json", "--out", "run"],
        dir.path(),
        &[("STEPSIM_DISK_LIMIT_BYTES", "1T")],
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("STEPSIM_DISK_LIMIT_BYTES=1T: not a number of bytes"),
        "{}",
        stderr(&o)
    );
    assert_eq!(listing(dir.path()), ["c.json"]);
    // Enough room: the run is made.
    let o = stepsim(
        &["generate", "--config", "c.json", "--out", "run"],
        dir.path(),
        &[("STEPSIM_DISK_LIMIT_BYTES", "1000000000")],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
}
