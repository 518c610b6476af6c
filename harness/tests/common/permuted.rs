//! One challenge run's truth in two orders, and a battery of refused
//! submissions (issue #23). Shared by `harness/tests/refusal_order.rs`
//! (through the library) and the root `tests/refusal_order.rs` (through
//! `stepsim score`), which include this file with `#[path]`.
//!
//! Truth `a` is the run as made (PSF-major, shears ascending, the public
//! part before the held-out part); truth `b` is the same run with the
//! datasets, and the images inside each dataset, listed in another order in
//! `datasets.json`: the same ids, the same truth files. A participant knows
//! the set of ids and nothing else, so every refusal must read the same
//! against both once the truth directory's path is replaced.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use stepsim_contract::run_dir::RunDir;
use stepsim_contract::run_layout::Datasets;
use stepsim_testkit::synthetic::{self, SynthRun, SynthSpec};

/// One submitted row: image id, x, y, e1, e2, weight.
pub type Row = (String, f64, f64, f64, f64, f64);

/// The run, its truth in two orders, and the submissions.
pub struct Pair {
    /// Holds everything.
    pub dir: tempfile::TempDir,
    /// The run as made.
    pub run: SynthRun,
    /// `RUN/private` in the order made.
    pub a: PathBuf,
    /// `RUN/private` in the permuted order.
    pub b: PathBuf,
    /// (name, file or directory) of each submission of the battery.
    pub subs: Vec<(String, PathBuf)>,
}

/// 2 PSFs × 3 shears public and 2 PSFs × 2 shears held out, 2 fields each:
/// 20 images. Ids `i<d>f<f>` (public) and `hi<d>f<f>` (held out).
fn the_run() -> SynthRun {
    let mut spec = SynthSpec::small(2);
    spec.psfs.truncate(2);
    spec.shears = vec![(0.0, 0.0), (0.01, 0.0), (0.05, 0.0)];
    synthetic::challenge_run(&spec, &[(0.031, -0.044), (-0.02, 0.07)], 99).2
}

/// The permuted `datasets.json`: datasets reversed then rotated by three
/// (public and held-out datasets interleaved), images of each dataset
/// reversed.
pub fn permute(d: &Datasets) -> Datasets {
    let mut p = d.clone();
    p.datasets.reverse();
    p.datasets.rotate_left(3);
    for e in &mut p.datasets {
        e.images.reverse();
    }
    p
}

/// Every row of a perfect catalogue of `run` (stars at weight 1), image by
/// image in run order.
pub fn perfect_rows(run: &SynthRun) -> Vec<Row> {
    let index = run.index();
    index
        .images
        .iter()
        .zip(&run.truth)
        .flat_map(|(info, rows)| {
            rows.iter().map(|t| {
                let (e1, e2) = if t.is_star() {
                    (0.0, 0.0)
                } else {
                    (t.e1, t.e2)
                };
                (info.image.clone(), t.x, t.y, e1, e2, 1.0)
            })
        })
        .collect()
}

/// Rows as a whitespace table with a `# image x y e1 e2 weight` header.
pub fn text_table(rows: &[Row]) -> String {
    let mut s = String::from("# image x y e1 e2 weight\n");
    for (id, x, y, e1, e2, w) in rows {
        s.push_str(&format!("{id} {x:?} {y:?} {e1:?} {e2:?} {w:?}\n"));
    }
    s
}

/// Rows as CSV.
pub fn csv_table(rows: &[Row]) -> String {
    let mut s = String::from("image,x,y,e1,e2,weight\n");
    for (id, x, y, e1, e2, w) in rows {
        s.push_str(&format!("{id},{x:?},{y:?},{e1:?},{e2:?},{w:?}\n"));
    }
    s
}

/// Writes a directory of per-image whitespace tables (no `image` column).
fn write_dir(dir: &Path, rows: &[Row]) {
    std::fs::create_dir_all(dir).unwrap();
    let mut by_image: std::collections::BTreeMap<&str, String> = Default::default();
    for (id, x, y, e1, e2, w) in rows {
        by_image
            .entry(id)
            .or_insert_with(|| "# x y e1 e2 weight\n".to_owned())
            .push_str(&format!("{x:?} {y:?} {e1:?} {e2:?} {w:?}\n"));
    }
    for (id, text) in by_image {
        std::fs::write(dir.join(format!("{id}.txt")), text).unwrap();
    }
}

