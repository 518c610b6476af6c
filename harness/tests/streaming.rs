//! The streamed submission reader and scorer (issue #23): the same reports
//! as the whole-file twin on every form, at most one buffer of rows held,
//! the limit that follows the run, and gzip streams checked member by
//! member.

use crate::common;

use common::{doubles, fits_table, gzip, text};
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;
use stepsim_contract::run_dir::RunDir;
use stepsim_harness::{
    ImageIndex, SUBMISSION_BYTES_PER_IMAGE, SUBMISSION_BYTES_PER_TRUTH_ROW, ScoreOptions, SubRow,
    load_truth_set, prepare, read_submission_limited, read_submission_slow,
    read_submission_spilled, run_submission_limit, score, score_slow,
};
use stepsim_testkit::synthetic::{SynthRun, SynthSpec, make_run, submission_text};

struct Fixture {
    dir: tempfile::TempDir,
    run: SynthRun,
    rows: Vec<Vec<SubRow>>,
}

impl Fixture {
    /// 60 images (6 PSFs × 5 shears × 2 fields), a submission with a bias,
    /// varied weights, positions off by a fraction of a pixel, and a false
    /// detection per image.
    fn new() -> Self {
        let mut spec = SynthSpec::small(2);
        spec.shape_noise = true;
        let run = make_run(&spec);
        let dir = tempfile::tempdir().unwrap();
        run.write(RunDir::new(dir.path()).private().path()).unwrap();
        let mut rows = run.submission(&|t, d| {
            Some((
                t.e1 * 1.03 + 0.0007 * d as f64,
                t.e2 * 0.98,
                0.5 + (t.x * 7.0).rem_euclid(1.0),
            ))
        });
        for (i, im) in rows.iter_mut().enumerate() {
            for (k, r) in im.iter_mut().enumerate() {
                r.x += 0.013 * (k % 7) as f64;
                r.y -= 0.011 * (k % 5) as f64;
            }
            im.push(SubRow {
                x: 3.25 + i as f64,
                y: 150.5,
                e1: 0.3,
                e2: -0.2,
                weight: 1.0,
                line: 0,
            });
        }
        Self { dir, run, rows }
    }

    fn private(&self) -> PathBuf {
        RunDir::new(self.dir.path()).private().path().to_path_buf()
    }

    fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    fn index(&self) -> ImageIndex {
        self.run.index()
    }

    fn text(&self) -> String {
        submission_text(&self.index(), &self.rows)
    }

    fn csv(&self) -> String {
        let idx = self.index();
        let mut s = String::from("image,x,y,e1,e2,weight\r\n");
        for (info, rows) in idx.images.iter().zip(&self.rows) {
            for r in rows {
                s.push_str(&format!(
                    "\"{}\", {:?},{:?},{:?},{:?},{:?}\r\n",
                    info.image, r.x, r.y, r.e1, r.e2, r.weight
                ));
            }
        }
        s
    }

    fn fits(&self) -> Vec<u8> {
        let idx = self.index();
        let mut ids = Vec::new();
        let mut cols: [Vec<f64>; 5] = Default::default();
        for (info, rows) in idx.images.iter().zip(&self.rows) {
            for r in rows {
                ids.push(info.image.as_str());
                for (c, v) in cols.iter_mut().zip([r.x, r.y, r.e1, r.e2, r.weight]) {
                    c.push(v);
                }
            }
        }
        fits_table(&[
            text("IMAGE", &ids),
            doubles("X", &cols[0]),
            doubles("Y", &cols[1]),
            doubles("E1", &cols[2]),
            doubles("E2", &cols[3]),
            doubles("WEIGHT", &cols[4]),
        ])
    }

    fn opts(&self, sub: &Path) -> ScoreOptions {
        let mut o = ScoreOptions::new(self.private(), sub);
        o.bootstrap_resamples = 40;
        o
    }

    /// Scores `sub` streamed and whole; asserts identical JSON; returns it.
    fn same_report(&self, sub: &Path) -> String {
        let a = score(&self.opts(sub)).unwrap_or_else(|e| panic!("{}: {e}", sub.display()));
        let b = score_slow(&self.opts(sub)).unwrap();
        let (ja, jb) = (
            serde_json::to_string_pretty(&a).unwrap(),
            serde_json::to_string_pretty(&b).unwrap(),
        );
        assert_eq!(ja, jb, "{}", sub.display());
        assert!(a.summary.m_mean.is_some() && a.summary.sigma_c.is_some());
        assert!(a.summary.bootstrap.is_some());
        ja
    }
}

