//! End-to-end checks of `stepsim measure`: a synthetic public run, output
//! format, thread-count independence, and refused input.

use std::path::Path;
use stepsim_testkit::scene::{SceneSpec, synthetic_scene, write_public_run};

use crate::common;
use common::{ok, run_with, stderr, stepsim};

/// Writes a public half with two 512² synthetic images (ADU, gain 4).
fn public_run(dir: &Path) {
    let scenes: Vec<_> = ["ib2", "ia1"]
        .iter()
        .enumerate()
        .map(|(k, id)| {
            let spec = SceneSpec {
                width: 512,
                height: 512,
                n_galaxy_pairs: 60,
                n_stars: 80,
                star_flux_e: (1e5, 3e6),
                ..SceneSpec::step_like([0.05, 0.0], [0.04, 0.01], 100 + k as u64)
            };
            (*id, synthetic_scene(&spec).1)
        })
        .collect();
    let refs: Vec<_> = scenes.iter().map(|(id, img)| ("d0", *id, img)).collect();
    write_public_run(dir, &refs).unwrap();
}

fn measure(run: &Path, out: &Path, threads: &str) -> std::process::Output {
    run_with(
        stepsim()
            .args(["measure", "--run"])
            .arg(run)
            .arg("--out")
            .arg(out)
            .args(["--threads", threads]),
    )
}

#[test]
fn measure_writes_a_sorted_submission_independent_of_threads() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("public");
    public_run(&run);
    let (a, b) = (dir.path().join("a.txt"), dir.path().join("b.txt"));
    ok(measure(&run, &a, "1"));
    ok(measure(&run, &b, "2"));
    let text = std::fs::read_to_string(&a).unwrap();
    assert_eq!(text, std::fs::read_to_string(&b).unwrap());
    check_submission(&text);
    // Metadetection too: the same bytes at any thread count.
    let md = |out: &Path, threads: &str, sums: Option<&Path>| {
        let mut cmd = stepsim();
        cmd.args(["measure", "--method", "metadetect", "--run"])
            .arg(&run)
            .arg("--out")
            .arg(out)
            .args(["--threads", threads]);
        if let Some(sums) = sums {
            cmd.arg("--version-sums").arg(sums);
        }
        run_with(&mut cmd)
    };
    let (c, d) = (dir.path().join("c.txt"), dir.path().join("d.txt"));
    let sums = dir.path().join("sums.txt");
    let out = ok(md(&c, "1", Some(&sums)));
    ok(md(&d, "2", None));
    // Its one dataset's response, with an error from its two images; no
    // KSB+ PSF model.
    let err = stderr(&out);
    let line = err
        .lines()
        .find(|l| l.starts_with("stepsim: dataset d0: R = [["))
        .unwrap_or_else(|| panic!("{err}"));
    assert!(
        line.ends_with("(jackknife over its 2 images; its rows use the diagonal)"),
        "{line}"
    );
    assert!(!err.contains("PSF order"), "{err}");
    let text = std::fs::read_to_string(&c).unwrap();
    assert_eq!(text, std::fs::read_to_string(&d).unwrap());
    check_submission(&text);
    // The version sums: a line per image, from which the printed R follows.
    let table = std::fs::read_to_string(&sums).unwrap();
    let mut lines = table.lines();
    assert_eq!(
        lines.next(),
        Some(
            "# image dataset n_0 sum_e1_0 sum_e2_0 n_1p sum_e1_1p sum_e2_1p n_1m sum_e1_1m \
             sum_e2_1m n_2p sum_e1_2p sum_e2_2p n_2m sum_e1_2m sum_e2_2m"
        )
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split_whitespace().collect()).collect();
    assert_eq!(
        rows.iter().map(|r| r[0]).collect::<Vec<_>>(),
        ["ia1", "ib2"]
    );
    let mut tot = [[0.0f64; 3]; 5];
    for r in &rows {
        assert_eq!((r.len(), r[1]), (17, "d0"), "{r:?}");
        for (v, t) in tot.iter_mut().enumerate() {
            let n: u64 = r[2 + 3 * v].parse().unwrap();
            assert!(n > 10, "{r:?}");
            t[2] += n as f64;
            t[0] += r[3 + 3 * v].parse::<f64>().unwrap();
            t[1] += r[4 + 3 * v].parse::<f64>().unwrap();
        }
    }
    let mean = |v: usize, i: usize| tot[v][i] / tot[v][2];
    let r = [
        [
            (mean(1, 0) - mean(2, 0)) / 0.02,
            (mean(3, 0) - mean(4, 0)) / 0.02,
        ],
        [
            (mean(1, 1) - mean(2, 1)) / 0.02,
            (mean(3, 1) - mean(4, 1)) / 0.02,
        ],
    ];
    let printed = format!(
        "stepsim: dataset d0: R = [[{:.4}, {:.4}], [{:.4}, {:.4}]] ± ",
        r[0][0], r[0][1], r[1][0], r[1][1]
    );
    assert!(line.starts_with(&printed), "{line} against {printed}");
    assert!(err.contains("stepsim: wrote the version sums"), "{err}");
    // Refused without metadetection (nothing measured, nothing written),
    // and where it would overwrite the submission.
    let ksb_sums = dir.path().join("ksb-sums.txt");
    let o = run_with(
        stepsim()
            .args(["measure", "--run"])
            .arg(&run)
            .arg("--out")
            .arg(dir.path().join("e.txt"))
            .arg("--version-sums")
            .arg(&ksb_sums),
    );
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("needs --method metadetect"),
        "{}",
        stderr(&o)
    );
    assert!(!ksb_sums.exists() && !dir.path().join("e.txt").exists());
    let o = md(&c, "1", Some(&c));
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("give it its own file"),
        "{}",
        stderr(&o)
    );
    assert_eq!(std::fs::read_to_string(&c).unwrap(), text);
}

