//! Header shapes that used to take minutes (issue #23, the column bomb): a
//! 1.5 MB header naming 200 000 columns took the format check 208 s,
//! because every name was compared with all the names before it. Headers
//! are now capped at `MAX_COLUMNS` names, refused (naming the file, the line
//! and the count) before a name is compared, and every check is linear in
//! the size of the header. Times are asserted loosely (a debug build on a
//! busy machine): a refusal in well under a second.

use crate::common;

use common::{Col, doubles, fits_table, gzip, index, text};
use std::io::Write as _;
use std::path::Path;
use std::time::{Duration, Instant};
use stepsim_harness::{MAX_COLUMNS, parse_file, read_submission};

/// A loose bound for work that is linear in a few MB.
const QUICK: Duration = Duration::from_millis(900);

fn wide_names(n: usize) -> Vec<String> {
    let mut v: Vec<String> = ["image", "x", "y", "e1", "e2"]
        .iter()
        .map(|s| (*s).to_owned())
        .collect();
    v.extend((v.len()..n).map(|k| format!("col{k:06}")));
    v
}

fn refused_quickly(path: &Path, bytes: &[u8]) -> String {
    let t = Instant::now();
    let e = parse_file(path, bytes, &index(), None)
        .unwrap_err()
        .to_string();
    let took = t.elapsed();
    eprintln!(
        "{}: {} bytes refused in {took:?}",
        path.display(),
        bytes.len()
    );
    assert!(took < QUICK, "{} bytes refused in {took:?}", bytes.len());
    e
}

#[test]
fn a_header_of_200_000_columns_is_refused_in_well_under_a_second() {
    for n in [10_000usize, 100_000, 200_000] {
        let names = wide_names(n);
        let ws = format!("# {}\nimA 1 1 0 0\n", names.join(" "));
        if n == 200_000 {
            assert!(ws.len() > 1_500_000, "{}", ws.len());
        }
        let e = refused_quickly(Path::new("wide.txt"), ws.as_bytes());
        assert_eq!(
            e,
            format!(
                "wide.txt: line 1: the header names {n} columns, more than the \
                 {MAX_COLUMNS} a submission may have"
            )
        );
        // CSV, after blank lines and a byte-order mark.
        let csv = format!("\u{feff}\n\n{}\nimA,1,1,0,0\n", names.join(","));
        let e = refused_quickly(Path::new("wide.csv"), csv.as_bytes());
        assert!(
            e.starts_with(&format!("wide.csv: line 3: the header names {n} columns")),
            "{e}"
        );
        // Gzip-compressed.
        let e = refused_quickly(Path::new("wide.txt.gz"), &gzip(ws.as_bytes(), 1));
        assert!(
            e.contains(&format!("line 1: the header names {n} columns")),
            "{e}"
        );
    }
}

#[test]
fn the_cap_is_exact_and_the_columns_under_it_are_read() {
    let ok = |n: usize| {
        let names = wide_names(n);
        let row = vec!["0"; n - 5].join(" ");
        format!(
            "# {}\nimA 1 1 0 0 {row}\nimB 2 2 0 0 {row}\n",
            names.join(" ")
        )
    };
    let t = Instant::now();
    let fr = parse_file(
        Path::new("w.txt"),
        ok(MAX_COLUMNS).as_bytes(),
        &index(),
        None,
    )
    .unwrap();
    assert!(t.elapsed() < QUICK, "{:?}", t.elapsed());
    assert_eq!(fr.rows.len(), 2);
    assert_eq!(fr.ignored_columns.len(), MAX_COLUMNS - 5);
    let e = parse_file(
        Path::new("w.txt"),
        ok(MAX_COLUMNS + 1).as_bytes(),
        &index(),
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.starts_with("w.txt: line 1: the header names 1025 columns, more than the 1024"),
        "{e}"
    );
}

#[test]
fn a_wide_file_in_a_directory_is_refused_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("imA.txt"), "# x y e1 e2\n1 1 0 0\n").unwrap();
    let mut names = vec!["x".to_owned(), "y".into(), "e1".into(), "e2".into()];
    names.extend((0..200_000).map(|k| format!("c{k}")));
    let mut f = std::fs::File::create(dir.path().join("imB.txt")).unwrap();
    writeln!(f, "# {}\n1 1 0 0", names.join(" ")).unwrap();
    drop(f);
    let t = Instant::now();
    let e = read_submission(dir.path(), &index())
        .unwrap_err()
        .to_string();
    assert!(t.elapsed() < QUICK, "{:?}", t.elapsed());
    let want = format!(
        "{}: line 1: the header names 200004 columns",
        dir.path().join("imB.txt").display()
    );
    assert!(e.starts_with(&want), "{e}");
}