/// Every line after the header in a scrambled (deterministic) order.
fn unsorted(text: &str) -> String {
    let mut lines: Vec<&str> = text.lines().collect();
    let header = lines.remove(0);
    let mut keyed: Vec<(u64, &str)> = lines
        .iter()
        .enumerate()
        .map(|(k, l)| {
            (
                (k as u64)
                    .wrapping_mul(0x9e37_79b9_7f4a_7c15)
                    .rotate_left(17),
                *l,
            )
        })
        .collect();
    keyed.sort();
    let mut s = format!("{header}\n");
    for (_, l) in keyed {
        s.push_str(l);
        s.push('\n');
    }
    s
}

#[test]
fn streamed_reports_equal_the_whole_file_twin_in_every_form() {
    let fx = Fixture::new();
    let text = fx.text();
    let mut forms: Vec<(&str, Vec<u8>)> = vec![
        ("s.txt", text.clone().into_bytes()),
        ("s.csv", fx.csv().into_bytes()),
        ("s.fits", fx.fits()),
        ("s.txt.gz", gzip(text.as_bytes(), 6)),
        ("s.fits.gz", gzip(&fx.fits(), 6)),
        ("u.txt", unsorted(&text).into_bytes()),
    ];
    // Three gzip members, split inside a line.
    let b = text.as_bytes();
    let (m1, m2) = (b.len() / 3 + 5, 2 * b.len() / 3 + 1);
    let mut multi = gzip(&b[..m1], 6);
    multi.extend(gzip(&b[m1..m2], 6));
    multi.extend(gzip(&b[m2..], 6));
    forms.push(("m.txt.gz", multi));
    let mut reports = Vec::new();
    for (name, bytes) in &forms {
        let p = fx.path(name);
        std::fs::write(&p, bytes).unwrap();
        let json = fx.same_report(&p);
        // The name differs; the figures do not.
        let v: serde_json::Value = serde_json::from_str(&json).unwrap();
        reports.push(v["summary"].clone());
    }
    // Text, CSV, FITS and gzip hold the same numbers in the same order, so
    // they score alike to the bit; the unsorted catalogue sums its rows in
    // another order, so alike to rounding.
    for (k, r) in reports.iter().enumerate() {
        for key in ["m_mean", "sigma_c"] {
            let (a, b) = (r[key].as_f64().unwrap(), reports[0][key].as_f64().unwrap());
            if forms[k].0 == "u.txt" {
                assert!((a - b).abs() < 1e-12, "{key}: {a} {b}");
            } else {
                assert_eq!(a, b, "{} {key}", forms[k].0);
            }
        }
    }
    // A directory of per-image tables, one of them gzip.
    let d = fx.path("dir");
    std::fs::create_dir(&d).unwrap();
    let idx = fx.index();
    for (k, (info, rows)) in idx.images.iter().zip(&fx.rows).enumerate() {
        let mut s = String::from("# x y e1 e2 weight\n");
        for r in rows {
            s.push_str(&format!(
                "{:?} {:?} {:?} {:?} {:?}\n",
                r.x, r.y, r.e1, r.e2, r.weight
            ));
        }
        if k == 3 {
            std::fs::write(
                d.join(format!("{}.txt.gz", info.image)),
                gzip(s.as_bytes(), 6),
            )
            .unwrap();
        } else {
            std::fs::write(d.join(format!("{}.txt", info.image)), s).unwrap();
        }
    }
    fx.same_report(&d);
}

#[test]
fn streamed_and_whole_readers_refuse_alike() {
    let fx = Fixture::new();
    let idx = fx.index();
    let text = fx.text();
    let lines: Vec<&str> = text.lines().collect();
    let image_of = |l: &str| l.split_whitespace().next().unwrap().to_owned();
    let n = lines.len();
    // A duplicate in a later image listed before an earlier image's
    // duplicate: the first in file order is named.
    let mut dup = lines.clone();
    dup.insert(n - 2, lines[n - 3]);
    dup.insert(40, lines[30]);
    let mut over = lines.clone();
    let first = image_of(lines[1]);
    over.push(Box::leak(
        format!("{first} 7.5 7.5 0.1 0.1 1e308").into_boxed_str(),
    ));
    over.push(Box::leak(
        format!("{first} 8.5 7.5 0.1 0.1 1e308").into_boxed_str(),
    ));
    over.push(lines[5]);
    let mut bad_row = lines.clone();
    bad_row.insert(90, "imX 1 1 0 0 1");
    let cases: Vec<(&str, String)> = vec![
        ("dup.txt", dup.join("\n")),
        ("over.txt", over.join("\n")),
        ("bad.txt", bad_row.join("\n")),
        ("empty.txt", "# image x y e1 e2\n\n".into()),
        ("none.txt", "\n\n".into()),
        (
            "long.txt",
            format!("# image x y e1 e2\n{}\n", "x".repeat(17 << 20)),
        ),
    ];
    for (name, body) in cases {
        let p = fx.path(name);
        std::fs::write(&p, &body).unwrap();
        let a = read_submission_limited(&p, &idx, 64 << 20)
            .unwrap_err()
            .to_string();
        let b = read_submission_slow(&p, &idx, 64 << 20)
            .unwrap_err()
            .to_string();
        if name == "long.txt" {
            assert!(
                a.contains("line 2") && a.contains("longer than 16 MiB"),
                "{a}"
            );
            continue;
        }
        assert_eq!(a, b, "{name}");
        assert!(a.starts_with(&p.display().to_string()), "{a}");
    }
    // The duplicate named is at the earlier line of the two.
    let e = read_submission_limited(&fx.path("dup.txt"), &idx, 64 << 20)
        .unwrap_err()
        .to_string();
    assert!(e.contains(":41:") || e.contains("line 41"), "{e}");
    let e = read_submission_limited(&fx.path("over.txt"), &idx, 64 << 20)
        .unwrap_err()
        .to_string();
    assert!(e.contains("duplicate row"), "a duplicate comes first: {e}");
}