#[test]
fn unshear_measures_metadetection_again_and_writes_where_it_sheared_back() {
    // `--unshear`: the sums file gains the sheared-back version's columns,
    // its first seventeen are those of a plain metadetection, the version's
    // shear is minus the plain rows' weighted mean (the dataset's first
    // estimate ĝ₀), and the rows' weighted mean is ĝ₀ + ⟨e⟩/R of the new
    // columns. Refused without metadetection, nothing written.
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("public");
    public_run(&run);
    let md = |out: &Path, sums: &Path, unshear: bool| {
        let mut cmd = stepsim();
        cmd.args([
            "measure",
            "--method",
            "metadetect",
            "--threads",
            "2",
            "--run",
        ])
        .arg(&run)
        .arg("--out")
        .arg(out)
        .arg("--version-sums")
        .arg(sums);
        if unshear {
            cmd.arg("--unshear");
        }
        ok(run_with(&mut cmd))
    };
    let (a, sa, b, sb) = (
        dir.path().join("a.txt"),
        dir.path().join("a.sums"),
        dir.path().join("b.txt"),
        dir.path().join("b.sums"),
    );
    md(&a, &sa, false);
    let err = stderr(&md(&b, &sb, true));
    assert!(
        err.contains("stepsim: dataset d0: measured again sheared back by ĝ₀ = ("),
        "{err}"
    );
    let mean = |path: &Path| {
        let mut acc = [0.0f64; 3];
        for l in std::fs::read_to_string(path).unwrap().lines().skip(1) {
            let w: Vec<f64> = l.split(' ').skip(1).map(|v| v.parse().unwrap()).collect();
            acc = [acc[0] + w[4] * w[2], acc[1] + w[4] * w[3], acc[2] + w[4]];
        }
        assert!(acc[2] > 20.0, "{acc:?}");
        [acc[0] / acc[2], acc[1] / acc[2]]
    };
    let (plain, again) = (mean(&a), mean(&b));
    let table = std::fs::read_to_string(&sb).unwrap();
    let first = std::fs::read_to_string(&sa).unwrap();
    assert!(
        table
            .lines()
            .next()
            .unwrap()
            .ends_with("sum_e2_2m shear1_u shear2_u n_u sum_e1_u sum_e2_u")
    );
    let mut tot = [[0.0f64; 3]; 6];
    for (l, f) in table.lines().zip(first.lines()).skip(1) {
        let w: Vec<&str> = l.split(' ').collect();
        assert_eq!(w.len(), 22, "{l}");
        assert_eq!(w[..17].join(" "), f, "the first measurement's columns");
        let g0 = [w[17].parse::<f64>().unwrap(), w[18].parse::<f64>().unwrap()];
        for i in 0..2 {
            // The rows are written to six decimals.
            assert!((g0[i] + plain[i]).abs() < 1e-5, "{g0:?} {plain:?}");
        }
        let v: Vec<f64> = w[2..17]
            .iter()
            .chain(&w[19..])
            .map(|x| x.parse().unwrap())
            .collect();
        for (k, t) in tot.iter_mut().enumerate() {
            *t = [t[0] + v[3 * k + 1], t[1] + v[3 * k + 2], t[2] + v[3 * k]];
        }
    }
    let m = |k: usize, i: usize| tot[k][i] / tot[k][2];
    let r = [(m(1, 0) - m(2, 0)) / 0.02, (m(3, 1) - m(4, 1)) / 0.02];
    for i in 0..2 {
        let want = plain[i] + m(5, i) / r[i];
        assert!((again[i] - want).abs() < 1e-5, "{again:?} against {want}");
    }
    assert_ne!(
        std::fs::read(&a).unwrap(),
        std::fs::read(&b).unwrap(),
        "the rows are the second measurement's"
    );
    let ksb = dir.path().join("k.txt");
    let o = run_with(
        stepsim()
            .args(["measure", "--unshear", "--run"])
            .arg(&run)
            .arg("--out")
            .arg(&ksb),
    );
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("--unshear needs --method metadetect"),
        "{}",
        stderr(&o)
    );
    assert!(!ksb.exists());
}

