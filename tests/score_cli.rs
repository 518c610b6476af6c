//! End-to-end checks of `stepsim score` and `stepsim leaderboard`: the report
//! has the SPEC §7 keys and the known answer, bad input exits 1 naming file,
//! line and column with nothing written, reports are never overwritten
//! without --force.

use std::path::{Path, PathBuf};
use std::process::Output;
use stepsim_contract::run_dir::RunDir;
use stepsim_contract::truth::TruthRow;
use stepsim_testkit::synthetic::{SynthRun, SynthSpec, make_run, submission_text};

use crate::common;
use common::fits_table::{doubles, fits_table, text, zeros};
use common::{run, run_with, stderr};

/// `stepsim ARGS` with arguments of mixed types (strings and paths).
fn stepsim(args: &[&dyn AsRef<std::ffi::OsStr>]) -> Output {
    run(args, Path::new("."))
}

struct Fixture {
    dir: tempfile::TempDir,
    run: SynthRun,
}

impl Fixture {
    fn new() -> Self {
        let dir = tempfile::tempdir().unwrap();
        let mut spec = SynthSpec::small(2);
        spec.psfs.truncate(2);
        spec.shears.truncate(4);
        let run = make_run(&spec);
        run.write(RunDir::new(dir.path()).private().path()).unwrap();
        Self { dir, run }
    }
    fn path(&self, p: &str) -> PathBuf {
        self.dir.path().join(p)
    }
    /// A text submission with multiplicative bias m0, stars and no false
    /// detections.
    fn submission(&self, name: &str, m0: f64) -> PathBuf {
        let rows = self.run.submission(&|t: &TruthRow, _| {
            Some(if t.is_star() {
                (0.0, 0.0, 1.0)
            } else {
                ((1.0 + m0) * t.e1, (1.0 + m0) * t.e2, 1.0)
            })
        });
        let p = self.path(name);
        std::fs::write(&p, submission_text(&self.run.index(), &rows)).unwrap();
        p
    }
    fn score(&self, sub: &Path, out: &str, extra: &[&str]) -> Output {
        self.score_threads(sub, out, extra, None)
    }
    fn score_threads(
        &self,
        sub: &Path,
        out: &str,
        extra: &[&str],
        threads: Option<&str>,
    ) -> Output {
        let truth = self.path("private");
        let out = self.path(out);
        let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![
            &"score",
            &"--truth",
            &truth,
            &"--submission",
            &sub,
            &"--out",
            &out,
        ];
        for e in extra {
            args.push(e);
        }
        let mut c = common::stepsim();
        c.args(args);
        if let Some(t) = threads {
            c.env("RAYON_NUM_THREADS", t);
        }
        run_with(&mut c)
    }
}

fn keys(v: &serde_json::Value) -> Vec<String> {
    let mut k: Vec<String> = v.as_object().unwrap().keys().cloned().collect();
    k.sort();
    k
}

