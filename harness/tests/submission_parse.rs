//! The submission reader: every accepted form, every refusal (with file,
//! line and column), and a fuzz loop that must never panic.

use rand::{RngExt, SeedableRng};
use std::path::Path;
use stepsim_contract::seed::SimRng;
use stepsim_harness::{HarnessError, parse_file, read_submission};

use crate::common;
use common::index;

const GOOD: &str = "# image x y e1 e2 weight flags\n\
                    imA 10.5 20.25 0.01 -0.02 2.0 0\n\
                    # a comment\n\
                    \n\
                    imB\t0.5\t80.5\t0.1\t0.2\t1\t3\n";

#[test]
fn whitespace_table_with_comments_and_extra_columns() {
    let idx = index();
    let fr = parse_file(Path::new("s.txt"), GOOD.as_bytes(), &idx, None).unwrap();
    assert_eq!(fr.rows.len(), 2);
    assert_eq!(fr.rows[0].0, 0);
    assert_eq!(fr.rows[0].1.x, 10.5);
    assert_eq!(fr.rows[0].1.weight, 2.0);
    assert_eq!(fr.rows[0].1.line, 2);
    assert_eq!(fr.rows[1].0, 1);
    assert_eq!(
        fr.rows[1].1.y, 80.5,
        "the half-pixel border is on the image"
    );
    assert_eq!(fr.rows[1].1.line, 5);
    // `flags` is a documented optional column (what `stepsim measure`
    // writes): read as nothing, and not reported as ignored.
    assert!(fr.ignored_columns.is_empty(), "{:?}", fr.ignored_columns);
}

#[test]
fn csv_with_quotes_crlf_and_default_weight() {
    let idx = index();
    let text = "IMAGE,X,Y,E1,E2\r\n\"imB\",3,4,0.5,-0.5\r\nimA, 7 ,8,0,0\r\n";
    let fr = parse_file(Path::new("s.csv"), text.as_bytes(), &idx, None).unwrap();
    assert_eq!(fr.rows.len(), 2);
    assert_eq!(fr.rows[0].0, 1);
    assert_eq!(fr.rows[0].1.e2, -0.5);
    assert_eq!(fr.rows[0].1.weight, 1.0);
    assert_eq!(fr.rows[1].1.x, 7.0);
    assert!(fr.ignored_columns.is_empty());
}

#[test]
fn csv_quoted_fields_may_hold_commas_and_quotes() {
    let idx = index();
    let text = "image,x,y,e1,e2,\"note, free text\"\n\
                \"imA\",1,2,0.1,0.2,\"near a star, blended\"\n\
                imB, 3 ,4,0,0,\"say \"\"hi\"\", twice\"\n";
    let fr = parse_file(Path::new("s.csv"), text.as_bytes(), &idx, None).unwrap();
    assert_eq!(fr.rows.len(), 2);
    assert_eq!(
        (fr.rows[0].0, fr.rows[0].1.x, fr.rows[0].1.e2),
        (0, 1.0, 0.2)
    );
    assert_eq!(
        (fr.rows[1].0, fr.rows[1].1.x, fr.rows[1].1.line),
        (1, 3.0, 3)
    );
    assert_eq!(fr.ignored_columns, ["note, free text"]);
    // A comma inside quotes is one field: a number with a decimal comma is
    // refused as a number, naming line and column.
    let err = parse_file(
        Path::new("s.csv"),
        b"image,x,y,e1,e2\nimA,\"1,5\",2,0,0\n",
        &idx,
        None,
    )
    .unwrap_err()
    .to_string();
    assert_eq!(
        err, "s.csv: line 2, column `x`: cannot read `1,5` as a number",
        "{err}"
    );
}

fn write_fits(path: &Path, images: &[&str], x: &[f64], e1: &[f64]) {
    use fitsio::tables::{ColumnDataType, ColumnDescription};
    let _ = std::fs::remove_file(path);
    let mut f = fitsio::FitsFile::create(path).open().unwrap();
    let mut cols = vec![
        ColumnDescription::new("IMAGE")
            .with_type(ColumnDataType::String)
            .that_repeats(12)
            .create()
            .unwrap(),
    ];
    for n in ["X", "Y", "E1", "E2", "FLUX"] {
        cols.push(
            ColumnDescription::new(n)
                .with_type(ColumnDataType::Double)
                .create()
                .unwrap(),
        );
    }
    let hdu = f.create_table("SHEAR", &cols).unwrap();
    let n = x.len();
    hdu.write_col(
        &mut f,
        "IMAGE",
        &images.iter().map(|s| s.to_string()).collect::<Vec<_>>(),
    )
    .unwrap();
    hdu.write_col(&mut f, "X", x).unwrap();
    hdu.write_col(&mut f, "Y", &vec![5.0; n]).unwrap();
    hdu.write_col(&mut f, "E1", e1).unwrap();
    hdu.write_col(&mut f, "E2", &vec![0.0; n]).unwrap();
    hdu.write_col(&mut f, "FLUX", &vec![1.0; n]).unwrap();
}

