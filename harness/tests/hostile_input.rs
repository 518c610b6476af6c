//! Hostile and absurd submissions: every one is refused with a sentence
//! naming the file (and line or row and column where there is one), never a
//! panic, an abort, a hang or an unbounded read.

use crate::common;

use common::{
    Col, card, doubles, empty_primary, fits_table, good_table, gzip, index, pad, text, zeros,
};
use std::path::Path;
use stepsim_harness::{parse_file, read_submission, read_submission_limited};

fn parse_fits_bytes(bytes: &[u8]) -> Result<Vec<String>, String> {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("s.fits");
    std::fs::write(&p, bytes).unwrap();
    parse_file(&p, bytes, &index(), None)
        .map(|fr| {
            assert_eq!(fr.rows.len(), 3);
            fr.ignored_columns
        })
        .map_err(|e| {
            let e = e.to_string();
            assert!(e.starts_with(&p.display().to_string()), "{e}");
            e[p.display().to_string().len()..].to_owned()
        })
}

/// Extra columns of every type (fitsio panics describing P, Q, C and M).
fn odd_columns() -> Vec<Col> {
    vec![
        zeros("P", "1PD(2)", 8, 3),
        zeros("Q", "1QE(2)", 16, 3),
        zeros("C", "C", 8, 3),
        zeros("M", "M", 16, 3),
        zeros("L", "L", 1, 3),
        zeros("V", "3D", 24, 3),
        zeros("B", "8X", 1, 3),
    ]
}

#[test]
fn fits_columns_of_any_type_are_ignored_when_extra() {
    let ignored = parse_fits_bytes(&good_table(odd_columns())).unwrap();
    assert_eq!(ignored, ["p", "q", "c", "m", "l", "v", "b"]);
}

#[test]
fn fits_required_columns_of_the_wrong_type_are_refused_by_name() {
    let cases: [(Col, &str); 7] = [
        (
            zeros("E1", "1PD(2)", 8, 3),
            ", column `e1`: the column holds a variable-length array (TFORM P or Q) \
             (TFORM `1PD(2)`) where one number per row is needed",
        ),
        (
            zeros("E1", "1QE(2)", 16, 3),
            ", column `e1`: the column holds a variable-length array (TFORM P or Q) \
             (TFORM `1QE(2)`) where one number per row is needed",
        ),
        (
            zeros("E1", "C", 8, 3),
            ", column `e1`: the column holds complex numbers (TFORM `C`) where one \
             number per row is needed",
        ),
        (
            zeros("E1", "M", 16, 3),
            ", column `e1`: the column holds complex numbers (TFORM `M`) where one \
             number per row is needed",
        ),
        (
            zeros("E1", "L", 1, 3),
            ", column `e1`: the column holds logical values (TFORM `L`) where one \
             number per row is needed",
        ),
        (
            zeros("E1", "3D", 24, 3),
            ", column `e1`: the column holds a vector of 3 numbers per row (TFORM `3D`) \
             where one number per row is needed",
        ),
        (
            text("E1", &["a", "b", "c"]),
            ", column `e1`: the column holds text (TFORM `8A`) where one number per row \
             is needed",
        ),
    ];
    for (e1, want) in cases {
        let cols = vec![
            text("IMAGE", &["imA", "imB", "imA"]),
            doubles("X", &[1.0, 2.0, 3.0]),
            doubles("Y", &[5.0, 5.0, 5.0]),
            e1,
            doubles("E2", &[0.0, 0.0, 0.0]),
        ];
        assert_eq!(parse_fits_bytes(&fits_table(&cols)).unwrap_err(), want);
    }
    let cols = vec![
        doubles("IMAGE", &[1.0, 2.0, 3.0]),
        doubles("X", &[1.0, 2.0, 3.0]),
        doubles("Y", &[5.0, 5.0, 5.0]),
        doubles("E1", &[0.0, 0.0, 0.0]),
        doubles("E2", &[0.0, 0.0, 0.0]),
    ];
    assert_eq!(
        parse_fits_bytes(&fits_table(&cols)).unwrap_err(),
        ", column `image`: the column holds numbers (TFORM `D`) where text (the image id) \
         is needed"
    );
}