/// Builds the pair and the battery; `fits` writes rows as a FITS table
/// (columns IMAGE, X, Y, E1, E2, WEIGHT).
pub fn pair(fits: &dyn Fn(&[Row]) -> Vec<u8>) -> Pair {
    let dir = tempfile::tempdir().unwrap();
    let run = the_run();
    let (run_a, run_b) = (
        RunDir::new(dir.path().join("a")),
        RunDir::new(dir.path().join("b")),
    );
    let (a, b) = (run_a.private(), run_b.private());
    run.write(a.path()).unwrap();
    std::fs::create_dir_all(b.truth_dir()).unwrap();
    std::fs::copy(a.config(), b.config()).unwrap();
    for e in std::fs::read_dir(a.truth_dir()).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), b.truth_dir().join(e.file_name())).unwrap();
    }
    let permuted = permute(&run.datasets);
    assert_ne!(
        serde_json::to_string(&permuted).unwrap(),
        serde_json::to_string(&run.datasets).unwrap()
    );
    std::fs::write(
        b.datasets(),
        serde_json::to_string_pretty(&permuted).unwrap(),
    )
    .unwrap();

    let all = perfect_rows(&run);
    let without = |drop: &dyn Fn(&str) -> bool| -> Vec<Row> {
        all.iter().filter(|r| !drop(&r.0)).cloned().collect()
    };
    // Several images across datasets and both parts: the first of them in
    // the run's order (`i000f001`) is not the smallest id (`hi001f000`).
    let several = ["i000f001", "i004f000", "i005f001", "hi001f000", "hi003f001"];
    let missing_several = without(&|id| several.contains(&id));
    let subs_dir = dir.path().join("subs");
    std::fs::create_dir_all(&subs_dir).unwrap();
    let mut subs: Vec<(String, PathBuf)> = Vec::new();
    let mut file = |name: &str, bytes: Vec<u8>| {
        let p = subs_dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        subs.push((name.to_owned(), p));
    };
    file("complete.txt", text_table(&all).into_bytes());
    file(
        "missing_one.txt",
        text_table(&without(&|id| id == "i003f001")).into_bytes(),
    );
    file(
        "missing_several.txt",
        text_table(&missing_several).into_bytes(),
    );
    file(
        "public_only.txt",
        text_table(&without(&|id| id.starts_with('h'))).into_bytes(),
    );
    file(
        "holdout_only.txt",
        text_table(&without(&|id| id.starts_with('i'))).into_bytes(),
    );
    file(
        "one_image.txt",
        text_table(&without(&|id| id != "i002f000")).into_bytes(),
    );
    let mut unknown = all.clone();
    unknown.insert(
        all.len() / 2,
        ("i999f000".into(), 10.0, 10.0, 0.0, 0.0, 1.0),
    );
    file("unknown_id.txt", text_table(&unknown).into_bytes());
    let mut unknown_missing = missing_several.clone();
    unknown_missing.push(("zz".into(), 10.0, 10.0, 0.0, 0.0, 1.0));
    file(
        "unknown_id_and_missing.txt",
        text_table(&unknown_missing).into_bytes(),
    );
    // Bad values on rows of two images (held-out first in the file, then
    // public), and the same with the lines the other way round.
    let bad_at = |rows: &mut Vec<Row>, id: &str, k: usize, f: &dyn Fn(&mut Row)| {
        let i = rows
            .iter()
            .enumerate()
            .filter(|(_, r)| r.0 == id)
            .nth(k)
            .unwrap()
            .0;
        f(&mut rows[i]);
    };
    let mut two_bad = all.clone();
    bad_at(&mut two_bad, "hi002f000", 3, &|r| r.3 = f64::NAN);
    bad_at(&mut two_bad, "i001f001", 5, &|r| r.1 = -7.0);
    let mut swapped = two_bad.clone();
    swapped.reverse();
    file("bad_values.txt", text_table(&two_bad).into_bytes());
    file("bad_values_swapped.txt", text_table(&swapped).into_bytes());
    let mut dup = all.clone();
    let i = dup.iter().position(|r| r.0 == "i004f001").unwrap();
    dup.push(dup[i + 2].clone());
    file("duplicate.txt", text_table(&dup).into_bytes());
    let mut heavy = all.clone();
    bad_at(&mut heavy, "hi000f001", 0, &|r| r.5 = 1e308);
    bad_at(&mut heavy, "hi000f001", 1, &|r| r.5 = 1e308);
    bad_at(&mut heavy, "i002f001", 0, &|r| r.5 = 1e308);
    bad_at(&mut heavy, "i002f001", 1, &|r| r.5 = 1e308);
    file("weight_overflow.txt", text_table(&heavy).into_bytes());
    let body = |t: String| t.split_once('\n').unwrap().1.to_owned();
    file(
        "no_e2.txt",
        format!("# image x y e1 weight flags\n{}", body(text_table(&all))).into_bytes(),
    );
    file(
        "x_twice.txt",
        format!("# image x y e1 e2 x\n{}", body(text_table(&all))).into_bytes(),
    );
    let wide: Vec<String> = (0..2000).map(|k| format!("c{k}")).collect();
    file(
        "too_many_columns.txt",
        format!("# image x y e1 e2 weight {}\n", wide.join(" ")).into_bytes(),
    );
    file(
        "missing_several.csv",
        csv_table(&missing_several).into_bytes(),
    );
    file("missing_several.fits", fits(&missing_several));
    let mut fits_unknown = all.clone();
    fits_unknown[17].0 = "i003f009".into();
    file("unknown_id.fits", fits(&fits_unknown));
    file("empty.txt", b"# image x y e1 e2\n".to_vec());

    let mut dir_sub = |name: &str, rows: &[Row], extra: &[(&str, &str)]| {
        let p = subs_dir.join(name);
        write_dir(&p, rows);
        for (f, text) in extra {
            std::fs::write(p.join(f), text).unwrap();
        }
        subs.push((name.to_owned(), p));
    };
    dir_sub("dir_complete", &all, &[]);
    dir_sub("dir_missing_several", &missing_several, &[]);
    dir_sub(
        "dir_second_file",
        &all,
        &[("i003f000.csv", "x,y,e1,e2\n10,10,0,0\n")],
    );
    dir_sub(
        "dir_unknown",
        &all,
        &[("i009f000.txt", "# x y e1 e2\n1 1 0 0\n")],
    );
    dir_sub(
        "dir_bad_values",
        &all,
        &[
            ("hi002f001.txt", "# x y e1 e2\n1 1 nan 0\n"),
            ("i001f000.txt", "# x y e1 e2\n1 1 0 2e9\n"),
        ],
    );
    Pair {
        a: a.path().to_path_buf(),
        b: b.path().to_path_buf(),
        dir,
        run,
        subs,
    }
}

/// `message` with the truth directory `truth` (and its run directory)
/// replaced by `<truth>`.
pub fn normalise(message: &str, truth: &Path) -> String {
    message.replace(&truth.display().to_string(), "<truth>")
}