#[test]
fn long_names_with_a_common_prefix_are_compared_in_linear_time() {
    // 1000 names of 30 kB, the last a repeat of the first. When the names
    // differ in their last characters, comparing each with all before it
    // reads 15 GB; when they differ in their first, a few kB. Linear
    // checks take the same time for both (the same bytes); the bound is
    // relative, so that a busy machine does not fail it.
    let len = 30_000;
    let header = |common_prefix: bool| {
        let mut names: Vec<String> = ["image", "x", "y", "e1", "e2"]
            .iter()
            .map(|s| (*s).to_owned())
            .collect();
        let pad = "p".repeat(len);
        let name = |k: usize| {
            if common_prefix {
                format!("{pad}{k:04}")
            } else {
                format!("{k:04}{pad}")
            }
        };
        names.extend((0..995).map(name));
        names.push(name(0).to_uppercase());
        format!("# {}\n", names.join(" "))
    };
    let time = |text: &str| {
        let t = Instant::now();
        let e = parse_file(Path::new("long.txt"), text.as_bytes(), &index(), None)
            .unwrap_err()
            .to_string();
        (t.elapsed(), e)
    };
    let (early, text) = (header(false), header(true));
    let (t_early, _) = time(&early);
    let (t_late, e) = time(&text);
    assert!(
        t_late < 2 * t_early + Duration::from_millis(300),
        "{t_late:?} against {t_early:?}"
    );
    // The name is quoted short.
    assert!(
        e.starts_with(&format!(
            "long.txt: line 1, column `{}… (30004 bytes)`: column named twice",
            "p".repeat(64)
        )),
        "{}",
        &e[..e.len().min(300)]
    );
}

#[test]
fn messages_quote_long_values_short() {
    let id = "z".repeat(20_000_000);
    let t = Instant::now();
    let e = parse_file(
        Path::new("s.txt"),
        format!("# image x y e1 e2\n{id} 1 1 0 0\n").as_bytes(),
        &index(),
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());
    assert_eq!(
        e,
        format!(
            "s.txt: line 2, column `image`: unknown image id `{}… (20000000 bytes)`",
            "z".repeat(64)
        )
    );
    let e = parse_file(
        Path::new("s.txt"),
        format!("# image x y e1 e2\nimA {id} 1 0 0\n").as_bytes(),
        &index(),
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(e.ends_with("as a number") && e.len() < 200, "{e}");
    // A missing column among many: the header is quoted in part.
    let names = wide_names(1000);
    let e = parse_file(
        Path::new("s.txt"),
        format!("# {}\n", names[1..].join(" ")).as_bytes(),
        &index(),
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("required column missing (header has: x y e1 e2 col000005"),
        "{e}"
    );
    assert!(e.ends_with("… (999 columns))") && e.len() < 400, "{e}");
}

#[test]
fn many_comment_lines_and_a_very_long_line_are_read_in_linear_time() {
    let mut s = String::from("# image x y e1 e2\n");
    for _ in 0..1_000_000 {
        s.push_str("# a comment\n");
    }
    s.push_str("imA 1 1 0 0\n");
    let t = Instant::now();
    let fr = parse_file(Path::new("c.txt"), s.as_bytes(), &index(), None).unwrap();
    assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());
    assert_eq!(fr.rows[0].1.line, 1_000_002);
    // One data line of 500 000 fields: refused on its count (linear: 0.3 s
    // for a million fields, 1.2 s for four million, on a loaded machine).
    let mut s = String::from("image,x,y,e1,e2\nimA,1,1,0,0");
    s.push_str(&",0".repeat(500_000));
    let t = Instant::now();
    let e = parse_file(Path::new("l.csv"), s.as_bytes(), &index(), None)
        .unwrap_err()
        .to_string();
    assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());
    assert_eq!(e, "l.csv: line 2: expected 5 fields, found 500005");
}

fn fits_of(n_cols: usize) -> Vec<u8> {
    let mut cols: Vec<Col> = vec![
        text("IMAGE", &["imA", "imB"]),
        doubles("X", &[1.0, 2.0]),
        doubles("Y", &[1.0, 2.0]),
        doubles("E1", &[0.0, 0.0]),
        doubles("E2", &[0.0, 0.0]),
    ];
    for k in cols.len()..n_cols {
        let name: &'static str = Box::leak(format!("C{k}").into_boxed_str());
        cols.push(doubles(name, &[0.0, 0.0]));
    }
    fits_table(&cols)
}