/// A submission of the test run: its header, sorted rows of seven
/// finite columns inside the 512² images, weights exactly where the flags
/// are 0, more than 20 of them, no two rows at one position, both images.
fn check_submission(text: &str) {
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("# image x y e1 e2 weight flags"));
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split_whitespace().collect()).collect();
    assert!(rows.len() > 60, "{} rows", rows.len());
    let mut last = (String::new(), f64::NEG_INFINITY, f64::NEG_INFINITY);
    let mut weighted = 0;
    for r in &rows {
        assert_eq!(r.len(), 7, "{r:?}");
        let (x, y): (f64, f64) = (r[1].parse().unwrap(), r[2].parse().unwrap());
        assert!((0.5..=512.5).contains(&x) && (0.5..=512.5).contains(&y));
        let (e1, e2, w): (f64, f64, f64) = (
            r[3].parse().unwrap(),
            r[4].parse().unwrap(),
            r[5].parse().unwrap(),
        );
        assert!(e1.is_finite() && e2.is_finite() && w >= 0.0);
        let flags: u32 = r[6].parse().unwrap();
        assert_eq!(flags == 0, w > 0.0, "{r:?}");
        weighted += usize::from(w > 0.0);
        let key = (r[0].to_string(), y, x);
        assert!(
            key.0 > last.0 || (key.0 == last.0 && (y, x) >= (last.1, last.2)),
            "{r:?} after {last:?}"
        );
        last = key;
    }
    assert!(weighted > 20, "{weighted} weighted rows");
    let mut keys: Vec<(&str, &str, &str)> = rows.iter().map(|r| (r[0], r[1], r[2])).collect();
    keys.sort();
    keys.dedup();
    assert_eq!(keys.len(), rows.len(), "duplicate rows");
    assert!(rows.iter().any(|r| r[0] == "ia1") && rows.iter().any(|r| r[0] == "ib2"));
}

#[test]
fn pgamma_fit_and_psf_order_options_are_accepted() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("public");
    public_run(&run);
    let out_a = dir.path().join("fit.txt");
    let out = ok(run_with(
        stepsim()
            .args([
                "measure",
                "--pgamma",
                "fit-size",
                "--calibration",
                "none",
                "--psf-order",
                "1",
                "--run",
            ])
            .arg(&run)
            .arg("--out")
            .arg(&out_a),
    ));
    let err = stderr(&out);
    assert!(
        err.contains("PSF order 1") || err.contains("PSF order 0"),
        "{err}"
    );
    let text = std::fs::read_to_string(&out_a).unwrap();
    let weighted = text
        .lines()
        .skip(1)
        .filter(|l| l.split_whitespace().nth(6) == Some("0"))
        .count();
    assert!(weighted > 20, "{weighted}");
    // A fitted P^γ cannot be calibrated: refused, naming the way out,
    // before anything is written.
    let out_b = dir.path().join("fit-calibrated.txt");
    let out = run_with(
        stepsim()
            .args(["measure", "--pgamma", "fit-size", "--run"])
            .arg(&run)
            .arg("--out")
            .arg(&out_b),
    );
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stderr(&out).contains("--calibration none"),
        "{}",
        stderr(&out)
    );
    assert!(!out_b.exists());
    // Orders above 4 are a usage error.
    let out = run_with(stepsim().args(["measure", "--psf-order", "7", "--run", "x", "--out", "y"]));
    assert_eq!(out.status.code(), Some(2));
}

