//! FITS submissions and truth tables whose names look like cfitsio's
//! extended syntax (`[1]`, `(2)`, a leading `!`) are read as the files they
//! name.

use crate::common;

use common::index;
use std::path::Path;
use stepsim_harness::parse_file;

fn write_table(path: &Path, x: &[f64]) {
    use fitsio::tables::{ColumnDataType, ColumnDescription};
    use stepsim_contract::io::fits::{Primary, create_fits, finish_fits};
    let mut f = create_fits(path, Primary::default()).unwrap();
    let mut cols = vec![
        ColumnDescription::new("IMAGE")
            .with_type(ColumnDataType::String)
            .that_repeats(8)
            .create()
            .unwrap(),
    ];
    for n in ["X", "Y", "E1", "E2"] {
        cols.push(
            ColumnDescription::new(n)
                .with_type(ColumnDataType::Double)
                .create()
                .unwrap(),
        );
    }
    let hdu = f.create_table("SHEAR", &cols).unwrap();
    let n = x.len();
    hdu.write_col(&mut f, "IMAGE", &vec!["imA".to_string(); n])
        .unwrap();
    hdu.write_col(&mut f, "X", x).unwrap();
    hdu.write_col(&mut f, "Y", &vec![5.0; n]).unwrap();
    hdu.write_col(&mut f, "E1", &vec![0.1; n]).unwrap();
    hdu.write_col(&mut f, "E2", &vec![0.0; n]).unwrap();
    finish_fits(f, path).unwrap();
}

#[test]
fn fits_submissions_with_bracketed_names_are_read_as_named() {
    let dir = tempfile::tempdir().unwrap();
    let sub = dir.path().join("team[1]");
    std::fs::create_dir(&sub).unwrap();
    for name in ["s[1].fits", "s(2).fits", "!s.fits"] {
        let p = sub.join(name);
        write_table(&p, &[1.0, 2.0, 3.0]);
        let bytes = std::fs::read(&p).unwrap();
        let fr = parse_file(&p, &bytes, &index(), None).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(fr.rows.len(), 3, "{name}");
        assert_eq!(fr.rows[2].1.x, 3.0, "{name}");
    }
    // A file that is not FITS is refused with a sentence naming it.
    let p = sub.join("junk[2].fits");
    let mut junk = b"SIMPLE  = junk".to_vec();
    junk.resize(2880, b'x');
    std::fs::write(&p, junk).unwrap();
    let e = parse_file(&p, &std::fs::read(&p).unwrap(), &index(), None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("junk[2].fits"), "{e}");
    assert!(!e.contains("FitsError") && !e.contains("status:"), "{e}");
}