#[test]
fn score_writes_the_spec_report_and_refuses_to_overwrite_it() {
    let fx = Fixture::new();
    let sub = fx.submission("team.txt", 0.01);
    let before = std::fs::read(&sub).unwrap();
    let o = fx.score(&sub, "out", &["--name", "Team A"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        std::fs::read(&sub).unwrap(),
        before,
        "the submission is untouched"
    );
    let text = std::fs::read_to_string(fx.path("out/report.json")).unwrap();
    let r: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(
        keys(&r),
        [
            "by_disk_size",
            "by_magnitude",
            "datasets",
            "isolation_plane",
            "match_radius_arcsec",
            "psfs",
            "run",
            "submission",
            "summary",
            "warnings"
        ]
    );
    // The run's identity: the SHA-256 of the truth's datasets.json.
    let dj = std::fs::read(fx.path("private/datasets.json")).unwrap();
    assert_eq!(r["run"], stepsim_harness::run_identity(&dj).as_str());
    assert!(
        r["run"].as_str().unwrap().starts_with("sha256:") && r["run"].as_str().unwrap().len() == 71
    );
    assert_eq!(r["submission"], "Team A");
    assert_eq!(r["match_radius_arcsec"], 1.0);
    // No config.json in the synthetic private directory: positions are the
    // image's.
    assert_eq!(r["isolation_plane"], "image");
    let d = &r["datasets"][0];
    for k in [
        "dataset",
        "psf",
        "g1_true",
        "g2_true",
        "n_images",
        "n_objects",
        "g1",
        "g1_err",
        "g2",
        "g2_err",
        "ngal_per_arcmin2",
        "pct_stars",
        "pct_false",
        "pct_stars_weighted",
        "pct_false_weighted",
        "snr",
        "sn_shot",
        "sn_shot_weighted",
    ] {
        assert!(d.get(k).is_some(), "datasets[].{k}");
    }
    assert_eq!(r["datasets"].as_array().unwrap().len(), 8);
    assert_eq!(d["n_images"], 2);
    assert_eq!(d["pct_false"], 0.0);
    assert!(d["pct_stars"].as_f64().unwrap() > 1.0);
    let p = &r["psfs"][0];
    for k in [
        "psf",
        "m",
        "m_err",
        "q",
        "q_err",
        "c1",
        "c1_err",
        "c2",
        "c2_err",
        "linear",
        "m_uncontaminated",
        "m_selc",
        "c1_selc",
        "c2_selc",
        "m_weight",
        "c1_weight",
    ] {
        assert!(p.get(k).is_some(), "psfs[].{k}");
    }
    // Stars were submitted with zero shear: they dilute m; galaxies alone
    // give the injected m0 = 0.01 exactly (ring-symmetric shapes).
    let m_unc = p["m_uncontaminated"].as_f64().unwrap();
    assert!((m_unc - 0.01).abs() < 1e-6, "{m_unc}");
    assert!(p["m"].as_f64().unwrap() < 0.0);
    for k in [
        "m_mean",
        "q_mean",
        "sigma_c",
        "m_uncontaminated_mean",
        "m_selc_mean",
        "sigma_c_selc",
        "m_weight_mean",
        "q_c",
        "bootstrap",
    ] {
        assert!(r["summary"].get(k).is_some(), "summary.{k}");
    }
    assert_eq!(r["by_magnitude"]["variable"], "mag");
    assert_eq!(r["by_disk_size"]["variable"], "disk_h_arcsec");
    let md = std::fs::read_to_string(fx.path("out/report.md")).unwrap();
    assert!(md.contains("Table 5") && md.contains("Table 4") && md.contains("| Team A |"));
    for f in [
        "fig2_shear_response",
        "fig3_m_sigma_c",
        "fig4_mselc_muncontaminated",
        "fig5_residual_magnitude",
    ] {
        let png = std::fs::read(fx.path(&format!("out/{f}.png"))).unwrap();
        assert!(stepsim_figure::png::decode(&png).is_some(), "{f}.png");
        let svg = std::fs::read_to_string(fx.path(&format!("out/{f}.svg"))).unwrap();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    }
    // Same input, same bytes (bootstrap included), whatever the thread count.
    for (out, threads) in [("out1", "1"), ("out3", "3")] {
        let o = fx.score_threads(&sub, out, &["--name", "Team A"], Some(threads));
        assert!(o.status.success());
        let again = std::fs::read_to_string(fx.path(&format!("{out}/report.json"))).unwrap();
        assert_eq!(again, text, "{threads} threads");
        let md = std::fs::read(fx.path(&format!("{out}/report.md"))).unwrap();
        assert_eq!(md, std::fs::read(fx.path("out/report.md")).unwrap());
    }
    // No overwrite without --force.
    let o = fx.score(&sub, "out", &["--name", "other"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("already exists"), "{}", stderr(&o));
    assert_eq!(
        std::fs::read_to_string(fx.path("out/report.json")).unwrap(),
        text
    );
    let o = fx.score(&sub, "out", &["--name", "other", "--force"]);
    assert!(o.status.success());
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fx.path("out/report.json")).unwrap())
            .unwrap();
    assert_eq!(r["submission"], "other");
    assert!(r["summary"]["bootstrap"].is_object());
    // Without resamples: no intervals, the same figures.
    let o = fx.score(&sub, "nob", &["--bootstrap-resamples", "0"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let nob: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fx.path("nob/report.json")).unwrap())
            .unwrap();
    assert!(nob["summary"]["bootstrap"].is_null());
    assert_eq!(nob["summary"]["m_mean"], r["summary"]["m_mean"]);
    assert_eq!(nob["summary"]["q_c"], r["summary"]["q_c"]);
}