#[test]
fn the_reader_holds_one_buffer_of_rows_not_the_catalogue() {
    // 12 images of 4096² with 3000 rows each, the images interleaved row by
    // row (the worst order for grouping).
    let mut spec = SynthSpec::small(1);
    spec.psfs.truncate(2);
    spec.shears.truncate(3);
    spec.width_px = 4096;
    spec.height_px = 4096;
    let run = make_run(&spec);
    let idx = run.index();
    assert_eq!(idx.images.len(), 6);
    let per_image = 3000usize;
    let mut s = String::from("# image x y e1 e2 weight\n");
    for k in 0..per_image {
        for info in &idx.images {
            let x = 1.0 + (k % 4000) as f64 + 0.25;
            let y = 1.0 + (k / 4000) as f64 + 0.5;
            s.push_str(&format!("{} {x} {y} 0.01 -0.02 1\n", info.image));
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("c.txt");
    std::fs::write(&p, &s).unwrap();
    let buffer = 1000;
    let sub = read_submission_spilled(&p, &idx, 64 << 20, buffer).unwrap();
    let whole = read_submission_slow(&p, &idx, 64 << 20).unwrap();
    assert_eq!(sub.n_rows(), per_image * idx.images.len());
    let held = sub.max_rows_held().unwrap();
    assert_eq!(held, buffer);
    assert!(held < per_image, "less than one image's rows held");
    assert_eq!(whole.max_rows_held(), None);
    for i in 0..idx.images.len() {
        assert_eq!(sub.image_rows(i).unwrap(), whole.image_rows(i).unwrap());
    }
    // The default buffer through the pipeline.
    let sub = read_submission_limited(&p, &idx, 64 << 20).unwrap();
    assert!(sub.max_rows_held().unwrap() <= stepsim_harness::DEFAULT_BUFFER_ROWS);
}

#[test]
fn the_limit_follows_the_run_and_the_option_overrides_it() {
    let fx = Fixture::new();
    let truth = load_truth_set(&fx.private()).unwrap();
    let n_truth: usize = fx.run.truth.iter().map(Vec::len).sum();
    let formula = SUBMISSION_BYTES_PER_TRUTH_ROW * n_truth as u64 + SUBMISSION_BYTES_PER_IMAGE * 60;
    assert!(formula < 256 << 20);
    assert_eq!(
        run_submission_limit(&truth).unwrap(),
        256 << 20,
        "the floor"
    );
    // A gzip submission that inflates to 300 MiB (blank lines after the
    // rows): refused at the small run's limit, 256 MiB, and scored when the
    // limit allows it.
    let mut text = fx.text().into_bytes();
    let pad = 300usize << 20;
    let blank = gzip(&vec![b'\n'; 1 << 20], 6);
    let mut g = gzip(&text, 6);
    for _ in 0..300 {
        g.extend_from_slice(&blank);
    }
    let p = fx.path("padded.txt.gz");
    std::fs::write(&p, &g).unwrap();
    let e = prepare(&fx.opts(&p)).unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "{}: larger than the limit of 256 MiB (after gzip decompression); refused without \
             reading it",
            p.display()
        )
    );
    let mut o = fx.opts(&p);
    o.max_submission_bytes = Some((text.len() + pad) as u64);
    let a = score(&o).unwrap();
    let plain = fx.path("plain.txt");
    std::fs::write(&plain, &text).unwrap();
    let b = score(&fx.opts(&plain)).unwrap();
    assert_eq!(a.summary, b.summary);
    o.max_submission_bytes = Some((text.len() + pad - 1) as u64);
    let e = prepare(&o).unwrap_err().to_string();
    assert!(
        e.starts_with(&p.display().to_string()) && e.contains("(after gzip decompression)"),
        "{e}"
    );
    // As stored: a limit one byte short of the file names it and the limit.
    let mut o = fx.opts(&plain);
    o.max_submission_bytes = Some(text.len() as u64 - 1);
    let e = prepare(&o).unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "{}: larger than the limit of {} bytes (the file); refused without reading it",
            plain.display(),
            text.len() - 1
        )
    );
    o.max_submission_bytes = Some(text.len() as u64);
    assert!(prepare(&o).is_ok());
    text.clear();
}