/// `stepsim measure` of the public run `run` with `options`, written into
/// `dir` (a file named by the options): its stderr and the submission's
/// rows (the columns after `image`).
fn measured_rows(run: &Path, dir: &Path, options: &[&str]) -> (String, Vec<Vec<f64>>) {
    let out = dir.join(format!("{}.txt", options.join("_")));
    let err = stderr(&ok(run_with(
        stepsim()
            .arg("measure")
            .args(options)
            .arg("--run")
            .arg(run)
            .arg("--out")
            .arg(&out),
    )));
    let rows = std::fs::read_to_string(&out)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| {
            l.split_whitespace()
                .skip(1)
                .map(|v| v.parse().unwrap())
                .collect()
        })
        .collect();
    (err, rows)
}

#[test]
fn the_pgamma_calibration_divides_each_estimate_and_can_be_turned_off() {
    // The same detections with and without the calibration; each weighted
    // row's estimate differs by its k (a function of size and |e| only, so
    // both components by the same factor), and k varies between galaxies.
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("public");
    public_run(&run);
    let rows = |calibration: &str| -> Vec<Vec<f64>> {
        let (err, rows) = measured_rows(&run, dir.path(), &["--calibration", calibration]);
        // Each image's line gives the range of k, unless it is off.
        let lines = err.lines().filter(|l| l.contains(" weighted, ")).count();
        let with_k = err.lines().filter(|l| l.contains(", P^γ k 0.")).count();
        assert_eq!(lines, 2, "{err}");
        assert_eq!(with_k, if calibration == "none" { 0 } else { 2 }, "{err}");
        rows
    };
    let (on, off) = (rows("exponential"), rows("none"));
    assert_eq!(on.len(), off.len());
    let mut ks = Vec::new();
    for (a, b) in on.iter().zip(&off) {
        assert_eq!((a[0], a[1]), (b[0], b[1]), "positions");
        if a[4] > 0.0 && b[4] > 0.0 && a[2].abs() > 0.02 && a[3].abs() > 0.02 {
            let (k1, k2) = (b[2] / a[2], b[3] / a[3]);
            // Both printed to 6 decimals.
            assert!(
                (k1 - k2).abs() < 2e-4 / a[2].abs().min(a[3].abs()),
                "{a:?} {b:?}"
            );
            ks.push(k1);
        }
    }
    assert!(ks.len() > 30, "{} rows compared", ks.len());
    let (lo, hi) = ks
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &k| {
            (l.min(k), h.max(k))
        });
    // Measured: k from 0.932 to 0.998.
    assert!(
        lo > 0.88 && lo < 0.96 && hi > 0.97 && hi < 1.02,
        "k from {lo} to {hi}"
    );
    assert!(
        hi - lo > 1e-3,
        "k from {lo} to {hi}: the same for every galaxy"
    );
    assert_ne!(on, rows("gaussian"));
    let out = run_with(stepsim().args([
        "measure",
        "--calibration",
        "sersic",
        "--run",
        "x",
        "--out",
        "y",
    ]));
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn missing_manifest_and_broken_image_are_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = measure(&dir.path().join("nowhere"), &dir.path().join("s.txt"), "1");
    assert_eq!(out.status.code(), Some(1));
    let err = stderr(&out);
    assert!(err.contains("manifest.json"), "{err}");
    assert!(!dir.path().join("s.txt").exists());

    let run = dir.path().join("public");
    public_run(&run);
    std::fs::write(run.join("d0/ia1.fits"), b"SIMPLE  = this is not FITS").unwrap();
    let out = measure(&run, &dir.path().join("s.txt"), "1");
    assert_eq!(out.status.code(), Some(1));
    let err = stderr(&out);
    assert!(err.contains("ia1.fits"), "{err}");
    assert!(!dir.path().join("s.txt").exists());

    std::fs::write(run.join("manifest.json"), b"{\"format\": 3}").unwrap();
    let out = measure(&run, &dir.path().join("s.txt"), "1");
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains("manifest.json"));

    let out = run_with(stepsim().args(["measure", "--run", "x"]));
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn sharded_measure_joined_is_byte_identical_to_one_measure() {
    // Three datasets whose image ids interleave, one image poor in stars
    // (it needs its dataset's pooled locus): shards split by dataset, so the
    // pooling, and every row, is the same.
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("public");
    let scenes: Vec<_> = [
        ("d0", "ia", 80),
        ("d1", "ib", 60),
        ("d0", "ic", 2),
        ("d2", "id", 60),
    ]
    .iter()
    .enumerate()
    .map(|(k, (d, id, stars))| {
        let spec = SceneSpec {
            width: 384,
            height: 384,
            n_galaxy_pairs: 30,
            n_stars: *stars,
            star_flux_e: (1e5, 3e6),
            ..SceneSpec::step_like([0.05, 0.0], [0.04, 0.01], 300 + k as u64)
        };
        (*d, *id, synthetic_scene(&spec).1)
    })
    .collect();
    let refs: Vec<_> = scenes.iter().map(|(d, id, img)| (*d, *id, img)).collect();
    write_public_run(&run, &refs).unwrap();
    let whole = dir.path().join("whole.txt");
    let o = ok(measure(&run, &whole, "2"));
    // Off a terminal it says how far it is (one group of 4 images here).
    let e = stderr(&o);
    assert!(e.contains("stepsim: 4/4 images measured (100%)"), "{e}");
    let sub = dir.path().join("sub.txt");
    let shard = |k: u32| {
        ok(run_with(
            stepsim()
                .args(["measure", "--run"])
                .arg(&run)
                .arg("--out")
                .arg(&sub)
                .args(["--shard", &format!("{k}/2"), "--threads", "1"]),
        ));
    };
    let finish = || {
        run_with(
            stepsim()
                .args(["measure", "--run"])
                .arg(&run)
                .arg("--out")
                .arg(&sub)
                .arg("--finish"),
        )
    };
    shard(2);
    // Shard 2 of 2 measured dataset d1 only (sorted ids d0, d1, d2).
    let part = std::fs::read_to_string(dir.path().join("sub.txt.shards/2-of-2.txt")).unwrap();
    let imgs: std::collections::BTreeSet<&str> = part
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split_whitespace().next().unwrap())
        .collect();
    assert_eq!(imgs.into_iter().collect::<Vec<_>>(), ["ib"]);
    // A missing part: refused, naming it, nothing written.
    let o = finish();
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("1-of-2.txt") && e.contains("--shard 1/2"), "{e}");
    assert!(!sub.exists());
    shard(1);
    ok(finish());
    assert!(std::fs::read(&sub).unwrap() == std::fs::read(&whole).unwrap());
}