#[test]
fn bad_submissions_exit_1_naming_file_line_and_column_and_write_nothing() {
    let fx = Fixture::new();
    let good = std::fs::read_to_string(fx.submission("good.txt", 0.0)).unwrap();
    let lines: Vec<&str> = good.lines().collect();
    let first_id = lines[1].split_whitespace().next().unwrap();
    let with_line3 = |l: &str| {
        let mut v = lines.clone();
        v[2] = l;
        v.join("\n") + "\n"
    };
    let dup = lines[1].to_owned();
    let cases: Vec<(String, String, &str)> = vec![
        (
            with_line3("nosuchimage 10 10 0 0 1"),
            "line 3, column `image`".into(),
            "unknown image",
        ),
        (
            good.replacen(" e2 ", " flux ", 1),
            "line 1, column `e2`".into(),
            "required column missing",
        ),
        (
            with_line3(&format!("{first_id} 10 10 NaN 0 1")),
            "line 3, column `e1`".into(),
            "not finite",
        ),
        (
            with_line3(&format!("{first_id} 10 301 0 0 1")),
            "line 3, column `y`".into(),
            "off the image",
        ),
        (
            with_line3(&format!("{first_id} 10 ten 0 0 1")),
            "line 3, column `y`".into(),
            "cannot read `ten`",
        ),
        (
            with_line3(&dup),
            "line 3, column `x`".into(),
            "duplicate row",
        ),
        (String::new(), "bad.txt: empty file".into(), "empty"),
    ];
    for (text, place, what) in cases {
        let sub = fx.path("bad.txt");
        std::fs::write(&sub, &text).unwrap();
        let o = fx.score(&sub, "badout", &[]);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{what}: {e}");
        assert!(
            e.contains("bad.txt") && e.contains(&place) && e.contains(what),
            "{what}: {e}"
        );
        assert!(!fx.path("badout").exists(), "{what}: nothing written");
    }
    // Missing images: refused, then scored with the flag (and a warning).
    let sub = fx.path("partial.txt");
    let partial: Vec<&str> = lines
        .iter()
        .copied()
        .filter(|l| !l.starts_with(first_id))
        .collect();
    std::fs::write(&sub, partial.join("\n") + "\n").unwrap();
    let o = fx.score(&sub, "partial", &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("--allow-missing-images"),
        "{}",
        stderr(&o)
    );
    assert!(!fx.path("partial").exists());
    let o = fx.score(&sub, "partial", &["--allow-missing-images"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fx.path("partial/report.json")).unwrap())
            .unwrap();
    assert!(
        r["warnings"][0]
            .as_str()
            .unwrap()
            .contains("1 of 16 images")
    );
    // Usage errors exit 2, a bad option value included (SPEC: 2 = usage).
    let o = stepsim(&[&"score", &"--submission", &sub]);
    assert_eq!(o.status.code(), Some(2));
    for bad in [
        "--match-radius-arcsec=-1",
        "--match-radius-arcsec=0",
        "--match-radius-arcsec=x",
    ] {
        let o = fx.score(&sub, "r", &[bad]);
        assert_eq!(o.status.code(), Some(2), "{bad}: {}", stderr(&o));
        assert!(stderr(&o).contains("--match-radius-arcsec"), "{bad}");
        assert!(!fx.path("r").exists(), "{bad}");
    }
}