/// Rewrites the value of a header card of the extension.
fn set_card(bytes: &mut [u8], key: &str, value: &str) {
    let at = (2880..bytes.len())
        .step_by(80)
        .find(|&i| bytes[i..i + 8].starts_with(key.as_bytes()))
        .unwrap();
    let v = format!("{value:>20}");
    bytes[at + 10..at + 30].copy_from_slice(v.as_bytes());
}

#[test]
fn fits_headers_that_claim_more_than_the_file_holds_are_refused_before_reading() {
    // 10¹² rows: reading them would need terabytes.
    let mut b = good_table(vec![]);
    set_card(&mut b, "NAXIS2", "1000000000000");
    let e = parse_fits_bytes(&b).unwrap_err();
    assert!(
        e.contains(
            "the table header announces 1000000000000 rows of 40 bytes, more than the file holds"
        ),
        "{e}"
    );
    // A text field wider than the row (buffers are sized by it).
    let mut b = good_table(vec![]);
    let at = (2880..b.len())
        .step_by(80)
        .find(|&i| b[i..i + 8] == *b"TFORM1  ")
        .unwrap();
    b[at + 10..at + 30].copy_from_slice(b"'900000000A'        ");
    let e = parse_fits_bytes(&b).unwrap_err();
    assert_eq!(e, ": HDU 2: the table's column formats are invalid");
    let b = good_table(vec![]);
    // A table that is not there: no extension after the primary HDU.
    let e = parse_fits_bytes(&b[..2880]).unwrap_err();
    assert_eq!(
        e,
        ": no table extension in this FITS file (a binary or ASCII table extension with \
         the columns is needed)"
    );
    // A truncated extension header is a damaged file, said so.
    let e = parse_fits_bytes(&b[..2880 + 800]).unwrap_err();
    assert!(e.starts_with(": HDU 2: "), "{e}");
    assert!(!e.contains("FitsError") && !e.contains("status"), "{e}");
}

#[test]
fn text_with_a_bom_and_any_line_ends_is_read_and_binary_is_refused_by_line() {
    let idx = index();
    for text in [
        "\u{feff}# image x y e1 e2\nimA 1 2 0.1 0.2\nimB 3 4 0 0\n",
        "# image x y e1 e2\rimA 1 2 0.1 0.2\rimB 3 4 0 0\r",
        "\u{feff}image,x,y,e1,e2\r\nimA,1,2,0.1,0.2\r\n\r\nimB,3,4,0,0",
    ] {
        let fr = parse_file(Path::new("s.txt"), text.as_bytes(), &idx, None).unwrap();
        assert_eq!(fr.rows.len(), 2, "{text:?}");
        assert_eq!((fr.rows[1].0, fr.rows[1].1.x), (1, 3.0));
    }
    // Line numbers count CR-only ends: the bad value is on line 3.
    let e = parse_file(
        Path::new("s.txt"),
        b"# image x y e1 e2\rimA 1 2 0.1 0.2\rimB 3 4 zz 0\r",
        &idx,
        None,
    )
    .unwrap_err();
    assert_eq!(
        e.to_string(),
        "s.txt: line 3, column `e1`: cannot read `zz` as a number"
    );
    let cases: [(&[u8], &str); 4] = [
        (
            b"# image x y e1 e2\nimA 1 2 0.1 0.2\x00\x00\n",
            "s.txt: line 2: contains a NUL byte: this is binary data, not a text table",
        ),
        (
            b"# image x y e1 e2\nimA 1 2 0.1 0.2\nimB\x01 1 2 0 0\n",
            "s.txt: line 3: contains the control character 0x01: this is binary data, \
             not a text table",
        ),
        (
            b"\xff\xfe#\x00 \x00",
            "s.txt: line 1: the file is UTF-16 text; save it as UTF-8",
        ),
        (
            b"\x00\x00\x00\x00\x00",
            "s.txt: line 1: contains a NUL byte: this is binary data, not a text table",
        ),
    ];
    for (bytes, want) in cases {
        let e = parse_file(Path::new("s.txt"), bytes, &idx, None).unwrap_err();
        assert_eq!(e.to_string(), want);
    }
}