#[test]
fn fits_table_is_read_by_column_name() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("s.fits");
    write_fits(
        &p,
        &["imA", "imB", "imB"],
        &[1.0, 2.0, 3.0],
        &[0.1, 0.2, 0.3],
    );
    let bytes = std::fs::read(&p).unwrap();
    let fr = parse_file(&p, &bytes, &index(), None).unwrap();
    assert_eq!(fr.rows.len(), 3);
    assert_eq!(fr.rows[2].0, 1);
    assert_eq!(fr.rows[2].1.e1, 0.3);
    assert_eq!(fr.rows[2].1.line, 3);
    assert_eq!(fr.ignored_columns, vec!["flux".to_owned()]);
    // A NaN is refused with its row and column.
    write_fits(&p, &["imA", "imB"], &[1.0, 2.0], &[0.1, f64::NAN]);
    let bytes = std::fs::read(&p).unwrap();
    let e = parse_file(&p, &bytes, &index(), None)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("s.fits: row 2, column `e1`") && e.contains("not finite"),
        "{e}"
    );
    write_fits(&p, &["imA", "imZ"], &[1.0, 2.0], &[0.1, 0.1]);
    let bytes = std::fs::read(&p).unwrap();
    let e = parse_file(&p, &bytes, &index(), None)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("row 2, column `image`: unknown image id `imZ`"),
        "{e}"
    );
}

#[test]
fn a_directory_of_per_image_tables() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("imA.txt"),
        "# x y e1 e2\n1 2 0.1 0.2\n3 4 0.3 0.4\n",
    )
    .unwrap();
    std::fs::write(
        dir.path().join("imB.csv"),
        "x,y,e1,e2,image\n5,6,0.5,0.6,imB\n",
    )
    .unwrap();
    let sub = read_submission(dir.path(), &index()).unwrap();
    assert_eq!(sub.image_len(0), 2);
    assert_eq!(sub.image_len(1), 1);
    assert_eq!(sub.image_rows(1).unwrap()[0].e2, 0.6);
    assert!(sub.missing_images().is_empty());
    // A file whose image column disagrees with its name.
    std::fs::write(
        dir.path().join("imB.csv"),
        "x,y,e1,e2,image\n5,6,0.5,0.6,imA\n",
    )
    .unwrap();
    let e = read_submission(dir.path(), &index())
        .unwrap_err()
        .to_string();
    assert!(e.contains("imB.csv: line 2, column `image`"), "{e}");
    // A file for an unknown image.
    std::fs::write(dir.path().join("imB.csv"), "x,y,e1,e2\n5,6,0.5,0.6\n").unwrap();
    std::fs::write(dir.path().join("imC.txt"), "# x y e1 e2\n1 2 3 4\n").unwrap();
    let e = read_submission(dir.path(), &index())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("imC.txt") && e.contains("unknown image id `imC`"),
        "{e}"
    );
}

/// (text, expected fragment of the message).
const BAD: &[(&str, &str)] = &[
    (
        "# image x y e1 e2\nimA 1 2 0.1 0.2\nimQ 1 2 0.1 0.2\n",
        "line 3, column `image`: unknown image id `imQ`",
    ),
    (
        "# image x y e1\nimA 1 2 0.1\n",
        "line 1, column `e2`: required column missing",
    ),
    (
        "# x y e1 e2\n1 2 0.1 0.2\n",
        "line 1, column `image`: required column missing",
    ),
    (
        "# image x y e1 e2\nimA 1 2 nan 0.2\n",
        "line 2, column `e1`: value `NaN` is not finite",
    ),
    (
        "# image x y e1 e2\nimA 1 2 0.1 -inf\n",
        "line 2, column `e2`: value `-inf` is not finite",
    ),
    (
        "# image x y e1 e2\nimA 100.6 2 0.1 0.2\n",
        "line 2, column `x`: x = 100.6 is off the image",
    ),
    (
        "# image x y e1 e2\nimA 0.4 2 0.1 0.2\n",
        "line 2, column `x`",
    ),
    (
        "# image x y e1 e2\nimA 1 80.51 0.1 0.2\n",
        "line 2, column `y`: y = 80.51 is off the image",
    ),
    (
        "# image x y e1 e2\nimA 1 2 0.1x 0.2\n",
        "line 2, column `e1`: cannot read `0.1x` as a number",
    ),
    (
        "# image x y e1 e2\nimA 1 2 0.1\n",
        "line 2: expected 5 fields, found 4",
    ),
    (
        "# image x y e1 e2 weight\nimA 1 2 0.1 0.2 -1\n",
        "line 2, column `weight`: weight -1 is negative",
    ),
    (
        "# image x y e1 e2\nimA 1 2 0.1 0.2\nimB 1 2 0 0\n\nimA 1.0 2.0 0.3 0.3\n",
        "line 5, column `x`: duplicate row: image `imA` x = 1 y = 2 already given at line 2",
    ),
    ("", "s.txt: empty file"),
    ("\n  \n", "s.txt: empty file"),
    ("# image x y e1 e2\n# only comments\n", "s.txt: no rows"),
    (
        "image x y e1 e2\nimA 1 2 3 4\n",
        "line 1: the first line must be a header",
    ),
    (
        "# image x x e1 e2\n",
        "line 1, column `x`: column named twice",
    ),
    (
        "image,x,y,e1,e2\nimA,1,2,0.1\n",
        "line 2: expected 5 fields, found 4",
    ),
    (
        "image,x,y,e1,e2\nimA,1,,0.1,0\n",
        "line 2, column `y`: cannot read `` as a number",
    ),
];