#[test]
fn directory_submissions_and_the_leaderboard() {
    let fx = Fixture::new();
    // A directory of per-image CSV files without the image column, with an
    // extra column that is ignored with a warning.
    let rows = fx
        .run
        .submission(&|t: &TruthRow, _| (!t.is_star()).then_some((t.e1, t.e2, 1.0)));
    let dir = fx.path("perimage");
    std::fs::create_dir(&dir).unwrap();
    for (info, rows) in fx.run.index().images.iter().zip(&rows) {
        let mut s = String::from("x,y,e1,e2,flags,mag\n");
        for r in rows {
            s.push_str(&format!("{:?},{:?},{:?},{:?},0,24\n", r.x, r.y, r.e1, r.e2));
        }
        std::fs::write(dir.join(format!("{}.csv", info.image)), s).unwrap();
    }
    let o = fx.score(&dir, "best", &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fx.path("best/report.json")).unwrap())
            .unwrap();
    assert_eq!(r["submission"], "perimage");
    assert!(r["summary"]["m_mean"].as_f64().unwrap().abs() < 1e-6);
    // `flags` is documented (not warned about); `mag` is not.
    let w = r["warnings"][0].as_str().unwrap();
    assert!(w.contains("mag") && !w.contains("flags"), "{w}");
    let sub = fx.submission("worse.txt", 0.05);
    assert!(fx.score(&sub, "worse", &[]).status.success());
    let a = fx.path("worse/report.json");
    let b = fx.path("best/report.json");
    let lb = fx.path("lb");
    let o = stepsim(&[&"leaderboard", &a, &b, &"--out", &lb]);
    assert!(o.status.success(), "{}", stderr(&o));
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(lb.join("leaderboard.json")).unwrap())
            .unwrap();
    assert_eq!(j["entries"][0]["submission"], "perimage");
    assert_eq!(j["entries"][0]["rank"], 1);
    assert_eq!(j["entries"][1]["submission"], "worse.txt");
    let png = std::fs::read(lb.join("fig3_m_sigma_c.png")).unwrap();
    assert!(stepsim_figure::png::decode(&png).is_some());
    let svg = std::fs::read_to_string(lb.join("fig3_m_sigma_c.svg")).unwrap();
    assert_eq!(
        svg.matches("<circle").count(),
        2,
        "one point per submission"
    );
    let md = std::fs::read_to_string(lb.join("leaderboard.md")).unwrap();
    assert!(md.find("perimage").unwrap() < md.find("worse.txt").unwrap());
    // An earlier leaderboard is not overwritten without --force (each file).
    for name in [
        "fig3_m_sigma_c.svg",
        "fig3_m_sigma_c.png",
        "leaderboard.md",
        "leaderboard.json",
    ] {
        let lb2 = fx.path("lb2");
        let _ = std::fs::remove_dir_all(&lb2);
        std::fs::create_dir(&lb2).unwrap();
        std::fs::write(lb2.join(name), "keep").unwrap();
        let o = stepsim(&[&"leaderboard", &a, &b, &"--out", &lb2]);
        assert_eq!(o.status.code(), Some(1), "{name}");
        assert!(stderr(&o).contains("already exists"), "{}", stderr(&o));
        assert_eq!(std::fs::read_to_string(lb2.join(name)).unwrap(), "keep");
        assert_eq!(std::fs::read_dir(&lb2).unwrap().count(), 1);
    }
    let o = stepsim(&[&"leaderboard", &a, &b, &"--out", &lb, &"--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = stepsim(&[&"leaderboard", &a, &fx.path("best/report.md")]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("report.md"));
}

#[test]
fn score_refuses_when_any_file_it_writes_exists() {
    let fx = Fixture::new();
    let sub = fx.submission("team.txt", 0.0);
    let out = fx.path("out");
    let all = stepsim_harness::output_paths(&out);
    assert_eq!(all.len(), 10);
    for p in &all {
        let _ = std::fs::remove_dir_all(&out);
        std::fs::create_dir(&out).unwrap();
        std::fs::write(p, "keep me").unwrap();
        let o = fx.score(&sub, "out", &[]);
        assert_eq!(o.status.code(), Some(1), "{}", p.display());
        assert_eq!(
            stderr(&o).trim_end(),
            format!(
                "stepsim: error: {}: already exists; pass --force to overwrite it",
                p.display()
            )
        );
        assert_eq!(std::fs::read_to_string(p).unwrap(), "keep me");
        assert_eq!(
            std::fs::read_dir(&out).unwrap().count(),
            1,
            "nothing else written"
        );
    }
    // With --force every file is replaced, and the list is what is written.
    assert!(fx.score(&sub, "out", &["--force"]).status.success());
    let mut written: Vec<PathBuf> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    written.sort();
    let mut want = all.clone();
    want.sort();
    assert_eq!(written, want);
}

/// A FITS table with the submission's columns and an extra complex column
/// `SPIN` (`M`); with `e1_tform_complex`, `E1` is complex too (fitsio cannot
/// write complex columns, so the table is written byte by byte).
fn fits_with_complex_column(rows: &[(String, f64, f64)], e1_tform_complex: bool) -> Vec<u8> {
    let ids: Vec<&str> = rows.iter().map(|r| r.0.as_str()).collect();
    let col = |f: fn(&(String, f64, f64)) -> f64| rows.iter().map(f).collect::<Vec<f64>>();
    let e1 = if e1_tform_complex {
        let mut c = zeros("E1", "M", 16, rows.len());
        for r in &mut c.rows {
            r[..8].copy_from_slice(&0.01f64.to_be_bytes());
        }
        c
    } else {
        doubles("E1", &vec![0.01; rows.len()])
    };
    fits_table(&[
        text("IMAGE", &ids),
        doubles("X", &col(|r| r.1)),
        doubles("Y", &col(|r| r.2)),
        e1,
        doubles("E2", &vec![0.0; rows.len()]),
        zeros("SPIN", "M", 16, rows.len()),
    ])
}

#[test]
fn hostile_submissions_exit_1_without_panic_hang_or_unbounded_read() {
    let fx = Fixture::new();
    let rows: Vec<(String, f64, f64)> = fx
        .run
        .index()
        .images
        .iter()
        .map(|i| (i.image.clone(), 10.0, 12.0))
        .collect();
    // An extra complex column is ignored with a warning (fitsio panicked).
    let p = fx.path("complex.fits");
    std::fs::write(&p, fits_with_complex_column(&rows, false)).unwrap();
    let o = fx.score(&p, "ok", &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("warning: columns ignored: spin"),
        "{}",
        stderr(&o)
    );
    // A complex e1 is refused by name.
    std::fs::write(&p, fits_with_complex_column(&rows, true)).unwrap();
    let o = fx.score(&p, "out", &[]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o)
            .contains("complex.fits, column `e1`: the column holds complex numbers (TFORM `M`)"),
        "{}",
        stderr(&o)
    );
    // A device and a FIFO: refused at once (the FIFO used to hang).
    let o = fx.score(Path::new("/dev/zero"), "out", &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("/dev/zero: not a regular file (a device)"),
        "{}",
        stderr(&o)
    );
    let fifo = fx.path("fifo.txt");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let o = fx.score(&fifo, "out", &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("fifo.txt: not a regular file (a FIFO)"),
        "{}",
        stderr(&o)
    );
    // A 300 MiB file (sparse: no disk used) is refused by its size.
    let big = fx.path("big.txt");
    std::fs::File::create(&big)
        .unwrap()
        .set_len(300 << 20)
        .unwrap();
    let o = fx.score(&big, "out", &[]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("big.txt: larger than the limit of 256 MiB (the file)"),
        "{}",
        stderr(&o)
    );
    assert!(!fx.path("out").exists(), "nothing written");
}