#[test]
fn the_detection_thresholds_are_options_and_refused_out_of_range() {
    // The defaults are DETECT_THRESH 2 and a peak of 5 σ: naming them
    // changes nothing; raising both finds fewer sources.
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("public");
    public_run(&run);
    let rows = |options: &[&str]| measured_rows(&run, dir.path(), options).1;
    let default = rows(&[]);
    let named = rows(&["--detect-thresh", "2", "--detect-peak-sn", "5"]);
    assert_eq!(default, named);
    let raised = rows(&["--detect-thresh", "30", "--detect-peak-sn", "80"]);
    assert!(
        !raised.is_empty() && raised.len() < default.len(),
        "{} rows at 30 σ, {} at 2 σ",
        raised.len(),
        default.len()
    );
    let out = dir.path().join("refused.txt");
    for bad in [
        &["--detect-thresh", "0"][..],
        &["--detect-thresh", "nan"],
        &["--detect-peak-sn", "-1"],
        &["--detect-peak-sn", "2e6"],
    ] {
        let o = run_with(
            stepsim()
                .arg("measure")
                .args(bad)
                .arg("--run")
                .arg(&run)
                .arg("--out")
                .arg(&out),
        );
        assert_eq!(o.status.code(), Some(2), "{bad:?}: {}", stderr(&o));
    }
    let o = run_with(
        stepsim()
            .args(["measure", "--detect-thresh", "9", "--detect-peak-sn", "8"])
            .arg("--run")
            .arg(&run)
            .arg("--out")
            .arg(&out),
    );
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(
        err.contains("--detect-peak-sn 8 is below --detect-thresh 9"),
        "{err}"
    );
    assert!(!out.exists());
}