#[test]
fn every_kind_of_bad_input_is_refused_naming_file_line_and_column() {
    let idx = index();
    for (text, want) in BAD {
        let err = parse_file(Path::new("s.txt"), text.as_bytes(), &idx, None).unwrap_err();
        assert!(matches!(err, HarnessError::Submission { .. }));
        let msg = err.to_string();
        assert!(msg.starts_with("s.txt"), "{msg}");
        assert!(
            msg.contains(want),
            "input {text:?}\n got  {msg}\n want {want}"
        );
    }
    let e = parse_file(
        Path::new("s.txt"),
        b"# image x y e1 e2\nimA 1 2 \xff 0\n",
        &idx,
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("line 2") && e.contains("UTF-8"), "{e}");
}

#[test]
fn fuzzed_inputs_never_panic() {
    let idx = index();
    let mut rng = SimRng::seed_from_u64(2024);
    let alphabet = b"# \t\n\r,.-+0123456789eEnaifimABxyw\"\xff";
    let (mut ok, mut refused) = (0, 0);
    for case in 0..6000 {
        let bytes: Vec<u8> = if case % 3 == 0 {
            // Random bytes over a small alphabet (with the header now and then).
            let n = rng.random_range(0..160);
            let mut v: Vec<u8> = if rng.random::<f64>() < 0.5 {
                b"# image x y e1 e2 weight\n".to_vec()
            } else {
                Vec::new()
            };
            v.extend((0..n).map(|_| alphabet[rng.random_range(0..alphabet.len())]));
            v
        } else {
            // A valid file with a few random edits.
            let mut v = GOOD.as_bytes().to_vec();
            for _ in 0..rng.random_range(1..5) {
                let at = rng.random_range(0..=v.len());
                match rng.random_range(0..3) {
                    0 if at < v.len() => {
                        v.remove(at);
                    }
                    1 => v.insert(at, alphabet[rng.random_range(0..alphabet.len())]),
                    _ if at < v.len() => v[at] = rng.random::<u8>(),
                    _ => {}
                }
            }
            v
        };
        match parse_file(Path::new("f.txt"), &bytes, &idx, None) {
            Ok(fr) => {
                ok += 1;
                assert!(!fr.rows.is_empty());
                for (_, r) in fr.rows {
                    assert!(r.x.is_finite() && r.e1.is_finite() && r.weight >= 0.0);
                }
            }
            Err(e) => {
                refused += 1;
                assert!(e.to_string().starts_with("f.txt"), "{e}");
            }
        }
    }
    assert!(ok > 100 && refused > 1000, "ok {ok} refused {refused}");
    // Mutated FITS files: flipped bytes in the header and in the data.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.fits");
    write_fits(
        &p,
        &["imA", "imB", "imA"],
        &[1.0, 2.0, 3.0],
        &[0.1, 0.2, 0.3],
    );
    let good = std::fs::read(&p).unwrap();
    for case in 0..400 {
        let mut v = good.clone();
        for _ in 0..rng.random_range(1..4) {
            let at = if case % 3 == 0 {
                rng.random_range(9..v.len()) // anywhere past `SIMPLE  =`
            } else if case % 3 == 1 {
                rng.random_range(2880..v.len()) // extension header and data
            } else {
                rng.random_range(5760..v.len()) // data
            };
            v[at] = rng.random::<u8>();
        }
        if case % 10 == 0 {
            v.truncate(rng.random_range(2880..v.len()));
        }
        std::fs::write(&p, &v).unwrap();
        if let Err(e) = parse_file(&p, &v, &idx, None) {
            assert!(e.to_string().contains("m.fits"), "{e}");
        }
    }
}
