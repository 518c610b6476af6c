//! Hostile and absurd input to the simulator's commands: each is refused
//! with a sentence naming the key, file or value (exit 1; usage errors
//! exit 2), writes nothing, and never panics or aborts.

use std::path::Path;

use crate::common;
use common::{run_env, stderr};

/// 1 Gaussian PSF × 2 shears × 2 images of 256², enough objects to measure.
const TINY: &str = r#"{
  "run": {"seed": 99},
  "image": {"width_px": 256, "height_px": 256, "n_images": 2, "margin_arcsec": 2.0},
  "psfs": [{"name": "g", "model": "gaussian"}],
  "shears": [{"g1": 0.0}, {"g1": 0.05}],
  "population": {"galaxies": {"mag_faint": 24.0}}
}"#;

/// Names of the entries of `dir`, sorted.
fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// One refused command: run in a fresh directory holding `c.json` (TINY)
/// and `files`, it must exit with `code`, say every one of `words` on
/// stderr (the file, line, key or value at fault, and the remedy), and
/// leave the directory as it was.
struct Refusal {
    /// Extra files written first (name, text).
    files: &'static [(&'static str, &'static str)],
    args: Vec<&'static str>,
    env: &'static [(&'static str, &'static str)],
    code: i32,
    words: &'static [&'static str],
}

const GENERATE: [&str; 5] = ["generate", "--config", "c.json", "--out", "run"];

/// 65536² pixels down to I = 19: more memory than the 8 GiB allowed.
const BIG: [&str; 6] = [
    "--set",
    "image.width_px=65536",
    "--set",
    "image.height_px=65536",
    "--set",
    "population.galaxies.mag_faint=19",
];
const LIMIT_8_GIB: &[(&str, &str)] = &[("STEPSIM_MEMORY_LIMIT_BYTES", "8589934592")];

/// `stepsim generate` on c.json into `run`, then `extra`.
fn generate(extra: &[&'static str]) -> Vec<&'static str> {
    [GENERATE.as_slice(), extra].concat()
}

fn refusal(
    args: Vec<&'static str>,
    env: &'static [(&'static str, &'static str)],
    code: i32,
    words: &'static [&'static str],
) -> Refusal {
    Refusal {
        files: &[],
        args,
        env,
        code,
        words,
    }
}

fn bad_config(
    files: &'static [(&'static str, &'static str)],
    words: &'static [&'static str],
) -> Refusal {
    Refusal {
        files,
        args: vec!["config", "--config", files[0].0],
        env: &[],
        code: 1,
        words,
    }
}