#[test]
fn absurd_values_are_refused_naming_line_column_and_value() {
    let idx = index();
    let cases = [
        (
            "# image x y e1 e2\nimA 1 2 1e308 0\n",
            "s.txt: line 2, column `e1`: e1 = 1e308 is beyond the accepted range \
             (|e1| ≤ 1e6); cut failed measurements",
        ),
        (
            "# image x y e1 e2\nimA 1 2 0 -1000000.5\n",
            "s.txt: line 2, column `e2`: e2 = -1000000.5 is beyond the accepted range \
             (|e2| ≤ 1e6); cut failed measurements",
        ),
        (
            "# image x y e1 e2 weight\nimA 1 2 0 0 inf\n",
            "s.txt: line 2, column `weight`: value `inf` is not finite",
        ),
        (
            "# image x y e1 e2 weight\nimA 1 2 0 0 -0.5\n",
            "s.txt: line 2, column `weight`: weight -0.5 is negative",
        ),
        // Each weight finite, their sum not.
        (
            "# image x y e1 e2 weight\nimA 1 2 0 0 1e308\nimB 1 2 0 0 1e308\nimA 3 4 0 0 1e308\n",
            "s.txt: line 4, column `weight`: weight 1e308 makes the weighted sums of image `imA` \
             overflow (larger than 1.7976931348623157e308); scale the weights down",
        ),
        // Finite Σw, but Σw|e1| overflows.
        (
            "# image x y e1 e2 weight\nimA 1 2 0.5 0 1e304\nimA 3 4 1e5 0 1e304\n",
            "s.txt: line 3, column `weight`",
        ),
    ];
    for (text, want) in cases {
        let e = parse_file(Path::new("s.txt"), text.as_bytes(), &idx, None)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with(want),
            "input {text:?}\n got  {e}\n want {want}"
        );
    }
    // At the bound itself: accepted.
    let fr = parse_file(
        Path::new("s.txt"),
        b"# image x y e1 e2\nimA 1 2 1e6 -1e6\n",
        &idx,
        None,
    )
    .unwrap();
    assert_eq!(fr.rows[0].1.e1, 1e6);
}

#[test]
fn reads_are_bounded_raw_and_decompressed() {
    let idx = index();
    let dir = tempfile::tempdir().unwrap();
    let text = b"# image x y e1 e2\nimA 1 2 0.1 0.2\nimB 3 4 0 0\n";
    // A gzip text submission is read (decompressed within the cap) ...
    let p = dir.path().join("s.txt.gz");
    std::fs::write(&p, gzip(text, 6)).unwrap();
    assert_eq!(read_submission(&p, &idx).unwrap().n_rows(), 2);
    // ... and a bomb is refused at the cap, naming the file and the cap.
    let mut bomb_text = text.to_vec();
    bomb_text.extend(std::iter::repeat_n(b'\n', 3 << 20));
    std::fs::write(&p, gzip(&bomb_text, 6)).unwrap();
    let e = read_submission_limited(&p, &idx, 1 << 20)
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        format!(
            "{}: larger than the limit of 1 MiB (after gzip decompression); refused without \
             reading it",
            p.display()
        )
    );
    // A plain file over the cap.
    let p = dir.path().join("big.txt");
    std::fs::write(&p, &bomb_text).unwrap();
    let e = read_submission_limited(&p, &idx, 1 << 20)
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        format!(
            "{}: larger than the limit of 1 MiB (the file); refused without reading it",
            p.display()
        )
    );
    // A directory whose files together exceed the cap.
    let d = dir.path().join("d");
    std::fs::create_dir(&d).unwrap();
    std::fs::write(d.join("imA.txt"), vec![b'\n'; 600 << 10]).unwrap();
    std::fs::write(d.join("imB.txt"), vec![b'\n'; 600 << 10]).unwrap();
    let e = read_submission_limited(&d, &idx, 1 << 20)
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        format!(
            "{}: the submission's files together are larger than the limit of 1 MiB",
            d.join("imB.txt").display()
        )
    );
}