#[test]
fn the_leaderboard_ranks_one_run_and_one_radius_with_escaped_names() {
    let fx = Fixture::new();
    let sub = fx.submission("a.txt", 0.0);
    assert!(
        fx.score(
            &sub,
            "a",
            &["--name", "x|y`z`<script>alert(1)</script>\nnext"]
        )
        .status
        .success()
    );
    assert!(fx.score(&sub, "b", &[]).status.success());
    assert!(
        fx.score(
            &sub,
            "r2",
            &["--match-radius-arcsec", "2", "--name", "wide"]
        )
        .status
        .success()
    );
    assert!(fx.score(&sub, "same", &[]).status.success());
    let a = fx.path("a/report.json");
    let b = fx.path("b/report.json");
    // Names cannot break the table or inject HTML.
    let o = stepsim(&[&"leaderboard", &a, &b]);
    assert!(o.status.success(), "{}", stderr(&o));
    let md = String::from_utf8(o.stdout).unwrap();
    let row = md.lines().find(|l| l.contains("script")).unwrap();
    assert!(
        row.contains(" | x\\|y\\`z\\`&lt;script&gt;alert(1)&lt;/script&gt; next | "),
        "{row}"
    );
    let other_row = md.lines().find(|l| l.contains("a.txt")).unwrap();
    assert_eq!(row.matches(" | ").count(), other_row.matches(" | ").count());
    assert!(!md.contains("<script>"));
    let report_md = std::fs::read_to_string(fx.path("a/report.md")).unwrap();
    assert!(
        report_md.starts_with("# Score of x\\|y\\`z\\`&lt;script&gt;"),
        "{report_md}"
    );
    // Another radius, the same file twice, the same name twice.
    let cases: [(&Path, &Path, String); 3] = [
        (
            &a,
            &fx.path("r2/report.json"),
            format!(
                "{}: matched within 2 arcsec, {} within 1 arcsec; a leaderboard compares one \
                 match radius",
                fx.path("r2/report.json").display(),
                a.display()
            ),
        ),
        (
            &b,
            &b,
            format!("{}: given twice (also as {})", b.display(), b.display()),
        ),
        (
            &b,
            &fx.path("same/report.json"),
            format!(
                "{}: submission `a.txt` is also the name in {}; score one of them again with \
                 another --name",
                fx.path("same/report.json").display(),
                b.display()
            ),
        ),
    ];
    for (x, y, want) in cases {
        let o = stepsim(&[&"leaderboard", &x, &y]);
        assert_eq!(o.status.code(), Some(1));
        assert_eq!(stderr(&o).trim_end(), format!("stepsim: error: {want}"));
    }
    // Isolated galaxies classed in another plane (a lensed run scored
    // before and after the source plane), and a plane that is neither.
    let mut lensed: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&b).unwrap()).unwrap();
    lensed["isolation_plane"] = "source".into();
    let lensed_path = fx.path("lensed.json");
    std::fs::write(&lensed_path, lensed.to_string()).unwrap();
    let o = stepsim(&[&"leaderboard", &a, &lensed_path]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("classes its isolated galaxies in the source plane"),
        "{}",
        stderr(&o)
    );
    lensed["isolation_plane"] = "sideways".into();
    std::fs::write(&lensed_path, lensed.to_string()).unwrap();
    let o = stepsim(&[&"leaderboard", &a, &lensed_path]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("lensed.json"), "{}", stderr(&o));
    // Another run (other shears, so another datasets.json).
    let other = tempfile::tempdir().unwrap();
    let mut spec = SynthSpec::small(2);
    spec.psfs.truncate(2);
    spec.shears.truncate(3);
    let run2 = make_run(&spec);
    let other_run = RunDir::new(other.path());
    run2.write(other_run.private().path()).unwrap();
    let rows2 = run2.submission(&|t: &TruthRow, _| Some((t.e1, t.e2, 1.0)));
    let sub2 = other.path().join("s2.txt");
    std::fs::write(&sub2, submission_text(&run2.index(), &rows2)).unwrap();
    let o = stepsim(&[
        &"score",
        &"--truth",
        &other_run.private().path(),
        &"--submission",
        &sub2,
        &"--out",
        &other.path().join("o"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let c = other.path().join("o/report.json");
    let o = stepsim(&[&"leaderboard", &a, &c]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains(&format!(
            "{}: scored against another run than {}",
            c.display(),
            a.display()
        )) && e.contains("a leaderboard ranks the submissions of one run"),
        "{e}"
    );
    // A device as a report: refused at once, not read forever.
    let o = stepsim(&[&"leaderboard", &a, &"/dev/zero"]);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(
        stderr(&o).trim_end(),
        "stepsim: error: /dev/zero: not a regular file (a device); only regular files are read"
    );
    // A report from before the run identity: score again.
    let mut old: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&b).unwrap()).unwrap();
    old.as_object_mut().unwrap().remove("run");
    let oldp = fx.path("old.json");
    std::fs::write(&oldp, old.to_string()).unwrap();
    let o = stepsim(&[&"leaderboard", &a, &oldp]);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(
        stderr(&o).trim_end(),
        format!(
            "stepsim: error: {}: this report has no `run` key (the run's identity): it was \
             written by an earlier stepsim; score the submission again to rank it",
            oldp.display()
        )
    );
}