#[test]
fn the_size_cut_option_changes_only_the_small_flags() {
    // `--size-cut psf-corrected` moves galaxies in and out of SMALL (32);
    // the rows, positions and the detection's flags stay. (The P^γ
    // calibration's mix of shapes comes from the galaxies that pass every
    // cut, so k, and with it PGAMMA (256) and BIG_SHEAR (512), may move.)
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("public");
    public_run(&run);
    let rows = |cut: &str| measured_rows(&run, dir.path(), &["--size-cut", cut]).1;
    let (windowed, corrected) = (rows("windowed"), rows("psf-corrected"));
    assert_eq!(windowed.len(), corrected.len());
    let mut changed = 0;
    for (a, b) in windowed.iter().zip(&corrected) {
        assert_eq!((a[0], a[1]), (b[0], b[1]), "positions");
        let (fa, fb) = (a[5] as u32, b[5] as u32);
        let k_moves = 256 | 512;
        assert_eq!(fa & !(32 | k_moves), fb & !(32 | k_moves), "{a:?} {b:?}");
        changed += usize::from(fa & 32 != fb & 32);
    }
    assert!(changed > 0, "no SMALL flag changed");
    let bad = run_with(
        stepsim()
            .args(["measure", "--size-cut", "area", "--run"])
            .arg(&run)
            .arg("--out")
            .arg(dir.path().join("x.txt")),
    );
    assert_eq!(bad.status.code(), Some(2), "{}", stderr(&bad));
}