#[test]
fn a_fits_table_of_999_columns_is_read_and_one_beyond_the_cap_refused() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("wide.fits");
    let bytes = fits_of(999);
    std::fs::write(&p, &bytes).unwrap();
    let t = Instant::now();
    let fr = parse_file(&p, &bytes, &index(), None).unwrap();
    assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());
    assert_eq!(fr.rows.len(), 2);
    assert_eq!(fr.ignored_columns.len(), 994);
    // Beyond the cap (and the standard's 999): refused quickly, naming the
    // file.
    for n in [1100, 2000, 20_000] {
        let p = dir.path().join(format!("wide{n}.fits"));
        let bytes = fits_of(n);
        std::fs::write(&p, &bytes).unwrap();
        let t = Instant::now();
        let e = parse_file(&p, &bytes, &index(), None)
            .unwrap_err()
            .to_string();
        assert!(t.elapsed() < Duration::from_secs(2), "{:?}", t.elapsed());
        eprintln!("{n} FITS columns: {e}");
        assert_eq!(
            e,
            format!(
                "{}: the table has {n} columns, more than the {MAX_COLUMNS} a submission may have",
                p.display()
            )
        );
    }
}

/// What the reader must say about a header of `names` (lower-case
/// comparison), by the rules of docs/scoring.md, written out plainly.
fn expected(names: &[String]) -> Result<(), String> {
    if names.len() > MAX_COLUMNS {
        return Err(format!("the header names {} columns", names.len()));
    }
    let lower: Vec<String> = names.iter().map(|n| n.to_ascii_lowercase()).collect();
    for (i, n) in lower.iter().enumerate() {
        if n.is_empty() {
            return Err(format!("column {} of the header has no name", i + 1));
        }
        if lower[..i].contains(n) {
            return Err(format!("column `{n}`: column named twice"));
        }
    }
    for r in ["x", "y", "e1", "e2", "image"] {
        if !lower.iter().any(|n| n == r) {
            return Err(format!("column `{r}`: required column missing"));
        }
    }
    Ok(())
}

#[test]
fn random_header_shapes_end_as_the_rules_say() {
    use rand::{RngExt, SeedableRng};
    let mut rng = stepsim_contract::seed::SimRng::seed_from_u64(2323);
    let pool = [
        "image", "x", "y", "e1", "e2", "weight", "flags", "X", "E1", "Image", "mag", "",
    ];
    let mut outcomes = [0usize; 2];
    for case in 0..400 {
        let csv = rng.random_bool(0.5);
        let n = match rng.random_range(0..10) {
            0 => rng.random_range(MAX_COLUMNS - 3..MAX_COLUMNS + 4),
            1 => rng.random_range(2000..6000),
            _ => rng.random_range(2..10),
        };
        let mut names: Vec<String> = (0..n)
            .map(|_| match rng.random_range(0..4) {
                0 => format!("c{}", rng.random_range(0..20_000)),
                1 if csv => format!("q,{}", rng.random_range(0..50)),
                _ => pool[rng.random_range(0..pool.len())].to_owned(),
            })
            .collect();
        if !csv {
            names.retain(|s| !s.is_empty());
        }
        if rng.random_bool(0.5) && names.len() >= 5 {
            // Often a valid core, to reach the later checks.
            for (k, r) in ["image", "x", "y", "e1", "e2"].iter().enumerate() {
                names[k] = (*r).to_owned();
            }
        }
        let quote = |s: &String| {
            if s.contains(',') {
                format!("\"{s}\"")
            } else {
                s.clone()
            }
        };
        let value = |s: &String| match s.to_ascii_lowercase().as_str() {
            "image" => "imA".to_owned(),
            _ => "1".to_owned(),
        };
        let (head, row) = if csv {
            (
                names.iter().map(quote).collect::<Vec<_>>().join(","),
                names.iter().map(value).collect::<Vec<_>>().join(","),
            )
        } else {
            (
                format!("# {}", names.join(" ")),
                names.iter().map(value).collect::<Vec<_>>().join(" "),
            )
        };
        let text = format!("{head}\n{row}\n");
        let t = Instant::now();
        let got = parse_file(Path::new("h.txt"), text.as_bytes(), &index(), None);
        assert!(t.elapsed() < QUICK, "case {case}: {:?}", t.elapsed());
        match (expected(&names), got) {
            (Ok(()), Ok(fr)) => {
                assert_eq!(fr.rows.len(), 1, "case {case}");
                outcomes[0] += 1;
            }
            (Err(want), Err(e)) => {
                let e = e.to_string();
                assert!(e.starts_with("h.txt: line 1"), "case {case}: {e}");
                assert!(e.contains(&want), "case {case}: want `{want}`, got {e}");
                outcomes[1] += 1;
            }
            (want, got) => panic!("case {case} {names:?}: want {want:?}, got {got:?}"),
        }
    }
    assert!(outcomes.iter().all(|&k| k > 40), "{outcomes:?}");
}