#[cfg(unix)]
#[test]
fn only_regular_files_are_read_and_links_in_a_directory_are_refused() {
    use std::os::unix::fs::symlink;
    let idx = index();
    let dir = tempfile::tempdir().unwrap();
    // Devices and FIFOs: refused at once (a FIFO would block a reader).
    let e = read_submission(Path::new("/dev/zero"), &idx)
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        "/dev/zero: not a regular file (a device); only regular files are read"
    );
    let fifo = dir.path().join("fifo.txt");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let e = read_submission(&fifo, &idx).unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "{}: not a regular file (a FIFO); only regular files are read",
            fifo.display()
        )
    );
    // The top-level path may be a link (the organiser named it).
    let real = dir.path().join("real.txt");
    std::fs::write(&real, "# image x y e1 e2\nimA 1 2 0 0\nimB 1 2 0 0\n").unwrap();
    let link = dir.path().join("link.txt");
    symlink(&real, &link).unwrap();
    assert_eq!(read_submission(&link, &idx).unwrap().n_rows(), 2);
    // In a directory, a link is refused (it could point anywhere, e.g. at
    // the truth), and so is a FIFO.
    let d = dir.path().join("d");
    std::fs::create_dir(&d).unwrap();
    std::fs::write(d.join("imA.txt"), "# x y e1 e2\n1 2 0 0\n").unwrap();
    symlink(&real, d.join("imB.txt")).unwrap();
    let e = read_submission(&d, &idx).unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "{}: is a symbolic link; a submission directory must hold the files themselves \
             (links are refused so that nothing outside it is read)",
            d.join("imB.txt").display()
        )
    );
    std::fs::remove_file(d.join("imB.txt")).unwrap();
    let c = std::ffi::CString::new(d.join("imB.txt").to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let e = read_submission(&d, &idx).unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "{}: not a regular file (a FIFO); only regular files are read",
            d.join("imB.txt").display()
        )
    );
}

#[cfg(unix)]
#[test]
fn a_fits_file_whose_name_is_not_utf8_is_refused_not_a_panic() {
    use std::os::unix::ffi::OsStrExt;
    let dir = tempfile::tempdir().unwrap();
    let p = dir
        .path()
        .join(std::ffi::OsStr::from_bytes(b"sub\xff.fits"));
    let b = good_table(vec![]);
    std::fs::write(&p, &b).unwrap();
    let e = read_submission(&p, &index()).unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "{}: the file name is not valid UTF-8, which cfitsio cannot open; rename the file",
            p.display()
        )
    );
}

/// An ASCII table extension (XTENSION = 'TABLE'), `image_tform` for the
/// image column.
fn ascii_table(image_tform: &str) -> Vec<u8> {
    let mut o = empty_primary();
    let rows = [
        "imA     1.0     5.0     0.1     0.0     ",
        "imB     2.0     5.0     0.2     0.0     ",
    ];
    let mut cards = vec![
        "XTENSION= 'TABLE   '".to_owned(),
        "BITPIX  =                    8".into(),
        "NAXIS   =                    2".into(),
        "NAXIS1  =                   40".into(),
        "NAXIS2  =                    2".into(),
        "PCOUNT  =                    0".into(),
        "GCOUNT  =                    1".into(),
        "TFIELDS =                    5".into(),
    ];
    for (k, name) in ["IMAGE", "X", "Y", "E1", "E2"].iter().enumerate() {
        cards.push(format!("TTYPE{}  = '{name}'", k + 1));
        cards.push(format!("TBCOL{}  = {:>20}", k + 1, 8 * k + 1));
        let f = if k == 0 { image_tform } else { "F8.2" };
        cards.push(format!("TFORM{}  = '{f}'", k + 1));
    }
    cards.push("END".into());
    for c in &cards {
        card(&mut o, c);
    }
    pad(&mut o, b' ');
    for r in rows {
        o.extend(r.as_bytes());
    }
    pad(&mut o, b' ');
    o
}

#[test]
fn ascii_tables_are_read_and_a_field_wider_than_the_row_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("a.fits");
    let b = ascii_table("A8");
    std::fs::write(&p, &b).unwrap();
    let fr = parse_file(&p, &b, &index(), None).unwrap();
    assert_eq!(fr.rows.len(), 2);
    assert_eq!(
        (fr.rows[1].0, fr.rows[1].1.x, fr.rows[1].1.e1),
        (1, 2.0, 0.2)
    );
    // A field wider than the row (a string buffer sized by it would take
    // 900 MB per row): cfitsio refuses it, in words.
    let b = ascii_table("A900000000");
    std::fs::write(&p, &b).unwrap();
    let e = parse_file(&p, &b, &index(), None).unwrap_err().to_string();
    assert!(
        !e.contains("FitsError") && e.starts_with(&p.display().to_string()),
        "{e}"
    );
    assert_eq!(
        e,
        format!(
            "{}: HDU 2: the table's column formats are invalid",
            p.display()
        )
    );
}