/// A `generate` refused for one `--set` value.
fn bad_value(set: &'static str, words: &'static [&'static str]) -> Refusal {
    refusal(generate(&["--set", set]), &[], 1, words)
}

fn refusals() -> Vec<Refusal> {
    vec![
        // Configs that are not objects: the file, the line and the key.
        bad_config(
            &[("array.json", "[{}, {}, {}]")],
            &["array.json: the config (line 1): expected a JSON object {...}, found an array"],
        ),
        bad_config(
            &[("nested.json", "{\n  \"image\": [64, 64, 0.2, 1]\n}")],
            &["nested.json: key `image` (line 2): expected a JSON object {...}, found an array"],
        ),
        bad_config(
            &[("psf.json", "{\"psfs\": [[\"g\", \"gaussian\"]]}")],
            &["psf.json: key `psfs.0`: expected a JSON object {...}, found an array"],
        ),
        bad_config(
            &[("number.json", "7")],
            &["number.json: the config (line 1): expected a JSON object {...}, found a number"],
        ),
        // An override that turns a section into an array.
        refusal(
            vec![
                "config",
                "--config",
                "c.json",
                "--set",
                "instrument=[1,2,3]",
            ],
            &[],
            1,
            &["--set: key `instrument`: expected a JSON object"],
        ),
        // Absurd values: the key, the range and the value.
        bad_value(
            "instrument.exposure_s=1e300",
            &["key `instrument.exposure_s`: must be in [0.001, 1000000], got 1e300"],
        ),
        bad_value(
            "image.pixel_scale_arcsec=1e-9",
            &["key `image.pixel_scale_arcsec`: must be in [0.03, 5], got 1e-9"],
        ),
        bad_value(
            "instrument.gain_e_per_adu=1e-12",
            &["key `instrument.gain_e_per_adu`: must be in [0.01, 1000]"],
        ),
        bad_value(
            "instrument.saturation_adu=1e300",
            &["key `instrument.saturation_adu`: must be in [1, 2147483647]"],
        ),
        bad_value(
            "population.galaxies.mag_faint=39",
            &["key `population.galaxies.mag_faint`: must be in [17, 32], got 39"],
        ),
        bad_value(
            "population.stars.density_per_arcmin2=99999",
            &["key `population.stars.density_per_arcmin2`: must be in [0, 10000]"],
        ),
        // In range one by one, but the sky alone saturates every pixel.
        bad_value(
            "instrument.exposure_s=1e6",
            &["key `instrument`: the sky alone gives"],
        ),
        // Too big for memory: refused before anything is written, with the
        // figure, the limit and the remedy.
        refusal(
            [generate(&["--threads", "2"]), BIG.to_vec()].concat(),
            LIMIT_8_GIB,
            1,
            &[
                "generate needs about ",
                "2 images of 65536 × 65536 px in flight",
                "only 8.0 GiB is available (STEPSIM_MEMORY_LIMIT_BYTES=8589934592)",
                "lower image.width_px",
            ],
        ),
        refusal(
            [
                [
                    "bench",
                    "--config",
                    "c.json",
                    "--psf",
                    "g",
                    "--repeats",
                    "1",
                ]
                .as_slice(),
                &BIG,
            ]
            .concat(),
            LIMIT_8_GIB,
            1,
            &["bench needs about "],
        ),
        refusal(
            vec![
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
            LIMIT_8_GIB,
            1,
            &["psf needs about "],
        ),
        refusal(
            GENERATE.to_vec(),
            &[("STEPSIM_MEMORY_LIMIT_BYTES", "8G")],
            1,
            &["STEPSIM_MEMORY_LIMIT_BYTES=8G: not a number of bytes"],
        ),
        // Too big for the disk: the figure, what is there, what is free, the
        // remedy.
        refusal(
            GENERATE.to_vec(),
            &[("STEPSIM_DISK_LIMIT_BYTES", "100000")],
            1,
            &[
                "generate would write about ",
                "truth tables",
                "to run, of which 0.0 MiB is already there",
                "only 0.1 MiB is free (STEPSIM_DISK_LIMIT_BYTES=100000)",
                "output.compression \"rice\"",
            ],
        ),
        refusal(
            GENERATE.to_vec(),
            &[("STEPSIM_DISK_LIMIT_BYTES", "1T")],
            1,
            &["STEPSIM_DISK_LIMIT_BYTES=1T: not a number of bytes"],
        ),
        // Thread counts beyond the documented range: usage errors.
        refusal(
            generate(&["--threads", "100000"]),
            &[],
            2,
            &["more than 1024"],
        ),
        refusal(
            generate(&["--threads", "1025"]),
            &[],
            2,
            &["more than 1024"],
        ),
        refusal(
            vec![
                "bench",
                "--config",
                "c.json",
                "--psf",
                "g",
                "--threads",
                "3000",
            ],
            &[],
            2,
            &["more than 1024"],
        ),
        refusal(
            vec![
                "measure",
                "--run",
                "run/public",
                "--out",
                "s.txt",
                "--threads",
                "5000",
            ],
            &[],
            2,
            &["more than 1024"],
        ),
    ]
}

#[test]
fn refused_input_names_what_is_wrong_exits_1_or_2_and_writes_nothing() {
    for (k, case) in refusals().iter().enumerate() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("c.json"), TINY).unwrap();
        for (name, text) in case.files {
            std::fs::write(d.join(name), text).unwrap();
        }
        let before = listing(d);
        let o = run_env(&case.args, d, case.env);
        let e = stderr(&o);
        let what = format!("case {k}: stepsim {}", case.args.join(" "));
        assert_eq!(o.status.code(), Some(case.code), "{what}: {e}");
        for w in case.words {
            assert!(e.contains(w), "{what}: `{w}` not in: {e}");
        }
        assert!(
            e.contains("error: ") && !e.contains("panicked"),
            "{what}: {e}"
        );
        assert_eq!(listing(d), before, "{what} wrote something");
    }
}

#[test]
fn a_thread_count_beyond_4_per_core_is_capped_with_a_note() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("c.json"), TINY).unwrap();
    let o = run_env(
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
    let o = run_env(
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
        let o = run_env(
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
        let o = run_env(
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
    let o = common::run_with(
        common::stepsim()
            .args(["generate", "--config", "c.json", "--out"])
            .arg(bad)
            .current_dir(dir.path()),
    );
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
    let o = run_env(
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
fn a_run_that_fits_the_disk_limit_is_made() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("c.json"), TINY).unwrap();
    // Enough room: the run is made.
    let o = run_env(
        &["generate", "--config", "c.json", "--out", "run"],
        dir.path(),
        &[("STEPSIM_DISK_LIMIT_BYTES", "1000000000")],
    );
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
}