#[test]
fn the_run_limit_counts_the_truth_objects_from_the_headers() {
    // One image whose truth table has 1.2 million rows (a single 4-byte
    // column: the header's NAXIS2 is all the limit reads).
    let fx = Fixture::new();
    let truth = load_truth_set(&fx.private()).unwrap();
    let first = &truth.index.images[0].image;
    let p = truth.truth_path(first);
    std::fs::remove_file(&p).unwrap();
    {
        use fitsio::tables::{ColumnDataType, ColumnDescription};
        let mut f = fitsio::FitsFile::create(&p).open().unwrap();
        let col = ColumnDescription::new("kind")
            .with_type(ColumnDataType::Int)
            .create()
            .unwrap();
        let hdu = f
            .create_table(stepsim_contract::io::truth::TRUTH_EXTNAME, &[col])
            .unwrap();
        hdu.write_col(&mut f, "kind", &vec![0i32; 1_200_000])
            .unwrap();
    }
    let others: usize = fx.run.truth[1..].iter().map(Vec::len).sum();
    let want = SUBMISSION_BYTES_PER_TRUTH_ROW * (1_200_000 + others as u64)
        + SUBMISSION_BYTES_PER_IMAGE * 60;
    assert!(want > 256 << 20);
    assert_eq!(run_submission_limit(&truth).unwrap(), want);
    // A truth table that cannot be read is named.
    std::fs::write(&p, b"not fits").unwrap();
    let e = run_submission_limit(&truth).unwrap_err().to_string();
    assert!(e.contains(&format!("{first}.fits")), "{e}");
}

#[test]
fn gzip_members_are_checked_and_bounded() {
    let fx = Fixture::new();
    let idx = fx.index();
    let text = fx.text();
    // A corrupted CRC-32 is refused, naming the file.
    let mut g = gzip(text.as_bytes(), 6);
    let n = g.len();
    g[n - 8] ^= 0x01;
    let p = fx.path("crc.txt.gz");
    std::fs::write(&p, &g).unwrap();
    for e in [
        read_submission_limited(&p, &idx, 64 << 20).unwrap_err(),
        read_submission_slow(&p, &idx, 64 << 20).unwrap_err(),
    ] {
        assert_eq!(
            e.to_string(),
            format!(
                "{}: not a valid gzip file: the CRC-32 recorded in the gzip trailer is not that \
                 of the data (the file is corrupt)",
                p.display()
            )
        );
    }
    // So is a flipped bit in the data that still inflates.
    let mut g = gzip(text.as_bytes(), 6);
    let k = g.len() / 2;
    g[k] ^= 0x10;
    std::fs::write(&p, &g).unwrap();
    let e = read_submission_limited(&p, &idx, 64 << 20)
        .unwrap_err()
        .to_string();
    assert!(e.contains("not a valid gzip file"), "{e}");
    // 400 000 empty members (8 MB): refused at the member bound, at once.
    let empty = gzip(b"", 6);
    assert_eq!(empty.len(), 20);
    let mut bomb = gzip(text.as_bytes(), 6);
    for _ in 0..400_000 {
        bomb.extend_from_slice(&empty);
    }
    let p = fx.path("members.txt.gz");
    std::fs::File::create(&p).unwrap().write_all(&bomb).unwrap();
    let t = Instant::now();
    let e = read_submission_limited(&p, &idx, 64 << 20)
        .unwrap_err()
        .to_string();
    let secs = t.elapsed().as_secs_f64();
    assert_eq!(
        e,
        format!(
            "{}: not a valid gzip file: more than 65536 gzip members (the limit); compress the \
             file as one member",
            p.display()
        )
    );
    assert!(secs < 5.0, "{secs} s");
    assert_eq!(stepsim_harness::MAX_GZIP_MEMBERS, 65_536);
    // Exactly the bound reads.
    let mut ok = gzip(text.as_bytes(), 6);
    for _ in 1..65_536 {
        ok.extend_from_slice(&empty);
    }
    let p = fx.path("bound.txt.gz");
    std::fs::write(&p, &ok).unwrap();
    let sub = read_submission_limited(&p, &idx, 64 << 20).unwrap();
    assert_eq!(sub.n_rows(), fx.rows.iter().map(Vec::len).sum::<usize>());
}