#[test]
fn a_run_with_lensed_positions_classes_isolated_galaxies_in_the_source_plane() {
    // The same truth and submission scored as a run whose positions are
    // lensed (private/config.json says so) and as one whose are not. The
    // submission measures g exactly on the galaxies isolated in the source
    // plane of their dataset and 0.8 g on the others, so m_isolated is 0
    // exactly when the harness classes in the source plane; in the image
    // plane some galaxies change class at g ≠ 0 (neighbours at 12–28 px
    // about the 15-px radius) and m_isolated is not 0.
    use stepsim_harness::{Isolation, Plane, isolated};
    let fx = Fixture::new();
    let index = fx.run.index();
    let mut iso = std::collections::HashSet::new();
    for (info, t) in index.images.iter().zip(&fx.run.truth) {
        let ds = &fx.run.datasets.datasets[info.dataset];
        let class = Isolation::standard(
            fx.run.datasets.pixel_scale_arcsec,
            Plane::Source {
                g1: ds.g1,
                g2: ds.g2,
            },
        );
        for (row, ok) in t.iter().zip(isolated(t, class)) {
            if ok {
                iso.insert((info.dataset, row.x.to_bits(), row.y.to_bits()));
            }
        }
    }
    let ds = fx.run.datasets.datasets.clone();
    let rows = fx.run.submission(&|t: &TruthRow, d| {
        let g = (ds[d].g1, ds[d].g2);
        if t.is_star() {
            None
        } else if iso.contains(&(d, t.x.to_bits(), t.y.to_bits())) {
            Some((g.0, g.1, 1.0))
        } else {
            Some((0.8 * g.0, 0.8 * g.1, 1.0))
        }
    });
    let sub = fx.path("sub.txt");
    std::fs::write(&sub, submission_text(&index, &rows)).unwrap();
    let report = |out: &str| -> serde_json::Value {
        let o = fx.score(&sub, out, &[]);
        assert!(o.status.success(), "{}", stderr(&o));
        let text = std::fs::read_to_string(fx.path(&format!("{out}/report.json"))).unwrap();
        serde_json::from_str(&text).unwrap()
    };
    let image = report("image");
    let config = fx.path("private/config.json");
    std::fs::write(&config, r#"{"population": {"lens_positions": true}}"#).unwrap();
    let source = report("source");
    assert_eq!(image["isolation_plane"], "image");
    assert_eq!(source["isolation_plane"], "source");
    for (pi, ps) in image["psfs"]
        .as_array()
        .unwrap()
        .iter()
        .zip(source["psfs"].as_array().unwrap())
    {
        let (mi, ms) = (
            pi["m_isolated"].as_f64().unwrap(),
            ps["m_isolated"].as_f64().unwrap(),
        );
        assert!(ms.abs() < 1e-12, "source plane: {ms}");
        assert!(mi.abs() > 1e-4, "image plane: {mi}");
        // The whole catalogue's m does not depend on the class.
        assert_eq!(pi["m"], ps["m"]);
    }
    // A config.json that does not say true or false is refused by name.
    std::fs::write(&config, r#"{"population": {"lens_positions": "yes"}}"#).unwrap();
    let o = fx.score(&sub, "refused", &[]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("config.json")
            && e.contains("population.lens_positions is a string, not true or false")
            && !e.contains("yes"),
        "{e}"
    );
    assert!(!fx.path("refused").exists());
}

#[test]
fn combine_joins_reports_of_runs_with_different_psfs() {
    // One run scored; a second report made from it by renaming its PSFs
    // stands for a run of other PSFs. The combined summary is the summary
    // of all four PSF rows; bad input exits 1 naming the file.
    let fx = Fixture::new();
    let sub = fx.submission("team.txt", 0.02);
    let o = fx.score(&sub, "a", &["--bootstrap-resamples", "0"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(fx.path("a/report.json")).unwrap();
    let mut b: serde_json::Value = serde_json::from_str(&text).unwrap();
    for p in b["psfs"].as_array_mut().unwrap() {
        let name = format!("{}-b", p["psf"].as_str().unwrap());
        p["psf"] = name.into();
        p["m"] = (p["m"].as_f64().unwrap() + 0.1).into();
    }
    for d in b["datasets"].as_array_mut().unwrap() {
        let (id, psf) = (d["dataset"].as_str().unwrap(), d["psf"].as_str().unwrap());
        let (id, psf) = (format!("{id}b"), format!("{psf}-b"));
        d["dataset"] = id.into();
        d["psf"] = psf.into();
    }
    b["run"] = "sha256:other".into();
    std::fs::create_dir(fx.path("b")).unwrap();
    std::fs::write(fx.path("b/report.json"), b.to_string()).unwrap();
    let (a_dir, b_json, out) = (fx.path("a"), fx.path("b/report.json"), fx.path("ab"));
    let o = stepsim(&[&"score", &"--combine", &a_dir, &b_json, &"--out", &out]);
    assert!(o.status.success(), "{}", stderr(&o));
    let c: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let a: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(c["psfs"].as_array().unwrap().len(), 4);
    // ⟨m⟩ over four PSFs: the first report's ⟨m⟩ + 0.05.
    let want = a["summary"]["m_mean"].as_f64().unwrap() + 0.05;
    assert!((c["summary"]["m_mean"].as_f64().unwrap() - want).abs() < 1e-12);
    assert!(c["summary"].get("bootstrap").is_none());
    assert!(c["run"].as_str().unwrap().starts_with("combined:sha256:"));
    for f in ["report.md", "fig2_shear_response.png", "fig3_m_sigma_c.png"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    // The same PSF in two reports (another run, other datasets): refused,
    // naming the second file; nothing written.
    let mut c: serde_json::Value = serde_json::from_str(&text).unwrap();
    for d in c["datasets"].as_array_mut().unwrap() {
        let id = format!("{}c", d["dataset"].as_str().unwrap());
        d["dataset"] = id.into();
    }
    c["run"] = "sha256:third".into();
    let c_json = fx.path("c.json");
    std::fs::write(&c_json, c.to_string()).unwrap();
    let out2 = fx.path("aa");
    let o = stepsim(&[&"score", &"--combine", &a_dir, &c_json, &"--out", &out2]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("is also in"), "{}", stderr(&o));
    assert!(!out2.exists());
    // Not a report: the file and the JSON position.
    std::fs::write(fx.path("bad.json"), "{\"submission\": \n [").unwrap();
    let bad = fx.path("bad.json");
    let o = stepsim(&[&"score", &"--combine", &a_dir, &bad, &"--out", &out2]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("bad.json") && stderr(&o).contains("line 2"),
        "{}",
        stderr(&o)
    );
    // A report given twice, even under two names: refused.
    let o = stepsim(&[
        &"score",
        &"--combine",
        &a_dir,
        &fx.path("a/report.json"),
        &"--out",
        &out2,
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("given twice"), "{}", stderr(&o));
    // --combine with a radius (the reports carry theirs) is a usage error.
    let o = stepsim(&[
        &"score",
        &"--combine",
        &a_dir,
        &b_json,
        &"--match-radius-arcsec",
        &"2",
        &"--out",
        &out2,
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    // --combine with --truth is a usage error (exit 2).
    let truth = fx.path("private");
    let o = stepsim(&[
        &"score",
        &"--combine",
        &a_dir,
        &b_json,
        &"--truth",
        &truth,
        &"--out",
        &out2,
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
}

#[test]
fn the_submission_limit_follows_the_option() {
    // The run's own limit (256 MiB for this small run, the floor) is
    // overridden by --max-submission-bytes: a file of exactly the limit is
    // scored, one byte more is refused naming the file and the limit.
    let fx = Fixture::new();
    let sub = fx.submission("limit.txt", 0.0);
    let n = std::fs::metadata(&sub).unwrap().len();
    let at = n.to_string();
    let o = fx.score(&sub, "ok", &["--max-submission-bytes", &at]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(fx.path("ok/report.json").exists());
    let below = (n - 1).to_string();
    let o = fx.score(&sub, "no", &["--max-submission-bytes", &below]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains(&format!(
            "limit.txt: larger than the limit of {} (the file); refused without reading it",
            stepsim_harness::show_bytes(n - 1)
        )),
        "{}",
        stderr(&o)
    );
    assert!(!fx.path("no").exists(), "nothing written");
    // Not a number of bytes: a usage error.
    let o = fx.score(&sub, "bad", &["--max-submission-bytes", "lots"]);
    assert_eq!(o.status.code(), Some(2));
}