#[test]
fn details_are_written_beside_the_submission_and_refused_where_they_cannot_be() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("public");
    public_run(&run);
    let (plain, sub, table) = (
        dir.path().join("plain.txt"),
        dir.path().join("sub.txt"),
        dir.path().join("sub.details"),
    );
    ok(measure(&run, &plain, "2"));
    let with = |out: &Path, details: &Path, extra: &[&str]| {
        run_with(
            stepsim()
                .args(["measure", "--run"])
                .arg(&run)
                .arg("--out")
                .arg(out)
                .arg("--details")
                .arg(details)
                .args(extra),
        )
    };
    ok(with(&sub, &table, &["--threads", "1"]));
    // The submission is the same bytes; the table holds its lines in its
    // order, each with eight more columns of KSB+'s and eleven of
    // metacal's (`nan`, and a mask 0, under KSB+).
    let text = std::fs::read_to_string(&sub).unwrap();
    assert_eq!(text, std::fs::read_to_string(&plain).unwrap());
    let details = std::fs::read_to_string(&table).unwrap();
    let mut lines = details.lines();
    assert_eq!(
        lines.next(),
        Some(
            "# image x y e1 e2 weight flags r_g_px nu mag pgamma k e_cor1 e_cor2 sigma_gamma \
             e1_0 e2_0 e1_1p e2_1p e1_1m e2_1m e1_2p e2_2p e1_2m e2_2m mc_selected"
        )
    );
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), text.lines().count() - 1);
    for (d, s) in rows.iter().zip(text.lines().skip(1)) {
        let cols: Vec<&str> = d.split(' ').collect();
        assert_eq!((cols.len(), cols[..7].join(" ")), (26, s.to_string()));
        assert_eq!(
            cols[15..],
            [
                "nan", "nan", "nan", "nan", "nan", "nan", "nan", "nan", "nan", "nan", "0"
            ]
        );
    }
    // Metacal rows have no KSB+ parts: `nan`, their r_g and ν kept.
    let (mc, mc_table) = (dir.path().join("mc.txt"), dir.path().join("mc.details"));
    ok(with(&mc, &mc_table, &["--method", "metacal"]));
    let mc_rows = std::fs::read_to_string(&mc_table).unwrap();
    let weighted: Vec<Vec<&str>> = mc_rows
        .lines()
        .skip(1)
        .map(|l| l.split(' ').collect::<Vec<_>>())
        .filter(|c| c[5] != "0.000000")
        .collect();
    assert!(weighted.len() > 20, "{}", weighted.len());
    for c in &weighted {
        assert_eq!(c[10..15], ["nan"; 5], "{c:?}");
        assert!(c[7].parse::<f64>().unwrap() > 1.0 && c[8].parse::<f64>().unwrap() >= 10.0);
        // A weighted row passed the cuts unsheared.
        assert_eq!(c[25].parse::<u32>().unwrap() & 1, 1, "{c:?}");
    }
    // The versions' columns give back the dataset's response (both images
    // are one dataset): recomputed here from the table alone, R⁻¹ e(0) is
    // each weighted row's e to the table's six decimals.
    type Versions = ([[f64; 2]; 5], u32);
    let versions: Vec<Versions> = mc_rows
        .lines()
        .skip(1)
        .map(|l| l.split(' ').collect::<Vec<_>>())
        .filter(|c| c[15] != "nan")
        .map(|c| {
            let v = |k: usize| c[15 + k].parse::<f64>().unwrap();
            let e = [0, 1, 2, 3, 4].map(|i| [v(2 * i), v(2 * i + 1)]);
            (e, c[25].parse().unwrap())
        })
        .collect();
    let mean = |f: &dyn Fn(&Versions) -> Option<f64>| {
        let xs: Vec<f64> = versions.iter().filter_map(f).collect();
        xs.iter().sum::<f64>() / xs.len() as f64
    };
    let mut r = [[0.0; 2]; 2];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, rij) in row.iter_mut().enumerate() {
            let (p, m) = (1 + 2 * j, 2 + 2 * j);
            let gamma = mean(&|(e, s)| (s & 1 == 1).then(|| (e[p][i] - e[m][i]) / 0.02));
            let on = |v: usize| mean(&|(e, s)| (s >> v & 1 == 1).then_some(e[0][i]));
            *rij = gamma + (on(p) - on(m)) / 0.02;
        }
    }
    assert!(r[0][0] > 0.3 && r[1][1] > 0.3, "{r:?}");
    let det = r[0][0] * r[1][1] - r[0][1] * r[1][0];
    let mut checked = 0;
    for c in &weighted {
        let v = |k: usize| c[k].parse::<f64>().unwrap();
        let g = [
            (r[1][1] * v(15) - r[0][1] * v(16)) / det,
            (-r[1][0] * v(15) + r[0][0] * v(16)) / det,
        ];
        assert!(
            (g[0] - v(3)).abs() < 1e-4 && (g[1] - v(4)).abs() < 1e-4,
            "{g:?} {c:?}"
        );
        checked += 1;
    }
    assert_eq!(checked, weighted.len());
    // The table's own file, a directory, and shards: refused before
    // measuring.
    let o = with(&dir.path().join("s3.txt"), dir.path(), &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("is a directory"), "{}", stderr(&o));
    assert!(!dir.path().join("s3.txt").exists());
    // Nothing else is left beside the outputs.
    let tmp: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(tmp.is_empty(), "{tmp:?}");
    // Any spelling of a shared file: the same path, through `..`, the
    // submission's rows file, or the table's rows file as the submission.
    let d = dir.path();
    for (out, table) in [
        (sub.clone(), sub.clone()),
        (sub.clone(), d.join("none/yet/../../sub.txt")),
        (sub.clone(), d.join("sub.txt.rows.tmp")),
        (d.join("t.rows.tmp"), d.join("t")),
    ] {
        let o = with(&out, &table, &[]);
        assert_eq!(o.status.code(), Some(1), "{out:?} {table:?}");
        assert!(
            stderr(&o).contains("shares a file with the submission"),
            "{}",
            stderr(&o)
        );
    }
    assert_eq!(std::fs::read_to_string(&sub).unwrap(), text);
    assert!(!d.join("t").exists() && !d.join("none").exists());
    let o = with(&d.join("new/"), &table, &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("--out") && stderr(&o).contains("is a directory"));
    let o = with(&d.join("s4.txt"), &d.join("new/"), &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(!d.join("new").exists() && !d.join("s4.txt").exists());
    let o = with(&dir.path().join("s2.txt"), &table, &["--shard", "1/2"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--details"), "{}", stderr(&o));
    assert!(!dir.path().join("s2.txt.shards").exists());
}
